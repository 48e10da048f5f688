"""The quasi-static force law of one tensegrity prism, F(h) = -dE/dh (docs/physics.md section 6).

The prism energy ``E(h)`` at height h, minimised over what a 1D chain does not carry (twist, base
radius) with the bar length fixed: closed form for rigid bases (:func:`rigid_force`), tabulated
for flexible bases (:func:`table_law`). Used by :mod:`solver.models.chain1d`; pure NumPy/SciPy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

GOLD = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass
class PrismLaw:
    """One prism's quasi-static law. ``kind`` 0 = rigid closed form with ``rigid`` = (r, b, L_s,
    k_s, n_cross, h_lock); 1 = table: grid ``lo``, ``dh``, ``fcoef`` (n - 1, 4) cubic pieces of
    F (N),
    ``ecoef`` (n - 1, 5) quartic pieces of E (J), ``phi``/``radius`` (n,) at the grid nodes."""
    kind: int
    rigid: np.ndarray
    lo: float = 0.0
    dh: float = 1.0
    fcoef: np.ndarray = None
    ecoef: np.ndarray = None
    phi: np.ndarray = None
    radius: np.ndarray = None


def cross_length(h, r, phi):
    """Cross-cable length m at height h, radius r, twist phi (rad)."""
    return np.sqrt(2.0 * r * r * (1.0 - np.cos(phi - 2.0 * math.pi / 3.0)) + h * h)


def twist(h, r, b):
    """Twist (rad, in [0, pi]) that keeps the bar length b at height h and radius r."""
    return np.arccos(np.clip(1.0 - (b * b - h * h) / (2.0 * r * r), -1.0, 1.0))


def prism_energy(h, r, phi, cross, bases):
    """Energy J of one prism: cross cables ``cross`` (k, L) pairs at length
    :func:`cross_length`, base cables ``bases`` (weight, k, L) at side ``sqrt(3) r``."""
    s = cross_length(h, r, phi)
    side = math.sqrt(3.0) * r
    e = 0.0
    for k, L in cross:
        e = e + 0.5 * k * np.maximum(s - L, 0.0) ** 2
    for wgt, k, L in bases:
        e = e + wgt * 0.5 * k * np.maximum(side - L, 0.0) ** 2
    return e


def rigid_force(h, r, b, L_s, k_s, n_cross=3):
    """Closed-form F(h) N of a rigid-base prism (docs/physics.md section 6); inf at and below the
    lock."""
    h = np.asarray(h, dtype=np.float64)
    phi = twist(h, r, b)
    s = np.sqrt(b * b + 2.0 * math.sqrt(3.0) * r * r * np.cos(phi + math.pi / 6.0))
    with np.errstate(divide='ignore', invalid='ignore'):
        ds = math.sqrt(3.0) * h * np.sin(phi + math.pi / 6.0) / (s * np.sin(phi))
        f = -n_cross * k_s * np.maximum(s - L_s, 0.0) * ds
    return np.where(h * h <= b * b - 4.0 * r * r, np.inf, f)


def minimise_energy(h, b, cross, bases, iters=90):
    """``(E*, phi*, r*)`` arrays: the prism energy at heights ``h`` (array, m) minimised over the
    twist phi in [pi/2, pi] (the base radius follows from the bar length b), by vectorised golden
    section."""
    h = np.asarray(h, dtype=np.float64)
    d2 = b * b - h * h

    def energy(phi):
        r = np.sqrt(d2 / (2.0 * (1.0 - np.cos(phi))))
        return prism_energy(h, r, phi, cross, bases), r

    lo = np.full(h.shape, math.pi / 2.0)
    hi = np.full(h.shape, math.pi)
    x1 = hi - GOLD * (hi - lo)
    x2 = lo + GOLD * (hi - lo)
    f1, f2 = energy(x1)[0], energy(x2)[0]
    for _ in range(iters):
        left = f1 < f2
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        x2n = np.where(left, x1, lo + GOLD * (hi - lo))
        x1n = np.where(left, hi - GOLD * (hi - lo), x2)
        x1, x2 = x1n, x2n
        fa = energy(x1)[0]
        fb = energy(x2)[0]
        f1, f2 = fa, fb
    phi = 0.5 * (lo + hi)
    e, r = energy(phi)
    return e, phi, r


def envelope_force(h, r, phi, cross, bases):
    """``F = -dE/dh`` N at the minimiser (envelope theorem). Where the minimum is interior in the
    radius (twist below 180 deg) the partial derivative is taken at fixed radius (the twist
    follows the bar length): it is insensitive to the minimiser's error in phi. At 180 deg (cross
    cables slack, the radius at the end of its range) it is taken at fixed twist, the radius
    following ``r^2 = (b^2 - h^2) / (2 (1 - cos phi))``: the minimum in phi is interior there."""
    s = cross_length(h, r, phi)
    folded = phi > math.pi - 1e-7
    with np.errstate(divide='ignore', invalid='ignore'):
        ds_r = h * (1.0 - np.sin(phi - 2.0 * math.pi / 3.0) / np.sin(phi)) / s   # fixed r
    dr = np.where(folded, -h / (2.0 * (1.0 - np.cos(phi)) * r), 0.0)         # fixed phi
    ds_phi = (2.0 * r * (1.0 - np.cos(phi - 2.0 * math.pi / 3.0)) * dr + h) / s
    ds = np.where(folded, ds_phi, ds_r)
    de = 0.0
    for k, L in cross:
        de = de + k * np.maximum(s - L, 0.0) * ds
    side = math.sqrt(3.0) * r
    for wgt, k, L in bases:
        de = de + wgt * k * np.maximum(side - L, 0.0) * math.sqrt(3.0) * dr
    return -de


def table_law(h0, b, cross, bases, lo_frac=0.02, hi_frac=1.5, n=2001):
    """A tabulated :class:`PrismLaw` over ``h in [lo_frac h0, min(hi_frac h0, 0.999 b)]``."""
    hi = min(hi_frac * h0, 0.999 * b)
    grid = np.linspace(lo_frac * h0, hi, n)
    _, phi, r = minimise_energy(grid, b, cross, bases)
    F = envelope_force(grid, r, phi, cross, bases)
    spl = CubicSpline(grid, F)
    anti = spl.antiderivative()          # E(h) = E(grid[0]) - int F
    e0 = float(minimise_energy(np.array([grid[0]]), b, cross, bases)[0][0])
    ecoef = -anti.c.T.copy()
    ecoef[:, -1] += e0
    return PrismLaw(kind=1, rigid=np.zeros(6), lo=float(grid[0]), dh=float(grid[1] - grid[0]),
                    fcoef=np.ascontiguousarray(spl.c.T), ecoef=np.ascontiguousarray(ecoef),
                    phi=phi, radius=r)


def poly_eval(h, lo, dh, coef):
    """The piecewise polynomial rows ``coef`` (n - 1, d) on the uniform grid (``lo``, ``dh``) at
    the heights ``h`` (array), clamped to the table (NumPy twin of
    ``solver.models.chain1d._piece``)."""
    h = np.asarray(h, dtype=np.float64)
    n = coef.shape[0]
    i = np.clip(((h - lo) / dh).astype(np.int64), 0, n - 1)
    t = h - (lo + i * dh)
    y = np.zeros_like(h)
    for j in range(coef.shape[1]):
        y = y * t + coef[i, j]
    return y
