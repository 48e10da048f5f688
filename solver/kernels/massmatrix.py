"""The constrained dynamics with a banded, non-diagonal mass matrix (massive bars sharing nodes).

A bar of mass ``m_b`` is a uniform rigid rod: its kinetic energy ``m_b / 6 (|v_a|^2 + v_a . v_b +
|v_b|^2)`` gives the mass matrix ``M = C_B^T m C_B / 12 + C_R^T m C_R`` (``C_R = |C_B| / 2``), i.e.
the rod block ``[[m_b/3, m_b/6], [m_b/6, m_b/3]]`` on the bar's two nodes, plus the lumped node
masses on the diagonal (physics of :mod:`solver.kernels.dynamics`). When two massive bars share a
node (columns on shared bases: each bar chain is a tridiagonal block of M), ``M^-1`` is a full
matrix within each chain, so the constraint matrix ``J M^-1 J^T`` of :mod:`solver.kernels.dynamics`
is full too. This module keeps the mass matrix and solves the saddle-point (KKT) system itself::

    [ M (x) I3   -J^T ] [ a   ]   [ f         ]
    [ J           0   ] [ lam ] = [ -|b'|^2   ]

ordered item by item (a free node: its three coordinates; a rigid member: its multiplier) so that
the matrix is banded, and factorised by a banded LU with partial pivoting (LAPACK ``gbtrf``
style: the upper factor keeps ``kl + ku`` diagonals above the main one). The same matrix with
other right-hand sides gives the mass-weighted projections: ``[0; -g]`` (a Gauss-Newton step of
positions, ``x += dx``) and ``[0; -J v]`` (velocities, ``v += dv``). Cost per solve
``n_u * kl * (2 kl + ku)`` with ``n_u = 3 n_free + n_con`` unknowns: linear in the number of
prisms; a flexible-base bar chain has ``kl = ku = 4``.

Layout (the read-only record :class:`KKT`, built by :func:`layout`)::

    node_u (n_nodes,) int64   offset of a free node's x coordinate, -1 when clamped
    con_u (n_con,) int64      offset of each constraint's multiplier
    mass_p, mass_q (n_entries,) int64, mass_val (n_entries,) kg: entries M[p, q] between free
                              nodes (both orders of an off-diagonal pair)
    dims (3,) int64           n_u, kl, ku (:data:`N_U`, :data:`KL`, :data:`KU`)

Scratch (the record :class:`KKTScratch`, :func:`scratch`): ``band (n_u, 2 kl + ku + 1)``, ``lmul
(n_u, kl)``, ``rhs (n_u,)``, ``piv (n_u,) int64``. ``band[i, j - i + kl]`` holds entry (i, j).

A network whose massive bars are class 1 (no node shared by two massive bars) keeps the
node-local inverse of :mod:`solver.build.network` and never comes here: ``node_u`` is then empty.
"""
import math
from typing import NamedTuple

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import reverse_cuthill_mckee

from solver.compiled import jit, jit_inline
from solver.kernels.rotation import ROT_C, ROT_S, constraint_error_arrays, rel

from solver.status import BAD_WORKSPACE, NONFINITE, NOT_CONVERGED, OK, SINGULAR  # noqa: F401

EMPTY_I = np.zeros(0, dtype=np.int64)
EMPTY_I.setflags(write=False)
EMPTY_F = np.zeros(0)
EMPTY_F.setflags(write=False)
NO_DIMS = np.zeros(3, dtype=np.int64)
NO_DIMS.setflags(write=False)
N_U, KL, KU = 0, 1, 2          # the entries of ``KKT.dims``


class KKT(NamedTuple):
    """The layout of the KKT system of massive bars that share nodes (empty arrays: none)."""
    node_u: np.ndarray
    con_u: np.ndarray
    mass_p: np.ndarray
    mass_q: np.ndarray
    mass_val: np.ndarray
    dims: np.ndarray

    @property
    def active(self):
        """Whether the network takes this system (massive bars that share nodes)."""
        return self.node_u.shape[0] != 0


class KKTScratch(NamedTuple):
    """Scratch of the KKT solve."""
    band: np.ndarray
    lmul: np.ndarray
    rhs: np.ndarray
    piv: np.ndarray


NO_KKT = KKT(EMPTY_I, EMPTY_I, EMPTY_I, EMPTY_I, EMPTY_F, NO_DIMS)


NO_FORCE = np.zeros((0, 3))


