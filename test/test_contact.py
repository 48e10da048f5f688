"""Strikers, prism stops and cable damping (solver/kernels/contact.py), each against an independent
reference: the analytic two-mass collision, the analytic damped oscillator, the exact symmetric
reduction, and invariants (energy, momentum, bar lengths, the lock)."""
import hashlib
import math

import numpy as np
import pytest

from solver.models import extras

from solver.integrators import registry as integrators

from solver.models import family as models

from solver.build import structures
from solver.simulate.runner import run
from solver.build.scene import Scene, SceneError
from solver.simulate.simulation import SimulationDiverged
from solver.simulate.array import simulation_for
from solver.analysis.observables import prism_twists

SCENES = 'config/scenes'


def _scene(name, *sets):
    return Scene.load(f'{SCENES}/{name}.yaml').with_overrides(list(sets))


# -- striker -----------------------------------------------------------------------------------

@pytest.mark.parametrize('ratio', [1.0, 3.0, 0.25])
def test_striker_on_a_free_mass_is_the_two_mass_collision(ratio):
    """A striker m_s at v0 on a free mass m through a linear spring k: contact lasts
    pi sqrt(mu / k), mu = m m_s / (m + m_s); afterwards v_s = (m_s - m) / (m_s + m) v0 and
    v_m = 2 m_s / (m_s + m) v0 (elastic 1D collision; equal masses: the striker stops)."""
    m, k, v0 = 0.0083, 1.0e4, 0.1
    m_s = ratio * m
    net = structures.explicit([[0.0, 0.0, 0.0]], [], [], m, 1.0, cable_rest_length=[])
    effects = extras.Effects(strikers=True, striker_k=k, striker_expo=1.0, striker_mass=m_s,
                             resolution=40.0, m_eff=m * m_s / (m + m_s), levels=np.array([[[0]]]))
    model = models.Full3D(net, effects=effects)
    model.v[1, 2] = -v0                     # the striker (row 1) moves down onto the mass
    mu = m * m_s / (m + m_s)
    duration = math.pi * math.sqrt(mu / k)
    dt = duration / 400
    integ = integrators.get('rk4_projected')
    t, d_prev, t_end_contact = 0.0, 0.0, None
    for _ in range(800):
        steps, status = integ.run(model.rec, model.data, model.work, dt, 1)
        assert status == 0
        t += dt
        d = model.x[0, 2] - model.x[1, 2]           # overlap of mass and striker face
        if d <= 0.0 < d_prev:
            t_end_contact = t - dt * d / (d - d_prev)    # linear interpolation of the zero
            break
        d_prev = d
    assert t_end_contact == pytest.approx(duration, rel=1e-5)
    for _ in range(5):                               # out of contact: free flight
        integ.run(model.rec, model.data, model.work, dt, 1)
    v_s = -(m_s - m) / (m_s + m) * v0
    v_m = -2.0 * m_s / (m_s + m) * v0
    assert model.v[1, 2] == pytest.approx(v_s, abs=1e-7 * v0)
    assert model.v[0, 2] == pytest.approx(v_m, rel=1e-7)
    assert m * model.v[0, 2] + m_s * model.v[1, 2] == pytest.approx(-m_s * v0, rel=1e-12)
    assert np.all(model.v[:, :2] == 0.0)


