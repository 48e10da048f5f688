"""Adaptive Dormand-Prince 5(4) with error control, projection and kink landing.

``y = (x, v)``, ``y' = (v, a(x, v))`` with ``a`` from
:func:`solver.kernels.dynamics.accelerations`. Each
accepted step is the 5th-order solution, then positions and velocities are projected on the rigid
members as in ``rk4_projected``. The error estimate (5th minus embedded 4th order) is measured in
the RMS norm of ``err / (atol + rtol max(|y|, |y+|))`` over every coordinate of x (m) and v (m/s)
(the scipy ``RK45`` convention; positions are absolute, so ``rtol`` acts on about 0.3 m for the
paper's column). A step is accepted when that norm is at most 1; the next step is
``h * clip(0.9 err^(-1/5), 0.2, 5)``, never above ``dt``. The tolerance is per step: the global
error accumulates over the steps. A step whose stages fail (singular constraint matrix,
non-finite values) is rejected and retried 4x shorter. With ``kinks`` a step is shortened to land
on the next
predicted cable slack/taut transition, which keeps the error estimate honest across kinks.
"""
from __future__ import annotations

import math

import numpy as np

from solver.kernels import dynamics as dyn
from solver.kernels import effects
from solver.kernels import ramp
from solver.kernels import summary
from solver.compiled import jit
from solver.integrators.base import Integrator
from solver.kernels.kinks import next_kink
from solver.kernels.records import copy_data, copy_into
from solver.status import STEP_TOO_SMALL

H_MIN_FRACTION = 1e-9      # smallest step, as a fraction of dt, before giving up

# Butcher tableau (Dormand & Prince 1980); E = b5 - b4 for the error estimate
C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0])
A = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [1 / 5, 0.0, 0.0, 0.0, 0.0, 0.0],
    [3 / 40, 9 / 40, 0.0, 0.0, 0.0, 0.0],
    [44 / 45, -56 / 15, 32 / 9, 0.0, 0.0, 0.0],
    [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0.0, 0.0],
    [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656, 0.0],
    [35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84],
])
B = A[6].copy()
E = np.array([-71 / 57600, 0.0, 71 / 16695, -71 / 1920, 17253 / 339200, -22 / 525, 1 / 40])


@jit
def _stages(x, v, h, A, m, d, w, kx, kv, xs, vs, pw):
    """Stages 2..7 of the step of size h from (x, v), given stage 1 in ``kx[0] = v``, ``kv[0] =
    a(x, v)``. Stage 7 is evaluated at the 5th-order solution, left in ``xs``, ``vs``. ``pw``:
    the power the forces dissipate at each stage (``pw[0]`` given)."""
    n = x.shape[0]
    for s in range(1, 7):
        for p in range(n):
            for i in range(3):
                dx = 0.0
                dv = 0.0
                for j in range(s):
                    a = A[s, j]
                    if a != 0.0:
                        dx += a * kx[j, p, i]
                        dv += a * kv[j, p, i]
                xs[p, i] = x[p, i] + h * dx
                vs[p, i] = v[p, i] + h * dv
        if not (dyn.all_finite(xs) and dyn.all_finite(vs)):
            return dyn.NONFINITE
        status = dyn.accelerations(xs, vs, m, d, w, kv[s])
        if status != dyn.OK:
            return status
        pw[s] = effects.power(d)
        copy_into(kx[s], vs)
    return dyn.OK


@jit
def _error_norm(x, v, xs, vs, h, E, kx, kv, rtol, atol):
    """RMS of ``err / (atol + rtol max(|y|, |y+|))`` over all coordinates of x and v."""
    n = x.shape[0]
    total = 0.0
    for p in range(n):
        for i in range(3):
            ex = 0.0
            ev = 0.0
            for j in range(7):
                ex += E[j] * kx[j, p, i]
                ev += E[j] * kv[j, p, i]
            sx = atol + rtol * max(abs(x[p, i]), abs(xs[p, i]))
            sv = atol + rtol * max(abs(v[p, i]), abs(vs[p, i]))
            total += (h * ex / sx) ** 2 + (h * ev / sv) ** 2
    return math.sqrt(total / (6.0 * n))


