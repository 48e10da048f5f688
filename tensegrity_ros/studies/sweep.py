"""``tensegrity sweep``: one run per point of a grid (or a Latin hypercube) of scene overrides, on
Dask distributed; one row per point in a Parquet table and a CSV file.

Each point is run as :func:`solver.simulate.runner.simulate`, the function ``tensegrity run``
uses, runs it: the points go in batches (:func:`solver.simulate.batch.simulate_batch`: the
points of a batch share what their network topology shares and step together on threads), and a
row holds the figures of that point's ``tensegrity run --json`` summary under their dotted names
(``pulse.amplitude``, ``energy_drift_rel``). Rows are appended to ``rows.jsonl`` as
they complete (the table is rewritten from it), so an interrupted sweep keeps every finished point
and a rerun of the same command runs only the points that are missing. The grid and the
points' keys are :mod:`tensegrity_ros.studies.grid`, the rows and tables
:mod:`tensegrity_ros.studies.table`, the Dask cluster :mod:`tensegrity_ros.studies.cluster`.
"""
from __future__ import annotations

import json
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from tensegrity_ros.io.progress import growing_bar
from tensegrity_ros.studies.batching import (BATCH_SECONDS, batches, chunks, contact_cost,
                                             dearest_first, point_cost, topology_of)
from tensegrity_ros.studies.cluster import Cluster, dashboard_option
from tensegrity_ros.studies.grid import (SweepError, canonical, code_version, parse_axis,
                                         point_id, points)
from tensegrity_ros.studies.sweep_check import convergence_columns, convergence_report, failed
from tensegrity_ros.studies.table import (CSV, FIGURES, ROWS, TABLE, empty_figures, flatten,
                                          read_rows, write_table)


# -- one point ------------------------------------------------------------------------------------
def run_point(scene, overrides, pid=None):
    """One row: ``scene`` (a :class:`solver.build.scene.Scene`) with ``overrides`` (``{key:
    value}``, applied in order) run by :func:`solver.simulate.runner.simulate`. Never raises for a
    failed run: the row's ``status`` is ``ok``, ``diverged`` or ``error`` with a one-line
    ``reason``."""
    from solver import simulate_scene as simulate
    from solver import SimulationDiverged
    wall0, cpu0 = time.perf_counter(), time.process_time()
    row = {'point_id': pid, **{k: canonical(v) for k, v in overrides.items()}}
    row.update(empty_figures())
    try:
        point = simulate(scene, list(overrides.items()))
        row.update(flatten(point.summary))
        row['status'], row['reason'] = 'ok', ''
    except SimulationDiverged as exc:
        row['status'], row['reason'] = 'diverged', str(exc).splitlines()[0]
    except Exception as exc:           # noqa: BLE001 - a failed point is a row, never a crash
        row['status'] = 'error'
        row['reason'] = f'{type(exc).__name__}: {exc}'.splitlines()[0]
    row['task_wall_s'] = time.perf_counter() - wall0
    row['cpu_time_s'] = time.process_time() - cpu0
    row['worker_pid'] = os.getpid()
    return row


