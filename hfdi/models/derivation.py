"""The derivatives an :class:`~hfdi.models.EnergyModel` needs: ``f = ∂V/∂u``, the
upper triangle of ``K = ∂²V/∂u²`` and of ``T(u)[w] = Σ_k ∂K/∂u_k w_k``, with
the structurally non-zero entries' places, and common-subexpression
elimination for printing them as code.

Decision: symengine where the energy is elementary, sympy otherwise. An
energy built from sums, products, powers, numbers, ``π``, ``e`` and the
elementary functions of :data:`ELEMENTARY` is differentiated and reduced by
symengine (C++): for a 14-DOF chain of nonlinear springs 12 ms where sympy
took seconds. Any other function (``Abs``, ``Max``, ``Heaviside``,
``Piecewise``, ``floor``, ...) takes sympy, whose derivatives of them depend
on the symbols' assumptions (``Abs`` of a real symbol) and bring
``DiracDelta`` (:func:`~hfdi.models.sympy_input.without_impulses`), which
symengine does not model alike. Both give the same mathematics; the
printed code's operations may differ in order, not in value beyond
rounding.
"""
from __future__ import annotations

import functools

import sympy

from . import sympy_input as _in

__all__ = ["ELEMENTARY", "Derivation", "derive", "elementary", "cse", "reduced_lines",
           "unpacked", "python_functions", "UnprintableError"]

#: The functions symengine differentiates for an energy (one argument each).
ELEMENTARY = frozenset({sympy.sin, sympy.cos, sympy.tan, sympy.exp, sympy.log, sympy.asin,
                        sympy.acos, sympy.atan, sympy.sinh, sympy.cosh, sympy.tanh,
                        sympy.asinh, sympy.acosh, sympy.atanh})


@functools.lru_cache(maxsize=1)
def _symengine():
    """symengine, or None where it is not installed (sympy then does all)."""
    try:
        import symengine
    except ImportError:       # pragma: no cover - a dependency; kept optional at run time
        return None
    return symengine


def elementary(expr) -> bool:
    """Whether ``expr`` is built only from what symengine takes exactly:
    ``Add``, ``Mul``, ``Pow``, symbols, integers, rationals, floats of
    double precision (53 bits), ``π``, ``e`` and the functions of
    :data:`ELEMENTARY`."""
    for node in sympy.preorder_traversal(expr):
        if isinstance(node, (sympy.Add, sympy.Mul, sympy.Pow, sympy.Symbol, sympy.Integer,
                             sympy.Rational)) or node in (sympy.pi, sympy.E):
            continue
        if isinstance(node, sympy.Float):
            # a double exactly: another precision's value is its decimal
            # digits on sympy's route (Float("0.1", 3) is 0.1 there)
            if node._prec == 53:
                continue
            return False
        if isinstance(node, sympy.Function) and node.func in ELEMENTARY and len(node.args) == 1:
            continue
        return False
    return True


