"""A lane group's intervals concluded for all its lanes at once: one call's interval for every
lane (:func:`conclude_call`, :meth:`solver.simulate.lanebatch.LaneGroup.advance`: arrays, the
node; :func:`conclude_ramped`, the call of ramping lanes), and the intervals of a chunk, lane
by lane, for the lean records of sweeps and fits
(:meth:`solver.simulate.batch.BatchSimulation.advance_intervals`).

Concluding one interval at a time (:meth:`solver.simulate.lanebatch.LaneGroup.conclude`, then
the run's :meth:`~solver.simulate.runner.Recorder.record`) runs about 35 us of Python a point and
interval, one thread at a time (the GIL), while the compiled lane steps of a 64-point batch cost
about 70-340 us a point and interval. Here the figures of every interval a lane finished
are computed at once, from the chunk's state summaries and ledgers, with the operations the
single interval does, element by element (so the same values, bit for bit): the divergence
check of :meth:`Simulation._check`, the energy scale, the clock, the frame figures of the lean
record. The intervals up to the first one that fails a check are concluded so; from that one
on the lane goes on one interval at a time (which restores, raises and names the step as the
single run does). A simulation whose check needs its full state (the prisms' twists:
``divergence.bar_crossing``), or a run that records more than the lean figures, goes one
interval at a time."""
from __future__ import annotations

import time

import numpy as np

from solver.analysis import observables
from solver.kernels import ramp, records
from solver.simulate.simulation import StateSummary
from solver.status import OK


class Lean:
    """The lean figures of ``m`` consecutive intervals of one simulation (as
    :meth:`Simulation.frame_figures` gives them after each): ``t`` (list of s), ``strain``
    (m, columns, prisms), ``energy``, ``constraint_error``, ``balance`` (m,); ``at(q)`` sets the
    simulation's data to the end of the ``q``-th of them (a record that reads the state there)."""

    def __init__(self, t, strain, energy, cerr, balance, at):
        self.t, self.strain, self.energy, self.constraint_error = t, strain, energy, cerr
        self.balance, self.at = balance, at

    def __len__(self):
        return len(self.t)


def applies(sim):
    """Whether :func:`conclude` serves ``sim``: its check reads no full state."""
    return not sim._check_twist


def conclude(group, k, n, ch, count):
    """The first of ``count`` intervals (of ``n`` steps) of lane ``k`` of ``group`` from its
    chunk ``ch`` concluded at once, up to the first that the lane did not finish or that fails
    the divergence check: the simulation's clock, step counts, energy scale and data moved to
    the last of them, as as many :meth:`LaneGroup.conclude` calls would. Returns their
    :class:`Lean` figures, or None where none is concluded so."""
    s = group.sims[k]
    if group._fallen[k] or not applies(s):
        return None
    m = min(count, int(ch.done[k]))
    if m <= 0:
        return None
    out = ch.out[:m, k]
    e, cerr = out[:, 1], out[:, 2]
    # the energy scale each interval's check reads: the one the previous interval left
    # (Simulation._conclude)
    before = np.maximum.accumulate(np.concatenate(([s._energy_scale], np.abs(e[:-1]))))
    levels = s.network.levels.size
    heights = ch.heights[:m, k]
    ok, balance = _verdicts(out, ch.data.ledger[1:m + 1, k, records.DISSIPATED], s._energy_ref,
                            before, s.div.energy_error, s.div.constraint_error, _one_sided(s),
                            levels and heights[0].size)
    bad = np.flatnonzero(~ok)
    m = int(bad[0]) if bad.size else m
    if m == 0:
        return None
    t, t_now, span = [], s.t, n * s.dt
    for _ in range(m):
        t_now += span
        t.append(t_now)
    s.t, s.step = t_now, s.step + n * m
    s.steps_taken += int(ch.steps[:m, k].sum())
    s._energy_scale = max(s._energy_scale, float(np.max(np.abs(e[:m]))))
    if levels:
        strain = observables.strains_of_heights(heights[:m], s.network.h0)
    else:
        strain = np.zeros((m, 0, 0))

    group.to_end(k, m - 1, ch)
    return Lean(t, strain, e[:m], cerr[:m], balance[:m], lambda q: group.to_end(k, q, ch))


