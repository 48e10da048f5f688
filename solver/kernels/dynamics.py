"""Numba kernels of the constrained dynamics (docs/physics.md section 1.1).

Two levels, as everywhere in the solver: :func:`pack` (Python) validates and allocates, the
``@jit`` kernels take arrays and tuples of arrays only and write into ``out`` arrays.

``net`` tuple (read-only model arrays, see :class:`solver.build.network.Network`)::

    (w_diag, partner, w_off, con_tail, con_head, con_length, con_coef, cable_a, cable_b,
     con_rot, cable_rot, con_coef3, kkt)

The last three serve the symmetric reduction (:mod:`solver.models.sym3d`) and are empty for a plain
network:
a member then joins its tail node to the ROTATED IMAGE ``R^r x_head`` of its head node, ``R`` the
rotation by 2 pi / 3 about z and ``r = con_rot[c]`` (``cable_rot`` for cables) in {0, 1, 2}; the
force
on the image is rotated back onto the node. ``con_coef3`` (n_con, bw + 1, 3) replaces ``con_coef``:
``A[c, c-k] = coef3[c, k] . (b_c^z b_d^z, b_c^x b_d^x + b_c^y b_d^y, b_c^y b_d^x - b_c^x b_d^y)``.
With empty arrays every kernel takes the plain path (r = 0), so ``full3d`` pays nothing for them.
``kkt`` is the layout of the mass-matrix system of :mod:`solver.kernels.massmatrix` (massive bars
that share nodes); its arrays are empty for every other network, and the kernels then take the
node-local inverse mass path unchanged.

``act`` tuple (actuation, mutable by commands)::

    (cable_rest_length (n_cables,) m, cable_EA (n_cables,) N, f_ext (n_nodes, 3) N, extras)

``extras``: cable damping, strikers and prism stops (:mod:`solver.kernels.contact`); all empty
(:data:`solver.kernels.contact.NO_EXTRAS`) unless a scene asks for them, and then the kernels take
the code path they take without them.

``ws`` workspace tuple (scratch, preallocated once): see :func:`workspace`.

Status codes returned by kernels: ``OK``, ``SINGULAR`` (constraint matrix not positive definite:
dependent or degenerate rigid members), ``NONFINITE`` (NaN or inf appeared), ``NOT_CONVERGED``
(the position projection did not reach its tolerance).
"""
import math

import numpy as np

from solver.kernels import massmatrix as mm
from solver.kernels.banded import band_ldl_solve
from solver._jit import jit
from solver.kernels.barcontact import bar_forces, base_forces
from solver.kernels.contact import NO_EXTRAS, axial_contacts, cable_forces_damped
from solver.kernels.rotation import (ROT_C, ROT_S, add_constraint_forces_rot,  # noqa: F401
                                     assemble_band_rot, cable_forces_rot, member_vectors_rot,
                                     rel)
from solver.status import NONFINITE, NOT_CONVERGED, OK, SINGULAR  # noqa: F401


NO_ROT = np.zeros(0, dtype=np.int64)
NO_ROT.setflags(write=False)
NO_COEF3 = np.zeros((0, 1, 3))
NO_COEF3.setflags(write=False)


def readonly(a):
    """``a`` as a read-only array (a view when it is writable). The static arrays of the kernels
    (``net``, ``summ``) are all read-only, wherever they come from (a network's own arrays, or
    ones padded or computed here): numba compiles a kernel once per combination of writable and
    read-only arguments, and the first FB kernel alone takes about a minute to compile."""
    a = np.asarray(a)
    if not a.flags.writeable:
        return a
    view = a.view()
    view.flags.writeable = False
    return view


def pack(network, cable_rest_length=None, cable_EA=None, f_ext=None):
    """The ``(net, act)`` tuples of a network; ``act`` arrays are fresh writable copies. A network
    with rotated members (:class:`solver.models.sym3d.ReducedNetwork`) fills the last three ``net``
    slots."""
    net = tuple(readonly(a) for a in (
        network.w_diag, network.partner, network.w_off, network.con_tail, network.con_head,
        network.con_length, network.con_coef, network.cable_a, network.cable_b,
        getattr(network, 'con_rot', NO_ROT), getattr(network, 'cable_rot', NO_ROT),
        getattr(network, 'con_coef3', NO_COEF3))) + (getattr(network, 'kkt', mm.NO_KKT),)
    rest = np.array(network.cable_rest_length if cable_rest_length is None else cable_rest_length,
                    dtype=np.float64)
    EA = np.array(network.cable_EA if cable_EA is None else cable_EA, dtype=np.float64)
    f = np.zeros((network.n_nodes, 3)) if f_ext is None else np.array(f_ext, dtype=np.float64)
    return net, (rest, EA, f, NO_EXTRAS)


