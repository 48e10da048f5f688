"""What a scene switches on of the effects (cable damping, prism stops, strikers, bar contact:
:mod:`solver.kernels.contact`, :mod:`solver.kernels.barcontact`), as :class:`Effects`, and the
one builder of a model's records (:func:`build`, :mod:`solver.kernels.records`): the effects join
the model record when it is built, the strikers' rows join the state, topology, forces and
summary."""
import math
from dataclasses import dataclass, replace

import numpy as np

from solver.kernels import barcontact
from solver.kernels import records as rec
from solver.build import memo


def bar_pairs(network):
    """The pairs of bars that can touch, as full node indices (n_pairs, 4) ``a_lo, a_hi, b_lo,
    b_hi`` (lower level first): the three pairs of each prism's bars, and each bar of a prism
    against the bars of the prism above that do not share its node (where a flattened prism's
    bars meet its neighbour's). None without prisms."""
    levels = np.asarray(network.levels)
    if not levels.size or not network.n_bars:
        return None
    level_of = {}
    for c in range(levels.shape[0]):
        for j in range(levels.shape[1]):
            for n in levels[c, j]:
                level_of[int(n)] = (c, j)
    prisms = {}
    for a, b in zip(np.asarray(network.bar_a), np.asarray(network.bar_b)):
        (ca, ja), (cb, jb) = level_of[int(a)], level_of[int(b)]
        if ca != cb or abs(ja - jb) != 1:
            continue
        lo, hi = (int(a), int(b)) if ja < jb else (int(b), int(a))
        prisms.setdefault((ca, min(ja, jb)), []).append((lo, hi))
    pairs = []
    for (c, j), bars in prisms.items():
        pairs += [bars[i] + bars[k] for i in range(len(bars)) for k in range(i + 1, len(bars))]
        pairs += [a + b for a in bars for b in prisms.get((c, j + 1), ()) if not set(a) & set(b)]
    return np.array(pairs, dtype=np.int64).reshape(-1, 4) if pairs else None


def _read_only(a):
    if a is not None:
        a.setflags(write=False)
    return a


def _bar_contact(scene, network):
    """``(pairs, diameter m, Hertz k, smallest node mass kg)`` of the scene's bar contact
    (:mod:`solver.kernels.barcontact`), or ``(None, 0, 0, 0)`` with ``contact.bars: none`` or no
    prisms."""
    pairs = None
    if scene.contact.bars != 'none':         # one search per topology inside a batch
        pairs = memo.lookup('bar-pairs', (network.levels, network.bar_a, network.bar_b),
                            lambda: _read_only(bar_pairs(network)))
    if pairs is None:
        return None, 0.0, 0.0, 0.0
    mat = scene.materials
    mass = np.asarray(network.node_mass)[~np.asarray(network.clamped, bool)]
    mass = mass[mass > 0]
    m_min = float(mass.min()) if mass.size else float(network.total_mass) / network.n_nodes
    return (pairs, 2.0 * mat.bar_radius,
            barcontact.hertz_constant(mat.bar_radius, mat.bar_E, mat.bar_poisson), m_min)


def _model_pairs(pairs, reduced):
    """``pairs`` (full node indices) as the kernel's (n, 8) node/rotation rows of a model: all
    rotations 0 in ``full3d``; in ``sym3d`` one pair per orbit of three under the rotation (its
    ends as representatives and rotations), and the energy multiplicity 3 (found once per
    topology inside :func:`solver.build.memo.sharing`)."""
    if reduced is None:
        rows = np.zeros((len(pairs), 8), dtype=np.int64)
        rows[:, 0::2] = pairs
        return rows, 1.0
    rep, rot = np.asarray(reduced.node_rep), np.asarray(reduced.node_rot)
    rows = memo.lookup('pairs', (np.asarray(pairs), rep, rot),
                       lambda: _reduced_pairs(pairs, rep, rot))
    return rows.copy(), 3.0


