"""Classical RK4 over lanes (:mod:`solver.kernels.lanes`): B instances of one model stepped
together, each lane's operations those of :func:`solver.integrators.rk4._rk4_run` on that
instance, in the same order, so each lane equals its single run bit for bit.

- :func:`rk4_projected_run`: the plain network with every effect off, all lanes on one clock
  (``rk4_projected`` without kinks; the kernels' own test and bench).
- :func:`rounds` (with :func:`begin`, :func:`end` and their checked forms): every effect, each
  lane on its own clock with its own steps (see :func:`rounds`); the lane groups of
  :mod:`solver.simulate.lanebatch` call them.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from solver.compiled import jit_lanes
from solver.integrators.rk4 import REFINE_COARSEN, REFINE_LEVELS, REFINE_SHARE
from solver.kernels import effects, lanechunk, lanedata, lanes, lanesteps, summary
from solver.status import OK


@jit_lanes
def rk4_step(x, v, h, a1, topo, d, w, status):
    """One classical RK4 step of size h of each lane, given its first-stage accelerations ``a1``;
    the new state is written to ``x``, ``v`` of the lanes whose ``status`` is still ``OK`` after
    the three further evaluations (:func:`solver.integrators.rk4._rk4_step` without effects)."""
    n = x.shape[0]
    n_lanes = x.shape[2]
    # the element-wise updates as loops over whole arrays (each entry's operations are those of
    # the scalar step)
    x1, v1, b1 = x.reshape(-1), v.reshape(-1), a1.reshape(-1)
    xs, vs, acc = w.xs.reshape(-1), w.vs.reshape(-1), w.acc.reshape(-1)
    xacc, vacc = w.xacc.reshape(-1), w.vacc.reshape(-1)
    for j in range(x1.shape[0]):
        xacc[j] = v1[j]
        vacc[j] = b1[j]
        xs[j] = x1[j] + 0.5 * h * v1[j]
        vs[j] = v1[j] + 0.5 * h * b1[j]
    for stage in range(1, 4):
        lanes.accelerations(w.xs, w.vs, topo, d, w, w.acc, status)
        wt = 1.0 if stage == 3 else 2.0
        c = 0.5 * h if stage == 1 else h
        for j in range(x1.shape[0]):
            xacc[j] += wt * vs[j]
            vacc[j] += wt * acc[j]
        if stage < 3:
            for j in range(x1.shape[0]):
                xs[j] = x1[j] + c * vs[j]
                vs[j] = v1[j] + c * acc[j]
    go, xa, va = w.go, w.xacc, w.vacc
    for k in range(n_lanes):
        go[k] = 1 if status[k] == OK else 0
    for p in range(n):
        for i in range(3):
            for k in range(n_lanes):
                x[p, i, k] = x[p, i, k] + h / 6.0 * xa[p, i, k] if go[k] != 0 else x[p, i, k]
                v[p, i, k] = v[p, i, k] + h / 6.0 * va[p, i, k] if go[k] != 0 else v[p, i, k]


@jit_lanes
def rk4_projected_run(topo, d, w, dt, n_steps, tol, max_iter, status, steps):
    """Advance each lane's ``d.x``, ``d.v`` by ``n_steps * dt`` with classical RK4, positions and
    velocities projected on the rigid members after every step, all lanes on one clock (the
    steps of :func:`solver.integrators.rk4._rk4_run`). A lane that fails (a singular constraint
    matrix, a projection that does not converge, a state that is not finite) keeps its code in
    ``status`` and its state from the moment it failed; the other lanes go on. ``steps`` (B,)
    counts each lane's steps taken. Returns the number of lanes still ``OK``."""
    x, v, a1 = d.x, d.v, w.a1
    n_lanes = x.shape[2]
    total = n_steps * dt
    t = 0.0
    left = 0
    for k in range(n_lanes):
        if status[k] == OK:
            left += 1
    while left > 0 and total - t > 1e-9 * dt:
        h = min(dt, total - t)
        lanes.accelerations(x, v, topo, d, w, a1, status)
        rk4_step(x, v, h, a1, topo, d, w, status)
        lanes.project_positions(x, topo, w, tol, max_iter, status)
        lanes.project_velocities(x, v, topo, w, status)
        lanes.check_finite(x, v, w.piv, status)
        left = 0
        for k in range(n_lanes):
            if status[k] == OK:
                steps[k] += 1
                left += 1
        t += h
    return left


