"""Integrators (issue 4): observed order, RATTLE energy, rk4 drift, adaptive error control, and
divergence detection (every failure mode ends in SimulationDiverged; nothing NaN escapes).

Small structures and short times only: a single prism or a 5-prism column.
"""
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from solver.integrators import registry as integrators
from solver.build.scene import Scene, SceneError
from solver.simulate.simulation import SimulationDiverged
from solver.simulate.array import simulation_for

ROOT = Path(__file__).resolve().parents[1]
PRISM = Scene.load(ROOT / 'config' / 'scenes' / 'prism.yaml')
COLUMN = Scene.load(ROOT / 'config' / 'scenes' / 'fb_column.yaml')
METHODS = ('rk4_projected', 'rk4', 'rattle', 'dopri54_projected')


def _sim(scene, overrides, v0):
    sim = simulation_for(scene.with_overrides(['model=full3d'] + list(overrides)))
    if v0:
        sim.apply_impact(v0)
    return sim


def _state(sim):
    return np.concatenate([np.ravel(sim.model.positions()), np.ravel(sim.model.velocities())])


def _bar_length_error(sim):
    """max |(|x_b - x_a| / L) - 1| over the bars, from positions (independent of the kernels)."""
    net = sim.network
    x = np.asarray(sim.model.positions())
    x0 = np.asarray(net.x0)
    L = np.linalg.norm(x0[net.bar_b] - x0[net.bar_a], axis=1)
    return float(np.max(np.abs(np.linalg.norm(x[net.bar_b] - x[net.bar_a], axis=1) / L - 1)))


# -- interface ------------------------------------------------------------------------------------
def test_every_method_is_registered_with_its_order():
    assert set(METHODS) <= set(integrators.METHODS)
    orders = {name: integrators.get(name).order for name in METHODS}
    assert orders == {'rk4_projected': 4, 'rk4': 4, 'rattle': 2, 'dopri54_projected': 5}


def test_unknown_method_lists_the_valid_ones():
    with pytest.raises(ValueError) as err:
        integrators.get('euler')
    for name in METHODS:
        assert name in str(err.value)
    with pytest.raises(ValueError, match='rattle'):
        simulation_for(PRISM.with_overrides(['integrator=leapfrog']))


def test_adaptive_tolerances_are_validated():
    with pytest.raises(SceneError, match='integrator.rtol'):
        PRISM.with_overrides(['integrator.rtol=0'])
    with pytest.raises(SceneError, match='integrator.atol'):
        PRISM.with_overrides(['integrator.atol=-1'])


def test_dormand_prince_tableau_is_consistent():
    """Row sums equal the nodes, both weight rows sum to 1, and the 5th-order weights satisfy the
    order conditions sum b c^k = 1 / (k + 1) for k < 5 (independent of the step code)."""
    from solver.integrators import dopri as adaptive
    A, b, c, e = adaptive.A, adaptive.B, adaptive.C, adaptive.E
    assert np.allclose(A[:, :6].sum(axis=1)[1:], c[1:], atol=1e-15)
    assert math.isclose(b.sum(), 1.0, rel_tol=1e-14)
    assert abs(e.sum()) < 1e-15
    b7 = np.append(b, 0.0)
    for k in range(5):
        assert math.isclose(float(b7 @ c ** k), 1.0 / (k + 1), rel_tol=1e-12)


# -- accuracy -------------------------------------------------------------------------------------
@pytest.mark.parametrize('method', METHODS)
def test_observed_order_matches_nominal_order(method):
    """Self-convergence on a smooth problem (a prism hit softly enough that no cable goes slack):
    the differences between runs at dt, dt/2, dt/4 shrink by 2^p."""
    T = 0.064
    over = ['integrator.projection_tol=1e-14', 'run.output_dt=0.01']
    counts = (16, 32, 64, 128)
    if method == 'dopri54_projected':        # loose tolerances: every step accepted at dt
        over += ['integrator.rtol=0.1', 'integrator.atol=0.1']
        counts = (32, 64, 128, 256)
    finals = []
    for n in counts:
        sim = _sim(PRISM, over + [f'integrator.method={method}', f'integrator.dt={T / n}'], 2e-4)
        sim.advance(T)
        assert np.all(sim.frame().tension > 0), 'a cable went slack: the problem is not smooth'
        if method == 'dopri54_projected':
            assert sim.integrator.stats()['rejected'] == 0
        finals.append(_state(sim))
    diffs = [np.max(np.abs(finals[i] - finals[i + 1])) for i in range(3)]
    observed = math.log2(diffs[1] / diffs[2])
    nominal = integrators.get(method).order
    assert abs(observed - nominal) < 0.35, (diffs, observed)


