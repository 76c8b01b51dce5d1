"""Compiled kernels of a :class:`hfdi.System` whose callables are numba
functions, and of a :class:`hfdi.LinearSystem`'s numba load.

A ``System`` built from functions compiled with ``numba.njit`` (``f(u)``,
``K(u)``, ``T(u, w)``, and optionally ``V(u)``, ``p(t)``, ``p'(t)``) runs
compiled, and so does a ``LinearSystem`` whose ``p(t)`` (and ``p'(t)``, if
given) are: each is called by a kernel of the signature the compiled loop
takes (:mod:`hfdi.compiled.signatures`), which hands ``u`` on and returns what
the function returns, so both speeds call the same machine code. A function
whose result is not of the kernel's type (a float64 C-contiguous array of
one or two dimensions, a float) fails to compile here: the run then takes
the Python path and says why once. The kernels close over the user's
functions, so numba compiles them in each process (not cached on disk).
"""
from __future__ import annotations

import functools
import math

import numpy as np

__all__ = ["system_kernels", "load_kernels", "is_compiled_function"]

#: The callables of a System, by the name its constructor takes them under.
_CALLABLES = ("internal_force", "stiffness", "stiffness_derivative", "potential_energy",
              "load", "load_rate")


def is_compiled_function(function) -> bool:
    """Whether ``function`` is a numba dispatcher (``numba.njit``'s result)."""
    from numba.core.dispatcher import Dispatcher
    return isinstance(function, Dispatcher)


def system_kernels(system, functions: dict):
    """:class:`~hfdi.compiled.CompiledKernels` of a ``System`` whose callables
    ``functions`` (by constructor name; ``None`` for one not given) are all
    numba functions.

    Raises
    ------
    hfdi.compiled.CompiledUnavailable
        Naming the first callable that is a Python function.
    """
    _refuse_python_functions("System", functions)
    from . import CompiledKernels
    from ..models.kernels import compiled
    from ..models.loads import hat_load, hat_load_params
    force, stiffness, stiffness_derivative, potential_energy, load, load_rate = _kernels(
        *(functions.get(name) for name in _CALLABLES))
    params = np.zeros(1)
    load_params = params
    if load is None:          # the zero load
        load, load_params = compiled(hat_load), hat_load_params(system.n_dof)
    return CompiledKernels(force, stiffness, stiffness_derivative, potential_energy, params,
                           load=load, load_params=load_params, load_rate=load_rate)


def load_kernels(owner: str, load, load_rate):
    """``(load, load_rate)``: the kernels calling the numba functions ``load``
    and ``load_rate`` (``None`` for one not given).

    Raises
    ------
    hfdi.compiled.CompiledUnavailable
        Naming the first of them that is a Python function (``owner``'s).
    """
    _refuse_python_functions(owner, {"load": load, "load_rate": load_rate})
    return _load_kernels(load, load_rate)


def _refuse_python_functions(owner, functions):
    from . import CompiledUnavailable
    for name in _CALLABLES:
        function = functions.get(name)
        if function is not None and not is_compiled_function(function):
            raise CompiledUnavailable(
                f"{owner}'s {name} is a Python function, which the compiled loop cannot call "
                f"(given as a numba.njit function, it runs compiled)")


@functools.lru_cache(maxsize=64)
def _load_kernels(p, dp):
    """The kernels calling ``p`` and ``p'`` (compiled once per pair in a process)."""
    from numba import njit

    from ..core.jit import JIT_OPTIONS
    from ..core.numba_types import LOAD
    load = load_rate = None
    if p is not None:
        @njit(LOAD, **JIT_OPTIONS)
        def load(time, params):
            return p(time)
    if dp is not None:
        @njit(LOAD, **JIT_OPTIONS)
        def load_rate(time, params):
            return dp(time)
    return load, load_rate


@functools.lru_cache(maxsize=64)
def _kernels(f, k, t, v, p, dp):
    """The kernels calling ``f``, ``K``, ``T``, ``V``, ``p``, ``p'`` (compiled
    once per set of functions in a process)."""
    from numba import njit

    from ..core.jit import JIT_OPTIONS
    from ..core.numba_types import FORCE, POTENTIAL_ENERGY, STIFFNESS, STIFFNESS_DERIVATIVE

    @njit(FORCE, **JIT_OPTIONS)
    def force(u, params):
        return f(u)

    @njit(STIFFNESS, **JIT_OPTIONS)
    def stiffness(u, params):
        return k(u)

    if t is None:
        # HFDI, the only scheme that calls T, is refused without it
        @njit(STIFFNESS_DERIVATIVE, **JIT_OPTIONS)
        def stiffness_derivative(u, w, params):
            return np.zeros((u.shape[0], u.shape[0]))
    else:
        @njit(STIFFNESS_DERIVATIVE, **JIT_OPTIONS)
        def stiffness_derivative(u, w, params):
            return t(u, w)

    if v is None:
        @njit(POTENTIAL_ENERGY, **JIT_OPTIONS)
        def potential_energy(u, params):
            return math.nan            # unknown, as System's potential_energy says
    else:
        @njit(POTENTIAL_ENERGY, **JIT_OPTIONS)
        def potential_energy(u, params):
            return v(u)

    return (force, stiffness, stiffness_derivative, potential_energy) + _load_kernels(p, dp)
