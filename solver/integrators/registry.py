"""Time integrators behind one interface.

An integrator advances positions ``x`` (n_nodes, 3) m and velocities ``v`` (n_nodes, 3) m/s in
place by
``n_steps`` fixed steps of ``dt`` s, with the ``(net, act, ws)`` tuples of :mod:`solver.kernels.dynamics`,
and returns ``(steps_done, status)``; a non-OK status stops it at the step that failed, leaving the
last good state in ``x`` and ``v``.

Methods (:data:`METHODS`; the scene key ``integrator.method`` or ``--set integrator=NAME`` picks
one):

- ``rk4_projected`` (default): classical RK4, then mass-weighted projection of positions and
  velocities; steps land on cable slack/taut kinks. Order 4, four force evaluations per step.
- ``rk4``: the same RK4 without projection. Bar lengths drift (the failure mode of section 1.2 of
  docs/physics.md, kept to show it).
- ``rattle``: velocity Verlet with RATTLE constraints. Order 2, one force evaluation per step,
  symmetric and (to the projection tolerance) symplectic: energy stays bounded over long runs.
- ``dopri54_projected``: adaptive Dormand-Prince 5(4) with error control (``integrator.rtol``,
  ``integrator.atol``), ``dt`` is the initial and largest step; projection after every accepted
  step, steps land on kinks.
- ``implicit_midpoint``: the implicit midpoint rule with the bar forces as unknowns
  (:mod:`solver.integrators.implicit`), for stiff scenes: order 2, A-stable, Newton on a banded KKT system
  per step, then projection; fixed steps.

To add a method: write an ``@jit`` kernel ``_my_run(x, v, dt, n_steps, net, act, ws, tol, max_iter,
kinks)`` with that contract (calling only :func:`solver.kernels.dynamics.accelerations`,
``project_positions``, ``project_velocities``, ``all_finite`` and :func:`next_kink`, and passing
the ``net``/``act``/``ws`` tuples through untouched) and its checked twin (three lines, as
:func:`_rk4_checked`: ``keep_state``, the run kernel, then ``dynamics.state_summary``: a
``Simulation.advance`` is then one compiled call), subclass :class:`Integrator` (``name``,
``order``, ``projected``, ``kernel``, ``checked``; override :meth:`Integrator.extra_args` when the
kernel takes other arguments after ``max_iter``, e.g. scratch arrays from
:meth:`Integrator.scratch`) and add it to :data:`METHODS`.
"""
from __future__ import annotations

import math

import numpy as np

from solver.kernels import dynamics as dyn
from solver._jit import jit
from solver.kernels.contact import contact_kink


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
        if rotated:         # a cable to the image R^r x_b (sym3d)
            cr = dyn.ROT_C[cable_rot[c]]
            sr = dyn.ROT_S[cable_rot[c]]
            dx = cr * x[b, 0] - sr * x[b, 1] - x[a, 0]
            dy = sr * x[b, 0] + cr * x[b, 1] - x[a, 1]
            vx = cr * v[b, 0] - sr * v[b, 1] - v[a, 0]
            vy = sr * v[b, 0] + cr * v[b, 1] - v[a, 1]
            ax = cr * acc[b, 0] - sr * acc[b, 1] - acc[a, 0]
            ay = sr * acc[b, 0] + cr * acc[b, 1] - acc[a, 1]
        else:
            dx = x[b, 0] - x[a, 0]
            dy = x[b, 1] - x[a, 1]
            vx = v[b, 0] - v[a, 0]
            vy = v[b, 1] - v[a, 1]
            ax = acc[b, 0] - acc[a, 0]
            ay = acc[b, 1] - acc[a, 1]
        dz = x[b, 2] - x[a, 2]
        vz = v[b, 2] - v[a, 2]
        az = acc[b, 2] - acc[a, 2]
        bb = dx * dx + dy * dy + dz * dz
        bbd = dx * vx + dy * vy + dz * vz
        bdbd = vx * vx + vy * vy + vz * vz
        bbdd = dx * ax + dy * ay + dz * az
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
    ex = act[3]
    if ex[2].shape[0] != 0 or ex[3].shape[0] != 0:      # stops and strikers (solver.kernels.contact)
        t_best = contact_kink(x, v, acc, ex, t_best, ignore)
    return t_best


