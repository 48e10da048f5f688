"""Whether a run's pulse figures are converged: the same point run again with every step control
refined, and the relative change of each figure between the two.

    base = simulate(scene, overrides)
    refined = simulate(scene, overrides + refined_overrides(base.scene))
    check = compare(figures_of(base.summary), figures_of(refined.summary), tolerance=0.01)
    check['converged']          # False: some figure moved by more than 1 %

The energy ledger catches a step that loses or gains energy; it does not catch a figure that is
read off a part of the response the steps do not resolve (a phase error keeps the energy, and a
column struck at 1 m/s presses prisms flat onto their bases, where the strain ``(h - h0) / h``
magnifies every error of ``h``). Halving every step control and comparing is the check that does.

A figure that fails it may be under-resolved (finer steps settle it) or sensitive: after strong
impacts the response is chaotic (twin runs part exponentially, docs/physics.md section 7.1), and
a figure read late enough moves as much when the input changes in its seventh digit as when the
steps are halved; no step size settles it. :func:`sensitivity` tells the two apart from a twin
of the refined run with the impacts changed by :data:`PERTURBATION`, up and down:

    up, down = (figures_of(simulate(scene, overrides + refined_overrides(base.scene)
                                    + perturbed_overrides(base.scene, rel)).summary)
                for rel in (PERTURBATION, -PERTURBATION))
    check['sensitivity'] = sensitivity(check, figures_of(refined.summary), up, down)
"""
from __future__ import annotations

import math

from solver.build.scene import RANGES
from solver.simulate.results import json_safe
from solver.integrators import registry as integrators

# the figures a pulse is summarised by (solver.analysis.observables.Pulse): the tracked peak's
# and the front's at two stations
FIGURES = ('amplitude', 'amplitude_median', 'speed_m_s', 'speed_snapshot_m_s', 'front_speed_m_s',
           'front_amplitude')

# the default limit of the check (relative change of a figure): --convergence without TOL
TOLERANCE = 0.01

# the relative change of every impact velocity of the sensitivity twin: 0.1 um/s at 1 m/s, far
# below what any measured input is known to, far above the round-off of the figures
PERTURBATION = 1e-7


def refined_overrides(scene):
    """The overrides that refine every step control of ``scene`` (a loaded scene, its own
    overrides applied) by two: ``integrator.dt`` halved, ``integrator.rtol`` divided by 32 for an
    adaptive method (a fifth-order error estimate: 2^5), ``contact.resolution`` (steps per Hertz
    contact) doubled where bar contact is on. A list of ``(key, value)``."""
    it = scene.integrator
    out = [('integrator.dt', it.dt / 2.0)]
    if integrators.get(it.method).adaptive:
        out.append(('integrator.rtol', it.rtol / 32.0))
    contact = scene.contact
    if contact.bars != 'none' and 2 * contact.resolution <= RANGES['contact.resolution'][1]:
        out.append(('contact.resolution', 2 * contact.resolution))
    return out


def rung_overrides(scene, k):
    """The overrides of :func:`refined_overrides` applied ``k`` times to ``scene`` (rung ``k``
    of a refinement ladder: ``dt / 2^k``, ``contact.resolution x 2^k``, ``rtol / 32^k``); a
    list of ``(key, value)``, empty for ``k = 0``."""
    out = {}
    for _ in range(k):
        out.update(refined_overrides(scene.with_overrides(list(out.items()))))
    return list(out.items())


def perturbed_overrides(scene, rel=PERTURBATION):
    """The overrides that change every impact velocity of ``scene`` (loaded, its own overrides
    applied) by the factor ``1 + rel``: ``loading.impact.velocities`` for a train with its own
    velocities, else ``loading.impact.v0``. None when no impact has a velocity to change."""
    imp = scene.loading.impact
    if imp.velocities is not None:
        if not any(imp.velocities):
            return None
        return [('loading.impact.velocities', [v * (1.0 + rel) for v in imp.velocities])]
    if not imp.v0:
        return None
    return [('loading.impact.v0', imp.v0 * (1.0 + rel))]


