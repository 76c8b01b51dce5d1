"""One attempt of a step, compiled: predictor, every stage of the scheme and the
Newton corrector of :func:`hfdi.corrector.solve_step`, for dense systems.

Two drivers call it: the compiled driver (:mod:`hfdi.compiled.driver`), for
whole runs of ordinary steps, and the Python driver (:class:`hfdi.Integrator`),
which calls :meth:`CompiledStep.solve_step` where it would call
:func:`hfdi.corrector.solve_step`, with the same arguments and the same
:class:`~hfdi.corrector.StepOutcome` back. Loads are not evaluated here: the
load at the stage times (and HFDI's load rate) are evaluated before the
attempt and handed in, from Python (so that breakpoints and one-sided limits
work as on the Python path) or from the compiled load.

The compiled function restates, operation for operation, the Python code it
replaces: :func:`hfdi.corrector.predict` and :func:`hfdi.corrector.newton`,
``_InertiaStage`` (Newmark, Eqs. 3–5, and both Bathe sub-steps, Eqs. 6–10) and
``_HFDIStage`` (Eqs. 15–21, Table 1) of :mod:`hfdi.schemes`, with the same
iteration counting, ``N_max``, error estimate and evaluation counters; the
convergence test (Eq. 38, or the estimated remaining error) is the Python
path's own :func:`hfdi.corrector.convergence_test`, compiled. Products with
dense matrices and the solves call the Python path's BLAS and LAPACK
routines (:mod:`hfdi.compiled.lapack`); sums of a few terms written out here
may round differently from numpy's, so states
agree to rounding, not always bit for bit; ``tests/test_compiled_step.py``
asserts equal step and Newton counts and states within 1e-12 on every paper
model, scheme and mode.
"""
from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit, types
from numba.experimental import structref

from ..corrector import NO_MEASUREMENT, StepOutcome, convergence_test
from ..evaluation import ModelError, NonFiniteError, State
from ..schemes import HFDI, Bathe, Newmark
from .lapack import all_finite as _all_finite
from .lapack import INTS, gesv, getrf, getrs, getrs_columns, solve, work_arrays
from .loads import hat_load
from .signatures import (FORCE_TYPE, INDEX_VECTOR, INT32_MATRIX, JIT_OPTIONS, KERNEL_SET,
                         LOAD_TYPE, MATRIX, POTENTIAL_ENERGY_TYPE, STIFFNESS_DERIVATIVE_TYPE,
                         STIFFNESS_TYPE, TENSOR, VECTOR)

__all__ = ["CompiledStep", "attempt", "attempt_with", "kernel_set", "workspace"]

# -- codes shared with the Python side -------------------------------------------
# status of an attempt
OK = 0
RESIDUAL_NOT_FINITE = 1
TANGENT_SINGULAR = 2
CORRECTION_NOT_FINITE = 3
NO_CONVERGENCE = 4
END_NOT_FINITE = 5
FORCE_NOT_FINITE = 6
STIFFNESS_NOT_FINITE = 7
DERIVATIVE_NOT_FINITE = 8
STEP_MATRIX_SINGULAR = 9
# a kernel's value of another shape than (N,) or (N, N): the Python side
# raises ModelError, as the Evaluator does for the model's methods (numba
# checks no bounds: the attempt must not read past such a value)
FORCE_SHAPE = 10
STIFFNESS_SHAPE = 11
DERIVATIVE_SHAPE = 12
# schemes
NEWMARK, BATHE, HFDI_SCHEME = 0, 1, 2
# entries of ``config`` (int64)
SCHEME, HAS_PREVIOUS, HAS_START_FORCE, MAX_ITERATIONS, MASS_KIND, DAMPING_KIND, \
    NEWTON_TEST = range(7)
# entries of ``coefficients`` (float64)
GAMMA, BETA, T_START, T_PREVIOUS, T_END, TOL, FLOOR, NEWTON_CONSTANT, NEWTON_GUARD = range(9)
# entries of the returned ``info`` (int64)
ITERATIONS_0, ITERATIONS_1, STAGES_COUNTED, NFEV, NJEV, NTEV, NLU, FAILED_STAGE, BAD_ROWS, \
    BAD_COLUMNS = range(10)
INFO_SIZE = 10
# rows of the returned ``out``: the end state, then Bathe's mid-step state
END_U, END_V, END_A, END_F, MID_U, MID_V, MID_A = range(7)
# kinds of M and C
NONE, DIAGONAL, DENSE = 0, 1, 2
# rows of the work space's vectors and matrices (:func:`workspace`)
W_U, W_U2, W_BDIAG, W_Q0, W_F0, W_GN, W_G, W_VD, W_WORK, W_RES, W_DU, W_KV, W_TMP, W_RHS, \
    W_SHIFT, W_A0, W_V0 = range(17)
X_S, X_SB, X_TANGENT, X_LU, X_B, X_B_LU, X_WORK, X_PROD = range(8)
_WORK_VECTORS, _WORK_MATRICES = 17, 8

# the Python path's test itself, compiled (hfdi.compiled.cache watches its source too)
_convergence_test = njit(**JIT_OPTIONS)(convergence_test)


# -- the kernels' values ------------------------------------------------------------

@njit(inline="always", **JIT_OPTIONS)
def _vector_fault(x, n, shape_status, finite_status, info):
    """``OK``, or the status of a kernel's vector that is not (N,) (its length
    into ``info[BAD_ROWS]``) or not finite."""
    if x.shape[0] != n:
        info[BAD_ROWS], info[BAD_COLUMNS] = x.shape[0], -1
        return shape_status
    return OK if _all_finite(x) else finite_status


