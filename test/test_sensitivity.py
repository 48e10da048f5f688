"""Sensitive figures: ``run --convergence``'s twin with the impact velocities changed by one part
in 10^7 (``solver.simulate.convergence.sensitivity``), the check's strict JSON, and the twin runs
of ``bench.twins`` (how fast a response magnifies a change of its input)."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from solver.build.scene import Scene
from solver.simulate import convergence
from solver.simulate.runner import simulate

SCENES = Path(__file__).resolve().parents[1] / 'config' / 'scenes'
FB = str(SCENES / 'fb_column.yaml')


def _summary(amplitude, median, speed, snapshot):
    pulse = {'amplitude': amplitude, 'amplitude_median': median, 'speed_m_s': speed,
             'speed_snapshot_m_s': snapshot}
    return [pulse]              # the figures compare reads of a one-column run


def _main(capsys, *args):
    from tensegrity_ros import cli
    capsys.readouterr()
    code = cli.main(['run', *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_perturbed_overrides_change_every_impact_velocity_by_the_factor():
    fb = Scene.load(FB)
    assert convergence.perturbed_overrides(fb, 1e-7) == [
        ('loading.impact.v0', fb.loading.impact.v0 * (1 + 1e-7))]
    train = fb.with_overrides([('run.t_end', 0.3), ('loading.impact.times', [0.0, 0.1]),
                               ('loading.impact.velocities', [0.1, 0.2])])
    assert convergence.perturbed_overrides(train, 1e-7) == [
        ('loading.impact.velocities', [0.1 * (1 + 1e-7), 0.2 * (1 + 1e-7)])]
    assert convergence.perturbed_overrides(fb.with_overrides([('loading.impact.v0', 0.0)])) \
        is None


def test_only_failing_figures_that_move_under_the_perturbation_too_are_sensitive():
    base = _summary(1.00, 0.50, 0.20, 0.30)
    refined = _summary(1.10, 0.50, 0.25, 0.30)        # amplitude and speed fail at 1 %
    check = convergence.compare(base, refined, 0.01)
    twin = _summary(1.10, 0.60, 0.30, 0.30)           # the median moves but did not fail
    sens = convergence.sensitivity(check, refined, twin)
    assert sens['perturbation'] == convergence.PERTURBATION
    assert sens['changes']['speed_m_s'] == pytest.approx(0.05 / 0.30)
    assert sens['changes']['amplitude'] == 0.0
    assert sens['sensitive'] == ['speed_m_s']
    check['sensitivity'] = sens
    line = convergence.failure(check, [('integrator.dt', 1e-4)])
    # the under-resolved amplitude is named first, the sensitive speed after it
    assert line.startswith('pulse figures not converged: amplitude moves 9.09 %')
    assert 'speed_m_s also move(s) by more than the limit' in line
    assert '1 part in 10^7' in line and 'chaotic' in line
    # every failing figure sensitive: not determined, no advice to refine
    check['sensitivity'] = convergence.sensitivity(check, refined, _summary(1.3, 0.5, 0.3, 0.3))
    line = convergence.failure(check, [('integrator.dt', 1e-4)])
    assert line.startswith('pulse figures not determined: speed_m_s moves 20 % when every step '
                           'control is refined (dt/2; limit 1 %)')
    assert 'moves 16.7 % when every impact velocity changes by 1 part in 10^7' in line
    assert 'settle amplitude, speed_m_s only once' in line
    assert 'finer integrator.dt' not in line


def test_a_figure_found_in_one_run_only_is_strict_json(capsys, monkeypatch):
    """A figure found in one run only has an infinite change: the JSON gets null and names it
    in ``found_in_one_run`` (the check and its sensitivity twin), and the run exits 1."""
    compare = convergence.compare

    def one_run_only(base, refined, tolerance=0.01, figures=None):
        check = compare(base, refined, tolerance, figures)
        check['changes']['speed_m_s'] = math.inf
        check.update(worst='speed_m_s', converged=False)
        return check
    monkeypatch.setattr(convergence, 'compare', one_run_only)
    code, out, err = _main(capsys, FB, '--v0', '0.1', '--t-end', '0.3', '--convergence',
                           '--json')
    assert code == 1
    assert err.strip().splitlines() == [err.strip()] and 'speed_m_s is found in one run' in err
    check = json.loads(out)['convergence']
    assert check['found_in_one_run'] == ['speed_m_s'] and check['changes']['speed_m_s'] is None
    assert check['sensitivity']['found_in_one_run'] == ['speed_m_s']
    code, out, _ = _main(capsys, FB, '--v0', '0.1', '--t-end', '0.3', '--convergence')
    assert 'speed_m_s found in one run only' in out and 'sensitivity (impact velocities' in out


def test_the_sensitivity_twins_are_the_refined_run_with_v0_changed(capsys):
    """FB at 1 m/s fails the check; its sensitivity twins' changes are the larger of those
    between runs given the refined steps by hand, at v0 and at v0 (1 +- 1e-7)."""
    code, out, err = _main(capsys, FB, '--v0', '1', '--t-end', '0.6', '--convergence',
                           '--json')
    assert code == 1
    check = json.loads(out)['convergence']
    sens = check['sensitivity']
    assert sens['perturbation'] == 1e-7
    fb = Scene.load(FB)
    steps = [('run.t_end', 0.6), ('integrator.dt', fb.integrator.dt / 2),
             ('contact.resolution', 2 * fb.contact.resolution)]
    refined = simulate(FB, [('loading.impact.v0', 1.0)] + steps).summary.to_json()
    up, down = (simulate(FB, [('loading.impact.v0', 1.0 * (1 + r))] + steps).summary.to_json()
                for r in (1e-7, -1e-7))
    for k in convergence.FIGURES:
        assert sens['changes'][k] == max(
            convergence.relative_change(refined['pulse'][k], twin['pulse'][k])
            for twin in (up, down))
    assert sens['sensitive'] == [k for k in convergence.FIGURES
                                 if check['changes'][k] > 0.01 and sens['changes'][k] > 0.01]


def test_the_growth_rate_of_an_exponential_separation_is_its_exponent():
    """``bench.twins.efold_rate`` of ``d = 1e-12 exp(20 t)``, saturating at 1e-3 m: 20 /s, read
    from 0.1 s to where it passes 1e-4 m; the same through an oscillation (the running maximum);
    a linear growth: ``ln(t1 / t0) / (t1 - t0)``."""
    from bench import twins
    t = np.arange(1, 201) * 0.005
    d = np.minimum(1e-12 * np.exp(20.0 * t), 1e-3)
    assert twins.efold_rate(t, d) == pytest.approx(20.0, rel=1e-9)
    wobbly = d * (1.0 + 0.5 * np.sin(2 * np.pi * t / 0.005 / 2) ** 2 * (t > 0.1) * (t < 0.5))
    assert twins.efold_rate(t, wobbly) == pytest.approx(20.0, rel=0.05)
    assert twins.efold_rate(t, 1e-9 * t) == pytest.approx(math.log(1.0 / 0.1) / 0.9)
    assert twins.efold_rate(t, np.full_like(t, 1.0)) is None       # saturated throughout
    assert twins.at({'times': list(t), 'separation_m': list(d)}, 0.5) == d[99]


def test_twin_runs_are_two_runs_apart_by_the_perturbation(tmp_path):
    """``bench.twins.twins``: the separation at each output time is the largest node distance
    of two runs given the steps and velocities by hand; its plot is a PNG."""
    from bench import twins
    c = twins.twins('fb_column', 1.0, refine=0, t_end=0.2)
    fb = Scene.load(FB)
    from solver.simulate.array import simulation_for
    sims = []
    for v in (1.0, 1.0 * (1 + twins.REL)):
        sim = simulation_for(fb.with_overrides([('loading.impact.v0', v), ('run.t_end', 0.2)]))
        sim.apply_impact(v)
        sims.append(sim)
    for k in range(len(c['times'])):
        for sim in sims:
            sim.advance(fb.run.output_dt)
        a, b = (sim.frame() for sim in sims)
        assert c['separation_m'][k] == float(np.max(np.abs(a.positions - b.positions)))
    assert 0 < c['separation_m'][-1] < 1e-6 and c['t_apart_s'] is None
    twins.plot([c], tmp_path / 'twins.png')
    assert (tmp_path / 'twins.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_an_ensemble_is_the_runs_at_the_velocities_around_v0():
    """``bench.twins.ensemble``: n runs at v0 (1 + (j - (n - 1) / 2) step) with the steps of the
    rung, each as a run given them by hand; its mean and standard error are those of the
    values; a run the ledger stops is counted, not averaged."""
    from bench import twins
    rb = str(SCENES / 'rb_column.yaml')
    scene = Scene.load(rb)
    e = twins.ensemble('rb_column', 0.3, refine=1, n=3, step=1e-3, t_end=0.3)
    speeds = []
    for j in range(3):
        v = 0.3 * (1 + (j - 1) * 1e-3)
        speeds.append(simulate(rb, [f'integrator.dt={scene.integrator.dt / 2}',
                                    f'contact.resolution={2 * scene.contact.resolution}',
                                    'run.t_end=0.3', f'loading.impact.v0={v!r}'])
                      .summary.to_json()['pulse']['speed_m_s'])
    assert e['values']['speed_m_s'] == speeds and e['stopped'] == []
    st = e['stats']['speed_m_s']
    assert st['mean'] == pytest.approx(np.mean(speeds), rel=1e-12)
    assert st['sem'] == pytest.approx(np.std(speeds, ddof=1) / math.sqrt(3), rel=1e-9)
    # a balance limit no run keeps: each is stopped and counted, nothing averaged
    strict = twins.ensemble('rb_column', 0.3, n=2, t_end=0.3,
                            overrides=['divergence.energy_error=1e-12'])
    assert len(strict['stopped']) == 2 and 'energy balance' in strict['stopped'][0]['reason']
    assert strict['stats']['speed_m_s'] == {'mean': None, 'std': None, 'sem': None, 'n': 0}
