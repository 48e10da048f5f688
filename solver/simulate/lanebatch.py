"""Simulations of one model stepped together as lanes (:mod:`solver.integrators.rk4lanes`).

A :class:`LaneGroup` takes B :class:`~solver.simulate.simulation.Simulation` objects whose
models are alike (:func:`lane_key`: the same model class, the same constants record by value,
the same integrator settings) and steps them in one compiled call: each lane on its own clock,
with its own steps, exactly the steps its single run would take (bit for bit). The group owns
the data: each simulation's ``model.data`` is rebound to views of the group's lane-outer arrays,
so that its commands, frames and checks read and write the group's memory in place and the
call copies nothing in or out. A group notices when a simulation's model or data were replaced
(an expansion to ``full3d``, a reset of the model) and is then rebuilt by its owner
(:meth:`LaneGroup.bound`).

After the call the divergence checks run on the state summaries the call computed per lane,
all lanes at once (:func:`solver.simulate.lanebulk.conclude_call`); a simulation that fails them
concludes on its own (:meth:`Simulation._conclude`: the restore from the data the call kept and
the replay that names the failing step). One lane's failure leaves the others' results as they
are.

Lanes serve ``rk4_projected`` and ``rk4`` on exact models without the KKT system of massive bars
(:func:`eligible`); everything else steps one simulation at a time. Simulations whose prestrain
ramps run step as lanes of groups of their own where the caller asks for it (``ramps``: an
array's columns), each lane with its own ramp (:mod:`solver.integrators.rk4laneramp`).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from solver.compiled import compiled_overload
from solver.integrators import rk4laneramp, rk4lanes
from solver.kernels import lanechunk, lanedata, lanes as lanes_mod, ramp, records
from solver.simulate import lanebulk, parallel
from solver.simulate.simulation import StateSummary
from solver.status import OK

LANE_METHODS = ('rk4_projected', 'rk4')

# The largest group stepped in one call. One (n_nodes, 3, B) array of the full3d FB column at 64
# lanes is 235 kB, and a group holds about a dozen (the core's L2 cache: 1 MB).
# bench/results/lanes.json gives the cost of an evaluation per lane at 32, 64 and 128 lanes; it
# moves by about 0.1x of the scalar evaluation from run to run on a shared machine.
MAX_LANES = 64
SMALLEST = 2            # blocks of stragglers halve down to this many lanes


def eligible(sim, ramps=False):
    """Whether ``sim`` can step as a lane: an exact record model (not ``chain1d``), an
    integrator of :data:`LANE_METHODS`, no KKT system, no prestrain ramp running unless
    ``ramps``."""
    m = sim.model
    return (not m.integrates_itself and m.exact
            and (sim._ramp is None or (ramps and sim._ramp_record() is not None))
            and sim.integrator.name in LANE_METHODS
            and m.rec.topo.kkt.node_u.shape[0] == 0)


def _fingerprint(value):
    """A hashable summary of a record's constants by value (arrays by dtype, shape and bytes)."""
    if isinstance(value, np.ndarray):
        return (value.dtype.str, value.shape, value.tobytes())
    if isinstance(value, tuple):
        return tuple(_fingerprint(v) for v in value)
    return value


_NUMBERS: dict = {}         # fingerprint -> number
_RECORDS: dict = {}         # id(constants record) -> (record, its number)
_MAPS: dict = {}            # id(ramp record) -> (record, the number of its map)


def _number(obj, seen, value):
    """A number per distinct ``value(obj)`` (a fingerprint), computed once per object ``obj``
    (never edited) and kept in ``seen`` (id -> (object, number))."""
    hit = seen.get(id(obj))
    if hit is None or hit[0] is not obj:
        if len(seen) > 4096:
            seen.clear()
        hit = seen[id(obj)] = (obj, _NUMBERS.setdefault(value(obj), len(_NUMBERS)))
    return hit[1]


