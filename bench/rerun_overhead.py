"""Cost of a Rerun recording: a run with and without :class:`RerunRecorder`, side by side.

    python -m bench.rerun_overhead [--scene config/scenes/fb_column.yaml] [--repeats 30]
                                   [--out DIR] [--t-end S]

The same simulation is run from its impact to ``run.t_end`` (or ``--t-end``: the opening and
closing of a recording are a fixed cost that weighs less in longer runs) at the scene's output rate
(``run.output_dt``), alternately plain and recording to a ``.rrd`` file (recorder construction,
every frame and ``close()`` included), ``repeats`` pairs after one discarded warm-up pair. Reports
the overhead ``recorded / plain - 1`` of wall time and of CPU time (all threads of this process
Rerun's encoder and writer threads count), per pair, as the median of the
pairs (with a 90 % bootstrap interval of that median: :func:`median_interval`) and as the ratio
of the best (smallest) times of each kind (the least disturbed by other processes). Each pair is
followed by a recording of the same frames fed from memory (the recording alone, no simulation):
its best time over the best plain run is the cost of recording with the least noise. Writes
``rerun_overhead.csv`` (one row per pair) and ``rerun_overhead.json`` (the medians, the time a
fresh process takes to import the recorder and rerun-sdk, and the time of a first small
recording in that process: paid once per process). Only ratios measured in the same process are
reported; the machine may be busy.

The recorder buffers the frames and sends them as columns every ``flush_every`` frames; Rerun's
threads encode and write: the timing ends when ``close()`` returns, which is after the file was
written to its end (footer included).
Every recorded file is checked after its timing: it must hold every frame and read without the
"no footer" warning. ``others_cores`` is the CPU time other processes used during a pair per
second of it, ``steal_cores`` the time the hypervisor took from this machine's vCPUs (both from
``/proc/stat``, less this process; 1.0 = one of the two cores all along): with a
busy or stolen second core the recording's threads compete with the simulation, so the summary
also gives the median of the quiet pairs (the two below :data:`QUIET_CORES` together), besides
the median of all pairs, and says ``HOST BUSY`` when the median pair was not quiet: the figure
then shows the host rather than the recording.
"""
from __future__ import annotations

import argparse
import csv
import gc
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

# A pair (or a run, by its median pair) counts as quiet when other processes and the hypervisor
# (steal) took less than this many cores during it.
QUIET_CORES = 0.1


