"""What the lane twins of the step control's full scans (:mod:`solver.kernels.lanesteps`) cost
per lane, against the scalar kernels called lane by lane on each lane's scalar-layout data (as
:func:`solver.integrators.rk4lanes.run` calls them).

    python -m bench.lanesteps [--lanes 32 64]

The lanes are the sym3d FB column (``config/scenes/fb_column.yaml``, bar contact on) at five
states: prestrains 0.002-0.01, impacts of 0.3, 1 and 2 m/s, advanced 0.02-0.06 s; lane l is
state l mod 5 drifted by ``1e-5 l v`` (so that lanes differ). Three costs per lane, each the
best of ``--repeats`` timed loops inside one compiled function (numba's dispatch not timed):
``next_kink`` for a step of ``dt`` (``next_kink_lanes``), ``step_energy``
(``step_energy_lanes``) and ``ledger_energy`` (``ledger_energy_lanes``). Prints a table in us
per lane per call; nothing is written.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from solver import Scene
from solver.compiled import jit, jit_lanes
from solver.kernels.lanedata import LaneState, lane_record
from solver.kernels import dynamics as dyn
from solver.kernels import lanesteps, records
from solver.kernels.effects import ledger_energy
from solver.kernels.kinks import next_kink
from solver.kernels.summary import step_energy
from solver.simulate.simulation import Simulation

ROOT = Path(__file__).resolve().parents[1]
STATES = [(0.002, 0.3, 1), (0.004, 1.0, 2), (0.006, 2.0, 3), (0.003, 1.0, 1), (0.01, 2.0, 2)]
DT = 6.25e-4


@jit
def _scalar_kinks(m, S, acc, h, ignore, out, n):
    for _ in range(n):
        for k in range(out.shape[0]):
            out[k] = next_kink(S.x[k], S.v[k], acc[k], m, lane_record(S, k), h, ignore)


@jit
def _scalar_energies(m, S, out, n, ledger):
    for _ in range(n):
        for k in range(out.shape[0]):
            d = lane_record(S, k)
            out[k] = ledger_energy(d.x, d.v, m, d) if ledger else step_energy(d.x, d.v, m, d)


@jit_lanes
def _lane_kinks(m, x, v, acc, rest, h, ignore, go, out, n):
    for _ in range(n):
        lanesteps.next_kink_lanes(x, v, acc, m, rest, h, ignore, go, out)


@jit_lanes
def _lane_energies(m, x, v, rest, EA, f_ext, scan, go, out, tmp, n, ledger):
    for _ in range(n):
        if ledger:
            lanesteps.ledger_energy_lanes(x, v, m, rest, EA, f_ext, scan, go, out, tmp)
        else:
            lanesteps.step_energy_lanes(x, v, m, rest, EA, f_ext, go, out, tmp)


def _states():
    scene = Scene.load(ROOT / 'config' / 'scenes' / 'fb_column.yaml')
    out = []
    for prestrain, v0, n in STATES:
        sim = Simulation(scene)
        sim.apply_prestrain(prestrain)
        sim.apply_impact(v0)
        for _ in range(n):
            sim.advance(0.02)
        d = records.clone_data(sim.model.data)
        acc = np.zeros_like(d.x)
        dyn.accelerations(d.x, d.v, sim.model.rec, records.clone_data(d),
                          records.clone_work(sim.model.work), acc)
        out.append((sim.model.rec, d, acc))
    return out


def _lanes(states, n_lanes):
    """The lane-outer LaneState and accelerations, and the lane-inner arrays."""
    picks = [(states[k % len(states)], 1e-5 * k) for k in range(n_lanes)]

    def outer(get):
        return np.ascontiguousarray(np.stack([get(s, tau) for s, tau in picks]))
    S = LaneState(outer(lambda s, t: s[1].x + t * s[1].v), outer(lambda s, t: s[1].v),
                  outer(lambda s, t: s[1].rest), outer(lambda s, t: s[1].EA),
                  outer(lambda s, t: s[1].f_ext), outer(lambda s, t: s[1].ledger),
                  outer(lambda s, t: s[1].contact.scan), outer(lambda s, t: s[1].contact.active),
                  outer(lambda s, t: s[1].refine), np.zeros((n_lanes, 2) + states[0][1].x.shape))
    acc = outer(lambda s, t: s[2])

    def inner(a):
        return np.ascontiguousarray(np.moveaxis(a, 0, -1))
    return S, acc, inner


def _best(call, n, repeats):
    call(1)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        call(n)
        best = min(best, time.perf_counter() - t0)
    return best / n


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--lanes', type=int, nargs='+', default=[32, 64])
    parser.add_argument('--repeats', type=int, default=7)
    parser.add_argument('--calls', type=int, default=200)
    args = parser.parse_args(argv)
    states = _states()
    m = states[0][0]
    print(f'{"B":>4} {"kernel":<14} {"scalar us/lane":>15} {"lanes us/lane":>14} {"ratio":>6}')
    for n_lanes in args.lanes:
        S, acc, inner = _lanes(states, n_lanes)
        x, v, a = inner(S.x), inner(S.v), inner(acc)
        rest, EA, f_ext = inner(S.rest), inner(S.EA), inner(S.f_ext)
        go = np.ones(n_lanes, np.int64)
        out = np.zeros(n_lanes)
        want = np.zeros(n_lanes)
        tmp = np.zeros((3, n_lanes))
        h = np.full(n_lanes, DT)
        n, r = args.calls, args.repeats
        rows = [('next_kink',
                 _best(lambda c: _scalar_kinks(m, S, acc, DT, 1e-3 * DT, want, c), n, r),
                 _best(lambda c: _lane_kinks(m, x, v, a, rest, h, 1e-3 * DT, go, out, c), n, r))]
        assert np.array_equal(out, want)
        for name, ledger in (('step_energy', False), ('ledger_energy', True)):
            rows.append((name, _best(lambda c: _scalar_energies(m, S, want, c, ledger), n, r),
                         _best(lambda c: _lane_energies(m, x, v, rest, EA, f_ext, S.scan, go,
                                                        out, tmp, c, ledger), n, r)))
            assert np.array_equal(out, want)
        for name, ts, tl in rows:
            print(f'{n_lanes:>4} {name:<14} {1e6 * ts / n_lanes:>15.3f} '
                  f'{1e6 * tl / n_lanes:>14.3f} {tl / ts:>6.2f}')


if __name__ == '__main__':
    main()
