"""The model protocol: a second-order system ``M u'' + C u' + f(u) = p(t)``.

A model gives its size, ``M``, ``C``, ``f(u)``, ``K(u) = df/du``,
``T(u)[w] = d(K(u) w)/du`` (HFDI's tangent, Eq. 21), ``p(t)``, ``V(u)`` (the
energy balance, Eq. 40) and quantities of interest (the error norms, Eq. 42):
subclass :class:`SecondOrderSystem`, or build one from callables with
:class:`System`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.sparse as sp

from . import checks

__all__ = [
    "SecondOrderSystem",
    "System",
    "LinearSystem",
    "DerivativeCheck",
    "check_derivatives",
    "load_rate_error",
]


class SecondOrderSystem:
    """Base class of a model ``M u'' + C u' + f(u) = p(t)``.

    Subclasses set :attr:`n_dof`, :attr:`mass` and, where they have them,
    :attr:`damping`, :attr:`initial_displacement` and
    :attr:`initial_velocity`, and override :meth:`internal_force`,
    :meth:`stiffness` and :meth:`stiffness_derivative`. The other methods
    have defaults: no load, no potential energy (the energy balance is then
    reported as NaN) and ``u`` as the only quantity of interest.

    Attributes
    ----------
    name : str
        Short name of the model.
    n_dof : int
        Number of degrees of freedom ``N``.
    mass : ndarray (N,) or ndarray (N, N) or sparse (N, N)
        Mass matrix; a 1-D array is a diagonal matrix.
    damping : None or ndarray (N,) or ndarray (N, N) or sparse (N, N)
        Damping matrix, ``None`` for an undamped model.
    initial_displacement, initial_velocity : ndarray (N,)
        Default initial conditions ``u(t0)`` and ``u'(t0)``.
    u_scale : float
        A length of the model, the absolute floor of the Newton convergence
        test (see :func:`hfdi.integrate`) and, for a model starting at
        ``u0 = 0``, the scale of the default ``atol`` of ``u`` where the model
        declares it (:func:`declared_u_scale`).
    """

    name: str = "system"
    n_dof: int = 0
    mass = None
    damping = None
    initial_displacement = None
    initial_velocity = None
    u_scale: float = 1.0
    #: Units and labels of the variables of the model's FMU (see :mod:`fmu.metadata`);
    #: ``stop_time`` is the end of its default experiment. ``None``: SI units assumed.
    fmi_metadata: dict | None = None

    # -- mechanics ---------------------------------------------------------
    def internal_force(self, u):
        """Internal force ``f(u)``, shape (N,)."""
        raise NotImplementedError

    def stiffness(self, u):
        """Tangent ``K(u) = df/du``, ndarray or sparse (N, N)."""
        raise NotImplementedError

    def stiffness_derivative(self, u, w):
        """Directional derivative ``T(u)[w] = d(K(u) w)/du``, (N, N)."""
        raise NotImplementedError

    def load(self, t):
        """External load ``p(t)``, shape (N,)."""
        return np.zeros(self.n_dof)

    #: Exact load rate ``p'(t)``; ``None`` when the model has none, in which
    #: case HFDI differentiates the load within the step under error control,
    #: else takes the paper's difference quotient (docs/algorithm.md, "Load rate")
    load_rate: Callable | None = None

    #: True when the load is linear between the times of :meth:`load_breakpoints`
    #: (hat pulses, steps): the paper's quotient is then its exact rate, and
    #: HFDI evaluates the load no more to derive one.
    load_linear_between_breakpoints: bool = False

    def load_breakpoints(self):
        """Times where the load ``p`` or its rate ``p'`` jumps (a kink of a hat
        pulse, a step load), as a sequence of floats; empty by default.

        Error-controlled runs land their steps on them and restart the
        predictor there, so that no step straddles a kink (docs/algorithm.md).
        """
        return ()

    def potential_energy(self, u):
        """Potential energy ``V(u)`` with ``f = dV/du``; NaN if unknown."""
        return np.nan

    def quantities(self, t, u, v):
        """Quantities of interest, vectorised over times.

        Parameters
        ----------
        t : ndarray (n,)
        u, v : ndarray (n, N)

        Returns
        -------
        dict of str to ndarray (n, m)
        """
        return {"u": np.asarray(u)}

    def parameters(self) -> dict:
        """The model's parameters (name to value), for reports."""
        return {}

    def __repr__(self):
        params = ", ".join(f"{k}={v!r}" for k, v in self.parameters().items())
        return f"{type(self).__name__}({params})"


