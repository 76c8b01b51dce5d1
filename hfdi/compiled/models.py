"""Compiled kernels (numba) of the four paper models: ``f``, ``K``, ``T[w]`` and ``V``.

Each kernel reproduces the model's Python method expression for expression
(loops over pairs and elements instead of vectorised arrays), so the two agree
to rounding; ``tests/test_compiled_kernels.py`` checks both that and the
kernels' derivatives against finite differences. The model data travel in one
float64 vector ``params``, built by the ``*_kernels`` functions from a model
object; its layout is stated at each of them.

Importing this module imports numba and loads (or, the first time, compiles
and caches) every kernel; :meth:`compiled_kernels` of the models imports it
only when called.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import CompiledKernels, SparseKernels
from .loads import hat_load, hat_load_params
from .signatures import (FORCE, JIT_OPTIONS, POTENTIAL_ENERGY, SPARSE_STIFFNESS,
                         SPARSE_STIFFNESS_DERIVATIVE, STIFFNESS, STIFFNESS_DERIVATIVE)

__all__ = ["dumbbell_kernels", "tetrahedra_kernels", "articulated_kernels",
           "toss_rule_kernels", "toss_rule_sparse_kernels"]


# -- pair potentials -----------------------------------------------------------
# For a pair (i, j) of particles in ``dim`` dimensions with d = x_j − x_i the
# pair's vector q goes to +j and −i, its dim × dim block H to +(i,i), +(j,j),
# −(i,j), −(j,i) (see hfdi/models/pair.py for the formulas).

@njit(**JIT_OPTIONS)
def _relative(u, i, j, dim, out):
    r2 = 0.0
    for k in range(dim):
        out[k] = u[j * dim + k] - u[i * dim + k]
        r2 += out[k] * out[k]
    return math.sqrt(r2)


@njit(**JIT_OPTIONS)
def _relative3(u, i, j):
    """``(r, d)`` of the pair (i, j) in three dimensions as :func:`_relative`
    forms them, ``d`` a tuple: no scratch array to allocate at every call."""
    d0 = u[3 * j] - u[3 * i]
    d1 = u[3 * j + 1] - u[3 * i + 1]
    d2 = u[3 * j + 2] - u[3 * i + 2]
    r2 = 0.0
    r2 += d0 * d0
    r2 += d1 * d1
    r2 += d2 * d2
    return math.sqrt(r2), (d0, d1, d2)


@njit(**JIT_OPTIONS)
def _scatter_vector(f, i, j, dim, q):
    for k in range(dim):
        f[j * dim + k] += q[k]
        f[i * dim + k] -= q[k]


@njit(inline="always", **JIT_OPTIONS)
def _scatter_entry(K, i, j, dim, a, b, h):
    """Entry ``(a, b)`` of a pair's block, ``h``, to +(i,i), +(j,j), −(i,j), −(j,i)."""
    K[i * dim + a, i * dim + b] += h
    K[j * dim + a, j * dim + b] += h
    K[i * dim + a, j * dim + b] -= h
    K[j * dim + a, i * dim + b] -= h


@njit(**JIT_OPTIONS)
def _scatter_block(K, i, j, dim, H):
    for a in range(dim):
        for b in range(dim):
            _scatter_entry(K, i, j, dim, a, b, H[a, b])


# The pair terms are scattered entry by entry as they are formed: a small
# array per pair would cost an allocation and its reference counting, more
# than the pair's arithmetic.

@njit(**JIT_OPTIONS)
def _pair_force_add(f, i, j, dim, d, r, dphi):
    """``f += (φ'/r) d`` at j, minus at i."""
    c = dphi / r
    for k in range(dim):
        q = c * d[k]
        f[j * dim + k] += q
        f[i * dim + k] -= q


