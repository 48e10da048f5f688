"""A small commander for the ``tensegrity_sim`` node, and the demo (``tensegrity demo``).

:class:`Commander` is an ordinary rclpy node: it publishes ``~/cmd/impact``, ``~/cmd/prestrain``
and ``~/cmd/focus`` of the simulation node, listens to its ``~/strain``, ``~/field`` and
``/diagnostics`` and calls its services. :func:`run_demo` starts the node paused in a second
process, starts the node's clock once both sides are connected, commands an impact over the topic
(a paused node rejects commands), collects the strain wave for a while, stops the node with SIGINT
and returns a summary dict whose figures come from the float64 ``~/strain`` topic.
:func:`run_focus_demo` does the same with a focus on a lens array: the plan and the arrivals the
node measures come from ``/diagnostics``, the field from ``~/field``.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PointStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import Image, PointCloud2
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool, Trigger

from tensegrity_ros.msgs import messages
from tensegrity_ros.node.qos import QOS


def strain_matrix(msg):
    """(n_columns, n_prisms) strain of a ``~/strain`` message, shaped by its layout."""
    dims = [d.size for d in msg.layout.dim]
    return np.asarray(msg.data, dtype=np.float64).reshape(dims)


class Commander(Node):
    """Talks to the node ``<namespace>/<node_name>``. Keeps what it receives: ``clouds`` (list of
    (t s, (n_nodes, 3) positions) from ``~/nodes``, stamped with simulation time), ``strain``
    (list of (n_columns, n_prisms) arrays from ``~/strain``, which has no header) and
    ``diagnostics`` (list of (level, message, dict of values))."""

    def __init__(self, namespace=messages.NAMESPACE, node_name=messages.NODE_NAME, context=None):
        super().__init__('tensegrity_commander', context=context)
        base = messages.resolve_topic('~/', namespace, node_name).rstrip('/')
        self.base = base
        self.pub_impact = self.create_publisher(Float64MultiArray, f'{base}/cmd/impact', QOS)
        self.pub_prestrain = self.create_publisher(Float64MultiArray, f'{base}/cmd/prestrain',
                                                   QOS)
        self.pub_focus = self.create_publisher(PointStamped, f'{base}/cmd/focus', QOS)
        self.clouds, self.strain, self.tension, self.diagnostics = [], [], [], []
        self.fields = []                 # (t s, (height, width) float32) from ~/field, if asked
        self._frame_subs = [
            self.create_subscription(PointCloud2, f'{base}/nodes', self._on_cloud, QOS),
            self.create_subscription(Float64MultiArray, f'{base}/strain',
                                     lambda m: self.strain.append(strain_matrix(m)), QOS),
            self.create_subscription(Float64MultiArray, f'{base}/cable_tension',
                                     lambda m: self.tension.append(np.asarray(m.data)), QOS)]
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, QOS)
        self.cli_reset = self.create_client(Trigger, f'{base}/reset')
        self.cli_running = self.create_client(SetBool, f'{base}/set_running')

    def _on_cloud(self, msg):
        self.clouds.append((messages.stamp_to_ns(msg.header.stamp) * 1e-9,
                            messages.cloud_positions(msg)))

    def _on_diag(self, msg):
        for st in msg.status:
            if st.name == messages.NODE_NAME:
                self.diagnostics.append((ord(st.level) if isinstance(st.level, bytes)
                                         else int(st.level), st.message,
                                         {kv.key: kv.value for kv in st.values}))

    def connected(self, paused=False):
        """True once the node subscribes to our commands and we receive its frames; for a node
        started paused (which publishes no frames), once the topics in both directions are
        matched, its ``/diagnostics`` arrive and ``~/set_running`` is available."""
        commands_matched = self.pub_impact.get_subscription_count() > 0 and \
            self.pub_prestrain.get_subscription_count() > 0
        if paused:
            return commands_matched and bool(self.diagnostics) and \
                all(s.get_publisher_count() > 0 for s in self._frame_subs) and \
                self.cli_running.service_is_ready()
        return commands_matched and bool(self.clouds) and bool(self.strain) and \
            bool(self.tension)

    def listen_to_field(self):
        """Keep the ``~/field`` images (:attr:`fields`) from now on."""
        self._field_sub = self.create_subscription(
            Image, f'{self.base}/field', lambda m: self.fields.append(
                (messages.stamp_to_ns(m.header.stamp) * 1e-9, messages.image_values(m))), QOS)

    def focus(self, x, z):
        """``~/cmd/focus`` at ``(x, z)`` m (x along the array, z the depth below the bases)."""
        msg = PointStamped()
        msg.point.x, msg.point.z = float(x), float(z)
        self.pub_focus.publish(msg)

    def impact(self, v0, label='all'):
        self.pub_impact.publish(messages.command_array(v0, label))

    def prestrain(self, p, label='all'):
        self.pub_prestrain.publish(messages.command_array(p, label))

    def set_running(self, executor, running=True, timeout_s=30.0):
        """Call ``~/set_running``; returns the response (raises RuntimeError without one)."""
        future = self.cli_running.call_async(SetBool.Request(data=bool(running)))
        spin_until(executor, future.done, timeout_s)
        if not future.done() or future.result() is None:
            raise RuntimeError(f'{self.base}/set_running did not answer within {timeout_s:g} s')
        return future.result()


STRAIN_MATCH_TOL = 1e-4     # |strain from the float32 cloud - float64 strain| of the same frame
                            # (the rounding is about 2.5e-6; adjacent frames differ far more)


def stamped_strain(clouds, strains, levels, h0, tol=STRAIN_MATCH_TOL):
    """Simulation times for the ``~/strain`` messages (float64, no header): each is matched, in
    order, to the first ``~/nodes`` cloud not yet used whose strain (recomputed from its float32
    points) agrees within ``tol``; a message that matches none (its cloud was dropped) is left
    out. Returns (times (n,), strain (n, n_columns, n_prisms)): the figures come from the float64
    values, the float32 points only give each its stamp."""
    from solver import observables
    s32 = [observables.prism_strains(x, levels, h0) for _, x in clouds]
    times, got = [], []
    j0 = 0
    for s in strains:
        for j in range(j0, len(clouds)):
            if s32[j].shape == s.shape and float(np.max(np.abs(s32[j] - s))) <= tol:
                times.append(clouds[j][0])
                got.append(s)
                j0 = j + 1
                break
    shape = (0,) + (strains[0].shape if strains else (0, 0))
    return np.array(times), (np.array(got) if got else np.zeros(shape))


def demo_domain_id(pid=None):
    """The demo's default ROS_DOMAIN_ID when none is given: 100 + pid % 50, so that two demos
    on one machine rarely share a domain (the tests use other ranges)."""
    return 100 + (os.getpid() if pid is None else pid) % 50


def spin_until(executor, predicate, timeout_s, step_s=0.02):
    """Spin ``executor`` until ``predicate()`` is true or ``timeout_s`` wall seconds pass."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        executor.spin_once(timeout_sec=step_s)
    return predicate()


