"""Time integrators behind one interface.

An integrator advances positions ``x`` (n_nodes, 3) m and velocities ``v`` (n_nodes, 3) m/s in place by
``n_steps`` fixed steps of ``dt`` s, with the ``(net, act, ws)`` tuples of :mod:`solver.dynamics`, and
returns ``(steps_done, status)``; a non-OK status stops it at the step that failed, leaving the last
good state in ``x`` and ``v``.

To add a method: write an ``@jit`` kernel ``_my_run(x, v, dt, n_steps, net, act, ws, tol, max_iter)``
with that contract, subclass :class:`Integrator` (``name``, ``order``, ``projected``, ``kernel``) and add
it to :data:`METHODS`. The scene key ``integrator.method`` (or ``--set integrator=NAME``) selects it.
"""
from __future__ import annotations

import math

from . import dynamics as dyn
from ._jit import jit


@jit
def _rk4_step(x, v, h, a1, net, act, ws):
    """One classical RK4 step of size h of ``x' = v, v' = a(x, v)`` given the first-stage
    acceleration ``a1 = a(x, v)``; the new state is left in ``x``, ``v``."""
    xs, vs, acc, xacc, vacc = ws[5], ws[6], ws[7], ws[8], ws[9]
    n = x.shape[0]
    xacc[:, :] = v
    vacc[:, :] = a1
    for p in range(n):
        for i in range(3):
            xs[p, i] = x[p, i] + 0.5 * h * v[p, i]
            vs[p, i] = v[p, i] + 0.5 * h * a1[p, i]
    for stage in range(1, 4):
        status = dyn.accelerations(xs, vs, net, act, ws, acc)
        if status != dyn.OK:
            return status
        w = 1.0 if stage == 3 else 2.0
        c = 0.5 * h if stage == 1 else h
        for p in range(n):
            for i in range(3):
                xacc[p, i] += w * vs[p, i]
                vacc[p, i] += w * acc[p, i]
                if stage < 3:
                    xs[p, i] = x[p, i] + c * vs[p, i]
                    vs[p, i] = v[p, i] + c * acc[p, i]
    for p in range(n):
        for i in range(3):
            x[p, i] += h / 6.0 * xacc[p, i]
            v[p, i] += h / 6.0 * vacc[p, i]
    return dyn.OK


@jit
def next_kink(x, v, acc, net, act, h, ignore):
    """Earliest time in ``(ignore, h)`` at which a cable is predicted to go slack or taut, from a
    quadratic Taylor model of ``s - L`` (position, velocity, acceleration); ``h`` if none.

    The tension-only cable law has a kink at ``s = L``; a Runge-Kutta step whose stages straddle it
    loses its order. Landing steps on kinks restores it (a kink closer than ``ignore`` is taken as
    already crossed)."""
    cable_a, cable_b, cable_rot = net[7], net[8], net[10]
    rest = act[0]
    t_best = h
    rotated = cable_rot.shape[0] > 0
    for c in range(cable_a.shape[0]):
        a = cable_a[c]
        b = cable_b[c]
        cr = dyn.ROT_C[cable_rot[c]] if rotated else 1.0     # cable to the image R^r x_b
        sr = dyn.ROT_S[cable_rot[c]] if rotated else 0.0
        bb = 0.0
        bbd = 0.0
        bdbd = 0.0
        bbdd = 0.0
        for i in range(3):
            if i == 0:
                db = cr * x[b, 0] - sr * x[b, 1] - x[a, 0]
                dv = cr * v[b, 0] - sr * v[b, 1] - v[a, 0]
                da = cr * acc[b, 0] - sr * acc[b, 1] - acc[a, 0]
            elif i == 1:
                db = sr * x[b, 0] + cr * x[b, 1] - x[a, 1]
                dv = sr * v[b, 0] + cr * v[b, 1] - v[a, 1]
                da = sr * acc[b, 0] + cr * acc[b, 1] - acc[a, 1]
            else:
                db = x[b, 2] - x[a, 2]
                dv = v[b, 2] - v[a, 2]
                da = acc[b, 2] - acc[a, 2]
            bb += db * db
            bbd += db * dv
            bdbd += dv * dv
            bbdd += db * da
        s = math.sqrt(bb)
        g = s - rest[c]
        sd = bbd / s
        sdd = (bdbd + bbdd - sd * sd) / s
        disc = sd * sd - 2.0 * sdd * g
        if disc < 0.0:
            continue
        q = -0.5 * (sd + math.copysign(math.sqrt(disc), sd))
        for r in range(2):
            if r == 0:
                t = q / (0.5 * sdd) if sdd != 0.0 else -1.0
            else:
                t = g / q if q != 0.0 else -1.0
            if ignore < t < t_best:
                t_best = t
    return t_best


@jit
def _rk4_projected_run(x, v, dt, n_steps, net, act, ws, tol, max_iter, kinks):
    """Advance by ``n_steps * dt``; with ``kinks`` a step is shortened to land on the next cable
    slack/taut transition. Returns (RK4 steps taken, status)."""
    a1 = ws[10]
    total = n_steps * dt
    t = 0.0
    steps = 0
    while total - t > 1e-9 * dt:
        h = min(dt, total - t)
        status = dyn.accelerations(x, v, net, act, ws, a1)
        if status == dyn.OK and kinks:
            h = next_kink(x, v, a1, net, act, h, 1e-3 * dt)
        if status == dyn.OK:
            status = _rk4_step(x, v, h, a1, net, act, ws)
        if status == dyn.OK:
            status = dyn.project_positions(x, net, ws, tol, max_iter)
        if status == dyn.OK:
            status = dyn.project_velocities(x, v, net, ws)
        if status == dyn.OK and not (dyn.all_finite(x) and dyn.all_finite(v)):
            status = dyn.NONFINITE
        if status != dyn.OK:
            return steps, status
        t += h
        steps += 1
    return steps, dyn.OK


class Integrator:
    """A fixed-step method. ``kernel`` is the ``@jit`` run function described in the module doc."""
    name = ''
    order = 0
    projected = False
    kernel = None

    def run(self, x, v, dt, n_steps, net, act, ws, tol=1e-12, max_iter=3, kinks=True):
        steps, status = type(self).kernel(x, v, float(dt), int(n_steps), net, act, ws,
                                          float(tol), int(max_iter), bool(kinks))
        return int(steps), int(status)


class RK4Projected(Integrator):
    """Classical RK4, then mass-weighted projection of positions and velocities after every step
    (physics.md section 1.2). Four force evaluations per step; steps land on cable kinks."""
    name = 'rk4_projected'
    order = 4
    projected = True
    kernel = staticmethod(_rk4_projected_run)


METHODS = {cls.name: cls for cls in (RK4Projected,)}


def get(name):
    """The integrator called ``name``; an unknown name lists the valid ones."""
    try:
        return METHODS[name]()
    except KeyError:
        raise ValueError(f'unknown integrator {name!r}; valid: {", ".join(sorted(METHODS))}') from None
