"""Lane twins of the full scans of an RK4 step's control (:mod:`solver.kernels.lanes` for the
layout): where a step ends (:func:`next_kink_lanes`, twin of
:func:`solver.kernels.kinks.next_kink`) and the energy the ledger compares
(:func:`step_energy_lanes`, twin of :func:`solver.kernels.summary.step_energy`;
:func:`ledger_energy_lanes`, twin of :func:`solver.kernels.effects.ledger_energy`; its terms,
:func:`energy_rows` and :func:`cable_energy_lanes`, which a ramp books).

``x``, ``v``, ``acc``, ``f_ext`` are (n_nodes, 3, B), ``rest``, ``EA`` (n_cables, B); ``m`` is
the scalar :class:`~solver.kernels.records.Model` all lanes share. The loops over cables, nodes
and bars run over all lanes at once, the lane index innermost; each lane performs exactly the
floating-point operations of the scalar kernel in the same order, so each lane's result equals
the scalar kernel's on that instance bit for bit. The parts that touch a few nodes (stops,
strikers, bar and base contacts) call the scalar kernels lane by lane, on views of the lane
(strided arrays: the same operations). A lane whose ``go`` is 0 keeps its ``out`` entry.
"""
import math

from solver.compiled import jit_inline, jit_lanes
from solver.kernels.contact import contact_kink, extra_energy, gap_kink
from solver.kernels.contactsteps import bounded_contact_energy
from solver.kernels.lanerot import lane_chord
from solver.kernels.rotation import ROT_C, ROT_S


@jit_inline
def _cable_quad(x, v, acc, rest, a, b, cr, sr, rotated, c, k):
    """Cable ``c`` of lane ``k`` as :func:`solver.kernels.kinks.next_kink` sees it: its gap
    ``g = s - L``, length ``s``, ``b.b'``, ``b'.b'``, ``b.b''`` (``rotated``: the chord to the
    image ``R x_b``, of cosine ``cr`` and sine ``sr``)."""
    if rotated:
        dx = cr * x[b, 0, k] - sr * x[b, 1, k] - x[a, 0, k]
        dy = sr * x[b, 0, k] + cr * x[b, 1, k] - x[a, 1, k]
        vx = cr * v[b, 0, k] - sr * v[b, 1, k] - v[a, 0, k]
        vy = sr * v[b, 0, k] + cr * v[b, 1, k] - v[a, 1, k]
        ax = cr * acc[b, 0, k] - sr * acc[b, 1, k] - acc[a, 0, k]
        ay = sr * acc[b, 0, k] + cr * acc[b, 1, k] - acc[a, 1, k]
    else:
        dx = x[b, 0, k] - x[a, 0, k]
        dy = x[b, 1, k] - x[a, 1, k]
        vx = v[b, 0, k] - v[a, 0, k]
        vy = v[b, 1, k] - v[a, 1, k]
        ax = acc[b, 0, k] - acc[a, 0, k]
        ay = acc[b, 1, k] - acc[a, 1, k]
    dz = x[b, 2, k] - x[a, 2, k]
    vz = v[b, 2, k] - v[a, 2, k]
    az = acc[b, 2, k] - acc[a, 2, k]
    bb = dx * dx + dy * dy + dz * dz
    bbd = dx * vx + dy * vy + dz * vz
    bdbd = vx * vx + vy * vy + vz * vz
    bbdd = dx * ax + dy * ay + dz * az
    s = math.sqrt(bb)
    return s - rest[c, k], s, bbd, bdbd, bbdd


@jit_inline
def _far(g, s, bbd, bdbd, bbdd, t_best):
    """The early-out test of :func:`solver.kernels.kinks.next_kink`: the cable's model has no
    root within ``t_best``."""
    return abs(g) * s > 1.000001 * (abs(bbd) * t_best
                                    + 0.5 * (abs(bdbd + bbdd) + bdbd) * t_best * t_best)