# -- the checked run with every effect: lanes on their own clocks -------------------------------
class LaneControl(NamedTuple):
    """Each lane's step control (B,): its clock ``t``, the step ``h`` of the current round, the
    step before the contact limit ``h_free``, the shorter step ``h2`` after a trial that was not
    kept, the ledger energy ``e0`` at the step's start, the run state :func:`effects.mark` kept
    (``met``, ``p0``, ``d0``), the trial's ``known`` motion and the state
    :func:`effects.begin_trial` kept (``tb``, ``tp``, ``td``, ``tf``), the work of the damping
    ``work``; int64 (B,): the halving levels ``level``, ``clevel``, whether the steps are
    refined ``refine``, the round's ``mode`` (0 plain step, 1 trial, 2 trial not kept), ``live``
    (the lane steps in the current round) and ``go`` (the lane takes the step being computed),
    the status ``st`` of the current round and ``ev`` (the lanes an evaluation computes for:
    ``go`` and ``st`` still ``OK``, as a single run stops evaluating at its first failure).
    Scratch of a round: each lane's step to its next kink ``hk``, the ledger energy at its
    step's end ``e1`` and a mask ``mk``, a coefficient per lane ``cs``, the nodes of the
    largest speed ``nv`` and acceleration ``na`` (int64) and their squares ``r2``."""
    t: np.ndarray
    h: np.ndarray
    h_free: np.ndarray
    h2: np.ndarray
    e0: np.ndarray
    met: np.ndarray
    p0: np.ndarray
    d0: np.ndarray
    known: np.ndarray
    tb: np.ndarray
    tp: np.ndarray
    td: np.ndarray
    tf: np.ndarray
    work: np.ndarray
    level: np.ndarray
    clevel: np.ndarray
    refine: np.ndarray
    mode: np.ndarray
    live: np.ndarray
    go: np.ndarray
    st: np.ndarray
    ev: np.ndarray
    hk: np.ndarray
    e1: np.ndarray
    mk: np.ndarray
    cs: np.ndarray
    nv: np.ndarray
    na: np.ndarray
    r2: np.ndarray


_COUNTS = {'level', 'clevel', 'refine', 'mode', 'live', 'go', 'st', 'ev', 'mk', 'nv', 'na'}


def lane_control(lanes_n):
    """A zeroed :class:`LaneControl` of ``lanes_n`` lanes, and the two arrays its fields are
    rows of: the float fields' (n_float, B) and the int64 fields' (n_int, B) (a block of lanes
    moves in two copies: :meth:`solver.simulate.lanebatch._Block.take`)."""
    floats = np.zeros((len(LaneControl._fields) - len(_COUNTS), lanes_n))
    ints = np.zeros((len(_COUNTS), lanes_n), np.int64)
    f, i = iter(floats), iter(ints)
    return (LaneControl(*(next(i) if name in _COUNTS else next(f)
                          for name in LaneControl._fields)), floats, ints)


@jit_lanes
def _stage_power(S, C, weight):
    for k in range(C.go.shape[0]):
        if C.go[k] != 0:
            C.work[k] += weight * effects.power(lanedata.lane_record(S, k))