def test_striker_sym3d_equals_full3d_and_conserves_energy():
    """The striker keeps the 3-fold symmetry: the reduced model reproduces the full one, and the
    total energy (column + striker kinetic + contact) is conserved at a fine step."""
    sets = ('loading.impact.mode=striker', 'integrator.dt=1e-4', 'structure.n_prisms=10')
    runs = {}
    for model in ('sym3d', 'full3d'):
        sim = simulation_for(_scene('fb_column', *sets, f'model={model}'))
        assert sim.model.name == model
        added = sim.apply_impact(0.1)
        assert added == pytest.approx(0.5 * 0.0249 * 0.1 ** 2, rel=1e-12)
        e0 = sim.energy()
        energies, strikers = [], []
        for _ in range(40):
            sim.advance(1e-3)
            f = sim.frame()
            energies.append(f.energy)
            strikers.append(f.striker.copy())
        runs[model] = (f.positions, np.array(strikers))
        assert np.max(np.abs(np.array(energies) - e0)) / e0 < 1e-6
    assert np.max(np.abs(runs['sym3d'][0] - runs['full3d'][0])) < 1e-11
    assert np.max(np.abs(runs['sym3d'][1] - runs['full3d'][1])) < 1e-11
    # the column took most of the striker's momentum within 40 ms
    assert runs['sym3d'][1][-1, 0, 1] > -0.05


@pytest.mark.parametrize('name', ['fb_column', 'rb_column'])
def test_a_striker_at_the_scenes_own_dt_resolves_its_contact(name):
    """At the scenes' own dt (0.625 ms FB, 1 ms RB) the striker's contact, a few milliseconds
    long, would take a handful of RK4 steps (the energy balance failed at the first step, 1.7e-4
    of the scale on FB); within a striker contact the steps are its duration over
    ``contact.resolution``. The run keeps its balance, and doubling the resolution moves the
    pulse figures by less than 1e-5 (converged)."""
    from solver.simulate.runner import simulate
    pulses = []
    for resolution in (40, 80):
        s = simulate(f'{SCENES}/{name}.yaml', [('loading.impact.mode', 'striker'),
                                              ('contact.resolution', resolution)]).summary
        assert abs(s.energy_balance_error) < 1e-5
        pulses.append(s.to_json()['pulse'])
        steps = s.steps_taken
    assert steps > s.t_end / s.dt                 # the contact took shorter steps
    for key in ('amplitude', 'speed_m_s'):
        assert pulses[0][key] == pytest.approx(pulses[1][key], rel=1e-5)


def test_striker_energy_balance_right_after_the_impact():
    sim = simulation_for(_scene('fb_column', 'loading.impact.mode=striker',
                            'loading.impact.striker_mass=0.0747'))
    before = sim.energy()
    assert sim.striker()[0, 1] == 0.0
    sim.apply_impact(0.15)
    st = sim.striker()
    assert st[0, 1] == -0.15
    assert sim.energy() - before == pytest.approx(0.5 * 0.0747 * 0.15 ** 2, rel=1e-12)


# -- cable damping ---------------------------------------------------------------------------

# sha256 of the strain history (11 frames x 1 x 50, float64) of this FB run computed by the code
# without strikers, stops and damping (same machine, numba without fastmath): zero damping must
# reproduce it bit for bit
UNDAMPED_FB_STRAIN_SHA256 = 'e831a64b46a6044f3618cdb31b6da9ea89e866bc12b231f96b2cf019e750e37f'


def _fb_strain(*sets):
    sim = simulation_for(_scene('fb_column', *sets))
    sim.apply_impact(0.1)
    return run(sim, 0.05, 0.005).strain


def test_zero_damping_is_bit_for_bit_the_undamped_code():
    plain = _fb_strain()
    for sets in (('materials.cable_damping=0.0',), ('materials.cable_damping_ratio=0.0',),
                 ('contact.lock=none',)):
        assert np.array_equal(_fb_strain(*sets), plain)
    assert hashlib.sha256(np.ascontiguousarray(plain).tobytes()).hexdigest() == \
        UNDAMPED_FB_STRAIN_SHA256


def test_damped_column_loses_energy_monotonically():
    sim = simulation_for(_scene('fb_column', 'materials.cable_damping_ratio=0.05'))
    sim.apply_impact(0.1)
    rec = run(sim, 0.2, 0.005)
    assert np.all(np.diff(rec.energy) < 0.0)
    assert rec.energy[-1] < 0.9 * rec.energy[0]


