"""LAPACK for the compiled attempt: the Python path's routines, called into work arrays.

The Python path solves its dense systems with scipy's LAPACK
(:mod:`hfdi.linalg`: ``gesv`` for a Newton correction, ``getrf``/``getrs``
for HFDI's matrix ``B``). The compiled attempt calls the same routines of the
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
from numba.extending import get_cython_function_address

from .signatures import JIT_OPTIONS

__all__ = ["all_finite", "gesv", "getrf", "getrs", "getrs_columns", "work_arrays"]


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

# entries of the int32 ``ints`` work array
_N, _NRHS, _INFO, _TRANS = range(4)


@njit(**JIT_OPTIONS)
def all_finite(x):
    """Whether every entry of ``x`` (N,) or (N, M) is finite (index loops: an
    iterator over ``x.ravel()`` costs more than the test for small arrays)."""
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
def work_arrays(n):
    """``(lu (N, N), pivots (N,) int32, ints (4,) int32)`` for the routines below."""
    ints = np.zeros(4, np.int32)
    ints[_TRANS] = 0x4E4E4E4E          # "NNNN": dgetrs reads the first byte, N
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
    _transpose_into(A, lu)
    ints[_N], ints[_NRHS], ints[_INFO] = A.shape[0], 1, 0
    _dgesv(ints.ctypes, ints[_NRHS:].ctypes, lu.ctypes, ints.ctypes, pivots.ctypes, x.ctypes,
           ints.ctypes, ints[_INFO:].ctypes)
    return ints[_INFO] == 0


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
