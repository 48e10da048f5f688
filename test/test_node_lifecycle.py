"""The managed node through its lifecycle services (``~/change_state``, ``~/get_state``) in a real
rclpy context (own domain id): configure, activate, deactivate, activate keep the state and
publish only while active; cleanup removes the interfaces; a configure that cannot load its scene
fails with the node left unconfigured."""
import os

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from lifecycle_msgs.msg import State, Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from solver.build.scene import Scene  # noqa: E402
from tensegrity_ros.msgs import messages  # noqa: E402
from tensegrity_ros.node.demo import Commander, spin_until  # noqa: E402
from tensegrity_ros.node.node import TensegritySim  # noqa: E402

DOMAIN = 80 + os.getpid() % 10


@pytest.fixture
def managed(tmp_path):
    scene = Scene.load('config/scenes/lens_array.yaml').with_overrides(
        ['structure.n_prisms=8', 'structure.n_columns=2'])
    path = tmp_path / 'two.yaml'
    path.write_text(yaml.safe_dump(scene.data))
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN)
    nodes = []

    def make(scene_file=str(path)):
        node = TensegritySim(context=ctx, parameter_overrides=[
            Parameter('scene_file', value=scene_file), Parameter('real_time_factor', value=0.0),
            Parameter('autostart', value=False)])
        nodes.append(node)
        return node
    cmd = Commander(context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(cmd)
    base = messages.resolve_topic('~/').rstrip('/')
    change = cmd.create_client(ChangeState, f'{base}/change_state')
    get = cmd.create_client(GetState, f'{base}/get_state')

    def call(client, request):
        fut = client.call_async(request)
        assert spin_until(ex, fut.done, 60)
        return fut.result()

    def transition(tid):
        return call(change, ChangeState.Request(transition=Transition(id=tid))).success

    def state():
        return call(get, GetState.Request()).current_state.id
    yield make, ex, cmd, transition, state, (change, get)
    ex.shutdown()
    for node in nodes:
        node.close()
        node.destroy_node()
    cmd.destroy_node()
    rclpy.shutdown(context=ctx)


def test_transitions_keep_the_state_and_publish_only_while_active(managed):
    make, ex, cmd, transition, state, clients = managed
    node = make()
    ex.add_node(node)
    assert spin_until(ex, lambda: all(c.service_is_ready() for c in clients), 30)
    assert state() == State.PRIMARY_STATE_UNCONFIGURED
    assert node.sim is None and cmd.count_publishers(f'{cmd.base}/strain') == 0

    assert transition(Transition.TRANSITION_CONFIGURE)
    assert state() == State.PRIMARY_STATE_INACTIVE and node.sim is not None
    assert spin_until(ex, lambda: cmd.pub_impact.get_subscription_count() > 0, 30)
    spin_until(ex, lambda: False, 0.5)
    assert not cmd.strain and node.sim.t == 0.0             # inactive: no frames, no steps

    assert transition(Transition.TRANSITION_ACTIVATE)
    assert state() == State.PRIMARY_STATE_ACTIVE
    cmd.impact([0.0, 0.1], 'column')
    assert spin_until(ex, lambda: node.counts['accepted'] == 1 and node.sim.t > 0.05, 60)
    assert spin_until(ex, lambda: len(cmd.strain) > 5, 30)

    assert transition(Transition.TRANSITION_DEACTIVATE)
    assert state() == State.PRIMARY_STATE_INACTIVE
    t_kept, x_kept = node.sim.t, node.sim.frame().positions.copy()
    spin_until(ex, lambda: False, 0.3)                      # what was in flight arrives
    n_strain = len(cmd.strain)
    spin_until(ex, lambda: False, 0.5)
    assert len(cmd.strain) == n_strain                      # nothing published while inactive
    assert node.sim.t == t_kept
    assert np.array_equal(node.sim.frame().positions, x_kept)
    assert np.abs(x_kept - node.sim.network.x0).max() > 1e-6    # the wave is in the kept state

    n_clouds = len(cmd.clouds)
    assert transition(Transition.TRANSITION_ACTIVATE)
    assert spin_until(ex, lambda: len(cmd.clouds) > n_clouds + 2, 30)
    stamps = [t for t, _ in cmd.clouds[n_clouds:]]
    assert stamps[0] == pytest.approx(t_kept, abs=1e-9)     # continues from the kept state
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    assert node.counts['accepted'] == 1                     # the counters were kept too

    assert transition(Transition.TRANSITION_DEACTIVATE)
    assert transition(Transition.TRANSITION_CLEANUP)
    assert state() == State.PRIMARY_STATE_UNCONFIGURED and node.sim is None
    assert spin_until(ex, lambda: cmd.count_publishers(f'{cmd.base}/strain') == 0, 30)
    # configured again: a fresh simulation from the scene
    assert transition(Transition.TRANSITION_CONFIGURE)
    assert node.sim.t == 0.0 and node.counts['accepted'] == 0


def test_configure_that_cannot_load_its_scene_fails_and_stays_unconfigured(managed):
    make, ex, cmd, transition, state, clients = managed
    node = make('/nope/missing.yaml')       # parameters are fine; the file is loaded at configure
    ex.add_node(node)
    assert spin_until(ex, lambda: all(c.service_is_ready() for c in clients), 30)
    assert not transition(Transition.TRANSITION_CONFIGURE)
    assert state() == State.PRIMARY_STATE_UNCONFIGURED and node.sim is None


def test_autostart_is_active_at_once(managed):
    make, ex, cmd, transition, state, clients = managed
    from tensegrity_ros.node.node import TensegritySim as Sim
    node = Sim(context=cmd.context, parameter_overrides=[
        Parameter('scene_file', value='config/scenes/prism.yaml'),
        Parameter('real_time_factor', value=0.0)])
    try:
        ex.add_node(node)
        assert spin_until(ex, lambda: all(c.service_is_ready() for c in clients), 30)
        assert state() == State.PRIMARY_STATE_ACTIVE and node.timer is not None
    finally:
        node.close()
        node.destroy_node()


def test_every_transition_logs_a_line(managed, monkeypatch):
    """INFO for each transition that succeeds (configure, activate, deactivate, cleanup,
    shutdown), ERROR for a configure that fails and for the error transition."""
    from types import SimpleNamespace
    make = managed[0]
    lines = []

    class Log:
        def __getattr__(self, level):
            return lambda text, **kw: lines.append((level, text))

    def last_lines(node, *steps):
        monkeypatch.setattr(node, 'get_logger', lambda: Log())
        out = []
        for step in steps:
            del lines[:]
            getattr(node, f'trigger_{step}')()
            assert lines, step
            out.append((lines[-1][0], lines[-1][1].split(' ')[0]))
            assert all(level == 'info' for level, _ in lines) or step == 'configure'
        return out

    assert last_lines(make(), 'configure', 'activate', 'deactivate', 'cleanup', 'configure',
                      'shutdown') == [
        ('info', 'configured'), ('info', 'activated:'), ('info', 'deactivated'),
        ('info', 'cleaned'), ('info', 'configured'), ('info', 'shutdown')]
    bad = make('/nope/missing.yaml')
    assert last_lines(bad, 'configure') == [('error', 'configure')]
    del lines[:]
    bad.on_error(SimpleNamespace(label='configuring'))
    assert [level for level, _ in lines] == ['error'] and 'configuring' in lines[0][1]
