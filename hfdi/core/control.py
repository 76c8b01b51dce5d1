"""The built-in controllers' rules (docs/algorithm.md, "Step-size control" and
"Error control"), landing, the fixed step's grid and the load breakpoints.

The user-facing controller objects (:mod:`hfdi.controller`) carry their
settings into ``CONFIG``; the rules are these functions, for both speeds.
Each ``adapt`` returns ``(accept, next size, stop)`` with ``stop`` one of
:mod:`hfdi.core.codes`' stops (``STOP_NONE``: none).
"""
from __future__ import annotations

import math

from .codes import STOP_FIXED_FAILED, STOP_HALVINGS, STOP_MIN_STEP, STOP_NONE
from .jit import jitable
from .state import COMBINED, ERROR, FIXED, ITERATION

__all__ = ["landing", "clip", "limit", "on_grid", "is_breakpoint", "passes_breakpoint",
           "retry", "iteration_adapt", "error_adapt", "adapt", "iteration_search", "uses_error"]


@jitable
def landing(cfg, h, remaining):
    """The size to take when ``remaining`` is left to the next time to reach and
    ``h`` is proposed. The iteration-count rule (the paper's tables) lands when
    within 1 %; the others stretch a step within 10 % and split what is left
    of less than two steps evenly, so that no sliver of a step is taken."""
    if cfg.controller == ITERATION:
        if h >= remaining or remaining - h <= 0.01 * h:
            return remaining
        return h
    if remaining <= 1.1 * h:
        return remaining
    if remaining < 2.0 * h:
        return 0.5 * remaining
    return h


@jitable
def clip(cfg, run, h, t_limit):
    """``(t_end, clipped)``: the end of a step of proposed size ``h`` that must not
    pass ``t_limit``, and whether it was shortened or stretched to land (the
    fixed step: its grid ``grid_origin + k h``)."""
    t = run.t
    if cfg.controller == FIXED:
        t_next = run.grid_origin + (run.grid_steps + 1) * h
        # within a millionth of the step the grid point is t_limit itself
        if t_next >= t_limit - 1e-6 * h:
            return t_limit, True
        return t_next, False
    remaining = t_limit - t
    take = landing(cfg, h, remaining)
    if take >= remaining:
        return t_limit, True
    return t + take, take != h


@jitable
def on_grid(run, h, point):
    """Whether the fixed step's grid as it is now lands on ``point`` (within its
    landing rule's ``1e-6 h``)."""
    origin = run.grid_origin
    return abs(point - (origin + round((point - origin) / h) * h)) <= 1e-6 * h


@jitable
def limit(cfg, data, run, t_limit):
    """``t_limit``, or the next load breakpoint before it (with a fixed step,
    the next one on its grid)."""
    points = data.breakpoints
    if points.shape[0]:
        i = 0
        while i < points.shape[0] and points[i] <= run.t:      # the first one after t
            i += 1
        while i < points.shape[0] and points[i] < t_limit:
            if cfg.controller != FIXED or on_grid(run, cfg.fixed_step, points[i]):
                return float(points[i])
            i += 1
    return t_limit


@jitable
def passes_breakpoint(data, t_start, t_end):
    """Whether a load breakpoint lies strictly inside ``(t_start, t_end)``."""
    points = data.breakpoints
    for i in range(points.shape[0]):
        if points[i] > t_start:
            return points[i] < t_end
    return False


@jitable
def is_breakpoint(data, t):
    points = data.breakpoints
    for i in range(points.shape[0]):
        if points[i] >= t:
            return points[i] == t
    return False


@jitable(inline=True)
def _clamp(h, low, high):
    return min(max(h, low), high)


@jitable(inline=True)
def retry(rejections, max_rejections, h_next, min_step):
    """Reject; retry with ``h_next`` unless ``max_rejections`` or ``min_step`` stops."""
    if rejections + 1 > max_rejections:
        return False, h_next, STOP_HALVINGS
    if h_next < min_step:
        return False, h_next, STOP_MIN_STEP
    return False, h_next, STOP_NONE