@njit(**JIT_OPTIONS)
def _pair_stiffness_add(K, i, j, dim, d, r, dphi, ddphi):
    """``K += scatter(a I + b d dᵀ)``, ``a = φ'/r``, ``b = (φ'' − a)/r²``."""
    a = dphi / r
    b = (ddphi - a) / (r * r)
    for p in range(dim):
        for q in range(dim):
            h = (b * d[p]) * d[q]
            if p == q:
                h += a
            _scatter_entry(K, i, j, dim, p, q, h)


@njit(**JIT_OPTIONS)
def _pair_derivative_add(T, i, j, dim, d, r, wd, dphi, ddphi, dddphi):
    """``T += scatter(x dᵀ + d yᵀ + b s I)`` (see PairPotential.stiffness_derivative)."""
    s = 0.0
    for k in range(dim):
        s += d[k] * wd[k]
    r2 = r * r
    t = ddphi - dphi / r
    b = t / r2
    db = (dddphi - ddphi / r + dphi / r2) / r2 - 2.0 * t / (r2 * r)
    c = db * s / r
    for p in range(dim):
        xp = b * wd[p]
        for q in range(dim):
            yq = b * wd[q] + c * d[q]
            h = xp * d[q] + d[p] * yq
            if p == q:
                h += b * s
            _scatter_entry(T, i, j, dim, p, q, h)


# -- dumbbell: params = (A, sigma) ---------------------------------------------

@njit(**JIT_OPTIONS)
def _bond(u):
    dx = u[2] - u[0]
    dy = u[3] - u[1]
    return dx, dy, math.sqrt(dx * dx + dy * dy)


@njit(**JIT_OPTIONS)
def _bond_derivatives(A, s, r):
    s3 = math.pow(s, 3.0)
    s5 = math.pow(s, 5.0)
    r4 = math.pow(r, 4.0)
    r6 = math.pow(r, 6.0)
    return (A * (-5 * s5 / r6 + 3 * s3 / r4), A * (30 * s5 / math.pow(r, 7.0) - 12 * s3 / math.pow(r, 5.0)),
            A * (-210 * s5 / math.pow(r, 8.0) + 60 * s3 / r6))


@njit(**JIT_OPTIONS)
def _bond_blocks(hxx, hxy, hyy):
    out = np.empty((4, 4))
    H = ((hxx, hxy), (hxy, hyy))
    for a in range(2):
        for b in range(2):
            out[a, b] = H[a][b]
            out[a + 2, b + 2] = H[a][b]
            out[a, b + 2] = -H[a][b]
            out[a + 2, b] = -H[a][b]
    return out


@njit(FORCE, **JIT_OPTIONS)
def dumbbell_force(u, params):
    A, s = params[0], params[1]
    dx, dy, r = _bond(u)
    q = A * (-5 * math.pow(s, 5.0) / math.pow(r, 6.0) + 3 * math.pow(s, 3.0) / math.pow(r, 4.0)) / r
    f = np.empty(4)
    f[0] = -(q * dx)
    f[1] = -(q * dy)
    f[2] = q * dx
    f[3] = q * dy
    return f


@njit(STIFFNESS, **JIT_OPTIONS)
def dumbbell_stiffness(u, params):
    dx, dy, r = _bond(u)
    d1, d2, _ = _bond_derivatives(params[0], params[1], r)
    a = d1 / r
    b = (d2 - a) / (r * r)
    return _bond_blocks(a + b * dx * dx, b * dx * dy, a + b * dy * dy)


@njit(STIFFNESS_DERIVATIVE, **JIT_OPTIONS)
def dumbbell_stiffness_derivative(u, w, params):
    dx, dy, r = _bond(u)
    wx = w[2] - w[0]
    wy = w[3] - w[1]
    d1, d2, d3 = _bond_derivatives(params[0], params[1], r)
    s = dx * wx + dy * wy
    b = (d2 - d1 / r) / (r * r)
    db = (d3 - d2 / r + d1 / (r * r)) / (r * r) - 2.0 * (d2 - d1 / r) / (r * r * r)
    c = db * s / r
    bs = b * s
    return _bond_blocks(2.0 * b * wx * dx + c * dx * dx + bs,
                        b * (wx * dy + dx * wy) + c * dx * dy,
                        2.0 * b * wy * dy + c * dy * dy + bs)


