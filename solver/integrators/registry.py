"""Time integrators behind one interface.

An integrator advances the positions ``d.x`` (n_rows, 3) m and velocities ``d.v`` (n_rows, 3) m/s
of a model's data in place by ``n_steps`` fixed steps of ``dt`` s, with the model record ``m``,
its data ``d`` and scratch ``w`` (:mod:`solver.kernels.records`), and returns ``(steps_done,
status)``; a non-OK status stops it at the step that failed, leaving the last good state in
``d.x`` and ``d.v``.

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
  (:mod:`solver.integrators.implicit`), for stiff scenes: order 2, A-stable, Newton on a banded KKT
  system per step, then projection; fixed steps.

To add a method: in a new file of ``solver/integrators/``, write an ``@jit`` kernel ``_my_run(m,
d, w, dt, n_steps, tol, max_iter, kinks)`` with that contract, calling only
:func:`solver.kernels.dynamics.accelerations` (the forces of every effect), ``project_positions``,
``project_velocities``, ``all_finite``, :func:`solver.kernels.kinks.next_kink` and the step
control of :mod:`solver.kernels.effects` (``start``/``finish`` around the call, and the limits
its kind of step needs), passing the records through untouched: an integrator never asks which
effects a scene has (``test_layering`` checks it). Write its checked twin (three lines, as
:func:`solver.integrators.rk4._rk4_checked`: ``copy_data``, the run kernel, then
``summary.state_summary``: a ``Simulation.advance`` is then one compiled call), subclass
:class:`solver.integrators.base.Integrator` (``name``, ``order``, ``projected``, ``kernel``,
``checked``; override :meth:`Integrator.extra_args` when the kernel takes other arguments after
``max_iter``, e.g. scratch arrays from :meth:`Integrator.scratch`) and add it to
:data:`METHODS`. Keep every array the kernel writes in the scratch or in an array attribute:
:meth:`Integrator.clone` copies those for a simulation's copy (the columns of an array step on
threads at once). A method that carries something from one call to the next (``rattle`` its
accelerations, ``dopri54_projected`` its step size) forgets it in :meth:`Integrator.reset` and,
where a command invalidates it, in :meth:`Integrator.state_changed`.
"""
from __future__ import annotations

from solver.integrators.dopri import DOPRI54Projected
from solver.integrators.implicit import ImplicitMidpoint
from solver.integrators.rk4 import RK4, RK4Projected, Rattle
from solver.kernels.kinks import next_kink  # noqa: F401  (part of the family's contract)
from solver.status import STEP_TOO_SMALL  # noqa: F401

METHODS = {cls.name: cls for cls in (RK4Projected, RK4, Rattle, DOPRI54Projected,
                                     ImplicitMidpoint)}



def get(name, **options):
    """The integrator called ``name`` (``options``: ``rtol``, ``atol`` of adaptive methods); an
    unknown name lists the valid ones."""
    try:
        cls = METHODS[name]
    except KeyError:
        valid = ', '.join(sorted(METHODS))
        raise ValueError(f'unknown integrator {name!r}; valid: {valid}') from None
    return cls(**options)
