"""What a column delivers to its support: the axial base force and the pulse arrival there.

The base force of a column is the axial reaction at its clamped base level, N, positive when the
column pushes down on the support (compressive): minus the z sum of the member forces that act on
the nodes of that level (cable tensions and the bars' constraint forces, the multipliers of
:func:`solver.kernels.dynamics.accelerations`). Rigid members whose two nodes are clamped carry
nothing (they are not constraints of the network). The base level of a column is its lowest level
whose three nodes are all clamped; a column without one has no base force (0).

Momentum balance of a column (what the tests check): the support is the only body outside the
free nodes that members touch, so ``d P_z / dt = B + F_ext,z`` with ``P_z`` the column's axial
momentum, and ``int B dt`` over an interval is the change of ``P_z`` minus the external impulse.

:func:`first_arrival` times the first compressive pulse at the base from a base-force history (on
the paper's columns: a fast, small front), :func:`pulse_arrival` the largest one (the solitary
pulse, which follows at about half that speed and pushes several times harder).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from solver import status as codes
from solver.compiled import compiled_overload, jit
from solver.kernels import dynamics as dyn
from solver.kernels import records

ARRIVAL_FRACTION = 0.5        # arrival: the rise to the first compressive peak crosses this share
PEAK_FLOOR = 0.02             # the first peak: a local maximum above this share of the top ...
PEAK_DROP = 0.1               # ... after which the force falls by this share of it before rising
                              # above it again (a wiggle on a rising flank is no peak)


def base_levels(network):
    """Node indices (n_columns, 3) of each column's base level (its lowest fully clamped level),
    -1 rows for a column without one."""
    return _base_rows(network.levels, network.clamped)


def _base_rows(levels, clamped):
    """Node indices (n_columns, k) of each column's lowest level whose ``k`` nodes (``levels``
    (n_columns, n_levels, k)) are all ``clamped``; -1 rows for a column without one."""
    levels = np.asarray(levels)
    out = -np.ones((levels.shape[0], levels.shape[2]), dtype=np.int64)
    clamped = np.asarray(clamped)
    for c in range(levels.shape[0]):
        for j in range(levels.shape[1]):
            if np.all(clamped[levels[c, j]]):
                out[c] = levels[c, j]
                break
    return out


class ModelBaseForce:
    """Base force per column of a model's current state, from the model's own state and records
    (:mod:`solver.kernels.records`): ``full3d`` or the exact ``sym3d`` reduction, where a reduced
    node stands for ``node_mult`` nodes of the full network and the z force on each of its rotated
    images is the same, so the base force is the multiplicity-weighted z sum over the reduced base
    nodes. No full state is expanded, and the force evaluation is the integrator's own compiled
    kernel on a workspace of its own. The member forces are those of :class:`BaseForce`: cables
    with their damping, prism stops, touching bars and bases (every pair looked at, as after a
    rescan) and the bars' multipliers; strikers, which act at the free end, are left out. Raises
    ValueError if the constraint matrix is singular."""

    def __init__(self, model):
        self.base, self.mult = self.rows(model)
        self.work = records.clone_work(model.work)
        self.acc = np.zeros_like(model.x)
        self._entry = None          # the compiled overload of _model_base_force, after a call
        self._copies = None         # its scratch: the contact state's and the ledger's copies

    @staticmethod
    def rows(model):
        """``(base, mult)``: the reduced base nodes of each column (n_columns, k; -1 rows for
        a column without a base) and their multiplicities."""
        sm = model.rec.summary
        base = _base_rows(sm.levels, sm.clamped)
        return base, np.asarray(sm.node_mult, dtype=np.float64)[np.maximum(base, 0)]

    @staticmethod
    def applies(model):
        """Whether ``model`` offers what this needs: a summary of its own state (an exact model
        stepped on records) and node-local masses (no mass-matrix system of massive bars sharing
        nodes)."""
        return (model.exact and not model.integrates_itself
                and model.rec.topo.kkt.node_u.shape[0] == 0)

    def __call__(self, model):
        d = model.data
        like = (d.contact.scan, d.contact.active, d.ledger)
        c = self._copies
        if c is None or any(a.shape != b.shape for a, b in zip(c, like)):
            c = self._copies = tuple(np.empty_like(a) for a in like)
        out = np.empty(self.base.shape[0])
        args = (model.rec, d, self.work, self.acc, *c, self.base, self.mult, out)
        if self._entry is None:     # through numba's dispatch, then its compiled overload
            status = _model_base_force(*args)
            self._entry = compiled_overload(_model_base_force, args) or _model_base_force
        else:
            status = self._entry(*args)
        if status != dyn.OK:
            raise ValueError(f'base force: {codes.text(status)}')
        return out


@jit
def _model_base_force(rec, d, work, acc, scan, active, ledger, base, mult, out):
    """:class:`ModelBaseForce` in one compiled call: the forces of ``d`` (the model ``rec``'s
    data) evaluated with copies of its contact state, in which every pair and every prism's
    bases are looked at (``scan``, ``active``), and of its ledger (the damping's power:
    scratch), then :func:`_base_sum` into ``out``. Returns the evaluation's status."""
    for i in range(scan.shape[0]):
        scan[i] = d.contact.scan[i]
    for i in range(active.shape[0]):
        active[i] = d.contact.active[i]
    for i in range(ledger.shape[0]):
        ledger[i] = d.ledger[i]
    scan[records.LOOK] = 1.0
    active[0] = -1
    own = records.Data(d.x, d.v, d.rest, d.EA, d.f_ext, ledger,
                       records.ContactState(scan, active), d.refine)
    status = dyn.accelerations(d.x, d.v, rec, own, work, acc)
    if status == dyn.OK:
        _base_sum(work.f, d.f_ext, base, mult, out)
    return status


