"""Array primitives of the core: each a numpy body (Python) and a loop (compiled).

The loops make one pass without temporaries (compiled code allocates nothing
per step); the numpy bodies are the fewest calls. Both compute every entry
with the same operations in the same order (``a * x[i] + b * y[i]`` is the
same number either way), so the two speeds round alike. Dot products and
products with dense matrices are BLAS calls of one library in both: compiled
``np.dot`` calls scipy's BLAS, and so do the Python bodies here (numpy's own
BLAS may be another build, whose sums round otherwise).

Matrix arguments are described by a *kind* (:data:`NONE`, :data:`DIAGONAL`,
:data:`DENSE`, :data:`SPARSE`) with the diagonal in one array and the full
matrix in another, so that one compiled code serves every model; sparse
matrices (scipy) occur in Python only.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import blas as _blas

from .jit import jitable, primitive

__all__ = ["NONE", "DIAGONAL", "DENSE", "SPARSE", "copy", "copy_matrix", "fill", "fill_matrix",
           "all_finite_matrix", "lincomb", "axpy", "scale", "times",
           "add_times", "divide", "divide_by", "matvec", "scaled_into", "add_scaled", "add_kind", "add_diagonal",
           "divide_rows", "max_abs", "all_finite", "row_sum_max", "kinetic", "dot", "matmul",
           "keep_larger"]

#: Kinds of a matrix of the model (mass, damping).
NONE, DIAGONAL, DENSE, SPARSE = 0, 1, 2, 3


# -- vectors -------------------------------------------------------------------------

def _lincomb_loop(out, a, x, b, y):
    for i in range(out.shape[0]):
        out[i] = a * x[i] + b * y[i]


@primitive(_lincomb_loop)
def lincomb(out, a, x, b, y):
    """``out = a x + b y`` (``out`` may be ``x`` or ``y``)."""
    by = b * y              # before out is written: out may be y
    np.multiply(x, a, out)
    out += by


def _keep_larger_loop(out, x):
    for i in range(out.shape[0]):
        if abs(x[i]) > abs(out[i]):
            out[i] = x[i]


@primitive(_keep_larger_loop)
def keep_larger(out, x):
    """``out[i] = x[i]`` where ``|x[i]| > |out[i]|``."""
    np.copyto(out, x, where=np.abs(x) > np.abs(out))


def _copy_loop(out, x):
    for i in range(out.shape[0]):
        out[i] = x[i]


@primitive(_copy_loop)
def copy(out, x):
    """``out[:] = x`` (vectors of the same length; compiled without a check of
    the shapes, whose error paths cost seconds of compiling)."""
    out[...] = x


def _copy_matrix_loop(out, x):
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            out[i, j] = x[i, j]


@primitive(_copy_matrix_loop)
def copy_matrix(out, x):
    """``out[:, :] = x``."""
    out[...] = x


def _fill_loop(out, value):
    for i in range(out.shape[0]):
        out[i] = value


@primitive(_fill_loop)
def fill(out, value):
    """``out[:] = value``."""
    out[...] = value


def _fill_matrix_loop(out, value):
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            out[i, j] = value


@primitive(_fill_matrix_loop)
def fill_matrix(out, value):
    """``out[:, :] = value``."""
    out[...] = value


def _axpy_loop(y, a, x):
    for i in range(y.shape[0]):
        y[i] = y[i] + a * x[i]


@primitive(_axpy_loop)
def axpy(y, a, x):
    """``y += a x``."""
    y += a * x


def _scale_loop(out, a, x):
    for i in range(out.shape[0]):
        out[i] = a * x[i]


@primitive(_scale_loop)
def scale(out, a, x):
    """``out = a x``."""
    np.multiply(x, a, out)


def _times_compiled(kind, diagonal, full, x, out):
    if kind == DIAGONAL:
        for i in range(x.shape[0]):
            out[i] = diagonal[i] * x[i]
    elif kind == DENSE:
        matvec(full, x, out)
    else:
        for i in range(x.shape[0]):
            out[i] = 0.0


@primitive(_times_compiled)
def times(kind, diagonal, full, x, out):
    """``out = A x`` for the matrix ``A`` of ``kind`` (zero for :data:`NONE`)."""
    if kind == DIAGONAL:
        np.multiply(diagonal, x, out)
    elif kind == DENSE:
        _gemv(full, x, out)
    elif kind == SPARSE:
        out[:] = full @ x
    else:
        out[:] = 0.0


def _divide_loop(x, d):
    for i in range(x.shape[0]):
        x[i] = x[i] / d[i]


@primitive(_divide_loop)
def divide(x, d):
    """``x /= d`` entry by entry."""
    np.divide(x, d, out=x)


def _divide_by_loop(x, s):
    for i in range(x.shape[0]):
        x[i] = x[i] / s


@primitive(_divide_by_loop)
def divide_by(x, s):
    """``x /= s`` for a number ``s``."""
    np.divide(x, s, out=x)


def _matvec_compiled(A, x, out):
    for i in range(A.shape[0]):
        total = 0.0
        for j in range(A.shape[1]):
            total += A[i, j] * x[j]
        out[i] = total


@primitive(_matvec_compiled)
def matvec(A, x, out):
    """``out = A x`` for a dense or (Python only) sparse ``A``."""
    if isinstance(A, np.ndarray):
        _gemv(A, x, out)
    else:
        out[:] = A @ x


def _gemv(A, x, out):
    # each row summed in index order, as the compiled loop sums it (see dot)
    out[:] = np.add.accumulate(A * x, axis=1)[:, -1] if A.shape[1] else 0.0


def _dot_compiled(x, y):
    total = 0.0
    for i in range(x.shape[0]):
        total += x[i] * y[i]
    return total


@primitive(_dot_compiled)
def dot(x, y):
    """``xᵀ y``, summed in index order at both speeds (``np.add.accumulate``
    is sequential, where ``sum`` is pairwise). Decision: not BLAS's ``ddot``:
    its call cost 0.4 µs of the dumbbell's 3 µs HFDI iteration."""
    return float(np.add.accumulate(x * y)[-1]) if x.shape[0] else 0.0