# -- the sweep ------------------------------------------------------------------------------------
@dataclass
class Sweep:
    """A sweep of ``scene`` (a Scene) over ``points`` (dicts of overrides, ``extra`` applied after
    each, e.g. ``run.t_end``) into ``out_dir``."""
    scene: object
    points: list
    out_dir: Path
    keys: list
    extra: dict = field(default_factory=dict)
    convergence: float | None = None     # the tolerance of the convergence check, when asked
    convergence_figures: tuple | None = None     # the figures it judges (None: all)
    # the sensitivity twins' (point_id, overrides) by the point's id, made once
    _twins: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def overrides(self, point):
        return {**point, **self.extra}

    def refined(self, overrides):
        """The overrides of the refined twin of a point (``overrides``, as :meth:`overrides`
        gives them): every step control of the point's scene refined
        (:func:`solver.simulate.convergence.refined_overrides`)."""
        from solver import refined_overrides
        scene = self.scene.with_overrides(list(overrides.items()))
        return {**overrides, **dict(refined_overrides(scene))}

    def sensitivity_twins(self, overrides):
        """The overrides of the two sensitivity twins of a point (``overrides``, as
        :meth:`overrides` gives them): its refined twin with every impact velocity changed by
        ``1 +- PERTURBATION`` (:func:`solver.simulate.convergence.perturbed_overrides`); none
        for a point without an impact velocity."""
        from solver import PERTURBATION, perturbed_overrides
        refined = self.refined(overrides)
        scene = self.scene.with_overrides(list(refined.items()))
        out = []
        for rel in (PERTURBATION, -PERTURBATION):
            changed = perturbed_overrides(scene, rel)
            if changed is not None:
                out.append({**refined, **dict(changed)})
        return out

    def twin_runs(self, pid, overrides, code=None):
        """``(point_id, overrides)`` of the sensitivity twins of the point ``pid`` (its
        ``overrides``), kept once made."""
        if pid not in self._twins:
            code = code or code_version()
            self._twins[pid] = [(point_id(self.scene.data, t, code), t)
                                for t in self.sensitivity_twins(overrides)]
        return self._twins[pid]

    def runs(self, done=None):
        """Every run of the sweep, ``(point_id, overrides)``: the points, then with
        ``convergence`` their refined twins (:meth:`refined`), then, given the rows ``done``
        so far, the sensitivity twins (:meth:`sensitivity_twins`) of each point whose check
        failed there."""
        data, code = self.scene.data, code_version()
        base = [self.overrides(p) for p in self.points]
        out = [(point_id(data, o, code), o) for o in base]
        if self.convergence is not None:
            twins = [(point_id(data, t, code), t) for t in map(self.refined, base)]
            out += twins
            if done is not None:
                for (pid, o), (tid, _) in zip(out, twins):
                    if failed(done.get(pid), done.get(tid), self.convergence,
                              self.convergence_figures):
                        out += self.twin_runs(pid, o, code)
        return out

    def table(self, done, runs=None):
        """The table's rows of the points run so far (``done``: rows by point id), in order; with
        ``convergence`` each with the check of it against its refined twin and, where it failed,
        its sensitivity twins (:func:`convergence_columns`). ``runs``: :meth:`runs`, when the
        caller has it."""
        runs = self.runs() if runs is None else runs
        n = len(self.points)
        rows = []
        for k, (pid, base) in enumerate(runs[:n]):
            if pid not in done:
                continue
            row = done[pid]
            if self.convergence is not None:
                twin_id, twin = runs[n + k]
                refined = {key: v for key, v in twin.items() if base.get(key) != v}
                def twins(pid=pid, base=base):
                    found = [done.get(tid) for tid, _ in self.twin_runs(pid, base)]
                    return found if found and None not in found else None
                row = {**row, **convergence_columns(row, done.get(twin_id), self.convergence,
                                                    refined, self.convergence_figures, twins)}
            rows.append(row)
        return rows

    def columns(self):
        check = list(convergence_columns(None, None, 0.01, {})) if self.convergence else []
        return (['point_id', *self.keys, *[k for k in self.extra if k not in self.keys],
                 'status', 'reason', *[k for k in empty_figures()], *check,
                 'task_wall_s', 'cpu_time_s', 'worker_pid'])


def validate_points(scene, sweep_points, extra, convergence=None):
    """Apply every point's overrides to ``scene`` once (no run): an unknown key or a value out of
    range stops the sweep before anything runs, with the scene's message; with ``convergence``
    the overrides of each point's refined twin as well."""
    from solver import SceneError
    from solver import refined_overrides
    for p in sweep_points:
        overrides = list({**p, **extra}.items())
        try:
            point = scene.with_overrides(overrides)
        except SceneError as exc:
            raise SweepError(str(exc)) from None
        if convergence is not None:
            try:
                point.with_overrides(refined_overrides(point))
            except SceneError as exc:
                raise SweepError(f'--convergence: the refined twin of {dict(overrides)}: '
                                 f'{exc}') from None


