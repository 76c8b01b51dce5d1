"""The Python side of the FMU's native layer (``fmu/native/hfdi_fmi2.c``).

:mod:`fmu.build` copies this file into the FMU's resources under a
build-specific name and writes ``hfdi_fmu.json`` beside it (the slave's
module and class, the GUID, the build interpreter's ``sys.path``). The native
layer puts the resources folder first on ``sys.path``, imports this module
and calls :func:`instantiate`; every later FMI call is a method of the
:class:`Adapter` it returns.

The contract with the native layer: a method returns plain values (floats,
ints, bools, str, bytes, lists) or raises. An exception is that call's
``fmi2Error`` with the exception's text as the log message, and the instance
is as before the call (the slave checks everything before it changes
anything). ``do_step`` returning ``False`` is ``fmi2Discard``. Messages the
slave queued are collected after every call by :meth:`Adapter.take_log`.

This module imports nothing of the project: it must run in any host that
can load the FMU.
"""
from __future__ import annotations

import ctypes
import importlib
import json
import os
import sys

__all__ = ["instantiate", "Adapter", "CONFIG", "GATE_FIELDS"]

#: The build's description of the FMU, in its resources folder.
CONFIG = "hfdi_fmu.json"

#: The entries of the native path's gate, in the order of the native layer's
#: ``GATE_*`` (``fmu/native/hfdi_fmi2.c``, which describes the protocol): armed,
#: dirty (native steps not yet taken over by the slave), the C function and its
#: context (:class:`hfdi.compiled.NativeAdvance`), the addresses of the time,
#: of the state arrays and of the inputs, the value-reference table and its
#: length, the CPU nanoseconds of the native steps not yet counted, and the
#: doSteps, reads and writes the native path served (for tests and
#: diagnostics), and whether the states may be read there (also on the
#: Python path, from a copy the slave makes after its doStep).
GATE_FIELDS = ("armed", "dirty", "function", "context", "time", "state", "inputs", "table",
               "table_length", "cpu_ns", "steps", "reads", "writes", "readable")
GATE_SIZE = 16


def instantiate(resources: str, instance_name: str, guid: str, visible: bool,
                logging_on: bool, own_interpreter: bool = False) -> "Adapter":
    """``fmi2Instantiate``: check the GUID and the resources, make the slave.

    ``own_interpreter``: the native layer started this interpreter (a host
    that is not Python); the build interpreter's package folders are then
    added to ``sys.path``. A Python host keeps its own environment.

    Raises
    ------
    ValueError
        For a GUID that is not this FMU's, or damaged resources; the message
        says which, in one line.
    """
    path = os.path.join(resources, CONFIG)
    try:
        with open(path, encoding="utf-8") as f:
            config = json.load(f)
        module_name, class_name, own_guid = config["module"], config["class"], config["guid"]
        extra_path = [str(p) for p in config.get("path", [])]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"the FMU's resources are damaged: {path} cannot be read "
                         f"({type(exc).__name__})") from None
    if guid != own_guid:
        raise ValueError(f"the GUID {guid!r} is not this FMU's ({own_guid}): the model "
                         f"description and the binary do not belong together")
    # the build interpreter's packages (numpy, scipy) for a host that has no
    # Python of its own
    if own_interpreter:
        for entry in extra_path:
            if entry not in sys.path:
                sys.path.append(entry)
    try:
        module = importlib.import_module(module_name)
        slave_class = getattr(module, class_name)
    except Exception as exc:
        raise ValueError(f"the FMU's resources are damaged: its slave {module_name}."
                         f"{class_name} cannot be loaded ({type(exc).__name__}: {exc})") from None
    return Adapter(slave_class, resources, instance_name, visible)


class Adapter:
    """One FMU instance: the slave and the calls of the native layer."""

    def __init__(self, slave_class, resources, instance_name, visible):
        self._make = lambda: slave_class(instance_name=instance_name, resources=resources,
                                         visible=visible)
        self._pending = []
        # the native path's gate: lives as long as this adapter, across resets
        self.gate = (ctypes.c_int64 * GATE_SIZE)()
        self.slave = self._attached(self._make())

    def _attached(self, slave):
        attach = getattr(slave, "attach_native_gate", None)
        if attach is not None:
            attach(self.gate, GATE_FIELDS)
        return slave

    # -- the native path ----------------------------------------------------------
    def native_gate(self) -> int:
        """The gate's address, for the native layer (0: no native path)."""
        if getattr(self.slave, "attach_native_gate", None) is None:
            return 0
        return ctypes.addressof(self.gate)

    def sync_native(self):
        """The slave takes over the steps the native layer took."""
        self.slave.sync_native()

    # -- log ------------------------------------------------------------------
    def take_log(self) -> list:
        """The slave's queued messages as ``(status, category, text)``, emptied."""
        if not self._pending and not self.slave.log_queue:     # after almost every call
            return []
        queue = self._pending + list(self.slave.log_queue)
        self._pending = []
        del self.slave.log_queue[:]
        return [(int(m.status), str(m.category or ""), str(m.msg)) for m in queue]

    # -- life cycle ---------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time, tolerance):
        self.slave.setup_experiment(start_time, stop_time, tolerance)

    def enter_initialization_mode(self):
        self.slave.enter_initialization_mode()

    def exit_initialization_mode(self):
        self.slave.exit_initialization_mode()

    def terminate(self):
        self.slave.terminate()

    def reset(self):
        """``fmi2Reset``: a new slave, as after ``fmi2Instantiate``."""
        for i in range(GATE_SIZE):
            self.gate[i] = 0
        fresh = self._attached(self._make())
        self._pending += list(self.slave.log_queue)
        self.slave = fresh

    def do_step(self, current_time, step_size) -> bool:
        return bool(self.slave.do_step(current_time, step_size))

    def time(self) -> float:
        return self.slave.time()

    # -- values -------------------------------------------------------------------
    def get_real(self, refs):
        return list(map(float, self.slave.get_real(refs)))

    def get_integer(self, refs):
        return [int(x) for x in self.slave.get_integer(refs)]

    def get_boolean(self, refs):
        return [bool(x) for x in self.slave.get_boolean(refs)]

    def get_string(self, refs):
        return [str(x) for x in self.slave.get_string(refs)]

    def set_real(self, refs, values):
        self.slave.set_real(refs, values)

    def set_integer(self, refs, values):
        self.slave.set_integer(refs, values)

    def set_boolean(self, refs, values):
        self.slave.set_boolean(refs, values)

    def set_string(self, refs, values):
        self.slave.set_string(refs, values)

    # -- FMU states ---------------------------------------------------------------
    def get_state(self):
        return self.slave._get_fmu_state()

    def set_state(self, state):
        self.slave._set_fmu_state(state)

    def serialize(self, state) -> bytes:
        return bytes(self.slave.serialize_state(state))

    def deserialize(self, data: bytes):
        return self.slave.deserialize_state(data)

