"""Generalized-α (Chung and Hulbert, J. Appl. Mech. 60, 1993).

A step solves ``M a_{n+1−α_m} + C v_{n+1−α_f} + f_{n+1−α_f} = p(t_{n+1−α_f})``
with Newmark's relations, ``α_m``, ``α_f``, ``γ``, ``β`` from the spectral
radius ρ∞ at ``ωh → ∞``, and the internal force interpolated,
``f_{n+1−α_f} = (1 − α_f) f(u_{n+1}) + α_f f(u_n)`` (docs/algorithm.md,
"Schemes", with the decision).
"""
from __future__ import annotations

import numpy as np

from .. import checks
from .base import Scheme, affine, newmark_coefficients, stage_function

__all__ = ["GeneralizedAlpha"]


@stage_function
def generalized_alpha_stage(h, index, params):
    alpha_m, alpha_f, gamma, beta = params[0], params[1], params[2], params[3]
    ca, cv, a0, v0 = newmark_coefficients(h, gamma, beta)
    return affine(1.0, 1.0 - alpha_f, ca, cv, a0, v0, 1.0 - alpha_m, alpha_m, 1.0 - alpha_f,
                  alpha_f)


class GeneralizedAlpha(Scheme):
    """Generalized-α (Chung–Hulbert), the scheme of Abaqus, ANSYS, OpenSees and
    Code_Aster.

    Parameters
    ----------
    rho_inf : float
        The spectral radius at infinite ``ωh``, in ``[0, 1]``: 1 keeps every
        frequency (the trapezoidal rule on linear problems), 0 annihilates
        the highest in one step; default 0.8.
    """

    name = "generalized_alpha"
    order = 2
    keeps_force = True
    lagged_acceleration = True
    stage = staticmethod(generalized_alpha_stage)

    def __init__(self, rho_inf: float = 0.8):
        self.rho_inf = checks.real("GeneralizedAlpha rho_inf", rho_inf, low=0.0,
                                   low_closed=True, high=1.0, high_closed=True)
        r = self.rho_inf
        self.alpha_m = (2.0 * r - 1.0) / (r + 1.0)
        self.alpha_f = r / (r + 1.0)
        # the state's a is the acceleration at t + (α_m − α_f) h
        self.acceleration_lag = self.alpha_m - self.alpha_f
        self.gamma = 0.5 - self.alpha_m + self.alpha_f
        self.beta = 0.25 * (1.0 - self.alpha_m + self.alpha_f) ** 2
        # v = γ/(βh) (u − u_n) + …
        self.velocity_gain = 2.0 * self.gamma / self.beta

    def params(self):
        return np.array([self.alpha_m, self.alpha_f, self.gamma, self.beta])

    def __repr__(self):
        return f"GeneralizedAlpha(rho_inf={self.rho_inf})"
