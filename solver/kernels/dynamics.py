"""Numba kernels of the constrained dynamics (docs/physics.md section 1.1).

Two levels, as everywhere in the solver: Python builders (:func:`plain`,
:func:`solver.models.extras.build`) validate and allocate, the ``@jit`` kernels take arrays and
the named records of :mod:`solver.kernels.records` (``m`` a :class:`~solver.kernels.records.Model`,
``d`` its :class:`~solver.kernels.records.Data`, ``w`` its :class:`~solver.kernels.records.Work`)
and write into ``out`` arrays.

:func:`accelerations` is the one entry that composes the forces of every effect a scene switches
on (external forces, cables with or without damping, prism stops, strikers, bar and base contact)
and solves the constraints for the accelerations; the integrators call it and know nothing of
which effects exist. A member of a ``sym3d`` model joins its tail node to the ROTATED IMAGE
``R^r x_head`` of its head node (``topo.con_rot``, ``topo.cable_rot``); with those empty every
kernel takes the plain path, so ``full3d`` pays nothing for them. ``topo.kkt`` is the layout of
the mass-matrix system of :mod:`solver.kernels.massmatrix` (massive bars that share nodes); its
arrays are empty for every other network, and the kernels then take the node-local inverse mass
path unchanged.

Status codes returned by kernels: ``OK``, ``SINGULAR`` (constraint matrix not positive definite:
dependent or degenerate rigid members), ``NONFINITE`` (NaN or inf appeared), ``NOT_CONVERGED``
(the position projection did not reach its tolerance).
"""
import math

from solver.kernels import massmatrix as mm
from solver.kernels.banded import band_ldl_solve
from solver.compiled import jit
from solver.kernels.barcontact import bar_forces, base_forces
from solver.kernels.contact import axial_contacts, cable_forces_damped
from solver.kernels.records import LOOK, MET, copy_into
from solver.kernels.rotation import (ROT_C, ROT_S, add_constraint_forces_rot,  # noqa: F401
                                     assemble_band_rot, cable_forces_rot, member_vectors_rot,
                                     rel)
from solver.status import NONFINITE, NOT_CONVERGED, OK, SINGULAR  # noqa: F401


@jit
def cable_forces(x, cable_a, cable_b, rest, EA, f):
    """Add tension-only cable forces to ``f`` (n_nodes, 3) N: ``T = EA (s - L) / L`` when
    ``s > L``."""
    for c in range(cable_a.shape[0]):
        a = cable_a[c]
        b = cable_b[c]
        dx = x[b, 0] - x[a, 0]
        dy = x[b, 1] - x[a, 1]
        dz = x[b, 2] - x[a, 2]
        s = math.sqrt(dx * dx + dy * dy + dz * dz)
        L = rest[c]
        if s > L:
            g = EA[c] / L * (s - L) / s   # force density gamma = T / s
            f[a, 0] += g * dx
            f[a, 1] += g * dy
            f[a, 2] += g * dz
            f[b, 0] -= g * dx
            f[b, 1] -= g * dy
            f[b, 2] -= g * dz


@jit
def apply_w(f, w_diag, partner, w_off, out):
    """``out = W f``: the inverse mass operator, node-wise (a partner only for massive bars)."""
    for p in range(f.shape[0]):
        w = w_diag[p]
        q = partner[p]
        for i in range(3):
            out[p, i] = w * f[p, i]
        if q >= 0:
            wo = w_off[p]
            for i in range(3):
                out[p, i] += wo * f[q, i]


@jit
def member_vectors(x, tail, head, bvec):
    for c in range(tail.shape[0]):
        for i in range(3):
            bvec[c, i] = x[head[c], i] - x[tail[c], i]


@jit
def assemble_band(bvec, coef, band):
    """``band[c, k] = A[c, c-k] = coef[c, k] * (b_c . b_{c-k})``."""
    m, width = coef.shape
    for c in range(m):
        for k in range(width):
            cf = coef[c, k]
            if cf == 0.0 or k > c:
                band[c, k] = 0.0
                continue
            d = c - k
            band[c, k] = cf * (bvec[c, 0] * bvec[d, 0] + bvec[c, 1] * bvec[d, 1]
                               + bvec[c, 2] * bvec[d, 2])


@jit
def add_constraint_forces(lam, bvec, tail, head, f):
    """``f += sum_c lam_c G_c``: ``+lam b`` on the head node, ``-lam b`` on the tail node."""
    for c in range(tail.shape[0]):
        h = head[c]
        t = tail[c]
        for i in range(3):
            g = lam[c] * bvec[c, i]
            f[h, i] += g
            f[t, i] -= g


