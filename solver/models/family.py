"""The model family: a scene pays only for the model it needs.

A model owns the arrays its integrator kernels work on and maps its own coordinates to the full
network's node positions (for frames, messages and recordings):

- ``x``, ``v``: the model's state arrays (``(n, 3)`` float64), advanced in place by the integrator;
- ``net``, ``act``, ``ws``: the kernel tuples of :mod:`solver.kernels.dynamics`;
- ``positions()`` / ``velocities()``: full (n_nodes, 3) arrays of the network;
- ``set_state(x_full, v_full)``: load a full state;
- ``cable_rest_length``, ``cable_EA`` (full (n_cables,) arrays) and ``set_cables(rest, EA)``;
- ``summ``: the arrays of :func:`solver.kernels.summary.state_summary` for the model's own state
(energy,
  prism heights, constraint error in one compiled pass, also run inside the integrator call of
  each ``Simulation.advance``), or None: the simulation then computes them from the full state
  (``sym3d`` where its reduction of them is not exact), or, for a model with its own ``advance``
  (``chain1d``), asks its ``energy()`` and ``constraint_error()``.

``sym3d`` (:mod:`solver.models.sym3d`) raises :class:`~solver.models.sym3d.NotSymmetric` from
``set_state`` or
``set_cables`` when given an asymmetric state; the simulation then expands the run to ``full3d``
(:func:`expand`). ``chain1d`` (:mod:`solver.models.chain1d`) has its own state and ``advance``.

To add a model: subclass :class:`Model`, add it to :data:`MODELS`, and teach :func:`choose` when
``model: auto`` may pick it (only when it is exact for the scene).
"""
from __future__ import annotations

import numpy as np

from solver.kernels import dynamics as dyn
from solver.kernels import summary
from solver.models.base import Model


class Full3D(Model):
    """Every node in 3D with every rigid member as a constraint (docs/physics.md section 1.1)."""
    name = 'full3d'

    def __init__(self, network, f_ext=None):
        super().__init__(network)
        self.net, self.act = dyn.pack(network, f_ext=f_ext)
        self.ws = dyn.workspace_for(network)
        self.x = np.array(network.x0)
        self.v = np.zeros_like(self.x)
        self.summ = full_summary_arrays(network)

    @property
    def cable_rest_length(self):
        return self.act[0]

    @property
    def cable_EA(self):
        return self.act[1]

    # the state arrays may carry rows beyond the network's nodes (strikers, solver.kernels.contact)
    def positions(self):
        n = self.network.n_nodes
        return self.x if self.x.shape[0] == n else self.x[:n]

    def velocities(self):
        n = self.network.n_nodes
        return self.v if self.v.shape[0] == n else self.v[:n]

    def set_state(self, x, v):
        n = self.network.n_nodes
        self.x[:n] = x
        self.v[:n] = v

    def set_cables(self, rest, EA):
        """Load (n_cables,) rest lengths m and EA N."""
        self.act[0][:] = rest
        self.act[1][:] = EA


def full_summary_arrays(network):
    """The :func:`solver.kernels.summary.state_summary` arrays of a full network."""
    levels = network.levels if network.levels.size else np.zeros((0, 0, 1), dtype=np.int64)
    return summary.summary_arrays(network.x0, network.node_mass, network.clamped, network.bar_a,
                                  network.bar_b, network.bar_mass,
                                  np.ascontiguousarray(levels, dtype=np.int64), network.n_cables)




from solver.models.chain1d import Chain1D  # noqa: E402
from solver.models.sym3d import NotSymmetric, Sym3D, reduce_network  # noqa: E402

MODELS = {cls.name: cls for cls in (Full3D, Sym3D, Chain1D)}



def symmetric_loading(scene):
    """Whether the scene's loading keeps the 3-fold symmetry about z: gravity acts along z and
    every impact is axial on a whole level (always true for the loads a scene can describe);
    returns (bool, reason)."""
    return True, 'axial impact on whole levels, gravity along z'


def choose(requested, network, scene):
    """The model class for a scene. ``auto`` picks the cheapest exact model: ``sym3d`` when the
    network is 3-fold symmetric about z (structure, materials, supports) and the loading is too,
    ``full3d`` otherwise. ``chain1d`` is an approximation and is used only when asked for."""
    if requested == 'auto':
        ok, _ = symmetric_loading(scene)
        if ok:
            try:
                reduce_network(network)
                return Sym3D
            except NotSymmetric:
                pass
        return Full3D
    if requested not in MODELS:
        raise ValueError(f'model {requested!r} is not available; available: '
                         f'{", ".join(sorted(MODELS))}')
    if requested == 'sym3d':
        try:
            reduce_network(network)
        except NotSymmetric as exc:
            raise ValueError(f'model sym3d: {exc}') from None
    return MODELS[requested]


def expand(model, f_ext=None):
    """A :class:`Full3D` model holding the state and cables of ``model`` (no jump: the full state
    is the symmetric expansion of the reduced one)."""
    full = Full3D(model.network, f_ext=f_ext)
    full.set_state(model.positions(), model.velocities())
    full.set_cables(model.cable_rest_length, model.cable_EA)
    return full