def _reduced_pairs(pairs, rep, rot):
    node = {(int(rep[n]), int(rot[n])): n for n in range(len(rep))}

    def image(n):                       # the node R x_n
        return node[(int(rep[n]), (int(rot[n]) + 1) % 3)]

    seen, rows = set(), []
    for pair in pairs:
        pair = tuple(int(n) for n in pair)
        key = frozenset((pair[:2], pair[2:]))
        if key in seen:
            continue
        img = pair
        for _ in range(3):
            seen.add(frozenset((img[:2], img[2:])))
            img = tuple(image(n) for n in img)
        rows.append([v for n in pair for v in (rep[n], rot[n])])
    return np.array(rows, dtype=np.int64).reshape(-1, 8)


def cable_damping(scene, network):
    """Per-cable damping coefficients (n_cables,) N s/m of a scene, or None when zero:
    ``materials.cable_damping`` for every cable, or from ``materials.cable_damping_ratio`` zeta as
    ``c = 2 zeta sqrt(k m)``, ``k = EA / L`` of the cable and ``m`` the unit mass."""
    mat = scene.materials
    c, zeta = float(mat.cable_damping), float(mat.cable_damping_ratio)
    if c > 0:
        return np.full(network.n_cables, c)
    if zeta > 0:
        k = np.asarray(network.cable_EA) / np.asarray(network.cable_rest_length)
        return 2.0 * zeta * np.sqrt(k * float(mat.unit_mass))
    return None


def stop_heights(network, tolerance):
    """Height m of each prism's stop (n_columns, n_prisms): the rigid-base lock
    ``sqrt(b^2 - 4 r^2)`` (twist 180 deg, the bars meet on the axis) plus ``tolerance * h0``;
    flexible bases (no rigid edges): ``tolerance * h0`` (the two bases meet)."""
    meta = network.meta
    h0 = float(network.h0)
    lock = 0.0
    if network.n_edges > 0:
        b, r = float(meta['bar_length']), float(meta['radius'])
        lock = math.sqrt(max(b * b - 4.0 * r * r, 0.0))
    stop = lock + tolerance * h0
    if not stop < h0:
        raise ValueError(f'contact.tolerance: {tolerance:g} puts the stop at {stop:.4g} m, not '
                         f'below the prism height h0 = {h0:.4g} m (the stops would push at rest)')
    return np.full((network.n_columns, network.n_prisms), stop)


@dataclass(frozen=True)
class Effects:
    """What a scene switches on of the effects (:mod:`solver.kernels.contact`,
    :mod:`solver.kernels.barcontact`), on the full network, for :func:`build`: ``damp`` (n_cables,)
    N s/m or None, ``stop_h`` (n_columns, n_prisms) m or None and ``k_stop`` N/m, ``strikers``
    (one per column) with their contact law (``striker_k``, ``striker_expo``), ``striker_mass``
    kg, the scene's ``gravity`` m/s^2 and ``m_eff`` kg; ``pairs`` (full
    node indices (n, 4), :func:`bar_pairs`) or None with the bars' ``diameter`` m, Hertz ``k``,
    ``m_min`` kg; ``resolution``, the steps per contact duration of strikers and bars alike; the
    ledger's ``energy_rate`` per second and whether steps after a contact are checked against it
    (``refine``)."""
    damp: np.ndarray | None = None
    stop_h: np.ndarray | None = None
    k_stop: float = 0.0
    strikers: bool = False
    striker_k: float = 0.0
    striker_expo: float = 1.0
    striker_mass: float = 0.0
    gravity: float = 0.0
    m_eff: float = 0.0
    pairs: np.ndarray | None = None
    diameter: float = 0.0
    k: float = 0.0
    m_min: float = 0.0
    resolution: float = 0.0
    energy_rate: float = 0.0
    refine: bool = False
    levels: np.ndarray | None = None        # the levels the effects act on (default: the
    #                                         network's; a network without columns may name some)

    @property
    def active(self):
        """Whether anything is switched on."""
        return (self.damp is not None or self.stop_h is not None or self.strikers
                or self.pairs is not None)

    def without(self, *names):
        """A copy with the effects ``names`` (``'pairs'``, ``'strikers'``) switched off."""
        off = {'pairs': None, 'strikers': False}
        return replace(self, **{name: off[name] for name in names})


NONE = Effects()


