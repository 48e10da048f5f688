"""Massive bars that share nodes (the banded mass-matrix system of solver.kernels.massmatrix) and
the mass placement options, each against an independent reference: the dense NumPy KKT twin
(test/twins.py), rigid-body mechanics of a single rod derived here, invariants (total mass, energy,
rest at t = 0, the constraints) and the full model against the symmetric reduction."""
import math

import numpy as np
import pytest

import twins
from solver.kernels import dynamics as dyn
from solver.kernels import records
from solver.kernels import summary
from solver.kernels import massmatrix as mm
from solver.build import structures
from solver.build.network import Network
from solver.build.scene import Scene, SceneError
from solver.simulate.array import simulation_for
from solver.models.sym3d import Sym3D

UNIT = 0.0249


def _networks():
    return {
        'fb_3': structures.column(n_prisms=3, bar_mass_fraction=0.3),
        'fb_4_unit_bases_end': structures.column(n_prisms=4, bar_mass_fraction=0.5,
                                                 mass_placement='unit_bases', end_mass=0.01),
        'fb_3_bar_mass_key': structures.column(n_prisms=3, bar_mass=0.004),
        'rb_3_edges': structures.column(n_prisms=3, bases='rigid', bar_mass_fraction=0.3),
        'rb_3_stiff': structures.column(n_prisms=3, bases='rigid', rigid_bases_as='stiff_cables',
                                        kappa=50.0, bar_mass_fraction=0.2),
        'two_columns_rb': structures.column(n_prisms=2, n_columns=2, bases='rigid',
                                            bar_mass_fraction=0.4),
        'parallel_left': structures.column(n_prisms=3, stacking='parallel', handedness='left',
                                           bar_mass_fraction=0.3),
    }


NETWORKS = _networks()


def _state(net, seed, amp=2e-4, vamp=0.05):
    rng = np.random.default_rng(seed)
    x = np.array(net.x0) + amp * rng.standard_normal(net.x0.shape)
    v = vamp * rng.standard_normal(net.x0.shape)
    x[net.clamped] = net.x0[net.clamped]
    v[net.clamped] = 0.0
    return x, v


def _relclose(a, b, rtol):
    scale = max(np.max(np.abs(b)), 1e-300)
    return np.max(np.abs(a - b)) / scale < rtol


@pytest.mark.parametrize('name', sorted(NETWORKS))
def test_kkt_path_is_taken_and_banded(name):
    net = NETWORKS[name]
    n_u, kl, ku = net.kkt.dims
    assert n_u == 3 * int(np.sum(~net.clamped)) + net.n_constraints
    # the band does not grow with the column: at most two levels of unknowns
    per_level = 3 * 3 * net.n_columns + 6
    assert 0 < kl <= per_level and ku == kl
    assert net.n_columns > 1 or kl <= 15


@pytest.mark.parametrize('name', sorted(NETWORKS))
def test_accelerations_and_multipliers_match_dense_kkt(name):
    net = NETWORKS[name]
    mr, dr, ws = records.plain(net)
    for seed in range(3):
        x, v = _state(net, seed)
        a = np.zeros_like(x)
        assert dyn.accelerations(x, v, mr, dr, ws, a) == dyn.OK
        lam = dict(zip(zip(net.con_tail, net.con_head), ws.lam))
        a_ref, lam_ref, members = twins.accelerations(x, v, net, dr.rest, dr.EA)
        assert _relclose(a, a_ref, 1e-9)
        assert _relclose(np.array([lam[(t, h)] for t, h in members]), lam_ref, 1e-9)


@pytest.mark.parametrize('name', sorted(NETWORKS))
def test_projections_match_dense_twins(name):
    net = NETWORKS[name]
    mr, dr, ws = records.plain(net)
    x, v = _state(net, 7)
    ref = twins.project_velocities(x, v, net)
    assert dyn.project_velocities(x, v, mr.topo, ws) == dyn.OK
    assert _relclose(v, ref, 1e-9)
    b = x[net.con_head] - x[net.con_tail]
    bd = v[net.con_head] - v[net.con_tail]
    assert np.max(np.abs(np.einsum('ij,ij->i', b, bd))) < 1e-14
    x, _ = _state(net, 3, amp=1e-5)
    ref = twins.project_positions(x, net, iterations=1)
    one = x.copy()
    assert dyn.project_positions(one, mr.topo, ws, 1e-300, 1) == dyn.NOT_CONVERGED
    assert np.max(np.abs(one - ref)) < 1e-15 + 1e-9 * np.max(np.abs(ref - x))
    assert dyn.project_positions(x, mr.topo, ws, 1e-12, 5) == dyn.OK
    b = x[net.con_head] - x[net.con_tail]
    assert np.max(np.abs(np.linalg.norm(b, axis=1) / net.con_length - 1)) < 1e-12


