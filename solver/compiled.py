"""The one place that sets numba options for every kernel of the solver.

``cache=True`` keeps compiled kernels on disk so that a second process (a test, the node, the CLI)
starts without compiling. Numba checks only the source file of a cached function itself, not the
functions it calls in other modules, so a kernel of ``integrators.py`` would keep running the old
``dynamics.py`` code after an edit. The cache therefore lives in a folder named after a hash of
every solver source file in every sub-package (and the numba version): any edit to the solver
starts a fresh cache.

No ``fastmath``: the benchmarks have not shown it is worth the loss of IEEE semantics (NaN
detection relies on them).
"""
import hashlib
import os
import shutil
import uuid
from pathlib import Path

import numba


def source_hash(directory=Path(__file__).parent, salt=''):
    """sha256 (hex) of ``salt`` and of the relative paths and contents of every ``*.py`` file
    below ``directory``, sub-packages included."""
    directory = Path(directory)
    digest = hashlib.sha256(salt.encode())
    for path in sorted(directory.rglob('*.py')):
        digest.update(path.relative_to(directory).as_posix().encode() + b'\0')
        digest.update(path.read_bytes() + b'\0')
    return digest.hexdigest()


def _writable(folder):
    """Whether this process can write in ``folder`` (made if missing): a probe file of its own
    name, written and removed (processes starting at once each test with their own file: with a
    shared name one could remove another's probe, which then took the folder for read-only and
    compiled into the fallback cache, where no other process looks)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f'.probe-{os.getpid()}-{uuid.uuid4().hex}'
        probe.write_bytes(b'')
        probe.unlink()
        return True
    except OSError:
        return False


def _cache_dir():
    tag = f'numba-{source_hash(salt=numba.__version__)[:16]}'
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

# Kernels run without numba's reference counting (``_nrt=False``): with it, every compiled function
# increments the count of every array it receives on entry and decrements it on every exit, and a
# kernel that receives the named records (solver.kernels.records: about 60 arrays) pays 120 atomic
# operations per call, which LLVM's pruning cannot remove across the kernels' loops. Measured
# (perf, a sym3d column stepped with RK4): 40 % of the integrator's time went to those counts.
# A kernel of ``jit`` therefore allocates nothing (no ``np.empty``, no array copies, no
# ``a[:] = b`` of arrays: :func:`solver.kernels.records.copy_into` copies by loops); it only
# reads and writes arrays its caller owns, so no count is needed. A kernel that must allocate
# uses ``jit_alloc``, with counting.
jit = numba.njit(cache=True, nogil=True, _nrt=False)
jit_alloc = numba.njit(cache=True, nogil=True)

# Small helpers called inside member loops (``kernels.rotation.rel``): inlined by numba. LLVM
# declines to inline a helper that reads module-level arrays (``ROT_C``/``ROT_S``), and the call
# then costs ten times the loop body (constraint_error_arrays: 2.4 us instead of 0.27 us for 50
# members).
jit_inline = numba.njit(cache=True, nogil=True, inline='always', _nrt=False)

# Lane kernels (solver.kernels.lanes: many instances of one topology, the instance index innermost)
# use NumPy's error model: with the default 'python' model every float division carries a check
# for a zero divisor that raises ZeroDivisionError, and that branch stops LLVM from vectorising
# the loop over instances. Under 'numpy' a division by zero gives inf or NaN as IEEE says; every
# other operation, and so every result of a lane that divides by no zero, is the same.
jit_lanes = numba.njit(cache=True, nogil=True, _nrt=False, error_model='numpy')


# -- calling a compiled kernel without numba's dispatch ------------------------------------------
# A kernel call goes through numba's dispatcher, which types every argument to pick the compiled
# overload: about 4 us for the ~60 arrays of an integrator's checked call, per call. A caller that
# makes the same call over and over with arguments of unchanging types (Simulation.advance) looks
# the overload up once and calls its entry point, which only unboxes the arguments.
_SIGNATURES: dict = {}


def _layout(value):
    """A key that determines numba's type of an argument: array dtype, dimensions, layout and
    flags; tuples element by element; other values by their Python type."""
    import numpy as np
    if isinstance(value, np.ndarray):
        f = value.flags
        return (value.dtype.str, value.ndim, f.c_contiguous, f.f_contiguous, f.writeable,
                f.aligned)
    if isinstance(value, tuple):
        return tuple(_layout(v) for v in value)
    return type(value)


def compiled_overload(dispatcher, args):
    """The entry point of the overload ``dispatcher`` has compiled for the types of ``args``, or
    None when it has none yet (call the dispatcher once first). Calling it is calling the kernel
    with arguments of exactly those types; with others it would misread them, so a caller keeps it
    only while its arguments are the same objects (or of the same types)."""
    key = (id(dispatcher), tuple(_layout(a) for a in args))
    sig = _SIGNATURES.get(key)
    if sig is None:
        from numba.core.typing.typeof import Purpose, typeof
        sig = _SIGNATURES[key] = tuple(typeof(a, Purpose.argument) for a in args)
    cres = dispatcher.overloads.get(sig)
    return None if cres is None else cres.entry_point
