"""Builders: networks from a few parameters (docs/physics.md sections 2 and 3).

- :func:`column`: ``n_columns`` columns of ``n_prisms`` right-handed minimal triangular prisms
stacked on
  shared bases, flexible (FB) or rigid (RB) bases; a single prism is ``n_prisms=1``.
- :func:`explicit`: any network given as nodes, bars, cables (and optional rigid edges).

To add a structure: write a function returning a :class:`~solver.build.network.Network` whose cable
rest lengths put it at rest (check 1 of docs/physics.md section 7), register it in
:data:`BUILDERS`, and list its parameters with their defaults in
:data:`solver.build.scene.STRUCTURE_DEFAULTS`.
"""
from __future__ import annotations

import math

import numpy as np

from solver.build import memo
from solver.build.network import Network, NetworkError

PHI0 = 5.0 * math.pi / 6.0   # self-equilibrated twist of the minimal triangular prism


def cross_prestrain_rest(length, p):
    """Rest length of a cable of current length ``length`` at prestrain ``p = (s - L) / L``."""
    return length / (1.0 + p)


def rest_for_tension(length, EA, tension):
    """Rest length ``L`` with ``EA (length - L) / L = tension``."""
    return EA * length / (EA + tension)


def column(n_prisms=50, radius=0.005, h0=0.0062, cable_E=5.48e6, cable_radius=1.4e-4,
           unit_mass=0.0249, bar_mass=0.0, prestrain=0.002, bases='flexible', stacking='shared',
           rigid_bases_as='edges', kappa=100.0, n_columns=1, column_spacing=0.03,
           clamped_levels=(0,), handedness='right', bar_mass_fraction=0.0,
           mass_placement='level', end_mass=0.0):
    """Columns of tensegrity prisms along z (docs/physics.md section 3).

    Level j of column c (j = 0..n_prisms) holds nodes ``3 j + k`` (+ ``c * 3 (n_prisms + 1)``) at
    ``(r cos(j phi0 + 2 pi k / 3) + c * spacing, r sin(...), j h0)``. Bars ``(j, k) -> (j+1, k)``,
    cross
    cables ``(j, k) -> (j+1, (k-1) mod 3)`` (``k+1`` when left-handed), base cables ``(j, k) -> (j,
    k+1)``. Cross cables get
    prestrain ``p``; base cables get the tension of the prism self-stress ``t_l = gamma_s r``
    (twice at
    interior levels with ``stacking='shared'``; one cable per prism with ``stacking='parallel'``).
    Rigid bases are rigid edges (``rigid_bases_as='edges'``) or base cables with EA x ``kappa``.
    Masses (:func:`column_masses`): ``unit_mass`` kg per prism, of which ``bar_mass_fraction``
    is in the prism's three bars (uniform rods) and the rest lumped on base nodes, a third per
    node, by ``mass_placement``: ``'level'`` one unit per level (level 0 keeps a whole unit: no
    prism below it has bars), ``'unit_bases'`` half of each prism on each of its two bases (the
    end levels carry half a unit). ``bar_mass`` kg is added to every bar, ``end_mass`` kg to the
    free end level (the last one), shared by its three nodes.
    """
    if n_prisms < 1 or n_columns < 1:
        raise NetworkError('n_prisms and n_columns must be at least 1')
    sign = 1.0 if handedness == 'right' else -1.0
    phi0 = sign * PHI0
    cross = -1 if handedness == 'right' else 1     # mirror image: cross cables to (k + 1) mod 3
    n_levels = n_prisms + 1
    EA = cable_E * math.pi * cable_radius ** 2
    per_col = 3 * n_levels
    x = np.zeros((n_columns * per_col, 3))
    bars, cables, edges, kinds = [], [], [], []
    cable_EA, cable_rest = [], []
    levels = np.zeros((n_columns, n_levels, 3), dtype=np.int64)

    def node(c, j, k):
        return c * per_col + 3 * j + (k % 3)

    for c in range(n_columns):
        for j in range(n_levels):
            for k in range(3):
                t = j * phi0 + 2.0 * math.pi * k / 3.0
                x[node(c, j, k)] = (radius * math.cos(t) + c * column_spacing,
                                    radius * math.sin(t), j * h0)
                levels[c, j, k] = node(c, j, k)

    # cross-cable geometry is the same in every prism: s, rest length, force density
    s_len = np.linalg.norm(x[node(0, 1, cross)] - x[node(0, 0, 0)])
    L_s = cross_prestrain_rest(s_len, prestrain)
    gamma_s = EA * (s_len - L_s) / (L_s * s_len)
    t_l = gamma_s * radius
    side = math.sqrt(3.0) * radius
    rigid = bases == 'rigid'
    base_EA = EA * kappa if (rigid and rigid_bases_as == 'stiff_cables') else EA

    for c in range(n_columns):
        for j in range(n_levels):
            if j < n_prisms:
                for k in range(3):
                    bars.append((node(c, j, k), node(c, j + 1, k)))
                for k in range(3):
                    cables.append((node(c, j, k), node(c, j + 1, k + cross)))
                    cable_EA.append(EA)
                    cable_rest.append(L_s)
                    kinds.append('cross')
            n_adjacent = 2 if 0 < j < n_prisms else 1
            for k in range(3):
                a, b = node(c, j, k), node(c, j, k + 1)
                if rigid and rigid_bases_as == 'edges':
                    edges.append((a, b))
                elif stacking == 'parallel':
                    for _ in range(n_adjacent):
                        cables.append((a, b))
                        cable_EA.append(base_EA)
                        cable_rest.append(rest_for_tension(side, base_EA, t_l))
                        kinds.append('base')
                else:
                    cables.append((a, b))
                    cable_EA.append(base_EA)
                    cable_rest.append(rest_for_tension(side, base_EA, n_adjacent * t_l))
                    kinds.append('base')

    clamped = [node(c, j, k) for c in range(n_columns) for j in clamped_levels for k in range(3)]
    node_mass, bar_masses = column_masses(levels, len(x), unit_mass, bar_mass, bar_mass_fraction,
                                          mass_placement, end_mass, clamped)
    meta = dict(builder='column', n_prisms=n_prisms, radius=radius, h0=h0, EA=EA,
                prestrain=prestrain,
                bases=bases, stacking=stacking, rigid_bases_as=rigid_bases_as, kappa=kappa,
                cross_length=s_len, cross_rest_length=L_s, gamma_s=gamma_s, base_tension=t_l,
                bar_length=float(np.linalg.norm(x[node(0, 1, 0)] - x[node(0, 0, 0)])),
                unit_mass=unit_mass, twist=phi0, bar_mass_fraction=bar_mass_fraction,
                mass_placement=mass_placement, end_mass=end_mass)
    return Network.build(x, node_mass, bars, cables, cable_rest, cable_EA, rigid_edges=edges,
                         clamped=clamped, bar_mass=bar_masses, cable_kind=kinds, levels=levels,
                         h0=h0,
                         meta=meta)


