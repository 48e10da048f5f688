"""The helper process's side of a Rerun recording (:mod:`tensegrity_ros.io.rerun_log` is the
recorder's side, in the simulation's process): :func:`serve` runs in a fresh interpreter and
writes each recording handed to it through an owned :class:`rerun.RecordingStream`
(:class:`_Writer`); the entities are listed in :mod:`tensegrity_ros.io.rerun_log`. Only this module
imports rerun-sdk and pyarrow: the simulation's process does not pay their import (0.3 s).
"""
from __future__ import annotations

import math
import mmap
import os
import signal
import threading
import time
from multiprocessing.connection import Connection
from multiprocessing.reduction import recv_handle

import numpy as np
import pyarrow as pa
import pyarrow.compute  # noqa: F401  (imported by rerun on first use; load it with the module)
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import Chunk

TIMELINE = 'sim_time'

# Cable colours as on the ROS markers (messages.tension_colors): blue (slack side) to red at
# ``tension_scale``; slack cables grey and translucent.
_BAR_RGBA = (200, 200, 210, 255)
_NODE_RGBA = (240, 120, 40, 255)


def _rgba32(r, g, b, a):
    return (np.uint32(r) << 24) | (np.uint32(g) << 16) | (np.uint32(b) << 8) | np.uint32(a)


_U = np.linspace(0.0, 1.0, 256)
_LUT = _rgba32(np.rint(255 * _U).astype(np.uint32), np.rint(51 * (1 - _U)).astype(np.uint32),
               np.rint(255 * (1 - _U)).astype(np.uint32), np.uint32(255))
SLACK_COLOR = _rgba32(128, 128, 128, 64)
_LUT_SLACK = np.concatenate(([SLACK_COLOR], _LUT))        # index 0: slack, 1 + level
def tension_colors(tension, scale):
    """Packed RGBA (``0xRRGGBBAA``, uint32) per cable: tension ``(..., n_cables)`` N mapped by
    ``u = T / scale`` (clipped to [0, 1], 256 levels) to ``(u, 0.2 (1 - u), 1 - u)``; slack cables
    (T <= 0) get :data:`SLACK_COLOR`."""
    tension = np.asarray(tension, dtype=np.float64)
    idx = np.multiply(tension, 255.0 / scale)
    np.rint(idx, out=idx)
    np.minimum(np.maximum(idx, 0.0, out=idx), 255.0, out=idx)
    idx += tension > 0.0                        # 0: slack, else 1 + the level
    return _LUT_SLACK.take(idx.astype(np.intp))


def _ns(t):
    """Seconds -> int64 nanoseconds (the ``sim_time`` index), elementwise."""
    return np.rint(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64)


def trails(a, b, n_nodes):
    """Cover the members ``a[k]`` - ``b[k]`` (node indices) with trails, each member exactly once:
    a list of node index arrays, consecutive nodes of a trail joined by a member. Walks start at
    odd-degree nodes first, so a chain of bars (a column's three helices) becomes one trail; drawn
    as one line strip each, they need about half the points of one strip per member."""
    adj = [[] for _ in range(n_nodes)]
    for e, (u, v) in enumerate(zip(np.asarray(a).tolist(), np.asarray(b).tolist())):
        adj[u].append((v, e))
        adj[v].append((u, e))
    used = [False] * len(np.asarray(a))
    nxt = [0] * n_nodes
    out = []
    for start in [n for n in range(n_nodes) if len(adj[n]) % 2] + list(range(n_nodes)):
        while True:
            path, u = [start], start
            while True:
                while nxt[u] < len(adj[u]) and used[adj[u][nxt[u]][1]]:
                    nxt[u] += 1
                if nxt[u] == len(adj[u]):
                    break
                v, e = adj[u][nxt[u]]
                used[e] = True
                path.append(v)
                u = v
            if len(path) == 1:
                break
            out.append(np.array(path, dtype=np.int64))
    return out


