"""Frame -> ROS 2 messages: pure functions shared by the node and the MCAP writer.

Nothing here talks to ROS middleware: the functions build message objects from a
:class:`solver.simulate.simulation.Frame` and a :class:`solver.build.network.Network`, so the
node, the MCAP log
and the tests see exactly the same bytes.

Stable API (keep it so; the recorder depends on it):

- :data:`TYPES`: topic key -> ROS type name, e.g. ``'~/nodes' -> 'sensor_msgs/msg/PointCloud2'``.
  Keys starting with ``~/`` are private to the node, ``/clock`` and ``/diagnostics`` are absolute.
- :data:`MSG_CLASSES`: topic key -> message class.
- :func:`resolve_topic`: ``'~/nodes' -> '/tensegrity/tensegrity_sim/nodes'``.
- :func:`frame_messages` ``(frame, network, stamp=None, markers=True, clock=False)``: dict topic
  key -> message for one publish frame (stamps from simulation time ``frame.t``).
- :func:`diagnostics_message`, :func:`command_array`, :func:`sim_stamp`, :func:`stamp_to_ns`,
  :func:`nodes_cloud` / :func:`cloud_positions`, :func:`multi_array`, :func:`marker_array`,
  :func:`field_image` / :func:`image_values`.
"""
from __future__ import annotations

import array
import math

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PointStamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image, PointCloud2, PointField
from std_msgs.msg import ColorRGBA, Float64MultiArray, MultiArrayDimension, String
from visualization_msgs.msg import Marker, MarkerArray

from tensegrity_ros.msgs import style
from tensegrity_ros.msgs.style import (BAR_COLOR, COMMANDS, FRAME_ID, LINE_WIDTH_M,  # noqa: F401
                                       N_BINS, NAMESPACE, NODE_NAME, OPTIONAL, PUBLISHED, TYPES,
                                       XYZ, check_finite, resolve_topic, sim_stamp, stamp_to_ns)

MSG_CLASSES = {
    '~/nodes': PointCloud2, '~/strain': Float64MultiArray, '~/cable_tension': Float64MultiArray,
    '~/markers': MarkerArray, '~/base_force': Float64MultiArray,
    '~/striker': Float64MultiArray, '/clock': Clock, '/diagnostics': DiagnosticArray,
    '~/cmd/prestrain': Float64MultiArray, '~/cmd/impact': Float64MultiArray,
    '~/structure': String, '~/cmd/focus': PointStamped, '~/field': Image,
    '~/energy': Float64MultiArray, '~/events': String,
}
XYZ_FIELDS = [PointField(name=n, offset=offset, datatype=PointField.FLOAT32, count=1)
              for n, offset in XYZ]


def _header(msg, stamp):
    msg.header.stamp = stamp
    msg.header.frame_id = FRAME_ID
    return msg


def multi_array(values, labels):
    """``Float64MultiArray`` of a C-ordered array ``values`` with one layout dimension per axis,
    named by ``labels`` (stride = product of the sizes of that axis and the ones after it)."""
    a = np.ascontiguousarray(values, dtype=np.float64)
    if a.ndim != len(labels):
        raise ValueError(f'multi_array: {a.ndim} axes but {len(labels)} labels')
    msg = Float64MultiArray()
    stride = int(a.size)
    dims = []
    for label, size in zip(labels, a.shape):
        dims.append(MultiArrayDimension(label=label, size=int(size), stride=int(stride)))
        stride = stride // size if size else 0
    msg.layout.dim = dims
    msg.layout.data_offset = 0
    msg.data = array.array('d', a.tobytes())      # 30x faster than assigning the ndarray
    return msg


def command_array(values, label):
    """A command message (``~/cmd/prestrain`` or ``~/cmd/impact``): a flat vector with one layout
    dimension labelled ``label`` (``'all'``, ``'column'`` or ``'cross_cable'``)."""
    return multi_array(np.atleast_1d(np.asarray(values, dtype=np.float64)).ravel(), (label,))


def nodes_cloud(positions, stamp):
    """``PointCloud2`` of node positions (n_nodes, 3) m: float32 x y z, little endian, dense."""
    p = np.ascontiguousarray(positions, dtype='<f4')
    msg = _header(PointCloud2(), stamp)
    msg.height = 1
    msg.width = int(p.shape[0])
    msg.fields = XYZ_FIELDS
    msg.is_bigendian = False
    msg.point_step = 12
    msg.row_step = 12 * msg.width
    msg.is_dense = True
    msg.data = array.array('B', p.tobytes())
    return msg


