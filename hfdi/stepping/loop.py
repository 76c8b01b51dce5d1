"""The integrator's loop: the first step, every later step, and runs of steps.

:func:`advance` takes steps until ``t_stop`` with a built-in controller; it is
the whole run for both speeds: compiled (:func:`advance_compiled`, the model's
kernels through function pointers) or as plain Python (a Python model). A
custom controller's run is the same attempts and acceptance driven from
Python (:mod:`hfdi.integrator`).
"""
from __future__ import annotations

import math

from ..core.arrays import copy
from ..core.codes import (FIRST_STEP_FAILED, HALVINGS_EXHAUSTED, MAX_STEPS, MODEL_ERROR,
                          NEWTON_FAILED, OK, REACHED, ROWS_FULL, STEP_BELOW_MINIMUM, STOPPED,
                          STOP_BELOW_RESOLUTION, STOP_FIRST_STEP, STOP_FIXED_FAILED,
                          STOP_HALVINGS, STOP_MAX_STEPS, STOP_MIN_STEP, STOP_MODEL_SHAPE,
                          STOP_NONE, STOP_SHORT_FAILED, STOP_SHORT_NOT_FINITE, SUCCESS)
from ..core.control import (adapt, clip, error_adapt, is_breakpoint, iteration_search, limit,
                            uses_error)
from ..core.estimate import error_norm, is_short
from ..core.jit import entry, jitable
from ..core.state import COMBINED, ERROR, FIXED
from .attempt import (SHORT_STEP_RATE, _is_shape_fault, accept, attempt, estimate_error,
                      fastest_rate, stop, taylor_step)
from .stages import AFFINE_STAGES, HFDI_STAGES

__all__ = ["try_attempt", "take_step", "advance", "advance_hfdi", "advance_affine",
           "status_of"]


@jitable(inline=True)
def status_of(reason):
    """The hfdi.Status of a controller's stop."""
    if reason == STOP_HALVINGS:
        return HALVINGS_EXHAUSTED
    if reason == STOP_FIXED_FAILED:
        return NEWTON_FAILED
    return STEP_BELOW_MINIMUM


@jitable(inline=True)
def try_attempt(fn, cfg, data, run, vec, proposed, t_limit, t_end, clipped, hfdi):
    """An attempt to ``t_end`` (towards ``t_limit``) for a proposed ``proposed``,
    with the error norm (``RUN.a_err``) under error control: the outcome."""
    run.a_proposed = proposed
    run.a_clipped = clipped
    left = t_end == t_limit and is_breakpoint(data, t_end)
    outcome = attempt(fn, cfg, data, run, vec, t_end, left, hfdi)
    if outcome == OK and uses_error(cfg):
        estimate_error(cfg, data, run, vec, run.a_h)
        run.a_estimated = True
        run.a_err = error_norm(cfg, data, run, vec)
    return outcome


@jitable(inline=True)
def _shape_stop(run, outcome):
    return stop(run, MODEL_ERROR, STOP_MODEL_SHAPE)


@jitable(inline=True)
def short_step(fn, cfg, data, run, vec, t_end, t_limit, hfdi):
    """A step to ``t_end`` shorter than ``SHORT_STEP`` of the one proposed, taken
    by Taylor's expansion, or by the scheme past a stiff component the
    expansion would not resolve; accepted as it is, and not the history."""
    h = t_end - run.t
    left = t_end == t_limit and is_breakpoint(data, t_end)
    if h * fastest_rate(fn, cfg, data, run, vec) > SHORT_STEP_RATE:
        outcome = try_attempt(fn, cfg, data, run, vec, run.proposed, t_limit, t_end, True, hfdi)
        if _is_shape_fault(outcome):
            return _shape_stop(run, outcome)
        run.steps += 1
        run.newton_iterations += run.a_iterations
        if outcome == OK:
            return accept(fn, cfg, data, run, vec)
        run.rejected += 1
        return stop(run, NEWTON_FAILED, STOP_SHORT_FAILED)
    run.a_proposed = run.proposed
    run.a_clipped = True
    outcome = taylor_step(fn, cfg, data, run, vec, t_end, left)
    if _is_shape_fault(outcome):
        return _shape_stop(run, outcome)
    if outcome != OK:
        run.a_outcome = outcome
        return stop(run, MODEL_ERROR, STOP_SHORT_NOT_FINITE)
    run.steps += 1
    run.a_taylor = True
    return accept(fn, cfg, data, run, vec)