def needs_kkt(bars, bar_mass):
    """Whether some node belongs to two or more massive bars (class k for the masses)."""
    bars = np.asarray(bars, dtype=np.int64).reshape(-1, 2)
    massive = bars[np.asarray(bar_mass) != 0]
    if not len(massive):
        return False
    counts = np.bincount(massive.ravel())
    return bool(np.any(counts > 1))


def mass_entries(node_mass, clamped, bars, bar_mass):
    """Entries ``(p, q, M_pq)`` of the node mass matrix restricted to free nodes (lumped masses
    plus rod blocks), off-diagonal pairs in both orders."""
    n = len(node_mass)
    diag = np.array(node_mass, dtype=np.float64)
    off = {}
    for (a, b), mb in zip(np.asarray(bars).reshape(-1, 2), bar_mass):
        if mb == 0:
            continue
        diag[a] += mb / 3.0
        diag[b] += mb / 3.0
        if not clamped[a] and not clamped[b]:
            key = (min(a, b), max(a, b))
            off[key] = off.get(key, 0.0) + mb / 6.0
    ps, qs, vs = [], [], []
    for p in range(n):
        if not clamped[p]:
            ps.append(p)
            qs.append(p)
            vs.append(diag[p])
    for (p, q), m in off.items():
        ps += [p, q]
        qs += [q, p]
        vs += [m, m]
    return (np.array(ps, dtype=np.int64), np.array(qs, dtype=np.int64),
            np.array(vs, dtype=np.float64), diag)


def _offsets(node_order, con_pos, n_nodes, n_con):
    """Unknown offsets from an order of items: nodes (3 unknowns) and constraints (1)."""
    items = [(k, 0, int(p)) for k, p in enumerate(node_order)]
    items += [(pos, 1, c) for c, pos in enumerate(con_pos)]
    items.sort()
    node_u = -np.ones(n_nodes, dtype=np.int64)
    con_u = np.zeros(n_con, dtype=np.int64)
    u = 0
    for _, kind, i in items:
        if kind == 0:
            node_u[i] = u
            u += 3
        else:
            con_u[i] = u
            u += 1
    return node_u, con_u, u


def _width(node_u, con_u, members, mass_p, mass_q):
    w = 2
    if len(mass_p):
        w = max(w, int(np.max(np.abs(node_u[mass_p] - node_u[mass_q]))))
    for c, (t, h) in enumerate(members):
        for p in (t, h):
            if node_u[p] >= 0:
                w = max(w, abs(int(con_u[c]) - int(node_u[p])),
                        abs(int(con_u[c]) - int(node_u[p]) - 2))
    return w


def layout(n_nodes, clamped, members, mass_p, mass_q, x0):
    """The ``(node_u, con_u, dims)`` arrays of the KKT system: the narrowest band found among
    node orders (index order, level order by z, reverse Cuthill-McKee of the node graph) with
    each multiplier placed next to its nodes (before its later node or after its earlier one)."""
    clamped = np.asarray(clamped, dtype=bool)
    members = np.asarray(members, dtype=np.int64).reshape(-1, 2)
    free = np.nonzero(~clamped)[0]
    rows, cols = list(mass_p), list(mass_q)
    for t, h in members:
        if not clamped[t] and not clamped[h]:
            rows += [t, h]
            cols += [h, t]
    adj = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_nodes, n_nodes))
    sub = adj[free][:, free]
    rcm = free[reverse_cuthill_mckee(sub.tocsr(), symmetric_mode=True)]
    z = np.asarray(x0)[free, 2]
    orders = [free, free[np.lexsort((free, z))], rcm]
    best = None
    for order in orders:
        rank = -np.ones(n_nodes, dtype=np.int64)
        rank[order] = np.arange(len(order))
        for rule in ('before_later', 'after_earlier'):
            pos = np.zeros(len(members))
            for c, (t, h) in enumerate(members):
                ranks = [rank[p] for p in (t, h) if rank[p] >= 0]
                pos[c] = (max(ranks) - 0.5) if rule == 'before_later' else (min(ranks) + 0.5)
            node_u, con_u, n_u = _offsets(order, pos, n_nodes, len(members))
            w = _width(node_u, con_u, members, mass_p, mass_q)
            if best is None or w < best[0]:
                best = (w, node_u, con_u, n_u)
    w, node_u, con_u, n_u = best
    return node_u, con_u, np.array([n_u, w, w], dtype=np.int64)


