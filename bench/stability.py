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

Two maps. The first (``stability.csv``, ``stability.png``, ``stability_limits.csv``) runs the
scenes as shipped, without contact: above 0.2-0.3 m/s every run, the reference included, ends in
a physical failure. The second (``stability_contact.csv``, ``stability_contact.png``) runs the
same grid with the prism stops of :mod:`solver.kernels.contact` (:data:`CONTACT`: ``contact.lock:
penalty`` at its documented stiffness 1e5 N/m and tolerance 0.05 h0) on a dt grid that starts
lower (:data:`CONTACT_DTS`, the stop is a stiff spring), for the methods that run stops
(``implicit_midpoint`` refuses them). ``stability_contact_limits.csv`` gives, per column,
prestrain, v0 and method, the largest stable, conserving (within the default limits) and
accurate dt of both maps side by side.

Stiff scenes (:data:`STIFF_SCENES`, one entry per scene: a column and its scene overrides): the
same classification for every method of :data:`STIFF_METHODS` that the scene admits
(``implicit_midpoint`` refuses strikers, stops and damping, :func:`stiff_methods`), on a finer dt
grid (:data:`STIFF_DTS`) at v0 = 0.1 m/s, written to ``stability_stiff.csv`` (with the mean step
actually taken: kink landing shortens the steps of ``rk4_projected``, ``rk4`` and
``dopri54_projected`` on the slack/taut switching of stiff cables) and, per scene and method, the
largest stable, conserving and accurate dt and the ratios to ``rk4_projected`` to
``stability_stiff_limits.csv``.

Cost: the no-contact map is 1470 runs and 42 references, the contact map 1512 and 42, the stiff
scenes 153 and 3. ``tensegrity bench --only stability`` (all three) takes about 7 min of one core
on a shared 2-core machine, ``--quick`` about 15 s; the grids are the full ones (no shrinking
was needed).
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
LOOSE = {'energy_error': 0.1, 'constraint_error': 1e-3}
DRIFT_ENERGY, DRIFT_CONSTRAINT = 1e-3, 1e-6
CLASSES = ('accurate', 'inaccurate', 'drifting', 'diverged')
SHORT = {'prism height': 'S', 'prism twist': 'L', 'energy balance': 'E', 'constraint error': 'C',
         'state': 'N', 'rigid members': 'R', 'constraint projection': 'P', 'step size': 'H'}


# the contact map: the scenes' own bar contact (solver/kernels/barcontact.py); the plain map
# has line bars (PLAIN)
CONTACT = ('contact.bars=hertz',)
CONTACT_LABEL = 'bar contact: contact.bars hertz, bars 0.2 mm thick (the default)'
PLAIN = ('contact.bars=none',)
CONTACT_METHODS = ('rk4_projected', 'rk4', 'rattle', 'dopri54_projected')  # implicit refuses it
CONTACT_DTS = (1.25e-4, 2.5e-4) + DTS
CONTACT_V0S = (0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 1.0, 2.0)

# stiff scenes: name -> (column, scene overrides); add a scene with one entry
STIFF_SCENES = {
    'RB, stiff-cable bases, kappa 1e4': ('RB', ('structure.rigid_bases_as=stiff_cables',
                                                 'structure.kappa=1e4')),
    'RB, stiff-cable bases, kappa 1e3': ('RB', ('structure.rigid_bases_as=stiff_cables',
                                                 'structure.kappa=1e3')),
    'RB, stiff-cable bases, kappa 1e3, striker 1e6 N/m': (
        'RB', ('structure.rigid_bases_as=stiff_cables', 'structure.kappa=1e3',
               'loading.impact.mode=striker', 'loading.impact.contact=linear',
               'loading.impact.contact_stiffness=1e6')),
}
STIFF_DTS = (2.5e-5, 5e-5, 1e-4, 2e-4, 4e-4, 8e-4, 1.6e-3, 3.2e-3, 6.4e-3)  # divide the output dt
STIFF_OUTPUT_DT = 6.4e-3
STIFF_METHODS = ('rk4_projected', 'rk4_projected (no kink landing)', 'rk4', 'rattle',
                 'dopri54_projected', 'implicit_midpoint')
# labels that are not method names: label -> (method, land on kinks)
VARIANTS = {'rk4_projected (no kink landing)': ('rk4_projected', False)}
# scene keys whose physics implicit_midpoint's step does not have (it refuses them)
NOT_IMPLICIT = ('loading.impact.mode=striker', 'contact.lock=penalty', 'materials.cable_damping')


