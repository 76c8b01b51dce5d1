"""Checks of user input that raise a ``ValueError`` naming the parameter, its
value and what is allowed."""
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["real", "positive", "non_negative", "integer", "finite_array", "real_array",
           "callable_or_none", "square_matrix", "symmetric_definite", "complex_values"]


def real(name: str, value, *, low=None, high=None, low_closed=False, high_closed=False) -> float:
    """``value`` as a finite float in the given range.

    The range is ``low < value < high`` (``<=`` where ``*_closed``); either
    bound may be ``None``.
    """
    parts = []
    if low is not None:
        parts.append(f"{'>=' if low_closed else '>'} {low:g}")
    if high is not None:
        parts.append(f"{'<=' if high_closed else '<'} {high:g}")
    allowed = "a finite number" + (" " + " and ".join(parts) if parts else "")
    # a bool or a string is a mistake even where float() would take it
    if isinstance(value, (bool, np.bool_, str, bytes)):
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {allowed}, got {value!r}") from None
    ok = math.isfinite(number)
    if ok and low is not None:
        ok = number >= low if low_closed else number > low
    if ok and high is not None:
        ok = number <= high if high_closed else number < high
    if not ok:
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    return number


def positive(name: str, value) -> float:
    """A finite float ``> 0``."""
    return real(name, value, low=0.0)


def non_negative(name: str, value) -> float:
    """A finite float ``>= 0``."""
    return real(name, value, low=0.0, low_closed=True)


def integer(name: str, value, minimum: int, maximum: int | None = None) -> int:
    """An integer ``>= minimum`` (and ``<= maximum`` if given; bools are refused)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum \
            or (maximum is not None and value > maximum):
        allowed = f">= {minimum}" if maximum is None else f"in [{minimum}, {maximum}]"
        raise ValueError(f"{name} must be an integer {allowed}, got {value!r}")
    return int(value)


def complex_values(value) -> bool:
    """Whether ``value`` (an array, a sparse matrix, a number or a sequence)
    holds complex numbers: converting it to float would drop their imaginary
    parts, with nothing but numpy's warning."""
    try:
        return bool(np.iscomplexobj(value))
    except (TypeError, ValueError):          # ragged or unconvertible: the caller says why
        return False


def real_array(value) -> np.ndarray | None:
    """``value`` (a number or an array of any shape) as a float ndarray when
    it holds real numbers; ``None`` for text, bools, complex numbers or what
    numpy cannot read as numbers, where ``np.asarray(value, float)`` would read
    ``"1.5"`` as 1.5 and ``True`` as 1, or drop imaginary parts. The caller
    checks shape and range and names the parameter."""
    if isinstance(value, (str, bytes)) or complex_values(value):
        return None
    try:
        raw = np.asarray(value)
        return None if raw.dtype.kind in "bSU" else raw.astype(float)
    except (TypeError, ValueError):
        return None


def finite_array(name: str, value, shape, *, positive: bool = False,
                 to_match: str = "") -> np.ndarray:
    """A float array of the given shape with finite (and, if asked, positive)
    entries; ``to_match`` says where the shape comes from (" to match the mass")."""
    if complex_values(value):
        raise ValueError(f"{name} must be real, got complex values {value!r:.80}")
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an array of shape {shape} of numbers, "
                         f"got {value!r}") from None
    what = "positive finite" if positive else "finite"
    if arr.shape != tuple(shape):
        raise ValueError(f"{name} must have shape {tuple(shape)}{to_match} ({what} entries), "
                         f"got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or (positive and not np.all(arr > 0)):
        raise ValueError(f"{name} must have {what} entries, got {arr.tolist()!r}")
    return arr


def callable_or_none(name: str, value, signature: str):
    """``value`` if it is callable or ``None``; ``signature`` describes what is expected."""
    if value is not None and not callable(value):
        raise ValueError(f"{name} must be a callable {signature} or None, got {value!r}")
    return value


def square_matrix(name: str, value, n: int | None = None, *, to_match: str = ""):
    """``value`` as a float ndarray of shape (N,) (a diagonal) or (N, N), or a
    scipy sparse (N, N) matrix, with finite real entries and ``N >= 1``.

    The one check of a mass, damping or stiffness matrix given by a user
    (:class:`~hfdi.system.System`, :func:`hfdi.evaluation.normalise_matrix`,
    the symbolic models).

    Parameters
    ----------
    name : str
        The parameter, named in the messages.
    value : array_like (N,) or (N, N), or scipy sparse (N, N)
    n : int, optional
        The size ``N`` must be this when given.
    to_match : str, optional
        Appended to the wrong-size message to say why ``N`` must be ``n``
        (e.g. ``" to match the mass"``).

    Returns
    -------
    ndarray (N,) or (N, N), or the scipy sparse ``value`` itself
        A dense ``value`` that is already a float array is not copied.
    """
    shape = "(N,) (diagonal) or (N, N)" if n is None else f"({n},) (diagonal) or ({n}, {n})"
    if sp.issparse(value):
        if complex_values(value):
            raise ValueError(f"{name} must be real, got a complex sparse matrix")
        if value.ndim != 2 or value.shape[0] != value.shape[1] or value.shape[0] < 1:
            raise ValueError(f"{name} must be square (N, N) with N >= 1, got sparse shape "
                             f"{value.shape}")
        if n is not None and value.shape != (n, n):
            raise ValueError(f"{name} must have shape ({n}, {n}){to_match}, got a sparse "
                             f"matrix of shape {value.shape}")
        if not np.all(np.isfinite(value.data)):
            raise ValueError(f"{name} must have finite entries, got a sparse matrix with "
                             f"{np.count_nonzero(~np.isfinite(value.data))} non-finite entries")
        return value
    if complex_values(value):
        raise ValueError(f"{name} must be real, got complex values")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an array of numbers of shape {shape}, or a scipy "
                         f"sparse matrix, got {value!r}") from None
    if arr.ndim not in (1, 2) or arr.shape[0] < 1 or arr.shape != arr.shape[:1] * arr.ndim:
        raise ValueError(f"{name} must have shape {shape}"
                         f"{' with N >= 1' if n is None else to_match}, got shape {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise ValueError(f"{name} must have shape {shape}{to_match}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name} must have finite entries, got {float(arr[tuple(bad)])!r} at "
                         f"index {tuple(int(i) for i in bad)}")
    return arr


