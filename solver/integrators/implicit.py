"""Implicit midpoint with rigid-member constraints, for stiff scenes (``implicit_midpoint``).

One step of size ``h`` from ``(x0, v0)`` solves, for the new positions ``x1`` and one multiplier
per rigid member,

    M (x1 - x0 - h v0) = h^2 / 2 (f + G(xm)^T lambda),   g(x1) = 0,
    xm = (x0 + x1) / 2,   v1 = 2 (x1 - x0) / h - v0,

i.e. the implicit midpoint rule ``x1 = x0 + h (v0 + v1) / 2``, ``v1 = v0 + h M^-1 (f + G^T
lambda)`` with the bar forces as unknowns that put ``x1`` exactly on the rigid members. The cable
force ``f`` is the discrete gradient of the cable energy between ``x0`` and ``x1``
(:func:`dg_forces`): for a taut cable it is the midpoint force of a linear spring, and its work
over the step equals the change of cable energy exactly, also across a slack/taut transition. The
constraint term does no work either (``g`` is quadratic, ``g(x0) = g(x1) = 0``), so the step
conserves the energy to the Newton tolerance. Then positions and velocities are projected
(:func:`solver.kernels.dynamics.project_positions`, ``project_velocities``) as in
``rk4_projected``: bar
errors stay at the projection tolerance and the energy can only decrease. External forces enter
as they are (``d.f_ext``); velocity-dependent forces are not part of the step.

Newton's method on the saddle-point (KKT) system

    [ M + h^2/2 K + H_c   G^T ] [dx ]   [-r]
    [ G                   0   ] [dnu] = [-g]

with ``K`` the symmetrised tangent of the discrete-gradient cable forces and ``H_c`` the
constraint curvature. The unknowns are ordered node by node (the network's order or reverse
Cuthill-McKee, whichever gives the smaller band) with each rigid member right after the later of
its two nodes, so the matrix is banded (a cable or member couples only its two nodes) and every
leading block is itself a non-singular KKT matrix: a banded LDL^T factorisation without pivoting
(signed pivots) solves it in ``O(N b^2)``. The matrix is assembled and factored at every iterate
(a frozen factor diverges when stiff cables go slack or taut within the step); a step fails
(``NEWTON_FAILED``) after ``NEWTON_MAX_ITER`` iterations.

Properties: order 2; for a linear spring A-stable without damping (the step is a rotation by
``2 atan(omega h / 2)``) and the quadratic energy is conserved; the energy never rises.

Two levels as in :mod:`solver.kernels.dynamics`: :func:`layout` (Python) orders the unknowns and
sizes the band, the ``@jit`` kernels take arrays and the records of
:mod:`solver.kernels.records`. Networks with massive bars (a non-diagonal mass matrix) are
refused.
"""
from __future__ import annotations

import math

import numpy as np

from solver.kernels import dynamics as dyn
from solver.kernels import summary
# The Newton step builds small matrices (3x3 blocks, their products): the kernels that allocate
# them, and those that call them, are compiled with numba's reference counting (``jit_alloc``);
# the others without it, as every solver kernel (solver.compiled)
from solver.compiled import jit, jit_alloc, jit_inline
from solver.integrators.base import Integrator
from solver.kernels.banded import band_ldl_apply, band_ldl_factor
from solver.kernels.records import copy_data, copy_into
from solver.kernels.rotation import ROT_C, ROT_S, rel

from solver.status import NEWTON_FAILED  # noqa: E402
NEWTON_TOL = 1e-13          # on max |dx|, relative to the largest |position| of the start state
NEWTON_MAX_ITER = 60


