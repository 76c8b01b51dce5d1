"""Models defined by a potential energy written in sympy.

:class:`EnergyModel` derives ``f = ∂V/∂u``, ``K`` (the Hessian) and ``T(u)[w]``
once, at construction (:mod:`hfdi.models.derivation`: symengine for an
elementary energy, sympy otherwise); its Python functions are made on first
use; the parameters stay symbols, set at every evaluation. Two ready-made models:
:func:`elastic_pendulum` and :func:`spring_chain` (docs/user-models.md,
"A model from its potential energy").
"""
from __future__ import annotations

import copy
from typing import Callable, Mapping, Sequence

import numpy as np
import sympy

from .. import checks
from ..system import SecondOrderSystem
from . import sympy_input as _in
from .derivation import UnprintableError, derive, python_functions

__all__ = ["EnergyModel", "elastic_pendulum", "spring_chain"]


class EnergyModel(SecondOrderSystem):
    """A model ``M u'' + C u' + ∂V/∂u = p(t)`` from a sympy potential energy ``V``.

    The gradient ``f``, the Hessian ``K`` and the third-derivative contraction
    ``T(u)[w]_ij = Σ_k ∂³V/∂u_i ∂u_j ∂u_k w_k`` are derived once, at
    construction, by symengine where the energy is elementary (sums,
    products, powers and the functions of
    :data:`hfdi.models.derivation.ELEMENTARY`) and by sympy otherwise. The
    Python path's functions (numpy) and the compiled kernels are printed
    from the same common-subexpression elimination, on first use. They are
    exact, so the HFDI corrector gets the tangent it needs (paper, Eq. 21).

    Parameters
    ----------
    dofs : sympy.Symbol or sequence of sympy.Symbol
        The ``N`` degrees of freedom ``u``, in the order of the state vector.
    energy : sympy expression
        Potential energy ``V``; may use the ``dofs`` and the symbols of
        ``parameters`` and nothing else (no bound variables, as of a ``Sum``).
        ``Max``, ``Min``, ``Abs`` and the like of real DOF symbols are taken:
        the ``DiracDelta`` of their derivatives counts as 0 (and at a kink
        ``Heaviside(0) = 1/2``, on the compiled path as on the Python path).
    mass : array_like (N,) or (N, N) or scipy sparse (N, N)
        Mass matrix; a 1-D array is a (positive) diagonal.
    parameters : dict of sympy.Symbol to float, optional
        Values of the parameter symbols in ``energy`` and ``quantities``. They
        remain symbols in the compiled functions and are substituted at every
        evaluation: :meth:`set_parameters` changes them without re-deriving.
    load : callable ``p(t) -> (N,)``, or sequence of N sympy expressions, optional
        External load; zero when omitted. Given as expressions of ``time`` and
        the parameters, its exact rate is derived and both run compiled
        (docs/user-models.md).
    load_rate : callable ``p'(t) -> (N,)``, optional
        Exact load rate for HFDI (otherwise HFDI takes the paper's difference
        quotient, and on a smooth load it is then second order: many more
        steps under error control); not with a load given as expressions,
        whose rate is derived.
    damping : array_like (N,) or (N, N) or scipy sparse (N, N), optional
    quantities : dict of str to expression or sequence of expressions, optional
        Quantities of interest in the ``dofs``, the ``velocities``, ``time``
        and the parameters. :meth:`quantities` evaluates them for many times at
        once and returns an ``(n, m)`` array per name (``m = 1`` for a single
        expression). ``"u"`` (the displacement) is included unless given here.
    velocities : sequence of sympy.Symbol, optional
        Symbols standing for ``u'`` in ``quantities``, one per DOF.
    time : sympy.Symbol, optional
        Symbol standing for ``t`` in ``quantities``.
    initial_displacement, initial_velocity : array_like (N,), optional
        Default initial conditions; zero when omitted.
    name : str, optional
    u_scale : float, optional
        A length of the model: the floor of the Newton convergence test and
        the scale of the perturbations of :func:`hfdi.check_derivatives`; 1
        when omitted, and the default ``atol`` then takes its scale from the
        load for a model starting at rest.
    observation_time : float, optional
        A natural duration of the model's experiment.
    sparse : bool, optional
        Return ``K`` and ``T`` as scipy CSR matrices with a fixed pattern (the
        structurally non-zero entries of the symbolic expressions) instead of
        dense arrays. Worth it for large, sparsely coupled models.

    Attributes
    ----------
    dofs : tuple of sympy.Symbol
    energy : sympy.Expr
    gradient : tuple of sympy.Expr
        ``∂V/∂u_i`` in the user's symbols.
    hessian : sympy.ImmutableSparseMatrix
        ``∂²V/∂u_i ∂u_j`` in the user's symbols.
    stiffness_pattern : tuple of ndarray
        ``(rows, cols)`` of the structurally non-zero entries of ``K``.
    stiffness_derivative_pattern : tuple of ndarray
        The same for ``T``.

    Raises
    ------
    ValueError
        If a symbol is repeated or is not a Symbol, if the energy or a quantity
        uses a symbol that is neither a DOF nor declared, or a bound variable
        or an undefined function, if the mass or
        damping does not match the number of DOFs, if a parameter value is not
        a finite real number, ...

    See Also
    --------
    hfdi.System : a model from plain callables.
    hfdi.check_derivatives : check f, K and T against finite differences.
    elastic_pendulum, spring_chain : models built with this class.

    Examples
    --------
    A Duffing oscillator ``V = ½ k x² + ¼ k3 x⁴`` with ``k3`` a parameter:

    >>> import sympy
    >>> import hfdi
    >>> from hfdi.models.symbolic import EnergyModel
    >>> x, k3 = sympy.symbols("x k3")
    >>> model = EnergyModel([x], x**2 / 2 + k3 * x**4 / 4, mass=[1.0],
    ...                     parameters={k3: 2.0}, initial_displacement=[1.0])
    >>> model.gradient
    (k3*x**3 + x,)
    >>> model.internal_force([1.0]), model.stiffness([1.0])
    (array([3.]), array([[7.]]))
    >>> model.stiffness_derivative([1.0], [1.0])
    array([[12.]])
    >>> model.set_parameters({k3: 0.0})
    >>> model.internal_force([1.0])
    array([1.])
    >>> hfdi.check_derivatives(model).ok(1e-8)
    True
    """

    def __init__(self, dofs, energy, mass, *, parameters: Mapping | None = None,
                 load: Callable | None = None, load_rate: Callable | None = None,
                 damping=None, quantities: Mapping | None = None,
                 velocities: Sequence | None = None, time: sympy.Symbol | None = None,
                 initial_displacement=None, initial_velocity=None,
                 name: str = "energy_model", u_scale: float | None = None,
                 observation_time: float | None = None, sparse: bool = False):
        dofs = _in.symbols(dofs, "dofs")
        n = len(dofs)
        energy = _in.expression(energy, "energy")

        parameters = {} if parameters is None else parameters
        if not isinstance(parameters, Mapping):
            raise ValueError("parameters must be a dict mapping sympy Symbols to numbers, "
                             f"got {type(parameters).__name__}")
        param_symbols = _in.symbols(tuple(parameters), "parameters") if parameters else ()
        param_values = tuple(_in.real(parameters[s], f"parameter {s}") for s in param_symbols)

        velocity_symbols = (() if velocities is None
                            else _in.symbols(velocities, "velocities", length=n))
        if time is not None and not isinstance(time, sympy.Symbol):
            raise ValueError(f"time must be a sympy Symbol, got {time!r}")
        time_symbols = () if time is None else (time,)

        # every symbol has one role and one name, so that the error messages,
        # parameters() and set_parameters() by name are unambiguous
        roles = ([(s, "dof") for s in dofs] + [(s, "parameter") for s in param_symbols]
                 + [(s, "velocity") for s in velocity_symbols]
                 + [(s, "time") for s in time_symbols])
        by_name = {}
        for s, role in roles:
            if s.name in by_name:
                other, other_role = by_name[s.name]
                what = "twice" if other == s else "for two different symbols"
                raise ValueError(f"the name {s.name!r} is used {what} "
                                 f"(as {other_role} and as {role})")
            by_name[s.name] = (s, role)

        _in.known_symbols([energy], set(dofs) | set(param_symbols), "energy",
                          "declare them as dofs or give their values in parameters")

        load_exprs = None
        if load is not None and not callable(load):
            load_exprs = self._parse_load(load, n, set(param_symbols) | set(time_symbols))
            if load_rate is not None:
                raise ValueError("load_rate must not be given with a load of sympy "
                                 "expressions: its exact rate is derived from them")
        checks.callable_or_none("load_rate", load_rate, "t -> (N,)")

        self.n_dof = n
        self.mass = _in.square_or_diagonal(mass, n, "mass", positive_diagonal=True)
        self.damping = (None if damping is None else
                        _in.square_or_diagonal(damping, n, "damping"))
        self.initial_displacement = _in.vector(initial_displacement, n, "initial_displacement")
        self.initial_velocity = _in.vector(initial_velocity, n, "initial_velocity")
        if u_scale is not None:
            self.u_scale = checks.positive("u_scale", u_scale)
        self.observation_time = (None if observation_time is None
                                 else checks.positive("observation_time", observation_time))
        if not isinstance(name, str):
            raise ValueError(f"name must be a string, got {name!r}")
        self.name = name
        self.sparse = bool(sparse)
        self._load = None if load_exprs is not None else load
        self._load_rate = load_rate

        self.dofs = dofs
        self.energy = energy
        self.parameter_symbols = param_symbols
        self._param_values = param_values
        self.parameter_version = 0           # counts set_parameters (Integrator.model_changed)
        self.velocity_symbols = velocity_symbols
        self.time_symbol = time
        self._quantity_names, self._quantity_sizes, quantity_exprs = self._parse_quantities(
            quantities, set(dofs) | set(param_symbols) | set(velocity_symbols) | set(time_symbols))

        # The derivatives and the compiled code use internal symbols: the
        # user's names may be Python keywords, invalid identifiers, or clash
        # with the names that common-subexpression elimination generates.
        self._u = sympy.symbols(f"_u0:{n}")
        self._w = sympy.symbols(f"_w0:{n}")
        self._v = sympy.symbols(f"_v0:{n}")
        self._p = sympy.symbols(f"_p0:{len(param_symbols)}")
        self._t = sympy.Symbol("_t")
        rename = dict(zip(dofs, self._u))
        rename.update(zip(param_symbols, self._p))
        rename.update(zip(velocity_symbols, self._v))
        rename.update(zip(time_symbols, (self._t,)))
        self._user_symbol = {internal: user for user, internal in rename.items()}
        self._derivation, self._gradient = derive(energy, dofs, rename, self._w)
        self._k_layout = _in.SymmetricLayout(n, self._derivation.k_rows, self._derivation.k_cols)
        self._t_layout = _in.SymmetricLayout(n, self._derivation.t_rows, self._derivation.t_cols)
        rates = [] if load_exprs is None else [
            _in.right_rate(e.diff(time)) if time is not None else sympy.Integer(0)
            for e in load_exprs]
        leftover = [e for e in rates if e.has(sympy.Derivative)]
        if leftover:
            # as for the energy's derivatives (derivation.derive)
            raise ValueError(
                f"the model's load rate could not be derived in closed form (sympy left "
                f"{next(iter(leftover[0].atoms(sympy.Derivative)))}); declare the symbols that "
                f"Abs, sign, re or im act on real (sympy.Symbol(name, real=True))")
        # the expressions that need no derivative (V, f, K, T: _exprs)
        self._plain_exprs = {
            "q": [_in.without_impulses(e).xreplace(rename) for e in quantity_exprs],
            "p": [] if load_exprs is None else [_in.without_impulses(e).xreplace(rename)
                                                 for e in load_exprs],
            "dp": [e.xreplace(rename) for e in rates],
        }
        # the quantities, the load and sympy's derivatives are lambdified now:
        # what has no numerical form is refused here
        self._plain_functions = self._make_plain_functions()
        self._derived_functions = (self._make_derived_functions()
                                   if self._derivation.engine == "sympy" else None)
        self.load_expressions = load_exprs

    # -- construction helpers ------------------------------------------------
    @staticmethod
    def _parse_load(load, n, allowed):
        """A load given as N sympy expressions of time and the parameters."""
        items = _in.items(load)
        if len(items) != n:
            raise ValueError(f"load must be a callable t -> (N,) or {n} sympy expressions "
                             f"(one per degree of freedom), got {len(items)} item(s)")
        items = [_in.expression(e, "load") for e in items]
        _in.known_symbols(items, allowed, "load", "a load of sympy expressions may use time "
                          "(give it as time=) and the parameters")
        return tuple(items)

    @staticmethod
    def _parse_quantities(quantities, allowed):
        names, sizes, exprs = [], [], []
        if quantities is None:
            quantities = {}
        if not isinstance(quantities, Mapping):
            raise ValueError("quantities must be a dict mapping names to sympy expressions, "
                             f"got {type(quantities).__name__}")
        for qname, value in quantities.items():
            if not isinstance(qname, str) or not qname:
                raise ValueError(f"quantity names must be non-empty strings, got {qname!r}")
            items = _in.items(value)
            if not items:
                raise ValueError(f"quantity {qname!r} has no expressions")
            items = [_in.expression(e, f"quantity {qname!r}") for e in items]
            _in.known_symbols(items, allowed, f"quantity {qname!r}", "quantities may use the "
                              "dofs, the velocities, time and the parameters")
            names.append(qname)
            sizes.append(len(items))
            exprs.extend(items)
        return tuple(names), tuple(sizes), exprs

    @property
    def _exprs(self) -> dict:
        """Every expression of the model in the internal symbols, sympy's."""
        v, f, k, t = self._derivation.sympy()
        return dict(self._plain_exprs, V=v, f=f, K=k, T=t)

    @property
    def gradient(self) -> tuple:
        """``∂V/∂u_i`` in the user's symbols."""
        if self._gradient is None:
            _, f, _, _ = self._derivation.sympy()
            self._gradient = tuple(e.xreplace(self._user_symbol) for e in f)
        return self._gradient

    @property
    def hessian(self):
        """``∂²V/∂u_i ∂u_j`` in the user's symbols (sympy.ImmutableSparseMatrix)."""
        entries = {}
        d = self._derivation
        _, _, k, _ = d.sympy()
        for i, j, e in zip(d.k_rows, d.k_cols, k):
            entries[(i, j)] = entries[(j, i)] = e.xreplace(self._user_symbol)
        return sympy.ImmutableSparseMatrix(self.n_dof, self.n_dof, entries)

    def _fn(self, name):
        """The Python path's function ``name``: ``"v"``, ``"f"``, ``"k"``, ``"t"``
        (:meth:`_make_derived_functions`, made on first use where symengine
        derived them: building the model does not print them) or ``"q"``,
        ``"p"``, ``"dp"`` (:meth:`_make_plain_functions`)."""
        if name in ("q", "p", "dp"):
            if self._plain_functions is None:            # not kept by a pickle
                self._plain_functions = self._make_plain_functions()
            return self._plain_functions[name]
        if self._derived_functions is None:
            self._derived_functions = self._make_derived_functions()
        return self._derived_functions[name]

    def _make_plain_functions(self) -> dict:
        """The quantities', the load's and its rate's functions (lambdify; a
        ValueError naming what has no numerical form)."""
        u, v, p, t = list(self._u), list(self._v), list(self._p), self._t
        ex = self._plain_exprs
        return {"q": _in.lambdified([t, u, v, p], ex["q"], "quantities") if ex["q"] else None,
                "p": _in.lambdified([t, p], ex["p"], "load") if ex["p"] else None,
                "dp": _in.lambdified([t, p], ex["dp"], "load rate") if ex["p"] else None}

    def _make_derived_functions(self) -> dict:
        """``V``, ``f``, ``K`` and ``T``'s functions: from symengine's reduced
        expressions where it derived them, else lambdified."""
        u, w, p = list(self._u), list(self._w), list(self._p)
        if self._derivation.engine == "symengine":
            try:
                return python_functions(self._derivation, u, w, p)
            except UnprintableError:
                pass
        ex = self._exprs
        return {"v": _in.lambdified([u, p], ex["V"], "energy"),
                "f": _in.lambdified([u, p], ex["f"], "internal force (the energy's gradient)"),
                "k": _in.lambdified([u, p], ex["K"], "stiffness"),
                "t": _in.lambdified([u, w, p], ex["T"], "stiffness derivative")}

    # Generated functions do not pickle; the expressions do, so a copy in
    # another process makes them again on first use (no new derivation).
    def __getstate__(self):
        state = self.__dict__.copy()
        state["_plain_functions"] = state["_derived_functions"] = None
        return state

    # Copies in the same process share the generated functions and the
    # derivation (they hold no state), instead of making them again.
    _SHARED = ("_plain_functions", "_derived_functions", "_derivation")

    def __copy__(self):
        other = object.__new__(type(self))
        other.__dict__.update(self.__dict__)
        return other

    def __deepcopy__(self, memo):
        other = object.__new__(type(self))
        memo[id(self)] = other
        for key, value in self.__dict__.items():
            other.__dict__[key] = value if key in self._SHARED else copy.deepcopy(value, memo)
        return other

    @property
    def stiffness_pattern(self):
        """``(rows, cols)`` of the structurally non-zero entries of ``K``, CSR order."""
        return self._k_layout.rows.copy(), self._k_layout.cols.copy()

    @property
    def stiffness_derivative_pattern(self):
        """``(rows, cols)`` of the structurally non-zero entries of ``T``, CSR order."""
        return self._t_layout.rows.copy(), self._t_layout.cols.copy()

    # -- parameters --------------------------------------------------------------
    def parameters(self) -> dict:
        """The parameter values by symbol name."""
        return {s.name: v for s, v in zip(self.parameter_symbols, self._param_values)}

    def set_parameters(self, values: Mapping | None = None, **by_name) -> None:
        """Change parameter values in place; the compiled functions are kept.

        An :class:`~hfdi.Integrator` running this model follows the change from
        its current time on (it sees :attr:`parameter_version` change and calls
        its :meth:`~hfdi.Integrator.model_changed`).

        Parameters
        ----------
        values : dict of sympy.Symbol (or name) to float, optional
        **by_name : float
            Values by symbol name, e.g. ``set_parameters(k=2.0)``.
        """
        updates = dict(values or {})
        updates.update(by_name)
        current = list(self._param_values)
        index = {s: i for i, s in enumerate(self.parameter_symbols)}
        index.update({s.name: i for i, s in enumerate(self.parameter_symbols)})
        for key, value in updates.items():
            if key not in index:
                known = ", ".join(s.name for s in self.parameter_symbols) or "none"
                raise ValueError(f"{key!r} is not a parameter of this model (parameters: {known})")
            current[index[key]] = _in.real(value, f"parameter {key}")
        self._param_values = tuple(current)
        self.parameter_version += 1

    def with_parameters(self, values: Mapping | None = None, **by_name) -> "EnergyModel":
        """A copy with other parameter values, sharing the compiled functions."""
        other = copy.copy(self)
        other.set_parameters(values, **by_name)
        return other

    # -- compiled kernels ------------------------------------------------------------
    def compiled_params(self) -> np.ndarray:
        """The parameter values now, as the compiled kernels read them: the
        compiled path follows :meth:`set_parameters` as the Python path does."""
        return np.ascontiguousarray(self._param_values, dtype=np.float64).reshape(-1)

    def compiled_kernels(self):
        """Compiled (numba) kernels generated from the model's expressions, for
        ``compiled=True`` or ``None`` (:mod:`hfdi.compiled.symbolic`); they read
        the parameter values of :meth:`compiled_params` at every call.

        Raises
        ------
        hfdi.compiled.CompiledUnavailable
            When an expression has no compiled form (the Python path runs).
        OSError, RuntimeError, ...
            When the kernels cannot be written, compiled or cached otherwise:
            ``compiled=None`` then says so once and runs the Python path.
        """
        from ..compiled import CompiledUnavailable
        from ..compiled.symbolic import KernelSourceError, energy_model_kernels
        try:
            return energy_model_kernels(self)
        except KernelSourceError as exc:
            raise CompiledUnavailable(f"model {self.name!r}: {exc}") from None

    # -- mechanics -----------------------------------------------------------------
    def _state(self, u, what="u"):
        u = np.asarray(u, dtype=float)
        if u.shape != (self.n_dof,):
            raise ValueError(f"{what} must have shape ({self.n_dof},), got {u.shape}")
        return u

    def internal_force(self, u):
        """``f(u) = ∂V/∂u``, shape (N,)."""
        # a constant entry (0 for a DOF that V does not depend on) comes back as
        # a Python scalar; the rest as numpy scalars: asarray takes both
        return np.asarray(self._fn("f")(self._state(u), self._param_values), dtype=float)

    def stiffness(self, u):
        """``K(u) = ∂²V/∂u²``: ndarray (N, N), or CSR when ``sparse``."""
        values = np.asarray(self._fn("k")(self._state(u), self._param_values), dtype=float)
        return self._k_layout.csr(values) if self.sparse else self._k_layout.dense(values)

    def stiffness_derivative(self, u, w):
        """``T(u)[w] = d(K(u) w)/du``: ndarray (N, N), or CSR when ``sparse``."""
        values = np.asarray(self._fn("t")(self._state(u), self._state(w, "w"),
                                        self._param_values), dtype=float)
        return self._t_layout.csr(values) if self.sparse else self._t_layout.dense(values)

    def potential_energy(self, u):
        """``V(u)``: a float for ``u`` of shape (N,), an (n,) array for (n, N)."""
        u = np.asarray(u, dtype=float)
        if u.ndim == 2 and u.shape[1] == self.n_dof:
            value = self._fn("v")(u.T, self._param_values)
            return np.broadcast_to(np.asarray(value, dtype=float), u.shape[:1]).copy()
        return float(self._fn("v")(self._state(u), self._param_values))

    def load(self, t):
        """External load ``p(t)``, shape (N,)."""
        if self._plain_exprs["p"]:
            return self._vector_at(self._fn("p"), t)
        return np.zeros(self.n_dof) if self._load is None else np.asarray(self._load(t), float)

    @property
    def load_rate(self):
        """The exact load rate ``t -> p'(t)``: derived from a load of sympy
        expressions, or the callable given, or ``None``."""
        return self._derived_load_rate if self._plain_exprs["p"] else self._load_rate

    def _derived_load_rate(self, t):
        """``p'(t)``, derived from a load of sympy expressions."""
        return self._vector_at(self._fn("dp"), t)

    def _vector_at(self, fun, t):
        # constant entries come back as scalars: each entry as a float
        values = fun(float(t), self._param_values)
        return np.array([float(x) for x in values], dtype=float)

    def quantities(self, t, u, v=None):
        """Quantities of interest at many times in one vectorised call.

        Parameters
        ----------
        t : float or ndarray (n,)
        u : ndarray (N,) or (n, N)
        v : ndarray (N,) or (n, N), optional
            Needed only if a quantity uses the velocity symbols.

        Returns
        -------
        dict of str to ndarray (n, m)
        """
        u = np.atleast_2d(np.asarray(u, dtype=float))
        if u.ndim != 2 or u.shape[1] != self.n_dof:
            raise ValueError(f"u must have shape (n, {self.n_dof}), got {u.shape}")
        n = u.shape[0]
        t = np.asarray(t, dtype=float).ravel()
        if t.size not in (1, n):
            raise ValueError(f"t must be a scalar or have {n} entries, got {t.size}")
        t = np.broadcast_to(t, (n,))
        if v is None:
            if self.velocity_symbols and any(e.has(*self._v) for e in self._plain_exprs["q"]):
                raise ValueError("these quantities use the velocities: pass v")
            v = np.zeros_like(u)
        v = np.atleast_2d(np.asarray(v, dtype=float))
        if v.shape != u.shape:
            raise ValueError(f"v must have the shape of u {u.shape}, got {v.shape}")
        out = {"u": u}
        if not self._plain_exprs["q"]:
            return out
        values = self._fn("q")(t, u.T, v.T, self._param_values)
        # constant expressions come back as scalars: broadcast every column to (n,)
        columns = np.stack(np.broadcast_arrays(*[np.asarray(c, dtype=float) for c in values],
                                               np.empty(n))[:-1], axis=1)
        start = 0
        for qname, size in zip(self._quantity_names, self._quantity_sizes):
            out[qname] = columns[:, start:start + size]
            start += size
        return out

    def __repr__(self):
        params = ", ".join(f"{k}={v!r}" for k, v in self.parameters().items())
        dofs = ", ".join(s.name for s in self.dofs)
        sep = "; " if params else ""
        return f"EnergyModel({self.name!r}, dofs=({dofs}){sep}{params})"