@jit
def _rk4_advance(x, v, dt, n_steps, net, act, ws, tol, max_iter, kinks, project):
    """Advance by ``n_steps * dt`` with classical RK4; with ``kinks`` a step is shortened to land
    on the next cable slack/taut transition, with ``project`` positions and velocities are
    projected on the rigid members after every step. Returns (RK4 steps taken, status)."""
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
        if project and status == dyn.OK:
            status = dyn.project_positions(x, net, ws, tol, max_iter)
        if project and status == dyn.OK:
            status = dyn.project_velocities(x, v, net, ws)
        if status == dyn.OK and not (dyn.all_finite(x) and dyn.all_finite(v)):
            status = dyn.NONFINITE
        if status != dyn.OK:
            return steps, status
        t += h
        steps += 1
    return steps, dyn.OK


@jit
def _rk4_projected_run(x, v, dt, n_steps, net, act, ws, tol, max_iter, kinks):
    """RK4 with projection after every step (see :func:`_rk4_advance`)."""
    return _rk4_advance(x, v, dt, n_steps, net, act, ws, tol, max_iter, kinks, True)


@jit
def _rk4_run(x, v, dt, n_steps, net, act, ws, tol, max_iter, kinks):
    """:func:`_rk4_projected_run` without the projections (``tol``, ``max_iter`` unused): the
    constraints hold only at the acceleration level, so bar lengths drift."""
    return _rk4_advance(x, v, dt, n_steps, net, act, ws, tol, max_iter, kinks, False)


@jit
def _rattle_run(x, v, dt, n_steps, net, act, ws, tol, max_iter, acc, x_old):
    """Velocity Verlet with RATTLE constraints, ``n_steps`` steps of ``dt``; scratch ``acc`` and
    ``x_old`` (n, 3). One force evaluation per step (plus one per call to start).

    Stage 1 (SHAKE): ``x+ = x + h v + h^2/2 a(x)``, projected on the rigid members; the half-step
    velocity is ``(x+ - x) / h`` (it includes the constraint impulse). Stage 2: ``v+ = v_1/2 +
    h/2 a(x+)``, projected on the tangent space. ``a`` already holds the acceleration-level
    multipliers, so ``x + h v + h^2/2 a`` misses the constraints by O(h^3) only; the Gauss-Newton
    projection (gradients at the iterate) then differs from SHAKE (gradients at ``x``) by
    O(h^4) per step, and it is converged to ``tol``. In stage 2 the constraint part of ``a(x+)``
    lies in the range the velocity projection removes, so stage 2 is exactly RATTLE's."""
    status = dyn.accelerations(x, v, net, act, ws, acc)
    if status != dyn.OK:
        return 0, status
    n = x.shape[0]
    for step in range(n_steps):
        h = dt
        for p in range(n):
            for i in range(3):
                x_old[p, i] = x[p, i]
                x[p, i] += h * v[p, i] + 0.5 * h * h * acc[p, i]
        status = dyn.project_positions(x, net, ws, tol, max_iter)
        if status == dyn.OK:
            for p in range(n):
                for i in range(3):
                    v[p, i] = (x[p, i] - x_old[p, i]) / h
            status = dyn.accelerations(x, v, net, act, ws, acc)
        if status == dyn.OK:
            for p in range(n):
                for i in range(3):
                    v[p, i] += 0.5 * h * acc[p, i]
            status = dyn.project_velocities(x, v, net, ws)
        if status == dyn.OK and not (dyn.all_finite(x) and dyn.all_finite(v)):
            status = dyn.NONFINITE
        if status != dyn.OK:
            return step, status
    return n_steps, dyn.OK


@jit
def keep_state(x, v, keep):
    """Copy ``x``, ``v`` into ``keep = (x_keep, v_keep)`` (the state to restore on failure)."""
    keep[0][:, :] = x
    keep[1][:, :] = v


# The checked kernels (Integrator.checked_args): the run kernel between keep_state and
# dynamics.state_summary, in one compiled call (a Simulation.advance makes no other).
@jit
def _rk4_projected_checked(x, v, dt, n_steps, net, act, ws, tol, max_iter, kinks, keep, summ,
                           heights):
    keep_state(x, v, keep)
    out = _rk4_advance(x, v, dt, n_steps, net, act, ws, tol, max_iter, kinks, True)
    return out + dyn.state_summary(x, v, net, act, summ, heights)


@jit
def _rk4_checked(x, v, dt, n_steps, net, act, ws, tol, max_iter, kinks, keep, summ, heights):
    keep_state(x, v, keep)
    out = _rk4_advance(x, v, dt, n_steps, net, act, ws, tol, max_iter, kinks, False)
    return out + dyn.state_summary(x, v, net, act, summ, heights)


