"""What a fit determined (``tensegrity fit``, docs/sweeps.md): for each free key, at the best
point and the other keys held there, how far it can move before a fitted figure moves by more than
:data:`TOLERANCE`, and whether it ended on a bound of its ``--free`` range.

The estimate is local and linear: every case is run again with the key moved by :data:`STEP` of
its bound range up and down (central differences; one-sided at a bound), each fitted figure's
relative slope ``(f(x + d) - f(x - d)) / (2 d) / f(x)`` is taken, and the key's range is
``x +- TOLERANCE / max |slope|``, cut at the bounds. A range that reaches a bound on both sides
means the targets do not determine the key within them.
"""
from __future__ import annotations

import math

import numpy as np

STEP = 0.01           # the difference step, a fraction of each free key's bound range
TOLERANCE = 0.01      # a fitted figure may move by this much (relative) within a key's range
AT_BOUND = 1e-3       # a value within this fraction of the range from a bound is on it


def determination(obj, x, figures, threads=None):
    """The ``free`` entries of a fit's result (see the module text) for the best point ``x`` of
    the :class:`~tensegrity_ros.studies.fit.Objective` ``obj``, whose cases gave the flattened
    summaries ``figures`` (None for a case that did not run)."""
    p = obj.problem
    points, steps = [], []
    for i, (_, lo, hi) in enumerate(p.free):
        d = STEP * (hi - lo)
        up, down = min(x[i] + d, hi), max(x[i] - d, lo)
        for v in (up, down):
            moved = np.array(x, dtype=float)
            moved[i] = v
            points.append(moved)
        steps.append((up, down))
    got = obj.evaluate_many(points, threads=threads) if points else []
    out = []
    for i, (key, lo, hi) in enumerate(p.free):
        value = float(x[i])
        (up, down), f_up, f_down = steps[i], got[2 * i][2], got[2 * i + 1][2]
        slopes = {}
        for k, case in enumerate(p.cases):
            for name in case.figures:
                a, b, f = (_figure(s, k, name) for s in (f_up, f_down, figures))
                if None not in (a, b, f) and f != 0 and up > down:
                    slopes[f'case {k + 1} {name}'] = (a - b) / (up - down) / f
        out.append(_entry(key, value, lo, hi, slopes))
    return out


def _figure(summaries, k, name):
    s = summaries[k] if summaries is not None else None
    v = s.get(name) if s else None
    return float(v) if v is not None and math.isfinite(v) else None


def _entry(key, value, lo, hi, slopes):
    value, lo, hi = float(value), float(lo), float(hi)
    span = hi - lo
    bound = ('lower' if value - lo <= AT_BOUND * span else
             'upper' if hi - value <= AT_BOUND * span else None)
    entry = {'key': key, 'value': value, 'lo': lo, 'hi': hi, 'at_bound': bound,
             'tolerance': TOLERANCE, 'range': None, 'half_width_rel': None,
             'pinned_by': None, 'elasticity': None, 'determined': False}
    if not slopes:
        return entry
    figure, slope = max(slopes.items(), key=lambda kv: abs(kv[1]))
    slope = float(slope)
    entry['pinned_by'] = figure
    entry['elasticity'] = slope * value          # d ln f / d ln x of that figure
    if slope == 0:
        entry['range'] = [lo, hi]
        return entry
    w = TOLERANCE / abs(slope)
    entry['range'] = [max(lo, value - w), min(hi, value + w)]
    entry['half_width_rel'] = w / abs(value) if value else None
    entry['determined'] = bool(value - w > lo or value + w < hi)
    return entry


def bound_note(entries):
    """The one line of a fit that ended on a bound of a free key (None when none did)."""
    hit = [e for e in entries if e['at_bound']]
    if not hit:
        return None
    parts = [f"{e['key']} = {e['value']:.6g} on its {e['at_bound']} bound "
             f"(--free {e['key']}={e['lo']:g}:{e['hi']:g})" for e in hit]
    return ('the fit ended on a bound: ' + '; '.join(parts)
            + '; the best value may lie beyond it: widen the range')


def format_lines(entries):
    """The text of the ``free`` entries."""
    if not entries:
        return []
    lines = [f'  what the targets determine (each free key alone, the others at the best point; '
             f'linear estimate from runs at +-{100 * STEP:g} % of its range): the values over '
             f'which every fitted figure stays within {100 * TOLERANCE:g} % of its fitted value']
    for e in entries:
        head = f"    {e['key']} = {e['value']:.6g}"
        if e['range'] is None:
            lines.append(f'{head}: no figure could be compared (a run did not end ok)')
            continue
        a, b = e['range']
        width = ('' if e['half_width_rel'] is None
                 else f" (+-{100 * e['half_width_rel']:.3g} %)")
        what = (f'{a:.6g} to {b:.6g}{width}' if e['determined'] else
                f'{a:.6g} to {b:.6g}, its whole --free range: NOT determined by the targets')
        pinned = (f", most sensitive figure {e['pinned_by']} (d ln f / d ln x = "
                  f"{e['elasticity']:.3g})" if e['pinned_by'] else '')
        bound = (f"  [ON ITS {e['at_bound'].upper()} BOUND]" if e['at_bound'] else '')
        lines.append(f'{head}: {what}{pinned}{bound}')
    return lines
