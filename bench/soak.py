"""Soak of the node under a command flood: ``python -m bench.soak [--minutes 10] [--rate 1000]``
(also ``tensegrity bench --only soak``); ``--no-mcap``, ``--no-rerun`` leave a recording out (to
compare), ``--rate 0`` the commands.

The node runs in a second process at ``real_time_factor`` 0, recording MCAP and Rerun, on its
own ROS domain (localhost only). This process floods it with ``--rate`` commands per second:
valid impacts and prestrains, impacts strong enough to make it diverge (``on_divergence``
``reset``: it goes back to rest and runs on; the flood's ``set_running`` calls would resume a
paused one), malformed commands (NaN, infinite, out of range, wrong length), ``reset`` calls and
parameter changes. It watches ``~/strain``, ``~/nodes`` and ``/diagnostics``, samples the node's
memory, open files and threads, and at the end stops the node with SIGINT and reads both
recordings back. The report (printed as a table, written as JSON) says whether the node stayed
alive, every frame was finite, the publish rate held, the files are complete, and no helper
process is left.

``python -m bench.soak --actuator [--minutes 0.5]`` is the acceptance flood of a virtual
actuator instead (:data:`ACTUATOR`): 1,000 commands/s, 40 % impacts of 0.02-0.15 m/s, 30 %
prestrains, 30 % NaN, MCAP recording, nothing else (no resets, no ``set_running``). It passes
when the node publishes at least 180 frames per wall second, nothing non-finite, and never
pauses; the exit code is 1 otherwise.

This module holds the node's process, the flood and the command; :mod:`bench.soak_report` reads
the recordings back (``check_files``) and writes the report's table (``table``), both reachable
here too.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .soak_report import check_files, table

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / 'config' / 'scenes' / 'fb_column.yaml'
PUBLISH_RATE_HZ = 200.0
STRONG_EVERY_S = 10.0            # an impact of 10 m/s (the column diverges) this often
# the acceptance flood of a virtual actuator (--actuator): its command mix and what it must hold
ACTUATOR = {'impact_share': 0.4, 'impact_v0': (0.02, 0.15), 'prestrain_share': 0.3,
            'prestrain': (0.001, 0.01), 'min_frames_per_s': 180.0}


def _proc_stats(proc):
    """RSS (MB), open files, threads of a psutil process; its child processes (pid, RSS MB): the
    node starts none, so any is reported."""
    import psutil
    with proc.oneshot():
        rss = proc.memory_info().rss / 2**20
        fds = proc.num_fds()
        threads = proc.num_threads()
        cpu = proc.cpu_times()
    helpers, helper_cpu = [], 0.0
    for child in proc.children(recursive=True):
        try:
            helpers.append((child.pid, child.memory_info().rss / 2**20))
            c = child.cpu_times()
            helper_cpu += c.user + c.system
        except psutil.Error:
            pass
    return {'rss_mb': rss, 'open_files': fds, 'threads': threads, 'helpers': helpers,
            'cpu_s': cpu.user + cpu.system, 'helper_cpu_s': helper_cpu}


def _start_node(out, domain_id, mcap=True, rerun=True, params=None):
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    params = {'scene_file': str(SCENE), 'real_time_factor': 0.0,
              'publish_rate_hz': PUBLISH_RATE_HZ,
              **({'record_mcap': str(out / 'soak.mcap')} if mcap else {}),
              **({'record_rerun': str(out / 'soak.rrd')} if rerun else {}), **(params or {})}
    cmd = [sys.executable, '-m', 'tensegrity_ros.node.node', '--ros-args']
    for k, v in params.items():
        cmd += ['-p', f'{k}:={v}']
    log = open(out / 'node.log', 'w')
    return subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT), log


def _flood_message(rng, n_columns):
    """(kind, values) of one flood command: 'impact', 'prestrain' or 'bad_impact'/'bad_prestrain'
    with a malformed value list. (Impacts strong enough to diverge are sent on a timer.)"""
    u = rng.random()
    if u < 0.35:
        return 'impact', [float(rng.uniform(-0.01, 0.01))]
    if u < 0.65:
        return 'prestrain', [float(rng.uniform(0.001, 0.01))]
    bad = rng.integers(4)
    values = ([math.nan], [math.inf], [11.0], [0.1] * (n_columns + 1))[bad]
    return ('bad_impact' if rng.random() < 0.5 else 'bad_prestrain'), values


def _actuator_message(rng, n_columns):
    """(kind, values) of one command of the actuator flood (:data:`ACTUATOR`): an impact, a
    prestrain, or a NaN on either topic."""
    u = rng.random()
    if u < ACTUATOR['impact_share']:
        return 'impact', [float(rng.uniform(*ACTUATOR['impact_v0']))]
    if u < ACTUATOR['impact_share'] + ACTUATOR['prestrain_share']:
        return 'prestrain', [float(rng.uniform(*ACTUATOR['prestrain']))]
    return ('bad_impact' if rng.random() < 0.5 else 'bad_prestrain'), [math.nan]


def soak(duration_s=600.0, rate=1000.0, out_dir=None, domain_id=None, warmup_s=5.0, log=print,
         seed=0, mcap=True, rerun=True, actuator=False, node_params=None):
    """Run the soak for ``duration_s`` s of flood; returns the report (dict). ``mcap``,
    ``rerun``: whether the node records each (both for the soak proper; off to compare).
    ``actuator``: the actuator flood (:data:`ACTUATOR`; impacts, prestrains and NaN only);
    ``node_params``: more parameters of the node (dict)."""
    import psutil
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rcl_interfaces.srv import SetParameters
    from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import Float64MultiArray
    from std_srvs.srv import SetBool, Trigger

    from tensegrity_ros.msgs import cdr, messages
    from tensegrity_ros.node.demo import spin_until, stop_process

    out = Path(out_dir) if out_dir else Path(tempfile.mkdtemp(prefix='soak-'))
    out.mkdir(parents=True, exist_ok=True)
    domain_id = domain_id if domain_id is not None else 100 + os.getpid() % 100
    proc, node_log = _start_node(out, domain_id, mcap, rerun, node_params)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    client = rclpy.create_node('soak_client', context=ctx)
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    base = messages.resolve_topic('~/').rstrip('/')
    # the client spends as little CPU as it can (it shares the cores with the node): no QoS event
    # handlers (each is polled on every executor cycle), commands published as CDR bytes
    # (tensegrity_ros.msgs.cdr, the same message as messages.command_array)
    quiet_pub = PublisherEventCallbacks(use_default_callbacks=False)
    quiet_sub = SubscriptionEventCallbacks(use_default_callbacks=False)
    pubs = {topic: client.create_publisher(Float64MultiArray, f'{base}/cmd/{topic}', qos,
                                           event_callbacks=quiet_pub)
            for topic in ('impact', 'prestrain')}
    seen = {'strain': 0, 'non_finite': 0, 'nodes': 0, 'nodes_non_finite': 0, 'diag': [],
            'strain_walls': []}

    def on_strain(msg):
        seen['strain'] += 1
        seen['strain_walls'].append(time.monotonic())
        if not np.all(np.isfinite(np.asarray(msg.data))):
            seen['non_finite'] += 1

    def on_nodes(msg):
        seen['nodes'] += 1
        if not np.all(np.isfinite(np.frombuffer(bytes(msg.data), dtype='<f4'))):
            seen['nodes_non_finite'] += 1

    def on_diag(msg):
        for st in msg.status:
            if st.name == messages.NODE_NAME:
                seen['diag'].append((time.monotonic(), st.level, st.message,
                                     {kv.key: kv.value for kv in st.values}))
    client.create_subscription(Float64MultiArray, f'{base}/strain', on_strain, qos,
                               event_callbacks=quiet_sub)
    client.create_subscription(PointCloud2, f'{base}/nodes', on_nodes, qos,
                               event_callbacks=quiet_sub)
    client.create_subscription(DiagnosticArray, '/diagnostics', on_diag, qos,
                               event_callbacks=quiet_sub)
    cli_running = client.create_client(SetBool, f'{base}/set_running')
    cli_reset = client.create_client(Trigger, f'{base}/reset')
    cli_params = client.create_client(SetParameters, f'{base}/set_parameters')
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(client)
    report = {'duration_s': duration_s, 'rate_target': rate, 'out_dir': str(out),
              'record': {'mcap': bool(mcap), 'rerun': bool(rerun)},
              'mix': 'actuator' if actuator else 'soak'}
    sent = {k: 0 for k in ('impact', 'strong', 'prestrain', 'bad_impact', 'bad_prestrain',
                           'set_running', 'reset', 'set_parameters')}
    futures = []
    try:
        ok = spin_until(ex, lambda: seen['strain'] > 0 and all(
            p.get_subscription_count() for p in pubs.values()) and cli_running.service_is_ready()
            and cli_params.service_is_ready(), 180)
        if not ok:
            raise RuntimeError(f'the node did not come up (exit code {proc.poll()})')
        spin_until(ex, lambda: False, warmup_s)
        node_ps = psutil.Process(proc.pid)
        report['start'] = _proc_stats(node_ps)
        log(f'soak: node up, flooding {rate:g} commands/s for {duration_s:g} s'
            f'{" (actuator mix)" if actuator else ""}')
        rng = np.random.default_rng(seed)
        n_columns = 1
        t0 = time.monotonic()
        cpu0 = time.process_time()
        n_sent = 0
        next_running = next_reset = next_param = t0
        next_strong, quiet_until = t0 + 2.0, t0
        samples = []                        # (wall, frames_published) from /diagnostics
        last_stats = t0
        while True:
            now = time.monotonic()
            if now - t0 >= duration_s or proc.poll() is not None:
                break
            due = int((now - t0) * rate)
            while n_sent < due:
                if actuator:
                    kind, values = _actuator_message(rng, n_columns)
                else:
                    kind, values = _flood_message(rng, n_columns)
                if kind == 'impact' and now < quiet_until:      # the strong one stays the last
                    kind = 'prestrain'                           # impact of its tick
                    values = [float(rng.uniform(0.001, 0.01))]
                if now >= next_strong and not actuator:     # makes the column diverge
                    kind, values, next_strong = 'strong', [10.0], now + STRONG_EVERY_S
                    quiet_until = now + 0.05
                topic = 'impact' if kind in ('impact', 'strong', 'bad_impact') else 'prestrain'
                pubs[topic].publish(cdr.multi_array_cdr(np.asarray(values, np.float64),
                                                        ('all',)))
                sent[kind] += 1
                n_sent += 1
            if actuator:                    # commands only
                pass
            elif now >= next_running:                   # resumes a paused node
                futures.append(cli_running.call_async(SetBool.Request(data=True)))
                sent['set_running'] += 1
                next_running = now + 0.5
            if now >= next_reset and not actuator:
                futures.append(cli_reset.call_async(Trigger.Request()))
                sent['reset'] += 1
                next_reset = now + 2.0
            if now >= next_param and not actuator:
                value = float(rng.choice([10.0, 20.0, 40.0]))
                req = SetParameters.Request(parameters=[
                    Parameter('marker_rate_hz', value=value).to_parameter_msg()])
                futures.append(cli_params.call_async(req))
                sent['set_parameters'] += 1
                next_param = now + 1.0
            if now - last_stats >= 10.0:
                last_stats = now
                stats = _proc_stats(node_ps)
                helper = ''.join(f', helper RSS {m:.0f} MB' for _, m in stats['helpers'])
                log(f'soak: {now - t0:5.0f} s, {n_sent} sent, node RSS {stats["rss_mb"]:.0f} MB'
                    f'{helper}')
            ex.spin_once(timeout_sec=0.001)
            futures = [f for f in futures if not f.done()]
        wall = time.monotonic() - t0
        report['sent'] = dict(sent, total=n_sent, per_s=n_sent / wall)
        report['node_alive'] = proc.poll() is None
        if report['node_alive']:        # CPU seconds per wall second of the flood, each process
            stats = _proc_stats(node_ps)
            report['cpu_per_s'] = {
                'node': (stats['cpu_s'] - report['start']['cpu_s']) / wall,
                'rerun_helper': (stats['helper_cpu_s'] - report['start']['helper_cpu_s']) / wall,
                'flood_client': (time.process_time() - cpu0) / wall}
        spin_until(ex, lambda: False, 1.5)           # the last periodic /diagnostics
        if report['node_alive']:
            report['end'] = _proc_stats(node_ps)
        diag = [d for d in seen['diag'] if d[0] >= t0]
        for w, level, _, values in diag:
            # the periodic ones (a divergence or a pause publishes one at once, in between)
            if not samples or w - samples[-1][0] >= 0.4:
                samples.append((w, int(values['frames_published']), values['running'] == 'true'))
        # the rate over the diagnostics periods the node was running throughout (not paused)
        rates, frames, span = [], 0, 0.0
        for (w0, f0, r0), (w1, f1, r1) in zip(samples, samples[1:]):
            if r0 and r1 and w1 - w0 > 0.2:
                rates.append((f1 - f0) / (w1 - w0))
                frames += f1 - f0
                span += w1 - w0
        total_rate = frames / span if span else 0.0
        report['running_fraction'] = (span / (samples[-1][0] - samples[0][0])
                                      if len(samples) > 1 else 0.0)
        last = diag[-1][3] if diag else {}
        # the longest tick of each diagnostics period (ms; the node's tick_max_ms)
        ticks = [float(v['tick_max_ms']) for _, level, _, v in diag if v['running'] == 'true']
        report['publish_rate'] = {
            'target_hz': PUBLISH_RATE_HZ, 'mean_hz': total_rate,
            'p05_hz': float(np.percentile(rates, 5)) if rates else None,
            'min_hz': float(min(rates)) if rates else None,
            'tick_max_ms_median': float(np.median(ticks)) if ticks else None,
            'tick_max_ms_max': float(max(ticks)) if ticks else None}
        # frames per wall second over the whole flood, paused or not (the node's own count)
        flood = [(w, f) for w, f, _ in samples if w <= t0 + wall]
        report['frames_per_s'] = ((flood[-1][1] - flood[0][1]) / (flood[-1][0] - flood[0][0])
                                  if len(flood) > 1 and flood[-1][0] > flood[0][0] else 0.0)
        walls = np.array(seen['strain_walls'])
        report['strain_received_per_s'] = float(np.sum((walls >= t0) & (walls <= t0 + wall))
                                                / wall)
        report['commands'] = {k: int(last.get(f'commands_{k}', 0))
                              for k in ('accepted', 'superseded', 'rejected')}
        received = sum(report['commands'].values())
        report['commands']['received'] = received
        # topic commands the node never took: overwritten in its subscriptions' keep-last-10
        # history (reliable QoS does not block a publisher) while it was busy
        report['commands']['qos_dropped'] = n_sent - received
        # pauses: /diagnostics saying running false (after running true or at the start)
        report['pauses'] = sum(1 for a, b in zip([None] + diag, diag)
                               if b[3]['running'] == 'false' and
                               (a is None or a[3]['running'] == 'true'))
        report['paused_diagnostics'] = sum(d[3]['running'] == 'false' for d in diag)
        before = [d for d in seen['diag'] if d[0] < t0]
        report['divergences'] = (int(diag[-1][3].get('divergences', 0)) - (
            int(before[-1][3].get('divergences', 0)) if before else 0)) if diag else 0
        report['last_divergence'] = diag[-1][3].get('last_divergence') if diag else None
        report['strain_received'] = seen['strain']
        report['strain_non_finite_received'] = seen['non_finite']
        report['nodes_received'] = seen['nodes']
        report['nodes_non_finite_received'] = seen['nodes_non_finite']
        report['diagnostics_received'] = len(diag)
    finally:
        helpers = []
        try:
            helpers = [pid for pid, _ in _proc_stats(psutil.Process(proc.pid))['helpers']]
        except psutil.Error:
            pass
        code, _ = stop_process(proc, 60.0)
        node_log.close()
        ex.shutdown()
        client.destroy_node()
        rclpy.shutdown(context=ctx)
    report['node_exit_code'] = code
    deadline = time.monotonic() + 30
    while any(psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE
              for p in helpers) and time.monotonic() < deadline:
        time.sleep(0.1)
    report['helpers_left'] = [p for p in helpers if psutil.pid_exists(p)
                              and psutil.Process(p).status() != psutil.STATUS_ZOMBIE]
    report['log_bytes'] = (out / 'node.log').stat().st_size
    report['files'] = check_files(out / 'soak.mcap' if mcap else None,
                                  out / 'soak.rrd' if rerun else None)
    report['load_average'] = os.getloadavg()
    return report


def actuator_verdict(r):
    """The acceptance of the actuator flood: (check, passed, figure) rows."""
    f = r['files']['mcap']
    non_finite = (r['strain_non_finite_received'] + r['nodes_non_finite_received']
                  + (f['non_finite'] if f else 0))
    return [
        ('node alive, exit code 0', r['node_alive'] and r['node_exit_code'] == 0,
         f"{r['node_alive']}, {r['node_exit_code']}"),
        (f"frames per wall second >= {ACTUATOR['min_frames_per_s']:g}",
         r['frames_per_s'] >= ACTUATOR['min_frames_per_s'], f"{r['frames_per_s']:.1f}"),
        ('non-finite values published (strain, nodes received; MCAP)', non_finite == 0,
         str(non_finite)),
        ('never paused', r['pauses'] == 0 and r['paused_diagnostics'] == 0,
         f"{r['pauses']} pauses, {r['divergences']} divergences"),
        ('MCAP complete', bool(f and f['complete']), str(bool(f and f['complete']))),
    ]


def main(out='bench/results', quick=False, log=print, minutes=None, rate=1000.0, mcap=True,
         rerun=True, actuator=False):
    """``tensegrity bench --only soak``: the soak (10 minutes; 20 s with ``quick``); writes
    ``soak.json`` and ``soak.md`` into ``out``; returns their paths. ``actuator``: the actuator
    flood instead (30 s unless ``minutes``; no Rerun recording), ``actuator.json`` and
    ``actuator.md`` with its verdict; the paths and whether it passed."""
    out = Path(out)
    if actuator:
        duration = 60.0 * minutes if minutes is not None else 30.0
        name, rerun = 'actuator', False
    else:
        duration = 60.0 * minutes if minutes is not None else 20.0 if quick else 600.0
        name = 'soak'
    with tempfile.TemporaryDirectory(prefix='soak-') as tmp:
        r = soak(duration, rate, out_dir=tmp, log=log, mcap=mcap, rerun=rerun, actuator=actuator)
    out.mkdir(parents=True, exist_ok=True)
    text = table(r)
    passed = None
    if actuator:
        verdict = actuator_verdict(r)
        passed = all(ok for _, ok, _ in verdict)
        r['verdict'] = {check: {'passed': ok, 'figure': fig} for check, ok, fig in verdict}
        text += '\n\n| acceptance | passed | figure |\n|---|---|---|\n' + '\n'.join(
            f"| {check} | {'yes' if ok else 'NO'} | {fig} |" for check, ok, fig in verdict)
    (out / f'{name}.json').write_text(json.dumps(r, indent=2, default=str))
    (out / f'{name}.md').write_text(text + '\n')
    log(text)
    paths = [str(out / f'{name}.json'), str(out / f'{name}.md')]
    return (paths, passed) if actuator else paths


if __name__ == '__main__':
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--minutes', type=float, default=None,
                   help='flood duration (default 10; 0.5 with --actuator)')
    p.add_argument('--rate', type=float, default=1000.0, help='commands per second')
    p.add_argument('--out', default='bench/results')
    p.add_argument('--no-mcap', action='store_true', help='the node records no MCAP (to compare)')
    p.add_argument('--no-rerun', action='store_true', help='the node records no Rerun (to '
                   'compare)')
    p.add_argument('--actuator', action='store_true', help='the acceptance flood of a virtual '
                   'actuator: 40 %% impacts of 0.02-0.15 m/s, 30 %% prestrains, 30 %% NaN, MCAP '
                   'only; exit code 1 unless it holds 180 frames/s, publishes nothing '
                   'non-finite and never pauses')
    a = p.parse_args()
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    minutes = a.minutes if a.minutes is not None or a.actuator else 10.0
    result = main(a.out, minutes=minutes, rate=a.rate, mcap=not a.no_mcap, rerun=not a.no_rerun,
                  actuator=a.actuator)
    sys.exit(0 if not a.actuator or result[1] else 1)
