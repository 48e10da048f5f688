"""Step sizes around bar contact (:mod:`solver.kernels.barcontact`, docs/physics.md section 7.1):
the scans that say when a pair of bars or the bases of a prism could touch within a step, and
the test that a step tried whole near a closest approach surely passed clear.

:func:`contact_step` sizes the steps around a contact: a pair that could touch within the step is
approached in steps that close at most half of its gap (conservative advancement), and while a
pair touches steps are ``T / steps``, ``T`` the Hertz contact duration ``2.94 d_max / u`` of the
pair's approach speed ``u`` (with the energy it already stores) against the smallest node mass.
Far from contact nothing changes: the step is returned as given.

The scans keep what they know in the contact state (``ContactState.scan`` of
:mod:`solver.kernels.records`: ``MET``, ``SLACK``, ``LOOK``, ``MOTION``, then from ``HEAD``): the
motion
summed since the last full scan and each pair's gap at its last exact evaluation, so a pair is
evaluated again only when it could have closed its gap; the last ``3 n`` entries are the
positions an integrator call ended at (``barcontact.remember``).
"""
import math

from solver.compiled import jit, jit_inline
from solver.kernels.barcontact import (at_remembered, bar_energy_bounded, level_z, pair,
                                      point, prism_base_energy, rel_velocity)
from solver.kernels.records import HEAD, LOOK, MOTION, SLACK
from solver.kernels.contact import hertz_duration


@jit_inline
def _resolve(gap, V, A, u2, h, bc, scale):
    """The step for one contact: ``h`` (unchanged: it cannot touch within ``h``), else the
    conservative approach step or the contact step ``T / steps`` times ``scale`` (the refinement
    after a step that failed the energy balance), whichever is longer."""
    h_safe = 0.0
    if gap > 0.0:
        if 1.25 * (V * h + 0.5 * A * h * h) < gap:
            return h
        c = 0.4 * gap                   # 1.25 (V h + A h^2 / 2) = gap / 2
        h_safe = 2.0 * c / (V + math.sqrt(V * V + 2.0 * A * c)) if V + A > 0.0 else h
    return min(h, max(h_safe, hertz_duration(bc.m_min, bc.k, max(math.sqrt(u2), 1e-9))
                      / bc.steps * scale))


@jit_inline
def motion_bound(v, acc, h):
    """Bound m of any relative motion within a step of ``h`` from velocities ``v``, accelerations
    ``acc``: ``2 (V h + A h^2 / 2)`` with ``V``, ``A`` twice the largest node speed and
    acceleration (see :func:`contact_step`)."""
    V = 2.0 * _largest(v)
    A = 2.0 * _largest(acc)
    return 2.0 * (V * h + 0.5 * A * h * h)


@jit_inline
def _prism_slot(pairs, levels, c, j):
    """Where the contact state keeps the gap bound of prism ``j`` (its bases ``j - 1``, ``j``)
    of column ``c``: after the pairs'."""
    return HEAD + pairs.shape[0] + c * (levels.shape[1] - 1) + j - 1


@jit_inline
def motion_so_far(state):
    """The motion summed since the last :func:`rescan` (0 right after it: NaN there)."""
    return state[MOTION] if math.isfinite(state[MOTION]) else 0.0


