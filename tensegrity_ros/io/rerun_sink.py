"""Headless Rerun recordings of a run (docs/rerun.md), on rerun-sdk's public API.

    with RerunRecorder(sim.network, path='run.rrd') as rec:     # or connect='rerun+http://...'
        runner.run(sim, t_end, output_dt, on_frame=rec.frame)
        rec.command(0.0, 'impact v0 = 0.1 m/s')

One owned :class:`rerun.RecordingStream` (never the global one), one timeline ``sim_time`` (a
duration from the simulation clock; no wall-clock timelines). Frames are copied into buffers and
sent every ``flush_every`` frames as columns (``rr.send_columns``, one call per entity); Rerun's
own threads encode and write. Entities:

- ``topology`` (static): member index arrays ``bar_a``/``bar_b``/``cable_a``/``cable_b``,
  ``cable_kind``, ``levels`` (flattened) and ``levels_shape``, the reference positions ``x0``.
- ``world/nodes`` Points3D, ``world/bars`` and ``world/cables`` LineStrips3D (one strip of two
  points per member, float32 m); cables coloured by tension as the ROS markers
  (:func:`tensegrity_ros.msgs.style.tension_colors`), slack cables grey and translucent.
- ``strain/column_c`` Scalars (one series per prism), ``strain_profile/column_c`` BarChart (the
  strain per prism at each time), ``strain_profile_log/column_c`` BarChart (the same on the
  symmetric-log scale :func:`~tensegrity_ros.io.rerun_columns.symlog`), ``base_force/column_c``
  Scalars N (positive compressive).
- ``wave/column_c`` Tensor (prism x time from the last impact: the last ``wave_window`` frames,
  strain on the symmetric-log scale) and ``wave_scale/column_c`` (its colour scale), at the time
  of every ``wave_every``-th frame (more apart as the map grows: at most a tenth of its frames)
  and of the last: at every time cursor the map of the wave so far.
- ``energy`` J, ``constraint_error`` and ``energy_balance_error`` (of the frames that carry
  it) Scalars; ``episode`` Scalars (0, then one more after each reset of the node: the frame's
  ``episode``, or for frames without one the number of times the clock went back);
  ``commands`` TextLog; ``legend`` TextDocument.
- ``field/peak_pressure`` and ``field/pressure`` Images (``L``, over ``field/scale``), for arrays
  given a ``field_grid``.
"""
from __future__ import annotations

import math
import socket
import time
import urllib.parse
from pathlib import Path

import numpy as np
import rerun as rr

from tensegrity_ros.io.rerun_columns import (LINEAR_STRAIN, constant_ranges, duration_ns,
                                             heat_map_grid, packed_colors, segments, symlog,
                                             symlog_inverse, tensor_rows)
from tensegrity_ros.io.rerun_layout import TIMELINE, blueprint, legend_markdown
from tensegrity_ros.msgs.style import reference_tension_scale

DEFAULT_URL = 'rerun+http://127.0.0.1:9876/proxy'
PRISM_AXIS = 'prism (0: clamped end, at the bottom)'
BAR_RGBA = (200, 200, 210, 255)
NODE_RGBA = (240, 120, 40, 255)
SCALE_STEPS = 101
F32_MAX = float(np.finfo(np.float32).max)
# A file takes this many frames, then the recording goes on in the next segment file: rerun-sdk
# holds native memory for every chunk of a file until the file is finished (docs/rerun.md).
SPLIT_FRAMES = 50_000


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