def node_process(params, domain_id, extra_env=None):
    """Start ``tensegrity_node`` in a second process with ``params`` (dict name -> value)."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               **(extra_env or {}))
    root = str(Path(__file__).resolve().parents[2])
    env['PYTHONPATH'] = root + os.pathsep + env.get('PYTHONPATH', '')
    cmd = [sys.executable, '-m', 'tensegrity_ros.node.node', '--ros-args']
    for k, v in params.items():
        text = str(v).lower() if isinstance(v, bool) else str(v)
        cmd += ['-p', f'{k}:={text}']
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)


def stop_process(proc, timeout_s=15.0):
    """SIGINT, then SIGTERM, then SIGKILL; returns (exit code, output)."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        if proc.poll() is not None:
            break
        proc.send_signal(sig)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            continue
    out = proc.stdout.read() if proc.stdout else ''
    return proc.returncode, out


def _recorder_available(module):
    import importlib.util
    return importlib.util.find_spec(f'tensegrity_ros.{module}') is not None


def run_demo(scene_file='config/scenes/fb_column.yaml', v0=(0.1,), duration_s=1.2, rtf=1.0,
             out_dir='runs/demo', domain_id=None, record=True, prestrain=None,
             publish_rate_hz=200.0, connect_timeout_s=120.0):
    """Start the node (second process) paused, wait for it, start its clock (so that the impact
    lands a tick or two after t = 0, whenever the node came up; a paused node rejects commands),
    optionally command a prestrain (per column, waiting for its ramp), command an impact ``v0``
    (1 value or one per column) over the topic, collect ``~/strain`` (float64, stamped through
    ``~/nodes``, see :func:`stamped_strain`) for ``duration_s`` s of simulation time after the
    impact, stop the node with SIGINT.
    ``domain_id`` None: :func:`demo_domain_id`. Returns the summary dict (also written to
    ``out_dir/summary.json``)."""
    import json

    from solver import observables
    from solver import Scene
    from solver import build_network

    from tensegrity_ros.node.params import find_config

    if domain_id is None:
        domain_id = demo_domain_id()
    scene_path = find_config(scene_file)
    network = build_network(Scene.load(scene_path))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    params = {'scene_file': str(scene_path), 'real_time_factor': float(rtf),
              'publish_rate_hz': float(publish_rate_hz), 'start_paused': True}
    outputs = {'mcap': None, 'rerun': None}
    if record and _recorder_available('io.mcap_writer'):
        outputs['mcap'] = params['record_mcap'] = str(out / 'run')
    if record and _recorder_available('io.rerun_sink'):
        outputs['rerun'] = params['record_rerun'] = str(out / 'run.rrd')
    v0 = [float(v) for v in np.atleast_1d(v0)]
    proc = node_process(params, domain_id)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    cmd = Commander(context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(cmd)
    info = {}
    try:
        w0 = time.monotonic()
        spin_until(ex, lambda: cmd.connected(paused=True) or proc.poll() is not None,
                   connect_timeout_s)
        if not cmd.connected(paused=True):
            raise RuntimeError('the node did not come up within '
                               f'{connect_timeout_s:g} s (exit code {proc.poll()})')
        info['startup_s'] = time.monotonic() - w0
        cmd.set_running(ex, True)
        if prestrain is not None:
            spin_until(ex, lambda: bool(cmd.clouds), 30.0)
            cmd.prestrain(prestrain, 'all' if np.size(prestrain) == 1 else 'column')
            t_p = cmd.clouds[-1][0] if cmd.clouds else 0.0
            spin_until(ex, lambda: bool(cmd.clouds) and cmd.clouds[-1][0] >= t_p + 0.2, 30.0)
        n_diag, n_c = len(cmd.diagnostics), len(cmd.clouds)
        w1 = time.monotonic()                  # the node runs on while the answer comes
        cmd.impact(v0, 'all' if len(v0) == 1 else 'column')

        def accepted():
            return [d for d in cmd.diagnostics[n_diag:]
                    if d[2].get('last_command_topic') == '~/cmd/impact']
        spin_until(ex, lambda: bool(accepted()), 30.0)
        if not accepted() or accepted()[0][2]['last_command'] != 'accepted':
            raise RuntimeError(f'impact not accepted: {accepted()[:1]}')
        t_imp = float(accepted()[0][2]['last_command_sim_time_s'])     # when it was applied
        spin_until(ex, lambda: bool(cmd.clouds) and cmd.clouds[-1][0] >= t_imp + duration_s,
                   duration_s / max(rtf, 0.05) * 3.0 + 30.0)
        info['wall_s'] = time.monotonic() - w1
        info['frames'] = sum(t >= t_imp for t, _ in cmd.clouds[n_c:])
    finally:
        code, output = stop_process(proc)
        ex.shutdown()
        cmd.destroy_node()
        rclpy.shutdown(context=ctx)
    t_all, s_all = stamped_strain(cmd.clouds, cmd.strain, network.levels, network.h0)
    keep = t_all >= t_imp
    times, strain = t_all[keep] - t_imp, s_all[keep]
    # the same figures as the headless run (solver.simulate.runner): the first passage of the pulse
    pulses = [observables.first_passage(times, strain[:, c], network.h0).as_dict()
              for c in range(network.n_columns)] if len(times) else []
    last = cmd.diagnostics[-1][2] if cmd.diagnostics else {}
    span = float(times[-1]) if len(times) else 0.0
    summary = {
        'scene': str(scene_path), 'domain_id': domain_id, 'v0': v0, 'prestrain': prestrain,
        'startup_s': info.get('startup_s'), 't_impact': t_imp, 'sim_span_s': span,
        'wall_s': info.get('wall_s'), 'frames': info.get('frames'),
        'strain_frames': int(len(times)), 'strain_unmatched': len(cmd.strain) - len(t_all),
        'real_time_factor': span / info['wall_s'] if info.get('wall_s') else None,
        'receive_rate_hz': info['frames'] / info['wall_s'] if info.get('wall_s') else None,
        'min_strain': float(strain.min()) if strain.size else None,
        'pulses': pulses, 'diagnostics': last, 'node_exit_code': code,
        'node_output_tail': output.strip().splitlines()[-5:], 'outputs': outputs,
    }
    (out / 'summary.json').write_text(json.dumps(summary, indent=2, default=str))
    return summary


def format_summary(s):
    """Human-readable lines of a :func:`run_demo` summary."""
    lines = [f"demo: {Path(s['scene']).name} over ROS 2 (domain {s['domain_id']}): node up in "
             f"{s['startup_s']:.1f} s, impact v0 = {s['v0']} m/s accepted at t = "
             f"{s['t_impact']:.3f} s",
             f"  received {s['frames']} frames covering {s['sim_span_s']:.3f} s of simulation in "
             f"{s['wall_s']:.2f} s wall: {s['real_time_factor']:.2f}x real time, "
             f"{s['receive_rate_hz']:.0f} Hz"]
    lines.append(f"  figures from {s['strain_frames']} ~/strain frames (float64)")
    for c, p in enumerate(s['pulses']):
        amp = p['amplitude']
        lines.append(f"  column {c}: leading pulse |strain| {amp:.4f} at {p['t_ref']:g} s after "
                     f"impact, speed {p['speed_m_s']:.3f} m/s, width {p['width_prisms']} prisms")
    d = s['diagnostics']
    if d:
        lines.append(f"  node: energy {d.get('energy_J')} J, constraint error "
                     f"{d.get('constraint_error')}, commands accepted "
                     f"{d.get('commands_accepted')}, rejected {d.get('commands_rejected')}")
    return lines + _exit_and_outputs(s)


def run_focus_demo(focus, scene_file='config/scenes/lens_focus.yaml', speed=1.5, rtf=1.0,
                   out_dir='runs/demo_focus', domain_id=None, record=True, dims=2,
                   connect_timeout_s=120.0, plan_timeout_s=600.0):
    """The lens over ROS 2: start the node (second process) paused with ``medium_speed_m_s`` =
    ``speed``, start its clock once connected, command ``~/cmd/focus`` at ``focus`` = (X, Z) m
    (the node does not step while it plans), wait until the node has measured the arrivals of
    its own run (``focus_measured`` on ``/diagnostics``, the scene's ``run.t_end`` after the
    impact), keep the last ``~/field`` image, stop the node. The focal gain is the node's peak
    pressure at F over that of the same array at the mean prestrain, simulated here
    (solver.studies.lens.simulate; the same field model, 2D). Returns the summary dict (also
    ``out_dir/summary.json``)."""
    import json

    from solver import field

    from solver import lens
    from solver import Scene

    from tensegrity_ros.node.params import find_config

    if domain_id is None:
        domain_id = demo_domain_id()
    scene_path = find_config(scene_file)
    scene = Scene.load(scene_path)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    params = {'scene_file': str(scene_path), 'real_time_factor': float(rtf),
              'start_paused': True, 'medium_speed_m_s': float(speed),
              'diagnostics_rate_hz': 10.0}
    outputs = {'mcap': None, 'rerun': None}
    if record and _recorder_available('io.mcap_writer'):
        outputs['mcap'] = params['record_mcap'] = str(out / 'run')
    if record and _recorder_available('io.rerun_sink'):
        outputs['rerun'] = params['record_rerun'] = str(out / 'run.rrd')
    proc = node_process(params, domain_id)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    cmd = Commander(context=ctx)
    cmd.listen_to_field()
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(cmd)
    info = {}
    try:
        w0 = time.monotonic()
        spin_until(ex, lambda: (cmd.connected(paused=True)
                                and cmd.pub_focus.get_subscription_count() > 0)
                   or proc.poll() is not None, connect_timeout_s)
        if not cmd.connected(paused=True):
            raise RuntimeError('the node did not come up within '
                               f'{connect_timeout_s:g} s (exit code {proc.poll()})')
        info['startup_s'] = time.monotonic() - w0
        cmd.set_running(ex, True)
        n_diag = len(cmd.diagnostics)
        cmd.focus(*focus)

        def answered():
            return [d for d in cmd.diagnostics[n_diag:]
                    if d[2].get('last_command_topic') == '~/cmd/focus']
        spin_until(ex, lambda: bool(answered()) or proc.poll() is not None, plan_timeout_s)
        if not answered() or answered()[0][2]['last_command'] != 'accepted':
            detail = answered()[0][2].get('last_command_detail') if answered() else \
                f'no answer within {plan_timeout_s:g} s'
            raise RuntimeError(f'focus not accepted: {detail}')
        info['plan_s'] = time.monotonic() - w0 - info['startup_s']
        w1 = time.monotonic()
        window = float(scene.run.t_end) + 0.5
        spin_until(ex, lambda: any(d[2].get('focus_measured') == 'true'
                                   for d in cmd.diagnostics[n_diag:]),
                   window / max(rtf, 0.05) * 3.0 + 60.0)
        info['wall_s'] = time.monotonic() - w1
        measured = [d[2] for d in cmd.diagnostics[n_diag:] if d[2].get('focus_measured') == 'true']
        if not measured:
            raise RuntimeError('the node did not report the arrivals of the focus')
        t_last = float(measured[0]['sim_time_s'])
        spin_until(ex, lambda: bool(cmd.fields) and cmd.fields[-1][0] >= t_last - 1e-3, 10.0)
    finally:
        code, output = stop_process(proc)
        ex.shutdown()
        cmd.destroy_node()
        rclpy.shutdown(context=ctx)
    d = measured[0]
    prestrain = json.loads(d['focus_prestrain'])
    target = json.loads(d['focus_arrival_target_s'])
    predicted = json.loads(d['focus_arrival_predicted_s'])
    simulated = json.loads(d['focus_arrival_simulated_s'])
    residual = json.loads(d['focus_residual_s'])
    xs = lens.base_x(scene)
    columns = [{'column': i, 'x_m': float(x), 'prestrain': p, 'target_s': T, 'predicted_s': P,
                'simulated_s': S, 'residual_s': R}
               for i, (x, p, T, P, S, R) in enumerate(zip(xs, prestrain, target, predicted,
                                                          simulated, residual))]
    v0 = float(d['focus_v0'])
    p_u = float(np.mean(prestrain))
    tu, bu, _ = lens.simulate(scene, np.full(len(xs), p_u), v0)
    ref = field.focus_report(tu, bu, xs, focus, speed, scene.structure.column_spacing, dims,
                             plane=False)
    p_f = float(d['focus_peak_pressure'])
    image = cmd.fields[-1][1] if cmd.fields else None
    summary = {
        'scene': str(scene_path), 'domain_id': domain_id, 'focus_m': [float(v) for v in focus],
        'medium_speed_m_s': float(speed), 'v0': v0, 't0_s': float(d['focus_t0_s']),
        'startup_s': info.get('startup_s'), 'plan_s': info.get('plan_s'),
        'wall_s': info.get('wall_s'), 'columns': columns, 'uniform_prestrain': p_u,
        'p_focus': p_f, 'p_focus_uniform': ref['p_focus'],
        'focal_gain': p_f / ref['p_focus'] if ref['p_focus'] > 0 and p_f > 0 else None,
        'field_images': len(cmd.fields),
        'field_shape': list(image.shape) if image is not None else None,
        'field_max': float(image.max()) if image is not None else None,
        'node_exit_code': code, 'node_output_tail': output.strip().splitlines()[-5:],
        'outputs': outputs,
    }
    (out / 'summary.json').write_text(json.dumps(summary, indent=2, default=str))
    return summary


def format_focus_summary(s):
    """Human-readable lines of a :func:`run_focus_demo` summary."""
    X, Z = s['focus_m']
    lines = [f"demo: {Path(s['scene']).name} over ROS 2 (domain {s['domain_id']}): focus "
             f"({X:g}, {Z:g}) m in a medium of {s['medium_speed_m_s']:g} m/s, v0 = {s['v0']:g} "
             f"m/s; node up in {s['startup_s']:.1f} s, plan in {s['plan_s']:.1f} s, T0 = "
             f"{s['t0_s']:.4f} s after the impact",
             '  column   x m    prestrain   target s   predicted s   simulated s   residual ms']

    def num(v, fmt):
        return 'n/a' if v is None else format(v, fmt)
    for c in s['columns']:
        res = None if c['residual_s'] is None else 1e3 * c['residual_s']
        lines.append(f"  {c['column']:6d} {c['x_m']:6.3f} {c['prestrain']:11.5f} "
                     f"{c['target_s']:10.4f} {c['predicted_s']:13.4f} "
                     f"{num(c['simulated_s'], '13.4f')} {num(res, '13.3f')}")
    gain = s['focal_gain']
    lines.append(f"  focal gain {num(gain, '.3f')}: peak pressure at F {s['p_focus']:.4g} (the "
                 f"node's run) against {s['p_focus_uniform']:.4g} at uniform prestrain "
                 f"{s['uniform_prestrain']:.5f} (model units, 2D)")
    if s['field_shape']:
        lines.append(f"  ~/field: {s['field_images']} images of {s['field_shape'][0]} x "
                     f"{s['field_shape'][1]} (32FC1), largest peak pressure "
                     f"{s['field_max']:.4g}")
    return lines + _exit_and_outputs(s)


def _exit_and_outputs(s):
    """The last lines of a demo summary: the node's exit code and the files written."""
    lines = [f"  node stopped with exit code {s['node_exit_code']}"]
    for key, path in s['outputs'].items():
        lines.append(f'  {key}: {path}' if path else f'  {key}: not recorded')
    return lines
