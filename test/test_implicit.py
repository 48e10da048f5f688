"""The implicit integrator for stiff scenes (``implicit_midpoint``): the discrete solution of a
linear oscillator (analytic), observed order, constraints after every step, energy that never
grows, agreement of the full and reduced models, and its stable step on a stiff-cable column
against the largest stable step of ``rk4_projected``.
"""
import math
from pathlib import Path

import numpy as np
import pytest

from solver.integrators import registry as integrators
from solver.build.scene import Scene
from solver.simulate.simulation import SimulationDiverged
from solver.simulate.array import simulation_for

ROOT = Path(__file__).resolve().parents[1]
# the midpoint step refuses bar contact (test_forces_outside_the_midpoint_step_are_refused):
# line bars here
LINE_BARS = ['contact.bars=none']
PRISM = Scene.load(ROOT / 'config' / 'scenes' / 'prism.yaml').with_overrides(LINE_BARS)
RB = Scene.load(ROOT / 'config' / 'scenes' / 'rb_column.yaml').with_overrides(LINE_BARS)
STIFF = ['structure.n_prisms=10', 'structure.rigid_bases_as=stiff_cables', 'structure.kappa=1e4',
         'run.output_dt=0.016']


def _oscillator(g=9.81, mass=0.0083, rest=0.01):
    """A mass hanging from a clamped node by one cable, at its equilibrium (taut): (simulation,
    k N/m, omega rad/s)."""
    EA = 5.48e6 * math.pi * 1.4e-4 ** 2
    k = EA / rest
    s_eq = rest + mass * g / k
    data = {'name': 'oscillator',
            'structure': {'builder': 'explicit', 'nodes': [[0, 0, 0], [0, 0, -s_eq]],
                          'bars': [], 'cables': [[0, 1]], 'clamped': [0], 'node_mass': mass,
                          'cable_rest_length': [rest]},
            'loading': {'gravity': g}, 'model': 'full3d',
            'integrator': {'method': 'implicit_midpoint', 'dt': 1e-3}, 'run': {'output_dt': 1e-3}}
    return simulation_for(Scene(data)), k, math.sqrt(k / mass)


def _bar_length_error(sim):
    """max | |x_b - x_a| / L - 1 | over bars and rigid edges, from the full positions."""
    net = sim.network
    x, x0 = np.asarray(sim.model.positions()), np.asarray(net.x0)
    a = np.concatenate([net.bar_a, net.con_tail[net.n_bars:]]) if net.n_constraints > \
        net.n_bars else net.bar_a
    b = np.concatenate([net.bar_b, net.con_head[net.n_bars:]]) if net.n_constraints > \
        net.n_bars else net.bar_b
    L = np.linalg.norm(x0[b] - x0[a], axis=1)
    return float(np.max(np.abs(np.linalg.norm(x[b] - x[a], axis=1) / L - 1)))


# -- interface ------------------------------------------------------------------------------------
def test_registered_with_its_order():
    integ = integrators.get('implicit_midpoint')
    assert integ.order == 2 and integ.projected
    with pytest.raises(ValueError, match='implicit_midpoint'):
        integrators.get('implicit')


def test_massive_bars_are_refused_with_a_clear_error():
    """A free massive bar couples its two end nodes in the mass matrix: refused, with the reason
    and the methods that handle it."""
    data = {'name': 'rod', 'structure': {'builder': 'explicit',
                                         'nodes': [[0, 0, 0], [0, 0, 0.01], [0.01, 0, 0]],
                                         'bars': [[0, 1]], 'cables': [[1, 2]], 'clamped': [2],
                                         'cable_rest_length': [0.0139]},
            'materials': {'bar_mass': 0.001}, 'model': 'full3d',
            'integrator': {'method': 'implicit_midpoint', 'dt': 1e-3}, 'run': {'output_dt': 1e-3}}
    sim = simulation_for(Scene(data))
    assert np.any(sim.network.partner >= 0)
    with pytest.raises(ValueError, match='massive bars.*rk4_projected'):
        sim.advance(sim.dt)


