"""Rerun recordings (tensegrity_ros/io/rerun_sink.py) read back with rerun's own reader.

rerun-sdk 0.41 has no ``rerun.dataframe`` module any more (its dataframe queries need the optional
``datafusion`` package); the recording is read with ``rerun.chunk.RrdReader``, chunk by chunk, as
Arrow record batches. Every value is compared with the solver's own frames, the network arrays or
an independent colour computation (the ROS marker colours of messages.py).
"""
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

rr = pytest.importorskip('rerun')
from rerun.chunk import RrdReader  # noqa: E402

from solver.simulate.runner import run  # noqa: E402
from solver.build.scene import Scene  # noqa: E402
from solver.simulate.array import simulation_for
from tensegrity_ros.io.rerun_columns import heat_map_grid  # noqa: E402
from tensegrity_ros.io.rerun_sink import RerunRecorder  # noqa: E402
from tensegrity_ros.msgs.style import reference_tension_scale  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FB = ROOT / 'config' / 'scenes' / 'fb_column.yaml'


# -- reading helpers ---------------------------------------------------------------------------
def flat(arr):
    """A nested Arrow list array -> 1-D numpy of its leaf values."""
    if isinstance(arr, pa.ChunkedArray):
        arr = arr.combine_chunks()
    while pa.types.is_list(arr.type) or pa.types.is_fixed_size_list(arr.type) \
            or pa.types.is_large_list(arr.type):
        arr = arr.flatten()
    return arr.to_numpy(zero_copy_only=False)


def read(path):
    """{entity_path: {'static': {component: row-0 Arrow value list}, 'rows': [(t_ns, {component:
    one-row Arrow slice})]}} of the first recording in ``path``, rows sorted by sim_time."""
    out = {}
    for chunk in RrdReader(path).stream():
        ent = out.setdefault(chunk.entity_path, {'static': {}, 'rows': []})
        rb = chunk.to_record_batch()
        comps = [n for n in rb.schema.names if n != 'sim_time' and not n.startswith('rerun.')]
        if chunk.is_static:
            for n in comps:
                ent['static'][n] = rb.column(n).slice(0, 1)
            continue
        assert chunk.timeline_names == ['sim_time']
        times = rb.column('sim_time').cast(pa.int64()).to_numpy()
        for i, t in enumerate(times):
            ent['rows'].append((int(t), {n: rb.column(n).slice(i, 1) for n in comps}))
    for ent in out.values():
        ent['rows'].sort(key=lambda r: r[0])
    return out


def at(ent, t, comp):
    """Leaf values of ``comp`` of the row at sim_time ``t`` s (exactly one row expected)."""
    ns = round(t * 1e9)
    rows = [r for tt, r in ent['rows'] if tt == ns and comp in r]
    assert len(rows) == 1, f'{len(rows)} rows at t = {t}'
    return flat(rows[0][comp])


def strips_at(ent, t):
    """The line strips of the row at sim_time ``t``: a list of (n_points, 3) float32 arrays."""
    ns = round(t * 1e9)
    rows = [r for tt, r in ent['rows'] if tt == ns]
    assert len(rows) == 1
    return [np.array(strip, dtype=np.float32)
            for strip in rows[0]['LineStrips3D:strips'].flatten().to_pylist()]


def tensor(ent, row=None):
    """(shape, float64 values) of the Tensor logged in row ``row``; by default the static one
    (the whole wave, written when the recording closes)."""
    data = (ent['static'] if row is None else ent['rows'][row][1])['Tensor:data'] \
        .flatten().to_pylist()
    assert len(data) == 1
    return tuple(data[0]['shape']), np.array(data[0]['buffer'], dtype=np.float64)


# -- fixtures ----------------------------------------------------------------------------------
def small_run(tmp_path, n_prisms=8, t_end=0.1, v0=0.1, **kw):
    scene = Scene.load(FB).with_overrides([f'structure.n_prisms={n_prisms}',
                                           f'run.t_end={t_end}', 'model=full3d'])
    sim = simulation_for(scene)
    sim.apply_impact(v0)
    frames = []
    path = tmp_path / 'run.rrd'
    with RerunRecorder(sim.network, path, **kw) as rec:
        rec.command(0.0, f'impact v0 = {v0} m/s')
        run(sim, t_end, scene['run.output_dt'], on_frame=lambda f: (frames.append(f),
                                                                        rec.frame(f)))
    return sim, frames, path


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    sim, frames, path = small_run(tmp_path_factory.mktemp('rerun'), flush_every=7)
    return sim, frames, read(path), path