class RerunRecorder:
    """Records solver frames of one network to a ``.rrd`` file and/or a live viewer.

    ``path``: the ``.rrd`` file; ``connect``: the gRPC URL of a running viewer (``True`` for
    :data:`DEFAULT_URL`); at least one. ``tension_scale`` N: the top of the colour ramp (default
    :func:`~tensegrity_ros.msgs.style.reference_tension_scale`). Frames go out every
    ``flush_every`` frames, or after ``max_latency_s`` wall seconds. A frame that does not match
    the network, or holds a value that is not finite or beyond float32, raises ValueError and
    records nothing. A new episode (a frame's ``episode`` differs from the previous frame's, or
    its time is not after the previous frame's) flushes what came before and starts a new heat
    map. After ``split_frames`` frames in one file (default :data:`SPLIT_FRAMES`; None: never)
    the recording goes on in ``STEM_1.rrd``, ``STEM_2.rrd``, ... next to ``path``, each file
    complete with the static entities (the blueprint is in the first), all of one recording id
    (:func:`segment_files`; ``paths`` lists them); segments of an earlier recording to the same
    ``path`` are removed when it starts."""

    def __init__(self, network, path=None, *, connect=None, tension_scale=None, flush_every=50,
                 max_latency_s=0.5, wave_window=1000, wave_every=10,
                 application_id='tensegrity_ros', recording_id=None, send_blueprint=True,
                 field_grid=None, split_frames=SPLIT_FRAMES):
        if path is None and not connect:
            raise ValueError('rerun: give a file path or a viewer URL (connect) to record to')
        if tension_scale is not None and not (np.isfinite(tension_scale) and tension_scale > 0):
            raise ValueError(f'rerun: tension_scale must be a positive number, got '
                             f'{tension_scale}')
        if split_frames is not None and int(split_frames) < 1:
            raise ValueError(f'rerun: split_frames must be at least 1 (or None), got '
                             f'{split_frames}')
        if min(int(flush_every), int(wave_window), int(wave_every)) < 1 or \
                not max_latency_s > 0:
            raise ValueError('rerun: flush_every, wave_window and wave_every must be at least 1, '
                             'max_latency_s positive')
        if field_grid is not None:
            field_grid = tuple(float(v) for v in field_grid)
            if len(field_grid) != 4 or not all(math.isfinite(v) for v in field_grid):
                raise ValueError(f'rerun: field_grid must be (x0, x1, z0, z1) m, got '
                                 f'{field_grid!r}')
        self.net, self.field_grid = network, field_grid
        self._layout = (max(network.n_columns, 1), field_grid) if send_blueprint else None
        self.path = None if path is None else str(path)
        self.url = (DEFAULT_URL if connect is True else connect) or None
        if self.url is not None:
            check_viewer(self.url)
        self.split_frames = None if split_frames is None else int(split_frames)
        self.paths = []                 # the files recorded to: path, then its segments
        if self.path is not None:
            _writable(self.path)
            for old in segment_files(self.path)[1:]:   # a previous recording's segments
                old.unlink()
        self.tension_scale = (reference_tension_scale(network) if tension_scale is None
                              else float(tension_scale))
        self.flush_every, self.max_latency_s = int(flush_every), float(max_latency_s)
        self.wave_window, self.wave_every = int(wave_window), int(wave_every)
        n_col = network.n_columns if network.n_prisms else 0
        self._shapes = ((network.n_nodes, 3), (network.levels.shape[0], network.n_prisms),
                        (network.n_cables,))
        self._n_base = network.n_columns if network.levels.size else 0
        b = self.flush_every
        self._x = np.empty((b,) + self._shapes[0])
        self._s = np.empty((b,) + self._shapes[1])
        self._tension = np.empty((b,) + self._shapes[2])
        self._base = np.zeros((b, self._n_base))
        self._scalars = np.empty((b, 5))        # t, energy, constraint and balance errors, episode
        self._ranges = {}                       # time series view -> [lo, hi] of its values
        self._wave = np.empty((n_col, network.n_prisms, self.wave_window))
        self._wave_t = np.empty(self.wave_window)
        self._n = self._wave_n = self._wave_at = 0     # frames: buffered, in the map, at its last
        self._lo = np.full(n_col, np.inf)             # strain extremes per column so far
        self._hi = np.full(n_col, -np.inf)
        self._impact_t = None
        self._commands = []                           # (t s, text, level) not yet sent
        self._last_t = self._episode = None
        self._last_flush = time.monotonic()
        self.n_frames = self.n_commands = self.n_restarts = self.n_fields = 0
        self._closed = False
        self._in_file = 0                             # frames sent to the current file
        self.stream = rr.RecordingStream(application_id, recording_id=recording_id)
        self.stream.set_log_time_enabled(False)
        self.stream.set_log_tick_enabled(False)
        self._to_file(self.path)

    def _to_file(self, path):
        """Record to ``path`` (and the viewer) from now on: the static entities first, and in
        the first file the blueprint. The stream stays the same and later files get no
        blueprint of their own: rerun-sdk 0.41 never ends the two threads of a stream it
        made, a blueprint's included (rerun-io/rerun#2116)."""
        sinks = ([rr.FileSink(path)] if path else []) + (
            [rr.GrpcSink(self.url)] if self.url else [])
        self.stream.set_sinks(*sinks)
        if path:
            self.paths.append(path)
        if self._layout is not None and len(self.paths) <= 1:
            self.stream.send_blueprint(blueprint(*self._layout), make_active=True,
                                       make_default=True)
        self._log_static(self._wave.shape[0])

    def _next_file(self):
        """Finish the current file (its footer written) and go on in the next segment."""
        path = str(segment_path(self.path, len(self.paths)))
        _writable(path)
        self.stream.flush()
        self._in_file = 0
        self._to_file(path)

    # -- static ---------------------------------------------------------------------------------
    def _log_static(self, n_col):
        net, log = self.net, self.stream.log
        log('topology', rr.AnyValues(
            bar_a=np.asarray(net.bar_a, np.int64), bar_b=np.asarray(net.bar_b, np.int64),
            cable_a=np.asarray(net.cable_a, np.int64), cable_b=np.asarray(net.cable_b, np.int64),
            cable_kind=[str(k) for k in net.cable_kind],
            levels=np.asarray(net.levels, np.int64).ravel(),
            levels_shape=np.asarray(net.levels.shape, np.int64),
            x0=np.asarray(net.x0, np.float64).ravel()), static=True)
        log('legend', rr.TextDocument(legend_markdown(self.tension_scale),
                                      media_type='text/markdown'), static=True)
        log('world', rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)     # column axis: z
        log('world/nodes', rr.Points3D.from_fields(colors=[NODE_RGBA],
                                                   radii=rr.Radius.ui_points(3.0)), static=True)
        log('world/bars', rr.LineStrips3D.from_fields(colors=[BAR_RGBA],
                                                      radii=rr.Radius.ui_points(2.5)), static=True)
        log('world/cables', rr.LineStrips3D.from_fields(radii=rr.Radius.ui_points(1.2)),
            static=True)
        log('energy', rr.SeriesLines(names=['energy']), static=True)
        log('constraint_error', rr.SeriesLines(names=['constraint error']), static=True)
        log('energy_balance_error', rr.SeriesLines(names=['energy balance error']), static=True)
        names = [f'prism {p}' for p in range(net.n_prisms)]
        for c in range(n_col):
            log(f'strain/column_{c}', rr.SeriesLines(names=names), static=True)

    # -- per frame ------------------------------------------------------------------------------
    def frame(self, frame):
        """Buffer one :class:`solver.simulate.simulation.Frame` (see the class text)."""
        self._open()
        t = float(frame.t)
        x, strain, tension = frame.positions, frame.strain, frame.tension
        if (np.shape(x), np.shape(strain), np.shape(tension)) != self._shapes:
            raise ValueError(f'rerun: frame at t = {t:g} s does not match the network '
                             f'(positions {np.shape(x)}, strain {np.shape(strain)}, '
                             f'tension {np.shape(tension)}); not recorded')
        base = np.asarray(frame.base_force, dtype=np.float64)
        balance = frame.energy_balance_error
        values = (('time', t), ('energy', frame.energy),
                  ('constraint error', frame.constraint_error), ('positions', x),
                  ('strain', strain), ('tension', tension), ('base force', base),
                  ('energy balance error', 0.0 if balance is None else balance))
        for name, v in values:
            a = np.abs(np.asarray(v, dtype=np.float64))
            if not (np.isfinite(a).all() and (a <= F32_MAX).all()):
                raise ValueError(f'rerun: frame at t = {t:g} s has non-finite {name} (or beyond '
                                 f'float32); not recorded')
        episode = frame.episode
        if (self._last_t is not None and t <= self._last_t) or (
                episode is not None and self._episode is not None and episode != self._episode):
            self.flush()                                          # a reset: a new episode
            self._wave_n = self._wave_at = 0
            self.n_restarts += 1
        self._episode = episode
        i = self._n
        self._x[i], self._s[i], self._tension[i] = x, strain, tension
        if self._n_base:            # a frame without base forces records 0
            self._base[i] = base if base.shape == (self._n_base,) else 0.0
        self._scalars[i] = (t, frame.energy, frame.constraint_error,
                            np.nan if balance is None else balance,
                            self.n_restarts if episode is None else episode)
        self._last_t, self._n = t, i + 1
        self.n_frames += 1
        if self._n == self.flush_every or \
                time.monotonic() - self._last_flush > self.max_latency_s:
            self.flush()

    def command(self, t, text, level=None):
        """A command (or any event) as a text entry at simulation time ``t`` s on ``commands``;
        ``level`` defaults to ERROR for texts starting with 'diverged', WARN for 'rejected' or
        'paused', else INFO.
        Commands are sent together with the frames (at the latest ``max_latency_s`` after the
        last batch, also while no frame comes), in the order they were given."""
        self._open()
        if not math.isfinite(t):
            raise ValueError(f'rerun: command time {t} is not finite')
        text = str(text)
        if text.startswith('impact') or ': impact ' in text:     # the heat map starts here
            self._impact_t = float(t)
        self._commands.append((float(t), text, level or (
            'ERROR' if text.startswith('diverged') else
            'WARN' if text.startswith(('rejected', 'paused')) else 'INFO')))
        self.n_commands += 1
        if time.monotonic() - self._last_flush > self.max_latency_s:
            self.flush()

    def field(self, t, peak, pressure=None, scale=None):
        """The field in the medium at simulation time ``t`` s: ``peak`` (n_z, n_x), the peak
        pressure so far on ``field_grid`` (rows: depth down, columns: x), optionally ``pressure``
        at ``t``, shown over ``scale`` (default the largest value of ``peak``)."""
        self._open()
        if self.field_grid is None:
            raise ValueError('rerun: field images need a field_grid (x0, x1, z0, z1)')
        arrays = [np.array(a, dtype=np.float64) for a in (peak, pressure) if a is not None]
        if arrays[0].ndim != 2 or any(a.shape != arrays[0].shape for a in arrays):
            raise ValueError(f'rerun: field images must be 2-D of one shape, got '
                             f'{[a.shape for a in arrays]}')
        if not (math.isfinite(t) and all(np.isfinite(a).all() for a in arrays)):
            raise ValueError(f'rerun: field at t = {t:g} s is not finite; not recorded')
        scale = float(arrays[0].max(initial=0.0)) if scale is None else float(scale)
        scale = scale if math.isfinite(scale) and scale > 0 else 1.0
        self.stream.set_time(TIMELINE, duration=duration_ns(t))
        self.stream.log('field/peak_pressure', rr.Image(
            np.clip(arrays[0] / scale, 0.0, 1.0).astype(np.float32), color_model='L'))
        self.stream.log('field/scale', rr.Scalars([scale]))
        if len(arrays) > 1:
            self.stream.log('field/pressure', rr.Image(np.clip(
                0.5 + 0.5 * arrays[1] / scale, 0.0, 1.0).astype(np.float32), color_model='L'))
        self.n_fields += 1

    # -- batches --------------------------------------------------------------------------------
    def flush(self):
        """Send the buffered frames as columns (with the heat maps that fall among them)."""
        self._open()
        n, self._n = self._n, 0
        self._last_flush = time.monotonic()
        if n:
            if self.path and self.split_frames and self._in_file >= self.split_frames:
                self._next_file()
            self._send(n)
            self._in_file += n
        if self._commands:
            times, texts, levels = zip(*self._commands)
            self._commands = []
            rr.send_columns('commands', [rr.TimeColumn(TIMELINE, duration=duration_ns(times))],
                            rr.TextLog.columns(text=list(texts), level=list(levels)),
                            recording=self.stream)

    def _send(self, n):
        net = self.net
        t = self._scalars[:n, 0]
        index = [rr.TimeColumn(TIMELINE, duration=duration_ns(t))]

        def put(path, columns):
            rr.send_columns(path, index, columns, recording=self.stream)
        x = self._x[:n].astype(np.float32)
        put('world/nodes', rr.Points3D.columns(positions=x.reshape(-1, 3)).partition(
            [net.n_nodes] * n))
        if net.n_bars:
            bars = np.stack([x[:, net.bar_a], x[:, net.bar_b]], axis=2).reshape(-1, 2, 3)
            put('world/bars', [segments(bars, n)])
        if net.n_cables:
            cables = np.stack([x[:, net.cable_a], x[:, net.cable_b]], axis=2).reshape(-1, 2, 3)
            put('world/cables', [segments(cables, n)] + list(rr.LineStrips3D.columns(
                colors=packed_colors(self._tension[:n], self.tension_scale))
                .partition([net.n_cables] * n)))
        n_p = net.n_prisms
        for c in range(self._wave.shape[0]):
            s = self._s[:n, c].copy()
            put(f'strain/column_{c}', rr.Scalars.columns(scalars=s.ravel()).partition([n_p] * n))
            put(f'strain_profile/column_{c}', [tensor_rows(s)])
            put(f'strain_profile_log/column_{c}', [tensor_rows(symlog(s))])
            self._lo[c], self._hi[c] = min(self._lo[c], s.min()), max(self._hi[c], s.max())
        for c in range(self._n_base):
            put(f'base_force/column_{c}', rr.Scalars.columns(scalars=self._base[:n, c].copy()))
        put('energy', rr.Scalars.columns(scalars=self._scalars[:n, 1].copy()))
        put('constraint_error', rr.Scalars.columns(scalars=self._scalars[:n, 2].copy()))
        put('episode', rr.Scalars.columns(scalars=self._scalars[:n, 4].copy()))
        has = np.isfinite(self._scalars[:n, 3])        # the frames that carry a balance error
        for view, v in (('base_force', self._base[:n]), ('energy', self._scalars[:n, 1]),
                        ('constraint_error', self._scalars[:n, 2]),
                        ('energy_balance_error', self._scalars[:n, 3][has])):
            if v.size:
                r = self._ranges.setdefault(view, [np.inf, -np.inf])
                r[0], r[1] = min(r[0], float(v.min())), max(r[1], float(v.max()))
        if has.any():
            rr.send_columns('energy_balance_error', [rr.TimeColumn(TIMELINE, duration=duration_ns(
                t[has]))], rr.Scalars.columns(scalars=self._scalars[:n, 3][has]),
                recording=self.stream)
        j = 0
        while self._wave.shape[0] and j < n:          # the heat map's ring, a map when due
            m = min(n - j, max(1, self._wave_due() - (self._wave_n - self._wave_at)))
            self._ring(t[j:j + m], self._s[j:j + m])
            j += m
            if self._wave_n - self._wave_at >= self._wave_due():
                self._log_wave()

    def _wave_due(self):
        """Frames between two heat maps: ``wave_every``, or a tenth of the frames the map
        holds, whichever is more (the bytes of the maps stay within those of the frames)."""
        return max(self.wave_every, min(self._wave_n, self.wave_window) // 10)

    def _ring(self, t, s):
        """Put the frames of times ``t`` and strains ``s`` (n, n_col, n_prisms) in the ring."""
        w, n = self.wave_window, len(t)
        keep = slice(max(0, n - w), n)
        at = (self._wave_n + keep.start + np.arange(keep.stop - keep.start)) % w
        self._wave[:, :, at] = s[keep].transpose(1, 2, 0)
        self._wave_t[at] = t[keep]
        self._wave_n += n

    def _log_wave(self):
        """The heat map and its colour scale of every column at the time of the last frame in
        the ring: the wave from the impact to that time, strain on the symmetric-log scale."""
        self._wave_at = self._wave_n
        n, w = self._wave_n, self.wave_window
        order = np.arange(n) if n <= w else np.r_[n % w:w, 0:n % w]       # oldest first
        times = self._wave_t[order]
        grid, pick = heat_map_grid(times, self._impact_t)
        label = (f'sim_time {grid[0]:.3f} to {grid[-1]:.3f} s' + (
            f', {1e3 * (grid[1] - grid[0]):.3g} ms per column' if len(grid) > 1 else ''))
        self.stream.set_time(TIMELINE, duration=duration_ns(times[-1]))
        for c in range(self._wave.shape[0]):
            image = symlog(self._wave[c][:, order[pick]]).astype(np.float32)
            lim = float(np.abs(image).max(initial=0.0)) or 1.0
            self.stream.log(f'wave/column_{c}', rr.Tensor(
                image, dim_names=(PRISM_AXIS, label), value_range=(-lim, lim)))
            self.stream.log(f'wave_scale/column_{c}', rr.Tensor(
                np.linspace(-lim, lim, SCALE_STEPS, dtype=np.float32)[None, :],
                dim_names=('', scale_label(lim)), value_range=(-lim, lim)))

    def sync(self):
        """Send everything buffered and wait until Rerun has written it."""
        self.flush()
        self.stream.flush()

    def close(self):
        """Send what is buffered and the heat map at the last frame, then finish the file /
        disconnect: the file is complete when this returns. Idempotent."""
        if self._closed:
            return
        try:
            self.flush()
            if self._wave_n > self._wave_at:
                self._log_wave()
            for c in range(len(self._lo) if self.n_frames else 0):
                # two invisible bars at the run's strain extremes: the chart keeps its y range
                for path, ends in (('strain_profile', (self._lo[c], self._hi[c])),
                                   ('strain_profile_log', symlog([self._lo[c], self._hi[c]]))):
                    self.stream.log(f'{path}/column_{c}/range', rr.BarChart(
                        [float(v) for v in ends], abscissa=[0.0, 0.0], widths=[0.0, 0.0],
                        color=(0, 0, 0, 0)), static=True)
            flat = constant_ranges(self._ranges)
            if flat and self._layout is not None:
                self.stream.send_blueprint(blueprint(*self._layout, y_ranges=flat),
                                           make_active=True, make_default=True)
            if self.url is not None:
                self.stream.flush()
        except Exception as exc:
            raise ValueError(f'rerun: {exc}') from None
        finally:
            self._closed = True
            self.stream.disconnect()

    def _open(self):
        if self._closed:
            raise ValueError('rerun: recorder is closed')

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def scale_label(lim):
    """The name of the colour scale's axis for a heat map of symmetric-log range ``lim``: the
    strain at its ends, at half and at the linear threshold."""
    ticks = ', '.join(f'{symlog_inverse(v):+.3g}' for v in (-lim, -lim / 2, 0.0, lim / 2, lim))
    return (f'strain, symmetric log (linear within +-{LINEAR_STRAIN:g}): at 0, 1/4, 1/2, 3/4, 1 '
            f'of the width: {ticks}')


def _writable(path):
    try:
        open(path, 'wb').close()
    except OSError as exc:
        raise ValueError(f'rerun: cannot record to {path}: {exc.strerror or exc}') from None


def segment_path(path, k):
    """The ``k``-th file of a recording to ``path``: ``path`` itself for 0, else ``STEM_k.rrd``
    next to it."""
    p = Path(path)
    return p if k == 0 else p.with_name(f'{p.stem}_{k}{p.suffix or ".rrd"}')


def segment_files(path):
    """The files of a recording to ``path`` that exist, in order: ``path``, ``STEM_1.rrd``,
    ``STEM_2.rrd``, ... (to the first missing one). Open them together (``rerun STEM*.rrd``): they
    are one recording."""
    out, k = [], 0
    while segment_path(path, k).exists():
        out.append(segment_path(path, k))
        k += 1
    return out
