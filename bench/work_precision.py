"""Work-precision chart: error of the strain history against cost per simulated second.

For each of the paper's columns (FB, RB; v0 = 0.1 m/s, prestrain 0.002), each model (sym3d,
full3d; chain1d, which has its own integrator, as a model-error point) and each method over a range
of dt (tolerances for ``dopri54_projected``), the run is recorded every ``OUTPUT_DT`` s over a
window of ``T_END`` s. Its error is the largest difference of the strain history (every prism,
every output time) from a converged reference, relative to the reference's peak strain. Its cost
is the wall time of the stepping per simulated second (top row) and the number of force
evaluations per simulated second (bottom row: machine-independent, but blind to the cost of
projections and kink prediction).

Reference: ``rk4_projected`` (sym3d) at dt = 1.5625e-5 s. It is shown converged by runs written
next to it (``work_precision_reference.csv``): the same method at twice the step (the difference
is about 15x the reference's own error for a 4th-order method), the same step on ``full3d`` (the
models agree to round-off), and an independent method, ``dopri54_projected`` at rtol 1e-12 (whose
per-step tolerance acts on absolute positions, about 0.3 m, so it agrees only to its tolerance).
The first two bound the "reference spread" shaded on the chart; errors below it are not resolved.
Timings: the fastest of 3 to 7 runs; ``cost_vs_default`` = wall time divided by that of
``rk4_projected`` at dt = 5e-4 s on the same column and model, measured in the same process (the
machine may be busy: read ratios).

Stiff scenes (:data:`bench.stability.STIFF_SCENES`): the same error and cost for the explicit
methods and ``implicit_midpoint`` (where the scene admits it: not with a striker,
:func:`bench.stability.stiff_methods`) over a window of ``STIFF_T_END`` s at v0 = 0.1 m/s,
against an ``rk4_projected`` reference at ``STIFF_REF_DT``, checked against an independent method
(``implicit_midpoint`` at ``STIFF_CHECK_DT``, or ``dopri54_projected`` at rtol 1e-10 where the
implicit method is refused) and against ``rk4_projected`` at twice its step, into
``work_precision_stiff.csv``, ``work_precision_stiff_reference.csv`` and
``work_precision_stiff.png``. The stiff scenes have no converged strain history (their stiff base
cables switch slack/taut on nanometre stretches), so the chart's second row and
``work_precision_stiff_fastest.csv`` rank by the energy drift, which needs no reference.
``tensegrity bench --only stiff`` (these and the stiff scenes of :mod:`bench.stability`) takes
about 80 s on a shared 2-core machine, ``--quick`` about 12 s.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from . import common

OUTPUT_DT = 8e-3
REF_DT = 1.5625e-5
T_END = 0.4
QUICK_T_END = 0.1
LEVELS = (1e-2, 1e-4, 1e-6, 1e-8)         # accuracy levels of the "fastest method" table
STIFF_T_END = 0.128
STIFF_OUTPUT_DT = 6.4e-3
STIFF_REF_DT = 2.5e-5
STIFF_CHECK_DT = 5e-5


def _grid(quick):
    """(label, method, kinks, [(dt, rtol)...]) series."""
    halvings = [8e-3 / 2 ** k for k in range(9)]              # 8e-3 ... 3.125e-5 (divide 8e-3)
    rattle = [4e-3 / 2 ** k for k in range(9)]                # 4e-3 ... 1.5625e-5
    tols = [10.0 ** -k for k in range(3, 12)]                 # 1e-3 ... 1e-11
    if quick:
        halvings, rattle, tols = halvings[1:8:3], rattle[1:8:3], tols[0:9:4]
    return [
        ('rk4_projected', 'rk4_projected', True, [(dt, None) for dt in halvings]),
        ('rk4_projected (no kink landing)', 'rk4_projected', False,
         [(dt, None) for dt in halvings]),
        ('rk4', 'rk4', True, [(dt, None) for dt in halvings]),
        ('rattle', 'rattle', True, [(dt, None) for dt in rattle]),
        ('dopri54_projected', 'dopri54_projected', True, [(OUTPUT_DT, t) for t in tols]),
    ]


def references(column, t_end, log):
    """The reference history and {check: relative strain difference from it}; the spread of the
    chart is the largest of the checks marked ``bound``."""
    model = common.available_models()[0]
    ref = common.record(common.scene(column, model, 'rk4_projected', REF_DT, OUTPUT_DT, t_end))
    if ref.diverged:
        raise RuntimeError(f'reference diverged: {ref.diverged}')
    checks = {
        f'bound: rk4_projected dt={2 * REF_DT:g} {model}': common.scene(
            column, model, 'rk4_projected', 2 * REF_DT, OUTPUT_DT, t_end),
        'independent: dopri54_projected rtol=1e-12': common.scene(
            column, model, 'dopri54_projected', 1e-3, OUTPUT_DT, t_end, rtol=1e-12, atol=1e-15),
    }
    if 'full3d' in common.available_models() and model != 'full3d':
        checks[f'bound: rk4_projected dt={REF_DT:g} full3d'] = common.scene(
            column, 'full3d', 'rk4_projected', REF_DT, OUTPUT_DT, t_end)
    spread = {}
    for name, sc in checks.items():
        spread[name] = common.strain_error(common.record(sc), ref)
        log(f'  {column} reference vs {name}: relative strain difference {spread[name]:.2e}')
    return ref, spread


def run(out, quick=False, log=print):
    """Measure every series; returns (rows, spreads)."""
    t_end = QUICK_T_END if quick else T_END
    repeats = 1 if quick else 3
    model_list = common.available_models(('sym3d',) if quick else ('sym3d', 'full3d'))
    chain = common.available_models(('chain1d',))
    rows, spreads = [], {}
    for column in common.COLUMNS:
        log(f'work-precision: {column} column, window {t_end:g} s, models {model_list + chain}')
        ref, spread = references(column, t_end, log)
        spreads[column] = spread
        for model in model_list + chain:
            base = common.record(common.scene(column, model, *common.DEFAULT, OUTPUT_DT, t_end),
                                 repeats=repeats)
            series = _grid(quick) if model != 'chain1d' else [     # its own Verlet integrator
                ('chain1d (own integrator)', 'rk4_projected', True,
                 [(1e-3, None), (2.5e-4, None)])]
            for label, method, kinks, points in series:
                for dt, rtol in points:
                    sc = common.scene(column, model, method, dt, OUTPUT_DT, t_end, rtol=rtol,
                                      atol=None if rtol is None else rtol * 1e-3, kinks=kinks)
                    h = common.record(sc, repeats=repeats)
                    err = common.strain_error(h, ref) if not h.diverged else float('nan')
                    rows.append({
                        'column': column, 'model': model, 'method': label, 'dt': dt,
                        'rtol': rtol if rtol is not None else '', 't_end': t_end,
                        'steps': h.steps, 'evaluations': h.evaluations,
                        'evals_per_sim_s': (h.evaluations / t_end if model != 'chain1d'
                                            else float('nan')),    # chain1d: own sub-steps
                        'repeats': h.extra['repeats'],
                        'wall_s': h.wall_s,
                        'wall_per_sim_s': h.wall_s / t_end,
                        'cost_vs_default': h.wall_s / base.wall_s,
                        'strain_error_rel': err,
                        'energy_drift_rel': common.energy_drift(h) if not h.diverged else
                        float('nan'),
                        'constraint_error': float(np.max(h.constraint_error)),
                        'status': 'ok' if not h.diverged else f'diverged: {h.quantity}'})
                    log(f'  {column} {model:6s} {label:32s} dt={dt:.3g} rtol={rtol or "":<6} '
                        f'err={err:.2e} wall/sim-s={h.wall_s / t_end:.3g} s '
                        f'{"" if not h.diverged else "DIVERGED " + h.quantity}')
    return rows, spreads


def _stiff_grid(quick, methods=None):
    """(label, method, kinks, [(dt, rtol)...]) series of the stiff scenes, for the methods of
    ``methods`` (None: all)."""
    imp = [6.4e-3 / 2 ** k for k in range(0, 8)]             # 6.4 ms ... 50 us
    rk4 = [4e-4 / 2 ** k for k in range(0, 4)]               # 0.4 ms ... 50 us
    tols = [10.0 ** -k for k in range(4, 11, 2)]
    if quick:
        imp, rk4, tols = imp[1::3], rk4[1:2], tols[:1]
    series = [('rk4_projected', 'rk4_projected', True, [(dt, None) for dt in rk4]),
              ('rattle', 'rattle', True, [(dt, None) for dt in rk4]),
              ('dopri54_projected', 'dopri54_projected', True, [(1e-3, t) for t in tols]),
              ('implicit_midpoint', 'implicit_midpoint', True, [(dt, None) for dt in imp])]
    return [s for s in series if methods is None or s[1] in methods]


def stiff_run(quick=False, log=print):
    """Error against cost on the stiff scenes; returns (rows, spreads)."""
    from .stability import LOOSE, STIFF_SCENES, stiff_methods
    model = common.available_models()[0]
    t_end = STIFF_T_END / 4 if quick else STIFF_T_END
    scenes = list(STIFF_SCENES.items())
    scenes = [scenes[0], scenes[-1]] if quick else scenes
    rows, spreads = [], {}
    for name, (column, over) in scenes:
        def sc(method, dt, rtol=None, kinks=True):
            # the loose limits of the stability map: the chart measures each run's energy
            # drift itself (down from 1e-3), which the default ledger (1e-4) would stop
            return common.scene(column, model, method, dt, STIFF_OUTPUT_DT, t_end, rtol=rtol,
                                atol=None if rtol is None else rtol * 1e-3, kinks=kinks,
                                divergence=LOOSE).with_overrides(list(over))
        methods = stiff_methods(over)
        ref = common.record(sc('rk4_projected', STIFF_REF_DT))
        if ref.diverged:
            raise RuntimeError(f'stiff reference diverged: {ref.diverged}')
        checks = {f'bound: rk4_projected dt={2 * STIFF_REF_DT:g}':
                  sc('rk4_projected', 2 * STIFF_REF_DT)}
        if 'implicit_midpoint' in methods:
            checks[f'independent: implicit_midpoint dt={STIFF_CHECK_DT:g}'] = sc(
                'implicit_midpoint', STIFF_CHECK_DT)
        else:
            checks['independent: dopri54_projected rtol=1e-10'] = sc('dopri54_projected', 1e-3,
                                                                     1e-10)
        spreads[name] = {}
        for key, check in checks.items():
            spreads[name][key] = common.strain_error(common.record(check), ref)
            log(f'  {name}: reference vs {key}: relative strain difference '
                f'{spreads[name][key]:.2e}')
        for label, method, kinks, points in _stiff_grid(quick, methods):
            for dt, rtol in points:
                h = common.record(sc(method, dt, rtol, kinks), repeats=1 if quick else 3)
                err = common.strain_error(h, ref) if not h.diverged else float('nan')
                rows.append({'scene': name, 'column': column, 'model': model, 'method': label,
                             'dt': dt, 'rtol': rtol if rtol is not None else '',
                             't_end': t_end, 'steps': h.steps, 'evaluations': h.evaluations,
                             'evals_per_sim_s': h.evaluations / t_end, 'wall_s': h.wall_s,
                             'wall_per_sim_s': h.wall_s / t_end, 'strain_error_rel': err,
                             'energy_drift_rel': (common.energy_drift(h) if not h.diverged
                                                  else float('nan')),
                             'constraint_error': float(np.max(h.constraint_error)),
                             'status': 'ok' if not h.diverged else f'diverged: {h.quantity}'})
                log(f'  {name} {label:18s} dt={dt:.3g} rtol={rtol or "":<6} err={err:.2e} '
                    f'wall/sim-s={h.wall_s / t_end:.3g} s steps={h.steps} '
                    f'{"" if not h.diverged else "DIVERGED " + h.quantity}')
    return rows, spreads


ENERGY_LEVELS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)   # energy-drift levels, stiff scenes


def stiff_fastest(rows, levels=ENERGY_LEVELS):
    """Per stiff scene and energy-drift level: the cheapest run (wall time) that finished with
    ``energy_drift_rel`` at most the level, its runner-up method and their cost ratio. The energy
    drift needs no reference, which the stiff scenes lack (their strain histories do not
    converge). Returns a list of dicts."""
    out = []
    for name in dict.fromkeys(r['scene'] for r in rows):
        sel = [r for r in rows if r['scene'] == name and r['status'] == 'ok'
               and np.isfinite(r['energy_drift_rel'])]
        for level in levels:
            best = {}
            for r in sel:
                if r['energy_drift_rel'] <= level and (
                        r['method'] not in best or r['wall_s'] < best[r['method']]['wall_s']):
                    best[r['method']] = r
            ranked = sorted(best.values(), key=lambda r: r['wall_s'])
            b = ranked[0] if ranked else None
            second = ranked[1] if len(ranked) > 1 else None
            out.append({'scene': name, 'energy_level': level,
                        'method': b['method'] if b else 'none', 'dt': b['dt'] if b else '',
                        'rtol': b['rtol'] if b else '',
                        'wall_per_sim_s': b['wall_per_sim_s'] if b else float('nan'),
                        'energy_drift_rel': b['energy_drift_rel'] if b else float('nan'),
                        'runner_up': second['method'] if second else '',
                        'runner_up_ratio': (second['wall_s'] / b['wall_s'] if second
                                            else float('nan'))})
    return out


def load_stiff_rows(path):
    """The rows of a ``work_precision_stiff.csv`` with numbers parsed (to redraw the chart)."""
    import csv
    text = ('scene', 'column', 'model', 'method', 'status', 'rtol')
    rows = []
    with open(path) as fh:
        for r in csv.DictReader(fh):
            rows.append({k: (v if k in text or v == '' else float(v)) for k, v in r.items()})
            if rows[-1]['rtol'] != '':
                rows[-1]['rtol'] = float(rows[-1]['rtol'])
    return rows


def stiff_plot(rows, path, spreads=None):
    """Wall time per simulated second against the strain-history error (top) and against the
    energy drift (bottom), per stiff scene; ``spreads`` ({scene: {check: difference}}) shades
    the reference spread (``bound`` checks) and marks the independent check by a dashed line."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    scenes = list(dict.fromkeys(r['scene'] for r in rows))
    fig, axes = plt.subplots(2, len(scenes), figsize=(6.0 * len(scenes), 9), squeeze=False,
                             constrained_layout=True)
    colours = {'rk4_projected': 'C0', 'rattle': 'C2', 'dopri54_projected': 'C1',
               'implicit_midpoint': 'C4'}
    for i, (key, xlabel) in enumerate((
            ('strain_error_rel', 'strain-history error / peak strain (reference not converged)'),
            ('energy_drift_rel', 'energy drift, max |E - E0| / E0 (no reference needed)'))):
        for ax, name in zip(axes[i], scenes):
            xs = []
            for label in colours:
                sel = sorted((r for r in rows if (r['scene'], r['method']) == (name, label)
                              and r['status'] == 'ok' and np.isfinite(r[key])),
                             key=lambda r: r[key])
                if sel:
                    xs += [max(r[key], 1e-16) for r in sel]
                    ax.loglog([max(r[key], 1e-16) for r in sel],
                              [r['wall_per_sim_s'] for r in sel], marker='o', ms=3.5,
                              color=colours[label], label=label)
            if i == 0:
                checks = (spreads or {}).get(name, {})
                floor = max((v for k, v in checks.items() if k.startswith('bound')),
                            default=np.nan)
                if np.isfinite(floor):
                    ax.axvspan(1e-16, max(floor, 1e-16), color='0.85', zorder=0,
                               label='reference spread (rk4_projected at 2x its step)')
                    xs.append(floor)
                for k, v in checks.items():
                    if k.startswith('independent') and np.isfinite(v):
                        ax.axvline(v, color='0.4', ls='--', lw=1,
                                   label=f'reference vs {k.split(": ", 1)[1]}')
                if xs:
                    ax.set_xlim(min(xs) / 3, max(xs) * 3)
            failed = sorted({f'{r["method"]} {r["dt"] * 1e3:g} ms' for r in rows
                             if r['scene'] == name and r['status'] != 'ok'})
            ax.set_title(f'{name}\ndiverged: {", ".join(failed) or "none"}', fontsize=8)
            ax.set_xlabel(xlabel)
            ax.set_ylabel('wall time per simulated second, s')
            ax.grid(True, which='both', alpha=0.3)
            ax.legend(fontsize=7)
    fig.suptitle('Work-precision on stiff scenes (v0 = 0.1 m/s, sym3d, 0.128 s; '
                 'implicit_midpoint refuses the striker scene)')
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


