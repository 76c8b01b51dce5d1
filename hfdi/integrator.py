"""The adaptive predictor–corrector driver (paper Sections 4–5) and ``integrate``.

:class:`Integrator` is a small stateful solver in the manner of
``scipy.integrate``'s: :meth:`Integrator.step` takes one accepted step,
:meth:`Integrator.advance` continues to a given time and lands on it exactly,
and :meth:`Integrator.get_state` / :meth:`Integrator.set_state` copy and
restore everything that determines the rest of the run (the state, the
predictor's history, the controller's proposed step, the statistics).

:func:`integrate` runs an :class:`Integrator` to ``t_end`` and returns a
:class:`Result` with the solution at every accepted step.
"""
from __future__ import annotations

import copy
import enum
import inspect
import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from . import checks
from .controller import FixedStep, IterationCountController
from .corrector import predict, solve_step
from .evaluation import Evaluator, ModelError, NonFiniteError, State, brief
from .schemes import HFDI, Scheme, get_scheme
from .system import SecondOrderSystem

__all__ = ["Integrator", "IntegratorState", "Result", "Statistics", "Status", "integrate"]


class Status(enum.IntEnum):
    """How a run ended (negative values are failures).

    ``MODEL_ERROR``: during the run the model returned a value of the wrong
    shape (or a potential energy that is not a number), a mistake that no
    step size cures; the message names the function.
    """

    SUCCESS = 0
    RUNNING = 1
    STEP_BELOW_MINIMUM = -1
    HALVINGS_EXHAUSTED = -2
    MAX_STEPS = -3
    NEWTON_FAILED = -4
    ENERGY_GROWTH = -5
    FIRST_STEP_FAILED = -6
    MODEL_ERROR = -7


@dataclass
class Statistics:
    """Counters of a run, as the paper counts them (Section 5, Eq. 43).

    Attributes
    ----------
    steps : int
        Predictor–corrector steps, diverged attempts included.
    accepted, rejected : int
        Accepted steps and diverged attempts (``steps = accepted + rejected``).
    newton_iterations : int
        ``N_tot``: Newton corrections of all steps, diverged ones included
        (both sub-steps for Bathe).
    first_step_trials : int
        Attempts made to choose the first step size (the accepted one included).
    first_step_trial_iterations : int
        Newton corrections of the discarded first-step trials; they are not in
        ``steps`` or ``newton_iterations``.
    nfev, njev, ntev, npev, nlu : int
        Evaluations of f, K, T and V, and linear factorisations.
    cpu_time : float
        Process time of the run, seconds.
    """

    steps: int = 0
    accepted: int = 0
    rejected: int = 0
    newton_iterations: int = 0
    first_step_trials: int = 0
    first_step_trial_iterations: int = 0
    nfev: int = 0
    njev: int = 0
    ntev: int = 0
    npev: int = 0
    nlu: int = 0
    cpu_time: float = 0.0
    t_start: float = 0.0
    t_reached: float = 0.0

    @property
    def mean_iterations(self) -> float:
        """``N_mv = N_tot / steps`` (Eq. 43)."""
        return self.newton_iterations / self.steps if self.steps else float("nan")

    @property
    def mean_step(self) -> float:
        """``Δt_mv``: time covered divided by ``steps``."""
        return (self.t_reached - self.t_start) / self.steps if self.steps else float("nan")

    def __getitem__(self, key):
        return getattr(self, key)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["mean_iterations"] = self.mean_iterations
        d["mean_step"] = self.mean_step
        return d


@dataclass
class IntegratorState:
    """Everything that determines the continuation of a run (see
    :meth:`Integrator.get_state`). Picklable."""

    current: State
    previous: State | None
    proposed_step: float
    first_step_pending: bool
    status: int
    message: str
    statistics: Statistics
    potential: float
    initial_potential: float
    work: float
    energy_error: float
    energy_scale: float
    last_step: float
    last_iterations: int
    last_energy_increment: float


def _optional_positive(name, value):
    return None if value is None else checks.positive(name, value)


def _initial_vector(name, value, n, source):
    """An initial condition as a finite float array of shape (n,)."""
    label = name if source is None else f"{name} (from {source})"
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


