"""``tensegrity run --convergence``: the point run again with every step control refined, and a
run whose pulse figures move by more than the tolerance exits 1 with one line naming the figure."""
import json
import math
from pathlib import Path

import pytest

from solver.build.scene import Scene
from solver.simulate import convergence
from solver.simulate.runner import simulate

SCENES = Path(__file__).resolve().parents[1] / 'config' / 'scenes'
FB = str(SCENES / 'fb_column.yaml')


def _summary(*pulses):
    """The figures compare reads of a run with these columns' pulses."""
    return list(pulses)


def _pulse(amplitude, median, speed, snapshot):
    return {'amplitude': amplitude, 'amplitude_median': median, 'speed_m_s': speed,
            'speed_snapshot_m_s': snapshot}


def test_compare_takes_the_largest_change_over_columns_against_the_larger_value():
    base = _summary(_pulse(0.150, 0.148, 0.250, None), _pulse(0.100, 0.100, 0.240, None))
    refined = _summary(_pulse(0.151, 0.148, 0.250, None), _pulse(0.100, 0.098, 0.246, None))
    check = convergence.compare(base, refined, tolerance=0.01)
    assert check['changes']['amplitude'] == pytest.approx(0.001 / 0.151)
    assert check['changes']['amplitude_median'] == pytest.approx(0.002 / 0.100)
    assert check['changes']['speed_m_s'] == pytest.approx(0.006 / 0.246)
    assert check['changes']['speed_snapshot_m_s'] is None          # neither run has it
    assert check['worst'] == 'speed_m_s' and check['converged'] is False
    assert convergence.compare(base, refined, tolerance=0.05)['converged'] is True
    line = convergence.failure(check, [('integrator.dt', 1e-4)])
    assert 'speed_m_s moves 2.44 %' in line and 'dt/2' in line and 'limit 1 %' in line


def test_a_check_on_chosen_figures_judges_those_and_lists_every_change():
    base = _summary(_pulse(0.150, 0.148, 0.250, None))
    refined = _summary(_pulse(0.151, 0.148, 0.256, None))
    check = convergence.compare(base, refined, 0.01, figures=('amplitude',))
    assert check['figures'] == ['amplitude'] and check['worst'] == 'amplitude'
    assert check['converged'] is True and convergence.failure(check, []) is None
    assert check['changes']['speed_m_s'] == pytest.approx(0.006 / 0.256)   # listed, not judged
    assert convergence.compare(base, refined, 0.01)['converged'] is False
    assert convergence.check_figures('pulse.front_speed_m_s, amplitude') == (
        'amplitude', 'front_speed_m_s')
    with pytest.raises(ValueError, match="unknown figure 'speed'"):
        convergence.check_figures('amplitude,speed')
    with pytest.raises(ValueError, match='no figure given'):
        convergence.check_figures(' , ')


def test_a_figure_found_in_one_run_only_is_not_converged():
    check = convergence.compare(_summary(_pulse(0.1, 0.1, None, 0.2)),
                                _summary(_pulse(0.1, 0.1, 0.25, 0.2)))
    assert math.isinf(check['changes']['speed_m_s']) and check['converged'] is False
    assert 'speed_m_s is found in one run only' in convergence.failure(check, [])
    nothing = convergence.compare(_summary(), _summary())
    assert nothing['converged'] is None and convergence.failure(nothing, []) is None
    with pytest.raises(ValueError, match='tolerance'):
        convergence.compare(_summary(), _summary(), tolerance=1.5)


def test_refined_overrides_halve_every_step_control_the_scene_uses():
    fb = Scene.load(FB)
    assert convergence.refined_overrides(fb) == [
        ('integrator.dt', fb.integrator.dt / 2), ('contact.resolution',
                                                  2 * fb.contact.resolution)]
    lines = fb.with_overrides([('contact.bars', 'none')])
    assert convergence.refined_overrides(lines) == [('integrator.dt', fb.integrator.dt / 2)]
    dopri = fb.with_overrides([('integrator.method', 'dopri54_projected'),
                               ('integrator.rtol', 1e-6)])
    assert ('integrator.rtol', 1e-6 / 32) in convergence.refined_overrides(dopri)


