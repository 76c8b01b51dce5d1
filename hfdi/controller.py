"""Step-size controllers: small objects that choose the first step and judge every attempt.

A controller has two methods, in the manner of diffrax's:

``init(trial, h0) -> (attempt, decision)``
    Choose the first step. ``trial(h)`` runs one attempt of size ``h`` (at
    most; it may be shortened to land on a time) from the initial state and
    returns its :class:`Attempt`; the controller returns the attempt to accept
    (or ``None``) and a :class:`Decision` with the size proposed next.
``adapt(attempt, rejections) -> decision``
    Accept or reject an attempt, propose the next size, or stop the run with a
    failed status. ``rejections`` counts the attempts already rejected for
    this step.

The integrator is the loop; the rules are here: :class:`IterationCount` (the
paper's Eq. 39), :class:`ErrorControl`, :class:`Combined` (both) and
:class:`FixedStep` (docs/algorithm.md, "Step-size control" and "Error control").
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np

from . import checks
from .core import control
from .core.estimate import default_atol, error_fraction, first_step_atol, weighted_rms
from .core.state import COMBINED, CONFIG, CUSTOM, ERROR, FIXED, ITERATION, RUN

__all__ = ["Attempt", "Decision", "Controller", "IterationCount", "ErrorControl", "Combined",
           "FixedStep", "IterationCountController", "TARGET_ITERATIONS_RANGE",
           "DEFAULT_RTOL", "RTOL_RANGE"]

#: Allowed target Newton corrections per (sub-)step. Above 100 the corrector's
#: ``N_max = 2 N̄`` no longer bounds the work of a diverging attempt usefully.
TARGET_ITERATIONS_RANGE = (1.0, 100.0)
#: The relative tolerance of the error-controlled mode when none is given.
DEFAULT_RTOL = 1e-4
#: Allowed relative tolerances: above 0.1 the estimate's asymptotics mean
#: nothing; below 1e-13 rounding errors of the step dominate the estimate.
RTOL_RANGE = (1e-13, 0.1)
#: Allowed Newton tolerances ``tol`` (relative): below ten machine epsilons
#: no correction can meet one.
TOL_RANGE = (10.0 * float(np.finfo(float).eps), 1.0)


@dataclass
class Attempt:
    """One attempt at a step, as the integrator hands it to a controller.

    Attributes
    ----------
    h : float
        The size taken.
    proposed : float
        The size the controller had proposed (``h`` differs when the step
        was shortened to land on a time).
    clipped : bool
        Whether the step was shortened (or stretched a little) to land.
    converged : bool
        Whether every stage's corrector converged.
    iterations : int
        Newton corrections of the attempt (all stages).
    message : str
        Why the corrector failed (empty when it converged).
    error : ndarray (2N,) or None
        Local error estimate of ``u`` and ``v`` (only for controllers with
        ``uses_error_estimate``, and only when converged).
    history : bool
        Whether the estimate had the predictor's history (``False`` on the
        first step and after a load breakpoint).
    first : bool
        Whether the attempt is a trial of the run's first step.
    y_start, y_end : ndarray (2N,) or None
        ``(u, v)`` at the start and end of the attempt (with ``error``).
    velocity_noise : float
        The uncertainty of ``v`` left by the corrector's tolerance, added to
        the weights of ``v`` so that it never drives the step down.
    displacement_noise : float
        The uncertainty of ``u`` likewise, added to the weights of ``u``.
    elapsed : float
        The time from the run's start to the attempt's end (NaN: unknown).
    accepted : int
        The steps the run accepted before the attempt.
    """

    h: float
    proposed: float
    clipped: bool
    converged: bool
    iterations: int
    message: str = ""
    error: np.ndarray | None = None
    history: bool = True
    first: bool = False
    y_start: np.ndarray | None = None
    y_end: np.ndarray | None = None
    velocity_noise: float = 0.0
    displacement_noise: float = 0.0
    elapsed: float = math.nan
    accepted: int = 0


@dataclass
class Decision:
    """A controller's verdict on an attempt.

    ``status`` is ``None`` unless the run must stop; it is then the name of a
    failed :class:`~hfdi.Status` and ``message`` says why.
    """

    accept: bool
    next_step: float
    status: str | None = None
    message: str = ""


class Controller:
    """Base class: see the module's docstring for the protocol.

    Attributes
    ----------
    uses_error_estimate : bool
        Whether attempts must carry the local error estimate.
    target : float or None
        Target Newton corrections per step (the iteration-count rule only).
    max_iterations : int
        Default ``N_max``: corrections allowed per (sub-)step before the
        corrector counts as diverged.
    min_step, max_step : float
    max_rejections : int
        Consecutive rejected attempts allowed for one step.
    first_step_trials : int
        Attempts allowed to choose the first step.
    """

    uses_error_estimate = False
    target = None
    max_iterations = 50

    def __init__(self, min_step=None, max_step=None, max_rejections=30, first_step_trials=40):
        self.min_step = 0.0 if min_step is None else checks.positive("min_step", min_step)
        self.max_step = math.inf if max_step is None or max_step == math.inf else \
            checks.positive("max_step", max_step)
        if self.min_step >= self.max_step:
            raise ValueError(f"min_step must be < max_step = {self.max_step}, got "
                             f"{self.min_step}")
        self.max_rejections = checks.integer("max_halvings", max_rejections, 0)
        self.first_step_trials = checks.integer("first_step_trials", first_step_trials, 1)

    def init(self, trial, h0: float):
        raise NotImplementedError(f"{type(self).__name__} must define init(trial, h0) -> "
                                  f"(attempt, decision): see hfdi.controller")

    def adapt(self, attempt: Attempt, rejections: int) -> Decision:
        raise NotImplementedError(f"{type(self).__name__} must define adapt(attempt, "
                                  f"rejections) -> Decision: see hfdi.controller")

    def prepare(self, n: int, order: int) -> None:
        """Fit the controller to a system of ``n`` degrees of freedom and a
        scheme of order ``order``; the integrator calls it on its own copy,
        before the first step. Refuses what does not fit (``ValueError``)."""

    #: The kind the core's rules know this controller by (``CUSTOM``: none).
    kind = CUSTOM

    def landing(self, h: float, remaining: float) -> float:
        """The size to take when ``remaining`` is left to the next time to reach
        and ``h`` is proposed (docs/algorithm.md, "Landing without slivers")."""
        return control.landing(self.config(), h, remaining)

    def settings(self) -> dict:
        """The ``CONFIG`` fields of this controller (:mod:`hfdi.core.state`)."""
        return dict(controller=self.kind, min_step=self.min_step, max_step=self.max_step,
                    first_step_trials=self.first_step_trials)

    def config(self):
        """A ``CONFIG`` record with this controller's settings, for the core's rules."""
        cached = self.__dict__.get("_config")
        if cached is None:
            cached = self.__dict__["_config"] = CONFIG.new(**self.settings())
        return cached

    def _decision(self, attempt, accepted, h_next, stop, why):
        """A :class:`Decision` from a core rule's verdict (``stop``: its guard)."""
        if stop == control.STOP_NONE:
            return Decision(accepted, h_next)
        tried = f"h = {attempt.h:.6g}"
        if stop == control.STOP_HALVINGS:
            what = f"diverged after {self.max_rejections} halvings" if not attempt.converged \
                else f"rejected {self.max_rejections} times in a row"
            return Decision(False, h_next, "HALVINGS_EXHAUSTED",
                            f"step {what} (last attempt {tried}): {why}")
        return Decision(False, h_next, "STEP_BELOW_MINIMUM",
                        f"step {h_next:.6g} below min_step = {self.min_step:.6g} after "
                        f"the attempt with {tried} was rejected: {why}")


