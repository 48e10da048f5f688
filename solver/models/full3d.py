"""The full model ``full3d``: every node in 3D with every rigid member as a constraint
(docs/physics.md section 1.1)."""
from __future__ import annotations

import numpy as np

from solver.kernels import summary
from solver.models import extras
from solver.models.base import RecordModel


class Full3D(RecordModel):
    """Every node in 3D with every rigid member as a constraint; ``effects``: what the scene
    switches on (:class:`~solver.models.extras.Effects`), ``striker_state`` where its strikers
    start (:func:`solver.models.extras.build`)."""
    name = 'full3d'

    def __init__(self, network, f_ext=None, effects=extras.NONE, striker_state=None):
        super().__init__(network)
        self.effects = effects
        f = np.zeros((network.n_nodes, 3)) if f_ext is None else f_ext
        self.rec, self.data, self.work = extras.build(
            network, network.topology(), np.array(network.x0), network.cable_rest_length,
            network.cable_EA, f, full_summary_arrays(network), effects, None, striker_state)

    @property
    def cable_rest_length(self):
        return self.data.rest

    @property
    def cable_EA(self):
        return self.data.EA

    # the state arrays may carry rows beyond the network's nodes (strikers, solver.kernels.contact)
    def positions(self):
        n = self.network.n_nodes
        return self.x if self.x.shape[0] == n else self.x[:n]

    def expansion(self):
        """How a state expands to the full network (:func:`solver.kernels.laneview.frame_rows`):
        ``(rep, cos, sin, rotate, cable_map)``; here each node and cable is its own."""
        n, k = self.network.n_nodes, self.network.n_cables
        return (np.arange(n), np.ones(n), np.zeros(n), False, np.arange(k))

    def velocities(self):
        n = self.network.n_nodes
        return self.v if self.v.shape[0] == n else self.v[:n]

    def set_state(self, x, v):
        n = self.network.n_nodes
        self.x[:n] = x
        self.v[:n] = v

    def set_cables(self, rest, EA):
        """Load (n_cables,) rest lengths m and EA N."""
        self.data.rest[:] = rest
        self.data.EA[:] = EA


def full_summary_arrays(network):
    """The :func:`solver.kernels.summary.state_summary` arrays of a full network."""
    levels = network.levels if network.levels.size else np.zeros((0, 0, 1), dtype=np.int64)
    return summary.summary_arrays(network.x0, network.node_mass, network.clamped, network.bar_a,
                                  network.bar_b, network.bar_mass,
                                  np.ascontiguousarray(levels, dtype=np.int64), network.n_cables)