def test_damped_cable_mass_oscillator_matches_the_analytic_one():
    """A mass hanging on one damped cable (gravity keeps it taut): z - z_eq = a e^(-zeta w t)
    (cos w_d t + zeta / sqrt(1 - zeta^2) sin w_d t), w = sqrt(k / m), zeta = c / (2 sqrt(k m))."""
    m, L, EA, g, c = 0.01, 0.1, 10.0, 9.81, 0.2
    k = EA / L
    stretch = m * g / k                     # static stretch 0.98 mm
    a = 0.5 * stretch                       # start 0.49 mm below the equilibrium, at rest
    scene = Scene({'structure': {'builder': 'explicit',
                                 'nodes': [[0.0, 0.0, 0.0], [0.0, 0.0, -(L + stretch + a)]],
                                 'cables': [[0, 1]], 'clamped': [0], 'node_mass': m,
                                 'cable_rest_length': [L]},
                   'materials': {'cable_E': EA / (math.pi * 1.4e-4 ** 2), 'cable_damping': c},
                   'loading': {'gravity': g}, 'model': 'full3d',
                   'integrator': {'dt': 1e-4}, 'run': {'output_dt': 1e-3}})
    sim = simulation_for(scene)
    w = math.sqrt(k / m)
    zeta = c / (2.0 * math.sqrt(k * m))
    wd = w * math.sqrt(1.0 - zeta ** 2)
    z_eq = -(L + stretch)
    err = 0.0
    energies = [sim.energy()]
    for _ in range(300):
        sim.advance(1e-3)
        t = sim.t
        ref = z_eq - a * math.exp(-zeta * w * t) * (math.cos(wd * t) + zeta / math.sqrt(
            1.0 - zeta ** 2) * math.sin(wd * t))
        err = max(err, abs(sim.frame().positions[1, 2] - ref))
        energies.append(sim.energy())
    assert 0.05 < zeta < 0.5
    assert err < 1e-6 * a
    assert np.all(np.diff(energies) < 0.0)


# -- prism stops (contact.lock) ----------------------------------------------------------------

def test_penalty_stops_at_1_m_s_lose_energy_and_are_stopped():
    """The opt-in penalty stop (line bars) at 1 m/s: its energy error is a loss, and a loss stops
    the run as a gain does (it used to end with 21 % drift and exit 0)."""
    sim = simulation_for(_scene('rb_column', 'contact.lock=penalty', 'contact.bars=none'))
    sim.apply_impact(1.0)
    with pytest.raises(SimulationDiverged, match='energy balance lost'):
        while sim.t < 1.0 - 1e-9:
            sim.advance(0.005)


@pytest.mark.parametrize('name', ['rb_column', 'fb_column'])
def test_bar_contact_at_1_m_s_keeps_the_prisms_and_the_energy(name):
    """The default columns (bars 0.2 mm thick, Hertz contact) hit at 1 m/s: 0.3 s, every prism
    height positive, no rigid-base prism twisted through 180 deg, energy balance within the
    limit at every frame, and contacts did engage."""
    sim = simulation_for(_scene(name))
    sim.apply_impact(1.0)
    net = sim.network
    sign = np.sign(prism_twists(np.asarray(net.x0), net.levels))
    worst, h_min, steps0 = 0.0, np.inf, sim.steps_taken
    while sim.t < 0.3 - 1e-9:
        sim.advance(0.005)
        f = sim.frame()
        assert np.all(f.strain < 1.0)       # strain (h - h0) / h: >= 1 only for h <= 0
        h_min = min(h_min, float(np.min(1.0 / (1.0 - f.strain))))     # h / h0
        if name == 'rb_column':
            assert np.all(prism_twists(f.positions, net.levels) * sign > 0.0)
        worst = max(worst, abs(sim.energy_error()))
    assert h_min > 0.0
    assert worst < sim.div.energy_error
    assert sim.steps_taken > 2 * int(round(sim.t / sim.dt)) - steps0   # contact sub-steps taken
    plain = simulation_for(_scene(name, 'contact.bars=none'))         # line bars break
    plain.apply_impact(1.0)
    with pytest.raises(SimulationDiverged):
        while plain.t < 0.3 - 1e-9:
            plain.advance(0.005)