# -- ready-made models ------------------------------------------------------------

def elastic_pendulum(k: float = 30.0, length: float = 1.0, mass: float = 1.0,
                     g: float = 9.81, *, u0=(0.35, -1.6), v0=(0.0, 0.0),
                     observation_time: float = 20.0) -> EnergyModel:
    """A mass on a linear spring in the plane, swinging under gravity.

    The spring is pinned at the origin; ``u = (x, y)`` is the position of the
    mass with ``y`` upwards, and

    ``V = ½ k (√(x² + y²) − L)² + m g y``.

    With the defaults the spring frequency ``√(k/m) ≈ 5.48`` rad/s is close to
    twice the pendulum frequency ``√(g/(L + m g/k)) ≈ 2.72`` rad/s, the 2:1
    resonance at which the bouncing and the swinging trade energy back and
    forth, so the motion is strongly nonlinear.

    Parameters
    ----------
    k : float
        Spring stiffness.
    length : float
        Unstretched length ``L`` of the spring.
    mass : float
        The mass ``m`` (in the mass matrix and the gravity term).
    g : float
        Gravity.
    u0, v0 : array_like (2,)
        Initial position and velocity. Default: released from rest, stretched
        and a little off the vertical.
    observation_time : float

    Returns
    -------
    EnergyModel
        With parameters ``k``, ``L`` and ``g`` (changeable with
        :meth:`EnergyModel.set_parameters`; ``m`` is fixed because it is also
        in the mass matrix), and the quantities ``length`` (``r``), ``angle``
        (from the downward vertical), ``energy`` (``V + ½ m |u'|²``).

    See docs/user-models.md, "A model from its potential energy", for its use.
    """
    m = checks.positive("elastic_pendulum mass", mass)
    for what, value in (("k", k), ("length", length), ("g", g)):
        checks.positive(f"elastic_pendulum {what}", value)
    x, y, vx, vy = sympy.symbols("x y v_x v_y")
    ks, L, gs = sympy.symbols("k L g")
    r = sympy.sqrt(x ** 2 + y ** 2)
    energy = ks / 2 * (r - L) ** 2 + m * gs * y
    quantities = {
        "length": r,
        "angle": sympy.atan2(x, -y),
        "energy": energy + m / 2 * (vx ** 2 + vy ** 2),
    }
    return EnergyModel([x, y], energy, mass=[m, m],
                       parameters={ks: float(k), L: float(length), gs: float(g)},
                       quantities=quantities, velocities=[vx, vy],
                       initial_displacement=u0, initial_velocity=v0,
                       name="elastic_pendulum", u_scale=float(length),
                       observation_time=observation_time)


