"""Unilateral contacts and cable damping: the striker, the prism stops, viscous cables.

Each is an effect of the model record (:mod:`solver.kernels.records`): ``m.damping`` (per-cable
coefficients), ``m.stops`` (each prism's stop height and the penalty stiffness), ``m.strikers``
(their rows of the state arrays, their columns and contact law, mass, gravity), all on the levels
``m.levels`` (node indices of each level of the model's state; one representative per level in
``sym3d``, standing for ``m.per_level`` nodes of the full network). Empty arrays switch an effect
off, and :func:`solver.kernels.dynamics.accelerations` then takes exactly the path it takes
without this module.

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

from solver.compiled import jit, jit_inline
from solver.kernels.records import POWER
from solver.kernels.rotation import add_pair_force, cable_chord, image_chord



@jit
def cable_forces_damped(x, v, cable_a, cable_b, cable_rot, rest, EA, damp, f, ledger):
    """Add tension-only cable forces with viscous damping to ``f``: for ``s > L``,
    ``T = max(EA (s - L) / L + damp ds/dt, 0)``. ``cable_rot`` empty: plain cables; otherwise
    cables to the rotated image ``R^r x_b`` (the force on the image rotated back, as
    :func:`solver.kernels.rotation.cable_forces_rot`), each standing for the 3 of its orbit.
    ``ledger[POWER]``: the power W the damping takes out, ``sum (T - T_elastic) ds/dt``
    (>= 0)."""
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
    ledger[POWER] = mult * p


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
def axial_contacts(x, m, f):
    """Add the forces of the prism stops and strikers of the model ``m`` to ``f``."""
    levels, stop_h, st = m.levels, m.stops.height, m.strikers
    st_row, st_col = st.row, st.col
    k = levels.shape[2]
    share = 1.0 / m.per_level
    kl = m.stops.k
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
            F = contact_force(d, st.k, st.expo)
            f[st_row[s], 2] += F
            for i in range(k):
                f[levels[c, top, i], 2] -= F * share


@jit
def extra_energy(x, v, m):
    """Energy J of the stops and strikers of the model ``m``: striker kinetic and gravity energy,
    contact and stop energies."""
    levels, stop_h, st = m.levels, m.stops.height, m.strikers
    st_row, st_col = st.row, st.col
    e = 0.0
    for c in range(stop_h.shape[0]):
        for j in range(1, levels.shape[1]):
            d = _stop_overlap(x, levels, stop_h, c, j)
            if d > 0.0:
                e += 0.5 * m.stops.k * d * d
    top = levels.shape[1] - 1
    for s in range(st_row.shape[0]):
        r = st_row[s]
        e += 0.5 * st.mass * v[r, 2] * v[r, 2] + st.mass * st.gravity * x[r, 2]
        d = _level_z(x, levels, st_col[s], top) - x[r, 2]
        if d > 0.0:
            e += contact_energy(d, st.k, st.expo)
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
def striker_step(x, v, acc, m, h):
    """``h``, or the step that resolves a striker contact of the model ``m``: ``T /
    strikers.steps`` while a striker touches its column's end or could touch it within ``h``,
    ``T`` the duration of the contact between the striker and the end level as two masses
    (``strikers.m_eff`` the effective mass): ``pi sqrt(m / k)`` for the linear law, ``2.94 d_max /
    u`` for Hertz's (``u`` the approach speed with the energy the contact already stores).
    Without it a contact of a few milliseconds takes a handful of steps of the scene's ``dt``
    and the energy balance fails at the first one."""
    levels, st = m.levels, m.strikers
    st_row, st_col = st.row, st.col
    mass, k = st.m_eff, st.k
    for s in range(st_row.shape[0]):
        g, gd, gdd = _striker_gap(x, v, acc, levels, st_row, st_col, s)
        if g > abs(gd) * h + 0.5 * abs(gdd) * h * h:
            continue                                       # cannot touch within h
        if st.expo == 1.0:
            T = math.pi * math.sqrt(mass / k)
        else:
            d = max(-g, 0.0)
            T = hertz_duration(mass, k, max(math.sqrt(gd * gd + 0.8 * k * d * d * math.sqrt(d)
                                                      / mass), 1e-9))
        h = min(h, T / st.steps)
    return h


@jit
def contact_kink(x, v, acc, m, h, ignore):
    """Earliest time in ``(ignore, h)`` at which a stop or a striker contact of the model ``m``
    is predicted to open or close (its force law has a kink at zero overlap); ``h`` if none."""
    levels, stop_h, st_row, st_col = m.levels, m.stops.height, m.strikers.row, m.strikers.col
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
