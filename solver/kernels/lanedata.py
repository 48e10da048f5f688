"""The data of many instances of one model as lanes, and their accelerations with every effect.

:mod:`solver.kernels.lanes` steps the plain forces and constraints of B instances with the
instance (lane) index innermost. The effects a scene switches on keep state per instance (the
ledger, the contact scans, the refinement levels) that the scalar kernels of
:mod:`solver.kernels.effects` read and write; here each instance's data lives lane-OUTER in a
:class:`LaneState` (lane k's slices are the arrays of its :class:`~solver.kernels.records.Data`,
:func:`lane_record`), with lane-inner copies (:class:`~solver.kernels.lanes.LaneData`) for the
vector loops. :func:`evaluate` is the lane twin of
:func:`solver.kernels.dynamics.accelerations`: the integrators over lanes
(:mod:`solver.integrators.rk4lanes`) call it and the entries of :mod:`solver.kernels.effects` on
:func:`lane_record`, and know no effect.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from solver.compiled import jit_inline, jit_lanes
from solver.kernels import lanes, lanesteps
from solver.kernels.barcontact import bar_forces, base_forces
from solver.kernels.contact import axial_contacts
from solver.kernels.records import LOOK, MET, POWER, ContactState, Data, Work, copy_data
from solver.status import OK


class LaneState(NamedTuple):
    """The data of B instances with the lane index OUTERMOST: lane k's slices (``x[k]``,
    ``scan[k]``, ...) are the arrays of that instance's :class:`~solver.kernels.records.Data`
    (:func:`lane_record`), which the scalar effect kernels read and write as they do in a single
    run. ``saved`` (B, 2, n, 3) is each lane's :attr:`Work.saved`."""
    x: np.ndarray
    v: np.ndarray
    rest: np.ndarray
    EA: np.ndarray
    f_ext: np.ndarray
    ledger: np.ndarray
    scan: np.ndarray
    active: np.ndarray
    refine: np.ndarray
    saved: np.ndarray


class LaneScratch(NamedTuple):
    """Per-lane scratch in the scalar layout: each lane's first-stage accelerations ``a1``
    (B, n, 3), which a step tried whole reads and a pending step starts from."""
    a1: np.ndarray


@jit_inline
def lane_record(S, k):
    """Lane k's :class:`~solver.kernels.records.Data` (views into ``S``)."""
    return Data(S.x[k], S.v[k], S.rest[k], S.EA[k], S.f_ext[k], S.ledger[k],
                ContactState(S.scan[k], S.active[k]), S.refine[k])


@jit_inline
def lane_work_record(w0, S, k):
    """The scalar :class:`~solver.kernels.records.Work` of lane k: the shared scratch ``w0``
    with lane k's ``saved``."""
    return Work(w0.f, w0.wf, w0.bvec, w0.band, w0.lam, w0.xs, w0.vs, w0.acc, w0.xacc, w0.vacc,
                w0.a1, w0.kkt, S.saved[k])


@jit_lanes
def to_lanes(src, dst):
    """``dst[..., k] = src[k]``: lane-outer (B, ...) to lane-inner (..., B)."""
    n_lanes = src.shape[0]
    s = src.reshape((n_lanes, -1))
    d = dst.reshape((-1, n_lanes))
    for j in range(s.shape[1]):         # stores in order, loads from B rows at a time
        for k in range(n_lanes):
            d[j, k] = s[k, j]


@jit_lanes
def from_lanes(src, dst):
    """``dst[k] = src[..., k]``: lane-inner (..., B) to lane-outer (B, ...), every lane."""
    n_lanes = dst.shape[0]
    s = src.reshape((-1, n_lanes))
    d = dst.reshape((n_lanes, -1))
    for j in range(s.shape[0]):
        for k in range(n_lanes):
            d[k, j] = s[j, k]


@jit_lanes
def lane_out(src, k, dst):
    """``dst[...] = src[..., k]``: one lane of a lane-inner array into a scalar-layout one."""
    n_lanes = src.shape[src.ndim - 1]
    s = src.reshape((-1, n_lanes))
    d = dst.reshape(-1)
    for j in range(d.shape[0]):
        d[j] = s[j, k]


@jit_lanes
def lane_in(src, k, dst):
    """``dst[..., k] = src[...]``: a scalar-layout array into one lane of a lane-inner one."""
    n_lanes = dst.shape[dst.ndim - 1]
    s = src.reshape(-1)
    d = dst.reshape((-1, n_lanes))
    for j in range(s.shape[0]):
        d[j, k] = s[j]


