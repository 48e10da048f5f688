"""Lanes: many instances of one network stepped together, the instance (lane) index
innermost, so that LLVM vectorises each loop across instances.

All lanes share the :class:`~solver.kernels.records.Topology` (members, cables, inverse mass,
band layout); each has its own state and cable parameters, in a :class:`LaneData`: ``x``, ``v``
and ``f_ext`` (n_nodes, 3, B), ``rest`` and ``EA`` (n_cables, B). Scratch is a
:class:`LaneWork`. The kernels here cover the forces and constraints of
:mod:`solver.kernels.dynamics`, plain or with rotated members (``sym3d``, their kernels in
:mod:`solver.kernels.lanerot`), with or without cable damping; not the massive-bar KKT system.
The effects that keep state per instance (contacts, the ledger) are composed in
:mod:`solver.kernels.lanedata`.

Each kernel performs, lane by lane, exactly the floating-point operations of its scalar twin in
:mod:`solver.kernels.dynamics` and :mod:`solver.kernels.banded`, in the same order, so every lane
equals the scalar kernel on that instance bit for bit. One difference is not a value: a slack
cable adds a zero force where the scalar kernel adds nothing, which can turn a force of -0.0
into +0.0 and no division of these kernels has a force as its divisor. Loops run over all lanes:
a lane that has failed keeps computing (NaN or inf, harmless under NumPy's error model,
:data:`solver.compiled.jit_lanes`), but its state is not written after that (its scratch and
``out`` arrays are) and its status keeps the first failure.

Status arrays (B,) int64 hold one code of :mod:`solver.status` per lane. A kernel sets the code
of a lane that fails only while that lane's code is ``OK``.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from solver.compiled import jit_lanes
from solver.kernels.lanerot import (add_constraint_forces_rot, assemble_band_rot,
                                    cable_forces_damped, cable_forces_rot, lane_chord,
                                    member_vectors_rot, rhs_rot)
from solver.kernels.rotation import ROT_C, ROT_S
from solver.status import NONFINITE, NOT_CONVERGED, OK, SINGULAR


class LaneData(NamedTuple):
    """The state and cable parameters of B instances: ``x``, ``v`` (n_nodes, 3, B) m, m/s,
    ``rest`` (n_cables, B) m, ``EA`` (n_cables, B) N, ``f_ext`` (n_nodes, 3, B) N."""
    x: np.ndarray
    v: np.ndarray
    rest: np.ndarray
    EA: np.ndarray
    f_ext: np.ndarray


class LaneWork(NamedTuple):
    """Scratch of the lane kernels: nodal forces and their mass-weighted image, member vectors,
    the constraint band (n_con, bw + 1, B) and multipliers (n_con, B), one cable's forces
    ``tmp`` (3, B) and, for rotated and damped cables, ``pair`` (6, B), the stage arrays of RK4
    (n_nodes, 3, B), and per lane (B,): a pivot or sum ``piv``, the worst constraint error
    ``worst``, the active mask ``go`` and the status of the last solve ``flag``."""
    f: np.ndarray
    wf: np.ndarray
    bvec: np.ndarray
    band: np.ndarray
    lam: np.ndarray
    tmp: np.ndarray
    pair: np.ndarray
    xs: np.ndarray
    vs: np.ndarray
    acc: np.ndarray
    xacc: np.ndarray
    vacc: np.ndarray
    a1: np.ndarray
    piv: np.ndarray
    worst: np.ndarray
    go: np.ndarray
    flag: np.ndarray


def lane_data(x, v, rest, EA, f_ext):
    """A :class:`LaneData` of per-lane arrays (sequences of B arrays in the scalar layout:
    ``x[l]`` (n_nodes, 3), ``rest[l]`` (n_cables,)), stacked with the lane index last."""
    def stack(arrays):
        return np.ascontiguousarray(np.stack([np.asarray(a, dtype=np.float64) for a in arrays],
                                             axis=-1))
    return LaneData(stack(x), stack(v), stack(rest), stack(EA), stack(f_ext))


def lane_work(topo, n_rows, lanes):
    """A zeroed :class:`LaneWork` for ``lanes`` instances of ``n_rows`` nodes on ``topo``; a
    ValueError when the lanes do not step ``topo`` (:func:`check_lanes`)."""
    check_lanes(topo)
    n_con, width = topo.con_coef.shape

    def z(*shape):
        return np.zeros(shape + (lanes,))
    return LaneWork(z(n_rows, 3), z(n_rows, 3), z(n_con, 3), z(n_con, width), z(n_con), z(3),
                    z(6), z(n_rows, 3), z(n_rows, 3), z(n_rows, 3), z(n_rows, 3), z(n_rows, 3),
                    z(n_rows, 3), z(), z(), np.zeros(lanes, np.int64),
                    np.zeros(lanes, np.int64))


def lane(a, index):
    """Lane ``index`` of a lane array, as a C-contiguous array in the scalar layout."""
    return np.ascontiguousarray(a[..., index])


def check_lanes(topo):
    """Raise ValueError unless the lanes step networks of ``topo``: plain or rotated members
    (``sym3d``), not the KKT system of massive bars that share nodes."""
    if topo.kkt.node_u.shape[0]:
        raise ValueError('lanes: networks with massive bars that share nodes (a KKT system) '
                         'step one instance at a time')


@jit_lanes
def copy(dst, src):
    """``dst[...] = src`` for C-contiguous arrays of one shape, as one loop (no reference
    counting: :mod:`solver.compiled`)."""
    a = dst.reshape(-1)
    b = src.reshape(-1)
    for j in range(a.shape[0]):
        a[j] = b[j]


@jit_lanes
def zero(dst):
    """``dst[...] = 0`` for a C-contiguous array, as one loop."""
    a = dst.reshape(-1)
    for j in range(a.shape[0]):
        a[j] = 0.0


@jit_lanes
def cable_forces(x, cable_a, cable_b, rest, EA, f, tmp):
    """Add tension-only cable forces to ``f`` (n_nodes, 3, B) N, lane by lane as
    :func:`solver.kernels.dynamics.cable_forces`; ``tmp`` (3, B) holds one cable's forces."""
    n_lanes = x.shape[2]
    row = 3 * n_lanes
    f2 = f.reshape((f.shape[0], row))       # a node's 3 B entries as one row: longer loops
    t2 = tmp.reshape(row)
    for c in range(cable_a.shape[0]):
        a = cable_a[c]
        b = cable_b[c]
        for k in range(n_lanes):
            dx = x[b, 0, k] - x[a, 0, k]
            dy = x[b, 1, k] - x[a, 1, k]
            dz = x[b, 2, k] - x[a, 2, k]
            s = math.sqrt(dx * dx + dy * dy + dz * dz)
            L = rest[c, k]
            g = 0.0
            if s > L:
                g = EA[c, k] / L * (s - L) / s
            tmp[0, k] = g * dx
            tmp[1, k] = g * dy
            tmp[2, k] = g * dz
        for j in range(row):
            f2[a, j] += t2[j]
        for j in range(row):
            f2[b, j] -= t2[j]