# -- the first step ------------------------------------------------------------------

@jitable(inline=True)
def _save(run, vec):
    """Keep the last attempt aside (the first step's best trial)."""
    run.saved_h, run.saved_t_end = run.a_h, run.a_t_end
    run.saved_proposed, run.saved_clipped = run.a_proposed, run.a_clipped
    run.saved_iterations, run.saved_newton_error = run.a_iterations, run.a_newton_error
    run.saved_err = run.a_err
    copy(vec.u_saved, vec.u_new)
    copy(vec.v_saved, vec.v_new)
    copy(vec.a_saved, vec.a_new)
    copy(vec.f_saved, vec.f_new)
    copy(vec.p_saved, vec.p_new)
    copy(vec.u_mid_saved, vec.u_mid)
    copy(vec.v_mid_saved, vec.v_mid)
    copy(vec.a_mid_saved, vec.a_mid)
    copy(vec.p_mid_saved, vec.p_mid)
    copy(vec.a_start_saved, vec.a_start)


@jitable(inline=True)
def _restore(run, vec):
    run.a_h, run.a_t_end = run.saved_h, run.saved_t_end
    run.a_proposed, run.a_clipped = run.saved_proposed, run.saved_clipped
    run.a_iterations, run.a_newton_error = run.saved_iterations, run.saved_newton_error
    run.a_err = run.saved_err
    run.a_estimated = False             # VECTORS.error is the last trial's
    run.a_outcome = OK
    copy(vec.u_new, vec.u_saved)
    copy(vec.v_new, vec.v_saved)
    copy(vec.a_new, vec.a_saved)
    copy(vec.f_new, vec.f_saved)
    copy(vec.p_new, vec.p_saved)
    copy(vec.u_mid, vec.u_mid_saved)
    copy(vec.v_mid, vec.v_mid_saved)
    copy(vec.a_mid, vec.a_mid_saved)
    copy(vec.p_mid, vec.p_mid_saved)
    copy(vec.a_start, vec.a_start_saved)


@jitable(inline=True)
def _trial(fn, cfg, data, run, vec, h, t_limit, hfdi):
    """One trial of the first step's search: the outcome, or ``-1`` when ``h``
    is below the resolution of time (no attempt)."""
    t_end, clipped = clip(cfg, run, h, t_limit)
    if not t_end - run.t > 0.0:
        return -1
    outcome = try_attempt(fn, cfg, data, run, vec, h, t_limit, t_end, clipped, hfdi)
    run.first_step_trials += 1
    run.first_step_trial_iterations += run.a_iterations
    run.trials += 1
    run.trials_smallest = min(run.trials_smallest, run.a_h)
    return outcome


@jitable(inline=True)
def _iteration_init(fn, cfg, data, run, vec, h, t_limit, hfdi):
    """The first step of the iteration-count rule (:func:`hfdi.core.control.iteration_search`),
    the closest converged trial kept aside (:func:`_save`). ``(found, outcome)``:
    whether one converged, and the outcome of a model fault that stops the
    search."""
    run.search_low = run.search_high = math.nan
    run.search_best = math.inf
    found = False
    for _ in range(cfg.first_step_trials):
        outcome = _trial(fn, cfg, data, run, vec, h, t_limit, hfdi)
        if outcome == -1:
            break
        if _is_shape_fault(outcome):
            return found, outcome
        if outcome != OK:
            run.trial_failure = outcome
        better, done, h = iteration_search(cfg, run, outcome == OK, run.a_iterations, run.a_h,
                                           run.a_clipped)
        if better:
            found = True
            _save(run, vec)
        if done:
            break
    return found, OK


