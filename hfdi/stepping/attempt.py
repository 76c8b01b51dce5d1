"""One attempt at a step, a short step, and the acceptance of a step.

:func:`attempt` takes every stage of the scheme (predictor, then Newton) from
the current state to ``VECTORS.*_new``; :func:`accept` makes that the current
state, with the energy balance (Eqs. 40–41); :func:`short_step` takes a step
much shorter than the one proposed (docs/algorithm.md, "Short steps");
:func:`refresh` recomputes what the state keeps from the load or the model
after either changed from outside.
"""
from __future__ import annotations

import math

from ..core.arrays import (all_finite, axpy, copy, dot, fill, keep_larger, kinetic, lincomb,
                           matvec, row_sum_max, scale, times)
from ..core.codes import (END_NOT_FINITE, ENERGY_GROWTH, MODEL_ERROR, OK, OVERFLOW,
                          SHAPE_FAULTS, STOP_ENERGY, STOP_MODEL_FAULT, STOP_MODEL_SHAPE,
                          STOP_OVERFLOW, STOP_POTENTIAL_LOST)
from ..core.control import is_breakpoint, passes_breakpoint
from ..core.estimate import is_short, local_error, predict, velocity_history_factor
from ..core.jit import jitable
from ..core.state import FIXED, MAX_STAGES
from .global_error import propagate
from .stages import (affine_end, affine_setup, force_into, hfdi_end, hfdi_setup, load_into,
                     mass_solve, newton, one_sided, stiffness_of)

__all__ = ["attempt", "accept", "estimate_error", "taylor_step", "fastest_rate", "SHORT_STEP_RATE", "refresh",
           "stop", "energy_overflows", "carry_global_error"]

#: Taylor's expansion is explicit: a short step is taken by it only where
#: ``h (ω_max + γ_max) ≤ SHORT_STEP_RATE`` (:func:`fastest_rate`); past a
#: stiff component the scheme takes it (docs/algorithm.md).
SHORT_STEP_RATE = 0.1


@jitable(inline=True)
def stop(run, status, reason):
    """Stop the run with a failed ``status`` (hfdi.Status) for ``reason``
    (:mod:`hfdi.core.codes`); the state stays the last good one."""
    run.status = status
    run.stop = reason
    return False


@jitable(inline=True)
def _failed(run, outcome, stage, iterations):
    run.a_outcome = outcome
    run.a_stage = stage
    run.a_iterations = iterations
    return outcome


@jitable
def start_acceleration(fn, cfg, data, run, vec, h):
    """``VECTORS.a_start``, the state's ``a`` as a step of size ``h`` takes it:
    ``a`` itself, or where it is the acceleration at ``t + lag·h`` of the
    previous step's ``H`` (``CONFIG.acceleration_lag``, generalized-α), moved
    to ``t + lag·h`` along the slope of the last two, so that a change of
    step does not disturb the scheme's lagged acceleration (docs/algorithm.md,
    "Tolerance proportionality"). Without history (the first step, a
    restart) the state's ``a`` is the equation of motion's at ``t``, and the
    lagged one is ``a + lag·h ȧ``, ``M ȧ = p' − C a − K v`` with ``p'`` a
    forward difference over ``|lag|·h``: started at ``a`` itself, the scheme
    makes an ``O(h)`` error in its first steps that the estimate does not
    see (docs/algorithm.md, "Global error estimate")."""
    lag = cfg.acceleration_lag
    if lag == 0.0:
        copy(vec.a_start, vec.a)
    elif run.has_previous:
        H = run.t - run.t_previous
        c = lag * (h - H) / H
        lincomb(vec.a_start, 1.0 + c, vec.a, -c, vec.a_previous)
    else:
        tau = lag * h
        delta = abs(tau)
        jerk, work = vec.a_start, vec.work
        outcome, K = stiffness_of(fn, cfg, data, run, vec.u)
        if outcome == OK:
            outcome = load_into(fn, cfg, data, run, run.t + delta, jerk)
        if outcome != OK:
            copy(vec.a_start, vec.a)
            return
        lincomb(jerk, 1.0 / delta, jerk, -1.0 / delta, vec.p)
        matvec(K, vec.v, work)
        axpy(jerk, -1.0, work)
        times(cfg.c_kind, data.Cd, data.Cf, vec.a, work)
        axpy(jerk, -1.0, work)
        if not mass_solve(cfg, data, vec, jerk):
            copy(vec.a_start, vec.a)
            return
        lincomb(vec.a_start, 1.0, vec.a, tau, jerk)


