"""Shared helpers of the integrator benchmarks: scenes, timed strain histories, errors.

A run is the paper's column (``fb_column.yaml`` or ``rb_column.yaml``) hit at its free end and
recorded every ``output_dt`` s for ``t_end`` s: strain (n_out + 1, n_prisms), energy, constraint
error, and the wall time of the ``advance`` calls only (frames and set-up excluded).
"""
from __future__ import annotations

import csv
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from solver.models import family as models
from solver.build.scene import Scene
from solver.simulate.simulation import SimulationDiverged
from solver.simulate.array import simulation_for

ROOT = Path(__file__).resolve().parents[1]
COLUMNS = {'FB': ROOT / 'config' / 'scenes' / 'fb_column.yaml',
           'RB': ROOT / 'config' / 'scenes' / 'rb_column.yaml'}
DEFAULT = ('rk4_projected', 5e-4)           # the default method and step: cost ratios refer to it


def short_e(value):
    """``value`` with one decimal in scientific notation and a short exponent (8.6e-4), as the
    docs quote figures."""
    mantissa, exp = f'{value:.1e}'.split('e')
    return f'{mantissa}e{int(exp)}'


def available_models(wanted=('sym3d', 'full3d')):
    """The models of ``wanted`` this checkout provides (sym3d may be absent)."""
    return [m for m in wanted if m in models.MODELS]


def scene(column, model, method, dt, output_dt, t_end, prestrain=0.002, v0=0.1, rtol=None,
          atol=None, kinks=True, divergence=None, bars='none'):
    """The scene of one benchmark run (overrides of the shipped column scene). ``bars``: the
    integrator benches compare methods on the paper's line bars by default (``implicit_midpoint``
    refuses bar contact); the stability map's contact half passes ``hertz``."""
    over = [f'contact.bars={bars}', f'model={model}', f'integrator.method={method}',
            f'integrator.dt={dt!r}',
            f'run.output_dt={output_dt!r}', f'run.t_end={t_end!r}', f'prestrain={prestrain!r}',
            f'loading.impact.v0={v0!r}', f'integrator.land_on_kinks={str(kinks).lower()}']
    if rtol is not None:
        over += [f'integrator.rtol={rtol!r}', f'integrator.atol={atol!r}']
    for key, value in (divergence or {}).items():
        over.append(f'divergence.{key}={value}')
    return Scene.load(COLUMNS[column]).with_overrides(over)


@dataclass
class History:
    """A recorded run. ``strain`` (n_t, n_prisms) of column 0, ``energy`` (n_t,) J,
    ``constraint_error`` (n_t,); ``diverged`` is the exception text (None if the run finished),
    ``quantity`` the failed check; ``wall_s`` the time spent in ``advance``."""
    times: np.ndarray
    strain: np.ndarray
    energy: np.ndarray
    constraint_error: np.ndarray
    wall_s: float
    steps: int
    evaluations: int = 0
    diverged: str | None = None
    quantity: str | None = None
    t_fail: float = float('nan')
    extra: dict = field(default_factory=dict)


def record(sc, network=None, repeats=1, min_total_s=0.5, max_repeats=7):
    """Run ``sc`` from its impact to ``run.t_end``; the fastest of at least ``repeats`` identical
    runs gives the wall time (short runs repeat until ``min_total_s`` of stepping, at most
    ``max_repeats`` times: the least disturbed timing on a busy machine). Returns a
    :class:`History`."""
    best = None
    total = 0.0
    n = 0
    while n < max(1, repeats) or (repeats > 1 and total < min_total_s and n < max_repeats):
        hist = _record_once(sc, network)
        total += hist.wall_s
        n += 1
        if best is None or hist.wall_s < best.wall_s:
            best = hist
        if hist.diverged:
            break
    best.extra['repeats'] = n
    return best


def _record_once(sc, network):
    sim = simulation_for(sc, network=network)
    sim.advance(sim.dt)          # compile or load the kernels outside the timing
    sim.reset()
    sim.apply_impact(sc['loading.impact.v0'])
    out_dt, t_end = sc['run.output_dt'], sc['run.t_end']
    n_out = int(round(t_end / out_dt))
    frames = [sim.frame()]
    wall = 0.0
    diverged = quantity = None
    t_fail = float('nan')
    for _ in range(n_out):
        t0 = time.perf_counter()
        try:
            sim.advance(out_dt)
        except SimulationDiverged as exc:
            wall += time.perf_counter() - t0
            diverged, quantity, t_fail = str(exc), exc.quantity, exc.t
            break
        wall += time.perf_counter() - t0
        frames.append(sim.frame())
    stats = sim.integrator.stats() if hasattr(sim.integrator, 'stats') else {}
    evals = stats.get('evaluations', sim.steps_taken * sim.integrator.evaluations_per_step)
    return History(times=np.array([f.t for f in frames]),
                   strain=np.array([f.strain[0] for f in frames]),
                   energy=np.array([f.energy for f in frames]),
                   constraint_error=np.array([f.constraint_error for f in frames]),
                   wall_s=wall, steps=sim.steps_taken, evaluations=int(evals),
                   diverged=diverged, quantity=quantity, t_fail=t_fail)


def strain_error(hist, ref):
    """max over the common output times and prisms of ``|eps - eps_ref|``, divided by the peak
    ``|eps_ref|`` (dimensionless); NaN when the run did not reach the end of the reference."""
    if hist.strain.shape != ref.strain.shape:
        return float('nan')
    peak = float(np.max(np.abs(ref.strain)))
    return float(np.max(np.abs(hist.strain - ref.strain))) / peak


def energy_drift(hist):
    """max |E - E(0)| / |E(0)| over the recorded times."""
    e0 = hist.energy[0]
    return float(np.max(np.abs(hist.energy - e0)) / abs(e0))


def write_csv(path, rows):
    """Rows (list of dicts with the same keys) to ``path``; returns ``str(path)``."""
    path = Path(path)
    with path.open('w', newline='') as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f'{v:.6g}' if isinstance(v, float) else v)
                             for k, v in row.items()})
    return str(path)
