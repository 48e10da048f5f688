"""Unilateral contacts and cable damping: the striker, the prism stops, viscous cables.

Everything here enters the dynamics through one tuple, the fourth slot of the ``act`` tuple of
:mod:`solver.kernels.dynamics` (``act[3]``, "extras")::

    (damp (n_cables,) N s/m, levels (n_columns, n_levels, k) node indices,
     stop_h (n_columns, n_prisms) m, st_row (n_strikers,), st_col (n_strikers,), par (6,),
     pairs (n_pairs, 8), bpar (6,), touched (3,), saved (2, n_nodes, 3), dissipation (2,),
     active (n_pairs + 1,), x0 (n_nodes, 3), node_mass, clamped, node_mult (n_nodes,),
     bar_a, bar_b, bar_mass (n_massive_bars,), cable_mult (n_cables,), rate (1,))

``par = (k_stop N/m, k_contact, contact exponent (1 linear, 1.5 Hertz), nodes per level of the
full network, striker mass kg, gravity m/s^2, steps per striker contact, effective mass kg of a
striker against its column's end level)``; ``pairs`` and ``bpar``: the bar pairs of
:mod:`solver.kernels.barcontact`; ``touched``: the contacts met by force evaluations, the
contact scan's slack m and whether forces must look for contacts; ``saved`` holds the state a
step started from (scratch of the integrators' contact steps); ``dissipation``: the power W the
cable damping takes out at the last force evaluation and the energy J it took out so far;
``active``: the pairs the force evaluations look at; ``x0`` to ``cable_mult``: the state
summary's arrays (:func:`solver.kernels.summary.step_energy`, with bar contact only) and
``rate`` the energy balance a whole step beside a near miss may spend, relative, per second.
Empty arrays switch a part off: with all of them empty (:data:`NO_EXTRAS`, what
:func:`solver.kernels.dynamics.pack` gives) the kernels of
:mod:`solver.kernels.dynamics` take exactly the code path they take without this module.

- **Cable damping**: a taut cable (``s > L``) carries ``T = k (s - L) + c ds/dt``, floored at 0 (a
  cable cannot push); a slack one carries nothing. The damping force only ever removes energy.
- **Striker**: a rigid body of mass ``m_s`` moving along the column axis, one per column, its
  contact face at height ``z_s`` (rows ``st_row`` of the state arrays, x and y unused). The overlap
  with the column's free end is ``d = z_end - z_s`` (``z_end`` the mean height of the end level);
  for ``d > 0`` the contact pushes the striker up and each end node down by ``F / k`` with
  ``F = k_c d`` (linear) or ``k_c d^1.5`` (Hertz), energy ``k_c d^2 / 2`` or ``2 k_c d^2.5 / 5``.
- **Prism stops**: for each prism a stop between its two levels: when the height ``h`` (mean z of
  the upper level minus that of the lower) falls below ``stop_h``, a linear penalty force
  ``k_stop (stop_h - h)`` pushes the two levels apart, shared equally by their nodes, energy
  ``k_stop (stop_h - h)^2 / 2``.

Forces that act on whole levels, equally per node, keep the 3-fold symmetry, so the reduced
``sym3d`` model runs them too (there a level is one node standing for ``k`` = 3: it gets the force
of one full node).
"""
import math

import numpy as np

from solver._jit import jit, jit_inline
from solver.kernels.rotation import add_pair_force, cable_chord, image_chord


def _empty(shape, dtype=np.float64):
    # writable like the arrays of an active scene: one compiled type for both (never written)
    return np.zeros(shape, dtype=dtype)


NO_EXTRAS = (_empty(0), _empty((0, 0, 1), np.int64), _empty((0, 0)), _empty(0, np.int64),
             _empty(0, np.int64), _empty(8), _empty((0, 8), np.int64), _empty(6),
             _empty(3), _empty((2, 0, 3)), _empty(2),
             np.full(1, -1, dtype=np.int64),
             # the energy of a state without contact (models.extras.energy_slots): x0, node
             # mass, clamped, node and cable multiplicity, massive bars, and the balance rate
             _empty((0, 3)), _empty(0), _empty(0, np.bool_), _empty(0), _empty(0, np.int64),
             _empty(0, np.int64), _empty(0), _empty(0), _empty(1))