def test_small_workspace_is_reported_not_overrun():
    net = NETWORKS['fb_3']
    mr, dr, ws = records.plain(net)
    ws = ws._replace(kkt=mm.scratch(mm.NO_DIMS))                          # no KKT scratch
    a = np.zeros((net.n_nodes, 3))
    assert dyn.accelerations(np.array(net.x0), a.copy(), mr, dr, ws, a) == mm.BAD_WORKSPACE


@pytest.mark.parametrize('n,kl,ku', [(30, 2, 3), (40, 4, 4), (25, 6, 1)])
def test_band_lu_matches_dense_solve_with_zero_diagonal(n, kl, ku):
    """A banded matrix with zeros on the diagonal (a saddle-point pattern): partial pivoting
    must swap rows."""
    rng = np.random.default_rng(n)
    A = np.zeros((n, n))
    for i in range(n):
        for j in range(max(0, i - kl), min(n, i + ku + 1)):
            A[i, j] = rng.uniform(-1, 1)
    A[np.arange(0, n, 3), np.arange(0, n, 3)] = 0.0
    band = np.zeros((n, 2 * kl + ku + 1))
    for i in range(n):
        for j in range(max(0, i - kl), min(n, i + ku + 1)):
            band[i, j - i + kl] = A[i, j]
    rhs = rng.standard_normal(n)
    y = rhs.copy()
    piv = np.zeros(n, dtype=np.int64)
    assert mm.band_lu_solve(band, np.zeros((n, kl)), piv, y, n, kl, ku) == dyn.OK
    assert np.any(piv != np.arange(n))
    np.testing.assert_allclose(y, np.linalg.solve(A, rhs), rtol=1e-10, atol=1e-10)


def test_band_lu_reports_a_singular_matrix():
    # A = [[1, 0, 0], [1, 0, 0], [0, 1, 1]] (rows 0 and 1 equal), kl = 1, ku = 0
    band = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    assert mm.band_lu_solve(band, np.zeros((3, 1)), np.zeros(3, dtype=np.int64), np.ones(3),
                            3, 1, 0) == dyn.SINGULAR


# -- a single rod with end masses: rigid-body mechanics ------------------------------------------

def _rod_mass_matrix_by_quadrature(m_i, m_j, m_b):
    """2x2 node mass matrix of a uniform rod from T = int_0^1 m_b/2 |(1-s) v_i + s v_j|^2 ds
    (Gauss-Legendre, exact for this quadratic) plus the end masses."""
    s, w = np.polynomial.legendre.leggauss(4)
    s, w = 0.5 * (s + 1), 0.5 * w
    N = np.stack([1 - s, s])                       # shape functions at the nodes
    return m_b * (N * w) @ N.T + np.diag([m_i, m_j])


def _rigid_body_accelerations(x, v, f, m_i, m_j, m_b):
    """Newton-Euler for the rigid segment (end masses + uniform rod) under end forces."""
    L = np.linalg.norm(x[1] - x[0])
    e = (x[1] - x[0]) / L
    m = m_i + m_j + m_b
    s_c = (m_j + 0.5 * m_b) / m                     # centre of mass at x_i + s_c L e
    c = x[0] + s_c * L * e
    r = np.array([x[0] - c, x[1] - c])
    inertia = m_i * (s_c * L) ** 2 + m_j * ((1 - s_c) * L) ** 2 \
        + m_b * (L ** 2 / 12 + ((0.5 - s_c) * L) ** 2)
    omega = np.cross(e, v[1] - v[0]) / L
    torque = np.cross(r[0], f[0]) + np.cross(r[1], f[1])
    torque -= np.dot(torque, e) * e                 # a line body does not spin about its axis
    alpha = torque / inertia
    acc_c = (f[0] + f[1]) / m
    return np.array([acc_c + np.cross(alpha, rp) + np.cross(omega, np.cross(omega, rp))
                     for rp in r])


@pytest.mark.parametrize('m_i,m_j,m_b', [(0.0083, 0.0083, 0.004), (0.01, 0.002, 0.03),
                                         (0.0, 0.005, 0.02)])