@jit_lanes
def step(m, S, L, W, X, C, a1, h):
    """One classical RK4 step of each lane whose ``C.go`` is set, of its own size ``h[k]``,
    given its first-stage accelerations ``a1`` (:func:`solver.integrators.rk4._rk4_step` per
    lane). The new state is written to ``L.x``, ``L.v`` of the lanes that take the step and
    whose ``C.st`` stays ``OK``; the damping's work is booked in their ledger."""
    x, v = L.x, L.v
    n_lanes = C.go.shape[0]
    xs, vs, acc, xacc, vacc = W.xs, W.vs, W.acc, W.xacc, W.vacc
    n = x.shape[0]
    for k in range(n_lanes):
        if C.go[k] != 0:
            C.work[k] = effects.power(lanedata.lane_record(S, k))
    # the element-wise updates over (n * 3, B) rows, each lane's coefficient from a (B,) array
    # (the operations of the scalar step: x + (0.5 h) v, x + c v, x + (h / 6) xacc). The sums
    # xacc, vacc start from v, a1 where the scalar step copies them (v + 2 vs is v copied plus
    # 2 vs), and the last one is added in the loop of the step's end: fewer passes over memory
    shape = (n * 3, n_lanes)
    rows = shape[0]
    x2, v2, a2 = x.reshape(shape), v.reshape(shape), a1.reshape(shape)
    xs2, vs2, ac2 = xs.reshape(shape), vs.reshape(shape), acc.reshape(shape)
    xa2, va2 = xacc.reshape(shape), vacc.reshape(shape)
    c = C.cs
    for k in range(n_lanes):
        c[k] = 0.5 * h[k]
    for j in range(rows):
        for k in range(n_lanes):
            xs2[j, k] = x2[j, k] + c[k] * v2[j, k]
            vs2[j, k] = v2[j, k] + c[k] * a2[j, k]
    for stage in range(1, 3):
        lanedata.evaluate(xs, vs, m, S, L, W, X, C, acc)
        _stage_power(S, C, 2.0)
        for k in range(n_lanes):
            c[k] = 0.5 * h[k] if stage == 1 else h[k]
        if stage == 1:
            for j in range(rows):
                for k in range(n_lanes):
                    xa2[j, k] = v2[j, k] + 2.0 * vs2[j, k]
                    va2[j, k] = a2[j, k] + 2.0 * ac2[j, k]
                    xs2[j, k] = x2[j, k] + c[k] * vs2[j, k]
                    vs2[j, k] = v2[j, k] + c[k] * ac2[j, k]
            continue
        for j in range(rows):
            for k in range(n_lanes):
                xa2[j, k] += 2.0 * vs2[j, k]
                va2[j, k] += 2.0 * ac2[j, k]
                xs2[j, k] = x2[j, k] + c[k] * vs2[j, k]
                vs2[j, k] = v2[j, k] + c[k] * ac2[j, k]
    lanedata.evaluate(xs, vs, m, S, L, W, X, C, acc)
    _stage_power(S, C, 1.0)
    go = W.go
    for k in range(n_lanes):
        go[k] = 1 if C.go[k] != 0 and C.st[k] == OK else 0
        c[k] = h[k] / 6.0
    for j in range(rows):
        for k in range(n_lanes):
            xa = xa2[j, k] + 1.0 * vs2[j, k]
            va = va2[j, k] + 1.0 * ac2[j, k]
            x2[j, k] = x2[j, k] + c[k] * xa if go[k] != 0 else x2[j, k]
            v2[j, k] = v2[j, k] + c[k] * va if go[k] != 0 else v2[j, k]
    for k in range(n_lanes):
        if go[k] != 0:
            effects.dissipate(lanedata.lane_record(S, k), h[k] / 6.0 * C.work[k])


@jit_lanes
def begin(m, S, L, C, status, steps):
    """The start of a call: ``L`` from ``S``, every clock at 0, and for each lane whose
    ``status`` is ``OK`` the effects' start and its halving levels (as
    :func:`solver.integrators.rk4._rk4_run` begins)."""
    lanedata.enter(S, L)
    for k in range(status.shape[0]):
        lanechunk.start_lane(m, S, C, k, steps, status[k] == OK)


@jit_lanes
def end(m, S, C, status):
    """The end of a call: the effects' finish and the halving levels kept, for each lane that
    ended ``OK``."""
    for k in range(status.shape[0]):
        if status[k] == OK:
            lanechunk.end_lane(m, S, C, k)


