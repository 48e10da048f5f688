"""The exact 3-fold symmetric reduction ``sym3d`` (docs/physics.md section 6).

A network that is mapped onto itself by the rotation ``R`` by 2 pi / 3 about the z axis (nodes,
members, rest lengths, stiffnesses, masses and supports), loaded symmetrically, keeps that
symmetry for ever: ``x_{R p} = R x_p``. One node per orbit of three nodes then carries the whole
motion. A member ``(a, b)`` of the full network becomes a member joining the representative ``A``
of ``a`` to the rotated image ``R^r x_B`` of the representative of ``b`` (``r`` in {0, 1, 2}); the
three members of an orbit become one. A rigid base triangle becomes ONE member from ``x_j`` to
``R x_j`` (length ``sqrt(3) r``: the radial constraint ``x^2 + y^2 = r^2``), a base cable
likewise.

The reduced system is the full one restricted to the symmetric subspace (Lagrangian divided by 3),
so node masses, multipliers and cable tensions are those of the full model and its trajectories are
the full model's, to round-off. The kernels of :mod:`solver.kernels.dynamics` and
:mod:`solver.integrators.registry` run it unchanged through the rotated members of its
:class:`~solver.kernels.records.Topology` (``con_rot``, ``cable_rot``, ``con_coef3``).

:func:`reduce_network` finds the symmetry (or raises :class:`NotSymmetric`);
:class:`Sym3D` is the model (same interface as :class:`solver.models.family.Full3D`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from solver.kernels import records
from solver.kernels import summary
from solver.kernels.rotation import expand
from solver.compiled import jit
from solver.build import memo
from solver.models import extras
from solver.models.base import RecordModel
from solver.kernels.rotation import ROT_C, ROT_S
from solver.kernels import massmatrix
from solver.build.network import (NetworkError, band_order, diagonal_inverse_mass,
                                   inverse_mass, length_of)
from solver.build.network import read_only_copy as _ro

R3 = np.array([[-0.5, -math.sqrt(3.0) / 2.0, 0.0], [math.sqrt(3.0) / 2.0, -0.5, 0.0],
               [0.0, 0.0, 1.0]])
ROT = (np.eye(3), R3, R3 @ R3)       # R^r, r = 0, 1, 2


@jit
def _expand_kernel(a, rep, cos, sin, out):
    """:func:`solver.kernels.rotation.expand`, compiled to be called from Python."""
    expand(a, rep, cos, sin, out)


class NotSymmetric(ValueError):
    """The network or a state is not 3-fold symmetric about the z axis; the message says why."""


@dataclass(frozen=True)
class ReducedNetwork:
    """Solver arrays of the reduced network (names as in :class:`solver.build.network.Network`).

    ``x0`` (n_orbits, 3) m; ``con_rot``/``cable_rot`` rotation index of each member's head image
    (``con_rot`` empty when no rigid member is rotated: the plain kernels then apply);
    ``con_coef3`` (n_con, bw + 1, 3) coupling coefficients (see :mod:`solver.kernels.dynamics`).
    ``node_rep``/``node_rot`` (n_full,): full node p is ``R^node_rot[p] x[node_rep[p]]``;
    ``cable_map`` (n_full_cables,): reduced cable of each full cable."""
    x0: np.ndarray
    node_mass: np.ndarray
    clamped: np.ndarray
    w_diag: np.ndarray
    partner: np.ndarray
    w_off: np.ndarray
    con_tail: np.ndarray
    con_head: np.ndarray
    con_rot: np.ndarray
    con_length: np.ndarray
    con_coef: np.ndarray
    con_coef3: np.ndarray
    bandwidth: int
    cable_a: np.ndarray
    cable_b: np.ndarray
    cable_rot: np.ndarray
    cable_rest_length: np.ndarray
    cable_EA: np.ndarray
    node_rep: np.ndarray
    node_rot: np.ndarray
    cable_map: np.ndarray
    reps: np.ndarray
    kkt: tuple = massmatrix.NO_KKT
    bar_a: np.ndarray = field(default_factory=lambda: massmatrix.EMPTY_I)
    bar_b: np.ndarray = field(default_factory=lambda: massmatrix.EMPTY_I)
    bar_mass: np.ndarray = field(default_factory=lambda: massmatrix.EMPTY_F)

    n_nodes = length_of('x0')
    n_constraints = length_of('con_tail')

    def topology(self):
        """The kernels' :class:`~solver.kernels.records.Topology`: members to rotated images."""
        return records.Topology(
            self.w_diag, self.partner, self.w_off, self.con_tail, self.con_head, self.con_length,
            self.con_coef, self.cable_a, self.cable_b, self.con_rot, self.cable_rot,
            self.con_coef3, self.kkt)