def test_massive_bars_sharing_nodes_are_refused_too():
    """Massive bars whose nodes are shared (the column's bar chains) take the banded KKT mass
    system, which the midpoint step does not solve: refused before any step, not run wrongly."""
    scene = Scene.load(ROOT / 'config' / 'scenes' / 'fb_column.yaml').with_overrides(
        ['structure.n_prisms=3', 'materials.bar_mass_fraction=0.3', 'model=full3d',
         'integrator=implicit_midpoint', 'contact.bars=none'])
    sim = simulation_for(scene)
    assert not np.any(sim.network.partner >= 0)        # not the class-1 rod blocks
    with pytest.raises(ValueError, match='massive bars'):
        sim.advance(sim.dt)


# -- accuracy -------------------------------------------------------------------------------------
@pytest.mark.parametrize('omega_h', [0.5, 3.0])
def test_linear_oscillator_follows_the_discrete_midpoint_rotation(omega_h):
    """For ``u'' = -omega^2 u`` the implicit midpoint map is a rotation of (u, u'/omega) by
    ``2 atan(omega h / 2)`` per step, of modulus 1 for every h (A-stable, no damping): the
    hanging mass follows it to round-off, also beyond RK4's stability limit (omega h = 2.83)."""
    sim, k, w = _oscillator()
    m = sim.model
    z_eq = float(m.x[1, 2])
    v0 = 0.05                           # amplitude v0 / w = 0.8 mm < static stretch 2.4 mm: taut
    m.v[1, 2] = v0
    h, n = omega_h / w, 40
    steps, status = sim.integrator.run(m.rec, m.data, m.work, h, n)
    assert (steps, status) == (n, 0)
    theta = 2.0 * math.atan(omega_h / 2.0)
    amp = v0 / w
    assert abs(m.x[1, 2] - z_eq - amp * math.sin(n * theta)) < 1e-9 * amp
    assert abs(m.v[1, 2] - v0 * math.cos(n * theta)) < 1e-9 * v0
    assert np.all(m.x[:, :2] == 0.0)


def test_order_two_against_the_exact_oscillation():
    """Errors against the exact solution ``A sin(omega t)`` at dt, dt/2, dt/4 fall as dt^2."""
    errors = []
    T = 0.2
    for n in (50, 100, 200):
        sim, k, w = _oscillator()
        m = sim.model
        z_eq = float(m.x[1, 2])
        m.v[1, 2] = 0.05
        sim.integrator.run(m.rec, m.data, m.work, T / n, n)
        errors.append(abs(m.x[1, 2] - z_eq - 0.05 / w * math.sin(w * T)))
    slopes = [math.log2(errors[i] / errors[i + 1]) for i in range(2)]
    assert all(abs(s - 2.0) < 0.1 for s in slopes), (errors, slopes)


def test_observed_order_on_a_prism():
    """Self-convergence on a prism hit softly (every cable taut, bars as constraints): the
    differences between runs at dt, dt/2, dt/4 shrink by 2^2."""
    T = 0.064
    finals = []
    for n in (16, 32, 64, 128):
        sim = simulation_for(PRISM.with_overrides([
            'model=full3d', 'integrator=implicit_midpoint', f'integrator.dt={T / n}',
            'integrator.projection_tol=1e-14', 'run.output_dt=0.01']))
        sim.apply_impact(2e-4)
        sim.advance(T)
        assert np.all(sim.frame().tension > 0), 'a cable went slack: the problem is not smooth'
        finals.append(np.concatenate([np.ravel(sim.model.positions()),
                                      np.ravel(sim.model.velocities())]))
    diffs = [np.max(np.abs(finals[i] - finals[i + 1])) for i in range(3)]
    observed = math.log2(diffs[1] / diffs[2])
    assert abs(observed - 2.0) < 0.35, (diffs, observed)


