"""The model family: sym3d against full3d, model selection and expansion, the chain1d force law
against the prism energy computed from node coordinates, the chain at the rigid-base lock."""
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from solver.kernels import summary
from solver.models import family as models
from solver.models import chain1d
from solver.models.chain1d import Chain1D
from solver.build.scene import Scene
from solver.simulate.array import simulation_for
from solver.build.structures import build_network
from solver.models.sym3d import NotSymmetric, reduce_network

SCENES = Path(__file__).resolve().parent.parent / 'config' / 'scenes'


def _scene(name, *sets):
    return Scene.load(SCENES / f'{name}.yaml').with_overrides(list(sets))


def _impacted(name, model, v0=0.1, t=0.2):
    sim = simulation_for(_scene(name, f'model={model}'))
    sim.apply_impact(v0)
    sim.advance(t)
    return sim


# -- sym3d ---------------------------------------------------------------------------------------
@pytest.mark.parametrize('name', ['fb_column', 'rb_column'])
def test_sym3d_equals_full3d_on_the_paper_columns(name):
    full, sym = _impacted(name, 'full3d'), _impacted(name, 'sym3d')
    assert (full.model.name, sym.model.name) == ('full3d', 'sym3d')
    xf, xs = full.frame().positions, sym.frame().positions
    assert np.max(np.abs(xf - full.network.x0)) > 1e-4       # the wave has moved the nodes
    assert np.max(np.abs(xs - xf)) <= 1e-9 * np.max(np.abs(xf))
    assert sym.energy() == pytest.approx(full.energy(), rel=1e-9)
    np.testing.assert_allclose(sym.frame().tension, full.frame().tension, rtol=0, atol=1e-12)


@pytest.mark.parametrize('name,sets', [
    ('fb_column', ['structure.handedness=left']),
    ('fb_column', ['loading.gravity=0.2']),
    ('fb_column', ['structure.stacking=parallel']),
    ('prism', ['materials.bar_mass=0.002', 'structure.bases=rigid']),      # massive bars
    ('rb_column', ['structure.rigid_bases_as=stiff_cables', 'integrator.dt=1e-4']),
    ('rb_column', ['loading.impact.mode=energy', 'loading.impact.v0=0.02']),
])
def test_sym3d_equals_full3d_on_other_symmetric_variants(name, sets):
    x = {}
    for model in ('full3d', 'auto'):
        sim = simulation_for(_scene(name, f'model={model}', *sets))
        sim.apply_impact(sim.scene['loading.impact.v0'])
        sim.advance(0.05)
        x[sim.model.name] = sim.frame().positions
    assert set(x) == {'full3d', 'sym3d'}
    assert np.max(np.abs(x['sym3d'] - x['full3d'])) <= 1e-9 * np.max(np.abs(x['full3d']))


@pytest.mark.parametrize('name', ['fb_column', 'rb_column'])
def test_auto_selects_sym3d_on_the_paper_columns(name):
    scene = _scene(name)
    assert scene['model'] == 'auto'
    assert simulation_for(scene).model.name == 'sym3d'


def test_auto_falls_back_to_full3d_and_sym3d_on_request_names_the_problem():
    scene = _scene('fb_column', 'structure.n_columns=2', 'structure.n_prisms=3')
    # two columns: not symmetric about z as one network, each column about its own axis
    assert simulation_for(scene.with_overrides(['model=full3d'])).model.name == 'full3d'
    assert simulation_for(scene).model.name == 'sym3d'
    assert models.choose('auto', build_network(scene), scene) is models.Full3D
    with pytest.raises(ValueError, match='sym3d'):
        simulation_for(scene.with_overrides(['model=sym3d']), network=build_network(scene))
    assert simulation_for(_scene('fb_column', 'model=chain1d')).model.name == 'chain1d'


