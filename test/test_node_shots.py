"""A train and a strong shot through the node (own rclpy context and domain id), as a user drives
an actuator hard: the FB column gets 20 impacts of 0.1 m/s on ``~/cmd/impact``, one every 50 ms
of simulation time, then one of 2 m/s at 1 s, and the node steps on into the lasting contact of
the crushed end. It accepts every command, keeps stepping within the energy ledger's limit, and
what it publishes equals, bit for bit, a simulation replaying the same calls. No wall-clock
figure is asserted (``python -m bench.shots`` measures the real-time factor)."""
import os

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from solver.build.scene import Scene  # noqa: E402
from solver.simulate.array import simulation_for  # noqa: E402
from tensegrity_ros.node.demo import spin_until  # noqa: E402
from node_helpers import commanded_node  # noqa: E402

DOMAIN = 100 + os.getpid() % 10
SCENE = 'config/scenes/fb_column.yaml'
TRAIN = (20, 0.05, 0.1)           # impacts, every (s of simulation), v0 m/s: fb_train.yaml's
SHOT_T, SHOT_V0 = 1.0, 2.0        # then the strong shot
AFTER_SHOT_S = 0.1                # simulation time stepped after it


@pytest.fixture
def shot_node():
    with commanded_node(DOMAIN, SCENE) as started:
        yield started


def _impact_at(node, ex, cmd, t, v0, count):
    """Step until simulation time ``t``, then command an impact of ``v0`` and wait until it is
    the ``count``-th command accepted."""
    assert spin_until(ex, lambda: node.sim.t >= t, 60), f'the node did not reach t = {t} s'
    cmd.impact([v0], 'all')
    assert spin_until(ex, lambda: node.counts['accepted'] + node.counts['rejected'] >= count, 30)
    assert node.intake.last_command[:2] == ('~/cmd/impact', 'accepted'), node.intake.last_command


def test_train_then_strong_shot_through_the_node(shot_node):
    node, ex, cmd, log = shot_node
    n, every, v0 = TRAIN
    for k in range(n):
        _impact_at(node, ex, cmd, k * every, v0, k + 1)
    _impact_at(node, ex, cmd, SHOT_T, SHOT_V0, n + 1)
    t_shot = node.sim.t
    assert spin_until(ex, lambda: node.sim.t >= t_shot + AFTER_SHOT_S, 120)
    assert cmd.set_running(ex, False).success
    sim = node.sim
    assert node.counts['rejected'] == 0 and node.divergences == 0
    impacts = [c for c in log.calls if c[0] == 'apply_impact']
    assert [c[1][0] for c in impacts] == [v0] * n + [SHOT_V0]

    # the shot crushed the end: bars met, within the ledger's limit
    assert sim.contacts_met > 0
    limit = Scene.load(SCENE)['divergence.energy_error']
    assert abs(sim.energy_error()) <= limit
    assert np.isfinite(sim.frame().positions).all()

    # the same calls on a simulation of the scene, without the node
    ref = simulation_for(Scene.load(SCENE))
    log.replay(ref)
    got, want = sim.frame(), ref.frame()
    assert (sim.t, sim.step, sim.steps_taken) == (ref.t, ref.step, ref.steps_taken)
    assert sim.contacts_met == ref.contacts_met
    assert np.array_equal(got.positions, want.positions)
    assert np.array_equal(got.strain, want.strain)
    assert got.energy == want.energy

    # what went out last: the float64 strain and float32 positions of that state
    x32 = want.positions.astype('<f4').astype(np.float64)
    assert spin_until(ex, lambda: cmd.strain and cmd.clouds
                      and np.array_equal(cmd.strain[-1], want.strain)
                      and np.array_equal(cmd.clouds[-1][1], x32), 10)
    # the pulses of the train and the shot: the impacted end is pressed far beyond the train's
    assert np.abs(want.strain).max() > 0.5
