"""Central pair potentials between particles, vectorised over pairs.

For a pair potential ``φ(r)`` of the distance ``r = |d|``, ``d = x_j − x_i``,
the force on the relative coordinate is ``φ'(r) e`` (``e = d/r``), its Hessian
``H = a I + b d dᵀ`` with ``a = φ'/r`` and ``b = (φ'' − φ'/r)/r²``, and the
directional derivative of ``H w`` along the relative coordinate is
``b (w dᵀ + d wᵀ) + (b'/r)(d·w) d dᵀ + b (d·w) I``, with
``b' = (φ''' − φ''/r + φ'/r²)/r² − 2(φ'' − φ'/r)/r³``.
The particle quantities follow by scattering ``±`` these pieces onto the
blocks of particles ``i`` and ``j``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["PairPotential"]


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
        eye = np.eye(self.dim)
        self._eye = eye
        # flat indices of the 4 blocks (ii, jj, ij, ji) of every pair, for np.add.at-free scatter
        d = np.arange(self.dim)
        rows_i = (self.i[:, None] * self.dim + d)            # (m, dim)
        rows_j = (self.j[:, None] * self.dim + d)
        n = self.n_dof

        def block(r, c):
            return (r[:, :, None] * n + c[:, None, :]).ravel()
        self._blocks = (block(rows_i, rows_i), block(rows_j, rows_j),
                        block(rows_i, rows_j), block(rows_j, rows_i))
        self._rows_i, self._rows_j = rows_i.ravel(), rows_j.ravel()

    def geometry(self, u):
        """Relative vectors ``d`` (m, dim) and distances ``r`` (m,)."""
        x = u.reshape(self.n_particles, self.dim)
        d = x[self.j] - x[self.i]
        return d, np.sqrt(np.einsum("pk,pk->p", d, d))

    def force(self, u, dphi):
        """Internal force for pair forces ``dphi = φ'(r)`` (m,)."""
        d, r = self.geometry(u)
        pair = (dphi / r)[:, None] * d
        f = np.zeros(self.n_dof)
        np.add.at(f, self._rows_j, pair.ravel())
        np.add.at(f, self._rows_i, -pair.ravel())
        return f

    def _scatter(self, blocks):
        n = self.n_dof
        flat = blocks.ravel()
        out = np.bincount(self._blocks[0], flat, n * n)
        out += np.bincount(self._blocks[1], flat, n * n)
        out -= np.bincount(self._blocks[2], flat, n * n)
        out -= np.bincount(self._blocks[3], flat, n * n)
        return out.reshape(n, n)

    def stiffness(self, u, dphi, ddphi):
        """Tangent for ``φ'`` and ``φ''`` given per pair."""
        d, r = self.geometry(u)
        a = dphi / r
        b = (ddphi - a) / r ** 2
        H = a[:, None, None] * self._eye + b[:, None, None] * d[:, :, None] * d[:, None, :]
        return self._scatter(H)

    def stiffness_derivative(self, u, w, dphi, ddphi, dddphi):
        """``d(K(u) w)/du`` for ``φ'``, ``φ''`` and ``φ'''`` given per pair."""
        d, r = self.geometry(u)
        wx = w.reshape(self.n_particles, self.dim)
        wd = wx[self.j] - wx[self.i]
        s = np.einsum("pk,pk->p", d, wd)
        b = (ddphi - dphi / r) / r ** 2
        db = (dddphi - ddphi / r + dphi / r ** 2) / r ** 2 - 2.0 * (ddphi - dphi / r) / r ** 3
        Td = (b[:, None, None] * (wd[:, :, None] * d[:, None, :] + d[:, :, None] * wd[:, None, :])
              + (db * s / r)[:, None, None] * d[:, :, None] * d[:, None, :]
              + (b * s)[:, None, None] * self._eye)
        return self._scatter(Td)