def describe(refined):
    """``dt/2, contact.resolution x2``: the refinement as the messages name it."""
    names = {'integrator.dt': 'dt/2', 'integrator.rtol': 'rtol/32',
             'contact.resolution': 'contact.resolution x2'}
    return ', '.join(names.get(k, f'{k}={v}') for k, v in refined)


def figures_of(summary):
    """The figures :func:`compare` reads of a :class:`~solver.simulate.results.RunSummary`: per
    column, ``{figure: value}`` for each of :data:`FIGURES`, None where the pulse was not found
    (as in the summary's JSON)."""
    return [{k: v for k, v in json_safe(p.as_dict()).items() if k in FIGURES}
            for p in summary.pulses]


def relative_change(base, refined):
    """Relative change of one figure, against the larger of the two values; inf when only
    one run found it (a pulse seen at one step size and not at the other is not converged), None
    when neither did."""
    ok_b = base is not None and math.isfinite(base)
    ok_r = refined is not None and math.isfinite(refined)
    if not ok_b and not ok_r:
        return None
    if ok_b != ok_r:
        return math.inf
    if refined == base:
        return 0.0
    return abs(base - refined) / max(abs(refined), abs(base))


def check_tolerance(tolerance, name='--convergence', error=ValueError):
    """Raise ``error`` naming ``name`` unless ``tolerance`` (a relative change) is in (0, 1)."""
    if not 0.0 < tolerance < 1.0:
        raise error(f'{name}: {tolerance!r} must be in (0, 1)')


def check_figures(figures, name='--convergence-figures', error=ValueError):
    """``figures`` (names of :data:`FIGURES`, a comma-separated string or a sequence) as a tuple
    in :data:`FIGURES` order; ``error`` naming ``name`` and the unknown figure otherwise."""
    names = [f.strip() for f in figures.split(',')] if isinstance(figures, str) else list(figures)
    names = [f[len('pulse.'):] if f.startswith('pulse.') else f for f in names if f]
    if not names:
        raise error(f'{name}: no figure given (any of {", ".join(FIGURES)})')
    for f in names:
        if f not in FIGURES:
            raise error(f'{name}: unknown figure {f!r} (one of {", ".join(FIGURES)})')
    return tuple(f for f in FIGURES if f in names)


def compare(base, refined, tolerance=0.01, figures=None):
    """The convergence check of two runs' pulse figures (``base``, and ``refined`` of the same
    point with every step control refined; each a list per column of ``{figure: value}``,
    :func:`figures_of` of a run's summary, None or NaN where the pulse was not found): per
    figure of :data:`FIGURES` its largest relative change
    over the columns (``changes``; None where no run found it), the worst figure and whether every
    change is within ``tolerance`` (``converged``; None when neither run has a pulse). With
    ``figures`` (a subset of :data:`FIGURES`, :func:`check_figures`) only those decide ``worst``
    and ``converged``; ``changes`` still lists every figure, ``figures`` the ones checked."""
    check_tolerance(tolerance, 'convergence tolerance')
    checked = FIGURES if figures is None else check_figures(figures)
    pb, pr = list(base), list(refined)
    changes = {k: None for k in FIGURES}
    for i in range(max(len(pb), len(pr))):
        b = pb[i] if i < len(pb) else {}
        r = pr[i] if i < len(pr) else {}
        for k in FIGURES:
            c = relative_change(b.get(k), r.get(k))
            if c is not None and (changes[k] is None or c > changes[k]):
                changes[k] = c
    found = {k: c for k, c in changes.items() if c is not None and k in checked}
    worst = max(found, key=found.get) if found else None
    return {'tolerance': tolerance, 'changes': changes, 'worst': worst, 'figures': list(checked),
            'converged': None if worst is None else bool(found[worst] <= tolerance),
            'figures_refined': {k: (pr[0].get(k) if pr else None) for k in FIGURES}}