@jit_lanes
def rounds(m, S, L, W, X, C, w0, dt, total, tol, max_iter, kinks, project, status, steps,
           min_live, ch):
    """Step each lane whose ``status`` is ``OK`` until its clock ``C.t`` reaches ``total`` s, as
    :func:`solver.integrators.rk4._rk4_run` steps one instance, every lane on its own clock with
    its own steps (kink landing, contact steps, trials, refinement against the ledger). The
    lanes take their rounds together: in a round each lane takes (or retakes) one step; its
    force evaluations run over all lanes at once, its step control runs lane by lane on the
    scalar kernels (the lane's data in ``S``; its positions and velocities live in the
    lane-inner copy ``L``, which the step limits and the contact scans read through views of
    the lane, and are copied into ``S`` only where a scalar kernel reads them there: a refined
    step's start, a trial; ``C`` holds each lane's step control and ``X.a1`` the accelerations
    a pending step starts from). On return ``S`` holds every lane's state. A lane that fails
    keeps its code in ``status`` and stops; ``steps`` counts each lane's steps. Returns 0 when
    every lane is done, or the number of lanes still stepping once it is below ``min_live`` (at
    the end of a round: the caller moves them to fewer lanes, :mod:`solver.simulate.lanebatch`,
    and calls again). ``ch``: the :class:`~solver.kernels.lanechunk.Chunk` of
    :func:`chunk_run` (a lane at the end of an interval with more to go goes on with the next),
    or an empty one."""
    n_lanes = status.shape[0]
    bars = effects.has_bar_contact(m)
    chunked = ch.todo.shape[0] != 0
    while True:
        left = 0
        for k in range(n_lanes):
            if (chunked and ch.todo[k] > 0 and status[k] == OK
                    and not total - C.t[k] > 1e-9 * dt):
                lanechunk.at_end(m, S, L, C, ch, k, steps)
            C.live[k] = 1 if status[k] == OK and total - C.t[k] > 1e-9 * dt else 0
            left += C.live[k]
        if left == 0 or left < min_live:
            lanedata.leave(L, S)
            return left
        # the step's start, lane by lane; a lane whose trial was not kept (mode 2) takes the
        # shorter step from the same start, with the same first-stage accelerations
        for k in range(n_lanes):
            pending = C.mode[k] == 2
            C.go[k] = C.live[k] if not pending else 0
            C.st[k] = OK if C.live[k] != 0 else -1
            if C.live[k] == 0 or pending:
                continue
            C.mode[k] = 0
            d = lanedata.lane_record(S, k)
            w = lanedata.lane_work_record(w0, S, k)
            refine = effects.refining(m, d)
            C.refine[k] = 1 if refine else 0
            if not refine:
                C.level[k] = 0
                C.clevel[k] = 0
            C.h[k] = min(dt * 0.5 ** C.level[k], total - C.t[k])
            met, p0, d0 = effects.mark(d)
            C.met[k] = met
            C.p0[k] = p0
            C.d0[k] = d0
            if refine:
                lanedata.sync_out(L, S, k)      # the step's start, read in S
                effects.save_start(d.x, d.v, w)
                if C.e0[k] != C.e0[k]:
                    C.e0[k] = effects.ledger_energy(d.x, d.v, m, d)
        lanedata.evaluate(L.x, L.v, m, S, L, W, X, C, W.a1)
        # where the step ends: the next kink over lanes, then lane by lane (_controlled_step's
        # plan)
        for k in range(n_lanes):
            C.mk[k] = 1 if C.go[k] != 0 and C.st[k] == OK else 0
            C.hk[k] = C.h[k]
        if kinks:
            lanesteps.next_kink_lanes(L.x, L.v, W.a1, m, L.rest, C.h, 1e-3 * dt, C.mk, C.hk)
        if bars:                        # the nodes of the largest speed and acceleration
            lanesteps.largest_nodes(L.v, C.nv, C.r2)
            lanesteps.largest_nodes(W.a1, C.na, C.r2)
        for k in range(n_lanes):
            if C.mode[k] == 2 and C.live[k] != 0:
                lanedata.lane_in(X.a1[k], k, W.a1)
                C.h[k] = C.h2[k]
                C.go[k] = 1
                continue
            if C.go[k] == 0 or C.st[k] != OK:
                C.go[k] = 0
                continue
            d = lanedata.lane_record(S, k)
            xk, vk, ak = L.x[:, :, k], L.v[:, :, k], W.a1[:, :, k]     # views of the lane
            h = effects.fixed_step_limit(xk, vk, ak, m, C.hk[k])
            C.h_free[k] = h
            if bars:
                # those nodes alone bound the motion as the whole lane does: where no contact
                # can start within h, the scan needs no more (X.a1[k] is free scratch here)
                vp, ap = X.a1[k, 0:1], X.a1[k, 1:2]
                lanesteps.node_of(L.v, C.nv, k, vp)
                lanesteps.node_of(W.a1, C.na, k, ap)
                if effects.surely_clear(vp, ap, d, h):
                    vk, ak = vp, ap
                else:
                    # the scan reads the lane's nodes over and over: from contiguous copies
                    # (the step's start in S, as a refined step keeps it there already)
                    if C.refine[k] == 0:
                        lanedata.sync_out(L, S, k)
                    lanedata.lane_out(W.a1, k, X.a1[k])
                    xk, vk, ak = d.x, d.v, X.a1[k]
            h_c, trial, known = effects.plan(xk, vk, ak, m, d, h, C.met[k], 0.5 ** C.clevel[k])
            if h_c >= h:
                C.h[k] = h
            elif trial:             # after a scan: X.a1[k] and S hold the step's start
                w = lanedata.lane_work_record(w0, S, k)
                tb, tp, td, tf = effects.begin_trial(d.x, d.v, d, w)
                C.tb[k] = tb
                C.tp[k] = tp
                C.td[k] = td
                C.tf[k] = tf
                C.known[k] = known
                C.h[k] = h
                C.h2[k] = h_c
                C.mode[k] = 1
            else:
                C.h[k] = h_c
        step(m, S, L, W, X, C, W.a1, C.h)
        # a step tried whole: kept, or undone (the shorter step follows in the next round)
        for k in range(n_lanes):
            if C.mode[k] == 2:
                C.mode[k] = 0           # taken in the current round
                continue
            if C.mode[k] != 1:
                continue
            d = lanedata.lane_record(S, k)
            w = lanedata.lane_work_record(w0, S, k)
            trial = (C.tb[k], C.tp[k], C.td[k], C.tf[k])
            C.mode[k] = 0
            if C.st[k] == OK:
                lanedata.sync_out(L, S, k)
                if effects.trial_kept(d.x, d.v, X.a1[k], m, d, w, C.h[k], C.known[k], trial):
                    continue
            effects.undo_trial(d.x, d.v, d, w, trial)
            lanedata.sync_in(L, S, k)
            C.st[k] = -1                # no projection, no end of step in the current round
            C.mode[k] = 2
        if project:
            lanes.project_positions(L.x, m.topo, W, tol, max_iter, C.st)
            lanes.project_velocities(L.x, L.v, m.topo, W, C.st)
        lanes.check_finite(L.x, L.v, W.piv, C.st)
        # the step's end: the ledger energy over lanes, then lane by lane: failed, retaken at
        # half its length, or done
        marked = 0
        for k in range(n_lanes):
            C.mk[k] = 1 if (C.live[k] != 0 and C.mode[k] != 2 and C.st[k] == OK
                            and C.refine[k] != 0) else 0
            marked += C.mk[k]
        if marked != 0:
            lanedata.ledger_energies(m, S, L, C.mk, C.e1, W.tmp)
        for k in range(n_lanes):
            if C.live[k] == 0 or C.mode[k] == 2:
                continue
            if C.st[k] != OK:
                status[k] = C.st[k]
                continue
            d = lanedata.lane_record(S, k)
            h = C.h[k]
            if C.refine[k] != 0:
                e1 = C.e1[k]
                e0 = C.e0[k]
                err = abs(e1 + (effects.dissipated(d) - C.d0[k]) - e0)
                budget = REFINE_SHARE * effects.rate(m) * h * abs(e0)
                limited = h < C.h_free[k]
                lv = C.clevel[k] if limited else C.level[k]
                if err > budget and lv < REFINE_LEVELS:
                    w = lanedata.lane_work_record(w0, S, k)
                    effects.back_to(d.x, d.v, d, w, (C.met[k], C.p0[k], C.d0[k]))
                    lanedata.sync_in(L, S, k)
                    if limited:
                        C.clevel[k] += 1
                    else:
                        C.level[k] += 1
                    continue
                if err < REFINE_COARSEN * budget:
                    if limited and C.clevel[k] > 0:
                        C.clevel[k] -= 1
                    elif not limited and C.level[k] > 0:
                        C.level[k] -= 1
                C.e0[k] = e1
            C.t[k] += h
            steps[k] += 1


