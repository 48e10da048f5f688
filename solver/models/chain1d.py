"""The 1D lumped-mass chain ``chain1d`` with the quasi-static prism force law F(h)
(docs/physics.md section 6).

State: axial displacements ``u_j`` (n_levels,) m and velocities ``w_j`` m/s of the base levels;
level mass ``M_j`` = the sum of its node masses; prism heights ``h_i = h0 + u_{i+1} - u_i``;
``M_j u_j'' = F(h_{j-1}) - F(h_j)`` (+ external axial force), ``F = -dE/dh`` (> 0 pushes the two
levels apart), ``E(h)`` the prism energy at height h minimised over what the chain does not carry
(twist, base radius). Twist and radius have no inertia here: that is the model's approximation.
Every prism uses the law of an interior prism (the end prisms of a shared-base column carry a
full end-level base cable instead of half of a shared one; the chain ignores that difference).

Force laws (:class:`~solver.models.prism_law.PrismLaw`):

- rigid bases (rigid edges): closed form, base radius r fixed, twist from the bar length,
  ``cos phi = 1 - (b^2 - h^2) / (2 r^2)``, ``F = -3 k_s (s - L_s)_+ ds/dh``. Singular
  (``F ~ 1 / sqrt(h - h_lock)``, integrable: the energy stays finite) at the LOCK
  ``h_lock = sqrt(b^2 - 4 r^2)`` where the twist reaches 180 deg. What the model does there: the
  prism cannot get shorter (``h >= h_lock`` is a hard contact of its two levels); a prism that
  reaches it bounces: the relative axial velocity of its two levels is reversed by an elastic
  impulse (momentum and energy kept). Near the lock, sub-steps shrink so that no prism's gap to
  the lock changes by more than 5 % per sub-step; within ``1e-9 h0`` of it the contact acts, and
  the force is evaluated at ``h >= h_lock + 1e-9 h0``. (The 3D model has no such wall: its twist
  can pass 180 deg, which the divergence check reports as bars crossing.)
- flexible bases (and rigid bases as stiff cables): ``E(h) = min over (phi, r)`` of the
  cross-cable energy plus the base-cable energy the prism carries (an interior base cable shared
  by two prisms counts half for each), with the bar length fixed. Precomputed once per model on a
  grid of h (golden-section search in phi, vectorised over the grid), F by the envelope theorem
  (:func:`~solver.models.prism_law.envelope_force`), interpolated by a cubic spline; E is the exact
  antiderivative of that spline, so forces and energy agree. Under strong compression the
  minimiser folds to 180 deg of twist with slack cross cables and only the base cables resist
  (the law softens); a prism pushed below the table (``0.02 h0``, crushed flat) stops the run
  with a clear error.

Integration: velocity Verlet with sub-steps of at most ``SUBSTEP`` (symplectic; cheap in 1D), for
a table law also at most ``OMEGA_SUBSTEP`` over the chain's highest frequency.
Energy drift: 2e-4 to 4e-4 per second for rigid bases (the near-lock stiffness), about 1e-6 for the
tabulated laws.
Impact: the end level gets ``w = -v0`` (no constraint to project: the impulse and energy modes
of 3D impacts coincide here).
"""
from __future__ import annotations

import copy
import math

import numpy as np

from solver.kernels import dynamics as dyn
from solver.compiled import jit
from solver.models.base import SelfIntegrating
from solver.models.prism_law import (PrismLaw, poly_eval, cross_length, prism_energy, rigid_force,
                        table_law, twist)

from solver.status import OUT_OF_TABLE  # noqa: E402
# largest Verlet sub-steps, s: the paper figures agree with 2e-6 s sub-steps to 0.05 %; the energy
# drift of the rigid-base chain (near-lock stiffness) is about 4e-4 per second at 1e-5 s
SUBSTEP = {0: 1e-5, 1: 1e-4}        # by law kind: 0 rigid closed form, 1 table
# a table law's sub-step is also at most this over the chain's highest angular frequency
# 2 sqrt(k_max / m) (k_max the largest |dF/dh| of the table): Verlet's energy error grows as
# (omega h)^2, and 0.02 keeps it near 1e-5 of the pulse energy (stiff-cable rigid bases have
# k_max 25 times the flexible bases'; the flexible-base chain keeps 1e-4 s, omega h = 0.017)
OMEGA_SUBSTEP = 0.02
LOCK_ETA = 0.05         # near the rigid-base lock: largest relative change of the gap per sub-step


