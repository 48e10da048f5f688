"""The step control the effects of a scene ask of an integrator, behind effect-free entries.

An integrator kernel calls :func:`solver.kernels.dynamics.accelerations` for the forces of every
effect, and the entries here for where a step may end and whether it was good; it never asks which
effects a scene has. Each entry does nothing (returns the step as given, keeps nothing) when the
effects it serves are off, so a scene without contact takes the plain path.

- :func:`start`, :func:`finish`: at the start and end of an integrator call (the contact scans
  resume from where the last call ended, or rescan; the positions a finished call ended at).
- :func:`fixed_step_limit`: the step of a fixed-step method near a contact its steps cannot
  resolve (strikers); :func:`scan_limit`: the step of an adaptive method near bars that could
  touch; :func:`gate`: a method whose steps are taken whole (RATTLE) tells the forces where to
  look.
- :func:`plan`, :func:`begin_trial`, :func:`trial_kept`, :func:`undo_trial`: a step that may be
  tried whole beside a near miss and kept only when it surely passed clear of every contact and
  kept the energy balance (docs/physics.md section 7.1).
- :func:`refining`, :func:`ledger_energy`, :func:`mark`, :func:`back_to`, :func:`halvings`,
  :func:`keep_levels`, :func:`rate`: the steps after a contact checked against the energy
  ledger and taken
  again at half their length when they used more than their share.

The small entries are inlined into the integrators (``jit_inline``): each is a few reads of the
records, and a call passes the records' ~60 arrays by value (0.9 us of a 13 us RK4 step of the
sym3d FB column, measured).
"""
from solver.compiled import jit, jit_inline
from solver.kernels.barcontact import remember
from solver.kernels.contact import striker_step
from solver.kernels.contactsteps import (add_motion, bounded_contact_energy, contact_step,
                                       gate as contact_gate, motion_bound, motion_so_far,
                                       passed_clear, rescan, resume)
from solver.kernels.records import (CONTACT_LEVEL, DISSIPATED, LOOK, MET, POWER, SAVED_V,
                                    SAVED_X, SLACK, STEP_LEVEL, copy_into)
from solver.kernels.summary import contact_energy, step_energy


@jit_inline
def start(x, m, d):
    """At the start of an integrator call from positions ``x``."""
    if m.bar_contact.pairs.shape[0] != 0:
        resume(x, d.contact.scan, d.contact.active)


@jit_inline
def finish(x, m, d):
    """At the end of an integrator call that finished at positions ``x``."""
    if m.bar_contact.pairs.shape[0] != 0:
        remember(x, d.contact.scan)


@jit_inline
def fixed_step_limit(x, v, acc, m, h):
    """``h``, or the shorter step a fixed-step method takes to resolve a striker contact
    (:func:`solver.kernels.contact.striker_step`)."""
    if m.strikers.row.shape[0] != 0:
        return striker_step(x, v, acc, m, h)
    return h


@jit_inline
def scan_limit(x, v, acc, m, d, h):
    """``h``, or the step an adaptive method takes where bars or bases could touch within it
    (:func:`solver.kernels.contactsteps.contact_step`)."""
    if m.bar_contact.pairs.shape[0] != 0:
        return contact_step(x, v, acc, m.bar_contact, m.levels, h, d.contact.scan,
                            d.contact.active, 1.0)
    return h


@jit_inline
def gate(x, v, acc, m, d, h):
    """For a method whose step of ``h`` is taken whole
    (:func:`solver.kernels.contactsteps.gate`)."""
    if m.bar_contact.pairs.shape[0] != 0:
        contact_gate(x, v, acc, m.bar_contact, m.levels, h, d.contact.scan, d.contact.active)


