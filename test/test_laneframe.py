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


def _rows_alone(sim):
    """Each column's frame rows as its own simulation makes them (Simulation.frame: the
    model's positions, observables.cable_tensions), moved by the column's offset."""
    n, k = sim._per
    x, strain = np.empty((sim.n_columns, n, 3)), np.empty((sim.n_columns, sim.network.n_prisms))
    tension, energy = np.empty((sim.n_columns, k)), np.empty(sim.n_columns)
    for g in sim.groups:
        f = g.sim.frame()
        for c in g.columns:
            x[c] = f.positions + sim._offset[c]
            strain[c], tension[c], energy[c] = f.strain[0], f.tension, f.energy
    return x, strain, tension, energy


@pytest.mark.parametrize('model, lanes', [('sym3d', True), ('sym3d', False),
                                          ('full3d', True)])
def test_an_arrays_frame_rows_equal_each_columns_own_frame_bit_for_bit(model, lanes):
    """Positions, strains, tensions and energies of an array's frame, taken a lane group at a
    time (laneframe.fill: one compiled call for positions and tensions), equal each column's
    own frame, bit for bit (the bytes: signs of zeros too), and so does the energy balance error
    of the column furthest from balance, on sym3d columns and on columns expanded to full3d;
    columns of equal prestrain share one simulation (a lane shows two columns); through bar
    contact after impacts of 0.3 and 1 m/s."""
    sim = simulation_for(Scene.load(FB).with_overrides([('structure.n_columns', 6)]))
    sim.lanes, sim.threads = lanes, 1
    p = np.array([0.02, 0.03, 0.02, 0.04, 0.03, 0.05])
    sim.apply_prestrain(p[:, None] * np.ones((1, sim.network.n_prisms)))
    sim.apply_impact(0.3, columns=[0, 2, 3])
    sim.apply_impact(1.0, columns=[1, 4, 5])
    assert len(sim.groups) == 4
    if model == 'full3d':
        for g in sim.groups:
            g.sim.expand_to_full3d('test: the frame of full3d columns')
    for q in range(40):
        sim.advance(0.005)
        if q % 8:
            continue
        f = sim.frame()
        x, strain, tension, energy = _rows_alone(sim)
        assert {g.sim.model.name for g in sim.groups} == {model}
        assert f.positions.tobytes() == x.reshape(-1, 3).tobytes(), q
        assert f.strain.tobytes() == strain.tobytes(), q
        assert f.tension.tobytes() == tension.reshape(-1).tobytes(), q
        assert f.energy == float(sum(energy.tolist())), q
        balance = [g.sim.energy_error() for g in sim.groups]    # each column's own
        assert f.energy_balance_error == max(balance, key=abs) != 0.0, q
    assert sim._plan is not None and len(sim._plan.groups) == 1
    assert sim.contacts_met > 0
    n, k = sim._per                     # the lane group served every column (none by itself)
    rows = (np.empty((6, n, 3)), np.empty((6, sim.network.n_prisms)), np.empty((6, k)),
            np.empty(6), np.empty(6))
    served = laneframe.fill(sim._plan, {id(g.sim): g.columns for g in sim.groups}, sim._offset,
                            *rows)
    assert set(served) == {id(g.sim) for g in sim.groups}
    x, strain, tension, energy = _rows_alone(sim)
    assert rows[0].tobytes() == x.tobytes() and rows[2].tobytes() == tension.tobytes()
