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
reported. One run's ratios: on a busy machine they are noisy.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from solver.build import structures
from solver.build.scene import Scene
from solver.compiled import jit, jit_lanes
from solver.integrators import rk4lanes
from solver.integrators.rk4 import RK4Projected
from solver.kernels import dynamics as dyn
from solver.kernels import lanes, records

from .common import COLUMNS

LANES = (1, 8, 32, 64, 128)
DT = 6.25e-4
TOL = 1e-12
MAX_ITER = 20
SECONDS = 0.15          # the length of one timed measurement


@jit
def _scalar_evaluations(m, d, w, out, n):
    for _ in range(n):
        dyn.accelerations(d.x, d.v, m, d, w, out)


@jit_lanes
def _lane_evaluations(topo, data, work, out, status, n):
    for _ in range(n):
        lanes.accelerations(data.x, data.v, topo, data, work, out, status)


def _network():
    scene = Scene.load(COLUMNS['FB']).with_overrides([('model', 'full3d'),
                                                      ('contact.bars', 'none')])
    return structures.build_network(scene)


def _scalar(net):
    m, d, w = records.plain(net)
    d.v[net.levels[0, -1], 2] = -0.1
    dyn.project_velocities(d.x, d.v, m.topo, w)
    return m, d, w


def _lanes(net, n_lanes, v):
    data = lanes.lane_data([net.x0] * n_lanes, [v] * n_lanes,
                           [net.cable_rest_length * (1.0 - 1e-5 * k) for k in range(n_lanes)],
                           [net.cable_EA] * n_lanes,
                           [np.zeros((net.n_nodes, 3))] * n_lanes)
    return data, lanes.lane_work(net.topology(), net.n_nodes, n_lanes)


def _timed(call, unit_s):
    """Seconds per unit of ``call(n)`` (n units), with n chosen for :data:`SECONDS`."""
    n = max(1, int(SECONDS / unit_s))
    t0 = time.perf_counter()
    call(n)
    return (time.perf_counter() - t0) / n


def _measure(net, n_lanes, kind):
    """(scalar s, lanes s per instance) of one evaluation or one step, the pair of lowest
    ratio of three."""
    m, d, w = _scalar(net)
    data, work = _lanes(net, n_lanes, d.v)
    topo = net.topology()
    out1 = np.zeros_like(d.x)
    out = np.zeros_like(data.x)
    status = np.zeros(n_lanes, np.int64)
    steps = np.zeros(n_lanes, np.int64)
    if kind == 'evaluation':
        def one(n):
            _scalar_evaluations(m, d, w, out1, n)

        def many(n):
            _lane_evaluations(topo, data, work, out, status, n)
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


def main(out_dir='bench/results', log=print):
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    net = _network()
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
    load.append(os.getloadavg()[0])
    log(f'lanes: load average {load[0]:.2f} at the start, {load[1]:.2f} at the end '
        f'({os.cpu_count()} CPUs)')
    path = out / 'lanes.json'
    path.write_text(json.dumps({'network': 'fb_column full3d, no bar contact',
                                'n_nodes': int(net.n_nodes), 'n_cables': int(net.n_cables),
                                'dt_s': DT, 'ratio': 'lanes time per instance / scalar time',
                                'load_average_start_end': load, 'cpus': os.cpu_count(),
                                'rows': rows}, indent=2))
    return [str(path)]


if __name__ == '__main__':
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', default='bench/results')
    args = ap.parse_args()
    for p in main(args.out):
        print(p)
