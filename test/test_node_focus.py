"""``~/cmd/focus`` on a small lens array in a real rclpy context (own domain id): the node plans
the prestrains with the focusing design, ramps them, impacts every column at once at the end of
the ramp and reports the plan on ``/diagnostics``, then the arrivals it measures on its own run;
``~/field`` carries the peak pressure map (32FC1) only when someone listens; an unreachable focus
and a bad point are rejected naming the problem, changing nothing."""
import json
import os

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from geometry_msgs.msg import PointStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from solver.studies import lens  # noqa: E402
from solver.build.scene import Scene  # noqa: E402
from tensegrity_ros.msgs import messages  # noqa: E402
from tensegrity_ros.node.demo import Commander, spin_until  # noqa: E402
from solver.studies.lens_record import IMAGE_SHAPE  # noqa: E402
from tensegrity_ros.node.node import TensegritySim  # noqa: E402

DOMAIN = 0 + os.getpid() % 10
SETS = ['structure.n_prisms=10', 'structure.n_columns=3', 'lens.grid=9', 'run.t_end=0.3']
SPEED = 2.0
RAMP = 0.02


@pytest.fixture
def focused(tmp_path, monkeypatch):
    monkeypatch.setenv('TENSEGRITY_CACHE', str(tmp_path / 'cache'))
    scene = Scene.load('config/scenes/lens_focus.yaml').with_overrides(SETS)
    path = tmp_path / 'small_lens.yaml'
    path.write_text(yaml.safe_dump(scene.data))
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN)
    node = TensegritySim(context=ctx, parameter_overrides=[
        Parameter('scene_file', value=str(path)), Parameter('real_time_factor', value=0.0),
        Parameter('medium_speed_m_s', value=SPEED), Parameter('prestrain_ramp_s', value=RAMP),
        Parameter('diagnostics_rate_hz', value=20.0)])
    cmd = Commander(context=ctx)
    pub = cmd.create_publisher(PointStamped, f'{cmd.base}/cmd/focus', 10)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(cmd)
    assert spin_until(ex, lambda: cmd.connected() and pub.get_subscription_count() > 0, 60)

    def focus(x, z, y=0.0):
        msg = PointStamped()
        msg.point.x, msg.point.y, msg.point.z = float(x), float(y), float(z)
        pub.publish(msg)
    yield node, ex, cmd, focus, Scene.load(path)
    ex.shutdown()
    node.close()
    cmd.destroy_node()
    node.destroy_node()
    rclpy.shutdown(context=ctx)


def test_focus_plans_ramps_and_impacts_every_column_at_once(focused):
    node, ex, cmd, focus, scene = focused
    t_cmd = node.sim.t
    focus(0.02, 0.1)
    assert spin_until(ex, lambda: (node.focus.current or {}).get('state') == 'impacted',
                      600)
    # the plan is the focusing design's for this scene, focus, speed and the scene's v0
    ref = lens.design(scene, (0.02, 0.1), SPEED, scene['loading.impact.v0'])
    got = node.focus.current['plan']
    p_ref = [c['prestrain'] for c in ref.columns]
    assert [c['prestrain'] for c in got['columns']] == pytest.approx(p_ref, rel=1e-12)
    # the delay law of the plan: targets follow -|F - X_i| / C
    xs = np.arange(3) * scene['structure.column_spacing']
    target = np.array([c['target_s'] for c in got['columns']])
    np.testing.assert_allclose(target - target[1],
                               -(np.hypot(xs - 0.02, 0.1) - 0.1) / SPEED, atol=1e-12)
    # the outer columns are symmetric about the focus: the same prestrain
    assert p_ref[0] == pytest.approx(p_ref[2], rel=1e-9) and p_ref[0] != p_ref[1]
    # ramped to the plan, impacted at the end of the ramp, every column moving
    np.testing.assert_allclose(node.sim.prestrain.mean(axis=1), p_ref, rtol=1e-9)
    t_imp = node.focus.current['impact_sim_time_s']
    assert t_imp - t_cmd == pytest.approx(RAMP, abs=2 * node.sim.dt + 0.05)
    assert t_imp >= t_cmd + RAMP - 1e-9
    assert spin_until(ex, lambda: node.sim.t > t_imp + 0.03, 60)
    s = node.sim.frame().strain
    assert np.all(s.min(axis=1) < -1e-3)                          # a pulse in every column
    # the plan on /diagnostics
    n = len(cmd.diagnostics)
    assert spin_until(ex, lambda: any(d[2].get('focus') == 'impacted'
                                      for d in cmd.diagnostics[n:]), 30)
    d = next(d[2] for d in cmd.diagnostics[n:] if d[2].get('focus') == 'impacted')
    assert json.loads(d['focus_prestrain']) == pytest.approx(p_ref, rel=1e-9)
    assert float(d['focus_z_m']) == 0.1 and float(d['focus_medium_speed_m_s']) == SPEED
    assert all('nan' not in v.lower() for v in d.values())