def active(extras):
    """Whether an extras tuple switches anything on."""
    return bool(extras[0].shape[0] or extras[2].size or extras[3].shape[0]
                or extras[6].shape[0])


@jit
def cable_forces_damped(x, v, cable_a, cable_b, cable_rot, rest, EA, damp, f, power):
    """Add tension-only cable forces with viscous damping to ``f``: for ``s > L``,
    ``T = max(EA (s - L) / L + damp ds/dt, 0)``. ``cable_rot`` empty: plain cables; otherwise
    cables to the rotated image ``R^r x_b`` (the force on the image rotated back, as
    :func:`solver.kernels.rotation.cable_forces_rot`), each standing for the 3 of its orbit.
    ``power[0]``: the power W the damping takes out, ``sum (T - T_elastic) ds/dt`` (>= 0)."""
    mult = 3.0 if cable_rot.shape[0] > 0 else 1.0
    p = 0.0
    for c in range(cable_a.shape[0]):
        a, b, cr, sr, dx, dy, dz = cable_chord(x, cable_a, cable_b, cable_rot, c)
        s = math.sqrt(dx * dx + dy * dy + dz * dz)
        L = rest[c]
        if s > L:
            ux, uy, uz = image_chord(v, a, b, cr, sr)
            rate = (dx * ux + dy * uy + dz * uz) / s
            elastic = EA[c] / L * (s - L)
            T = max(elastic + damp[c] * rate, 0.0)
            p += (T - elastic) * rate
            if T > 0.0:
                add_pair_force(f, a, b, T / s, dx, dy, dz, cr, sr)
    power[0] = mult * p


@jit
def _level_z(x, levels, c, j):
    k = levels.shape[2]
    z = 0.0
    for i in range(k):
        z += x[levels[c, j, i], 2]
    return z / k


@jit_inline
def _stop_overlap(x, levels, stop_h, c, j):
    """Overlap m of stop ``j - 1`` of column ``c``: its height minus the level gap (> 0: shut)."""
    return stop_h[c, j - 1] - (_level_z(x, levels, c, j) - _level_z(x, levels, c, j - 1))


@jit
def contact_force(d, k, expo):
    """Contact force N of an overlap ``d`` > 0 m (linear ``k d`` or Hertz ``k d^1.5``)."""
    if expo == 1.0:
        return k * d
    return k * d * math.sqrt(d)


@jit
def contact_energy(d, k, expo):
    """Energy J stored at overlap ``d`` > 0 m: ``k d^2 / 2`` or ``2 k d^2.5 / 5``."""
    if expo == 1.0:
        return 0.5 * k * d * d
    return 0.4 * k * d * d * math.sqrt(d)


@jit
def axial_contacts(x, ex, f):
    """Add the forces of the prism stops and strikers of ``ex`` (the extras tuple) to ``f``."""
    levels, stop_h, st_row, st_col, par = ex[1], ex[2], ex[3], ex[4], ex[5]
    k = levels.shape[2]
    share = 1.0 / par[3]
    kl = par[0]
    for c in range(stop_h.shape[0]):
        for j in range(1, levels.shape[1]):
            d = _stop_overlap(x, levels, stop_h, c, j)
            if d > 0.0:
                F = kl * d * share
                for i in range(k):
                    f[levels[c, j, i], 2] += F
                    f[levels[c, j - 1, i], 2] -= F
    top = levels.shape[1] - 1
    for s in range(st_row.shape[0]):
        c = st_col[s]
        d = _level_z(x, levels, c, top) - x[st_row[s], 2]
        if d > 0.0:
            F = contact_force(d, par[1], par[2])
            f[st_row[s], 2] += F
            for i in range(k):
                f[levels[c, top, i], 2] -= F * share


@jit
def extra_energy(x, v, ex):
    """Energy J of the extras: striker kinetic and gravity energy, contact and stop energies."""
    levels, stop_h, st_row, st_col, par = ex[1], ex[2], ex[3], ex[4], ex[5]
    e = 0.0
    for c in range(stop_h.shape[0]):
        for j in range(1, levels.shape[1]):
            d = _stop_overlap(x, levels, stop_h, c, j)
            if d > 0.0:
                e += 0.5 * par[0] * d * d
    top = levels.shape[1] - 1
    for s in range(st_row.shape[0]):
        r = st_row[s]
        e += 0.5 * par[4] * v[r, 2] * v[r, 2] + par[4] * par[5] * x[r, 2]
        d = _level_z(x, levels, st_col[s], top) - x[r, 2]
        if d > 0.0:
            e += contact_energy(d, par[1], par[2])
    return e


