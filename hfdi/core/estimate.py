"""Predictor (Eqs. 36–37), local error estimate and its weighted norm.

docs/algorithm.md, "Predictor" and "Error control", derives each formula.
"""
from __future__ import annotations

import math

import numpy as np

from .arrays import axpy, dot, lincomb, max_abs
from .jit import jitable, primitive

__all__ = ["predict", "local_error", "velocity_history_factor", "error_norm", "weighted_rms",
           "velocity_noise", "displacement_noise", "error_fraction", "default_atol",
           "first_step_atol", "SHARE_FLOOR_STEPS", "SHORT_STEP", "is_short"]

#: A step shorter than this fraction of the one proposed is a *short step*,
#: taken by Taylor's expansion (or the scheme past a stiff component) and not
#: kept as the history (docs/algorithm.md, "Short steps").
SHORT_STEP = 1e-3

_EPS = float(np.finfo(float).eps)


@jitable(inline=True)
def is_short(h, proposed):
    """Whether a step of size ``h`` where ``proposed`` was proposed is a short step."""
    return h < SHORT_STEP * proposed


@jitable
def predict(run, vec, s, out):
    """The corrector's initial guess ``s`` after ``t`` into ``out`` (Eqs. 36–37):
    ``u + s v`` without history, else the quartic ``P`` with ``P(−H) = u_{n−1}``,
    ``P'(−H) = v_{n−1}``, ``P(0) = u``, ``P'(0) = v``, ``P''(0) = a``:
    ``P(s) = u + s v + a s²/2 − (4σ³ + 3σ⁴) r1 − H(σ³ + σ⁴) r2``, ``σ = s/H``,
    ``r1 = u_{n−1} − u + H v − H² a/2``, ``r2 = v_{n−1} − v + H a``."""
    lincomb(out, 1.0, vec.u, s, vec.v)
    if not run.has_previous:
        return
    H = run.t - run.t_previous
    r1, r2 = vec.tmp, vec.work
    lincomb(r1, 1.0, vec.u_previous, -1.0, vec.u)
    axpy(r1, H, vec.v)
    axpy(r1, -(0.5 * H * H), vec.a)
    lincomb(r2, 1.0, vec.v_previous, -1.0, vec.v)
    axpy(r2, H, vec.a)
    sigma = s / H
    s3 = sigma * sigma * sigma
    s4 = s3 * sigma
    axpy(out, 0.5 * s * s, vec.a)
    axpy(out, -(4.0 * s3 + 3.0 * s4), r1)
    axpy(out, -(H * (s3 + s4)), r2)


@jitable
def velocity_history_factor(sigma, order, defect):
    """``c_v(σ) = 1 + (3σ² + 2σ³)/σ^{p+1} + d (1 + 1/σ)²``: ``v_{n+1} − Q'(h)``
    over the local error of ``v`` in a run, signed. The second term is the
    previous step's error, which enters through ``v_{n−1}``; the third,
    ``Q'``'s own defect ``v^{(4)} h²(h + H)²/24`` against a leading error
    ``λ h⁴ v^{(4)}`` (``d = 1/(24λ)``, order 3; 0 for order 2, whose error
    is of lower order than the defect). For HFDI (``λ = −1/72``) it is
    ``−2 − 4/σ``: the difference has the opposite sign of the error."""
    w = 1.0 + 1.0 / sigma
    return 1.0 + (3.0 + 2.0 * sigma) * sigma ** float(1 - order) + defect * (w * w)