def run_batch(task, scene, items):
    """The rows of ``items`` (``(point_id, overrides)`` pairs), one ``task`` (e.g.
    :func:`run_point`) each."""
    return [task(scene, overrides, pid) for pid, overrides in items]


def run_points(scene, items, threads=1, on_row=None, lanes=True):
    """The rows of ``items`` (``(point_id, overrides)`` pairs) as one batch
    (:func:`solver.simulate.batch.simulate_batch` on ``threads`` threads): each row as
    :func:`run_point` makes it, ``task_wall_s`` and ``cpu_time_s`` the point's own share (its
    set-up, and its steps, records and summary on its thread; the base force, which a row does
    not hold, is not recorded). ``on_row(row)`` is called as each point finishes. Never raises
    for a failed point. ``lanes=False`` steps the points one at a time (the same rows)."""
    from solver import simulate_batch
    rows = [None] * len(items)

    def done(k, bp):
        pid, overrides = items[k]
        row = {'point_id': pid, **{key: canonical(v) for key, v in overrides.items()}}
        row.update(empty_figures())
        if bp.status == 'ok':
            row.update(flatten(bp.summary))
        row['status'], row['reason'] = bp.status, bp.reason
        row['task_wall_s'] = bp.task_wall_s
        row['cpu_time_s'] = bp.cpu_time_s
        row['worker_pid'] = os.getpid()
        rows[k] = row
        if on_row is not None:
            on_row(row)

    simulate_batch([(scene, list(o.items())) for _, o in items], threads=threads, on_point=done,
                   base=False, lanes=lanes)     # a row holds no base-force figure
    return rows


