"""The kernels of :class:`hfdi.LinearSystem` (``f = K u``), for its compiled path.

``params`` is ``K`` by rows (N², C order). The products are ``np.dot``, which
numpy and numba both hand to BLAS's ``dgemv``, so the two speeds agree.
"""
from __future__ import annotations

import numpy as np

from .kernels import kernel

__all__ = ["linear_force", "linear_stiffness", "linear_stiffness_derivative",
           "linear_potential_energy"]


@kernel
def _matrix(u, params):
    n = u.shape[0]
    return params[:n * n].reshape((n, n))


@kernel
def linear_force(u, params):
    return np.dot(_matrix(u, params), u)


@kernel
def linear_stiffness(u, params):
    return _matrix(u, params).copy()


@kernel
def linear_stiffness_derivative(u, w, params):
    n = u.shape[0]
    return np.zeros((n, n))


@kernel
def linear_potential_energy(u, params):
    return 0.5 * np.dot(u, np.dot(_matrix(u, params), u))
