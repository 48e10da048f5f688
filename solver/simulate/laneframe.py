"""What an array's frame reads of its lane groups, one compiled call per group instead of one
per column: the columns' base forces (:func:`solver.kernels.lanebase.base_forces`), kept in each
simulation's cache, where :meth:`~solver.simulate.simulation.Simulation.base_force` finds them
(the values it computes itself one column at a time, bit for bit). An array that steps one
column simulation at a time makes its lane groups for its frames all the same
(:meth:`~solver.simulate.array.ArraySimulation.frame`): the columns' data then live in the
groups' memory, where each column steps as before."""
from __future__ import annotations

import weakref

import numpy as np

from solver.analysis.support import ModelBaseForce
from solver.kernels import lanebase

_ARGS = weakref.WeakKeyDictionary()     # lane group -> its call's arguments (or None: no call)


def put_base_forces(plan):
    """For every lane group of ``plan`` (a :class:`~solver.simulate.lanebatch.Plan`, or None)
    that still holds its simulations (their data are its lanes): the base force of each of them
    in one call, kept as its ``base_force``. A group is left to its simulations (each computes
    its own when asked) where one of them has its base force already, where their model has no
    base force of its own state (:meth:`ModelBaseForce.applies`) or an evaluation fails."""
    for group in () if plan is None else plan.groups:
        sims = group.sims
        if any('base_force' in s._cache for s in sims) or not group.bound():
            continue
        if group not in _ARGS:
            _ARGS[group] = _arguments(group)
        args = _ARGS[group]
        if args is not None and not group.call(lanebase.base_forces, args):
            out = args[-1]
            for k, s in enumerate(sims):
                s._cache['base_force'] = out[k].copy()


def _arguments(group):
    """The arguments of :func:`solver.kernels.lanebase.base_forces` for ``group`` (its scratch
    made once), or None where its model has no base force of its own state."""
    s0, top = group.sims[0], group.blocks[0]
    m = s0.model
    if not s0.network.levels.size or m.integrates_itself or not ModelBaseForce.applies(m):
        return None
    base, mult = ModelBaseForce.rows(m)
    S, C = top.S, top.C
    return (group.rec, S, top.L, top.W, top.X, C, np.empty_like(S.scan), np.empty_like(S.active),
            np.empty_like(S.ledger), np.empty_like(C.go), np.empty_like(C.st), base, mult,
            np.empty((len(group.sims), base.shape[0])))
