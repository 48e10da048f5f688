"""``tensegrity fit``: the scene values (continuous ``--free`` keys and discrete ``--choice`` keys)
that bring simulated figures closest to a target, by differential evolution
(:func:`scipy.optimize.differential_evolution`), each population evaluated on Dask.

The target file lists cases (scene overrides) and the figures each must reach, named as in the
run summary (``pulse.amplitude``); the error of a point is the weighted root mean square of the
relative errors ``(simulated - target) / target`` over every figure of every case. Each case of
each point is one :func:`solver.simulate.runner.simulate` run, as ``tensegrity run`` makes it.
"""
from __future__ import annotations

import functools
import itertools
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from tensegrity_ros.studies.cluster import Cluster, dashboard_option
from tensegrity_ros.studies.grid import SweepError, parse_axis
from tensegrity_ros.studies.sweep import chunks
from tensegrity_ros.studies.table import FIGURES, flatten

PENALTY = 10.0        # the error of a point whose run diverged or misses a figure (1000 %)


@dataclass
class Case:
    """One case of a target: scene overrides ``set``, ``figures`` to reach, their ``weights``."""
    set: dict
    figures: dict
    weights: dict


def load_target(path):
    """The cases of a target file (see the module docstring); raises :class:`SweepError` naming
    the problem."""
    path = Path(path)
    try:
        raw = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise SweepError(f'--target {path}: cannot read ({exc.strerror})') from None
    except yaml.YAMLError as exc:
        raise SweepError(f'--target {path}: not valid YAML ({getattr(exc, "problem", exc)})') \
            from None
    where = f'--target {path}'
    if not isinstance(raw, dict) or set(raw) != {'cases'}:
        raise SweepError(f'{where}: expected a mapping with one key, cases')
    cases = raw['cases']
    if not isinstance(cases, list) or not cases:
        raise SweepError(f'{where}: cases must be a non-empty list')
    out = []
    for i, case in enumerate(cases):
        at = f'{where}: case {i + 1}'
        if not isinstance(case, dict):
            raise SweepError(f'{at}: expected a mapping (set, figures, weights)')
        unknown = set(case) - {'set', 'figures', 'weights'}
        if unknown:
            raise SweepError(f'{at}: unknown key {sorted(unknown)[0]!r} '
                             '(valid: set, figures, weights)')
        sets = case.get('set') or {}
        figures = case.get('figures')
        weights = case.get('weights') or {}
        if not isinstance(sets, dict):
            raise SweepError(f'{at}: set must be a mapping of scene keys to values')
        if not isinstance(figures, dict) or not figures:
            raise SweepError(f'{at}: figures must be a non-empty mapping of figure names to '
                             'values')
        if not isinstance(weights, dict):
            raise SweepError(f'{at}: weights must be a mapping of figure names to numbers')
        for name, value in figures.items():
            if name not in FIGURES:
                raise SweepError(f'{at}: unknown figure {name!r} (one of {", ".join(FIGURES)})')
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value) or value == 0:
                raise SweepError(f'{at}: figure {name}: expected a finite non-zero number, got '
                                 f'{value!r}')
        for name, w in weights.items():
            if name not in figures:
                raise SweepError(f'{at}: weight for {name!r}, which is not among its figures')
            if isinstance(w, bool) or not isinstance(w, (int, float)) or not (w > 0) \
                    or not math.isfinite(w):
                raise SweepError(f'{at}: weight {name}: expected a positive number, got {w!r}')
        out.append(Case({str(k): v for k, v in sets.items()},
                        {k: float(v) for k, v in figures.items()},
                        {k: float(weights.get(k, 1.0)) for k in figures}))
    return out


@dataclass
class Problem:
    """What a fit varies: ``free`` [(key, lo, hi)], ``choices`` [(key, [values])]; the ``scene``,
    its ``cases`` and the overrides ``extra`` applied to every run (``run.t_end``)."""
    scene: object
    cases: list
    free: list
    choices: list
    extra: dict

    @property
    def bounds(self):
        return ([(lo, hi) for _, lo, hi in self.free]
                + [(0, len(vals) - 1) for _, vals in self.choices])

    @property
    def integrality(self):
        return [False] * len(self.free) + [True] * len(self.choices)

    def values(self, x):
        """The scene values of the optimiser's vector ``x`` (choices as their index)."""
        out = {key: float(v) for (key, _, _), v in zip(self.free, x)}
        for (key, vals), v in zip(self.choices, x[len(self.free):]):
            out[key] = vals[min(max(int(round(float(v))), 0), len(vals) - 1)]
        return out

    def combo(self, x):
        return tuple(self.values(x)[k] for k, _ in self.choices)

    def overrides(self, case, values):
        return {**case.set, **values, **self.extra}


