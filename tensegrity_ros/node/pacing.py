"""How many steps a tick of the node takes: the pace of ``real_time_factor`` within a work budget.

Pure arithmetic on wall-clock and simulation times, no ROS: the node hands it the times, the
costs it measured (moving averages of a step, of publishing a frame and of the markers) and the
wall time its command callbacks took since the last tick.
"""
from __future__ import annotations

import math

WORK_FRACTION = 0.9              # share of a publish period the stepping (and publishing) may use
FAST_WORK_FRACTION = 1.0         # at real_time_factor 0: share of the time left until the next
                                 # tick is due (no pace to keep, no margin)
MIN_WORK_FRACTION = 0.2          # a tick steps at least this share of a period
SMOOTHING = 0.2                  # weight of a new measurement in the moving averages
MIN_STEP_FRACTION = 1.0 / 256    # the shortest step a tick takes when a whole one does not fit


class Pacer:
    """The pace: ``anchor_wall`` (monotonic s) and ``anchor_t`` (simulation s) of the last
    re-anchoring, and the measured costs, s: ``step_cost`` per step, ``publish_cost`` per frame,
    ``marker_cost`` extra for the markers, ``cmd_wall`` of commands since the last tick."""

    def __init__(self, period, step_cost):
        self.period, self.step_cost = period, step_cost
        self.publish_cost = self.marker_cost = self.cmd_wall = 0.0
        self.anchor_wall = self.anchor_t = 0.0

    def anchor(self, t_sim, now):
        """The pace counts from simulation time ``t_sim`` at wall time ``now``."""
        self.anchor_wall, self.anchor_t = now, t_sim

    def steps(self, now, t_sim, dt, rtf, deadline=None, markers=False):
        """Steps to take now: towards the paced target time, capped by the work budget. At
        ``rtf`` 0 the budget is the time left until ``deadline`` (wall time the next tick is due;
        default one period from ``now``) less the cost of publishing: a tick that started late,
        or spent time on commands, steps less, so that the next one starts on time and the
        publish rate holds. ``markers``: the frame of this tick carries markers.

        Whole steps (an int) while one fits in the budget; when a single step costs more (a
        column in lasting contact), the fraction of a step that fits (a float in
        [:data:`MIN_STEP_FRACTION`, 1), for :meth:`Simulation.advance_part`)."""
        publish = self.publish_cost + (self.marker_cost if markers else 0.0)
        if rtf <= 0:
            left = self.period if deadline is None else deadline - now
            budget = max(FAST_WORK_FRACTION * left - publish, MIN_WORK_FRACTION * self.period)
            return self._fit(budget)
        # paced, a tick keeps a margin so that it ends before the next one is due
        budget = max(WORK_FRACTION * self.period - publish - self.cmd_wall,
                     MIN_WORK_FRACTION * self.period)
        cap = self._fit(budget)
        target = self.anchor_t + rtf * (now - self.anchor_wall)
        want = int(math.floor((target - t_sim) / dt + 1e-9))
        if want > cap:                 # cannot keep up: do what fits, do not accumulate debt
            self.anchor(t_sim + cap * dt, now)
            return cap
        return max(want, 0)

    def _fit(self, budget):
        """The steps that fit in ``budget`` s: whole ones, or the fraction of one."""
        fits = budget / max(self.step_cost, 1e-9)
        return int(fits) if fits >= 1.0 else max(fits, MIN_STEP_FRACTION)

    def stepped(self, n, seconds):
        """``n`` steps (a fraction of one included) took ``seconds``."""
        self.step_cost = (1 - SMOOTHING) * self.step_cost + SMOOTHING * seconds / n

    def published(self, seconds, markers):
        """Publishing a frame took ``seconds`` (with ``markers``: the markers' part on top)."""
        if markers:
            self.marker_cost = ((1 - SMOOTHING) * self.marker_cost
                                + SMOOTHING * max(seconds - self.publish_cost, 0.0))
        else:
            self.publish_cost = (1 - SMOOTHING) * self.publish_cost + SMOOTHING * seconds