# -- layout (Python) ------------------------------------------------------------------------------
def _band_of(node_key, tail, head, ca, cb):
    """Slots of the unknowns for a node order ``node_key`` (node -> rank) and their band."""
    n = len(node_key)
    order = np.argsort(node_key, kind='stable')
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    m = len(tail)
    after = np.maximum(rank[tail], rank[head]) if m else np.zeros(0, dtype=np.int64)
    # sort keys: node of rank k -> (k, 0), member c -> (after_c, 1)
    keys = np.concatenate([rank * 2, after * 2 + 1])
    size = np.concatenate([np.full(n, 3), np.ones(m, dtype=np.int64)])
    seq = np.argsort(keys, kind='stable')
    start = np.zeros(n + m, dtype=np.int64)
    start[seq] = np.concatenate([[0], np.cumsum(size[seq])[:-1]])
    node_pos, con_pos = start[:n], start[n:]
    bw = 2
    for a, b in zip(ca, cb):
        bw = max(bw, abs(int(node_pos[a]) - int(node_pos[b])) + 2)
    for c in range(m):
        for p in (tail[c], head[c]):
            bw = max(bw, abs(int(con_pos[c]) - int(node_pos[p])))
    return node_pos, con_pos, bw


def layout(topo):
    """``(node_pos, con_pos, n_unknowns, bandwidth)`` of the KKT system of a
    :class:`~solver.kernels.records.Topology`: node p's three unknowns at ``node_pos[p] ..+2``,
    rigid member c's multiplier at ``con_pos[c]``. Raises ``ValueError`` for massive bars."""
    if np.any(np.asarray(topo.partner) >= 0) or topo.kkt.node_u.shape[0]:
        raise ValueError('implicit_midpoint: networks with massive bars (materials.bar_mass > 0) '
                         'are not supported (non-diagonal mass matrix); use rk4_projected, '
                         'rattle or dopri54_projected')
    n = len(topo.w_diag)
    tail = np.asarray(topo.con_tail, dtype=np.int64)
    head = np.asarray(topo.con_head, dtype=np.int64)
    ca, cb = np.asarray(topo.cable_a, dtype=np.int64), np.asarray(topo.cable_b, dtype=np.int64)
    best = _band_of(np.arange(n), tail, head, ca, cb)
    if n > 2:
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import reverse_cuthill_mckee
        i = np.concatenate([tail, head, ca, cb, np.arange(n)])
        j = np.concatenate([head, tail, cb, ca, np.arange(n)])
        graph = coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)).tocsr()
        perm = reverse_cuthill_mckee(graph, symmetric_mode=True)
        key = np.empty(n, dtype=np.int64)
        key[perm] = np.arange(n)
        other = _band_of(key, tail, head, ca, cb)
        if other[2] < best[2]:
            best = other
    node_pos, con_pos, bw = best
    return node_pos, con_pos, 3 * n + len(tail), bw


@jit
def _rot(rot, c):
    if rot.shape[0] == 0:
        return 1.0, 0.0
    return ROT_C[rot[c]], ROT_S[rot[c]]


# -- discrete-gradient cable forces -------------------------------------------------------------
@jit
def dg_density(s0, s1, L, k):
    """Discrete-gradient force density of a tension-only cable, ``V(s) = k/2 (s - L)_+^2``, from
    length ``s0`` to ``s1``: ``gbar = (V(s1) - V(s0)) / ((s1^2 - s0^2) / 2)`` (its limit when
    ``s1 = s0``), and ``d gbar / d s1``. ``gbar`` is C^1 in ``s1`` across the slack/taut kink."""
    t0 = s0 > L
    t1 = s1 > L
    if t0 and t1:
        q = s0 + s1
        return k * (1.0 - 2.0 * L / q), 2.0 * k * L / (q * q)
    if not (t0 or t1):
        return 0.0, 0.0
    den = s1 * s1 - s0 * s0
    if t1:                                    # slack -> taut
        e = s1 - L
        return k * e * e / den, k * e * (2.0 * den - 2.0 * s1 * e) / (den * den)
    e = s0 - L                                # taut -> slack
    return -k * e * e / den, 2.0 * s1 * k * e * e / (den * den)


