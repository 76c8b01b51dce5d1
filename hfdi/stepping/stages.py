"""The stages of a step and the one Newton corrector that solves them.

Two kinds of stage (:class:`hfdi.core.state.Stage`): *affine* stages, whose
``a`` and ``v`` are affine in the unknown ``u`` (Newmark, both of Bathe's
sub-steps, generalized-α; paper Eqs. 3–10), and HFDI's stage (Eqs. 15–21,
Table 1), in ``u`` alone with ``v_D(u)`` eliminated. Each gives a residual
and its exact tangent at an iterate; :func:`newton` corrects until Eq. 38
(or the estimated remaining error) says it has converged.

Every model value passes through :func:`force_into`, :func:`stiffness_of`,
:func:`derivative_of` or :func:`load_into`, which count it and return a code
for a value of a wrong shape (a mistake in the model: the run stops) or not
finite (a failed attempt: a shorter step may avoid it).
"""
from __future__ import annotations

import math

import numpy as np

from ..core.arrays import (DENSE, DIAGONAL, NONE, add_diagonal, add_scaled, all_finite,
                           all_finite_matrix, axpy, copy, copy_matrix, divide, divide_by,
                           divide_rows, dot, fill, fill_matrix, lincomb, matmul, matvec, scale,
                           scaled_into, times)
from ..core.codes import (CORRECTION_NOT_FINITE, DERIVATIVE_NOT_FINITE, DERIVATIVE_SHAPE,
                          END_NOT_FINITE, FORCE_NOT_FINITE, FORCE_SHAPE, LOAD_NOT_FINITE,
                          LOAD_RATE_NOT_FINITE, LOAD_RATE_SHAPE, LOAD_SHAPE, NO_CONVERGENCE,
                          OK, RESIDUAL_NOT_FINITE, STEP_MATRIX_SINGULAR, STIFFNESS_NOT_FINITE,
                          STIFFNESS_SHAPE, TANGENT_SINGULAR)
from ..core.jit import jitable
from ..linsolve.dense import gesv, getrf, getrs, getrs_columns, solve
from ..linsolve.sparse import (general_affine_tangent, general_hfdi_setup, general_hfdi_tangent,
                               general_mass_solve, general_solve, general_velocity)

__all__ = ["CONSTANT_MEMORY", "HFDI_STAGES", "AFFINE_STAGES", "convergence_test", "newton", "force_into", "stiffness_of",
           "derivative_of", "load_into", "one_sided", "mass_solve", "affine_setup",
           "affine_end", "hfdi_setup", "hfdi_end", "b_solve"]

#: Memory of the corrector's carried quadratic constant (docs/algorithm.md,
#: "Corrector"): a measurement replaces the constant when larger, else the
#: constant shrinks by this factor; a run of one correction divides the guard
#: by it.
CONSTANT_MEMORY = 0.9
#: The kind of a scheme's stages as the stepping code's argument ``hfdi``
#: takes it: HFDI's (True) or affine (None). Compiled code then holds the
#: code of one kind only: numba removes the branch of an ``is None`` test on
#: a constant argument, where a test of its truth would compile both.
HFDI_STAGES, AFFINE_STAGES = True, None
_EPS = float(np.finfo(float).eps)


# -- the model's values -------------------------------------------------------------

@jitable(inline=True)
def _vector_fault(run, x, n, shape_code, finite_code):
    if x.shape[0] != n:
        run.bad_rows = x.shape[0]
        run.bad_columns = -1
        return shape_code
    return OK if all_finite(x) else finite_code


@jitable(inline=True)
def _matrix_fault(run, X, n, shape_code, finite_code):
    if X.shape[0] != n or X.shape[1] != n:
        run.bad_rows = X.shape[0]
        run.bad_columns = X.shape[1]
        return shape_code
    return OK if all_finite_matrix(X) else finite_code


@jitable
def force_into(fn, cfg, data, run, u, out):
    """``out = f(u)``: an outcome code."""
    run.nfev += 1
    f = fn.force(u, data.params)
    outcome = _vector_fault(run, f, cfg.n, FORCE_SHAPE, FORCE_NOT_FINITE)
    if outcome != FORCE_SHAPE:
        copy(out, f)
    return outcome


