"""Checks of user input that raise a ``ValueError`` naming the parameter, its
value and what is allowed."""
from __future__ import annotations

import math

import numpy as np

__all__ = ["real", "positive", "non_negative", "integer", "finite_array"]


def real(name: str, value, *, low=None, high=None, low_closed=False, high_closed=False) -> float:
    """``value`` as a finite float in the given range.

    The range is ``low < value < high`` (``<=`` where ``*_closed``); either
    bound may be ``None``.
    """
    parts = []
    if low is not None:
        parts.append(f"{'>=' if low_closed else '>'} {low:g}")
    if high is not None:
        parts.append(f"{'<=' if high_closed else '<'} {high:g}")
    allowed = "a finite number" + (" " + " and ".join(parts) if parts else "")
    if isinstance(value, bool):
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {allowed}, got {value!r}") from None
    ok = math.isfinite(number)
    if ok and low is not None:
        ok = number >= low if low_closed else number > low
    if ok and high is not None:
        ok = number <= high if high_closed else number < high
    if not ok:
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    return number


def positive(name: str, value) -> float:
    """A finite float ``> 0``."""
    return real(name, value, low=0.0)


def non_negative(name: str, value) -> float:
    """A finite float ``>= 0``."""
    return real(name, value, low=0.0, low_closed=True)


def integer(name: str, value, minimum: int) -> int:
    """An integer ``>= minimum`` (bools are refused)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def finite_array(name: str, value, shape, *, positive: bool = False) -> np.ndarray:
    """A float array of the given shape with finite (and, if asked, positive) entries."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an array of shape {shape} of numbers, "
                         f"got {value!r}") from None
    what = "positive finite" if positive else "finite"
    if arr.shape != tuple(shape):
        raise ValueError(f"{name} must have shape {tuple(shape)} ({what} entries), "
                         f"got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or (positive and not np.all(arr > 0)):
        raise ValueError(f"{name} must have {what} entries, got {arr.tolist()!r}")
    return arr
