"""What an array's frame reads of its lane groups, a group at a time instead of a column at a
time: the columns' base forces in one compiled call (:func:`solver.kernels.lanebase.base_forces`),
kept in each simulation's cache, where :meth:`~solver.simulate.simulation.Simulation.base_force`
finds them, and the positions and cable tensions of all lanes in another
(:func:`solver.kernels.laneview.frame_rows`), the strains from their state summaries
(:func:`fill`); each the values a simulation computes itself one column at a time, bit for bit.
An array that steps one column simulation at a time makes its lane groups for its frames all the
same (:meth:`~solver.simulate.array.ArraySimulation.frame`): the columns' data then live in the
groups' memory, where each column steps as before."""
from __future__ import annotations

import weakref

import numpy as np

from solver.analysis import observables
from solver.analysis.support import ModelBaseForce
from solver.kernels import lanebase, laneview, records
from solver.simulate import lanebulk

_ARGS = weakref.WeakKeyDictionary()     # lane group -> its call's arguments (or None: no call)
_VIEWS = weakref.WeakKeyDictionary()    # lane group -> its expansion and scratch (fill)


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



def fill(plan, columns_of, offset, x, strain, tension, base, energy):
    """The rows of an array's frame (``x`` (columns, n_nodes, 3), ``strain``, ``tension``,
    ``base``, ``energy``) of the columns of every lane group of ``plan`` (or None) that still
    holds its simulations, for columns with prism levels, a group at a time: positions (moved
    by ``offset``) and tensions in one call (:func:`solver.kernels.laneview.frame_rows`), strains
    of the state summaries' heights, energies and base forces (:func:`put_base_forces` first).
    ``columns_of``: id of a simulation -> the columns it stands for. Returns id of each
    simulation served -> its constraint error and energy balance error
    (:meth:`Simulation.energy_error`, over the group's lanes: :func:`lanebulk.balances`)."""
    put_base_forces(plan)
    errs = {}
    for group in () if plan is None else plan.groups:
        sims = group.sims
        s0 = sims[0]
        if not s0.network.levels.size or not group.bound():
            continue
        args = _VIEWS.get(group)
        if args is None:
            rep, cos, sin, rotate, cable_map = s0.model.expansion()
            net = s0.network
            args = _VIEWS[group] = (rep, cos, sin, rotate, net.cable_a, net.cable_b, cable_map,
                                    np.empty((len(rep), 3)))
        rep, cos, sin, rotate, ca, cb, cmap, pos = args
        first, cols, lane = [0], [], []
        for k, s in enumerate(sims):
            got = columns_of[id(s)]
            cols += got
            lane += [k] * len(got)
            first.append(len(cols))
        S = group.blocks[0].S
        group.call(laneview.frame_rows, (S.x, rep, cos, sin, rotate, ca, cb, cmap, S.rest, S.EA,
                                         np.array(first), np.array(cols), offset, pos, x,
                                         tension))
        summ = [s._summary() for s in sims]
        h = observables.strains_of_heights(np.stack([u.heights for u in summ]), s0.network.h0)
        strain[cols] = h[lane, 0]
        base[cols] = np.take([s.base_force()[0] for s in sims], lane)
        e = np.array([u.energy for u in summ])
        energy[cols] = e[lane]
        bal = lanebulk.balances(e, S.ledger[:, records.DISSIPATED],
                                np.array([s._energy_ref for s in sims]),
                                np.array([s._energy_scale for s in sims]))
        errs.update(zip(map(id, sims), zip((u.constraint_error for u in summ), bal.tolist())))
    return errs
