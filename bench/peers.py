"""``tensegrity bench --peers``: speed against peers at equal accuracy, measured side by side.

On the paper's FB column (p = 0.002, v0 = 0.1 m/s, 1 s) this runs, in one process:

1. a converged reference: ``full3d`` + ``rk4_projected`` at ``dt = 10 ms / 320``, shown converged
   by comparing with ``10 ms / 160``;
2. our solver: every exact model (``full3d``, ``sym3d`` if present) with every integrator, at the
   with and without landing steps on cable kinks, at the largest step (or loosest ``rtol``)
   whose strain error meets the target; the fastest is ours;
3. MuJoCo (:mod:`bench.peers_mujoco`): the same column as a kinematic tree, its RK4, largest step
   meeting the target; checked at rest before the impact and against the reference pulse;
4. the plain SciPy baseline (:mod:`bench.peers_scipy`): ``solve_ivp`` DOP853, loosest ``rtol``
   meeting the target;
5. the kernel bound (:mod:`bench.peers_kernels`) of our best configuration.

Accuracy metric: ``max`` over the output times (every 10 ms) and the 50 prisms of
``|eps - eps_ref|`` (absolute strain), target 1e-3. Writes ``peers.json``, ``peers.csv`` (every
run tried) and ``peers.png`` into ``out_dir``.
"""
from __future__ import annotations

import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from solver.integrators import registry as integrators
from solver.kernels import records

from solver.models import family as models
from solver.analysis.observables import track_pulse
from solver.build.scene import Scene
from solver.simulate.simulation import SimulationDiverged
from solver.simulate.array import simulation_for

from . import peers_report

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / 'config' / 'scenes' / 'fb_column.yaml'
TARGET = 1e-3                 # strain error (absolute, max over time and prisms)
V0, PRESTRAIN, OUTPUT_DT = 0.1, 0.002, 0.01
LADDER = (1, 2, 3, 4, 5, 7, 10, 14, 20, 28, 40, 56, 80)   # steps per 10 ms output interval
RTOLS = (1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 3e-6, 1e-6, 3e-7, 1e-7, 1e-8, 1e-9)
EXCLUDED_MODELS = ('chain1d',)  # not the same physics (no base rotation)
# docs/physics.md section 7, check 3: rigid members hold to 1e-9 (relative)
BAR_TOL = 1e-9


# The solver's divergence guard (energy growth 1e-3, constraint error 1e-6 by default) stops runs
# whose strain may still be within the target; MuJoCo and SciPy have no such guard, so here the
# strain error alone decides (the guard still stops blow-ups).
GUARD = [('divergence.energy_error', 0.1), ('divergence.constraint_error', 1e-3)]


def fb_scene(overrides=()):
    return Scene.load(SCENE).with_overrides(
        [('prestrain', PRESTRAIN), ('loading.impact.v0', V0), ('run.output_dt', OUTPUT_DT)]
        + GUARD + list(overrides))


def integrator_only(overrides, t_end):
    """CPU seconds per step of the integrator kernel alone (one call for the whole run, no
    ``Simulation.advance`` bookkeeping), from the impact, best of 3; ``(s_per_step, steps)``."""
    sim = simulation_for(fb_scene(overrides))
    sim.apply_impact(V0)
    m = sim.model
    d = records.clone_data(m.data)          # the runs step a copy of the data
    n = int(round(t_end / sim.dt))
    sim.integrator.run(m.rec, d, m.work, sim.dt, 1, sim.tol, sim.max_iter, sim.kinks)
    best = math.inf
    for _ in range(3):
        records.copy_data(m.data, d)
        sim.integrator.reset()
        t0 = time.thread_time()
        steps, status = sim.integrator.run(m.rec, d, m.work, sim.dt, n, sim.tol,
                                           sim.max_iter, sim.kinks)
        best = min(best, (time.thread_time() - t0) / max(steps, 1))
    return best, steps


