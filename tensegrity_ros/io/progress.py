"""Progress bars of long commands (runs, sweeps, fits, the paper's table)."""
from __future__ import annotations

import sys


def progress_bar(total, desc, unit='run', leave=True):
    """A tqdm bar of ``total`` ``unit``s on a terminal (stderr); nothing otherwise, nor for a
    total of 0. Returns ``(update, close)``: ``update`` is None without a bar."""
    if not sys.stderr.isatty() or total == 0:
        return None, (lambda: None)
    from tqdm import tqdm
    bar = tqdm(total=total, desc=desc, unit=unit, leave=leave)
    return bar.update, bar.close
