"""Contact between the bars of a prism: rods of radius ``r_b`` that touch when the closest distance
of their axes reaches ``D = 2 r_b`` (docs/physics.md section 9).

A pair is two bar segments given by their end nodes, each end a node and a rotation index (the
node's image ``R^r x_node``; all 0 in ``full3d``)::

    pairs (n_pairs, 8) int64: a_lo, ra_lo, a_hi, ra_hi, b_lo, rb_lo, b_hi, rb_hi

of the model's :class:`~solver.kernels.records.BarContact` record ``bc``, with the diameter ``D``
m, Hertz's ``k`` N/m^1.5, the energy multiplicity, the smallest node mass and the steps per
contact.

The law is Hertz's for two crossed rods of equal radius and material (effective radius ``r_b``):
``F = k d^1.5`` at overlap ``d = D - dist``, ``k = 4/3 E* sqrt(r_b)``, ``E* = E / (2 (1 - nu^2))``,
energy ``2 k d^2.5 / 5``; the force acts along the line of the closest points, on each bar at its
closest point, shared by its two end nodes by the lever rule (exact for a massless rigid bar). In
``sym3d`` one pair stands for the three of an orbit: its forces on the images are rotated back onto
the representatives (they are then the forces of the other two pairs), its energy counts 3 times.

The steps around a contact are sized by :mod:`solver.kernels.contactsteps`, whose scans keep
their state in ``ContactState.scan`` (:mod:`solver.kernels.records`: :data:`MET` .. :data:`HEAD`,
and the positions of :func:`remember`).

**Bases.** The two bases of a prism cannot pass through each other: when its height (mean z of
its upper level minus that of its lower, ``Model.levels``) falls below ``D`` (the
thickness of the bars lying flat between them), each joint of the upper level rests on the lower
base as one more crossed-rod contact, ``F = k d^1.5`` per node at overlap ``d = D - h``, energy
``2 k d^2.5 / 5`` per node of the full network.
"""
import math

from solver.compiled import jit, jit_inline
from solver.kernels.records import HEAD, MET, MOTION  # noqa: F401 (MET: named in the doc)
from solver.kernels.rotation import ROT_C, ROT_S


def hertz_constant(radius, E, poisson):
    """``k`` N/m^1.5 of two crossed rods of radius ``radius`` m, modulus ``E`` Pa."""
    return 4.0 / 3.0 * E / (2.0 * (1.0 - poisson * poisson)) * math.sqrt(radius)


# the columns of a pair's row: each end's node and rotation
A_LO, RA_LO, A_HI, RA_HI, B_LO, RB_LO, B_HI, RB_HI = range(8)


@jit_inline
def point(u, node, r):
    if r == 0:
        return u[node, 0], u[node, 1], u[node, 2]
    c = ROT_C[r]
    s = ROT_S[r]
    return c * u[node, 0] - s * u[node, 1], s * u[node, 0] + c * u[node, 1], u[node, 2]


@jit_inline
def _push(f, node, r, gx, gy, gz):
    """``f[node] += R^-r g``."""
    c = ROT_C[r]
    s = ROT_S[r]
    f[node, 0] += c * gx + s * gy
    f[node, 1] += c * gy - s * gx
    f[node, 2] += gz


@jit_inline
def _clamp01(a):
    return 0.0 if a < 0.0 else (1.0 if a > 1.0 else a)


@jit
def segment_params(ax, ay, az, ux, uy, uz, bx, by, bz, wx, wy, wz):
    """``(s, t)`` in [0, 1]^2 of the closest points ``a + s u``, ``b + t w`` of two segments of
    non-zero length (Ericson, Real-Time Collision Detection, 5.1.9)."""
    rx, ry, rz = ax - bx, ay - by, az - bz
    a = ux * ux + uy * uy + uz * uz
    e = wx * wx + wy * wy + wz * wz
    f = wx * rx + wy * ry + wz * rz
    c = ux * rx + uy * ry + uz * rz
    b = ux * wx + uy * wy + uz * wz
    denom = a * e - b * b
    s = _clamp01((b * f - c * e) / denom) if denom > 1e-14 * a * e else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t = 0.0
        s = _clamp01(-c / a)
    elif t > 1.0:
        t = 1.0
        s = _clamp01((b - c) / a)
    return s, t


