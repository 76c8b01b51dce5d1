"""Dense output: Hermite interpolants on (u, v, a) at the step ends.

Every scheme gives, at the end of each step, a displacement, a velocity and an
acceleration in equilibrium. ``u`` is interpolated by the quintic Hermite
interpolant that matches all three at both ends (``C²`` across steps, error
``O(h⁶ u⁽⁶⁾)`` on exact data), ``v`` by the cubic Hermite interpolant of
``(v, a)`` at both ends (error ``h⁴ max|u⁽⁵⁾| / 384`` on exact data).

``v`` is not the quintic's derivative, which divides the step's local error
of ``u`` by ``h``: docs/algorithm.md, "Dense output", gives the decision.
"""
from __future__ import annotations

import numpy as np

from . import checks

__all__ = ["hermite_quintic", "hermite_cubic", "interpolate_state", "Solution"]


def hermite_quintic(t_nodes, u, v, a, t):
    """Quintic Hermite interpolation of ``u`` with ``u' = v``, ``u'' = a`` at the nodes.

    On each interval ``[t_k, t_k+1]`` the interpolant ``P`` matches ``u``,
    ``v`` and ``a`` at both ends. Its error is at most
    ``h⁶ max|u⁽⁶⁾| / 46080`` in ``u``, ``O(h⁵ u⁽⁶⁾)`` in ``P'`` and
    ``O(h⁴ u⁽⁶⁾)`` in ``P''``.

    Parameters
    ----------
    t_nodes : ndarray (K,), non-decreasing, K >= 2
    u, v, a : ndarray (K, N)
    t : ndarray (n,), inside ``[t_nodes[0], t_nodes[-1]]``

    Returns
    -------
    P, dP, ddP : ndarray (n, N)
        ``P(t)``, ``P'(t)`` and ``P''(t)``.
    """
    return _quintic(t_nodes, u, v, a, t, True)


def _quintic(t_nodes, u, v, a, t, derivatives):
    """:func:`hermite_quintic`; ``P`` alone (``None`` for the derivatives)
    without ``derivatives``: half the work, which a single time's event
    search pays in numpy's calls, not in arithmetic."""
    k, h, s = _intervals(t_nodes, t)
    s2 = s * s
    s3 = s2 * s
    s4 = s3 * s
    s5 = s4 * s
    # basis of value, slope and curvature at the left (0) and right (1) ends
    # (the left value's, 1 - h01, is folded into u0 + h01 (u1 - u0)) ...
    h10 = s - 6 * s3 + 8 * s4 - 3 * s5
    h20 = 0.5 * s2 - 1.5 * s3 + 1.5 * s4 - 0.5 * s5
    h01 = 10 * s3 - 15 * s4 + 6 * s5
    h11 = -4 * s3 + 7 * s4 - 3 * s5
    h21 = 0.5 * s3 - s4 + 0.5 * s5
    u0, u1 = u[k], u[k + 1]
    v0, v1 = v[k] * h, v[k + 1] * h
    a0, a1 = a[k] * h * h, a[k + 1] * h * h
    du = u1 - u0
    P = u0 + h10 * v0 + h20 * a0 + h01 * du + h11 * v1 + h21 * a1
    if not derivatives:
        return P, None, None
    # ... its first derivatives in s ...
    d00 = -30 * s2 + 60 * s3 - 30 * s4
    d10 = 1 - 18 * s2 + 32 * s3 - 15 * s4
    d20 = s - 4.5 * s2 + 6 * s3 - 2.5 * s4
    d11 = -12 * s2 + 28 * s3 - 15 * s4
    d21 = 1.5 * s2 - 4 * s3 + 2.5 * s4
    # ... and second derivatives in s
    c00 = -60 * s + 180 * s2 - 120 * s3
    c10 = -36 * s + 96 * s2 - 60 * s3
    c20 = 1 - 9 * s + 18 * s2 - 10 * s3
    c11 = -24 * s + 84 * s2 - 60 * s3
    c21 = 3 * s - 12 * s2 + 10 * s3
    dP = (-d00 * du + d10 * v0 + d20 * a0 + d11 * v1 + d21 * a1) / h
    ddP = (-c00 * du + c10 * v0 + c20 * a0 + c11 * v1 + c21 * a1) / (h * h)
    return P, dP, ddP


def _intervals(t_nodes, t):
    """For each time of ``t``: the interval ``k`` of ``t_nodes`` holding it, its
    length ``h`` and the position ``s`` in it, (n, 1) each but ``k``. A time
    given twice among the nodes (a jump of the acceleration) belongs to the
    interval after it; the last node, given twice, to the state that reached
    it (``s = 0`` on the zero-length interval)."""
    t_nodes = np.asarray(t_nodes, dtype=float)
    t = np.asarray(t, dtype=float)
    k = np.clip(np.searchsorted(t_nodes, t, side="right") - 1, 0, t_nodes.size - 2)
    h = (t_nodes[k + 1] - t_nodes[k])[:, None]
    empty = h == 0.0
    h = np.where(empty, 1.0, h)
    s = np.where(empty, 0.0, (t - t_nodes[k])[:, None] / h)
    return k, h, s