class _Strips:
    """Line strips through fixed node sequences (one strip per sequence): ``index`` picks a
    strip point's coordinates out of one frame's ``x.ravel()``; ``offsets`` are the strip offsets
    of up to ``n_frames`` frames of strips (sliced per batch; never written after construction,
    so Arrow arrays may view them)."""

    def __init__(self, sequences, n_frames):
        if isinstance(sequences, np.ndarray):         # (n, k): n strips of k nodes each
            nodes = sequences.reshape(-1).astype(np.int64)
            self.lengths = np.full(len(sequences), sequences.shape[1], dtype=np.int32)
        else:
            nodes = np.concatenate(sequences) if sequences else np.zeros(0, np.int64)
            self.lengths = np.array([len(s) for s in sequences], dtype=np.int32)
        self.index = (nodes[:, None] * 3 + np.arange(3)).ravel()      # into one frame's x.ravel()
        self.n = len(self.lengths)
        self.offsets = np.zeros(n_frames * self.n + 1, dtype=np.int32)
        np.cumsum(np.tile(self.lengths, n_frames), out=self.offsets[1:])

    def arrow(self, points, n_t):
        """One Arrow ``LineStrip3D`` array of ``n_t * n`` strips from their points, float32 m
        (``n_t * len(index)`` values, frame after frame), built directly (rerun's generic
        conversion loops over strips in Python)."""
        inner = pa.FixedSizeListArray.from_arrays(_f32(points), type=_STRIP_TYPE.value_type)
        return pa.ListArray.from_arrays(_i32(self.offsets[:n_t * self.n + 1]), inner,
                                        type=_STRIP_TYPE)


def _f32(a):
    """A 1-D contiguous numpy array as an Arrow array, zero-copy."""
    return pa.Array.from_buffers(pa.float32(), len(a), [None, pa.py_buffer(a)])


def _i32(a):
    return pa.Array.from_buffers(pa.int32(), len(a), [None, pa.py_buffer(a)])


def _pack(rows, n_t, n_x, n_p, n_s, n_c, bar_index, cable_index, scale):
    """(helper) The Rerun arrays of the first ``n_t`` rows of a batch buffer: node positions,
    bar-trail points and cable end points as float32 (frame after frame), the cable colours
    (:func:`tension_colors` with ``scale``), the strain per column (column, frame, prism:
    ``n_s / n_p`` columns of ``n_p`` prisms), energy, constraint error and the times in int64 ns.
    Every array is new. NumPy: a compiled version took 0.23 instead of 0.41 ms per 50 frames, but
    its first call in a process 0.22 s (loading the numba cache), more than it saves in a run of
    ``tensegrity run``."""
    r = rows[:n_t]
    nodes = r[:, :n_x].astype(np.float32)
    bars = nodes.take(bar_index, axis=1).reshape(-1)        # gathered from float32: 2x fewer bytes
    cables = nodes.take(cable_index, axis=1).reshape(-1)
    colors = tension_colors(r[:, n_x + n_s:n_x + n_s + n_c], scale).reshape(-1)
    # copied in every case (a reshape alone views the buffer when there is one prism)
    strain = r[:, n_x:n_x + n_s].reshape(n_t, -1, max(n_p, 1)).transpose(1, 0, 2).copy()
    strain = strain.reshape(-1)
    times = _ns(r[:, -3])
    return (nodes.reshape(-1), bars, cables, colors, strain, r[:, -2].copy(), r[:, -1].copy(),
            times)


_STRIP_TYPE = rr.components.LineStrip3DBatch._ARROW_DATATYPE
_POINT_TYPE = rr.components.Position3DBatch._ARROW_DATATYPE


class _Column:
    """A component column for ``Chunk.from_columns`` / ``send_columns`` built directly as Arrow:
    ``array`` holds one list of components per row (what :class:`rerun.ComponentColumn` hands
    over, without its generic conversions); likewise :class:`_Times` for the ``sim_time``
    index."""

    __slots__ = ('descriptor', 'array')

    def __init__(self, descriptor, array):
        self.descriptor, self.array = descriptor, array

    def component_descriptor(self):
        return self.descriptor

    def as_arrow_array(self):
        return self.array


class _Times:
    __slots__ = ('array',)

    def __init__(self, ns):
        """``ns``: 1-D contiguous int64 nanoseconds (viewed, not copied)."""
        self.array = pa.Array.from_buffers(pa.duration('ns'), len(ns), [None, pa.py_buffer(ns)])

    def timeline_name(self):
        return TIMELINE

    def as_arrow_array(self):
        return self.array


def _row_chunk(entity_path, archetype, t=None):
    """A chunk of one row of an archetype's components, static (``t`` None) or at ``sim_time``
    ``t`` s: what ``log(entity_path, archetype, static=...)`` records (after ``set_time``),
    without the row batcher."""
    return Chunk.from_columns(entity_path, [] if t is None else [_Times(_ns([t]))], [
        _Column(batch.component_descriptor(), _one_row(batch.as_arrow_array()))
        for batch in archetype.as_component_batches()])


def _one_row(values):
    """A column of one row holding every element of ``values``."""
    return pa.ListArray.from_arrays(pa.array([0, len(values)], pa.int32()), values)


