"""What a fit says it determined (tensegrity_ros.studies.fit_report), on objectives whose figures
are known functions of the free keys: the range over which the figures stay within the tolerance
against the range worked out by hand, a key no figure depends on, a bound hit."""
import math

import pytest

from tensegrity_ros.studies import fit_report
from tensegrity_ros.studies.fit import Case, Problem


class _Formula:
    """An objective's ``problem`` and ``evaluate_many``: figure ``f`` of one case is
    ``formula(a, b)`` of the free keys (no simulation)."""

    def __init__(self, formula, free):
        self.formula = formula
        self.problem = Problem(None, [Case({}, {'f': 1.0}, {'f': 1.0})], free, [], {})

    def evaluate_many(self, xs, threads=None):
        return [(None, None, [{'f': self.formula(*x)}], ['ok']) for x in xs]


FREE = [('a', 1.0, 3.0), ('b', 0.0, 10.0)]


def test_a_key_the_figures_depend_on_gets_the_range_of_the_tolerance_and_one_they_do_not_none():
    """f = a^2: within 1 % where |2 da / a| <= 0.01, i.e. a +- a / 200; b moves nothing."""
    obj = _Formula(lambda a, b: a * a, FREE)
    x = [2.0, 4.0]
    got = fit_report.determination(obj, x, [{'f': 4.0}])
    a, b = got
    assert a['range'] == pytest.approx([2.0 - 0.01, 2.0 + 0.01], rel=1e-4)
    assert a['half_width_rel'] == pytest.approx(0.005, rel=1e-4)
    assert a['elasticity'] == pytest.approx(2.0, rel=1e-4)       # d ln(a^2) / d ln a
    assert a['determined'] and a['at_bound'] is None and a['pinned_by'] == 'case 1 f'
    assert b['range'] == [0.0, 10.0] and not b['determined']
    text = '\n'.join(fit_report.format_lines(got))
    assert 'NOT determined' in text and text.count('NOT determined') == 1
    assert fit_report.bound_note(got) is None


def test_a_weak_dependence_gives_a_range_cut_at_the_bounds():
    """f = 1 + 1e-3 b: |1e-3 db / f| <= 0.01 allows db = +-10 (f = 1.005 at b = 5): the whole
    range 0..10."""
    obj = _Formula(lambda a, b: 1.0 + 1e-3 * b, FREE)
    got = fit_report.determination(obj, [2.0, 5.0], [{'f': 1.005}])
    assert got[1]['range'] == [0.0, 10.0] and not got[1]['determined']
    assert math.isclose(got[1]['elasticity'], 1e-3 * 5.0 / 1.005, rel_tol=1e-6)


def test_a_value_on_a_bound_is_flagged_in_one_line():
    obj = _Formula(lambda a, b: a * (1.0 + b), FREE)
    got = fit_report.determination(obj, [3.0, 0.0], [{'f': 3.0}])
    assert [e['at_bound'] for e in got] == ['upper', 'lower']
    note = fit_report.bound_note(got)
    assert '\n' not in note and 'a = 3 on its upper bound' in note
    assert 'b = 0 on its lower bound' in note and 'widen' in note
    # one-sided differences at the bound: f = a (1 + b) at b = 0 has d ln f / d ln a = 1
    assert got[0]['elasticity'] == pytest.approx(1.0, rel=1e-6)


def test_a_fit_that_ends_on_a_bound_says_so_in_one_line_and_in_its_json():
    """The paper's FB figures (p = 0.002 in the paper's reading) fitted with prestrain confined to
    0.0005..0.001: the best value is one of the two ends given on the command line."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    res = subprocess.run(
        [sys.executable, '-m', 'tensegrity_ros.cli', 'fit', 'config/scenes/fb_column.yaml',
         '--target', 'config/paper/fb_target.yaml', '--free', 'prestrain=0.0005:0.001',
         '--t-end', '0.55', '--popsize', '2', '--maxiter', '2', '--workers', '1', '--json'],
        cwd=root, env=dict(os.environ, PYTHONPATH=str(root)), capture_output=True, text=True,
        timeout=600)
    assert res.returncode == 0, res.stderr
    (line,) = res.stderr.strip().splitlines()
    (entry,) = json.loads(res.stdout)['free']
    end = {'lower': 0.0005, 'upper': 0.001}[entry['at_bound']]
    assert entry['value'] == pytest.approx(end, abs=1e-3 * 0.0005)
    assert line.startswith('tensegrity: the fit ended on a bound: prestrain = ')
    assert f"on its {entry['at_bound']} bound" in line and 'widen' in line