def test_kink_landing_restores_the_order_of_rk4_across_slack_transitions():
    """A prism hit at 0.05 m/s: cables go slack and taut again. Landing the steps on those kinks
    keeps RK4 close to order 4; without it the order drops and the error is far larger."""
    T = 0.064
    slack_seen = False
    diffs = {}
    for kinks in ('true', 'false'):
        finals = []
        for n in (64, 128, 256, 512):
            sim = _sim(PRISM, ['integrator=rk4_projected', f'integrator.dt={T / n}',
                               'run.output_dt=0.008', f'integrator.land_on_kinks={kinks}',
                               'integrator.projection_tol=1e-14',
                               'divergence.energy_error=1e-2'], 0.05)    # the coarse steps
            for _ in range(8):
                sim.advance(T / 8)
                slack_seen = slack_seen or bool(np.any(sim.frame().tension == 0.0))
            finals.append(_state(sim))
        diffs[kinks] = [np.max(np.abs(finals[i] - finals[i + 1])) for i in range(3)]
    assert slack_seen
    assert math.log2(diffs['true'][1] / diffs['true'][2]) > 3.3, diffs
    assert math.log2(diffs['false'][1] / diffs['false'][2]) < 3.0, diffs
    assert diffs['false'][2] > 20 * diffs['true'][2], diffs


def test_dopri_error_follows_the_tolerance():
    """Tighter rtol gives a smaller error against a fine rk4_projected run; slack/taut kinks
    included (v0 = 0.05 m/s on a prism)."""
    T = 0.1
    ref = _sim(PRISM, ['integrator=rk4_projected', 'integrator.dt=2.5e-5'], 0.05)
    ref.advance(T)
    errors = []
    for rtol in (1e-5, 1e-9):
        sim = _sim(PRISM, ['integrator=dopri54_projected', 'integrator.dt=1e-2',
                           'run.output_dt=1e-2', f'integrator.rtol={rtol}',
                           f'integrator.atol={rtol * 1e-3}',
                           'divergence.energy_error=1e-2'], 0.05)     # loose rtol: a study
        sim.advance(T)
        errors.append(np.max(np.abs(_state(sim) - _state(ref))))
        assert sim.integrator.stats()['accepted'] > 10      # the step was controlled, not dt
    assert errors[1] < errors[0] / 100, errors


def test_rattle_keeps_energy_bounded_over_long_runs():
    """20 s of a prism: RATTLE's energy error oscillates without growing and scales as dt^2; the
    adaptive non-symplectic method drifts over the same run (contrast)."""
    def energy_errors(method, dt, extra=()):
        sim = _sim(PRISM, [f'integrator.method={method}', f'integrator.dt={dt}',
                           'run.output_dt=0.01', 'divergence.energy_error=10', *extra], 2e-4)
        e0 = sim.energy()
        errs = []
        for _ in range(2000):
            sim.advance(0.01)
            errs.append(abs(sim.energy() - e0))
        errs = np.array(errs)
        return errs[:200].max(), errs[-200:].max()

    first, last = energy_errors('rattle', 2e-3)
    assert last < 1.1 * first, (first, last)
    first_half_dt, _ = energy_errors('rattle', 1e-3)
    assert 3.0 < first / first_half_dt < 5.0
    d_first, d_last = energy_errors('dopri54_projected', 8e-3, ('integrator.rtol=1e-4',))
    assert d_last > 5 * d_first


