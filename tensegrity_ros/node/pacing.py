"""How many steps a tick of the node takes: the pace of ``real_time_factor`` within a work budget.

Pure arithmetic on wall-clock and simulation times, no ROS: the node hands it the times, the
costs it measured (of each stepping call, of publishing a frame and of the markers) and the wall
time its command callbacks took since the last tick.

**The cost of a tick's steps** is modelled as ``K + n c``: ``c`` the cost of one more step,
``K`` the fixed cost of a call however few its steps (an array's call prepares and concludes each
lane group and column, about a millisecond on 64 columns while a ramp runs; near 0 for a single
column). Both follow the ticks of whole steps: the least-squares line through the ticks' step
counts and costs since the last command (a moving average once they are many) gives ``K`` as its
intercept and ``c`` as its slope while the counts vary; else ``c`` follows each tick's cost less
``K`` (:meth:`Pacer._line`). A model in
proportion to the steps (``K`` = 0) would hold ticks whose fixed cost fills half the budget to
one step, where eight fit. Where the model gives no more steps than the last tick took and that
tick left a quarter of its budget unused, a tick takes one step more (a probe, which measures
the line; at most one in :data:`PROBE_EVERY` ticks). The steps a tick takes grow at most to
``2 n + 1`` from the last tick's ``n`` beyond what that tick's cost allows in proportion
(unpaced, where a tick takes all that fits; paced, the pace bounds it). After
:meth:`Pacer.changed` (a command: the cost of a step may change by orders) the next tick's cost
is not taken (it carries what the command leaves to the next step: an array's lane groups split
anew) and the ticks take whole steps until :data:`SETTLE` of them are measured, instead of
fractions of a step from a cost measured before the command; unpaced, that tick takes one step
and the ticks after it grow from there, instead of the many steps the cost before the command
allowed.

A tick takes whole steps while one fits in its budget; at ``real_time_factor`` 0, for a single
simulation (``fill``: not an array, whose fractions cost about a whole step), when only a few fit
(fewer than :data:`FILL_BELOW`: steps in lasting contact), it fills what they leave of its budget
with a fraction of a further step, instead of waiting for the next tick. When a whole step costs
more than the budget (a column in lasting contact takes hundreds of contact sub-steps per
step), it takes one step shortened to a fraction ``f`` of ``dt``
(:meth:`Simulation.advance_part`), whose cost the pacer predicts as ``F + f (C - F)``: ``C = K +
c`` the cost of a whole step, ``F`` the floor, what a fraction costs however short. A single
column in contact has a floor near 0 (its cost follows ``f``); an array has a large one, since
each column out of contact takes a whole integrator step and each column costs its per-call
overhead whatever the fraction.

- A fractional step moves ``c`` towards the smaller of its cost less ``K`` over ``f`` (a bound
  from above: the ticks return to whole steps when the contact ends) and the last whole steps'.
  A fraction that costs more than ``K + f c`` so never makes a whole step look dearer than the
  last whole steps were, and the fraction does not shrink towards :data:`MIN_STEP_FRACTION`
  while simulated time stops.
- ``F`` follows the difference between the cost of each fractional step and its prediction
  (``F`` at least ``K``, at most ``C``); each whole step shrinks it by the weight
  :data:`SMOOTHING`, so that fractions are tried again.
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
LINE_SMOOTHING = 0.05            # its weight in the moments of the line K + n c (see Pacer._line)
MIN_STEP_FRACTION = 1.0 / 256    # the shortest step a tick takes when a whole one does not fit
FLOOR_MULTIPLE = 2.0             # a fractional step may cost this many times the floor, when
                                 # that exceeds the budget
EXCESS_RECHECK = 0.25            # fractional steps costing this share more than predicted (a
                                 # moving average, each share at most 1): the next tick takes a
                                 # whole step, which measures the cost of one
FILL_BELOW = 4                   # at real_time_factor 0, a tick that fits fewer whole steps
                                 # than this fills the rest of its budget with a fraction
MIN_FILL = 0.1                   # the shortest fraction a tick adds to its whole steps
SHIFT = 2.0                      # a tick of whole steps costing this factor more or less than the
                                 # line K + n c predicts starts its fit anew (a contact began)
MIN_SPREAD = 0.05                # the moving variance of the ticks' step counts over their squared
                                 # mean below which the line K + n c is not refitted (the counts
                                 # vary too little to tell K from c)
PROBE_LEFT = 0.25                # share of the budget a tick of whole steps left unused for the
                                 # next to take one step more than the model gives (a probe)
PROBE_EVERY = 8                  # ticks of whole steps from one probe to the next
SETTLE = 2                       # ticks of whole steps measured after a command before a tick
                                 # takes a fraction of a step or fills with one


class Pacer:
    """The pace: ``anchor_wall`` (monotonic s) and ``anchor_t`` (simulation s) of the last
    re-anchoring; ``fill``: whether a tick at ``real_time_factor`` 0 fills its budget with a
    fraction of a step after its whole steps (:meth:`_fill`); and the measured costs, s:
    ``step_cost`` of one more step and ``call_cost`` of a call (the model ``K + n c``, see the
    module text), ``whole_cost`` of one step in the last whole steps taken (with its share of
    ``K``), ``floor_cost`` of a fraction of a step however short (at most ``K + c``), ``excess``
    the moving average of the share by which fractional steps cost more than predicted,
    ``publish_cost`` per frame, ``marker_cost`` extra for the markers, ``cmd_wall`` of commands
    since the last tick."""

    def __init__(self, period, step_cost, fill=False):
        self.period, self.step_cost, self.whole_cost = period, step_cost, step_cost
        self.fill = fill
        self.call_cost = self.floor_cost = self.excess = 0.0
        self.publish_cost = self.marker_cost = self.cmd_wall = 0.0
        self.anchor_wall = self.anchor_t = 0.0
        self._moments = None            # moving (n, s, n^2, n s) of the ticks of whole steps
        self._count = 0                 # ticks in them
        self._probe_wait = 0            # ticks of whole steps until a probe may be taken
        self._skip = False              # the next tick's cost is not taken (see changed)
        self._settle = 0                # ticks of whole steps still to measure after a command
        self._last = None               # (steps, seconds, budget) of the last tick of whole steps
        self.budget = math.inf          # s: the budget of the last tick the pacer was asked for
        self._growing = False           # its whole steps were held to the growth from the last

    def anchor(self, t_sim, now):
        """The pace counts from simulation time ``t_sim`` at wall time ``now``."""
        self.anchor_wall, self.anchor_t = now, t_sim

    def changed(self):
        """A command may have changed the cost of a step by orders (an impact, a prestrain
        ramp): the next tick's cost is not taken (it carries what the command leaves to the next
        step: an array's lane groups split anew, a kernel loaded); the ticks take whole steps
        (fractions and fills again once :data:`SETTLE` ticks of them were measured), unpaced
        one on the next tick and growing from there; the line ``K + n c`` is refitted from
        them."""
        self._last, self._moments, self._probe_wait = (0, 0.0, 0.0), None, 0
        self._skip, self._settle = True, SETTLE

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
            self.budget = budget
            n = self._fit(budget, grow=True)
            return n + self._fill(n, budget) if n >= 1 else n
        # paced, a tick keeps a margin so that it ends before the next one is due
        budget = max(WORK_FRACTION * self.period - publish - self.cmd_wall,
                     MIN_WORK_FRACTION * self.period)
        self.budget = budget
        cap = self._fit(budget)
        target = self.anchor_t + rtf * (now - self.anchor_wall)
        want = int(math.floor((target - t_sim) / dt + 1e-9))
        if want > cap:                 # cannot keep up: do what fits, do not accumulate debt
            self.anchor(t_sim + cap * dt, now)
            return cap
        return max(want, 0)

    def _fit(self, budget, grow=False):
        """The steps that fit in ``budget`` s: whole ones (:meth:`_whole_steps`); else the
        largest fraction ``f`` whose predicted cost ``F + f (C - F)`` is at most ``budget`` or
        :data:`FLOOR_MULTIPLE` ``F``, whichever is larger; one whole step when that fraction
        reaches 1, or while fractional steps cost more than predicted (``excess`` above
        :data:`EXCESS_RECHECK`). After a command, whole steps until :data:`SETTLE` ticks of them
        are measured."""
        self._growing = False
        whole, floor = self._costs()
        if budget >= whole or self._settle > 0:
            return self._whole_steps(budget, grow)
        allowed = max(budget, FLOOR_MULTIPLE * floor)
        if allowed >= whole or self.excess > EXCESS_RECHECK:
            return 1
        return max((allowed - floor) / (whole - floor), MIN_STEP_FRACTION)

    def _whole_steps(self, budget, grow):
        """Whole steps (at least one) that fit in ``budget`` by ``K + n c``; one more than the
        last tick's where the model gives no more, that tick left :data:`PROBE_LEFT` of its
        budget unused and no such probe was taken in the last :data:`PROBE_EVERY` ticks of
        whole steps. With ``grow`` (unpaced: a tick takes all that fits), one step on the tick
        after a command and at most ``2 n + 1`` from the last tick's ``n`` beyond what its cost
        allows in proportion; paced, the pace bounds the steps a tick asks for."""
        c = max(self.step_cost, 1e-12)
        n = max(int((budget - self.call_cost) / c), 1)
        if self._last is None:
            return n
        last, seconds, last_budget = self._last
        if last < 1:
            self._growing = grow and n > 1
            return 1 if grow else n
        if (n <= last and self._probe_wait <= 0
                and seconds <= (1.0 - PROBE_LEFT) * last_budget):
            n = int(last) + 1
            self._probe_wait = PROBE_EVERY
        if not grow:
            return n
        # beyond what the last tick's cost allows in proportion: at most doubled
        cap = max(2 * int(last) + 1, int(budget * last / max(seconds, 1e-12)))
        self._growing = n > cap
        return min(n, cap)

    def _costs(self):
        """``(C, F)``: the predicted cost of a whole step, ``K + c``, and the floor of a
        fraction (at least ``K``)."""
        whole = max(self.call_cost + self.step_cost, 1e-9)
        return whole, min(max(self.floor_cost, self.call_cost), whole)

    def _fill(self, n, budget):
        """With ``fill``: the fraction of a further step that fits in what ``n`` whole steps
        leave of ``budget`` (predicted cost ``F + f (C - F)``, as :meth:`_fit`), when ``n`` is
        below :data:`FILL_BELOW`, fractions pay (a floor below half a whole step, and no
        ``excess``), the steps are those the cost allows (not held to their growth after a
        command) and the fraction is at least :data:`MIN_FILL`; else 0."""
        whole, floor = self._costs()
        if (not self.fill or n >= FILL_BELOW or 2.0 * floor >= whole
                or self.excess > EXCESS_RECHECK or self._growing or self._settle > 0):
            return 0.0
        f = (budget - self.call_cost - n * self.step_cost - floor) / (whole - floor)
        return min(f, 1.0 - MIN_FILL) if f >= MIN_FILL else 0.0

    def stepped(self, n, seconds):
        """``n`` steps took ``seconds`` (in the tick of the last :meth:`steps`). Whole steps
        (with a fraction of one more: :meth:`_fill`) measure the line ``K + n c`` (and shrink
        the floor). A fraction of one (``n`` < 1) moves ``c`` towards the smaller of its cost
        less ``K`` over ``n`` and the last whole steps' ``c``, and the floor (at least ``K``)
        and ``excess`` by the difference between ``seconds`` and the cost so predicted. The
        first tick after :meth:`changed` measures nothing."""
        if self._skip:
            self._skip = False
            if n >= 1:               # the next tick grows from n by 2 n + 1 only
                self._last = (n, math.inf, self.budget)
            return
        if n >= 1:
            self._probe_wait -= 1
            self._line(n, seconds)
            self._settle -= 1
            self._last = (n, seconds, self.budget)
            self.floor_cost = min((1 - SMOOTHING) * self.floor_cost,
                                  self.call_cost + self.step_cost)
            self.excess = 0.0
            return
        per_step = min(max(seconds - self.call_cost, 0.0) / n,
                       self.whole_cost - self.call_cost)
        whole = self.call_cost + per_step
        floor = min(max(self.floor_cost, self.call_cost), whole)
        self.step_cost = (1 - SMOOTHING) * self.step_cost + SMOOTHING * per_step
        predicted = floor + n * (whole - floor)
        miss = seconds - predicted
        self.excess = ((1 - SMOOTHING) * self.excess
                       + SMOOTHING * min(miss / max(predicted, 1e-12), 1.0))
        self.floor_cost = min(max(floor + SMOOTHING * miss, 0.0),
                              self.call_cost + self.step_cost)

    def _line(self, n, seconds):
        """Refit the line ``K + n c`` with this tick. Its moments are the mean of the ticks
        since the command (or since the cost moved by more than :data:`SHIFT` from the line's
        prediction: a contact began or ended) while they are fewer than ``1 /``
        :data:`LINE_SMOOTHING`, then a moving average of that weight. Where the counts vary and
        the slope is positive, ``K`` is the intercept and ``c`` the slope through the mean; else
        ``c`` moves towards this tick's cost less ``K`` over its steps (to it, on the first tick
        of the moments while a command settles: :data:`SETTLE`). ``K`` stays at most
        ``n / (n + 1)`` of this tick's cost (a noisy fit leaves a share to ``c``)."""
        predicted = self.call_cost + n * self.step_cost
        if not predicted / SHIFT <= seconds <= SHIFT * predicted:
            self._moments = None                # the cost moved: refit from this tick
        sample = (n, seconds, n * n, n * seconds)
        first = self._moments is None
        if first:
            self._moments, self._count = sample, 1
        else:
            self._count += 1
            w = max(1.0 / self._count, LINE_SMOOTHING)
            self._moments = tuple((1 - w) * m + w * x for m, x in zip(self._moments, sample))
        mn, ms, mnn, mns = self._moments
        fitted = False
        var = mnn - mn * mn                     # of the step counts
        if var >= MIN_SPREAD * mn * mn:
            slope = (mns - mn * ms) / var
            if slope > 0.0:
                self.call_cost, fitted = max(ms - slope * mn, 0.0), True
        self.call_cost = min(self.call_cost, seconds * n / (n + 1.0))
        per_step = (seconds - self.call_cost) / n
        if first and self._settle > 0:         # a new fit while a command settles
            self.step_cost = per_step
        elif fitted:
            self.step_cost = max(ms - self.call_cost, 0.0) / mn
        else:
            self.step_cost = (1 - SMOOTHING) * self.step_cost + SMOOTHING * per_step
        self.whole_cost = self.call_cost + per_step

    def published(self, seconds, markers):
        """Publishing a frame took ``seconds`` (with ``markers``: the markers' part on top)."""
        if markers:
            self.marker_cost = ((1 - SMOOTHING) * self.marker_cost
                                + SMOOTHING * max(seconds - self.publish_cost, 0.0))
        else:
            self.publish_cost = (1 - SMOOTHING) * self.publish_cost + SMOOTHING * seconds