def scene_effects(scene, network):
    """The :class:`Effects` a scene switches on for ``network``."""
    imp = scene.loading.impact
    lock = scene.contact.lock != 'none'
    strikers = imp.mode == 'striker'
    if (lock or strikers) and not network.levels.size:
        key = 'contact.lock' if lock else 'loading.impact.mode'
        raise ValueError(f'{key}: needs a column structure (levels)')
    m_eff = 0.0
    if strikers:            # the striker against the lumped masses of its column's end level
        m_end = np.asarray(network.node_mass)[np.asarray(network.levels)[:, -1]].sum(axis=1)
        m_eff = 1.0 / (1.0 / imp.striker_mass + 1.0 / float(m_end.min()))
    pairs, diameter, k, m_min = _bar_contact(scene, network)
    return Effects(
        damp=cable_damping(scene, network),
        stop_h=stop_heights(network, scene.contact.tolerance) if lock else None,
        k_stop=float(scene.contact.stiffness), strikers=strikers,
        striker_k=float(imp.contact_stiffness),
        striker_expo=1.0 if imp.contact == 'linear' else 1.5,
        striker_mass=float(imp.striker_mass), gravity=float(scene.loading.gravity),
        m_eff=float(m_eff), pairs=pairs, diameter=float(diameter), k=float(k),
        m_min=float(m_min), resolution=float(scene.contact.resolution),
        energy_rate=float(scene.divergence.energy_error), refine=scene.contact.refine == 'ledger')


def _levels_of(levels_full, reduced):
    """The levels of the model's state: the full network's, or one representative per level."""
    if not levels_full.size:
        return np.zeros((0, 0, 1), dtype=np.int64)
    if reduced is None:
        return np.ascontiguousarray(levels_full, dtype=np.int64)
    return np.ascontiguousarray(np.asarray(reduced.node_rep)[levels_full[:, :, :1]],
                                dtype=np.int64)


def _striker_rows(x0, levels, striker_state):
    """Start positions and velocities (ns, 3) of the strikers' contact faces (one per column of
    ``levels``): at the centre of each column's free end, touching it and at rest, or at
    ``striker_state`` ((ns, 2) z, v_z); and the rest positions."""
    x_full = np.asarray(x0)
    ns = levels.shape[0]
    x_extra = np.zeros((ns, 3))
    for c in range(ns):
        end = x_full[levels[c, -1]]
        x_extra[c] = (end[:, 0].mean(), end[:, 1].mean(), end[:, 2].mean())
    x_rest = x_extra.copy()
    v_extra = np.zeros((ns, 3))
    if striker_state is not None:
        x_extra[:, 2] = striker_state[:, 0]
        v_extra[:, 2] = striker_state[:, 1]
    return x_extra, v_extra, x_rest


