"""Compile every kernel into numba's on-disk cache before it is needed, on all cores.

A fresh install (or any edit of ``solver/``, which starts a fresh cache: :mod:`solver.compiled`)
compiles its kernels at their first call, one after the other, in whatever process calls them
first: a few minutes of one core. :func:`compile_all` instead runs short simulations that reach
every kernel the solver calls (each integrator's checked and run kernels, the chain model, the
frame's observables), split into groups that compile in parallel processes, then all of them in
one more process, which loads them from the cache and compiles whatever the parallel ones lost
(:func:`_sole_pass`); a later process loads them all. A marker in the cache folder records a
complete pass, so a second call returns at once.

    python -m solver.simulate.precompile          # or: tensegrity compile

A test run of several files calls it before its first test (``test/conftest.py``; with
pytest-xdist the main process, before its workers start).
"""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]       # the folder holding the solver package
MARKER = '.precompiled'

# Groups of integrators that compile in one process each, of about equal cost when compiled
# from nothing (measured with numba's compile events on this 2-core host): rk4 and
# rk4_projected are one kernel (about 70 s with the force, projection and contact kernels it
# calls), to which dopri54_projected adds its stages; rattle compiles those shared kernels
# again in its own process, implicit_midpoint its Newton solver, and 'lanes' the kernels over
# lanes (solver.simulate.lanebatch: about 50 s).
GROUPS = (('rattle', 'implicit_midpoint', 'chain1d', 'lanes'),
          ('rk4_projected', 'rk4', 'dopri54_projected'))


def _exercise(method):
    """Short runs that call every kernel ``method`` uses (``'chain1d'``: the chain model;
    ``'lanes'``: a lane group)."""
    from solver.build.scene import Scene
    from solver.simulate.simulation import Simulation

    # the scene schema's defaults are the paper's FB column (fb_column.yaml but for its dt): no
    # file needed, so an install compiles as a checkout does; the kernels' types do not depend
    # on the values. The checks stay out of the way: these runs are for the compiler.
    base = Scene({'name': 'precompile', 'divergence': {'energy_error': 1.0}})
    if method == 'lanes':                       # rk4_projected and rk4 over lanes
        from solver.simulate.lanebatch import LaneGroup
        pair = [Simulation(base), Simulation(base)]
        pair[1].apply_impact(0.1)
        LaneGroup(pair).advance(2)
        for s in pair:                          # and with prestrain ramps running
            s.apply_prestrain(0.0025, ramp_s=3 * s.dt)
        LaneGroup(pair, ramps=True).advance(2)
        trio = LaneGroup([Simulation(base) for _ in range(3)])      # stragglers' moves
        top, fewer = trio.blocks[0], trio.blocks[1]
        fewer.take(top, [0, 2])
        fewer.give(top, [0, 2])
        from solver.simulate.array import simulation_for
        arr = simulation_for(base.with_overrides([('structure.n_columns', 2)]))
        arr.lanes = True
        arr.apply_impact(0.1, columns=[1])      # two column simulations: a lane group
        arr.advance(2 * arr.dt)
        arr.frame()                             # its base forces, positions and tensions
        return
    if method == 'chain1d':
        scene = base.with_overrides([('model', 'chain1d'), ('contact.bars', 'none')])
    elif method == 'implicit_midpoint':           # it refuses bar contact
        scene = base.with_overrides([('integrator.method', method), ('contact.bars', 'none')])
    else:
        scene = base.with_overrides([('integrator.method', method)])
    sim = Simulation(scene)
    sim.apply_impact(0.1)
    sim.advance(2 * sim.dt)                     # the checked kernel (one compiled call)
    sim.frame()                                 # tensions, base force, heights
    if method != 'chain1d':
        sim.apply_prestrain(0.0021, ramp_s=2 * sim.dt)
        sim.advance(2 * sim.dt)                 # the ramped kernel (run kernel, one step a call)
        sim.frame()


