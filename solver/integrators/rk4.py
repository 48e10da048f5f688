"""Classical RK4 (plain and projected) and velocity Verlet with RATTLE constraints: fixed-step
kernels and their :class:`~solver.integrators.base.Integrator` classes."""
from __future__ import annotations

import math

from solver._jit import jit
from solver.integrators.base import Integrator
from solver.kernels import dynamics as dyn
from solver.kernels import summary
from solver.kernels.barcontact import remember
from solver.kernels.contactsteps import (add_motion, bounded_contact_energy, contact_step, gate,
                                       motion_so_far, passed_clear, rescan, resume)
from solver.kernels.contact import striker_step
from solver.kernels.kinks import keep_state, next_kink


@jit
def _rk4_step(x, v, h, a1, net, act, ws):
    """One classical RK4 step of size h of ``x' = v, v' = a(x, v)`` given the first-stage
    acceleration ``a1 = a(x, v)``; the new state is left in ``x``, ``v``."""
    xs, vs, acc, xacc, vacc = ws[5], ws[6], ws[7], ws[8], ws[9]
    n = x.shape[0]
    dis = act[3][10]                # damping: its power at each stage, Simpson-weighted
    damped = act[3][0].shape[0] != 0
    work = dis[0]
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
        if damped:
            work += w * dis[0]
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
    if damped:
        dis[1] += h / 6.0 * work
    return dyn.OK



@jit
def _kept_balance(x0, v0, x, v, net, act, h, dissipated):
    """Whether a step of ``h`` from ``x0``, ``v0`` to ``x``, ``v`` that met no contact (cable
    damping having taken out ``dissipated`` J before it) kept the energy balance within its
    share of the ledger's limit: ``|E1 + D1 - D0 - E0| <= rate h |E0|``, ``rate`` =
    ``divergence.energy_error`` per second (``act[3][20]``). Beside contacts the bars vibrate
    fast: a whole step that passes clear of every contact can still be too long for them. True
    where the extras carry no energy arrays."""
    e0 = summary.step_energy(x0, v0, net, act)
    if e0 != e0:
        return True
    ex = act[3]
    e1 = summary.step_energy(x, v, net, act)
    return abs(e1 + (ex[10][1] - dissipated) - e0) <= ex[20][0] * h * abs(e0)


@jit
def _contact_aware_step(x, v, h, a1, net, act, ws, met, scale):
    """One RK4 step from a state whose accelerations ``a1`` were just evaluated (``met``: the
    contact count before that evaluation), with bar contact on
    (:mod:`solver.kernels.barcontact`): the plain step of ``h`` when no contact can start within
    it; when one could, the plain step is still tried, with the contact forces looked for, and
    kept if none of its evaluations met a contact, it surely passed clear of every contact
    (:func:`~solver.kernels.contactsteps.passed_clear`: a near miss changes nothing) and it kept
    the energy balance (:func:`_kept_balance`); otherwise,
    and while a contact lasts, the step of
    :func:`~solver.kernels.contactsteps.contact_step` times ``scale`` (``_rk4_run``'s contact
    refinement). Returns (status, the step taken)."""
    ex = act[3]
    touched_at_start = ex[8][0] > met
    known = motion_so_far(ex[8])
    h_c = contact_step(x, v, a1, ex[6], ex[1], ex[7], h, ex[8], ex[11])
    if h_c >= h:
        return _rk4_step(x, v, h, a1, net, act, ws), h
    h_c *= scale
    flag = ex[8][2]
    if not touched_at_start:
        saved = ex[9]
        saved[0, :, :] = x
        saved[1, :, :] = v
        before = ex[8][0]
        power, dissipated = ex[10][0], ex[10][1]
        ex[8][2] = 1.0
        status = _rk4_step(x, v, h, a1, net, act, ws)
        if status == dyn.OK and ex[8][0] == before and passed_clear(
                saved[0], saved[1], a1, x, ex[6], ex[1], ex[7], h, ex[8], known) and (
                _kept_balance(saved[0], saved[1], x, v, net, act, h, dissipated)):
            add_motion(ex[8], saved[1], a1, h)  # the slack was for the shorter step
            ex[11][0] = -1
            return status, h
        x[:, :] = saved[0]
        v[:, :] = saved[1]
        ex[8][0] = before
        if ex[10].shape[0] != 0:        # the damping's ledger back to the step's start
            ex[10][0] = power
            ex[10][1] = dissipated
        ex[8][2] = flag
    return _rk4_step(x, v, h_c, a1, net, act, ws), h_c