MASS_PLACEMENTS = ('level', 'unit_bases')


def column_masses(levels, n_nodes, unit_mass, bar_mass=0.0, bar_mass_fraction=0.0,
                  mass_placement='level', end_mass=0.0, clamped=()):
    """Lumped node masses (n_nodes,) kg and bar masses (n_bars,) kg of columns whose levels are
    ``levels`` (n_columns, n_levels, 3) and whose bars are ordered as :func:`column` makes them
    (three per prism, prism by prism, column by column). See :func:`column` for the meaning."""
    if not 0.0 <= bar_mass_fraction < 1.0:
        raise NetworkError(f'bar_mass_fraction: {bar_mass_fraction!r} is outside [0, 1)')
    if mass_placement not in MASS_PLACEMENTS:
        raise NetworkError(f'mass_placement: {mass_placement!r} is not one of '
                           f'{", ".join(MASS_PLACEMENTS)}')
    if end_mass < 0 or bar_mass < 0:
        raise NetworkError('end_mass and bar_mass must be non-negative')
    n_columns, n_levels = levels.shape[0], levels.shape[1]
    n_prisms = n_levels - 1
    lumped = (1.0 - bar_mass_fraction) * unit_mass        # per prism, on base nodes
    node_mass = np.full(n_nodes, lumped / 3.0)
    if mass_placement == 'level':
        node_mass[levels[:, 0].ravel()] = unit_mass / 3.0
    else:
        node_mass[levels[:, 0].ravel()] = 0.5 * lumped / 3.0
        node_mass[levels[:, -1].ravel()] = 0.5 * lumped / 3.0
    if end_mass:
        end = levels[:, -1].ravel()
        if np.any(np.isin(end, np.asarray(clamped, dtype=np.int64))):
            raise NetworkError('end_mass: the end level is clamped (the extra mass belongs on '
                               'the free, impacted end)')
        node_mass[end] += end_mass / 3.0
    bars = np.full(3 * n_prisms * n_columns, bar_mass + bar_mass_fraction * unit_mass / 3.0)
    return node_mass, bars


