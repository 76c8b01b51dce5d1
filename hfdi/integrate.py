"""``integrate``: a whole run of an :class:`~hfdi.Integrator` to ``t_end``, as a
:class:`~hfdi.Result` with every accepted step (or only the outputs asked for)."""
from __future__ import annotations

import functools
import inspect
import math
import time

import numpy as np

from . import checks
from .dense import interpolate_state
from .evaluation import State
from .controller import RTOL_RANGE
from .integrator import Integrator
from .messages import Status
from .options import times as _times
from .result import Result, Rows
from .system import SecondOrderSystem

__all__ = ["integrate", "PROGRESS_INTERVAL", "ERROR_MODES", "GLOBAL_RUNS", "GLOBAL_MARGIN"]


#: Wall-clock seconds between two calls of integrate's progress callback.
PROGRESS_INTERVAL = 0.5
#: Values of ``integrate(error=...)``.
ERROR_MODES = ("local", "global")
#: ``error="global"``: the most runs made, and where a rerun aims, as a share of
#: the tolerance (docs/algorithm.md, "Global error estimate").
GLOBAL_RUNS = 3
GLOBAL_MARGIN = 0.5


@functools.lru_cache(maxsize=1)
def _integrator_parameters():
    """``Integrator``'s parameters (inspected once: 0.2 ms a call, a quarter of a
    short run's fixed cost)."""
    return inspect.signature(Integrator).parameters


