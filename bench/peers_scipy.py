"""The plain SciPy baseline of ``tensegrity bench --peers``: the code a Python user writes first.

The same model as the solver (docs/physics.md section 1.1: node masses, rigid massless bars as
constraints, tension-only cables), as a NumPy right-hand side for ``scipy.integrate.solve_ivp``:

- state ``y = [x_free (n_free * 3), v_free (n_free * 3)]`` (m, m/s), clamped nodes fixed at ``x0``;
- cable forces vectorised with ``np.add.at``;
- the dense constraint Jacobian ``J`` (n_con, 3 n_nodes), ``A = J W J^T`` and one dense
  ``np.linalg.solve`` per evaluation for the multipliers, ``a = W (f + J^T lambda)``.

No projection (solve_ivp knows nothing of constraints): the bar lengths hold only as well as the
tolerance does, which is what a first attempt gets.
"""
from __future__ import annotations

import time

import numpy as np


class ScipyColumn:
    """The NumPy right-hand side of a network (massless bars, node masses)."""

    def __init__(self, network, rest_length=None, EA=None):
        if np.any(np.asarray(network.bar_mass) != 0):
            raise ValueError('SciPy baseline: massive bars are not supported (node masses only)')
        self.network = network
        self.x0 = np.array(network.x0)
        self.free = np.nonzero(~np.asarray(network.clamped))[0]
        self.n = network.n_nodes
        self.rest = np.array(network.cable_rest_length if rest_length is None else rest_length)
        self.EA = np.array(network.cable_EA if EA is None else EA)
        tail = np.concatenate([network.bar_a, network.edge_a]).astype(np.int64)
        head = np.concatenate([network.bar_b, network.edge_b]).astype(np.int64)
        keep = ~(network.clamped[tail] & network.clamped[head])
        self.tail, self.head = tail[keep], head[keep]
        winv = np.where(network.clamped, 0.0, 1.0 / np.asarray(network.node_mass))
        self.winv3 = np.repeat(winv, 3)            # (3 n,) 1/kg per coordinate
        self.rows = np.arange(len(self.tail))[:, None]
        self.evaluations = 0

    def full(self, y):
        """``(x, v)`` (n_nodes, 3) each from the state vector ``y``."""
        k = 3 * len(self.free)
        x = self.x0.copy()
        v = np.zeros_like(x)
        x[self.free] = y[:k].reshape(-1, 3)
        v[self.free] = y[k:].reshape(-1, 3)
        return x, v

    def pack(self, x, v):
        return np.concatenate([x[self.free].ravel(), v[self.free].ravel()])

    def accelerations(self, x, v):
        """Node accelerations (n_nodes, 3) m/s^2 at positions ``x`` and velocities ``v``."""
        net = self.network
        d = x[net.cable_b] - x[net.cable_a]
        s = np.linalg.norm(d, axis=1)
        gamma = np.where(s > self.rest, self.EA / self.rest * (s - self.rest) / s, 0.0)
        f = np.zeros_like(x)
        np.add.at(f, net.cable_a, gamma[:, None] * d)
        np.add.at(f, net.cable_b, -gamma[:, None] * d)
        b = x[self.head] - x[self.tail]
        bdot = v[self.head] - v[self.tail]
        J = np.zeros((len(b), 3 * self.n))
        J[self.rows, 3 * self.head[:, None] + np.arange(3)] = b
        J[self.rows, 3 * self.tail[:, None] + np.arange(3)] = -b
        JW = J * self.winv3
        A = JW @ J.T
        rhs = -(JW @ f.ravel() + np.einsum('ij,ij->i', bdot, bdot))
        lam = np.linalg.solve(A, rhs)
        return (self.winv3 * (f.ravel() + J.T @ lam)).reshape(-1, 3)

    def rhs(self, t, y):
        self.evaluations += 1
        x, v = self.full(y)
        a = self.accelerations(x, v)
        return np.concatenate([y[3 * len(self.free):], a[self.free].ravel()])

    def solve(self, x, v, times, rtol, atol=None, method='DOP853'):
        """Integrate from ``(x, v)`` at ``times[0]`` through ``times`` (n_t,) s.

        Returns ``(positions (n_t, n_nodes, 3) m, wall_time_s, stats)`` (``stats['cpu_s']`` the
        thread's CPU time); ``atol`` defaults to
        ``1e-3 rtol`` (m and m/s: displacements are a fraction of a millimetre)."""
        from scipy.integrate import solve_ivp
        atol = 1e-3 * rtol if atol is None else atol
        self.evaluations = 0
        t0, c0 = time.perf_counter(), time.thread_time()
        sol = solve_ivp(self.rhs, (times[0], times[-1]), self.pack(x, v), method=method,
                        t_eval=times, rtol=rtol, atol=atol)
        wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
        if not sol.success:
            raise RuntimeError(f'solve_ivp {method} rtol={rtol:g}: {sol.message}')
        pos = np.array([self.full(y)[0] for y in sol.y.T])
        stats = {'evaluations': int(sol.nfev), 'cpu_s': cpu,
                 'rtol': rtol, 'atol': atol}
        return pos, wall, stats
