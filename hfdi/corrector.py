"""Predictor (paper Eqs. 36–37) and Newton corrector (Eqs. 35 and 38)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


from .evaluation import Evaluator, ModelError, NonFiniteError, State
from .linalg import SingularMatrixError, all_finite

__all__ = ["predict", "predict_from_rates", "local_error", "velocity_history_factor", "newton",
           "convergence_test", "solve_step", "StepOutcome", "CONSTANT_MEMORY",
           "NO_MEASUREMENT", "SHORT_STEP", "SHORT_STEP_RATE", "is_short", "fastest_rate",
           "short_step"]

#: A step shorter than this fraction of the step proposed is a *short step*:
#: a step the controller did not ask for, forced by a landing point (a
#: communication point a few rounding units past a load breakpoint or the
#: last step's end). Two things go wrong in such a step otherwise:
#:
#: - the schemes form ``a`` (and ``v``) from differences of ``u`` divided by
#:   ``h²`` (``h``): rounding in ``u`` (``ε‖u‖``) reaches them amplified by
#:   ``1/h²``; a step of 1e-15 after steps of 1e-2 changed ``a`` by a factor
#:   1e13 and ``v`` by 3 %;
#: - as the history of the extrapolations (:func:`predict`,
#:   :func:`local_error`) it amplifies rounding by ``(s/H)^4`` and ``(s/H)^2``;
#:   past a breakpoint (``H`` = 2e-17, ``s`` = 1e-4) every later attempt failed.
#:
#: A short step is therefore taken by Taylor's expansion with the acceleration
#: from the equation of motion (:func:`short_step`; by the scheme past a stiff
#: component, :data:`SHORT_STEP_RATE`) and does not become the
#: history (the step proposed after it carries over: :func:`is_short` of the
#: accepted step against it). docs/algorithm.md, "Short steps".
SHORT_STEP = 1e-3

#: Taylor's expansion is explicit: its map grows a mode of rate ``θ = ω h``
#: (velocity Verlet's map, ``‖·‖`` in the mode's energy) by 1.0001 at
#: ``θ = 0.1``, 1.13 at 1 and without bound beyond 2. A short step is taken
#: by it only where ``h (ω_max + γ_max) ≤ SHORT_STEP_RATE`` (:func:`fastest_rate`);
#: past a stiff component the proposed step does not resolve (a proposed step
#: above ``1/(SHORT_STEP·ω_max)``), the scheme takes it as an ordinary step,
#: whose rounding ``ε‖u‖/h²`` then stays below ``ε ω_max² ‖u‖ / SHORT_STEP_RATE²``.
SHORT_STEP_RATE = 0.1

_isfinite = math.isfinite
_sqrt = math.sqrt


def is_short(h: float, proposed: float) -> bool:
    """Whether a step of size ``h`` where ``proposed`` was proposed is a short
    step (see :data:`SHORT_STEP`)."""
    return h < SHORT_STEP * proposed


def fastest_rate(ev: Evaluator, u) -> float:
    """A bound of the fastest rate of the motion linearised at ``u``:
    ``ω_max + γ_max`` with ``ω_max² ≤ ‖K(u)‖_∞ / λ_min(M)`` and ``γ_max ≤
    ‖C‖_∞ / λ_min(M)`` (Gershgorin; :meth:`Evaluator.mass_floor`); ``inf``
    where ``K`` cannot be evaluated or ``M``'s bound is not positive."""
    floor = ev.mass_floor()
    if not floor > 0.0:
        return math.inf
    try:
        K = ev.stiffness(u)
    except ModelError:
        raise
    except Exception:        # the step proper meets it again and reports it
        return math.inf
    omega2 = float(np.asarray(abs(K).sum(axis=1)).max()) / floor
    rate = _sqrt(omega2) if _isfinite(omega2) else math.inf
    C = ev.damping
    if C is not None:
        rows = np.abs(C) if ev.damping_is_diagonal else np.asarray(abs(C).sum(axis=1))
        rate += float(rows.max()) / floor
    return rate


