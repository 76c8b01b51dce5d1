"""The model protocol: a second-order system ``M u'' + C u' + f(u) = p(t)``.

A model tells the integrator its size, its mass matrix ``M`` (diagonal, dense
or sparse), its damping ``C`` (or none), the internal force ``f(u)``, the
tangent ``K(u) = df/du``, the directional derivative of the tangent
``T(u)[w] = d(K(u) w)/du`` that the HFDI tangent needs (paper, Eq. 21 and
Table 1), the external load ``p(t)``, the potential energy ``V(u)`` used by the
energy balance (Eq. 40) and named quantities of interest ``z(t, u, v)`` used
by the error norms (Eq. 42).

Derive a model from :class:`SecondOrderSystem` and override its methods, or
build one from plain callables with :class:`System`.
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
        test (see :func:`hfdi.integrate`).
    """

    name: str = "system"
    n_dof: int = 0
    mass = None
    damping = None
    initial_displacement = None
    initial_velocity = None
    u_scale: float = 1.0

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
    #: case HFDI uses the paper's difference quotient (Section 4).
    load_rate: Callable | None = None

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
                 initial_velocity=None, name="system", u_scale=1.0):
        self.mass = checks.square_matrix("System mass", mass)
        self.n_dof = n = self.mass.shape[0]
        self.damping = None if damping is None else \
            _matching_matrix("System damping", damping, n)
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
        self.load_rate = load_rate
        self._v = potential_energy
        self._q = quantities
        self.initial_displacement = (np.zeros(n) if initial_displacement is None else
                                     checks.finite_array("System initial_displacement",
                                                         initial_displacement, (n,)))
        self.initial_velocity = (np.zeros(n) if initial_velocity is None else
                                 checks.finite_array("System initial_velocity",
                                                     initial_velocity, (n,)))
        self.name = name
        self.u_scale = checks.positive("System u_scale", u_scale)

    def internal_force(self, u):
        return self._f(u)

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

    Raises
    ------
    ValueError
        For arguments of the wrong kind or shape (see :class:`System`).
    """

    name = "linear"

    def __init__(self, mass, stiffness, damping=None, load=None, load_rate=None,
                 initial_displacement=None, initial_velocity=None):
        self.mass = checks.square_matrix("LinearSystem mass", mass)
        self.n_dof = n = self.mass.shape[0]
        k = _matching_matrix("LinearSystem stiffness", stiffness, n)
        if sp.issparse(k):
            self._K = sp.csr_matrix(k, dtype=float)
        else:
            self._K = np.diag(k) if k.ndim == 1 else k
        self.damping = None if damping is None else \
            _matching_matrix("LinearSystem damping", damping, n)
        self._p = checks.callable_or_none("LinearSystem load", load, "p(t) -> (N,)")
        self.load_rate = checks.callable_or_none("LinearSystem load_rate", load_rate,
                                                 "p'(t) -> (N,)")
        self.initial_displacement = (np.zeros(n) if initial_displacement is None else
                                     checks.finite_array("LinearSystem initial_displacement",
                                                         initial_displacement, (n,)))
        self.initial_velocity = (np.zeros(n) if initial_velocity is None else
                                 checks.finite_array("LinearSystem initial_velocity",
                                                     initial_velocity, (n,)))

    def internal_force(self, u):
        return self._K @ u

    def stiffness(self, u):
        return self._K

    def stiffness_derivative(self, u, w):
        return sp.csr_matrix((self.n_dof, self.n_dof)) if sp.issparse(self._K) \
            else np.zeros((self.n_dof, self.n_dof))

    def load(self, t):
        return np.zeros(self.n_dof) if self._p is None else np.asarray(self._p(t), float)

    def potential_energy(self, u):
        return 0.5 * float(u @ (self._K @ u))


class HeldLoad:
    """An ``extra_load`` constant in time, changed only from outside between
    runs: a co-simulation input held over a communication step.

    ``HeldLoad(source)`` is called as any ``extra_load`` (``load(t)`` returns
    ``source()``, whatever ``t``), and says so: being constant over each
    :meth:`Integrator.advance`, it is added by the compiled driver
    (:mod:`hfdi.compiled.driver`) as one vector per call, where any other
    ``extra_load`` keeps the steps on the Python driver.

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
    a = checks.square_matrix(name, value)
    if a.shape[0] != n:
        raise ValueError(f"{name} must have shape ({n},) (diagonal) or ({n}, {n}) to match "
                         f"the mass, got shape {a.shape}")
    return a


