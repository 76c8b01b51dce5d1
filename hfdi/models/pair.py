"""Central pair potentials between particles: the pair terms of the kernels.

For a pair potential ``φ(r)`` of the distance ``r = |d|``, ``d = x_j − x_i``,
the force on the relative coordinate is ``φ'(r) e`` (``e = d/r``), its Hessian
``H = a I + b d dᵀ`` with ``a = φ'/r`` and ``b = (φ'' − φ'/r)/r²``, and the
directional derivative of ``H w`` along the relative coordinate is
``b (w dᵀ + d wᵀ) + (b'/r)(d·w) d dᵀ + b (d·w) I``, with
``b' = (φ''' − φ''/r + φ'/r²)/r² − 2(φ'' − φ'/r)/r³``.
The particle quantities follow by scattering ``±`` these pieces onto the
blocks of particles ``i`` and ``j``: the pair's vector goes to ``+j`` and
``−i``, its ``dim × dim`` block to ``+(i,i)``, ``+(j,j)``, ``−(i,j)``, ``−(j,i)``.

Each function is a kernel (:mod:`hfdi.models.kernels`): the particle models'
``f``, ``K`` and ``T`` call them, as plain Python and compiled alike. The
terms are scattered entry by entry as they are formed: a small array per
pair would cost an allocation, more than the pair's arithmetic.
"""
from __future__ import annotations

import math

from .kernels import kernel

__all__ = ["relative", "pair_force_add", "pair_stiffness_add", "pair_derivative_add",
           "scatter_vector", "scatter_block"]


@kernel
def relative(u, i, j, dim):
    """``(r, d)`` of the pair (i, j) in ``dim`` (2 or 3) dimensions, ``d`` a tuple."""
    d0 = u[j * dim] - u[i * dim]
    d1 = u[j * dim + 1] - u[i * dim + 1]
    r2 = 0.0
    r2 += d0 * d0
    r2 += d1 * d1
    if dim == 2:
        return math.sqrt(r2), (d0, d1, 0.0)
    d2 = u[j * dim + 2] - u[i * dim + 2]
    r2 += d2 * d2
    return math.sqrt(r2), (d0, d1, d2)


@kernel
def scatter_vector(f, i, j, dim, q):
    """``f += q`` at particle ``j``, ``−q`` at particle ``i``."""
    for k in range(dim):
        f[j * dim + k] += q[k]
        f[i * dim + k] -= q[k]


@kernel(inline=True)
def scatter_entry(K, i, j, dim, a, b, h):
    """Entry ``(a, b)`` of a pair's block, ``h``, to +(i,i), +(j,j), −(i,j), −(j,i)."""
    K[i * dim + a, i * dim + b] += h
    K[j * dim + a, j * dim + b] += h
    K[i * dim + a, j * dim + b] -= h
    K[j * dim + a, i * dim + b] -= h


@kernel
def scatter_block(K, i, j, dim, H):
    """The block ``H`` (dim, dim) of the pair (i, j) scattered into ``K``."""
    for a in range(dim):
        for b in range(dim):
            scatter_entry(K, i, j, dim, a, b, H[a, b])


@kernel
def pair_force_add(f, i, j, dim, d, r, dphi):
    """``f += (φ'/r) d`` at j, minus at i."""
    c = dphi / r
    for k in range(dim):
        q = c * d[k]
        f[j * dim + k] += q
        f[i * dim + k] -= q


@kernel
def pair_stiffness_add(K, i, j, dim, d, r, dphi, ddphi):
    """``K += scatter(a I + b d dᵀ)``, ``a = φ'/r``, ``b = (φ'' − a)/r²``."""
    a = dphi / r
    b = (ddphi - a) / (r * r)
    for p in range(dim):
        for q in range(dim):
            h = (b * d[p]) * d[q]
            if p == q:
                h += a
            scatter_entry(K, i, j, dim, p, q, h)


@kernel
def pair_derivative_add(T, i, j, dim, d, r, wd, dphi, ddphi, dddphi):
    """``T += scatter(x dᵀ + d yᵀ + b s I)`` with ``x = b w_d``, ``s = d·w_d`` and
    ``y = x + (b' s / r) d``."""
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
            scatter_entry(T, i, j, dim, p, q, h)
