"""The pacer against fake cost models (pure arithmetic: no ROS, no wall clock): hundreds of ticks
driven as the node drives them (``Pacer.steps``, the steps, ``Pacer.stepped`` with their cost),
with a whole step that costs more than a tick's budget.

A single column in lasting contact: a fraction of a step costs that fraction of a whole one, and
the ticks settle on the fraction that fits. An array: a fraction costs at least a floor near or
above the budget however short it is, and simulated time keeps a good part of the pace of whole
steps (it does not shrink to ``MIN_STEP_FRACTION`` of a step a tick). When the contact ends the
ticks return to whole steps within a few ticks."""
import math

import pytest

from tensegrity_ros.node.pacing import FAST_WORK_FRACTION, MIN_STEP_FRACTION, Pacer

PERIOD = 0.005                   # s: 200 Hz
DT = 0.625e-3                    # s: the FB column's step
BUDGET = FAST_WORK_FRACTION * PERIOD   # s: a tick's budget at real_time_factor 0
REST = 0.01 * BUDGET             # s: a step of a column out of contact
CONTACT = 10 * BUDGET            # s: a whole step in lasting contact


def jitter(k):
    """A deterministic scatter of measured wall times, +-10 %."""
    return 1.0 + 0.1 * math.sin(1.7 * k)


def proportional(whole):
    """A single column: a fraction ``f`` of a step costs ``f`` times a whole one."""
    return lambda f, k: f * whole(k)


def with_floor(floor, whole):
    """An array: a fraction costs at least ``floor`` s, ``max(floor, f C)``."""
    return lambda f, k: max(floor, f * whole(k))


def floor_plus(floor, whole):
    """An array: a fraction costs ``floor`` s plus its share of the rest, ``F + f (C - F)``."""
    return lambda f, k: floor + f * (whole(k) - floor)


def drive(pacer, part, whole, ticks, rtf=0.0, call=lambda k: 0.0, command_at=None):
    """``ticks`` ticks of the node: each asks the pacer for its steps, takes them at the cost the
    model gives (``n`` whole steps: ``call(k) + n whole(k)``; a fraction ``f``: ``part(f, k)``;
    whole steps and a fraction of one more: the sum; all with the jitter) and tells the pacer.
    The next tick is due a period on, or when this one ends. At tick ``command_at`` a command
    is applied first (``Pacer.changed``). Returns ``(steps, seconds)`` of each tick."""
    now = t_sim = 0.0
    pacer.anchor(t_sim, now)
    ticks_out = []
    for k in range(ticks):
        if k == command_at:
            pacer.changed()
        n = pacer.steps(now, t_sim, DT, rtf, deadline=now + PERIOD)
        seconds = 0.0
        if n > 0:
            w = int(n)
            seconds = ((call(k) + w * whole(k) if w else 0.0)
                       + (part(n - w, k) if n > w else 0.0)) * jitter(k)
            pacer.stepped(n, seconds)
            t_sim += n * DT
        ticks_out.append((n, seconds))
        now += max(PERIOD, seconds)
    return ticks_out


def sim_per_tick(ticks):
    """Simulated seconds per tick."""
    return sum(n for n, _ in ticks) * DT / len(ticks)


def pace(ticks):
    """Simulated seconds per wall second (a tick lasts a period, or longer when it overruns)."""
    return sum(n for n, _ in ticks) * DT / sum(max(PERIOD, s) for _, s in ticks)


def contact_from(k0, before=REST, after=CONTACT):
    """The cost of a whole step, s: ``before`` until tick ``k0``, then ``after``."""
    return lambda k: before if k < k0 else after


def test_a_column_in_lasting_contact_takes_the_fraction_of_a_step_that_fits():
    """Cost proportional to the fraction: after the contact begins each tick takes a fraction
    of a step that costs about the budget, and simulated time advances about budget / C of a
    step a tick, without whole steps that would overrun the tick tenfold."""
    whole = contact_from(50)
    ticks = drive(Pacer(PERIOD, REST), proportional(whole), whole, 400)
    settled = ticks[100:]
    assert all(0 < n < 1 for n, _ in settled)
    assert sim_per_tick(settled) == pytest.approx(BUDGET / CONTACT * DT, rel=0.1)
    assert max(s for _, s in settled) < 1.3 * BUDGET
    assert pace(settled) == pytest.approx(DT / CONTACT, rel=0.15)      # as whole steps would


@pytest.mark.parametrize('model, floor', [(with_floor, 1.2), (with_floor, 2.0),
                                          (with_floor, 5.0), (floor_plus, 1.0),
                                          (floor_plus, 3.0), (with_floor, 15.0)])
