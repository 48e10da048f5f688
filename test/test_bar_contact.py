"""Bars with a radius (solver/kernels/barcontact.py, docs/physics.md section 7.1): the closest
points of two segments against a brute-force search, forces against the gradient of the energy,
the reduced model against the full one, pulse trains and strong impacts on the default columns,
the paper's regime unchanged where no contact acts, convergence, and the energy ledger stopping a
run whose steps are too long."""
import math
from pathlib import Path

import numpy as np
import pytest

from solver.build.scene import Scene
from solver.kernels import barcontact as bc
from solver.kernels.records import HEAD, MET, MOTION
from solver.kernels import contactsteps as cs
from solver.simulate.array import simulation_for
from solver.simulate.runner import simulate
from solver.simulate.simulation import SimulationDiverged

ROOT = Path(__file__).resolve().parents[1]
ALL = np.full(1, -1, dtype=np.int64)       # bar_forces: look at every pair


def _scene(name, *sets):
    return Scene.load(ROOT / 'config' / 'scenes' / f'{name}.yaml').with_overrides(list(sets))


def _brute_distance(a0, a1, b0, b1, n=101):
    """Closest distance of two segments by a grid search over (s, t), polished by a bounded
    minimiser from the best grid point (the squared distance is convex in (s, t))."""
    from scipy.optimize import minimize
    s = np.linspace(0.0, 1.0, n)
    p = a0 + s[:, None] * (a1 - a0)
    q = b0 + s[:, None] * (b1 - b0)
    grid = np.linalg.norm(p[:, None] - q[None], axis=2)
    i, j = np.unravel_index(np.argmin(grid), grid.shape)

    def sq(st):
        return float(np.sum((a0 + st[0] * (a1 - a0) - b0 - st[1] * (b1 - b0)) ** 2))

    best = minimize(sq, [s[i], s[j]], method='L-BFGS-B', bounds=[(0, 1), (0, 1)],
                    options={'ftol': 1e-15, 'gtol': 1e-12})
    return min(grid[i, j], np.sqrt(best.fun))


def test_closest_points_of_segments_match_a_brute_force_search():
    rng = np.random.default_rng(3)
    cases = [rng.normal(size=(4, 3)) for _ in range(200)]
    cases.append(np.array([[0, 0, 0], [1, 0, 0], [0.5, -1, 0.2], [0.5, 1, 0.2]], float))  # crossed
    cases.append(np.array([[0, 0, 0], [1, 0, 0], [2, 0.1, 0], [3, 0.1, 0]], float))    # in line
    cases.append(np.array([[0, 0, 0], [1, 0, 0], [0.2, 0.3, 0], [0.8, 0.3, 0]], float))  # parallel
    for a0, a1, b0, b1 in cases:
        s, t = bc.segment_params(*a0, *(a1 - a0), *b0, *(b1 - b0))
        d = np.linalg.norm(a0 + s * (a1 - a0) - b0 - t * (b1 - b0))
        assert 0.0 <= s <= 1.0 and 0.0 <= t <= 1.0
        brute = _brute_distance(a0, a1, b0, b1)
        assert d <= brute + 1e-12
        assert d >= brute - 1e-6 * max(np.linalg.norm(a1 - a0), np.linalg.norm(b1 - b0))


def _overlapping_prism():
    """A full3d FB column of 2 prisms, the first pressed flat so that its bars and bases
    overlap: (x, the bar-contact record, levels, nodes per level)."""
    sim = simulation_for(_scene('fb_column', 'structure.n_prisms=2', 'model=full3d'))
    rec = sim.model.rec
    x = np.array(sim.model.x)
    x[3:6, 2] *= 0.03           # the middle level almost down on the bottom one
    return x, rec.bar_contact, rec.levels, rec.per_level


