"""Matrix helpers shared by the schemes: diagonal, dense and sparse matrices.

A matrix of the model (mass, damping, tangent) is kept in one of three forms:
a 1-D array for a diagonal matrix, a 2-D ndarray, or a scipy sparse matrix in
CSR form. Diagonal stays diagonal, so a lumped mass never becomes a full
matrix, and a sparse tangent never becomes dense.

These functions sit on the corrector's hot path: on the small benchmark models
a Newton correction costs tens of microseconds, so they dispatch on the type
once, call LAPACK directly (``gesv``, ``potrf``/``potrs``, ``getrf``/``getrs``,
``gbsv``, ``gtsv``) rather than through the checking wrappers of numpy and
scipy, and build the band storage of a sparse matrix with a few vectorised
operations.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import checks

__all__ = ["normalise_matrix", "combine", "Factorization", "SingularMatrixError",
           "all_finite", "solve", "banded_from_sparse", "is_symmetric", "SYMMETRY_TOLERANCE",
           "CHOLESKY_FROM"]

_F64 = np.empty(1)
_gesv, _getrf, _getrs, _gbsv, _gtsv, _potrf, _potrs = sla.get_lapack_funcs(
    ("gesv", "getrf", "getrs", "gbsv", "gtsv", "potrf", "potrs"), (_F64,))

#: A dense matrix whose entries ``a_ij`` differ from ``a_ji`` by at most this
#: fraction of ``√|a_ii| · √|a_jj|`` is symmetric to rounding, and :func:`solve`
#: tries Cholesky on its lower triangle first. The tangents of models with a
#: potential (K a Hessian, T its derivative) are symmetric in exact arithmetic
#: and differ from their transposes by rounding only (at most 4e-16 of that
#: scale on the paper's models, every scheme); a perturbation of 1e-12 of the
#: tangent changes a Newton correction by 1e-12 times the tangent's condition
#: number, not where the corrector converges (the residual is unchanged).
#: docs/algorithm.md, "Linear solves".
SYMMETRY_TOLERANCE = 1e-12
#: The smallest dense system :func:`solve` tries Cholesky on. Below it
#: LAPACK's call overhead outweighs the halved arithmetic, and ``gesv``'s one
#: call is the faster (in a compiled loop, Cholesky's two calls against
#: ``gesv``: N = 4 0.50 against 0.46 µs, N = 9 1.44 against 1.24, N = 10 1.12
#: against 1.47, N = 21 2.3 against 4.6).
CHOLESKY_FROM = 10
_isfinite = math.isfinite
_HALF_MAX = 0.5 * float(np.finfo(float).max)
_isfinite_array = np.isfinite


class SingularMatrixError(ArithmeticError):
    """A linear system in the corrector could not be solved."""


def all_finite(x) -> bool:
    """Whether every entry of the float array ``x`` is finite (no NaN, no infinity).

    ``np.isfinite(x).all()`` with the method form of ``all``, which skips the
    dispatch of ``np.all``; unlike a test on a sum or a dot product it cannot
    overflow, so it never warns.
    """
    return _isfinite_array(x).all()


def normalise_matrix(a, n: int, name: str):
    """Return ``a`` as a 1-D diagonal, a 2-D ndarray or CSR sparse, checked to be ``n``×``n``.

    ``None`` stays ``None``. The checks (real, finite, the shape) and their
    messages naming ``name`` are :func:`hfdi.checks.square_matrix`'s. A sparse
    or dense matrix that is exactly diagonal is stored as its diagonal.
    """
    if a is None:
        return None
    a = checks.square_matrix(name, a, n)
    if sp.issparse(a):
        a = sp.csr_matrix(a, dtype=float)
        if a.nnz == 0 or (a - sp.diags(a.diagonal())).count_nonzero() == 0:
            return np.asarray(a.diagonal(), dtype=float)
        return a
    if a.ndim == 1:
        return a.copy()
    if np.count_nonzero(a - np.diag(np.diag(a))) == 0:
        return np.diag(a).copy()
    return np.ascontiguousarray(a)


def diagonal_csr(d):
    """A CSR matrix with diagonal ``d``, built directly (no DIA conversion)."""
    n = d.shape[0]
    index = np.arange(n + 1, dtype=np.int32)
    return sp.csr_matrix((d, index[:-1], index), shape=(n, n))


def add_diagonal(out, d):
    """``out += diag(d)`` in place for a 2-D ndarray ``out``; returns ``out``."""
    if out.flags.c_contiguous:
        diagonal = out.reshape(-1)[::out.shape[1] + 1]
        diagonal += d
    else:
        out[np.diag_indices_from(out)] += d
    return out


def combine(*terms):
    """Sum ``Σ c_i A_i`` of diagonal, dense or sparse matrices.

    Terms are pairs ``(c, A)``; ``A`` may be ``None`` (skipped). The result is
    dense if any term is dense, sparse (CSR) if any is sparse, else diagonal.
    The dense terms are summed in order, then the sparse ones, then the
    diagonal ones; the result is a new array (no term is modified).
    """
    d = out = None
    sparse = None
    for c, a in terms:
        if a is None or c == 0.0:
            continue
        if isinstance(a, np.ndarray):
            if a.ndim == 1:
                d = c * a if d is None else d + c * a
            elif out is None:
                out = c * a
            else:
                out += c * a
        elif sparse is None:
            sparse = [(c, a)]
        else:
            sparse.append((c, a))
    if out is not None:
        if sparse is not None:
            for c, a in sparse:
                out += c * a.toarray()
        return out if d is None else add_diagonal(out, d)
    if sparse is not None:
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
            if not all_finite(a) or not a.all():
                raise SingularMatrixError("diagonal matrix has a zero or non-finite entry")
            self.kind, self._data = "diag", a
        elif sp.issparse(a):
            if not all_finite(a.data):
                raise SingularMatrixError("matrix has non-finite entries")
            try:
                self._data = spla.splu(sp.csc_matrix(a))
            except RuntimeError as exc:  # SuperLU: "Factor is exactly singular"
                raise SingularMatrixError(str(exc)) from None
            self.kind = "sparse"
        else:
            a = np.asarray(a, dtype=float)
            if not all_finite(a):
                raise SingularMatrixError("matrix has non-finite entries")
            lu, piv, info = _getrf(a)
            if info < 0:
                raise ValueError(f"illegal value in argument {-info} of getrf")
            if not np.diagonal(lu).all():
                raise SingularMatrixError("matrix is exactly singular")
            self.kind, self._data = "dense", (lu, piv)
        self.shape = a.shape

    def solve(self, b):
        if self.kind == "diag":
            return (b.T / self._data).T if b.ndim == 2 else b / self._data
        if self.kind == "sparse":
            return self._data.solve(b)
        lu, piv = self._data
        x, info = _getrs(lu, piv, b)
        if info:
            raise ValueError(f"illegal value in argument {-info} of getrs")
        return x


#: Sparse matrices whose band (lower + upper) is at most this wide are solved
#: with LAPACK's banded LU (gbsv), linear in the size and with no fill-in
#: beyond the band; wider ones with SuperLU.
BANDED_MAX_WIDTH = 64


def _canonical_csr(a):
    """``a`` as CSR without duplicate entries (a copy only when ``a`` has some)."""
    if a.format != "csr":
        a = a.tocsr()
    if not a.has_canonical_format:
        a = a.copy()
        a.sum_duplicates()
    return a


def _rows_and_offsets(a):
    """Row and ``row − column`` of every stored entry of the CSR ``a`` (int64)."""
    rows = np.repeat(np.arange(a.shape[0], dtype=np.int64), np.diff(a.indptr))
    return rows, rows - a.indices


def _offsets(a):
    """``row − column`` of every stored entry of the CSR ``a`` (int64)."""
    return _rows_and_offsets(a)[1]


#: Patterns of the last sparse matrices put into band storage: the model's
#: tangent and its derivative keep one pattern from iteration to iteration,
#: so their band positions are found once and then only checked (two
#: comparisons of the index arrays) and reused.
_PATTERNS: list = []
_PATTERNS_KEPT = 3


class _Pattern:
    __slots__ = ("indptr", "indices", "lower", "upper", "positions")

    def __init__(self, a, lower, upper, offsets):
        self.indptr, self.indices = a.indptr.copy(), a.indices.copy()
        self.lower, self.upper = lower, upper
        offsets += upper
        offsets *= a.shape[0]
        offsets += a.indices
        self.positions = offsets          # flat index into band storage without spare rows

    def matches(self, a):
        return (a.indptr.shape == self.indptr.shape and a.indices.shape == self.indices.shape
                and np.array_equal(a.indptr, self.indptr)
                and np.array_equal(a.indices, self.indices))


def _pattern(a):
    """The cached :class:`_Pattern` of the CSR ``a`` (canonical once known), or a new one."""
    if a.format == "csr":
        for pattern in list(_PATTERNS):
            if pattern.matches(a):
                return a, pattern
    a = _canonical_csr(a)
    if a.nnz == 0:
        return a, None
    off = _offsets(a)
    pattern = _Pattern(a, int(max(off.max(), 0)), int(max(-off.min(), 0)), off)
    _PATTERNS.insert(0, pattern)
    del _PATTERNS[_PATTERNS_KEPT:]
    return a, pattern


def banded_from_sparse(a, max_width=BANDED_MAX_WIDTH, extra_lower=False, bandwidths_only=False):
    """The band of a sparse matrix in LAPACK storage, or ``None`` when wider than ``max_width``.

    Returns ``(ab, lower, upper)`` with ``a[i, j]`` at ``ab[extra + upper + i − j, j]``,
    ``extra = lower`` when ``extra_lower`` is true (the rows ``gbsv`` needs for
    its fill-in), else 0. Built from the CSR arrays with one scatter of the
    entries (positions cached per sparsity pattern): O(nnz) time and
    O((l + u) n) memory. With ``bandwidths_only`` ``ab`` is ``None`` and
    ``max_width`` is ignored.
    """
    a, pattern = _pattern(a)
    n = a.shape[0]
    lower, upper = (0, 0) if pattern is None else (pattern.lower, pattern.upper)
    if bandwidths_only:
        return None, lower, upper
    if lower + upper > max_width:
        return None
    top = lower if extra_lower else 0
    ab = np.zeros((top + lower + upper + 1, n))
    if pattern is not None:
        ab[top:].reshape(-1)[pattern.positions] = a.data
    return ab, lower, upper


def solve_band(ab, lower, upper, b):
    """Solve with a matrix in ``gbsv`` storage (``lower`` extra rows on top); ``ab``
    is overwritten. Tridiagonal matrices go to ``gtsv``, as in
    :func:`scipy.linalg.solve_banded`."""
    n = ab.shape[1]
    if n == 1:
        x = b / ab[lower + upper, 0]
        if not all_finite(x):
            raise SingularMatrixError("singular matrix")
        return x
    if lower == upper == 1:
        _, _, _, x, info = _gtsv(ab[3, :-1], ab[2, :], ab[1, 1:], b, True, True, True, False)
    else:
        _, _, x, info = _gbsv(lower, upper, ab, b, overwrite_ab=True, overwrite_b=False)
    if info > 0:
        raise SingularMatrixError("singular matrix")
    if info < 0:
        raise ValueError(f"illegal value in argument {-info} of gbsv")
    return x


def is_symmetric(a) -> bool:
    """Whether the dense, non-empty ``a`` (N, N) is symmetric to rounding:
    ``|a_ij − a_ji| ≤`` :data:`SYMMETRY_TOLERANCE` ``· √|a_ii| · √|a_jj|`` for
    every pair (false for entries that are not finite). Each pair is held to
    the scale of its own rows, not to the largest entry: a stiff entry must
    not let a soft coupling's true asymmetry pass. The compiled attempt's
    test (:func:`hfdi.compiled.lapack.symmetric`) decides alike, operation
    for operation."""
    scale = np.abs(a).max()
    if not _isfinite(scale):
        return False
    roots = np.sqrt(np.abs(np.diagonal(a)))
    bound = SYMMETRY_TOLERANCE * np.multiply.outer(roots, roots)
    if scale > _HALF_MAX:       # a − aᵀ may overflow (to inf: not symmetric)
        with np.errstate(over="ignore"):
            return bool((np.abs(a - a.T) <= bound).all())
    return bool((np.abs(a - a.T) <= bound).all())


def solve(a, b):
    """Solve ``a x = b`` once (one factorisation); see :class:`Factorization`.

    A dense ``a`` of at least :data:`CHOLESKY_FROM` rows and symmetric to
    rounding (:func:`is_symmetric`) goes to LAPACK ``potrf``/``potrs``
    (Cholesky of its lower triangle: half the work of LU, and at N = 21 half
    the time), and to ``gesv`` when it is not positive definite; any other
    dense ``a`` goes to ``gesv``. A sparse one with a
    band of at most :data:`BANDED_MAX_WIDTH` goes to ``gbsv``, a wider one to
    SuperLU; an object with a ``solve`` method (the HFDI block tangent) solves
    itself.
    """
    if isinstance(a, np.ndarray) and a.ndim == 2:
        if a.shape[0] >= CHOLESKY_FROM and is_symmetric(a):
            factor, info = _potrf(a, lower=1, clean=0)
            if info == 0:
                x, info = _potrs(factor, b, lower=1)
                if info == 0:
                    return x
            if info < 0:
                raise ValueError(f"illegal value in argument {-info} of potrf/potrs")
            # info > 0: not positive definite; LU below
        _, _, x, info = _gesv(a, b)
        if info > 0:
            raise SingularMatrixError("Singular matrix")
        if info < 0:
            raise ValueError(f"illegal value in argument {-info} of gesv")
        return x
    if sp.issparse(a):
        band = banded_from_sparse(a, extra_lower=True)
        if band is not None:
            ab, lower, upper = band
            if not all_finite(ab):
                raise SingularMatrixError("matrix has non-finite entries")
            return solve_band(ab, lower, upper, b)
        return Factorization(a).solve(b)
    if hasattr(a, "solve"):
        return a.solve(b)
    return Factorization(a).solve(b)
