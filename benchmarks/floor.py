"""The floor: the same Newton iteration in a minimal compiled loop.

A fixed-step run of one scheme written as plainly as compiled code allows, for
a diagonal ``M`` and no damping (the four paper models): the model's own
compiled kernels passed as arguments (numba specialises the loop on them and
may inline them), LAPACK as the compiled attempt calls it
(:func:`hfdi.compiled.lapack.solve`: Cholesky for a tangent symmetric to
rounding, else LU), work
arrays allocated once, a linear predictor, the convergence test of Eq. 38 and
nothing else: no error estimate, no controller, no energy balance, no checks
of the model's values, no statistics. What the library's compiled path costs
above this per Newton iteration is the price of its generality and its
guards (docs/compiled.md).

:func:`floor_us` runs it at the mean step of a library run and returns µs per
Newton iteration (:func:`floor_run`, its end state, is held to the library's
fixed-step run by ``tests/test_profile.py``); ``python -m benchmarks profile --paths`` prints it beside
the compiled path's.
"""
from __future__ import annotations

import math
import time

import numpy as np

__all__ = ["floor_us", "floor_run"]

_LOOPS = {}


def _loops():
    """The three minimal loops, compiled on first use (numba imported here)."""
    if _LOOPS:
        return _LOOPS
    from numba import njit

    from hfdi.compiled.lapack import solve, work_arrays

    @njit
    def correct(tangent, du, u, lu, pivots, ints, tol):
        """``u += tangent⁻¹ du`` (``du`` holds ``−residual``); converged by Eq. 38."""
        solve(tangent, du, lu, pivots, ints)
        step2, size2 = 0.0, 0.0
        for i in range(u.shape[0]):
            u[i] += du[i]
            step2 += du[i] * du[i]
            size2 += u[i] * u[i]
        return math.sqrt(step2) <= tol * max(math.sqrt(size2), 1.0)

    @njit
    def newton(force, stiffness, params, M, ca, rhs, u, tol, work, counters):
        """Newton on ``ca M u + f(u) = rhs`` from ``u`` (in place)."""
        n = u.shape[0]
        tangent, residual, du, lu, pivots, ints = work
        for _ in range(50):
            f = force(u, params)
            K = stiffness(u, params)
            for i in range(n):
                residual[i] = ca * M[i] * u[i] + f[i] - rhs[i]
                du[i] = -residual[i]
                for j in range(n):
                    tangent[i, j] = K[i, j]
                tangent[i, i] += ca * M[i]
            counters[0] += 1
            if correct(tangent, du, u, lu, pivots, ints, tol):
                return

    @njit
    def newmark(force, stiffness, load, params, load_params, M, u, v, a, h, steps, tol):
        n = u.shape[0]
        work = (np.empty((n, n)), np.empty(n), np.empty(n)) + work_arrays(n)
        counters = np.zeros(1, np.int64)
        gamma, beta = 0.5, 0.25
        ca, cv = 1.0 / (beta * h * h), gamma / (beta * h)
        rhs, new = np.empty(n), np.empty(n)
        for k in range(steps):
            p = load((k + 1) * h, load_params)
            a0 = -ca * u - v / (beta * h) - (0.5 / beta - 1.0) * a
            v0 = -cv * u + (1.0 - gamma / beta) * v + h * (1.0 - 0.5 * gamma / beta) * a
            for i in range(n):
                rhs[i] = p[i] - M[i] * a0[i]
                new[i] = u[i] + h * v[i]
            newton(force, stiffness, params, M, ca, rhs, new, tol, work, counters)
            for i in range(n):
                u[i] = new[i]
                v[i] = cv * new[i] + v0[i]
                a[i] = ca * new[i] + a0[i]
        return counters[0]

    @njit
    def bathe(force, stiffness, load, params, load_params, M, u, v, a, h, steps, tol):
        n = u.shape[0]
        work = (np.empty((n, n)), np.empty(n), np.empty(n)) + work_arrays(n)
        counters = np.zeros(1, np.int64)
        g = 0.5                  # the library's default sub-step ratio
        hg = g * h
        ca, cv = 4.0 / (hg * hg), 2.0 / hg
        c1, c2 = (1.0 - g) / (g * h), -1.0 / ((1.0 - g) * g * h)
        c3 = (2.0 - g) / ((1.0 - g) * h)
        rhs, mid, new = np.empty(n), np.empty(n), np.empty(n)
        mid_v, v0, a0 = np.empty(n), np.empty(n), np.empty(n)
        for k in range(steps):
            t = k * h
            p = load(t + hg, load_params)
            for i in range(n):       # the trapezoidal rule over γ h
                a0[i] = -ca * u[i] - 2.0 * cv * v[i] - a[i]
                v0[i] = -cv * u[i] - v[i]
                rhs[i] = p[i] - M[i] * a0[i]
                mid[i] = u[i] + hg * v[i]
            newton(force, stiffness, params, M, ca, rhs, mid, tol, work, counters)
            for i in range(n):
                mid_v[i] = cv * mid[i] + v0[i]
            p = load(t + h, load_params)
            for i in range(n):       # the three-point backward formula
                v0[i] = c1 * u[i] + c2 * mid[i]
                a0[i] = c1 * v[i] + c2 * mid_v[i] + c3 * v0[i]
                rhs[i] = p[i] - M[i] * a0[i]
                new[i] = u[i] + h * v[i]
            newton(force, stiffness, params, M, c3 * c3, rhs, new, tol, work, counters)
            for i in range(n):
                u[i] = new[i]
                v[i] = c3 * new[i] + v0[i]
                a[i] = c3 * c3 * new[i] + a0[i]
        return counters[0]

    @njit
    def hfdi(force, stiffness, derivative, load, params, load_params, M, u, v, h, steps,
             tol):
        """HFDI's Newton on Eq. 21 with its exact tangent (diagonal M, no C)."""
        n = u.shape[0]
        c, c2 = h * h / 6.0, 2.0 * h / 3.0
        b = c2 * M
        S, tangent = np.empty((n, n)), np.empty((n, n))
        g, vD, residual, du, q0, F0 = (np.empty(n), np.empty(n), np.empty(n), np.empty(n),
                                       np.empty(n), np.empty(n))
        lu, pivots, ints = work_arrays(n)
        iterations = 0
        p_n = load(0.0, load_params)
        f_n = force(u, params)
        for k in range(steps):
            p = load((k + 1) * h, load_params)
            for i in range(n):
                q0[i] = -M[i] * (u[i] + h / 3.0 * v[i])
                F0[i] = -M[i] * v[i] - h / 3.0 * (p_n[i] - f_n[i])
            pt = (p - p_n) / h
            x = u + h * v
            for _ in range(50):
                f = force(x, params)
                K = stiffness(x, params)
                for i in range(n):
                    g[i] = p[i] - f[i]
                    vD[i] = (M[i] * x[i] + q0[i] + c * g[i]) / b[i]
                Kv = np.dot(K, vD)
                for i in range(n):
                    residual[i] = M[i] * vD[i] - c2 * g[i] + c * (pt[i] - Kv[i]) + F0[i]
                    du[i] = -residual[i]
                T = derivative(x, vD, params)
                for i in range(n):
                    for j in range(n):
                        S[i, j] = -c * K[i, j]
                        tangent[i, j] = c2 * K[i, j] - c * T[i, j]
                    S[i, i] += M[i]
                tangent += S @ (S / b.reshape(n, 1))
                iterations += 1
                if correct(tangent, du, x, lu, pivots, ints, tol):
                    break
            f_n = force(x, params)
            for i in range(n):
                v[i] = (M[i] * x[i] + q0[i] + c * (p[i] - f_n[i])) / b[i]
                u[i] = x[i]
            p_n = p
        return iterations

    _LOOPS.update(newmark=newmark, bathe=bathe, hfdi=hfdi)
    return _LOOPS


