"""Pulse trains and strong impacts on the default columns (docs/physics.md section 7.1).

    python -m bench --only trains [--quick]

Writes ``trains.json`` (``rows``: one per case: impacts applied, time reached, smallest prism
height over h0, largest energy balance error, steps, wall time, status; ``convergence``: the
refinement ladder of the pulse figures of single impacts of 0.3, 1 and 2 m/s,
:func:`convergence`, drawn in ``trains_convergence.png``; ``twins``: the twin runs of each of
those impacts at the finest rung, :mod:`bench.twins`, drawn in ``trains_twins.png``;
``ensembles``: the pulse figures of 16 impacts within 1e-6 of 1 m/s at every rung,
:func:`bench.twins.ensemble`) and ``train_strain.png``
(the strain of every prism over time under a train of impacts on ``fb_column``)."""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from solver.build.scene import Scene
from solver.simulate.array import simulation_for
from solver.simulate.simulation import SimulationDiverged

ROOT = Path(__file__).resolve().parents[1]
TRAINS = [('fb_column', 0.1, 0.01, 200), ('fb_column', 0.15, 0.05, 200),
          ('rb_column', 0.1, 0.01, 200), ('rb_column', 0.15, 0.05, 200)]
SINGLES = [(name, v0) for name in ('fb_column', 'rb_column') for v0 in (0.3, 1.0, 2.0)]


def train(name, v0, period, count, t_end=None, overrides=(), strain=None):
    """Impacts of ``v0`` every ``period`` s, ``count`` of them, then to ``t_end`` (default: one
    period after the last); the row of the case. ``strain``: a list that gets each frame's
    strain (n_prisms,) of column 0."""
    scene = Scene.load(ROOT / 'config' / 'scenes' / f'{name}.yaml').with_overrides(list(overrides))
    sim = simulation_for(scene)
    out_dt = scene.run.output_dt
    t_end = count * period if t_end is None else t_end
    per = max(int(round(period / out_dt)), 1)
    row = {'scene': name, 'v0': v0, 'period_s': period, 'count': count,
           'overrides': list(overrides), 'impacts': 0}
    h_min, err, t0, status = np.inf, 0.0, time.perf_counter(), 'ok'
    try:
        for k in range(int(round(t_end / out_dt))):
            if k % per == 0 and row['impacts'] < count:
                sim.apply_impact(v0)
                row['impacts'] += 1
            sim.advance(out_dt)
            f = sim.frame()
            h_min = min(h_min, float(np.min(1.0 / (1.0 - f.strain))))
            err = max(err, abs(sim.energy_error()))
            if strain is not None:
                strain.append(f.strain[0].copy())
    except SimulationDiverged as exc:
        status = str(exc)
    row.update({'t_reached_s': sim.t, 'h_min_over_h0': h_min, 'balance_error_max': err,
                'steps': sim.step, 'steps_taken': sim.steps_taken,
                'wall_s': time.perf_counter() - t0, 'status': status})
    return row


LEVELS = 3                  # refinements of the ladder: every step control halved 1, 2, 3 times


SENSITIVITIES = (1e-9, 1e-7, 1e-5)     # the v0 changes of the finest rung's twins


