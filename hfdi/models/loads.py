"""Load histories of the benchmark models.

The paper's figures with the load histories of the tetrahedra and the
articulated system are lost; the project chose triangular ("hat") pulses for
both (docs/models.md marks which data are the paper's).

A model's load is :func:`hat_load`, a kernel (:mod:`hfdi.models.kernels`):
its Python ``load(t)`` and its compiled load are that one function.
"""
from __future__ import annotations

import math

import numpy as np

from .kernels import kernel

__all__ = ["hat", "hat_load", "hat_load_params"]


def hat(t, amplitude, t1):
    """Triangular load pulse rising to ``amplitude`` at ``t1`` and back to 0 at ``2 t1``.

    ``P(t) = P t/t1`` for ``0 ≤ t ≤ t1``, ``P (2 − t/t1)`` for
    ``t1 < t ≤ 2 t1`` and ``0`` otherwise (also for ``t < 0``). The pulse is
    continuous, so its impulse is ``P t1``; its rate jumps at ``0``, ``t1``
    and ``2 t1``.

    Parameters
    ----------
    t : float or array_like
        Time(s).
    amplitude : float
        Peak value ``P``.
    t1 : float
        Rise time, > 0.

    Returns
    -------
    float or ndarray
        ``P(t)``: a float for a scalar ``t``, else an array of ``t``'s shape.

    Raises
    ------
    ValueError
        If ``t1`` is not a positive finite number.
    """
    t1 = float(t1)
    if not (math.isfinite(t1) and t1 > 0):
        raise ValueError(f"hat: t1 must be a positive finite number, got {t1!r}")
    scalar = np.ndim(t) == 0
    s = np.asarray(t, dtype=float) / t1
    # min(s, 2 − s) is the rising and the falling branch at once; clipping at 0
    # removes both t < 0 and t > 2 t1
    value = float(amplitude) * np.clip(np.minimum(s, 2.0 - s), 0.0, None)
    return float(value) if scalar else value


@kernel
def hat_load(t, load_params):
    """``p(t)`` (N,): ``load_params = (N, m, dof_1, P_1, t1_1, …, dof_m, P_m, t1_m)``,
    pulse ``k`` adding ``hat(t; P_k, t1_k)`` to ``p[dof_k]``; with no pulse the
    zero load."""
    n = int(load_params[0])
    p = np.zeros(n)
    for k in range(int(load_params[1])):
        dof = int(load_params[2 + 3 * k])
        amplitude, t1 = load_params[3 + 3 * k], load_params[4 + 3 * k]
        s = t / t1
        # hat(): amplitude · clip(min(s, 2 − s), 0, None), the same operations
        value = min(s, 2.0 - s)
        if value < 0.0:
            value = 0.0
        p[dof] += amplitude * value
    return p


def hat_load_params(n_dof, pulses=()) -> np.ndarray:
    """``load_params`` of :func:`hat_load` for ``n_dof`` degrees of freedom and the
    pulses ``[(dof, amplitude, t1), …]`` (none: the zero load)."""
    rows = [float(n_dof), float(len(pulses))]
    for dof, amplitude, t1 in pulses:
        if not 0 <= int(dof) < n_dof:
            raise ValueError(f"hat_load_params: dof must be in [0, {n_dof}), got {dof!r}")
        if not (np.isfinite(t1) and t1 > 0):
            raise ValueError(f"hat_load_params: t1 must be a positive finite number, "
                             f"got {t1!r}")
        rows += [float(dof), float(amplitude), float(t1)]
    return np.ascontiguousarray(rows, dtype=np.float64)
