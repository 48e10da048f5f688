"""Impact trains of a scene (``loading.impact.period``/``count`` or ``times``/``velocities``):
validation, the runner applying each impact at its step (between output frames too), the energy
ledger in the summary, and sweep rows over the period against ``tensegrity run --json``."""
import json
from pathlib import Path

import numpy as np
import pytest

from solver.build.scene import Scene, SceneError
from solver.simulate.array import simulation_for
from solver.simulate.runner import simulate
from tensegrity_ros import cli
from tensegrity_ros.studies import sweep as sw
from tensegrity_ros.studies import table

ROOT = Path(__file__).resolve().parents[1]
FB = str(ROOT / 'config' / 'scenes' / 'fb_column.yaml')
SHORT = ['structure.n_prisms=10', 'run.t_end=0.1']
TRAIN = SHORT + ['loading.impact.period=0.02', 'loading.impact.count=5']
TIMING = ('wall_time_s', 'real_time_factor')


def _figures(summary):
    return {k: v for k, v in summary.items() if k not in TIMING}


@pytest.fixture(scope='module')
def train():
    return simulate(FB, TRAIN)


def test_a_train_of_five_impacts_lands_on_its_times_and_balances(train):
    s = train.summary.to_json()
    assert [i['t_s'] for i in s['impacts']] == pytest.approx([0.0, 0.02, 0.04, 0.06, 0.08],
                                                             abs=1e-12)
    assert [i['v0_m_s'] for i in s['impacts']] == [0.1] * 5
    # the first impact hits the column at rest: the work of the scene's single impact
    single = simulate(FB, SHORT).summary.to_json()
    assert single['impacts'][0]['work_J'] == s['impacts'][0]['work_J'] > 0
    assert single['energy_work_J'] == pytest.approx(single['impacts'][0]['work_J'], rel=1e-12)
    assert sum(i['work_J'] for i in s['impacts']) == pytest.approx(s['energy_work_J'], rel=1e-12)
    assert s['energy_work_J'] > 3 * single['energy_work_J']         # the later kicks added
    assert 0 <= s['energy_balance_error'] < 1e-4
    assert s['bar_contact'] == 'hertz'
    rec = train.record
    assert len(rec.energy_balance_error) == len(rec.times) == 21        # frames on output_dt
    np.testing.assert_allclose(rec.times, np.arange(21) * 0.005, atol=1e-12)
    assert s['energy_balance_error'] == np.max(np.abs(rec.energy_balance_error))
    # the ledger closes: energy now = energy at rest + the work of the commands, within the error
    e_rest = rec.energy[0] - s['impacts'][0]['work_J']
    assert abs(rec.energy[-1] - e_rest - s['energy_work_J']) <= 1e-4 * rec.energy.max()


def test_the_same_train_as_times_and_velocities_gives_the_identical_summary(train):
    listed = simulate(FB, SHORT + ['loading.impact.times=[0, 0.02, 0.04, 0.06, 0.08]',
                                   'loading.impact.velocities=[0.1, 0.1, 0.1, 0.1, 0.1]'])
    assert _figures(listed.summary.to_json()) == _figures(train.summary.to_json())
    no_velocities = simulate(FB, SHORT + ['loading.impact.times=[0, 0.02, 0.04, 0.06, 0.08]'])
    assert _figures(no_velocities.summary.to_json()) == _figures(train.summary.to_json())


def test_impacts_between_frames_are_all_applied_on_the_step_grid():
    """Impacts every 1.25 ms (2 steps) against frames every 5 ms: every impact is applied at its
    step, and the end state is that of applying them by hand between plain advances."""
    sets = SHORT[:1] + ['run.t_end=0.02', 'loading.impact.period=0.00125',
                        'loading.impact.count=12']
    point = simulate(FB, sets)
    s = point.summary.to_json()
    dt = point.sim.dt
    assert dt == 6.25e-4
    assert [i['t_s'] for i in s['impacts']] == pytest.approx([2 * k * dt for k in range(12)],
                                                             abs=1e-12)
    np.testing.assert_allclose(point.record.times, np.arange(5) * 0.005, atol=1e-12)
    assert s['energy_balance_error'] < 1e-4
    sim = simulation_for(Scene.load(FB).with_overrides(sets))
    for k in range(12):
        sim.apply_impact(0.1)
        sim.advance(2 * dt)
    sim.advance(0.02 - 24 * dt)
    np.testing.assert_allclose(point.sim.frame().positions, sim.frame().positions, rtol=0,
                               atol=1e-13)
    assert sim.energy_work() == pytest.approx(s['energy_work_J'], rel=1e-12)