def stiff_methods(over, methods=STIFF_METHODS):
    """The methods of ``methods`` that run a scene with overrides ``over``: without
    ``implicit_midpoint`` when the scene has a striker, prism stops or cable damping."""
    refused = any(o.replace(' ', '').startswith(key) and not o.endswith(('=0', '=0.0', '=none'))
                  for o in over for key in NOT_IMPLICIT)
    return tuple(m for m in methods if not (refused and VARIANTS.get(m, (m,))[0]
                                            == 'implicit_midpoint'))


def _grid(quick, contact=False):
    if quick:
        methods = ('rk4_projected', 'rattle', 'dopri54_projected')
        return methods, ((2.5e-4, 1e-3, 8e-3) if contact else (1e-3, 8e-3)), (0.1, 1.0), (0.002,)
    if contact:
        return CONTACT_METHODS, CONTACT_DTS, CONTACT_V0S, PRESTRAINS
    return METHODS, DTS, V0S, PRESTRAINS


def stiff_run(quick=False, log=print, v0=0.1):
    """The stiff scenes: every method of :data:`STIFF_METHODS` the scene admits
    (:func:`stiff_methods`) at every dt of :data:`STIFF_DTS` (quick: four of them, the first and
    the last scene, a quarter of the window), classified against a ``dopri54_projected``
    reference at rtol 1e-10. Returns rows."""
    model = common.available_models(('sym3d', 'full3d'))[0]
    t_end = T_END / 4 if quick else T_END
    scenes = list(STIFF_SCENES.items())
    scenes = [scenes[0], scenes[-1]] if quick else scenes
    dts = STIFF_DTS[1::2] if quick else STIFF_DTS
    rows = []
    for name, (column, over) in scenes:
        def sc(method, dt, rtol=None, atol=None, kinks=True):
            return common.scene(column, model, method, dt, STIFF_OUTPUT_DT, t_end, v0=v0,
                                rtol=rtol, atol=atol, kinks=kinks,
                                divergence=LOOSE).with_overrides(list(over))
        ref = common.record(sc('dopri54_projected', 1e-3, 1e-10, 1e-13))
        ref_state = 'ok' if not ref.diverged else f'diverged: {ref.quantity}'
        for label in stiff_methods(over):
            method, kinks = VARIANTS.get(label, (label, True))
            for dt in dts:
                rtol = 1e-6 if method == 'dopri54_projected' else None
                h = common.record(sc(method, dt, rtol, None if rtol is None else 1e-9, kinks))
                cls, err, drift, cerr = classify(h, ref)
                span = float(h.times[-1] - h.times[0])
                rows.append({'scene': name, 'column': column, 'model': model, 'method': label,
                             'dt': dt, 'v0': v0, 't_end': t_end, 'class': cls,
                             'quantity': h.quantity or '', 't_fail': h.t_fail,
                             'strain_error_rel': err, 'energy_drift_rel': drift,
                             'constraint_error': cerr, 'steps': h.steps,
                             'mean_step': (span / h.steps if h.steps and not h.diverged
                                           else float('nan')),
                             'evaluations': h.evaluations, 'wall_s': h.wall_s,
                             'reference': ref_state})
            log(f'stability (stiff): {name}: {label}: ' + ' '.join(
                f'{r["dt"]:g}:{r["class"][:3]}' for r in rows
                if (r['scene'], r['method']) == (name, label)))
    return rows


def stiff_limits(rows):
    """Per stiff scene and method: the largest dt below which no run diverged (stable), below
    which every run stayed within the default limits (conserving), and below which every run is
    accurate; the mean step taken at the largest stable dt; the stable and conserving dt as
    ratios to those of ``rk4_projected`` (NaN where either is missing)."""
    out = []
    for name in dict.fromkeys(r['scene'] for r in rows):
        sel = [dict(r, column=name, prestrain=0.002, v0=0.1) for r in rows if r['scene'] == name]
        lim = largest_steps(sel, name, v0s=(0.1,))
        base = lim.get('rk4_projected', {})
        for method, got in lim.items():
            at = [r for r in sel if r['method'] == method and r['dt'] == got['stable']]
            ratios = {}
            for key in ('stable', 'conserving'):
                b = base.get(key)
                ratios[key] = got[key] / b if got[key] and b else float('nan')
            out.append({'scene': name, 'method': method,
                        'largest_stable_dt': got['stable'] or '',
                        'largest_conserving_dt': got['conserving'] or '',
                        'largest_accurate_dt': got['accurate'] or '',
                        'mean_step_at_stable_dt': (at[0].get('mean_step', float('nan')) if at
                                                   else float('nan')),
                        'stable_dt_vs_rk4_projected': ratios['stable'],
                        'conserving_dt_vs_rk4_projected': ratios['conserving']})
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


