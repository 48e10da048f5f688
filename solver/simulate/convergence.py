"""Whether a run's pulse figures are converged: the same point run again with every step control
refined, and the relative change of each figure between the two.

    base = simulate(scene, overrides)
    refined = simulate(scene, overrides + refined_overrides(base.scene))
    check = compare(base.summary, refined.summary, tolerance=0.01)
    check['converged']          # False: some figure moved by more than 1 %

The energy ledger catches a step that loses or gains energy; it does not catch a figure that is
read off a part of the response the steps do not resolve (a phase error keeps the energy, and a
column struck at 1 m/s presses prisms flat onto their bases, where the strain ``(h - h0) / h``
magnifies every error of ``h``). Halving every step control and comparing is the check that does.
"""
from __future__ import annotations

import math

from solver.build.scene import RANGES
from solver.integrators import registry as integrators

# the figures a pulse is summarised by (solver.analysis.observables.Pulse)
FIGURES = ('amplitude', 'amplitude_median', 'speed_m_s', 'speed_snapshot_m_s')


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


def describe(refined):
    """``dt/2, contact.resolution x2``: the refinement as the messages name it."""
    names = {'integrator.dt': 'dt/2', 'integrator.rtol': 'rtol/32',
             'contact.resolution': 'contact.resolution x2'}
    return ', '.join(names.get(k, f'{k}={v}') for k, v in refined)


def _pulses(summary):
    pulses = summary.get('pulses') or []
    if not pulses and summary.get('pulse'):
        pulses = [summary['pulse']]
    return pulses


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


def compare(base, refined, tolerance=0.01):
    """The convergence check of two run summaries (``base``, and ``refined`` of the same point
    with every step control refined): per figure of :data:`FIGURES` its largest relative change
    over the columns (``changes``; None where no run found it), the worst figure and whether every
    change is within ``tolerance`` (``converged``; None when neither run has a pulse)."""
    check_tolerance(tolerance, 'convergence tolerance')
    pb, pr = _pulses(base), _pulses(refined)
    changes = {k: None for k in FIGURES}
    for i in range(max(len(pb), len(pr))):
        b = pb[i] if i < len(pb) else {}
        r = pr[i] if i < len(pr) else {}
        for k in FIGURES:
            c = relative_change(b.get(k), r.get(k))
            if c is not None and (changes[k] is None or c > changes[k]):
                changes[k] = c
    found = {k: c for k, c in changes.items() if c is not None}
    worst = max(found, key=found.get) if found else None
    return {'tolerance': tolerance, 'changes': changes, 'worst': worst,
            'converged': None if worst is None else bool(found[worst] <= tolerance),
            'figures_refined': {k: (pr[0].get(k) if pr else None) for k in FIGURES}}


def failure(check, refined):
    """The one line that says a check failed (None when it did not): the figure, its change,
    the refinement and the limit."""
    if check['converged'] is not False:
        return None
    k = check['worst']
    c = check['changes'][k]
    moved = 'is found in one run only' if math.isinf(c) else f'moves {100 * c:.3g} %'
    return (f'pulse figures not converged: {k} {moved} when every step control is refined '
            f'({describe(refined)}; limit {100 * check["tolerance"]:g} %); read it with a finer '
            f'integrator.dt and contact.resolution, and check again (after strong impacts some '
            f'figures settle at no step: docs/physics.md section 7.1)')