@jit
def _rattle_checked(x, v, dt, n_steps, net, act, ws, tol, max_iter, acc, x_old, keep, summ,
                    heights):
    keep_state(x, v, keep)
    out = _rattle_run(x, v, dt, n_steps, net, act, ws, tol, max_iter, acc, x_old)
    return out + dyn.state_summary(x, v, net, act, summ, heights)


STEP_TOO_SMALL = 10    # status code beyond those of solver.kernels.dynamics (adaptive step underflow)


class Integrator:
    """A method behind one interface. ``kernel`` is the ``@jit`` run function described in the
    module doc, ``checked`` its twin (see :meth:`checked_args`); ``extra_args`` gives the kernel
    arguments after ``max_iter``; ``evaluations_per_step`` counts force evaluations (for work
    estimates)."""
    name = ''
    order = 0
    projected = False
    adaptive = False
    evaluations_per_step = 0
    kernel = None
    checked = None

    def __init__(self, rtol=1e-8, atol=1e-10):
        self.rtol, self.atol = float(rtol), float(atol)
        self._scratch = {}

    def scratch(self, key, shape):
        """A zeroed float64 array owned by this integrator (reused while the shape is the same)."""
        a = self._scratch.get(key)
        if a is None or a.shape != tuple(shape):
            a = self._scratch[key] = np.zeros(shape)
        return a

    def extra_args(self, x, kinks):
        """The kernel arguments after ``max_iter`` for a state shaped like ``x``."""
        return (bool(kinks),)

    def reset(self):
        """Forget any step-size history (adaptive methods)."""

    def get_state(self):
        """A copy of the integrator's own state (step-size history), for :meth:`set_state`."""
        return None

    def set_state(self, state):
        pass

    def run(self, x, v, dt, n_steps, net, act, ws, tol=1e-12, max_iter=3, kinks=True):
        """Advance ``x``, ``v`` (n, 3) in place by ``n_steps * dt`` s; returns (steps, status)."""
        steps, status = self.kernel(x, v, float(dt), int(n_steps), net, act, ws, float(tol),
                                     int(max_iter), *self.extra_args(x, kinks))
        return int(steps), int(status)

    def checked_args(self, x, net, act, ws, tol, max_iter, kinks, keep, summ):
        """The arguments of ``checked`` between ``n_steps`` and ``heights``: ``checked(x, v, dt,
        n_steps, *checked_args(...), heights)`` is :meth:`run` in one compiled call that first
        copies ``x``, ``v`` into ``keep = (x_keep, v_keep)`` and then summarises the end state
        (:func:`solver.kernels.dynamics.state_summary` with the arrays ``summ``, prism heights into
        ``heights``), returning ``(steps, status, finite, energy J, relative constraint error,
        smallest prism height m)``. ``Simulation.advance`` builds them once per model."""
        return (net, act, ws, float(tol), int(max_iter)) + tuple(self.extra_args(x, kinks)) + (
            keep, summ)


class RK4Projected(Integrator):
    """Classical RK4, then mass-weighted projection of positions and velocities after every step
    (docs/physics.md section 1.2). Four force evaluations per step; steps land on cable kinks."""
    name = 'rk4_projected'
    order = 4
    projected = True
    evaluations_per_step = 4
    kernel = staticmethod(_rk4_projected_run)
    checked = staticmethod(_rk4_projected_checked)


class RK4(Integrator):
    """Classical RK4 without projection: bar lengths drift (shown, not hidden). Steps land on
    kinks."""
    name = 'rk4'
    order = 4
    evaluations_per_step = 4
    kernel = staticmethod(_rk4_run)
    checked = staticmethod(_rk4_checked)


class Rattle(Integrator):
    """Velocity Verlet with RATTLE constraints (see :func:`_rattle_run`): order 2, one force
    evaluation per step, fixed steps (no kink landing: a variable step would break symplecticity,
    and a kink costs a second-order method no order)."""
    name = 'rattle'
    order = 2
    projected = True
    evaluations_per_step = 1
    kernel = staticmethod(_rattle_run)
    checked = staticmethod(_rattle_checked)

    def extra_args(self, x, kinks):
        return self.scratch('acc', x.shape), self.scratch('x_old', x.shape)


