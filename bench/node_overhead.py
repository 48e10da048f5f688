"""Cost of the ROS 2 node against the bare solver, measured side by side in one process.

    python -m bench.node_overhead [--scene config/scenes/fb_column.yaml] [--window 3] [--rounds 3]
                                  [--no-subscriber] [--record] [--out bench/results]

Each round measures, one after the other on the same wave (an impact at the start of each window):

- ``bare``: the solver alone, ``Simulation.advance`` in chunks of 0.05 s of simulation (its best
  throughput: one divergence check per 100 steps at the default dt);
- ``node rtf=0``: the node in this process (its own rclpy context and executor) with
  ``real_time_factor`` 0 and ``publish_rate_hz`` 200, publishing every topic (markers at 20 Hz);
- ``node rtf=1``: the same node paced to the wall clock.

A subscriber process receives every topic (as RViz or Foxglove would), so DDS really delivers the
data; ``--no-subscriber`` leaves it out. Reported: simulated seconds per wall second (real-time
factor) and frames per wall second for each, the ratio node rtf=0 / bare (the publishing overhead
is ``1 - ratio``), the same ratio per CPU second of this process (all its threads, so DDS is
counted; robust when other processes compete for the cores), and the longest tick the node
reported. Medians over rounds; the machine may be busy, so only the ratios, measured within
seconds of each other, mean anything.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

LISTENER = '''
import rclpy, sys
from rclpy.executors import SingleThreadedExecutor
from tensegrity_ros.node.demo import Commander
rclpy.init()
c = Commander()
c.create_subscription(__import__('visualization_msgs.msg', fromlist=['MarkerArray']).MarkerArray,
                      c.base + '/markers', lambda m: None, 10)
ex = SingleThreadedExecutor(); ex.add_node(c)
print('ready', flush=True)
try:
    while rclpy.ok():
        ex.spin_once(timeout_sec=0.1)
        del c.clouds[:], c.strain[:], c.tension[:]
except Exception:
    pass
'''


def _bare(sim, window_s, chunk):
    sim.reset()
    sim.apply_impact(0.1)
    t0, c0 = time.perf_counter(), time.process_time()
    frames = 0
    while time.perf_counter() - t0 < window_s:
        sim.advance(chunk * sim.dt)
        frames += 1
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {'rtf': sim.t / wall, 'rate_hz': frames / wall, 'sim_per_cpu': sim.t / cpu}


def _node(node, ex, rtf, window_s):
    node.params['real_time_factor'] = rtf
    node.sim.reset()
    node.sim.apply_impact(0.1)
    node.restart_pace()            # the pace and the achieved factor count from here
    f0, t_sim0 = node.counts['frames'], node.sim.t
    node.publishing.tick_max_s = 0.0
    t0, c0 = time.perf_counter(), time.process_time()
    while time.perf_counter() - t0 < window_s:
        ex.spin_once(timeout_sec=0.01)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    sim_s = node.sim.t - t_sim0
    return {'rtf': sim_s / wall, 'rate_hz': (node.counts['frames'] - f0) / wall,
            'sim_per_cpu': sim_s / cpu, 'tick_max_ms': 1e3 * node.publishing.tick_max_s}


def cost_breakdown(node, n=200):
    """CPU microseconds per call of the pieces of one publish frame (process time, so other
    processes on the machine do not count): stepping one frame's worth of steps, ``sim.frame()``,
    building the messages, building the markers, the whole ``_publish_frame`` and one executor
    ``spin_once`` with a ready timer."""
    from rclpy.executors import SingleThreadedExecutor

    from tensegrity_ros.msgs import messages as M
    sim = node.sim
    sim.reset()
    sim.apply_impact(0.1)
    sim.advance(0.1)
    steps = max(1, int(round(node.period / sim.dt)))

    def cpu(f, k=n):
        f()
        c0 = time.process_time()
        for _ in range(k):
            f()
        return (time.process_time() - c0) / k * 1e6
    fr = sim.frame()
    stamp = M.sim_stamp(fr.t)
    out = {'steps_per_frame': steps,
           'advance_one_frame_us': cpu(lambda: sim.advance(steps * sim.dt)),
           'sim_frame_us': cpu(sim.frame),
           'frame_messages_us': cpu(lambda: M.frame_messages(fr, sim.network, markers=False,
                                                              clock=True)),
           'marker_array_us': cpu(lambda: M.marker_array(fr, sim.network, stamp), 20)}
    due = node.publishing.markers_due
    node.publishing.markers_due = lambda now: False
    out['publish_frame_us'] = cpu(lambda: node.publishing.frame(time.monotonic()))
    node.publishing.markers_due = due
    ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)
    node.timer.cancel()
    ready = node.create_timer(0.0, lambda: None, )
    out['spin_once_us'] = cpu(lambda: ex.spin_once(timeout_sec=0.0))
    node.destroy_timer(ready)
    node.timer.reset()
    ex.remove_node(node)
    return out


def measure(scene='config/scenes/fb_column.yaml', window_s=3.0, rounds=3, subscriber=True,
            publish_rate_hz=200.0, domain_id=None, model='', log=print, record=None):
    """Run the rounds; returns a dict of medians and per-round figures. ``record``: a folder
    where the node records MCAP and Rerun (``record_mcap``, ``record_rerun``) all along."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from tensegrity_ros.node.node import TensegritySim, load_simulation

    domain_id = domain_id if domain_id is not None else 10 + os.getpid() % 20
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    root = str(Path(__file__).resolve().parent.parent)
    env['PYTHONPATH'] = root + os.pathsep + env.get('PYTHONPATH', '')
    listener = None
    if subscriber:
        listener = subprocess.Popen([sys.executable, '-c', LISTENER], env=env,
                                    stdout=subprocess.PIPE, text=True)
        listener.stdout.readline()
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    try:
        params = dict(scene_file=scene, real_time_factor=0.0, publish_rate_hz=publish_rate_hz,
                      model=model)
        sim = load_simulation(dict(params, integrator='', dt=0.0))
        bare_sim = load_simulation(dict(params, integrator='', dt=0.0))
        if record is not None:
            params.update(record_mcap=str(Path(record) / 'node.mcap'),
                          record_rerun=str(Path(record) / 'node.rrd'))
        node = TensegritySim(sim=sim, context=ctx,
                             parameter_overrides=[Parameter(k, value=v)
                                                  for k, v in params.items()])
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        chunk = max(1, int(round(1.0 / publish_rate_hz / sim.dt)))
        if subscriber:
            end = time.monotonic() + 10
            while time.monotonic() < end and node.pubs['~/nodes'].get_subscription_count() == 0:
                ex.spin_once(timeout_sec=0.05)
        _node(node, ex, 0.0, 0.5)                                   # warm-up
        rows = []
        for r in range(rounds):
            row = {'bare': _bare(bare_sim, window_s, max(1, int(round(0.05 / sim.dt)))),
                   'node_rtf0': _node(node, ex, 0.0, window_s),
                   'node_rtf1': _node(node, ex, 1.0, window_s)}
            row['ratio_rtf0_bare'] = row['node_rtf0']['rtf'] / row['bare']['rtf']
            row['cpu_ratio_rtf0_bare'] = (row['node_rtf0']['sim_per_cpu']
                                          / row['bare']['sim_per_cpu'])
            rows.append(row)
            log(f"round {r + 1}: bare {row['bare']['rtf']:.2f}x, node rtf=0 "
                f"{row['node_rtf0']['rtf']:.2f}x at {row['node_rtf0']['rate_hz']:.0f} Hz "
                f"(ratio {row['ratio_rtf0_bare']:.3f}, per CPU second "
                f"{row['cpu_ratio_rtf0_bare']:.3f}), node rtf=1 "
                f"{row['node_rtf1']['rtf']:.3f}x at {row['node_rtf1']['rate_hz']:.0f} Hz")
        costs = cost_breakdown(node)
        log('CPU per call, us: ' + ', '.join(f'{k} {v:.0f}' for k, v in costs.items()))
        node.close()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
        if listener is not None:
            listener.terminate()
            listener.wait(10)

    def med(path):
        vals = [row[path[0]][path[1]] if len(path) == 2 else row[path[0]] for row in rows]
        return statistics.median(vals)

    return {
        'scene': scene, 'model': sim.model.name, 'window_s': window_s, 'rounds': rounds,
        'subscriber': subscriber, 'recording': record is not None,
        'publish_rate_hz': publish_rate_hz, 'steps_per_frame': chunk,
        'bare_rtf': med(('bare', 'rtf')),
        'node_rtf0_rtf': med(('node_rtf0', 'rtf')), 'node_rtf0_rate_hz': med(('node_rtf0',
                                                                                'rate_hz')),
        'node_rtf1_rtf': med(('node_rtf1', 'rtf')), 'node_rtf1_rate_hz': med(('node_rtf1',
                                                                                'rate_hz')),
        'ratio_rtf0_bare': med(('ratio_rtf0_bare',)),
        'overhead': 1.0 - med(('ratio_rtf0_bare',)),
        'cpu_ratio_rtf0_bare': med(('cpu_ratio_rtf0_bare',)),
        'cpu_overhead': 1.0 - med(('cpu_ratio_rtf0_bare',)),
        'tick_max_ms_rtf0': max(row['node_rtf0']['tick_max_ms'] for row in rows),
        'tick_max_ms_rtf1': max(row['node_rtf1']['tick_max_ms'] for row in rows),
        'cpu_costs_us': costs,
        'rows': rows,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--scene', default='config/scenes/fb_column.yaml')
    ap.add_argument('--window', type=float, default=3.0, help='wall seconds per measurement')
    ap.add_argument('--rounds', type=int, default=3)
    ap.add_argument('--model', default='', help='model override (default: the scene\'s)')
    ap.add_argument('--no-subscriber', action='store_true')
    ap.add_argument('--record', action='store_true',
                    help='the node records MCAP and Rerun (to a temporary folder) all along')
    ap.add_argument('--out', default='bench/results')
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        res = measure(args.scene, args.window, args.rounds, subscriber=not args.no_subscriber,
                      model=args.model, record=tmp if args.record else None)
    print(f"{res['model']}: bare solver {res['bare_rtf']:.2f}x real time; node rtf=0: "
          f"{res['node_rtf0_rtf']:.2f}x"
          f" at {res['node_rtf0_rate_hz']:.0f} Hz = {res['ratio_rtf0_bare']:.3f} of the bare "
          f"solver (overhead {100 * res['overhead']:.1f} % wall, "
          f"{100 * res['cpu_overhead']:.1f} % per CPU second; longest tick "
          f"{res['tick_max_ms_rtf0']:.1f} ms); node rtf=1: {res['node_rtf1_rtf']:.3f}x at "
          f"{res['node_rtf1_rate_hz']:.0f} Hz (longest tick {res['tick_max_ms_rtf1']:.1f} ms)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    name = (f"node_overhead_{res['model']}{'' if res['subscriber'] else '_nosub'}"
            f"{'_record' if res['recording'] else ''}.json")
    (out / name).write_text(json.dumps(res, indent=2))
    print(out / name)
    return 0


if __name__ == '__main__':
    sys.exit(main())