@jit_lanes
def chunk_run(m, S, L, W, X, C, w0, dt, n_steps, tol, max_iter, kinks, project, status, steps,
              ch):
    """``ch.todo[k]`` intervals of ``n_steps * dt`` of each lane whose ``status`` is ``OK``, in
    one call (:mod:`solver.kernels.lanechunk`): every lane steps its own intervals as
    :func:`begin_checked`, :func:`rounds` and :func:`end_checked` would step each (the same
    steps, bit for bit), its data kept in ``ch`` at each interval's start and end, with the
    state summary and steps of each interval. A lane that fails stops with its code in
    ``status`` after ``ch.done[k]`` intervals."""
    lanedata.keep(S, lanechunk.kept(ch, 0, S.saved), status)
    begin(m, S, L, C, status, steps)
    for k in range(status.shape[0]):
        ch.done[k] = 0
        if status[k] != OK:
            ch.todo[k] = 0
    rounds(m, S, L, W, X, C, w0, dt, n_steps * dt, tol, max_iter, kinks, project, status,
           steps, 0, ch)


@jit_lanes
def begin_checked(m, S, L, C, status, steps, kept):
    """:func:`begin` after a copy of every running lane's data into ``kept`` (a
    :class:`~solver.kernels.lanedata.LaneState`: the data to restore)."""
    lanedata.keep(S, kept, status)
    begin(m, S, L, C, status, steps)


