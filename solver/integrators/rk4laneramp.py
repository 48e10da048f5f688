"""Prestrain ramps over lanes: :func:`ramped` steps B lanes of one model, each with its own
ramp (:class:`solver.kernels.ramp.LaneRamp`), as :func:`solver.integrators.rk4._rk4_ramped`
steps one instance: before each step of ``dt`` the lane's rest lengths of its ramp at that
time and the work they book (:func:`set_rests`: what :func:`solver.kernels.ramp.set_rest` does
for one instance, its energies over lanes), then the step as a call of one ``dt`` (as
:func:`solver.integrators.rk4lanes.begin`, ``rounds`` and ``end`` over the lanes still
ramping; the lane-inner copies are made once, and the rest lengths set in both copies), so
each lane equals its single run bit for bit. A lane stops where its single call
stops: after the step whose rest lengths end its ramp, after a failed step, before rest
lengths that break its model's symmetry, at the end of the interval; the simulation takes the
rest of its interval by itself (:meth:`solver.simulate.simulation.Simulation._integrate`).
"""
from __future__ import annotations

from solver.compiled import jit_lanes
from solver.integrators import rk4lanes
from solver.kernels import lanechunk, lanedata, lanesteps, ramp, summary
from solver.status import OK

IDLE = -99          # the status of a lane that does not take the present step


@jit_lanes
def ramped(m, S, L, W, X, C, w0, dt, n_steps, tol, max_iter, kinks, project, R, ch, status,
           st, steps, done, taken, went, made, out, heights, Q):
    """``n_steps`` steps of ``dt`` of each lane whose ``status`` is ``OK``, its ramp's rest
    lengths set before each (see the module's text; the ramp's ``clock`` and ``book`` rows set
    by the caller). Per lane (B,): ``done`` the steps done, ``taken`` the integrator's steps,
    ``status`` the status, ``went`` what the last :func:`~solver.kernels.ramp.set_rest`
    returned, ``made`` 1 where the lane reached the end of the interval (its state summary in
    ``out`` (B, 4) and ``heights``: :func:`solver.kernels.lanechunk.put_summary`). ``st``,
    ``steps`` (B,) scratch, ``Q`` the ramps' :class:`~solver.kernels.ramp.LaneRest`; ``ch``
    an empty :class:`~solver.kernels.lanechunk.Chunk`."""
    n_lanes = status.shape[0]
    for j in range(n_lanes):
        done[j] = -1
        taken[j] = 0
        went[j] = ramp.SET
        made[j] = 0
    lanedata.enter(S, L)        # kept up to date from here: rounds ends with S from L
    for k in range(n_steps + 1):
        for j in range(n_lanes):
            C.mk[j] = 1 if status[j] == OK and done[j] < 0 else 0
        set_rests(m, S, L, R, Q, k, C.mk, went, W.tmp)
        going = 0
        for j in range(n_lanes):
            st[j] = IDLE
            if C.mk[j] == 0:
                continue
            if went[j] == ramp.ASYMMETRIC or k == n_steps:
                done[j] = k
                if went[j] != ramp.ASYMMETRIC:
                    lanechunk.put_summary(m, lanedata.lane_record(S, j), out[j], heights[j])
                    made[j] = 1
                continue
            st[j] = OK
            going += 1
        if going == 0:
            return
        for j in range(n_lanes):        # rk4lanes.begin, its copies already made
            lanechunk.start_lane(m, S, C, j, steps, st[j] == OK)
        rk4lanes.rounds(m, S, L, W, X, C, w0, dt, dt, tol, max_iter, kinks, project, st, steps,
                        0, ch)
        rk4lanes.end(m, S, C, st)
        for j in range(n_lanes):
            if st[j] == IDLE:
                continue
            taken[j] += steps[j]
            if st[j] != OK:
                status[j] = st[j]
                done[j] = k + 1
            elif went[j] == ramp.ENDED:
                done[j] = k + 1
                if k + 1 == n_steps:
                    lanechunk.put_summary(m, lanedata.lane_record(S, j), out[j], heights[j])
                    made[j] = 1


@jit_lanes
def set_rests(m, S, L, R, Q, k, go, went, tmp):
    """:func:`solver.kernels.ramp.set_rest` of step ``k`` for each lane whose ``go`` is set,
    its result in ``went``: the rest lengths over lanes (:func:`solver.kernels.ramp.next_rests`,
    scratch ``Q``, a :class:`~solver.kernels.ramp.LaneRest`) into ``S`` and the lane-inner
    ``L`` (which holds the lanes' states), the energies before and after over lanes
    (:func:`solver.kernels.lanesteps.energy_rows` into ``tmp`` (3, B)), the contact terms lane
    by lane. The same operations as ``set_rest`` lane by lane. A model with summary arrays (a
    ramp steps in a compiled call only on an exact model: ``Loading._ramp_record``)."""
    n_lanes = go.shape[0]
    ramp.next_rests(R, Q, k, go, went)
    lanesteps.energy_rows(L.x, L.v, m, L.rest, L.EA, L.f_ext, tmp)
    E = Q.E
    for j in range(n_lanes):
        if go[j] == 0 or went[j] == ramp.ASYMMETRIC:
            continue
        d = lanedata.lane_record(S, j)
        extra, touch = summary.contact_parts(d.x, d.v, m, d)
        a = tmp[0, j] + tmp[1, j]
        E[0, j] = a
        E[1, j] = summary.energy_sum(m, a, tmp[2, j], extra, touch)
        E[2, j] = extra
        E[3, j] = touch
    ramp.load_lanes(R, Q, go, went, L.rest, L.EA, S.rest, S.EA)
    lanesteps.cable_energy_lanes(L.x, m, L.rest, L.EA, tmp[2])
    for j in range(n_lanes):
        if go[j] != 0 and went[j] != ramp.ASYMMETRIC:
            after = summary.energy_sum(m, E[0, j], tmp[2, j], E[2, j], E[3, j])
            ramp.book(ramp.lane_ramp(R, j), E[1, j], after)