def _matmul_compiled(A, B, out):
    np.dot(A, B, out)


@primitive(_matmul_compiled)
def matmul(A, B, out):
    """``out = A B`` (BLAS's ``dgemm``; C-ordered, as compiled ``np.dot`` calls
    it: ``outᵀ = Bᵀ Aᵀ``)."""
    out[...] = _blas.dgemm(1.0, B.T, A.T).T


@jitable
def add_times(kind, diagonal, full, x, out, work):
    """``out += A x`` (nothing for :data:`NONE`); ``work`` holds ``A x``."""
    if kind != NONE:
        times(kind, diagonal, full, x, work)
        axpy(out, 1.0, work)


def _max_abs_loop(x):
    largest = 0.0
    for i in range(x.shape[0]):
        largest = max(largest, abs(x[i]))
    return largest


@primitive(_max_abs_loop)
def max_abs(x):
    """``max |x_i|`` (0 for an empty ``x``; NaN entries are skipped)."""
    return float(np.abs(x).max(initial=0.0))


_EXPONENT = 0x7FF0000000000000       # the exponent bits of a float64: all set for inf and NaN


def _finite_vector(x):
    # the array's 64-bit words: integer arithmetic without a branch, which LLVM
    # vectorises (a floating-point test or sum is a chain of dependent steps)
    words = x.view(np.int64)
    bad = 0
    for i in range(words.shape[0]):
        bad |= (words[i] & _EXPONENT) == _EXPONENT
    return bad == 0


@primitive(_finite_vector)
def all_finite(x):
    """Whether no entry of the vector ``x`` is inf or NaN (in Python, of any
    array or a sparse matrix's data)."""
    data = x.data if hasattr(x, "tocsr") else x
    return bool(np.isfinite(data).all())


def _finite_matrix(x):
    words = x.view(np.int64)
    bad = 0
    for i in range(words.shape[0]):
        for j in range(words.shape[1]):
            bad |= (words[i, j] & _EXPONENT) == _EXPONENT
    return bad == 0


@primitive(_finite_matrix)
def all_finite_matrix(x):
    """Whether no entry of the matrix ``x`` (dense or, in Python, sparse) is inf or NaN."""
    return all_finite(x)


# -- matrices ------------------------------------------------------------------------

def _scaled_into_loop(out, c, A):
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            out[i, j] = c * A[i, j]


@primitive(_scaled_into_loop)
def scaled_into(out, c, A):
    """``out = c A`` (dense)."""
    np.multiply(A, c, out)


def _add_scaled_loop(out, c, A):
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            out[i, j] = out[i, j] + c * A[i, j]


@primitive(_add_scaled_loop)
def add_scaled(out, c, A):
    """``out += c A`` (dense)."""
    out += c * A


def _add_diagonal_loop(out, c, d):
    for i in range(d.shape[0]):
        out[i, i] = out[i, i] + c * d[i]


@primitive(_add_diagonal_loop)
def add_diagonal(out, c, d):
    """``out += c diag(d)``."""
    out.reshape(-1)[::out.shape[1] + 1] += c * d


@jitable
def add_kind(out, c, kind, diagonal, full):
    """``out += c A`` for the matrix ``A`` of ``kind`` (dense ``out``)."""
    if kind == DENSE:
        add_scaled(out, c, full)
    elif kind == DIAGONAL:
        add_diagonal(out, c, diagonal)


def _divide_rows_loop(out, A, d):
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            out[i, j] = A[i, j] / d[i]


@primitive(_divide_rows_loop)
def divide_rows(out, A, d):
    """``out = diag(d)⁻¹ A``."""
    np.divide(A, d[:, None], out)


def _row_sum_max_loop(A):
    largest = 0.0
    for i in range(A.shape[0]):
        total = 0.0
        for j in range(A.shape[1]):
            total += abs(A[i, j])
        largest = max(largest, total)
    return largest


@primitive(_row_sum_max_loop)
def row_sum_max(A):
    """``‖A‖_∞ = max_i Σ_j |A_ij|`` (dense or sparse)."""
    if not isinstance(A, np.ndarray):
        return float(np.asarray(abs(A).sum(axis=1)).max()) if A.shape[0] else 0.0
    totals = np.zeros(A.shape[0])
    for column in np.abs(A).T:          # summed in the loop's order (numpy's sums pair)
        totals += column
    return max(0.0, float(totals.max())) if A.shape[0] else 0.0


@jitable
def kinetic(kind, diagonal, full, v, work):
    """``½ vᵀ M v`` (``work`` holds ``M v``)."""
    times(kind, diagonal, full, v, work)
    return 0.5 * dot(v, work)
