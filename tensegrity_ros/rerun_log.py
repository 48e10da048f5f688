"""Headless Rerun recordings of a run (interfaces.md section 6).

    with RerunRecorder(sim.network, path='run.rrd') as rec:     # or connect='rerun+http://...'
        runner.run(sim, t_end, output_dt, on_frame=rec.frame)
        rec.command(0.0, 'impact v0 = 0.1 m/s')

Everything goes through an owned :class:`rerun.RecordingStream` (never the global one), on the
timeline ``sim_time`` (a duration, from the simulation clock; no wall-clock timelines). Entities:

- ``topology`` (static): member index arrays ``bar_a``/``bar_b``/``cable_a``/``cable_b`` (int64),
  ``cable_kind`` (str), ``levels`` (n_columns * n_levels * 3,) and the reference positions ``x0``.
- ``world/nodes`` Points3D (n_nodes per frame, m), ``world/bars`` LineStrips3D (the bars as
  :func:`trails`: a column's bars are three helices, three strips), ``world/cables`` LineStrips3D
  (n_cables strips of 2 points, ``cable_a`` to ``cable_b``), coloured by tension
  ``T / tension_scale`` from blue to red as the ROS markers; slack cables (T = 0) grey and
  translucent. Positions are float32 (as Rerun stores them). Static colours and radii.
- ``strain/column_0`` Scalars: ``frame.strain[0]`` (n_prisms,), one series per prism (named
  ``prism 0`` ...); one entity per column.
- ``wave/column_0`` Tensor (n_prisms, n_frames): the strain of column 0 over the frames so far
  (the last ``wave_window`` frames), logged every ``wave_period_s`` wall seconds and at the end, at
  the time of its last frame; one entity per column.
- ``energy`` (J) and ``constraint_error`` Scalars; ``commands`` TextLog events.

Frames are buffered and sent in column batches (one chunk per entity, ``Chunk.from_columns`` and
one ``send_chunks`` call per batch) every ``flush_every`` frames and on :meth:`close`. The caller's
thread only checks each frame (a compiled check) and copies it into a batch buffer in shared
memory (a few microseconds); a helper process (:func:`serve`, a fresh interpreter started on first
use or ahead by :func:`prestart`, kept for later recordings) opens the stream, sends the
blueprint and the static entities, converts and sends the batches, the commands and the wave
images while the simulation goes on; Rerun's own threads in it encode and write. :meth:`close`
hands over the last batch and waits until the helper has finished the file. On a thread of the
simulation's process instead (sessions 1-4), the recorder's Python held the GIL the simulation
needs between its kernels: +30 % of a default run against +14 % now (docs/rerun.md). Every array
handed to Rerun is a fresh one (Arrow may keep referencing it after the call); the batch buffers
are reused once the helper hands them back.
"""
from __future__ import annotations

import math
import mmap
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.parse
from multiprocessing.connection import Connection
from multiprocessing.reduction import recv_handle, send_handle
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute  # noqa: F401  (imported by rerun on first use; load it with the module)
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import Chunk

DEFAULT_URL = 'rerun+http://127.0.0.1:9876/proxy'
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
# a frame is refused unless every value is finite and fits float32 (as positions are stored)
_F32_MAX = float(np.finfo(np.float32).max)


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


