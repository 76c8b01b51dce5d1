"""Dense linear solves of the core: LAPACK from both speeds, the same routines.

Python calls scipy's LAPACK wrappers; compiled code calls the same routines
(``scipy.linalg.cython_lapack``) bound by name (docs/compiled.md, "Decision:
LAPACK is bound by name"). Both hand LAPACK the same matrix (compiled code its
transpose written into ``lu``, Python a Fortran copy) and keep factors and
pivots in LAPACK's layout (pivots 1-based). A dense tangent of at least
:data:`CHOLESKY_FROM` rows that is :func:`symmetric` to rounding is solved by
Cholesky, any other by ``gesv``; docs/algorithm.md, "Linear solves".
"""
from __future__ import annotations

import math

import functools

import numpy as np
import scipy.linalg as sla

from ..core.arrays import all_finite_matrix
from ..core.jit import jitable, primitive

__all__ = ["CHOLESKY_FROM", "SYMMETRY_TOLERANCE", "INTS", "work_ints", "symmetric", "solve",
           "factored_solve", "NOT_SOLVED", "CHOLESKY", "LU", "gesv", "getrf", "getrs",
           "getrs_columns"]

#: The smallest dense system solved by Cholesky when symmetric: below it
#: ``gesv``'s one call is the faster (in a compiled loop, N = 4: 0.46 against
#: 0.50 µs; N = 10: 1.47 against 1.12; N = 21: 4.6 against 2.3).
CHOLESKY_FROM = 10
#: ``|a_ij − a_ji| ≤ SYMMETRY_TOLERANCE · √|a_ii| · √|a_jj|`` for every pair is
#: symmetric to rounding (each pair held to its own rows' scale: a stiff entry
#: must not let a soft coupling's true asymmetry pass).
SYMMETRY_TOLERANCE = 1e-12
#: Length of the int32 work array LAPACK's integer arguments are passed in.
INTS = 5
_N, _NRHS, _INFO, _TRANS, _UPLO = range(INTS)
#: What :func:`solve` did: nothing (singular or not finite), or solved by the
#: factors it left in its ``lu`` (and ``pivots``) of one of two kinds, which
#: :func:`factored_solve` solves with again.
NOT_SOLVED, CHOLESKY, LU = 0, 1, 2

_F64 = np.empty(1)
_gesv, _getrf, _getrs, _potrf, _potrs = sla.get_lapack_funcs(
    ("gesv", "getrf", "getrs", "potrf", "potrs"), (_F64,))


@functools.lru_cache(maxsize=None)
def _compiled_globals():
    """LAPACK's routines for compiled code: those of scipy's LAPACK, made known to
    LLVM under names of their own and declared as external functions of
    pointers, which the compiled bodies below call by those names (an address
    baked into the code would not be cacheable)."""
    import llvmlite.binding as llvm
    from numba import types
    from numba.extending import get_cython_function_address

    def bind(routine: str, arguments: int):
        symbol = f"hfdi_scipy_lapack_{routine}"
        llvm.add_symbol(symbol, get_cython_function_address("scipy.linalg.cython_lapack",
                                                            routine))
        return types.ExternalFunction(symbol, types.void(*[types.voidptr] * arguments))

    # dgesv(n, nrhs, a, lda, ipiv, b, ldb, info); dgetrf(m, n, a, lda, ipiv, info);
    # dgetrs(trans, n, nrhs, a, lda, ipiv, b, ldb, info); dpotrf(uplo, n, a, lda, info);
    # dpotrs(uplo, n, nrhs, a, lda, b, ldb, info)
    return {"_dgesv": bind("dgesv", 8), "_dgetrf": bind("dgetrf", 6),
            "_dgetrs": bind("dgetrs", 9), "_dpotrf": bind("dpotrf", 5),
            "_dpotrs": bind("dpotrs", 8)}


