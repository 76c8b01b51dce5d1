"""The global error estimate: the local error estimates carried through the
linearised motion (docs/algorithm.md, "Global error estimate").

The error ``e_n = y_n − y(t_n)`` of ``y = (u, v)`` obeys, to first order in
``e``, ``e_{n+1} = Φ_n e_n + ℓ_{n+1}``: ``ℓ_{n+1}`` the step's local error
(:func:`hfdi.core.estimate.local_error` estimates it) and ``Φ_n`` the
derivative of the exact flow over the step at ``y_n``, the solution operator
of the variational equation ``M δu'' + C δu' + K(u(t)) δu = 0``.
:func:`propagate` applies ``Φ_n`` to ``VECTORS.global_error``: after an HFDI
step the derivative of that step itself, from its Newton tangent's factors
(one evaluation of ``K``, a few products and one solve); otherwise one step
of an L-stable SDIRK method of order 3 with ``K`` frozen at the step's
midpoint (one evaluation of ``K``, one factorisation of ``M + γh C + (γh)²
K`` and three solves).
"""
from __future__ import annotations

import math

from ..core.arrays import (all_finite, axpy, copy, fill, lincomb, matvec, max_abs, scale,
                           scaled_into, times)
from ..core.codes import OK
from ..core.jit import jitable
from ..linsolve.dense import factored_solve, getrf, getrs
from ..linsolve.sparse import general_propagation_factor, general_propagation_solve
from .stages import _EPS, _add_matrix, b_solve, force_into, stiffness_of

__all__ = ["GAMMA", "PROPAGATOR", "PROPAGATOR_STAGES", "propagate"]

#: Alexander's three-stage SDIRK (1977): order 3, L-stable, stiffly accurate
#: (the step's end is its last stage), every stage with the diagonal ``γ``,
#: the root of ``6γ³ − 18γ² + 9γ − 1`` in (1/6, 1/2). L-stable, so that an
#: error in a stiff, damped component dies out as the motion's own does.
GAMMA = 0.43586652150845899942
_B1 = -1.5 * GAMMA * GAMMA + 4.0 * GAMMA - 0.25
_B2 = 1.5 * GAMMA * GAMMA - 5.0 * GAMMA + 1.25
#: Its coefficients below the diagonal, row by row (``a_ij``, ``j < i``).
PROPAGATOR = (0.0, 0.0, 0.0,
              0.5 * (1.0 - GAMMA), 0.0, 0.0,
              _B1, _B2, 0.0)
PROPAGATOR_STAGES = 3

#: The relative size of the step of :func:`_start_stiffness_times`' difference.
_SQRT_EPS = math.sqrt(_EPS)
#: The rounding of that difference it accepts, as a share of its size.
DIFFERENCE_ROUNDING = 1e-3


@jitable
def _factor(fn, cfg, data, run, vec, gh):
    """Factorise ``S = M + γh C + (γh)² K``, ``K`` at the step's midpoint
    ``(u_n + u_{n+1})/2``; ``(done, K)``."""
    u_mid = vec.residual
    lincomb(u_mid, 0.5, vec.u, 0.5, vec.u_new)
    outcome, K = stiffness_of(fn, cfg, data, run, u_mid)
    if outcome != OK:
        return False, K
    run.nlu += 1
    if cfg.sparse:
        return general_propagation_factor(vec, data, cfg, K, gh), K
    G = vec.G
    scaled_into(G, gh * gh, K)
    _add_matrix(G, 1.0, cfg.m_kind, data.Md, data.Mf)
    _add_matrix(G, gh, cfg.c_kind, data.Cd, data.Cf)
    return getrf(G, vec.G_lu, vec.g_pivots, vec.ints), K


@jitable
def propagate(fn, cfg, data, run, vec, h):
    """``VECTORS.global_error ← Φ g`` over the step of size ``h`` from the
    current state to ``VECTORS.*_new`` (the module's docstring). Each stage
    ``Y = z + γh J Y`` of the first-order form ``y' = J y`` solves ``S W =
    M z_v − γh K z_u`` for its velocity ``W`` and has ``X = z_u + γh W``; its
    derivative ``(Y − z)/(γh) = (W, (W − z_v)/(γh))`` needs no mass solve.
    ``g`` becomes NaN (no estimate from here on) where ``K`` cannot be
    evaluated or ``S`` is singular; the run goes on."""
    n = cfg.n
    g = vec.global_error
    if not g[0] == g[0]:
        return                        # NaN: the estimate was lost before
    if run.tangent_kind != 0 and run.tangent_h == h and not run.a_taylor:
        if not _propagate_hfdi(fn, cfg, data, run, vec, h) or not all_finite(g):
            fill(g, math.nan)
        return
    gh = GAMMA * h
    done, K = _factor(fn, cfg, data, run, vec, gh)
    if not done:
        fill(g, math.nan)
        return
    z, F, w, work = vec.g_z, vec.g_stages, vec.rhs, vec.work
    zu, zv = z[:n], z[n:]
    for i in range(PROPAGATOR_STAGES):
        copy(z, g)
        for j in range(i):
            axpy(z, h * PROPAGATOR[3 * i + j], F[j])
        times(cfg.m_kind, data.Md, data.Mf, zv, w)
        matvec(K, zu, work)
        axpy(w, -gh, work)
        if cfg.sparse:
            general_propagation_solve(vec, w)
        else:
            getrs(vec.G_lu, vec.g_pivots, vec.ints, w)
        copy(F[i][:n], w)
        lincomb(F[i][n:], 1.0 / gh, w, -1.0 / gh, zv)
    # stiffly accurate: the step's end is the last stage's Y
    lincomb(g[:n], 1.0, zu, gh, w)
    copy(g[n:], w)
    if not all_finite(g):
        fill(g, math.nan)