@jit_inline
def _chords(x0, x1, a, b, cable_rot, c):
    """A cable's vectors and lengths at both ends of a step (to the rotated image for sym3d)."""
    ax, ay, az = rel(x0, a, b, cable_rot, c)
    bx, by, bz = rel(x1, a, b, cable_rot, c)
    return (ax, ay, az, bx, by, bz, math.sqrt(ax * ax + ay * ay + az * az),
            math.sqrt(bx * bx + by * by + bz * bz))


@jit
def dg_forces(x0, x1, m, d, f):
    """``f`` = external forces + discrete-gradient cable forces ``gbar (d0 + d1) / 2`` between
    the configurations ``x0`` and ``x1`` (their work over the step equals the change of the
    cable energy exactly)."""
    cable_a, cable_b, cable_rot = m.topo.cable_a, m.topo.cable_b, m.topo.cable_rot
    rest, EA, f_ext = d.rest, d.EA, d.f_ext
    copy_into(f, f_ext)
    for c in range(cable_a.shape[0]):
        a = cable_a[c]
        b = cable_b[c]
        cr, sr = _rot(cable_rot, c)
        ax, ay, az, bx, by, bz, s0, s1 = _chords(x0, x1, a, b, cable_rot, c)
        g, _ = dg_density(s0, s1, rest[c], EA[c] / rest[c])
        if g == 0.0:
            continue
        fx = 0.5 * g * (ax + bx)
        fy = 0.5 * g * (ay + by)
        fz = 0.5 * g * (az + bz)
        f[a, 0] += fx
        f[a, 1] += fy
        f[a, 2] += fz
        f[b, 0] -= cr * fx + sr * fy
        f[b, 1] -= cr * fy - sr * fx
        f[b, 2] -= fz


# -- assembly -------------------------------------------------------------------------------------
@jit
def _add(band, i, j, value):
    """Add ``value`` to the symmetric entry (i, j) (stored once, in the lower band)."""
    if i >= j:
        band[i, i - j] += value
    else:
        band[j, j - i] += value


@jit_alloc
def _add_pair(band, pa, pb, fa, fb, K, cr, sr, same):
    """Add the stiffness of a two-node element with 3x3 tangent ``K`` acting on ``d = R x_b -
    x_a`` (``R`` the rotation by (cr, sr) about z): blocks ``K`` (a, a), ``-K R`` (a, b),
    ``R^T K R`` (b, b), or ``(R - I)^T K (R - I)`` when a and b are the same node (``same``).
    ``fa``/``fb``: whether the nodes are free (a clamped node's rows are left alone)."""
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = cr, -sr, 0.0
    R[1, 0], R[1, 1], R[1, 2] = sr, cr, 0.0
    R[2, 0], R[2, 1], R[2, 2] = 0.0, 0.0, 1.0
    KR = K @ R
    RKR = R.T @ KR
    if same:
        if not fa:
            return
        B = K - KR - KR.T + RKR
        for i in range(3):
            for j in range(i + 1):
                _add(band, pa + i, pa + j, B[i, j])
        return
    if fa:
        for i in range(3):
            for j in range(i + 1):
                _add(band, pa + i, pa + j, K[i, j])
    if fb:
        for i in range(3):
            for j in range(i + 1):
                _add(band, pb + i, pb + j, RKR[i, j])
    if fa and fb:
        for i in range(3):
            for j in range(3):
                _add(band, pa + i, pb + j, -KR[i, j])