def case_residuals(case, figures):
    """The weighted relative errors ``sqrt(w) (simulated - target) / target`` of one case's
    ``figures`` (a flattened summary, or None for a diverged run): a missing figure counts as
    :data:`PENALTY`."""
    out = []
    for name, target in case.figures.items():
        got = figures.get(name) if figures else None
        rel = PENALTY if got is None or not math.isfinite(got) else (got - target) / target
        out.append(math.sqrt(case.weights[name]) * rel)
    return out


class Objective:
    """The error of a point (picklable: it is what each Dask task calls): the weighted root mean
    square of the relative errors over every figure of every case."""

    def __init__(self, problem):
        self.problem = problem
        self.wsum = sum(sum(c.weights.values()) for c in problem.cases)

    def evaluate(self, x):
        """``(error, residuals, [flattened summary or None per case], [status per case])``."""
        return self.evaluate_many([x])[0]

    def evaluate_many(self, xs, threads=1):
        """:meth:`evaluate` of every point of ``xs``: their cases run as one batch
        (:func:`solver.simulate.batch.simulate_batch` on ``threads`` threads; each case's summary
        is that of its single run)."""
        from solver import simulate_batch
        p = self.problem
        values = [p.values(x) for x in xs]
        items = [(p.scene, list(p.overrides(case, v).items())) for v in values for case in p.cases]
        got = iter(simulate_batch(items, threads=threads, base=False))   # no fit figure of it
        out = []
        for _ in values:
            res, figs, status = [], [], []
            for case in p.cases:
                bp = next(got)
                if bp.status == 'ok':
                    f = flatten(bp.summary)
                    status.append('ok')
                elif bp.status == 'diverged':
                    f = None
                    status.append(f'diverged: {bp.reason}')
                else:                   # as the single run: a failed case stops the fit
                    raise bp.error
                res += case_residuals(case, f)
                figs.append(f)
            res = np.array(res)
            out.append((math.sqrt(float(res @ res) / self.wsum), res, figs, status))
        return out

    def __call__(self, x):
        return self.evaluate(x)[0]


def _errors(obj, xs):
    """The errors of the points ``xs`` (one batch; a Dask task)."""
    return [e[0] for e in obj.evaluate_many(xs)]


class RecordingMap:
    """The map-like callable handed to the optimiser: maps on the cluster (or in this process)
    and keeps every evaluated point and its error. An :class:`Objective` is mapped in batches
    (:meth:`Objective.evaluate_many`): in this process one batch on every core, on the cluster
    one task per batch of a few points."""

    def __init__(self, cluster=None, threads=None):
        self.cluster = cluster
        self.threads = threads
        self.history = []

    def __call__(self, func, iterable):
        xs = [np.array(x, dtype=float) for x in iterable]
        if not isinstance(func, Objective):
            ys = self.cluster.map(func, xs) if self.cluster is not None else [func(x) for x in xs]
        elif self.cluster is None:
            ys = [e[0] for e in func.evaluate_many(xs, threads=self.threads)]
        else:
            parts = chunks(xs, self.cluster.n_workers)
            ys = [y for part in self.cluster.map(functools.partial(_errors, func), parts)
                  for y in part]
        self.history.extend(zip(xs, ys))
        return ys