def _record_number(rec):
    """A number per distinct constants record, by value (a record is never edited:
    :mod:`solver.kernels.records`)."""
    return _number(rec, _RECORDS, _fingerprint)


def _map_number(rec):
    """A number per distinct prestrain map of :class:`~solver.kernels.ramp.Ramp` records (their
    shared fields, by value)."""
    return _number(rec, _MAPS, lambda r: ('ramp map', _fingerprint(ramp.shared_part(r))))


def lane_key(sim):
    """What simulations must share to step as lanes of one group: the model class, its
    constants (by value), the shapes of its data, ``dt``, the integrator's settings and,
    while a prestrain ramp runs, its map (by value)."""
    m = sim.model
    d = m.data
    return (type(m).__name__, _record_number(m.rec), d.x.shape, d.contact.scan.shape,
            d.contact.active.shape, sim.integrator.name, float(sim.dt), float(sim.tol),
            int(sim.max_iter), bool(sim.kinks), sim._heights_shape,
            None if sim._ramp is None else _map_number(sim._ramp_record()))


class LaneGroup:
    """B simulations of one :func:`lane_key` stepped together (see the module text); with
    ``ramps``, simulations whose prestrain ramps run (each its own, :attr:`R`)."""

    def __init__(self, sims, ramps=False):
        sims = list(sims)
        if not sims:
            raise ValueError('a lane group needs simulations')
        key = lane_key(sims[0])
        for s in sims:
            if not eligible(s, ramps) or lane_key(s) != key:
                raise ValueError('lane group: the simulations are not alike')
        self.sims = sims
        self._ramps = [s._ramp for s in sims]
        self._integrators = [s.integrator for s in sims]
        self.R = None if key[-1] is None else ramp.stack([s._ramp_record() for s in sims])
        self.Q = None if self.R is None else ramp.lane_rest(self.R)
        self._keeps = None              # a ramped call's Kept per simulation
        b = len(sims)
        m0 = sims[0].model
        self.rec = m0.rec
        d0 = m0.data
        n = d0.x.shape[0]

        def stack(get, dtype=np.float64):
            return np.ascontiguousarray(np.stack([get(s.model.data) for s in sims]), dtype=dtype)
        self.S = lanedata.LaneState(
            stack(lambda d: d.x), stack(lambda d: d.v), stack(lambda d: d.rest),
            stack(lambda d: d.EA), stack(lambda d: d.f_ext), stack(lambda d: d.ledger),
            stack(lambda d: d.contact.scan), stack(lambda d: d.contact.active, np.int64),
            stack(lambda d: d.refine), np.zeros((b, 2, n, 3)))
        self.kept = lanedata.LaneState(*(np.zeros_like(a) for a in self.S))
        self._kept = [self.record(self.kept, k) for k in range(b)]     # each lane's views
        self.blocks = [_Block(self.S, self.rec.topo, m0.work)]
        size = b
        while size > SMALLEST:          # fewer lanes for the stragglers: half as many
            size = (size + 1) // 2
            self.blocks.append(_Block(None, self.rec.topo, m0.work, like=self.S, lanes=size))
        self.out = np.zeros((b, 4))
        self._chunk = None              # the Chunk of the most intervals asked for so far
        self._fallen = [False] * b      # the simulations that left the last chunk
        self._entries = {}              # kernel -> its compiled overload for this group
        self._models = []
        self._data = []
        for k, s in enumerate(sims):
            data = self.record(self.S, k)
            s.model.data = data
            s._call = None
            s._changed()
            self._models.append(s.model)
            self._data.append(data)

    @staticmethod
    def record(S, k):
        """Lane ``k``'s :class:`~solver.kernels.records.Data`: views into ``S``."""
        return records.Data(S.x[k], S.v[k], S.rest[k], S.EA[k], S.f_ext[k], S.ledger[k],
                            records.ContactState(S.scan[k], S.active[k]), S.refine[k])

    def bound(self):
        """Whether every simulation still steps on this group's memory, alike and eligible,
        with the prestrain ramp (or none) it had when the group was made."""
        # the model, its data, the ramp and the integrator the group was made with: what
        # eligible() read of each then
        return all(s.model is m and m.data is d and s._ramp is r and s.integrator is i
                   for s, m, d, r, i in zip(self.sims, self._models, self._data, self._ramps,
                                            self._integrators))

    def _check_bound(self):
        if not self.bound():
            raise RuntimeError('lane group: a simulation left the group (rebuild it)')

    def advance(self, n):
        """Advance every simulation by ``n`` steps of ``dt`` in one call, then conclude each
        (:meth:`Simulation._conclude`). Returns ``[(ok, steps or exception)]`` per simulation,
        as :func:`solver.simulate.parallel.each` does; a simulation that failed restored itself
        to its state before the call."""
        self._check_bound()
        if n <= 0:
            return [(True, s.advance(0.0)) for s in self.sims]
        if self.R is not None:
            return self._advance_ramped(n)
        s0 = self.sims[0]
        top = self.blocks[0]
        top.status[:] = OK
        heights = np.empty((len(self.sims),) + s0._heights_shape)
        self._step(n, heights)
        return lanebulk.conclude_call(self, n, heights, top.steps, top.status)

    def _advance_ramped(self, n):
        """:meth:`advance` of simulations whose ramps run: their first ramped calls as lanes
        (:func:`solver.integrators.rk4laneramp.ramped`), concluded at once where a lane's call
        ended its interval (:func:`~solver.simulate.lanebulk.conclude_ramped`); any other
        simulation's interval goes on by itself from where its call stopped."""
        sims, R, top = self.sims, self.R, self.blocks[0]
        s0, b = sims[0], len(sims)
        top.status[:] = OK
        self.call(lanedata.keep, (top.S, self.kept, top.status))     # what a failure restores
        self._keeps = [s._kept(d, s.integrator.get_state()) for s, d in zip(sims, self._kept)]
        R.clock[:] = [(s.t, s._ramp.t0, s._ramp.duration, s.dt) for s in sims]
        R.book[:] = [(s._energy_ref, s._energy_scale) for s in sims]
        st, steps, done, taken, went, made = np.zeros((6, b), np.int64)
        heights = np.empty((b,) + s0._heights_shape)
        self.call(rk4laneramp.ramped, (
            self.rec, top.S, top.L, top.W, top.X, top.C, top.w0, float(s0.dt), int(n),
            float(s0.tol), int(s0.max_iter), bool(s0.kinks), bool(s0.integrator.projected), R,
            NO_CHUNK, top.status, st, steps, done, taken, went, made, self.out, heights, self.Q))
        return lanebulk.conclude_ramped(self, n, heights, (done, taken, went, made))

    def _step(self, n, heights):
        """The compiled call of :meth:`advance`: the lanes step together while at least half of
        them still step; the stragglers then move to a block of fewer lanes (the next
        :class:`_Block`), and back when they are done, so that a few lanes in long contact do
        not cost the vector work of all of them."""
        s0 = self.sims[0]
        dt = float(s0.dt)
        total = n * dt
        fixed = (dt, total, float(s0.tol), int(s0.max_iter), bool(s0.kinks),
                 bool(s0.integrator.projected))
        top = self.blocks[0]
        self.call(rk4lanes.begin_checked, (self.rec, top.S, top.L, top.C, top.status,
                                             top.steps, self.kept))
        chain = []                      # (block, its lanes' slots in the block above)
        block = top
        for smaller in self.blocks[1:] + [None]:
            left = block.rounds(self.rec, fixed, 0 if smaller is None else smaller.lanes + 1)
            if left == 0:
                break
            alive = np.flatnonzero((block.status == OK) & (total - block.C.t > 1e-9 * dt))
            smaller.take(block, alive)
            chain.append((block, alive))
            block = smaller
        for above, alive in reversed(chain):
            block.give(above, alive)
            block = above
        self.call(rk4lanes.end_checked, (self.rec, top.S, top.L, top.W, top.C, top.status,
                                           self.out, heights, not chain))

    def chunk(self, n, todo):
        """``todo[k]`` intervals of ``n`` steps of simulation ``k`` in one compiled call
        (:func:`solver.integrators.rk4lanes.chunk_run`), none of them concluded yet: returns the
        :class:`~solver.kernels.lanechunk.Chunk`, for :meth:`conclude` interval by interval."""
        self._check_bound()
        if self.R is not None:
            raise RuntimeError('lane group: a chunk of ramped lanes')
        s0, top = self.sims[0], self.blocks[0]
        top.status[:] = np.where(np.asarray(todo) > 0, OK, NOT_A_LANE)     # 0: left as is
        k_max = max(todo)
        ch = self._chunk        # one of more intervals serves: the lanes' todo say how many
        if ch is None or ch.out.shape[0] < k_max:
            ch = self._chunk = lanechunk.chunk(self.S, k_max, s0._heights_shape)
        ch.todo[:] = todo
        self._fallen = [False] * len(self.sims)
        self.call(rk4lanes.chunk_run, (self.rec, top.S, top.L, top.W, top.X, top.C, top.w0,
                                        float(s0.dt), int(n), float(s0.tol), int(s0.max_iter),
                                        bool(s0.kinks), bool(s0.integrator.projected),
                                        top.status, top.steps, ch))
        return ch

    def conclude(self, k, j, n, ch):
        """Interval ``j`` of simulation ``k`` from the :meth:`chunk` ``ch``, concluded as its own
        call would be (:meth:`Simulation._conclude`: checked, the clock moved, or restored and
        :class:`SimulationDiverged` raised): its data set to the interval's end first. Where its
        lane failed within the interval, the simulation takes that interval by itself
        (:meth:`Simulation.advance`, which fails as the lane did), and its later ones too."""
        s = self.sims[k]
        if self._fallen[k] or j >= ch.done[k]:
            if not self._fallen[k]:
                self._fallen[k] = True
                self.call(records.copy_data, (_chunk_data(ch, j, k), s.model.data))
            return s.advance(n * s.dt)
        self.to_end(k, j, ch)
        # the interval's start is read only on a failure (to restore it)
        return s._conclude(n, int(ch.steps[j, k]), OK, lambda: _chunk_data(ch, j, k), None)

    def to_end(self, k, j, ch):
        """Simulation ``k``'s data and summary at the end of interval ``j`` of chunk ``ch``."""
        s = self.sims[k]
        self.call(records.copy_data, (_chunk_data(ch, j + 1, k), s.model.data))
        o = ch.out[j, k]
        s._cache = {'summary': StateSummary(o[0] != 0.0, o[1], ch.heights[j, k].copy(), o[2],
                                            o[3])}

    def call(self, kernel, args):
        """``kernel(*args)`` through numba's dispatch the first time, then through the compiled
        overload (the arguments are this group's arrays, or new ones of the same types)."""
        entry = self._entries.get(kernel)
        if entry is None:
            out = kernel(*args)
            self._entries[kernel] = compiled_overload(kernel, args) or kernel
            return out
        return entry(*args)

    def restore(self, k, before):
        """Back to the data the last call started from, for simulation ``k`` that concluded its
        interval (an array restores every column when one fails); ``before``: its
        ``(t, step, steps_taken, energy scale, twist reference)`` before the call."""
        s = self.sims[k]
        s._restore(s._kept(self._kept[k], None) if self.R is None else self._keeps[k])
        s.t, s.step, s.steps_taken, s._energy_scale, s._twist_ref = before


