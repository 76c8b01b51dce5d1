"""From sympy to numbers for :class:`~hfdi.models.symbolic.EnergyModel`: the
checks of its inputs, its expressions lambdified into functions, and the layout
of a symmetric matrix compiled from its upper-triangle entries."""
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
import sympy
from sympy.core.function import AppliedUndef

from .. import checks

__all__ = ["symbols", "items", "expression", "known_symbols", "real", "square_or_diagonal",
           "vector", "SymmetricLayout", "lambdified", "without_impulses", "right_rate"]


# -- input checks -------------------------------------------------------------

def symbols(value, what, length=None):
    """A tuple of distinct sympy Symbols from a Symbol or a sequence of them."""
    if isinstance(value, sympy.Symbol):
        value = (value,)
    elif isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        raise ValueError(f"{what} must be a sympy Symbol or a sequence of them, got {value!r}")
    items = tuple(sympy.Matrix(value)) if isinstance(value, sympy.MatrixBase) else tuple(value)
    bad = [s for s in items if not isinstance(s, sympy.Symbol)]
    if bad:
        raise ValueError(f"{what} must be sympy Symbols (e.g. sympy.symbols('x y')), "
                         f"got {bad[0]!r} of type {type(bad[0]).__name__}")
    if not items:
        raise ValueError(f"{what} must not be empty")
    if length is not None and len(items) != length:
        raise ValueError(f"{what} must have one symbol per degree of freedom ({length}), "
                         f"got {len(items)}")
    seen = set()
    for s in items:
        if s in seen:
            raise ValueError(f"{what} contains the symbol {s} more than once")
        seen.add(s)
    return items


def items(value) -> list:
    """The entries of a sympy Matrix or a sequence (flattened), or ``[value]``."""
    if isinstance(value, sympy.MatrixBase):
        return list(value)
    if isinstance(value, (list, tuple, np.ndarray)):
        return list(np.ravel(np.asarray(value, dtype=object)))
    return [value]


def expression(value, what):
    """``value`` as a scalar sympy expression (numbers allowed, strings not)."""
    if isinstance(value, (str, bytes)):
        # parsing strings would create symbols by name behind the user's back
        raise ValueError(f"{what} must be a sympy expression, not a string: {value!r}")
    try:
        expr = sympy.sympify(value, strict=True)
    except (sympy.SympifyError, TypeError):
        raise ValueError(f"{what} must be a sympy expression, got {value!r}") from None
    if not isinstance(expr, sympy.Expr) or isinstance(expr, sympy.MatrixBase):
        raise ValueError(f"{what} must be a scalar sympy expression, got "
                         f"{type(expr).__name__}: {expr!r}")
    undefined = expr.atoms(AppliedUndef)
    if undefined:
        raise ValueError(f"{what} contains undefined functions {sorted(map(str, undefined))}; "
                         "write them out as expressions of the symbols")
    # Only the free symbols are renamed before the expressions are printed as
    # code (by lambdify, and for the compiled kernels): the name of a bound
    # variable (of Sum, Product, Integral, Lambda, Subs), or of a sympy.codegen
    # node, would be written into that code verbatim, so a name could be code.
    for node in sympy.preorder_traversal(expr):
        bound = getattr(node, "bound_symbols", None)
        if bound:
            raise ValueError(
                f"{what} contains {type(node).__name__} over the bound variable(s) "
                f"{sorted(map(str, bound))}: expressions with bound variables (Sum, Product, "
                f"Integral, Lambda, Subs) are not taken; write them out (e.g. with .doit())")
        if type(node).__module__.startswith("sympy.codegen"):
            raise ValueError(f"{what} contains the code-generation node "
                             f"{type(node).__name__}: write it as a sympy expression")
        # a number that is not real (I, sqrt(-2), log(-2)): the compiled
        # functions would return complex values, whose imaginary part a
        # model's real arrays drop
        if node.is_number and node.is_extended_real is False:
            raise ValueError(f"{what} must be real, got the complex number {node} in "
                             f"{str(expr):.200}")
    hidden = expr.atoms(sympy.Symbol) - expr.free_symbols
    if hidden:
        raise ValueError(f"{what} contains the symbols {sorted(map(str, hidden))} other than "
                         "as free symbols: write the expression out in its symbols")
    return expr


def known_symbols(exprs, allowed, what, hint):
    """Refuse ``exprs`` (of ``what``) with free symbols outside ``allowed``; ``hint``
    says which symbols they may use."""
    unknown = set().union(*(e.free_symbols for e in exprs)) - allowed
    if unknown:
        raise ValueError(f"{what} depends on unknown symbols "
                         f"{', '.join(sorted(map(str, unknown)))}: {hint}")


