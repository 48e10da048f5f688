"""Validation of the node's command messages (docs/interfaces.md section 4): pure functions, no
ROS I/O.

Each parser takes the data and layout of a ``std_msgs/Float64MultiArray`` and returns values ready
for :class:`solver.simulate.simulation.Simulation`, or raises :class:`CommandError` whose message
names the problem. Nothing is changed by a parser; a rejected command changes nothing.

``~/cmd/impact``: ``v0`` m/s, positive compressive, ``|v0| <= 10``; 1 value (every column) or one
per column. ``~/cmd/prestrain``: cross prestrain ``0 < p <= 0.5``; 1 value (every column), one per
column, or one per cross cable in the network's cable order (column, prism, cable k). The
per-cross-cable form is accepted only when the three cross cables of each prism have equal values:
a prism's self-stress is one mode, so unequal values cannot keep the reference geometry in
equilibrium (such a command is rejected, naming the first prism that differs). Layout label (first
dimension), optional: ``all``, ``column``
or ``cross_cable``; when given it must agree with the number of values.
"""
from __future__ import annotations

import math

import numpy as np

from solver import RANGES

IMPACT_RANGE = RANGES['loading.impact.v0'][:2]       # [-10, 10] m/s, inclusive
PRESTRAIN_RANGE = RANGES['prestrain'][:2]            # (0, 0.5]
LABELS = ('all', 'column', 'cross_cable')
EQUAL_RTOL = 1e-9


class CommandError(ValueError):
    """A malformed command; the message names the problem."""


def _values(topic, data, layout):
    try:
        v = np.array(data, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise CommandError(f'{topic}: data is not a list of numbers') from None
    if v.size == 0:
        raise CommandError(f'{topic}: empty command (no values)')
    if layout is not None:
        if int(layout.data_offset) != 0:
            raise CommandError(f'{topic}: layout.data_offset must be 0, got {layout.data_offset}')
        dims = list(layout.dim)
        if len(dims) > 1:
            raise CommandError(f'{topic}: expected a flat vector (at most 1 layout dimension), '
                               f'got {len(dims)} dimensions')
        if dims and int(dims[0].size) != v.size:
            raise CommandError(f'{topic}: layout says {dims[0].size} values but data has {v.size}')
    bad = ~np.isfinite(v)
    if np.any(bad):
        i = int(np.argmax(bad))
        what = 'NaN' if math.isnan(v[i]) else 'infinite'
        raise CommandError(f'{topic}: value {i} is {what}')
    return v


def _label(topic, layout):
    if layout is None or not list(layout.dim):
        return ''
    label = str(layout.dim[0].label)
    if label not in ('',) + LABELS:
        raise CommandError(f'{topic}: unknown layout label {label!r} (use one of '
                           f'{", ".join(LABELS)})')
    return label


def parse_impact(data, layout, n_columns):
    """Impact velocities (n_columns,) m/s from a command; raises :class:`CommandError`."""
    topic = '~/cmd/impact'
    v = _values(topic, data, layout)
    label = _label(topic, layout)
    if label == 'cross_cable':
        raise CommandError(f'{topic}: per-cross-cable impact is not defined (1 value, or one per '
                           'column)')
    if v.size == 1 and label in ('', 'all') or (v.size == n_columns and label in ('', 'column')):
        pass
    else:
        want = '1' if label == 'all' or n_columns == 1 else (
            str(n_columns) if label == 'column' else f'1 or {n_columns}')
        raise CommandError(f'{topic}: expected {want} values, got {v.size}')
    lo, hi = IMPACT_RANGE
    out = (v > hi) | (v < lo)
    if np.any(out):
        raise CommandError(f'{topic}: v0 = {v[np.argmax(out)]:g} m/s is outside [{lo:g}, {hi:g}]')
    return np.broadcast_to(v, (n_columns,)).copy()


def parse_prestrain(data, layout, n_columns, n_prisms, cross_prism=None):
    """Per-prism cross prestrain (n_columns, n_prisms) from a command; ``cross_prism``
    (n_cross,) maps each cross cable (in cable order) to ``column * n_prisms + prism`` (needed for
    the per-cable form). Raises :class:`CommandError`."""
    topic = '~/cmd/prestrain'
    v = _values(topic, data, layout)
    label = _label(topic, layout)
    n_cross = 0 if cross_prism is None else len(cross_prism)
    sizes = {'all': 1, 'column': n_columns, 'cross_cable': n_cross}
    if label:
        if v.size != sizes[label]:
            raise CommandError(f'{topic}: label {label!r} needs {sizes[label]} values, got '
                               f'{v.size}')
    elif v.size == 1:
        label = 'all'
    elif v.size == n_columns:
        label = 'column'
    elif v.size == n_cross and n_cross:
        label = 'cross_cable'
    else:
        raise CommandError(f'{topic}: expected 1, {n_columns} (one per column) or {n_cross} (one '
                           f'per cross cable) values, got {v.size}')
    lo, hi = PRESTRAIN_RANGE
    out = (v <= lo) | (v > hi)
    if np.any(out):
        raise CommandError(f'{topic}: p = {v[np.argmax(out)]:g} is outside ({lo:g}, {hi:g}]')
    if label == 'all':
        return np.full((n_columns, n_prisms), v[0])
    if label == 'column':
        return np.repeat(v[:, None], n_prisms, axis=1)
    cross_prism = np.asarray(cross_prism)
    n = n_columns * n_prisms
    p_max = np.full(n, -np.inf)
    p_min = np.full(n, np.inf)
    np.maximum.at(p_max, cross_prism, v)
    np.minimum.at(p_min, cross_prism, v)
    differ = p_max - p_min > EQUAL_RTOL * np.abs(p_max)
    if np.any(differ):
        k = int(np.argmax(differ))
        c, i = divmod(k, n_prisms)
        raise CommandError(f'{topic}: the cross cables of prism {i} of column {c} have different '
                           f'prestrain ({p_min[k]:g} .. {p_max[k]:g}); only equal values per '
                           'prism keep the reference geometry in equilibrium')
    return p_max.reshape(n_columns, n_prisms)


def describe(values, limit=6):
    """Short text of a command's values for logs (never prints NaN: non-finite shown as text)."""
    v = list(np.ravel(values))
    parts = [f'{x:g}' if math.isfinite(x) else 'non-finite' for x in v[:limit]]
    more = f', ... ({len(v)} values)' if len(v) > limit else ''
    return '[' + ', '.join(parts) + more + ']'