def _node_map(x0, tol):
    """``sigma`` (n,) with ``R x0[p] = x0[sigma[p]]`` (within ``tol`` m)."""
    tree = cKDTree(x0)
    dist, sigma = tree.query(x0 @ R3.T)
    if np.any(dist > tol):
        p = int(np.argmax(dist))
        raise NotSymmetric(f'node {p} has no image under the 2 pi / 3 rotation about z')
    if len(np.unique(sigma)) != len(sigma) or np.any(sigma == np.arange(len(sigma))):
        raise NotSymmetric('the rotation does not permute the nodes in orbits of three')
    return sigma


def _orbits(sigma):
    """Representatives and, per node, (representative, rotation index)."""
    n = len(sigma)
    rep = -np.ones(n, dtype=np.int64)
    rot = np.zeros(n, dtype=np.int64)
    reps = []
    for p in range(n):
        if rep[p] >= 0:
            continue
        i = len(reps)
        reps.append(p)
        q = p
        for r in range(3):
            rep[q], rot[q] = i, r
            q = sigma[q]
        if q != p:
            raise NotSymmetric(f'node {p}: its orbit under the rotation is not of length three')
    return np.array(reps, dtype=np.int64), rep, rot


def _reduce_members(pairs, rep, rot, props, what):
    """Reduced (tail, head, r) of each orbit of members, with a map full -> reduced.

    ``props`` (n_members, k) values that must agree along an orbit (rest length, EA, ...).

    Inside :func:`solver.build.memo.sharing` the grouping of a topology (``pairs``, ``rep``,
    ``rot``) is found once: another network of that topology takes it when its own ``props``
    agree along every group it makes (as the search below would require them to), else it is
    searched for again."""
    if not memo.active():
        return _search_members(pairs, rep, rot, props, what)
    props = np.asarray(props, dtype=np.float64)
    try:
        arr, first, mapping = memo.lookup('member-groups', (what, pairs, rep, rot),
                                          lambda: _grouped_members(pairs, rep, rot, props, what))
    except NotSymmetric:                # the first network of the topology was not symmetric
        return _search_members(pairs, rep, rot, props, what)
    prop = props[first]
    if np.all(np.abs(prop[mapping] - props) <= 1e-12 * np.abs(props)):
        return arr, prop, mapping
    return _search_members(pairs, rep, rot, props, what)


def _grouped_members(pairs, rep, rot, props, what):
    """``(arr, first, mapping)``: :func:`_search_members` with ``first`` the first full member of
    each reduced member (whose ``props`` the reduced member has)."""
    arr, _, mapping = _search_members(pairs, rep, rot, props, what)
    first = np.full(len(arr), -1, dtype=np.int64)
    for m in range(len(mapping) - 1, -1, -1):
        first[mapping[m]] = m
    return arr, first, mapping


def _search_members(pairs, rep, rot, props, what):
    keys = {}
    mapping = np.zeros(len(pairs), dtype=np.int64)
    out = []
    for m, (a, b) in enumerate(pairs):
        A, B = int(rep[a]), int(rep[b])
        r = int((rot[b] - rot[a]) % 3)
        if A > B or (A == B and r == 2):       # the same orbit seen from the other end
            A, B, r = B, A, (-r) % 3
        key = (A, B, r)
        slots = keys.setdefault(key, [])
        # parallel members of one orbit: the k-th full member of a rotation class joins slot k // 3
        idx = None
        for s in slots:
            if out[s][4] < 3 and np.allclose(out[s][3], props[m], rtol=1e-12, atol=0):
                idx = s
                break
        if idx is None:
            idx = len(out)
            out.append([A, B, r, props[m], 0])
            slots.append(idx)
        out[idx][4] += 1
        mapping[m] = idx
    for A, B, r, prop, count in out:
        if count != 3:
            raise NotSymmetric(f'{what}: a member orbit has {count} members instead of three '
                               '(members or their properties are not symmetric)')
    arr = np.array([(o[0], o[1], o[2]) for o in out], dtype=np.int64).reshape(-1, 3)
    prop = np.array([o[3] for o in out], dtype=np.float64).reshape(len(out), props.shape[1])
    return arr, prop, mapping