def _main(capsys, *args):
    from tensegrity_ros import cli
    capsys.readouterr()
    code = cli.main(['run', *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_the_paper_regime_is_converged_and_the_check_is_the_refined_run(capsys):
    """FB column at 0.1 m/s: every figure moves by far less than 1 % (exit 0); the refined figures
    are those of the same point run separately with dt halved and the contact resolution
    doubled."""
    code, out, err = _main(capsys, FB, '--v0', '0.1', '--t-end', '0.6', '--convergence',
                           '--json')
    assert code == 0, err
    check = json.loads(out)['convergence']
    assert check['converged'] is True and check['tolerance'] == 0.01
    assert all(c is not None and c < 1e-3 for c in check['changes'].values())
    fb = Scene.load(FB)
    assert check['refined'] == {'integrator.dt': fb.integrator.dt / 2,
                                'contact.resolution': 2 * fb.contact.resolution}
    twin = simulate(FB, [('loading.impact.v0', 0.1), ('run.t_end', 0.6),
                         ('integrator.dt', fb.integrator.dt / 2),
                         ('contact.resolution', 2 * fb.contact.resolution)])
    assert check['figures_refined'] == {k: twin.summary.to_json()['pulse'][k]
                                        for k in convergence.FIGURES}
    code, out, _ = _main(capsys, FB, '--v0', '0.1', '--t-end', '0.6', '--convergence')
    assert code == 0 and 'convergence (dt/2, contact.resolution x2)' in out
    assert ': converged (limit 1 %)' in out


def test_a_column_struck_at_1_m_s_is_not_converged_and_exits_1(capsys):
    """FB column at 1 m/s: the energy balance holds (the run alone exits 0), but prisms pressed
    flat onto their bases give an amplitude that moves by tens of percent when the steps are
    refined: with --convergence the run exits 1, with one line naming the figure, and the JSON
    still carries the check."""
    code, out, err = _main(capsys, FB, '--v0', '1', '--t-end', '0.6', '--json')
    assert code == 0 and json.loads(out)['energy_balance_error'] < 1e-4
    code, out, err = _main(capsys, FB, '--v0', '1', '--t-end', '0.6', '--convergence',
                           '--json')
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and 'pulse figures not converged' in lines[0], err
    check = json.loads(out)['convergence']
    assert check['converged'] is False and check['changes'][check['worst']] > 0.01
    assert check['worst'] in lines[0]


def test_at_1_m_s_the_front_figures_pass_the_check_the_tracked_peak_fails(capsys):
    """--convergence-figures judges the front only (and implies --convergence): the same FB
    point at 1 m/s exits 0, its JSON still lists the tracked peak's changes past the limit."""
    code, out, err = _main(capsys, FB, '--v0', '1', '--t-end', '0.6', '--convergence-figures',
                           'front_speed_m_s,front_amplitude', '--json')
    assert code == 0, err
    check = json.loads(out)['convergence']
    assert check['figures'] == ['front_speed_m_s', 'front_amplitude']
    assert check['converged'] is True and check['tolerance'] == 0.01
    assert all(check['changes'][k] < 0.01 for k in check['figures'])
    assert check['changes']['amplitude_median'] > 0.01
    code, out, err = _main(capsys, FB, '--t-end', '0.6', '--convergence-figures', 'front_sped')
    assert code == 2 and out == ''
    assert err.strip().splitlines() == [
        "tensegrity: --convergence-figures: unknown figure 'front_sped' (one of "
        + ', '.join(convergence.FIGURES) + ')']


def test_a_bad_tolerance_is_one_line_and_runs_nothing(capsys):
    code, out, err = _main(capsys, FB, '--t-end', '0.6', '--convergence', '2')
    assert code == 2 and out == ''
    assert err.strip().splitlines() == ["tensegrity: --convergence: 2.0 must be in (0, 1)"]


def test_the_refined_run_stops_when_told():
    """The main run failed or was interrupted: the refined run ends after its current interval,
    raising instead of running on to t_end (nothing keeps the process waiting for it)."""
    import argparse
    import time
    from tensegrity_ros.commands import run
    args = argparse.Namespace(scene=FB, set=[], v0=1.0, prestrain=None, t_end=5.0,
                              convergence=0.01)
    refined, future, stop = run._refined_run(args)
    time.sleep(0.5)
    stop.set()
    with pytest.raises(run._Stopped):
        future.result()


def test_the_trains_bench_ladder_refines_every_step_control_each_rung(tmp_path):
    """``bench.trains.convergence``: rung k is the point with dt / 2^k and contact.resolution x
    2^k (compared with runs given those values by hand), and each step of the ladder is the
    relative change of ``run --convergence`` between consecutive rungs; the change under v0 +1e-9
    at the finest rung is that of a run given those steps by hand."""
    from bench import trains
    rb = str(SCENES / 'rb_column.yaml')
    scene = Scene.load(rb)
    c = trains.convergence('rb_column', 0.3, t_end=0.3, levels=2, perturbations=1)
    assert len(c['ladder']) == 3 and len(c['steps']) == 2
    for k, rung in enumerate(c['ladder']):
        assert rung['dt'] == scene.integrator.dt / 2 ** k
        assert rung['resolution'] == scene.contact.resolution * 2 ** k
        hand = simulate(rb, ['loading.impact.v0=0.3', 'run.t_end=0.3',
                             f'integrator.dt={scene.integrator.dt / 2 ** k}',
                             f'contact.resolution={scene.contact.resolution * 2 ** k}'])
        pulse = hand.summary.to_json()['pulse']
        assert rung['figures'] == {f: pulse[f] for f in convergence.FIGURES}
        assert rung['steps_taken'] == hand.summary.to_json()['steps_taken']
    for k, step in enumerate(c['steps']):
        a, b = c['ladder'][k]['figures'], c['ladder'][k + 1]['figures']
        for f in convergence.FIGURES:
            assert step[f] == convergence.relative_change(a[f], b[f])
    assert c['steps'][0]['speed_m_s'] is not None and c['steps'][0]['speed_m_s'] < 0.01
    # the sensitivity to v0 at the finest rung's steps: the same figures of a run given them
    moved = simulate(rb, [f'loading.impact.v0={0.3 * (1 + 1e-9)}', 'run.t_end=0.3',
                          f'integrator.dt={scene.integrator.dt / 4}',
                          f'contact.resolution={scene.contact.resolution * 4}']
                     ).summary.to_json()['pulse']
    for f in convergence.FIGURES:
        assert c['conditioning_finest'][f] == convergence.relative_change(
            moved[f], c['ladder'][-1]['figures'][f])
    trains.plot_convergence([c], tmp_path / 'ladder.png')
    assert (tmp_path / 'ladder.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
