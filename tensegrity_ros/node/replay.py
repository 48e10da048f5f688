"""Replay an MCAP log over ROS 2 (``tensegrity replay``) and convert it to a Rerun recording.

:class:`Replayer` republishes every recorded topic with its recorded QoS (from the channel's
``offered_qos_profiles``), the recorded CDR bytes unchanged, at the recorded log times scaled by
``rate``, and publishes ``/clock`` (``rosgraph_msgs/msg/Clock``) at each new log time. A recorded
``/clock`` channel is not republished (the replay clock replaces it). Killed logs replay up to
their last complete chunk.

:func:`to_rerun` writes a ``.rrd`` through an owned :class:`rerun.RecordingStream` (never the
global one) on timeline ``sim_time``: with the project's Rerun layout when the log carries its
network, otherwise topic by topic (:func:`to_rerun_generic`).
"""
from __future__ import annotations

import importlib
import time

import numpy as np

from tensegrity_ros.io.mcap_reader import (McapLog)

CLOCK_TOPIC = '/clock'


class ReplayError(ValueError):
    """A log that cannot be replayed (bad rate, unknown message type)."""


def message_class(type_name):
    """The rclpy class of ``'pkg/msg/Type'``."""
    parts = type_name.split('/')
    if len(parts) == 2:
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3:
        raise ReplayError(f'message type {type_name!r} not understood')
    try:
        return getattr(importlib.import_module(f'{parts[0]}.{parts[1]}'), parts[2])
    except (ImportError, AttributeError):
        raise ReplayError(f'message type {type_name} is not installed') from None


def qos_from_yaml(text):
    """An rclpy ``QoSProfile`` from ``offered_qos_profiles`` YAML (first profile; reliable,
    volatile, keep last 10 when empty or unreadable). Only history, depth, reliability and
    durability are taken: they decide compatibility and delivery."""
    import yaml
    from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)
    try:
        profiles = yaml.safe_load(text or '') or []
        p = profiles[0] if isinstance(profiles, list) and profiles else {}
    except yaml.YAMLError:
        return qos

    def policy(enum, value):
        if isinstance(value, int):
            return enum(value)
        try:
            return enum[str(value).upper()]
        except KeyError:
            return None

    for key, enum in (('reliability', ReliabilityPolicy), ('durability', DurabilityPolicy),
                      ('history', HistoryPolicy)):
        if key in p:
            v = policy(enum, p[key])
            if v is not None and v.name not in ('SYSTEM_DEFAULT', 'UNKNOWN'):
                setattr(qos, key, v)
    if int(p.get('depth', 0) or 0) > 0:
        qos.depth = int(p['depth'])
    return qos


def log_channels(path):
    """topic -> (type name, offered_qos_profiles YAML) of every channel in the log, in order."""
    log = McapLog(path)
    out = {}
    for m in log.messages():
        if m.topic not in out:
            out[m.topic] = (m.type_name, m.channel.metadata.get('offered_qos_profiles', ''))
    return out


def check_options(rate, delay_s=0.0, wait_s=0.0):
    """Raise :class:`ReplayError` naming the first bad option."""
    if not (np.isfinite(rate) and rate > 0):
        raise ReplayError(f'--rate must be a positive number, not {rate!r}')
    if not (np.isfinite(delay_s) and delay_s >= 0):
        raise ReplayError(f'--delay must be >= 0 s, not {delay_s!r}')
    if not (np.isfinite(wait_s) and wait_s >= 0):
        raise ReplayError(f'--wait must be >= 0 s, not {wait_s!r}')


def _sleep_until(due, should_stop):
    """Sleep until ``time.monotonic()`` reaches ``due``, in slices, unless told to stop."""
    while not should_stop():
        wait = due - time.monotonic()
        if wait <= 0:
            return
        time.sleep(min(wait, 0.1))


