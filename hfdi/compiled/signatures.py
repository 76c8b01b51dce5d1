"""The types of compiled model kernels (imports numba), for kernels written by hand.

The signatures themselves are :mod:`hfdi.core.state`'s (``FORCE``, ``STIFFNESS``,
``STIFFNESS_DERIVATIVE``, ``POTENTIAL_ENERGY``, ``LOAD``); a large sparse model may
fill the data array of its fixed CSR pattern instead, from the element positions
``slots`` (an int64 array) and the number of stored entries ``nnz``:

- ``stiffness_data(u, params, slots, nnz) -> data``           :data:`SPARSE_STIFFNESS`
- ``stiffness_derivative_data(u, w, params, slots, nnz) -> data``
  :data:`SPARSE_STIFFNESS_DERIVATIVE`

``JIT_OPTIONS`` are the options of every kernel: cached on disk (where the
cache is trusted, :func:`hfdi.core.jit.cache_trusted`), division by zero
giving inf/NaN as in numpy.
"""
from __future__ import annotations

from numba import types

from ..core.jit import JIT_OPTIONS as _OPTIONS
from ..core.jit import cache_trusted
from ..core.numba_types import (FORCE, LOAD, MATRIX, POTENTIAL_ENERGY, STIFFNESS,
                                STIFFNESS_DERIVATIVE, VECTOR)

__all__ = ["VECTOR", "MATRIX", "FORCE", "STIFFNESS", "STIFFNESS_DERIVATIVE", "POTENTIAL_ENERGY",
           "LOAD", "SPARSE_STIFFNESS", "SPARSE_STIFFNESS_DERIVATIVE", "JIT_OPTIONS"]

#: ``data of K(u)`` in a fixed CSR pattern: ``stiffness_data(u, params, slots, nnz)``
SPARSE_STIFFNESS = VECTOR(VECTOR, VECTOR, types.int64[:, ::1], types.int64)
#: ``data of T(u)[w]``: ``stiffness_derivative_data(u, w, params, slots, nnz)``
SPARSE_STIFFNESS_DERIVATIVE = VECTOR(VECTOR, VECTOR, VECTOR, types.int64[:, ::1], types.int64)

JIT_OPTIONS = dict(cache=cache_trusted()[0], **_OPTIONS)