def run(quick=False, log=print, contact=False):
    """The map of line bars (:data:`PLAIN`), or (``contact``) with the bar contact of the
    scenes (:data:`CONTACT`), on its own grid (:func:`_grid`). Returns rows; their ``contact``
    column names the setting."""
    methods, dts, v0s, prestrains = _grid(quick, contact)
    model = common.available_models(('sym3d', 'full3d'))[0]
    t_end = T_END / 2 if quick else T_END
    extra = list(CONTACT) if contact else list(PLAIN)
    label = CONTACT_LABEL if contact else 'none (line bars)'
    rows = []
    for column in common.COLUMNS:
        for p in prestrains:
            for v0 in v0s:
                ref = common.record(common.scene(column, model, 'dopri54_projected', 1e-3,
                                                 OUTPUT_DT, t_end, prestrain=p, v0=v0, rtol=1e-10,
                                                 atol=1e-13, divergence=LOOSE
                                                 ).with_overrides(extra))
                ref_state = 'ok' if not ref.diverged else f'diverged: {ref.quantity}'
                for method in methods:
                    for dt in dts:
                        rtol = 1e-6 if method == 'dopri54_projected' else None
                        h = common.record(common.scene(
                            column, model, method, dt, OUTPUT_DT, t_end, prestrain=p, v0=v0,
                            rtol=rtol, atol=None if rtol is None else 1e-9, divergence=LOOSE
                        ).with_overrides(extra))
                        cls, err, drift, cerr = classify(h, ref)
                        rows.append({'column': column, 'model': model, 'contact': label,
                                     'method': method, 'dt': dt, 'v0': v0, 'prestrain': p,
                                     't_end': t_end, 'class': cls, 'quantity': h.quantity or '',
                                     't_fail': h.t_fail, 'strain_error_rel': err,
                                     'energy_drift_rel': drift, 'constraint_error': cerr,
                                     'reference': ref_state})
                cells = [r for r in rows if (r['column'], r['prestrain'], r['v0']) ==
                         (column, p, v0)]
                log(f'stability{" (contact)" if contact else ""}: {column} p={p:g} v0={v0:g} '
                    f'(reference {ref_state}): '
                    + ' '.join(m + ' ' + ''.join(r['class'][:2] + ',' for r in cells
                                                 if r['method'] == m) for m in methods))
    return rows


def largest_steps(rows, column, prestrain=0.002, v0s=(0.1, 0.15)):
    """Per method: the largest dt of the grid below which no cell (v0 in ``v0s``) diverged
    (``stable``), below which every cell finished within the default limits, i.e. is accurate or
    inaccurate (``conserving``), and below which every cell is accurate (``accurate``); None
    where even the smallest dt fails. Returns {method: {'stable', 'conserving', 'accurate'}}."""
    tests = {'stable': lambda c: c != 'diverged',
             'conserving': lambda c: c in ('accurate', 'inaccurate'),
             'accurate': lambda c: c == 'accurate'}
    out = {}
    for method in sorted({r['method'] for r in rows}):
        sel = [r for r in rows if r['column'] == column and r['method'] == method
               and r['prestrain'] == prestrain and r['v0'] in v0s]
        got = dict.fromkeys(tests)
        still = dict.fromkeys(tests, True)
        for dt in sorted({r['dt'] for r in sel}):
            cells = [r['class'] for r in sel if r['dt'] == dt]
            for key, ok in tests.items():
                still[key] = still[key] and all(ok(c) for c in cells)
                got[key] = dt if still[key] else got[key]
        out[method] = got
    return out


def largest_stable(rows, column, prestrain=0.002, v0s=(0.1, 0.15)):
    """Per method: the largest dt of the grid below which no cell (v0 in ``v0s``) diverged, and the
    largest below which every cell is accurate. Returns {method: (stable_dt, accurate_dt)}."""
    return {m: (g['stable'], g['accurate'])
            for m, g in largest_steps(rows, column, prestrain, v0s).items()}