def convergence(name, v0=1.0, t_end=1.0, levels=LEVELS, perturbations=3,
                sensitivities=SENSITIVITIES):
    """How well the pulse figures at ``v0`` are determined, as a refinement ladder: the point
    run with every step control refined ``k`` times (``solver.simulate.convergence.
    rung_overrides``: ``dt / 2^k``, ``contact.resolution x 2^k``) for
    ``k = 0 .. levels``, and the relative change of each figure between consecutive rungs
    (``steps``: ``solver.simulate.convergence.relative_change``, the measure of ``tensegrity run
    --convergence``); converged figures show changes that shrink down the ladder. Also the
    largest change under perturbations of v0 by 1e-9, 2e-9, ... at the scene's own steps
    (``conditioning``: how far the response at those steps carries a change of the input), and
    the change under v0 (1 + rel) at the finest rung's steps for each ``rel`` of
    ``sensitivities`` (``sensitivity_finest``; ``conditioning_finest`` is its 1e-9 entry)."""
    from solver import json_safe
    from solver.simulate.convergence import FIGURES, figures_of, relative_change, rung_overrides
    from solver.simulate.runner import simulate
    path = ROOT / 'config' / 'scenes' / f'{name}.yaml'
    base = [f'loading.impact.v0={v0}', f'run.t_end={t_end}']

    def run(overrides):
        t0 = time.perf_counter()
        point = simulate(path, overrides)
        s = point.summary
        figures = figures_of(s)
        return {'figures': json_safe(figures[0] if figures else {k: None for k in FIGURES}),
                'balance_error': s.energy_balance_error,
                'steps_taken': s.steps_taken,
                'dt': point.scene.integrator.dt, 'resolution': point.scene.contact.resolution,
                'wall_s': time.perf_counter() - t0}

    scene = Scene.load(path).with_overrides(base)
    ladder = []
    for k in range(levels + 1):
        finest = [f'{key}={v}' for key, v in rung_overrides(scene, k)]
        ladder.append(run(base + finest))

    def change(a, b):
        return {k: relative_change(a[k], b[k]) for k in FIGURES}

    spread = {k: 0.0 for k in FIGURES}
    for j in range(1, perturbations + 1):
        moved = run([f'loading.impact.v0={v0 * (1 + j * 1e-9)}', f'run.t_end={t_end}'])
        for k, c in change(moved['figures'], ladder[0]['figures']).items():
            spread[k] = None if c is None or spread[k] is None else max(spread[k], c)
    sens = []
    for rel in sensitivities:
        moved = run([f'loading.impact.v0={v0 * (1 + rel)}', f'run.t_end={t_end}'] + finest)
        sens.append({'rel': rel, 'changes': change(moved['figures'], ladder[-1]['figures'])})
    return {'scene': name, 'v0': v0, 't_end': t_end, 'ladder': ladder,
            'steps': [change(a['figures'], b['figures']) for a, b in zip(ladder, ladder[1:])],
            'conditioning': spread,
            'conditioning_finest': next((e['changes'] for e in sens if e['rel'] == 1e-9), None),
            'sensitivity_finest': sens}


def _pct(x):
    return 'n/a' if x is None else f'{x:.2%}'


def _short_pct(x):
    """A relative change in percent, two significant digits (``∞``: found in one run only)."""
    if x is None:
        return 'n/a'
    if math.isinf(x):
        return '∞'
    if x == 0 or 100 * x < 0.005:
        return '0'
    return f'{100 * x:.2g}' if 100 * x >= 0.1 else f'{100 * x:.2f}'.rstrip('0')


# the column names of the pulse figures (solver.simulate.convergence.FIGURES) in the tables
NAMES = {'amplitude': 'amplitude', 'amplitude_median': 'median amplitude',
         'speed_m_s': 'speed (window fit)', 'speed_snapshot_m_s': 'snapshot speed',
         'front_speed_m_s': 'front speed', 'front_amplitude': 'front amplitude'}


def _header(first):
    from solver.simulate.convergence import FIGURES
    cols = list(first) + [NAMES[f] for f in FIGURES]
    return ['| ' + ' | '.join(cols) + ' |', '|' + '---|' * len(cols)]


def convergence_table(conv):
    """The markdown table of docs/physics.md section 7.1 from the ``convergence`` entries of
    ``trains.json``: per case and figure the change at each rung, then under v0 +1e-9 at the
    scene's steps and at the finest rung's, in %."""
    from solver.simulate.convergence import FIGURES
    lines = _header(['scene, v0'])
    for c in conv:
        cells = []
        for f in FIGURES:
            steps = [st[f] for st in c['steps']]
            fine = c['conditioning_finest'][f]
            if all(x is None for x in steps + [c['conditioning'][f], fine]):
                cells.append('n/a')
            else:
                cells.append(' / '.join(_short_pct(x) for x in steps) + '; '
                             + _short_pct(c['conditioning'][f]) + ', ' + _short_pct(fine))
        lines.append(f"| `{c['scene']}`, {c['v0']:g} m/s | " + ' | '.join(cells) + ' |')
    return lines


