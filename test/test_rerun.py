"""What a Rerun recording (tensegrity_ros/io/rerun_sink.py) holds, read back with rerun's own
reader (rerun_helpers.py): entities, the sim_time timeline, positions, strips, strain, energies
and errors against the solver's own frames, cable colours against an independent colour
computation (the ROS marker colours of messages.py), the topology against the network arrays,
the wave image, commands, a train, two columns, the base force, the blueprint's views, the bar
chart, the heat map and its grid, the field in the medium; ``tensegrity run --rerun`` and
``tensegrity lens --rerun``. The recorder's refusals, clock resets, viewers, killed processes,
closing and segment files: test_rerun_files.py."""
import numpy as np
import pytest

rr = pytest.importorskip('rerun')
from rerun.chunk import RrdReader  # noqa: E402

from solver.simulate.runner import run  # noqa: E402
from solver.build.scene import Scene  # noqa: E402
from solver.simulate.array import simulation_for  # noqa: E402
from tensegrity_ros.io.rerun_columns import heat_map_grid  # noqa: E402
from tensegrity_ros.io.rerun_sink import RerunRecorder  # noqa: E402
from tensegrity_ros.msgs.style import reference_tension_scale  # noqa: E402

from rerun_helpers import (FB, ROOT, at, blueprint_views, field_images, flat, read,  # noqa: E402
                           small_run, strips_at, symlog, tensor)


# -- fixtures ----------------------------------------------------------------------------------
@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    sim, frames, path = small_run(tmp_path_factory.mktemp('rerun'), flush_every=7)
    return sim, frames, read(path), path


# -- a recorded run against the solver ---------------------------------------------------------
def test_entities_timeline_and_frame_count(recorded):
    sim, frames, data, _ = recorded
    expected = {'/world/nodes', '/world/bars', '/world/cables', '/strain/column_0', '/energy',
                '/constraint_error', '/wave/column_0', '/commands', '/topology'}
    assert expected <= set(data)
    times = [round(f.t * 1e9) for f in frames]
    assert len(frames) == 21                          # t_end / output_dt + the first frame
    for ent in ('/world/nodes', '/world/bars', '/world/cables', '/strain/column_0', '/energy',
                '/constraint_error'):
        assert [t for t, _ in data[ent]['rows']] == times, ent


def test_values_equal_the_solver_frames_at_chosen_times(recorded):
    sim, frames, data, _ = recorded
    net = sim.network
    for f in (frames[0], frames[7], frames[13], frames[-1]):     # across flush boundaries (7)
        x = at(data['/world/nodes'], f.t, 'Points3D:positions').reshape(-1, 3)
        np.testing.assert_array_equal(x, f.positions.astype(np.float32))
        # bars as trails: consecutive points of a strip are the two ends of one bar, and every
        # bar is drawn exactly once
        drawn = sorted(tuple(sorted((tuple(p), tuple(q)))) for strip in strips_at(
            data['/world/bars'], f.t) for p, q in zip(strip[:-1], strip[1:]))
        x32 = f.positions.astype(np.float32)
        want = sorted(tuple(sorted((tuple(x32[a]), tuple(x32[b]))))
                      for a, b in zip(net.bar_a, net.bar_b))
        assert drawn == want
        cables = at(data['/world/cables'], f.t, 'LineStrips3D:strips').reshape(-1, 2, 3)
        np.testing.assert_array_equal(cables[:, 0], f.positions[net.cable_a].astype(np.float32))
        np.testing.assert_array_equal(cables[:, 1], f.positions[net.cable_b].astype(np.float32))
        np.testing.assert_array_equal(at(data['/strain/column_0'], f.t, 'Scalars:scalars'),
                                      f.strain[0])
        assert at(data['/energy'], f.t, 'Scalars:scalars')[0] == f.energy
        assert at(data['/constraint_error'], f.t, 'Scalars:scalars')[0] == f.constraint_error
        assert at(data['/energy_balance_error'], f.t, 'Scalars:scalars')[0] == \
            f.energy_balance_error
    assert frames[-1].strain.min() < -1e-3        # the wave is in the data compared


