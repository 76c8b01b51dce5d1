"""Events: zero crossings of functions of the state, found between step ends.

An event function is ``g(t, u, v) -> float``, with ``solve_ivp``'s optional
attributes ``terminal`` (``True`` ends the run at the first zero, an integer
``k`` at the ``k``-th) and ``direction`` (``+1`` only where ``g`` rises
through zero, ``−1`` only where it falls, ``0`` both). After each accepted
step ``g`` is evaluated at the step's end; a change of sign (or a zero at the
end) is located on the step's dense output (:mod:`hfdi.dense`, the quintic
Hermite of ``u`` and the cubic of ``v``) by Brent's bracketing method to
within ``4ε`` of ``t``, as ``solve_ivp`` does. Several zeros in one step are
taken in time order. A zero exactly at ``t0`` counts when ``g`` then leaves
zero in the event's direction (as ``solve_ivp``); a zero exactly at a step
end counts once, in the step that reaches it. A zero held over an interval
(``max(t − 1, 0)``) is one zero: counted where ``g`` reaches it, or, where
it was not counted there (a run that starts on it, or the event's
direction did not take it), where ``g`` leaves it in the event's
direction; both found by bisection (Brent's method needs a change of sign). A change of sign and back
within one step is not seen (as in every method that samples ``g`` at step
ends): a step no longer than the time ``g`` stays on one side is the user's
to ask for (``max_step``).

:class:`Events` keeps the functions, their last values, the counts and the
events found; :class:`~hfdi.Integrator` asks it for the zeros of each step
and decides what they do (docs/algorithm.md, "Events").
"""
from __future__ import annotations

import math
import numbers

import numpy as np

from .dense import interpolate_state

__all__ = ["Events", "EventError", "Crossing", "ROOT_TOLERANCE", "LEAVING", "NEARER"]

#: Brent's absolute and relative tolerance on ``t`` (``solve_ivp``'s).
ROOT_TOLERANCE = 4.0 * np.finfo(float).eps
#: Where, as a share of the step, a function that starts it at a counted zero
#: is first looked at: far enough for the motion to show above the zero's
#: rounding, near enough that no other zero falls before it.
LEAVING = 1e-6
#: Where a function that the first look finds back on its arrival side is
#: looked at again, as shares of the first look's distance from the zero:
#: a flight shorter than that look (a slow rebound after a reset) left to
#: the other side and came back before it.
NEARER = (1e-2, 1e-4, 1e-6)


class EventError(ValueError):
    """An event function that raised, or did not return a finite real number."""


class Crossing:
    """One zero of event function ``index`` at ``t``, the state ``u``, ``v`` there."""

    __slots__ = ("t", "index", "u", "v", "reached")

    def __init__(self, t, index, u, v, reached=False):
        # reached: where g reached a zero it may stay at (not where it left one)
        self.t, self.index, self.u, self.v, self.reached = t, index, u, v, reached

    def __repr__(self):
        return f"Crossing(t={self.t!r}, index={self.index})"


def _compiled(g) -> bool:
    """Whether ``g`` is a numba dispatcher (``@numba.njit``), without importing numba."""
    return type(g).__module__.startswith("numba.") and hasattr(g, "py_func")


_TABLE = []


def _compiled_table():
    """``table(g, t, u, v, out)``: ``out[j] = g(t[j], u[j], v[j])`` compiled (one
    specialisation per event function ``g``, as numba compiles a function for
    each function it is given)."""
    if not _TABLE:
        import numba

        @numba.njit
        def table(g, t, u, v, out):
            for j in range(t.shape[0]):
                out[j] = g(t[j], u[j], v[j])
        _TABLE.append(table)
    return _TABLE[0]


def _read_only(x):
    """A read-only copy: an event function that writes into its arguments
    cannot reach the run's arrays."""
    x = np.array(x, dtype=float)
    x.flags.writeable = False
    return x


def _as_list(events):
    if callable(events):
        return [events]
    try:
        items = list(events)
    except TypeError:
        raise ValueError(f"events must be a callable g(t, u, v) -> float or a list of them, "
                         f"got {events!r}") from None
    for i, g in enumerate(items):
        if not callable(g):
            raise ValueError(f"events[{i}] must be callable as g(t, u, v) -> float, got {g!r}")
    return items


def _terminal(i, g):
    """The count of zeros that ends the run (``inf``: never)."""
    value = getattr(g, "terminal", False)
    if isinstance(value, (bool, np.bool_)):
        return 1.0 if value else math.inf
    if isinstance(value, numbers.Integral) and value >= 1:
        return float(value)
    raise ValueError(f"events[{i}].terminal must be True, False or an integer >= 1 (the "
                     f"count of zeros that ends the run), got {value!r}")