def build(network, topo, x, rest, EA, f_ext, summary, effects=NONE, reduced=None,
          striker_state=None):
    """The records ``(Model, Data, Work)`` of a model (:mod:`solver.kernels.records`): its
    topology ``topo``, state ``x`` (the model's rows, at rest), cables ``rest`` and ``EA``,
    external forces ``f_ext`` and state summary (``summary_arrays`` of its own state, or None when
    it has none), with the ``effects`` of its scene (:class:`Effects`, on the full ``network``;
    ``reduced``: the reduced network of ``sym3d``, or None). Strikers add one row per column to
    the state (the striker's contact face at ``(x, y, z_s)``: x, y stay at the column's centre),
    padded into the topology, forces and summary; ``striker_state`` ((n_columns, 2) z, v_z): where
    they start (default: touching the free end, at rest)."""
    levels_full = np.asarray(network.levels if effects.levels is None else effects.levels)
    levels = _levels_of(levels_full, reduced)
    n = x.shape[0]
    ns = levels_full.shape[0] if effects.strikers else 0
    v = np.zeros((n, 3))
    f_ext = np.array(f_ext, dtype=np.float64)
    if ns:
        if topo.kkt.node_u.shape[0]:
            raise ValueError('loading.impact.mode: striker is not available with massive bars '
                             'that share nodes (materials.bar_mass_fraction, '
                             'materials.bar_mass): the striker is not part of their mass-matrix '
                             'system; use mode impulse or energy, or massless bars')
        x_extra, v_extra, x_rest = _striker_rows(network.x0, levels_full, striker_state)
        x = np.concatenate([x, x_extra])
        v = np.concatenate([v, v_extra])
        # no mass term: the striker's inverse mass goes into w_diag (its force is along z only)
        topo = topo._replace(
            w_diag=rec.readonly(np.concatenate([topo.w_diag,
                                                np.full(ns, 1.0 / effects.striker_mass)])),
            partner=rec.readonly(np.concatenate([topo.partner, -np.ones(ns, np.int64)])),
            w_off=rec.readonly(np.concatenate([topo.w_off, np.zeros(ns)])))
        f_ext = np.concatenate([f_ext, np.zeros((ns, 3))])
        f_ext[n:, 2] = -effects.striker_mass * effects.gravity
        if summary is not None:
            summary = summary._replace(**{k: rec.readonly(a) for k, a in (
                ('x0', np.concatenate([summary.x0, x_rest])),
                ('node_mass', np.concatenate([summary.node_mass, np.zeros(ns)])),
                ('clamped', np.concatenate([summary.clamped, np.zeros(ns, bool)])),
                ('node_mult', np.concatenate([summary.node_mult, np.zeros(ns)])))})
    rows = n + ns
    damp = rec.empty(0)
    if effects.damp is not None:
        if reduced is None:
            damp = np.array(effects.damp, dtype=np.float64)
        else:
            damp = np.zeros(len(reduced.cable_a))
            damp[reduced.cable_map] = effects.damp
    pairs, mult = rec.empty((0, 8), np.int64), 1.0
    scan, active = np.zeros(rec.HEAD), np.full(1, -1, dtype=np.int64)
    if effects.pairs is not None:
        pairs, mult = _model_pairs(effects.pairs, reduced)
        prisms = levels.shape[0] * max(levels.shape[1] - 1, 0) if levels.size else 0
        # contacts met, slack, look, motion since the last rescan (records.HEAD entries), each
        # pair's and each prism's gap bound (kernels.contactsteps.contact_step), the positions
        # the last call ended at (resume); the motion NaN: the first scan evaluates every pair
        scan = np.concatenate(([0.0, -1.0, 1.0, np.nan], np.zeros(len(pairs) + prisms),
                               np.full(3 * rows, np.nan)))
        active = np.full(len(pairs) + 1, -1, dtype=np.int64)
    has_summary = summary is not None
    model = rec.Model(
        topo=topo, levels=rec.readonly(levels),
        per_level=float(levels_full.shape[2]) if levels_full.size else 3.0,
        damping=rec.Damping(rec.readonly(damp)),
        stops=rec.Stops(rec.empty((0, 0)) if effects.stop_h is None
                        else rec.readonly(np.array(effects.stop_h, np.float64)),
                        float(effects.k_stop)),
        strikers=rec.Strikers(rec.readonly(np.arange(n, rows, dtype=np.int64)),
                              rec.readonly(np.arange(ns, dtype=np.int64)),
                              float(effects.striker_k), float(effects.striker_expo),
                              float(effects.striker_mass), float(effects.gravity),
                              float(effects.resolution), float(effects.m_eff)),
        bar_contact=rec.BarContact(rec.readonly(pairs), float(effects.diameter),
                                   float(effects.k), float(mult), float(effects.m_min),
                                   float(effects.resolution)),
        summary=summary if has_summary else rec.NO_SUMMARY,
        ledger=rec.LedgerRule(float(effects.energy_rate),
                              bool(effects.refine and effects.pairs is not None and has_summary)))
    data = rec.Data(np.ascontiguousarray(x, dtype=np.float64), v,
                    np.array(rest, dtype=np.float64), np.array(EA, dtype=np.float64), f_ext,
                    np.zeros(2), rec.ContactState(scan, active), np.zeros(2))
    work = rec.work_for(topo, rows)
    return model, data, work


def full_effects(effects, network):
    """The records of ``network`` (a full one, at rest) with the cable damping, prism stops and
    bar contact of ``effects`` (no strikers): the member forces of a full state, as the base force
    needs them (every pair and every prism's bases looked at)."""
    return build(network, network.topology(), np.array(network.x0),
                 network.cable_rest_length, network.cable_EA, np.zeros((network.n_nodes, 3)),
                 None, effects.without('strikers'))


def striker_state(model):
    """(n_strikers, 2) striker face height m and axial velocity m/s of a model (a copy)."""
    ns = model.n_strikers
    if not ns:
        return np.zeros((0, 2))
    return np.stack([model.x[-ns:, 2], model.v[-ns:, 2]], axis=1)