class _Block:
    """One set of lanes and its scratch: ``S`` (the group's memory for the first block; a
    block of ``lanes`` stragglers shaped ``like`` it otherwise), the lane-inner copies ``L``,
    scratch ``W``, ``X``, ``w0``, the step control ``C``, each lane's ``status`` and
    ``steps``."""

    def __init__(self, S, topo, work, like=None, lanes=None):
        if S is None:
            S = lanedata.LaneState(*(np.zeros((lanes,) + a.shape[1:], a.dtype) for a in like))
        self.S = S
        self.lanes = b = S.x.shape[0]
        n, nc = S.x.shape[1], S.rest.shape[1]
        self.L = lanes_mod.LaneData(np.zeros((n, 3, b)), np.zeros((n, 3, b)),
                                    np.zeros((nc, b)), np.zeros((nc, b)), np.zeros((n, 3, b)))
        self.W = lanes_mod.lane_work(topo, n, b)
        self.X = lanedata.LaneScratch(np.zeros((b, n, 3)))
        self.C, self._floats, self._ints = rk4lanes.lane_control(b)
        self.w0 = records.clone_work(work)
        self.status = np.zeros(b, np.int64)
        self.steps = np.zeros(b, np.int64)
        self._entry = self._mover = None

    def rounds(self, rec, fixed, min_live):
        """:func:`solver.integrators.rk4lanes.rounds` on this block's lanes."""
        dt, total, tol, max_iter, kinks, project = fixed
        args = (rec, self.S, self.L, self.W, self.X, self.C, self.w0, dt, total, tol, max_iter,
                kinks, project, self.status, self.steps, int(min_live), NO_CHUNK)
        if self._entry is None:         # through numba's dispatch, then its compiled overload
            left = rk4lanes.rounds(*args)
            self._entry = compiled_overload(rk4lanes.rounds, args) or rk4lanes.rounds
            return left
        return self._entry(*args)

    def take(self, above, alive):
        """Move the lanes ``alive`` of the block ``above`` into the first lanes of this one;
        the others here do not step."""
        m = len(alive)
        above.move(self, alive, np.arange(m))
        self.status[m:] = NOT_A_LANE
        lanedata.enter(self.S, self.L)

    def give(self, above, alive):
        """Move the lanes taken by :meth:`take` back into the block ``above``."""
        self.move(above, np.arange(len(alive)), alive)

    def move(self, b, src, dst):
        """This block's lanes ``src`` into lanes ``dst`` of block ``b``
        (:func:`solver.kernels.lanedata.move`; through its compiled overload after the first)."""
        args = (self.S, self._floats, self._ints, self.X.a1, self.status, self.steps, b.S,
                b._floats, b._ints, b.X.a1, b.status, b.steps, np.asarray(src, np.int64),
                np.asarray(dst, np.int64))
        if self._mover is None:
            lanedata.move(*args)
            self._mover = compiled_overload(lanedata.move, args) or lanedata.move
        else:
            self._mover(*args)


