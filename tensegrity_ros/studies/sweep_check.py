"""The convergence check of a sweep (``tensegrity sweep --convergence``): each point's row against
the row of its refined twin (every step control refined), and, for a point that fails, against
the two sensitivity twins that tell a figure the steps do not resolve from one no step size
settles (:func:`solver.simulate.convergence.sensitivity`, as ``tensegrity run --convergence``
does): the refined run with every impact velocity changed by 1 part in 10^7, up and down.

The columns a checked row carries are :func:`convergence_columns`'; :func:`convergence_report`
is the command's line on them.
"""
from __future__ import annotations

import math

# the column naming the figures no step size settles
SENSITIVE = 'convergence.sensitive'


def _parts():
    """``1 part in 10^7``: the change of the impact velocities of the sensitivity twins."""
    from solver import PERTURBATION
    return f'1 part in 10^{round(-math.log10(PERTURBATION))}'


def _pulse_figures(row):
    """A row's first pulse as the figures the convergence module compares
    (:func:`solver.simulate.convergence.figures_of`: one column)."""
    from solver import FIGURES
    return [{k: row.get(f'pulse.{k}') for k in FIGURES}]


def check(row, twin, tolerance, figures=None):
    """:func:`solver.simulate.convergence.compare` of a point's ``row`` and its refined
    ``twin`` (rows), or None when either did not run ok."""
    from solver import compare
    if row is None or twin is None or row.get('status') != 'ok' or twin.get('status') != 'ok':
        return None
    return compare(_pulse_figures(row), _pulse_figures(twin), tolerance, figures)


def failed(row, twin, tolerance, figures=None):
    """Whether the point of ``row`` ran ok and failed its check against the refined ``twin``
    that also ran ok: the points whose sensitivity twins run."""
    c = check(row, twin, tolerance, figures)
    return c is not None and c['converged'] is False


def convergence_columns(row, twin, tolerance, refined, figures=None, twins=None):
    """The convergence check of a point's ``row`` against the row of its refined ``twin`` (None
    while it has not run; ``refined``: the overrides in which the twin differs from the point,
    e.g. ``{'integrator.dt': 5e-4}``): ``converged`` (True, False, or
    None when the point did not run ok, its twin has not run or neither found a pulse),
    ``convergence.worst`` (the figure that moved most), ``convergence.change`` (its relative
    change) and ``convergence.<figure>`` for each figure of
    :data:`solver.simulate.convergence.FIGURES` (from the row's pulse, the first column's), and
    ``convergence.refined`` (what was refined, e.g. ``dt/2, contact.resolution x2``). A twin that
    did not run ok fails the check: ``convergence.worst`` then says ``refined run diverged`` (or
    ``error``). ``figures``: the figures that decide ``converged`` and ``convergence.worst``
    (:func:`solver.simulate.convergence.compare`; None: all).

    ``twins``: called when the check fails, it gives the rows of the point's two sensitivity
    twins (None while they have not both run). ``convergence.sensitive`` names the failing
    figures that also move past the limit when every impact velocity changes by
    :data:`~solver.simulate.convergence.PERTURBATION` (comma-separated; empty when none does:
    finer steps settle the failure), None where the check passed, was not made, or a twin did
    not run ok."""
    from solver import convergence
    out = {'converged': None, 'convergence.worst': None, 'convergence.change': None,
           **{f'convergence.{k}': None for k in convergence.FIGURES},
           'convergence.refined': None, SENSITIVE: None}
    if row is None or row.get('status') != 'ok' or twin is None:
        return out
    out['convergence.refined'] = convergence.describe(list(refined.items()))
    if twin.get('status') != 'ok':
        out.update({'converged': False, 'convergence.worst': f'refined run {twin.get("status")}'})
        return out
    c = check(row, twin, tolerance, figures)
    out['converged'] = c['converged']
    out['convergence.worst'] = c['worst']
    if c['worst'] is not None:
        out['convergence.change'] = c['changes'][c['worst']]
    out.update({f'convergence.{k}': v for k, v in c['changes'].items()})
    found = twins() if c['converged'] is False and twins is not None else None
    if found is not None and all(t is not None and t.get('status') == 'ok' for t in found):
        sens = convergence.sensitivity(c, _pulse_figures(twin), *map(_pulse_figures, found))
        out[SENSITIVE] = ','.join(sens['sensitive'])
    return out


def convergence_report(rows, tolerance, keys=()):
    """One line: how many points passed the convergence check, the worst of those that did not,
    and how many of those are sensitive (``convergence.sensitive``)."""
    checked = [r for r in rows if r.get('converged') is not None]
    failed_rows = [r for r in checked if r['converged'] is False]
    line = (f'convergence (every step control refined, limit {100 * tolerance:g} %): '
            f'{len(checked) - len(failed_rows)} of {len(checked)} checked points converged')
    if failed_rows:
        def size(r):
            c = r.get('convergence.change')
            return math.inf if c is None else c
        worst = max(failed_rows, key=size)
        change = worst.get('convergence.change')
        moved = ('' if change is None else ' is found in one run only' if math.isinf(change)
                 else f' moves {100 * change:.3g} %')
        where = ', '.join(f'{k}={worst.get(k)}' for k in keys) or worst['point_id']
        line += (f'; {len(failed_rows)} not (column "converged"), worst at {where}: '
                 f'{worst["convergence.worst"]}{moved}')
        sensitive = [r for r in failed_rows if r.get(SENSITIVE)]
        if sensitive:
            line += (f'; {len(sensitive)} of them sensitive (column "{SENSITIVE}": those '
                     f'figures move past the limit when every impact velocity changes by '
                     f'{_parts()}, and no step size settles them: docs/physics.md section 7.1)')
    return line
