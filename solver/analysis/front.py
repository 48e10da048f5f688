"""The front of a pulse read as two strain gauges would, and the interpolation of sampled
histories it and the pulse tracker (:mod:`solver.analysis.observables`) share: a crossing of a
level between frames, a maximum refined by the parabola through its neighbours.
"""
from __future__ import annotations

import math

import numpy as np


def parabola(c0, c1, c2):
    """``(offset, value)`` of the vertex of the parabola through ``(-1, c0), (0, c1), (1, c2)``
    when it is a maximum inside ``[-1, 1]`` ((0, c1) otherwise)."""
    den = c0 - 2 * c1 + c2
    if den < 0:
        d = 0.5 * (c0 - c2) / den
        if -1.0 <= d <= 1.0:
            return d, c1 - 0.25 * (c0 - c2) * d
    return 0.0, c1


def vertex(values, k):
    """The per-frame maximum ``values[k]`` refined by the parabola through it and its two
    neighbouring frames (uniform output steps), where both exist and are finite."""
    if 0 < k < len(values) - 1 and np.isfinite(values[k - 1]) and np.isfinite(values[k + 1]):
        return float(parabola(values[k - 1], values[k], values[k + 1])[1])
    return float(values[k])


def crossing(times, values, k, level):
    """The time ``values`` reaches ``level`` between frames ``k - 1`` and ``k``, interpolated
    linearly; ``times[k]`` where there is no finite rising segment before frame ``k``."""
    if k > 0 and np.isfinite(values[k - 1]) and values[k] > values[k - 1]:
        return float(times[k - 1] + (level - values[k - 1]) / (values[k] - values[k - 1])
                     * (times[k] - times[k - 1]))
    return float(times[k])


def front_stations(n_prisms):
    """The two prisms, counted from the impacted end (0 = next to it), whose front arrivals
    (:func:`station_front`) give the front figures: a tenth and two fifths of the column (5
    and 20 of 50). ``None`` for a column too short to hold two stations two prisms apart."""
    near, far = int(round(n_prisms / 10)), int(round(2 * n_prisms / 5))
    return (near, far) if far - near >= 2 and far < n_prisms else None


# the compression (strain) at which a station registers the front: above the weak precursors
# that run ahead of strong pulses (1.5 % at 1 m/s on fb_column), below the pulses of the paper's
# regime (15 % at 0.1 m/s)
FRONT_LEVEL = 0.03


def station_front(times, compression, level=FRONT_LEVEL):
    """``(arrival, peak)`` of the front at one prism: the first time ``compression`` (n_t,)
    reaches ``level``, interpolated linearly between the two frames around the crossing, and the
    first maximum after it, refined by the parabola through it and its two neighbouring frames
    (uniform output steps). ``(nan, nan)`` when the level is never reached; the peak is NaN
    when the compression still rises at the history's end."""
    c = np.asarray(compression, dtype=float)
    above = np.nonzero(c >= level)[0]
    if not above.size:
        return math.nan, math.nan
    k = int(above[0])
    arrival = crossing(times, c, k, level)
    j = k
    while j + 1 < len(c) and c[j + 1] >= c[j]:
        j += 1
    if j == len(c) - 1:
        return arrival, math.nan
    return arrival, vertex(c, j)


def front_arrivals(times, from_impact):
    """``((near, far), (t_near, t_far), peak)``: the prisms of :func:`front_stations`, the
    front's arrival at each and its first peak at the far one (:func:`station_front`), from a
    strain history ``from_impact`` (n_t, n_prisms) ordered from the impacted end; None for a
    column too short for two stations or an empty history."""
    stations = front_stations(from_impact.shape[1])
    if stations is None or not len(times):
        return None
    near, far = stations
    t_near, _ = station_front(times, -from_impact[:, near])
    t_far, peak = station_front(times, -from_impact[:, far])
    return stations, (t_near, t_far), peak


def front_figures(times, from_impact, h0):
    """``(front_speed_m_s, front_amplitude, front_arrival_s)`` of :class:`Pulse` from a strain
    history ``from_impact`` (n_t, n_prisms) ordered from the impacted end: the front's arrivals
    (:func:`station_front`) at the two prisms of :func:`front_stations`, and its first peak of
    compression at the far one. NaN where the front does not reach a station, or the far
    station before the near one."""
    nan = math.nan
    front = front_arrivals(times, from_impact)
    if front is None:
        return nan, nan, nan
    (near, far), (t_near, t_far), peak = front
    if not (math.isfinite(t_near) and math.isfinite(t_far)) or t_far <= t_near:
        return nan, peak, t_far
    return (far - near) * h0 / (t_far - t_near), peak, t_far
