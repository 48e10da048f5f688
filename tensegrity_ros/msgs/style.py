"""What every form of the node's messages shares: names, topics and their types, stamps from
simulation time, the colours of the cable markers, and which topics one frame carries.

:mod:`tensegrity_ros.msgs.messages` builds rclpy message objects and
:mod:`tensegrity_ros.msgs.cdr` the same messages as CDR bytes; both take these definitions and
hand their builders to :func:`frame_topics`, so a frame's topics are decided in one place.
"""
from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np
from builtin_interfaces.msg import Time

FRAME_ID = 'world'
NAMESPACE = '/tensegrity'
NODE_NAME = 'tensegrity_sim'

TYPES = {
    '~/nodes': 'sensor_msgs/msg/PointCloud2',
    '~/strain': 'std_msgs/msg/Float64MultiArray',
    '~/cable_tension': 'std_msgs/msg/Float64MultiArray',
    '~/markers': 'visualization_msgs/msg/MarkerArray',
    '~/base_force': 'std_msgs/msg/Float64MultiArray',
    '~/striker': 'std_msgs/msg/Float64MultiArray',
    '/clock': 'rosgraph_msgs/msg/Clock',
    '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
    '~/cmd/prestrain': 'std_msgs/msg/Float64MultiArray',
    '~/cmd/impact': 'std_msgs/msg/Float64MultiArray',
    '~/structure': 'std_msgs/msg/String',     # JSON, transient-local, once per activation
    '~/cmd/focus': 'geometry_msgs/msg/PointStamped',
    '~/field': 'sensor_msgs/msg/Image',       # 32FC1 peak pressure map, at field_rate_hz
    '~/energy': 'std_msgs/msg/Float64MultiArray',   # per frame: ENERGY_LABEL
    '~/events': 'std_msgs/msg/String',        # commands applied or rejected, resets, pauses
}
PUBLISHED = ('~/nodes', '~/strain', '~/cable_tension', '~/markers', '/clock', '/diagnostics',
             '~/base_force', '~/energy', '~/events')
# the one dimension of ``~/energy``: its three values in order
ENERGY_LABEL = 'energy_J,constraint_error,energy_balance_error'
OPTIONAL = ('~/striker',)      # published only by scenes that have strikers
COMMANDS = ('~/cmd/prestrain', '~/cmd/impact')

BAR_COLOR = (0.55, 0.55, 0.6, 1.0)
LINE_WIDTH_M = 3.0e-4
N_BINS = 10                   # tension colour bins of the cable markers

XYZ = (('x', 0), ('y', 4), ('z', 8))     # PointCloud2 fields: float32 x y z, byte offsets


def resolve_topic(key, namespace=NAMESPACE, node=NODE_NAME):
    """Full topic name of a key: ``'~/nodes'`` -> ``'/tensegrity/tensegrity_sim/nodes'``;
    absolute keys are returned unchanged."""
    if key.startswith('~/'):
        ns = namespace.rstrip('/')
        return f'{ns}/{node}/{key[2:]}'
    return key