@njit(POTENTIAL_ENERGY, **JIT_OPTIONS)
def dumbbell_potential_energy(u, params):
    A, s = params[0], params[1]
    r = _bond(u)[2]
    return A * (math.pow(s, 5.0) / math.pow(r, 5.0) - math.pow(s, 3.0) / math.pow(r, 3.0))


def dumbbell_kernels(model) -> CompiledKernels:
    """Kernels of a :class:`~hfdi.models.dumbbell.Dumbbell`; ``params = (A, σ)``."""
    return CompiledKernels(dumbbell_force, dumbbell_stiffness, dumbbell_stiffness_derivative,
                           dumbbell_potential_energy,
                           np.array([model.A, model.sigma], dtype=np.float64),
                           hat_load, hat_load_params(model.n_dof))


# -- tetrahedra: params = (r0³, k/3, −2k, k, r0), six entries each -------------

_TET_I = (0, 0, 0, 1, 1, 2)
_TET_J = (1, 2, 3, 2, 3, 3)


@njit(FORCE, **JIT_OPTIONS)
def tetrahedra_force(u, params):
    f = np.zeros(12)
    for p in range(6):
        i, j = _TET_I[p], _TET_J[p]
        r, d = _relative3(u, i, j)
        q = params[p] / r
        _pair_force_add(f, i, j, 3, d, r, params[6 + p] * (r - q / r))
    return f


@njit(STIFFNESS, **JIT_OPTIONS)
def tetrahedra_stiffness(u, params):
    K = np.zeros((12, 12))
    for p in range(6):
        i, j = _TET_I[p], _TET_J[p]
        r, d = _relative3(u, i, j)
        q = params[p] / r
        k3 = params[6 + p]
        _pair_stiffness_add(K, i, j, 3, d, r, k3 * (r - q / r), k3 * (1.0 + 2.0 * q / (r * r)))
    return K


@njit(STIFFNESS_DERIVATIVE, **JIT_OPTIONS)
def tetrahedra_stiffness_derivative(u, w, params):
    T = np.zeros((12, 12))
    for p in range(6):
        i, j = _TET_I[p], _TET_J[p]
        r, d = _relative3(u, i, j)
        wd = _relative3(w, i, j)[1]
        q = params[p] / r
        k3 = params[6 + p]
        _pair_derivative_add(T, i, j, 3, d, r, wd, k3 * (r - q / r),
                             k3 * (1.0 + 2.0 * q / (r * r)), params[12 + p] * q / (r * r * r))
    return T


@njit(POTENTIAL_ENERGY, **JIT_OPTIONS)
def tetrahedra_potential_energy(u, params):
    V = 0.0
    for p in range(6):
        r = _relative3(u, _TET_I[p], _TET_J[p])[0]
        k, r0 = params[18 + p], params[24 + p]
        q = r0 ** 3 / r
        V += k / 6.0 * (r ** 2 + 2.0 * q - 3.0 * r0 ** 2)
    return V


def tetrahedra_kernels(model) -> CompiledKernels:
    """Kernels of a :class:`~hfdi.models.tetrahedra.Tetrahedra`;
    ``params = (r0³, k/3, −2k, k, r0)`` per pair 12, 13, 14, 23, 24, 34 (30 entries)."""
    r03, k3, m2k = model._constants
    params = np.concatenate([r03, k3, m2k, model.spring_constant, model.rest_length])
    return CompiledKernels(tetrahedra_force, tetrahedra_stiffness,
                           tetrahedra_stiffness_derivative, tetrahedra_potential_energy,
                           np.ascontiguousarray(params, dtype=np.float64), hat_load,
                           hat_load_params(12, [(0, model.load_amplitude, model.load_time)]))


