"""The Rerun recorder (tensegrity_ros/io/rerun_sink.py) as a writer of files and streams, read
back with rerun's own reader (rerun_helpers.py): bad frames and values beyond float32 refused,
changing nothing; a reset clock; a viewer URL without a viewer, and streaming to a headless
``rerun --save`` stand-in; a recording process killed after ``sync()``; the file complete when
``close()`` returns; an old file replaced; thousands of commands between frames, in order; long
recordings split into segment files of one recording. What a recording holds:
test_rerun.py."""
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

rr = pytest.importorskip('rerun')
from rerun.chunk import RrdReader  # noqa: E402

from solver.simulate.runner import run  # noqa: E402
from solver.build.scene import Scene  # noqa: E402
from solver.simulate.array import simulation_for  # noqa: E402
from tensegrity_ros.io.rerun_sink import RerunRecorder  # noqa: E402

from rerun_helpers import FB, ROOT, at, flat, read, small_run  # noqa: E402


# -- refused input, a reset clock --------------------------------------------------------------
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


def test_split_frames_below_one_is_refused(tmp_path):
    sim = simulation_for(Scene.load(FB).with_overrides(['structure.n_prisms=3']))
    with pytest.raises(ValueError, match='split_frames must be at least 1'):
        RerunRecorder(sim.network, tmp_path / 'x.rrd', split_frames=0)
    assert not (tmp_path / 'x.rrd').exists()


# -- viewers -----------------------------------------------------------------------------------
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


# -- the helper process and the files ----------------------------------------------------------
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


def test_recording_over_an_old_file_replaces_it(tmp_path):
    old = tmp_path / 'run.rrd'
    old.write_bytes(b'not a recording ' * 4096)         # e.g. the previous run's file
    sim, frames, path = small_run(tmp_path, t_end=0.03, flush_every=4)
    assert path == old
    data = read(path)
    assert [t for t, _ in data['/energy']['rows']] == [round(f.t * 1e9) for f in frames]
    assert b'not a recording' not in path.read_bytes()


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