@jitable
def stiffness_of(fn, cfg, data, run, u):
    """``(outcome, K(u))``."""
    run.njev += 1
    K = fn.stiffness(u, data.params)
    return _matrix_fault(run, K, cfg.n, STIFFNESS_SHAPE, STIFFNESS_NOT_FINITE), K


@jitable
def derivative_of(fn, cfg, data, run, u, w):
    """``(outcome, T(u)[w])``."""
    run.ntev += 1
    T = fn.stiffness_derivative(u, w, data.params)
    return _matrix_fault(run, T, cfg.n, DERIVATIVE_SHAPE, DERIVATIVE_NOT_FINITE), T


@jitable(inline=True)
def one_sided(t, t_end, left):
    """``t``, or one rounding unit before it when a step ending there lands on a
    load breakpoint (``left``): the load's left limit (loads are written
    piecewise, ``t < t1``; docs/algorithm.md, "Load breakpoints")."""
    if left and t == t_end:
        return float(np.nextafter(t, -np.inf))
    return t


@jitable
def load_into(fn, cfg, data, run, t, out):
    """``out = p(t)`` (plus the held load): an outcome code."""
    p = fn.load(t, data.load_params)
    outcome = _vector_fault(run, p, cfg.n, LOAD_SHAPE, LOAD_NOT_FINITE)
    if outcome == LOAD_SHAPE:
        return outcome
    copy(out, p)
    if cfg.has_held:
        axpy(out, 1.0, data.held)
    return outcome if outcome != OK else (OK if all_finite(out) else LOAD_NOT_FINITE)


@jitable
def mass_solve(cfg, data, vec, x):
    """``x ← M⁻¹ x``; false when that fails (``x`` not finite after it)."""
    if cfg.sparse:
        general_mass_solve(vec, data, cfg, x)
    elif cfg.m_kind == DIAGONAL:
        divide(x, data.Md)
    else:
        # a workspace of its own: VECTORS.lu keeps the Newton tangent's factors
        return gesv(data.Mf, x, vec.mass_lu, vec.mass_pivots, vec.ints)
    return True


# -- the corrector ---------------------------------------------------------------------

@jitable
def convergence_test(step, du2, previous, scale_, tol, constant, guard, estimated):
    """The corrector's test after one correction: ``(done, error, constant, guard)``.

    ``step = ‖Δu‖``, ``du2 = ‖Δu‖²``, ``previous`` the correction before (``inf``
    after the first), ``scale_ = max(‖u‖, floor)``. Done when Eq. 38 passes,
    ``‖Δu‖ ≤ tol · scale_``, or, with ``estimated``, when the estimated error
    left is within the same bound: after a later correction ``ρ/(1 − ρ) ‖Δu‖``
    with the observed rate ``ρ`` (SUNDIALS' test), after the first ``G ‖Δu‖²``
    with the carried guard ``G`` of the quadratic constant (docs/algorithm.md,
    "Corrector"). Every later correction measures the constant
    ``max(‖Δu_k‖, ε scale_)/‖Δu_{k−1}‖²``. ``error`` is the estimate of the
    remaining error (``inf`` when not done).
    """
    bound = tol * scale_
    # a correction larger than the bound is > 0, so previous > 0 here
    if previous < math.inf:
        measured = max(step, _EPS * scale_) / (previous * previous)
        constant = measured if constant == math.inf else max(measured,
                                                             CONSTANT_MEMORY * constant)
        guard = constant
        rate = step / previous
        error = step * rate / (1.0 - rate) if rate < 1.0 else step
        estimate_passes = estimated and rate < 1.0 and error <= bound
    else:
        # Eq. 38's own estimate when it passes, else the carried constant's
        error = du2 / scale_
        estimate_passes = estimated and step > bound and guard * du2 <= bound
        if estimate_passes:
            error = constant * du2
    if step <= bound or estimate_passes:
        if previous == math.inf:
            guard = guard / CONSTANT_MEMORY
        return True, error, constant, guard
    return False, math.inf, constant, guard