def _cpu_stat():
    """(CPU seconds the whole machine spent busy so far, without idle, iowait and steal; CPU
    seconds the hypervisor took from this machine's vCPUs so far: steal), from ``/proc/stat``, or
    None."""
    try:
        with open('/proc/stat') as f:
            v = [int(x) for x in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    tick = os.sysconf('SC_CLK_TCK')
    return (sum(v[:3]) + sum(v[5:7])) / tick, v[7] / tick


def check_complete(path, n_frames):
    """Raise unless the .rrd at ``path`` holds ``n_frames`` rows of ``/energy`` and its footer."""
    from rerun.chunk import RrdReader
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        rows = sum(chunk.to_record_batch().num_rows for chunk in RrdReader(str(path)).stream()
                   if chunk.entity_path == '/energy' and not chunk.is_static)
    if rows != n_frames or any('footer' in str(w.message) for w in caught):
        raise RuntimeError(f'{path}: {rows} of {n_frames} frames, '
                           f'{[str(w.message) for w in caught]}')


def _one(sim, scene, path, frames=None):
    """(wall s, CPU s of this process, main-thread CPU s, 0.0) of one run, plain (``path`` None)
    or recorded to ``path``; with ``frames`` (the
    run's frames), only recording those frames is timed."""
    from solver.simulate.runner import run
    from tensegrity_ros.io.rerun_sink import RerunRecorder

    v0 = scene['loading.impact.v0']
    t_end, output_dt = scene['run.t_end'], scene['run.output_dt']
    sim.reset()
    sim.apply_impact(v0, scene['loading.impact.columns'])
    w0, c0, m0 = time.perf_counter(), time.process_time(), time.thread_time()
    if path is None:
        run(sim, t_end, output_dt)
    else:
        with RerunRecorder(sim.network, path) as rec:              # as the CLI
            rec.command(sim.t, f'impact v0 = {v0} m/s')
            if frames is None:
                run(sim, t_end, output_dt, on_frame=rec.frame)
            else:
                for f in frames:
                    rec.frame(f)
    w, c, m = time.perf_counter() - w0, time.process_time() - c0, time.thread_time() - m0
    return w, c, m, 0.0


def measure(scene_path='config/scenes/fb_column.yaml', repeats=3, log=print, t_end=None):
    """List of dicts, one per measured pair: wall and CPU seconds plain / recorded, and ratios;
    also the time of the recording alone (the run's frames fed from memory), ``*_rec_only_s``."""
    from solver.simulate.runner import run
    from solver.build.scene import Scene
    from solver.simulate.array import simulation_for

    scene = Scene.load(scene_path)
    if t_end is not None:
        scene = scene.with_overrides([('run.t_end', float(t_end))])
    sim = simulation_for(scene)
    sim.advance(sim.dt)                       # compile (or load cached) kernels first
    from tensegrity_ros.io import rerun_sink  # noqa: F401
    gc.freeze()                               # as tensegrity run does before its run
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
            b0, c0, w0 = _cpu_stat(), time.process_time(), time.perf_counter()
            for path in order:
                got['rec' if path is not None else 'plain'] = _one(sim, scene, path)
            b1, c1, w1 = _cpu_stat(), time.process_time(), time.perf_counter()
            got['only'] = _one(sim, scene, Path(tmp) / 'only.rrd', frames)
            check_complete(rrd, len(frames))                  # after the timings
            check_complete(Path(tmp) / 'only.rrd', len(frames))
            if i == 0:
                continue                       # warm-up pair (thread start-up, page cache)
            row = {'pair': i, 'wall_plain_s': got['plain'][0], 'wall_rec_s': got['rec'][0],
                   'cpu_plain_s': got['plain'][1], 'cpu_rec_s': got['rec'][1],
                   'wall_rec_only_s': got['only'][0], 'cpu_rec_only_s': got['only'][1],
                   'main_cpu_rec_only_s': got['only'][2],
                   'rrd_bytes': rrd.stat().st_size,
                   'others_cores': (None if b0 is None else max(
                       0.0, (b1[0] - b0[0]) - (c1 - c0) - got['rec'][3]) / (w1 - w0)),
                   'steal_cores': None if b0 is None else (b1[1] - b0[1]) / (w1 - w0)}
            row['wall_overhead'] = row['wall_rec_s'] / row['wall_plain_s'] - 1.0
            row['cpu_overhead'] = row['cpu_rec_s'] / row['cpu_plain_s'] - 1.0
            log(f"pair {i}: wall {row['wall_plain_s']:.3f} s plain, {row['wall_rec_s']:.3f} s "
                f"recorded ({100 * row['wall_overhead']:+.1f} %); cpu {row['cpu_plain_s']:.3f} / "
                f"{row['cpu_rec_s']:.3f} s ({100 * row['cpu_overhead']:+.1f} %); recording alone "
                f"{row['wall_rec_only_s']:.3f} s wall, {row['cpu_rec_only_s']:.3f} s cpu "
                f"({row['main_cpu_rec_only_s']:.3f} s in the main thread); "
                f"{row['rrd_bytes'] / 1e6:.2f} MB; others "
                + ('?' if row['others_cores'] is None else
                   f"{row['others_cores']:.2f} cores, steal {row['steal_cores']:.2f} cores"))
            rows.append(row)
    return rows


def median_interval(values, level=0.9, resamples=2000, seed=0):
    """(low, high): the central ``level`` interval of the median of ``values`` over bootstrap
    resamples (pairs drawn with replacement; a fixed seed, so a run reports one interval). It
    shows how far the median of this many pairs may move by chance; pairs measured within the
    same minute share the host's phase, so runs at other times may spread wider."""
    import numpy as np
    v = np.asarray(values, dtype=float)
    draws = np.random.default_rng(seed).choice(v, size=(resamples, len(v)))
    lo, hi = np.quantile(np.median(draws, axis=1), [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)


def import_cost(repeats=3):
    """Medians over ``repeats`` fresh processes that have already set up a simulation: (seconds
    to import the recorder and rerun-sdk; seconds of a first, 3-frame recording in that process).
    What a process pays once, besides the run's own cost; the second figure shows the first-use
    costs the warm benchmark above does not see."""
    code = '\n'.join([
        'import gc, tempfile, time',
        'from solver.build.scene import Scene',
        'from solver.simulate.array import simulation_for',
        "sim = simulation_for(Scene.load('config/scenes/fb_column.yaml'))",
        'frames = []',
        'for _ in range(3):',
        '    frames.append(sim.frame())',
        '    sim.advance(0.005)',
        't0 = time.perf_counter()',
        'from tensegrity_ros.io.rerun_sink import RerunRecorder',
        't1 = time.perf_counter()',
        'gc.freeze()                       # as tensegrity run',
        'with tempfile.TemporaryDirectory() as tmp:',
        "    with RerunRecorder(sim.network, tmp + '/first.rrd') as rec:",
        '        for frame in frames:',
        '            rec.frame(frame)',
        '    t2 = time.perf_counter()',
        'print(t1 - t0, t2 - t1)'])
    runs = [[float(v) for v in subprocess.run(
        [sys.executable, '-c', code], check=True, capture_output=True, text=True,
        cwd=Path(__file__).resolve().parents[1]).stdout.split()] for _ in range(repeats)]
    return (statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs))


def main(out='bench/results', quick=False, log=print, scene='config/scenes/fb_column.yaml',
         repeats=None, t_end=None):
    """Run :func:`measure`, write ``rerun_overhead.csv`` into ``out``; returns the files
    written."""
    rows = measure(scene, repeats or (3 if quick else 30), log=log, t_end=t_end)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / ('rerun_overhead.csv' if t_end is None else f'rerun_overhead_t{t_end:g}.csv')
    with path.open('w', newline='') as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    wall = statistics.median(r['wall_overhead'] for r in rows)
    wall_lo, wall_hi = median_interval([r['wall_overhead'] for r in rows])
    cpu = statistics.median(r['cpu_overhead'] for r in rows)
    best_wall = min(r['wall_rec_s'] for r in rows) / min(r['wall_plain_s'] for r in rows) - 1
    best_cpu = min(r['cpu_rec_s'] for r in rows) / min(r['cpu_plain_s'] for r in rows) - 1
    alone_wall = min(r['wall_rec_only_s'] for r in rows) / min(r['wall_plain_s'] for r in rows)
    alone_cpu = min(r['cpu_rec_only_s'] for r in rows) / min(r['cpu_plain_s'] for r in rows)
    alone_main = min(r['main_cpu_rec_only_s'] for r in rows) / min(r['cpu_plain_s'] for r in rows)
    quiet = [r for r in rows if r['others_cores'] is not None
             and r['others_cores'] + r['steal_cores'] < QUIET_CORES]
    quiet_txt = f'; quiet pairs (others and steal < {QUIET_CORES:g} core): {len(quiet)}'
    if quiet:
        quiet_txt += (f', median wall '
                      f'{100 * statistics.median(r["wall_overhead"] for r in quiet):+.1f} %, cpu '
                      f'{100 * statistics.median(r["cpu_overhead"] for r in quiet):+.1f} %')
    busy = None
    if rows[0]['others_cores'] is not None:
        busy = (statistics.median(r['others_cores'] for r in rows),
                statistics.median(r['steal_cores'] for r in rows))
        if sum(busy) >= QUIET_CORES:
            log(f'HOST BUSY: other processes used {busy[0]:.2f} and the hypervisor took (steal) '
                f'{busy[1]:.2f} of a core during the median pair: Rerun\'s threads use the '
                f'second vCPU, so this figure shows the host, not the recording; measure '
                f'again when the machine is quiet')
    log(f'rerun recording overhead, median of {len(rows)} pairs: wall {100 * wall:+.1f} % '
        f'(90 % interval of the median {100 * wall_lo:+.1f} to {100 * wall_hi:+.1f} %), '
        f'cpu {100 * cpu:+.1f} %; best of each: wall {100 * best_wall:+.1f} %, cpu '
        f'{100 * best_cpu:+.1f} %; recording alone / plain run (best of each): wall '
        f'{100 * alone_wall:.1f} %, cpu {100 * alone_cpu:.1f} % (main thread '
        f'{100 * alone_main:.1f} %){quiet_txt}; load average {os.getloadavg()[0]:.2f}  -> {path}')
    imp, first = import_cost()
    plain = statistics.median(r['wall_plain_s'] for r in rows)
    log(f'once per process (median of 3 fresh processes): importing the recorder '
        f'{imp:.2f} s, {imp / plain:.1f}x the plain run; a first 3-frame recording '
        f'{1e3 * first:.1f} ms')
    summary = path.with_suffix('.json')
    summary.write_text(json.dumps({
        'pairs': len(rows), 'wall_overhead_median': wall,
        'wall_overhead_median_90': [wall_lo, wall_hi], 'cpu_overhead_median': cpu,
        'wall_overhead_best': best_wall, 'plain_wall_s_median': plain, 'import_s': imp,
        'first_recording_s': first, 'quiet_pairs': len(quiet),
        'others_cores_median': None if busy is None else busy[0],
        'steal_cores_median': None if busy is None else busy[1],
        'load_average': os.getloadavg()[0]}, indent=2) + '\n')
    return [str(path), str(summary)]


if __name__ == '__main__':
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--scene', default='config/scenes/fb_column.yaml')
    ap.add_argument('--repeats', type=int, default=30)
    ap.add_argument('--out', default='bench/results')
    ap.add_argument('--t-end', type=float, help='simulated seconds per run (default: the scene)')
    a = ap.parse_args()
    main(a.out, scene=a.scene, repeats=a.repeats, t_end=a.t_end)
    sys.exit(0)