@jitable
def _propagate_hfdi(fn, cfg, data, run, vec, h):
    """``g ← Φ g`` with ``Φ`` the derivative of the HFDI step just taken with
    respect to its start ``(u_n, v_n)``, by the step's own equations
    (docs/algorithm.md, "Global error estimate"): with ``c = h²/6``,
    ``S = M − c K``, ``B = 2h/3 M + c C`` and the Newton tangent ``J`` (its
    factors in ``VECTORS.lu``), ``w = −h/3 M g_v − c K g_u``,
    ``J δd = −(S B⁻¹ w + (2h/3 K − c T[v_D] + h/3 K_n) g_u − M g_v)``, then
    ``g_u ← g_u + δd`` and ``g_v ← B⁻¹ (S δd + w)``. ``K``, ``T[v_D]``,
    ``S`` and ``J`` are the last iterate's; ``K_n g_u`` is a difference of
    ``f`` (:func:`_start_stiffness_times`). False where it cannot be made."""
    n = cfg.n
    c = h * h / 6.0
    g = vec.global_error
    gu, gv = g[:n], g[n:]
    ku, mv, w, y, r, tu = vec.kv, vec.residual, vec.a0, vec.v0, vec.du, vec.rhs
    k_start = vec.work
    if not _start_stiffness_times(fn, cfg, data, run, vec, gu, k_start):
        return False
    matvec(vec.K_last, gu, ku)
    times(cfg.m_kind, data.Md, data.Mf, gv, mv)
    lincomb(w, -(h / 3.0), mv, -c, ku)
    copy(y, w)
    b_solve(cfg, vec, y)
    matvec(vec.S, y, r)
    axpy(r, 2.0 * h / 3.0, ku)
    matvec(vec.T_last, gu, tu)
    axpy(r, -c, tu)
    axpy(r, h / 3.0, k_start)
    axpy(r, -1.0, mv)
    scale(r, -1.0, r)
    factored_solve(run.tangent_kind, vec.lu, vec.pivots, vec.ints, r)
    matvec(vec.S, r, y)
    axpy(y, 1.0, w)
    b_solve(cfg, vec, y)
    axpy(gu, 1.0, r)
    copy(gv, y)
    return True


@jitable
def _start_stiffness_times(fn, cfg, data, run, vec, gu, out):
    """``out = K(u_n) g_u`` for the HFDI propagator: a forward difference of
    ``f`` along ``g_u``, ``(f(u_n + s g_u) − f(u_n))/s`` with
    ``s‖g_u‖ = √ε max(‖u_n‖, u_scale)``, one force where a whole ``K`` was
    evaluated (docs/algorithm.md, "Global error estimate"); ``K(u_n)``
    itself where ``f(u_n)`` is not at hand or the difference's rounding
    exceeds :data:`DIFFERENCE_ROUNDING` of it (a force far larger than
    ``K u``). False where neither can be evaluated."""
    size_g = max_abs(gu)
    if size_g == 0.0:
        fill(out, 0.0)
        return True
    if run.has_force:
        s = _SQRT_EPS * max(max_abs(vec.u), cfg.floor) / size_g
        shifted = vec.tmp
        lincomb(shifted, 1.0, vec.u, s, gu)
        if force_into(fn, cfg, data, run, shifted, out) == OK:
            rounding = 4.0 * _EPS * (max_abs(out) + max_abs(vec.f)) / s
            lincomb(out, 1.0 / s, out, -1.0 / s, vec.f)
            if rounding <= DIFFERENCE_ROUNDING * max_abs(out):
                return True
    outcome, K = stiffness_of(fn, cfg, data, run, vec.u)
    if outcome != OK:
        return False
    matvec(K, gu, out)
    return True