@jit_inline
def _cable_kinks(x, v, acc, rest, a, b, cr, sr, rotated, c, ignore, go, out):
    """One cable of :func:`next_kink_lanes` over all lanes: the test over lanes (vectorised,
    the first lane that fails it), then the roots of the lanes that fail it, from that lane on
    (their quantities computed again: the same operations, the same values)."""
    n_lanes = out.shape[0]
    first = n_lanes
    for k in range(n_lanes):
        g, s, bbd, bdbd, bbdd = _cable_quad(x, v, acc, rest, a, b, cr, sr, rotated, c, k)
        near = go[k] != 0 and not _far(g, s, bbd, bdbd, bbdd, out[k])
        first = min(first, k if near else n_lanes)
    for k in range(first, n_lanes):
        if go[k] == 0:
            continue
        g, s, bbd, bdbd, bbdd = _cable_quad(x, v, acc, rest, a, b, cr, sr, rotated, c, k)
        t_best = out[k]
        if _far(g, s, bbd, bdbd, bbdd, t_best):
            continue
        sd = bbd / s
        sdd = (bdbd + bbdd - sd * sd) / s
        out[k] = gap_kink(g, sd, sdd, t_best, ignore)


@jit_lanes
def next_kink_lanes(x, v, acc, m, rest, h, ignore, go, out):
    """For each lane ``k`` with ``go[k]`` set, ``out[k]`` = :func:`solver.kernels.kinks.
    next_kink` of that lane for a step of at most ``h[k]`` (``h`` (B,)): the earliest time in
    ``(ignore, h[k])`` at which a cable is predicted to go slack or taut, or a stop or striker
    contact to open or close; ``h[k]`` if none. The cables over lanes, each lane with its own
    ``t_best`` (``out``); the stops and strikers by the scalar
    :func:`~solver.kernels.contact.contact_kink` on views of the lane."""
    cable_a, cable_b, cable_rot = m.topo.cable_a, m.topo.cable_b, m.topo.cable_rot
    n_lanes = out.shape[0]
    for k in range(n_lanes):
        out[k] = h[k] if go[k] != 0 else out[k]
    if cable_rot.shape[0] > 0:      # cables to the image R^r x_b (sym3d)
        for c in range(cable_a.shape[0]):
            cr = ROT_C[cable_rot[c]]
            sr = ROT_S[cable_rot[c]]
            _cable_kinks(x, v, acc, rest, cable_a[c], cable_b[c], cr, sr, True, c, ignore, go,
                         out)
    else:
        for c in range(cable_a.shape[0]):
            _cable_kinks(x, v, acc, rest, cable_a[c], cable_b[c], 1.0, 0.0, False, c, ignore,
                         go, out)
    if m.stops.height.shape[0] != 0 or m.strikers.row.shape[0] != 0:   # kernels.contact
        for k in range(n_lanes):
            if go[k] != 0:
                out[k] = contact_kink(x[:, :, k], v[:, :, k], acc[:, :, k], m, out[k], ignore)


@jit_lanes
def largest_nodes(u, node, best):
    """For each lane ``k``, ``node[k]``: the first node ``p`` of the largest ``|u_p|^2`` over
    the nodes of ``u`` (n_nodes, 3, B), each computed ``u0 u0 + u1 u1 + u2 u2`` and compared
    ``r > best`` as :func:`solver.kernels.contactsteps.contact_step` finds the largest speed and
    acceleration (a NaN is never the largest); -1 where none exceeds 0. That node alone, as a
    (1, 3) array, gives the scalar scan the same bound of the motion. ``best`` (B,) scratch."""
    n_lanes = node.shape[0]
    for k in range(n_lanes):
        best[k] = 0.0
        node[k] = -1
    for p in range(u.shape[0]):
        for k in range(n_lanes):
            r = u[p, 0, k] * u[p, 0, k] + u[p, 1, k] * u[p, 1, k] + u[p, 2, k] * u[p, 2, k]
            big = r > best[k]
            best[k] = r if big else best[k]
            node[k] = p if big else node[k]


