"""Prestrain as an actuator (solver level): the reference geometry stays in equilibrium at any
per-prism prestrain, tensions follow the analytic self-stress, ramps leave a resting column at
rest, bad values change nothing."""
import math

import numpy as np
import pytest
from twins import accelerations

from solver.build.scene import Scene
from solver.simulate.array import simulation_for

SCENES = 'config/scenes/'


def make(name='fb_column.yaml', *sets):
    sets = ['structure.n_prisms=8', 'structure.n_columns=2'] + list(sets)
    return simulation_for(Scene.load(SCENES + name).with_overrides(sets))


def analytic_tensions(net, p):
    """Cross cable: T = EA p. Base cable at level j (shared bases): gamma_s r per adjacent prism,
    gamma_s = EA p / s (docs/physics.md section 2), r = base circumradius."""
    r, s, EA = net.meta['radius'], net.meta['cross_length'], net.meta['EA']
    T = np.zeros(net.n_cables)
    lev = {}
    for c in range(net.n_columns):
        for j in range(net.n_prisms + 1):
            for k in range(3):
                lev[int(net.levels[c, j, k])] = (c, j)
    for i, (a, b) in enumerate(zip(net.cable_a, net.cable_b)):
        (c, ja), (_, jb) = lev[int(a)], lev[int(b)]
        if ja != jb:
            T[i] = EA * p[c, min(ja, jb)]
        else:
            adj = [q for q in (ja - 1, ja) if 0 <= q < net.n_prisms]
            T[i] = sum(EA * p[c, q] / s * r for q in adj)
    return T


@pytest.mark.parametrize('scene,sets', [('fb_column.yaml', ()),
                                        ('fb_column.yaml', ('structure.stacking=parallel',)),
                                        ('rb_column.yaml', ())])
def test_graded_prestrain_keeps_reference_equilibrium(scene, sets):
    sim = make(scene, *sets)
    net = sim.network
    rng = np.random.default_rng(3)
    p = rng.uniform(0.0005, 0.01, size=(net.n_columns, net.n_prisms))
    sim.apply_prestrain(p)
    rest, EA = sim.model.cable_rest_length, sim.model.cable_EA
    a, _, _ = accelerations(np.array(net.x0), np.zeros_like(net.x0), net, rest, EA)
    assert np.abs(a).max() < 1e-10                     # docs/physics.md section 7, check 1
    if scene == 'fb_column.yaml' and not sets:
        assert np.allclose(sim.frame().tension, analytic_tensions(net, p), rtol=1e-12, atol=0)


def test_builder_rest_lengths_reproduced():
    sim = make()
    before = np.array(sim.model.cable_rest_length)
    sim.apply_prestrain(sim.network.meta['prestrain'])
    assert np.allclose(sim.model.cable_rest_length, before, rtol=1e-13, atol=0)


def test_ramp_at_rest_stays_at_rest_and_reaches_target():
    sim = make()
    net = sim.network
    sim.apply_prestrain([0.004, 0.001], ramp_s=0.02)
    mid = None
    for _ in range(8):
        sim.advance(0.005)
        if mid is None:
            mid = sim.prestrain.copy()
    assert sim.prestrain[0, 0] == pytest.approx(0.004) and sim.prestrain[1, 0] == 0.001
    assert 0.002 < mid[0, 0] < 0.004                  # ramped, not jumped
    assert np.abs(sim.model.velocities()).max() < 1e-12
    assert np.abs(sim.model.positions() - net.x0).max() < 1e-12
    p = np.array([[0.004] * net.n_prisms, [0.001] * net.n_prisms])
    assert np.allclose(sim.frame().tension, analytic_tensions(net, p), rtol=1e-10)


def test_stiffer_column_carries_a_faster_wave():
    """Per-column prestrain addresses columns independently: the stiffer column's pulse reaches the
    clamped end earlier (sign of the effect, physics: speed grows with prestress)."""
    sim = make('fb_column.yaml', 'structure.n_prisms=20')
    sim.apply_prestrain([0.02, 0.002])
    sim.apply_impact(0.05)
    first = [None, None]
    for k in range(200):
        sim.advance(0.005)
        eps = sim.frame().strain
        for c in range(2):
            if first[c] is None and eps[c, :5].min() < -0.01:
                first[c] = k
        if None not in first:
            break
    assert first[0] is not None and first[1] is not None and first[0] < first[1]


@pytest.mark.parametrize('bad', [float('nan'), math.inf, 0.0, -0.001, 0.6, [0.1, 0.2, 0.3],
                                 np.zeros((2, 3))])
def test_bad_prestrain_changes_nothing(bad):
    sim = make()
    sim.apply_impact(0.1)
    sim.advance(0.01)
    rest, p = np.array(sim.model.cable_rest_length), sim.prestrain
    x = np.array(sim.model.positions())
    with pytest.raises(ValueError, match='prestrain'):
        sim.apply_prestrain(bad, ramp_s=0.01)
    assert np.array_equal(rest, sim.model.cable_rest_length) and np.array_equal(p, sim.prestrain)
    assert np.array_equal(x, sim.model.positions()) and np.array_equal(p, sim.prestrain_goal)


def test_ramp_during_a_wave_accounts_actuator_work():
    """Changing rest lengths does work on the system; the divergence check must not mistake it
    for energy growth, and after the ramp energy is conserved again."""
    sim = make()
    sim.apply_impact(0.1)
    sim.advance(0.02)
    sim.apply_prestrain(0.004, ramp_s=0.02)
    sim.advance(0.03)                                   # raises SimulationDiverged if mis-counted
    e1 = sim.energy()
    sim.advance(0.05)
    assert abs(sim.energy() - e1) / e1 < 1e-6
