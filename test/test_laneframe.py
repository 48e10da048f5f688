"""An array's frame takes the base forces of its lane groups from one compiled call per group
(solver.simulate.laneframe): every column's value equals, bit for bit, what its own simulation
computes alone (solver.analysis.support.ModelBaseForce, one evaluation per column), at rest,
through bar and base contact after impacts of up to 1 m/s, and through a prestrain ramp; the
call leaves every column's data as it was (the next steps are those of an array that never
published a frame)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from solver import Scene
from solver.analysis.support import ModelBaseForce
from solver.simulate import laneframe
from solver.simulate.array import simulation_for

ROOT = Path(__file__).resolve().parents[1]
FB = ROOT / 'config' / 'scenes' / 'fb_column.yaml'


def _array(n, v0s, lanes=True):
    """An array of ``n`` FB columns, prestrains 0.02 to 0.08, column ``c`` hit at ``v0s[c]``,
    stepped as lanes or (``lanes`` False, the scene's default) one column at a time."""
    sim = simulation_for(Scene.load(FB).with_overrides([('structure.n_columns', n)]))
    sim.lanes, sim.threads = lanes, 1
    sim.apply_prestrain(np.linspace(0.02, 0.08, n)[:, None] * np.ones((1, sim.network.n_prisms)))
    for c, v0 in enumerate(v0s):
        if v0:
            sim.apply_impact(v0, columns=[c])
    return sim


def _alone(sim):
    """Each column's base force as its simulation computes it alone (a fresh ModelBaseForce,
    the path Simulation.base_force takes one column at a time)."""
    out = np.empty(sim.n_columns)
    for g in sim.groups:
        out[g.columns] = ModelBaseForce(g.sim.model)(g.sim.model)[0]
    return out


@pytest.mark.parametrize('lanes', [True, False])
def test_a_lane_groups_base_forces_equal_each_columns_own_bit_for_bit(monkeypatch, lanes):
    """Stepped as lanes or one column at a time: the frame makes the lane groups of its
    columns either way (their data in the groups' memory), and the steps of an array that
    publishes frames are those of one that does not."""
    calls = []                              # columns that computed their own base force
    own = ModelBaseForce.__call__
    monkeypatch.setattr(ModelBaseForce, '__call__', lambda me, m: calls.append(1) or own(me, m))
    v0s = (0.0, 0.1, 0.3, 1.0, 0.5, 0.0)
    sim = _array(6, v0s, lanes)
    twin = _array(6, v0s, lanes)            # steps the same, never publishes a frame
    met, largest = 0, 0.0
    for q in range(100):                    # 0.5 s: the fronts reach the base at about 0.4 s
        sim.advance(0.005)
        twin.advance(0.005)
        alone = _alone(sim)
        before = [g.sim.model.data.x.copy() for g in sim.groups]
        k = len(calls)
        got = sim.frame().base_force
        assert len(calls) == k                  # the lanes' call gave every column's
        assert np.array_equal(got, alone), q
        assert all(np.array_equal(g.sim.model.data.x, x) for g, x in zip(sim.groups, before))
        met, largest = sim.contacts_met, max(largest, float(np.max(np.abs(got))))
    assert len(sim._plan.groups) == 1
    assert met > 0 and largest > 1e-3                           # through contact, at the base
    assert len(set(got.tolist())) == 6                          # six columns apart
    # the frames changed nothing the steps read: the twin ends on the same state, bit for bit
    for a, b in zip(sim.groups, twin.groups):
        for name in ('x', 'v', 'ledger', 'scan', 'active', 'refine'):
            if name in ('scan', 'active'):
                pa, pb = getattr(a.sim.model.data.contact, name), \
                    getattr(b.sim.model.data.contact, name)
            else:
                pa, pb = getattr(a.sim.model.data, name), getattr(b.sim.model.data, name)
            assert np.array_equal(pa, pb), name


def test_a_ramping_array_and_a_group_that_was_left_take_the_columns_own_values():
    sim = _array(4, (0.2, 0.2, 0.2, 0.2))
    sim.apply_prestrain(np.linspace(0.03, 0.09, 4), columns=[0, 1, 2, 3], ramp_s=0.02)
    for _ in range(8):                      # through the ramp, as ramped lanes, and after it
        sim.advance(0.005)
        assert np.array_equal(sim.frame().base_force, _alone(sim))
    # a column split from its group by a command steps alone until the next plan: the stale
    # group's call is skipped and every value is still the column's own
    sim.apply_impact(0.4, columns=[2])
    laneframe.put_base_forces(sim._plan)
    assert np.array_equal(sim.frame().base_force, _alone(sim))
