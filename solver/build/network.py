"""Network: the fixed, read-only description of a tensegrity network.

A network is a set of pin-jointed nodes joined by rigid members (bars and rigid base edges:
holonomic
length constraints) and tension-only elastic cables. Everything in a :class:`Network` is fixed for
a run;
the only things a command may change (cable rest lengths and stiffnesses) are copied into the
simulation
state. All arrays are read-only (``writeable=False``) so no kernel can corrupt the model.

Shapes and units (SI):

- ``x0`` (n_nodes, 3) m: reference positions; ``node_mass`` (n_nodes,) kg: lumped masses.
- ``clamped`` (n_nodes,) bool.
- ``bar_a``/``bar_b`` (n_bars,) int64, ``bar_mass`` (n_bars,) kg.
- ``edge_a``/``edge_b`` (n_edges,) int64: rigid edges (rigid bases), massless.
- ``cable_a``/``cable_b`` (n_cables,) int64, ``cable_rest_length`` (n_cables,) m,
  ``cable_EA`` (n_cables,) N; stiffness ``k = EA / L``.
- Constraints (bars then rigid edges, minus those whose two nodes are clamped), in banded order:
  ``con_tail``/``con_head`` (n_con,) int64, ``con_length`` (n_con,) m, ``con_coef`` (n_con, bw +
  1):
  ``A[c, c - k] = con_coef[c, k] * (b_c . b_{c-k})`` is the constraint matrix ``J W J^T``.
- Inverse mass operator ``W`` (node-wise, the same for x, y and z): ``w_diag`` (n_nodes,) 1/kg,
  ``partner`` (n_nodes,) int64 (-1 if none) and ``w_off`` (n_nodes,): ``(W f)_p = w_diag[p] f_p +
  w_off[p] f_partner[p]``. Partners come from massive bars (2x2 rod block); clamped nodes have ``w
  = 0``.
- Massive bars that share nodes (class k for the masses, e.g. columns on shared bases): the
  inverse mass is not node-local; ``kkt`` holds the layout of the banded saddle-point system of
  :mod:`solver.kernels.massmatrix` (empty arrays otherwise), and ``w_diag`` is then only the
  inverse of the diagonal of M (used for nothing but the constraint ordering).
- ``levels`` (n_columns, n_levels, 3) int64: node indices of each base level of each column (empty
for
  networks that are not columns); ``h0`` m: reference prism height.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import reverse_cuthill_mckee

from solver.build import memo
from solver.kernels import massmatrix
from solver.kernels import records


class NetworkError(ValueError):
    """A network description that cannot be simulated (bad index, zero mass, degenerate member)."""


def read_only_copy(a, dtype):
    a = np.array(a, dtype=dtype, copy=True)
    a.setflags(write=False)
    return a


_ro = read_only_copy


def length_of(array):
    """A read-only property: the length of the record's array ``array`` (``n_nodes``, ...)."""
    return property(lambda self: len(getattr(self, array)), doc=f'len({array})')


