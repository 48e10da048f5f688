"""Simulation: one scene, one model, one integrator, one clock (``t``).

    sim = Simulation(Scene.load('config/scenes/fb_column.yaml'))
    sim.apply_impact(0.1)
    while sim.t < 1.0:
        sim.advance(0.005)
        frame = sim.frame()

Commands (:meth:`apply_impact`) and :meth:`advance` either succeed or change nothing: bad values
raise
``ValueError`` naming the problem; a diverging step raises :class:`SimulationDiverged` and restores
the last good state.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from solver import status as codes
from solver.compiled import compiled_overload
from solver.kernels import dynamics as dyn
from solver.kernels import records
from solver.kernels import summary
from solver.kernels import contact
from solver.build import memo
from solver.models import extras
from solver.integrators import registry as integrators
from solver.models import family as models
from solver.analysis import observables
from solver.build import structures
from solver.build.scene import Scene
from solver.simulate.checks import Checks, SimulationDiverged  # noqa: F401 (imported from here)
from solver.simulate.interface import SimulationAPI
from solver.simulate.loading import Loading, rest_length_values


@dataclass
class Frame:
    """A copied snapshot. ``positions`` (n_nodes, 3) m, ``strain`` (n_columns, n_prisms),
    ``tension`` (n_cables,) N (elastic part), ``energy`` J (striker and contacts included),
    ``constraint_error`` (relative), ``t`` s, ``base_force`` (n_columns,) N: the axial
    reaction at each column's clamped base, positive compressive (:mod:`solver.analysis.support`;
    empty when not given); ``striker`` (n_columns, 2): each column's striker face height m
    and axial velocity m/s (``loading.impact.mode: striker``), else None;
    ``energy_balance_error``: :meth:`Simulation.energy_error` of the state; ``episode``: the
    node's episode it belongs to (None in a headless run)."""
    t: float
    step: int
    positions: np.ndarray
    strain: np.ndarray
    tension: np.ndarray
    energy: float
    constraint_error: float
    base_force: np.ndarray = field(default_factory=lambda: np.zeros(0))
    striker: np.ndarray | None = None
    energy_balance_error: float = 0.0
    episode: int | None = None      # the node's episode (a reset starts a new one); None headless


class StateSummary(NamedTuple):
    """What the divergence check and a frame read of a state, from one pass: whether it is
    finite, its energy J, the prism heights (n_columns, n_prisms) m, the relative constraint
    error and the smallest prism height m."""
    finite: bool
    energy: float
    heights: np.ndarray
    constraint_error: float
    h_min: float


class FrameFigures(NamedTuple):
    """The figures of a :class:`Frame` a run's summary reads: ``t`` s, ``strain`` (n_columns,
    n_prisms), ``energy`` J, ``constraint_error`` and ``energy_balance_error`` (relative)."""
    t: float
    strain: np.ndarray
    energy: float
    constraint_error: float
    energy_balance_error: float


class FullState(NamedTuple):
    """Full (n_nodes, 3) positions m and velocities m/s of a state (shared, read only)."""
    x: np.ndarray
    v: np.ndarray


class BaseForceOf(NamedTuple):
    """The base force of a model: ``force`` reads the model's own state (``own``) or a full
    one."""
    model: object
    force: object
    own: bool


@dataclass
class CheckedCall:
    """The one compiled call of :meth:`Simulation.advance` for a model and an integrator: the
    data record the call keeps its start in (``kept``), its arguments after ``max_iter``
    (``fixed``) and, after the first call, the compiled entry point (``entry``)."""
    model: object
    integrator: object
    kept: records.Data
    fixed: tuple
    entry: object = None


