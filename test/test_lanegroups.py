"""Lane groups (solver.simulate.lanebatch) against single runs: simulations stepped together as
lanes equal, bit for bit, the same simulations stepped one at a time (positions, strains,
energies, balance, steps taken, contacts met, the damping's ledger), with different prestrains,
impacts that bring bar and base contact, cable damping, a pulse train, stragglers moved to
fewer lanes, and a lane that diverges alone with its single run's reason; arrays of columns
equal their one-at-a-time twin on 1 and 2 threads."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from solver import Scene
from solver.simulate import chooser, lanebatch
from solver.simulate.array import simulation_for
from solver.simulate.simulation import Simulation, SimulationDiverged

ROOT = Path(__file__).resolve().parents[1]
FB = ROOT / 'config' / 'scenes' / 'fb_column.yaml'


def _same(a, b):
    """Whether two simulations are in the same state, bit for bit."""
    fa, fb = a.frame(), b.frame()
    return (np.array_equal(fa.positions, fb.positions) and np.array_equal(fa.strain, fb.strain)
            and np.array_equal(fa.tension, fb.tension) and fa.energy == fb.energy
            and fa.energy_balance_error == fb.energy_balance_error and a.t == b.t
            and a.step == b.step and a.steps_taken == b.steps_taken
            and a.contacts_met == b.contacts_met
            and a.model.dissipated() == b.model.dissipated())


def _arrays(n, ways, threads, p_high, v0):
    """Arrays of ``n`` FB columns, one per way of stepping in ``ways``, on ``threads``:
    prestrains 0.02 to ``p_high`` (one per column), each column hit at ``v0``."""
    scene = Scene.load(FB).with_overrides([('structure.n_columns', n)])
    sims = []
    for lanes in ways:
        sim = simulation_for(scene)
        sim.lanes, sim.threads = lanes, threads
        n_p = sim.network.n_prisms
        sim.apply_prestrain(np.linspace(0.02, p_high, n)[:, None] * np.ones((1, n_p)))
        sim.apply_impact(v0)
        sims.append(sim)
    return sims


def _pair(scene, commands):
    """Two lists of simulations of ``scene``, each with ``commands[k](sim)`` applied."""
    def make():
        out = []
        for c in commands:
            s = Simulation(scene)
            c(s)
            out.append(s)
        return out
    return make(), make()


def _cmd(prestrain, v0):
    def apply(sim):
        sim.apply_prestrain(prestrain)
        sim.apply_impact(v0)
    return apply


def _step_both(group, singles, n, intervals):
    """``intervals`` calls of ``n`` steps: the group's results and the singles' (ok, value)."""
    out = []
    for _ in range(intervals):
        got = group.advance(n)
        want = []
        for s in singles:
            try:
                want.append((True, s.advance(n * s.dt)))
            except SimulationDiverged as exc:
                want.append((False, exc))
        out.append((got, want))
    return out


def test_mixed_lanes_equal_their_single_runs():
    """Nine lanes: different prestrains; impacts of 0.3, 1 and 2 m/s (bar and base contact,
    trials, ledger refinement), which split the lanes into stragglers moved to fewer lanes;
    one lane hit at 30 m/s diverges in its first step. Every other lane equals its single run
    after every interval; the diverging lane fails with its single run's message, restored to
    its state before the interval."""
    scene = Scene.load(FB)
    v0s = [0.3, 1.0, 2.0, 1.0, 0.3, 2.0, 1.0, 30.0, 0.3]
    commands = [_cmd(0.02 + 0.005 * k, v) for k, v in enumerate(v0s)]
    lanes, singles = _pair(scene, commands)
    group = lanebatch.LaneGroup(lanes)
    assert len(group.blocks) > 1                # 9 lanes: stragglers move to a block of 8
    got, want = _step_both(group, singles, 8, 1)[0]
    bad = v0s.index(30.0)
    for k, ((ok, value), (ok_s, value_s)) in enumerate(zip(got, want)):
        assert ok == (k != bad) and ok_s == ok
        if not ok:
            assert isinstance(value, SimulationDiverged)
            assert str(value) == str(value_s)
        else:
            assert value == value_s
        assert _same(lanes[k], singles[k]), k
    keep = [k for k in range(len(lanes)) if k != bad]
    group = lanebatch.LaneGroup([lanes[k] for k in keep])
    singles = [singles[k] for k in keep]
    for got, want in _step_both(group, singles, 8, 5):
        assert got == want
        assert all(_same(a, b) for a, b in zip(group.sims, singles))
    hard = [s for s, v in zip(group.sims, [v0s[k] for k in keep]) if v >= 1.0]
    assert all(s.contacts_met > 0 for s in hard)
    assert max(s.steps_taken for s in group.sims) > 2 * min(s.steps_taken for s in group.sims)


def test_full3d_lanes_equal_their_single_runs():
    """Columns on ``full3d`` (plain cables: no rotated images) step as lanes too: four lanes,
    different prestrains, impacts of 0.3 and 1 m/s (bar contact), equal to their single runs
    after every interval."""
    scene = Scene.load(FB).with_overrides([('model', 'full3d')])
    commands = [_cmd(0.02 + 0.01 * k, v) for k, v in enumerate((0.3, 1.0, 0.3, 1.0))]
    lanes, singles = _pair(scene, commands)
    assert lanes[0].model.name == 'full3d'
    group = lanebatch.LaneGroup(lanes)
    for got, want in _step_both(group, singles, 8, 6):
        assert got == want
        assert all(_same(a, b) for a, b in zip(lanes, singles))
    assert all(s.contacts_met > 0 for s in lanes[1::2])


def test_a_lane_in_long_contact_moves_down_every_block_and_equals_its_single_run(monkeypatch):
    """Sixteen lanes, one struck at 2 m/s and fifteen at 0.05 m/s: within each interval the
    struck lane steps on long after the others are done, so it moves from the 16 lanes to the
    blocks of 8, 4 and 2 in turn (each block's lanes: half the last's), and back. Every lane
    equals its single run after every interval."""
    scene = Scene.load(FB)
    v0s = [0.05] * 16
    v0s[5] = 2.0
    commands = [_cmd(0.02 + 0.002 * k, v) for k, v in enumerate(v0s)]
    lanes, singles = _pair(scene, commands)
    group = lanebatch.LaneGroup(lanes)
    assert [b.lanes for b in group.blocks] == [16, 8, 4, 2]
    moves = []
    take = lanebatch._Block.take

    def spy(block, above, alive):
        moves.append((above.lanes, block.lanes, len(alive)))
        return take(block, above, alive)
    monkeypatch.setattr(lanebatch._Block, 'take', spy)
    for got, want in _step_both(group, singles, 8, 4):
        assert got == want
        assert all(_same(a, b) for a, b in zip(group.sims, singles))
    # the struck lane alone went down the whole chain, in at least one interval
    assert {(16, 8, 1), (8, 4, 1), (4, 2, 1)} <= set(moves)
    assert lanes[5].contacts_met > 0
    assert all(s.contacts_met == 0 for k, s in enumerate(lanes) if k != 5)


def test_damped_lanes_and_a_pulse_train():
    """Cable damping (the power and the energy it takes out, booked per lane) and the impacts
    of a pulse train applied between intervals: lanes equal their single runs."""
    scene = Scene.load(FB).with_overrides([('materials.cable_damping_ratio', 0.02)])
    commands = [_cmd(0.03 + 0.01 * k, 0.5 + 0.25 * k) for k in range(4)]
    lanes, singles = _pair(scene, commands)
    group = lanebatch.LaneGroup(lanes)
    for i in range(4):
        for got, want in _step_both(group, singles, 6, 1):
            assert got == want
        for k, (a, b) in enumerate(zip(lanes, singles)):
            if i % 2 == k % 2:
                a.apply_impact(0.2)
                b.apply_impact(0.2)
        assert all(_same(a, b) for a, b in zip(lanes, singles))
    assert all(s.model.dissipated() > 0 for s in lanes)


def test_lane_keys_group_only_alike_models():
    """Prestrains differ in the data only: one key. A radius or a prism height changes the
    model's constants: another key, another group; a running ramp steps alone."""
    scene = Scene.load(FB)
    a, b = Simulation(scene), Simulation(scene)
    b.apply_prestrain(0.07)
    assert lanebatch.lane_key(a) == lanebatch.lane_key(b)
    for key, value in [('structure.h0', 0.0065), ('structure.radius', 0.0052)]:
        other = Simulation(scene.with_overrides([(key, value)]))
        assert lanebatch.lane_key(other) != lanebatch.lane_key(a)
    c = Simulation(scene)
    c.apply_prestrain(0.05, ramp_s=0.01)
    assert not lanebatch.eligible(c)
    lists, singles = lanebatch.groups_of([a, b, c])
    assert [len(x) for x in lists] == [2] and singles == [c]