def explicit(nodes, bars, cables, node_mass, cable_EA, cable_rest_length=None, prestrain=None,
             rigid_edges=(), clamped=(), bar_mass=0.0):
    """A network given member by member. Cable rest lengths are given, or follow from a prestrain
    applied to the given geometry (the geometry must then be an equilibrium for that prestress)."""
    nodes = np.asarray(nodes, dtype=np.float64)
    cables_arr = np.asarray(cables, dtype=np.int64).reshape(-1, 2)
    if cable_rest_length is None:
        if prestrain is None:
            raise NetworkError('explicit structure needs cable_rest_length or prestrain')
        if cables_arr.size and (cables_arr.min() < 0 or cables_arr.max() >= len(nodes)):
            raise NetworkError(f'cables: node index out of range 0..{len(nodes) - 1}')
        s = np.linalg.norm(nodes[cables_arr[:, 1]] - nodes[cables_arr[:, 0]], axis=1)
        cable_rest_length = cross_prestrain_rest(s, prestrain)
    return Network.build(nodes, node_mass, bars, cables_arr, cable_rest_length, cable_EA,
                         rigid_edges=rigid_edges, clamped=clamped, bar_mass=bar_mass,
                         meta=dict(builder='explicit'))


BUILDERS = {'column': column, 'prism': column, 'explicit': explicit}


# -- prestrain as an actuator (column networks) ---------------------------------------------------
def prestrain_map(network):
    """The :class:`PrestrainMap` of ``network``; inside :func:`solver.build.memo.sharing` one
    for every network of the same levels, geometry, cables and stacking (the columns of an
    array that a command reaches one by one)."""
    return memo.lookup('prestrain-map', (network.levels, network.x0, network.cable_a,
                                         network.cable_b, str(network.meta.get('stacking'))),
                       lambda: PrestrainMap(network))


