"""How the Rerun recorder (:mod:`tensegrity_ros.io.rerun_sink`) shapes its data: sim-time
columns, cable colours, line strips and bar-chart tensors built as whole Arrow arrays (rerun-sdk
would convert them row by row in Python), the heat map's time grid, and the y ranges of series
that stayed constant. Pure functions of NumPy arrays."""
from __future__ import annotations

import math

import numpy as np
import pyarrow as pa
import rerun as rr

from tensegrity_ros.msgs.style import tension_colors


LINEAR_STRAIN = 0.01      # the symmetric-log scale of strain is linear within +-1 % strain


def symlog(strain, s0=LINEAR_STRAIN):
    """Strain on the symmetric-log scale of the heat map and the log bar chart:
    ``sign(s) log10(1 + |s| / s0)``: linear around 0 (within ``s0``), logarithmic beyond, so a
    0.15 pulse keeps a third of the range of a -31.5 crush."""
    s = np.asarray(strain, dtype=np.float64)
    return np.sign(s) * np.log10(1.0 + np.abs(s) / s0)


def symlog_inverse(y, s0=LINEAR_STRAIN):
    """The strain of a symmetric-log value ``y`` (:func:`symlog`)."""
    y = np.asarray(y, dtype=np.float64)
    return np.sign(y) * s0 * (10.0 ** np.abs(y) - 1.0)


def packed_colors(tension, scale):
    """Packed RGBA (``0xRRGGBBAA``, uint32) of the marker colours
    (:func:`~tensegrity_ros.msgs.style.tension_colors`)."""
    rgba = np.rint(255.0 * tension_colors(np.ravel(tension), scale)).astype(np.uint32)
    return (rgba[:, 0] << 24) | (rgba[:, 1] << 16) | (rgba[:, 2] << 8) | rgba[:, 3]


def duration_ns(t):
    """Times ``t`` s as ``timedelta64[ns]`` (a ``sim_time`` column)."""
    return np.rint(np.asarray(t, dtype=np.float64) * 1e9).astype('timedelta64[ns]')


def _arrow_type(archetype, descriptor):
    """The Arrow type rerun-sdk gives the component ``descriptor`` of a public ``archetype``."""
    return next(b.as_arrow_array().type for b in archetype.as_component_batches()
                if b.component_descriptor() == descriptor)


STRIPS_TYPE = _arrow_type(rr.LineStrips3D([[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]]),
                          rr.LineStrips3D.descriptor_strips())
TENSOR_TYPE = _arrow_type(rr.BarChart([0.0]), rr.BarChart.descriptor_values())


class _Arrow:
    """An Arrow array as a component batch (``rerun.ComponentBatchLike``)."""

    def __init__(self, array):
        self.array = array

    def as_arrow_array(self):
        return self.array


def segments(points, n_rows):
    """A ``LineStrips3D:strips`` column of two-point strips, ``points`` (n_rows * k, 2, 3), ``k``
    strips a row, built as one Arrow array (rerun-sdk converts strip by strip)."""
    flat = pa.array(np.ascontiguousarray(points, dtype=np.float32).ravel())
    array = pa.ListArray.from_arrays(
        pa.array(np.arange(len(points) + 1, dtype=np.int32) * 2),
        pa.FixedSizeListArray.from_arrays(flat, type=STRIPS_TYPE.value_type), type=STRIPS_TYPE)
    return rr.ComponentColumn(rr.LineStrips3D.descriptor_strips(), _Arrow(array),
                              lengths=np.full(n_rows, len(points) // max(n_rows, 1), np.int32))


def tensor_rows(values):
    """A ``BarChart:values`` column of 1-D ``TensorData`` rows, one per row of ``values``
    (n_rows, k), built as one Arrow array: ``rr.BarChart`` converts row by row in Python (1.5 ms
    a row) and rerun-sdk batches no tensors."""
    values = np.ascontiguousarray(values, dtype=np.float64)
    n, k = values.shape
    union = TENSOR_TYPE.field('buffer').type
    f64 = [f.name for f in union].index('F64')
    children = [pa.nulls(0, f.type) if pa.types.is_null(f.type) else pa.array([], f.type)
                for f in union]
    children[f64] = pa.ListArray.from_arrays(pa.array(np.arange(n + 1, dtype=np.int32) * k),
                                             pa.array(values.ravel()), type=union[f64].type)
    buffer = pa.UnionArray.from_buffers(union, n, [
        None, pa.py_buffer(np.full(n, union.type_codes[f64], np.int8)),
        pa.py_buffer(np.arange(n, dtype=np.int32))], children=children)
    shape = pa.ListArray.from_arrays(pa.array(np.arange(n + 1, dtype=np.int32)),
                                     pa.array(np.full(n, k, np.uint64)),
                                     type=TENSOR_TYPE.field('shape').type)
    array = pa.StructArray.from_arrays(
        [shape, pa.nulls(n, TENSOR_TYPE.field('names').type), buffer], fields=list(TENSOR_TYPE))
    return rr.ComponentColumn(rr.BarChart.descriptor_values(), _Arrow(array),
                              lengths=np.ones(n, np.int32))


def constant_ranges(ranges):
    """``{view: (lo, hi)}`` y ranges for the time series whose values stayed constant (within
    1e-9 of their size): +-5 % around the value (+-1 around 0). Rerun draws a constant series
    on an axis of +-1 around it, where a small constant value looks like zero."""
    out = {}
    for view, (lo, hi) in ranges.items():
        if not (math.isfinite(lo) and math.isfinite(hi)):
            continue
        size = max(abs(lo), abs(hi))
        if hi - lo <= 1e-9 * size or hi == lo:
            centre = 0.5 * (lo + hi)
            half = 0.05 * abs(centre) if centre != 0 else 1.0
            out[view] = (centre - half, centre + half)
    return out


def heat_map_grid(times, impact_t=None):
    """The columns of the heat map: ``(grid, pick)``, a uniform time grid s from the impact
    (``impact_t``; the first frame when None or when no frame is that late) to the last frame,
    one step the median frame interval, and the index of the frame shown at each grid time (the
    last frame at or before it). ``times`` (n,) s, increasing."""
    times = np.asarray(times, dtype=np.float64)
    start = 0
    if impact_t is not None:
        start = int(np.searchsorted(times, impact_t - 1e-9))
        if start >= len(times):
            start = 0
    t = times[start:]
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    if not dt > 0:
        return t.copy(), np.arange(start, len(times))
    grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt + 1e-6)) + 1)
    return grid, np.searchsorted(times, grid + 1e-6 * dt, side='right') - 1