@pytest.mark.parametrize('bases', ['flexible', 'rigid'])
def test_reduced_network_has_one_node_and_member_per_orbit(bases):
    net = build_network(_scene('fb_column', f'structure.bases={bases}'))
    red = reduce_network(net)
    assert red.n_nodes == 51 and red.n_nodes * 3 == net.n_nodes
    n_base = 51 if bases == 'flexible' else 0
    assert len(red.cable_a) == 50 + n_base
    assert sorted(set(red.cable_rot.tolist())) == ([1, 2] if n_base else [2])
    if bases == 'rigid':          # 50 bars + one radial constraint per free level
        radial = red.con_tail == red.con_head
        assert radial.sum() == 50 and red.n_constraints == 100
        np.testing.assert_allclose(red.con_length[radial], math.sqrt(3) * 0.005, rtol=1e-12)
    else:
        assert red.n_constraints == 50


def test_asymmetric_network_is_rejected():
    net = build_network(_scene('prism'))
    x = np.array(net.x0)
    x[4, 0] += 1e-4
    from solver.build.network import Network
    moved = Network.build(x, net.node_mass, np.stack([net.bar_a, net.bar_b], 1),
                          np.stack([net.cable_a, net.cable_b], 1), net.cable_rest_length,
                          net.cable_EA, clamped=np.nonzero(net.clamped)[0])
    with pytest.raises(NotSymmetric):
        reduce_network(moved)
    assert models.choose('auto', moved, {}) is models.Full3D


def test_asymmetric_command_expands_to_full3d_without_a_jump():
    sym = _impacted('fb_column', 'auto', t=0.05)
    full = _impacted('fb_column', 'full3d', t=0.05)
    x_before = sym.frame().positions
    rest = full.network.cable_rest_length.copy()
    cross = [i for i, k in enumerate(full.network.cable_kind) if k == 'cross']
    rest[cross[40]] *= 0.995          # one cable of one prism: breaks the 3-fold symmetry
    sym.set_cable_rest_lengths(rest)
    full.set_cable_rest_lengths(rest)
    assert sym.model.name == 'full3d' and sym.expanded
    np.testing.assert_array_equal(sym.frame().positions, x_before)
    sym.advance(0.05)
    full.advance(0.05)
    xs, xf = sym.frame().positions, full.frame().positions
    assert np.max(np.abs(xs - xf)) <= 1e-9 * np.max(np.abs(xf))
    sym.reset()
    assert sym.model.name == 'sym3d'


def test_symmetric_command_keeps_sym3d():
    sim = _impacted('fb_column', 'auto', t=0.02)
    sim.set_cable_rest_lengths(sim.network.cable_rest_length * 0.999)
    assert sim.model.name == 'sym3d'


# -- chain1d: the force law ----------------------------------------------------------------------
def _prism_cross_length(h, r, phi):
    """Cross-cable length from node coordinates: bottom node k = 0 at angle 0, top node k' = 2 at
    angle phi + 4 pi / 3 (cross cables join n_k to n'_(k-1))."""
    bottom = np.array([r, 0.0, 0.0])
    top = np.array([r * math.cos(phi + 4 * math.pi / 3), r * math.sin(phi + 4 * math.pi / 3), h])
    return float(np.linalg.norm(top - bottom))


def _bar_twist(h, r, b):
    """Twist keeping the bar (n_0 -> n'_0) at length b, from |n'_0 - n_0|^2 = b^2."""
    return math.acos(1.0 - (b * b - h * h) / (2.0 * r * r))


def _rigid_energy(chain, h):
    k, L = chain.cross[0]
    s = _prism_cross_length(h, chain.r0, _bar_twist(h, chain.r0, chain.b))
    return 3 * 0.5 * k * max(s - L, 0.0) ** 2


