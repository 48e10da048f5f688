"""Cost of an MCAP log: a run with and without ``tensegrity run --mcap``'s recorder, side by side.

    python -m bench.mcap_overhead [--scene config/scenes/fb_column.yaml] [--repeats 3]
                                  [--out bench/results/mcap_overhead.json]

The same simulation runs from its impact to ``run.t_end`` at ``run.output_dt``, alternately plain
and recording (recorder opened, the impact command, every frame's messages built by
:mod:`tensegrity_ros.msgs.messages` and written, file closed), ``repeats`` pairs after one
discarded warm-up pair. Reports the overhead ``recorded / plain - 1`` of wall and process CPU time
(all threads) as the median over pairs, the file size per simulated second and per frame, and the
time :func:`~tensegrity_ros.io.mcap_reader.load_run` takes relative to the plain run. Only ratios
measured in the same process are reported: the machine may be busy. The figures go to ``--out``
(JSON) with the host's load average at the start.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path


def _one(sim, scene, path):
    from solver.simulate.runner import run
    from tensegrity_ros.io.mcap_frames import FrameLog, marker_every
    from tensegrity_ros.io.mcap_writer import McapRecorder

    v0 = scene['loading.impact.v0']
    t_end, output_dt = scene['run.t_end'], scene['run.output_dt']
    sim.reset()
    sim.apply_impact(v0, scene['loading.impact.columns'])
    w0, c0 = time.perf_counter(), time.process_time()
    if path is None:
        run(sim, t_end, output_dt)
    else:
        with McapRecorder(path) as rec:
            log = FrameLog(rec, sim.network, marker_every=marker_every(output_dt))
            log.command('~/cmd/impact', [v0], 'all', sim.frame())
            run(sim, t_end, output_dt, on_frame=log.frame)
    return time.perf_counter() - w0, time.process_time() - c0


def measure(scene_path='config/scenes/fb_column.yaml', repeats=3, log=print):
    """Dict of median ratios and sizes (see the module docstring)."""
    from solver.build.scene import Scene
    from solver.simulate.array import simulation_for
    from tensegrity_ros.io.mcap_reader import load_run

    scene = Scene.load(scene_path)
    sim = simulation_for(scene)
    sim.advance(sim.dt)                       # compile (or load cached) kernels first
    wall, cpu, load = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / 'run.mcap'
        for i in range(repeats + 1):
            order = (None, path) if i % 2 == 0 else (path, None)
            got = {('rec' if p is not None else 'plain'): _one(sim, scene, p) for p in order}
            t0 = time.perf_counter()
            run = load_run(path)
            t_load = time.perf_counter() - t0
            if i == 0:
                continue                       # warm-up pair
            wall.append(got['rec'][0] / got['plain'][0] - 1.0)
            cpu.append(got['rec'][1] / got['plain'][1] - 1.0)
            load.append(t_load / got['plain'][0])
            log(f'pair {i}: wall overhead {wall[-1]:+.1%}, cpu overhead {cpu[-1]:+.1%}, '
                f'load_run / plain run {load[-1]:.2f}')
        size = path.stat().st_size
    t_end = scene['run.t_end']
    out = {'scene': scene.name, 'frames': len(run.time), 'n_nodes': sim.network.n_nodes,
           'n_cables': sim.network.n_cables,
           'wall_overhead': statistics.median(wall), 'cpu_overhead': statistics.median(cpu),
           'load_over_plain_run': statistics.median(load), 'file_bytes': size,
           'bytes_per_sim_second': size / t_end, 'bytes_per_frame': size / len(run.time)}
    log(f"{out['scene']} ({out['n_nodes']} nodes, {out['n_cables']} cables, {out['frames']} "
        f"frames): recording costs {out['wall_overhead']:+.0%} wall, {out['cpu_overhead']:+.0%} "
        f"CPU; load_run takes {out['load_over_plain_run']:.2f}x the plain run; "
        f"{size / 1e6:.2f} MB ({out['bytes_per_frame'] / 1e3:.1f} kB per frame)")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--scene', default='config/scenes/fb_column.yaml')
    ap.add_argument('--repeats', type=int, default=3)
    ap.add_argument('--out', default='bench/results/mcap_overhead.json')
    args = ap.parse_args(argv)
    load_avg = os.getloadavg()[0]
    out = measure(args.scene, args.repeats)
    out.update(repeats=args.repeats, load_average_1min_at_start=load_avg)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2))
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
