"""What one instance costs when B instances of the FB column run as lanes, against one instance
run by the scalar kernels.

    python -m bench.lanes [--out bench/results]

The network is the paper's FB column as a ``full3d`` network without bar contact; lane l has its
rest lengths scaled by 1 - 1e-5 l and an impact on its top level. Two costs, each for B = 1, 8,
32, 64 and 128 lanes: one force-and-constraint evaluation (:func:`solver.kernels.lanes.
accelerations` against :func:`solver.kernels.dynamics.accelerations`) and one projected RK4 step
(:func:`solver.integrators.rk4lanes.rk4_projected_run` against the scalar ``rk4_projected``
kernel, no kinks). The calls repeat inside compiled loops, so numba's dispatch is not timed. The
ratio is the lanes' time per instance over the scalar time (below 1: the lanes are cheaper); each
lane measurement is paired with a scalar one just before it and the lowest ratio of three pairs is
reported.

Then whole runs of the FB column scene as users run it (``fb_column.yaml``: ``sym3d``, bar and
base contact, the ledger's refinement), B columns with different prestrains (0.02-0.08) stepped
as a :class:`~solver.simulate.lanebatch.LaneGroup` against the same B simulations stepped one at
a time, on one thread, in calls of 8 steps (the node's 200 Hz frames): at rest after the
prestrain (no contact) and after an impact of 0.3 m/s on every column (contact); then the array
of 64 columns (:class:`~solver.simulate.array.ArraySimulation`, one thread) with ``lanes`` True,
False and ``'auto'``. The figure is the wall time per column over one column's single run (the
issue's "per-column cost"). Last, the 1,024-point sweep of docs/sweeps.md on two threads, its
batches as lanes and one point at a time (:func:`sweep`; about 80 s). One run's ratios: on a
busy machine they are noisy.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from solver.build.scene import Scene
from solver.integrators import rk4lanes
from solver.integrators.rk4 import RK4Projected
from solver.kernels import dynamics as dyn

from .common import COLUMNS
from .flops import lane_evaluations, lane_state, network, scalar_evaluations, scalar_state

LANES = (1, 8, 32, 64, 128)
DT = 6.25e-4
TOL = 1e-12
MAX_ITER = 20
SECONDS = 0.15          # the length of one timed measurement


def _timed(call, unit_s):
    """Seconds per unit of ``call(n)`` (n units), with n chosen for :data:`SECONDS`."""
    n = max(1, int(SECONDS / unit_s))
    t0 = time.perf_counter()
    call(n)
    return (time.perf_counter() - t0) / n


def _measure(net, n_lanes, kind):
    """(scalar s, lanes s per instance) of one evaluation or one step, the pair of lowest
    ratio of three."""
    m, d, w = scalar_state(net)
    data, work = lane_state(net, n_lanes, d.v)
    topo = net.topology()
    out1 = np.zeros_like(d.x)
    out = np.zeros_like(data.x)
    status = np.zeros(n_lanes, np.int64)
    steps = np.zeros(n_lanes, np.int64)
    if kind == 'evaluation':
        def one(n):
            scalar_evaluations(m, d, w, out1, n)

        def many(n):
            lane_evaluations(topo, data, work, out, status, n)
    else:
        def one(n):
            RK4Projected.kernel(m, d, w, DT, n, TOL, MAX_ITER, False, True)

        def many(n):
            rk4lanes.rk4_projected_run(topo, data, work, DT, n, TOL, MAX_ITER, status, steps)
    one(1)                              # compile or load outside the timing
    many(1)
    t1 = _timed(one, 1e-5)
    tb = _timed(many, 1e-5 * n_lanes)
    pairs = []
    for _ in range(3):
        s = _timed(one, t1)
        b = _timed(many, tb) / n_lanes
        pairs.append((b / s, s, b))
    if not (status == dyn.OK).all():
        raise RuntimeError(f'lanes: a lane failed ({status})')
    ratio, s, b = min(pairs)
    return s, b, ratio


RUN_LANES = (8, 32, 64)
RUN_CALLS = 40           # calls of 8 steps (0.2 s of simulation) per run


def _runs_case(n_lanes, v0, calls=RUN_CALLS):
    """Wall time s of ``calls`` calls of 8 steps: B simulations as one lane group, the same B
    one at a time, and one simulation alone (the first of them), and whether the lanes ended
    equal to the single runs."""
    from solver.simulate import lanebatch
    from solver.simulate.simulation import Simulation
    scene = Scene.load(COLUMNS['FB'])

    def make():
        out = []
        for k in range(n_lanes):
            sim = Simulation(scene)
            sim.apply_prestrain(0.02 + 0.06 * k / max(n_lanes - 1, 1))
            if v0:
                sim.apply_impact(v0)
            out.append(sim)
        return out
    a, b = make(), make()
    group = lanebatch.LaneGroup(a)
    group.advance(8)                          # compile / load outside the timing
    for sim in b:
        sim.advance(8 * sim.dt)
    t0 = time.perf_counter()
    for _ in range(calls):
        group.advance(8)
    lanes_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(calls):
        for sim in b:
            sim.advance(8 * sim.dt)
    scalar_s = time.perf_counter() - t0
    same = all(np.array_equal(x.model.positions(), y.model.positions()) and
               x.steps_taken == y.steps_taken for x, y in zip(a, b))
    return lanes_s, scalar_s, same, sum(s.steps_taken for s in b)


def _array_case(n_columns, v0, calls=RUN_CALLS):
    """Wall time s of ``calls`` calls of 8 steps of an array of ``n_columns`` different
    columns on one thread, per ``lanes`` mode."""
    from solver.simulate.array import simulation_for
    scene = Scene.load(COLUMNS['FB']).with_overrides([('structure.n_columns', n_columns)])
    out = {}
    for mode in (False, True, 'auto'):
        sim = simulation_for(scene)
        sim.lanes, sim.threads = mode, 1
        p = np.linspace(0.02, 0.08, n_columns)[:, None] * np.ones((1, sim.network.n_prisms))
        sim.apply_prestrain(p)
        sim.apply_impact(v0)
        sim.advance(8 * sim.dt)
        t0 = time.perf_counter()
        for _ in range(calls):
            sim.advance(8 * sim.dt)
        out[str(mode)] = time.perf_counter() - t0
    return out


def runs(log=print):
    """The whole-run figures (see the module text)."""
    rows = []
    for n_lanes in RUN_LANES:
        for v0 in (0.0, 0.3):
            lanes_s, scalar_s, same, steps = _runs_case(n_lanes, v0)
            row = {'lanes': n_lanes, 'v0_m_s': v0, 'lanes_s': lanes_s, 'one_at_a_time_s': scalar_s,
                   'ratio': lanes_s / scalar_s, 'equal_bit_for_bit': same, 'steps': steps}
            rows.append(row)
            log(f"lanes: run B={n_lanes:3d} v0={v0:.1f}: lanes {lanes_s:.3f} s, one at a time "
                f"{scalar_s:.3f} s: per-column ratio {row['ratio']:.3f}, equal {same}")
    arr = _array_case(64, 0.3)
    log('lanes: array of 64 columns at 0.3 m/s, one thread: ' + ', '.join(
        f'lanes={k} {v:.3f} s' for k, v in arr.items()))
    return rows, arr


SWEEP_GRID = ('loading.impact.v0=0.05:0.2:16', 'prestrain=0.001:0.004:32',
              'structure.stacking=shared,parallel')


def sweep(log=print, threads=2):
    """The 1,024-point sweep of docs/sweeps.md (1 s runs) in this process on ``threads``
    threads, its batches stepped as lanes, then one point at a time: the wall times and whether
    the rows are equal (every figure, timings aside). A sweep of four short points in each way
    goes first, untimed: a kernel that numba loads or compiles on its first call does so there,
    not in the timed sweeps."""
    import tempfile
    from tensegrity_ros.studies import sweep as sw
    from tensegrity_ros.studies.table import TIMING_FIELDS
    out = {'grid': list(SWEEP_GRID), 't_end_s': 1.0, 'threads': threads}
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for lanes in (True, False):
            warm = sw.build(COLUMNS['FB'], ['loading.impact.v0=0.1,0.2', 'prestrain=0.001,0.002'],
                            out=Path(tmp) / f'warm_{lanes}', t_end=0.05)
            sw.execute(warm, threads=threads, lanes=lanes)
        for lanes in (True, False):
            sweep = sw.build(COLUMNS['FB'], list(SWEEP_GRID), out=Path(tmp) / str(lanes),
                             t_end=1.0)
            t0 = time.perf_counter()
            got, _ = sw.execute(sweep, threads=threads, lanes=lanes)
            key = 'lanes_s' if lanes else 'one_at_a_time_s'
            out[key] = time.perf_counter() - t0
            rows[lanes] = [{k: v for k, v in r.items() if k not in TIMING_FIELDS} for r in got]
            log(f'lanes: the 1,024-point sweep, {"lanes" if lanes else "one at a time"}: '
                f'{out[key]:.1f} s')
    out['points'] = len(rows[True])
    out['ok'] = sum(r['status'] == 'ok' for r in rows[True])
    out['rows_equal'] = json.dumps(rows[True], sort_keys=True, default=str) == json.dumps(
        rows[False], sort_keys=True, default=str)
    out['ratio'] = out['lanes_s'] / out['one_at_a_time_s']
    log(f"lanes: sweep ratio {out['ratio']:.2f}, rows equal {out['rows_equal']}")
    return out


def main(out_dir='bench/results', log=print):
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    net = network()
    load = [os.getloadavg()[0]]         # how busy the machine was (1-minute load average)
    rows = []
    for n_lanes in LANES:
        row = {'lanes': n_lanes}
        for kind in ('evaluation', 'step'):
            s, b, ratio = _measure(net, n_lanes, kind)
            row[f'{kind}_scalar_us'] = s * 1e6
            row[f'{kind}_lanes_us_per_instance'] = b * 1e6
            row[f'{kind}_ratio'] = ratio
            log(f'lanes: B={n_lanes:4d} {kind:10s}: scalar {s * 1e6:8.2f} us, lanes '
                f'{b * 1e6:8.2f} us per instance: ratio {ratio:.3f} ({1 / ratio:.2f}x)')
        rows.append(row)
    run_rows, array = runs(log)
    big = sweep(log)
    load.append(os.getloadavg()[0])
    log(f'lanes: load average {load[0]:.2f} at the start, {load[1]:.2f} at the end '
        f'({os.cpu_count()} CPUs)')
    path = out / 'lanes.json'
    path.write_text(json.dumps({'network': 'fb_column full3d, no bar contact',
                                'n_nodes': int(net.n_nodes), 'n_cables': int(net.n_cables),
                                'dt_s': DT, 'ratio': 'lanes time per instance / scalar time',
                                'load_average_start_end': load, 'cpus': os.cpu_count(),
                                'rows': rows, 'runs': run_rows,
                                'array_64_columns_one_thread_s': array,
                                'sweep_1024': big}, indent=2))
    return [str(path)]


if __name__ == '__main__':
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', default='bench/results')
    args = ap.parse_args()
    for p in main(args.out):
        print(p)
