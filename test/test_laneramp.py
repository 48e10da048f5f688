"""Prestrain ramps stepped as lanes (solver.integrators.rk4laneramp through
solver.simulate.lanebatch): each lane with its own ramp equals its single run, which steps the
ramp in the integrator's compiled ramped call, bit for bit, interval after interval: through
impacts with bar contact, a ramp that ends within an interval (the rest of it stepped by the
simulation alone), one that ends exactly at an interval's end, and a lane that diverges alone
with its single run's reason. An array's columns ramp as lanes on 1 and 2 threads and equal
the array stepped one column at a time."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from solver import Scene
from solver.simulate import lanebatch
from solver.simulate.array import simulation_for
from solver.simulate.simulation import Simulation, SimulationDiverged
from test_lanegroups import _same as same_state, _step_both as step_both

ROOT = Path(__file__).resolve().parents[1]
FB = ROOT / 'config' / 'scenes' / 'fb_column.yaml'


def _same(a, b):
    """Whether two simulations are in the same state, bit for bit, their ramps included."""
    return (same_state(a, b) and np.array_equal(a.prestrain, b.prestrain)
            and a._energy_ref == b._energy_ref and a._energy_scale == b._energy_scale
            and (a._ramp is None) == (b._ramp is None))


def _made(scene, v0s, targets, ramp_s):
    """Two lists of simulations: prestrain 0.02, hit at ``v0s[k]``, then a ramp to
    ``targets[k]`` over ``ramp_s`` s."""
    def make():
        out = []
        for v0, p in zip(v0s, targets):
            s = Simulation(scene)
            s.apply_prestrain(0.02)
            s.apply_impact(v0)
            s.apply_prestrain(p, ramp_s=ramp_s)
            out.append(s)
        return out
    return make(), make()


def _interval(group, singles, n):
    """One interval of ``n`` steps of the lane group and of the singles: both results."""
    return step_both(group, singles, n, 1)[0]


@pytest.mark.parametrize('ramp_steps', [20, 16])
def test_ramped_lanes_equal_their_single_runs(ramp_steps):
    """Six lanes ramping to different prestrains after impacts of 0.1-1 m/s (bar contact at
    1 m/s) over ``ramp_steps`` steps, in intervals of 8: the ramp ends within the third
    interval (20: the lanes stop after the step whose rest lengths end it, the simulations
    step the rest alone) or at the second's end (16). After every interval each lane equals its
    single run; then the columns step as a plain lane group."""
    scene = Scene.load(FB)
    v0s = [0.1, 0.3, 1.0, 0.1, 0.5, 1.0]
    targets = [0.03, 0.05, 0.04, 0.06, 0.025, 0.07]
    dt = Simulation(scene).dt
    lanes, singles = _made(scene, v0s, targets, ramp_steps * dt)
    group = lanebatch.LaneGroup(lanes, ramps=True)
    assert group.R is not None and group.R.start.shape[0] == 6
    while group.bound():
        got, want = _interval(group, singles, 8)
        assert got == want
        assert all(_same(a, b) for a, b in zip(lanes, singles))
    assert all(s._ramp is None for s in lanes) and lanes[0].step == 8 * -(-ramp_steps // 8)
    assert np.allclose(np.array([s.prestrain[0, 0] for s in lanes]), targets, rtol=1e-12)
    assert lanes[2].contacts_met > 0
    group = lanebatch.LaneGroup(lanes)          # the ramps over: plain lanes
    for _ in range(2):
        got, want = _interval(group, singles, 8)
        assert got == want
        assert all(_same(a, b) for a, b in zip(lanes, singles))


def test_a_ramped_lane_that_diverges_stops_alone():
    """A lane hit at 30 m/s diverges in its first step: it fails with its single run's
    message, restored with its ramp to its state before the interval; the others go on and
    equal their single runs."""
    scene = Scene.load(FB)
    v0s = [0.1, 30.0, 0.3]
    lanes, singles = _made(scene, v0s, [0.03, 0.04, 0.05], 0.05)
    start = [(s.t, s.prestrain.copy(), s._ramp) for s in lanes]
    group = lanebatch.LaneGroup(lanes, ramps=True)
    got, want = _interval(group, singles, 8)
    for k, ((ok, value), (ok_s, value_s)) in enumerate(zip(got, want)):
        assert ok == (k != 1) and ok_s == ok
        if ok:
            assert value == value_s
        else:
            assert isinstance(value, SimulationDiverged) and str(value) == str(value_s)
            t, p, r = start[k]
            assert lanes[k].t == t and np.array_equal(lanes[k].prestrain, p)
            assert lanes[k]._ramp is r
        assert _same(lanes[k], singles[k]), k


def test_ramps_group_only_where_asked_and_by_their_map():
    """A running ramp makes a simulation a lane only where the caller asks (``ramps``), in a
    group apart from the plain lanes; ramps of different targets share a key."""
    scene = Scene.load(FB)
    a, b, c, d = (Simulation(scene) for _ in range(4))
    c.apply_prestrain(0.05, ramp_s=0.01)
    d.apply_prestrain(0.03, ramp_s=0.02)
    assert not lanebatch.eligible(c) and lanebatch.eligible(c, ramps=True)
    assert lanebatch.lane_key(c) == lanebatch.lane_key(d) != lanebatch.lane_key(a)
    lists, singles = lanebatch.groups_of([a, b, c, d])
    assert [len(x) for x in lists] == [2] and singles == [c, d]
    lists, singles = lanebatch.groups_of([a, b, c, d], ramps=True)
    assert sorted(map(len, lists)) == [2, 2] and not singles
    with pytest.raises(ValueError, match='not alike'):
        lanebatch.LaneGroup([c, d])             # ramps not asked for


@pytest.mark.parametrize('threads', [1, 2])
def test_an_arrays_columns_ramp_as_lanes(threads):
    """Twelve columns hit at 0.3 m/s, then ramped to twelve prestrains over 0.02 s: the
    array steps the ramping columns as lane groups (one a thread), then, the ramps over, as
    plain lanes, and equals the array stepped one column at a time after every interval."""
    scene = Scene.load(FB).with_overrides([('structure.n_columns', 12)])
    sims = []
    for lanes in (True, False):
        sim = simulation_for(scene)
        sim.lanes, sim.threads = lanes, threads
        sim.apply_impact(0.3)
        sim.advance(8 * sim.dt)
        n_p = sim.network.n_prisms
        sim.apply_prestrain(np.linspace(0.02, 0.06, 12)[:, None] * np.ones((1, n_p)),
                            ramp_s=0.02)
        sims.append(sim)
    a, b = sims
    ramped = False
    for _ in range(6):
        for sim in sims:
            sim.advance(8 * sim.dt)
        groups = a._plan.groups
        ramped = ramped or (len(groups) == threads and all(g.R is not None for g in groups))
        fa, fb = a.frame(), b.frame()
        assert np.array_equal(fa.positions, fb.positions)
        assert np.array_equal(fa.strain, fb.strain) and fa.energy == fb.energy
        assert fa.energy_balance_error == fb.energy_balance_error
        assert np.array_equal(a.prestrain, b.prestrain)
        assert a.steps_taken == b.steps_taken and a.contacts_met == b.contacts_met
    assert ramped and not a._plan.singles
    assert all(g.R is None for g in a._plan.groups)
    assert np.allclose(a.prestrain[:, 0], np.linspace(0.02, 0.06, 12), rtol=1e-12)
