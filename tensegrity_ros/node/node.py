"""The ROS 2 node ``tensegrity_sim`` (docs/node.md): one managed node class and :func:`main`.

    tensegrity_node [--ros-args -p real_time_factor:=0.0 --params-file config/node.yaml]

One timer on the wall (steady) clock drives everything, whatever ``use_sim_time`` says: each tick
applies the commands that arrived since the last one, advances the simulation towards the paced
target time within a work budget, then publishes one frame. Stamps and ``/clock`` are simulation
time, and the simulation clock never goes back: a reset restores the rest state and starts a new
episode while the clock runs on (:meth:`TensegritySim.clock_time`). The node is a thin adapter
over its parts, one job each: :class:`~tensegrity_ros.node.pacing.Pacer` (how far a tick steps),
:class:`~tensegrity_ros.node.stepping.Stepper` (stepping; ``~/step`` while paused),
:class:`~tensegrity_ros.node.intake.Intake` (commands),
:class:`~tensegrity_ros.node.publishing.Publishing` (frames, structure, ``/diagnostics``),
:class:`~tensegrity_ros.node.realtime.RealTime` (the achieved real-time factor) and
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
# rclpy exports RCLError only from its private extension module (no public name): main() needs
# it to tell a publish cut short by a shutdown from a real error
from rclpy._rclpy_pybind11 import RCLError
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import String

from solver import SimulationDiverged
from tensegrity_ros.io.sinks import FanOut
from tensegrity_ros.msgs import messages, style
from tensegrity_ros.node import endpoints
from tensegrity_ros.node.changes import apply_changes, check_changes
from tensegrity_ros.node.focus import Focus
from tensegrity_ros.node.intake import Intake
from tensegrity_ros.node.pacing import Pacer
from tensegrity_ros.node.params import (DEFAULTS, LOG_THROTTLE_S, ParameterError, ThrottledLog,
                                        check_parameters, descriptor, find_config,
                                        load_simulation,
                                        measure_step_cost, unknown_parameters, warm_commands)
from tensegrity_ros.node.publishing import Publishing
from tensegrity_ros.node.realtime import RealTime
from tensegrity_ros.node.recorders import open_recorders
from tensegrity_ros.node.stepping import Stepper, StepService



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
        # rclpy has no public read of the start-up overrides (-p, parameters file,
        # parameter_overrides) before a declaration: unknown names and bad values are refused
        # here with our message, before rclpy's range check at declaration gives its own
        overrides = self._parameter_overrides
        unknown = unknown_parameters(overrides)
        if unknown is not None:
            raise unknown
        check_parameters({n: overrides[n].value if n in overrides else d
                          for n, d in DEFAULTS.items()})
        for name, default in DEFAULTS.items():
            self.declare_parameter(name, default, descriptor(name))
        self.params = check_parameters({n: self.get_parameter(n).value for n in DEFAULTS})
        self.add_on_set_parameters_callback(lambda ps: check_changes(self.params, ps))
        self.add_post_set_parameters_callback(lambda ps: apply_changes(self, ps))
        self.period = 1.0 / self.params['publish_rate_hz']
        self._given_sim = sim
        self.sim = self.timer = None
        self.active = False
        self.pubs, self._srvs = {}, []
        self.sinks = FanOut(lambda sink, exc: self.get_logger().error(
            f'recorder {sink!r} failed and was removed: {exc}'))
        self.log = ThrottledLog(self.get_logger(), LOG_THROTTLE_S)
        if self.params['autostart']:
            self._setup()          # a bad scene raises here (the console script exits 2)
            for name, trigger in (('configure', self.trigger_configure),
                                  ('activate', self.trigger_activate)):
                if trigger() != TransitionCallbackReturn.SUCCESS:
                    raise RuntimeError(f'{messages.NODE_NAME}: {name} failed (see the log)')

    # every path of set_parameters goes through this private hook of rclpy, which has no public
    # one before its own message (that lists no valid names): unknown names refused by name
    def _check_undeclared_parameters(self, parameter_list):
        from tensegrity_ros.node.params import refuse_undeclared
        names = [p.name for p in parameter_list]
        refuse_undeclared(names, [n for n in names if self.has_parameter(n)])
        super()._check_undeclared_parameters(parameter_list)     # (the hook's own check)

    # -- lifecycle (each transition logs one line: INFO when it succeeds, ERROR else) ----------
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
        self.restart_pace()
        self.publishing.structure()
        self.publishing.frame(time.monotonic())
        # the wall (steady) clock: with use_sim_time the node's clock follows /clock, which only
        # this node publishes, so a timer on it would wait forever
        self.timer = self.create_timer(self.period, self._tick,
                                       clock=Clock(clock_type=ClockType.STEADY_TIME))
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
        return self._down('cleaned up (unconfigured): the simulation is dropped, the recorders '
                          'closed')

    def on_shutdown(self, state):
        return self._down(f'shutdown (the node was {state.label}): the recorders closed')

    def on_error(self, state):
        return self._down(f'error in a transition from {state.label}: torn down to '
                          f'unconfigured, the recorders closed', error=True)

    def _down(self, text, error=False):
        """Back to parameters only: what configure built is destroyed, the recorders closed."""
        self.active = False
        self._drop_timer()
        self.close()
        if self.sim is not None:
            endpoints.destroy(self, self.pubs, self.intake.subscriptions, self._srvs)
        self.pubs, self._srvs, self.sim = {}, [], None
        (self.get_logger().error if error else self.get_logger().info)(text)
        return TransitionCallbackReturn.SUCCESS

    def _drop_timer(self):
        if self.timer is not None:
            self.timer.cancel()
            self.destroy_timer(self.timer)
            self.timer = None

    def _setup(self):
        """What configure builds: the simulation (the caller's, in its state, or the one the
        parameters describe), the parts, recorders, publishers, subscriptions and services."""
        from solver import is_array
        sim = self._given_sim
        if sim is None:
            self.get_logger().info(
                f'{find_config(self.params["scene_file"])}: loading the scene and compiling the '
                f'solver (from the numba cache if compiled before; a first start after an '
                f'install or a change of solver/ compiles for a minute or more)')
            sim = load_simulation(self.params)
            step_cost = measure_step_cost(sim)
            warm_commands(sim)
        else:                      # a caller's simulation, in its state: start cautiously
            step_cost = 0.1 * self.period
        self.sim, net = sim, sim.network
        self.episode, self.t_offset = 0, 0.0       # the clock: t_offset + the episode's sim.t
        self.cross_prism = sim.prestrain_map.cross_prism if sim.prestrain is not None else None
        self.t_max = style.reference_tension_scale(net)
        self.running, self.problem = not self.params['start_paused'], ''
        self.divergences, self.last_divergence = 0, None
        self.pacer = Pacer(self.period, step_cost, fill=not is_array(sim.scene))
        self.realtime = RealTime(step_cost, net.n_columns, net.n_nodes)
        self.intake, self.focus = Intake(self), Focus(self)
        self.counts = self.intake.counts
        self.stepper = Stepper(sim, self.focus if is_array(sim.scene) else None)
        self.publishing = Publishing(self)
        self.topics = {key: self.resolve_topic_name(key) for key in messages.TYPES}
        stepping = StepService(self.stepper, lambda: self.running, self.advance, self.clock_time,
                               lambda: self.sim.dt, self.event)
        try:
            self.pubs, self.intake.subscriptions, self._srvs = endpoints.create(
                self, sim.striker() is not None, {'~/reset': self._on_reset,
                                                  '~/set_running': self._on_set_running,
                                                  '~/step': stepping})
        except ParameterError:
            self.sim = None
            raise
        self.pacer.anchor(sim.t, time.monotonic())
        for sink in open_recorders(self.params, sim, self.topics, self.pubs, self.t_max):
            self.add_sink(sink)
        self.get_logger().info(
            f'{sim.scene.name}: {net.n_nodes} nodes, {net.n_cables} cables, {sim.model.name} + '
            f'{sim.integrator.name}, dt = {sim.dt:g} s, publishing at '
            f'{self.params["publish_rate_hz"]:g} Hz, real-time factor '
            f'{self.params["real_time_factor"]:g}')

    def add_sink(self, sink):
        """Record the node's traffic with ``sink`` (see :mod:`tensegrity_ros.io.sinks`)."""
        return self.sinks.add(sink)

    def close(self):
        """Close the recorders (idempotent)."""
        self.sinks.close()

    # -- the tick -------------------------------------------------------------------------------
    def _tick(self):
        now = time.monotonic()
        until = self.timer.time_until_next_call() if self.timer is not None else None
        deadline = now + (until * 1e-9 if until is not None else self.period)
        self.intake.take()
        self.intake.apply()
        if self.running:
            n = self.stepper.limit(self.steps_this_tick(time.monotonic(), deadline))
            if n is None:                          # the planned impact was made: step on
                n = self.steps_this_tick(time.monotonic(), deadline)
            if n > 0:
                self.advance(n, now)
        self.intake.cmd_wall = 0.0
        self.intake.tally.flush(now)
        if now - self.publishing.last_diag >= 1.0 / self.params['diagnostics_rate_hz']:
            self.publishing.diagnostics(now)
        self.publishing.tick_max_s = max(self.publishing.tick_max_s, time.monotonic() - now)

    def steps_this_tick(self, now, deadline=None):
        """Steps to take now (:meth:`tensegrity_ros.node.pacing.Pacer.steps`)."""
        self.pacer.cmd_wall = self.intake.cmd_wall
        return self.pacer.steps(now, self.sim.t, self.sim.dt, self.params['real_time_factor'],
                                deadline, self.publishing.markers_due(now))

    def advance(self, n, now):
        """``n`` steps (a fraction of one: ``n`` < 1), then the frame; False on a divergence
        (handled as ``on_divergence`` says: :meth:`diverged`)."""
        t0 = time.perf_counter()
        try:
            taken = self.stepper.advance(n)
        except SimulationDiverged as exc:
            self.diverged(str(exc), exc.t)
            if self.running:                # reset: the rest state goes out at once
                self.publishing.frame(now)
            return False
        self.pacer.stepped(taken, time.perf_counter() - t0)
        ok = self.publishing.frame(now)
        self.stepper.after(now)
        return ok

    def restart_pace(self):
        """The pace and the measured rates count from now (activation, resume, reset)."""
        now = time.monotonic()
        self.pacer.anchor(self.sim.t, now)
        self.publishing.restart_window(now)
        self.realtime.restart()

    def pause(self, why):
        """Stop stepping and say why (log, event, ``/diagnostics`` at once)."""
        self.running, self.problem = False, why
        self.log('pause', 'error', why)
        self.event(why)
        self.publishing.diagnostics(time.monotonic())

    def diverged(self, text, t):
        """The simulation diverged at simulation time ``t`` (``text``: the solver's
        :class:`SimulationDiverged`, or a frame that is not finite; the state is the last good
        one): counted and kept for ``/diagnostics``; then ``on_divergence``: ``pause`` stops the
        clock (:meth:`pause`), ``reset`` puts the simulation back to its rest state in a new
        episode and the node steps and publishes on. Either way an ERROR log line and an ERROR
        ``/diagnostics`` status name it at once."""
        self.focus.record = None
        action = self.params['on_divergence']
        self.divergences += 1
        self.last_divergence = {'wall': time.monotonic(), 'sim_time_s': self.clock_time(t),
                                'text': text, 'action': action, 'reported': False}
        if action == 'pause':
            self.pause(f'paused: {text}')
            return
        self.log('divergence', 'error', f'{text}; reset to the rest state, episode '
                 f'{self.episode + 1} (on_divergence: reset)')
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
        """An event (a command applied or rejected, a reset, a pause, a step) at the clock time
        now: on ``~/events`` and to the recorders."""
        t = self.clock_time()
        msg = String(data=text)
        self.pubs['~/events'].publish(msg)
        self.sinks.message(self.topics['~/events'], msg,
                           messages.stamp_to_ns(messages.sim_stamp(t)))
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
        self.restart_pace()
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
            self.restart_pace()
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
    finishes first); exit 2 with one line on stderr for an argument that is not a ROS argument,
    a bad parameter or scene."""
    from solver import NetworkError
    from solver import SceneError
    from rclpy._rclpy_pybind11 import UnknownROSArgsError     # (no public name either)
    from rclpy.utilities import remove_ros_args
    argv = list(sys.argv if args is None else args)
    try:
        extra = remove_ros_args(argv)[1:]
        if extra:                   # rclpy would pass them by: refuse them instead
            raise UnknownROSArgsError(f'unknown argument{"s" if len(extra) > 1 else ""} '
                                      f'{" ".join(extra)}')
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except (RCLError, UnknownROSArgsError) as exc:
        text = str(exc).split(', at ')[0].splitlines()[0]
        if text.startswith('['):    # rcl's list of unknown flags after --ros-args
            text = f'unknown ROS argument {text.strip("[]")}'
        print(f'tensegrity_node: {text} (the node takes ROS arguments only: --ros-args '
              f'-p NAME:=VALUE --params-file FILE -r __ns:=/NAMESPACE)', file=sys.stderr)
        return 2
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
