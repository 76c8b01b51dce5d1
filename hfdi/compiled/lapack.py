"""LAPACK for the compiled attempt: the Python path's routines, called into work arrays.

The Python path solves its dense systems with scipy's LAPACK
(:mod:`hfdi.linalg`: ``potrf``/``potrs`` or ``gesv`` for a Newton correction,
``getrf``/``getrs`` for HFDI's matrix ``B``). The compiled attempt calls the same routines of the
same library, so that both paths give the same numbers (with kernels equal to
the model's methods, the same steps bit for bit), but straight and into
arrays allocated once per stage: ``np.linalg.solve`` in compiled code
allocates, copies and checks at every call (for N = 12, 0.99 µs against
0.67 µs for the call here).

The routines are looked up in ``scipy.linalg.cython_lapack`` when this module
is imported and made known to LLVM under names of their own (llvmlite's
``add_symbol``); the compiled code calls them by those names as external
functions, so it stays cacheable on disk (an address baked into the code
would not be).

Matrices are C-ordered (N, N) arrays here; LAPACK reads columns, so each
routine is given the transpose, written into the work array ``lu``.
"""
from __future__ import annotations

import math

import llvmlite.binding as llvm
import numpy as np
from numba import njit, types
from numba.extending import get_cython_function_address, overload

from ..linalg import CHOLESKY_FROM, SYMMETRY_TOLERANCE
from .signatures import JIT_OPTIONS

__all__ = ["all_finite", "gesv", "solve", "symmetric", "getrf", "getrs", "getrs_columns",
           "work_arrays", "INTS"]


def _bind(routine: str, arguments: int):
    """``routine`` of scipy's LAPACK as an external function of ``arguments`` pointers."""
    symbol = f"hfdi_scipy_lapack_{routine}"
    llvm.add_symbol(symbol, get_cython_function_address("scipy.linalg.cython_lapack", routine))
    return types.ExternalFunction(symbol, types.void(*[types.voidptr] * arguments))


# dgesv(n, nrhs, a, lda, ipiv, b, ldb, info)
_dgesv = _bind("dgesv", 8)
# dgetrf(m, n, a, lda, ipiv, info)
_dgetrf = _bind("dgetrf", 6)
# dgetrs(trans, n, nrhs, a, lda, ipiv, b, ldb, info)
_dgetrs = _bind("dgetrs", 9)
# dpotrf(uplo, n, a, lda, info)
_dpotrf = _bind("dpotrf", 5)
# dpotrs(uplo, n, nrhs, a, lda, b, ldb, info)
_dpotrs = _bind("dpotrs", 8)

# entries of the int32 ``ints`` work array (INTS of them)
_N, _NRHS, _INFO, _TRANS, _UPLO = range(5)
INTS = 5
# the rule of the Python path (hfdi.linalg.solve, hfdi.linalg.is_symmetric)
_SYMMETRY_TOLERANCE = SYMMETRY_TOLERANCE
_CHOLESKY_FROM = CHOLESKY_FROM


_EXPONENT = 0x7FF0000000000000       # the exponent bits of a float64: all set for inf and NaN
# up to this many entries the test entry by entry is the faster
_SMALL = 64


def _finite_words(x):
    """Pure-Python stand-in; the compiled versions are chosen by the layout below."""
    return bool(np.all(np.isfinite(x)))


@overload(_finite_words, jit_options=JIT_OPTIONS, inline="always")
def _finite_words_compiled(x):
    if isinstance(x, types.Array) and x.layout == "C":
        # a contiguous array read as its 64-bit words, flat: the test is
        # integer arithmetic without a branch, which LLVM vectorises (0.10
        # against 0.29 µs for a 21 × 21 matrix entry by entry; a loop over
        # the rows of a 2-D view is not vectorised, 0.24 µs)
        def words(x):
            flat = x.reshape(-1).view(np.int64)
            bad = 0
            for i in range(flat.shape[0]):
                bad |= (flat[i] & _EXPONENT) == _EXPONENT
            return bad == 0
        return words

    def entries(x):
        return _finite_entries(x)
    return entries


@njit(**JIT_OPTIONS)
def _finite_entries(x):
    """Entry by entry, stopping at the first bad one."""
    if x.ndim == 1:
        for i in range(x.shape[0]):
            if not math.isfinite(x[i]):
                return False
        return True
    for i in range(x.shape[0]):
        for j in range(x.shape[1]):
            if not math.isfinite(x[i, j]):
                return False
    return True


@njit(**JIT_OPTIONS)
def all_finite(x):
    """Whether every entry of ``x`` (N,) or (N, M) is finite (no inf, no NaN):
    entry by entry up to ``_SMALL`` entries (the faster there: 4 × 4, 0.024
    against 0.035 µs), on the words of a larger contiguous ``x``."""
    if x.size <= _SMALL:
        return _finite_entries(x)
    return _finite_words(x)


@njit(**JIT_OPTIONS)
def work_arrays(n):
    """``(lu (N, N), pivots (N,) int32, ints (INTS,) int32)`` for the routines below."""
    ints = np.zeros(INTS, np.int32)
    ints[_TRANS] = 0x4E4E4E4E          # "NNNN": dgetrs reads the first byte, N
    ints[_UPLO] = 0x4C4C4C4C           # "LLLL": dpotrf and dpotrs, the lower triangle
    return np.empty((n, n)), np.empty(n, np.int32), ints


