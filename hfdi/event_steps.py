"""How an :class:`~hfdi.Integrator` takes its steps with event functions.

:class:`EventSteps` is a part of :class:`~hfdi.Integrator` (a base class of
it). The steps run as without events, compiled or in Python, in calls of many
steps; the accepted steps of a call are then scanned for zeros of the event
functions (:class:`hfdi.events.Events`). A zero that changes the run — a
terminal event's last allowed zero, or one where ``on_event`` resets the
state — sends the integrator back to the start of the call (its saved state:
the steps are taken again exactly), forward over the steps before the one
that holds the zero, and on to the zero's time, landing there as on any stop
time. There it ends (``Status.TERMINATED``) or restarts from the reset state
as after a load breakpoint: no step history, the predictor and the first
step's choice anew, ``f``, ``p`` and ``a`` from the model, and the energy the
reset added or took counted as work done on the system (Eq. 41), so that the
energy balance does not report it as numerical dissipation
(docs/algorithm.md, "Events").
"""
from __future__ import annotations


import numpy as np

from . import run_records
from .evaluation import ModelError
from .events import EventError, Events
from .messages import Status

__all__ = ["EventSteps"]

#: The keys of a block of rows (``advance(rows=)``).
_ROW_KEYS = ("t", "u", "v", "a", "step_size", "iterations", "energy_increment", "total_energy",
             "external_work", "global_error")


def _joined(blocks):
    if not blocks:
        return None
    if len(blocks) == 1:
        return blocks[0]
    return {key: np.concatenate([b[key] for b in blocks]) for key in _ROW_KEYS}


def _head(rows, j):
    return {key: value[:j] for key, value in rows.items()}


