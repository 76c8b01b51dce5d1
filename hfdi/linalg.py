"""Matrix helpers shared by the schemes: diagonal, dense and sparse matrices.

A matrix of the model (mass, damping, tangent) is kept in one of three forms:
a 1-D array for a diagonal matrix, a 2-D ndarray, or a scipy sparse matrix in
CSR form. Diagonal stays diagonal, so a lumped mass never becomes a full
matrix, and a sparse tangent never becomes dense.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["normalise_matrix", "matvec", "combine", "Factorization", "SingularMatrixError"]


class SingularMatrixError(ArithmeticError):
    """A linear system in the corrector could not be solved."""


def normalise_matrix(a, n: int, name: str):
    """Return ``a`` as a 1-D diagonal, a 2-D ndarray or CSR sparse, checked to be ``n``×``n``.

    ``None`` stays ``None``. A sparse or dense matrix that is exactly diagonal
    is stored as its diagonal.
    """
    if a is None:
        return None
    if sp.issparse(a):
        if a.shape != (n, n):
            raise ValueError(f"{name} must have shape ({n}, {n}), got {a.shape}")
        a = sp.csr_matrix(a, dtype=float)
        if a.nnz == 0 or (a - sp.diags(a.diagonal())).count_nonzero() == 0:
            return np.asarray(a.diagonal(), dtype=float)
        return a
    try:
        arr = np.asarray(a, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an array of numbers of shape ({n},) (diagonal) or "
                         f"({n}, {n}), or a scipy sparse matrix, got {a!r}") from None
    if arr.ndim == 1:
        if arr.shape != (n,):
            raise ValueError(f"{name} given as a diagonal must have shape ({n},), got {arr.shape}")
        return arr.copy()
    if arr.shape != (n, n):
        raise ValueError(f"{name} must have shape ({n}, {n}), got {arr.shape}")
    if np.count_nonzero(arr - np.diag(np.diag(arr))) == 0:
        return np.diag(arr).copy()
    return arr


def matvec(a, x):
    """``a @ x`` for a diagonal (1-D), dense or sparse ``a``; ``None`` is zero."""
    if a is None:
        return np.zeros_like(x)
    if isinstance(a, np.ndarray) and a.ndim == 1:
        return a * x
    return a @ x


def diagonal_csr(d):
    """A CSR matrix with diagonal ``d``, built directly (no DIA conversion)."""
    n = d.shape[0]
    index = np.arange(n + 1, dtype=np.int32)
    return sp.csr_matrix((d, index[:-1], index), shape=(n, n))


def combine(*terms):
    """Sum ``Σ c_i A_i`` of diagonal, dense or sparse matrices.

    Terms are pairs ``(c, A)``; ``A`` may be ``None`` (skipped). The result is
    dense if any term is dense, sparse (CSR) if any is sparse, else diagonal.
    """
    terms = [(c, a) for c, a in terms if a is not None and c != 0.0]
    dense = [t for t in terms if isinstance(t[1], np.ndarray) and t[1].ndim == 2]
    sparse = [t for t in terms if sp.issparse(t[1])]
    diag = [t for t in terms if isinstance(t[1], np.ndarray) and t[1].ndim == 1]
    d = None
    for c, a in diag:
        d = c * a if d is None else d + c * a
    if dense:
        c0, a0 = dense[0]
        out = c0 * a0
        for c, a in dense[1:]:
            out += c * a
        for c, a in sparse:
            out += c * a.toarray()
        if d is not None:
            out[np.diag_indices_from(out)] += d
        return out
    if sparse:
        out = sparse[0][0] * sparse[0][1]
        for c, a in sparse[1:]:
            out = out + c * a
        if d is not None:
            out = out + diagonal_csr(d)
        return out if out.format == "csr" else out.tocsr()
    return d


class Factorization:
    """A factorised square matrix (diagonal, dense or sparse) that solves ``A x = b``.

    Raises :class:`SingularMatrixError` when ``A`` is singular or not finite.
    """

    __slots__ = ("kind", "_data", "shape")

    def __init__(self, a):
        if isinstance(a, np.ndarray) and a.ndim == 1:
            if not np.all(np.isfinite(a)) or np.any(a == 0.0):
                raise SingularMatrixError("diagonal matrix has a zero or non-finite entry")
            self.kind, self._data = "diag", a
        elif sp.issparse(a):
            if not np.all(np.isfinite(a.data)):
                raise SingularMatrixError("matrix has non-finite entries")
            try:
                self._data = spla.splu(sp.csc_matrix(a))
            except RuntimeError as exc:  # SuperLU: "Factor is exactly singular"
                raise SingularMatrixError(str(exc)) from None
            self.kind = "sparse"
        else:
            a = np.asarray(a, dtype=float)
            if not np.all(np.isfinite(a)):
                raise SingularMatrixError("matrix has non-finite entries")
            lu, piv = sla.lu_factor(a, check_finite=False)
            if np.any(np.diag(lu) == 0.0):
                raise SingularMatrixError("matrix is exactly singular")
            self.kind, self._data = "dense", (lu, piv)
        self.shape = a.shape

    def solve(self, b):
        if self.kind == "diag":
            return (b.T / self._data).T if b.ndim == 2 else b / self._data
        if self.kind == "sparse":
            return self._data.solve(b)
        return sla.lu_solve(self._data, b, check_finite=False)


#: Sparse matrices whose band (lower + upper) is at most this wide are solved
#: with LAPACK's banded LU (gbsv), linear in the size and with no fill-in
#: beyond the band; wider ones with SuperLU.
BANDED_MAX_WIDTH = 64


def bandwidths(a):
    """Lower and upper bandwidth ``(l, u)`` of a sparse matrix."""
    coo = a.tocoo()
    if coo.nnz == 0:
        return 0, 0
    diff = coo.row.astype(np.int64) - coo.col
    return int(max(diff.max(), 0)), int(max(-diff.min(), 0))


def solve_banded_sparse(a, b, lower, upper):
    """Solve ``a x = b`` for a sparse ``a`` with bandwidths ``(lower, upper)``."""
    a = a.tocsr()
    a.sum_duplicates()            # a no-op for the canonical CSR the schemes build
    coo = a.tocoo()
    ab = np.zeros((lower + upper + 1, a.shape[1]))
    ab[upper + coo.row - coo.col, coo.col] = coo.data
    if not np.all(np.isfinite(ab)):
        raise SingularMatrixError("matrix has non-finite entries")
    try:
        return sla.solve_banded((lower, upper), ab, b, check_finite=False)
    except np.linalg.LinAlgError as exc:
        raise SingularMatrixError(str(exc)) from None


def solve(a, b):
    """Solve ``a x = b`` once (one factorisation); see :class:`Factorization`."""
    if isinstance(a, np.ndarray) and a.ndim == 2:
        try:
            x = np.linalg.solve(a, b)
        except np.linalg.LinAlgError as exc:
            raise SingularMatrixError(str(exc)) from None
        return x
    if hasattr(a, "solve") and not sp.issparse(a):
        return a.solve(b)
    if sp.issparse(a):
        lower, upper = bandwidths(a)
        if lower + upper <= BANDED_MAX_WIDTH:
            return solve_banded_sparse(a, b, lower, upper)
    return Factorization(a).solve(b)