_TENSOR_TYPE = rr.components.TensorDataBatch._ARROW_DATATYPE
_RANGE_TYPE = rr.components.ValueRangeBatch._ARROW_DATATYPE
_UNION = _TENSOR_TYPE.field('buffer').type
_F64 = [f.name for f in _UNION].index('F64')
# the union's other members, empty (constants: built once, 0.3 ms per wave image otherwise)
_UNION_EMPTY = [pa.nulls(0, f.type) if pa.types.is_null(f.type) else pa.array([], type=f.type)
                for f in _UNION]
_UNION_TAG = pa.py_buffer(np.array([_UNION.type_codes[_F64]], np.int8))
_UNION_OFFSET = pa.py_buffer(np.zeros(1, np.int32))


def tensor_data(image, dim_names):
    """One ``TensorData`` (what ``rr.Tensor(image, dim_names=...)`` logs as ``Tensor:data``) of a
    float64 array, built directly as Arrow: shape, dimension names and the values (a copy of
    ``image``, wrapped without a further one) as the ``F64`` member of the buffer union
    (``rr.Tensor`` converts in Python, 1.3 ms for a 50 x 241 image)."""
    image = np.array(image, dtype=np.float64, order='C')        # a copy: Arrow keeps viewing it
    shape = pa.array([list(image.shape)], _TENSOR_TYPE.field('shape').type)
    names = pa.array([list(dim_names)], _TENSOR_TYPE.field('names').type)
    return _tensors(image.reshape(-1), np.array([0, image.size], np.int32), shape, names)


def vectors_data(values, n_rows):
    """``n_rows`` 1-D ``TensorData`` of equal length (what ``rr.BarChart(row)`` logs as
    ``BarChart:values``, row after row), built directly as Arrow around ``values`` (float64,
    ``n_rows * k`` values, row after row; viewed, not copied)."""
    k = len(values) // max(n_rows, 1)
    offsets = np.arange(n_rows + 1, dtype=np.int32) * k
    shape = pa.ListArray.from_arrays(_i32(offsets // max(k, 1)),
                                     pa.array(np.full(n_rows, k, np.uint64)),
                                     type=_TENSOR_TYPE.field('shape').type)
    names = pa.nulls(n_rows, _TENSOR_TYPE.field('names').type)
    return _tensors(values, offsets, shape, names)


def _tensors(values, offsets, shape, names):
    """TensorData rows: the F64 lists ``values[offsets[i]:offsets[i + 1]]``."""
    n = len(offsets) - 1
    children = list(_UNION_EMPTY)
    children[_F64] = pa.ListArray.from_arrays(
        _i32(offsets), pa.Array.from_buffers(pa.float64(), len(values),
                                             [None, pa.py_buffer(values)]),
        type=_UNION[_F64].type)
    tags = _UNION_TAG if n == 1 else pa.py_buffer(np.full(n, _UNION.type_codes[_F64], np.int8))
    index = _UNION_OFFSET if n == 1 else pa.py_buffer(np.arange(n, dtype=np.int32))
    buffer = pa.UnionArray.from_buffers(      # keeps the union's exact type (field nullability)
        _UNION, n, [None, tags, index], children=children)
    return pa.StructArray.from_arrays([shape, names, buffer], fields=list(_TENSOR_TYPE))


_TENSOR_DATA = rr.Tensor.descriptor_data()
_TENSOR_RANGE = rr.Tensor.descriptor_value_range()
_POSITIONS = rr.Points3D.descriptor_positions()
_STRIPS = rr.LineStrips3D.descriptor_strips()
_COLORS = rr.LineStrips3D.descriptor_colors()
_SCALARS = rr.Scalars.descriptor_scalars()
_BAR_VALUES = rr.BarChart.descriptor_values()


def _threads():
    """Native ids of this process's threads (Linux), else an empty set."""
    try:
        return {int(t) for t in os.listdir('/proc/self/task')}
    except OSError:
        return set()


def blueprint(n_columns=1, field_grid=None):
    """The default layout, as the paper's figures: on the left the 3D column (cables coloured by
    tension) above the colour legend (with a ``field_grid``, the field in the medium between
    them: the peak pressure so far and the pressure at the time cursor); on the right the strain
    along the column at the time cursor (a bar chart per prism), the prism-by-``sim_time`` heat
    map of the wave from the impact with its colour scale, energy and constraint error side by
    side, and the command log. Several columns: one tab per column for the bar chart and for the
    heat map (the columns' scales stay comparable: each heat map is symmetric about zero at its
    own largest strain)."""
    bars = [rrb.BarChartView(origin=f'strain_profile/column_{c}',
                             name=f'strain per prism at the time cursor, column {c} '
                                  f'(prism 0: clamped end)',
                             plot_legend=rrb.archetypes.PlotLegend(visible=False))
            for c in range(n_columns)]
    waves = [rrb.Vertical(
        rrb.TensorView(origin=f'wave/column_{c}',
                       name=f'strain, prism x sim_time from the impact, column {c}',
                       slice_selection=rrb.archetypes.TensorSliceSelection(
                           width=rr.TensorDimensionSelection(1),
                           height=rr.TensorDimensionSelection(0)),
                       scalar_mapping=rrb.archetypes.TensorScalarMapping(colormap=COLORMAP),
                       view_fit='fill'),
        rrb.TensorView(origin=f'wave_scale/column_{c}', name='colour scale: strain',
                       scalar_mapping=rrb.archetypes.TensorScalarMapping(colormap=COLORMAP),
                       view_fit='fill'),
        row_shares=[5, 1], name=f'column {c}')
        for c in range(n_columns)]

    def one_or_tabs(views):
        return views[0] if len(views) == 1 else rrb.Tabs(*views)
    left = [rrb.Spatial3DView(origin='world', name='column, cables coloured by tension')]
    shares = [6]
    if field_grid is not None:
        x0, x1, z0, z1 = field_grid
        where = f'x {x0:.3g} to {x1:.3g} m across, depth {z0:.3g} to {z1:.3g} m down'
        left.append(rrb.Horizontal(
            rrb.Spatial2DView(origin='field/peak_pressure',
                              name=f'peak pressure in the medium so far, {where}'),
            rrb.Spatial2DView(origin='field/pressure', name='pressure at the time cursor '
                              '(grey: zero)')))
        shares = [4, 3]
    left.append(rrb.TextDocumentView(origin='legend', name='colours'))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(*left, row_shares=shares + [1]),
            rrb.Vertical(
                one_or_tabs(bars),
                one_or_tabs(waves),
                rrb.Horizontal(rrb.TimeSeriesView(origin='base_force', name='base force, N'),
                               rrb.TimeSeriesView(origin='energy', name='energy, J'),
                               rrb.TimeSeriesView(origin='constraint_error',
                                                  name='constraint error')),
                rrb.TextLogView(origin='commands', name='commands'),
                row_shares=[3, 4, 1.5, 1]),
            column_shares=[2, 3]),
        rrb.BlueprintPanel(state='collapsed'),
        rrb.SelectionPanel(state='collapsed'),
        rrb.TimePanel(timeline=TIMELINE, state='collapsed'))