def build(scene_path, target, free, choices, t_end=None):
    """A validated :class:`Problem` (raises :class:`SweepError` / ``SceneError``; nothing run)."""
    from solver import Scene, SceneError
    scene = Scene.load(scene_path)
    if not free and not choices:
        raise SweepError('fit: give at least one --free KEY=LO:HI or --choice KEY=A,B')
    cases = load_target(target)
    fr = []
    for text in free or []:
        ax = parse_axis(text, '--free')
        if ax.range is None:
            raise SweepError(f'--free {text!r}: expected KEY=LO:HI')
        fr.append((ax.key, ax.range[0], ax.range[1]))
    ch = []
    for text in choices or []:
        ax = parse_axis(text, '--choice')
        if ax.values is None or ':' in text.split('=', 1)[1]:
            raise SweepError(f'--choice {text!r}: expected KEY=A,B,...')
        ch.append((ax.key, ax.values))
    keys = [k for k, _, _ in fr] + [k for k, _ in ch]
    for k in keys:
        if keys.count(k) > 1:
            raise SweepError(f'fit: {k} is given twice')
        for i, case in enumerate(cases):
            if k in case.set:
                raise SweepError(f'--target {target}: case {i + 1} sets {k}, which the fit '
                                 'varies')
    extra = {} if t_end is None else {'run.t_end': t_end}
    problem = Problem(scene, cases, fr, ch, extra)
    # every case at every corner of the free ranges and every choice: keys and values valid
    corners = itertools.product(*[(lo, hi) for _, lo, hi in fr], *[vals for _, vals in ch])
    for corner in corners:
        values = dict(zip(keys, corner))
        for i, case in enumerate(cases):
            try:
                scene.with_overrides(list(problem.overrides(case, values).items()))
            except SceneError as exc:
                src = next((k for k in keys if str(exc).startswith(k + ':')), None)
                opt = ('--free' if any(k == src for k, _, _ in fr) else '--choice') if src \
                    else f'--target {target}: case {i + 1}'
                raise SweepError(f'{opt}: {exc}') from None
    return problem


def polish(obj, x, mapper, max_nfev=40):
    """Refine the continuous values of ``x`` (its choices fixed) by
    :func:`scipy.optimize.least_squares` on the weighted relative errors; each evaluation is
    recorded in ``mapper.history``. Returns the better of ``x`` and the refined point."""
    from scipy.optimize import least_squares
    p = obj.problem
    nf = len(p.free)
    if nf == 0:
        return x
    lo = np.array([b[0] for b in p.bounds[:nf]])
    hi = np.array([b[1] for b in p.bounds[:nf]])
    fixed = x[nf:]

    def residuals(z):
        full = np.concatenate([z, fixed])
        err, res, _, _ = obj.evaluate(full)
        mapper.history.append((full, err))
        return res

    sol = least_squares(residuals, np.clip(x[:nf], lo, hi), bounds=(lo, hi), x_scale=hi - lo,
                        diff_step=1e-3, max_nfev=max_nfev, method='trf')
    best = min(mapper.history, key=lambda h: h[1])
    del sol                      # the best point evaluated (the solution is among them)
    return np.array(best[0])


def fit(problem, cluster=None, seed=0, popsize=8, maxiter=20, tol=1e-3, refine=True,
        threads=None):
    """Run the fit: differential evolution over the free keys and the choices (the choices as
    integer indices, ``integrality``), each generation evaluated by the map over ``cluster``;
    then, with ``refine``, :func:`polish` on the continuous values at the best point's choices.
    Returns the result as a JSON-ready dict."""
    from scipy.optimize import differential_evolution
    obj = Objective(problem)
    mapper = RecordingMap(cluster, threads)
    res = differential_evolution(obj, problem.bounds, integrality=problem.integrality,
                                 workers=mapper, updating='deferred', polish=False, rng=seed,
                                 popsize=popsize, maxiter=maxiter, tol=tol)
    best_x = np.array(res.x, dtype=float)
    n_de = len(mapper.history)
    if refine:
        best_x = polish(obj, best_x, mapper)
    err, _, figs, status = obj.evaluate(best_x)
    from tensegrity_ros.studies.fit_report import determination
    free = determination(obj, best_x, figs, threads=threads)
    n_runs = (len(mapper.history) + 1 + 2 * len(free)) * len(problem.cases)
    combos = {}                   # choice values -> (best error, its point, points evaluated)
    for x, y in mapper.history:
        c = problem.combo(x)
        best_y, best, n = combos.get(c, (math.inf, None, 0))
        combos[c] = (y, x, n + 1) if y < best_y else (best_y, best, n + 1)
    ranking = sorted(combos.items(), key=lambda kv: kv[1][0])
    cases = []
    for case, f, st in zip(problem.cases, figs, status):
        rows = {}
        for name, target in case.figures.items():
            got = f.get(name) if f else None
            rows[name] = {'target': target, 'simulated': got, 'weight': case.weights[name],
                          'rel_error': None if got is None else (got - target) / target}
        cases.append({'set': case.set, 'status': st, 'figures': rows})
    return {
        'best': problem.values(best_x), 'error': err, 'cases': cases, 'free': free,
        'combinations': [{'choice': dict(zip([k for k, _ in problem.choices], c)),
                          'best': problem.values(x), 'error': y, 'evaluations': n}
                         for c, (y, x, n) in ranking],
        'runs': n_runs, 'evaluations': len(mapper.history) + 1, 'generations': int(res.nit),
        'evaluations_evolution': n_de, 'evaluations_polish': len(mapper.history) - n_de,
        'converged': bool(res.success), 'message': str(res.message), 'seed': seed,
        'popsize': popsize, 'maxiter': maxiter,
    }


