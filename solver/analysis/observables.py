"""Observables: strains, tensions, energy, constraint error, and the pulse tracker (docs/physics.md
section 4).

All functions take plain arrays; shapes and units are in each docstring.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from solver.kernels import records
from solver.kernels import summary
from solver.analysis.front import crossing, front_figures, parabola, vertex


def state_summary(x, v, network, rest, EA, f_ext=None):
    """``(finite, energy J, prism heights (n_columns, n_prisms) m, relative constraint error)`` of
    a full state in one compiled call (:func:`solver.kernels.summary.state_summary`): what the
    divergence check and a frame need. The energy is kinetic + cable strain energy, minus the
    work potential of constant external forces ``f_ext`` (n_nodes, 3) N when given."""
    from solver.models.full3d import full_summary_arrays
    levels = network.levels
    heights = np.empty((levels.shape[0], max(levels.shape[1] - 1, 0)))
    sm = full_summary_arrays(network)
    m = records.bare_model(network.topology(), sm, sm.levels)
    x = np.ascontiguousarray(x, dtype=np.float64)
    v = np.ascontiguousarray(v, dtype=np.float64)
    f = np.zeros((network.n_nodes, 3)) if f_ext is None else np.array(f_ext, dtype=np.float64)
    d = records.data_of(x, v, np.array(rest, dtype=np.float64), np.array(EA, dtype=np.float64), f)
    finite, e, cerr, _ = summary.state_summary(x, v, m, d, heights)
    return finite, e, heights, cerr


def prism_heights(x, levels):
    """Prism heights (n_columns, n_prisms) m: mean z of level i+1 minus mean z of level i.

    ``x`` (n_nodes, 3) m, ``levels`` (n_columns, n_levels, 3) node indices."""
    out = np.empty((levels.shape[0], max(levels.shape[1] - 1, 0)))
    summary.level_heights(np.ascontiguousarray(x, dtype=np.float64), levels, out)
    return out


def prism_strains(x, levels, h0):
    """Axial strain per prism (n_columns, n_prisms): ``(h - h0) / h``, negative in compression."""
    return strains_of_heights(prism_heights(x, levels), h0)


def strains_of_heights(h, h0):
    """Axial strains ``(h - h0) / h`` of prism heights ``h`` (any shape), element by element."""
    return (h - h0) / h


def cable_tensions(x, network, rest, EA):
    """Tension per cable (n_cables,) N (zero when slack)."""
    out = np.zeros(network.n_cables)
    summary.cable_tensions(x, network.cable_a, network.cable_b, rest, EA, out)
    return out


def kinetic_energy(v, network):
    """Kinetic energy J of node velocities ``v`` (n_nodes, 3) m/s (lumped and bar masses)."""
    return summary.kinetic_energy(v, network.node_mass, network.clamped, network.bar_a,
                                  network.bar_b, network.bar_mass)


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
    """Leading-pulse figures of one column (docs/physics.md section 4).

    Every figure comes from the interpolated peak of each output frame (:func:`leading_peak`: a
    parabola through the three prisms around the extreme gives its position and value between
    prisms), so that the figures move continuously with the parameters of the run.

    ``amplitude`` is the |strain| of the leading pulse at ``t_ref``, interpolated linearly in time
    between the two output frames around ``t_ref`` (the nearest tracked time when the history
    does not reach ``t_ref``); ``amplitude_median/min/max`` over the window
    where the peak is in prisms ``window``; ``amplitude_passage_max`` the largest |strain| of the
    peak over the history given (the first passage in :func:`first_passage`) once the peak is
    ``window[0]`` prisms or more from the impacted end (the strain concentrated at the impacted
    end right after the impact is not the pulse), refined by a parabola through the per-frame
    values around the largest one. ``speed_m_s`` is the slope of
    peak position against time in the window; ``speed_snapshot_m_s`` the peak position at
    ``t_ref`` (prisms from the impacted end, times ``h0``) divided by ``t_ref``;
    ``speed_arrival_m_s`` the distance to the clamped end (``n_prisms - 2`` prisms from the
    impacted end) divided by the time the peak reaches it, ``arrival_end_s`` (interpolated
    between frames). ``width_prisms`` is the number of contiguous prisms around the peak with
    ``|eps| >= 0.5 |eps_peak|`` at the frame nearest ``t_ref``; ``width_half_prisms`` and
    ``width_10_prisms`` the widths at half and at 10 % of the peak, with the crossings
    interpolated linearly between prisms and the widths linearly in time. ``arrival_time_s`` is
    the first time the peak is in the window. NaN where the pulse never reached the window (the
    widths: where there is no pulse at ``t_ref``).

    ``speed_paper_m_s`` is the paper's reading of a speed: the peak position at ``t_ref`` rounded
    to whole prisms, times ``h0``, over ``t_ref`` ("the peak moved 20 prisms in 0.5 s").

    The front figures read the column as two strain gauges would (:mod:`solver.analysis.front`,
    at prisms 5 and 20 from the impacted end of 50): ``front_arrival_s`` the time the far
    station's compression first reaches ``FRONT_LEVEL``,
    ``front_speed_m_s`` the stations' distance over the time between their arrivals,
    ``front_amplitude`` the |strain| of the far station's first peak after the arrival. They
    depend on the front alone, not on where the peak is at one moment, and stay determined
    after strong impacts whose later response is chaotic (docs/physics.md section 7.1).

    The momentum figures (:func:`pulse_momentum`, filled in by a run that has the node
    velocities at the frame nearest ``t_ref``; NaN otherwise) describe the leading pulse at that
    frame over its prisms, the contiguous prisms around the peak whose ``|eps|`` is at least 10 %
    of the peak's: ``momentum_strain`` kg m/s, ``m V sum(delta_i)`` (m the unit mass, V
    ``speed_m_s``, ``delta_i = (h_i - h0) / h0 = eps_i / (1 - eps_i)`` the shortening of prism
    i), what a pulse of permanent shape carries; ``momentum_nodes`` kg m/s, the momentum of the
    nodes of those prisms (lumped and bar masses) along the column; both positive towards the
    clamped end; ``momentum_ratio`` the first over the second; ``width_eff_prisms`` W =
    ``sum(eps_i) / eps_peak``; ``momentum_share`` f = ``momentum_nodes / (m v0)``, the share of
    the impact's momentum (``v0`` of the first impact); ``momentum_prisms`` the number of prisms
    summed; ``momentum_column`` kg m/s the momentum of the whole column at that frame (before
    the pulse reaches the clamped end: what the impact gave it)."""
    amplitude: float
    amplitude_median: float
    amplitude_min: float
    amplitude_max: float
    speed_m_s: float
    width_prisms: int
    t_ref: float
    arrival_time_s: float
    amplitude_passage_max: float = math.nan
    speed_snapshot_m_s: float = math.nan
    speed_arrival_m_s: float = math.nan
    arrival_end_s: float = math.nan
    width_half_prisms: float = math.nan
    width_10_prisms: float = math.nan
    speed_paper_m_s: float = math.nan
    front_speed_m_s: float = math.nan
    front_amplitude: float = math.nan
    front_arrival_s: float = math.nan
    momentum_strain: float = math.nan
    momentum_nodes: float = math.nan
    momentum_ratio: float = math.nan
    width_eff_prisms: float = math.nan
    momentum_share: float = math.nan
    momentum_prisms: int = 0
    momentum_column: float = math.nan

    def as_dict(self):
        return {'amplitude': self.amplitude, 'amplitude_median': self.amplitude_median,
                'amplitude_min': self.amplitude_min, 'amplitude_max': self.amplitude_max,
                'amplitude_passage_max': self.amplitude_passage_max,
                'speed_m_s': self.speed_m_s, 'speed_snapshot_m_s': self.speed_snapshot_m_s,
                'speed_arrival_m_s': self.speed_arrival_m_s,
                'width_prisms': self.width_prisms, 'width_half_prisms': self.width_half_prisms,
                'width_10_prisms': self.width_10_prisms,
                't_ref': self.t_ref, 'arrival_time_s': self.arrival_time_s,
                'arrival_end_s': self.arrival_end_s, 'speed_paper_m_s': self.speed_paper_m_s,
                'front_speed_m_s': self.front_speed_m_s, 'front_amplitude': self.front_amplitude,
                'front_arrival_s': self.front_arrival_s,
                'momentum_strain': self.momentum_strain, 'momentum_nodes': self.momentum_nodes,
                'momentum_ratio': self.momentum_ratio, 'width_eff_prisms': self.width_eff_prisms,
                'momentum_share': self.momentum_share, 'momentum_prisms': self.momentum_prisms,
                'momentum_column': self.momentum_column}


def _peak_index(eps, threshold=0.25, floor=1e-6):
    comp = -eps
    top = comp.max()
    if not top > floor:
        return -1
    above = np.nonzero(comp >= threshold * top)[0]
    i = above[-1]
    while i > 0 and comp[i - 1] >= comp[i]:
        i -= 1
    return int(i)


def leading_peak(eps, threshold=0.25, floor=1e-6):
    """Position (prisms from the impacted end, 0 = prism next to it) and strain of the leading
    compressive peak of one strain profile ``eps`` (n_prisms,), ordered from the impacted end.
    The front is the farthest prism whose compression exceeds ``threshold`` times the largest
    compression of the profile; the peak is the local minimum reached walking back from the
    front, refined by the parabola through it and its two neighbours (position and strain between
    prisms). ``(nan, nan)`` when at rest (no compression above ``floor``, which keeps round-off
    noise from being tracked as a pulse)."""
    i = _peak_index(eps, threshold, floor)
    if i < 0:
        return np.nan, np.nan
    if 0 < i < len(eps) - 1:
        d, c = parabola(-eps[i - 1], -eps[i], -eps[i + 1])
        return float(i + d), -float(c)
    return float(i), float(eps[i])


def pulse_width(eps, pos, amplitude, fraction):
    """Width in prisms of the pulse around ``pos`` (prisms, :func:`leading_peak`) of the profile
    ``eps`` (n_prisms,) at ``fraction`` of ``amplitude`` (|strain|): the distance between the two
    points where ``|eps|`` falls below ``fraction * amplitude``, each interpolated linearly between
    the last prism above and the first below (a profile still above the level at its end stops
    there). NaN without a peak."""
    if not (math.isfinite(pos) and math.isfinite(amplitude) and amplitude > 0):
        return math.nan
    a = np.abs(np.asarray(eps, dtype=float))
    n = len(a)
    level = fraction * amplitude
    i = min(max(int(round(pos)), 0), n - 1)
    if a[i] < level:
        return 0.0
    lo = i
    while lo > 0 and a[lo - 1] >= level:
        lo -= 1
    left = float(lo)
    if lo > 0:
        left = lo - (a[lo] - level) / (a[lo] - a[lo - 1])
    hi = i
    while hi < n - 1 and a[hi + 1] >= level:
        hi += 1
    right = float(hi)
    if hi < n - 1:
        right = hi + (a[hi] - level) / (a[hi] - a[hi + 1])
    return right - left


def _at_time(times, values, t):
    """``values`` interpolated linearly at ``t`` between the two frames around it (NaN outside the
    history or where one of the two is NaN)."""
    if not len(times) or t < times[0] - 1e-9 or t > times[-1] + 1e-9:
        return math.nan
    k = int(np.searchsorted(times, t))
    if k < len(times) and abs(times[k] - t) <= 1e-9:
        return float(values[k])
    if k > 0 and abs(times[k - 1] - t) <= 1e-9:
        return float(values[k - 1])
    k = min(max(k, 1), len(times) - 1)
    t0, t1 = times[k - 1], times[k]
    w = (t - t0) / (t1 - t0)
    return float((1 - w) * values[k - 1] + w * values[k])


def _max_over_time(times, amp):
    """Largest of the per-frame values ``amp`` (NaN ignored), refined by :func:`vertex`."""
    if not np.any(np.isfinite(amp)):
        return math.nan
    return vertex(amp, int(np.nanargmax(amp)))


def _peaks(from_impact, threshold=0.25, floor=1e-6):
    """:func:`leading_peak` of every frame: positions and |strains| (n_t,) each, all frames at
    once with its operations element by element (the same values)."""
    eps = np.asarray(from_impact, dtype=float)
    n_t = len(eps)
    pos = np.full(n_t, np.nan)
    amp = np.full(n_t, np.nan)
    if n_t == 0 or eps.shape[1] == 0:
        return pos, amp
    comp = -eps
    with np.errstate(invalid='ignore'):
        top = comp.max(axis=1)
        rows = np.flatnonzero(top > floor)          # the frames with a peak (_peak_index)
        comp, eps = comp[rows], eps[rows]
        n_p = comp.shape[1]
        front = n_p - 1 - np.argmax((comp >= threshold * top[rows, None])[:, ::-1], axis=1)
        # walking back from the front while the compression does not fall: to the last prism
        # at or before it where it fell (or prism 0)
        fell = np.ones(comp.shape, dtype=bool)
        fell[:, 1:] = ~(comp[:, :-1] >= comp[:, 1:])
        last = np.maximum.accumulate(np.where(fell, np.arange(n_p), 0), axis=1)
        i = last[np.arange(len(rows)), front]
    inner = (i > 0) & (i < n_p - 1)
    pos[rows] = i
    amp[rows] = np.abs(eps[np.arange(len(rows)), i])
    k, j = np.flatnonzero(inner), i[inner]
    c0, c1, c2 = -eps[k, j - 1], -eps[k, j], -eps[k, j + 1]     # front.parabola, elementwise
    den = c0 - 2 * c1 + c2
    with np.errstate(divide='ignore', invalid='ignore'):
        d = 0.5 * (c0 - c2) / den
    vertex_in = (den < 0) & (-1.0 <= d) & (d <= 1.0)
    with np.errstate(invalid='ignore'):
        pos[rows[k]] = np.where(vertex_in, j + d, j + 0.0)
        amp[rows[k]] = np.abs(-np.where(vertex_in, c1 - 0.25 * (c0 - c2) * d, c1))
    return pos, amp


def _near(times, t):
    """The frames :func:`_at_time` may read at ``t`` (a mask of ``times``)."""
    near = np.zeros(len(times), dtype=bool)
    k = int(np.searchsorted(times, t))
    near[max(k - 2, 0):k + 2] = True
    return near


def track_pulse(times, strains, h0, window=(10, 40), t_ref=0.5, peaks=None):
    """Pulse figures from a strain history of one column.

    ``times`` (n_t,) s, ``strains`` (n_t, n_prisms) with prism 0 at the clamped end and the impact
    at the last prism, ``h0`` m. ``peaks``: the ``(positions, |strains|)`` of the frames'
    leading peaks when already found. Returns a :class:`Pulse`."""
    times = np.asarray(times, dtype=float)
    strains = np.asarray(strains)
    from_impact = strains[:, ::-1]
    n = strains.shape[1]
    pos, amp = _peaks(from_impact) if peaks is None else peaks
    inside = (pos >= window[0]) & (pos <= window[1])
    # only the first passage through the window: once the peak has left it at the far end, a
    # peak found inside again is the wave reflected from the clamped end (a peak that stops
    # just short of the end never triggers the cut of first_passage)
    beyond = np.nonzero(pos > window[1])[0]
    if beyond.size:
        inside[beyond[0]:] = False
    nan = float('nan')
    if inside.sum() >= 2:
        speed = float(np.polyfit(times[inside], pos[inside], 1)[0] * h0)
        a_in = amp[inside]
        med, lo, hi = float(np.median(a_in)), float(a_in.min()), float(a_in.max())
        arrival = float(times[inside][0])
    else:
        speed = med = lo = hi = arrival = nan
    # arrival at the clamped end: the peak's position crosses n - 2 (interpolated in time)
    arrival_end = speed_arrival = nan
    end = n - 2
    reached = np.nonzero(pos >= end)[0]
    if end > 0 and reached.size:
        arrival_end = crossing(times, pos, int(reached[0]), end)
        if arrival_end > 0:
            speed_arrival = end * h0 / arrival_end
    k_ref = int(np.argmin(np.abs(times - t_ref))) if len(times) else 0
    width = 0
    amplitude = _at_time(times, amp, t_ref)
    if not math.isfinite(amplitude) and len(times) and (t_ref < times[0] or t_ref > times[-1]):
        amplitude = float(amp[k_ref])          # a history that ends before t_ref: its last peak
    pos_ref = _at_time(times, pos, t_ref)
    snapshot = pos_ref * h0 / t_ref if t_ref > 0 else nan
    paper = round(pos_ref) * h0 / t_ref if t_ref > 0 and math.isfinite(pos_ref) else nan
    near = _near(times, t_ref)          # the widths are read at t_ref only
    halves = np.array([pulse_width(from_impact[k], pos[k], amp[k], 0.5) if near[k] else math.nan
                       for k in range(len(times))])
    tenths = np.array([pulse_width(from_impact[k], pos[k], amp[k], 0.1) if near[k] else math.nan
                       for k in range(len(times))])
    if len(times) and np.isfinite(pos[k_ref]):
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
    front_speed, front_amplitude, front_arrival = front_figures(times, from_impact, h0)
    return Pulse(amplitude, med, lo, hi, speed, int(width),
                 float(times[k_ref]) if len(times) else t_ref, arrival,
                 amplitude_passage_max=_max_over_time(times, np.where(pos >= window[0], amp,
                                                                      np.nan)),
                 speed_snapshot_m_s=float(snapshot), speed_arrival_m_s=speed_arrival,
                 speed_paper_m_s=float(paper), front_speed_m_s=front_speed,
                 front_amplitude=front_amplitude, front_arrival_s=front_arrival,
                 arrival_end_s=arrival_end, width_half_prisms=_at_time(times, halves, t_ref),
                 width_10_prisms=_at_time(times, tenths, t_ref))


def first_passage(times, strain, h0, t_ref=0.5):
    """:func:`~solver.track_pulse` on the history up to the time the leading peak
    first reaches the clamped end (``n_prisms - 2`` prisms from the impact), so that a reflected
    wave never enters the speed fit; the figures at ``t_ref`` (amplitude, widths, snapshot speed)
    are NaN (width 0) when the pulse has already reached the end by then. ``strain`` (n_t,
    n_prisms) of one column."""
    n = strain.shape[1]
    pos, amp = _peaks(np.asarray(strain)[:, ::-1])
    reached = np.nonzero(pos >= n - 2)[0]          # NaN compares False
    end = int(reached[0]) + 1 if reached.size else len(times)
    p = track_pulse(times[:end], strain[:end], h0, t_ref=t_ref, peaks=(pos[:end], amp[:end]))
    if times[end - 1] < t_ref - 1e-9:
        p.amplitude, p.width_prisms = math.nan, 0
        p.width_half_prisms = p.width_10_prisms = p.speed_snapshot_m_s = math.nan
        p.speed_paper_m_s = math.nan
    return p


def momentum_masses(network):
    """Mass (n_nodes,) kg that carries each node's velocity into the momentum: its lumped mass
    and half of the mass of every bar at it (a uniform rod's momentum is its mass times the mean
    of its two ends' velocities)."""
    mass = np.array(network.node_mass, dtype=float)
    if network.n_bars:
        np.add.at(mass, network.bar_a, 0.5 * network.bar_mass)
        np.add.at(mass, network.bar_b, 0.5 * network.bar_mass)
    return mass


def level_momenta(v, levels, mass):
    """Axial momentum (n_columns, n_levels) kg m/s of every base level: the sum of ``mass *
    v_z`` over its three nodes. ``v`` (n_nodes, 3) m/s, ``mass`` (n_nodes,)
    (:func:`momentum_masses`)."""
    return np.einsum('cln,cln->cl', mass[levels], np.asarray(v)[levels, 2])


def pulse_momentum(pulse, eps, p_level, unit_mass, v0, fraction=0.1):
    """Fill the momentum figures of ``pulse`` (:class:`Pulse`; its ``speed_m_s`` is V) from one
    frame: ``eps`` (n_prisms,) strains and ``p_level`` (n_levels,) axial level momenta
    (:func:`level_momenta`), prism 0 and level 0 at the clamped end, prism i between levels i and
    i + 1. The pulse's prisms are the contiguous prisms around the leading peak
    (:func:`leading_peak`) with ``|eps| >= fraction |eps_peak|``. Their nodes' momentum: each
    level between two of them counts whole, a level at the edge of the range half (the other
    half belongs to the prism beyond), the clamped and the impacted end levels whole (they
    belong to one prism only). Returns ``pulse``."""
    eps = np.asarray(eps, dtype=float)
    n = len(eps)
    from_impact = eps[::-1]
    pos, e = leading_peak(from_impact)
    if not (math.isfinite(pos) and e < 0):
        return pulse
    a = np.abs(from_impact)
    level = fraction * abs(e)
    i = min(max(int(round(pos)), 0), n - 1)
    lo = hi = i
    while lo > 0 and a[lo - 1] >= level:
        lo -= 1
    while hi < n - 1 and a[hi + 1] >= level:
        hi += 1
    first, last = n - 1 - hi, n - 1 - lo          # the range in prisms from the clamped end
    weights = np.zeros(n + 1)
    weights[first:last + 2] = 1.0
    if first > 0:
        weights[first] = 0.5
    if last + 1 < n:
        weights[last + 1] = 0.5
    p_nodes = -float(np.dot(weights, p_level))    # positive towards the clamped end
    band = eps[first:last + 1]
    shortening = band / (1.0 - band)              # (h - h0) / h0
    p_strain = -unit_mass * pulse.speed_m_s * float(shortening.sum())
    pulse.momentum_strain = p_strain
    pulse.momentum_nodes = p_nodes
    pulse.momentum_ratio = p_strain / p_nodes if p_nodes else math.nan
    pulse.width_eff_prisms = float(band.sum() / e)
    pulse.momentum_share = p_nodes / (unit_mass * v0) if v0 else math.nan
    pulse.momentum_prisms = int(last - first + 1)
    pulse.momentum_column = -float(np.sum(p_level))
    return pulse


def prism_twists(x, levels):
    """Relative twist (n_columns, n_prisms) rad in (-pi, pi] of the top base of each prism about
    its bottom base (node 0 of each level about the level's centroid, in the xy plane). Its sign
    stays that of the reference twist (+-150 deg) unless the bars cross: through 180 deg (past the
    rigid-base lock) or through 0. ``x`` (n_nodes, 3) m, ``levels`` (n_columns, n_levels, 3)."""
    centre = x[levels].mean(axis=2)                       # (n_columns, n_levels, 3)
    r = x[levels[:, :, 0]] - centre
    a, b = r[:, :-1], r[:, 1:]
    return np.arctan2(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
                      a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1])