# -- articulated: params = (k_e, k_f, h) ---------------------------------------
# Links 0 (mass 1 → 2) and 1 (mass 2 → 3) in the plane; the hinge's Δα and its
# derivatives through the complex link vectors z = d_x + i d_y (see the
# model's notes): ∇α = (Im 1/z, Re 1/z), blocks s_k Im(c e_a e_b).

@njit(**JIT_OPTIONS)
def _hinge(u):
    ax, ay = u[2] - u[0], u[3] - u[1]
    bx, by = u[4] - u[2], u[5] - u[3]
    delta = -math.atan2(ax * by - ay * bx, ax * bx + ay * by)
    return delta, complex(ax, ay), complex(bx, by)


@njit(**JIT_OPTIONS)
def _hinge_gradient(za, zb):
    """``g = ∂Δα/∂u`` (6,)."""
    ga = 1.0 / za
    gb = 1.0 / zb
    grads = np.empty((2, 2))
    grads[0, 0], grads[0, 1] = ga.imag, ga.real
    grads[1, 0], grads[1, 1] = -gb.imag, -gb.real
    g = np.zeros(6)
    _scatter_vector(g, 0, 1, 2, grads[0])
    _scatter_vector(g, 1, 2, 2, grads[1])
    return g


@njit(**JIT_OPTIONS)
def _link_blocks(ca, cb):
    """``scatter(s_k Im(c_k e_a e_b))`` (6, 6) for complex ``c_0 = ca``, ``c_1 = cb``."""
    out = np.zeros((6, 6))
    H = np.empty((2, 2))
    H[0, 0], H[0, 1], H[1, 0], H[1, 1] = ca.imag, ca.real, ca.real, -ca.imag
    _scatter_block(out, 0, 1, 2, H)
    H[0, 0], H[0, 1], H[1, 0], H[1, 1] = -cb.imag, -cb.real, -cb.real, cb.imag
    _scatter_block(out, 1, 2, 2, H)
    return out


@njit(FORCE, **JIT_OPTIONS)
def articulated_force(u, params):
    k_e, k_f, h = params[0], params[1], params[2]
    f = np.zeros(6)
    d = np.empty(2)
    for link in range(2):
        r = _relative(u, link, link + 1, 2, d)
        _pair_force_add(f, link, link + 1, 2, d, r, k_e * (r - h))
    delta, za, zb = _hinge(u)
    g = _hinge_gradient(za, zb)
    c = k_f * delta
    for i in range(6):
        f[i] += c * g[i]
    return f


@njit(STIFFNESS, **JIT_OPTIONS)
def articulated_stiffness(u, params):
    k_e, k_f, h = params[0], params[1], params[2]
    K = np.zeros((6, 6))
    d = np.empty(2)
    for link in range(2):
        r = _relative(u, link, link + 1, 2, d)
        _pair_stiffness_add(K, link, link + 1, 2, d, r, k_e * (r - h), k_e)
    delta, za, zb = _hinge(u)
    g = _hinge_gradient(za, zb)
    G = _link_blocks(-1.0 / za ** 2, -1.0 / zb ** 2)
    for i in range(6):
        for j in range(6):
            K[i, j] += k_f * (g[i] * g[j] + delta * G[i, j])
    return K


@njit(STIFFNESS_DERIVATIVE, **JIT_OPTIONS)
def articulated_stiffness_derivative(u, w, params):
    k_e, k_f, h = params[0], params[1], params[2]
    T = np.zeros((6, 6))
    d = np.empty(2)
    wd = np.empty(2)
    for link in range(2):
        r = _relative(u, link, link + 1, 2, d)
        _relative(w, link, link + 1, 2, wd)
        _pair_derivative_add(T, link, link + 1, 2, d, r, wd, k_e * (r - h), k_e, 0.0)
    delta, za, zb = _hinge(u)
    g = _hinge_gradient(za, zb)
    G = _link_blocks(-1.0 / za ** 2, -1.0 / zb ** 2)
    oa = complex(w[2] - w[0], w[3] - w[1])
    ob = complex(w[4] - w[2], w[5] - w[3])
    D = _link_blocks(2.0 * oa / za ** 3, 2.0 * ob / zb ** 3)
    Gw = G @ w
    gw = 0.0
    for i in range(6):
        gw += g[i] * w[i]
    for i in range(6):
        for j in range(6):
            T[i, j] += k_f * (gw * G[i, j] + g[i] * Gw[j] + Gw[i] * g[j] + delta * D[i, j])
    return T


