"""Classical RK4 (plain and projected) and velocity Verlet with RATTLE constraints: fixed-step
kernels and their :class:`~solver.integrators.base.Integrator` classes."""
from __future__ import annotations

import math

from solver.compiled import jit, jit_inline
from solver.integrators.base import Integrator
from solver.kernels import dynamics as dyn
from solver.kernels import effects
from solver.kernels import ramp
from solver.kernels import summary
from solver.kernels.kinks import next_kink
from solver.kernels.records import copy_data, copy_into


@jit
def _rk4_step(x, v, h, a1, m, d, w):
    """One classical RK4 step of size h of ``x' = v, v' = a(x, v)`` given the first-stage
    acceleration ``a1 = a(x, v)``; the new state is left in ``x``, ``v``. The power the forces
    dissipate (``d.ledger``, cable damping) is integrated with Simpson's weights."""
    xs, vs, acc, xacc, vacc = w.xs, w.vs, w.acc, w.xacc, w.vacc
    n = x.shape[0]
    work = effects.power(d)
    copy_into(xacc, v)
    copy_into(vacc, a1)
    for p in range(n):
        for i in range(3):
            xs[p, i] = x[p, i] + 0.5 * h * v[p, i]
            vs[p, i] = v[p, i] + 0.5 * h * a1[p, i]
    for stage in range(1, 4):
        status = dyn.accelerations(xs, vs, m, d, w, acc)
        if status != dyn.OK:
            return status
        wt = 1.0 if stage == 3 else 2.0
        work += wt * effects.power(d)
        c = 0.5 * h if stage == 1 else h
        for p in range(n):
            for i in range(3):
                xacc[p, i] += wt * vs[p, i]
                vacc[p, i] += wt * acc[p, i]
                if stage < 3:
                    xs[p, i] = x[p, i] + c * vs[p, i]
                    vs[p, i] = v[p, i] + c * acc[p, i]
    for p in range(n):
        for i in range(3):
            x[p, i] += h / 6.0 * xacc[p, i]
            v[p, i] += h / 6.0 * vacc[p, i]
    effects.dissipate(d, h / 6.0 * work)
    return dyn.OK


@jit_inline
def _controlled_step(x, v, h, a1, m, d, w, met, scale):
    """One RK4 step from a state whose accelerations ``a1`` were just evaluated (``met``: the
    run state's contact count before that evaluation) under the step control of the effects
    (:func:`solver.kernels.effects.plan`): the plain step of ``h`` where it allows it; else ``h``
    tried whole and kept if the effects accept it (:func:`~solver.kernels.effects.trial_kept`),
    otherwise the shorter step they ask for (times ``scale``: ``_rk4_run``'s refinement).
    Returns (status, the step taken)."""
    h_c, trial, known = effects.plan(x, v, a1, m, d, h, met, scale)
    if h_c >= h:
        return _rk4_step(x, v, h, a1, m, d, w), h
    if trial:
        kept = effects.begin_trial(x, v, d, w)
        status = _rk4_step(x, v, h, a1, m, d, w)
        if status == dyn.OK and effects.trial_kept(x, v, a1, m, d, w, h, known, kept):
            return status, h
        effects.undo_trial(x, v, d, w, kept)
    return _rk4_step(x, v, h_c, a1, m, d, w), h_c


# Steps after a contact (docs/physics.md section 7.1): every step is checked against the energy
# ledger, and one that used more than REFINE_SHARE of ``divergence.energy_error`` per second
# (times the step and the energy) is taken again at half the step, down to 1 / 2^REFINE_LEVELS:
# the step of ``dt`` where no contact limits it, the contact step where one does (two levels of
# their own). A level is undone while steps use less than REFINE_COARSEN of their share.
REFINE_SHARE = 1.0
REFINE_LEVELS = 4
REFINE_COARSEN = 1.0 / 64.0


