"""The data of the paper identification (bench/paper_id.py): the paper's flexible-base figures
and how they are weighted, the family of modelling choices and the keys the fit frees, the
thin-bar member, the bar materials of the contact scan; the residuals of a member against the
paper's figures, the paths of a fit under each speed reading, and the paper's figures written as a
``tensegrity fit`` target."""
from __future__ import annotations

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
SPEEDS = {'slope': 'pulse.speed_m_s', 'snapshot': 'pulse.speed_snapshot_m_s',
          'paper': 'pulse.speed_paper_m_s'}
WIDTH = 'pulse.width_half_prisms'
WIDTH_WEIGHT = 0.25                # "about 4 prisms": read off a figure, a quarter of the weight
FAMILY = {
    'structure.radius': [round(0.0029 + 0.0003 * i, 6) for i in range(8)],
    'structure.stacking': ['shared', 'parallel'],
    'structure.mass_placement': ['level', 'unit_bases'],
    # the striker (a rigid mass through a stiff linear contact, 1e4 N/m) does not keep the
    # energy balance at the family's time step (3e-4 of the energy lost in the first step): it
    # is in the sensitivity study only, at half the step
    'loading.impact.mode': ['impulse', 'energy'],
    # bar radius (contact between bars): 0.1 mm (the default, line-like at these velocities) to
    # 0.55 mm, the largest whose bars do not touch at rest at every base radius of the family
    # (rest gap between the axes of a prism's bars 1.18 mm at r = 2.9 mm: rest_gap)
    'materials.bar_radius': [0.0001, 0.0003, 0.00045, 0.00055],
}
CHOICE_KEYS = [k for k in FAMILY if k != 'structure.radius']
# the fit: these keys continuous over the family's range, the others discrete
FIT_FREE = ('structure.radius', 'materials.bar_radius')
FIT_CHOICES = [k for k in CHOICE_KEYS if k not in FIT_FREE]
# the closest member with bars of the default 0.1 mm radius (r = 4.525 mm, shared, unit_bases,
# impulse: the identification of a family of thin bars): its RB prediction is reported next to
# the identified one
THIN_BARS = {'structure.radius': 0.004525, 'structure.stacking': 'shared',
             'structure.mass_placement': 'unit_bases', 'loading.impact.mode': 'impulse',
             'materials.bar_radius': 0.0001}
# bar materials of the contact scan: (label, E Pa, Poisson ratio)
BAR_MATERIALS = (('steel', 2.0e11, 0.3), ('aluminium', 7.0e10, 0.33), ('polymer', 3.0e9, 0.35))


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


def fit_files(out, speed='slope'):
    """``(target, fit.json, fit.txt)`` paths of the fit under the speed reading ``speed``: the
    slope reading's target is ``config/paper/fb_target.yaml``, the others' are written next to
    their results."""
    if speed == 'slope':
        return TARGET, out / 'fit.json', out / 'fit.txt'
    return (out / f'fb_target_{speed}.yaml', out / f'fit_{speed}.json', out / f'fit_{speed}.txt')


def write_target(path=TARGET, speed_key=SPEEDS['slope']):
    """The paper's FB figures as a ``tensegrity fit`` target, speeds read by ``speed_key`` (the
    slope of the peak track by default)."""
    cases = []
    for v0, (amp, speed, width) in PAPER.items():
        figs, weights = {'pulse.amplitude': amp}, {}
        if speed is not None:
            figs[speed_key] = speed
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
            + ('' if speed_key == SPEEDS['slope'] else
               f'# Speeds read as {speed_key} (python -m bench.paper_id --speed).\n')
            + yaml.safe_dump({'cases': cases}, sort_keys=False))
    if not path.exists() or path.read_text() != text:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return path