@njit(POTENTIAL_ENERGY, **JIT_OPTIONS)
def articulated_potential_energy(u, params):
    k_e, k_f, h = params[0], params[1], params[2]
    d = np.empty(2)
    stretch = 0.0
    for link in range(2):
        r = _relative(u, link, link + 1, 2, d)
        stretch += (r - h) ** 2
    delta = _hinge(u)[0]
    return 0.5 * k_e * stretch + 0.5 * k_f * delta ** 2


def articulated_kernels(model) -> CompiledKernels:
    """Kernels of an :class:`~hfdi.models.articulated.Articulated`; ``params = (k_e, k_f, h)``."""
    return CompiledKernels(articulated_force, articulated_stiffness,
                           articulated_stiffness_derivative, articulated_potential_energy,
                           np.array([model.k_e, model.k_f, model.h], dtype=np.float64),
                           hat_load,
                           hat_load_params(6, [(1, model.load_amplitude, model.load_time)]))


# -- toss rule: params = (N_el, EA, GA, EJ, h_e, 1/h_e, cos α̂_e, sin α̂_e) -------------------
# Element e joins nodes e and e + 1 (DOFs 3e … 3e + 5). Its reduced
# coordinates y = (u_ξ, v_ξ, α_o, χ) = L_e d_e with L_e = D_e B (see the
# model's notes); f_e = h_e L_eᵀ ∇W, K_e = h_e L_eᵀ ∇²W L_e and
# T_e = h_e L_eᵀ ∇³W[L_e w_e] L_e, the reduced derivatives of
# W = ½ (EA ε² + GA γ² + EJ χ²) from ∂ε/∂α_o = γ, ∂γ/∂α_o = −(1 + ε).

# L_e = D_e B has two non-zero entries at most per column: ∓1/h_e (u_ξ, v_ξ)
# for the translations of nodes i and j, and 1/2 (α_o) and ∓1/h_e (χ) for
# their rotations. With h_e/h_e² = 1/h_e and h_e/h_e = 1, the products below
# are h_e L_eᵀ (·) written out entry by entry: 36 entries from seven numbers.


@njit(**JIT_OPTIONS)
def _beam_reduced(x, e, inv_h):
    """``(u_ξ, v_ξ, α_o, χ)`` of element ``e`` for the nodal vector ``x``."""
    i, j = 3 * e, 3 * e + 3
    return ((x[j] - x[i]) * inv_h, (x[j + 1] - x[i + 1]) * inv_h,
            0.5 * (x[j + 2] + x[i + 2]), (x[j + 2] - x[i + 2]) * inv_h)


@njit(**JIT_OPTIONS)
def _element(params, e):
    """``(h_e, 1/h_e, cos α̂_e, sin α̂_e)`` of element ``e``."""
    n_el = int(params[0])
    return (params[4 + e], params[4 + n_el + e], params[4 + 2 * n_el + e],
            params[4 + 3 * n_el + e])


@njit(**JIT_OPTIONS)
def _beam_strains(p, q, a, cos_hat, sin_hat):
    """``ε``, ``γ`` and their gradients ``∇ε = (cb, sb, γ)``, ``∇γ = (−sb, cb, −(1 + ε))``
    (tuples), ``cb``, ``sb`` the cosine and sine of ``β = α_o + α̂`` by the
    addition theorem: one sine and cosine per element, not two."""
    ca, sa = math.cos(a), math.sin(a)
    cb, sb = ca * cos_hat - sa * sin_hat, sa * cos_hat + ca * sin_hat
    eps = ca - 1.0 + cb * p + sb * q
    gam = -sa - sb * p + cb * q
    return eps, gam, (cb, sb, gam), (-sb, cb, -(1.0 + eps))


