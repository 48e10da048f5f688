"""What an array of columns costs per column, against one column's symmetric run.

    python -m bench.array [--quick] [--out bench/results]      (or: tensegrity bench --only array)

Runs the paper's FB column (``fb_column.yaml``, ``model: auto``: ``sym3d``) hit at its free end,
then arrays of the same column: 25 columns with a different prestrain each (nothing can be
shared: one reduced simulation per column), 25 alike columns (one simulation shared), 100
columns with different prestrains, and the 25-column array as one ``full3d`` network (what
``model: full3d`` costs). The wall time is that of the ``advance`` calls only, the fastest of a
few repeats; the figure is the cost per column over the single column's. One run's ratios: on a
busy machine they are noisy.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from solver.build.scene import Scene
from solver.simulate.array import simulation_for

from .common import COLUMNS, write_csv


def _scene(n_columns, model='auto', t_end=1.2):
    return Scene.load(COLUMNS['FB']).with_overrides(
        [f'structure.n_columns={n_columns}', f'model={model}', f'run.t_end={t_end}'])


def _run(scene, prestrain=None):
    """Wall time s of the advance calls of one run from the impact to ``run.t_end``, and the
    simulation (its model name, how many column simulations ran)."""
    sim = simulation_for(scene)
    sim.advance(sim.dt)          # compile / load the kernels outside the timing
    sim.reset()
    if prestrain is not None:
        sim.apply_prestrain(prestrain)
    sim.apply_impact(scene['loading.impact.v0'])
    out_dt = scene['run.output_dt']
    wall = 0.0
    for _ in range(int(round(scene['run.t_end'] / out_dt))):
        t0 = time.perf_counter()
        sim.advance(out_dt)
        wall += time.perf_counter() - t0
    return wall, sim


def main(out_dir='bench/results', quick=False, log=print):
    """Each case runs ``repeats`` times, each time right after a run of the single column: the
    ratio of a pair sees the same load of the machine; the lowest ratio of the pairs is
    reported (and the median)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_end = 0.3 if quick else 1.2
    repeats = 2 if quick else 3
    single = _scene(1, t_end=t_end)
    cases = [('25 columns, different prestrains', 25, 'auto', True),
             ('25 alike columns (shared)', 25, 'auto', False),
             ('100 columns, different prestrains', 100, 'auto', True),
             ('25 columns as one full3d network', 25, 'full3d', True)]
    rows = []
    for name, n, model, graded in cases:
        if quick and n == 100:
            continue
        p = np.linspace(0.0015, 0.0035, n) if graded else None
        ratios, walls, ones = [], [], []
        for _ in range(1 if model == 'full3d' else repeats):
            one, sim1 = _run(single)
            wall, sim = _run(_scene(n, model, t_end), prestrain=p)
            ones.append(one)
            walls.append(wall)
            ratios.append(wall / n / one)
        k = int(np.argmin(ratios))
        rows.append(dict(case=name, n_columns=n, model=sim.model.name,
                         simulated=getattr(sim, 'n_simulated', 1), one_column_s=ones[k],
                         wall_s=walls[k], per_column_s=walls[k] / n,
                         ratio_per_column=ratios[k],
                         ratio_median=float(np.median(ratios)), pairs=len(ratios)))
        log(f'array: {name} ({sim.model.name}): {walls[k]:.3f} s against one column '
            f'({sim1.model.name}) {ones[k]:.3f} s: {ratios[k]:.3f}x per column (median '
            f'{np.median(ratios):.3f}x of {len(ratios)})')
    csv_path = write_csv(out / 'array.csv', rows)
    json_path = out / 'array.json'
    json_path.write_text(json.dumps({'t_end_s': t_end, 'quick': quick, 'rows': rows}, indent=2))
    return [csv_path, str(json_path)]


if __name__ == '__main__':
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--quick', action='store_true', help='0.3 s runs, no 100-column array')
    ap.add_argument('--out', default='bench/results')
    args = ap.parse_args()
    for path in main(args.out, quick=args.quick):
        print(path)
