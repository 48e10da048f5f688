"""Arrays of independent columns: one reduced simulation per column against the whole array in
full3d (the slower obvious twin), shared simulations of alike columns against one simulation per
column (bit for bit), splits, expansion of one column, divergence naming its column."""
import numpy as np
import pytest

from solver.simulate.array import ArraySimulation
from solver.build.scene import Scene
from solver.simulate.simulation import Simulation, SimulationDiverged
from solver.simulate.array import simulation_for

LENS = 'config/scenes/lens_array.yaml'


def _scene(*sets):
    return Scene.load(LENS).with_overrides(['structure.n_prisms=15', *sets])


def _close(a, b, what):
    """Positions within 1e-9 of the column height; forces (tensions, base forces) are stiffness
    times position, and the energy force times position: within 1e-7 of their largest value."""
    fa, fb = a.frame(), b.frame()
    height = a.network.n_prisms * a.network.h0
    assert np.max(np.abs(fa.positions - fb.positions)) <= 1e-9 * height, what
    t_scale = np.max(np.abs(fb.tension))
    assert np.max(np.abs(fa.tension - fb.tension)) <= 1e-7 * t_scale, what
    b_scale = max(np.max(np.abs(fb.base_force)), t_scale)      # a sum of member forces
    assert np.max(np.abs(fa.base_force - fb.base_force)) <= 1e-7 * b_scale, what
    np.testing.assert_allclose(fa.strain, fb.strain, rtol=0, atol=1e-7)
    assert fa.energy == pytest.approx(fb.energy, rel=1e-7)


def test_auto_runs_an_array_per_column_and_full3d_on_request():
    sim = simulation_for(_scene())
    assert isinstance(sim, ArraySimulation) and sim.model.name == 'sym3d'
    assert sim.n_simulated == 1                         # five alike columns, one simulation
    full = simulation_for(_scene('model=full3d'))
    assert type(full) is Simulation and full.model.name == 'full3d'


def test_per_column_reduction_equals_full3d_with_different_prestrains():
    # line bars: with contact each group's steps follow its own contacts, so the step sequences
    # (and the results, within the integration error) differ from one full3d run's
    arr = simulation_for(_scene('contact.bars=none'))
    full = simulation_for(_scene('model=full3d', 'contact.bars=none'))
    p = [0.001, 0.0025, 0.004, 0.003, 0.0015]
    for s in (arr, full):
        s.apply_prestrain(p)
        s.apply_impact([0.1, 0.08, 0.1, 0.12, 0.1])
    assert arr.n_simulated == 5 and arr.model.name == 'sym3d'
    moved = 0.0
    for _ in range(4):
        for s in (arr, full):
            s.advance(0.04)
        _close(arr, full, f't = {arr.t:g}')
        moved = max(moved, np.max(np.abs(full.frame().positions - full.network.x0)))
    assert moved > 1e-4                                  # the waves have moved the nodes
    assert np.max(np.abs(full.frame().base_force)) > 1e-4
    np.testing.assert_array_equal(arr.prestrain, full.prestrain)


def _commands(sim):
    """The same command sequence; returns the frames after each stage."""
    frames = []
    sim.apply_impact(0.1)
    sim.advance(0.03)
    frames.append(sim.frame())
    sim.apply_prestrain(0.004, columns=[2], ramp_s=0.01)          # column 2 alone: a split
    sim.advance(0.03)
    frames.append(sim.frame())
    sim.apply_impact([0.05], columns=[4])                           # column 4 alone
    sim.advance(0.03)
    frames.append(sim.frame())
    sim.apply_prestrain([0.004, 0.004], columns=[0, 1])             # alike again, not merged
    sim.advance(0.02)
    frames.append(sim.frame())
    return frames


def test_shared_array_equals_one_simulation_per_column_exactly_and_splits():
    shared = ArraySimulation(_scene())
    plain = ArraySimulation(_scene(), dedup=False)
    assert (shared.n_simulated, plain.n_simulated) == (1, 5)
    counts = []
    fs = _commands(shared)
    counts = shared.n_simulated
    fp = _commands(plain)
    for a, b in zip(fs, fp):
        for name in ('positions', 'strain', 'tension', 'base_force'):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        assert a.energy == b.energy and a.t == b.t
    assert counts == 4                   # {0, 1}, {2}, {3}, {4}
    assert sorted(g.columns for g in shared.groups) == [[0, 1], [2], [3], [4]]
    # and the split array is right, not only self-consistent: the full3d twin (line bars: the
    # full3d contact scan of five columns is slow, and with contact the step sequences differ)
    line = ArraySimulation(_scene('contact.bars=none'))
    full = simulation_for(_scene('model=full3d', 'contact.bars=none'))
    for sim in (line, full):
        _commands(sim)
    assert sorted(g.columns for g in line.groups) == [[0, 1], [2], [3], [4]]
    _close(line, full, 'after the splits')


def test_asymmetric_cables_expand_only_their_column():
    arr, full = simulation_for(_scene()), simulation_for(_scene('model=full3d'))
    rest = np.array(arr.model.cable_rest_length)
    k = arr.network.n_cables // 5
    rest[k + 4] *= 1.0005                                 # one cross cable of column 1
    for s in (arr, full):
        s.set_cable_rest_lengths(rest)
        s.apply_impact(0.1)
        s.advance(0.06)
    names = {tuple(g.columns): g.sim.model.name for g in arr.groups}
    assert names == {(0, 2, 3, 4): 'sym3d', (1,): 'full3d'}
    assert arr.model.name == 'full3d+sym3d' and 'columns [1]' in arr.expanded
    _close(arr, full, 'one column expanded')


