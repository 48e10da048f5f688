"""The peers of ``tensegrity bench --peers`` compute the same physics as the solver.

- the SciPy baseline's NumPy right-hand side equals the solver's banded kernel at random states;
- the MuJoCo column (skipped without ``mujoco``) has the network's nodes and masses, is at rest at
  t = 0, stays at rest, and its impulse equals the solver's projected impact;
- MuJoCo's tension-only tendon agrees with the analytic two-node oscillator on both sides of the
  rest length (tension above it, nothing below).
"""
import math

import numpy as np
import pytest

from solver.kernels import dynamics as dyn
from solver.kernels import records
from solver.build import structures
from solver import json_safe
from solver.build.scene import Scene
from solver.simulate.array import simulation_for

from bench.peers_mujoco import MujocoColumn, bar_tree
from bench.peers_scipy import ScipyColumn


def small_column(n_prisms=4):
    scene = Scene.load('config/scenes/fb_column.yaml').with_overrides(
        [('structure.n_prisms', n_prisms), ('model', 'full3d')])
    return simulation_for(scene)


def random_state(net, rng, scale=2e-4):
    x = np.array(net.x0) + scale * rng.standard_normal(net.x0.shape)
    v = 0.05 * rng.standard_normal(x.shape)
    x[net.clamped] = net.x0[net.clamped]
    v[net.clamped] = 0.0
    return x, v


def test_scipy_rhs_equals_solver_accelerations():
    sim = small_column(6)
    net = sim.network
    m = sim.model
    sc = ScipyColumn(net)
    rng = np.random.default_rng(7)
    for _ in range(5):
        x, v = random_state(net, rng)
        ours = np.zeros_like(x)
        assert dyn.accelerations(x, v, m.rec, m.data, m.work, ours) == dyn.OK
        theirs = sc.accelerations(x, v)
        assert np.max(np.abs(theirs - ours)) <= 1e-9 * np.max(np.abs(ours))
        # the state-vector form round-trips and its derivative is (v, a) on free nodes
        y = sc.pack(x, v)
        xb, vb = sc.full(y)
        assert np.array_equal(xb, x) and np.array_equal(vb, v)
        dy = sc.rhs(0.0, y)
        k = 3 * len(sc.free)
        assert np.array_equal(dy[:k], v[sc.free].ravel())
        assert np.allclose(dy[k:], ours[sc.free].ravel(), rtol=0, atol=1e-9 * np.abs(ours).max())


def test_scipy_rhs_keeps_bar_lengths_to_second_order():
    """The multipliers make the bar-length acceleration vanish: d2/dt2 |b|^2 / 2 = 0."""
    sim = small_column(3)
    net = sim.network
    sc = ScipyColumn(net)
    x, v = random_state(net, np.random.default_rng(3), scale=0.0)
    a = sc.accelerations(x, v)
    b = x[net.bar_b] - x[net.bar_a]
    bd = v[net.bar_b] - v[net.bar_a]
    bdd = a[net.bar_b] - a[net.bar_a]
    g2 = np.einsum('ij,ij->i', b, bdd) + np.einsum('ij,ij->i', bd, bd)
    assert np.max(np.abs(g2)) < 1e-10 * np.max(np.einsum('ij,ij->i', bd, bd))


try:
    import mujoco  # noqa: F401
    HAVE_MUJOCO = True
except ImportError:
    HAVE_MUJOCO = False
needs_mujoco = pytest.mark.skipif(not HAVE_MUJOCO,
                                  reason='optional dependency mujoco (pip install .[peers])')


@needs_mujoco
def test_mujoco_column_nodes_masses_and_rest():
    sim = small_column(5)
    net = sim.network
    mc = MujocoColumn(net, 5e-4)
    free = ~np.asarray(net.clamped)
    assert mc.model.nbody - 1 == net.n_bars == free.sum()      # one body per bar (tree)
    assert mc.model.nv == 3 * net.n_bars                          # one ball joint each
    assert mc.model.ntendon == net.n_cables
    # each body carries the mass of the node it ends in; the total is the free nodes' mass
    assert math.isclose(float(np.sum(mc.model.body_mass)), float(np.sum(net.node_mass[free])),
                        rel_tol=1e-12)
    _, _, head = bar_tree(net)
    assert np.allclose(mc.model.body_mass[1:], net.node_mass[head], rtol=1e-12)
    assert np.max(np.abs(mc.positions() - net.x0)) < 1e-15
    # tendon lengths are the cable lengths, and the springs sit at the prestress
    s = np.linalg.norm(net.x0[net.cable_b] - net.x0[net.cable_a], axis=1)
    assert np.allclose(mc.data.ten_length, s, rtol=1e-14)
    # at rest: node accelerations below 1e-10 m/s^2 (docs/physics.md section 7, check 1), and it
    # stays put
    assert np.max(np.abs(mc.node_accelerations())) < 1e-10
    mc.advance(200)
    assert np.max(np.abs(mc.positions() - net.x0)) < 1e-12