def check_convergence(problem, result, tolerance, threads=None):
    """The convergence check of a fit's best point (``result`` of :func:`fit`): each case run
    again with every step control refined (:func:`solver.simulate.convergence.refined_overrides`
    of the case's scene) and the relative change of each of its fitted figures from the value
    the fit found (:func:`~solver.simulate.convergence.relative_change`). Returns
    ``{'tolerance', 'converged', 'worst': {'case', 'figure', 'change', 'refined'}, 'cases':
    [{'refined', 'status', 'changes', 'converged'}]}``; a case whose refined run (or whose own
    run) does not end ok fails the check."""
    from solver import convergence
    from solver import simulate_batch
    items, refined = [], []
    for case in problem.cases:
        overrides = list(problem.overrides(case, result['best']).items())
        extra = convergence.refined_overrides(problem.scene.with_overrides(overrides))
        items.append((problem.scene, overrides + extra))
        refined.append(convergence.describe(extra))
    runs = simulate_batch(items, threads=threads, base=False)
    cases, worst = [], None
    for k, (case, bp, found) in enumerate(zip(problem.cases, runs, result['cases'])):
        entry = {'refined': refined[k], 'status': bp.status, 'changes': {}, 'converged': False}
        if bp.status == 'ok' and found['status'] == 'ok':
            f = flatten(bp.summary)
            entry['changes'] = {name: convergence.relative_change(r['simulated'], f.get(name))
                                for name, r in found['figures'].items()}
            known = {n: c for n, c in entry['changes'].items() if c is not None}
            entry['converged'] = all(c <= tolerance for c in known.values())
        elif bp.status != 'ok':
            known = {f'refined run {bp.status}': math.inf}
        else:                       # the fit's own run of the case did not end ok
            known = {f"run {found['status'].split(':')[0]}": math.inf}
        for name, c in known.items():
            if worst is None or c > worst['change']:
                worst = {'case': k + 1, 'figure': name, 'change': c, 'refined': refined[k]}
        cases.append(entry)
    return {'tolerance': tolerance, 'converged': all(c['converged'] for c in cases),
            'worst': worst, 'cases': cases}


def convergence_failure(check):
    """The one line of a failed :func:`check_convergence` (None when it passed)."""
    if check['converged']:
        return None
    w = check['worst']
    moved = ('cannot be compared' if math.isinf(w['change'])
             else f"moves {100 * w['change']:.3g} %")
    return (f"fitted figures not converged: case {w['case']} {w['figure']} {moved} when every "
            f"step control is refined ({w['refined']}; limit {100 * check['tolerance']:g} %); "
            f"fit with a finer integrator.dt and contact.resolution")


