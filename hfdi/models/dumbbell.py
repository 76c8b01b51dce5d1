"""The dumbbell of the paper's Section 5.1: two masses and a Lennard-Jones-type bond.

All data are the paper's: ``V(r) = A[(σ/r)⁵ − (σ/r)³]`` (Eq. 44) with
``σ = (3/5)^{1/2}`` (so the bond is force-free at ``r₀ = σ (5/3)^{1/2} = 1``),
``A = 10⁶``, unit masses, ``u(0) = (0, 0, 1, 0)``, ``u'(0) = (0, 10, 0, 5)``,
``T_o = 2``. The bond's small-oscillation frequency is
``ω = (2 φ''(1))^{1/2} ≈ 2362`` rad/s.
"""
from __future__ import annotations

import math

import numpy as np

from .. import checks
from ..system import SecondOrderSystem
from .pair import PairPotential

__all__ = ["Dumbbell", "dumbbell"]


class Dumbbell(SecondOrderSystem):
    """Two particles in the plane, ``u = (x1, y1, x2, y2)``, joined by
    ``V(r) = A[(σ/r)⁵ − (σ/r)³]``.

    Parameters
    ----------
    A : float
        Bond strength (paper: 10⁶, the "quasi-rigid" case).
    sigma : float
        Length parameter (paper: (3/5)^{1/2}).
    masses : tuple of 2 floats
    u0, v0 : array_like (4,)
        Initial positions and velocities.
    """

    name = "dumbbell"
    #: Units and labels of the variables of the model's FMU (see :mod:`fmu.metadata`);
    #: ``stop_time`` is the end of its default experiment.
    fmi_metadata = {
        "dofs": [["m", "x of particle {k}"], ["m", "y of particle {k}"]],
        "parameters": {
            "A": ["J", "bond strength A of V(r) = A[(sigma/r)^5 - (sigma/r)^3] (paper Eq. 44)"],
            "sigma": ["m", "length parameter sigma of the bond potential (rest length "
                           "sigma*(5/3)^(1/2))"],
        },
        "quantities": {
            "u": ["m", "positions", None],
            "stretch": ["1", "relative bond stretch (r - r0)/r0", None],
        },
        "stop_time": 2.0,
    }

    def __init__(self, A=1e6, sigma=math.sqrt(3.0 / 5.0), masses=(1.0, 1.0),
                 u0=(0.0, 0.0, 1.0, 0.0), v0=(0.0, 10.0, 0.0, 5.0)):
        self.A = checks.positive("dumbbell A", A)
        self.sigma = checks.positive("dumbbell sigma", sigma)
        self.masses = checks.finite_array("dumbbell masses", masses, (2,), positive=True)
        self.n_dof = 4
        self.mass = np.repeat(self.masses, 2)
        self.initial_displacement = checks.finite_array("dumbbell u0", u0, (4,))
        self.initial_velocity = checks.finite_array("dumbbell v0", v0, (4,))
        if np.hypot(*(self.initial_displacement[2:] - self.initial_displacement[:2])) == 0:
            raise ValueError(f"dumbbell u0 must place the two masses apart (the bond length "
                             f"must be > 0), got {tuple(self.initial_displacement.tolist())}")
        self.rest_length = self.sigma * math.sqrt(5.0 / 3.0)
        self.u_scale = self.rest_length
        self._pair = PairPotential(2, 2, [0], [1])

    def parameters(self):
        return {"A": self.A, "sigma": self.sigma, "masses": tuple(self.masses)}

    # φ(r) and its derivatives
    def _phi(self, r, order):
        A, s = self.A, self.sigma
        s3, s5 = s ** 3, s ** 5
        if order == 0:
            return A * (s5 / r ** 5 - s3 / r ** 3)
        if order == 1:
            return A * (-5 * s5 / r ** 6 + 3 * s3 / r ** 4)
        if order == 2:
            return A * (30 * s5 / r ** 7 - 12 * s3 / r ** 5)
        return A * (-210 * s5 / r ** 8 + 60 * s3 / r ** 6)

    def distance(self, u):
        return self._pair.geometry(np.asarray(u, float))[1]

    # f, K and T of the single bond in scalar arithmetic: with one pair of
    # particles in the plane the numpy versions spend nearly all their time
    # in call overhead. ``d = x2 − x1``, ``H = a I + b d dᵀ``; the blocks of
    # particle 1 and 2 are ``±H`` (see pair.py for the formulas).
    def _bond(self, u):
        x1, y1, x2, y2 = np.asarray(u, dtype=float).tolist()
        dx, dy = x2 - x1, y2 - y1
        return dx, dy, math.sqrt(dx * dx + dy * dy)

    def _derivatives(self, r):
        """The first three derivatives of the bond potential at ``r`` as floats."""
        A, s = self.A, self.sigma
        s3, s5 = s ** 3, s ** 5
        r4, r6 = r ** 4, r ** 6
        return (A * (-5 * s5 / r6 + 3 * s3 / r4),
                A * (30 * s5 / r ** 7 - 12 * s3 / r ** 5),
                A * (-210 * s5 / r ** 8 + 60 * s3 / r6))

    def internal_force(self, u):
        dx, dy, r = self._bond(u)
        A, s = self.A, self.sigma
        q = A * (-5 * s ** 5 / r ** 6 + 3 * s ** 3 / r ** 4) / r
        fx, fy = q * dx, q * dy
        return np.array((-fx, -fy, fx, fy))

    @staticmethod
    def _blocks(hxx, hxy, hyy):
        """The 4 x 4 matrix with blocks ``[[H, -H], [-H, H]]`` of a symmetric 2 x 2 ``H``."""
        return np.array(((hxx, hxy, -hxx, -hxy), (hxy, hyy, -hxy, -hyy),
                         (-hxx, -hxy, hxx, hxy), (-hxy, -hyy, hxy, hyy)))

    def stiffness(self, u):
        dx, dy, r = self._bond(u)
        d1, d2, _ = self._derivatives(r)
        a = d1 / r
        b = (d2 - a) / (r * r)
        return self._blocks(a + b * dx * dx, b * dx * dy, a + b * dy * dy)

    def stiffness_derivative(self, u, w):
        dx, dy, r = self._bond(u)
        w1x, w1y, w2x, w2y = np.asarray(w, dtype=float).tolist()
        wx, wy = w2x - w1x, w2y - w1y
        d1, d2, d3 = self._derivatives(r)
        s = dx * wx + dy * wy
        b = (d2 - d1 / r) / (r * r)
        db = (d3 - d2 / r + d1 / (r * r)) / (r * r) - 2.0 * (d2 - d1 / r) / (r * r * r)
        c = db * s / r
        bs = b * s
        return self._blocks(2.0 * b * wx * dx + c * dx * dx + bs,
                            b * (wx * dy + dx * wy) + c * dx * dy,
                            2.0 * b * wy * dy + c * dy * dy + bs)

    def compiled_kernels(self):
        """Compiled kernels of f, K, T, V and the load (:func:`hfdi.compiled.models.dumbbell_kernels`;
        imports numba)."""
        from ..compiled.models import dumbbell_kernels
        return dumbbell_kernels(self)

    def potential_energy(self, u):
        r = self._bond(u)[2]
        A, s = self.A, self.sigma
        return A * (s ** 5 / r ** 5 - s ** 3 / r ** 3)

    def quantities(self, t, u, v):
        u = np.atleast_2d(u)
        r = np.hypot(u[:, 2] - u[:, 0], u[:, 3] - u[:, 1])
        return {"u": u, "stretch": ((r - self.rest_length) / self.rest_length)[:, None]}


def dumbbell(**params) -> Dumbbell:
    """The paper's dumbbell (Section 5.1); keyword arguments as :class:`Dumbbell`."""
    return Dumbbell(**params)