def scratch(dims):
    """The :class:`KKTScratch` for KKT dimensions ``dims = (n_u, kl, ku)``."""
    n_u, kl, ku = (int(d) for d in dims)
    return KKTScratch(np.zeros((n_u, 2 * kl + ku + 1)), np.zeros((n_u, kl)), np.zeros(n_u),
                      np.zeros(n_u, dtype=np.int64))


@jit
def band_lu_solve(band, lmul, piv, rhs, n, kl, ku):
    """Solve ``A y = rhs`` in place (``rhs[:n]`` becomes y) by LU with partial pivoting of the
    banded ``A`` (``kl`` sub-, ``ku`` super-diagonals) stored as ``band[i, j - i + kl]``, width
    ``2 kl + ku + 1`` (room for the fill of row interchanges). ``band`` is overwritten by U,
    ``lmul[k, i - k - 1]`` by the multipliers, ``piv`` by the interchanges. Returns ``OK`` or
    ``SINGULAR`` (a pivot below 1e-14 of the largest entry)."""
    amax = 0.0
    for i in range(n):
        for j in range(kl + ku + 1):
            a = abs(band[i, j])
            if a > amax:
                amax = a
    tiny = 1e-14 * amax
    if not tiny > 0.0:
        return SINGULAR
    ku2 = kl + ku
    for k in range(n):
        last = min(n - 1, k + kl)
        p = k
        big = abs(band[k, kl])
        for i in range(k + 1, last + 1):
            a = abs(band[i, k - i + kl])
            if a > big:
                big = a
                p = i
        piv[k] = p
        if not big > tiny:
            return SINGULAR
        jend = min(n - 1, k + ku2)
        if p != k:
            for j in range(k, jend + 1):
                t = band[k, j - k + kl]
                band[k, j - k + kl] = band[p, j - p + kl]
                band[p, j - p + kl] = t
            t = rhs[k]
            rhs[k] = rhs[p]
            rhs[p] = t
        inv = 1.0 / band[k, kl]
        yk = rhs[k]
        for i in range(k + 1, last + 1):
            off = k - i + kl
            l = band[i, off] * inv
            lmul[k, i - k - 1] = l
            if l != 0.0:
                band[i, off] = 0.0
                d = kl - i            # column j sits at j + d in row i, at j - k + kl in row k
                dk = kl - k
                for j in range(k + 1, jend + 1):
                    band[i, j + d] -= l * band[k, j + dk]
                rhs[i] -= l * yk
    for i in range(n - 1, -1, -1):
        s = rhs[i]
        for j in range(i + 1, min(n - 1, i + ku2) + 1):
            s -= band[i, j - i + kl] * rhs[j]
        rhs[i] = s / band[i, kl]
    return OK


@jit_inline
def _grad_head(bx, by, bz, rot, c):
    """``R^-r b``: the constraint gradient on the head node of a member to a rotated image."""
    if rot.shape[0] == 0:
        return bx, by, bz
    cr = ROT_C[rot[c]]
    sr = ROT_S[rot[c]]
    return cr * bx + sr * by, cr * by - sr * bx, bz


@jit
def assemble(x, tail, head, rot, kkt, kws, bvec):
    """Fill ``kws.band`` with the KKT matrix at positions ``x`` (member vectors into ``bvec``).
    Returns ``OK`` or ``BAD_WORKSPACE``."""
    node_u, con_u, mass_p, mass_q, mass_val, dims = (kkt.node_u, kkt.con_u, kkt.mass_p,
                                                     kkt.mass_q, kkt.mass_val, kkt.dims)
    band = kws.band
    n, kl, ku = dims[N_U], dims[KL], dims[KU]
    if band.shape[0] < n or band.shape[1] != 2 * kl + ku + 1 or kws.lmul.shape[1] != kl \
            or kws.rhs.shape[0] < n or bvec.shape[0] < tail.shape[0]:
        return BAD_WORKSPACE
    band[:n, :] = 0.0
    for e in range(mass_p.shape[0]):
        p = node_u[mass_p[e]]
        q = node_u[mass_q[e]]
        m = mass_val[e]
        for i in range(3):
            band[p + i, q - p + kl] += m
    for c in range(tail.shape[0]):
        bx, by, bz = rel(x, tail[c], head[c], rot, c)
        bvec[c, 0] = bx
        bvec[c, 1] = by
        bvec[c, 2] = bz
        uc = con_u[c]
        h = node_u[head[c]]
        if h >= 0:
            g = _grad_head(bx, by, bz, rot, c)
            for i in range(3):
                band[uc, h + i - uc + kl] += g[i]
                band[h + i, uc - h - i + kl] -= g[i]
        t = node_u[tail[c]]
        if t >= 0:
            g = (bx, by, bz)
            for i in range(3):
                band[uc, t + i - uc + kl] -= g[i]
                band[t + i, uc - t - i + kl] += g[i]
    return OK


