"""How a run ended, in words: the one place where the codes of the stepping
code (:mod:`hfdi.core.codes`) become :class:`Status` names and messages."""
from __future__ import annotations

import enum
import math

from .core import codes
from .core.state import COMBINED, ITERATION

__all__ = ["Status", "attempt_message", "stop_message"]


class Status(enum.IntEnum):
    """How a run ended (negative values are failures).

    ``MODEL_ERROR``: during the run the model returned a value of the wrong
    shape (or a potential energy that is not a number), a mistake that no
    step size cures; the message names the function.

    ``OVERFLOW``: a converged step reached a state whose energy balance
    (Eqs. 40–41) is beyond floating point, an infinite kinetic energy, work
    of the load or potential energy (a load or state of the order of 1e150
    or more); that state is not accepted.

    ``TERMINATED``: a terminal event function reached its zero (its last
    allowed one), or ``integrate``'s progress callback raised
    ``StopIteration``, and the run ended there, as asked; a success.

    ``TOLERANCE_NOT_MET``: ``integrate(error="global")`` reached ``t_end``,
    but its last run's estimated global error is above the tolerance (or
    the estimate was lost); the result is that run's, complete.
    """

    SUCCESS = codes.SUCCESS
    RUNNING = codes.RUNNING
    STEP_BELOW_MINIMUM = codes.STEP_BELOW_MINIMUM
    HALVINGS_EXHAUSTED = codes.HALVINGS_EXHAUSTED
    MAX_STEPS = codes.MAX_STEPS
    NEWTON_FAILED = codes.NEWTON_FAILED
    ENERGY_GROWTH = codes.ENERGY_GROWTH
    FIRST_STEP_FAILED = codes.FIRST_STEP_FAILED
    MODEL_ERROR = codes.MODEL_ERROR
    OVERFLOW = codes.OVERFLOW
    TOLERANCE_NOT_MET = codes.TOLERANCE_NOT_MET
    #: a terminal event ended the run at its zero (not a failure: ``success``)
    TERMINATED = 2


_ATTEMPT = {
    codes.RESIDUAL_NOT_FINITE: "residual is not finite",
    codes.TANGENT_SINGULAR: "tangent is singular (singular matrix)",
    codes.CORRECTION_NOT_FINITE: "Newton correction is not finite",
    codes.END_NOT_FINITE: "end-of-step state is not finite",
    codes.FORCE_NOT_FINITE: "internal_force is not finite at a trial state",
    codes.STIFFNESS_NOT_FINITE: "stiffness is not finite at a trial state",
    codes.DERIVATIVE_NOT_FINITE: "stiffness_derivative is not finite at a trial state",
    codes.STEP_MATRIX_SINGULAR: "the HFDI matrix B = 2h/3 M + h²/6 C is singular",
    codes.LOAD_NOT_FINITE: "load is not finite",
    codes.LOAD_RATE_NOT_FINITE: "load_rate is not finite",
}
#: The model's value each outcome is about (a Python model's own message replaces ours).
_MODEL_VALUES = (codes.FORCE_NOT_FINITE, codes.STIFFNESS_NOT_FINITE,
                 codes.DERIVATIVE_NOT_FINITE, codes.LOAD_NOT_FINITE,
                 codes.LOAD_RATE_NOT_FINITE) + codes.SHAPE_FAULTS
_NEWTON = (codes.RESIDUAL_NOT_FINITE, codes.TANGENT_SINGULAR, codes.CORRECTION_NOT_FINITE,
           codes.NO_CONVERGENCE)
_SHAPE_OF = {codes.FORCE_SHAPE: "internal_force", codes.STIFFNESS_SHAPE: "stiffness",
             codes.DERIVATIVE_SHAPE: "stiffness_derivative", codes.LOAD_SHAPE: "load",
             codes.LOAD_RATE_SHAPE: "load_rate"}


def attempt_message(run, cfg, fault=None) -> str:
    """Why the last attempt (``RUN.a_*``) failed; ``fault`` the Python model's
    own message of its last fault (:attr:`hfdi.evaluation.Evaluator.fault`)."""
    outcome = run.a_outcome
    if outcome == codes.OK:
        err = run.a_err
        return ("error estimate is not finite" if not math.isfinite(err) else
                f"local error {err:.3g} times the tolerance")
    if outcome in _MODEL_VALUES and fault is not None:
        return fault[0]
    if outcome in _SHAPE_OF:
        n = cfg.n
        vector = run.bad_columns < 0
        shape = (run.bad_rows,) if vector else (run.bad_rows, run.bad_columns)
        return (f"{_SHAPE_OF[outcome]} returned shape {shape}, expected "
                f"{(n,) if vector else (n, n)}")
    if outcome == codes.NO_CONVERGENCE:
        message = f"no convergence in N_max = {cfg.max_iterations} corrections"
    else:
        message = _ATTEMPT.get(outcome, f"failed ({outcome})")
    if cfg.stages > 1 and outcome in _NEWTON:
        message += f" (sub-step {run.a_stage + 1})"
    return message


