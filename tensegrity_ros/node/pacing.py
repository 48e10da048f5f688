"""How many steps a tick of the node takes: the pace of ``real_time_factor`` within a work budget.

Pure arithmetic on wall-clock and simulation times, no ROS: the node hands it the times, the
costs it measured (moving averages of a step, of publishing a frame and of the markers) and the
wall time its command callbacks took since the last tick.

A tick takes whole steps while one fits in its budget; at ``real_time_factor`` 0, for a single
simulation (``fill``: not an array, whose fractions cost about a whole step), when only a few fit
(fewer than :data:`FILL_BELOW`: steps in lasting contact), it fills what they leave of its budget
with a fraction of a further step, instead of waiting for the next tick. When a whole step costs
more than the budget (a column in lasting contact takes hundreds of contact sub-steps per
step), it takes one step shortened to a fraction ``f`` of ``dt``
(:meth:`Simulation.advance_part`), whose cost the pacer predicts as ``F + f (C - F)``: ``C`` the
cost of a whole step, ``F`` the floor, what a fraction costs however short. A single column in
contact has a floor near 0 (its cost follows ``f``); an array has a large one, since each column
out of contact takes a whole integrator step and each column costs its per-call overhead whatever
the fraction.

- ``C`` follows the whole steps the node takes. A fractional step moves it towards the smaller
  of its cost over ``f`` (a bound from above: the ticks return to whole steps when the contact
  ends) and the cost of a step in the last whole steps taken. A fraction that costs more than
  ``f C`` so never makes a whole step look dearer than the last whole steps were, and the
  fraction does not shrink towards :data:`MIN_STEP_FRACTION` while simulated time stops.
- ``F`` follows the difference between the cost of each fractional step and its prediction
  (``F`` at most ``C``); each whole step shrinks it by the weight :data:`SMOOTHING`, so that
  fractions are tried again.
- The fraction is the largest whose predicted cost fits in the budget, or in
  :data:`FLOOR_MULTIPLE` times the floor when that is larger: a floor near or above the budget
  leaves the fraction about half of the tick, and simulated time keeps about half the pace of
  whole steps. A floor of half a whole step's cost or more makes the tick take a whole step; so
  do fractional steps that cost more than predicted by :data:`EXCESS_RECHECK` on average (a
  whole step costs more than the last whole steps did: this one measures it).
"""
from __future__ import annotations

import math

WORK_FRACTION = 0.9              # share of a publish period the stepping (and publishing) may use
FAST_WORK_FRACTION = 1.0         # at real_time_factor 0: share of the time left until the next
                                 # tick is due (no pace to keep, no margin)
MIN_WORK_FRACTION = 0.2          # a tick steps at least this share of a period
SMOOTHING = 0.2                  # weight of a new measurement in the moving averages
MIN_STEP_FRACTION = 1.0 / 256    # the shortest step a tick takes when a whole one does not fit
FLOOR_MULTIPLE = 2.0             # a fractional step may cost this many times the floor, when
                                 # that exceeds the budget
EXCESS_RECHECK = 0.25            # fractional steps costing this share more than predicted (a
                                 # moving average, each share at most 1): the next tick takes a
                                 # whole step, which measures the cost of one
FILL_BELOW = 4                   # at real_time_factor 0, a tick that fits fewer whole steps
                                 # than this fills the rest of its budget with a fraction
MIN_FILL = 0.1                   # the shortest fraction a tick adds to its whole steps


