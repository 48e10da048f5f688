"""tensegrity sweep --convergence: each point run again with every step control refined, the
check in its row; against separate runs of the refined points and changes computed here."""
import json
import math
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from solver.build.scene import Scene
from solver.simulate.runner import simulate
from tensegrity_ros import cli
from tensegrity_ros.studies import sweep as sw

ROOT = Path(__file__).resolve().parents[1]
FB = str(ROOT / 'config' / 'scenes' / 'fb_column.yaml')
T_END = 0.55                     # past t_ref = 0.5 s: every pulse figure is defined
FIGS = ('amplitude', 'amplitude_median', 'speed_m_s', 'speed_snapshot_m_s', 'front_speed_m_s',
        'front_amplitude')


def _refined_summary(v0):
    """The refined twin of the FB point at ``v0``, run on its own: dt halved and the contact
    resolution doubled, written out here rather than taken from the code under test."""
    scene = Scene.load(FB)
    sets = [('loading.impact.v0', v0), ('run.t_end', T_END),
            ('integrator.dt', scene.integrator.dt / 2),
            ('contact.resolution', 2 * scene.contact.resolution)]
    return simulate(scene, sets).summary.to_json()


def _change(a, b):
    return 0.0 if a == b else abs(a - b) / max(abs(a), abs(b))


@pytest.fixture(scope='module')
def checked(tmp_path_factory):
    out = tmp_path_factory.mktemp('conv')
    sweep = sw.build(FB, ['loading.impact.v0=0.1,1'], out=out, t_end=T_END, convergence=0.01)
    rows, n = sw.execute(sweep, threads=1)
    return out, sweep, rows, n


def test_each_row_holds_the_change_against_a_separate_refined_run(checked):
    out, sweep, rows, n = checked
    assert n == 6                # two points, their refined twins, the failing one's two twins
    assert [r['loading.impact.v0'] for r in rows] == [0.1, 1.0]
    for row in rows:
        ref = _refined_summary(row['loading.impact.v0'])['pulse']
        changes = {k: _change(row[f'pulse.{k}'], ref[k]) for k in FIGS}
        for k in FIGS:
            assert row[f'convergence.{k}'] == pytest.approx(changes[k], rel=1e-9, abs=1e-15)
        worst = max(changes, key=changes.get)
        assert row['convergence.worst'] == worst
        assert row['converged'] is (changes[worst] <= 0.01)
        assert row['convergence.refined'] == 'dt/2, contact.resolution x2'
    # the paper's velocity converges, 1 m/s (prisms pressed onto their bases) does not
    assert rows[0]['converged'] is True and rows[1]['converged'] is False
    table = pq.read_table(out / 'results.parquet').to_pylist()
    assert len(table) == 2                        # the twins run, but the table has the points
    assert [t['converged'] for t in table] == [True, False]
    assert len((out / 'rows.jsonl').read_text().splitlines()) == 6


def _refined(scene_path, v0, t_end):
    scene = Scene.load(scene_path)
    sets = [('loading.impact.v0', v0), ('run.t_end', t_end),
            ('integrator.dt', scene.integrator.dt / 2),
            ('contact.resolution', 2 * scene.contact.resolution)]
    return simulate(scene, sets).summary.to_json()['pulse']


def _sensitive_by_hand(row, scene_path, v0, t_end):
    """The failing figures of ``row`` that also move past 1 % between the refined run and its
    twins at v0 x (1 +- 1e-7), from refined runs made here."""
    refined = _refined(scene_path, v0, t_end)
    moved = {k: 0.0 for k in FIGS}
    for v in (v0 * (1.0 + 1e-7), v0 * (1.0 - 1e-7)):
        twin = _refined(scene_path, v, t_end)
        for k in FIGS:
            a, b = refined[k], twin[k]
            if a is None and b is None:
                continue
            moved[k] = max(moved[k], math.inf if (a is None) != (b is None) else _change(a, b))
    failing = [k for k in FIGS if row[f'convergence.{k}'] is not None
               and row[f'convergence.{k}'] > 0.01]
    return failing, [k for k in failing if moved[k] > 0.01]