def test_rigid_law_is_the_derivative_of_the_prism_energy():
    chain = Chain1D(build_network(_scene('rb_column', 'model=chain1d')))
    h0 = chain.h0
    assert (chain.h_lock - h0) / chain.h_lock == pytest.approx(-0.1005, abs=5e-4)  # physics
    assert abs(chain.force(np.array([h0]))[0]) < 1e-12
    d = 1e-7 * h0
    for h in np.linspace(chain.h_lock + 0.01 * h0, 1.3 * h0, 25):
        numeric = -(_rigid_energy(chain, h + d) - _rigid_energy(chain, h - d)) / (2 * d)
        assert chain.force(np.array([h]))[0] == pytest.approx(numeric, rel=1e-5, abs=1e-9)
    # small-strain stiffness (docs/physics.md section 6: 3.21 N/m), infinite at the lock
    k = -(chain.force(np.array([h0 + d]))[0] - chain.force(np.array([h0 - d]))[0]) / (2 * d)
    assert k == pytest.approx(3.21, abs=0.01)
    assert np.isinf(chain.force(np.array([chain.h_lock * (1 - 1e-9)]))[0])
    assert chain.force(np.array([chain.h_lock + 1e-9 * h0]))[0] > 1e2


def _flexible_energy(chain, h):
    """min over the base radius of the prism energy from node coordinates (scipy, bounded)."""
    def energy(r):
        phi = _bar_twist(h, r, chain.b)
        s = _prism_cross_length(h, r, phi)
        e = sum(0.5 * k * max(s - L, 0.0) ** 2 for k, L in chain.cross)
        side = math.sqrt(3) * r
        return e + sum(w * 0.5 * k * max(side - L, 0.0) ** 2 for w, k, L in chain.bases)
    r_lo = math.sqrt(chain.b ** 2 - h * h) / 2 * (1 + 1e-12)      # twist 180 deg
    r_hi = math.sqrt((chain.b ** 2 - h * h) / 2)                   # twist 90 deg
    res = minimize_scalar(energy, bounds=(r_lo, r_hi), method='bounded',
                          options={'xatol': 1e-15})
    return res.fun


def test_flexible_law_is_the_derivative_of_the_minimised_prism_energy():
    chain = Chain1D(build_network(_scene('fb_column', 'model=chain1d')))
    h0 = chain.h0
    scale = np.max(np.abs(chain.force(np.linspace(0.5 * h0, 1.3 * h0, 50))))
    assert abs(chain.force(np.array([h0]))[0]) < 1e-8 * scale
    d = 1e-5 * h0
    for h in np.linspace(0.5 * h0, 1.3 * h0, 17):
        numeric = -(_flexible_energy(chain, h + d) - _flexible_energy(chain, h - d)) / (2 * d)
        assert chain.force(np.array([h]))[0] == pytest.approx(numeric, abs=1e-5 * scale)
    # the tabulated energy is the antiderivative of the law, and matches the minimum energy
    e_tab = chain.prism_energy(np.array([0.7 * h0, h0]))
    e_min = [_flexible_energy(chain, 0.7 * h0), _flexible_energy(chain, h0)]
    assert e_tab[0] - e_tab[1] == pytest.approx(e_min[0] - e_min[1], rel=1e-6)


# -- chain1d: dynamics ---------------------------------------------------------------------------
def test_chain1d_small_oscillation_period_of_one_prism():
    sim = simulation_for(_scene('prism', 'model=chain1d', 'structure.bases=rigid',
                            'integrator.dt=1e-4'))
    chain = sim.model
    v0 = 1e-5
    sim.apply_impact(v0)
    k = 3.2176      # small-strain stiffness of the closed-form law (checked above against 3.21)
    period = 2 * math.pi * math.sqrt(chain.level_mass[-1] / k)
    times, z = [], []
    while sim.t < 0.75 * period:
        sim.advance(1e-4)
        times.append(sim.t)
        z.append(chain.u[-1])
    t_min = times[int(np.argmin(z))]
    assert t_min == pytest.approx(period / 4, rel=2e-3)
    assert min(z) == pytest.approx(-v0 * period / (2 * math.pi), rel=2e-3)