def test_contact_forces_are_minus_the_gradient_of_the_contact_energy():
    x, bars, levels, per_level = _overlapping_prism()
    f = np.zeros_like(x)
    n_touch = bc.bar_forces(x, bars, f, ALL) + bc.base_forces(x, levels, bars, f)
    assert n_touch >= 4                     # three pairs of bars and the two bases

    def energy(y):
        return bc.bar_energy(y, bars) + bc.base_energy(y, levels, bars, per_level)

    grad = np.zeros_like(x)
    eps = 1e-9
    for p in range(x.shape[0]):
        for i in range(3):
            up, dn = x.copy(), x.copy()
            up[p, i] += eps
            dn[p, i] -= eps
            grad[p, i] = (energy(up) - energy(dn)) / (2 * eps)
    scale = np.max(np.abs(f))
    assert scale > 0
    np.testing.assert_allclose(f, -grad, atol=1e-5 * scale)


def test_hertz_constant_of_crossed_steel_rods():
    # 4/3 E/(2 (1 - nu^2)) sqrt(r): 0.2 mm steel rods
    assert math.isclose(bc.hertz_constant(1e-4, 2e11, 0.3),
                        4 / 3 * 2e11 / (2 * 0.91) * 0.01, rel_tol=1e-12)


def test_reduced_contact_forces_and_energy_equal_the_full_ones():
    """sym3d keeps one pair per orbit of three (its forces on the images rotated back, its energy
    counted 3 times): on a symmetric state where bars and bases touch, the forces on the
    representatives and the energy equal those of full3d's every pair."""
    sym = simulation_for(_scene('fb_column', 'structure.n_prisms=12'))
    full = simulation_for(_scene('fb_column', 'structure.n_prisms=12', 'model=full3d'))
    assert sym.model.name == 'sym3d' and full.model.name == 'full3d'
    reduced, ex_r, ex_f = sym.model.reduced, sym.model.rec, full.model.rec
    assert len(ex_f.bar_contact.pairs) == 3 * len(ex_r.bar_contact.pairs)
    x_f = np.array(sym.network.x0)
    top = x_f[:, 2] > 8.5 * 0.0062                 # the last four prisms pressed nearly flat
    x_f[top, 2] = 8.5 * 0.0062 + (x_f[top, 2] - 8.5 * 0.0062) * 0.03
    sym.model.set_state(x_f, np.zeros_like(x_f))
    x_r = np.array(sym.model.x)
    f_r, f_f = np.zeros_like(x_r), np.zeros_like(x_f)
    n_r = (bc.bar_forces(x_r, ex_r.bar_contact, f_r, ALL)
           + bc.base_forces(x_r, ex_r.levels, ex_r.bar_contact, f_r))
    n_f = (bc.bar_forces(x_f, ex_f.bar_contact, f_f, ALL)
           + bc.base_forces(x_f, ex_f.levels, ex_f.bar_contact, f_f))
    assert n_r > 0 and n_f > n_r
    reps = np.asarray(reduced.reps)
    scale = np.max(np.abs(f_f))
    np.testing.assert_allclose(f_r, f_f[reps], atol=1e-12 * scale)
    e_r = (bc.bar_energy(x_r, ex_r.bar_contact)
           + bc.base_energy(x_r, ex_r.levels, ex_r.bar_contact, ex_r.per_level))
    e_f = (bc.bar_energy(x_f, ex_f.bar_contact)
           + bc.base_energy(x_f, ex_f.levels, ex_f.bar_contact, ex_f.per_level))
    assert e_f > 0 and math.isclose(e_r, e_f, rel_tol=1e-12)


@pytest.mark.parametrize('name, v0, period, count', [('fb_column', 0.1, 0.01, 20),
                                                     ('rb_column', 0.15, 0.05, 10)])
def test_a_train_of_impacts_keeps_every_prism_and_the_energy(name, v0, period, count):
    """The acceptance trains in short (tensegrity bench --only trains: 200 impacts each)."""
    sim = simulation_for(_scene(name))
    sign = np.sign(_twists(sim, np.asarray(sim.network.x0)))
    per = int(round(period / 0.005))
    worst = 0.0
    for k in range(count * per):
        if k % per == 0:
            sim.apply_impact(v0)
        sim.advance(0.005)
        f = sim.frame()
        assert np.all(f.strain < 1.0)                   # every prism height positive
        if name == 'rb_column':
            assert np.all(_twists(sim, f.positions) * sign > 0.0)      # never past 180 deg
        worst = max(worst, abs(sim.energy_error()))
    assert worst < sim.div.energy_error
    assert sim.contacts_met > 0


