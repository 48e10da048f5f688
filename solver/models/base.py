"""The interface every model implements (``full3d``, ``sym3d``, ``chain1d``).

A model owns the state of one network and hands the kernels their arrays. What
:class:`~solver.simulate.simulation.Simulation` uses of it:

- ``name``; ``network`` (the full :class:`~solver.build.network.Network`);
- ``positions()``, ``velocities()``: the full (n_nodes, 3) state, m and m/s;
  ``set_state(x, v)``: load a full state;
- ``cable_rest_length``, ``cable_EA`` (n_cables,); ``set_cables(rest, EA)``;
- for models stepped by an integrator: ``x``, ``v`` (the state the kernels advance), the
  ``net``, ``act``, ``ws`` tuples of :mod:`solver.kernels.dynamics`, ``summ`` (the arrays of
  ``state_summary``, or None), ``n_strikers`` (rows of ``x`` after the nodes, set by
  :func:`solver.models.extras.attach`), ``reduced`` (the reduced network of ``sym3d``, or None);
- for a model with its own kernel (``integrates_itself``: ``chain1d``): ``advance(dt, n_steps)``
  -> (steps, status), ``impact(v0)``, ``energy()``, ``constraint_error()``, ``heights()``,
  ``snapshot()`` / ``restore(snapshot)``.

A setter that cannot keep the model's assumptions (an asymmetric state for ``sym3d``) raises
and changes nothing; the simulation then expands the run to ``full3d``.
"""


import copy

import numpy as np


def copy_arrays(value):
    """A copy of a (nested) tuple of arrays: the kernels' ``act`` and ``ws`` tuples."""
    if isinstance(value, tuple):
        return tuple(copy_arrays(v) for v in value)
    return np.array(value)


class Model:
    name = ''
    summ = None
    n_strikers = 0
    reduced = None
    integrates_itself = False

    def __init__(self, network):
        self.network = network

    def copy(self):
        """An independent copy: the state and the arrays the kernels write (``x``, ``v``, the
        ``act`` and ``ws`` tuples) its own, the network and the constant arrays shared."""
        new = copy.copy(self)
        new.x, new.v = self.x.copy(), self.v.copy()
        new.act = copy_arrays(self.act)
        if hasattr(self, 'ws'):
            new.ws = copy_arrays(self.ws)
        return new

    def positions(self):
        raise NotImplementedError

    def velocities(self):
        raise NotImplementedError
