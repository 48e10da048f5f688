"""What a sweep costs: 256 points of 1 s runs of the flexible-base column (v0 x prestrain,
16 x 16), run four ways with the same rows:

- ``serial``: one :func:`tensegrity_ros.studies.sweep.run_point` (a single ``tensegrity run``)
  after the other in this process: the reference;
- ``batched_1``: the batched runner (:func:`solver.simulate.batch.simulate_batch`, through
  ``sweep.execute``) on one thread;
- ``batched_threads``: the batched runner on ``workers`` threads in this process (what
  ``tensegrity sweep`` does by default);
- ``cluster``: a ``workers``-process ``LocalCluster``, one Dask task per batch, each batch on one
  thread, cluster start and close included.

The first three run interleaved: in each of :data:`ROUNDS` rounds a share of the points (every
``ROUNDS``-th, spanning the grid) runs all three ways, in an order that rotates from round to
round, so that the host's speed drifting over the minute weighs on all three alike (on this
shared host two back-to-back runs gave 0.64x and 0.77x for the same code). Ratios are of wall
times against the serial sweep (per point for ``batched_1``). Where the rest
goes: ``set-up`` (scenes, simulations, shared reductions: the part of each point outside the
threads), ``busy`` (a point's steps, records and summary on its thread: the summed busy time over
the wall time and the threads is the threads' use), and for the cluster its start, close and the
first task of each worker (the numba cache load). Written to ``sweep.json``.
"""
from __future__ import annotations

import dataclasses
import json
import tempfile
import time
from pathlib import Path

from .common import COLUMNS

ROUNDS = 6                   # interleaved rounds of the serial and batched runs (see main)
V0S = '0.06:0.13:16'
PRESTRAINS = '0.0015:0.0035:16'


def _timed(sw, sweep, **kw):
    t0 = time.perf_counter()
    rows, _ = sw.execute(sweep, **kw)
    return time.perf_counter() - t0, rows


def _busy(rows):
    return sum(r['task_wall_s'] for r in rows)


