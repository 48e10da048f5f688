"""Batched runs: B independent simulations stepped on a pool of threads (the compiled kernels
release the GIL, so the instances of a batch step on every core at once).

    batch = BatchSimulation.of([scene_a, scene_b, scene_c])
    for i in range(batch.size):
        batch[i].apply_impact(0.1)
    batch.advance(0.005)                # every running instance, in parallel
    batch.status                        # ['running', 'diverged', 'running']

Each instance is a :class:`~solver.simulate.simulation.Simulation` (or an
:class:`~solver.simulate.array.ArraySimulation`) of its own scene: geometry, masses, prestrains,
impacts, contact and damping parameters may differ. Every instance has its own status: one whose
step diverges (or fails) stops, keeps its state, and is reported (``status`` ``diverged`` or
``error``, ``reasons`` its one-line message) while the others go on. What instances of one
network topology share is built once: while a batch builds its instances the memo of
:mod:`solver.build.memo` is on (the sym3d reduction, the grouping of the topology's member
orbits, the reduced bar-contact pairs).

:func:`simulate_batch` is :func:`solver.simulate.runner.simulate` for a list of (scene,
overrides) points: per point the same :func:`~solver.simulate.runner.summary`, or the status and
reason of a point that diverged or failed. Without ``frames`` it records only what the summary
reads (lean recording: no positions, no cable tensions); the figures are the same. A batch of one
point is the single run. By default its points of one model step together as lanes
(:mod:`solver.simulate.lanebatch`), each through the intervals before its next impact or its end
in calls of up to :data:`CHUNK` intervals (fewer where their data would pass :data:`CHUNK_BYTES`:
:meth:`BatchSimulation.advance_intervals`); with
``lanes=False`` its threads take the points one after another, each run to its end, so that one
thread's set-up and summary (Python) overlap another's steps (compiled). Every figure is the same
either way, bit for bit.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass


from solver.build.scene import Scene
from solver.build import memo
from solver.simulate import lanebatch, lanebulk
from solver.simulate.array import simulation_for
from solver.simulate.parallel import default_threads, each as parallel_each
from solver.simulate.runner import ImpactTrain, Point, Recorder, summary
from solver.simulate.simulation import SimulationDiverged

RUNNING, OK, DIVERGED, ERROR = 'running', 'ok', 'diverged', 'error'
# the most output intervals a lane group takes in one call (simulate_batch): over many intervals
# the lanes' step counts even out (a lane in contact takes ten times the steps of one that is
# not, and which lane that is changes from interval to interval). A call waits for its slowest
# lane: in two 64-point batches of the 1,024-point sweep (docs/sweeps.md, 200 intervals a
# point) the lanes' steps were 0.73-0.95 of the slowest lane's in calls of 40 intervals, 0.89 and
# 0.94 in one call of 200; three batches took 0.91-1.00 of the time on one thread (four runs
# each, alternating: the machine's noise is of that order). The call keeps every lane's data at
# each interval's end, about 10 kB a lane for the FB column: at most CHUNK_BYTES in all
CHUNK = 200
CHUNK_BYTES = 256 << 20


def reason_of(exc):
    """The one-line reason of a failed instance (as a sweep row gives it)."""
    if isinstance(exc, SimulationDiverged):
        return str(exc).splitlines()[0]
    return f'{type(exc).__name__}: {exc}'.splitlines()[0]


class BatchSimulation:
    """B independent simulations (``sims``) stepped together on ``threads`` threads (default:
    every core; 1: in the calling thread). ``status[i]`` is ``running``, ``diverged`` or
    ``error`` (``reasons[i]``, ``errors[i]`` the exception); a stopped instance is left out of
    every later :meth:`advance` and :meth:`each`."""

    def __init__(self, sims, threads=None, lanes=True):
        self.sims = list(sims)
        self.threads = max(1, int(threads or default_threads()))
        n = len(self.sims)
        self.status = [RUNNING] * n
        self.reasons = [''] * n
        self.errors = [None] * n
        self.lanes = bool(lanes)
        self._plan = None           # (indices, lanebatch.Plan) of the last lane step

    @classmethod
    def of(cls, scenes, threads=None, lanes=True):
        """A batch of one simulation per scene (:func:`~solver.simulate.array.simulation_for`),
        what scenes of one topology share built once."""
        with memo.sharing():
            return cls([simulation_for(s) for s in scenes], threads, lanes)

    @property
    def size(self):
        return len(self.sims)

    def __len__(self):
        return len(self.sims)

    def __getitem__(self, i):
        return self.sims[i]

    @property
    def running(self):
        """Indices of the instances still running."""
        return [i for i, s in enumerate(self.status) if s == RUNNING]

    def stop(self, i, exc):
        """Stop instance ``i`` with the exception ``exc`` (``diverged`` for a
        :class:`SimulationDiverged`, else ``error``)."""
        self.status[i] = DIVERGED if isinstance(exc, SimulationDiverged) else ERROR
        self.reasons[i] = reason_of(exc)
        self.errors[i] = exc

    def each(self, fn, indices=None):
        """``fn(i, sim)`` for every running instance (or those of ``indices`` still running), on
        the threads (:func:`solver.simulate.parallel.each`: one share of the instances per
        thread). An exception stops its instance (:meth:`stop`). Returns ``{i: result}`` of the
        instances that did not stop."""
        todo = [i for i in (self.running if indices is None else indices)
                if self.status[i] == RUNNING]
        out = {}
        for i, (ok, value) in zip(todo, parallel_each(lambda i: fn(i, self.sims[i]), todo,
                                                      self.threads)):
            if ok:
                out[i] = value
            else:
                self.stop(i, value)
        return out

    def advance(self, duration):
        """Advance every running instance by ``duration`` s
        (:meth:`~solver.simulate.simulation.Simulation.advance`); an instance that diverges is
        restored to its last good state and stops. Returns ``{i: steps}`` of the others.

        With :attr:`lanes` (the default) the instances that can step as lanes of one model
        (:mod:`solver.simulate.lanebatch`: the same topology, constants, ``dt`` and integrator)
        step together in one compiled call per group, a group per thread; each lane takes the
        steps of its single run, so the results are the same bit for bit."""
        todo = self.running
        if self.lanes and len(todo) > 1:
            sims = [self.sims[i] for i in todo]
            plan = self._lane_plan(todo, sims)
            if plan.groups:
                return self._advance_lanes(duration, todo, sims, plan)
        return self.each(lambda i, sim: sim.advance(duration), todo)

    def advance_intervals(self, counts, duration, visit, spent, many=None):
        """``counts[i]`` intervals of ``duration`` s of each running instance ``i`` of
        ``counts``, each followed by ``visit(i, q)`` (``q``: the interval, from 0) with the
        instance's state at that interval's end; with ``many``, a lane's intervals that
        :func:`solver.simulate.lanebulk.conclude` concludes at once are followed by one
        ``many(i, lean)`` instead. An instance that diverges or fails in an
        interval or its visit stops there. ``spent[i]`` is set to the (wall s, thread CPU s) of
        the instance's steps not yet reported, before each visit that follows them.

        With :attr:`lanes`, the instances that step as lanes of one group take all their
        intervals in one compiled call per group
        (:meth:`~solver.simulate.lanebatch.LaneGroup.chunk`), the groups on the threads, then
        are concluded and visited interval by interval (the same steps, checks and results as
        interval by interval); the others take their intervals one at a time on the threads."""
        todo = [i for i in counts if self.status[i] == RUNNING]
        sims = [self.sims[i] for i in todo]
        plan = (self._lane_plan(todo, sims) if self.lanes and len(todo) > 1
                else lanebatch.Plan([], sims, 0))
        index = {id(s): i for i, s in zip(todo, sims)}

        def work(task):
            is_group, item = task
            if not is_group:
                return self._intervals(index[id(item)], counts, duration, visit, spent)
            n = max(int(round(duration / item.sims[0].dt)), 0)
            most = max(1, min(CHUNK, CHUNK_BYTES // sum(a.nbytes for a in item.S)))
            which = [index[id(s)] for s in item.sims]
            left = {i: counts[i] for i in which}
            while any(left.values()):       # calls of at most `most` intervals
                part = {i: min(c, most) if self.status[i] == RUNNING else 0
                        for i, c in left.items()}
                t0, c0 = time.perf_counter(), time.thread_time()
                ch = item.chunk(n, [part[i] for i in which])
                share = ((time.perf_counter() - t0) / len(which),
                         (time.thread_time() - c0) / len(which))
                lanebulk.conclude_chunk(item, n, ch, which, part, visit, spent, share,
                                        lambda i: self.status[i] == RUNNING, self.stop, many)
                left = {i: c - part[i] for i, c in left.items()}
        tasks = [(True, g) for g in plan.groups] + [(False, s) for s in plan.singles]
        for ok, value in parallel_each(work, tasks, self.threads if len(tasks) > 1 else 1):
            if not ok:
                raise value         # a group's call itself failed: not a lane's divergence

    def _intervals(self, i, counts, duration, visit, spent):
        """:meth:`advance_intervals` of instance ``i`` one interval at a time."""
        sim = self.sims[i]
        for q in range(counts[i]):
            try:
                t0, c0 = time.perf_counter(), time.thread_time()
                sim.advance(duration)
                spent[i] = (time.perf_counter() - t0, time.thread_time() - c0)
                visit(i, q)
            except Exception as exc:                # noqa: BLE001 - this instance stops
                self.stop(i, exc)
                return

    def _lane_plan(self, todo, sims):
        """The :class:`~solver.simulate.lanebatch.Plan` of the instances ``todo``, kept while
        they are the same and the plan holds."""
        if self._plan is None or self._plan[0] != todo or not self._plan[1].holds():
            self._plan = (todo, lanebatch.plan_of(sims, self.threads))
        return self._plan[1]

    def _advance_lanes(self, duration, todo, sims, plan):
        step = lanebatch.Step(plan, sims)
        step.run(duration, self.threads)
        out = {}
        for i, sim in zip(todo, sims):
            exc = step.error(sim)        # a lane or single that failed restored itself
            if exc is None:
                out[i] = step.result[id(sim)][1]
            else:
                self.stop(i, exc)
        return out

    def frames(self):
        """The :meth:`~solver.simulate.simulation.Simulation.frame` of every instance (stopped
        ones too: their last good state)."""
        return [s.frame() for s in self.sims]

    def close(self):
        """Nothing to release (the threads are the process's pool); a batch is a context manager
        for symmetry with other resources."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# -- the batched runner -------------------------------------------------------------------------
@dataclass
class BatchPoint:
    """One point of :func:`simulate_batch`: ``status`` ``ok``, ``diverged`` or ``error`` with a
    one-line ``reason``; for ``ok`` the :class:`~solver.simulate.runner.Point` (``point``, its
    ``summary``), else None. ``task_wall_s``: the point's share of the batch's wall time (its
    build, its steps and records on its thread, its summary); ``cpu_time_s`` the CPU time of
    the same (thread CPU time)."""
    status: str
    reason: str = ''
    point: Point | None = None
    task_wall_s: float = 0.0
    cpu_time_s: float = 0.0
    error: BaseException | None = None       # the exception of a point that did not finish

    @property
    def summary(self):
        return None if self.point is None else self.point.summary


class _Run(Recorder):
    """One instance's run to ``run.t_end`` (:class:`~solver.simulate.runner.Recorder`, the
    steps of :func:`solver.simulate.runner.run`), one output interval at a time; ``busy`` and
    ``cpu`` the wall and thread CPU time of its intervals."""

    def __init__(self, scene, sim, frames, on_frame, base=True):
        super().__init__(sim, scene.run.t_end, scene.run.output_dt,
                         ImpactTrain(scene.loading.impact, sim.dt), on_frame=on_frame,
                         frames=frames, base=base)
        self.scene = scene
        self.busy = 0.0
        self.cpu = 0.0
        self.point = None

    def _timed(self, work, *args):
        t0, c0 = time.perf_counter(), time.thread_time()
        try:
            work(*args)
        finally:
            self.busy += time.perf_counter() - t0
            self.cpu += time.thread_time() - c0

    def start(self):
        self._timed(super().start)

    def interval(self, k):
        self._timed(super().interval, k)

    def stepped(self, spent):
        """Book the ``(wall s, thread CPU s)`` of steps the batch took for this run
        (:meth:`BatchSimulation.advance_intervals`); :meth:`take_frame` follows."""
        self.wall += spent[0]
        self.busy += spent[0]
        self.cpu += spent[1]

    def take_frame(self):
        """:meth:`record`, timed: the end of an interval the batch stepped."""
        self._timed(self.record)

    def take_frames(self, lean):
        """:meth:`record_many`, timed: the ends of intervals the batch stepped."""
        self._timed(self.record_many, lean)


def _prepare(scene, overrides):
    if not isinstance(scene, Scene):
        scene = Scene.load(scene)
    overrides = list(overrides)
    if overrides:
        scene = scene.with_overrides(overrides)
    return scene, simulation_for(scene)


def simulate_batch(items, threads=None, frames=False, on_frame=None, on_point=None,
                   together=False, base=True, lanes=True):
    """:func:`solver.simulate.runner.simulate` of every ``(scene, overrides)`` of ``items`` (a
    scene is a :class:`Scene` or a path; overrides as for ``simulate``), as one batch on
    ``threads`` threads. Returns a :class:`BatchPoint` per item, in order: ``ok`` with the
    point's summary (equal to the single run's), or ``diverged`` / ``error`` with the one-line
    reason (a point whose scene or simulation cannot be built is an ``error``; the others run
    on). ``frames``: record full frames (:meth:`Simulation.frame`) instead of the lean record;
    ``on_frame(index, frame)`` gets every frame of every point (then frames are full; called on
    the batch's threads). ``on_point(index, batch_point)`` is called as each point finishes (one
    call at a time; an exception from it stops the batch after the points running and is
    raised).

    By default (``lanes``, more than one point) every point is set up first, then the points
    advance together (a :class:`BatchSimulation`): those of one model as lanes, many intervals
    per call, the others one interval at a time. With ``lanes=False`` each thread takes the next
    point not yet taken and runs it to its end (set-up, steps, summary), and points finish one by
    one; ``together=True`` then sets every point up first and steps them one interval at a time.
    The figures are the same every way.

    ``base=False`` (lean records only) leaves out the base force, the costliest figure of a frame
    (a force evaluation of the full network): the summary's ``base`` is then ``[]``, every other
    figure the same (sweep rows and fits do not read it)."""
    items = list(items)
    out = [None] * len(items)
    lock = threading.Lock()
    stopped = []

    def deliver(k, bp):
        with lock:
            out[k] = bp
            if on_point is not None and not stopped:
                try:
                    on_point(k, bp)
                except BaseException:
                    stopped.append(True)
                    raise

    with memo.sharing():
        if together or (lanes and len(items) > 1):
            _together(items, threads, (frames, base), on_frame, deliver, lanes)
        else:
            def one(k):
                if stopped:
                    return
                bp = _point(k, items[k], (frames, base), on_frame)
                deliver(k, bp)

            for ok, value in parallel_each(one, range(len(items)), threads):
                if not ok:
                    raise value
    return out


def _set_up(k, item, record, on_frame):
    """``(run, None)`` of item ``k``, or ``(None, error BatchPoint)``; the time it took.
    ``record``: ``(frames, base)`` of :func:`simulate_batch`."""
    t0, c0 = time.perf_counter(), time.thread_time()
    try:
        scene, overrides = item
        sc, sim = _prepare(scene, overrides)
        cb = None if on_frame is None else (lambda f: on_frame(k, f))
        frames, base = record
        run = _Run(sc, sim, frames, cb, base=base or frames or cb is not None)
        bp = None
    except Exception as exc:                        # noqa: BLE001 - a failed point, not a crash
        run, bp = None, BatchPoint(ERROR, reason_of(exc), error=exc)
    return run, bp, time.perf_counter() - t0, time.thread_time() - c0


def _summarise(run):
    """The ``ok`` point of ``run`` (its pulses and summary)."""
    t0, c0 = time.perf_counter(), time.thread_time()
    rec = run.record_of()
    run.point = Point(run.scene, run.sim, rec, summary(run.scene, run.sim, rec))
    run.busy += time.perf_counter() - t0
    run.cpu += time.thread_time() - c0


def _point(k, item, record, on_frame):
    """The :class:`BatchPoint` of item ``k`` run to its end in this thread."""
    run, bp, wall, cpu = _set_up(k, item, record, on_frame)
    if run is None:
        bp.task_wall_s, bp.cpu_time_s = wall, cpu
        return bp
    try:
        run.start()
        for i in range(run.n_out):
            run.interval(i)
        _summarise(run)
        bp = BatchPoint(OK, '', run.point)
    except Exception as exc:                        # noqa: BLE001 - its point stops
        bp = BatchPoint(DIVERGED if isinstance(exc, SimulationDiverged) else ERROR,
                        reason_of(exc), error=exc)
    bp.task_wall_s, bp.cpu_time_s = wall + run.busy, cpu + run.cpu
    return bp


def _together(items, threads, record, on_frame, deliver, lanes=True):
    """:func:`simulate_batch` with ``together=True``: every point set up, then the running
    points advanced together, each by its own intervals (see ``advance``)."""
    runs, sims, index, build = [], [], [], {}
    for k, item in enumerate(items):
        run, bp, wall, cpu = _set_up(k, item, record, on_frame)
        build[k] = (wall, cpu)
        if run is None:
            bp.task_wall_s, bp.cpu_time_s = wall, cpu
            deliver(k, bp)
        else:
            runs.append(run)
            sims.append(run.sim)
            index.append(k)

    nxt = [-1] * len(runs)          # each run's next interval (-1: its start)

    def step(j):
        """The next interval of run ``j`` by itself (its start first)."""
        run, i = runs[j], nxt[j]
        if i < 0:
            run.start()
        else:
            run.interval(i)
        nxt[j] = i + 1
        if run.n_out == i + 1:
            _summarise(run)

    def recorded(j, take, count):
        """Run ``j``'s next ``count`` intervals were stepped by the batch: the steps' time
        booked, ``take()`` (their frames), and the summary after the last interval."""
        if j in spent:
            runs[j].stepped(spent.pop(j))
        take()
        nxt[j] += count
        if runs[j].n_out == nxt[j]:
            _summarise(runs[j])

    def visit(j, q):
        """Run ``j``'s next interval was stepped by the batch: its frame (and summary)."""
        recorded(j, runs[j].take_frame, 1)

    def many(j, lean):
        """Run ``j``'s next ``len(lean)`` intervals were stepped and concluded at once: their
        lean record (and summary)."""
        recorded(j, lambda: runs[j].take_frames(lean), len(lean))
    lean_only = all(not (r.frames or r.with_base) for r in runs)     # many() serves them

    def advance(live):
        """Every run of ``live`` through the intervals before its next impact (or its end) in
        one :meth:`BatchSimulation.advance_intervals` per interval length (lanes where they
        allow); a run with an impact in its next interval, or every run without ``lanes``,
        takes that one interval by itself."""
        counts = {j: min(runs[j].plain_intervals(), runs[j].n_out - nxt[j])
                  for j in live if nxt[j] >= 0} if lanes else {}
        counts = {j: c for j, c in counts.items() if c > 0}
        if len(counts) < 2:
            counts = {}
        batch.each(lambda j, sim: step(j), [j for j in live if j not in counts])
        by_duration = {}
        for j, c in counts.items():
            by_duration.setdefault(runs[j].per_frame * sims[j].dt, {})[j] = c
        for duration, part in by_duration.items():
            batch.advance_intervals(part, duration, visit, spent,
                                    many if lean_only else None)

    def finish(j):
        k, run = index[j], runs[j]
        if batch.status[j] == RUNNING:
            batch.status[j] = OK
            bp = BatchPoint(OK, '', run.point)
        else:
            bp = BatchPoint(batch.status[j], batch.reasons[j], error=batch.errors[j])
        bp.task_wall_s = build[k][0] + run.busy
        bp.cpu_time_s = build[k][1] + run.cpu
        deliver(k, bp)

    spent = {}
    with BatchSimulation(sims, threads, lanes) as batch:
        live = list(range(len(runs)))
        while live:
            advance(live)
            for j in live:
                if batch.status[j] != RUNNING or nxt[j] >= runs[j].n_out:
                    finish(j)
            live = [j for j in live if batch.status[j] == RUNNING and nxt[j] < runs[j].n_out]