def sensitivity_table(conv, twin_cases):
    """The second markdown table of docs/physics.md section 7.1: per case the distance of the
    twin runs at 0.5 and 1 s and its mean e-folding time (:mod:`bench.twins`), and per figure
    its change at the finest rung under v0 (1 + 1e-9 / 1e-7 / 1e-5), in %."""
    from solver.simulate.convergence import FIGURES
    from bench.twins import at
    lines = _header(['scene, v0', 'twins apart at 0.5 s / 1 s', 'e-fold'])
    for c, tw in zip(conv, twin_cases):
        rate = tw['efold_rate_per_s']
        cells = [f"{at(tw, 0.5):.1e} / {at(tw, 1.0):.1e} m",
                 f'{1e3 / rate:.0f} ms' if rate and rate > 0 else 'none']
        for f in FIGURES:
            moved = [e['changes'][f] for e in c['sensitivity_finest']]
            cells.append('n/a' if all(x is None for x in moved)
                         else ' / '.join(_short_pct(x) for x in moved))
        lines.append(f"| `{c['scene']}`, {c['v0']:g} m/s | " + ' | '.join(cells) + ' |')
    return lines


ENSEMBLES = [('fb_column', 1.0), ('rb_column', 1.0)]   # bench.twins.ensemble at every rung


def ensemble_table(ensembles):
    """The third markdown table of docs/physics.md section 7.1: per case and rung the mean and
    standard error of the amplitude, the window-fit speed and the front speed over the
    ensemble's runs, and how many runs the checks stopped (:func:`bench.twins.ensemble`)."""
    lines = ['| scene, v0 | steps | runs stopped | amplitude | speed (window fit), m/s '
             '| front speed, m/s |', '|---|---|---|---|---|---|']

    def cell(st, digits, sem_format=None):
        if st['mean'] is None:
            return 'n/a'
        sem = '' if st['sem'] is None else f" ± {st['sem']:{sem_format or f'.{digits}f'}}"
        return f"{st['mean']:.{digits}f}{sem} ({st['n']})"
    for e in ensembles:
        steps = 'scene' if e['refine'] == 0 else f"/{2 ** e['refine']}"
        lines.append(f"| `{e['scene']}`, {e['v0']:g} m/s | {steps} | {len(e['stopped'])} of "
                     f"{e['n']} | {cell(e['stats']['amplitude'], 4)} | "
                     f"{cell(e['stats']['speed_m_s'], 4)} | "
                     f"{cell(e['stats']['front_speed_m_s'], 6, '.0e')} |")
    return lines