@jitable
def attempt(fn, cfg, data, run, vec, t_end, left, hfdi):
    """One attempt at the step from ``RUN.t`` to ``t_end`` (``left``: it lands on
    a load breakpoint, whose load is taken from the left): every stage,
    predictor then Newton. ``hfdi``: the kind of the scheme's stages,
    :data:`~hfdi.stepping.stages.HFDI_STAGES` or ``AFFINE_STAGES``. Returns
    the outcome (:mod:`hfdi.core.codes`, also in
    ``RUN.a_outcome``); on success the end state is in ``VECTORS.*_new`` (the
    first of two stages' in ``*_mid``), the corrections in
    ``RUN.a_iterations`` and ``VECTORS.stage_iterations``, and Newton's memory
    is carried on."""
    h = t_end - run.t
    run.a_h = h
    run.a_t_end = t_end
    run.a_taylor = False
    run.a_outcome = OK
    run.a_stage = 0
    run.a_iterations = 0
    run.a_newton_error = 0.0
    run.a_err = math.nan
    run.a_estimated = False
    iterations = vec.stage_iterations
    for s in range(MAX_STAGES):
        iterations[s] = 0
    constant, guard = run.newton_constant, run.newton_guard
    if hfdi is None:
        start_acceleration(fn, cfg, data, run, vec, h)
    total = 0
    newton_error = 0.0
    for s in range(cfg.stages):
        st = fn.stage(h, s, data.scheme_params)
        t_load = t_end if st.load_time == 1.0 else run.t + st.load_time * h
        outcome = load_into(fn, cfg, data, run, one_sided(t_load, t_end, left), vec.p_stage)
        if outcome != OK:
            return _failed(run, outcome, s, total)
        predict(run, vec, h if st.time == 1.0 else st.time * h, vec.trial)
        axpy(vec.trial, -1.0, vec.u)        # Newton's unknown is the increment
        if hfdi is not None:
            outcome = hfdi_setup(fn, cfg, data, run, vec, h, t_end, left)
        else:
            outcome = affine_setup(fn, cfg, data, run, vec, st)
        if outcome != OK:
            return _failed(run, outcome, s, total)
        outcome, k, error, constant, guard = newton(fn, cfg, data, run, vec, st, h, constant,
                                                    guard, hfdi)
        if k >= 0:
            iterations[s] = k
            total += k
        if outcome != OK:
            return _failed(run, outcome, s, total)
        newton_error = max(newton_error, error)
        last = s == cfg.stages - 1
        if hfdi is not None:
            outcome = hfdi_end(fn, cfg, data, run, vec, h)
        elif last:
            outcome = affine_end(fn, cfg, data, run, vec, st, vec.u_new, vec.v_new, vec.a_new)
        else:
            outcome = affine_end(fn, cfg, data, run, vec, st, vec.u_mid, vec.v_mid, vec.a_mid)
            copy(vec.p_mid, vec.p_stage)
        if outcome != OK:
            return _failed(run, outcome, s, total)
        if last:
            if st.load_time == 1.0:
                copy(vec.p_new, vec.p_stage)
            else:
                outcome = load_into(fn, cfg, data, run, one_sided(t_end, t_end, left), vec.p_new)
                if outcome != OK:
                    return _failed(run, outcome, s, total)
            if cfg.keeps_force and hfdi is None:
                outcome = force_into(fn, cfg, data, run, vec.u_new, vec.f_new)
                if outcome != OK:
                    return _failed(run, outcome, s, total)
    run.a_iterations = total
    run.a_newton_error = newton_error
    run.newton_constant = constant
    run.newton_guard = guard
    return OK


@jitable
def _equation_acceleration(cfg, data, vec, v, f, p, out):
    """``out = M⁻¹ (p − C v − f)``; false when the mass solve fails."""
    times(cfg.c_kind, data.Cd, data.Cf, v, out)
    lincomb(out, 1.0, p, -1.0, out)
    axpy(out, -1.0, f)
    return mass_solve(cfg, data, vec, out)


