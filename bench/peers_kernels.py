"""The kernel bound of ``tensegrity bench --peers``: kernels timed in numba loops (no Python).

``profile(model, dt)`` times, at the model's current state, one force-and-
constraint evaluation (:func:`solver.kernels.dynamics.accelerations`) and the other per-step
kernels of the
projected Runge-Kutta methods (kink prediction, position and velocity projection, and with bar
contact the scan that lists the pairs that could touch), each as the mean over a jitted loop of
``n`` calls, so that no interpreter overhead is included.
"""
from __future__ import annotations

import time

import numpy as np

from solver.kernels import dynamics as dyn
from solver.kernels import records
from solver.compiled import jit
from solver.kernels.effects import gate
from solver.kernels.kinks import next_kink
from solver.kernels.records import SLACK
from solver.models.base import RecordModel


@jit
def _loop_acc(x, v, m, d, w, out, n):
    bad = 0
    for _ in range(n):
        bad += dyn.accelerations(x, v, m, d, w, out)
    return bad


@jit
def _loop_gate(x, v, acc, m, d, h, n):
    for _ in range(n):
        gate(x, v, acc, m, d, h)
    return d.contact.scan[SLACK]


@jit
def _loop_kink(x, v, acc, m, d, h, n):
    s = 0.0
    for _ in range(n):
        s += next_kink(x, v, acc, m, d, h, 1e-3 * h)
    return s


@jit
def _loop_project_positions(x_off, xs, topo, w, tol, max_iter, n):
    bad = 0
    for _ in range(n):
        records.copy_into(xs, x_off)
        bad += dyn.project_positions(xs, topo, w, tol, max_iter)
    return bad


@jit
def _loop_copy(x_off, xs, n):
    for _ in range(n):
        records.copy_into(xs, x_off)
    return xs[0, 0]


@jit
def _loop_project_velocities(x, v_off, vs, topo, w, n):
    bad = 0
    for _ in range(n):
        records.copy_into(vs, v_off)
        bad += dyn.project_velocities(x, vs, topo, w)
    return bad


def _timed(fn, *args, n):
    fn(*args, 2)                            # compile / warm
    best = np.inf
    for _ in range(3):
        t0 = time.thread_time()
        fn(*args, n)
        best = min(best, (time.thread_time() - t0) / n)
    return best


def profile(model, dt, n=2000, tol=1e-12, max_iter=3):
    """CPU seconds per call of each per-step kernel at the model's state (best of 3 loops of
    ``n``).

    Returns ``{'accelerations': s, 'next_kink': s, 'project_positions': s,
    'project_velocities': s}`` (``accelerations`` is one force-and-constraint evaluation), and
    ``contact_scan`` with bar contact (:func:`solver.kernels.contactsteps.gate`, on copies of the
    contact state, which the evaluation then uses). The
    projections are timed from a state pushed off the constraint manifold by one explicit Euler
    step of ``dt`` (what they see after a Runge-Kutta step); the copy that restores it is
    subtracted. Raises ``TypeError`` for a model not stepped on records (``chain1d``)."""
    if not isinstance(model, RecordModel):
        raise TypeError(f'model {model.name!r} has no kernel records: cannot time its kernels')
    x, v = np.array(model.x), np.array(model.v)
    m, ws = model.rec, model.work
    net = m.topo
    # copies of the data: the timed loops change the contact state and the ledger
    d = model.data._replace(contact=records.ContactState(model.data.contact.scan.copy(),
                                                         model.data.contact.active.copy()),
                            ledger=model.data.ledger.copy())
    acc = np.zeros_like(x)
    out = {}
    if m.bar_contact.pairs.shape[0]:      # bar contact: one scan per step, as the step makes it
        dyn.accelerations(x, v, m, d, ws, acc)
        # the force evaluation then looks at the pairs the scan listed
        out['contact_scan'] = _timed(_loop_gate, x, v, acc, m, d, dt, n=n)
    t_acc = _timed(_loop_acc, x, v, m, d, ws, acc, n=n)
    dyn.accelerations(x, v, m, d, ws, acc)
    t_kink = _timed(_loop_kink, x, v, acc, m, d, dt, n=n)
    x_off = x + dt * v + 0.5 * dt * dt * acc
    v_off = v + dt * acc
    xs = np.zeros_like(x)
    t_copy = _timed(_loop_copy, x_off, xs, n=n)
    t_pp = _timed(_loop_project_positions, x_off, xs, net, ws, tol, max_iter, n=n) - t_copy
    t_pv = _timed(_loop_project_velocities, x, v_off, xs, net, ws, n=n) - t_copy
    return dict(out, accelerations=t_acc, next_kink=t_kink, project_positions=max(t_pp, 0.0),
                project_velocities=max(t_pv, 0.0))


def advance_profile(sim, duration, output_dt, top=8):
    """cProfile of ``sim.advance(output_dt)`` calls over ``duration`` s: the ``top`` functions by
    own time, as ``[{'function': 'file:line(name)', 'fraction': own time / total}]``, plus the
    total seconds. Shows where the Python side of a step goes."""
    import cProfile
    import pstats
    prof = cProfile.Profile()
    n = int(round(duration / output_dt))
    prof.enable()
    for _ in range(n):
        sim.advance(output_dt)
    prof.disable()
    stats = pstats.Stats(prof).stats
    total = sum(v[2] for v in stats.values())
    rows = sorted(stats.items(), key=lambda kv: kv[1][2], reverse=True)[:top]
    out = []
    for (path, line, name), v in rows:
        short = '/'.join(str(path).split('/')[-2:])
        out.append({'function': f'{short}:{line}({name})', 'calls': int(v[1]),
                    'fraction': v[2] / total if total else 0.0})
    return {'total_s': total, 'top': out}
