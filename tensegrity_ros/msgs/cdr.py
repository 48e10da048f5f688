"""The node's frame messages serialized straight from NumPy arrays (CDR, little endian).

Building a ``visualization_msgs/MarkerArray`` of ~900 ``geometry_msgs/Point`` objects and having
rclpy convert them back to C costs milliseconds per message; the same bytes written from the arrays
cost tens of microseconds. :func:`marker_array_cdr` returns the serialized form of exactly what
:func:`tensegrity_ros.msgs.messages.marker_array` builds (a test deserializes one and compares it
to the other), ready for ``Publisher.publish(bytes)``. :func:`frame_messages_cdr` does the same for
every message of a frame (:func:`tensegrity_ros.msgs.messages.frame_messages`): the conversion of
message objects to C inside ``publish`` is the largest cost of publishing at 200 Hz.

Encoding: XCDR1 (plain CDR) little endian, as ROS 2's Fast DDS writes it: a 4-byte encapsulation
header ``00 01 00 00``, then every primitive aligned to its size (doubles to 8) relative to the end
of that header; strings are a uint32 length (with the NUL) then the bytes and a NUL; sequences a
uint32 count then the elements.
"""
from __future__ import annotations

import functools
import struct

import numpy as np

from tensegrity_ros.msgs import style as M

_HEADER = b'\x00\x01\x00\x00'
LINE_LIST = 5
FLOAT32 = 7                     # sensor_msgs/PointField.FLOAT32
ADD = 0


class _Writer:
    def __init__(self):
        self.parts = [_HEADER]
        self.n = 0                      # offset after the encapsulation header

    def _align(self, k):
        pad = (-self.n) % k
        if pad:
            self.parts.append(b'\x00' * pad)
            self.n += pad

    def raw(self, data):
        self.parts.append(data)
        self.n += len(data)

    def pack(self, fmt, size, *values):
        self._align(size)
        self.raw(struct.pack('<' + fmt, *values))

    def string(self, text):
        data = text.encode() + b'\x00'
        self.pack('I', 4, len(data))
        self.raw(data)

    def array(self, a, dtype, size):
        """A sequence of fixed-size elements from a C-ordered array (first axis = elements)."""
        self.pack('I', 4, len(a))
        if len(a):
            self._align(size)
            self.raw(np.ascontiguousarray(a, dtype=dtype).tobytes())

    def header(self, sec, nanosec, frame_id):
        self.pack('iI', 4, sec, nanosec)
        self.string(frame_id)

    def bytes(self):
        return b''.join(self.parts)

    def block(self, key, build):
        """Append the bytes ``build(writer)`` writes, cached per ``key`` and start alignment:
        for constant fields the padding depends only on the offset modulo 8, so the bytes are
        built once (a marker's constant fields are ~40 small writes)."""
        k = (key, self.n % 8)
        data = _BLOCKS.get(k)
        if data is None:
            w = _Writer()
            w.parts, w.n = [], self.n % 8
            build(w)
            data = _BLOCKS[k] = b''.join(w.parts)
        self.raw(data)


_BLOCKS = {}


def _marker_fields(w, ns, marker_id, color):
    w.string(ns)
    w.pack('iii', 4, marker_id, LINE_LIST, ADD)
    w.pack('7d', 8, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)           # pose: origin, identity
    w.pack('3d', 8, M.LINE_WIDTH_M, 0.0, 0.0)                     # scale
    w.pack('4f', 4, *color)                                       # color
    w.pack('iI', 4, 0, 0)                                         # lifetime
    w.pack('?', 1, False)                                         # frame_locked


def _marker_tail(w):
    w.pack('I', 4, 0)                                             # colors
    w.string('')                                                  # texture_resource
    w.header(0, 0, '')                                            # texture: header,
    w.string('')                                                  #   format,
    w.pack('I', 4, 0)                                             #   data
    w.pack('I', 4, 0)                                             # uv_coordinates
    w.string('')                                                  # text
    w.string('')                                                  # mesh_resource
    w.string('')                                                  # mesh_file: filename,
    w.pack('I', 4, 0)                                             #   data
    w.pack('?', 1, False)                                         # mesh_use_embedded_materials


def _marker(w, stamp, ns, marker_id, color, ends):
    w.header(stamp.sec, stamp.nanosec, M.FRAME_ID)
    color = tuple(float(c) for c in color)
    w.block(('marker', ns, marker_id, color),
            lambda b: _marker_fields(b, ns, marker_id, color))    # constant: cached
    w.array(ends, '<f8', 8)                                       # points
    w.block('marker tail', _marker_tail)