@njit(**JIT_OPTIONS)
def _transpose_into(A, lu):
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            lu[j, i] = A[i, j]


@njit(**JIT_OPTIONS)
def gesv(A, x, lu, pivots, ints):
    """``x ← A⁻¹ x`` for ``A`` (N, N) (left as it is) by ``dgesv``; false when ``A``
    is singular or not finite (the cases ``np.linalg.solve`` refuses), ``x``
    then undefined."""
    if not all_finite(A):
        return False
    return _gesv_finite(A, x, lu, pivots, ints)


@njit(inline="always", **JIT_OPTIONS)
def _gesv_finite(A, x, lu, pivots, ints):
    """:func:`gesv` for an ``A`` known to be finite (inlined: a call that passes
    arrays costs their reference counts, as much as a small solve's checks)."""
    _transpose_into(A, lu)
    ints[_N], ints[_NRHS], ints[_INFO] = A.shape[0], 1, 0
    _dgesv(ints.ctypes, ints[_NRHS:].ctypes, lu.ctypes, ints.ctypes, pivots.ctypes, x.ctypes,
           ints.ctypes, ints[_INFO:].ctypes)
    return ints[_INFO] == 0


@njit(**JIT_OPTIONS)
def symmetric(A, roots):
    """:func:`hfdi.linalg.is_symmetric` for a finite ``A`` (N, N), N ≥ 1, with
    the same operations (``roots`` (N,) is scratch for ``√|A_ii|``), so that
    the two paths decide alike."""
    n = A.shape[0]
    for i in range(n):
        roots[i] = math.sqrt(abs(A[i, i]))
    for i in range(n):
        for j in range(i):
            if not abs(A[i, j] - A[j, i]) <= _SYMMETRY_TOLERANCE * (roots[i] * roots[j]):
                return False
    return True


@njit(**JIT_OPTIONS)
def solve(A, x, lu, pivots, ints):
    """``x ← A⁻¹ x`` as :func:`hfdi.linalg.solve` solves a dense system:
    Cholesky (``dpotrf``/``dpotrs``, lower triangle) when ``A`` has at least
    ``CHOLESKY_FROM`` rows and is symmetric to rounding and positive
    definite, else :func:`gesv`; false when ``A`` is
    singular or not finite, ``x`` then undefined."""
    if not all_finite(A):
        return False
    if A.shape[0] >= _CHOLESKY_FROM and symmetric(A, lu[0]):
        _transpose_into(A, lu)
        ints[_N], ints[_NRHS], ints[_INFO] = A.shape[0], 1, 0
        _dpotrf(ints[_UPLO:].ctypes, ints.ctypes, lu.ctypes, ints.ctypes, ints[_INFO:].ctypes)
        if ints[_INFO] == 0:
            _dpotrs(ints[_UPLO:].ctypes, ints.ctypes, ints[_NRHS:].ctypes, lu.ctypes,
                    ints.ctypes, x.ctypes, ints.ctypes, ints[_INFO:].ctypes)
            return ints[_INFO] == 0
    return _gesv_finite(A, x, lu, pivots, ints)


@njit(**JIT_OPTIONS)
def getrf(A, lu, pivots, ints):
    """The LU factors of ``A`` (N, N) into ``lu`` and ``pivots`` by ``dgetrf``;
    false when ``A`` is singular or not finite."""
    if not all_finite(A):
        return False
    _transpose_into(A, lu)
    ints[_N], ints[_INFO] = A.shape[0], 0
    _dgetrf(ints.ctypes, ints.ctypes, lu.ctypes, ints.ctypes, pivots.ctypes,
            ints[_INFO:].ctypes)
    return ints[_INFO] == 0


@njit(**JIT_OPTIONS)
def getrs(lu, pivots, ints, x):
    """``x ← A⁻¹ x`` for ``x`` (N,) from :func:`getrf`'s factors (``dgetrs``)."""
    ints[_N], ints[_NRHS], ints[_INFO] = lu.shape[0], 1, 0
    _dgetrs(ints[_TRANS:].ctypes, ints.ctypes, ints[_NRHS:].ctypes, lu.ctypes, ints.ctypes,
            pivots.ctypes, x.ctypes, ints.ctypes, ints[_INFO:].ctypes)


@njit(**JIT_OPTIONS)
def getrs_columns(lu, pivots, ints, X, work):
    """``X ← A⁻¹ X`` for ``X`` (N, M) from :func:`getrf`'s factors, all columns in
    one ``dgetrs``; ``work`` (M, N) holds them."""
    n, m = X.shape
    for i in range(n):
        for j in range(m):
            work[j, i] = X[i, j]
    ints[_N], ints[_NRHS], ints[_INFO] = n, m, 0
    _dgetrs(ints[_TRANS:].ctypes, ints.ctypes, ints[_NRHS:].ctypes, lu.ctypes, ints.ctypes,
            pivots.ctypes, work.ctypes, ints.ctypes, ints[_INFO:].ctypes)
    for i in range(n):
        for j in range(m):
            X[i, j] = work[j, i]