def declared_u_scale(system) -> float | None:
    """The model's own ``u_scale``, or ``None`` where it only inherits the
    base class's (a :class:`System` or :class:`LinearSystem` built without
    one): set on the instance or by a subclass."""
    if "u_scale" in vars(system) or any("u_scale" in vars(k) for k in type(system).__mro__
                                        if k is not SecondOrderSystem):
        value = getattr(system, "u_scale", None)
        return None if value is None else checked_u_scale(value)
    return None


def checked_u_scale(value) -> float:
    """A model's ``u_scale``: a finite number > 0 (a NaN made the default
    atol NaN, and a run took 70 times the steps or none passed; 0 or a
    negative one was taken silently)."""
    try:
        return checks.positive("system.u_scale", value)
    except ValueError:
        raise ValueError(f"system.u_scale must be a finite number > 0 (the model's length "
                         f"scale, the default atol's), got {value!r}") from None


class System(SecondOrderSystem):
    """A model assembled from callables.

    Parameters
    ----------
    mass : array_like (N,) or (N, N) or sparse
        Mass matrix; 1-D means diagonal.
    internal_force : callable ``f(u) -> (N,)``
    stiffness : callable ``K(u) -> (N, N)``
    stiffness_derivative : callable ``T(u, w) -> (N, N)`` or None
        Needed by HFDI only; with ``None`` the integrator refuses HFDI up front.
    damping : array_like or sparse, optional
    load : callable ``p(t) -> (N,)``, optional
    load_rate : callable ``p'(t) -> (N,)``, optional
    potential_energy : callable ``V(u) -> float``, optional
    quantities : callable ``(t, u, v) -> dict``, optional
    initial_displacement, initial_velocity : array_like (N,), optional
        Zero when omitted.
    name : str, optional
    u_scale : float, optional
        A length of the model (:attr:`SecondOrderSystem.u_scale`); 1 when
        omitted, and the default ``atol`` then takes its scale from what the
        load and the initial velocity drive for a model starting at rest.

    Raises
    ------
    ValueError
        For arguments of the wrong kind or shape. Whether the mass is positive
        definite, the damping semi-definite and the functions return the
        right shapes is checked when an integrator is built on the model.
    """

    def __init__(self, mass, internal_force, stiffness, stiffness_derivative, *,
                 damping=None, load=None, load_rate=None, potential_energy=None,
                 quantities=None, initial_displacement=None,
                 initial_velocity=None, name="system", u_scale=None):
        _matrices_and_start(self, "System", mass, damping, initial_displacement,
                            initial_velocity)
        for what, value, signature in (
                ("internal_force", internal_force, "f(u) -> (N,)"),
                ("stiffness", stiffness, "K(u) -> (N, N)")):
            if not callable(value):
                raise ValueError(f"System {what} must be a callable {signature}, got {value!r}")
        for what, value, signature in (
                ("stiffness_derivative", stiffness_derivative, "T(u, w) -> (N, N)"),
                ("load", load, "p(t) -> (N,)"), ("load_rate", load_rate, "p'(t) -> (N,)"),
                ("potential_energy", potential_energy, "V(u) -> float"),
                ("quantities", quantities, "(t, u, v) -> dict")):
            checks.callable_or_none(f"System {what}", value, signature)
        self._f = internal_force
        self._k = stiffness
        self._t = stiffness_derivative
        self._p = load
        self._load_rate = load_rate
        self._v = potential_energy
        self._q = quantities
        self.name = name
        if u_scale is not None:
            self.u_scale = checks.positive("System u_scale", u_scale)

    def internal_force(self, u):
        return self._f(u)

    def compiled_kernels(self):
        """Kernels calling the given callables where every one is a numba
        function (:mod:`hfdi.compiled.callables`): the run is then compiled.
        Imports numba.

        Raises
        ------
        hfdi.compiled.CompiledUnavailable
            Naming a callable that is a Python function (the run takes the
            Python path and says so once).
        """
        from .compiled.callables import system_kernels
        return system_kernels(self, {
            "internal_force": self._f, "stiffness": self._k, "stiffness_derivative": self._t,
            "potential_energy": self._v, "load": self._p, "load_rate": self._load_rate})

    @property
    def load_rate(self):
        """The exact load rate ``p'(t)`` given, or ``None``."""
        return self._load_rate

    @load_rate.setter
    def load_rate(self, rate):
        self._load_rate = checks.callable_or_none("System load_rate", rate, "p'(t) -> (N,)")

    def stiffness(self, u):
        return self._k(u)

    def stiffness_derivative(self, u, w):
        if self._t is None:
            raise NotImplementedError("System(stiffness_derivative=None) has no "
                                      "T(u, w) = d(K(u) w)/du; Newmark and Bathe do without")
        return self._t(u, w)

    def load(self, t):
        return np.zeros(self.n_dof) if self._p is None else self._p(t)

    def potential_energy(self, u):
        return np.nan if self._v is None else self._v(u)

    def quantities(self, t, u, v):
        return {"u": np.asarray(u)} if self._q is None else self._q(t, u, v)


