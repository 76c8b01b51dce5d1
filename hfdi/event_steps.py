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
as after a load breakpoint: no step history (the predictor starts anew),
``f``, ``p`` and ``a`` from the model, and the energy the
reset added or took counted as work done on the system (Eq. 41), so that the
energy balance does not report it as numerical dissipation
(docs/algorithm.md, "Events").
"""
from __future__ import annotations


import math

import numpy as np

from . import run_records
from .evaluation import ModelError, State
from .events import Crossing, EventError, Events
from .messages import Status
from .result import Rows

__all__ = ["EventSteps"]


def _joined(blocks, n):
    """The blocks of rows of a call as one block (``None`` without rows)."""
    if not blocks:
        return None
    if len(blocks) == 1:
        return blocks[0]
    rows = Rows(n)
    for block in blocks:
        rows.extend(block)
    return rows.arrays()


def _head(rows, j):
    return {key: value[:j] for key, value in rows.items()}


class EventSteps:
    """The steps of an :class:`~hfdi.Integrator` that has event functions."""

    def _setup_events(self, events, on_event) -> None:
        """``events`` and ``on_event`` of the constructor, checked; the event
        functions evaluated at the initial state (a :class:`EventError`, a
        ``ValueError``, names the one that fails there)."""
        if events is None and getattr(self.system, "events", None):
            # the model's own (docs/user-models.md, "Events"), with its resets
            events = self.system.events
            if on_event is None:
                on_event = getattr(self.system, "on_event", None)
        elif events is not None and not callable(events) and hasattr(events, "__len__") \
                and len(events) == 0:
            events = None                    # none, not even the model's
        self._pause_at_events = False        # advance(until_event=True)
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
        from .controller import core_kind
        from .core.state import CUSTOM
        if core_kind(self.controller) == CUSTOM:
            raise ValueError(f"events need one of the built-in controllers (error control, "
                             f"the iteration count or a fixed step); controller "
                             f"{type(self.controller).__name__} steps on its own")
        self._events = Events(events)
        self._on_event = on_event
        self._forget_answered()
        state = self.state
        self._events.start(state.t, state.u, state.v)

    # -- what the events found ---------------------------------------------------------
    @property
    def terminated(self) -> bool:
        """Whether a terminal event ended the run (``Status.TERMINATED``)."""
        return self._run.status == Status.TERMINATED

    def _event_arrays(self, name):
        if self._events is None:
            return None
        return self._events.arrays(name, self.ev.n)

    @property
    def event_count(self):
        """Per event function, the count of its zeros so far (an int array, a
        copy; ``None`` without events)."""
        return None if self._events is None else self._events.count.copy()

    @property
    def last_event_times(self):
        """Per event function, the time of its last zero (NaN before the first;
        ``None`` without events)."""
        if self._events is None:
            return None
        return np.array([x[-1] if x else math.nan for x in self._events.t_events])

    @property
    def t_events(self):
        """Per event function, the times of its zeros so far (``None`` without events)."""
        return self._event_arrays("t")

    @property
    def u_events(self):
        """Per event function, ``u`` at its zeros (k, N) (by the dense output)."""
        return self._event_arrays("u")

    @property
    def v_events(self):
        """Per event function, ``v`` at its zeros (k, N) (by the dense output)."""
        return self._event_arrays("v")

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
            self._refresh_compiled(data=False)
        consumer = self._rows
        start = self.state
        saved = self.get_state()
        blocks = []
        self._rows = blocks.append
        # at most a call of the stepping code that fills no row array: taken
        # again exactly, and rewinding costs at most that; fewer where the
        # zeros that stop the run (on_event, a pause) came close together: a
        # zero every 20 steps cost a whole call taken and rewound each (15 ms
        # a zero), now about twice the steps between them
        most = (ROWS_PER_CALL - 2) // 2
        chunk = min(getattr(self, "_event_chunk", most), most)
        try:
            self._steps(t_stop, min(max_accepted, chunk))
        finally:
            self._rows = consumer
        rows = _joined(blocks, self.ev.n)
        if rows is None:
            return
        stop = self._scan(start, rows)
        if stop is None:
            self._event_chunk = min(2 * chunk, most)
            if consumer is not None:
                consumer(rows)
            return
        j, crossing, asks, last, error, later = stop
        self._event_chunk = max(EVENT_CHUNK_MIN, 2 * (j + 1))
        # back to the call's start, forward over the steps before row j
        self._retake(saved, rows, j, t_stop)
        if error is not None:
            # an event function or on_event failed in the step to row j: the
            # run stops before it, where the events are known
            self._run.status = int(Status.MODEL_ERROR)
            self._message = f"t = {self.t:.10g}: {error}"
            return
        while self.t < crossing.t and not self.failed:
            self._steps(crossing.t, STEPS_PER_CALL)
        if self.failed:
            return
        self._at_event(crossing, asks, last, later)

    def _retake(self, saved, rows, j, t_stop):
        """Back to ``saved`` (the call's start) and forward over the steps before
        row ``j`` of ``rows`` (the same steps, bit for bit), handing their rows on."""
        consumer = self._rows
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

    def _scan(self, start, rows):
        """The first row whose step holds a zero that changes the run (a terminal
        event's last, one ``on_event`` answers, or a pause), or where an event
        function fails: ``(row, crossing, whether on_event is asked, terminal,
        error, the step's later zeros)``; ``None`` when there is none. The zeros
        before it are recorded and the events' values moved on to the row
        before it. The functions are evaluated at every row; only the steps
        where one changes sign (or starts at zero) are looked into."""
        events = self._events
        t, u, v, a = rows["t"], rows["u"], rows["v"], rows["a"]
        G, failed, error = events.table(t, u, v)
        left = np.vstack([events.g[None], G[:-1]])
        look = events.active(left, G).any(axis=1) | (left == 0).any(axis=1)
        look &= rows["step_size"] > 0                 # a restart row: the same t, u, v
        look[failed:] = False
        for j in np.flatnonzero(look):
            if j:
                events.moved(t[j - 1], G[j - 1])
            if j == 0:
                t0, u0, v0, a0 = start.t, start.u, start.v, start.a
            else:
                t0, u0, v0, a0 = t[j - 1], u[j - 1], v[j - 1], a[j - 1]
            before = events.snapshot()
            counted = []
            try:
                found = events.crossings(t0, u0, v0, a0, t[j], u[j], v[j], a[j], G[j])
                for k, crossing in enumerate(found):
                    last = events.record(crossing)
                    # on_event is asked at the zero, once the run has landed
                    # there: it may change the load or the model, which the
                    # steps taken past the zero did not see
                    asks = self._on_event is not None
                    if last or asks or self._pause_at_events:
                        # zeros of other functions at the same time are recorded
                        # too (on_event answers each, in turn, once landed)
                        for other in found[k + 1:]:
                            if other.t == crossing.t:
                                last = events.record(other) or last
                        # and the later ones are looked for at the landing
                        later = [c for c in found[k + 1:] if c.t != crossing.t]
                        return j, crossing, asks, last, None, later
                    if crossing.t == t[j] or G[j][crossing.index] == 0:
                        counted.append(crossing.index)      # held to the step's end
            except EventError as exc:
                events.rollback(before)
                return j, None, None, False, exc, []
            events.moved(t[j], G[j], counted)
        if failed < t.size:
            if failed:
                events.moved(t[failed - 1], G[failed - 1])
            return failed, None, None, False, error, []
        events.moved(t[-1], G[-1])
        return None

    def _answer(self, i, t):
        """``on_event``'s reset state for the zero of ``events[i]`` at ``t``, the
        current (landed) state (checked), or ``None``."""
        if self._on_event is None:
            return None
        try:
            answer = self._on_event(t, self._vec.u.copy(), self._vec.v.copy(), i)
        except Exception as exc:
            raise EventError(f"on_event raised {type(exc).__name__}: {exc} at the zero of "
                             f"events[{i}] at t = {t!r}") from exc
        if answer is None:
            return None
        n = self.ev.n
        try:
            u, v = answer
            if np.iscomplexobj(u) or np.iscomplexobj(v):
                raise TypeError
            u = np.array(u, dtype=float).reshape(n)
            v = np.array(v, dtype=float).reshape(n)
        except Exception:
            raise EventError(f"on_event must return None or (u, v), two arrays of {n} "
                             f"values, got {answer!r} at the zero of events[{i}] at "
                             f"t = {t!r}") from None
        if not (np.isfinite(u).all() and np.isfinite(v).all()):
            raise EventError(f"on_event returned a state that is not finite at the zero of "
                             f"events[{i}] at t = {t!r}: u = {u}, v = {v}")
        return u, v

    def _at_event(self, crossing, asks, last, later):
        """At the zero's time (landed there): ask ``on_event`` (``asks``) about
        each zero recorded there, and restart from the state it gives, or
        from the current one with the model as ``on_event`` left it where it
        changed it (:meth:`_model_after_event`); end the run if the zero was a
        terminal event's last allowed one."""
        events = self._events
        i, t = crossing.index, crossing.t
        here = [k for k in range(len(events)) if events.t_events[k]
                and events.t_events[k][-1] == t]
        try:
            g = events.values(t, self._vec.u, self._vec.v)
        except EventError as exc:
            self._stop_at_event(f"t = {t:.10g}: {exc}")
            return
        # a zero the step held just after this one (ulps later: g = u and
        # g = atan(5u) + u³) that the landed state is already past would
        # never be seen again: counted here, with this one
        for other in later:
            k = other.index
            start = events.g[k]
            # g at the step's start (the events stand there), the crossing of
            # it found in the step (in its direction): passed at the landing?
            # (from a held zero: left it, the way the crossing goes)
            passed = g[k] * start <= 0 if start != 0 else \
                g[k] != 0 and not events.held[k] and events.direction[k] * g[k] >= 0
            if k in here or not passed:
                continue
            last = events.record(Crossing(t, k, self._vec.u.copy(), self._vec.v.copy())) \
                or last
            here.append(k)
        seen = self._model_here() if asks else None
        landed = (self._vec.u.copy(), self._vec.v.copy()) if asks else None  # before a reset
        jumped = False
        for k in ([i] + [k for k in here if k != i]) if asks else []:
            try:
                reset = self._answer(k, t)
            except EventError as exc:
                self._stop_at(t, g, here, f"t = {t:.10g}: {exc}")
                return
            changed = self._matrix_changed()
            if changed:
                self._stop_at(t, g, here, f"t = {t:.10g}: on_event changed the model's "
                                          f"{changed}, which the run reads once: a new "
                                          f"Integrator takes it (set_state carries the state "
                                          f"over)")
                return
            try:
                if reset is not None:
                    jumped = self._reset_state(*reset) or jumped
                    seen = self._model_here()
                else:
                    now = self._model_here()
                    if not _same_model(seen, now):
                        self._model_after_event()
                    seen = now
                g = events.values(t, self._vec.u, self._vec.v)
            except (ModelError, EventError) as exc:
                what = "reset" if reset is not None else "answer"
                self._stop_at(t, g, here, f"t = {t:.10g}: after on_event's {what}: {exc}")
                return
        motion = _reset_motion(*landed, self._vec.u, self._vec.v) if jumped else None
        accumulating = [k for k in here if self._accumulating(k, t, motion)] if asks else []
        if accumulating:
            self._stop_at(t, g, here, (
                f"t = {t:.10g}: the zeros of events[{accumulating[0]}] that on_event answers "
                f"accumulate ({ZENO_ZEROS} in a row, each within {ZENO_INTERVAL:g} times "
                f"its longest interval between zeros of the last, or a reset's motion since "
                f"it within {ZENO_ROUNDING:g} ulps of u): a Zeno point, past "
                f"which steps cannot follow the model (a bouncing contact comes to rest "
                f"there; a model that holds the contact, or a terminal event before it, "
                f"goes on)"))
            return
        # the zeros count once: at the landed (or reset) state the functions
        # with a zero recorded at t are taken as at zero, and the next step
        # starts from the side each leaves to
        g[here] = 0.0
        events.moved(t, g, here)
        if jumped:
            # a state the reset moved holds no zero over a while: g left at 0
            # by it (to rounding: a floor at u = 100, the rebound's first
            # ulps) is looked at afresh, and the ball left on the floor's
            # wrong side crossed it again (it fell through with SUCCESS)
            events.held[here] = False
        if last:
            self._run.status = int(Status.TERMINATED)
            self._message = (f"t = {t:.10g}: events[{i}] ended the run (its zero number "
                             f"{int(events.count[i])}, terminal)")

    def _forget_answered(self) -> None:
        """Per function: its last zero ``on_event`` answered, its longest
        interval between them (from ``t0`` to the first), and how many came
        in a row within :data:`ZENO_INTERVAL` of that (:meth:`_accumulating`),
        none yet. Also at a restored state, whose history of zeros is not
        known: a master that restored a state before a zero and took the step
        again ten times (the same zero answered ten times at one time) was
        stopped as at a Zeno point."""
        count = len(self._events.count)
        self._answered_t = np.full(count, math.nan)
        self._answered_gap = np.zeros(count)
        self._answered_between = np.zeros(count)    # the longest, not from t0
        self._answered_in_a_row = np.zeros(count, dtype=int)

    def _accumulating(self, k, t, motion) -> bool:
        """Whether the zeros of ``events[k]`` that ``on_event`` answered, this one
        at ``t`` the last, are :data:`ZENO_ZEROS` in a row, each close to the
        one before: within :data:`ZENO_INTERVAL` times the function's longest
        interval between them (the first from ``t0``), or answered by a
        reset whose ``motion`` (:func:`_reset_motion`; ``None`` without one)
        shows a changed component that moved within the rounding of its ``u``
        since the one before, the gap within :data:`ZENO_ROUNDING_INTERVAL` of the
        longest interval between two of them (not from ``t0``: zeros that
        came regularly from the first, a sampled controller's, are no
        accumulation however small their motion). The impacts of
        a ball bouncing to rest shorten geometrically, and past their
        accumulation point no step resolves them (the ball fell through the
        floor with SUCCESS; a ball held on it by a force made a zero each
        1e-9 s for hours); on a floor at u = 1e4 they stop shortening where
        the flights reach the rounding of u (0.7–1.1e-6 s, about the first
        rule's threshold) and went on, a step and a zero each, until
        max_steps. Per function, and against its own intervals: the zeros of
        several contacts that close together, or a function's zeros late in
        a long run, are not an accumulation; zeros that reset nothing (a
        clock's) count by the first rule alone."""
        last = self._answered_t[k]
        gap = t - (self.t0 if math.isnan(last) else last)
        self._answered_gap[k] = max(self._answered_gap[k], gap)
        longest = self._answered_gap[k]
        if not math.isnan(last):
            self._answered_between[k] = max(self._answered_between[k], gap)
        if not math.isnan(last) and (gap <= ZENO_INTERVAL * longest or (
                motion is not None and gap <= ZENO_ROUNDING_INTERVAL * self._answered_between[k]
                and bool(np.any(motion[0] * gap + motion[1] <= motion[2])))):
            self._answered_in_a_row[k] += 1
        else:
            self._answered_in_a_row[k] = 1
        self._answered_t[k] = t
        return self._answered_in_a_row[k] >= ZENO_ZEROS

    def _matrix_changed(self) -> str:
        """The model's matrix on_event changed (:meth:`Evaluator.matrix_changed`),
        or ``""``."""
        try:
            return self.ev.matrix_changed()
        except ValueError as exc:            # not a matrix any more
            return f"mass or damping ({exc})"

    def _model_here(self):
        """What ``on_event`` may change of the model, seen at the current state:
        its parameter count, ``p(t)`` and ``f(u)`` (``None`` where they cannot
        be evaluated)."""
        try:
            return (getattr(self.system, "parameter_version", None),
                    np.array(self.ev.load(self.t), dtype=float),
                    np.array(self.ev.force(self._vec.u), dtype=float))
        except Exception:
            return None
        finally:
            self._absorb_counts()

    def _model_after_event(self) -> None:
        """After ``on_event`` returned ``None`` and changed the model here (a load
        or a parameter it switched): the state stays, and the run restarts
        from it with the model now (:meth:`model_changed`), the state's row
        there twice, as at a load breakpoint."""
        self.model_changed()
        self._restart_row(self.total_energy)

    def _restart_row(self, energy) -> None:
        """The current state's row, a step of size 0 (as a restart at a load
        breakpoint), handed on to the rows' consumer."""
        if self._rows is not None:
            run, vec = self._run, self._vec
            row = Rows(self.ev.n)
            row.append(State(run.t, vec.u, vec.v, vec.a, None, None), 0.0, 0, 0.0, energy,
                       run.work, vec.global_error)
            self._rows(row.arrays())

    def _stop_at(self, t, g, here, message):
        """Stop at the zeros ``here`` at ``t`` (counted, the functions' values
        ``g`` taken as at zero there) with ``message``."""
        g[here] = 0.0
        self._events.moved(t, g, here)
        self._stop_at_event(message)

    def _stop_at_event(self, message):
        # self._run, not a local name for it: a failed refresh replaces it
        self._run.status = int(Status.MODEL_ERROR)
        self._message = message

    def _reset_state(self, u, v) -> bool:
        """The current state becomes ``(t, u, v)`` with ``f``, ``p`` and ``a``
        from the model; the energy the jump adds is work done on the system;
        the next step starts afresh (:class:`ModelError` when the model
        fails at the new state; the integrator is then left at the old one).
        Whether the state changed."""
        run, vec, ev = self._run, self._vec, self.ev
        before = self.get_state()
        potential_before = run.potential
        kinetic_before = ev.kinetic_energy(vec.v)
        jumped = not (np.array_equal(vec.u, u) and np.array_equal(vec.v, v))
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
        run = self._run                      # _refresh may have replaced it
        if jumped:
            # the error carried to the zero moves the zero's time too, and a
            # jump of the state turns that into an error of its own (the
            # saltation term), which needs the reset's derivative: not known
            # for a Python on_event, so the estimate is lost from here
            vec.global_error[:] = np.nan
        kinetic_after = ev.kinetic_energy(vec.v)
        energy_after = potential + kinetic_after
        jump = kinetic_after - kinetic_before
        if math.isfinite(potential) and math.isfinite(potential_before):
            jump += potential - potential_before    # a model without V: the kinetic part
        run.potential = potential
        run.work += jump
        run.energy_scale = max(run.energy_scale, abs(energy_after)
                               if math.isfinite(energy_after) else 0.0)
        self._restart_row(energy_after)
        return jumped


#: Zeros of one function answered by ``on_event`` in a row, each within
#: ``ZENO_INTERVAL`` times the function's longest interval between its zeros
#: after the one before, that stop the run as a Zeno point
#: (:meth:`EventSteps._accumulating`; a run that needs more may raise them).
ZENO_ZEROS = 10
ZENO_INTERVAL = 1e-6
#: ... or each answered by a reset that changed a component whose motion
#: since the one before is within ``ZENO_ROUNDING`` ulps of its ``u``, the
#: interval within ``ZENO_ROUNDING_INTERVAL`` times the longest between two
#: of them: bounces at the rounding of ``u``, which shorten no further.
ZENO_ROUNDING = 100.0
ZENO_ROUNDING_INTERVAL = 1e-3

_EPS = float(np.finfo(float).eps)


def _reset_motion(u_landed, v_landed, u, v):
    """``(speed, jump, rounding)`` over the components a reset changed (from
    the landed state to ``(u, v)``; ``None`` when it changed none): the
    larger of their speeds before and after (a bounce's landing and
    take-off: their motion since the last zero is at most ``speed·gap``),
    the jump of their ``u``, and :data:`ZENO_ROUNDING` ulps of their ``u``.
    Per component, any one of them: a bouncing DOF at 1e4 beside one
    oscillating at 1 (the largest speed of all kept it from ever counting),
    or beside a bounce counter the reset adds 1 to, or one it rewrites by an
    ulp, is judged by its own motion; a rattle of 1e-9 beside a DOF at rest
    at 1e9 (the rounding of ``‖u‖∞`` took it for one) and a stepper that a
    clock's reset moves by 1e-3 at rest (its speed 0) move more than their
    rounding."""
    moved = (u != u_landed) | (v != v_landed)
    if not moved.any():
        return None
    speed = np.maximum(np.abs(v_landed), np.abs(v))[moved]
    jump = np.abs(u - u_landed)[moved]
    rounding = ZENO_ROUNDING * _EPS * np.maximum(np.abs(u_landed), np.abs(u))[moved]
    return speed, jump, rounding

#: The fewest accepted steps a call of the stepping code takes between the
#: zeros that stop a run (the calls' own cost bounds it from below).
EVENT_CHUNK_MIN = 16


def _same_model(before, after) -> bool:
    """Whether two :meth:`EventSteps._model_here` are alike (to rounding: a
    compiled load and its Python method may differ in the last digits)."""
    if before is None or after is None or before[0] != after[0]:
        return False
    return all(np.allclose(x, y, rtol=1e-12, atol=0.0) for x, y in zip(before[1:], after[1:]))
