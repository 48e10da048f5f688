"""The FB column as a MuJoCo model (optional dependency ``mujoco``) for ``bench --peers``.

How the pin-jointed network maps onto MuJoCo (the same physics, not an approximation of it):

- MuJoCo has no node graph with exact distance constraints: its equality constraints are soft
  (``solref``/``solimp``) and solved by its constraint solver. But the bars of a flexible-base
  column form three serial chains rooted at the clamped level: the network is a kinematic
  **tree**. Each bar is one body whose **ball joint** sits at its parent node and whose mass is the
  lumped mass of its child node, placed at that node. Bar lengths hold exactly (reduced
  coordinates), as in the paper's model.
- A point mass on a ball joint has no inertia about the bar axis, and MuJoCo needs positive
  definite body inertias. Each body gets a tiny isotropic inertia ``spin_inertia * m L^2`` about
  its node (default 1e-6 of the bar's swinging inertia). The spin of a bar about its own axis is
  an extra degree of freedom that no force drives (every force acts on the axis); the only change
  to the node dynamics is that 1e-6 relative extra rotational inertia.
- Cables are spatial tendons between node sites with ``stiffness = EA / L`` and
  ``springlength = "0 L"``: MuJoCo's dead band makes the spring act only above the rest length
  L, i.e. tension only, ``T = k (s - L)_+``.
- No gravity, no damping, no contacts, no constraints (``<flag contact/constraint="disable">``),
  MuJoCo's RK4.

The impact is the same impulse as the solver's (docs/physics.md section 3.1): node momenta
``m (0, 0, -v0)`` on the free-end nodes mapped to generalized velocities
``qvel = M^-1 J^T p``, which is the mass-weighted projection onto the constraint tangent space.

Networks with rigid base edges (RB columns), massive bars, or any bar graph that is not a forest
rooted at clamped nodes are not trees: :func:`build_mjcf` refuses them with a clear error.
"""
from __future__ import annotations

from collections import deque

import numpy as np


def _f(v):
    return repr(float(v))


def _vec(a):
    return ' '.join(_f(c) for c in a)


def bar_tree(network):
    """Orient every bar away from the clamped nodes.

    Returns ``(parent_bar, tail, head)``: per tree body (one per bar) the index of its parent body
    (-1 for a bar attached to a clamped node), its joint node and its mass node, in an order where
    every parent precedes its children. Raises ``ValueError`` if the bars are not such a forest."""
    if network.n_edges:
        raise ValueError('MuJoCo model: rigid base edges make closed loops; only flexible-base '
                         'columns (bar trees) map onto a MuJoCo kinematic tree')
    if np.any(np.asarray(network.bar_mass) != 0):
        raise ValueError('MuJoCo model: massive bars are not supported (node masses only)')
    n = network.n_nodes
    adj = [[] for _ in range(n)]
    for j, (a, b) in enumerate(zip(network.bar_a, network.bar_b)):
        adj[a].append((j, b))
        adj[b].append((j, a))
    clamped = np.asarray(network.clamped)
    body_of_node = np.full(n, -1)
    seen_bar = np.zeros(network.n_bars, dtype=bool)
    parent, tail, head = [], [], []
    queue = deque(int(p) for p in np.nonzero(clamped)[0])
    reached = clamped.copy()
    while queue:
        p = queue.popleft()
        for j, q in adj[p]:
            if seen_bar[j]:
                continue
            seen_bar[j] = True
            if reached[q]:
                raise ValueError(f'MuJoCo model: bar {j} closes a loop (node {q}); the bars must '
                                 'form a tree rooted at the clamped nodes')
            reached[q] = True
            body_of_node[q] = len(parent)
            parent.append(int(body_of_node[p]) if not clamped[p] else -1)
            tail.append(p)
            head.append(int(q))
            queue.append(int(q))
    if not reached.all():
        missing = np.nonzero(~reached)[0]
        raise ValueError(f'MuJoCo model: nodes {missing[:5].tolist()} are not connected to a '
                         'clamped node through bars')
    return np.array(parent), np.array(tail), np.array(head)


