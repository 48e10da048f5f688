"""Changes of the running node's parameters (``set_parameters``, ``ros2 param set``): refused
with the reason the start-up check would give, or made to take effect at once."""
from __future__ import annotations

from rcl_interfaces.msg import SetParametersResult

from tensegrity_ros.node import endpoints
from tensegrity_ros.node.params import check_parameters, refusal


def check_changes(current, params):
    """The answer to a change of ``params`` (rclpy ``Parameter`` objects) of a node whose values
    are ``current``: refused with the reason for a value the start-up check would refuse or a
    parameter fixed while the node runs."""
    reason = refusal(current, {p.name: p.value for p in params})
    return SetParametersResult(successful=reason is None, reason=reason or '')


def apply_changes(node, params):
    """Make the accepted changes ``params`` take effect now on ``node``: the pace
    (``real_time_factor`` counts from the change), the timer's period, ``/clock`` switched on;
    one log line names what changed."""
    new = check_parameters(dict(node.params, **{p.name: p.value for p in params
                                                if p.name in node.params}))
    old, node.params = node.params, new
    if new['real_time_factor'] != old['real_time_factor'] and node.sim is not None:
        node.restart_pace()
    if new['publish_rate_hz'] != old['publish_rate_hz']:
        node.period = 1.0 / new['publish_rate_hz']
        if node.sim is not None:
            node.pacer.period = node.period
        if node.timer is not None:             # active (else: the next activation's)
            node.timer.timer_period_ns = round(node.period * 1e9)
            node.timer.reset()
    if new['use_sim_clock'] and node.sim is not None and '/clock' not in node.pubs:
        node.pubs['/clock'] = endpoints.publisher(node, '/clock')
    changed = [p.name for p in params if p.name in new and new[p.name] != old[p.name]]
    if changed:
        node.log('parameters', 'info', 'parameters: ' + ', '.join(
            f'{n} = {new[n]!r}' for n in changed))
