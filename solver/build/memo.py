"""Build once what many simulations of one network topology share: a memo that is on only inside
:func:`sharing` (the batched runs of :mod:`solver.simulate.batch` switch it on for a batch, and a
``Simulation`` for its own construction, where the model's choice and the model reduce the same
network).

Keys are digests of the *values* a result is computed from (array bytes, shapes and dtypes), so a
hit returns what the computation would return for those values: the sym3d reduction of a network
(:func:`solver.models.sym3d.reduce_network`: the orbit and member maps depend on the topology and
the geometry's symmetry only, the rest on the values; see there), the constraint structure of a
network (:func:`solver.build.network._constraints`: geometry, masses and members, not the cables,
so points that differ in prestrain share it), the bar pairs that can touch and their reduced
rows (:mod:`solver.models.extras`). Outside :func:`sharing` nothing is kept. What it returns is
shared: callers copy it or only read it.
"""
from __future__ import annotations

import contextlib
import hashlib
import threading

import numpy as np

_LOCK = threading.Lock()
_DEPTH = 0
_MEMO: dict = {}
MAX_ENTRIES = 256            # a long-lived worker that meets many topologies forgets the oldest


@contextlib.contextmanager
def sharing():
    """While inside (in any thread of the process), :func:`lookup` keeps its results; the memo
    is emptied when the last ``sharing`` block ends."""
    global _DEPTH
    with _LOCK:
        _DEPTH += 1
    try:
        yield
    finally:
        with _LOCK:
            _DEPTH -= 1
            if _DEPTH == 0:
                _MEMO.clear()


def active():
    """Whether a :func:`sharing` block is open."""
    return _DEPTH > 0


def key(kind, *values):
    """A digest of ``kind`` and ``values`` (arrays, numbers, strings)."""
    h = hashlib.blake2b(kind.encode(), digest_size=20)
    for v in values:
        if isinstance(v, np.ndarray) or hasattr(v, '__array__'):
            a = np.ascontiguousarray(v)
            h.update(f'|{a.dtype.str}{a.shape}|'.encode())
            h.update(a.tobytes())
        else:
            h.update(f'|{v!r}|'.encode())
    return h.digest()


def lookup(kind, values, compute):
    """``compute()``, kept under the digest of ``kind`` and ``values`` while :func:`sharing` is
    on (a kept exception is raised again). Outside :func:`sharing`: ``compute()``."""
    if not _DEPTH:
        return compute()
    k = key(kind, *values)
    hit = _MEMO.get(k)
    if hit is None:
        try:
            hit = (True, compute())
        except Exception as exc:             # noqa: BLE001 - kept, raised again below
            hit = (False, exc)
        with _LOCK:
            if len(_MEMO) >= MAX_ENTRIES:
                _MEMO.pop(next(iter(_MEMO)))
            _MEMO[k] = hit
    ok, value = hit
    if not ok:
        raise value.with_traceback(None)
    return value