@jitable
def estimate_error(cfg, data, run, vec, h):
    """The local error estimate of the attempt just made, into ``VECTORS.error``
    (:func:`hfdi.core.estimate.local_error`). Where the state's acceleration
    lags (``CONFIG.lagged_acceleration``) the estimate's derivative data are
    the equation of motion's accelerations at ``t`` and ``t_previous``, from
    the kept ``f`` and ``p``; the state's where a mass solve fails."""
    if cfg.lagged_acceleration:
        now, before = vec.a_equation, vec.a_equation_previous
        if _equation_acceleration(cfg, data, vec, vec.v, vec.f, vec.p, now) and (
                not run.has_previous or _equation_acceleration(
                    cfg, data, vec, vec.v_previous, vec.f_previous, vec.p_previous, before)):
            local_error(run, vec, h, cfg.velocity_order, cfg.velocity_defect, now, before)
            end = vec.tmp
            if _equation_acceleration(cfg, data, vec, vec.v_new, vec.f_new, vec.p_new, end):
                if run.has_previous:
                    _velocity_by_quadrature(run, vec, h, before, now, end)
                else:
                    _taylor_from_the_end(vec, h, end)
            return
    local_error(run, vec, h, cfg.velocity_order, cfg.velocity_defect, vec.a, vec.a_previous)
    if cfg.velocity_defect != 0.0 and not (cfg.exact_rate or cfg.derived_rate) \
            and run.has_previous:
        _load_rate_error(cfg, data, run, vec, h)


@jitable
def _load_rate_error(cfg, data, run, vec, h):
    """The part of HFDI's local error of ``v`` that the paper's quotient
    ``(p_{n+1} − p_n)/h`` for ``p'(t_{n+1})`` makes, ``R = h³/12 M⁻¹ p''``
    (``p''`` the second divided difference of ``p_{n−1}``, ``p_n``,
    ``p_{n+1}``), into ``v``'s part of ``VECTORS.error``: :func:`local_error`
    divided the velocity's difference by the factor of the scheme's own
    ``λ h⁴ v⁽⁴⁾``; ``R``, of order ``h³``, enters that difference as a local
    error of order 2 does, with ``c_2(σ) = 1 + (3σ² + 2σ³)/σ³`` (its share
    through ``v_{n−1}`` too), so the estimate gains ``(1 − c_2(σ)/c_v(σ)) R``.
    Zero where the load is linear between its breakpoints
    (docs/algorithm.md, "Velocity")."""
    n = cfg.n
    H = run.t - run.t_previous
    R = vec.tmp
    span = h + H
    lincomb(R, 2.0 / (h * span), vec.p_new, -2.0 / (h * span) - 2.0 / (H * span), vec.p)
    axpy(R, 2.0 / (H * span), vec.p_previous)
    scale(R, h * h * h / 12.0, R)
    if not mass_solve(cfg, data, vec, R):
        return
    sigma = h / H
    as_order_2 = velocity_history_factor(sigma, 2, 0.0)
    factor = velocity_history_factor(sigma, cfg.velocity_order, cfg.velocity_defect)
    axpy(vec.error[n:], 1.0 - as_order_2 / factor, R)


@jitable
def _taylor_from_the_end(vec, h, end):
    """A step without history, of a scheme whose acceleration lags: where
    Taylor's polynomial from the step's end, ``u_{n+1} − h v_{n+1} + h² a/2``
    and ``v_{n+1} − h a`` (``a`` the equation of motion's acceleration there,
    with the load at ``t_{n+1}``), misses the start by more than the one from
    the start misses the end, that miss is the estimate. Generalized-α's
    step sees the load at ``t_n + (1 − α_f) h`` alone: a first step over a
    load that jumps in its last ``α_f`` saw nothing, and was accepted (a
    structure at rest under a step load at t = 0.3: one step to 0.5, the
    answer 0.37 off with SUCCESS at any rtol)."""
    n = vec.u.shape[0]
    back = vec.work
    lincomb(back, 1.0, vec.u_new, -h, vec.v_new)
    axpy(back, 0.5 * h * h, end)
    axpy(back, -1.0, vec.u)
    keep_larger(vec.error[:n], back)
    lincomb(back, 1.0, vec.v_new, -h, end)
    axpy(back, -1.0, vec.v)
    keep_larger(vec.error[n:], back)