def spring_chain(n_masses: int = 5, k: float = 1.0, k3: float = 4.0, mass: float = 1.0, *,
                 u0=None, v0=None, observation_time: float = 30.0) -> EnergyModel:
    """A chain of masses joined by hardening springs, fixed at one end.

    Mass ``i`` (``i = 1..n``) moves along the chain with displacement
    ``u_i``; spring ``i`` joins mass ``i − 1`` to mass ``i``, with ``u_0 = 0``
    the fixed end, and stores

    ``V_i = ½ k d_i² + ¼ k3 d_i⁴``,  ``d_i = u_i − u_{i−1}``.

    ``K`` and ``T`` are tridiagonal and returned as CSR matrices
    (``sparse=True``).

    Parameters
    ----------
    n_masses : int
    k, k3 : float
        Linear and cubic spring coefficients.
    mass : float
        Each mass.
    u0, v0 : array_like (n_masses,), optional
        Initial displacement and velocity. Default: every spring stretched by
        0.8, so that the cubic force ``k3 d³`` exceeds the linear one, and
        released from rest; the free end snaps back and a nonlinear wave runs
        up and down the chain.
    observation_time : float

    Returns
    -------
    EnergyModel
        With parameters ``k`` and ``k3`` and the quantity ``extension`` (the
        ``d_i``, shape (n, n_masses)).

    Examples
    --------
    >>> from hfdi.models.symbolic import spring_chain
    >>> chain = spring_chain(n_masses=4)
    >>> K = chain.stiffness(chain.initial_displacement)
    >>> K.format, K.nnz
    ('csr', 10)
    """
    n = checks.integer("spring_chain n_masses", n_masses, 1)
    checks.positive("spring_chain k", k)
    checks.non_negative("spring_chain k3", k3)
    checks.positive("spring_chain mass", mass)
    u = sympy.symbols(f"u1:{n + 1}")
    ks, k3s = sympy.symbols("k k3")
    d = [u[0]] + [u[i] - u[i - 1] for i in range(1, n)]
    energy = sympy.Add(*[ks / 2 * di ** 2 + k3s / 4 * di ** 4 for di in d])
    if u0 is None:
        u0 = 0.8 * np.arange(1, n + 1)
    return EnergyModel(u, energy, mass=np.full(n, float(mass)),
                       parameters={ks: float(k), k3s: float(k3)},
                       quantities={"extension": d},
                       initial_displacement=u0, initial_velocity=v0,
                       name="spring_chain", u_scale=1.0,
                       observation_time=observation_time, sparse=True)
