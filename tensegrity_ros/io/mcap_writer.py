"""MCAP recording in the ROS 2 profile (docs/interfaces.md section 5).

:class:`McapRecorder` takes rclpy message objects, serializes them to CDR with
``rclpy.serialization.serialize_message`` and writes them the way rosbag2's MCAP storage does:

- schema encoding ``ros2msg`` with the full concatenated definition (:func:`full_definition`: the
  main ``.msg`` text, then every dependency after a line of 80 ``=`` and ``MSG: pkg/Type``),
- channel metadata ``offered_qos_profiles`` (:func:`qos_yaml`) and ``topic_type_hash`` (RIHS01),
- a summary with statistics, chunk indexes and message indexes when the file is closed.

Crash safety: chunks are small and a chunk is closed and handed to the operating system at least
every ``flush_period_s`` seconds of wall time (a background thread does it while nothing is being
written), so a SIGKILL loses at most that much. SIGINT and SIGTERM finish the file properly when
the recorder is a context manager inside :func:`signals_as_interrupt` (or rclpy's own handlers).
Log times are the messages' simulation-time stamps in nanoseconds, never the wall clock.

With ``bag=True`` the recorder writes a rosbag2 bag folder (docs/mcap.md): ``runs/x`` or
``runs/x.mcap`` becomes ``runs/x/x_0.mcap`` and, when the recorder closes, ``runs/x/metadata.yaml``
(:func:`bag_metadata`, metadata version :data:`BAG_VERSION`).
"""
from __future__ import annotations

import atexit
import contextlib
import json
import os
import re
import signal
import threading
import time
from functools import lru_cache
from pathlib import Path

import numpy as np

DELIMITER = '=' * 80 + '\n'
_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVES = frozenset({'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16',
                         'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string'})
# rmw reports unset durations of a Fast DDS endpoint as RMW_DURATION_INFINITE; rosbag2 stores that
INFINITE = {'sec': 9223372036, 'nsec': 854775807}
PROFILE = 'ros2'
# rosbag2's metadata.yaml version: 8 is the newest that Humble's rosbag2 reads (its QoS is a YAML
# text with integer policies; 9 turned it into a YAML list) and Jazzy's and later read it too
BAG_VERSION = 8


class RecordingError(ValueError):
    """A recording could not be written (bad path, unknown message type)."""


def share_dir():
    """The ``share`` directory holding ``<pkg>/msg/*.msg`` (the venv's, or a ROS install's)."""
    import sys
    candidates = [Path(sys.prefix) / 'share']
    candidates += [Path(p) / 'share' for p in os.environ.get('AMENT_PREFIX_PATH', '').split(':')
                   if p]
    for c in candidates:
        if (c / 'std_msgs' / 'msg').is_dir():
            return c
    raise RecordingError('cannot find the ROS message definitions (<prefix>/share/std_msgs/msg)')


def type_name(msg_or_class):
    """``'sensor_msgs/msg/PointCloud2'`` for an rclpy message (or message class)."""
    cls = msg_or_class if isinstance(msg_or_class, type) else type(msg_or_class)
    parts = cls.__module__.split('.')
    if len(parts) < 2 or parts[1] not in ('msg', 'srv', 'action'):
        raise RecordingError(f'{cls.__module__}.{cls.__name__} is not a ROS message class')
    return f'{parts[0]}/{parts[1]}/{cls.__name__}'


def _split(name):
    """('pkg', 'msg', 'Type') from 'pkg/Type' or 'pkg/msg/Type'."""
    parts = name.split('/')
    if len(parts) == 2:
        return parts[0], 'msg', parts[1]
    if len(parts) == 3:
        return tuple(parts)
    raise RecordingError(f'message type name {name!r} not understood')


@lru_cache(maxsize=None)
def _msg_text(name):
    pkg, ns, typ = _split(name)
    path = share_dir() / pkg / ns / f'{typ}.msg'
    if not path.is_file():
        raise RecordingError(f'no .msg definition for {name} (looked for {path})')
    return path.read_text()


def _dependencies(text, package):
    """Sorted field types of a .msg text that are messages, as 'pkg/Type' (rosbag2's parse)."""
    deps = set()
    for m in _FIELD_TYPE.finditer(text):
        t = m.group(1)
        if t in _PRIMITIVES:
            continue
        deps.add(t if '/' in t else f'{package}/{t}')
    return sorted(deps)


@lru_cache(maxsize=None)
def full_definition(name):
    """The complete ``ros2msg`` definition of ``name`` as rosbag2 writes it into a schema: the
    type's own .msg text, then depth first each not yet seen dependency, preceded by ``\\n``, 80
    ``=`` and ``MSG: pkg/Type`` (std::set order, so sorted)."""
    seen = set()

    def append(dep_name):
        text = _msg_text(dep_name)
        out = text
        for dep in _dependencies(text, _split(dep_name)[0]):
            if dep not in seen:
                seen.add(dep)
                out += '\n' + DELIMITER + f'MSG: {dep}\n' + append(dep)
        return out

    return append(name)