def stop_message(run, cfg, fault=None, t_limit=math.inf) -> str:
    """The message of a run stopped by ``RUN.stop`` (``RUN.status < 0``), starting
    with the time of its last good state."""
    why = attempt_message(run, cfg, fault)
    h, reason = run.a_h, run.stop
    to = f" (to t = {run.t + h:.10g})"
    if reason == codes.STOP_BELOW_RESOLUTION:
        text = f"step {run.proposed:.6g} is below the resolution of time at t"
    elif reason in (codes.STOP_MIN_STEP, codes.STOP_HALVINGS):
        rule = _iteration_rule(run, cfg)
        text = _guard(run, reason, cfg.it_min_step if rule else cfg.er_min_step,
                      cfg.it_max_rejections if rule else cfg.er_max_rejections, why)
        text += (f": {why}" if reason == codes.STOP_MIN_STEP else "") + to
        if reason == codes.STOP_MIN_STEP and not rule and run.a_outcome == codes.OK:
            # the error test, not the corrector, shrank the steps to nothing
            text += (f"; a jump or kink of the load near t = {run.t + h:.10g} (or a "
                     f"singularity of the model)? A load's, declared (breakpoints=[...] or "
                     f"the model's load_breakpoints()), is landed on instead of crossed")
    elif reason == codes.STOP_FIXED_FAILED:
        text = f"corrector failed with fixed step {h:.6g}: {why}" + (
            "" if run.first_step_pending else to)
    elif reason == codes.STOP_FIRST_STEP:
        if cfg.controller in (ITERATION, COMBINED) and math.isinf(run.search_best):
            failure = run.a_outcome
            run.a_outcome = run.trial_failure
            why = attempt_message(run, cfg, fault)
            run.a_outcome = failure
            text = (f"no first step converged in {run.trials} trials down to h = "
                    f"{run.trials_smallest:.6g}: {why}")
        else:
            # the error rule's last rejection of a first-step trial
            guard = _guard(run, run.trial_guard, cfg.er_min_step, cfg.er_max_rejections, why)
            text = (f"no first step passed the error test in {run.trials} trials down to h = "
                    f"{run.trials_smallest:.6g}{': ' + guard if guard else ''}")
    elif reason == codes.STOP_MAX_STEPS:
        before = f" before t = {run.stop_t:.10g}" if math.isfinite(run.stop_t) else ""
        text = f"max_steps = {cfg.max_steps} reached (attempts, rejected ones included){before}"
    elif reason == codes.STOP_SHORT_NOT_FINITE:
        text = (f"the short step of {h:.3g} to t = {run.a_t_end:.10g} gives values that are "
                f"not finite")
    elif reason == codes.STOP_SHORT_FAILED:
        text = f"the short step of {h:.3g} to t = {run.a_t_end:.10g} failed: {why}"
    elif reason == codes.STOP_ENERGY:
        text = (f"energy balance broke down: spurious energy {run.energy_error:.4g} exceeds "
                f"{cfg.energy_limit:g} x energy scale {run.energy_scale:.4g}")
    elif reason == codes.STOP_OVERFLOW:
        text = (f"the step to t = {run.stop_t:.10g} overflows: kinetic energy "
                f"{run.stop_kinetic:.4g}, work of the load {run.stop_work:.4g}, potential "
                f"energy {run.stop_potential:.4g} (a load or state too large for floating "
                f"point)")
    elif reason == codes.STOP_POTENTIAL_LOST:
        text = (f"potential_energy is NaN (unknown) at the end of the step to t = "
                f"{run.stop_t:.10g}, but was {run.initial_potential:.10g} at the start: a "
                f"model gives V everywhere or nowhere (NaN); the energy balance would be NaN "
                f"from here on")
    elif reason == codes.STOP_MODEL_SHAPE:
        text = f"the model returned an unusable value in a step from this time: {why}"
    else:
        text = why
    return f"t = {run.t:.10g}: {text}"


def _iteration_rule(run, cfg) -> bool:
    """Whether the iteration-count rule made the last verdict (it stops first in
    the combined mode, on attempts that did not converge)."""
    return cfg.controller == ITERATION or (cfg.controller == COMBINED
                                           and run.a_outcome != codes.OK)


def _guard(run, reason, min_step, limit, why) -> str:
    """What a step rule's stop ``reason`` (``STOP_MIN_STEP``, ``STOP_HALVINGS``, else
    ``""``) says, with its ``min_step`` and its ``limit`` of rejections."""
    if reason == codes.STOP_MIN_STEP:
        return (f"step {run.stop_next:.6g} below min_step = {min_step:.6g} after the attempt "
                f"with h = {run.a_h:.6g} was rejected")
    if reason == codes.STOP_HALVINGS:
        what = f"diverged after {limit} halvings" if run.a_outcome != codes.OK else \
            f"rejected {limit} times in a row"
        return f"step {what} (last attempt h = {run.a_h:.6g}): {why}"
    return ""
