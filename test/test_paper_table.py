"""The ``tensegrity paper`` table: speeds that are not a travelling pulse are marked, and every
column is explained by a legend line. Strain histories are built here from a prescribed peak
path, independently of the solver."""
import math

import numpy as np
import pytest

from solver.studies import paper
from solver.analysis.observables import first_passage

H0, N = 0.0062, 50
TIMES = np.arange(0.0, 0.6, 0.005)


def history(peak):
    """Strain (n_t, N) of a Gaussian compressive pulse whose peak is ``peak(t)`` prisms from the
    impacted end (prism N - 1); no pulse where ``peak(t)`` is None."""
    prisms = np.arange(N)[::-1]
    strain = np.zeros((len(TIMES), N))
    for k, t in enumerate(TIMES):
        p = peak(t)
        if p is not None:
            strain[k] = -0.05 * np.exp(-0.5 * ((prisms - p) / 0.8) ** 2)
    return strain


def classify(strain):
    p = first_passage(TIMES, strain, H0)
    n = paper.speed_points(strain)
    return p.speed_m_s, n, paper.speed_note(p.speed_m_s, n)


def test_a_travelling_pulse_keeps_its_speed():
    speed, n, note = classify(history(lambda t: 100.0 * t))      # 100 prisms/s outwards
    assert note == '' and speed == pytest.approx(100.0 * H0, rel=0.02)
    assert n == pytest.approx(30 / (100.0 * 0.005), abs=1)       # prisms 10-40 at 0.5/frame


def test_a_peak_moving_back_is_not_a_speed():
    # the peak appears at prism 35 and drifts back towards the impacted end
    speed, n, note = classify(history(lambda t: max(35.0 - 20.0 * t, 0.0) if t > 0 else None))
    assert speed < 0 and n >= paper.MIN_SPEED_POINTS and note == 'negative'


def test_a_peak_in_the_window_for_two_frames_is_not_a_speed():
    # a far precursor seen in two frames only, then gone
    speed, n, note = classify(history(lambda t: 12.0 + 400.0 * (t - 0.01)
                                      if 0.01 <= t <= 0.0151 else None))
    assert math.isfinite(speed) and n == 2 and note == 'few points'


def test_a_pulse_that_never_reaches_the_window_is_marked():
    speed, n, note = classify(history(lambda t: 3.0))
    assert math.isnan(speed) and n == 0 and note == 'no pulse'


def _row(label, speed, note):
    return paper.Row(variant={}, label=label, v0=0.1, amplitude=0.07, amplitude_median=0.01,
                     speed_m_s=speed, width_prisms=1, arrival_time_s=0.02, ke_fraction=1.0,
                     speed_points=3, speed_note=note)


def test_the_table_marks_the_speed_and_explains_every_column():
    result = {'rows': [_row('RB test back', -0.020, 'negative'),
                       _row('RB test few', 3.759, 'few points'),
                       _row('FB test ok', 0.254, '')], 'speed': {}}
    for markdown in (False, True):
        text = paper.format_table(result, markdown=markdown)
        lines = text.splitlines()
        back = next(line for line in lines if 'RB test back' in line)
        few = next(line for line in lines if 'RB test few' in line)
        ok = next(line for line in lines if 'FB test ok' in line)
        assert '(negative)' in back and '-0.020' not in back
        assert '(few points)' in few and '3.759' not in few
        assert '0.254' in ok and '(' not in ok
        head = lines[0].strip('| ').split(' | ') if markdown else lines[0].split('  ')
        columns = [c.strip() for c in head if c.strip()]
        legend = [line.lstrip('- ') for line in lines if ': ' in line and line[:1] != '|']
        for column in columns:                    # a legend line names every column
            assert any(column in line.split(': ', 1)[0] for line in legend), column
        for key in paper.SPEED_NOTES:             # and every mark
            assert f'({key})' in text.split('speed m/s: ', 1)[1]


def test_paper_set_applies_an_option_to_every_variant_and_names_it(monkeypatch):
    """``tensegrity paper --set KEY=VALUE``: the option reaches every variant's scene (the
    identified scenes excepted), is checked before anything runs, and the table says so."""
    from solver.studies import paper
    seen = []

    def fake_run(variant, v0, t_end=1.2, output_dt=0.005, sets=(), scenes=paper.SCENES):
        seen.append((variant.scene, list(sets)))
        from dataclasses import asdict
        return paper.Row(variant=asdict(variant), label=variant.label(), v0=v0, status='ok')
    monkeypatch.setattr(paper, 'run_variant', fake_run)
    monkeypatch.setattr(paper, 'speed_ratio', lambda **kw: {})
    result = paper.paper_table(v0s=(0.1,), models=('sym3d',),
                               sets=['structure.mass_placement=unit_bases'])
    assert seen and all(s == ['structure.mass_placement=unit_bases'] for _, s in seen)
    text = paper.format_table(result)
    assert text.splitlines()[0].endswith('structure.mass_placement=unit_bases')
    from tensegrity_ros.cli import main
    assert main(['paper', '--set', 'structure.nope=1']) == 2