@jit_inline
def node_of(u, node, k, out):
    """Node ``node[k]`` of lane ``k`` of ``u`` into ``out`` (1, 3); zeros for -1."""
    p = node[k]
    for i in range(3):
        out[0, i] = u[p, i, k] if p >= 0 else 0.0


@jit_lanes
def constraint_error_lanes(x, topo, out):
    """``out[k]``: :func:`solver.kernels.rotation.constraint_error_arrays` of lane ``k``, the
    largest ``|g_c| / L_c^2`` over the members, plain or rotated (a NaN stays the largest)."""
    tail, head, length, rot = topo.con_tail, topo.con_head, topo.con_length, topo.con_rot
    n_lanes = out.shape[0]
    for k in range(n_lanes):
        out[k] = 0.0
    for c in range(tail.shape[0]):
        t = tail[c]
        h = head[c]
        L2 = length[c] * length[c]
        if rot.shape[0] == 0:
            for k in range(n_lanes):
                dx = x[h, 0, k] - x[t, 0, k]
                dy = x[h, 1, k] - x[t, 1, k]
                dz = x[h, 2, k] - x[t, 2, k]
                e = abs(0.5 * (dx * dx + dy * dy + dz * dz - L2)) / L2
                out[k] = out[k] if e <= out[k] else e
        else:
            cr = ROT_C[rot[c]]
            sr = ROT_S[rot[c]]
            for k in range(n_lanes):
                dx, dy, dz = lane_chord(x, t, h, cr, sr, k)
                e = abs(0.5 * (dx * dx + dy * dy + dz * dz - L2)) / L2
                out[k] = out[k] if e <= out[k] else e


@jit_lanes
def step_energy_lanes(x, v, m, rest, EA, f_ext, go, out, tmp):
    """For each lane ``k`` with ``go[k]`` set, ``out[k]`` = :func:`solver.kernels.summary.
    step_energy` of that lane: node (kinetic and external-force), bar kinetic and cable energies,
    each summed over lanes into its own row of ``tmp`` (3, B) (scratch: :func:`energy_rows`),
    then added as the scalar kernel adds them, plus the strikers and stops of the model by the
    scalar :func:`~solver.kernels.contact.extra_energy` on views of the lane; NaN when the model
    has no summary."""
    n_lanes = out.shape[0]
    if m.summary.node_mass.shape[0] == 0:
        for k in range(n_lanes):
            out[k] = math.nan if go[k] != 0 else out[k]
        return
    energy_rows(x, v, m, rest, EA, f_ext, tmp)
    en, eb, ec = tmp[0], tmp[1], tmp[2]
    for k in range(n_lanes):
        out[k] = en[k] + eb[k] + ec[k] if go[k] != 0 else out[k]
    if m.stops.height.shape[0] != 0 or m.strikers.row.shape[0] != 0:     # kernels.contact
        for k in range(n_lanes):
            if go[k] != 0:
                out[k] += extra_energy(x[:, :, k], v[:, :, k], m)


