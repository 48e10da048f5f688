"""The ROS 2 side of a recording, as rosbag2 writes it (docs/interfaces.md section 5): a message
type's full concatenated definition (:func:`full_definition`: the main ``.msg`` text, then every
dependency after a line of 80 ``=`` and ``MSG: pkg/Type``) and its RIHS01 hash
(:func:`type_hash`), the ``offered_qos_profiles`` YAML of a channel (:func:`qos_yaml`, and the
integer form of :func:`qos_yaml_v8`), and a bag folder's ``metadata.yaml`` (:func:`bag_metadata`,
version :data:`BAG_VERSION`). :mod:`tensegrity_ros.io.mcap_writer` writes them into the file."""
from __future__ import annotations

import json
import os
import re
from functools import lru_cache
from pathlib import Path

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
