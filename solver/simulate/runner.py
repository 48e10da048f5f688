"""Headless runs: a scene from its impact (or train of impacts) to ``t_end``, recorded at
``output_dt``; the summary."""
from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field

import numpy as np

from solver.analysis import observables, support
from solver.build.scene import Scene
from solver.simulate.results import ImpactApplied, RunSummary, StrikerEnd
from solver.simulate.simulation import Simulation, SimulationDiverged
from solver.simulate.array import simulation_for


@dataclass
class RunRecord:
    """Everything a run recorded. ``times`` (n_t,) s, ``strain`` (n_t, n_columns, n_prisms),
    ``energy`` (n_t,) J, ``constraint_error`` (n_t,), ``energy_balance_error`` (n_t,) (signed,
    relative: :meth:`Simulation.energy_error`), ``wall_time_s`` of the time stepping only,
    ``impacts``: the :class:`~solver.simulate.results.ImpactApplied` of each impact the run
    applied."""
    times: np.ndarray
    strain: np.ndarray
    energy: np.ndarray
    constraint_error: np.ndarray
    wall_time_s: float
    steps: int
    steps_taken: int
    pulses: list = field(default_factory=list)
    base_force: np.ndarray = None       # (n_t, n_columns) N, positive compressive
    energy_balance_error: np.ndarray = None
    impacts: list = field(default_factory=list)


def run_frame(sim: Simulation):
    """The current :meth:`Simulation.frame` of ``sim`` (it carries the energy balance error)."""
    return sim.frame()


class ImpactTrain:
    """The impacts of a scene's ``loading.impact`` (one, or a train) on the step grid of ``dt``:
    an impact at ``t`` s lands on step ``round(t / dt)``; impacts of 0 m/s are left out. Each is
    applied once, by :meth:`apply_due`; ``applied`` lists the
    :class:`~solver.simulate.results.ImpactApplied` of those applied, ``t_s`` the simulation
    time it was applied at."""

    def __init__(self, impact, dt):
        self.columns = impact.columns
        self.impacts = [(int(round(t / dt)), float(v0)) for t, v0 in impact.train() if v0]
        self.applied = []

    def __len__(self):
        return len(self.impacts)

    def next_step(self):
        """The step of the next impact to apply, or None when all are applied."""
        i = len(self.applied)
        return self.impacts[i][0] if i < len(self.impacts) else None

    def apply_due(self, sim, on_impact=None):
        """Apply every impact due at or before ``sim.step`` (:meth:`Simulation.apply_impact`),
        calling ``on_impact(index, entry)`` after each (``entry`` as in ``applied``)."""
        while (k := self.next_step()) is not None and k <= sim.step:
            v0 = self.impacts[len(self.applied)][1]
            work = sim.apply_impact(v0, self.columns)
            self.applied.append(ImpactApplied(float(sim.t), v0, float(work)))
            if on_impact is not None:
                on_impact(len(self.applied) - 1, self.applied[-1])


def frame_count(t_end, output_dt):
    """Frames :func:`run` hands out for ``t_end`` in ``output_dt`` steps (the first included)."""
    return int(round(t_end / output_dt)) + 1


def run(sim: Simulation, t_end, output_dt, on_frame=None, progress=None, train=None,
        on_impact=None):
    """Advance ``sim`` to ``t_end`` in ``output_dt`` intervals, calling ``on_frame(frame)``
    (a :class:`~solver.simulate.simulation.Frame`) at each output time (including the first)
    and ``progress(n)`` with the steps of each interval. ``train`` (an :class:`ImpactTrain`):
    each impact is applied when the clock reaches its step, within an interval as on a frame's
    time (before that frame is taken); impacts after the last frame are not applied.
    ``on_impact`` as for :meth:`ImpactTrain.apply_due`."""
    recorder = Recorder(sim, t_end, output_dt, train, on_frame=on_frame, on_impact=on_impact)
    recorder.start()
    for k in range(recorder.n_out):
        recorder.interval(k)
        if progress is not None:
            progress(1)
    return recorder.record_of()