def stiff_main(out, quick=False, log=print):
    """The stiff scenes only: ``work_precision_stiff.csv``, ``work_precision_stiff.png``."""
    out = Path(out)
    tag = '_quick' if quick else ''
    rows, spreads = stiff_run(quick, log)
    ref_rows = [{'scene': n, 'check': k, 'strain_difference_rel': v}
                for n, d in spreads.items() for k, v in d.items()]
    best = stiff_fastest(rows)
    for b in best:
        log(f'  fastest at energy drift <= {b["energy_level"]:g}: {b["scene"]}: {b["method"]} '
            f'(dt {b["dt"]}, rtol {b["rtol"]}), {b["wall_per_sim_s"]:.3g} s per simulated s, '
            f'runner-up {b["runner_up"]} x{b["runner_up_ratio"]:.2f}')
    return [common.write_csv(out / f'work_precision_stiff{tag}.csv', rows),
            common.write_csv(out / f'work_precision_stiff_reference{tag}.csv', ref_rows),
            common.write_csv(out / f'work_precision_stiff_fastest{tag}.csv', best),
            stiff_plot(rows, out / f'work_precision_stiff{tag}.png', spreads)]


def fastest(rows, levels=LEVELS, cost='wall_s', exclude=()):
    """Per column and model and accuracy level: the cheapest run (by ``cost``: ``wall_s`` or
    ``evaluations``) whose error is at most the level, among methods not in ``exclude``; with the
    runner-up method and its cost ratio. Returns a list of dicts."""
    out = []
    keys = sorted({(r['column'], r['model']) for r in rows if r['model'] != 'chain1d'})
    for column, model in keys:
        sel = [r for r in rows if (r['column'], r['model']) == (column, model)
               and r['status'] == 'ok' and np.isfinite(r['strain_error_rel'])
               and r['method'] not in exclude]
        for level in levels:
            ok = [r for r in sel if r['strain_error_rel'] <= level]
            if not ok:
                out.append({'column': column, 'model': model, 'level': level, 'method': 'none',
                            'dt': '', 'rtol': '', 'wall_per_sim_s': float('nan'),
                            'evals_per_sim_s': float('nan'), 'cost_vs_default': float('nan'),
                            'runner_up': '', 'runner_up_ratio': float('nan')})
                continue
            best_per_method = {}
            for r in ok:
                m = r['method']
                if m not in best_per_method or r[cost] < best_per_method[m][cost]:
                    best_per_method[m] = r
            ranked = sorted(best_per_method.values(), key=lambda r: r[cost])
            b = ranked[0]
            second = ranked[1] if len(ranked) > 1 else None
            out.append({'column': column, 'model': model, 'level': level, 'method': b['method'],
                        'dt': b['dt'], 'rtol': b['rtol'], 'wall_per_sim_s': b['wall_per_sim_s'],
                        'evals_per_sim_s': b.get('evals_per_sim_s', float('nan')),
                        'cost_vs_default': b['cost_vs_default'],
                        'runner_up': second['method'] if second else '',
                        'runner_up_ratio': second[cost] / b[cost] if second else float('nan')})
    return out