def contact_limits(maps):
    """``maps``: {contact label: rows}. Per column, prestrain, v0 and method, the largest stable,
    conserving and accurate dt of each map, one row per map (methods of the map only)."""
    out = []
    for label, rows in maps.items():
        for column in dict.fromkeys(r['column'] for r in rows):
            for p in sorted({r['prestrain'] for r in rows}):
                for v0 in sorted({r['v0'] for r in rows}):
                    ref = {r['reference'] for r in rows if (r['column'], r['prestrain'],
                                                            r['v0']) == (column, p, v0)}
                    for method, got in largest_steps(rows, column, p, (v0,)).items():
                        out.append({'column': column, 'prestrain': p, 'v0': v0,
                                    'contact': label, 'method': method,
                                    'largest_stable_dt': got['stable'] or '',
                                    'largest_conserving_dt': got['conserving'] or '',
                                    'largest_accurate_dt': got['accurate'] or '',
                                    'reference': ' / '.join(sorted(ref))})
    return out


def plot(rows, path, setting=None):
    """The map as one panel per method and (column, prestrain); ``setting`` names the contact
    setting in the title (None: without contact)."""
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
    fig.suptitle('Stability map, 50-prism columns (sym3d), '
                 + (f'with {setting}' if setting else 'without contact (contact.lock none)')
                 + f'\naccurate = strain history within {ACCURATE:g} of the peak strain; '
                 'diverged because: S prism collapsed (slack cables),\nL bars crossed '
                 '(rigid-base lock), E energy, C constraint error, P projection failed, '
                 'N non-finite', fontsize=9)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return str(path)


def main(out, quick=False, log=print):
    """Run both maps and the stiff scenes; write ``stability.csv``, ``stability_limits.csv``,
    ``stability.png`` (without contact), ``stability_contact.csv``, ``stability_contact.png``,
    ``stability_contact_limits.csv`` (with the prism stops, limits of both maps) and the files of
    :func:`stiff_main`; returns the paths."""
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
    written += contact_main(out, quick, log, rows)
    return written + stiff_main(out, quick, log)


def contact_main(out, quick=False, log=print, plain=None):
    """The map with the prism stops: ``stability_contact.csv``, ``stability_contact.png`` and
    ``stability_contact_limits.csv`` (with the rows of the map without contact, ``plain``, when
    given)."""
    out = Path(out)
    tag = '_quick' if quick else ''
    rows = run(quick, log, contact=True)
    maps = ({'none': plain} if plain else {}) | {CONTACT_LABEL: rows}
    limits = contact_limits(maps)
    for r in limits:
        if r['prestrain'] == 0.002 and r['v0'] >= 0.3:
            log(f'  {r["column"]} v0={r["v0"]:g} {r["contact"][:12]}: {r["method"]}: stable '
                f'{r["largest_stable_dt"]}, conserving {r["largest_conserving_dt"]}, accurate '
                f'{r["largest_accurate_dt"]} (reference {r["reference"]})')
    return [common.write_csv(out / f'stability_contact{tag}.csv', rows),
            common.write_csv(out / f'stability_contact_limits{tag}.csv', limits),
            plot(rows, out / f'stability_contact{tag}.png', setting=CONTACT_LABEL)]


def stiff_main(out, quick=False, log=print):
    """The stiff scenes only: ``stability_stiff.csv`` and ``stability_stiff_limits.csv``."""
    out = Path(out)
    tag = '_quick' if quick else ''
    rows = stiff_run(quick, log)
    limits = stiff_limits(rows)
    for r in limits:
        log(f'  {r["scene"]}: {r["method"]}: largest stable dt {r["largest_stable_dt"]} (mean '
            f'step {r["mean_step_at_stable_dt"]:.3g}), conserving {r["largest_conserving_dt"]}, '
            f'accurate {r["largest_accurate_dt"]}, x{r["stable_dt_vs_rk4_projected"]:.3g} '
            f'(conserving x{r["conserving_dt_vs_rk4_projected"]:.3g}) rk4_projected')
    return [common.write_csv(out / f'stability_stiff{tag}.csv', rows),
            common.write_csv(out / f'stability_stiff_limits{tag}.csv', limits)]