def _twists(sim, x):
    from solver.analysis.observables import prism_twists
    return prism_twists(x, sim.network.levels)


@pytest.mark.parametrize('name', ['fb_column', 'rb_column'])
def test_the_paper_regime_is_unchanged_where_no_contact_acts(name):
    """At 0.1, 0.125 and 0.15 m/s: where no contact force acted the run takes the line-bar
    steps and its summary equals the line-bar one to the last bit (near a closest approach the
    plain step is kept when it surely passed clear); where a contact acted, the run says so
    (its contact count)."""
    acted = []
    for v0 in (0.1, 0.125, 0.15):
        sets = [f'loading.impact.v0={v0}', 'run.t_end=1.2']
        with_bars = simulate(_scene(name), sets)
        line = simulate(_scene(name), sets + ['contact.bars=none'])
        if with_bars.sim.contacts_met:
            acted.append(v0)
            continue
        assert with_bars.sim.steps_taken == line.sim.steps_taken, v0
        a, b = with_bars.summary.to_json()['pulse'], line.summary.to_json()['pulse']
        for key, value in b.items():
            if isinstance(value, float):
                assert a[key] == value, (v0, key)
    assert len(acted) < 3, acted         # the bars act at most at the stronger impacts


def test_a_step_too_long_for_the_contact_is_stopped_by_the_energy_ledger():
    sim = simulation_for(_scene('fb_column', 'contact.resolution=4'))
    sim.apply_impact(1.0)
    with pytest.raises(SimulationDiverged) as info:
        while sim.t < 1.0:
            sim.advance(0.005)
    assert info.value.quantity == 'energy balance'
    assert '\n' not in str(info.value) and 'energy balance' in str(info.value)


@pytest.mark.parametrize('name', ['fb_column', 'rb_column'])
def test_pulse_figures_at_a_strong_impact_converge_as_the_step_is_halved(name):
    """0.3 m/s (three times the paper's strongest impact; bars touch in both columns): halving dt
    changes the leading pulse's amplitude, speed and snapshot speed by less than 1 %, and the
    contacts are resolved by the same control at both steps. (At 1 m/s the figures are not
    determined to 1 %: docs/physics.md section 7.1, `tensegrity bench --only trains`.)"""
    figures = []
    for scale in (1.0, 0.5):
        scene = _scene(name)
        point = simulate(scene, ['loading.impact.v0=0.3', 'run.t_end=0.6',
                                 f'integrator.dt={scene.integrator.dt * scale}'])
        assert point.sim.contacts_met > 0
        assert point.summary.to_json()['energy_balance_error'] < point.sim.div.energy_error
        figures.append(point.summary.to_json()['pulse'])
    coarse, fine = figures
    for key in ('amplitude', 'speed_m_s', 'speed_snapshot_m_s'):
        assert math.isclose(coarse[key], fine[key], rel_tol=0.01), (key, coarse[key], fine[key])


def test_fb_figures_at_1_m_s_converge_once_the_steps_resolve_the_contacts():
    """FB at 1 m/s: from the first refinement on (dt/2, 80 steps per contact) the amplitude and
    the snapshot speed at 0.5 s move by less than 1 % when every step control is halved again
    (at the scene's own steps the amplitude moves 1.5 %: docs/physics.md section 7.1)."""
    from solver.simulate.convergence import relative_change
    scene = _scene('fb_column')
    dt, res = scene.integrator.dt, scene.contact.resolution
    pulses = []
    for k in (1, 2):
        point = simulate(scene, ['loading.impact.v0=1.0', 'run.t_end=0.55',
                                 f'integrator.dt={dt / 2 ** k}',
                                 f'contact.resolution={res * 2 ** k}'])
        assert point.summary.to_json()['energy_balance_error'] < point.sim.div.energy_error
        pulses.append(point.summary.to_json()['pulse'])
    for key in ('amplitude', 'speed_snapshot_m_s'):
        assert relative_change(pulses[0][key], pulses[1][key]) < 0.01, key


def _raw_steps(sim, n):
    """``n`` steps of the integrator kernel on the model's arrays, no Simulation checks."""
    m = sim.model
    steps, status = sim.integrator.run(m.rec, m.data, m.work, sim.dt, n, sim.tol,
                                       sim.max_iter, sim.kinks)
    assert status == 0
    return m.x.copy(), m.v.copy()


