"""The field the columns send into a host medium: a stated, cheap model.

The bases of the columns lie on the surface ``z = 0`` of a homogeneous, linear, lossless acoustic
medium of wave speed ``C`` (m/s) that fills ``z > 0`` (depth ``z``, m; the array along ``x``). Each
base pushes on the medium with its base force ``B_i(t)`` (N, :mod:`solver.analysis.support`),
normal to the surface: in the far field a normal force radiates as a dipole, with a pressure that
follows the rate of change of the force and the obliquity ``cos theta_i = z / R_i``. The model's
pressure (in units of N/s per spreading length, up to the medium's constant factor) is the
delay-and-sum

    p(r, t) = sum_i cos theta_i  s_i(t - R_i / C) / g(R_i),    s_i = dB_i/dt,  R_i = |r - X_i|,

with geometric spreading ``g(R) = sqrt(R / R0)`` in 2D (line sources along y, cylindrical waves)
or ``g(R) = R / R0`` in 3D (point sources, spherical waves), ``R0`` = 1 m, and ``R`` no smaller
than ``r_min`` (the column radius: the model says nothing closer to a base). One-way coupling:
the medium does not push back on the columns (the base is clamped), which holds while the
medium's impedance is far below the column's support stiffness. Not modelled: the near field of
a finite source, the 2D tail of cylindrical waves (the 2D model keeps only its far-field
amplitude), reflections at the surface, attenuation, dispersion, shear waves.

:func:`peak_map` evaluates ``max_t p(r, t)`` (the compressive peak) on a grid; :class:`PeakMap`
does the same for a uniformly sampled record fed in pieces (the node's ``~/field``);
:func:`image_grid` is the grid of the field images; :func:`focus_report` gives the figures of a
field at a focus (the peak there, the lateral and the axial peak).
"""
from __future__ import annotations

import numpy as np


def spreading(R, dims):
    """Geometric spreading factor g(R) (R in m, dims 2 or 3)."""
    if dims == 2:
        return np.sqrt(R)
    if dims == 3:
        return R
    raise ValueError(f'field: dims must be 2 or 3, got {dims!r}')


def source_rates(times, forces):
    """``s_i = dB_i/dt`` (n_t, n_columns) N/s of base forces (n_t, n_columns) N at ``times``."""
    return np.gradient(np.asarray(forces, dtype=np.float64), np.asarray(times), axis=0)