def short_step(ev: Evaluator, current: State, t_end: float, keep_force: bool) -> State:
    """A short step (see :data:`SHORT_STEP`) from ``current`` to ``t_end``:
    ``u = u_n + h v_n + h² a_n / 2``, ``a`` from the equation of motion there
    (Eq. 14, with ``v_n + h a_n``), ``v = v_n + h (a_n + a) / 2``; its errors
    are ``O(h³)``, ``SHORT_STEP³`` of the scheme's own at the proposed step.
    ``f`` is kept in the state when ``keep_force`` (HFDI)."""
    h = t_end - current.t
    u = current.u + h * current.v + (0.5 * h * h) * current.a
    p = ev.load(t_end)
    f = ev.force(u)
    a = ev.acceleration(t_end, u, current.v + h * current.a, f, p)
    v = current.v + (0.5 * h) * (current.a + a)
    return State(t_end, u, v, a, f if keep_force else None, p)


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


def predict_from_rates(current: State, previous: State, s: float):
    """The quartic ``Q`` with ``Q(0) = u_n``, ``Q'(0) = v_n``, ``Q''(0) = a_n``,
    ``Q'(−H) = v_{n−1}`` and ``Q''(−H) = a_{n−1}``, and ``Q'``, at ``s`` after ``t_n``.

    Unlike :func:`predict` it does not use ``u_{n−1}``: the history enters
    only through ``H v_{n−1}`` and ``H² a_{n−1}``, so the previous step's
    local error reaches ``Q`` one order of ``h`` smaller than it reaches
    ``P`` (see :func:`local_error`). With ``r2 = v_{n−1} − v_n + H a_n`` and
    ``r3 = a_{n−1} − a_n``: ``Q(s) = u_n + v_n s + a_n s²/2 + c3 s³ + c4 s⁴``,
    ``c3 = r2/H² + r3/(3H)``, ``c4 = (2 r2 + H r3)/(4 H³)``.

    Returns
    -------
    Q, dQ : ndarray (N,)
    """
    H = current.t - previous.t
    r2 = previous.v - current.v + H * current.a
    r3 = previous.a - current.a
    c3 = r2 / (H * H) + r3 / (3.0 * H)
    c4 = (2.0 * r2 + H * r3) / (4.0 * H ** 3)
    s2 = s * s
    Q = current.u + s * current.v + (0.5 * s2) * current.a + (s2 * s) * c3 + (s2 * s2) * c4
    dQ = current.v + s * current.a + (3.0 * s2) * c3 + (4.0 * s2 * s) * c4
    return Q, dQ


def local_error(current: State, previous: State | None, new: State, h: float,
                order: int):
    """Estimate of the local error of ``u`` and ``v`` in the step from ``current`` to ``new``.

    Milne's device: the converged state minus an extrapolation from the past
    (no extra model evaluation). The extrapolation is
    :func:`predict_from_rates`: ``Q`` is exact to ``O(h⁵)`` on a smooth
    solution, one order above HFDI's local error in ``u`` and two above
    Newmark's and Bathe's, and the previous step's error enters it at
    ``O(h^{p+2})`` only; so the estimate of ``u`` over its true local error
    tends to 1 (HFDI: 1 + O(h)) in a real run, with no correction factor.
    ``Q'`` is exact to ``O(h⁴)`` but takes ``v_{n−1}`` with weight ``O(1)``:
    the difference for ``v`` is divided by :func:`velocity_history_factor`,
    which makes it asymptotically exact for Newmark and Bathe and of the
    right order for HFDI.
    docs/algorithm.md, "Error control", says why the corrector's own
    predictor :func:`predict` is not used (its history point ``u_{n−1}``
    carries the previous error at the order of the estimate).

    Without history (the first step, and the first after a load breakpoint)
    the extrapolation is the Taylor polynomial ``u_n + h v_n + h² a_n/2``
    (and ``v_n + h a_n``), whose own error is of the order of Newmark's and
    Bathe's local error or above: the estimate then errs on the safe side.

    Parameters
    ----------
    current, previous : State
        The step's start and the state before it (``None`` without history).
    new : State
        The converged state at ``current.t + h``.
    h : float
    order : int
        Order ``p`` of the scheme.

    Returns
    -------
    ndarray (2N,)
        The estimates for ``u``, then for ``v``.
    """
    if previous is None:
        Q = current.u + h * current.v + (0.5 * h * h) * current.a
        return np.concatenate([new.u - Q, new.v - (current.v + h * current.a)])
    Q, dQ = predict_from_rates(current, previous, h)
    sigma = h / (current.t - previous.t)
    return np.concatenate([new.u - Q, (new.v - dQ) / velocity_history_factor(sigma, order)])