class Clock:
    """Accumulates wall time and the CPU time of this thread (``time.thread_time``): on a busy
    machine the CPU time is what a step costs, the wall time also counts waiting for a core."""

    def __init__(self):
        self.wall = self.cpu = 0.0

    def __enter__(self):
        self._w, self._c = time.perf_counter(), time.thread_time()
        return self

    def __exit__(self, *exc):
        self.wall += time.perf_counter() - self._w
        self.cpu += time.thread_time() - self._c


def strain_error(eps, ref):
    n = min(len(eps), len(ref))
    return float(np.max(np.abs(np.asarray(eps[:n]) - np.asarray(ref[:n]))))


def run_ours(overrides, t_end, ref=None, abort=True):
    """One run of our solver. Returns a dict with the strain history (n_t, n_prisms), the CPU and
    wall time of ``advance`` only, the steps taken and the simulation (its final state)."""
    sim = simulation_for(fb_scene(overrides))
    sim.advance(sim.dt)                      # compile or load cached kernels, untimed
    sim.reset()
    sim.apply_impact(V0)
    n_out = int(round(t_end / OUTPUT_DT))
    eps = [sim.frame().strain[0]]
    clock, err, done, reason = Clock(), 0.0, True, ''
    for k in range(n_out):
        try:
            with clock:
                sim.advance(OUTPUT_DT)
        except SimulationDiverged as exc:
            err, done, reason = math.inf, False, str(exc)
            break
        eps.append(sim.frame().strain[0])
        if ref is not None:
            err = max(err, float(np.max(np.abs(eps[-1] - ref[k + 1]))))
            if abort and err > TARGET:
                done, reason = False, f'error above target at t = {sim.t:.3g} s'
                break
    return {'eps': np.array(eps), 'cpu_s': clock.cpu, 'wall_s': clock.wall,
            'steps': sim.steps_taken, 'error': err,
            'constraint_error_end': sim.constraint_error() if done else None,
            'completed': done, 'reason': reason, 'sim': sim, 'model': sim.model.name,
            'method': sim.integrator.name}


def run_mujoco(network, n_sub, t_end, ref=None, abort=True):
    from .peers_mujoco import MujocoColumn
    import mujoco
    mc = MujocoColumn(network, OUTPUT_DT / n_sub)
    mc.impact(V0)
    n_out = int(round(t_end / OUTPUT_DT))
    eps = [mc.strain()[0]]
    clock, err, done = Clock(), 0.0, True
    bad = mujoco.mjtWarning.mjWARN_BADQACC
    for k in range(n_out):
        with clock:
            mc.advance(n_sub)
        if mc.data.warning[bad].number > 0 or not np.all(np.isfinite(mc.data.qpos)):
            err, done = math.inf, False
            break
        eps.append(mc.strain()[0])
        if ref is not None:
            err = max(err, float(np.max(np.abs(eps[-1] - ref[k + 1]))))
            if abort and err > TARGET:
                done = False
                break
    return {'eps': np.array(eps), 'cpu_s': clock.cpu, 'wall_s': clock.wall,
            'steps': n_sub * (len(eps) - 1),
            'error': err, 'completed': done, 'column': mc}


def _row(peer, config, knob, value, r, t_end):
    ok = r['completed']
    return {'peer': peer, 'configuration': config, 'knob': knob, 'value': value,
            'strain_error': r['error'], 'completed': ok, 't_end_s': t_end,
            'cpu_s': r['cpu_s'] if ok else None, 'wall_s': r['wall_s'] if ok else None,
            'steps': r.get('steps'),
            'real_time_factor': t_end / r['cpu_s'] if ok and r['cpu_s'] > 0 else None}