@lru_cache(maxsize=None)
def type_hash(name):
    """The RIHS01 type hash of ``name`` from its ``.json`` type description, or '' if absent."""
    pkg, ns, typ = _split(name)
    path = share_dir() / pkg / ns / f'{typ}.json'
    if not path.is_file():
        return ''
    for entry in json.loads(path.read_text()).get('type_hashes', []):
        if entry.get('type_name') == f'{pkg}/{ns}/{typ}':
            return entry.get('hash_string', '')
    return ''


def _duration(d):
    ns = int(getattr(d, 'nanoseconds', 0))
    if ns <= 0:
        return dict(INFINITE)
    return {'sec': ns // 10**9, 'nsec': ns % 10**9}


def _profile_yaml(fields):
    """The YAML text of a one-profile list: ``fields`` ``(key, value)`` in order, a dict value
    (a duration) as a nested mapping."""
    lines = []
    for i, (key, value) in enumerate(fields):
        lead = '- ' if i == 0 else '  '
        if isinstance(value, dict):
            lines.append(f'{lead}{key}:')
            lines += [f'    {k}: {v}' for k, v in value.items()]
        else:
            lines.append(f'{lead}{key}: {value}')
    return '\n'.join(lines)


def qos_yaml(qos=None):
    """``offered_qos_profiles`` YAML (one profile) for an rclpy ``QoSProfile`` in the form rosbag2
    (Jazzy and later, metadata version 9) writes it: policies as strings, durations as
    ``{sec, nsec}``, unset durations as infinite, system-default liveliness as ``automatic`` (what
    Fast DDS reports for an rclpy publisher). Default: reliable, volatile, keep last 10."""
    if qos is None:
        from rclpy.qos import QoSProfile
        qos = QoSProfile(depth=10)
    liveliness = qos.liveliness.name.lower()
    if liveliness == 'system_default':
        liveliness = 'automatic'
    fields = [
        ('history', qos.history.name.lower()),
        ('depth', int(qos.depth)),
        ('reliability', qos.reliability.name.lower()),
        ('durability', qos.durability.name.lower()),
        ('deadline', _duration(qos.deadline)),
        ('lifespan', _duration(qos.lifespan)),
        ('liveliness', liveliness),
        ('liveliness_lease_duration', _duration(qos.liveliness_lease_duration)),
        ('avoid_ros_namespace_conventions', 'true' if qos.avoid_ros_namespace_conventions
         else 'false'),
    ]
    return _profile_yaml(fields)


def qos_yaml_v8(qos=None):
    """``offered_qos_profiles`` of a ``metadata.yaml`` of version :data:`BAG_VERSION`: the text
    of a one-profile YAML list with the policies as rmw's integers (history 1 keep last, 2 keep
    all; reliability 1 reliable, 2 best effort; durability 1 transient local, 2 volatile;
    liveliness 1 automatic), as Humble's ``Rosbag2QoS`` decodes them."""
    if qos is None:
        from rclpy.qos import QoSProfile
        qos = QoSProfile(depth=10)

    def code(policy, default):
        value = int(policy.value)
        return default if value == 0 else value        # system default: what Fast DDS offers
    fields = [
        ('history', code(qos.history, 1)), ('depth', int(qos.depth)),
        ('reliability', code(qos.reliability, 1)), ('durability', code(qos.durability, 2)),
        ('deadline', _duration(qos.deadline)), ('lifespan', _duration(qos.lifespan)),
        ('liveliness', code(qos.liveliness, 1)),
        ('liveliness_lease_duration', _duration(qos.liveliness_lease_duration)),
        ('avoid_ros_namespace_conventions', 'true' if qos.avoid_ros_namespace_conventions
         else 'false')]
    return _profile_yaml(fields)


def bag_metadata(file_name, topics, first_ns, last_ns, ros_distro=None):
    """The ``metadata.yaml`` text of a bag holding the one MCAP file ``file_name``: ``topics`` a
    list of ``(name, type name, QoS profile, message count)`` in the order they were declared;
    ``first_ns``, ``last_ns`` the first and last log times (None: no message)."""
    import yaml
    count = sum(t[3] for t in topics)
    start = int(first_ns or 0)
    duration = int(last_ns - first_ns) if first_ns is not None else 0
    info = {
        'version': BAG_VERSION,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': count,
        'topics_with_message_count': [
            {'topic_metadata': {'name': name, 'type': type_name, 'serialization_format': 'cdr',
                                'offered_qos_profiles': qos_yaml_v8(qos),
                                'type_description_hash': type_hash(type_name)},
             'message_count': n} for name, type_name, qos, n in topics],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [file_name],
        'files': [{'path': file_name, 'starting_time': {'nanoseconds_since_epoch': start},
                   'duration': {'nanoseconds': duration}, 'message_count': count}],
        'custom_data': {},
        'ros_distro': ros_distro if ros_distro is not None else (
            os.environ.get('ROS_DISTRO') or 'kilted'),
    }

    class Dumper(yaml.SafeDumper):
        pass

    def text(dumper, value):
        style = '|' if '\n' in value else None
        return dumper.represent_scalar('tag:yaml.org,2002:str', value, style=style)
    Dumper.add_representer(str, text)
    return yaml.dump({'rosbag2_bagfile_information': info}, Dumper=Dumper, sort_keys=False,
                     default_flow_style=False, width=1000)


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