@jitable
def newton(fn, cfg, data, run, vec, st, h, constant, guard, hfdi):
    """Newton on the stage ``st`` (HFDI's when ``hfdi``) from the guess in
    ``VECTORS.trial``, corrected in place: ``(outcome, corrections, error,
    constant, guard)``, corrections ``−1`` when a model value failed (the
    stage's corrections then uncounted). The last tangent's factors stay in
    ``VECTORS.lu``: ``RUN.tangent_kind`` (:func:`hfdi.linsolve.dense.solve`'s
    kind; 0 where they are not kept: sparse, affine stages) and
    ``RUN.tangent_h`` say for which step (:mod:`hfdi.stepping.global_error`)."""
    u = vec.trial
    du = vec.du
    previous = math.inf
    run.tangent_kind = 0
    lincomb(vec.u_iterate, 1.0, vec.u, 1.0, u)
    for k in range(1, cfg.max_iterations + 1):
        if hfdi is not None:
            outcome, J = _hfdi_residual(fn, cfg, data, run, vec, u, h)
        else:
            outcome, J = _affine_residual(fn, cfg, data, run, vec, u, st)
        if outcome != OK:
            return outcome, -1, math.inf, constant, guard
        if not all_finite(vec.residual):
            return RESIDUAL_NOT_FINITE, k - 1, math.inf, constant, guard
        run.nlu += 1
        scale(du, -1.0, vec.residual)
        if cfg.sparse:
            solved = general_solve(vec, J, du)
        else:
            solved = solve(J, du, vec.lu, vec.pivots, vec.ints)
            if hfdi is not None:
                run.tangent_kind = solved
                run.tangent_h = h
        if not solved:
            return TANGENT_SINGULAR, k - 1, math.inf, constant, guard
        # ‖Δu‖² as np.linalg.norm forms it; NaN or infinity in Δu makes it
        # non-finite (an overflow too, hence the entry-wise test only then)
        du2 = dot(du, du)
        if not math.isfinite(du2) and not all_finite(du):
            return CORRECTION_NOT_FINITE, k, math.inf, constant, guard
        axpy(u, 1.0, du)
        # the unknown is the increment u − u_n: the test's scale is ‖u‖
        lincomb(vec.u_iterate, 1.0, vec.u, 1.0, u)
        size = math.sqrt(dot(vec.u_iterate, vec.u_iterate))
        step = math.sqrt(du2)
        done, error, constant, guard = convergence_test(
            step, du2, previous, max(size, cfg.floor), cfg.tol, constant, guard, cfg.estimated)
        if done:
            return OK, k, error, constant, guard
        previous = step
    return NO_CONVERGENCE, cfg.max_iterations, math.inf, constant, guard


# -- affine stages -------------------------------------------------------------------

@jitable
def _combine_sources(out, vec, cv, ca, cu1, cv1, ca1):
    """``out = cu1 (u_1 − u_n) + cv v + ca a + cv1 v_1 + ca1 a_1`` over the
    step's start and the first stage's end, terms with a zero coefficient
    skipped: ``a`` or ``v`` of the stage without its term in the increment
    ``u − u_n`` (the ``u_n`` terms add up to zero, :class:`Stage`)."""
    scale(out, cv, vec.v)
    if ca != 0.0:
        axpy(out, ca, vec.a_start)
    if cu1 != 0.0:
        lincomb(vec.tmp, 1.0, vec.u_mid, -1.0, vec.u)
        axpy(out, cu1, vec.tmp)
    if cv1 != 0.0:
        axpy(out, cv1, vec.v_mid)
    if ca1 != 0.0:
        axpy(out, ca1, vec.a_mid)


@jitable
def affine_setup(fn, cfg, data, run, vec, st):
    """What an affine stage keeps over its iterations: ``a0``, ``v0`` (``a`` and
    ``v`` at a zero increment), the right-hand side ``p − m_new M a0 − m_old M a_n − f_new C v0 − f_old (C v_n
    + f_n)`` and the diagonal part of the tangent ``m_new ca M + f_new cv C``
    (``VECTORS.shift``). An outcome code (``f_n`` may be evaluated)."""
    _combine_sources(vec.a0, vec, st.a_v, st.a_a, st.a_u1, st.a_v1, st.a_a1)
    _combine_sources(vec.v0, vec, st.v_v, st.v_a, st.v_u1, st.v_v1, st.v_a1)
    work, rhs = vec.work, vec.rhs
    times(cfg.m_kind, data.Md, data.Mf, vec.a0, work)
    lincomb(rhs, 1.0, vec.p_stage, -st.m_new, work)
    if st.m_old != 0.0:
        times(cfg.m_kind, data.Md, data.Mf, vec.a_start, work)
        axpy(rhs, -st.m_old, work)
    if cfg.c_kind != NONE:
        times(cfg.c_kind, data.Cd, data.Cf, vec.v0, work)
        axpy(rhs, -st.f_new, work)
    if st.f_old != 0.0:
        if cfg.c_kind != NONE:
            times(cfg.c_kind, data.Cd, data.Cf, vec.v, work)
            axpy(rhs, -st.f_old, work)
        if run.has_force:
            axpy(rhs, -st.f_old, vec.f)
        else:
            outcome = force_into(fn, cfg, data, run, vec.u, vec.tmp)
            if outcome != OK:
                return outcome
            axpy(rhs, -st.f_old, vec.tmp)
    shift = vec.shift
    fill(shift, 0.0)
    if cfg.m_kind == DIAGONAL:
        scale(shift, st.m_new * st.ca, data.Md)
    if cfg.c_kind == DIAGONAL:
        axpy(shift, st.f_new * st.cv, data.Cd)
    return OK