@pytest.mark.parametrize('threads, way', [(1, True), (2, True), (2, 'auto')])
def test_array_lanes_equal_one_column_at_a_time(threads, way):
    """An array of 20 columns with different prestrains hit at 0.5 m/s: stepped as lanes (one
    lane group per thread), or switching between lanes and single simulations as measured
    (``'auto'``), it equals the array stepped one column simulation at a time."""
    sims = _arrays(20, (way, False), threads, 0.06, 0.5)
    for sim in sims:
        for _ in range(6):
            sim.advance(8 * sim.dt)
    a, b = sims
    assert a._plan is not None and len(a._plan.groups) == threads
    fa, fb = a.frame(), b.frame()
    assert np.array_equal(fa.positions, fb.positions)
    assert np.array_equal(fa.strain, fb.strain)
    assert fa.energy == fb.energy and a.steps_taken == b.steps_taken
    assert a.contacts_met == b.contacts_met


def test_chooser_takes_the_faster_way_and_probes_the_other():
    """Unknown ways first (their first call not counted), then the cheaper per step, the other
    once every ``probe_every`` calls times how many times slower it was; a way that becomes
    cheaper takes over."""
    c = chooser.Chooser(probe_every=4, weight=1.0, margin=0.1)
    trace = []
    for _ in range(16):
        way = c.pick()
        trace.append(way)
        cost = 1.0 if way is False else (2.0 if c.calls < 8 else 0.5)
        c.note(way, cost * 8, 8)
    assert trace[:4] == [True, True, False, False]
    assert trace[4:8] == [False, False, False, True]     # lanes 2x slower: probed at call 8
    assert trace[8:] == [True] * 7 + [False]             # cheaper from call 8 on; probe at 16


