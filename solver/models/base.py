"""The interface every model implements (``full3d``, ``sym3d``, ``chain1d``), written as code.

A model owns the state of one network. :class:`Model` is what
:class:`~solver.simulate.simulation.Simulation` and the node use of any model; a model stepped by
an integrator on the records of :mod:`solver.kernels.records` is a :class:`RecordModel`
(``full3d``, ``sym3d``), a model with its own kernel a :class:`SelfIntegrating` one
(``chain1d``). A setter that cannot keep the model's assumptions (an asymmetric state for
``sym3d``) raises and changes nothing; the simulation then expands the run to ``full3d``.
"""
from __future__ import annotations

import copy
from abc import ABC, abstractmethod

import numpy as np

from solver.kernels import records


class ModelView(ABC):
    """What callers read and set of a model: ``name``, its state as full (n_nodes, 3) arrays, its
    cables (an array of columns offers this view of all its columns' models)."""
    name = ''
    n_strikers = 0          # rows of the state arrays after the nodes, one per striker

    @abstractmethod
    def positions(self):
        """Full (n_nodes, 3) positions m (may be shared: read only)."""

    @abstractmethod
    def velocities(self):
        """Full (n_nodes, 3) velocities m/s (may be shared: read only)."""

    @abstractmethod
    def set_state(self, x, v):
        """Load a full state (n_nodes, 3) m and m/s."""

    @property
    @abstractmethod
    def cable_rest_length(self):
        """Full (n_cables,) rest lengths m."""

    @property
    @abstractmethod
    def cable_EA(self):
        """Full (n_cables,) EA N."""

    @abstractmethod
    def set_cables(self, rest, EA):
        """Load full (n_cables,) rest lengths m and EA N."""


class Model(ModelView):
    """A model of one network (``network``: the full :class:`~solver.build.network.Network`),
    stepped by a :class:`~solver.simulate.simulation.Simulation`. Capabilities: ``exact`` (a
    summary of its own state in one compiled pass), ``integrates_itself`` (its own kernel),
    ``reduced`` (the reduced network of a symmetric reduction, else None), ``has_bars`` (bars that
    can touch). The run state the steps keep besides positions and velocities (contacts met,
    energy dissipated, the refinement levels) reads 0 and None in a model without it."""
    integrates_itself = False
    exact = False
    has_bars = True
    reduced = None

    def __init__(self, network):
        self.network = network

    @property
    def contacts_met(self):
        """Force evaluations that met a touching pair of bars or two touching bases."""
        return 0

    def dissipated(self):
        """Energy J cable damping took out (as booked by the integrator)."""
        return 0.0

    def set_dissipated(self, value):
        """Set the energy J cable damping took out."""

    def refinement(self):
        """``(contacts met, the two halving levels)`` of the steps after a contact, or None
        where they are never refined."""
        return None

    def set_refinement(self, kept):
        """Set what :meth:`refinement` returned."""

    @abstractmethod
    def keep(self):
        """What :meth:`restore` takes back: everything the steps change (a copy)."""

    @abstractmethod
    def restore(self, kept):
        """Back to the state :meth:`keep` returned."""

    @abstractmethod
    def copy(self):
        """An independent copy: the state its own, the constants shared."""


class RecordModel(Model):
    """A model stepped by an integrator: the records ``rec`` (constants), ``data`` and ``work``
    of :mod:`solver.kernels.records`, built once (:func:`solver.models.extras.build`); ``exact``:
    whether ``rec.summary`` summarises its state (else the simulation computes the summary from
    the full state); ``effects``: the :class:`~solver.models.extras.Effects` it was built with.
    The state arrays may carry rows beyond the network's nodes: one per striker."""
    rec: records.Model
    data: records.Data
    work: records.Work
    exact = True

    @property
    def x(self):
        return self.data.x

    @property
    def v(self):
        return self.data.v

    @property
    def n_strikers(self):
        return self.rec.strikers.row.shape[0]

    @property
    def contacts_met(self):
        if not self.rec.bar_contact.pairs.shape[0]:
            return 0
        return int(self.data.contact.scan[records.MET])

    def dissipated(self):
        return float(self.data.ledger[records.DISSIPATED])

    def set_dissipated(self, value):
        self.data.ledger[records.DISSIPATED] = value

    def refinement(self):
        if not self.rec.ledger.refine:
            return None
        r = self.data.refine
        return (float(self.data.contact.scan[records.MET]), float(r[records.STEP_LEVEL]),
                float(r[records.CONTACT_LEVEL]))

    def set_refinement(self, kept):
        if kept is not None and self.rec.ledger.refine:
            met, level, clevel = kept
            self.data.contact.scan[records.MET] = met
            self.data.refine[records.STEP_LEVEL] = level
            self.data.refine[records.CONTACT_LEVEL] = clevel

    def keep(self):
        return records.clone_data(self.data)

    def restore(self, kept):
        """Copy ``kept`` back into the data. The contact scans start over (the next call
        rescans): what they knew held for the positions the failed steps reached."""
        records.copy_data(kept, self.data)
        scan = self.data.contact.scan
        if self.rec.bar_contact.pairs.shape[0]:
            scan[scan.shape[0] - 3 * self.data.x.shape[0]] = np.nan

    def copy(self):
        new = copy.copy(self)
        new.data = records.clone_data(self.data)
        new.work = records.clone_work(self.work)
        return new


class SelfIntegrating(Model):
    """A model with its own kernel (``chain1d``)."""
    integrates_itself = True

    @abstractmethod
    def advance(self, dt, n_steps):
        """``n_steps`` steps of ``dt`` s in place; returns (steps, status)."""

    @abstractmethod
    def impact(self, v0):
        """An impact of ``v0`` m/s on the free end; returns the energy added, J."""

    @abstractmethod
    def energy(self):
        """Energy J of the state."""

    @abstractmethod
    def constraint_error(self):
        """Relative constraint error of the state."""

    @abstractmethod
    def heights(self):
        """Prism heights m."""
