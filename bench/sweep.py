"""Parallel efficiency of ``tensegrity sweep``: a 64-point sweep of 1 s runs of the flexible-base
column (v0 x prestrain, 8 x 8), once serially in this process and once on a 2-worker
``LocalCluster``, with the same task function (:func:`tensegrity_ros.studies.sweep.run_point`).

Efficiency = (serial wall time / cluster wall time) / workers. Where the rest goes: the cluster's
start (scheduler and worker processes, their imports), each worker's first task (numba cache
load; the serial side pays the same load once, in its untimed first point, reported as
``serial_first_point_s``), and the scheduling overhead per point (cluster wall time minus the
busiest worker's task time, per point). The cluster runs the points in batches
(:func:`tensegrity_ros.studies.sweep.chunks`). Written to ``sweep.json``.
"""
from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

from .common import COLUMNS

V0S = '0.06:0.13:8'
PRESTRAINS = '0.0015:0.0035:8'


def main(out, quick=False, log=print, workers=2):
    from tensegrity_ros.studies import sweep as sw
    grid = [f'loading.impact.v0={V0S}', f'prestrain={PRESTRAINS}']
    t_end = 1.0
    if quick:
        grid = ['loading.impact.v0=0.06:0.13:4', 'prestrain=0.0015:0.0035:2']
        t_end = 0.3
    out = Path(out)
    with tempfile.TemporaryDirectory() as tmp:
        serial = sw.build(COLUMNS['FB'], grid, out=Path(tmp) / 'serial', t_end=t_end)
        n = len(serial.points)
        log(f'sweep bench: {n} points of {t_end:g} s, serial')
        t0 = time.perf_counter()
        sw.run_point(serial.scene, serial.overrides(serial.points[0]))      # kernels warm
        first_point_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        rows_s, _ = sw.execute(serial)
        serial_s = time.perf_counter() - t0
        log(f'  serial {serial_s:.2f} s; {workers}-worker LocalCluster')
        t0 = time.perf_counter()
        cluster = sw.Cluster(workers=workers)
        t_start = time.perf_counter() - t0
        try:
            par = sw.build(COLUMNS['FB'], grid, out=Path(tmp) / 'cluster', t_end=t_end)
            t1 = time.perf_counter()
            batches = [len(b) for b in sw.chunks(par.points, cluster.n_workers)]
            rows_p, _ = sw.execute(par, cluster)
            run_s = time.perf_counter() - t1
        finally:
            t2 = time.perf_counter()
            cluster.close()
            t_close = time.perf_counter() - t2
    total_p = t_start + run_s + t_close
    task_s = sum(r['task_wall_s'] for r in rows_p)
    by_worker = {}
    first = {}
    for r in rows_p:
        by_worker[r['worker_pid']] = by_worker.get(r['worker_pid'], 0.0) + r['task_wall_s']
    for r in rows_p:                     # the slowest task of each worker: its first (cache load)
        first[r['worker_pid']] = max(first.get(r['worker_pid'], 0.0), r['task_wall_s'])
    serial_task = sum(r['task_wall_s'] for r in rows_s) / n
    first_extra = sum(max(0.0, v - serial_task) for v in first.values())
    busiest = max(by_worker.values())
    same = all({k: v for k, v in a.items() if k not in sw.TIMING_FIELDS}
               == {k: v for k, v in b.items() if k not in sw.TIMING_FIELDS}
               for a, b in zip(rows_s, rows_p))
    result = {
        'points': n, 't_end_s': t_end, 'workers': workers, 'scene': 'fb_column.yaml',
        'grid': grid,
        'serial_s': serial_s, 'cluster_total_s': total_p, 'cluster_run_s': run_s,
        'speedup': serial_s / total_p, 'efficiency': serial_s / total_p / workers,
        'efficiency_excluding_start': serial_s / run_s / workers,
        'cluster_start_s': t_start, 'cluster_close_s': t_close,
        'serial_first_point_s': first_point_s,
        'tasks': len(batches), 'points_per_task': batches,
        'serial_task_mean_s': serial_task, 'cluster_task_mean_s': task_s / n,
        'worker_first_task_extra_s': first_extra,
        'scheduling_overhead_per_task_s': max(0.0, run_s - busiest) / n,
        'tasks_per_worker': {str(k): sum(r['worker_pid'] == k for r in rows_p)
                             for k in by_worker},
        'rows_identical': same, 'quick': quick,
    }
    log(f"  cluster start {t_start:.2f} s, run {run_s:.2f} s, close {t_close:.2f} s; "
        f"speed-up {result['speedup']:.2f}, efficiency {result['efficiency']:.2f} "
        f"({result['efficiency_excluding_start']:.2f} without the cluster start)")
    path = out / ('sweep_quick.json' if quick else 'sweep.json')
    path.write_text(json.dumps(result, indent=2))
    return [str(path)]
