"""A lane group's intervals concluded at once (solver/simulate/lanebulk.py) give the rows of the
points run one at a time, bit for bit: the lean figures, the pulse momenta read at the frame
nearest T_REF, and a lane that fails a divergence check in the middle of a call (it alone
stops, at the single run's step and with its reason)."""
import json

import pytest

from solver.build.scene import Scene
from solver.simulate import lanebulk
from solver.simulate.batch import simulate_batch
from solver.simulate.runner import T_REF
from sweep_helpers import FB
from tensegrity_ros.studies.table import TIMING_FIELDS, flatten


def _row(bp):
    figures = None if bp.summary is None else {
        k: v for k, v in flatten(bp.summary).items() if k not in TIMING_FIELDS}
    return json.dumps({'status': bp.status, 'reason': bp.reason, 'figures': figures},
                      sort_keys=True, default=str)


@pytest.mark.parametrize('threads', [1, 2])
def test_intervals_concluded_at_once_give_the_single_runs_rows(monkeypatch, threads):
    scene = Scene.load(FB)
    t_end = T_REF + 0.1
    items = [(scene, [('loading.impact.v0', v), ('prestrain', p), ('run.t_end', t_end)])
             for v in (0.05, 0.3) for p in (0.001, 0.003)]
    # checks that fail after a few intervals: energy balance both ways, constraint error
    items += [(scene, [('loading.impact.v0', 0.3), ('divergence.energy_error', e),
                       ('run.t_end', t_end)]) for e in (1e-7, 1e-9)]
    items += [(scene, [('loading.impact.v0', 0.3), ('divergence.constraint_error', 1e-14),
                       ('run.t_end', t_end)])]
    at_once = []
    real = lanebulk.conclude

    def counted(*args):
        lean = real(*args)
        at_once.append(0 if lean is None else len(lean))
        return lean
    monkeypatch.setattr(lanebulk, 'conclude', counted)
    lanes = simulate_batch(items, threads=threads, base=False, lanes=True)
    single = simulate_batch(items, threads=1, base=False, lanes=False)
    assert [_row(a) for a in lanes] == [_row(b) for b in single]
    assert [b.status for b in single] == ['ok'] * 4 + ['diverged'] * 3
    assert {b.reason.split(': ')[1].split(' ')[0] for b in single[4:]} == {'energy',
                                                                           'constraint'}
    # every ok point's intervals were concluded at once (120 of 0.005 s), the failing ones'
    # up to the interval before their failure
    assert sum(at_once) >= 4 * round(t_end / 0.005) and max(at_once) > 1
    assert all(bp.summary.pulses[0].momentum_ratio == bp.summary.pulses[0].momentum_ratio
               for bp in single[:4])      # the momenta at T_REF were read (not NaN)
