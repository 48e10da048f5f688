"""Numba kernels that summarise a state (docs/physics.md section 7): its energy (kinetic, cable,
external forces, and the strikers, prism stops and bar contacts of a scene that has them), prism
heights, constraint error and finiteness in one pass for the divergence check and a frame
(:func:`state_summary`), the contact-free energy of a step beside a near miss
(:func:`step_energy`), and cable tensions. The kernels take the records of
:mod:`solver.kernels.records` (the model ``m`` with its :class:`~solver.kernels.records.Summary`,
its data ``d``).
"""
import math

import numpy as np

from solver.compiled import jit
from solver.kernels.barcontact import bar_energy_scanned, base_energy
from solver.kernels.contact import extra_energy
from solver.kernels.dynamics import all_finite
from solver.kernels.records import Summary, readonly
from solver.kernels.rotation import constraint_error_arrays, rel


@jit
def kinetic_energy(v, node_mass, clamped, bar_a, bar_b, bar_mass):
    """``sum 1/2 m_p |v_p|^2 + sum_bars m_b / 6 (|v_a|^2 + v_a.v_b + |v_b|^2)`` J."""
    e = 0.0
    for p in range(v.shape[0]):
        if not clamped[p]:
            e += 0.5 * node_mass[p] * (v[p, 0] ** 2 + v[p, 1] ** 2 + v[p, 2] ** 2)
    return e + _bar_kinetic_energy(v, bar_a, bar_b, bar_mass)


@jit
def _bar_kinetic_energy(v, bar_a, bar_b, bar_mass):
    """``sum_bars m_b / 6 (|v_a|^2 + v_a.v_b + |v_b|^2)`` J (uniform bars)."""
    e = 0.0
    for j in range(bar_a.shape[0]):
        mb = bar_mass[j]
        if mb != 0.0:
            a = bar_a[j]
            b = bar_b[j]
            e += mb / 6.0 * (v[a, 0] ** 2 + v[a, 1] ** 2 + v[a, 2] ** 2
                             + v[a, 0] * v[b, 0] + v[a, 1] * v[b, 1] + v[a, 2] * v[b, 2]
                             + v[b, 0] ** 2 + v[b, 1] ** 2 + v[b, 2] ** 2)
    return e


@jit
def _node_energy(x, v, x0, f_ext, node_mass, clamped, node_mult):
    """``sum mult_p (1/2 m_p |v_p|^2 - f_p . (x_p - x0_p))`` over free nodes, J."""
    e = 0.0
    for p in range(x.shape[0]):
        if not clamped[p]:
            e += node_mult[p] * (0.5 * node_mass[p] * (v[p, 0] ** 2 + v[p, 1] ** 2 + v[p, 2] ** 2)
                                 - f_ext[p, 0] * (x[p, 0] - x0[p, 0])
                                 - f_ext[p, 1] * (x[p, 1] - x0[p, 1])
                                 - f_ext[p, 2] * (x[p, 2] - x0[p, 2]))
    return e


@jit
def _cable_energy(x, cable_a, cable_b, cable_rot, rest, EA, cable_mult):
    """``sum mult_c 1/2 EA_c / L_c (s_c - L_c)_+^2`` J (``cable_rot`` as in the topology)."""
    e = 0.0
    for c in range(cable_a.shape[0]):
        dx, dy, dz = rel(x, cable_a[c], cable_b[c], cable_rot, c)
        s = math.sqrt(dx * dx + dy * dy + dz * dz)
        if s > rest[c]:
            e += cable_mult[c] * 0.5 * EA[c] / rest[c] * (s - rest[c]) ** 2
    return e


@jit
def level_heights(x, levels, heights):
    """Prism heights into ``heights`` (n_columns, n_levels - 1) m: the mean z of the k nodes of
    level j + 1 minus that of level j (``levels`` (n_columns, n_levels, k) node indices).
    Returns the smallest height (NaN when a height is NaN, inf when there is none)."""
    h_min = math.inf
    k = levels.shape[2]
    for c in range(levels.shape[0]):
        z_prev = 0.0
        for j in range(levels.shape[1]):
            z = 0.0
            for i in range(k):
                z += x[levels[c, j, i], 2]
            z /= k
            if j > 0:
                h = z - z_prev
                heights[c, j - 1] = h
                if h < h_min or h != h:     # a NaN height stays the minimum
                    h_min = h
            z_prev = z
    return h_min


def summary_arrays(x0, node_mass, clamped, bar_a, bar_b, bar_mass, levels, n_cables,
                   node_mult=None, cable_mult=None):
    """The :class:`~solver.kernels.records.Summary` of :func:`state_summary`: the arrays it needs
    that the topology and the data do not hold (read-only). ``levels`` (n_columns, n_levels, k)
    node indices (a level's height is the mean z of
    its k nodes); ``node_mult``/``cable_mult``: how many nodes or cables of the full network each
    one stands for (default 1)."""
    return Summary(*(readonly(a) for a in (
        x0, node_mass, clamped, np.ones(len(node_mass)) if node_mult is None else node_mult,
        bar_a, bar_b, bar_mass, np.ones(n_cables) if cable_mult is None else cable_mult,
        levels)))