def search_ours(ref, t_end, ladder, rtols, rows, log):
    """Largest step (loosest rtol) meeting the target for each exact model and integrator, re-timed
    (median of 5). Returns the list of passing candidates, fastest first."""
    names = [m for m in models.MODELS if m not in EXCLUDED_MODELS]
    found = []
    for model in names:
        for method, kinks in [(m, k) for m in integrators.METHODS for k in (True, False)]:
            adaptive = getattr(integrators.METHODS[method], 'adaptive', False)
            knob = 'rtol' if adaptive else 'dt'
            values = rtols if adaptive else [OUTPUT_DT / n for n in ladder]
            for value in values:
                ov = [('model', model), ('integrator.method', method),
                      ('integrator.land_on_kinks', kinks)]
                ov += ([('integrator.dt', OUTPUT_DT), ('integrator.rtol', value),
                        ('integrator.atol', 1e-2 * value)] if adaptive
                       else [('integrator.dt', value)])
                try:
                    r = run_ours(ov, t_end, ref)
                except ValueError as exc:      # a model that does not apply to this scene
                    log(f'  ours {model}/{method}: {exc}')
                    break
                if not r['completed']:
                    log(f'  ours {model}/{method} kinks={kinks} {knob}={value:.3g}: stopped, '
                        f'{r["reason"][:90]}')
                config = f'{r["model"]}+{r["method"]}' + ('' if kinks else ' (no kink landing)')
                rows.append(_row('ours', config, knob, value, r, t_end))
                if r['completed'] and r['error'] <= TARGET:
                    again = [r] + [run_ours(ov, t_end) for _ in range(4)]
                    r = dict(r, cpu_s=statistics.median(a['cpu_s'] for a in again),
                             wall_s=statistics.median(a['wall_s'] for a in again),
                             cpus_s=[a['cpu_s'] for a in again])
                    found.append(dict(r, knob=knob, value=value, overrides=ov, config=config))
                    log(f'  ours {config} {knob}={value:.3g}: error {r["error"]:.2e}, '
                        f'{r["cpu_s"]:.3f} s CPU')
                    break
            else:
                log(f'  ours {model}/{method} kinks={kinks}: target not reached')
    return sorted(found, key=lambda c: c['cpu_s'])


def retime(cands, t_end, log, rounds=7):
    """Re-time close candidates round-robin (``rounds`` runs each, first runs excluded) so that a
    busy moment of the machine does not pick the winner; fastest median CPU time first."""
    cpus = {id(c): [] for c in cands}
    walls = {id(c): [] for c in cands}
    for _ in range(rounds):
        for c in cands:
            r = run_ours(c['overrides'], t_end)
            cpus[id(c)].append(r['cpu_s'])
            walls[id(c)].append(r['wall_s'])
    out = [dict(c, cpu_s=statistics.median(cpus[id(c)]), wall_s=statistics.median(walls[id(c)]),
                cpus_s=cpus[id(c)]) for c in cands]
    out.sort(key=lambda c: c['cpu_s'])
    log('  re-timed (median of %d, CPU): ' % rounds
        + ', '.join(f'{c["config"]} {c["cpu_s"]:.4f} s' for c in out))
    return out


def search_mujoco(network, ref, t_end, ladder, rows, log):
    best = None
    for n in ladder:
        r = run_mujoco(network, n, t_end, ref)
        rows.append(_row('mujoco', 'tree+RK4', 'dt', OUTPUT_DT / n, r, t_end))
        log(f'  mujoco dt={OUTPUT_DT / n:.3g}: error {r["error"]:.2e}'
            + (f', {r["cpu_s"]:.2f} s CPU' if r['completed'] else ' (stopped)'))
        if r['completed'] and r['error'] <= TARGET:
            finer = run_mujoco(network, 2 * n, t_end, ref, abort=False)   # work-precision point
            rows.append(_row('mujoco', 'tree+RK4', 'dt', OUTPUT_DT / (2 * n), finer, t_end))
            return dict(r, knob='dt', value=OUTPUT_DT / n, n_sub=n, met=True)
        if r['completed']:
            best = dict(r, knob='dt', value=OUTPUT_DT / n, n_sub=n, met=False)
    return best