def velocity_history_factor(sigma: float, order: int) -> float:
    """``c_v(σ) = 1 + (3σ² + 2σ³)/σ^{p+1}``: ``v_{n+1} − Q'(h)`` over the local
    error of ``v`` in a run.

    ``v_{n−1}`` enters ``Q'(h)`` with the weight ``3σ² + 2σ³`` and carries the
    previous step's local error of ``v``, ``≈ ℓ_v/σ^{p+1}`` (docs/algorithm.md,
    "Error control"). ``c_v > 1`` for every ``σ > 0``.
    """
    return 1.0 + (3.0 + 2.0 * sigma) * sigma ** (1 - order)


#: Memory of the corrector's carried quadratic constant (docs/algorithm.md,
#: "Corrector"). A measurement replaces the constant when it is larger, else
#: the constant shrinks by this factor: the constant varies with the
#: direction of the error from step to step, and a memory of its peaks keeps
#: one small measurement from stopping the next corrections too early.
#: A Newton run that stops after one correction measures nothing; the test
#: then uses a guard, the constant divided by this factor once for every such
#: run since the last measurement: trust in an old measurement fades, and a
#: second correction, which measures again, comes back from time to time.
CONSTANT_MEMORY = 0.9

#: The carried quadratic constant and its guard before any measurement.
NO_MEASUREMENT = (math.inf, math.inf)

_EPS = float(np.finfo(float).eps)


def newton(ev: Evaluator, problem, u, tol: float, floor: float, max_iterations: int,
           memory: tuple = NO_MEASUREMENT, estimated: bool = False):
    """Newton's method on ``problem`` from the guess ``u``.

    Converged when ``‖Δu‖ ≤ tol · max(‖u‖, floor)`` (Eq. 38 with an absolute
    floor) or, with ``estimated``, also when the estimate of the error
    ``‖u − u*‖`` left after the correction is at most that bound: after the
    first correction ``G ‖Δu‖²`` with the guard ``G`` of the quadratic
    constant carried from earlier corrections (``memory``; ``inf`` when none
    was measured, and then the first correction is never enough), after later
    ones ``ρ/(1 − ρ) ‖Δu‖`` with the observed rate ``ρ`` of the last two
    (SUNDIALS' test, for quadratic convergence or not).

    Every correction after the first measures the constant,
    ``m = max(‖Δu_k‖, ε max(‖u‖, floor)) / ‖Δu_{k−1}‖²`` (a correction below
    rounding tells no more than rounding): the constant becomes
    ``max(m, CONSTANT_MEMORY · C)`` (``m`` for the first) and the guard the
    constant. A run that converges after one correction divides the guard by
    :data:`CONSTANT_MEMORY`.

    Parameters
    ----------
    memory : (float, float)
        The carried constant ``C`` and its guard ``G`` (:data:`NO_MEASUREMENT`).
    estimated : bool
        Stop on the estimated error too (``Integrator(newton_test="error")``).

    Returns
    -------
    u, corrections, converged, message, error, memory
        ``error`` the estimate of ``‖u − u*‖`` after the last correction,
        which widens the velocity's weights (docs/algorithm.md, "Error
        control"): as above, with ``C`` rather than ``G`` after one
        correction (the guard is a safety margin, not the estimate), and the
        quadratic ``‖Δu‖² / max(‖u‖, floor)`` when Eq. 38 passes at the
        first. ``memory`` the constant and guard after this run of
        corrections.
    """
    residual_and_jacobian = problem.residual_and_jacobian
    solve = ev.solve
    constant, guard = memory
    previous = math.inf
    for k in range(1, max_iterations + 1):
        residual, tangent = residual_and_jacobian(u)
        if not all_finite(residual):
            return u, k - 1, False, "residual is not finite", math.inf, (constant, guard)
        try:
            du = solve(tangent, -residual)
        except SingularMatrixError as exc:
            return u, k - 1, False, f"tangent is singular ({exc})", math.inf, (constant, guard)
        # ‖Δu‖² as np.linalg.norm forms it; NaN or infinity in Δu makes it
        # non-finite (an overflow too, hence the entry-wise test only then)
        du2 = du.dot(du)
        if not _isfinite(du2) and not all_finite(du):
            return u, k, False, "Newton correction is not finite", math.inf, (constant, guard)
        u = u + du
        size = _sqrt(u.dot(u))
        step = _sqrt(du2)
        done, error, constant, guard = convergence_test(step, du2, previous, max(size, floor),
                                                        tol, constant, guard, estimated)
        if done:
            return u, k, True, "", error, (constant, guard)
        previous = step
    return u, max_iterations, False, f"no convergence in N_max = {max_iterations} corrections", \
        math.inf, (constant, guard)


