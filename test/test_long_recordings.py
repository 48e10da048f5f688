"""Recordings longer than every internal buffer: each path that writes a file (the Rerun recorder
directly, ``tensegrity run --mcap --rerun``, ``tensegrity replay --to-rerun``, the node's
``record_mcap`` and ``record_rerun``) finishes with the file complete (rerun's reader warns on a
missing footer: the warning is an error here; the MCAP summary is read) and every frame in it.

The Rerun recorder buffers ``flush_every`` frames (50 by default) and sends them as columns;
every test here fills and sends that buffer many times (30x or more).
"""
import os
import subprocess
import sys
import threading
import warnings

import numpy as np
import pyarrow as pa
import pytest

from mcap_helpers import ROOT, small_network, synthetic_frames

pytest.importorskip('rerun')
from rerun.chunk import RrdReader  # noqa: E402

from tensegrity_ros.io.mcap_reader import McapLog  # noqa: E402
from tensegrity_ros.io.rerun_sink import RerunRecorder  # noqa: E402
from tensegrity_ros.io.sinks import Sink

FB = ROOT / 'config' / 'scenes' / 'fb_column.yaml'
DEFAULT_HELD = 50                # frames the recorder buffers by default (flush_every)


def rrd_times(path, entity='world/nodes'):
    """Sorted sim_time stamps (ns) of every row of ``entity`` in a .rrd; any warning of rerun's
    reader (a file without its footer) fails the test."""
    times = []
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        for chunk in RrdReader(path).stream():
            if chunk.entity_path.lstrip('/') == entity and not chunk.is_static:
                rb = chunk.to_record_batch()
                times += rb.column('sim_time').cast(pa.int64()).to_pylist()
    return sorted(times)


def mcap_stamps(path, leaf):
    """Log times of every message on the topic ending in ``leaf``; the log must be complete."""
    log = McapLog(path)
    stamps = [m.log_time_ns for m in log.messages() if m.topic.endswith('/' + leaf)]
    assert not log.truncated, f'{path} was cut short'
    return stamps


def within(seconds, fn, *args):
    """Run ``fn(*args)`` in a thread; fail (instead of hanging the suite) if it does not return
    in time."""
    out, err = [], []

    def target():
        try:
            out.append(fn(*args))
        except BaseException as exc:        # re-raised in the test's thread
            err.append(exc)
    th = threading.Thread(target=target, daemon=True)
    th.start()
    th.join(seconds)
    assert not th.is_alive(), f'{fn.__name__} did not return within {seconds} s (a hang)'
    if err:
        raise err[0]
    return out[0]


def test_a_small_buffer_sent_forty_times_records_every_frame(tmp_path):
    """A buffer of 10 frames: 40 batches all arrive, in order."""
    net = small_network(3)
    frames = synthetic_frames(net, 400, dt=0.005)
    path = tmp_path / 'one_buffer.rrd'

    def record():
        with RerunRecorder(net, path, flush_every=10, max_latency_s=1e9) as rec:
            for f in frames:
                rec.frame(f)
        return rec.n_frames
    assert within(120, record) == 400
    assert rrd_times(path) == [k * 5_000_000 for k in range(400)]


def test_a_recording_thirty_times_the_default_buffer(tmp_path):
    """The default buffer (50 frames), 1,650 frames handed over as fast as they come: all in the
    file."""
    net = small_network(3)
    n = 33 * DEFAULT_HELD
    frames = synthetic_frames(net, n, dt=0.005)
    path = tmp_path / 'long.rrd'

    def record():
        with RerunRecorder(net, path, max_latency_s=1e9) as rec:
            for f in frames:
                rec.frame(f)
    within(180, record)
    assert rrd_times(path) == [k * 5_000_000 for k in range(n)]


def test_run_and_replay_of_a_long_log_record_every_frame(tmp_path):
    """``tensegrity run --mcap --rerun`` over 1,701 output frames (34 Rerun batches and some
    20 MCAP chunks), then ``tensegrity replay --to-rerun`` of that log, as the user runs them
    (subprocesses, bounded in time): every frame in each file."""
    n = 1701
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    run = [sys.executable, '-m', 'tensegrity_ros.cli', 'run', str(FB), '--set',
           'structure.n_prisms=4', '--set', 'run.output_dt=0.00125', '--t-end', '2.125',
           '--mcap', '--rerun', '--out', str(tmp_path)]
    r = subprocess.run(run, cwd=ROOT, env=env, capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr
    expected = [k * 1_250_000 for k in range(n)]
    for leaf in ('strain', 'nodes', 'cable_tension'):
        assert mcap_stamps(tmp_path / 'run.mcap', leaf) == expected
    assert rrd_times(tmp_path / 'run.rrd') == expected
    out = tmp_path / 'replayed.rrd'
    r = subprocess.run([sys.executable, '-m', 'tensegrity_ros.cli', 'replay',
                        str(tmp_path / 'run.mcap'), '--to-rerun', str(out)],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr
    assert rrd_times(out) == expected
    assert rrd_times(out, 'strain/column_0') == expected


def test_node_records_every_published_frame_to_both_files(tmp_path):
    """The node at real_time_factor 0 with ``record_mcap`` and ``record_rerun``, its Rerun
    500 frames published (10 Rerun batches), each one in both files."""
    rclpy = pytest.importorskip('rclpy')
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from solver.build.scene import Scene
    from solver.simulate.array import simulation_for
    from tensegrity_ros.node.demo import spin_until
    from tensegrity_ros.node.node import TensegritySim
    mcap, rrd = tmp_path / 'node.mcap', tmp_path / 'node.rrd'
    sim = simulation_for(Scene.load(FB).with_overrides(['structure.n_prisms=4']))
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=90 + os.getpid() % 10)
    stamps = []
    try:
        node = TensegritySim(sim=sim, context=ctx, parameter_overrides=[
            Parameter('real_time_factor', value=0.0), Parameter('publish_rate_hz', value=500.0),
            Parameter('record_mcap', value=str(mcap)), Parameter('record_rerun', value=str(rrd))])
        node.add_sink(Sink(frame=lambda f: stamps.append(round(f.t * 1e9))))
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        assert within(180, spin_until, ex, lambda: len(stamps) >= 500, 120)
        ex.shutdown()
        within(120, node.close)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    stamps = [0] + stamps                  # the node's first frame comes before our sink
    assert len(stamps) == len(set(stamps)) and stamps == sorted(stamps)
    assert rrd_times(rrd) == stamps
    assert mcap_stamps(mcap, 'strain') == stamps
    assert mcap_stamps(mcap, 'nodes') == stamps
    diag = mcap_stamps(mcap, 'diagnostics')
    assert diag and np.all(np.diff(diag) >= 0)