#: Relative size of the antisymmetric part below which a matrix counts as
#: symmetric: assembly in floating point leaves differences of a few ulps.
SYMMETRY_RTOL = 1e-10
#: Negative eigenvalues down to this fraction of ``‖A‖_∞`` are taken as
#: round-off when a matrix must be positive *semi*-definite.
SEMIDEFINITE_RTOL = 1e-10


def _sparse_non_positive_pivots(a) -> int:
    """Number of pivots ``≤ 0`` of a symmetric ``LDLᵀ`` of the sparse ``a``.

    SuperLU in symmetric mode with no threshold pivoting (``diag_pivot_thresh
    = 0``) factorises ``P A Pᵀ = L U`` with ``U = D Lᵀ``, so ``diag(U)`` is
    ``D`` and, by Sylvester's law of inertia, has as many non-positive
    entries as ``A`` has non-positive eigenvalues. A zero pivot forces SuperLU
    to swap rows (``perm_r ≠ perm_c``) or to stop; both mean ``A`` is not
    positive definite and count as one.
    """
    try:
        lu = spla.splu(sp.csc_matrix(a), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options=dict(SymmetricMode=True))
    except RuntimeError:            # "Factor is exactly singular"
        return 1
    if not np.array_equal(lu.perm_r, lu.perm_c):
        return max(1, int(np.count_nonzero(lu.U.diagonal() <= 0)))
    return int(np.count_nonzero(lu.U.diagonal() <= 0))


def symmetric_definite(name: str, a, *, semi: bool = False, what: str = ""):
    """Check that ``a`` is symmetric positive definite (``semi``: semi-definite).

    ``a`` is a 1-D array (a diagonal), a 2-D ndarray or a scipy sparse matrix
    with finite entries. The checks are the cheap ones, each a factorisation
    at most: a diagonal must be ``> 0`` (``>= 0``); a dense or sparse matrix
    must be symmetric to ``SYMMETRY_RTOL`` and have a positive (non-negative)
    diagonal, and then a dense one must admit a Cholesky factorisation, a
    sparse one a symmetric ``LDLᵀ`` with positive pivots. For ``semi`` the
    factorisation is of ``A + δ I``, ``δ = SEMIDEFINITE_RTOL ‖A‖_∞``, so that
    negative eigenvalues of round-off size pass.

    Raises
    ------
    ValueError
        Naming ``name``, what is wrong and what is allowed.
    """
    allowed = "symmetric positive " + ("semi-definite" if semi else "definite")
    lead = f"{name} must be {allowed}{what}"
    if isinstance(a, np.ndarray) and a.ndim == 1:
        bad = np.flatnonzero(a < 0) if semi else np.flatnonzero(~(a > 0))
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"{lead}; its diagonal entry [{i}] is {float(a[i])!r} "
                             f"(allowed: {'>= 0' if semi else '> 0'})")
        return
    sparse = sp.issparse(a)
    diag = np.asarray(a.diagonal()).ravel()
    scale = float(abs(a).max()) if (a.nnz if sparse else a.size) else 0.0
    if scale == 0.0:
        if semi:
            return
        raise ValueError(f"{lead}; it is zero")
    asym = abs(a - a.T)
    if float(asym.max()) > SYMMETRY_RTOL * scale:
        if sparse:
            asym = asym.tocoo()
            k = int(np.argmax(asym.data))
            i, j = int(asym.row[k]), int(asym.col[k])
        else:
            i, j = (int(x) for x in np.unravel_index(np.argmax(asym), a.shape))
        aij, aji = a[i, j], a[j, i]
        raise ValueError(f"{lead}; it is not symmetric: [{i}, {j}] is {float(aij)!r} but "
                         f"[{j}, {i}] is {float(aji)!r}")
    bad = np.flatnonzero(diag < 0) if semi else np.flatnonzero(~(diag > 0))
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{lead}; its diagonal entry [{i}, {i}] is {float(diag[i])!r} "
                         f"(allowed: {'>= 0' if semi else '> 0'})")
    n = a.shape[0]
    shift = SEMIDEFINITE_RTOL * float(abs(a).sum(axis=1).max()) if semi else 0.0
    if sparse:
        shifted = a + shift * sp.identity(n, format="csr") if semi else a
        count = _sparse_non_positive_pivots(shifted)
        if count:
            raise ValueError(f"{lead}; a symmetric LDLᵀ factorisation has {count} "
                             f"non-positive pivot(s), so it has "
                             f"{'negative' if semi else 'non-positive'} eigenvalues")
        return
    try:
        np.linalg.cholesky(a + shift * np.eye(n) if semi else a)
    except np.linalg.LinAlgError:
        low = float(np.linalg.eigvalsh(a)[0])
        raise ValueError(f"{lead}; its Cholesky factorisation fails (smallest eigenvalue "
                         f"{low:.6g})") from None
