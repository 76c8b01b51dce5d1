"""The adaptive predictor–corrector integrator (paper Sections 4–5).

:class:`Integrator` is a small stateful solver in the manner of
``scipy.integrate``'s: :meth:`Integrator.step` takes one accepted step,
:meth:`Integrator.advance` continues to a given time and lands on it exactly,
and :meth:`Integrator.get_state` / :meth:`Integrator.set_state` copy and
restore everything that determines the rest of the run.

The steps are the stepping code's (:mod:`hfdi.stepping`), one implementation
at two speeds: compiled when the model has compiled kernels
(:mod:`hfdi.compiled`), as Python otherwise (the model's own methods through
the :class:`~hfdi.evaluation.Evaluator`). A controller object of the user's
runs the same attempts and acceptance from a Python loop (:mod:`hfdi.custom`).
"""
from __future__ import annotations

import math
import time

import numpy as np

from . import checks, compiled as compiled_path, run_records
from .controller import ErrorControl, FixedStep, core_kind
from .core import codes
from .core.state import COMBINED, CUSTOM, ERROR, RUN
from .core.state import HFDI as HFDI_STAGE
from .evaluation import Evaluator, ModelError, ModelFault, State
from .compiled_steps import CompiledSteps
from .event_steps import EventSteps
from .state_access import StateAccess
from .messages import Status, stop_message
from .options import (NEWTON_TESTS, breakpoints_of, fit_error_control, initial_vector,
                      driven_scale, make_controller, needs_driven_scale,
                      newton_tolerance, optional_positive, time_value)
from .preflight import default_first_step, initial_state
from .result import STATISTICS_FIELDS, Statistics
from .schemes import HFDI, Scheme, get_scheme
from .stepping import attempt as stepping
from .stepping.loop import advance as advance_python
from .stepping.stages import AFFINE_STAGES, HFDI_STAGES
from .system import HeldLoad, SecondOrderSystem, declared_u_scale

__all__ = ["Integrator", "ROWS_PER_CALL", "STEPS_PER_CALL"]

#: Rows of accepted steps the stepping code writes per call before it hands
#: them over (and Python gets control back: Ctrl-C is seen between calls).
ROWS_PER_CALL = 2048
#: At most this many accepted steps per call of the stepping code: between
#: calls control is back in Python, where a KeyboardInterrupt is seen (a
#: compiled loop cannot be interrupted), at a cost of about a µs per call.
STEPS_PER_CALL = 10_000
#: The largest count a limit may be (the stepping code counts in 64-bit integers).
MAX_COUNT = 2 ** 62