@pytest.mark.parametrize('method', ['rk4_projected', 'dopri54_projected'])
def test_a_call_from_positions_the_scans_did_not_see_scans_again(method):
    """The contact scans carry their bounds from one integrator call to the next only while the
    positions are those the last call ended at. A column at rest (its scans: every pair far and
    still) is given, behind the kernels' back, the state of a column in a contact cascade: its
    next steps must find the contacts and equal, bit for bit, the steps of a copy of the
    cascade that carried its own bounds (both with the same refinement state of
    ``rk4_projected``: contacts met, the halving levels at 0)."""
    sets = [f'integrator.method={method}']
    hot = simulation_for(_scene('rb_column', *sets))
    hot.apply_impact(1.0)
    hot.advance(0.04)
    x, v = hot.model.x.copy(), hot.model.v.copy()
    met = hot.contacts_met
    twin = hot.clone()                 # carries the cascade's bounds
    twin.model.data.refine[:] = 0.0    # the levels a call from unknown positions starts at
    x1, v1 = _raw_steps(twin, 20)
    assert twin.contacts_met > met     # the 20 steps do meet contacts
    cold = simulation_for(_scene('rb_column', *sets))
    cold.advance(0.01)                 # at rest: its bounds say nothing can touch
    cold.model.x[:], cold.model.v[:] = x, v
    cold.model.data.contact.scan[MET] = met    # contacts met: rk4_projected refines as in the
    #                                            cascade
    # the same step-size history (an adaptive method's proposed step): only the scans differ
    cold.integrator.set_state(hot.integrator.get_state())
    x2, v2 = _raw_steps(cold, 20)
    assert cold.contacts_met == twin.contacts_met
    np.testing.assert_array_equal(x2, x1)
    np.testing.assert_array_equal(v2, v1)


def _pairs_known_apart(sim):
    """How many pairs the scans' bounds keep apart at the current positions (0 when the bounds
    do not hold there: see barcontact.bar_energy_scanned)."""
    m = sim.model
    state, pairs = m.data.contact.scan, m.rec.bar_contact.pairs
    k = state.shape[0] - m.x.size
    if not (np.isfinite(state[MOTION]) and np.array_equal(state[k:], m.x.ravel())):
        return 0
    return int(np.sum(state[HEAD:HEAD + pairs.shape[0]] - state[MOTION] > 0.0))


@pytest.mark.parametrize('name, method, v0', [('fb_column', 'rk4_projected', 1.0),
                                              ('fb_column', 'dopri54_projected', 1.0),
                                              ('fb_column', 'rattle', 0.1)])
def test_the_contact_energy_skips_only_pairs_that_store_none(name, method, v0):
    """The state summary leaves out the pairs whose gap the scans bound above zero. At the end of
    every interval of a run through contacts its contact energy must equal, bit for bit, the
    energy of every pair evaluated (barcontact.bar_energy), while most pairs are skipped; after
    positions set from outside every pair is evaluated."""
    sets = [f'integrator.method={method}']
    if method == 'rattle':              # second order: its energy error at the scene's dt
        sets.append('divergence.energy_error=0.01')
    sim = simulation_for(_scene(name, *sets))
    sim.apply_impact(v0)
    bars = sim.model.rec.bar_contact
    pairs = bars.pairs
    touching, skipped, snap = 0, 0, None
    for _ in range(150):
        sim.advance(0.001)
        m = sim.model
        e_all = bc.bar_energy(m.x, bars)
        assert bc.bar_energy_scanned(m.x, bars, m.data.contact.scan) == e_all
        if e_all > 0.0:
            touching += 1
            snap = m.x.copy()
        skipped = max(skipped, _pairs_known_apart(sim))
    assert skipped > pairs.shape[0] // 2          # the scans keep most pairs out of the sum
    if v0 < 0.2:
        return
    assert touching > 0                           # and contacts store energy in this run
    # touching positions put into a column at rest (its bounds: every pair far): all counted
    other = simulation_for(_scene(name, *sets))
    other.advance(0.005)
    other.model.x[:] = snap
    assert _pairs_known_apart(other) == 0
    e = bc.bar_energy(snap, bars)
    assert e > 0.0 and bc.bar_energy_scanned(snap, bars, other.model.data.contact.scan) == e


