"""What every scheme is: :class:`Scheme`, and the decorator of stage functions."""
from __future__ import annotations

import numpy as np

from ..core.jit import entry, jitable
from ..core.state import AFFINE, MAX_STAGES, Stage

__all__ = ["Scheme", "stage_function", "affine", "newmark_coefficients"]


def stage_function(function):
    """A scheme's stage function ``(h, index, params) -> Stage``, compiled when a
    compiled run first uses it (cached on disk); Python runs call ``function``."""
    return entry(function)


class Scheme:
    """Base class of the one-step schemes.

    Attributes
    ----------
    name : str
    order : int
        Order of accuracy on smooth problems.
    stage_fractions : tuple of float
        Where each stage's unknown lies in the step, as a fraction of ``h``
        (at most :data:`~hfdi.core.state.MAX_STAGES` stages).
    velocity_gain : float
        ``h`` times the sum of the magnitudes of the coefficients with which the
        step's displacements enter its end velocity: an error ``δ`` in the
        ``u``'s reaches ``v`` as at most ``velocity_gain · δ / h`` (the error
        control's allowance for the corrector's remaining error).
    keeps_force : bool
        Whether a step needs ``f(u_n)`` of its start (kept in the state).
    lagged_acceleration : bool
        Whether the state's ``a`` is the scheme's own variable rather than the
        equation of motion's acceleration at ``t`` (generalized-α's lags it by
        ``(α_f − α_m) h``): the error estimate then takes the equation of
        motion's (docs/algorithm.md, "Error control").
    acceleration_lag : float
        Where the state's lagged ``a`` lies, as a fraction of the step after
        ``t`` (generalized-α: ``α_m − α_f``); a change of step moves it there.
    velocity_error_constant : float
        ``λ`` of the leading local error of ``v``, ``λ h^{p+1} v^{(p+1)}``,
        where the error estimate needs it: at order 3 the estimate's quartic
        has a defect in ``v`` of the same order (docs/algorithm.md,
        "Velocity"); 0 where it is of higher order (order 2). With the
        paper's quotient for ``p'`` the estimate adds the quotient's own
        ``O(h³)`` part (docs/algorithm.md, "Velocity").
    stage : numba dispatcher
        The stage function (:func:`stage_function`).
    """

    name = "scheme"
    order = 0
    stage_fractions: tuple = (1.0,)
    velocity_gain = 3.0
    keeps_force = False
    lagged_acceleration = False
    acceleration_lag = 0.0
    velocity_error_constant = 0.0
    stage = None

    @property
    def velocity_defect(self) -> float:
        """``d = 1/(24 λ)`` of the velocity estimate's factor
        (:func:`hfdi.core.estimate.velocity_history_factor`); 0 without ``λ``."""
        constant = self.velocity_error_constant
        return 1.0 / (24.0 * constant) if constant else 0.0

    @property
    def n_stages(self) -> int:
        return len(self.stage_fractions)

    def params(self) -> np.ndarray:
        """The stage function's ``params`` (float64)."""
        return np.zeros(0)

    def stages(self, h: float) -> list:
        """The coefficients of every stage of a step of size ``h`` (Python)."""
        assert self.n_stages <= MAX_STAGES
        return [self.stage.py_func(h, k, self.params()) for k in range(self.n_stages)]

    def __repr__(self):
        return f"{type(self).__name__}()"

    def __eq__(self, other):
        return type(self) is type(other) and repr(self) == repr(other)

    def __hash__(self):
        return hash(repr(self))


@jitable
def affine(time, load_time, ca, cv, a0, v0, m_new=1.0, m_old=0.0, f_new=1.0, f_old=0.0):
    """A :class:`~hfdi.core.state.Stage` affine in ``u``: ``a0`` and ``v0`` are
    each six coefficients over ``(u_n, v_n, a_n, u_1, v_1, a_1)``."""
    return Stage(AFFINE, time, load_time, ca, cv, m_new, m_old, f_new, f_old,
                 a0[0], a0[1], a0[2], a0[3], a0[4], a0[5],
                 v0[0], v0[1], v0[2], v0[3], v0[4], v0[5])


@jitable
def newmark_coefficients(h, gamma, beta):
    """``(ca, cv, a0, v0)`` of Newmark's relations (paper Eqs. 3–4) over ``h``:
    ``a = ca u + a0``, ``v = cv u + v0``, with ``a0`` and ``v0`` as coefficients
    over ``(u_n, v_n, a_n)`` (zero for the first stage's end)."""
    ca = 1.0 / (beta * h * h)
    cv = gamma / (beta * h)
    a0 = (-ca, -1.0 / (beta * h), -(0.5 / beta - 1.0), 0.0, 0.0, 0.0)
    v0 = (-cv, 1.0 - gamma / beta, h * (1.0 - 0.5 * gamma / beta), 0.0, 0.0, 0.0)
    return ca, cv, a0, v0
