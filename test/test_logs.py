"""Logs a user can trust: a node recording across ``~/reset`` (every published frame in the file,
log times and ``/clock`` never decrease, the loader returns the episodes in order), the bag
folder read by an independent reader (``rosbags``), and ``tensegrity run`` with a train of
impacts logged in order.

The node runs in a real rclpy context (own domain id, localhost only); what it published is taken
from a subscriber of its topics, the file's log times from ``mcap``'s own record reader and the
bag from ``rosbags.rosbag2.Reader`` with the ROS 2 Kilted type store.
"""
import os

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
rosbags = pytest.importorskip('rosbags')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rosbags.rosbag2 import Reader  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from mcap_helpers import ROOT  # noqa: E402
from solver.build.scene import Scene  # noqa: E402
from solver.simulate.array import simulation_for  # noqa: E402
from tensegrity_ros.io.mcap_reader import load_run  # noqa: E402
from tensegrity_ros.msgs import messages as M  # noqa: E402
from tensegrity_ros.node.demo import spin_until  # noqa: E402

DOMAIN = 150 + os.getpid() % 40
STRAIN = M.resolve_topic('~/strain')


def file_log_times(path):
    """(topic, log time ns) of every message of an MCAP file in file order, by ``mcap``'s record
    reader (not the project's)."""
    from mcap.reader import make_reader
    with open(path, 'rb') as f:
        reader = make_reader(f)
        return [(channel.topic, msg.log_time)
                for _, channel, msg in reader.iter_messages(log_time_order=False)]


def bag_strain(folder):
    """[(log time ns, strain values)] of the strain topic of a bag folder, read and decoded by
    rosbags; and the bag's per-topic message counts."""
    store = get_typestore(Stores.ROS2_KILTED)
    out = []
    with Reader(folder) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        for conn, t, raw in reader.messages(connections=[c for c in reader.connections
                                                         if c.topic == STRAIN]):
            msg = store.deserialize_cdr(raw, conn.msgtype)
            out.append((t, np.asarray(msg.data, dtype=np.float64)))
    return out, counts


