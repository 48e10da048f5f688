"""The checks of docs/physics.md section 7 (1, 2, 3, 5, 6), each against an independent reference:
analytic values of section 2-3, invariants (energy, bar lengths, the lock), and convergence
studies."""
import math

import numpy as np
import pytest

from solver.kernels import dynamics as dyn
from solver.kernels import records
from solver.build import structures
from solver.analysis.observables import kinetic_energy, prism_strains
from solver.simulate.runner import run
from solver.build.scene import Scene
from solver.simulate.array import simulation_for

R, H0, P = 0.005, 0.0062, 0.002
EA = 5.48e6 * math.pi * (1.4e-4) ** 2
SCENES = 'config/scenes'


def _at_rest_accelerations(net):
    mr, dr, ws = records.plain(net)
    a = np.zeros((net.n_nodes, 3))
    assert dyn.accelerations(np.array(net.x0), np.zeros_like(a), mr, dr, ws, a) == dyn.OK
    return a, ws.lam.copy()


# -- check 1: equilibrium at t = 0 -------------------------------------------------------------

@pytest.mark.parametrize('kw', [
    dict(n_prisms=1), dict(), dict(bases='rigid'), dict(stacking='parallel'),
    dict(bases='rigid', rigid_bases_as='stiff_cables'), dict(n_columns=3, n_prisms=10),
    dict(prestrain=0.02, n_prisms=10), dict(handedness='left', n_prisms=5)])
def test_column_is_at_rest_before_the_impact(kw):
    net = structures.column(**kw)
    a, lam = _at_rest_accelerations(net)
    assert np.max(np.abs(a)) < 1e-10


def test_prism_geometry_and_self_stress_match_the_analytic_values():
    net = structures.column(n_prisms=1)
    m = net.meta
    # docs/physics.md section 2: b^2 = 2 r^2 (1 - cos phi) + h^2, s^2 =
    # 2 r^2 (1 - cos(phi - 2 pi/3)) + h^2
    phi = 5 * math.pi / 6
    b = math.sqrt(2 * R ** 2 * (1 - math.cos(phi)) + H0 ** 2)
    s = math.sqrt(2 * R ** 2 * (1 - math.cos(phi - 2 * math.pi / 3)) + H0 ** 2)
    assert m['bar_length'] == pytest.approx(b, rel=1e-12)
    assert m['cross_length'] == pytest.approx(s, rel=1e-12)
    # section 3 derived numbers: bar 11.478 mm, cross 6.7185 mm, rest 6.7051 mm, k 50.32 N/m
    assert b == pytest.approx(11.478e-3, abs=1e-6)
    assert s == pytest.approx(6.7185e-3, abs=1e-7)
    assert m['cross_rest_length'] == pytest.approx(6.7051e-3, abs=1e-7)
    assert EA / m['cross_rest_length'] == pytest.approx(50.32, abs=0.01)
    assert EA * P == pytest.approx(6.749e-4, rel=1e-3)    # tension = k (s - L) = EA p
    # bar force density equals the cross-cable force density gamma_s = EA p / s (section 2)
    _, lam = _at_rest_accelerations(net)
    assert np.allclose(lam, EA * P / s, rtol=1e-9)


def test_base_cable_tension_is_the_prism_self_stress():
    for stacking, interior in (('shared', 2.0), ('parallel', 1.0)):
        net = structures.column(n_prisms=3, stacking=stacking)
        x = np.array(net.x0)
        d = np.linalg.norm(x[net.cable_b] - x[net.cable_a], axis=1)
        T = np.array(net.cable_EA) / net.cable_rest_length * (d - net.cable_rest_length)
        base = np.array(net.cable_kind) == 'base'
        s = net.meta['cross_length']
        t_l = EA * P / s * R              # gamma_s r
        level = net.cable_a[base] // 3
        expected = np.where((level == 0) | (level == 3), t_l, interior * t_l)
        assert np.allclose(T[base], expected, rtol=1e-9)


# -- the impact initial condition (section 3.1) ------------------------------------------------

@pytest.mark.parametrize('bases,fraction', [('flexible', 0.85), ('rigid', 0.14)])
def test_impulse_keeps_the_expected_kinetic_energy_fraction(bases, fraction):
    sim = simulation_for(Scene({'structure': {'bases': bases}}))
    sim.apply_impact(0.1)
    m_node = 0.0249 / 3
    ke_axial = 3 * 0.5 * m_node * 0.1 ** 2
    assert kinetic_energy(sim.model.velocities(), sim.network) / ke_axial == pytest.approx(
        fraction, abs=0.01)


def test_energy_mode_impact_has_the_axial_kinetic_energy():
    sim = simulation_for(Scene({'structure': {'bases': 'rigid'},
                            'loading': {'impact': {'mode': 'energy'}}}))
    sim.apply_impact(0.125)
    assert kinetic_energy(sim.model.velocities(), sim.network) == pytest.approx(
        3 * 0.5 * (0.0249 / 3) * 0.125 ** 2, rel=1e-12)