def plot(strain, out_dt, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    s = np.array(strain)
    fig, ax = plt.subplots(figsize=(7, 3.6))
    # clipped at -0.3: the pulses show; prisms pressed flat (strain -1 and below) saturate
    im = ax.imshow(s.T, aspect='auto', origin='lower', cmap='magma',
                   extent=(0, len(s) * out_dt, -0.5, s.shape[1] - 0.5), vmin=-0.3, vmax=0)
    ax.set_xlabel('time (s)')
    ax.set_ylabel('prism (0: clamped base)')
    ax.set_title('fb_column, 10 impacts of 0.1 m/s every 50 ms: strain')
    fig.colorbar(im, ax=ax, label='strain (h - h0) / h, clipped at -0.3')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_convergence(conv, path):
    """The refinement ladder of ``conv`` (``convergence`` entries): each figure at each rung over
    its value at the finest rung, one line per case; a figure that settles runs into 1."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from solver.simulate.convergence import FIGURES
    names = dict(NAMES, amplitude='amplitude at 0.5 s',
                 speed_snapshot_m_s='snapshot speed at 0.5 s',
                 front_speed_m_s='front speed, prisms 5-20',
                 front_amplitude='front peak, prism 20')
    fig, axes = plt.subplots(2, (len(FIGURES) + 1) // 2, figsize=(11, 6), sharex=True)
    axes = axes.ravel()
    colors = plt.rcParams['axes.prop_cycle'].by_key()['color']
    for ax, f in zip(axes, FIGURES):
        for i, c in enumerate(conv):
            values = [r['figures'][f] for r in c['ladder']]
            last = values[-1]
            if last is None or not last:
                continue
            y = [np.nan if v is None else v / last for v in values]
            ax.plot(range(len(y)), y, 'o-', ms=3, color=colors[i % len(colors)])
        ax.axhspan(0.99, 1.01, color='0.85', zorder=0)
        ax.set_title(names.get(f, f), fontsize=10)
        ax.set_xticks(range(len(conv[0]['ladder'])))
        ax.set_xticklabels(['scene'] + [f'/{2 ** k}' for k in range(1, len(conv[0]['ladder']))])
    for ax in axes[-(len(axes) // 2):]:
        ax.set_xlabel('every step control')
    for ax in axes[::len(axes) // 2]:
        ax.set_ylabel('over the finest rung (band: 1 %)')
    handles = [plt.Line2D([], [], marker='o', ms=3, color=colors[i % len(colors)])
               for i in range(len(conv))]
    fig.legend(handles, [f"{c['scene']}, {c['v0']:g} m/s" for c in conv], fontsize=8,
               loc='center right')
    fig.tight_layout(rect=(0, 0, 0.86, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(out, quick=False, log=print):
    out = Path(out)
    rows = []
    for name, v0, period, count in TRAINS:
        row = train(name, v0, period, 20 if quick else count)
        log(f'{name} {count} x {v0} m/s every {period * 1e3:g} ms: {row["status"]}, '
            f'{row["impacts"]} impacts, h_min/h0 {row["h_min_over_h0"]:.3f}, balance error '
            f'{row["balance_error_max"]:.2e}, {row["wall_s"]:.1f} s')
        rows.append(row)
    for name, v0 in SINGLES:
        row = train(name, v0, 1.0, 1, t_end=0.2 if quick else 1.0)
        log(f'{name} one impact of {v0} m/s, 1 s: {row["status"]}, h_min/h0 '
            f'{row["h_min_over_h0"]:.3f}, balance error {row["balance_error_max"]:.2e}')
        rows.append(row)
    conv = [] if quick else [convergence(name, v0) for name in ('fb_column', 'rb_column')
                             for v0 in (0.3, 1.0, 2.0)]
    for c in conv:
        log(f'{c["scene"]} at {c["v0"]} m/s, change per refinement (dt/2, resolution x2) and '
            f'under v0 +1e-9 (scene steps, finest): ' + '; '.join(
                f'{k} ' + ' / '.join(_pct(st[k]) for st in c['steps'])
                + f', {_pct(c["conditioning"][k])}, {_pct(c["conditioning_finest"][k])}'
                for k in c['conditioning']))
    from bench import twins
    twin_cases = [] if quick else [twins.twins(c['scene'], c['v0'], refine=LEVELS)
                                  for c in conv]
    for tw in twin_cases:
        log(f"{tw['scene']} at {tw['v0']} m/s, twins 1e-9 apart: e-fold rate "
            f"{tw['efold_rate_per_s']} /s, 1 um apart at {tw['t_apart_s']} s, "
            f"{tw['separation_m'][-1]:.2e} m at the end")
    ensembles = [] if quick else [twins.ensemble(name, v0, k) for name, v0 in ENSEMBLES
                                  for k in range(LEVELS + 1)]
    if conv:
        log('\n'.join(convergence_table(conv)))
        log('\n'.join(ensemble_table(ensembles)))
        log('\n'.join(sensitivity_table(conv, twin_cases)))
        plot_convergence(conv, out / 'trains_convergence.png')
        twins.plot(twin_cases, out / 'trains_twins.png')
    strain = []
    train('fb_column', 0.1, 0.05, 10, t_end=1.2, strain=strain)
    plot(strain, 0.005, out / 'train_strain.png')
    path = out / 'trains.json'
    path.write_text(json.dumps({'rows': rows, 'convergence': conv, 'twins': twin_cases,
                                'ensembles': ensembles}, indent=1, default=float))
    return [path, out / 'train_strain.png'] + ([out / 'trains_convergence.png',
                                                out / 'trains_twins.png'] if conv else [])