@njit(inline="always", **JIT_OPTIONS)
def _matrix_fault(X, n, shape_status, finite_status, info):
    """``OK``, or the status of a kernel's matrix that is not (N, N) (its shape
    into ``info``) or not finite."""
    if X.shape[0] != n or X.shape[1] != n:
        info[BAD_ROWS], info[BAD_COLUMNS] = X.shape[0], X.shape[1]
        return shape_status
    return OK if _all_finite(X) else finite_status


# -- small dense linear algebra ----------------------------------------------------

@njit(inline="always", **JIT_OPTIONS)
def _times_into(diagonal, full, kind, x, out):
    """``out = A x`` for ``A`` of the given kind (zero for NONE). Inlined (here and
    below): a call with array arguments costs their reference counting, more
    than a diagonal product of a small system."""
    if kind == DIAGONAL:
        for i in range(x.shape[0]):
            out[i] = diagonal[i] * x[i]
    elif kind == DENSE:
        _dense_times_into(full, x, out)
    else:
        for i in range(x.shape[0]):
            out[i] = 0.0


@njit(**JIT_OPTIONS)
def _dense_times_into(A, x, out):
    """``out = A x`` by BLAS (as the Python path's ``A @ x``), into ``out``."""
    np.dot(A, x, out)


@njit(**JIT_OPTIONS)
def _add_dense(out, c, full, kind):
    """``out += c A`` for a dense ``A`` (the dense terms of hfdi.linalg.combine)."""
    if kind == DENSE and c != 0.0:
        for i in range(out.shape[0]):
            for j in range(out.shape[1]):
                out[i, j] += c * full[i, j]


@njit(**JIT_OPTIONS)
def _add_diagonal(d, c, diagonal, kind):
    """``d += c diag(A)`` for a diagonal ``A`` (combine's diagonal terms)."""
    if kind == DIAGONAL and c != 0.0:
        for i in range(d.shape[0]):
            d[i] += c * diagonal[i]


@njit(**JIT_OPTIONS)
def workspace(n):
    """The work arrays of :func:`attempt`, made once by its caller:
    ``(vectors (17, N), matrices (8, N, N), pivots (2, N) int32, ints (2, INTS)
    int32)``, rows named ``W_*`` and ``X_*``; two sets of LAPACK's pivots and
    integers (:func:`~hfdi.compiled.lapack.work_arrays`), the tangent's and
    HFDI's ``B``'s. An allocation costs about 50 ns, and an attempt made
    some forty of them. Every entry is written before it is read: empty, not
    zeroed (a megabyte at N = 127, and the driver makes them at every call)."""
    ints = np.empty((2, INTS), np.int32)
    for k in range(2):
        ints[k] = work_arrays(0)[2]
    return (np.empty((_WORK_VECTORS, n)), np.empty((_WORK_MATRICES, n, n)),
            np.empty((2, n), np.int32), ints)


# -- predictor and corrector --------------------------------------------------------

@njit(**JIT_OPTIONS)
def _predict(u, v, a, has_previous, H, u_previous, v_previous, s, out):
    """:func:`hfdi.corrector.predict` (Eqs. 36–37) into ``out``, which it
    returns: linear without history, else the quartic through the two last
    states."""
    n = u.shape[0]
    if not has_previous:
        for i in range(n):
            out[i] = u[i] + s * v[i]
        return out
    sigma = s / H
    s3 = math.pow(sigma, 3.0)
    s4 = math.pow(sigma, 4.0)
    for i in range(n):
        r1 = u_previous[i] - u[i] + H * v[i] - (0.5 * H * H) * a[i]
        r2 = v_previous[i] - v[i] + H * a[i]
        out[i] = (u[i] + s * v[i] + (0.5 * s * s) * a[i] - (4.0 * s3 + 3.0 * s4) * r1
                  - (H * (s3 + s4)) * r2)
    return out


@njit(**JIT_OPTIONS)
def _newton_update(u, tangent, residual, tol, floor, previous, constant, guard, estimated,
                   counters, du, lu, pivots, ints):
    """One correction ``Δu = −tangent⁻¹ residual`` added to ``u`` in place, and
    the convergence test of :func:`hfdi.corrector.newton`
    (:func:`hfdi.corrector.convergence_test`: Eq. 38, or with ``estimated``
    the estimated remaining error too): ``(status, done, error,
    |Δu|, constant, guard)`` with ``done`` true when converged and the
    carried quadratic constant and its guard. ``du`` and LAPACK's ``lu``,
    ``pivots`` and ``ints`` are work arrays."""
    counters[NLU] += 1
    for i in range(du.shape[0]):
        du[i] = -residual[i]
    if not solve(tangent, du, lu, pivots, ints):
        return TANGENT_SINGULAR, False, math.inf, previous, constant, guard
    du2 = np.dot(du, du)
    if not math.isfinite(du2) and not _all_finite(du):
        return CORRECTION_NOT_FINITE, False, math.inf, previous, constant, guard
    u += du
    size = math.sqrt(np.dot(u, u))
    step = math.sqrt(du2)
    done, error, constant, guard = _convergence_test(step, du2, previous, max(size, floor), tol,
                                                     constant, guard, estimated)
    return OK, done, error, step, constant, guard