# -- checks 2 and 3: energy and bar lengths over a paper run -------------------------------------

@pytest.fixture(scope='module')
def fb_run():
    scene = Scene.load(f'{SCENES}/fb_column.yaml').with_overrides(['run.t_end=1.0'])
    sim = simulation_for(scene)
    sim.apply_impact(0.1)
    return sim, run(sim, 1.0, scene['run.output_dt'])


@pytest.mark.parametrize('name', ['fb_column', 'rb_column'])
def test_energy_drift_below_1e6_per_second_at_the_default_step(name, fb_run):
    if name == 'fb_column':
        sim, rec = fb_run
    else:
        sim = simulation_for(Scene.load(f'{SCENES}/{name}.yaml'))
        sim.apply_impact(0.1)
        rec = run(sim, 1.0, 0.01)
    drift = np.max(np.abs(rec.energy - rec.energy[0])) / rec.energy[0]
    assert drift / (rec.times[-1] - rec.times[0]) < 1e-6


def test_bar_lengths_kept_below_1e9_relative(fb_run):
    sim, rec = fb_run
    x = sim.model.positions()
    b = np.linalg.norm(x[sim.network.bar_b] - x[sim.network.bar_a], axis=1)
    b0 = np.linalg.norm(sim.network.x0[sim.network.bar_b] - sim.network.x0[sim.network.bar_a],
                        axis=1)
    assert np.max(np.abs(b / b0 - 1)) < 1e-9
    assert np.max(rec.constraint_error) < 1e-9


def test_fb_pulse_is_a_compression_travelling_from_the_impacted_end(fb_run):
    sim, rec = fb_run
    strain = rec.strain[:, 0]
    k1, k2 = np.searchsorted(rec.times, [0.3, 0.7])
    i1, i2 = np.argmin(strain[k1]), np.argmin(strain[k2])
    assert strain[k1, i1] < -0.01 and strain[k2, i2] < -0.01
    assert i2 < i1                      # moved towards the clamped end (prism 0)


# -- check 5: rigid bases never pass the lock
# ------------------------------------------------------

def test_rigid_bases_never_exceed_the_lock_strain():
    # twist reaches 180 deg: h_lock^2 = b^2 - 4 r^2 (section 3: lock strain -0.1005)
    b2 = 2 * R ** 2 * (1 - math.cos(5 * math.pi / 6)) + H0 ** 2
    h_lock = math.sqrt(b2 - 4 * R ** 2)
    eps_lock = (h_lock - H0) / h_lock
    assert eps_lock == pytest.approx(-0.1005, abs=1e-4)
    scene = Scene({'structure': {'bases': 'rigid', 'n_prisms': 10},
                   'integrator': {'dt': 2e-4},
                   # run through the lock (by default the run stops there: bars cross)
                   'divergence': {'bar_crossing': 'none'}})
    sim = simulation_for(scene)
    sim.apply_impact(0.4)
    worst = 0.0
    for _ in range(100):
        sim.advance(0.002)
        worst = min(worst, prism_strains(sim.model.positions(), sim.network.levels, H0).min())
    assert worst < 0.5 * eps_lock                   # the impact does drive prisms towards the lock
    assert worst >= eps_lock - 1e-9


# -- check 6: convergence ------------------------------------------------------------------------

def test_halving_dt_changes_amplitude_and_speed_little(fb_run):
    _, rec = fb_run
    base = Scene.load(f'{SCENES}/fb_column.yaml')
    scene = base.with_overrides(['run.t_end=1.0', f'integrator.dt={base["integrator.dt"] / 2}'])
    sim = simulation_for(scene)
    sim.apply_impact(0.1)
    half = run(sim, 1.0, scene['run.output_dt'])
    p, q = rec.pulses[0], half.pulses[0]
    assert abs(p.amplitude / q.amplitude - 1) < 0.005
    assert abs(p.amplitude_median / q.amplitude_median - 1) < 0.005
    assert abs(p.speed_m_s / q.speed_m_s - 1) < 0.01


def test_observed_order_is_four_on_a_smooth_problem():
    """A prism with a small impact keeps every cable taut (smooth force law): the error against a
    fine reference must fall by 2^4 per halving of dt."""
    def end_state(dt):
        sim = simulation_for(Scene.load(f'{SCENES}/prism.yaml').with_overrides(
            [f'integrator.dt={dt}', 'run.output_dt=0.04']))
        sim.apply_impact(0.005)
        sim.advance(0.04)
        assert np.all(sim.frame().tension > 0)
        return sim.model.positions().copy()
    ref = end_state(1.25e-5)
    errs = [np.max(np.abs(end_state(dt) - ref)) for dt in (1.6e-3, 8e-4, 4e-4)]
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all((orders > 3.5) & (orders < 4.6)), orders
