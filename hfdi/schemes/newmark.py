"""Newmark's scheme, average acceleration by default (paper Eqs. 3–5)."""
from __future__ import annotations

import numpy as np

from .. import checks
from .base import Scheme, affine, newmark_coefficients, stage_function

__all__ = ["Newmark"]


@stage_function
def newmark_stage(h, index, params):
    """One stage: the equation of motion at ``t_{n+1}`` with Newmark's relations."""
    ca, cv, a0, v0 = newmark_coefficients(h, params[0], params[1])
    return affine(1.0, 1.0, ca, cv, a0, v0)


class Newmark(Scheme):
    """Newmark's scheme (paper Eqs. 3–5).

    Parameters
    ----------
    gamma, beta : float
        Newmark parameters; ``gamma = 1/2, beta = 1/4`` is the trapezoidal rule,
        second order and unconditionally stable on linear problems.
    """

    name = "newmark"
    stage = staticmethod(newmark_stage)

    def __init__(self, gamma: float = 0.5, beta: float = 0.25):
        self.gamma = checks.real("Newmark gamma", gamma, low=0.0, high=1.0, high_closed=True)
        self.beta = checks.real("Newmark beta", beta, low=0.0, high=0.5, high_closed=True)
        self.order = 2 if self.gamma == 0.5 else 1
        # v = γ/(βh) (u − u_n) + …
        self.velocity_gain = 2.0 * self.gamma / self.beta

    def params(self):
        return np.array([self.gamma, self.beta])

    def __repr__(self):
        return f"Newmark(gamma={self.gamma}, beta={self.beta})"