@njit(**JIT_OPTIONS)
def _inertia_stage(force, stiffness, params, Md, Mf, m_kind, Cd, Cf, c_kind, ca, cv, a0, v0,
                   p, u, tol, floor, max_iterations, constant, guard, estimated, counters,
                   vectors, matrices, all_pivots, all_ints):
    """Newton on ``ca M u + cv C u + f(u) = p − M a0 − C v0`` (``_InertiaStage``)
    from the guess ``u``, corrected in place: ``(status, k, error, constant, guard)``,
    ``k = −1`` when a model value failed (the stage's corrections are then not
    counted, as on the Python path). The rest of the arguments: :func:`workspace`."""
    n = u.shape[0]
    rhs, work, residual, du = vectors[W_RHS], vectors[W_WORK], vectors[W_RES], vectors[W_DU]
    _times_into(Md, Mf, m_kind, a0, work)
    for i in range(n):
        rhs[i] = p[i] - work[i]
    if c_kind != NONE:
        _times_into(Cd, Cf, c_kind, v0, work)
        for i in range(n):
            rhs[i] = rhs[i] - work[i]
    shift = vectors[W_SHIFT]
    for i in range(n):
        shift[i] = 0.0
    _add_diagonal(shift, ca, Md, m_kind)
    _add_diagonal(shift, cv, Cd, c_kind)
    dense_mass = m_kind == DENSE and ca != 0.0
    dense_damping = c_kind == DENSE and cv != 0.0
    tangent, lu = matrices[X_TANGENT], matrices[X_LU]
    pivots, ints = all_pivots[0], all_ints[0]
    previous = math.inf
    for k in range(1, max_iterations + 1):
        counters[NFEV] += 1
        f = force(u, params)
        status = _vector_fault(f, n, FORCE_SHAPE, FORCE_NOT_FINITE, counters)
        if status != OK:
            return status, -1, math.inf, constant, guard
        _times_into(Md, Mf, m_kind, u, work)
        for i in range(n):
            residual[i] = ca * work[i] + f[i] - rhs[i]
        if c_kind != NONE:
            _times_into(Cd, Cf, c_kind, u, work)
            for i in range(n):
                residual[i] += cv * work[i]
        counters[NJEV] += 1
        K = stiffness(u, params)
        status = _matrix_fault(K, n, STIFFNESS_SHAPE, STIFFNESS_NOT_FINITE, counters)
        if status != OK:
            return status, -1, math.inf, constant, guard
        # ca M + cv C + K, summed as hfdi.linalg.combine sums them
        for i in range(n):
            for j in range(n):
                entry = 0.0
                if dense_mass:
                    entry += ca * Mf[i, j]
                if dense_damping:
                    entry += cv * Cf[i, j]
                tangent[i, j] = entry + K[i, j]
            tangent[i, i] += shift[i]
        if not _all_finite(residual):
            return RESIDUAL_NOT_FINITE, k - 1, math.inf, constant, guard
        status, done, error, previous, constant, guard = _newton_update(
            u, tangent, residual, tol, floor, previous, constant, guard, estimated, counters, du,
            lu, pivots, ints)
        if status == TANGENT_SINGULAR:
            return status, k - 1, math.inf, constant, guard
        if status != OK:
            return status, k, math.inf, constant, guard
        if done:
            return OK, k, error, constant, guard
    return NO_CONVERGENCE, max_iterations, math.inf, constant, guard


@njit(**JIT_OPTIONS)
def _newmark_coefficients(u, v, a, h, gamma, beta, a0, v0):
    """``ca, cv, a0, v0`` of Newmark's relations (3)–(4) over ``h``, the
    vectors into ``a0`` and ``v0``."""
    ca = 1.0 / (beta * h * h)
    cv = gamma / (beta * h)
    bh = beta * h
    ka = 0.5 / beta - 1.0
    kv = 1.0 - gamma / beta
    kva = h * (1.0 - 0.5 * gamma / beta)
    for i in range(u.shape[0]):
        a0[i] = (-ca) * u[i] - v[i] / bh - ka * a[i]
        v0[i] = (-cv) * u[i] + kv * v[i] + kva * a[i]
    return ca, cv, a0, v0


@njit(**JIT_OPTIONS)
def _end_finite(out):
    return _all_finite(out[END_U]) and _all_finite(out[END_V]) and _all_finite(out[END_A])


@njit(**JIT_OPTIONS)
def _inertia_end(out, u, ca, cv, a0, v0):
    """The end state of an inertia stage, ``v = cv u + v0``, ``a = ca u + a0``,
    into ``out``: ``OK`` or ``END_NOT_FINITE``."""
    out[END_U] = u
    for i in range(u.shape[0]):
        out[END_V, i] = cv * u[i] + v0[i]
        out[END_A, i] = ca * u[i] + a0[i]
    return OK if _end_finite(out) else END_NOT_FINITE


@njit(inline="always", **JIT_OPTIONS)
def _hfdi_velocity_into(Md, Mf, m_kind, u, q0, c, g, b_diagonal, dense_b, B_lu, b_pivots,
                        b_ints, out):
    """``out = v_D(u)`` of Eq. 19: ``B v_D = M u + q0 + c g`` (``B`` diagonal
    unless ``dense_b``, then ``B_lu`` holds its factors)."""
    _times_into(Md, Mf, m_kind, u, out)
    for i in range(u.shape[0]):
        out[i] = out[i] + q0[i] + c * g[i]
    if not dense_b:
        for i in range(u.shape[0]):
            out[i] /= b_diagonal[i]
    else:
        getrs(B_lu, b_pivots, b_ints, out)