def hermite_cubic(t_nodes, y, dy, t):
    """Cubic Hermite interpolation of ``y`` with ``y' = dy`` at the nodes.

    Its error on each interval is at most ``h⁴ max|y⁽⁴⁾| / 384``.

    Parameters
    ----------
    t_nodes : ndarray (K,), non-decreasing, K >= 2
    y, dy : ndarray (K, N)
    t : ndarray (n,), inside ``[t_nodes[0], t_nodes[-1]]``

    Returns
    -------
    ndarray (n, N)
    """
    k, h, s = _intervals(t_nodes, t)
    s2 = s * s
    s3 = s2 * s
    h10 = s - 2 * s2 + s3
    h01 = 3 * s2 - 2 * s3
    h11 = s3 - s2
    y0 = y[k]
    return y0 + h01 * (y[k + 1] - y0) + h10 * (h * dy[k]) + h11 * (h * dy[k + 1])


def interpolate_state(t_nodes, u, v, a, t):
    """``u`` and ``v`` between step ends (the module's rule): ``u`` by
    :func:`hermite_quintic` on ``(u, v, a)``, ``v`` by :func:`hermite_cubic` on
    ``(v, a)``.

    Parameters
    ----------
    t_nodes : ndarray (K,), non-decreasing, K >= 2
        A time given twice is a jump of the acceleration.
    u, v, a : ndarray (K, N)
    t : ndarray (n,), inside ``[t_nodes[0], t_nodes[-1]]``

    Returns
    -------
    u, v : ndarray (n, N)
    """
    P, _, _ = _quintic(t_nodes, u, v, a, t, False)
    return P, hermite_cubic(t_nodes, v, a, t)


class Solution:
    """The continuous solution of a run: ``u`` and ``v`` anywhere in ``[t[0], t[-1]]``.

    Parameters
    ----------
    t : ndarray (K,), non-decreasing, K >= 1
        Step ends (the initial time first). A time given twice is a jump of
        the acceleration (a load jump): the interval before it ends with the
        first state, the one after starts with the second.
    u, v, a : ndarray (K, N)
        The states there.
    global_error : ndarray (K, 2N), optional
        The estimated global error there (:attr:`hfdi.Result.global_error`).
    """

    def __init__(self, t, u, v, a, global_error=None):
        self.t = np.asarray(t, dtype=float)
        self.u, self.v, self.a = np.asarray(u), np.asarray(v), np.asarray(a)
        self._global_error = None if global_error is None else np.asarray(global_error)
        if self.t.ndim != 1 or self.t.size < 1 or np.any(np.diff(self.t) < 0):
            raise ValueError("Solution: t must be a non-empty, non-decreasing 1-D array")

    @property
    def t_span(self):
        return float(self.t[0]), float(self.t[-1])

    def _times(self, t):
        """``(times (n,), scalar)`` of ``t``, checked against the run's interval."""
        times = checks.real_array(t)
        if times is None:
            raise ValueError(f"t must be real times in the run's interval, got {t!r:.80}")
        if times.ndim > 1:
            raise ValueError(f"t must be a time or a 1-D array of times, got shape {times.shape}")
        scalar = times.ndim == 0
        times = np.atleast_1d(times)
        t0, t1 = self.t_span
        if not np.all(np.isfinite(times)) or times.size and (times.min() < t0 or
                                                             times.max() > t1):
            raise ValueError(f"t must lie in the run's interval [{t0!r}, {t1!r}], got "
                             f"{t!r}" if scalar else
                             f"t must lie in the run's interval [{t0!r}, {t1!r}], got values "
                             f"in [{times.min()!r}, {times.max()!r}]")
        return times, scalar

    def global_error(self, t):
        """The estimated global error of ``(u, v)`` at ``t``: linear between the
        step ends (it changes by a step's local error and its propagation
        over a step, both small against itself).

        Returns
        -------
        ndarray (2N,) for a scalar ``t``, else (n, 2N)
        """
        if self._global_error is None:
            raise ValueError("this Solution was made without the global error estimate")
        times, scalar = self._times(t)
        g = self._global_error
        if self.t.size == 1:
            out = np.repeat(g[:1], times.size, axis=0)
        else:
            # the right end of a repeated time (a load jump) holds the same estimate
            i = np.clip(np.searchsorted(self.t, times, side="right") - 1, 0, self.t.size - 2)
            t0, t1 = self.t[i], self.t[i + 1]
            width = t1 - t0
            w = np.divide(times - t0, width, out=np.zeros_like(times), where=width > 0)
            out = g[i] + w[:, None] * (g[i + 1] - g[i])
        return out[0] if scalar else out

    def evaluate(self, t):
        """``u(t)`` and ``v(t)`` by :func:`interpolate_state`.

        Parameters
        ----------
        t : float or array_like (n,)
            Times in ``[t[0], t[-1]]``.

        Returns
        -------
        u, v : ndarray (N,) for a scalar ``t``, else (n, N)

        Raises
        ------
        ValueError
            For a time outside the run or not finite.
        """
        times, scalar = self._times(t)
        if self.t.size == 1:
            u = np.repeat(self.u[:1], times.size, axis=0)
            v = np.repeat(self.v[:1], times.size, axis=0)
        else:
            u, v = interpolate_state(self.t, self.u, self.v, self.a, times)
        return (u[0], v[0]) if scalar else (u, v)

    __call__ = evaluate

    def __repr__(self):
        return f"Solution(t_span={self.t_span}, steps={self.t.size - 1})"