class Replayer:
    """Publishes a log through an rclpy ``node`` (created by the caller, who owns the context).

    ``rate`` > 0 scales the recorded timing (2 = twice as fast). ``clock`` publishes ``/clock``.
    ``wait_s`` > 0 first waits (up to that long) until some subscriber matches one of the
    publishers, then ``delay_s`` more, so that subscribers can match them.

    Each publisher keeps the recorded reliability, durability and history kind; its history is
    at least ``MIN_DEPTH`` deep (depth plays no part in matching), so that a reliable subscriber
    that falls behind for a moment is not overtaken. :meth:`flush` waits for reliable
    subscribers to acknowledge everything published."""

    MIN_DEPTH = 100

    def __init__(self, node, path, rate=1.0, clock=True, delay_s=0.0, wait_s=0.0):
        check_options(rate, delay_s, wait_s)
        self.wait_s = float(wait_s)
        from rosgraph_msgs.msg import Clock
        self.node, self.path, self.rate, self.delay_s = node, path, float(rate), float(delay_s)
        self.channels = log_channels(path)
        if not self.channels:
            raise ReplayError(f'{path}: the log holds no messages')
        self.publishers = {}
        for topic, (type_name, qos_text) in self.channels.items():
            if topic == CLOCK_TOPIC:
                continue
            qos = qos_from_yaml(qos_text)
            qos.depth = max(qos.depth, self.MIN_DEPTH)
            self.publishers[topic] = node.create_publisher(message_class(type_name), topic, qos)
        self._clock_cls = Clock
        self.clock_pub = node.create_publisher(Clock, CLOCK_TOPIC, 10) if clock else None
        self.published = 0
        self.truncated = False

    def _publish_clock(self, ns):
        from builtin_interfaces.msg import Time
        if self.clock_pub is not None:
            self.clock_pub.publish(self._clock_cls(
                clock=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)))

    def play_once(self, should_stop=lambda: False):
        """Publish the whole log once with its timing; returns the number of messages published.
        Stops early (returning what was published) when ``should_stop()`` becomes true."""
        if self.wait_s:
            end = time.monotonic() + self.wait_s
            while time.monotonic() < end and not should_stop() and not any(
                    p.get_subscription_count() for p in self.publishers.values()):
                time.sleep(0.02)
            self.wait_s = 0.0
        if self.delay_s:
            _sleep_until(time.monotonic() + self.delay_s, should_stop)
            self.delay_s = 0.0
        log = McapLog(self.path)
        wall0 = t0 = None
        last_clock = None
        n = 0
        for m in log.messages():
            if should_stop():
                break
            if m.topic == CLOCK_TOPIC:
                continue
            if t0 is None:
                wall0, t0 = time.monotonic(), m.log_time_ns
            _sleep_until(wall0 + (m.log_time_ns - t0) * 1e-9 / self.rate, should_stop)
            if should_stop():
                break
            if m.log_time_ns != last_clock:
                self._publish_clock(m.log_time_ns)
                last_clock = m.log_time_ns
            self.publishers[m.topic].publish(m.data)
            n += 1
        self.truncated = log.truncated
        self.published += n
        return n

    def flush(self, timeout_s=2.0):
        """Wait (up to ``timeout_s`` in all) until reliable subscribers have acknowledged every
        message published, so that leaving right after the last one loses nothing in flight.
        Returns whether everything was acknowledged."""
        from rclpy.duration import Duration
        end = time.monotonic() + timeout_s
        pubs = list(self.publishers.values())
        if self.clock_pub is not None:
            pubs.append(self.clock_pub)
        ok = True
        for pub in pubs:
            left = max(0.0, end - time.monotonic())
            ok = pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))) and ok
        return ok

    def play(self, loop=False, should_stop=lambda: False):
        """Play once, or forever with ``loop`` (until ``should_stop()``)."""
        total = self.play_once(should_stop)
        while loop and not should_stop():
            total += self.play_once(should_stop)
        return total


def replay_main(path, rate=1.0, loop=False, delay_s=0.5, clock=True, args=None, wait_s=0.0):
    """``tensegrity replay``: init rclpy, play, shut down. Returns (messages published, whether
    the file was truncated)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    McapLog(path)                         # clear errors before starting ROS
    check_options(rate, delay_s, wait_s)
    rclpy.init(args=args)
    node = player = None
    try:
        node = rclpy.create_node('tensegrity_replay')
        player = Replayer(node, path, rate=rate, clock=clock, delay_s=delay_s, wait_s=wait_s)
        player.play(loop=loop, should_stop=lambda: not rclpy.ok())
        if rclpy.ok():
            player.flush()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return (player.published, player.truncated) if player is not None else (0, False)
