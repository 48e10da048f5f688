"""Picking, call by call, the faster of two ways to step that give the same result: lanes
(:mod:`solver.simulate.lanebatch`) or one simulation at a time, as measured along the run
(:class:`~solver.simulate.array.ArraySimulation` with ``integrator.lanes: auto``)."""
from __future__ import annotations

import time


class Chooser:
    """Picks, call by call, the faster of two ways to step that give the same result (lanes or
    one simulation at a time): each way's wall time per step, averaged over its recent calls
    (the first call of a way, which builds and may compile, not counted); until both are known
    the unknown one is taken, then the cheaper (a switch needs it cheaper by ``margin``), and
    every ``probe_every`` calls (times how many times slower it was, up to ``patience``) the
    other one once more: the dynamics change (contact makes lanes wait for each other)."""

    def __init__(self, probe_every=64, weight=0.3, patience=8, margin=0.1):
        self.probe_every, self.weight, self.patience = probe_every, weight, patience
        self.margin = margin
        self.cost = {True: None, False: None}
        self.seen = {True: 0, False: 0}
        self.calls = 0
        self.best = None

    def pick(self):
        self.calls += 1
        for way in (True, False):
            if self.cost[way] is None:
                return way
        best = self.cost[True] <= self.cost[False]
        if self.best is not None and best != self.best and (
                self.cost[best] > (1.0 - self.margin) * self.cost[self.best]):
            best = self.best            # not cheaper by the margin: keep the way in use
        self.best = best
        # a way that lost by far is probed less often: every probe_every calls times how many
        # times slower it was (at most ``patience`` times less often)
        slower = max(self.cost[True], self.cost[False]) / max(
            min(self.cost[True], self.cost[False]), 1e-300)
        every = self.probe_every * max(1, min(int(slower), self.patience))
        return (not best) if self.calls % every == 0 else best

    def run(self, step, n):
        """``step(way)`` of ``n`` steps by the way :meth:`pick` gives, timed and noted."""
        way = self.pick()
        t0 = time.perf_counter()
        out = step(way)
        self.note(way, time.perf_counter() - t0, n)
        return out

    def note(self, way, seconds, n):
        self.seen[way] += 1
        if self.seen[way] < 2:
            return
        c = seconds / max(n, 1)
        old = self.cost[way]
        self.cost[way] = c if old is None else (1 - self.weight) * old + self.weight * c
