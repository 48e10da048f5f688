"""The interface every integrator family implements (the contract is in
:mod:`solver.integrators.registry`, which lists the families)."""
from __future__ import annotations

import copy

import numpy as np


class Integrator:
    """A method behind one interface. ``kernel`` is the ``@jit`` run function described in the
    module doc, ``checked`` its twin (see :meth:`checked_args`), ``ramped`` (or None) its twin
    under a prestrain ramp (see :meth:`ramped_args`); ``extra_args`` gives the kernel
    arguments after ``max_iter``; ``evaluations_per_step`` counts force evaluations (for work
    estimates)."""
    name = ''
    order = 0
    projected = False
    adaptive = False
    evaluations_per_step = 0
    kernel = None
    checked = None
    ramped = None

    def __init__(self, rtol=1e-8, atol=1e-10):
        self.rtol, self.atol = float(rtol), float(atol)
        self._scratch = {}

    def clone(self):
        """An independent copy with the same settings and history (:meth:`get_state`), and its
        own scratch and state arrays: simulations stepped at once on threads must not share the
        arrays their kernels write."""
        new = copy.copy(self)
        new._scratch = {}
        for name, value in vars(self).items():
            if isinstance(value, np.ndarray):
                setattr(new, name, value.copy())
        return new

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

    def state_changed(self):
        """The state or the forces were changed outside the integrator (a command, new rest
        lengths): forget what a method carries from one call to the next (``rattle``'s
        accelerations)."""

    def get_state(self):
        """A copy of the integrator's own state (step-size history), for :meth:`set_state`."""
        return None

    def set_state(self, state):
        pass

    def run(self, m, d, w, dt, n_steps, tol=1e-12, max_iter=3, kinks=True):
        """Advance ``d.x``, ``d.v`` (the state of the model record ``m``, its data ``d`` and
        scratch ``w``, :mod:`solver.kernels.records`) in place by ``n_steps * dt`` s; returns
        (steps, status)."""
        steps, status = self.kernel(m, d, w, float(dt), int(n_steps), float(tol), int(max_iter),
                                    *self.extra_args(d.x, kinks))
        return int(steps), int(status)

    def checked_args(self, m, d, w, tol, max_iter, kinks, kept):
        """The arguments of ``checked`` between ``n_steps`` and ``heights``: ``checked(m, d, w,
        dt, n_steps, *checked_args(...), heights)`` is :meth:`run` in one compiled call that
        first copies the data ``d`` into ``kept`` (:func:`solver.kernels.records.copy_data`: the
        state to restore when a check fails) and then summarises the end state
        (:func:`solver.kernels.summary.state_summary`, prism heights into ``heights``),
        returning ``(steps, status, finite, energy J, relative constraint error, smallest prism
        height m)``. ``Simulation.advance`` builds them once per model."""
        return (float(tol), int(max_iter)) + tuple(self.extra_args(d.x, kinks)) + (kept,)

    def ramped_args(self, m, d, w, tol, max_iter, kinks):
        """The arguments of ``ramped`` between ``n_steps`` and the ramp: ``ramped(m, d, w, dt,
        n_steps, *ramped_args(...), r, k0, heights)`` is, from step ``k0`` of ``n_steps``,
        the rest lengths of the :class:`solver.kernels.ramp.Ramp` ``r`` at that step
        (:func:`solver.kernels.ramp.set_rest`) then :meth:`run` of one step, in one compiled
        call (and the rest lengths after the last step); it returns ``(steps done, the kernel's
        steps, status, what the last set_rest returned)`` and, after the rest lengths at the
        end, the state summary of ``checked`` (else ``(False, NaN, NaN, NaN)``:
        :func:`solver.kernels.ramp.finish`), stopping after a failed step, after the step the
        ramp ended on, or before rest lengths the model cannot hold (left unset). Whatever
        :meth:`state_changed` forgets the twin forgets after each change."""
        return (float(tol), int(max_iter)) + tuple(self.extra_args(d.x, kinks))