def reference_tension_scale(network):
    """Twice the largest cable tension N of the reference geometry (1 N without prestress): the
    default top of the colour ramp, as the node uses for its markers."""
    x0 = np.asarray(network.x0)
    s = np.linalg.norm(x0[network.cable_b] - x0[network.cable_a], axis=1)
    rest = np.asarray(network.cable_rest_length)
    t = np.where(s > rest, np.asarray(network.cable_EA) * (s - rest) / rest, 0.0)
    return 2.0 * float(t.max()) if t.size and t.max() > 0 else 1.0


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
    """(worker) The Rerun arrays of the first ``n_t`` rows of a batch buffer: node positions,
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
    strain = r[:, n_x:n_x + n_s].reshape(n_t, -1, max(n_p, 1)).transpose(1, 0, 2).reshape(-1)
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
    values = pa.Array.from_buffers(pa.float64(), image.size, [None, pa.py_buffer(image)])
    children = list(_UNION_EMPTY)
    children[_F64] = pa.ListArray.from_arrays(_i32(np.array([0, image.size], np.int32)), values,
                                              type=_UNION[_F64].type)
    buffer = pa.UnionArray.from_buffers(      # keeps the union's exact type (field nullability)
        _UNION, 1, [None, _UNION_TAG, _UNION_OFFSET], children=children)
    shape = pa.array([list(image.shape)], _TENSOR_TYPE.field('shape').type)
    names = pa.array([list(dim_names)], _TENSOR_TYPE.field('names').type)
    return pa.StructArray.from_arrays([shape, names, buffer], fields=list(_TENSOR_TYPE))


_TENSOR_DATA = rr.Tensor.descriptor_data()
_TENSOR_RANGE = rr.Tensor.descriptor_value_range()
_POSITIONS = rr.Points3D.descriptor_positions()
_STRIPS = rr.LineStrips3D.descriptor_strips()
_COLORS = rr.LineStrips3D.descriptor_colors()
_SCALARS = rr.Scalars.descriptor_scalars()


def _threads():
    """Native ids of this process's threads (Linux), else an empty set."""
    try:
        return {int(t) for t in os.listdir('/proc/self/task')}
    except OSError:
        return set()


def other_cpus():
    """The CPUs this process may run on, except the one the calling thread runs on now; None
    with fewer than two (or where Linux's ``/proc/thread-self/stat`` is missing)."""
    try:
        cpus = os.sched_getaffinity(0)
        with open('/proc/thread-self/stat') as f:
            cpu = int(f.read().rsplit(')', 1)[1].split()[36])      # field 39: processor
    except (OSError, ValueError, IndexError, AttributeError):
        return None
    rest = cpus - {cpu}
    return rest if len(cpus) > 1 and rest else None


def check_viewer(url, timeout_s=1.0):
    """Raise ValueError unless ``url`` is a Rerun gRPC URL with something listening on its port
    (a quick TCP probe, so that a missing viewer is reported before the run, not after it)."""
    u = urllib.parse.urlsplit(str(url))
    if u.scheme not in ('rerun', 'rerun+http', 'rerun+https') or not u.hostname:
        raise ValueError(f'rerun: {url!r} is not a viewer URL (expected e.g. {DEFAULT_URL})')
    try:
        socket.create_connection((u.hostname, u.port or 9876), timeout=timeout_s).close()
    except OSError as exc:
        raise ValueError(f'rerun: no viewer listening at {url} ({exc.strerror or exc}); start '
                         f'one with `rerun` or record to a file instead') from None


def blueprint(n_columns=1):
    """The default layout: the 3D column beside the strain plots (series per prism, prism-by-time
    wave), with energy, constraint error and the command log below."""
    waves = [rrb.TensorView(origin=f'wave/column_{c}', name=f'strain wave, column {c}',
                            slice_selection=rrb.archetypes.TensorSliceSelection(
                                width=rr.TensorDimensionSelection(1),
                                height=rr.TensorDimensionSelection(0)),
                            scalar_mapping=rrb.archetypes.TensorScalarMapping(
                                colormap='Spectral'))
             for c in range(n_columns)]
    wave = waves[0] if len(waves) == 1 else rrb.Tabs(*waves)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin='world', name='column'),
            rrb.Vertical(
                rrb.TimeSeriesView(origin='strain', name='strain per prism',
                                   plot_legend=rrb.archetypes.PlotLegend(visible=False)),
                wave,
                rrb.Horizontal(rrb.TimeSeriesView(origin='energy', name='energy, J'),
                               rrb.TimeSeriesView(origin='constraint_error',
                                                  name='constraint error')),
                rrb.TextLogView(origin='commands', name='commands'),
                row_shares=[3, 3, 1.2, 1]),
            column_shares=[2, 3]),
        collapse_panels=True)


