"""The named records every kernel works on, split as MuJoCo splits ``mjModel`` and ``mjData``:

- :class:`Model`: the constants of a built network and of the effects its scene switches on
  (topology, rest geometry, inverse masses, bar-contact pairs, stop levels, striker parameters,
  damping coefficients, the band layout). Read-only arrays, built once by
  :func:`solver.models.extras.build` and never edited afterwards.
- :class:`Data`: everything a step changes or a command sets (positions, velocities, cable rest
  lengths and EA, external forces, the energy ledger, the contact scans, the refinement levels).
  :func:`copy_data` copies one into another of the same shapes in one call: the state a
  ``Simulation`` restores when a check fails.
- :class:`Work`: scratch only.

Each effect has its own sub-record (:class:`Damping`, :class:`Stops`, :class:`Strikers`,
:class:`BarContact` of the model; :class:`ContactState` of the data). An effect is off when its
arrays are empty: every scene compiles to the same types, and the kernels then take exactly the
path they take without it. The records are ``typing.NamedTuple`` classes: numba compiles a field
read to a static offset, as it did the slots of the tuples these records replace.

Mutable scalars of the data live in small arrays whose entries have names here (``ledger[POWER]``,
``contact.scan[MET]``, ``refine[STEP_LEVEL]``).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from solver.compiled import jit, jit_inline
from solver.kernels.massmatrix import KKT, KKTScratch, scratch


class Topology(NamedTuple):
    """The network's rigid members, cables and inverse mass (:class:`solver.build.network.Network`
    for the meaning of each array). ``con_rot``, ``cable_rot`` and ``con_coef3`` serve the
    symmetric reduction (:mod:`solver.models.sym3d`): a member joins its tail node to the rotated
    image ``R^r x_head`` of its head node; they are empty for a plain network, whose kernels then
    take the plain path. ``kkt``: the layout of the mass-matrix system of massive bars that share
    nodes (:mod:`solver.kernels.massmatrix`; empty arrays otherwise)."""
    w_diag: np.ndarray
    partner: np.ndarray
    w_off: np.ndarray
    con_tail: np.ndarray
    con_head: np.ndarray
    con_length: np.ndarray
    con_coef: np.ndarray
    cable_a: np.ndarray
    cable_b: np.ndarray
    con_rot: np.ndarray
    cable_rot: np.ndarray
    con_coef3: np.ndarray
    kkt: KKT


class Damping(NamedTuple):
    """Viscous cables (:func:`solver.kernels.contact.cable_forces_damped`): ``coef``
    (n_cables,) N s/m; empty: no damping."""
    coef: np.ndarray


class Stops(NamedTuple):
    """Prism stops (``contact.lock: penalty``): ``height`` (n_columns, n_prisms) m of each stop
    (empty: none), ``k`` N/m of the linear penalty."""
    height: np.ndarray
    k: float


class Strikers(NamedTuple):
    """Strikers (``loading.impact.mode: striker``), one per column: ``row`` the rows of the state
    arrays after the nodes, ``col`` the column each strikes (empty: none); the contact law
    ``F = k d^expo`` (``expo`` 1 or 1.5), the striker ``mass`` kg and ``gravity`` m/s^2, the
    ``steps`` per contact duration, ``m_eff`` kg the striker against its column's end level."""
    row: np.ndarray
    col: np.ndarray
    k: float
    expo: float
    mass: float
    gravity: float
    steps: float
    m_eff: float


class BarContact(NamedTuple):
    """Bars and bases that touch (:mod:`solver.kernels.barcontact`): ``pairs`` (n_pairs, 8) the
    node/rotation rows of the pairs that can touch (empty: no bar contact), ``diameter`` m (the
    axes' distance at touch), Hertz ``k`` N/m^1.5, the energy multiplicity ``mult`` (3 in
    ``sym3d``), the smallest node mass ``m_min`` kg and the ``steps`` per contact duration."""
    pairs: np.ndarray
    diameter: float
    k: float
    mult: float
    m_min: float
    steps: float


class Summary(NamedTuple):
    """The arrays of :func:`solver.kernels.summary.state_summary` that the topology does not hold:
    reference positions, node masses, clamped flags, node multiplicity, the massive bars, cable
    multiplicity and the prism levels of the model's own state. Empty arrays: the model has no
    exact summary of its own state (a ``sym3d`` run whose levels are not single orbits)."""
    x0: np.ndarray
    node_mass: np.ndarray
    clamped: np.ndarray
    node_mult: np.ndarray
    bar_a: np.ndarray
    bar_b: np.ndarray
    bar_mass: np.ndarray
    cable_mult: np.ndarray
    levels: np.ndarray


