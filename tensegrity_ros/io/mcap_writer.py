"""MCAP recording in the ROS 2 profile (docs/interfaces.md section 5).

:class:`McapRecorder` takes rclpy message objects, serializes them to CDR with
``rclpy.serialization.serialize_message`` and writes them the way rosbag2's MCAP storage does:

- schema encoding ``ros2msg`` with the full concatenated definition (the main ``.msg`` text,
  then every dependency after a line of 80 ``=`` and ``MSG: pkg/Type``),
- channel metadata ``offered_qos_profiles`` and ``topic_type_hash`` (RIHS01), both made by
  :mod:`tensegrity_ros.io.bag_format`,
- a summary with statistics, chunk indexes and message indexes when the file is closed.

Crash safety: chunks are small and a chunk is closed and handed to the operating system at least
every ``flush_period_s`` seconds of wall time (a background thread does it while nothing is being
written), so a SIGKILL loses at most that much. SIGINT and SIGTERM finish the file properly when
the recorder is a context manager inside :func:`signals_as_interrupt` (or rclpy's own handlers).
Log times are the messages' simulation-time stamps in nanoseconds, never the wall clock.

With ``bag=True`` the recorder writes a rosbag2 bag folder (docs/mcap.md): ``runs/x`` or
``runs/x.mcap`` becomes ``runs/x/x_0.mcap`` and, when the recorder closes, ``runs/x/metadata.yaml``
(``bag_format.bag_metadata``, metadata version ``bag_format.BAG_VERSION``).
"""
from __future__ import annotations

import atexit
import contextlib
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np

from tensegrity_ros.io.bag_format import (PROFILE, RecordingError, bag_metadata, full_definition,
                                          qos_yaml, type_hash, type_name)


def _finite(msg):
    """False if ``msg`` is a float array message (``*MultiArray``) with a non-finite value."""
    data = getattr(msg, 'data', None)
    if getattr(data, 'typecode', '') not in ('d', 'f') or not hasattr(msg, 'layout'):
        return True
    return bool(np.all(np.isfinite(np.frombuffer(data, dtype=data.typecode))))


class _DirectFile:
    """A write-through file: every ``write`` goes straight to the OS (no user-space buffer), so a
    record the MCAP writer has emitted survives a SIGKILL of this process."""

    def __init__(self, path):
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._pos = 0

    def write(self, data):
        view = memoryview(data)
        while view:
            n = os.write(self._fd, view)
            view = view[n:]
        self._pos += len(data)
        return len(data)

    def tell(self):
        return self._pos

    def flush(self):
        pass

    def close(self):
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