COLORMAP = 'Spectral'
PRISM_AXIS = 'prism (0: clamped end)'


def legend_markdown(tension_scale):
    """The text of the ``legend`` entity: what the colours of the 3D view mean."""
    return (f'**Cables**: tension T from blue (0 N) to red (T >= {tension_scale:.3g} N, twice '
            f'the largest prestress tension); slack cables grey and translucent. '
            f'**Bars** light grey, **nodes** orange. Heat map and bar chart: axial strain, '
            f'negative in compression.')


def _topology_arrays(net):
    """The network's topology as logged on ``topology`` (``AnyValues`` fields)."""
    return {'bar_a': np.asarray(net.bar_a, np.int64), 'bar_b': np.asarray(net.bar_b, np.int64),
            'cable_a': np.asarray(net.cable_a, np.int64),
            'cable_b': np.asarray(net.cable_b, np.int64),
            'cable_kind': np.array([str(k) for k in net.cable_kind], dtype=object),
            'levels': np.asarray(net.levels, np.int64).ravel(),
            'levels_shape': np.asarray(net.levels.shape, np.int64),
            'x0': np.asarray(net.x0, np.float64).ravel()}


def _style_archetypes(tension_scale=1.0):
    """The static entities that do not depend on the network: view coordinates, colours and
    radii, the colour legend, the names of the energy and constraint-error series."""
    return [
        ('legend', rr.TextDocument(legend_markdown(tension_scale), media_type='text/markdown')),
        ('world', rr.ViewCoordinates.RIGHT_HAND_Z_UP),                  # column axis: z
        ('world/nodes', rr.Points3D.from_fields(colors=[_NODE_RGBA],
                                                radii=rr.Radius.ui_points(3.0))),
        ('world/bars', rr.LineStrips3D.from_fields(colors=[_BAR_RGBA],
                                                   radii=rr.Radius.ui_points(2.5))),
        ('world/cables', rr.LineStrips3D.from_fields(radii=rr.Radius.ui_points(1.2))),
        ('energy', rr.SeriesLines(names=['energy'])),
        ('constraint_error', rr.SeriesLines(names=['constraint error']))]