def test_cable_colours_follow_tension_and_dim_slack_cables(recorded):
    """Colour of a taut cable: u = T / scale clipped to [0, 1] as (u, 0.2 (1 - u), 1 - u), opaque
    (the ROS markers' law, written out here); slack cables grey and translucent."""
    sim, frames, data, _ = recorded
    scale = reference_tension_scale(sim.network)
    f = max(frames, key=lambda fr: int(np.sum(fr.tension <= 0)))
    slack = f.tension <= 0
    assert slack.any() and (~slack).any()
    packed = at(data['/world/cables'], f.t, 'LineStrips3D:colors').astype(np.uint32)
    rgba = np.stack([(packed >> s) & 0xFF for s in (24, 16, 8, 0)], axis=1).astype(float)
    u = np.clip(f.tension / scale, 0.0, 1.0)
    want = 255.0 * np.stack([u, 0.2 * (1 - u), 1 - u, np.ones_like(u)], axis=1)
    assert np.max(np.abs(rgba[~slack] - want[~slack])) <= 0.5          # rounded to 8 bits
    assert np.all(rgba[slack, 3] < 100) and np.all(rgba[slack, :3] == 128)


def test_topology_is_static_and_matches_the_network(recorded):
    sim, _, data, _ = recorded
    net, topo = sim.network, data['/topology']
    assert topo['rows'] == []                                  # static only
    for name in ('bar_a', 'bar_b', 'cable_a', 'cable_b'):
        np.testing.assert_array_equal(flat(topo['static'][name]), getattr(net, name))
    assert list(flat(topo['static']['cable_kind'])) == list(net.cable_kind)
    np.testing.assert_array_equal(flat(topo['static']['x0']).reshape(-1, 3), net.x0)
    shape = tuple(flat(topo['static']['levels_shape']))
    np.testing.assert_array_equal(flat(topo['static']['levels']).reshape(shape), net.levels)


def test_heat_map_follows_the_time_cursor_with_the_wave_so_far(recorded):
    """The heat map is logged on sim_time (nothing static: a static map would show at every
    time cursor): every 10th frame (wave_every) and the last, each the symmetric-log strain of
    every frame up to its time, across the batches of 7 frames."""
    sim, frames, data, _ = recorded
    wave = data['/wave/column_0']
    assert wave['static'] == {}
    times = [t for t, _ in wave['rows']]
    assert times == [round(frames[k].t * 1e9) for k in (9, 19, 20)]
    for row, t in enumerate(times):
        upto = [f for f in frames if round(f.t * 1e9) <= t]
        shape, values = tensor(wave, row)
        assert shape == (sim.network.n_prisms, len(upto))
        np.testing.assert_allclose(values.reshape(shape),
                                   symlog(np.stack([f.strain[0] for f in upto], axis=1)),
                                   rtol=1e-6, atol=1e-7)          # float32


def test_commands_are_text_events_and_a_blueprint_is_stored(recorded):
    _, _, data, path = recorded
    rows = data['/commands']['rows']
    assert [t for t, _ in rows] == [0]
    assert list(flat(rows[0][1]['TextLog:text'])) == ['impact v0 = 0.1 m/s']
    assert len(RrdReader(path).blueprints()) in (1, 2)    # 2: y ranges of constant series


def test_run_cli_records_what_the_solver_computes(tmp_path, capsys):
    import json

    from tensegrity_ros.cli import main
    args = ['run', str(FB), '--set', 'structure.n_prisms=4', '--set', 'model=full3d',
            '--t-end', '0.02', '--out', str(tmp_path), '--rerun', '--json']
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['outputs']['rerun'] == str(tmp_path / 'run.rrd')
    data = read(out['outputs']['rerun'])
    # the same scene run again without recording (the solver is deterministic)
    scene = Scene.load(FB).with_overrides(['structure.n_prisms=4', 'model=full3d'])
    sim = simulation_for(scene)
    sim.apply_impact(scene['loading.impact.v0'])
    frames = []
    run(sim, 0.02, scene['run.output_dt'], on_frame=frames.append)
    assert [t for t, _ in data['/energy']['rows']] == [round(f.t * 1e9) for f in frames]
    for f in frames:
        assert at(data['/energy'], f.t, 'Scalars:scalars')[0] == pytest.approx(f.energy,
                                                                                rel=1e-12)
    text = flat(data['/commands']['rows'][0][1]['TextLog:text'])[0]
    assert text.startswith(f"impact v0 = {scene['loading.impact.v0']:g} m/s")