@dataclass(frozen=True)
class Network:
    x0: np.ndarray
    node_mass: np.ndarray
    clamped: np.ndarray
    bar_a: np.ndarray
    bar_b: np.ndarray
    bar_mass: np.ndarray
    edge_a: np.ndarray
    edge_b: np.ndarray
    cable_a: np.ndarray
    cable_b: np.ndarray
    cable_rest_length: np.ndarray
    cable_EA: np.ndarray
    cable_kind: tuple
    w_diag: np.ndarray
    partner: np.ndarray
    w_off: np.ndarray
    con_tail: np.ndarray
    con_head: np.ndarray
    con_length: np.ndarray
    con_coef: np.ndarray
    bandwidth: int
    levels: np.ndarray
    h0: float
    meta: dict = field(default_factory=dict)
    kkt: tuple = massmatrix.NO_KKT

    n_nodes = length_of('x0')
    n_bars = length_of('bar_a')
    n_edges = length_of('edge_a')
    n_cables = length_of('cable_a')
    n_constraints = length_of('con_tail')

    @property
    def n_columns(self):
        return self.levels.shape[0]

    @property
    def n_prisms(self):
        return max(self.levels.shape[1] - 1, 0)

    @staticmethod
    def build(x0, node_mass, bars, cables, cable_rest_length, cable_EA, *, rigid_edges=(),
              clamped=(), bar_mass=None, cable_kind=None, levels=None, h0=0.0, meta=None):
        """Validate a network description and derive the solver arrays.

        ``bars``, ``rigid_edges`` and ``cables`` are sequences of (tail, head) node index pairs;
        ``clamped`` a sequence of node indices; ``bar_mass`` (n_bars,) kg or None (massless bars).
        """
        x0 = np.asarray(x0, dtype=np.float64)
        if x0.ndim != 2 or x0.shape[1] != 3 or len(x0) == 0:
            raise NetworkError('nodes must be an (n, 3) array of positions')
        n = len(x0)
        node_mass = np.broadcast_to(np.asarray(node_mass, dtype=np.float64), (n,))
        bars = np.asarray(bars, dtype=np.int64).reshape(-1, 2)
        edges = np.asarray(rigid_edges, dtype=np.int64).reshape(-1, 2)
        cables = np.asarray(cables, dtype=np.int64).reshape(-1, 2)
        for name, pairs in (('bars', bars), ('rigid_edges', edges), ('cables', cables)):
            if pairs.size and (pairs.min() < 0 or pairs.max() >= n):
                raise NetworkError(f'{name}: node index out of range 0..{n - 1}')
            if pairs.size and np.any(pairs[:, 0] == pairs[:, 1]):
                raise NetworkError(f'{name}: a member joins a node to itself')
        rest = np.broadcast_to(np.asarray(cable_rest_length, dtype=np.float64), (len(cables),))
        EA = np.broadcast_to(np.asarray(cable_EA, dtype=np.float64), (len(cables),))
        if np.any(~np.isfinite(rest)) or np.any(rest <= 0):
            raise NetworkError('cable rest lengths must be positive')
        if np.any(~np.isfinite(EA)) or np.any(EA <= 0):
            raise NetworkError('cable EA must be positive')
        is_clamped = np.zeros(n, dtype=bool)
        is_clamped[np.asarray(clamped, dtype=np.int64)] = True
        bar_mass = (np.zeros(len(bars)) if bar_mass is None
                    else np.broadcast_to(np.asarray(bar_mass, dtype=np.float64), (len(bars),)))
        if np.any(bar_mass < 0) or np.any(node_mass < 0):
            raise NetworkError('masses must be non-negative')

        w_diag, partner, w_off, members, length, bw, coef, kkt = memo.lookup(
            'constraints', (x0, node_mass, is_clamped, bars, bar_mass, edges),
            lambda: _constraints(x0, node_mass, is_clamped, bars, bar_mass, edges))
        if levels is None:
            levels = np.zeros((0, 0, 3), dtype=np.int64)
        kind = tuple(cable_kind) if cable_kind is not None else ('cable',) * len(cables)
        return Network(
            x0=_ro(x0, np.float64), node_mass=_ro(node_mass, np.float64),
            clamped=_ro(is_clamped, bool),
            bar_a=_ro(bars[:, 0], np.int64), bar_b=_ro(bars[:, 1], np.int64),
            bar_mass=_ro(bar_mass, np.float64),
            edge_a=_ro(edges[:, 0], np.int64), edge_b=_ro(edges[:, 1], np.int64),
            cable_a=_ro(cables[:, 0], np.int64), cable_b=_ro(cables[:, 1], np.int64),
            cable_rest_length=_ro(rest, np.float64), cable_EA=_ro(EA, np.float64),
            cable_kind=kind,
            w_diag=_ro(w_diag, np.float64), partner=_ro(partner, np.int64),
            w_off=_ro(w_off, np.float64),
            con_tail=_ro(members[:, 0], np.int64), con_head=_ro(members[:, 1], np.int64),
            con_length=_ro(length, np.float64), con_coef=_ro(coef, np.float64),
            bandwidth=int(bw), levels=_ro(levels, np.int64), h0=float(h0), meta=dict(meta or {}),
            kkt=kkt)

    def topology(self):
        """The kernels' :class:`~solver.kernels.records.Topology` of this network (no rotated
        members)."""
        return records.Topology(
            self.w_diag, self.partner, self.w_off, self.con_tail, self.con_head, self.con_length,
            self.con_coef, self.cable_a, self.cable_b, records.NO_ROT, records.NO_ROT,
            records.NO_COEF3, self.kkt)

    def gravity_mass(self):
        """Mass (n_nodes,) kg on which uniform gravity acts at each node: the lumped mass plus
        half of each bar's mass at each of its ends (the consistent load of a uniform rod)."""
        m = np.array(self.node_mass, dtype=np.float64)
        if np.any(self.bar_mass):
            np.add.at(m, self.bar_a, 0.5 * self.bar_mass)
            np.add.at(m, self.bar_b, 0.5 * self.bar_mass)
        return m

    @property
    def total_mass(self):
        """Sum of the entries of the mass matrix (clamped nodes included), kg."""
        return float(np.sum(self.node_mass) + np.sum(self.bar_mass))


