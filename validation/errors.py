"""The paper's error norm (Eq. 42) of an analysis against a reference solution.

``ε_z = sqrt(∫ (z − z*)ᵀ (z − z*) dt) / sqrt(∫ z*ᵀ z* dt)`` over the analysis's
interval ``[t0, t_end]``, the integrals by the trapezoidal rule over the
analysis's own step times, and ``z*`` the reference (see
:mod:`validation.reference`) at exactly those times.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["error_norm", "error_norms", "relative_error", "estimated_error_norm"]


def _trapezoid(t, f):
    return 0.5 * float(np.sum(np.diff(t) * (f[1:] + f[:-1])))


def relative_error(t, error_squared, reference_squared) -> float:
    """``ε`` of Eq. 42 from ``|z − z*|²`` and ``|z*|²`` at the times ``t`` (n,).

    ``sqrt(∫|z − z*|² dt / ∫|z*|² dt)`` by the trapezoidal rule; ``0`` when
    both integrals vanish, ``inf`` when only the reference's does, NaN when
    either is NaN.
    """
    num = _trapezoid(t, np.asarray(error_squared, dtype=float))
    den = _trapezoid(t, np.asarray(reference_squared, dtype=float))
    if math.isnan(num) or math.isnan(den):
        return math.nan
    if den == 0.0:
        return 0.0 if num == 0.0 else math.inf
    return math.sqrt(num / den)


def error_norm(t, z, z_ref) -> float:
    """Relative error ``ε`` of Eq. 42 of a quantity ``z`` against ``z*``.

    Parameters
    ----------
    t : array_like (n,)
        The analysis's step times, non-decreasing, ``n >= 2``.
    z, z_ref : array_like (n, m) or (n,)
        The analysis's quantity and the reference's at ``t``.

    Returns
    -------
    float
        ``sqrt(∫|z − z*|² dt / ∫|z*|² dt)`` by the trapezoidal rule; ``0``
        when both integrals vanish and ``inf`` when only the reference's does.
        NaN in ``z`` gives NaN.
    """
    t = np.asarray(t, dtype=float)
    z = np.asarray(z, dtype=float)
    z_ref = np.asarray(z_ref, dtype=float)
    if z.ndim == 1:
        z = z[:, None]
    if z_ref.ndim == 1:
        z_ref = z_ref[:, None]
    if t.ndim != 1 or t.size < 2:
        raise ValueError(f"t must be 1-D with at least 2 times, got shape {t.shape}")
    if z.shape != z_ref.shape or z.ndim != 2 or z.shape[0] != t.size:
        raise ValueError(f"z and z_ref must both have shape ({t.size}, m), "
                         f"got {z.shape} and {z_ref.shape}")
    if np.any(np.diff(t) < 0):
        raise ValueError("t must be non-decreasing")
    return relative_error(t, np.sum((z - z_ref) ** 2, axis=1), np.sum(z_ref ** 2, axis=1))


def error_norms(model, result, reference) -> dict:
    """``ε`` (Eq. 42) of every quantity of interest of ``model`` for one analysis.

    Parameters
    ----------
    model : hfdi.SecondOrderSystem
        The model the analysis integrated; its :meth:`quantities` define ``z``.
    result : hfdi.Result
        The analysis: ``t`` (n,), ``u``, ``v`` (n, N). A run stopped early is
        measured over the interval it reached.
    reference : validation.reference.Reference
        Either dense over an interval containing ``result.t`` or computed at
        exactly ``result.t``.

    Returns
    -------
    dict of str to float
        Quantity name → ``ε``; NaN for every quantity when the analysis holds
        fewer than two times (a run that failed before its first step).
    """
    t = np.asarray(result.t, dtype=float)
    z = model.quantities(t, np.asarray(result.u), np.asarray(result.v))
    if t.size < 2:
        return {name: math.nan for name in z}
    u_ref, v_ref = reference.at(t)
    z_ref = model.quantities(t, u_ref, v_ref)
    return {name: error_norm(t, z[name], z_ref[name]) for name in z}


def estimated_error_norm(result) -> float:
    """``ε_u`` of Eq. 42 as the run's own global error estimate tells it,
    without a reference: ``sqrt(∫|g_u|² dt / ∫|u|² dt)``, ``g_u`` the ``u``
    columns of :attr:`hfdi.Result.global_error` (NaN where it was lost)."""
    t = np.asarray(result.t, dtype=float)
    if t.size < 2:
        return math.nan
    n = result.u.shape[1]
    g = np.asarray(result.global_error)[:, :n]
    return relative_error(t, np.sum(g ** 2, axis=1), np.sum(np.asarray(result.u) ** 2, axis=1))