class Pacer:
    """The pace: ``anchor_wall`` (monotonic s) and ``anchor_t`` (simulation s) of the last
    re-anchoring; ``fill``: whether a tick at ``real_time_factor`` 0 fills its budget with a
    fraction of a step after its whole steps (:meth:`_fill`); and the measured costs, s:
    ``step_cost`` per whole step (moving average), ``whole_cost`` per step of the last whole
    steps taken, ``floor_cost`` of a fraction of a step however short (at most ``step_cost``),
    ``excess`` the moving average of the share by which fractional steps cost more than
    predicted, ``publish_cost`` per frame, ``marker_cost`` extra for the markers, ``cmd_wall`` of
    commands since the last tick."""

    def __init__(self, period, step_cost, fill=False):
        self.period, self.step_cost, self.whole_cost = period, step_cost, step_cost
        self.fill = fill
        self.floor_cost = self.excess = 0.0
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
        [:data:`MIN_STEP_FRACTION`, 1), for :meth:`Simulation.advance_part`), or one whole step
        where fractions do not pay (:meth:`_fit`). At ``rtf`` 0, whole steps and a fraction of
        one more (a float above 1) where :meth:`_fill` adds one."""
        publish = self.publish_cost + (self.marker_cost if markers else 0.0)
        if rtf <= 0:
            left = self.period if deadline is None else deadline - now
            budget = max(FAST_WORK_FRACTION * left - publish, MIN_WORK_FRACTION * self.period)
            n = self._fit(budget)
            return n + self._fill(n, budget) if n >= 1 else n
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
        """The steps that fit in ``budget`` s: whole ones; else the largest fraction ``f`` whose
        predicted cost ``F + f (C - F)`` is at most ``budget`` or :data:`FLOOR_MULTIPLE` ``F``,
        whichever is larger; one whole step when that fraction reaches 1, or while fractional
        steps cost more than predicted (``excess`` above :data:`EXCESS_RECHECK`)."""
        whole, floor = self._costs()
        fits = budget / whole
        if fits >= 1.0:
            return int(fits)
        allowed = max(budget, FLOOR_MULTIPLE * floor)
        if allowed >= whole or self.excess > EXCESS_RECHECK:
            return 1
        return max((allowed - floor) / (whole - floor), MIN_STEP_FRACTION)

    def _costs(self):
        """``(C, F)``: the predicted cost of a whole step and the floor of a fraction."""
        whole = max(self.step_cost, 1e-9)
        return whole, min(self.floor_cost, whole)

    def _fill(self, n, budget):
        """With ``fill``: the fraction of a further step that fits in what ``n`` whole steps
        leave of ``budget`` (predicted cost ``F + f (C - F)``, as :meth:`_fit`), when ``n`` is
        below :data:`FILL_BELOW`, fractions pay (a floor below half a whole step, and no
        ``excess``) and the fraction is at least :data:`MIN_FILL`; else 0."""
        whole, floor = self._costs()
        if (not self.fill or n >= FILL_BELOW or 2.0 * floor >= whole
                or self.excess > EXCESS_RECHECK):
            return 0.0
        f = (budget - n * whole - floor) / (whole - floor)
        return min(f, 1.0 - MIN_FILL) if f >= MIN_FILL else 0.0

    def stepped(self, n, seconds):
        """``n`` steps took ``seconds``. Whole steps (with a fraction of one more: :meth:`_fill`)
        measure the cost of one (and shrink the floor). A fraction of one (``n`` < 1) moves the
        cost of a whole step towards the smaller of ``seconds / n`` and ``whole_cost``, and the
        floor and ``excess`` by the difference between ``seconds`` and the cost so predicted."""
        if n >= 1:
            self.whole_cost = seconds / n
            self.step_cost = (1 - SMOOTHING) * self.step_cost + SMOOTHING * self.whole_cost
            self.floor_cost = min((1 - SMOOTHING) * self.floor_cost, self.step_cost)
            self.excess = 0.0
            return
        whole = min(seconds / n, self.whole_cost)
        floor = min(self.floor_cost, whole)
        self.step_cost = (1 - SMOOTHING) * self.step_cost + SMOOTHING * whole
        predicted = floor + n * (whole - floor)
        miss = seconds - predicted
        self.excess = ((1 - SMOOTHING) * self.excess
                       + SMOOTHING * min(miss / max(predicted, 1e-12), 1.0))
        self.floor_cost = min(max(floor + SMOOTHING * miss, 0.0), self.step_cost)

    def published(self, seconds, markers):
        """Publishing a frame took ``seconds`` (with ``markers``: the markers' part on top)."""
        if markers:
            self.marker_cost = ((1 - SMOOTHING) * self.marker_cost
                                + SMOOTHING * max(seconds - self.publish_cost, 0.0))
        else:
            self.publish_cost = (1 - SMOOTHING) * self.publish_cost + SMOOTHING * seconds
