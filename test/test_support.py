"""The base force (what a column delivers to its support): the prestress reaction at rest from
the prism's equilibrium, the momentum balance of the column after an impact, the arrival time of
a known pulse shape."""
import math

import numpy as np
import pytest

from solver.build.scene import Scene
from solver.simulate.array import simulation_for
from solver.analysis.support import axial_momentum, first_arrival, pulse_arrival

SCENES = 'config/scenes/'


def _sim(name='fb_column', *sets):
    return simulation_for(Scene.load(f'{SCENES}{name}.yaml').with_overrides(list(sets)))


def _cross_axial(net, p):
    """Axial pull of the cross cables on a level-0 node of a prism at prestrain p: the cable
    tension EA p (physics: T = EA (s - L) / L with L = s / (1 + p)) times h0 / s."""
    return net.meta['EA'] * p * net.meta['h0'] / net.meta['cross_length']


@pytest.mark.parametrize('name,sets', [
    ('fb_column', ['structure.n_prisms=10']),
    ('rb_column', ['structure.n_prisms=10']),
    ('fb_column', ['structure.n_prisms=6', 'structure.n_columns=3', 'model=full3d']),
    ('fb_column', ['structure.n_prisms=6', 'structure.n_columns=3']),
])
def test_base_force_at_rest_is_the_self_equilibrated_reaction(name, sets):
    """At rest the level-0 nodes are in equilibrium under the bar, the cross cable and the (level)
    base members; the base members are horizontal, so the axial parts of the bar push and the
    cross cable pull cancel: the reaction is 0. Each part alone is 3 EA p h0 / s, so a base force
    that missed the bars (or the cables) would be that large."""
    sim = _sim(name, *sets)
    net = sim.network
    p = np.linspace(0.001, 0.006, net.n_columns)
    sim.apply_prestrain(p)
    scale = 3 * _cross_axial(net, p)
    assert np.all(scale > 1e-4)
    b = sim.frame().base_force
    assert b.shape == (net.n_columns,)
    assert np.all(np.abs(b) <= 1e-10 * scale)


@pytest.mark.parametrize('model,g', [('sym3d', 0.0), ('full3d', 0.0), ('sym3d', 0.2)])
def test_impulse_on_the_support_is_the_momentum_change(model, g):
    """d P_z / dt = B + F_ext: the time integral of the base force over the first passage (and
    the reflection) equals the change of the column's axial momentum after the impact minus the
    impulse of gravity on its free nodes, within the quadrature error (trapezoid at every
    step)."""
    sim = _sim('fb_column', 'structure.n_prisms=20', f'model={model}', f'loading.gravity={g}')
    weight = g * sim.network.node_mass[~sim.network.clamped].sum()
    assert axial_momentum(sim.model.velocities(), sim.network)[0] == 0.0
    sim.apply_impact(0.1)
    p0 = axial_momentum(sim.model.velocities(), sim.network)[0]
    assert p0 == pytest.approx(-3 * sim.network.node_mass[-1] * 0.1, rel=1e-12)
    t, b, p = [0.0], [sim.base_force()[0]], [p0]
    for _ in range(int(round(0.4 / sim.dt))):
        sim.advance(sim.dt)
        t.append(sim.t)
        b.append(sim.base_force()[0])
        p.append(axial_momentum(sim.model.velocities(), sim.network)[0])
    t, b, p = map(np.array, (t, b, p))
    impulse = np.concatenate([[0.0], np.cumsum(0.5 * (b[1:] + b[:-1]) * np.diff(t))])
    impulse -= weight * t
    assert np.max(np.abs(b)) > 1e-3                  # the pulse reached the base
    assert abs(impulse[-1]) > 0.05 * abs(p0)
    assert np.max(np.abs(impulse - (p - p0))) <= 1e-4 * abs(p0)