class LedgerRule(NamedTuple):
    """How the steps keep the energy ledger: ``rate`` (``divergence.energy_error`` per second,
    relative), and whether steps after a contact are checked against it and refined
    (``contact.refine: ledger``, with bar contact and an exact summary)."""
    rate: float
    refine: bool


class Model(NamedTuple):
    """The constants of a built model (read-only; see the module text). ``levels`` (n_columns,
    n_levels, k): node indices of each level of the model's state (one representative per level
    in ``sym3d``), ``per_level`` the nodes of a level in the full network."""
    topo: Topology
    levels: np.ndarray
    per_level: float
    damping: Damping
    stops: Stops
    strikers: Strikers
    bar_contact: BarContact
    summary: Summary
    ledger: LedgerRule


class ContactState(NamedTuple):
    """What the contact scans know (:mod:`solver.kernels.contactsteps`): ``scan`` holds the
    contacts met, the scan's slack, whether the forces look for contacts and the motion summed
    (:data:`MET`, :data:`SLACK`, :data:`LOOK`, :data:`MOTION`), then each pair's and each prism's
    gap bound from :data:`HEAD`, then the positions the last call ended at (``3 n``);
    ``active``: the pairs the force evaluations look at (``active[0]`` < 0: all)."""
    scan: np.ndarray
    active: np.ndarray


class Data(NamedTuple):
    """Everything a step changes or a command sets (see the module text). ``ledger``: the power W
    cable damping takes out at the last force evaluation (:data:`POWER`) and the energy J it took
    out so far (:data:`DISSIPATED`); ``refine``: the halving levels of the steps after a contact
    (:data:`STEP_LEVEL`, :data:`CONTACT_LEVEL`)."""
    x: np.ndarray
    v: np.ndarray
    rest: np.ndarray
    EA: np.ndarray
    f_ext: np.ndarray
    ledger: np.ndarray
    contact: ContactState
    refine: np.ndarray


class Work(NamedTuple):
    """Scratch: nodal forces and their mass-weighted image, member vectors, the constraint band
    and multipliers, the stage arrays of the explicit methods, the KKT scratch, and the state a
    step started from (``saved[0]`` x, ``saved[1]`` v)."""
    f: np.ndarray
    wf: np.ndarray
    bvec: np.ndarray
    band: np.ndarray
    lam: np.ndarray
    xs: np.ndarray
    vs: np.ndarray
    acc: np.ndarray
    xacc: np.ndarray
    vacc: np.ndarray
    a1: np.ndarray
    kkt: KKTScratch
    saved: np.ndarray


# named entries of the data's small arrays
POWER, DISSIPATED = 0, 1                    # Data.ledger
STEP_LEVEL, CONTACT_LEVEL = 0, 1            # Data.refine
MET, SLACK, LOOK, MOTION = 0, 1, 2, 3       # ContactState.scan
HEAD = 4                                    # ContactState.scan: the gap bounds start here
SAVED_X, SAVED_V = 0, 1                     # Work.saved


def empty(shape, dtype=np.float64):
    """A read-only empty (or zero) array: what switches a record's array off."""
    a = np.zeros(shape, dtype=dtype)
    a.setflags(write=False)
    return a


NO_ROT = empty(0, np.int64)                 # Topology.con_rot, cable_rot of a plain network
NO_COEF3 = empty((0, 1, 3))                 # Topology.con_coef3 of a plain network


def readonly(a):
    """``a`` as a read-only array (a view when it is writable). The arrays of a :class:`Model`
    are all read-only, wherever they come from: numba compiles a kernel once per combination of
    writable and read-only arguments, and the first FB kernel alone takes about a minute."""
    a = np.asarray(a)
    if not a.flags.writeable:
        return a
    view = a.view()
    view.flags.writeable = False
    return view


def workspace(n_rows, n_con, bandwidth, kkt_scratch):
    """A zeroed :class:`Work` for ``n_rows`` rows of state, ``n_con`` constraints of
    ``bandwidth`` and the KKT scratch ``kkt_scratch``."""
    def z(*shape):
        return np.zeros(shape)
    return Work(z(n_rows, 3), z(n_rows, 3), z(n_con, 3), z(n_con, bandwidth + 1), z(n_con),
                z(n_rows, 3), z(n_rows, 3), z(n_rows, 3), z(n_rows, 3), z(n_rows, 3),
                z(n_rows, 3), kkt_scratch, z(2, n_rows, 3))


