"""Headless Rerun recordings of a run (docs/interfaces.md section 6).

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
- ``base_force/column_0`` Scalars: ``frame.base_force[0]`` N (the axial reaction at the clamped
  base, positive compressive); one entity per column.
- ``energy`` (J) and ``constraint_error`` Scalars; ``commands`` TextLog events.
- ``field/peak_pressure`` Image (float32, one channel, depth down the rows, x along the array
  across the columns; given to :meth:`RerunRecorder.field`, with a ``field_grid``): the peak
  pressure in the host medium so far (:mod:`solver.analysis.field`) over its scale,
  ``field/scale`` Scalars
  (that scale, model units), and optionally ``field/pressure`` Image, the pressure at that time
  mapped to ``0.5 + 0.5 p / scale`` (0.5: zero pressure).

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

import atexit
import math
import mmap
import os
import socket
import subprocess
import sys
import threading
import time
import urllib.parse
from multiprocessing.connection import Connection
from multiprocessing.reduction import send_handle
from pathlib import Path

import numpy as np

DEFAULT_URL = 'rerun+http://127.0.0.1:9876/proxy'
# a frame is refused unless every value is finite and fits float32 (as positions are stored)
_F32_MAX = float(np.finfo(np.float32).max)


def reference_tension_scale(network):
    """Twice the largest cable tension N of the reference geometry (1 N without prestress): the
    default top of the colour ramp, as the node uses for its markers."""
    x0 = np.asarray(network.x0)
    s = np.linalg.norm(x0[network.cable_b] - x0[network.cable_a], axis=1)
    rest = np.asarray(network.cable_rest_length)
    t = np.where(s > rest, np.asarray(network.cable_EA) * (s - rest) / rest, 0.0)
    return 2.0 * float(t.max()) if t.size and t.max() > 0 else 1.0


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


# -- the helper process ---------------------------------------------------------------------------
# A recording is written by a helper process (one per recording at a time, kept for later ones):
# Rerun's Python (the blueprint, the chunks) held the GIL that the simulation needs between its
# kernels when it ran on a thread of the simulation's process (docs/rerun.md).
_HELPER_CODE = ('import sys\nfrom tensegrity_ros.io.rerun_writer import serve\n'
                'serve(int(sys.argv[1]))\n')
_IDLE = []                              # helpers with no recording: at most one
_WAIT_SLICE_S = 1.0                     # a wait for the helper checks it is alive this often
_IDLE_LOCK = threading.Lock()


class _Helper:
    """A helper process running :func:`serve`, and the connection to it."""

    def __init__(self):
        ours, theirs = socket.socketpair()
        root = str(Path(__file__).resolve().parents[2])
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

    def stop(self, timeout_s=10.0):
        """Close the connection (the helper exits when it sees the end) and wait for it."""
        self.conn.close()
        try:
            self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def prestart():
    """Start a helper process now, if none is idle, so that a recording made later in this process
    does not wait for one (it imports rerun-sdk and pyarrow: about 0.4 s). ``tensegrity run`` and
    the node (with ``record_rerun``) call it before they build the simulation."""
    with _IDLE_LOCK:
        _drop_dead()
        if not _IDLE:
            _IDLE.append(_Helper())


def _drop_dead():
    for helper in [h for h in _IDLE if not h.alive()]:
        _IDLE.remove(helper)
        helper.conn.close()


def _take_helper():
    with _IDLE_LOCK:
        _drop_dead()
        if _IDLE:
            return _IDLE.pop()
    return _Helper()


def _give_back(helper):
    """Keep ``helper`` for a later recording, unless one is idle already (then it exits)."""
    with _IDLE_LOCK:
        _drop_dead()
        if not _IDLE:
            _IDLE.append(helper)
            return
    helper.stop()


def shutdown_helpers(timeout_s=10.0):
    """Let the idle helpers exit and wait for them (at exit: no helper outlives its owner, and
    none is left as a zombie). A helper busy with a recording finishes it first (see
    :meth:`RerunRecorder.close`)."""
    with _IDLE_LOCK:
        idle = list(_IDLE)
        _IDLE.clear()
    for helper in idle:
        helper.stop(timeout_s)


atexit.register(shutdown_helpers)


# -- the recorder ---------------------------------------------------------------------------------
class RerunRecorder:
    """Records solver frames of one network to a ``.rrd`` file and/or a live viewer.

    ``network``: the :class:`solver.build.network.Network` (read-only arrays). ``path``: ``.rrd``
    file to
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
    max_commands = 1000                 # commands handed over together, at most

    def __init__(self, network, path=None, *, connect=None, tension_scale=None, flush_every=50,
                 max_latency_s=0.5, wave_window=1000, wave_period_s=2.0,
                 application_id='tensegrity_ros', recording_id=None, send_blueprint=True,
                 spare_caller_cpu=True, expected_frames=None, field_grid=None):
        if path is None and not connect:
            raise ValueError('rerun: give a file path or a viewer URL (connect) to record to')
        if tension_scale is not None and not (np.isfinite(tension_scale) and tension_scale > 0):
            raise ValueError(f'rerun: tension_scale must be a positive number, got '
                             f'{tension_scale}')
        if field_grid is not None:
            field_grid = tuple(float(v) for v in field_grid)
            if len(field_grid) != 4 or not all(math.isfinite(v) for v in field_grid):
                raise ValueError(f'rerun: field_grid must be (x0, x1, z0, z1) m, got '
                                 f'{field_grid!r}')
        self.field_grid = field_grid
        self.n_fields = 0
        if int(flush_every) < 1 or int(wave_window) < 1:
            raise ValueError('rerun: flush_every and wave_window must be at least 1')
        if not max_latency_s > 0:
            raise ValueError(f'rerun: max_latency_s must be positive, got {max_latency_s}')
        if expected_frames is not None and not (isinstance(expected_frames, (int, np.integer))
                                                and expected_frames >= 1):
            raise ValueError(f'rerun: expected_frames must be a positive integer, got '
                             f'{expected_frames!r}')
        from solver.kernels.dynamics import finite_below   # the helper process needs no numba
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
        self._commands = []                     # (t, text, level) not yet handed over
        self._last_commands = self._last_flush
        self.n_restarts = 0
        # A batch buffer holds one float64 row per frame: positions (n_nodes * 3), strain
        # (n_columns * n_prisms), tension (n_cables), base force (n_columns, columns only), then
        # t, energy and constraint error.
        shapes = ((network.n_nodes, 3), tuple(network.levels.shape[:1]) + (network.n_prisms,),
                  (network.n_cables,))
        self._shapes = shapes
        n_x, n_s = 3 * network.n_nodes, math.prod(shapes[1])
        self._cols = (slice(0, n_x), slice(n_x, n_x + n_s),
                      slice(n_x + n_s, n_x + n_s + network.n_cables))
        self._n_base = network.n_columns if network.levels.size else 0
        c0 = n_x + n_s + network.n_cables
        self._cols += (slice(c0, c0 + self._n_base),)
        width = c0 + self._n_base + 3
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
                              self._buffers.shape, cpus, application_id, recording_id,
                              send_blueprint, self.field_grid))
            send_handle(helper.conn, memfd, helper.proc.pid)
        except (OSError, EOFError, AttributeError) as exc:    # AttributeError: no memfd here
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
        if self._error is None:
            self._error = (f'rerun: the recording helper process exited (code '
                           f'{self._helper.proc.poll()}); recording stopped')
        self._check()

    def _receive(self, until=None):
        """Handle the helper's messages (buffers handed back, its first error): those already
        here, or (``until``) every message up to the first of that kind, which is returned."""
        conn = self._helper.conn
        try:
            while True:
                if until is None:
                    if not conn.poll():
                        return None
                else:                           # wait, in slices: a helper gone is an error
                    while not conn.poll(_WAIT_SLICE_S):
                        if not self._helper.alive():
                            raise EOFError
                msg = conn.recv()
                if msg[0] == 'free':
                    self._free.append(msg[1])
                elif msg[0] == 'error' and self._error is None:
                    self._error = msg[1]
                if msg[0] == until:             # whatever its kind ('free' too)
                    return msg
        except (EOFError, OSError):
            self._lost()

    def _check(self):
        """Raise the helper's first error (its message, as ValueError) in the caller's thread."""
        if self._error is not None:
            raise ValueError(self._error)

    def sync(self):
        """Wait until the helper has sent everything handed to it so far (frames still in the
        batch buffer are not: see :meth:`flush`); raise its error if any."""
        if self._closed:
            raise ValueError('rerun: recorder is closed')
        self._post_commands()
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
        n_b, (cx, cs, ct, cb) = self.flush_every, self._cols
        self._bx = rows[:, cx].reshape((n_b,) + self._shapes[0])        # views into rows
        self._bs = rows[:, cs].reshape((n_b,) + self._shapes[1])
        self._bt = rows[:, ct]
        self._bb = rows[:, cb]

    def frame(self, frame):
        """Buffer one :class:`solver.simulate.simulation.Frame`; sends a batch every
        ``flush_every`` frames.
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
        base = getattr(frame, 'base_force', None)
        if self._n_base:            # a frame without base forces (an older caller) records 0
            self._bb[i] = base if np.shape(base) == (self._n_base,) else 0.0
        row[-3] = t
        row[-2] = float(frame.energy)
        row[-1] = float(frame.constraint_error)
        if not self._finite_below(row, _F32_MAX):      # compiled: no 512-bit instructions
            bad = [name for name, v in (('time', row[-3]), ('energy', row[-2]),
                                        ('constraint error', row[-1]), ('positions', x),
                                        ('strain', strain), ('tension', tension),
                                        ('base force', self._bb[i]))
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
        self._commands.append((float(t), text, level))
        self.n_commands += 1
        if len(self._commands) >= self.max_commands or \
                time.monotonic() - self._last_commands > self.max_latency_s:
            self._post_commands()

    def _post_commands(self):
        """Hand the commands given since the last time over in one message (the helper logs
        them as one chunk): before every batch, sync and close, so that the helper sees them in
        the same order relative to the frames as they were given; and at the latest after
        ``max_latency_s`` or :attr:`max_commands` of them (a paused node publishes no frames)."""
        self._last_commands = time.monotonic()
        if self._commands:
            entries, self._commands = self._commands, []
            self._post(('commands', entries))

    def field(self, t, peak, pressure=None, scale=None):
        """The field in the medium at simulation time ``t`` s: ``peak`` (n_z, n_x), the peak
        pressure so far on the recorder's ``field_grid`` (rows: depth from the surface down,
        columns: x), and optionally ``pressure`` (n_z, n_x) at ``t``, shown over ``scale``
        (default the largest value of ``peak``). Non-finite values raise ValueError and record
        nothing."""
        if self._closed:
            raise ValueError('rerun: recorder is closed')
        if self.field_grid is None:
            raise ValueError('rerun: field images need a field_grid (x0, x1, z0, z1)')
        self._receive()
        self._check()
        peak = np.array(peak, dtype=np.float64)
        arrays = [peak] + ([] if pressure is None else [np.array(pressure, dtype=np.float64)])
        if peak.ndim != 2 or any(a.shape != peak.shape for a in arrays):
            raise ValueError(f'rerun: field images must be 2-D of one shape, got '
                             f'{[a.shape for a in arrays]}')
        if not (math.isfinite(t) and all(np.isfinite(a).all() for a in arrays)):
            raise ValueError(f'rerun: field at t = {t:g} s is not finite; not recorded')
        scale = float(peak.max(initial=0.0)) if scale is None else float(scale)
        if not (math.isfinite(scale) and scale > 0):
            scale = 1.0
        self._post(('field', float(t), peak.astype(np.float32),
                    None if pressure is None else arrays[1].astype(np.float32), scale))
        self.n_fields += 1

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
        if n_t or wave or restart:
            self._post_commands()
            self._post(('send', self._index if n_t else None, n_t, wave, restart))
        if n_t:
            self._new_buffer()
        self._n_buf = 0

    def close(self):
        """Send what is buffered and the wave image, then finish the file / disconnect: the file
        is complete when this returns. Idempotent."""
        if self._closed:
            return
        self._closed = True
        n_t, self._n_buf = self._n_buf, 0
        try:
            self._post_commands()
            self._post(('close', self._index if n_t else None, n_t))
            _, error, self.helper_cpu_s = self._receive(until='closed')
        finally:
            self._rows = self._bx = self._bs = self._bt = self._bb = self._buffers = None
            self._mem.close()
        _give_back(self._helper)                # the file is finished: ready for another one
        if self._error is None:
            self._error = error
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