NOT_A_LANE = -99        # the status of an empty lane of a block of stragglers


NO_CHUNK = lanechunk.empty()


def _chunk_data(ch, j, k):
    """Lane ``k``'s data at entry ``j`` of the chunk ``ch`` (views)."""
    e = ch.data
    return records.Data(*(a[j, k] for a in e[:6]),
                        records.ContactState(e.scan[j, k], e.active[j, k]), e.refine[j, k])


def clock_of(sim):
    """What :meth:`LaneGroup.restore` puts back besides the data."""
    return sim.t, sim.step, sim.steps_taken, sim._energy_scale, sim._twist_ref


class Step:
    """One interval of every simulation of ``sims`` (split by ``plan``, a :class:`Plan`): the
    lane groups and the single simulations on threads, each simulation's result kept, and
    what restores every one of them when one failed (an array of columns fails as a whole)."""

    def __init__(self, plan, sims):
        self.plan, self.sims = plan, sims
        self.before = {id(s): clock_of(s) for s in sims}
        self.keeps = {id(s): s._keep() for s in plan.singles}
        self.result = {}            # id(sim) -> (ok, steps or exception)
        self.where = {}             # id(sim) -> (lane group, lane)

    def run(self, duration, threads):
        """Advance each simulation by ``duration`` s on ``threads`` threads (a group by the
        whole steps of its ``dt`` that :meth:`Simulation.advance` would take)."""
        tasks = [(True, g) for g in self.plan.groups] + [(False, s) for s in self.plan.singles]

        def work(task):
            is_lanes, item = task
            if is_lanes:
                return item.advance(max(int(round(duration / item.sims[0].dt)), 0))
            return item.advance(duration)
        done = parallel.each(work, tasks, threads if len(tasks) > 1 else 1)
        for (is_lanes, item), (ok, value) in zip(tasks, done):
            if not is_lanes:
                self.result[id(item)] = (ok, value)
                continue
            if not ok:
                raise value         # the group's call itself failed: not a lane's divergence
            for k, (s, r) in enumerate(zip(item.sims, value)):
                self.result[id(s)] = r
                self.where[id(s)] = (item, k)

    def error(self, sim):
        """The exception of ``sim``'s interval, or None."""
        ok, value = self.result[id(sim)]
        return None if ok else value

    def most_steps(self):
        return max(v for _, v in self.result.values())

    def restore(self):
        """Every simulation that concluded its interval back to its start (one that failed
        restored itself)."""
        for s in self.sims:
            if not self.result[id(s)][0]:
                continue
            if id(s) in self.where:
                group, k = self.where[id(s)]
                group.restore(k, self.before[id(s)])
            else:
                s._restore(self.keeps[id(s)])
                s.t, s.step, s.steps_taken = self.before[id(s)][:3]


