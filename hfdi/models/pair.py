"""Central pair potentials between particles, vectorised over pairs.

For a pair potential ``φ(r)`` of the distance ``r = |d|``, ``d = x_j − x_i``,
the force on the relative coordinate is ``φ'(r) e`` (``e = d/r``), its Hessian
``H = a I + b d dᵀ`` with ``a = φ'/r`` and ``b = (φ'' − φ'/r)/r²``, and the
directional derivative of ``H w`` along the relative coordinate is
``b (w dᵀ + d wᵀ) + (b'/r)(d·w) d dᵀ + b (d·w) I``, with
``b' = (φ''' − φ''/r + φ'/r²)/r² − 2(φ'' − φ'/r)/r³``.
The particle quantities follow by scattering ``±`` these pieces onto the
blocks of particles ``i`` and ``j``.

For the small systems of the benchmarks the gather ``d = x_j − x_i`` and the
scatters are dense matrix products with constant 0/±1 matrices, built once:
one BLAS call each instead of fancy indexing, ``np.add.at`` and ``bincount``
(whose fixed costs dominate at a few dozen unknowns). Larger systems keep the
index-based gather and scatter, whose memory is linear in the pairs.
"""
from __future__ import annotations

import numpy as np

__all__ = ["PairPotential"]

_add_reduce = np.add.reduce

#: Systems whose dense scatter matrix (``n_dof² × pairs·dim²``) has at most
#: this many entries use the dense products.
DENSE_SCATTER_MAX = 1 << 18


class PairPotential:
    """Scatter pair terms onto a system of particles.

    Parameters
    ----------
    n_particles, dim : int
    i, j : array_like of int (m,)
        The particles of each pair.
    """

    def __init__(self, n_particles: int, dim: int, i, j):
        self.n_particles, self.dim = int(n_particles), int(dim)
        self.i = np.asarray(i, dtype=int)
        self.j = np.asarray(j, dtype=int)
        self.n_dof = self.n_particles * self.dim
        m, dim, n = self.i.size, self.dim, self.n_dof
        self.n_pairs = m
        eye = np.eye(self.dim)
        self._eye = eye
        d = np.arange(self.dim)
        rows_i = (self.i[:, None] * self.dim + d)            # (m, dim)
        rows_j = (self.j[:, None] * self.dim + d)

        def block(r, c):
            return (r[:, :, None] * n + c[:, None, :]).ravel()
        self._blocks = (block(rows_i, rows_i), block(rows_j, rows_j),
                        block(rows_i, rows_j), block(rows_j, rows_i))
        self._rows_i, self._rows_j = rows_i.ravel(), rows_j.ravel()
        self.dense = n * n * m * dim * dim <= DENSE_SCATTER_MAX
        if self.dense:
            # gather: d.ravel() = G u;  scatter of pair vectors: f = Gᵀ q.ravel()
            G = np.zeros((m * dim, n))
            G[np.arange(m * dim), self._rows_j] += 1.0
            G[np.arange(m * dim), self._rows_i] -= 1.0
            self._gather = G
            self._gather_t = np.ascontiguousarray(G.T)
            # scatter of pair blocks: K.ravel() = P H.ravel(), H (m, dim, dim)
            P = np.zeros((n * n, m * dim * dim))
            cols = np.arange(m * dim * dim)
            for index, sign in zip(self._blocks, (1.0, 1.0, -1.0, -1.0)):
                P[index, cols] += sign
            self._scatter_matrix = P

    # -- geometry ----------------------------------------------------------
    def relative(self, u):
        """Relative vectors ``d`` (m, dim) of the pairs."""
        if self.dense:
            return (self._gather @ u).reshape(self.n_pairs, self.dim)
        x = u.reshape(self.n_particles, self.dim)
        return x[self.j] - x[self.i]

    def geometry(self, u):
        """Relative vectors ``d`` (m, dim) and distances ``r`` (m,)."""
        d = self.relative(u)
        return d, np.sqrt(_add_reduce(d * d, axis=1))

    # -- scatter -----------------------------------------------------------
    def scatter_vectors(self, q):
        """``Σ_pairs`` of ``+q`` at particle ``j`` and ``−q`` at particle ``i``, (N,)."""
        if self.dense:
            return self._gather_t @ q.reshape(-1)
        f = np.zeros(self.n_dof)
        np.add.at(f, self._rows_j, q.ravel())
        np.add.at(f, self._rows_i, -q.ravel())
        return f

    def _scatter(self, blocks):
        n = self.n_dof
        if self.dense:
            return (self._scatter_matrix @ blocks.reshape(-1)).reshape(n, n)
        flat = blocks.ravel()
        out = np.bincount(self._blocks[0], flat, n * n)
        out += np.bincount(self._blocks[1], flat, n * n)
        out -= np.bincount(self._blocks[2], flat, n * n)
        out -= np.bincount(self._blocks[3], flat, n * n)
        return out.reshape(n, n)

    # -- force, tangent and its derivative -----------------------------------
    # Each takes the geometry (d, r) a model has already computed, or u.
    def force(self, u, dphi, geometry=None):
        """Internal force for pair forces ``dphi = φ'(r)`` (m,)."""
        d, r = self.geometry(u) if geometry is None else geometry
        return self.scatter_vectors((dphi / r)[:, None] * d)

    def stiffness(self, u, dphi, ddphi, geometry=None):
        """Tangent for ``φ'`` and ``φ''`` given per pair."""
        d, r = self.geometry(u) if geometry is None else geometry
        a = dphi / r
        b = (ddphi - a) / (r * r)
        H = (b[:, None] * d)[:, :, None] * d[:, None, :]             # b d dᵀ
        H.reshape(self.n_pairs, -1)[:, ::self.dim + 1] += a[:, None]  # + a I
        return self._scatter(H)

    def stiffness_derivative(self, u, w, dphi, ddphi, dddphi, geometry=None):
        """``d(K(u) w)/du`` for the first three derivatives of ``φ`` given per pair.

        With ``x = b w_d``, ``s = d·w_d`` and ``y = x + (b_r s / r) d``, ``b_r``
        the derivative of ``b`` by ``r``, the block is ``x dᵀ + d yᵀ + b s I``.
        """
        d, r = self.geometry(u) if geometry is None else geometry
        wd = self.relative(w)
        s = _add_reduce(d * wd, axis=1)
        r2 = r * r
        t = ddphi - dphi / r
        b = t / r2
        db = (dddphi - ddphi / r + dphi / r2) / r2 - 2.0 * t / (r2 * r)
        x = b[:, None] * wd
        y = x + (db * s / r)[:, None] * d
        Td = x[:, :, None] * d[:, None, :]
        Td += d[:, :, None] * y[:, None, :]
        Td.reshape(self.n_pairs, -1)[:, ::self.dim + 1] += (b * s)[:, None]
        return self._scatter(Td)
