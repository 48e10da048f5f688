"""Lane kernels of the rotated members of the symmetric reduction (``sym3d``) and of damped
cables: B instances with the instance (lane) index innermost, as in :mod:`solver.kernels.lanes`,
each kernel performing lane by lane the operations of its scalar twin in
:mod:`solver.kernels.rotation` and :mod:`solver.kernels.contact` in the same order (every lane
equals the scalar kernel bit for bit)."""
from __future__ import annotations

import math

from solver.compiled import jit_inline, jit_lanes
from solver.kernels.rotation import ROT_C, ROT_S


@jit_inline
def lane_chord(u, a, b, cr, sr, k):
    """Lane k's ``R u[b] - u[a]`` for the rotation of cosine ``cr`` and sine ``sr`` about z, as
    :func:`solver.kernels.rotation.image_chord`: a 3-tuple."""
    return (cr * u[b, 0, k] - sr * u[b, 1, k] - u[a, 0, k],
            sr * u[b, 0, k] + cr * u[b, 1, k] - u[a, 1, k], u[b, 2, k] - u[a, 2, k])


@jit_inline
def _pair_force(tmp, k, g, dx, dy, dz, cr, sr):
    """Lane k's force ``g (dx, dy, dz)`` on node a and its reaction rotated back onto node b
    (:func:`solver.kernels.rotation.add_pair_force`) into ``tmp[:5, k]``."""
    fx = g * dx
    fy = g * dy
    tmp[0, k] = fx
    tmp[1, k] = fy
    tmp[2, k] = g * dz
    tmp[3, k] = cr * fx + sr * fy
    tmp[4, k] = cr * fy - sr * fx


@jit_inline
def _add_pair(f, a, b, tmp, n_lanes):
    """Add one cable's forces of every lane (``tmp`` of :func:`_pair_force`) to nodes a and b."""
    for i in range(3):
        for k in range(n_lanes):
            f[a, i, k] += tmp[i, k]
    for i in range(2):
        for k in range(n_lanes):
            f[b, i, k] -= tmp[3 + i, k]
    for k in range(n_lanes):
        f[b, 2, k] -= tmp[2, k]


@jit_lanes
def cable_forces_rot(x, cable_a, cable_b, cable_rot, rest, EA, f, tmp):
    """Cables from ``x_a`` to the image ``R^r x_b`` lane by lane
    (:func:`solver.kernels.rotation.cable_forces_rot`); ``tmp`` (6, B) holds one cable's
    forces on a and b."""
    n_lanes = x.shape[2]
    for c in range(cable_a.shape[0]):
        a = cable_a[c]
        b = cable_b[c]
        cr = ROT_C[cable_rot[c]]
        sr = ROT_S[cable_rot[c]]
        for k in range(n_lanes):
            dx, dy, dz = lane_chord(x, a, b, cr, sr, k)
            s = math.sqrt(dx * dx + dy * dy + dz * dz)
            L = rest[c, k]
            g = 0.0
            if s > L:
                g = EA[c, k] / L * (s - L) / s
            _pair_force(tmp, k, g, dx, dy, dz, cr, sr)
        _add_pair(f, a, b, tmp, n_lanes)


@jit_lanes
def cable_forces_damped(x, v, cable_a, cable_b, cable_rot, rest, EA, damp, f, tmp, power, live):
    """Tension-only cables with viscous damping lane by lane
    (:func:`solver.kernels.contact.cable_forces_damped`), plain or to the rotated image; the
    damping's power W of lane k into ``power[k]`` where ``live[k]`` (the others keep theirs)."""
    n_lanes = x.shape[2]
    rotated = cable_rot.shape[0] > 0
    mult = 3.0 if rotated else 1.0
    p = tmp[5]
    for k in range(n_lanes):
        p[k] = 0.0
    for c in range(cable_a.shape[0]):
        a = cable_a[c]
        b = cable_b[c]
        cr = 1.0
        sr = 0.0
        if rotated:
            cr = ROT_C[cable_rot[c]]
            sr = ROT_S[cable_rot[c]]
        for k in range(n_lanes):
            dx, dy, dz = lane_chord(x, a, b, cr, sr, k)
            s = math.sqrt(dx * dx + dy * dy + dz * dz)
            L = rest[c, k]
            g = 0.0
            if s > L:
                ux, uy, uz = lane_chord(v, a, b, cr, sr, k)
                rate = (dx * ux + dy * uy + dz * uz) / s
                elastic = EA[c, k] / L * (s - L)
                T = max(elastic + damp[c] * rate, 0.0)
                p[k] += (T - elastic) * rate
                if T > 0.0:
                    g = T / s
            _pair_force(tmp, k, g, dx, dy, dz, cr, sr)
        _add_pair(f, a, b, tmp, n_lanes)
    for k in range(n_lanes):
        if live[k] != 0:
            power[k] = mult * p[k]


