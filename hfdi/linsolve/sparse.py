"""Linear algebra of large systems (``N ≥ DENSE_BELOW``), Python only.

There ``M``, ``C``, ``K`` and ``T`` may be diagonal, dense or sparse (scipy
CSR), and the tangents keep that structure: a sparse tangent with a narrow
band goes to LAPACK's banded LU (``gbsv``), a wider one to SuperLU; HFDI's
tangent ``S B⁻¹ S + R`` is formed with a diagonal ``B``, solved as a sparse
block system with a sparse ``B``, or, when a diagonal ``B`` spreads over more
than :data:`BLOCK_SPREAD`, as the interleaved banded block system
(docs/algorithm.md, "Schemes"). The stepping code reaches it through the
``general_*`` functions below, which compiled code never calls (it runs dense
systems only): each is :func:`~hfdi.core.jit.python_only` with a stub.

Their state between calls (``B``'s factors, ``M``'s, the compiled band
builders of a model with sparse kernels) is a :class:`General` in
``VECTORS.sparse``.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..core.arrays import DIAGONAL, NONE
from ..core.jit import python_only
from . import dense

__all__ = ["DENSE_BELOW", "BANDED_MAX_WIDTH", "BLOCK_SPREAD", "SingularMatrixError",
           "General", "combine", "Factorization", "banded_from_sparse", "solve_band",
           "general_solve", "general_affine_tangent", "general_hfdi_setup",
           "general_velocity", "general_hfdi_tangent", "general_mass_solve",
           "general_propagation_factor", "general_propagation_solve"]

#: Models of fewer DOFs than this are dense: below about a hundred unknowns a
#: dense LU costs microseconds, while every scipy.sparse operation costs tens
#: of microseconds of overhead.
DENSE_BELOW = 128
#: Sparse matrices whose band (lower + upper) is at most this wide are solved
#: with LAPACK's banded LU, linear in the size; wider ones with SuperLU.
BANDED_MAX_WIDTH = 64
#: Spread ``max(b)/min(b)`` of a diagonal HFDI ``B`` above which a sparse
#: tangent is solved as the block system rather than as ``S B⁻¹ S + R``
#: (about 1/sqrt(machine epsilon)). The toss rule's lumped masses spread by
#: ``12/h_e²``, past this from about 1500 elements on.
BLOCK_SPREAD = 1e8

_getrf, _getrs, _gtsv, _gbsv = sla.get_lapack_funcs(("getrf", "getrs", "gtsv", "gbsv"),
                                                (np.empty(1),))


class SingularMatrixError(ArithmeticError):
    """A linear system could not be solved."""


def all_finite(x) -> bool:
    return bool(np.isfinite(x).all())


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


def _canonical_csr(a):
    """``a`` as CSR without duplicate entries (a copy only when ``a`` has some)."""
    if a.format != "csr":
        a = a.tocsr()
    if not a.has_canonical_format:
        a = a.copy()
        a.sum_duplicates()
    return a


def _offsets(a):
    """``row − column`` of every stored entry of the CSR ``a`` (int64)."""
    return np.repeat(np.arange(a.shape[0], dtype=np.int64), np.diff(a.indptr)) - a.indices


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
    if not all_finite(ab):
        raise SingularMatrixError("matrix has non-finite entries")
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


class _ShiftedTangent:
    """``K + diag(d)`` for a sparse ``K``, solved without forming the sum in CSR.

    The band of ``K`` goes into LAPACK band storage (see
    :func:`banded_from_sparse`) and ``d`` onto its main diagonal:
    one banded LU per solve, linear in the size. A band wider than
    :data:`BANDED_MAX_WIDTH` falls back to SuperLU on the CSR sum.
    ``bands`` (:mod:`hfdi.compiled.band`, with a compiled sparse model) builds
    the same band in one compiled pass.
    """

    __slots__ = ("K", "d", "bands")

    def __init__(self, K, d, bands=None):
        self.K, self.d, self.bands = K, d, bands

    @property
    def shape(self):
        return self.K.shape

    def tocsr(self):
        return combine((1.0, self.K), (1.0, self.d))

    def solve(self, b):
        if self.bands is not None and _compiled_csr(self.K):
            _, lower, upper = banded_from_sparse(self.K, bandwidths_only=True)
            if lower + upper > BANDED_MAX_WIDTH:
                return Factorization(self.tocsr()).solve(b)
            ab = self.bands.shifted_band(self.K, self.d, lower, upper)
        else:
            band = banded_from_sparse(self.K, extra_lower=True)
            if band is None:
                return Factorization(self.tocsr()).solve(b)
            ab, lower, upper = band
            ab[lower + upper] += self.d
        return solve_band(ab, lower, upper, b)


def _compiled_csr(a) -> bool:
    """Whether ``a`` is a canonical float64 CSR matrix with int32 indices, the
    arrays :mod:`hfdi.compiled.band` takes."""
    return (a.format == "csr" and a.has_canonical_format and a.data.dtype == np.float64
            and a.indices.dtype == np.int32 and a.indptr.dtype == np.int32)


class _BlockTangent:
    """HFDI tangent ``S B⁻¹ S + R`` solved as the sparse block system
    ``[[B, −S], [S, R]] [y; Δu] = [0; b]`` when ``B`` is sparse but not diagonal,
    so that ``B⁻¹`` (a dense matrix) is never formed."""

    def __init__(self, B, S, R):
        self.n = B.shape[0]
        self.matrix = sp.bmat([[B, -S], [S, R]], format="csc")

    def solve(self, b):
        try:
            lu = spla.splu(self.matrix)
        except RuntimeError as exc:
            raise SingularMatrixError(str(exc)) from None
        return lu.solve(np.concatenate([np.zeros(self.n), b]))[self.n:]


def _common_band(a, other):
    """The band of the sparse ``a`` in LAPACK storage (no spare rows), widened to
    hold the band of ``other`` too: ``(ab, lower, upper)``."""
    ab, lower, upper = banded_from_sparse(a, max_width=2 * a.shape[0])
    _, lo, up = banded_from_sparse(other, max_width=0, bandwidths_only=True)
    if lo > lower or up > upper:
        wide = np.zeros((max(lo, lower) + max(up, upper) + 1, ab.shape[1]))
        top = max(up, upper) - upper
        wide[top:top + ab.shape[0]] = ab
        ab, lower, upper = wide, max(lo, lower), max(up, upper)
    return ab, lower, upper


class _InterleavedBlockTangent:
    """HFDI tangent ``S B⁻¹ S + R`` for a diagonal ``B`` and sparse ``K``, ``T``,
    solved as the scaled block system with its unknowns interleaved, in banded
    form (docs/algorithm.md, "Schemes": why, and the system).

    ``S = M − c K`` and ``R = C + c₂ K − c T`` (``M``, ``C`` diagonal,
    ``c = h²/6``, ``c₂ = 2h/3``). The entries go straight from the CSR arrays
    of ``K`` and ``T`` into LAPACK band storage: one ``gbsv`` of size ``2n``
    per solve, linear in ``n``, no sparse matrix product; pivoting may take
    an ``S`` entry instead of a huge ``S B⁻¹ S`` one. A band wider than
    :data:`BANDED_MAX_WIDTH` goes to SuperLU as :class:`_BlockTangent`.
    """

    __slots__ = ("n", "b", "M", "C", "K", "T", "c", "c2", "bands")

    def __init__(self, b, M, C, K, T, c, c2, bands=None):
        self.n = b.shape[0]
        self.b, self.M, self.C, self.K, self.T, self.c, self.c2 = b, M, C, K, T, c, c2
        self.bands = bands          # hfdi.compiled.band, with a compiled sparse model

    @property
    def shape(self):
        return (self.n, self.n)

    def band(self):
        """``(ab, kl, ku)``: the block matrix in ``gbsv`` storage (``kl`` spare rows on top).

        ``K`` and ``T`` go to band storage first (one scatter of their
        entries each); every diagonal of the block matrix is then a strided
        slice of a diagonal of ``K`` or ``T``, so the interleaved array is
        filled by contiguous vector operations, O(n (l + u)).
        """
        n = self.n
        K, lower, upper = _common_band(self.K, self.T)
        T = _common_band(self.T, self.K)[0]
        kl, ku = 2 * lower + 1, 2 * upper + 1
        ab = np.zeros((2 * kl + ku + 1, 2 * n))
        centre = kl + ku                    # row of the main diagonal: a[r, s] at ab[centre + r − s, s]
        c, c2 = self.c, self.c2
        scale = 1.0 / np.sqrt(self.b)       # B^{-1/2}
        padded = np.zeros(n + lower + upper)
        padded[upper:upper + n] = scale     # scale[j + o] at padded[upper + o + j]
        for o in range(-upper, lower + 1):  # o = i − j; K[i, j] at K[upper + o, j]
            k, t = K[upper + o], T[upper + o]
            kd = c * k
            # (2i, 2j + 1): −(B^{-1/2} S)_ij = b_i^{-1/2} c K_ij   (− M_ii below)
            ab[centre + 2 * o - 1, 1::2] = kd * padded[upper + o:upper + o + n]
            # (2i + 1, 2j): (S B^{-1/2})_ij = −c K_ij b_j^{-1/2}   (+ M_ii below)
            ab[centre + 2 * o + 1, 0::2] = -kd * scale
            # (2i + 1, 2j + 1): R_ij = c₂ K_ij − c T_ij   (+ C_ii below)
            ab[centre + 2 * o, 1::2] = c2 * k + (-c) * t
        ab[centre - 1, 1::2] -= self.M * scale
        ab[centre + 1, 0::2] += self.M * scale
        diagonal = ab[centre]
        diagonal[0::2] = 1.0                # (2i, 2i): B^{-1/2} B B^{-1/2} = I
        if self.C is not None:
            diagonal[1::2] += self.C
        return ab, kl, ku

    def solve(self, rhs):
        widths = [banded_from_sparse(a, bandwidths_only=True)[1:] for a in (self.K, self.T)]
        if max(lo for lo, _ in widths) + max(up for _, up in widths) > BANDED_MAX_WIDTH:
            S = combine((1.0, self.M), (-self.c, self.K))
            R = combine((1.0, self.C), (self.c2, self.K), (-self.c, self.T))
            return _BlockTangent(sp.diags(self.b, format="csr"), S, R).solve(rhs)
        if self.bands is not None and _compiled_csr(self.K) and _compiled_csr(self.T):
            # the same band in one compiled pass over the CSR entries
            lower = max(lo for lo, _ in widths)
            upper = max(up for _, up in widths)
            ab, kl, ku = self.bands.interleaved_block_band(
                self.K, self.T, self.M, self.C, self.b, self.c, self.c2, lower, upper)
        else:
            ab, kl, ku = self.band()
        z = np.zeros(2 * self.n)
        z[1::2] = rhs
        return solve_band(ab, kl, ku, z)[1::2]

    def toarray(self):
        """The tangent ``S B⁻¹ S + R`` as a dense array (for checks; O(n²) memory)."""
        S = combine((1.0, self.M), (-self.c, self.K)).toarray()
        R = combine((1.0, self.C), (self.c2, self.K), (-self.c, self.T)).toarray()
        return S @ (S / self.b[:, None]) + R


# -- the general linear algebra of a run ---------------------------------------------

class General:
    """The state of a run's general linear algebra (``VECTORS.sparse``).

    Parameters
    ----------
    bands : module or None
        :mod:`hfdi.compiled.band` for a model with compiled sparse kernels
        (the tangents' bands built in one compiled pass), else ``None``.
    """

    def __init__(self, bands=None):
        self.bands = bands
        self.B = self.b_diagonal = self.B_factor = None
        self.block_band = False
        self.mass_factor = None
        self.propagation = None


def _solve_general(a, b):
    """Solve ``a x = b``: dense (Cholesky or LU, as the dense solver decides),
    sparse (banded or SuperLU) or an object that solves itself."""
    if isinstance(a, np.ndarray) and a.ndim == 2:
        n = a.shape[0]
        x = np.array(b, dtype=float)
        if not dense.solve(a, x, np.empty((n, n)), np.empty(n, np.int32), dense.work_ints()):
            raise SingularMatrixError("singular matrix")
        return x
    if sp.issparse(a):
        band = banded_from_sparse(a, extra_lower=True)
        return Factorization(a).solve(b) if band is None else solve_band(*band, b)
    if hasattr(a, "solve"):
        return a.solve(b)
    return Factorization(a).solve(b)


def _mass_damping(data, cfg):
    """``M`` and ``C`` (``None`` without damping) of the run, diagonal or not."""
    return (data.Md if cfg.m_kind == DIAGONAL else data.Mf,
            None if cfg.c_kind == NONE else (data.Cd if cfg.c_kind == DIAGONAL else data.Cf))


@python_only(lambda vec, J, x: False)
def general_solve(vec, J, x):
    """``x ← J⁻¹ x``; false when ``J`` is singular."""
    try:
        x[:] = _solve_general(J, x)
    except SingularMatrixError:
        return False
    return True


@python_only(lambda vec, data, cfg, K, cM, cC, cK: vec.J)
def general_affine_tangent(vec, data, cfg, K, cM, cC, cK):
    """``cM M + cC C + cK K`` as the solver wants it: ``K`` plus a diagonal kept
    apart when ``M`` and ``C`` are diagonal (:class:`_ShiftedTangent` for a
    sparse ``K``), else the sum."""
    M, C = _mass_damping(data, cfg)
    scaled = K if cK == 1.0 else cK * K
    if cfg.m_kind == DIAGONAL and cfg.c_kind in (NONE, DIAGONAL):
        shift = combine((cM, M), (cC, C))
        if isinstance(scaled, np.ndarray):
            tangent = scaled * 1.0                    # a new array: K may be the model's
            tangent.reshape(-1)[::tangent.shape[1] + 1] += shift
            return tangent
        return _ShiftedTangent(scaled, shift, vec.sparse.bands)
    return combine((cM, M), (cC, C), (1.0, scaled))


@python_only(lambda vec, data, cfg, K, gh: False)
def general_propagation_factor(vec, data, cfg, K, gh):
    """Factorise ``M + γh C + (γh)² K`` (``gh = γh``) for the global error's
    propagator (:mod:`hfdi.stepping.global_error`); false when singular."""
    S = general_affine_tangent(vec, data, cfg, K, 1.0, gh, gh * gh)
    try:
        vec.sparse.propagation = Factorization(S.tocsr() if isinstance(S, _ShiftedTangent)
                                               else S)
    except SingularMatrixError:
        return False
    return True


@python_only(lambda vec, x: None)
def general_propagation_solve(vec, x):
    """``x ← S⁻¹ x`` with :func:`general_propagation_factor`'s factors."""
    x[:] = vec.sparse.propagation.solve(x)


@python_only(lambda vec, data, cfg, c, c2: 0)
def general_hfdi_setup(vec, data, cfg, c, c2):
    """HFDI's ``B = 2h/3 M + h²/6 C`` (``c2 = 2h/3``, ``c = h²/6``) for the step:
    0 when singular, 1 when diagonal, 2 when factorised (one more LU counted)."""
    state = vec.sparse
    M, C = _mass_damping(data, cfg)
    B = combine((c2, M), (c, C))
    state.B = B
    state.b_diagonal = B if B.ndim == 1 else None
    try:
        state.B_factor = Factorization(B)
    except SingularMatrixError:
        return 0
    b = state.b_diagonal
    # a sparse tangent with a diagonal B whose entries spread over more than
    # BLOCK_SPREAD is solved in the block form (_InterleavedBlockTangent)
    state.block_band = (b is not None and b.size > 0
                        and float(b.max()) > BLOCK_SPREAD * float(b.min()))
    return 1 if b is not None else 2


@python_only(lambda vec, x: None)
def general_velocity(vec, x):
    """``x ← B⁻¹ x`` with the step's ``B``."""
    state = vec.sparse
    if state.b_diagonal is not None:
        x /= state.b_diagonal
    else:
        x[:] = state.B_factor.solve(x)


@python_only(lambda vec, data, cfg, K, T, c, c2: vec.J)
def general_hfdi_tangent(vec, data, cfg, K, T, c, c2):
    """``S B⁻¹ S + R``, ``S = M − c K``, ``R = C + c2 K − c T``, as the solver wants it."""
    state = vec.sparse
    M, C = _mass_damping(data, cfg)
    b = state.b_diagonal
    if state.block_band and sp.issparse(K):
        return _InterleavedBlockTangent(b, M, C, K, T, c, c2, state.bands)
    S = combine((1.0, M), (-c, K))
    R = combine((1.0, C), (c2, K), (-c, T))
    if b is not None:
        if sp.issparse(S):
            scaled = S.copy()
            scaled.data /= b[scaled.indices]          # S B⁻¹, column scaling in place
            return scaled @ S + R
        return S @ (S / b[:, None]) + R
    if sp.issparse(state.B):
        if not sp.issparse(S):
            S = sp.csr_matrix(S)
        return _BlockTangent(state.B, S, sp.csr_matrix(R))
    S = S.toarray() if sp.issparse(S) else S
    R = R.toarray() if sp.issparse(R) else R
    return S @ state.B_factor.solve(S) + R


@python_only(lambda vec, data, cfg, x: None)
def general_mass_solve(vec, data, cfg, x):
    """``x ← M⁻¹ x`` (``M``'s factors kept for the run)."""
    state = vec.sparse
    if state.mass_factor is None:
        state.mass_factor = Factorization(_mass_damping(data, cfg)[0])
    x[:] = state.mass_factor.solve(x)