# -- a step tried whole beside a near miss -------------------------------------------------------
@jit_inline
def plan(x, v, acc, m, d, h, met, scale):
    """``(step, trial, known)`` for a step of at most ``h`` from ``x``, ``v`` (accelerations
    ``acc`` just evaluated; ``met`` the contacts met before that evaluation): ``step`` is ``h``
    when no contact can start within it; otherwise the contact step
    (:func:`~solver.kernels.contactsteps.contact_step`, its ``T / steps`` part times ``scale``,
    the refinement of the steps after a contact), and ``trial`` says whether ``h`` may be tried
    first (no contact touched at the start): :func:`begin_trial`, the step, :func:`trial_kept`,
    else :func:`undo_trial` and the shorter step. ``known``: the motion the scans had summed at the
    start, for :func:`trial_kept`."""
    bc = m.bar_contact
    if bc.pairs.shape[0] == 0:
        return h, False, 0.0
    scan = d.contact.scan
    touched_at_start = scan[MET] > met
    known = motion_so_far(scan)
    h_c = contact_step(x, v, acc, bc, m.levels, h, scan, d.contact.active, scale)
    if h_c >= h:
        return h, False, known
    return h_c, not touched_at_start, known


@jit_inline
def has_bar_contact(m):
    """Whether the model has pairs of bars (or bases) that can touch."""
    return m.bar_contact.pairs.shape[0] != 0


@jit_inline
def surely_clear(v, acc, d, h):
    """Whether the contact scans already know that no contact can start within a step of ``h``
    from velocities ``v``, accelerations ``acc``: the quick test of
    :func:`~solver.kernels.contactsteps.contact_step` (the gap bound left exceeds the bound of
    any relative motion), without changing the contact state. ``v``, ``acc`` may be the nodes
    of largest speed and acceleration alone (the bound depends on those only)."""
    return d.contact.scan[SLACK] > motion_bound(v, acc, h)


@jit_inline
def with_contact_energy(e, x, m, d):
    """``e`` plus the energy J stored in touching bars and bases at ``x`` (as
    :func:`~solver.kernels.summary.state_summary` adds it; ``e`` where the model has no bar
    contact)."""
    if m.bar_contact.pairs.shape[0] != 0:
        e += contact_energy(x, m, d)
    return e


@jit
def begin_trial(x, v, d, w):
    """Before a step tried whole: keep its start in ``w.saved`` and what the steps change of the
    run state (returned, for :func:`trial_kept` and :func:`undo_trial`); the forces of the step
    look for every contact."""
    save_start(x, v, w)
    scan = d.contact.scan
    trial = mark(d) + (scan[LOOK],)
    scan[LOOK] = 1.0
    return trial


@jit
def _kept_balance(x0, v0, x, v, m, d, h, dissipated):
    """Whether a step of ``h`` from ``x0``, ``v0`` to ``x``, ``v`` that met no contact (cable
    damping having taken out ``dissipated`` J before it) kept the energy balance within its
    share of the ledger's limit: ``|E1 + D1 - D0 - E0| <= rate h |E0|``, ``rate`` =
    ``divergence.energy_error`` per second. Beside contacts the bars vibrate fast: a whole step
    that passes clear of every contact can still be too long for them. True where the model has
    no summary of its state."""
    e0 = step_energy(x0, v0, m, d)
    if e0 != e0:
        return True
    e1 = step_energy(x, v, m, d)
    return abs(e1 + (d.ledger[DISSIPATED] - dissipated) - e0) <= m.ledger.rate * h * abs(e0)


@jit
def trial_kept(x, v, acc, m, d, w, h, known, trial):
    """Whether the step of ``h`` just tried whole (:func:`begin_trial` returned ``trial``) is
    kept: none of its evaluations met a contact, it surely passed clear of every contact
    (:func:`~solver.kernels.contactsteps.passed_clear`: a near miss changes nothing) and it kept
    the energy balance (:func:`_kept_balance`)."""
    before, power, dissipated, flag = trial
    scan = d.contact.scan
    saved = w.saved
    if scan[MET] == before and passed_clear(
            saved[SAVED_X], saved[SAVED_V], acc, x, m.bar_contact, m.levels, h, scan, known) and (
            _kept_balance(saved[SAVED_X], saved[SAVED_V], x, v, m, d, h, dissipated)):
        add_motion(scan, saved[SAVED_V], acc, h)  # the slack was for the shorter step
        d.contact.active[0] = -1
        return True
    return False


