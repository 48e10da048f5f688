"""The QoS of the node's endpoints: the default profile of every publisher and command
subscription, the structure's (transient-local: late subscribers and recorders get it), the
policies a ``qos_overrides.<topic>.<publisher|subscription>.<policy>`` parameter may set, and the
error naming an override that no endpoint declared."""
from __future__ import annotations

from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSPolicyKind, QoSProfile,
                       ReliabilityPolicy)
from rclpy.qos_overriding_options import QoSOverridingOptions

QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
# the structure (JSON): sent once per activation, kept for late subscribers and recorders
STRUCTURE_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL,
                           history=HistoryPolicy.KEEP_LAST)
# every publisher and command subscription takes its QoS from parameters
# qos_overrides.<topic>.<publisher|subscription>.<policy> (parameters file or -p), defaults above
QOS_OVERRIDES = QoSOverridingOptions(policy_kinds=(
    QoSPolicyKind.HISTORY, QoSPolicyKind.DEPTH, QoSPolicyKind.RELIABILITY,
    QoSPolicyKind.DURABILITY))


def fresh(base=QOS):
    """A fresh copy of ``base`` (rclpy writes the overrides into the profile it is given)."""
    return QoSProfile(history=base.history, depth=base.depth, reliability=base.reliability,
                      durability=base.durability)


def unknown_overrides(bad, valid):
    """The message of the ``qos_overrides.*`` parameters ``bad`` that no publisher or
    subscription declared, with the form and one of the ``valid`` names."""
    s, them = ('s', 'them') if len(bad) > 1 else ('', 'it')
    return (f'unknown QoS override{s} {", ".join(bad)}: no publisher or subscription of this '
            f'node has {them} (valid: qos_overrides.<topic>.<publisher|subscription>.<history|'
            f'depth|reliability|durability>, e.g. {valid[0] if valid else "none"}; '
            f'{len(valid)} in all)')
