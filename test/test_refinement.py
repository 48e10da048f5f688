"""The steps of ``rk4_projected`` after a contact (solver.integrators.rk4, docs/physics.md
section 7.1): each is checked against its share of the energy ledger and taken again at half its
length when it used more. Checked against the ledger itself (energy is conserved: nothing
damps these columns), against runs at a fixed finer step, and for the state a stop restores."""
from pathlib import Path

import numpy as np
import pytest

from solver.build.scene import Scene
from solver.integrators import rk4
from solver.kernels.records import MET
from solver.simulate.array import simulation_for
from solver.simulate.runner import simulate
from solver.simulate.simulation import SimulationDiverged

ROOT = Path(__file__).resolve().parents[1]


def _scene(name, *sets):
    return Scene.load(ROOT / 'config' / 'scenes' / f'{name}.yaml').with_overrides(list(sets))


@pytest.mark.parametrize('name, v0', [('rb_column', 0.75), ('fb_column', 0.85)])
def test_strong_impacts_run_well_inside_the_ledger(name, v0):
    """Two impacts of a sweep from 0.3 to 2 m/s that stopped at the ledger (balance lost 1.03e-4
    of the energy scale at 0.34 s and 1.02e-4 at 0.235 s) when RK4 at the scene's step damped
    the vibrations the contacts excite: they run 1 s with a balance error under a tenth of the
    limit; with ``contact.refine: none`` they stop there again."""
    sets = [f'loading.impact.v0={v0}', 'run.t_end=1.0']
    point = simulate(_scene(name), sets)
    s = point.summary.to_json()
    assert s['contacts_met'] > 0
    assert abs(s['energy_balance_error']) < 0.1 * point.sim.div.energy_error, s
    with pytest.raises(SimulationDiverged, match='energy balance lost'):
        simulate(_scene(name), sets + ['contact.refine=none'])


def _interval(sim, keep, t0, dt, refine):
    """5 ms from the kept state with steps ``dt``, refined or not (not: as before any contact);
    the positions and the energy change."""
    sim._restore(keep)
    sim.t = t0
    if not refine:
        sim.model.data.contact.scan[MET] = 0.0
    sim.dt, dt0 = dt, sim.dt
    e0 = sim.energy()
    try:
        sim.advance(0.005)
    finally:
        sim.dt = dt0
    return np.array(sim.model.positions()), sim.energy() - e0


def test_refined_steps_follow_a_run_at_a_fixed_finer_step():
    """RB at 0.75 m/s among contacts: of the 5 ms intervals from 0.1 to 0.5 s, the one where the
    plain steps of the scene lose the most energy (RK4 damps the fast vibrations the contacts
    excite; at least 10x the refinement's share). There the refined steps keep the energy to
    within their share and end 10x closer to a run at dt / 64."""
    sim = simulation_for(_scene('rb_column', 'loading.impact.v0=0.75'))
    sim.apply_impact(0.75)
    worst = None
    while sim.t < 0.5 - 1e-9:
        keep, t0 = sim._keep(), sim.t
        if t0 > 0.1 - 1e-9:
            _, de = _interval(sim, keep, t0, sim.dt, refine=False)
            if worst is None or de < worst[2]:
                worst = (keep, t0, de)
            sim._restore(keep)
            sim.t = t0
        sim.advance(0.005)
    keep, t0, de_plain = worst
    budget = rk4.REFINE_SHARE * sim.div.energy_error * 0.005 * abs(sim._energy_scale)
    assert de_plain < -10 * budget
    dt = sim.dt
    x_ref, _ = _interval(sim, keep, t0, dt / 64, refine=False)
    x_plain, _ = _interval(sim, keep, t0, dt, refine=False)
    x_fine, de_fine = _interval(sim, keep, t0, dt, refine=True)
    assert abs(de_fine) < budget
    err_plain = np.max(np.abs(x_plain - x_ref))
    err_fine = np.max(np.abs(x_fine - x_ref))
    assert err_fine < 0.1 * err_plain, (err_fine, err_plain)


def test_a_stop_restores_the_refinement_and_names_the_same_step_again():
    """A run the ledger stops after contacts (FB at 1 m/s, 6 steps per contact where the scene
    takes 40) is restored with what its steps depend on (contacts met, halving levels): the same
    interval tried again stops at the same step with the same message. A reset clears them."""
    sim = simulation_for(_scene('fb_column', 'contact.resolution=6'))
    sim.apply_impact(1.0)
    with pytest.raises(SimulationDiverged) as first:
        while sim.t < 1.0:
            before = sim._refinement()
            sim.advance(0.005)
    assert sim._refinement() == before
    assert before[0] > 0                     # contacts met before the failing interval
    with pytest.raises(SimulationDiverged) as again:
        sim.advance(0.005)
    assert str(again.value) == str(first.value)
    sim.reset()
    assert sim._refinement() == (0.0, 0.0, 0.0)


def test_the_refined_contact_step_bounds_a_step_shortened_for_another_reason():
    """While a pair of bars touches, a step of the refinement level ``k`` is at most the contact
    step ``T / steps`` times ``2^-k``, also where something else (a cable's kink, the ``dt``
    level) already made it shorter than ``T / steps``: otherwise the ledger's retry of a rejected
    step takes the same step again and accepts it over its budget. From a state of FB at 1 m/s
    in contact, ``effects.plan`` is asked for steps just under the unrefined contact step."""
    from solver.kernels import dynamics as dyn
    from solver.kernels import effects
    sim = simulation_for(_scene('fb_column'))
    sim.apply_impact(1.0)
    m = sim.model
    rec, d, w = m.rec, m.data, m.work
    acc = np.zeros_like(d.x)
    checked = 0
    while sim.t < 0.2 and checked < 5:
        sim.advance(0.001)
        met = d.contact.scan[MET]
        assert dyn.accelerations(d.x, d.v, rec, d, w, acc) == dyn.OK
        saved = d.contact.scan.copy(), d.contact.active.copy()
        h_c, _, _ = effects.plan(d.x, d.v, acc, rec, d, sim.dt, met, 1.0)
        touching = d.contact.scan[MET] > met and h_c < sim.dt    # a contact acted at x
        for k in (1, 4):
            h = 0.9 * h_c                   # as a step landed on a kink just before
            step, _, _ = effects.plan(d.x, d.v, acc, rec, d, h, met, 0.5 ** k)
            if touching:
                assert step <= h_c * 0.5 ** k * (1 + 1e-12), (sim.t, k, step, h_c)
            else:
                assert step == h
        d.contact.scan[:], d.contact.active[:] = saved
        checked += touching
    assert checked == 5