def _min_distance_over_step(x0, v, acc, h, n=201):
    """Least axis distance of two bars whose four ends move exactly as ``x0 + v t + acc t^2 / 2``
    over ``[0, h]``: a grid in time polished by a bounded scalar minimiser around its best
    point (``segment_params`` is checked against a brute-force search above)."""
    from scipy.optimize import minimize_scalar

    def dist(t):
        x = x0 + v * t + 0.5 * acc * t * t
        a0, a1, b0, b1 = x
        s, u = bc.segment_params(*a0, *(a1 - a0), *b0, *(b1 - b0))
        return float(np.linalg.norm(a0 + s * (a1 - a0) - b0 - u * (b1 - b0)))

    ts = np.linspace(0.0, h, n)
    d = [dist(t) for t in ts]
    k = int(np.argmin(d))
    lo, hi = ts[max(k - 1, 0)], ts[min(k + 1, n - 1)]
    polished = minimize_scalar(dist, bounds=(lo, hi), method='bounded',
                               options={'xatol': 1e-12 * h}).fun
    return min(min(d), polished)


def _axis_distance(x, pairs):
    s, t, nx, ny, nz = bc.pair(x, pairs, 0)
    return math.sqrt(nx * nx + ny * ny + nz * nz)


def test_the_near_miss_bound_never_passes_a_touch_and_passes_sliding_bars():
    """``_kept_apart`` (a step that passed clear of a close pair) against exact motions: two
    crossed bars 50 mm long sliding over each other at up to 0.1 m/s, turning, approaching and
    accelerating (up to 20 m/s^2) within a 3.3 ms step, the threshold ``D`` either between
    their least distance and the distances at both ends (a touch the ends do not see) or up to
    30 um below the least distance (a near miss). The bound must never pass a step whose true
    least distance reaches ``D``, and it must pass every near miss by more than ``A h^2 / 4``
    that the crude bound of the relative end speed (``g0 + g1 > 2 (V h + A h^2 / 2)``) refuses:
    the case of a twisting prism."""
    rng = np.random.default_rng(11)
    pairs = np.array([[0, 0, 1, 0, 2, 0, 3, 0]], dtype=np.int64)
    h, L = 1e-2 / 3, 0.05
    passed = refused_crude = passed_near = unsound = touching = 0
    for _ in range(400):
        ta, tb = rng.normal(size=3), rng.normal(size=3)
        ta /= np.linalg.norm(ta)
        tb -= (tb @ ta) * ta
        tb /= np.linalg.norm(tb)
        tb = np.cos(rng.uniform(0.3, 1.2)) * ta + np.sin(rng.uniform(0.3, 1.2)) * tb
        tb /= np.linalg.norm(tb)
        n = np.cross(ta, tb)
        n /= np.linalg.norm(n)
        ca = rng.uniform(-0.3, 0.3) * L * ta
        xm = np.array([ca - 0.5 * L * ta, ca + 0.5 * L * ta,     # crossed at mid-step
                       -0.5 * L * tb + 5e-4 * n, 0.5 * L * tb + 5e-4 * n])
        slide = rng.uniform(-0.1, 0.1, size=(4, 1)) * np.array([ta, ta, tb, tb])
        vm = slide + rng.normal(scale=0.01, size=(4, 3))
        vm[:2] += rng.uniform(-0.005, 0.005) * n          # bar a moves towards or away from b
        acc = rng.normal(scale=20.0 / 3 ** 0.5, size=(4, 3)) * rng.uniform(0.0, 1.0)
        x0 = xm - 0.5 * h * vm + 0.125 * h * h * acc       # the motion through xm at h / 2
        v = vm - 0.5 * h * acc
        x1 = x0 + v * h + 0.5 * acc * h * h
        true_min = _min_distance_over_step(x0, v, acc, h)
        ends = min(_axis_distance(x0, pairs), _axis_distance(x1, pairs))
        if rng.uniform() < 0.5:         # touches within the step, clear at both ends
            D = true_min + rng.uniform(0.0, 1.0) * (ends - true_min)
        else:                           # a near miss, by up to 30 um
            D = true_min - rng.uniform(0.0, 3e-5)
        if D >= ends:
            continue                                       # refused before either bound
        g0, g1 = _axis_distance(x0, pairs) - D, _axis_distance(x1, pairs) - D
        V, A = cs._reach(v, pairs[0]), cs._reach(acc, pairs[0])
        ok = cs._kept_apart(x0, x1, pairs, 0, D, V, A, h)
        if true_min <= D:
            touching += 1
            unsound += ok
            continue
        passed += ok
        if g0 + g1 <= 2.0 * (V * h + 0.5 * A * h * h) and true_min - D > A * h * h / 4.0:
            refused_crude += 1
            passed_near += ok
    assert touching > 20 and unsound == 0                 # never passes a step that touched
    assert refused_crude > 20
    assert passed_near == refused_crude                   # and keeps the near misses