@njit(**JIT_OPTIONS)
def _hfdi_stage(force, stiffness, derivative, params, Md, Mf, m_kind, Cd, Cf, c_kind, u_n, v_n,
                f_n, p_n, p, pt, h, u, tol, floor, max_iterations, constant, guard, estimated,
                counters, out, vectors, matrices, all_pivots, all_ints):
    """Newton on the HFDI residual ``F(u)`` of Eq. 21 with its exact tangent
    ``S B⁻¹ S + C + 2h/3 K − h²/6 T(u)[v_D]`` (``_HFDIStage``) from the guess
    ``u``, corrected in place, then the end state into ``out``:
    ``(status, k, error, constant, guard)``. The last four: :func:`workspace`."""
    n = u.shape[0]
    c = h * h / 6.0
    c2 = 2.0 * h / 3.0
    g_n, tmp = vectors[W_GN], vectors[W_TMP]
    for i in range(n):
        g_n[i] = p_n[i] - f_n[i]
    # B = 2h/3 M + h²/6 C: diagonal, or dense and factorised once
    b_diagonal = vectors[W_BDIAG]
    for i in range(n):
        b_diagonal[i] = 0.0
    dense_b = m_kind == DENSE or c_kind == DENSE
    B_lu, b_pivots, b_ints = matrices[X_B_LU], all_pivots[1], all_ints[1]
    if dense_b:
        B = matrices[X_B]
        B[:, :] = 0.0
        _add_dense(B, c2, Mf, m_kind)
        _add_dense(B, c, Cf, c_kind)
        d = tmp
        for i in range(n):
            d[i] = 0.0
        _add_diagonal(d, c2, Md, m_kind)
        _add_diagonal(d, c, Cd, c_kind)
        for i in range(n):
            B[i, i] += d[i]
        counters[NLU] += 1
        if not getrf(B, B_lu, b_pivots, b_ints):
            return STEP_MATRIX_SINGULAR, 0, math.inf, constant, guard
    else:
        _add_diagonal(b_diagonal, c2, Md, m_kind)
        _add_diagonal(b_diagonal, c, Cd, c_kind)
        for i in range(n):
            if not (b_diagonal[i] != 0.0 and math.isfinite(b_diagonal[i])):
                return STEP_MATRIX_SINGULAR, 0, math.inf, constant, guard
    # q0 = −M (u_n + h/3 v_n), F0 = −M v_n − C u_n − h/3 g_n
    q0, F0 = vectors[W_Q0], vectors[W_F0]
    for i in range(n):
        tmp[i] = u_n[i] + (h / 3.0) * v_n[i]
    _times_into(Md, Mf, m_kind, tmp, q0)
    for i in range(n):
        q0[i] = -q0[i]
    _times_into(Md, Mf, m_kind, v_n, F0)
    _times_into(Cd, Cf, c_kind, u_n, tmp)
    for i in range(n):
        F0[i] = -F0[i] - tmp[i] - (h / 3.0) * g_n[i]
    dense_mass, dense_damping = m_kind == DENSE, c_kind == DENSE
    g, vD, work = vectors[W_G], vectors[W_VD], vectors[W_WORK]
    residual, du, Kv = vectors[W_RES], vectors[W_DU], vectors[W_KV]
    S, SB, tangent = matrices[X_S], matrices[X_SB], matrices[X_TANGENT]
    work_matrix, product, lu = matrices[X_WORK], matrices[X_PROD], matrices[X_LU]
    pivots, ints = all_pivots[0], all_ints[0]
    previous = math.inf
    converged = False
    k_done = max_iterations
    error = math.inf
    for k in range(1, max_iterations + 1):
        counters[NFEV] += 1
        f = force(u, params)
        status = _vector_fault(f, n, FORCE_SHAPE, FORCE_NOT_FINITE, counters)
        if status != OK:
            return status, -1, math.inf, constant, guard
        for i in range(n):
            g[i] = p[i] - f[i]
        counters[NJEV] += 1
        K = stiffness(u, params)
        status = _matrix_fault(K, n, STIFFNESS_SHAPE, STIFFNESS_NOT_FINITE, counters)
        if status != OK:
            return status, -1, math.inf, constant, guard
        _hfdi_velocity_into(Md, Mf, m_kind, u, q0, c, g, b_diagonal, dense_b, B_lu, b_pivots,
                            b_ints, vD)
        # residual = M v_D − c2 g + c (p' − K v_D) + F0 (+ C u)
        np.dot(K, vD, Kv)
        for i in range(n):
            residual[i] = c * (pt[i] - Kv[i])
        _times_into(Md, Mf, m_kind, vD, work)
        for i in range(n):
            residual[i] = work[i] - c2 * g[i] + residual[i] + F0[i]
        if c_kind != NONE:
            _times_into(Cd, Cf, c_kind, u, work)
            for i in range(n):
                residual[i] += work[i]
        counters[NTEV] += 1
        T = derivative(u, vD, params)
        status = _matrix_fault(T, n, DERIVATIVE_SHAPE, DERIVATIVE_NOT_FINITE, counters)
        if status != OK:
            return status, -1, math.inf, constant, guard
        # S = M − c K and R = C + c2 K − c T, summed as hfdi.linalg.combine sums them
        for i in range(n):
            for j in range(n):
                entry = Mf[i, j] if dense_mass else 0.0
                S[i, j] = entry + (-c) * K[i, j]
                entry = Cf[i, j] if dense_damping else 0.0
                tangent[i, j] = entry + c2 * K[i, j] + (-c) * T[i, j]
            if m_kind == DIAGONAL:
                S[i, i] += Md[i]
            if c_kind == DIAGONAL:
                tangent[i, i] += Cd[i]
        # + S B⁻¹ S
        if not dense_b:
            for i in range(n):
                for j in range(n):
                    SB[i, j] = S[i, j] / b_diagonal[i]
        else:
            SB[:, :] = S
            getrs_columns(B_lu, b_pivots, b_ints, SB, work_matrix)
        np.dot(S, SB, product)
        for i in range(n):
            for j in range(n):
                tangent[i, j] += product[i, j]
        if not _all_finite(residual):
            return RESIDUAL_NOT_FINITE, k - 1, math.inf, constant, guard
        status, done, error, previous, constant, guard = _newton_update(
            u, tangent, residual, tol, floor, previous, constant, guard, estimated, counters, du,
            lu, pivots, ints)
        if status == TANGENT_SINGULAR:
            return status, k - 1, math.inf, constant, guard
        if status != OK:
            return status, k, math.inf, constant, guard
        if done:
            k_done = k
            converged = True
            break
    if not converged:
        return NO_CONVERGENCE, max_iterations, math.inf, constant, guard
    # the end state: f, v_D and a = M⁻¹(p − f − C v) (Eq. 14)
    counters[NFEV] += 1
    f = force(u, params)
    status = _vector_fault(f, n, FORCE_SHAPE, FORCE_NOT_FINITE, counters)
    if status == FORCE_SHAPE:
        return status, k_done, error, constant, guard
    if status != OK:
        out[END_U] = u
        return status, k_done, error, constant, guard
    for i in range(n):
        g[i] = p[i] - f[i]
    v, a = out[END_V], out[END_A]
    _hfdi_velocity_into(Md, Mf, m_kind, u, q0, c, g, b_diagonal, dense_b, B_lu, b_pivots,
                        b_ints, v)
    # a = M⁻¹ (p − f − C v)
    _times_into(Cd, Cf, c_kind, v, work)
    for i in range(n):
        a[i] = p[i] - f[i] - work[i]
    if m_kind == DENSE:
        gesv(Mf, a, lu, pivots, ints)
    else:
        for i in range(n):
            a[i] = a[i] / Md[i]
    out[END_U] = u
    out[END_F] = f
    if not _end_finite(out):
        return END_NOT_FINITE, k_done, error, constant, guard
    return OK, k_done, error, constant, guard