# the dispatchers take the single arrays their branches read: plain or rotated (sym3d) kernels
@jit
def _members(x, tail, head, rot, bvec):
    if rot.shape[0] == 0:
        member_vectors(x, tail, head, bvec)
    else:
        member_vectors_rot(x, tail, head, rot, bvec)


@jit
def _assemble(bvec, coef, coef3, rot, band):
    if rot.shape[0] == 0:
        assemble_band(bvec, coef, band)
    else:
        assemble_band_rot(bvec, coef3, band)


@jit
def _add_forces(lam, bvec, tail, head, rot, f):
    if rot.shape[0] == 0:
        add_constraint_forces(lam, bvec, tail, head, f)
    else:
        add_constraint_forces_rot(lam, bvec, tail, head, rot, f)


@jit
def accelerations(x, v, m, d, w, out):
    """Accelerations (n_rows, 3) m/s^2 of the constrained system at ``x``, ``v`` into ``out``, with
    the forces of every effect of the model ``m`` (its data ``d``, scratch ``w``); multipliers
    (bar force densities, > 0 in compression) are left in ``w.lam``, the damping's power in
    ``d.ledger[POWER]``, the contacts met counted in ``d.contact.scan[MET]``. Returns a status
    code."""
    topo = m.topo
    tail, head, rot, cable_rot = topo.con_tail, topo.con_head, topo.con_rot, topo.cable_rot
    f, wf, bvec, band, lam = w.f, w.wf, w.bvec, w.band, w.lam
    copy_into(f, d.f_ext)
    if m.damping.coef.shape[0] != 0:        # damped cables (solver.kernels.contact)
        cable_forces_damped(x, v, topo.cable_a, topo.cable_b, cable_rot, d.rest, d.EA,
                            m.damping.coef, f, d.ledger)
    elif cable_rot.shape[0] == 0:
        cable_forces(x, topo.cable_a, topo.cable_b, d.rest, d.EA, f)
    else:
        cable_forces_rot(x, topo.cable_a, topo.cable_b, cable_rot, d.rest, d.EA, f)
    if m.stops.height.shape[0] != 0 or m.strikers.row.shape[0] != 0:
        axial_contacts(x, m, f)
    scan = d.contact.scan
    if m.bar_contact.pairs.shape[0] != 0 and scan[LOOK] != 0.0:   # kernels.barcontact
        scan[MET] += bar_forces(x, m.bar_contact, f, d.contact.active)
        if scan[LOOK] == 1.0:                                       # 2: no two bases can touch
            scan[MET] += base_forces(x, m.levels, m.bar_contact, f)
    if topo.kkt.node_u.shape[0] != 0:       # massive bars sharing nodes: the banded KKT system
        return mm.accelerations(x, v, f, tail, head, rot, topo.kkt, w.kkt, bvec, lam, out)
    apply_w(f, topo.w_diag, topo.partner, topo.w_off, wf)
    if rot.shape[0] == 0:
        member_vectors(x, tail, head, bvec)
        for c in range(tail.shape[0]):
            h = head[c]
            t = tail[c]
            s = 0.0
            for i in range(3):
                db = v[h, i] - v[t, i]
                s += bvec[c, i] * (wf[h, i] - wf[t, i]) + db * db
            lam[c] = -s
        assemble_band(bvec, topo.con_coef, band)
    else:
        member_vectors_rot(x, tail, head, rot, bvec)
        for c in range(tail.shape[0]):
            ax, ay, az = rel(wf, tail[c], head[c], rot, c)
            dx, dy, dz = rel(v, tail[c], head[c], rot, c)
            lam[c] = -(bvec[c, 0] * ax + bvec[c, 1] * ay + bvec[c, 2] * az
                       + dx * dx + dy * dy + dz * dz)
        assemble_band_rot(bvec, topo.con_coef3, band)
    status = band_ldl_solve(band, lam)
    if status != OK:
        return status
    _add_forces(lam, bvec, tail, head, rot, f)
    apply_w(f, topo.w_diag, topo.partner, topo.w_off, out)
    return OK