@jit
def dopri_run(m, d, w, dt, n_steps, tol, max_iter, kinks, rtol, atol, A, E, kx, kv, xs, vs,
              hstate, pw):
    """Advance ``d.x``, ``d.v`` by ``n_steps * dt`` adaptively. ``hstate``: [proposed step,
    accepted, rejected, force evaluations], carried between calls; ``pw`` (7,) scratch: the power
    the forces dissipate at each stage. Returns (accepted steps, status)."""
    x, v, topo = d.x, d.v, m.topo
    total = n_steps * dt
    t = 0.0
    accepted = 0
    h_prop = hstate[0] if 0.0 < hstate[0] <= dt else dt
    need_k1 = True
    effects.start(x, m, d)
    while total - t > 1e-9 * dt:
        if need_k1:
            copy_into(kx[0], v)
            status = dyn.accelerations(x, v, m, d, w, kv[0])
            pw[0] = effects.power(d)
            hstate[3] += 1
            if status != dyn.OK:
                return accepted, status
            need_k1 = False
        h = min(h_prop, total - t)
        if kinks:
            h = next_kink(x, v, kv[0], m, d, h, 1e-3 * h)
        h = effects.scan_limit(x, v, kv[0], m, d, h)
        status = _stages(x, v, h, A, m, d, w, kx, kv, xs, vs, pw)
        hstate[3] += 6
        err = _error_norm(x, v, xs, vs, h, E, kx, kv, rtol, atol) if status == dyn.OK else np.inf
        if err <= 1.0:
            copy_into(x, xs)
            copy_into(v, vs)
            for s in range(6):          # the dissipated energy, with the 5th-order weights
                effects.dissipate(d, h * A[6, s] * pw[s])
            status = dyn.project_positions(x, topo, w, tol, max_iter)
            if status == dyn.OK:
                status = dyn.project_velocities(x, v, topo, w)
            if status != dyn.OK:
                return accepted, status
            t += h
            accepted += 1
            hstate[1] += 1
            need_k1 = True
            grow = 5.0 if err == 0.0 else min(5.0, max(0.2, 0.9 * err ** -0.2))
            if h >= 0.999 * h_prop:        # a step cut short (kink, end) says nothing new
                h_prop = min(dt, h * grow)
        else:
            hstate[2] += 1
            shrink = 0.25 if not math.isfinite(err) else max(0.2, 0.9 * err ** -0.2)
            h_prop = h * shrink
            if h_prop < H_MIN_FRACTION * dt:
                hstate[0] = h_prop
                return accepted, STEP_TOO_SMALL
    hstate[0] = h_prop
    effects.finish(x, m, d)
    return accepted, dyn.OK


@jit
def dopri_checked(m, d, w, dt, n_steps, tol, max_iter, kinks, rtol, atol, A, E, kx, kv, xs, vs,
                  hstate, pw, kept, heights):
    """:func:`dopri_run` between ``copy_data`` and ``summary.state_summary`` (see
    ``Integrator.checked_args``)."""
    copy_data(d, kept)
    out = dopri_run(m, d, w, dt, n_steps, tol, max_iter, kinks, rtol, atol, A, E, kx, kv, xs, vs,
                    hstate, pw)
    return out + summary.state_summary(d.x, d.v, m, d, heights)


@jit
def dopri_ramped(m, d, w, dt, n_steps, tol, max_iter, kinks, rtol, atol, A, E, kx, kv, xs, vs,
                 hstate, pw, r, k0, heights):
    """:func:`dopri_run` under a prestrain ramp, as :func:`solver.integrators.rk4._rk4_ramped`
    (see ``Integrator.ramped``)."""
    taken = 0
    for k in range(k0, n_steps + 1):
        went = ramp.set_rest(m, d, r, k)
        if went == ramp.ASYMMETRIC or k == n_steps:
            return ramp.finish(m, d, k, taken, dyn.OK, went, heights, went != ramp.ASYMMETRIC)
        steps, status = dopri_run(m, d, w, dt, 1, tol, max_iter, kinks, rtol, atol, A, E, kx, kv,
                                  xs, vs, hstate, pw)
        taken += steps
        if status != dyn.OK or went == ramp.ENDED:
            return ramp.finish(m, d, k + 1, taken, status, went, heights,
                               status == dyn.OK and k + 1 == n_steps)
    return ramp.finish(m, d, n_steps, taken, dyn.OK, ramp.SET, heights, False)


class DOPRI54Projected(Integrator):
    """Adaptive Dormand-Prince 5(4) (see :mod:`solver.integrators.dopri`): ``dt`` is the initial
    and largest step, ``rtol``/``atol`` the error tolerances. Seven force evaluations per accepted
    step (six plus a fresh first stage after the projection); ``stats()`` counts steps and
    evaluations."""
    name = 'dopri54_projected'
    order = 5
    projected = True
    adaptive = True
    evaluations_per_step = 7

    def __init__(self, rtol=1e-8, atol=1e-10):
        super().__init__(rtol, atol)
        self.hstate = np.zeros(4)

    kernel = staticmethod(dopri_run)
    checked = staticmethod(dopri_checked)
    ramped = staticmethod(dopri_ramped)

    def reset(self):
        self.hstate[:] = 0.0

    def get_state(self):
        return self.hstate.copy()

    def set_state(self, state):
        self.hstate[:] = state

    def stats(self):
        """``{'accepted': int, 'rejected': int, 'evaluations': int}`` since the last reset."""
        return {'accepted': int(self.hstate[1]), 'rejected': int(self.hstate[2]),
                'evaluations': int(self.hstate[3])}

    def extra_args(self, x, kinks):
        n = x.shape[0]
        return (bool(kinks), self.rtol, self.atol, A, E,
                self.scratch('kx', (7, n, 3)), self.scratch('kv', (7, n, 3)),
                self.scratch('xs', (n, 3)), self.scratch('vs', (n, 3)), self.hstate,
                self.scratch('pw', (7,)))