@jit
def _rk4_run(m, d, w, dt, n_steps, tol, max_iter, kinks, project):
    """Advance ``d.x``, ``d.v`` by ``n_steps * dt`` with classical RK4; with ``kinks`` a step is
    shortened to land on the next cable slack/taut transition, with ``project`` positions and
    velocities are projected on the rigid members after every step (``rk4_projected``; without,
    ``rk4``: the constraints hold only at the acceleration level, so bar lengths drift, and
    ``tol``, ``max_iter`` are unused). One kernel for both methods, ``project`` an argument: one
    compilation instead of two.

    Where the effects ask for it (:func:`solver.kernels.effects.refining`: after a contact) each
    step is checked against its share of the energy ledger and taken again at half its length
    when it used more (:data:`REFINE_SHARE`); the two halving levels (``d.refine``: state of the
    run, which the Simulation keeps, restores and resets with the rest) carry over to the next
    call. Returns (RK4 steps taken, status)."""
    x, v, a1, topo = d.x, d.v, w.a1, m.topo
    effects.start(x, m, d)
    level, clevel = effects.halvings(m, d)        # halvings of dt, of the contact step
    total = n_steps * dt
    t = 0.0
    steps = 0
    e0 = math.nan                   # the energy at the step's start, when refining
    while total - t > 1e-9 * dt:
        refine = effects.refining(m, d)
        if not refine:
            level = clevel = 0
        h = min(dt * 0.5 ** level, total - t)
        at = effects.mark(d)        # the run state the step changes besides x, v
        met, p0, d0 = at
        if refine:
            effects.save_start(x, v, w)
            if e0 != e0:
                e0 = effects.ledger_energy(x, v, m, d)
        status = dyn.accelerations(x, v, m, d, w, a1)
        if status == dyn.OK and kinks:
            h = next_kink(x, v, a1, m, d, h, 1e-3 * dt)
        if status == dyn.OK:
            h = effects.fixed_step_limit(x, v, a1, m, h)
        h_free = h
        if status == dyn.OK:
            status, h = _controlled_step(x, v, h, a1, m, d, w, met, 0.5 ** clevel)
        if project and status == dyn.OK:
            status = dyn.project_positions(x, topo, w, tol, max_iter)
        if project and status == dyn.OK:
            status = dyn.project_velocities(x, v, topo, w)
        if status == dyn.OK and not (dyn.all_finite(x) and dyn.all_finite(v)):
            status = dyn.NONFINITE
        if status != dyn.OK:
            return steps, status
        if refine:
            e1 = effects.ledger_energy(x, v, m, d)
            err = abs(e1 + (effects.dissipated(d) - d0) - e0)
            budget = REFINE_SHARE * effects.rate(m) * h * abs(e0)
            limited = h < h_free        # shortened by a contact: its step is halved, else dt
            if err > budget and (clevel if limited else level) < REFINE_LEVELS:
                effects.back_to(x, v, d, w, at)
                if limited:
                    clevel += 1
                else:
                    level += 1
                continue
            if err < REFINE_COARSEN * budget:
                if limited and clevel > 0:
                    clevel -= 1
                elif not limited and level > 0:
                    level -= 1
            e0 = e1
        t += h
        steps += 1
    effects.finish(x, m, d)
    effects.keep_levels(m, d, level, clevel)
    return steps, dyn.OK


@jit
def _carried(x, v, carry):
    """Whether the call starts where the last one ended: ``carry[0]`` 1 and ``x``, ``v`` equal to
    the copies after it."""
    if carry[0] != 1.0:
        return False
    n = x.shape[0]
    for p in range(n):
        for i in range(3):
            if carry[1 + 3 * p + i] != x[p, i] or carry[1 + 3 * (n + p) + i] != v[p, i]:
                return False
    return True


@jit
def _hold(x, v, carry):
    n = x.shape[0]
    for p in range(n):
        for i in range(3):
            carry[1 + 3 * p + i] = x[p, i]
            carry[1 + 3 * (n + p) + i] = v[p, i]
    carry[0] = 1.0


@jit
def _rattle_run(m, d, w, dt, n_steps, tol, max_iter, acc, x_old, carry):
    """Velocity Verlet with RATTLE constraints, ``n_steps`` steps of ``dt``; scratch ``acc`` and
    ``x_old`` (n, 3). One force evaluation per step.

    Each step's position update uses the accelerations of the previous step's second stage. A
    call that starts from the state the last call ended at (``carry``: a flag and copies of
    ``x``, ``v``; cleared by :meth:`Rattle.state_changed` when a command changes the forces) uses
    the accelerations that call left in ``acc``, so a run split into calls takes the steps of one
    call; any other start evaluates them (one more force evaluation).

    Stage 1 (SHAKE): ``x+ = x + h v + h^2/2 a(x)``, projected on the rigid members; the half-step
    velocity is ``(x+ - x) / h`` (it includes the constraint impulse). Stage 2: ``v+ = v_1/2 +
    h/2 a(x+)``, projected on the tangent space. ``a`` already holds the acceleration-level
    multipliers, so ``x + h v + h^2/2 a`` misses the constraints by O(h^3) only; the Gauss-Newton
    projection (gradients at the iterate) then differs from SHAKE (gradients at ``x``) by
    O(h^4) per step, and it is converged to ``tol``. In stage 2 the constraint part of ``a(x+)``
    lies in the range the velocity projection removes, so stage 2 is exactly RATTLE's."""
    x, v, topo = d.x, d.v, m.topo
    effects.start(x, m, d)
    carried = _carried(x, v, carry)
    carry[0] = 0.0                  # set again by _hold when the call finishes
    if not carried:
        status = dyn.accelerations(x, v, m, d, w, acc)
        if status != dyn.OK:
            return 0, status
    n = x.shape[0]
    for step in range(n_steps):
        h = dt
        effects.gate(x, v, acc, m, d, h)
        for p in range(n):
            for i in range(3):
                x_old[p, i] = x[p, i]
                x[p, i] += h * v[p, i] + 0.5 * h * h * acc[p, i]
        status = dyn.project_positions(x, topo, w, tol, max_iter)
        if status == dyn.OK:
            for p in range(n):
                for i in range(3):
                    v[p, i] = (x[p, i] - x_old[p, i]) / h
            status = dyn.accelerations(x, v, m, d, w, acc)
        if status == dyn.OK:
            for p in range(n):
                for i in range(3):
                    v[p, i] += 0.5 * h * acc[p, i]
            status = dyn.project_velocities(x, v, topo, w)
        if status == dyn.OK and not (dyn.all_finite(x) and dyn.all_finite(v)):
            status = dyn.NONFINITE
        if status != dyn.OK:
            return step, status
    effects.finish(x, m, d)
    _hold(x, v, carry)
    return n_steps, dyn.OK