@jit_lanes
def apply_w(f, w_diag, partner, w_off, out):
    """``out = W f`` lane by lane (:func:`solver.kernels.dynamics.apply_w`)."""
    n = f.shape[0]
    row = 3 * f.shape[2]
    f2 = f.reshape((n, row))
    out2 = out.reshape((n, row))
    for p in range(n):
        w = w_diag[p]
        q = partner[p]
        for j in range(row):
            out2[p, j] = w * f2[p, j]
        if q >= 0:
            wo = w_off[p]
            for j in range(row):
                out2[p, j] += wo * f2[q, j]


@jit_lanes
def member_vectors(x, tail, head, bvec):
    """``bvec[c] = x[head[c]] - x[tail[c]]`` lane by lane."""
    row = 3 * x.shape[2]
    x2 = x.reshape((x.shape[0], row))
    b2 = bvec.reshape((bvec.shape[0], row))
    for c in range(tail.shape[0]):
        h = head[c]         # read once: LLVM cannot tell that the stores leave head unchanged
        t = tail[c]
        for j in range(row):
            b2[c, j] = x2[h, j] - x2[t, j]


@jit_lanes
def assemble_band(bvec, coef, band):
    """``band[c, j] = coef[c, j] * (b_c . b_{c-j})`` lane by lane
    (:func:`solver.kernels.dynamics.assemble_band`)."""
    m, width = coef.shape
    n_lanes = band.shape[2]
    for c in range(m):
        for j in range(width):
            cf = coef[c, j]
            if cf == 0.0 or j > c:
                for k in range(n_lanes):
                    band[c, j, k] = 0.0
                continue
            d = c - j
            for k in range(n_lanes):
                band[c, j, k] = cf * (bvec[c, 0, k] * bvec[d, 0, k] + bvec[c, 1, k] * bvec[d, 1, k]
                                      + bvec[c, 2, k] * bvec[d, 2, k])