def test_arrival_of_a_gaussian_pulse():
    """Half-height crossing of a Gaussian bump at t0 with width sigma: t0 - sqrt(2 ln 2) sigma;
    its rise width is that of the rate's positive lobe at half its height (the roots of
    x exp(-x^2 / 2) = exp(-1/2) / 2, times sigma). A pull on the support before it (a tensile
    precursor) is no arrival: it is reported as the precursor; a smaller compressive bump before
    it is the first peak when above 2 % of the largest (below, it is not), however much larger
    the later one."""
    t = np.linspace(0, 1, 2001)
    t0, sig = 0.5, 0.03
    bump = 2.0 * np.exp(-0.5 * ((t - t0) / sig) ** 2)
    a = first_arrival(t, 1.0 + bump)
    assert a.rest_N == 1.0
    assert a.time_s == pytest.approx(t0 - math.sqrt(2 * math.log(2)) * sig, abs=1e-5)
    assert a.peak_time_s == pytest.approx(t0, abs=1e-3) and a.peak_N == pytest.approx(2.0, 1e-6)
    from scipy.optimize import brentq
    g = lambda x: x * math.exp(-0.5 * x * x) - 0.5 * math.exp(-0.5)      # noqa: E731
    width = (brentq(g, 1.0, 5.0) - brentq(g, 0.0, 1.0)) * sig
    assert a.rise_s == pytest.approx(width, rel=2e-3)
    assert a.precursor_N == 0.0
    pull = -0.5 * np.exp(-0.5 * ((t - 0.3) / sig) ** 2)
    b = first_arrival(t, bump + pull)
    assert b.time_s == pytest.approx(a.time_s, abs=1e-6) and b.peak_N == pytest.approx(2.0, 1e-6)
    assert b.precursor_N == pytest.approx(-0.5, rel=1e-3)
    for height in (0.5, 0.05):                   # 25 % and 2.5 % of the later bump
        early = height * np.exp(-0.5 * ((t - 0.3) / sig) ** 2)
        c = first_arrival(t, bump + early)
        assert c.time_s == pytest.approx(0.3 - math.sqrt(2 * math.log(2)) * sig, abs=1e-4)
        assert c.peak_N == pytest.approx(height, rel=1e-3)
    tiny = 0.02 * np.exp(-0.5 * ((t - 0.3) / sig) ** 2)              # 1 % of the later bump
    assert first_arrival(t, bump + tiny).time_s == pytest.approx(a.time_s, abs=1e-6)
    # a step with a wiggle on its rising flank: the peak is the top of the step
    step = 1.0 / (1.0 + np.exp(-(t - 0.5) / 0.01))
    wiggle = step + 0.05 * np.exp(-0.5 * ((t - 0.48) / 0.002) ** 2)      # dips 2 % after it
    w = first_arrival(t, wiggle)
    assert w.time_s == pytest.approx(0.5, abs=1e-3) and w.peak_N == pytest.approx(1.0, 1e-3)
    assert math.isnan(first_arrival(t, np.zeros_like(t)).time_s)
    assert math.isnan(first_arrival(t, pull).time_s)              # only a pull: no pulse


def test_pulse_arrival_times_the_largest_compression():
    """A small early bump and a larger late one: the first arrival is the early one's half-height
    crossing, the pulse arrival the late one's; a pull before it is its precursor."""
    t = np.linspace(0, 1, 2001)
    sig = 0.02
    early = 0.2 * np.exp(-0.5 * ((t - 0.3) / sig) ** 2)
    late = 1.5 * np.exp(-0.5 * ((t - 0.7) / sig) ** 2)
    pull = -0.1 * np.exp(-0.5 * ((t - 0.5) / sig) ** 2)
    half = math.sqrt(2 * math.log(2)) * sig
    f = early + late + pull
    assert first_arrival(t, f).time_s == pytest.approx(0.3 - half, abs=1e-4)
    a = pulse_arrival(t, f)
    assert a.time_s == pytest.approx(0.7 - half, abs=1e-4)
    assert a.peak_time_s == pytest.approx(0.7, abs=1e-3) and a.peak_N == pytest.approx(1.5, 1e-4)
    assert a.precursor_N == pytest.approx(-0.1, rel=1e-3)
    assert math.isnan(pulse_arrival(t, pull).time_s)


