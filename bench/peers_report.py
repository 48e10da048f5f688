"""Checks, environment, JSON assembly, CSV, PNG and the text table of ``bench --peers``."""
from __future__ import annotations

import csv
import ctypes
import glob
import math
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np

from solver import json_safe

TARGETS = {'speedup_vs_mujoco': 10.0, 'speedup_vs_scipy': 50.0, 'step_over_kernel_bound': 1.2,
           'real_time_factor_fb': 200.0}


def single_thread_blas():
    """Limit NumPy's OpenBLAS to one thread (every peer runs on one core); True if done."""
    import numpy
    libs = glob.glob(os.path.join(os.path.dirname(numpy.__file__) + '.libs', '*openblas*.so*'))
    for path in libs:
        lib = ctypes.CDLL(path)
        for name in ('scipy_openblas_set_num_threads64_', 'openblas_set_num_threads64_',
                     'openblas_set_num_threads'):
            if hasattr(lib, name):
                getattr(lib, name)(1)
                return True
    return False


def machine_and_versions(root):
    import numba
    import scipy
    try:
        import mujoco
        mj = mujoco.__version__
    except ImportError:
        mj = None
    cpu = platform.processor()
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                cpu = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    try:
        rev = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=root, text=True,
                             capture_output=True, timeout=10).stdout.strip() or None
        dirty = bool(subprocess.run(['git', 'status', '--porcelain', 'solver'], cwd=root,
                                    text=True, capture_output=True, timeout=10).stdout.strip())
    except (OSError, subprocess.SubprocessError):
        rev, dirty = None, None
    machine = {'cpu': cpu, 'cores': os.cpu_count(), 'platform': platform.platform(),
               'load_average_start': list(os.getloadavg())}
    versions = {'python': sys.version.split()[0], 'numpy': np.__version__,
                'numba': numba.__version__, 'scipy': scipy.__version__, 'mujoco': mj,
                'tensegrity_ros_git': rev, 'solver_has_uncommitted_changes': dirty}
    return machine, versions


def json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f'not JSON serialisable: {type(o).__name__}')


def mujoco_check(network, v_ours, dt, v0, rest_time=0.05):
    """Is the MuJoCo column the same physics? At rest before the impact (node accelerations at
    t = 0, drift over ``rest_time`` s without impact) and the same impulse (node velocities right
    after the impact against the solver's ``v_ours`` (n_nodes, 3) m/s)."""
    from .peers_mujoco import MujocoColumn
    mc = MujocoColumn(network, dt)
    acc = mc.node_accelerations()
    mc.advance(int(round(rest_time / dt)))
    drift = float(np.max(np.abs(mc.positions() - np.asarray(network.x0))))
    mc.reset()
    mc.impact(v0)
    dv = float(np.max(np.abs(mc.node_velocities() - v_ours)))
    return {'rest_max_node_acceleration_m_s2': float(np.max(np.abs(acc))),
            'rest_drift_m': drift, 'rest_time_s': rest_time,
            'impact_velocity_max_diff_m_s': dv,
            'impact_velocity_max_m_s': float(np.max(np.abs(v_ours))),
            'at_rest': bool(np.max(np.abs(acc)) < 1e-10 and drift < 1e-12),
            'nv': int(mc.model.nv), 'n_bodies': int(mc.model.nbody - 1),
            'n_tendons': int(mc.model.ntendon)}


def _rel(a, b):
    if a is None or b is None or not (math.isfinite(a) and math.isfinite(b)) or b == 0:
        return None
    return abs(a - b) / abs(b)


def _peer(r, t_end, pulse_fn, times, h0, pulse_ref):
    if r is None:
        return None
    out = {'knob': r['knob'], 'value': r['value'], 'strain_error': r['error'],
           'met_target': bool(r.get('met', True)), 'cpu_s': r['cpu_s'], 'wall_s': r['wall_s'],
           'real_time_factor': t_end / r['cpu_s'] if r['cpu_s'] else None,
           'real_time_factor_wall': t_end / r['wall_s'] if r['wall_s'] else None,
           'steps': r.get('steps'), 'evaluations': r.get('evaluations'),
           'cpus_s': r.get('cpus_s', [r['cpu_s']]), 'search_cpu_s': r.get('search_cpu_s')}
    if r.get('eps') is not None:
        p = pulse_fn(r['eps'], times[:len(r['eps'])], h0)
        out['pulse'] = p
        out['pulse_amplitude_rel_diff'] = _rel(p['amplitude'], pulse_ref['amplitude'])
        out['pulse_speed_rel_diff'] = _rel(p['speed_m_s'], pulse_ref['speed_m_s'])
    return out


