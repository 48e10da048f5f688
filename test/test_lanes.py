"""Lanes (solver.kernels.lanes, solver.integrators.rk4lanes): B instances of the FB column, each
with its own rest lengths, prestrain and impact, stepped together; every lane is compared with
the scalar kernels on that instance, bit for bit (np.array_equal), for one force-and-constraint
evaluation, one position and velocity projection and a 50-step projected RK4 run; a lane made
NaN fails alone, with the scalar run's status, steps and state."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from solver import Scene
from solver.build import structures
from solver.integrators import rk4lanes
from solver.integrators.rk4 import RK4Projected
from solver.kernels import dynamics as dyn
from solver.kernels import lanes, records
from solver.status import OK

ROOT = Path(__file__).resolve().parents[1]
B = 5
DT = 6.25e-4
TOL = 1e-12
MAX_ITER = 20


@pytest.fixture(scope='module')
def column():
    """The FB column's network and B lanes of scalar (Model, Data, Work): lane l with rest
    lengths scaled by 1 - 1e-3 l, EA scaled by 1 + 0.01 l, small lane-dependent external forces
    and an impact of 0.1 (1 + 0.2 l) m/s on the top level (velocities then projected by the
    scalar kernel, so that each lane starts on the tangent space)."""
    scene = Scene.load(ROOT / 'config' / 'scenes' / 'fb_column.yaml').with_overrides(
        [('model', 'full3d'), ('contact.bars', 'none')])
    net = structures.build_network(scene)
    rng = np.random.default_rng(7)
    scalars = []
    for k in range(B):
        m, d, w = records.plain(net, rest=net.cable_rest_length * (1.0 - 1e-3 * k),
                                EA=net.cable_EA * (1.0 + 0.01 * k),
                                f_ext=1e-4 * k * rng.normal(size=(net.n_nodes, 3)))
        d.v[net.levels[0, -1], 2] = -0.1 * (1.0 + 0.2 * k)
        assert dyn.project_velocities(d.x, d.v, m.topo, w) == OK
        scalars.append((m, d, w))
    return net, scalars


def lanes_of(net, scalars):
    """A LaneData and LaneWork of the scalar lanes' current data (copies)."""
    ds = [d for _, d, _ in scalars]
    data = lanes.lane_data([d.x for d in ds], [d.v for d in ds], [d.rest for d in ds],
                           [d.EA for d in ds], [d.f_ext for d in ds])
    return data, lanes.lane_work(net.topology(), net.n_nodes, len(scalars))


def fresh(scalars):
    return [(m, records.clone_data(d), records.clone_work(w)) for m, d, w in scalars]


def test_lanes_are_different_instances(column):
    """The lanes differ (else a comparison lane by lane could not tell lanes apart)."""
    net, scalars = column
    data, _ = lanes_of(net, scalars)
    for k in range(1, B):
        assert not np.array_equal(data.rest[:, k], data.rest[:, 0])
        assert not np.array_equal(data.v[..., k], data.v[..., 0])


def test_accelerations_equal_the_scalar_kernel_in_every_lane(column):
    net, scalars = column
    scalars = fresh(scalars)
    data, work = lanes_of(net, scalars)
    topo = net.topology()
    out = np.full_like(data.x, np.nan)
    status = np.zeros(B, np.int64)
    lanes.accelerations(data.x, data.v, topo, data, work, out, status)
    assert list(status) == [OK] * B
    for k, (m, d, w) in enumerate(scalars):
        a = np.zeros_like(d.x)
        assert dyn.accelerations(d.x, d.v, m, d, w, a) == OK
        assert np.array_equal(lanes.lane(out, k), a), k
        assert np.array_equal(lanes.lane(work.lam, k), w.lam), k
        assert np.abs(a).max() > 0.0


def _iterations(m, d, w):
    """How many Gauss-Newton corrections the scalar projection of ``d.x`` takes (the fewest
    ``max_iter`` with which it converges)."""
    for j in range(MAX_ITER + 1):
        x = d.x.copy()
        if dyn.project_positions(x, m.topo, w, TOL, j) == OK:
            return j
    raise AssertionError('the scalar projection does not converge')


