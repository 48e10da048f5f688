"""What every simulation provides, written as code: :class:`SimulationAPI`, the abstract base that
:class:`~solver.simulate.simulation.Simulation` (one network) and
:class:`~solver.simulate.array.ArraySimulation` (independent columns, one simulation per group of
alike columns) implement. Runs, batches, the node and the lens use a simulation through it only.

Every implementation also sets these attributes: ``scene`` (its :class:`Scene`), ``network``
(the full network: frames and commands are in its node and cable order), ``dt`` s,
``integrator``, ``div`` (the scene's divergence limits), ``model`` (a
:class:`~solver.models.base.ModelView`: the state as full arrays), ``bar_contact`` (the contact
the run has: the scene's ``contact.bars`` or why none), ``expanded`` (why a reduced model was
expanded to ``full3d``, or None), and the clock ``t`` s, ``step`` (steps of ``dt`` since the
reset) and ``steps_taken`` (integrator steps, sub-steps included).
"""
from __future__ import annotations

from abc import ABC, abstractmethod


class SimulationAPI(ABC):
    """The interface of a simulation (see the module text)."""

    # -- the clock ------------------------------------------------------------------------------
    @abstractmethod
    def reset(self):
        """Back to the reference geometry at rest, t = 0, rest lengths of the scene."""

    @abstractmethod
    def advance(self, duration):
        """Advance by ``duration`` s in whole steps of ``dt``; returns the integrator steps taken.
        Raises :class:`~solver.simulate.checks.SimulationDiverged` (the state restored) when a
        check fails."""

    @abstractmethod
    def advance_part(self, fraction):
        """Advance by one step shortened to ``fraction`` (0 < fraction <= 1) of ``dt``, checked
        like :meth:`advance`."""

    # -- commands -------------------------------------------------------------------------------
    @abstractmethod
    def apply_impact(self, v0, columns=None, mode=None):
        """Impact the free ends of the addressed columns at ``v0`` m/s; returns the work J."""

    @abstractmethod
    def prestrain_target(self, p, columns=None):
        """The per-prism prestrain (n_columns, n_prisms) a prestrain command of ``p`` on
        ``columns`` sets (columns not addressed keep their target). Raises ``ValueError``."""

    @abstractmethod
    def apply_prestrain(self, p, columns=None, ramp_s=0.0):
        """Change the cross prestrain of the addressed columns over ``ramp_s`` s."""

    @abstractmethod
    def set_cable_rest_lengths(self, rest):
        """Set every cable's rest length (n_cables,) m."""

    @property
    @abstractmethod
    def prestrain(self):
        """The current cross prestrain per prism (n_columns, n_prisms), or None (no columns)."""

    @property
    @abstractmethod
    def prestrain_goal(self):
        """The prestrain per prism (n_columns, n_prisms) the columns ramp to, or have."""

    @property
    @abstractmethod
    def prestrain_map(self):
        """The :class:`~solver.build.structures.PrestrainMap` of the network."""

    # -- the state ------------------------------------------------------------------------------
    @abstractmethod
    def frame(self):
        """A copied :class:`~solver.simulate.simulation.Frame` of the current state."""

    @abstractmethod
    def frame_figures(self):
        """The :class:`~solver.simulate.simulation.FrameFigures` of the current state."""

    @abstractmethod
    def energy(self):
        """Total mechanical energy J."""

    @abstractmethod
    def energy_error(self):
        """The energy balance error (signed, relative) of the ledger."""

    @abstractmethod
    def energy_work(self):
        """Work J the commands put in since the reset."""

    @abstractmethod
    def constraint_error(self):
        """The largest relative violation of a rigid member."""

    @property
    @abstractmethod
    def contacts_met(self):
        """Force evaluations in which bars or bases touched, since the reset."""

    @abstractmethod
    def base_force(self):
        """Axial base force (n_columns,) N, positive compressive."""

    @abstractmethod
    def striker(self):
        """(n_columns, 2) striker face height m and axial velocity m/s, or None."""
