"""Classical RK4 with projections for lanes (:mod:`solver.kernels.lanes`): B instances of one
plain network stepped together with one clock, each lane with its own status. The operations of
each lane are those of :func:`solver.integrators.rk4._rk4_run` (``rk4_projected``, no kinks) on a
model with every effect off, in the same order: each lane's run equals the scalar run bit for bit.
"""
from __future__ import annotations

from solver.compiled import jit_lanes
from solver.kernels import lanes
from solver.status import OK


@jit_lanes
def rk4_step(x, v, h, a1, topo, d, w, status):
    """One classical RK4 step of size h of each lane, given its first-stage accelerations ``a1``;
    the new state is written to ``x``, ``v`` of the lanes whose ``status`` is still ``OK`` after
    the three further evaluations (:func:`solver.integrators.rk4._rk4_step` without effects)."""
    xs, vs, acc, xacc, vacc = w.xs, w.vs, w.acc, w.xacc, w.vacc
    n = x.shape[0]
    n_lanes = x.shape[2]
    for p in range(n):
        for i in range(3):
            for k in range(n_lanes):
                xacc[p, i, k] = v[p, i, k]
                vacc[p, i, k] = a1[p, i, k]
                xs[p, i, k] = x[p, i, k] + 0.5 * h * v[p, i, k]
                vs[p, i, k] = v[p, i, k] + 0.5 * h * a1[p, i, k]
    for stage in range(1, 4):
        lanes.accelerations(xs, vs, topo, d, w, acc, status)
        wt = 1.0 if stage == 3 else 2.0
        c = 0.5 * h if stage == 1 else h
        for p in range(n):
            for i in range(3):
                for k in range(n_lanes):
                    xacc[p, i, k] += wt * vs[p, i, k]
                    vacc[p, i, k] += wt * acc[p, i, k]
                    if stage < 3:
                        xs[p, i, k] = x[p, i, k] + c * vs[p, i, k]
                        vs[p, i, k] = v[p, i, k] + c * acc[p, i, k]
    go = w.go
    for k in range(n_lanes):
        go[k] = 1 if status[k] == OK else 0
    for p in range(n):
        for i in range(3):
            for k in range(n_lanes):
                x[p, i, k] = x[p, i, k] + h / 6.0 * xacc[p, i, k] if go[k] != 0 else x[p, i, k]
                v[p, i, k] = v[p, i, k] + h / 6.0 * vacc[p, i, k] if go[k] != 0 else v[p, i, k]


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