def floor_us(model, scheme: str, step: float, t_end: float, tol: float, repeats: int = 3):
    """µs per Newton iteration of the minimal loop of ``scheme`` on ``model``
    (compiled kernels, diagonal ``M``, no damping) at the fixed ``step`` over
    ``t_end``, best of ``repeats``; ``(µs, iterations per step)``."""
    run, steps = _runner(model, scheme, step, t_end, tol)
    run()                                           # compile
    best, iterations = math.inf, 0
    for _ in range(max(1, int(repeats))):
        start = time.perf_counter()
        iterations = run()[2]
        best = min(best, time.perf_counter() - start)
    return 1e6 * best / max(iterations, 1), iterations / steps


def floor_run(model, scheme: str, step: float, t_end: float, tol: float):
    """The minimal loop's end state: ``(u, v, Newton iterations)``."""
    return _runner(model, scheme, step, t_end, tol)[0]()


def _runner(model, scheme, step, t_end, tol):
    from hfdi.compiled import kernels_of
    from hfdi.compiled.loads import hat_load

    kernels, why = kernels_of(model)
    if kernels is None:
        raise ValueError(f"no compiled kernels: {why}")
    M = np.asarray(model.mass, dtype=float)
    if M.ndim == 2 and np.array_equal(M, np.diag(np.diagonal(M))):
        M = np.ascontiguousarray(np.diagonal(M))
    if M.ndim != 1 or model.damping is not None:
        raise ValueError("the minimal loop takes a diagonal mass and no damping")
    load = kernels.load if kernels.load is not None else hat_load
    load_params = kernels.load_params if kernels.load is not None else np.zeros(1)
    steps = max(1, int(round(t_end / step)))
    h = t_end / steps
    loop = _loops()[scheme]

    def run():
        u = np.array(model.initial_displacement, dtype=float)
        v = np.zeros_like(u) if model.initial_velocity is None else \
            np.array(model.initial_velocity, dtype=float)
        if scheme == "hfdi":
            iterations = loop(kernels.force, kernels.stiffness, kernels.stiffness_derivative,
                              load, kernels.params, load_params, M, u, v, h, steps, tol)
        else:
            # the initial acceleration M⁻¹(p(0) − f(u0)), as the library starts
            a = (load(0.0, load_params) - kernels.force(u, kernels.params)) / M
            iterations = loop(kernels.force, kernels.stiffness, load, kernels.params,
                              load_params, M, u, v, a, h, steps, tol)
        return u, v, int(iterations)

    return run, steps