class Integrator:
    """Adaptive predictor–corrector integration of ``M u'' + C u' + f(u) = p(t)``.

    Exactly one of ``target_iterations`` (adaptive) and ``step`` (fixed step)
    must be given.

    Parameters
    ----------
    system : SecondOrderSystem
    scheme : {"newmark", "bathe", "hfdi"} or Scheme
    target_iterations : float, optional
        Target Newton iteration count ``N̄`` per (sub-)step (Eq. 39). For Bathe
        the step's target is ``2 N̄``, as the paper's "2·N̄". The corrector of
        each (sub-)step diverges after ``N_max = 2 N̄`` corrections.
    step : float, optional
        Fixed step size.
    t0 : float
        Initial time.
    u0, v0 : array_like (N,), optional
        Initial displacement and velocity; the model's defaults when omitted.
    tol : float
        Newton tolerance ``η`` of Eq. 38, in (0, 1).
    first_step : float, optional
        First trial step. Default: ``1/ω`` with ``ω`` a Gershgorin bound of the
        highest frequency of ``(K(u0), M)``, capped by ``max_step``.
    min_step, max_step : float, optional
        Guards on the step size. Defaults: ``1e-12·max(1, |t_bound|)`` and
        ``t_bound − t0`` (or no limit without ``t_bound``).
    max_halvings : int
        Consecutive halvings allowed after diverged attempts.
    max_steps : int
        Maximum number of steps (attempts included).
    max_iterations : int, optional
        Corrections allowed per (sub-)step: ``N_max``. Default ``2 N̄``
        rounded down (adaptive) or 50 (fixed step).
    first_step_trials : int
        Attempts allowed to choose the first step size.
    t_bound : float, optional
        The end of the run when known; sets default step limits.
    energy_limit : float, optional
        Stop with ``Status.ENERGY_GROWTH`` when the spurious energy
        ``Σ ΔE`` (Eq. 40) exceeds ``energy_limit`` times the energy scale of
        the run (largest sum so far of kinetic energy, change of potential
        energy and external work). ``None`` disables the check.
    extra_load : callable ``t -> (N,)``, optional
        Added to the model's load.

    Raises
    ------
    ValueError
        For an argument out of its range, naming it, its value and what is
        allowed; for a mass matrix that is not symmetric positive definite or
        a damping matrix that is not symmetric positive semi-definite.
    ModelError
        (a ``ValueError``) when the model fails at the initial state: ``f``,
        ``K``, ``T`` (HFDI only), ``p``, ``p'`` (when used) or ``V`` returns
        the wrong shape or a value that is not finite, or raises. They are
        evaluated here once so that such mistakes come up front rather than
        as failed steps.
    """

    def __init__(self, system: SecondOrderSystem, scheme="hfdi", *, target_iterations=None,
                 step=None, t0=0.0, u0=None, v0=None, tol=1e-8, first_step=None,
                 min_step=None, max_step=None, max_halvings=30, max_steps=1_000_000,
                 max_iterations=None, first_step_trials=40, t_bound=None, energy_limit=None,
                 extra_load=None):
        self.scheme: Scheme = get_scheme(scheme)
        checks.callable_or_none("extra_load", extra_load, "t -> (N,)")
        self.ev = ev = Evaluator(system, extra_load)
        self.system = system
        if (target_iterations is None) == (step is None):
            raise ValueError("give exactly one of target_iterations (adaptive) and step (fixed), "
                             f"got target_iterations={target_iterations!r}, step={step!r}")
        if isinstance(self.scheme, HFDI) and self.scheme.load_rate == "exact" \
                and not ev.has_load_rate:
            why = "extra_load is given" if system.load_rate is not None else \
                "the model has no load_rate"
            raise ValueError(f"scheme HFDI(load_rate='exact') needs the exact load rate, but "
                             f"{why}; use HFDI(load_rate='auto') or "
                             f"HFDI(load_rate='difference')")
        try:
            tol = checks.real("tol", tol, low=0.0, high=1.0)
        except ValueError:
            raise ValueError(f"tol must be in (0, 1), got {tol!r}") from None
        self.tol = tol
        self.t0 = checks.real("t0", t0)
        self.t_bound = None if t_bound is None else checks.real("t_bound", t_bound)
        if self.t_bound is not None and not self.t_bound > self.t0:
            raise ValueError(f"t_bound must be > t0 = {self.t0}, got {t_bound!r}")
        span = None if self.t_bound is None else self.t_bound - self.t0
        self.max_step = _optional_positive("max_step", max_step) \
            or (span if span is not None else math.inf)
        self.min_step = _optional_positive("min_step", min_step) \
            or 1e-12 * max(1.0, abs(self.t_bound if self.t_bound is not None else self.t0))
        if self.min_step >= self.max_step:
            default = " (the default; give min_step for so short a run)" if min_step is None \
                else ""
            raise ValueError(f"min_step must be < max_step = {self.max_step}, got "
                             f"{self.min_step}{default}")
        self.max_halvings = checks.integer("max_halvings", max_halvings, 0)
        self.max_steps = checks.integer("max_steps", max_steps, 1)
        self.first_step_trials = checks.integer("first_step_trials", first_step_trials, 1)
        self.energy_limit = _optional_positive("energy_limit", energy_limit)

        self.adaptive = target_iterations is not None
        if self.adaptive:
            try:
                # above 100 the corrector's N_max = 2 N̄ no longer bounds the work of
                # a diverging attempt in any useful way
                target = checks.real("target_iterations", target_iterations, low=1.0,
                                     low_closed=True, high=100.0, high_closed=True)
            except ValueError:
                raise ValueError(f"target_iterations must be a finite number in [1, 100] "
                                 f"(Newton corrections per step), got "
                                 f"{target_iterations!r}") from None
            self.controller = IterationCountController(target * self.scheme.n_stages,
                                                       self.min_step, self.max_step)
            default_max = max(1, int(math.floor(2.0 * target)))
            self.sliver = 0.01
        else:
            h = checks.positive("step", step)
            if span is not None and span / h > self.max_steps * (1.0 + 1e-9):
                raise ValueError(f"step = {step!r} needs {math.ceil(span / h)} steps from t0 = "
                                 f"{self.t0:g} to t_bound = {self.t_bound:g}, more than "
                                 f"max_steps = {self.max_steps}; allowed: step >= "
                                 f"{span / self.max_steps:.6g}")
            self.controller = FixedStep(h)
            default_max = 50
            self.sliver = 1e-9
        self.max_iterations = default_max if max_iterations is None else \
            checks.integer("max_iterations", max_iterations, 1)
        self.floor = float(getattr(system, "u_scale", 1.0) or 1.0)

        n = ev.n
        initial = []
        for name, given, attribute in (("u0", u0, "initial_displacement"),
                                       ("v0", v0, "initial_velocity")):
            source = None
            if given is None:
                given = getattr(system, attribute, None)
                source = f"system.{attribute}"
            initial.append(np.zeros(n) if given is None else
                           _initial_vector(name, given, n, source))
        u0, v0 = initial
        first_step = _optional_positive("first_step", first_step)

        start = time.process_time()
        current, K0, potential = self._initial_state(u0, v0)
        if self.adaptive:
            h0 = first_step or self._default_first_step(K0)
            proposed = min(h0, self.max_step)
        else:
            proposed = self.controller.step
        stats = Statistics(t_start=self.t0, t_reached=self.t0)
        self._s = IntegratorState(
            current=current, previous=None, proposed_step=proposed,
            first_step_pending=self.adaptive, status=int(Status.RUNNING), message="",
            statistics=stats, potential=potential, initial_potential=potential, work=0.0,
            energy_error=0.0,
            energy_scale=ev.kinetic_energy(current.v), last_step=math.nan,
            last_iterations=0, last_energy_increment=0.0)
        self._cpu(start)

    # -- public state --------------------------------------------------------
    @property
    def state(self) -> State:
        """The current (last accepted) :class:`State`."""
        return self._s.current

    @property
    def t(self) -> float:
        return self._s.current.t

    @property
    def status(self) -> Status:
        return Status(self._s.status)

    @property
    def message(self) -> str:
        return self._s.message

    @property
    def failed(self) -> bool:
        return self._s.status < 0

    @property
    def statistics(self) -> Statistics:
        return self._s.statistics

    @property
    def proposed_step(self) -> float:
        """The step size the controller proposes for the next step."""
        return self._s.proposed_step

    @property
    def last_step(self) -> float:
        return self._s.last_step

    @property
    def last_iterations(self) -> int:
        """Newton corrections of the last accepted step (both sub-steps for Bathe)."""
        return self._s.last_iterations

    @property
    def potential_energy(self) -> float:
        """``V`` at the current state."""
        return self._s.potential

    @property
    def total_energy(self) -> float:
        """``W = V + T`` at the current state (Section 4)."""
        return self._s.potential + self.ev.kinetic_energy(self._s.current.v)

    @property
    def last_energy_increment(self) -> float:
        """``ΔE`` of the last accepted step (Eq. 40)."""
        return self._s.last_energy_increment

    @property
    def external_work(self) -> float:
        """Work of the load since the start (Eq. 41, summed)."""
        return self._s.work

    @property
    def energy_error(self) -> float:
        """``Σ ΔE`` over the accepted steps."""
        return self._s.energy_error

    def get_state(self) -> IntegratorState:
        """A deep copy of the integrator's state, for :meth:`set_state`."""
        self._sync_counters()
        return copy.deepcopy(self._s)

    def set_state(self, saved: IntegratorState) -> None:
        """Restore a state from :meth:`get_state`; the run then continues
        exactly as it did from that point."""
        if not isinstance(saved, IntegratorState):
            raise TypeError(f"state must be an IntegratorState, got {type(saved).__name__}")
        self._s = copy.deepcopy(saved)
        st = self._s.statistics
        ev = self.ev
        ev.nfev, ev.njev, ev.ntev, ev.npev, ev.nlu = st.nfev, st.njev, st.ntev, st.npev, st.nlu

    def load_changed(self) -> None:
        """Tell the integrator that the load jumps at the current time.

        The current state keeps the load ``p_n`` and the acceleration ``a_n``
        computed when it was reached; the schemes read both (Newmark and Bathe
        through ``a_n``, HFDI through ``p_n`` in its load rate, the energy
        balance through the work). After a jump of the load at ``t_n`` (a
        co-simulation input changed at a communication point), both are
        recomputed from the load now, the acceleration being the right limit.
        """
        current = self._s.current
        p = self.ev.load(current.t)
        f = current.f if current.f is not None else self.ev.force(current.u)
        a = self.ev.acceleration(current.t, current.u, current.v, f, p)
        self._s.current = State(current.t, current.u, current.v, a, f, p)
        self._sync_counters()

    # -- stepping ------------------------------------------------------------
    def _initial_state(self, u0, v0):
        """The initial :class:`State`, ``K(u0)`` and ``V(u0)``, every model function
        checked once.

        A model is often wrong at first. Evaluating each function the run will
        use at the initial state turns a wrong shape, a NaN or an exception
        into a :class:`ModelError` that names the function, instead of a run
        whose every step fails for a reason the user has to guess.
        """
        ev, t0 = self.ev, self.t0
        name = getattr(self.system, "name", type(self.system).__name__)
        where = f"at the initial state (t0 = {t0:g}, u0 = {brief(u0)}, v0 = {brief(v0)})"

        def call(function, fun, *args):
            try:
                return fun(*args)
            except ModelError as exc:
                raise ModelError(f"model {name!r}: {exc} {where}") from None
            except NonFiniteError as exc:
                raise ModelError(f"model {name!r}: {exc}, the initial state (t0 = {t0:g}); "
                                 f"the run cannot start there") from None
            except NotImplementedError as exc:
                raise ModelError(f"model {name!r}: scheme {self.scheme.name!r} needs "
                                 f"{function}, which raised NotImplementedError"
                                 f"{': ' + str(exc) if str(exc) else ''}") from exc
            except Exception as exc:
                raise ModelError(f"model {name!r}: {function} raised {type(exc).__name__}: "
                                 f"{exc} {where}") from exc

        f = call("internal_force", ev.force, u0)
        p = call("load", ev.load, t0)
        K = call("stiffness", ev.stiffness, u0)
        if isinstance(self.scheme, HFDI):
            call("stiffness_derivative", ev.stiffness_derivative, u0, v0)
            if self.scheme.load_rate == "exact" or (self.scheme.load_rate == "auto"
                                                     and ev.has_load_rate):
                call("load_rate", ev.load_rate, t0)
        potential = call("potential_energy", ev.potential_energy, u0)
        a = ev.acceleration(t0, u0, v0, f, p)
        if not np.all(np.isfinite(a)):
            raise ModelError(f"model {name!r}: the initial acceleration "
                             f"M⁻¹(p − f − C v0) is not finite ({brief(a)}) {where}")
        return State(t0, u0.copy(), v0.copy(), a, f, p), K, potential

    def _default_first_step(self, K) -> float:
        """``1/ω`` with ``ω²`` bounded by Gershgorin's theorem on ``M⁻¹K(u0)``."""
        row_sums = np.asarray(abs(K).sum(axis=1)).ravel()
        m = self.ev.mass
        m_diag = m if m.ndim == 1 else np.asarray(m.diagonal()).ravel()
        with np.errstate(divide="ignore", invalid="ignore"):
            omega2 = np.nanmax(np.where(m_diag > 0, row_sums / m_diag, 0.0))
        if omega2 > 0 and math.isfinite(omega2):
            h0 = 1.0 / math.sqrt(omega2)
        else:
            h0 = 1e-3 * (self.t_bound - self.t0 if self.t_bound is not None else 1.0)
        return max(h0, 10.0 * self.min_step)

    def _cpu(self, start):
        self._s.statistics.cpu_time += time.process_time() - start

    def _sync_counters(self):
        st = self._s.statistics
        ev = self.ev
        st.nfev, st.njev, st.ntev, st.npev, st.nlu = ev.nfev, ev.njev, ev.ntev, ev.npev, ev.nlu

    def _fail(self, status: Status, message: str) -> bool:
        self._s.status = int(status)
        self._s.message = f"t = {self.t:.10g}: {message}"
        return False

    def _clip(self, h: float, t_limit: float):
        """The end time of a step of proposed size ``h`` that must not pass ``t_limit``.

        Lands exactly on ``t_limit`` when within reach, or when stopping
        short would leave a sliver smaller than ``sliver·h``."""
        t = self.t
        remaining = t_limit - t
        if h >= remaining or remaining - h <= self.sliver * h:
            return t_limit, True
        return t + h, False

    def _attempt(self, t_end: float):
        s = self._s
        current, previous = s.current, s.previous
        return solve_step(self.ev, self.scheme, current, t_end,
                          lambda offset: predict(current, previous, offset),
                          self.tol, self.floor, self.max_iterations)

    def _accept(self, outcome, h):
        s = self._s
        ev = self.ev
        old, new = s.current, outcome.state
        try:
            potential = ev.potential_energy(new.u)
        except Exception as exc:
            # the converged state is not accepted: the run keeps its last good state
            return self._fail(Status.MODEL_ERROR,
                              f"potential_energy failed at the end of the step to t = "
                              f"{new.t:.10g}: {type(exc).__name__}: {exc}")
        kinetic_old, kinetic_new = ev.kinetic_energy(old.v), ev.kinetic_energy(new.v)
        # Eq. 41, the trapezoidal rule over the points where the scheme samples
        # the load: the step's ends, and Bathe's mid-step, whose load the
        # scheme does feel and an end-point rule would miss.
        work = 0.0
        for a, b in zip([old, *outcome.stages], [*outcome.stages, new]):
            work += 0.5 * float((b.u - a.u) @ (a.p + b.p))
        increment = potential - s.potential + kinetic_new - kinetic_old - work  # Eq. 40
        s.previous, s.current = old, new
        s.work += work
        s.energy_error += increment
        s.energy_scale = max(s.energy_scale, kinetic_new + abs(potential - s.initial_potential)
                             + abs(s.work))
        s.potential = potential
        s.last_step = h
        s.last_iterations = outcome.total_iterations
        s.last_energy_increment = increment
        st = s.statistics
        st.accepted += 1
        st.t_reached = new.t
        if self.energy_limit is not None and math.isfinite(increment) \
                and s.energy_error > self.energy_limit * max(s.energy_scale, 1e-300):
            return self._fail(Status.ENERGY_GROWTH,
                              f"energy balance broke down: spurious energy {s.energy_error:.4g} "
                              f"exceeds {self.energy_limit:g} x energy scale {s.energy_scale:.4g}")
        return True

    def step(self, t_limit: float = math.inf) -> bool:
        """Take one accepted step, not beyond ``t_limit``.

        Diverged attempts are retried with the step halved (Section 4).
        Returns ``False`` when a guard stopped the run; :attr:`status` and
        :attr:`message` then say why, and :attr:`state` is the last good state.
        """
        if self.failed:
            return False
        if not t_limit > self.t:
            raise ValueError(f"t_limit must be > t = {self.t}, got {t_limit!r}")
        if self.t_bound is not None:
            t_limit = min(t_limit, self.t_bound)
        start = time.process_time()
        try:
            if self._s.first_step_pending:
                return self._first_step(t_limit)
            return self._regular_step(t_limit)
        except ModelError as exc:
            # a wrong shape mid-run: retrying cannot help, and raising would
            # lose the run of integrate(); stop with the last good state
            return self._fail(Status.MODEL_ERROR, f"the model returned an unusable value in "
                                                  f"a step from this time: {exc}")
        finally:
            self._sync_counters()
            self._cpu(start)

    def _regular_step(self, t_limit):
        s = self._s
        st = s.statistics
        halvings = 0
        while True:
            if st.steps >= self.max_steps:
                before = f" before t = {t_limit:.10g}" if math.isfinite(t_limit) else ""
                return self._fail(Status.MAX_STEPS,
                                  f"max_steps = {self.max_steps} reached (attempts, diverged "
                                  f"ones included){before}")
            proposed = s.proposed_step
            t_end, clipped = self._clip(proposed, t_limit)
            h = t_end - self.t
            if not h > 0.0:
                # the halvings went below the spacing of floating-point times at t
                return self._fail(Status.STEP_BELOW_MINIMUM,
                                  f"step {proposed:.6g} is below the resolution of time at t")
            outcome = self._attempt(t_end)
            st.steps += 1
            st.newton_iterations += outcome.total_iterations
            if outcome.converged:
                s.proposed_step = self.controller.next_step(h, proposed, clipped,
                                                            outcome.total_iterations)
                return self._accept(outcome, h)
            st.rejected += 1
            attempt = f"h = {h:.6g}, to t = {t_end:.10g}"
            if not self.adaptive:
                return self._fail(Status.NEWTON_FAILED,
                                  f"corrector failed with fixed step {h:.6g} (to t = "
                                  f"{t_end:.10g}): {outcome.message}")
            halvings += 1
            if halvings > self.max_halvings:
                return self._fail(Status.HALVINGS_EXHAUSTED,
                                  f"step diverged after {self.max_halvings} halvings (last "
                                  f"attempt {attempt}): {outcome.message}")
            if 0.5 * h < self.min_step:
                return self._fail(Status.STEP_BELOW_MINIMUM,
                                  f"step {0.5 * h:.6g} below min_step = {self.min_step:.6g} "
                                  f"after the attempt with {attempt} failed: {outcome.message}")
            s.proposed_step = 0.5 * h

    def _first_step(self, t_limit):
        """Choose ``Δt₀`` so that the first step converges in ``N̄`` iterations
        (Section 5): bracket ``h`` between a size that needs too few corrections
        and one that needs too many (or diverges), doubling or halving until
        bracketed and bisecting geometrically after."""
        s = self._s
        st = s.statistics
        target = self.controller.target
        h = s.proposed_step
        low = high = None
        best = None            # (distance to target, outcome, h, proposed, clipped)
        message = ""
        smallest = math.inf
        for _ in range(self.first_step_trials):
            t_end, clipped = self._clip(h, t_limit)
            h_try = t_end - self.t
            if not h_try > 0.0:        # below the resolution of time at t
                break
            smallest = min(smallest, h_try)
            outcome = self._attempt(t_end)
            st.first_step_trials += 1
            st.first_step_trial_iterations += outcome.total_iterations
            if outcome.converged:
                n = outcome.total_iterations
                if best is None or abs(n - target) < best[0]:
                    best = (abs(n - target), outcome, h_try, h, clipped)
                if abs(n - target) <= 0.5 or (n < target and (clipped or h_try >= self.max_step)):
                    break
                if n < target:
                    low = h_try
                else:
                    high = h_try
            else:
                message = outcome.message
                high = h_try
            if low is not None and high is not None:
                if high / low < 1.0 + 1e-3:
                    break
                h = math.sqrt(low * high)
            elif low is not None:
                h = min(2.0 * low, self.max_step)
            else:
                h = 0.5 * high
            if h < self.min_step:
                break
        if best is None:
            return self._fail(Status.FIRST_STEP_FAILED,
                              f"no first step converged in {st.first_step_trials} trials "
                              f"down to h = {smallest:.6g}: {message}")
        _, outcome, h_try, proposed, clipped = best
        # The accepted trial is the run's first step; the others are reported apart.
        st.first_step_trial_iterations -= outcome.total_iterations
        st.steps += 1
        st.newton_iterations += outcome.total_iterations
        s.first_step_pending = False
        s.proposed_step = self.controller.next_step(h_try, proposed, clipped,
                                                    outcome.total_iterations)
        return self._accept(outcome, h_try)

    def advance(self, t_stop: float, callback=None) -> bool:
        """Integrate to ``t_stop`` and land on it exactly.

        The step the controller proposes carries over from call to call: a
        step shortened to land on ``t_stop`` does not shrink the next one.

        Parameters
        ----------
        t_stop : float
            Must be ``>= t``.
        callback : callable ``callback(integrator)``, optional
            Called after every accepted step.

        Returns
        -------
        bool
            ``True`` when ``t_stop`` was reached; ``False`` when a guard
            stopped the run (see :attr:`status`, :attr:`message`).
        """
        t_stop = float(t_stop)
        if not math.isfinite(t_stop) or t_stop < self.t:
            raise ValueError(f"t_stop must be finite and >= t = {self.t}, got {t_stop!r}")
        if self.t_bound is not None and t_stop > self.t_bound:
            raise ValueError(f"t_stop must be <= t_bound = {self.t_bound}, got {t_stop!r}")
        while self.t < t_stop:
            ok = self.step(t_stop)
            if callback is not None and self.statistics.accepted and (ok or self._s.status ==
                                                                      Status.ENERGY_GROWTH):
                callback(self)
            if not ok:
                return False
        return True


