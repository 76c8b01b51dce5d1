"""Compiled band builders of the sparse tangents (numba), for a compiled sparse model.

With :class:`hfdi.compiled.SparseKernels` the model's K and T come as CSR
matrices of a fixed pattern. The tangents of the schemes then go from those
CSR arrays into LAPACK band storage here in one pass over the stored entries,
instead of the scatter into a band copy of K and of T and the strided numpy
passes that interleave them (:meth:`hfdi.linsolve.sparse._InterleavedBlockTangent.band`,
:class:`hfdi.linsolve.sparse._ShiftedTangent`). Each entry is computed by the
same floating-point operations in the same order as there, so the band, and
with it every step, is bit for bit the Python path's for the same K and T
(tests/test_compiled_path.py).

Importing this module imports numba.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from .signatures import JIT_OPTIONS

__all__ = ["interleaved_block_band", "shifted_band"]

_VECTOR = types.float64[::1]
_INDEX = types.int32[::1]
_BAND = types.float64[::1, :]


@njit(types.void(_INDEX, _INDEX, _VECTOR, _INDEX, _INDEX, _VECTOR, _VECTOR, _VECTOR,
                 types.boolean, _VECTOR, types.float64, types.float64, types.int64,
                 types.int64, _BAND), **JIT_OPTIONS)
def _interleaved_block_band(k_indptr, k_indices, k_data, t_indptr, t_indices, t_data, M, C,
                            has_damping, b, c, c2, lower, upper, ab):
    """HFDI's block tangent in ``gbsv`` storage with the unknowns interleaved.

    The matrix of :class:`hfdi.linsolve.sparse._InterleavedBlockTangent`,
    ``[[I, −B^{-1/2} S], [S B^{-1/2}, R]]`` with ``S = M − c K`` and
    ``R = C + c₂ K − c T`` (``M``, ``C``, ``b`` diagonal, as (n,) vectors),
    from the canonical CSR arrays of ``K`` and ``T`` whose bands lie within
    ``(lower, upper)``, written into the zeros ``ab``: see
    :func:`interleaved_block_band`.
    """
    n = b.shape[0]
    kl, ku = 2 * lower + 1, 2 * upper + 1
    centre = kl + ku
    scale = np.empty(n)
    for j in range(n):
        scale[j] = 1.0 / math.sqrt(b[j])
    for i in range(n):
        # the entries of row i of K and of T in one walk over both sorted rows;
        # an entry missing from one of them is its zero, as in the band copies
        pk, k_end = k_indptr[i], k_indptr[i + 1]
        pt, t_end = t_indptr[i], t_indptr[i + 1]
        while pk < k_end or pt < t_end:
            jk = np.int64(k_indices[pk]) if pk < k_end else n
            jt = np.int64(t_indices[pt]) if pt < t_end else n
            j = min(jk, jt)
            k = 0.0
            if jk == j:
                k = k_data[pk]
                pk += 1
            t = 0.0
            if jt == j:
                t = t_data[pt]
                pt += 1
            o = i - j
            kd = c * k
            ab[centre + 2 * o - 1, 2 * j + 1] = kd * scale[i]
            ab[centre + 2 * o + 1, 2 * j] = -kd * scale[j]
            ab[centre + 2 * o, 2 * j + 1] = c2 * k + (-c) * t
    for j in range(n):
        ms = M[j] * scale[j]
        ab[centre - 1, 2 * j + 1] -= ms
        ab[centre + 1, 2 * j] += ms
        ab[centre, 2 * j] = 1.0
        if has_damping:
            ab[centre, 2 * j + 1] += C[j]


def interleaved_block_band(K, T, M, C, b, c, c2, lower, upper):
    """HFDI's block tangent ``[[I, −B^{-1/2} S], [S B^{-1/2}, R]]`` in ``gbsv``
    storage with the unknowns interleaved, as
    :meth:`hfdi.linsolve.sparse._InterleavedBlockTangent.band` builds it.

    Parameters
    ----------
    K, T : scipy CSR (n, n)
        Canonical, float64 data, int32 indices; bands within ``(lower, upper)``.
    M, b : ndarray (n,)
        The diagonals of ``M`` and ``B``.
    C : ndarray (n,) or None
        The diagonal of ``C``.
    c, c2 : float
        ``h²/6`` and ``2h/3``.

    Returns
    -------
    ab : ndarray (2 kl + ku + 1, 2n), Fortran order
        ``kl = 2 lower + 1``, ``ku = 2 upper + 1``, ``kl`` spare rows on top.
        Allocated here by numpy (pages of zeros mapped as they are first
        written) in the order LAPACK reads, so that ``gbsv`` takes it
        without a copy; filled column by column in compiled code.
    """
    n = b.shape[0]
    kl, ku = 2 * lower + 1, 2 * upper + 1
    ab = np.zeros((2 * n, 2 * kl + ku + 1)).T
    _interleaved_block_band(K.indptr, K.indices, K.data, T.indptr, T.indices, T.data, M,
                            M if C is None else C, C is not None, b, float(c), float(c2),
                            int(lower), int(upper), ab)
    return ab, kl, ku


@njit(types.void(_INDEX, _INDEX, _VECTOR, _VECTOR, types.int64, types.int64, _BAND),
      **JIT_OPTIONS)
def _shifted_band(indptr, indices, data, d, lower, upper, ab):
    n = d.shape[0]
    top = lower + upper
    for i in range(n):
        for position in range(indptr[i], indptr[i + 1]):
            j = indices[position]
            ab[top + i - j, j] = data[position]
    for j in range(n):
        ab[top, j] += d[j]


def shifted_band(K, d, lower, upper):
    """``K + diag(d)`` in ``gbsv`` storage (``lower`` spare rows on top) for a
    CSR ``K`` as in :func:`interleaved_block_band` whose band lies within
    ``(lower, upper)``, as :class:`hfdi.linsolve.sparse._ShiftedTangent` builds it;
    Fortran order."""
    ab = np.zeros((d.shape[0], 2 * lower + upper + 1)).T
    _shifted_band(K.indptr, K.indices, K.data, d, int(lower), int(upper), ab)
    return ab