@jit
def passed_clear(x0, v0, a0, x1, bc, levels, h, state, known):
    """Whether a step of ``h`` from ``x0`` (velocities ``v0``, accelerations ``a0``) to ``x1``
    surely met no contact (a contact shorter than the step may fall between its force
    evaluations): every pair's (and every prism's base) gap is positive at both ends, and either
    their sum exceeds what the pair could have closed and reopened within the step,
    ``2 (V h + A h^2 / 2)``, or, where the bars slide by less than their thickness within the
    step (``V h < D``), the finer near-miss bound holds (:func:`_kept_apart`, with ``A`` the
    larger of twice the accelerations at the start and twice the mean ones over the step; for two
    bases, whose gap is linear in the positions, ``min(g0, g1) > 2 A h^2 / 8``). Faster near
    misses keep the shorter steps: beside a contact that lasts less than a step (a column struck
    at 1 m/s) those steps are what holds the energy balance. A pair whose
    gap bound (``state``, :func:`contact_step`; ``known`` the motion summed at the step's start)
    exceeds the bound of any relative motion within the step is only
    checked at the end."""
    pairs = bc.pairs
    D = bc.diameter
    reach = motion_bound(v0, a0, h)
    for i in range(pairs.shape[0]):
        if state[HEAD + i] - known > reach:
            s, t, nx, ny, nz = pair(x1, pairs, i)
            if nx * nx + ny * ny + nz * nz <= D * D:
                return False
            continue
        s, t, nx, ny, nz = pair(x0, pairs, i)
        g0 = math.sqrt(nx * nx + ny * ny + nz * nz) - D
        s, t, nx, ny, nz = pair(x1, pairs, i)
        g1 = math.sqrt(nx * nx + ny * ny + nz * nz) - D
        p = pairs[i]
        V, A = _reach(v0, p), _reach(a0, p)
        if g0 <= 0.0 or g1 <= 0.0:
            return False
        if g0 + g1 <= 2.0 * (V * h + 0.5 * A * h * h) and not (V * h < D and _kept_apart(
                x0, x1, pairs, i, D, V, 2.0 * max(A, _mean_reach(x0, v0, x1, p, h)), h)):
            return False
    for c in range(levels.shape[0]):
        for j in range(1, levels.shape[1]):
            g1 = level_z(x1, levels, c, j) - level_z(x1, levels, c, j - 1) - D
            if state[_prism_slot(pairs, levels, c, j)] - known > reach:
                if g1 <= 0.0:
                    return False
                continue
            g0 = level_z(x0, levels, c, j) - level_z(x0, levels, c, j - 1) - D
            rate = abs(level_z(v0, levels, c, j) - level_z(v0, levels, c, j - 1))
            accel = abs(level_z(a0, levels, c, j) - level_z(a0, levels, c, j - 1))
            if g0 <= 0.0 or g1 <= 0.0:
                return False
            if (g0 + g1 <= 2.0 * (rate * h + 0.5 * accel * h * h)
                    and min(g0, g1) <= 2.0 * accel * h * h / 8.0):
                return False
    return True


@jit_inline
def _normal(x, pairs, i):
    """The unit vector from bar b's closest point to bar a's, pair ``i``."""
    s, t, nx, ny, nz = pair(x, pairs, i)
    r = math.sqrt(nx * nx + ny * ny + nz * nz)
    return nx / r, ny / r, nz / r


@jit_inline
def _separation(x, p, nx, ny, nz):
    """``min`` over the ends ``a_i`` of bar a and ``b_j`` of bar b of ``n . (a_i - b_j)``: a lower
    bound of the bars' distance for any unit ``n`` (``|a - b| >= n . (a - b)``, and the smallest
    value of a linear function on two segments is taken at their ends); the distance itself when
    ``n`` is the normal of closest points inside both bars. Also the largest ``|a_i - b_j|``."""
    low, far = math.inf, 0.0
    for i in (0, 2):
        ax, ay, az = point(x, p[i], p[i + 1])
        for j in (4, 6):
            bx, by, bz = point(x, p[j], p[j + 1])
            rx, ry, rz = ax - bx, ay - by, az - bz
            low = min(low, nx * rx + ny * ry + nz * rz)
            far = max(far, math.sqrt(rx * rx + ry * ry + rz * rz))
    return low, far