class FixedStep(Controller):
    """A constant step size (for order tests and references), landing on the
    grid ``t_a + k·step`` (docs/algorithm.md, "Landing without slivers")."""

    kind = FIXED

    def __init__(self, step: float, **limits):
        self.step = checks.positive("step", step)
        super().__init__(**limits)

    def settings(self):
        return {**super().settings(), "fixed_step": self.step}

    def init(self, trial, h0):
        attempt = trial(self.step)
        return (attempt if attempt.converged else None), self.adapt(attempt, 0)

    def adapt(self, attempt, rejections):
        if attempt.converged:
            return Decision(True, self.step)
        return Decision(False, self.step, "NEWTON_FAILED",
                        f"corrector failed with fixed step {attempt.h:.6g}: {attempt.message}")

    def __repr__(self):
        return f"FixedStep({self.step})"


class IterationCount(Controller):
    """Step size from the Newton iteration count (paper Eq. 39, Section 5).

    ``h_{n+1} = h_n (N̄ / N_n)^{1/2}``, with ``N̄`` the target corrections of a
    whole step (``2 N̄`` for Bathe's two sub-steps): it controls the work per
    step, not the error (docs/algorithm.md, "Step-size control"). The rules
    are :func:`hfdi.core.control.iteration_adapt` and
    :func:`~hfdi.core.control.iteration_search`.

    Parameters
    ----------
    target : float
        Target corrections per step, in :data:`TARGET_ITERATIONS_RANGE` per
        stage.
    n_stages : int
        Stages of the scheme (2 for Bathe): the step's target is
        ``n_stages · target``.
    """

    kind = ITERATION

    def __init__(self, target: float, n_stages: int = 1, **limits):
        low, high = TARGET_ITERATIONS_RANGE
        try:
            target = checks.real("target_iterations", target, low=low, low_closed=True,
                                 high=high, high_closed=True)
        except ValueError:
            raise ValueError(f"target_iterations must be a finite number in [{low:g}, {high:g}] "
                             f"(Newton corrections per step), got {target!r}") from None
        self.per_stage = target
        self.target = target * n_stages
        self.max_iterations = max(1, int(math.floor(2.0 * target)))
        super().__init__(**limits)

    def settings(self):
        return {**super().settings(), "target": self.target, "it_min_step": self.min_step,
                "it_max_step": self.max_step, "it_max_rejections": self.max_rejections}

    def adapt(self, attempt, rejections):
        accepted, h_next, stop = control.iteration_adapt(
            self.config(), attempt.h, attempt.proposed, attempt.clipped, attempt.converged,
            attempt.iterations, rejections)
        return self._decision(attempt, accepted, h_next, stop, attempt.message)

    def init(self, trial, h0):
        """``Δt₀`` such that the first step converges in ``N̄`` iterations
        (Section 5), by :func:`hfdi.core.control.iteration_search`."""
        search = RUN.new(search_low=math.nan, search_high=math.nan, search_best=math.inf)
        h, best, message, smallest, trials = h0, None, "", math.inf, 0
        for _ in range(self.first_step_trials):
            attempt = trial(h)
            if attempt is None:            # below the resolution of time at t
                break
            trials += 1
            smallest = min(smallest, attempt.h)
            if not attempt.converged:
                message = attempt.message
            better, done, h = control.iteration_search(self.config(), search, attempt.converged,
                                                       attempt.iterations, attempt.h,
                                                       attempt.clipped)
            if better:
                best = attempt
            if done:
                break
        if best is None:
            return None, Decision(False, h, "FIRST_STEP_FAILED",
                                  f"no first step converged in {trials} trials down to h = "
                                  f"{smallest:.6g}: {message}")
        return best, self.adapt(best, 0)

    def __repr__(self):
        return f"IterationCount(target={self.per_stage})"