def main(out, quick=False, log=print, workers=2):
    from solver import compile_all
    from tensegrity_ros.studies import sweep as sw
    from tensegrity_ros.studies.table import TIMING_FIELDS
    compile_all(log=log)      # every kernel cached: the cluster's workers load, not compile
    grid = [f'loading.impact.v0={V0S}', f'prestrain={PRESTRAINS}']
    t_end = 1.0
    if quick:
        grid = ['loading.impact.v0=0.06:0.13:4', 'prestrain=0.0015:0.0035:4']
        t_end = 0.3
    out = Path(out)
    res = {'scene': 'fb_column.yaml', 'grid': grid, 't_end_s': t_end, 'workers': workers,
           'quick': quick}
    with tempfile.TemporaryDirectory() as tmp:
        def build(name):
            return sw.build(COLUMNS['FB'], grid, out=Path(tmp) / name, t_end=t_end)

        serial = build('serial')
        n = res['points'] = len(serial.points)
        log(f'sweep bench: {n} points of {t_end:g} s')
        t0 = time.perf_counter()
        sw.run_point(serial.scene, serial.overrides(serial.points[0]))      # kernels warm
        res['serial_first_point_s'] = time.perf_counter() - t0
        sw.run_points(serial.scene, [(None, serial.overrides(serial.points[0]))], threads=1)
        # the three in-process runs interleaved: ROUNDS rounds, each a share of the points
        # (every ROUNDS-th, so each share spans the grid) run all three ways in a rotating order,
        # so that a drift of the host's speed over the minute weighs on all three alike
        kinds = (('serial', {'task': sw.run_point}), ('batched_1', {'threads': 1}),
                 ('batched_threads', {'threads': workers}))
        times = {k: 0.0 for k, _ in kinds}
        rows = {k: [None] * n for k, _ in kinds}
        for r in range(ROUNDS):
            idx = list(range(r, n, ROUNDS))
            for kind, kw in kinds[r % 3:] + kinds[:r % 3]:
                sub = dataclasses.replace(serial, points=[serial.points[i] for i in idx],
                                          out_dir=Path(tmp) / f'{kind}_{r}')
                t, got = _timed(sw, sub, **kw)
                times[kind] += t
                for i, row in zip(idx, got):
                    rows[kind][i] = row
        rows_s, rows_1, rows_t = rows['serial'], rows['batched_1'], rows['batched_threads']
        res['rounds'] = ROUNDS
        res['serial_s'] = times['serial']
        log(f"  serial single runs {res['serial_s']:.2f} s ({res['serial_s'] / n * 1e3:.1f} ms "
            'a point)')
        res['batched_1_s'] = times['batched_1']
        res['batched_1_ratio_per_point'] = res['batched_1_s'] / res['serial_s']
        log(f"  batched, 1 thread {res['batched_1_s']:.2f} s: "
            f"{res['batched_1_ratio_per_point']:.3f}x a single run per point")
        res['batched_threads_s'] = times['batched_threads']
        res['batched_threads_ratio'] = res['batched_threads_s'] / res['serial_s']
        log(f"  batched, {workers} threads {res['batched_threads_s']:.2f} s: "
            f"{res['batched_threads_ratio']:.3f}x serial")
        t0 = time.perf_counter()
        cluster = sw.Cluster(workers=workers, dashboard=None)
        res['cluster_start_s'] = time.perf_counter() - t0
        try:
            par = build('cluster')
            res['cluster_run_s'], rows_c = _timed(sw, par, cluster=cluster)
        finally:
            t0 = time.perf_counter()
            cluster.close()
            res['cluster_close_s'] = time.perf_counter() - t0
    res['cluster_total_s'] = res['cluster_start_s'] + res['cluster_run_s'] + res['cluster_close_s']
    res['cluster_ratio'] = res['cluster_total_s'] / res['serial_s']
    res['efficiency'] = res['serial_s'] / res['cluster_total_s'] / workers
    res['efficiency_excluding_start'] = res['serial_s'] / res['cluster_run_s'] / workers
    log(f"  {workers}-worker LocalCluster: start {res['cluster_start_s']:.2f} s, run "
        f"{res['cluster_run_s']:.2f} s, close {res['cluster_close_s']:.2f} s: "
        f"{res['cluster_ratio']:.3f}x serial")
    best = min(('batched_threads', res['batched_threads_s']), ('cluster', res['cluster_total_s']),
               key=lambda kv: kv[1])
    res['two_core_best'] = best[0]
    res['two_core_ratio'] = best[1] / res['serial_s']
    # where the time goes
    # per point: the stepping (advance calls, the summary's wall_time_s) and the rest of the
    # point's own time (set-up, records, pulses and summary)
    res['serial_point_mean_s'] = _busy(rows_s) / n
    res['serial_stepping_mean_s'] = sum(r['wall_time_s'] for r in rows_s) / n
    res['serial_other_mean_s'] = res['serial_point_mean_s'] - res['serial_stepping_mean_s']
    res['batched_1_point_busy_mean_s'] = _busy(rows_1) / n
    res['batched_1_stepping_mean_s'] = sum(r['wall_time_s'] for r in rows_1) / n
    res['batched_1_other_mean_s'] = (res['batched_1_point_busy_mean_s']
                                     - res['batched_1_stepping_mean_s'])
    res['batched_1_outside_points_s'] = res['batched_1_s'] - _busy(rows_1)
    res['batched_threads_busy_sum_s'] = _busy(rows_t)
    res['batched_threads_use'] = _busy(rows_t) / (res['batched_threads_s'] * workers)
    res['batched_threads_stepping_sum_s'] = sum(r['wall_time_s'] for r in rows_t)
    by_worker, first = {}, {}
    for r in rows_c:
        by_worker[r['worker_pid']] = by_worker.get(r['worker_pid'], 0.0) + r['task_wall_s']
        first[r['worker_pid']] = max(first.get(r['worker_pid'], 0.0), r['task_wall_s'])
    res['cluster_busiest_worker_s'] = max(by_worker.values())
    res['cluster_idle_s'] = res['cluster_run_s'] - res['cluster_busiest_worker_s']
    res['points_per_worker'] = {str(k): sum(r['worker_pid'] == k for r in rows_c)
                                for k in by_worker}
    res['batches'] = [len(b) for b in sw.batches(
        list(range(n)), workers, [sw.point_cost(serial.scene.with_overrides(
            list(serial.overrides(p).items()))) for p in serial.points], [()] * n)]

    def same(a, b):
        return all({k: v for k, v in x.items() if k not in TIMING_FIELDS}
                   == {k: v for k, v in y.items() if k not in TIMING_FIELDS}
                   for x, y in zip(a, b))
    res['rows_identical'] = same(rows_s, rows_1) and same(rows_s, rows_t) and same(rows_s, rows_c)
    log(f"  best on {workers} cores: {best[0]}, {res['two_core_ratio']:.3f}x serial; rows "
        f"identical: {res['rows_identical']}")
    path = out / ('sweep_quick.json' if quick else 'sweep.json')
    path.write_text(json.dumps(res, indent=2))
    return [str(path)]