def field_image(values, stamp):
    """``Image`` (encoding ``32FC1``, little endian) of a map ``values`` (height, width): row 0
    at the surface, depth growing down the rows, x along the columns. Non-finite values raise
    ValueError (never published)."""
    a = np.ascontiguousarray(values, dtype='<f4')
    if a.ndim != 2:
        raise ValueError(f'field image: expected a 2-D map, got shape {a.shape}')
    if not np.isfinite(a).all():
        raise ValueError('field image: non-finite values')
    msg = _header(Image(), stamp)
    msg.height, msg.width = (int(n) for n in a.shape)
    msg.encoding = '32FC1'
    msg.is_bigendian = 0
    msg.step = 4 * msg.width
    msg.data = array.array('B', a.tobytes())
    return msg


def image_values(msg):
    """Inverse of :func:`field_image`: the (height, width) float32 map of a ``32FC1`` image."""
    if msg.encoding != '32FC1' or msg.step != 4 * msg.width:
        raise ValueError(f'field image: expected dense 32FC1, got {msg.encoding!r}, step '
                         f'{msg.step} for width {msg.width}')
    dtype = '>f4' if msg.is_bigendian else '<f4'
    return np.frombuffer(bytes(msg.data), dtype=dtype).reshape(msg.height, msg.width)


def cloud_positions(msg):
    """Inverse of :func:`nodes_cloud`: (n_nodes, 3) float64 positions of a ``PointCloud2``."""
    raw = np.frombuffer(bytes(msg.data), dtype='<f4')
    return raw.reshape(msg.width * msg.height, 3).astype(np.float64)


def _line_list(marker_id, ns, stamp, x, a, b, color):
    m = _header(Marker(), stamp)
    m.ns = ns
    m.id = marker_id
    m.type = Marker.LINE_LIST
    m.action = Marker.ADD
    m.pose.orientation.w = 1.0
    m.scale.x = LINE_WIDTH_M
    m.color = ColorRGBA(r=float(color[0]), g=float(color[1]), b=float(color[2]),
                        a=float(color[3]))
    ends = np.empty((2 * len(a), 3))
    ends[0::2] = x[a]
    ends[1::2] = x[b]
    m.points = [Point(x=px, y=py, z=pz) for px, py, pz in ends.tolist()]
    return m


def marker_array(frame, network, stamp, t_max=None):
    """``MarkerArray`` of line lists: bars and rigid edges (ns ``bars``, id 0, grey) and cables
    coloured by tension (ns ``cables``): id 0 the slack cables (dimmed), ids 1..:data:`N_BINS` the
    taut cables in equal tension bins up to ``t_max`` N (default 2x the largest reference
    tension), each bin one colour of :func:`tension_colors`. Every marker is sent every time
    (possibly empty), so a viewer never keeps a stale one."""
    x = np.asarray(frame.positions, dtype=np.float64)
    if t_max is None:
        t_max = style.reference_tension_scale(network)
    bar_a = np.concatenate([network.bar_a, network.edge_a])
    bar_b = np.concatenate([network.bar_b, network.edge_b])
    bins, colors = style.cable_bins(frame.tension, t_max)
    arr = MarkerArray()
    arr.markers = [_line_list(0, 'bars', stamp, x, bar_a, bar_b, BAR_COLOR)] + [
        _line_list(k, 'cables', stamp, x, network.cable_a[bins == k],
                   network.cable_b[bins == k], colors[k]) for k in range(N_BINS + 1)]
    return arr


def frame_messages(frame, network, stamp=None, markers=True, clock=False, t_max=None):
    """Messages of one publish frame: dict topic key -> message object (see
    :func:`tensegrity_ros.msgs.style.frame_topics` for the topics; :func:`tensegrity_ros.msgs.cdr.
    frame_messages_cdr` gives the same messages as CDR bytes). ``stamp`` defaults to
    :func:`sim_stamp` of ``frame.t``. Raises ``ValueError`` if the frame holds a non-finite value
    (nothing NaN is ever published)."""
    return style.frame_topics(frame, network, _OBJECTS, stamp, markers, clock, t_max)


def diagnostics_message(stamp, values, level=0, message='', name='tensegrity_sim',
                        hardware_id='simulation'):
    """``DiagnosticArray`` with one status: ``values`` a dict name -> value (floats formatted with
    ``%.6g``, non-finite floats as ``'n/a'``), ``level`` 0 OK, 1 WARN, 2 ERROR, 3 STALE."""
    status = DiagnosticStatus(level=bytes([int(level)]), name=name, message=str(message),
                              hardware_id=hardware_id)
    kv = []
    for key, value in values.items():
        if isinstance(value, float):
            text = f'{value:.6g}' if math.isfinite(value) else 'n/a'
        else:
            text = str(value)
        kv.append(KeyValue(key=str(key), value=text))
    status.values = kv
    arr = DiagnosticArray()
    arr.header.stamp = stamp
    arr.header.frame_id = FRAME_ID
    arr.status = [status]
    return arr


_OBJECTS = style.Builders(cloud=nodes_cloud, multi=multi_array, markers=marker_array,
                          clock=lambda stamp: Clock(clock=stamp))
