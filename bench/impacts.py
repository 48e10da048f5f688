"""Single impacts from 0.3 to 2 m/s on the default columns, with the steps after a contact
refined against the energy ledger (``contact.refine: ledger``, the default) and without
(``none``); docs/physics.md section 7.1.

    python -m bench.impacts [--quick] [--out bench/results]    # tensegrity bench --only impacts

Writes ``impacts.json``: per scene and mode every point (v0, status, the stop's message,
energy balance error, contacts met, steps, CPU seconds of its thread) and a summary (points
stopped, largest and median balance error; for ``ledger`` the median ratio of steps and the ratio
of CPU time to ``none`` over the points both finish), and ``impacts.png``, the balance error
against v0. The points run on every core (CPU time is per thread: a point's own cost)."""
from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from bench.common import short_e
from solver.build.scene import Scene
from solver.simulate.parallel import each
from solver.simulate.runner import simulate
from solver.simulate.simulation import SimulationDiverged

ROOT = Path(__file__).resolve().parents[1]
SCENES = ('fb_column', 'rb_column')
MODES = ('ledger', 'none')
V0 = (0.3, 2.0, 35)             # from, to, how many (np.linspace)
T_END = 1.0


def point(name, mode, v0):
    """One impact of ``v0`` m/s on ``name`` for ``T_END`` s with ``contact.refine`` ``mode``."""
    scene = Scene.load(ROOT / 'config' / 'scenes' / f'{name}.yaml')
    sets = [f'loading.impact.v0={v0!r}', f'run.t_end={T_END}', f'contact.refine={mode}']
    c0 = time.thread_time()
    row = {'scene': name, 'mode': mode, 'v0': v0}
    try:
        s = simulate(scene, sets).summary
        row.update(status='ok', reason='', energy_balance_error=s.energy_balance_error,
                   contacts_met=s.contacts_met, steps_taken=s.steps_taken)
    except SimulationDiverged as exc:
        row.update(status='diverged', reason=str(exc), energy_balance_error=None,
                   contacts_met=None, steps_taken=None)
    row['cpu_s'] = time.thread_time() - c0
    return row


def summarize(rows, limit):
    """The summary of one scene's rows of both modes (see the module's text)."""
    out = {}
    by = {m: {r['v0']: r for r in rows if r['mode'] == m} for m in MODES}
    for m in MODES:
        ok = [r for r in by[m].values() if r['status'] == 'ok']
        errs = [abs(r['energy_balance_error']) for r in ok]
        out[m] = {'points': len(by[m]), 'stopped': len(by[m]) - len(ok),
                  'stopped_v0': sorted(v for v, r in by[m].items() if r['status'] != 'ok'),
                  'balance_error_max': max(errs) if errs else None,
                  'balance_error_median': statistics.median(errs) if errs else None,
                  'limit': limit}
    both = [v for v in by['ledger'] if by['ledger'][v]['status'] == 'ok'
            and by['none'].get(v, {}).get('status') == 'ok']
    if both:
        out['ledger']['steps_ratio_median'] = statistics.median(
            by['ledger'][v]['steps_taken'] / by['none'][v]['steps_taken'] for v in both)
        out['ledger']['cpu_ratio'] = (sum(by['ledger'][v]['cpu_s'] for v in both)
                                      / sum(by['none'][v]['cpu_s'] for v in both))
    return out


def table(result):
    """The lines of docs/physics.md's table of ``impacts.json`` (section 7.1)."""
    rows = ['| scene | `contact.refine` | stopped at the ledger | largest / median balance error '
            '| steps (median), CPU against `none` |', '|---|---|---|---|---|']
    for name in SCENES:
        for mode in MODES:
            m = result['summary'][name][mode]
            stop = f"{m['stopped']} of {m['points']}"
            if m['stopped']:
                stop += f" ({', '.join(f'{v:.3g}' for v in m['stopped_v0'])} m/s)"
            cost = (f"x{m['steps_ratio_median']:.2f}, x{m['cpu_ratio']:.2f}" if 'cpu_ratio' in m
                    else '')
            rows.append(f"| `{name}` | `{mode}` | {stop} | {short_e(m['balance_error_max'])} / "
                        f"{short_e(m['balance_error_median'])} | {cost} |")
    return rows


def plot(rows, limit, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(SCENES), figsize=(10, 3.8), sharey=True)
    for ax, name in zip(axes, SCENES):
        for mode, color in zip(MODES, ('tab:blue', 'tab:red')):
            rs = [r for r in rows if r['scene'] == name and r['mode'] == mode]
            ok = [r for r in rs if r['status'] == 'ok']
            ax.semilogy([r['v0'] for r in ok], [max(abs(r['energy_balance_error']), 1e-12)
                                                for r in ok], 'o-', ms=3, color=color,
                        label=f'contact.refine: {mode}')
            stop = [r['v0'] for r in rs if r['status'] != 'ok']
            if stop:
                ax.plot(stop, [limit] * len(stop), 'x', color=color, ms=8,
                        label=f'{mode}: stopped at the ledger')
        ax.axhline(limit, color='k', lw=0.8, ls='--', label='divergence.energy_error')
        ax.set_title(f'{name}, one impact, {T_END:g} s')
        ax.set_xlabel('impact velocity v0, m/s')
    axes[0].set_ylabel('largest |energy balance error| of the run')
    axes[0].legend(fontsize=7, loc='lower right')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(out='bench/results', quick=False, log=print):
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    lo, hi, n = V0
    v0s = [float(v) for v in np.linspace(lo, hi, 5 if quick else n)]
    todo = [(name, mode, v) for name in SCENES for mode in MODES for v in v0s]
    for name in SCENES:             # compile or load the kernels before anything is timed
        simulate(Scene.load(ROOT / 'config' / 'scenes' / f'{name}.yaml'),
                 ['loading.impact.v0=1.0', 'run.t_end=0.05'])
    t0 = time.perf_counter()
    rows = []
    for ok, value in each(lambda args: point(*args), todo):
        if not ok:
            raise value
        rows.append(value)
    limit = Scene.load(ROOT / 'config' / 'scenes' / 'fb_column.yaml').divergence.energy_error
    result = {'v0': v0s, 't_end_s': T_END, 'quick': quick, 'rows': rows,
              'summary': {name: summarize([r for r in rows if r['scene'] == name], limit)
                          for name in SCENES},
              'bench_wall_s': time.perf_counter() - t0}
    (out / 'impacts.json').write_text(json.dumps(result, indent=2))
    plot(rows, limit, out / 'impacts.png')
    for name, s in result['summary'].items():
        for mode in MODES:
            m = s[mode]
            extra = (f", steps x{m['steps_ratio_median']:.2f} (median), CPU x{m['cpu_ratio']:.2f}"
                     if 'cpu_ratio' in m else '')
            log(f"{name} refine={mode}: {m['stopped']} of {m['points']} stopped "
                f"{m['stopped_v0']}, balance error max {m['balance_error_max']:.2e}, median "
                f"{m['balance_error_median']:.2e}{extra}")
    return [str(out / 'impacts.json'), str(out / 'impacts.png')]


if __name__ == '__main__':
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--quick', action='store_true', help='5 velocities instead of 35')
    p.add_argument('--out', default='bench/results')
    a = p.parse_args()
    main(a.out, quick=a.quick)