@jitable
def local_error(run, vec, h, velocity_order, defect, a, a_previous):
    """The estimate of the local error of ``u`` and ``v`` of the step from the
    current state to ``VECTORS.*_new`` into ``VECTORS.error`` (2N): the new
    state minus the quartic ``Q`` with ``Q(0) = u``, ``Q'(0) = v``,
    ``Q''(0) = a``, ``Q'(−H) = v_{n−1}``, ``Q''(−H) = a_{n−1}`` (Milne's
    device, no extra evaluation); the velocity's difference divided by
    :func:`velocity_history_factor` (of the order ``velocity_order`` of ``v``'s
    local error, ``defect`` its ``d``). Without history the Taylor polynomial
    ``u + h v + h² a/2`` (and ``v + h a``), erring on the safe side. ``a``
    and ``a_previous`` are the accelerations at ``t`` and ``t_previous``
    (the state's, or the equation of motion's where the state's lags)."""
    n = vec.u.shape[0]
    eu, ev = vec.error[:n], vec.error[n:]
    Q, dQ = vec.tmp, vec.work
    lincomb(Q, 1.0, vec.u, h, vec.v)
    axpy(Q, 0.5 * h * h, a)
    lincomb(dQ, 1.0, vec.v, h, a)
    factor = 1.0
    if run.has_previous:
        H = run.t - run.t_previous
        r2, r3 = vec.rhs, vec.residual
        lincomb(r2, 1.0, vec.v_previous, -1.0, vec.v)
        axpy(r2, H, a)
        lincomb(r3, 1.0, a_previous, -1.0, a)
        s2 = h * h
        # Q += s³ c3 + s⁴ c4, dQ += 3 s² c3 + 4 s³ c4, with
        # c3 = r2/H² + r3/(3H), c4 = (2 r2 + H r3)/(4 H³)
        c3, c4 = vec.kv, vec.vd
        lincomb(c3, 1.0 / (H * H), r2, 1.0 / (3.0 * H), r3)
        lincomb(c4, 2.0 / (4.0 * H * H * H), r2, H / (4.0 * H * H * H), r3)
        axpy(Q, s2 * h, c3)
        axpy(Q, s2 * s2, c4)
        axpy(dQ, 3.0 * s2, c3)
        axpy(dQ, 4.0 * s2 * h, c4)
        factor = velocity_history_factor(h / H, velocity_order, defect)
    lincomb(eu, 1.0, vec.u_new, -1.0, Q)
    lincomb(ev, 1.0 / factor, vec.v_new, -1.0 / factor, dQ)


def _ratio_loop(ratio, error, u0, v0, u1, v1, rtol, atol, noise_u, noise_v, fraction):
    n = u0.shape[0]
    controlled = 0
    for i in range(2 * n):
        if atol[i] == math.inf:
            ratio[i] = 0.0
            continue
        controlled += 1
        if error[i] == 0.0:
            ratio[i] = 0.0
            continue
        if i < n:
            scale = (atol[i] + rtol[i] * max(abs(u0[i]), abs(u1[i]))) * fraction + noise_u
        else:
            scale = (atol[i] + rtol[i] * max(abs(v0[i - n]), abs(v1[i - n]))) * fraction \
                + noise_v
        ratio[i] = error[i] / scale
    return controlled


@primitive(_ratio_loop)
def _ratio(ratio, error, u0, v0, u1, v1, rtol, atol, noise_u, noise_v, fraction):
    n = u0.shape[0]
    scale = (atol + rtol * np.maximum(np.abs(np.concatenate((u0, v0))),
                                      np.abs(np.concatenate((u1, v1))))) * fraction
    scale[:n] += noise_u
    scale[n:] += noise_v
    with np.errstate(divide="ignore", invalid="ignore"):
        np.divide(error, scale, out=ratio)
    uncontrolled = atol == math.inf
    ratio[(error == 0.0) | uncontrolled] = 0.0
    return ratio.shape[0] - int(np.count_nonzero(uncontrolled))


@jitable
def weighted_rms(error, u0, v0, u1, v1, rtol, atol, noise_u, noise_v, fraction, ratio):
    """``‖e / ((atol + rtol·max(|y_0|, |y_1|))·fraction + noise)‖_RMS`` over
    ``y = (u, v)``, ``noise`` being ``noise_u`` for ``u`` and ``noise_v`` for
    ``v`` (:func:`displacement_noise`, :func:`velocity_noise`); entries of
    ``e`` that are 0 count 0 (``ratio`` (2N,) is scratch). ``fraction`` is
    the share of the tolerance the step may spend (:func:`error_fraction`).
    A component whose ``atol`` is infinite is not controlled: it counts
    neither in the sum nor in the number of components (the RMS is over
    those controlled, so that controlling ``u`` alone holds ``u`` to the
    same tolerance)."""
    controlled = _ratio(ratio, error, u0, v0, u1, v1, rtol, atol, noise_u, noise_v, fraction)
    return math.sqrt(dot(ratio, ratio) / controlled)


def default_atol(n, rtol, u_scale, v_scale):
    """The default ``atol`` (2N,): ``1e-3·min(rtol)`` times ``U`` for ``u``
    and ``V`` for ``v`` (:func:`hfdi.options.state_scales`)."""
    scale = 1e-3 * float(np.min(rtol))
    return np.concatenate([np.full(n, scale * u_scale), np.full(n, scale * v_scale)])