def test_run_cli_records_a_train_and_the_energy_balance_error(tmp_path, capsys):
    """A train of 3 impacts: each is a command at its time (only the first starts the heat map),
    and the balance error of every frame is a series; frames without it (the node's) record
    none."""
    import json

    from tensegrity_ros.cli import main
    args = ['run', str(FB), '--set', 'structure.n_prisms=4', '--set', 'loading.impact.count=3',
            '--set', 'loading.impact.period=0.0075', '--t-end', '0.02', '--out', str(tmp_path),
            '--rerun', '--json']
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    data = read(out['outputs']['rerun'])
    texts = [(t, flat(r['TextLog:text'])[0]) for t, r in data['/commands']['rows']]
    assert texts == [(0, 'impact v0 = 0.1 m/s on all columns (1 of 3)'),
                     (7_500_000, 'train impact 2 of 3: v0 = 0.1 m/s on all columns'),
                     (15_000_000, 'train impact 3 of 3: v0 = 0.1 m/s on all columns')]
    rows = data['/energy_balance_error']['rows']
    assert [t for t, _ in rows] == [k * 5_000_000 for k in range(5)]
    errors = [abs(flat(r['Scalars:scalars'])[0]) for _, r in rows]
    assert max(errors) == out['energy_balance_error'] and 0 < max(errors) < 1e-4
    sim = simulation_for(Scene.load(FB).with_overrides(['structure.n_prisms=4']))
    with RerunRecorder(sim.network, tmp_path / 'plain.rrd') as rec:
        rec.frame(sim.frame())            # every Frame (the node's too) carries its balance error
    rows = read(tmp_path / 'plain.rrd')['/energy_balance_error']['rows']
    assert [(t, flat(r['Scalars:scalars'])[0]) for t, r in rows] == [(0, 0.0)]


def test_two_columns_record_one_strain_series_and_wave_per_column(tmp_path):
    scene = Scene.load(FB).with_overrides(['structure.n_prisms=4', 'structure.n_columns=2',
                                           'run.t_end=0.03', 'model=full3d'])
    sim = simulation_for(scene)
    sim.apply_impact(0.1, [1])                                 # column 1 only
    frames = []
    path = tmp_path / 'two.rrd'
    with RerunRecorder(sim.network, path, flush_every=4) as rec:
        run(sim, 0.03, scene['run.output_dt'], on_frame=lambda f: (frames.append(f),
                                                                   rec.frame(f)))
    data = read(path)
    for c in (0, 1):
        ent = data[f'/strain/column_{c}']
        assert [t for t, _ in ent['rows']] == [round(f.t * 1e9) for f in frames]
        for f in frames[::3]:
            np.testing.assert_array_equal(at(ent, f.t, 'Scalars:scalars'), f.strain[c])
        shape, values = tensor(data[f'/wave/column_{c}'])
        np.testing.assert_allclose(values.reshape(shape),
                                   symlog(np.stack([f.strain[c] for f in frames], axis=1)),
                                   rtol=1e-6, atol=1e-7)
    assert np.abs(frames[-1].strain[1]).max() > np.abs(frames[-1].strain[0]).max()


def test_base_force_series_per_column(recorded):
    """``base_force/column_0`` holds the frames' base force (N) at every frame time."""
    sim, frames, data, _ = recorded
    ent = data['/base_force/column_0']
    assert [t for t, _ in ent['rows']] == [round(f.t * 1e9) for f in frames]
    got = np.array([at(ent, f.t, 'Scalars:scalars')[0] for f in frames])
    want = np.array([f.base_force[0] for f in frames])
    np.testing.assert_array_equal(got, want)


# -- the layout --------------------------------------------------------------------------------
def test_the_stored_blueprint_holds_the_paper_style_views(recorded):
    _, _, _, path = recorded
    assert blueprint_views(path) == {
        ('3D', 'world'), ('TextDocument', 'legend'), ('BarChart', 'strain_profile/column_0'),
        ('BarChart', 'strain_profile_log/column_0'),
        ('Tensor', 'wave/column_0'), ('Tensor', 'wave_scale/column_0'),
        ('TimeSeries', 'base_force'), ('TimeSeries', 'energy'),
        ('TimeSeries', 'energy_balance_error'), ('TimeSeries', 'constraint_error'),
        ('TextLog', 'commands')}


