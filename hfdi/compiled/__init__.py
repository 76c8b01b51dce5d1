"""Compiled (numba) models: the kernels protocol, their checks, and the choice of path.

A model offers :class:`CompiledKernels` through ``compiled_kernels()``, or, for
a large sparse system, :class:`SparseKernels` through
``compiled_sparse_kernels()``; :func:`kernel_mismatch` checks that they
compute the model. docs/compiled.md describes the protocol and the speed.
"""
from __future__ import annotations

import logging
import math
import warnings
from typing import Callable, NamedTuple

import numpy as np

__all__ = ["CompiledKernels", "CompiledUnavailable", "InitialValues", "KERNEL_TOLERANCE",
           "NativeAdvance", "SparseKernels", "compiled_reason", "kernel_mismatch",
           "kernels_of", "library_kernels", "numba_available", "sparse_kernels_of",
           "say_once", "follow_model", "zero_load"]

_log = logging.getLogger("hfdi.compiled")


def __getattr__(name):
    # NativeAdvance compiles (or loads) its C function on import, the zero load
    # imports numba: only when asked for
    if name == "zero_load":
        from .loads import hat_load
        return hat_load
    if name == "NativeAdvance":
        from .native import NativeAdvance
        return NativeAdvance
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class CompiledKernels(NamedTuple):
    """A model's compiled kernels and the data they read.

    Attributes
    ----------
    force : numba function ``(u, params) -> f (N,)``
    stiffness : numba function ``(u, params) -> K (N, N)``
    stiffness_derivative : numba function ``(u, w, params) -> T(u)[w] (N, N)``
    potential_energy : numba function ``(u, params) -> V`` (float)
    params : ndarray (P,), float64, C-contiguous
        The model's data, read by the kernels and never written.
    load : numba function ``(t, load_params) -> p (N,)``, optional
        The model's load ``p(t)``; without it the run is compiled only for a
        model whose load is the zero load.
        :func:`hfdi.compiled.loads.hat_load` is the zero load and sums of hat pulses.
    load_params : ndarray (Q,), float64, C-contiguous, optional
        The load's data (``params`` itself, the same array, when the load
        reads the model's data).
    load_rate : numba function ``(t, load_params) -> p' (N,)``, optional
        The exact load rate, for a model whose ``load_rate`` HFDI takes.

    Each function is compiled with the signature of
    :mod:`hfdi.compiled.signatures` (``FORCE``, ``STIFFNESS``,
    ``STIFFNESS_DERIVATIVE``, ``POTENTIAL_ENERGY``, ``LOAD``).
    """

    force: Callable
    stiffness: Callable
    stiffness_derivative: Callable
    potential_energy: Callable
    params: np.ndarray
    load: Callable | None = None
    load_params: np.ndarray | None = None
    load_rate: Callable | None = None


class SparseKernels(NamedTuple):
    """Compiled ``f``, ``K`` and ``T`` of a large sparse model, called as the model's own methods.

    For systems of ``N ≥ DENSE_BELOW`` unknowns the steps run in Python with
    sparse and banded linear algebra; the evaluator calls these instead of the
    model's methods (e.g. :meth:`hfdi.models.TossRule.compiled_sparse_kernels`).

    Attributes
    ----------
    force : callable ``u -> f``, (N,) float64
    stiffness : callable ``u -> K``, scipy CSR (N, N)
    stiffness_derivative : callable ``(u, w) -> T(u)[w]``, scipy CSR (N, N)
    """

    force: Callable
    stiffness: Callable
    stiffness_derivative: Callable


class InitialValues(NamedTuple):
    """The Python model's values at the initial state, which the kernels must
    reproduce (see :func:`kernel_mismatch`): ``t0``, ``u0``, ``v0``, ``f(u0)``,
    ``K(u0)``, ``T(u0)[v0]`` (``None`` unless HFDI) and ``V(u0)``."""

    t0: float
    u0: np.ndarray
    v0: np.ndarray
    f: np.ndarray
    K: object
    T: object
    V: float
    #: the load is compared at times up to this one (the run's ``t_bound``)
    t_end: float = math.inf


#: Largest relative difference allowed between a kernel and the Python method it
#: restates (they differ by rounding: sums in another order).
KERNEL_TOLERANCE = 1e-8


