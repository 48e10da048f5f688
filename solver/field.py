"""The field the columns send into a host medium: a stated, cheap model.

The bases of the columns lie on the surface ``z = 0`` of a homogeneous, linear, lossless acoustic
medium of wave speed ``C`` (m/s) that fills ``z > 0`` (depth ``z``, m; the array along ``x``).
Each base pushes on the medium with its base force ``B_i(t)`` (N, :mod:`solver.support`), normal
to the surface: in the far field a normal force radiates as a dipole, with a pressure that follows
the rate of change of the force and the obliquity ``cos theta_i = z / R_i``. The model's pressure
(in units of N/s per spreading length, up to the medium's constant factor) is the delay-and-sum

    p(r, t) = sum_i cos theta_i  s_i(t - R_i / C) / g(R_i),    s_i = dB_i/dt,  R_i = |r - X_i|,

with geometric spreading ``g(R) = sqrt(R / R0)`` in 2D (line sources along y, cylindrical waves)
or ``g(R) = R / R0`` in 3D (point sources, spherical waves), ``R0`` = 1 m, and ``R`` no smaller
than ``r_min`` (the column radius: the model says nothing closer to a base). One-way coupling:
the medium does not push back on the columns (the base is clamped), which holds while the
medium's impedance is far below the column's support stiffness. Not modelled: the near field of
a finite source, the 2D tail of cylindrical waves (the 2D model keeps only its far-field
amplitude), reflections at the surface, attenuation, dispersion, shear waves.

:func:`peak_map` evaluates ``max_t p(r, t)`` (the compressive peak) on a grid.
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
    (n_t,) s (zero before the first sample), bases at ``x = base_x`` (n_columns,) m, ``z = 0``."""
    points = np.asarray(points, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    sources = np.asarray(sources, dtype=np.float64)
    if not (np.isfinite(speed) and speed > 0):
        raise ValueError(f'field: medium speed must be a positive number, got {speed!r}')
    out = np.zeros((len(points), len(times)))
    for i, xb in enumerate(base_x):
        R = np.maximum(np.hypot(points[:, 0] - xb, points[:, 1]), r_min)
        shifted = times[None, :] - (R / speed)[:, None]
        out += np.interp(shifted, times, sources[:, i], left=0.0, right=sources[-1, i]) \
            * (points[:, 1] / R / spreading(R, dims))[:, None]
    return out


def peak_map(xs, zs, times, sources, base_x, speed, dims=2, r_min=0.005, chunk=4096):
    """``max_t p`` on the grid ``xs`` x ``zs``: (n_z, n_x), and the time (n_z, n_x) s of the
    peak."""
    X, Z = np.meshgrid(xs, zs)
    pts = np.stack([X.ravel(), Z.ravel()], axis=1)
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
            out[k] += np.interp(t - R / speed, times, sources[:, i], left=0.0) \
                * pts[:, 1] / R / spreading(R, dims)
    return out.reshape((len(at),) + X.shape)
