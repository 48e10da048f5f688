"""The node's ``record_rerun`` parameter: what the node publishes is what the .rrd holds.

The node runs in a real rclpy context (own domain id, localhost only) as fast as possible; its
published ``~/strain`` and ``~/nodes`` messages (captured through its sink hook) are compared with
the recording read back by rerun's reader, across an impact command and a reset.
"""
import os

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
pytest.importorskip('rerun')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from solver.build.scene import Scene  # noqa: E402
from tensegrity_ros.msgs import messages  # noqa: E402
from tensegrity_ros.node.demo import spin_until  # noqa: E402
from tensegrity_ros.node.node import TensegritySim  # noqa: E402

from rerun_helpers import FB, at, flat, read  # noqa: E402
from tensegrity_ros.io.sinks import Sink

DOMAIN = 60 + os.getpid() % 20


def test_node_records_what_it_publishes(tmp_path):
    scene = Scene.load(FB).with_overrides(['structure.n_prisms=6'])
    scene_file = tmp_path / 'small.yaml'
    scene_file.write_text(yaml.safe_dump(scene.data))
    rrd = tmp_path / 'node.rrd'
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN)
    try:
        params = dict(scene_file=str(scene_file), real_time_factor=0.0, record_rerun=str(rrd))
        node = TensegritySim(context=ctx, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        sunk = []
        node.add_sink(Sink(
            message=lambda topic, msg, ns: sunk.append((topic, msg, ns))))
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)

        def published(key):
            return [(ns, m) for topic, m, ns in sunk if topic.endswith(key)]

        assert spin_until(ex, lambda: len(published('/strain')) >= 5, 30)
        node.intake.impact(messages.command_array([0.1], 'all'))
        assert spin_until(ex, lambda: len(published('/strain')) >= 40, 30)
        node._on_reset(Trigger.Request(), Trigger.Response())
        n = len(published('/strain'))
        assert spin_until(ex, lambda: len(published('/strain')) >= n + 10, 30)
        ex.shutdown()
        node.close()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)

    data = read(rrd)
    strain = published('/strain')
    # every published strain frame is in the recording at its stamp (the clock runs on across
    # the reset: each stamp once)
    rows = {}
    for t, r in data['/strain/column_0']['rows']:
        rows.setdefault(t, []).append(flat(r['Scalars:scalars']))
    assert sorted(rows) == sorted({ns for ns, _ in strain} | {0})
    # the node publishes its first frame (t = 0) before our sink is added
    assert sum(len(v) for v in rows.values()) == len(strain) + 1
    assert all(len(v) == 1 for v in rows.values())
    # the episode: 0 up to the reset, 1 after it
    episode = [(t, flat(r['Scalars:scalars'])[0]) for t, r in data['/episode']['rows']]
    assert [t for t, _ in episode] == sorted(rows)
    e = np.array([v for _, v in episode])
    k = int(np.argmax(e))
    assert k > 0 and np.all(e[:k] == 0) and np.all(e[k:] == 1)
    for ns, msg in strain:
        assert any(np.array_equal(v, np.asarray(msg.data)) for v in rows[ns])
    assert min(np.min(v) for vs in rows.values() for v in vs) < -1e-3      # the pulse is there
    # node positions of the latest frame (a stamp seen once), against the PointCloud2 (float32)
    ns, cloud = max((c for c in published('/nodes') if len(rows[c[0]]) == 1), key=lambda c: c[0])
    np.testing.assert_array_equal(
        at(data['/world/nodes'], ns * 1e-9, 'Points3D:positions').reshape(-1, 3),
        messages.cloud_positions(cloud).astype(np.float32))
    # the commands and the reset are text events
    texts = [str(flat(r['TextLog:text'])[0]) for _, r in data['/commands']['rows']]
    assert any('impact' in s for s in texts) and any(s == 'reset' for s in texts)
