"""An example co-simulation master for hfdi's FMUs, on fmpy's low-level FMI 2.0 API.

:class:`Unit` drives one FMU instance through :class:`fmpy.fmi2.FMU2Slave`
(instantiate, setupExperiment, enter/exitInitializationMode, doStep,
getFMUstate/setFMUstate, terminate). :func:`cosimulate` is a Jacobi master:
at each communication point it reads the units' outputs, lets an exchange
function compute every unit's inputs, and steps all units over the same
interval. When a unit answers ``fmi2Discard`` it restores every unit to the
state saved before the step and retries with half the step, until the step
lands on the next communication point.

:func:`coupled_dumbbells` couples two dumbbell FMUs by a spring-damper between
particle 2 of the first and particle 1 of the second, the force computed by
the master from the outputs at the start of each step and held over it.

Run ``python -m fmu master --help``.
"""
from __future__ import annotations

import math
import shutil
import threading
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2Discard,
                       fmi2LastSuccessfulTime)

__all__ = ["Unit", "Trace", "CoSimulationError", "cosimulate", "coupled_dumbbells",
           "spring_damper_force"]

_STATUS = ("OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING")


class CoSimulationError(RuntimeError):
    """The master could not continue (a step kept failing down to the smallest step)."""


#: fmpy validates the model description with libxml2's schema parser, which
#: is not thread-safe: units built in several threads at once failed with
#: "xmlSchemaPValAttrNodeValue ... not a built-in type". The parsing is
#: serialized; the instantiations stay concurrent.
_PARSE_LOCK = threading.Lock()