@jit_alloc
def assemble_kkt(x0, x1, xm, h, nu, m, d, node_pos, con_pos, band):
    """The KKT matrix of the step from ``x0`` at the iterate ``x1`` (midpoint ``xm``) into
    ``band`` (see the module doc): the cable blocks are the symmetric part of the derivative of
    the discrete-gradient force ``gbar dm`` with respect to ``x1``."""
    topo = m.topo
    w_diag, tail, head = topo.w_diag, topo.con_tail, topo.con_head
    cable_a, cable_b, rot, cable_rot = topo.cable_a, topo.cable_b, topo.con_rot, topo.cable_rot
    rest, EA = d.rest, d.EA
    band[:, :] = 0.0
    c2 = 0.5 * h * h
    for p in range(xm.shape[0]):
        q = node_pos[p]
        mass = 1.0 / w_diag[p] if w_diag[p] > 0.0 else 1.0   # a clamped node: identity rows
        for i in range(3):
            band[q + i, 0] += mass
    K = np.empty((3, 3))
    dm = np.empty(3)
    n1 = np.empty(3)
    for c in range(cable_a.shape[0]):
        a = cable_a[c]
        b = cable_b[c]
        cr, sr = _rot(cable_rot, c)
        ax, ay, az, bx, by, bz, s0, s1 = _chords(x0, x1, a, b, cable_rot, c)
        g, dg = dg_density(s0, s1, rest[c], EA[c] / rest[c])
        if g == 0.0 and dg == 0.0:
            continue
        dm[0], dm[1], dm[2] = 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * (az + bz)
        n1[0], n1[1], n1[2] = bx / s1, by / s1, bz / s1
        for i in range(3):
            for j in range(3):
                K[i, j] = c2 * (0.5 * dg * (dm[i] * n1[j] + n1[i] * dm[j])
                                + (0.5 * g if i == j else 0.0))
        _add_pair(band, node_pos[a], node_pos[b], w_diag[a] > 0.0, w_diag[b] > 0.0, K, cr, sr,
                  a == b)
    for c in range(tail.shape[0]):
        t = tail[c]
        hd = head[c]
        cr, sr = _rot(rot, c)
        bx, by, bz = rel(xm, t, hd, rot, c)
        # constraint curvature: d/dx1 of G(xm)^T nu = nu / 2 * Hessian of g_c
        for i in range(3):
            for j in range(3):
                K[i, j] = 0.5 * nu[c] if i == j else 0.0
        _add_pair(band, node_pos[t], node_pos[hd], w_diag[t] > 0.0, w_diag[hd] > 0.0, K, cr, sr,
                  t == hd)
        q = con_pos[c]
        gh0 = cr * bx + sr * by           # R^T b on the head node
        gh1 = -sr * bx + cr * by
        gt = (-bx, -by, -bz)
        gh = (gh0, gh1, bz)
        if t == hd:
            if w_diag[t] > 0.0:
                for i in range(3):
                    _add(band, q, node_pos[t] + i, gt[i] + gh[i])
            continue
        if w_diag[t] > 0.0:
            for i in range(3):
                _add(band, q, node_pos[t] + i, gt[i])
        if w_diag[hd] > 0.0:
            for i in range(3):
                _add(band, q, node_pos[hd] + i, gh[i])


@jit
def _residual(x, x0, v0, h, f, xm, nu, topo, node_pos, con_pos, rhs):
    """``rhs = -(r, g(x1))``: ``r = M (x1 - x0 - h v0) - h^2/2 f + G(xm)^T nu`` with the step's
    forces ``f`` (:func:`dg_forces`); g at ``x1 = x``."""
    w_diag, tail, head = topo.w_diag, topo.con_tail, topo.con_head
    length, rot = topo.con_length, topo.con_rot
    hh = 0.5 * h * h
    for p in range(x.shape[0]):
        q = node_pos[p]
        w = w_diag[p]
        for i in range(3):
            if w > 0.0:
                rhs[q + i] = hh * f[p, i] - (x[p, i] - x0[p, i] - h * v0[p, i]) / w
            else:
                rhs[q + i] = 0.0
    for c in range(tail.shape[0]):
        t = tail[c]
        hd = head[c]
        cr, sr = _rot(rot, c)
        bx, by, bz = rel(xm, t, hd, rot, c)
        nc = nu[c]
        qt = node_pos[t]
        qh = node_pos[hd]
        if w_diag[t] > 0.0:
            rhs[qt] += nc * bx
            rhs[qt + 1] += nc * by
            rhs[qt + 2] += nc * bz
        if w_diag[hd] > 0.0:
            rhs[qh] -= nc * (cr * bx + sr * by)
            rhs[qh + 1] -= nc * (-sr * bx + cr * by)
            rhs[qh + 2] -= nc * bz
        ex = cr * x[hd, 0] - sr * x[hd, 1] - x[t, 0]
        ey = sr * x[hd, 0] + cr * x[hd, 1] - x[t, 1]
        ez = x[hd, 2] - x[t, 2]
        rhs[con_pos[c]] = -0.5 * (ex * ex + ey * ey + ez * ez - length[c] * length[c])


