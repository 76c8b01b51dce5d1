"""Steps under a controller object of the user's (:class:`hfdi.controller.Controller`).

The attempts, the error estimate, short steps and the acceptance are the
stepping code's (:mod:`hfdi.stepping`), run in Python; this loop only puts
the controller's ``init``, ``adapt`` and ``landing`` where the built-in
controllers' rules are (:func:`hfdi.stepping.loop.take_step`).
"""
from __future__ import annotations

import numpy as np

from .controller import Attempt
from .core import codes
from .core.control import is_breakpoint, limit
from .core.estimate import displacement_noise, is_short, velocity_noise
from .evaluation import ModelFault
from .messages import Status, attempt_message, stop_message
from .stepping import attempt as stepping
from .stepping.loop import short_step

__all__ = ["custom_steps"]

_KEPT = ("u_new", "v_new", "a_new", "f_new", "p_new", "u_mid", "v_mid", "a_mid", "p_mid",
         "a_start")
_KEPT_RUN = ("a_h", "a_t_end", "a_proposed", "a_clipped", "a_iterations", "a_newton_error")


class _ShapeFault(Exception):
    """A model's value of a wrong shape: the run stops with MODEL_ERROR."""


def custom_steps(itg, t_stop, max_accepted):
    """Steps of ``itg`` towards ``t_stop``, at most ``max_accepted``; the rows
    the accepted steps write handed on whenever their buffer fills, and at
    the end (they were never handed on: ``integrate`` with a subclass of
    ``ErrorControl`` returned the initial row alone, with SUCCESS)."""
    try:
        _custom_steps(itg, t_stop, max_accepted)
    finally:
        itg._hand_on_rows()


def _custom_steps(itg, t_stop, max_accepted):
    run = itg._run
    room = itg._vec.row_t.shape[0]
    taken = 0
    with np.errstate(all="ignore"):
        while run.t < t_stop and taken < max_accepted and run.status >= 0:
            if room and run.rows + 2 > room:   # a step writes two rows at a breakpoint
                itg._hand_on_rows()
            try:
                if not _step(itg, t_stop):
                    return
            except _ShapeFault:
                stepping.stop(run, codes.MODEL_ERROR, codes.STOP_MODEL_SHAPE)
                return
            except ModelFault as exc:
                run.status = int(Status.MODEL_ERROR)
                itg._message = (f"t = {run.t:.10g}: potential_energy failed at the end of the "
                                f"step to t = {run.a_t_end:.10g}: {exc}")
                return
            taken += 1
            if run.t >= itg._cfg.t_bound:
                run.status = int(Status.SUCCESS)


def _fail(itg, status, message):
    itg._run.status = int(status)
    itg._message = f"t = {itg.t:.10g}: {message}"
    return False


def _clip(itg, h, t_limit):
    """The controller's landing rule: ``(t_end, clipped)``."""
    t = itg._run.t
    remaining = t_limit - t
    take = itg.controller.landing(h, remaining)
    if take >= remaining:
        return t_limit, True
    return t + take, take != h


def _try(itg, proposed, t_limit, landing=None):
    """One attempt as an :class:`~hfdi.controller.Attempt` (``None`` below the
    resolution of time), its end state kept with it."""
    run, cfg, data, vec = itg._run, itg._cfg, itg._data, itg._vec
    t_end, clipped = _clip(itg, proposed, t_limit) if landing is None else landing
    h = t_end - run.t
    if not h > 0.0:
        return None
    run.a_proposed, run.a_clipped = proposed, clipped
    left = t_end == t_limit and is_breakpoint(data, t_end)
    outcome = stepping.attempt(itg._functions(), cfg, data, run, vec, t_end, left, itg._hfdi)
    if outcome in codes.SHAPE_FAULTS:
        raise _ShapeFault
    converged = outcome == codes.OK
    attempt = Attempt(h, proposed, clipped, converged, run.a_iterations,
                      "" if converged else attempt_message(run, cfg, itg.ev.fault),
                      history=run.has_previous, first=bool(run.first_step_pending))
    attempt.kept = ({name: getattr(vec, name).copy() for name in _KEPT},
                    {name: getattr(run, name) for name in _KEPT_RUN})
    if converged and itg.controller.uses_error_estimate:
        stepping.estimate_error(cfg, data, run, vec, h)
        attempt.error = vec.error.copy()
        attempt.y_start = np.concatenate([vec.u, vec.v])
        attempt.y_end = np.concatenate([vec.u_new, vec.v_new])
        attempt.velocity_noise = velocity_noise(cfg.velocity_gain, run.a_newton_error, vec, h)
        attempt.displacement_noise = displacement_noise(run.a_newton_error, vec)
        attempt.elapsed = t_end - run.t_start
        attempt.accepted = run.accepted
    return attempt


def _accept(itg, attempt):
    vectors, scalars = attempt.kept
    for name, value in vectors.items():
        getattr(itg._vec, name)[:] = value
    for name, value in scalars.items():
        setattr(itg._run, name, value)
    itg._run.a_taylor = False
    return stepping.accept(itg._functions(), itg._cfg, itg._data, itg._run, itg._vec)


def _step(itg, t_limit):
    run, cfg, data, vec = itg._run, itg._cfg, itg._data, itg._vec
    fn = itg._functions()
    t_limit = min(t_limit, cfg.t_bound)
    end = limit(cfg, data, run, t_limit)
    if run.first_step_pending:
        if 0.0 < end - run.t and is_short(end - run.t, run.proposed):
            return short_step(fn, cfg, data, run, vec, end, end, itg._hfdi)

        def trial(h):
            attempt = _try(itg, h, end)
            if attempt is not None:
                run.first_step_trials += 1
                run.first_step_trial_iterations += attempt.iterations
            return attempt

        attempt, decision = itg.controller.init(trial, run.proposed)
        if attempt is None:
            return _fail(itg, Status[decision.status or "FIRST_STEP_FAILED"], decision.message)
        run.first_step_trial_iterations -= attempt.iterations
        run.steps += 1
        run.newton_iterations += attempt.iterations
        run.first_step_pending = False
        run.proposed = decision.next_step
        return _accept(itg, attempt)
    rejections = 0
    while True:
        if run.steps >= cfg.max_steps:
            run.stop_t = t_limit
            stepping.stop(run, codes.MAX_STEPS, codes.STOP_MAX_STEPS)
            itg._message = stop_message(run, cfg)
            return False
        landing = _clip(itg, run.proposed, end)
        h = landing[0] - run.t
        if 0.0 < h and is_short(h, run.proposed):
            return short_step(fn, cfg, data, run, vec, landing[0], end, itg._hfdi)
        attempt = _try(itg, run.proposed, end, landing)
        if attempt is None:
            return _fail(itg, Status.STEP_BELOW_MINIMUM, f"step {run.proposed:.6g} is below "
                                                         f"the resolution of time at t")
        run.steps += 1
        run.newton_iterations += attempt.iterations
        decision = itg.controller.adapt(attempt, rejections)
        if decision.accept:
            run.proposed = decision.next_step
            return _accept(itg, attempt)
        run.rejected += 1
        if attempt.converged:
            run.error_test_failures += 1
        if decision.status is not None:
            return _fail(itg, Status[decision.status],
                         f"{decision.message} (to t = {run.t + attempt.h:.10g})")
        run.proposed = decision.next_step
        rejections += 1
