"""A prestrain ramp inside the compiled stepping loop: the cable rest lengths of each step of a
ramp (:meth:`solver.simulate.loading.Loading.apply_prestrain` with ``ramp_s`` > 0) and the
actuator's work they book, from the arrays of a :class:`Ramp` record.

:func:`set_rest` does for step ``k`` of a call what the simulation's ``_ramp_to`` does in Python
(the prestrain interpolated at ``t + k dt``, the rest lengths of
:meth:`solver.build.structures.PrestrainMap.rest_lengths`, loaded into the model's data as its
``set_cables`` loads them, the change of energy booked as work), with the same floating-point
operations in the same order, so a ramp stepped here gives the states of the Python one bit for
bit. An integrator's ramped twin (``Integrator.ramped``, e.g.
:func:`solver.integrators.rk4._rk4_ramped`) calls it before each step of one ``dt``.
"""
from __future__ import annotations

from typing import NamedTuple

import math

import numpy as np

from solver.compiled import jit
from solver.kernels import summary

SET = 0           # rest lengths of the ramp set, the ramp goes on
ENDED = 1         # the target's rest lengths set: the ramp is over
ASYMMETRIC = 2    # not set: they break the reduction's symmetry (the simulation expands first)

# clock entries of a Ramp: the simulation's t at the call's start, the ramp's start time and
# duration, dt (all s)
T_CALL, T0, DURATION, DT = 0, 1, 2, 3
REF, SCALE = 0, 1     # book entries: the energy reference and scale J of the balance


class Ramp(NamedTuple):
    """A ramp's arrays. Prestrains per prism (flat, column-major as ``PrestrainMap``):
    ``start``, ``target``, ``p`` (the last set, written), ``p_next`` (scratch). The map:
    ``length`` (n_cables,) m, ``cross`` cable indices with their prism ``cross_prism``, ``count``
    cross cables per prism (float), ``base`` cable indices with the prisms ``below`` and ``above``
    (-1: none) and ``radius`` m; ``EA`` (n_cables,) N. The model's cables: ``cable_map`` full
    cable -> model cable, ``source`` model cable -> the full cable whose value it takes (the last
    one mapped to it, as NumPy's ``r[cable_map] = rest`` leaves it; -1: none). Scratch ``gamma``
    (n_prisms + 1,), ``rest`` (n_cables,); ``clock`` (:data:`T_CALL`...), ``book``
    (:data:`REF`, :data:`SCALE`), read and written."""
    start: np.ndarray
    target: np.ndarray
    p: np.ndarray
    p_next: np.ndarray
    length: np.ndarray
    cross: np.ndarray
    cross_prism: np.ndarray
    count: np.ndarray
    base: np.ndarray
    below: np.ndarray
    above: np.ndarray
    radius: np.ndarray
    EA: np.ndarray
    cable_map: np.ndarray
    source: np.ndarray
    gamma: np.ndarray
    rest: np.ndarray
    clock: np.ndarray
    book: np.ndarray


@jit
def _prestrain_at(r, k):
    """The ramp's prestrain at ``t + k dt`` into ``r.p_next``; whether the ramp has ended."""
    c = r.clock
    t = c[T_CALL] + k * c[DT]
    u = (t - c[T0]) / c[DURATION]
    if u >= 1.0:
        for i in range(r.target.shape[0]):
            r.p_next[i] = r.target[i]
        return True
    f = u
    if 0.0 > u:                     # Python's max(u, 0.0)
        f = 0.0
    for i in range(r.start.shape[0]):
        r.p_next[i] = r.start[i] + f * (r.target[i] - r.start[i])
    return False