def _marker():
    from solver.compiled import CACHE_DIR
    return Path(CACHE_DIR) / MARKER


def compile_all(processes=None, log=print, timeout_s=1200.0):
    """Compile every kernel into the cache, ``processes`` groups at a time (default: the
    cores, at most :data:`GROUPS`); returns the seconds spent (0.0 when the cache was complete).
    Raises ``RuntimeError`` naming each group that failed or gave no result within
    ``timeout_s`` seconds (its process is killed)."""
    marker = _marker()
    if marker.exists():
        return 0.0
    processes = max(1, min(processes or os.cpu_count() or 1, len(GROUPS)))
    t0 = time.perf_counter()
    log(f'compiling the solver kernels into {marker.parent} ({processes} processes; once per '
        'solver source) ...')
    pending = list(GROUPS)
    running = []
    failed = []
    while pending or running:
        while pending and len(running) < processes:
            group = pending.pop(0)
            proc = subprocess.Popen([sys.executable, '-m', 'solver.simulate.precompile', *group],
                                    cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                    text=True)
            running.append((group, proc))
        group, proc = running.pop(0)
        try:
            out, _ = proc.communicate(timeout=max(timeout_s - (time.perf_counter() - t0), 0.0))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            failed.append(f'{"/".join(group)}: no result after {timeout_s:g} s')
            continue
        if proc.returncode != 0:
            failed.append(f'{"/".join(group)}: {out.strip().splitlines()[-1] if out else "?"}')
    if failed:
        raise RuntimeError('precompile failed for ' + '; '.join(failed))
    again = _sole_pass(max(timeout_s - (time.perf_counter() - t0), 1.0))
    if again:
        log(f'compiled again in one process (lost by the parallel ones): {", ".join(again)}')
    marker.write_text(f'{time.time()}\n')
    spent = time.perf_counter() - t0
    log(f'compiled in {spent:.0f} s')
    return spent


def _sole_pass(timeout_s):
    """Every group once more in one process, which loads what the parallel ones cached and
    compiles what they lost; returns the names of the kernels it compiled. Numba keeps one
    index file per function, and two processes that compile the same function at once (a kernel
    every group calls) may each rewrite it from what they read before the other wrote: one of
    their entries goes, and a later process would compile that kernel again (about 3 s when
    nothing is lost)."""
    methods = [m for group in GROUPS for m in group]
    try:
        proc = subprocess.run([sys.executable, '-m', 'solver.simulate.precompile', '--count',
                               *methods], cwd=ROOT, capture_output=True, text=True,
                              timeout=timeout_s)
    except subprocess.TimeoutExpired:        # (run kills the process)
        raise RuntimeError(f'precompile failed: its last pass gave no result after '
                           f'{timeout_s:g} s') from None
    if proc.returncode != 0:
        tail = (proc.stdout + proc.stderr).strip().splitlines()
        raise RuntimeError(f'precompile failed in its last pass: {tail[-1] if tail else "?"}')
    return [n for n in proc.stdout.strip().split(',') if n]


def compiled_while(methods):
    """The names of the kernels numba compiles (rather than loads from the cache) while the
    short runs of ``methods`` (:func:`_exercise`) call them."""
    from numba.core import event
    names = []

    class Count(event.Listener):
        def on_start(self, ev):
            names.append(ev.data['dispatcher'].py_func.__name__)

        def on_end(self, ev):
            pass

    listener = Count()
    event.register('numba:compile', listener)
    try:
        for method in methods:
            _exercise(method)
    finally:
        event.unregister('numba:compile', listener)
    return names


def main(argv=None):
    args = sys.argv[1:] if argv is None else argv
    if args and args[0] == '--count':   # the last pass: the kernels compiled, comma-separated
        print(','.join(compiled_while(args[1:])))
        return 0
    if args:                            # a worker: compile these methods here
        for method in args:
            _exercise(method)
        return 0
    compile_all()
    return 0


if __name__ == '__main__':
    sys.exit(main())