class Integrator(CompiledSteps, EventSteps, StateAccess):
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
    scheme : {"newmark", "bathe", "hfdi", "generalized_alpha"} or Scheme
    rtol : float or array_like (N,) or (2N,), optional
        Relative tolerance, in ``[1e-13, 0.1)``: each step's local error is
        kept below its share ``h̄/τ`` of it (``h̄`` the mean step, ``τ`` the
        span ``t_bound − t0``, or without ``t_bound`` the time integrated so
        far), so that the error of the answer follows it
        (:class:`~hfdi.controller.ErrorControl`; docs/accuracy.md).
    atol : float or array_like (N,) or (2N,), optional
        Absolute tolerance, ``> 0``; ``inf`` leaves a component uncontrolled
        (``inf`` for ``v``'s half of a (2N,) array controls ``u`` alone:
        docs/accuracy.md, "Controlling u alone"). Default ``1e-3 · rtol · U``
        for ``u`` and ``1e-3 · rtol · V`` for ``v``, the scales of the
        initial state, or of a model at rest its declared ``u_scale`` or the
        displacement its load and initial velocity drive
        (:func:`hfdi.options.state_scales`).
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
        (docs/algorithm.md, "Corrector"). Default ``"error"`` under error
        control alone, ``"correction"`` in the other modes (whose Newton
        counts are the paper's ``N``).
    first_step : float, optional
        First trial step. Default: ``1/ω`` with ``ω`` a Gershgorin bound of the
        highest frequency of ``(K(u0), M)``, capped by ``max_step``.
    min_step, max_step : float, optional
        Guards on the step size. Defaults: ``1e-12·max(1, |t_bound|)``, or a
        millionth of a shorter span ``t_bound − t0``, but not below 64
        spacings of the floating-point times at ``t_bound``; and
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
        Added to the model's load (a :class:`~hfdi.HeldLoad` for a held
        co-simulation input keeps the steps compiled).
    breakpoints : array_like, optional
        Times where the load or its rate jumps, besides the model's own
        ``load_breakpoints()``. Under error control steps land on them and
        the predictor restarts there; the iteration-count mode keeps its
        steps (the paper's tables are made so); the fixed-step mode keeps
        its grid and treats the breakpoints on it as error control does (the
        load's left limit at the end of the step that lands there, its right
        limit after), and steps over the others.
    check_stiffness : bool
        Check ``K(u0)`` against central differences of ``f`` along two
        directions (4 or 8 extra force evaluations for a correct model, at
        most 32) and refuse a model whose
        ``K`` is not ``∂f/∂u`` (default); for HFDI with the model's
        ``load_rate``, check ``p'(t0)`` against forward differences of ``p``
        too (at most 26 load evaluations).
        Turn off only for a force with a kink at ``u0``.
    compiled : {None, True, False}
        Take the steps in compiled code (:mod:`hfdi.compiled`, numba; see
        docs/compiled.md). ``None`` (default): compiled when the model has
        compiled kernels that compute it, the system is dense (``N < 128``)
        and the controller is a built-in one, else the same steps as Python
        (said once when a model's kernels cannot be used); ``True``: compiled
        or :class:`hfdi.compiled.CompiledUnavailable` naming the reason;
        ``False``: Python. Both run the same code (:mod:`hfdi.stepping`).
    global_error : bool
        Carry the estimate of the global error (:attr:`global_error`,
        ``Result.global_error``): per step one more evaluation of ``K`` and one
        factorisation of an N×N matrix (docs/algorithm.md, "Global error
        estimate"). Default ``True``.
    error_span : float, optional
        The time ``τ`` over which error control shares out the tolerance
        (:class:`~hfdi.controller.ErrorControl`'s ``span``) where it is not
        ``t_bound − t0``: a co-simulation unit knows the experiment's stop
        time but steps without a bound.
    events : callable or list of callables, optional
        Event functions ``g(t, u, v) -> float`` whose zeros the run locates
        (``solve_ivp``'s convention: attributes ``terminal``, ``True`` or a
        count, and ``direction``, −1, 0 or +1; :mod:`hfdi.events`), found in
        :attr:`t_events`, :attr:`u_events`, :attr:`v_events`. A terminal
        event ends the run at its zero (``Status.TERMINATED``, not a
        failure).
    on_event : callable ``on_event(t, u, v, which) -> (u, v) or None``, optional
        Called at every zero, once the run has landed on it (``which``: the
        event function's index); a state it returns replaces the current
        one there (an impact), and the run restarts from it as after a load
        breakpoint, the energy of the jump counted as work done on the
        system (``external_work``). With ``None`` the state stays and the
        run restarts from it with the model as ``on_event`` left it (a load
        or parameter it switched: :meth:`model_changed`).

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
        ``check_stiffness``).
    """

    def __init__(self, system: SecondOrderSystem, scheme="hfdi", *, rtol=None, atol=None,
                 target_iterations=None, step=None, controller=None, t0=0.0, u0=None, v0=None,
                 tol=None, first_step=None, min_step=None, max_step=None, max_halvings=30,
                 max_steps=1_000_000, max_iterations=None, first_step_trials=40, t_bound=None,
                 energy_limit=None, extra_load=None, breakpoints=None, check_stiffness=True,
                 compiled=None, newton_test=None, global_error=True, error_span=None,
                 events=None, on_event=None):
        self.scheme: Scheme = get_scheme(scheme)
        if not isinstance(global_error, (bool, np.bool_)):
            raise ValueError(f"global_error must be True or False, got {global_error!r}")
        #: whether the run carries the global error estimate (``global_error=``)
        self.carries_global_error = bool(global_error)
        checks.callable_or_none("extra_load", extra_load, "t -> (N,)")
        if not isinstance(check_stiffness, bool):
            raise ValueError(f"check_stiffness must be True or False, got {check_stiffness!r}")
        if compiled not in (None, True, False):
            raise ValueError(f"compiled must be None (auto), True or False, got {compiled!r}")
        self.check_stiffness = check_stiffness
        self.ev = ev = Evaluator(system, extra_load)
        self.system = system
        # a model that counts the changes of its parameters (EnergyModel): the
        # integrator follows them (model_changed) before its next step
        self._model_version = getattr(system, "parameter_version", None)
        # the load rate the run chose with (a System's or LinearSystem's is
        # assigned, not counted): another one is followed as a change
        self._load_rate_seen = system.load_rate
        if isinstance(self.scheme, HFDI) and self.scheme.load_rate == "exact" \
                and not ev.has_load_rate:
            why = "extra_load is given" if system.load_rate is not None else \
                "the model has no load_rate"
            raise ValueError(f"scheme HFDI(load_rate='exact') needs the exact load rate, but "
                             f"{why}; use HFDI(load_rate='auto'), 'derived' or "
                             f"'difference'")
        self.t0 = checks.real("t0", t0)
        self.t_bound = None if t_bound is None else checks.real("t_bound", t_bound)
        if self.t_bound is not None and not self.t_bound > self.t0:
            raise ValueError(f"t_bound must be > t0 = {self.t0}, got {t_bound!r}")
        span = None if self.t_bound is None else self.t_bound - self.t0
        max_steps = checks.integer("max_steps", max_steps, 1, MAX_COUNT)
        self.energy_limit = optional_positive("energy_limit", energy_limit)
        u_scale = declared_u_scale(system) or 1.0
        self.controller = c = make_controller(
            controller, rtol, atol, target_iterations, step, span, min_step, max_step,
            max_halvings, first_step_trials, self.scheme, self.t0, self.t_bound,
            max_steps)
        self.min_step, self.max_step = c.min_step, c.max_step
        self.fixed = isinstance(c, FixedStep)
        self.max_iterations = c.max_iterations if max_iterations is None else \
            checks.integer("max_iterations", max_iterations, 1, 2**31 - 1)
        if newton_test is not None and not (isinstance(newton_test, str)
                                            and newton_test in NEWTON_TESTS):
            raise ValueError(f"newton_test must be one of {', '.join(map(repr, NEWTON_TESTS))}, "
                             f"got {newton_test!r}")
        self.floor = u_scale
        every = breakpoints_of(system, breakpoints)
        # the fixed step lands on those on its grid
        self.breakpoints = every if c.uses_error_estimate or self.fixed else np.empty(0)

        n = ev.n
        initial = []
        for name, given, attribute in (("u0", u0, "initial_displacement"),
                                       ("v0", v0, "initial_velocity")):
            source = None
            if given is None:
                given = getattr(system, attribute, None)
                source = f"system.{attribute}"
            initial.append(np.zeros(n) if given is None else
                           initial_vector(name, given, n, source))
        u0, v0 = initial
        error_span = optional_positive("error_span", error_span)
        self.newton_test = newton_test or (
            "error" if isinstance(c, ErrorControl) else "correction")
        self.tol = newton_tolerance(tol, c)
        first_step = optional_positive("first_step", first_step)
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
        current, K0, T0, potential = initial_state(
            ev, self.scheme, self.t0, u0, v0, check_stiffness, self.floor, self.t_bound, every)
        # the default atol's scales: of the state, or (a model at rest) of what
        # its load and initial velocity drive
        declared = declared_u_scale(system)
        error_span = span if error_span is None else error_span
        driven = driven_scale(ev, K0, self.t0, v0, error_span) \
            if needs_driven_scale(c, u0, declared) else None
        fit_error_control(c, error_span, u0, v0, declared, driven)
        c.prepare(ev.n, self.scheme.order)
        if self.energy_limit is not None and math.isnan(potential):
            raise ValueError(
                f"energy_limit needs the model's potential energy (the energy balance, "
                f"Eq. 40), but model {getattr(system, 'name', type(system).__name__)!r} "
                f"returns NaN (unknown) from potential_energy at u0; give the model "
                f"potential_energy or leave energy_limit=None")
        exact = isinstance(self.scheme, HFDI) and self.scheme.exact_rate(ev.has_load_rate)
        # a load linear between its breakpoints (held inputs added) has the
        # quotient for its exact rate: HFDI's "auto" derives none
        linear = bool(getattr(system, "load_linear_between_breakpoints", False)) and (
            ev.extra_load is None or isinstance(ev.extra_load, HeldLoad))
        derived = isinstance(self.scheme, HFDI) and not exact and self.scheme.derived_rate(
            ev.has_load_rate or linear, core_kind(c) in (ERROR, COMBINED))
        #: the scheme's stages are HFDI's (else affine): the compiled loop's constant
        self._hfdi = HFDI_STAGES if self.scheme.stage.py_func(
            1.0, 0, self.scheme.params()).kind == HFDI_STAGE else AFFINE_STAGES
        self._cfg = run_records.config(
            ev, c, self.scheme, exact_rate=exact, derived_rate=derived, tol=self.tol,
            floor=self.floor,
            max_iterations=self.max_iterations, estimated=self.newton_test == "error",
            energy_limit=self.energy_limit, max_steps=max_steps, t_bound=self.t_bound,
            global_error=bool(global_error))
        self._data = run_records.data(ev, c, self.scheme, self.breakpoints)
        self._vec, self._state_block = run_records.vectors(ev, 0)
        proposed = c.step if self.fixed else \
            min(first_step or default_first_step(ev, K0, self.t0, self.t_bound, self.min_step),
                self.max_step)
        self._run = RUN.new(t=self.t0, t_previous=self.t0, proposed=proposed,
                            first_step_pending=not self.fixed, potential=potential,
                            initial_potential=potential, energy_scale=ev.kinetic_energy(
                                current.v), grid_origin=self.t0, t_start=self.t0,
                            t_reached=self.t0)
        self._put_current(current)
        self._message = ""
        self._rows = None               # a callable taking blocks of rows (advance(rows=))
        self._python_functions = None
        self._compiled_call = None      # (fn, cfg array, data, vec) of the compiled loop
        self._not_compiled = ""         # why the steps run in Python
        self._choose_path(compiled, current, K0, T0, potential)
        self._setup_events(events, on_event)
        self._absorb_counts()
        self._run_cpu = time.process_time() - start

    # -- the records of the stepping code ------------------------------------------
    def _put_current(self, current: State, previous: State | None = None):
        vec, run = self._vec, self._run
        run.t = current.t
        vec.u[:], vec.v[:], vec.a[:], vec.p[:] = current.u, current.v, current.a, current.p
        run.has_force = current.f is not None
        if current.f is not None:
            vec.f[:] = current.f
        run.has_previous = previous is not None
        if previous is not None:
            run.t_previous = previous.t
            vec.u_previous[:], vec.v_previous[:] = previous.u, previous.v
            vec.a_previous[:], vec.p_previous[:] = previous.a, previous.p
            if previous.f is not None:
                vec.f_previous[:] = previous.f

    def _absorb_counts(self):
        """Add the Evaluator's own evaluations (checks outside the steps) to the
        statistics."""
        ev, run = self.ev, self._run
        run.nfev += ev.nfev
        run.njev += ev.njev
        run.ntev += ev.ntev
        run.npev += ev.npev
        ev.nfev = ev.njev = ev.ntev = ev.npev = 0

    @property
    def compiled(self) -> bool:
        """Whether the steps run compiled (see ``compiled``, docs/compiled.md)."""
        return self._compiled_call is not None

    @property
    def compiled_model(self) -> bool:
        """Whether the model's f, K and T run compiled: in the compiled loop, or
        called by the steps of a sparse system whose model has
        :class:`hfdi.compiled.SparseKernels`."""
        return self._compiled_call is not None or self.ev.kernels is not None

    @property
    def max_steps(self) -> int:
        """The run's limit of attempts (``max_steps``); may be set between calls
        (an FMU's budget of internal steps per communication step)."""
        return int(self._cfg.max_steps)

    @max_steps.setter
    def max_steps(self, value):
        value = checks.integer("max_steps", value, 1, MAX_COUNT)
        self._cfg.max_steps = value
        if self._compiled_call is not None:
            self._compiled_call[1]["max_steps"] = value

    @property
    def not_compiled_reason(self) -> str:
        """Why the steps run in Python (``""`` while they run compiled): the
        reason the compiled path was refused at the start, or left during the run."""
        return "" if self._compiled_call is not None else self._not_compiled

    def _functions(self):
        """The model as the Python steps call it."""
        if self._python_functions is None:
            self._python_functions = self.ev.functions(self.scheme.stage.py_func,
                                                       self._cfg.exact_rate)
        return self._python_functions

    # -- public state --------------------------------------------------------------
    @property
    def state(self) -> State:
        """The current (last accepted) :class:`State`."""
        run, vec = self._run, self._vec
        return State(run.t, vec.u.copy(), vec.v.copy(), vec.a.copy(),
                     vec.f.copy() if run.has_force else None, vec.p.copy())

    @property
    def t(self) -> float:
        return self._run.t

    @property
    def status(self) -> Status:
        return Status(self._run.status)

    @property
    def message(self) -> str:
        return self._message

    @property
    def failed(self) -> bool:
        return self._run.status < 0

    @property
    def finished(self) -> bool:
        """Whether ``t_bound`` has been reached."""
        return self.t_bound is not None and self.t >= self.t_bound

    @property
    def statistics(self) -> Statistics:
        run = self._run
        stats = Statistics(**{name: getattr(run, name) for name in STATISTICS_FIELDS
                              if name != "cpu_time"})
        stats.cpu_time = self._run_cpu
        return stats

    @property
    def proposed_step(self) -> float:
        """The size the controller proposes for the next step."""
        return self._run.proposed

    @property
    def last_step(self) -> float:
        return self._run.last_step

    @property
    def last_iterations(self) -> int:
        """Newton corrections of the last accepted step."""
        return self._run.last_iterations

    @property
    def potential_energy(self) -> float:
        """``V`` at the current state."""
        return self._run.potential

    @property
    def total_energy(self) -> float:
        """``W = V + T`` at the current state (Eq. 40)."""
        return self._run.potential + self.ev.kinetic_energy(self._vec.v)

    @property
    def last_energy_increment(self) -> float:
        """``ΔE`` of the last accepted step (Eq. 40)."""
        return self._run.last_energy_increment

    @property
    def external_work(self) -> float:
        """Work of the load since the start (Eq. 41, summed)."""
        return self._run.work

    @property
    def energy_error(self) -> float:
        """``Σ ΔE`` since the start: the spurious energy of the run."""
        return self._run.energy_error

    @property
    def tolerances(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(rtol, atol)`` of the error rule, each (2N,) over ``(u, v)``, or
        ``None`` in a mode without error control."""
        error = getattr(self.controller, "error", self.controller)
        if not isinstance(error, ErrorControl):
            return None
        n = 2 * self.ev.n
        return (np.broadcast_to(np.asarray(error.rtol, dtype=float), (n,)).copy(),
                np.broadcast_to(np.asarray(error.atol, dtype=float), (n,)).copy())

    @property
    def global_error(self) -> np.ndarray:
        """The estimated global error of ``(u, v)`` now (2N: ``u``'s N entries,
        then ``v``'s), a copy: the local error estimates of the steps so far
        carried through the linearised motion (docs/algorithm.md, "Global
        error estimate"). NaN where it was lost (``K`` failed or the
        propagator's matrix was singular) and with ``global_error=False``."""
        if not self.carries_global_error:
            return np.full(2 * self.ev.n, np.nan)
        return self._vec.global_error.copy()

    # -- jumps from outside ------------------------------------------------------------
    def load_changed(self) -> None:
        """Tell the integrator that the load jumps at the current time.

        The current state keeps the load ``p_n`` and the acceleration ``a_n``
        computed when it was reached; the schemes read both (Newmark and Bathe
        through ``a_n``, HFDI through ``p_n`` in ``g_n`` and the paper's load rate, the energy
        balance through the work). After a jump of the load at ``t_n`` (a
        co-simulation input changed at a communication point), both are
        recomputed from the load now, the acceleration being the right limit;
        a compiled run takes the load's data from the model now (a changed
        amplitude, say).
        """
        self._refresh(new_force=False)
        if self._compiled_call is not None:
            compiled_path.follow_load(self)

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
        step history is dropped as at a load breakpoint. A compiled run takes
        the model's data now, and its kernels are checked against the model
        again (:func:`hfdi.compiled.follow_model`).

        Raises
        ------
        ModelError
            When the model cannot be evaluated at the current state (the
            integrator is then left as it was).
        ValueError
            When the model's ``mass`` or ``damping`` changed, or HFDI's model
            gained or lost its ``load_rate``: they are read (the rate chosen)
            once, at construction; a new ``Integrator`` takes them (and
            :meth:`set_state` the state reached).
        """
        run = self._run
        changed = self.ev.matrix_changed()
        if changed:
            raise ValueError(
                f"the {changed} of model {type(self.system).__name__} changed after the "
                f"integrator was built, which reads M and C once: build a new Integrator "
                f"for the new matrices (set_state carries the state reached over)")
        if isinstance(self.scheme, HFDI) and \
                self.scheme.exact_rate(self.ev.has_load_rate) != bool(self._cfg.exact_rate):
            now = "given" if self.ev.has_load_rate else "removed"
            raise ValueError(
                f"the load_rate of model {type(self.system).__name__} was {now} after the "
                f"integrator was built, which chooses HFDI's load rate (the model's p' or one "
                f"it derives) once: build a new Integrator (set_state carries the state "
                f"reached over)")
        try:
            potential = self.ev.potential_energy(self._vec.u)
        except ModelError:
            self._absorb_counts()
            raise
        except Exception as exc:
            self._absorb_counts()
            raise ModelError(f"the changed model cannot be evaluated at the current state "
                             f"(t = {run.t:.10g}): {type(exc).__name__}: {exc}") from None
        self._refresh(new_force=True)      # drops the step history too
        run.potential = potential
        run.newton_constant = run.newton_guard = math.inf     # measured on the model as it was
        self._model_version = getattr(self.system, "parameter_version", None)
        self._load_rate_seen = self.system.load_rate
        if self._compiled_call is not None:
            compiled_path.follow_model(self)

    def _refresh(self, new_force):
        """The current state's ``p``, ``a`` (and ``f``) from the load (model) now."""
        run = self._run
        saved = RUN.copy(run)
        before = (self._vec.p.copy(), self._vec.f.copy(), self._vec.a.copy())
        self.ev.fault = None
        ok = stepping.refresh(self._functions(), self._cfg, self._data, run, self._vec,
                              new_force)
        self._absorb_counts()
        if not ok:
            message = stop_message(run, self._cfg, self.ev.fault)
            self._run = saved
            self._vec.p[:], self._vec.f[:], self._vec.a[:] = before
            raise ModelError(f"the changed model cannot be evaluated at the current state "
                             f"(t = {run.t:.10g}): {message}")

    def _follow_model(self) -> bool:
        """:meth:`model_changed` if the model's ``parameter_version`` moved or
        its ``load_rate`` is another one; ``False`` (status MODEL_ERROR) when
        the changed model fails there."""
        # == and not `is`: a model's method is a new bound method at each access
        if (self._model_version is None
                or self.system.parameter_version == self._model_version) \
                and self.system.load_rate == self._load_rate_seen:
            return True
        try:
            self.model_changed()
        except ModelError as exc:
            self._run.status = int(Status.MODEL_ERROR)
            self._message = f"t = {self.t:.10g}: {exc}"
            return False
        return True

    # -- stepping ---------------------------------------------------------------------
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
        t_limit = time_value("t_limit", t_limit)
        if self.failed or self.finished or self.terminated or t_limit == self.t:
            return False
        if not t_limit > self.t:
            raise ValueError(f"t_limit must be > t = {self.t}, got {t_limit!r}")
        if not self._follow_model():
            return False
        accepted = self._run.accepted
        self._take_steps(t_limit, 1)
        return self._run.accepted > accepted and not self.failed

    def advance(self, t_stop: float, callback=None, rows=None, until_event=False) -> bool:
        """Integrate to ``t_stop`` and land on it exactly.

        The step the controller proposes carries over from call to call: a
        step shortened to land on ``t_stop`` does not shrink the next one.

        Parameters
        ----------
        t_stop : float
            Must be ``>= t``.
        callback : callable ``callback(integrator)``, optional
            Called after every accepted step.
        rows : callable ``rows(block)``, optional
            Receives the accepted steps as they are taken, in blocks: dicts of
            arrays with the keys of :class:`~hfdi.Result` (``t``, ``u``, ``v``,
            ``a``, ``step_size``, ``iterations``, ``energy_increment``,
            ``total_energy``, ``external_work``), the caller's to keep. At a
            load breakpoint where the acceleration jumps, the time is there
            twice: the state the step reached, then the one the next starts
            from (a step of size 0).
        until_event : bool, optional
            Stop at the first zero of an event function before ``t_stop``
            (after ``on_event``'s reset there): :attr:`t` is then the zero's
            time, and the next call goes on from it. A zero at the call's
            start time (``t0``'s, say) is counted, not stopped at: every stop
            moves the run on. A co-simulation unit returns early there (FMI
            3.0's ``earlyReturn``).

        Returns
        -------
        bool
            ``True`` when ``t_stop`` was reached (or, with ``until_event``, an
            event before it); ``False`` when a guard stopped the run (see
            :attr:`status`, :attr:`message`).
        """
        t_stop = time_value("t_stop", t_stop)
        checks.callable_or_none("callback", callback, "callback(integrator)")
        checks.callable_or_none("rows", rows, "rows(block)")
        if not math.isfinite(t_stop) or t_stop < self.t:
            raise ValueError(f"t_stop must be finite and >= t = {self.t}, got {t_stop!r}")
        if self.t_bound is not None and t_stop > self.t_bound:
            raise ValueError(f"t_stop must be <= t_bound = {self.t_bound}, got {t_stop!r}")
        if self.failed or self.terminated:   # even at t_stop = t: it did not get there
            return False
        if rows is not None and not self._vec.row_t.shape[0]:
            self._vec = self._vec._replace(**run_records.row_arrays(self.ev.n, ROWS_PER_CALL))
            self._refresh_compiled(data=False)
        if not isinstance(until_event, (bool, np.bool_)):
            raise ValueError(f"until_event must be True or False, got {until_event!r}")
        events = self._events if until_event else None
        found = None if events is None else int(events.count.sum())
        start = self.t
        self._rows = rows
        try:
            if events is not None:
                self._pause_at_events = True
            while self.t < t_stop:
                if self.failed or self.terminated:
                    return False
                if not self._follow_model():
                    return False
                accepted = self._run.accepted
                self._take_steps(t_stop, 1 if callback is not None else STEPS_PER_CALL)
                if callback is not None and self._run.accepted > accepted and (
                        not self.failed or self._run.status == Status.ENERGY_GROWTH):
                    callback(self)
                if found is not None and int(events.count.sum()) > found:
                    if self.t > start:
                        break
                    found = int(events.count.sum())    # a zero at the start: go on
        finally:
            self._rows = None
            self._pause_at_events = False
        return not self.failed

    def _steps(self, t_stop: float, max_accepted: int) -> None:
        """Steps towards ``t_stop``, at most ``max_accepted`` of them: one call of
        the stepping code, compiled or in Python, or the custom controller's
        loop; rows handed on, the message made."""
        run = self._run
        start = time.process_time()
        try:
            if self._cfg.controller == CUSTOM:
                from .custom import custom_steps
                custom_steps(self, t_stop, max_accepted)
            elif self._compiled_call is not None and self._held_ready() \
                    and not self._shadowed():
                self._compiled_steps(t_stop, max_accepted)
            else:
                self._python_steps(t_stop, max_accepted)
        finally:
            self._run_cpu += time.process_time() - start
            # also when the rows' consumer raised (integrate's progress stop)
            if run.status < 0 and not self._message:
                self._message = stop_message(run, self._cfg, self.ev.fault)
        if self.finished and run.status >= 0:
            run.status = int(Status.SUCCESS)
            self._message = f"reached t_bound = {self.t_bound!r}"

    def _python_steps(self, t_stop, max_accepted):
        run = self._run
        self.ev.fault = None
        with np.errstate(all="ignore"):
            while True:
                try:
                    reason = advance_python(self._functions(), self._cfg, self._data, run,
                                            self._vec, t_stop, max_accepted, self._hfdi)
                except ModelFault as exc:
                    run.status = int(Status.MODEL_ERROR)
                    run.stop = codes.STOP_MODEL_FAULT
                    self._message = (f"t = {run.t:.10g}: potential_energy failed at the end of "
                                     f"the step to t = {run.a_t_end:.10g}: {exc}")
                    reason = codes.STOPPED
                self._hand_on_rows()
                if reason != codes.ROWS_FULL:
                    return

    def _hand_on_rows(self):
        """The rows the stepping code wrote in its last call, to ``advance(rows=)``."""
        count = self._run.rows
        self._run.rows = 0
        if not count or self._rows is None:
            return
        vec = self._vec
        self._rows({"t": vec.row_t[:count].copy(), "u": vec.row_u[:count].copy(),
                    "v": vec.row_v[:count].copy(), "a": vec.row_a[:count].copy(),
                    "step_size": vec.row_h[:count].copy(),
                    "iterations": vec.row_iterations[:count].astype(int),
                    "energy_increment": vec.row_increment[:count].copy(),
                    "total_energy": vec.row_energy[:count].copy(),
                    "external_work": vec.row_work[:count].copy(),
                    "global_error": vec.row_global[:count].copy()})