@jit
def _rest_lengths(r):
    """``PrestrainMap.rest_lengths(p_next, EA)`` into ``r.rest``, operation for operation."""
    p, rest, length, g = r.p_next, r.rest, r.length, r.gamma
    for i in range(g.shape[0]):
        g[i] = 0.0
    for j in range(r.cross.shape[0]):
        c = r.cross[j]
        q = r.cross_prism[j]
        s = length[c]
        rest[c] = s / (1.0 + p[q])
        g[q] += r.EA[c] * p[q] / s          # np.bincount: in cable order
    for i in range(r.count.shape[0]):
        g[i] = g[i] / r.count[i]
    for j in range(r.base.shape[0]):
        c = r.base[j]
        a, b = r.below[j], r.above[j]
        t = ((g[a] if a >= 0 else 0.0) + (g[b] if b >= 0 else 0.0)) * r.radius[j]
        rest[c] = r.EA[c] * length[c] / (r.EA[c] + t)


@jit
def _symmetric(r):
    """Whether the model's cables hold ``r.rest``: ``sym3d``'s ``set_cables`` test (a rest
    length off its model cable's value by more than 1e-12 of the largest fails; NaN passes, as
    there)."""
    rest, cmap, src = r.rest, r.cable_map, r.source
    worst, top, nan = 0.0, 0.0, False
    for i in range(cmap.shape[0]):
        j = src[cmap[i]]
        diff = abs((rest[j] if j >= 0 else 0.0) - rest[i])
        size = abs(rest[i])
        if diff != diff or size != size:
            nan = True
        worst = max(worst, diff)
        top = max(top, size)
    return nan or not worst > 1e-12 * top


@jit
def set_rest(m, d, r, k):
    """Step ``k`` of the call: the rest lengths of the ramp at ``t + k dt`` into the data ``d``
    of the model ``m`` (the energy before and after: the simulation's ``energy()``, from
    :func:`solver.kernels.summary.energy_parts` with the cables' term evaluated at both; the
    change booked as work: ``ref += after - before``, ``scale = max(scale, |after|, |ref|)``), the
    prestrain into ``r.p``. Returns :data:`SET`, :data:`ENDED` or :data:`ASYMMETRIC` (nothing
    changed)."""
    went = next_rest(r, k)
    if went == ASYMMETRIC:
        return ASYMMETRIC
    a, cables, extra, touch = summary.energy_parts(d.x, d.v, m, d)
    before = summary.energy_sum(m, a, cables, extra, touch)
    load(d, r)
    after = summary.energy_sum(m, a, summary.cable_energy(d.x, m, d), extra, touch)
    book(r, before, after)
    return went


@jit
def next_rest(r, k):
    """The first part of :func:`set_rest`: the rest lengths at step ``k`` into ``r.rest``;
    :data:`SET`, :data:`ENDED` or :data:`ASYMMETRIC` (then :func:`load` and :func:`book` are
    not to follow)."""
    ended = _prestrain_at(r, k)
    _rest_lengths(r)
    if not _symmetric(r):
        return ASYMMETRIC
    return ENDED if ended else SET


@jit
def load(d, r):
    """The rest lengths of :func:`next_rest` and the EA into the data ``d``, as the model's
    ``set_cables`` loads them."""
    for j in range(d.rest.shape[0]):
        i = r.source[j]
        d.rest[j] = r.rest[i] if i >= 0 else 0.0
        d.EA[j] = r.EA[i] if i >= 0 else 0.0


@jit
def book(r, before, after):
    """The work of a :func:`load` that took the energy from ``before`` to ``after`` J:
    ``ref += after - before``, ``scale = max(scale, |after|, |ref|)``; the prestrain of
    :func:`next_rest` kept in ``r.p``."""
    b = r.book
    b[REF] += after - before
    scale = b[SCALE]                 # Python's max(scale, |after|, |ref|)
    if abs(after) > scale:
        scale = abs(after)
    if abs(b[REF]) > scale:
        scale = abs(b[REF])
    b[SCALE] = scale
    for i in range(r.p.shape[0]):
        r.p[i] = r.p_next[i]