@jit
def _base_sum(f, f_ext, base, mult, out):
    """``out[c] = -sum_i mult[c, i] (f - f_ext)[base[c, i], 2]``, 0 for a column without a base
    (``base[c, 0]`` -1)."""
    for c in range(base.shape[0]):
        s = 0.0
        if base[c, 0] >= 0:
            for i in range(base.shape[1]):
                p = base[c, i]
                s += mult[c, i] * (f[p, 2] - f_ext[p, 2])
            s = -s
        out[c] = s


class BaseForce:
    """Base force per column of a full state of ``network`` (see the module text), with the cable
    damping, prism stops and bar contact of ``effects`` (:class:`solver.models.extras.Effects`,
    or None)."""

    def __init__(self, network, effects=None):
        from solver.models.extras import NONE, full_effects
        self.network = network
        self.base = base_levels(network)
        self.model, self.data, self.work = full_effects(effects or NONE, network)
        self._acc = np.zeros((network.n_nodes, 3))
        self._zero = np.zeros((network.n_nodes, 3))

    def member_forces(self, x, v, rest, EA, f_ext=None):
        """Resultant member force (n_nodes, 3) N on every node (cables with their damping, prism
        stops, touching bars and bases, bar multipliers) of the state ``x``, ``v`` (n_nodes, 3)
        with rest lengths ``rest`` and ``EA`` (n_cables,); ``f_ext`` (n_nodes, 3) N enters the
        multipliers. Raises ValueError if the constraint matrix is singular."""
        f_ext = self._zero if f_ext is None else np.ascontiguousarray(f_ext, dtype=np.float64)
        d = self.data._replace(rest=np.ascontiguousarray(rest, dtype=np.float64),
                               EA=np.ascontiguousarray(EA, dtype=np.float64), f_ext=f_ext)
        status = dyn.accelerations(np.ascontiguousarray(x, dtype=np.float64),
                                   np.ascontiguousarray(v, dtype=np.float64), self.model, d,
                                   self.work, self._acc)
        if status != dyn.OK:
            raise ValueError(f'base force: {codes.text(status)}')
        return self.work.f - f_ext

    def __call__(self, x, v, rest, EA, f_ext=None):
        """Base force (n_columns,) N, positive compressive."""
        f = self.member_forces(x, v, rest, EA, f_ext)
        out = np.zeros(len(self.base))
        has = self.base[:, 0] >= 0
        out[has] = -f[self.base[has], 2].sum(axis=1)
        return out


