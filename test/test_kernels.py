"""Each numba kernel against its slow dense NumPy twin (test/twins.py) on perturbed, moving
states."""
import numpy as np
import pytest

import twins
from solver.kernels import dynamics as dyn
from solver.kernels import records
from solver.kernels import summary
from solver.kernels import banded
from solver.build import structures


def _networks():
    return {
        'prism_fb': structures.column(n_prisms=1),
        'prism_massive_bars': structures.column(n_prisms=1, bar_mass=0.004),
        'column_fb': structures.column(n_prisms=4),
        'column_rb_edges': structures.column(n_prisms=4, bases='rigid'),
        'column_rb_stiff': structures.column(n_prisms=3, bases='rigid',
                                             rigid_bases_as='stiff_cables', kappa=50.0),
        'column_parallel': structures.column(n_prisms=3, stacking='parallel'),
        'two_columns_rb': structures.column(n_prisms=2, n_columns=2, bases='rigid'),
    }


NETWORKS = _networks()


def _state(net, seed, amp=2e-4, vamp=0.05):
    rng = np.random.default_rng(seed)
    x = np.array(net.x0) + amp * rng.standard_normal(net.x0.shape)
    v = vamp * rng.standard_normal(net.x0.shape)
    x[net.clamped] = net.x0[net.clamped]
    v[net.clamped] = 0.0
    return x, v


def _relclose(a, b, rtol=1e-8):
    scale = max(np.max(np.abs(b)), 1e-300)
    return np.max(np.abs(a - b)) / scale < rtol


@pytest.mark.parametrize('name', sorted(NETWORKS))
def test_cable_forces_match_twin(name):
    net = NETWORKS[name]
    x, _ = _state(net, 1, amp=5e-4)     # big enough that some cables go slack
    rest = np.array(net.cable_rest_length)
    f = np.zeros_like(x)
    dyn.cable_forces(x, net.cable_a, net.cable_b, rest, np.array(net.cable_EA), f)
    ref = twins.cable_forces(x, net, rest, np.array(net.cable_EA))
    assert _relclose(f, ref, 1e-12)


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
        assert _relclose(a, a_ref, 1e-8)
        lam_fast = np.array([lam[(t, h)] for t, h in members])
        assert _relclose(lam_fast, lam_ref, 1e-8)


@pytest.mark.parametrize('bw', [1, 2, 6])
def test_band_solver_matches_dense_solve(bw):
    rng = np.random.default_rng(bw)
    m = 40
    A = np.zeros((m, m))
    for i in range(m):
        for j in range(max(0, i - bw), i):
            A[i, j] = A[j, i] = rng.uniform(-1, 1)
    A += np.diag(np.sum(np.abs(A), axis=1) + 1.0)     # diagonally dominant: SPD
    band = np.zeros((m, bw + 1))
    for i in range(m):
        for k in range(min(i, bw) + 1):
            band[i, k] = A[i, i - k]
    rhs = rng.standard_normal(m)
    y = rhs.copy()
    assert banded.band_ldl_solve(band, y) == dyn.OK
    assert np.allclose(y, np.linalg.solve(A, rhs), rtol=1e-12, atol=1e-12)


def test_band_solver_reports_singular_matrix():
    band = np.array([[1.0, 0.0], [1.0, 1.0]])     # A = [[1, 1], [1, 1]]
    assert banded.band_ldl_solve(band, np.ones(2)) == dyn.SINGULAR


@pytest.mark.parametrize('name', sorted(NETWORKS))
def test_velocity_projection_matches_twin(name):
    net = NETWORKS[name]
    mr, dr, ws = records.plain(net)
    x, v = _state(net, 7)
    ref = twins.project_velocities(x, v, net)
    assert dyn.project_velocities(x, v, mr.topo, ws) == dyn.OK
    assert _relclose(v, ref, 1e-9)
    # the projected velocity does not stretch any rigid member
    b = x[net.con_head] - x[net.con_tail]
    bd = v[net.con_head] - v[net.con_tail]
    assert np.max(np.abs(np.einsum('ij,ij->i', b, bd))) < 1e-14