def assemble(*, target, t_end, quick, ref_n, halving, pulse_ref, ours, ours_all, mj, sp, kernel,
             times, h0, machine, versions, blas1, pulse_fn, output_dt, v0, prestrain, bar_tol):
    peer = dict(t_end=t_end, pulse_fn=pulse_fn, times=times, h0=h0, pulse_ref=pulse_ref)
    res = {
        'scene': 'config/scenes/fb_column.yaml', 'prestrain': prestrain, 'v0_m_s': v0,
        't_end_s': t_end, 'quick': quick, 'target_strain_error': target,
        'error_metric': (f'max over output times (every {output_dt * 1e3:g} ms) and prisms of '
                         '|eps - eps_ref| (absolute axial strain)'),
        'reference': {'model': 'full3d', 'integrator': 'rk4_projected', 'dt': output_dt / ref_n,
                      'halving_strain_change': halving, 'pulse': pulse_ref},
        'ours': None, 'ours_candidates': [], 'mujoco': None, 'scipy': None, 'kernel': kernel,
        'ours_rule': (f'fastest configuration meeting the target whose rigid members hold to '
                      f'{bar_tol:g} (relative constraint error at the end of the run)'),
    }
    if ours is not None:
        res['ours'] = dict(_peer(ours, **peer), configuration=ours['config'],
                           constraint_error_end=ours.get('constraint_error_end'))
        res['ours_candidates'] = [{'configuration': c['config'], 'knob': c['knob'],
                                   'value': c['value'], 'strain_error': c['error'],
                                   'cpu_s': c['cpu_s'], 'wall_s': c['wall_s'],
                                   'steps': c['steps'],
                                   'constraint_error_end': c.get('constraint_error_end')}
                                  for c in ours_all]
    if mj is not None:
        res['mujoco'] = dict(_peer(mj, **peer), model='kinematic tree (ball joints) + '
                             'tendons springlength="0 L", RK4', check=mj.get('check'))
        c = res['mujoco']
        amp, speed = c.get('pulse_amplitude_rel_diff'), c.get('pulse_speed_rel_diff')
        c['same_physics'] = bool(c['check'] and c['check']['at_rest'] and amp is not None
                                 and speed is not None and amp < 0.02 and speed < 0.02)
    if sp is not None:
        res['scipy'] = dict(_peer(sp, **peer), method='solve_ivp DOP853, atol = 1e-3 rtol, '
                            'dense NumPy KKT per evaluation', blas_single_thread=blas1)
    same = [c for c in ours_all if c['model'] == 'full3d'
            and c['constraint_error_end'] <= bar_tol]
    if same and res['ours'] and res['mujoco']:
        res['full3d_only'] = {
            'configuration': same[0]['config'], 'cpu_s': same[0]['cpu_s'],
            'strain_error': same[0]['error'],
            'speedup_vs_mujoco': res['mujoco']['cpu_s'] / same[0]['cpu_s'],
            'speedup_vs_scipy': (res['scipy']['cpu_s'] / same[0]['cpu_s']) if res['scipy']
            else None, 'real_time_factor': t_end / same[0]['cpu_s']}
    w = res['ours']['cpu_s'] if res['ours'] else None
    res['speedup_vs_mujoco'] = (res['mujoco']['cpu_s'] / w) if w and res['mujoco'] else None
    res['speedup_vs_scipy'] = (res['scipy']['cpu_s'] / w) if w and res['scipy'] else None
    ww = res['ours']['wall_s'] if res['ours'] else None
    res['speedup_vs_mujoco_wall'] = (res['mujoco']['wall_s'] / ww) if ww and res['mujoco'] \
        else None
    res['speedup_vs_scipy_wall'] = (res['scipy']['wall_s'] / ww) if ww and res['scipy'] \
        else None
    res['timing'] = ('CPU time of the timing thread (time.thread_time) for the ratios and '
                     'real-time factors, wall time alongside. Final timing interleaved: ours, '
                     'MuJoCo, ours, MuJoCo, ours, MuJoCo, ours, SciPy, ours; medians (SciPy: its '
                     'one run). The configuration of ours was picked among the 3 fastest '
                     'candidates re-timed round-robin (median of 7). NumPy BLAS on one thread')
    res['step_over_kernel_bound'] = kernel['step_over_kernel_bound'] if kernel else None
    res['real_time_factor_fb'] = t_end / w if w else None
    res['real_time_factor_fb_wall'] = t_end / ww if ww else None
    if w and kernel and res['ours'].get('steps'):
        res['real_time_factor_fb_integrator_only'] = t_end / (
            kernel['integrator_only_time_per_step_s'] * res['ours']['steps'])
    if kernel:
        per = kernel['time_per_step_s']
        parts = {k: kernel[k] * (kernel['evaluations_per_step'] if k == 'accelerations' else 1)
                 for k in kernel['parts_in_step']}
        alone = kernel.get('integrator_only_time_per_step_s', per)
        parts['integrator arithmetic (stage sums, checks)'] = alone - sum(parts.values())
        parts['Simulation.advance bookkeeping (Python, guards)'] = per - alone
        kernel['profile_s_per_step'] = parts
        kernel['profile_fraction_of_step'] = {k: v / per for k, v in parts.items()}
    met = {}
    for key, goal in TARGETS.items():
        val = res[key]
        met[key] = None if val is None else bool(val <= goal if key == 'step_over_kernel_bound'
                                                  else val >= goal)
    res['targets'] = dict(TARGETS, met=met)
    res['machine'] = machine
    res['versions'] = versions
    return json_safe(res)      # NaN and infinities as None: JSON has neither