@jit
def _kept_apart(x0, x1, pairs, i, D, V, A, h):
    """Whether the bars of pair ``i``, at positive gaps at both ends of a step
    of ``h`` from ``x0`` to ``x1``, surely stayed more than ``D`` apart within it, given that no
    relative speed of their ends exceeds ``V`` at the start and no relative acceleration ``A``
    within the step: the test for a near miss, where the bars slide past each other.

    Any unit ``n(t)`` bounds the distance from below, ``dist >= f_ij = n . (a_i - b_j)`` for all
    ends (:func:`_separation`). Take ``n`` the normalised linear blend of the closest-point normals
    ``n0``, ``n1`` at the two ends: then ``f_ij(0)``, ``f_ij(h)`` are the distances (when the
    closest points lie inside the bars), and ``f'' = n'' r + 2 n' r' + n r''`` with
    ``|n'| <= d / (c h)``, ``|n''| <= 3 d^2 / (c h)^2`` (``d = |n1 - n0|``, ``c = cos`` of half
    their angle, the least length of the blend), ``|r| <= R0 + V h + A h^2 / 2``,
    ``|r'| <= V + A h``, ``|r''| <= A``. A function with ``f'' <= K`` on ``[0, h]`` stays above
    ``min(f(0), f(h)) - K h^2 / 8``. Where the crude bound ``g0 + g1 > 2 (V h + A h^2 / 2)`` of
    :func:`passed_clear` counts the whole sliding speed as approach, this one counts only the
    turning of the normal, tens of times less at a near miss of a twisting prism."""
    p = pairs[i]
    n0x, n0y, n0z = _normal(x0, pairs, i)
    n1x, n1y, n1z = _normal(x1, pairs, i)
    d = math.sqrt((n1x - n0x) ** 2 + (n1y - n0y) ** 2 + (n1z - n0z) ** 2)
    c2 = 1.0 - 0.25 * d * d
    if c2 < 0.25:                       # the normal turned by more than 120 degrees
        return False
    c = math.sqrt(c2)
    low0, far = _separation(x0, p, n0x, n0y, n0z)
    low1, _ = _separation(x1, p, n1x, n1y, n1z)
    K = (3.0 * d * d / (c2 * h * h) * (far + V * h + 0.5 * A * h * h)
         + 2.0 * d / (c * h) * (V + A * h) + A)
    return min(low0, low1) - K * h * h / 8.0 > D


@jit_inline
def _reach(u, p):
    """Largest relative speed (or acceleration) between an end of bar a and an end of bar b."""
    best = 0.0
    for i in (0, 2):
        ax, ay, az = point(u, p[i], p[i + 1])
        for j in (4, 6):
            bx, by, bz = point(u, p[j], p[j + 1])
            r = (ax - bx) ** 2 + (ay - by) ** 2 + (az - bz) ** 2
            if r > best:
                best = r
    return math.sqrt(best)


@jit_inline
def _mean_reach(x0, v0, x1, p, h):
    """Largest relative mean acceleration over a step of ``h`` from ``x0`` (velocities ``v0``) to
    ``x1`` between an end of bar a and an end of bar b: ``2 (x1 - x0 - v0 h) / h^2`` of the ends,
    which sees a change of the forces within the step (a cable going taut) that the accelerations
    at its start do not."""
    best = 0.0
    c = 2.0 / (h * h)
    for i in (0, 2):
        a1x, a1y, a1z = point(x1, p[i], p[i + 1])
        a0x, a0y, a0z = point(x0, p[i], p[i + 1])
        avx, avy, avz = point(v0, p[i], p[i + 1])
        for j in (4, 6):
            b1x, b1y, b1z = point(x1, p[j], p[j + 1])
            b0x, b0y, b0z = point(x0, p[j], p[j + 1])
            bvx, bvy, bvz = point(v0, p[j], p[j + 1])
            rx = (a1x - a0x - avx * h) - (b1x - b0x - bvx * h)
            ry = (a1y - a0y - avy * h) - (b1y - b0y - bvy * h)
            rz = (a1z - a0z - avz * h) - (b1z - b0z - bvz * h)
            best = max(best, c * math.sqrt(rx * rx + ry * ry + rz * rz))
    return best


@jit_inline
def _largest(u):
    best = 0.0
    for p in range(u.shape[0]):
        r = u[p, 0] * u[p, 0] + u[p, 1] * u[p, 1] + u[p, 2] * u[p, 2]
        if r > best:
            best = r
    return math.sqrt(best)