def pressure(points, times, sources, base_x, speed, dims=2, r_min=0.005):
    """``p(r, t)`` (n_points, n_t) at ``points`` (n_points, 2) = (x, z) m for the source
    histories ``sources`` (n_t, n_columns) N/s (:func:`source_rates`) sampled at ``times``
    (n_t,) s (zero outside the samples), bases at ``x = base_x`` (n_columns,) m, ``z = 0``."""
    points = np.asarray(points, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    sources = np.asarray(sources, dtype=np.float64)
    if not (np.isfinite(speed) and speed > 0):
        raise ValueError(f'field: medium speed must be a positive number, got {speed!r}')
    out = np.zeros((len(points), len(times)))
    for i, xb in enumerate(base_x):
        R = np.maximum(np.hypot(points[:, 0] - xb, points[:, 1]), r_min)
        shifted = times[None, :] - (R / speed)[:, None]
        out += np.interp(shifted, times, sources[:, i], left=0.0, right=0.0) \
            * (points[:, 1] / R / spreading(R, dims))[:, None]
    return out


def extended(times, sources, points, base_x, speed, r_min=0.005):
    """The record ``times`` (n_t,), ``sources`` (n_t, n_columns) continued with zero rates (the
    forces hold) at its mean step until the last sample has reached the farthest of ``points``
    (n, 2): the times over which a record's field lasts."""
    times = np.asarray(times, dtype=np.float64)
    sources = np.asarray(sources, dtype=np.float64)
    pts = np.asarray(points, dtype=np.float64)
    bx = np.asarray(base_x, dtype=np.float64)
    if len(times) < 2 or not len(pts):
        return times, sources
    reach = float(np.max(np.maximum(np.hypot(pts[:, 0, None] - bx[None, :], pts[:, 1, None]),
                                    r_min))) / speed
    dt = (times[-1] - times[0]) / (len(times) - 1)
    n = int(np.ceil(reach / dt)) + 1
    return (np.concatenate([times, times[-1] + dt * np.arange(1, n + 1)]),
            np.concatenate([sources, np.zeros((n, sources.shape[1]))]))


def peak_map(xs, zs, times, sources, base_x, speed, dims=2, r_min=0.005, chunk=4096):
    """``max_t p`` on the grid ``xs`` x ``zs``: (n_z, n_x), and the time (n_z, n_x) s of the
    peak, over the record and after it until its end has passed every point
    (:func:`extended`)."""
    X, Z = np.meshgrid(xs, zs)
    pts = np.stack([X.ravel(), Z.ravel()], axis=1)
    if not (np.isfinite(speed) and speed > 0):
        raise ValueError(f'field: medium speed must be a positive number, got {speed!r}')
    times, sources = extended(times, sources, pts, base_x, speed, r_min)
    peak = np.empty(len(pts))
    when = np.empty(len(pts))
    for a in range(0, len(pts), chunk):
        p = pressure(pts[a:a + chunk], times, sources, base_x, speed, dims, r_min)
        k = np.argmax(p, axis=1)
        peak[a:a + chunk] = p[np.arange(len(k)), k]
        when[a:a + chunk] = np.asarray(times)[k]
    return peak.reshape(X.shape), when.reshape(X.shape)


def frames(xs, zs, times, sources, base_x, speed, at, dims=2, r_min=0.005):
    """Snapshots ``p(r, t)`` (n_at, n_z, n_x) on the grid at the times ``at`` (s)."""
    X, Z = np.meshgrid(xs, zs)
    pts = np.stack([X.ravel(), Z.ravel()], axis=1)
    out = np.zeros((len(at), len(pts)))
    for i, xb in enumerate(base_x):
        R = np.maximum(np.hypot(pts[:, 0] - xb, pts[:, 1]), r_min)
        for k, t in enumerate(at):
            out[k] += np.interp(t - R / speed, times, sources[:, i], left=0.0, right=0.0) \
                * pts[:, 1] / R / spreading(R, dims)
    return out.reshape((len(at),) + X.shape)


def image_grid(base_x, n_x=64, n_z=48):
    """Cell centres ``(xs (n_x,), zs (n_z,))`` m of the field images: along the array from a
    quarter of its length ``L`` (the distance between the outer bases; 2 cm for one column)
    before the first base to a quarter after the last, and from the surface down to ``1.5 L``."""
    bx = np.asarray(base_x, dtype=np.float64)
    length = float(bx.max() - bx.min()) or 0.02
    x0, x1 = float(bx.min()) - 0.25 * length, float(bx.max()) + 0.25 * length
    xs = x0 + (x1 - x0) / n_x * (np.arange(n_x) + 0.5)
    zs = 1.5 * length / n_z * (np.arange(n_z) + 0.5)
    return xs, zs


class PeakMap:
    """``max_t p(r, t)`` at ``points`` (n_points, 2) = (x, z) m of a record of base forces
    sampled every ``dt`` s (zero rate before its first sample), fed in pieces by :meth:`extend`:
    :func:`peak_map` at the sample times, with the rate of each sample as ``np.gradient`` takes it
    (central differences; one-sided at the ends) and after the record until its end has passed
    every point (as :func:`extended`). A sample's pressure is taken once its rate is final (the
    next sample is in); the last one and the times after the record on :meth:`finish`.
    ``count``: sample times taken (the record's and, after :meth:`finish`, those after it)."""

    def __init__(self, points, base_x, speed, dt, dims=2, r_min=0.005):
        pts = np.asarray(points, dtype=np.float64)
        bx = np.asarray(base_x, dtype=np.float64)
        if not (np.isfinite(speed) and speed > 0):
            raise ValueError(f'field: medium speed must be a positive number, got {speed!r}')
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f'field: the sample step must be positive, got {dt!r}')
        R = np.maximum(np.hypot(pts[None, :, 0] - bx[:, None], pts[None, :, 1]), r_min)
        self.weight = pts[None, :, 1] / R / spreading(R, dims)        # (n_columns, n_points)
        delay = R / speed / dt                                       # in samples
        self.shift = np.floor(delay).astype(np.int64)
        self.frac = delay - self.shift
        self.dt = float(dt)
        self.peak = np.full(len(pts), -np.inf)
        self.count = 0
        self._forces = np.zeros((0, len(bx)))
        self._n = 0

    def extend(self, forces):
        """Append samples ``forces`` (n_new, n_columns) N and take every sample whose rate is
        final."""
        forces = np.atleast_2d(np.asarray(forces, dtype=np.float64))
        need = self._n + len(forces)
        if need > len(self._forces):
            grown = np.zeros((max(need, 2 * len(self._forces), 64), self._forces.shape[1]))
            grown[:self._n] = self._forces[:self._n]
            self._forces = grown
        self._forces[self._n:need] = forces
        self._n = need
        self._take(self._n - 1)

    def finish(self):
        """Take the last sample (its one-sided rate) and the times after the record, with zero
        rates, until the record's end has passed every point."""
        self._take(self._n + int(self.shift.max(initial=0)) + 2)

    def _rates(self):
        b = self._forces[:self._n]
        if self._n < 2:
            return np.zeros_like(b)
        return np.gradient(b, self.dt, axis=0)

    def _take(self, upto, chunk=2_000_000):
        if upto <= self.count or self._n == 0:
            return
        s = self._rates()
        n_pts = self.weight.shape[1]
        step = max(1, chunk // max(n_pts, 1))
        for k0 in range(self.count, upto, step):
            k = np.arange(k0, min(upto, k0 + step))
            p = np.zeros((n_pts, len(k)))
            n = len(s)
            for i in range(self.weight.shape[0]):
                j = k[None, :] - self.shift[i][:, None]          # sample at or after t - R / C
                u = self.frac[i][:, None]
                a = np.where((j >= 0) & (j < n), s[np.clip(j, 0, n - 1), i], 0.0)
                b = np.where((j >= 1) & (j <= n), s[np.clip(j - 1, 0, n - 1), i], 0.0)
                p += ((1.0 - u) * a + u * b) * self.weight[i][:, None]
            np.maximum(self.peak, p.max(axis=1), out=self.peak)
        self.count = upto


def focus_report(times, forces, base_x, focus, speed, spacing, dims=2, r_min=0.005, plane=True):
    """The field of a record at a focus ``(X, Z)`` m: ``p_focus`` (``max_t p`` at F), the lateral
    profile across the focal depth (``lateral_x_m``, ``lateral_peak``; x every ``spacing / 20``
    over the :func:`image_grid` range) with its peak ``lateral_peak_x_m`` and the offset
    ``lateral_offset_spacings`` = ``|x_peak - X| / spacing``, and ``axial_peak_z_m``, the depth
    of the largest ``max_t p`` along ``x = X`` (z every ``spacing / 20`` from the surface down to
    ``2 Z``), and the field's peak: ``peak_xz_m``, the point of the largest ``max_t p`` on the
    plane from the lateral profile's x range and from the surface down to ``2 Z`` (every
    ``spacing / 10``; left out with ``plane=False``), with ``peak_offset_spacings`` =
    ``|peak - F| / spacing``. ``times``
    (n_t,), ``forces`` (n_t, n_columns) N: the base-force record."""
    X, Z = (float(v) for v in focus)
    rates = source_rates(times, forces)
    xs, _ = image_grid(base_x)
    h = spacing / 20.0
    xl = np.arange(min(xs[0], X), max(xs[-1], X) + 0.5 * h, h)
    zl = np.arange(h, 2.0 * Z + 0.5 * h, h)
    lat, _ = peak_map(xl, [Z], times, rates, base_x, speed, dims, r_min)
    ax, _ = peak_map([X], zl, times, rates, base_x, speed, dims, r_min)
    at, _ = peak_map([X], [Z], times, rates, base_x, speed, dims, r_min)
    k = int(np.argmax(lat[0]))
    out = {}
    if plane:
        g = spacing / 10.0
        xp = np.arange(xl[0], xl[-1] + 0.5 * g, g)
        zp = np.arange(g, 2.0 * Z + 0.5 * g, g)
        pm, _ = peak_map(xp, zp, times, rates, base_x, speed, dims, r_min)
        iz, ix = np.unravel_index(int(np.argmax(pm)), pm.shape)
        peak = (float(xp[ix]), float(zp[iz]))
        out = {'peak_xz_m': peak,
               'peak_offset_spacings': float(np.hypot(peak[0] - X, peak[1] - Z) / spacing)}
    return {**out, 'p_focus': float(at[0, 0]), 'lateral_x_m': xl, 'lateral_peak': lat[0],
            'lateral_peak_x_m': float(xl[k]),
            'lateral_offset_spacings': float(abs(xl[k] - X) / spacing),
            'axial_peak_z_m': float(zl[int(np.argmax(ax[:, 0]))])}
