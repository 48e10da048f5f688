"""The one place that sets numba options for every kernel of the solver.

``cache=True`` keeps compiled kernels in ``__pycache__`` so that a second process (a test, the node, the
CLI) starts without compiling. No ``fastmath``: the benchmarks have not shown it is worth the loss of
IEEE semantics (NaN detection relies on them).
"""
import numba

jit = numba.njit(cache=True, nogil=True)