def _direction(i, g):
    value = getattr(g, "direction", 0)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real) \
            or not math.isfinite(value):
        raise ValueError(f"events[{i}].direction must be -1, 0 or +1 (its sign is used), got "
                         f"{value!r}")
    return float(np.sign(value))


class Events:
    """The event functions of a run and what they found.

    Parameters
    ----------
    events : callable or sequence of callables
        ``g(t, u, v) -> float``; attributes ``terminal`` and ``direction`` as
        in ``solve_ivp`` (module docstring).
    """

    def __init__(self, events):
        self.functions = _as_list(events)
        self.direction = np.array([_direction(i, g) for i, g in enumerate(self.functions)])
        self.limit = np.array([_terminal(i, g) for i, g in enumerate(self.functions)])
        m = len(self.functions)
        self.count = np.zeros(m, dtype=int)
        self.t_events = [[] for _ in range(m)]
        self.u_events = [[] for _ in range(m)]
        self.v_events = [[] for _ in range(m)]
        #: ``g`` at the time ``t`` (the current time), and whether a zero there
        #: was counted
        self.g = np.full(m, math.nan)
        self.counted_zero = np.zeros(m, dtype=bool)
        #: a zero counted where g reached it, g at zero at every step end since:
        #: leaving it is no new crossing
        self.held = np.zeros(m, dtype=bool)
        self._reached = np.zeros(m, dtype=bool)
        self.t = math.nan

    def __len__(self):
        return len(self.functions)

    def value(self, i, t, u, v) -> float:
        """``g_i(t, u, v)`` as a float; :class:`EventError` naming ``events[i]`` when
        it raises or gives no finite real number."""
        try:
            value = self.functions[i](t, u, v)
        except Exception as exc:
            raise EventError(f"events[{i}] raised {type(exc).__name__}: {exc} at t = {t!r}") \
                from exc
        try:
            if isinstance(value, (str, bytes, complex, np.complexfloating)) \
                    or np.ndim(value) != 0:
                raise TypeError
            value = float(value)
        except Exception:
            raise EventError(f"events[{i}] must return a real number, got {value!r} at "
                             f"t = {t!r}") from None
        if not math.isfinite(value):
            raise EventError(f"events[{i}] returned {value} at t = {t!r}; an event function "
                             f"must be finite wherever the run goes")
        return value

    def values(self, t, u, v) -> np.ndarray:
        """Every function at ``(t, u, v)`` (read-only copies are passed)."""
        u, v = _read_only(u), _read_only(v)
        return np.array([self.value(i, t, u, v) for i in range(len(self))])

    def table(self, t, u, v):
        """Every function at every row of ``t`` (k,), ``u``, ``v`` (k, N):
        ``(G (k, m), row, error)``, ``row`` the first row where a function
        failed (``k`` when none did; the rows from it on are not valid) and
        ``error`` its :class:`EventError` (or ``None``). A function compiled
        with numba (``@numba.njit``) is evaluated over the rows in one
        compiled loop; any other, a Python call per row."""
        u, v = _read_only(u), _read_only(v)
        t = np.ascontiguousarray(t, dtype=float)
        out = np.empty((t.size, len(self)))
        failed, error = t.size, None
        for i, g in enumerate(self.functions):
            column = out[:, i]
            if _compiled(g):
                try:
                    _compiled_table()(g, t, u, v, column)
                except Exception as exc:
                    # which row raised is not known: the first
                    return out, 0, EventError(
                        f"events[{i}] raised {type(exc).__name__}: {exc} (compiled, "
                        f"between t = {t[0]!r} and {t[-1]!r})")
                bad = np.flatnonzero(~np.isfinite(column[:failed]))
                if bad.size:
                    failed, error = int(bad[0]), EventError(
                        f"events[{i}] returned {column[bad[0]]} at t = {t[bad[0]]!r}; an "
                        f"event function must be finite wherever the run goes")
                continue
            for j in range(failed):
                try:
                    column[j] = self.value(i, float(t[j]), u[j], v[j])
                except EventError as exc:
                    failed, error = j, exc
                    break
        return out, failed, error

    def start(self, t, u, v) -> None:
        """The values at the initial (or a restored) state; no zero counted there yet."""
        self.g = self.values(t, u, v)
        self.counted_zero[:] = False
        self.held[:] = False
        self.t = float(t)

    def resume(self, t, g, counted) -> None:
        """At a restored state: the values ``g`` the run held at ``t`` and the
        zeros ``counted`` there (:meth:`counted_codes`)."""
        self.g = np.array(g, dtype=float)
        codes = np.asarray(counted)
        self.counted_zero = (codes == 1) | (codes == 3)
        self.held = codes >= 2
        self.t = float(t)

    def counted_codes(self) -> np.ndarray:
        """Per function, 1 for a zero counted at the current time, 2 for a held
        one counted where reached (3: both), as a state keeps them."""
        return self.counted_zero + 2.0 * self.held

    def active(self, left, right):
        """Which functions cross zero between the values ``left`` and ``right``
        (arrays (..., m)) in their direction (``solve_ivp``'s rule)."""
        up = (left <= 0) & (right >= 0)
        down = (left >= 0) & (right <= 0)
        return (up & (self.direction > 0)) | (down & (self.direction < 0)) | \
            ((up | down) & (self.direction == 0))

    def crossings(self, t0, u0, v0, a0, t1, u1, v1, a1, g1):
        """The zeros in the step from ``t0`` to ``t1`` (the states at both ends,
        ``g1`` the functions' values at ``t1``), in time order; nothing is
        recorded (:meth:`record`, :meth:`moved`)."""
        nodes = np.array([t0, t1])
        stack = (np.vstack([u0, u1]), np.vstack([v0, v1]), np.vstack([a0, a1]))

        def state(t):
            u, v = interpolate_state(nodes, *stack, np.array([t]))
            return u[0], v[0]

        # A function at zero at t0 starts the step on the side it leaves to:
        # its value just after t0 on the dense output. A zero counted at t0
        # (an event there, or a reset at it) is not counted again, but
        # leaving it and coming back within the step (a bounce's whole
        # flight) is a crossing; an uncounted zero (at the run's start)
        # counts at t0 if g leaves it in the event's direction.
        left_t = np.full(len(self), float(t0))
        left_g = self.g.copy()
        at_start = []
        # counted zeros that g, at the state the step landed at, had still to
        # reach: the first crossing ahead is that zero again
        still_ahead = set()
        after = t0 + LEAVING * (t1 - t0)
        for i in np.flatnonzero(self.g == 0):
            if not after < t1:
                continue
            leaving = self.value(i, after, *map(_read_only, state(after)))
            if not self.counted_zero[i] and leaving != 0 and \
                    self.direction[i] * leaving >= 0:
                at_start.append(int(i))
            left_t[i], left_g[i] = after, leaving
            g_start = self.value(i, t0, *map(_read_only, (u0, v0))) \
                if self.counted_zero[i] else 0.0
            if g_start * leaving > 0 and abs(leaving) < abs(g_start):
                # the landed state lies a little before the zero counted at t0
                # (its own error), and g is still on its way there: passing it
                # is no new crossing (answered by on_event, every zero of a
                # pass-through event counted twice, 2e-8 to 2e-3 s apart)
                still_ahead.add(int(i))
            if self.counted_zero[i] and leaving != 0 and self.direction[i] * leaving >= 0:
                # on the side a crossing in the event's direction ends on: a
                # flight shorter than the look (a ball sent up from the floor
                # at 1e-6 m/s) may have left to the other side and come back
                # before it, unseen (the ball then fell through the floor).
                # Only a move away from where g really is at t0 is a flight:
                # the state a step landed at lies a little off the zero (its
                # own error), on either side, and g passing on through the
                # zero from there is no new crossing
                for share in NEARER:
                    near = t0 + share * (after - t0)
                    if not near > t0:
                        break
                    g_near = self.value(i, near, *map(_read_only, state(near)))
                    if g_near * leaving < 0 and (g_start * leaving >= 0
                                                 or abs(g_near) > abs(g_start)):
                        left_t[i], left_g[i] = near, g_near
                        still_ahead.discard(int(i))     # a flight, seen nearer
                        break
        active = self.active(left_g, g1)
        # g staying at zero is no crossing
        active &= ~((left_g == 0) & (g1 == 0))
        found = [Crossing(float(t0), i, u0.copy(), v0.copy()) for i in at_start]
        for i in np.flatnonzero(active):
            if i in still_ahead:
                continue
            reached = False
            if left_g[i] == 0:
                # still at the zero at the probe, left by the step's end: a zero
                # held over a while (a clipped depth, max(t − 1, 0)); counted
                # where g leaves it, unless it was counted where g reached it
                if self.held[i]:
                    continue
                t_root, g_left = self._edge(i, left_t[i], t1, g1[i], lambda g: g == 0,
                                            state)
                if g_left * g1[i] < 0:
                    # left to the other side first: the crossing is on the way back
                    t_root = self._root(i, t_root, t1, g_left, g1[i], state)
            elif g1[i] == 0:
                # the first zero on the way, not the step's end: g may reach
                # zero before t1 and stay there
                side = math.copysign(1.0, left_g[i])
                t_root = self._edge(i, left_t[i], t1, g1[i], lambda g: side * g > 0, state)[0]
                reached = True
            else:
                t_root = self._root(i, left_t[i], t1, left_g[i], g1[i], state)
                if self.value(i, t_root, *map(_read_only, state(t_root))) == 0.0:
                    # Brent may stop anywhere on a zero held inside the step
                    side = math.copysign(1.0, left_g[i])
                    t_root = self._edge(i, left_t[i], t_root, 0.0, lambda g: side * g > 0,
                                        state)[0]
                    reached = True
            if self.counted_zero[i] and t_root <= np.nextafter(np.nextafter(t0, t1), t1):
                # within two spacings of the time of a zero counted at t0: that
                # zero, where the landed state lies a rounding of t before it
                # (at t0 = 1e5 the probe LEAVING·h rounded to t0, g read the
                # side before the crossing, and the zero was counted ten
                # times at one time, taken for a Zeno point)
                continue
            if t_root == t0:
                u, v = u0.copy(), v0.copy()
            elif t_root == t1:
                u, v = u1.copy(), v1.copy()
            else:
                u, v = state(t_root)
            found.append(Crossing(float(t_root), int(i), u, v, reached))
        found.sort(key=lambda c: (c.t, c.index))
        return found

    def _root(self, i, t0, t1, g0, g1, state):
        from scipy.optimize import brentq

        def g(t):
            # the ends' values are the step ends' own (the dense output meets
            # them there, up to rounding that could hide the bracket)
            if t == t0:
                return g0
            if t == t1:
                return g1
            return self.value(i, t, *map(_read_only, state(t)))
        return brentq(g, t0, t1, xtol=ROOT_TOLERANCE, rtol=ROOT_TOLERANCE)

    def _edge(self, i, lo, hi, g_hi, as_at_lo, state):
        """The first time in ``(lo, hi]`` where ``g_i`` is no longer as at
        ``lo`` (``as_at_lo(g)``, true at ``lo`` and false at ``hi``, where
        ``g`` is ``g_hi``), to :data:`ROOT_TOLERANCE`, and ``g`` there:
        bisection, for a zero held over an interval, where Brent's method has
        no change of sign to follow. ``hi`` exactly when ``g`` is as at
        ``lo`` until then."""
        while hi - lo > ROOT_TOLERANCE * (1.0 + abs(hi)):
            mid = lo + 0.5 * (hi - lo)
            if not lo < mid < hi:
                break
            g_mid = self.value(i, mid, *map(_read_only, state(mid)))
            if as_at_lo(g_mid):
                lo = mid
            else:
                hi, g_hi = mid, g_mid
        return hi, g_hi

    def record(self, crossing: Crossing) -> bool:
        """Count ``crossing``; whether it is a terminal event's last allowed zero."""
        i = crossing.index
        self.count[i] += 1
        self._reached[i] = crossing.reached
        self.t_events[i].append(crossing.t)
        self.u_events[i].append(crossing.u)
        self.v_events[i].append(crossing.v)
        return self.count[i] >= self.limit[i]

    def moved(self, t, g, counted=()) -> None:
        """``t`` is the current time: ``g`` there, and the events whose zero was
        counted exactly there (added to those counted before at the same
        ``t``: a restart at a load breakpoint keeps ``t``, ``u`` and ``v``)."""
        g = np.array(g, dtype=float)
        if t != self.t:
            self.counted_zero[:] = False
            # a zero counted where g reached it, and g still at it: the same
            # zero, whose leaving is no new crossing (the steps between look
            # at every zero, so g was at zero at each of their ends)
            self.held &= (self.g == 0) & (g == 0)
        self.g = g
        for i in counted:
            self.counted_zero[i] = True
            self.held[i] = self._reached[i]
        self.t = float(t)

    def snapshot(self):
        """What :meth:`rollback` returns to."""
        return (self.count.copy(), [len(x) for x in self.t_events], self.g.copy(),
                self.counted_zero.copy(), self.held.copy(), self._reached.copy(), self.t)

    def rollback(self, snapshot) -> None:
        """Forget what was recorded and moved since ``snapshot``."""
        count, sizes, g, counted, held, reached, t = snapshot
        self.count[:] = count
        for lists in (self.t_events, self.u_events, self.v_events):
            for i, size in enumerate(sizes):
                del lists[i][size:]
        self.g, self.counted_zero, self.t = g.copy(), counted.copy(), t
        self.held, self._reached = held.copy(), reached.copy()

    def arrays(self, name, n):
        """Per function, the zeros' times (``name`` ``"t"``: arrays (k,)) or
        states there (``"u"``, ``"v"``: arrays (k, N))."""
        if name == "t":
            return [np.array(t, dtype=float) for t in self.t_events]
        found = self.u_events if name == "u" else self.v_events
        return [np.array(x, dtype=float).reshape(-1, n) for x in found]