# -- tests -------------------------------------------------------------------------------------
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


def test_wave_image_is_the_strain_of_every_frame(recorded):
    sim, frames, data, _ = recorded
    wave = data['/wave/column_0']
    assert 'Tensor:data' in wave['static']      # the whole wave, at every time
    shape, values = tensor(wave)
    assert shape == (sim.network.n_prisms, len(frames))
    np.testing.assert_array_equal(values.reshape(shape),
                                  np.stack([f.strain[0] for f in frames], axis=1))


def test_commands_are_text_events_and_a_blueprint_is_stored(recorded):
    _, _, data, path = recorded
    rows = data['/commands']['rows']
    assert [t for t, _ in rows] == [0]
    assert list(flat(rows[0][1]['TextLog:text'])) == ['impact v0 = 0.1 m/s']
    assert len(RrdReader(path).blueprints()) in (1, 2)    # 2: y ranges of constant series


def test_bad_frames_are_rejected_and_change_nothing(tmp_path):
    scene = Scene.load(FB).with_overrides(['structure.n_prisms=3'])
    sim = simulation_for(scene)
    good = sim.frame()
    path = tmp_path / 'bad.rrd'
    with RerunRecorder(sim.network, path) as rec:
        rec.frame(good)
        bad = sim.frame()
        bad.t = 0.01
        bad.positions[4, 2] = math.nan
        with pytest.raises(ValueError, match='non-finite positions'):
            rec.frame(bad)
        bad = sim.frame()
        bad.t = 0.01
        bad.tension = bad.tension[:-1]
        with pytest.raises(ValueError, match='does not match the network'):
            rec.frame(bad)
        assert rec.n_frames == 1
        rec.command(0.005, 'rejected ~/cmd/impact: velocity is not finite')
        with pytest.raises(ValueError, match='command time'):
            rec.command(math.nan, 'impact')
        later = sim.frame()
        later.t = 0.02
        rec.frame(later)
    data = read(path)
    assert [t for t, _ in data['/world/nodes']['rows']] == [0, 20_000_000]
    (t_cmd, cmd), = data['/commands']['rows']
    assert t_cmd == 5_000_000 and list(flat(cmd['TextLog:level'])) == ['WARN']
    for t in (0.0, 0.02):
        assert np.all(np.isfinite(at(data['/world/nodes'], t, 'Points3D:positions')))
    with pytest.raises(ValueError, match='file path or a viewer URL'):
        RerunRecorder(sim.network)
    with pytest.raises(ValueError, match='cannot record to'):
        RerunRecorder(sim.network, tmp_path / 'no_such_dir' / 'x.rrd')
    with pytest.raises(ValueError, match='tension_scale'):
        RerunRecorder(sim.network, tmp_path / 'x.rrd', tension_scale=-1.0)


def test_a_reset_clock_keeps_recording(tmp_path):
    """The node resets the simulation (t back to 0): both stretches are kept."""
    scene = Scene.load(FB).with_overrides(['structure.n_prisms=3'])
    sim = simulation_for(scene)
    path = tmp_path / 'reset.rrd'
    with RerunRecorder(sim.network, path, flush_every=4) as rec:
        for stretch in range(2):
            sim.reset()
            sim.apply_impact(0.05 * (stretch + 1))
            for _ in range(3):
                rec.frame(sim.frame())
                sim.advance(0.005)
        assert rec.n_restarts == 1
    rows = read(path)['/energy']['rows']
    assert [t for t, _ in rows] == [0, 0, 5_000_000, 5_000_000, 10_000_000, 10_000_000]


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


