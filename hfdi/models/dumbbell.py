"""The dumbbell of the paper's Section 5.1: two masses and a Lennard-Jones-type bond.

``V(r) = A[(σ/r)⁵ − (σ/r)³]`` (Eq. 44); all data are the paper's
(docs/models.md, "Dumbbell").
"""
from __future__ import annotations

import math

import numpy as np

from .. import checks
from .base import KernelModel, length_scale
from .kernels import kernel

__all__ = ["Dumbbell", "dumbbell"]


#: The paper's start: the masses 1 apart on the x axis, moving up at 10 and 5.
DEFAULT_U0 = (0.0, 0.0, 1.0, 0.0)
DEFAULT_V0 = (0.0, 10.0, 0.0, 5.0)


class Dumbbell(KernelModel):
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
    FIXED_PARAMETERS = ("masses",)
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
                 u0=DEFAULT_U0, v0=DEFAULT_V0):
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

    @property
    def rest_length(self) -> float:
        """The bond's length at rest, ``σ (5/3)^½``."""
        return self.sigma * math.sqrt(5.0 / 3.0)

    @length_scale
    def u_scale(self) -> float:
        """The rest length: the model's length scale (the default atol's)."""
        return self.rest_length

    def parameters(self):
        params = {"A": self.A, "sigma": self.sigma, "masses": tuple(self.masses.tolist())}
        for name, value, default in (("u0", self.initial_displacement, DEFAULT_U0),
                                     ("v0", self.initial_velocity, DEFAULT_V0)):
            if not np.array_equal(value, default):
                params[name] = tuple(np.asarray(value, dtype=float).tolist())
        return params

    def params(self):
        """The kernels' data ``(A, σ)``."""
        return np.array((self.A, self.sigma))

    def distance(self, u):
        return _bond(np.asarray(u, dtype=float))[2]

    def quantities(self, t, u, v):
        u = np.atleast_2d(u)
        r = np.hypot(u[:, 2] - u[:, 0], u[:, 3] - u[:, 1])
        return {"u": u, "stretch": ((r - self.rest_length) / self.rest_length)[:, None]}


# -- the kernels: params = (A, σ) ---------------------------------------------------
# The single bond in scalar arithmetic: ``d = x2 − x1``, ``H = a I + b d dᵀ``;
# the blocks of particle 1 and 2 are ``±H`` (see pair.py for the formulas).

@kernel
def _bond(u):
    dx = u[2] - u[0]
    dy = u[3] - u[1]
    return dx, dy, math.sqrt(dx * dx + dy * dy)


@kernel
def _bond_derivatives(A, s, r):
    """The first three derivatives of the bond potential at ``r``."""
    s3 = math.pow(s, 3.0)
    s5 = math.pow(s, 5.0)
    r4 = math.pow(r, 4.0)
    r6 = math.pow(r, 6.0)
    return (A * (-5 * s5 / r6 + 3 * s3 / r4),
            A * (30 * s5 / math.pow(r, 7.0) - 12 * s3 / math.pow(r, 5.0)),
            A * (-210 * s5 / math.pow(r, 8.0) + 60 * s3 / r6))


@kernel
def _bond_blocks(hxx, hxy, hyy):
    """The 4 x 4 matrix with blocks ``[[H, -H], [-H, H]]`` of a symmetric 2 x 2 ``H``."""
    out = np.empty((4, 4))
    H = ((hxx, hxy), (hxy, hyy))
    for a in range(2):
        for b in range(2):
            out[a, b] = H[a][b]
            out[a + 2, b + 2] = H[a][b]
            out[a, b + 2] = -H[a][b]
            out[a + 2, b] = -H[a][b]
    return out


@kernel
def dumbbell_force(u, params):
    A, s = params[0], params[1]
    dx, dy, r = _bond(u)
    q = A * (-5 * math.pow(s, 5.0) / math.pow(r, 6.0)
             + 3 * math.pow(s, 3.0) / math.pow(r, 4.0)) / r
    f = np.empty(4)
    f[0] = -(q * dx)
    f[1] = -(q * dy)
    f[2] = q * dx
    f[3] = q * dy
    return f


@kernel
def dumbbell_stiffness(u, params):
    dx, dy, r = _bond(u)
    d1, d2, _ = _bond_derivatives(params[0], params[1], r)
    a = d1 / r
    b = (d2 - a) / (r * r)
    return _bond_blocks(a + b * dx * dx, b * dx * dy, a + b * dy * dy)


@kernel
def dumbbell_stiffness_derivative(u, w, params):
    dx, dy, r = _bond(u)
    wx = w[2] - w[0]
    wy = w[3] - w[1]
    d1, d2, d3 = _bond_derivatives(params[0], params[1], r)
    s = dx * wx + dy * wy
    b = (d2 - d1 / r) / (r * r)
    db = (d3 - d2 / r + d1 / (r * r)) / (r * r) - 2.0 * (d2 - d1 / r) / (r * r * r)
    c = db * s / r
    bs = b * s
    return _bond_blocks(2.0 * b * wx * dx + c * dx * dx + bs,
                        b * (wx * dy + dx * wy) + c * dx * dy,
                        2.0 * b * wy * dy + c * dy * dy + bs)


@kernel
def dumbbell_potential_energy(u, params):
    A, s = params[0], params[1]
    r = _bond(u)[2]
    return A * (math.pow(s, 5.0) / math.pow(r, 5.0) - math.pow(s, 3.0) / math.pow(r, 3.0))


Dumbbell.KERNELS = (dumbbell_force, dumbbell_stiffness, dumbbell_stiffness_derivative,
                    dumbbell_potential_energy)


def dumbbell(**params) -> Dumbbell:
    """The paper's dumbbell (Section 5.1); keyword arguments as :class:`Dumbbell`."""
    return Dumbbell(**params)