def _difference(kernel_value, python_value):
    """``max |a − b| / max |b|``, inf for another shape or a non-finite ``a``;
    sparse against sparse without forming either densely."""
    import scipy.sparse as sp
    if sp.issparse(kernel_value) and sp.issparse(python_value):
        if kernel_value.shape != python_value.shape \
                or not np.all(np.isfinite(kernel_value.data)):
            return math.inf
        scale = float(abs(python_value).max()) if python_value.nnz else 0.0
        gap = abs(kernel_value - python_value)
        gap = float(gap.max()) if gap.nnz else 0.0
        return gap / scale if scale > 0 else float(abs(kernel_value).max())
    b = python_value.toarray() if hasattr(python_value, "toarray") else np.asarray(
        python_value, dtype=float)
    a = np.asarray(kernel_value, dtype=float)
    if a.shape != b.shape:
        return math.inf
    # not finite where the Python method is not finite either is agreement
    # (a load undefined past the run, a state outside a model's domain)
    finite = np.isfinite(b)
    if not np.array_equal(np.isfinite(a), finite) or not np.array_equal(a[~finite], b[~finite],
                                                                       equal_nan=True):
        return math.inf
    a, b = a[finite], b[finite]
    if not b.size:
        return 0.0
    scale = float(np.abs(b).max())
    return float(np.abs(a - b).max()) / scale if scale > 0 else float(np.abs(a).max())


def _probe(system, u0):
    """A second state for the kernels' check, ``u0`` moved by 5 % of ``u_scale``
    along a fixed direction, and a direction ``w`` for ``T[w]`` (docs/compiled.md,
    "Decision: the second state")."""
    i = np.arange(1.0, u0.size + 1.0)
    scale = float(getattr(system, "u_scale", 1.0) or 1.0)
    d = np.sin(1.3 * i + 0.7)
    return u0 + 0.05 * scale * d / np.abs(d).max(), np.cos(0.9 * i + 0.4)


def _state_checks(system, initial, calls):
    """``(what, kernel call, Python value)`` for the kernels
    ``calls = (f(u), K(u), T(u, w), V(u) or None)`` at the initial state and at
    :func:`_probe`'s state (not there where the Python model fails)."""
    force, stiffness, derivative, energy = calls
    u0 = np.ascontiguousarray(initial.u0, dtype=np.float64)
    v0 = np.ascontiguousarray(initial.v0, dtype=np.float64)
    hfdi = initial.T is not None
    potential = energy is not None and math.isfinite(initial.V)
    checks = [("force", lambda: force(u0), initial.f),
              ("stiffness", lambda: stiffness(u0), initial.K)]
    if hfdi:
        checks.append(("stiffness_derivative", lambda: derivative(u0, v0), initial.T))
    if potential:
        checks.append(("potential_energy", lambda: energy(u0), initial.V))
    u1, w = _probe(system, u0)
    try:
        values = [("force", lambda: force(u1), system.internal_force(u1)),
                  ("stiffness", lambda: stiffness(u1), system.stiffness(u1))]
        if hfdi:
            values.append(("stiffness_derivative", lambda: derivative(u1, w),
                           system.stiffness_derivative(u1, w)))
        if potential:
            values.append(("potential_energy", lambda: energy(u1), system.potential_energy(u1)))
    except Exception:
        return checks
    return checks + [(f"{what} at a second state", call, value) for what, call, value in values]


#: Where the library's own kernels are defined (tests/test_one_implementation.py
#: holds the two speeds equal on them).
_LIBRARY_MODULES = ("hfdi.models.",)


def library_kernels(system, kernels) -> bool:
    """Whether ``system``'s kernels are the library's own: every function of
    ``kernels`` from :data:`_LIBRARY_MODULES`, handed out by a model class of
    :mod:`hfdi.models`. Then :func:`kernel_mismatch` is not run
    (docs/compiled.md, "Decision: the library's own kernels are not checked").
    """
    method = "compiled_kernels" if isinstance(kernels, CompiledKernels) else \
        "compiled_sparse_kernels"
    source = getattr(getattr(type(system), method, None), "__module__", "") or ""
    functions = [k for k in kernels if callable(k)]
    return source.startswith("hfdi.models.") and bool(functions) and all(
        str(getattr(k, "__module__", "")).startswith(_LIBRARY_MODULES) for k in functions)