@jit_alloc
def _midpoint_step(x, v, h, m, d, w, node_pos, con_pos, band, rhs, nu, x0, v0, xm, f, acc,
                   scale, nstate):
    """One step (Newton until ``max |dx| <= NEWTON_TOL * scale``); the new positions are left in
    ``x`` (velocities not yet updated), the start state in ``x0``, ``v0``. Returns a status
    code."""
    n = x.shape[0]
    w_diag = m.topo.w_diag
    copy_into(x0, x)
    copy_into(v0, v)
    status = dyn.accelerations(x0, v0, m, d, w, acc)
    nstate[3] += 1
    if status != dyn.OK:
        return status
    lam = w.lam
    for c in range(nu.shape[0]):
        nu[c] = -0.5 * h * h * lam[c]
    for p in range(n):                       # predictor: x0 + h v0 + h^2/2 a(x0, v0)
        if w_diag[p] > 0.0:
            for i in range(3):
                x[p, i] = x0[p, i] + h * v0[p, i] + 0.5 * h * h * acc[p, i]
    tol = NEWTON_TOL * scale
    prev = math.inf
    for it in range(NEWTON_MAX_ITER):
        for p in range(n):
            for i in range(3):
                xm[p, i] = 0.5 * (x0[p, i] + x[p, i])
        dg_forces(x0, x, m, d, f)
        nstate[3] += 1
        _residual(x, x0, v0, h, f, xm, nu, m.topo, node_pos, con_pos, rhs)
        assemble_kkt(x0, x, xm, h, nu, m, d, node_pos, con_pos, band)
        status = band_ldl_factor(band)
        nstate[1] += 1
        if status != dyn.OK:
            return status
        band_ldl_apply(band, rhs)
        nstate[0] += 1
        size = 0.0
        for p in range(n):
            q = node_pos[p]
            if w_diag[p] > 0.0:
                for i in range(3):
                    x[p, i] += rhs[q + i]
                    size = max(size, abs(rhs[q + i]))
        for c in range(nu.shape[0]):
            nu[c] += rhs[con_pos[c]]
        if not math.isfinite(size):
            return dyn.NONFINITE
        if size <= tol:
            return dyn.OK
        if it >= 2 and size > 0.5 * prev and size < 1e3 * tol:
            return dyn.OK                     # stagnating at round-off
        prev = size
    return NEWTON_FAILED


@jit_alloc
def midpoint_run(m, d, w, dt, n_steps, tol, max_iter, node_pos, con_pos, band, rhs, nu, x0, v0,
                 xm, f, acc, nstate):
    """``n_steps`` implicit midpoint steps of ``dt`` with projection after each; ``nstate``:
    [Newton iterations, factorisations, steps, force evaluations], accumulated. Returns (steps,
    status)."""
    x, v, topo = d.x, d.v, m.topo
    n = x.shape[0]
    for step in range(n_steps):
        scale = 0.0
        for p in range(n):
            for i in range(3):
                scale = max(scale, abs(x[p, i]))
        status = _midpoint_step(x, v, dt, m, d, w, node_pos, con_pos, band, rhs, nu, x0, v0,
                                xm, f, acc, max(scale, 1e-300), nstate)
        if status == dyn.OK:
            status = dyn.project_positions(x, topo, w, tol, max_iter)
        if status == dyn.OK:
            for p in range(n):
                for i in range(3):
                    v[p, i] = 2.0 * (x[p, i] - x0[p, i]) / dt - v0[p, i]
            status = dyn.project_velocities(x, v, topo, w)
        if status == dyn.OK and not (dyn.all_finite(x) and dyn.all_finite(v)):
            status = dyn.NONFINITE
        if status != dyn.OK:
            copy_into(x, x0)                  # the last good state
            copy_into(v, v0)
            return step, status
        nstate[2] += 1
    return n_steps, dyn.OK


