"""Many output intervals of a lane group in one call (:func:`solver.integrators.rk4lanes.
chunk_run`): each lane steps its intervals one after another on its own clock, so the lanes wait
for each other once per call, not at every interval's end.

A lane's steps within an interval depend on its own state: a lane meeting a contact takes ten
times the steps of one that does not, and the lane that does changes from interval to interval.
Stepped one interval per call, the lanes wait for the slowest at every interval; over many
intervals their step counts even out. At each interval's end a lane does what the end of a call
and the start of the next one do for a single run (the effects' finish and start, the halvings
kept, the clock from 0, the state summary of the checked call), and its data are kept as they
stand, for the caller to check and record interval by interval as the single run's calls would.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from solver.compiled import jit_inline, jit_lanes
from solver.kernels import effects, summary
from solver.kernels.lanedata import LaneState, lane_out, lane_record
from solver.kernels.records import copy_data


class Chunk(NamedTuple):
    """K intervals of B lanes: ``data`` (a :class:`~solver.kernels.lanedata.LaneState` whose
    arrays lead with K + 1 entries) every lane's data at the start of each interval and at the
    end of the last (entry j is interval j's start, entry j + 1 its end; ``saved`` is empty);
    ``out`` (K, B, 4: finite, energy J, constraint error, smallest prism height m) and
    ``heights`` (K, B, n_columns, n_prisms) the state summary at each interval's end; ``steps``
    (K, B) the steps of each interval; ``todo`` (B,) the intervals each lane has still to
    finish (0: none, as for every lane of an :func:`empty` chunk) and ``done`` (B,) those it
    finished."""
    data: LaneState
    out: np.ndarray
    heights: np.ndarray
    steps: np.ndarray
    todo: np.ndarray
    done: np.ndarray


def chunk(S, n_intervals, heights_shape):
    """A zeroed :class:`Chunk` of ``n_intervals`` intervals for the lanes of ``S`` (a
    :class:`~solver.kernels.lanedata.LaneState`)."""
    b = S.x.shape[0]
    return Chunk(_entries(S, n_intervals + 1), np.zeros((n_intervals, b, 4)),
                 np.zeros((n_intervals, b) + tuple(heights_shape)),
                 np.zeros((n_intervals, b), np.int64), np.zeros(b, np.int64),
                 np.zeros(b, np.int64))


def _entries(S, n):
    """A :class:`~solver.kernels.lanedata.LaneState` of ``n`` entries of the data of ``S``
    (an empty ``saved``)."""
    return LaneState(*(np.zeros((n,) + a.shape, a.dtype) for a in S[:-1]),
                     np.zeros((n, 0) + S.saved.shape[1:]))


def empty():
    """A :class:`Chunk` of no intervals (the calls of one interval)."""
    like = LaneState(*(np.zeros((0,) * k) for k in (3, 3, 2, 2, 3, 2, 2)),
                     np.zeros((0, 0), np.int64), np.zeros((0, 0)), np.zeros((0, 0, 0, 0)))
    return Chunk(_entries(like, 0), np.zeros((0, 0, 4)), np.zeros((0, 0, 0, 0)),
                 np.zeros((0, 0), np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))


@jit_inline
def record(ch, j, k):
    """Lane ``k``'s :class:`~solver.kernels.records.Data` at the start of interval ``j`` (views
    into ``ch``)."""
    return lane_record(kept(ch, j, ch.data.saved[j]), k)


@jit_inline
def kept(ch, j, saved):
    """The data at the start of interval ``j`` as a
    :class:`~solver.kernels.lanedata.LaneState` (views; ``saved`` the lanes' own)."""
    e = ch.data
    return LaneState(e.x[j], e.v[j], e.rest[j], e.EA[j], e.f_ext[j], e.ledger[j], e.scan[j],
                     e.active[j], e.refine[j], saved)


@jit_inline
def start_lane(m, S, C, k, steps, running):
    """Lane ``k`` at the start of a call: its clock at 0 and, if ``running``, the effects' start
    and its halving levels (:func:`~solver.integrators.rk4lanes.begin`)."""
    C.t[k] = 0.0
    C.e0[k] = math.nan
    C.mode[k] = 0
    steps[k] = 0
    if running:
        d = lane_record(S, k)
        effects.start(d.x, m, d)
        level, clevel = effects.halvings(m, d)
        C.level[k] = level
        C.clevel[k] = clevel


@jit_inline
def end_lane(m, S, C, k):
    """Lane ``k`` at the end of a call that it ended running: the effects' finish and its
    halving levels kept (:func:`~solver.integrators.rk4lanes.end`)."""
    d = lane_record(S, k)
    effects.finish(d.x, m, d)
    effects.keep_levels(m, d, C.level[k], C.clevel[k])


@jit_inline
def put_summary(m, d, row, heights):
    """The checked call's state summary of the data ``d``
    (:func:`solver.kernels.summary.state_summary`) into ``row`` (4: finite, energy J,
    constraint error, smallest prism height m) and ``heights``."""
    finite, e, cerr, h_min = summary.state_summary(d.x, d.v, m, d, heights)
    row[0] = 1.0 if finite else 0.0
    row[1] = e
    row[2] = cerr
    row[3] = h_min


@jit_lanes
def at_end(m, S, L, C, ch, k, steps):
    """Lane ``k`` reached the end of its interval ``ch.done[k]``: the end of a call
    (:func:`end_lane` and the checked call's state summary, with the lane's state from the
    lane-inner ``L``), its data kept, and, if it has intervals left, the start of the next
    (:func:`start_lane`)."""
    j = ch.done[k]
    d = lane_record(S, k)
    lane_out(L.x, k, d.x)
    lane_out(L.v, k, d.v)
    end_lane(m, S, C, k)
    put_summary(m, d, ch.out[j, k], ch.heights[j, k])
    ch.steps[j, k] = steps[k]
    copy_data(d, record(ch, j + 1, k))
    ch.done[k] = j + 1
    ch.todo[k] -= 1
    if ch.todo[k] > 0:
        start_lane(m, S, C, k, steps, True)