def kernel_mismatch(system, kernels, initial: InitialValues, params=None) -> str:
    """Why ``kernels`` do not compute ``system`` (``""`` when they do): each
    kernel at the initial state and at :func:`_probe`'s, and the load at a few
    times up to ``initial.t_end``, against the Python model (docs/compiled.md,
    "Models"). ``params``: the kernels' data now (default ``kernels.params``)."""
    p = kernels.params if params is None else params
    checks = _state_checks(system, initial, (
        lambda u: kernels.force(u, p), lambda u: kernels.stiffness(u, p),
        lambda u, w: kernels.stiffness_derivative(u, w, p),
        lambda u: kernels.potential_energy(u, p)))
    if kernels.load is not None:
        # a pulse is often zero at t0: the load also at later times, and just
        # after each breakpoint; within the run (a load may be defined up to
        # its end only)
        times = [initial.t0 + dt for dt in (0.0, 1e-3, 1e-2, 0.1, 1.0, 10.0)]
        breakpoints = system.load_breakpoints() if hasattr(system, "load_breakpoints") else ()
        times += [float(b) * (1.0 + 1e-3) + 1e-9 for b in list(breakpoints)[:8]]
        times = [t for t in times if t == initial.t0 or t <= initial.t_end]
        # load data that are the model's data follow them, as in the compiled loop
        load_params = p if kernels.load_params is kernels.params else kernels.load_params
        rate = kernels.load_rate if getattr(system, "load_rate", None) is not None else None
        for t in times:
            try:
                python = np.asarray(system.load(t), dtype=float)
                python_rate = None if rate is None else np.asarray(system.load_rate(t), float)
            except Exception:        # the Python load is not defined there: not compared
                continue
            checks.append((f"load at t = {t:g}", lambda t=t: kernels.load(t, load_params),
                           python))
            if rate is not None:
                checks.append((f"load_rate at t = {t:g}",
                               lambda t=t: rate(t, load_params), python_rate))
    return _first_mismatch(type(system).__name__, checks)


def _first_mismatch(name, checks) -> str:
    """The first ``(what, kernel call, Python value)`` of ``checks`` whose values differ."""
    for what, kernel, python in checks:
        try:
            difference = _difference(kernel(), python)
        except Exception as exc:
            return _Fault(f"model {name}: its compiled {what} raised "
                          f"{type(exc).__name__}: {exc}")
        if not difference <= KERNEL_TOLERANCE:
            return _Fault(f"model {name}: its compiled {what} does not match the Python "
                          f"method (relative difference {difference:.3g}): the kernels "
                          f"compute another model")
    return ""


class CompiledUnavailable(RuntimeError):
    """``compiled=True`` was asked for but the compiled path cannot run (the
    message says why)."""


_NUMBA = None          # None: not tried yet; else (ok, reason)


def numba_available() -> tuple[bool, str]:
    """``(True, "")`` when numba imports, else ``(False, why)``; tried once per process."""
    global _NUMBA
    if _NUMBA is None:
        try:
            import numba  # noqa: F401
            _NUMBA = (True, "")
        except Exception as exc:     # ImportError, or a broken llvmlite
            _NUMBA = (False, f"numba cannot be imported ({type(exc).__name__}: {exc})")
    return _NUMBA


_METHODS = ("internal_force", "stiffness", "stiffness_derivative")


def _definer(cls, name):
    """The class of ``cls``'s MRO that defines ``name``, or ``None``."""
    return next((c for c in cls.__mro__ if name in vars(c)), None)


class _Fault(str):
    """A reason for the Python path that is a fault, said once in the log (not
    merely a model without kernels)."""


def kernels_of(system):
    """``(kernels, "")`` for a model whose ``compiled_kernels()`` describe its
    Python methods, else ``(None, why)`` (a subclass that overrides
    ``internal_force``, ``stiffness`` or ``stiffness_derivative`` but not
    ``compiled_kernels`` runs on the Python path)."""
    kernels, why = _offered(system, "compiled_kernels", CompiledKernels, "compiled kernels")
    if kernels is None:
        return None, why
    cls = type(system)
    owner = _definer(cls, "compiled_kernels")
    if kernels.load is not None:
        # the compiled loop also runs the load and V: a subclass that
        # redefines them has no compiled load
        for name in _DRIVER_METHODS:
            if not issubclass(owner, _definer(cls, name) or object):
                kernels = kernels._replace(load=None, load_params=None)
                break
    return kernels, ""