class PrestrainMap:
    """Which prism self-stress each cable of a column network carries, from ``network.levels``.

    A prism's self-stress is self-equilibrated in the reference geometry and scales with its cross
    prestrain ``p``, so per-prism values superpose: a cross cable of prism i carries prism i's
    self-stress, an interior shared base cable at level j carries ``t_l(p_{j-1}) + t_l(p_j)``
    (``stacking='parallel'``: the first cable of a side carries prism j-1, the second prism j),
    with ``t_l(p) = gamma_s(p) r`` and ``gamma_s(p) = EA_s p / s`` (docs/physics.md section 2).
    Rigid base edges carry any base force as constraint forces. Prism index: ``column *
    n_prisms + prism``.

    Arrays: ``cross`` (n_cross,) cable indices in cable order (the per-cable command order),
    ``cross_prism`` (n_cross,), ``base`` (n_base,) cable indices, ``base_prisms`` (n_base, 2) prism
    indices (-1 = none), ``length`` (n_cables,) m reference lengths, ``radius`` (n_base,) m,
    ``cross_count`` (n_columns * n_prisms,) cross cables per prism.
    """

    def __init__(self, network):
        if network.levels.size == 0:
            raise ValueError('prestrain needs a column structure (levels)')
        self.n_columns, self.n_prisms = network.n_columns, network.n_prisms
        n_lev = self.n_prisms + 1
        where = -np.ones((network.n_nodes, 2), dtype=np.int64)      # node -> (column, level)
        for c in range(self.n_columns):
            for j in range(n_lev):
                where[network.levels[c, j]] = (c, j)
        x0 = network.x0
        self.length = np.linalg.norm(x0[network.cable_b] - x0[network.cable_a], axis=1)
        cross, cross_prism, base, base_prisms, radius = [], [], [], [], []
        seen = {}
        for i, (a, b) in enumerate(zip(network.cable_a, network.cable_b)):
            (ca, ja), (cb, jb) = where[a], where[b]
            if ca < 0 or cb < 0 or ca != cb:
                raise ValueError(f'prestrain: cable {i} does not belong to one column')
            if abs(ja - jb) == 1:
                cross.append(i)
                cross_prism.append(ca * self.n_prisms + min(ja, jb))
            elif ja == jb:
                below = ca * self.n_prisms + ja - 1 if ja > 0 else -1
                above = ca * self.n_prisms + ja if ja < self.n_prisms else -1
                if network.meta.get('stacking') == 'parallel' and below >= 0 and above >= 0:
                    key = (min(a, b), max(a, b))
                    first = key not in seen
                    seen[key] = True
                    below, above = (below, -1) if first else (-1, above)
                base.append(i)
                base_prisms.append((below, above))
                centre = x0[network.levels[ca, ja]].mean(axis=0)
                radius.append(np.linalg.norm(x0[a] - centre))
            else:
                raise ValueError(f'prestrain: cable {i} spans more than one prism')
        self.cross = np.array(cross, dtype=np.int64)
        self.cross_prism = np.array(cross_prism, dtype=np.int64)
        self.base = np.array(base, dtype=np.int64)
        self.base_prisms = np.array(base_prisms, dtype=np.int64).reshape(-1, 2)
        self.radius = np.array(radius)
        counts = np.bincount(self.cross_prism, minlength=self.n_columns * self.n_prisms)
        if np.any(counts == 0):
            raise ValueError('prestrain: a prism has no cross cable')
        self.cross_count = counts

    def rest_lengths(self, p, cable_EA, out=None):
        """Cable rest lengths (n_cables,) m that keep the reference geometry in equilibrium at the
        per-prism cross prestrain ``p`` (n_columns, n_prisms); ``cable_EA`` (n_cables,) N."""
        p = np.asarray(p, dtype=np.float64).reshape(-1)
        rest = np.empty(len(self.length)) if out is None else out
        s = self.length[self.cross]
        rest[self.cross] = s / (1.0 + p[self.cross_prism])
        # gamma_s per prism: mean over its cross cables of EA p / s
        weights = cable_EA[self.cross] * p[self.cross_prism] / s
        gamma = np.bincount(self.cross_prism, weights=weights, minlength=len(p)) / self.cross_count
        g_ext = np.append(gamma, 0.0)               # index -1 -> no prism
        t = (g_ext[self.base_prisms[:, 0]] + g_ext[self.base_prisms[:, 1]]) * self.radius
        EA_b = cable_EA[self.base]
        rest[self.base] = EA_b * self.length[self.base] / (EA_b + t)
        return rest


def build_network(scene):
    """The :class:`~solver.build.network.Network` a scene describes."""
    s, m = scene.structure, scene.materials
    if s.builder == 'column':
        return column(
            n_prisms=s.n_prisms, radius=s.radius, h0=s.h0, cable_E=m.cable_E,
            cable_radius=m.cable_radius, unit_mass=m.unit_mass, bar_mass=m.bar_mass,
            prestrain=scene.prestrain, bases=s.bases, stacking=s.stacking,
            rigid_bases_as=s.rigid_bases_as, kappa=s.kappa, n_columns=s.n_columns,
            column_spacing=s.column_spacing, clamped_levels=tuple(s.clamped_levels),
            handedness=s.handedness, bar_mass_fraction=m.bar_mass_fraction,
            mass_placement=s.mass_placement, end_mass=m.end_mass)
    EA = m.cable_E * math.pi * m.cable_radius ** 2
    rest = None if s.cable_rest_length is None else list(s.cable_rest_length)
    return explicit([list(p) for p in s.nodes], [list(b) for b in s.bars],
                    [list(c) for c in s.cables], s.node_mass, EA, cable_rest_length=rest,
                    prestrain=None if rest is not None else scene.prestrain,
                    rigid_edges=[list(e) for e in s.rigid_edges], clamped=list(s.clamped),
                    bar_mass=m.bar_mass)
