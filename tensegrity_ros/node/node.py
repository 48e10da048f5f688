"""The ROS 2 node ``tensegrity_sim`` (docs/interfaces.md section 4): one node class and
:func:`main`.

    tensegrity_node [--ros-args -p real_time_factor:=0.0 --params-file config/node.yaml]

One timer drives everything: each tick applies the commands that arrived since the last one,
advances the simulation towards the paced target time, never working longer than 90 % of a
publish period less the time the command callbacks took (with ``real_time_factor`` 0: as far as
fits until the next tick is due), then publishes one frame (built by
:mod:`tensegrity_ros.msgs.cdr`,
or :mod:`tensegrity_ros.msgs.messages` for a recorder that needs message objects).
Commands are taken by the tick itself (the executor never runs their subscriptions), so they never
race a step: each tick takes every command waiting, validates (and counts, and hands to the
recorders) each one, and applies the last valid one per topic (the others are counted as
superseded), so a flood of commands cannot starve the simulation. ``/diagnostics`` go out at
``diagnostics_rate_hz`` with counters (and at once when the simulation pauses itself); repeated log
lines are throttled (:meth:`TensegritySim._log`). Stamps are simulation time.

Recorders hook in through three lists (see :meth:`TensegritySim.add_sink`): ``_sinks`` get
``(topic, msg, stamp_ns)`` for every published message and every received command (the frame's
messages as CDR ``bytes`` when every sink takes bytes, as the MCAP recorder does), ``_frame_sinks``
get each published :class:`solver.simulate.simulation.Frame`, ``_event_sinks`` get ``(t, text)``
per
command.
"""
from __future__ import annotations

import gc
import math
import signal
import sys
import time

import numpy as np
import rclpy
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
from rclpy.event_handler import PublisherEventCallbacks
from rclpy._rclpy_pybind11 import RCLError
from rclpy.callback_groups import CallbackGroup
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSPolicyKind, QoSProfile,
                       ReliabilityPolicy)
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.signals import SignalHandlerOptions
from geometry_msgs.msg import PointStamped
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool, Trigger

from solver.simulate.simulation import SimulationDiverged

from tensegrity_ros.msgs import cdr, messages, style

from tensegrity_ros.node import commands
from tensegrity_ros.node.params import (DEFAULTS, DESCRIPTIONS, RANGES, READ_ONLY, RESTART,  # noqa: F401
                          ParameterError, check_parameters, find_config, load_simulation,
                          measure_step_cost, unknown_parameters)

QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
# the structure (~/structure, std_msgs/String, JSON): sent once per activation, kept for late
# subscribers and recorders
STRUCTURE_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL,
                           history=HistoryPolicy.KEEP_LAST)
STRUCTURE_TOPIC = '~/structure'
# the field in the medium of an array (sensor_msgs/Image, 32FC1): at field_rate_hz after an impact
FIELD_TOPIC = '~/field'
# every publisher and command subscription takes its QoS from parameters
# qos_overrides.<topic>.<publisher|subscription>.<policy> (parameters file or -p), defaults above
QOS_OVERRIDES = QoSOverridingOptions(policy_kinds=(
    QoSPolicyKind.HISTORY, QoSPolicyKind.DEPTH, QoSPolicyKind.RELIABILITY,
    QoSPolicyKind.DURABILITY))


def _qos(base=QOS):
    """A fresh copy of ``base`` (rclpy writes the overrides into the profile it is given)."""
    return QoSProfile(history=base.history, depth=base.depth, reliability=base.reliability,
                      durability=base.durability)
LOG_THROTTLE_S = 1.0             # a repeated log line (or rejected-command event): at most
                                 # once per this many seconds
MAX_TAKE = 100                   # commands per topic taken at the start of a tick, at most
WORK_FRACTION = 0.9              # share of a publish period the stepping (and publishing) may use
FAST_WORK_FRACTION = 1.0         # at real_time_factor 0: share of the time left until the next
                                 # tick is due (no pace to keep, no margin)
MIN_WORK_FRACTION = 0.2          # a tick steps at least this share of a period


class TakenByTick(CallbackGroup):
    """The callback group of the command subscriptions: the executor never waits on them or runs
    their callbacks; each tick takes what is waiting (:meth:`TensegritySim._take_commands`). A
    flood of commands then costs no executor cycle per message (the wait set rebuilt in Python,
    a task per message) and never delays a tick."""

    def can_execute(self, entity):
        return False

    def beginning_execution(self, entity):
        return False

    def ending_execution(self, entity):
        pass