@jit_alloc
def midpoint_checked(m, d, w, dt, n_steps, tol, max_iter, node_pos, con_pos, band, rhs, nu, x0,
                     v0, xm, f, acc, nstate, kept, heights):
    """:func:`midpoint_run` between ``copy_data`` and ``summary.state_summary``."""
    copy_data(d, kept)
    out = midpoint_run(m, d, w, dt, n_steps, tol, max_iter, node_pos, con_pos, band, rhs, nu, x0,
                       v0, xm, f, acc, nstate)
    return out + summary.state_summary(d.x, d.v, m, d, heights)


class ImplicitMidpoint(Integrator):
    """Implicit midpoint rule with the rigid members as unknown forces, for stiff scenes (see
    :mod:`solver.integrators.implicit`): order 2, A-stable, symmetric; Newton on a banded KKT
    system each step, then projection. Fixed steps (no kink landing). ``stats()`` counts Newton
    iterations, factorisations and force evaluations. Massive bars are refused."""
    name = 'implicit_midpoint'
    order = 2
    projected = True
    evaluations_per_step = 3

    def __init__(self, rtol=1e-8, atol=1e-10):
        super().__init__(rtol, atol)
        self.nstate = np.zeros(4)
        self._layout = None

    kernel = staticmethod(midpoint_run)
    checked = staticmethod(midpoint_checked)

    def reset(self):
        self.nstate[:] = 0.0

    def stats(self):
        """``{'steps', 'newton_iterations', 'factorizations', 'evaluations'}`` since the last
        reset."""
        s = self.nstate
        return {'steps': int(s[2]), 'newton_iterations': int(s[0]),
                'factorizations': int(s[1]), 'evaluations': int(s[3])}

    def _args(self, m, d):
        if self._layout is None or self._layout[0] is not m.topo:
            self._layout = (m.topo, layout(m.topo))
        x = d.x
        node_pos, con_pos, size, bw = self._layout[1]
        n, n_con = x.shape[0], len(con_pos)
        return (node_pos, con_pos, self.scratch('band', (size, bw + 1)),
                self.scratch('rhs', (size,)), self.scratch('nu', (n_con,)),
                self.scratch('x0', x.shape), self.scratch('v0', x.shape),
                self.scratch('xm', x.shape), self.scratch('f', x.shape),
                self.scratch('acc', (n, 3)), self.nstate)

    @staticmethod
    def _refuse_effects(m):
        """The step has no bar contact, cable damping, prism stops or strikers: refuse them
        rather than run without them."""
        if m.bar_contact.pairs.size:
            raise ValueError('implicit_midpoint: bar contact (contact.bars: hertz) is not part of '
                             'its step: its discrete gradient conserves the cable energy only, '
                             'and its long fixed steps cannot resolve a contact lasting '
                             'microseconds; use rk4_projected or dopri54_projected, or set '
                             'contact.bars: none')
        if m.damping.coef.size or m.stops.height.size or m.strikers.row.size:
            raise ValueError('implicit_midpoint: cable damping, prism stops (contact.lock) and '
                             'strikers are not part of its step; use rk4_projected or '
                             'dopri54_projected')

    def run(self, m, d, w, dt, n_steps, tol=1e-12, max_iter=3, kinks=True):
        self._refuse_effects(m)
        steps, status = self.kernel(m, d, w, float(dt), int(n_steps), float(tol), int(max_iter),
                                    *self._args(m, d))
        return int(steps), int(status)

    def checked_args(self, m, d, w, tol, max_iter, kinks, kept):
        self._refuse_effects(m)
        return (float(tol), int(max_iter)) + self._args(m, d) + (kept,)
