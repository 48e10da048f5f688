"""How the node advances its simulation: each tick as paced, and by request while paused.

:class:`Stepper` steps the simulation itself, and through the lens part
(:class:`tensegrity_ros.node.focus.Focus`) only for an array, whose planned impact and impact
record need each step. :class:`StepService` answers ``~/step``: while the node is paused it
advances by a number of steps or by a duration of simulation time, publishing (and recording) the
frame of every step, and answers when the steps are done, as the ``StepSimulation`` service of
ROS 2's ``simulation_interfaces`` does (docs/node.md, Stepping while paused).
"""
from __future__ import annotations

import math
import time

MAX_STEPS = 100_000              # steps one request may ask for (the executor waits for them)
PART_TOL = 1e-9                  # a duration within this share of a step of a whole number


def step(sim, n):
    """Advance ``sim`` by ``n`` steps: ``n`` < 1, one step shortened to that fraction of ``dt``;
    a float above 1, its whole steps, then the fraction of one more."""
    whole = int(n)
    if whole >= 1:
        sim.advance(whole * sim.dt)
    if n - whole > 0.0:
        sim.advance_part(n - whole)


class StepError(ValueError):
    """A ``~/step`` request that cannot be done; the message says why."""


class Stepper:
    """Steps ``sim``; ``lens``: the node's :class:`Focus` for an array (its planned impact lands
    on a step, its record samples every step), None for any other scene."""

    def __init__(self, sim, lens):
        self.sim, self.lens = sim, lens

    def limit(self, n):
        """At most ``n`` steps, so that a planned impact of the lens lands on a step (None: it
        was made now, ask again); the lens steps whole steps or a fraction of one."""
        if self.lens is None:
            return n
        return self.lens.steps_until_impact(int(n) if n >= 1 else n)

    def advance(self, n):
        """``n`` steps (``n`` < 1: one step shortened to that fraction of ``dt``; a float above
        1: its whole steps, then the fraction of one more); returns the steps taken (the lens
        takes a whole step for a fraction while it records)."""
        if self.lens is not None:
            return self.lens.advance(n)
        step(self.sim, n)
        return n

    def after(self, now):
        """Once per stepping: the lens's figures and field when they are due."""
        if self.lens is not None:
            self.lens.after_steps(now)

    @property
    def whole_steps_only(self):
        """True while the lens records or plans an impact (it steps whole steps)."""
        return self.lens is not None and (self.lens.record is not None
                                          or self.lens.impact_at is not None)


def parse_request(parameters, dt):
    """``(whole steps, fraction of a last step)`` of a ``~/step`` request: exactly one of the
    parameters ``steps`` (integer >= 1) or ``duration_s`` (seconds of simulation time > 0, a
    float or an integer). Raises :class:`StepError`."""
    from rcl_interfaces.msg import ParameterType
    if len(parameters) != 1 or parameters[0].name not in ('steps', 'duration_s'):
        names = ', '.join(p.name for p in parameters) or 'none'
        raise StepError(f'~/step: give exactly one of steps (integer) or duration_s (seconds), '
                        f'got {names}')
    p = parameters[0]
    kind = p.value.type
    if p.name == 'steps':
        if kind != ParameterType.PARAMETER_INTEGER:
            raise StepError('~/step: steps must be an integer parameter')
        n, part = int(p.value.integer_value), 0.0
        if n < 1:
            raise StepError(f'~/step: steps must be >= 1, got {n}')
    else:
        if kind == ParameterType.PARAMETER_DOUBLE:
            d = float(p.value.double_value)
        elif kind == ParameterType.PARAMETER_INTEGER:
            d = float(p.value.integer_value)
        else:
            raise StepError('~/step: duration_s must be a number of seconds')
        if not (math.isfinite(d) and d > 0):
            raise StepError(f'~/step: duration_s must be a positive number of seconds, got {d!r}')
        whole = d / dt
        n = int(math.floor(whole + PART_TOL))
        part = whole - n if whole - n > PART_TOL else 0.0
    if n > MAX_STEPS:
        raise StepError(f'~/step: {n} steps asked, at most {MAX_STEPS} per request (dt = '
                        f'{dt:g} s)')
    return n, part


class StepService:
    """The handler of ``~/step`` (``rcl_interfaces/srv/SetParameters``: one parameter, ``steps``
    or ``duration_s``; the answer's one result says what was done or why not). It uses only what
    it is handed: the :class:`Stepper`, ``running()`` (the node's clock runs), ``advance(n, now)``
    (steps and the frame after them; False on a divergence), ``clock()`` (the clock time, s),
    ``dt()`` and ``event(text)``."""

    def __init__(self, stepper, running, advance, clock, dt, event):
        self.stepper, self.running, self.advance = stepper, running, advance
        self.clock, self.dt, self.event = clock, dt, event

    def __call__(self, request, response):
        from rcl_interfaces.msg import SetParametersResult
        ok, text = self.step(request.parameters)
        response.results = [SetParametersResult(successful=ok, reason=text)]
        return response

    def step(self, parameters):
        """``(done, text)`` of a request."""
        dt = self.dt()
        try:
            if self.running():
                raise StepError('~/step: the clock is running; pause it first '
                                '(~/set_running false), then step')
            n, part = parse_request(parameters, dt)
            if part and self.stepper.whole_steps_only:
                raise StepError(f'~/step: an impact of the array is planned or recorded, which '
                                f'steps whole steps; ask for a multiple of dt = {dt:g} s')
        except StepError as exc:
            return False, str(exc)
        t0 = self.clock()
        done = 0
        for k in range(n + (1 if part else 0)):
            size = 1 if k < n else part
            if k < n:
                self.stepper.limit(1)            # a planned impact due now is made first
            if not self.advance(size, time.monotonic()):
                return False, (f'~/step: the simulation diverged after {done} of {n} steps; '
                               f'see ~/events and /diagnostics')
            done += 1
        t1 = self.clock()
        text = (f'stepped {n} step{"s" if n != 1 else ""} of {dt:g} s'
                + (f' and a last one of {part * dt:.9g} s' if part else '')
                + f' while paused: clock {t0:.9f} -> {t1:.9f} s')
        self.event(text)
        return True, text
