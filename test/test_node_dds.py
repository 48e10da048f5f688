"""A second process commanding the node over DDS (loopback only, own domain id), and the command
line of the node."""
import os
import subprocess
import sys

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from solver.build.scene import Scene  # noqa: E402
from tensegrity_ros.node.demo import (Commander, node_process, spin_until,  # noqa: E402
                                      stop_process)

DOMAIN = 10 + (os.getpid() + 7) % 20


def test_second_process_commands_node_over_dds(tmp_path):
    scene = Scene.load('config/scenes/lens_array.yaml').with_overrides(
        ['structure.n_prisms=8', 'structure.n_columns=2'])
    path = tmp_path / 'two.yaml'
    path.write_text(yaml.safe_dump(scene.data))
    proc = node_process({'scene_file': str(path), 'real_time_factor': 1.0}, DOMAIN)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN)
    cmd = Commander(context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(cmd)
    try:
        assert spin_until(ex, lambda: cmd.connected() or proc.poll() is not None, 120)
        assert proc.poll() is None, stop_process(proc)[1]
        assert cmd.strain[-1].shape == (2, 8)
        # per-column impact: only column 1 is hit
        cmd.impact([0.0, 0.1], 'column')
        n = len(cmd.strain)
        assert spin_until(ex, lambda: len(cmd.strain) > n + 60, 60)
        s = np.array(cmd.strain[n:])
        assert s[:, 1].min() < -0.01 and np.abs(s[:, 0]).max() < 1e-9
        # a malformed command over DDS is rejected and reported on /diagnostics
        k = len(cmd.diagnostics)
        cmd.impact([0.1, 0.1, 0.1], '')
        assert spin_until(ex, lambda: any(d[0] == 1 and 'expected' in d[1]
                                          for d in cmd.diagnostics[k:]), 20)
        # reset over DDS: back at rest, and the stamps go on increasing (a new episode)
        assert cmd.cli_reset.wait_for_service(timeout_sec=10)
        t_before = cmd.clouds[-1][0]
        fut = cmd.cli_reset.call_async(Trigger.Request())
        assert spin_until(ex, fut.done, 20) and fut.result().success
        assert 'episode 1' in fut.result().message
        k = len(cmd.clouds)
        assert spin_until(ex, lambda: len(cmd.clouds) > k + 5, 10)
        assert cmd.clouds[k][0] > t_before and np.abs(cmd.strain[-1]).max() < 1e-9
        times = [c[0] for c in cmd.clouds]
        assert np.all(np.diff(times) > 0)
    finally:
        code, out = stop_process(proc)
        ex.shutdown()
        cmd.destroy_node()
        rclpy.shutdown(context=ctx)
    assert code == 0, out
    assert 'Traceback' not in out


def test_node_command_line_rejects_bad_parameter():
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    r = subprocess.run([sys.executable, '-m', 'tensegrity_ros.cli', 'node', '--ros-args', '-p',
                        'publish_rate_hz:=-5.0'], env=env, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and 'publish_rate_hz' in lines[0] and 'Traceback' not in r.stderr
