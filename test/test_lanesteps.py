"""Lane twins of the step control's full scans (solver.kernels.lanesteps): B = 5 instances of the
FB column, each with its own prestrain and impact (0.3, 1, 2 m/s) advanced a few steps of 0.02 s
(cables slack and taut, bar contacts met), stacked as lanes; every lane of
``next_kink_lanes`` (several steps, kinks found and not), ``step_energy_lanes`` and
``ledger_energy_lanes`` equals the scalar kernel on that instance bit for bit. Cases: the scene
as it is (sym3d, bar contact), full3d, full3d with massive bars, damped cables, and stops with a
striker (the scalar contact kernels on views of a lane)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from solver import Scene
from solver.kernels import dynamics as dyn
from solver.kernels import lanesteps, records, summary
from solver.kernels.effects import ledger_energy
from solver.kernels.kinks import next_kink
from solver.simulate.simulation import Simulation
from solver.status import OK

ROOT = Path(__file__).resolve().parents[1]
B = 5
# (prestrain, impact m/s, advances of 0.02 s) of each lane
LANES = [(0.002, 0.3, 1), (0.004, 1.0, 2), (0.006, 2.0, 3), (0.003, 1.0, 1), (0.01, 2.0, 2)]
CASES = {
    'sym3d': [],
    'full3d': [('model', 'full3d')],
    'massbars': [('model', 'full3d'), ('materials.bar_mass_fraction', 0.3)],
    'damped': [('materials.cable_damping_ratio', 0.05)],
    'axial': [('contact.lock', 'penalty'), ('loading.impact.mode', 'striker')],
}


def _stack(arrays):
    return np.ascontiguousarray(np.stack(arrays, axis=-1))


@pytest.fixture(scope='module', params=list(CASES))
def column(request):
    """``(name, m, instances, lane arrays)``: per lane ``(m, d, acc)`` (its model record, its
    data, its accelerations by the scalar kernel) and the lane-inner ``x``, ``v``, ``acc``,
    ``rest``, ``EA``, ``f_ext`` and lane-outer ``scan``."""
    scene = Scene.load(ROOT / 'config' / 'scenes' / 'fb_column.yaml')
    if CASES[request.param]:
        scene = scene.with_overrides(CASES[request.param])
    inst = []
    for prestrain, v0, n in LANES:
        sim = Simulation(scene)
        sim.apply_prestrain(prestrain)
        sim.apply_impact(v0)
        for _ in range(n):
            sim.advance(0.02)
        m, d = sim.model.rec, records.clone_data(sim.model.data)
        acc = np.zeros_like(d.x)
        assert dyn.accelerations(d.x, d.v, m, records.clone_data(d),
                                 records.clone_work(sim.model.work), acc) == OK
        inst.append((m, d, acc, sim.contacts_met))
    ds = [d for _, d, _, _ in inst]
    arrays = dict(x=_stack([d.x for d in ds]), v=_stack([d.v for d in ds]),
                  acc=_stack([a for _, _, a, _ in inst]), rest=_stack([d.rest for d in ds]),
                  EA=_stack([d.EA for d in ds]), f_ext=_stack([d.f_ext for d in ds]),
                  scan=np.ascontiguousarray(np.stack([d.contact.scan for d in ds])))
    return request.param, inst[0][0], inst, arrays


def test_the_lanes_differ_and_met_contacts(column):
    """Different instances (else a comparison lane by lane could not tell lanes apart), some with
    bar contacts met, some cables slack and some taut, and the model the lanes share is each
    instance's."""
    name, m, inst, a = column
    for k in range(1, B):
        assert not np.array_equal(a['x'][..., k], a['x'][..., 0])
        assert not np.array_equal(a['rest'][:, k], a['rest'][:, 0])
    assert max(met for *_, met in inst) > 0
    for mk, *_ in inst:
        assert np.array_equal(mk.topo.cable_a, m.topo.cable_a)
        assert np.array_equal(mk.summary.x0, m.summary.x0)
    if name == 'axial':
        assert m.stops.height.shape[0] and m.strikers.row.shape[0]
    if name == 'damped':
        assert m.damping.coef.shape[0]
    if name == 'massbars':
        assert np.any(m.summary.bar_mass != 0.0)


def _kinks(m, a, h, ignore, go, fill=-7.0):
    out = np.full(B, fill)
    lanesteps.next_kink_lanes(a['x'], a['v'], a['acc'], m, a['rest'], h, ignore, go, out)
    return out


