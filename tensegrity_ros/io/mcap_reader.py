"""Read tensegrity MCAP logs: messages in file order, and :func:`load_run` -> NumPy arrays.

Needs only ``mcap`` and ``mcap_ros2`` (no rclpy): messages are decoded from their ``ros2msg``
schemas. A file cut short (a SIGKILLed recording) is read up to its last complete chunk: every
chunk is CRC-checked, reading stops at the first record that is incomplete or corrupt, and
``truncated`` says so.

A log is named by a bare ``.mcap`` file, a rosbag2 bag folder (``metadata.yaml`` and the
``.mcap`` files it lists; a folder without ``metadata.yaml``, a killed recording, by the
``.mcap`` files in it), or the path the recording was asked for (``runs/x.mcap`` or
``runs/x`` for the bag folder ``runs/x/``, :func:`bag_paths`).

Example::

    from tensegrity_ros.io.mcap_reader import load_run
    run = load_run('runs/demo/run')       # the bag folder (or runs/demo/run/run_0.mcap)
    run.time.shape        # (n_t,) s, never decreasing
    run.episode.shape     # (n_t,) int: 0, then + 1 at each reset of the node
    run.strain.shape      # (n_t, n_columns, n_prisms)
    run.positions.shape   # (n_t, n_nodes, 3) m
    run.tensions.shape    # (n_t, n_cables) N
    run.command_time, run.command_topic, run.command_values   # commands received
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

# frame topics by the last part of their name (the namespace may differ)
STRAIN, NODES, TENSION = 'strain', 'nodes', 'cable_tension'
COMMAND_PREFIX = '/cmd/'


BAG_METADATA = 'metadata.yaml'


class LogError(ValueError):
    """A file that is not a readable MCAP log."""


def bag_paths(path):
    """``(folder, mcap file)`` of the bag a recording asked for as ``path`` writes: ``runs/x`` or
    ``runs/x.mcap`` -> ``runs/x/`` holding ``runs/x/x_0.mcap`` (and ``metadata.yaml``), as
    ``ros2 bag record -o runs/x`` names them."""
    p = Path(path)
    folder = p.with_suffix('') if p.suffix == '.mcap' else p
    return folder, folder / f'{folder.name}_0.mcap'


def log_files(path):
    """The ``.mcap`` files of the log ``path`` names, in order (see the module text); raises
    :class:`LogError` when there is none."""
    p = Path(path)
    if p.is_file():
        return [p]
    folder = p if p.is_dir() else bag_paths(p)[0]
    if not folder.is_dir():
        raise LogError(f'no such MCAP file or bag folder: {p}')
    meta = folder / BAG_METADATA
    files = []
    if meta.is_file():
        import yaml
        try:
            info = yaml.safe_load(meta.read_text())['rosbag2_bagfile_information']
            files = [folder / f for f in info['relative_file_paths']]
        except (yaml.YAMLError, KeyError, TypeError) as exc:
            raise LogError(f'{meta}: not a rosbag2 metadata file ({exc})') from None
        missing = [str(f) for f in files if not f.is_file()]
        if missing:
            raise LogError(f'{meta} names files that do not exist: {", ".join(missing)}')
    else:
        files = sorted(folder.glob('*.mcap'))
    if not files:
        raise LogError(f'{folder}: a folder without MCAP files')
    return files


@dataclass
class LogMessage:
    """One message of a log: ``topic``, ``type_name`` ('pkg/msg/Type'), ``log_time_ns`` (int,
    simulation ns), ``data`` (CDR bytes), ``schema`` and ``channel`` records (mcap)."""
    topic: str
    type_name: str
    log_time_ns: int
    data: bytes
    schema: object
    channel: object


class McapLog:
    """A log (a file or a bag folder, :func:`log_files`) opened for one pass over its records.

    ``messages()`` yields :class:`LogMessage` in file order (= time order for our recorder);
    afterwards ``truncated`` is True if a file ended before its footer (a killed recording) and
    ``error`` holds the reason. ``decode(msg)`` decodes with the ``mcap_ros2`` decoder.
    ``path``: the (first) ``.mcap`` file; ``files``: all of them."""

    def __init__(self, path):
        self.files = log_files(path)
        self.path = self.files[0]
        self.truncated = False
        self.error = ''
        self.header = None
        self.channels = {}
        self.schemas = {}
        self.statistics = None
        self.metadata = {}
        self._decoders = {}

    def messages(self, topics=None):
        """Yield :class:`LogMessage` (only ``topics`` if given: an iterable of full names)."""
        wanted = None if topics is None else set(topics)
        for path in self.files:
            self.path = path
            self.header, self.channels, self.schemas = None, {}, {}
            yield from self._file_messages(wanted)

    def _file_messages(self, wanted):
        from mcap.exceptions import McapError
        from mcap.records import (Channel, Footer, Header, Message, Metadata, Schema,
                                  Statistics)
        from mcap.stream_reader import StreamReader
        with open(self.path, 'rb') as f:
            reader = StreamReader(f, validate_crcs=True)
            records = reader.records
            seen_footer = False
            while True:
                try:
                    rec = next(records)
                except StopIteration:
                    break
                except (McapError, ValueError, EOFError, MemoryError, OSError) as exc:
                    if self.header is None:
                        detail = str(exc) or type(exc).__name__
                        if self.path.stat().st_size == 0:
                            detail = 'the file is empty'
                        raise LogError(f'{self.path}: not an MCAP file ({detail})') from None
                    self.truncated = True
                    self.error = f'{type(exc).__name__}: {exc}'.rstrip(': ')
                    break
                except Exception as exc:   # a corrupt compressed chunk (zstd/lz4 errors)
                    self.truncated = True
                    self.error = f'{type(exc).__name__}: {exc}'
                    break
                if isinstance(rec, Header):
                    self.header = rec
                elif isinstance(rec, Schema):
                    self.schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    self.channels[rec.id] = rec
                elif isinstance(rec, Statistics):
                    self.statistics = rec
                elif isinstance(rec, Metadata):
                    self.metadata[rec.name] = dict(rec.metadata)
                elif isinstance(rec, Footer):
                    seen_footer = True
                elif isinstance(rec, Message):
                    ch = self.channels.get(rec.channel_id)
                    if ch is None:
                        raise LogError(f'{self.path}: message on unknown channel {rec.channel_id}')
                    if wanted is not None and ch.topic not in wanted:
                        continue
                    schema = self.schemas.get(ch.schema_id)
                    yield LogMessage(ch.topic, schema.name if schema else '', rec.log_time,
                                     rec.data, schema, ch)
            if not seen_footer and not self.truncated:
                self.truncated = True
                self.error = 'file ends before its footer'

    def decode(self, msg: LogMessage):
        """The message decoded by ``mcap_ros2`` (attribute access like an rclpy message)."""
        key = (msg.type_name, msg.schema.data if msg.schema else b'')
        dec = self._decoders.get(key)
        if dec is None:
            from mcap_ros2.decoder import DecoderFactory
            dec = DecoderFactory().decoder_for(msg.channel.message_encoding, msg.schema)
            if dec is None:
                raise LogError(f'{msg.topic}: cannot decode {msg.channel.message_encoding!r} '
                               f'with schema {msg.type_name!r}')
            self._decoders[key] = dec
        return dec(msg.data)


@dataclass
class RunLog:
    """A run read from a log, as arrays. Frame arrays hold the stamps at which strain, node
    positions and cable tensions were all logged:

    ``time`` (n_t,) s; ``strain`` (n_t, n_columns, n_prisms); ``positions`` (n_t, n_nodes, 3) m;
    ``tensions`` (n_t, n_cables) N. Commands received: ``command_time`` (n_cmd,) s,
    ``command_topic`` (n_cmd,) str ('impact' or 'prestrain'), ``command_values`` list of (k,)
    arrays. ``episode`` (n_t,) int: 0 from the start, one more after each reset of the node
    (frames are in the order of their episode, then time). ``topics``: full topic name ->
    message count read; ``truncated``: the file was cut short and only its complete chunks were
    read; ``network``: the topology the log carries (:func:`log_network`), or None."""
    time: np.ndarray
    strain: np.ndarray
    positions: np.ndarray
    tensions: np.ndarray
    command_time: np.ndarray
    command_topic: np.ndarray
    command_values: list
    topics: dict = field(default_factory=dict)
    truncated: bool = False
    network: object = None
    episode: np.ndarray = None

    def commands(self, name):
        """(times (k,) s, list of value arrays) of the command topic ``name`` ('impact', ...)."""
        idx = [i for i, t in enumerate(self.command_topic) if t == name]
        return self.command_time[idx], [self.command_values[i] for i in idx]


def multi_array_values(msg):
    """(shape tuple, float64 array of that shape) of a decoded ``Float64MultiArray``, using its
    layout dims (a flat vector when the layout is empty)."""
    data = np.asarray(msg.data, dtype=np.float64)
    data = data[int(msg.layout.data_offset):]
    shape = tuple(int(d.size) for d in msg.layout.dim)
    if not shape or int(np.prod(shape)) != data.size:
        return (data.size,), data
    return shape, data.reshape(shape)


def cloud_xyz(msg):
    """(n_points, 3) float64 x y z of a decoded ``PointCloud2`` (any field layout with float32
    x, y, z; big or little endian)."""
    offsets = {f.name: int(f.offset) for f in msg.fields}
    if not {'x', 'y', 'z'} <= offsets.keys():
        raise LogError('PointCloud2 without x, y, z fields')
    n = int(msg.width) * int(msg.height)
    order = '>' if msg.is_bigendian else '<'
    dtype = np.dtype({'names': ['x', 'y', 'z'], 'formats': [order + 'f4'] * 3,
                      'offsets': [offsets['x'], offsets['y'], offsets['z']],
                      'itemsize': int(msg.point_step)})
    raw = np.frombuffer(bytes(msg.data), dtype=dtype, count=n)
    return np.stack([raw['x'], raw['y'], raw['z']], axis=1).astype(np.float64)


def log_network(metadata):
    """The network topology of a log's ``tensegrity_network`` metadata record, as an object
    with the :class:`solver.build.network.Network` names (``bar_a``, ``bar_b``, ``edge_a``,
    ``edge_b``,
    ``cable_a``, ``cable_b`` int64; ``cable_kind`` str; ``levels`` (n_columns, n_levels, 3);
    ``x0`` (n_nodes, 3) m; ``n_nodes``, ``n_bars``, ``n_edges``, ``n_cables``, ``n_columns``,
    ``n_prisms``; ``scene``; ``tension_scale`` N), or None when the log has none."""
    import json
    from types import SimpleNamespace
    meta = metadata.get('tensegrity_network')
    if not meta:
        return None
    try:
        ints = {k: np.array(json.loads(meta[k]), dtype=np.int64)
                for k in ('bar_a', 'bar_b', 'edge_a', 'edge_b', 'cable_a', 'cable_b')}
        n_nodes = int(meta['n_nodes'])
        levels = np.array(json.loads(meta['levels']), dtype=np.int64).reshape(
            json.loads(meta['levels_shape']))
        x0 = np.array(json.loads(meta['x0']), dtype=np.float64).reshape(n_nodes, 3)
        kinds = np.array(json.loads(meta['cable_kind']), dtype=str)
        scale = float(meta.get('tension_scale') or 0.0)
    except (KeyError, ValueError, TypeError) as exc:
        raise LogError(f'tensegrity_network metadata unreadable: {exc}') from None
    return SimpleNamespace(
        scene=meta.get('scene', ''), tension_scale=scale, x0=x0, levels=levels,
        cable_kind=kinds, n_nodes=n_nodes,
        n_bars=len(ints['bar_a']), n_edges=len(ints['edge_a']), n_cables=len(ints['cable_a']),
        n_columns=levels.shape[0] if levels.ndim == 3 else 0,
        n_prisms=max(levels.shape[1] - 1, 0) if levels.ndim == 3 else 0, **ints)


def _leaf(topic):
    return topic.rsplit('/', 1)[-1]


def diagnostics_values(msg):
    """``{key: value}`` of a decoded ``DiagnosticArray``: numbers as float, other texts as str."""
    out = {}
    for status in msg.status:
        for kv in status.values:
            try:
                out[kv.key] = float(kv.value)
            except ValueError:
                out[kv.key] = kv.value
    return out


class Episodes:
    """The episode of each message of a log read in file order: the ``episode`` value of the
    latest ``/diagnostics`` (the node publishes one at once when it resets; 0 before the first),
    plus one for each time a frame's log time went back (logs written before the clock kept
    running across resets)."""

    def __init__(self, log):
        self.log, self.current, self.back, self._last = log, 0, 0, None

    def see(self, m):
        """Take message ``m`` (a :class:`LogMessage`) into account; returns its episode."""
        if m.type_name == 'diagnostic_msgs/msg/DiagnosticArray':
            value = diagnostics_values(self.log.decode(m)).get('episode')
            if isinstance(value, float):
                self.current = int(value)
        elif _leaf(m.topic) in (STRAIN, NODES, TENSION):
            if self._last is not None and m.log_time_ns < self._last:
                self.back += 1
            self._last = m.log_time_ns
        return self.current + self.back


def load_run(path):
    """Read a log written by the node or ``tensegrity run --mcap`` (a file or a bag folder) into
    a :class:`RunLog`: every frame in order, with its episode."""
    log = McapLog(path)
    frames = {STRAIN: {}, NODES: {}, TENSION: {}}
    cmd_t, cmd_topic, cmd_values = [], [], []
    counts = {}
    episodes = Episodes(log)
    for m in log.messages():
        counts[m.topic] = counts.get(m.topic, 0) + 1
        leaf = _leaf(m.topic)
        key = (episodes.see(m), m.log_time_ns)
        if COMMAND_PREFIX in m.topic and m.type_name == 'std_msgs/msg/Float64MultiArray':
            _, values = multi_array_values(log.decode(m))
            cmd_t.append(m.log_time_ns / 1e9)
            cmd_topic.append(leaf)
            cmd_values.append(values.ravel())
        elif leaf in (STRAIN, TENSION) and m.type_name == 'std_msgs/msg/Float64MultiArray':
            frames[leaf][key] = multi_array_values(log.decode(m))[1]
        elif leaf == NODES and m.type_name == 'sensor_msgs/msg/PointCloud2':
            frames[NODES][key] = cloud_xyz(log.decode(m))
    present = [k for k in frames if frames[k]]
    keys = sorted(set.intersection(*(set(frames[k]) for k in present))) if present else []

    def stack(name, tail):
        if not frames[name]:
            return np.zeros((len(keys),) + tail)
        return np.array([frames[name][k] for k in keys], dtype=np.float64)

    strain = stack(STRAIN, (0, 0))
    if strain.ndim == 2:            # a strain message without layout: one column
        strain = strain[:, None, :]
    return RunLog(time=np.array([k[1] for k in keys], dtype=np.int64) / 1e9, strain=strain,
                  positions=stack(NODES, (0, 3)), tensions=stack(TENSION, (0,)),
                  command_time=np.array(cmd_t, dtype=np.float64),
                  command_topic=np.array(cmd_topic, dtype=str), command_values=cmd_values,
                  topics=counts, truncated=log.truncated, network=log_network(log.metadata),
                  episode=np.array([k[0] for k in keys], dtype=np.int64))