@jitable
def iteration_adapt(cfg, h, proposed, clipped, converged, iterations, rejections):
    """Eq. 39, ``h (N̄/N)^{1/2}``; a step shortened to land that converged within
    the target keeps the proposal; a diverged attempt is halved."""
    if converged:
        target = cfg.target
        if clipped and iterations <= target:
            new = proposed
        else:
            new = h * math.sqrt(target / max(iterations, 1))
        return True, _clamp(new, cfg.it_min_step, cfg.it_max_step), STOP_NONE
    return retry(rejections, cfg.it_max_rejections, 0.5 * h, cfg.it_min_step)


@jitable
def error_adapt(cfg, h, proposed, clipped, converged, err, history, rejections):
    """Accept ``err ≤ 1``; the next size ``h · safety · err^{−1/(p+1)}`` within
    ``[shrink, grow] h`` (at most ``h`` after a rejection, exponent 1/3 after a
    step without history); a diverged attempt or an estimate that is not
    finite is halved."""
    if not converged or not math.isfinite(err):
        return retry(rejections, cfg.er_max_rejections, 0.5 * h, cfg.er_min_step)
    exponent = 1.0 / (cfg.order + 1) if history else 1.0 / 3.0
    if err == 0.0:
        factor = cfg.grow
    else:
        factor = min(cfg.grow, max(cfg.shrink, cfg.safety * err ** (-exponent)))
    if err <= 1.0:
        if rejections:
            factor = min(factor, 1.0)
        h_next = h * factor
        if clipped:
            h_next = max(h_next, min(proposed, h * cfg.grow))
        return True, _clamp(h_next, cfg.er_min_step, cfg.er_max_step), STOP_NONE
    return retry(rejections, cfg.er_max_rejections, h * factor, cfg.er_min_step)


@jitable
def adapt(cfg, run, converged, err):
    """The verdict of the built-in controller on the last attempt (``RUN.a_*``)."""
    h, proposed, clipped = run.a_h, run.a_proposed, run.a_clipped
    kind = cfg.controller
    if kind == FIXED:
        if converged:
            return True, cfg.fixed_step, STOP_NONE
        return False, cfg.fixed_step, STOP_FIXED_FAILED
    if kind == ITERATION:
        return iteration_adapt(cfg, h, proposed, clipped, converged, run.a_iterations,
                               run.rejections)
    if kind == ERROR:
        return error_adapt(cfg, h, proposed, clipped, converged, err, run.has_previous,
                           run.rejections)
    accept_a, next_a, stop_a = iteration_adapt(cfg, h, proposed, clipped, converged,
                                               run.a_iterations, run.rejections)
    accept_b, next_b, stop_b = error_adapt(cfg, h, proposed, clipped, converged, err,
                                           run.has_previous, run.rejections)
    if stop_a != STOP_NONE:
        return accept_a, next_a, stop_a
    if stop_b != STOP_NONE:
        return accept_b, next_b, stop_b
    return accept_a and accept_b, min(next_a, next_b), STOP_NONE


@jitable
def iteration_search(cfg, run, converged, iterations, h, clipped):
    """One trial of the first step's search for ``N̄`` corrections (Section 5):
    ``(better, done, next size)``. The search brackets ``h`` between a size
    that needs too few corrections and one that needs too many (or diverges),
    doubling or halving until bracketed and bisecting geometrically after,
    until a trial is within ±0.5 of ``N̄``; ``better`` says the trial is the
    closest so far, which the caller keeps. Its state is ``RUN.search_*``
    (start: ``search_low = search_high = NaN``, ``search_best = inf``)."""
    target = cfg.target
    better = False
    if converged:
        distance = abs(iterations - target)
        if distance < run.search_best:
            run.search_best = distance
            better = True
        if distance <= 0.5 or (iterations < target and (clipped or h >= cfg.it_max_step)):
            return better, True, h
        if iterations < target:
            run.search_low = h
        else:
            run.search_high = h
    else:
        run.search_high = h
    low, high = run.search_low, run.search_high
    if not math.isnan(low) and not math.isnan(high):
        if high / low < 1.0 + 1e-3:
            return better, True, h
        h = math.sqrt(low * high)
    elif not math.isnan(low):
        h = min(2.0 * low, cfg.it_max_step)
    else:
        h = 0.5 * high
    return better, h < cfg.it_min_step, h


@jitable(inline=True)
def uses_error(cfg):
    return cfg.controller == ERROR or cfg.controller == COMBINED