def test_chooser_switches_only_for_a_margin():
    """Ways within the margin of each other: the one in use stays."""
    c = chooser.Chooser(probe_every=1000, weight=1.0, margin=0.1)
    for way, cost in [(True, 1.0), (True, 1.0), (False, 1.0), (False, 1.05)]:
        assert c.pick() is way
        c.note(way, cost, 1)
    assert c.pick() is True                     # lanes 1.0 against 1.05
    c.note(True, 1.1, 1)                        # now 1.1 against 1.05: within 10 %
    assert c.pick() is True
    c.note(True, 1.3, 1)                        # 1.3 against 1.05: switch
    assert c.pick() is False


def test_the_scene_chooses_the_arrays_way_of_stepping():
    """``integrator.lanes``: off (the default), on, auto; anything else is refused by name."""
    from solver.build.scene import SceneError
    base = Scene.load(FB).with_overrides([('structure.n_columns', 3)])
    assert simulation_for(base).lanes is False
    for value, want in [('on', True), ('auto', 'auto'), ('off', False)]:
        assert simulation_for(base.with_overrides([('integrator.lanes', value)])).lanes == want
    with pytest.raises(SceneError, match='integrator.lanes'):
        base.with_overrides([('integrator.lanes', 'sideways')])


def test_columns_join_the_lanes_again_after_a_ramp():
    """A ramped prestrain steps the columns as ramped lanes; once it has ended they step as
    plain lanes again, and the array equals its one-at-a-time twin."""
    scene = Scene.load(FB).with_overrides([('structure.n_columns', 6)])
    sims = []
    for lanes in (True, False):
        sim = simulation_for(scene)
        sim.lanes, sim.threads = lanes, 1
        n_p = sim.network.n_prisms
        sim.apply_prestrain(np.linspace(0.02, 0.05, 6)[:, None] * np.ones((1, n_p)),
                            ramp_s=4 * sim.dt)
        sim.advance(8 * sim.dt)                 # the ramp, then plain steps
        sim.advance(8 * sim.dt)                 # no command between: the split is redone
        sims.append(sim)
    a, b = sims
    assert [len(g.sims) for g in a._plan.groups] == [6] and not a._plan.singles
    assert np.array_equal(a.frame().positions, b.frame().positions)
    assert a.steps_taken == b.steps_taken and a.energy() == b.energy()


@pytest.mark.parametrize('threads', [1, 2])
def test_fractions_of_a_step_step_as_lanes(threads, monkeypatch):
    """``advance_part`` on an array that steps as lanes: one step of the fraction of ``dt`` as
    lanes (no column simulation takes a part alone), equal to the array stepped one column at
    a time, bit for bit: after impacts of 0.2-1 m/s (bar contact) and through a ramp."""
    sims = _arrays(8, (True, False), threads, 0.05, np.linspace(0.2, 1.0, 8))
    a, b = sims

    def alone(self, fraction):
        raise AssertionError('a column simulation took a part of a step alone')
    for k, f in enumerate([0.5, 0.25, 1.0, 0.75, 0.3] * 3):
        if k == 5:
            for sim in sims:
                sim.apply_prestrain(np.linspace(0.05, 0.02, 8), ramp_s=6 * sim.dt)
        with monkeypatch.context() as mp:
            mp.setattr(Simulation, 'advance_part', alone)
            assert a.advance_part(f) >= 1
        b.advance_part(f)
        for sim in sims:
            sim.advance(2 * sim.dt)
        fa, fb = a.frame(), b.frame()
        assert a.t == b.t and a.step == b.step and a.steps_taken == b.steps_taken
        assert np.array_equal(fa.positions, fb.positions)
        assert np.array_equal(fa.strain, fb.strain) and fa.energy == fb.energy
        assert fa.energy_balance_error == fb.energy_balance_error
        assert np.array_equal(a.prestrain, b.prestrain)
    assert a.contacts_met > 0 and a.contacts_met == b.contacts_met
    with pytest.raises(ValueError, match='fraction'):
        a.advance_part(1.5)