@njit(**JIT_OPTIONS)
def _alpha_entry(r, i, j):
    """Entry ``(i, j)`` of a 3 × 3 matrix non-zero in its α_o row and column
    only, that row being ``r`` (``∇²k`` with ``r = ±∇`` of the other strain)."""
    if j == 2:
        return r[i]
    if i == 2:
        return r[j]
    return 0.0


@njit(**JIT_OPTIONS)
def _beam_block(block, h, inv_h, red):
    """``block`` (6, 6) ``= h L_eᵀ red L_e`` for a symmetric reduced ``red``
    (4, 4) whose χ row and column are zero but for ``red[3, 3]``; symmetric
    bit for bit (each value is written to both of its places)."""
    for t in range(2):
        for s in range(2):
            x = inv_h * red[t, s]
            block[t, s] = x
            block[3 + t, 3 + s] = x
            block[t, 3 + s] = -x
            block[3 + t, s] = -x
        # translation t of node i (sign −) or j (+) against either rotation
        y = 0.5 * red[t, 2]
        block[t, 2] = block[t, 5] = block[2, t] = block[5, t] = -y
        block[3 + t, 2] = block[3 + t, 5] = block[2, 3 + t] = block[5, 3 + t] = y
    q, r = 0.25 * h * red[2, 2], inv_h * red[3, 3]
    block[2, 2] = block[5, 5] = q + r
    block[2, 5] = block[5, 2] = q - r


@njit(**JIT_OPTIONS)
def _beam_add(out, e, h, inv_h, red, block):
    """``out[dofs_e, dofs_e] += h L_eᵀ red L_e`` (``block`` (6, 6) is scratch)."""
    _beam_block(block, h, inv_h, red)
    base = 3 * e
    for a in range(6):
        for b in range(6):
            out[base + a, base + b] += block[a, b]


@njit(FORCE, **JIT_OPTIONS)
def toss_rule_force(u, params):
    n_el = int(params[0])
    EA, GA, EJ = params[1], params[2], params[3]
    f = np.zeros(3 * (n_el + 1))
    for e in range(n_el):
        h, inv_h, cos_hat, sin_hat = _element(params, e)
        p, q, a, chi = _beam_reduced(u, e, inv_h)
        eps, gam, g_eps, g_gam = _beam_strains(p, q, a, cos_hat, sin_hat)
        EA_eps, GA_gam = EA * eps, GA * gam
        grad = (EA_eps * g_eps[0] + GA_gam * g_gam[0], EA_eps * g_eps[1] + GA_gam * g_gam[1],
                EA_eps * g_eps[2] + GA_gam * g_gam[2])
        # h L_eᵀ (∇W, EJ χ): ∓∇W_t on the translations of nodes i and j,
        # h/2 ∂W/∂α_o ∓ EJ χ on their rotations
        base = 3 * e
        half, bend = 0.5 * h * grad[2], EJ * chi
        f[base] -= grad[0]
        f[base + 1] -= grad[1]
        f[base + 3] += grad[0]
        f[base + 4] += grad[1]
        f[base + 2] += half - bend
        f[base + 5] += half + bend
    return f


@njit(**JIT_OPTIONS)
def _beam_add_data(data, slots, e, h, inv_h, red, block):
    """``data[slots[e, 6a + b]] += h (L_eᵀ red L_e)[a, b]``: :func:`_beam_add` into the
    data array of a CSR matrix whose pattern holds every element coupling."""
    _beam_block(block, h, inv_h, red)
    for a in range(6):
        for b in range(6):
            data[slots[e, 6 * a + b]] += block[a, b]