def work_ints() -> np.ndarray:
    """The int32 work array of the routines here (its character arguments set)."""
    ints = np.zeros(INTS, np.int32)
    ints[_TRANS] = 0x4E4E4E4E          # "NNNN": dgetrs reads the first byte, N
    ints[_UPLO] = 0x4C4C4C4C           # "LLLL": dpotrf and dpotrs, the lower triangle
    return ints


@jitable
def _transpose_into(A, lu):
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            lu[j, i] = A[i, j]


def _symmetric_loop(A, roots):
    n = A.shape[0]
    for i in range(n):
        roots[i] = math.sqrt(abs(A[i, i]))
    for i in range(n):
        for j in range(i):
            if not abs(A[i, j] - A[j, i]) <= SYMMETRY_TOLERANCE * (roots[i] * roots[j]):
                return False
    return True


@primitive(_symmetric_loop)
def symmetric(A, roots):
    """Whether the finite ``A`` (N, N) is symmetric to rounding (see
    :data:`SYMMETRY_TOLERANCE`); ``roots`` (N,) is scratch."""
    np.sqrt(np.abs(np.diagonal(A)), out=roots)
    with np.errstate(over="ignore", invalid="ignore"):
        return bool((np.abs(A - A.T) <= SYMMETRY_TOLERANCE * np.multiply.outer(roots, roots))
                    .all())


def _gesv_compiled(A, x, lu, pivots, ints):
    _transpose_into(A, lu)
    ints[_N], ints[_NRHS], ints[_INFO] = A.shape[0], 1, 0
    _dgesv(ints.ctypes, ints[_NRHS:].ctypes, lu.ctypes, ints.ctypes, pivots.ctypes, x.ctypes,
           ints.ctypes, ints[_INFO:].ctypes)
    return ints[_INFO] == 0


@primitive(_gesv_compiled)
def _gesv_finite(A, x, lu, pivots, ints):
    factors, pivots_0, solution, info = _gesv(A, x)
    # the factors kept as compiled code keeps them (LAPACK's layout, 1-based)
    lu[:, :] = factors.T
    pivots[:] = pivots_0 + 1
    if info != 0:
        return False
    x[:] = solution
    return True


@jitable
def gesv(A, x, lu, pivots, ints):
    """``x ← A⁻¹ x`` by LU with partial pivoting (``A`` left as it is); false when
    ``A`` is singular or not finite (``x`` then undefined)."""
    if not all_finite_matrix(A):
        return False
    return _gesv_finite(A, x, lu, pivots, ints)


def _cholesky_compiled(A, x, lu, ints):
    _transpose_into(A, lu)
    ints[_N], ints[_NRHS], ints[_INFO] = A.shape[0], 1, 0
    _dpotrf(ints[_UPLO:].ctypes, ints.ctypes, lu.ctypes, ints.ctypes, ints[_INFO:].ctypes)
    if ints[_INFO] != 0:
        return 1           # not positive definite: LU instead
    _dpotrs(ints[_UPLO:].ctypes, ints.ctypes, ints[_NRHS:].ctypes, lu.ctypes, ints.ctypes,
            x.ctypes, ints.ctypes, ints[_INFO:].ctypes)
    return 0 if ints[_INFO] == 0 else 2


@primitive(_cholesky_compiled)
def _cholesky(A, x, lu, ints):
    """0 solved, 1 not positive definite (nothing changed), 2 failed."""
    factor, info = _potrf(A, lower=1, clean=0)
    if info != 0:
        return 1
    lu[:, :] = factor.T
    solution, info = _potrs(factor, x, lower=1)
    if info != 0:
        return 2
    x[:] = solution
    return 0


@jitable
def solve(A, x, lu, pivots, ints):
    """``x ← A⁻¹ x`` for a dense tangent: Cholesky when ``A`` has at least
    :data:`CHOLESKY_FROM` rows, is symmetric to rounding and positive
    definite, else :func:`gesv`. :data:`CHOLESKY` or :data:`LU`, the factors
    left in ``lu`` and ``pivots`` for :func:`factored_solve`; or
    :data:`NOT_SOLVED` (0) when ``A`` is singular or not finite."""
    if not all_finite_matrix(A):
        return NOT_SOLVED
    if A.shape[0] >= CHOLESKY_FROM and symmetric(A, lu[0]):
        outcome = _cholesky(A, x, lu, ints)
        if outcome != 1:
            return CHOLESKY if outcome == 0 else NOT_SOLVED
    return LU if _gesv_finite(A, x, lu, pivots, ints) else NOT_SOLVED