class LinearSystem(SecondOrderSystem):
    """The linear model ``M u'' + C u' + K u = p(t)``.

    Parameters
    ----------
    mass, stiffness : array_like (N,) or (N, N) or sparse
        ``M`` and ``K``; 1-D arrays are diagonal matrices.
    damping : array_like or sparse, optional
    load, load_rate : callable, optional
    initial_displacement, initial_velocity : array_like (N,), optional
    u_scale : float, optional
        As for :class:`System`.

    Raises
    ------
    ValueError
        For arguments of the wrong kind or shape (see :class:`System`).
    """

    name = "linear"

    def __init__(self, mass, stiffness, damping=None, load=None, load_rate=None,
                 initial_displacement=None, initial_velocity=None, u_scale=None):
        n = _matrices_and_start(self, "LinearSystem", mass, damping, initial_displacement,
                                initial_velocity)
        if u_scale is not None:
            self.u_scale = checks.positive("LinearSystem u_scale", u_scale)
        k = _matching_matrix("LinearSystem stiffness", stiffness, n)
        # A diagonal K is dense below the integrator's dense threshold, sparse
        # above it: as a dense (N, N) array it would cost N² memory and dense
        # solves (a 2,000-DOF diagonal took 2,600 times as long).
        from .evaluation import DENSE_BELOW
        if k.ndim == 1 and n >= DENSE_BELOW:
            k = sp.diags(k, format="csr")
        if sp.issparse(k):
            self._K = sp.csr_matrix(k, dtype=float)
            self._T = sp.csr_matrix((n, n))
        else:
            self._K = np.diag(k) if k.ndim == 1 else k
            self._T = np.zeros((n, n))
        self._p = checks.callable_or_none("LinearSystem load", load, "p(t) -> (N,)")
        self.load_rate = load_rate

    @property
    def load_rate(self):
        """The exact load rate ``p'(t)`` given, or ``None``."""
        return self._load_rate

    @load_rate.setter
    def load_rate(self, rate):
        self._load_rate = checks.callable_or_none("LinearSystem load_rate", rate,
                                                  "p'(t) -> (N,)")

    def internal_force(self, u):
        return self._K @ u

    def compiled_kernels(self):
        """The compiled kernels of ``f = K u`` (:mod:`hfdi.models.linear_kernels`)
        where the compiled path can run this system: a dense ``K`` (fewer than
        ``DENSE_BELOW`` unknowns), and no load or a load (and load rate) given
        as ``numba.njit`` functions (:mod:`hfdi.compiled.callables`); a Python
        load function cannot run compiled (the run then says so once and takes
        the Python path). Imports numba."""
        from .compiled import CompiledUnavailable
        if sp.issparse(self._K):
            raise CompiledUnavailable("LinearSystem has a sparse stiffness: its steps run "
                                      "with sparse solves in Python")
        from .compiled.callables import load_kernels
        load, rate = load_kernels("LinearSystem", self._p, self._load_rate)
        from .models.kernels import compiled_kernels
        from .models.linear_kernels import (linear_force, linear_potential_energy,
                                            linear_stiffness, linear_stiffness_derivative)
        from .models.loads import hat_load_params
        kernels = compiled_kernels(linear_force, linear_stiffness, linear_stiffness_derivative,
                                   linear_potential_energy,
                                   np.ascontiguousarray(self._K, float).reshape(-1),
                                   load_params=hat_load_params(self.n_dof))
        if load is None:
            return kernels._replace(load_rate=rate)
        return kernels._replace(load=load, load_params=np.zeros(1), load_rate=rate)

    def stiffness(self, u):
        return self._K

    def stiffness_derivative(self, u, w):
        return self._T

    def load(self, t):
        return np.zeros(self.n_dof) if self._p is None else self._p(t)

    def potential_energy(self, u):
        return 0.5 * float(u @ (self._K @ u))