@jit_lanes
def member_vectors_rot(x, tail, head, rot, bvec):
    """``bvec[c] = R^rot[c] x[head[c]] - x[tail[c]]`` lane by lane."""
    n_lanes = x.shape[2]
    for c in range(tail.shape[0]):
        h = head[c]
        t = tail[c]
        cr = ROT_C[rot[c]]
        sr = ROT_S[rot[c]]
        for k in range(n_lanes):
            bvec[c, 0, k] = cr * x[h, 0, k] - sr * x[h, 1, k] - x[t, 0, k]
            bvec[c, 1, k] = sr * x[h, 0, k] + cr * x[h, 1, k] - x[t, 1, k]
            bvec[c, 2, k] = x[h, 2, k] - x[t, 2, k]


@jit_lanes
def assemble_band_rot(bvec, coef3, band):
    """The band of the rotated members lane by lane
    (:func:`solver.kernels.rotation.assemble_band_rot`)."""
    m = coef3.shape[0]
    width = coef3.shape[1]
    n_lanes = band.shape[2]
    for c in range(m):
        for j in range(width):
            if j > c:
                for k in range(n_lanes):
                    band[c, j, k] = 0.0
                continue
            d = c - j
            c0 = coef3[c, j, 0]
            c1 = coef3[c, j, 1]
            c2 = coef3[c, j, 2]
            for k in range(n_lanes):
                band[c, j, k] = (c0 * bvec[c, 2, k] * bvec[d, 2, k]
                                 + c1 * (bvec[c, 0, k] * bvec[d, 0, k]
                                         + bvec[c, 1, k] * bvec[d, 1, k])
                                 + c2 * (bvec[c, 1, k] * bvec[d, 0, k]
                                         - bvec[c, 0, k] * bvec[d, 1, k]))


@jit_lanes
def add_constraint_forces_rot(lam, bvec, tail, head, rot, f):
    """``f += sum_c lam_c G_c`` with the head force rotated back lane by lane
    (:func:`solver.kernels.rotation.add_constraint_forces_rot`)."""
    n_lanes = f.shape[2]
    for c in range(tail.shape[0]):
        h = head[c]
        t = tail[c]
        cr = ROT_C[rot[c]]
        sr = ROT_S[rot[c]]
        for k in range(n_lanes):
            gx = lam[c, k] * bvec[c, 0, k]
            gy = lam[c, k] * bvec[c, 1, k]
            gz = lam[c, k] * bvec[c, 2, k]
            f[h, 0, k] += cr * gx + sr * gy
            f[h, 1, k] += cr * gy - sr * gx
            f[h, 2, k] += gz
            f[t, 0, k] -= gx
            f[t, 1, k] -= gy
            f[t, 2, k] -= gz


@jit_lanes
def rhs_rot(wf, v, bvec, topo, lam):
    """The right-hand side of the acceleration multipliers of rotated members lane by lane (the
    ``rel`` terms of :func:`solver.kernels.dynamics.accelerations`)."""
    tail, head, rot = topo.con_tail, topo.con_head, topo.con_rot
    n_lanes = v.shape[2]
    for c in range(tail.shape[0]):
        h = head[c]
        t = tail[c]
        cr = ROT_C[rot[c]]
        sr = ROT_S[rot[c]]
        for k in range(n_lanes):
            ax, ay, az = lane_chord(wf, t, h, cr, sr, k)
            dx, dy, dz = lane_chord(v, t, h, cr, sr, k)
            lam[c, k] = -(bvec[c, 0, k] * ax + bvec[c, 1, k] * ay + bvec[c, 2, k] * az
                          + dx * dx + dy * dy + dz * dz)
