"""What a scene switches on of :mod:`solver.kernels.contact` (cable damping, prism stops,
strikers), and how it is loaded into a model: the extras tuple (``act[3]``), the strikers' rows of
the state, the padded ``net``/``ws``/``summ`` tuples."""
import math

import numpy as np

from solver.kernels import dynamics as dyn
from solver.kernels.contact import NO_EXTRAS


def active_spec(spec):
    """Whether a :func:`scene_extras` dict switches anything on."""
    return spec['damp'] is not None or spec['stop_h'] is not None or spec['strikers']


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
    None), ``stop_h`` ((n_columns, n_prisms) or None), ``strikers`` (bool), ``par`` (6,)."""
    imp = scene.loading.impact
    lock = scene.contact.lock != 'none'
    strikers = imp.mode == 'striker'
    if (lock or strikers) and not network.levels.size:
        key = 'contact.lock' if lock else 'loading.impact.mode'
        raise ValueError(f'{key}: needs a column structure (levels)')
    par = np.array([scene.contact.stiffness, imp.contact_stiffness,
                    1.0 if imp.contact == 'linear' else 1.5,
                    float(network.levels.shape[2]) if network.levels.size else 3.0,
                    imp.striker_mass, scene.loading.gravity])
    return {'damp': cable_damping(scene, network),
            'stop_h': stop_heights(network, scene.contact.tolerance) if lock else None,
            'strikers': strikers, 'par': par}


def network_extras(spec, network):
    """The extras tuple of ``spec`` for the full ``network`` without strikers (cable damping and
    prism stops only): the member forces of a full state, as the base force needs them."""
    if spec is None or not active_spec(spec):
        return NO_EXTRAS
    damp = NO_EXTRAS[0] if spec['damp'] is None else np.array(spec['damp'], dtype=np.float64)
    stop_h = NO_EXTRAS[2] if spec['stop_h'] is None else np.array(spec['stop_h'], np.float64)
    levels = np.ascontiguousarray(network.levels, dtype=np.int64) if network.levels.size \
        else NO_EXTRAS[1]
    return (damp, levels, stop_h, NO_EXTRAS[3], NO_EXTRAS[4], spec['par'].copy())


def attach(model, spec, striker_state=None):
    """Load the extras ``spec`` (:func:`scene_extras`) into a ``full3d`` or ``sym3d`` model: its
    ``act`` gets the extras tuple; with strikers its state arrays get one row per column at the
    end (the striker's contact face at ``(x, y, z_s)``: x, y stay at the column's centre), and its
    ``net``, ``ws``, ``summ`` are padded to match. ``striker_state`` ((n_columns, 2) z, v_z):
    where the strikers start (default: touching the free end, at rest). Sets
    ``model.n_strikers``."""
    net_full = model.network
    reduced = model.reduced
    if spec is None or not active_spec(spec):
        model.n_strikers = 0
        return model
    levels_full = np.asarray(spec.get('levels', net_full.levels))     # (n_columns, n_levels, k)
    if reduced is None:
        levels = np.ascontiguousarray(levels_full, dtype=np.int64)
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
    ex = (damp, levels, stop_h, rows, np.arange(ns, dtype=np.int64), spec['par'].copy())
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
        model.net = pad + tuple(net[3:])
        f_ext = np.concatenate([model.act[2], np.zeros((ns, 3))])
        f_ext[n:, 2] = -spec['par'][4] * spec['par'][5]
        model.act = (model.act[0], model.act[1], f_ext, ex)
        n_con = len(net[3])
        model.ws = dyn.workspace(n + ns, n_con, model.ws[3].shape[1] - 1)
        if model.summ is not None:
            s = model.summ
            model.summ = (np.concatenate([s[0], x_extra0]), np.concatenate([s[1], np.zeros(ns)]),
                          np.concatenate([s[2], np.zeros(ns, bool)]),
                          np.concatenate([s[3], np.zeros(ns)])) + tuple(s[4:])
    else:
        model.act = (model.act[0], model.act[1], model.act[2], ex)
    model.n_strikers = ns
    return model


def striker_state(model):
    """(n_strikers, 2) striker face height m and axial velocity m/s of a model (a copy)."""
    ns = model.n_strikers
    if not ns:
        return np.zeros((0, 2))
    return np.stack([model.x[-ns:, 2], model.v[-ns:, 2]], axis=1)