class HeldLoad:
    """An ``extra_load`` constant in time, changed only from outside between
    runs: a co-simulation input held over a communication step.

    ``HeldLoad(source)`` is called as any ``extra_load`` (``load(t)`` returns
    ``source()``, whatever ``t``), and says so: being constant over each
    :meth:`Integrator.advance`, it is added by the compiled loop as one vector
    per call, where any other ``extra_load`` keeps the steps in Python.

    Parameters
    ----------
    source : callable ``() -> (N,)``
        The load now. Its value may change only between calls of
        :meth:`~hfdi.Integrator.advance` or :meth:`~hfdi.Integrator.step`,
        followed by :meth:`~hfdi.Integrator.load_changed` (the load jumps
        there).
    """

    def __init__(self, source):
        if not callable(source):
            raise ValueError(f"HeldLoad: source must be callable as source() -> (N,), got "
                             f"{source!r}")
        self.source = source

    def __call__(self, t):
        return self.source()

    def __repr__(self):
        return f"HeldLoad({self.source!r})"


def _matching_matrix(name, value, n):
    """A matrix of the model checked to be (n,) (a diagonal) or (n, n)."""
    return checks.square_matrix(name, value, n, to_match=" to match the mass")


def _matrices_and_start(model, who, mass, damping, initial_displacement, initial_velocity):
    """``model``'s mass, damping and initial conditions (zero when omitted),
    checked in the messages of ``who``; returns ``N``."""
    model.mass = checks.square_matrix(f"{who} mass", mass)
    model.n_dof = n = model.mass.shape[0]
    model.damping = None if damping is None else \
        _matching_matrix(f"{who} damping", damping, n)
    model.initial_displacement, model.initial_velocity = (
        np.zeros(n) if value is None else checks.finite_array(
            f"{who} {what}", value, (n,), to_match=f" to match the mass of {n} DOFs")
        for what, value in (("initial_displacement", initial_displacement),
                            ("initial_velocity", initial_velocity)))
    return n


# -- finite-difference check ------------------------------------------------

@dataclass
class DerivativeCheck:
    """Worst relative errors of a model's derivatives against finite differences.

    An error is ``inf`` where the model's value (or the finite difference
    made of its values) is not finite at a state checked: such a model fails
    :meth:`ok` whatever the tolerance.

    Attributes
    ----------
    force : float
        ``max |D_d V − f·d| / ‖f‖`` (NaN when the model has no potential energy,
        ``V`` NaN at every state; ``inf`` when ``V`` is NaN at some states only).
    stiffness : float
        ``max ‖K d − D_d f‖ / ‖K d‖`` over random unit directions ``d``.
    stiffness_derivative : float
        ``max ‖T[w] z − D_z(K w)‖ / ‖T[w] z‖``.
    samples : int
        Number of states tried.
    load_rate : float
        The largest relative mismatch of a component of ``p'(t)`` with the
        forward differences of ``p`` over the times checked
        (:func:`load_rate_error`; NaN when the model has no ``load_rate``).
    """

    force: float
    stiffness: float
    stiffness_derivative: float
    samples: int
    details: list = field(default_factory=list, repr=False)
    load_rate: float = np.nan

    @property
    def worst(self) -> float:
        """The largest error checked (NaN entries, "not provided", are left out)."""
        values = [e for e in (self.force, self.stiffness, self.stiffness_derivative,
                              self.load_rate) if not np.isnan(e)]
        return float(max(values)) if values else np.nan

    def ok(self, rtol: float = 1e-6) -> bool:
        return bool(self.worst <= rtol)


def _richardson(fun, x, d, eps):
    """Directional derivative of ``fun`` at ``x`` along ``d``, O(eps⁴) accurate."""
    def central(e):
        return (np.asarray(fun(x + e * d)) - np.asarray(fun(x - e * d))) / (2 * e)
    return (4.0 * central(eps / 2) - central(eps)) / 3.0


def _dense(a):
    return a.toarray() if sp.issparse(a) else np.asarray(a, dtype=float)


