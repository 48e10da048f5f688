"""The MCAP log of a headless run (``tensegrity run --mcap``).

:class:`FrameLog` turns solver frames into the messages the node publishes, built by the same
:mod:`tensegrity_ros.msgs.messages` functions, under the same topic names, and writes them to a
:class:`~tensegrity_ros.io.mcap_writer.McapRecorder`; so a log is the same whichever way it was
made. Commands applied by the command line (the impact) are logged as the node would log them on
receipt.
"""
from __future__ import annotations

import json

import numpy as np

from tensegrity_ros.msgs import cdr
from tensegrity_ros.msgs import messages as M
from tensegrity_ros.msgs import style

MARKER_RATE_HZ = 20.0       # the node's default marker_rate_hz (docs/interfaces.md section 4)


NETWORK_METADATA = 'tensegrity_network'


def network_metadata(network, scene_name=''):
    """``{name: {key: text}}`` for :class:`~tensegrity_ros.io.mcap_writer.McapRecorder`'s
    ``metadata``:
    the topology of ``network`` as JSON texts (member index arrays, cable kinds, levels, reference
    positions x0 in m, the markers' tension colour scale in N), so that a log can be drawn and
    analysed without the scene file."""
    def text(a):
        return json.dumps(np.asarray(a).tolist())
    net = network
    return {NETWORK_METADATA: {
        'scene': str(scene_name), 'n_nodes': str(net.n_nodes),
        'bar_a': text(net.bar_a), 'bar_b': text(net.bar_b),
        'edge_a': text(net.edge_a), 'edge_b': text(net.edge_b),
        'cable_a': text(net.cable_a), 'cable_b': text(net.cable_b),
        'cable_kind': json.dumps([str(k) for k in net.cable_kind]),
        'levels_shape': text(np.shape(net.levels)), 'levels': text(np.ravel(net.levels)),
        'x0': text(np.ravel(net.x0)),
        'tension_scale': repr(style.reference_tension_scale(net))}}


def structure_json(network, scene_name, rest):
    """The node's ``~/structure`` text: :func:`network_metadata`'s topology (JSON values parsed)
    with the sizes and the cable rest lengths ``rest`` (m, in the network's cable order)."""
    meta = network_metadata(network, scene_name)[NETWORK_METADATA]
    data = {k: (v if k == 'scene' else json.loads(v)) for k, v in meta.items()}
    data.update(n_bars=int(len(network.bar_a)), n_cables=int(network.n_cables),
                n_columns=int(network.n_columns), n_prisms=int(network.n_prisms),
                rest_length=[float(r) for r in np.asarray(rest)])
    return json.dumps(data)


def marker_every(output_dt, marker_rate_hz=MARKER_RATE_HZ):
    """Frames between marker (and diagnostics) messages for frames every ``output_dt`` s."""
    return max(1, int(round(1.0 / (marker_rate_hz * output_dt))))


def topic_qos():
    """The QoS the node offers on every topic (reliable, volatile, keep last 10)."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


class FrameLog:
    """Writes frames of ``network`` to ``recorder`` under ``namespace``.

    ``marker_every``: markers and diagnostics every that many frames (the node publishes them at
    ``marker_rate_hz`` <= ``publish_rate_hz``); ``clock``: also ``/clock`` per frame (the node's
    default ``use_sim_clock``)."""

    def __init__(self, recorder, network, namespace=M.NAMESPACE, node=M.NODE_NAME, marker_every=1,
                 clock=True):
        if int(marker_every) < 1:
            raise ValueError(f'marker_every must be >= 1, not {marker_every!r}')
        self.rec, self.net = recorder, network
        self.namespace, self.node = namespace, node
        self.marker_every, self.clock = int(marker_every), bool(clock)
        self.n_frames = 0
        self.accepted = 0
        self.last_command = ('none', 'none', '')
        qos = topic_qos()
        self._optional = set()          # optional topics declared on their first message
        for key in M.PUBLISHED + M.COMMANDS:
            if key == '/clock' and not clock:
                continue
            recorder.declare(self.topic(key), M.MSG_CLASSES[key], qos)

    def topic(self, key):
        return M.resolve_topic(key, self.namespace, self.node)

    def frame(self, frame):
        """Write one :class:`solver.simulate.simulation.Frame` (raises ValueError if it is not
        finite)."""
        stamp = M.sim_stamp(frame.t)
        ns = M.stamp_to_ns(stamp)
        extra = self.n_frames % self.marker_every == 0
        msgs = cdr.frame_messages_cdr(frame, self.net, stamp=stamp, markers=extra,
                                      clock=self.clock)
        for key, data in msgs.items():          # the node's bytes (cdr.py), checked finite
            if key in M.OPTIONAL and key not in self._optional:
                self._optional.add(key)
                self.rec.declare(self.topic(key), M.MSG_CLASSES[key], topic_qos())
            self.rec.write_serialized(self.topic(key), data, ns)
        self.n_frames += 1
        if extra:
            self._diagnostics(frame, 'running')

    def diagnostics_values(self, frame):
        """The node's ``/diagnostics`` keys that a headless run knows (no wall-clock pacing), and
        ``energy_balance_error`` when the frame carries it (every
        :class:`~solver.simulate.simulation.Frame` does)."""
        topic, verdict, detail = self.last_command
        balance = frame.energy_balance_error
        return {'sim_time_s': float(frame.t), 'episode': 0, 'episode_time_s': float(frame.t),
                'steps': int(frame.step), 'running': 'true',
                'energy_J': float(frame.energy),
                'constraint_error': float(frame.constraint_error),
                **({} if balance is None else {'energy_balance_error': float(balance)}),
                'frames_published': self.n_frames, 'commands_accepted': self.accepted,
                'commands_rejected': 0, 'last_command_topic': topic, 'last_command': verdict,
                'last_command_detail': detail}

    def _diagnostics(self, frame, message):
        stamp = M.sim_stamp(frame.t)
        self.rec.write(self.topic('/diagnostics'),
                       M.diagnostics_message(stamp, self.diagnostics_values(frame), 0, message),
                       M.stamp_to_ns(stamp))

    def event(self, t, text):
        """Log an event (what the node publishes on ``~/events``) at simulation time ``t`` s."""
        self.rec.write(self.topic('~/events'), M.String(data=str(text)),
                       M.stamp_to_ns(M.sim_stamp(t)))

    def command(self, key, values, label, frame, detail=''):
        """Log a command (``'~/cmd/impact'`` or ``'~/cmd/prestrain'``) applied at ``frame`` (a
        :class:`solver.simulate.simulation.Frame`, for its time and the diagnostics), as the node
        logs one it receives and accepts: the command, then a ``/diagnostics`` saying so."""
        if key not in M.COMMANDS:
            raise ValueError(f'unknown command topic {key!r}')
        self.rec.write(self.topic(key), M.command_array(values, label),
                       M.stamp_to_ns(M.sim_stamp(frame.t)))
        self.accepted += 1
        self.last_command = (key, 'accepted', detail)
        self._diagnostics(frame, f'accepted {key}')
