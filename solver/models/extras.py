"""What a scene switches on of :mod:`solver.kernels.contact` (cable damping, prism stops,
strikers), and how it is loaded into a model: the extras tuple (``act[3]``), the strikers' rows of
the state, the padded ``net``/``ws``/``summ`` tuples."""
import math

import numpy as np

from solver.kernels import barcontact
from solver.kernels import dynamics as dyn
from solver.kernels.contact import NO_EXTRAS
from solver.build import memo


def active_spec(spec):
    """Whether a :func:`scene_extras` dict switches anything on."""
    return (spec['damp'] is not None or spec['stop_h'] is not None or spec['strikers']
            or spec.get('pairs') is not None)


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
    """``(pairs, bpar)`` of the scene's bar contact (:mod:`solver.kernels.barcontact`), or
    ``(None, None)`` with ``contact.bars: none`` or no prisms."""
    pairs = None
    if scene.contact.bars != 'none':         # one search per topology inside a batch
        pairs = memo.lookup('bar-pairs', (network.levels, network.bar_a, network.bar_b),
                            lambda: _read_only(bar_pairs(network)))
    if pairs is None:
        return None, None
    mat = scene.materials
    mass = np.asarray(network.node_mass)[~np.asarray(network.clamped, bool)]
    mass = mass[mass > 0]
    m_min = float(mass.min()) if mass.size else float(network.total_mass) / network.n_nodes
    bpar = np.array([2.0 * mat.bar_radius,
                     barcontact.hertz_constant(mat.bar_radius, mat.bar_E, mat.bar_poisson),
                     1.0, m_min, float(scene.contact.resolution),
                     float(network.levels.shape[2])])
    return pairs, bpar


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


def scene_extras(scene, network):
    """What a scene switches on, for :func:`attach`: a dict with ``damp`` (full (n_cables,) or
    None), ``stop_h`` ((n_columns, n_prisms) or None), ``strikers`` (bool), ``par`` (8,)."""
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
    par = np.array([scene.contact.stiffness, imp.contact_stiffness,
                    1.0 if imp.contact == 'linear' else 1.5,
                    float(network.levels.shape[2]) if network.levels.size else 3.0,
                    imp.striker_mass, scene.loading.gravity, float(scene.contact.resolution),
                    m_eff])
    pairs, bpar = _bar_contact(scene, network)
    return {'damp': cable_damping(scene, network),
            'stop_h': stop_heights(network, scene.contact.tolerance) if lock else None,
            'strikers': strikers, 'par': par, 'pairs': pairs, 'bpar': bpar,
            'energy_rate': float(scene.divergence.energy_error),
            'refine': scene.contact.refine == 'ledger'}


def _pair_slots(spec, reduced, n_rows, levels):
    """The four bar-contact slots of the extras tuple for a model (``reduced`` or None) whose
    state has ``n_rows`` rows and whose prisms are given by ``levels`` (the extras' slot)."""
    if spec.get('pairs') is None:
        return NO_EXTRAS[6:10]
    rows, mult = _model_pairs(spec['pairs'], reduced)
    bpar = spec['bpar'].copy()
    bpar[2] = mult
    # contacts met, slack, look, motion since the last rescan (barcontact.HEAD entries), each
    # pair's and each prism's gap bound (kernels.contactsteps.contact_step), the positions the
    # last call ended at (resume); the motion NaN: the first scan evaluates every pair
    prisms = levels.shape[0] * max(levels.shape[1] - 1, 0) if levels.size else 0
    state = np.concatenate(([0.0, -1.0, 1.0, np.nan], np.zeros(len(rows) + prisms),
                            np.full(3 * n_rows, np.nan)))
    return rows, bpar, state, np.zeros((2, n_rows, 3))


def _active_slot(spec):
    """The extras slot listing the pairs the force evaluations look at (-1: all)."""
    if spec.get('pairs') is None:
        return NO_EXTRAS[11]
    return np.full(len(spec['pairs']) + 1, -1, dtype=np.int64)


def _dissipation_slot(spec):
    """The extras slot of the cable damping's power and dissipated energy (its own per model)."""
    return NO_EXTRAS[10] if spec['damp'] is None else np.zeros(2)


def network_extras(spec, network):
    """The extras tuple of ``spec`` for the full ``network`` without strikers (cable damping and
    prism stops only): the member forces of a full state, as the base force needs them."""
    if spec is None or not active_spec(spec):
        return NO_EXTRAS
    damp = NO_EXTRAS[0] if spec['damp'] is None else np.array(spec['damp'], dtype=np.float64)
    stop_h = NO_EXTRAS[2] if spec['stop_h'] is None else np.array(spec['stop_h'], np.float64)
    # writable like NO_EXTRAS's (one compiled type; never written)
    levels = np.array(network.levels, dtype=np.int64) if network.levels.size else NO_EXTRAS[1]
    return (damp, levels, stop_h, NO_EXTRAS[3], NO_EXTRAS[4], spec['par'].copy(),
            *_pair_slots(spec, None, network.n_nodes, levels), _dissipation_slot(spec),
            _active_slot(spec), *NO_EXTRAS[12:])


