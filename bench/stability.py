"""Stability map: for each method, a grid of dt against impact velocity and prestrain.

Each cell is one run of the paper's column (FB or RB, 50 prisms, model ``sym3d``: exact for this
symmetric impact) over ``T_END`` s, recorded every ``OUTPUT_DT`` s, classified as

- ``diverged``: the run stopped with ``SimulationDiverged`` under LOOSE limits (energy growth
  10 %, constraint error 1e-3), i.e. it blew up or met a physical failure: a prism collapsed
  through itself (slack cables), a prism twisted through 180 deg (the rigid-base lock),
  non-finite values;
- ``drifting``: it finished, but its energy moved by more than 1e-3 (relative) or its constraint
  error exceeded 1e-6, the limits at which a default run stops;
- ``inaccurate``: conserved, but its strain history differs from the reference by more than
  ``ACCURATE`` (0.1 %) of the peak strain;
- ``accurate``: otherwise.

The reference of each (column, v0, prestrain) is ``dopri54_projected`` with rtol 1e-10
(dt <= 1e-3). Where the reference itself diverges (a physical failure) a run that finishes is
``inaccurate``. ``dopri54_projected`` is placed by its largest step dt (rtol 1e-6).

Stiff scenes (:data:`STIFF_SCENES`, one entry per scene: a column and its scene overrides): the
same classification for every method, ``implicit_midpoint`` included, on a finer dt grid
(:data:`STIFF_DTS`) at v0 = 0.1 m/s, written to ``stability_stiff.csv`` and, per scene and method,
the largest stable and accurate dt to ``stability_stiff_limits.csv``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from . import common

METHODS = ('rk4_projected', 'rk4', 'rattle', 'dopri54_projected', 'implicit_midpoint')
DTS = (5e-4, 1e-3, 2e-3, 4e-3, 8e-3, 1.6e-2, 3.2e-2)    # all divide OUTPUT_DT
V0S = (0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 1.0)
PRESTRAINS = (0.0005, 0.002, 0.01)
OUTPUT_DT = 3.2e-2
T_END = 0.32
ACCURATE = 1e-3
LOOSE = {'energy_growth': 0.1, 'constraint_error': 1e-3}
DRIFT_ENERGY, DRIFT_CONSTRAINT = 1e-3, 1e-6
CLASSES = ('accurate', 'inaccurate', 'drifting', 'diverged')
SHORT = {'prism height': 'S', 'prism twist': 'L', 'energy': 'E', 'constraint error': 'C',
         'state': 'N', 'rigid members': 'R', 'constraint projection': 'P', 'step size': 'H'}


# stiff scenes: name -> (column, scene overrides); add a scene with one entry
STIFF_SCENES = {
    'RB, stiff-cable bases, kappa 1e4': ('RB', ('structure.rigid_bases_as=stiff_cables',
                                                 'structure.kappa=1e4')),
    'RB, stiff-cable bases, kappa 1e3': ('RB', ('structure.rigid_bases_as=stiff_cables',
                                                 'structure.kappa=1e3')),
}
STIFF_DTS = (1e-4, 2e-4, 4e-4, 8e-4, 1.6e-3, 3.2e-3, 6.4e-3)   # all divide STIFF_OUTPUT_DT
STIFF_OUTPUT_DT = 6.4e-3
STIFF_METHODS = ('rk4_projected', 'rk4', 'rattle', 'dopri54_projected', 'implicit_midpoint')


def _grid(quick):
    if quick:
        return ('rk4_projected', 'rattle', 'dopri54_projected'), (1e-3, 8e-3), (0.1, 1.0), (0.002,)
    return METHODS, DTS, V0S, PRESTRAINS


def stiff_run(quick=False, log=print, v0=0.1):
    """The stiff scenes: every method of :data:`STIFF_METHODS` at every dt of
    :data:`STIFF_DTS` (quick: three of them, one scene), classified against a
    ``dopri54_projected`` reference at rtol 1e-10. Returns rows."""
    model = common.available_models(('sym3d', 'full3d'))[0]
    t_end = T_END / 4 if quick else T_END
    scenes = list(STIFF_SCENES.items())[:1] if quick else list(STIFF_SCENES.items())
    dts = STIFF_DTS[1::2] if quick else STIFF_DTS
    rows = []
    for name, (column, over) in scenes:
        def sc(method, dt, rtol=None, atol=None):
            return common.scene(column, model, method, dt, STIFF_OUTPUT_DT, t_end, v0=v0,
                                rtol=rtol, atol=atol, divergence=LOOSE).with_overrides(list(over))
        ref = common.record(sc('dopri54_projected', 1e-3, 1e-10, 1e-13))
        ref_state = 'ok' if not ref.diverged else f'diverged: {ref.quantity}'
        for method in STIFF_METHODS:
            for dt in dts:
                rtol = 1e-6 if method == 'dopri54_projected' else None
                h = common.record(sc(method, dt, rtol, None if rtol is None else 1e-9))
                cls, err, drift, cerr = classify(h, ref)
                rows.append({'scene': name, 'column': column, 'model': model, 'method': method,
                             'dt': dt, 'v0': v0, 't_end': t_end, 'class': cls,
                             'quantity': h.quantity or '', 't_fail': h.t_fail,
                             'strain_error_rel': err, 'energy_drift_rel': drift,
                             'constraint_error': cerr, 'steps': h.steps,
                             'evaluations': h.evaluations, 'wall_s': h.wall_s,
                             'reference': ref_state})
            log(f'stability (stiff): {name}: {method}: ' + ' '.join(
                f'{r["dt"]:g}:{r["class"][:3]}' for r in rows
                if (r['scene'], r['method']) == (name, method)))
    return rows


def stiff_limits(rows):
    """Per stiff scene and method: the largest dt below which no run diverged, the largest
    below which every run is accurate, and the stable-step ratio to ``rk4_projected``."""
    out = []
    for name in dict.fromkeys(r['scene'] for r in rows):
        sel = [dict(r, column=name, prestrain=0.002, v0=0.1) for r in rows if r['scene'] == name]
        lim = largest_stable(sel, name, v0s=(0.1,))
        base = lim.get('rk4_projected', (None, None))[0]
        for method, (stable, accurate) in lim.items():
            out.append({'scene': name, 'method': method,
                        'largest_stable_dt': stable if stable else '',
                        'largest_accurate_dt': accurate if accurate else '',
                        'stable_dt_vs_rk4_projected': (stable / base if stable and base
                                                       else float('nan'))})
    return out


def classify(hist, ref):
    """(class, strain error, energy drift, max constraint error) of a run against its reference."""
    if hist.diverged:
        return 'diverged', float('nan'), float('nan'), float('nan')
    drift = common.energy_drift(hist)
    cerr = float(np.max(hist.constraint_error))
    if not (drift <= DRIFT_ENERGY and cerr <= DRIFT_CONSTRAINT):
        err = common.strain_error(hist, ref) if not ref.diverged else float('nan')
        return 'drifting', err, drift, cerr
    if ref.diverged:
        return 'inaccurate', float('nan'), drift, cerr
    err = common.strain_error(hist, ref)
    return ('accurate' if err <= ACCURATE else 'inaccurate'), err, drift, cerr


def run(quick=False, log=print):
    methods, dts, v0s, prestrains = _grid(quick)
    model = common.available_models(('sym3d', 'full3d'))[0]
    t_end = T_END / 2 if quick else T_END
    rows = []
    for column in common.COLUMNS:
        for p in prestrains:
            for v0 in v0s:
                ref = common.record(common.scene(column, model, 'dopri54_projected', 1e-3,
                                                 OUTPUT_DT, t_end, prestrain=p, v0=v0, rtol=1e-10,
                                                 atol=1e-13, divergence=LOOSE))
                ref_state = 'ok' if not ref.diverged else f'diverged: {ref.quantity}'
                for method in methods:
                    for dt in dts:
                        rtol = 1e-6 if method == 'dopri54_projected' else None
                        h = common.record(common.scene(
                            column, model, method, dt, OUTPUT_DT, t_end, prestrain=p, v0=v0,
                            rtol=rtol, atol=None if rtol is None else 1e-9, divergence=LOOSE))
                        cls, err, drift, cerr = classify(h, ref)
                        rows.append({'column': column, 'model': model, 'method': method,
                                     'dt': dt, 'v0': v0, 'prestrain': p, 't_end': t_end,
                                     'class': cls, 'quantity': h.quantity or '',
                                     't_fail': h.t_fail, 'strain_error_rel': err,
                                     'energy_drift_rel': drift, 'constraint_error': cerr,
                                     'reference': ref_state})
                cells = [r for r in rows if (r['column'], r['prestrain'], r['v0']) ==
                         (column, p, v0)]
                log(f'stability: {column} p={p:g} v0={v0:g} (reference {ref_state}): '
                    + ' '.join(m + ' ' + ''.join(r['class'][:2] + ',' for r in cells
                                                 if r['method'] == m) for m in methods))
    return rows


def largest_stable(rows, column, prestrain=0.002, v0s=(0.1, 0.15)):
    """Per method: the largest dt of the grid below which no cell (v0 in ``v0s``) diverged, and the
    largest below which every cell is accurate. Returns {method: (stable_dt, accurate_dt)}."""
    out = {}
    for method in sorted({r['method'] for r in rows}):
        sel = [r for r in rows if r['column'] == column and r['method'] == method
               and r['prestrain'] == prestrain and r['v0'] in v0s]
        stable = accurate = None
        still_stable = still_accurate = True
        for dt in sorted({r['dt'] for r in sel}):
            cells = [r for r in sel if r['dt'] == dt]
            still_stable = still_stable and all(c['class'] != 'diverged' for c in cells)
            still_accurate = still_accurate and all(c['class'] == 'accurate' for c in cells)
            stable = dt if still_stable else stable
            accurate = dt if still_accurate else accurate
        out[method] = (stable, accurate)
    return out


def plot(rows, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    methods = [m for m in METHODS if any(r['method'] == m for r in rows)]
    panels = sorted({(r['column'], r['prestrain']) for r in rows})
    dts = sorted({r['dt'] for r in rows})
    v0s = sorted({r['v0'] for r in rows})
    cmap = ListedColormap(['#4caf50', '#ffc107', '#ff7043', '#b71c1c'])
    fig, axes = plt.subplots(len(methods), len(panels), squeeze=False,
                             figsize=(2.6 * len(panels) + 1.5, 2.3 * len(methods) + 1.2),
                             constrained_layout=True)
    for i, method in enumerate(methods):
        for j, (column, p) in enumerate(panels):
            ax = axes[i, j]
            grid = np.full((len(v0s), len(dts)), np.nan)
            for r in rows:
                if (r['method'], r['column'], r['prestrain']) != (method, column, p):
                    continue
                a, b = v0s.index(r['v0']), dts.index(r['dt'])
                grid[a, b] = CLASSES.index(r['class'])
                if r['class'] == 'diverged':
                    ax.text(b, a, SHORT.get(r['quantity'], '?'), ha='center', va='center',
                            fontsize=7, color='white')
            ax.imshow(grid, cmap=cmap, vmin=-0.5, vmax=3.5, origin='lower', aspect='auto')
            ax.set_xticks(range(len(dts)), [f'{d * 1e3:g}' for d in dts], fontsize=7)
            ax.set_yticks(range(len(v0s)), [f'{v:g}' for v in v0s], fontsize=7)
            if i == 0:
                ax.set_title(f'{column}, prestrain {p:g}', fontsize=9)
            if j == 0:
                ax.set_ylabel(f'{method}\nv0, m/s', fontsize=8)
            if i == len(methods) - 1:
                ax.set_xlabel('dt, ms', fontsize=8)
    handles = [plt.Rectangle((0, 0), 1, 1, color=cmap(k)) for k in range(4)]
    fig.legend(handles, CLASSES, loc='outside lower center', ncol=4, fontsize=8)
    fig.suptitle('Stability map, 50-prism columns (sym3d), accurate = strain history within '
                 f'{ACCURATE:g} of the peak strain\ndiverged because: S prism collapsed (slack '
                 'cables), L bars crossed (rigid-base lock),\nE energy, C constraint error, '
                 'P projection failed, N non-finite', fontsize=9)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return str(path)


def main(out, quick=False, log=print):
    """Run, write ``stability.csv``, ``stability_limits.csv`` and ``stability.png``; returns the
    paths."""
    out = Path(out)
    tag = '_quick' if quick else ''
    rows = run(quick, log)
    limits = []
    for column in common.COLUMNS:
        for method, (stable, accurate) in largest_stable(rows, column).items():
            limits.append({'column': column, 'prestrain': 0.002, 'v0': '0.1 and 0.15',
                           'method': method, 'largest_stable_dt': stable if stable else '',
                           'largest_accurate_dt': accurate if accurate else ''})
            log(f'  {column}: {method}: largest stable dt {stable}, largest accurate dt '
                f'{accurate} (grid {sorted({r["dt"] for r in rows})})')
    written = [common.write_csv(out / f'stability{tag}.csv', rows),
               common.write_csv(out / f'stability_limits{tag}.csv', limits),
               plot(rows, out / f'stability{tag}.png')]
    return written + stiff_main(out, quick, log)


def stiff_main(out, quick=False, log=print):
    """The stiff scenes only: ``stability_stiff.csv`` and ``stability_stiff_limits.csv``."""
    out = Path(out)
    tag = '_quick' if quick else ''
    rows = stiff_run(quick, log)
    limits = stiff_limits(rows)
    for r in limits:
        log(f'  {r["scene"]}: {r["method"]}: largest stable dt {r["largest_stable_dt"]}, '
            f'accurate {r["largest_accurate_dt"]}, x{r["stable_dt_vs_rk4_projected"]:.3g} '
            'rk4_projected')
    return [common.write_csv(out / f'stability_stiff{tag}.csv', rows),
            common.write_csv(out / f'stability_stiff_limits{tag}.csv', limits)]