def test_bar_chart_is_the_strain_per_prism_of_each_frame(recorded):
    sim, frames, data, _ = recorded
    ent = data['/strain_profile/column_0']
    assert [t for t, _ in ent['rows']] == [round(f.t * 1e9) for f in frames]
    for f in (frames[0], frames[7], frames[-1]):
        (tensor,), = [r['BarChart:values'].flatten().to_pylist() for t, r in ent['rows']
                      if t == round(f.t * 1e9)]
        assert tensor['shape'] == [sim.network.n_prisms]
        np.testing.assert_array_equal(tensor['buffer'], f.strain[0])
    # the y range: invisible zero-width bars at the run's strain extremes (static)
    (bars,) = [t['buffer'] for t in data['/strain_profile/column_0/range']['static']
               ['BarChart:values'].flatten().to_pylist()]
    all_strain = np.stack([f.strain[0] for f in frames])
    assert list(bars) == [all_strain.min(), all_strain.max()]
    # the symmetric-log chart: the same strain on the scale written out in rerun_helpers.symlog
    log = data['/strain_profile_log/column_0']
    for f in (frames[3], frames[-1]):
        (row,), = [r['BarChart:values'].flatten().to_pylist() for t, r in log['rows']
                   if t == round(f.t * 1e9)]
        np.testing.assert_allclose(row['buffer'], symlog(f.strain[0]), rtol=1e-12)
    (bars,) = [t['buffer'] for t in data['/strain_profile_log/column_0/range']['static']
               ['BarChart:values'].flatten().to_pylist()]
    np.testing.assert_allclose(bars, symlog([all_strain.min(), all_strain.max()]), rtol=1e-12)


def test_heat_map_starts_at_the_impact_on_a_sim_time_axis(tmp_path):
    """Idle frames before the impact command are left out; the heat map's columns are the
    frames on a uniform sim_time grid (5 ms here) from the impact, and its time axis says so."""
    scene = Scene.load(FB).with_overrides(['structure.n_prisms=6', 'model=full3d'])
    sim = simulation_for(scene)
    frames = []
    path = tmp_path / 'idle.rrd'
    with RerunRecorder(sim.network, path, flush_every=8) as rec:
        for k in range(18):
            if k == 10:                                    # 10 idle frames, then the impact
                t_impact = sim.t
                sim.apply_impact(0.1)
                rec.command(t_impact, 'impact v0 = 0.1 m/s')
            frames.append(sim.frame())
            rec.frame(frames[-1])
            sim.advance(0.005)
    data = read(path)
    after = [f for f in frames if f.t >= t_impact - 1e-12]
    assert len(after) < len(frames)
    shape, values = tensor(data['/wave/column_0'])
    assert shape == (6, len(after))                        # n_prisms rows, frames from impact
    np.testing.assert_allclose(values.reshape(shape),
                               symlog(np.stack([f.strain[0] for f in after], axis=1)),
                               rtol=1e-6, atol=1e-7)
    names = data['/wave/column_0']['rows'][-1][1]['Tensor:data'].flatten().to_pylist()[0][
        'names']
    assert names[0].startswith('prism')
    assert names[1] == (f'sim_time {after[0].t:.3f} to {after[-1].t:.3f} s, '
                        f'{1e3 * (after[1].t - after[0].t):.3g} ms per column')
    # the colour scale: the heat map's symmetric range as a gradient strip
    lo, hi = flat(data['/wave_scale/column_0']['rows'][-1][1]['Tensor:value_range'])
    lim = np.abs(values).max()
    assert (lo, hi) == (-lim, lim)
    _, scale = tensor(data['/wave_scale/column_0'])
    assert scale[0] == -lim and scale[-1] == lim and np.all(np.diff(scale) > 0)
    # its axis names the strain at 0, 1/4, 1/2, 3/4 and 1 of the width: the symmetric-log
    # scale inverted by hand, s = sign(y) 0.01 (10^|y| - 1)
    label = data['/wave_scale/column_0']['rows'][-1][1]['Tensor:data'].flatten().to_pylist()[0][
        'names'][1]
    ticks = [float(v) for v in label.rsplit(': ', 1)[1].split(', ')]
    big = np.abs(np.stack([f.strain[0] for f in after])).max()
    half = 0.01 * (10.0 ** (np.log10(1.0 + big / 0.01) / 2) - 1.0)
    assert ticks == pytest.approx([-big, -half, 0.0, half, big], rel=5e-3)


