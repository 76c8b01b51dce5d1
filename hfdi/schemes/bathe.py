"""Bathe's two sub-step scheme (paper Eqs. 6–10)."""
from __future__ import annotations

import numpy as np

from .. import checks
from .base import Scheme, affine, newmark_coefficients, stage_function

__all__ = ["Bathe"]


@stage_function
def bathe_stage(h, index, params):
    """Sub-step 1: the trapezoidal rule over ``γh``; sub-step 2: the three-point
    backward formula with the coefficients of Eq. 8,
    ``v = c1 u_n + c2 û + c3 u``, ``a = c1 v_n + c2 v̂ + c3 v``."""
    g = params[0]
    if index == 0:
        ca, cv, a0, v0 = newmark_coefficients(g * h, 0.5, 0.25)
        return affine(g, g, ca, cv, a0, v0)
    c1 = (1.0 - g) / (g * h)
    c2 = -1.0 / ((1.0 - g) * g * h)
    c3 = (2.0 - g) / ((1.0 - g) * h)
    # v0 = c1 u_n + c2 û; a0 = c1 v_n + c2 v̂ + c3 v0
    return affine(1.0, 1.0, c3 * c3, c3, (c3 * c1, c1, 0.0, c3 * c2, c2, 0.0),
                  (c1, 0.0, 0.0, c2, 0.0, 0.0))


class Bathe(Scheme):
    """Bathe's two sub-step scheme (paper Eqs. 6–10): the trapezoidal rule over
    ``gamma·h``, then the three-point backward formula.

    Parameters
    ----------
    gamma : float
        Sub-step ratio in (0, 1); 1/2 gives two equal sub-steps.
    """

    name = "bathe"
    order = 2
    stage = staticmethod(bathe_stage)

    def __init__(self, gamma: float = 0.5):
        self.gamma = checks.real("Bathe gamma", gamma, low=0.0, high=1.0)
        self.stage_fractions = (self.gamma, 1.0)
        # Eq. 8: v = c1 u_n + c2 û + c3 u, |c1| + |c2| + |c3| (times h)
        g = self.gamma
        self.velocity_gain = (1.0 - g) / g + 1.0 / ((1.0 - g) * g) + (2.0 - g) / (1.0 - g)

    def params(self):
        return np.array([self.gamma])

    def __repr__(self):
        return f"Bathe(gamma={self.gamma})"