class Derivation:
    """``V``, ``f``, the upper triangles of ``K`` and ``T[w]`` of one energy, in the
    internal symbols (``u`` → ``_u<i>``, ``w`` → ``_w<i>``, the parameters
    ``_p<i>``), as expressions of the engine that derived them (``engine``:
    ``"symengine"`` or ``"sympy"``), and the places ``(k_rows, k_cols)``,
    ``(t_rows, t_cols)`` of their entries. :meth:`sympy` gives all four as
    sympy expressions (converted once)."""

    def __init__(self, engine, v, f, k_rows, k_cols, k, t_rows, t_cols, t):
        self.engine = engine
        self.v = v
        self.f, self.k, self.t = list(f), list(k), list(t)
        self.k_rows, self.k_cols, self.t_rows, self.t_cols = k_rows, k_cols, t_rows, t_cols
        self._sympy = None
        self._reduced = {}

    def reduced(self, group: str) -> tuple:
        """``group`` (``"v"``, ``"f"``, ``"k"`` or ``"t"``; symengine derivations
        only) after symengine's common-subexpression elimination, as Python
        text: ``(temporaries, results)``, the temporaries ``(name, text)``
        pairs named ``_c<k>``, the results the group's expressions in order
        (:func:`reduced_lines` makes the code of them). Made once and kept
        with copies and pickles, so that a copy computes in the same order,
        bit for bit (symengine's elimination may order terms otherwise for
        the same expressions)."""
        made = self._reduced.get(group)
        if made is None:
            exprs = [self.v] if group == "v" else getattr(self, group)
            temporaries, reduced = _symengine().cse(exprs) if exprs else ([], [])
            names = {str(a): f"_c{i}" for i, (a, _) in enumerate(temporaries)}
            made = self._reduced[group] = (
                [(names[str(a)], _text(b, names)) for a, b in temporaries],
                [_text(e, names) for e in reduced])
        return made

    def sympy(self) -> tuple:
        """``(V, f, K, T)``, ``V`` a sympy expression, the others lists of them."""
        if self._sympy is None:
            if self.engine == "sympy":
                self._sympy = (self.v, self.f, self.k, self.t)
            else:
                self._sympy = (sympy.sympify(self.v), *([sympy.sympify(e) for e in group]
                                                         for group in (self.f, self.k, self.t)))
        return self._sympy

    def __getstate__(self):
        # symengine's objects are kept as sympy's in copies and pickles (made
        # symengine's again on loading), the reduced text as it is
        v, f, k, t = self.sympy()
        reduced = self._reduced
        if self.engine == "symengine":
            try:
                reduced = {group: self.reduced(group) for group in ("v", "f", "k", "t")}
            except UnprintableError:
                pass
        return dict(self.__dict__, v=v, f=f, k=k, t=t, _sympy=None, _reduced=dict(reduced))

    def __setstate__(self, state):
        self.__dict__.update(state)
        se = _symengine()
        if self.engine == "symengine":
            if se is None:        # pragma: no cover - loaded where symengine is missing
                self.engine = "sympy"
            else:
                self.v = se.sympify(self.v)
                self.f, self.k, self.t = ([se.sympify(e) for e in group]
                                          for group in (self.f, self.k, self.t))


def derive(energy, dofs, rename, w_internal) -> tuple[Derivation, tuple]:
    """The :class:`Derivation` of ``energy`` in the user's ``dofs`` and the
    gradient in the user's symbols (``None`` when symengine derived it: the
    model's ``gradient`` converts it on demand). ``rename`` maps every user
    symbol to its internal one, ``w_internal`` the internal ``w``."""
    energy = _in.without_impulses(energy)
    se = _symengine()
    if se is not None and elementary(energy):
        return _derive_symengine(se, energy.xreplace(rename), [rename[s] for s in dofs],
                                 w_internal), None
    return _derive_sympy(energy, dofs, rename, w_internal)


def _derive_symengine(se, energy, u, w_internal):
    V = se.sympify(energy)
    u = [se.Symbol(s.name) for s in u]
    w = [se.Symbol(s.name) for s in w_internal]
    n = len(u)
    f = [se.diff(V, s) for s in u]
    k_rows, k_cols, k = [], [], []
    for i in range(n):
        present = f[i].free_symbols
        for j in range(i, n):
            if u[j] not in present:
                continue
            e = se.diff(f[i], u[j])
            if e != 0:
                k_rows.append(i)
                k_cols.append(j)
                k.append(e)
    t_rows, t_cols, t = [], [], []
    for i, j, e in zip(k_rows, k_cols, k):
        present = e.free_symbols
        terms = [se.diff(e, s) * w[m] for m, s in enumerate(u) if s in present]
        te = se.Add(*terms) if terms else se.Integer(0)
        if te != 0:
            t_rows.append(i)
            t_cols.append(j)
            t.append(te)
    return Derivation("symengine", V, f, k_rows, k_cols, k, t_rows, t_cols, t)


