"""The model family: a scene pays only for the model it needs.

A model owns the arrays its integrator kernels work on and maps its own coordinates to the full
network's node positions (for frames, messages and recordings):

- ``x``, ``v``: the model's state arrays (``(n, 3)`` float64), advanced in place by the integrator;
- ``net``, ``act``, ``ws``: the kernel tuples of :mod:`solver.dynamics`;
- ``positions()`` / ``velocities()``: full (n_nodes, 3) arrays of the network;
- ``set_state(x_full, v_full)``: load a full state.

To add a model: subclass :class:`Model`, add it to :data:`MODELS`, and teach :func:`choose` when
``model: auto`` may pick it (only when it is exact for the scene).
"""
from __future__ import annotations

import numpy as np

from . import dynamics as dyn


class Model:
    name = ''

    def __init__(self, network):
        self.network = network

    def positions(self):
        raise NotImplementedError

    def velocities(self):
        raise NotImplementedError


class Full3D(Model):
    """Every node in 3D with every rigid member as a constraint (physics.md section 1.1)."""
    name = 'full3d'

    def __init__(self, network, f_ext=None):
        super().__init__(network)
        self.net, self.act = dyn.pack(network, f_ext=f_ext)
        self.ws = dyn.workspace(network.n_nodes, network.n_constraints, network.bandwidth)
        self.x = np.array(network.x0)
        self.v = np.zeros_like(self.x)

    @property
    def cable_rest_length(self):
        return self.act[0]

    @property
    def cable_EA(self):
        return self.act[1]

    def positions(self):
        return self.x

    def velocities(self):
        return self.v

    def set_state(self, x, v):
        self.x[:] = x
        self.v[:] = v


MODELS = {cls.name: cls for cls in (Full3D,)}


def choose(requested, network, scene_data):
    """The model class for a scene. ``auto`` picks the cheapest exact model; until the reduced models
    exist that is ``full3d``."""
    name = 'full3d' if requested == 'auto' else requested
    if name not in MODELS:
        raise ValueError(f'model {name!r} is not available; available: {", ".join(sorted(MODELS))}')
    return MODELS[name]