#: The former name of :class:`IterationCount`.
IterationCountController = IterationCount


class ErrorControl(Controller):
    """Step size from the local error estimate (docs/algorithm.md, "Error
    control" and "Tolerance proportionality").

    ``err = ‖e / ((atol + rtol·max(|y_n|, |y_{n+1}|))·h̄/τ)‖_RMS`` over the
    first-order state ``y = (u, v)``, weighed as IDA and ``solve_ivp`` weigh
    it, but each step may spend only the share ``h̄/τ`` of the tolerance
    (``h̄`` the run's mean step so far, ``τ`` its span), so that the local
    errors of the whole run add up to about the tolerance and the error of
    the answer follows ``rtol``. ``e`` is
    :func:`~hfdi.core.estimate.local_error`. An attempt with ``err ≤ 1`` is
    accepted; otherwise it is retried. The next size is
    ``h · safety · err^{−1/(p+1)}``, limited to ``[shrink, grow]·h`` (and to
    at most ``h`` right after a rejection). A diverged corrector halves the
    step. With ``per_step=True`` the rule is IDA's and ``solve_ivp``'s: the
    share is 1, and the error accumulates over the run as
    ``rtol^{p/(p+1)}``.

    Parameters
    ----------
    rtol : float or array_like (N,) or (2N,)
        Relative tolerance, in :data:`RTOL_RANGE`. A scalar or an (N,) array
        applies to ``u`` and ``v`` alike; a (2N,) array gives ``u``'s, then
        ``v``'s.
    atol : float or array_like (N,) or (2N,), optional
        Absolute tolerance, ``> 0``, laid out as ``rtol``; in the units of
        ``u`` (and of ``v`` for the second half of a (2N,) array). An
        infinite entry leaves its component uncontrolled (not every entry):
        ``inf`` for ``v``'s half controls the error of ``u`` alone
        (docs/accuracy.md, "Controlling u alone"). Default
        ``1e-3 · min(rtol) · (U, V)``, ``U`` and ``V`` the scales of ``u``
        and ``v`` (:func:`hfdi.options.state_scales`); an integrator fills
        it in from its model.
    u_scale, v_scale : float, optional
        The scales ``U`` and ``V`` of the default ``atol`` when the
        controller is used without an integrator (1).
    order : int, optional
        Order ``p`` of the scheme; by default the order of the scheme of the
        integrator that uses the controller.
    per_step : bool
        Bound the error per step (IDA's rule) instead of at a share of the
        tolerance.
    span : float, optional
        ``τ``, the time the error may accumulate over. Default: the run's
        ``t_bound − t0`` when the integrator knows it, else the time from the
        run's start to the step's end (the share is then ``1/(n + 1)`` at
        the ``n``-th step, and the local errors add up to ``rtol·ln n`` at
        most).
    safety, grow, shrink : float
        The usual factors: 0.9, 5 and 0.2.
    """

    uses_error_estimate = True
    max_iterations = 10
    kind = ERROR

    def __init__(self, rtol=DEFAULT_RTOL, atol=None, *, u_scale=None, v_scale=None,
                 order: int | None = None, per_step=False, span=None, safety=0.9, grow=5.0,
                 shrink=0.2, **limits):
        self.rtol = _tolerance("rtol", rtol, *RTOL_RANGE)
        # atol > 0: a weight atol + rtol·|u| of zero would fail every step at u = 0
        self.atol = None if atol is None else _tolerance("atol", atol, 0.0, math.inf,
                                                         open_low=True, infinite_ok=True)
        self.u_scale = None if u_scale is None else checks.positive("u_scale", u_scale)
        self.v_scale = None if v_scale is None else checks.positive("v_scale", v_scale)
        self.order = None if order is None else checks.integer("order", order, 1)
        if not isinstance(per_step, (bool, np.bool_)):
            raise ValueError(f"per_step must be True or False, got {per_step!r}")
        self.per_step = bool(per_step)
        self.span = None if span is None else checks.positive("span", span)
        self.safety = checks.real("safety", safety, low=0.0, high=1.0, high_closed=True)
        self.grow = checks.real("grow", grow, low=1.0, high=math.inf)
        self.shrink = checks.real("shrink", shrink, low=0.0, high=1.0)
        super().__init__(**limits)

    def fit_run(self, span, u_scale, v_scale):
        """Fill in what was not given from the integrator's run: the span
        ``τ`` (``None``: unknown) and the scales of the default ``atol``."""
        if self.span is None and span is not None:
            self.span = span
        if self.u_scale is None:
            self.u_scale = u_scale
        if self.v_scale is None:
            self.v_scale = v_scale
        self.__dict__.pop("_config", None)

    def prepare(self, n: int, order: int) -> None:
        """Take the scheme's order unless one was given; see :meth:`check_size`."""
        if self.order is None:
            self.order = order
        self.__dict__.pop("_config", None)
        self.check_size(n)

    def check_size(self, n: int):
        """Refuse tolerances given per degree of freedom for another size, and
        lay those given for ``u`` out over ``(u, v)``."""
        if self.atol is None:
            self.atol = default_atol(n, self.rtol, self.u_scale or 1.0, self.v_scale or 1.0)
        for name in ("rtol", "atol"):
            value = getattr(self, name)
            if np.ndim(value) and np.shape(value) not in ((n,), (2 * n,)):
                raise ValueError(f"{name} given per degree of freedom must have shape ({n},) "
                                 f"(u and v alike) or ({2 * n},) (u, then v), got "
                                 f"{np.shape(value)}")
            if np.ndim(value) and np.shape(value) == (n,):
                setattr(self, name, np.concatenate([value, value]))

    def first_atol(self, n: int) -> np.ndarray:
        """The ``atol`` (2N,) of the run's first step: :attr:`atol` with
        every component controlled (:func:`hfdi.core.estimate.first_step_atol`)."""
        return first_step_atol(np.broadcast_to(self.atol, (2 * n,)), self.rtol,
                               self.u_scale or 1.0, self.v_scale or 1.0)

    def error_norm(self, attempt: Attempt) -> float:
        """The weighted RMS norm of the attempt's error estimate
        (:func:`hfdi.core.estimate.weighted_rms`); the run's first step is
        held to :meth:`first_atol`."""
        n = attempt.y_start.size // 2
        y0, y1 = attempt.y_start, attempt.y_end
        rtol = np.broadcast_to(self.rtol, (2 * n,)).astype(float)
        atol = self.first_atol(n) if attempt.first else \
            np.broadcast_to(self.atol, (2 * n,)).astype(float)
        span = math.nan if self.span is None else self.span
        fraction = error_fraction(self.per_step, span, attempt.elapsed, attempt.accepted,
                                  attempt.history)
        return weighted_rms(attempt.error, y0[:n], y0[n:], y1[:n], y1[n:], rtol, atol,
                            attempt.displacement_noise, attempt.velocity_noise, fraction,
                            np.empty(2 * n))

    def settings(self):
        return {**super().settings(), "order": self.order or 0, "er_min_step": self.min_step,
                "er_max_step": self.max_step, "er_max_rejections": self.max_rejections,
                "safety": self.safety, "grow": self.grow, "shrink": self.shrink,
                "per_step": self.per_step,
                "error_span": math.nan if self.span is None else self.span}

    def adapt(self, attempt, rejections):
        if self.order is None:
            raise ValueError("ErrorControl has no order: give order=p, or let an integrator "
                             "fit it to its scheme (prepare)")
        err = self.error_norm(attempt) if attempt.converged else math.nan
        accepted, h_next, stop = control.error_adapt(
            self.config(), attempt.h, attempt.proposed, attempt.clipped, attempt.converged, err,
            attempt.history, rejections)
        why = attempt.message if not attempt.converged else (
            "error estimate is not finite" if not math.isfinite(err) else
            f"local error {err:.3g} times the tolerance")
        return self._decision(attempt, accepted, h_next, stop, why)

    def init(self, trial, h0):
        """The first step by the same estimate, from the Taylor predictor
        (no history): shrink ``h0`` until the estimate passes."""
        h = h0
        message = ""
        trials = 0
        for rejections in range(self.first_step_trials):
            attempt = trial(h)
            if attempt is None:
                break
            trials += 1
            decision = self.adapt(attempt, rejections)
            if decision.accept:
                return attempt, decision
            message = decision.message
            # first_step_trials bounds this loop; max_halvings is the bound
            # of a later step's rejections; min_step bounds both
            if decision.status == "HALVINGS_EXHAUSTED":
                if decision.next_step < self.min_step:
                    message = (f"step {decision.next_step:.6g} below min_step = "
                               f"{self.min_step:.6g} after the attempt with h = "
                               f"{attempt.h:.6g} was rejected")
                    break
            elif decision.status is not None:
                break
            h = decision.next_step
        return None, Decision(False, h, "FIRST_STEP_FAILED",
                              f"no first step passed the error test in {trials} trials "
                              f"down to h = {h:.6g}"
                              f"{': ' + message if message else ''}")

    def __repr__(self):
        extra = ", per_step=True" if self.per_step else \
            ("" if self.span is None else f", span={self.span!r}")
        return f"ErrorControl(rtol={_exact(self.rtol)}, atol={_exact(self.atol)}{extra})"


