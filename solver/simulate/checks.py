"""What makes a simulation stop itself: the checks after every interval (:meth:`Checks._check`:
finite state, integrator status, constraint error, energy balance, prism heights and twists), the
state kept to restore, and the search for the first failing step that names it in a
:class:`SimulationDiverged`. A mixin of :class:`solver.simulate.simulation.Simulation`."""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from solver import status as codes
from solver.analysis import observables
from solver.kernels import dynamics as dyn


class SimulationDiverged(RuntimeError):
    """The run stopped itself: ``t`` s, ``step``, the ``quantity`` that failed and a ``hint``."""

    def __init__(self, t, step, quantity, detail, hint):
        self.t, self.step, self.quantity, self.hint = t, step, quantity, hint
        super().__init__(f'simulation diverged at t = {t:.6g} s (step {step}): {quantity} '
                         f'{detail}; {hint}')

    def for_columns(self, columns):
        """This exception of a one-column simulation, its text naming an array's ``columns``."""
        text = str(self)
        name = (f'column {columns[0]}' if len(columns) == 1
                else f'columns {", ".join(map(str, columns))}')
        if 'column 0' in text:
            text = re.sub(r'\bcolumn 0\b', name, text)
        else:
            text = text.replace(': ', f': {name}: ', 1)
        new = SimulationDiverged(self.t, self.step, self.quantity, '', self.hint)
        new.args = (text,)
        return new


@dataclass(frozen=True)
class Kept:
    """The state :meth:`Checks._restore` goes back to: the model's ``data`` and the
    ``integrator``'s state, the prestrain and its ramp, the energy reference and scale, the prism
    twists last accepted."""
    data: object
    integrator: object
    prestrain: object
    ramp: object
    energy_ref: float
    energy_scale: float
    twist_ref: object


class Checks:
    """The divergence checks of a :class:`~solver.simulate.simulation.Simulation` (which
    provides the state, the cached summary and the clock)."""

    def _keep(self):
        return self._kept(self.model.keep(), self.integrator.get_state())

    def _kept(self, data, integ_state):
        """What :meth:`_restore` takes: the model's data kept before an interval (``data``: what
        :meth:`~solver.models.base.Model.keep` returns), the integrator's state and the run's
        (read now: the steps do not change them)."""
        return Kept(data, integ_state, self._prestrain, self._ramp, self._energy_ref,
                    self._energy_scale, self._twist_ref)

    def _restore(self, keep):
        self.model.restore(keep.data)
        self._prestrain, self._ramp, self._energy_ref = keep.prestrain, keep.ramp, keep.energy_ref
        self.integrator.set_state(keep.integrator)
        self.integrator.state_changed()
        self._energy_scale = keep.energy_scale
        self._twist_ref = keep.twist_ref
        self._changed()

    def _check(self, status):
        """``(quantity, detail, hint)`` of the first failed divergence check of the current state
        after an integrator ``status``, or None when the state is sound."""
        finite, e, h, err, h_min = self._summary()
        if not finite:
            return 'state', 'non-finite positions or velocities', codes.HINT_STEP
        if status != dyn.OK:
            quantity, hint = codes.DIAGNOSIS.get(status, ('state', codes.HINT_STEP))
            return quantity, codes.text(status), hint
        if not err <= self.div.constraint_error:
            return ('constraint error', f'{err:.3g} exceeds {self.div.constraint_error:g}',
                    codes.HINT_CONSTRAINT)
        err = self._balance(e)
        if not (err <= self.div.energy_error
                and (err >= -self.div.energy_error
                     or (self.effects.damp is not None and not self._books_dissipation))):
            return ('energy balance', f'{"gained" if err > 0 else "lost"} {abs(err):.3g} of the '
                                      f'energy scale (limit {self.div.energy_error:g})',
                    codes.HINT_ENERGY)
        net = self.network
        if net.levels.size:
            if h.size and not h_min > 0.0:
                c, i = np.unravel_index(int(np.argmin(np.where(np.isfinite(h), h, -np.inf))),
                                        h.shape)
                return ('prism height', f'prism {i} of column {c} collapsed (height '
                                        f'{h[c, i]:.3g} m)', codes.HINT_SLACK)
            twist = self._twists()
            if twist is not None:
                ref = self._twist_ref
                # a prism whose twist changed sign since the last accepted check went through
                # 0 deg (pulled out to its full bar length and on to the other hand: followed)
                # or through 180 deg (its bars crossed at the lock), whichever is the shorter way
                locked = ~(twist * ref > 0.0) & ~(np.abs(twist) + np.abs(ref) <= math.pi)
                if np.any(locked):
                    c, i = np.argwhere(locked)[0]
                    hint = (codes.HINT_LOCK_CONTACT if self.effects.stop_h is not None
                            else codes.HINT_LOCK_BARS if not self.bar_contact.startswith('none')
                            else codes.HINT_LOCK)
                    return ('prism twist', f'prism {i} of column {c} twisted through 180 deg '
                                           f'({math.degrees(twist[c, i]):.1f} deg)', hint)
                self._twist_ref = twist
        return None

    def _twists(self):
        """Prism twists (n_columns, n_prisms) rad of the current state, where the twist is
        checked (``divergence.bar_crossing``), else None."""
        if not (self._check_twist and self.network.levels.size):
            return None
        return observables.prism_twists(self._full_state().x, self.network.levels)

    def _locate(self, n, keep, problem):
        """The :class:`SimulationDiverged` of an interval of ``n`` steps that failed with
        ``problem``: replays it one step at a time from ``keep`` to name the first failing step
        (the state is restored afterwards)."""
        t0 = self.t
        k_fail, found = n - 1, problem
        try:
            for k in range(n):
                self.t = t0 + k * self.dt
                _, status = self._integrate(1)
                p = self._check(status)
                if p is not None:
                    k_fail, found = k, p
                    break
        finally:
            self.t = t0
            self._restore(keep)
        quantity, detail, hint = found
        return SimulationDiverged(t0 + (k_fail + 1) * self.dt, self.step + k_fail + 1, quantity,
                                  detail, hint)