@jitable(inline=True)
def _error_init(fn, cfg, data, run, vec, h, t_limit, hfdi):
    """The first step by the error estimate from the Taylor predictor (no
    history): shrink ``h`` until the estimate passes. ``(found, outcome,
    next size)``; the last rejection's guard in ``RUN.trial_guard`` and its size in
    ``RUN.stop_next`` for the message."""
    run.trial_guard = STOP_NONE
    for rejections in range(cfg.first_step_trials):
        outcome = _trial(fn, cfg, data, run, vec, h, t_limit, hfdi)
        if outcome == -1:
            break
        if _is_shape_fault(outcome):
            return False, outcome, h
        accepted, h_next, reason = error_adapt(cfg, run.a_h, h, run.a_clipped, outcome == OK,
                                               run.a_err, run.has_previous, rejections)
        if accepted:
            return True, OK, h_next
        run.trial_guard = reason
        run.stop_next = h_next
        # first_step_trials bounds this loop; max_halvings is the bound of a
        # later step's rejections; min_step bounds both
        if reason == STOP_HALVINGS:
            if h_next < cfg.er_min_step:
                run.trial_guard = STOP_MIN_STEP
                break
        elif reason != STOP_NONE:
            break
        h = h_next
    run.trials_smallest = h                # the message's "down to"
    return False, OK, h


@jitable(inline=True)
def first_step(fn, cfg, data, run, vec, t_limit, hfdi):
    """The first step, chosen by the built-in controller's rule; its trials
    other than the accepted one are counted apart from the steps."""
    run.trials = 0
    run.trials_smallest = math.inf
    run.stop_t = 0.0
    kind = cfg.controller
    h_next = run.proposed
    if kind == FIXED:
        outcome = _trial(fn, cfg, data, run, vec, cfg.fixed_step, t_limit, hfdi)
        if _is_shape_fault(outcome):
            return _shape_stop(run, outcome)
        if outcome != OK:
            if outcome == -1:
                return stop(run, STEP_BELOW_MINIMUM, STOP_BELOW_RESOLUTION)
            return stop(run, NEWTON_FAILED, STOP_FIXED_FAILED)
        h_next = cfg.fixed_step
    elif kind == ERROR:
        found, outcome, h_next = _error_init(fn, cfg, data, run, vec, run.proposed, t_limit,
                                             hfdi)
        if _is_shape_fault(outcome):
            return _shape_stop(run, outcome)
        if not found:
            return stop(run, FIRST_STEP_FAILED, STOP_FIRST_STEP)
    else:
        found, outcome = _iteration_init(fn, cfg, data, run, vec, run.proposed, t_limit,
                                         hfdi)
        if _is_shape_fault(outcome):
            return _shape_stop(run, outcome)
        if not found:
            return stop(run, FIRST_STEP_FAILED, STOP_FIRST_STEP)
        _restore(run, vec)
        accepted, h_next, reason = adapt(cfg, run, run.a_outcome == OK, run.a_err)
        if kind == COMBINED and not accepted:
            found, outcome, h_next = _error_init(fn, cfg, data, run, vec, h_next, t_limit,
                                                 hfdi)
            if _is_shape_fault(outcome):
                return _shape_stop(run, outcome)
            if not found:
                return stop(run, FIRST_STEP_FAILED, STOP_FIRST_STEP)
    run.first_step_trial_iterations -= run.a_iterations
    run.steps += 1
    run.newton_iterations += run.a_iterations
    run.first_step_pending = False
    run.proposed = h_next
    return accept(fn, cfg, data, run, vec)


