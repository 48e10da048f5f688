"""Cost of a Rerun recording: a run with and without :class:`RerunRecorder`, side by side.

    python -m bench.rerun_overhead [--scene config/scenes/fb_column.yaml] [--repeats 7] [--out DIR]
                                   [--t-end S]

The same simulation is run from its impact to ``run.t_end`` (or ``--t-end``: the opening and
closing of a recording are a fixed cost that weighs less in longer runs) at the scene's output rate
(``run.output_dt``), alternately plain and recording to a ``.rrd`` file (recorder construction,
every frame and the final flush included), ``repeats`` pairs after one discarded warm-up pair.
Reports the overhead ``recorded / plain - 1`` of wall time and of process CPU time (all threads,
so Rerun's encoder and writer threads count), per pair, as the median of the pairs and as the ratio
of the best (smallest) times of each kind (the least disturbed by other processes). Each pair is
followed by a recording of the same frames fed from memory (the recording alone, no simulation):
its best time over the best plain run is the cost of recording with the least noise. Writes
``rerun_overhead.csv``. Only ratios measured in the same process are reported; the machine may be
busy.
"""
from __future__ import annotations

import argparse
import csv
import statistics
import sys
import tempfile
import time
from pathlib import Path


def _one(sim, scene, path, frames=None):
    """(wall s, process CPU s, main-thread CPU s) of one run, plain (``path`` None) or recorded
    to ``path``; with ``frames`` (the run's frames), only recording those frames is timed."""
    from solver.runner import run
    from tensegrity_ros.rerun_log import RerunRecorder

    v0 = scene['loading.impact.v0']
    t_end, output_dt = scene['run.t_end'], scene['run.output_dt']
    sim.reset()
    sim.apply_impact(v0, scene['loading.impact.columns'])
    w0, c0, m0 = time.perf_counter(), time.process_time(), time.thread_time()
    if path is None:
        run(sim, t_end, output_dt)
    else:
        with RerunRecorder(sim.network, path) as rec:
            rec.command(sim.t, f'impact v0 = {v0} m/s')
            if frames is None:
                run(sim, t_end, output_dt, on_frame=rec.frame)
            else:
                for f in frames:
                    rec.frame(f)
    return time.perf_counter() - w0, time.process_time() - c0, time.thread_time() - m0


def measure(scene_path='config/scenes/fb_column.yaml', repeats=3, log=print, t_end=None):
    """List of dicts, one per measured pair: wall and CPU seconds plain / recorded, and ratios;
    also the time of the recording alone (the run's frames fed from memory), ``*_rec_only_s``."""
    from solver.runner import run
    from solver.scene import Scene
    from solver.simulation import Simulation

    scene = Scene.load(scene_path)
    if t_end is not None:
        scene = scene.with_overrides([('run.t_end', float(t_end))])
    sim = Simulation(scene)
    sim.advance(sim.dt)                       # compile (or load cached) kernels first
    sim.reset()
    sim.apply_impact(scene['loading.impact.v0'], scene['loading.impact.columns'])
    frames = []
    run(sim, scene['run.t_end'], scene['run.output_dt'], on_frame=frames.append)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(repeats + 1):
            rrd = Path(tmp) / f'run{i}.rrd'
            order = (None, rrd) if i % 2 == 0 else (rrd, None)
            got = {}
            for path in order:
                got['rec' if path is not None else 'plain'] = _one(sim, scene, path)
            got['only'] = _one(sim, scene, Path(tmp) / 'only.rrd', frames)
            if i == 0:
                continue                       # warm-up pair (thread start-up, page cache)
            row = {'pair': i, 'wall_plain_s': got['plain'][0], 'wall_rec_s': got['rec'][0],
                   'cpu_plain_s': got['plain'][1], 'cpu_rec_s': got['rec'][1],
                   'wall_rec_only_s': got['only'][0], 'cpu_rec_only_s': got['only'][1],
                   'main_cpu_rec_only_s': got['only'][2],
                   'rrd_bytes': rrd.stat().st_size}
            row['wall_overhead'] = row['wall_rec_s'] / row['wall_plain_s'] - 1.0
            row['cpu_overhead'] = row['cpu_rec_s'] / row['cpu_plain_s'] - 1.0
            log(f"pair {i}: wall {row['wall_plain_s']:.3f} s plain, {row['wall_rec_s']:.3f} s "
                f"recorded ({100 * row['wall_overhead']:+.1f} %); cpu {row['cpu_plain_s']:.3f} / "
                f"{row['cpu_rec_s']:.3f} s ({100 * row['cpu_overhead']:+.1f} %); recording alone "
                f"{row['wall_rec_only_s']:.3f} s wall, {row['cpu_rec_only_s']:.3f} s cpu "
                f"({row['main_cpu_rec_only_s']:.3f} s in the main thread); "
                f"{row['rrd_bytes'] / 1e6:.2f} MB")
            rows.append(row)
    return rows


def main(out='bench/results', quick=False, log=print, scene='config/scenes/fb_column.yaml',
         repeats=None, t_end=None):
    """Run :func:`measure`, write ``rerun_overhead.csv`` into ``out``; returns the files
    written."""
    rows = measure(scene, repeats or (3 if quick else 7), log=log, t_end=t_end)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / ('rerun_overhead.csv' if t_end is None else f'rerun_overhead_t{t_end:g}.csv')
    with path.open('w', newline='') as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    wall = statistics.median(r['wall_overhead'] for r in rows)
    cpu = statistics.median(r['cpu_overhead'] for r in rows)
    best_wall = min(r['wall_rec_s'] for r in rows) / min(r['wall_plain_s'] for r in rows) - 1
    best_cpu = min(r['cpu_rec_s'] for r in rows) / min(r['cpu_plain_s'] for r in rows) - 1
    alone_wall = min(r['wall_rec_only_s'] for r in rows) / min(r['wall_plain_s'] for r in rows)
    alone_cpu = min(r['cpu_rec_only_s'] for r in rows) / min(r['cpu_plain_s'] for r in rows)
    alone_main = min(r['main_cpu_rec_only_s'] for r in rows) / min(r['cpu_plain_s'] for r in rows)
    log(f'rerun recording overhead, median of {len(rows)} pairs: wall {100 * wall:+.1f} %, '
        f'cpu {100 * cpu:+.1f} %; best of each: wall {100 * best_wall:+.1f} %, cpu '
        f'{100 * best_cpu:+.1f} %; recording alone / plain run (best of each): wall '
        f'{100 * alone_wall:.1f} %, cpu {100 * alone_cpu:.1f} % (main thread '
        f'{100 * alone_main:.1f} %)  -> {path}')
    return [str(path)]


if __name__ == '__main__':
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--scene', default='config/scenes/fb_column.yaml')
    ap.add_argument('--repeats', type=int, default=7)
    ap.add_argument('--out', default='bench/results')
    ap.add_argument('--t-end', type=float, help='simulated seconds per run (default: the scene)')
    a = ap.parse_args()
    main(a.out, scene=a.scene, repeats=a.repeats, t_end=a.t_end)
    sys.exit(0)
