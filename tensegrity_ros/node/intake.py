"""The node's command intake: commands are taken by the tick, checked at once, applied by the tick.

The executor never runs the command subscriptions (:class:`TakenByTick`); each tick takes every
command waiting (:meth:`Intake.take`), validates, counts and records each one, and applies the
last valid one per topic (:meth:`Intake.apply`; the others count as superseded), so a flood of
commands cannot starve the simulation and no command races a step. While the node is paused, a
valid command is rejected (:meth:`Intake.paused`): applied to the frozen state, impacts would
stack up unseen until the clock starts.
"""
from __future__ import annotations

import math
import re
import time

from rclpy.callback_groups import CallbackGroup

from tensegrity_ros.msgs import messages
from tensegrity_ros.node import commands
from tensegrity_ros.node.params import LOG_THROTTLE_S

MAX_TAKE = 100                   # commands per topic taken at the start of a tick, at most


class Paused(commands.CommandError):
    """A valid command that arrived while the node is paused; the message says why."""


class TakenByTick(CallbackGroup):
    """The callback group of the command subscriptions: the executor never waits on them or runs
    their callbacks; each tick takes what is waiting. A flood of commands then costs no executor
    cycle per message (the wait set rebuilt in Python, a task per message) and never delays a
    tick."""

    def can_execute(self, entity):
        return False

    def beginning_execution(self, entity):
        return False

    def ending_execution(self, entity):
        pass


class RejectionTally:
    """The log of rejected commands: the first of a quiet second at once, then, once a second,
    one line with the count of each reason since (a reason: its text with the numbers masked,
    shown by its last example), so that a burst is reported whole and never only by its
    first command. ``logger()``: the logger to write to (looked up at each line)."""

    NUMBER = re.compile(r'[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?')

    def __init__(self, logger, interval_s=LOG_THROTTLE_S):
        self.logger, self.interval_s = logger, interval_s
        self.last = -math.inf                  # wall time of the last line
        self.counts, self.examples = {}, {}

    def add(self, text, now):
        """A command rejected at wall time ``now`` because of ``text``."""
        if not self.counts and now - self.last >= self.interval_s:
            self.last = now
            self.logger().warning(f'rejected {text}')
            return
        key = self.NUMBER.sub('#', text)
        self.counts[key] = self.counts.get(key, 0) + 1
        self.examples[key] = text

    def flush(self, now):
        """The line of the rejections since the last one, when a second has passed."""
        if not self.counts or now - self.last < self.interval_s:
            return
        total = sum(self.counts.values())
        parts = [f'{n} x {self.examples[k]}' for k, n in
                 sorted(self.counts.items(), key=lambda kv: -kv[1])]
        self.logger().warning(f'rejected {total} more command{"s" if total > 1 else ""} in the '
                              f'last {now - self.last:.1f} s: ' + '; '.join(parts))
        self.last = now
        self.counts, self.examples = {}, {}