@jitable
def _affine_residual(fn, cfg, data, run, vec, u, st):
    """The residual ``m_new ca M d + f_new (cv C d + f(u_n + d)) − rhs`` of the
    increment ``d`` (``u``) into ``VECTORS.residual`` and the tangent
    ``m_new ca M + f_new cv C + f_new K``: ``(outcome, tangent)``."""
    cM, cC, cK = st.m_new * st.ca, st.f_new * st.cv, st.f_new
    f, work, r = vec.g, vec.work, vec.residual
    outcome = force_into(fn, cfg, data, run, vec.u_iterate, f)
    if outcome != OK:
        return outcome, vec.J
    times(cfg.m_kind, data.Md, data.Mf, u, work)
    lincomb(r, cM, work, cK, f)
    axpy(r, -1.0, vec.rhs)
    if cfg.c_kind != NONE:
        times(cfg.c_kind, data.Cd, data.Cf, u, work)
        axpy(r, cC, work)
    outcome, K = stiffness_of(fn, cfg, data, run, vec.u_iterate)
    if outcome != OK:
        return outcome, vec.J
    if cfg.sparse:
        return OK, general_affine_tangent(vec, data, cfg, K, cM, cC, cK)
    J = vec.J
    scaled_into(J, cK, K)
    if cfg.m_kind == DENSE:
        add_scaled(J, cM, data.Mf)
    if cfg.c_kind == DENSE:
        add_scaled(J, cC, data.Cf)
    if cfg.m_kind == DIAGONAL or cfg.c_kind == DIAGONAL:
        add_diagonal(J, 1.0, vec.shift)
    return OK, J


@jitable
def affine_end(fn, cfg, data, run, vec, st, u, v, a):
    """The stage's end state from the converged increment ``d`` in
    ``VECTORS.trial``: ``u_n + d``, ``v = cv d + v0``, ``a = ca d + a0`` into
    ``u``, ``v``, ``a``."""
    d = vec.trial
    lincomb(u, 1.0, vec.u, 1.0, d)
    lincomb(v, st.cv, d, 1.0, vec.v0)
    lincomb(a, st.ca, d, 1.0, vec.a0)
    return OK if all_finite(u) and all_finite(v) and all_finite(a) else END_NOT_FINITE


# -- HFDI ----------------------------------------------------------------------------

