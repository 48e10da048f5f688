"""Simulation: one scene, one model, one integrator, one clock (``t``).

    sim = Simulation(Scene.load('config/scenes/fb_column.yaml'))
    sim.apply_impact(0.1)
    while sim.t < 1.0:
        sim.advance(0.005)
        frame = sim.frame()

Commands (:meth:`apply_impact`) and :meth:`advance` either succeed or change nothing: bad values raise
``ValueError`` naming the problem; a diverging step raises :class:`SimulationDiverged` and restores the
last good state.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import dynamics as dyn
from . import integrators, models, observables, structures
from .scene import Scene


class SimulationDiverged(RuntimeError):
    """The run stopped itself: ``t`` s, ``step``, the ``quantity`` that failed and a ``hint``."""

    def __init__(self, t, step, quantity, detail, hint):
        self.t, self.step, self.quantity, self.hint = t, step, quantity, hint
        super().__init__(f'simulation diverged at t = {t:.6g} s (step {step}): {quantity} {detail}; '
                         f'{hint}')


@dataclass
class Frame:
    """A copied snapshot. ``positions`` (n_nodes, 3) m, ``strain`` (n_columns, n_prisms),
    ``tension`` (n_cables,) N, ``energy`` J, ``constraint_error`` (relative), ``t`` s."""
    t: float
    step: int
    positions: np.ndarray
    strain: np.ndarray
    tension: np.ndarray
    energy: float
    constraint_error: float


def build_network(scene):
    """The :class:`~solver.network.Network` a scene describes."""
    s = scene['structure']
    m = scene['materials']
    builder = s.pop('builder')
    if builder == 'column':
        return structures.column(
            n_prisms=s['n_prisms'], radius=s['radius'], h0=s['h0'], cable_E=m['cable_E'],
            cable_radius=m['cable_radius'], unit_mass=m['unit_mass'], bar_mass=m['bar_mass'],
            prestrain=scene['prestrain'], bases=s['bases'], stacking=s['stacking'],
            rigid_bases_as=s['rigid_bases_as'], kappa=s['kappa'], n_columns=s['n_columns'],
            column_spacing=s['column_spacing'], clamped_levels=tuple(s['clamped_levels']),
            handedness=s['handedness'])
    EA = m['cable_E'] * math.pi * m['cable_radius'] ** 2
    rest = s['cable_rest_length']
    return structures.explicit(s['nodes'], s['bars'], s['cables'], s['node_mass'], EA,
                               cable_rest_length=rest,
                               prestrain=None if rest is not None else scene['prestrain'],
                               rigid_edges=s['rigid_edges'], clamped=s['clamped'],
                               bar_mass=m['bar_mass'])


class Simulation:
    def __init__(self, scene: Scene, network=None):
        self.scene = scene
        self.network = network if network is not None else build_network(scene)
        g = scene['loading.gravity']
        f_ext = np.zeros((self.network.n_nodes, 3))
        if g:
            f_ext[:, 2] = -g * self.network.node_mass
            f_ext[self.network.clamped] = 0.0
        self.f_ext = f_ext
        model_cls = models.choose(scene['model'], self.network, scene.data)
        self.model = model_cls(self.network, f_ext=f_ext)
        it = scene['integrator']
        self.integrator = integrators.get(it['method'])
        self.dt = it['dt']
        self.tol = it['projection_tol']
        self.max_iter = it['projection_max_iter']
        self.kinks = it['land_on_kinks']
        self.div = scene['divergence']
        self.reset()

    # -- state ----------------------------------------------------------------------------------
    def reset(self):
        """Back to the reference geometry at rest, t = 0, rest lengths of the scene."""
        net = self.network
        self.model.set_state(net.x0, np.zeros((net.n_nodes, 3)))
        self.model.act[0][:] = net.cable_rest_length
        self.model.act[1][:] = net.cable_EA
        self.t = 0.0
        self.step = 0
        self.steps_taken = 0
        self._energy_ref = self.energy()

    def energy(self):
        return observables.energy(self.model.positions(), self.model.velocities(), self.network,
                                  self.model.act[0], self.model.act[1], self.f_ext)

    def constraint_error(self):
        return observables.constraint_error(self.model.positions(), self.network)

    # -- commands -------------------------------------------------------------------------------
    def impact_velocities(self, v0, columns=None, mode=None):
        """Full (n_nodes, 3) velocities after an axial impact of ``v0`` m/s (positive compressive)
        on the free-end level of the given columns: scalar or one value per addressed column."""
        net = self.network
        if net.levels.size == 0:
            raise ValueError('impact needs a column structure (levels)')
        cols = list(range(net.n_columns)) if columns is None else list(columns)
        v0 = np.broadcast_to(np.asarray(v0, dtype=np.float64), (len(cols),)) if np.ndim(v0) == 0 \
            else np.asarray(v0, dtype=np.float64)
        if v0.shape != (len(cols),):
            raise ValueError(f'impact: expected 1 or {len(cols)} values, got {v0.size}')
        if not np.all(np.isfinite(v0)):
            raise ValueError('impact: velocity is not finite')
        mode = mode or self.scene['loading.impact.mode']
        v = np.array(self.model.velocities())
        x = np.array(self.model.positions())
        kick = np.zeros_like(v)
        for c, vc in zip(cols, v0):
            kick[net.levels[c, -1], 2] = -vc
        ke_target = observables.kinetic_energy(kick, net)
        net_t, _ = dyn.pack(net)
        ws = dyn.workspace(net.n_nodes, net.n_constraints, net.bandwidth)
        status = dyn.project_velocities(x, kick, net_t, ws)
        if status != dyn.OK:
            raise ValueError(f'impact: {dyn.STATUS_TEXT[status]}')
        if mode == 'energy':
            ke = observables.kinetic_energy(kick, net)
            if ke > 0:
                kick *= math.sqrt(ke_target / ke)
        return v + kick

    def apply_impact(self, v0, columns=None, mode=None):
        """Impact the free end(s): the velocity jump is projected on the constraints (impulse, the
        default) or, with ``mode='energy'``, also rescaled to the kinetic energy ``3 m v0^2 / 2`` per
        column. Returns the kinetic energy added, J."""
        before = self.energy()
        v_new = self.impact_velocities(v0, columns, mode)
        self.model.set_state(self.model.positions(), v_new)
        self._energy_ref = self.energy()
        return self._energy_ref - before

    # -- time -----------------------------------------------------------------------------------
    def advance(self, duration):
        """Advance by ``duration`` s in whole steps of ``dt`` (the last one shortened to land on
        ``t + duration``). Raises :class:`SimulationDiverged` and restores the state on failure."""
        n = max(int(round(duration / self.dt)), 0)
        if n == 0:
            return 0
        m = self.model
        x_keep, v_keep = m.x.copy(), m.v.copy()
        steps, status = self.integrator.run(m.x, m.v, self.dt, n, m.net, m.act, m.ws, self.tol,
                                            self.max_iter, self.kinks)
        problem = None
        if status != dyn.OK:
            problem = ('state', dyn.STATUS_TEXT[status])
        else:
            err = self.constraint_error()
            e = self.energy()
            growth = (e - self._energy_ref) / max(abs(self._energy_ref), 1e-300)
            if not err <= self.div['constraint_error']:
                problem = ('constraint error', f'{err:.3g} exceeds {self.div["constraint_error"]:g}')
            elif not growth <= self.div['energy_growth']:
                problem = ('energy', f'grew by {growth:.3g} (relative), limit '
                                     f'{self.div["energy_growth"]:g}')
        if problem is not None:
            m.x[:], m.v[:] = x_keep, v_keep
            raise SimulationDiverged(self.t + steps * self.dt, self.step + steps, problem[0],
                                     problem[1], 'try a smaller integrator.dt or another method')
        self.t += n * self.dt
        self.step += n
        self.steps_taken += steps
        return steps

    def frame(self):
        """A copied :class:`Frame` of the current state."""
        x = np.array(self.model.positions())
        net = self.network
        strain = (observables.prism_strains(x, net.levels, net.h0) if net.levels.size
                  else np.zeros((0, 0)))
        return Frame(t=self.t, step=self.step, positions=x, strain=strain,
                     tension=observables.cable_tensions(x, net, self.model.act[0],
                                                        self.model.act[1]),
                     energy=self.energy(), constraint_error=self.constraint_error())
