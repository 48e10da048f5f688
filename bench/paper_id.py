"""Which model did the paper simulate? The identification study of docs/paper.md.

    python -m bench.paper_id [--out bench/results/paper_id] [--workers N] [--quick]
                             [--only family,fit,sensitivity,predict,figure]

Every figure of docs/paper.md comes from the files this writes:

1. ``family/``: a sweep (``tensegrity sweep``) of the flexible-base (FB) column over the family
   of modelling choices the paper leaves open: the base circumradius (the reading of the lattice
   constant a), the base-cable topology, where the unit mass sits and how the impact enters, at
   the paper's three impact velocities. ``family.csv``: the best grid point of every discrete
   combination and its residual against the paper's FB figures, under both speed readings
   (slope of the peak track, or a snapshot at 0.5 s).
2. ``fit.json``: ``tensegrity fit`` over the same family (radius continuous, the rest discrete)
   against ``config/paper/fb_target.yaml``.
3. ``sensitivity.csv``: one key at a time around the identified point (every discrete choice
   flipped, the radius moved, bar masses, a lumped end mass, the prestrain, a halved time step).
4. ``predict.json``: the rigid-base (RB) column with the identified choices, only the bases
   switched; nothing is tuned on it.
5. ``strain_waves.png``: strain along the column at several times, per v0, for the identified FB
   and RB columns (the style of the paper's Figs. 2-3).

Runs go through :func:`solver.simulate.runner.simulate` (as ``tensegrity run``) on a Dask
LocalCluster.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
FB = ROOT / 'config' / 'scenes' / 'fb_column.yaml'
PAPER_FB = ROOT / 'config' / 'scenes' / 'paper_fb.yaml'
PAPER_RB = ROOT / 'config' / 'scenes' / 'paper_rb.yaml'
TARGET = ROOT / 'config' / 'paper' / 'fb_target.yaml'
V0S = (0.1, 0.125, 0.15)
T_END = 1.0
# the paper's FB figures (amplitude at 0.5 s, speed, width); None: not given
PAPER = {0.1: (0.054, 0.248, 4.0), 0.125: (0.0697, None, None), 0.15: (0.085, 0.372, None)}
SPEEDS = {'slope': 'pulse.speed_m_s', 'snapshot': 'pulse.speed_snapshot_m_s'}
WIDTH = 'pulse.width_half_prisms'
WIDTH_WEIGHT = 0.25                # "about 4 prisms": read off a figure, a quarter of the weight
FAMILY = {
    'structure.radius': [round(0.0029 + 0.0003 * i, 6) for i in range(8)],
    'structure.stacking': ['shared', 'parallel'],
    'structure.mass_placement': ['level', 'unit_bases'],
    'loading.impact.mode': ['impulse', 'energy', 'striker'],
}
CHOICE_KEYS = [k for k in FAMILY if k != 'structure.radius']


def residuals(figs_by_v0, speed_key):
    """Relative errors (simulated - paper) / paper of every FB figure the paper gives, with their
    weights: amplitudes at the three v0, speeds at 0.1 and 0.15, width at 0.1. ``figs_by_v0``:
    v0 -> row (flat summary figures). Returns (weighted rms, list of (name, error, weight))."""
    out = []
    for v0, (amp, speed, width) in PAPER.items():
        row = figs_by_v0.get(v0)
        for name, target, key, w in (('amplitude', amp, 'pulse.amplitude', 1.0),
                                     ('speed', speed, speed_key, 1.0),
                                     ('width', width, WIDTH, WIDTH_WEIGHT)):
            if target is None:
                continue
            got = None if row is None else row.get(key)
            err = 10.0 if got is None or not math.isfinite(got) else (got - target) / target
            out.append((f'{name} at {v0:g}', err, w))
    total = sum(w for _, _, w in out)
    return math.sqrt(sum(w * e * e for _, e, w in out) / total), out


def _cluster(workers):
    from tensegrity_ros.studies.sweep import Cluster
    return Cluster(workers=workers) if (workers or 2) > 1 else None


def family(out, cluster, quick=False):
    """The family sweep and its table of best points per combination."""
    from tensegrity_ros.studies.sweep import build, execute, progress_bar
    grids = [f'{k}={",".join(str(v) for v in vals)}' for k, vals in FAMILY.items()]
    if quick:
        grids[0] = 'structure.radius=0.0035,0.005'
    grids.append('loading.impact.v0=' + ','.join(str(v) for v in V0S))
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


def fit(out, cluster, quick=False):
    """``tensegrity fit`` over the family against the paper's FB figures."""
    from tensegrity_ros.studies import fit as fitmod
    lo, hi = FAMILY['structure.radius'][0], FAMILY['structure.radius'][-1]
    choices = [f'{k}={",".join(FAMILY[k])}' for k in CHOICE_KEYS]
    problem = fitmod.build(FB, TARGET, [f'structure.radius={lo}:{hi}'], choices, t_end=T_END)
    result = fitmod.fit(problem, cluster, seed=0, popsize=3 if quick else 4,
                        maxiter=2 if quick else 4)
    (out / 'fit.json').write_text(json.dumps(result, indent=1))
    (out / 'fit.txt').write_text('\n'.join(fitmod.format_result(result)) + '\n')
    return result


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
    for f in ((0.98, 1.02) if quick else (0.95, 0.98, 1.02, 1.05)):
        cases.append((f'radius x {f:g}', {'structure.radius': round(r0 * f, 7)}))
    for key in CHOICE_KEYS:
        for v in FAMILY[key]:
            if v != base.get(key, _default(key)):
                cases.append((f'{key} = {v}', {key: v}))
    cases += [('prestrain 0.0018', {'prestrain': 0.0018}),
              ('prestrain 0.0022', {'prestrain': 0.0022}),
              ('integrator.dt / 2', {'integrator.dt': 3.125e-4}),
              ('end mass = 1 unit', {'materials.end_mass': 0.0249})]
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
            row[f'width_{v0:g}'] = f.get(WIDTH)
            row[f'status_{v0:g}'] = f.get('status')
        table.append(row)
    _write_csv(out / 'sensitivity.csv', table)
    return table