def test_a_fraction_with_a_floor_keeps_simulated_time_going(model, floor):
    """A fraction costs at least ``floor`` budgets however short (an array: its columns out of
    contact take whole steps, each column its overhead); a whole step costs 10 budgets. Simulated
    time per tick stays of the order of budget / C of a step, at least half of it, and the pace
    at least 0.4 of what whole steps give; it does not shrink towards MIN_STEP_FRACTION of a step
    a tick. (A floor above the cost of a whole step: mostly whole steps.)"""
    whole = contact_from(50)
    ticks = drive(Pacer(PERIOD, REST), model(floor * BUDGET, whole), whole, 600)
    settled = ticks[200:]
    assert sim_per_tick(settled) > 0.5 * BUDGET / CONTACT * DT
    assert sim_per_tick(settled) > 10 * MIN_STEP_FRACTION * DT
    assert pace(settled) > 0.4 * DT / CONTACT


def test_the_ticks_return_to_whole_steps_when_the_contact_ends():
    """A column in lasting contact (fractions), then out of contact (a whole step costs a fifth
    of the budget): whole steps again within a few ticks, as many as fit."""
    whole = contact_from(200, CONTACT, 0.2 * BUDGET)
    ticks = drive(Pacer(PERIOD, CONTACT), proportional(whole), whole, 300)
    assert all(n < 1 for n, _ in ticks[100:200])
    first = next(k for k in range(200, 300) if ticks[k][0] >= 1)
    assert first - 200 <= 20
    assert all(n >= 3 for n, _ in ticks[first + 20:])


def test_an_array_returns_to_whole_steps_when_the_contact_ends():
    """The same from an array's fractions with a floor above the budget."""
    whole = contact_from(200, CONTACT, 0.2 * BUDGET)
    in_contact = floor_plus(2 * BUDGET, whole)

    def part(f, k):            # out of contact a fraction costs what a whole step does
        return in_contact(f, k) if k < 200 else whole(k)
    ticks = drive(Pacer(PERIOD, CONTACT), part, whole, 300)
    first = next(k for k in range(200, 300) if ticks[k][0] >= 1)
    assert first - 200 <= 20
    assert all(n >= 3 for n, _ in ticks[first + 20:])


@pytest.mark.parametrize('growth', [2.0, 10.0])
def test_a_contact_that_grows_shrinks_the_fraction_again(growth):
    """In lasting contact a whole step comes to cost ``growth`` times more: the ticks, after a
    whole step or two that measure the new cost, take the fraction that fits again."""
    whole = contact_from(100, CONTACT, growth * CONTACT)
    ticks = drive(Pacer(PERIOD, CONTACT), proportional(whole), whole, 400)
    assert sum(1 for n, _ in ticks[100:] if n >= 1) <= 2
    settled = ticks[150:]
    assert sim_per_tick(settled) == pytest.approx(BUDGET / (growth * CONTACT) * DT, rel=0.1)
    assert max(s for _, s in settled) < 1.3 * BUDGET


def test_paced_ticks_that_cannot_keep_up_take_what_fits_with_a_floor():
    """At real_time_factor 1 with a whole step dearer than the budget and a floor above it: the
    pacer re-anchors each tick (no debt) and simulated time keeps going."""
    whole = contact_from(0, after=CONTACT)
    ticks = drive(Pacer(PERIOD, CONTACT), with_floor(2 * BUDGET, whole), whole, 400, rtf=1.0)
    settled = ticks[100:]
    assert pace(settled) > 0.4 * DT / CONTACT


@pytest.mark.parametrize('cost', [0.3, 0.6, 0.9])
def test_a_single_column_fills_the_tick_after_its_few_whole_steps(cost):
    """A whole step costs ``cost`` budgets (a column in lasting contact, fractions proportional):
    at real_time_factor 0 each tick takes the whole steps that fit and a fraction of one more in
    what they leave, so that it works through its budget instead of idling until the next tick:
    simulated time per tick is about budget / C of a step, ticks stay within the period."""
    whole = contact_from(0, after=cost * BUDGET)
    ticks = drive(Pacer(PERIOD, cost * BUDGET, fill=True), proportional(whole), whole, 300)
    settled = ticks[50:]
    assert sim_per_tick(settled) > 0.85 * BUDGET / (cost * BUDGET) * DT
    assert max(s for _, s in settled) < 1.25 * BUDGET
    assert any(n != int(n) for n, _ in settled)


