"""The ROS 2 node ``tensegrity_sim`` (docs/node.md): one managed node class and :func:`main`.

    tensegrity_node [--ros-args -p real_time_factor:=0.0 --params-file config/node.yaml]

One timer drives everything: each tick applies the commands that arrived since the last one,
advances the simulation towards the paced target time within a work budget, then publishes one
frame. Stamps are simulation time, and the simulation clock never goes back: a reset restores the
rest state and starts a new episode while the clock runs on (:meth:`TensegritySim.clock_time`).
The node is a thin adapter over its parts, one job each:
:class:`~tensegrity_ros.node.pacing.Pacer` (how far a tick steps),
:class:`~tensegrity_ros.node.intake.Intake` (commands),
:class:`~tensegrity_ros.node.publishing.Publishing` (frames, structure, ``/diagnostics``) and
:class:`~tensegrity_ros.node.focus.Focus` (the lens); recorders are sinks
(:mod:`tensegrity_ros.io.sinks`). Repeated log lines are throttled
(:class:`~tensegrity_ros.node.params.ThrottledLog`).
"""
from __future__ import annotations

import gc
import signal
import sys
import time

import rclpy
from geometry_msgs.msg import PointStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy._rclpy_pybind11 import RCLError
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool, Trigger

from solver import SimulationDiverged
from tensegrity_ros.io.sinks import FanOut, McapSink, RerunSink
from tensegrity_ros.msgs import messages, style
from tensegrity_ros.node.focus import FIELD_TOPIC, Focus
from tensegrity_ros.node.intake import Intake, TakenByTick
from tensegrity_ros.node.pacing import Pacer
from tensegrity_ros.node.params import (DEFAULTS, LOG_THROTTLE_S, ParameterError, ThrottledLog,
                                        check_parameters, descriptor, load_simulation,
                                        measure_step_cost, refusal, unknown_parameters)
from tensegrity_ros.node.publishing import STRUCTURE_TOPIC, Publishing
from tensegrity_ros.node.qos import (QOS, QOS_OVERRIDES, STRUCTURE_QOS, fresh as _qos,
                                     unknown_overrides)