@jit_lanes
def evaluate(x, v, m, S, L, W, X, C, out):
    """Accelerations of every lane at ``x``, ``v`` (lane-inner) into ``out``, with the forces of
    every effect, as :func:`solver.kernels.dynamics.accelerations` per lane: external forces and
    cables over lanes, then for each lane that takes the step (``C.go``) its stops, strikers and
    bar and base contacts by the scalar kernels on that lane (``C.ev``; on views of its
    positions and forces: the same operations in the same order), then the constraints
    over lanes. A lane's failure goes to ``C.st``; ``C`` is the integrator's step control
    (:class:`~solver.integrators.rk4lanes.LaneControl`: its ``go``, ``st`` and ``ev``)."""
    f, ev = W.f, C.ev
    for k in range(ev.shape[0]):
        ev[k] = 1 if C.go[k] != 0 and C.st[k] == OK else 0
    lanes.copy(f, L.f_ext)
    lanes.cables(x, v, m.topo, m.damping.coef, L.rest, L.EA, f, W.tmp, W.pair, W.piv,
                 ev)
    if m.damping.coef.shape[0] != 0:
        for k in range(ev.shape[0]):
            if ev[k] != 0:
                S.ledger[k, POWER] = W.piv[k]
    axial = m.stops.height.shape[0] != 0 or m.strikers.row.shape[0] != 0
    bars = m.bar_contact.pairs.shape[0] != 0
    if axial or bars:
        for k in range(ev.shape[0]):
            if ev[k] == 0:
                continue
            scan = S.scan[k]
            touch = bars and scan[LOOK] != 0.0
            if not (axial or touch):
                continue
            xk = x[:, :, k]             # views: these kernels read and write a few nodes
            fk = f[:, :, k]
            if axial:
                axial_contacts(xk, m, fk)
            if touch:
                scan[MET] += bar_forces(xk, m.bar_contact, fk, S.active[k])
                if scan[LOOK] == 1.0:
                    scan[MET] += base_forces(xk, m.levels, m.bar_contact, fk)
    lanes.constrained(x, v, m.topo, W, out, C.st)


@jit_lanes
def sync_out(L, S, k):
    """Lane k's state from the lane-inner copy ``L`` into ``S``."""
    lane_out(L.x, k, S.x[k])
    lane_out(L.v, k, S.v[k])


@jit_lanes
def sync_in(L, S, k):
    """Lane k's state from ``S`` into the lane-inner copy ``L``."""
    lane_in(S.x[k], k, L.x)
    lane_in(S.v[k], k, L.v)


@jit_lanes
def enter(S, L):
    """The lane-inner copies ``L`` of the data in ``S`` (state, cables, external forces)."""
    to_lanes(S.x, L.x)
    to_lanes(S.v, L.v)
    to_lanes(S.rest, L.rest)
    to_lanes(S.EA, L.EA)
    to_lanes(S.f_ext, L.f_ext)


@jit_lanes
def keep(S, kept, status):
    """:func:`~solver.kernels.records.copy_data` of each lane whose ``status`` is ``OK`` from
    ``S`` into ``kept``: whole arrays when every lane is."""
    every = True
    for k in range(status.shape[0]):
        every = every and status[k] == OK
    if not every:
        for k in range(status.shape[0]):
            if status[k] == OK:
                copy_data(lane_record(S, k), lane_record(kept, k))
        return
    lanes.copy(kept.x, S.x)
    lanes.copy(kept.v, S.v)
    lanes.copy(kept.rest, S.rest)
    lanes.copy(kept.EA, S.EA)
    lanes.copy(kept.f_ext, S.f_ext)
    lanes.copy(kept.ledger, S.ledger)
    lanes.copy(kept.scan, S.scan)
    lanes.copy(kept.active, S.active)
    lanes.copy(kept.refine, S.refine)


@jit_lanes
def leave(L, S):
    """Every lane's state from the lane-inner copy ``L`` into ``S``."""
    from_lanes(L.x, S.x)
    from_lanes(L.v, S.v)


@jit_lanes
def ledger_energies(m, S, L, go, out, tmp):
    """:func:`solver.kernels.effects.ledger_energy` of each lane whose ``go`` is set, into
    ``out`` (:func:`solver.kernels.lanesteps.ledger_energy_lanes` on the lane-inner state ``L``
    and each lane's contact scans); ``tmp`` (3, B) scratch."""
    lanesteps.ledger_energy_lanes(L.x, L.v, m, L.rest, L.EA, L.f_ext, S.scan, go, out, tmp)


@jit_lanes
def move(S, F, I, a1, status, steps, T, F2, I2, a12, status2, steps2, src, dst):
    """Lane ``src[i]`` of one block of lanes into lane ``dst[i]`` of another, for every ``i``:
    its data (``S`` into ``T``, every field), step control (the float rows ``F`` and int rows
    ``I`` of :func:`solver.integrators.rk4lanes.lane_control`), pending accelerations ``a1``,
    ``status`` and ``steps``; copies only, so the lanes step on bit for bit."""
    for i in range(src.shape[0]):
        a = src[i]
        b = dst[i]
        lanes.copy(T.x[b], S.x[a])
        lanes.copy(T.v[b], S.v[a])
        lanes.copy(T.rest[b], S.rest[a])
        lanes.copy(T.EA[b], S.EA[a])
        lanes.copy(T.f_ext[b], S.f_ext[a])
        lanes.copy(T.ledger[b], S.ledger[a])
        lanes.copy(T.scan[b], S.scan[a])
        lanes.copy(T.active[b], S.active[a])
        lanes.copy(T.refine[b], S.refine[a])
        lanes.copy(T.saved[b], S.saved[a])
        for j in range(F.shape[0]):
            F2[j, b] = F[j, a]
        for j in range(I.shape[0]):
            I2[j, b] = I[j, a]
        lanes.copy(a12[b], a1[a])
        status2[b] = status[a]
        steps2[b] = steps[a]