@dataclass
class Result:
    """Solution of :func:`integrate`.

    Attributes
    ----------
    t : ndarray (n,)
        Times of the initial state and of every accepted step (the ``t_eval``
        points among them).
    u, v, a : ndarray (n, N)
        Displacement, velocity and acceleration at ``t``.
    step_size : ndarray (n,)
        Size of the step that ended at ``t`` (NaN at the start).
    iterations : ndarray (n,)
        Newton corrections of the accepted step that ended at ``t``.
    energy_increment : ndarray (n,)
        ``ΔE`` of the step ending at ``t`` (Eq. 40; 0 at the start).
    total_energy : ndarray (n,)
        ``W = V + T`` at ``t``.
    external_work : ndarray (n,)
        Work of the load from the start (Eq. 41, summed).
    status : Status
    message : str
    success : bool
    stats : Statistics
    scheme : str
    t_eval_index : ndarray of int or None
        Index into ``t`` of each requested ``t_eval`` point.
    system : SecondOrderSystem
        The model integrated.
    """

    t: np.ndarray
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    step_size: np.ndarray
    iterations: np.ndarray
    energy_increment: np.ndarray
    total_energy: np.ndarray
    external_work: np.ndarray
    status: Status
    message: str
    stats: Statistics
    scheme: str
    t_eval_index: np.ndarray | None = None
    system: SecondOrderSystem | None = field(default=None, repr=False)

    @property
    def success(self) -> bool:
        return self.status == Status.SUCCESS

    def quantities(self, system: SecondOrderSystem | None = None) -> dict:
        """The quantities of interest of ``system`` (default: the model
        integrated) at ``t``, a dict of (n, m) arrays."""
        return (system or self.system).quantities(self.t, self.u, self.v)

    def __repr__(self):
        st = self.stats
        return (f"Result(scheme={self.scheme!r}, status={self.status.name}, steps={st.steps}, "
                f"mean_iterations={st.mean_iterations:.3f}, mean_step={st.mean_step:.4g}, "
                f"t_final={self.t[-1]:.6g})")


