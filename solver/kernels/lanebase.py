"""The axial base force of every lane of a lane group in one call.

A node's array publishes each column's base force with every frame: one force-and-constraint
evaluation of the column. One at a time, that is :func:`solver.analysis.support._model_base_force`
per column (a compiled evaluation, and its call from Python); here the lanes are evaluated
together (:func:`solver.kernels.lanedata.evaluate`, every lane bit for bit the scalar
evaluation), with the contact state of each lane set as that kernel sets its copy: every pair of
bars and every prism's bases looked at, except in a lane whose contact scans bound every gap
above zero at the positions its last call ended at (``scan[SLACK]`` positive there: its next
step would not look either): no contact force can act, so none is looked for, and the forces are
the same. The lanes' own contact state, ledger and step control are put back afterwards, so the
call changes no lane's data.
"""
from __future__ import annotations

from solver.compiled import jit_inline, jit_lanes
from solver.kernels import lanedata
from solver.kernels.barcontact import at_remembered
from solver.kernels.records import LOOK, SLACK
from solver.status import OK


@jit_inline
def _rows(scan, scan_to, active, active_to, ledger, ledger_to, k):
    """Row ``k`` of ``scan``, ``active``, ``ledger`` into the same rows of the ``_to`` arrays."""
    for i in range(scan.shape[1]):
        scan_to[k, i] = scan[k, i]
    for i in range(active.shape[1]):
        active_to[k, i] = active[k, i]
    for i in range(ledger.shape[1]):
        ledger_to[k, i] = ledger[k, i]


@jit_lanes
def base_forces(m, S, L, W, X, C, scan, active, ledger, go, st, base, mult, out):
    """``out[k, c]``: the axial base force of column ``c`` of lane ``k`` (positive compressive)
    at the state in ``S``, as :func:`solver.analysis.support._model_base_force` gives it for
    that lane alone: ``-sum_i mult[c, i] (f - f_ext)[base[c, i], 2]`` over the member forces of
    one evaluation (0 for a column without a base, ``base[c, 0]`` -1). ``scan``, ``active``,
    ``ledger`` (shaped as ``S``'s), ``go`` and ``st`` (B,) keep what the call puts back; ``L``,
    ``W``, ``X`` are scratch (a lane call refills them). Returns the number of lanes whose
    evaluation failed (their ``out`` rows are left unset)."""
    n_lanes = S.x.shape[0]
    for k in range(n_lanes):
        _rows(S.scan, scan, S.active, active, S.ledger, ledger, k)
        go[k] = C.go[k]
        st[k] = C.st[k]
        if S.scan[k, SLACK] > 0.0 and at_remembered(S.x[k], S.scan[k]):
            S.scan[k, LOOK] = 0.0       # the scans bound every gap above 0 here: no contact
        else:
            S.scan[k, LOOK] = 1.0
            S.active[k, 0] = -1
        C.go[k] = 1
        C.st[k] = OK
    lanedata.enter(S, L)
    lanedata.evaluate(L.x, L.v, m, S, L, W, X, C, W.acc)
    failed = 0
    f = W.f
    for k in range(n_lanes):
        if C.st[k] != OK:
            failed += 1
        else:
            for c in range(base.shape[0]):          # solver.analysis.support._base_sum
                s = 0.0
                if base[c, 0] >= 0:
                    for i in range(base.shape[1]):
                        p = base[c, i]
                        s += mult[c, i] * (f[p, 2, k] - S.f_ext[k, p, 2])
                    s = -s
                out[k, c] = s
        _rows(scan, S.scan, active, S.active, ledger, S.ledger, k)
        C.go[k] = go[k]
        C.st[k] = st[k]
    return failed