# The checked kernels (Integrator.checked_args): the run kernel between copy_data (the data kept
# to restore) and summary.state_summary, in one compiled call (a Simulation.advance makes no
# other).
@jit
def _rk4_checked(m, d, w, dt, n_steps, tol, max_iter, kinks, project, kept, heights):
    copy_data(d, kept)
    out = _rk4_run(m, d, w, dt, n_steps, tol, max_iter, kinks, project)
    return out + summary.state_summary(d.x, d.v, m, d, heights)


@jit
def _rattle_checked(m, d, w, dt, n_steps, tol, max_iter, acc, x_old, carry, kept, heights):
    copy_data(d, kept)
    out = _rattle_run(m, d, w, dt, n_steps, tol, max_iter, acc, x_old, carry)
    return out + summary.state_summary(d.x, d.v, m, d, heights)


# The ramped kernels (Integrator.ramped): the run kernel one step of dt at a time from step k0 of
# n_steps, the rest lengths of the prestrain ramp r set before each step and after the last
# (ramp.set_rest), in one compiled call. They return (steps done, the kernel's steps, status,
# what the last set_rest returned) and the end state's summary when they reach the end of the
# interval (ramp.finish): they stop after the step whose rest lengths end the ramp, after a
# failed step, or before rest lengths that break the model's symmetry (left unset).
@jit
def _rk4_ramped(m, d, w, dt, n_steps, tol, max_iter, kinks, project, r, k0, heights):
    taken = 0
    for k in range(k0, n_steps + 1):
        went = ramp.set_rest(m, d, r, k)
        if went == ramp.ASYMMETRIC or k == n_steps:
            return ramp.finish(m, d, k, taken, dyn.OK, went, heights, went != ramp.ASYMMETRIC)
        steps, status = _rk4_run(m, d, w, dt, 1, tol, max_iter, kinks, project)
        taken += steps
        if status != dyn.OK or went == ramp.ENDED:
            return ramp.finish(m, d, k + 1, taken, status, went, heights,
                               status == dyn.OK and k + 1 == n_steps)
    return ramp.finish(m, d, n_steps, taken, dyn.OK, ramp.SET, heights, False)


@jit
def _rattle_ramped(m, d, w, dt, n_steps, tol, max_iter, acc, x_old, carry, r, k0, heights):
    taken = 0
    for k in range(k0, n_steps + 1):
        went = ramp.set_rest(m, d, r, k)
        if went == ramp.ASYMMETRIC:
            return ramp.finish(m, d, k, taken, dyn.OK, went, heights, False)
        carry[0] = 0.0              # new forces: Rattle.state_changed
        if k == n_steps:
            return ramp.finish(m, d, k, taken, dyn.OK, went, heights, True)
        steps, status = _rattle_run(m, d, w, dt, 1, tol, max_iter, acc, x_old, carry)
        taken += steps
        if status != dyn.OK or went == ramp.ENDED:
            return ramp.finish(m, d, k + 1, taken, status, went, heights,
                               status == dyn.OK and k + 1 == n_steps)
    return ramp.finish(m, d, n_steps, taken, dyn.OK, ramp.SET, heights, False)


class RK4Projected(Integrator):
    """Classical RK4, then mass-weighted projection of positions and velocities after every step
    (docs/physics.md section 1.2). Four force evaluations per step; steps land on cable kinks."""
    name = 'rk4_projected'
    order = 4
    projected = True
    evaluations_per_step = 4
    kernel = staticmethod(_rk4_run)
    checked = staticmethod(_rk4_checked)
    ramped = staticmethod(_rk4_ramped)

    def extra_args(self, x, kinks):
        return (bool(kinks), self.projected)


class RK4(RK4Projected):
    """Classical RK4 without projection: bar lengths drift (shown, not hidden). Steps land on
    kinks."""
    name = 'rk4'
    projected = False


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
    ramped = staticmethod(_rattle_ramped)

    def extra_args(self, x, kinks):
        return (self.scratch('acc', x.shape), self.scratch('x_old', x.shape),
                self.scratch('carry', (1 + 2 * x.size,)))

    def reset(self):
        self.state_changed()

    def state_changed(self):
        carry = self._scratch.get('carry')
        if carry is not None:
            carry[0] = 0.0