def test_a_failed_point_names_the_figures_its_sensitivity_twins_move_past_the_limit(checked):
    """The point that failed (FB at 1 m/s) ran its refined twin twice more with v0 x (1 +- 1e-7):
    its ``convergence.sensitive`` lists the failing figures that move by more than the limit
    under that change too, recomputed here from separate refined runs (none at 0.55 s: the twins
    part later); the point that passed has none, and ran no twin."""
    out, sweep, rows, n = checked
    assert rows[0]['convergence.sensitive'] is None
    failing, want = _sensitive_by_hand(rows[1], FB, 1.0, T_END)
    assert failing and rows[1]['convergence.sensitive'] == ','.join(want)
    table = pq.read_table(out / 'results.parquet').to_pylist()
    assert table[1]['convergence.sensitive'] == rows[1]['convergence.sensitive']


def test_a_chaotic_point_is_named_sensitive(tmp_path, capsys):
    """RB at 1 m/s over 1 s (twins part in about 20 ms, docs/physics.md section 7.1): the failing
    figures its sensitivity twins also move are named, as separate refined runs give them, and
    the command's line counts the point as sensitive."""
    rb = str(ROOT / 'config' / 'scenes' / 'rb_column.yaml')
    out = tmp_path / 'rb'
    assert cli.main(['sweep', rb, '--grid', 'loading.impact.v0=1', '--t-end', '1',
                     '--convergence', '--workers', '1', '--out', str(out)]) == 0
    text = capsys.readouterr().out
    row = pq.read_table(out / 'results.parquet').to_pylist()[0]
    assert row['converged'] is False
    failing, want = _sensitive_by_hand(row, rb, 1.0, 1.0)
    assert want, 'this point was chosen for figures the twins move'
    assert row['convergence.sensitive'] == ','.join(want)
    assert '1 points, 4 runs with the refined and sensitivity twins (4 run now' in text
    assert '1 of them sensitive (column "convergence.sensitive"' in text


def test_a_rerun_runs_nothing_and_a_plain_sweep_then_checked_runs_only_the_twins(checked,
                                                                                tmp_path):
    out, sweep, rows, _ = checked
    again, n = sw.execute(sw.build(FB, ['loading.impact.v0=0.1,1'], out=out, t_end=T_END,
                                   convergence=0.01))
    assert n == 0 and again == rows
    plain = sw.build(FB, ['loading.impact.v0=0.1'], out=tmp_path, t_end=T_END)
    first, n = sw.execute(plain, threads=1)
    assert n == 1 and 'converged' not in first[0]
    later, n = sw.execute(sw.build(FB, ['loading.impact.v0=0.1'], out=tmp_path, t_end=T_END,
                                   convergence=0.01), threads=1)
    assert n == 1 and later[0]['converged'] is True
    assert later[0]['pulse.amplitude'] == first[0]['pulse.amplitude']


def test_the_command_reports_the_points_that_did_not_converge(tmp_path, capsys):
    out = tmp_path / 'cmd'
    assert cli.main(['sweep', FB, '--grid', 'loading.impact.v0=0.1,1', '--t-end', str(T_END),
                     '--convergence', '--workers', '1', '--out', str(out),
                     '--plot', 'convergence.change']) == 0
    text = capsys.readouterr().out
    assert ('2 points, 6 runs with the refined and sensitivity twins (6 run now, 0 already'
            in text)
    assert '1 of 2 checked points converged; 1 not' in text
    # the worst point and figure named are the table's: the row at 1 m/s, its worst figure
    rows = pq.read_table(out / 'results.parquet').to_pylist()
    worst = max((r for r in rows if r['converged'] is False),
                key=lambda r: r['convergence.change'])
    assert worst['loading.impact.v0'] == 1.0 and worst['convergence.worst'] in FIGS
    assert (f"worst at loading.impact.v0=1: {worst['convergence.worst']} moves "
            f"{100 * worst['convergence.change']:.3g} %") in text
    assert (out / 'convergence.change.png').stat().st_size > 0


