"""Which model did the paper simulate? The identification study of docs/paper.md.

    python -m bench.paper_id [--out bench/results/paper_id] [--workers N] [--quick]
                             [--only family,fit,sensitivity,contact,predict,momentum,figure]
                             [--speed slope|snapshot|paper]

Every figure of docs/paper.md comes from the files this writes:

1. ``family/``: a sweep (``tensegrity sweep``) of the flexible-base (FB) column over the family
   of modelling choices the paper leaves open: the base circumradius (the reading of the lattice
   constant a), the base-cable topology, where the unit mass sits and how the impact enters, at
   the paper's three impact velocities, and the bar radius (contact between the bars,
   docs/physics.md section 7.1). ``family.csv``: the best grid radius of every discrete
   combination and its residual against the paper's FB figures, under the three speed readings
   (slope of the peak track, a snapshot at 0.5 s, the snapshot rounded to whole prisms: the
   paper's reading).
2. ``fit.json``: ``tensegrity fit`` over the same family (base and bar radius continuous, the
   rest discrete) against ``config/paper/fb_target.yaml`` (``--speed`` picks the speed reading
   of the target: ``fit_<reading>.json`` and a target of that reading in the output folder for
   the snapshot and paper readings).
3. ``sensitivity.csv``: one key at a time around the identified point (every discrete choice
   flipped, the radius moved, bar masses, a lumped end mass, the prestrain, a halved time step,
   the bars' material and line bars).
4. ``contact.csv``: the bar radius from line-like bars to bars that nearly touch at rest, for
   steel and polymer bars, at the identified point: amplitudes, speeds, speed ratios,
   widths and momentum shares.
5. ``predict.json``: the rigid-base (RB) column with the identified choices, only the bases
   switched; nothing is tuned on it; next to it the thin-bar member's (THIN_BARS).
6. ``momentum.json``: the leading pulse's momentum figures (share f of the impact momentum,
   effective width W, strain- against velocity-derived momentum) of the identified FB member
   at the three v0.
7. ``strain_waves.png``: strain along the column at several times, per v0, for the identified FB
   and RB columns (the style of the paper's Figs. 2-3).

Runs go through :func:`solver.simulate.runner.simulate` (as ``tensegrity run``) on a Dask
LocalCluster. This module holds the stages that run (family, fit, sensitivity, contact, predict,
momentum) and the command; :mod:`bench.paper_id_data` the paper's figures, the family, the
residuals and the fit target; :mod:`bench.paper_id_report` the figure and the report's tables.
Every name of the two is reachable here too (``paper_id.FAMILY``, ``paper_id.report``).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path

from .paper_id_data import (BAR_MATERIALS, CHOICE_KEYS, FAMILY, FB, FIT_CHOICES, FIT_FREE, PAPER,
                            PAPER_FB, PAPER_RB, ROOT, SPEEDS, T_END, THIN_BARS, V0S, WIDTH,
                            fit_files, residuals, write_target)
from .paper_id_report import figure, report
# reachable as paper_id.X like the names above (the tests use them)
from .paper_id_data import TARGET, WIDTH_WEIGHT  # noqa: F401
from .paper_id_report import speed_ratios  # noqa: F401


def _cluster(workers):
    from tensegrity_ros.studies.cluster import Cluster
    return Cluster(workers=workers) if (workers or 2) > 1 else None


def family(out, cluster, quick=False):
    """The family sweep and its table of best points per combination."""
    from tensegrity_ros.io.progress import progress_bar
    from tensegrity_ros.studies.sweep import build, execute
    grids = [f'{k}={",".join(str(v) for v in vals)}' for k, vals in FAMILY.items()]
    if quick:
        grids[0] = 'structure.radius=0.0035,0.005'
        grids[-1] = 'materials.bar_radius=0.0001,0.00045'
    grids.append('loading.impact.v0=' + ','.join(str(v) for v in V0S))
    _drop_stale_rows(out / 'family')
    sweep = build(FB, grids, out=out / 'family', t_end=T_END)
    update, close = progress_bar(len(sweep.points), 'family')
    try:
        rows, _ = execute(sweep, cluster, progress=update)
    finally:
        close()
    groups = {}
    for r in rows:
        key = tuple(r[k] for k in ('structure.radius', *CHOICE_KEYS))
        groups.setdefault(key, {})[r['loading.impact.v0']] = r
    table = []
    for reading, speed_key in SPEEDS.items():
        best = {}
        for key, figs in groups.items():
            err, _ = residuals(figs, speed_key)
            combo = key[1:]
            if combo not in best or err < best[combo][0]:
                best[combo] = (err, key[0], figs)
        for combo, (err, radius, figs) in best.items():
            row = {'speed_reading': reading, **dict(zip(CHOICE_KEYS, combo)),
                   'structure.radius': radius, 'rms_error': err}
            for v0 in V0S:
                f = figs.get(v0, {})
                row[f'amplitude_{v0:g}'] = f.get('pulse.amplitude')
                row[f'speed_{v0:g}'] = f.get(speed_key)
                row[f'width_{v0:g}'] = f.get(WIDTH)
            table.append(row)
    table.sort(key=lambda r: (r['speed_reading'], r['rms_error']))
    _write_csv(out / 'family.csv', table)
    return table


def _drop_stale_rows(folder):
    """Rewrite ``rows.jsonl`` of a family sweep without the rows that lack a key of the family
    (those of an earlier family), so that the sweep resumes only its own points."""
    path = folder / 'rows.jsonl'
    if not path.exists():
        return
    def member(line):
        try:
            row = json.loads(line)
        except json.JSONDecodeError:          # a line cut short by a kill
            return False
        return isinstance(row, dict) and all(k in row for k in FAMILY)
    lines = path.read_text().splitlines()
    keep = [ln for ln in lines if member(ln)]
    if len(keep) < len(lines):
        path.write_text(''.join(ln + '\n' for ln in keep))


def fit(out, cluster, quick=False, speed='slope'):
    """``tensegrity fit`` over the family against the paper's FB figures, speeds read by
    ``speed`` (a key of SPEEDS)."""
    from tensegrity_ros.studies import fit as fitmod
    target, json_path, txt_path = fit_files(out, speed)
    write_target(target, SPEEDS[speed])
    free = [f'{k}={min(FAMILY[k])}:{max(FAMILY[k])}' for k in FIT_FREE]
    choices = [f'{k}={",".join(FAMILY[k])}' for k in FIT_CHOICES]
    problem = fitmod.build(FB, target, free, choices, t_end=T_END)
    result = fitmod.fit(problem, cluster, seed=0, popsize=3 if quick else 4,
                        maxiter=2 if quick else 4)
    json_path.write_text(json.dumps(result, indent=1))
    txt_path.write_text('\n'.join(fitmod.format_result(result)) + '\n')
    return result


def rest_gap(overrides=(), scene_path=FB):
    """The smallest distance m between the axes of two bars that can touch
    (:func:`solver.models.extras.bar_pairs`) in the column at rest: bars of a radius of half of
    it or more would touch before any impact."""
    import numpy as np

    from solver.build import structures
    from solver.build.scene import Scene
    from solver.kernels.barcontact import segment_params
    from solver.models.extras import bar_pairs
    net = structures.build_network(Scene.load(scene_path).with_overrides(list(overrides)))
    x = np.asarray(net.x0)
    best = math.inf
    for a0, a1, b0, b1 in bar_pairs(net):
        u, w = x[a1] - x[a0], x[b1] - x[b0]
        s, t = segment_params(*x[a0], *u, *x[b0], *w)
        best = min(best, float(np.linalg.norm(x[a0] + s * u - x[b0] - t * w)))
    return best


def identified_overrides(scene_path=PAPER_FB):
    """The scene values of ``paper_fb.yaml`` that differ from ``fb_column.yaml`` (the identified
    choices), as ``--set`` pairs."""
    from solver.build.scene import Scene
    a, b = Scene.load(FB).data, Scene.load(scene_path).data
    out = {}

    def walk(x, y, prefix=''):
        for k in y:
            if isinstance(y[k], dict):
                walk(x[k], y[k], prefix + k + '.')
            elif x[k] != y[k] and k not in ('name', 'description'):
                out[prefix + k] = y[k]
    walk(a, b)
    return out


def _runs(cluster, scene_path, cases):
    """Run ``cases`` (list of (label, overrides dict)) of ``scene_path`` at every v0; returns
    label -> v0 -> flat row."""
    from tensegrity_ros.studies.sweep import Sweep, execute
    from solver.build.scene import Scene
    scene = Scene.load(scene_path)
    points, labels = [], []
    for label, sets in cases:
        for v0 in V0S:
            points.append({**sets, 'loading.impact.v0': v0})
            labels.append(label)
    keys = sorted({k for p in points for k in p})
    sweep = Sweep(scene, points, Path('/nonexistent'), keys, {'run.t_end': T_END})
    rows = _execute_in_memory(sweep, cluster, execute)
    out = {}
    for label, p, r in zip(labels, points, rows):
        out.setdefault(label, {})[p['loading.impact.v0']] = r
    return out


def _execute_in_memory(sweep, cluster, execute):
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        sweep.out_dir = Path(tmp)
        rows, _ = execute(sweep, cluster)
    return rows


def sensitivity(out, cluster, quick=False):
    """One key at a time around the identified point."""
    base = identified_overrides()
    r0 = base.get('structure.radius', 0.005)
    cases = [('identified', {})]
    for f in ((0.98, 1.02) if quick else (0.95, 0.98, 0.999, 1.001, 1.02, 1.05)):
        cases.append((f'radius x {f:g}', {'structure.radius': round(r0 * f, 9)}))
    rb0 = base.get('materials.bar_radius', _default('materials.bar_radius'))
    for f in (() if quick else (0.99, 1.01)):
        cases.append((f'bar radius x {f:g}', {'materials.bar_radius': round(rb0 * f, 10)}))
    for key in CHOICE_KEYS:
        for v in FAMILY[key]:
            if v != base.get(key, _default(key)):
                cases.append((f'{key} = {v}', {key: v}))
    cases += [('prestrain 0.0018', {'prestrain': 0.0018}),
              ('prestrain 0.0022', {'prestrain': 0.0022}),
              ('integrator.dt / 2', {'integrator.dt': 3.125e-4}),
              ('end mass = 1 unit', {'materials.end_mass': 0.0249}),
              ('contact.bars = none (line bars)', {'contact.bars': 'none'}),
              ('striker, integrator.dt / 2', {'loading.impact.mode': 'striker',
                                              'integrator.dt': 3.125e-4})]
    cases += [(f'{name} bars (E {E:.2g} Pa)', {'materials.bar_E': E, 'materials.bar_poisson': nu})
              for name, E, nu in BAR_MATERIALS[1:]]
    if not quick:
        cases += [('bar mass fraction 0.3', {'materials.bar_mass_fraction': 0.3})]
    res = _runs(cluster, PAPER_FB, cases)
    table = []
    for label, _ in cases:
        figs = res[label]
        row = {'case': label}
        for reading, key in SPEEDS.items():
            row[f'rms_error_{reading}'] = residuals(figs, key)[0]
        for v0 in V0S:
            f = figs.get(v0, {})
            row[f'amplitude_{v0:g}'] = f.get('pulse.amplitude')
            row[f'speed_{v0:g}'] = f.get('pulse.speed_m_s')
            row[f'snapshot_{v0:g}'] = f.get('pulse.speed_snapshot_m_s')
            row[f'paper_{v0:g}'] = f.get('pulse.speed_paper_m_s')
            row[f'width_{v0:g}'] = f.get(WIDTH)
            row[f'status_{v0:g}'] = f.get('status')
        table.append(row)
    _write_csv(out / 'sensitivity.csv', table)
    return table


def _default(key):
    from solver.build.scene import Scene
    return Scene.load(FB)[key]


def contact(out, cluster, quick=False):
    """The bar radius and material at the identified point: from 0.1 mm to the largest radius
    whose bars do not touch at rest there, in 0.05 mm steps, for steel and polymer bars (the
    stiffest and the softest contact of BAR_MATERIALS)."""
    base = identified_overrides()
    limit = 0.5 * rest_gap(base.items())
    radii = [round(1e-4 + 5e-5 * i, 6) for i in range(40) if 1e-4 + 5e-5 * i < limit]
    if quick:
        radii = radii[::4]
    cases = [(f'{name} r_b {rb:g}', {'materials.bar_radius': rb, 'materials.bar_E': E,
                                     'materials.bar_poisson': nu})
             for name, E, nu in (BAR_MATERIALS[:1] if quick else BAR_MATERIALS[::2])
             for rb in radii]
    res = _runs(cluster, PAPER_FB, cases)
    table = []
    for label, sets in cases:
        figs = res[label]
        row = {'material': label.split()[0], 'bar_radius': sets['materials.bar_radius'],
               'bar_E': sets['materials.bar_E'], 'rest_gap': 2 * limit}
        for reading, key in SPEEDS.items():
            row[f'rms_error_{reading}'] = residuals(figs, key)[0]
            a, b = figs[0.1].get(key), figs[0.15].get(key)
            row[f'ratio_{reading}'] = b / a if a and b else None
        for v0 in V0S:
            f = figs.get(v0, {})
            row[f'amplitude_{v0:g}'] = f.get('pulse.amplitude')
            row[f'speed_{v0:g}'] = f.get('pulse.speed_m_s')
            row[f'paper_{v0:g}'] = f.get('pulse.speed_paper_m_s')
            row[f'width_{v0:g}'] = f.get(WIDTH)
            row[f'W_{v0:g}'] = f.get('pulse.width_eff_prisms')
            row[f'f_{v0:g}'] = f.get('pulse.momentum_share')
            row[f'status_{v0:g}'] = f.get('status')
        table.append(row)
    _write_csv(out / 'contact.csv', table)
    return table


PREDICT_KEYS = ('status', 'reason', 'pulse.amplitude', 'pulse.amplitude_median',
                'pulse.speed_m_s', 'pulse.speed_snapshot_m_s', 'pulse.speed_paper_m_s',
                'pulse.width_half_prisms', 'pulse.width_prisms', 'pulse.amplitude_passage_max',
                'energy_drift_rel', 'constraint_error_rel')


def predict(out, cluster):
    """The RB column with the identified choices (paper_rb.yaml), with the thin-bar member's
    (THIN_BARS) and the plain RB reading; the FB columns next to them."""
    fb = _runs(cluster, PAPER_FB, [('identified FB', {})])
    res = _runs(cluster, PAPER_RB, [('identified RB', {})])
    prev_fb = _runs(cluster, PAPER_FB, [('thin-bar FB', THIN_BARS)])
    prev = _runs(cluster, PAPER_RB, [('thin-bar RB', THIN_BARS)])
    plain = _runs(cluster, ROOT / 'config' / 'scenes' / 'rb_column.yaml', [('plain RB', {})])
    result = {label: {f'{v0:g}': {k: r.get(k) for k in PREDICT_KEYS} for v0, r in figs.items()}
              for d in (fb, res, prev_fb, prev, plain) for label, figs in d.items()}
    (out / 'predict.json').write_text(json.dumps(result, indent=1))
    return result


MOMENTUM_KEYS = ('status', 'pulse.amplitude', 'pulse.speed_m_s', 'pulse.speed_paper_m_s',
                 'pulse.width_half_prisms', 'pulse.width_eff_prisms', 'pulse.momentum_share',
                 'pulse.momentum_strain', 'pulse.momentum_nodes', 'pulse.momentum_ratio',
                 'pulse.momentum_prisms', 'pulse.momentum_column')


def momentum(out, cluster):
    """The momentum figures of the identified FB member (and of the thin-bar member, the
    plain reading and the identified RB column) at the three v0: ``momentum.json``, label -> v0
    -> figures, with ``column_share`` the column's momentum over ``m v0`` (before the pulse
    reaches the clamped end: what the impact gave it)."""
    from solver.build.scene import Scene
    m = Scene.load(PAPER_FB)['materials.unit_mass']
    runs = {}
    runs.update(_runs(cluster, PAPER_FB, [('identified FB', {})]))
    runs.update(_runs(cluster, PAPER_FB, [('thin-bar FB', THIN_BARS)]))
    runs.update(_runs(cluster, FB, [('plain FB', {})]))
    runs.update(_runs(cluster, PAPER_RB, [('identified RB', {})]))
    result = {}
    for label, figs in runs.items():
        result[label] = {}
        for v0, r in figs.items():
            row = {k: r.get(k) for k in MOMENTUM_KEYS}
            col = r.get('pulse.momentum_column')
            row['column_share'] = None if col is None else col / (m * v0)
            result[label][f'{v0:g}'] = row
    # the paper's pulse, were it of permanent shape: f = V eps_peak W / v0 with W = 4 prisms
    result['paper (W = 4 prisms)'] = {
        f'{v0:g}': {'pulse.amplitude': a, 'pulse.speed_m_s': s, 'pulse.width_eff_prisms': 4.0,
                    'pulse.momentum_share': s * a * 4.0 / v0}
        for v0, (a, s, _) in PAPER.items() if s is not None}
    (out / 'momentum.json').write_text(json.dumps(result, indent=1))
    return result


def _write_csv(path, rows):
    cols = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, 'w', newline='') as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f'{v:.6g}' if isinstance(v, float) else v) for k, v in r.items()})


def main(argv=None):
    ap = argparse.ArgumentParser(prog='python -m bench.paper_id',
                                 description=__doc__.split('\n')[0])
    ap.add_argument('--out', default=str(ROOT / 'bench' / 'results' / 'paper_id'))
    ap.add_argument('--workers', type=int, default=None, help='worker processes (default: cores)')
    ap.add_argument('--quick', action='store_true',
                    help='a small family and short fit (smoke run)')
    ap.add_argument('--only', default='family,fit,sensitivity,contact,predict,momentum,figure,'
                                      'report')
    ap.add_argument('--speed', default='slope', choices=list(SPEEDS),
                    help="the fit's speed reading: slope of the peak track (fit.json), snapshot "
                         "at 0.5 s or the paper's whole-prism snapshot (fit_<reading>.json)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    only = set(args.only.split(','))
    write_target()
    cluster = _cluster(args.workers) if only - {'figure', 'report'} else None
    try:
        if 'family' in only:
            table = family(out, cluster, args.quick)
            for r in table[:6]:
                print(f"family best: {r['speed_reading']:8} {r['rms_error']:.3f} "
                      + ' '.join(f'{r[k]}' for k in (*CHOICE_KEYS, 'structure.radius')))
        if 'fit' in only:
            result = fit(out, cluster, args.quick, args.speed)
            print(f"fit: error {result['error']:.4f} at {result['best']} ({result['runs']} runs)")
        if 'sensitivity' in only:
            for r in sensitivity(out, cluster, args.quick):
                print(f"sensitivity: {r['case']:<36} rms slope {r['rms_error_slope']:.3f}")
        if 'contact' in only:
            for r in contact(out, cluster, args.quick):
                print(f"contact: {r['material']:<9} r_b {1e3 * r['bar_radius']:.2f} mm ratio "
                      f"slope {r['ratio_slope'] or float('nan'):.3f} rms "
                      f"{r['rms_error_slope']:.3f}")
        if 'predict' in only:
            predict(out, cluster)
            print(f'predict: {out / "predict.json"}')
        if 'momentum' in only:
            momentum(out, cluster)
            print(f'momentum: {out / "momentum.json"}')
    finally:
        if cluster is not None:
            cluster.close()
    if 'figure' in only:
        print(f'figure: {figure(out)}')
    if 'report' in only:
        text = report(out)
        (out / 'report.md').write_text(text + '\n')
        print(text)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
