"""Load histories of the benchmark models.

The paper's figures with the load histories of the tetrahedra and the
articulated system are lost; the project chose triangular ("hat") pulses for
both (see the models' docstrings for which data are the paper's).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["hat", "hat_breakpoints"]


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


def hat_breakpoints(t1):
    """The times where :func:`hat`'s rate jumps: ``0``, ``t1`` and ``2 t1``."""
    t1 = float(t1)
    return (0.0, t1, 2.0 * t1)