def search_scipy(network, x, v, ref, t_end, rtols, rows, log):
    """Loosest rtol meeting the target (``rtols`` from loose to tight)."""
    from solver.analysis.observables import prism_strains

    from .peers_scipy import ScipyColumn
    sc = ScipyColumn(network)
    times = np.arange(int(round(t_end / OUTPUT_DT)) + 1) * OUTPUT_DT
    r = None
    for rtol in rtols:                 # loosest first: the cheap runs come first
        try:
            pos, wall, stats = sc.solve(x, v, times, rtol)
            eps = np.array([prism_strains(p, network.levels, network.h0)[0] for p in pos])
            r = {'eps': eps, 'cpu_s': stats['cpu_s'], 'wall_s': wall,
                 'error': strain_error(eps, ref), 'completed': True, 'steps': None,
                 'evaluations': stats['evaluations']}
        except (RuntimeError, np.linalg.LinAlgError) as exc:
            r = {'eps': None, 'cpu_s': math.nan, 'wall_s': math.nan, 'error': math.inf,
                 'completed': False, 'steps': None, 'evaluations': None, 'reason': str(exc)}
        rows.append(_row('scipy', 'solve_ivp DOP853', 'rtol', rtol, r, t_end))
        log(f'  scipy rtol={rtol:.0e}: error {r["error"]:.2e}, {r["cpu_s"]:.1f} s CPU, '
            f'{r["evaluations"]} evaluations')
        r = dict(r, knob='rtol', value=rtol, met=r['error'] <= TARGET)
        if r['met']:
            break
    return r


def side_by_side(ours, mj, sp, network, x, v, t_end, log, rounds=3):
    """The final timing, interleaved so that every ratio compares runs made in the same minutes:
    ours, MuJoCo, ours, MuJoCo, ... ours, SciPy, ours. Replaces the search timings by the medians
    (SciPy: its one run) and keeps the lists."""
    o_cpu, o_wall, m_cpu, m_wall = [], [], [], []

    def time_ours():
        r = run_ours(ours['overrides'], t_end)
        o_cpu.append(r['cpu_s'])
        o_wall.append(r['wall_s'])

    for _ in range(rounds):
        time_ours()
        if mj is not None:
            r = run_mujoco(network, mj['n_sub'], t_end)
            m_cpu.append(r['cpu_s'])
            m_wall.append(r['wall_s'])
    time_ours()
    if sp is not None and sp['completed']:
        from .peers_scipy import ScipyColumn
        times = np.arange(int(round(t_end / OUTPUT_DT)) + 1) * OUTPUT_DT
        _, wall, stats = ScipyColumn(network).solve(x, v, times, sp['value'])
        sp = dict(sp, cpu_s=stats['cpu_s'], wall_s=wall, search_cpu_s=sp['cpu_s'],
                  cpus_s=[stats['cpu_s']])
        time_ours()
    ours = dict(ours, cpu_s=statistics.median(o_cpu), wall_s=statistics.median(o_wall),
                cpus_s=o_cpu, search_cpu_s=ours['cpu_s'])
    if mj is not None:
        mj = dict(mj, cpu_s=statistics.median(m_cpu), wall_s=statistics.median(m_wall),
                  cpus_s=m_cpu, search_cpu_s=mj['cpu_s'])
    log('  ours ' + ', '.join(f'{c:.4f}' for c in o_cpu) + ' s CPU; MuJoCo '
        + ', '.join(f'{c:.2f}' for c in m_cpu) + ' s'
        + (f'; SciPy {sp["cpu_s"]:.2f} s' if sp is not None and sp['completed'] else ''))
    return ours, mj, sp


def pulse_figures(eps, times, h0):
    p = track_pulse(times, eps, h0)
    return {'amplitude': p.amplitude, 'amplitude_median': p.amplitude_median,
            'speed_m_s': p.speed_m_s}