def energy_slots(model, spec):
    """The last extras slots: copies of the model's state summary arrays (``x0``, node mass,
    clamped, node multiplicity, massive bars, cable multiplicity) and ``divergence.energy_error``
    as a rate per second, followed by the two halving levels of the steps after a contact
    (``contact.refine: ledger``; without them the steps are never refined), for
    :func:`solver.kernels.summary.step_energy`, which the RK4 kernels use to check a whole step
    beside a near miss of bar contact and every step after a contact; empty without bar contact or
    without a summary (a ``sym3d`` model that is not exact). Writable copies, like
    :data:`NO_EXTRAS`' (one compiled type)."""
    s = model.summ
    if spec.get('pairs') is None or s is None:
        return NO_EXTRAS[12:]
    return (np.array(s[0], dtype=np.float64).reshape(-1, 3), np.array(s[1], dtype=np.float64),
            np.array(s[2], dtype=np.bool_), np.array(s[3], dtype=np.float64),
            np.array(s[4], dtype=np.int64), np.array(s[5], dtype=np.int64),
            np.array(s[6], dtype=np.float64), np.array(s[7], dtype=np.float64),
            np.array([spec.get('energy_rate', 0.0)] + [0.0, 0.0] * spec.get('refine', True),
                     dtype=np.float64))


def attach(model, spec, striker_state=None):
    """Load the extras ``spec`` (:func:`scene_extras`) into a ``full3d`` or ``sym3d`` model: its
    ``act`` gets the extras tuple; with strikers its state arrays get one row per column at the
    end (the striker's contact face at ``(x, y, z_s)``: x, y stay at the column's centre), and its
    ``net``, ``ws``, ``summ`` are padded to match. ``striker_state`` ((n_columns, 2) z, v_z):
    where the strikers start (default: touching the free end, at rest). Sets
    ``model.n_strikers``."""
    net_full = model.network
    reduced = model.reduced
    if spec is not None and np.shape(spec['par']) != NO_EXTRAS[5].shape:
        raise ValueError(f'extras: par has {np.size(spec["par"])} entries, the kernels read '
                         f'{NO_EXTRAS[5].size} (solver.kernels.contact)')
    if spec is None or not active_spec(spec):
        model.n_strikers = 0
        return model
    levels_full = np.asarray(spec.get('levels', net_full.levels))     # (n_columns, n_levels, k)
    if reduced is None:                  # a writable copy, like NO_EXTRAS's (one compiled type)
        levels = np.array(levels_full, dtype=np.int64)
    else:
        levels = np.ascontiguousarray(np.asarray(reduced.node_rep)[levels_full[:, :, :1]],
                                      dtype=np.int64)
    damp = NO_EXTRAS[0]
    if spec['damp'] is not None:
        if reduced is None:
            damp = np.array(spec['damp'], dtype=np.float64)
        else:
            damp = np.zeros(len(reduced.cable_a))
            damp[reduced.cable_map] = spec['damp']
    stop_h = NO_EXTRAS[2] if spec['stop_h'] is None else np.array(spec['stop_h'], np.float64)
    n = model.x.shape[0]
    ns = levels_full.shape[0] if spec['strikers'] else 0
    rows = np.arange(n, n + ns, dtype=np.int64)
    if not levels.size:
        levels = NO_EXTRAS[1]
    ex = (damp, levels, stop_h, rows, np.arange(ns, dtype=np.int64), spec['par'].copy(),
          *_pair_slots(spec, reduced, n + ns, levels), _dissipation_slot(spec),
          _active_slot(spec))
    if ns and len(model.net) > 12 and np.asarray(model.net[12][0]).shape[0]:
        raise ValueError('loading.impact.mode: striker is not available with massive bars that '
                         'share nodes (materials.bar_mass_fraction, materials.bar_mass): the '
                         'striker is not part of their mass-matrix system; use mode impulse or '
                         'energy, or massless bars')
    if ns:
        x_full = np.asarray(net_full.x0)
        x_extra = np.zeros((ns, 3))
        for c in range(ns):
            end = x_full[levels_full[c, -1]]
            x_extra[c] = (end[:, 0].mean(), end[:, 1].mean(), end[:, 2].mean())
        x_extra0 = x_extra.copy()
        v_extra = np.zeros((ns, 3))
        if striker_state is not None:
            x_extra[:, 2] = striker_state[:, 0]
            v_extra[:, 2] = striker_state[:, 1]
        model.x = np.concatenate([model.x, x_extra])
        model.v = np.concatenate([model.v, v_extra])
        net = model.net
        pad = (np.concatenate([net[0], np.zeros(ns)]),          # no mass term: the striker's
               np.concatenate([net[1], -np.ones(ns, np.int64)]),  # acceleration is set below
               np.concatenate([net[2], np.zeros(ns)]))
        # the striker's inverse mass goes into w_diag: its force is along z only
        pad[0][n:] = 1.0 / spec['par'][4]
        model.net = tuple(dyn.readonly(a) for a in pad) + tuple(net[3:])
        f_ext = np.concatenate([model.act[2], np.zeros((ns, 3))])
        f_ext[n:, 2] = -spec['par'][4] * spec['par'][5]
        model.act = (model.act[0], model.act[1], f_ext, ex)
        n_con = len(net[3])
        model.ws = dyn.workspace(n + ns, n_con, model.ws[3].shape[1] - 1)
        if model.summ is not None:
            s = model.summ
            model.summ = tuple(dyn.readonly(a) for a in (
                np.concatenate([s[0], x_extra0]), np.concatenate([s[1], np.zeros(ns)]),
                np.concatenate([s[2], np.zeros(ns, bool)]),
                np.concatenate([s[3], np.zeros(ns)]))) + tuple(s[4:])
    model.act = (model.act[0], model.act[1], model.act[2], ex + energy_slots(model, spec))
    model.n_strikers = ns
    return model


def striker_state(model):
    """(n_strikers, 2) striker face height m and axial velocity m/s of a model (a copy)."""
    ns = model.n_strikers
    if not ns:
        return np.zeros((0, 2))
    return np.stack([model.x[-ns:, 2], model.v[-ns:, 2]], axis=1)