def execute(sweep, cluster=None, progress=None, task=None, on_row=None, chunk=None,
            threads=None, more=None, lanes=True):
    """Run the points of ``sweep`` not yet in its ``out_dir``, in batches (:func:`batches`;
    ``chunk`` fixes the number of points per batch): in this process when ``cluster`` is None
    (each batch on ``threads`` threads, default every core), else one Dask task per batch (one
    thread each). ``task`` (a function like :func:`run_point`) runs the points one by one
    instead, a task of a few points each (:func:`chunks`). Each finished row is appended to
    ``rows.jsonl`` at once; the table is rewritten every few seconds and at the end (also after
    Ctrl-C or an error). With ``convergence``, once the points and their refined twins have run,
    the sensitivity twins of the points that failed the check run (``more(n)`` is told how many
    first). ``lanes=False``: the points of an in-process batch step one at a time, not as lanes
    (the same rows). Returns ``(rows of every point in order, number run now)``."""
    out = Path(sweep.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    done = read_rows(out)
    runs = sweep.runs()
    columns = sweep.columns()
    last_write = [time.monotonic()]
    n_run = 0

    def finish(row, fh):
        nonlocal n_run
        done[row['point_id']] = row
        fh.write(json.dumps(row, allow_nan=True) + '\n')
        fh.flush()
        os.fsync(fh.fileno())
        n_run += 1
        if progress is not None:
            progress(1)
        if on_row is not None:
            on_row(row)
        if time.monotonic() - last_write[0] > 5.0:
            write_table(out, sweep.table(done, runs), columns)
            last_write[0] = time.monotonic()

    def missing(runs):
        return list(dict((pid, o) for pid, o in runs if pid not in done).items())

    try:
        with (out / ROWS).open('a') as fh:
            _run_all(sweep, missing(runs), cluster, task, chunk, threads,
                     lambda row: finish(row, fh), lanes)
            if sweep.convergence is not None:      # the sensitivity twins of failed points
                runs = sweep.runs(done)
                todo = missing(runs)
                if todo and more is not None:
                    more(len(todo))
                _run_all(sweep, todo, cluster, task, chunk, threads,
                         lambda row: finish(row, fh), lanes)
    finally:
        rows = sweep.table(done, runs)
        write_table(out, rows, columns)
    return rows, n_run


def _run_all(sweep, todo, cluster, task, chunk, threads, finish, lanes=True):
    """Run ``todo`` (``(point_id, overrides)`` pairs) as :func:`execute` describes, calling
    ``finish(row)`` for each row as it completes."""
    if not todo:
        return

    def cut(workers, seconds=BATCH_SECONDS, threads=None, dearest=False):
        """The batches of ``todo`` (:func:`batches`), with ``dearest`` in the order of
        :func:`dearest_first` by their :func:`contact_cost`."""
        if task is not None:
            return chunks(todo, workers, chunk)
        scenes = [sweep.scene.with_overrides(list(o.items())) for _, o in todo]
        costs = [point_cost(sc) for sc in scenes]
        size = chunk
        if threads and not chunk:
            # batches stepped as lanes, one per thread at a time: as many points as the largest
            # lane group (solver.MAX_LANES), a small sweep in as many equal batches as threads.
            # The 1,024-point sweep of docs/sweeps.md on two threads, one run each in the same
            # minutes, took 24.8-26.4 s (44-46 s of CPU) in batches of 64 points against
            # 27.7-29.9 s (53-57 s) in batches of about 2 s of estimated work (35 points): a
            # lane group's rounds cost less per lane the more lanes share them
            from solver import MAX_LANES
            size = min(MAX_LANES, -(-len(todo) // threads))
        parts = batches(todo, workers, costs, [topology_of(o) for _, o in todo], size=size,
                        seconds=seconds)
        if not dearest:
            return parts
        cost = {pid: contact_cost(sc) for (pid, _), sc in zip(todo, scenes)}
        return dearest_first(parts, [sum(cost[pid] for pid, _ in b) for b in parts])

    if cluster is None:
        if task is not None:
            for pid, o in todo:
                finish(task(sweep.scene, o, pid))
        else:
            from solver import default_threads, on_threads
            n = threads or default_threads()
            if not lanes:
                for b in cut(None, seconds=BATCH_SECONDS * n):
                    run_points(sweep.scene, b, threads=n, on_row=finish, lanes=False)
                return
            # a batch per thread, each taking the next when done: one thread's set-up and
            # summaries (Python) overlap the other's steps, and no thread waits for another
            # (:func:`dearest_first`: the batches of the fastest shots go first)
            lock = threading.Lock()

            def locked(row):
                with lock:
                    finish(row)
            for ok, value in on_threads(
                    lambda b: run_points(sweep.scene, b, threads=1, on_row=locked),
                    cut(None, threads=n, dearest=True), n):
                if not ok:
                    raise value
        return
    from distributed import as_completed
    # the scene (about 1 kB pickled) travels inside each task: scattered data lives only on the
    # workers that hold it and is lost for good when they die, a task's arguments go again with
    # its retry
    scene = sweep.scene
    futures = {}
    for b in cut(cluster.n_workers):
        items = list(b)
        key = f'points-{b[0][0]}-{len(b)}'
        fut = (cluster.client.submit(run_batch, task, scene, items, key=key, pure=False)
               if task is not None
               else cluster.client.submit(run_points, scene, items, key=key, pure=False))
        futures[fut] = b
    try:
        for fut in as_completed(futures):
            try:
                rows = fut.result()
            except Exception as exc:    # noqa: BLE001 - e.g. KilledWorker
                reason = f'{type(exc).__name__}: {exc}'.splitlines()[0]
                rows = [{'point_id': pid, **o, **empty_figures(), 'status': 'error',
                         'reason': reason} for pid, o in futures[fut]]
            for row in rows:
                finish(row)
    finally:
        for fut in futures:
            if not fut.done():
                fut.cancel()


# -- the command ----------------------------------------------------------------------------------
def build(scene_path, grids, samples=None, seed=0, out=None, t_end=None, convergence=None,
          convergence_figures=None):
    """A validated :class:`Sweep` from the command's options (raises :class:`SweepError` or
    :class:`solver.build.scene.SceneError`, nothing run). ``convergence_figures`` (names, or one
    comma-separated string) implies ``convergence`` 0.01 when it is None."""
    if convergence_figures is not None:
        from solver import check_figures
        convergence_figures = check_figures(convergence_figures, error=SweepError)
        if convergence is None:
            from solver import TOLERANCE
            convergence = TOLERANCE
    if convergence is not None:
        from solver import check_tolerance
        check_tolerance(convergence, error=SweepError)
    from solver import Scene
    scene = Scene.load(scene_path)
    if not grids:
        raise SweepError('sweep: give at least one --grid KEY=...')
    axes = [parse_axis(g) for g in grids]
    pts = points(axes, samples=samples, seed=seed)
    extra = {} if t_end is None else {'run.t_end': t_end}
    validate_points(scene, pts, extra, convergence)
    out_dir = Path(out) if out else Path('runs') / 'sweeps' / scene.name
    return Sweep(scene, pts, out_dir, [a.key for a in axes], extra, convergence,
                 convergence_figures)


def main(args):
    """``tensegrity sweep``: returns the exit code."""
    if args.workers is not None and args.workers < 1:
        raise SweepError(f'--workers: must be >= 1, got {args.workers}')
    dashboard_option(args)
    tolerance = getattr(args, 'convergence', None)
    figures = getattr(args, 'convergence_figures', None)
    checked = tolerance is not None or figures is not None
    plottable = FIGURES + (('convergence.change',) if checked else ())
    if args.plot and args.plot not in plottable:
        raise SweepError(f'--plot {args.plot}: unknown figure (one of {", ".join(plottable)})')
    sweep = build(args.scene, args.grid, samples=args.samples, seed=args.seed, out=args.out,
                  t_end=args.t_end, convergence=tolerance, convergence_figures=figures)
    out = Path(sweep.out_dir)
    done = read_rows(out)
    n_todo = len({pid for pid, _ in sweep.runs(done)} - set(done))
    cluster = None
    close = (lambda: None)
    try:
        # one machine: the batched runner's threads in this process (no cluster to start; see
        # docs/sweeps.md), a LocalCluster only when --workers asks for processes
        if n_todo and (args.scheduler or (args.workers or 1) > 1):
            cluster = Cluster(workers=args.workers, address=args.scheduler,
                              dashboard=dashboard_option(args))
            cluster.report_dashboard()
        update, grow, close = growing_bar(n_todo, 'sweep')
        rows, n_run = execute(sweep, cluster, progress=update, more=grow,
                              threads=1 if args.workers == 1 else None)
    finally:
        close()
        if cluster is not None:
            cluster.close()
    counts = {s: sum(r['status'] == s for r in rows) for s in ('ok', 'diverged', 'error')}
    run_ids = {pid for pid, _ in sweep.runs(read_rows(out))}
    twins = ''
    if sweep.convergence is not None:
        which = ('refined twins' if len(run_ids) == 2 * len(sweep.points)
                 else 'refined and sensitivity twins')
        twins = f', {len(run_ids)} runs with the {which}'
    already = len(run_ids) - n_run
    print(f'{len(rows)} points{twins} ({n_run} run now, {already} already in {out}): '
          f'{counts["ok"]} ok, {counts["diverged"]} diverged, {counts["error"]} error')
    if sweep.convergence is not None:
        print('  ' + convergence_report(rows, sweep.convergence, sweep.keys))
    print(f'  table: {out / TABLE}, {out / CSV}')
    if args.plot:
        from tensegrity_ros.studies.plots import sweep_map
        print(f'  plot: {sweep_map(rows, sweep.keys, args.plot, out / f"{args.plot}.png")}')
    return 0