def test_times_round_to_the_step_grid_and_velocities_apply_in_order():
    s = simulate(FB, SHORT + ['loading.impact.times=[0.0101, 0.03]',
                              'loading.impact.velocities=[0.05, -0.02]']).summary.to_json()
    # 0.0101 s is step 16.16 of 0.625 ms: step 16, 0.01 s
    assert [(i['t_s'], i['v0_m_s']) for i in s['impacts']] == [
        pytest.approx((0.01, 0.05), abs=1e-12), pytest.approx((0.03, -0.02), abs=1e-12)]
    assert s['impacts'][0]['work_J'] > 0
    assert s['energy_balance_error'] < 1e-4


@pytest.mark.parametrize('sets,key', [
    (['loading.impact.count=0'], 'loading.impact.count'),
    (['loading.impact.count=3'], 'loading.impact.period'),                   # period 0
    (['loading.impact.period=-0.01'], 'loading.impact.period'),
    (['loading.impact.period=0.5', 'loading.impact.count=4'], 'loading.impact.period'),  # > t_end
    (['loading.impact.times=[0.02, 0.01]'], 'loading.impact.times'),         # not sorted
    (['loading.impact.times=[-0.01, 0.01]'], 'loading.impact.times'),
    (['loading.impact.times=[0, .nan]'], 'loading.impact.times'),
    (['loading.impact.times=[0, 2.0]'], 'loading.impact.times'),             # after t_end
    (['loading.impact.times=[]'], 'loading.impact.times'),
    (['loading.impact.times=0.01'], 'loading.impact.times'),
    (['loading.impact.times=[0, 0.01]', 'loading.impact.velocities=[0.1]'],
     'loading.impact.velocities'),                                           # lengths differ
    (['loading.impact.times=[0]', 'loading.impact.velocities=[11.0]'],
     'loading.impact.velocities'),
    (['loading.impact.velocities=[0.1]'], 'loading.impact.velocities'),     # without times
    (['loading.impact.times=[0, 0.01]', 'loading.impact.count=2',
      'loading.impact.period=0.01'], 'loading.impact.times'),               # both forms
])
def test_bad_train_keys_give_one_message_naming_the_key(sets, key):
    with pytest.raises(SceneError) as err:
        Scene.load(FB).with_overrides(['run.t_end=1.0'] + sets)
    text = str(err.value)
    assert text.startswith(f'{FB}: {key}:') or text.startswith(f'{key}:'), text
    assert '\n' not in text


def test_a_sweep_over_the_period_gives_the_rows_of_tensegrity_run(tmp_path, capsys):
    grid = ['loading.impact.period=0.01,0.02', 'loading.impact.count=3', 'structure.n_prisms=10']
    rows, n = sw.execute(sw.build(FB, grid, out=tmp_path, t_end=0.1))
    assert n == 2 and [r['status'] for r in rows] == ['ok', 'ok']
    for row, period in zip(rows, (0.01, 0.02)):
        capsys.readouterr()
        assert cli.main(['run', FB, '--set', 'structure.n_prisms=10', '--set',
                         f'loading.impact.period={period}', '--set', 'loading.impact.count=3',
                         '--t-end', '0.1', '--json']) == 0
        summary = json.loads(capsys.readouterr().out)
        assert row['loading.impact.period'] == period
        assert len(summary['impacts']) == 3
        for key in table.SUMMARY_FIELDS:
            if key not in table.TIMING_FIELDS:
                assert row[key] == summary[key], key
        for key, value in summary['pulse'].items():
            assert row[f'pulse.{key}'] == value, key
        assert 0 < row['energy_balance_error'] < 1e-4
    assert rows[0]['energy_balance_error'] != rows[1]['energy_balance_error']