def test_rk4_without_projection_drifts_and_projection_removes_it():
    """Bar lengths measured from positions: rk4 drifts further with time, rk4_projected stays at
    round-off on the same run (5-prism column, v0 = 0.1 m/s)."""
    over = ['structure.n_prisms=5', 'divergence.constraint_error=1.0', 'integrator.dt=5e-4']
    drift = {}
    for method in ('rk4', 'rk4_projected'):
        sim = _sim(COLUMN, over + [f'integrator.method={method}'], 0.1)
        errs = []
        for _ in range(3):
            sim.advance(0.15)
            errs.append(_bar_length_error(sim))
        drift[method] = errs
    assert drift['rk4'][2] > drift['rk4'][0] > 1e-11
    assert max(drift['rk4_projected']) < 1e-12
    assert drift['rk4'][2] > 100 * max(drift['rk4_projected'])


# -- divergence -----------------------------------------------------------------------------------
def _expect_divergence(sim, duration, quantities, chunk=None):
    """Advance until SimulationDiverged; check the state was restored (finite, as before the failed
    call) and return the exception."""
    chunk = chunk or duration
    t = 0.0
    while t < duration:
        before = _state(sim)
        t_before = sim.t
        try:
            sim.advance(chunk)
        except SimulationDiverged as exc:
            after = _state(sim)
            assert np.array_equal(after, before)
            assert sim.t == t_before
            frame = sim.frame()
            for a in (frame.positions, frame.strain, frame.tension):
                assert np.all(np.isfinite(a))
            assert math.isfinite(frame.energy) and math.isfinite(frame.constraint_error)
            assert exc.quantity in quantities, str(exc)
            assert f'step {exc.step}' in str(exc) and exc.hint in str(exc)
            return exc
        t += chunk
    pytest.fail('no SimulationDiverged')


def _first_failing_step_is_named(scene_overrides, scene, v0, exc):
    """Independent check of the reported step: a fresh run reaches step - 1 and fails on the
    next."""
    sim = _sim(scene, scene_overrides, v0)
    if exc.step > 1:
        sim.advance((exc.step - 1) * sim.dt)
    with pytest.raises(SimulationDiverged):
        sim.advance(sim.dt)
    assert math.isclose(exc.t, exc.step * sim.dt)


def test_energy_balance_error_is_divergence():
    over = ['structure.n_prisms=5', 'integrator.method=rattle', 'integrator.dt=0.02',
            'run.output_dt=0.02']
    exc = _expect_divergence(_sim(COLUMN, over, 0.1), 1.0, {'energy balance'})
    assert 'dt' in exc.hint
    _first_failing_step_is_named(over, COLUMN, 0.1, exc)


def test_constraint_error_is_divergence():
    over = ['structure.n_prisms=5', 'integrator.method=rk4', 'integrator.dt=0.02',
            'run.output_dt=0.1']
    exc = _expect_divergence(_sim(COLUMN, over, 0.1), 1.0, {'constraint error'})
    assert 'projected' in exc.hint
    _first_failing_step_is_named(over, COLUMN, 0.1, exc)


def test_non_finite_state_is_divergence():
    sim = _sim(PRISM, [], 0.05)
    sim.advance(0.01)
    sim.model.velocities()[-1, 0] = np.nan      # a corrupted state must never be advanced
    with pytest.raises(SimulationDiverged) as err:
        sim.advance(0.01)
    assert err.value.quantity == 'state'


@pytest.mark.parametrize('method', METHODS)
def test_slack_cables_collapse_is_divergence(method):
    """Almost no prestrain: the cables go slack and the impacted prism folds through itself."""
    over = ['structure.n_prisms=5', 'prestrain=1e-5', f'integrator.method={method}',
            'contact.bars=none',         # line bars: nothing stops the collapse
            'divergence.energy_error=1e-2']  # rattle's error passes 1e-4 first
    _expect_divergence(_sim(COLUMN, over, 0.3), 0.3, {'prism height'}, chunk=0.005)


@pytest.mark.parametrize('method', METHODS)
def test_rigid_base_lock_is_divergence(method):
    """A fast impact drives a rigid-base prism through its lock (twist 180 deg, bars crossing)."""
    over = ['structure.bases=rigid', f'integrator.method={method}', 'contact.bars=none']
    _expect_divergence(_sim(PRISM, over, 1.0), 0.1, {'prism twist'}, chunk=0.005)