def test_unreachable_focus_and_bad_points_are_rejected_changing_nothing(focused):
    node, ex, cmd, focus, scene = focused
    p0 = node.sim.prestrain.copy()
    # a slow medium: the delay law spans 3.9 s across the array, far beyond what the prestrain
    # range can shift the arrivals by
    assert node.set_parameters([Parameter('medium_speed_m_s', value=0.01)])[0].successful
    for args, words in (((0.0, 0.001), ('out of reach', 'column')),
                        ((0.02, float('nan')), ('finite',)),
                        ((0.02, -0.1), ('Z > 0',))):
        k = node.counts['rejected']
        focus(*args)
        assert spin_until(ex, lambda: node.counts['rejected'] == k + 1, 120), args
        text = node.intake.last_command[2]
        assert text.startswith('~/cmd/focus') and all(w in text for w in words), text
    assert node.focus.current is None and np.array_equal(node.sim.prestrain, p0)


def test_field_image_after_a_focus(focused):
    """A subscriber gets the peak pressure map: 32FC1, the stated 48 x 64 pixels, finite, stamped
    after the impact; once the record is complete /diagnostics carry the arrivals measured on
    the node's run, on the delay law within 1 ms."""
    node, ex, cmd, focus, scene = focused
    images = []
    cmd.create_subscription(Image, f'{cmd.base}/field', images.append, 10)
    assert spin_until(ex, lambda: node.pubs['~/field'].get_subscription_count() > 0, 30)
    focus(0.02, 0.1)
    assert spin_until(ex, lambda: (node.focus.current or {}).get('state') == 'impacted',
                      600)
    t_imp = node.focus.current['impact_sim_time_s']
    # an image stamped after the impact once the pulses have reached the bases (before that
    # the peak map is 0 everywhere)
    assert spin_until(ex, lambda: node.focus.record is not None and node.focus.record.done, 120)
    n_done = len(images)
    assert spin_until(ex, lambda: len(images) > n_done, 60)       # an image of the whole record
    m = images[-1]
    assert messages.stamp_to_ns(m.header.stamp) > t_imp * 1e9
    assert (m.encoding, m.height, m.width, m.step) == ('32FC1', *IMAGE_SHAPE, 4 * IMAGE_SHAPE[1])
    v = messages.image_values(m)
    assert np.isfinite(v).all() and v.max() > 0
    n = len(cmd.diagnostics)
    assert spin_until(ex, lambda: any(d[2].get('focus_measured') == 'true'
                                      for d in cmd.diagnostics[n:]), 120)
    d = next(d[2] for d in cmd.diagnostics[n:] if d[2].get('focus_measured') == 'true')
    sim = np.array(json.loads(d['focus_arrival_simulated_s']))
    xs = np.arange(3) * scene['structure.column_spacing']
    law = float(d['focus_t0_s']) - np.hypot(xs - 0.02, 0.1) / SPEED      # T_i = T0 - |F - X_i| / C
    assert np.max(np.abs(sim - law)) <= 1e-3                     # stated: 1 ms (grid 9: 0.5 ms)
    assert np.allclose(json.loads(d['focus_residual_s']), sim - law, atol=1e-6)
    # the same as the design's own check run (the ramp keeps the columns at rest)
    plan = lens.design(scene, (0.02, 0.1), SPEED, scene['loading.impact.v0'])
    lens.check(scene, plan)
    assert sim == pytest.approx([c['simulated_s'] for c in plan.columns], abs=1e-6)
    assert float(d['focus_peak_pressure']) > 0


def test_field_is_computed_only_when_someone_listens(focused):
    """A focus records its base forces (its arrivals are reported) but, without a subscriber or
    recorder, no field is computed; a plain impact records nothing then; with a subscriber it
    does, and an image follows; with field_rate_hz 0 nothing is published."""
    node, ex, cmd, focus, scene = focused
    focus(0.02, 0.1)
    assert spin_until(ex, lambda: node.focus.record is not None and node.focus.record.done, 600)
    assert node.focus.record._peak.count == 0                      # nobody listened

    def rest():          # each impact from rest: impacts on top of each other collapse a prism
        node._on_reset(Trigger.Request(), Trigger.Response())
        assert node.running and not node.problem

    rest()
    cmd.impact([0.1])
    t = node.sim.t
    assert spin_until(ex, lambda: node.sim.t > t + 0.05, 60)
    assert node.focus.record is None
    images = []
    cmd.create_subscription(Image, f'{cmd.base}/field', images.append, 10)
    assert spin_until(ex, lambda: node.pubs['~/field'].get_subscription_count() > 0, 30)
    rest()
    cmd.impact([0.1])
    assert spin_until(ex, lambda: bool(images), 60) and node.focus.record is not None
    assert node.set_parameters([Parameter('field_rate_hz', value=0.0)])[0].successful
    rest()
    cmd.impact([0.1])
    t, n = node.sim.t, len(images)
    assert spin_until(ex, lambda: node.sim.t > t + 0.2, 60)
    assert node.focus.record is None and len(images) == n
