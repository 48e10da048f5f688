"""Progress bars of long commands (runs, sweeps, fits, the paper's table)."""
from __future__ import annotations

import sys


def _bar(total, desc, unit, leave):
    """A tqdm bar of ``total`` ``unit``s on a terminal (stderr); None otherwise, or for a total
    of 0."""
    if not sys.stderr.isatty() or total == 0:
        return None
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, unit=unit, leave=leave)


def progress_bar(total, desc, unit='run', leave=True):
    """A tqdm bar of ``total`` ``unit``s on a terminal (stderr); nothing otherwise, nor for a
    total of 0. Returns ``(update, close)``: ``update`` is None without a bar."""
    bar = _bar(total, desc, unit, leave)
    return (None, (lambda: None)) if bar is None else (bar.update, bar.close)


def growing_bar(total, desc, unit='run'):
    """:func:`progress_bar` whose total can grow while it runs (a sweep's sensitivity twins,
    known only once the points they check have run). Returns ``(update, grow, close)``;
    ``update`` and ``grow`` (``grow(n)`` adds ``n`` to the total) are None without a bar."""
    bar = _bar(total, desc, unit, True)
    if bar is None:
        return None, None, (lambda: None)

    def grow(n):
        bar.total += n
        bar.refresh()
    return bar.update, grow, bar.close
