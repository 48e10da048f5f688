"""The real-time factor the node achieves, told honestly: measured over a sliding window of wall
time, compared with the target, and when it falls below :data:`BEHIND` of the target a WARN
status naming why (contact sub-steps, the size of an array, or the publishing) and one log line.

No ROS: the node hands it the wall and clock times of its frames and the costs its pacer
measured (:class:`tensegrity_ros.node.pacing.Pacer`).
"""
from __future__ import annotations

import math
from collections import deque

WINDOW_S = 2.0                   # wall seconds the achieved factor is measured over
MIN_SPAN_S = 1.0                 # a factor is reported once the window spans this much
BEHIND = 0.9                     # WARN below this share of the target
LOG_EVERY_S = 30.0               # while behind, the WARN log line again after this long
CONTACT_COST = 2.0               # a step costing this many times its cost at rest: contact


class RealTime:
    """``sample(now, t)`` after each frame while running (wall s, clock s); ``factor()`` the
    simulated seconds per wall second over the last :data:`WINDOW_S`; ``status(...)`` the WARN
    of ``/diagnostics`` while behind. ``rest_step_cost`` (s): a step's cost at the start (at
    rest); ``n_columns``, ``n_nodes``: the size of the scene, for the reason."""

    def __init__(self, rest_step_cost, n_columns, n_nodes, window_s=WINDOW_S):
        self.rest_step_cost, self.n_columns, self.n_nodes = rest_step_cost, n_columns, n_nodes
        self.window_s = window_s
        self.samples = deque()
        self.span_s = 0.0                # wall seconds the last factor was measured over
        self.behind_since = None
        self._last_log = -math.inf

    def restart(self):
        """Measure from the next sample on (activation, resume, reset; the node's first sample
        after an activation is its first tick's frame)."""
        self.samples.clear()
        self.behind_since = None

    def shift(self, dt):
        """The clock jumped by ``dt`` (a reset after a divergence): the window counts the time
        simulated before the jump as if the clock had not jumped."""
        self.samples = deque((w, t + dt) for w, t in self.samples)

    def sample(self, now, t):
        """A frame at wall time ``now`` (monotonic s) and clock time ``t`` (s)."""
        s = self.samples
        s.append((now, t))
        while len(s) > 2 and s[1][0] <= now - self.window_s:
            s.popleft()

    def factor(self):
        """The achieved real-time factor over the window, or None before it spans
        :data:`MIN_SPAN_S`."""
        if len(self.samples) < 2:
            return None
        (w0, t0), (w1, t1) = self.samples[0], self.samples[-1]
        self.span_s = w1 - w0
        return (t1 - t0) / (w1 - w0) if w1 - w0 >= MIN_SPAN_S else None

    def reason(self, target, dt, step_cost, publish_cost, rate_hz, call_cost=0.0):
        """Why the node is behind: a step's wall cost now against its cost at rest and against
        the wall time real time allows it (``dt / target``), and the share of the wall time the
        steps and ``rate_hz`` frames need at the target (each frame's tick one stepping call,
        which costs ``call_cost`` however few its steps)."""
        allowed = dt / target
        cost = f'a step of {dt * 1e3:.3g} ms costs {step_cost * 1e3:.3g} ms of wall time'
        need = step_cost / allowed + (publish_cost + call_cost) * rate_hz
        if step_cost > CONTACT_COST * self.rest_step_cost and step_cost > allowed * BEHIND:
            return (f'contact sub-steps: {cost}, {step_cost / self.rest_step_cost:.3g}x its '
                    f'cost at rest')
        if self.rest_step_cost > allowed * BEHIND:
            return (f'array size: {self.n_columns} column{"s" if self.n_columns > 1 else ""} of '
                    f'{self.n_nodes} nodes in all; {cost} at rest, {allowed * 1e3:.3g} ms '
                    f'allowed')
        if need <= BEHIND:
            return (f'CPU time: stepping and publishing need {100 * need:.0f} % of the wall '
                    f'time at this pace, and the node got less (other processes, or a long '
                    f'callback)')
        call = (f' and {call_cost * 1e3:.3g} ms per stepping call however few its steps'
                if call_cost > 0.0 else '')
        return (f'publishing: {cost}, {publish_cost * 1e3:.3g} ms per frame to publish{call} at '
                f'{rate_hz:g} Hz')

    def status(self, now, target, running, dt, step_cost, publish_cost, rate_hz, call_cost=0.0):
        """``(message, log_line)`` while running below :data:`BEHIND` of a target > 0 (the log
        line None when one went out less than :data:`LOG_EVERY_S` ago in the same spell), else
        ``(None, None)``."""
        f = self.factor()
        if not running or target <= 0 or f is None or f >= BEHIND * target:
            self.behind_since = None
            return None, None
        message = (f'behind real time: {f:.3g}x achieved over the last {self.span_s:.2g} s, '
                   f'target {target:g}x; '
                   f'{self.reason(target, dt, step_cost, publish_cost, rate_hz, call_cost)}')
        log = None
        if self.behind_since is None or now - self._last_log >= LOG_EVERY_S:
            self._last_log = now
            log = message + ' (a command lands at the simulation time reached when it is taken)'
        if self.behind_since is None:
            self.behind_since = now
        return message, log
