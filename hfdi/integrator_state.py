"""The integrator's state, to copy and restore it, and its bytes.

:class:`IntegratorState` holds everything that determines the continuation of
a run (:meth:`hfdi.Integrator.get_state`); :meth:`IntegratorState.to_bytes`
and :meth:`~IntegratorState.from_bytes` carry it across processes as data
only (:mod:`hfdi.serial`), bit for bit.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from . import serial
from .evaluation import State, brief
from .messages import Status
from .result import STATISTICS_FIELDS, Statistics

__all__ = ["IntegratorState", "STATE_FORMAT", "check_state"]


def _clone(obj):
    """``copy.copy`` of a plain dataclass instance (its fields in its ``__dict__``)."""
    new = object.__new__(type(obj))
    new.__dict__.update(obj.__dict__)
    return new


@dataclass
class IntegratorState:
    """Everything that determines the continuation of a run (see
    :meth:`Integrator.get_state`).

    :meth:`to_bytes` and :meth:`from_bytes` write and read it as data only
    (:mod:`hfdi.serial`), so that bytes from elsewhere can never run code;
    the round trip is bit-exact. ``previous`` is the step history (``None``
    after a start, a restart or, for generalized-α, a short step); its
    ``a`` is, for generalized-α, the lagged acceleration the last step
    started from (at ``previous.t + lag·h``), not the acceleration at
    ``previous.t``.
    """

    current: State
    previous: State | None
    proposed_step: float
    first_step_pending: bool
    status: int
    message: str
    statistics: Statistics
    potential: float
    initial_potential: float
    work: float
    energy_error: float
    energy_scale: float
    last_step: float
    last_iterations: int
    last_energy_increment: float
    grid_origin: float
    grid_steps: int
    newton_constant: float
    newton_guard: float
    controller: str
    n_dof: int
    #: ``repr`` of the scheme (with its parameters) that made the state.
    scheme: str = ""
    #: The model's ``parameter_version`` the state was computed with (-1: a
    #: model that does not count parameter changes).
    model_version: int = -1
    #: A digest of the ``M`` and ``C`` the state's acceleration was computed
    #: with (:func:`hfdi.evaluation.matrices_digest`; ``""``: not recorded).
    matrices: str = ""
    #: The global error estimate of ``(u, v)`` at ``current.t`` (2N; NaN:
    #: lost, see :attr:`Integrator.global_error`); ``None`` is zero.
    global_error: np.ndarray | None = None
    #: The event functions' values at ``current.t`` as the run holds them (a
    #: zero counted there is held at 0), and which zeros were counted exactly
    #: there (1.0) or counted where reached and held since (2.0; both: 3.0)
    #: — so that a restored run does not count them again (``None``: no
    #: events, or none known at ``current.t``).
    event_values: np.ndarray | None = None
    event_counted: np.ndarray | None = None
    #: The zeros each event function has counted towards its ``terminal``
    #: limit (whole numbers; ``None``: no events), so that a restored run
    #: ends at the same zero (the record ``t_events`` is the caller's and stays).
    event_count: np.ndarray | None = None

    def copy(self, copy_arrays: bool = True) -> IntegratorState:
        """A deep copy, field by field: a co-simulation step saves one before
        every communication step, where ``copy.deepcopy``'s generic walk cost
        more than the step (and ``copy.copy`` of each dataclass, 1.4 µs, as
        much as the arrays). With ``copy_arrays=False`` the states (and their
        arrays) are shared; see :meth:`Integrator.get_state`."""
        new = _clone(self)
        if copy_arrays:
            new.current = self.current.copy()
            new.previous = None if self.previous is None else self.previous.copy()
            new.global_error = None if self.global_error is None else self.global_error.copy()
            for name in ("event_values", "event_counted", "event_count"):
                value = getattr(self, name)
                setattr(new, name, None if value is None else value.copy())
        new.statistics = _clone(self.statistics)
        return new

    def to_bytes(self) -> bytes:
        """The state as bytes: arrays in binary, everything else in a JSON header."""
        arrays = {}

        def one(label, st):
            if st is None:
                return None
            for name in _STATE_ARRAYS:
                value = getattr(st, name)
                if value is not None:
                    arrays[f"{label}.{name}"] = np.asarray(value, dtype=np.float64)
            return {"t": float(st.t), "f": st.f is not None}

        if self.global_error is not None:
            arrays["global_error"] = np.asarray(self.global_error, dtype=np.float64)
        if self.event_values is not None:
            arrays["event_values"] = np.asarray(self.event_values, dtype=np.float64)
            arrays["event_counted"] = np.asarray(self.event_counted, dtype=np.float64)
        if self.event_count is not None:
            arrays["event_count"] = np.asarray(self.event_count, dtype=np.float64)
        header = {name: kind(getattr(self, name)) for name, kind in _STATE_SCALARS.items()}
        header.update(format=STATE_FORMAT, current=one("current", self.current),
                      previous=one("previous", self.previous),
                      statistics={k: type(getattr(Statistics, k))(getattr(self.statistics, k))
                                  for k in _STATISTICS_FIELDS})
        return serial.pack(header, arrays)

    @classmethod
    def from_bytes(cls, data) -> IntegratorState:
        """Read :meth:`to_bytes`' bytes, checking every field's type and shape.

        Raises
        ------
        ValueError
            For bytes that are not such a state (corrupt, truncated, of
            another format version, or with a field of the wrong type).
        """
        try:
            header, arrays = serial.unpack(data)
        except ValueError:
            raise ValueError("not a serialized integrator state") from None
        if header.get("format") != STATE_FORMAT:
            raise ValueError(f"not a serialized integrator state of format {STATE_FORMAT!r}")
        n = _field(header, "n_dof", int)

        def one(label):
            entry = header.get(label)
            if entry is None and label == "previous":
                return None
            if not isinstance(entry, dict):
                raise ValueError(f"serialized state: {label} is missing")
            values = {}
            for name in _STATE_ARRAYS:
                key = f"{label}.{name}"
                if name == "f" and not _field(entry, "f", bool):
                    values[name] = None
                    continue
                value = arrays.pop(key, None)
                if not (isinstance(value, np.ndarray) and value.dtype == np.float64
                        and value.shape == (n,)):
                    raise ValueError(f"serialized state: {key} must be a float64 array of "
                                     f"shape ({n},)")
                values[name] = value
            return State(_field(entry, "t", float), **values)

        current, previous = one("current"), one("previous")
        global_error = arrays.pop("global_error", None)
        if global_error is not None and not (global_error.dtype == np.float64
                                             and global_error.shape == (2 * n,)):
            raise ValueError(f"serialized state: global_error must be a float64 array of "
                             f"shape ({2 * n},)")
        event_values = arrays.pop("event_values", None)
        event_counted = arrays.pop("event_counted", None)
        if (event_values is None) != (event_counted is None) or event_values is not None and not (
                event_values.dtype == event_counted.dtype == np.float64
                and event_values.ndim == 1 and event_values.shape == event_counted.shape
                and np.isfinite(event_values).all()
                and np.isin(event_counted, (0.0, 1.0, 2.0, 3.0)).all()):
            raise ValueError("serialized state: event_values and event_counted must be two "
                             "float64 arrays of one length, finite, the second of 0 … 3")
        event_count = arrays.pop("event_count", None)
        if event_count is not None and not (event_count.dtype == np.float64
                                            and event_count.ndim == 1
                                            and event_counts_valid(event_count)):
            raise ValueError(f"serialized state: event_count must be a float64 array of whole "
                             f"numbers in [0, {MAX_EVENT_COUNT}]")
        if arrays:
            raise ValueError(f"serialized state: unexpected entries {sorted(arrays)}")
        counts = header.get("statistics")
        if not isinstance(counts, dict) or set(counts) != set(_STATISTICS_FIELDS):
            raise ValueError("serialized state: statistics malformed")
        statistics = Statistics(**{k: _field(counts, k, type(getattr(Statistics, k)))
                                   for k in _STATISTICS_FIELDS})
        scalars = {k: _field(header, k, kind) for k, kind in _STATE_SCALARS.items()}
        return cls(current=current, previous=previous, statistics=statistics,
                   global_error=global_error, event_values=event_values,
                   event_counted=event_counted, event_count=event_count, **scalars)


#: The largest count of an event function's zeros a state holds (exact in a float).
MAX_EVENT_COUNT = 2 ** 53

def event_counts_valid(count: np.ndarray) -> bool:
    """Whether every entry is a whole number in ``[0, MAX_EVENT_COUNT]``."""
    return bool(np.isfinite(count).all() and (count >= 0).all()
                and (count == np.floor(count)).all() and (count <= MAX_EVENT_COUNT).all())


#: Format of :meth:`IntegratorState.to_bytes`; a version bump makes old bytes unreadable.
STATE_FORMAT = "hfdi-integrator-state/6"
_STATE_ARRAYS = ("u", "v", "a", "f", "p")
#: The fields of plain types, by name (the annotations are strings here).
_STATE_SCALARS = {f.name: {"float": float, "bool": bool, "int": int, "str": str}[f.type]
                  for f in dataclasses.fields(IntegratorState)
                  if f.type in ("float", "bool", "int", "str")}
_STATISTICS_FIELDS = tuple(f.name for f in dataclasses.fields(Statistics))


def _field(mapping, key, kind):
    """``mapping[key]`` of type ``kind`` (an int is a float too; a bool is no int)."""
    value = mapping.get(key)
    ok = isinstance(value, bool) if kind is bool else (
        isinstance(value, int) and not isinstance(value, bool) if kind is int else
        isinstance(value, (int, float)) and not isinstance(value, bool) if kind is float else
        isinstance(value, kind))
    if not ok:
        raise ValueError(f"serialized state: {key} must be of type {kind.__name__}, "
                         f"got {type(value).__name__}")
    return float(value) if kind is float else value


def check_state(saved: IntegratorState, *, n: int, controller: str, scheme: str, t0: float,
                t_bound, kinetic_energy, potential_known=False) -> None:
    """Refuse (ValueError) a state that is not one of an integrator of ``n``
    degrees of freedom with this ``controller`` and ``scheme`` (their reprs)
    from ``t0`` to ``t_bound``, or holds values out of their range
    (``kinetic_energy(v)`` is the model's; ``potential_known``: the model
    gives its potential energy, so a state's may not be NaN). Bytes of
    :meth:`IntegratorState.from_bytes` are data: here their values are checked."""
    if saved.n_dof != n:
        raise ValueError(f"state has {saved.n_dof} degrees of freedom, this integrator's "
                         f"model has {n}")
    if saved.controller != controller:
        raise ValueError(f"state was saved by an integrator with controller "
                         f"{saved.controller}; this one has {controller}")
    if saved.scheme != scheme:
        raise ValueError(f"state was saved by an integrator with scheme "
                         f"{saved.scheme or 'unknown'}; this one has {scheme}")
    if saved.status not in {int(s) for s in Status}:
        raise ValueError(f"state.status must be one of {sorted(int(s) for s in Status)}, "
                         f"got {saved.status!r}")
    if saved.status < 0 and not saved.message:
        raise ValueError(f"state.status {Status(saved.status).name} (a failure) needs its "
                         f"message, got an empty one")
    for label, st in (("current", saved.current), ("previous", saved.previous)):
        if st is None and label == "previous":
            continue
        if not isinstance(st, State):
            raise ValueError(f"state.{label} must be a State, got {type(st).__name__}")
        for name in _STATE_ARRAYS:
            value = getattr(st, name)
            if value is None and name == "f":       # not kept by every scheme
                continue
            if not (isinstance(value, np.ndarray) and value.shape == (n,)
                    and value.dtype == np.float64 and np.isfinite(value).all()):
                raise ValueError(f"state.{label}.{name} must be a finite float array of "
                                 f"shape ({n},), got {brief(value)}")
        if not math.isfinite(st.t):
            raise ValueError(f"state.{label}.t must be finite, got {st.t!r}")
    if t_bound is not None and saved.current.t > t_bound:
        raise ValueError(f"state.current.t = {saved.current.t!r} is beyond t_bound = "
                         f"{t_bound!r}")
    if saved.current.t < t0:
        raise ValueError(f"state.current.t = {saved.current.t!r} is before this "
                         f"integrator's t0 = {t0!r}")
    if saved.previous is not None and not saved.previous.t < saved.current.t:
        raise ValueError(f"state.previous.t = {saved.previous.t!r} must be before "
                         f"state.current.t = {saved.current.t!r}")
    g = saved.global_error
    if g is not None and not (isinstance(g, np.ndarray) and g.shape == (2 * n,)
                              and g.dtype == np.float64 and not np.isinf(g).any()):
        raise ValueError(f"state.global_error must be None or a float array of shape "
                         f"({2 * n},) without infinities (NaN: lost), got {brief(g)}")
    st = saved.statistics
    if not isinstance(st, Statistics):
        raise ValueError(f"state.statistics must be a Statistics, got "
                         f"{type(st).__name__}")
    for name in STATISTICS_FIELDS:
        value = getattr(st, name)
        if not (isinstance(value, (int, float)) and value >= 0
                if name not in ("t_start", "t_reached") else math.isfinite(value)):
            raise ValueError(f"state.statistics.{name} must be a finite count >= 0, got "
                             f"{value!r}")
    if saved.grid_steps < 0:
        raise ValueError(f"state.grid_steps must be >= 0, got {saved.grid_steps!r}")
    for name in ("work", "energy_scale", "grid_origin"):
        if not math.isfinite(getattr(saved, name)):
            raise ValueError(f"state.{name} must be finite, got {getattr(saved, name)!r}")
    # NaN where the model gives no potential energy: the balance is unknown
    # (a System without potential_energy had its own states refused); where
    # it gives one, an edited NaN would turn energy_limit off unsaid
    unknown = math.isnan(saved.potential) or math.isnan(saved.initial_potential)
    if unknown and potential_known:
        raise ValueError(f"state.potential and state.initial_potential must be finite for "
                         f"a model that gives its potential energy, got "
                         f"{saved.potential!r} and {saved.initial_potential!r}")
    if not (math.isfinite(saved.energy_error) or unknown and math.isnan(saved.energy_error)):
        raise ValueError(f"state.energy_error must be finite, or NaN where the potential "
                         f"energy is unknown (NaN), got {saved.energy_error!r}")
    if saved.energy_scale < 0:
        raise ValueError(f"state.energy_scale must be >= 0, got {saved.energy_scale!r}")
    for name in ("potential", "initial_potential"):
        if math.isinf(getattr(saved, name)):     # NaN is the model's "unknown"
            raise ValueError(f"state.{name} must be finite or NaN (unknown), got "
                             f"{getattr(saved, name)!r}")
    kinetic = kinetic_energy(saved.current.v)
    if not math.isfinite(kinetic):
        raise ValueError(f"state.current.v has a kinetic energy beyond floating point "
                         f"({kinetic!r}); no run reaches such a state (Status.OVERFLOW)")
    if not (math.isfinite(saved.proposed_step) and saved.proposed_step > 0):
        raise ValueError(f"state.proposed_step must be finite and > 0, got "
                         f"{saved.proposed_step!r}")
    for name in ("newton_constant", "newton_guard"):
        if not getattr(saved, name) >= 0:
            raise ValueError(f"state.{name} must be >= 0 (inf: none measured), got "
                             f"{getattr(saved, name)!r}")