@jit
def _contact_free_energy(x, v, m, d):
    """Kinetic, cable and external-force energy J, and that of strikers and prism stops where a
    scene has them: :func:`state_summary`'s energy less the bar contact, from the model's summary
    arrays (see there)."""
    sm, topo = m.summary, m.topo
    # one compiled function per part: written as one loop nest, the same code ran 3x slower
    e = (_node_energy(x, v, sm.x0, d.f_ext, sm.node_mass, sm.clamped, sm.node_mult)
         + _bar_kinetic_energy(v, sm.bar_a, sm.bar_b, sm.bar_mass)
         + _cable_energy(x, topo.cable_a, topo.cable_b, topo.cable_rot, d.rest, d.EA,
                         sm.cable_mult))
    if m.stops.height.shape[0] != 0 or m.strikers.row.shape[0] != 0:     # kernels.contact
        e += extra_energy(x, v, m)
    return e


@jit
def state_summary(x, v, m, d, heights):
    """``(finite, energy J, relative constraint error, smallest prism height m)`` of a state of
    the model ``m`` (data ``d``: rest lengths, EA, external forces, the contact scans), and the
    prism heights (n_columns, n_prisms) m into ``heights``, in one pass: what the divergence check
    and a frame need, from the model's :class:`~solver.kernels.records.Summary`. The energy is
    kinetic (lumped node masses, bar masses ``m_b / 6 (|v_a|^2 + v_a.v_b + |v_b|^2)``) plus cable
    strain energy ``1/2 EA / L (s - L)_+^2``, minus the work ``f_ext . (x - x0)`` of constant
    external forces; each node and cable term counts ``node_mult``/``cable_mult`` times (a reduced
    network); plus the strikers, stops and bar contacts of the scene. The smallest height is NaN
    when a height is."""
    e = _contact_free_energy(x, v, m, d)
    if m.bar_contact.pairs.shape[0] != 0:
        e += contact_energy(x, m, d)
    topo = m.topo
    return (all_finite(x) and all_finite(v), e,
            constraint_error_arrays(x, topo.con_tail, topo.con_head, topo.con_length,
                                    topo.con_rot),
            level_heights(x, m.summary.levels, heights))


@jit
def energy_parts(x, v, m, d):
    """The terms of :func:`state_summary`'s energy J: ``(kinetic and external forces, cables,
    strikers and stops, bar contact)``, 0.0 where the scene has none; :func:`energy_sum` adds
    them as it does. Only the cables' term depends on the rest lengths
    (:func:`cable_energy`)."""
    sm = m.summary
    a = (_node_energy(x, v, sm.x0, d.f_ext, sm.node_mass, sm.clamped, sm.node_mult)
         + _bar_kinetic_energy(v, sm.bar_a, sm.bar_b, sm.bar_mass))
    extra, touch = contact_parts(x, v, m, d)
    return a, cable_energy(x, m, d), extra, touch


@jit
def contact_parts(x, v, m, d):
    """The last two terms of :func:`energy_parts`: ``(strikers and stops, bar contact)`` J."""
    extra = 0.0
    if m.stops.height.shape[0] != 0 or m.strikers.row.shape[0] != 0:     # kernels.contact
        extra = extra_energy(x, v, m)
    touch = 0.0
    if m.bar_contact.pairs.shape[0] != 0:
        touch = contact_energy(x, m, d)
    return extra, touch


@jit
def contact_energy(x, m, d):
    """Energy J stored in touching bars (the pairs the scans of ``d`` do not bound apart) and
    bases at ``x``, the positions an integrator call ended at; for a model with bar contact."""
    bc = m.bar_contact
    return (bar_energy_scanned(x, bc, d.contact.scan)
            + base_energy(x, m.levels, bc, m.per_level))


@jit
def cable_energy(x, m, d):
    """The cables' term of :func:`energy_parts`, J, at the rest lengths and EA of ``d``."""
    topo = m.topo
    return _cable_energy(x, topo.cable_a, topo.cable_b, topo.cable_rot, d.rest, d.EA,
                         m.summary.cable_mult)


@jit
def energy_sum(m, a, cables, extra, touch):
    """:func:`state_summary`'s energy J from the terms of :func:`energy_parts`, added in its
    order (the terms a scene does not have are not added)."""
    e = a + cables
    if m.stops.height.shape[0] != 0 or m.strikers.row.shape[0] != 0:
        e += extra
    if m.bar_contact.pairs.shape[0] != 0:
        e += touch
    return e


@jit
def step_energy(x, v, m, d):
    """Energy J of a state in which no contact acts (kinetic, cable, external forces, and strikers
    and prism stops where a scene has them), from the model's summary arrays; NaN when the model
    has none (a ``sym3d`` run that is not exact)."""
    if m.summary.node_mass.shape[0] == 0:
        return math.nan
    return _contact_free_energy(x, v, m, d)


@jit
def cable_tensions(x, cable_a, cable_b, rest, EA, out):
    """Tension per cable (n_cables,) N, zero when slack."""
    for c in range(cable_a.shape[0]):
        a = cable_a[c]
        b = cable_b[c]
        s = math.sqrt((x[b, 0] - x[a, 0]) ** 2 + (x[b, 1] - x[a, 1]) ** 2
                      + (x[b, 2] - x[a, 2]) ** 2)
        out[c] = EA[c] / rest[c] * (s - rest[c]) if s > rest[c] else 0.0
