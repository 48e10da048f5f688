"""The focusing design: one prestrain per column so that the pulses reach the bases on a delay law.

The bases of an array lie on the surface ``z = 0`` of a host medium of wave speed ``C``; column
``i`` has its base at ``X_i = (x_i, 0)``. Pulses that leave the bases at ``T_i = T0 - |F - X_i| /
C`` meet at the focus ``F = (X, Z)`` at ``T0``. The arrival time of a column's solitary pulse at
its base (:func:`solver.analysis.support.pulse_arrival`: the largest compression of the record,
which the scene's ``run.t_end`` must hold, and nothing larger after it) depends on its prestrain;
:func:`arrival_map` measures it with the solver itself on a grid of prestrains over the scene's
``lens`` range, for the scene and the impact velocity, and keeps it on disk. :func:`design`
picks ``T0`` in the middle of the interval where every target lies within the map's range (the
most margin on both sides), then per column the prestrain whose interpolated arrival time is
the target (the map need not be monotone: every grid segment that brackets the target is a
candidate, the first is taken; the grid is geometric, denser at small prestrain).
:func:`simulate` runs the array with those prestrains and one impact on every column at once;
the plan reports per column the prestrain, the predicted and the simulated arrival time and the
residual.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from solver.build.scene import Scene
from solver.simulate.array import simulation_for
from solver.analysis.support import pulse_arrival

CACHE_VERSION = 5         # the arrival definition of solver.analysis.support is part of the map


class LensError(ValueError):
    """A focus that cannot be designed (unreachable, bad input); the message names the column."""


def cache_dir():
    """``$TENSEGRITY_CACHE/lens`` or ``~/.cache/tensegrity_ros/lens``."""
    root = os.environ.get('TENSEGRITY_CACHE')
    return Path(root) / 'lens' if root else Path.home() / '.cache' / 'tensegrity_ros' / 'lens'


def prestrain_range(scene):
    lo, hi, n = scene.lens.prestrain_min, scene.lens.prestrain_max, scene.lens.grid
    if not lo < hi:
        raise LensError(f'lens.prestrain_min ({lo:g}) must be below lens.prestrain_max ({hi:g})')
    return lo, hi, n


def base_x(scene):
    """x (m) of each column's base (axis) in the column builder's layout."""
    return np.arange(scene.structure.n_columns) * scene.structure.column_spacing


SAMPLE_S = 1e-3          # base forces are sampled every this many seconds (whole steps)


def record_base(sim, t_end, on_frame=None, frame_dt=None):
    """Base force of every column every :data:`SAMPLE_S` (whole integrator steps) from now to
    ``t_end`` s: ``(times (n_t,), forces (n_t, n_columns))``. ``on_frame(frame)``: called with
    :meth:`~solver.simulate.simulation.Simulation.frame` now and every ``frame_dt`` s (a whole
    number of samples)."""
    t, b = [sim.t], [sim.base_force()]
    every = max(1, int(round(SAMPLE_S / sim.dt)))
    n = int(round((t_end - sim.t) / (every * sim.dt)))
    frame_every = (max(1, int(round(frame_dt / (every * sim.dt)))) if on_frame is not None
                   and frame_dt else 0)
    if frame_every:
        on_frame(sim.frame())
    for k in range(1, n + 1):
        sim.advance(every * sim.dt)
        t.append(sim.t)
        b.append(sim.base_force())
        if frame_every and k % frame_every == 0:
            on_frame(sim.frame())
    return np.array(t), np.array(b)


def simulate(scene, prestrain, v0, on_frame=None, frame_dt=None):
    """Run the array of ``scene`` with per-column ``prestrain`` (set at once) and an impact of
    ``v0`` m/s on every column at t = 0, to ``run.t_end``: ``(times, base forces, arrivals)``.
    ``on_frame``, ``frame_dt``: as :func:`record_base`."""
    sim = simulation_for(scene)
    sim.apply_prestrain(np.asarray(prestrain, dtype=np.float64))
    sim.apply_impact(v0)
    t, b = record_base(sim, scene.run.t_end, on_frame, frame_dt)
    arrivals = np.array([pulse_arrival(t, b[:, c]).time_s for c in range(b.shape[1])])
    return t, b, arrivals


@dataclass
class ArrivalMap:
    prestrain: np.ndarray
    arrival_s: np.ndarray
    cached: bool = False


def _key(scene, v0, grid):
    data = scene.data
    data['structure']['n_columns'] = 1
    for k in ('name', 'description', 'outputs'):
        data.pop(k, None)
    text = json.dumps([CACHE_VERSION, data, float(v0), [float(p) for p in grid]], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def arrival_map(scene, v0, directory=None):
    """Arrival time (s) of one column's pulse at its base against its prestrain, on the scene's
    ``lens`` grid, for an impact of ``v0`` m/s (one column per grid point, simulated side by
    side); read from / written to ``directory`` (default :func:`cache_dir`)."""
    lo, hi, n = prestrain_range(scene)
    grid = np.geomspace(lo, hi, n)
    directory = cache_dir() if directory is None else Path(directory)
    path = directory / f'{_key(scene, v0, grid)}.json'
    if path.is_file():
        try:
            d = json.loads(path.read_text())
            return ArrivalMap(np.array(d['prestrain']), np.array(d['arrival_s']), cached=True)
        except (ValueError, KeyError):
            pass                                 # a broken cache file is recomputed
    probe = scene.with_overrides([('structure.n_columns', n), ('model', 'auto')])
    _, _, arrival = simulate(probe, grid, v0)
    if not np.all(np.isfinite(arrival)):
        bad = grid[~np.isfinite(arrival)]
        raise LensError(f'lens: no pulse reaches the base by run.t_end = {scene.run.t_end:g} s '
                        f'at prestrain {bad[0]:g} (v0 = {v0:g} m/s): lengthen run.t_end')
    try:
        directory.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({'prestrain': grid.tolist(), 'arrival_s': arrival.tolist(),
                                    'v0': v0, 'scene': scene.name}))
    except OSError:
        pass                                     # no cache: computed again next time
    return ArrivalMap(grid, arrival)


def invert(amap, target):
    """Prestrain whose interpolated arrival time is ``target`` (the first bracketing grid
    segment), or the grid point of the closest arrival time; and its predicted arrival."""
    p, T = amap.prestrain, amap.arrival_s
    for k in range(len(p) - 1):
        a, b = T[k], T[k + 1]
        if min(a, b) <= target <= max(a, b):
            u = 0.0 if b == a else (target - a) / (b - a)
            return float(p[k] + u * (p[k + 1] - p[k])), float(a + u * (b - a))
    k = int(np.argmin(np.abs(T - target)))
    return float(p[k]), float(T[k])


@dataclass
class Plan:
    """A focusing design and its check. ``columns``: per column ``column``, ``x_m``,
    ``prestrain``, ``target_s`` (the delay law), ``predicted_s`` (from the map), ``simulated_s``
    and ``residual_s`` (simulated - target; filled by :func:`check`)."""
    focus: tuple
    speed: float
    v0: float
    t0: float
    columns: list
    map_prestrain: list
    map_arrival_s: list
    cached: bool = False
    extra: dict = field(default_factory=dict)

    def as_dict(self):
        return {'focus_m': list(self.focus), 'medium_speed_m_s': self.speed, 'v0': self.v0,
                't0_s': self.t0, 'columns': self.columns,
                'map': {'prestrain': self.map_prestrain, 'arrival_s': self.map_arrival_s},
                **self.extra}


def delays(xs, focus, speed):
    """``-|F - X_i| / C`` (s) of bases at ``x = xs`` (m), z = 0."""
    X, Z = focus
    return -np.hypot(np.asarray(xs) - X, Z) / speed


def design(scene, focus, speed, v0, directory=None):
    """The :class:`Plan` for focus ``(X, Z)`` m in a medium of speed ``speed`` m/s; raises
    :class:`LensError` naming a column when the prestrain range cannot reach the delay law."""
    X, Z = (float(v) for v in focus)
    if not (math.isfinite(X) and math.isfinite(Z) and Z > 0):
        raise LensError(f'lens: the focus must be finite with depth Z > 0, got ({X:g}, {Z:g})')
    if not (math.isfinite(speed) and speed > 0):
        raise LensError(f'lens: the medium speed must be a positive number, got {speed!r}')
    if scene.structure.builder != 'column' or scene.structure.n_columns < 2:
        raise LensError('lens: the scene must be an array of at least two columns')
    lo, hi, _ = prestrain_range(scene)
    amap = arrival_map(scene, v0, directory)
    xs = base_x(scene)
    d = delays(xs, (X, Z), speed)
    t_lo, t_hi = float(amap.arrival_s.min()), float(amap.arrival_s.max())
    c_lo, c_hi = t_lo - d.min(), t_hi - d.max()
    t0 = 0.5 * (c_lo + c_hi)
    target = t0 + d
    if c_lo > c_hi:
        i = int(np.argmax(np.maximum(t_lo - target, target - t_hi)))
        need = 'earlier' if target[i] < t_lo else 'later'
        raise LensError(
            f'lens: focus ({X:g}, {Z:g}) m at C = {speed:g} m/s is out of reach: column {i} '
            f'needs its pulse at the base {need} ({target[i]:.4f} s) than prestrains in '
            f'[{lo:g}, {hi:g}] give ({t_lo:.4f} .. {t_hi:.4f} s); the delay law spans '
            f'{1e3 * (d.max() - d.min()):.1f} ms across the array, the range '
            f'{1e3 * (t_hi - t_lo):.1f} ms (a deeper focus or a faster medium needs less)')
    cols = []
    for i, (x, T) in enumerate(zip(xs, target)):
        p, pred = invert(amap, T)
        cols.append({'column': i, 'x_m': float(x), 'prestrain': p, 'target_s': float(T),
                     'predicted_s': pred, 'simulated_s': None, 'residual_s': None})
    return Plan((X, Z), float(speed), float(v0), float(t0), cols, amap.prestrain.tolist(),
                amap.arrival_s.tolist(), cached=amap.cached,
                extra={'law_span_s': float(d.max() - d.min()), 'map_span_s': t_hi - t_lo})


def check(scene, plan, on_frame=None, frame_dt=None):
    """Simulate the plan (prestrains, one impact on every column) and fill in the simulated
    arrival times, residuals and the rise widths of the pulses (``rise_s``, see
    :class:`solver.analysis.support.Arrival`); returns ``(times, base forces)`` of the run.
    ``on_frame``, ``frame_dt``: as :func:`record_base`."""
    p = [c['prestrain'] for c in plan.columns]
    t, b, arrival = simulate(scene, p, plan.v0, on_frame, frame_dt)
    for i, (c, a) in enumerate(zip(plan.columns, arrival)):
        c['simulated_s'] = float(a)
        c['residual_s'] = float(a - c['target_s'])
        c['rise_s'] = pulse_arrival(t, b[:, i]).rise_s
    return t, b


def parse_focus(text):
    """``'X,Z'`` -> (X, Z) floats; LensError otherwise."""
    try:
        parts = [float(v) for v in str(text).split(',')]
    except ValueError:
        parts = []
    if len(parts) != 2:
        raise LensError(f'--focus: expected X,Z in m (two numbers), got {text!r}')
    return tuple(parts)


def load(path, sets=()):
    return Scene.load(path).with_overrides(list(sets))