def _largest_slope(fcoef, dh):
    """The largest |dF/dh| of the cubic pieces ``fcoef`` (n - 1, 4) over [0, dh] each: the
    quadratic F' at both ends and at its vertex when that lies inside (where the minimiser folds,
    the slope peaks within a piece)."""
    c0, c1, c2 = fcoef[:, 0], fcoef[:, 1], fcoef[:, 2]
    slopes = [np.abs(c2), np.abs(3.0 * c0 * dh * dh + 2.0 * c1 * dh + c2)]
    with np.errstate(divide='ignore', invalid='ignore'):
        t = np.where(c0 != 0.0, -c1 / (3.0 * c0), -1.0)
    inside = (t > 0.0) & (t < dh)
    slopes.append(np.where(inside, np.abs(3.0 * c0 * t * t + 2.0 * c1 * t + c2), 0.0))
    return float(np.max(slopes))


@jit
def _piece(h, lo, dh, coef):
    """Evaluate piecewise polynomial rows ``coef`` (n - 1, d) on the uniform grid at h; NaN
    outside."""
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


class Chain1D(SelfIntegrating):
    """The 1D chain as a model of one column (see the module doc). State ``u``, ``w``
    (n_levels,)."""
    name = 'chain1d'
    has_bars = False

    def __init__(self, network, f_ext=None, effects=None, striker_state=None):
        if effects is not None and effects.active:
            raise ValueError('model chain1d: has no strikers, prism stops or cable damping; use '
                             'model full3d or sym3d')
        meta = network.meta
        if meta.get('builder') != 'column' or network.n_columns != 1:
            raise ValueError('model chain1d: needs a single column built by the column builder')
        if np.any(network.bar_mass):
            raise ValueError('model chain1d: bar masses are not modelled (a level carries only '
                             'its lumped node masses); use sym3d or full3d')
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
        self.substep = SUBSTEP[self.law.kind]
        if self.law.kind == 1:
            k_max = _largest_slope(self.law.fcoef, self.law.dh)
            omega = 2.0 * math.sqrt(k_max / float(self.level_mass.min()))
            self.substep = min(self.substep, OMEGA_SUBSTEP / omega)
        self.u = np.zeros(len(lev))
        self.w = np.zeros(len(lev))
        self._acc = np.zeros(len(lev))
        self._rest = np.array(network.cable_rest_length)
        self._EA = np.array(network.cable_EA)
        c = network.x0[lev]
        self._center = c[:, :, :2].mean(axis=1)
        self._z0 = c[:, :, 2].mean(axis=1)
        d = c[0, 0, :2] - self._center[0]
        self._theta0 = math.atan2(d[1], d[0])

    def copy(self):
        new = copy.copy(self)
        new.u, new.w, new._acc = self.u.copy(), self.w.copy(), self._acc.copy()
        new._rest, new._EA = self._rest.copy(), self._EA.copy()
        return new

    def keep(self):
        return self.u.copy(), self.w.copy()

    def restore(self, kept):
        self.u[:], self.w[:] = kept

    def _prism_cables(self, i):
        """Cross cables (k, L) of prism i, and the base cables (weight, k, L) it carries (half of
        an interior base cable, all of an end-level one)."""
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
        return poly_eval(h, law.lo, law.dh, law.fcoef)

    def prism_energy(self, h):
        """E(h) J of one prism (minimised over twist and radius for flexible bases)."""
        h = np.asarray(h, dtype=np.float64)
        if self.law.kind == 0:
            phi = twist(h, self.r0, self.b)
            return prism_energy(h, self.r0, phi, self.cross, ())
        return poly_eval(h, self.law.lo, self.law.dh, self.law.ecoef)

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
        n_sub = max(1, int(math.ceil(dt / self.substep - 1e-9)))
        law = self.law
        fcoef = law.fcoef if law.kind == 1 else np.zeros((1, 4))
        steps, status = _chain_run(self.u, self.w, float(dt), int(n_steps), n_sub, self.h0,
                                   self.inv_m, self.f_ext, law.kind, law.rigid, law.lo, law.dh,
                                   fcoef, self._acc)
        return int(steps), int(status)

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