class Combined(Controller):
    """The iteration-count rule and the error rule together: an attempt is
    accepted when both accept it, and the smaller proposal wins."""

    uses_error_estimate = True
    kind = COMBINED

    def __init__(self, iteration: IterationCount, error: ErrorControl):
        self.iteration, self.error = iteration, error
        self.target = iteration.target
        self.max_iterations = iteration.max_iterations
        self.min_step = max(iteration.min_step, error.min_step)
        self.max_step = min(iteration.max_step, error.max_step)
        self.max_rejections = iteration.max_rejections
        self.first_step_trials = iteration.first_step_trials

    def prepare(self, n, order):
        self.iteration.prepare(n, order)
        self.error.prepare(n, order)

    def settings(self):
        return {**self.iteration.settings(), **self.error.settings(), "controller": COMBINED,
                "min_step": self.min_step, "max_step": self.max_step,
                "first_step_trials": self.first_step_trials}

    def adapt(self, attempt, rejections):
        a = self.iteration.adapt(attempt, rejections)
        b = self.error.adapt(attempt, rejections)
        if a.status is not None:
            return a
        if b.status is not None:
            return b
        return Decision(a.accept and b.accept, min(a.next_step, b.next_step))

    def init(self, trial, h0):
        attempt, decision = self.iteration.init(trial, h0)
        if attempt is None:
            return attempt, decision
        checked = self.adapt(attempt, 0)
        if checked.accept:
            return attempt, checked
        return self.error.init(trial, checked.next_step)

    def __repr__(self):
        return f"Combined({self.iteration!r}, {self.error!r})"