# -- finite-difference check ------------------------------------------------

@dataclass
class DerivativeCheck:
    """Worst relative errors of a model's derivatives against finite differences.

    Attributes
    ----------
    force : float
        ``max ‖f − ∇V‖ / ‖f‖`` (NaN when the model has no potential energy).
    stiffness : float
        ``max ‖K w − D_w f‖ / ‖K w‖`` over random directions ``w``.
    stiffness_derivative : float
        ``max ‖T[w] z − D_z(K w)‖ / ‖T[w] z‖``.
    samples : int
        Number of random states tried.
    """

    force: float
    stiffness: float
    stiffness_derivative: float
    samples: int
    details: list = field(default_factory=list, repr=False)

    @property
    def worst(self) -> float:
        return float(np.nanmax([self.force, self.stiffness, self.stiffness_derivative]))

    def ok(self, rtol: float = 1e-6) -> bool:
        return self.worst <= rtol


def _richardson(fun, x, d, eps):
    """Directional derivative of ``fun`` at ``x`` along ``d``, O(eps⁴) accurate."""
    def central(e):
        return (np.asarray(fun(x + e * d)) - np.asarray(fun(x - e * d))) / (2 * e)
    return (4.0 * central(eps / 2) - central(eps)) / 3.0


def _dense(a):
    return a.toarray() if sp.issparse(a) else np.asarray(a)


def _rel(err, ref):
    ref_norm = np.linalg.norm(ref)
    return float(np.linalg.norm(err) / ref_norm) if ref_norm > 0 else float(np.linalg.norm(err))


def check_derivatives(system: SecondOrderSystem, states=None, *, samples: int = 5,
                      spread: float = 0.05, eps: float = 1e-4, seed: int = 0):
    """Check ``f``, ``K`` and ``T`` of a model against finite differences.

    Directional derivatives are taken by central differences with Richardson
    extrapolation along random unit directions scaled by ``u_scale``.

    Parameters
    ----------
    system : SecondOrderSystem
    states : array_like (n, N), optional
        States to check at. Default: ``samples`` random perturbations of the
        initial displacement of relative size ``spread``.
    samples : int
    spread : float
    eps : float
        Finite-difference step, relative to ``system.u_scale``.
    seed : int

    Returns
    -------
    DerivativeCheck
    """
    rng = np.random.default_rng(seed)
    n = system.n_dof
    scale = float(getattr(system, "u_scale", 1.0) or 1.0)
    if states is None:
        base = np.asarray(system.initial_displacement, float)
        states = base + spread * scale * rng.standard_normal((samples, n))
    states = np.atleast_2d(np.asarray(states, float))
    h = eps * scale
    worst_f = worst_k = worst_t = 0.0
    has_potential = True
    details = []
    for u in states:
        d = rng.standard_normal(n)
        d /= np.linalg.norm(d)
        w = rng.standard_normal(n)
        z = rng.standard_normal(n)
        f = np.asarray(system.internal_force(u))
        # f against the gradient of V, along d
        dv = _richardson(lambda x: np.array(system.potential_energy(x)), u, d, h)
        if np.isnan(dv).any():
            has_potential = False
            e_f = np.nan
        else:
            e_f = abs(float(dv) - float(f @ d)) / max(np.linalg.norm(f), 1e-300)
        K = _dense(system.stiffness(u))
        e_k = _rel(K @ d - _richardson(system.internal_force, u, d, h), K @ d)
        Tw = _dense(system.stiffness_derivative(u, w))
        e_t = _rel(Tw @ z - _richardson(lambda x: _dense(system.stiffness(x)) @ w, u, z, h),
                   Tw @ z)
        details.append((e_f, e_k, e_t))
        if has_potential:
            worst_f = max(worst_f, e_f)
        worst_k = max(worst_k, e_k)
        worst_t = max(worst_t, e_t)
    return DerivativeCheck(force=worst_f if has_potential else np.nan,
                           stiffness=worst_k, stiffness_derivative=worst_t,
                           samples=len(states), details=details)