def _coupling3(members, w_diag, partner, w_off, bw):
    """``coef3[c, k] = sum s_e s_f W_pq (1, cos t, sin t)``, t = 2 pi (rho_e - rho_f) / 3, over the
    ends e = (p, sign, rho) of constraint c and f of d = c - k (head: sign +1, rho = r; tail: -1,
    rho = 0)."""
    m = len(members)
    coef = np.zeros((m, bw + 1, 3))
    for c in range(m):
        ends_c = ((members[c, 1], 1.0, members[c, 2]), (members[c, 0], -1.0, 0))
        for k in range(min(c, bw) + 1):
            d = c - k
            ends_d = ((members[d, 1], 1.0, members[d, 2]), (members[d, 0], -1.0, 0))
            for p, sp, rp in ends_c:
                for q, sq, rq in ends_d:
                    if p == q:
                        w = w_diag[p]
                    elif partner[p] == q:
                        w = w_off[p]
                    else:
                        continue
                    t = 2.0 * math.pi * (rp - rq) / 3.0
                    coef[c, k] += sp * sq * w * np.array([1.0, math.cos(t), math.sin(t)])
    coef[np.abs(coef) < 1e-14 * np.max(np.abs(coef), initial=1.0)] = 0.0
    return coef


REDUCE_INPUTS = ('x0', 'node_mass', 'clamped', 'bar_a', 'bar_b', 'bar_mass', 'edge_a', 'edge_b',
                 'cable_a', 'cable_b', 'cable_rest_length', 'cable_EA')


def reduce_network(network, tol=1e-9):
    """The :class:`ReducedNetwork` of a 3-fold symmetric network; raises :class:`NotSymmetric`.
    Inside :func:`solver.build.memo.sharing` a network of the same values (every array of
    :data:`REDUCE_INPUTS`) gets the same (read-only) result, and one of the same topology reuses
    its orbits' member grouping (:func:`_reduce_members`)."""
    return memo.lookup('reduce', (tol, *(getattr(network, k) for k in REDUCE_INPUTS)),
                       lambda: _reduce_network(network, tol))