_SIGNATURE = types.Tuple((types.int64, MATRIX, INDEX_VECTOR, types.float64))(
    FORCE_TYPE, STIFFNESS_TYPE, STIFFNESS_DERIVATIVE_TYPE, VECTOR,   # kernels, params
    INDEX_VECTOR, VECTOR,                                           # config, coefficients
    VECTOR, MATRIX, VECTOR, MATRIX,                                 # M (diag, dense), C
    MATRIX, MATRIX, MATRIX,                                         # start, previous, loads
    MATRIX, INDEX_VECTOR,                                           # out, info
    MATRIX, TENSOR, INT32_MATRIX, INT32_MATRIX)                     # workspace()


@njit(_SIGNATURE, **JIT_OPTIONS)
def attempt(force, stiffness, derivative, params, config, coefficients, Md, Mf, Cd, Cf,
            start, previous, loads, out, info, vectors, matrices, pivots, ints):
    """One attempt at the step ``t_start → t_end``, every stage, predictor then Newton.

    Parameters
    ----------
    force, stiffness, derivative : compiled kernels (see :mod:`hfdi.compiled.signatures`)
    params : ndarray (P,)
    config : ndarray (7,) int64
        Scheme (0 Newmark, 1 Bathe, 2 HFDI), history present, ``start`` has
        ``f``, ``N_max``, kind of ``M`` and of ``C`` (0 none, 1 diagonal, 2
        dense), and whether Newton stops on the estimated error too
        (``estimated`` of :func:`hfdi.corrector.newton`).
    coefficients : ndarray (9,)
        Scheme parameters ``γ``, ``β`` (Newmark; ``γ`` alone for Bathe),
        ``t_start``, ``t_previous``, ``t_end``, Newton tolerance ``η``, floor,
        and Newton's carried quadratic constant and its guard
        (:func:`hfdi.corrector.newton`), replaced by theirs after the attempt
        when it succeeds (status 0).
    Md, Mf, Cd, Cf : ndarray (N,) and (N, N)
        ``M`` and ``C`` as a diagonal or a dense array, whichever their kind says.
    start : ndarray (5, N)
        ``u, v, a, f, p`` at ``t_start``.
    previous : ndarray (2, N)
        ``u, v`` at ``t_previous`` (the predictor's history).
    loads : ndarray (3, N)
        ``p`` at Bathe's mid-step time, ``p(t_end)`` and HFDI's ``p'(t_end)``.
    out : ndarray (7, N)
    info : ndarray (INFO_SIZE,) int64
        Written over (see below) and returned.
    vectors, matrices, pivots, ints : the work arrays of :func:`workspace`

    Returns
    -------
    status : int
    out : ndarray (7, N)
        ``u, v, a, f`` at ``t_end`` and ``u, v, a`` at Bathe's mid-step.
    info : ndarray (INFO_SIZE,) int64
        Corrections per stage, stages counted, ``nfev``, ``njev``, ``ntev``,
        ``nlu``, the failed stage, and the shape of a kernel's value of a
        wrong shape (``FORCE_SHAPE`` …; columns −1 for a vector).
    newton_error : float
        The largest estimate over the stages of the corrector's remaining error.
    """
    n = start.shape[1]
    out[:, :] = 0.0
    info[:] = 0
    scheme = config[SCHEME]
    has_previous = config[HAS_PREVIOUS] != 0
    max_iterations = config[MAX_ITERATIONS]
    m_kind, c_kind = config[MASS_KIND], config[DAMPING_KIND]
    t0, t_end = coefficients[T_START], coefficients[T_END]
    tol, floor = coefficients[TOL], coefficients[FLOOR]
    constant, guard = coefficients[NEWTON_CONSTANT], coefficients[NEWTON_GUARD]
    estimated = config[NEWTON_TEST] != 0
    H = t0 - coefficients[T_PREVIOUS]
    u_n, v_n, a_n = start[0], start[1], start[2]
    h = t_end - t0
    newton_error = 0.0
    if scheme == HFDI_SCHEME:
        if config[HAS_START_FORCE] != 0:
            f_n = start[3]
        else:
            info[NFEV] += 1
            f_n = force(np.ascontiguousarray(u_n), params)
            status = _vector_fault(f_n, n, FORCE_SHAPE, FORCE_NOT_FINITE, info)
            if status != OK:
                return status, out, info, math.inf
        guess = _predict(u_n, v_n, a_n, has_previous, H, previous[0], previous[1], 1.0 * h,
                         vectors[W_U])
        status, k, error, constant, guard = _hfdi_stage(
            force, stiffness, derivative, params, Md, Mf, m_kind, Cd, Cf, c_kind, u_n, v_n, f_n,
            start[4], loads[1], loads[2], h, guess, tol, floor, max_iterations, constant, guard,
            estimated, info, out, vectors, matrices, pivots, ints)
        if k >= 0:
            info[ITERATIONS_0] = k
            info[STAGES_COUNTED] = 1
        if status == OK:
            coefficients[NEWTON_CONSTANT], coefficients[NEWTON_GUARD] = constant, guard
        return status, out, info, error
    if scheme == NEWMARK:
        ca, cv, a0, v0 = _newmark_coefficients(u_n, v_n, a_n, h, coefficients[GAMMA],
                                               coefficients[BETA], vectors[W_A0], vectors[W_V0])
        u = _predict(u_n, v_n, a_n, has_previous, H, previous[0], previous[1], 1.0 * h,
                     vectors[W_U])
        status, k, error, constant, guard = _inertia_stage(
            force, stiffness, params, Md, Mf, m_kind, Cd, Cf, c_kind, ca, cv, a0, v0, loads[1],
            u, tol, floor, max_iterations, constant, guard, estimated, info, vectors, matrices,
            pivots, ints)
        if k >= 0:
            info[ITERATIONS_0] = k
            info[STAGES_COUNTED] = 1
        if status != OK:
            return status, out, info, math.inf
        status = _inertia_end(out, u, ca, cv, a0, v0)
        if status != OK:
            return status, out, info, math.inf
        coefficients[NEWTON_CONSTANT], coefficients[NEWTON_GUARD] = constant, guard
        return status, out, info, error
    # Bathe: the trapezoidal rule over γ h, then the three-point backward formula
    g = coefficients[GAMMA]
    ca, cv, a0, v0 = _newmark_coefficients(u_n, v_n, a_n, g * h, 0.5, 0.25, vectors[W_A0],
                                           vectors[W_V0])
    u = _predict(u_n, v_n, a_n, has_previous, H, previous[0], previous[1], g * h, vectors[W_U])
    status, k, error, constant, guard = _inertia_stage(
        force, stiffness, params, Md, Mf, m_kind, Cd, Cf, c_kind, ca, cv, a0, v0, loads[0], u,
        tol, floor, max_iterations, constant, guard, estimated, info, vectors, matrices, pivots,
        ints)
    if k >= 0:
        info[ITERATIONS_0] = k
        info[STAGES_COUNTED] = 1
    if status != OK:
        return status, out, info, math.inf
    newton_error = error
    mid_u, mid_v, mid_a = out[MID_U], out[MID_V], out[MID_A]
    for i in range(n):
        mid_u[i] = u[i]
        mid_v[i] = cv * u[i] + v0[i]
        mid_a[i] = ca * u[i] + a0[i]
    if not (_all_finite(mid_u) and _all_finite(mid_v) and _all_finite(mid_a)):
        return END_NOT_FINITE, out, info, math.inf
    c1 = (1.0 - g) / (g * h)
    c2 = -1.0 / ((1.0 - g) * g * h)
    c3 = (2.0 - g) / ((1.0 - g) * h)
    # the second sub-step's v0 and a0, over the first's (no longer needed)
    for i in range(n):
        v0[i] = c1 * u_n[i] + c2 * mid_u[i]
        a0[i] = c1 * v_n[i] + c2 * mid_v[i] + c3 * v0[i]
    info[FAILED_STAGE] = 1
    u = _predict(u_n, v_n, a_n, has_previous, H, previous[0], previous[1], 1.0 * h,
                 vectors[W_U2])
    status, k, error, constant, guard = _inertia_stage(
        force, stiffness, params, Md, Mf, m_kind, Cd, Cf, c_kind, c3 * c3, c3, a0, v0, loads[1],
        u, tol, floor, max_iterations, constant, guard, estimated, info, vectors, matrices,
        pivots, ints)
    if k >= 0:
        info[ITERATIONS_1] = k
        info[STAGES_COUNTED] = 2
    if status != OK:
        return status, out, info, math.inf
    status = _inertia_end(out, u, c3 * c3, c3, a0, v0)
    if status != OK:
        return status, out, info, math.inf
    coefficients[NEWTON_CONSTANT], coefficients[NEWTON_GUARD] = constant, guard
    return status, out, info, max(newton_error, error)


