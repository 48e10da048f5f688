"""The node's endpoints: its publishers (QoS from the parameters), the command subscriptions the
tick takes from, the services, the check of the ``qos_overrides.*`` parameters, and their
destruction at cleanup."""
from __future__ import annotations

from geometry_msgs.msg import PointStamped
from rcl_interfaces.srv import SetParameters
from rclpy.event_handler import PublisherEventCallbacks
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool, Trigger

from tensegrity_ros.msgs import messages
from tensegrity_ros.node.focus import FIELD_TOPIC
from tensegrity_ros.node.intake import TakenByTick
from tensegrity_ros.node.params import ParameterError
from tensegrity_ros.node.publishing import STRUCTURE_TOPIC
from tensegrity_ros.node.qos import (QOS, QOS_OVERRIDES, STRUCTURE_QOS, fresh,
                                     unknown_overrides)

COMMANDS = (('~/cmd/impact', Float64MultiArray), ('~/cmd/prestrain', Float64MultiArray),
            ('~/cmd/focus', PointStamped))


def publisher(node, key, msg_class=None, qos=QOS):
    """The publisher of ``key`` on ``node``, QoS as overridden by the parameters. No QoS-event
    handlers: each is a waitable the executor polls on every tick."""
    return node.create_publisher(
        msg_class or messages.MSG_CLASSES[key], key, fresh(qos),
        event_callbacks=PublisherEventCallbacks(use_default_callbacks=False),
        qos_overriding_options=QOS_OVERRIDES)


def create(node, with_striker, services):
    """Publishers (``/clock`` while ``use_sim_clock``; the striker's topics ``with_striker``),
    the command subscriptions (taken by the tick, :class:`TakenByTick`) and the services
    (``services``: name -> callback of ``~/reset``, ``~/set_running``, ``~/step``) of ``node``;
    returns ``(pubs, subscriptions, services)``. Raises ParameterError (after destroying them
    again) for a ``qos_overrides.*`` parameter no endpoint declared."""
    pubs = {key: publisher(node, key) for key in messages.PUBLISHED + (
        messages.OPTIONAL if with_striker else ())
        if key != '/clock' or node.params['use_sim_clock']}
    pubs[STRUCTURE_TOPIC] = publisher(node, STRUCTURE_TOPIC, String, STRUCTURE_QOS)
    pubs[FIELD_TOPIC] = publisher(node, FIELD_TOPIC)
    by_tick = TakenByTick()
    handlers = node.intake.handlers
    subs = [(node.create_subscription(cls, key, handlers[key], fresh(), callback_group=by_tick,
                                      qos_overriding_options=QOS_OVERRIDES), handlers[key])
            for key, cls in COMMANDS]
    types = {'~/reset': Trigger, '~/set_running': SetBool, '~/step': SetParameters}
    srvs = [node.create_service(types[name], name, cb) for name, cb in services.items()]
    # rclpy has no public list of the overrides a node was given (-p, parameters file) apart
    # from the declared ones: a misspelled topic, entity or policy is only found in this one
    bad = sorted(n for n in node._parameter_overrides
                 if n.startswith('qos_overrides.') and not node.has_parameter(n))
    if bad:
        valid = sorted(n for n in node.list_parameters([], 0).names
                       if n.startswith('qos_overrides.'))
        destroy(node, pubs, subs, srvs)
        raise ParameterError(unknown_overrides(bad, valid))
    return pubs, subs, srvs


def destroy(node, pubs, subs, srvs):
    """Destroy the endpoints :func:`create` made."""
    for pub in pubs.values():
        node.destroy_publisher(pub)
    for sub, _ in subs:
        node.destroy_subscription(sub)
    for srv in srvs:
        node.destroy_service(srv)
