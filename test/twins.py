"""Slow, obvious NumPy twins of the solver kernels: dense matrices, no bands, no operators.

They share nothing with the kernels but the network's member lists and masses, so agreement is
evidence that the fast path computes the physics of docs/physics.md section 1.1.
"""
import numpy as np


def dense_mass(net):
    """The (n_nodes, n_nodes) node mass matrix: lumped masses plus rod blocks of massive bars."""
    M = np.diag(np.array(net.node_mass, dtype=float))
    for a, b, mb in zip(net.bar_a, net.bar_b, net.bar_mass):
        M[a, a] += mb / 3
        M[b, b] += mb / 3
        M[a, b] += mb / 6
        M[b, a] += mb / 6
    return M


def free_index(net):
    return np.nonzero(~np.asarray(net.clamped))[0]


def rigid_members(net):
    """(tail, head) of every bar and rigid edge with at least one free node."""
    pairs = list(zip(net.bar_a, net.bar_b)) + list(zip(net.edge_a, net.edge_b))
    return [(t, h) for t, h in pairs if not (net.clamped[t] and net.clamped[h])]


def cable_forces(x, net, rest, EA):
    """(n_nodes, 3) N of tension-only cables, vectorised."""
    d = x[net.cable_b] - x[net.cable_a]
    s = np.linalg.norm(d, axis=1)
    T = np.where(s > rest, EA / rest * (s - rest), 0.0)
    f = np.zeros_like(x)
    np.add.at(f, net.cable_a, (T / s)[:, None] * d)
    np.add.at(f, net.cable_b, -(T / s)[:, None] * d)
    return f


def jacobian(x, net):
    """Constraint Jacobian (n_con, 3 n_free) of g_c = (|b|^2 - L^2) / 2 in free coordinates."""
    free = free_index(net)
    col = {p: i for i, p in enumerate(free)}
    members = rigid_members(net)
    J = np.zeros((len(members), 3 * len(free)))
    for c, (t, h) in enumerate(members):
        b = x[h] - x[t]
        if h in col:
            J[c, 3 * col[h]:3 * col[h] + 3] += b
        if t in col:
            J[c, 3 * col[t]:3 * col[t] + 3] -= b
    return J


def accelerations(x, v, net, rest, EA, f_ext=None):
    """Dense KKT solve of ``M a = f + J^T lam``, ``J a = -|b'|^2``; returns (a (n, 3), lam)."""
    free = free_index(net)
    n_f = len(free)
    M3 = np.kron(dense_mass(net)[np.ix_(free, free)], np.eye(3))
    f = cable_forces(x, net, rest, EA)
    if f_ext is not None:
        f = f + f_ext
    J = jacobian(x, net)
    members = rigid_members(net)
    q = np.array([np.dot(v[h] - v[t], v[h] - v[t]) for t, h in members])
    m = len(members)
    K = np.zeros((3 * n_f + m, 3 * n_f + m))
    K[:3 * n_f, :3 * n_f] = M3
    K[:3 * n_f, 3 * n_f:] = -J.T
    K[3 * n_f:, :3 * n_f] = J
    rhs = np.concatenate([f[free].ravel(), -q])
    sol = np.linalg.solve(K, rhs)
    a = np.zeros_like(x)
    a[free] = sol[:3 * n_f].reshape(-1, 3)
    return a, sol[3 * n_f:], members


def project_velocities(x, v, net):
    """``v - M^-1 J^T (J M^-1 J^T)^-1 J v`` (mass-weighted projection), dense."""
    free = free_index(net)
    Minv = np.linalg.inv(np.kron(dense_mass(net)[np.ix_(free, free)], np.eye(3)))
    J = jacobian(x, net)
    vf = v[free].ravel()
    mu = np.linalg.solve(J @ Minv @ J.T, -J @ vf)
    out = v.copy()
    out[free] = (vf + Minv @ J.T @ mu).reshape(-1, 3)
    return out


def project_positions(x, net, iterations):
    """``iterations`` mass-weighted Gauss-Newton steps ``x += M^-1 J^T dmu`` with
    ``J M^-1 J^T dmu = -g``."""
    free = free_index(net)
    Minv = np.linalg.inv(np.kron(dense_mass(net)[np.ix_(free, free)], np.eye(3)))
    members = rigid_members(net)
    lengths = {}
    for t, h in members:
        lengths[(t, h)] = np.linalg.norm(net.x0[h] - net.x0[t])
    x = x.copy()
    for _ in range(iterations):
        J = jacobian(x, net)
        g = np.array([0.5 * (np.dot(x[h] - x[t], x[h] - x[t]) - lengths[(t, h)] ** 2)
                      for t, h in members])
        dmu = np.linalg.solve(J @ Minv @ J.T, -g)
        x[free] += (Minv @ J.T @ dmu).reshape(-1, 3)
    return x


def kinetic_energy(v, net):
    free = free_index(net)
    M3 = np.kron(dense_mass(net)[np.ix_(free, free)], np.eye(3))
    vf = v[free].ravel()
    return 0.5 * vf @ M3 @ vf
