"""Logs converted to Rerun recordings (``tensegrity replay RUN --to-rerun OUT.rrd``): a log of this
project's node or ``tensegrity run --mcap`` through the live recorder
(:class:`~tensegrity_ros.io.rerun_sink.RerunRecorder`), so that the result holds what the live
recording holds; any other ROS 2 log topic by topic."""
from __future__ import annotations

import numpy as np

from tensegrity_ros.io.mcap_reader import (NODES, STRAIN, TENSION, LogError, McapLog, cloud_xyz,
                                           diagnostics_values, log_network,
                                           multi_array_values)

CLOCK_TOPIC = '/clock'


def _diag_values(msg):
    """The numeric values of a decoded ``DiagnosticArray`` (texts left out)."""
    return {k: v for k, v in diagnostics_values(msg).items() if isinstance(v, float)}


def _rgba(colors):
    return np.array([[c.r, c.g, c.b, c.a] for c in colors], dtype=np.float32)


BASE_FORCE, ENERGY, EVENTS = 'base_force', 'energy', 'events'


def to_rerun(path, out, application_id='tensegrity_ros', recording_id=None, status=None):
    """Convert a log (a file or a bag folder) to a Rerun ``.rrd`` file ``out``; returns the
    number of messages converted. ``status`` (a dict), if given, gets ``truncated``: whether the
    log was cut short (a killed recording: converted up to its last complete chunk).

    A log that carries its network (``tensegrity_network`` metadata, written by the node and by
    ``tensegrity run --mcap``) goes through
    :class:`~tensegrity_ros.io.rerun_sink.RerunRecorder`, so the result is what the live
    recording of the same run holds (docs/interfaces.md section 6): every frame with its base
    forces, energy, constraint and energy balance errors (``~/energy``) and episode, and the
    events of ``~/events`` as the command log. Logs without ``~/energy`` take the energy from
    ``/diagnostics`` (held from the latest one), logs without ``~/events`` the command log from
    the command topics. Other logs get a generic conversion (:func:`to_rerun_generic`)."""
    first = McapLog(path)
    diag, leaves = [], set()
    for m in first.messages():
        leaves.add(m.topic.rsplit('/', 1)[-1])
        if m.type_name == 'diagnostic_msgs/msg/DiagnosticArray':
            diag.append((m.log_time_ns, _diag_values(first.decode(m))))
    net = log_network(first.metadata)
    if net is None:
        return to_rerun_generic(path, out, application_id, recording_id, status)
    from types import SimpleNamespace

    from tensegrity_ros.io.mcap_reader import Episodes
    from tensegrity_ros.io.rerun_sink import RerunRecorder
    diag = [(t, v) for t, v in diag if 'energy_J' in v and 'constraint_error' in v]
    diag_t = np.array([t for t, _ in diag], dtype=np.int64)
    has_events = EVENTS in leaves
    log = McapLog(path)
    episodes = Episodes(log)
    n, pending, stamp, episode = 0, {}, None, 0
    with RerunRecorder(net, str(out), tension_scale=net.tension_scale or None,
                       application_id=application_id,
                       recording_id=recording_id or str(path)) as rec:
        def emit():
            if not {STRAIN, NODES, TENSION} <= pending.keys():
                return
            if ENERGY in pending:
                energy, constraint, balance = pending[ENERGY][:3]
            else:
                i = max(int(np.searchsorted(diag_t, stamp, side='right')) - 1, 0)
                values = diag[i][1] if diag else {}
                energy = values.get('energy_J', 0.0)
                constraint = values.get('constraint_error', 0.0)
                balance = values.get('energy_balance_error')
            rec.frame(SimpleNamespace(
                t=stamp / 1e9, positions=pending[NODES], strain=pending[STRAIN],
                tension=pending[TENSION], base_force=pending.get(BASE_FORCE, np.zeros(0)),
                energy=energy, constraint_error=constraint, energy_balance_error=balance,
                episode=episode))
        for m in log.messages():
            leaf = m.topic.rsplit('/', 1)[-1]
            now = episodes.see(m)
            if m.log_time_ns != stamp:
                emit()
                pending, stamp = {}, m.log_time_ns
            if leaf == EVENTS and m.type_name == 'std_msgs/msg/String':
                rec.command(m.log_time_ns / 1e9, log.decode(m).data)
            elif '/cmd/' in m.topic:
                if has_events:
                    continue                    # the events say what became of each command
                values = multi_array_values(log.decode(m))[1].ravel()
                rec.command(m.log_time_ns / 1e9, f'{leaf}: {np.array2string(values)}')
            elif leaf in (STRAIN, TENSION, BASE_FORCE, ENERGY) and \
                    m.type_name.endswith('Float64MultiArray'):
                pending[leaf] = multi_array_values(log.decode(m))[1]
                episode = now
            elif leaf == NODES and m.type_name == 'sensor_msgs/msg/PointCloud2':
                pending[leaf] = cloud_xyz(log.decode(m))
                episode = now
            else:
                continue
            n += 1
        emit()
    if status is not None:
        status['truncated'] = log.truncated
    return n


def to_rerun_generic(path, out, application_id='tensegrity_ros', recording_id=None,
                     status=None):
    """Convert any ROS 2 log to Rerun through an owned recording stream, topic by topic
    (PointCloud2 points, MarkerArray line lists, Float64MultiArray and diagnostics scalars)."""
    import rerun as rr
    log = McapLog(path)
    rec = rr.RecordingStream(application_id, recording_id=recording_id or str(path))
    rec.set_log_time_enabled(False)     # one clock: simulation time only
    rec.save(str(out))
    n = 0
    try:
        for m in log.messages():
            leaf = m.topic.rsplit('/', 1)[-1]
            if m.topic == CLOCK_TOPIC:
                continue
            rec.set_time('sim_time', duration=m.log_time_ns * 1e-9)
            msg = log.decode(m)
            if m.type_name == 'sensor_msgs/msg/PointCloud2':
                rec.log(leaf, rr.Points3D(cloud_xyz(msg), radii=rr.Radius.ui_points(3.0)))
            elif m.type_name == 'visualization_msgs/msg/MarkerArray':
                for mk in msg.markers:
                    pts = np.array([[p.x, p.y, p.z] for p in mk.points]).reshape(-1, 2, 3)
                    colors = _rgba(mk.colors)[0::2] if len(mk.colors) else _rgba([mk.color])
                    rec.log(mk.ns or f'marker_{mk.id}', rr.LineStrips3D(pts, colors=colors))
            elif m.type_name == 'std_msgs/msg/Float64MultiArray':
                shape, values = multi_array_values(msg)
                rec.log(m.topic.split('/', 3)[-1] if '/cmd/' in m.topic else leaf,
                        rr.Scalars(values.ravel()))
            elif m.type_name == 'diagnostic_msgs/msg/DiagnosticArray':
                for key, value in _diag_values(msg).items():
                    if np.isfinite(value):
                        rec.log(f'diagnostics/{key}', rr.Scalars(value))
            else:
                continue
            n += 1
    finally:
        rec.flush()
        rec.disconnect()
    if status is not None:
        status['truncated'] = log.truncated
    if n == 0:
        raise LogError(f'{path}: nothing to convert')
    return n