def bare_model(topo, summary, levels, per_level=3.0, rate=0.0):
    """A :class:`Model` of ``topo`` with every effect off (its ``summary``, ``levels`` and
    ``per_level`` as in :class:`Model`; ``rate`` of its :class:`LedgerRule`)."""
    return Model(topo, readonly(levels), float(per_level), Damping(empty(0)),
                 Stops(empty((0, 0)), 0.0),
                 Strikers(empty(0, np.int64), empty(0, np.int64), 0.0, 1.0, 0.0, 0.0, 0.0,
                          0.0),
                 BarContact(empty((0, 8), np.int64), 0.0, 0.0, 1.0, 0.0, 0.0), summary,
                 LedgerRule(float(rate), False))


def data_of(x, v, rest, EA, f_ext, contact=None):
    """A :class:`Data` of the given arrays (used as they are: float64, C-contiguous), with a
    fresh ledger and refinement and the contact state ``contact`` (none: no bar contact)."""
    if contact is None:
        contact = ContactState(np.zeros(HEAD), np.full(1, -1, dtype=np.int64))
    return Data(x, v, rest, EA, f_ext, np.zeros(2), contact, np.zeros(2))


NO_SUMMARY = Summary(empty((0, 3)), empty(0), empty(0, np.bool_), empty(0),
                     empty(0, np.int64), empty(0, np.int64), empty(0), empty(0),
                     empty((0, 0, 1), np.int64))


def plain(network, rest=None, EA=None, f_ext=None, summary=NO_SUMMARY, levels=None):
    """``(Model, Data, Work)`` of a network (full or reduced: anything with ``topology()``) at
    rest with every effect off: rest lengths, EA and external forces fresh copies of the given
    ones (default: the network's, zero forces); ``levels`` those of the model's state."""
    topo = network.topology()
    n = len(network.x0)
    levels = np.zeros((0, 0, 1)) if levels is None else np.asarray(levels)
    if not levels.size:
        levels = np.zeros((0, 0, 1), dtype=np.int64)
    m = bare_model(topo, summary, np.ascontiguousarray(levels, dtype=np.int64),
                   float(levels.shape[2]) if levels.size else 3.0)
    d = data_of(np.array(network.x0, dtype=np.float64), np.zeros((n, 3)),
                np.array(network.cable_rest_length if rest is None else rest, dtype=np.float64),
                np.array(network.cable_EA if EA is None else EA, dtype=np.float64),
                np.zeros((n, 3)) if f_ext is None else np.array(f_ext, dtype=np.float64))
    return m, d, work_for(topo, n)


def work_for(topo, n_rows):
    """A zeroed :class:`Work` for ``n_rows`` rows of state on the topology ``topo``."""
    return workspace(n_rows, topo.con_tail.shape[0], topo.con_coef.shape[1] - 1,
                     scratch(topo.kkt.dims))


def clone_data(data):
    """An independent copy of a :class:`Data` (every array copied)."""
    return Data(data.x.copy(), data.v.copy(), data.rest.copy(), data.EA.copy(),
                data.f_ext.copy(), data.ledger.copy(),
                ContactState(data.contact.scan.copy(), data.contact.active.copy()),
                data.refine.copy())


def clone_work(work):
    """An independent, zeroed :class:`Work` of the same shapes."""
    return Work(*(KKTScratch(*(np.zeros_like(b) for b in a)) if isinstance(a, KKTScratch)
                  else np.zeros_like(a) for a in work))


@jit_inline
def copy_into(dst, src):
    """``dst[...] = src`` for C-contiguous arrays of the same shape, by a loop: the kernels run
    without reference counting (:mod:`solver.compiled`), and numba's array assignment needs it."""
    a = dst.reshape(-1)
    b = src.reshape(-1)
    for i in range(a.shape[0]):
        a[i] = b[i]


@jit
def copy_data(src, dst):
    """Copy every array of the :class:`Data` ``src`` into ``dst`` (the same shapes)."""
    copy_into(dst.x, src.x)
    copy_into(dst.v, src.v)
    copy_into(dst.rest, src.rest)
    copy_into(dst.EA, src.EA)
    copy_into(dst.f_ext, src.f_ext)
    copy_into(dst.ledger, src.ledger)
    copy_into(dst.contact.scan, src.contact.scan)
    copy_into(dst.contact.active, src.contact.active)
    copy_into(dst.refine, src.refine)
