"""The outputs of the paper identification (bench/paper_id.py) that docs/paper.md shows: the
figure ``strain_waves.png`` (strain along the identified FB and RB columns at several times), the
speed ratios over the members of the family sweep, and the report's Markdown tables read from the
files the stages wrote."""
from __future__ import annotations

import csv
import json
import math

from .paper_id_data import (CHOICE_KEYS, FAMILY, PAPER_FB, PAPER_RB, SPEEDS, V0S, fit_files,
                            residuals)

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
    from tensegrity_ros.studies.table import read_rows
    groups = {}
    for r in _members(read_rows(out / 'family').values()):
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


def _members(rows):
    """The rows (dicts) that are members of the family: every key of FAMILY set to one of its
    values (a sweep folder keeps the rows of earlier families: they are not)."""
    return [r for r in rows if all(any(r.get(k) == v for v in vals)
                                   for k, vals in FAMILY.items())]


def _near(r):
    """Amplitudes at 0.1 and 0.15 within 50 % of the paper's."""
    return (r['amplitude_0.1'] and r['amplitude_0.15']
            and abs(r['amplitude_0.1'] / 0.054 - 1) < 0.5
            and abs(r['amplitude_0.15'] / 0.085 - 1) < 0.5)


def report(out):
    """The tables of docs/paper.md as Markdown, from the files the stages wrote."""
    lines = []

    def f(v, fmt='.3g'):
        return 'n/a' if v in (None, '') else format(float(v), fmt)

    def mm(v):
        return f'{1e3 * float(v):.2f}'

    def per_case(table, cells):
        """The rows ``| label | v0 | cells... |`` of a ``{label: {v0: figures}}`` result."""
        return [f"| {label} | {v0} | " + ' | '.join(cells(r)) + ' |'
                for label, per in table.items() for v0, r in per.items()]
    fam = list(csv.DictReader(open(out / 'family.csv')))
    for reading, top in (('slope', 16), ('snapshot', 6), ('paper', 6)):
        rows = sorted((r for r in fam if r['speed_reading'] == reading),
                      key=lambda r: float(r['rms_error']))
        lines += [f'\nFamily, best grid radius per combination, speed read by {reading} '
                  f'(best {min(top, len(rows))} of {len(rows)}):\n',
                  '| stacking | mass placement | impact | bar r_b (mm) | r (mm) | rms error | '
                  'amplitude 0.1 / 0.125 / 0.15 | speed 0.1 / 0.15 (m/s) | width at 0.1 '
                  '(prisms) |', '|---|---|---|---|---|---|---|---|---|']
        for r in rows[:top]:
            lines.append(f"| {r['structure.stacking']} | {r['structure.mass_placement']} | "
                         f"{r['loading.impact.mode']} | {mm(r['materials.bar_radius'])} | "
                         f"{1e3 * float(r['structure.radius']):.1f} | "
                         f"{100 * float(r['rms_error']):.1f} % | {f(r['amplitude_0.1'])} / "
                         f"{f(r['amplitude_0.125'])} / {f(r['amplitude_0.15'])} | "
                         f"{f(r['speed_0.1'])} / {f(r['speed_0.15'])} | "
                         f"{f(r['width_0.1'], '.2f')} |")
    lines += ['\nBest member per bar radius (rms error, speed by slope / by the paper\'s '
              'reading):\n', '| bar r_b (mm) | slope | paper | best combination (slope) |',
              '|---|---|---|---|']
    for rb in FAMILY['materials.bar_radius']:
        best = {}
        for reading in ('slope', 'paper'):
            rows = [r for r in fam if r['speed_reading'] == reading
                    and abs(float(r['materials.bar_radius']) - rb) < 1e-9]
            best[reading] = min(rows, key=lambda r: float(r['rms_error'])) if rows else None
        b = best['slope']
        if b is None:
            continue
        lines.append(f"| {1e3 * rb:.2f} | {100 * float(b['rms_error']):.1f} % | "
                     f"{100 * float(best['paper']['rms_error']):.1f} % | "
                     f"{b['structure.stacking']}, {b['structure.mass_placement']}, "
                     f"{b['loading.impact.mode']}, r = {1e3 * float(b['structure.radius']):.1f}"
                     f" mm |")
    ratios = speed_ratios(out)
    near = [r for r in ratios if _near(r)]
    lines += ['\nSpeed ratio speed(0.15) / speed(0.1) over the family (paper: 1.50):\n']
    if ratios:
        r0 = ratios[0]
        lines.append(f'- all {len(ratios)} member-readings: largest {r0["ratio"]:.3f} '
                     f'({r0["speed_reading"]}, r = {1e3 * r0["structure.radius"]:.1f} mm, '
                     f'r_b = {mm(r0["materials.bar_radius"])} mm, {r0["structure.stacking"]}, '
                     f'{r0["structure.mass_placement"]}, {r0["loading.impact.mode"]}; '
                     f'amplitudes {r0["amplitude_0.1"]:.3g} / {r0["amplitude_0.15"]:.3g})')
    if near:
        lines.append(f'- the {len(near)} whose amplitudes at 0.1 and 0.15 are within 50 % of the '
                     f"paper's: largest {near[0]['ratio']:.3f} ({near[0]['speed_reading']}, "
                     f"r_b = {mm(near[0]['materials.bar_radius'])} mm), median "
                     f"{sorted(r['ratio'] for r in near)[len(near) // 2]:.3f}")
        for reading in SPEEDS:
            sub = [r for r in near if r['speed_reading'] == reading]
            if sub:
                lines.append(f'  - read by {reading}: {len(sub)} members, largest '
                             f"{sub[0]['ratio']:.3f}, {sum(r['ratio'] > 1.11 for r in sub)} "
                             'above 1.11')
        for rb in FAMILY['materials.bar_radius']:
            sub = [r for r in near if abs(r['materials.bar_radius'] - rb) < 1e-9]
            if sub:
                lines.append(f'  - r_b = {1e3 * rb:.2f} mm: {len(sub)} member-readings, largest '
                             f"{sub[0]['ratio']:.3f}, median "
                             f"{sorted(r['ratio'] for r in sub)[len(sub) // 2]:.3f}")
    else:
        lines.append('- none near')
    for speed in SPEEDS:
        _, json_path, txt_path = fit_files(out, speed)
        if json_path.exists():
            fit = json.loads(json_path.read_text())
            lines += [f'\nFit (`tensegrity fit`, speeds read by {speed}):\n']
            lines += txt_path.read_text().splitlines() + [f"\n({fit['runs']} runs)"]
    if (out / 'sensitivity.csv').exists():
        lines += ['\nSensitivity:\n', '| case | rms (slope) | rms (snapshot) | rms (paper) | '
                  'amplitude 0.1 / 0.125 / 0.15 | speed 0.1 / 0.15 | snapshot 0.1 / 0.15 |',
                  '|---|---|---|---|---|---|---|']
        for r in csv.DictReader(open(out / 'sensitivity.csv')):
            lines.append(f"| {r['case']} | {100 * float(r['rms_error_slope']):.1f} % | "
                         f"{100 * float(r['rms_error_snapshot']):.1f} % | "
                         f"{100 * float(r.get('rms_error_paper') or 'nan'):.1f} % | "
                         f"{f(r['amplitude_0.1'])} / {f(r['amplitude_0.125'])} / "
                         f"{f(r['amplitude_0.15'])} | "
                         f"{f(r['speed_0.1'])} / {f(r['speed_0.15'])} | "
                         f"{f(r['snapshot_0.1'])} / {f(r['snapshot_0.15'])} |")
    if (out / 'contact.csv').exists():
        rows = list(csv.DictReader(open(out / 'contact.csv')))
        gap = float(rows[0]['rest_gap']) if rows else math.nan
        lines += [f'\nBar contact at the identified point (bars touch at rest from r_b = '
                  f'{1e3 * gap / 2:.2f} mm):\n',
                  '| bars | r_b (mm) | rms (slope) | amplitude 0.1 / 0.125 / 0.15 | '
                  'speed 0.1 / 0.15 | ratio slope / paper reading | width at 0.1 / 0.15 | '
                  'W 0.1 / 0.15 | f 0.1 / 0.15 |', '|---|---|---|---|---|---|---|---|---|']
        for r in rows:
            lines.append(f"| {r['material']} | {mm(r['bar_radius'])} | "
                         f"{100 * float(r['rms_error_slope']):.1f} % | {f(r['amplitude_0.1'])}"
                         f" / {f(r['amplitude_0.125'])} / {f(r['amplitude_0.15'])} | "
                         f"{f(r['speed_0.1'])} / {f(r['speed_0.15'])} | "
                         f"{f(r['ratio_slope'])} / {f(r['ratio_paper'])} | "
                         f"{f(r['width_0.1'], '.2f')} / {f(r['width_0.15'], '.2f')} | "
                         f"{f(r['W_0.1'], '.2f')} / {f(r['W_0.15'], '.2f')} | "
                         f"{f(r['f_0.1'], '.2f')} / {f(r['f_0.15'], '.2f')} |")
    if (out / 'predict.json').exists():
        pred = json.loads((out / 'predict.json').read_text())
        lines += ['\nPrediction:\n', '| column | v0 | amplitude at 0.5 s | median | speed | '
                  'snapshot speed | width (half max) | status |',
                  '|---|---|---|---|---|---|---|---|']
        lines += per_case(pred, lambda r: [
            f(r['pulse.amplitude']), f(r['pulse.amplitude_median']), f(r['pulse.speed_m_s']),
            f(r['pulse.speed_snapshot_m_s']), f(r['pulse.width_half_prisms'], '.2f'),
            r['status']])
        for label in (k for k in pred if k.endswith('FB')):
            figs = {float(v0): r for v0, r in pred[label].items()}
            errs = ', '.join(f'{100 * residuals(figs, key)[0]:.1f} % ({reading})'
                             for reading, key in SPEEDS.items())
            lines.append(f'\nrms error of {label}: {errs}')
    if (out / 'momentum.json').exists():
        mom = json.loads((out / 'momentum.json').read_text())
        lines += ['\nMomentum of the leading pulse at 0.5 s:\n',
                  '| column | v0 | amplitude | speed (slope) | W (prisms) | f = P / (m v0) | '
                  'strain / velocity momentum | column momentum / (m v0) |',
                  '|---|---|---|---|---|---|---|---|']
        lines += per_case(mom, lambda r: [
            f(r.get('pulse.amplitude')), f(r.get('pulse.speed_m_s')),
            f(r.get('pulse.width_eff_prisms'), '.2f'), f(r.get('pulse.momentum_share'), '.3f'),
            f(r.get('pulse.momentum_ratio'), '.3f'), f(r.get('column_share'), '.3f')])
    return '\n'.join(lines)