# -- the Python side -------------------------------------------------------------------

_MESSAGES = {
    RESIDUAL_NOT_FINITE: "residual is not finite",
    TANGENT_SINGULAR: "tangent is singular (singular matrix)",
    CORRECTION_NOT_FINITE: "Newton correction is not finite",
    END_NOT_FINITE: "end-of-step state is not finite",
    FORCE_NOT_FINITE: "internal_force is not finite at a trial state",
    STIFFNESS_NOT_FINITE: "stiffness is not finite at a trial state",
    DERIVATIVE_NOT_FINITE: "stiffness_derivative is not finite at a trial state",
    STEP_MATRIX_SINGULAR: "model raised SingularMatrixError: the HFDI matrix "
                          "B = 2h/3 M + h²/6 C is singular",
}


#: a kernel's value of a wrong shape: the model's method it stands for
_SHAPE_OF = {FORCE_SHAPE: "internal_force", STIFFNESS_SHAPE: "stiffness",
             DERIVATIVE_SHAPE: "stiffness_derivative"}


def _kind_and_arrays(matrix, n):
    """``(kind, diagonal (N,), dense (N, N))`` of an Evaluator's M or C (unused one empty)."""
    empty_vector, empty_matrix = np.zeros(0), np.zeros((0, 0))
    if matrix is None:
        return NONE, empty_vector, empty_matrix
    if matrix.ndim == 1:
        return DIAGONAL, np.ascontiguousarray(matrix, dtype=np.float64), empty_matrix
    return DENSE, empty_vector, np.ascontiguousarray(matrix, dtype=np.float64)