@pytest.mark.parametrize('name,sets', [
    ('fb_column', ['structure.n_prisms=8']),                       # sym3d, bases touch at 0.3
    ('rb_column', ['structure.n_prisms=8']),
    ('fb_column', ['structure.n_prisms=8', 'materials.cable_damping_ratio=0.05']),
    ('fb_column', ['structure.n_prisms=8', 'model=full3d']),
    ('fb_column', ['structure.n_prisms=6', 'loading.gravity=9.81']),
    ('fb_column', ['structure.n_prisms=6', 'loading.impact.mode=striker']),
    ('fb_column', ['structure.n_prisms=6', 'contact.lock=penalty']),
    ('fb_column', ['structure.n_prisms=6', 'structure.n_columns=3']),
])
def test_the_base_force_of_the_model_state_equals_the_full_state_one(name, sets):
    """The base force a simulation gives (from the model's own, maybe reduced, state: no
    expansion) equals the slower one of the full expanded state (BaseForce over the full network,
    with every bar pair and base looked at) to round-off, through an impact strong enough for
    bars and bases to touch."""
    from solver.analysis.support import BaseForce, ModelBaseForce
    sim = _sim(name, *sets)
    models = [g.sim.model for g in sim.groups] if hasattr(sim, 'groups') else [sim.model]
    assert all(ModelBaseForce.applies(m) for m in models)    # an array: each group's own
    from solver.models.extras import scene_effects
    full = BaseForce(sim.network, scene_effects(sim.scene, sim.network))
    sim.apply_impact(0.3)
    worst = scale = 0.0
    for _ in range(60):
        sim.advance(0.005)
        x, v = sim.model.positions(), sim.model.velocities()
        want = full(x, v, sim.model.cable_rest_length, sim.model.cable_EA,
                    getattr(sim, 'f_ext', None))
        got = sim.base_force()
        worst = max(worst, float(np.max(np.abs(got - want))))
        scale = max(scale, float(np.max(np.abs(want))))
    assert scale > 1e-3                          # the pulse reached the base
    assert worst <= 1e-11 * scale
    if 'n_prisms=8' in sets and name == 'fb_column':
        assert sim.contacts_met > 0              # contact forces were part of it


def test_the_compiled_base_force_equals_its_steps_done_one_by_one():
    """ModelBaseForce (one compiled call) against the same steps taken one by one here: the
    forces evaluated (dynamics.accelerations) on copies of the data with every bar pair and
    prism base looked at and the ledger a scratch copy, then the z sum over the base nodes.
    Bit for bit, through strong contact (2 m/s), a rigid base and cable damping."""
    from solver.analysis.support import ModelBaseForce
    from solver.kernels import dynamics as dyn
    from solver.kernels import records

    def by_steps(mbf, model):
        d = model.data
        contact = records.ContactState(d.contact.scan.copy(), d.contact.active.copy())
        contact.scan[records.LOOK] = 1.0
        contact.active[0] = -1
        own = d._replace(contact=contact, ledger=d.ledger.copy())
        f = np.zeros_like(d.x)
        work = records.clone_work(model.work)
        assert dyn.accelerations(d.x, d.v, model.rec, own, work, f) == dyn.OK
        out = np.zeros(mbf.base.shape[0])
        for c in range(mbf.base.shape[0]):
            if mbf.base[c, 0] >= 0:
                s = 0.0
                for i, p in enumerate(mbf.base[c]):
                    s += mbf.mult[c, i] * (work.f[p, 2] - d.f_ext[p, 2])
                out[c] = -s
        return out

    cases = [('fb_column', 2.0, ['structure.n_prisms=12']),
             ('rb_column', 1.0, ['structure.n_prisms=12']),
             ('fb_column', 0.5, ['structure.n_prisms=12', 'materials.cable_damping_ratio=0.05'])]
    for name, v0, sets in cases:
        sim = _sim(name, *sets)
        sim.apply_impact(v0)
        mbf = ModelBaseForce(sim.model)
        for _ in range(40):
            sim.advance(0.002)
            assert np.array_equal(mbf(sim.model), by_steps(mbf, sim.model)), name
        assert sim.contacts_met > 0, name