@jit
def project_positions(x, topo, w, tol, max_iter):
    """Mass-weighted Gauss-Newton projection of positions onto the rigid-member manifold:
    ``A dmu = -g``, ``x += W sum_c dmu_c G_c`` until ``|g_c| < tol L_c^2``. Returns a status
    code."""
    w_diag, partner, w_off = topo.w_diag, topo.partner, topo.w_off
    tail, head, length = topo.con_tail, topo.con_head, topo.con_length
    coef, rot, coef3 = topo.con_coef, topo.con_rot, topo.con_coef3
    f, wf, bvec, band, lam = w.f, w.wf, w.bvec, w.band, w.lam
    if topo.kkt.node_u.shape[0] != 0:
        return mm.project_positions(x, tail, head, rot, length, topo.kkt, w.kkt, bvec, tol,
                                    max_iter)
    for it in range(max_iter + 1):
        _members(x, tail, head, rot, bvec)
        worst = 0.0
        for c in range(tail.shape[0]):
            L2 = length[c] * length[c]
            g = 0.5 * (bvec[c, 0] ** 2 + bvec[c, 1] ** 2 + bvec[c, 2] ** 2 - L2)
            lam[c] = -g
            e = abs(g) / L2
            if not e <= worst:
                worst = e
        if worst < tol:
            return OK
        if it == max_iter or not math.isfinite(worst):
            break
        status = _correct(x, lam, bvec, band, coef, coef3, rot, tail, head, f, wf, w_diag,
                          partner, w_off)
        if status != OK:
            return status
    return NOT_CONVERGED


@jit
def project_velocities(x, v, topo, w):
    """Mass-weighted projection of velocities onto the constraint tangent space:
    ``A mu = -J v``, ``v += W J^T mu`` (the impulse that removes every velocity violating a rigid
    member while changing momentum least in the mass metric). Returns a status code."""
    w_diag, partner, w_off = topo.w_diag, topo.partner, topo.w_off
    tail, head, rot = topo.con_tail, topo.con_head, topo.con_rot
    coef, coef3 = topo.con_coef, topo.con_coef3
    f, wf, bvec, band, lam = w.f, w.wf, w.bvec, w.band, w.lam
    if topo.kkt.node_u.shape[0] != 0:
        return mm.project_velocities(x, v, tail, head, rot, topo.kkt, w.kkt, bvec)
    _members(x, tail, head, rot, bvec)
    if rot.shape[0] == 0:
        for c in range(tail.shape[0]):
            h = head[c]
            t = tail[c]
            lam[c] = -(bvec[c, 0] * (v[h, 0] - v[t, 0]) + bvec[c, 1] * (v[h, 1] - v[t, 1])
                       + bvec[c, 2] * (v[h, 2] - v[t, 2]))
    else:
        for c in range(tail.shape[0]):
            dx, dy, dz = rel(v, tail[c], head[c], rot, c)
            lam[c] = -(bvec[c, 0] * dx + bvec[c, 1] * dy + bvec[c, 2] * dz)
    return _correct(v, lam, bvec, band, coef, coef3, rot, tail, head, f, wf, w_diag, partner,
                    w_off)


@jit
def _correct(u, lam, bvec, band, coef, coef3, rot, tail, head, f, wf, w_diag, partner, w_off):
    """The mass-weighted correction of both projections: solve ``A mu = lam`` (``lam`` becomes
    mu), then ``u += W sum_c mu_c G_c``. Returns a status code."""
    _assemble(bvec, coef, coef3, rot, band)
    status = band_ldl_solve(band, lam)
    if status != OK:
        return status
    f[:, :] = 0.0
    _add_forces(lam, bvec, tail, head, rot, f)
    apply_w(f, w_diag, partner, w_off, wf)
    for p in range(u.shape[0]):
        for i in range(3):
            u[p, i] += wf[p, i]
    return OK


@jit
def all_finite(a):
    """Whether every entry of the 2D array ``a`` is finite. ``a * 0`` is 0 for a finite entry and
    NaN for an infinite or NaN one, so the sum of them is 0 exactly when all are finite: no
    branch per entry, and three independent sums let the additions overlap (5x faster than
    testing each entry, which the integrators do after every step)."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    n = a.shape[0]
    for i in range(a.shape[1]):
        p = 0
        while p + 2 < n:
            s0 += a[p, i] * 0.0
            s1 += a[p + 1, i] * 0.0
            s2 += a[p + 2, i] * 0.0
            p += 3
        while p < n:
            s0 += a[p, i] * 0.0
            p += 1
    return s0 + s1 + s2 == 0.0


@jit
def finite_below(a, limit):
    """Whether every entry of the 1D array ``a`` is finite and of magnitude below ``limit`` (a NaN
    fails). For callers between kernels (a recorder checking each frame): NumPy's and OpenBLAS's
    reductions take 512-bit instructions on CPUs with AVX-512, after which the solver's kernels ran
    slower for a while (7 % of a recorded run, see docs/rerun.md); numba's code keeps to 256-bit
    vectors."""
    s = 0.0
    m = 0.0
    for i in range(a.shape[0]):
        s += a[i] * 0.0
        m = max(m, abs(a[i]))
    return s == 0.0 and m < limit