def test_projections_equal_the_scalar_kernels_in_every_lane(column):
    """Positions pushed off the manifold by lane-dependent amounts (one lane not at all), then
    projected: the lanes take different numbers of Gauss-Newton corrections (a lane that has
    converged must stop changing while the others go on), and each equals the scalar
    projection."""
    net, scalars = column
    scalars = fresh(scalars)
    rng = np.random.default_rng(3)
    for k, (_, d, _) in enumerate(scalars):
        d.x[...] += (0.0, 1e-9, 1e-7, 1e-5, 1e-4)[k] * rng.normal(size=d.x.shape)
    assert len({_iterations(*s) for s in scalars}) >= 3
    data, work = lanes_of(net, scalars)
    topo = net.topology()
    status = np.zeros(B, np.int64)
    lanes.project_positions(data.x, topo, work, TOL, MAX_ITER, status)
    lanes.project_velocities(data.x, data.v, topo, work, status)
    assert list(status) == [OK] * B
    for k, (m, d, w) in enumerate(scalars):
        assert dyn.project_positions(d.x, m.topo, w, TOL, MAX_ITER) == OK
        assert dyn.project_velocities(d.x, d.v, m.topo, w) == OK
        assert np.array_equal(lanes.lane(data.x, k), d.x), k
        assert np.array_equal(lanes.lane(data.v, k), d.v), k


def test_a_projection_that_does_not_converge_stops_its_lane_alone(column):
    """With one iteration allowed, the lane pushed far off does not converge (as the scalar
    projection) and the others do."""
    net, scalars = column
    scalars = fresh(scalars)
    rng = np.random.default_rng(5)
    for k, (_, d, _) in enumerate(scalars):
        d.x[...] += (1e-3 if k == 2 else 1e-9) * rng.normal(size=d.x.shape)
    data, work = lanes_of(net, scalars)
    status = np.zeros(B, np.int64)
    lanes.project_positions(data.x, net.topology(), work, 1e-8, 1, status)
    expected = [dyn.project_positions(d.x, m.topo, w, 1e-8, 1) for m, d, w in scalars]
    assert expected[2] == dyn.NOT_CONVERGED and expected.count(OK) == B - 1
    assert list(status) == expected
    for k, (_, d, _) in enumerate(scalars):
        assert np.array_equal(lanes.lane(data.x, k), d.x), k


def _scalar_runs(scalars, n_steps):
    out = []
    for m, d, w in scalars:
        steps, status = RK4Projected.kernel(m, d, w, DT, n_steps, TOL, MAX_ITER, False, True)
        out.append((steps, status))
    return out


def test_a_projected_rk4_run_equals_the_scalar_run_in_every_lane(column):
    net, scalars = column
    scalars = fresh(scalars)
    data, work = lanes_of(net, scalars)
    status = np.zeros(B, np.int64)
    steps = np.zeros(B, np.int64)
    left = rk4lanes.rk4_projected_run(net.topology(), data, work, DT, 50, TOL, MAX_ITER,
                                      status, steps)
    x0 = [d.x.copy() for _, d, _ in scalars]
    expected = _scalar_runs(scalars, 50)
    assert expected == [(50, OK)] * B and left == B
    assert list(steps) == [50] * B and list(status) == [OK] * B
    for k, (_, d, _) in enumerate(scalars):
        assert not np.array_equal(d.x, x0[k])
        assert np.array_equal(lanes.lane(data.x, k), d.x), k
        assert np.array_equal(lanes.lane(data.v, k), d.v), k


def test_a_nan_lane_fails_alone_and_the_others_match_their_scalar_runs(column):
    net, scalars = column
    scalars = fresh(scalars)
    scalars[3][1].x[10, 1] = np.nan
    data, work = lanes_of(net, scalars)
    status = np.zeros(B, np.int64)
    steps = np.zeros(B, np.int64)
    left = rk4lanes.rk4_projected_run(net.topology(), data, work, DT, 50, TOL, MAX_ITER,
                                      status, steps)
    expected = _scalar_runs(scalars, 50)
    assert expected[3][1] != OK and [e for k, e in enumerate(expected) if k != 3] == \
        [(50, OK)] * (B - 1)
    assert left == B - 1
    assert [(int(s), int(c)) for s, c in zip(steps, status)] == expected
    for k, (_, d, _) in enumerate(scalars):
        assert np.array_equal(lanes.lane(data.x, k), d.x, equal_nan=True), k
        assert np.array_equal(lanes.lane(data.v, k), d.v, equal_nan=True), k


def test_lanes_refuse_a_network_they_do_not_step():
    """A column with massive bars (the banded KKT system of the mass matrix) gets no lane
    scratch: its instances step one at a time."""
    from solver.simulate.simulation import Simulation
    scene = Scene({'structure': {'n_prisms': 4}, 'model': 'full3d',
                   'materials': {'bar_mass_fraction': 0.3}})
    topo = Simulation(scene).model.rec.topo
    assert topo.kkt.node_u.shape[0] > 0
    with pytest.raises(ValueError, match='KKT'):
        lanes.lane_work(topo, topo.w_diag.shape[0], 2)
