"""The integrator's options: from the arguments of :class:`hfdi.Integrator` to a
controller, tolerances, breakpoints and initial conditions, each checked with
a message that names the argument."""
from __future__ import annotations

import copy
import math

import numpy as np

from . import checks
from .controller import (DEFAULT_RTOL, RTOL_RANGE, TOL_RANGE, Combined, Controller, ErrorControl,
                         FixedStep, IterationCount)
from .evaluation import brief
from .linsolve.sparse import DENSE_BELOW, Factorization, SingularMatrixError, combine

__all__ = ["make_controller", "newton_tolerance", "breakpoints_of", "initial_vector",
           "optional_positive", "time_value", "times", "state_scales", "fit_error_control",
           "driven_scale", "load_response_scale", "velocity_response_scale", "NEWTON_TESTS"]

#: Values of ``Integrator(newton_test=...)``.
NEWTON_TESTS = ("correction", "error")


def optional_positive(name, value):
    return None if value is None else checks.positive(name, value)


def initial_vector(name, value, n, source):
    """An initial condition as a finite float array of shape (n,)."""
    label = name if source is None else f"{name} (from {source})"
    if checks.complex_values(value):
        raise ValueError(f"{label} must be real, got complex values {value!r:.80}")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{label} must be an array of {n} finite numbers, "
                         f"got {value!r}") from None
    if arr.shape != (n,):
        raise ValueError(f"{label} must have shape ({n},) (one entry per degree of freedom), "
                         f"got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        i = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise ValueError(f"{label} must be finite, got {brief(arr)} (entry {i} is "
                         f"{float(arr[i])!r})")
    return arr


# the smallest step the default allows, in spacings of the floating-point
# times it steps between: below it t_n + h rounds to a few values only
_RESOLUTION = 64


def default_min_step(t0, t_bound) -> float:
    """The default ``min_step``: ``1e-12·max(1, |t_bound|)``, a millionth of a
    shorter span ``t_bound − t0`` (so that a run of 1e-12 s has steps), and
    never below ``_RESOLUTION`` spacings of the floating-point times at
    ``t_bound``."""
    t_end = t_bound if t_bound is not None else t0
    step = 1e-12 * max(1.0, abs(t_end))
    if t_bound is not None:
        step = min(step, 1e-6 * abs(t_bound - t0))
    return max(step, _RESOLUTION * math.ulp(max(abs(t0), abs(t_end))))


def make_controller(controller, rtol, atol, target, step, span, min_step, max_step,
                    max_halvings, first_step_trials, scheme, t0, t_bound,
                    max_steps) -> Controller:
    """The controller of the mode the arguments ask for."""
    given = {name: value for name, value in (("rtol", rtol), ("atol", atol),
                                             ("target_iterations", target),
                                             ("step", step)) if value is not None}
    if controller is not None:
        if given:
            raise ValueError(f"controller replaces rtol, atol, target_iterations and step; "
                             f"got controller and {', '.join(given)}")
        if not isinstance(controller, Controller):
            raise TypeError(f"controller must be a hfdi.controller.Controller, got "
                            f"{type(controller).__name__}")
        missing = [name for name in ("init", "adapt")
                   if getattr(type(controller), name) is getattr(Controller, name)]
        if missing:
            raise TypeError(f"controller {type(controller).__name__} must define "
                            f"{' and '.join(missing)} (see hfdi.controller)")
        # its own copy: prepare() fits it to this system and scheme, and
        # the caller's object stays usable for another integrator
        return copy.deepcopy(controller)
    if step is not None and len(given) > 1:
        others = ", ".join(f"{name}={value!r}" for name, value in given.items()
                           if name != "step")
        raise ValueError(f"step (the fixed-step mode) excludes rtol, atol and "
                         f"target_iterations, got step={step!r} and {others}")
    if atol is not None and rtol is None and target is not None:
        raise ValueError("atol needs error control: give rtol too (with target_iterations "
                         "for the combined mode)")
    given_max = max_step
    max_step = optional_positive("max_step", max_step) \
        or (span if span is not None else math.inf)
    default_min = min_step is None
    min_step = optional_positive("min_step", min_step) \
        or default_min_step(t0, t_bound)
    if min_step >= max_step:
        hint = ""
        if default_min and span is not None and min_step >= span:
            hint = (f" (the default: t0 = {t0!r} and t_bound = {t_bound!r} are within "
                    f"{_RESOLUTION:g} floating-point spacings of each other, too close "
                    f"to step between)")
        elif default_min:
            hint = " (the default; give min_step for so small a max_step)"
        raise ValueError(f"min_step must be < max_step = {max_step}, got {min_step}{hint}")
    if step is None and given_max is not None and span is not None and \
            span / max_step > max_steps * (1.0 + 1e-9):
        # the run could only end at MAX_STEPS, after all of them
        raise ValueError(f"max_step = {given_max!r} needs at least {math.ceil(span / max_step)} "
                         f"steps from t0 = {t0:g} to t_bound = {t_bound:g}, more than "
                         f"max_steps = {max_steps}; allowed: max_step >= "
                         f"{span / max_steps:.6g}, or a larger max_steps")
    limits = dict(min_step=min_step, max_step=max_step, max_rejections=max_halvings,
                  first_step_trials=first_step_trials)
    if step is not None:
        h = checks.positive("step", step)
        # in the fixed-step mode every step is h: a bound it breaks is a contradiction
        if not default_min and h < min_step:
            raise ValueError(f"step = {step!r} is below min_step = {min_step!r}; in the "
                             f"fixed-step mode every step is step (allowed: step >= "
                             f"min_step, or leave min_step out)")
        if given_max is not None and h > max_step:
            raise ValueError(f"step = {step!r} exceeds max_step = {max_step!r}; in the "
                             f"fixed-step mode every step is step (allowed: step <= "
                             f"max_step, or leave max_step out)")
        if span is not None and span / h > max_steps * (1.0 + 1e-9):
            needs = span / h            # inf for a step near the smallest float
            count = math.ceil(needs) if math.isfinite(needs) else "more than 1e308"
            raise ValueError(f"step = {step!r} needs {count} steps from t0 = "
                             f"{t0:g} to t_bound = {t_bound:g}, more than "
                             f"max_steps = {max_steps}; allowed: step >= "
                             f"{span / max_steps:.6g}")
        return FixedStep(h, **limits)
    iteration = None if target is None else \
        IterationCount(target, scheme.n_stages, **limits)
    if iteration is not None and rtol is None:
        return iteration
    error = ErrorControl(DEFAULT_RTOL if rtol is None else rtol, atol, order=scheme.order,
                         **limits)
    return error if iteration is None else Combined(iteration, error)


#: The smallest scale of the default atol: ``1e-3·rtol`` of it is a normal
#: number at the smallest ``rtol``.
_SMALLEST_SCALE = float(np.finfo(float).tiny) / (1e-3 * RTOL_RANGE[0])


def state_scales(u0, v0, u_scale, span, driven_scale=None):
    """``(U, V)``, the scales of ``u`` and ``v`` of the default ``atol``:
    ``U = ‖u0‖∞``; for a model starting at ``u0 = 0`` the model's declared
    ``u_scale`` (``None``: none), else ``driven_scale``, the displacement its
    load and its initial velocity drive (:func:`load_response_scale`,
    :func:`velocity_response_scale`), else 1; ``V = max(‖v0‖∞, U/τ)`` with
    ``τ`` the run's span (one length per span: the slowest motion the run
    can show), or ``max(‖v0‖∞, U)`` (per unit of time) when the span is not
    known."""
    # the first scale whose atol (1e-3·rtol of it, at the smallest rtol) is a
    # normal number: a subnormal u0 or v0 gave atol 0, and no first step passed
    U = next(float(scale) for scale in (np.max(np.abs(u0), initial=0.0), u_scale or 0.0,
                                        driven_scale or 0.0, 1.0)
             if scale >= _SMALLEST_SCALE)
    V = max(float(np.max(np.abs(v0), initial=0.0)), U / span if span else U)
    return U, V


#: Times in the span where the load is sampled for :func:`load_response_scale`.
LOAD_SAMPLES = 17


def load_response_scale(ev, K0, t0, span) -> float | None:
    """The displacement the model's own load drives from rest: the largest
    ``|x|`` of ``(K + 2M/τ²) x = p(t)`` over :data:`LOAD_SAMPLES` times of
    the span ``τ`` of the error control (at ``t0`` alone, ``τ = 1``, when it
    is not known), ``K = K(u0)``: the static deflection of the stiff modes,
    the free flight ``p τ²/(2M)`` of the soft ones. The whole matrices, not
    their diagonals: where stiff springs couple the degrees of freedom, the
    diagonal is the stiff modes' and the slow mode's deflection is orders of
    magnitude larger (docs/algorithm.md, "Tolerance proportionality").
    No larger than the free flight ``‖p‖₂ τ²/(2 λ_min(M))`` (the bound for a
    positive semi-definite ``K``; an indefinite one may make the matrix
    singular), and the diagonal's ``p_i/(|K_ii| + 2M_ii/τ²)`` where the
    solve fails or no positive bound of ``λ_min(M)`` is known (a sparse ``M``
    that Gershgorin's bound cannot certify). ``None`` without a load. The
    model's load only, not an ``extra_load`` (an FMU's inputs: the scale is
    the model's); samples where it cannot be evaluated or is not a finite
    (N,) vector are left out."""
    times = [t0] if span is None else np.linspace(t0, t0 + span, LOAD_SAMPLES)
    loads = []
    for t in times:
        try:
            value = np.asarray(ev.system.load(float(t)), dtype=float)
        except Exception:           # a load that fails later fails in the run
            continue
        if value.shape == (ev.n,) and np.all(np.isfinite(value)) and value.any():
            loads.append(value)
    if not loads:
        return None
    P = np.column_stack(loads)
    tau = span if span is not None else 1.0
    shift = 2.0 / (tau * tau) if tau * tau > 0.0 else math.inf
    floor = ev.mass_floor()
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # without a positive bound of λ_min(M) nothing bounds the solve's
        # answer (K may cancel 2M/τ²): the diagonal's
        response = _static_response(ev, K0, shift, P) if floor > 0.0 else None
        if response is None:
            stiffness = np.abs(_diagonal(K0))
            response = np.abs(P).max(axis=1) / (stiffness + shift * ev.mass_diagonal)
        response = response[np.isfinite(response)]
        scale = float(response.max(initial=0.0))
        if floor > 0.0:
            scale = min(scale, float(np.linalg.norm(P, axis=0).max()) / (shift * floor))
    return scale if scale > 0.0 else None


def _static_response(ev, K0, shift, P):
    """``|x|`` (N,), the largest over the columns of ``(K0 + shift M) X = P``;
    ``None`` where the matrix is singular or the solve not finite."""
    try:
        X = Factorization(combine((1.0, K0), (shift, ev.mass))).solve(P)
    except SingularMatrixError:
        return None
    return np.abs(X).max(axis=1) if np.all(np.isfinite(X)) else None


def _diagonal(A) -> np.ndarray:
    """The diagonal (N,) of ``A``: a diagonal vector, a dense or a sparse matrix."""
    return A if A.ndim == 1 else np.asarray(A.diagonal()).ravel()


def fit_error_control(controller, span, u0, v0, u_scale, driven_scale=None):
    """Give the error rule(s) of ``controller`` the run's span and the state's
    scales (:meth:`hfdi.controller.ErrorControl.fit_run`)."""
    for part in (controller, getattr(controller, "error", None)):
        if isinstance(part, ErrorControl):
            part.fit_run(span, *state_scales(u0, v0, u_scale, span, driven_scale))


def driven_scale(ev, K0, t0, v0, span) -> float | None:
    """The displacement that the load and the initial velocity of a model at
    rest drive: the larger of :func:`load_response_scale` and
    :func:`velocity_response_scale` (``None`` when neither drives any)."""
    scales = [scale for scale in (load_response_scale(ev, K0, t0, span),
                                  velocity_response_scale(ev, K0, v0, span))
              if scale is not None]
    return max(scales) if scales else None


def velocity_response_scale(ev, K0, v0, span) -> float | None:
    """The displacement that the initial velocity ``v0`` drives from ``u0 =
    0``: mode by mode of ``K0 φ = λ M φ`` (the symmetric part of ``K0``),
    the modal velocity ``φᵀ M v0`` over ``√(|λ| + c² + 1/τ²)`` (``c =
    φᵀ C φ``, the mode's damping; ``τ`` the span of the error control, 1
    when it is not known): the amplitude ``v0/ω`` of a stiff mode, ``v0·m/c``
    of an overdamped one, the flight ``v0·τ`` over the span of a free one;
    ``U`` the largest ``Σ_k |φ_ik|·amplitude_k``. Where ``M`` is not dense-able
    (``N ≥`` :data:`hfdi.linsolve.sparse.DENSE_BELOW`) or not positive definite,
    the diagonal's ``|v0_i|/√(|K_ii|/M_ii + (C_ii/M_ii)² + 1/τ²)``, which
    can only be smaller where springs couple the degrees of freedom (a
    tighter ``atol``, never a looser one). ``None`` for ``v0 = 0``."""
    v0 = np.asarray(v0, dtype=float)
    if not np.any(v0):
        return None
    tau = span if span is not None else 1.0
    with np.errstate(all="ignore"):
        scale = _modal_velocity_response(ev, K0, v0, tau) if ev.n < DENSE_BELOW else None
        if scale is None:
            mass, stiffness = ev.mass_diagonal, np.abs(_diagonal(K0))
            damping = 0.0 if ev.damping is None else np.abs(_diagonal(ev.damping))
            rate = np.hypot(np.sqrt(stiffness / mass), damping / mass)
            response = np.abs(v0) * tau / np.hypot(1.0, tau * rate)
            response = response[np.isfinite(response)]
            scale = float(response.max(initial=0.0))
    return scale if scale > 0.0 else None


def _modal_velocity_response(ev, K0, v0, tau):
    """:func:`velocity_response_scale` through the modes; ``None`` where ``M``
    is not positive definite or the modes are not finite."""
    n = ev.n
    # each as a dense (n, n) array (a diagonal vector, a sparse matrix or none)
    M, K, C = (combine((1.0, np.zeros((n, n))), (1.0, A)) for A in (ev.mass, K0, ev.damping))
    try:
        L = np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return None
    # K φ = λ M φ as L⁻¹ K L⁻ᵀ y = λ y, φ = L⁻ᵀ y (mass-normalised)
    A = np.linalg.solve(L, np.linalg.solve(L, 0.5 * (K + K.T)).T)
    if not np.all(np.isfinite(A)):
        return None
    lam, Y = np.linalg.eigh(0.5 * (A + A.T))
    Phi = np.linalg.solve(L.T, Y)
    modal_velocity = Y.T @ (L.T @ v0)
    modal_damping = np.einsum("ik,ij,jk->k", Phi, C, Phi)
    # |q̇|/√(|λ| + c² + 1/τ²) without forming 1/τ² (a span of 1e-200 made it 1/0)
    rate = np.hypot(np.sqrt(np.abs(lam)), modal_damping)
    amplitude = np.abs(modal_velocity) * tau / np.hypot(1.0, tau * rate)
    response = np.abs(Phi) @ amplitude
    return float(response.max()) if np.all(np.isfinite(response)) else None


def needs_driven_scale(controller, u0, u_scale) -> bool:
    """Whether the default ``atol`` of ``controller`` would take its scale of
    ``u`` from what drives a model at rest (:func:`state_scales`)."""
    if np.any(u0) or u_scale:
        return False
    return any(isinstance(part, ErrorControl) and part.atol is None and part.u_scale is None
               for part in (controller, getattr(controller, "error", None)))


def newton_tolerance(tol, controller):
    if tol is None:
        tol = 1e-8
        if controller.uses_error_estimate:
            rtol = getattr(controller, "error", controller).rtol
            tol = min(tol, max(1e-12, 1e-3 * float(np.min(rtol))))
    try:
        return checks.real("tol", tol, low=TOL_RANGE[0], high=TOL_RANGE[1],
                           low_closed=True)
    except ValueError:
        raise ValueError(f"tol must be in [{TOL_RANGE[0]:g}, {TOL_RANGE[1]:g}) (Newton's "
                         f"relative tolerance; below about 10ε no correction can meet it), "
                         f"got {tol!r}") from None



def breakpoints_of(system, extra):
    """The sorted load breakpoints of the model and of ``extra``."""
    own = system.load_breakpoints() if hasattr(system, "load_breakpoints") \
        else ()
    arrays = []
    for name, given in (("the model's load_breakpoints()", own), ("breakpoints", extra)):
        try:
            arrays.append(np.asarray(() if given is None else given, dtype=float).ravel())
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be an array of times, got {given!r}") from None
    times = np.concatenate(arrays)
    if not np.all(np.isfinite(times)):
        raise ValueError(f"breakpoints must be finite, got {times!r}")
    return np.unique(times)


def time_value(name, value) -> float:
    """A time given to ``step`` or ``advance`` as a float (``inf`` allowed:
    the callers say what range they take); a ``ValueError`` naming it for
    anything that is not one real number."""
    if isinstance(value, (bool, np.bool_, str, bytes)) or checks.complex_values(value) \
            or np.ndim(value) != 0:
        raise ValueError(f"{name} must be a real number (a time), got {value!r:.80}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number (a time), got {value!r:.80}") from None


def times(name, value, t0, t_end):
    """``value`` as a finite, strictly increasing float array inside ``[t0, t_end]``."""
    times = checks.real_array(value)
    if times is None:
        raise ValueError(f"{name} must be an array of real times in [t0, t_end], "
                         f"got {value!r:.80}")
    if times.ndim > 1:
        raise ValueError(f"{name} must be a 1-D array of times, got shape {times.shape}")
    times = times.ravel()
    if not np.all(np.isfinite(times)):
        i = int(np.flatnonzero(~np.isfinite(times))[0])
        raise ValueError(f"{name} must be finite, got {name}[{i}] = {float(times[i])!r}")
    if np.any(np.diff(times) <= 0):
        i = int(np.flatnonzero(np.diff(times) <= 0)[0])
        raise ValueError(f"{name} must be strictly increasing, got {name}[{i}] = "
                         f"{float(times[i])!r} followed by {name}[{i + 1}] = "
                         f"{float(times[i + 1])!r}")
    if times.size and (times[0] < t0 or times[-1] > t_end):
        raise ValueError(f"{name} must lie in [t0, t_end] = [{t0}, {t_end}], "
                         f"got [{times[0]}, {times[-1]}]")
    return times