def test_divergence_names_the_column_and_restores_every_column():
    arr = simulation_for(_scene('contact.bars=none'))       # line bars: 3 m/s breaks a column
    arr.apply_impact(0.1)
    arr.advance(0.02)
    arr.apply_impact([3.0], columns=[3])                  # far beyond what column 3 survives
    before = arr.frame()
    with pytest.raises(SimulationDiverged, match='column 3'):
        for _ in range(40):
            before = arr.frame()
            arr.advance(0.01)
    after = arr.frame()
    assert after.t == before.t
    for name in ('positions', 'strain', 'tension'):
        np.testing.assert_array_equal(getattr(after, name), getattr(before, name))


@pytest.mark.parametrize('bad', [float('nan'), 0.7, [0.1, 0.2]])
def test_bad_commands_change_nothing(bad):
    arr = simulation_for(_scene())
    arr.apply_impact(0.1)
    arr.advance(0.01)
    f0, groups = arr.frame(), arr.n_simulated
    with pytest.raises(ValueError, match='prestrain'):
        arr.apply_prestrain(bad, columns=[1, 2, 3])
    with pytest.raises(ValueError, match='impact'):
        arr.apply_impact([0.1, float('nan')], columns=[0, 7] if bad == 0.7 else [0, 1])
    f1 = arr.frame()
    assert arr.n_simulated == groups
    np.testing.assert_array_equal(f0.positions, f1.positions)


@pytest.mark.parametrize('method', ['rk4_projected', 'rattle', 'dopri54_projected',
                                    'implicit_midpoint'])
def test_columns_of_an_array_step_as_if_alone_with_every_method(method):
    """The columns of an array step at once on threads, each on its own copy of the simulation:
    with different prestrains each column must end where the column run alone ends, to the last
    bit, whatever scratch arrays and step-size history its integrator keeps."""
    sets = ['structure.n_prisms=8', 'structure.n_columns=4', f'integrator.method={method}',
            'divergence.energy_error=0.01']
    if method == 'implicit_midpoint':
        sets.append('contact.bars=none')        # it refuses bar contact
    ps = [0.001, 0.002, 0.004, 0.003]
    arr = simulation_for(_scene(*sets))
    arr.apply_prestrain(ps)
    arr.apply_impact(0.1)
    for _ in range(30):
        arr.advance(0.005)
    assert len(arr.groups) == 4
    for c, p in enumerate(ps):
        alone = simulation_for(_scene(*sets, 'structure.n_columns=1'))
        alone.apply_prestrain(p)
        alone.apply_impact(0.1)
        for _ in range(30):
            alone.advance(0.005)
        g = next(g for g in arr.groups if c in g.columns)
        np.testing.assert_array_equal(g.sim.model.x, alone.model.x, err_msg=f'column {c}')
        np.testing.assert_array_equal(g.sim.model.v, alone.model.v, err_msg=f'column {c}')


def test_the_array_frame_equals_the_frames_of_its_column_simulations():
    """ArraySimulation.frame against the frames of its column simulations, put side by side
    here (each column's positions shifted by its place in the row): equal bit for bit, with
    alike columns sharing a simulation, one column expanded to full3d (a cable of its own
    changed), and contact after a 1 m/s impact."""
    sim = simulation_for(_scene())
    rest = np.array(sim.model.cable_rest_length)
    rest[sim.network.n_cables // 5 + 4] *= 1.0005        # one cross cable of column 1
    sim.set_cable_rest_lengths(rest)
    sim.apply_impact(1.0, columns=[1, 3])
    spacing = sim.scene.structure.column_spacing
    n, k = sim.network.n_nodes // 5, sim.network.n_cables // 5
    for _ in range(12):
        sim.advance(0.005)
        got = sim.frame()
        energies, worst = [0.0] * 5, 0.0
        for g in sim.groups:
            f = g.sim.frame()
            for c in g.columns:
                assert np.array_equal(got.positions[c * n:(c + 1) * n],
                                      f.positions + np.array([c * spacing, 0.0, 0.0]))
                assert np.array_equal(got.tension[c * k:(c + 1) * k], f.tension)
                assert np.array_equal(got.strain[c], f.strain[0])
                assert got.base_force[c] == f.base_force[0]
                energies[c] = f.energy
            worst = max(worst, f.constraint_error)
        assert got.energy == float(sum(energies)) and got.constraint_error == worst
    names = {tuple(g.columns): g.sim.model.name for g in sim.groups}
    assert names == {(0, 2, 4): 'sym3d', (1,): 'full3d', (3,): 'sym3d'}
    assert sim.contacts_met > 0


def test_a_command_on_every_column_builds_their_prestrain_map_once():
    """Distinct prestrains split the array into one simulation per column; the columns share one
    prestrain map (built once for the command), equal to a map built afresh from a column's
    network; each column then holds its own prestrain."""
    from solver.build.structures import PrestrainMap
    sim = simulation_for(_scene())
    p = np.linspace(0.02, 0.06, sim.n_columns)
    sim.apply_prestrain(p)
    maps = [g.sim.prestrain_map for g in sim.groups]
    assert len(maps) == sim.n_columns and all(m is maps[0] for m in maps)
    fresh = PrestrainMap(sim.groups[-1].sim.network)
    for name in ('length', 'cross', 'cross_prism', 'base', 'base_prisms', 'radius',
                 'cross_count'):
        assert np.array_equal(getattr(maps[0], name), getattr(fresh, name)), name
    np.testing.assert_allclose(sim.prestrain, p[:, None] * np.ones((1, sim.network.n_prisms)),
                               rtol=1e-12)
