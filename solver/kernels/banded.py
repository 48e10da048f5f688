"""Banded LDL^T solves of symmetric systems given by their lower band (``band[i, k] = A[i, i-k]``),
in place and without pivoting: the constraint systems of the dynamics (positive definite) and the
KKT systems of the implicit step (indefinite). Square-root-free: the factor keeps the unit lower L
off the diagonal and ``1 / d_i`` on it (one division per row keeps the dependency chain short).
"""
import math

from solver.compiled import jit
from solver.status import OK, SINGULAR


@jit
def _factor(band, definite):
    """LDL^T of ``band`` in place. A pivot fails (``SINGULAR``) when it is not positive
    (``definite``) or when it is zero or not finite (indefinite systems); else ``OK``."""
    m, width = band.shape
    bw = width - 1
    for i in range(m):
        lo = max(0, i - bw)
        for j in range(lo, i):          # w_j = A_ij - sum_k w_k L_jk  (w_k = L_ik d_k)
            s = band[i, i - j]
            for k in range(lo, j):
                s -= band[i, i - k] * band[j, j - k]
            band[i, i - j] = s
        d = band[i, 0]
        for j in range(lo, i):
            w = band[i, i - j]
            lij = w * band[j, 0]
            band[i, i - j] = lij
            d -= w * lij
        if definite:
            if not d > 0.0:
                return SINGULAR
        elif not (abs(d) > 0.0 and math.isfinite(d)):
            return SINGULAR
        band[i, 0] = 1.0 / d
    return OK


@jit
def band_ldl_factor(band):
    """LDL^T of a symmetric (possibly indefinite) banded matrix, in place; pivots may have either
    sign. Returns ``OK`` or ``SINGULAR`` (a zero or non-finite pivot)."""
    return _factor(band, False)


@jit
def band_ldl_apply(band, rhs):
    """Solve ``A y = rhs`` in place (``rhs`` becomes y) with the factor left in ``band``."""
    m, width = band.shape
    bw = width - 1
    for i in range(m):
        s = rhs[i]
        for k in range(max(0, i - bw), i):
            s -= band[i, i - k] * rhs[k]
        rhs[i] = s
    for i in range(m - 1, -1, -1):
        s = rhs[i] * band[i, 0]
        for k in range(i + 1, min(m, i + bw + 1)):
            s -= band[k, k - i] * rhs[k]
        rhs[i] = s


@jit
def _tridiag_ldl_solve(band, rhs):
    """:func:`band_ldl_solve` for bandwidth 1 (bar chains of flexible-base columns), unrolled."""
    m = band.shape[0]
    d = band[0, 0]
    if not d > 0.0:
        return SINGULAR
    inv = 1.0 / d
    band[0, 0] = inv
    y = rhs[0]
    for i in range(1, m):
        w = band[i, 1]
        lij = w * inv
        d = band[i, 0] - w * lij
        if not d > 0.0:
            return SINGULAR
        inv = 1.0 / d
        band[i, 1] = lij
        band[i, 0] = inv
        y = rhs[i] - lij * y
        rhs[i] = y
    z = rhs[m - 1] * band[m - 1, 0]
    rhs[m - 1] = z
    for i in range(m - 2, -1, -1):
        z = rhs[i] * band[i, 0] - band[i + 1, 1] * z
        rhs[i] = z
    return OK


@jit
def band_ldl_solve(band, rhs):
    """Solve ``A y = rhs`` in place for a positive definite banded A (``band`` is overwritten by
    its factor). Returns ``OK`` or ``SINGULAR`` (a pivot that is not positive)."""
    if band.shape[1] == 2:
        return _tridiag_ldl_solve(band, rhs)
    status = _factor(band, True)
    if status == OK:
        band_ldl_apply(band, rhs)
    return status