def core_kind(controller) -> int:
    """The kind the core's rules know ``controller`` by: a built-in controller's
    own, ``CUSTOM`` for any other (a subclass too: its methods may differ)."""
    if type(controller) is Combined:
        parts = (type(controller.iteration), type(controller.error))
        return COMBINED if parts == (IterationCount, ErrorControl) else CUSTOM
    if type(controller) in (FixedStep, IterationCount, ErrorControl):
        return controller.kind
    return CUSTOM


def _exact(value) -> str:
    """A tolerance as text that tells any two different values apart (an
    integrator refuses the state of another controller by this text): a
    float's repr, the entries of a short array, else the array's size, range
    and a digest of its bytes. numpy's own text keeps 8 digits and elides
    arrays of over 1,000 entries."""
    if np.ndim(value) == 0:
        return repr(float(value))
    values = np.ascontiguousarray(value, dtype=float)
    if values.size <= 6:
        return "[" + ", ".join(repr(x) for x in values.tolist()) + "]"
    digest = hashlib.sha256(values.tobytes()).hexdigest()[:16]
    return (f"<{values.size} values in [{float(values.min())!r}, {float(values.max())!r}], "
            f"sha256 {digest}>")


def _tolerance(name, value, low, high, open_low=False, infinite_ok=False):
    """A tolerance as a float or a 1-D float array, every entry in ``[low, high)``
    (``(low, high)`` with ``open_low``); with ``infinite_ok`` (``high``
    infinite) entries may be infinite, all but one at least: an array that
    leaves some components uncontrolled."""
    interval = f"{'(' if open_low else '['}{low:g}, {high:g}{']' if infinite_ok else ')'}"
    if isinstance(value, (str, bytes)) or np.asarray(value).dtype.kind not in "iuf":
        raise ValueError(f"{name} must be a number or an array of numbers (one per degree "
                         f"of freedom) in {interval}, got {value!r}")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number or an array of numbers (one per degree "
                         f"of freedom) in {interval}, got {value!r}") from None
    infinite = infinite_ok and arr.ndim == 1 and np.any(arr == math.inf)
    if infinite_ok and arr.ndim == 0 and arr == math.inf:
        raise ValueError(f"{name} = inf would leave every component uncontrolled: an "
                         f"infinite entry is accepted inside an array, for the components "
                         f"not controlled (the others in (0, inf))")
    if infinite and np.all(arr == math.inf):
        raise ValueError(f"{name} must leave some component controlled: an infinite entry "
                         f"is a component whose error is not controlled, and every entry of "
                         f"{name} is infinite")
    finite = arr[arr != math.inf] if infinite else arr
    if np.iscomplexobj(np.asarray(value)) or arr.ndim > 1 or arr.size == 0 or \
            not np.all(np.isfinite(finite)) or np.any(finite < low) or \
            np.any(finite >= high) or open_low and np.any(finite == low):
        what = ("a finite number or a 1-D array of numbers, inf for a component not "
                "controlled" if infinite_ok else "a finite number or a 1-D array of them")
        raise ValueError(f"{name} must be {what} (one per degree of freedom) in {interval}, "
                         f"got {value!r}")
    return float(arr) if arr.ndim == 0 else arr.copy()