@jit_lanes
def add_constraint_forces(lam, bvec, tail, head, f):
    """``f += sum_c lam_c G_c`` lane by lane (``+lam b`` on the head node, ``-lam b`` on the
    tail node)."""
    n_lanes = f.shape[2]
    for c in range(tail.shape[0]):
        h = head[c]
        t = tail[c]
        for i in range(3):
            for k in range(n_lanes):
                g = lam[c, k] * bvec[c, i, k]
                f[h, i, k] += g
                f[t, i, k] -= g


@jit_lanes
def band_ldl_solve(band, rhs, piv, flag):
    """Solve ``A y = rhs`` in place for each lane's positive definite banded A (``band``
    (m, bw + 1, B) becomes its LDL^T factor, ``rhs`` (m, B) the solution): the operations of
    :func:`solver.kernels.banded.band_ldl_solve` lane by lane (its bandwidth-1 form performs the
    same ones). ``flag`` (B,) gets ``OK`` or ``SINGULAR`` (a pivot that is not positive: that
    lane's factor and solution are meaningless); ``piv`` (B,) is scratch."""
    m, width, n_lanes = band.shape
    bw = width - 1
    for k in range(n_lanes):
        flag[k] = OK
    for i in range(m):
        lo = max(0, i - bw)
        for j in range(lo, i):
            for q in range(lo, j):
                for k in range(n_lanes):
                    band[i, i - j, k] -= band[i, i - q, k] * band[j, j - q, k]
        for k in range(n_lanes):
            piv[k] = band[i, 0, k]
        for j in range(lo, i):
            for k in range(n_lanes):
                w = band[i, i - j, k]
                lij = w * band[j, 0, k]
                band[i, i - j, k] = lij
                piv[k] -= w * lij
        for k in range(n_lanes):
            d = piv[k]
            flag[k] = flag[k] if d > 0.0 else SINGULAR
            band[i, 0, k] = 1.0 / d
    for i in range(m):
        for q in range(max(0, i - bw), i):
            for k in range(n_lanes):
                rhs[i, k] -= band[i, i - q, k] * rhs[q, k]
    for i in range(m - 1, -1, -1):
        for k in range(n_lanes):
            rhs[i, k] = rhs[i, k] * band[i, 0, k]
        for q in range(i + 1, min(m, i + bw + 1)):
            for k in range(n_lanes):
                rhs[i, k] -= band[q, q - i, k] * rhs[q, k]


@jit_lanes
def fail(status, flag):
    """Give each lane whose ``status`` is ``OK`` the code ``flag`` of its last solve."""
    for k in range(status.shape[0]):
        status[k] = flag[k] if status[k] == OK else status[k]


@jit_lanes
def accelerations(x, v, topo, d, w, out, status):
    """Accelerations (n_nodes, 3, B) m/s^2 of each lane's constrained system at ``x``, ``v`` into
    ``out``, from its external forces and tension-only cables (``d``), as
    :func:`solver.kernels.dynamics.accelerations` on a plain model with every effect off;
    multipliers in ``w.lam``. A lane whose constraint matrix is not positive definite gets
    ``SINGULAR`` in ``status`` (when it is ``OK``)."""
    copy(w.f, d.f_ext)
    cable_forces(x, topo.cable_a, topo.cable_b, d.rest, d.EA, w.f, w.tmp)
    constrained(x, v, topo, w, out, status)