def workspace(n_nodes, n_con, bandwidth, kkt_dims=None):
    """Scratch arrays: ``(f, wf, bvec, band, lam, stage arrays..., kws)``; ``kws`` (the last) is
    the scratch of the mass-matrix system for ``kkt_dims = (n_u, kl, ku)`` (empty when None)."""
    def z(*shape):
        return np.zeros(shape)
    return (z(n_nodes, 3), z(n_nodes, 3), z(n_con, 3), z(n_con, bandwidth + 1), z(n_con),
            z(n_nodes, 3), z(n_nodes, 3), z(n_nodes, 3), z(n_nodes, 3), z(n_nodes, 3),
            z(n_nodes, 3), mm.scratch(mm.NO_DIMS if kkt_dims is None else kkt_dims))


def workspace_for(network):
    """:func:`workspace` sized for ``network`` (a :class:`~solver.build.network.Network` or a
    reduced one), including the scratch of its mass-matrix system."""
    kkt = getattr(network, 'kkt', mm.NO_KKT)
    return workspace(network.n_nodes, network.n_constraints, network.bandwidth, kkt[5])


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


# the dispatchers take single arrays, never the whole ``net`` tuple: passing a tuple of arrays to
# a compiled function costs a reference count per array (about 1 us per projection measured)
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
def accelerations(x, v, net, act, ws, out):
    """Accelerations (n_nodes, 3) m/s^2 of the constrained system into ``out``; multipliers
    (bar force densities, > 0 in compression) are left in ``ws[4]``. Returns a status code."""
    w_diag, partner, w_off, tail, head = net[0], net[1], net[2], net[3], net[4]
    coef, cable_a, cable_b, rot, coef3 = net[6], net[7], net[8], net[9], net[11]
    rest, EA, f_ext, ex = act[0], act[1], act[2], act[3]
    f, wf, bvec, band, lam = ws[0], ws[1], ws[2], ws[3], ws[4]
    f[:, :] = f_ext
    if ex[0].shape[0] != 0:                 # damped cables (solver.kernels.contact)
        cable_forces_damped(x, v, cable_a, cable_b, net[10], rest, EA, ex[0], f, ex[10])
    elif net[10].shape[0] == 0:
        cable_forces(x, cable_a, cable_b, rest, EA, f)
    else:
        cable_forces_rot(x, cable_a, cable_b, net[10], rest, EA, f)
    if ex[2].shape[0] != 0 or ex[3].shape[0] != 0:      # prism stops, strikers
        axial_contacts(x, ex, f)
    if ex[6].shape[0] != 0 and ex[8][2] != 0.0:         # bars touching (kernels.barcontact)
        ex[8][0] += bar_forces(x, ex[6], ex[7], f, ex[11])
        if ex[8][2] == 1.0:                             # 2: no two bases can touch
            ex[8][0] += base_forces(x, ex[1], ex[7], f)
    if net[12][0].shape[0] != 0:        # massive bars sharing nodes: the banded KKT system
        return mm.accelerations(x, v, f, tail, head, rot, net[12], ws[11], bvec, lam, out)
    apply_w(f, w_diag, partner, w_off, wf)
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
        assemble_band(bvec, coef, band)
    else:
        member_vectors_rot(x, tail, head, rot, bvec)
        for c in range(tail.shape[0]):
            ax, ay, az = rel(wf, tail[c], head[c], rot, c)
            dx, dy, dz = rel(v, tail[c], head[c], rot, c)
            lam[c] = -(bvec[c, 0] * ax + bvec[c, 1] * ay + bvec[c, 2] * az
                       + dx * dx + dy * dy + dz * dz)
        assemble_band_rot(bvec, coef3, band)
    status = band_ldl_solve(band, lam)
    if status != OK:
        return status
    _add_forces(lam, bvec, tail, head, rot, f)
    apply_w(f, w_diag, partner, w_off, out)
    return OK


@jit
def project_positions(x, net, ws, tol, max_iter):
    """Mass-weighted Gauss-Newton projection of positions onto the rigid-member manifold:
    ``A dmu = -g``, ``x += W sum_c dmu_c G_c`` until ``|g_c| < tol L_c^2``. Returns a status
    code."""
    w_diag, partner, w_off, tail, head, length = net[0], net[1], net[2], net[3], net[4], net[5]
    coef, rot, coef3 = net[6], net[9], net[11]
    f, wf, bvec, band, lam = ws[0], ws[1], ws[2], ws[3], ws[4]
    if net[12][0].shape[0] != 0:
        return mm.project_positions(x, tail, head, rot, length, net[12], ws[11], bvec, tol,
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
def project_velocities(x, v, net, ws):
    """Mass-weighted projection of velocities onto the constraint tangent space:
    ``A mu = -J v``, ``v += W J^T mu`` (the impulse that removes every velocity violating a rigid
    member while changing momentum least in the mass metric). Returns a status code."""
    w_diag, partner, w_off, tail, head, rot = net[0], net[1], net[2], net[3], net[4], net[9]
    coef, coef3 = net[6], net[11]
    f, wf, bvec, band, lam = ws[0], ws[1], ws[2], ws[3], ws[4]
    if net[12][0].shape[0] != 0:
        return mm.project_velocities(x, v, tail, head, rot, net[12], ws[11], bvec)
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
