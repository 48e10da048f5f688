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

Frames are buffered and sent in column batches (``send_columns``) every ``flush_every`` frames and
on :meth:`close`, which keeps the per-frame cost to a few array copies. Every array handed to
Rerun is a fresh copy (Arrow may keep referencing it after the call; the buffers are reused).
"""
from __future__ import annotations

import math
import socket
import time
import urllib.parse
from collections import deque

import numpy as np
import pyarrow as pa
import pyarrow.compute  # noqa: F401  (imported by rerun on first use; load it with the module)
import rerun as rr
import rerun.blueprint as rrb

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


def tension_colors(tension, scale):
    """Packed RGBA (``0xRRGGBBAA``, uint32) per cable: tension ``(..., n_cables)`` N mapped by
    ``u = T / scale`` (clipped to [0, 1], 256 levels) to ``(u, 0.2 (1 - u), 1 - u)``; slack cables
    (T <= 0) get :data:`SLACK_COLOR`."""
    tension = np.asarray(tension, dtype=np.float64)
    idx = np.clip(np.rint(tension * (255.0 / scale)), 0, 255).astype(np.intp)
    out = _LUT[idx]
    out[tension <= 0.0] = SLACK_COLOR
    return out


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
    """Line strips through fixed node sequences (one strip per sequence), gathered per frame."""

    def __init__(self, sequences):
        nodes = np.concatenate(sequences) if sequences else np.zeros(0, np.int64)
        self.index = (nodes[:, None] * 3 + np.arange(3)).ravel()      # into one frame's x.ravel()
        self.lengths = np.array([len(s) for s in sequences], dtype=np.int32)
        self.n = len(sequences)

    def arrow(self, x32):
        """One Arrow ``LineStrip3D`` array of n_t * n strips for the frames ``x32`` (n_t, n_nodes,
        3) float32 m, built directly (rerun's generic conversion loops over strips in Python)."""
        n_t = x32.shape[0]
        pts = np.take(x32.reshape(n_t, -1), self.index, axis=1)
        inner = pa.FixedSizeListArray.from_arrays(pa.array(pts.reshape(-1)),
                                                  type=_STRIP_TYPE.value_type)
        offsets = np.zeros(n_t * self.n + 1, dtype=np.int32)
        np.cumsum(np.tile(self.lengths, n_t), out=offsets[1:])
        return pa.ListArray.from_arrays(pa.array(offsets), inner, type=_STRIP_TYPE)


_STRIP_TYPE = rr.components.LineStrip3DBatch._ARROW_DATATYPE


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


def _column(descriptor, batch, n_rows, per_row):
    """A column of ``n_rows`` rows of ``per_row`` values each of one component ``batch`` (rerun's
    ``Archetype.columns().partition()`` first builds and then replaces a unit partition, an
    O(n_values) cumsum; the offsets here are direct)."""
    offsets = np.arange(n_rows + 1, dtype=np.int32) * np.int32(per_row)
    return rr.ComponentColumn(descriptor, batch, offsets=offsets)


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


class RerunRecorder:
    """Records solver frames of one network to a ``.rrd`` file and/or a live viewer.

    ``network``: the :class:`solver.network.Network` (read-only arrays). ``path``: ``.rrd`` file to
    write (headless). ``connect``: gRPC URL of a running viewer (``True`` for :data:`DEFAULT_URL`).
    At least one of the two is required. ``tension_scale`` N: tension shown at the top of the
    colour ramp (default :func:`reference_tension_scale`).
    Frames are sent in batches of ``flush_every`` frames, or sooner when ``max_latency_s`` of wall
    time passed since the last batch (a live viewer stays current; a paced node's file stays
    fresh; small batches also let Rerun's encoder threads work while the simulation runs).
    The strain-wave image (the last ``wave_window`` frames) is sent at most every
    ``wave_period_s`` wall seconds, and on :meth:`close`.
    """

    def __init__(self, network, path=None, *, connect=None, tension_scale=None, flush_every=50,
                 max_latency_s=0.5, wave_window=1000, wave_period_s=2.0,
                 application_id='tensegrity_ros', recording_id=None, send_blueprint=True):
        if path is None and not connect:
            raise ValueError('rerun: give a file path or a viewer URL (connect) to record to')
        if tension_scale is not None and not (np.isfinite(tension_scale) and tension_scale > 0):
            raise ValueError(f'rerun: tension_scale must be a positive number, got '
                             f'{tension_scale}')
        if int(flush_every) < 1 or int(wave_window) < 1:
            raise ValueError('rerun: flush_every and wave_window must be at least 1')
        if not max_latency_s > 0:
            raise ValueError(f'rerun: max_latency_s must be positive, got {max_latency_s}')
        self.net = network
        self.path = None if path is None else str(path)
        self.url = (DEFAULT_URL if connect is True else connect) or None
        if self.url is not None:
            check_viewer(self.url)
        self.tension_scale = (reference_tension_scale(network) if tension_scale is None
                              else float(tension_scale))
        self.flush_every = int(flush_every)
        self.max_latency_s = float(max_latency_s)
        self._bars = _Strips(trails(network.bar_a, network.bar_b, network.n_nodes))
        self._cables = _Strips([np.array(ab, dtype=np.int64) for ab in
                                zip(network.cable_a, network.cable_b)])      # colour per cable
        self._last_flush = time.monotonic()
        self.n_frames = 0
        self.n_commands = 0
        self.n_restarts = 0
        n_b = self.flush_every
        self._b = {'t': np.zeros(n_b), 'x': np.zeros((n_b, network.n_nodes, 3), np.float32),
                   'strain': np.zeros((n_b,) + tuple(network.levels.shape[:1])
                                      + (network.n_prisms,)),
                   'tension': np.zeros((n_b, network.n_cables)),
                   'energy': np.zeros(n_b), 'cerr': np.zeros(n_b)}
        self._n_buf = 0
        self._wave_t = deque(maxlen=int(wave_window))
        self._wave = deque(maxlen=int(wave_window))
        self.wave_period_s = float(wave_period_s)
        self._wave_pending = False
        self._last_wave = time.monotonic()
        self._last_t = None
        self._closed = False

        stream = rr.RecordingStream(application_id, recording_id=recording_id)
        stream.set_log_time_enabled(False)            # sim_time only: no wall-clock timelines
        stream.set_log_tick_enabled(False)
        bp = blueprint(max(network.n_columns, 1)) if send_blueprint else None
        sinks = []
        if self.path is not None:
            sinks.append(rr.FileSink(self.path))
        if self.url is not None:
            sinks.append(rr.GrpcSink(self.url))
        try:
            stream.set_sinks(*sinks, default_blueprint=bp)
        except RuntimeError as exc:             # e.g. a directory that does not exist
            raise ValueError(f'rerun: cannot record to {self.path or self.url}: {exc}') from None
        self.stream = stream
        self._log_static()

    # -- static ---------------------------------------------------------------------------------
    def _log_static(self):
        net, s = self.net, self.stream
        s.log('topology', rr.AnyValues(
            bar_a=np.asarray(net.bar_a, np.int64), bar_b=np.asarray(net.bar_b, np.int64),
            cable_a=np.asarray(net.cable_a, np.int64), cable_b=np.asarray(net.cable_b, np.int64),
            cable_kind=[str(k) for k in net.cable_kind],
            levels=np.asarray(net.levels, np.int64).ravel(),
            levels_shape=np.asarray(net.levels.shape, np.int64),
            x0=np.asarray(net.x0, np.float64).ravel()), static=True)
        s.log('world', rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)   # column axis: z
        s.log('world/nodes', rr.Points3D.from_fields(colors=[_NODE_RGBA],
                                                     radii=rr.Radius.ui_points(3.0)), static=True)
        s.log('world/bars', rr.LineStrips3D.from_fields(colors=[_BAR_RGBA],
                                                        radii=rr.Radius.ui_points(2.5)),
              static=True)
        s.log('world/cables', rr.LineStrips3D.from_fields(radii=rr.Radius.ui_points(1.2)),
              static=True)
        names = [f'prism {p}' for p in range(net.n_prisms)]
        for c in range(net.n_columns if net.n_prisms else 0):
            s.log(f'strain/column_{c}', rr.SeriesLines(names=names), static=True)
        s.log('energy', rr.SeriesLines(names=['energy']), static=True)
        s.log('constraint_error', rr.SeriesLines(names=['constraint error']), static=True)

    # -- per frame ------------------------------------------------------------------------------
    def frame(self, frame):
        """Buffer one :class:`solver.simulation.Frame`; sends a batch every ``flush_every`` frames.
        A frame that does not match the network or has non-finite values raises ValueError and
        records nothing. A time not after the previous frame (the simulation was reset) flushes
        the frames before it and restarts the strain wave; ``sim_time`` then holds both."""
        if self._closed:
            raise ValueError('rerun: recorder is closed')
        t = float(frame.t)
        x, strain, tension = frame.positions, frame.strain, frame.tension
        energy, cerr = float(frame.energy), float(frame.constraint_error)
        i, b = self._n_buf, self._b
        try:
            b['x'][i] = x
            b['strain'][i] = strain
            b['tension'][i] = tension
            ok = (np.shape(x) == b['x'].shape[1:] and np.shape(strain) == b['strain'].shape[1:]
                  and np.shape(tension) == b['tension'].shape[1:])
        except ValueError:
            ok = False
        if not ok:
            raise ValueError(f'rerun: frame at t = {t:g} s does not match the network '
                             f'(positions {np.shape(x)}, strain {np.shape(strain)}, '
                             f'tension {np.shape(tension)}); not recorded')
        # one sum is finite only if every term is (NaN and inf propagate): the cheap common case
        if not math.isfinite(t + energy + cerr + b['x'][i].sum() + b['strain'][i].sum()
                             + b['tension'][i].sum()):
            bad = [name for name, v in (('time', t), ('energy', energy),
                                        ('constraint error', cerr), ('positions', b['x'][i]),
                                        ('strain', b['strain'][i]), ('tension', b['tension'][i]))
                   if not np.isfinite(v).all()] or ['values (overflow)']
            raise ValueError(f'rerun: frame at t = {t:g} s has non-finite {bad[0]}; not recorded')
        if self._last_t is not None and t <= self._last_t:
            # the clock went back (a reset): send what came before, so that every batch has
            # increasing times, and start a new strain wave
            self.flush(wave=True)
            self._wave.clear()
            self._wave_t.clear()
            self.n_restarts += 1
            b['x'][0], b['strain'][0], b['tension'][0] = b['x'][i], b['strain'][i], b['tension'][i]
            i = 0
        b['t'][i], b['energy'][i], b['cerr'][i] = t, energy, cerr
        self._last_t = t
        self._n_buf = i + 1
        self.n_frames += 1
        if self._n_buf == self.flush_every or \
                time.monotonic() - self._last_flush > self.max_latency_s:
            self.flush()

    def command(self, t, text, level=None):
        """A command (or any event) as a text entry at simulation time ``t`` s on ``commands``;
        ``level`` defaults to WARN for texts starting with 'rejected' or 'paused', else INFO."""
        if self._closed:
            raise ValueError('rerun: recorder is closed')
        if not math.isfinite(t):
            raise ValueError(f'rerun: command time {t} is not finite')
        text = str(text)
        if level is None:
            level = 'WARN' if text.startswith(('rejected', 'paused')) else 'INFO'
        self.stream.set_time(TIMELINE, duration=np.timedelta64(int(_ns(t)), 'ns'))
        self.stream.log('commands', rr.TextLog(text, level=level))
        self.n_commands += 1

    # -- batches --------------------------------------------------------------------------------
    def flush(self, wave=False):
        """Send the buffered frames as column batches; the strain-wave image so far too if
        ``wave`` or ``wave_period_s`` of wall time passed since it was last sent."""
        n_t = self._n_buf
        self._last_flush = time.monotonic()
        if n_t == 0:
            if wave and self._wave_pending:
                self._log_wave()
            return
        self._n_buf = 0
        net, s, b = self.net, self.stream, self._b
        index = [rr.TimeColumn(TIMELINE, duration=_ns(b['t'][:n_t]).astype('timedelta64[ns]'))]
        x = b['x'][:n_t].copy()                                 # (n_t, n_nodes, 3) float32
        s.send_columns('world/nodes', index, [_column(
            rr.Points3D.descriptor_positions(),
            rr.components.Position3DBatch(x.reshape(-1, 3)), n_t, net.n_nodes)])
        if net.n_bars:
            s.send_columns('world/bars', index, [_column(
                rr.LineStrips3D.descriptor_strips(),
                rr.components.LineStrip3DBatch(self._bars.arrow(x)), n_t, self._bars.n)])
        if net.n_cables:
            colors = tension_colors(b['tension'][:n_t], self.tension_scale).reshape(-1)
            s.send_columns('world/cables', index, [
                _column(rr.LineStrips3D.descriptor_strips(),
                        rr.components.LineStrip3DBatch(self._cables.arrow(x)), n_t,
                        net.n_cables),
                _column(rr.LineStrips3D.descriptor_colors(),
                        rr.components.ColorBatch(pa.array(colors)), n_t, net.n_cables)])
        strain = b['strain'][:n_t]                              # (n_t, n_columns, n_prisms)
        for c in range(strain.shape[1] if strain.size else 0):
            s.send_columns(f'strain/column_{c}', index, [_column(
                rr.Scalars.descriptor_scalars(),
                rr.components.ScalarBatch(strain[:, c].reshape(-1).copy()), n_t,
                strain.shape[2])])
        for name, key in (('energy', 'energy'), ('constraint_error', 'cerr')):
            s.send_columns(name, index, [_column(
                rr.Scalars.descriptor_scalars(), rr.components.ScalarBatch(b[key][:n_t].copy()),
                n_t, 1)])
        if strain.size:
            self._wave_t.extend(b['t'][:n_t])
            self._wave.extend(strain.copy())
            self._wave_pending = True
        if self._wave_pending and (wave or self._last_flush - self._last_wave
                                   >= self.wave_period_s):
            self._log_wave()

    def _log_wave(self):
        self._wave_pending = False
        self._last_wave = time.monotonic()
        wave = np.stack(self._wave, axis=2)            # (n_columns, n_prisms, n_frames)
        self.stream.set_time(TIMELINE, duration=np.timedelta64(int(_ns(self._wave_t[-1])), 'ns'))
        for c in range(wave.shape[0]):
            lim = float(np.max(np.abs(wave[c]))) or 1.0
            self.stream.log(f'wave/column_{c}', rr.Tensor(wave[c], dim_names=('prism', 'frame'),
                                                          value_range=(-lim, lim)))

    def close(self):
        """Flush, then finish the file / disconnect. Idempotent."""
        if self._closed:
            return
        self.flush(wave=True)
        self._closed = True
        try:
            self.stream.flush()
        except RuntimeError as exc:             # the viewer went away: the file is still written
            raise ValueError(f'rerun: {exc}') from None
        finally:
            self.stream.disconnect()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
