"""Headless runs: a scene from its impact to ``t_end``, recorded at ``output_dt``; the summary."""
from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field

import numpy as np

from solver.analysis import observables, support
from solver.build.scene import Scene
from solver.simulate.simulation import Simulation
from solver.simulate.array import simulation_for


@dataclass
class RunRecord:
    """Everything a run recorded. ``times`` (n_t,) s, ``strain`` (n_t, n_columns, n_prisms),
    ``energy`` (n_t,) J, ``constraint_error`` (n_t,), ``wall_time_s`` of the time stepping only."""
    times: np.ndarray
    strain: np.ndarray
    energy: np.ndarray
    constraint_error: np.ndarray
    wall_time_s: float
    steps: int
    steps_taken: int
    pulses: list = field(default_factory=list)
    base_force: np.ndarray = None       # (n_t, n_columns) N, positive compressive


def frame_count(t_end, output_dt):
    """Frames :func:`run` hands out for ``t_end`` in ``output_dt`` steps (the first included)."""
    return int(round(t_end / output_dt)) + 1


def run(sim: Simulation, t_end, output_dt, on_frame=None, progress=None):
    """Advance ``sim`` to ``t_end`` in ``output_dt`` intervals, calling ``on_frame(frame)`` at each
    output time (including the first) and ``progress(n)`` with the steps of each interval."""
    ratio = output_dt / sim.dt
    if abs(ratio - round(ratio)) > 1e-6 * ratio:       # advance() takes whole steps
        raise ValueError(f'run.output_dt: {output_dt:g} s is not a whole multiple of '
                         f'integrator.dt = {sim.dt:g} s')
    n_out = frame_count(t_end, output_dt) - 1
    times, strain, energy, cerr, base = [], [], [], [], []

    def record(frame):
        times.append(frame.t)
        strain.append(frame.strain)
        energy.append(frame.energy)
        cerr.append(frame.constraint_error)
        base.append(frame.base_force)
        if on_frame is not None:
            on_frame(frame)

    record(sim.frame())
    wall = 0.0
    for _ in range(n_out):
        t0 = time.perf_counter()
        sim.advance(output_dt)
        wall += time.perf_counter() - t0
        record(sim.frame())
        if progress is not None:
            progress(1)
    rec = RunRecord(np.array(times), np.array(strain), np.array(energy), np.array(cerr), wall,
                    sim.step, sim.steps_taken, base_force=np.array(base))
    if sim.network.levels.size:
        rec.pulses = [observables.first_passage(rec.times, rec.strain[:, c], sim.network.h0)
                      for c in range(sim.network.n_columns)]
    return rec


def json_safe(value):
    """``value`` (dicts, lists, numbers, strings) with every non-finite float replaced by None, so
    that it is strict JSON (``null``): a pulse not found in a short run has NaN figures, and JSON
    has no NaN."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def summary(scene: Scene, sim: Simulation, rec: RunRecord, outputs=None):
    """The JSON summary of ``tensegrity run`` (docs/interfaces.md section 2); non-finite figures (a
    pulse not found, a run too short to time) are None."""
    t_end = float(rec.times[-1] - rec.times[0])
    e0 = rec.energy[0]
    drift = float(np.max(np.abs(rec.energy - e0)) / abs(e0)) if e0 else 0.0
    out = {
        'scene': scene.name, 'model': sim.model.name, 'integrator': sim.integrator.name,
        'dt': sim.dt, 't_end': t_end,
        'n_nodes': sim.network.n_nodes, 'n_bars': sim.network.n_bars,
        'n_cables': sim.network.n_cables, 'n_rigid_edges': sim.network.n_edges,
        'steps': int(rec.steps), 'steps_taken': int(rec.steps_taken),
        'wall_time_s': rec.wall_time_s,
        'real_time_factor': t_end / rec.wall_time_s if rec.wall_time_s > 0 else float('inf'),
        'energy_drift_rel': drift / t_end if t_end > 0 else drift,
        'constraint_error_rel': float(np.max(rec.constraint_error)),
        'pulse': rec.pulses[0].as_dict() if rec.pulses else None,
        'pulses': [p.as_dict() for p in rec.pulses],
        'base': support.base_summary(rec.times, rec.base_force),
        # loading.impact.mode: striker: each column's striker at the end (face height m, axial
        # velocity m/s, > 0 away from the column)
        'striker': None if sim.striker() is None else [
            {'z_m': float(z), 'v_m_s': float(v)} for z, v in sim.striker()],
        'outputs': dict({'mcap': None, 'rerun': None, 'plot': None}, **(outputs or {})),
    }
    return json_safe(out)


@dataclass
class Point:
    """One run of :func:`simulate`: the scene with its overrides, the simulation, the record and
    the summary."""
    scene: Scene
    sim: Simulation
    record: RunRecord
    summary: dict


def prepare(scene, overrides=()):
    """``(scene, sim)``: ``scene`` (a :class:`Scene` or a path) with ``overrides`` (``KEY=VALUE``
    strings or (key, value) pairs, applied in order) and its simulation, kernels compiled or
    loaded, the scene's impact applied."""
    if not isinstance(scene, Scene):
        scene = Scene.load(scene)
    overrides = list(overrides)
    if overrides:
        scene = scene.with_overrides(overrides)
    sim = simulation_for(scene)
    sim.advance(sim.dt)          # compile (or load cached) kernels outside the timed loop
    sim.reset()
    v0 = scene.loading.impact.v0
    if v0:
        sim.apply_impact(v0, scene.loading.impact.columns)
    return scene, sim


def simulate(scene, overrides=(), setup=None):
    """Scene + overrides -> simulation -> impact -> run to ``run.t_end`` -> summary: one run of
    ``tensegrity run`` (and of each point of a sweep or a fit). ``setup(stack, scene, sim)``, when
    given, is called after the impact inside a :class:`contextlib.ExitStack` that stays open for
    the run; it returns ``(on_frame, progress)`` for :func:`run` (either may be None).
    Raises :class:`~solver.simulate.simulation.SimulationDiverged` when the run diverges. Returns a
    :class:`Point`."""
    scene, sim = prepare(scene, overrides)
    with contextlib.ExitStack() as stack:
        on_frame, progress = setup(stack, scene, sim) if setup is not None else (None, None)
        rec = run(sim, scene.run.t_end, scene.run.output_dt, on_frame=on_frame,
                  progress=progress)
    return Point(scene, sim, rec, summary(scene, sim, rec))
