"""What the node publishes: each frame (as CDR bytes written from the arrays, or message objects
for a sink that needs them), the structure once per activation, and ``/diagnostics``.

rclpy's conversion of message objects is the largest cost of publishing (markers 50x), so a
frame goes out as the bytes of :mod:`tensegrity_ros.msgs.cdr` unless a recorder asks for objects.
Markers go out at ``marker_rate_hz`` and only when someone listens or records.
"""
from __future__ import annotations

import dataclasses
import math
import time

from std_msgs.msg import String

from tensegrity_ros.msgs import cdr, messages
from tensegrity_ros.node.params import DIVERGENCE_HOLD_S

STRUCTURE_TOPIC = '~/structure'


class Publishing:
    """The publishing part of node ``node``; ``achieved_rate_hz`` is measured over windows of at
    least 1 s, ``tick_max_s`` over a diagnostics period (the real-time factor: the node's
    :class:`~tensegrity_ros.node.realtime.RealTime`)."""

    def __init__(self, node):
        self.node = node
        self.last_marker = self.last_diag = -math.inf
        self.achieved_rate_hz = self.tick_max_s = 0.0
        self.restart_window(time.monotonic())

    def restart_window(self, now):
        """Measure the achieved rates from ``now`` on (activation, reset)."""
        self._window = (now, self.node.clock_time(), self.node.counts['frames'])

    def time_jump(self, t_before, t_after):
        """The clock jumped (one step at a reset after a divergence): the window keeps measuring
        the publish rate and counts the simulated time done before the jump."""
        wall, t_sim, frames = self._window
        self._window = (wall, t_sim + t_after - t_before, frames)
        self.node.realtime.shift(t_after - t_before)

    def markers_due(self, now):
        """Markers are due at ``marker_rate_hz``, and only built when someone listens (a
        subscriber or a sink of messages): they cost more than all other topics together."""
        node = self.node
        if not node.sinks.has('message') and \
                node.pubs['~/markers'].get_subscription_count() == 0:
            return False
        return now - self.last_marker >= 1.0 / node.params['marker_rate_hz']

    def structure(self):
        """``~/structure``: the topology and the current cable rest lengths (JSON)."""
        from tensegrity_ros.io.mcap_frames import structure_json
        node, sim = self.node, self.node.sim
        msg = String(data=structure_json(sim.network, sim.scene.name, sim.model.cable_rest_length))
        node.pubs[STRUCTURE_TOPIC].publish(msg)
        node.sinks.message(node.topics[STRUCTURE_TOPIC], msg,
                           messages.stamp_to_ns(messages.sim_stamp(node.clock_time())))

    def frame(self, now):
        """Publish the current frame at the clock time (:meth:`TensegritySim.clock_time`; the
        frame the sinks get has that ``t`` and its ``episode``); a frame that is not finite is
        never published: it is a divergence (the node resets or pauses, ``on_divergence``, and
        says why; returns False)."""
        node = self.node
        t0 = time.perf_counter()
        markers = self.markers_due(now)
        build = messages.frame_messages if node.sinks.wants_objects else cdr.frame_messages_cdr
        try:
            frame = clocked(node.sim.frame(), node)   # (its base force fails on a broken state)
            stamp = messages.sim_stamp(frame.t)
            msgs = build(frame, node.sim.network, stamp=stamp, markers=markers,
                         clock=node.params['use_sim_clock'], t_max=node.t_max)
        except ValueError as exc:
            node.diverged(f'the state gives no finite frame: {exc}', node.sim.t)
            return False
        if markers:
            self.last_marker = now
        stamp_ns = messages.stamp_to_ns(stamp)
        for key, msg in msgs.items():
            node.pubs[key].publish(msg)
            node.sinks.message(node.topics[key], msg, stamp_ns)
        node.sinks.frame(frame)
        node.counts['frames'] += 1
        if node.running and node.timer is not None:     # (from the first tick on)
            node.realtime.sample(now, frame.t)
        wall, t_sim, frames = self._window
        if now - wall >= 1.0:
            self.achieved_rate_hz = (node.counts['frames'] - frames) / (now - wall)
            self._window = (now, frame.t, node.counts['frames'])
        node.pacer.published(time.perf_counter() - t0, markers)
        return True

    def diagnostics_values(self):
        """The key/value pairs of ``/diagnostics`` (dict name -> float, int or str)."""
        node, sim, intake = self.node, self.node.sim, self.node.intake
        topic, verdict, detail = intake.last_command
        div = node.last_divergence
        counts = node.counts
        rtf = node.realtime.factor()
        return {
            'sim_time_s': float(node.clock_time()), 'episode': node.episode,
            'episode_time_s': float(sim.t), 'steps': int(sim.step),
            'running': str(node.running).lower(),
            'real_time_factor_target': float(node.params['real_time_factor']),
            'real_time_factor_achieved': float(-1.0 if rtf is None else rtf),
            'real_time_window_s': float(node.realtime.span_s),
            'publish_rate_hz_achieved': float(self.achieved_rate_hz),
            'tick_max_ms': 1e3 * float(self.tick_max_s),
            'energy_J': float(sim.energy()),
            **energy_balance(sim),
            'constraint_error': float(sim.constraint_error()),
            'frames_published': counts['frames'],
            'commands_accepted': counts['accepted'],
            'commands_rejected': counts['rejected'],
            'commands_superseded': counts['superseded'],
            'last_command_topic': topic, 'last_command': verdict, 'last_command_detail': detail,
            'last_command_sim_time_s': (float(intake.last_command_t)
                                        if math.isfinite(intake.last_command_t) else -1.0),
            'on_divergence': node.params['on_divergence'],
            'divergences': node.divergences,
            'last_divergence': div['text'] if div else 'none',
            'last_divergence_sim_time_s': div['sim_time_s'] if div else -1.0,
            **node.focus.values(),
        }

    def status(self, now):
        """``(level, message)`` of ``/diagnostics``: ERROR with the reason while paused by a
        problem, and once right at a divergence the node reset after; WARN naming the last
        divergence for ``DIVERGENCE_HOLD_S`` after it, else WARN while behind real time (with
        the reason; one throttled log line says so), else WARN after rejected commands; else
        OK."""
        node, intake = self.node, self.node.intake
        div = node.last_divergence
        if div is not None and not div['reported']:
            div['reported'] = True
            if not node.problem:
                return 2, f'diverged: {div["text"]}; reset to the rest state'
        if node.problem:
            return 2, node.problem
        if div is not None and now - div['wall'] < DIVERGENCE_HOLD_S:
            return 1, (f'last divergence {now - div["wall"]:.0f} s ago ({div["action"]}): '
                       f'{div["text"]}')
        pacer = node.pacer
        behind, log = node.realtime.status(now, node.params['real_time_factor'], node.running,
                                           node.sim.dt, pacer.step_cost, pacer.publish_cost,
                                           node.params['publish_rate_hz'], pacer.call_cost)
        if log:
            node.log('real time', 'warning', log)
        if behind:
            return 1, behind
        if intake.rejected_since:
            return 1, f'rejected {intake.last_command[2]}'
        return 0, 'running' if node.running else 'paused'

    def diagnostics(self, now):
        """``/diagnostics`` with the :meth:`status` and :meth:`diagnostics_values`."""
        node, intake = self.node, self.node.intake
        self.last_diag = now
        level, message = self.status(now)
        intake.rejected_since = 0
        stamp = messages.sim_stamp(node.clock_time())
        msg = messages.diagnostics_message(stamp, self.diagnostics_values(), level, message)
        node.pubs['/diagnostics'].publish(msg)
        node.sinks.message(node.topics['/diagnostics'], msg, messages.stamp_to_ns(stamp))
        self.tick_max_s = 0.0          # tick_max_ms covers one diagnostics period


def clocked(frame, node):
    """``frame`` (a :class:`solver.simulate.simulation.Frame`) at the node's clock time, with
    its ``episode``."""
    out = dataclasses.replace(frame, t=node.clock_time(frame.t))
    out.episode = node.episode
    return out


def energy_balance(sim):
    """``energy_work_J`` (work of the commands since the reset) and ``energy_balance_error``
    (signed, relative: the solver's ``Simulation.energy_error``; an array of columns: the group
    furthest off) of ``sim``."""
    return {'energy_work_J': float(sim.energy_work()),
            'energy_balance_error': float(sim.energy_error())}
