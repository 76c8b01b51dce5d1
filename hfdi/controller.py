"""Step-size controllers: the paper's iteration-count rule and a fixed step."""
from __future__ import annotations

import math

__all__ = ["IterationCountController", "FixedStep"]


class IterationCountController:
    """Step size from the Newton iteration count (paper Eq. 39, Section 5).

    ``h_{n+1} = h_n (N̄ / N_n)^{1/2}``, with ``N̄`` the target corrections of a
    whole step (``2 N̄`` for Bathe's two sub-steps).

    The paper writes the rule on a ratio ``μ`` that it multiplies again into
    the previous step; read literally that compounds the correction and the
    step runs away, while its tables show mean iteration counts that track
    ``N̄``. The rule is applied to the step size itself.

    A step shortened to land on an output or communication time says little
    about the size the controller proposed: when it converged within the
    target, the proposal is kept; when it needed more, the rule applies to the
    step actually taken.

    Parameters
    ----------
    target : float
        Target corrections per step.
    min_step, max_step : float
        Bounds of the proposed size.
    """

    def __init__(self, target: float, min_step: float, max_step: float):
        self.target = float(target)
        self.min_step = float(min_step)
        self.max_step = float(max_step)

    def next_step(self, h: float, proposed: float, clipped: bool, iterations: int) -> float:
        """The size proposed for the step after one of size ``h`` that took
        ``iterations`` corrections (``proposed`` was the size asked for)."""
        if clipped and iterations <= self.target:
            new = proposed
        else:
            new = h * math.sqrt(self.target / max(iterations, 1))
        return min(max(new, self.min_step), self.max_step)

    def __repr__(self):
        return f"IterationCountController(target={self.target})"


class FixedStep:
    """A constant step size (for order tests and references)."""

    def __init__(self, step: float):
        self.step = float(step)

    def next_step(self, h, proposed, clipped, iterations):
        return self.step

    def __repr__(self):
        return f"FixedStep({self.step})"