def _rel(err, ref):
    """``‖err‖ / ‖ref‖`` (``‖err‖`` where ``ref`` is 0); ``inf`` where either is
    not finite."""
    err, ref = np.asarray(err, dtype=float), np.asarray(ref, dtype=float)
    if not (np.all(np.isfinite(err)) and np.all(np.isfinite(ref))):
        return np.inf
    ref_norm = np.linalg.norm(ref)
    return float(np.linalg.norm(err) / ref_norm) if ref_norm > 0 else float(np.linalg.norm(err))


def load_rate_error(load, load_rate, t, time_scale, horizon=np.inf) -> float:
    """How far ``load_rate(t)`` is from the right derivative of ``load`` at ``t``.

    Forward differences, Richardson-extrapolated (``2 D(δ) − D(2δ)``), at
    ``δ = time_scale·10^-k`` for ``k = 2 … 13`` that stay before ``horizon``
    (the load's next breakpoint). Per component, a step counts where the
    rounding of ``p`` amplified by ``1/δ`` is below 1e-4 of the rate's size
    (the largest of ``|p'(t)|``, the difference, and the smallest mean rate
    the load resolves, so that a rate of zero at an extremum is judged), and
    the error is the smallest relative mismatch over the steps that count.
    Returns the largest of the components' errors; NaN when none could be
    judged, ``inf`` where the values are not finite.
    """
    rate = np.asarray(load_rate(t), dtype=float)
    p0 = np.asarray(load(t), dtype=float)
    if not (np.all(np.isfinite(rate)) and np.all(np.isfinite(p0))):
        return np.inf
    eps = np.finfo(float).eps
    steps = []
    for k in range(2, 14):
        delta = time_scale * 10.0 ** -k
        t1, t2 = t + delta, t + 2 * delta
        if not t1 > t:
            break
        if t2 > horizon:
            continue
        p1 = np.asarray(load(t1), dtype=float)
        p2 = np.asarray(load(t2), dtype=float)
        if not (np.all(np.isfinite(p1)) and np.all(np.isfinite(p2))):
            continue
        # 2 D(δ) − D(2δ) with D(h) = (p(t + h) − p(t))/h = p' + h p''/2 + …:
        # error −δ² p‴/3; the steps as represented (t + δ rounds)
        difference = 2.0 * (p1 - p0) / (t1 - t) - (p2 - p0) / (t2 - t)
        rounding = 16.0 * eps * (np.abs(p0) + np.abs(p1) + np.abs(p2)) / (t1 - t)
        steps.append((difference, rounding, np.abs(p2 - p0) / (t2 - t)))
    # the smallest mean rate the load resolves, per component
    floor = np.full(rate.shape, np.inf)
    for _, rounding, mean in steps:
        floor = np.where((mean > 0) & (rounding <= 1e-4 * mean), np.minimum(floor, mean), floor)
    floor = np.where(np.isfinite(floor), floor, 0.0)
    best = np.full(rate.shape, np.inf)
    for difference, rounding, _ in steps:
        size = np.maximum(np.maximum(np.abs(rate), np.abs(difference)), floor)
        counts = (size > 0) & (rounding <= 1e-4 * size)
        with np.errstate(divide="ignore", invalid="ignore"):
            relative = np.where(counts, np.abs(rate - difference) / size, np.inf)
        best = np.minimum(best, relative)
    judged = np.isfinite(best)
    return float(best[judged].max()) if judged.any() else np.nan


