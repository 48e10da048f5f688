"""``Simulation.advance_part``: one step shortened to a fraction of ``dt`` (the node takes one when
a whole step costs more than a tick's budget)."""
import math

import numpy as np
import pytest

from solver.build.scene import Scene
from solver.simulate.array import simulation_for
from solver.simulate.simulation import Simulation

SMALL = ['structure.n_prisms=10']


def _sim(*sets, scene='config/scenes/fb_column.yaml'):
    return Simulation(Scene.load(scene).with_overrides(SMALL + list(sets)))


def _state(sim):
    return np.concatenate([sim.model.x.ravel(), sim.model.v.ravel()])


def test_fractions_of_a_step_land_on_its_end_and_converge_to_the_reference():
    """Out of contact: four quarter steps end at t + dt and lie closer to a fine reference than
    one whole step (a smaller step of the same method, not a different path)."""
    runs = {}
    for name, parts in (('whole', [1.0]), ('quarters', [0.25] * 4), ('reference', [1 / 64] * 64)):
        sim = _sim()
        sim.apply_impact(0.1)
        sim.advance(20 * sim.dt)                 # the pulse is in the column
        t0 = sim.t
        for f in parts:
            sim.advance_part(f)
        assert sim.t == pytest.approx(t0 + sim.dt, rel=0, abs=1e-15)
        assert sim.step == 20 + len(parts)
        assert abs(sim.energy_error()) < sim.div.energy_error
        runs[name] = _state(sim)
    err_whole = np.abs(runs['whole'] - runs['reference']).max()
    err_quarters = np.abs(runs['quarters'] - runs['reference']).max()
    assert 0 < err_quarters < err_whole


def test_in_lasting_contact_fractions_cost_their_share_of_the_sub_steps():
    """A column pressed into bar contact takes tens of contact sub-steps per step; taken in
    quarters, the same stretch costs no more sub-steps (a contact's steps follow its own
    duration, not the call; quarter steps may cost fewer, as more of their near misses are
    slow enough to be kept whole), so a tick that fits only part of a step still makes
    progress."""
    sim = _sim()
    for _ in range(30):                          # a hammered column: lasting contact
        sim.apply_impact(0.15)
        sim.advance(2 * sim.dt)
    assert sim.contacts_met
    twin = sim.clone()
    before = sim.steps_taken
    sim.advance(10 * sim.dt)
    whole = sim.steps_taken - before
    assert whole >= 200, 'the state is not in lasting contact; the test needs one'
    before = twin.steps_taken
    for _ in range(40):
        twin.advance_part(0.25)
    quarters = twin.steps_taken - before
    assert twin.t == pytest.approx(sim.t, rel=0, abs=1e-12)
    assert quarters <= 1.25 * whole
    assert abs(twin.energy_error()) < twin.div.energy_error


@pytest.mark.parametrize('bad', [0.0, -0.5, 1.5, math.nan])
def test_a_bad_fraction_is_refused_and_changes_nothing(bad):
    sim = _sim()
    sim.apply_impact(0.1)
    sim.advance(5 * sim.dt)
    t, step, state = sim.t, sim.step, _state(sim)
    with pytest.raises(ValueError, match='fraction'):
        sim.advance_part(bad)
    assert (sim.t, sim.step) == (t, step) and np.array_equal(_state(sim), state)
    assert sim.dt == pytest.approx(sim.scene.integrator.dt)


def test_an_array_advances_every_column_by_the_same_fraction():
    scene = Scene.load('config/scenes/lens_array.yaml').with_overrides(SMALL)
    arr = simulation_for(scene)
    arr.apply_impact(0.1)
    t0 = arr.t
    arr.advance_part(0.5)
    assert arr.t == pytest.approx(t0 + 0.5 * arr.dt, rel=0, abs=1e-15)
    assert {g.sim.t for g in arr.groups} == {arr.t}
    assert all(g.sim.dt == arr.dt for g in arr.groups)