# -- constraints and energy -----------------------------------------------------------------------
@pytest.mark.parametrize('model', ['full3d', 'sym3d'])
def test_bars_kept_and_energy_never_grows_on_the_stiff_column(model):
    """A 10-prism column whose rigid bases are stiff cables (kappa 1e4), hit at 0.1 m/s, at
    dt = 4 ms: after every step every bar keeps its length to 1e-9 (measured from the full
    positions), and the energy never rises (the discrete-gradient forces and the bar forces do
    no net work over a step; the velocity projection only removes kinetic energy)."""
    sim = simulation_for(RB.with_overrides(STIFF + [f'model={model}',
                                                    'integrator=implicit_midpoint',
                                                    'integrator.dt=4e-3']))
    sim.apply_impact(0.1)
    e_prev = e0 = sim.energy()
    for _ in range(40):
        sim.advance(sim.dt)
        assert _bar_length_error(sim) < 1e-9
        e = sim.energy()
        assert e <= e_prev + 1e-12 * e0
        e_prev = e
    assert e_prev > (1 - 1e-3) * e0          # and it does not dissipate much either


def test_energy_conserved_exactly_for_a_linear_spring_at_a_large_step():
    """The hanging mass at omega h = 3: the quadratic energy (kinetic + cable + gravity) is the
    same after 200 steps to 1e-11 (implicit midpoint conserves quadratic invariants)."""
    sim, k, w = _oscillator()
    m = sim.model
    m.v[1, 2] = 0.05

    def energy():
        s = abs(m.x[1, 2] - m.x[0, 2])
        return (0.5 * 0.0083 * m.v[1, 2] ** 2 + 0.5 * k * (s - 0.01) ** 2
                + 0.0083 * 9.81 * m.x[1, 2])
    e0 = energy()
    sim.integrator.run(m.rec, m.data, m.work, 3.0 / w, 200)
    assert abs(energy() - e0) < 1e-11 * 0.5 * 0.0083 * 0.05 ** 2


def test_full_and_reduced_models_agree():
    over = STIFF + ['integrator=implicit_midpoint', 'integrator.dt=2e-3']
    runs = []
    for model in ('full3d', 'sym3d'):
        sim = simulation_for(RB.with_overrides(over + [f'model={model}']))
        sim.apply_impact(0.1)
        sim.advance(0.032)
        runs.append(np.array(sim.model.positions()))
    assert np.max(np.abs(runs[0] - runs[1])) < 1e-11


# -- stiff scene ----------------------------------------------------------------------------------
def _survives(method, dt, t_end=0.16):
    # stability, not accuracy (near its limit RK4 damps: 12 % of the energy gone in 4 ms at
    # 0.2 ms): only an energy that doubles or vanishes counts
    sim = simulation_for(RB.with_overrides(STIFF + ['model=sym3d', f'integrator.method={method}',
                                                f'integrator.dt={dt}',
                                                'divergence.energy_error=1.0']))
    sim.apply_impact(0.1)
    try:
        sim.advance(t_end)
    except SimulationDiverged:
        return False
    return True


def test_stable_step_at_least_10x_that_of_rk4_projected_on_the_stiff_column():
    """rk4_projected diverges at dt = 0.4 ms on the stiff-cable column (its largest stable step is
    below 0.4 ms); implicit_midpoint runs at 10x that, 4 ms."""
    assert _survives('rk4_projected', 2e-4)
    assert not _survives('rk4_projected', 4e-4)
    assert _survives('implicit_midpoint', 4e-3)


@pytest.mark.parametrize('sets', [['contact.bars=hertz'], ['materials.cable_damping=0.01'],
                                  ['contact.lock=penalty'],
                                  ['loading.impact.mode=striker']])
def test_forces_outside_the_midpoint_step_are_refused(sets):
    """Cable damping, prism stops and strikers are not part of the midpoint step: refused with
    a clear error instead of being silently left out."""
    scene = Scene.load(ROOT / 'config' / 'scenes' / 'fb_column.yaml').with_overrides(
        ['structure.n_prisms=3', 'model=full3d', 'integrator=implicit_midpoint',
         'contact.bars=none', *sets])
    sim = simulation_for(scene)
    with pytest.raises(ValueError, match='not part of its step'):
        sim.advance(sim.dt)