@njit(**JIT_OPTIONS)
def _toss_stiffness_reduced(u, e, params, red):
    """``red[:3, :3] = ∇²W`` of element ``e`` in ``(u_ξ, v_ξ, α_o)`` (``red[3, 3]`` is EJ);
    returns ``(h_e, 1/h_e)``."""
    EA, GA = params[1], params[2]
    h, inv_h, cos_hat, sin_hat = _element(params, e)
    p, q, a, chi = _beam_reduced(u, e, inv_h)
    eps, gam, g_eps, g_gam = _beam_strains(p, q, a, cos_hat, sin_hat)
    # ∇²ε has the α_o row ∇γ, ∇²γ the row −∇ε
    m_eps = (-g_eps[0], -g_eps[1], -g_eps[2])
    for i in range(3):
        for j in range(3):
            red[i, j] = (EA * (g_eps[i] * g_eps[j] + eps * _alpha_entry(g_gam, i, j))
                         + GA * (g_gam[i] * g_gam[j] + gam * _alpha_entry(m_eps, i, j)))
    return h, inv_h


@njit(**JIT_OPTIONS)
def _toss_derivative_reduced(u, w, e, params, red):
    """``red[:3, :3] = ∇³W[z]`` of element ``e``, ``z`` the reduced image of ``w``
    (the curvature term is quadratic: no third derivative); returns ``(h_e, 1/h_e)``."""
    EA, GA = params[1], params[2]
    h, inv_h, cos_hat, sin_hat = _element(params, e)
    p, q, a, _ = _beam_reduced(u, e, inv_h)
    zp, zq, za, _ = _beam_reduced(w, e, inv_h)
    z = (zp, zq, za)
    eps, gam, g_eps, g_gam = _beam_strains(p, q, a, cos_hat, sin_hat)
    m_eps = (-g_eps[0], -g_eps[1], -g_eps[2])
    m_gam = (-g_gam[0], -g_gam[1], -g_gam[2])
    for i in range(3):
        for j in range(3):
            red[i, j] = 0.0
    # per strain k (rigidity R): R (∇²k z ∇kᵀ + ∇k (∇²k z)ᵀ + (∇k·z) ∇²k + k ∇³k[z]),
    # with ∇²k's α_o row r (∇γ for ε, −∇ε for γ) and ∇³k's t = −∇k
    for which in range(2):
        if which == 0:
            R, k, g, r, t = EA, eps, g_eps, g_gam, m_eps
        else:
            R, k, g, r, t = GA, gam, g_gam, m_eps, m_gam
        Hz = (r[0] * za, r[1] * za, r[0] * zp + r[1] * zq + r[2] * za)
        gz = g[0] * z[0] + g[1] * z[1] + g[2] * z[2]
        # ∇³k[z]: α_o row and column (t_p z_α, t_q z_α, t·z)
        third = (t[0] * za, t[1] * za, t[0] * zp + t[1] * zq + t[2] * za)
        for i in range(3):
            for j in range(3):
                red[i, j] += R * (Hz[i] * g[j] + g[i] * Hz[j] + gz * _alpha_entry(r, i, j)
                                  + k * _alpha_entry(third, i, j))
    return h, inv_h


@njit(STIFFNESS, **JIT_OPTIONS)
def toss_rule_stiffness(u, params):
    n_el = int(params[0])
    n = 3 * (n_el + 1)
    K = np.zeros((n, n))
    red = np.zeros((4, 4))
    block = np.empty((6, 6))
    red[3, 3] = params[3]
    for e in range(n_el):
        h, inv_h = _toss_stiffness_reduced(u, e, params, red)
        _beam_add(K, e, h, inv_h, red, block)
    return K


@njit(STIFFNESS_DERIVATIVE, **JIT_OPTIONS)
def toss_rule_stiffness_derivative(u, w, params):
    n_el = int(params[0])
    n = 3 * (n_el + 1)
    T = np.zeros((n, n))
    red = np.zeros((4, 4))
    block = np.empty((6, 6))
    for e in range(n_el):
        h, inv_h = _toss_derivative_reduced(u, w, e, params, red)
        _beam_add(T, e, h, inv_h, red, block)
    return T