@njit(KERNEL_SET(FORCE_TYPE, STIFFNESS_TYPE, STIFFNESS_DERIVATIVE_TYPE, POTENTIAL_ENERGY_TYPE,
                 LOAD_TYPE, LOAD_TYPE), **JIT_OPTIONS)
def kernel_set(force, stiffness, stiffness_derivative, potential_energy, load, load_rate):
    """The six kernels as one :class:`~hfdi.compiled.signatures.KernelSet`
    (for :func:`attempt_with` and :func:`hfdi.compiled.driver.drive`)."""
    kernels = structref.new(KERNEL_SET)
    kernels.force = force
    kernels.stiffness = stiffness
    kernels.stiffness_derivative = stiffness_derivative
    kernels.potential_energy = potential_energy
    kernels.load = load
    kernels.load_rate = load_rate
    return kernels


@njit(types.Tuple((types.int64, MATRIX, INDEX_VECTOR, types.float64))(
    KERNEL_SET, VECTOR, INDEX_VECTOR, VECTOR, VECTOR, MATRIX, VECTOR, MATRIX, MATRIX, MATRIX,
    MATRIX, MATRIX, TENSOR, INT32_MATRIX, INT32_MATRIX), **JIT_OPTIONS)
def attempt_with(kernels, params, config, coefficients, Md, Mf, Cd, Cf, start, previous, loads,
                 vectors, matrices, pivots, ints):
    """:func:`attempt` with the model's kernels in one
    :class:`~hfdi.compiled.signatures.KernelSet`: one argument for numba to
    unbox at a call from Python instead of three first-class functions. Its
    ``out`` and ``info`` are new arrays (the end state's arrays become the
    caller's; :func:`attempt` zeroes them), the work arrays the caller's
    :func:`workspace`."""
    n = start.shape[1]
    return attempt(kernels.force, kernels.stiffness, kernels.stiffness_derivative, params,
                   config, coefficients, Md, Mf, Cd, Cf, start, previous, loads,
                   np.empty((7, n)), np.empty(INFO_SIZE, np.int64), vectors, matrices, pivots, ints)


@functools.lru_cache(maxsize=32)
def _shared_kernel_set(force, stiffness, derivative, potential_energy, load, load_rate):
    """:func:`kernel_set`, one per six kernels: its fields are set once and
    only read, so the integrators of one model share it; making one resolves
    six function addresses in numba, 0.45 ms of the 2 ms an Integrator of
    the tetrahedra took to make."""
    return kernel_set(force, stiffness, derivative, potential_energy, load, load_rate)