def test_single_massive_bar_against_rigid_body_mechanics(m_i, m_j, m_b):
    """A bar with end masses, end forces and a spinning, translating state. Accelerations from
    Newton-Euler of the rigid segment; the force density (multiplier, > 0 in compression) from
    the length constraint ``b . b'' + |b'|^2 = 0`` with the rod's mass matrix from quadrature:
    ``lam = -(|b'|^2 + G . M^-1 f) / (G . M^-1 G)``. Checked on the class-1 path (node-local 2x2
    inverse) and on the banded KKT kernel."""
    rng = np.random.default_rng(int(1000 * (m_i + m_j + m_b)))
    x = np.array([[0.001, -0.002, 0.0], [0.004, 0.003, 0.011]])
    b = x[1] - x[0]
    v = rng.standard_normal((2, 3)) * 0.1
    rel = v[1] - v[0]
    v[1] -= np.dot(rel, b) / np.dot(b, b) * b      # respect the constraint: b . b' = 0
    f = rng.standard_normal((2, 3)) * 1e-3
    a_ref = _rigid_body_accelerations(x, v, f, m_i, m_j, m_b)
    M = _rod_mass_matrix_by_quadrature(m_i, m_j, m_b)
    Minv = np.linalg.inv(M)
    G = np.array([-b, b])                           # gradient of (|b|^2 - L^2) / 2
    bd = v[1] - v[0]
    lam_ref = -(bd @ bd + np.sum(G * (Minv @ f))) / np.sum(G * (Minv @ G))
    # the multiplier also satisfies the node equations M a = f + lam G
    np.testing.assert_allclose(M @ a_ref, f + lam_ref * G, rtol=1e-9, atol=1e-15)

    net = Network.build(x, [m_i, m_j], [(0, 1)], np.zeros((0, 2)), [], [], bar_mass=m_b)
    assert net.kkt.node_u.size == 0                     # class 1: the node-local inverse
    mr, dr, ws = records.plain(net, f_ext=f)
    a = np.zeros((2, 3))
    assert dyn.accelerations(x, v, mr, dr, ws, a) == dyn.OK
    np.testing.assert_allclose(a, a_ref, rtol=1e-9, atol=1e-12 * np.abs(a_ref).max())
    assert ws.lam[0] == pytest.approx(lam_ref, rel=1e-9)

    mp, mq, mv, _ = mm.mass_entries(np.array([m_i, m_j]), np.zeros(2, bool), [(0, 1)], [m_b])
    node_u, con_u, dims = mm.layout(2, np.zeros(2, bool), np.array([[0, 1]]), mp, mq, x)
    kkt = mm.KKT(node_u, con_u, mp, mq, mv, dims)
    a2, lam2 = np.zeros((2, 3)), np.zeros(1)
    assert mm.accelerations(x, v, f, np.array([0]), np.array([1]), records.NO_ROT, kkt,
                            mm.scratch(dims), np.zeros((1, 3)), lam2, a2) == dyn.OK
    np.testing.assert_allclose(a2, a_ref, rtol=1e-9, atol=1e-12 * np.abs(a_ref).max())
    assert lam2[0] == pytest.approx(lam_ref, rel=1e-9)


# -- masses ------------------------------------------------------------------------------------

@pytest.mark.parametrize('placement', ['level', 'unit_bases'])
@pytest.mark.parametrize('fraction', [0.0, 0.3, 0.9])
@pytest.mark.parametrize('end_mass', [0.0, 0.02])
def test_total_and_level_masses(placement, fraction, end_mass):
    n, n_col = 6, 2
    net = structures.column(n_prisms=n, n_columns=n_col, bar_mass_fraction=fraction,
                            mass_placement=placement, end_mass=end_mass)
    M = twins.dense_mass(net)
    units = n + 1 if placement == 'level' else n
    assert M.sum() == pytest.approx(n_col * (units * UNIT + end_mass), rel=1e-13)
    assert net.total_mass == pytest.approx(M.sum(), rel=1e-13)
    # lumped mass per level: what the option says
    lumped = (1 - fraction) * UNIT
    level_mass = np.asarray(net.node_mass)[net.levels].sum(axis=2)      # (n_col, n + 1)
    if placement == 'level':
        expected = np.r_[UNIT, np.full(n, lumped)]
    else:
        expected = np.r_[lumped / 2, np.full(n - 1, lumped), lumped / 2]
    expected[-1] += end_mass
    np.testing.assert_allclose(level_mass, np.tile(expected, (n_col, 1)), rtol=1e-13)
    # the bars of each prism carry the fraction
    np.testing.assert_allclose(np.asarray(net.bar_mass).reshape(n_col, n, 3).sum(axis=2),
                               fraction * UNIT, rtol=1e-13, atol=0)
    # the end mass sits on the three nodes of the free end only
    end = net.levels[:, -1].ravel()
    assert np.allclose(np.asarray(net.node_mass)[end],
                       expected[-1] / 3) and not np.any(net.clamped[end])


