"""A checked, counting view of a model, used by the schemes and the driver.

Wrapping the user's functions keeps the counters (``nfev``, ``njev``,
``ntev``, ``nlu``) in one place, as ``scipy.integrate`` does, and normalises
the matrices once (see :mod:`hfdi.linalg`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .linalg import Factorization, combine, matvec, normalise_matrix, solve
from .system import SecondOrderSystem

__all__ = ["State", "Evaluator", "ModelError", "DENSE_BELOW"]

#: Sparse matrices of models with fewer DOFs than this are handled as dense
#: arrays: below about a hundred unknowns a dense LU costs microseconds, while
#: every scipy.sparse operation costs tens of microseconds of overhead.
DENSE_BELOW = 128


class ModelError(ValueError):
    """The model returned something unusable (wrong shape, not finite) or raised."""


@dataclass(frozen=True)
class State:
    """The solution at one time.

    Attributes
    ----------
    t : float
    u, v, a : ndarray (N,)
        Displacement, velocity, acceleration.
    f : ndarray (N,)
        Internal force ``f(u)``, kept so that the next step need not recompute it.
    p : ndarray (N,)
        External load ``p(t)``.
    """

    t: float
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    f: np.ndarray
    p: np.ndarray


class Evaluator:
    """Counting wrapper around a :class:`~hfdi.system.SecondOrderSystem`.

    Parameters
    ----------
    system : SecondOrderSystem
    extra_load : callable ``t -> (N,)``, optional
        Added to the model's load (used for inputs of a co-simulation).
    """

    def __init__(self, system: SecondOrderSystem, extra_load=None):
        if not isinstance(system, SecondOrderSystem):
            raise TypeError(f"system must be a hfdi.SecondOrderSystem, got {type(system).__name__}")
        n = int(system.n_dof)
        if n < 1:
            raise ValueError(f"system.n_dof must be >= 1, got {system.n_dof}")
        self.system = system
        self.n = n
        self.mass = normalise_matrix(system.mass, n, "mass")
        if self.mass is None:
            raise ValueError("system.mass must be given")
        self.damping = normalise_matrix(system.damping, n, "damping")
        if n < DENSE_BELOW:
            self.mass, self.damping = (a.toarray() if sp.issparse(a) else a
                                       for a in (self.mass, self.damping))
        self.extra_load = extra_load
        self.nfev = self.njev = self.ntev = self.nlu = self.npev = 0
        self._mass_factor = None
        self.mass_is_diagonal = self.mass.ndim == 1
        self.damping_is_diagonal = self.damping is None or (
            isinstance(self.damping, np.ndarray) and self.damping.ndim == 1)

    # -- counted model calls --------------------------------------------------
    def _vector(self, value, what):
        arr = np.asarray(value, dtype=float)
        if arr.shape != (self.n,):
            raise ModelError(f"{what} returned shape {arr.shape}, expected ({self.n},)")
        return arr

    def _matrix(self, value, what):
        if sp.issparse(value):
            if value.shape != (self.n, self.n):
                raise ModelError(f"{what} returned shape {value.shape}, expected ({self.n}, {self.n})")
            return value.toarray() if self.n < DENSE_BELOW else value
        arr = np.asarray(value, dtype=float)
        if arr.shape != (self.n, self.n):
            raise ModelError(f"{what} returned shape {arr.shape}, expected ({self.n}, {self.n})")
        return arr

    def force(self, u):
        self.nfev += 1
        return self._vector(self.system.internal_force(u), "internal_force")

    def stiffness(self, u):
        self.njev += 1
        return self._matrix(self.system.stiffness(u), "stiffness")

    def stiffness_derivative(self, u, w):
        self.ntev += 1
        return self._matrix(self.system.stiffness_derivative(u, w), "stiffness_derivative")

    def load(self, t):
        p = self._vector(self.system.load(t), "load")
        if self.extra_load is not None:
            p = p + self._vector(self.extra_load(t), "extra load")
        return p

    @property
    def has_load_rate(self):
        return self.system.load_rate is not None and self.extra_load is None

    def load_rate(self, t):
        return self._vector(self.system.load_rate(t), "load_rate")

    def potential_energy(self, u):
        self.npev += 1
        return float(self.system.potential_energy(u))

    # -- mass and damping -----------------------------------------------------
    def mass_times(self, x):
        return matvec(self.mass, x)

    def damping_times(self, x):
        return matvec(self.damping, x)

    def mass_solve(self, b):
        if self._mass_factor is None:
            self._mass_factor = Factorization(self.mass)
        return self._mass_factor.solve(b)

    def acceleration(self, t, u, v, f=None, p=None):
        """``a = M⁻¹(p − f − C v)`` (Eq. 14)."""
        f = self.force(u) if f is None else f
        p = self.load(t) if p is None else p
        return self.mass_solve(p - f - self.damping_times(v))

    def state(self, t, u, v):
        """A consistent :class:`State` at ``t`` (computes f, p and a)."""
        u = np.array(u, dtype=float)
        v = np.array(v, dtype=float)
        f = self.force(u)
        p = self.load(t)
        return State(t, u, v, self.acceleration(t, u, v, f, p), f, p)

    def kinetic_energy(self, v):
        return 0.5 * float(v @ matvec(self.mass, v))

    # -- linear algebra -------------------------------------------------------
    def combine(self, *terms):
        return combine(*terms)

    def solve(self, a, b):
        self.nlu += 1
        return solve(a, b)

    def counters(self):
        return {"nfev": self.nfev, "njev": self.njev, "ntev": self.ntev,
                "nlu": self.nlu, "npev": self.npev}