@jitable
def _velocity_by_quadrature(run, vec, h, before, now, end):
    """``v``'s part of ``VECTORS.error`` for a scheme whose acceleration lags:
    ``v_{n+1} − v_n − ∫ P``, ``P`` the quadratic through the equation of
    motion's accelerations at ``t_{n−1}``, ``t_n`` and the step's end (an
    error ``O(h⁴)`` against the scheme's ``O(h³)``). Its end term sees the
    load at ``t_{n+1}``, which generalized-α's step, evaluating the load at
    ``t_n + (1 − α_f) h``, does not: a jump of the load in the step's last
    ``α_f`` went unseen by step and estimate alike (docs/algorithm.md,
    "Error control")."""
    n = vec.u.shape[0]
    ev = vec.error[n:]
    H = run.t - run.t_previous
    w_before = -h * h * h / (6.0 * H * (H + h))
    w_now = h * h / (6.0 * H) + 0.5 * h
    w_end = (h * h / 3.0 + 0.5 * H * h) / (H + h)
    lincomb(ev, 1.0, vec.v_new, -1.0, vec.v)
    axpy(ev, -w_before, before)
    axpy(ev, -w_now, now)
    axpy(ev, -w_end, end)


@jitable
def fastest_rate(fn, cfg, data, run, vec):
    """A bound of the fastest rate of the motion linearised at ``u``:
    ``ω_max + γ_max``, ``ω_max² ≤ ‖K(u)‖_∞ / λ_min(M)``, ``γ_max ≤ ‖C‖_∞ /
    λ_min(M)`` (Gershgorin; ``CONFIG.mass_floor``): ``inf`` where ``K`` cannot
    be evaluated or no positive bound of ``λ_min(M)`` is known."""
    if not cfg.mass_floor > 0.0:
        return math.inf
    outcome, K = stiffness_of(fn, cfg, data, run, vec.u)
    if outcome != OK:
        return math.inf
    omega2 = row_sum_max(K) / cfg.mass_floor
    rate = math.sqrt(omega2) if math.isfinite(omega2) else math.inf
    return rate + cfg.damping_rate


@jitable
def taylor_step(fn, cfg, data, run, vec, t_end, left):
    """A short step by Taylor's expansion into ``VECTORS.*_new``:
    ``u = u_n + h v_n + h² a_n/2``, ``a`` from the equation of motion there
    (Eq. 14, with ``v_n + h a_n``), ``v = v_n + h (a_n + a)/2``; errors
    ``O(h³)``. An outcome code."""
    h = t_end - run.t
    u, v, a = vec.u_new, vec.v_new, vec.a_new
    lincomb(u, 1.0, vec.u, h, vec.v)
    axpy(u, 0.5 * h * h, vec.a)
    outcome = load_into(fn, cfg, data, run, one_sided(t_end, t_end, left), vec.p_new)
    if outcome != OK:
        return outcome
    outcome = force_into(fn, cfg, data, run, u, vec.f_new)
    if outcome != OK:
        return outcome
    lincomb(v, 1.0, vec.v, h, vec.a)                      # v_n + h a_n, for C v
    times(cfg.c_kind, data.Cd, data.Cf, v, vec.work)
    lincomb(a, 1.0, vec.p_new, -1.0, vec.f_new)
    axpy(a, -1.0, vec.work)
    mass_solve(cfg, data, vec, a)
    lincomb(vec.work, 1.0, vec.a, 1.0, a)
    lincomb(v, 1.0, vec.v, 0.5 * h, vec.work)
    run.a_h = h
    run.a_t_end = t_end
    run.a_iterations = 0
    run.a_estimated = False
    return OK if all_finite(u) and all_finite(v) and all_finite(a) else END_NOT_FINITE


@jitable
def carry_global_error(fn, cfg, data, run, vec, h, taylor):
    """``g_{n+1} = Φ_n g_n + ℓ_{n+1}`` for the accepted step
    (:mod:`hfdi.stepping.global_error`), ``ℓ`` the step's local error
    estimate (made here where the controller did not). A step without
    history adds nothing: its estimate, Taylor's, bounds ``O(h³)`` terms
    that are not its error, and the error rule sizes such a step so that
    its true error is far below (docs/algorithm.md, "Global error
    estimate"); a short step by Taylor's expansion adds nothing either. A
    fixed step over a load breakpoint off its grid leaves no estimate (NaN)."""
    propagate(fn, cfg, data, run, vec, h)
    if cfg.controller == FIXED and passes_breakpoint(data, run.t, run.a_t_end):
        # a fixed step over a load jump off its grid: an O(h) error the
        # estimate, made for smooth loads, does not see (250 times too small
        # or 160 times too large): no estimate from here on
        fill(vec.global_error, math.nan)
        return
    if taylor or not run.has_previous:
        return
    if not run.a_estimated:
        estimate_error(cfg, data, run, vec, h)
    axpy(vec.global_error, 1.0, vec.error)
    if not all_finite(vec.global_error):
        fill(vec.global_error, math.nan)      # lost: NaN from here on, never inf


