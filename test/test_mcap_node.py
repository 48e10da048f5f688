"""The node's ``record_mcap``: what the node published (as a subscriber received it, in bytes)
and the command it received are what the log holds and what the loader reads."""
import os
import time

import numpy as np
import pytest

from mcap_helpers import ROOT

pytest.importorskip('rclpy')

from tensegrity_ros.msgs import messages as M  # noqa: E402
from tensegrity_ros.io.mcap_reader import McapLog, load_run  # noqa: E402

TOPICS = ('~/strain', '~/nodes', '~/cable_tension')


def contiguous_in(received, logged):
    """True if ``received`` (non-empty) appears in ``logged`` as one contiguous run."""
    n = len(received)
    return n > 0 and any(logged[i:i + n] == received for i in range(len(logged) - n + 1))


def test_node_log_holds_what_was_published_and_received(tmp_path):
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message
    from solver.build.scene import Scene
    from solver.simulate.array import simulation_for
    from std_msgs.msg import Float64MultiArray
    from tensegrity_ros.node.node import TensegritySim

    path = tmp_path / 'node.mcap'
    scene = Scene.load(ROOT / 'config' / 'scenes' / 'prism.yaml')
    domain = 30 + (os.getpid() + 10) % 20
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    got = {key: [] for key in TOPICS}
    try:
        sim = simulation_for(scene)
        node = TensegritySim(sim=sim, context=ctx, parameter_overrides=[
            Parameter('record_mcap', value=str(path)),
            Parameter('real_time_factor', value=0.0),
            Parameter('publish_rate_hz', value=100.0)])
        probe = rclpy.create_node('mcap_node_probe', context=ctx)
        qos = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
        for key in TOPICS:
            probe.create_subscription(M.MSG_CLASSES[key], M.resolve_topic(key),
                                      lambda data, key=key: got[key].append(bytes(data)), qos,
                                      raw=True)
        pub = probe.create_publisher(Float64MultiArray, M.resolve_topic('~/cmd/impact'), qos)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        ex.add_node(probe)
        deadline = time.monotonic() + 60
        while (pub.get_subscription_count() < 1 or not got['~/strain']) \
                and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.02)
        command = M.command_array([0.05], 'all')
        pub.publish(command)
        n0 = len(got['~/strain'])
        while len(got['~/strain']) < n0 + 30 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.02)
        node.close()
        node.destroy_node()
        probe.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    assert len(got['~/strain']) >= n0 + 30, 'the node did not publish in time'

    log = McapLog(path)
    logged = {}
    for m in log.messages():
        logged.setdefault(m.topic, []).append(m)
    assert not log.truncated
    # compared as messages: CDR alignment padding is not zeroed by the serializer, so equal
    # messages need not be equal bytes
    for key in TOPICS:
        cls = M.MSG_CLASSES[key]
        sent = [deserialize_message(d, cls) for d in got[key]]
        kept = [deserialize_message(m.data, cls) for m in logged[M.resolve_topic(key)]]
        assert contiguous_in(sent, kept), key
    cmds = logged[M.resolve_topic('~/cmd/impact')]
    assert [deserialize_message(m.data, Float64MultiArray) for m in cmds] == [command]

    run = load_run(path)
    assert list(run.command_topic) == ['impact'] and run.command_values[0].tolist() == [0.05]
    received = [deserialize_message(d, Float64MultiArray) for d in got['~/strain']]
    by_time = {round(t * 1e9): s for t, s in zip(run.time, run.strain)}
    strain_log = logged[M.resolve_topic('~/strain')]
    stamps = [m.log_time_ns for m in strain_log]
    kept = [deserialize_message(m.data, Float64MultiArray) for m in strain_log]
    first = next(i for i in range(len(kept)) if kept[i:i + len(received)] == received)
    for msg, ns in zip(received, stamps[first:]):
        np.testing.assert_array_equal(by_time[ns].ravel(), np.array(msg.data))
    # every message of the node's log decodes with both decoders, to the same values
    from mcap_helpers import same
    reader = McapLog(path)
    for m in reader.messages():
        cls = M.MSG_CLASSES[next(k for k in M.TYPES if M.resolve_topic(k) == m.topic)]
        same(deserialize_message(m.data, cls), reader.decode(m), path=m.topic)
    # Rerun's own MCAP loader shows the nodes as points, at the logged stamps
    chunk = pytest.importorskip('rerun.chunk')
    pts = {}
    for ch in chunk.McapReader(McapLog(path).path, timeline_type='duration_ns').stream():
        rb = ch.to_record_batch()
        if ch.entity_path == M.resolve_topic('~/nodes') and 'Points3D:positions' in \
                rb.schema.names:
            for ti, p in zip(rb.column('message_log_time').cast('int64').to_pylist(),
                             rb.column('Points3D:positions').to_pylist()):
                pts[ti] = np.array(p)
    assert sorted(pts) == sorted(round(t * 1e9) for t in run.time)
    np.testing.assert_array_equal(pts[round(run.time[-1] * 1e9)], run.positions[-1])
    np.testing.assert_array_equal(run.network.cable_a, sim.network.cable_a)
    np.testing.assert_array_equal(run.network.x0, sim.network.x0)
    # converts to the live Rerun layout (energy from the node's /diagnostics)
    from tensegrity_ros.io.convert import to_rerun
    assert to_rerun(path, tmp_path / 'node.rrd') >= 3 * len(run.time)
    # at rest before the command; the impact shows in the strain after it
    before = run.strain[run.time <= run.command_time[0]]
    after = run.strain[run.time > run.command_time[0]]
    assert np.all(before == before[0]) and np.any(after != before[0])
