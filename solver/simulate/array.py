"""Arrays of columns that do not interact: one reduced simulation per column, shared by the
columns that are alike.

The column builder lays out column ``c`` as column 0 moved by ``c * column_spacing`` along x, and
no member joins two columns: the columns are independent systems. :class:`ArraySimulation` runs
each as a one-column :class:`~solver.simulate.simulation.Simulation` of its own (``model: auto``
then picks the exact 3-fold reduction ``sym3d`` about the column's own axis), and columns that have
had the same commands share one simulation (a *group*). A command that treats the columns of a
group differently splits it: the group's simulation is copied, state, cables, prestrain ramp and
integrator history included, so every copy continues exactly as the shared one would have. A
command that breaks a column's symmetry (asymmetric rest lengths or state) expands only that
column's simulation to ``full3d`` (the one-column simulation does this itself).

:class:`ArraySimulation` implements :class:`~solver.simulate.interface.SimulationAPI`, as
:class:`~solver.simulate.simulation.Simulation` does (:func:`simulation_for` returns an
:class:`ArraySimulation` when :func:`wants_array` holds); frames hold the full array
(node, cable and column order of the column builder's network). Every column steps with the same
``dt`` on one clock ``t``; the groups are independent simulations and step in parallel on threads
(:mod:`solver.simulate.parallel`). A divergence in any column restores every column and names the
column.
"""
from __future__ import annotations

import math

import numpy as np

from solver.build import memo
from solver.build.scene import Scene
from solver.analysis import observables
from solver.build.structures import PrestrainMap, build_network
from solver.models.base import ModelView
from solver.simulate import chooser, lanebatch, laneframe, parallel
from solver.simulate.interface import SimulationAPI
from solver.simulate.loading import prestrain_values, rest_length_values
from solver.simulate.simulation import Frame, FrameFigures, Simulation, SimulationDiverged


def simulation_for(scene, network=None, **options):
    """The simulation of ``scene``: an :class:`ArraySimulation` for an array of columns built by
    the column builder (:func:`wants_array`, no ``network`` given), else a
    :class:`~solver.simulate.simulation.Simulation` (``network``: an existing network to run)."""
    if network is None and wants_array(scene):
        return ArraySimulation(scene, **options)
    return Simulation(scene, network, **options)


def wants_array(scene):
    """Whether ``scene`` runs as an :class:`ArraySimulation`: a column-builder structure with more
    than one column and ``model`` ``auto`` or ``sym3d``."""
    s = scene.structure
    return s.builder == 'column' and s.n_columns > 1 and scene.model in ('auto', 'sym3d')


class _ArrayModel(ModelView):
    """The model view of an array (what callers read of ``sim.model``): full arrays assembled
    from the columns' models; ``name`` the columns' model (``sym3d``, ``full3d`` or both joined
    by ``+``)."""

    def __init__(self, array):
        self._a = array

    @property
    def name(self):
        names = sorted({g.sim.model.name for g in self._a.groups})
        return '+'.join(names)

    def positions(self):
        return self._a._assemble_nodes(lambda s: s.model.positions(), offset=True)

    def velocities(self):
        return self._a._assemble_nodes(lambda s: s.model.velocities(), offset=False)

    @property
    def cable_rest_length(self):
        return self._a._assemble_cables(lambda s: s.model.cable_rest_length)

    @property
    def cable_EA(self):
        return self._a._assemble_cables(lambda s: s.model.cable_EA)

    def set_state(self, x, v):
        self._a._load(x, v)

    def set_cables(self, rest, EA):
        self._a._set_cables(rest, EA)


class _Group:
    __slots__ = ('sim', 'columns')

    def __init__(self, sim, columns):
        self.sim, self.columns = sim, list(columns)


