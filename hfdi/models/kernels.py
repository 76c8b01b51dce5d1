"""One definition of a model's physics for both speeds.

A benchmark model writes its ``f``, ``K``, ``T[w]`` and ``V`` once, as plain
functions of ``(u, params)`` declared :func:`kernel`; its Python methods call
them as plain Python, its ``compiled_kernels()`` hands them compiled
(:func:`compiled`); docs/models.md, "One physics per model". Importing this
module imports no numba.
"""
from __future__ import annotations

import functools

from ..core.jit import entry, jitable

__all__ = ["kernel", "compiled", "compiled_kernels"]

#: A model's kernel or a function a kernel calls: plain Python when called
#: from Python, compiled into the kernel (:func:`hfdi.core.jit.twin`) in compiled code.
kernel = jitable


@functools.lru_cache(maxsize=None)
def compiled(function):
    """The numba dispatcher of the kernel ``function``, the functions it calls
    being their compiled twins; cached on disk where the cache is trusted
    (:func:`hfdi.core.jit.cache_trusted`), compiled for the kernel's
    signature when the compiled loop first takes it. Imports numba."""
    return entry(function).dispatcher


def compiled_kernels(force, stiffness, stiffness_derivative, potential_energy, params,
                     load=None, load_params=None):
    """:class:`hfdi.compiled.CompiledKernels` of the plain kernels given, compiled
    (:func:`compiled`); ``load`` defaults to the hat-pulse load
    (:func:`hfdi.models.loads.hat_load`)."""
    import numpy as np

    from ..compiled import CompiledKernels
    from .loads import hat_load
    return CompiledKernels(compiled(force), compiled(stiffness), compiled(stiffness_derivative),
                           compiled(potential_energy),
                           np.ascontiguousarray(params, dtype=np.float64),
                           compiled(hat_load if load is None else load),
                           np.ascontiguousarray(load_params, dtype=np.float64))