def _default(key):
    from solver.build.scene import Scene
    return Scene.load(FB)[key]


def predict(out, cluster):
    """The RB column with the identified choices (paper_rb.yaml) and the plain RB reading."""
    res = _runs(cluster, PAPER_RB, [('identified RB', {})])
    plain = _runs(cluster, ROOT / 'config' / 'scenes' / 'rb_column.yaml', [('plain RB', {})])
    fb = _runs(cluster, PAPER_FB, [('identified FB', {})])
    keep = ('status', 'reason', 'pulse.amplitude', 'pulse.amplitude_median', 'pulse.speed_m_s',
            'pulse.speed_snapshot_m_s', 'pulse.width_half_prisms', 'pulse.width_prisms',
            'pulse.amplitude_passage_max', 'energy_drift_rel', 'constraint_error_rel')
    result = {label: {f'{v0:g}': {k: r.get(k) for k in keep} for v0, r in figs.items()}
              for d in (fb, res, plain) for label, figs in d.items()}
    (out / 'predict.json').write_text(json.dumps(result, indent=1))
    return result


def figure(out):
    """Strain against prism index at several times, per v0, identified FB and RB columns."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import numpy as np

    from solver.simulate.runner import simulate
    from solver.build.scene import Scene
    times = (0.1, 0.3, 0.5, 0.7)
    fig, axes = plt.subplots(2, 3, figsize=(14, 6.5), sharex=True, constrained_layout=True)
    for row, (path, name) in enumerate(((PAPER_FB, 'FB'), (PAPER_RB, 'RB'))):
        for col, v0 in enumerate(V0S):
            scene = Scene.load(path).with_overrides([('loading.impact.v0', v0),
                                                     ('run.t_end', max(times))])
            rec = simulate(scene).record
            ax = axes[row, col]
            n = rec.strain.shape[2]
            for t in times:
                k = int(np.argmin(np.abs(rec.times - t)))
                ax.plot(np.arange(1, n + 1), rec.strain[k, 0], label=f't = {rec.times[k]:.1f} s')
            ax.set_title(f'{name}, v0 = {v0:g} m/s')
            ax.grid(alpha=0.3)
            if col == 0:
                ax.set_ylabel('axial strain')
            if row == 1:
                ax.set_xlabel(f'prism (1 = clamped end, {n} = impacted end)')
    axes[0, 0].legend(fontsize=8)
    fig.suptitle('identified model (config/scenes/paper_fb.yaml, paper_rb.yaml): strain along '
                 'the column')
    path = out / 'strain_waves.png'
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def speed_ratios(out):
    """speed(v0 = 0.15) / speed(v0 = 0.1) of every member of the family sweep, both readings;
    the paper's is 1.5. Returns (rows sorted by ratio, best first)."""
    from tensegrity_ros.studies.sweep import read_rows
    groups = {}
    for r in read_rows(out / 'family').values():
        key = tuple(r[k] for k in ('structure.radius', *CHOICE_KEYS))
        groups.setdefault(key, {})[r['loading.impact.v0']] = r
    rows = []
    for key, figs in groups.items():
        if 0.1 not in figs or 0.15 not in figs:
            continue
        for reading, sk in SPEEDS.items():
            a, b = figs[0.1].get(sk), figs[0.15].get(sk)
            if a and b:
                rows.append({'speed_reading': reading, 'structure.radius': key[0],
                             **dict(zip(CHOICE_KEYS, key[1:])), 'ratio': b / a,
                             'speed_0.1': a, 'speed_0.15': b,
                             'amplitude_0.1': figs[0.1].get('pulse.amplitude'),
                             'amplitude_0.15': figs[0.15].get('pulse.amplitude')})
    rows.sort(key=lambda r: -r['ratio'])
    return rows