def test_a_recording_across_a_reset_keeps_every_frame_in_order(tmp_path):
    """Impact, reset, impact while the node records: every published frame is in the file, its
    log times and /clock never decrease, the loader returns the two episodes in order, and the
    bag folder read by rosbags holds the loader's strain message for message."""
    from rosgraph_msgs.msg import Clock

    from tensegrity_ros.node.node import TensegritySim
    requested = tmp_path / 'node.mcap'
    sim = simulation_for(Scene.load(ROOT / 'config' / 'scenes' / 'fb_column.yaml')
                         .with_overrides(['structure.n_prisms=6']))
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN)
    strain, clock = [], []
    try:
        node = TensegritySim(sim=sim, context=ctx, parameter_overrides=[
            Parameter('record_mcap', value=str(requested)),
            Parameter('real_time_factor', value=0.0), Parameter('publish_rate_hz', value=200.0)])
        probe = rclpy.create_node('logs_probe', context=ctx)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        probe.create_subscription(Float64MultiArray, STRAIN,
                                  lambda m: strain.append(np.array(m.data)), qos)
        probe.create_subscription(Clock, '/clock',
                                  lambda m: clock.append(M.stamp_to_ns(m.clock)), qos)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        ex.add_node(probe)
        assert spin_until(ex, lambda: node.pubs['~/strain'].get_subscription_count() > 0
                          and len(strain) >= 3, 60)
        for _ in range(2):
            n = len(strain)
            node.intake.impact(M.command_array([0.1], 'all'))
            assert spin_until(ex, lambda: len(strain) >= n + 60, 60)
            if node.episode == 0:
                t_reset = node.clock_time()
                response = node._on_reset(Trigger.Request(), Trigger.Response())
                assert response.success and 'episode 1' in response.message
        for _ in range(20):                   # what is in flight reaches the probe
            ex.spin_once(timeout_sec=0.01)
        ex.shutdown()
        node.close()
        node.destroy_node()
        probe.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)

    folder = tmp_path / 'node'
    assert sorted(p.name for p in folder.iterdir()) == ['metadata.yaml', 'node_0.mcap']
    times = file_log_times(folder / 'node_0.mcap')
    assert all(b[1] >= a[1] for a, b in zip(times, times[1:])), 'log times went back'
    assert clock and all(b > a for a, b in zip(clock, clock[1:])), '/clock went back'
    logged_clock = [t for topic, t in times if topic == '/clock']
    assert all(b > a for a, b in zip(logged_clock, logged_clock[1:]))

    run = load_run(requested)              # the path asked for names the bag folder
    n_strain = sum(topic == STRAIN for topic, _ in times)
    assert len(run.time) == n_strain and np.all(np.diff(run.time) > 0)
    k = int(np.argmax(run.episode))        # the first frame of the second episode
    assert run.episode[0] == 0 and k > 0
    assert np.array_equal(run.episode, np.r_[np.zeros(k, int), np.ones(len(run.time) - k, int)])
    # the second episode starts at rest, one step after the last state of the first
    assert run.time[k] == pytest.approx(t_reset + sim.dt, abs=1e-9)
    assert np.abs(run.strain[k]).max() < 1e-9 and np.abs(run.strain[k - 1]).max() > 1e-4
    np.testing.assert_allclose(run.positions[k], sim.network.x0, rtol=0, atol=1e-6)
    # each episode has its impact, and the pulse is in each
    assert list(run.command_topic) == ['impact', 'impact']
    assert run.command_time[0] < run.time[k] <= run.command_time[1]
    assert run.strain[:k].min() < -1e-3 and run.strain[k:].min() < -1e-3
    # every frame the probe received is in the file, in order
    flat = [s.ravel() for s in run.strain]
    assert any(len(flat) - i >= len(strain) and all(
        np.array_equal(got, kept) for got, kept in zip(strain, flat[i:]))
        for i in range(len(flat)))
    assert len(strain) > 120

    # rosbags reads the folder (metadata.yaml) and its strain equals the loader's, bit for bit
    bag, counts = bag_strain(folder)
    assert [t for t, _ in bag] == [round(t * 1e9) for t in run.time]
    for (_, values), loaded in zip(bag, run.strain):
        np.testing.assert_array_equal(values, loaded.ravel())
    assert counts[STRAIN] == n_strain
    assert counts == {topic: sum(t == topic for t, _ in times) for topic in counts}


def test_a_run_with_a_train_logs_every_impact_and_frame_in_order(tmp_path):
    """``tensegrity run --mcap`` of a train of impacts: one episode, log times never decrease,
    each impact logged once in order at its time, and rosbags' strain equals the loader's."""
    from tensegrity_ros.cli import main
    assert main(['run', str(ROOT / 'config' / 'scenes' / 'fb_train.yaml'), '--set',
                 'structure.n_prisms=6', '--set', 'loading.impact.count=3', '--t-end', '0.3',
                 '--mcap', '--out',
                 str(tmp_path)]) == 0
    import json
    summary = json.loads((tmp_path / 'summary.json').read_text())
    folder = tmp_path / 'run'
    assert summary['outputs']['mcap'] == str(folder)
    times = file_log_times(folder / 'run_0.mcap')
    assert all(b[1] >= a[1] for a, b in zip(times, times[1:]))
    run = load_run(folder)
    assert np.all(np.diff(run.time) > 0) and not run.episode.any()
    impacts = summary['impacts']
    assert len(impacts) >= 2
    assert run.command_time.tolist() == pytest.approx([i['t_s'] for i in impacts], abs=1e-9)
    assert [v[0] for v in run.command_values] == [i['v0_m_s'] for i in impacts]
    bag, counts = bag_strain(folder)
    assert [t for t, _ in bag] == [round(t * 1e9) for t in run.time]
    for (_, values), loaded in zip(bag, run.strain):
        np.testing.assert_array_equal(values, loaded.ravel())
    # the events hold the same impacts, as text
    from tensegrity_ros.io.mcap_reader import McapLog
    log = McapLog(folder)
    events = [(m.log_time_ns, log.decode(m).data) for m in log.messages()
              if m.topic.endswith('/events')]
    assert [t for t, _ in events] == [round(i['t_s'] * 1e9) for i in impacts]
    assert events[0][1].startswith('impact ') and events[1][1].startswith('train impact 2 of')


