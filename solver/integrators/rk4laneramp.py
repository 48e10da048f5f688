"""Prestrain ramps over lanes: :func:`ramped` steps B lanes of one model, each with its own
ramp (:class:`solver.kernels.ramp.LaneRamp`), as :func:`solver.integrators.rk4._rk4_ramped`
steps one instance: before each step of ``dt`` the lane's rest lengths of its ramp at that
time (:func:`solver.kernels.ramp.set_rest`, lane by lane), then the step as a call of one
``dt`` (:func:`solver.integrators.rk4lanes.begin`, ``rounds`` and ``end`` over the lanes still
ramping), so each lane equals its single run bit for bit. A lane stops where its single call
stops: after the step whose rest lengths end its ramp, after a failed step, before rest
lengths that break its model's symmetry, at the end of the interval; the simulation takes the
rest of its interval by itself (:meth:`solver.simulate.simulation.Simulation._integrate`).
"""
from __future__ import annotations

from solver.compiled import jit_lanes
from solver.integrators import rk4lanes
from solver.kernels import lanechunk, lanedata, ramp
from solver.status import OK

IDLE = -99          # the status of a lane that does not take the present step


@jit_lanes
def ramped(m, S, L, W, X, C, w0, dt, n_steps, tol, max_iter, kinks, project, R, ch, status,
           st, steps, done, taken, went, made, out, heights):
    """``n_steps`` steps of ``dt`` of each lane whose ``status`` is ``OK``, its ramp's rest
    lengths set before each (see the module's text; the ramp's ``clock`` and ``book`` rows set
    by the caller). Per lane (B,): ``done`` the steps done, ``taken`` the integrator's steps,
    ``status`` the status, ``went`` what the last :func:`~solver.kernels.ramp.set_rest`
    returned, ``made`` 1 where the lane reached the end of the interval (its state summary in
    ``out`` (B, 4) and ``heights``: :func:`solver.kernels.lanechunk.put_summary`). ``st``,
    ``steps`` (B,) scratch; ``ch`` an empty :class:`~solver.kernels.lanechunk.Chunk`."""
    n_lanes = status.shape[0]
    for j in range(n_lanes):
        done[j] = -1
        taken[j] = 0
        went[j] = ramp.SET
        made[j] = 0
    for k in range(n_steps + 1):
        going = 0
        for j in range(n_lanes):
            st[j] = IDLE
            if status[j] != OK or done[j] >= 0:
                continue
            d = lanedata.lane_record(S, j)
            g = ramp.set_rest(m, d, ramp.lane_ramp(R, j), k)
            went[j] = g
            if g == ramp.ASYMMETRIC or k == n_steps:
                done[j] = k
                if g != ramp.ASYMMETRIC:
                    lanechunk.put_summary(m, d, out[j], heights[j])
                    made[j] = 1
                continue
            st[j] = OK
            going += 1
        if going == 0:
            return
        rk4lanes.begin(m, S, L, C, st, steps)
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