def test_connect_needs_a_listening_viewer(tmp_path):
    scene = Scene.load(FB).with_overrides(['structure.n_prisms=3'])
    net = simulation_for(scene).network
    with socket.socket() as s:                   # a port nobody listens on
        s.bind(('127.0.0.1', 0))
        port = s.getsockname()[1]
    with pytest.raises(ValueError, match='no viewer listening'):
        RerunRecorder(net, connect=f'rerun+http://127.0.0.1:{port}/proxy')
    with pytest.raises(ValueError, match='not a viewer URL'):
        RerunRecorder(net, connect='localhost:9876')


@pytest.mark.filterwarnings('ignore:RRD file has no footer')
def test_connect_streams_to_a_running_viewer(tmp_path):
    """A headless Rerun server (``rerun --save``) stands in for the viewer."""
    exe = Path(sys.executable).parent / 'rerun'
    if not exe.exists():
        pytest.skip('rerun CLI not installed')
    env = dict(os.environ, HOME=str(tmp_path), XDG_CONFIG_HOME=str(tmp_path / 'cfg'),
               XDG_DATA_HOME=str(tmp_path / 'data'), XDG_CACHE_HOME=str(tmp_path / 'cache'))
    subprocess.run([str(exe), 'analytics', 'disable'], env=env, timeout=60,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        port = s.getsockname()[1]
    saved = tmp_path / 'viewer.rrd'
    # own process group: the `rerun` script starts the viewer binary as a child, which a plain
    # terminate() would leave running after the test
    server = subprocess.Popen([str(exe), '--bind', '127.0.0.1', '--port', str(port),
                               '--save', str(saved)], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                socket.create_connection(('127.0.0.1', port), timeout=0.5).close()
                break
            except OSError:
                assert time.monotonic() < deadline, 'rerun server did not start'
                time.sleep(0.2)
        scene = Scene.load(FB).with_overrides(['structure.n_prisms=3', 'model=full3d'])
        sim = simulation_for(scene)
        sim.apply_impact(0.1)
        frames = []
        with RerunRecorder(sim.network, connect=f'rerun+http://127.0.0.1:{port}/proxy',
                           flush_every=4) as rec:
            run(sim, 0.03, 0.005, on_frame=lambda f: (frames.append(f), rec.frame(f)))
        deadline = time.monotonic() + 30
        while True:                              # the server writes what it received
            try:
                rows = read(saved).get('/energy', {'rows': []})['rows']
            except Exception:
                rows = []
            if len(rows) == len(frames) or time.monotonic() > deadline:
                break
            time.sleep(0.3)
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)
    data = read(saved)
    assert [t for t, _ in data['/energy']['rows']] == [round(f.t * 1e9) for f in frames]
    f = frames[4]
    np.testing.assert_array_equal(at(data['/strain/column_0'], f.t, 'Scalars:scalars'),
                                  f.strain[0])


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
        np.testing.assert_array_equal(values.reshape(shape),
                                      np.stack([f.strain[c] for f in frames], axis=1))
    assert np.abs(frames[-1].strain[1]).max() > np.abs(frames[-1].strain[0]).max()


def test_a_killed_recording_keeps_what_sync_wrote(tmp_path):
    """SIGKILL of the recording process after sync(): the file holds the 100 frames sent until
    then, readable, and nothing of the frames buffered after them."""
    path = tmp_path / 'killed.rrd'
    code = f'''
import time
from solver.build.scene import Scene
from solver.simulate.array import simulation_for
from tensegrity_ros.io.rerun_sink import RerunRecorder
sim = simulation_for(Scene.load({str(FB)!r}).with_overrides(['structure.n_prisms=3']))
rec = RerunRecorder(sim.network, {str(path)!r}, flush_every=50, max_latency_s=1e9)
for k in range(120):
    if k == 100:
        rec.sync()
        print('ready', flush=True)
    rec.frame(sim.frame())
    sim.advance(0.005)
time.sleep(120)
'''
    proc = subprocess.Popen([sys.executable, '-c', code], cwd=ROOT, stdout=subprocess.PIPE,
                            text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    try:
        assert proc.stdout.readline().split() == ['ready']
    finally:
        proc.kill()
        proc.wait(timeout=30)
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')                 # no footer: the process was killed
        rows = read(path)['/energy']['rows']
    assert [t for t, _ in rows] == [k * 5_000_000 for k in range(100)]


# -- the helper process ------------------------------------------------------------------------
def _read_checked(path):
    """read(path), failing on any warning of rerun's reader (e.g. a missing footer)."""
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        return read(path)


def test_close_returns_with_the_file_complete(tmp_path):
    """When close() returns, the file holds every frame, the static entities and the blueprint,
    and ends with its footer."""
    scene = Scene.load(FB).with_overrides(['structure.n_prisms=3'])
    sim = simulation_for(scene)
    path = tmp_path / 'complete.rrd'
    rec = RerunRecorder(sim.network, path, flush_every=4)
    for k in range(11):                               # two batches and three frames buffered
        rec.frame(sim.frame())
        sim.advance(0.005)
    rec.close()
    data = _read_checked(path)
    assert [t for t, _ in data['/energy']['rows']] == [k * 5_000_000 for k in range(11)]
    assert data['/topology']['static'] and len(RrdReader(path).blueprints()) in (1, 2)
    rec.close()                                       # idempotent
    with pytest.raises(ValueError, match='closed'):
        rec.frame(sim.frame())


def test_values_beyond_float32_are_refused(tmp_path):
    scene = Scene.load(FB).with_overrides(['structure.n_prisms=3'])
    sim = simulation_for(scene)
    path = tmp_path / 'huge.rrd'
    with RerunRecorder(sim.network, path) as rec:
        bad = sim.frame()
        bad.positions[2, 0] = 1e39                    # finite, but not as float32
        with pytest.raises(ValueError, match='beyond float32'):
            rec.frame(bad)
        assert rec.n_frames == 0
        rec.frame(sim.frame())
    assert [t for t, _ in read(path)['/world/nodes']['rows']] == [0]


def test_recording_over_an_old_file_replaces_it(tmp_path):
    old = tmp_path / 'run.rrd'
    old.write_bytes(b'not a recording ' * 4096)         # e.g. the previous run's file
    sim, frames, path = small_run(tmp_path, t_end=0.03, flush_every=4)
    assert path == old
    data = read(path)
    assert [t for t, _ in data['/energy']['rows']] == [round(f.t * 1e9) for f in frames]
    assert b'not a recording' not in path.read_bytes()


def test_base_force_series_per_column(recorded):
    """``base_force/column_0`` holds the frames' base force (N) at every frame time."""
    sim, frames, data, _ = recorded
    ent = data['/base_force/column_0']
    assert [t for t, _ in ent['rows']] == [round(f.t * 1e9) for f in frames]
    got = np.array([at(ent, f.t, 'Scalars:scalars')[0] for f in frames])
    want = np.array([f.base_force[0] for f in frames])
    np.testing.assert_array_equal(got, want)


# -- the layout --------------------------------------------------------------------------------
def blueprint_views(path):
    """{(view class, origin)} of the blueprint stored in the recording file ``path`` (the last
    one sent: the recorder sends it again on close when a series stayed constant)."""
    reader = RrdReader(path)
    store = reader.blueprints()[-1]
    views = set()
    for chunk in reader.stream(store=store):
        rb = chunk.to_record_batch()
        if 'ViewBlueprint:class_identifier' in rb.schema.names:
            for cls, origin in zip(rb.column('ViewBlueprint:class_identifier').to_pylist(),
                                   rb.column('ViewBlueprint:space_origin').to_pylist()):
                views.add((cls[0], origin[0]))
    return views


def test_the_stored_blueprint_holds_the_paper_style_views(recorded):
    _, _, _, path = recorded
    assert blueprint_views(path) == {
        ('3D', 'world'), ('TextDocument', 'legend'), ('BarChart', 'strain_profile/column_0'),
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
    np.testing.assert_array_equal(values.reshape(shape),
                                  np.stack([f.strain[0] for f in after], axis=1))
    names = data['/wave/column_0']['static']['Tensor:data'].flatten().to_pylist()[0]['names']
    assert names[0].startswith('prism')
    assert names[1] == (f'sim_time {after[0].t:.3f} to {after[-1].t:.3f} s, '
                        f'{1e3 * (after[1].t - after[0].t):.3g} ms per column')
    # the colour scale: the heat map's symmetric range as a gradient strip
    lo, hi = flat(data['/wave_scale/column_0']['static']['Tensor:value_range'])
    lim = np.abs(values).max()
    assert (lo, hi) == (-lim, lim)
    _, scale = tensor(data['/wave_scale/column_0'])
    assert scale[0] == -lim and scale[-1] == lim and np.all(np.diff(scale) > 0)


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
def field_images(ent):
    """[(t_ns, (height, width) float32 image)] of an Image entity."""
    out = []
    for t, row in ent['rows']:
        fmt = row['Image:format'].flatten().to_pylist()[0]
        assert fmt['color_model'] == 1                       # L: one channel
        raw = np.array(row['Image:buffer'].flatten().flatten().to_pylist(), dtype=np.uint8)
        out.append((t, raw.view(np.float32).reshape(fmt['height'], fmt['width'])))
    return out


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


def test_commands_between_frames_are_all_recorded_in_order(tmp_path):
    """2,500 commands between the frames of a run and more while no frame comes (a paused node)
    are all in the file, in order, with their times, texts and levels."""
    scene = Scene.load(FB).with_overrides(['structure.n_prisms=3'])
    sim = simulation_for(scene)
    path = tmp_path / 'flood.rrd'
    sent = []
    with RerunRecorder(sim.network, path, flush_every=4, max_latency_s=0.2) as rec:
        for k in range(10):
            rec.frame(sim.frame())
            for j in range(250):
                text = f'impact v0 = {k}.{j:03d} m/s' if j % 5 else f'rejected {k}.{j:03d}'
                rec.command(sim.t, text)
                sent.append((round(sim.t * 1e9), text, 'WARN' if j % 5 == 0 else 'INFO'))
            sim.advance(0.005)
        for j in range(4):                      # paused: no frames come
            rec.command(sim.t, f'reset {j}')
            sent.append((round(sim.t * 1e9), f'reset {j}', 'INFO'))
        assert rec.n_commands == len(sent)
    rows = read(path)['/commands']['rows']
    got = [(t, str(flat(r['TextLog:text'])[0]), str(flat(r['TextLog:level'])[0]))
           for t, r in rows]
    assert got == sent


def test_a_long_recording_goes_on_in_segment_files_of_one_recording(tmp_path):
    """Past ``split_frames`` frames a file is finished (its footer written) and the recording
    goes on in run_1.rrd, run_2.rrd: every file complete with the static entities, the
    blueprint in the first, one recording id, every frame once, in order; an earlier
    recording's segments are removed; the process's threads do not grow with the files (a
    recorder keeps the 4 native threads of its stream and blueprint; a stream or blueprint per
    file would add 2 more each)."""
    psutil = pytest.importorskip('psutil')
    threads = psutil.Process().num_threads()
    from tensegrity_ros.io.rerun_sink import segment_files
    for k in (1, 2, 3):                 # an earlier, longer recording's segments
        (tmp_path / f'run_{k}.rrd').write_bytes(b'old')
    sim, frames, path = small_run(tmp_path, t_end=0.2, flush_every=6, split_frames=10)
    files = segment_files(path)
    assert [f.name for f in files] == ['run.rrd', 'run_1.rrd', 'run_2.rrd', 'run_3.rrd']
    assert len(frames) == 41            # batches of 6: 12 frames in each of the first three
    times, ids = [], set()
    for f in files:
        data = _read_checked(f)
        assert data['/topology']['static']
        times += [t for t, _ in data['/energy']['rows']]
        ids |= {str(r) for r in RrdReader(f).recordings()}
    assert times == [round(fr.t * 1e9) for fr in frames]
    assert len(ids) == 1, ids
    assert RrdReader(files[0]).blueprints()
    assert b'old' not in files[-1].read_bytes()
    assert psutil.Process().num_threads() - threads <= 4


def test_split_frames_below_one_is_refused(tmp_path):
    sim = simulation_for(Scene.load(FB).with_overrides(['structure.n_prisms=3']))
    with pytest.raises(ValueError, match='split_frames must be at least 1'):
        RerunRecorder(sim.network, tmp_path / 'x.rrd', split_frames=0)
    assert not (tmp_path / 'x.rrd').exists()