def report(out):
    """The tables of docs/paper.md as Markdown, from the files the stages wrote."""
    lines = []

    def f(v, fmt='.3g'):
        return 'n/a' if v in (None, '') else format(float(v), fmt)
    fam = list(csv.DictReader(open(out / 'family.csv')))
    for reading in SPEEDS:
        lines += [f'\nFamily, best grid radius per combination, speed read by {reading}:\n',
                  '| stacking | mass placement | impact | r (mm) | rms error | amplitude '
                  '0.1 / 0.125 / 0.15 | speed 0.1 / 0.15 (m/s) | width at 0.1 (prisms) |',
                  '|---|---|---|---|---|---|---|---|']
        for r in sorted((r for r in fam if r['speed_reading'] == reading),
                        key=lambda r: float(r['rms_error'])):
            lines.append(f"| {r['structure.stacking']} | {r['structure.mass_placement']} | "
                         f"{r['loading.impact.mode']} | "
                         f"{1e3 * float(r['structure.radius']):.1f} | "
                         f"{100 * float(r['rms_error']):.1f} % | {f(r['amplitude_0.1'])} / "
                         f"{f(r['amplitude_0.125'])} / {f(r['amplitude_0.15'])} | "
                         f"{f(r['speed_0.1'])} / {f(r['speed_0.15'])} | "
                         f"{f(r['width_0.1'], '.2f')} |")
    ratios = speed_ratios(out)
    near = [r for r in ratios if r['amplitude_0.1'] and abs(r['amplitude_0.1'] / 0.054 - 1) < 0.5
            and abs(r['amplitude_0.15'] / 0.085 - 1) < 0.5]
    lines += ['\nSpeed ratio speed(0.15) / speed(0.1) over the family (paper: 1.50):\n',
              f'- all {len(ratios)} member-readings: largest {ratios[0]["ratio"]:.3f} '
              f'({ratios[0]["speed_reading"]}, r = {1e3 * ratios[0]["structure.radius"]:.1f} mm, '
              f'{ratios[0]["structure.stacking"]}, {ratios[0]["structure.mass_placement"]}, '
              f'{ratios[0]["loading.impact.mode"]}; amplitudes {ratios[0]["amplitude_0.1"]:.3g} '
              f'/ {ratios[0]["amplitude_0.15"]:.3g})',
              f'- the {len(near)} whose amplitudes at 0.1 and 0.15 are within 50 % of the '
              f"paper's: largest {near[0]['ratio']:.3f}, median "
              f"{sorted(r['ratio'] for r in near)[len(near) // 2]:.3f}" if near else '- none near']
    fit = json.loads((out / 'fit.json').read_text())
    lines += ['\nFit (`tensegrity fit`):\n'] + (out / 'fit.txt').read_text().splitlines()
    lines += [f"\n({fit['runs']} runs)"]
    if (out / 'sensitivity.csv').exists():
        lines += ['\nSensitivity:\n', '| case | rms (slope) | rms (snapshot) | amplitude 0.1 / '
                  '0.125 / 0.15 | speed 0.1 / 0.15 | snapshot 0.1 / 0.15 |',
                  '|---|---|---|---|---|---|']
        for r in csv.DictReader(open(out / 'sensitivity.csv')):
            lines.append(f"| {r['case']} | {100 * float(r['rms_error_slope']):.1f} % | "
                         f"{100 * float(r['rms_error_snapshot']):.1f} % | "
                         f"{f(r['amplitude_0.1'])} / {f(r['amplitude_0.125'])} / "
                         f"{f(r['amplitude_0.15'])} | "
                         f"{f(r['speed_0.1'])} / {f(r['speed_0.15'])} | "
                         f"{f(r['snapshot_0.1'])} / {f(r['snapshot_0.15'])} |")
    if (out / 'predict.json').exists():
        pred = json.loads((out / 'predict.json').read_text())
        lines += ['\nPrediction:\n', '| column | v0 | amplitude at 0.5 s | median | speed | '
                  'snapshot speed | width (half max) | status |',
                  '|---|---|---|---|---|---|---|---|']
        for label, per in pred.items():
            for v0, r in per.items():
                lines.append(f"| {label} | {v0} | {f(r['pulse.amplitude'])} | "
                             f"{f(r['pulse.amplitude_median'])} | {f(r['pulse.speed_m_s'])} | "
                             f"{f(r['pulse.speed_snapshot_m_s'])} | "
                             f"{f(r['pulse.width_half_prisms'], '.2f')} | {r['status']} |")
    return '\n'.join(lines)


