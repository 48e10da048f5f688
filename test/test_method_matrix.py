"""Every integration method, picked as a user picks it (``--set integrator=NAME``), on both
default columns at 0.1 and 1 m/s (issue 50): it runs to the scene's end within the energy ledger,
or it is refused with one message whose hint names only methods that run all four cases."""
import re
from pathlib import Path

from solver.build.scene import SceneError
from solver.integrators.registry import METHODS
from solver.simulate.runner import simulate

ROOT = Path(__file__).resolve().parents[1]
COLUMNS = ('fb_column', 'rb_column')
SPEEDS = (0.1, 1.0)


def _named(text, subject):
    """The methods a refusal's text recommends: every name of METHODS in it, the refused
    method's own name (the subject the message starts with) left out."""
    body = text.split(':', 1)[1] if text.split(':', 1)[0].endswith(subject) else text
    return {m for m in METHODS if re.search(rf'(?<![\w.]){re.escape(m)}(?![\w])', body)}


def _outcome(method, column, v0):
    """('ran', balance error, its limit), ('refused', message) or ('diverged', message)."""
    from solver.simulate.simulation import SimulationDiverged
    try:
        point = simulate(ROOT / 'config' / 'scenes' / f'{column}.yaml',
                         [f'integrator={method}', f'loading.impact.v0={v0}'])
    except SimulationDiverged as exc:
        return ('diverged', str(exc))
    except (SceneError, ValueError) as exc:
        return ('refused', str(exc))
    return ('ran', point.summary.energy_balance_error, point.scene.divergence.energy_error)


def test_every_method_runs_the_default_columns_or_is_refused_naming_ones_that_do():
    """The full runs (1.2 s: rk4's drift reaches its limit late in the run at too large a step,
    so a shortened run would not tell)."""
    outcomes = {(m, c, v): _outcome(m, c, v) for m in METHODS for c in COLUMNS for v in SPEEDS}
    diverged = {k: o[1] for k, o in outcomes.items() if o[0] == 'diverged'}
    assert not diverged, diverged
    for key, o in outcomes.items():
        if o[0] == 'ran':
            assert abs(o[1]) <= o[2], (key, o)
    running = {m for m in METHODS
               if all(outcomes[m, c, v][0] == 'ran' for c in COLUMNS for v in SPEEDS)}
    assert 'rk4_projected' in running and len(running) >= 2
    for m in METHODS:
        kinds = {outcomes[m, c, v][0] for c in COLUMNS for v in SPEEDS}
        if m in running:
            continue
        assert 'refused' in kinds, (m, kinds)
        for c in COLUMNS:
            for v in SPEEDS:
                kind, *rest = outcomes[m, c, v]
                if kind != 'refused':
                    continue
                text = rest[0]
                assert '\n' not in text and len(text) < 400, text
                named = _named(text, m)
                assert named, text                   # it says what to use instead
                assert named <= running, (m, named - running, text)