def write_csv(rows, path):
    keys = ['peer', 'configuration', 'knob', 'value', 'strain_error', 'completed', 't_end_s',
            'cpu_s', 'wall_s', 'steps', 'real_time_factor']
    with open(path, 'w', newline='') as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: ('' if r.get(k) is None else r.get(k)) for k in keys})


def plot(rows, res, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    colours = {'ours': 'tab:blue', 'mujoco': 'tab:red', 'scipy': 'tab:green'}
    for peer, col in colours.items():
        pts = [(r['cpu_s'], r['strain_error']) for r in rows
               if r['peer'] == peer and r['completed'] and r['cpu_s']]
        if pts:
            wall, err = zip(*pts)
            a1.loglog(wall, err, 'o', color=col, label=peer, alpha=0.8)
    a1.axhline(res['target_strain_error'], color='k', ls='--', lw=0.8, label='target')
    a1.set_xlabel(f'CPU time for {res["t_end_s"]:g} s simulated (s)')
    a1.set_ylabel('max |strain - reference|')
    a1.set_title('work-precision, FB column (completed runs)')
    a1.legend(fontsize=8)
    names, walls = [], []
    for key, label in (('ours', 'ours'), ('mujoco', 'MuJoCo'), ('scipy', 'SciPy DOP853')):
        if res.get(key):
            names.append(label)
            walls.append(res[key]['cpu_s'])
    k = res.get('kernel')
    if k and res.get('ours') and res['ours'].get('steps'):
        names.append('kernel bound')
        walls.append(k['kernel_bound_step'] * res['ours']['steps'])
    a2.barh(names, walls, color=['tab:blue', 'tab:red', 'tab:green', 'tab:gray'][:len(names)])
    for i, w in enumerate(walls):
        a2.text(w, i, f' {res["t_end_s"] / w:.3g}x real time', va='center', fontsize=8)
    a2.set_xlim(min(walls) / 3, max(walls) * 30)
    a2.set_xscale('log')
    a2.axvline(res['t_end_s'], color='k', ls=':', lw=0.8, label='real time')
    a2.set_xlabel('CPU time at the target accuracy (s)')
    a2.set_title(f'strain error <= {res["target_strain_error"]:g}')
    a2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt(v, spec):
    return '-' if v is None else format(v, spec)


def table(res):
    """The Markdown table of the README section."""
    lines = ['| peer | configuration | step / tolerance | strain error | CPU (s) | x real time |',
             '|---|---|---|---|---|---|']
    for key, name in (('ours', 'ours'), ('mujoco', 'MuJoCo'), ('scipy', 'SciPy')):
        r = res.get(key)
        if not r:
            continue
        conf = r.get('configuration') or r.get('model') or r.get('method')
        lines.append(f"| {name} | {conf} | {r['knob']} = {r['value']:.3g} | "
                     f"{_fmt(r['strain_error'], '.2e')} | {_fmt(r['cpu_s'], '.3f')} | "
                     f"{_fmt(r['real_time_factor'], '.1f')} |")
    lines.append('')
    k = res.get('kernel')
    if k:
        alone = k['integrator_only_time_per_step_s'] * 1e6
        lines.append(f"- per step ({k['configuration']}): {k['time_per_step_s'] * 1e6:.1f} us "
                     f"through Simulation.advance, {alone:.1f} us integrator alone, "
                     f"kernel bound {k['kernel_bound_step'] * 1e6:.1f} us "
                     f"({k['evaluations_per_step']} x {k['accelerations'] * 1e6:.2f} us per "
                     f"evaluation + {', '.join(k['parts_in_step'][1:]) or 'nothing else'})")
        lines.append('- where a step goes: ' + ', '.join(
            f'{name} {frac:.0%}' for name, frac in k['profile_fraction_of_step'].items()))
        lines.append(f"- real time factor of the integrator alone: "
                     f"{_fmt(res.get('real_time_factor_fb_integrator_only'), '.1f')}")
    for key, goal in TARGETS.items():
        lines.append(f"- {key}: {_fmt(res.get(key), '.2f')} (target "
                     f"{'<=' if key == 'step_over_kernel_bound' else '>='} {goal:g}, met: "
                     f"{res['targets']['met'].get(key)})")
    return '\n'.join(lines)