_DRIVER_METHODS = ("load", "load_rate", "load_breakpoints", "potential_energy")


def sparse_kernels_of(system):
    """``(kernels, "")`` for a model whose :class:`SparseKernels` describe its
    Python methods, else ``(None, why)``; as :func:`kernels_of`, with
    ``compiled_sparse_kernels()``."""
    return _offered(system, "compiled_sparse_kernels", SparseKernels,
                    "compiled sparse kernels")


def _offered(system, method, kind, what):
    """``(system.method(), "")`` when the model offers kernels of type ``kind``
    through ``method`` that describe its Python methods, else ``(None, why)``."""
    cls = type(system)
    owner = _definer(cls, method)
    if owner is None:
        return None, f"model {cls.__name__} has no {what}"
    for name in _METHODS:
        if not issubclass(owner, _definer(cls, name) or object):
            return None, (f"{cls.__name__}.{name} overrides the method of {owner.__name__}, "
                          f"whose compiled kernels compute another model")
    ok, why = numba_available()
    if not ok:
        return None, why
    try:
        kernels = getattr(system, method)()
    except CompiledUnavailable as exc:
        return None, str(exc)
    except Exception as exc:
        # numba failing to compile or to cache (no writable cache directory,
        # say): the run does not depend on it, the Python path takes it
        return None, _Fault(f"{cls.__name__}.{method}() failed: {type(exc).__name__}: {exc}")
    if not isinstance(kernels, kind):
        raise TypeError(f"{cls.__name__}.{method}() must return a hfdi.compiled.{kind.__name__}, "
                        f"got {type(kernels).__name__}")
    return kernels, ""


def sparse_kernel_mismatch(system, kernels: SparseKernels, initial: InitialValues) -> str:
    """:func:`kernel_mismatch` for :class:`SparseKernels` (f, K and T[v0] at u0,
    f, K and T[w] at the second state)."""
    checks = _state_checks(system, initial, (kernels.force, kernels.stiffness,
                                             kernels.stiffness_derivative, None))
    return _first_mismatch(type(system).__name__, checks)


_SAID = set()


def say_once(reason: str, message: str = "the compiled step is not used ({reason}); "
                                        "the Python path runs") -> None:
    """Warn once per process and message (``message``, with ``{reason}`` in it)
    that the Python path runs instead."""
    message = "hfdi: " + message.format(reason=reason)
    if message in _SAID:
        return
    _SAID.add(message)
    _log.info(message)
    warnings.warn(message, RuntimeWarning, stacklevel=3)


#: The model's methods whose instance attributes (``m.load = ...``) would make
#: the model another one than its class's compiled kernels compute.
_SHADOWED = frozenset({"internal_force", "stiffness", "stiffness_derivative", "load",
                       "load_rate", "load_breakpoints", "potential_energy"})


def shadowed(system) -> str:
    """The first of the model's methods replaced by an instance attribute, or ``""``."""
    names = _SHADOWED.intersection(getattr(system, "__dict__", {}))
    return min(names) if names else ""


def compiled_reason(integrator, initial: InitialValues):
    """``("", kernels)`` when ``integrator``'s run can be compiled with the model's
    kernels, else ``(why, None)``: a custom controller, an ``extra_load`` other
    than a :class:`~hfdi.HeldLoad`, no kernels (or numba missing), a method
    replaced on the instance, a Python load without a compiled one, an exact
    load rate without a compiled one, or kernels that compute another model."""
    from ..controller import core_kind
    from ..core.state import CUSTOM
    from ..system import HeldLoad, SecondOrderSystem
    system, ev = integrator.system, integrator.ev
    if core_kind(integrator.controller) == CUSTOM:
        return (f"controller {type(integrator.controller).__name__} is not one of the built-in "
                f"controllers"), None
    if ev.extra_load is not None and not isinstance(ev.extra_load, HeldLoad):
        return "an extra_load is given that is not a hfdi.HeldLoad", None
    kernels, why = kernels_of(system)
    if why:
        return why, None
    name = shadowed(system)
    if name:
        return (f"{type(system).__name__}.{name} is replaced on the instance, which its "
                f"compiled kernels do not compute"), None
    if kernels.load is None and type(system).load is not SecondOrderSystem.load:
        return f"model {type(system).__name__} has no compiled load", None
    if integrator._cfg.exact_rate and kernels.load_rate is None:
        return "HFDI takes the model's exact load rate, which has no compiled form", None
    if not library_kernels(system, kernels):
        reason = kernel_mismatch(system, kernels, initial)
        if reason:
            return reason, None
    return "", kernels