def _topology_arrays(net):
    """The network's topology as logged on ``topology`` (``AnyValues`` fields)."""
    return {'bar_a': np.asarray(net.bar_a, np.int64), 'bar_b': np.asarray(net.bar_b, np.int64),
            'cable_a': np.asarray(net.cable_a, np.int64),
            'cable_b': np.asarray(net.cable_b, np.int64),
            'cable_kind': np.array([str(k) for k in net.cable_kind], dtype=object),
            'levels': np.asarray(net.levels, np.int64).ravel(),
            'levels_shape': np.asarray(net.levels.shape, np.int64),
            'x0': np.asarray(net.x0, np.float64).ravel()}


def _style_archetypes():
    """The static entities that do not depend on the network: view coordinates, colours and
    radii, the names of the energy and constraint-error series."""
    return [
        ('world', rr.ViewCoordinates.RIGHT_HAND_Z_UP),                  # column axis: z
        ('world/nodes', rr.Points3D.from_fields(colors=[_NODE_RGBA],
                                                radii=rr.Radius.ui_points(3.0))),
        ('world/bars', rr.LineStrips3D.from_fields(colors=[_BAR_RGBA],
                                                   radii=rr.Radius.ui_points(2.5))),
        ('world/cables', rr.LineStrips3D.from_fields(radii=rr.Radius.ui_points(1.2))),
        ('energy', rr.SeriesLines(names=['energy'])),
        ('constraint_error', rr.SeriesLines(names=['constraint error']))]


def static_archetypes(net):
    """The static entities of a recording of ``net`` as rerun archetypes: (entity path,
    archetype) pairs. The recorder logs the same components, the network's arrays built
    directly (see ``RerunRecorder._log_static``); this is the reference it is tested against."""
    topo = _topology_arrays(net)
    topo['cable_kind'] = list(topo['cable_kind'])
    names = [f'prism {p}' for p in range(net.n_prisms)]
    return ([('topology', rr.AnyValues(**topo))] + _style_archetypes()
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
# A recording is written by a helper process (one per recording at a time, kept for later ones):
# Rerun's Python (the blueprint, the chunks) held the GIL that the simulation needs between its
# kernels when it ran on a thread of the simulation's process (docs/rerun.md).
_HELPER_CODE = 'import sys\nfrom tensegrity_ros.rerun_log import serve\nserve(int(sys.argv[1]))\n'
_IDLE = []                              # helpers with no recording, newest last
_IDLE_LOCK = threading.Lock()


class _Helper:
    """A helper process running :func:`serve`, and the connection to it."""

    def __init__(self):
        ours, theirs = socket.socketpair()
        root = str(Path(__file__).resolve().parents[1])
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            [root] + [p for p in os.environ.get('PYTHONPATH', '').split(os.pathsep) if p]))
        try:
            self.proc = subprocess.Popen(
                [sys.executable, '-c', _HELPER_CODE, str(theirs.fileno())],
                pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                env=env, close_fds=True)
        finally:
            theirs.close()
        self.conn = Connection(ours.detach())

    def alive(self):
        return self.proc.poll() is None


def prestart():
    """Start a helper process now, if none is idle, so that a recording made later in this process
    does not wait for one (it imports rerun-sdk and pyarrow: about 0.4 s). ``tensegrity run`` and
    the node call it before they build the simulation."""
    with _IDLE_LOCK:
        if not any(h.alive() for h in _IDLE):
            _IDLE.append(_Helper())


def _take_helper():
    with _IDLE_LOCK:
        while _IDLE:
            helper = _IDLE.pop()
            if helper.alive():
                return helper
    return _Helper()


def _give_back(helper):
    with _IDLE_LOCK:
        _IDLE.append(helper)