class ArraySimulation(SimulationAPI):
    """An array of independent columns (see the module text). ``dedup=False`` gives every column
    its own simulation from the start (the plain twin of the shared one)."""

    threads = None          # threads the groups step on (None: every core; 1: one after another)
    # alike groups step together as lanes (solver.simulate.lanebatch): True, False, or 'auto':
    # the faster of the two as measured along the run (both give the same result, bit for bit);
    # set from the scene's integrator.lanes
    lanes = False
    _chooser = None

    def __init__(self, scene: Scene, network=None, dedup=True):
        if network is not None:
            raise ValueError('ArraySimulation builds its own network from the scene')
        self.scene = scene
        self.network = net = build_network(scene)
        data = scene.data
        data['structure']['n_columns'] = 1
        data['loading']['impact']['columns'] = None
        if data['model'] == 'sym3d':
            data['model'] = 'auto'      # per column: sym3d where the column is symmetric
        self.column_scene = Scene(data, source=scene.source)
        proto = Simulation(self.column_scene)
        cnet = proto.network
        self.n_columns = nc = net.n_columns
        self._per = (cnet.n_nodes, cnet.n_cables)
        self._offset = np.zeros((nc, 3))
        self._offset[:, 0] = np.arange(nc) * scene.structure.column_spacing
        self._check_layout(cnet)
        self.dedup = bool(dedup)
        self.lanes = {'off': False, 'on': True, 'auto': 'auto'}[scene.integrator.lanes]
        self._proto = proto
        self.dt = proto.dt
        self.integrator = proto.integrator
        self.div = proto.div
        self._prestrain_map = None
        self.model = _ArrayModel(self)
        self.reset()

    def _check_layout(self, cnet):
        """The full network is the column network repeated, moved by the offsets (the builder's
        layout); anything else is a programming error."""
        net, nc = self.network, self.n_columns
        n, k = self._per
        tiled = (np.asarray(cnet.x0)[None] + self._offset[:, None]).reshape(-1, 3)
        shift = (np.arange(nc) * n)[:, None]
        same = (net.n_nodes == nc * n and net.n_cables == nc * k
                and np.allclose(net.x0, tiled, rtol=0, atol=1e-12)
                and np.array_equal(net.cable_a, (cnet.cable_a[None] + shift).ravel())
                and np.array_equal(net.cable_b, (cnet.cable_b[None] + shift).ravel())
                and np.array_equal(net.bar_a, (cnet.bar_a[None] + shift).ravel()))
        if not same:
            raise RuntimeError('array: the network is not the column network repeated')

    # -- groups ---------------------------------------------------------------------------------
    def reset(self):
        """Back to the reference geometry at rest, t = 0: every column alike again."""
        self._proto.reset()
        cols = range(self.n_columns)
        if self.dedup:
            self.groups = [_Group(self._proto, cols)]
        else:
            self.groups = [_Group(self._proto if c == 0 else self._proto.clone(), [c])
                           for c in cols]
        self._cache = {}
        self._plan = None

    def _group_of(self):
        """Group index per column (n_columns,)."""
        g = np.empty(self.n_columns, dtype=np.int64)
        for i, grp in enumerate(self.groups):
            g[grp.columns] = i
        return g

    def _dispatch(self, per_column, apply):
        """Apply a command column by column: ``per_column`` maps column -> a hashable key of what
        the command does to it (None: not addressed); ``apply(sim, key)`` applies it to a
        simulation. Groups whose columns get different keys are split first (copies); all checks
        must be done before (nothing here may fail half-way)."""
        new_groups = []
        for grp in self.groups:
            parts = {}
            for c in grp.columns:
                parts.setdefault(per_column(c), []).append(c)
            items = list(parts.items())
            for i, (key, cols) in enumerate(items):
                sim = grp.sim if i == 0 else grp.sim.clone()
                new_groups.append((_Group(sim, cols), key))
        # apply after every copy is made (a copy must be of the state before the command); what
        # the columns' commands build of their network, they build once (memo)
        with memo.sharing():
            for grp, key in new_groups:
                if key is not None:
                    apply(grp.sim, key)
        self.groups = sorted((g for g, _ in new_groups), key=lambda g: g.columns[0])
        self._cache = {}
        self._plan = None
        if self.lanes and len(self.groups) > 1:
            self._lane_plan()       # with the command, not in the next step's time (the node)

    # -- assembling full arrays -----------------------------------------------------------------
    def _assemble_nodes(self, get, offset):
        n = self._per[0]
        out = np.empty((self.n_columns * n, 3))
        for grp in self.groups:
            a = np.asarray(get(grp.sim))
            for c in grp.columns:
                out[c * n:(c + 1) * n] = a + self._offset[c] if offset else a
        return out

    def _assemble_cables(self, get):
        k = self._per[1]
        out = np.empty(self.n_columns * k)
        for grp in self.groups:
            a = np.asarray(get(grp.sim))
            for c in grp.columns:
                out[c * k:(c + 1) * k] = a
        return out

    def _split_nodes(self, a, offset):
        a = np.asarray(a, dtype=np.float64)
        n = self._per[0]
        if a.shape != (self.n_columns * n, 3):
            raise ValueError(f'array: expected ({self.n_columns * n}, 3) values, got {a.shape}')
        return [a[c * n:(c + 1) * n] - (self._offset[c] if offset else 0.0)
                for c in range(self.n_columns)]

    def _load(self, x, v):
        xs, vs = self._split_nodes(x, True), self._split_nodes(v, False)
        keys = [(xs[c].tobytes(), vs[c].tobytes()) for c in range(self.n_columns)]
        states = dict(zip(keys, zip(xs, vs)))
        self._dispatch(lambda c: keys[c], lambda s, key: s._load(*states[key]))

    def _set_cables(self, rest, EA):
        k = self._per[1]
        rest, EA = np.asarray(rest, dtype=np.float64), np.asarray(EA, dtype=np.float64)
        if rest.shape != (self.n_columns * k,) or EA.shape != rest.shape:
            raise ValueError(f'array: expected {self.n_columns * k} cable values')
        rows = {}
        keys = []
        for c in range(self.n_columns):
            r, e = rest[c * k:(c + 1) * k], EA[c * k:(c + 1) * k]
            key = (r.tobytes(), e.tobytes())
            rows[key] = (r, e)
            keys.append(key)
        self._dispatch(lambda c: keys[c], lambda s, key: s._set_cables(*rows[key]))

    # -- clock and summaries --------------------------------------------------------------------
    t = property(lambda self: self.groups[0].sim.t)
    step = property(lambda self: self.groups[0].sim.step)

    @property
    def steps_taken(self):
        """Integrator steps of one column (the most any column took)."""
        return max(g.sim.steps_taken for g in self.groups)

    @property
    def expanded(self):
        """Why columns were expanded to ``full3d`` (text naming them), or None."""
        why = [(g.columns, g.sim.expanded) for g in self.groups if g.sim.expanded]
        return '; '.join(f'columns {cols}: {text}' for cols, text in why) if why else None

    @property
    def f_ext(self):
        return self._assemble_nodes(lambda s: s.f_ext, offset=False)

    def energy(self):
        """Total energy of the array, J."""
        e = np.empty(self.n_columns)
        for g in self.groups:
            e[g.columns] = g.sim.energy()
        return float(sum(e.tolist()))           # column by column: the same sum however grouped

    def constraint_error(self):
        return float(max(g.sim.constraint_error() for g in self.groups))

    def energy_error(self):
        """The energy balance error of the column furthest from balance (signed, relative to
        that column's own scale: :meth:`Simulation.energy_error`)."""
        return float(max((g.sim.energy_error() for g in self.groups), key=abs))

    def energy_work(self):
        """Work J put in by commands since the reset, every column."""
        return float(sum(len(g.columns) * g.sim.energy_work() for g in self.groups))

    # the bar contact of the scene (every group has it), and the contacts met by every group
    bar_contact = property(lambda self: self.groups[0].sim.bar_contact)
    contacts_met = property(lambda self: sum(g.sim.contacts_met for g in self.groups))

    def base_force(self):
        out = np.empty(self.n_columns)
        for g in self.groups:
            out[g.columns] = g.sim.base_force()[0]
        return out

    @property
    def n_simulated(self):
        """How many column simulations run (groups)."""
        return len(self.groups)

    # -- commands -------------------------------------------------------------------------------
    def _columns(self, columns, what):
        cols = list(range(self.n_columns)) if columns is None else [int(c) for c in columns]
        if not cols or any(not 0 <= c < self.n_columns for c in cols):
            raise ValueError(f'{what}: columns must be indices 0..{self.n_columns - 1}')
        return cols

    def apply_impact(self, v0, columns=None, mode=None):
        """Impact the free ends of the addressed columns (as :meth:`Simulation.apply_impact`,
        each column on its own; ``mode='energy'`` rescales each column's kick to its own
        ``3 m v0^2 / 2``). Returns the kinetic energy added, J."""
        cols = self._columns(columns, 'impact')
        v0 = np.asarray(v0, dtype=np.float64)
        v = np.broadcast_to(v0, (len(cols),)) if v0.ndim == 0 else v0
        if v.shape != (len(cols),):
            raise ValueError(f'impact: expected 1 or {len(cols)} values, got {v0.size}')
        if not np.all(np.isfinite(v)):
            raise ValueError('impact: velocity is not finite')
        mode = mode or self.scene.loading.impact.mode
        value = dict(zip(cols, v.tolist()))
        before = self.energy()
        self._dispatch(value.get, lambda s, key: s.apply_impact(key, mode=mode))
        return self.energy() - before

    def prestrain_target(self, p, columns=None):
        """Per-prism prestrain (n_columns, n_prisms) of a command (see
        :meth:`Simulation.prestrain_target`)."""
        cols = self._columns(columns, 'prestrain')
        n_p = self.network.n_prisms
        p = prestrain_values(p, len(cols), n_p)
        target = self.prestrain_goal
        target[cols] = p
        return target

    def apply_prestrain(self, p, columns=None, ramp_s=0.0):
        """Change the cross prestrain of the addressed columns, ramped over ``ramp_s`` s (see
        :meth:`Simulation.apply_prestrain`), each column on its own."""
        target = self.prestrain_target(p, columns)
        if not (math.isfinite(ramp_s) and ramp_s >= 0):
            raise ValueError(f'prestrain: ramp duration {ramp_s!r} must be >= 0')
        cols = set(self._columns(columns, 'prestrain'))
        rows = {c: target[c] for c in cols}
        self._dispatch(lambda c: rows[c].tobytes() if c in cols else None,
                       lambda s, key: s.apply_prestrain(np.frombuffer(key)[None, :],
                                                        ramp_s=ramp_s))

    def set_cable_rest_lengths(self, rest):
        """Set the cable rest lengths (n_cables,) m of the whole array (see
        :meth:`Simulation.set_cable_rest_lengths`); a column whose set breaks its symmetry is
        expanded to ``full3d`` alone."""
        k = self._per[1]
        rest = rest_length_values(rest, self.network.n_cables)
        rows = [rest[c * k:(c + 1) * k] for c in range(self.n_columns)]
        self._dispatch(lambda c: rows[c].tobytes(),
                       lambda s, key: s.set_cable_rest_lengths(np.frombuffer(key)))

    @property
    def prestrain(self):
        out = np.empty((self.n_columns, self.network.n_prisms))
        for g in self.groups:
            out[g.columns] = g.sim.prestrain[0]
        return out

    @property
    def prestrain_goal(self):
        """The prestrain per prism (n_columns, n_prisms) each column ramps to, or has."""
        out = np.empty((self.n_columns, self.network.n_prisms))
        for g in self.groups:
            out[g.columns] = g.sim.prestrain_goal[0]
        return out

    @property
    def prestrain_map(self):
        """The :class:`~solver.build.structures.PrestrainMap` of the whole array's network
        (built on first use)."""
        if self._prestrain_map is None:
            self._prestrain_map = PrestrainMap(self.network)
        return self._prestrain_map

    def striker(self):
        """(n_columns, 2) each column's striker face height m and axial velocity m/s, or None
        without strikers."""
        out = None
        for g in self.groups:
            st = g.sim.striker()
            if st is None:
                return None
            if out is None:
                out = np.empty((self.n_columns, 2))
            out[g.columns] = st            # (1, 2): the group's one column
        return out

    # -- time -----------------------------------------------------------------------------------
    def advance(self, duration):
        """Advance every column by ``duration`` s (whole steps of ``dt``), the groups in parallel
        on :attr:`threads` threads (:func:`solver.simulate.parallel.each`). A divergence in any
        column restores every column and raises :class:`SimulationDiverged` naming it (the first
        diverging group in column order)."""
        n = max(int(round(duration / self.dt)), 0)
        if not (self.lanes and n > 0 and len(self.groups) > 1):
            return self._each(lambda sim: sim.advance(duration))
        if self.lanes != 'auto':
            return self._advance_lanes(duration, n)
        if self._chooser is None:
            self._chooser = chooser.Chooser()
        return self._chooser.run(lambda lanes: self._advance_lanes(duration, n) if lanes
                                 else self._each(lambda sim: sim.advance(duration)), n)

    def _lane_plan(self):
        """``(lane groups, single simulations)`` of the present groups
        (:func:`solver.simulate.lanebatch.plan_of`), kept while the groups stay and the split
        holds (:meth:`~solver.simulate.lanebatch.Plan.holds`)."""
        if self._plan is None or not self._plan.holds():
            self._plan = lanebatch.plan_of([g.sim for g in self.groups],
                                           self.threads or parallel.default_threads(), True)
        return self._plan

    def _advance_lanes(self, duration, n):
        """:meth:`advance` with alike groups stepped as lanes (one lane group per thread) and
        the others one at a time; a failure restores every column, as :meth:`_each` does."""
        step = lanebatch.Step(self._lane_plan(), [g.sim for g in self.groups])
        step.run(duration, self.threads)
        self._cache = {}
        failed = next(((g, step.error(g.sim)) for g in self.groups if step.error(g.sim)), None)
        if failed is not None:
            step.restore()
            grp, exc = failed
            if isinstance(exc, SimulationDiverged):
                raise exc.for_columns(grp.columns) from None
            raise exc
        return step.most_steps()

    def advance_part(self, fraction):
        """Every column by one step shortened to ``fraction`` of ``dt``
        (:meth:`Simulation.advance_part`): as lanes where :meth:`advance` steps them so
        (``'auto'``: the way its chooser prefers), every column's ``dt`` that fraction for the
        call, else one column simulation at a time."""
        sims = [g.sim for g in self.groups]
        way = self.lanes if self.lanes != 'auto' else self._chooser and self._chooser.best
        if not (way and len(sims) > 1 and 0.0 < float(fraction) <= 1.0):
            return self._each(lambda sim: sim.advance_part(fraction))
        dts = [s.dt for s in sims]
        for s in sims:
            s.dt = float(fraction) * s.dt      # as Simulation.advance_part
        try:
            return self._advance_lanes(sims[0].dt, 1)
        finally:
            for s, dt in zip(sims, dts):
                s.dt = dt

    def _each(self, step):
        groups = self.groups
        keeps = [(s._keep(), s.t, s.step, s.steps_taken) for s in (g.sim for g in groups)]
        results = parallel.each(lambda g: step(g.sim), groups,
                                self.threads if len(groups) > 1 else 1)
        self._cache = {}
        failed = next(((g, v) for g, (ok, v) in zip(groups, results) if not ok), None)
        if failed is not None:
            for g, (ok, _), (k, t, step, taken) in zip(groups, results, keeps):
                if ok:                     # a group that failed restored itself
                    g.sim._restore(k)
                    g.sim.t, g.sim.step, g.sim.steps_taken = t, step, taken
            grp, exc = failed
            if isinstance(exc, SimulationDiverged):
                raise exc.for_columns(grp.columns) from None
            raise exc
        return max(v for _, v in results)

    def frame_figures(self):
        """The :class:`~solver.simulate.simulation.FrameFigures` of the whole array, as
        ``Simulation.frame_figures`` (from :meth:`frame`)."""
        f = self.frame()
        return FrameFigures(f.t, f.strain, f.energy, f.constraint_error, f.energy_balance_error)

    def frame(self):
        """A copied :class:`~solver.simulate.simulation.Frame` of the whole array (each group's
        figures as its ``Simulation.frame``; the lane groups' a group at a time:
        :func:`~solver.simulate.laneframe.fill`)."""
        (n, k), nc, n_p = self._per, self.n_columns, self.network.n_prisms
        x, strain, tension = np.empty((nc, n, 3)), np.empty((nc, n_p)), np.empty((nc, k))
        base, energy, cerr, balance = np.empty(nc), np.empty(nc), 0.0, []
        errs = laneframe.fill(self._lane_plan() if len(self.groups) > 1 else None,
                              {id(g.sim): g.columns for g in self.groups}, self._offset, x,
                              strain, tension, base, energy)
        for grp in self.groups:         # balance: each group's energy balance error, in order
            s, m = grp.sim, grp.sim.model
            if id(s) in errs:
                cerr = max(cerr, errs[id(s)][0])
                balance.append(errs[id(s)][1])
                continue
            balance.append(s.energy_error())
            pos = m.positions()
            f = s.frame_figures()
            ten = observables.cable_tensions(pos, s.network, m.cable_rest_length, m.cable_EA)
            b = s.base_force()[0]
            for c in grp.columns:
                np.add(pos, self._offset[c], out=x[c])
                tension[c], strain[c], base[c], energy[c] = ten, f.strain[0], b, f.energy
            cerr = max(cerr, f.constraint_error)
        return Frame(t=self.t, step=self.step, positions=x.reshape(nc * n, 3), strain=strain,
                     tension=tension.reshape(nc * k), energy=float(sum(energy.tolist())),
                     constraint_error=cerr, base_force=base,
                     energy_balance_error=float(max(balance, key=abs)))