# -- a step, and runs of them ------------------------------------------------------------

@jitable(inline=True)
def take_step(fn, cfg, data, run, vec, t_limit, hfdi):
    """One accepted step not beyond ``t_limit`` (``> RUN.t``), rejected attempts
    retried as the controller says. False when the run stopped (``RUN.status``)."""
    t_limit = min(t_limit, cfg.t_bound)
    if run.first_step_pending:
        end = limit(cfg, data, run, t_limit)
        if 0.0 < end - run.t and is_short(end - run.t, run.proposed):
            # before the first step too; the controller's rule stays pending
            return short_step(fn, cfg, data, run, vec, end, end, hfdi)
        return first_step(fn, cfg, data, run, vec, end, hfdi)
    end = limit(cfg, data, run, t_limit)
    run.rejections = 0
    while True:
        if run.steps >= cfg.max_steps:
            run.stop_t = t_limit
            return stop(run, MAX_STEPS, STOP_MAX_STEPS)
        t_end, clipped = clip(cfg, run, run.proposed, end)
        h = t_end - run.t
        if 0.0 < h and is_short(h, run.proposed):
            return short_step(fn, cfg, data, run, vec, t_end, end, hfdi)
        if not h > 0.0:
            return stop(run, STEP_BELOW_MINIMUM, STOP_BELOW_RESOLUTION)
        outcome = try_attempt(fn, cfg, data, run, vec, run.proposed, end, t_end, clipped, hfdi)
        if _is_shape_fault(outcome):
            return _shape_stop(run, outcome)
        run.steps += 1
        run.newton_iterations += run.a_iterations
        converged = outcome == OK
        accepted, h_next, reason = adapt(cfg, run, converged, run.a_err)
        if accepted:
            run.proposed = h_next
            return accept(fn, cfg, data, run, vec)
        run.rejected += 1
        if converged:
            run.error_test_failures += 1
        if reason != STOP_NONE:
            run.stop_next = h_next
            return stop(run, status_of(reason), reason)
        run.proposed = h_next
        run.rejections += 1


@jitable(inline=True)
def advance(fn, cfg, data, run, vec, t_stop, max_accepted, hfdi):
    """Steps until ``t_stop`` (``≤ t_bound``), at most ``max_accepted`` of them
    (a callback's one at a time), rows into ``VECTORS.row_*`` while they have
    room. Returns why it returned (:mod:`hfdi.core.codes`: ``REACHED``,
    ``STOPPED``, ``ROWS_FULL``); with ``max_accepted`` steps taken, ``REACHED``
    too (``RUN.t`` tells)."""
    run.rows = 0
    capacity = vec.row_t.shape[0]
    taken = 0
    while run.t < t_stop:
        if run.status < 0:
            return STOPPED
        if taken >= max_accepted:
            return REACHED
        if capacity and run.rows + 2 > capacity:
            return ROWS_FULL
        if not take_step(fn, cfg, data, run, vec, t_stop, hfdi):
            return STOPPED
        taken += 1
        if run.t >= cfg.t_bound:
            run.status = SUCCESS
    return REACHED


@entry
def advance_hfdi(fn, cfg, data, run, vec, t_stop, max_accepted):
    """:func:`advance` compiled for a scheme of HFDI's stage: ``cfg`` and ``run``
    as one-element structured arrays (:meth:`hfdi.core.records.Scalars.pack`),
    ``data``, ``vec`` and ``fn`` as their compiled structs."""
    return advance(fn, cfg[0], data, run[0], vec, t_stop, max_accepted, HFDI_STAGES)


@entry
def advance_affine(fn, cfg, data, run, vec, t_stop, max_accepted):
    """:func:`advance` compiled for a scheme of affine stages (as
    :func:`advance_hfdi`): a run compiles only the stages its scheme takes."""
    return advance(fn, cfg[0], data, run[0], vec, t_stop, max_accepted, AFFINE_STAGES)