@njit(SPARSE_STIFFNESS, **JIT_OPTIONS)
def toss_rule_stiffness_data(u, params, slots, nnz):
    """The data array (nnz,) of ``K`` in the CSR pattern whose positions ``slots`` (N_el, 36)
    gives for each element's 6 × 6 couplings."""
    data = np.zeros(nnz)
    red = np.zeros((4, 4))
    block = np.empty((6, 6))
    red[3, 3] = params[3]
    for e in range(int(params[0])):
        h, inv_h = _toss_stiffness_reduced(u, e, params, red)
        _beam_add_data(data, slots, e, h, inv_h, red, block)
    return data


@njit(SPARSE_STIFFNESS_DERIVATIVE, **JIT_OPTIONS)
def toss_rule_stiffness_derivative_data(u, w, params, slots, nnz):
    """The data array (nnz,) of ``T(u)[w]`` in the pattern of :func:`toss_rule_stiffness_data`."""
    data = np.zeros(nnz)
    red = np.zeros((4, 4))
    block = np.empty((6, 6))
    for e in range(int(params[0])):
        h, inv_h = _toss_derivative_reduced(u, w, e, params, red)
        _beam_add_data(data, slots, e, h, inv_h, red, block)
    return data


@njit(POTENTIAL_ENERGY, **JIT_OPTIONS)
def toss_rule_potential_energy(u, params):
    n_el = int(params[0])
    EA, GA, EJ = params[1], params[2], params[3]
    V = 0.0
    for e in range(n_el):
        h, inv_h, cos_hat, sin_hat = _element(params, e)
        p, q, a, chi = _beam_reduced(u, e, inv_h)
        eps, gam, _, _ = _beam_strains(p, q, a, cos_hat, sin_hat)
        V += h * (EA * eps ** 2 + GA * gam ** 2 + EJ * chi ** 2)
    return 0.5 * V


def _toss_rule_params(model):
    """``(N_el, EA, GA, EJ, h_e …, 1/h_e …, cos α̂_e …, sin α̂_e …)`` (4 + 4 N_el entries)."""
    params = np.concatenate([[model.n_elements, model.EA, model.GA, model.EJ],
                             model._h, model._inv_h, model._C, model._S])
    return np.ascontiguousarray(params, dtype=np.float64)


def toss_rule_kernels(model) -> CompiledKernels:
    """Kernels of a :class:`~hfdi.models.toss_rule.TossRule` (dense ``K`` and ``T``);
    ``params = (N_el, EA, GA, EJ, h_e …, 1/h_e …, cos α̂_e …, sin α̂_e …)`` (4 + 4 N_el
    entries)."""
    return CompiledKernels(toss_rule_force, toss_rule_stiffness,
                           toss_rule_stiffness_derivative, toss_rule_potential_energy,
                           _toss_rule_params(model), hat_load,
                           hat_load_params(model.n_dof,
                                           [(1, model.force_amplitude, model.load_time),
                                            (2, model.moment_amplitude, model.load_time)]))


def toss_rule_sparse_kernels(model) -> SparseKernels:
    """Compiled f, K and T of a large :class:`~hfdi.models.toss_rule.TossRule`:
    element loops, each element's 6 × 6 block added straight into the data
    array of the model's CSR pattern (``model.csr_from_data``). O(N_el) time,
    no temporary per element."""
    params = _toss_rule_params(model)
    slots = np.ascontiguousarray(model.element_positions(), dtype=np.int64)
    nnz = int(model._nnz)
    as_vector = np.ascontiguousarray

    def force(u):
        return toss_rule_force(as_vector(u, dtype=np.float64), params)

    def stiffness(u):
        return model.csr_from_data(
            toss_rule_stiffness_data(as_vector(u, dtype=np.float64), params, slots, nnz))

    def stiffness_derivative(u, w):
        return model.csr_from_data(toss_rule_stiffness_derivative_data(
            as_vector(u, dtype=np.float64), as_vector(w, dtype=np.float64), params, slots, nnz))

    return SparseKernels(force, stiffness, stiffness_derivative)