@jit_lanes
def project_positions(x, topo, w, tol, max_iter, status):
    """Mass-weighted Gauss-Newton projection of each lane's positions onto the rigid-member
    manifold, as :func:`solver.kernels.dynamics.project_positions`: ``A dmu = -g``,
    ``x += W sum_c dmu_c G_c`` until ``|g_c| < tol L_c^2``. Each lane stops on its own: a lane
    that converged (or failed) stays as it is from then on. Lanes whose ``status`` is not ``OK`` on
    entry are left as they are; a lane that does not converge gets ``NOT_CONVERGED``, one whose
    constraint matrix is singular ``SINGULAR``."""
    tail, length = topo.con_tail, topo.con_length
    bvec, lam, worst, go = w.bvec, w.lam, w.worst, w.go
    n_lanes = x.shape[2]
    for k in range(n_lanes):
        go[k] = 1 if status[k] == OK else 0
    for it in range(max_iter + 1):
        members(x, topo, bvec)
        for k in range(n_lanes):
            worst[k] = 0.0
        for c in range(tail.shape[0]):
            L2 = length[c] * length[c]
            for k in range(n_lanes):
                g = 0.5 * (bvec[c, 0, k] ** 2 + bvec[c, 1, k] ** 2 + bvec[c, 2, k] ** 2 - L2)
                lam[c, k] = -g
                e = abs(g) / L2
                worst[k] = worst[k] if e <= worst[k] else e
        left = 0
        for k in range(n_lanes):
            if go[k] != 0:
                if worst[k] < tol:
                    go[k] = 0
                elif it == max_iter or not math.isfinite(worst[k]):
                    go[k] = 0
                    status[k] = NOT_CONVERGED
                else:
                    left += 1
        if left == 0:
            return
        correct(x, lam, bvec, topo, w, status)


@jit_lanes
def project_velocities(x, v, topo, w, status):
    """Mass-weighted projection of each lane's velocities onto the constraint tangent space, as
    :func:`solver.kernels.dynamics.project_velocities`: ``A mu = -J v``, ``v += W J^T mu``.
    Lanes whose ``status`` is not ``OK`` are left as they are; one whose constraint matrix is
    singular gets ``SINGULAR``."""
    tail, head = topo.con_tail, topo.con_head
    bvec, lam, go = w.bvec, w.lam, w.go
    n_lanes = x.shape[2]
    for k in range(n_lanes):
        go[k] = 1 if status[k] == OK else 0
    members(x, topo, bvec)
    if topo.con_rot.shape[0] == 0:
        for c in range(tail.shape[0]):
            h = head[c]
            t = tail[c]
            for k in range(n_lanes):
                lam[c, k] = -(bvec[c, 0, k] * (v[h, 0, k] - v[t, 0, k])
                              + bvec[c, 1, k] * (v[h, 1, k] - v[t, 1, k])
                              + bvec[c, 2, k] * (v[h, 2, k] - v[t, 2, k]))
    else:
        rot = topo.con_rot
        for c in range(tail.shape[0]):
            h = head[c]
            t = tail[c]
            cr = ROT_C[rot[c]]
            sr = ROT_S[rot[c]]
            for k in range(n_lanes):
                dx, dy, dz = lane_chord(v, t, h, cr, sr, k)
                lam[c, k] = -(bvec[c, 0, k] * dx + bvec[c, 1, k] * dy + bvec[c, 2, k] * dz)
    correct(v, lam, bvec, topo, w, status)


@jit_lanes
def correct(u, lam, bvec, topo, w, status):
    """The mass-weighted correction of both projections for the lanes of ``w.go``: solve
    ``A mu = lam`` (``lam`` becomes mu), then ``u += W sum_c mu_c G_c``; a lane whose solve fails
    gets ``SINGULAR`` and leaves ``go`` unchanged."""
    f, wf, go, flag = w.f, w.wf, w.go, w.flag
    n_lanes = u.shape[2]
    assemble(bvec, topo, w.band)
    band_ldl_solve(w.band, lam, w.piv, flag)
    for k in range(n_lanes):
        if go[k] != 0 and flag[k] != OK:
            go[k] = 0
            status[k] = flag[k]
    zero(f)
    add_forces(lam, bvec, topo, f)
    apply_w(f, topo.w_diag, topo.partner, topo.w_off, wf)
    for p in range(u.shape[0]):
        for i in range(3):
            for k in range(n_lanes):
                u[p, i, k] = u[p, i, k] + wf[p, i, k] if go[k] != 0 else u[p, i, k]