def sensitivity(check, refined, *twins, rel=PERTURBATION):
    """Which figures that failed ``check`` (:func:`compare`) are sensitive rather than
    under-resolved: ``refined`` is the pulse figures of the refined run (:func:`figures_of`),
    ``twins`` those of the same
    refined run with every impact velocity changed by the factor ``1 + rel`` (or ``1 - rel``:
    :func:`perturbed_overrides`). Per figure its largest relative change over the columns and
    the twins (``changes``), and ``sensitive``: the figures whose change under refinement and
    under the perturbation both exceed the tolerance (in :data:`FIGURES` order)."""
    tol = check['tolerance']
    moved = {k: None for k in FIGURES}
    for twin in twins:
        for k, c in compare(refined, twin, tol)['changes'].items():
            if c is not None and (moved[k] is None or c > moved[k]):
                moved[k] = c
    sensitive = [k for k in _checked(check) if check['changes'][k] is not None and
                 check['changes'][k] > tol and moved[k] is not None and moved[k] > tol]
    return {'perturbation': rel, 'changes': moved, 'sensitive': sensitive}


def _checked(check):
    """The figures ``check`` (:func:`compare`) judged."""
    return check.get('figures') or FIGURES


def jsonable(check):
    """``check`` (:func:`compare`, with its ``sensitivity``) for strict JSON: a change that is
    infinite (a figure found in one run only) becomes None and its figure is listed in
    ``found_in_one_run`` (of the check, or of its sensitivity)."""
    def clean(part):
        once = [k for k, c in part['changes'].items() if c is not None and math.isinf(c)]
        return dict(part, changes={k: None if k in once else c
                                   for k, c in part['changes'].items()},
                    found_in_one_run=once)
    out = clean(check)
    if out.get('sensitivity'):
        out['sensitivity'] = clean(out['sensitivity'])
    return out


def _moved(c):
    return 'is found in one run only' if math.isinf(c) else f'moves {100 * c:.3g} %'


def _parts(rel):
    """``1 part in 10^7`` for 1e-7."""
    return f'1 part in 10^{round(-math.log10(rel))}'


def failure(check, refined):
    """The one line that says a check failed (None when it did not): the figure, its change,
    the refinement and the limit. With ``check['sensitivity']`` (:func:`sensitivity`) it also
    names the figures that move by more than the limit when every impact velocity changes by
    :data:`PERTURBATION`: finer steps settle those only once their errors are far below that
    change (a chaotic response). A figure the twins leave in place may still be sensitive: two
    twins sample the response twice."""
    if check['converged'] is not False:
        return None
    tol = check['tolerance']
    sens = check.get('sensitivity')
    sensitive = sens['sensitive'] if sens else []
    failing = {k: c for k, c in check['changes'].items()
               if c is not None and c > tol and k in _checked(check)}
    unresolved = {k: c for k, c in failing.items() if k not in sensitive}
    chaotic = (f'the response is chaotic there (docs/physics.md section 7.1): finer steps settle '
               f'{", ".join(sensitive)} only once their errors are far below that change')
    if not unresolved:
        k = check['worst']
        return (f'pulse figures not determined: {k} {_moved(check["changes"][k])} when every '
                f'step control is refined ({describe(refined)}; limit {100 * tol:g} %) and '
                f'{_moved(sens["changes"][k])} when every impact velocity changes by '
                f'{_parts(sens["perturbation"])}: {chaotic}')
    k = max(unresolved, key=unresolved.get)
    line = (f'pulse figures not converged: {k} {_moved(unresolved[k])} when every step control '
            f'is refined ({describe(refined)}; limit {100 * tol:g} %); read it with a finer '
            f'integrator.dt and contact.resolution, and check again')
    if sensitive:
        return (f'{line}; {", ".join(sensitive)} also move(s) by more than the limit when every '
                f'impact velocity changes by {_parts(sens["perturbation"])}: {chaotic}')
    return (f'{line} (after strong impacts some figures settle at no step: docs/physics.md '
            f'section 7.1)')