def _reduce_network(network, tol):
    x0 = np.asarray(network.x0)
    scale = max(float(np.max(np.abs(x0))), 1e-300)
    sigma = _node_map(x0, tol * scale)
    reps, rep, rot = _orbits(sigma)
    for name, arr in (('node_mass', network.node_mass), ('clamped', network.clamped)):
        if np.any(arr[sigma] != arr):
            raise NotSymmetric(f'{name} differs between symmetric nodes')
    bars = np.stack([network.bar_a, network.bar_b], axis=1)
    edges = np.stack([network.edge_a, network.edge_b], axis=1)
    cables = np.stack([network.cable_a, network.cable_b], axis=1)
    rbars, bmass, _ = _reduce_members(bars, rep, rot, np.asarray(network.bar_mass)[:, None],
                                      'bars')
    redges, _, _ = _reduce_members(edges, rep, rot, np.zeros((len(edges), 1)), 'rigid edges')
    rcab, cprop, cable_map = _reduce_members(
        cables, rep, rot, np.stack([network.cable_rest_length, network.cable_EA], axis=1),
        'cables')
    bmass = bmass[:, 0]
    if np.any((bmass > 0) & (rbars[:, 2] != 0)):
        raise NotSymmetric('a massive bar joins a node to a rotated image (not supported)')
    node_mass = np.asarray(network.node_mass)[reps]
    clamped = np.asarray(network.clamped)[reps]
    # massive bars that share nodes: the reduced mass matrix has the rod blocks of the reduced
    # bars (every massive bar has r = 0, so a block couples x_a and x_b, not a rotated image)
    class_k = massmatrix.needs_kkt(rbars[:, :2], bmass)
    if class_k:
        w_diag, partner, w_off, mass = diagonal_inverse_mass(node_mass, clamped, rbars[:, :2],
                                                              bmass)
    else:
        w_diag, partner, w_off = inverse_mass(node_mass, clamped, rbars[:, :2], bmass)

    members = np.concatenate([rbars, redges]) if len(redges) else rbars
    x_red = x0[reps]
    b = np.einsum('mij,mj->mi', np.array([ROT[r] for r in members[:, 2]]).reshape(-1, 3, 3),
                  x_red[members[:, 1]]) - x_red[members[:, 0]]
    length = np.linalg.norm(b, axis=1)
    free = ~(clamped[members[:, 0]] & clamped[members[:, 1]])
    members, length = members[free], length[free]
    order, bw = band_order(members[:, :2], partner)
    members, length = members[order], length[order]
    coef3 = _coupling3(members, w_diag, partner, w_off, bw)
    # no rotated rigid member (flexible bases: bars only): the plain constraint kernels apply
    con_rot = members[:, 2] if np.any(members[:, 2]) else np.zeros(0, dtype=np.int64)
    if len(members) and np.any((coef3[:, 0, 0] <= 0) & (coef3[:, 0, 1] <= 0)):
        raise NetworkError('a rigid member has no free mass at either end')
    kkt = massmatrix.NO_KKT
    if class_k:
        node_u, con_u, dims = massmatrix.layout(len(reps), clamped, members[:, :2], mass[0],
                                                mass[1], x_red)
        mass_p, mass_q, mass_val = mass
        kkt = massmatrix.KKT(*(_ro(a, a.dtype) for a in (node_u, con_u, mass_p, mass_q, mass_val,
                                                          dims)))
    return ReducedNetwork(
        x0=_ro(x_red, np.float64), node_mass=_ro(node_mass, np.float64),
        clamped=_ro(clamped, bool), w_diag=_ro(w_diag, np.float64), partner=_ro(partner, np.int64),
        w_off=_ro(w_off, np.float64), con_tail=_ro(members[:, 0], np.int64),
        con_head=_ro(members[:, 1], np.int64), con_rot=_ro(con_rot, np.int64),
        con_length=_ro(length, np.float64), con_coef=_ro(coef3[:, :, 1], np.float64),
        con_coef3=_ro(coef3, np.float64), bandwidth=int(bw),
        cable_a=_ro(rcab[:, 0], np.int64), cable_b=_ro(rcab[:, 1], np.int64),
        cable_rot=_ro(rcab[:, 2], np.int64), cable_rest_length=_ro(cprop[:, 0], np.float64),
        cable_EA=_ro(cprop[:, 1], np.float64), node_rep=_ro(rep, np.int64),
        node_rot=_ro(rot, np.int64), cable_map=_ro(cable_map, np.int64), reps=_ro(reps, np.int64),
        kkt=kkt, bar_a=_ro(rbars[:, 0], np.int64), bar_b=_ro(rbars[:, 1], np.int64),
        bar_mass=_ro(bmass, np.float64))