def test_chain1d_rigid_lock_is_a_hard_elastic_contact():
    sim = simulation_for(_scene('prism', 'model=chain1d', 'structure.bases=rigid',
                            'integrator.dt=1e-6', 'run.output_dt=1e-3'))
    chain = sim.model
    k, L = chain.cross[0]
    s_lock = math.sqrt(chain.b ** 2 - 3 * chain.r0 ** 2)      # cross cable at 180 deg of twist
    e_lock = 1.5 * k * (s_lock - L) ** 2 - 1.5 * k * (chain.cross_length0 - L) ** 2
    sim.apply_impact(0.5)
    e0 = sim.energy()
    assert 0.5 * chain.level_mass[-1] * 0.5 ** 2 > 10 * e_lock     # enough to reach the lock
    h_min, w_end = math.inf, []
    for _ in range(3000):
        sim.advance(1e-6)
        h_min = min(h_min, chain.heights()[0])
        w_end.append(chain.w[-1])
    assert chain.h_lock - 1e-12 * chain.h0 <= h_min <= chain.h_lock + 1e-3 * chain.h0
    assert max(w_end) > 0.45                      # bounced back with nearly all its speed
    assert abs(sim.energy() - e0) <= 1e-4 * e0


def test_chain1d_rejects_cable_changes_and_keeps_energy_on_the_paper_column():
    sim = simulation_for(_scene('rb_column', 'model=chain1d'))
    with pytest.raises(ValueError, match='chain1d'):
        sim.set_cable_rest_lengths(sim.network.cable_rest_length * 0.99)
    sim.apply_impact(0.1)
    e0 = sim.energy()
    sim.advance(0.15)
    assert abs(sim.energy() - e0) <= 1e-4 * e0
    strain = sim.frame().strain
    assert strain.min() < -0.03 and np.all(strain > -0.1005 - 1e-6)


def test_a_stiff_table_law_takes_the_sub_steps_its_frequency_needs(monkeypatch):
    """Rigid bases as stiff cables (EA x 100): a table law about 25 times stiffer than the
    flexible bases', whose chain then takes sub-steps of OMEGA_SUBSTEP over its highest frequency
    2 sqrt(k_max / m) (at the 1e-4 s of the flexible bases its energy balance failed within
    0.03 s). It runs 1 s within the ledger's limit, and halving the sub-step moves the pulse
    speed by less than 1e-5 (converged); the flexible-base chain keeps its 1e-4 s."""
    from solver.simulate.runner import simulate
    assert Chain1D(build_network(_scene('fb_column', 'model=chain1d'))).substep == \
        chain1d.SUBSTEP[1]
    sets = [('model', 'chain1d'), ('structure.rigid_bases_as', 'stiff_cables'),
            ('structure.stacking', 'parallel'), ('loading.impact.v0', 0.15)]
    stiff = Chain1D(build_network(_scene('rb_column', *[f'{k}={v}' for k, v in sets])))
    law = stiff.law
    h = np.linspace(law.lo, law.lo + law.dh * law.fcoef.shape[0], 200001)    # the table
    k_max = np.max(np.abs(np.diff(stiff.force(h)) / (h[1] - h[0])))   # |dF/dh|, by differences
    omega = 2 * math.sqrt(k_max / stiff.level_mass.min())
    assert stiff.substep == pytest.approx(chain1d.OMEGA_SUBSTEP / omega, rel=0.02)
    assert stiff.substep < 0.5 * chain1d.SUBSTEP[1]
    runs = []
    for factor in (1.0, 0.5):
        monkeypatch.setattr(chain1d, 'OMEGA_SUBSTEP', 0.02 * factor)
        s = simulate(str(SCENES / 'rb_column.yaml'), sets).summary.to_json()
        assert abs(s['energy_balance_error']) < 1e-4
        runs.append(s['pulse']['speed_m_s'])
    assert runs[1] == pytest.approx(runs[0], rel=1e-5)