def test_default_masses_are_one_unit_per_level_lumped():
    net = structures.column(n_prisms=4)
    assert np.all(np.asarray(net.node_mass) == UNIT / 3.0)
    assert not np.any(net.bar_mass) and net.kkt.node_u.size == 0


@pytest.mark.parametrize('kw', [
    dict(bar_mass_fraction=0.3), dict(bar_mass_fraction=0.5, mass_placement='unit_bases'),
    dict(bar_mass_fraction=0.3, bases='rigid'), dict(bar_mass_fraction=0.3, end_mass=0.05),
    dict(bar_mass_fraction=0.3, n_columns=2, n_prisms=8),
    dict(bar_mass_fraction=0.3, bases='rigid', rigid_bases_as='stiff_cables')])
def test_column_with_massive_bars_is_at_rest(kw):
    net = structures.column(**kw)
    mr, dr, ws = records.plain(net)
    a = np.zeros((net.n_nodes, 3))
    assert dyn.accelerations(np.array(net.x0), np.zeros_like(a), mr, dr, ws, a) == dyn.OK
    assert np.max(np.abs(a)) < 1e-10
    if kw.get('n_columns', 1) == 1:
        model = Sym3D(net)
        ar = np.zeros_like(model.x)
        assert dyn.accelerations(model.x, model.v, model.rec, model.data, model.work, ar) == dyn.OK
        assert np.max(np.abs(ar)) < 1e-10


@pytest.mark.parametrize('bases', ['flexible', 'rigid'])
def test_sym3d_reduced_mass_matrix_matches_the_full_dense_kkt(bases):
    """On a symmetric, perturbed, moving state the reduced model's accelerations (expanded)
    equal the dense KKT solution of the full network."""
    net = structures.column(n_prisms=4, bases=bases, bar_mass_fraction=0.4,
                            mass_placement='unit_bases')
    model = Sym3D(net)
    assert model.reduced.kkt.node_u.size and model.exact
    rng = np.random.default_rng(5)
    xr = np.array(model.reduced.x0) + 2e-4 * rng.standard_normal(model.x.shape)
    vr = 0.05 * rng.standard_normal(model.x.shape)
    xr[model.reduced.clamped] = model.reduced.x0[model.reduced.clamped]
    vr[model.reduced.clamped] = 0.0
    a = np.zeros_like(xr)
    assert dyn.accelerations(xr, vr, model.rec, model.data, model.work, a) == dyn.OK
    x, v = model._expand(xr), model._expand(vr)
    a_ref, _, _ = twins.accelerations(x, v, net, np.array(net.cable_rest_length),
                                      np.array(net.cable_EA))
    assert _relclose(model._expand(a), a_ref, 1e-9)
    # and the reduced energy summary equals the full kinetic energy
    h = np.empty((1, 4))
    e = summary.state_summary(xr, vr, model.rec, model.data, h)[1]
    d = np.linalg.norm(x[net.cable_b] - x[net.cable_a], axis=1)
    rest = np.array(net.cable_rest_length)
    pe = np.sum(0.5 * np.array(net.cable_EA) / rest * np.clip(d - rest, 0, None) ** 2)
    assert e == pytest.approx(twins.kinetic_energy(v, net) + pe, rel=1e-12)


def test_impulse_uses_the_full_mass_matrix():
    """The velocity after the impact is the dense mass-weighted projection of the axial kick:
    no rigid member is stretched and the kinetic energy is that of the dense mass matrix."""
    sim = simulation_for(Scene({'structure': {'n_prisms': 12}, 'model': 'full3d',
                            'materials': {'bar_mass_fraction': 0.3}}))
    net = sim.network
    kick = np.zeros((net.n_nodes, 3))
    kick[net.levels[0, -1], 2] = -0.1
    ref = twins.project_velocities(np.array(net.x0), kick, net)
    added = sim.apply_impact(0.1)
    v = sim.model.velocities()
    assert _relclose(v, ref, 1e-10)
    assert added == pytest.approx(twins.kinetic_energy(ref, net), rel=1e-10)