# Steps after a contact (docs/physics.md section 7.1): every step is checked against the energy
# ledger, and one that used more than REFINE_SHARE of ``divergence.energy_error`` per second
# (times the step and the energy) is taken again at half the step, down to 1 / 2^REFINE_LEVELS:
# the step of ``dt`` where no contact limits it, the contact step where one does (two levels of
# their own). A level is undone while steps use less than REFINE_COARSEN of their share.
REFINE_SHARE = 1.0
REFINE_LEVELS = 4
REFINE_COARSEN = 1.0 / 64.0


@jit
def _refining(ex):
    """Whether the steps are checked against the energy ledger (:data:`REFINE_SHARE`): bar
    contact with the energy slots (``act[3][12:21]``), and a contact met since the reset. Until
    a contact, the steps are the plain ones. Contacts excite the fast vibrations of bars and
    nodes, which RK4 at the scene's step damps, and a lasting contact oscillates stiffly: both
    lose energy, which the ledger counts."""
    return ex[6].shape[0] != 0 and ex[13].shape[0] != 0 and ex[20].shape[0] > 2 and (
        ex[8][0] > 0.0)


@jit
def _ledger_energy(x, v, net, act):
    """Energy J of a state within or at the end of a step the contact scans bounded: without
    contact (:func:`~solver.kernels.summary.step_energy`) plus what touching bars and bases store
    (:func:`~solver.kernels.contactsteps.bounded_contact_energy`)."""
    ex = act[3]
    return summary.step_energy(x, v, net, act) + bounded_contact_energy(x, ex[6], ex[1], ex[7],
                                                                         ex[8])