def test_cheap_steps_and_arrays_take_whole_steps_only():
    """Steps far cheaper than the budget (many fit) keep the frames on the step grid; an array
    (no ``fill``) too, its fractions costing about a whole step."""
    cheap = contact_from(0, after=0.1 * BUDGET)
    ticks = drive(Pacer(PERIOD, 0.1 * BUDGET, fill=True), proportional(cheap), cheap, 100)
    assert all(n == int(n) and n >= 8 for n, _ in ticks[20:])
    dear = contact_from(0, after=0.6 * BUDGET)
    ticks = drive(Pacer(PERIOD, 0.6 * BUDGET), with_floor(0.6 * BUDGET, dear), dear, 100)
    assert all(n == int(n) for n, _ in ticks)


@pytest.mark.parametrize('fixed, step', [(0.55, 0.05), (0.3, 0.06), (0.05, 0.1)])
def test_a_fixed_cost_per_call_does_not_hold_the_ticks_to_few_steps(fixed, step):
    """A call costs ``fixed`` budgets plus ``step`` budgets a step (an array while a ramp runs:
    about a millisecond a call on 64 columns). The ticks settle within a step of the most that
    fit, ``(1 - fixed) / step``, and stay within the budget (the jitter aside), from an estimate
    of a step of ten budgets (a cost measured before a command; a fraction costs the call and its
    share of a step). A cost taken in proportion to the steps (1 step for 0.6 budgets: 1.7 fit)
    would hold the first case to one step a tick, where nine fit."""
    whole = contact_from(0, after=step * BUDGET)
    most = int((1.0 - fixed) / step + 1e-9)
    ticks = drive(Pacer(PERIOD, CONTACT), lambda f, k: fixed * BUDGET + f * whole(k), whole, 300,
                  call=lambda k: fixed * BUDGET)
    settled = ticks[60:]
    assert sum(n for n, _ in settled) / len(settled) >= most - 1
    assert sum(1 for _, s in settled if s > 1.15 * BUDGET) <= 0.05 * len(settled)


@pytest.mark.parametrize('fixed', [0.0, 0.5])
def test_after_a_command_the_steps_grow_from_one(fixed):
    """Out of contact many steps fit (a hundredth of a budget each); a command makes a step cost
    a third of a budget (a ramp on an array run one column at a time). The tick after it takes
    one step, and the ticks after that never run over the budget by more than one step's cost
    (the jitter aside), instead of the hundred steps the earlier cost allowed (30 budgets)."""
    after = (1.0 - fixed) / 3.0 * BUDGET
    whole = contact_from(100, REST, after)
    ticks = drive(Pacer(PERIOD, REST), proportional(whole), whole, 300,
                  call=lambda k: fixed * BUDGET if k >= 100 else 0.0, command_at=100)
    assert ticks[99][0] >= 50 and ticks[100][0] == 1
    assert max(s for _, s in ticks[100:]) < 1.1 * (BUDGET + after)
    assert sum(n for n, _ in ticks[150:]) / 150 >= 2


def test_paced_ticks_keep_the_pace_through_a_command():
    """At real_time_factor 1 with steps that cost a twentieth of the budget (eight a tick keep
    the pace): a command does not hold the ticks back (the pace bounds what a tick asks for;
    the growth from one step after a command is for unpaced ticks, which take all that fits).
    The ticks take the steps of a run without the command, and the frames stay on its grid."""
    whole = contact_from(0, after=0.05 * BUDGET)
    plain = drive(Pacer(PERIOD, 0.05 * BUDGET), proportional(whole), whole, 200, rtf=1.0)
    pacer = Pacer(PERIOD, 0.05 * BUDGET)
    ticks = drive(pacer, proportional(whole), whole, 200, rtf=1.0, command_at=100)
    assert [n for n, _ in ticks] == [n for n, _ in plain]


@pytest.mark.parametrize('spike_at', [101, 150])
def test_a_single_slow_tick_of_cheap_steps_keeps_them_whole(spike_at):
    """A single column at rest (a step costs a hundredth of the budget) whose tick ``spike_at``
    is slowed by three budgets (the machine paused it): the ticks keep taking whole steps,
    neither a fraction nor a fill, so the frames stay on the dt grid. (101: the first tick the
    pacer measures after a command; 150: any tick.)"""
    whole = contact_from(0, after=REST)
    ticks = drive(Pacer(PERIOD, REST, fill=True), proportional(whole), whole, 300,
                  call=lambda k: 3 * BUDGET if k == spike_at else 0.0, command_at=100)
    assert all(n == int(n) and n >= 1 for n, _ in ticks[100:])