def sim_stamp(t):
    """``builtin_interfaces/Time`` of a simulation time ``t`` s (>= 0), rounded to the ns."""
    ns = int(round(float(t) * 1e9))
    if ns < 0:
        raise ValueError(f'stamp: negative simulation time {t!r}')
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def stamp_to_ns(stamp):
    """Nanoseconds of a ``builtin_interfaces/Time``."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


class Builders(NamedTuple):
    """The message builders of one form (objects or bytes): ``cloud(positions, stamp)``,
    ``multi(values, labels)``, ``markers(frame, network, stamp, t_max)``, ``clock(stamp)``."""
    cloud: Callable
    multi: Callable
    markers: Callable
    clock: Callable


def tension_colors(tension, t_max):
    """RGBA (n_cables, 4) in [0, 1]: blue (low) to red (``t_max``); slack cables dimmed grey."""
    t = np.asarray(tension, dtype=np.float64)
    u = np.clip(t / t_max, 0.0, 1.0) if t_max > 0 else np.zeros_like(t)
    rgba = np.empty((len(t), 4))
    rgba[:, 0] = u
    rgba[:, 1] = 0.2 * (1.0 - u)
    rgba[:, 2] = 1.0 - u
    rgba[:, 3] = 1.0
    slack = t <= 0.0
    rgba[slack] = (0.5, 0.5, 0.5, 0.25)
    return rgba


def cable_bins(tension, t_max):
    """Colour bin per cable (n_cables,) int: 0 slack, k = 1..N_BINS for tensions in
    ``[(k-1), k) * t_max / N_BINS`` (the last bin also holds everything above ``t_max``), and the
    RGBA colour of each bin (N_BINS + 1, 4): :func:`tension_colors` at the bin centre."""
    tension = np.asarray(tension, dtype=np.float64)
    u = np.clip(tension / t_max, 0.0, 1.0)
    bins = np.where(tension <= 0.0, 0, 1 + np.minimum((u * N_BINS).astype(np.int64), N_BINS - 1))
    centres = np.concatenate([[0.0], (np.arange(N_BINS) + 0.5) / N_BINS * t_max])
    return bins, tension_colors(centres, t_max)


def reference_tension_scale(network):
    """The top of the tension colour ramp, N: twice the largest cable tension of the reference
    geometry at the network's rest lengths (2 N when no cable is taut). The cable markers, the
    MCAP metadata and the Rerun recording all use it."""
    s = np.linalg.norm(network.x0[network.cable_b] - network.x0[network.cable_a], axis=1)
    L = network.cable_rest_length
    t = np.where(s > L, network.cable_EA * (s - L) / L, 0.0)
    return 2.0 * (float(t.max()) if t.size and t.max() > 0 else 1.0)


def energy_values(frame):
    """(3,) float64: the frame's energy J, constraint error and energy balance error (0 when the
    frame carries none)."""
    balance = frame.energy_balance_error
    return np.array([frame.energy, frame.constraint_error, 0.0 if balance is None else balance],
                    dtype=np.float64)


def check_finite(frame):
    """``ValueError`` if a frame holds a non-finite value (nothing NaN is ever published)."""
    for name in ('positions', 'strain', 'tension', 'base_force', 'striker', 'energy',
                 'constraint_error', 'energy_balance_error'):
        value = getattr(frame, name)
        if value is not None and not np.all(np.isfinite(value)):
            raise ValueError(f'frame at t = {frame.t:.6g} s: {name} is not finite')


def frame_topics(frame, network, build, stamp=None, markers=True, clock=False, t_max=None):
    """The messages of one publish frame, made by ``build`` (:class:`Builders`): dict topic key ->
    message. Always ``'~/nodes'`` (PointCloud2), ``'~/strain'`` (dims ``column``, ``prism``) and
    ``'~/cable_tension'`` (dim ``cable``, N); ``'~/energy'`` (energy J, constraint error,
    energy balance error: one dimension labelled :data:`ENERGY_LABEL`); ``'~/base_force'`` (dim
    ``column``, N, positive compressive) when the frame has one value per column;
    ``'~/striker'`` (dims ``column``, ``state``: face height m, axial velocity m/s) when the
    frame has strikers; ``'~/markers'`` when ``markers``; ``'/clock'`` when ``clock``. ``stamp``
    defaults to :func:`sim_stamp` of ``frame.t``. Raises ``ValueError`` if the frame holds a
    non-finite value."""
    check_finite(frame)
    if stamp is None:
        stamp = sim_stamp(frame.t)
    cloud, multi = build.cloud, build.multi
    out = {
        '~/nodes': cloud(frame.positions, stamp),
        '~/strain': multi(np.asarray(frame.strain).reshape(network.n_columns, network.n_prisms),
                          ('column', 'prism')),
        '~/cable_tension': multi(frame.tension, ('cable',)),
        '~/energy': multi(energy_values(frame), (ENERGY_LABEL,)),
    }
    base = np.asarray(frame.base_force)
    if base.shape == (network.n_columns,) and base.size:
        out['~/base_force'] = multi(base, ('column',))
    if frame.striker is not None:
        out['~/striker'] = multi(np.ascontiguousarray(frame.striker), ('column', 'state'))
    if markers:
        out['~/markers'] = build.markers(frame, network, stamp, t_max)
    if clock:
        out['/clock'] = build.clock(stamp)
    return out