class Simulation(Loading, Checks, SimulationAPI):
    def __init__(self, scene: Scene, network=None):
        # the model's choice and the model reduce the network alike: once, within one memo
        with memo.sharing():
            self._build(scene, network)

    def _build(self, scene, network):
        self.scene = scene
        self.network = network if network is not None else structures.build_network(scene)
        levels = self.network.levels
        self._heights_shape = (levels.shape[0], max(levels.shape[1] - 1, 0))
        g = scene.loading.gravity
        f_ext = np.zeros((self.network.n_nodes, 3))
        if g:
            f_ext[:, 2] = -g * self.network.gravity_mass()
            f_ext[self.network.clamped] = 0.0
        self.f_ext = f_ext
        self._f_ext_or_none = f_ext if np.any(f_ext) else None
        self._model_cls = models.choose(scene.model, self.network, scene)
        self.effects = extras.scene_effects(scene, self.network)
        self.bar_contact = scene.contact.bars if self.effects.pairs is not None else 'none'
        if not self._model_cls.has_bars and self.effects.pairs is not None:
            self.effects = self.effects.without('pairs')  # its prisms are a force law, not bars
            self.bar_contact = f'none ({self._model_cls.name} has no bars)'
        self.model = self._model_cls(self.network, f_ext=f_ext, effects=self.effects)
        self.expanded = None            # why a sym3d run was expanded to full3d, if it was
        it = scene.integrator
        self.integrator = integrators.get(it.method, rtol=it.rtol, atol=it.atol)
        self.dt = it.dt
        self.tol = it.projection_tol
        self.max_iter = it.projection_max_iter
        self.kinks = it.land_on_kinks
        self.div = scene.divergence
        rigid = scene.structure.builder == 'column' and scene.structure.bases == 'rigid'
        self._check_twist = self.div.bar_crossing == 'all' or (
            self.div.bar_crossing == 'rigid' and rigid)
        self._base_force = None
        self.reset()

    # -- state ----------------------------------------------------------------------------------
    def reset(self):
        """Back to the reference geometry at rest, t = 0, rest lengths of the scene."""
        net = self.network
        if self.expanded is not None:                       # undo an expansion to full3d
            self.model = self._model_cls(net, f_ext=self.f_ext, effects=self.effects)
            self.expanded = None
        self.model.set_state(net.x0, np.zeros((net.n_nodes, 3)))
        ns = self.model.n_strikers
        if ns:                                  # strikers back on the free ends, at rest
            self.model.x[-ns:, 2] = np.asarray(net.x0)[net.levels[:, -1], 2].mean(axis=1)
            self.model.v[-ns:] = 0.0
        self.model.set_cables(net.cable_rest_length, net.cable_EA)
        self.model.set_refinement((0.0, 0.0, 0.0))      # contacts met, halving levels
        self.model.set_dissipated(0.0)
        self._cache = {}
        self._call = None
        self.t = 0.0
        self.step = 0
        self.steps_taken = 0
        self.integrator.reset()
        self._prestrain_map = None
        self._prestrain = None          # (n_columns, n_prisms) current cross prestrain, or None
        self._ramp = None               # the Ramp of the prestrain, while it ramps
        self._ramp_call = None          # its compiled call (Loading._ramp_record)
        if net.levels.size and net.meta.get('builder') == 'column':
            self._prestrain = np.full((net.n_columns, net.n_prisms), float(net.meta['prestrain']))
        self._energy_ref = self._energy_0 = self.energy()
        self._energy_scale = abs(self._energy_ref)
        self._twist_ref = self._twists()

    def clone(self):
        """An independent copy that continues exactly as this simulation would (state, cables,
        prestrain and ramp, energy reference, integrator history); arrays of columns split their
        groups with it."""
        new = copy.copy(self)
        new.model = self.model.copy()
        new.integrator = self.integrator.clone()
        new._cache = {}
        new._call = None
        new._prestrain = None if self._prestrain is None else self._prestrain.copy()
        new._ramp = None if self._ramp is None else self._ramp._replace(
            start=self._ramp.start.copy(), target=self._ramp.target.copy())
        new._ramp_call = None
        new._base_force = None
        return new

    # Quantities of the current state are computed once and kept until the state changes
    # (every change goes through _changed): the divergence check, frame() and the node share them.
    def _changed(self):
        self._cache = {}

    def _cached(self, key, compute):
        c = self._cache
        if key not in c:
            c[key] = compute()
        return c[key]

    def _summary(self):
        """The :class:`StateSummary` of the current state, from one compiled call (made by
        :meth:`advance` itself, inside the integrator call, when the model is exact)."""
        c = self._cache.get('summary')
        if c is None:
            c = self._cache['summary'] = self._compute_summary()
        return c

    def _compute_summary(self):
        m, net = self.model, self.network
        if m.exact:                             # on the model's own (maybe reduced) state
            h = np.empty(self._heights_shape)
            finite, e, cerr, h_min = summary.state_summary(m.x, m.v, m.rec, m.data, h)
            return StateSummary(finite, e, h, cerr, h_min)
        x, v = self._full_state()
        if m.integrates_itself:                   # chain1d: its own energy
            finite, e, h, cerr = (dyn.all_finite(x) and dyn.all_finite(v), m.energy(),
                                  observables.prism_heights(x, net.levels), m.constraint_error())
        else:
            finite, e, h, cerr = observables.state_summary(x, v, net, m.cable_rest_length,
                                                           m.cable_EA, self._f_ext_or_none)
            if self.effects.active:             # striker, contact energies
                e += contact.extra_energy(m.x, m.v, m.rec)
                finite = finite and dyn.all_finite(m.x) and dyn.all_finite(m.v)
        return StateSummary(finite, e, h, cerr, float(h.min()) if h.size else math.inf)

    def energy(self):
        """Total energy of the current state, J."""
        return self._summary().energy

    def _balance(self, e):
        scale = max(abs(self._energy_ref), abs(e), self._energy_scale, 1e-300)
        return (e + self.energy_dissipated() - self._energy_ref) / scale

    def energy_dissipated(self):
        """Energy J the cable damping took out since the reset (the ledger's ``D``; booked by
        ``rk4``, ``rk4_projected`` and ``dopri54_projected``, 0 otherwise)."""
        return self.model.dissipated()

    def _refinement(self):
        """What the steps of ``rk4`` after a contact depend on besides the state
        (:data:`solver.integrators.rk4.REFINE_SHARE`): the contacts met since the reset and the
        two halving levels, or None where the model never refines them."""
        return self.model.refinement()

    @property
    def _books_dissipation(self):
        return self.integrator.name in ('rk4', 'rk4_projected', 'dopri54_projected')

    def energy_error(self):
        """Energy balance error of the current state (signed, relative):
        ``(E + D - E_0 - W) / S``, ``E`` the energy now (kinetic, cable, contact, striker), ``D``
        the energy cable damping took out (booked by ``rk4``, ``rk4_projected`` and
        ``dopri54_projected``), ``W`` the work of every command since the reset (impacts,
        prestrain changes, rest lengths), ``S`` the largest of ``|E|``, ``|E_0 + W|`` seen so far.
        Checked against ``divergence.energy_error`` after every :meth:`advance`: in both
        directions, or, with cable damping under a method that does not book ``D``, against
        gains only."""
        return self._balance(self.energy())

    @property
    def contacts_met(self):
        """How many force evaluations met a touching pair of bars or two touching bases since
        the reset (0 without bar contact): whether contact acted in a run."""
        return self.model.contacts_met

    def energy_work(self):
        """Work J put in by commands since the reset (the ledger's ``W``)."""
        return self._energy_ref - self._energy_0

    def _add_work(self, before):
        """Book the change of energy since ``before`` J as the work of a command."""
        after = self.energy()
        self._energy_ref += after - before
        self._energy_scale = max(self._energy_scale, abs(after), abs(self._energy_ref))
        return after - before

    def constraint_error(self):
        """Relative constraint error of the current state."""
        return self._summary().constraint_error

    def _full_state(self):
        """Full (n_nodes, 3) positions and velocities of the current state (shared, read only)."""
        return self._cached('full', lambda: FullState(self.model.positions(),
                                                      self.model.velocities()))

    def _heights(self):
        """Prism heights (n_columns, n_prisms) m of the current state (shared, read only)."""
        return self._summary().heights

    def expand_to_full3d(self, reason):
        """Continue a ``sym3d`` run with ``full3d`` from the same (expanded) state: no jump."""
        if self.model.reduced is not None:
            strikers = extras.striker_state(self.model)
            dissipated, kept = self.energy_dissipated(), self._refinement()
            self.model = models.expand(self.model, self.f_ext,
                                       strikers if len(strikers) else None)
            self.model.set_dissipated(dissipated)
            self.model.set_refinement(kept)     # contacts met and the halvings go on
            self.integrator.reset()                 # forget step-size history of sym3d
            self.expanded = reason
            self._changed()

    def _into_model(self, setter, *args):
        """Call the model's ``setter`` (``'set_state'`` or ``'set_cables'``) with full arrays; an
        asymmetric value expands a ``sym3d`` run to ``full3d`` first (same state, no jump)."""
        try:
            getattr(self.model, setter)(*args)
        except models.NotSymmetric as exc:
            self.expand_to_full3d(str(exc))
            getattr(self.model, setter)(*args)
        self.integrator.state_changed()
        self._changed()

    def _load(self, x, v):
        """Load a full state; an asymmetric one expands a ``sym3d`` run to ``full3d``."""
        self._into_model('set_state', x, v)
        self._twist_ref = self._twists()

    def set_cable_rest_lengths(self, rest):
        """Set the cable rest lengths (n_cables,) m directly (finite, positive). A set that breaks
        the 3-fold symmetry expands a ``sym3d`` run to ``full3d`` (same state, no jump). The
        change of stored energy is added to the divergence energy reference."""
        rest = rest_length_values(rest, self.network.n_cables)
        e0 = self.energy()
        self._set_cables(rest, self.model.cable_EA)
        self._add_work(e0)

    def _set_cables(self, rest, EA):
        """Load full (n_cables,) rest lengths and EA; asymmetric ones expand ``sym3d``."""
        self._into_model('set_cables', rest, EA)

    def _integrate(self, n, first=None):
        """``n`` steps; while a prestrain ramp runs, one step at a time with rest lengths updated
        at the start of each step (in the integrator's compiled ramped call where it has one:
        :meth:`~solver.simulate.loading.Loading._ramped`; ``first``: the result of the first
        such call, made by a lane group). Returns ``(steps, status)`` of the integrator."""
        m = self.model
        self._changed()
        if m.integrates_itself:                     # chain1d: its own state and kernel
            if self._ramp is not None:
                return 0, codes.CHAIN_CANNOT_RAMP
            return m.advance(self.dt, n)
        done = total = 0
        status = dyn.OK
        end_set = False             # the rest lengths at t + n dt set (by a ramped call)
        while first is not None or (done < n and self._ramp is not None):
            ramped, first = (self._ramped(done, n) if first is None else first), None
            if ramped is not None:
                done, steps, status, end_set, made = ramped
                if made is not None:                # the end state's, from the same call
                    self._cache = {'summary': StateSummary(*made)}
            else:
                self._ramp_to(self.t + done * self.dt)
                m = self.model
                steps, status = self.integrator.run(m.rec, m.data, m.work, self.dt, 1,
                                                    self.tol, self.max_iter, self.kinks)
                self._changed()
                done += 1
            total += steps
            if status != dyn.OK:
                return total, status
        m = self.model
        if done < n:
            steps, status = self.integrator.run(m.rec, m.data, m.work, self.dt, n - done,
                                                self.tol, self.max_iter, self.kinks)
            self._changed()
            total += steps
        if self._ramp is not None and not end_set:
            self._ramp_to(self.t + n * self.dt)
        return total, status

    # -- time -----------------------------------------------------------------------------------
    def advance(self, duration):
        """Advance by ``duration`` s in whole steps of ``dt`` (the last one shortened to land on
        ``t + duration``). Raises :class:`SimulationDiverged` and restores the state on failure.

        Without a prestrain ramp, on an exact model, this is one compiled call: the integrator
        keeps the start data, runs, and summarises the end state for the check."""
        n = max(int(round(duration / self.dt)), 0)
        if n == 0:
            return 0
        m = self.model
        if not m.exact or self._ramp is not None:
            return self._stepped(n, self._keep())
        integ, call = self.integrator, self._call
        if call is None or call.model is not m or call.integrator is not integ:
            kept = records.clone_data(m.data)       # where the call keeps the start data
            call = self._call = CheckedCall(m, integ, kept, integ.checked_args(
                m.rec, m.data, m.work, self.tol, self.max_iter, self.kinks, kept))
        integ_state = integ.get_state()
        h = np.empty(self._heights_shape)
        args = (m.rec, m.data, m.work, float(self.dt), n, *call.fixed, h)
        if call.entry is None:  # through numba's dispatch, then its compiled overload
            out = integ.checked(*args)
            call.entry = compiled_overload(integ.checked, args) or integ.checked
        else:
            out = call.entry(*args)
        steps, status, finite, e, cerr, h_min = out
        self._cache = {'summary': StateSummary(finite, e, h, cerr, h_min)}
        return self._conclude(n, steps, status, call.kept, integ_state)

    def _stepped(self, n, keep, first=None):
        """:meth:`advance` by :meth:`_integrate` (``first`` its argument) from the state
        ``keep`` holds, concluded."""
        steps, status = self._integrate(n, first)
        return self._conclude(n, steps, status, keep=keep)

    def _conclude(self, n, steps, status, kept_data=None, integ_state=None, keep=None):
        """The end of an interval of ``n`` steps whose integrator returned ``steps`` and
        ``status`` (from :meth:`advance`, or a lane group's call:
        :mod:`solver.simulate.lanebatch`), the state summary of the call, if it made one,
        already in the cache. Checks the state; on a failure restores the interval's start (the
        :class:`Kept` ``keep``, or the data ``kept_data`` the call kept, or a function that
        gives them, and the integrator's ``integ_state``) and raises
        :class:`SimulationDiverged` naming the step, else moves the clock. Returns ``steps``."""
        problem = self._check(status)
        if problem is not None:
            if keep is None:
                keep = self._kept(kept_data() if callable(kept_data) else kept_data,
                                  integ_state)
            self._restore(keep)
            raise self._locate(n, keep, problem)
        self._energy_scale = max(self._energy_scale, abs(self._summary().energy))
        self.t += n * self.dt
        self.step += n
        self.steps_taken += steps
        return steps

    def advance_part(self, fraction):
        """Advance by one step shortened to ``fraction`` (0 < fraction <= 1) of ``dt``, checked
        like :meth:`advance` (a frame off the ``dt`` grid; ``step`` counts it as one). The node
        takes one when a whole step costs more than a tick's budget (a column in lasting contact
        takes hundreds of contact sub-steps per step), so that it publishes on time."""
        fraction = float(fraction)
        if not 0.0 < fraction <= 1.0:
            raise ValueError(f'advance_part: fraction {fraction!r} must be in (0, 1]')
        dt = self.dt
        self.dt = fraction * dt
        try:
            return self.advance(self.dt)
        finally:
            self.dt = dt

    def base_force(self):
        """Axial base force (n_columns,) N of the current state, positive compressive (zeros for
        a network without columns or a model without a full state of rigid members): from the
        model's own state where it has a summary (:class:`solver.analysis.support.ModelBaseForce`:
        no expansion of a ``sym3d`` state), else from the full state
        (:class:`solver.analysis.support.BaseForce`)."""
        def compute():
            net, m = self.network, self.model
            if not net.levels.size or m.integrates_itself:       # chain1d: none
                return np.zeros(net.n_columns)
            kept = self._base_force        # the force of this model, and whether it reads
            if kept is None or kept.model is not m:     # the model's own state
                from solver.analysis.support import BaseForce, ModelBaseForce
                own = ModelBaseForce.applies(m)
                kept = self._base_force = BaseForceOf(
                    m, ModelBaseForce(m) if own else BaseForce(net, self.effects), own)
            if kept.own:
                return kept.force(m)
            x, v = self._full_state()
            return kept.force(x, v, m.cable_rest_length, m.cable_EA, self.f_ext)
        return self._cached('base_force', compute)

    def frame_figures(self):
        """The :class:`FrameFigures` of the current state: the figures of :meth:`frame` a run's
        summary reads, without copying positions or computing tensions."""
        net = self.network
        if net.levels.size:
            strain = observables.strains_of_heights(self._heights(), net.h0)
        else:
            strain = np.zeros((0, 0))
        return FrameFigures(self.t, strain, self.energy(), self.constraint_error(),
                            float(self.energy_error()))

    def frame(self):
        """A copied :class:`Frame` of the current state."""
        x = np.array(self._full_state().x)
        net = self.network
        f = self.frame_figures()
        return Frame(t=f.t, step=self.step, positions=x, strain=f.strain,
                     tension=observables.cable_tensions(x, net, self.model.cable_rest_length,
                                                        self.model.cable_EA),
                     energy=f.energy, constraint_error=f.constraint_error,
                     base_force=np.array(self.base_force()), striker=self.striker(),
                     energy_balance_error=f.energy_balance_error)