def integrate(system: SecondOrderSystem, scheme, t_end, *, rtol=None, atol=None,
              target_iterations=None, step=None, u0=None, v0=None, t0=0.0, t_eval=None,
              save_steps=True, progress=None, tol=None, error="local", **options) -> Result:
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
    rtol, atol : float or array_like (N,) or (2N,), optional
        Tolerances of the error of ``(u, v)``; an infinite ``atol`` entry
        leaves its component uncontrolled; see :class:`Integrator`.
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
        stalled run shows. Raising ``StopIteration`` ends the run where it
        is (``Status.TERMINATED``, a success, with the steps so far), as
        scipy's optimizers take it from their callbacks; another exception
        propagates.
    tol : float, optional
        Newton tolerance ``η`` (Eq. 38); see :class:`Integrator`.
    error : {"local", "global"}
        What ``rtol`` and ``atol`` bound under error control. ``"local"``
        (default): each step's local error, at the step's share of the
        tolerance, so that the error of the answer follows ``rtol``
        (docs/accuracy.md). ``"global"``: the answer's estimated global
        error, ``|g_i(t)| ≤ atol_i + rtol_i·S`` at every kept step and
        component (:attr:`Result.global_error_ratio` ``≤ 1``, ``S`` the
        largest ``|u|``, or ``|v|``, of the run): the run is repeated with
        the tolerance its estimate says is needed, at most
        :data:`GLOBAL_RUNS` runs in all; ``Status.TOLERANCE_NOT_MET`` when
        the last one still misses it. Error control alone (not with
        ``target_iterations``, ``step`` or ``controller``).
    **options
        Passed to :class:`Integrator` (``first_step``, ``min_step``,
        ``max_step``, ``max_halvings``, ``max_steps``, ``max_iterations``,
        ``energy_limit``, ``controller``, ``breakpoints``, ``events``,
        ``on_event``, ...). With ``events`` the zeros are in
        :attr:`Result.t_events` (and ``u_events``, ``v_events``); a
        terminal event ends the run there (``Status.TERMINATED``, a success).

    Returns
    -------
    Result
        ``status`` and ``message`` say how the run ended; on failure the
        arrays end at the last good state and the message starts with its
        time (``"t = ...: "``). ``global_error`` holds the estimated
        global error of every kept step.

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
        max_steps = options.get("max_steps", _integrator_parameters()["max_steps"].default)
        if t_eval.size > max_steps:
            raise ValueError(f"t_eval has {t_eval.size} points, more than max_steps = "
                             f"{max_steps}; give fewer output times or raise max_steps")
    if not isinstance(save_steps, (bool, np.bool_)):
        raise ValueError(f"save_steps must be True or False, got {save_steps!r}")
    if progress is not None and not callable(progress):
        raise ValueError(f"progress must be callable as progress(t, statistics), got "
                         f"{progress!r}")
    if not (isinstance(error, str) and error in ERROR_MODES):
        raise ValueError(f"error must be one of {', '.join(map(repr, ERROR_MODES))}, got "
                         f"{error!r}")
    if error == "global":
        other = [name for name, value in (("target_iterations", target_iterations),
                                          ("step", step),
                                          ("controller", options.get("controller")))
                 if value is not None]
        if other:
            raise ValueError(f"error='global' needs error control alone (rtol, atol); got "
                             f"{', '.join(other)}")
        if not options.get("global_error", True):
            raise ValueError("error='global' needs the global error estimate; got "
                             "global_error=False")
    allowed = [name for name in _integrator_parameters()
               if name not in ("system", "scheme", "rtol", "atol", "target_iterations", "step",
                               "t0", "u0", "v0", "tol", "t_bound")]
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ValueError(f"unknown option(s) {', '.join(unknown)} of integrate; allowed: "
                         f"{', '.join(allowed)}")
    def run(rtol, atol):
        integrator = Integrator(system, scheme, rtol=rtol, atol=atol,
                                target_iterations=target_iterations, step=step, t0=t0, u0=u0,
                                v0=v0, tol=tol, t_bound=t_end, **options)
        return _integrate(integrator, system, t_end, t_eval, save_steps, progress)

    result = run(rtol, atol)
    if error == "local" or result.message.startswith(PROGRESS_STOPPED):
        ratio = result.global_error_ratio if result.status == Status.SUCCESS else None
        if ratio is not None and math.isfinite(ratio) and ratio > SAY_GLOBAL_ABOVE:
            result.message += (f"; the estimated global error is {ratio:.3g} times the "
                               f"tolerance (rtol bounds each step's error; error=\"global\" "
                               f"bounds the answer's)")
        return result
    # the tolerance asked for, against which every run is measured
    asked_rtol, asked_atol = result.rtol, result.atol
    runs, factor, why = 1, 1.0, ""
    while result.success:
        ratio = result.global_error_ratio
        if ratio <= 1.0 or not math.isfinite(ratio):
            break
        if runs == GLOBAL_RUNS:
            why = f"after {runs} runs"
            break
        tighter = factor * GLOBAL_MARGIN / ratio
        if float(np.min(asked_rtol)) * tighter < RTOL_RANGE[0]:
            why = (f"the rtol that would meet it, {float(np.min(asked_rtol)) * tighter:.3g}, "
                   f"is below {RTOL_RANGE[0]:g}")
            break
        # the error of the answer follows rtol (docs/algorithm.md, "Tolerance
        # proportionality"): the rtol that puts it at GLOBAL_MARGIN
        again = run(asked_rtol * tighter, asked_atol * tighter)
        runs += 1
        again.rtol, again.atol = asked_rtol, asked_atol
        if again.message.startswith(PROGRESS_STOPPED):
            # the complete answer stays; the stopped rerun is said
            why = f"progress stopped the rerun at rtol {float(np.min(asked_rtol)) * tighter:.3g}"
            break
        if not again.success:
            # the complete answer stays; the failed rerun is said
            why = (f"the rerun at rtol {float(np.min(asked_rtol)) * tighter:.3g} failed "
                   f"({again.status.name}: {again.message})")
            break
        result, factor = again, tighter
    result.runs = runs
    if not result.success:
        return result
    ratio = result.global_error_ratio
    last = float(np.min(asked_rtol)) * factor
    # where the run ended: t_end, or a terminal event's zero (its message)
    ended = "reached t_end" if result.status == Status.SUCCESS else result.message
    if not ratio <= 1.0:
        result.status = Status.TOLERANCE_NOT_MET
        result.message = (f"{ended}, but the estimated global error is {ratio:.3g} times "
                          f"the tolerance (the run at rtol {last:.3g}; {why})"
                          if math.isfinite(ratio) else
                          f"{ended}, but the global error estimate was lost (on_event "
                          f"reset the state, the stiffness failed or the propagator's matrix "
                          f"was singular) in the run at rtol {last:.3g}")
    else:
        result.message = (f"{ended}; estimated global error {ratio:.3g} of the "
                          f"tolerance (the run at rtol {last:.3g}, {runs} run(s))")
    return result


#: A run of local error control whose estimated global error is more than
#: this many times its tolerance says so in its message (its status stays
#: SUCCESS: it did what rtol asks of each step). Controlling ``u`` alone on a
#: pendulum released near the top (u0 = 3, to t = 40) left ``u``'s error at
#: 32-187 times rtol, estimated at 17-185, where ``(u, v)`` stays within 5.
SAY_GLOBAL_ABOVE = 10.0

