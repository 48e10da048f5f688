"""The 1D lumped-mass chain ``chain1d`` with the quasi-static prism force law F(h) (physics.md
section 6).

State: axial displacements ``u_j`` (n_levels,) m and velocities ``w_j`` m/s of the base levels; level
mass ``M_j`` = the sum of its node masses; prism heights ``h_i = h0 + u_{i+1} - u_i``;
``M_j u_j'' = F_{j-1}(h_{j-1}) - F_j(h_j)`` (+ external axial force), ``F = -dE/dh`` (> 0 pushes the
two levels apart), ``E(h)`` the prism energy at height h minimised over everything the chain does not
carry (twist, base radius). The twist has no inertia here: that is the model's approximation.

Force laws (:class:`PrismLaw`):

- rigid bases (rigid edges): closed form, base radius r fixed, twist from the bar length,
  ``cos phi = 1 - (b^2 - h^2) / (2 r^2)``, ``F = -3 k_s (s - L_s)_+ ds/dh``. Singular (infinite,
  integrably: ``F ~ 1 / sqrt(h - h_lock)``) at the LOCK ``h_lock = sqrt(b^2 - 4 r^2)`` where the twist
  reaches 180 deg. What the model does there: the prism cannot get shorter (``h >= h_lock`` is a hard
  contact of the two levels); a prism that reaches it bounces: the relative axial velocity of its two
  levels is reversed by an elastic impulse (momentum and energy kept).
  Near the lock, sub-steps shrink so that no prism closes more than half its remaining gap per
  sub-step; within ``1e-9 h0`` of the lock the contact impulse acts, and the force is evaluated at
  ``h >= h_lock + 1e-9 h0`` (finite, changes the energy by O(sqrt(1e-9)) of the lock energy). The 3D model instead folds through 180 deg of twist smoothly.
- flexible bases (and rigid bases as stiff cables): ``E(h) = min over (phi, r)`` of the cross-cable
  energy plus the base-cable energy the prism carries (an interior base cable shared by two prisms
  counts half for each), with the bar length fixed. Precomputed once per model on a grid of h
  (golden-section search in phi, vectorised over the grid), F by the envelope theorem
  (:func:`envelope_force`) and interpolated by a cubic spline; E is the exact antiderivative of that
  spline, so forces and energy agree. Leaving the table's h range stops the run with a clear error.

Integration: velocity Verlet with ``n_sub`` sub-steps per step (symplectic; cheap, 1D).
Impact: the end level gets ``w = -v0`` (the twist has no inertia, so the impulse and energy modes of
3D impacts coincide here).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from . import dynamics as dyn
from ._jit import jit

OUT_OF_TABLE = 20
STATUS_TEXT = {OUT_OF_TABLE: ('a prism height left the range of the force-law table (crushed flat or '
                              'overstretched: the quasi-static law has no more resistance)'),
               dyn.NONFINITE: 'non-finite state'}
SUBSTEP = 2e-6          # s, largest Verlet sub-step
LOCK_ETA = 0.05         # near the rigid-base lock: largest relative change of the gap per sub-step
GOLD = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass
class PrismLaw:
    """One prism's quasi-static law. ``kind`` 0 = rigid closed form with ``rigid`` = (r, b, L_s,
    k_s, n_cross, h_lock); 1 = table: grid ``lo``, ``dh``, ``fcoef`` (n - 1, 4) cubic pieces of F (N),
    ``ecoef`` (n - 1, 5) quartic pieces of E (J), ``phi``/``radius`` (n,) at the grid nodes."""
    kind: int
    rigid: np.ndarray
    lo: float = 0.0
    dh: float = 1.0
    fcoef: np.ndarray = None
    ecoef: np.ndarray = None
    phi: np.ndarray = None
    radius: np.ndarray = None


def cross_length(h, r, phi):
    """Cross-cable length m at height h, radius r, twist phi (rad)."""
    return np.sqrt(2.0 * r * r * (1.0 - np.cos(phi - 2.0 * math.pi / 3.0)) + h * h)


def twist(h, r, b):
    """Twist (rad, in [0, pi]) that keeps the bar length b at height h and radius r."""
    return np.arccos(np.clip(1.0 - (b * b - h * h) / (2.0 * r * r), -1.0, 1.0))


def prism_energy(h, r, phi, cross, bases):
    """Energy J of one prism: cross cables ``cross`` (k, L) pairs at length
    :func:`cross_length`, base cables ``bases`` (weight, k, L) at side ``sqrt(3) r``."""
    s = cross_length(h, r, phi)
    side = math.sqrt(3.0) * r
    e = 0.0
    for k, L in cross:
        e = e + 0.5 * k * np.maximum(s - L, 0.0) ** 2
    for wgt, k, L in bases:
        e = e + wgt * 0.5 * k * np.maximum(side - L, 0.0) ** 2
    return e


def rigid_force(h, r, b, L_s, k_s, n_cross=3):
    """Closed-form F(h) N of a rigid-base prism (physics.md section 6); inf at and below the lock."""
    h = np.asarray(h, dtype=np.float64)
    phi = twist(h, r, b)
    s = np.sqrt(b * b + 2.0 * math.sqrt(3.0) * r * r * np.cos(phi + math.pi / 6.0))
    with np.errstate(divide='ignore', invalid='ignore'):
        ds = math.sqrt(3.0) * h * np.sin(phi + math.pi / 6.0) / (s * np.sin(phi))
        f = -n_cross * k_s * np.maximum(s - L_s, 0.0) * ds
    return np.where(h * h <= b * b - 4.0 * r * r, np.inf, f)


def minimise_energy(h, b, cross, bases, iters=90):
    """``(E*, phi*, r*)`` arrays: the prism energy at heights ``h`` (array, m) minimised over the twist
    phi in [pi/2, pi] (the base radius follows from the bar length b), by vectorised golden section."""
    h = np.asarray(h, dtype=np.float64)
    d2 = b * b - h * h

    def energy(phi):
        r = np.sqrt(d2 / (2.0 * (1.0 - np.cos(phi))))
        return prism_energy(h, r, phi, cross, bases), r

    lo = np.full(h.shape, math.pi / 2.0)
    hi = np.full(h.shape, math.pi)
    x1 = hi - GOLD * (hi - lo)
    x2 = lo + GOLD * (hi - lo)
    f1, f2 = energy(x1)[0], energy(x2)[0]
    for _ in range(iters):
        left = f1 < f2
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        x2n = np.where(left, x1, lo + GOLD * (hi - lo))
        x1n = np.where(left, hi - GOLD * (hi - lo), x2)
        x1, x2 = x1n, x2n
        fa = energy(x1)[0]
        fb = energy(x2)[0]
        f1, f2 = fa, fb
    phi = 0.5 * (lo + hi)
    e, r = energy(phi)
    return e, phi, r


def envelope_force(h, r, phi, cross, bases):
    """``F = -dE/dh`` N at the minimiser (envelope theorem). Where the minimum is interior in the
    radius (twist below 180 deg) the partial derivative is taken at fixed radius (the twist
    follows the bar length): it is insensitive to the minimiser's error in phi. At 180 deg (cross
    cables slack, the radius at the end of its range) it is taken at fixed twist, the radius
    following ``r^2 = (b^2 - h^2) / (2 (1 - cos phi))``: the minimum in phi is interior there."""
    s = cross_length(h, r, phi)
    folded = phi > math.pi - 1e-7
    with np.errstate(divide='ignore', invalid='ignore'):
        ds_r = h * (1.0 - np.sin(phi - 2.0 * math.pi / 3.0) / np.sin(phi)) / s   # fixed r
    dr = np.where(folded, -h / (2.0 * (1.0 - np.cos(phi)) * r), 0.0)         # fixed phi
    ds_phi = (2.0 * r * (1.0 - np.cos(phi - 2.0 * math.pi / 3.0)) * dr + h) / s
    ds = np.where(folded, ds_phi, ds_r)
    de = 0.0
    for k, L in cross:
        de = de + k * np.maximum(s - L, 0.0) * ds
    side = math.sqrt(3.0) * r
    for wgt, k, L in bases:
        de = de + wgt * k * np.maximum(side - L, 0.0) * math.sqrt(3.0) * dr
    return -de


def table_law(h0, b, cross, bases, lo_frac=0.02, hi_frac=1.5, n=2001):
    """A tabulated :class:`PrismLaw` over ``h in [lo_frac h0, min(hi_frac h0, 0.999 b)]``."""
    hi = min(hi_frac * h0, 0.999 * b)
    grid = np.linspace(lo_frac * h0, hi, n)
    _, phi, r = minimise_energy(grid, b, cross, bases)
    F = envelope_force(grid, r, phi, cross, bases)
    spl = CubicSpline(grid, F)
    anti = spl.antiderivative()          # E(h) = E(grid[0]) - int F
    e0 = float(minimise_energy(np.array([grid[0]]), b, cross, bases)[0][0])
    ecoef = -anti.c.T.copy()
    ecoef[:, -1] += e0
    return PrismLaw(kind=1, rigid=np.zeros(6), lo=float(grid[0]), dh=float(grid[1] - grid[0]),
                    fcoef=np.ascontiguousarray(spl.c.T), ecoef=np.ascontiguousarray(ecoef),
                    phi=phi, radius=r)


@jit
def _piece(h, lo, dh, coef):
    """Evaluate piecewise polynomial rows ``coef`` (n - 1, d) on the uniform grid at h; NaN outside."""
    x = (h - lo) / dh
    n = coef.shape[0]
    if not (x >= 0.0 and x <= n):
        return math.nan
    i = min(int(x), n - 1)
    t = h - (lo + i * dh)
    y = 0.0
    for j in range(coef.shape[1]):
        y = y * t + coef[i, j]
    return y


@jit
def _force(h, h0, kind, rigid, lo, dh, fcoef):
    if kind == 1:
        return _piece(h, lo, dh, fcoef)
    r, b, L_s, k_s, n_cross, h_lock = rigid[0], rigid[1], rigid[2], rigid[3], rigid[4], rigid[5]
    h = max(h, h_lock + 1e-9 * h0)
    c = min(max(1.0 - (b * b - h * h) / (2.0 * r * r), -1.0), 1.0)
    phi = math.acos(c)
    s = math.sqrt(b * b + 2.0 * math.sqrt(3.0) * r * r * math.cos(phi + math.pi / 6.0))
    if s <= L_s:
        return 0.0
    ds = math.sqrt(3.0) * h * math.sin(phi + math.pi / 6.0) / (s * math.sin(phi))
    return -n_cross * k_s * (s - L_s) * ds


@jit
def _accel(u, h0, inv_m, f_ext, kind, rigid, lo, dh, fcoef, out):
    n = u.shape[0]
    for j in range(n):
        out[j] = f_ext[j]
    for i in range(n - 1):
        F = _force(h0 + u[i + 1] - u[i], h0, kind, rigid, lo, dh, fcoef)
        if not math.isfinite(F):
            return OUT_OF_TABLE
        out[i + 1] += F
        out[i] -= F
    for j in range(n):
        out[j] *= inv_m[j]
    return dyn.OK


@jit
def _contacts(u, w, h0, inv_m, h_lock, g_min):
    """Hard contact at the lock: a prism closer than ``g_min`` to it that is still closing gets its
    relative axial velocity reversed by an elastic impulse (momentum and energy kept)."""
    for i in range(u.shape[0] - 1):
        gap = h0 + u[i + 1] - u[i] - h_lock
        im = inv_m[i] + inv_m[i + 1]
        vr = w[i + 1] - w[i]
        if gap < g_min and vr < 0.0 and im > 0.0:
            j = -2.0 * vr / im
            w[i + 1] += j * inv_m[i + 1]
            w[i] -= j * inv_m[i]


@jit
def _lock_step(u, w, acc, h0, h_lock, g_min, h_max, eta):
    """Largest sub-step (<= h_max) over which no prism's gap to the lock changes by more than
    ``eta`` of itself (from the relative velocity and acceleration of its levels): the force
    ``~ 1 / sqrt(gap)`` is then resolved, and a prism that really reaches the lock meets it within
    ``g_min`` in a few hundred sub-steps (the gap shrinks geometrically)."""
    h = h_max
    for i in range(u.shape[0] - 1):
        gap = max(h0 + u[i + 1] - u[i] - h_lock, g_min)
        vc = abs(w[i] - w[i + 1])
        ac = abs(acc[i] - acc[i + 1])
        # vc h + ac h^2 / 2 <= eta gap
        if ac > 0.0:
            lim = (-vc + math.sqrt(vc * vc + 2.0 * ac * eta * gap)) / ac
        elif vc > 0.0:
            lim = eta * gap / vc
        else:
            continue
        h = min(h, lim)
    return h


@jit
def _chain_run(u, w, dt, n_steps, n_sub, h0, inv_m, f_ext, kind, rigid, lo, dh, fcoef, acc):
    """``n_steps`` steps of ``dt`` s, each of ``n_sub`` velocity-Verlet sub-steps (rigid bases:
    shortened near the lock, see :func:`_lock_step`, and :func:`_contacts` there). Returns
    (steps, status)."""
    h_max = dt / n_sub
    h_lock = rigid[5]
    g_min = 1e-9 * h0
    status = _accel(u, h0, inv_m, f_ext, kind, rigid, lo, dh, fcoef, acc)
    if status != dyn.OK:
        return 0, status
    n = u.shape[0]
    for step in range(n_steps):
        t = 0.0
        while dt - t > 1e-12 * dt:
            h = min(h_max, dt - t)
            if kind == 0:
                _contacts(u, w, h0, inv_m, h_lock, g_min)
                h = max(_lock_step(u, w, acc, h0, h_lock, g_min, h, LOCK_ETA), 1e-14 * dt)
            for j in range(n):
                w[j] += 0.5 * h * acc[j]
                u[j] += h * w[j]
            status = _accel(u, h0, inv_m, f_ext, kind, rigid, lo, dh, fcoef, acc)
            if status != dyn.OK:
                return step, status
            for j in range(n):
                w[j] += 0.5 * h * acc[j]
            t += h
        if not (dyn.all_finite(u.reshape(-1, 1)) and dyn.all_finite(w.reshape(-1, 1))):
            return step, dyn.NONFINITE
    return n_steps, dyn.OK


def _poly_eval(h, lo, dh, coef):
    """NumPy twin of :func:`_piece` for arrays of h."""
    h = np.asarray(h, dtype=np.float64)
    n = coef.shape[0]
    i = np.clip(((h - lo) / dh).astype(np.int64), 0, n - 1)
    t = h - (lo + i * dh)
    y = np.zeros_like(h)
    for j in range(coef.shape[1]):
        y = y * t + coef[i, j]
    return y


class Chain1D:
    """The 1D chain as a model of one column (see the module doc). State ``u``, ``w`` (n_levels,)."""
    name = 'chain1d'

    def __init__(self, network, f_ext=None):
        meta = network.meta
        if meta.get('builder') != 'column' or network.n_columns != 1:
            raise ValueError('model chain1d: needs a single column built by the column builder')
        self.network = network
        lev = np.asarray(network.levels[0])
        self.levels = lev
        clamped = np.asarray(network.clamped)[lev]
        if np.any(clamped.any(axis=1) != clamped.all(axis=1)):
            raise ValueError('model chain1d: a level is only partly clamped')
        self.level_mass = np.asarray(network.node_mass)[lev].sum(axis=1)
        self.inv_m = np.where(clamped.all(axis=1), 0.0, 1.0 / self.level_mass)
        f = np.zeros((network.n_nodes, 3)) if f_ext is None else np.asarray(f_ext, float)
        self.f_ext = f[lev, 2].sum(axis=1) * (self.inv_m > 0)
        self.h0, self.r0, self.b = float(network.h0), float(meta['radius']), \
            float(meta['bar_length'])
        self.sign = 1.0 if meta.get('twist', 1.0) >= 0 else -1.0
        n_pr = network.n_prisms
        mid = n_pr // 2
        self.cross, self.bases = self._prism_cables(mid)
        self.rigid_bases = network.n_edges > 0
        if self.rigid_bases:
            k_s, L_s = self.cross[0]
            h_lock = math.sqrt(max(self.b ** 2 - 4.0 * self.r0 ** 2, 0.0))
            self.law = PrismLaw(kind=0, rigid=np.array([self.r0, self.b, L_s, k_s,
                                                        float(len(self.cross)), h_lock]))
            self.h_lock = h_lock
            self.cross_length0 = float(cross_length(self.h0, self.r0, abs(meta['twist'])))
        else:
            self.law = table_law(self.h0, self.b, self.cross, self.bases)
            self.h_lock = None
        self.u = np.zeros(len(lev))
        self.w = np.zeros(len(lev))
        self.x, self.v = self.u, self.w          # the state, as Simulation keeps and restores it
        self._acc = np.zeros(len(lev))
        self._rest = np.array(network.cable_rest_length)
        self._EA = np.array(network.cable_EA)
        self.act = (self._rest.copy(), self._EA.copy(), self.f_ext)
        c = network.x0[lev]
        self._center = c[:, :, :2].mean(axis=1)
        self._z0 = c[:, :, 2].mean(axis=1)
        d = c[0, 0, :2] - self._center[0]
        self._theta0 = math.atan2(d[1], d[0])

    def _prism_cables(self, i):
        """Cross cables (k, L) of prism i, and the base cables (weight, k, L) it carries (half of an
        interior base cable, all of an end-level one)."""
        net = self.network
        lev = self.levels
        kinds = np.array(net.cable_kind)
        a, b = np.asarray(net.cable_a), np.asarray(net.cable_b)
        k = np.asarray(net.cable_EA) / np.asarray(net.cable_rest_length)
        L = np.asarray(net.cable_rest_length)
        lo, hi = set(lev[i]), set(lev[i + 1])
        cross, bases = [], []
        for c in range(net.n_cables):
            ends = {int(a[c]), int(b[c])}
            if kinds[c] == 'cross' and len(ends & lo) == 1 and len(ends & hi) == 1:
                cross.append((float(k[c]), float(L[c])))
            elif kinds[c] == 'base':
                for j, nodes in ((i, lo), (i + 1, hi)):
                    if ends <= nodes:
                        wgt = 0.5 if 0 < j < len(lev) - 1 else 1.0
                        bases.append((wgt, float(k[c]), float(L[c])))
        if not cross:
            raise ValueError('model chain1d: prism without cross cables')
        return cross, bases

    # -- the law --------------------------------------------------------------------------------
    def force(self, h):
        """F(h) N (array in, array out); ``inf`` at or below the rigid-base lock."""
        law = self.law
        if law.kind == 0:
            k_s, L_s = self.cross[0]
            return rigid_force(h, self.r0, self.b, L_s, k_s, len(self.cross))
        return _poly_eval(h, law.lo, law.dh, law.fcoef)

    def prism_energy(self, h):
        """E(h) J of one prism (minimised over twist and radius for flexible bases)."""
        h = np.asarray(h, dtype=np.float64)
        if self.law.kind == 0:
            phi = twist(h, self.r0, self.b)
            return prism_energy(h, self.r0, phi, self.cross, ())
        return _poly_eval(h, self.law.lo, self.law.dh, self.law.ecoef)

    def shape(self, h):
        """(twist rad, base radius m) of prisms of height h (quasi-static)."""
        h = np.asarray(h, dtype=np.float64)
        if self.law.kind == 0:
            return twist(h, self.r0, self.b), np.full(h.shape, self.r0)
        grid = self.law.lo + self.law.dh * np.arange(len(self.law.phi))
        return np.interp(h, grid, self.law.phi), np.interp(h, grid, self.law.radius)

    # -- the model interface -------------------------------------------------------------------
    def heights(self):
        return self.h0 + np.diff(self.u)

    def advance(self, dt, n_steps):
        """``n_steps`` steps of ``dt`` s in place; returns (steps, status)."""
        n_sub = max(1, int(math.ceil(dt / SUBSTEP - 1e-9)))
        law = self.law
        fcoef = law.fcoef if law.kind == 1 else np.zeros((1, 4))
        steps, status = _chain_run(self.u, self.w, float(dt), int(n_steps), n_sub, self.h0,
                                   self.inv_m, self.f_ext, law.kind, law.rigid, law.lo, law.dh,
                                   fcoef, self._acc)
        return int(steps), int(status)

    def snapshot(self):
        return self.u.copy(), self.w.copy()

    def restore(self, snap):
        self.u[:], self.w[:] = snap

    def positions(self):
        """Full (n_nodes, 3) m: levels moved by u and turned/scaled by the quasi-static twist and
        radius of their prisms (a picture of the chain state; bars keep their length for rigid
        bases, for flexible bases a level takes the mean radius of its two prisms)."""
        phi, rad = self.shape(self.heights())
        theta = self._theta0 + np.concatenate([[0.0], np.cumsum(self.sign * phi)])
        rl = np.concatenate([[rad[0]], 0.5 * (rad[:-1] + rad[1:]), [rad[-1]]]) if len(rad) > 1 \
            else np.array([rad[0], rad[0]])
        x = np.array(self.network.x0)
        for k in range(3):
            t = theta + 2.0 * math.pi * k / 3.0
            nodes = self.levels[:, k]
            x[nodes, 0] = self._center[:, 0] + rl * np.cos(t)
            x[nodes, 1] = self._center[:, 1] + rl * np.sin(t)
            x[nodes, 2] = self._z0 + self.u
        return x

    def velocities(self):
        """Full (n_nodes, 3) m/s: the axial level velocities (the chain carries no twist rate)."""
        v = np.zeros((self.network.n_nodes, 3))
        v[self.levels, 2] = self.w[:, None]
        return v

    def set_state(self, x, v):
        """Load the axial part of full positions and velocities (mean z per level)."""
        x = np.asarray(x)
        v = np.asarray(v)
        self.u[:] = x[self.levels, 2].mean(axis=1) - self._z0
        self.w[:] = v[self.levels, 2].mean(axis=1)

    def impact(self, v0):
        """Axial velocity -v0 m/s added to the free end level; returns the energy added, J."""
        e0 = self.energy()
        self.w[-1] -= float(v0)
        return self.energy() - e0

    def energy(self):
        """Kinetic + prism energies - work of the axial external forces, J."""
        ke = 0.5 * float(np.sum(self.level_mass * (self.inv_m > 0) * self.w ** 2))
        return ke + float(np.sum(self.prism_energy(self.heights()))) \
            - float(np.sum(self.f_ext * self.u))

    def constraint_error(self):
        """The chain has no rigid members: 0."""
        return 0.0

    @property
    def cable_rest_length(self):
        return self._rest.copy()

    @property
    def cable_EA(self):
        return self._EA.copy()

    def set_cables(self, rest, EA):
        """Only the scene's own cables: the force law is precomputed for them."""
        if not (np.allclose(rest, self._rest, rtol=1e-12, atol=0)
                and np.allclose(EA, self._EA, rtol=1e-12, atol=0)):
            raise ValueError('model chain1d: cable rest lengths or stiffnesses cannot change (the '
                             'force law is precomputed for the scene); use full3d or sym3d')