@pytest.mark.parametrize('name', sorted(NETWORKS))
def test_position_projection_matches_twin(name):
    net = NETWORKS[name]
    mr, dr, ws = records.plain(net)
    x, _ = _state(net, 3, amp=1e-5)
    ref = twins.project_positions(x, net, iterations=1)
    one = x.copy()
    assert dyn.project_positions(one, mr.topo, ws, 1e-300, 1) == dyn.NOT_CONVERGED
    assert np.max(np.abs(one - ref)) < 1e-15 + 1e-9 * np.max(np.abs(ref - x))
    assert dyn.project_positions(x, mr.topo, ws, 1e-12, 5) == dyn.OK
    b = x[net.con_head] - x[net.con_tail]
    rel = np.abs(np.linalg.norm(b, axis=1) / net.con_length - 1)
    assert rel.max() < 1e-12


@pytest.mark.parametrize('name', sorted(NETWORKS))
def test_state_summary_matches_twin(name):
    """summary.state_summary (one pass: energy, constraint error, prism heights) against NumPy:
    kinetic energy with the dense mass matrix, cable strain energy, the work of external forces,
    mean level heights and the constraint error of each rigid member."""
    from solver.models.family import full_summary_arrays
    net = NETWORKS[name]
    x, v = _state(net, 11, amp=5e-4)
    rest, EA = np.array(net.cable_rest_length), 1.3 * np.array(net.cable_EA)
    f_ext = np.random.default_rng(3).standard_normal(x.shape)
    f_ext[net.clamped] = 0.0
    h = np.empty((net.levels.shape[0], net.levels.shape[1] - 1))
    mr, dr, ws = records.plain(net, rest, EA, f_ext, summary=full_summary_arrays(net))
    finite, e, cerr, h_min = summary.state_summary(x, v, mr, dr, h)
    d = np.linalg.norm(x[net.cable_b] - x[net.cable_a], axis=1)
    pe_ref = np.sum(0.5 * EA / rest * np.clip(d - rest, 0, None) ** 2)
    e_ref = twins.kinetic_energy(v, net) + pe_ref - np.sum(f_ext * (x - net.x0))
    assert finite and e == pytest.approx(e_ref, rel=1e-12)
    z = x[net.levels, 2].mean(axis=2)                     # (n_columns, n_levels)
    np.testing.assert_allclose(h, np.diff(z, axis=1), rtol=0, atol=1e-15)
    assert h_min == h.min()
    g = [abs(np.sum((x[b] - x[a]) ** 2) / np.sum((net.x0[b] - net.x0[a]) ** 2) - 1) / 2
         for a, b in twins.rigid_members(net)]
    assert cerr == pytest.approx(max(g), rel=1e-9)
    x[5, 1] = np.nan
    assert not summary.state_summary(x, v, mr, dr, h)[0]
    x[net.levels[0, 1, 0], 2] = np.nan
    assert np.isnan(summary.state_summary(x, v, mr, dr, h)[3])


@pytest.mark.parametrize('shape', [(7, 3), (8, 3), (5, 1), (4, 2), (0, 3)])
def test_all_finite_matches_numpy(shape):
    """The branch-free finiteness test equals np.isfinite(a).all() with a NaN or an infinity at
    every position, and is not fooled by finite values whose sum overflows."""
    a = np.random.default_rng(1).standard_normal(shape) * 1e308
    assert dyn.all_finite(a) and np.isfinite(a).all()
    for bad in (np.nan, np.inf, -np.inf):
        for idx in np.ndindex(*shape):
            b = a.copy()
            b[idx] = bad
            assert dyn.all_finite(b) == bool(np.isfinite(b).all()) is False


@pytest.mark.parametrize('n', [0, 1, 7, 815])
def test_finite_below_matches_numpy(n):
    """``finite_below(a, limit)`` equals ``np.isfinite(a).all() and np.abs(a).max() < limit``
    with a NaN, an infinity or a value at the limit at every position."""
    limit = float(np.finfo(np.float32).max)
    a = np.random.default_rng(2).uniform(-1.0, 1.0, n) * 1e38
    assert dyn.finite_below(a, limit) and np.isfinite(a).all() and (np.abs(a) < limit).all()
    for bad in (np.nan, np.inf, -np.inf, limit, -limit, 1e300):
        for i in range(0, n, max(1, n // 40)):
            b = a.copy()
            b[i] = bad
            expected = bool(np.isfinite(b).all() and (np.abs(b) < limit).all())
            assert expected is False and dyn.finite_below(b, limit) is False
    zeros = a * 0.0                          # magnitudes 0: below any positive limit, not below 0
    assert dyn.finite_below(zeros, 1e-300) and not dyn.finite_below(zeros, 0.0)