def serve(fd):
    """(helper process) Write the recordings described by the messages on the socket ``fd``, one
    after the other; exit when the other end closes (a recording in progress is finished first,
    so that a killed simulation still leaves a complete file of what it handed over). Interrupts
    are ignored: the process that owns the recording decides when it ends."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    conn = Connection(fd)
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


class _Writer:
    """(helper process) One recording: the stream, its sinks, the blueprint and the static
    entities, then the batches, commands and wave images handed over, until ``close``. Batches
    are read from shared memory (``memfd``: ``n_buffers`` buffers of ``flush_every`` rows of
    ``width`` float64, as the recorder fills them); each buffer is handed back (``free``) once
    sent. The first error is reported (``error``) and the rest is drained without sending; the
    file is finished in any case."""

    def __init__(self, conn, memfd, all_cpus, net, path, url, tension_scale, flush_every,
                 wave_window, wave_period_s, shapes, n_buffers, cpus, application_id,
                 recording_id, send_blueprint):
        self._cpu0 = time.process_time()
        self.conn, self.all_cpus = conn, all_cpus
        self.net, self.path, self.url = net, path, url
        self.tension_scale, self.flush_every = tension_scale, flush_every
        self.wave_window, self.wave_period_s = wave_window, wave_period_s
        self._shapes = shapes
        self._width = 3 * net.n_nodes + math.prod(shapes[1]) + net.n_cables + 3
        size = n_buffers * flush_every * self._width * 8
        try:
            self._mem = mmap.mmap(memfd, size)
        finally:
            os.close(memfd)
        self._buffers = np.ndarray((n_buffers, flush_every, self._width), np.float64, self._mem)
        self._stream = None
        self._error = None
        self._tids = set()
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
            self.conn.send(('error', _message(exc)))

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
            elif kind == 'command':
                self._do(self._log_command, *msg[1:])
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
            self._do(self._send, index, n_t, True, False)
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
        if send_blueprint:                      # what set_sinks(default_blueprint=...) sends
            stream.send_blueprint(blueprint(max(net.n_columns, 1)), make_active=False,
                                  make_default=True)
        self._log_static()
        self._bars = _Strips(trails(net.bar_a, net.bar_b, net.n_nodes), self.flush_every)
        self._cables = _Strips(np.stack([np.asarray(net.cable_a), np.asarray(net.cable_b)],
                                        axis=1).reshape(-1, 2), self.flush_every)
        self._pack_args = (net.n_prisms, math.prod(self._shapes[1]), net.n_cables,
                           self._bars.index, self._cables.index, self.tension_scale)
        self._offsets = {}                      # (n_t, k) -> row offsets, as Arrow
        self._wave = None                       # (n_columns, n_prisms, wave_window) ring
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
            for path, archetype in _style_archetypes()]
        static += [(f'strain/column_{c}', [(_SERIES_NAMES, names)])
                   for c in range(net.n_columns if net.n_prisms else 0)]
        rr.send_chunks([Chunk.from_columns(path, [], [_Column(d, _one_row(a)) for d, a in batches])
                        for path, batches in static], recording=self._stream)

    def _log_command(self, t, text, level):
        rr.send_chunks(_row_chunk('commands', rr.TextLog(text, level=level), t),
                       recording=self._stream)

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
                chunks.append(Chunk.from_columns(f'strain/column_{c}', index, self._per_row(
                    _SCALARS, pa.array(strain[c * n_t * n_p:(c + 1) * n_t * n_p]), n_t, n_p)))
            chunks.append(Chunk.from_columns('energy', index, self._per_row(
                _SCALARS, pa.array(energy), n_t, 1)))
            chunks.append(Chunk.from_columns('constraint_error', index, self._per_row(
                _SCALARS, pa.array(cerr), n_t, 1)))
            rr.send_chunks(chunks, recording=s)                 # one call for the batch
            if n_p:
                self._wave_add(strain.reshape(-1, n_t, n_p).transpose(1, 0, 2), rows[n_t - 1, -3])
        if self._wave_pending and (wave or restart or time.monotonic() - self._last_wave
                                   >= self.wave_period_s):
            self._log_wave()
        if restart:
            self._wave_n = 0

    def _per_row(self, descriptor, values, n_t, k):
        """A component column of ``n_t`` rows of ``k`` values each."""
        offsets = self._offsets.get((n_t, k))
        if offsets is None:                     # immutable: shared by every batch of n_t rows
            offsets = self._offsets[n_t, k] = _i32(np.arange(n_t + 1, dtype=np.int32) * k)
        return [_Column(descriptor, pa.ListArray.from_arrays(offsets, values))]

    def _wave_add(self, strain, t_last):
        """Append the strain of a batch (n_t, n_columns, n_prisms) to the wave ring."""
        w = self.wave_window
        if self._wave is None:
            self._wave = np.empty(strain.shape[1:] + (w,))
        keep = strain[-w:]                      # more frames than the window: the last ones
        at = (self._wave_n + len(strain) - len(keep) + np.arange(len(keep))) % w
        self._wave[:, :, at] = keep.transpose(1, 2, 0)
        self._wave_n += len(strain)
        self._wave_t = float(t_last)
        self._wave_pending = True

    def _log_wave(self):
        self._wave_pending = False
        self._last_wave = time.monotonic()
        n, w = self._wave_n, self.wave_window
        if n <= w:
            wave = self._wave[:, :, :n]                 # (n_columns, n_prisms, n_frames)
        else:                                           # oldest first
            wave = np.concatenate((self._wave[:, :, n % w:], self._wave[:, :, :n % w]), axis=2)
        chunks = []
        for c in range(wave.shape[0]):
            image = wave[c]                         # tensor_data copies it
            lim = float(max(image.max(initial=0.0), -image.min(initial=0.0))) or 1.0
            chunks.append(Chunk.from_columns(f'wave/column_{c}', [_Times(_ns([self._wave_t]))], [
                _Column(_TENSOR_DATA, _one_row(tensor_data(image, ('prism', 'frame')))),
                _Column(_TENSOR_RANGE, _one_row(pa.FixedSizeListArray.from_arrays(
                    pa.array([-lim, lim]), type=_RANGE_TYPE)))]))
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


def _message(exc):
    """The text the recorder raises (as ValueError) for an error of the helper."""
    return str(exc) if isinstance(exc, ValueError) else f'rerun: recording failed: {exc!r}'


# -- the recorder ---------------------------------------------------------------------------------
class RerunRecorder:
    """Records solver frames of one network to a ``.rrd`` file and/or a live viewer.

    ``network``: the :class:`solver.network.Network` (read-only arrays). ``path``: ``.rrd`` file to
    write (headless). ``connect``: gRPC URL of a running viewer (``True`` for :data:`DEFAULT_URL`).
    At least one of the two is required. ``tension_scale`` N: tension shown at the top of the
    colour ramp (default :func:`reference_tension_scale`).
    Frames are sent in batches of ``flush_every`` frames, or sooner when ``max_latency_s`` of wall
    time passed since the last batch (a live viewer stays current; a paced node's file stays
    fresh). ``expected_frames``, for a run of known length (``tensegrity run``), shortens the
    first batch so that the last one holds at most ``flush_every // 10`` frames: :meth:`close`
    then waits for less. The strain-wave image (the last ``wave_window`` frames) is sent at most
    every ``wave_period_s`` wall seconds, and on :meth:`close`.

    The calling thread only checks each frame and copies it into a batch buffer in memory shared
    with a helper process (:func:`serve`; started on first use, or ahead by :func:`prestart`, and
    kept for later recordings), which opens the stream and sends the blueprint, the static
    entities, the batches, the commands and the wave images, in the order they were handed over.
    An error in the helper is raised as ValueError by a later :meth:`frame` (at the next batch),
    :meth:`command`, :meth:`flush`, :meth:`sync` or :meth:`close`. If the recording process dies,
    the helper finishes the file with every batch handed to it. With ``spare_caller_cpu`` (and more
    than one CPU) the helper and the threads Rerun starts in it run on the other CPUs than the
    one the constructing thread ran on, until :meth:`close`. After :meth:`close`,
    :attr:`helper_cpu_s` is the CPU time the helper process spent on the recording (all its
    threads, Rerun's included).
    """

    n_buffers = 8                       # batch buffers in shared memory (backpressure beyond)

    def __init__(self, network, path=None, *, connect=None, tension_scale=None, flush_every=50,
                 max_latency_s=0.5, wave_window=1000, wave_period_s=2.0,
                 application_id='tensegrity_ros', recording_id=None, send_blueprint=True,
                 spare_caller_cpu=True, expected_frames=None):
        if path is None and not connect:
            raise ValueError('rerun: give a file path or a viewer URL (connect) to record to')
        if tension_scale is not None and not (np.isfinite(tension_scale) and tension_scale > 0):
            raise ValueError(f'rerun: tension_scale must be a positive number, got '
                             f'{tension_scale}')
        if int(flush_every) < 1 or int(wave_window) < 1:
            raise ValueError('rerun: flush_every and wave_window must be at least 1')
        if not max_latency_s > 0:
            raise ValueError(f'rerun: max_latency_s must be positive, got {max_latency_s}')
        if expected_frames is not None and not (isinstance(expected_frames, (int, np.integer))
                                                and expected_frames >= 1):
            raise ValueError(f'rerun: expected_frames must be a positive integer, got '
                             f'{expected_frames!r}')
        from solver.dynamics import finite_below   # here: the helper process needs no numba
        self._finite_below = finite_below
        self.path = None if path is None else str(path)
        self.url = (DEFAULT_URL if connect is True else connect) or None
        if self.url is not None:
            check_viewer(self.url)
        self.tension_scale = (reference_tension_scale(network) if tension_scale is None
                              else float(tension_scale))
        self.flush_every = int(flush_every)
        self.max_latency_s = float(max_latency_s)
        # frames of the batch being filled; for a run of known length the first batch is cut so
        # that the last one, which close() waits for, is short
        self._batch = self.flush_every
        if expected_frames is not None:
            tail = max(1, self.flush_every // 10)
            self._batch = (int(expected_frames) - tail) % self.flush_every or self.flush_every
        self._last_flush = time.monotonic()
        self.n_frames = 0
        self.n_commands = 0
        self.n_restarts = 0
        # A batch buffer holds one float64 row per frame: positions (n_nodes * 3), strain
        # (n_columns * n_prisms), tension (n_cables), then t, energy and constraint error.
        shapes = ((network.n_nodes, 3), tuple(network.levels.shape[:1]) + (network.n_prisms,),
                  (network.n_cables,))
        self._shapes = shapes
        n_x, n_s = 3 * network.n_nodes, math.prod(shapes[1])
        self._cols = (slice(0, n_x), slice(n_x, n_x + n_s),
                      slice(n_x + n_s, n_x + n_s + network.n_cables))
        width = n_x + n_s + network.n_cables + 3
        self._last_t = None
        self._closed = False
        self._error = None
        self._helper = None
        self.helper_cpu_s = None                # CPU seconds of the helper, known after close()
        if self.path is not None:               # create the file now: errors come at once
            try:                                # (appending: an old file is truncated by the
                open(self.path, 'ab').close()   # helper's sink, not here: 1.7 ms for 2 MB)
            except OSError as exc:              # e.g. a directory that does not exist
                raise ValueError(f'rerun: cannot record to {self.path}: '
                                 f'{exc.strerror or exc}') from None
        size = self.n_buffers * self.flush_every * width * 8
        memfd = os.memfd_create('tensegrity-rerun', os.MFD_CLOEXEC)
        try:
            os.ftruncate(memfd, size)
            self._mem = mmap.mmap(memfd, size)
            self._buffers = np.ndarray((self.n_buffers, self.flush_every, width), np.float64,
                                       self._mem)
            self._free = list(range(self.n_buffers - 1, -1, -1))
            helper = _take_helper()
            cpus = other_cpus() if spare_caller_cpu else None
            net = _NetArrays(network)
            helper.conn.send(('open', net, self.path, self.url, self.tension_scale,
                              self.flush_every, int(wave_window), float(wave_period_s), shapes,
                              self.n_buffers, cpus, application_id, recording_id,
                              send_blueprint))
            send_handle(helper.conn, memfd, helper.proc.pid)
        except (OSError, EOFError) as exc:
            raise ValueError(f'rerun: cannot start the recording helper process: {exc}') from None
        finally:
            os.close(memfd)
        self._helper = helper
        self._n_buf = 0
        self._new_buffer()

    # -- messages -------------------------------------------------------------------------------
    def _post(self, msg):
        try:
            self._helper.conn.send(msg)
        except OSError:
            self._lost()

    def _lost(self):
        code = self._helper.proc.poll()
        self._error = self._error or ValueError(
            f'rerun: the recording helper process exited (code {code}); recording stopped')
        self._check()

    def _handle(self, msg):
        kind = msg[0]
        if kind == 'free':
            self._free.append(msg[1])
        elif kind == 'error' and self._error is None:
            self._error = ValueError(msg[1])
        return kind

    def _receive(self, until=None):
        """Handle the helper's messages: those already here, or (``until``) every message up to
        the first of that kind."""
        conn = self._helper.conn
        try:
            while until is not None or conn.poll():
                if self._handle(conn.recv()) == until:
                    return
        except (EOFError, OSError):
            self._lost()

    def _check(self):
        """Raise the helper's first error (as ValueError) in the caller's thread."""
        if self._error is not None:
            raise self._error

    def sync(self):
        """Wait until the helper has sent everything handed to it so far (frames still in the
        batch buffer are not: see :meth:`flush`); raise its error if any."""
        if self._closed:
            raise ValueError('rerun: recorder is closed')
        self._post(('sync',))
        self._receive(until='synced')
        self._check()

    # -- per frame ------------------------------------------------------------------------------
    def _new_buffer(self):
        self._receive()                         # buffers handed back, errors
        if not self._free:                      # the helper is behind: wait for a buffer
            self._receive(until='free')
        self._index = self._free.pop()
        rows = self._rows = self._buffers[self._index]
        n_b, (cx, cs, ct) = self.flush_every, self._cols
        self._bx = rows[:, cx].reshape((n_b,) + self._shapes[0])        # views into rows
        self._bs = rows[:, cs].reshape((n_b,) + self._shapes[1])
        self._bt = rows[:, ct]

    def frame(self, frame):
        """Buffer one :class:`solver.simulation.Frame`; sends a batch every ``flush_every`` frames.
        A frame that does not match the network or has non-finite values raises ValueError and
        records nothing. A time not after the previous frame (the simulation was reset) flushes
        the frames before it and restarts the strain wave; ``sim_time`` then holds both."""
        if self._closed:
            raise ValueError('rerun: recorder is closed')
        if self._error is not None:
            self._check()
        t = float(frame.t)
        x, strain, tension = frame.positions, frame.strain, frame.tension
        i = self._n_buf
        row = self._rows[i]
        try:
            self._bx[i] = x
            self._bs[i] = strain
            self._bt[i] = tension
        except ValueError:
            ok = False
        else:
            try:
                ok = (x.shape, strain.shape, tension.shape) == self._shapes
            except AttributeError:              # not arrays
                ok = (np.shape(x), np.shape(strain), np.shape(tension)) == self._shapes
        if not ok:
            raise ValueError(f'rerun: frame at t = {t:g} s does not match the network '
                             f'(positions {np.shape(x)}, strain {np.shape(strain)}, '
                             f'tension {np.shape(tension)}); not recorded')
        row[-3] = t
        row[-2] = float(frame.energy)
        row[-1] = float(frame.constraint_error)
        if not self._finite_below(row, _F32_MAX):      # compiled: no 512-bit instructions
            bad = [name for name, v in (('time', row[-3]), ('energy', row[-2]),
                                        ('constraint error', row[-1]), ('positions', x),
                                        ('strain', strain), ('tension', tension))
                   if not np.isfinite(v).all()] or ['values (beyond float32)']
            raise ValueError(f'rerun: frame at t = {t:g} s has non-finite {bad[0]}; not recorded')
        if self._last_t is not None and t <= self._last_t:
            # the clock went back (a reset): send what came before, so that every batch has
            # increasing times, and start a new strain wave
            self._submit(i, wave=True, restart=True)
            self._rows[0] = row
            self.n_restarts += 1
            i = 0
        self._last_t = t
        self._n_buf = i + 1
        self.n_frames += 1
        if self._n_buf >= self._batch or \
                time.monotonic() - self._last_flush > self.max_latency_s:
            self._submit(self._n_buf)

    def command(self, t, text, level=None):
        """A command (or any event) as a text entry at simulation time ``t`` s on ``commands``;
        ``level`` defaults to WARN for texts starting with 'rejected' or 'paused', else INFO."""
        if self._closed:
            raise ValueError('rerun: recorder is closed')
        self._receive()
        self._check()
        if not math.isfinite(t):
            raise ValueError(f'rerun: command time {t} is not finite')
        text = str(text)
        if level is None:
            level = 'WARN' if text.startswith(('rejected', 'paused')) else 'INFO'
        self._post(('command', float(t), text, level))
        self.n_commands += 1

    # -- batches --------------------------------------------------------------------------------
    def flush(self, wave=False):
        """Hand the buffered frames to the helper, which sends them as column batches; the
        strain-wave image so far too if ``wave`` or ``wave_period_s`` of wall time passed since
        it was last sent."""
        if self._closed:
            raise ValueError('rerun: recorder is closed')
        self._receive()
        self._check()
        self._submit(self._n_buf, wave)

    def _submit(self, n_t, wave=False, restart=False):
        self._last_flush = time.monotonic()
        self._batch = self.flush_every
        index = None
        if n_t:
            index = self._index
        if n_t or wave or restart:
            self._post(('send', index, n_t, wave, restart))
        if n_t:
            self._new_buffer()
        self._n_buf = 0

    def close(self):
        """Send what is buffered and the wave image, then finish the file / disconnect: the file
        is complete when this returns. Idempotent."""
        if self._closed:
            return
        self._closed = True
        helper, n_t = self._helper, self._n_buf
        self._n_buf = 0
        try:
            helper.conn.send(('close', self._index if n_t else None, n_t))
            while True:
                msg = helper.conn.recv()
                if self._handle(msg) == 'closed':
                    break
        except (EOFError, OSError):
            self._lost()
        finally:
            self._rows = self._bx = self._bs = self._bt = self._buffers = None
            self._mem.close()
        _give_back(helper)                      # the file is finished: ready for another one
        self.helper_cpu_s = msg[2]
        if msg[1] is not None and self._error is None:
            self._error = ValueError(msg[1])
        self._check()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


class _NetArrays:
    """What the helper needs of a network (its arrays and counts), picklable."""

    def __init__(self, net):
        for name in ('bar_a', 'bar_b', 'cable_a', 'cable_b', 'cable_kind', 'levels', 'x0'):
            setattr(self, name, np.asarray(getattr(net, name)))
        for name in ('n_nodes', 'n_bars', 'n_cables', 'n_prisms', 'n_columns'):
            setattr(self, name, int(getattr(net, name)))
