"""Predictor (paper Eqs. 36–37) and Newton corrector (Eqs. 35 and 38)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field


from .evaluation import Evaluator, ModelError, NonFiniteError, State
from .linalg import SingularMatrixError, all_finite

__all__ = ["predict", "newton", "solve_step", "StepOutcome"]

_isfinite = math.isfinite
_sqrt = math.sqrt


def predict(current: State, previous: State | None, s: float):
    """Extrapolated displacement ``s`` after ``current.t`` (Eqs. 36–37).

    Without history (the first step) this is ``u_n + s v_n``. Otherwise it is
    the quartic ``P`` with ``P(−H) = u_{n−1}``, ``P'(−H) = v_{n−1}``,
    ``P(0) = u_n``, ``P'(0) = v_n``, ``P''(0) = a_n``, ``H = t_n − t_{n−1}``:
    ``P(s) = u_n + v_n s + a_n s²/2 + x σ³ + y σ⁴`` with ``σ = s/H`` and
    ``x = −4 r1 − H r2``, ``y = −3 r1 − H r2`` from the residuals
    ``r1 = u_{n−1} − u_n + H v_n − H² a_n/2`` and ``r2 = v_{n−1} − v_n + H a_n``.
    """
    u, v = current.u, current.v
    if previous is None:
        return u + s * v
    a = current.a
    H = current.t - previous.t
    r1 = previous.u - u + H * v - (0.5 * H * H) * a
    r2 = previous.v - v + H * a
    sigma = s / H
    s3, s4 = sigma ** 3, sigma ** 4
    return u + s * v + (0.5 * s * s) * a - (4.0 * s3 + 3.0 * s4) * r1 - (H * (s3 + s4)) * r2


def newton(ev: Evaluator, problem, u, tol: float, floor: float, max_iterations: int):
    """Newton's method on ``problem`` from the guess ``u``.

    Converged when ``‖Δu‖ ≤ tol · max(‖u‖, floor)`` (Eq. 38 with an absolute
    floor). Returns ``(u, corrections, converged, message)``.
    """
    residual_and_jacobian = problem.residual_and_jacobian
    solve = ev.solve
    for k in range(1, max_iterations + 1):
        residual, tangent = residual_and_jacobian(u)
        if not all_finite(residual):
            return u, k - 1, False, "residual is not finite"
        try:
            du = solve(tangent, -residual)
        except SingularMatrixError as exc:
            return u, k - 1, False, f"tangent is singular ({exc})"
        # ‖Δu‖² as np.linalg.norm forms it; NaN or infinity in Δu makes it
        # non-finite (an overflow too, hence the entry-wise test only then)
        du2 = du.dot(du)
        if not _isfinite(du2) and not all_finite(du):
            return u, k, False, "Newton correction is not finite"
        u = u + du
        if _sqrt(du2) <= tol * max(_sqrt(u.dot(u)), floor):
            return u, k, True, ""
    return u, max_iterations, False, f"no convergence in N_max = {max_iterations} corrections"


@dataclass
class StepOutcome:
    """What one attempt at a step gave.

    Attributes
    ----------
    state : State or None
        End state, ``None`` if the attempt failed.
    iterations : list of int
        Newton corrections per stage (summed, they are the step's ``N``).
    message : str
        Why the attempt failed (empty on success).
    stages : list of State
        End states of the stages before the last (Bathe's mid-step state).
    """

    state: State | None
    iterations: list
    message: str = ""
    stages: list = field(default_factory=list)

    @property
    def converged(self) -> bool:
        return self.state is not None

    @property
    def total_iterations(self) -> int:
        return int(sum(self.iterations))


def solve_step(ev: Evaluator, scheme, start: State, t_end: float, predictor,
               tol: float, floor: float, max_iterations: int) -> StepOutcome:
    """One attempt at the step ``start.t → t_end``: every stage, predictor then Newton.

    ``predictor(s)`` gives the initial guess a time ``s`` after ``start.t``.
    A non-finite value or an exception raised by the model fails the attempt
    with its message, like a diverged corrector: a shorter step may avoid the
    state where the model fails. A wrong shape (:class:`ModelError`) is a
    mistake in the model that no step size cures, and is raised.
    """
    h = t_end - start.t
    done = []
    iterations = []
    try:
        for index, fraction in enumerate(scheme.stage_fractions):
            problem = scheme.stage(ev, start, t_end, index, done)
            u, k, ok, message = newton(ev, problem, predictor(fraction * h), tol, floor,
                                       max_iterations)
            iterations.append(k)
            if not ok:
                stage = f" (sub-step {index + 1})" if scheme.n_stages > 1 else ""
                return StepOutcome(None, iterations, message + stage)
            end = problem.finish(u)
            if not (all_finite(end.u) and all_finite(end.v)
                    and all_finite(end.a)):
                return StepOutcome(None, iterations, "end-of-step state is not finite")
            done.append(end)
    except ModelError:
        raise
    except NonFiniteError as exc:
        return StepOutcome(None, iterations, str(exc))
    except Exception as exc:  # the model failed at some state: treat as a failed attempt
        return StepOutcome(None, iterations, f"model raised {type(exc).__name__}: {exc}")
    return StepOutcome(done[-1], iterations, stages=done[:-1])