def _one_sided(sim):
    """Whether ``sim``'s balance is checked against gains only (:meth:`Simulation._check`: cable
    damping under a method that does not book it)."""
    return sim.effects.damp is not None and not sim._books_dissipation


def _verdicts(out, D, ref, before, lim, cerr_lim, one_sided, levels):
    """The divergence checks of :meth:`Simulation._check` on state summary rows ``out``
    (finite, energy, constraint error, smallest height), element by element over the rows
    (intervals of one simulation, or lanes; the other arguments scalars or one per row): the
    ledger's ``D``, the energy reference ``ref``, the energy scale ``before`` the check, the
    limits ``lim`` (balance) and ``cerr_lim``, ``one_sided`` balance checks, ``levels``: whether
    prism heights are checked. The balance as :meth:`Simulation._balance` computes it:
    ``(e + D - ref) / max(|ref|, |e|, before, 1e-300)``. Returns (verdicts, balances)."""
    finite, e, cerr, h_min = out[:, 0] != 0.0, out[:, 1], out[:, 2], out[:, 3]
    balance = balances(e, D, ref, before)
    ok = (finite & (cerr <= cerr_lim) & (balance <= lim)
          & ((balance >= -lim) | np.asarray(one_sided)))
    if levels:
        ok &= h_min > 0.0
    return ok, balance


def balances(e, D, ref, scale):
    """:meth:`Simulation._balance` element by element: ``(e + D - ref) / max(|ref|, |e|,
    scale, 1e-300)`` for energies ``e``, ledgers ``D``, references ``ref`` and scales
    ``scale`` (arrays, or scalars for all)."""
    return (e + D - ref) / np.maximum(np.maximum(np.maximum(np.abs(ref), np.abs(e)), scale),
                                      1e-300)


def sound(sims, status, out, D, levels, book=None):
    """Which of ``sims`` pass :meth:`Simulation._check` after one interval, each from its lane's
    integrator ``status``, state summary row ``out`` (finite, energy, constraint error, smallest
    height) and ledger ``D`` (its cable damping's energy): the same operations, element by element
    over the lanes (so the same verdicts), as the check of one simulation makes; ``levels``:
    whether the network has prism levels; ``book`` (B, 2): the energy references and scales the
    check reads, where not the simulations' own (a ramp's). A simulation whose check reads its
    full state (:func:`applies`) is never counted sound here."""
    if book is None:
        book = np.array([(s._energy_ref, s._energy_scale) for s in sims]).reshape(-1, 2)
    ok, _ = _verdicts(out, D, book[:, 0], book[:, 1],
                      np.array([s.div.energy_error for s in sims]),
                      np.array([s.div.constraint_error for s in sims]),
                      np.array([_one_sided(s) for s in sims]), levels)
    return ok & (status == OK) & np.array([applies(s) for s in sims])


def conclude_call(group, n, heights, steps, status):
    """The end of :meth:`LaneGroup.advance`'s call of ``n`` steps for every lane (its steps
    ``steps``, integrator ``status``, prism ``heights``, the state summaries in ``group.out``):
    each simulation that passes the divergence check (:func:`sound`) moves its clock, step
    counts and energy scale as :meth:`Simulation._conclude` does; any other concludes by itself
    (restores, raises naming the step). Returns ``[(ok, steps or exception)]`` per
    simulation."""
    sims = group.sims
    levels = sims[0].network.levels.size and heights[0].size
    ok = sound(sims, status, group.out, group.blocks[0].S.ledger[:, records.DISSIPATED],
               levels).tolist()
    results = []
    for s, o, h, taken, st, kept, good in zip(sims, group.out.tolist(), heights,
                                              steps.tolist(), status.tolist(), group._kept, ok):
        s._cache = {'summary': StateSummary(o[0] != 0.0, o[1], h, o[2], o[3])}
        if good:
            results.append((True, _moved(s, n, o[1], taken)))
            continue
        try:
            results.append((True, s._conclude(n, taken, st, kept, None)))
        except Exception as exc:            # noqa: BLE001 - this lane's result
            results.append((False, exc))
    return results