class Intake:
    """Commands of node ``node``. ``counts``: accepted (applied), superseded (valid, replaced by a
    later one of the same topic before the next tick), rejected (malformed, or refused when
    applied), frames; ``last_command`` (topic, accepted/rejected, detail) and its clock time
    ``last_command_t`` (:meth:`TensegritySim.clock_time`); ``pending`` topic -> ``apply()`` of its
    last valid command since a tick; ``cmd_wall`` the wall seconds the commands took since the
    last tick."""

    def __init__(self, node):
        self.node = node
        self.subscriptions = []                # (subscription, handler)
        self.counts = {'accepted': 0, 'rejected': 0, 'superseded': 0, 'frames': 0}
        self.last_command = ('none', 'none', '')
        self.last_command_t = math.nan
        self.pending = {}
        self.cmd_wall = 0.0
        self.rejected_since = 0                # rejections not yet reported on /diagnostics
        self._last_reject_event = -math.inf
        self.tally = RejectionTally(lambda: node.log.logger)
        self.handlers = {'~/cmd/impact': self.impact, '~/cmd/prestrain': self.prestrain,
                         '~/cmd/focus': self.focus}

    def _command(self, key, msg, check):
        """A command received on ``key``: recorded, validated at once (``check()`` returns the
        ``apply()`` that changes the simulation, or raises), counted; a valid one replaces the
        topic's pending command. Returns whether it was valid."""
        node = self.node
        w0 = time.perf_counter()
        node.sinks.message(node.topics[key], msg,
                           messages.stamp_to_ns(messages.sim_stamp(node.clock_time())))
        try:
            apply = check()
            self.refuse_if_paused(key)
        except (commands.CommandError, ValueError) as exc:
            self.reject(key, exc)
            ok = False
        else:
            if self.pending.pop(key, None) is not None:
                self.counts['superseded'] += 1
            self.pending[key] = apply
            ok = True
        self.cmd_wall += time.perf_counter() - w0
        return ok

    def refuse_if_paused(self, key):
        """Raise :class:`Paused` while the node is paused: a command is then rejected, never
        applied to the frozen state."""
        node = self.node
        if node.running:
            return
        why = 'paused by a divergence' if node.problem else 'paused'
        raise Paused(f'{key}: {why}, not applied (commands would stack on the frozen state); '
                     f'send ~/set_running true first')

    def reject(self, key, exc):
        node = self.node
        text = str(exc) if str(exc).startswith('~/') else f'{key}: {exc}'
        self.counts['rejected'] += 1
        self.rejected_since += 1
        self.last_command = (key, 'rejected', text)
        now = time.monotonic()
        self.tally.add(text, now)
        if now - self._last_reject_event >= LOG_THROTTLE_S:       # events: throttled as well
            self._last_reject_event = now
            node.event(f'rejected {text}')

    def take(self):
        """Take every command waiting in the subscriptions now (each through its handler): what
        the subscriptions' QoS history keeps, the last 10 per topic by default."""
        for sub, handler in self.subscriptions:
            for _ in range(MAX_TAKE):
                # rclpy has no public take of a subscription's message outside the executor
                # (its executor's own take goes through this handle): the tick takes them here
                with sub.handle:
                    got = sub.handle.take_message(sub.msg_type, sub.raw)
                if got is None:
                    break
                handler(got[0])

    def apply(self):
        """Apply the last valid command per topic that arrived since the previous tick (rejected
        if the node was paused since it arrived)."""
        node = self.node
        pending, self.pending = self.pending, {}
        for key, apply in pending.items():
            try:
                self.refuse_if_paused(key)
                detail = apply()
            except (commands.CommandError, ValueError) as exc:
                self.reject(key, exc)
                continue
            self.counts['accepted'] += 1
            node.pacer.changed()                # the cost of a step may have changed
            self.last_command = (key, 'accepted', detail)
            self.last_command_t = node.clock_time()
            node.log('accepted', 'info', f'{key}: {detail}')
            node.event(f'{key}: {detail}')

    # -- the topics -----------------------------------------------------------------------------
    def impact(self, msg):
        """``~/cmd/impact``: v0 m/s, one value or one per column."""
        node = self.node

        def check():
            v0 = commands.parse_impact(msg.data, msg.layout, node.sim.network.n_columns)

            def apply():
                added = node.sim.apply_impact(float(v0[0]) if v0.size == 1 else v0)
                node.focus.start_record()
                return f'impact v0 = {commands.describe(v0)} m/s, kinetic energy +{added:.3g} J'
            return apply
        return self._command('~/cmd/impact', msg, check)

    def prestrain(self, msg):
        """``~/cmd/prestrain``: cross prestrain, ramped in over ``prestrain_ramp_s``."""
        node = self.node

        def check():
            if node.cross_prism is None:
                raise commands.CommandError('~/cmd/prestrain: this scene is not a column of '
                                            'prisms; prestrain commands need one')
            if node.sim.model.name == 'chain1d':
                raise commands.CommandError('~/cmd/prestrain: the chain1d model cannot change its '
                                            'prestrain (its force law is precomputed for the '
                                            'scene); use model full3d or sym3d')
            net = node.sim.network
            p = commands.parse_prestrain(msg.data, msg.layout, net.n_columns, net.n_prisms,
                                         node.cross_prism)

            def apply():
                ramp = node.params['prestrain_ramp_s']
                node.sim.apply_prestrain(p, ramp_s=ramp)
                return (f'prestrain per column {commands.describe(p.mean(axis=1))} over '
                        f'{ramp:g} s')
            return apply
        return self._command('~/cmd/prestrain', msg, check)

    def focus(self, msg):
        """``~/cmd/focus``: see :class:`tensegrity_ros.node.focus.Focus`."""
        return self._command('~/cmd/focus', msg, lambda: self.node.focus.check(msg))