class Unit:
    """One instance of an FMU, driven through fmpy's ``FMU2Slave``.

    Parameters
    ----------
    fmu : path-like
        The ``.fmu`` file (or an extracted FMU directory).
    name : str
        Instance name.
    unzip_dir : path-like, optional
        An extraction of ``fmu`` to use (shared by several units); by default
        the unit extracts the FMU and removes the copy in :meth:`close`.
    logger : callable ``(status, category, message)``, optional
        Called for every message of the FMU; all are also kept in
        :attr:`messages` as ``(status name, category, message)``.

    Attributes
    ----------
    variables : dict
        Name to fmpy's ``ScalarVariable``.
    messages : list of tuple
    """

    def __init__(self, fmu, name="unit", *, unzip_dir=None, logger=None):
        with _PARSE_LOCK:
            self.model_description = md = read_model_description(str(fmu))
        self._own_dir = unzip_dir is None
        self.unzip_dir = extract(str(fmu)) if unzip_dir is None else str(unzip_dir)
        self.variables = {v.name: v for v in md.modelVariables}
        self.messages = []
        self._logger = logger
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(self._log)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._callbacks = callbacks            # ctypes callbacks must outlive the instance
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=self.unzip_dir,
                             modelIdentifier=md.coSimulation.modelIdentifier,
                             instanceName=name)
        try:
            self.fmu.instantiate(callbacks=callbacks, loggingOn=True)
        except Exception:
            why = "; ".join(m[2] for m in self.messages if m[0] != "OK") or "no reason logged"
            self.fmu.freeLibrary()
            if self._own_dir:
                shutil.rmtree(self.unzip_dir, ignore_errors=True)
            raise CoSimulationError(f"{fmu}: fmi2Instantiate failed: {why}") from None
        self._alive = True

    def _log(self, env, instance, status, category, message):
        status_name = _STATUS[status] if 0 <= status < len(_STATUS) else str(status)
        category = category.decode("utf-8", "replace") if category else ""
        message = message.decode("utf-8", "replace") if message else ""
        # FMI 2.0's message is a printf format; these FMUs pass no arguments,
        # so formatting it only turns "%%" into "%"
        message = message.replace("%%", "%")
        self.messages.append((status_name, category, message))
        if self._logger is not None:
            self._logger(status_name, category, message)

    # -- set-up -----------------------------------------------------------------
    def initialize(self, parameters=None, inputs=None, start_time=0.0, stop_time=None,
                   tolerance=None):
        """setupExperiment (with ``tolerance`` when given), enterInitializationMode,
        set values, exitInitializationMode.

        Raises
        ------
        fmpy.fmi1.FMICallException
            When the FMU rejects the parameters (``status`` is the FMI status).
        """
        self.fmu.setupExperiment(tolerance=tolerance, startTime=start_time, stopTime=stop_time)
        self.fmu.enterInitializationMode()
        self.set(parameters or {})
        self.set(inputs or {})
        self.fmu.exitInitializationMode()

    # -- values -------------------------------------------------------------------
    def vr(self, name):
        """The value reference of the variable ``name``."""
        try:
            return self.variables[name].valueReference
        except KeyError:
            raise KeyError(f"the FMU has no variable {name!r}") from None

    def set(self, values):
        """Set variables by name (a mapping), each with the call its type needs."""
        groups = {}
        for name, value in dict(values).items():
            groups.setdefault(self.variables[name].type, []).append((self.vr(name), value))
        for kind, pairs in groups.items():
            refs, vals = [p[0] for p in pairs], [p[1] for p in pairs]
            if kind == "Real":
                self.fmu.setReal(refs, [float(v) for v in vals])
            elif kind in ("Integer", "Enumeration"):
                self.fmu.setInteger(refs, [int(v) for v in vals])
            elif kind == "Boolean":
                self.fmu.setBoolean(refs, [bool(v) for v in vals])
            else:
                self.fmu.setString(refs, [str(v) for v in vals])

    def get(self, names) -> np.ndarray:
        """Real and Integer variables by name, as one float array."""
        names = list(names)
        out = np.empty(len(names))
        reals = [(k, self.vr(n)) for k, n in enumerate(names)
                 if self.variables[n].type == "Real"]
        ints = [(k, self.vr(n)) for k, n in enumerate(names)
                if self.variables[n].type != "Real"]
        if reals:
            out[[k for k, _ in reals]] = self.fmu.getReal([r for _, r in reals])
        if ints:
            out[[k for k, _ in ints]] = self.fmu.getInteger([r for _, r in ints])
        return out

    def get_string(self, name) -> str:
        """A String variable by name."""
        return self.fmu.getString([self.vr(name)])[0].decode("utf-8")

    # -- stepping -----------------------------------------------------------------
    def step(self, t, h) -> bool:
        """doStep; ``False`` on ``fmi2Discard``, other failures raise ``FMICallException``."""
        try:
            self.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        except FMICallException as exc:
            if exc.status == fmi2Discard:
                return False
            raise
        return True

    def last_successful_time(self) -> float:
        """``fmi2GetRealStatus(fmi2LastSuccessfulTime)``."""
        return self.fmu.getRealStatus(fmi2LastSuccessfulTime)

    # -- FMU state ------------------------------------------------------------------
    def get_state(self):
        """A new FMU state (``fmi2GetFMUstate``); release it with :meth:`free_state`."""
        return self.fmu.getFMUstate()

    def set_state(self, state):
        """Restore a state (``fmi2SetFMUstate``); the state stays valid."""
        self.fmu.setFMUstate(state)

    def free_state(self, state):
        """``fmi2FreeFMUstate``."""
        self.fmu.freeFMUstate(state)

    def serialize(self, state) -> bytes:
        """The state as bytes (``fmi2SerializeFMUstate``)."""
        return self.fmu.serializeFMUstate(state)

    def deserialize(self, data: bytes):
        """A new FMU state from :meth:`serialize`'s bytes (``fmi2DeSerializeFMUstate``)."""
        return self.fmu.deSerializeFMUstate(data)

    # -- end ------------------------------------------------------------------------
    def close(self, terminate=True):
        """terminate (optionally), freeInstance, and remove the unit's own extraction."""
        if not self._alive:
            return
        self._alive = False
        try:
            if terminate:
                self.fmu.terminate()
        finally:
            self.fmu.freeInstance()
            if self._own_dir:
                shutil.rmtree(self.unzip_dir, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close(terminate=exc[0] is None)


@dataclass
class Trace:
    """What :func:`cosimulate` recorded.

    Attributes
    ----------
    times : ndarray (n,)
        Accepted communication points, the start included (the points a
        halved step added included).
    values : list of ndarray (n, k_j)
        Per unit, the observed outputs at ``times``.
    discards : list of tuple
        ``(t, h, units)`` for every step that a unit discarded, ``units`` the
        indices of the units that did.
    """

    times: np.ndarray
    values: list
    discards: list = field(default_factory=list)

    @property
    def macro_steps(self) -> int:
        """Accepted communication steps."""
        return len(self.times) - 1


def cosimulate(units: Sequence[Unit], exchange: Callable, observe: Sequence[Sequence[str]],
               t_end: float, step: float = None, *, times=None, t_start: float = 0.0,
               min_step: float = None) -> Trace:
    """Jacobi co-simulation with rollback and step halving on ``fmi2Discard``.

    Parameters
    ----------
    units : sequence of Unit
        Initialized units, all at ``t_start``.
    exchange : callable ``(t, h, values) -> list of dict``
        Given the start ``t`` and size ``h`` of the step and the list of every
        unit's observed outputs at ``t``, the inputs (name to value) to set on
        each unit for the step.
    observe : sequence of sequence of str
        Per unit, the outputs to read at every communication point.
    t_end : float
    step : float, optional
        Regular communication step; the points are ``t_start + k·step``.
    times : array_like, optional
        The communication points instead (increasing, ending at ``t_end``).
    t_start : float
    min_step : float, optional
        Halving below this raises :class:`CoSimulationError`. Default
        ``2⁻²⁰`` times the first interval.

    Returns
    -------
    Trace
    """
    if times is None:
        if not (step and step > 0):
            raise ValueError("give step > 0 or times")
        n = max(1, math.ceil((t_end - t_start) / step * (1 - 1e-12)))
        times = [min(t_start + k * step, t_end) for k in range(1, n + 1)]
    times = [float(x) for x in times]
    if any(b <= a for a, b in zip([t_start] + times, times)):
        raise ValueError("communication points must increase from t_start")
    h_min = min_step if min_step is not None else (times[0] - t_start) * 2.0 ** -20
    t = float(t_start)
    values = [u.get(names) for u, names in zip(units, observe)]
    rows_t, rows = [t], [[v] for v in values]
    discards = []
    for target in times:
        while t < target:
            h = target - t
            saved = [u.get_state() for u in units]
            try:
                while True:
                    inputs = exchange(t, h, values)
                    failed = []
                    for j, (unit, given) in enumerate(zip(units, inputs)):
                        unit.set(given)
                        if not unit.step(t, h):
                            failed.append(j)
                            break          # the step is repeated by every unit anyway
                    if not failed:
                        break
                    discards.append((t, h, failed))
                    for unit, state in zip(units, saved):
                        unit.set_state(state)
                    h *= 0.5
                    if h < h_min:
                        raise CoSimulationError(
                            f"unit(s) {failed} discarded the step from t = {t!r} down to "
                            f"h = {2 * h:.3g}; last message: "
                            f"{units[failed[0]].messages[-1][2] if units[failed[0]].messages else ''}")
            finally:
                for unit, state in zip(units, saved):
                    unit.free_state(state)
            t = target if h == target - t else t + h
            values = [u.get(names) for u, names in zip(units, observe)]
            rows_t.append(t)
            for row, v in zip(rows, values):
                row.append(v)
    return Trace(np.asarray(rows_t), [np.asarray(r) for r in rows], discards)


def spring_damper_force(xa, va, xb, vb, stiffness, damping, rest_length):
    """Force on point a of a spring-damper from a to b (the force on b is its opposite)."""
    d = np.asarray(xb, float) - np.asarray(xa, float)
    length = float(np.hypot(*d)) if d.size == 2 else float(np.linalg.norm(d))
    e = d / length
    tension = stiffness * (length - rest_length) + damping * float((np.asarray(vb) -
                                                                    np.asarray(va)) @ e)
    return tension * e


def coupled_dumbbells(fmu, t_end=0.5, step=0.002, *, stiffness=1e3, damping=0.0,
                      offset=(2.0, 0.0), rest_length=1.0, parameters=None, min_step=None):
    """Two dumbbells joined by a spring-damper, one FMU instance each.

    Dumbbell B's coordinates are shifted by ``offset`` in the master (both
    FMUs start from the dumbbell's default state), so the spring between
    particle 2 of A and particle 1 of B starts at rest length 1 with the
    defaults. The coupling is explicit: stable for ``step`` well below
    ``2/sqrt(2 stiffness / m)``.

    Parameters
    ----------
    fmu : path-like
        A dumbbell FMU (``python -m fmu build dumbbell``).
    t_end, step : float
        End time and communication step.
    stiffness, damping, rest_length : float
        Spring-damper data.
    offset : (2,) array_like
        Where B's origin lies in A's frame.
    parameters : dict, optional
        FMU parameters for both units (``scheme``, ``target_iterations``, ...).
    min_step : float, optional
        See :func:`cosimulate`.

    Returns
    -------
    dict
        ``trace`` (:class:`Trace`; per unit ``u[1..4], v[1..4], W, dE,
        internal_steps``), ``spring_energy``, ``total_energy`` and
        ``momentum`` (unit masses, the dumbbell's default) at the trace's
        times, and ``internal_steps`` of each unit.
    """
    offset = np.asarray(offset, float)
    names = [f"u[{i}]" for i in range(1, 5)] + [f"v[{i}]" for i in range(1, 5)] + \
            ["W", "dE", "internal_steps"]
    unzip = extract(str(fmu))
    units = []
    try:
        for name in ("A", "B"):
            unit = Unit(fmu, name, unzip_dir=unzip)
            units.append(unit)
            unit.initialize(parameters, start_time=0.0, stop_time=t_end)

        def exchange(t, h, values):
            a, b = values
            f = spring_damper_force(a[2:4], a[6:8], b[0:2] + offset, b[4:6], stiffness, damping,
                                    rest_length)
            return [{"F[3]": f[0], "F[4]": f[1]}, {"F[1]": -f[0], "F[2]": -f[1]}]

        trace = cosimulate(units, exchange, [names, names], t_end, step, min_step=min_step)
    finally:
        for unit in units:
            unit.close()
        shutil.rmtree(unzip, ignore_errors=True)
    a, b = trace.values
    d = b[:, 0:2] + offset - a[:, 2:4]
    spring = 0.5 * stiffness * (np.hypot(d[:, 0], d[:, 1]) - rest_length) ** 2
    momentum = a[:, 4:6] + a[:, 6:8] + b[:, 4:6] + b[:, 6:8]
    return {"trace": trace, "spring_energy": spring,
            "total_energy": a[:, 8] + b[:, 8] + spring, "momentum": momentum,
            "internal_steps": (int(a[-1, 10]), int(b[-1, 10]))}


def run_example(fmu=None, t_end=0.5, step=0.002, stiffness=1e3, damping=0.0, scheme="hfdi",
                out=print) -> int:
    """The CLI's ``master`` command: run :func:`coupled_dumbbells` and print a summary."""
    import tempfile

    from .build import build

    with tempfile.TemporaryDirectory(prefix="hfdi_fmu_master_") as tmp:
        if fmu is None:
            fmu = build("dumbbell", tmp)
        result = coupled_dumbbells(fmu, t_end, step, stiffness=stiffness, damping=damping,
                                   parameters={"scheme": scheme})
    trace = result["trace"]
    energy, momentum = result["total_energy"], result["momentum"]
    out(f"two dumbbells coupled by a spring-damper (k = {stiffness:g}, c = {damping:g}), "
        f"scheme {scheme}, t = 0 .. {t_end:g}, communication step {step:g}")
    out(f"  communication steps: {trace.macro_steps}, discarded: {len(trace.discards)}, "
        f"internal steps: A {result['internal_steps'][0]}, B {result['internal_steps'][1]}")
    out(f"  total energy: {energy[0]:.10g} -> {energy[-1]:.10g} "
        f"(relative change {(energy[-1] - energy[0]) / abs(energy[0]):.2e})")
    drift = np.abs(momentum - momentum[0]).max()
    out(f"  linear momentum: ({momentum[0, 0]:.6g}, {momentum[0, 1]:.6g}), largest drift "
        f"{drift:.2e}")
    out(f"  spring elongation at the end: "
        f"{math.sqrt(2 * result['spring_energy'][-1] / stiffness) if stiffness else 0.0:.4g}")
    return 0