def integrate(system: SecondOrderSystem, scheme, t_end, *, target_iterations=None, step=None,
              u0=None, v0=None, t0=0.0, t_eval=None, tol=1e-8, **options) -> Result:
    """Integrate ``M u'' + C u' + f(u) = p(t)`` from ``t0`` to ``t_end``.

    Adaptive when ``target_iterations`` is given (step size from the Newton
    iteration count, Eq. 39), fixed-step when ``step`` is given.

    Parameters
    ----------
    system : SecondOrderSystem
    scheme : {"newmark", "bathe", "hfdi"} or Scheme
    t_end : float
    target_iterations : float, optional
        ``N̄`` per (sub-)step; see :class:`Integrator`.
    step : float, optional
        Fixed step size.
    u0, v0 : array_like (N,), optional
    t0 : float
    t_eval : array_like, optional
        Times in ``(t0, t_end]`` the steps must land on exactly; found in the
        result through ``t_eval_index``.
    tol : float
        Newton tolerance ``η`` (Eq. 38).
    **options
        Passed to :class:`Integrator` (``first_step``, ``min_step``,
        ``max_step``, ``max_halvings``, ``max_steps``, ``max_iterations``,
        ``energy_limit``, ...).

    Returns
    -------
    Result
        ``status`` and ``message`` say how the run ended; on failure the
        arrays end at the last good state and the message starts with its
        time (``"t = ...: "``).

    Raises
    ------
    ValueError
        For bad input, naming the parameter, its value and what is allowed;
        :class:`~hfdi.ModelError` (a ``ValueError``) for a model that fails at
        the initial state (see :class:`Integrator`). Faults during the run
        do not raise; they end it with a failed ``status``.
    """
    t0 = checks.real("t0", t0)
    try:
        t_end = float(t_end)
    except (TypeError, ValueError):
        raise ValueError(f"t_end must be a number > t0 = {t0}, got {t_end!r}") from None
    if not (math.isfinite(t_end) and t_end > t0):
        raise ValueError(f"t_end must be finite and > t0 = {t0}, got {t_end!r}")
    stops = [t_end]
    if t_eval is not None:
        try:
            t_eval = np.asarray(t_eval, dtype=float).ravel()
        except (TypeError, ValueError):
            raise ValueError(f"t_eval must be an array of times in [t0, t_end], "
                             f"got {t_eval!r}") from None
        if not np.all(np.isfinite(t_eval)):
            i = int(np.flatnonzero(~np.isfinite(t_eval))[0])
            raise ValueError(f"t_eval must be finite, got t_eval[{i}] = {float(t_eval[i])!r}")
        if np.any(np.diff(t_eval) <= 0):
            i = int(np.flatnonzero(np.diff(t_eval) <= 0)[0])
            raise ValueError(f"t_eval must be strictly increasing, got t_eval[{i}] = "
                             f"{float(t_eval[i])!r} followed by t_eval[{i + 1}] = "
                             f"{float(t_eval[i + 1])!r}")
        if t_eval.size and (t_eval[0] < t0 or t_eval[-1] > t_end):
            raise ValueError(f"t_eval must lie in [t0, t_end] = [{t0}, {t_end}], "
                             f"got [{t_eval[0]}, {t_eval[-1]}]")
        stops = [t for t in t_eval if t > t0] + ([t_end] if not t_eval.size or
                                                  t_eval[-1] < t_end else [])
    allowed = [name for name in inspect.signature(Integrator).parameters
               if name not in ("system", "scheme", "target_iterations", "step", "t0", "u0", "v0",
                               "tol", "t_bound")]
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ValueError(f"unknown option(s) {', '.join(unknown)} of integrate; allowed: "
                         f"{', '.join(allowed)}")
    integrator = Integrator(system, scheme, target_iterations=target_iterations, step=step,
                            t0=t0, u0=u0, v0=v0, tol=tol, t_bound=t_end, **options)
    s0 = integrator.state
    rows_t, rows_u, rows_v, rows_a = [s0.t], [s0.u], [s0.v], [s0.a]
    rows_h, rows_n, rows_de, rows_w, rows_l = [math.nan], [0], [0.0], [integrator.total_energy], [0.0]

    def record(itg: Integrator):
        st = itg.state
        rows_t.append(st.t)
        rows_u.append(st.u)
        rows_v.append(st.v)
        rows_a.append(st.a)
        rows_h.append(itg.last_step)
        rows_n.append(itg.last_iterations)
        rows_de.append(itg.last_energy_increment)
        rows_w.append(itg.total_energy)
        rows_l.append(itg.external_work)

    ok = True
    for t_stop in stops:
        ok = integrator.advance(t_stop, callback=record)
        if not ok:
            break
    status = integrator.status if not ok else Status.SUCCESS
    message = integrator.message if not ok else "reached t_end"
    t = np.asarray(rows_t)
    index = None
    if t_eval is not None:
        index = np.searchsorted(t, t_eval)
        index = np.where((index < t.size) & (t[np.minimum(index, t.size - 1)] == t_eval), index, -1)
    result = Result(t=t, u=np.asarray(rows_u), v=np.asarray(rows_v), a=np.asarray(rows_a),
                    step_size=np.asarray(rows_h), iterations=np.asarray(rows_n),
                    energy_increment=np.asarray(rows_de), total_energy=np.asarray(rows_w),
                    external_work=np.asarray(rows_l), status=status, message=message,
                    stats=copy.copy(integrator.statistics), scheme=integrator.scheme.name,
                    t_eval_index=index, system=system)
    return result
