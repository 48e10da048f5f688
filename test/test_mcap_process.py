"""MCAP logs across processes: a SIGKILLed recording, SIGINT/SIGTERM, replay over real rclpy to a
subscriber, and ``tensegrity run --mcap`` against the same run recorded in memory."""
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from mcap_helpers import ROOT, record_frames, small_network, synthetic_frames

pytest.importorskip('rclpy')

from tensegrity_ros.msgs import messages as M  # noqa: E402
from tensegrity_ros.io.mcap_reader import McapLog, load_run  # noqa: E402

# A recording child: frame k has strain k and node coordinates k, stamp k ms. After `n_fast`
# frames it waits until the background flush has handed them to the OS, says so, then keeps
# writing one frame every 2 ms (so a kill lands inside an open chunk) or idles ('idle').
CHILD = r'''
import faulthandler, signal, sys, time
faulthandler.register(signal.SIGUSR1)      # the test asks for the stacks if the child hangs
import numpy as np
from tensegrity_ros.msgs import messages as M
from tensegrity_ros.io.mcap_writer import McapRecorder, signals_as_interrupt
path, n_fast, mode = sys.argv[1], int(sys.argv[2]), sys.argv[3]
strain, nodes = M.resolve_topic('~/strain'), M.resolve_topic('~/nodes')
def write(rec, k):
    ns = k * 1_000_000
    rec.write(strain, M.multi_array(np.full((1, 3), float(k)), ('column', 'prism')), ns)
    rec.write(nodes, M.nodes_cloud(np.full((4, 3), float(k)), M.sim_stamp(k * 1e-3)), ns)
try:
    with signals_as_interrupt(), McapRecorder(path, chunk_size=2048, flush_period_s=0.05) as rec:
        for k in range(n_fast):
            write(rec, k)
        while rec.pending:
            time.sleep(0.005)
        print('flushed', n_fast, flush=True)
        k = n_fast
        while True:
            if mode == 'write':
                write(rec, k)
                k += 1
            time.sleep(0.002)
except KeyboardInterrupt:
    sys.exit(130)
'''


def child_env(domain=None):
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (env.get('PYTHONPATH'), str(ROOT)) if p)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    if domain is not None:
        env['ROS_DOMAIN_ID'] = str(domain)
    return env


def _ignore_sigint():
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def start_child(path, n_fast, mode, sigint_ignored=False):
    """The recording child; ``sigint_ignored``: started with SIGINT ignored, as a shell starts a
    background job (``cmd &``), which Python then leaves ignored."""
    proc = subprocess.Popen([sys.executable, '-c', CHILD, str(path), str(n_fast), mode],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=child_env(), preexec_fn=_ignore_sigint if sigint_ignored else None)
    line = proc.stdout.readline()
    assert line.split() == ['flushed', str(n_fast)], f'child said {line!r}'
    return proc


def wait_or_report(proc, timeout):
    """The child's exit code; if it has not exited after ``timeout`` s, its threads' stacks
    (faulthandler, SIGUSR1) in the failure message."""
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGUSR1)
        time.sleep(1.0)
        proc.kill()
        _, err = proc.communicate(timeout=30)
        pytest.fail(f'the child did not exit within {timeout} s; its stacks:\n{err}')


def check_prefix(path, n_min):
    """Frames 0..n-1 with n >= n_min, each with its own values; returns n."""
    run = load_run(path)
    n = len(run.time)
    assert n >= n_min
    k = np.arange(n)
    np.testing.assert_array_equal(run.time, k * 1_000_000 / 1e9)
    np.testing.assert_array_equal(run.strain, np.repeat(k[:, None, None], 3, axis=2) * 1.0)
    np.testing.assert_array_equal(run.positions, np.broadcast_to(k[:, None, None], (n, 4, 3)))
    return run


def test_sigkilled_recording_is_read_up_to_its_last_complete_chunk(tmp_path):
    path = tmp_path / 'killed.mcap'
    proc = start_child(path, 300, 'write')
    time.sleep(0.3)                    # the child keeps writing into open chunks meanwhile
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    log = McapLog(path)
    n_msgs = sum(1 for _ in log.messages())
    assert log.truncated                   # no footer: the file really was cut
    run = check_prefix(path, 300)
    assert run.truncated and n_msgs >= 2 * len(run.time)
    # the replay reader sees the same complete prefix
    from tensegrity_ros.node.replay import log_channels
    assert set(log_channels(path)) == {M.resolve_topic('~/strain'), M.resolve_topic('~/nodes')}
    # and Rerun's own loader recovers it too
    chunk = pytest.importorskip('rerun.chunk')
    info = chunk.McapReader(path, recover=True).info()
    assert info.summary_source == 'reconstructed' and info.message_count >= 600


@pytest.mark.parametrize('sig, ignored', [(signal.SIGINT, False), (signal.SIGTERM, False),
                                         (signal.SIGINT, True)])
