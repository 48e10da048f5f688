"""Twin runs: how fast a column's response magnifies a tiny change of its input
(docs/physics.md section 7.1; part of ``tensegrity bench --only trains``).

Two runs of one point, the second with the impact velocity changed by one part in 10^9, are
stepped side by side; the largest distance between their nodes at each output time is their
separation. Where the response is regular it grows slowly (about linearly); where it is chaotic
it grows exponentially until it saturates at the size of the motion. The rate of that growth
says how far ahead a figure can be read at all: step errors are changes of the state too, and
the response magnifies them alike.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from solver.build.scene import Scene
from solver.simulate.array import simulation_for

ROOT = Path(__file__).resolve().parents[1]
REL = 1e-9                  # the twin's impact velocity: v0 (1 + REL)
START = 0.1                 # s: the growth rate is measured from here (the pulse has formed)
SATURATED = 1e-4            # m: ... to where the separation stops growing exponentially
APART = 1e-6                # m: the separation reported as "apart" (t_apart_s)


def twins(name, v0, refine=1, rel=REL, t_end=1.0):
    """The twin runs of scene ``name`` struck at ``v0``, with every step control refined
    ``refine`` times (``solver.simulate.convergence.rung_overrides``): ``times`` (s),
    ``separation_m`` (largest node distance at each output time), ``efold_rate_per_s`` (its mean
    growth rate from ``START`` to ``SATURATED``, :func:`efold_rate`), ``t_apart_s`` (the first
    time the twins are ``APART``; None when they never are)."""
    from solver.simulate.convergence import rung_overrides
    scene = Scene.load(ROOT / 'config' / 'scenes' / f'{name}.yaml')
    ov = rung_overrides(scene, refine) + [('run.t_end', t_end)]
    sims = []
    for v in (v0, v0 * (1.0 + rel)):
        sim = simulation_for(scene.with_overrides(ov + [('loading.impact.v0', v)]))
        sim.apply_impact(v)
        sims.append(sim)
    out_dt = scene.run.output_dt
    times, sep = [], []
    for _ in range(int(round(t_end / out_dt))):
        for sim in sims:
            sim.advance(out_dt)
        a, b = (sim.frame() for sim in sims)
        times.append(a.t)
        sep.append(float(np.max(np.abs(a.positions - b.positions))))
    return {'scene': name, 'v0': v0, 'rel': rel, 'refine': refine, 'times': times,
            'separation_m': sep, 'efold_rate_per_s': efold_rate(times, sep),
            't_apart_s': next((t for t, d in zip(times, sep) if d > APART), None)}


def efold_rate(times, sep, start=START, saturated=SATURATED):
    """The mean growth rate of the separation ``sep`` at ``times``: ``ln(D(t1) / D(t0)) /
    (t1 - t0)`` of its running maximum ``D`` (the separation oscillates with the column), from
    ``t0``, the first time at or after ``start``, to ``t1``, the first time ``D`` reaches
    ``saturated`` (else the last time). None when the stretch is empty or starts at 0. A
    separation growing linearly from 0 has ``ln(t1 / t0) / (t1 - t0)``: 2.6 /s from 0.1 to 1 s."""
    t, d = np.asarray(times, dtype=float), np.maximum.accumulate(np.asarray(sep, dtype=float))
    i0 = int(np.searchsorted(t, start - 1e-12))
    if i0 >= len(t) or d[i0] <= 0.0:
        return None
    past = np.nonzero(d[i0:] >= saturated)[0]
    i1 = i0 + int(past[0]) if len(past) else len(t) - 1
    if i1 == i0:
        return None
    return math.log(d[i1] / d[i0]) / (t[i1] - t[i0])


def at(case, t):
    """The separation of ``case`` (:func:`twins`) at the output time nearest ``t``."""
    i = int(np.argmin(np.abs(np.asarray(case['times']) - t)))
    return case['separation_m'][i]


def plot(cases, path):
    """The separation of each case's twins over time, log scale."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 3.8))
    for c in cases:
        rate = c['efold_rate_per_s']
        label = f"{c['scene']}, {c['v0']:g} m/s" + (f' (e-fold {1e3 / rate:.0f} ms)'
                                                    if rate and rate > 0 else '')
        ax.semilogy(c['times'], np.maximum(c['separation_m'], 1e-16), label=label)
    ax.axhline(APART, color='0.6', lw=0.8, ls='--')
    ax.set_xlabel('time after the impact (s)')
    ax.set_ylabel('largest node distance (m)')
    k = cases[0]['refine']
    ax.set_title(f'twin runs, impact velocity 1 part in 10^{round(-math.log10(cases[0]["rel"]))}'
                 f' apart' + (f', every step control / {2 ** k}' if k else ''), fontsize=10)
    ax.legend(fontsize=7, loc='lower right')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def ensemble(name, v0, refine=0, n=16, step=1e-7, t_end=1.0, overrides=()):
    """The pulse figures of ``n`` runs struck at ``v0 (1 + (j - (n - 1) / 2) step)``, ``j = 0 ..
    n - 1``, with every step control refined ``refine`` times (and ``overrides``, ``KEY=VALUE``
    strings): ``values`` (per figure, the runs
    that found it), ``stopped`` (runs the ledger or another check stopped) and per figure its
    ``mean``, ``sem`` (standard error of the mean) and ``std`` (None below two values). Where
    a figure is a function of v0 the values agree; where the response is chaotic they scatter,
    and a figure that converges in distribution has means that agree across rungs."""
    from solver import json_safe
    from solver.simulate.convergence import FIGURES, figures_of, rung_overrides
    from solver.simulate.runner import simulate
    from solver.simulate.simulation import SimulationDiverged
    path = ROOT / 'config' / 'scenes' / f'{name}.yaml'
    ov = [f'{key}={v!r}' for key, v in rung_overrides(Scene.load(path), refine)]
    ov.append(f'run.t_end={t_end}')
    values, stopped = {f: [] for f in FIGURES}, []
    for j in range(n):
        v = v0 * (1.0 + (j - (n - 1) / 2) * step)
        try:
            summary = simulate(path, ov + list(overrides) + [f'loading.impact.v0={v!r}']
                               ).summary
            pulse = json_safe(figures_of(summary)[0]) if summary.pulses else {}
        except SimulationDiverged as exc:
            stopped.append({'v0': v, 'reason': str(exc)})
            continue
        for f in FIGURES:
            if pulse.get(f) is not None:
                values[f].append(pulse[f])
    stats = {}
    for f, vals in values.items():
        a = np.asarray(vals, dtype=float)
        std = float(a.std(ddof=1)) if len(a) > 1 else None
        stats[f] = {'mean': float(a.mean()) if len(a) else None, 'std': std,
                    'sem': std / math.sqrt(len(a)) if std is not None else None, 'n': len(a)}
    return {'scene': name, 'v0': v0, 'refine': refine, 'n': n, 'step': step,
            'values': values, 'stopped': stopped, 'stats': stats}