def inverse_mass(node_mass, clamped, bars, bar_mass):
    """Inverse of the mass matrix ``diag(m) + sum_bars rod blocks``, restricted to free nodes.

    A massive bar adds the rod block ``[[m/3, m/6], [m/6, m/3]]`` on its two nodes, so a node may
    belong
    to at most one massive bar (class-1 for the massive bars) for the inverse to stay node-local.
    """
    n = len(node_mass)
    m_diag = node_mass.copy()
    partner = -np.ones(n, dtype=np.int64)
    m_off = np.zeros(n)
    for (a, b), mb in zip(bars, bar_mass):
        if mb == 0:
            continue
        for p, q in ((a, b), (b, a)):
            if partner[p] >= 0:
                raise NetworkError(
                    f'node {p} is shared by two massive bars; bar masses need class-1 bars '
                    '(set bar_mass to 0 for networks with shared bar nodes)')
            partner[p] = q
            m_diag[p] += mb / 3.0
            m_off[p] = mb / 6.0
    w_diag = np.zeros(n)
    w_off = np.zeros(n)
    for p in range(n):
        if clamped[p]:
            continue
        q = partner[p]
        if q >= 0 and not clamped[q]:
            det = m_diag[p] * m_diag[q] - m_off[p] * m_off[q]
            w_diag[p] = m_diag[q] / det
            w_off[p] = -m_off[p] / det
        else:
            if m_diag[p] <= 0:
                raise NetworkError(f'free node {p} has no mass')
            w_diag[p] = 1.0 / m_diag[p]
    partner = np.where(w_off != 0, partner, -1)
    return w_diag, partner, w_off


def diagonal_inverse_mass(node_mass, clamped, bars, bar_mass):
    """For networks on the mass-matrix path: ``1 / M_pp`` on free nodes (no partners) and the
    entries of M restricted to free nodes (:func:`solver.kernels.massmatrix.mass_entries`)."""
    mp, mq, mv, diag = massmatrix.mass_entries(node_mass, clamped, bars, bar_mass)
    n = len(node_mass)
    w_diag = np.zeros(n)
    for p in range(n):
        if clamped[p]:
            continue
        if not diag[p] > 0:
            raise NetworkError(f'free node {p} has no mass')
        w_diag[p] = 1.0 / diag[p]
    return w_diag, -np.ones(n, dtype=np.int64), np.zeros(n), (mp, mq, mv)


