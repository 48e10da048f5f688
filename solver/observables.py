"""Observables: strains, tensions, energy, constraint error, and the pulse tracker (physics.md
section 4).

All functions take plain arrays; shapes and units are in each docstring.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import dynamics as dyn


def state_summary(x, v, network, rest, EA, f_ext=None):
    """``(finite, energy J, prism heights (n_columns, n_prisms) m, relative constraint error)`` of
    a full state in one compiled call (:func:`solver.dynamics.state_summary`): what the
    divergence check and a frame need. The energy is kinetic + cable strain energy, minus the
    work potential of constant external forces ``f_ext`` (n_nodes, 3) N when given."""
    from .models import full_summary_arrays
    levels = network.levels
    heights = np.empty((levels.shape[0], max(levels.shape[1] - 1, 0)))
    net, act = dyn.pack(network, rest, EA, f_ext)
    finite, e, cerr, _ = dyn.state_summary(
        np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(v, dtype=np.float64),
        net, act, full_summary_arrays(network), heights)
    return finite, e, heights, cerr


def prism_heights(x, levels):
    """Prism heights (n_columns, n_prisms) m: mean z of level i+1 minus mean z of level i.

    ``x`` (n_nodes, 3) m, ``levels`` (n_columns, n_levels, 3) node indices."""
    out = np.empty((levels.shape[0], max(levels.shape[1] - 1, 0)))
    dyn.level_heights(np.ascontiguousarray(x, dtype=np.float64), levels, out)
    return out


def prism_strains(x, levels, h0):
    """Axial strain per prism (n_columns, n_prisms): ``(h - h0) / h``, negative in compression."""
    h = prism_heights(x, levels)
    return (h - h0) / h


def cable_tensions(x, network, rest, EA):
    """Tension per cable (n_cables,) N (zero when slack)."""
    out = np.zeros(network.n_cables)
    dyn.cable_tensions(x, network.cable_a, network.cable_b, rest, EA, out)
    return out


def kinetic_energy(v, network):
    """Kinetic energy J of node velocities ``v`` (n_nodes, 3) m/s (lumped and bar masses)."""
    return dyn.kinetic_energy(v, network.node_mass, network.clamped, network.bar_a, network.bar_b,
                              network.bar_mass)


def constraint_error(x, network):
    """max over rigid members of ``|(|b|^2 - L^2) / 2| / L^2`` (about the relative length
    error)."""
    if network.n_constraints == 0:
        return 0.0
    b = x[network.con_head] - x[network.con_tail]
    L2 = network.con_length ** 2
    return float(np.max(np.abs(0.5 * (np.einsum('ij,ij->i', b, b) - L2)) / L2))


@dataclass
class Pulse:
    """Leading-pulse figures of one column (physics.md section 4).

    ``amplitude`` is the |strain| of the leading pulse at ``t_ref`` (or the nearest tracked time);
    ``amplitude_median/min/max`` over the window where the peak is in prisms ``window``;
    ``speed_m_s``
    the slope of peak position against time there; ``width_prisms`` the number of contiguous prisms
    around the peak with ``|eps| >= 0.5 |eps_peak|`` at ``t_ref``. NaN where the pulse never
    reached the window."""
    amplitude: float
    amplitude_median: float
    amplitude_min: float
    amplitude_max: float
    speed_m_s: float
    width_prisms: int
    t_ref: float
    arrival_time_s: float

    def as_dict(self):
        return {'amplitude': self.amplitude, 'amplitude_median': self.amplitude_median,
                'amplitude_min': self.amplitude_min, 'amplitude_max': self.amplitude_max,
                'speed_m_s': self.speed_m_s, 'width_prisms': self.width_prisms,
                't_ref': self.t_ref, 'arrival_time_s': self.arrival_time_s}


def leading_peak(eps, threshold=0.25, floor=1e-6):
    """Index (from the impacted end, 0 = prism next to it) and strain of the leading compressive
    peak of one strain profile ``eps`` (n_prisms,), ordered from the impacted end. The front is the
    farthest
    prism whose compression exceeds ``threshold`` times the largest compression of the profile; the
    peak is the local minimum reached walking back from the front. ``(nan, nan)`` when at rest (no
    compression above ``floor``, which keeps round-off noise from being tracked as a pulse)."""
    comp = -eps
    top = comp.max()
    if not top > floor:
        return np.nan, np.nan
    above = np.nonzero(comp >= threshold * top)[0]
    i = above[-1]
    while i > 0 and comp[i - 1] >= comp[i]:
        i -= 1
    pos = float(i)
    if 0 < i < len(eps) - 1:      # parabolic refinement of the peak position
        c0, c1, c2 = comp[i - 1], comp[i], comp[i + 1]
        den = c0 - 2 * c1 + c2
        if den < 0:
            pos += 0.5 * (c0 - c2) / den
    return pos, eps[i]


def track_pulse(times, strains, h0, window=(10, 40), t_ref=0.5):
    """Pulse figures from a strain history of one column.

    ``times`` (n_t,) s, ``strains`` (n_t, n_prisms) with prism 0 at the clamped end and the impact
    at the last prism, ``h0`` m. Returns a :class:`Pulse`."""
    times = np.asarray(times)
    strains = np.asarray(strains)
    from_impact = strains[:, ::-1]
    n = strains.shape[1]
    pos = np.full(len(times), np.nan)
    amp = np.full(len(times), np.nan)
    for k, eps in enumerate(from_impact):
        pos[k], e = leading_peak(eps)
        amp[k] = abs(e)
    inside = (pos >= window[0]) & (pos <= window[1])
    nan = float('nan')
    if inside.sum() >= 2:
        speed = float(np.polyfit(times[inside], pos[inside], 1)[0] * h0)
        a_in = amp[inside]
        med, lo, hi = float(np.median(a_in)), float(a_in.min()), float(a_in.max())
        arrival = float(times[inside][0])
    else:
        speed = med = lo = hi = arrival = nan
    k_ref = int(np.argmin(np.abs(times - t_ref)))
    width = 0
    amplitude = float(amp[k_ref]) if np.isfinite(amp[k_ref]) else nan
    if np.isfinite(pos[k_ref]):
        eps = from_impact[k_ref]
        i = int(round(pos[k_ref]))
        i = min(max(i, 0), n - 1)
        half = 0.5 * abs(amp[k_ref])
        lo_i = i
        while lo_i > 0 and abs(eps[lo_i - 1]) >= half:
            lo_i -= 1
        hi_i = i
        while hi_i < n - 1 and abs(eps[hi_i + 1]) >= half:
            hi_i += 1
        width = hi_i - lo_i + 1 if abs(eps[i]) >= half else 0
    return Pulse(amplitude, med, lo, hi, speed, int(width), float(times[k_ref]), arrival)


def first_passage(times, strain, h0, t_ref=0.5):
    """:func:`~solver.track_pulse` on the history up to the time the leading peak
    first reaches the clamped end (``n_prisms - 2`` prisms from the impact), so that a reflected
    wave never enters the speed fit; amplitude and width at ``t_ref`` are NaN / 0 when the pulse
    has already reached the end by then. ``strain`` (n_t, n_prisms) of one column."""
    n = strain.shape[1]
    end = len(times)
    for k in range(len(times)):
        pos, _ = leading_peak(strain[k, ::-1])
        if math.isfinite(pos) and pos >= n - 2:
            end = k + 1
            break
    p = track_pulse(times[:end], strain[:end], h0, t_ref=t_ref)
    if times[end - 1] < t_ref - 1e-9:
        p.amplitude, p.width_prisms = math.nan, 0
    return p