def _potrs_compiled(lu, ints, x):
    ints[_N], ints[_NRHS], ints[_INFO] = lu.shape[0], 1, 0
    _dpotrs(ints[_UPLO:].ctypes, ints.ctypes, ints[_NRHS:].ctypes, lu.ctypes, ints.ctypes,
            x.ctypes, ints.ctypes, ints[_INFO:].ctypes)


@primitive(_potrs_compiled)
def _potrs_factors(lu, ints, x):
    solution, _ = _potrs(lu.T, x, lower=1)
    x[:] = solution


@jitable
def factored_solve(kind, lu, pivots, ints, x):
    """``x ← A⁻¹ x`` with the factors :func:`solve` left of ``A`` (``kind``, what
    it returned: not :data:`NOT_SOLVED`)."""
    if kind == CHOLESKY:
        _potrs_factors(lu, ints, x)
    else:
        getrs(lu, pivots, ints, x)


def _getrf_compiled(A, lu, pivots, ints):
    _transpose_into(A, lu)
    ints[_N], ints[_INFO] = A.shape[0], 0
    _dgetrf(ints.ctypes, ints.ctypes, lu.ctypes, ints.ctypes, pivots.ctypes,
            ints[_INFO:].ctypes)
    return ints[_INFO] == 0


@primitive(_getrf_compiled)
def _getrf_finite(A, lu, pivots, ints):
    factors, pivots_0, info = _getrf(A)
    lu[:, :] = factors.T
    pivots[:] = pivots_0 + 1
    return info == 0


@jitable
def getrf(A, lu, pivots, ints):
    """The LU factors of ``A`` into ``lu`` and ``pivots``; false when ``A`` is
    singular or not finite."""
    if not all_finite_matrix(A):
        return False
    return _getrf_finite(A, lu, pivots, ints)


def _getrs_compiled(lu, pivots, ints, x):
    ints[_N], ints[_NRHS], ints[_INFO] = lu.shape[0], 1, 0
    _dgetrs(ints[_TRANS:].ctypes, ints.ctypes, ints[_NRHS:].ctypes, lu.ctypes, ints.ctypes,
            pivots.ctypes, x.ctypes, ints.ctypes, ints[_INFO:].ctypes)


@primitive(_getrs_compiled)
def getrs(lu, pivots, ints, x):
    """``x ← A⁻¹ x`` from :func:`getrf`'s factors."""
    solution, _ = _getrs(lu.T, pivots - 1, x)
    x[:] = solution


def _getrs_columns_compiled(lu, pivots, ints, X, work):
    n, m = X.shape
    for j in range(m):
        for i in range(n):
            work[j, i] = X[i, j]
        ints[_N], ints[_NRHS], ints[_INFO] = n, 1, 0
        _dgetrs(ints[_TRANS:].ctypes, ints.ctypes, ints[_NRHS:].ctypes, lu.ctypes, ints.ctypes,
                pivots.ctypes, work[j].ctypes, ints.ctypes, ints[_INFO:].ctypes)
        for i in range(n):
            X[i, j] = work[j, i]


@primitive(_getrs_columns_compiled)
def getrs_columns(lu, pivots, ints, X, work):
    """``X ← A⁻¹ X`` for ``X`` (N, M), a ``dgetrs`` per column; ``work`` (M, N)
    is scratch. Decision: one column at a time (level-2 triangular solves).
    All columns in one call take OpenBLAS's threaded level-3 path, which on a
    busy machine took 7 ms for N = 3 (its threads waiting for a core) instead
    of microseconds."""
    for j in range(X.shape[1]):
        solution, _ = _getrs(lu.T, pivots - 1, X[:, j])
        X[:, j] = solution