@jitable(inline=True)
def energy_overflows(kinetic_energy, work, potential):
    """Whether a step's energy terms are beyond floating point: an infinite or
    NaN kinetic energy or work (a NaN is an ``inf − inf`` here), or an
    infinite potential energy (a NaN one is the model's "unknown")."""
    return not (math.isfinite(kinetic_energy) and math.isfinite(work)) or math.isinf(potential)


@jitable
def _row(run, vec, h, iterations, increment, energy):
    i = run.rows
    vec.row_t[i] = run.t
    vec.row_h[i] = h
    vec.row_iterations[i] = iterations
    vec.row_increment[i] = increment
    vec.row_energy[i] = energy
    vec.row_work[i] = run.work
    copy(vec.row_u[i], vec.u)
    copy(vec.row_v[i], vec.v)
    copy(vec.row_a[i], vec.a)
    copy(vec.row_global[i], vec.global_error)
    run.rows = i + 1


@jitable
def accept(fn, cfg, data, run, vec):
    """Make the attempt's end (``VECTORS.*_new``) the current state: the energy
    balance (Eqs. 40–41: ``ΔE = V_{n+1} − V_n + T_{n+1} − T_n − ΔL``, ``ΔL`` by
    the trapezoidal rule over the stage ends where the scheme feels the
    load; its ends only after a Taylor step, ``RUN.a_taylor``), the
    history (not kept after a short step), the fixed step's
    grid, the restart at a load breakpoint, the statistics, and a row when
    ``VECTORS.row_t`` has room. False when the run stops (``RUN.status``):
    a potential energy lost or overflowing terms (the state is then not
    accepted), or ``energy_limit`` (it is)."""
    h = run.a_h
    t_end = run.a_t_end
    taylor = run.a_taylor
    run.npev += 1
    potential = fn.potential_energy(vec.u_new, data.params)
    if math.isnan(potential) and not math.isnan(run.initial_potential):
        run.stop_t = t_end
        return stop(run, MODEL_ERROR, STOP_POTENTIAL_LOST)
    kinetic_old = kinetic(cfg.m_kind, data.Md, data.Mf, vec.v, vec.work)
    kinetic_new = kinetic(cfg.m_kind, data.Md, data.Mf, vec.v_new, vec.work)
    difference, total = vec.tmp, vec.work
    if cfg.stages > 1 and not taylor:
        lincomb(difference, 1.0, vec.u_mid, -1.0, vec.u)
        lincomb(total, 1.0, vec.p, 1.0, vec.p_mid)
        work = 0.5 * dot(difference, total)
        lincomb(difference, 1.0, vec.u_new, -1.0, vec.u_mid)
        lincomb(total, 1.0, vec.p_mid, 1.0, vec.p_new)
        work += 0.5 * dot(difference, total)
    else:
        lincomb(difference, 1.0, vec.u_new, -1.0, vec.u)
        lincomb(total, 1.0, vec.p, 1.0, vec.p_new)
        work = 0.5 * dot(difference, total)
    if energy_overflows(kinetic_new, work, potential):
        run.stop_t, run.stop_kinetic, run.stop_work = t_end, kinetic_new, work
        run.stop_potential = potential
        return stop(run, OVERFLOW, STOP_OVERFLOW)
    increment = potential - run.potential + kinetic_new - kinetic_old - work   # Eq. 40
    if cfg.global_error:
        carry_global_error(fn, cfg, data, run, vec, h, taylor)
    if not is_short(h, run.proposed):
        copy(vec.u_previous, vec.u)
        copy(vec.v_previous, vec.v)
        if cfg.acceleration_lag != 0.0:
            # a lagged a is at t + lag·h of the step that made it, and the
            # state's is the equation's after a start or restart: the history
            # keeps the value this step started from, a step of h before the
            # new one at the same lag, as start_acceleration's slope assumes
            # (with the state's a the slope erred by about ȧ wherever the
            # step changed: generalized-α with ρ∞ ≤ 0.5 shrank its steps to
            # 1e-9 s and never recovered)
            copy(vec.a_previous, vec.a_start)
        else:
            copy(vec.a_previous, vec.a)
        copy(vec.f_previous, vec.f)
        copy(vec.p_previous, vec.p)
        run.t_previous = run.t
        run.has_previous = True
    elif cfg.acceleration_lag != 0.0:
        # a short step leaves a lagged a at its own short lag (the equation's
        # after Taylor's expansion), which no longer pairs with the history:
        # the next step starts afresh (kept, its steps fell 1e4-fold after an
        # advance to just past t)
        run.has_previous = False
    copy(vec.u, vec.u_new)
    copy(vec.v, vec.v_new)
    copy(vec.a, vec.a_new)
    copy(vec.f, vec.f_new)
    copy(vec.p, vec.p_new)
    run.has_force = cfg.keeps_force or taylor
    run.t = t_end
    if cfg.controller == FIXED:
        step = run.grid_origin + (run.grid_steps + 1) * h
        if run.a_clipped and t_end != step and abs(
                t_end - (run.grid_origin + (run.grid_steps + 1) * run.a_proposed)) \
                > 1e-6 * run.a_proposed:
            run.grid_origin = t_end                    # shortened off the grid
            run.grid_steps = 0
        else:
            run.grid_steps += 1
    run.work += work
    run.energy_error += increment
    run.energy_scale = max(run.energy_scale, kinetic_new + abs(potential - run.initial_potential)
                           + abs(run.work))
    run.potential = potential
    run.last_step = h
    run.last_iterations = run.a_iterations
    run.last_energy_increment = increment
    run.accepted += 1
    run.t_reached = t_end
    saving = vec.row_t.shape[0] > 0
    if saving:
        _row(run, vec, h, run.a_iterations, increment, potential + kinetic_new)
    run.restarted = False
    if is_breakpoint(data, t_end):
        # a kink or jump of the load: the history behind it would spoil the
        # predictor, and the next step starts from the load's right limit
        run.has_previous = False
        copy(vec.a_new, vec.a)
        if not refresh(fn, cfg, data, run, vec, False):
            return False
        run.restarted = False
        for i in range(vec.a.shape[0]):
            if vec.a[i] != vec.a_new[i]:
                run.restarted = True
                break
        if saving and run.restarted and run.t < cfg.t_bound:
            _row(run, vec, 0.0, 0, 0.0, potential + kinetic(cfg.m_kind, data.Md, data.Mf,
                                                            vec.v, vec.work))
    limit = cfg.energy_limit
    if math.isfinite(limit) and math.isfinite(increment) and \
            run.energy_error > limit * max(run.energy_scale, 1e-300):
        return stop(run, ENERGY_GROWTH, STOP_ENERGY)
    return True