@jit
def finish(m, d, k, taken, status, went, heights, summarise):
    """What a ramped call returns: ``(steps done, the kernel's steps, status, what the last
    set_rest returned, summarise)`` and, with ``summarise`` (the call ends at the end of the
    interval), :func:`solver.kernels.summary.state_summary` of the end state (prism heights
    into ``heights``), else ``(False, NaN, NaN, NaN)``."""
    if summarise:
        return (k, taken, status, went, True) + summary.state_summary(d.x, d.v, m, d, heights)
    return (k, taken, status, went, False, False, math.nan, math.nan, math.nan)


def source_of(cable_map, n_model):
    """Model cable -> the full cable whose value ``r[cable_map] = rest`` leaves in it (-1:
    none)."""
    src = np.full(n_model, -1, dtype=np.int64)
    src[cable_map] = np.arange(len(cable_map), dtype=np.int64)
    return src


# The ramps of B lanes of one model (:func:`stack`): the fields of :class:`Ramp`, those a lane
# has of its own stacked (B, ...) (:data:`OWN`), the map and the scratch shared (the lanes share
# the network).
LaneRamp = NamedTuple('LaneRamp', [(f, np.ndarray) for f in Ramp._fields])


OWN = ('start', 'target', 'p', 'p_next', 'EA', 'clock', 'book')    # a lane's own fields


def shared_part(r):
    """The fields of the :class:`Ramp` ``r`` that the lanes of one :class:`LaneRamp` share
    (the map), in field order."""
    return tuple(getattr(r, f) for f in Ramp._fields if f not in OWN)


def stack(records):
    """The :class:`LaneRamp` of the :class:`Ramp` records of B lanes (copies; the shared fields
    from the first, which the others must equal: :func:`shared_part`)."""
    first = records[0]
    return LaneRamp(*(np.stack([getattr(r, f) for r in records]) if f in OWN
                      else getattr(first, f).copy() for f in Ramp._fields))


@jit
def lane_ramp(R, k):
    """Lane ``k``'s :class:`Ramp` (views into ``R``)."""
    return Ramp(R.start[k], R.target[k], R.p[k], R.p_next[k], R.length, R.cross, R.cross_prism,
                R.count, R.base, R.below, R.above, R.radius, R.EA[k], R.cable_map, R.source,
                R.gamma, R.rest, R.clock[k], R.book[k])


# The ramps' steps over lanes (:func:`next_rests`): each lane performs the operations of
# :func:`next_rest` and :func:`load` on its own ramp in the same order, the lane index innermost.
class LaneRest(NamedTuple):
    """Lane-inner scratch of :func:`next_rests` for B lanes: ``p`` (n_prisms, B) the
    prestrains, ``gamma`` (n_gamma, B), ``rest`` and ``EA`` (n_cables, B) of the full network,
    per lane (B,) ``f`` the ramp's fraction, ``ended``, ``worst``, ``top``, ``nan``; ``E``
    (4, B) the energy terms a ramp's step books."""
    p: np.ndarray
    gamma: np.ndarray
    rest: np.ndarray
    EA: np.ndarray
    f: np.ndarray
    ended: np.ndarray
    worst: np.ndarray
    top: np.ndarray
    nan: np.ndarray
    E: np.ndarray


def lane_rest(R):
    """The :class:`LaneRest` of the :class:`LaneRamp` ``R``: its EA lane-inner, its rest lengths
    the scratch's."""
    b = R.p.shape[0]
    f = np.zeros(b)
    return LaneRest(np.zeros((R.p.shape[1], b)), np.zeros((R.gamma.shape[0], b)),
                    np.repeat(R.rest[:, None], b, axis=1), np.ascontiguousarray(R.EA.T),
                    f, np.zeros(b, np.int64), f.copy(), f.copy(), np.zeros(b, np.int64),
                    np.zeros((4, b)))