#: The start of the message of a run that progress ended.
PROGRESS_STOPPED = "progress raised StopIteration"


class _ProgressStop(Exception):
    """integrate's progress callback raised StopIteration: the run ends there."""


def _integrate(integrator, system, t_end, t_eval, save_steps, progress) -> Result:
    """One run of ``integrator`` to ``t_end`` as a :class:`Result`."""
    t0 = integrator.t0
    s0 = integrator.state
    rows = Rows(integrator.ev.n)
    g0 = integrator.global_error
    rows.append(s0, math.nan, 0, 0.0, integrator.total_energy, 0.0, g0)
    last = [s0, math.nan, 0, 0.0, integrator.total_energy, 0.0, g0]
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
            try:
                progress(t, integrator.statistics)
            except StopIteration:
                raise _ProgressStop from None

    # the largest |u|, |v| and |g| (per component) of every accepted step, kept
    # or not: Result.global_error_ratio's scales and extremes
    peaks = [float(np.abs(s0.u).max()), float(np.abs(s0.v).max()), np.abs(g0)]

    def record_rows(arrays: dict):
        """The accepted steps of a call of the stepping code, in bulk."""
        t = arrays["t"]
        outputs(t, arrays["u"], arrays["v"], arrays["a"])
        if not integrator.carries_global_error:
            arrays["global_error"][:] = np.nan
        peaks[0] = max(peaks[0], float(np.abs(arrays["u"]).max()))
        peaks[1] = max(peaks[1], float(np.abs(arrays["v"]).max()))
        # NaN (the estimate lost) stays NaN: np.maximum propagates it
        peaks[2] = np.maximum(peaks[2], np.abs(arrays["global_error"]).max(axis=0))
        if save_steps:
            rows.extend(arrays)
        last[:] = [State(float(t[-1]), arrays["u"][-1], arrays["v"][-1], arrays["a"][-1], None,
                         None), float(arrays["step_size"][-1]), int(arrays["iterations"][-1]),
                   float(arrays["energy_increment"][-1]), float(arrays["total_energy"][-1]),
                   float(arrays["external_work"][-1]), arrays["global_error"][-1]]
        report(float(t[-1]))

    try:
        ok, stopped = integrator.advance(t_end, rows=record_rows), False
    except _ProgressStop:
        # raised between two calls of the stepping code: the rows so far are
        # the integrator's accepted steps up to where it stands (a call that
        # failed keeps its failure)
        ok, stopped = not integrator.failed, True
    if progress is not None and not stopped:
        try:
            progress(integrator.t, integrator.statistics)
        except StopIteration:
            pass                        # the run has ended anyway
    if not save_steps and rows.size == 1 and integrator.statistics.accepted:
        rows.append(*last)
    # a terminal event exactly at t_end ends the run there too (as solve_ivp)
    status = integrator.status if not ok or integrator.terminated else Status.SUCCESS
    message = integrator.message if not ok or integrator.terminated else "reached t_end"
    if stopped and status == Status.SUCCESS and integrator.t < t_end:
        status = Status.TERMINATED
        message = f"{PROGRESS_STOPPED} at t = {integrator.t:.10g}"
    rtol, atol = integrator.tolerances or (None, None)
    if status == Status.TERMINATED and t_eval is not None:
        # as solve_ivp: the output times up to where the run ended
        keep = t_eval <= integrator.t
        t_eval, u_eval, v_eval = t_eval[keep], u_eval[keep], v_eval[keep]
    t_events, u_events, v_events = integrator.t_events, integrator.u_events, \
        integrator.v_events
    if stopped and t_events is not None:
        # zeros found in steps scanned past where the run was stopped
        kept = [np.asarray(times) <= integrator.t for times in t_events]
        t_events, u_events, v_events = ([x[k] for x, k in zip(which, kept)]
                                        for which in (t_events, u_events, v_events))
    return Result(**rows.arrays(), status=status, message=message,
                  t_events=t_events, u_events=u_events, v_events=v_events,
                  stats=integrator.statistics, scheme=integrator.scheme.name,
                  t_eval=t_eval, u_eval=None if t_eval is None else u_eval,
                  v_eval=None if t_eval is None else v_eval, system=system,
                  steps_saved=save_steps, rtol=rtol, atol=atol,
                  peaks=(peaks[0], peaks[1], peaks[2]))