def check_derivatives(system: SecondOrderSystem, states=None, *, samples: int = 5,
                      spread: float = 0.05, eps: float = 1e-4, seed: int = 0, times=None):
    """Check ``f``, ``K``, ``T`` (and ``V``, ``p'`` where given) of a model
    against finite differences.

    Directional derivatives are taken by central differences with Richardson
    extrapolation along random unit directions scaled by ``u_scale``; the
    load rate by forward differences (:func:`load_rate_error`).

    Parameters
    ----------
    system : SecondOrderSystem
    states : array_like (n, N), optional
        States to check at (finite). Default: ``samples`` random perturbations
        of the initial displacement of relative size ``spread``.
    samples : int
        Number of random states (1 … 1,000,000) when ``states`` is not given.
    spread : float
        Size of the random perturbations relative to ``u_scale``, in (0, 100].
    eps : float
        Finite-difference step relative to ``system.u_scale``, in (0, 0.1].
    seed : int
    times : array_like (m,), optional
        Times at which ``load_rate`` is checked against ``load``. Default:
        0, 0.25, 0.5, 0.75 and 1. Ignored for a model without ``load_rate``.

    Returns
    -------
    DerivativeCheck
        An entry is ``inf`` where a value is not finite.
    """
    if not isinstance(system, SecondOrderSystem):
        raise TypeError(f"system must be a hfdi.SecondOrderSystem, got {type(system).__name__}")
    n = int(system.n_dof)
    rng = np.random.default_rng(seed)
    scale = float(getattr(system, "u_scale", 1.0) or 1.0)
    spread = checks.real("spread", spread, low=0.0, high=100.0, high_closed=True)
    eps = checks.real("eps", eps, low=0.0, high=0.1, high_closed=True)
    if states is None:
        samples = checks.integer("samples", samples, 1, 1_000_000)
        u0 = getattr(system, "initial_displacement", None)
        base = checks.finite_array("system.initial_displacement",
                                   np.zeros(n) if u0 is None else u0, (n,))
        states = base + spread * scale * rng.standard_normal((samples, n))
    else:
        given, states = states, checks.real_array(states)
        states = None if states is None else np.atleast_2d(states)
        if states is None or states.ndim != 2 or states.shape[1] != n \
                or states.shape[0] < 1 or not np.all(np.isfinite(states)):
            raise ValueError(f"states must be an array of shape (n, {n}), n >= 1, of finite "
                             f"real numbers, got {given!r:.80}")
    h = eps * scale
    worst_f = worst_k = worst_t = 0.0
    # V known at some states and NaN ("not provided") at others is a fault of
    # the model, as in a run (MODEL_ERROR), not a model without V
    known_potential = unknown_potential = False
    details = []
    with np.errstate(all="ignore"):
        for u in states:
            d = rng.standard_normal(n)
            d /= np.linalg.norm(d)
            w = rng.standard_normal(n)
            z = rng.standard_normal(n)
            f = np.asarray(system.internal_force(u), dtype=float)
            # f against the gradient of V, along d
            potential = np.asarray(system.potential_energy(u), dtype=float)
            if np.isnan(potential).any():
                unknown_potential = True
                e_f = np.nan
            else:
                known_potential = True
                dv = _richardson(lambda x: np.asarray(system.potential_energy(x), dtype=float),
                                 u, d, h)
                e_f = _rel(float(dv) - float(f @ d), max(np.linalg.norm(f), 1e-300)) \
                    if np.all(np.isfinite(f)) else np.inf
            K = _dense(system.stiffness(u))
            e_k = _rel(K @ d - _richardson(system.internal_force, u, d, h), K @ d)
            Tw = _dense(system.stiffness_derivative(u, w))
            e_t = _rel(Tw @ z - _richardson(lambda x: _dense(system.stiffness(x)) @ w, u, z, h),
                       Tw @ z)
            details.append((e_f, e_k, e_t))
            if not np.isnan(e_f):
                worst_f = max(worst_f, e_f)
            worst_k = max(worst_k, e_k)
            worst_t = max(worst_t, e_t)
        worst_p = np.nan
        if getattr(system, "load_rate", None) is not None:
            given = times
            times = np.linspace(0.0, 1.0, 5) if given is None else checks.real_array(given)
            if times is not None:
                times = np.atleast_1d(times)
            if times is None or times.ndim != 1 or times.size < 1 \
                    or not np.all(np.isfinite(times)):
                raise ValueError(f"times must be a 1-D array of finite real times, got "
                                 f"{given!r:.80}")
            span = float(np.ptp(times)) if times.size > 1 else 0.0
            time_scale = max(span, float(np.abs(times).max()), 1.0)
            try:
                points = np.asarray(list(system.load_breakpoints()), dtype=float).ravel()
            except Exception:
                points = np.empty(0)
            errors = []
            for t in times:
                later = points[points > t]
                errors.append(load_rate_error(system.load, system.load_rate, float(t),
                                              time_scale,
                                              float(later.min()) if later.size else np.inf))
            errors = np.asarray(errors)
            worst_p = np.inf if np.isinf(errors).any() else \
                (float(np.nanmax(errors)) if not np.isnan(errors).all() else np.nan)
    if known_potential and unknown_potential:
        worst_f = np.inf
    return DerivativeCheck(force=worst_f if known_potential else np.nan,
                           stiffness=worst_k, stiffness_derivative=worst_t,
                           samples=len(states), details=details, load_rate=worst_p)