@pytest.mark.parametrize('name, sets', [('fb_column', ()), ('fb_column', ('model=full3d',)),
                                        ('paper_rb', ()),
                                        ('rb_column', ('loading.impact.mode=striker',))])
def test_the_step_energy_is_the_state_summary_energy_where_no_contact_acts(name, sets):
    """``summary.step_energy`` (what a whole step beside a near miss is checked with, from the
    arrays the extras carry) equals the energy of the state summary (its own arrays) at states of
    a pulse where no bar touches: reduced and full models, lumped masses on the bases, a
    striker."""
    from solver.kernels import summary
    sim = simulation_for(_scene(name, *sets))
    sim.apply_impact(0.05)
    checked = 0
    for _ in range(8):
        sim.advance(0.005)
        m = sim.model
        if sim.contacts_met:
            break
        e = summary.step_energy(m.x, m.v, m.rec, m.data)
        assert e == pytest.approx(sim.energy(), rel=1e-12, abs=1e-15)
        checked += 1
    assert checked >= 3


def test_whole_steps_beside_contacts_keep_the_energy_balance():
    """``paper_rb`` (bars 0.54 mm thick) struck at 2 m/s: a cascade of contacts leaves the bars
    vibrating fast, and a whole step that passes clear of every contact can still be far too
    long for them (the run used to gain 5e-4 of its energy within 30 ms and stop). Such a step is
    now taken in contact steps: 0.1 s of the cascade keep the balance within the limit at every
    interval, as ``dopri54_projected``'s error control keeps it on the same run."""
    for method in ('rk4_projected', 'dopri54_projected'):
        sim = simulation_for(_scene('paper_rb', f'integrator.method={method}'))
        sim.apply_impact(2.0)
        worst = 0.0
        while sim.t < 0.1 - 1e-9:
            sim.advance(0.005)
            worst = max(worst, abs(sim.energy_error()))
        assert sim.contacts_met > 10_000
        assert worst < 0.5 * sim.div.energy_error, (method, worst)


def test_near_misses_at_a_long_step_keep_the_line_bar_steps():
    """The FB column at 0.1 m/s with 3.33 ms steps (no kink landing, the fastest configuration at
    strain error 1e-3): its bars pass within 0.02 mm of touching at the pulse's peak but never
    touch, and the run takes (within 1 %) the steps of line bars instead of approaching each near
    miss in short steps (418 steps instead of 300 with the crude bound alone)."""
    sets = ['prestrain=0.002', 'model=sym3d', 'integrator.land_on_kinks=false',
            f'integrator.dt={0.01 / 3!r}', 'run.output_dt=0.01', 'run.t_end=1.0',
            'loading.impact.v0=0.1', 'divergence.energy_error=0.1']   # peers: the strain decides
    with_bars = simulate(_scene('fb_column'), sets)
    line = simulate(_scene('fb_column'), sets + ['contact.bars=none'])
    assert with_bars.sim.contacts_met == 0
    assert line.sim.steps_taken == 300
    assert with_bars.sim.steps_taken <= 1.01 * line.sim.steps_taken
    assert with_bars.sim.model.rec.bar_contact.diameter == pytest.approx(2e-4)  # 0.2 mm bars