def axial_momentum(v, network, columns=None):
    """Axial momentum (n_columns,) kg m/s of each column's free nodes: lumped masses and
    uniform bars (``m_b (v_a + v_b) / 2``) of the velocities ``v`` (n_nodes, 3)."""
    levels = network.levels
    free = ~np.asarray(network.clamped)
    col = -np.ones(network.n_nodes, dtype=np.int64)
    for c in range(levels.shape[0]):
        col[levels[c].ravel()] = c
    p = np.asarray(network.node_mass) * v[:, 2] * free
    out = np.bincount(col[col >= 0], weights=p[col >= 0], minlength=levels.shape[0])
    for a, b, mb in zip(network.bar_a, network.bar_b, network.bar_mass):
        if mb:
            out[col[a]] += 0.5 * mb * (v[a, 2] * free[a] + v[b, 2] * free[b])
    return out


@dataclass
class Arrival:
    """First compressive pulse at a column's base (see :func:`first_arrival`): ``time_s`` when the
    rise of the base force to its first compressive peak crosses :data:`ARRIVAL_FRACTION` of that
    peak (linear interpolation between samples); ``peak_time_s`` and ``peak_N`` (deviation from
    rest, N, positive) of that peak; ``rise_s``, the width at half height of the largest rate
    ``dB/dt`` on that rise (the duration of the pulse as the field of :mod:`solver.analysis.field`
    sees it); ``precursor_N`` (<= 0), the largest pull on the support before the arrival. NaN when
    no compressive pulse arrived."""
    time_s: float
    peak_time_s: float
    peak_N: float
    rest_N: float
    rise_s: float = math.nan
    precursor_N: float = math.nan

    def as_dict(self):
        return {'arrival_time_s': self.time_s, 'peak_time_s': self.peak_time_s,
                'peak_N': self.peak_N, 'rest_N': self.rest_N, 'rise_s': self.rise_s,
                'precursor_N': self.precursor_N}


def first_arrival(times, force, rest=None, floor=1e-12):
    """The :class:`Arrival` of a base-force history ``force`` (n_t,) N at ``times`` (n_t,) s.
    ``rest``: the rest value (default the first sample). With ``c = force - rest`` (compressive
    positive), the first peak is the first local maximum of ``c`` above :data:`PEAK_FLOOR` of the
    largest compression over the history after which ``c`` falls by :data:`PEAK_DROP` of it
    before it exceeds it (the largest compression if none does); the arrival is where the rise
    that ends at that peak (the samples before it at or above the level, back to the last one
    below) crosses :data:`ARRIVAL_FRACTION` of the peak. So a small first pulse stays the first
    when a larger one follows (on a short column the pulse that comes back from the impacted
    end is several times the first). Pulls on the support (a tensile precursor) are not pulses
    here: they are reported as ``precursor_N``. ``floor`` N: a largest compression below it is
    no pulse."""
    t = np.asarray(times, dtype=np.float64)
    f = np.asarray(force, dtype=np.float64)
    rest = float(f[0]) if rest is None else float(rest)
    c = f - rest
    nan = math.nan
    top = float(c.max(initial=0.0))
    if not top > floor:
        return Arrival(nan, nan, nan, rest, nan, float(min(c.min(initial=0.0), 0.0)))
    k = _first_peak(c, PEAK_FLOOR * top)
    return _arrival_at(t, c, k, rest)