@jit
def _rk4_run(x, v, dt, n_steps, net, act, ws, tol, max_iter, kinks, project):
    """Advance by ``n_steps * dt`` with classical RK4; with ``kinks`` a step is shortened to land
    on the next cable slack/taut transition, with ``project`` positions and velocities are
    projected on the rigid members after every step (``rk4_projected``; without, ``rk4``: the
    constraints hold only at the acceleration level, so bar lengths drift, and ``tol``,
    ``max_iter`` are unused). One kernel for both methods, ``project`` an argument: one
    compilation instead of two.

    After a contact (:func:`_refining`) each step is checked against its share of the energy
    ledger and taken again at half its length when it used more (:data:`REFINE_SHARE`); the two
    halving levels (``act[3][20][1:3]``: state of the run, which the Simulation keeps, restores
    and resets with the rest) carry over to the next call. Returns (RK4 steps taken, status)."""
    a1 = ws[10]
    ex = act[3]
    contact = ex[6].shape[0] != 0
    level = clevel = 0              # halvings of dt, of the contact step
    if contact:
        if ex[20].shape[0] > 2:
            level, clevel = int(ex[20][1]), int(ex[20][2])
        resume(x, ex[8], ex[11])    # the contact scans (kernels.contactsteps)
    total = n_steps * dt
    t = 0.0
    steps = 0
    e0 = math.nan                   # the energy at the step's start, when refining
    while total - t > 1e-9 * dt:
        refine = contact and _refining(ex)
        if not refine:
            level = clevel = 0
        h = min(dt * 0.5 ** level, total - t)
        p0 = d0 = 0.0
        met = ex[8][0]              # contacts met so far (kernels.barcontact)
        if refine:
            ex[9][0, :, :] = x
            ex[9][1, :, :] = v
            if e0 != e0:
                e0 = _ledger_energy(x, v, net, act)
            if ex[10].shape[0] != 0:
                p0, d0 = ex[10][0], ex[10][1]
        status = dyn.accelerations(x, v, net, act, ws, a1)
        if status == dyn.OK and kinks:
            h = next_kink(x, v, a1, net, act, h, 1e-3 * dt)
        if status == dyn.OK and ex[3].shape[0] != 0:
            h = striker_step(x, v, a1, ex, h)
        h_free = h
        if status == dyn.OK and contact:
            status, h = _contact_aware_step(x, v, h, a1, net, act, ws, met, 0.5 ** clevel)
        elif status == dyn.OK:
            status = _rk4_step(x, v, h, a1, net, act, ws)
        if project and status == dyn.OK:
            status = dyn.project_positions(x, net, ws, tol, max_iter)
        if project and status == dyn.OK:
            status = dyn.project_velocities(x, v, net, ws)
        if status == dyn.OK and not (dyn.all_finite(x) and dyn.all_finite(v)):
            status = dyn.NONFINITE
        if status != dyn.OK:
            return steps, status
        if refine:
            e1 = _ledger_energy(x, v, net, act)
            d1 = ex[10][1] if ex[10].shape[0] != 0 else 0.0
            err = abs(e1 + (d1 - d0) - e0)
            budget = REFINE_SHARE * ex[20][0] * h * abs(e0)
            limited = h < h_free        # shortened by a contact: its step is halved, else dt
            if err > budget and (clevel if limited else level) < REFINE_LEVELS:
                x[:, :] = ex[9][0]
                v[:, :] = ex[9][1]
                if ex[10].shape[0] != 0:
                    ex[10][0] = p0
                    ex[10][1] = d0
                ex[8][0] = met
                rescan(ex[8], ex[11])
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
    if contact:
        remember(x, ex[8])
    if ex[20].shape[0] > 2:
        ex[20][1] = level
        ex[20][2] = clevel
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
def _rattle_run(x, v, dt, n_steps, net, act, ws, tol, max_iter, acc, x_old, carry):
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
    ex = act[3]
    contact = ex[6].shape[0] != 0
    if contact:     # the pairs that could touch, listed by the scans (kernels.contactsteps)
        resume(x, ex[8], ex[11])
    carried = _carried(x, v, carry)
    carry[0] = 0.0                  # set again by _hold when the call finishes
    if not carried:
        status = dyn.accelerations(x, v, net, act, ws, acc)
        if status != dyn.OK:
            return 0, status
    n = x.shape[0]
    for step in range(n_steps):
        h = dt
        if contact:
            gate(x, v, acc, ex[6], ex[1], ex[7], h, ex[8], ex[11])
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
    if contact:
        remember(x, ex[8])
    _hold(x, v, carry)
    return n_steps, dyn.OK



# The checked kernels (Integrator.checked_args): the run kernel between keep_state and
# summary.state_summary, in one compiled call (a Simulation.advance makes no other).
@jit
def _rk4_checked(x, v, dt, n_steps, net, act, ws, tol, max_iter, kinks, project, keep, summ,
                 heights):
    keep_state(x, v, act, keep)
    out = _rk4_run(x, v, dt, n_steps, net, act, ws, tol, max_iter, kinks, project)
    return out + summary.state_summary(x, v, net, act, summ, heights)


@jit
def _rattle_checked(x, v, dt, n_steps, net, act, ws, tol, max_iter, acc, x_old, carry, keep,
                    summ, heights):
    keep_state(x, v, act, keep)
    out = _rattle_run(x, v, dt, n_steps, net, act, ws, tol, max_iter, acc, x_old, carry)
    return out + summary.state_summary(x, v, net, act, summ, heights)


class RK4Projected(Integrator):
    """Classical RK4, then mass-weighted projection of positions and velocities after every step
    (docs/physics.md section 1.2). Four force evaluations per step; steps land on cable kinks."""
    name = 'rk4_projected'
    order = 4
    projected = True
    evaluations_per_step = 4
    kernel = staticmethod(_rk4_run)
    checked = staticmethod(_rk4_checked)

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

    def extra_args(self, x, kinks):
        return (self.scratch('acc', x.shape), self.scratch('x_old', x.shape),
                self.scratch('carry', (1 + 2 * x.size,)))

    def reset(self):
        self.state_changed()

    def state_changed(self):
        carry = self._scratch.get('carry')
        if carry is not None:
            carry[0] = 0.0