class Sym3D(RecordModel):
    """One node per orbit of three (docs/physics.md section 6); state ``x``, ``v`` (n_orbits, 3).

    ``positions()``/``velocities()`` expand to the full network; :meth:`set_state` and
    :meth:`set_cables` take full arrays and raise :class:`NotSymmetric` (changing nothing) when
    they are not symmetric, which is the cue for :class:`~solver.simulate.simulation.Simulation` to
    expand the run to ``full3d``."""
    name = 'sym3d'

    def __init__(self, network, f_ext=None, effects=extras.NONE, striker_state=None,
                 reduced=None):
        self.network = network
        self.effects = effects
        self.reduced = red = reduced if reduced is not None else reduce_network(network)
        self._cos = ROT_C[red.node_rot]            # full node p is R(angle_p) x[node_rep[p]]
        self._sin = ROT_S[red.node_rot]
        self._rep = np.ascontiguousarray(red.node_rep, dtype=np.int64)
        f_full = np.zeros((network.n_nodes, 3)) if f_ext is None else np.asarray(f_ext, float)
        f_red = self._reduce(f_full, 'external forces')
        # state summary on the reduced state: each reduced node and cable stands for as many
        # full ones as map to it, a level's height is that of one of its nodes (rotations about
        # z keep z). A massive bar joins two representatives without rotation (reduce_network
        # refuses any other), so its kinetic energy is that of each of the three bars it stands
        # for. Exact only with every level one orbit; otherwise there is none.
        levels = network.levels
        summ = None
        if not levels.size or np.all(red.node_rep[levels] == red.node_rep[levels[:, :, :1]]):
            massive = np.asarray(red.bar_mass) != 0
            summ = summary.summary_arrays(
                red.x0, red.node_mass, red.clamped,
                np.ascontiguousarray(red.bar_a[massive]), np.ascontiguousarray(red.bar_b[massive]),
                3.0 * np.asarray(red.bar_mass)[massive],
                np.ascontiguousarray(red.node_rep[levels[:, :, :1]], dtype=np.int64)
                if levels.size else np.zeros((0, 0, 1), dtype=np.int64), len(red.cable_a),
                node_mult=np.bincount(red.node_rep, minlength=red.n_nodes).astype(np.float64),
                cable_mult=np.bincount(red.cable_map,
                                       minlength=len(red.cable_a)).astype(np.float64))
        self.rec, self.data, self.work = extras.build(
            network, red.topology(), np.array(red.x0), red.cable_rest_length, red.cable_EA,
            f_red, summ, effects, red, striker_state)
        self.exact = summ is not None

    def _expand(self, a):
        """Full (n_nodes, 3) array of a reduced one (a new array; rotations about z only)."""
        out = np.empty((len(self._rep), 3))
        _expand_kernel(np.ascontiguousarray(a, dtype=np.float64), self._rep, self._cos, self._sin,
                       out)
        return out

    def expansion(self):
        """How a state expands to the full network (:func:`solver.kernels.laneview.frame_rows`):
        ``(rep, cos, sin, rotate, cable_map)``, as :meth:`_expand` and the cable properties
        read it."""
        return (self._rep, self._cos, self._sin, True,
                np.ascontiguousarray(self.reduced.cable_map, dtype=np.int64))

    def _reduce(self, a_full, what, tol=1e-12):
        """Representative rows of a full (n_nodes, 3) array; :class:`NotSymmetric` if the array
        differs from its symmetric expansion by more than ``tol`` of its largest entry."""
        a_full = np.asarray(a_full, dtype=np.float64)
        a = a_full[self.reduced.reps]
        scale = max(float(np.max(np.abs(a_full), initial=0.0)), 1e-300)
        if np.max(np.abs(self._expand(a) - a_full), initial=0.0) > tol * scale:
            raise NotSymmetric(f'{what} are not 3-fold symmetric')
        return a

    def positions(self):
        """Full node positions (n_nodes, 3) m (a new array)."""
        return self._expand(self.x)

    def velocities(self):
        """Full node velocities (n_nodes, 3) m/s (a new array)."""
        return self._expand(self.v)

    def set_state(self, x, v):
        """Load full positions and velocities (n_nodes, 3); :class:`NotSymmetric` if asymmetric."""
        xr = self._reduce(x, 'positions')
        vr = self._reduce(v, 'velocities')
        self.data.x[:len(xr)] = xr     # rows beyond the orbits: strikers (solver.kernels.contact)
        self.data.v[:len(vr)] = vr

    @property
    def cable_rest_length(self):
        """Full (n_cables,) rest lengths, m (a new array)."""
        return self.data.rest[self.reduced.cable_map]

    @property
    def cable_EA(self):
        return self.data.EA[self.reduced.cable_map]

    def set_cables(self, rest, EA):
        """Load full (n_cables,) rest lengths m and EA N; :class:`NotSymmetric` if asymmetric."""
        cmap = self.reduced.cable_map
        rest = np.asarray(rest, dtype=np.float64)
        EA = np.asarray(EA, dtype=np.float64)
        r_red = np.zeros(len(self.data.rest))
        e_red = np.zeros(len(self.data.EA))
        r_red[cmap] = rest
        e_red[cmap] = EA
        for full, red, what in ((rest, r_red, 'cable rest lengths'), (EA, e_red, 'cable EA')):
            if np.max(np.abs(red[cmap] - full), initial=0.0) > 1e-12 * np.max(np.abs(full)):
                raise NotSymmetric(f'{what} are not 3-fold symmetric')
        self.data.rest[:] = r_red
        self.data.EA[:] = e_red