def _moved(s, n, energy, taken):
    """Simulation ``s`` past an interval of ``n`` steps that passed its check, as
    :meth:`Simulation._conclude` moves it (its end state's ``energy`` J, the integrator's
    ``taken`` steps): the energy scale, the clock, the step counts. Returns ``taken``."""
    s._energy_scale = max(s._energy_scale, abs(energy))
    s.t += n * s.dt
    s.step += n
    s.steps_taken += taken
    return taken


def conclude_ramped(group, n, heights, call):
    """The end of :meth:`LaneGroup._advance_ramped`'s call of ``n`` steps (``call``: per lane
    the steps done, the integrator's steps, what the last rest lengths set returned, whether the
    lane ended the interval: :func:`solver.integrators.rk4laneramp.ramped`). A simulation whose
    lane ended the interval and passes the divergence check (:func:`sound`, with the energy
    reference and scale its ramp booked) takes its ramp's prestrain, booking and end as
    :meth:`~solver.simulate.loading.Loading._ramp_went` does, then moves as :func:`conclude_call`
    moves one; any other goes on from where its call stopped by itself (its interval's rest, or
    the restore and the error naming the step). Returns ``[(ok, steps or exception)]``."""
    sims, R, status = group.sims, group.R, group.blocks[0].status
    done, taken, went, made = (a.tolist() for a in call)
    levels = sims[0].network.levels.size and heights[0].size
    whole = (call[3] == 1) & (status == OK)
    ok = (whole & sound(sims, status, group.out, group.blocks[0].S.ledger[:, records.DISSIPATED],
                        levels, R.book)).tolist()
    results = []
    book = R.book.tolist()
    p = R.p.copy()                  # each concluded lane's prestrain: a row of this copy
    for k, (s, o) in enumerate(zip(sims, group.out.tolist())):
        end = (o[0] != 0.0, o[1], heights[k], o[2], o[3]) if made[k] else None
        if ok[k]:
            s._cache = {'summary': StateSummary(*end)}
            s._energy_ref, s._energy_scale = book[k]
            s._prestrain = p[k].reshape(s._prestrain.shape)
            if went[k] == ramp.ENDED:
                s._ramp = None
            results.append((True, _moved(s, n, o[1], taken[k])))
            continue
        try:
            first = s._ramp_went(0, n, (done[k], taken[k], int(status[k]), went[k]), end,
                                 R.book[k], R.p[k])
            results.append((True, s._stepped(n, group._keeps[k], first)))
        except Exception as exc:            # noqa: BLE001 - this lane's result
            results.append((False, exc))
    return results


def conclude_chunk(group, n, ch, which, counts, visit, spent, share, running, stop, many=None):
    """The intervals of the lane ``group``'s chunk ``ch`` concluded and visited (its instances
    ``which``, ``counts`` their intervals, ``share`` each one's share of the call's time): with
    ``many``, each lane's first intervals at once (:func:`conclude`, then ``many(i, lean)``),
    the rest interval by interval (:meth:`LaneGroup.conclude`, then ``visit(i, q)``), on the
    thread that made the call: its Python runs while the other threads step. ``running(i)``:
    whether instance ``i`` still runs; ``stop(i, exc)`` stops it."""
    for i in which:
        if counts[i]:
            spent[i] = share

    def book(i, t0, c0):
        """Add the time since ``t0``, ``c0`` (wall, thread CPU) to instance ``i``'s share."""
        w, c = spent.pop(i, (0.0, 0.0))
        spent[i] = (w + time.perf_counter() - t0, c + time.thread_time() - c0)
    done = {}
    for k, i in enumerate(which):
        if many is None or not counts[i] or not running(i):
            continue
        try:
            t0, c0 = time.perf_counter(), time.thread_time()
            lean = conclude(group, k, n, ch, counts[i])
            if lean is None:
                continue
            book(i, t0, c0)
            done[i] = len(lean)
            many(i, lean)
        except Exception as exc:                    # noqa: BLE001 - this instance stops
            stop(i, exc)
    for q in range(max(counts[i] for i in which)):
        for k, i in enumerate(which):
            if q < done.get(i, 0) or q >= counts[i] or not running(i):
                continue
            try:
                t0, c0 = time.perf_counter(), time.thread_time()
                group.conclude(k, q, n, ch)
                book(i, t0, c0)
                visit(i, q)
            except Exception as exc:                # noqa: BLE001 - this instance stops
                stop(i, exc)