def static_archetypes(net, tension_scale=1.0):
    """The static entities of a recording of ``net`` as rerun archetypes: (entity path,
    archetype) pairs. The recorder logs the same components, the network's arrays built
    directly (see ``RerunRecorder._log_static``); this is the reference it is tested against."""
    topo = _topology_arrays(net)
    topo['cable_kind'] = list(topo['cable_kind'])
    names = [f'prism {p}' for p in range(net.n_prisms)]
    return ([('topology', rr.AnyValues(**topo))] + _style_archetypes(tension_scale)
            + [(f'strain/column_{c}', rr.SeriesLines(names=names))
               for c in range(net.n_columns if net.n_prisms else 0)])


class _Net0:
    """A network of nothing: the types of the topology arrays."""
    bar_a = bar_b = cable_a = cable_b = cable_kind = x0 = levels = np.zeros((0,), np.int64)
    n_prisms = n_columns = 0


# the descriptors of the topology fields (AnyValues), from one value of each type
_ANY = {b.component_descriptor().component: b.component_descriptor()
        for b in rr.AnyValues(**{name: ['x'] if a.dtype == object else np.zeros(1, a.dtype)
                                 for name, a in _topology_arrays(_Net0()).items()})
        .as_component_batches()}
_SERIES_NAMES = rr.SeriesLines.descriptor_names()


