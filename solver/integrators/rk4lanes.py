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