class TensegritySim(LifecycleNode):
    """The node ``tensegrity_sim``. ``sim``: an existing
    :class:`~solver.simulate.simulation.Simulation`
    to drive (tests, benchmarks) instead of the one the parameters describe; ``kwargs`` go to
    :class:`rclpy.lifecycle.LifecycleNode` (``context``, ``parameter_overrides``, ``namespace``).
    A managed node: with ``autostart`` (the default) it configures and activates itself in the
    constructor; without, it waits for ``~/change_state``."""

    def __init__(self, sim=None, **kwargs):
        kwargs.setdefault('namespace', messages.NAMESPACE)
        super().__init__(messages.NODE_NAME, **kwargs)
        unknown = unknown_parameters(self._parameter_overrides)
        if unknown is not None:
            raise unknown
        # the start-up values through the same check as later changes (before rclpy's range
        # check at declaration, whose message would not be ours)
        check_parameters({n: self._parameter_overrides[n].value
                          if n in self._parameter_overrides else d for n, d in DEFAULTS.items()})
        for name, default in DEFAULTS.items():
            desc = ParameterDescriptor(description=DESCRIPTIONS[name],
                                       read_only=name in READ_ONLY,
                                       dynamic_typing=True)    # types: check_parameters
            if name in RANGES:
                lo, hi = RANGES[name]
                desc.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi)]
            self.declare_parameter(name, default, desc)
        self.params = check_parameters({n: self.get_parameter(n).value for n in DEFAULTS})
        self.add_on_set_parameters_callback(self._check_new_parameters)
        self.add_post_set_parameters_callback(self._apply_new_parameters)
        self.period = 1.0 / self.params['publish_rate_hz']
        self._given_sim = sim
        self.sim = self.timer = None
        self.active = False
        self._pubs, self._cmd_subs, self._srvs = {}, [], []
        self._sinks, self._frame_sinks, self._event_sinks, self._closers = [], [], [], []
        self._bytes_sinks, self._field_sinks = [], []
        self._logged = {}              # throttled log line -> wall time it last went out
        if self.params['autostart']:
            self._setup()          # a bad scene raises here (the console script exits 2)
            for name, trigger in (('configure', self.trigger_configure),
                                  ('activate', self.trigger_activate)):
                if trigger() != TransitionCallbackReturn.SUCCESS:
                    raise RuntimeError(f'{messages.NODE_NAME}: {name} failed (see the log)')

    # -- lifecycle ------------------------------------------------------------------------------
    # unconfigured: parameters only; configure: the simulation (scene loaded, kernels compiled),
    # recorders, publishers, subscriptions and services; activate: the timer (stepping and
    # publishing); deactivate: the timer stops, the state stays; cleanup / shutdown: back to
    # parameters only.
    def on_configure(self, state):
        if self.sim is None:
            from solver.build.network import NetworkError
            from solver.build.scene import SceneError
            try:
                self._setup()
            except (ParameterError, SceneError, NetworkError, ValueError) as exc:
                self.get_logger().error(f'configure: {exc}')
                return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state):
        self.active = True
        self._anchor()
        self._rtf_window = (time.monotonic(), self.sim.t, self.counts['frames'])
        self._publish_structure()
        self._publish_frame(time.monotonic())
        self.timer = self.create_timer(self.period, self._tick)
        return super().on_activate(state)

    def on_deactivate(self, state):
        self.active = False
        self._drop_timer()
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state):
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state):
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    def _drop_timer(self):
        if self.timer is not None:
            self.timer.cancel()
            self.destroy_timer(self.timer)
            self.timer = None

    def _teardown(self):
        self.active = False
        self._drop_timer()
        self.close()
        for pub in self._pubs.values():
            self.destroy_publisher(pub)
        for sub, _ in self._cmd_subs:
            self.destroy_subscription(sub)
        for srv in self._srvs:
            self.destroy_service(srv)
        self._pubs, self._cmd_subs, self._srvs = {}, [], []
        self._sinks, self._frame_sinks, self._event_sinks, self._closers = [], [], [], []
        self._bytes_sinks, self._field_sinks = [], []
        self._record = None
        self.sim = None

    def _publisher(self, key, msg_class=None, qos=QOS):
        """The publisher of ``key`` with QoS ``qos`` as overridden by the parameters. No
        QoS-event handlers: each is a waitable the executor polls on every tick (they were most
        of the executor's cost per tick)."""
        return self.create_publisher(
            msg_class or messages.MSG_CLASSES[key], key, _qos(qos),
            event_callbacks=PublisherEventCallbacks(use_default_callbacks=False),
            qos_overriding_options=QOS_OVERRIDES)

    def _publish_structure(self):
        """``~/structure``: the topology and the current cable rest lengths (JSON)."""
        from tensegrity_ros.io.mcap_frames import structure_json
        msg = String(data=structure_json(self.sim.network, self.sim.scene.name,
                                         self.sim.model.cable_rest_length))
        self._pubs[STRUCTURE_TOPIC].publish(msg)
        self._emit(self._sinks, self._topics[STRUCTURE_TOPIC], msg,
                   messages.stamp_to_ns(messages.sim_stamp(self.sim.t)))

    def _setup(self):
        """What configure builds: the simulation (the caller's, in its state, or the one the
        parameters describe), recorders, publishers, subscriptions, services, counters."""
        sim = self._given_sim
        if sim is None:
            sim = load_simulation(self.params)
            self._step_cost = measure_step_cost(sim)
        else:                      # a caller's simulation, in its state: start cautiously
            self._step_cost = 0.1 * self.period
        self.sim = sim
        net = self.sim.network
        self._cross_prism = (self.sim.prestrain_map.cross_prism
                             if self.sim.prestrain is not None else None)
        self._t_max = style.reference_tension_scale(net)
        self._pubs = {key: self._publisher(key)
                      for key in messages.PUBLISHED + (
                          messages.OPTIONAL if self.sim.striker() is not None else ())
                      if key != '/clock' or self.params['use_sim_clock']}
        self._pubs[STRUCTURE_TOPIC] = self._publisher(STRUCTURE_TOPIC, String, STRUCTURE_QOS)
        self._pubs[FIELD_TOPIC] = self._publisher(FIELD_TOPIC)
        self._topics = {key: self.resolve_topic_name(key) for key in messages.TYPES}
        by_tick = TakenByTick()
        self._cmd_subs = [
            (self.create_subscription(msg_class, key, handler, _qos(), callback_group=by_tick,
                                      qos_overriding_options=QOS_OVERRIDES), handler)
            for key, msg_class, handler in (
                ('~/cmd/impact', Float64MultiArray, self._on_impact),
                ('~/cmd/prestrain', Float64MultiArray, self._on_prestrain),
                ('~/cmd/focus', PointStamped, self._on_focus))]
        self._check_qos_overrides()
        self.focus = None              # the last focus plan (dict) and its state
        self._focus_impact_at = None   # sim time of the planned impact, while it is ahead
        self._record = None            # lens_record.ImpactRecord of the last impact of an array
        self._last_field = -math.inf
        self._srvs = [self.create_service(Trigger, '~/reset', self._on_reset),
                          self.create_service(SetBool, '~/set_running', self._on_set_running)]
        self.running = not self.params['start_paused']
        # commands: accepted = applied; superseded = valid, replaced by a later one of the same
        # topic before the next tick; rejected = malformed (or refused when applied)
        self.counts = {'accepted': 0, 'rejected': 0, 'superseded': 0, 'frames': 0}
        self.last_command = ('none', 'none', '')      # (topic, accepted/rejected, detail)
        self.last_command_t = math.nan                # sim time the last command was applied
        self._pending = {}             # topic -> apply() of its last valid command since a tick
        self._cmd_wall = 0.0           # wall seconds the command callbacks took since a tick
        self._rejected_since = 0       # rejections not yet reported on /diagnostics
        self._last_reject_event = -math.inf
        self.problem = ''
        self._publish_cost = self._marker_cost = 0.0
        self.tick_max_s = 0.0
        self.achieved_rate_hz = 0.0
        self._last_marker = self._last_diag = -math.inf
        self._rtf_window = (time.monotonic(), self.sim.t, 0)
        self.achieved_rtf = 0.0
        self._anchor()
        self._open_recorders()
        self.get_logger().info(
            f'{self.sim.scene.name}: {net.n_nodes} nodes, {net.n_cables} cables, '
            f'{self.sim.model.name} + {self.sim.integrator.name}, dt = {self.sim.dt:g} s, '
            f'publishing at {self.params["publish_rate_hz"]:g} Hz, real-time factor '
            f'{self.params["real_time_factor"]:g}')

    def _check_qos_overrides(self):
        """A ``qos_overrides.*`` parameter that no publisher or subscription declared (a
        misspelled topic, entity or policy) is an error naming it and the valid ones; what
        configure built so far is destroyed again."""
        bad = sorted(n for n in self._parameter_overrides
                     if n.startswith('qos_overrides.') and not self.has_parameter(n))
        if not bad:
            return
        valid = sorted(n for n in self._parameters if n.startswith('qos_overrides.'))
        for pub in self._pubs.values():
            self.destroy_publisher(pub)
        for sub, _ in self._cmd_subs:
            self.destroy_subscription(sub)
        self._pubs, self._cmd_subs, self.sim = {}, [], None
        raise ParameterError(
            f'unknown QoS override{"s" if len(bad) > 1 else ""} {", ".join(bad)}: no publisher '
            f'or subscription of this node has {"them" if len(bad) > 1 else "it"} (valid: '
            f'qos_overrides.<topic>.<publisher|subscription>.<history|depth|reliability|'
            f'durability>, e.g. {valid[0] if valid else "none"}; {len(valid)} in all)')

    # -- hooks for recorders --------------------------------------------------------------------
    def add_sink(self, sink=None, frame_sink=None, event_sink=None, close=None, takes_bytes=False,
                 field_sink=None):
        """Register recorder callbacks: ``sink(topic, msg, stamp_ns)`` (full topic names),
        ``frame_sink(frame)``, ``event_sink(t, text)``, ``close()`` at shutdown,
        ``field_sink(t, peak, pressure)`` (the field maps of ``~/field``, with the pressure at
        ``t``). With ``takes_bytes``, ``sink`` accepts the frame's messages as the CDR ``bytes``
        that are published (rclpy message objects are then built only if another sink needs
        them)."""
        for lst, fn in ((self._sinks, sink), (self._frame_sinks, frame_sink),
                        (self._event_sinks, event_sink), (self._closers, close),
                        (self._field_sinks, field_sink)):
            if fn is not None:
                lst.append(fn)
        if sink is not None and takes_bytes:
            self._bytes_sinks.append(sink)

    def _open_recorders(self):
        if self.params['record_mcap']:
            from tensegrity_ros.io.mcap_frames import network_metadata
            from tensegrity_ros.io.mcap_writer import McapRecorder
            rec = McapRecorder(self.params['record_mcap'],
                               metadata=network_metadata(self.sim.network, self.sim.scene.name))
            for key, topic in self._topics.items():     # /clock too: it may be switched on
                pub = self._pubs.get(key)
                rec.declare(topic, messages.MSG_CLASSES[key],
                            pub.qos_profile if pub is not None else QOS)
            self.add_sink(sink=rec.write, close=rec.close, takes_bytes=True)
        if self.params['record_rerun']:
            from solver.studies.lens_record import grid_extent, image_grid, is_array
            from tensegrity_ros.io.rerun_sink import RerunRecorder
            grid = grid_extent(*image_grid(self.sim.scene)) if is_array(self.sim.scene) else None
            rr = RerunRecorder(self.sim.network, self.params['record_rerun'],
                               tension_scale=self._t_max, field_grid=grid)
            self.add_sink(frame_sink=rr.frame, event_sink=rr.command, close=rr.close,
                          field_sink=rr.field if grid is not None else None)

    def _log(self, kind, level, text):
        """Log ``text`` at ``level`` ('info', 'warning', 'error') unless a line of the same
        ``kind`` went out less than :data:`LOG_THROTTLE_S` ago. (rclpy's own
        ``throttle_duration_sec`` inspects the caller's frame and source file on every call,
        throttled or not: under a flood of commands that was a quarter of the node's time.)"""
        now = time.monotonic()
        if now - self._logged.get(kind, -math.inf) < LOG_THROTTLE_S:
            return
        self._logged[kind] = now
        logger = self.get_logger()     # one call site per severity (rclpy insists)
        if level == 'error':
            logger.error(text)
        elif level == 'warning':
            logger.warning(text)
        else:
            logger.info(text)

    def _emit(self, sinks, *args):
        for fn in list(sinks):
            try:
                fn(*args)
            except Exception as exc:   # a broken recorder must not stop the simulation
                sinks.remove(fn)
                self.get_logger().error(f'recorder {fn!r} failed and was removed: {exc}')

    def close(self):
        """Close the recorders (idempotent)."""
        closers, self._closers = self._closers, []
        for fn in closers:
            try:
                fn()
            except Exception as exc:
                self.get_logger().error(f'closing a recorder failed: {exc}')

    # -- parameters at run time -----------------------------------------------------------------
    def _check_new_parameters(self, params):
        """Refuse (with the reason) a change that the start-up check would refuse, or one of a
        parameter fixed while the node runs; rclpy refuses read-only ones and out-of-range values
        before this is called."""
        values = dict(self.params)
        for p in params:
            if p.name in READ_ONLY:
                return SetParametersResult(successful=False, reason=f'{p.name} {RESTART}')
            if p.name in values:
                values[p.name] = p.value
        try:
            check_parameters(values)
        except ParameterError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply_new_parameters(self, params):
        """Make accepted changes take effect now."""
        new = check_parameters(dict(self.params, **{p.name: p.value for p in params
                                                    if p.name in self.params}))
        old, self.params = self.params, new
        if new['real_time_factor'] != old['real_time_factor'] and self.sim is not None:
            self._anchor()                         # the new pace counts from now
        if new['publish_rate_hz'] != old['publish_rate_hz']:
            self.period = 1.0 / new['publish_rate_hz']
            if self.timer is not None:             # active (else: the next activation's)
                self.timer.timer_period_ns = round(self.period * 1e9)
                self.timer.reset()
        if new['use_sim_clock'] and self.sim is not None and '/clock' not in self._pubs:
            self._pubs['/clock'] = self._publisher('/clock')
        changed = [p.name for p in params if p.name in new and new[p.name] != old[p.name]]
        if changed:
            self._log('parameters', 'info', 'parameters: ' + ', '.join(
                f'{n} = {new[n]!r}' for n in changed))

    # -- pacing ---------------------------------------------------------------------------------
    def _anchor(self):
        self._anchor_wall = time.monotonic()
        self._anchor_t = self.sim.t

    def steps_this_tick(self, now, deadline=None):
        """Steps to take now: towards the paced target time, capped by the work budget. At
        real_time_factor 0 the budget is the time left until ``deadline`` (wall time the next
        tick is due; default one period from ``now``) less the cost of publishing: a tick that
        started late, or spent time on commands, steps less, so that the next one starts on time
        and the publish rate holds."""
        publish = self._publish_cost + (self._marker_cost if self._markers_due(now) else 0.0)
        rtf = self.params['real_time_factor']
        if rtf <= 0:
            left = self.period if deadline is None else deadline - now
            budget = max(FAST_WORK_FRACTION * left - publish, MIN_WORK_FRACTION * self.period)
            return max(1, int(budget / max(self._step_cost, 1e-9)))
        # paced, a tick keeps a margin so that it ends before the next one is due
        budget = max(WORK_FRACTION * self.period - publish - self._cmd_wall,
                     MIN_WORK_FRACTION * self.period)
        cap = max(1, int(budget / max(self._step_cost, 1e-9)))
        target = self._anchor_t + rtf * (now - self._anchor_wall)
        want = int(math.floor((target - self.sim.t) / self.sim.dt + 1e-9))
        if want > cap:                 # cannot keep up: do what fits, do not accumulate debt
            self._anchor_t = self.sim.t + cap * self.sim.dt
            self._anchor_wall = now
            return cap
        return max(want, 0)

    def _markers_due(self, now):
        """Markers are due at ``marker_rate_hz``, and only built when someone listens (a
        subscriber or a recorder sink): they cost more than all other topics together."""
        if not self._sinks and self._pubs['~/markers'].get_subscription_count() == 0:
            return False
        return now - self._last_marker >= 1.0 / self.params['marker_rate_hz']

    def _tick(self):
        now = time.monotonic()
        until = self.timer.time_until_next_call() if self.timer is not None else None
        self._deadline = now + (until * 1e-9 if until is not None else self.period)
        self._tick_work(now)
        self.tick_max_s = max(self.tick_max_s, time.monotonic() - now)

    def _tick_work(self, now):
        self._take_commands()
        self._apply_pending()
        if self.running:
            n = self.steps_this_tick(time.monotonic(), self._deadline)
            if self._focus_impact_at is not None:      # land exactly on the planned impact
                n = min(n, max(0, round((self._focus_impact_at - self.sim.t) / self.sim.dt)))
                if n == 0:
                    self._focus_impact()
                    n = self.steps_this_tick(time.monotonic(), self._deadline)
            if n > 0:
                t0 = time.perf_counter()
                try:
                    if self._record is None:
                        self.sim.advance(n * self.sim.dt)
                    else:                   # sampling the base forces on the way
                        self._record.advance(self.sim, n)
                except SimulationDiverged as exc:
                    self._record = None
                    self._pause(f'paused: {exc}')
                    return
                cost = (time.perf_counter() - t0) / n
                self._step_cost = 0.8 * self._step_cost + 0.2 * cost
                self._publish_frame(now)
                self._after_record(now)
        self._cmd_wall = 0.0
        if now - self._last_diag >= 1.0 / self.params['diagnostics_rate_hz']:
            self._publish_diagnostics(now)

    def _pause(self, why):
        self.running = False
        self.problem = why
        self._log('pause', 'error', why)
        self._emit(self._event_sinks, self.sim.t, why)
        self._publish_diagnostics(time.monotonic())

    # -- publishing -----------------------------------------------------------------------------
    def _publish_frame(self, now):
        t0 = time.perf_counter()
        frame = self.sim.frame()
        markers = self._markers_due(now)
        # the frame goes out as bytes written from the arrays (cdr.py): rclpy's conversion of
        # message objects is the largest cost of publishing (markers 50x); objects are built only
        # for a sink that cannot take the bytes
        objects = any(fn not in self._bytes_sinks for fn in self._sinks)
        build = messages.frame_messages if objects else cdr.frame_messages_cdr
        stamp = messages.sim_stamp(frame.t)
        try:
            msgs = build(frame, self.sim.network, stamp=stamp, markers=markers,
                         clock=self.params['use_sim_clock'], t_max=self._t_max)
        except ValueError as exc:          # non-finite frame: never published
            self._pause(f'paused: {exc}')
            return
        if markers:
            self._last_marker = now
        stamp_ns = messages.stamp_to_ns(stamp)
        for key, msg in msgs.items():
            self._pubs[key].publish(msg)
            self._emit(self._sinks, self._topics[key], msg, stamp_ns)
        self._emit(self._frame_sinks, frame)
        self.counts['frames'] += 1
        wall, t_sim, frames = self._rtf_window
        if now - wall >= 1.0:
            self.achieved_rtf = (frame.t - t_sim) / (now - wall)
            self.achieved_rate_hz = (self.counts['frames'] - frames) / (now - wall)
            self._rtf_window = (now, frame.t, self.counts['frames'])
        cost = time.perf_counter() - t0
        if markers:
            self._marker_cost = 0.8 * self._marker_cost + 0.2 * max(cost - self._publish_cost, 0)
        else:
            self._publish_cost = 0.8 * self._publish_cost + 0.2 * cost

    def diagnostics_values(self):
        """The key/value pairs of ``/diagnostics`` (dict name -> float, int or str)."""
        topic, verdict, detail = self.last_command
        return {
            'sim_time_s': float(self.sim.t), 'steps': int(self.sim.step),
            'running': str(self.running).lower(),
            'real_time_factor_target': float(self.params['real_time_factor']),
            'real_time_factor_achieved': float(self.achieved_rtf),
            'publish_rate_hz_achieved': float(self.achieved_rate_hz),
            'tick_max_ms': 1e3 * float(self.tick_max_s),
            'energy_J': float(self.sim.energy()),
            'constraint_error': float(self.sim.constraint_error()),
            'frames_published': self.counts['frames'],
            'commands_accepted': self.counts['accepted'],
            'commands_rejected': self.counts['rejected'],
            'commands_superseded': self.counts['superseded'],
            'last_command_topic': topic, 'last_command': verdict, 'last_command_detail': detail,
            'last_command_sim_time_s': (float(self.last_command_t)
                                        if math.isfinite(self.last_command_t) else -1.0),
            **self._focus_values(),
        }

    def _publish_diagnostics(self, now, level=None, message=None):
        self._last_diag = now
        periodic = level is None
        if level is None:
            level = 2 if self.problem else 1 if self._rejected_since else 0
            message = self.problem or (f'rejected {self.last_command[2]}' if self._rejected_since
                                       else 'running' if self.running else 'paused')
            self._rejected_since = 0
        stamp = messages.sim_stamp(self.sim.t)
        msg = messages.diagnostics_message(stamp, self.diagnostics_values(), level, message)
        self._pubs['/diagnostics'].publish(msg)
        self._emit(self._sinks, self._topics['/diagnostics'], msg, messages.stamp_to_ns(stamp))
        if periodic:
            self.tick_max_s = 0.0          # tick_max_ms covers one diagnostics period

    # -- the field in the medium ----------------------------------------------------------------
    def _start_record(self, focus=None):
        """After an impact of an array: record its base forces for the scene's ``run.t_end``
        (always for a focus, whose arrivals /diagnostics report; for another impact only while
        ``field_rate_hz`` > 0 and someone listens to ``~/field`` or records)."""
        from solver.studies.lens_record import ImpactRecord, is_array
        self._record = None
        if not is_array(self.sim.scene) or (focus is None and (
                self.params['field_rate_hz'] <= 0 or not self._field_wanted())):
            return
        self._record = ImpactRecord(self.sim, self.params['medium_speed_m_s'],
                                    float(self.sim.scene['run.t_end']), focus)
        self._last_field = -math.inf
        self._field_sent_t = None

    def _field_wanted(self):
        return bool(self._sinks or self._field_sinks
                    or self._pubs[FIELD_TOPIC].get_subscription_count() > 0)

    def _after_record(self, now):
        """Once per stepping tick with a record: the focus figures when it is complete, the
        field when it is due (``field_rate_hz``) and someone listens or records."""
        rec = self._record
        if rec is None:
            return
        if rec.focus is not None and rec.done and self.focus is not None \
                and 'measured' not in self.focus:
            plan = self.focus['plan']
            self.focus['measured'] = rec.measure([c['target_s'] for c in plan['columns']])
        rate = self.params['field_rate_hz']
        if rate > 0 and now - self._last_field >= 1.0 / rate and self._field_wanted():
            self._last_field = now
            self._publish_field(rec)

    def _publish_field(self, rec):
        """``~/field``: the peak pressure map since the impact (model units, 32FC1); the field
        sinks get it with the pressure now. A non-finite map is not published."""
        peak = rec.peak_map()
        if peak is None:
            return
        stamp = messages.sim_stamp(rec.peak_time)
        try:
            msg = messages.field_image(peak, stamp)
        except ValueError as exc:
            self.get_logger().error(f'~/field: {exc}; not published',
                                    throttle_duration_sec=LOG_THROTTLE_S)
            return
        self._pubs[FIELD_TOPIC].publish(msg)
        self._emit(self._sinks, self._topics[FIELD_TOPIC], msg, messages.stamp_to_ns(stamp))
        if self._field_sinks and rec.peak_time != self._field_sent_t:   # each time once
            self._field_sent_t = rec.peak_time
            now = rec.pressure_now()
            self._emit(self._field_sinks, float(rec.peak_time), peak,
                       now if np.isfinite(now).all() else None)

    # -- commands -------------------------------------------------------------------------------
    def _command(self, key, msg, check):
        """A command received on ``key``: recorded, validated at once (``check()`` returns the
        ``apply()`` that changes the simulation, or raises), counted; a valid one replaces the
        topic's pending command, applied by the tick (:meth:`_apply_pending`). Returns whether it
        was valid."""
        w0 = time.perf_counter()
        stamp_ns = messages.stamp_to_ns(messages.sim_stamp(self.sim.t))
        self._emit(self._sinks, self._topics[key], msg, stamp_ns)
        try:
            apply = check()
        except (commands.CommandError, ValueError) as exc:
            self._reject(key, exc)
            ok = False
        else:
            if self._pending.pop(key, None) is not None:
                self.counts['superseded'] += 1
            self._pending[key] = apply
            ok = True
        self._cmd_wall += time.perf_counter() - w0
        return ok

    def _reject(self, key, exc):
        text = str(exc) if str(exc).startswith('~/') else f'{key}: {exc}'
        self.counts['rejected'] += 1
        self._rejected_since += 1
        self.last_command = (key, 'rejected', text)
        self._log('rejected', 'warning', f'rejected {text}')
        now = time.monotonic()
        if now - self._last_reject_event >= LOG_THROTTLE_S:       # events: throttled as well
            self._last_reject_event = now
            self._emit(self._event_sinks, self.sim.t, f'rejected {text}')

    def _take_commands(self):
        """Take every command waiting in the subscriptions now (each through its callback), at
        once: the executor never takes them (:class:`TakenByTick`), so a flood costs no executor
        cycle per message and is taken whole (what the subscriptions' QoS history keeps: the last
        10 per topic by default)."""
        for sub, handler in self._cmd_subs:
            for _ in range(MAX_TAKE):
                with sub.handle:
                    got = sub.handle.take_message(sub.msg_type, sub.raw)
                if got is None:
                    break
                handler(got[0])

    def _apply_pending(self):
        """Apply the last valid command per topic that arrived since the previous tick."""
        pending, self._pending = self._pending, {}
        for key, apply in pending.items():
            try:
                detail = apply()
            except (commands.CommandError, ValueError) as exc:
                self._reject(key, exc)
                continue
            self.counts['accepted'] += 1
            self.last_command = (key, 'accepted', detail)
            self.last_command_t = self.sim.t
            self._log('accepted', 'info', f'{key}: {detail}')
            self._emit(self._event_sinks, self.sim.t, f'{key}: {detail}')

    def _on_impact(self, msg):
        def check():
            v0 = commands.parse_impact(msg.data, msg.layout, self.sim.network.n_columns)

            def apply():
                added = self.sim.apply_impact(float(v0[0]) if v0.size == 1 else v0)
                self._start_record()
                return f'impact v0 = {commands.describe(v0)} m/s, kinetic energy +{added:.3g} J'
            return apply
        return self._command('~/cmd/impact', msg, check)

    def _on_prestrain(self, msg):
        def check():
            if self._cross_prism is None:
                raise commands.CommandError('~/cmd/prestrain: this scene is not a column of '
                                            'prisms; prestrain commands need one')
            if self.sim.model.name == 'chain1d':
                raise commands.CommandError('~/cmd/prestrain: the chain1d model cannot change its '
                                            'prestrain (its force law is precomputed for the '
                                            'scene); use model full3d or sym3d')
            net = self.sim.network
            p = commands.parse_prestrain(msg.data, msg.layout, net.n_columns, net.n_prisms,
                                         self._cross_prism)

            def apply():
                ramp = self.params['prestrain_ramp_s']
                self.sim.apply_prestrain(p, ramp_s=ramp)
                per_col = p.mean(axis=1)
                return f'prestrain per column {commands.describe(per_col)} over {ramp:g} s'
            return apply
        return self._command('~/cmd/prestrain', msg, check)

    def _on_focus(self, msg):
        """``~/cmd/focus``: plan one prestrain per column (solver.studies.lens.design) for the
        focus
        (point.x along the array, point.z the depth below the bases, m) in a medium of speed
        ``medium_speed_m_s``, ramp the prestrains over ``prestrain_ramp_s``, then impact every
        column at once with the scene's v0. The first plan for a scene and v0 computes the
        arrival map (the node waits for it; kept on disk for the next time)."""
        def check():
            from solver.studies import lens
            x, z = float(msg.point.x), float(msg.point.z)
            if not (math.isfinite(x) and math.isfinite(z) and math.isfinite(msg.point.y)):
                raise commands.CommandError(f'~/cmd/focus: the point must be finite, got '
                                            f'({msg.point.x!r}, {msg.point.y!r}, {msg.point.z!r})')
            if self.sim.model.name == 'chain1d':
                raise commands.CommandError('~/cmd/focus: the chain1d model cannot change its '
                                            'prestrain; use model auto, full3d or sym3d')
            scene = self.sim.scene
            v0 = float(scene['loading.impact.v0'])
            if not v0 > 0:
                raise commands.CommandError('~/cmd/focus: the scene has no impact velocity '
                                            '(loading.impact.v0 > 0) to plan for')
            speed = self.params['medium_speed_m_s']
            try:
                plan = lens.design(scene, (x, z), speed, v0)
            except (lens.LensError, KeyError) as exc:
                raise commands.CommandError(f'~/cmd/focus: {exc}') from None
            p = [c['prestrain'] for c in plan.columns]

            def apply():
                ramp = self.params['prestrain_ramp_s']
                self.sim.apply_prestrain(p, ramp_s=ramp)
                self._focus_impact_at = self.sim.t + ramp
                self.focus = {'plan': plan.as_dict(), 'state': 'ramping',
                              'impact_sim_time_s': self._focus_impact_at}
                if ramp == 0:
                    self._focus_impact()
                return (f'focus ({x:g}, {z:g}) m at C = {speed:g} m/s: prestrain per column '
                        f'{commands.describe(np.array(p))} over {ramp:g} s, then impact '
                        f'v0 = {v0:g} m/s on every column')
            return apply
        return self._command('~/cmd/focus', msg, check)

    def _focus_impact(self):
        """The planned impact of a focus: every column at once."""
        self._focus_impact_at = None
        v0 = self.focus['plan']['v0']
        added = self.sim.apply_impact(v0)
        self.focus['state'] = 'impacted'
        self.focus['impact_sim_time_s'] = float(self.sim.t)
        self._start_record(tuple(self.focus['plan']['focus_m']))
        detail = f'focus impact v0 = {v0:g} m/s on every column, kinetic energy +{added:.3g} J'
        self._log('focus impact', 'info', f'~/cmd/focus: {detail}')
        self._emit(self._event_sinks, self.sim.t, f'~/cmd/focus: {detail}')

    def _focus_values(self):
        """The focus plan as /diagnostics values (texts; JSON lists per column)."""
        import json
        f = self.focus
        if f is None:
            return {'focus': 'none'}
        plan = f['plan']
        cols = plan['columns']
        return {'focus': f['state'], 'focus_x_m': float(plan['focus_m'][0]),
                'focus_z_m': float(plan['focus_m'][1]),
                'focus_medium_speed_m_s': float(plan['medium_speed_m_s']),
                'focus_v0': float(plan['v0']), 'focus_t0_s': float(plan['t0_s']),
                'focus_impact_sim_time_s': float(f['impact_sim_time_s']),
                'focus_prestrain': json.dumps([c['prestrain'] for c in cols]),
                'focus_arrival_target_s': json.dumps([c['target_s'] for c in cols]),
                'focus_arrival_predicted_s': json.dumps([c['predicted_s'] for c in cols]),
                **self._measured_values(f.get('measured'))}

    @staticmethod
    def _measured_values(m):
        """The figures of a focus measured on the node's own run (``focus_measured`` true once
        its record is complete): per column the simulated arrival and its residual (JSON lists,
        s after the impact; a column without a pulse as null) and the peak pressure at F."""
        import json
        if m is None:
            return {'focus_measured': 'false'}

        def finite(v):
            return [x if math.isfinite(x) else None for x in v]
        return {'focus_measured': 'true',
                'focus_arrival_simulated_s': json.dumps(finite(m['simulated_s'])),
                'focus_residual_s': json.dumps(finite(m['residual_s'])),
                'focus_peak_pressure': (float(m['peak_pressure'])
                                        if math.isfinite(m['peak_pressure']) else -1.0)}

    def _on_reset(self, request, response):
        self._take_commands()          # commands that came before the reset, then the reset
        self._apply_pending()
        self.sim.reset()
        self._focus_impact_at = None
        self._record = None
        if self.focus is not None and self.focus['state'] == 'ramping':
            self.focus['state'] = 'cancelled by reset'
        self.problem = ''
        self._anchor()
        self._rtf_window = (time.monotonic(), self.sim.t, self.counts['frames'])
        self._emit(self._event_sinks, self.sim.t, 'reset')
        if self.active:                # frames go out only while active
            self._publish_frame(time.monotonic())
        response.success = True
        response.message = 'reset to the reference geometry at rest, t = 0'
        return response

    def _on_set_running(self, request, response):
        self.running = bool(request.data)
        if self.running:
            self.problem = ''
            self._anchor()
        response.success = True
        response.message = 'running' if self.running else 'paused'
        return response


def _stop_on_signals():
    """SIGINT and SIGTERM ask the spin loop to stop (a list that gets the signal number): the tick
    that is running finishes, so that both recordings end on the same frame; a second signal
    interrupts at once (KeyboardInterrupt)."""
    stop = []

    def handler(signum, frame):
        if stop:
            raise KeyboardInterrupt
        stop.append(signum)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, handler)
    return stop


def main(args=None):
    """Console script ``tensegrity_node``: spin the node until Ctrl-C / SIGTERM (the current tick
    finishes first); exit 2 with one line on stderr for a bad parameter or scene."""
    from solver.build.network import NetworkError
    from solver.build.scene import SceneError
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = _stop_on_signals()
    node = None
    code = 0
    try:
        node = TensegritySim()
        gc.freeze()             # see cli.cmd_run: the start-up's objects are not scanned again
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while not stop and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ParameterError, SceneError, NetworkError, ValueError) as exc:
        print(f'tensegrity_node: {exc}', file=sys.stderr)
        code = 2
    except RCLError:
        if rclpy.ok():      # not a shutdown caught in the middle of a publish
            raise
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
