"""An array of distinct columns through the node (own rclpy context and domain id), stepped as
lanes: six FB columns get six different prestrains on ``~/cmd/prestrain`` and an impact of all
on ``~/cmd/impact``; the node steps them with ``ArraySimulation.lanes`` True, its frames flow, and
what it publishes equals, bit for bit, an array stepped one column simulation at a time through
the same commands and the same intervals. No wall-clock figure is asserted (the bench
``python -m bench.node_array`` measures the real-time factor)."""
import os

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')

from solver.build.scene import Scene  # noqa: E402
from solver.simulate import lanebatch  # noqa: E402
from solver.simulate.array import ArraySimulation  # noqa: E402
from tensegrity_ros.msgs import messages  # noqa: E402
from tensegrity_ros.node.demo import spin_until  # noqa: E402
from node_helpers import commanded_node  # noqa: E402

DOMAIN = 140 + os.getpid() % 10
N_COLUMNS = 6
PRESTRAIN = np.linspace(0.02, 0.08, N_COLUMNS)
V0 = 0.3
AFTER_IMPACT_S = 0.1             # simulation time stepped after the impact


@pytest.fixture
def array_node(tmp_path, monkeypatch):
    scene = Scene.load('config/scenes/fb_column.yaml').with_overrides(
        [f'structure.n_columns={N_COLUMNS}'])
    path = tmp_path / 'fb_array.yaml'
    path.write_text(yaml.safe_dump(scene.data))
    lane_calls = []
    advance = lanebatch.LaneGroup.advance

    def counted(group, n):
        lane_calls.append((len(group.sims), n))
        return advance(group, n)
    monkeypatch.setattr(lanebatch.LaneGroup, 'advance', counted)

    def lanes_on(node):
        node.sim.lanes = True
    with commanded_node(DOMAIN, path, prepare=lanes_on, prestrain_ramp_s=0.0) as (
            node, ex, cmd, log):
        yield node, ex, cmd, log, scene, lane_calls


def _accepted(node, ex, count, topic):
    assert spin_until(ex, lambda: node.counts['accepted'] + node.counts['rejected'] >= count,
                      30)
    assert node.intake.last_command[:2] == (topic, 'accepted'), node.intake.last_command


def test_distinct_columns_as_lanes_equal_single_simulations(array_node):
    node, ex, cmd, log, scene, lane_calls = array_node
    assert isinstance(node.sim, ArraySimulation) and node.sim.n_columns == N_COLUMNS
    cmd.prestrain(PRESTRAIN, 'column')
    _accepted(node, ex, 1, '~/cmd/prestrain')
    np.testing.assert_allclose(node.sim.prestrain.mean(axis=1), PRESTRAIN, rtol=1e-12)
    cmd.impact([V0], 'all')
    _accepted(node, ex, 2, '~/cmd/impact')
    t_impact = node.sim.t
    assert spin_until(ex, lambda: node.sim.t >= t_impact + AFTER_IMPACT_S, 60)
    assert cmd.set_running(ex, False).success

    # the node stepped the distinct columns as lanes, many intervals
    assert node.sim.n_simulated == N_COLUMNS
    # one lane group, or one per thread (two on this machine)
    assert len(lane_calls) >= 10 and all(b in (N_COLUMNS, N_COLUMNS // 2) for b, _ in lane_calls)
    assert node.divergences == 0

    # the same commands and intervals, one column simulation at a time
    ref = ArraySimulation(scene)
    ref.lanes = False
    log.replay(ref)
    got, want = node.sim.frame(), ref.frame()
    assert (node.sim.t, node.sim.step) == (ref.t, ref.step)
    assert node.sim.steps_taken == ref.steps_taken
    assert np.array_equal(got.positions, want.positions)
    assert np.array_equal(got.strain, want.strain)
    assert np.array_equal(got.tension, want.tension)
    assert got.energy == want.energy

    # what went out: the last frame's float64 strain and float32 positions, stamped at its time
    assert np.isfinite(want.positions).all()
    x32 = want.positions.astype('<f4').astype(np.float64)
    assert spin_until(ex, lambda: cmd.strain and cmd.clouds
                      and np.array_equal(cmd.strain[-1], want.strain)
                      and np.array_equal(cmd.clouds[-1][1], x32), 10)
    t_cloud = cmd.clouds[-1][0]
    assert t_cloud == messages.stamp_to_ns(messages.sim_stamp(node.clock_time())) * 1e-9
    # a pulse in every column, and the columns differ (their prestrains do)
    strain = cmd.strain[-1]
    assert strain.shape == (N_COLUMNS, scene['structure.n_prisms'])
    assert np.all(np.abs(strain).max(axis=1) > 1e-4)
    assert all(not np.array_equal(strain[c], strain[c + 1]) for c in range(N_COLUMNS - 1))