@jitable(inline=True)
def _is_shape_fault(outcome):
    for code in SHAPE_FAULTS:
        if outcome == code:
            return True
    return False


@jitable
def refresh(fn, cfg, data, run, vec, new_force):
    """The current state with ``p`` (the right limit) and ``a`` from the load
    now, and ``f`` too with ``new_force`` or when not kept, the step history
    dropped (a jump of the load or the model: the history behind it would
    spoil the predictor and the error estimate). False (the run stopped, the
    state unchanged) when the model fails there."""
    outcome = load_into(fn, cfg, data, run, run.t, vec.p_new)
    if outcome == OK and (new_force or not run.has_force):
        outcome = force_into(fn, cfg, data, run, vec.u, vec.f_new)
    elif outcome == OK:
        copy(vec.f_new, vec.f)
    if outcome != OK:
        run.a_outcome = outcome
        run.stop_t = run.t
        return stop(run, MODEL_ERROR, STOP_MODEL_SHAPE if _is_shape_fault(outcome)
                    else STOP_MODEL_FAULT)
    a = vec.tmp
    times(cfg.c_kind, data.Cd, data.Cf, vec.v, vec.work)
    lincomb(a, 1.0, vec.p_new, -1.0, vec.f_new)
    axpy(a, -1.0, vec.work)
    mass_solve(cfg, data, vec, a)
    copy(vec.p, vec.p_new)
    copy(vec.f, vec.f_new)
    copy(vec.a, a)
    run.has_force = True
    run.has_previous = False
    return True