@jit_inline
def gap_kink(g, gd, gdd, h, ignore):
    """Earliest time in ``(ignore, h)`` at which ``g + gd t + gdd t^2 / 2`` crosses 0; ``h`` if
    none: the quadratic Taylor model of a gap (a contact's overlap, a cable's ``s - L`` in
    :func:`solver.kernels.kinks.next_kink`), its roots taken in the stable form."""
    disc = gd * gd - 2.0 * gdd * g
    if disc < 0.0:
        return h
    q = -0.5 * (gd + math.copysign(math.sqrt(disc), gd))
    t_best = h
    for r in range(2):
        if r == 0:
            t = q / (0.5 * gdd) if gdd != 0.0 else -1.0
        else:
            t = g / q if q != 0.0 else -1.0
        if ignore < t < t_best:
            t_best = t
    return t_best


@jit_inline
def hertz_duration(m, k, u):
    """Duration s of a Hertz contact ``F = k d^1.5`` between a mass ``m`` kg and a wall met at
    the speed ``u`` m/s: ``2.94 d_max / u``, ``d_max = (5 m u^2 / (4 k))^0.4`` the largest
    overlap."""
    d_max = (1.25 * m * u * u / k) ** 0.4
    return 2.94 * d_max / u


@jit_inline
def _striker_gap(x, v, acc, levels, st_row, st_col, s):
    """Gap m of striker ``s`` to its column's end level (> 0: apart), its rate and its
    acceleration."""
    r = st_row[s]
    c = st_col[s]
    top = levels.shape[1] - 1
    return (x[r, 2] - _level_z(x, levels, c, top), v[r, 2] - _level_z(v, levels, c, top),
            acc[r, 2] - _level_z(acc, levels, c, top))


@jit
def striker_step(x, v, acc, ex, h):
    """``h``, or the step that resolves a striker contact: ``T / par[6]`` while a striker touches
    its column's end or could touch it within ``h``, ``T`` the duration of the contact between
    the striker and the end level as two masses (``par[7]`` the effective mass): ``pi sqrt(m /
    k)`` for the linear law, ``2.94 d_max / u`` for Hertz's (``u`` the approach speed with the
    energy the contact already stores). Without it a contact of a few milliseconds takes a
    handful of steps of the scene's ``dt`` and the energy balance fails at the first one."""
    levels, st_row, st_col, par = ex[1], ex[3], ex[4], ex[5]
    m, k = par[7], par[1]
    for s in range(st_row.shape[0]):
        g, gd, gdd = _striker_gap(x, v, acc, levels, st_row, st_col, s)
        if g > abs(gd) * h + 0.5 * abs(gdd) * h * h:
            continue                                       # cannot touch within h
        if par[2] == 1.0:
            T = math.pi * math.sqrt(m / k)
        else:
            d = max(-g, 0.0)
            T = hertz_duration(m, k, max(math.sqrt(gd * gd + 0.8 * k * d * d * math.sqrt(d)
                                                   / m), 1e-9))
        h = min(h, T / par[6])
    return h


@jit
def contact_kink(x, v, acc, ex, h, ignore):
    """Earliest time in ``(ignore, h)`` at which a stop or a striker contact is predicted to
    open or close (its force law has a kink at zero overlap); ``h`` if none."""
    levels, stop_h, st_row, st_col = ex[1], ex[2], ex[3], ex[4]
    for c in range(stop_h.shape[0]):
        for j in range(1, levels.shape[1]):
            g = _level_z(x, levels, c, j) - _level_z(x, levels, c, j - 1) - stop_h[c, j - 1]
            gd = _level_z(v, levels, c, j) - _level_z(v, levels, c, j - 1)
            gdd = _level_z(acc, levels, c, j) - _level_z(acc, levels, c, j - 1)
            h = gap_kink(g, gd, gdd, h, ignore)
    for s in range(st_row.shape[0]):
        g, gd, gdd = _striker_gap(x, v, acc, levels, st_row, st_col, s)
        h = gap_kink(g, gd, gdd, h, ignore)
    return h
