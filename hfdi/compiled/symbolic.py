"""Compiled kernels of an :class:`~hfdi.models.EnergyModel`, generated from its sympy expressions.

The expressions the model derived at construction are printed, after
common-subexpression elimination, as the source of numba functions with the
signatures of :mod:`hfdi.compiled.signatures`, computing in float64 as the
Python path does, written once under ``<cache>/kernels/`` by the digest of
their text and run as that file (docs/compiled.md, "Models"). They read the
model's parameters from ``params`` (``EnergyModel.compiled_params``); a load
of sympy expressions gives two more kernels, ``p(t)`` and ``p'(t)``.
"""
from __future__ import annotations

import hashlib
import sys
import types
import weakref

from . import CompiledKernels
from ..files import cache_dir, write_atomic

__all__ = ["energy_model_kernels", "kernel_source", "KernelSourceError"]

#: Generated modules imported in this process, by digest.
_IMPORTED: dict = {}
#: model -> its kernels' module, for as long as the model lives.
_MODULE_OF = weakref.WeakKeyDictionary()


class KernelSourceError(ValueError):
    """The model's expressions cannot be printed as compiled code (a sympy
    function without a Python ``math`` counterpart, such as ``besselj``)."""


_PRINTER_CLASS = None


def _printer():
    """sympy's Python printer, made to compute in float64 as the Python path does.

    Under numba ``math.floor``, ``math.ceil``, ``abs``/``max``/``min`` of
    integers, a conditional between integer literals and a product of int64
    values are int64: ``floor(n)**(-2)`` would be 0 and ``ceil(n)**5`` could
    wrap around, where lambdify's numpy code computes in floats. So every
    application of a function (``floor``, ``Max``, ``Mod``, ``sign``,
    ``Piecewise``, ...) is printed inside ``float(...)``, which costs nothing
    on a float. An integer beyond 2**53 is printed as the float numpy makes
    of it (numba cannot type one beyond int64 at all).
    Sums, products and powers of floats are floats; the integer literals
    left are exponents and coefficients, which numba converts as Python does.
    """
    global _PRINTER_CLASS
    if _PRINTER_CLASS is None:
        import sympy
        from sympy.printing.pycode import PythonCodePrinter

        class FloatPrinter(PythonCodePrinter):
            def _print(self, expr, **kwargs):
                text = super()._print(expr, **kwargs)
                if isinstance(expr, sympy.Expr) and not isinstance(
                        expr, (sympy.Atom, sympy.Add, sympy.Mul, sympy.Pow)):
                    return f"float({text})"
                return text

            def _print_Integer(self, expr):
                value = int(expr)
                return repr(float(value)) if abs(value) > 2 ** 53 else str(value)

            def _print_Rational(self, expr):
                return (f"{self._print_Integer(sympy.Integer(expr.p))}/"
                        f"{self._print_Integer(sympy.Integer(expr.q))}")

        _PRINTER_CLASS = FloatPrinter
    return _PRINTER_CLASS({"fully_qualified_modules": True})


def _body(printer, exprs, prefix):
    """Lines assigning ``<prefix><i> = exprs[i]`` after common-subexpression
    elimination (shared temporaries ``_c<k>``)."""
    from sympy.printing.codeprinter import PrintMethodNotImplementedError

    from ..models.derivation import cse
    temporaries, reduced = cse(exprs)
    try:
        lines = [f"    {symbol} = {printer.doprint(value)}" for symbol, value in temporaries]
        lines += [f"    {prefix}{i} = {printer.doprint(value)}" for i, value in enumerate(reduced)]
    except PrintMethodNotImplementedError as exc:
        raise KernelSourceError(str(exc).splitlines()[0]) from None
    return lines


def _derived_body(printer, derivation, group, prefix):
    """:func:`_body` of a group of the model's derivatives (``"v"``, ``"f"``,
    ``"k"``, ``"t"``): printed from symengine's reduced expressions where
    symengine derived them, by sympy's printer otherwise."""
    from ..models.derivation import UnprintableError, reduced_lines
    if derivation.engine == "symengine":
        try:
            return reduced_lines(derivation, group, prefix, "math")
        except UnprintableError:
            pass
    exprs = [derivation.v] if group == "v" else getattr(derivation, group)
    return _body(printer, exprs, prefix)


def _matrix(lines, name, n, layout, prefix):
    """``name = zeros((n, n))`` and the entries of a symmetric layout from ``<prefix><k>``."""
    lines.append(f"    {name} = np.zeros(({n}, {n}))")
    for row, col, source in zip(layout.rows, layout.cols, layout.source):
        lines.append(f"    {name}[{row}, {col}] = {prefix}{source}")