@jit_inline
def pair(x, pairs, i):
    """Closest points of pair ``i``: ``(s, t, n)`` with ``n = P - Q`` (from bar b to bar a)."""
    p = pairs[i]
    a0x, a0y, a0z = point(x, p[A_LO], p[RA_LO])
    a1x, a1y, a1z = point(x, p[A_HI], p[RA_HI])
    b0x, b0y, b0z = point(x, p[B_LO], p[RB_LO])
    b1x, b1y, b1z = point(x, p[B_HI], p[RB_HI])
    ux, uy, uz = a1x - a0x, a1y - a0y, a1z - a0z
    wx, wy, wz = b1x - b0x, b1y - b0y, b1z - b0z
    s, t = segment_params(a0x, a0y, a0z, ux, uy, uz, b0x, b0y, b0z, wx, wy, wz)
    nx = a0x + s * ux - b0x - t * wx
    ny = a0y + s * uy - b0y - t * wy
    nz = a0z + s * uz - b0z - t * wz
    if nx * nx + ny * ny + nz * nz < 1e-30:     # axes meet: push along their common normal
        nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
        scale = 1e-300 / math.sqrt(nx * nx + ny * ny + nz * nz + 1e-300)
        nx, ny, nz = nx * scale, ny * scale, nz * scale
    return s, t, nx, ny, nz


@jit_inline
def rel_velocity(v, p, s, t):
    """Velocity of the closest point of bar a minus that of bar b."""
    a0x, a0y, a0z = point(v, p[A_LO], p[RA_LO])
    a1x, a1y, a1z = point(v, p[A_HI], p[RA_HI])
    b0x, b0y, b0z = point(v, p[B_LO], p[RB_LO])
    b1x, b1y, b1z = point(v, p[B_HI], p[RB_HI])
    return ((1.0 - s) * a0x + s * a1x - (1.0 - t) * b0x - t * b1x,
            (1.0 - s) * a0y + s * a1y - (1.0 - t) * b0y - t * b1y,
            (1.0 - s) * a0z + s * a1z - (1.0 - t) * b0z - t * b1z)


@jit
def bar_forces(x, bc, f, active):
    """Add the contact forces of the touching pairs of ``bc`` to ``f``; returns how many pairs
    touch. ``active``: ``active[0]`` < 0 looks at every pair, else only at the ``active[0]``
    pairs listed after it (those the last scan found could touch: see
    ``contactsteps.scan_step``)."""
    pairs = bc.pairs
    D = bc.diameter
    k = bc.k
    touching = 0
    n = pairs.shape[0] if active[0] < 0 else active[0]
    for q in range(n):
        i = q if active[0] < 0 else active[q + 1]
        s, t, nx, ny, nz = pair(x, pairs, i)
        dist = math.sqrt(nx * nx + ny * ny + nz * nz)
        if dist >= D:
            continue
        touching += 1
        d = D - dist
        g = k * d * math.sqrt(d) / max(dist, 1e-300)
        gx, gy, gz = g * nx, g * ny, g * nz
        p = pairs[i]
        _push(f, p[A_LO], p[RA_LO], (1.0 - s) * gx, (1.0 - s) * gy, (1.0 - s) * gz)
        _push(f, p[A_HI], p[RA_HI], s * gx, s * gy, s * gz)
        _push(f, p[B_LO], p[RB_LO], -(1.0 - t) * gx, -(1.0 - t) * gy, -(1.0 - t) * gz)
        _push(f, p[B_HI], p[RB_HI], -t * gx, -t * gy, -t * gz)
    return touching


