"""QoS of the node the ROS way (real rclpy context, own domain id): overrides from a parameters
file change the offered QoS (seen through the graph, ``get_publishers_info_by_topic``), the
defaults stay elsewhere; ``~/structure`` is transient-local, so a subscriber that joins late still
gets it, and it describes the network the scene builds."""
import json
import os

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile,  # noqa: E402
                       ReliabilityPolicy)
from std_msgs.msg import String  # noqa: E402

from solver.build.scene import Scene  # noqa: E402
from solver.build.structures import build_network  # noqa: E402
from tensegrity_ros.msgs import messages  # noqa: E402
from tensegrity_ros.node.demo import spin_until  # noqa: E402
from tensegrity_ros.node.node import TensegritySim  # noqa: E402

DOMAIN = 50 + os.getpid() % 10
SCENE = 'config/scenes/prism.yaml'
BASE = messages.resolve_topic('~/').rstrip('/')


@pytest.fixture
def node_from_file(tmp_path):
    params = {'/**/tensegrity_sim': {'ros__parameters': {
        'scene_file': SCENE, 'real_time_factor': 0.0,
        'qos_overrides': {
            f'{BASE}/nodes': {'publisher': {'reliability': 'best_effort'}},
            f'{BASE}/strain': {'publisher': {'durability': 'transient_local', 'depth': 3}},
            f'{BASE}/cmd/impact': {'subscription': {'reliability': 'best_effort'}}}}}}
    path = tmp_path / 'qos.yaml'
    path.write_text(yaml.safe_dump(params))
    ctx = rclpy.Context()
    rclpy.init(args=['--ros-args', '--params-file', str(path)], context=ctx, domain_id=DOMAIN)
    node = TensegritySim(context=ctx)
    probe = rclpy.create_node('qos_probe', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(probe)
    yield node, probe, ex
    ex.shutdown()
    node.close()
    probe.destroy_node()
    node.destroy_node()
    rclpy.shutdown(context=ctx)


def _offered(probe, ex, topic):
    infos = []

    def found():
        infos[:] = probe.get_publishers_info_by_topic(topic)
        return bool(infos)
    assert spin_until(ex, found, 30), topic
    return infos[0].qos_profile


def test_qos_overrides_from_a_parameters_file(node_from_file):
    node, probe, ex = node_from_file
    nodes = _offered(probe, ex, f'{BASE}/nodes')
    assert nodes.reliability == ReliabilityPolicy.BEST_EFFORT
    strain = _offered(probe, ex, f'{BASE}/strain')
    assert strain.reliability == ReliabilityPolicy.RELIABLE           # only what was asked
    assert strain.durability == DurabilityPolicy.TRANSIENT_LOCAL
    tension = _offered(probe, ex, f'{BASE}/cable_tension')            # the defaults
    assert tension.reliability == ReliabilityPolicy.RELIABLE
    assert tension.durability == DurabilityPolicy.VOLATILE
    # the parameters that carry them, read-only as rclpy declares them
    p = node.get_parameter(f'qos_overrides.{BASE}/nodes.publisher.reliability')
    assert p.value == 'best_effort'
    assert node.get_parameter(f'qos_overrides.{BASE}/strain.publisher.depth').value == 3
    subs = []
    assert spin_until(ex, lambda: bool(subs.extend(probe.get_subscriptions_info_by_topic(
        f'{BASE}/cmd/impact')) or subs), 30)
    assert subs[0].qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT


def test_a_late_subscriber_gets_the_structure(node_from_file):
    node, probe, ex = node_from_file
    assert spin_until(ex, lambda: node.counts['frames'] > 20, 30)    # long after it was sent
    got = []
    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL, history=HistoryPolicy.KEEP_LAST)
    probe.create_subscription(String, f'{BASE}/structure', lambda m: got.append(m.data), qos)
    assert spin_until(ex, lambda: bool(got), 30)
    s = json.loads(got[0])
    net = build_network(Scene.load(SCENE))
    assert s['n_nodes'] == net.n_nodes and s['n_cables'] == net.n_cables
    assert s['n_bars'] == len(net.bar_a)
    assert s['cable_a'] == net.cable_a.tolist() and s['bar_b'] == net.bar_b.tolist()
    np.testing.assert_allclose(s['rest_length'], net.cable_rest_length, rtol=1e-12)
    np.testing.assert_allclose(np.reshape(s['x0'], (-1, 3)), net.x0, rtol=0, atol=1e-15)
    assert len(got) == 1                       # one message, not a stream


def test_a_misspelled_qos_override_is_an_error_naming_it():
    """An override no publisher or subscription declares (a topic misspelled) stops configure
    with one message naming it; nothing it would have built stays: no publisher is left, and
    configure succeeds once the parameter is gone."""
    from rclpy.lifecycle import TransitionCallbackReturn
    from rclpy.parameter import Parameter
    from tensegrity_ros.node.params import ParameterError
    bad = f'qos_overrides.{BASE}/nodez.publisher.reliability'
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN)
    try:
        with pytest.raises(ParameterError, match=bad.replace('.', r'\.')) as err:
            TensegritySim(context=ctx, parameter_overrides=[
                Parameter('scene_file', value=SCENE), Parameter(bad, value='best_effort')])
        assert 'publisher|subscription' in str(err.value)
        node = TensegritySim(context=ctx, parameter_overrides=[
            Parameter('scene_file', value=SCENE), Parameter('autostart', value=False),
            Parameter(bad, value='best_effort')])
        assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
        assert node.count_publishers(f'{BASE}/nodes') == 0 and node.sim is None
        node.destroy_node()
        good = TensegritySim(context=ctx, parameter_overrides=[
            Parameter('scene_file', value=SCENE), Parameter('autostart', value=False)])
        assert good.trigger_configure() == TransitionCallbackReturn.SUCCESS
        assert good.count_publishers(f'{BASE}/nodes') == 1
        good.close()
        good.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