def first_step_atol(atol, rtol, u_scale, v_scale):
    """The ``atol`` of the run's first step (2N,): ``atol``, its infinite
    entries (components left uncontrolled) replaced by the default's
    ``1e-3·min(rtol)·U`` for ``u`` and ``·V`` for ``v``. That step has no
    estimate in the global error (:mod:`hfdi.stepping.global_error`) and no
    size to start from, and an uncontrolled ``v`` let it grow until ``u``
    alone limited it: under ``u``-alone control the first step of a forced
    Duffing oscillator was 300 times longer than under ``(u, v)``, and its
    ``v`` error then fed ``u`` unseen (docs/algorithm.md, "Tolerance
    proportionality"). A restart (a load breakpoint) keeps ``atol``: its
    step starts from the run's, and held to ``v`` too, every restart of a
    load with breakpoints each 0.1 s took 2–3 times the steps."""
    atol = np.asarray(atol, dtype=float)
    return np.where(np.isinf(atol), default_atol(atol.shape[0] // 2, rtol, u_scale, v_scale),
                    atol)


#: The share of the tolerance is never below ``1/(SHARE_FLOOR_STEPS·(n + 1))``
#: after ``n`` accepted steps: a run that starts in a fast transient (a
#: stiff, damped mode) resolves it with tiny steps whose mean would make the
#: share so small that the steps could never grow again (docs/algorithm.md,
#: "Tolerance proportionality"). It adds about
#: ``(ln(N/100) + 0.6)/100`` of the tolerance over a run of ``N`` steps.
SHARE_FLOOR_STEPS = 100.0


@jitable
def error_fraction(per_step, span, elapsed, accepted, history):
    """The share of the tolerance a step may spend: all of it under the
    per-step rule and on a step without history (the first, or one after a
    restart, whose Taylor estimate of ``v`` is only ``O(h²)``); else
    ``h̄/τ``, ``h̄ = elapsed/(accepted + 1)`` the mean step of the run so far
    with this one (``elapsed`` from the run's start to the step's end,
    ``accepted`` steps before it) and ``τ`` the run's span, or ``elapsed``
    when the end is not known (``span`` NaN): the run's local errors then
    add up to about the tolerance (docs/algorithm.md, "Tolerance
    proportionality"); but not below ``1/(SHARE_FLOOR_STEPS·(accepted + 1))``."""
    if per_step or not history:
        return 1.0
    tau = elapsed if math.isnan(span) else span
    mean = elapsed / (accepted + 1.0)
    if not tau > mean:
        return 1.0
    return max(mean / tau, 1.0 / (SHARE_FLOOR_STEPS * (accepted + 1.0)))


@jitable
def error_norm(cfg, data, run, vec):
    """The error norm of the estimate in ``VECTORS.error`` of the attempt from
    the current state to ``VECTORS.*_new`` (:func:`weighted_rms`), with the
    share of the tolerance the attempt may spend (:func:`error_fraction`).
    The run's first step is held to ``DATA.first_atol``, which controls
    every component (:func:`first_step_atol`)."""
    h = run.a_h
    fraction = error_fraction(cfg.per_step, cfg.error_span, run.a_t_end - run.t_start,
                              run.accepted, run.has_previous)
    atol = data.first_atol if run.first_step_pending else data.atol
    return weighted_rms(vec.error, vec.u, vec.v, vec.u_new, vec.v_new, data.rtol, atol,
                        displacement_noise(run.a_newton_error, vec),
                        velocity_noise(cfg.velocity_gain, run.a_newton_error, vec, h),
                        fraction, vec.ratio)


@jitable
def displacement_noise(newton_error, vec):
    """The uncertainty of ``u`` the corrector's remaining error and rounding
    leave, ``error + ε‖u‖_∞``: below it a step's error can be neither told
    nor controlled (it matters at a share of the tolerance, where a step's share of
    the tolerance can fall below rounding)."""
    return newton_error + _EPS * max_abs(vec.u_new)


@jitable
def velocity_noise(velocity_gain, newton_error, vec, h):
    """The uncertainty of ``v`` the corrector's remaining error and rounding
    leave, ``g (error + ε‖u_{n+1} − u_n‖_∞)/h`` (``g`` the scheme's velocity
    gain; every scheme forms ``v`` from the increment): below it the
    velocity's error can be neither told nor controlled."""
    lincomb(vec.work, 1.0, vec.u_new, -1.0, vec.u)
    return velocity_gain * (newton_error + _EPS * max_abs(vec.work)) / h