def _write_csv(path, rows):
    cols = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, 'w', newline='') as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f'{v:.6g}' if isinstance(v, float) else v) for k, v in r.items()})


def write_target(path=TARGET):
    """The paper's FB figures as a ``tensegrity fit`` target (slope speed reading)."""
    cases = []
    for v0, (amp, speed, width) in PAPER.items():
        figs, weights = {'pulse.amplitude': amp}, {}
        if speed is not None:
            figs['pulse.speed_m_s'] = speed
        if width is not None:
            figs[WIDTH] = width
            weights[WIDTH] = WIDTH_WEIGHT
        case = {'set': {'loading.impact.v0': v0}, 'figures': figs}
        if weights:
            case['weights'] = weights
        cases.append(case)
    text = ('# The paper\'s flexible-base figures (p = 0.002) as a tensegrity fit target:\n'
            '# amplitude'
            ' at 0.5 s at the three impact velocities, speeds at 0.1 and 0.15 m/s, width about\n'
            '# 4 prisms at 0.1 m/s (read off a figure: a quarter of the weight).\n'
            + yaml.safe_dump({'cases': cases}, sort_keys=False))
    if not path.exists() or path.read_text() != text:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return path


def main(argv=None):
    ap = argparse.ArgumentParser(prog='python -m bench.paper_id',
                                 description=__doc__.split('\n')[0])
    ap.add_argument('--out', default=str(ROOT / 'bench' / 'results' / 'paper_id'))
    ap.add_argument('--workers', type=int, default=None, help='worker processes (default: cores)')
    ap.add_argument('--quick', action='store_true',
                    help='a small family and short fit (smoke run)')
    ap.add_argument('--only', default='family,fit,sensitivity,predict,figure,report')
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    only = set(args.only.split(','))
    write_target()
    cluster = _cluster(args.workers) if only - {'figure'} else None
    try:
        if 'family' in only:
            table = family(out, cluster, args.quick)
            for r in table[:6]:
                print(f"family best: {r['speed_reading']:8} {r['rms_error']:.3f} "
                      + ' '.join(f'{r[k]}' for k in (*CHOICE_KEYS, 'structure.radius')))
        if 'fit' in only:
            result = fit(out, cluster, args.quick)
            print(f"fit: error {result['error']:.4f} at {result['best']} ({result['runs']} runs)")
        if 'sensitivity' in only:
            for r in sensitivity(out, cluster, args.quick):
                print(f"sensitivity: {r['case']:<36} rms slope {r['rms_error_slope']:.3f}")
        if 'predict' in only:
            predict(out, cluster)
            print(f'predict: {out / "predict.json"}')
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