def kernel_source(model) -> str:
    """The Python source of the four kernels of ``model`` (an EnergyModel).

    Raises
    ------
    KernelSourceError
        When an expression uses a function that has no compiled form.
    """
    from ..models.derivation import unpacked
    printer = _printer()
    n = model.n_dof
    ex = model._plain_exprs
    derived = model._derivation
    u = unpacked("u", model._u)
    p = unpacked("params", model._p)
    lines = ['"""Kernels generated by hfdi.compiled.symbolic from an EnergyModel; do not edit."""',
             "import math", "", "import numpy as np", "from numba import njit", "",
             # the package this module is part of: an FMU imports its bundled
             # copy under another name, in hosts that may have no hfdi at all
             f"from {__package__}.signatures import (FORCE, LOAD, POTENTIAL_ENERGY, "
             "STIFFNESS,", "    STIFFNESS_DERIVATIVE)",
             f"from {__package__.rpartition('.')[0]}.core.jit import JIT_OPTIONS as _OPTIONS",
             f"from {__package__.rpartition('.')[0]}.core.jit import cache_trusted", "",
             # cached only where the cache is trusted now (HFDI_CACHE_DIR as it is
             # at import), never in a directory numba would fall back on
             "JIT_OPTIONS = dict(cache=cache_trusted()[0], **_OPTIONS)", ""]
    lines += ["", "@njit(FORCE, **JIT_OPTIONS)", "def force(u, params):", *u, *p]
    lines += _derived_body(printer, derived, "f", "_f")
    lines.append(f"    f = np.empty({n})")
    lines += [f"    f[{i}] = _f{i}" for i in range(n)]
    lines += ["    return f", ""]
    lines += ["", "@njit(STIFFNESS, **JIT_OPTIONS)", "def stiffness(u, params):", *u, *p]
    lines += _derived_body(printer, derived, "k", "_k")
    _matrix(lines, "K", n, model._k_layout, "_k")
    lines += ["    return K", ""]
    lines += ["", "@njit(STIFFNESS_DERIVATIVE, **JIT_OPTIONS)",
              "def stiffness_derivative(u, w, params):", *u, *unpacked("w", model._w), *p]
    lines += _derived_body(printer, derived, "t", "_t")
    _matrix(lines, "T", n, model._t_layout, "_t")
    lines += ["    return T", ""]
    lines += ["", "@njit(POTENTIAL_ENERGY, **JIT_OPTIONS)", "def potential_energy(u, params):",
              *u, *p]
    lines += _derived_body(printer, derived, "v", "_v")
    lines += ["    return float(_v0)", ""]
    for name, key in (("load", "p"), ("load_rate", "dp")):
        if not ex.get("p"):
            break
        lines += ["", "@njit(LOAD, **JIT_OPTIONS)", f"def {name}(t, params):",
                  f"    {model._t} = t", *p]
        lines += _body(printer, ex[key], "_l")
        lines.append(f"    p = np.empty({n})")
        lines += [f"    p[{i}] = _l{i}" for i in range(n)]
        lines += ["    return p", ""]
    return "\n".join(lines)


def _import(source: str):
    """The module of ``source``, written under the cache directory by its digest."""
    digest = hashlib.sha256(source.encode("utf-8")).hexdigest()[:24]
    module = _IMPORTED.get(digest)
    if module is not None:
        return module
    name = f"hfdi_energy_kernels_{digest}"
    path = cache_dir() / "kernels" / f"{name}.py"
    if not (path.is_file() and path.read_text(encoding="utf-8") == source):
        write_atomic(path, source)
    # the text generated here is run, never bytecode found beside the file
    # (nothing compares it with the text); the file is there for numba's cache
    code = compile(source, str(path), "exec", dont_inherit=True)
    module = types.ModuleType(name)
    module.__file__ = str(path)
    sys.modules[name] = module
    try:
        exec(code, module.__dict__)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    _IMPORTED[digest] = module
    return module


def energy_model_kernels(model) -> CompiledKernels:
    """The compiled kernels of an :class:`~hfdi.models.EnergyModel` (see the module).

    Raises
    ------
    KernelSourceError
        When an expression has no compiled form; the model then runs on the
        Python path.
    OSError, RuntimeError, ...
        When the kernels cannot be written, compiled or cached otherwise: a
        fault, which the default ``compiled=None`` reports once before it
        runs the Python path.
    """
    module = _MODULE_OF.get(model)
    if module is None:
        source = kernel_source(model)
        from numba.core.errors import TypingError, UnsupportedError
        try:
            module = _import(source)
        except (TypingError, UnsupportedError) as exc:
            # no compiled form of a printed function (math.factorial of a float):
            # a model without kernels; anything else is a fault the caller reports.
            # The first line after numba's "Failed in ..." names the function.
            lines = [line for line in str(exc).splitlines()
                     if line.strip() and not line.startswith("Failed in")] or [""]
            raise KernelSourceError(f"numba could not compile the generated kernels: "
                                    f"{type(exc).__name__}: {lines[0]}") from None
        # printing the expressions costs tens of ms, more than a short run:
        # once per model (its expressions are fixed at construction)
        _MODULE_OF[model] = module
    params = model.compiled_params()
    kernels = CompiledKernels(module.force, module.stiffness, module.stiffness_derivative,
                              module.potential_energy, params)
    if model.load_expressions is not None:
        # the load's data are the model's parameters: the same array, so that
        # the compiled loop hands the current values to both
        kernels = kernels._replace(load=module.load, load_params=params,
                                   load_rate=module.load_rate)
    elif model._load is None:
        # no load: the zero load, compiled, so that whole runs are compiled
        from .loads import hat_load, hat_load_params
        kernels = kernels._replace(load=hat_load, load_params=hat_load_params(model.n_dof))
    return kernels
