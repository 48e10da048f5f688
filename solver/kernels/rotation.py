"""Kernels for members joined to a ROTATED IMAGE of their head node (the ``sym3d`` model).

A member ``c`` with rotation index ``r = rot[c]`` in {0, 1, 2} joins ``x[tail]`` to ``R^r
x[head]``,
``R`` the rotation by 2 pi / 3 about z; its force on the image is rotated back onto the head node
(``R^-r``). :mod:`solver.kernels.dynamics` dispatches to these kernels when the rotation slots of
its
``net`` tuple are not empty (see :mod:`solver.models.sym3d`). Shapes as in
:mod:`solver.kernels.dynamics`.
"""
import math

import numpy as np

from solver.compiled import jit, jit_inline

# R^r = [[C[r], -S[r], 0], [S[r], C[r], 0], [0, 0, 1]]: rotation by 2 pi r / 3 about z
ROT_C = np.array([1.0, -0.5, -0.5])
ROT_S = np.array([0.0, math.sqrt(3.0) / 2.0, -math.sqrt(3.0) / 2.0])


@jit_inline
def expand(a, rep, cos, sin, out):
    """``out[p] = Rz(angle_p) a[rep[p]]`` with ``cos``/``sin`` of each full node's angle: a
    reduced (``sym3d``) array expanded to the full network."""
    for p in range(rep.shape[0]):
        q = rep[p]
        out[p, 0] = cos[p] * a[q, 0] - sin[p] * a[q, 1]
        out[p, 1] = sin[p] * a[q, 0] + cos[p] * a[q, 1]
        out[p, 2] = a[q, 2]


@jit_inline
def rel(u, t, h, rot, c):
    """``R^r u[h] - u[t]`` with ``r = rot[c]`` (r = 0 when ``rot`` is empty): a 3-tuple. Inlined
    by numba where it is called (a call would cost more than the member loop around it)."""
    if rot.shape[0] == 0:
        return u[h, 0] - u[t, 0], u[h, 1] - u[t, 1], u[h, 2] - u[t, 2]
    cr = ROT_C[rot[c]]
    sr = ROT_S[rot[c]]
    return (cr * u[h, 0] - sr * u[h, 1] - u[t, 0], sr * u[h, 0] + cr * u[h, 1] - u[t, 1],
            u[h, 2] - u[t, 2])


@jit_inline
def image_chord(u, a, b, cr, sr):
    """``R u[b] - u[a]`` for the rotation of cosine ``cr`` and sine ``sr`` about z: a 3-tuple."""
    return cr * u[b, 0] - sr * u[b, 1] - u[a, 0], sr * u[b, 0] + cr * u[b, 1] - u[a, 1], \
        u[b, 2] - u[a, 2]


@jit_inline
def cable_chord(x, cable_a, cable_b, cable_rot, c):
    """Cable ``c``: its nodes a and b, the cosine and sine of its rotation (1, 0 when
    ``cable_rot`` is empty) and the chord ``R x_b - x_a``."""
    a = cable_a[c]
    b = cable_b[c]
    cr = 1.0
    sr = 0.0
    if cable_rot.shape[0] > 0:
        cr = ROT_C[cable_rot[c]]
        sr = ROT_S[cable_rot[c]]
    dx, dy, dz = image_chord(x, a, b, cr, sr)
    return a, b, cr, sr, dx, dy, dz


@jit_inline
def add_pair_force(f, a, b, g, dx, dy, dz, cr, sr):
    """Add the force ``g (dx, dy, dz)`` of a member from node a to the image ``R^r x_b`` onto
    node a, and its reaction, rotated back (``R^-r``), onto node b."""
    fx = g * dx
    fy = g * dy
    f[a, 0] += fx
    f[a, 1] += fy
    f[a, 2] += g * dz
    f[b, 0] -= cr * fx + sr * fy
    f[b, 1] -= cr * fy - sr * fx
    f[b, 2] -= g * dz


@jit
def cable_forces_rot(x, cable_a, cable_b, cable_rot, rest, EA, f):
    """:func:`cable_forces` for cables from ``x_a`` to the image ``R^r x_b``: the force on the
    image is rotated back onto node b. The chord is written out here: through
    :func:`cable_chord` this loop, the hottest of ``sym3d``, ran 1.6x slower."""
    for c in range(cable_a.shape[0]):
        a = cable_a[c]
        b = cable_b[c]
        cr = ROT_C[cable_rot[c]]
        sr = ROT_S[cable_rot[c]]
        dx = cr * x[b, 0] - sr * x[b, 1] - x[a, 0]
        dy = sr * x[b, 0] + cr * x[b, 1] - x[a, 1]
        dz = x[b, 2] - x[a, 2]
        s = math.sqrt(dx * dx + dy * dy + dz * dz)
        L = rest[c]
        if s > L:
            add_pair_force(f, a, b, EA[c] / L * (s - L) / s, dx, dy, dz, cr, sr)


@jit
def member_vectors_rot(x, tail, head, rot, bvec):
    """``bvec[c] = R^rot[c] x[head[c]] - x[tail[c]]``."""
    for c in range(tail.shape[0]):
        h = head[c]
        t = tail[c]
        cr = ROT_C[rot[c]]
        sr = ROT_S[rot[c]]
        bvec[c, 0] = cr * x[h, 0] - sr * x[h, 1] - x[t, 0]
        bvec[c, 1] = sr * x[h, 0] + cr * x[h, 1] - x[t, 1]
        bvec[c, 2] = x[h, 2] - x[t, 2]


@jit
def assemble_band_rot(bvec, coef3, band):
    """``band[c, k] = A[c, c-k] = coef3[c, k] . (zz, xx + yy, y_c x_d - x_c y_d)`` of b_c, b_d."""
    m = coef3.shape[0]
    width = coef3.shape[1]
    for c in range(m):
        for k in range(width):
            if k > c:
                band[c, k] = 0.0
                continue
            d = c - k
            band[c, k] = (coef3[c, k, 0] * bvec[c, 2] * bvec[d, 2]
                          + coef3[c, k, 1] * (bvec[c, 0] * bvec[d, 0] + bvec[c, 1] * bvec[d, 1])
                          + coef3[c, k, 2] * (bvec[c, 1] * bvec[d, 0] - bvec[c, 0] * bvec[d, 1]))


@jit
def add_constraint_forces_rot(lam, bvec, tail, head, rot, f):
    """:func:`add_constraint_forces` with the head force ``R^-r (lam b)`` rotated back."""
    for c in range(tail.shape[0]):
        h = head[c]
        t = tail[c]
        cr = ROT_C[rot[c]]
        sr = ROT_S[rot[c]]
        gx = lam[c] * bvec[c, 0]
        gy = lam[c] * bvec[c, 1]
        gz = lam[c] * bvec[c, 2]
        f[h, 0] += cr * gx + sr * gy
        f[h, 1] += cr * gy - sr * gx
        f[h, 2] += gz
        f[t, 0] -= gx
        f[t, 1] -= gy
        f[t, 2] -= gz


@jit
def constraint_error_arrays(x, tail, head, length, rot):
    """max_c |g_c| / L_c^2 with ``g_c = (|b_c|^2 - L_c^2) / 2`` (dimensionless), members as in the
    ``net`` tuple (``rot`` empty for ``full3d``)."""
    worst = 0.0
    for c in range(tail.shape[0]):
        dx, dy, dz = rel(x, tail[c], head[c], rot, c)
        L2 = length[c] * length[c]
        e = abs(0.5 * (dx * dx + dy * dy + dz * dz - L2)) / L2
        if not e <= worst:          # also catches NaN
            worst = e
    return worst