# -- the paper table
# -------------------------------------------------------------------------------
def test_first_passage_measures_the_incoming_pulse_only():
    from solver.analysis.observables import first_passage
    h0, n, c = 0.0062, 50, 100.0          # a pulse moving 100 prisms/s, reflected at the far end
    times = np.arange(0.0, 1.0, 0.005)
    prisms = np.arange(n)[::-1]            # distance from the impacted end (prism n-1)
    strain = np.zeros((len(times), n))
    for k, t in enumerate(times):
        travelled = c * t
        pos = travelled if travelled <= n - 1 else 2 * (n - 1) - travelled
        strain[k] = -0.05 * np.exp(-0.5 * ((prisms - pos) / 0.8) ** 2) * (t > 0)
    p = first_passage(times, strain, h0)
    assert p.speed_m_s == pytest.approx(c * h0, rel=0.02)
    assert p.amplitude_median == pytest.approx(0.05, rel=0.05)
    assert p.arrival_time_s == pytest.approx(10 / c, abs=0.006)
    assert math.isnan(p.amplitude)          # the pulse reached the end before t = 0.5 s


@pytest.mark.parametrize('sets', [[], ['structure.bases=rigid'], ['loading.gravity=0.5'],
                                  ['structure.stacking=parallel']])
def test_sym3d_reduced_summary_equals_the_expanded_state(sets):
    """Energy, finiteness, prism heights and constraint error computed on the reduced state (no
    expansion) equal the full-network computation on the expanded state (and the NumPy
    constraint error)."""
    from solver.analysis.observables import constraint_error, state_summary
    sim = simulation_for(Scene.load(f'{SCENES}/fb_column.yaml').with_overrides(
        ['structure.n_prisms=8', 'model=sym3d'] + sets))
    sim.apply_impact(0.1)
    sim.advance(0.05)
    m = sim.model
    h = np.empty((sim.network.levels.shape[0], sim.network.levels.shape[1] - 1))
    finite, e, cerr, h_min = summary.state_summary(m.x, m.v, m.rec, m.data, h)
    assert h_min == h.min()
    f_ext = sim.f_ext if np.any(sim.f_ext) else None
    finite_ref, e_ref, h_ref, cerr_ref = state_summary(m.positions(), m.velocities(), sim.network,
                                                       m.cable_rest_length, m.cable_EA, f_ext)
    assert finite and finite_ref
    assert e == pytest.approx(e_ref, rel=1e-12)
    assert cerr_ref == pytest.approx(constraint_error(m.positions(), sim.network), abs=1e-15)
    assert cerr == pytest.approx(cerr_ref, abs=1e-14) and cerr < 1e-11
    np.testing.assert_allclose(h, h_ref, rtol=0, atol=1e-15)
    assert np.ptp(h) > 1e-6                     # the wave has changed the heights


@pytest.mark.parametrize('sets', [(), ('model=full3d',), ('loading.impact.mode=striker',),
                                  ('model=full3d', 'loading.impact.mode=striker'),
                                  ('contact.bars=none', 'contact.lock=penalty')])
def test_the_kernels_static_arrays_have_one_type_whatever_the_scene(sets):
    """numba compiles a kernel once per type of its arguments (the first FB kernel takes about a
    minute): every scene's records have one numba type, the model's arrays read-only, the
    data's and workspace's writable, whatever the scene switches on, so that one compiled kernel
    serves every scene."""
    from numba import typeof
    from solver.kernels.records import plain
    sim = simulation_for(_scene('fb_column', *sets))
    model = sim.model
    m, d, w = plain(sim.network)
    assert typeof(model.rec) == typeof(m)
    assert typeof(model.data) == typeof(d) and typeof(model.work) == typeof(w)
