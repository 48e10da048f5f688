"""The one place that sets numba options for every kernel of the solver.

``cache=True`` keeps compiled kernels on disk so that a second process (a test, the node, the CLI)
starts without compiling. Numba checks only the source file of a cached function itself, not the
functions it calls in other modules, so a kernel of ``integrators.py`` would keep running the old
``dynamics.py`` code after an edit. The cache therefore lives in a folder named after a hash of
every solver source file (and the numba version): any edit to the solver starts a fresh cache.

No ``fastmath``: the benchmarks have not shown it is worth the loss of IEEE semantics (NaN
detection relies on them).
"""
import hashlib
import os
import shutil
from pathlib import Path

import numba


def _source_hash():
    digest = hashlib.sha256(numba.__version__.encode())
    for path in sorted(Path(__file__).parent.glob('*.py')):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _writable(folder):
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / '.probe'
        probe.write_bytes(b'')
        probe.unlink()
        return True
    except OSError:
        return False


def _cache_dir():
    tag = f'numba-{_source_hash()}'
    if os.environ.get('NUMBA_CACHE_DIR'):
        return Path(os.environ['NUMBA_CACHE_DIR']) / f'tensegrity-{tag}'
    local = Path(__file__).parent / '__pycache__'
    if _writable(local / tag):
        for old in local.glob('numba-*'):        # caches of earlier solver sources
            if old.name != tag:
                shutil.rmtree(old, ignore_errors=True)
        return local / tag
    return Path.home() / '.cache' / 'tensegrity_ros' / tag


CACHE_DIR = _cache_dir()
numba.config.CACHE_DIR = str(CACHE_DIR)

jit = numba.njit(cache=True, nogil=True)

# Small helpers called inside member loops (``dynamics._rel``): inlined by numba itself. LLVM
# declines to inline a helper that reads module-level arrays (``ROT_C``/``ROT_S``), and the call
# then costs ten times the loop body (constraint_error_arrays: 2.4 us instead of 0.27 us for 50
# members).
jit_inline = numba.njit(cache=True, nogil=True, inline='always')