RANKINGS = (('wall time', 'wall_s', ()),
            ('wall time, constraint-keeping methods (not rk4)', 'wall_s', ('rk4',)),
            ('force evaluations', 'evaluations', ()))


def fastest_table(rows):
    """:func:`fastest` under each of :data:`RANKINGS`, one ``ranking`` column added."""
    return [dict(ranking=name, **b) for name, cost, exclude in RANKINGS
            for b in fastest(rows, cost=cost, exclude=exclude)]


def load_rows(path):
    """The rows of a ``work_precision.csv`` with numbers parsed (to rebuild tables and charts)."""
    import csv
    rows = []
    with open(path) as fh:
        for r in csv.DictReader(fh):
            for key, value in r.items():
                if key not in ('column', 'model', 'method', 'status', 'rtol') and value != '':
                    r[key] = float(value)
            r['rtol'] = float(r['rtol']) if r['rtol'] else ''
            rows.append(r)
    return rows


def plot(rows, spreads, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    columns = list(common.COLUMNS)
    fig, axes = plt.subplots(2, len(columns), figsize=(13, 10), constrained_layout=True)
    colours = {'rk4_projected': 'C0', 'rk4_projected (no kink landing)': 'C9', 'rk4': 'C3',
               'rattle': 'C2', 'dopri54_projected': 'C1', 'chain1d (own integrator)': 'C7'}
    styles = {'sym3d': '-', 'full3d': '--', 'chain1d': ':'}
    cost = (('wall_per_sim_s', 'wall time per simulated second, s'),
            ('evals_per_sim_s', 'force evaluations per simulated second'))
    for i, (key, ylabel) in enumerate(cost):
        for ax, column in zip(axes[i], columns):
            for (label, model) in sorted({(r['method'], r['model']) for r in rows
                                          if r['column'] == column}):
                sel = [r for r in rows if (r['column'], r['method'], r['model']) ==
                       (column, label, model) and r['status'] == 'ok'
                       and np.isfinite(r['strain_error_rel'])]
                if not sel:
                    continue
                sel.sort(key=lambda r: r['strain_error_rel'])
                ax.loglog([max(r['strain_error_rel'], 1e-16) for r in sel],
                          [r[key] for r in sel],
                          styles.get(model, ':'), marker='o', ms=3.5,
                          color=colours.get(label, 'k'), label=f'{label}, {model}')
            floor = max((v for k, v in spreads.get(column, {}).items()
                         if k.startswith('bound')), default=np.nan)
            if np.isfinite(floor):
                ax.axvspan(1e-13, max(floor, 1e-13), color='0.85', zorder=0,
                           label='reference spread')
            ax.set_xlim(left=1e-13)
            ax.set_title(f'{column} column (v0 = 0.1 m/s, p = 0.002)')
            ax.set_xlabel('strain-history error / peak strain (vs converged reference)')
            ax.set_ylabel(ylabel)
            ax.grid(True, which='both', alpha=0.3)
            if i == 0:
                ax.legend(fontsize=7)
    fig.suptitle('Work-precision: error against cost (left is more accurate, down is faster)')
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


def main(out, quick=False, log=print):
    """Run, write ``work_precision.csv``, ``work_precision_fastest.csv``,
    ``work_precision_reference.csv`` and ``work_precision.png`` into ``out``; returns the paths."""
    out = Path(out)
    tag = '_quick' if quick else ''
    rows, spreads = run(out, quick, log)
    best = fastest_table(rows)
    ref_rows = [{'column': c, 'check': k, 'strain_difference_rel': v}
                for c, d in spreads.items() for k, v in d.items()]
    written = [common.write_csv(out / f'work_precision{tag}.csv', rows),
               common.write_csv(out / f'work_precision_fastest{tag}.csv', best),
               common.write_csv(out / f'work_precision_reference{tag}.csv', ref_rows),
               plot(rows, spreads, out / f'work_precision{tag}.png')]
    written += stiff_main(out, quick, log)
    for b in best:
        log(f'  fastest ({b["ranking"]}) at error <= {b["level"]:g}: {b["column"]} {b["model"]}: '
            f'{b["method"]} '
            f'(dt {b["dt"]}, rtol {b["rtol"]}), {b["wall_per_sim_s"]:.3g} s per simulated s, '
            f'runner-up {b["runner_up"]} x{b["runner_up_ratio"]:.2f}')
    return written