def test_very_high_impact_speed_is_divergence():
    over = ['structure.n_prisms=5', 'integrator=rk4_projected', 'contact.bars=none']
    _expect_divergence(_sim(COLUMN, over, 1.0), 0.1, {'prism height', 'prism twist'},
                       chunk=0.005)


def test_divergence_in_the_cli_is_one_line_and_writes_nothing(tmp_path):
    out = tmp_path / 'run'
    res = subprocess.run(
        [sys.executable, '-m', 'tensegrity_ros.cli', 'run', str(ROOT / 'config' / 'scenes' /
                                                                'rb_column.yaml'),
         '--set', 'structure.n_prisms=3', '--set', 'contact.bars=none', '--v0', '1.0',
         '--t-end', '0.1', '--json',
         '--out', str(out)], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert res.returncode == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and 'diverged at t =' in lines[0] and 'step' in lines[0]
    assert res.stdout.strip() == ''
    assert not (out / 'summary.json').exists()


@pytest.mark.parametrize('method', METHODS)
def test_advance_calls_the_compiled_overload_as_the_dispatcher_would(method, monkeypatch):
    """After its first call Simulation.advance calls the integrator's compiled overload without
    numba's type dispatch: the run is the same to the last bit as one that always goes through
    the dispatcher."""
    from solver.simulate import simulation as simulation_module
    sets = [f'integrator.method={method}', 'model=sym3d', 'divergence.energy_error=0.01']
    direct = _sim(COLUMN, sets, 0.1)
    for _ in range(20):
        direct.advance(0.005)
    checked = direct.integrator.checked
    assert direct._call.entry is not None and direct._call.entry is not checked
    monkeypatch.setattr(simulation_module, 'compiled_overload', lambda *a: None)
    dispatched = _sim(COLUMN, sets, 0.1)
    for _ in range(20):
        dispatched.advance(0.005)
    assert dispatched._call.entry is checked
    np.testing.assert_array_equal(direct.model.x, dispatched.model.x)
    np.testing.assert_array_equal(direct.model.v, dispatched.model.v)
    assert direct.energy() == dispatched.energy()


def test_rattle_split_into_calls_takes_the_steps_of_one_call():
    """RATTLE's position update uses the accelerations of the previous step; a call that starts
    where the last one ended carries them over, so the run does not depend on how it is split
    into calls (bit for bit). A command between calls that changes the forces but not the state
    (new rest lengths) is felt at once: the run equals a copy told to evaluate afresh."""
    sets = ['integrator.method=rattle', 'divergence.energy_error=0.01', 'model=sym3d']
    one, split = _sim(COLUMN, sets, 0.1), _sim(COLUMN, sets, 0.1)
    one.advance(0.1)
    for _ in range(20):
        split.advance(0.005)
    np.testing.assert_array_equal(one.model.x, split.model.x)
    np.testing.assert_array_equal(one.model.v, split.model.v)
    fresh = split.clone()
    fresh.integrator.state_changed()
    for sim in (split, fresh):
        sim.apply_prestrain(0.004)
        sim.advance(0.005)
    np.testing.assert_array_equal(split.model.x, fresh.model.x)
    np.testing.assert_array_equal(split.model.v, fresh.model.v)


@pytest.mark.parametrize('model', ['full3d', 'sym3d', 'chain1d'])
def test_a_clone_steps_on_its_own(model):
    """Simulation.clone: the copy and the original, driven differently, each end where a
    simulation given only its own commands ends (nothing of the state is shared)."""
    sets = [f'model={model}', 'structure.n_prisms=8']
    if model == 'chain1d':
        sets.append('contact.bars=none')
    sim = _sim(COLUMN, sets, 0.05)
    sim.advance(0.02)
    twin = sim.clone()
    sim.apply_impact(0.02)
    twin.apply_impact(0.04)
    for _ in range(10):
        sim.advance(0.005)
        twin.advance(0.005)
    for v0, done in ((0.02, sim), (0.04, twin)):
        alone = _sim(COLUMN, sets, 0.05)
        alone.advance(0.02)
        alone.apply_impact(v0)
        for _ in range(10):
            alone.advance(0.005)
        np.testing.assert_array_equal(done.model.positions(), alone.model.positions())