def kernel_bound(ours, t_end, log, rounds=9):
    """CPU time per step of our best configuration against its kernel bound: the numba kernels one
    step calls (``evaluations_per_step`` force-and-constraint evaluations, plus the kink
    prediction and the two projections where the method uses them), each timed in a jitted loop.
    Also the integrator alone (no ``Simulation.advance``) and a cProfile of ``advance``.

    Each of ``rounds`` rounds times the three back to back (about 0.1 s), each the best of 3 (the
    kernel loops, the integrator alone, the run through ``advance``), and gives its own ratio;
    ``step_over_kernel_bound`` is the median of those ratios (a busy moment of the machine then
    spoils one round, not the figure), with every round's ratio and the ratio of the minima of
    each part (the least disturbed time of each, taken in different rounds) alongside."""
    from .peers_kernels import advance_profile, profile
    sim = ours['sim']
    integ = sim.integrator
    evals = getattr(integ, 'evaluations_per_step', 4)
    parts = ['accelerations']
    if sim.kinks and getattr(integ, 'lands_on_kinks', integ.name != 'rattle'):
        parts.append('next_kink')
    if getattr(integ, 'projected', False):
        parts += ['project_positions', 'project_velocities']
    if sim.bar_contact != 'none':
        parts.append('contact_scan')
    profs, bounds, alones, steps = [], [], [], []
    for _ in range(rounds):
        try:
            p = profile(sim.model, sim.dt)
        except TypeError as exc:
            log(f'  {exc}')
            return None
        profs.append(p)
        bounds.append(evals * p['accelerations'] + sum(p[q] for q in parts[1:]))
        alones.append(integrator_only(ours['overrides'], t_end)[0])
        r = min((run_ours(ours['overrides'], t_end) for _ in range(3)), key=lambda r: r['cpu_s'])
        steps.append(r['cpu_s'] / r['steps'])
    ratios = [st / b for st, b in zip(steps, bounds)]
    k = int(np.argsort(ratios)[len(ratios) // 2])            # the median round
    prof = profs[k]
    bound, per_step, alone = bounds[k], steps[k], alones[k]
    psim = simulation_for(fb_scene(ours['overrides']))
    psim.apply_impact(V0)
    py_profile = advance_profile(psim, min(t_end, 0.5), OUTPUT_DT)
    log(f'  step {per_step * 1e6:.1f} us ({alone * 1e6:.1f} us integrator alone), kernel bound '
        f'{bound * 1e6:.1f} us (median round of {rounds}; ratios '
        f'{min(ratios):.2f}-{max(ratios):.2f})')
    return dict(prof, evaluations_per_step=evals, evaluations_only_bound_step=evals *
                prof['accelerations'], kernel_bound_step=bound, parts_in_step=parts,
                time_per_step_s=per_step, integrator_only_time_per_step_s=alone,
                integrator_only_over_kernel_bound=alone / bound,
                step_over_kernel_bound=statistics.median(ratios),
                step_over_kernel_bound_rounds=ratios,
                step_over_kernel_bound_of_minima=min(steps) / min(bounds),
                advance_cprofile=py_profile, configuration=ours['config'], rounds=rounds)


def _stderr(msg):
    print(msg, file=sys.stderr, flush=True)


def main(out_dir='bench/results', quick=False, log=_stderr):
    """Run the comparison; returns the list of files written into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    blas1 = peers_report.single_thread_blas()
    machine, versions = peers_report.machine_and_versions(ROOT)
    t_end = 0.25 if quick else 1.0
    ref_n = 160 if quick else 320
    ladder = LADDER[:8] if quick else LADDER
    rows = []
    t_start = time.perf_counter()

    log(f'peers: reference full3d+rk4_projected dt = {OUTPUT_DT:g} s / {ref_n} and / {ref_n // 2}')
    ref_ov = [('model', 'full3d'), ('integrator.method', 'rk4_projected')]
    ref = run_ours(ref_ov + [('integrator.dt', OUTPUT_DT / ref_n)], t_end)
    half = run_ours(ref_ov + [('integrator.dt', 2 * OUTPUT_DT / ref_n)], t_end)
    eps_ref = ref['eps']
    times = np.arange(len(eps_ref)) * OUTPUT_DT
    network = ref['sim'].network
    halving = strain_error(half['eps'], eps_ref)
    log(f'  halving changes the strain by {halving:.2e} (target {TARGET:g})')

    log('peers: our solver')
    ours_all = search_ours(eps_ref, t_end, ladder, RTOLS[:8], rows, log)
    rigid = [c for c in ours_all if c['constraint_error_end'] <= BAR_TOL]
    if rigid:
        rigid[:3] = retime(rigid[:3], t_end, log)
    ours = rigid[0] if rigid else None
    if ours is not None and ours['knob'] == 'dt':      # work-precision points below the target
        for f in (2, 4):
            ov = [o for o in ours['overrides'] if o[0] != 'integrator.dt']
            r = run_ours(ov + [('integrator.dt', ours['value'] / f)], t_end, eps_ref, abort=False)
            rows.append(_row('ours', ours['config'], 'dt', ours['value'] / f, r, t_end))
    if ours_all and ours is not ours_all[0]:
        log(f'  fastest overall {ours_all[0]["config"]} lets the bars drift (constraint error '
            f'{ours_all[0]["constraint_error_end"]:.1e}); ours is the fastest that keeps them')

    log('peers: kernel bound')
    kernel = kernel_bound(ours, t_end, log) if ours is not None else None

    sim0 = simulation_for(fb_scene([('model', 'full3d')]))
    x0 = np.array(sim0.model.positions())
    v_imp = sim0.impact_velocities(V0)
    mj = None
    try:
        import mujoco  # noqa: F401
        have_mujoco = True
    except ImportError:
        have_mujoco = False
        log('peers: mujoco is not installed (pip install -e .[peers]); skipped')
    if have_mujoco:
        log('peers: MuJoCo')
        mj = search_mujoco(network, eps_ref, t_end, ladder, rows, log)
        if mj is not None:
            mj['check'] = peers_report.mujoco_check(network, v_imp, OUTPUT_DT / 10, V0)

    log('peers: SciPy solve_ivp DOP853')
    sp = search_scipy(network, x0, v_imp, eps_ref, t_end, RTOLS, rows, log)

    if ours is not None:
        log('peers: side-by-side timing')
        ours, mj, sp = side_by_side(ours, mj, sp, network, x0, v_imp, t_end, log)

    pulse_ref = pulse_figures(eps_ref, times, network.h0)
    result = peers_report.assemble(
        target=TARGET, t_end=t_end, quick=quick, ref_n=ref_n, halving=halving,
        pulse_ref=pulse_ref, ours=ours, ours_all=ours_all, mj=mj, sp=sp, kernel=kernel,
        times=times, h0=network.h0, machine=machine, versions=versions, blas1=blas1,
        pulse_fn=pulse_figures, output_dt=OUTPUT_DT, v0=V0, prestrain=PRESTRAIN,
        bar_tol=BAR_TOL)
    result['machine']['load_average_end'] = list(os.getloadavg())
    result['bench_wall_s'] = time.perf_counter() - t_start
    paths = [out / 'peers.json', out / 'peers.csv', out / 'peers.png']
    paths[0].write_text(json.dumps(result, indent=2, allow_nan=False,
                                   default=peers_report.json_default) + '\n')
    peers_report.write_csv(rows, paths[1])
    peers_report.plot(rows, result, paths[2])
    log(peers_report.table(result))
    return [str(p) for p in paths]


if __name__ == '__main__':
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', default=str(ROOT / 'bench' / 'results'))
    ap.add_argument('--quick', action='store_true')
    a = ap.parse_args()
    main(a.out, a.quick)