class McapRecorder:
    """Writes rclpy messages to one MCAP file (ROS 2 profile). Use as a context manager, or call
    :meth:`close`. Also a sink: ``recorder(topic, msg, stamp_ns)`` == ``recorder.write(...)``.

    ``chunk_size`` bytes (uncompressed) close a chunk early; ``flush_period_s`` of wall time bound
    what a SIGKILL can lose. Thread safe (one lock around the writer). ``bag``: write a rosbag2
    bag folder (:func:`~tensegrity_ros.io.mcap_reader.bag_paths`; ``folder`` names it, ``path``
    the MCAP file in it; ``metadata.yaml`` is written by :meth:`close`)."""

    def __init__(self, path, chunk_size=256 * 1024, flush_period_s=0.25, compression='zstd',
                 metadata=None, bag=False):
        from mcap.writer import CompressionType, Writer
        try:
            comp = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                    'none': CompressionType.NONE}[compression]
        except KeyError:
            raise RecordingError(f'compression must be zstd, lz4 or none, not {compression!r}')
        if not flush_period_s > 0:
            raise RecordingError(f'flush_period_s must be > 0, not {flush_period_s!r}')
        self.folder = None
        if bag:
            from tensegrity_ros.io.mcap_reader import BAG_METADATA, bag_paths
            self.folder, path = bag_paths(path)
            if self.folder.is_file():
                raise RecordingError(f'cannot write the bag folder {self.folder}: a file of '
                                     f'that name exists')
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if self.folder is not None:     # a previous recording's metadata is not this one's
                (self.folder / BAG_METADATA).unlink(missing_ok=True)
            self._file = _DirectFile(self.path)
        except OSError as exc:
            raise RecordingError(f'cannot write MCAP file {self.path}: {exc.strerror}') from None
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=comp)
        from rclpy.serialization import serialize_message
        self._serialize = serialize_message
        self._lock = threading.Lock()
        self._schemas = {}
        self._channels = {}
        self._sequence = {}
        self._qos = {}
        self._counts = {}                 # topic -> [type name, message count]
        self._first_ns = self._last_ns = None
        self._pending = False
        self._closed = False
        self.flush_period_s = float(flush_period_s)
        self.message_count = 0
        self.dropped = 0
        self._writer.start(profile=PROFILE, library='tensegrity_ros')
        for name, data in (metadata or {}).items():
            self._writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})
        self._last_flush = time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._flush_loop, name='mcap-flush', daemon=True)
        self._thread.start()
        atexit.register(self.close)        # a recorder left open is finished at normal exit

    def declare(self, topic, msg_class, qos=None):
        """Register ``topic`` with type ``msg_class`` and its offered QoS before its first message
        (otherwise the first message registers it with the default QoS)."""
        with self._lock:
            self._qos[topic] = qos
            self._channel(topic, msg_class)

    def _channel(self, topic, msg_or_class):
        cid = self._channels.get(topic)
        if cid is not None:
            return cid
        name = type_name(msg_or_class)
        sid = self._schemas.get(name)
        if sid is None:
            sid = self._writer.register_schema(name, 'ros2msg', full_definition(name).encode())
            self._schemas[name] = sid
        meta = {'offered_qos_profiles': qos_yaml(self._qos.get(topic))}
        digest = type_hash(name)
        if digest:
            meta['topic_type_hash'] = digest
        cid = self._writer.register_channel(topic, 'cdr', sid, meta)
        self._channels[topic] = cid
        self._counts[topic] = [name, 0]
        self._sequence[topic] = 0
        return cid

    def write(self, topic, msg, stamp_ns):
        """Append ``msg`` on ``topic`` with log and publish time ``stamp_ns`` (int, simulation
        nanoseconds); returns True. A float array message holding NaN or infinity (a malformed
        command the node received and rejected) is not logged: returns False and counts it in
        ``dropped`` (nothing NaN is ever logged; the node's ``/diagnostics`` say what it rejected).
        ``msg`` may also be serialized CDR ``bytes`` (see :meth:`write_serialized`). Writing to a
        closed recorder is an error."""
        if isinstance(msg, (bytes, bytearray)):
            return self.write_serialized(topic, msg, stamp_ns)
        if not _finite(msg):
            with self._lock:
                self.dropped += 1
            return False
        return self._add(topic, msg, self._serialize(msg), stamp_ns)

    __call__ = write

    def write_serialized(self, topic, data, stamp_ns):
        """Append an already serialized message (CDR ``bytes``, e.g. from
        :mod:`tensegrity_ros.msgs.cdr`) on a topic registered with :meth:`declare`; returns True.
        The caller vouches that it holds no NaN (:func:`cdr.frame_messages_cdr` checks)."""
        if topic not in self._channels:
            raise RecordingError(f'{topic}: declare the topic before writing serialized data')
        return self._add(topic, None, data, stamp_ns)

    def _add(self, topic, msg, data, stamp_ns):
        stamp_ns = int(stamp_ns)
        if stamp_ns < 0:
            raise RecordingError(f'{topic}: negative stamp {stamp_ns} ns')
        with self._lock:
            if self._closed:
                raise RecordingError(f'{self.path} is closed')
            cid = self._channel(topic, msg)
            self._sequence[topic] += 1
            self._counts[topic][1] += 1
            if self._first_ns is None:
                self._first_ns = stamp_ns
            self._first_ns, self._last_ns = min(self._first_ns, stamp_ns), max(
                self._last_ns or 0, stamp_ns)
            self._writer.add_message(cid, log_time=stamp_ns, data=data, publish_time=stamp_ns,
                                     sequence=self._sequence[topic])
            self.message_count += 1
            self._pending = True
            if time.monotonic() - self._last_flush >= self.flush_period_s:
                self._flush_locked()
        return True

    def _flush_locked(self):
        if self._pending:
            self._writer.flush()
            self._pending = False
        self._last_flush = time.monotonic()

    def flush(self):
        """Close the open chunk and hand everything to the operating system."""
        with self._lock:
            if not self._closed:
                self._flush_locked()

    def _flush_loop(self):
        while not self._stop.wait(self.flush_period_s / 2):
            with self._lock:
                if self._closed:
                    return
                if time.monotonic() - self._last_flush >= self.flush_period_s:
                    self._flush_locked()

    def close(self):
        """Write the summary (schemas, channels, statistics, indexes) and close the file; for a
        bag, then ``metadata.yaml`` (written whole, then renamed into place)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._stop.set()
            atexit.unregister(self.close)
            try:
                self._writer.finish()
            finally:
                self._file.close()
            if self.folder is not None:
                self._write_bag_metadata()

    def _write_bag_metadata(self):
        from tensegrity_ros.io.mcap_reader import BAG_METADATA
        topics = [(topic, name, self._qos.get(topic), n)
                  for topic, (name, n) in self._counts.items()]
        text = bag_metadata(self.path.name, topics, self._first_ns, self._last_ns)
        part = self.folder / (BAG_METADATA + '.part')
        part.write_text(text)
        os.replace(part, self.folder / BAG_METADATA)

    @property
    def closed(self):
        return self._closed

    @property
    def pending(self):
        """True while some written message is not yet handed to the operating system."""
        return self._pending

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


@contextlib.contextmanager
def signals_as_interrupt():
    """Within the block SIGINT and SIGTERM raise KeyboardInterrupt, so ``with`` blocks and
    ``finally`` clauses (closing a recording) run; SIGINT too where the process started with it
    ignored, as a shell starts its background jobs (``tensegrity run --mcap ... &``: ``kill
    -INT`` then still closes the file). Only in the main thread; elsewhere a no-op."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise KeyboardInterrupt(signal.Signals(signum).name)

    old = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)