@jit
def next_rests(R, Q, k, go, went):
    """:func:`next_rest` of step ``k`` for each lane whose ``go`` is set, over lanes: the
    prestrains into ``Q.p`` (and ``R.p_next``), the rest lengths into ``Q.rest``, what it
    returns into ``went``."""
    n_lanes = go.shape[0]
    p, g, rest, EA, length = Q.p, Q.gamma, Q.rest, Q.EA, R.length
    for k2 in range(n_lanes):               # _prestrain_at
        c = R.clock[k2]
        t = c[T_CALL] + k * c[DT]
        u = (t - c[T0]) / c[DURATION]
        Q.ended[k2] = 1 if u >= 1.0 else 0
        f = u
        if 0.0 > u:                         # Python's max(u, 0.0)
            f = 0.0
        Q.f[k2] = f
    for i in range(p.shape[0]):
        for k2 in range(n_lanes):
            a = R.start[k2, i]
            p[i, k2] = R.target[k2, i] if Q.ended[k2] else a + Q.f[k2] * (R.target[k2, i] - a)
    for i in range(g.shape[0]):             # _rest_lengths
        for k2 in range(n_lanes):
            g[i, k2] = 0.0
    for j in range(R.cross.shape[0]):
        c = R.cross[j]
        q = R.cross_prism[j]
        s = length[c]
        for k2 in range(n_lanes):
            rest[c, k2] = s / (1.0 + p[q, k2])
            g[q, k2] += EA[c, k2] * p[q, k2] / s
    for i in range(R.count.shape[0]):
        n = R.count[i]
        for k2 in range(n_lanes):
            g[i, k2] = g[i, k2] / n
    for j in range(R.base.shape[0]):
        c = R.base[j]
        a, b = R.below[j], R.above[j]
        r = R.radius[j]
        for k2 in range(n_lanes):
            t = ((g[a, k2] if a >= 0 else 0.0) + (g[b, k2] if b >= 0 else 0.0)) * r
            rest[c, k2] = EA[c, k2] * length[c] / (EA[c, k2] + t)
    cmap, src = R.cable_map, R.source
    for k2 in range(n_lanes):               # _symmetric
        Q.worst[k2] = 0.0
        Q.top[k2] = 0.0
        Q.nan[k2] = 0
    for i in range(cmap.shape[0]):
        j = src[cmap[i]]
        for k2 in range(n_lanes):
            diff = abs((rest[j, k2] if j >= 0 else 0.0) - rest[i, k2])
            size = abs(rest[i, k2])
            if diff != diff or size != size:
                Q.nan[k2] = 1
            Q.worst[k2] = max(Q.worst[k2], diff)
            Q.top[k2] = max(Q.top[k2], size)
    for k2 in range(n_lanes):
        if go[k2] == 0:
            continue
        for i in range(p.shape[0]):
            R.p_next[k2, i] = p[i, k2]
        if Q.nan[k2] or not Q.worst[k2] > 1e-12 * Q.top[k2]:
            went[k2] = ENDED if Q.ended[k2] else SET
        else:
            went[k2] = ASYMMETRIC


@jit
def load_lanes(R, Q, go, went, rest, EA, S_rest, S_EA):
    """:func:`load` of each lane whose ``go`` is set and whose :func:`next_rests` set its rest
    lengths: into the lane-inner ``rest`` and ``EA`` (n_model_cables, B) and the lane-outer
    ``S_rest`` and ``S_EA`` (B, n_model_cables)."""
    n_lanes = go.shape[0]
    for j in range(rest.shape[0]):
        i = R.source[j]
        for k2 in range(n_lanes):
            if go[k2] != 0 and went[k2] != ASYMMETRIC:
                r = Q.rest[i, k2] if i >= 0 else 0.0
                e = Q.EA[i, k2] if i >= 0 else 0.0
                rest[j, k2] = r
                EA[j, k2] = e
                S_rest[k2, j] = r
                S_EA[k2, j] = e
