"""How commands change a simulation's state: axial impacts (an impulse, a given energy or a
striker) and prestrain changes (at once or ramped), both checked before anything changes.

:class:`Loading` is the part of :class:`~solver.simulate.simulation.Simulation` that takes the
commands; it works on the simulation's model, network and energy reference.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from solver import status as codes
from solver.compiled import compiled_overload
from solver.analysis import observables
from solver.build import structures
from solver.build.scene import RANGES
from solver.kernels import dynamics as dyn
from solver.kernels import ramp as ramped
from solver.kernels import records
from solver.models import extras

PRESTRAIN_RANGE = RANGES['prestrain']     # (lower, upper, lower inclusive): 0 < p <= 0.5


def prestrain_values(p, n_cols, n_prisms):
    """The (n_cols, n_prisms) prestrain of a command for ``n_cols`` addressed columns: ``p`` a
    scalar, one value per column or the full array; raises ``ValueError`` naming the problem
    (shape, a value that is not finite or outside the range of the scene key ``prestrain``)."""
    p = np.asarray(p, dtype=np.float64)
    if p.ndim == 0:
        p = np.full((n_cols, n_prisms), float(p))
    elif p.shape == (n_cols,):
        p = np.repeat(p[:, None], n_prisms, axis=1)
    elif p.shape != (n_cols, n_prisms):
        raise ValueError(f'prestrain: expected 1, {n_cols} or {n_cols} x {n_prisms} values, got '
                         f'shape {p.shape}')
    if not np.all(np.isfinite(p)):
        raise ValueError('prestrain: value is not finite')
    lo, hi, _ = PRESTRAIN_RANGE
    if np.any(p <= lo) or np.any(p > hi):
        bad = p[(p <= lo) | (p > hi)].flat[0]
        raise ValueError(f'prestrain: {bad:g} is outside ({lo:g}, {hi:g}]')
    return p


def impact_values(v0, n_cols):
    """The impact velocities (n_cols,) m/s of a command: one value for every addressed column or
    one each, finite."""
    v0 = np.broadcast_to(np.asarray(v0, dtype=np.float64), (n_cols,)) if np.ndim(v0) == 0 \
        else np.asarray(v0, dtype=np.float64)
    if v0.shape != (n_cols,):
        raise ValueError(f'impact: expected 1 or {n_cols} values, got {v0.size}')
    if not np.all(np.isfinite(v0)):
        raise ValueError('impact: velocity is not finite')
    return v0


def rest_length_values(rest, n_cables):
    """Cable rest lengths (n_cables,) m of a command, checked: finite and positive."""
    rest = np.asarray(rest, dtype=np.float64)
    if rest.shape != (n_cables,):
        raise ValueError(f'cable rest lengths: expected {n_cables} values, got shape '
                         f'{rest.shape}')
    if not np.all(np.isfinite(rest)) or np.any(rest <= 0):
        raise ValueError('cable rest lengths: every value must be finite and positive')
    return rest


class Ramp(NamedTuple):
    """A prestrain ramp: from ``start`` at ``t0`` s to ``target`` (n_columns, n_prisms) over
    ``duration`` s, linear in the prestrain."""
    t0: float
    duration: float
    start: np.ndarray
    target: np.ndarray


class Loading:
    """Impact and prestrain commands (a part of ``Simulation``)."""

    def impact_velocities(self, v0, columns=None, mode=None):
        """Full (n_nodes, 3) velocities after an axial impact of ``v0`` m/s (positive compressive)
        on the free-end level of the given columns: scalar or one value per addressed column."""
        net = self.network
        if net.levels.size == 0:
            raise ValueError('impact needs a column structure (levels)')
        cols = list(range(net.n_columns)) if columns is None else list(columns)
        v0 = impact_values(v0, len(cols))
        mode = mode or self.scene.loading.impact.mode
        if mode == 'striker':
            raise ValueError('impact: a striker impact sets no node velocities (use apply_impact)')
        v = np.array(self.model.velocities())
        x = np.array(self.model.positions())
        kick = np.zeros_like(v)
        for c, vc in zip(cols, v0):
            kick[net.levels[c, -1], 2] = -vc
        ke_target = observables.kinetic_energy(kick, net)
        topo = net.topology()
        status = dyn.project_velocities(x, kick, topo, records.work_for(topo, net.n_nodes))
        if status != dyn.OK:
            raise ValueError(f'impact: {codes.text(status)}')
        if mode == 'energy':
            ke = observables.kinetic_energy(kick, net)
            if ke > 0:
                kick *= math.sqrt(ke_target / ke)
        return v + kick

    def _end_heights(self):
        """Mean height m of each column's free-end level (n_columns,)."""
        lev = self.network.levels
        return np.asarray(self._full_state().x)[lev[:, -1], 2].mean(axis=1)

    def striker(self):
        """(n_columns, 2) striker face height m and axial velocity m/s, or None without
        strikers."""
        st = extras.striker_state(self.model)
        return st if len(st) else None

    def _strike(self, v0, columns):
        """Striker impact: each addressed column's striker gets the axial velocity ``-v0``
        (towards the column); a striker out of contact is first placed on the free end (touching,
        no overlap, so no energy changes)."""
        m, net = self.model, self.network
        ns = m.n_strikers
        if not ns:
            raise ValueError('impact: mode striker needs loading.impact.mode: striker in the '
                             'scene (the strikers are built with the model)')
        cols = list(range(net.n_columns)) if columns is None else list(columns)
        if any(not 0 <= c < net.n_columns for c in cols):
            raise ValueError(f'impact: columns must be indices 0..{net.n_columns - 1}')
        v0 = impact_values(v0, len(cols))
        z_end = self._end_heights()
        rows = m.x.shape[0] - ns
        for c, vc in zip(cols, v0):
            if m.x[rows + c, 2] >= z_end[c]:
                m.x[rows + c, 2] = z_end[c]
            m.v[rows + c, 2] = -vc
        self.integrator.state_changed()
        self._changed()

    def apply_impact(self, v0, columns=None, mode=None):
        """Impact the free end(s): the velocity jump is projected on the constraints (impulse, the
        default) or, with ``mode='energy'``, also rescaled to the kinetic energy ``3 m v0^2 / 2``
        per column; with ``mode='striker'`` (the scene's ``loading.impact.mode: striker``) each
        column's striker is launched at ``v0`` against the free end instead. Returns the kinetic
        energy added, J."""
        before = self.energy()
        if (mode or self.scene.loading.impact.mode) == 'striker':
            self._strike(v0, columns)
            return self._add_work(before)
        if self.model.integrates_itself:            # chain1d: axial velocity on the end level
            if columns not in (None, [0], (0,)):
                raise ValueError('impact: chain1d has one column (0)')
            if np.ndim(v0) != 0 or not math.isfinite(float(v0)):
                raise ValueError('impact: chain1d takes one finite velocity')
            self.model.impact(float(v0))
            self._changed()
            return self._add_work(before)
        v_new = self.impact_velocities(v0, columns, mode)
        self._load(self.model.positions(), v_new)
        return self._add_work(before)

    @property
    def prestrain(self):
        """Current cross prestrain per prism (n_columns, n_prisms) (a copy), None if not a
        column."""
        return None if self._prestrain is None else self._prestrain.copy()

    @property
    def prestrain_map(self):
        """The :class:`~solver.build.structures.PrestrainMap` of the network (built on first
        use)."""
        if self._prestrain_map is None:
            self._prestrain_map = structures.prestrain_map(self.network)
        return self._prestrain_map

    def prestrain_target(self, p, columns=None):
        """Per-prism prestrain (n_columns, n_prisms) of a command: ``p`` a scalar (all addressed
        columns), one value per addressed column, or an (n_addressed, n_prisms) array; columns not
        addressed keep their current (target) values. Raises ``ValueError`` naming the problem."""
        if self._prestrain is None:
            raise ValueError('prestrain needs a column structure built by the column builder')
        net = self.network
        cols = list(range(net.n_columns)) if columns is None else list(columns)
        if not cols or any(not 0 <= c < net.n_columns for c in cols):
            raise ValueError(f'prestrain: columns must be indices 0..{net.n_columns - 1}')
        p = prestrain_values(p, len(cols), net.n_prisms)
        target = self.prestrain_goal
        target[cols] = p
        return target

    @property
    def prestrain_goal(self):
        """The prestrain per prism (n_columns, n_prisms) the columns are ramping to, or have
        (a copy)."""
        return (self._ramp.target if self._ramp is not None else self._prestrain).copy()

    def apply_prestrain(self, p, columns=None, ramp_s=0.0):
        """Change the cross prestrain of the addressed columns (see :meth:`prestrain_target`) by
        changing the rest lengths of all their cables so that the reference geometry stays in
        equilibrium (:class:`~solver.build.structures.PrestrainMap`), linearly in ``p`` over
        ``ramp_s`` s of simulation time (0 = at once). A ramp in progress continues from where it
        is. The actuator's work is added to the energy reference of the divergence check."""
        target = self.prestrain_target(p, columns)
        if not (math.isfinite(ramp_s) and ramp_s >= 0):
            raise ValueError(f'prestrain: ramp duration {ramp_s!r} must be >= 0')
        self.prestrain_map            # validate the network before changing anything
        if ramp_s < self.dt:
            self._ramp = None
            self._set_prestrain(target)
        else:
            self._ramp = Ramp(self.t, float(ramp_s), self._prestrain.copy(), target)

    def _set_prestrain(self, p):
        e0 = self.energy()
        EA = self.model.cable_EA
        self._set_cables(self.prestrain_map.rest_lengths(p, EA), EA)
        self._prestrain = np.array(p, dtype=np.float64)
        self._add_work(e0)

    def _ramp_to(self, t):
        r = self._ramp
        u = (t - r.t0) / r.duration
        if u >= 1.0:
            self._ramp = None
            self._set_prestrain(r.target)
        else:
            self._set_prestrain(r.start + max(u, 0.0) * (r.target - r.start))

    def _ramp_record(self):
        """The :class:`solver.kernels.ramp.Ramp` of the running ramp on the present model (built
        once per ramp and model), or None where the ramp steps in Python: a model without a
        summary of its own state (``exact``) or an integrator without a ramped twin."""
        m, integ, r = self.model, self.integrator, self._ramp
        call = self._ramp_call
        if call is not None and call.model is m and call.integrator is integ:
            if call.ramp is r:
                return call.rec
        else:
            call = self._ramp_call = RampCall(m, integ)
        call.ramp, call.rec = r, None
        if m.exact and not m.integrates_itself and integ.ramped is not None:
            pm = self.prestrain_map
            n_model = len(m.data.rest)
            cmap = (np.arange(n_model, dtype=np.int64) if m.reduced is None
                    else np.array(m.reduced.cable_map, dtype=np.int64))
            start = np.array(r.start, dtype=np.float64).reshape(-1)
            call.rec = ramped.Ramp(
                start, np.array(r.target, dtype=np.float64).reshape(-1), start.copy(),
                start.copy(), np.array(pm.length), np.array(pm.cross), np.array(pm.cross_prism),
                pm.cross_count.astype(np.float64), np.array(pm.base),
                np.ascontiguousarray(pm.base_prisms[:, 0]),
                np.ascontiguousarray(pm.base_prisms[:, 1]), np.array(pm.radius),
                np.array(m.cable_EA, dtype=np.float64), cmap, ramped.source_of(cmap, n_model),
                np.zeros(len(pm.cross_count)), np.zeros(len(pm.length)), np.zeros(4), np.zeros(2))
        return call.rec

    def _ramped(self, done, n):
        """Steps ``done``.. of ``n`` of a running ramp in one compiled call of the integrator's
        ramped twin (:meth:`solver.integrators.base.Integrator.ramped_args`), the rest lengths,
        prestrain and work as :meth:`_ramp_to` sets them before each step. Returns ``(steps
        done, integrator steps, status, whether the rest lengths at t + n dt are set, the state
        summary (finite, energy, heights, constraint error, smallest height) of the end state
        when the call reached it, else None)``, or None when it stepped nothing (no ramped call
        here, or rest lengths the model cannot hold)."""
        rec = self._ramp_record()
        if rec is None:
            return None
        m, integ, r, call = self.model, self.integrator, self._ramp, self._ramp_call
        rec.clock[:] = (self.t, r.t0, r.duration, self.dt)
        rec.book[:] = (self._energy_ref, self._energy_scale)
        h = np.empty(self._heights_shape)
        args = (m.rec, m.data, m.work, float(self.dt), int(n),
                *integ.ramped_args(m.rec, m.data, m.work, self.tol, self.max_iter, self.kinks),
                rec, int(done), h)
        if call.entry is None:      # through numba's dispatch, then its compiled overload
            out = integ.ramped(*args)
            call.entry = compiled_overload(integ.ramped, args) or integ.ramped
        else:
            out = call.entry(*args)
        k, steps, status, went, made, finite, e, cerr, h_min = out
        return self._ramp_went(done, n, (int(k), int(steps), int(status), int(went)),
                               (finite, e, h, cerr, h_min) if made else None, rec.book, rec.p)

    def _ramp_went(self, done, n, call, made, book, p):
        """:meth:`_ramped`'s result from what a ramped call from step ``done`` of ``n`` returned
        (``call``: steps done, integrator steps, status, what the last ``set_rest`` returned;
        ``made``: the end state's summary or None), its ramp's ``book`` and prestrain ``p``
        (this simulation's, or its lane's of a lane group: :mod:`solver.simulate.lanebatch`)."""
        k, steps, status, went = call
        self._changed()
        if went == ramped.ASYMMETRIC and k == done:
            return None
        self._energy_ref, self._energy_scale = float(book[0]), float(book[1])
        self._prestrain = p.reshape(self._prestrain.shape).copy()
        if went == ramped.ENDED:
            self._ramp = None
        return k, steps, status, k == n and went != ramped.ASYMMETRIC, made


@dataclass
class RampCall:
    """The ramped call of a simulation's model and integrator: the ramp whose record ``rec`` it
    holds (None: the ramp steps in Python) and, after the first call, the compiled entry point
    (``entry``; the arguments keep their types while model and integrator stay)."""
    model: object
    integrator: object
    ramp: object = None
    rec: object = None
    entry: object = None