def test_sigint_and_sigterm_finish_the_file(tmp_path, sig, ignored):
    """Also a child started with SIGINT ignored (a background job; so is a test run started with
    ``make test &``, whose children inherit it): its recording still finishes on SIGINT."""
    from mcap.reader import make_reader
    path = tmp_path / 'stopped.mcap'
    proc = start_child(path, 50, 'idle', sigint_ignored=ignored)
    proc.send_signal(sig)
    assert wait_or_report(proc, 30) == 130
    with open(path, 'rb') as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count == 100
    run = check_prefix(path, 50)
    assert not run.truncated and len(run.time) == 50


def test_recorder_left_open_is_finished_at_exit(tmp_path):
    from mcap.reader import make_reader
    path = tmp_path / 'open.mcap'
    script = ('import sys; from tensegrity_ros.msgs import messages as M; '
              'from tensegrity_ros.io.mcap_writer import McapRecorder; '
              'rec = McapRecorder(sys.argv[1]); '
              "[rec.write('/x', M.command_array([k], 'all'), k) for k in range(7)]")
    subprocess.run([sys.executable, '-c', script, str(path)], env=child_env(), check=True,
                   timeout=60)
    with open(path, 'rb') as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count == 7


def test_replay_reaches_a_subscriber_in_order_with_its_stamps(tmp_path):
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import Float64MultiArray
    net = small_network(2)
    frames = synthetic_frames(net, 15, dt=0.02, seed=3)
    path = tmp_path / 'run.mcap'
    record_frames(path, frames, net, marker_every=5)
    domain = 30 + os.getpid() % 20
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    got = {'strain': [], 'nodes': [], 'clock': [], 'impact': []}
    try:
        node = rclpy.create_node('mcap_replay_probe', context=ctx)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(Float64MultiArray, M.resolve_topic('~/strain'),
                                 lambda m: got['strain'].append(np.array(m.data)), qos)
        node.create_subscription(Float64MultiArray, M.resolve_topic('~/cmd/impact'),
                                 lambda m: got['impact'].append(list(m.data)), qos)
        node.create_subscription(PointCloud2, M.resolve_topic('~/nodes'),
                                 lambda m: got['nodes'].append((M.stamp_to_ns(m.header.stamp),
                                                                M.cloud_positions(m))), qos)
        node.create_subscription(Clock, '/clock',
                                 lambda m: got['clock'].append(M.stamp_to_ns(m.clock)), qos)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        proc = subprocess.Popen([sys.executable, '-m', 'tensegrity_ros.cli', 'replay', str(path),
                                 '--rate', '4', '--wait', '60', '--delay', '1'],
                                env=child_env(domain),
                                stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 90
        while proc.poll() is None and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        end = time.monotonic() + 1.0
        while time.monotonic() < end and len(got['strain']) < len(frames):
            ex.spin_once(timeout_sec=0.05)
        if proc.poll() is None:
            proc.kill()
        err = proc.communicate()[1]
        assert proc.returncode == 0, err
    finally:
        rclpy.shutdown(context=ctx)
    stamps = [int(round(f.t * 1e9)) for f in frames]
    assert len(got['strain']) == len(frames), err
    for f, s in zip(frames, got['strain']):
        np.testing.assert_array_equal(s, f.strain.ravel())
    assert [s for s, _ in got['nodes']] == stamps
    for f, (_, p) in zip(frames, got['nodes']):
        np.testing.assert_array_equal(p, f.positions.astype(np.float32))
    assert got['impact'] == [[0.1]]
    assert got['clock'] == sorted(got['clock']) and set(stamps) <= set(got['clock'])


def test_run_cli_mcap_logs_what_the_run_computed(tmp_path):
    """``tensegrity run --mcap`` against the same scene run again in memory: the log holds the
    run's strain history, node positions (float32) and the impact command."""
    from solver.simulate.runner import run
    from solver.build.scene import Scene
    from solver.simulate.array import simulation_for
    from tensegrity_ros.cli import main
    scene_file = ROOT / 'config' / 'scenes' / 'prism.yaml'
    args = ['run', str(scene_file), '--t-end', '0.01', '--mcap', '--json', '--out', str(tmp_path)]
    assert main(args) == 0
    log_path = tmp_path / 'run'                                   # the bag folder
    assert (log_path / 'metadata.yaml').is_file() and (log_path / 'run_0.mcap').is_file()
    assert json.loads((tmp_path / 'summary.json').read_text())['outputs']['mcap'] == str(log_path)
    scene = Scene.load(scene_file).with_overrides([('run.t_end', 0.01)])
    sim = simulation_for(scene)
    sim.apply_impact(scene['loading.impact.v0'], scene['loading.impact.columns'])
    positions = []
    rec = run(sim, 0.01, scene['run.output_dt'], on_frame=lambda f: positions.append(f.positions))
    logged = load_run(log_path)
    np.testing.assert_array_equal(logged.time, np.round(rec.times * 1e9) / 1e9)
    np.testing.assert_array_equal(logged.strain, rec.strain)
    np.testing.assert_array_equal(logged.positions,
                                  np.array(positions).astype(np.float32).astype(np.float64))
    assert logged.command_topic.tolist() == ['impact']
    assert logged.command_values[0].tolist() == [scene['loading.impact.v0']]
