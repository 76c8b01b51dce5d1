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
import dataclasses
import enum
import inspect
import math
import time
from dataclasses import dataclass, field

import numpy as np

from . import checks, serial
from .compiled import (InitialValues, compiled_driver, compiled_step, kernel_mismatch,
                       library_kernels, say_once)
from .controller import (DEFAULT_RTOL, Attempt, Combined, Controller, ErrorControl, FixedStep,
                         IterationCount)
from .corrector import (SHORT_STEP_RATE, StepOutcome, fastest_rate, is_short, local_error,
                        predict, short_step, solve_step)
from .dense import Solution, interpolate_state
from .evaluation import (Evaluator, ModelError, NonFiniteError, State, brief, energy_overflows,
                         potential_lost)
from .linalg import all_finite
from .schemes import HFDI, Scheme, get_scheme
from .system import SecondOrderSystem, load_rate_error

__all__ = ["Integrator", "IntegratorState", "Result", "Statistics", "Status", "integrate"]


_EPS = float(np.finfo(float).eps)
_SQRT_EPS = math.sqrt(_EPS)
#: Values of ``Integrator(newton_test=...)``.
NEWTON_TESTS = ("correction", "error")


class Status(enum.IntEnum):
    """How a run ended (negative values are failures).

    ``MODEL_ERROR``: during the run the model returned a value of the wrong
    shape (or a potential energy that is not a number), a mistake that no
    step size cures; the message names the function.

    ``OVERFLOW``: a converged step reached a state whose energy balance
    (Eqs. 40–41) is beyond floating point, an infinite kinetic energy, work
    of the load or potential energy (a load or state of the order of 1e150
    or more); that state is not accepted.
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
    OVERFLOW = -8


@dataclass
class Statistics:
    """Counters of a run, as the paper counts them (Section 5, Eq. 43).

    Attributes
    ----------
    steps : int
        Predictor–corrector steps, diverged attempts included.
    accepted, rejected : int
        Accepted steps and rejected attempts, diverged or failing the error
        test (``steps = accepted + rejected``).
    newton_iterations : int
        ``N_tot``: Newton corrections of all steps, diverged ones included
        (both sub-steps for Bathe).
    first_step_trials : int
        Attempts made to choose the first step size (the accepted one included).
    first_step_trial_iterations : int
        Newton corrections of the discarded first-step trials; they are not in
        ``steps`` or ``newton_iterations``.
    error_test_failures : int
        Attempts whose corrector converged but whose local error estimate
        failed the tolerance (part of ``rejected``).
    nfev, njev, ntev, npev, nlu : int
        Evaluations of f, K, T and V, and linear factorisations.
    cpu_time : float
        Process time of the run, seconds.
    """

    steps: int = 0
    accepted: int = 0
    rejected: int = 0
    newton_iterations: int = 0
    error_test_failures: int = 0
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


def _clone(obj):
    """``copy.copy`` of a plain dataclass instance (its fields in its ``__dict__``)."""
    new = object.__new__(type(obj))
    new.__dict__.update(obj.__dict__)
    return new


@dataclass
class IntegratorState:
    """Everything that determines the continuation of a run (see
    :meth:`Integrator.get_state`).

    :meth:`to_bytes` and :meth:`from_bytes` write and read it as data only
    (:mod:`hfdi.serial`), so that bytes from elsewhere can never run code;
    the round trip is bit-exact.
    """

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
    grid_origin: float
    grid_steps: int
    newton_constant: float
    newton_guard: float
    controller: str
    n_dof: int
    #: ``repr`` of the scheme (with its parameters) that made the state.
    scheme: str = ""
    #: The model's ``parameter_version`` the state was computed with (-1: a
    #: model that does not count parameter changes).
    model_version: int = -1

    def copy(self, copy_arrays: bool = True) -> IntegratorState:
        """A deep copy, field by field: a co-simulation step saves one before
        every communication step, where ``copy.deepcopy``'s generic walk cost
        more than the step (and ``copy.copy`` of each dataclass, 1.4 µs, as
        much as the arrays). With ``copy_arrays=False`` the states (and their
        arrays) are shared; see :meth:`Integrator.get_state`."""
        new = _clone(self)
        if copy_arrays:
            new.current = self.current.copy()
            new.previous = None if self.previous is None else self.previous.copy()
        new.statistics = _clone(self.statistics)
        return new

    def to_bytes(self) -> bytes:
        """The state as bytes: arrays in binary, everything else in a JSON header."""
        arrays = {}

        def one(label, st):
            if st is None:
                return None
            for name in _STATE_ARRAYS:
                value = getattr(st, name)
                if value is not None:
                    arrays[f"{label}.{name}"] = np.asarray(value, dtype=np.float64)
            return {"t": float(st.t), "f": st.f is not None}

        header = {name: kind(getattr(self, name)) for name, kind in _STATE_SCALARS.items()}
        header.update(format=STATE_FORMAT, current=one("current", self.current),
                      previous=one("previous", self.previous),
                      statistics={k: type(getattr(Statistics, k))(getattr(self.statistics, k))
                                  for k in _STATISTICS_FIELDS})
        return serial.pack(header, arrays)

    @classmethod
    def from_bytes(cls, data) -> IntegratorState:
        """Read :meth:`to_bytes`' bytes, checking every field's type and shape.

        Raises
        ------
        ValueError
            For bytes that are not such a state (corrupt, truncated, of
            another format version, or with a field of the wrong type).
        """
        try:
            header, arrays = serial.unpack(data)
        except ValueError:
            raise ValueError("not a serialized integrator state") from None
        if header.get("format") != STATE_FORMAT:
            raise ValueError(f"not a serialized integrator state of format {STATE_FORMAT!r}")
        n = _field(header, "n_dof", int)

        def one(label):
            entry = header.get(label)
            if entry is None and label == "previous":
                return None
            if not isinstance(entry, dict):
                raise ValueError(f"serialized state: {label} is missing")
            values = {}
            for name in _STATE_ARRAYS:
                key = f"{label}.{name}"
                if name == "f" and not _field(entry, "f", bool):
                    values[name] = None
                    continue
                value = arrays.pop(key, None)
                if not (isinstance(value, np.ndarray) and value.dtype == np.float64
                        and value.shape == (n,)):
                    raise ValueError(f"serialized state: {key} must be a float64 array of "
                                     f"shape ({n},)")
                values[name] = value
            return State(_field(entry, "t", float), **values)

        current, previous = one("current"), one("previous")
        if arrays:
            raise ValueError(f"serialized state: unexpected entries {sorted(arrays)}")
        counts = header.get("statistics")
        if not isinstance(counts, dict) or set(counts) != set(_STATISTICS_FIELDS):
            raise ValueError("serialized state: statistics malformed")
        statistics = Statistics(**{k: _field(counts, k, type(getattr(Statistics, k)))
                                   for k in _STATISTICS_FIELDS})
        scalars = {k: _field(header, k, kind) for k, kind in _STATE_SCALARS.items()}
        return cls(current=current, previous=previous, statistics=statistics, **scalars)


#: Format of :meth:`IntegratorState.to_bytes`; a version bump makes old bytes unreadable.
STATE_FORMAT = "hfdi-integrator-state/3"
_STATE_ARRAYS = ("u", "v", "a", "f", "p")
_STATE_SCALARS = {"proposed_step": float, "first_step_pending": bool, "status": int,
                  "message": str, "potential": float, "initial_potential": float,
                  "work": float, "energy_error": float, "energy_scale": float,
                  "last_step": float, "last_iterations": int, "last_energy_increment": float,
                  "grid_origin": float, "grid_steps": int, "newton_constant": float,
                  "newton_guard": float, "controller": str, "n_dof": int, "scheme": str,
                  "model_version": int}
_STATISTICS_FIELDS = tuple(f.name for f in dataclasses.fields(Statistics))


def _field(mapping, key, kind):
    """``mapping[key]`` of type ``kind`` (an int is a float too; a bool is no int)."""
    value = mapping.get(key)
    ok = isinstance(value, bool) if kind is bool else (
        isinstance(value, int) and not isinstance(value, bool) if kind is int else
        isinstance(value, (int, float)) and not isinstance(value, bool) if kind is float else
        isinstance(value, kind))
    if not ok:
        raise ValueError(f"serialized state: {key} must be of type {kind.__name__}, "
                         f"got {type(value).__name__}")
    return float(value) if kind is float else value


def _optional_positive(name, value):
    return None if value is None else checks.positive(name, value)


def _initial_vector(name, value, n, source):
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


class Integrator:
    """Adaptive predictor–corrector integration of ``M u'' + C u' + f(u) = p(t)``.

    Four modes, chosen by the arguments (docs/accuracy.md says when to use
    which):

    - **error control** — ``rtol`` (and ``atol``) given, or none of ``rtol``,
      ``target_iterations``, ``step`` and ``controller`` (then
      ``rtol = DEFAULT_RTOL = 1e-4``): the local error estimate of every step
      is kept below the tolerance;
    - **iteration count** — ``target_iterations`` alone: the paper's rule
      (Eq. 39). It controls the Newton work per step, **not the error**;
    - **combined** — ``target_iterations`` and ``rtol``: an attempt must pass
      both, and the smaller proposed step wins;
    - **fixed step** — ``step``.

    A :class:`~hfdi.controller.Controller` object given as ``controller``
    replaces all four.

    Parameters
    ----------
    system : SecondOrderSystem
    scheme : {"newmark", "bathe", "hfdi"} or Scheme
    rtol : float or array_like (N,), optional
        Relative tolerance of the local error of ``u``, in ``[1e-13, 0.1)``.
    atol : float or array_like (N,), optional
        Absolute tolerance, ``> 0``. Default ``1e-3 · rtol · u_scale`` (the
        model's length ``u_scale``).
    target_iterations : float, optional
        Target Newton iteration count ``N̄`` per (sub-)step (Eq. 39), in
        ``[1, 100]``. For Bathe the step's target is ``2 N̄``, as the paper's
        "2·N̄". The corrector of each (sub-)step diverges after
        ``N_max = 2 N̄`` corrections.
    step : float, optional
        Fixed step size. Steps land on ``t0 + k·step``: ``(t_end − t0)/n``
        takes exactly ``n`` steps.
    controller : Controller, optional
        A step-size controller object (see :mod:`hfdi.controller`), defining
        ``init`` and ``adapt``. The integrator works on its own copy
        (``Integrator.controller``), fitted to the system's size and, for an
        :class:`~hfdi.controller.ErrorControl` without ``order``, to the
        scheme's order; the object given can serve other integrators.
    t0 : float
        Initial time.
    u0, v0 : array_like (N,), optional
        Initial displacement and velocity; the model's defaults when omitted.
    tol : float, optional
        Newton tolerance ``η`` of Eq. 38, in (0, 1). Default ``1e-8``, and at
        most ``rtol/1000`` (not below ``1e-12``) under error control so that
        the corrector's error stays below the one controlled.
    newton_test : {"correction", "error"}, optional
        When the corrector stops: ``"correction"``, the paper's Eq. 38 (the
        last correction at most ``η · max(‖u‖, u_scale)``); ``"error"``, that
        or the estimate of the error the correction left at most that bound
        (after the first correction from the quadratic constant of the
        corrections before, after later ones from their observed rate;
        :func:`hfdi.corrector.newton`), which saves the confirming
        correction most steps take. Default ``"error"`` under error control
        alone, ``"correction"`` in the other modes (whose Newton counts are
        the paper's ``N``). docs/algorithm.md, "Corrector", says why.
    first_step : float, optional
        First trial step. Default: ``1/ω`` with ``ω`` a Gershgorin bound of the
        highest frequency of ``(K(u0), M)``, capped by ``max_step``.
    min_step, max_step : float, optional
        Guards on the step size. Defaults: ``1e-12·max(1, |t_bound|)`` and
        ``t_bound − t0`` (or no limit without ``t_bound``).
    max_halvings : int
        Consecutive rejected attempts allowed for one step (the first
        step's trials are bounded by ``first_step_trials`` instead).
    max_steps : int
        Maximum number of steps (attempts included).
    max_iterations : int, optional
        Corrections allowed per (sub-)step: ``N_max``. Default ``2 N̄``
        rounded down (iteration count), 10 (error control) or 50 (fixed
        step).
    first_step_trials : int
        Attempts allowed to choose the first step size.
    t_bound : float, optional
        The end of the run when known; sets default step limits. Once it is
        reached the integrator is finished: :attr:`status` is ``SUCCESS``
        and :meth:`step` takes no more steps.
    energy_limit : float, optional
        Stop with ``Status.ENERGY_GROWTH`` when the spurious energy
        ``Σ ΔE`` (Eq. 40) exceeds ``energy_limit`` times the energy scale of
        the run (largest sum so far of kinetic energy, change of potential
        energy and external work). ``None`` disables the check.
    extra_load : callable ``t -> (N,)``, optional
        Added to the model's load.
    breakpoints : array_like, optional
        Times where the load or its rate jumps, besides the model's own
        ``load_breakpoints()``. Under error control steps land on them and
        the predictor restarts there; the iteration-count mode keeps its
        steps (the paper's tables are made so); the fixed-step mode keeps
        its grid and treats the breakpoints on it as error control does (the
        load's left limit at the end of the step that lands there, its right
        limit after), and steps over the others.
    check_stiffness : bool
        Check ``K(u0)`` against central differences of ``f`` (4 extra force
        evaluations for a correct model, at most 16) and refuse a model whose
        ``K`` is not ``∂f/∂u`` (default); for HFDI with the model's
        ``load_rate``, check ``p'(t0)`` against forward differences of ``p``
        too (at most 26 load evaluations).
        Turn off only for a force with a kink at ``u0``.
    compiled : {None, True, False}
        Take the steps in compiled code (:mod:`hfdi.compiled`, numba; see
        docs/compiled.md). ``None`` (default, auto): compiled when the model
        has compiled kernels, numba imports and the system is dense
        (``N < 128``), with a warning once per process when only numba is
        missing; the Python path otherwise. ``True``: compiled or
        :class:`hfdi.compiled.CompiledUnavailable` naming the reason.
        ``False``: the Python path. Compiled, each attempt (predictor,
        stages, Newton) is one compiled call; with a compiled load too (the
        paper's models), :meth:`advance` runs whole sequences of steps in
        the compiled driver (:attr:`driven`), 18–35× faster per Newton
        iteration than the Python path. Where the kernels compute ``f``,
        ``K`` and ``T`` as the Python model does (the paper's models), both
        paths take the same steps and Newton counts and agree bit for bit.
        Where they round differently (the kernels that
        :class:`~hfdi.models.symbolic.EnergyModel` generates), the states
        agree to rounding, but under error control the local error
        estimate, a difference of nearly equal states, carries that
        rounding into the step sizes: they differ by about 1e-6 relative,
        and a run may take a step more or fewer.
        Compiling costs about 30 s once per installation.

    Raises
    ------
    ValueError
        For an argument out of its range, naming it, its value and what is
        allowed; for a mass matrix that is not symmetric positive definite or
        a damping matrix that is not symmetric positive semi-definite.
    ModelError
        (a ``ValueError``) when the model fails at the initial state: ``f``,
        ``K``, ``T`` (HFDI only), ``p``, ``p'`` (when used) or ``V`` returns
        the wrong shape, a value that is not finite or complex, or raises;
        or when ``K(u0)`` does not match a finite difference of ``f`` (see
        ``check_stiffness``). They are evaluated here once so that such
        mistakes come up front rather than as failed steps or wrong answers.
    """

    def __init__(self, system: SecondOrderSystem, scheme="hfdi", *, rtol=None, atol=None,
                 target_iterations=None, step=None, controller=None, t0=0.0, u0=None, v0=None,
                 tol=None, first_step=None, min_step=None, max_step=None, max_halvings=30,
                 max_steps=1_000_000, max_iterations=None, first_step_trials=40, t_bound=None,
                 energy_limit=None, extra_load=None, breakpoints=None, check_stiffness=True,
                 compiled=None, newton_test=None):
        self.scheme: Scheme = get_scheme(scheme)
        checks.callable_or_none("extra_load", extra_load, "t -> (N,)")
        if not isinstance(check_stiffness, bool):
            raise ValueError(f"check_stiffness must be True or False, got {check_stiffness!r}")
        self.check_stiffness = check_stiffness
        self.ev = ev = Evaluator(system, extra_load)
        self.system = system
        # a model that counts the changes of its parameters (EnergyModel): the
        # integrator follows them (model_changed) before its next step
        self._model_version = getattr(system, "parameter_version", None)
        if isinstance(self.scheme, HFDI) and self.scheme.load_rate == "exact" \
                and not ev.has_load_rate:
            why = "extra_load is given" if system.load_rate is not None else \
                "the model has no load_rate"
            raise ValueError(f"scheme HFDI(load_rate='exact') needs the exact load rate, but "
                             f"{why}; use HFDI(load_rate='auto') or "
                             f"HFDI(load_rate='difference')")
        self.t0 = checks.real("t0", t0)
        self.t_bound = None if t_bound is None else checks.real("t_bound", t_bound)
        if self.t_bound is not None and not self.t_bound > self.t0:
            raise ValueError(f"t_bound must be > t0 = {self.t0}, got {t_bound!r}")
        span = None if self.t_bound is None else self.t_bound - self.t0
        self.max_steps = checks.integer("max_steps", max_steps, 1)
        self.energy_limit = _optional_positive("energy_limit", energy_limit)
        self.controller = self._controller(
            controller, rtol, atol, target_iterations, step, span, min_step, max_step,
            max_halvings, first_step_trials, float(getattr(system, "u_scale", 1.0) or 1.0))
        c = self.controller
        c.prepare(ev.n, self.scheme.order)
        self.min_step, self.max_step = c.min_step, c.max_step
        self.fixed = isinstance(c, FixedStep)
        self.max_iterations = c.max_iterations if max_iterations is None else \
            checks.integer("max_iterations", max_iterations, 1)
        self.tol = self._newton_tolerance(tol)
        if newton_test is None:
            newton_test = "error" if isinstance(c, ErrorControl) else "correction"
        if not (isinstance(newton_test, str) and newton_test in NEWTON_TESTS):
            raise ValueError(f"newton_test must be one of {', '.join(map(repr, NEWTON_TESTS))}, "
                             f"got {newton_test!r}")
        self.newton_test = newton_test
        self._estimated = newton_test == "error"
        self.floor = float(getattr(system, "u_scale", 1.0) or 1.0)
        # the fixed step lands on those on its grid (_limit)
        self.breakpoints = self._breakpoints(breakpoints) if c.uses_error_estimate or self.fixed \
            else np.empty(0)
        self._given_breakpoints = breakpoints

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
        if first_step is not None:
            if self.fixed:
                raise ValueError(f"first_step applies to the adaptive modes; with step= "
                                 f"every step is step, got first_step={first_step!r}")
            if first_step < self.min_step:
                raise ValueError(f"first_step must be >= min_step = {self.min_step!r}, got "
                                 f"{first_step!r}")
            if max_step is not None and first_step > self.max_step:
                raise ValueError(f"first_step must be <= max_step = {self.max_step!r}, got "
                                 f"{first_step!r}")

        start = time.process_time()
        current, K0, T0, potential = self._initial_state(u0, v0)
        if self.energy_limit is not None and math.isnan(potential):
            raise ValueError(
                f"energy_limit needs the model's potential energy (the energy balance, "
                f"Eq. 40), but model {getattr(system, 'name', type(system).__name__)!r} "
                f"returns NaN (unknown) from potential_energy at u0; give the model "
                f"potential_energy or leave energy_limit=None")
        self._compiled = compiled_step(ev, self.scheme, compiled, initial=InitialValues(
            current.t, current.u, current.v, current.f, K0, T0, potential,
            math.inf if self.t_bound is None else self.t_bound))
        self._driver = None if self._compiled is None else compiled_driver(self)
        if self.fixed:
            proposed = c.step
        else:
            proposed = min(first_step or self._default_first_step(K0), self.max_step)
        stats = Statistics(t_start=self.t0, t_reached=self.t0)
        self._s = IntegratorState(
            current=current, previous=None, proposed_step=proposed,
            first_step_pending=not self.fixed, status=int(Status.RUNNING), message="",
            statistics=stats, potential=potential, initial_potential=potential, work=0.0,
            energy_error=0.0,
            energy_scale=ev.kinetic_energy(current.v), last_step=math.nan,
            last_iterations=0, last_energy_increment=0.0, grid_origin=self.t0, grid_steps=0,
            newton_constant=math.inf, newton_guard=math.inf, controller=repr(c), n_dof=n,
            scheme=repr(self.scheme))
        self._arrival = current
        self._cpu(start)

    # -- construction --------------------------------------------------------
    def _controller(self, controller, rtol, atol, target, step, span, min_step, max_step,
                    max_halvings, first_step_trials, u_scale) -> Controller:
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
        max_step = _optional_positive("max_step", max_step) \
            or (span if span is not None else math.inf)
        default_min = min_step is None
        min_step = _optional_positive("min_step", min_step) \
            or 1e-12 * max(1.0, abs(self.t_bound if self.t_bound is not None else self.t0))
        if min_step >= max_step:
            hint = " (the default; give min_step for so short a run)" if default_min else ""
            raise ValueError(f"min_step must be < max_step = {max_step}, got {min_step}{hint}")
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
            if span is not None and span / h > self.max_steps * (1.0 + 1e-9):
                needs = span / h            # inf for a step near the smallest float
                count = math.ceil(needs) if math.isfinite(needs) else "more than 1e308"
                raise ValueError(f"step = {step!r} needs {count} steps from t0 = "
                                 f"{self.t0:g} to t_bound = {self.t_bound:g}, more than "
                                 f"max_steps = {self.max_steps}; allowed: step >= "
                                 f"{span / self.max_steps:.6g}")
            return FixedStep(h, **limits)
        iteration = None if target is None else \
            IterationCount(target, self.scheme.n_stages, **limits)
        if iteration is not None and rtol is None:
            return iteration
        error = ErrorControl(DEFAULT_RTOL if rtol is None else rtol, atol, u_scale=u_scale,
                             order=self.scheme.order, **limits)
        return error if iteration is None else Combined(iteration, error)

    def _newton_tolerance(self, tol):
        if tol is None:
            tol = 1e-8
            if self.controller.uses_error_estimate:
                rtol = getattr(self.controller, "error", self.controller).rtol
                tol = min(tol, max(1e-12, 1e-3 * float(np.min(rtol))))
        try:
            return checks.real("tol", tol, low=0.0, high=1.0)
        except ValueError:
            raise ValueError(f"tol must be in (0, 1), got {tol!r}") from None

    def _on_grid(self, point: float) -> bool:
        """Whether the fixed step's grid ``grid_origin + k h`` (as it is now:
        a step shortened off it starts a new one) lands on ``point``, within
        the ``1e-6 h`` of its landing rule. A breakpoint there is taken as
        under error control (the step that ends on it with the load's left
        limit, the next from its right limit) and no step changes; the
        others are stepped over."""
        origin, h = self._s.grid_origin, self.controller.step
        return abs(point - (origin + round((point - origin) / h) * h)) <= 1e-6 * h

    def _breakpoints(self, extra):
        """The sorted load breakpoints of the model and of ``extra``."""
        own = self.system.load_breakpoints() if hasattr(self.system, "load_breakpoints") \
            else ()
        try:
            times = np.concatenate([np.asarray(own, dtype=float).ravel(),
                                    np.asarray(() if extra is None else extra,
                                               dtype=float).ravel()])
        except (TypeError, ValueError):
            raise ValueError(f"breakpoints must be an array of times, got {extra!r}") from None
        if not np.all(np.isfinite(times)):
            raise ValueError(f"breakpoints must be finite, got {times!r}")
        return np.unique(times)

    # -- public state --------------------------------------------------------
    @property
    def compiled(self) -> bool:
        """Whether the attempts run compiled (see ``compiled``, docs/compiled.md)."""
        return self._compiled is not None

    @property
    def compiled_model(self) -> bool:
        """Whether the model's f, K and T run compiled: inside the compiled
        attempts (dense systems), or called by the Python steps of a sparse
        system whose model has :class:`hfdi.compiled.SparseKernels`."""
        return self._compiled is not None or self.ev.kernels is not None

    @property
    def driven(self) -> bool:
        """Whether :meth:`advance` runs its ordinary steps in the compiled
        driver (:mod:`hfdi.compiled.driver`): compiled attempts, a model with
        a compiled load, no ``extra_load`` other than a :class:`~hfdi.HeldLoad`
        and a built-in controller (:func:`hfdi.compiled.driver_reason`)."""
        return self._driver is not None

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
    def finished(self) -> bool:
        """Whether ``t_bound`` has been reached."""
        return self.t_bound is not None and self.t >= self.t_bound

    @property
    def statistics(self) -> Statistics:
        return self._s.statistics

    @property
    def proposed_step(self) -> float:
        """The size the controller proposes for the next step."""
        return self._s.proposed_step

    @property
    def last_step(self) -> float:
        return self._s.last_step

    @property
    def last_iterations(self) -> int:
        """Newton corrections of the last accepted step."""
        return self._s.last_iterations

    @property
    def potential_energy(self) -> float:
        """``V`` at the current state."""
        return self._s.potential

    @property
    def total_energy(self) -> float:
        """``W = V + T`` at the current state (Eq. 40)."""
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
        """``Σ ΔE`` since the start: the spurious energy of the run."""
        return self._s.energy_error

    def get_state(self, copy_arrays: bool = True) -> IntegratorState:
        """A deep copy of the integrator's state, for :meth:`set_state`.

        Parameters
        ----------
        copy_arrays : bool
            With ``False`` the saved state shares the current and previous
            :class:`State` and their arrays with the integrator, at a third of
            the cost (a rollback saved before every co-simulation step). The
            integrator never writes into a state it has made (each step makes
            new ones), so the saved state stays exact as long as its holder
            does not write into those arrays either; :meth:`set_state` copies
            them back in.
        """
        self._sync_counters()
        saved = self._s.copy(copy_arrays)
        saved.model_version = -1 if self._model_version is None else int(self._model_version)
        return saved

    def set_state(self, saved: IntegratorState) -> None:
        """Restore a state from :meth:`get_state`; the run then continues
        exactly as it did from that point. For a model that counts the
        changes of its parameters (``parameter_version``), a state saved
        under another version is refreshed as by :meth:`model_changed`
        (``f``, ``a`` and ``V`` recomputed, the step history dropped).

        Raises
        ------
        TypeError
            If ``saved`` is not an :class:`IntegratorState`.
        ValueError
            If it belongs to a model of another size, to another model (its
            kept force ``f(u)`` is not this model's there), to an integrator
            of another scheme or mode (controller), or holds values out of
            their range (non-finite arrays, an unknown status, times out of
            order, negative counters); the integrator is then left as it was.
            Bytes from :meth:`IntegratorState.from_bytes` are data: this is
            where their values are checked.
        """
        if not isinstance(saved, IntegratorState):
            raise TypeError(f"state must be an IntegratorState, got {type(saved).__name__}")
        self._check_state(saved)
        before, version = self._s, self._model_version
        now = getattr(self.system, "parameter_version", None)
        # the state's f_n, a_n and V were computed under the parameters of its
        # version; under others they are recomputed (Newmark and Bathe keep no
        # f_n to tell by)
        refresh = now is not None and saved.model_version != now
        self._model_version = now
        self._s = saved.copy()
        st = self._s.statistics
        ev = self.ev
        counts = (ev.nfev, ev.njev, ev.ntev, ev.npev, ev.nlu)
        ev.nfev, ev.njev, ev.ntev, ev.npev, ev.nlu = st.nfev, st.njev, st.ntev, st.npev, st.nlu
        if refresh:
            try:
                self.model_changed()
            except ModelError:
                self._s, self._model_version = before, version
                ev.nfev, ev.njev, ev.ntev, ev.npev, ev.nlu = counts
                raise

    def _check_state(self, saved: IntegratorState):
        n = self.ev.n
        if saved.n_dof != n:
            raise ValueError(f"state has {saved.n_dof} degrees of freedom, this integrator's "
                             f"model has {n}")
        if saved.controller != repr(self.controller):
            raise ValueError(f"state was saved by an integrator with controller "
                             f"{saved.controller}; this one has {self.controller!r}")
        if saved.scheme != repr(self.scheme):
            raise ValueError(f"state was saved by an integrator with scheme "
                             f"{saved.scheme or 'unknown'}; this one has {self.scheme!r}")
        if saved.status not in {int(s) for s in Status}:
            raise ValueError(f"state.status must be one of {sorted(int(s) for s in Status)}, "
                             f"got {saved.status!r}")
        if saved.status < 0 and not saved.message:
            raise ValueError(f"state.status {Status(saved.status).name} (a failure) needs its "
                             f"message, got an empty one")
        for label, st in (("current", saved.current), ("previous", saved.previous)):
            if st is None and label == "previous":
                continue
            if not isinstance(st, State):
                raise ValueError(f"state.{label} must be a State, got {type(st).__name__}")
            for name in ("u", "v", "a", "f", "p"):
                value = getattr(st, name)
                if value is None and name == "f":       # not kept by every scheme
                    continue
                if not (isinstance(value, np.ndarray) and value.shape == (n,)
                        and value.dtype == np.float64 and np.isfinite(value).all()):
                    raise ValueError(f"state.{label}.{name} must be a finite float array of "
                                     f"shape ({n},), got {brief(value)}")
            if not math.isfinite(st.t):
                raise ValueError(f"state.{label}.t must be finite, got {st.t!r}")
        if self.t_bound is not None and saved.current.t > self.t_bound:
            raise ValueError(f"state.current.t = {saved.current.t!r} is beyond t_bound = "
                             f"{self.t_bound!r}")
        if saved.current.t < self.t0:
            raise ValueError(f"state.current.t = {saved.current.t!r} is before this "
                             f"integrator's t0 = {self.t0!r}")
        if saved.previous is not None and not saved.previous.t < saved.current.t:
            raise ValueError(f"state.previous.t = {saved.previous.t!r} must be before "
                             f"state.current.t = {saved.current.t!r}")
        st = saved.statistics
        if not isinstance(st, Statistics):
            raise ValueError(f"state.statistics must be a Statistics, got "
                             f"{type(st).__name__}")
        for name in _STATISTICS_FIELDS:
            value = getattr(st, name)
            if not (isinstance(value, (int, float)) and value >= 0
                    if name not in ("t_start", "t_reached") else math.isfinite(value)):
                raise ValueError(f"state.statistics.{name} must be a finite count >= 0, got "
                                 f"{value!r}")
        if saved.grid_steps < 0:
            raise ValueError(f"state.grid_steps must be >= 0, got {saved.grid_steps!r}")
        for name in ("work", "energy_error", "energy_scale", "grid_origin"):
            if not math.isfinite(getattr(saved, name)):
                raise ValueError(f"state.{name} must be finite, got {getattr(saved, name)!r}")
        if saved.energy_scale < 0:
            raise ValueError(f"state.energy_scale must be >= 0, got {saved.energy_scale!r}")
        for name in ("potential", "initial_potential"):
            if math.isinf(getattr(saved, name)):     # NaN is the model's "unknown"
                raise ValueError(f"state.{name} must be finite or NaN (unknown), got "
                                 f"{getattr(saved, name)!r}")
        kinetic = self.ev.kinetic_energy(saved.current.v)
        if not math.isfinite(kinetic):
            raise ValueError(f"state.current.v has a kinetic energy beyond floating point "
                             f"({kinetic!r}); no run reaches such a state (Status.OVERFLOW)")
        if not (math.isfinite(saved.proposed_step) and saved.proposed_step > 0):
            raise ValueError(f"state.proposed_step must be finite and > 0, got "
                             f"{saved.proposed_step!r}")
        for name in ("newton_constant", "newton_guard"):
            if not getattr(saved, name) >= 0:
                raise ValueError(f"state.{name} must be >= 0 (inf: none measured), got "
                                 f"{getattr(saved, name)!r}")
        self._check_state_model(saved.current, saved.model_version)

    def _check_state_model(self, current: State, saved_version: int) -> None:
        """The kept force ``f_n`` of a state against this model's ``f(u_n)``.

        The schemes read ``f_n`` and ``a_n`` from the state instead of
        evaluating them: a state of another model of the same size would go
        on with that model's force (an error of 3e-5 against 5e-7 measured).
        ``f`` is a pure function of ``u``, so one evaluation tells the models
        apart; the margin (1e-9 of the largest of ``f``, ``p`` and ``M a``)
        lets the compiled and Python kernels' roundings pass. For a model
        that counts the changes of its parameters (``parameter_version``, as
        :class:`~hfdi.models.symbolic.EnergyModel`) a mismatch under another
        version than the state's is a state saved under other parameters,
        which :meth:`set_state` refreshes; under the same version it is
        another model, refused.
        """
        if current.f is None:
            # Newmark and Bathe keep no f_n (they would need one more force
            # evaluation per step); their states are not told apart by model
            return
        ev = self.ev
        saved_counts = (ev.nfev, ev.njev, ev.ntev, ev.npev, ev.nlu)
        try:
            f = ev.force(current.u)
        except Exception as exc:
            raise ValueError(f"state.current: this model's internal_force fails at its u "
                             f"({type(exc).__name__}: {exc}); the state is of another "
                             f"model") from None
        finally:
            ev.nfev, ev.njev, ev.ntev, ev.npev, ev.nlu = saved_counts
        scale = max(float(np.abs(current.f).max()), float(np.abs(current.p).max()),
                    float(np.abs(ev.mass_times(current.a)).max()))
        mismatch = float(np.abs(f - current.f).max())
        if mismatch <= 1e-9 * scale:
            return
        if self._model_version is not None and saved_version != self.system.parameter_version:
            return                      # the same model under other parameters
        raise ValueError(f"state.current.f differs from this model's internal_force at "
                             f"state.current.u by {mismatch:.3g} (scale {scale:.3g}): the state "
                             f"was saved from another model, or from this one with other "
                             f"parameters")

    def load_changed(self) -> None:
        """Tell the integrator that the load jumps at the current time.

        The current state keeps the load ``p_n`` and the acceleration ``a_n``
        computed when it was reached; the schemes read both (Newmark and Bathe
        through ``a_n``, HFDI through ``p_n`` in its load rate, the energy
        balance through the work). After a jump of the load at ``t_n`` (a
        co-simulation input changed at a communication point), both are
        recomputed from the load now, the acceleration being the right limit.
        """
        self._refresh_load()
        self._sync_counters()

    def model_changed(self) -> None:
        """Tell the integrator that the model changed at the current time (its
        parameters, say); called by itself before its next step when the model
        counts its changes (``parameter_version``, as :class:`EnergyModel` does).

        The current state keeps the internal force ``f_n``, the acceleration
        ``a_n`` and the potential energy computed with the model as it was;
        the schemes read ``f_n`` and ``a_n`` and the energy balance the
        potential. All three are recomputed with the model now (``a_n`` being
        the right limit of the acceleration's jump), so that the energy
        balance (Eq. 40) counts no spurious energy for the change, and the
        step history is dropped as at a load breakpoint: the predictor's and
        the error estimate's extrapolation would run across the jump.

        Raises
        ------
        ModelError
            When the model cannot be evaluated at the current state (the
            integrator is then left as it was).
        """
        s = self._s
        try:
            potential = self.ev.potential_energy(s.current.u)
            self._refresh_load(new_force=True)      # the state is replaced last
        except ModelError:
            raise
        except Exception as exc:
            raise ModelError(f"the changed model cannot be evaluated at the current state "
                             f"(t = {s.current.t:.10g}): {type(exc).__name__}: {exc}") from None
        finally:
            self._sync_counters()
        s.previous = None
        s.potential = potential
        s.newton_constant = s.newton_guard = math.inf     # measured on the model as it was
        self._model_version = getattr(self.system, "parameter_version", None)
        if self._compiled is not None and not library_kernels(self.system,
                                                              self._compiled.kernels):
            self._check_kernels_again()

    def _check_kernels_again(self):
        """The compiled kernels against the changed model at the current state,
        as at construction (:func:`hfdi.compiled.kernel_mismatch`): kernels
        that agreed under the old parameters may not under the new ones (a
        term that vanished). Where they differ, the rest of the run is the
        Python path, said once."""
        cur, system = self._s.current, self.system
        try:
            K = system.stiffness(cur.u)
            T = system.stiffness_derivative(cur.u, cur.v) if isinstance(self.scheme, HFDI) \
                else None
        except Exception:       # not compared; the next step meets it
            return
        initial = InitialValues(cur.t, cur.u, cur.v, cur.f, K, T, self._s.potential,
                                math.inf if self.t_bound is None else self.t_bound)
        reason = kernel_mismatch(system, self._compiled.kernels, initial,
                                 params=self._compiled.params())
        if reason:
            say_once(str(reason), "after the model changed: {reason}; the rest of the run "
                     "is the Python path")
            self._compiled = self._driver = None

    def _follow_model(self) -> bool:
        """:meth:`model_changed` if the model's ``parameter_version`` moved;
        ``False`` (status MODEL_ERROR) when the changed model fails there."""
        if self._model_version is None or self.system.parameter_version == self._model_version:
            return True
        try:
            self.model_changed()
        except ModelError as exc:
            return self._fail(Status.MODEL_ERROR, str(exc))
        return True

    def _refresh_load(self, new_force=False):
        """The current state with ``p_n`` and ``a_n`` (the right limit) from
        the load now, and ``f_n`` too with ``new_force`` (or when not kept)."""
        current = self._s.current
        p = self.ev.load(current.t)
        f = self.ev.force(current.u) if new_force or current.f is None else current.f
        a = self.ev.acceleration(current.t, current.u, current.v, f, p)
        self._s.current = State(current.t, current.u, current.v, a, f, p)

    # -- stepping ------------------------------------------------------------
    def _initial_state(self, u0, v0):
        """The initial :class:`State`, ``K(u0)``, ``T(u0)[v0]`` (HFDI only, else
        ``None``) and ``V(u0)``, every model function checked once.

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
        T = None
        if self.check_stiffness:
            self._check_stiffness(u0, f, K, call, name)
        if isinstance(self.scheme, HFDI):
            T = call("stiffness_derivative", ev.stiffness_derivative, u0, v0)
            if self.scheme.load_rate == "exact" or (self.scheme.load_rate == "auto"
                                                     and ev.has_load_rate):
                call("load_rate", ev.load_rate, t0)
                if self.check_stiffness:
                    self._check_load_rate(call, name)
        potential = call("potential_energy", ev.potential_energy, u0)
        if math.isinf(potential):
            raise ModelError(f"model {name!r}: potential_energy is {potential} {where}; the "
                             f"energy balance (Eq. 40) cannot start there")
        a = ev.acceleration(t0, u0, v0, f, p)
        if not np.all(np.isfinite(a)):
            raise ModelError(f"model {name!r}: the initial acceleration "
                             f"M⁻¹(p − f − C v0) is not finite ({brief(a)}) {where}")
        return State(t0, u0.copy(), v0.copy(), a, f, p), K, T, potential

    def _check_stiffness(self, u0, f, K, call, name):
        """``K(u0)`` against central differences of ``f`` along one direction.

        HFDI uses ``K`` in its step equation (``g_t = p' − K v``), so a wrong
        ``K`` gives wrong answers there, not only a slow Newton; in every
        scheme it is a mistake in the model.

        Each degree of freedom is perturbed relative to its own size,
        ``d_i = s·√ε·max(|u0_i|, 1e-3·U) w_i`` (``U = max(max|u0|, u_scale)``,
        ``w`` a fixed direction), so that a rotation beside translations in
        mm is not perturbed by a large part of itself. At each scale ``s``
        (1, 1e2, 1e4, 1e6) the mismatches of the central differences at
        ``d`` and ``2d`` with ``K d`` and ``2 K d`` are Richardson-combined,
        ``(8 m(d) − m(2d))/6``, which cancels the ``O(d³)`` of the
        nonlinearity (a pure cubic spring at rest) and leaves ``(∂f/∂u − K) d``.
        Row ``i`` counts at a scale where the rounding of ``f`` there is below
        1e-4 of its terms ``Σ_j |K_ij d_j|`` (a large preload in ``f`` hides a
        wrong ``K`` at small ``d``), and its error is the smallest over the
        scales that count (rounding inside ``f``, large terms cancelling, is
        gone at a larger ``d``; a kink near ``u0`` at a smaller one). A row
        whose error is above 0.1 % of its terms is refused; a row that never
        counts (``K`` zero there) is not judged. 4 force evaluations when
        every row passes at the first scale, up to 16; beyond the first scale
        a failing evaluation (a model leaving its domain) only drops that
        scale.
        """
        ev = self.ev
        w = np.sin(np.arange(1, ev.n + 1) * 2.399963229728653)  # golden angle: no zero
        size_u = max(float(np.abs(u0).max()), self.floor)
        base = _SQRT_EPS * np.maximum(np.abs(u0), 1e-3 * size_u) * w
        n = ev.n
        best = np.full(n, np.inf)
        best_scale = np.zeros(n)
        for scale in (1.0, 1e2, 1e4, 1e6):
            steps, values = [], []
            try:
                for factor in (1.0, 2.0):
                    d = (u0 + factor * scale * base) - u0        # the step as represented
                    plus = call("internal_force", ev.force, u0 + d)
                    minus = call("internal_force", ev.force, u0 - d)
                    steps.append(d)
                    values.append((plus, minus))
            except ModelError:
                if scale == 1.0:
                    raise
                break
            (d1, d2), ((p1, q1), (p2, q2)) = steps, values
            m1 = 0.5 * (p1 - q1) - np.asarray(K @ d1).ravel()
            m2 = 0.5 * (p2 - q2) - np.asarray(K @ d2).ravel()
            error = np.abs(8.0 * m1 - m2) / 6.0
            terms = np.asarray(abs(K) @ np.abs(d1)).ravel()
            rounding = 16.0 * _EPS * (np.abs(p1) + np.abs(q1) + np.abs(p2) + np.abs(q2))
            counts = (terms > 0) & (rounding <= 1e-4 * terms)
            with np.errstate(divide="ignore", invalid="ignore"):
                relative = np.where(counts, error / terms, np.inf)
            better = relative < best
            best[better], best_scale[better] = relative[better], scale
            if not np.any((terms > 0) & ~(best <= 1e-3)):
                break           # every row that can be judged has passed: no scale fails it
        judged = np.isfinite(best)
        if not judged.any():
            return
        worst = int(np.argmax(np.where(judged, best, -1.0)))
        if best[worst] > 1e-3:
            largest = float(np.abs(base).max()) * best_scale[worst]
            raise ModelError(
                f"model {name!r}: stiffness does not match internal_force at u0: in row "
                f"{worst}, K(u0)·d and the central differences of f (|d| ≤ {largest:.3g}, "
                f"Richardson-extrapolated; the best of the steps 1 … 1e6 times that) "
                f"differ by {best[worst]:.2%} of the size of the row's terms. K must be "
                f"∂f/∂u: HFDI uses it in its step equation, where a wrong K gives a wrong "
                f"answer (check the model with hfdi.check_derivatives; pass "
                f"check_stiffness=False only if f has a kink at u0)")

    def _check_load_rate(self, call, name):
        """``p'(t0)`` against forward differences of ``p`` (:func:`load_rate_error`).

        HFDI puts ``p'`` into its step equation (``g_t = p' − K v``), so a
        wrong rate gives a wrong answer that no tolerance shows: a rate 5 times
        too large was off by 800 times the tolerance at rtol 1e-6. The
        differences are taken at steps of ``10^-2 … 10^-13`` times the run's
        span (1 where it is not known) that end before the load's next
        breakpoint, and the best agreement counts, so a correct rate of a load
        of any time scale passes; a mismatch above 0.1 % is refused, as for
        ``K``; a rate that cannot be judged (below the rounding of ``p``) is
        not.
        """
        ev, t0 = self.ev, self.t0
        scale = self.t_bound - t0 if self.t_bound is not None else 1.0
        # every breakpoint, the model's and the given ones, whether the mode
        # lands on them or not: a jump inside the differences hides a wrong rate
        try:
            points = self.breakpoints if self.breakpoints.size else \
                self._breakpoints(self._given_breakpoints)
        except Exception:              # not times: the run says so where it lands on them
            points = np.empty(0)
        later = points[points > t0]
        horizon = float(later.min()) if later.size else math.inf
        mismatch = call("load", lambda: load_rate_error(ev.load, ev.load_rate, t0, scale,
                                                        horizon))
        if mismatch > 1e-3:
            raise ModelError(
                f"model {name!r}: load_rate does not match load at t0 = {t0:g}: p'(t0) and "
                f"forward differences of p differ by {mismatch:.3g} of their size at the "
                f"best of the steps {scale * 1e-2:.3g} … {scale * 1e-13:.3g}. HFDI uses p' in "
                f"its step equation, where a wrong rate gives a wrong answer (check the model "
                f"with hfdi.check_derivatives; check_stiffness=False skips the checks of K "
                f"and p')")

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

    def _limit(self, t_limit: float) -> float:
        """``t_limit``, or the next load breakpoint before it (with a fixed step,
        the next one on its grid: :meth:`_on_grid`)."""
        bp = self.breakpoints
        if bp.size:
            i = int(np.searchsorted(bp, self.t, side="right"))
            while i < bp.size and bp[i] < t_limit:
                if not self.fixed or self._on_grid(float(bp[i])):
                    return float(bp[i])
                i += 1
        return t_limit

    def _clip(self, h: float, t_limit: float):
        """The end time of a step of proposed size ``h`` that must not pass
        ``t_limit``, and whether it lands there (the controller's landing
        rule; the fixed step's grid)."""
        t = self.t
        remaining = t_limit - t
        if self.fixed:
            s = self._s
            t_next = s.grid_origin + (s.grid_steps + 1) * h
            # within a millionth of the step the grid point is t_limit itself
            if t_next >= t_limit - 1e-6 * h:
                return t_limit, True
            return t_next, False
        take = self.controller.landing(h, remaining)
        if take >= remaining:
            return t_limit, True
        return t + take, take != h

    def _left_limit_at(self, t_end: float, t_limit: float):
        """``t_end`` when a step ending there takes the load's left limit (it
        lands on a breakpoint), else ``None`` (for ``Evaluator.left_limit_at``)."""
        return t_end if (self.breakpoints.size and t_end == t_limit
                         and t_end in self.breakpoints) else None

    def _try(self, proposed: float, t_limit: float, landing=None):
        """One attempt of proposed size ``proposed`` towards ``t_limit``, as an
        :class:`~hfdi.controller.Attempt` (``None`` below the resolution of time);
        ``landing``: ``_clip(proposed, t_limit)`` when the caller has it."""
        s = self._s
        current, previous = s.current, s.previous
        t_end, clipped = self._clip(proposed, t_limit) if landing is None else landing
        h = t_end - current.t
        if not h > 0.0:
            return None
        ev = self.ev
        ev.left_limit_at = self._left_limit_at(t_end, t_limit)
        try:
            if self._compiled is not None:
                outcome = self._compiled.solve_step(current, previous, t_end, self.tol,
                                                    self.floor, self.max_iterations,
                                                    (s.newton_constant, s.newton_guard),
                                                    self._estimated)
            else:
                outcome = solve_step(ev, self.scheme, current, t_end,
                                     lambda offset: predict(current, previous, offset),
                                     self.tol, self.floor, self.max_iterations,
                                     (s.newton_constant, s.newton_guard), self._estimated)
        finally:
            ev.left_limit_at = None
        if outcome.converged:
            # what the corrector measured (a failed attempt's measurements are
            # not kept: the compiled attempt reports them only on success)
            s.newton_constant, s.newton_guard = outcome.newton_memory
        attempt = Attempt(h, proposed, clipped, outcome.converged, outcome.total_iterations,
                          outcome.message, history=previous is not None)
        attempt.outcome = outcome
        if outcome.converged and self.controller.uses_error_estimate:
            new = outcome.state
            attempt.y_start = np.concatenate([current.u, current.v])
            attempt.y_end = np.concatenate([new.u, new.v])
            attempt.error = local_error(current, previous, new, h, self.scheme.order)
            # every scheme forms v from the step's u's divided by h, with
            # coefficients summing to scheme.velocity_gain (3 for HFDI, 4 for
            # the trapezoidal rule, 8 for Bathe's γ = 1/2): the corrector's
            # remaining error in u, and rounding, make v uncertain by about
            # velocity_gain·(error + ε‖u‖)/h, below which its error can be
            # neither told nor controlled
            attempt.velocity_noise = self.scheme.velocity_gain * (
                outcome.newton_error + _EPS * float(np.abs(new.u).max())) / h
        return attempt

    def _short_step(self, t_end: float, t_limit: float) -> bool:
        """A short step to ``t_end`` (towards ``t_limit``; :func:`hfdi.corrector.short_step`),
        accepted as it is: its error is far below the scheme's at the proposed
        step, and the proposed step carries over."""
        s = self._s
        current = s.current
        ev = self.ev
        h = t_end - current.t
        if h * fastest_rate(ev, current.u) > SHORT_STEP_RATE:
            return self._short_step_of_the_scheme(t_end, t_limit)
        ev.left_limit_at = self._left_limit_at(t_end, t_limit)
        try:
            new = short_step(ev, current, t_end, keep_force=type(self.scheme) is HFDI)
        finally:
            ev.left_limit_at = None
        if not (all_finite(new.u) and all_finite(new.v) and all_finite(new.a)):
            return self._fail(Status.MODEL_ERROR, f"the short step of {h:.3g} to t = "
                                                  f"{t_end:.10g} gives values that are not "
                                                  "finite")
        s.statistics.steps += 1
        attempt = Attempt(h, s.proposed_step, True, True, 0)
        attempt.outcome = StepOutcome(new, [0])
        return self._accept(attempt)

    def _short_step_of_the_scheme(self, t_end: float, t_limit: float) -> bool:
        """A short step past a stiff component (see :data:`hfdi.corrector.SHORT_STEP_RATE`),
        taken by the scheme and accepted as the Taylor step is: the proposed
        step carries over and the step does not become the history."""
        s = self._s
        st = s.statistics
        attempt = self._try(s.proposed_step, t_limit, (t_end, True))
        st.steps += 1
        st.newton_iterations += attempt.iterations
        if attempt.converged:
            return self._accept(attempt)
        st.rejected += 1
        return self._fail(Status.NEWTON_FAILED,
                          f"the short step of {attempt.h:.3g} to t = {t_end:.10g} failed: "
                          f"{attempt.message}")

    def _accept(self, attempt) -> bool:
        s = self._s
        ev = self.ev
        outcome, h = attempt.outcome, attempt.h
        old, new = s.current, outcome.state
        try:
            potential = ev.potential_energy(new.u)
        except Exception as exc:
            # the converged state is not accepted: the run keeps its last good state
            return self._fail(Status.MODEL_ERROR,
                              f"potential_energy failed at the end of the step to t = "
                              f"{new.t:.10g}: {type(exc).__name__}: {exc}")
        if potential_lost(potential, s.initial_potential):
            return self._fail(Status.MODEL_ERROR,
                              f"potential_energy is NaN (unknown) at the end of the step to "
                              f"t = {new.t:.10g}, but was {s.initial_potential:.10g} at the "
                              f"start: a model gives V everywhere or nowhere (NaN); the "
                              f"energy balance would be NaN from here on")
        kinetic_old, kinetic_new = ev.kinetic_energy(old.v), ev.kinetic_energy(new.v)
        # Eq. 41, the trapezoidal rule over the points where the scheme samples
        # the load: the step's ends, and Bathe's mid-step, whose load the
        # scheme does feel and an end-point rule would miss.
        work = 0.0
        for a, b in zip([old, *outcome.stages], [*outcome.stages, new]):
            work += 0.5 * float((b.u - a.u) @ (a.p + b.p))
        if energy_overflows(kinetic_new, work, potential):
            # finite values whose energies are not: accepting the state would
            # make the energy balance (and every later step's) inf or NaN
            return self._fail(Status.OVERFLOW,
                              f"the step to t = {new.t:.10g} overflows: kinetic energy "
                              f"{kinetic_new:.4g}, work of the load {work:.4g}, potential "
                              f"energy {potential:.4g} (a load or state too large for "
                              f"floating point)")
        increment = potential - s.potential + kinetic_new - kinetic_old - work  # Eq. 40
        if not is_short(h, s.proposed_step):       # a short step is no history
            s.previous = old
        s.current = new
        if self.fixed:
            if attempt.clipped and new.t != s.grid_origin + (s.grid_steps + 1) * h \
                    and abs(new.t - (s.grid_origin + (s.grid_steps + 1) * attempt.proposed)) \
                    > 1e-6 * attempt.proposed:
                s.grid_origin, s.grid_steps = new.t, 0   # shortened off the grid
            else:
                s.grid_steps += 1
        self._arrival = new
        if self.breakpoints.size and new.t in self.breakpoints:
            # a kink or jump of the load: the history behind it would spoil the
            # predictor, and the next step starts from the load's right limit
            s.previous = None
            self._refresh_load()
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
            return self._energy_growth()
        self._mark_finished()
        return True

    def _energy_growth(self) -> bool:
        s = self._s
        return self._fail(Status.ENERGY_GROWTH,
                          f"energy balance broke down: spurious energy {s.energy_error:.4g} "
                          f"exceeds {self.energy_limit:g} x energy scale {s.energy_scale:.4g}")

    def _native_synced(self, taken: int, cpu_time: float) -> None:
        """After :meth:`hfdi.compiled.NativeAdvance.sync` wrote ``taken`` accepted
        steps of native calls into the state: what :meth:`_drive` does after
        the compiled driver returned."""
        self._s.statistics.cpu_time += cpu_time
        self._sync_counters()
        if taken:
            self._arrival = self._s.current
        self._mark_finished()

    def _mark_finished(self):
        if self.finished:
            self._s.status = int(Status.SUCCESS)
            self._s.message = f"reached t_bound = {self.t_bound!r}"

    def step(self, t_limit: float = math.inf) -> bool:
        """Take one accepted step, not beyond ``t_limit``.

        Rejected attempts are retried as the controller says (halved after a
        diverged corrector). Returns ``False`` when no step was taken: a guard
        stopped the run (:attr:`status` and :attr:`message` say why, and
        :attr:`state` is the last good state), the integrator is
        :attr:`finished` (status ``SUCCESS``), or ``t_limit`` is the current
        time (so that ``while integrator.step(T)`` ends at ``T``).

        Raises
        ------
        ValueError
            For ``t_limit`` before the current time.
        """
        if not (self.failed or self.finished) and _time_value("t_limit", t_limit) == self.t:
            return False
        return self._step(t_limit)

    def _step(self, t_limit: float, rejections: int = 0) -> bool:
        """:meth:`step`, for a step that has had ``rejections`` rejected attempts
        already (in the compiled driver, which hands such a step over)."""
        if self.failed or self.finished:
            return False
        t_limit = _time_value("t_limit", t_limit)
        if not t_limit > self.t:
            raise ValueError(f"t_limit must be > t = {self.t}, got {t_limit!r}")
        if not self._follow_model():
            return False
        if self.t_bound is not None:
            t_limit = min(t_limit, self.t_bound)
        start = time.process_time()
        try:
            if self._s.first_step_pending:
                limit = self._limit(t_limit)
                if 0.0 < limit - self.t and is_short(limit - self.t, self._s.proposed_step):
                    # before the first step too; the controller's init stays pending
                    return self._short_step(limit, limit)
                return self._first_step(limit)
            return self._regular_step(t_limit, rejections)
        except ModelError as exc:
            # a wrong shape mid-run: retrying cannot help, and raising would
            # lose the run of integrate(); stop with the last good state
            return self._fail(Status.MODEL_ERROR, f"the model returned an unusable value in "
                                                  f"a step from this time: {exc}")
        finally:
            self._sync_counters()
            self._cpu(start)

    def _regular_step(self, t_limit, rejections=0):
        s = self._s
        st = s.statistics
        limit = self._limit(t_limit)
        while True:
            if st.steps >= self.max_steps:
                before = f" before t = {t_limit:.10g}" if math.isfinite(t_limit) else ""
                return self._fail(Status.MAX_STEPS,
                                  f"max_steps = {self.max_steps} reached (attempts, rejected "
                                  f"ones included){before}")
            landing = self._clip(s.proposed_step, limit)
            h = landing[0] - self.t
            if 0.0 < h and is_short(h, s.proposed_step):
                return self._short_step(landing[0], limit)
            attempt = self._try(s.proposed_step, limit, landing)
            if attempt is None:
                # the step went below the spacing of floating-point times at t
                return self._fail(Status.STEP_BELOW_MINIMUM,
                                  f"step {s.proposed_step:.6g} is below the resolution of "
                                  f"time at t")
            st.steps += 1
            st.newton_iterations += attempt.iterations
            decision = self.controller.adapt(attempt, rejections)
            if decision.accept:
                s.proposed_step = decision.next_step
                return self._accept(attempt)
            st.rejected += 1
            if attempt.converged:
                st.error_test_failures += 1
            if decision.status is not None:
                return self._fail(Status[decision.status],
                                  f"{decision.message} (to t = {self.t + attempt.h:.10g})")
            s.proposed_step = decision.next_step
            rejections += 1

    def _first_step(self, t_limit):
        """The first step, chosen by the controller's ``init``. Its trials
        other than the accepted one are counted apart from the steps."""
        s = self._s
        st = s.statistics

        def trial(h):
            attempt = self._try(h, t_limit)
            if attempt is not None:
                st.first_step_trials += 1
                st.first_step_trial_iterations += attempt.iterations
            return attempt

        attempt, decision = self.controller.init(trial, s.proposed_step)
        if attempt is None:
            return self._fail(Status[decision.status or "FIRST_STEP_FAILED"], decision.message)
        # The accepted trial is the run's first step; the others are reported apart.
        st.first_step_trial_iterations -= attempt.iterations
        st.steps += 1
        st.newton_iterations += attempt.iterations
        s.first_step_pending = False
        s.proposed_step = decision.next_step
        return self._accept(attempt)

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
        t_stop = _time_value("t_stop", t_stop)
        checks.callable_or_none("callback", callback, "callback(integrator)")
        if not math.isfinite(t_stop) or t_stop < self.t:
            raise ValueError(f"t_stop must be finite and >= t = {self.t}, got {t_stop!r}")
        if self.t_bound is not None and t_stop > self.t_bound:
            raise ValueError(f"t_stop must be <= t_bound = {self.t_bound}, got {t_stop!r}")
        if self.failed:             # even at t_stop = t: the run did not get there well
            return False
        if callback is None and self._driver is not None:
            return self._drive(t_stop)
        return self._python_steps(t_stop, callback)

    def _python_steps(self, t_stop, callback) -> bool:
        """:meth:`advance` in the Python driver."""
        while self.t < t_stop:
            if not self._python_step(t_stop, callback):
                return False
        return True

    def _python_step(self, t_stop, callback, rejections=0) -> bool:
        """One step of the Python driver (from ``rejections`` rejected attempts),
        then ``callback(self)`` after an accepted one."""
        ok = self._step(t_stop, rejections)
        if callback is not None and self.statistics.accepted and (
                ok or self._s.status == Status.ENERGY_GROWTH):
            callback(self)
        return ok

    def _drive(self, t_stop: float, rows=None, callback=None) -> bool:
        """:meth:`advance` through the compiled driver (:mod:`hfdi.compiled.driver`).

        The driver takes the ordinary steps; the first step and every step it
        hands over (a breakpoint, a stop, ``max_steps``) run here, each
        followed by ``callback(self)``. ``rows(arrays)`` receives the driver's
        accepted steps in bulk (the arrays of :class:`Result`), in order with
        the callbacks.
        """
        while self.t < t_stop:
            if self.failed:
                return False
            if not self._follow_model():
                return False
            driver = self._driver
            if driver is None:          # dropped by a change of the model or a fault
                return self._python_steps(t_stop, callback)
            held = driver.held_load(self)
            if self._s.first_step_pending or held is None:
                # the controller's init; or a faulty held load, which the
                # Python driver reports as it does any faulty load
                if not self._python_step(t_stop, callback):
                    return False
                continue
            start = time.process_time()
            limit = t_stop if self.t_bound is None else min(t_stop, self.t_bound)
            try:
                reason, taken, arrays, pending = driver.run(self, limit, rows is not None, held)
            except Exception as exc:
                # a kernel raised inside the driver, which loses the steps of
                # this call with it (the state is still the call's start). The
                # Python driver takes them again and the rest of the run around
                # the compiled attempt, where a raise is a failed attempt, as a
                # raising model is on the Python path.
                self._cpu(start)
                self._driver = None
                say_once(f"{type(exc).__name__}: {exc}",
                         "a compiled kernel raised {reason} in the compiled driver; the rest "
                         "of the run takes its steps in the Python driver")
                return self._python_steps(t_stop, callback)
            self._cpu(start)
            self._sync_counters()
            if taken:
                self._arrival = self._s.current
                if rows is not None:
                    rows(arrays)
            if reason == driver.ENERGY_CHECK:
                return self._energy_growth()
            self._mark_finished()
            if reason == driver.HAND_OVER and not self._python_step(t_stop, callback, pending):
                return False
        return True


@dataclass
class Result:
    """Solution of :func:`integrate`.

    Attributes
    ----------
    t : ndarray (n,)
        Times of the initial state and of every accepted step (with
        ``save_steps=False``: of the initial and the last state only). At a
        declared load breakpoint where the acceleration jumps, the time is
        there twice: the state the step reached (the load's left limit),
        then the one the next step starts from (a step of size 0).
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
    t_eval : ndarray (m,) or None
        The requested output times.
    u_eval, v_eval : ndarray (m, N) or None
        ``u`` and ``v`` there, by the dense output (NaN past the end of a
        failed run).
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
    t_eval: np.ndarray | None = None
    u_eval: np.ndarray | None = None
    v_eval: np.ndarray | None = None
    system: SecondOrderSystem | None = field(default=None, repr=False)
    steps_saved: bool = True

    @property
    def success(self) -> bool:
        return self.status == Status.SUCCESS

    @property
    def sol(self) -> Solution:
        """Dense output over the run: ``sol(t)`` gives ``(u, v)`` at any ``t``
        in ``[t[0], t[-1]]`` by Hermite interpolants on the step ends
        (:class:`~hfdi.dense.Solution`: quintic in ``u``, cubic in ``v``)."""
        if not self.steps_saved:
            raise ValueError("sol needs the steps: this run was made with save_steps=False")
        return Solution(self.t, self.u, self.v, self.a)

    def quantities(self, system: SecondOrderSystem | None = None) -> dict:
        """The quantities of interest of ``system`` (default: the model
        integrated) at ``t``, a dict of (n, m) arrays."""
        return (system or self.system).quantities(self.t, self.u, self.v)

    def __repr__(self):
        st = self.stats
        return (f"Result(scheme={self.scheme!r}, status={self.status.name}, steps={st.steps}, "
                f"mean_iterations={st.mean_iterations:.3f}, mean_step={st.mean_step:.4g}, "
                f"t_final={self.t[-1]:.6g})")


class _Rows:
    """Per-step records in blocks of arrays: a step of the Python driver costs a
    copy of its numbers into the open block (grown by doubling), a call of the
    compiled driver hands over its own rows as a block (views of its buffers,
    or a copy when it filled less than half of them), and :meth:`arrays`
    joins the blocks once."""

    def __init__(self, n: int):
        self.n = n
        self.size = 0                 # rows in all blocks
        self._blocks = []             # sealed blocks: dicts of arrays of equal length
        self._open = 0                # rows in the open block
        self._alloc(64)

    def _alloc(self, capacity):
        old = getattr(self, "data", None)
        self.data = {"t": np.empty(capacity), "u": np.empty((capacity, self.n)),
                     "v": np.empty((capacity, self.n)), "a": np.empty((capacity, self.n)),
                     "step_size": np.empty(capacity), "iterations": np.empty(capacity, int),
                     "energy_increment": np.empty(capacity), "total_energy": np.empty(capacity),
                     "external_work": np.empty(capacity)}
        if old is not None:
            for key, arr in old.items():
                self.data[key][:self._open] = arr[:self._open]

    def append(self, state: State, h, iterations, increment, energy, work):
        if self._open == self.data["t"].shape[0]:
            self._alloc(2 * self._open)
        i = self._open
        d = self.data
        d["t"][i] = state.t
        d["u"][i] = state.u
        d["v"][i] = state.v
        d["a"][i] = state.a
        d["step_size"][i] = h
        d["iterations"][i] = iterations
        d["energy_increment"][i] = increment
        d["total_energy"][i] = energy
        d["external_work"][i] = work
        self._open += 1
        self.size += 1

    def _seal(self):
        if self._open:
            # a copy of the rows, not a view that would keep the whole open
            # block; the open block is then written again from its start
            self._blocks.append({key: arr[:self._open].copy() for key, arr in self.data.items()})
            self._open = 0

    def extend(self, arrays: dict):
        """Append the rows of ``arrays`` (the keys of :meth:`arrays`), kept as
        they are: the caller gives up the arrays."""
        self._seal()
        self._blocks.append(arrays)
        self.size += arrays["t"].shape[0]

    def arrays(self) -> dict:
        blocks = self._blocks + ([{key: arr[:self._open] for key, arr in self.data.items()}]
                                 if self._open or not self._blocks else [])
        if len(blocks) == 1:
            return {key: np.array(arr) for key, arr in blocks[0].items()}
        return {key: np.concatenate([block[key] for block in blocks]) for key in self.data}


def _time_value(name, value) -> float:
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


def _times(name, value, t0, t_end):
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


#: Wall-clock seconds between two calls of integrate's progress callback.
PROGRESS_INTERVAL = 0.5


def integrate(system: SecondOrderSystem, scheme, t_end, *, rtol=None, atol=None,
              target_iterations=None, step=None, u0=None, v0=None, t0=0.0, t_eval=None,
              save_steps=True, progress=None, tol=None, **options) -> Result:
    """Integrate ``M u'' + C u' + f(u) = p(t)`` from ``t0`` to ``t_end``.

    The mode follows the arguments (see :class:`Integrator`): error control
    with ``rtol``/``atol`` — the default, at ``rtol = 1e-4`` —, the paper's
    iteration count with ``target_iterations`` alone (it does not control the
    error), both combined, or a fixed ``step``.

    Parameters
    ----------
    system : SecondOrderSystem
    scheme : {"newmark", "bathe", "hfdi"} or Scheme
    t_end : float
    rtol, atol : float or array_like (N,), optional
        Tolerances of the local error of ``u``; see :class:`Integrator`.
    target_iterations : float, optional
        ``N̄`` per (sub-)step; see :class:`Integrator`.
    step : float, optional
        Fixed step size.
    u0, v0 : array_like (N,), optional
    t0 : float
    t_eval : array_like (m,), optional
        Output times in ``[t0, t_end]``, at most ``max_steps`` of them; ``u``
        and ``v`` there come from the dense output (``u_eval``,
        ``v_eval``). They do not change the steps.
    save_steps : bool
        Keep every accepted step (``t``, ``u``, ..., and ``sol``). With
        ``False`` only the initial and last states and the ``t_eval``
        outputs are kept: memory independent of the number of steps.
    progress : callable ``progress(t, statistics)``, optional
        Called every half second of wall-clock time with the time reached and
        the run's :class:`Statistics`, and once at the end, so that a long or
        stalled run shows.
    tol : float, optional
        Newton tolerance ``η`` (Eq. 38); see :class:`Integrator`.
    **options
        Passed to :class:`Integrator` (``first_step``, ``min_step``,
        ``max_step``, ``max_halvings``, ``max_steps``, ``max_iterations``,
        ``energy_limit``, ``controller``, ``breakpoints``, ...).

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
        if isinstance(t_end, (str, bytes, bool, np.bool_)) or np.ndim(t_end) != 0:
            raise TypeError
        t_end = float(t_end)
    except (TypeError, ValueError):
        raise ValueError(f"t_end must be a number > t0 = {t0}, got {t_end!r}") from None
    if not (math.isfinite(t_end) and t_end > t0):
        raise ValueError(f"t_end must be finite and > t0 = {t0}, got {t_end!r}")
    if t_eval is not None:
        t_eval = _times("t_eval", t_eval, t0, t_end)
        max_steps = options.get("max_steps", inspect.signature(Integrator).parameters[
            "max_steps"].default)
        if t_eval.size > max_steps:
            raise ValueError(f"t_eval has {t_eval.size} points, more than max_steps = "
                             f"{max_steps}; give fewer output times or raise max_steps")
    if not isinstance(save_steps, (bool, np.bool_)):
        raise ValueError(f"save_steps must be True or False, got {save_steps!r}")
    if progress is not None and not callable(progress):
        raise ValueError(f"progress must be callable as progress(t, statistics), got "
                         f"{progress!r}")
    allowed = [name for name in inspect.signature(Integrator).parameters
               if name not in ("system", "scheme", "rtol", "atol", "target_iterations", "step",
                               "t0", "u0", "v0", "tol", "t_bound")]
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ValueError(f"unknown option(s) {', '.join(unknown)} of integrate; allowed: "
                         f"{', '.join(allowed)}")
    integrator = Integrator(system, scheme, rtol=rtol, atol=atol,
                            target_iterations=target_iterations, step=step, t0=t0, u0=u0, v0=v0,
                            tol=tol, t_bound=t_end, **options)
    s0 = integrator.state
    rows = _Rows(integrator.ev.n)
    rows.append(s0, math.nan, 0, 0.0, integrator.total_energy, 0.0)
    last = [s0, math.nan, 0, 0.0, integrator.total_energy, 0.0]
    if t_eval is not None:
        u_eval = np.full((t_eval.size, integrator.ev.n), np.nan)
        v_eval = np.full_like(u_eval, np.nan)
        at_start = t_eval == t0
        u_eval[at_start], v_eval[at_start] = s0.u, s0.v
        pending = [int(np.count_nonzero(at_start))]   # index of the next t_eval point
    clock = [time.monotonic()]

    def outputs(t, u, v, a):
        """The t_eval points up to ``t[-1]``, from the steps that start at the
        last one recorded and end at ``t`` (K,), with ``u, v, a`` (K, N) there."""
        if t_eval is not None and pending[0] < t_eval.size:
            stop = int(np.searchsorted(t_eval, t[-1], side="right"))
            if stop > pending[0]:
                old = last[0]          # where the first of these steps started
                ue, ve = interpolate_state(np.concatenate([[old.t], t]),
                                           np.vstack([old.u[None], u]),
                                           np.vstack([old.v[None], v]),
                                           np.vstack([old.a[None], a]), t_eval[pending[0]:stop])
                u_eval[pending[0]:stop], v_eval[pending[0]:stop] = ue, ve
                pending[0] = stop

    def report(t):
        if progress is not None and time.monotonic() - clock[0] >= PROGRESS_INTERVAL:
            clock[0] = time.monotonic()
            progress(t, integrator.statistics)

    def record(itg: Integrator):
        new = itg._arrival                      # the state the step reached
        restart = itg.state                     # the next one's start: differs after a jump
        outputs(np.array([new.t]), new.u[None], new.v[None], new.a[None])
        entry = (new, itg.last_step, itg.last_iterations, itg.last_energy_increment,
                 itg.total_energy, itg.external_work)
        if save_steps:
            rows.append(*entry)
        if restart is not new and not itg.finished and not np.array_equal(restart.a, new.a):
            entry = (restart, 0.0, 0, 0.0, itg.total_energy, itg.external_work)
            if save_steps:
                rows.append(*entry)
        last[:] = entry
        report(new.t)

    def record_rows(arrays: dict):
        """:func:`record` for the steps of the compiled driver, in bulk."""
        t = arrays["t"]
        outputs(t, arrays["u"], arrays["v"], arrays["a"])
        if save_steps:
            rows.extend(arrays)
        last[:] = [State(float(t[-1]), arrays["u"][-1], arrays["v"][-1], arrays["a"][-1], None,
                         None), float(arrays["step_size"][-1]), int(arrays["iterations"][-1]),
                   float(arrays["energy_increment"][-1]), float(arrays["total_energy"][-1]),
                   float(arrays["external_work"][-1])]
        report(float(t[-1]))

    if integrator.driven:
        ok = integrator._drive(t_end, rows=record_rows, callback=record)
    else:
        ok = integrator.advance(t_end, callback=record)
    if progress is not None:
        progress(integrator.t, integrator.statistics)
    if not save_steps and rows.size == 1 and integrator.statistics.accepted:
        rows.append(*last)
    status = integrator.status if not ok else Status.SUCCESS
    message = integrator.message if not ok else "reached t_end"
    result = Result(**rows.arrays(), status=status, message=message,
                    stats=copy.copy(integrator.statistics), scheme=integrator.scheme.name,
                    t_eval=t_eval, u_eval=None if t_eval is None else u_eval,
                    v_eval=None if t_eval is None else v_eval, system=system,
                    steps_saved=save_steps)
    return result