class DOPRI54Projected(Integrator):
    """Adaptive Dormand-Prince 5(4) (see :mod:`solver.integrators.dopri`): ``dt`` is the initial and largest
    step, ``rtol``/``atol`` the error tolerances. Seven force evaluations per accepted step (six
    plus a fresh first stage after the projection); ``stats()`` counts steps and evaluations."""
    name = 'dopri54_projected'
    order = 5
    projected = True
    adaptive = True
    evaluations_per_step = 7

    def __init__(self, rtol=1e-8, atol=1e-10):
        super().__init__(rtol, atol)
        self.hstate = np.zeros(4)
        from solver.integrators import dopri as adaptive  # the kernel module imports next_kink from here
        self._adaptive = adaptive

    @property
    def kernel(self):
        return self._adaptive.dopri_run

    @property
    def checked(self):
        return self._adaptive.dopri_checked

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
        return (bool(kinks), self.rtol, self.atol, self._adaptive.A, self._adaptive.E,
                self.scratch('kx', (7, n, 3)), self.scratch('kv', (7, n, 3)),
                self.scratch('xs', (n, 3)), self.scratch('vs', (n, 3)), self.hstate)


class ImplicitMidpoint(Integrator):
    """Implicit midpoint rule with the rigid members as unknown forces, for stiff scenes (see
    :mod:`solver.integrators.implicit`): order 2, A-stable, symmetric; Newton on a banded KKT system each
    step, then projection. Fixed steps (no kink landing). ``stats()`` counts Newton iterations,
    factorisations and force evaluations. Massive bars are refused."""
    name = 'implicit_midpoint'
    order = 2
    projected = True
    evaluations_per_step = 3

    def __init__(self, rtol=1e-8, atol=1e-10):
        super().__init__(rtol, atol)
        from solver.integrators import implicit
        self._implicit = implicit
        self.nstate = np.zeros(4)
        self._layout = None

    @property
    def kernel(self):
        return self._implicit.midpoint_run

    @property
    def checked(self):
        return self._implicit.midpoint_checked

    def reset(self):
        self.nstate[:] = 0.0

    def stats(self):
        """``{'steps', 'newton_iterations', 'factorizations', 'evaluations'}`` since the last
        reset."""
        s = self.nstate
        return {'steps': int(s[2]), 'newton_iterations': int(s[0]),
                'factorizations': int(s[1]), 'evaluations': int(s[3])}

    def _args(self, x, net):
        if self._layout is None or self._layout[0] is not net:
            self._layout = (net, self._implicit.layout(net))
        node_pos, con_pos, size, bw = self._layout[1]
        n, m = x.shape[0], len(con_pos)
        return (node_pos, con_pos, self.scratch('band', (size, bw + 1)),
                self.scratch('rhs', (size,)), self.scratch('nu', (m,)),
                self.scratch('x0', x.shape), self.scratch('v0', x.shape),
                self.scratch('xm', x.shape), self.scratch('f', x.shape),
                self.scratch('acc', (n, 3)), self.nstate)

    @staticmethod
    def _refuse_extras(act):
        """The step has no cable damping, prism stops or strikers (``act[3]``): refuse them
        rather than run without them."""
        ex = act[3] if len(act) > 3 else ()
        if any(np.asarray(ex[i]).size for i in (0, 2, 3) if i < len(ex)):
            raise ValueError('implicit_midpoint: cable damping, prism stops (contact.lock) and '
                             'strikers are not part of its step; use rk4_projected or '
                             'dopri54_projected')

    def run(self, x, v, dt, n_steps, net, act, ws, tol=1e-12, max_iter=3, kinks=True):
        self._refuse_extras(act)
        steps, status = self.kernel(x, v, float(dt), int(n_steps), net, act, ws, float(tol),
                                    int(max_iter), *self._args(x, net))
        return int(steps), int(status)

    def checked_args(self, x, net, act, ws, tol, max_iter, kinks, keep, summ):
        self._refuse_extras(act)
        return (net, act, ws, float(tol), int(max_iter)) + self._args(x, net) + (keep, summ)


METHODS = {cls.name: cls for cls in (RK4Projected, RK4, Rattle, DOPRI54Projected,
                                     ImplicitMidpoint)}

STATUS_TEXT = dict(dyn.STATUS_TEXT)
STATUS_TEXT[STEP_TOO_SMALL] = ('adaptive step size fell below 1e-9 dt (stiff or singular '
                               'motion)')
STATUS_TEXT[11] = 'implicit step: Newton iteration did not converge'    # implicit.NEWTON_FAILED


def status_text(status):
    """Human-readable text of a kernel status code."""
    return STATUS_TEXT.get(status, f'status {status}')


def get(name, **options):
    """The integrator called ``name`` (``options``: ``rtol``, ``atol`` of adaptive methods); an
    unknown name lists the valid ones."""
    try:
        cls = METHODS[name]
    except KeyError:
        valid = ', '.join(sorted(METHODS))
        raise ValueError(f'unknown integrator {name!r}; valid: {valid}') from None
    return cls(**options)