@jit_lanes
def energy_rows(x, v, m, rest, EA, f_ext, tmp):
    """Every lane's node (kinetic and external-force) energy into ``tmp[0]``, bar kinetic energy
    into ``tmp[1]`` and cable energy into ``tmp[2]`` (:func:`cable_energy_lanes`): the terms of
    :func:`solver.kernels.summary._contact_free_energy` (a model with summary arrays)."""
    n_lanes = x.shape[2]
    sm = m.summary
    en, eb = tmp[0], tmp[1]
    for k in range(n_lanes):
        en[k] = 0.0
        eb[k] = 0.0
    # summary._node_energy
    x0, node_mass, clamped, node_mult = sm.x0, sm.node_mass, sm.clamped, sm.node_mult
    for p in range(x.shape[0]):
        if clamped[p]:
            continue
        mult = node_mult[p]
        mp = node_mass[p]
        r0 = x0[p, 0]
        r1 = x0[p, 1]
        r2 = x0[p, 2]
        for k in range(n_lanes):
            en[k] += mult * (0.5 * mp * (v[p, 0, k] ** 2 + v[p, 1, k] ** 2 + v[p, 2, k] ** 2)
                             - f_ext[p, 0, k] * (x[p, 0, k] - r0)
                             - f_ext[p, 1, k] * (x[p, 1, k] - r1)
                             - f_ext[p, 2, k] * (x[p, 2, k] - r2))
    # summary._bar_kinetic_energy
    bar_a, bar_b, bar_mass = sm.bar_a, sm.bar_b, sm.bar_mass
    for j in range(bar_a.shape[0]):
        mb = bar_mass[j]
        if mb == 0.0:
            continue
        a = bar_a[j]
        b = bar_b[j]
        for k in range(n_lanes):
            eb[k] += mb / 6.0 * (v[a, 0, k] ** 2 + v[a, 1, k] ** 2 + v[a, 2, k] ** 2
                                 + v[a, 0, k] * v[b, 0, k] + v[a, 1, k] * v[b, 1, k]
                                 + v[a, 2, k] * v[b, 2, k]
                                 + v[b, 0, k] ** 2 + v[b, 1, k] ** 2 + v[b, 2, k] ** 2)
    cable_energy_lanes(x, m, rest, EA, tmp[2])


@jit_lanes
def cable_energy_lanes(x, m, rest, EA, ec):
    """Every lane's cable energy into ``ec`` (B,): :func:`solver.kernels.summary.cable_energy`
    of the lane, operation for operation."""
    n_lanes = x.shape[2]
    topo, sm = m.topo, m.summary
    for k in range(n_lanes):
        ec[k] = 0.0
    # summary._cable_energy (rotation.rel: plain or to the rotated image)
    cable_a, cable_b, cable_rot, cable_mult = topo.cable_a, topo.cable_b, topo.cable_rot, \
        sm.cable_mult
    if cable_rot.shape[0] == 0:
        for c in range(cable_a.shape[0]):
            a = cable_a[c]
            b = cable_b[c]
            mc = cable_mult[c]
            for k in range(n_lanes):
                dx = x[b, 0, k] - x[a, 0, k]
                dy = x[b, 1, k] - x[a, 1, k]
                dz = x[b, 2, k] - x[a, 2, k]
                s = math.sqrt(dx * dx + dy * dy + dz * dz)
                L = rest[c, k]
                e = mc * 0.5 * EA[c, k] / L * (s - L) ** 2
                ec[k] = ec[k] + e if s > L else ec[k]
    else:
        for c in range(cable_a.shape[0]):
            a = cable_a[c]
            b = cable_b[c]
            mc = cable_mult[c]
            cr = ROT_C[cable_rot[c]]
            sr = ROT_S[cable_rot[c]]
            for k in range(n_lanes):
                dx, dy, dz = lane_chord(x, a, b, cr, sr, k)
                s = math.sqrt(dx * dx + dy * dy + dz * dz)
                L = rest[c, k]
                e = mc * 0.5 * EA[c, k] / L * (s - L) ** 2
                ec[k] = ec[k] + e if s > L else ec[k]


@jit_lanes
def ledger_energy_lanes(x, v, m, rest, EA, f_ext, scan, go, out, tmp):
    """For each lane ``k`` with ``go[k]`` set, ``out[k]`` = :func:`solver.kernels.effects.
    ledger_energy` of that lane: :func:`step_energy_lanes` plus the energy of touching bars and
    bases (:func:`~solver.kernels.contactsteps.bounded_contact_energy`, scalar, on a view of the
    lane's positions and its scan state ``scan[k]``, ``scan`` (B, n_scan) lane-outer)."""
    step_energy_lanes(x, v, m, rest, EA, f_ext, go, out, tmp)
    for k in range(out.shape[0]):
        if go[k] != 0:
            out[k] = out[k] + bounded_contact_energy(x[:, :, k], m.bar_contact, m.levels,
                                                     m.per_level, scan[k])