# -- the helper process ---------------------------------------------------------------------------
def serve(fd):
    """(helper process) Write the recordings described by the messages on the socket ``fd``, one
    after the other; exit when the other end closes (a recording in progress is finished first,
    so that a killed simulation still leaves a complete file of what it handed over). Interrupts
    are ignored: the process that owns the recording decides when it ends."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    conn = _OwnedConnection(fd, os.getppid())
    all_cpus = os.sched_getaffinity(0)
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg[0] != 'open':
            continue
        memfd = recv_handle(conn)
        if not _Writer(conn, memfd, all_cpus, *msg[1:]).run():
            return


class _OwnedConnection(Connection):
    """The connection to the recording process, which is this process's parent: a receive that
    waits checks, every :data:`OWNER_CHECK_S`, that the parent is still there, and ends as the
    connection's end (EOFError) when it is not. The socket alone would not tell: a process the
    owner forked keeps its end open after the owner is gone."""

    def __init__(self, fd, owner):
        super().__init__(fd)
        self.owner = owner

    def recv(self):
        while not self.poll(OWNER_CHECK_S):
            if os.getppid() != self.owner:
                raise EOFError('the recording process is gone')
        return super().recv()


OWNER_CHECK_S = 0.25


class _Writer:
    """(helper process) One recording: the stream, its sinks, the blueprint and the static
    entities, then the batches, commands and wave images handed over, until ``close``. Batches
    are read from shared memory (``memfd``: float64 buffers of ``buffer_shape``, buffer x row x
    value, as the recorder fills them); each buffer is handed back (``free``) once
    sent. The first error is reported (``error``) and the rest is drained without sending; the
    file is finished in any case."""

    def __init__(self, conn, memfd, all_cpus, net, path, url, tension_scale, flush_every,
                 wave_window, wave_period_s, shapes, buffer_shape, cpus, application_id,
                 recording_id, send_blueprint, field_grid=None):
        self._cpu0 = time.process_time()
        self.conn, self.all_cpus = conn, all_cpus
        self.net, self.path, self.url = net, path, url
        self.tension_scale, self.flush_every = tension_scale, flush_every
        self.wave_window, self.wave_period_s = wave_window, wave_period_s
        self._shapes = shapes
        self.field_grid = field_grid
        try:
            self._mem = mmap.mmap(memfd, 8 * math.prod(buffer_shape))
        finally:
            os.close(memfd)
        self._buffers = np.ndarray(buffer_shape, np.float64, self._mem)
        self._stream = None
        self._error = None
        self._tids = set()
        self._wave, self._wave_n = None, 0      # set again by _open (which may fail before)
        if cpus:                                # inherited by the threads Rerun starts
            try:
                os.sched_setaffinity(0, cpus)
            except OSError:
                pass
        self._do(self._open, application_id, recording_id, send_blueprint)

    def _do(self, fn, *args):
        if self._error is not None:             # after an error, drain without sending
            return
        try:
            fn(*args)
        except Exception as exc:
            self._error = exc
            try:
                self.conn.send(('error', _message(exc)))
            except OSError:                     # the recording process is gone: finish anyway
                pass

    def run(self):
        """Serve this recording until ``close`` (True) or until the other end goes (False)."""
        conn = self.conn
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                self._close(None, 0)
                return False
            kind = msg[0]
            if kind == 'send':
                _, index, n_t, wave, restart = msg
                self._do(self._send, index, n_t, wave, restart)
                if index is not None:
                    conn.send(('free', index))
            elif kind == 'commands':
                self._do(self._log_commands, msg[1])
            elif kind == 'field':
                self._do(self._log_field, *msg[1:])
            elif kind == 'sync':
                conn.send(('synced',))
            elif kind == 'close':
                error = self._close(*msg[1:])
                conn.send(('closed', error, time.process_time() - self._cpu0))
                return True

    def _close(self, index, n_t):
        """Spread over every CPU (the recording process waits now), send the last batch and the
        wave image, finish the file; the first error's message, or None."""
        for tid in self._tids:
            try:
                os.sched_setaffinity(tid, self.all_cpus)
            except OSError:                     # a thread that has ended
                pass
        if self._stream is not None:
            self._do(self._send, index, n_t, False, False)
            if self._wave is not None and self._wave_n:
                self._do(self._log_wave, True)
            self._do(self._log_bar_range)
            try:
                self._finish()
            except Exception as exc:
                if self._error is None:
                    self._error = exc
        del self._buffers
        self._mem.close()
        return None if self._error is None else _message(self._error)

    def _open(self, application_id, recording_id, send_blueprint):
        net = self.net
        before = _threads()
        stream = rr.RecordingStream(application_id, recording_id=recording_id)
        stream.set_log_time_enabled(False)            # sim_time only: no wall-clock timelines
        stream.set_log_tick_enabled(False)
        sinks = []
        if self.path is not None:
            sinks.append(rr.FileSink(self.path))
        if self.url is not None:
            sinks.append(rr.GrpcSink(self.url))
        stream.set_sinks(*sinks)
        self._stream = stream
        self._tids = (_threads() - before) | {threading.get_native_id()}   # Rerun's and ours
        if send_blueprint:                      # applied however the file is opened
            stream.send_blueprint(blueprint(max(net.n_columns, 1), self.field_grid),
                                  make_active=True,
                                  make_default=True)
        self._log_static()
        self._bars = _Strips(trails(net.bar_a, net.bar_b, net.n_nodes), self.flush_every)
        self._cables = _Strips(np.stack([np.asarray(net.cable_a), np.asarray(net.cable_b)],
                                        axis=1).reshape(-1, 2), self.flush_every)
        self._pack_args = (net.n_prisms, math.prod(self._shapes[1]), net.n_cables,
                           self._bars.index, self._cables.index, self.tension_scale)
        self._offsets = {}                      # (n_t, k) -> row offsets, as Arrow
        self._wave = None                       # (n_columns, n_prisms, wave_window) ring
        self._wave_times = np.empty(self.wave_window)   # the ring's frame times, s
        self._impact_t = None                   # time of the last impact command, s
        self._lo = self._hi = None              # strain extremes per column so far
        self._wave_n = 0                        # frames in the wave (since the last restart)
        self._wave_t = 0.0                      # time of its last frame
        self._wave_pending = False
        self._last_wave = time.monotonic()

    def _log_static(self):
        """The static entities, as one static chunk each, sent in one call: what
        :func:`static_archetypes` logs (tested equal), with the network's arrays (topology,
        series names) wrapped directly as Arrow instead of converted by rerun's archetypes
        (0.8 ms less per recording)."""
        net = self.net
        topology = [(_ANY[name], pa.array(np.ascontiguousarray(values)))
                    for name, values in _topology_arrays(net).items()]
        names = pa.array([f'prism {p}' for p in range(net.n_prisms)], pa.string())
        static = [('topology', topology)] + [
            (path, [(b.component_descriptor(), b.as_arrow_array())
                    for b in archetype.as_component_batches()])
            for path, archetype in _style_archetypes(self.tension_scale)]
        static += [(f'strain/column_{c}', [(_SERIES_NAMES, names)])
                   for c in range(net.n_columns if net.n_prisms else 0)]
        rr.send_chunks([Chunk.from_columns(path, [], [_Column(d, _one_row(a)) for d, a in batches])
                        for path, batches in static], recording=self._stream)

    def _log_commands(self, entries):
        """``entries``: (t s, text, level) of the commands given since the last ones, as one
        chunk of ``commands`` (a row each)."""
        for t, text, _ in entries:
            if text.startswith('impact') or ': impact ' in text:   # the heat map starts here
                self._impact_t = t
        times, texts, levels = zip(*entries)
        rr.send_columns('commands', [_Times(_ns(times))],
                        rr.TextLog.columns(text=list(texts), level=list(levels)),
                        recording=self._stream)

    def _log_field(self, t, peak, pressure, scale):
        """``field/peak_pressure`` (and ``field/pressure``) Images and ``field/scale`` at ``t``."""
        chunks = [_row_chunk('field/peak_pressure', rr.Image(
            np.clip(peak / scale, 0.0, 1.0).astype(np.float32), color_model='L'), t),
            _row_chunk('field/scale', rr.Scalars([scale]), t)]
        if pressure is not None:
            chunks.append(_row_chunk('field/pressure', rr.Image(
                np.clip(0.5 + 0.5 * pressure / scale, 0.0, 1.0).astype(np.float32),
                color_model='L'), t))
        rr.send_chunks(chunks, recording=self._stream)

    def _send(self, index, n_t, wave, restart):
        """Send the first ``n_t`` rows of buffer ``index``; then the wave if due."""
        net, s = self.net, self._stream
        if n_t:
            rows = self._buffers[index]
            # every array handed to Rerun is a new one (Arrow may reference it after the call):
            # the buffer goes back to the recording process for later batches
            nodes, bars, cables, colors, strain, energy, cerr, times = _pack(
                rows, n_t, 3 * net.n_nodes, *self._pack_args)
            index = [_Times(times)]
            chunks = [Chunk.from_columns('world/nodes', index, self._per_row(
                _POSITIONS, pa.FixedSizeListArray.from_arrays(_f32(nodes), type=_POINT_TYPE),
                n_t, net.n_nodes))]
            if net.n_bars:
                chunks.append(Chunk.from_columns('world/bars', index, self._per_row(
                    _STRIPS, self._bars.arrow(bars, n_t), n_t, self._bars.n)))
            if net.n_cables:
                chunks.append(Chunk.from_columns('world/cables', index, self._per_row(
                    _STRIPS, self._cables.arrow(cables, n_t), n_t, net.n_cables) + self._per_row(
                    _COLORS, pa.array(colors), n_t, net.n_cables)))
            n_p = net.n_prisms
            for c in range(len(strain) // (n_t * n_p) if n_p else 0):
                part = strain[c * n_t * n_p:(c + 1) * n_t * n_p]
                chunks.append(Chunk.from_columns(f'strain/column_{c}', index, self._per_row(
                    _SCALARS, pa.array(part), n_t, n_p)))
                chunks.append(Chunk.from_columns(f'strain_profile/column_{c}', index,
                                                 self._per_row(_BAR_VALUES,
                                                               vectors_data(part, n_t), n_t, 1)))
            chunks.append(Chunk.from_columns('energy', index, self._per_row(
                _SCALARS, pa.array(energy), n_t, 1)))
            chunks.append(Chunk.from_columns('constraint_error', index, self._per_row(
                _SCALARS, pa.array(cerr), n_t, 1)))
            chunks += self._base_chunks(rows, n_t, index)
            rr.send_chunks(chunks, recording=s)                 # one call for the batch
            if n_p:
                per_column = strain.reshape(-1, n_t * n_p)
                lo, hi = per_column.min(axis=1), per_column.max(axis=1)
                self._lo = lo if self._lo is None else np.minimum(self._lo, lo)
                self._hi = hi if self._hi is None else np.maximum(self._hi, hi)
                self._wave_add(strain.reshape(-1, n_t, n_p).transpose(1, 0, 2), rows[:n_t, -3])
        if self._wave_pending and (wave or restart or time.monotonic() - self._last_wave
                                   >= self.wave_period_s):
            self._log_wave()
        if restart:
            self._wave_n = 0

    def _base_chunks(self, rows, n_t, index):
        """``base_force/column_c`` Scalars (N) of a batch: the row's values after the tensions
        (one per column; none for a network without columns)."""
        net = self.net
        c0 = 3 * net.n_nodes + math.prod(self._shapes[1]) + net.n_cables
        n_base = rows.shape[1] - 3 - c0
        return [Chunk.from_columns(f'base_force/column_{c}', index, self._per_row(
            _SCALARS, pa.array(rows[:n_t, c0 + c].copy()), n_t, 1)) for c in range(n_base)]

    def _per_row(self, descriptor, values, n_t, k):
        """A component column of ``n_t`` rows of ``k`` values each."""
        offsets = self._offsets.get((n_t, k))
        if offsets is None:                     # immutable: shared by every batch of n_t rows
            offsets = self._offsets[n_t, k] = _i32(np.arange(n_t + 1, dtype=np.int32) * k)
        return [_Column(descriptor, pa.ListArray.from_arrays(offsets, values))]

    def _wave_add(self, strain, times):
        """Append the strain of a batch (n_t, n_columns, n_prisms) at ``times`` (n_t,) s to the
        wave ring."""
        w = self.wave_window
        if self._wave is None:
            self._wave = np.empty(strain.shape[1:] + (w,))
        keep = strain[-w:]                      # more frames than the window: the last ones
        at = (self._wave_n + len(strain) - len(keep) + np.arange(len(keep))) % w
        self._wave[:, :, at] = keep.transpose(1, 2, 0)
        self._wave_times[at] = times[-w:]
        self._wave_n += len(strain)
        self._wave_t = float(times[-1])
        self._wave_pending = True

    def _log_wave(self, static=False):
        """The heat map and its colour scale of every column: at the time of the last frame, or
        (``static``, when the recording closes) at every time, so that the whole wave shows
        wherever the time cursor is."""
        self._wave_pending = False
        self._last_wave = time.monotonic()
        n, w = self._wave_n, self.wave_window
        if n <= w:
            wave, times = self._wave[:, :, :n], self._wave_times[:n]
        else:                                           # oldest first
            order = np.r_[n % w:w, 0:n % w]
            wave, times = self._wave[:, :, order], self._wave_times[order]
        image_times, pick = heat_map_grid(times, self._impact_t)
        label = (f'sim_time {image_times[0]:.3f} to {image_times[-1]:.3f} s'
                 + (f', {1e3 * (image_times[1] - image_times[0]):.3g} ms per column'
                    if len(image_times) > 1 else ''))
        t = [] if static else [_Times(_ns([self._wave_t]))]
        chunks = []
        for c in range(wave.shape[0]):
            image = wave[c][:, pick]                    # (n_prisms, n_times); tensor_data copies
            lim = float(max(image.max(initial=0.0), -image.min(initial=0.0))) or 1.0
            value_range = _one_row(pa.FixedSizeListArray.from_arrays(pa.array([-lim, lim]),
                                                                     type=_RANGE_TYPE))
            chunks.append(Chunk.from_columns(f'wave/column_{c}', t, [
                _Column(_TENSOR_DATA, _one_row(tensor_data(image, (PRISM_AXIS, label)))),
                _Column(_TENSOR_RANGE, value_range)]))
            scale = np.linspace(-lim, lim, _SCALE_STEPS)[None, :]
            chunks.append(Chunk.from_columns(f'wave_scale/column_{c}', t, [
                _Column(_TENSOR_DATA, _one_row(tensor_data(
                    scale, ('', f'strain {-lim:+.3g} (left) to {lim:+.3g} (right)')))),
                _Column(_TENSOR_RANGE, value_range)]))
        rr.send_chunks(chunks, recording=self._stream)

    def _log_bar_range(self):
        """Two invisible bars of zero width at the run's strain extremes per column (static):
        the bar chart's y range then spans the whole run at every time."""
        if self._lo is None:
            return
        chunks = []
        for c, (lo, hi) in enumerate(zip(self._lo, self._hi)):
            chunks.append(_row_chunk(f'strain_profile/column_{c}/range', rr.BarChart(
                [float(lo), float(hi)], abscissa=[0.0, 0.0], widths=[0.0, 0.0],
                color=(0, 0, 0, 0))))
        rr.send_chunks(chunks, recording=self._stream)

    def _finish(self):
        """Flush to a viewer; disconnect, which writes the rest of the file and its footer (for
        a file alone no separate flush is needed); then let go of the stream."""
        stream, self._stream = self._stream, None
        try:
            if self.url is not None:
                stream.flush()
        except RuntimeError as exc:             # the viewer went away: the file is still written
            raise ValueError(f'rerun: {exc}') from None
        finally:
            stream.disconnect()
            del stream


_SCALE_STEPS = 101


def heat_map_grid(times, impact_t=None):
    """The columns of the heat map: ``(grid, pick)``, a uniform time grid s from the impact
    (``impact_t``, the last impact command's time; the first frame when None or when no frame
    is that late) to the last frame, one step the median frame interval, and the index of the
    frame shown at each grid time (the last frame at or before it). ``times`` (n,) s,
    increasing."""
    times = np.asarray(times, dtype=np.float64)
    start = 0
    if impact_t is not None:
        start = int(np.searchsorted(times, impact_t - 1e-9))
        if start >= len(times):
            start = 0
    t = times[start:]
    if len(t) < 2:
        return t.copy(), np.arange(start, len(times))
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        return t.copy(), np.arange(start, len(times))
    grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt + 1e-6)) + 1)
    pick = np.searchsorted(times, grid + 1e-6 * dt, side='right') - 1
    return grid, pick


def _message(exc):
    """The text the recorder raises (as ValueError) for an error of the helper."""
    return str(exc) if isinstance(exc, ValueError) else f'rerun: recording failed: {exc!r}'


