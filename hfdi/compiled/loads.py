"""Compiled loads: sums of triangular ("hat") pulses, the loads of the paper's models.

``hat_load(t, load_params)`` is :func:`hfdi.models.loads.hat` restated for
numba, summed over the pulses listed in ``load_params``; with no pulse it is
the zero load. A model with another load history writes its own kernel of
signature :data:`hfdi.compiled.signatures.LOAD` (docs/compiled.md).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .signatures import JIT_OPTIONS, LOAD

__all__ = ["hat_load", "hat_load_params"]


@njit(LOAD, **JIT_OPTIONS)
def hat_load(t, load_params):
    """``p(t)`` (N,): ``load_params = (N, m, dof_1, P_1, t1_1, …, dof_m, P_m, t1_m)``,
    pulse ``k`` adding ``hat(t; P_k, t1_k)`` to ``p[dof_k]``."""
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