@jit_inline
def level_z(u, levels, c, j):
    z = 0.0
    for i in range(levels.shape[2]):
        z += u[levels[c, j, i], 2]
    return z / levels.shape[2]


@jit
def base_forces(x, levels, bc, f):
    """Add the forces of the prisms whose bases touch (height below ``D``) to ``f``; returns
    how many touch."""
    D, k = bc.diameter, bc.k
    touching = 0
    for c in range(levels.shape[0]):
        for j in range(1, levels.shape[1]):
            d = D - (level_z(x, levels, c, j) - level_z(x, levels, c, j - 1))
            if d > 0.0:
                touching += 1
                F = k * d * math.sqrt(d)
                for i in range(levels.shape[2]):
                    f[levels[c, j, i], 2] += F
                    f[levels[c, j - 1, i], 2] -= F
    return touching


@jit_inline
def prism_base_energy(x, levels, bc, c, j):
    """Energy J stored where the bases of prism ``j`` of column ``c`` touch, per node, not yet
    times the multiplicity (0 unless its height is below ``D``)."""
    d = bc.diameter - (level_z(x, levels, c, j) - level_z(x, levels, c, j - 1))
    if d > 0.0:
        return 0.4 * bc.k * d * d * math.sqrt(d)
    return 0.0


@jit
def base_energy(x, levels, bc, per_level):
    """Energy J stored where bases touch (every node of the full network counted: ``per_level``
    nodes per level)."""
    e = 0.0
    for c in range(levels.shape[0]):
        for j in range(1, levels.shape[1]):
            e += prism_base_energy(x, levels, bc, c, j)
    return per_level * e


@jit_inline
def _pair_energy(x, bc, i):
    """Energy J stored in pair ``i`` (0 unless it overlaps), not yet times the multiplicity."""
    s, t, nx, ny, nz = pair(x, bc.pairs, i)
    dist = math.sqrt(nx * nx + ny * ny + nz * nz)
    if dist >= bc.diameter:
        return 0.0
    d = bc.diameter - dist
    return 0.4 * bc.k * d * d * math.sqrt(d)


@jit
def bar_energy(x, bc):
    """Energy J stored in the touching pairs (times the multiplicity ``bc.mult``)."""
    e = 0.0
    for i in range(bc.pairs.shape[0]):
        e += _pair_energy(x, bc, i)
    return bc.mult * e


@jit_inline
def at_remembered(x, state):
    """Whether ``x`` are the positions :func:`remember` kept in the last ``3 n`` entries."""
    k = state.shape[0] - 3 * x.shape[0]
    for p in range(x.shape[0]):
        for i in range(3):
            if state[k + 3 * p + i] != x[p, i]:
                return False
    return True


@jit
def bar_energy_scanned(x, bc, state):
    """:func:`bar_energy` of the positions ``x`` an integrator call ended at, skipping the pairs
    whose gap the scans bound above zero (``state``, see ``contactsteps.contact_step``): they
    store none, so the sum is the same, for a fraction of the pairs. At any other positions (a
    command moved the state, a call stopped early, the scans were reset) every pair is
    evaluated."""
    return bar_energy_bounded(x, bc, state,
                              math.isfinite(state[MOTION]) and at_remembered(x, state))


@jit_inline
def bar_energy_bounded(x, bc, state, bounded):
    """:func:`bar_energy`, skipping the pairs whose gap bound in ``state`` less the motion summed
    since (``state[MOTION]``) is positive, where the bounds hold at ``x`` (``bounded``); with
    ``bounded`` False every pair is evaluated."""
    known = state[MOTION]
    e = 0.0
    for i in range(bc.pairs.shape[0]):
        if not (bounded and state[HEAD + i] - known > 0.0):
            e += _pair_energy(x, bc, i)
    return bc.mult * e


@jit
def remember(x, state):
    """At the end of an integrator call that finished: the positions it ended at."""
    k = state.shape[0] - 3 * x.shape[0]
    for p in range(x.shape[0]):
        for i in range(3):
            state[k + 3 * p + i] = x[p, i]