def _derive_sympy(energy, dofs, rename, w_internal):
    """sympy's derivation in the user's symbols (their assumptions decide the
    derivatives of ``Abs`` and the like), renamed after."""
    n = len(dofs)
    dof_set = set(dofs)
    # Differentiate term by term, each term only by the DOFs it contains:
    # for an energy that is a sum of local terms (springs, bonds) this keeps
    # the work proportional to the number of terms instead of N times it.
    terms = sympy.Add.make_args(energy)
    by_dof = {s: [] for s in dofs}
    for term in terms:
        for s in term.free_symbols & dof_set:
            by_dof[s].append(term)
    gradient = tuple(_in.without_impulses(sympy.Add(*[term.diff(s) for term in by_dof[s]]))
                     for s in dofs)
    depends = [g.free_symbols & dof_set for g in gradient]
    k_rows, k_cols, k_exprs = [], [], []
    for i in range(n):
        for j in range(i, n):
            # ∂g_i/∂u_j is structurally zero unless g_i contains u_j
            if dofs[j] not in depends[i]:
                continue
            e = _in.without_impulses(gradient[i].diff(dofs[j]))
            if e == 0:
                continue
            k_rows.append(i)
            k_cols.append(j)
            k_exprs.append(e)
    # a Dummy cannot collide with any symbol of the user
    w = tuple(sympy.Dummy(f"w{i}") for i in range(n))
    t_rows, t_cols, t_exprs = [], [], []
    for i, j, e in zip(k_rows, k_cols, k_exprs):
        present = e.free_symbols
        te = _in.without_impulses(sympy.Add(*[e.diff(s) * w[m] for m, s in enumerate(dofs)
                                              if s in present]))
        if te == 0:
            continue
        t_rows.append(i)
        t_cols.append(j)
        t_exprs.append(te)
    leftover = [e for e in (*gradient, *k_exprs, *t_exprs) if e.has(sympy.Derivative)]
    if leftover:
        raise ValueError("sympy could not differentiate the energy in closed form: "
                         f"{leftover[0]}; with Abs, sign, Max and the like, declare the "
                         "DOF symbols real, e.g. sympy.symbols('x y', real=True)")
    w_rename = dict(zip(w, w_internal))
    w_rename.update(rename)
    derivation = Derivation("sympy", energy.xreplace(rename),
                            [g.xreplace(rename) for g in gradient],
                            k_rows, k_cols, [e.xreplace(rename) for e in k_exprs],
                            t_rows, t_cols, [e.xreplace(w_rename) for e in t_exprs])
    return derivation, gradient


def cse(exprs, symbol_prefix="_c"):
    """Common-subexpression elimination of ``exprs`` (sympy or symengine):
    ``(temporaries, reduced)`` as sympy expressions, temporaries named
    ``<symbol_prefix><k>``; symengine's for its own expressions, sympy's
    otherwise."""
    exprs = list(exprs)
    se = _symengine()
    if se is not None and exprs and all(isinstance(e, se.Basic) for e in exprs):
        temporaries, reduced = se.cse(exprs)
        # symengine names its temporaries x0, x1, ...: renamed to ours, which
        # cannot clash with the internal symbols of the expressions
        rename = {sympy.Symbol(str(a)): sympy.Symbol(f"{symbol_prefix}{i}")
                  for i, (a, _) in enumerate(temporaries)}
        temporaries = [(rename[sympy.Symbol(str(a))], sympy.sympify(b).xreplace(rename))
                       for a, b in temporaries]
        reduced = [sympy.sympify(e).xreplace(rename) for e in reduced]
        return temporaries, reduced
    return sympy.cse(exprs, symbols=sympy.numbered_symbols(symbol_prefix))


# -- code from symengine's expressions ---------------------------------------------------

#: The names of :data:`ELEMENTARY` (math's and symengine's alike).
_FUNCTION_NAMES = frozenset(function.__name__ for function in ELEMENTARY)


class UnprintableError(ValueError):
    """An expression outside what :func:`_text` prints (sympy's printer then does)."""


#: The namespace of functions and constants in :func:`_text`'s output, replaced
#: by a module's (:func:`reduced_lines`).
_NS = "_ns_"
#: numpy's names of the inverse functions (math's are symengine's).
_NUMPY_NAMES = {f"{_NS}.{name}(": f"np.arc{name[1:]}(" for name in
                ("asin", "acos", "atan", "asinh", "acosh", "atanh")}


