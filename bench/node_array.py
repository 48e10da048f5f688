"""How many distinct columns the node streams at real time, for each way the array steps.

    python -m bench.node_array [--columns 10,20,30,50] [--window 5] [--span 1.2] [--ramp 0.2]
                               [--v0 0.3] [--bisect] [--whole-steps] [--out bench/results]
    (or: tensegrity bench --only node_array)

For each number of columns N the node (:class:`tensegrity_ros.node.node.TensegritySim`) runs in
this process, as :mod:`bench.node_overhead` runs it (its own rclpy context and domain id,
discovery on this machine, a single-threaded executor), on the FB column scene
(``config/scenes/fb_column.yaml``) with ``structure.n_columns`` = N, unpaced
(``real_time_factor`` 0) and publishing 200 frames per second. No other process subscribes: the
frames are built and handed to DDS, nobody receives them.

For each way :class:`solver.simulate.array.ArraySimulation` steps the array (``lanes`` False:
one column simulation at a time, on threads; True: alike simulations as lanes; ``'auto'``: the
faster of the two as measured) the node is reset through ``~/reset`` and commanded as a user
commands it, over its topics: N different prestrains (``np.linspace(0.02, 0.08, N)``, one per
column, ``prestrain_ramp_s`` 0) on ``~/cmd/prestrain``, then an impact of every column
(``--v0`` m/s) on ``~/cmd/impact``. From the tick that applied the impact on, the node steps for
``--window`` wall seconds or until ``--span`` s of simulation (1.2 s, the scene's ``run.t_end``)
have passed since the impact, whichever comes first: the steps cost more early in the wave (the
contacts of the impact) than later, so every way and every N is measured on the same stretch of
the wave where it keeps up; reported are the simulated seconds per wall second (the achieved
real-time factor), the frames per wall second, the simulated seconds per CPU second of this
process (all its threads), the longest tick and the cost of publishing a frame (the pacer's
moving average: the array's frame, its messages, handing them to DDS). The largest N of the
list whose factor is at least 1 is given per way; ``--bisect`` narrows it down between that N
and the next one of the list (to ``--resolution`` columns).

Then, for each N and each way of stepping, one prestrain command with a ramp (``--ramp`` s of
simulation time, the columns' prestrains reversed) from the rest state: the real-time factor
while the ramp runs (measured until the ramp ends or for ``--window`` wall seconds, whichever
comes first). One column simulation at a time, each column takes one compiled call per advance
that sets the ramp's rest lengths before every step
(:meth:`solver.simulate.loading.Loading._ramped`); as lanes, the ramping columns step as lane
groups of their own, each lane with its ramp (:mod:`solver.integrators.rk4laneramp`).

``--whole-steps`` makes every stepping tick take at least one whole step. The node's pacer
(:class:`tensegrity_ros.node.pacing.Pacer`) takes a fraction of a step when its estimate of one
step's cost exceeds the tick's budget; on an array a fraction of a step costs about what a whole
one does (the pacer predicts it with a floor), so this bound shows what the stepping itself
allows.

The results go to ``node_array.json`` (``node_array_v0_<v0>.json`` for another ``--v0``,
``_whole`` appended with ``--whole-steps``), with the machine's load average at the start and the
end and the commit. One run on a machine that
may be busy: the figures move with its load.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .common import COLUMNS, ROOT

MODES = (False, True, 'auto')
PRESTRAIN = (0.02, 0.08)         # the columns' prestrains: evenly spaced over this range
PUBLISH_RATE_HZ = 200.0
V0 = 0.3                         # m/s, the impact of every column (default)
SPAN_S = 1.2                     # s of simulation after the impact a measurement covers, at most
                                 # (the scene's run.t_end; a step costs more early in the wave)
COMMAND_TIMEOUT_S = 60.0         # wall seconds a command may take to be applied


def mode_name(mode):
    """The JSON and table name of a value of ``ArraySimulation.lanes``."""
    return {False: 'single', True: 'lanes', 'auto': 'auto'}[mode]


def commit():
    """``(commit hash, whether solver/, tensegrity_ros/ or bench/ have uncommitted changes)``
    of the checkout, or ``(None, None)`` outside git."""
    try:
        rev = subprocess.run(['git', 'rev-parse', 'HEAD'], cwd=ROOT, text=True,
                             capture_output=True, check=True).stdout.strip()
        dirty = subprocess.run(['git', 'status', '--porcelain', 'solver', 'tensegrity_ros',
                                'bench'], cwd=ROOT, text=True, capture_output=True,
                               check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None, None
    return rev, bool(dirty)


def prestrains(n):
    """The N different cross prestrains, one per column."""
    return np.linspace(*PRESTRAIN, n)


class Session:
    """The node on an array of ``n_columns`` FB columns in this process, and a small commanding
    node beside it (publishers of ``~/cmd/prestrain`` and ``~/cmd/impact``, a client of
    ``~/reset``); :meth:`close` tears both down."""

    def __init__(self, n_columns, folder, domain_id, whole_steps=False):
        import rclpy
        import yaml
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter import Parameter
        from std_msgs.msg import Float64MultiArray
        from std_srvs.srv import Trigger

        from solver.build.scene import Scene
        from tensegrity_ros.msgs import messages
        from tensegrity_ros.node.demo import spin_until
        from tensegrity_ros.node.node import TensegritySim
        from tensegrity_ros.node.qos import QOS

        self.n_columns = n_columns
        # integrator.lanes on: the node's start loads the ramped lanes' call too
        # (params.warm_commands); each measurement then sets the way it steps
        scene = Scene.load(COLUMNS['FB']).with_overrides([('structure.n_columns', n_columns),
                                                          ('integrator.lanes', 'on')])
        path = Path(folder) / f'fb_column_{n_columns}.yaml'
        path.write_text(yaml.safe_dump(scene.data))
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain_id)
        self.node = self.ctl = None
        try:
            self.node = TensegritySim(context=self.ctx, parameter_overrides=[
                Parameter('scene_file', value=str(path)),
                Parameter('real_time_factor', value=0.0),
                Parameter('publish_rate_hz', value=PUBLISH_RATE_HZ),
                Parameter('prestrain_ramp_s', value=0.0)])
            self.ctl = rclpy.create_node('node_array_bench', context=self.ctx)
            base = messages.resolve_topic('~/', messages.NAMESPACE,
                                          messages.NODE_NAME).rstrip('/')
            self.pub = {key: self.ctl.create_publisher(Float64MultiArray, f'{base}/cmd/{key}',
                                                       QOS) for key in ('prestrain', 'impact')}
            self.reset_client = self.ctl.create_client(Trigger, f'{base}/reset')
            self.trigger = Trigger
            if whole_steps:             # a tick takes at least one whole step
                limit = self.node.stepper.limit
                self.node.stepper.limit = lambda n: limit(1 if 0 < n < 1 else n)
            self.ex = SingleThreadedExecutor(context=self.ctx)
            self.ex.add_node(self.node)
            self.ex.add_node(self.ctl)
            self._spin_until = spin_until
            self.command_array = messages.command_array
            ready = spin_until(self.ex, lambda: all(
                p.get_subscription_count() > 0 for p in self.pub.values())
                and self.reset_client.service_is_ready(), COMMAND_TIMEOUT_S)
            if not ready:
                raise RuntimeError('node_array: the node\'s command topics and ~/reset did not '
                                   'connect')
        except BaseException:
            self.close()
            raise

    def spin_until(self, predicate, timeout_s=COMMAND_TIMEOUT_S):
        return self._spin_until(self.ex, predicate, timeout_s, step_s=0.01)

    def set_ramp(self, ramp_s):
        from rclpy.parameter import Parameter
        result = self.node.set_parameters([Parameter('prestrain_ramp_s', value=float(ramp_s))])
        if not result[0].successful:
            raise RuntimeError(f'node_array: prestrain_ramp_s refused: {result[0].reason}')

    def reset(self):
        """``~/reset`` through the service; returns when it answered."""
        future = self.reset_client.call_async(self.trigger.Request())
        if not self.spin_until(future.done) or not future.result().success:
            raise RuntimeError('node_array: ~/reset did not answer')

    def command(self, key, values, label):
        """Publish ``values`` on ``~/cmd/<key>`` and spin until the node applied it; returns
        the wall time (monotonic s) at which it is seen applied."""
        node = self.node
        accepted = node.counts['accepted']
        rejected = node.counts['rejected']
        self.pub[key].publish(self.command_array(values, label))
        if not self.spin_until(lambda: node.counts['accepted'] > accepted
                               or node.counts['rejected'] > rejected):
            raise RuntimeError(f'node_array: ~/cmd/{key} was not applied within '
                               f'{COMMAND_TIMEOUT_S:g} s')
        topic, verdict, detail = node.intake.last_command
        if verdict != 'accepted' or topic != f'~/cmd/{key}':
            raise RuntimeError(f'node_array: ~/cmd/{key} not accepted: {detail}')
        return time.monotonic()

    def window(self, window_s, until_t=None):
        """Spin for ``window_s`` wall seconds (or until the episode time reaches ``until_t``);
        returns the achieved figures."""
        node = self.node
        sim = node.sim
        node.publishing.tick_max_s = 0.0
        f0, t0 = node.counts['frames'], sim.t
        d0 = node.divergences
        steps = []                      # the steps of each stepping tick (a fraction: part of one)
        advance = node.stepper.advance

        def counted(n):
            steps.append(n)
            return advance(n)
        node.stepper.advance = counted
        w0, c0 = time.perf_counter(), time.process_time()
        try:
            while time.perf_counter() - w0 < window_s:
                if until_t is not None and sim.t >= until_t:
                    break
                self.ex.spin_once(timeout_sec=0.01)
        finally:
            del node.stepper.advance
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        sim_s = sim.t - t0
        return {'rtf': sim_s / wall, 'rate_hz': (node.counts['frames'] - f0) / wall,
                'sim_per_cpu_s': sim_s / cpu, 'wall_s': wall, 'sim_s': sim_s,
                'tick_max_ms': 1e3 * node.publishing.tick_max_s,
                'stepping_ticks': len(steps),
                'steps_per_tick': float(np.mean(steps)) if steps else 0.0,
                'part_step_ticks': sum(1 for n in steps if n < 1),
                'publish_ms': 1e3 * node.pacer.publish_cost,
                'divergences': node.divergences - d0}

    def close(self):
        import rclpy
        if getattr(self, 'ex', None) is not None:
            self.ex.shutdown()
        if self.node is not None:
            self.node.close()
            self.node.destroy_node()
        if self.ctl is not None:
            self.ctl.destroy_node()
        rclpy.shutdown(context=self.ctx)


def measure_mode(session, mode, v0, window_s, span_s):
    """One way of stepping on the wave of N different prestrains and an impact of all: the
    first ``span_s`` s of simulation after the impact, or ``window_s`` wall seconds of them."""
    node = session.node
    sim = node.sim
    sim.lanes = mode
    p = prestrains(session.n_columns)
    session.reset()
    session.set_ramp(0.0)
    session.command('prestrain', p, 'column')
    if not np.allclose(sim.prestrain.mean(axis=1), p, rtol=1e-12, atol=0):
        raise RuntimeError('node_array: the prestrain command did not reach the columns')
    session.command('impact', [v0], 'all')
    t_impact = node.intake.last_command_t - node.t_offset        # episode time of the impact
    row = session.window(window_s, until_t=t_impact + span_s)
    row.update(n_columns=session.n_columns, mode=mode_name(mode),
               t_start_s=float(sim.t - row['sim_s'] - t_impact),
               t_end_s=float(sim.t - t_impact),
               column_simulations=int(sim.n_simulated), model=sim.model.name,
               finite=bool(np.isfinite(sim.frame().positions).all()))
    plan = getattr(sim, '_plan', None)
    if mode and plan is not None:       # how the last interval is split
        row['lane_groups'] = [len(g.sims) for g in plan.groups]
        row['single_simulations'] = len(plan.singles)
    chooser = getattr(sim, '_chooser', None)
    if mode == 'auto' and chooser is not None:
        row['auto_cost_us_per_step'] = {mode_name(k): (None if c is None else 1e6 * c)
                                        for k, c in chooser.cost.items()}
    return row


def measure_ramp(session, ramp_s, window_s, mode):
    """The factor while a prestrain ramp of ``ramp_s`` s runs on the array (from rest), the
    array stepping in ``mode``."""
    node = session.node
    sim = node.sim
    sim.lanes = mode
    session.reset()
    session.set_ramp(ramp_s)
    t_cmd = sim.t
    session.command('prestrain', prestrains(session.n_columns)[::-1], 'column')
    # the tick that applies the command steps on: the window starts from that point
    row = session.window(window_s, until_t=t_cmd + ramp_s)
    done = sim.t >= t_cmd + ramp_s - 1e-9
    row.update(n_columns=session.n_columns, mode=mode_name(mode), ramp_s=ramp_s,
               ramp_done=bool(done),
               ramp_wall_s_estimate=ramp_s / row['rtf'] if row['rtf'] > 0 else None)
    session.set_ramp(0.0)
    return row


def largest_real_time(rows, mode):
    """The largest N of ``rows`` whose factor in ``mode`` is at least 1, or None."""
    ok = [r['n_columns'] for r in rows if r['mode'] == mode and r['rtf'] >= 1.0]
    return max(ok) if ok else None


def main(out_dir='bench/results', log=print, columns=(10, 20, 30, 50), window_s=5.0,
         span_s=SPAN_S, ramp_s=0.2, v0=V0, bisect=False, resolution=5, whole_steps=False,
         domain_id=None):
    """Measure (see the module text) and write ``node_array.json`` into ``out_dir``; returns
    the files written."""
    import json

    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    domain_id = domain_id if domain_id is not None else 120 + os.getpid() % 10
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    load_start = list(os.getloadavg())
    rev, dirty = commit()
    log(f'node_array: load average {load_start[0]:.2f} (1 min) on {os.cpu_count()} cores, '
        f'commit {rev and rev[:10]}')
    w0 = time.perf_counter()
    rows, ramps, probes = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        def run(n, modes, with_ramp):
            session = Session(n, tmp, domain_id, whole_steps)
            try:
                got = []
                for mode in modes:
                    row = measure_mode(session, mode, v0, window_s, span_s)
                    got.append(row)
                    log(f'{n:4d} columns, {row["mode"]:>6}: {row["rtf"]:.3f}x real time at '
                        f'{row["rate_hz"]:.0f} Hz ({row["sim_per_cpu_s"]:.3f} s per CPU s, '
                        f'longest tick {row["tick_max_ms"]:.1f} ms, a frame '
                        f'{row["publish_ms"]:.2f} ms)')
                ramps = [measure_ramp(session, ramp_s, window_s, m)
                         for m in (modes if with_ramp else ())]
                for ramp in ramps:
                    log(f'{n:4d} columns, {ramp["mode"]:>6}, ramp of {ramp_s:g} s: '
                        f'{ramp["rtf"]:.4f}x real time at {ramp["rate_hz"]:.0f} Hz over '
                        f'{ramp["wall_s"]:.1f} s'
                        f'{"" if ramp["ramp_done"] else " (the ramp still ran)"}')
                return got, ramps
            finally:
                session.close()

        for n in columns:
            got, ramped = run(n, MODES, ramp_s > 0)
            rows += got
            ramps += ramped
        if bisect:
            for mode in MODES:
                name = mode_name(mode)
                lo = largest_real_time(rows, name)
                above = [n for n in columns if (lo is None or n > lo)]
                hi = min(above) if above else None
                lo = lo or 1
                while hi is not None and hi - lo > resolution:
                    mid = (lo + hi) // 2
                    got, _ = run(mid, (mode,), False)
                    probes += got
                    lo, hi = (mid, hi) if got[0]['rtf'] >= 1.0 else (lo, mid)
    largest = {mode_name(m): largest_real_time(rows + probes, mode_name(m)) for m in MODES}
    result = {
        'commit': rev, 'uncommitted_changes': dirty,
        'load_average_start': load_start, 'load_average_end': list(os.getloadavg()),
        'cpu_count': os.cpu_count(),
        'scene': str(COLUMNS['FB'].relative_to(ROOT)), 'window_s': window_s,
        'span_s': span_s,
        'publish_rate_hz': PUBLISH_RATE_HZ, 'real_time_factor': 0.0, 'v0_m_s': v0,
        'prestrain_range': list(PRESTRAIN), 'subscriber': False,
        'whole_steps': whole_steps,
        'rows': rows, 'largest_real_time': largest, 'bisection': probes,
        'ramp': ramps, 'wall_s': time.perf_counter() - w0,
    }
    log('largest N at real time: ' + ', '.join(f'{k} {v}' for k, v in largest.items()))
    name = 'node_array' + ('' if v0 == V0 else f'_v0_{v0:g}') + ('_whole' if whole_steps else '')
    path = out / f'{name}.json'
    path.write_text(json.dumps(result, indent=2) + '\n')
    return [str(path)]


def table(result):
    """The figures as text: one line per N, the factor and the frame rate of each way."""
    names = [mode_name(m) for m in MODES]
    lines = ['   N  ' + '  '.join(f'{n:>16}' for n in names)]
    by = {(r['n_columns'], r['mode']): r for r in result['rows']}
    for n in sorted({r['n_columns'] for r in result['rows']}):
        cells = []
        for name in names:
            r = by.get((n, name))
            cells.append(f'{r["rtf"]:7.3f}x {r["rate_hz"]:4.0f} Hz' if r else ' ' * 16)
        lines.append(f'{n:4d}  ' + '  '.join(cells))
    for r in result['ramp']:
        lines.append(f'{r["n_columns"]:4d}  {r["mode"]:>6}, ramp of {r["ramp_s"]:g} s: '
                     f'{r["rtf"]:.4f}x at {r["rate_hz"]:.0f} Hz')
    return '\n'.join(lines)


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--columns', default='10,20,30,50',
                    help='numbers of columns, comma separated')
    ap.add_argument('--window', type=float, default=5.0,
                    help='wall seconds per measurement, at most')
    ap.add_argument('--span', type=float, default=SPAN_S,
                    help='simulated seconds after the impact per measurement, at most')
    ap.add_argument('--ramp', type=float, default=0.2,
                    help='prestrain ramp, s of simulation time (0: no ramp measurement)')
    ap.add_argument('--v0', type=float, default=V0, help='impact velocity, m/s')
    ap.add_argument('--bisect', action='store_true',
                    help='narrow the largest N at real time down per way of stepping')
    ap.add_argument('--resolution', type=int, default=5, help='columns, for --bisect')
    ap.add_argument('--whole-steps', action='store_true',
                    help='every stepping tick takes at least one whole step (the node\'s pacer '
                         'takes a fraction of one when a whole one exceeds its budget)')
    ap.add_argument('--out', default='bench/results')
    return ap.parse_args(argv)


def cli(argv=None):
    import json
    args = parse_args(argv)
    columns = tuple(int(c) for c in args.columns.split(',') if c.strip())
    paths = main(args.out, log=lambda msg: print(msg, file=sys.stderr, flush=True),
                 columns=columns, window_s=args.window, span_s=args.span, ramp_s=args.ramp,
                 v0=args.v0,
                 bisect=args.bisect, resolution=args.resolution,
                 whole_steps=args.whole_steps)
    print(table(json.loads(Path(paths[0]).read_text())))
    for p in paths:
        print(p)
    return 0


if __name__ == '__main__':
    sys.exit(cli())