def build_mjcf(network, dt, spin_inertia=1e-6, rest_length=None):
    """MJCF text of ``network`` (x0 configuration, at rest) with RK4 step ``dt`` s.

    Sites are named ``n<node>``, bodies ``bar<bar order>``, tendons ``c<cable>`` in the network's
    cable order. ``rest_length`` (n_cables,) m overrides the network's cable rest lengths."""
    parent, tail, head = bar_tree(network)
    x0 = np.asarray(network.x0)
    m = np.asarray(network.node_mass)
    rest = np.asarray(network.cable_rest_length if rest_length is None else rest_length)
    children = [[] for _ in range(len(parent))]
    roots = []
    for b, p in enumerate(parent):
        (roots if p < 0 else children[p]).append(b)
    out = ['<mujoco model="tensegrity_column">',
           '  <compiler angle="radian" inertiafromgeom="false"/>',
           f'  <option timestep="{_f(dt)}" integrator="RK4" gravity="0 0 0">',
           '    <flag contact="disable" constraint="disable" energy="enable"/>',
           '  </option>',
           '  <worldbody>']
    for p in np.nonzero(np.asarray(network.clamped))[0]:
        out.append(f'    <site name="n{p}" pos="{_vec(x0[p])}"/>')

    def emit(b, origin, indent):
        t, h = tail[b], head[b]
        rel = x0[h] - x0[t]
        mass = m[h]
        inertia = spin_inertia * mass * float(rel @ rel)
        pad = ' ' * indent
        out.append(f'{pad}<body name="bar{b}" pos="{_vec(x0[t] - origin)}">')
        out.append(f'{pad}  <joint name="j{b}" type="ball" pos="0 0 0"/>')
        out.append(f'{pad}  <inertial pos="{_vec(rel)}" mass="{_f(mass)}" '
                   f'diaginertia="{_f(inertia)} {_f(inertia)} {_f(inertia)}"/>')
        out.append(f'{pad}  <site name="n{h}" pos="{_vec(rel)}"/>')
        for c in children[b]:
            emit(c, x0[t], indent + 2)
        out.append(f'{pad}</body>')

    import sys
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 4 * len(parent) + 100))
    try:
        for b in roots:
            emit(b, np.zeros(3), 4)
    finally:
        sys.setrecursionlimit(limit)
    out.append('  </worldbody>')
    out.append('  <tendon>')
    for c, (a, b) in enumerate(zip(network.cable_a, network.cable_b)):
        k = network.cable_EA[c] / rest[c]
        out.append(f'    <spatial name="c{c}" stiffness="{_f(k)}" damping="0" '
                   f'springlength="0 {_f(rest[c])}"><site site="n{a}"/><site site="n{b}"/>'
                   '</spatial>')
    out.append('  </tendon>')
    out.append('</mujoco>')
    return '\n'.join(out) + '\n'


class MujocoColumn:
    """A compiled MuJoCo column plus the maps between its sites and the network's nodes.

    ``positions()`` (n_nodes, 3) m; ``strain()`` (n_columns, n_prisms); ``impact(v0)`` sets the
    generalized velocities of the solver's impulse; ``advance(n_steps)`` runs ``mj_step``."""

    def __init__(self, network, dt, spin_inertia=1e-6):
        import mujoco
        self.mujoco = mujoco
        self.network = network
        self.xml = build_mjcf(network, dt, spin_inertia)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        self.site_of_node = np.array([self.model.site(f'n{p}').id
                                      for p in range(network.n_nodes)])
        mujoco.mj_forward(self.model, self.data)

    @property
    def dt(self):
        return float(self.model.opt.timestep)

    def reset(self):
        self.mujoco.mj_resetData(self.model, self.data)
        self.mujoco.mj_forward(self.model, self.data)

    def positions(self):
        """Node positions (n_nodes, 3) m of the current state (kinematics refreshed)."""
        self.mujoco.mj_kinematics(self.model, self.data)
        return np.array(self.data.site_xpos[self.site_of_node])

    def node_velocities(self):
        """Node velocities (n_nodes, 3) m/s: site Jacobians times ``qvel``."""
        mj, m, d = self.mujoco, self.model, self.data
        mj.mj_forward(m, d)
        out = np.zeros((self.network.n_nodes, 3))
        jac = np.zeros((3, m.nv))
        for p, s in enumerate(self.site_of_node):
            mj.mj_jacSite(m, d, jac, None, int(s))
            out[p] = jac @ d.qvel
        return out

    def strain(self):
        from solver.analysis.observables import prism_strains
        return prism_strains(self.positions(), self.network.levels, self.network.h0)

    def impact(self, v0):
        """Axial impulse ``m (0, 0, -v0)`` on the free-end level of every column:
        ``qvel = M^-1 J^T p`` (the mass-weighted projection of docs/physics.md section 3.1)."""
        mj, m, d = self.mujoco, self.model, self.data
        mj.mj_forward(m, d)
        net = self.network
        tau = np.zeros(m.nv)
        jac = np.zeros((3, m.nv))
        for col in range(net.n_columns):
            for p in net.levels[col, -1]:
                mj.mj_jacSite(m, d, jac, None, int(self.site_of_node[p]))
                tau += jac.T @ (net.node_mass[p] * np.array([0.0, 0.0, -v0]))
        qvel = np.zeros(m.nv)
        mj.mj_solveM(m, d, qvel.reshape(1, -1), tau.reshape(1, -1))
        d.qvel[:] = qvel
        mj.mj_forward(m, d)

    def accelerations(self):
        """Generalized accelerations ``qacc`` (nv,) of the current state."""
        self.mujoco.mj_forward(self.model, self.data)
        return np.array(self.data.qacc)

    def node_accelerations(self):
        """Node accelerations (n_nodes, 3) m/s^2 (site frames' linear acceleration)."""
        mj, m, d = self.mujoco, self.model, self.data
        mj.mj_forward(m, d)
        mj.mj_rnePostConstraint(m, d)
        out = np.zeros((self.network.n_nodes, 3))
        res = np.zeros(6)
        for p, s in enumerate(self.site_of_node):
            mj.mj_objectAcceleration(m, d, mj.mjtObj.mjOBJ_SITE, int(s), res, 0)
            out[p] = res[3:]
        return out

    def energy(self):
        """Kinetic + potential (tendon spring) energy J, from MuJoCo's own energy computation."""
        mj, m, d = self.mujoco, self.model, self.data
        mj.mj_forward(m, d)
        mj.mj_energyPos(m, d)
        mj.mj_energyVel(m, d)
        return float(d.energy[0] + d.energy[1])

    def advance(self, n_steps):
        self.mujoco.mj_step(self.model, self.data, nstep=int(n_steps))