def _text(e, names):
    """Python text of the symengine expression ``e``, every compound part in
    parentheses, functions and constants of the namespace ``_ns_``,
    symbols renamed by ``names``. Integers beyond 2**53 are printed as the
    float numpy makes of them and every number is exact (``repr`` of a
    double)."""
    se = _symengine()
    if isinstance(e, se.Symbol):
        name = str(e)
        return names.get(name, name)
    if isinstance(e, se.Integer):
        return f"({_integer(int(e))})"
    if isinstance(e, se.Rational):
        p, q = (int(x) for x in e.get_num_den())
        return f"({_integer(p)}/{_integer(q)})"
    if isinstance(e, se.RealDouble):
        return f"({float(e)!r})"
    if e == se.pi:
        return f"{_NS}.pi"
    if e == se.E:
        return f"{_NS}.e"
    args = e.args
    if isinstance(e, se.Add):
        return "(" + " + ".join(_text(a, names) for a in args) + ")"
    if isinstance(e, se.Mul):
        return "(" + "*".join(_text(a, names) for a in args) + ")"
    if isinstance(e, se.Pow):
        base, exponent = args
        if base == se.E:
            return f"{_NS}.exp({_text(exponent, names)})"
        if exponent == se.Rational(1, 2):
            return f"{_NS}.sqrt({_text(base, names)})"
        if exponent == se.Rational(-1, 2):
            return f"(1/{_NS}.sqrt({_text(base, names)}))"
        return f"({_text(base, names)}**{_text(exponent, names)})"
    name = type(e).__name__
    if isinstance(e, se.Function) and name in _FUNCTION_NAMES and len(args) == 1:
        return f"{_NS}.{name}({_text(args[0], names)})"
    raise UnprintableError(f"no Python form of {e}")


def _integer(value):
    return repr(float(value)) if abs(value) > 2 ** 53 else str(value)


def reduced_lines(derivation, group, prefix, ns):
    """The lines of code of :meth:`Derivation.reduced`, the results named
    ``<prefix><i>``, functions and constants of the module ``ns``
    (``"math"`` for compiled code, ``"np"`` for the Python path: numpy's
    rules for a NaN or a division by zero)."""
    temporaries, results = derivation.reduced(group)
    targets = [name for name, _ in temporaries] + [f"{prefix}{i}" for i in range(len(results))]
    lines = []
    for target, text in zip(targets, [text for _, text in temporaries] + results):
        if ns == "np":
            for name, numpy_name in _NUMPY_NAMES.items():
                text = text.replace(name, numpy_name)
        lines.append(f"    {target} = {text.replace(_NS + '.', ns + '.')}")
    return lines


def unpacked(name, symbols):
    """Lines binding each of ``symbols`` to ``name[i]``."""
    return [f"    {s} = {name}[{i}]" for i, s in enumerate(symbols)]


def python_functions(derivation, u, w, p) -> dict:
    """The Python path's ``V``, ``f``, ``K`` and ``T`` of a symengine
    :class:`Derivation` (``"v"``, ``"f"``, ``"k"``, ``"t"``; ``K`` and ``T``
    as their upper-triangle values), made from the same reduced expressions
    as the compiled kernels and computing the same operations with numpy's
    functions: ``V`` takes ``u`` of shape ``(N,)`` or ``(N, n)``."""
    lines = ["import numpy as np", ""]
    for group, prefix, head in (("v", "_v", "def v(u, params):"),
                                ("f", "_f", "def f(u, params):"),
                                ("k", "_k", "def k(u, params):"),
                                ("t", "_t", "def t(u, w, params):")):
        lines.append(head)
        lines += unpacked("u", u)
        if group == "t":
            lines += unpacked("w", w)
        lines += unpacked("params", p)
        lines += reduced_lines(derivation, group, prefix, "np")
        count = 1 if group == "v" else len(getattr(derivation, group))
        values = [f"{prefix}{i}" for i in range(count)]
        lines.append(f"    return {values[0]}" if group == "v" else
                     f"    return [{', '.join(values)}]")
        lines.append("")
    namespace = {}
    exec(compile("\n".join(lines), "<hfdi EnergyModel functions>", "exec"), namespace)
    return {key: namespace[key] for key in ("v", "f", "k", "t")}