@jit
def undo_trial(x, v, d, w, trial):
    """Back to the start of a step tried whole that was not kept."""
    before, power, dissipated, flag = trial
    _back_to_start(x, v, d, w, before, power, dissipated)
    d.contact.scan[LOOK] = flag


# -- the steps after a contact, checked against the ledger ---------------------------------------
@jit_inline
def refining(m, d):
    """Whether the steps are checked against the energy ledger: bar contact with a summary of
    the state, ``contact.refine: ledger``, and a contact met since the reset. Until a contact,
    the steps are the plain ones. Contacts excite the fast vibrations of bars and nodes, which
    RK4 at the scene's step damps, and a lasting contact oscillates stiffly: both lose energy,
    which the ledger counts."""
    return m.ledger.refine and d.contact.scan[MET] > 0.0


@jit_inline
def halvings(m, d):
    """The halvings of the step and of the contact step the last call ended with (0, 0 where the
    steps are never refined)."""
    if m.ledger.refine:
        return int(d.refine[STEP_LEVEL]), int(d.refine[CONTACT_LEVEL])
    return 0, 0


@jit_inline
def rate(m):
    """The energy balance a step may spend, relative, per second (``divergence.energy_error``)."""
    return m.ledger.rate


@jit_inline
def keep_levels(m, d, level, clevel):
    """Keep the halvings for the next call (the Simulation keeps, restores and resets them with
    the rest of the data)."""
    if m.ledger.refine:
        d.refine[STEP_LEVEL] = level
        d.refine[CONTACT_LEVEL] = clevel


@jit
def ledger_energy(x, v, m, d):
    """Energy J of a state within or at the end of a step the contact scans bounded: without
    contact (:func:`~solver.kernels.summary.step_energy`) plus what touching bars and bases store
    (:func:`~solver.kernels.contactsteps.bounded_contact_energy`)."""
    return step_energy(x, v, m, d) + bounded_contact_energy(x, m.bar_contact, m.levels,
                                                            m.per_level, d.contact.scan)


@jit_inline
def mark(d):
    """What a step changes of the run state besides ``x``, ``v``: ``(contacts met, the damping's
    power, the energy it took out)``, for :func:`back_to`."""
    return d.contact.scan[MET], d.ledger[POWER], d.ledger[DISSIPATED]


@jit_inline
def dissipated(d):
    """The energy J cable damping took out so far."""
    return d.ledger[DISSIPATED]


@jit_inline
def power(d):
    """The power W the forces of the last evaluation dissipate (cable damping; 0 without)."""
    return d.ledger[POWER]


@jit_inline
def dissipate(d, energy):
    """Book ``energy`` J taken out by a step (the integral of :func:`power` over it)."""
    d.ledger[DISSIPATED] += energy


@jit
def back_to(x, v, d, w, at):
    """Undo a step: ``x``, ``v`` from ``w.saved``, the run state from :func:`mark`'s ``at``; the
    contact scans start over."""
    met, power, dis = at
    _back_to_start(x, v, d, w, met, power, dis)
    rescan(d.contact.scan, d.contact.active)


@jit
def _back_to_start(x, v, d, w, met, pw, dis):
    """``x``, ``v`` from ``w.saved``; the contacts met and the ledger to the given values."""
    copy_into(x, w.saved[SAVED_X])
    copy_into(v, w.saved[SAVED_V])
    d.ledger[POWER] = pw
    d.ledger[DISSIPATED] = dis
    d.contact.scan[MET] = met


@jit
def save_start(x, v, w):
    """Keep the start of a step in ``w.saved`` (for :func:`back_to`)."""
    copy_into(w.saved[SAVED_X], x)
    copy_into(w.saved[SAVED_V], v)