def _adjacency(members, partner):
    """Constraint-constraint adjacency: two constraints couple when they share a node or touch the
    two nodes of one massive bar (one mass block)."""
    index = np.arange(len(partner))
    group = np.where(partner >= 0, np.minimum(index, partner), index)
    by_node = [[] for _ in range(len(partner))]
    for c, (t, h) in enumerate(members):
        by_node[group[t]].append(c)
        if group[h] != group[t]:
            by_node[group[h]].append(c)
    rows, cols = [], []
    for cs in by_node:
        for c in cs:
            for d in cs:
                rows.append(c)
                cols.append(d)
    m = len(members)
    return csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(m, m))


def _bandwidth(adj, order):
    if adj.nnz == 0:
        return 0
    pos = np.empty(len(order), dtype=np.int64)
    pos[order] = np.arange(len(order))
    coo = adj.tocoo()
    return int(np.max(np.abs(pos[coo.row] - pos[coo.col])))


def band_order(members, partner):
    """Order constraints for a narrow band: the builder's order, level by level (sorted by lowest
    node), or reverse Cuthill-McKee, whichever is narrowest."""
    m = len(members)
    if m == 0:
        return np.arange(0, dtype=np.int64), 0
    adj = _adjacency(members, partner)
    candidates = [np.arange(m),
                  np.lexsort((members.max(axis=1), members.min(axis=1))),
                  reverse_cuthill_mckee(adj, symmetric_mode=True).astype(np.int64)]
    widths = [_bandwidth(adj, order) for order in candidates]
    best = int(np.argmin(widths))
    return candidates[best], widths[best]


def _coupling(members, w_diag, partner, w_off, bw):
    """``coef[c, k] = sum_{p in c, q in d} s_c(p) s_d(q) W_pq`` for d = c - k (s: head +1,
    tail -1)."""
    m = len(members)
    coef = np.zeros((m, bw + 1))
    for c in range(m):
        for k in range(min(c, bw) + 1):
            d = c - k
            total = 0.0
            for p, sp in ((members[c, 1], 1.0), (members[c, 0], -1.0)):
                for q, sq in ((members[d, 1], 1.0), (members[d, 0], -1.0)):
                    if p == q:
                        total += sp * sq * w_diag[p]
                    elif partner[p] == q:
                        total += sp * sq * w_off[p]
            coef[c, k] = total
    return coef


def _constraints(x0, node_mass, is_clamped, bars, bar_mass, edges):
    """The mass-weighted constraint structure of a network: inverse mass (or the KKT layout of
    massive bars), the free rigid members in band order, their lengths, bandwidth and coupling
    coefficients. It depends on the geometry, masses and members only (not on the cables), so
    the points of a sweep that differ in prestrain or impact share it (:mod:`solver.build.memo`,
    inside a batch)."""
    class_k = massmatrix.needs_kkt(bars, bar_mass)
    if class_k:
        w_diag, partner, w_off, mass = diagonal_inverse_mass(node_mass, is_clamped, bars,
                                                              bar_mass)
    else:
        w_diag, partner, w_off = inverse_mass(node_mass, is_clamped, bars, bar_mass)

    members = np.concatenate([bars, edges]) if len(edges) else bars
    length = np.linalg.norm(x0[members[:, 1]] - x0[members[:, 0]], axis=1)
    if np.any(length <= 0):
        raise NetworkError('a rigid member has zero length')
    free = ~(is_clamped[members[:, 0]] & is_clamped[members[:, 1]])
    members, length = members[free], length[free]
    order, bw = band_order(members, partner)
    members, length = members[order], length[order]
    coef = _coupling(members, w_diag, partner, w_off, bw)
    if len(members) and np.any(coef[:, 0] <= 0):
        raise NetworkError('a rigid member has no free mass at either end')

    kkt = massmatrix.NO_KKT
    if class_k:
        node_u, con_u, dims = massmatrix.layout(len(x0), is_clamped, members, mass[0], mass[1],
                                                x0)
        mass_p, mass_q, mass_val = mass
        kkt = massmatrix.KKT(*(_ro(a, a.dtype) for a in (node_u, con_u, mass_p, mass_q, mass_val,
                                                          dims)))
    return w_diag, partner, w_off, members, length, bw, coef, kkt