def refused(compiled, reason, what) -> bool:
    """Raise for ``compiled=True``; else say a fault (or a missing numba) once:
    whether it is such a one (said now or before)."""
    if compiled:
        raise CompiledUnavailable(f"compiled=True, but {what}: {reason}")
    if isinstance(reason, _Fault) or (not numba_available()[0]
                                      and reason == numba_available()[1]):
        say_once(reason)
        return True
    return False


def use_sparse_kernels(ev, compiled, initial):
    """A sparse system (``N ≥ DENSE_BELOW``): its model's f, K and T run
    compiled (:class:`SparseKernels`) when it has them and they match it."""
    kernels, reason = sparse_kernels_of(ev.system)
    if not reason and initial is not None:
        reason = "" if library_kernels(ev.system, kernels) else \
            sparse_kernel_mismatch(ev.system, kernels, initial)
    if reason:
        from ..evaluation import DENSE_BELOW
        refused(compiled, reason, f"the system has {ev.n} degrees of freedom (N ≥ "
                f"{DENSE_BELOW}, the steps run in Python) and its model cannot run compiled")
        return
    ev.use_kernels(kernels)


def follow_model(integrator) -> None:
    """After ``integrator.model_changed()`` on a compiled run: the kernels' data
    from the model now, checked against it again at the current state; where
    they differ, the rest of the run is the Python path, said once."""
    from ..schemes import HFDI
    system = integrator.system
    kernels, why = kernels_of(system)
    if not why and shadowed(system):
        why = f"{type(system).__name__}.{shadowed(system)} is replaced on the instance"
    if not why and not library_kernels(system, kernels):
        state = integrator.state
        try:
            K = system.stiffness(state.u)
            T = system.stiffness_derivative(state.u, state.v) if isinstance(
                integrator.scheme, HFDI) else None
        except Exception:       # not compared; the next step meets it
            K = T = None
        if K is not None:
            initial = InitialValues(state.t, state.u, state.v, state.f, K, T,
                                    integrator.potential_energy,
                                    math.inf if integrator.t_bound is None else
                                    integrator.t_bound)
            why = kernel_mismatch(system, kernels, initial)
    if why:
        say_once(str(why), "after the model changed: {reason}; the rest of the run takes its "
                 "steps in Python")
        integrator._leave_compiled(f"after the model changed: {why}")
        return
    take_kernel_data(integrator, kernels)


def follow_load(integrator) -> None:
    """After ``integrator.load_changed()`` on a compiled run: the load's data
    (and the model's) from the model now, as the Python steps' load takes it."""
    kernels, why = kernels_of(integrator.system)
    if not why:
        take_kernel_data(integrator, kernels)


def take_kernel_data(integrator, kernels) -> None:
    """The compiled run takes the data of ``kernels`` (the model's now): in place
    where the arrays keep their shapes (a native host holds them), else new
    arrays; new kernel functions make the run's functions again."""
    if any(getattr(kernels, name) is not getattr(integrator._kernels, name)
           for name in ("force", "stiffness", "stiffness_derivative", "potential_energy",
                        "load", "load_rate")):
        integrator._use_compiled(kernels)
        return
    data = integrator._data
    params = np.ascontiguousarray(kernels.params, dtype=float)
    if kernels.load_params is kernels.params:
        load_params = params
    elif kernels.load_params is None:
        load_params = None          # the zero load's: unchanged
    else:
        load_params = np.array(kernels.load_params, dtype=float)
    replaced = {}
    if params.shape == data.params.shape:
        data.params[:] = params
    else:
        replaced["params"] = params
    if load_params is not None:
        if load_params.shape == data.load_params.shape:
            data.load_params[:] = load_params
        else:
            replaced["load_params"] = load_params
    if replaced:
        integrator._data = data._replace(**replaced)
        integrator._refresh_compiled()