class EventSteps:
    """The steps of an :class:`~hfdi.Integrator` that has event functions."""

    def _setup_events(self, events, on_event) -> None:
        """``events`` and ``on_event`` of the constructor, checked; the event
        functions evaluated at the initial state (a :class:`EventError`, a
        ``ValueError``, names the one that fails there)."""
        if on_event is not None and not callable(on_event):
            raise ValueError(f"on_event must be callable as on_event(t, u, v, which) -> "
                             f"(u, v) or None, got {on_event!r}")
        if events is None:
            if on_event is not None:
                raise ValueError("on_event needs events: give the event functions whose "
                                 "zeros it answers")
            self._events = None
            self._on_event = None
            return
        self._events = Events(events)
        self._on_event = on_event
        state = self.state
        self._events.start(state.t, state.u, state.v)

    # -- what the events found ---------------------------------------------------------
    @property
    def terminated(self) -> bool:
        """Whether a terminal event ended the run (``Status.TERMINATED``)."""
        return self._run.status == Status.TERMINATED

    def _event_arrays(self, which):
        if self._events is None:
            return None
        return self._events.arrays(self.ev.n)[which]

    @property
    def t_events(self):
        """Per event function, the times of its zeros so far (``None`` without events)."""
        return self._event_arrays(0)

    @property
    def u_events(self):
        """Per event function, ``u`` at its zeros (k, N) (by the dense output)."""
        return self._event_arrays(1)

    @property
    def v_events(self):
        """Per event function, ``v`` at its zeros (k, N) (by the dense output)."""
        return self._event_arrays(2)

    # -- stepping ------------------------------------------------------------------------
    def _take_steps(self, t_stop: float, max_accepted: int) -> None:
        if self._events is None:
            self._steps(t_stop, max_accepted)
        else:
            self._event_steps(t_stop, max_accepted)

    def _event_steps(self, t_stop, max_accepted):
        """:meth:`_steps` with the event functions watched (module docstring)."""
        from .integrator import ROWS_PER_CALL, STEPS_PER_CALL
        if not self._vec.row_t.shape[0]:
            self._vec = self._vec._replace(**run_records.row_arrays(self.ev.n, ROWS_PER_CALL))
            self._refresh_compiled()
        consumer = self._rows
        start = self.state
        saved = self.get_state()
        blocks = []
        self._rows = blocks.append
        try:
            # at most a call of the stepping code that fills no row array:
            # taken again exactly, and rewinding costs at most that
            self._steps(t_stop, min(max_accepted, (ROWS_PER_CALL - 2) // 2))
        finally:
            self._rows = consumer
        rows = _joined(blocks)
        if rows is None:
            return
        try:
            stop = self._scan(start, rows)
        except EventError as exc:
            # the steps of this call are not kept: its start is the last
            # state whose events are known
            cpu = self._run_cpu
            self._restore(saved)
            self._run_cpu = cpu
            self._run.status = int(Status.MODEL_ERROR)
            self._message = f"t = {start.t:.10g}: {exc}"
            return
        if stop is None:
            if consumer is not None:
                consumer(rows)
            return
        j, crossing, reset = stop
        # back to the call's start, forward over the steps before the zero's
        cpu = self._run_cpu
        self._restore(saved)
        self._run_cpu = cpu
        accepted = int(np.count_nonzero(rows["step_size"][:j] > 0))
        if accepted:
            self._rows = None
            try:
                self._steps(t_stop, accepted)
            finally:
                self._rows = consumer
            if self.t != rows["t"][j - 1] or self.failed:     # pragma: no cover - guard
                raise AssertionError("the steps taken again did not repeat the first ones")
        if consumer is not None and j:
            consumer(_head(rows, j))
        while self.t < crossing.t and not self.failed:
            self._steps(crossing.t, STEPS_PER_CALL)
        if self.failed:
            return
        self._at_event(crossing, reset)

    def _scan(self, start, rows):
        """The first zero in ``rows`` that changes the run: ``(row, crossing, reset
        state or None)``, or ``None``; the zeros before it are recorded, and
        the events' values moved on. The functions are evaluated at every
        row; only the steps where one changes sign (or starts or ends at
        zero) are looked into."""
        events = self._events
        t, u, v, a = rows["t"], rows["u"], rows["v"], rows["a"]
        G = events.table(t, u, v)
        left = np.vstack([events.g[None], G[:-1]])
        look = events.active(left, G).any(axis=1) | (left == 0).any(axis=1)
        look &= rows["step_size"] > 0                 # a restart row: the same t, u, v
        moved_to = -1                                 # the row the events' values are at
        for j in np.flatnonzero(look):
            if moved_to != j - 1:
                events.moved(G[j - 1])
            if j == 0:
                t0, u0, v0, a0 = start.t, start.u, start.v, start.a
            else:
                t0, u0, v0, a0 = t[j - 1], u[j - 1], v[j - 1], a[j - 1]
            counted = []
            for crossing in events.crossings(t0, u0, v0, a0, t[j], u[j], v[j], a[j], G[j]):
                last = events.record(crossing)
                reset = self._answer(crossing)
                if last or reset is not None:
                    return j, crossing, reset
                if crossing.t == t[j]:
                    counted.append(crossing.index)
            events.moved(G[j], counted)
            moved_to = j
        if moved_to != t.size - 1:
            events.moved(G[-1])
        return None

    def _answer(self, crossing):
        """``on_event``'s reset state for ``crossing`` (checked), or ``None``."""
        if self._on_event is None:
            return None
        i, t = crossing.index, crossing.t
        try:
            answer = self._on_event(t, crossing.u.copy(), crossing.v.copy(), i)
        except Exception as exc:
            raise EventError(f"on_event raised {type(exc).__name__}: {exc} at the zero of "
                             f"events[{i}] at t = {t!r}") from exc
        if answer is None:
            return None
        n = self.ev.n
        try:
            u, v = answer
            u = np.array(u, dtype=float).reshape(n)
            v = np.array(v, dtype=float).reshape(n)
        except (TypeError, ValueError):
            raise EventError(f"on_event must return None or (u, v), two arrays of {n} "
                             f"values, got {answer!r} at the zero of events[{i}] at "
                             f"t = {t!r}") from None
        if not (np.isfinite(u).all() and np.isfinite(v).all()):
            raise EventError(f"on_event returned a state that is not finite at the zero of "
                             f"events[{i}] at t = {t!r}: u = {u}, v = {v}")
        return u, v

    def _at_event(self, crossing, reset):
        """At the zero's time (landed there): end the run, or reset and restart."""
        events, run = self._events, self._run
        i, t = crossing.index, crossing.t
        state = self.state
        try:
            g = events.values(t, state.u, state.v)
        except EventError as exc:
            run.status = int(Status.MODEL_ERROR)
            self._message = f"t = {t:.10g}: {exc}"
            return
        if reset is None:
            g[i] = 0.0
            events.moved(g, [i])
            run.status = int(Status.TERMINATED)
            self._message = (f"t = {t:.10g}: events[{i}] ended the run (its zero number "
                             f"{int(events.count[i])}, terminal)")
            return
        try:
            self._reset_state(*reset)
        except ModelError as exc:
            run.status = int(Status.MODEL_ERROR)
            self._message = f"t = {t:.10g}: after on_event's reset: {exc}"
            return
        after = self.state
        try:
            g = events.values(t, after.u, after.v)
        except EventError as exc:
            run.status = int(Status.MODEL_ERROR)
            self._message = f"t = {t:.10g}: after on_event's reset: {exc}"
            return
        # the reset is at the zero that made it (to the landing's rounding):
        # that zero counts once, and the next step starts from the side the
        # function then leaves to (Events.crossings)
        g[i] = 0.0
        events.moved(g, [i])

    def _reset_state(self, u, v) -> None:
        """The current state becomes ``(t, u, v)`` with ``f``, ``p`` and ``a``
        from the model; the energy the jump adds is work done on the system;
        the next step starts afresh (:class:`ModelError` when the model
        fails at the new state; the integrator is then left at the old one)."""
        run, vec, ev = self._run, self._vec, self.ev
        before = self.get_state()
        energy_before = run.potential + ev.kinetic_energy(vec.v)
        vec.u[:], vec.v[:] = u, v
        try:
            potential = float(ev.potential_energy(vec.u))
            self._refresh(new_force=True)
        except ModelError:
            self._restore(before)
            raise
        except Exception as exc:
            self._restore(before)
            raise ModelError(f"the model fails at the reset state: {type(exc).__name__}: "
                             f"{exc}") from None
        finally:
            self._absorb_counts()
        energy_after = potential + ev.kinetic_energy(vec.v)
        run.potential = potential
        run.work += energy_after - energy_before
        run.energy_scale = max(run.energy_scale, abs(energy_after))
        run.has_previous = False
        run.first_step_pending = not self.fixed
        if self._rows is not None:
            n = ev.n
            self._rows({"t": np.array([run.t]), "u": vec.u.copy()[None],
                        "v": vec.v.copy()[None], "a": vec.a.copy()[None],
                        "step_size": np.zeros(1), "iterations": np.zeros(1, dtype=int),
                        "energy_increment": np.zeros(1), "total_energy": np.array([
                            energy_after]), "external_work": np.array([run.work]),
                        "global_error": vec.global_error.copy().reshape(1, 2 * n)})