@jit_lanes
def check_finite(x, v, sums, status):
    """Give each lane whose ``status`` is ``OK`` and whose ``x`` or ``v`` holds a NaN or inf the
    code ``NONFINITE`` (``x * 0`` is 0 for a finite entry, NaN otherwise); ``sums`` (B,) is
    scratch."""
    n_lanes = x.shape[2]
    for k in range(n_lanes):
        sums[k] = 0.0
    for p in range(x.shape[0]):
        for i in range(3):
            for k in range(n_lanes):
                sums[k] += x[p, i, k] * 0.0 + v[p, i, k] * 0.0
    for k in range(n_lanes):
        if status[k] == OK and sums[k] != 0.0:
            status[k] = NONFINITE


@jit_lanes
def members(x, topo, bvec):
    """Member vectors, plain or rotated."""
    if topo.con_rot.shape[0] == 0:
        member_vectors(x, topo.con_tail, topo.con_head, bvec)
    else:
        member_vectors_rot(x, topo.con_tail, topo.con_head, topo.con_rot, bvec)


@jit_lanes
def assemble(bvec, topo, band):
    """The constraint band, plain or rotated."""
    if topo.con_rot.shape[0] == 0:
        assemble_band(bvec, topo.con_coef, band)
    else:
        assemble_band_rot(bvec, topo.con_coef3, band)


@jit_lanes
def add_forces(lam, bvec, topo, f):
    """The constraint forces, plain or rotated."""
    if topo.con_rot.shape[0] == 0:
        add_constraint_forces(lam, bvec, topo.con_tail, topo.con_head, f)
    else:
        add_constraint_forces_rot(lam, bvec, topo.con_tail, topo.con_head, topo.con_rot, f)


@jit_lanes
def rhs_plain(wf, v, bvec, topo, lam):
    """The right-hand side of the acceleration multipliers of plain members lane by lane."""
    tail, head = topo.con_tail, topo.con_head
    n_lanes = v.shape[2]
    for c in range(tail.shape[0]):
        h = head[c]
        t = tail[c]
        for k in range(n_lanes):
            s = 0.0
            db = v[h, 0, k] - v[t, 0, k]
            s += bvec[c, 0, k] * (wf[h, 0, k] - wf[t, 0, k]) + db * db
            db = v[h, 1, k] - v[t, 1, k]
            s += bvec[c, 1, k] * (wf[h, 1, k] - wf[t, 1, k]) + db * db
            db = v[h, 2, k] - v[t, 2, k]
            s += bvec[c, 2, k] * (wf[h, 2, k] - wf[t, 2, k]) + db * db
            lam[c, k] = -s


@jit_lanes
def cables(x, v, topo, damp, rest, EA, f, tmp, pair, power, live):
    """Add the cable forces of every lane to ``f``: damped (``damp`` not empty; the power into
    ``power`` where ``live``), plain or rotated; scratch ``tmp`` (3, B) for plain cables,
    ``pair`` (6, B) for the others."""
    if damp.shape[0] != 0:
        cable_forces_damped(x, v, topo.cable_a, topo.cable_b, topo.cable_rot, rest, EA, damp, f,
                            pair, power, live)
    elif topo.cable_rot.shape[0] == 0:
        cable_forces(x, topo.cable_a, topo.cable_b, rest, EA, f, tmp)
    else:
        cable_forces_rot(x, topo.cable_a, topo.cable_b, topo.cable_rot, rest, EA, f, pair)


@jit_lanes
def constrained(x, v, topo, w, out, status):
    """From the nodal forces ``w.f`` (every force but the constraints'), the accelerations of
    each lane's constrained system into ``out``, as the second half of
    :func:`solver.kernels.dynamics.accelerations` (plain or rotated members; no KKT system). A
    lane whose constraint matrix is not positive definite gets ``SINGULAR`` (when ``OK``)."""
    f, wf, bvec, band, lam = w.f, w.wf, w.bvec, w.band, w.lam
    apply_w(f, topo.w_diag, topo.partner, topo.w_off, wf)
    members(x, topo, bvec)
    if topo.con_rot.shape[0] == 0:
        rhs_plain(wf, v, bvec, topo, lam)
    else:
        rhs_rot(wf, v, bvec, topo, lam)
    assemble(bvec, topo, band)
    band_ldl_solve(band, lam, w.piv, w.flag)
    fail(status, w.flag)
    add_forces(lam, bvec, topo, f)
    apply_w(f, topo.w_diag, topo.partner, topo.w_off, out)