class CompiledStep:
    """The compiled attempt of one model and scheme, called as
    :func:`hfdi.corrector.solve_step` is.

    Parameters
    ----------
    ev : Evaluator
        Dense (``ev.n < DENSE_BELOW``), with ``M`` and ``C`` diagonal or dense.
    scheme : Newmark, Bathe or HFDI
    kernels : CompiledKernels
    """

    def __init__(self, ev, scheme, kernels):
        self.ev, self.scheme, self.kernels = ev, scheme, kernels
        self.exact_rate = type(scheme) is HFDI and (
            scheme.load_rate == "exact" or (scheme.load_rate == "auto" and ev.has_load_rate))
        # The kernels resolved once into one object, for the attempt (f, K, T)
        # and the compiled driver (V, p and p' too). Without a compiled load the
        # zero load holds its place, and without an exact rate the load holds
        # the rate's: neither is called then. self.kernels keeps the code alive.
        load = kernels.load if kernels.load is not None else hat_load
        rate = kernels.load_rate if self.exact_rate and kernels.load_rate is not None else load
        self.kernel_set = _shared_kernel_set(kernels.force, kernels.stiffness,
                                             kernels.stiffness_derivative,
                                             kernels.potential_energy, load, rate)
        n = ev.n
        m_kind, self.Md, self.Mf = _kind_and_arrays(ev.mass, n)
        c_kind, self.Cd, self.Cf = _kind_and_arrays(ev.damping, n)
        self.config = np.zeros(7, np.int64)
        self.config[MASS_KIND], self.config[DAMPING_KIND] = m_kind, c_kind
        self.coefficients = np.zeros(9)
        if type(scheme) is Newmark:
            self.config[SCHEME] = NEWMARK
            self.coefficients[GAMMA], self.coefficients[BETA] = scheme.gamma, scheme.beta
        elif type(scheme) is Bathe:
            self.config[SCHEME] = BATHE
            self.coefficients[GAMMA] = scheme.gamma
        elif type(scheme) is HFDI:
            self.config[SCHEME] = HFDI_SCHEME
        else:
            raise TypeError(f"the compiled step knows Newmark, Bathe and HFDI, got {scheme!r}")
        self._previous = np.zeros((2, n))
        self._zero = np.zeros(n)
        self._workspace = workspace(n)
        # a model whose data change after the kernels were made (EnergyModel's
        # set_parameters) hands its current params to every call
        self._current_params = getattr(ev.system, "compiled_params", None)

    def params(self):
        """The kernels' ``params`` now (the model's current ones where it says)."""
        if self._current_params is None:
            return self.kernels.params
        return self._current_params()

    def _loads(self, start: State, t_end: float):
        """``p`` at Bathe's mid-step, ``p(t_end)`` and HFDI's ``p'(t_end)`` (3, N),
        as the Python stages evaluate them."""
        ev, h = self.ev, t_end - start.t
        loads = np.zeros((3, ev.n))
        kind = self.config[SCHEME]
        if kind == BATHE:
            loads[0] = ev.load(start.t + self.scheme.gamma * h)
        loads[1] = ev.load(t_end)
        if kind == HFDI_SCHEME:
            loads[2] = ev.load_rate(t_end) if self.exact_rate else (loads[1] - start.p) / h
        return loads

    def solve_step(self, start: State, previous, t_end: float, tol: float, floor: float,
                   max_iterations: int, memory: tuple = NO_MEASUREMENT,
                   estimated: bool = False) -> StepOutcome:
        """One attempt at the step ``start.t → t_end`` from the history ``previous``
        (``None`` after a restart): :func:`hfdi.corrector.solve_step` with the
        predictor :func:`hfdi.corrector.predict`."""
        ev = self.ev
        try:
            loads = self._loads(start, t_end)
        except ModelError:
            raise
        except NonFiniteError as exc:
            return StepOutcome(None, [], str(exc))
        except Exception as exc:  # the load failed at some time: a failed attempt
            return StepOutcome(None, [], f"model raised {type(exc).__name__}: {exc}")
        config, coefficients = self.config, self.coefficients
        config[HAS_PREVIOUS] = previous is not None
        config[HAS_START_FORCE] = start.f is not None
        config[MAX_ITERATIONS] = max_iterations
        config[NEWTON_TEST] = estimated
        coefficients[NEWTON_CONSTANT], coefficients[NEWTON_GUARD] = memory
        coefficients[T_START], coefficients[T_END] = start.t, t_end
        coefficients[T_PREVIOUS] = previous.t if previous is not None else start.t
        coefficients[TOL], coefficients[FLOOR] = tol, floor
        history = self._previous
        if previous is not None:
            history[0], history[1] = previous.u, previous.v
        start_rows = np.stack([start.u, start.v, start.a,
                               start.f if start.f is not None else self._zero, start.p])
        try:
            status, out, info, newton_error = attempt_with(
                self.kernel_set, self.params(), config, coefficients, self.Md, self.Mf,
                self.Cd, self.Cf, start_rows, history, loads, *self._workspace)
        except Exception as exc:
            # a kernel raised: a failed attempt, as a raising model is on the
            # Python path (its evaluations of this attempt go uncounted)
            return StepOutcome(None, [], f"model raised {type(exc).__name__}: {exc}")
        if status in _SHAPE_OF:
            what = _SHAPE_OF[int(status)]
            rows, columns = int(info[BAD_ROWS]), int(info[BAD_COLUMNS])
            shape = (rows,) if columns < 0 else (rows, columns)
            expected = (ev.n,) if columns < 0 else (ev.n, ev.n)
            raise ModelError(f"{what} returned shape {shape}, expected {expected}")
        ev.nfev += int(info[NFEV])
        ev.njev += int(info[NJEV])
        ev.ntev += int(info[NTEV])
        ev.nlu += int(info[NLU])
        iterations = [int(i) for i in info[:int(info[STAGES_COUNTED])]]
        kind = config[SCHEME]
        if status != OK:
            if status == NO_CONVERGENCE:
                message = f"no convergence in N_max = {max_iterations} corrections"
            else:
                message = _MESSAGES[int(status)]
            if kind == BATHE and status in (RESIDUAL_NOT_FINITE, TANGENT_SINGULAR,
                                            CORRECTION_NOT_FINITE, NO_CONVERGENCE):
                message += f" (sub-step {int(info[FAILED_STAGE]) + 1})"
            return StepOutcome(None, iterations, message)
        stages = []
        if kind == BATHE:
            t_mid = start.t + self.scheme.gamma * (t_end - start.t)
            stages.append(State(t_mid, out[MID_U], out[MID_V], out[MID_A], None, loads[0]))
        f = out[END_F] if kind == HFDI_SCHEME else None
        end = State(t_end, out[END_U], out[END_V], out[END_A], f, loads[1])
        return StepOutcome(end, iterations, stages=stages, newton_error=float(newton_error),
                           newton_memory=(float(coefficients[NEWTON_CONSTANT]),
                                          float(coefficients[NEWTON_GUARD])))