def _series(data, entity, comp):
    """[(t ns, leaf values)] of every row of ``entity`` in rerun_helpers.read's result."""
    from rerun_helpers import flat
    return [(t, flat(r[comp])) for t, r in data.get(entity, {'rows': []})['rows'] if comp in r]


ENTITIES = [('base_force/column_0', 'Scalars:scalars'), ('strain/column_0', 'Scalars:scalars'),
            ('energy', 'Scalars:scalars'), ('constraint_error', 'Scalars:scalars'),
            ('energy_balance_error', 'Scalars:scalars'), ('episode', 'Scalars:scalars'),
            ('world/nodes', 'Points3D:positions'), ('commands', 'TextLog:text'),
            ('commands', 'TextLog:level')]


def same_recordings(live, converted):
    """Entity by entity, the converted recording holds what the live one holds."""
    from rerun_helpers import read
    a, b = read(live), read(converted)
    for entity, comp in ENTITIES:
        x, y = _series(a, '/' + entity, comp), _series(b, '/' + entity, comp)
        assert x, f'{entity} {comp}: nothing recorded'
        assert [t for t, _ in x] == [t for t, _ in y], f'{entity}: times differ'
        for (t, u), (_, v) in zip(x, y):
            assert np.array_equal(u, v), f'{entity} {comp} at {t} ns: {u} != {v}'
    return a


def test_to_rerun_writes_what_the_run_s_live_recording_writes(tmp_path):
    """``tensegrity run --mcap --rerun``, then ``tensegrity replay --to-rerun`` of its bag folder:
    base force, strain, energy (and its errors), episode, nodes and the command log equal the
    live recording's; the base force is not zero."""
    from tensegrity_ros.cli import main
    assert main(['run', str(ROOT / 'config' / 'scenes' / 'fb_column.yaml'), '--set',
                 'structure.n_prisms=6', '--t-end', '0.15', '--mcap', '--rerun', '--out',
                 str(tmp_path)]) == 0
    out = tmp_path / 'converted.rrd'
    assert main(['replay', str(tmp_path / 'run'), '--to-rerun', str(out)]) == 0
    data = same_recordings(tmp_path / 'run.rrd', out)
    base = np.concatenate([v for _, v in _series(data, '/base_force/column_0',
                                                 'Scalars:scalars')])
    assert np.abs(base).max() > 1e-3
    run = load_run(tmp_path / 'run')
    assert len(_series(data, '/strain/column_0', 'Scalars:scalars')) == len(run.time)


def test_to_rerun_writes_what_the_node_s_live_recording_writes_across_a_reset(tmp_path):
    """The node records MCAP and Rerun through an impact, a reset and an impact: the converted
    MCAP equals the node's own Rerun recording entity by entity, episodes and events included."""
    from tensegrity_ros.io.convert import to_rerun
    from tensegrity_ros.node.node import TensegritySim
    sim = simulation_for(Scene.load(ROOT / 'config' / 'scenes' / 'fb_column.yaml')
                         .with_overrides(['structure.n_prisms=6']))
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN)
    try:
        node = TensegritySim(sim=sim, context=ctx, parameter_overrides=[
            Parameter('record_mcap', value=str(tmp_path / 'node')),
            Parameter('record_rerun', value=str(tmp_path / 'node.rrd')),
            Parameter('real_time_factor', value=0.0), Parameter('publish_rate_hz', value=200.0)])
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        for _ in range(2):
            node.intake.impact(M.command_array([0.1], 'all'))
            n = node.counts['frames']
            assert spin_until(ex, lambda: node.counts['frames'] >= n + 60, 60)
            if node.episode == 0:
                node._on_reset(Trigger.Request(), Trigger.Response())
        ex.shutdown()
        node.close()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    to_rerun(tmp_path / 'node', tmp_path / 'converted.rrd')
    data = same_recordings(tmp_path / 'node.rrd', tmp_path / 'converted.rrd')
    episodes = np.concatenate([v for _, v in _series(data, '/episode', 'Scalars:scalars')])
    assert set(episodes.tolist()) == {0.0, 1.0} and np.all(np.diff(episodes) >= 0)
    texts = [str(v[0]) for _, v in _series(data, '/commands', 'TextLog:text')]
    assert texts.count('reset') == 1 and sum('impact v0' in s for s in texts) == 2