def real(value, what):
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a real number, got {value!r}") from None
    if not math.isfinite(out):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return out


def square_or_diagonal(value, n, what, positive_diagonal=False):
    """A mass or damping matrix: 1-D diagonal (n,), dense (n, n) or sparse (n, n),
    checked by :func:`hfdi.checks.square_matrix`; a copy, in CSR form when sparse."""
    out = checks.square_matrix(what, value, n, to_match=f" to match the {n} degrees of freedom")
    if sp.issparse(out):
        return sp.csr_matrix(out, dtype=float, copy=True)
    if positive_diagonal and out.ndim == 1 and not np.all(out > 0):
        raise ValueError(f"{what} given as a diagonal must be positive, got {out}")
    return np.array(out)


def vector(value, n, what):
    """An initial condition: zero when ``None``, else a finite (n,) array."""
    return np.zeros(n) if value is None else checks.finite_array(what, value, (n,))


# -- layout of a symmetric matrix from its upper-triangle entries ------------

class SymmetricLayout:
    """Where the compiled upper-triangle values go in the full ``n × n`` matrix.

    The compiled function returns one value per structurally non-zero entry
    ``(i, j)`` with ``i <= j``; :meth:`dense` and :meth:`csr` mirror them with
    one fancy-indexing operation, so no Python loop runs per entry.
    """

    def __init__(self, n, rows, cols):
        rows = np.asarray(rows, dtype=np.intp)
        cols = np.asarray(cols, dtype=np.intp)
        off = rows != cols
        full_rows = np.concatenate([rows, cols[off]])
        full_cols = np.concatenate([cols, rows[off]])
        source = np.concatenate([np.arange(rows.size), np.flatnonzero(off)])
        order = np.lexsort((full_cols, full_rows))  # CSR order: by row, then column
        self.n = n
        self.rows = full_rows[order]
        self.cols = full_cols[order]
        self.source = source[order]
        self.flat = self.rows * n + self.cols
        index_dtype = np.int32 if n * n < np.iinfo(np.int32).max else np.int64
        self.indices = self.cols.astype(index_dtype)
        self.indptr = np.concatenate(
            [[0], np.cumsum(np.bincount(self.rows, minlength=n))]).astype(index_dtype)

    @property
    def nnz(self):
        return int(self.rows.size)

    def dense(self, values):
        out = np.zeros(self.n * self.n)
        out[self.flat] = values[self.source]
        return out.reshape(self.n, self.n)

    def csr(self, values):
        # fresh index arrays: a caller that edits the structure in place must not
        # change the pattern of later evaluations
        return sp.csr_matrix((values[self.source], self.indices.copy(), self.indptr.copy()),
                             shape=(self.n, self.n))


def lambdified(args, exprs, what, cse=True):
    """The numpy function of ``exprs`` (lambdify, common subexpressions by
    ``cse``: sympy's, or a function of lambdify's ``cse=``), or a ValueError
    naming ``what`` when an expression has a function numpy lacks."""
    from sympy.printing.codeprinter import PrintMethodNotImplementedError
    try:
        return sympy.lambdify(args, exprs, modules="numpy", cse=cse)
    except PrintMethodNotImplementedError as exc:
        raise ValueError(f"the model's {what} has no numerical form: "
                         f"{str(exc).splitlines()[0]}") from None


# -- the model ------------------------------------------------------------------

def without_impulses(expr):
    """``expr`` with every ``DiracDelta`` as 0.

    Derivatives of ``Max``, ``Min``, ``Abs``, ``sign`` and ``Heaviside`` bring
    ``DiracDelta`` (the second derivative of a contact ``Max(0, x)``, say),
    which has no numerical value: neither numpy nor Python has it. Away from
    the kink it is 0, as a ``Piecewise`` written out would give; at the kink
    itself ``Heaviside(0)`` is sympy's 1/2 on both paths.
    """
    if not expr.has(sympy.DiracDelta):
        return expr
    return expr.replace(sympy.DiracDelta, lambda *args: sympy.Integer(0))


def right_rate(rate):
    """A derived load rate as HFDI reads it: at a kink of the load the right
    limit (a step leaves its start forwards), so ``Heaviside(0) = 1`` (sympy
    and numpy take 1/2); and without the impulses of a jump (``DiracDelta``,
    which has no numerical value: a jump of the load is a breakpoint, not a
    rate)."""
    rate = without_impulses(rate)
    return rate.replace(sympy.Heaviside, lambda arg, *rest: sympy.Heaviside(arg, 1))