@needs_mujoco
def test_mujoco_impulse_equals_solver_projection():
    sim = small_column(5)
    net = sim.network
    mc = MujocoColumn(net, 5e-4, spin_inertia=1e-9)
    mc.impact(0.1)
    ours = sim.impact_velocities(0.1)
    # equal up to the tiny spin inertia MuJoCo needs (1e-9 of the bar's swinging inertia)
    assert np.max(np.abs(mc.node_velocities() - ours)) < 1e-6 * np.max(np.abs(ours))
    # and the bars keep their lengths: J v = 0 on every bar
    vm = mc.node_velocities()
    b = net.x0[net.bar_b] - net.x0[net.bar_a]
    assert np.max(np.abs(np.einsum('ij,ij->i', b, vm[net.bar_b] - vm[net.bar_a]))) < 1e-15


@needs_mujoco
def test_mujoco_tendon_is_tension_only_spring():
    """A pendulum-free check of springlength="0 L": one bar, one node, one cable along the bar's
    swing direction. Stretched: the node accelerates back with k (s - L) / m. Slack: no force."""
    L_bar = 0.01
    for stretch in (1e-4, -1e-4):
        rest = 0.02 - stretch           # cable from the node at (L_bar, 0, 0) to (L_bar, 0.02, 0)
        net = structures.explicit(nodes=[[0, 0, 0], [L_bar, 0, 0], [L_bar, 0.02, 0]],
                                  bars=[[0, 1]], cables=[[1, 2]], node_mass=[1.0, 0.5, 1.0],
                                  cable_EA=[2.0], cable_rest_length=[rest], clamped=[0, 2])
        mc = MujocoColumn(net, 1e-4)
        acc = mc.node_accelerations()[1]
        k = 2.0 / rest
        s = 0.02
        a_y = k * max(s - rest, 0.0) / 0.5           # towards node 2 (+y), tangent to the swing
        assert acc[1] == pytest.approx(a_y, rel=1e-6, abs=1e-12)
        assert abs(acc[0]) < 1e-9 and abs(acc[2]) < 1e-12
        ours = np.zeros((3, 3))
        mr, dr, ws = records.plain(net)
        assert dyn.accelerations(np.array(net.x0), np.zeros((3, 3)), mr, dr, ws,
                                 ours) == dyn.OK
        assert np.allclose(acc, ours[1], rtol=1e-6, atol=1e-12)


def test_mujoco_builder_refuses_loops():
    """Rigid bases close loops: no kinematic tree, a clear error (needs no mujoco)."""
    scene = Scene.load('config/scenes/rb_column.yaml').with_overrides(
        [('structure.n_prisms', 2), ('model', 'full3d')])
    net = simulation_for(scene).network
    with pytest.raises(ValueError, match='rigid base edges'):
        bar_tree(net)


def test_bar_tree_follows_the_three_chains():
    """FB column: the body of node n_{j,k} hangs from the body of n_{j-1,k} (the bar below it)."""
    net = small_column(4).network
    parent, tail, head = bar_tree(net)
    levels = net.levels[0]
    body_of = {int(h): b for b, h in enumerate(head)}
    for j in range(1, levels.shape[0]):
        for k in range(3):
            b = body_of[int(levels[j, k])]
            assert tail[b] == levels[j - 1, k]
            assert parent[b] == (-1 if j == 1 else body_of[int(levels[j - 1, k])])
    assert all(parent[b] < b for b in range(len(parent)))      # parents come first


def impact_trajectory_ours(sim, t_end, n_out):
    sim.apply_impact(0.1)
    out = [np.array(sim.model.positions())]
    for _ in range(n_out):
        sim.advance(t_end / n_out)
        out.append(np.array(sim.model.positions()))
    return np.array(out)


def test_scipy_trajectory_matches_solver():
    """Two independent integrations of the same impact agree (DOP853 at rtol 1e-10 against RK4
    with projection at a small step) to far below the benchmark's strain target."""
    sim = small_column(3)
    sim.advance(sim.dt)
    sim.reset()
    v_imp = sim.impact_velocities(0.1)
    x0 = np.array(sim.network.x0)
    ours = impact_trajectory_ours(sim, 0.05, 5)
    sc = ScipyColumn(sim.network)
    times = np.linspace(0.0, 0.05, 6)
    theirs, _, stats = sc.solve(x0, v_imp, times, rtol=1e-10, atol=1e-13)
    assert stats['evaluations'] > 0
    disp = np.max(np.abs(ours[-1] - x0))
    assert disp > 1e-4                                   # the impact really moved the column
    assert np.max(np.abs(theirs - ours)) < 1e-6 * disp


