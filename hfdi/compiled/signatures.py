"""The numba types of the compiled model kernels (imports numba).

A compiled model gives four functions with exactly these signatures, so that
the compiled attempt (:mod:`hfdi.compiled.attempt`), compiled once for these
types, calls any model's kernels through function pointers and is cached on
disk once for all models (see docs/compiled.md):

- ``force(u, params) -> f``                      :data:`FORCE`
- ``stiffness(u, params) -> K``                  :data:`STIFFNESS`
- ``stiffness_derivative(u, w, params) -> T``    :data:`STIFFNESS_DERIVATIVE`
- ``potential_energy(u, params) -> V``           :data:`POTENTIAL_ENERGY`

and, for the compiled driver (:mod:`hfdi.compiled.driver`), a fifth:

- ``load(t, load_params) -> p``                  :data:`LOAD`

``u``, ``w`` and ``params`` are C-contiguous float64 vectors, ``f`` a new
C-contiguous (N,) vector, ``K`` and ``T`` new C-contiguous (N, N) arrays.

A large sparse model (:class:`hfdi.compiled.SparseKernels`) may fill the data
array of its fixed CSR pattern instead, from the element positions ``slots``
(an int64 array) and the number of stored entries ``nnz``:

- ``stiffness_data(u, params, slots, nnz) -> data``           :data:`SPARSE_STIFFNESS`
- ``stiffness_derivative_data(u, w, params, slots, nnz) -> data``
  :data:`SPARSE_STIFFNESS_DERIVATIVE`
"""
from __future__ import annotations

from numba import types
from numba.experimental import structref

from .cache import drop_stale_cache

# Every compiled module imports this one first: the cache is checked once,
# before numba loads anything from it (see hfdi.compiled.cache).
drop_stale_cache()

__all__ = ["VECTOR", "MATRIX", "TENSOR", "INDEX_VECTOR", "INT32_MATRIX", "FORCE", "STIFFNESS",
           "STIFFNESS_DERIVATIVE", "POTENTIAL_ENERGY", "LOAD", "SPARSE_STIFFNESS",
           "SPARSE_STIFFNESS_DERIVATIVE", "FORCE_TYPE", "STIFFNESS_TYPE",
           "STIFFNESS_DERIVATIVE_TYPE", "POTENTIAL_ENERGY_TYPE", "LOAD_TYPE", "JIT_OPTIONS",
           "KernelSet", "KERNEL_SET"]

VECTOR = types.float64[::1]
MATRIX = types.float64[:, ::1]
TENSOR = types.float64[:, :, ::1]
INDEX_VECTOR = types.int64[::1]
INT32_MATRIX = types.int32[:, ::1]

#: ``f(u, params)``
FORCE = VECTOR(VECTOR, VECTOR)
#: ``K(u, params)``
STIFFNESS = MATRIX(VECTOR, VECTOR)
#: ``T(u, params)[w]``, called as ``stiffness_derivative(u, w, params)``
STIFFNESS_DERIVATIVE = MATRIX(VECTOR, VECTOR, VECTOR)
#: ``V(u, params)``
POTENTIAL_ENERGY = types.float64(VECTOR, VECTOR)
#: ``p(t, load_params)``
LOAD = VECTOR(types.float64, VECTOR)
#: ``data of K(u)`` in a fixed CSR pattern: ``stiffness_data(u, params, slots, nnz)``
SPARSE_STIFFNESS = VECTOR(VECTOR, VECTOR, types.int64[:, ::1], types.int64)
#: ``data of T(u)[w]``: ``stiffness_derivative_data(u, w, params, slots, nnz)``
SPARSE_STIFFNESS_DERIVATIVE = VECTOR(VECTOR, VECTOR, VECTOR, types.int64[:, ::1], types.int64)

FORCE_TYPE = types.FunctionType(FORCE)
STIFFNESS_TYPE = types.FunctionType(STIFFNESS)
STIFFNESS_DERIVATIVE_TYPE = types.FunctionType(STIFFNESS_DERIVATIVE)
POTENTIAL_ENERGY_TYPE = types.FunctionType(POTENTIAL_ENERGY)
LOAD_TYPE = types.FunctionType(LOAD)


@structref.register
class KernelSetType(types.StructRef):
    """The numba type of a :class:`KernelSet`."""

    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class KernelSet(structref.StructRefProxy):
    """A model's six kernels (f, K, T, V, p, p') in one object for the compiled
    attempt and driver, made once per compiled step
    (:func:`hfdi.compiled.attempt.kernel_set`).

    Why: numba unboxes each first-class function argument at every call
    (about 2 µs each, 12 µs for six: a third of a one-step ``advance`` on the
    dumbbell); this object unboxes as one pointer. It holds the kernels'
    addresses, not the Python objects: whoever makes it keeps those alive.
    """


structref.define_boxing(KernelSetType, KernelSet)

#: The type of a :class:`KernelSet`: fields ``force``, ``stiffness``,
#: ``stiffness_derivative``, ``potential_energy``, ``load``, ``load_rate``.
KERNEL_SET = KernelSetType([("force", FORCE_TYPE), ("stiffness", STIFFNESS_TYPE),
                            ("stiffness_derivative", STIFFNESS_DERIVATIVE_TYPE),
                            ("potential_energy", POTENTIAL_ENERGY_TYPE), ("load", LOAD_TYPE),
                            ("load_rate", LOAD_TYPE)])

#: Options of every compiled function here: cached on disk; division by zero
#: gives inf/NaN as in numpy (a non-finite value fails the attempt, as a
#: model returning NaN does on the Python path) instead of raising.
JIT_OPTIONS = dict(cache=True, error_model="numpy")