class Recorder:
    """The steps and the record of :func:`run`, one output interval at a time (the batch's
    instances run the same): :meth:`start`, :meth:`interval` ``k`` for ``k < n_out``, then
    :meth:`record_of`. ``frames=False`` records only what the summary reads (no positions or
    cable tensions; no base force either with ``base=False``): the same figures."""

    def __init__(self, sim, t_end, output_dt, train=None, on_frame=None, on_impact=None,
                 frames=True, base=True):
        ratio = output_dt / sim.dt
        if abs(ratio - round(ratio)) > 1e-6 * ratio:       # advance() takes whole steps
            raise ValueError(f'run.output_dt: {output_dt:g} s is not a whole multiple of '
                             f'integrator.dt = {sim.dt:g} s')
        self.sim, self.train = sim, train
        self.per_frame = int(round(ratio))
        self.n_out = frame_count(t_end, output_dt) - 1
        self.on_frame, self.on_impact = on_frame, on_impact
        self.frames = frames or on_frame is not None
        self.with_base = base or self.frames
        self.times, self.strain, self.energy, self.cerr, self.base, self.balance = \
            [], [], [], [], [], []
        self.wall = 0.0
        self.at_ref = RefMomenta(sim, self.per_frame * sim.dt)

    def start(self):
        """The impacts due at the start, the first frame."""
        if self.train is not None:
            self.train.apply_due(self.sim, self.on_impact)
        self.record()

    def record(self):
        """Record the present state (a frame, or its lean part)."""
        sim = self.sim
        if self.frames:
            f = run_frame(sim)
            t, strain, e, cerr, base, bal = (f.t, f.strain, f.energy, f.constraint_error,
                                             f.base_force, f.energy_balance_error)
            if self.on_frame is not None:
                self.on_frame(f)
        else:              # lean: what the summary reads, computed as Simulation.frame does
            f = sim.frame_figures()
            t, strain, e, cerr, bal = (f.t, f.strain, f.energy, f.constraint_error,
                                       f.energy_balance_error)
            base = np.array(sim.base_force()) if self.with_base else None
        self._append(t, strain, e, cerr, base, bal)
        self.at_ref.note(sim, t, len(self.times) - 1)

    def _append(self, t, strain, e, cerr, base, bal):
        """A frame's figures onto the record's lists."""
        self.times.append(t)
        self.strain.append(strain)
        self.energy.append(e)
        self.cerr.append(cerr)
        self.base.append(base)
        self.balance.append(bal)

    def record_many(self, lean):
        """:meth:`record` of each interval of ``lean`` (a
        :class:`~solver.simulate.lanebulk.Lean`: the lean figures of the intervals the
        simulation has just passed, its state at the last), for a lean record only (no frames,
        no base force); the state of an interval whose momenta :class:`RefMomenta` reads is set
        for it."""
        if self.frames or self.with_base:
            raise ValueError('record_many: a lean record only')
        moved = False
        for q in range(len(lean)):
            t = lean.t[q]
            self._append(t, lean.strain[q], lean.energy[q], lean.constraint_error[q], None,
                         float(lean.balance[q]))
            if self.at_ref.reads(t):
                lean.at(q)
                moved = q != len(lean) - 1
            self.at_ref.note(self.sim, t, len(self.times) - 1)
        if moved:
            lean.at(len(lean) - 1)

    def _advance_to(self, step):
        sim = self.sim
        t0 = time.perf_counter()
        sim.advance((step - sim.step) * sim.dt)
        self.wall += time.perf_counter() - t0

    def plain_intervals(self):
        """How many of the next output intervals hold no impact (their steps are one
        ``sim.advance(per_frame * dt)`` each, then :meth:`record`: what :meth:`interval` does);
        a large number when no impact is due."""
        s = None if self.train is None else self.train.next_step()
        if s is None:
            return 1 << 30
        return max((s - self.sim.step - 1) // self.per_frame, 0)

    def interval(self, k):
        """Output interval ``k`` (0-based): each impact on its step within it (applied before
        that frame is taken), the steps, the frame."""
        sim, train = self.sim, self.train
        end = sim.step + self.per_frame
        while train is not None and (s := train.next_step()) is not None and s <= end:
            self._advance_to(max(s, sim.step))
            train.apply_due(sim, self.on_impact)
        self._advance_to(end)
        self.record()

    def record_of(self):
        """The :class:`RunRecord` so far, with its pulses."""
        sim = self.sim
        rec = RunRecord(np.array(self.times), np.array(self.strain), np.array(self.energy),
                        np.array(self.cerr), self.wall, sim.step, sim.steps_taken,
                        base_force=np.array(self.base) if self.with_base else None,
                        energy_balance_error=np.array(self.balance),
                        impacts=list(self.train.applied) if self.train is not None else [])
        self.at_ref.pulses(rec, sim)
        return rec


T_REF = 0.5          # the time the pulse figures are read at (observables.first_passage)


class RefMomenta:
    """The level momenta of a run at its frame nearest ``T_REF`` (:meth:`note` after each
    frame is recorded), for the pulse figures of the record (:meth:`pulses`)."""

    def __init__(self, sim, interval=0.0):
        net = sim.network
        self.masses = observables.momentum_masses(net) if net.levels.size else None
        self.dt, self.k, self.p = np.inf, -1, None
        self.interval = interval        # between frames, s: a frame farther before T_REF than
        # 1.5 intervals is never the one read (a later one is nearer, or none is near enough)

    def reads(self, t):
        """Whether :meth:`note` reads the state of a frame at time ``t`` s."""
        if self.interval > 0 and T_REF - t > 1.5 * self.interval:
            return False
        return self.masses is not None and abs(t - T_REF) < self.dt - 1e-12

    def note(self, sim, t, k):
        """Frame ``k`` at time ``t`` s was just recorded from the present state of ``sim``."""
        if self.reads(t):
            self.dt, self.k = abs(t - T_REF), k
            self.p = observables.level_momenta(sim.model.velocities(), sim.network.levels,
                                               self.masses)

    def pulses(self, rec, sim):
        """Set ``rec.pulses``: each column's first passage and, at the frame nearest
        ``T_REF`` when the pulse is there, its momentum figures
        (:func:`observables.pulse_momentum`)."""
        if not sim.network.levels.size:
            return
        rec.pulses = [observables.first_passage(rec.times, rec.strain[:, c], sim.network.h0)
                      for c in range(sim.network.n_columns)]
        k = self.k
        if k < 0 or abs(rec.times[k] - T_REF) > 0.5 * (rec.times[1] - rec.times[0] if
                                                        len(rec.times) > 1 else 0) + 1e-9:
            return
        unit_mass = float(sim.network.meta.get('unit_mass', np.nan))
        v0 = rec.impacts[0].v0_m_s if rec.impacts else np.nan
        for c, p in enumerate(rec.pulses):
            if np.isfinite(p.amplitude):
                observables.pulse_momentum(p, rec.strain[k, c], self.p[c], unit_mass, v0)


def summary(scene: Scene, sim: Simulation, rec: RunRecord):
    """The :class:`~solver.simulate.results.RunSummary` of a run (``tensegrity run``; its JSON:
    docs/interfaces.md section 2)."""
    t_end = float(rec.times[-1] - rec.times[0])
    e0 = rec.energy[0]
    drift = float(np.max(np.abs(rec.energy - e0)) / abs(e0)) if e0 else 0.0
    net, strikers = sim.network, sim.striker()
    return RunSummary(
        scene=scene.name, model=sim.model.name, integrator=sim.integrator.name, dt=sim.dt,
        t_end=t_end, n_nodes=net.n_nodes, n_bars=net.n_bars, n_cables=net.n_cables,
        n_rigid_edges=net.n_edges, steps=int(rec.steps), steps_taken=int(rec.steps_taken),
        wall_time_s=rec.wall_time_s,
        real_time_factor=t_end / rec.wall_time_s if rec.wall_time_s > 0 else float('inf'),
        energy_drift_rel=drift / t_end if t_end > 0 else drift,
        constraint_error_rel=float(np.max(rec.constraint_error)),
        # the energy ledger: the impacts applied, the work of every command, the largest
        # |balance error| over the frames (docs/physics.md section 7.1)
        impacts=tuple(rec.impacts), energy_work_J=float(sim.energy_work()),
        energy_balance_error=float(np.max(np.abs(rec.energy_balance_error))),
        bar_contact=sim.bar_contact, contacts_met=int(sim.contacts_met),
        pulses=tuple(rec.pulses), base=tuple(support.base_summary(rec.times, rec.base_force)),
        striker=None if strikers is None else tuple(StrikerEnd(float(z), float(v))
                                                    for z, v in strikers))


@dataclass
class Point:
    """One run of :func:`simulate`: the scene with its overrides, the simulation, the record and
    the summary."""
    scene: Scene
    sim: Simulation
    record: RunRecord
    summary: RunSummary


def _at_rest(scene, overrides):
    """``(scene, sim)``: ``scene`` (a :class:`Scene` or a path) with ``overrides`` and its
    simulation at rest at t = 0, kernels compiled or loaded."""
    if not isinstance(scene, Scene):
        scene = Scene.load(scene)
    overrides = list(overrides)
    if overrides:
        scene = scene.with_overrides(overrides)
    sim = simulation_for(scene)
    try:                         # compile (or load cached) kernels outside the timed loop
        sim.advance(sim.dt)
    except SimulationDiverged:   # the run's own first step says so, with its impacts applied
        pass
    sim.reset()
    return scene, sim


def prepare(scene, overrides=()):
    """``(scene, sim)``: ``scene`` (a :class:`Scene` or a path) with ``overrides`` (``KEY=VALUE``
    strings or (key, value) pairs, applied in order) and its simulation, kernels compiled or
    loaded, the scene's impacts at t = 0 applied (the later ones of a train: :func:`simulate`)."""
    scene, sim = _at_rest(scene, overrides)
    ImpactTrain(scene.loading.impact, sim.dt).apply_due(sim)
    return scene, sim


def simulate(scene, overrides=(), setup=None):
    """Scene + overrides -> simulation -> impacts (one, or a train) while it runs to
    ``run.t_end`` -> summary: one run of ``tensegrity run`` (and of each point of a sweep or a
    fit). ``setup(stack, scene, sim)``, when given, is called before the first impact inside a
    :class:`contextlib.ExitStack` that stays open for the run; it returns ``(on_frame, progress,
    on_impact)`` for :func:`run` (any may be None). Raises
    :class:`~solver.simulate.simulation.SimulationDiverged` when the run diverges. Returns a
    :class:`Point`."""
    scene, sim = _at_rest(scene, overrides)
    train = ImpactTrain(scene.loading.impact, sim.dt)
    with contextlib.ExitStack() as stack:
        on_frame, progress, on_impact = (setup(stack, scene, sim) if setup is not None
                                         else (None, None, None))
        rec = run(sim, scene.run.t_end, scene.run.output_dt, on_frame=on_frame,
                  progress=progress, train=train, on_impact=on_impact)
    return Point(scene, sim, rec, summary(scene, sim, rec))