@needs_mujoco
def test_mujoco_trajectory_matches_solver():
    """MuJoCo's RK4 on the tree model follows the solver's trajectory after the impact (the same
    physics up to the 1e-9 spin inertia and both integrators' errors)."""
    sim = simulation_for(Scene.load('config/scenes/fb_column.yaml').with_overrides(
        [('structure.n_prisms', 3), ('model', 'full3d'), ('integrator.dt', 1e-4)]))
    ours = impact_trajectory_ours(sim, 0.05, 5)
    mc = MujocoColumn(sim.network, 1e-4, spin_inertia=1e-9)
    mc.impact(0.1)
    theirs = [mc.positions()]
    for _ in range(5):
        mc.advance(100)
        theirs.append(mc.positions())
    disp = np.max(np.abs(ours[-1] - sim.network.x0))
    assert disp > 1e-4
    assert np.max(np.abs(np.array(theirs) - ours)) < 1e-5 * disp


def test_report_ratios_targets_and_json_on_hand_made_runs(tmp_path):
    """The figures of peers.json from hand-made runs: ratios of CPU times, the real-time factor,
    the target flags, the same-physics verdict, and no NaN in the JSON."""
    import json

    from bench import peers_report

    def run(cpu, wall, error, **extra):
        return dict(knob='dt', value=1e-3, error=error, cpu_s=cpu, wall_s=wall, steps=100,
                    eps=np.zeros((3, 2)), **extra)

    ref_pulse = {'amplitude': 0.15, 'speed_m_s': 0.25}

    def pulse_fn(eps, times, h0):   # the reference pulse, except for SciPy's (4-prism) history
        return dict(ref_pulse) if eps.shape[1] == 2 else {'amplitude': 0.16,
                                                           'speed_m_s': float('nan')}
    ours = run(0.02, 0.05, 5e-4, config='sym3d+rk4_projected', model='sym3d',
               constraint_error_end=1e-15)
    mj = run(2.0, 3.0, 6e-4, met=True, check={'at_rest': True})
    sp = dict(run(12.0, 20.0, 2e-4, met=True), eps=np.zeros((3, 4)))
    kernel = {'evaluations_per_step': 4, 'accelerations': 1e-5, 'project_positions': 2e-5,
              'project_velocities': 1e-5, 'parts_in_step': ['accelerations', 'project_positions',
                                                            'project_velocities'],
              'time_per_step_s': 1.4e-4, 'integrator_only_time_per_step_s': 8e-5,
              'kernel_bound_step': 7e-5, 'step_over_kernel_bound': 2.0}
    res = peers_report.assemble(
        target=1e-3, t_end=1.0, quick=False, ref_n=320, halving=1e-11, pulse_ref=ref_pulse,
        ours=ours, ours_all=[ours], mj=mj, sp=sp, kernel=kernel, times=np.arange(3) * 0.01,
        h0=0.0062, machine={}, versions={}, blas1=True, pulse_fn=pulse_fn, output_dt=0.01,
        v0=0.1, prestrain=0.002, bar_tol=1e-9)
    assert res['speedup_vs_mujoco'] == pytest.approx(100.0)
    assert res['speedup_vs_scipy'] == pytest.approx(600.0)
    assert res['speedup_vs_mujoco_wall'] == pytest.approx(60.0)
    assert res['real_time_factor_fb'] == pytest.approx(50.0)
    assert res['real_time_factor_fb_integrator_only'] == pytest.approx(1.0 / (8e-5 * 100))
    assert res['targets']['met'] == {'speedup_vs_mujoco': True, 'speedup_vs_scipy': True,
                                     'step_over_kernel_bound': False, 'real_time_factor_fb': False}
    assert res['mujoco']['same_physics'] is True          # identical pulse: relative diff 0
    assert res['scipy']['pulse_speed_rel_diff'] is None   # NaN speed -> null, never NaN
    parts = res['kernel']['profile_s_per_step']
    assert sum(parts.values()) == pytest.approx(1.4e-4)
    assert parts['Simulation.advance bookkeeping (Python, guards)'] == pytest.approx(6e-5)
    assert 'full3d_only' not in res                        # no full3d candidate was given
    text = json.dumps(res, allow_nan=False, default=peers_report.json_default)
    assert json.loads(text)['scipy']['pulse_amplitude_rel_diff'] == pytest.approx(0.01 / 0.15)
    rows = [json_safe(dict(peer='ours', configuration='x', knob='dt', value=1e-3,
                          strain_error=5e-4, completed=True, t_end_s=1.0, cpu_s=0.02,
                          wall_s=0.05, steps=100, real_time_factor=50.0))]
    peers_report.write_csv(rows, tmp_path / 'p.csv')
    lines = (tmp_path / 'p.csv').read_text().splitlines()
    assert lines[0].startswith('peer,configuration,knob,value,strain_error')
    assert lines[1].split(',')[:3] == ['ours', 'x', 'dt']