@jit_lanes
def end_checked(m, S, L, W, C, status, out, heights, fresh):
    """:func:`end`, then the state summary of each lane
    (:func:`solver.kernels.summary.state_summary`) into ``out`` (B, 4: finite, energy J,
    constraint error, smallest prism height m) and ``heights`` (B, n_columns, n_prisms): with
    :func:`begin_checked` the per-lane twin of :func:`solver.integrators.rk4._rk4_checked`. The
    energy without contact, the constraint error and the finiteness over lanes on ``L``
    (``fresh``: ``L`` holds the state of ``S``; else it is copied in first), the rest lane by
    lane."""
    end(m, S, C, status)
    n_lanes = status.shape[0]
    if m.summary.node_mass.shape[0] == 0:       # no summary arrays: the scalar kernel
        for k in range(n_lanes):
            lanechunk.put_summary(m, lanedata.lane_record(S, k), out[k], heights[k])
        return
    if not fresh:
        lanedata.to_lanes(S.x, L.x)
        lanedata.to_lanes(S.v, L.v)
    for k in range(n_lanes):
        C.mk[k] = 1
    lanesteps.step_energy_lanes(L.x, L.v, m, L.rest, L.EA, L.f_ext, C.mk, C.e1, W.tmp)
    lanesteps.constraint_error_lanes(L.x, m.topo, C.hk)
    lanes.check_finite(L.x, L.v, C.cs, C.mk)     # C.mk: 1 (OK is 0) stays 1
    for k in range(n_lanes):
        d = lanedata.lane_record(S, k)
        e = effects.with_contact_energy(C.e1[k], d.x, m, d)
        out[k, 0] = 1.0 if C.cs[k] == 0.0 else 0.0
        out[k, 1] = e
        out[k, 2] = C.hk[k]
        out[k, 3] = summary.level_heights(d.x, m.summary.levels, heights[k])