def _ends(x, a, b):
    ends = np.empty((2 * len(a), 3))
    ends[0::2] = x[a]
    ends[1::2] = x[b]
    return ends


def marker_array_cdr(frame, network, stamp, t_max=None):
    """Serialized ``MarkerArray`` (bytes) equal to :func:`messages.marker_array` of the same
    arguments."""
    x = np.asarray(frame.positions, dtype=np.float64)
    if t_max is None:
        t_max = M.reference_tension_scale(network)
    bins, colors = M.cable_bins(frame.tension, t_max)
    bar_a = np.concatenate([network.bar_a, network.edge_a])
    bar_b = np.concatenate([network.bar_b, network.edge_b])
    w = _Writer()
    w.pack('I', 4, M.N_BINS + 2)
    _marker(w, stamp, 'bars', 0, M.BAR_COLOR, _ends(x, bar_a, bar_b))
    for k in range(M.N_BINS + 1):
        sel = bins == k
        _marker(w, stamp, 'cables', k, colors[k],
                _ends(x, network.cable_a[sel], network.cable_b[sel]))
    return w.bytes()


@functools.lru_cache(maxsize=64)
def _multi_array_prefix(labels, shape):
    """Everything of a ``Float64MultiArray`` before its data (layout, data count, padding)."""
    w = _Writer()
    w.pack('I', 4, len(labels))
    size_all = int(np.prod(shape)) if shape else 1
    stride = size_all
    for label, size in zip(labels, shape):
        w.string(label)
        w.pack('II', 4, int(size), int(stride))
        stride = stride // size if size else 0
    w.pack('I', 4, 0)                                             # data_offset
    w.pack('I', 4, size_all)                                      # data: count,
    if size_all:
        w._align(8)                                               #   then the doubles
    return w.bytes()


def multi_array_cdr(values, labels):
    """Serialized ``Float64MultiArray`` equal to :func:`messages.multi_array` of the same
    arguments."""
    a = np.ascontiguousarray(values, dtype='<f8')
    if a.ndim != len(labels):
        raise ValueError(f'multi_array: {a.ndim} axes but {len(labels)} labels')
    return _multi_array_prefix(tuple(labels), a.shape) + a.tobytes()


@functools.lru_cache(maxsize=16)
def _cloud_middle(n_points):
    """The part of a ``PointCloud2`` between its stamp and its point data (frame id, sizes,
    fields, flags, data count): fixed for a number of points."""
    w = _Writer()
    w.pack('iI', 4, 0, 0)                                         # stamp placeholder
    w.string(M.FRAME_ID)
    w.pack('II', 4, 1, n_points)                                  # height, width
    w.pack('I', 4, len(M.XYZ))
    for name, offset in M.XYZ:
        w.string(name)
        w.pack('I', 4, offset)
        w.pack('B', 1, FLOAT32)
        w.pack('I', 4, 1)
    w.pack('?', 1, False)                                         # is_bigendian
    w.pack('II', 4, 12, 12 * n_points)                            # point_step, row_step
    w.pack('I', 4, 12 * n_points)                                 # data count
    return w.bytes()[len(_HEADER) + 8:]


def nodes_cloud_cdr(positions, stamp):
    """Serialized ``PointCloud2`` equal to :func:`messages.nodes_cloud` of the same arguments."""
    p = np.ascontiguousarray(positions, dtype='<f4')
    return b''.join((_HEADER, struct.pack('<iI', stamp.sec, stamp.nanosec),
                     _cloud_middle(p.shape[0]), p.tobytes(), b'\x01'))        # is_dense


def clock_cdr(stamp):
    """Serialized ``rosgraph_msgs/Clock``."""
    return _HEADER + struct.pack('<iI', stamp.sec, stamp.nanosec)


def frame_messages_cdr(frame, network, stamp=None, markers=True, clock=False, t_max=None):
    """:func:`tensegrity_ros.msgs.messages.frame_messages` as serialized messages: dict topic
    key -> bytes."""
    return M.frame_topics(frame, network, _BYTES, stamp, markers, clock, t_max)


_BYTES = M.Builders(cloud=nodes_cloud_cdr, multi=multi_array_cdr, markers=marker_array_cdr,
                    clock=clock_cdr)