def pulse_arrival(times, force, rest=None, floor=1e-12):
    """The :class:`Arrival` of the largest compression of a base-force history (the solitary
    pulse, when the history holds its first passage and nothing larger): where the rise that ends
    at the largest value of ``c = force - rest`` crosses :data:`ARRIVAL_FRACTION` of it, with
    its ``rise_s`` and the largest pull before it (``precursor_N``). NaN without a compression
    above ``floor`` N."""
    t = np.asarray(times, dtype=np.float64)
    f = np.asarray(force, dtype=np.float64)
    rest = float(f[0]) if rest is None else float(rest)
    c = f - rest
    if not float(c.max(initial=0.0)) > floor:
        return Arrival(math.nan, math.nan, math.nan, rest, math.nan,
                       float(min(c.min(initial=0.0), 0.0)))
    k = int(np.argmax(c))
    return _arrival_at(t, c, k, rest)


def _arrival_at(t, c, k, rest):
    """The :class:`Arrival` of the peak ``c[k]``: where the rise that ends at it (the samples
    before it at or above the level, back to the last one below) crosses
    :data:`ARRIVAL_FRACTION` of it (linear interpolation), its ``rise_s`` and the largest pull
    before it."""
    level = ARRIVAL_FRACTION * c[k]
    i = k
    while i > 0 and c[i - 1] >= level:
        i -= 1
    if i == 0:
        arrival = float(t[0])
    else:
        u = (level - c[i - 1]) / (c[i] - c[i - 1])
        arrival = float(t[i - 1] + u * (t[i] - t[i - 1]))
    return Arrival(arrival, float(t[k]), float(c[k]), rest, _rise_width(t, c, k),
                   float(min(c[:i + 1].min(), 0.0)))


def _first_peak(c, floor):
    """Index of the first local maximum of ``c`` at or above ``floor`` after which ``c`` falls by
    :data:`PEAK_DROP` of it before exceeding it; the largest value's if there is none."""
    n = len(c)
    i = 0
    while i < n - 1:
        if c[i] >= floor and c[i] >= c[i + 1]:
            j = i + 1
            while j < n and c[j] <= c[i]:
                if c[j] <= (1.0 - PEAK_DROP) * c[i]:
                    return i
                j += 1
            i = j                 # c rose above c[i] at j (or the history ended)
            continue
        i += 1
    return int(np.argmax(c))


def _rise_width(t, c, k):
    """Width (s) at half height of the largest rate dc/dt on the rise to the peak at index ``k``
    (the rise: back from ``k`` while ``c`` decreases), from the sampled rate (linear
    interpolation at the half-height crossings); NaN with fewer than three samples."""
    if len(c) < 3 or k < 1:
        return math.nan
    j0 = k
    while j0 > 0 and c[j0 - 1] <= c[j0]:
        j0 -= 1
    rate = np.gradient(c, t)
    m = j0 + int(np.argmax(rate[j0:k + 1]))
    half = 0.5 * rate[m]
    if not half > 0:
        return math.nan
    a = m
    while a > 0 and rate[a - 1] >= half:
        a -= 1
    b = m
    while b < len(rate) - 1 and rate[b + 1] >= half:
        b += 1

    def cross(i0, i1):            # where the rate crosses ``half`` between samples i0 and i1
        r0, r1 = rate[i0], rate[i1]
        return t[i0] + (half - r0) / (r1 - r0) * (t[i1] - t[i0]) if r1 != r0 else t[i0]
    left = cross(a - 1, a) if a > 0 else t[0]
    right = cross(b, b + 1) if b < len(rate) - 1 else t[-1]
    return float(right - left)


def base_summary(times, base_force):
    """Per column of a recorded run: the :class:`Arrival` figures and the largest compressive and
    tensile base force, N (``base_force`` (n_t, n_columns)); [] without a record."""
    if base_force is None or np.size(base_force) == 0:
        return []
    b = np.asarray(base_force)
    out = []
    for c in range(b.shape[1]):
        d = first_arrival(times, b[:, c]).as_dict()
        pulse = pulse_arrival(times, b[:, c])
        d.update(column=c, max_N=float(b[:, c].max()), min_N=float(b[:, c].min()),
                 pulse_arrival_time_s=pulse.time_s, pulse_peak_time_s=pulse.peak_time_s,
                 pulse_rise_s=pulse.rise_s)
        out.append(d)
    return out
