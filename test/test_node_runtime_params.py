"""Parameters of a running node (real rclpy context, own domain id), set through its
``set_parameters`` service as a ROS tool does: changes take effect at once, bad values and
parameters fixed at start-up are refused with a reason and leave the running value; unknown
parameters at start-up are an error naming them."""
import os
import time

import pytest

rclpy = pytest.importorskip('rclpy')
from rcl_interfaces.msg import ParameterType  # noqa: E402
from rcl_interfaces.srv import DescribeParameters, SetParameters  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from tensegrity_ros.msgs import messages  # noqa: E402
from tensegrity_ros.node.demo import node_process, spin_until, stop_process  # noqa: E402
from tensegrity_ros.node.node import TensegritySim  # noqa: E402

from node_helpers import commanded_node  # noqa: E402

DOMAIN = 200 + os.getpid() % 30
SCENE = 'config/scenes/prism.yaml'


@pytest.fixture
def running():
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN)
    node = TensegritySim(context=ctx, parameter_overrides=[
        Parameter('scene_file', value=SCENE), Parameter('real_time_factor', value=0.0),
        Parameter('publish_rate_hz', value=100.0)])
    client = rclpy.create_node('param_client', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(client)
    base = messages.resolve_topic('~/').rstrip('/')
    cli = client.create_client(SetParameters, f'{base}/set_parameters')
    describe = client.create_client(DescribeParameters, f'{base}/describe_parameters')
    assert spin_until(ex, lambda: cli.service_is_ready() and describe.service_is_ready(), 30)

    def call(client_, request):
        fut = client_.call_async(request)
        assert spin_until(ex, fut.done, 20)
        return fut.result()

    def set_(name, value):
        res = call(cli, SetParameters.Request(
            parameters=[Parameter(name, value=value).to_parameter_msg()]))
        return res.results[0]
    yield node, ex, set_, lambda names: call(describe, DescribeParameters.Request(names=names))
    ex.shutdown()
    node.close()
    client.destroy_node()
    node.destroy_node()
    rclpy.shutdown(context=ctx)


def test_real_time_factor_takes_effect_at_once(running):
    node, ex, set_, _ = running
    assert spin_until(ex, lambda: node.sim.t > 0.01, 30)      # as fast as possible so far
    w0 = time.monotonic()                                   # before the change
    assert set_('real_time_factor', 0.05).successful
    assert node.params['real_time_factor'] == 0.05
    t0 = node.sim.t
    spin_until(ex, lambda: False, 1.0)
    # paced now: the simulation never runs ahead of 0.05 x the wall time since the change
    assert node.sim.t - t0 <= 0.05 * (time.monotonic() - w0) + node.sim.dt


def test_publish_rate_changes_the_timer(running):
    node, ex, set_, _ = running
    assert set_('publish_rate_hz', 20.0).successful
    assert node.timer.timer_period_ns == 50_000_000
    n0, w0 = node.counts['frames'], time.monotonic()
    spin_until(ex, lambda: False, 1.0)
    assert node.counts['frames'] - n0 <= 20 * (time.monotonic() - w0) + 2


@pytest.mark.parametrize('name,value,needle', [
    ('publish_rate_hz', -5.0, 'publish_rate_hz'),
    ('real_time_factor', 'abc', 'real_time_factor'),
    ('marker_rate_hz', 0.0, 'marker_rate_hz'),
])
def test_bad_values_are_refused_with_a_reason_and_change_nothing(running, name, value, needle):
    node, ex, set_, _ = running
    before = dict(node.params)
    res = set_(name, value)
    assert not res.successful and needle in res.reason, res.reason
    assert node.params == before
    assert node.get_parameter(name).value == before[name]


def test_on_divergence_changes_at_once_and_a_bad_value_is_refused_naming_the_choices(running):
    node, ex, set_, describe = running
    res = set_('on_divergence', 'stop')
    assert not res.successful
    assert res.reason == "on_divergence: must be one of reset, pause, got 'stop'"
    assert node.params['on_divergence'] == 'reset' == node.get_parameter('on_divergence').value
    assert set_('on_divergence', 'pause').successful and node.params['on_divergence'] == 'pause'
    (desc,) = describe(['on_divergence']).descriptors
    assert not desc.read_only and desc.additional_constraints == 'one of: reset, pause'


@pytest.mark.parametrize('name,value', [('scene_file', '/nope.yaml'), ('dt', 1e-4),
                                        ('model', 'full3d'), ('record_mcap', '/tmp/x.mcap')])
def test_parameters_fixed_at_start_up_are_refused(running, name, value):
    node, ex, set_, describe = running
    res = set_(name, value)
    assert not res.successful and res.reason
    assert node.get_parameter(name).value == node.params[name]
    (desc,) = describe([name]).descriptors
    assert desc.read_only


def test_an_unknown_parameter_is_refused_naming_it_and_the_valid_ones(running):
    """rclpy's own reason names no parameter ("undeclared parameter(s): []")."""
    from rclpy.exceptions import ParameterNotDeclaredException
    node, ex, set_, _ = running
    res = set_('publish_rate', 50.0)                   # through ~/set_parameters, as ros2 param
    assert not res.successful
    assert res.reason.startswith('unknown parameter publish_rate (valid: scene_file, '), res.reason
    assert 'publish_rate_hz' in res.reason and '[]' not in res.reason
    with pytest.raises(ParameterNotDeclaredException, match='unknown parameters nope, nope2'):
        node.set_parameters_atomically([Parameter('nope2', value=1), Parameter('nope', value=1)])
    assert set_('publish_rate_hz', 50.0).successful     # a known one still goes through


def test_descriptors_carry_ranges(running):
    _, _, _, describe = running
    (desc,) = describe(['publish_rate_hz']).descriptors
    assert desc.type == ParameterType.PARAMETER_DOUBLE and not desc.read_only
    (r,) = desc.floating_point_range
    assert r.from_value > 0 and r.to_value >= 200


def test_unknown_start_up_parameter_exits_2_naming_it():
    proc = node_process({'scene_file': SCENE, 'publish_rate': 50.0}, DOMAIN + 1)
    try:
        proc.wait(timeout=120)
    finally:
        code, out = stop_process(proc)
    assert code == 2
    assert 'publish_rate' in out and 'publish_rate_hz' in out and 'Traceback' not in out


def test_start_paused_waits_for_set_running_and_rejects_commands_meanwhile():
    with commanded_node(DOMAIN, SCENE, connect_s=30, start_paused=True) as (node, ex, cmd, _):
        frames, energy = node.counts['frames'], node.sim.energy()
        cmd.impact([0.1])
        assert spin_until(ex, lambda: node.counts['rejected'] == 1, 10)
        spin_until(ex, lambda: False, 0.5)
        assert node.sim.t == 0.0 and node.counts['frames'] == frames      # paused: no steps
        assert node.sim.energy() == energy                                # no impact stacked
        assert node.counts['accepted'] == 0 and not node.running
        key, verdict, detail = node.intake.last_command
        assert (key, verdict) == ('~/cmd/impact', 'rejected') and 'set_running true' in detail
        res = cmd.set_running(ex, True)
        assert res.success and res.message == 'running'
        cmd.impact([0.1])                                     # running: accepted
        assert spin_until(ex, lambda: node.counts['accepted'] == 1, 10)
        assert spin_until(ex, lambda: node.sim.t > 0.01 and cmd.strain, 30)