@jitable
def hfdi_setup(fn, cfg, data, run, vec, h, t_end, left):
    """What the HFDI stage keeps over its iterations (Eqs. 19–21, multiplied
    through by ``M``): ``B = 2h/3 M + h²/6 C`` (diagonal in
    ``VECTORS.b_diagonal``, or factorised), ``q0 = −M (u_n + h/3 v_n)``,
    ``F0 = −M v_n − C u_n − h/3 g_n`` and ``p'(t_{n+1})`` (the model's, the
    derived one of :func:`_derived_load_rate`, or the paper's
    ``(p_{n+1} − p_n)/h``). An outcome code."""
    c, c2 = h * h / 6.0, 2.0 * h / 3.0
    g_n, f_n, work = vec.rhs, vec.tmp, vec.work
    if run.has_force:
        copy(f_n, vec.f)
    else:
        outcome = force_into(fn, cfg, data, run, vec.u, f_n)
        if outcome != OK:
            return outcome
    lincomb(g_n, 1.0, vec.p, -1.0, f_n)
    t_rate = one_sided(t_end, t_end, left)
    s1, s2 = t_rate - RATE_SPACING * h, t_rate - 2.0 * RATE_SPACING * h
    if cfg.exact_rate:
        rate = fn.load_rate(t_rate, data.load_params)
        outcome = _vector_fault(run, rate, cfg.n, LOAD_RATE_SHAPE, LOAD_RATE_NOT_FINITE)
        if outcome != OK:
            return outcome
        copy(vec.p_rate, rate)
    elif cfg.derived_rate and t_rate > s1 > s2:
        outcome = _derived_load_rate(fn, cfg, data, run, vec, t_rate, s1, s2)
        if outcome != OK:
            return outcome
    else:
        lincomb(vec.p_rate, 1.0, vec.p_stage, -1.0, vec.p)
        divide_by(vec.p_rate, h)
    if cfg.sparse:
        kind = general_hfdi_setup(vec, data, cfg, c, c2)
        if kind == 0:
            return STEP_MATRIX_SINGULAR
        if kind == 2:
            run.nlu += 1
    elif cfg.m_kind == DENSE or cfg.c_kind == DENSE:
        B = vec.B
        fill_matrix(B, 0.0)
        _add_matrix(B, c2, cfg.m_kind, data.Md, data.Mf)
        _add_matrix(B, c, cfg.c_kind, data.Cd, data.Cf)
        run.nlu += 1
        if not getrf(B, vec.B_lu, vec.b_pivots, vec.b_ints):
            return STEP_MATRIX_SINGULAR
    else:
        b = vec.b_diagonal
        scale(b, c2, data.Md)
        if cfg.c_kind == DIAGONAL:
            axpy(b, c, data.Cd)
        for i in range(b.shape[0]):
            if not (b[i] != 0.0 and math.isfinite(b[i])):
                return STEP_MATRIX_SINGULAR
    # The stage iterates on the increment d = u − u_n (docs/algorithm.md):
    # q0 = −h/3 M v_n; F0 = −M v_n − h/3 g_n
    times(cfg.m_kind, data.Md, data.Mf, vec.v, vec.f0)
    scale(vec.q0, -(h / 3.0), vec.f0)
    scale(vec.f0, -1.0, vec.f0)
    axpy(vec.f0, -(h / 3.0), g_n)
    return OK


#: The spacing of HFDI's derived load rate, as a share of the step: its
#: truncation error, δ² p‴/3, is 1/300 of h² p‴ (docs/algorithm.md, "Load rate")
RATE_SPACING = 0.1


@jitable
def _derived_load_rate(fn, cfg, data, run, vec, t, s1, s2):
    """``VECTORS.p_rate = p'(t)``, the slope at ``t`` of the quadratic through
    the load at ``t`` (``VECTORS.p_stage``), ``s1`` and ``s2`` (``t − δ`` and
    ``t − 2δ``, ``δ = RATE_SPACING·h``, both inside the step, where the load
    is smooth: the steps land on its breakpoints). Its error is ``O(h²)``
    where the paper's ``(p_{n+1} − p_n)/h`` has ``O(h)``: HFDI stays third
    order under any smooth load. An outcome code."""
    outcome = load_into(fn, cfg, data, run, s2, vec.work)
    if outcome != OK:
        return outcome
    outcome = load_into(fn, cfg, data, run, s1, vec.p_rate)
    if outcome != OK:
        return outcome
    d1, d2 = t - s1, t - s2
    w = d2 - d1
    lincomb(vec.p_rate, -d2 / (d1 * w), vec.p_rate, d1 / (d2 * w), vec.work)
    axpy(vec.p_rate, 1.0 / d1 + 1.0 / d2, vec.p_stage)
    return OK


@jitable
def _add_matrix(out, c, kind, diagonal, full):
    if kind == DENSE:
        add_scaled(out, c, full)
    elif kind == DIAGONAL:
        add_diagonal(out, c, diagonal)


@jitable
def b_solve(cfg, vec, x):
    """``x ← B⁻¹ x``, ``B = 2h/3 M + h²/6 C`` of :func:`hfdi_setup`."""
    if cfg.sparse:
        general_velocity(vec, x)
    elif cfg.m_kind == DENSE or cfg.c_kind == DENSE:
        getrs(vec.B_lu, vec.b_pivots, vec.b_ints, x)
    else:
        divide(x, vec.b_diagonal)