def test_next_kink_equals_the_scalar_kernel_in_every_lane(column):
    """For steps from 1e-5 s to 0.05 s, the same for every lane and different per lane: each
    lane's kink equals ``next_kink`` on its instance, at the instances' states and at drifted
    ones; some steps end at a kink, some do not."""
    _, m, inst0, a0 = column
    dt = 6.25e-4
    ignore = 1e-3 * dt
    go = np.ones(B, np.int64)
    found = same = 0
    steps = [np.full(B, h) for h in (1e-5, 1e-4, dt, 5e-3, 5e-2)]
    steps += [dt * np.array([0.5, 1.0, 2.0, 8.0, 80.0]), dt * np.array([80.0, 8.0, 2.0, 1.0, 0.1])]
    for h, tau in [(h, tau) for h in steps for tau in (0.0, 1e-4, 3e-4)]:
        a, inst = _drifted(inst0, a0, tau)
        out = _kinks(m, a, h, ignore, go)
        for k, (mk, d, acc, _) in enumerate(inst):
            want = next_kink(d.x, d.v, acc, mk, d, h[k], ignore)
            assert out[k] == want, (h[k], k, out[k], want)
            found += want < h[k]
            same += want == h[k]
    assert found > 0 and same > 0


def test_next_kink_leaves_lanes_that_do_not_go(column):
    _, m, inst, a = column
    dt = 6.25e-4
    go = np.array([1, 0, 1, 0, 1], np.int64)
    h = np.full(B, 50 * dt)
    out = _kinks(m, a, h, 1e-3 * dt, go)
    for k, (mk, d, acc, _) in enumerate(inst):
        if go[k]:
            assert out[k] == next_kink(d.x, d.v, acc, mk, d, h[k], 1e-3 * dt)
        else:
            assert out[k] == -7.0


def _drifted(inst, a, tau):
    """The lanes and the instances at positions ``x + tau v`` (more states to compare at: the
    kernels' results are functions of their inputs, whether or not a run reaches them)."""
    x = np.ascontiguousarray(a['x'] + tau * a['v'])
    return dict(a, x=x), [(mk, d._replace(x=np.ascontiguousarray(x[..., k])), acc, met)
                          for k, (mk, d, acc, met) in enumerate(inst)]


def test_step_and_ledger_energies_equal_the_scalar_kernels_in_every_lane(column):
    """At the instances' states and at 11 drifted ones: each lane's node, bar and cable sums
    (left in the scratch) equal the scalar parts, its step energy and its ledger energy the
    scalar kernels'."""
    _, m, inst0, a0 = column
    go = np.ones(B, np.int64)
    tmp = np.zeros((3, B))
    out = np.zeros(B)
    ledger = np.zeros(B)
    for j in range(12):
        a, inst = _drifted(inst0, a0, 2e-4 * j)
        lanesteps.step_energy_lanes(a['x'], a['v'], m, a['rest'], a['EA'], a['f_ext'], go, out,
                                    tmp)
        sm, topo = m.summary, m.topo
        parts = np.array([[summary._node_energy(d.x, d.v, sm.x0, d.f_ext, sm.node_mass,
                                                 sm.clamped, sm.node_mult),
                           summary._bar_kinetic_energy(d.v, sm.bar_a, sm.bar_b, sm.bar_mass),
                           summary._cable_energy(d.x, topo.cable_a, topo.cable_b,
                                                 topo.cable_rot, d.rest, d.EA, sm.cable_mult)]
                          for _, d, _, _ in inst]).T
        assert np.array_equal(tmp, parts), (j, tmp - parts)
        want = np.array([summary.step_energy(d.x, d.v, mk, d) for mk, d, _, _ in inst])
        assert np.array_equal(out, want), (j, out - want)
        lanesteps.ledger_energy_lanes(a['x'], a['v'], m, a['rest'], a['EA'], a['f_ext'],
                                      a['scan'], go, ledger, tmp)
        want = np.array([ledger_energy(d.x, d.v, mk, d) for mk, d, _, _ in inst])
        assert np.array_equal(ledger, want), (j, ledger - want)
        assert np.all(np.isfinite(want))


def test_step_energy_is_nan_without_a_summary_and_leaves_lanes_that_do_not_go(column):
    _, m, inst, a = column
    go = np.array([0, 1, 1, 0, 1], np.int64)
    out = np.full(B, 3.0)
    tmp = np.zeros((3, B))
    bare = m._replace(summary=records.NO_SUMMARY)
    lanesteps.step_energy_lanes(a['x'], a['v'], bare, a['rest'], a['EA'], a['f_ext'], go, out,
                                tmp)
    assert np.all(np.isnan(out[go != 0])) and np.all(out[go == 0] == 3.0)
    out = np.full(B, 3.0)
    lanesteps.step_energy_lanes(a['x'], a['v'], m, a['rest'], a['EA'], a['f_ext'], go, out, tmp)
    for k, (mk, d, _, _) in enumerate(inst):
        assert out[k] == (summary.step_energy(d.x, d.v, mk, d) if go[k] else 3.0)