@pytest.mark.parametrize('args, needle', [
    (['--convergence', '1.5'], '--convergence: 1.5 must be in (0, 1)'),
    (['--plot', 'convergence.change'], '--plot convergence.change: unknown figure'),
])
def test_bad_convergence_input_is_one_line_exit_2_and_runs_nothing(args, needle, tmp_path,
                                                                   capsys):
    out = tmp_path / 'out'
    capsys.readouterr()
    assert cli.main(['sweep', FB, '--grid', 'prestrain=0.002', *args, '--out', str(out),
                     '--workers', '1']) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count('\n') == 1
    assert not out.exists()


def test_a_twin_that_did_not_run_ok_fails_the_check_and_a_failed_point_has_none():
    row = {'status': 'ok', **{f'pulse.{k}': 1.0 for k in FIGS}}
    refined = {'integrator.dt': 1e-4}          # where the twin differs from the point
    cols = sw.convergence_columns(row, {'status': 'diverged'}, 0.01, refined)
    assert cols['converged'] is False and cols['convergence.worst'] == 'refined run diverged'
    assert cols['convergence.refined'] == 'dt/2'
    assert sw.convergence_columns({'status': 'error'}, row, 0.01, refined)['converged'] is None
    assert sw.convergence_columns(row, None, 0.01, refined)['converged'] is None
    # a figure one run found and the other did not is not converged
    twin = dict(row, **{'pulse.speed_m_s': None})
    cols = sw.convergence_columns(row, twin, 0.01, refined)
    assert cols['converged'] is False and math.isinf(cols['convergence.speed_m_s'])
    json.dumps(cols)


def test_fit_convergence_checks_the_best_point_against_separate_refined_runs(tmp_path, capsys):
    target = tmp_path / 'target.yaml'
    target.write_text('cases:\n'
                      '  - {set: {loading.impact.v0: 0.1}, figures: {pulse.amplitude: 0.15}}\n'
                      '  - {set: {loading.impact.v0: 1.5}, figures: {pulse.amplitude: 2.0}}\n')
    args = ['fit', FB, '--target', str(target), '--free', 'prestrain=0.0019:0.0021',
            '--popsize', '1', '--maxiter', '1', '--no-polish', '--t-end', str(T_END),
            '--workers', '1', '--convergence', '--json']
    capsys.readouterr()
    assert cli.main(args) == 1
    captured = capsys.readouterr()
    result = json.loads(captured.out)
    err = captured.err
    assert err.count('\n') == 1
    assert 'fitted figures not converged: case 2 pulse.amplitude moves' in err
    check = result['convergence']
    scene = Scene.load(FB)
    for i, v0 in enumerate((0.1, 1.5)):
        sets = [('loading.impact.v0', v0), ('prestrain', result['best']['prestrain']),
                ('run.t_end', T_END)]
        base = simulate(scene, sets).summary.to_json()['pulse']['amplitude']
        ref = simulate(scene, sets + [('integrator.dt', scene.integrator.dt / 2),
                                      ('contact.resolution', 2 * scene.contact.resolution)]
                       ).summary.to_json()['pulse']['amplitude']
        assert result['cases'][i]['figures']['pulse.amplitude']['simulated'] == base
        assert check['cases'][i]['changes']['pulse.amplitude'] == pytest.approx(
            _change(base, ref), rel=1e-9, abs=1e-15)
    assert [c['converged'] for c in check['cases']] == [True, False]
    assert check['converged'] is False and check['worst']['case'] == 2


def test_a_sweep_judging_the_front_only_converges_at_1_m_s(tmp_path):
    """--convergence-figures in a sweep: the FB point at 1 m/s, whose tracked peak fails the
    check (above), passes on the front figures; its row still holds every change."""
    sweep = sw.build(FB, ['loading.impact.v0=1'], out=tmp_path, t_end=T_END,
                     convergence_figures='front_speed_m_s,front_amplitude')
    assert sweep.convergence == 0.01
    rows, n = sw.execute(sweep, threads=1)
    assert n == 2 and rows[0]['converged'] is True
    assert rows[0]['convergence.worst'] in ('front_speed_m_s', 'front_amplitude')
    assert rows[0]['convergence.amplitude_median'] > 0.01
    with pytest.raises(sw.SweepError, match="unknown figure 'x'"):
        sw.build(FB, ['loading.impact.v0=1'], out=tmp_path, convergence_figures='x')
