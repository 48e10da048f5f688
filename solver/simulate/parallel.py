"""Independent simulations stepped on threads: the compiled kernels release the GIL
(``nogil=True``, :mod:`solver.compiled`), so simulations that share nothing advance on every
core at
once from one process. Used by :mod:`solver.simulate.batch` and
:class:`~solver.simulate.array.ArraySimulation`.
"""
from __future__ import annotations

import itertools
import os
import threading
from concurrent.futures import ThreadPoolExecutor

_POOLS: dict = {}
_LOCK = threading.Lock()
_INSIDE = threading.local()          # set while a thread runs a share: nested calls run serially


def default_threads():
    """The cores this process may run on."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:                          # not on Linux
        return os.cpu_count() or 1


def _pool(n):
    """A process-wide pool of ``n`` threads (kept: a pool per interval would cost more than a
    short interval)."""
    with _LOCK:
        pool = _POOLS.get(n)
        if pool is None:
            pool = _POOLS[n] = ThreadPoolExecutor(n, thread_name_prefix=f'tensegrity-{n}')
        return pool


def each(fn, items, threads=None):
    """``[(True, fn(item)) or (False, exception)]`` for every item of ``items``, in order, on
    ``threads`` threads (default :func:`default_threads`): each thread (the calling one too)
    takes the next item not yet taken until none is left. An exception of one item is returned
    in its place; the others still run. Anything else (``KeyboardInterrupt``) stops every thread
    after its current item and is raised. Called from inside an item (a batch of arrays of
    columns), it runs its items in that thread."""
    items = list(items)
    out = [None] * len(items)
    taken = itertools.count()
    stop = []

    def share():
        outer = getattr(_INSIDE, 'on', False)
        _INSIDE.on = True
        try:
            while not stop:
                i = next(taken)
                if i >= len(items):
                    return
                try:
                    out[i] = (True, fn(items[i]))
                except Exception as exc:           # noqa: BLE001 - returned in its place
                    out[i] = (False, exc)
        except BaseException:
            stop.append(True)
            raise
        finally:
            _INSIDE.on = outer

    n = min(max(1, int(threads or default_threads())), len(items))
    if getattr(_INSIDE, 'on', False):
        n = 1
    if n <= 1:
        share()
        return out
    pool = _pool(n - 1)
    futures = [pool.submit(share) for _ in range(1, n)]
    try:
        share()
    finally:
        errors = [f.exception() for f in futures]     # waits for every thread
    for e in errors:
        if e is not None:
            raise e                      # a stop raised in another thread
    return out
