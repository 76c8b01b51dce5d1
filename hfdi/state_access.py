"""How an :class:`~hfdi.Integrator` saves and restores its state
(:class:`~hfdi.IntegratorState`: bit-exact, checked where it comes back).

:class:`StateAccess` is a part of :class:`~hfdi.Integrator` (a base class of it).
"""
from __future__ import annotations

import math

import numpy as np

from .core.state import RUN
from .evaluation import ModelError, State
from .integrator_state import (MAX_EVENT_COUNT, IntegratorState, check_state,
                               event_counts_valid)
from .result import STATISTICS_FIELDS

__all__ = ["StateAccess"]


class StateAccess:
    """Saving and restoring the state of an :class:`~hfdi.Integrator`."""

    # -- saving and restoring -------------------------------------------------------
    def get_state(self, copy_arrays: bool = True) -> IntegratorState:
        """A copy of the integrator's state, for :meth:`set_state`: the current and
        previous states, the proposed step, Newton's memory, the energy
        balance, the statistics, status and message. (``copy_arrays`` is
        accepted for compatibility; the arrays are always copies.)"""
        run, vec = self._run, self._vec
        previous = None
        if run.has_previous:
            previous = State(run.t_previous, vec.u_previous.copy(), vec.v_previous.copy(),
                             vec.a_previous.copy(), vec.f_previous.copy(),
                             vec.p_previous.copy())
        return IntegratorState(
            current=self.state, previous=previous, proposed_step=run.proposed,
            first_step_pending=run.first_step_pending, status=run.status,
            message=self._message, statistics=self.statistics, potential=run.potential,
            initial_potential=run.initial_potential, work=run.work,
            energy_error=run.energy_error, energy_scale=run.energy_scale,
            last_step=run.last_step, last_iterations=run.last_iterations,
            last_energy_increment=run.last_energy_increment, grid_origin=run.grid_origin,
            grid_steps=run.grid_steps, newton_constant=run.newton_constant,
            newton_guard=run.newton_guard, controller=repr(self.controller), n_dof=self.ev.n,
            scheme=repr(self.scheme),
            model_version=-1 if self._model_version is None else int(self._model_version),
            matrices=self.ev.matrices,
            global_error=vec.global_error.copy(), **self._event_memory(run.t))

    def _event_memory(self, t) -> dict:
        """The zeros counted towards the terminal limits, and the events'
        values and counted zeros at ``t`` (IntegratorState's fields)."""
        events = getattr(self, "_events", None)
        if events is None:
            return {}
        memory = {"event_count": events.count.astype(np.float64)}
        if events.t == t:
            memory.update(event_values=events.g.copy(),
                          event_counted=events.counted_codes())
        return memory

    def set_state(self, saved: IntegratorState) -> None:
        """Restore a state from :meth:`get_state`; the run then continues
        exactly as it did from that point. For a model that counts the
        changes of its parameters (``parameter_version``), a state saved
        under another version, and a state saved with another mass or
        damping matrix (``IntegratorState.matrices``), is refreshed as by
        :meth:`model_changed` (``f``, ``a`` and ``V`` recomputed, the step
        history dropped).

        Raises
        ------
        TypeError
            If ``saved`` is not an :class:`IntegratorState`.
        ValueError
            If it belongs to a model of another size, to another model (its
            kept force ``f(u)`` is not this model's there: HFDI's and
            generalized-α's states; Newmark and Bathe keep no force, and a
            state of another model of the same size is taken, its
            acceleration that model's), to an integrator
            of another scheme or mode (controller), or holds values out of
            their range (non-finite arrays, an unknown status, times out of
            order, negative counters); the integrator is then left as it was.
            Bytes from :meth:`IntegratorState.from_bytes` are data: this is
            where their values are checked.
        """
        if not isinstance(saved, IntegratorState):
            raise TypeError(f"state must be an IntegratorState, got {type(saved).__name__}")
        self._check_state(saved)
        now = getattr(self.system, "parameter_version", None)
        # the state's f_n, a_n and V were computed under the parameters of its
        # version; under others they are recomputed (Newmark and Bathe keep no
        # f_n to tell by), and a failure there puts back what was (kept only
        # then: a copy of the state costs a third of a restore)
        # and a state of a model with other M or C (a new integrator for changed
        # matrices, as model_changed asks) has an acceleration of those
        refresh = (now is not None and saved.model_version != now
                   or saved.matrices not in ("", self.ev.matrices))
        before = (RUN.copy(self._run), self._message, self._model_version,
                  self.get_state()) if refresh else None
        self._model_version = now
        self._restore(saved)
        self._prime_events(saved)
        if refresh:
            try:
                self.model_changed()
            except (ModelError, ValueError):
                # a model that fails there, or whose matrices or load rate
                # changed: the integrator as it was
                run, self._message, self._model_version, state = before
                self._restore(state)
                self._run = run
                self._prime_events(state)
                raise

    def _prime_events(self, saved: IntegratorState) -> None:
        """The event functions' values at the restored state (the events
        found so far stay: they are the caller's record), and the zeros
        counted there as they were: a zero the state was stopped at is not
        found again (its g may round to the side before it)."""
        if getattr(self, "_events", None) is None:
            return
        current = self.state
        self._forget_answered()
        self._events.start(current.t, current.u, current.v)
        if saved.event_values is not None and saved.event_values.shape == self._events.g.shape:
            self._events.resume(current.t, saved.event_values, saved.event_counted)
        if saved.event_count is not None:
            self._events.count[:] = saved.event_count

    def _restore(self, saved: IntegratorState) -> None:
        run = self._run
        self._put_current(saved.current, saved.previous)
        run.proposed, run.first_step_pending = saved.proposed_step, saved.first_step_pending
        run.status = saved.status
        self._message = saved.message
        run.potential, run.initial_potential = saved.potential, saved.initial_potential
        run.work, run.energy_error = saved.work, saved.energy_error
        run.energy_scale, run.last_step = saved.energy_scale, saved.last_step
        run.last_iterations = saved.last_iterations
        run.last_energy_increment = saved.last_energy_increment
        run.grid_origin, run.grid_steps = saved.grid_origin, saved.grid_steps
        run.newton_constant, run.newton_guard = saved.newton_constant, saved.newton_guard
        if saved.global_error is None:
            self._vec.global_error[:] = 0.0
        else:
            self._vec.global_error[:] = saved.global_error
        for name in STATISTICS_FIELDS:
            if name != "cpu_time":
                setattr(run, name, getattr(saved.statistics, name))
        self._run_cpu = saved.statistics.cpu_time

    def _check_state(self, saved: IntegratorState):
        check_state(saved, n=self.ev.n, controller=repr(self.controller),
                    scheme=repr(self.scheme), t0=self.t0, t_bound=self.t_bound,
                    kinetic_energy=self.ev.kinetic_energy,
                    potential_known=not math.isnan(self._run.initial_potential))
        self._check_state_model(saved.current, saved.model_version)
        self._check_event_count(saved.event_count)

    def _check_event_count(self, count) -> None:
        """A saved ``event_count``: one whole number ``>= 0`` per event function
        of this integrator (its terminal limits depend on them); ignored by an
        integrator without events."""
        events = getattr(self, "_events", None)
        if count is None or events is None:
            return
        m = len(events.count)
        value = np.asarray(count) if isinstance(count, np.ndarray) else None
        if value is None or value.shape != (m,) or value.dtype.kind not in "fiu" \
                or not event_counts_valid(value):
            raise ValueError(f"state: event_count must be an array of {m} whole numbers in "
                             f"[0, {MAX_EVENT_COUNT}] (one per event function), got {count!r:.80}")

    def _check_state_model(self, current: State, saved_version: int) -> None:
        """The kept force ``f_n`` of a state against this model's ``f(u_n)``.

        The schemes read ``f_n`` and ``a_n`` from the state instead of
        evaluating them: a state of another model of the same size would go
        on with that model's force (an error of 3e-5 against 5e-7 measured).
        ``f`` is a pure function of ``u``, so one evaluation tells the models
        apart; the margin (1e-9 of the largest of ``f``, ``p`` and ``M a``)
        lets the compiled and Python kernels' roundings pass. For a model
        that counts the changes of its parameters (``parameter_version``, as
        :class:`~hfdi.models.symbolic.EnergyModel`) a mismatch under another
        version than the state's is a state saved under other parameters,
        which :meth:`set_state` refreshes; under the same version it is
        another model, refused.
        """
        if current.f is None:
            # Newmark and Bathe keep no f_n (they would need one more force
            # evaluation per step); their states are not told apart by model
            return
        ev = self.ev
        saved_counts = (ev.nfev, ev.njev, ev.ntev, ev.npev)
        try:
            f = ev.force(current.u)
        except Exception as exc:
            raise ValueError(f"state.current: this model's internal_force fails at its u "
                             f"({type(exc).__name__}: {exc}); the state is of another "
                             f"model") from None
        finally:
            ev.nfev, ev.njev, ev.ntev, ev.npev = saved_counts
        scale = max(float(np.abs(current.f).max()), float(np.abs(current.p).max()),
                    float(np.abs(ev.mass_times(current.a)).max()))
        mismatch = float(np.abs(f - current.f).max())
        if mismatch <= 1e-9 * scale:
            return
        if self._model_version is not None and saved_version != self.system.parameter_version:
            return                      # the same model under other parameters
        raise ValueError(f"state.current.f differs from this model's internal_force at "
                             f"state.current.u by {mismatch:.3g} (scale {scale:.3g}): the state "
                             f"was saved from another model, or from this one with other "
                             f"parameters")