def test_a_prism_pulled_over_through_zero_twist_is_followed_and_one_through_the_lock_stops():
    """A rigid-base prism whose twist goes through 0 deg has been pulled out to its full bar
    length and on to the other hand (``paper_rb`` at 3 m/s: the end base rebounds off the
    column), a motion the model follows: the run goes on with its energy balance within the
    limit and every prism height positive. Through 180 deg its bars cross at the lock (line bars
    at 1 m/s): that still stops the run, named as such."""
    sim = simulation_for(_scene('paper_rb'))
    net = sim.network
    ref = prism_twists(np.asarray(net.x0), net.levels)
    sim.apply_impact(3.0)
    turned, smallest = False, math.inf
    while sim.t < 0.1 - 1e-9:
        sim.advance(0.0025)
        f = sim.frame()
        twist = prism_twists(f.positions, net.levels)
        turned |= bool(np.any(twist * ref < 0.0))
        smallest = min(smallest, float(np.min(np.abs(twist))))
        assert np.all(f.strain < 1.0)
        assert abs(sim.energy_error()) < sim.div.energy_error
    assert turned and smallest < math.radians(30.0)
    plain = simulation_for(_scene('rb_column', 'contact.bars=none'))
    plain.apply_impact(1.0)
    with pytest.raises(SimulationDiverged, match='twisted through 180 deg') as info:
        while plain.t < 0.1:
            plain.advance(0.005)
    assert info.value.quantity == 'prism twist' and 'crossed at the rigid-base lock' in str(
        info.value)


# -- bad input ------------------------------------------------------------------------------

@pytest.mark.parametrize('sets, key', [
    (('materials.cable_damping=0.1', 'materials.cable_damping_ratio=0.1'),
     'materials.cable_damping_ratio'),
    (('materials.cable_damping=-1',), 'materials.cable_damping'),
    (('loading.impact.mode=hammer',), 'loading.impact.mode'),
    (('loading.impact.contact=soft',), 'loading.impact.contact'),
    (('loading.impact.striker_mass=0',), 'loading.impact.striker_mass'),
    (('contact.lock=wall',), 'contact.lock'),
    (('contact.stiffness=0',), 'contact.stiffness'),
])
def test_bad_contact_keys_name_the_key(sets, key):
    with pytest.raises(SceneError, match=key.replace('.', r'\.')):
        _scene('fb_column', *sets)


def test_stop_above_the_rest_height_and_chain1d_are_refused():
    with pytest.raises(ValueError, match='contact.tolerance'):
        simulation_for(_scene('rb_column', 'contact.lock=penalty', 'contact.tolerance=0.2'))
    with pytest.raises(ValueError, match='chain1d'):
        simulation_for(_scene('fb_column', 'loading.impact.mode=striker', 'model=chain1d'))


@pytest.mark.parametrize('method', ['rk4_projected', 'dopri54_projected'])
def test_the_ledger_books_what_cable_damping_takes_out(method):
    """A damped FB column (damping ratio 0.05) loses more than half its energy in 0.5 s; the
    ledger books that loss (the integral of the damping's power, with the method's own weights),
    so the balance stays within 1e-6 in both directions."""
    sim = simulation_for(_scene('fb_column', 'materials.cable_damping_ratio=0.05',
                                f'integrator.method={method}'))
    sim.apply_impact(0.1)
    e0 = sim.energy()
    worst = 0.0
    while sim.t < 0.5 - 1e-9:
        sim.advance(0.005)
        worst = max(worst, abs(sim.energy_error()))
    assert sim.energy() < 0.6 * e0
    assert math.isclose(sim.energy() + sim.energy_dissipated(), e0, rel_tol=1e-6)
    assert worst < 1e-6

