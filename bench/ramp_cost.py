"""What a step of a prestrain ramp costs beside a plain step, on arrays of distinct columns.

    python -m bench.ramp_cost [--columns 1,10,30] [--steps 64] [--modes single,lanes,auto]

For each N of ``--columns`` the FB column scene (``config/scenes/fb_column.yaml``) with
``structure.n_columns`` = N (one column: a plain
:class:`~solver.simulate.simulation.Simulation`; more: an
:class:`~solver.simulate.array.ArraySimulation` on one thread, for each way of ``--modes`` it
steps: one column simulation at a time, lanes, ``auto``) gets N different prestrains
(``np.linspace(0.02, 0.08, N)``, at once) and steps from rest in frames of 5 ms (8 steps of
the scene's ``dt``): ``--steps`` steps plain, then, on a fresh copy, ``--steps`` steps of a
0.2 s ramp to the reversed prestrains, and again with the ramp's steps set in Python, one
integrator call a step (``Loading._ramp_record`` None: the path of an integrator without a
ramped twin); each after 8 warm-up steps. Printed per N and way: the wall time per column per
step of each, and the ratios to plain stepping (one run, all three in it; the figures move with
the machine's load).
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

FB = 'config/scenes/fb_column.yaml'
FRAME_S = 0.005
RAMP_S = 0.2
MODES = {'single': False, 'lanes': True, 'auto': 'auto'}


def build(n, lanes):
    """The array of ``n`` FB columns with distinct prestrains, and those prestrains."""
    from solver.build.scene import Scene
    from solver.simulate.array import simulation_for
    sim = simulation_for(Scene.load(FB).with_overrides([f'structure.n_columns={n}']))
    if n > 1:
        sim.threads, sim.lanes = 1, lanes
    p = np.linspace(0.02, 0.08, n)
    sim.apply_prestrain(p if n > 1 else p[0], ramp_s=0.0)
    return sim, p


def per_step(sim, steps):
    """Wall seconds per step of ``steps`` steps (whole frames)."""
    k = int(round(FRAME_S / sim.dt))
    t0 = time.perf_counter()
    done = 0
    while done < steps:
        sim.advance(k * sim.dt)
        done += k
    return (time.perf_counter() - t0) / done


def measure(n, lanes, steps):
    """``(plain, ramp, ramp set in Python)`` wall seconds per column per step."""
    from solver.simulate.loading import Loading
    sim, p = build(n, lanes)
    per_step(sim, 8)
    out = [per_step(sim, steps) / n]
    record = Loading._ramp_record
    for python in (False, True):
        sim, p = build(n, lanes)
        sim.apply_prestrain(p[::-1] if n > 1 else 0.05, ramp_s=RAMP_S)
        if python:
            Loading._ramp_record = lambda self: None
        try:
            per_step(sim, 8)
            out.append(per_step(sim, steps) / n)
        finally:
            Loading._ramp_record = record
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(prog='python -m bench.ramp_cost', description=__doc__.split(
        '\n\n')[0])
    ap.add_argument('--columns', default='1,10,30', help='numbers of columns, comma separated')
    ap.add_argument('--steps', type=int, default=64, help='steps measured of each')
    ap.add_argument('--modes', default='single,lanes,auto',
                    help='ways the arrays step: single, lanes, auto (comma separated)')
    args = ap.parse_args(argv)
    print(f'load average {os.getloadavg()[0]:.2f} (1 min) on {os.cpu_count()} cores')
    print('us per column per step:')
    print('   N  way      plain    ramp  (x plain)  ramp in Python  (x plain)')
    for n in [int(c) for c in args.columns.split(',')]:
        for name in (args.modes.split(',') if n > 1 else ['single']):
            plain, ramp, slow = measure(n, MODES[name], args.steps)
            print(f'{n:4d}  {name:7s} {1e6 * plain:6.1f}  {1e6 * ramp:6.1f}  {ramp / plain:8.2f}  '
                  f'{1e6 * slow:14.1f}  {slow / plain:8.2f}', flush=True)
    print(f'load average {os.getloadavg()[0]:.2f} (1 min) at the end')


if __name__ == '__main__':
    main()