def convergence_test(step, du2, previous, scale, tol, constant, guard, estimated):
    """The test of :func:`newton` after one correction: ``(done, error,
    constant, guard)``.

    ``step = ‖Δu‖`` and ``du2 = ‖Δu‖²`` of the correction, ``previous`` the
    correction before it (``inf`` after the first), ``scale = max(‖u‖,
    floor)``; ``error`` is ``inf`` when not done. Plain arithmetic on numbers:
    the compiled attempt compiles this same function
    (:mod:`hfdi.compiled.attempt`), so that both paths test alike.
    """
    bound = tol * scale
    # a correction larger than the bound is > 0, so previous > 0 here
    if previous < math.inf:
        measured = max(step, _EPS * scale) / (previous * previous)
        constant = measured if constant == math.inf else max(measured, CONSTANT_MEMORY * constant)
        guard = constant
        rate = step / previous
        error = step * rate / (1.0 - rate) if rate < 1.0 else step
        estimate_passes = estimated and rate < 1.0 and error <= bound
    else:
        # Eq. 38's own estimate when it passes, else the carried constant's
        error = du2 / scale
        estimate_passes = estimated and step > bound and guard * du2 <= bound
        if estimate_passes:
            error = constant * du2
    if step <= bound or estimate_passes:
        if previous == math.inf:
            guard = guard / CONSTANT_MEMORY
        return True, error, constant, guard
    return False, math.inf, constant, guard


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
    newton_error : float
        The largest estimate over the stages of the error the corrector left
        in ``u`` (see :func:`newton`).
    newton_memory : (float, float)
        The corrector's carried quadratic constant and its guard after the
        attempt (see :func:`newton`).
    """

    state: State | None
    iterations: list
    message: str = ""
    stages: list = field(default_factory=list)
    newton_error: float = 0.0
    newton_memory: tuple = NO_MEASUREMENT

    @property
    def converged(self) -> bool:
        return self.state is not None

    @property
    def total_iterations(self) -> int:
        return int(sum(self.iterations))


def solve_step(ev: Evaluator, scheme, start: State, t_end: float, predictor,
               tol: float, floor: float, max_iterations: int,
               memory: tuple = NO_MEASUREMENT, estimated: bool = False) -> StepOutcome:
    """One attempt at the step ``start.t → t_end``: every stage, predictor then Newton.

    ``predictor(s)`` gives the initial guess a time ``s`` after ``start.t``.
    ``tol``, ``floor``, ``max_iterations``, ``memory`` and ``estimated`` are
    :func:`newton`'s; the memory passes from stage to stage.
    A non-finite value or an exception raised by the model fails the attempt
    with its message, like a diverged corrector: a shorter step may avoid the
    state where the model fails. A wrong shape (:class:`ModelError`) is a
    mistake in the model that no step size cures, and is raised.
    """
    h = t_end - start.t
    done = []
    iterations = []
    newton_error = 0.0
    try:
        for index, fraction in enumerate(scheme.stage_fractions):
            problem = scheme.stage(ev, start, t_end, index, done)
            u, k, ok, message, error, memory = newton(
                ev, problem, predictor(fraction * h), tol, floor, max_iterations, memory,
                estimated)
            iterations.append(k)
            newton_error = max(newton_error, error)
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
    return StepOutcome(done[-1], iterations, stages=done[:-1], newton_error=newton_error,
                       newton_memory=memory)