@pytest.mark.parametrize('over', [{}, {'structure': {'mass_placement': 'unit_bases'},
                                       'materials': {'bar_mass_fraction': 0.5,
                                                     'end_mass': 0.01}}])
def test_impact_conserves_energy_and_sym3d_equals_full3d(over):
    """FB column, impact at 0.1 m/s, default step: energy drift below 1e-6 per simulated second,
    bar lengths kept, and the symmetric reduction equals the full model."""
    base = {'structure': {'n_prisms': 16}, 'materials': {'bar_mass_fraction': 0.3}}
    for key, sub in over.items():
        base.setdefault(key, {}).update(sub)
    runs = {}
    for model in ('sym3d', 'full3d'):
        sim = simulation_for(Scene(dict(base, model=model)))
        assert sim.model.name == model
        sim.apply_impact(0.1)
        e0 = sim.energy()
        worst = 0.0
        t_end = 0.3 if model == 'sym3d' else 0.1
        while sim.t < t_end - 1e-12:
            sim.advance(0.005)
            worst = max(worst, abs(sim.energy() - e0) / e0)
            assert sim.constraint_error() < 1e-9
        assert worst / t_end < 1e-6
        runs[model] = sim
    full = runs['full3d']
    sym = simulation_for(Scene(dict(base, model='sym3d')))
    sym.apply_impact(0.1)
    sym.advance(full.t)
    # equal to round-off (which grows along the pulse: 1e-12 m after 0.1 s)
    np.testing.assert_allclose(sym.model.positions(), full.model.positions(), rtol=0,
                               atol=1e-10)


def test_auto_picks_sym3d_for_massive_bars_and_chain1d_refuses_them():
    sim = simulation_for(Scene({'structure': {'n_prisms': 5},
                            'materials': {'bar_mass_fraction': 0.3}}))
    assert sim.model.name == 'sym3d'
    with pytest.raises(ValueError, match='chain1d: bar masses'):
        simulation_for(Scene({'structure': {'n_prisms': 5}, 'model': 'chain1d',
                          'materials': {'bar_mass_fraction': 0.3}}))


@pytest.mark.parametrize('key,value,words', [
    ('materials.bar_mass_fraction', 1.0, 'outside [0.0, 1.0)'),
    ('materials.bar_mass_fraction', -0.2, 'outside [0.0, 1.0)'),
    ('materials.bar_mass_fraction', 'a', 'expected a number'),
    ('structure.mass_placement', 'top', 'not one of level, unit_bases'),
    ('materials.end_mass', -0.01, 'outside'),
])
def test_bad_mass_options_name_the_key(key, value, words):
    scene = Scene({'structure': {'n_prisms': 3}})
    with pytest.raises(SceneError) as err:
        scene.with_overrides([(key, value)])
    assert key in str(err.value) and words in str(err.value)
    assert scene['materials.bar_mass_fraction'] == 0.0      # the scene is unchanged


def test_mass_options_of_the_column_builder_only():
    data = {'structure': {'builder': 'explicit', 'nodes': [[0, 0, 0], [0, 0, 1]],
                          'bars': [[0, 1]]}, 'materials': {'end_mass': 0.1}}
    with pytest.raises(SceneError, match='materials.end_mass: only for'):
        Scene(data)


def test_end_mass_on_a_clamped_end_is_refused():
    with pytest.raises(ValueError, match='end_mass'):
        structures.column(n_prisms=3, clamped_levels=(0, 3), end_mass=0.01)


def test_gravity_acts_on_bar_masses():
    """With gravity the column sags under its whole weight: the axial reaction of the clamped
    level (the sum of the multipliers' z forces on it) equals the weight of everything free
    plus half of each bar attached to it."""
    net = structures.column(n_prisms=3, bar_mass_fraction=0.5)
    sim = simulation_for(Scene({'structure': {'n_prisms': 3}, 'model': 'full3d',
                            'materials': {'bar_mass_fraction': 0.5},
                            'loading': {'gravity': 9.81}}))
    weight = 9.81 * (np.sum(np.asarray(net.node_mass)[~net.clamped]) + np.sum(net.bar_mass)
                     - 0.5 * np.sum(np.asarray(net.bar_mass)[net.clamped[net.bar_a]]))
    assert -sim.f_ext[:, 2].sum() == pytest.approx(weight, rel=1e-12)
    assert math.isfinite(sim.energy())