@jitable
def _velocity(cfg, data, vec, u, g, h, out):
    """``out = v_D`` of Eq. 19 from the increment ``u = u_{n+1} − u_n``:
    ``B v_D = M u + q0 + h²/6 g``."""
    times(cfg.m_kind, data.Md, data.Mf, u, out)
    axpy(out, 1.0, vec.q0)
    axpy(out, h * h / 6.0, g)
    b_solve(cfg, vec, out)


@jitable
def _hfdi_residual(fn, cfg, data, run, vec, u, h):
    """``F(u) = M v_D + C u − 2h/3 g + h²/6 (p' − K v_D) + F0`` (Eq. 21) into
    ``VECTORS.residual`` and its exact tangent ``S B⁻¹ S + C + 2h/3 K −
    h²/6 T(u)[v_D]``, ``S = M − h²/6 K``: ``(outcome, tangent)``."""
    c, c2 = h * h / 6.0, 2.0 * h / 3.0
    f, g, vd, kv, work, r, gt = vec.tmp, vec.g, vec.vd, vec.kv, vec.work, vec.residual, vec.du
    ua = vec.u_iterate
    outcome = force_into(fn, cfg, data, run, ua, f)
    if outcome != OK:
        return outcome, vec.J
    lincomb(g, 1.0, vec.p_stage, -1.0, f)
    outcome, K = stiffness_of(fn, cfg, data, run, ua)
    if outcome != OK:
        return outcome, vec.J
    _velocity(cfg, data, vec, u, g, h, vd)
    matvec(K, vd, kv)
    lincomb(gt, 1.0, vec.p_rate, -1.0, kv)
    times(cfg.m_kind, data.Md, data.Mf, vd, work)
    lincomb(r, 1.0, work, -c2, g)
    axpy(r, c, gt)
    axpy(r, 1.0, vec.f0)
    if cfg.c_kind != NONE:
        times(cfg.c_kind, data.Cd, data.Cf, u, work)
        axpy(r, 1.0, work)
    outcome, T = derivative_of(fn, cfg, data, run, ua, vd)
    if outcome != OK:
        return outcome, vec.J
    if cfg.sparse:
        return OK, general_hfdi_tangent(vec, data, cfg, K, T, c, c2)
    if cfg.global_error:
        # the step's own derivative carries the global error estimate
        copy_matrix(vec.K_last, K)
        copy_matrix(vec.T_last, T)
    S, SB, J = vec.S, vec.SB, vec.J
    scaled_into(S, -c, K)
    _add_matrix(S, 1.0, cfg.m_kind, data.Md, data.Mf)
    scaled_into(J, c2, K)
    add_scaled(J, -c, T)
    _add_matrix(J, 1.0, cfg.c_kind, data.Cd, data.Cf)
    if cfg.m_kind == DENSE or cfg.c_kind == DENSE:
        copy_matrix(SB, S)
        getrs_columns(vec.B_lu, vec.b_pivots, vec.b_ints, SB, vec.columns)
    else:
        divide_rows(SB, S, vec.b_diagonal)
    matmul(S, SB, vec.product)
    add_scaled(J, 1.0, vec.product)
    return OK, J


@jitable
def hfdi_end(fn, cfg, data, run, vec, h):
    """The end state from the converged ``VECTORS.trial``: ``u``, ``f(u)``,
    ``v = v_D(u)`` and ``a = M⁻¹(p − f − C v)`` (Eq. 14) into ``VECTORS.*_new``."""
    u = vec.u_new
    lincomb(u, 1.0, vec.u, 1.0, vec.trial)
    outcome = force_into(fn, cfg, data, run, u, vec.f_new)
    if outcome != OK:
        return outcome
    lincomb(vec.g, 1.0, vec.p_stage, -1.0, vec.f_new)
    _velocity(cfg, data, vec, vec.trial, vec.g, h, vec.v_new)
    a = vec.a_new
    times(cfg.c_kind, data.Cd, data.Cf, vec.v_new, vec.work)
    lincomb(a, 1.0, vec.p_stage, -1.0, vec.f_new)
    axpy(a, -1.0, vec.work)
    mass_solve(cfg, data, vec, a)
    return OK if all_finite(u) and all_finite(vec.v_new) and all_finite(a) else END_NOT_FINITE