def test_heat_map_grid_resamples_uneven_frames_on_time():
    times = np.array([0.0, 0.1, 0.2, 0.21, 0.3, 0.5, 0.6])   # median step 0.1 s
    grid, pick = heat_map_grid(times, impact_t=0.1)
    np.testing.assert_allclose(grid, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    # the last frame at or before each grid time
    assert list(pick) == [1, 2, 4, 4, 5, 6]
    grid, pick = heat_map_grid(times, impact_t=5.0)           # no frame that late: all frames
    assert grid[0] == 0.0 and pick[0] == 0


def test_a_single_prism_records_its_bar_chart(tmp_path):
    """One prism: the strain of a batch is a strided view of the batch buffer unless copied."""
    sim = simulation_for(Scene.load(ROOT / 'config' / 'scenes' / 'prism.yaml'))
    sim.apply_impact(0.05)
    frames = []
    path = tmp_path / 'prism.rrd'
    with RerunRecorder(sim.network, path, flush_every=4) as rec:
        for _ in range(9):
            frames.append(sim.frame())
            rec.frame(frames[-1])
            sim.advance(0.005)
    ent = read(path)['/strain_profile/column_0']
    got = [r['BarChart:values'].flatten().to_pylist()[0]['buffer'] for _, r in ent['rows']]
    assert got == [list(f.strain[0]) for f in frames]


# -- the field in the medium -------------------------------------------------------------------
def test_field_images_are_the_given_maps_over_their_scale(tmp_path):
    """``field/peak_pressure`` holds the peak map over its scale, ``field/pressure`` the pressure
    mapped to 0.5 + 0.5 p / scale, at the given times; non-finite maps are refused; the
    blueprint gets the two views."""
    scene = Scene.load(FB).with_overrides(['structure.n_prisms=3', 'model=full3d'])
    sim = simulation_for(scene)
    path = tmp_path / 'field.rrd'
    rng = np.random.default_rng(3)
    maps = [(0.01 * k, rng.random((4, 6)) * k, rng.standard_normal((4, 6))) for k in (1, 2)]
    with RerunRecorder(sim.network, path, field_grid=(-0.04, 0.2, 0.0, 0.24)) as rec:
        rec.frame(sim.frame())
        for t, peak, p in maps:
            rec.field(t, peak, p, scale=2.0)
        with pytest.raises(ValueError, match='not finite'):
            rec.field(0.03, np.full((4, 6), np.nan))
        with pytest.raises(ValueError, match='one shape'):
            rec.field(0.03, np.ones((4, 6)), np.ones((3, 6)))
    data = read(path)
    peaks = field_images(data['/field/peak_pressure'])
    assert [t for t, _ in peaks] == [round(t * 1e9) for t, _, _ in maps]
    for (_, img), (_, peak, _) in zip(peaks, maps):
        np.testing.assert_allclose(img, np.clip(peak / 2.0, 0, 1), rtol=1e-6)
    for (_, img), (_, _, p) in zip(field_images(data['/field/pressure']), maps):
        np.testing.assert_allclose(img, np.clip(0.5 + 0.25 * p, 0, 1), rtol=1e-6)
    assert ('2D', 'field/peak_pressure') in blueprint_views(path)
    assert ('2D', 'field/pressure') in blueprint_views(path)


def test_lens_cli_records_the_field_over_sim_time(tmp_path, capsys, monkeypatch):
    """``tensegrity lens --rerun``: the check run's frames and, at every frame time and once
    after the record, the peak pressure so far, finite and growing, on the stated grid
    (48 x 64), largest at the end."""
    import yaml

    from tensegrity_ros.cli import main
    from solver.studies.lens_record import IMAGE_SHAPE
    monkeypatch.setenv('TENSEGRITY_CACHE', str(tmp_path / 'cache'))
    small = Scene.load(ROOT / 'config' / 'scenes' / 'lens_focus.yaml').with_overrides(
        ['structure.n_prisms=10', 'structure.n_columns=3', 'lens.grid=5', 'run.t_end=0.3'])
    scene = tmp_path / 'small_lens.yaml'
    scene.write_text(yaml.safe_dump(small.data))
    path = tmp_path / 'lens.rrd'
    assert main(['lens', str(scene), '--focus', '0.02,0.1', '--medium-speed', '2',
                 '--rerun', str(path)]) == 0
    assert str(path) in capsys.readouterr().out
    data = read(path)
    peaks = field_images(data['/field/peak_pressure'])
    frames = [t for t, _ in data['/world/nodes']['rows']]
    assert len(frames) == 61                                            # 0.3 s every 5 ms
    assert [t for t, _ in peaks][:-1] == frames and peaks[-1][0] > frames[-1]   # and after
    stack = np.array([img for _, img in peaks])
    assert stack.shape[1:] == IMAGE_SHAPE and np.isfinite(stack).all()
    assert np.all(np.diff(stack, axis=0) >= 0)                 # a peak so far only grows
    assert stack[0].max() == 0 and stack[-1].max() == pytest.approx(1.0)
    assert len(data['/field/pressure']['rows']) == len(frames) + 1