class Plan(NamedTuple):
    """Simulations split by :func:`groups_of`: the lane ``groups`` (:class:`LaneGroup`), the
    ``singles`` that step one at a time, and how many of those were :func:`eligible`
    (``n_eligible``)."""
    groups: list
    singles: list
    n_eligible: int
    ramps: bool = False

    def holds(self):
        """Whether the split still holds: every group bound (:meth:`LaneGroup.bound`) and as
        many singles eligible as when it was made (a column whose prestrain ramp ended can join
        a group again)."""
        return (all(g.bound() for g in self.groups)
                and sum(eligible(s, self.ramps) for s in self.singles) == self.n_eligible)


def plan_of(sims, threads=1, ramps=False):
    """The :class:`Plan` of ``sims`` (:func:`groups_of`), lane groups built."""
    lists, singles = groups_of(sims, threads, ramps=ramps)
    return Plan([LaneGroup(x, ramps) for x in lists], singles,
                sum(eligible(s, ramps) for s in singles), ramps)


def groups_of(sims, threads=1, max_lanes=MAX_LANES, min_lanes=2, ramps=False):
    """Split ``sims`` into lists that step as lane groups (alike and eligible, at most
    ``max_lanes`` a list, in the given order within a key; a key with more than ``threads``
    times ``min_lanes`` members is cut into at least ``threads`` lists, so that every thread
    steps one; ``ramps``: simulations whose prestrain ramps run too, in groups of their own)
    and the rest, which step one at a time. Returns ``(lane lists, singles)``."""
    by_key = {}
    singles = []
    for s in sims:
        if eligible(s, ramps):
            by_key.setdefault(lane_key(s), []).append(s)
        else:
            singles.append(s)
    lists = []
    for members in by_key.values():
        n = len(members)
        if n < 2:
            singles.extend(members)
            continue
        n_lists = max(-(-n // max_lanes), min(max(int(threads), 1), n // min_lanes), 1)
        size = -(-n // n_lists)
        for i in range(0, n, size):
            part = members[i:i + size]
            if len(part) > 1:
                lists.append(part)
            else:
                singles.extend(part)
    return lists, singles