@jit
def contact_step(x, v, acc, bc, levels, h, state, active, scale):
    """:func:`scan_step` where a contact could start within ``h`` (its contact steps
    ``T / steps`` times ``scale``), else ``h``, cheaply: the
    smallest gap of the last scan, less what every node could have moved since (twice the
    largest node speed and acceleration bound any relative motion; a factor 2 over the Taylor
    terms covers how fast the accelerations change within a step), is kept in ``state[SLACK]``
    (negative: scan now; an integrator sets it so when it starts from positions it did not
    make, :func:`resume`). ``state[LOOK]`` 0 tells the force evaluations of the step that no
    contact can act (they skip the pairs), 1 that they must look at the listed pairs and the
    bases, 2 at the listed pairs only. ``state[MOTION]`` sums those bounds of the motion over the
    steps since the last :func:`rescan`, and ``state[HEAD + i]`` holds pair ``i``'s gap at its
    last exact evaluation plus the sum then (then each prism's, for its bases): a scan evaluates
    again only the pairs whose gap, less the motion since, could close within the step. The
    last ``3 n`` entries are the positions of :func:`remember`."""
    reach = motion_bound(v, acc, h)
    if state[SLACK] > reach:
        state[SLACK] -= reach
        state[MOTION] += reach
        state[LOOK] = 0.0          # no contact force within this step: not evaluated
        return h
    h_new, g_min, bases = scan_step(x, v, acc, bc, levels, h, active, state, reach, scale)
    reach = motion_bound(v, acc, h_new)
    state[SLACK] = g_min - reach
    state[MOTION] += reach
    state[LOOK] = 0.0 if state[SLACK] > 0.0 else (1.0 if bases else 2.0)
    return h_new


@jit
def rescan(state, active):
    """Forget what the scans know (the state was not made by the steps they bounded): the next
    :func:`contact_step` evaluates every pair, the next force evaluation looks at every pair."""
    state[SLACK] = -1.0
    state[LOOK] = 1.0
    state[MOTION] = math.nan
    active[0] = -1


@jit
def resume(x, state, active):
    """At the start of an integrator call: keep what the scans know when the positions ``x`` are
    those the last call ended at (:func:`remember`; a command may have changed the velocities,
    which the bounds allow for: they bound the motion of positions, step by step), else
    :func:`rescan`. Until :func:`remember` at its end, a call that stops early leaves nothing to
    resume from."""
    if not at_remembered(x, state):
        rescan(state, active)
    state[state.shape[0] - 3 * x.shape[0]] = math.nan


@jit
def add_motion(state, v, acc, h):
    """Count a step of ``h`` from velocities ``v``, accelerations ``acc`` in ``state[MOTION]`` (the
    bound :func:`contact_step` adds) on top of what it counted already, and have the next step
    scan: for a step longer than the one :func:`contact_step` sized."""
    state[SLACK] = -1.0
    state[MOTION] += motion_bound(v, acc, h)


@jit
def gate(x, v, acc, bc, levels, h, state, active):
    """For a method that does not size its steps around contacts (RATTLE): :func:`contact_step`
    for a step of ``h`` from ``x, v`` (accelerations ``acc``) that is taken whole. The pairs that
    could touch within it are listed in ``active`` for the force evaluations; where a contact
    could start, they look (``state[LOOK]`` 1) and the next call scans again."""
    if contact_step(x, v, acc, bc, levels, h, state, active, 1.0) < h:
        add_motion(state, v, acc, h)
        state[LOOK] = 1.0