@jit
def _solve(kkt, kws):
    dims = kkt.dims
    return band_lu_solve(kws.band, kws.lmul, kws.piv, kws.rhs, dims[N_U], dims[KL], dims[KU])


@jit_inline
def _node_rhs(node_u, rhs, f, n):
    """Node rows of the right-hand side: ``f`` (zeros when ``f`` has no rows)."""
    for p in range(n):
        u = node_u[p]
        if u >= 0:
            for i in range(3):
                rhs[u + i] = f[p, i] if f.shape[0] else 0.0


@jit
def _solve_velocity_rows(x, v, f, tail, head, rot, kkt, kws, bvec, projection):
    """Assemble at ``x`` and solve with node rows ``f`` and member rows ``-|R v_h - v_t|^2``
    (accelerations) or ``-b . (R v_h - v_t)`` (``projection``: the velocity projection)."""
    status = assemble(x, tail, head, rot, kkt, kws, bvec)
    if status != OK:
        return status
    node_u, con_u = kkt.node_u, kkt.con_u
    rhs = kws.rhs
    _node_rhs(node_u, rhs, f, x.shape[0])
    for c in range(tail.shape[0]):
        dx, dy, dz = rel(v, tail[c], head[c], rot, c)
        if projection:
            rhs[con_u[c]] = -(bvec[c, 0] * dx + bvec[c, 1] * dy + bvec[c, 2] * dz)
        else:
            rhs[con_u[c]] = -(dx * dx + dy * dy + dz * dz)
    return _solve(kkt, kws)


@jit
def accelerations(x, v, f, tail, head, rot, kkt, kws, bvec, lam, out):
    """Accelerations into ``out`` and multipliers into ``lam`` for the nodal forces ``f``."""
    status = _solve_velocity_rows(x, v, f, tail, head, rot, kkt, kws, bvec, False)
    if status != OK:
        return status
    node_u, con_u = kkt.node_u, kkt.con_u
    rhs = kws.rhs
    for p in range(x.shape[0]):
        u = node_u[p]
        for i in range(3):
            out[p, i] = rhs[u + i] if u >= 0 else 0.0
    for c in range(tail.shape[0]):
        lam[c] = rhs[con_u[c]]
    return OK


@jit
def _apply_correction(y, kkt, kws):
    node_u = kkt.node_u
    rhs = kws.rhs
    for p in range(y.shape[0]):
        u = node_u[p]
        if u >= 0:
            for i in range(3):
                y[p, i] += rhs[u + i]


@jit
def project_positions(x, tail, head, rot, length, kkt, kws, bvec, tol, max_iter):
    """Mass-weighted Gauss-Newton projection of positions with the full mass matrix:
    ``[M -J^T; J 0] [dx; dmu] = [0; -g]``, ``x += dx``, until ``|g_c| < tol L_c^2``."""
    node_u, con_u = kkt.node_u, kkt.con_u
    rhs = kws.rhs
    for it in range(max_iter + 1):
        worst = constraint_error_arrays(x, tail, head, length, rot)
        if worst < tol:
            return OK
        if it == max_iter or not math.isfinite(worst):
            break
        status = assemble(x, tail, head, rot, kkt, kws, bvec)
        if status != OK:
            return status
        _node_rhs(node_u, rhs, NO_FORCE, x.shape[0])
        for c in range(tail.shape[0]):
            L2 = length[c] * length[c]
            rhs[con_u[c]] = -0.5 * (bvec[c, 0] ** 2 + bvec[c, 1] ** 2 + bvec[c, 2] ** 2 - L2)
        status = _solve(kkt, kws)
        if status != OK:
            return status
        _apply_correction(x, kkt, kws)
    return NOT_CONVERGED


@jit
def project_velocities(x, v, tail, head, rot, kkt, kws, bvec):
    """Mass-weighted projection of velocities with the full mass matrix:
    ``[M -J^T; J 0] [dv; mu] = [0; -J v]``, ``v += dv``."""
    status = _solve_velocity_rows(x, v, NO_FORCE, tail, head, rot, kkt, kws, bvec, True)
    if status != OK:
        return status
    _apply_correction(v, kkt, kws)
    return OK