def format_result(result):
    """The result as lines of text."""
    lines = [f"best point (error {100 * result['error']:.3g} % rms): "
             + ', '.join(f'{k} = {v:.6g}' if isinstance(v, float) else f'{k} = {v}'
                         for k, v in result['best'].items())]
    for i, case in enumerate(result['cases']):
        sets = ', '.join(f'{k}={v}' for k, v in case['set'].items()) or '(scene as given)'
        lines.append(f'  case {i + 1}: {sets}' + ('' if case['status'] == 'ok'
                                                    else f"  [{case['status']}]"))
        lines.append(f"    {'figure':<28} {'target':>12} {'simulated':>12} {'rel. error':>11}")
        for name, r in case['figures'].items():
            sim = 'n/a' if r['simulated'] is None else f"{r['simulated']:.6g}"
            rel = 'n/a' if r['rel_error'] is None else f"{100 * r['rel_error']:+.2f} %"
            lines.append(f"    {name:<28} {r['target']:>12.6g} {sim:>12} {rel:>11}")
    from tensegrity_ros.studies.fit_report import format_lines
    lines += format_lines(result.get('free') or [])
    if result['combinations'] and result['combinations'][0]['choice']:
        lines.append('  best evaluated point of each choice, best first:')
        for c in result['combinations']:
            choice = ', '.join(f'{k}={v}' for k, v in c['choice'].items())
            free = ', '.join(f'{k} = {v:.5g}' for k, v in c['best'].items()
                             if k not in c['choice'])
            lines.append(f"    {choice:<32} error {100 * c['error']:8.3g} %   {free}"
                         f"   ({c['evaluations']} points)")
    check = result.get('convergence')
    if check is not None:
        for i, case in enumerate(check['cases']):
            moved = ', '.join(f'{k} {100 * c:.3g} %' for k, c in case['changes'].items()
                              if c is not None) or f"refined run {case['status']}"
            lines.append(f"  convergence, case {i + 1} ({case['refined']}): {moved}: "
                         f"{'converged' if case['converged'] else 'NOT converged'} (limit "
                         f"{100 * check['tolerance']:g} %)")
    ranges = 2 * len(result.get('free') or [])
    lines.append(f"  {result['runs']} runs ({result['evaluations']} points"
                 f"{f' + {ranges} for the ranges' if ranges else ''} x "
                 f"{len(result['cases'])} cases), {result['generations']} generations, "
                 f"seed {result['seed']}: {result['message']}")
    return lines


def fitted_description(name, best, target=None):
    """The description of a fitted scene: what was fitted and the values found (the source scene's
    description may state other values, e.g. its prestrain)."""
    values = ', '.join(f'{k} = {v:.6g}' if isinstance(v, float) else f'{k} = {v}'
                       for k, v in best.items())
    to = f' to {target}' if target else ''
    return f'{name} fitted by tensegrity fit{to}: {values}; every other value as in {name}'


def write_scene(problem, best, path, target=None):
    """The scene with the best values written to ``path`` (YAML), its description stating them."""
    scene = problem.scene.with_overrides(list(best.items()))
    data = scene.data
    data['description'] = fitted_description(problem.scene.name, best, target)
    Path(path).write_text(
        f'# {problem.scene.name} with the values found by tensegrity fit\n'
        + yaml.safe_dump(data, sort_keys=False, width=99))
    return str(path)


def main(args):
    """``tensegrity fit``: returns the exit code."""
    if args.workers is not None and args.workers < 1:
        raise SweepError(f'--workers: must be >= 1, got {args.workers}')
    dashboard = dashboard_option(args)
    if args.popsize < 1 or args.maxiter < 1:
        raise SweepError('--popsize and --maxiter: must be >= 1')
    if args.write_scene and not Path(args.write_scene).parent.exists():
        raise SweepError(f'--write-scene {args.write_scene}: directory does not exist')
    tol = getattr(args, 'convergence', None)
    if tol is not None:
        from solver import check_tolerance
        check_tolerance(tol, error=SweepError)
    problem = build(args.scene, args.target, args.free, args.choice, t_end=args.t_end)
    cluster = None
    try:
        # as for sweeps: the batched runner's threads here unless --workers N > 1 or --scheduler
        if args.scheduler or (args.workers or 1) > 1:
            cluster = Cluster(workers=args.workers, address=args.scheduler, dashboard=dashboard)
            cluster.report_dashboard()
        result = fit(problem, cluster, seed=args.seed, popsize=args.popsize,
                     maxiter=args.maxiter, refine=not args.no_polish,
                     threads=1 if args.workers == 1 else None)
    finally:
        if cluster is not None:
            cluster.close()
    problem_line = None
    if tol is not None:
        result['convergence'] = check_convergence(problem, result, tol,
                                                  threads=1 if args.workers == 1 else None)
        problem_line = convergence_failure(result['convergence'])
    if args.write_scene:
        result['scene_file'] = write_scene(problem, result['best'], args.write_scene,
                                           args.target)
    if args.json:
        from solver import json_safe
        print(json.dumps(json_safe(result), allow_nan=False))
    else:
        for line in format_result(result):
            print(line)
        if args.write_scene:
            print(f"  scene: {result['scene_file']}")
    from tensegrity_ros.studies.fit_report import bound_note
    note = bound_note(result['free'])
    if note is not None:
        print(f'tensegrity: {note}', file=sys.stderr)
    if problem_line is not None:
        print(f'tensegrity: {problem_line}', file=sys.stderr)
        return 1
    return 0