@jit
def scan_step(x, v, acc, bc, levels, h, active, state, reach, scale):
    """The step to take from the state ``x, v`` (accelerations ``acc``) instead of ``h``: ``h``
    when no pair of bars and no two bases can touch within it, otherwise shortened (see the
    module's text).

    The distance of two segments changes by at most the largest change of ``a_i - b_j`` over
    their ends (every point of a segment is a convex combination of its ends), so a pair at gap
    ``g`` cannot touch within ``h`` while ``1.25 (V h + A h^2 / 2) < g`` (``V``, ``A`` the largest
    relative end speed and acceleration; 1.25 covers the Taylor remainder). A pair that could
    is approached in steps that close at most half its gap, and never shorter than the contact
    step ``T / steps`` times ``scale``: a step that any pair in contact bounds is at most that,
    whatever else shortened it. The pairs that could touch within ``h`` (gap below twice the Taylor
    reach) are listed in ``active`` for the force evaluations. A pair whose lower bound of the gap
    (``state``, see :func:`contact_step`) exceeds ``reach``, the bound of any relative motion
    within ``h``, is left as it is: it neither shortens the step nor gets listed, as its exact
    gap would not either; the same for the two bases of each prism. Returns (the step, the smallest
    gap m, or its lower bound, how many prisms' bases could touch within ``h``)."""
    pairs = bc.pairs
    D, k, m = bc.diameter, bc.k, bc.m_min
    h_new = h
    g_min = math.inf
    count = 0
    # after rescan (the motion NaN): every pair evaluated, and the sum restarts from 0
    fresh = not math.isfinite(state[MOTION])
    known = motion_so_far(state)
    state[MOTION] = known
    for i in range(pairs.shape[0]):
        bound = state[HEAD + i] - known
        if not fresh and bound > reach:
            g_min = min(g_min, bound)
            continue
        p = pairs[i]
        s, t, nx, ny, nz = pair(x, pairs, i)
        dist = math.sqrt(nx * nx + ny * ny + nz * nz)
        gap = dist - D
        state[HEAD + i] = gap + known
        g_min = min(g_min, gap)
        A = _reach(acc, p)
        if gap > 0.0:
            u2 = _reach(v, p) ** 2
            if gap <= 2.0 * (math.sqrt(u2) * h + 0.5 * A * h * h):
                count += 1
                active[count] = i
        else:
            count += 1
            active[count] = i
            d = -gap
            vx, vy, vz = rel_velocity(v, p, s, t)
            rate = (nx * vx + ny * vy + nz * vz) / max(dist, 1e-300)
            u2 = rate * rate + 0.8 * k * d * d * math.sqrt(d) / m
        h_new = _resolve(gap, math.sqrt(u2), A, u2, h_new, bc, scale)
    active[0] = count
    bases = 0                           # prisms whose bases could touch within h
    for c in range(levels.shape[0]):
        for j in range(1, levels.shape[1]):
            slot = _prism_slot(pairs, levels, c, j)
            bound = state[slot] - known
            if not fresh and bound > reach:
                g_min = min(g_min, bound)
                continue
            gap = level_z(x, levels, c, j) - level_z(x, levels, c, j - 1) - D
            state[slot] = gap + known
            g_min = min(g_min, gap)
            rate = level_z(v, levels, c, j) - level_z(v, levels, c, j - 1)
            accel = level_z(acc, levels, c, j) - level_z(acc, levels, c, j - 1)
            u2 = rate * rate
            if gap <= 0.0:
                u2 += 0.8 * k * (-gap) ** 2.5 / m
            if gap <= 2.0 * (abs(rate) * h + 0.5 * abs(accel) * h * h):
                bases += 1
            h_new = _resolve(gap, abs(rate), abs(accel), u2, h_new, bc, scale)
    return h_new, g_min, bases


@jit
def bounded_contact_energy(x, bc, levels, per_level, state):
    """Energy J stored in touching bars and bases at positions ``x`` that the scans' bounds cover
    (the start or the end of a step :func:`contact_step` sized): a pair or a prism whose gap
    bound less the motion summed so far (``state``) is positive stores none and is skipped;
    after a :func:`rescan` every pair and prism is evaluated. Times the multiplicities, as
    :func:`~solver.kernels.barcontact.bar_energy` and ``base_energy``."""
    pairs = bc.pairs
    known = state[MOTION]
    bounded = math.isfinite(known)
    eb = 0.0
    for c in range(levels.shape[0]):
        for j in range(1, levels.shape[1]):
            if not (bounded and state[_prism_slot(pairs, levels, c, j)] - known > 0.0):
                eb += prism_base_energy(x, levels, bc, c, j)
    return bar_energy_bounded(x, bc, state, bounded) + per_level * eb