class TensegritySim(LifecycleNode):
    """The node ``tensegrity_sim``. ``sim``: an existing simulation to drive (tests, benchmarks)
    instead of the one the parameters describe; ``kwargs`` go to :class:`LifecycleNode`
    (``context``, ``parameter_overrides``, ``namespace``). With ``autostart`` (the default) it
    configures and activates itself in the constructor; without, it waits for ``~/change_state``.
    Unconfigured: parameters only; configure: simulation, recorders, publishers, subscriptions,
    services; activate: the timer; deactivate: the timer stops, the state stays."""

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
            self.declare_parameter(name, default, descriptor(name))
        self.params = check_parameters({n: self.get_parameter(n).value for n in DEFAULTS})
        self.add_on_set_parameters_callback(self._check_new_parameters)
        self.add_post_set_parameters_callback(self._apply_new_parameters)
        self.period = 1.0 / self.params['publish_rate_hz']
        self._given_sim = sim
        self.sim = self.timer = None
        self.active = False
        self.pubs, self._srvs = {}, []
        self.sinks = FanOut(self._sink_failed)
        self.log = ThrottledLog(self.get_logger(), LOG_THROTTLE_S)
        if self.params['autostart']:
            self._setup()          # a bad scene raises here (the console script exits 2)
            for name, trigger in (('configure', self.trigger_configure),
                                  ('activate', self.trigger_activate)):
                if trigger() != TransitionCallbackReturn.SUCCESS:
                    raise RuntimeError(f'{messages.NODE_NAME}: {name} failed (see the log)')

    def _check_undeclared_parameters(self, parameter_list):
        """rclpy's check of a change (every path of set_parameters goes through it), the unknown
        names refused by name."""
        from tensegrity_ros.node.params import refuse_undeclared
        refuse_undeclared([p.name for p in parameter_list], self._parameters)
        super()._check_undeclared_parameters(parameter_list)

    # -- lifecycle ------------------------------------------------------------------------------
    # each transition logs one line: INFO when it succeeds, ERROR for a failure or an error
    def on_configure(self, state):
        if self.sim is None:
            from solver import NetworkError
            from solver import SceneError
            try:
                self._setup()
            except (ParameterError, SceneError, NetworkError, ValueError) as exc:
                self.get_logger().error(f'configure failed, still unconfigured: {exc}')
                return TransitionCallbackReturn.FAILURE
        self.get_logger().info('configured (inactive): simulation, recorders, publishers, '
                               'subscriptions and services ready')
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state):
        self.active = True
        self.pacer.anchor(self.sim.t, time.monotonic())
        self.publishing.restart_window(time.monotonic())
        self.publishing.structure()
        self.publishing.frame(time.monotonic())
        self.timer = self.create_timer(self.period, self._tick)
        self.get_logger().info(f'activated: stepping and publishing from t = '
                               f'{self.clock_time():.9g} s')
        return super().on_activate(state)

    def on_deactivate(self, state):
        self.active = False
        self._drop_timer()
        self.get_logger().info(f'deactivated at t = {self.clock_time():.9g} s: the timer stops, '
                               f'the state stays')
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        self._teardown()
        self.get_logger().info('cleaned up (unconfigured): the simulation is dropped, the '
                               'recorders closed')
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state):
        self._teardown()
        self.get_logger().info(f'shutdown (the node was {state.label}): the recorders closed')
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state):
        self._teardown()
        self.get_logger().error(f'error in a transition from {state.label}: torn down to '
                                f'unconfigured, the recorders closed')
        return TransitionCallbackReturn.SUCCESS

    def _drop_timer(self):
        if self.timer is not None:
            self.timer.cancel()
            self.destroy_timer(self.timer)
            self.timer = None

    def _teardown(self):
        """Back to parameters only: what configure built is destroyed, the recorders closed."""
        self.active = False
        self._drop_timer()
        self.close()
        self._destroy_entities()
        self.sim = None

    def _destroy_entities(self):
        for pub in self.pubs.values():
            self.destroy_publisher(pub)
        subscriptions = self.intake.subscriptions if self.sim is not None else []
        for sub, _ in subscriptions:
            self.destroy_subscription(sub)
        for srv in self._srvs:
            self.destroy_service(srv)
        self.pubs, self._srvs, subscriptions[:] = {}, [], []

    def _publisher(self, key, msg_class=None, qos=QOS):
        """The publisher of ``key``, QoS as overridden by the parameters. No QoS-event handlers:
        each is a waitable the executor polls on every tick."""
        return self.create_publisher(
            msg_class or messages.MSG_CLASSES[key], key, _qos(qos),
            event_callbacks=PublisherEventCallbacks(use_default_callbacks=False),
            qos_overriding_options=QOS_OVERRIDES)

    def _setup(self):
        """What configure builds: the simulation (the caller's, in its state, or the one the
        parameters describe), the parts, recorders, publishers, subscriptions and services."""
        sim = self._given_sim
        if sim is None:
            sim = load_simulation(self.params)
            step_cost = measure_step_cost(sim)
        else:                      # a caller's simulation, in its state: start cautiously
            step_cost = 0.1 * self.period
        self.sim, net = sim, sim.network
        self.episode, self.t_offset = 0, 0.0       # the clock: t_offset + the episode's sim.t
        self.cross_prism = sim.prestrain_map.cross_prism if sim.prestrain is not None else None
        self.t_max = style.reference_tension_scale(net)
        self.running, self.problem = not self.params['start_paused'], ''
        self.divergences, self.last_divergence = 0, None
        self.pacer = Pacer(self.period, step_cost)
        self.intake, self.focus = Intake(self), Focus(self)
        self.counts = self.intake.counts
        self.publishing = Publishing(self)
        self.pubs = {key: self._publisher(key) for key in messages.PUBLISHED + (
            messages.OPTIONAL if sim.striker() is not None else ())
            if key != '/clock' or self.params['use_sim_clock']}
        self.pubs[STRUCTURE_TOPIC] = self._publisher(STRUCTURE_TOPIC, String, STRUCTURE_QOS)
        self.pubs[FIELD_TOPIC] = self._publisher(FIELD_TOPIC)
        self.topics = {key: self.resolve_topic_name(key) for key in messages.TYPES}
        by_tick = TakenByTick()
        self.intake.subscriptions = [
            (self.create_subscription(cls, key, self.intake.handlers[key], _qos(),
                                      callback_group=by_tick,
                                      qos_overriding_options=QOS_OVERRIDES),
             self.intake.handlers[key])
            for key, cls in (('~/cmd/impact', Float64MultiArray),
                             ('~/cmd/prestrain', Float64MultiArray),
                             ('~/cmd/focus', PointStamped))]
        self._check_qos_overrides()
        self._srvs = [self.create_service(Trigger, '~/reset', self._on_reset),
                      self.create_service(SetBool, '~/set_running', self._on_set_running)]
        self.pacer.anchor(sim.t, time.monotonic())
        self._open_recorders()
        self.get_logger().info(
            f'{sim.scene.name}: {net.n_nodes} nodes, {net.n_cables} cables, {sim.model.name} + '
            f'{sim.integrator.name}, dt = {sim.dt:g} s, publishing at '
            f'{self.params["publish_rate_hz"]:g} Hz, real-time factor '
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
        self._destroy_entities()
        self.sim = None
        raise ParameterError(unknown_overrides(bad, valid))

    # -- recorders ------------------------------------------------------------------------------
    def add_sink(self, sink):
        """Record the node's traffic with ``sink`` (see :mod:`tensegrity_ros.io.sinks`)."""
        return self.sinks.add(sink)

    def _sink_failed(self, sink, exc):
        self.get_logger().error(f'recorder {sink!r} failed and was removed: {exc}')

    def _open_recorders(self):
        if self.params['record_mcap']:
            from tensegrity_ros.io.mcap_frames import network_metadata
            from tensegrity_ros.io.mcap_writer import McapRecorder
            rec = McapRecorder(self.params['record_mcap'], bag=True,
                               metadata=network_metadata(self.sim.network, self.sim.scene.name))
            for key, topic in self.topics.items():     # /clock too: it may be switched on
                pub = self.pubs.get(key)
                rec.declare(topic, messages.MSG_CLASSES[key],
                            pub.qos_profile if pub is not None else QOS)
            self.add_sink(McapSink(rec))
        if self.params['record_rerun']:
            from solver import grid_extent, image_grid, is_array
            from tensegrity_ros.io.rerun_sink import RerunRecorder
            grid = grid_extent(*image_grid(self.sim.scene)) if is_array(self.sim.scene) else None
            self.add_sink(RerunSink(RerunRecorder(self.sim.network, self.params['record_rerun'],
                                                  tension_scale=self.t_max, field_grid=grid)))

    def close(self):
        """Close the recorders (idempotent)."""
        self.sinks.close()

    # -- parameters at run time -----------------------------------------------------------------
    def _check_new_parameters(self, params):
        """Refuse (with the reason) a change the start-up check would refuse, or one of a
        parameter fixed while the node runs."""
        reason = refusal(self.params, {p.name: p.value for p in params})
        return SetParametersResult(successful=reason is None, reason=reason or '')

    def _apply_new_parameters(self, params):
        """Make accepted changes take effect now."""
        new = check_parameters(dict(self.params, **{p.name: p.value for p in params
                                                    if p.name in self.params}))
        old, self.params = self.params, new
        if new['real_time_factor'] != old['real_time_factor'] and self.sim is not None:
            self.pacer.anchor(self.sim.t, time.monotonic())     # the new pace counts from now
        if new['publish_rate_hz'] != old['publish_rate_hz']:
            self.period = 1.0 / new['publish_rate_hz']
            if self.sim is not None:
                self.pacer.period = self.period
            if self.timer is not None:             # active (else: the next activation's)
                self.timer.timer_period_ns = round(self.period * 1e9)
                self.timer.reset()
        if new['use_sim_clock'] and self.sim is not None and '/clock' not in self.pubs:
            self.pubs['/clock'] = self._publisher('/clock')
        changed = [p.name for p in params if p.name in new and new[p.name] != old[p.name]]
        if changed:
            self.log('parameters', 'info', 'parameters: ' + ', '.join(
                f'{n} = {new[n]!r}' for n in changed))

    # -- the tick -------------------------------------------------------------------------------
    def _tick(self):
        now = time.monotonic()
        until = self.timer.time_until_next_call() if self.timer is not None else None
        deadline = now + (until * 1e-9 if until is not None else self.period)
        self._tick_work(now, deadline)
        self.publishing.tick_max_s = max(self.publishing.tick_max_s, time.monotonic() - now)

    def steps_this_tick(self, now, deadline=None):
        """Steps to take now (:meth:`tensegrity_ros.node.pacing.Pacer.steps`)."""
        self.pacer.cmd_wall = self.intake.cmd_wall
        return self.pacer.steps(now, self.sim.t, self.sim.dt, self.params['real_time_factor'],
                                deadline, self.publishing.markers_due(now))

    def _tick_work(self, now, deadline):
        self.intake.take()
        self.intake.apply()
        if self.running:
            n = self.focus.steps_until_impact(self.steps_this_tick(time.monotonic(), deadline))
            if n is None:                          # the planned impact was made: step on
                n = self.steps_this_tick(time.monotonic(), deadline)
            if n > 0:
                t0 = time.perf_counter()
                try:
                    self.focus.advance(n)
                except SimulationDiverged as exc:
                    self.diverged(str(exc), exc.t)
                    if self.running:                # reset: the rest state goes out at once
                        self.publishing.frame(now)
                else:
                    self.pacer.stepped(n, time.perf_counter() - t0)
                    self.publishing.frame(now)
                    self.focus.after_steps(now)
        self.intake.cmd_wall = 0.0
        if now - self.publishing.last_diag >= 1.0 / self.params['diagnostics_rate_hz']:
            self.publishing.diagnostics(now)

    def pause(self, why):
        """Stop stepping and say why (log, event, ``/diagnostics`` at once)."""
        self.running = False
        self.problem = why
        self.log('pause', 'error', why)
        self.event(why)
        self.publishing.diagnostics(time.monotonic())

    def diverged(self, text, t):
        """The simulation diverged at simulation time ``t`` (``text``: the solver's
        :class:`SimulationDiverged`, or a frame that is not finite; the state is the last good
        one). Counted and kept for ``/diagnostics``; then ``on_divergence``: ``pause`` stops the
        clock (:meth:`pause`), ``reset`` puts the simulation back to its rest state (t = 0) and
        the node steps and publishes on. Either way an ERROR log line and an ERROR
        ``/diagnostics`` status name the divergence at once."""
        self.focus.record = None
        action = self.params['on_divergence']
        self.divergences += 1
        self.last_divergence = {'wall': time.monotonic(), 'sim_time_s': self.clock_time(t),
                                'text': text,
                                'action': action, 'reported': False}
        if action == 'pause':
            self.pause(f'paused: {text}')
            return
        self.log('divergence', 'error',
                 f'{text}; reset to the rest state, episode {self.episode + 1} '
                 f'(on_divergence: reset)')
        self.event(f'diverged, reset to the rest state: {text}')
        t_before = self.clock_time()
        self._reset_simulation()
        self.publishing.time_jump(t_before, self.clock_time())
        self.publishing.diagnostics(time.monotonic())

    def clock_time(self, t=None):
        """The simulation clock, s, of the episode time ``t`` (default: now): it never goes
        back. Each reset starts a new episode (``episode`` + 1) at the rest state, one step
        ``dt`` after the last state of the previous one; stamps, ``/clock`` and recordings use
        this clock, the solver its episode's ``sim.t`` (0 at each reset)."""
        return self.t_offset + (self.sim.t if t is None else t)

    def event(self, text):
        """An event (a command applied or rejected, a reset, a pause) at the clock time now: on
        ``~/events`` and to the recorders."""
        t = self.clock_time()
        msg = String(data=text)
        stamp_ns = messages.stamp_to_ns(messages.sim_stamp(t))
        self.pubs['~/events'].publish(msg)
        self.sinks.message(self.topics['~/events'], msg, stamp_ns)
        self.sinks.event(t, text)

    def _reset_simulation(self):
        """The simulation at its rest state, a new episode (the clock runs on, see
        :meth:`clock_time`); a planned focus impact dropped; the pace counts from now."""
        t_end = self.clock_time()
        self.sim.reset()
        self.episode += 1
        self.t_offset = t_end + self.sim.dt - self.sim.t
        self.focus.reset()
        self.problem = ''
        self.pacer.anchor(self.sim.t, time.monotonic())

    # -- services -------------------------------------------------------------------------------
    def _on_reset(self, request, response):
        self.intake.take()             # commands that came before the reset, then the reset
        self.intake.apply()
        self._reset_simulation()
        self.publishing.restart_window(time.monotonic())
        self.event('reset')
        self.publishing.diagnostics(time.monotonic())     # the new episode, before its frames
        if self.active:                # frames go out only while active
            self.publishing.frame(time.monotonic())
        response.success = True
        response.message = (f'reset to the reference geometry at rest: episode {self.episode} '
                            f'from t = {self.clock_time():.9g} s (the clock runs on)')
        return response

    def _on_set_running(self, request, response):
        self.running = bool(request.data)
        if self.running:
            self.problem = ''
            self.pacer.anchor(self.sim.t, time.monotonic())
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
    from solver import NetworkError
    from solver import SceneError
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
