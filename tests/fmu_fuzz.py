"""Hostile calls and serialized-state bytes against an FMU's native layer.

    python tests/fmu_fuzz.py EXTRACTED_FMU [--cases N] [--seed S]

Drives one instance of the extracted FMU through its binary with raw ctypes
calls (no fmpy wrapper between): every fmi2 function with NULL pointers,
counts of 0, 1, 2^24 + 1, 2^40, 2^63 and SIZE_MAX, value references out of
range or of another type, NaN and infinite values, text that is not UTF-8,
state pointers that are not live states, in every phase of the life cycle;
then ``N`` serialized states made from a valid one (cut short, bits flipped,
bytes overwritten or inserted, random bytes after the header line), each
deserialized, restored, stepped and read. A case's sizes never exceed the
arrays it passes, except above the native layer's limits, where nothing may
be read.

The process must survive every case (run it under ASan/UBSan with
``tests/test_fmu_host.py::test_fuzz_under_sanitizers``), no call may return
``fmi2Fatal``, and every call refused (``fmi2Error``) or not carried out
(``fmi2Discard``) must come with a log message. Prints one summary line;
exit status 0 when all of that holds, 1 with the first failure otherwise.
"""
from __future__ import annotations

import argparse
import copy
import ctypes
import math
import random
import sys
from ctypes import (POINTER, byref, c_char_p, c_double, c_int, c_size_t, c_uint, c_void_p)
from pathlib import Path

import fmpy
import numpy as np
from fmpy import read_model_description
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from hfdi import serial  # noqa: E402  (the layout of the state's bytes)

STATUS = ("OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING")
SIZE_MAX = 2 ** 64 - 1
#: Counts above the native layer's limit (2^24 values a call) and beyond.
HUGE = (2 ** 24 + 1, 2 ** 31, 2 ** 32, 2 ** 40, 2 ** 63, SIZE_MAX)
REALS = (0.0, -0.0, 1.0, float("nan"), float("inf"), float("-inf"), 1.7e308, 5e-324, -1e300)
INTEGERS = (0, 1, -1, 2 ** 31 - 1, -2 ** 31, 7)
STEPS = (0.0, -0.01, float("nan"), float("inf"), float("-inf"), 5e-324, 1e-300, 1e-12, 0.001,
         0.01, 0.1)
STRINGS = (b"hfdi", b"newmark", b"", b"\xff\xfe", b"%s%n%p" * 8, b"x" * 100_000, None)


class Failure(Exception):
    """A case that broke a rule (the message says which)."""


class Fuzz:
    """One instance of the FMU, called through raw prototypes."""

    def __init__(self, unzip):
        md = read_model_description(unzip)
        self.logged = 0                                  # messages so far
        self.slave = FMU2Slave(guid=md.guid, unzipDirectory=unzip,
                               modelIdentifier=md.coSimulation.modelIdentifier,
                               instanceName="fuzz")
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(self._log)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        self._callbacks = callbacks
        self.slave.instantiate(callbacks=callbacks, loggingOn=True)
        self.c = self.slave.component
        dll = self.slave.dll
        self.types = {v.name: v.type for v in md.modelVariables}
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.n_vars = len(md.modelVariables)
        self.counts = {name: 0 for name in STATUS}
        self.calls = 0

        def fn(name, *argtypes):
            return ctypes.CFUNCTYPE(c_int, *argtypes)((name, dll))

        values = {"Real": POINTER(c_double), "Integer": POINTER(c_int),
                  "Boolean": POINTER(c_int), "String": POINTER(c_char_p)}
        self.get = {k: fn(f"fmi2Get{k}", c_void_p, POINTER(c_uint), c_size_t, t)
                    for k, t in values.items()}
        self.set = {k: fn(f"fmi2Set{k}", c_void_p, POINTER(c_uint), c_size_t, t)
                    for k, t in values.items()}
        self.setup = fn("fmi2SetupExperiment", c_void_p, c_int, c_double, c_double, c_int,
                        c_double)
        self.enter = fn("fmi2EnterInitializationMode", c_void_p)
        self.exit = fn("fmi2ExitInitializationMode", c_void_p)
        self.terminate = fn("fmi2Terminate", c_void_p)
        self.reset = fn("fmi2Reset", c_void_p)
        self.do_step = fn("fmi2DoStep", c_void_p, c_double, c_double, c_int)
        self.cancel = fn("fmi2CancelStep", c_void_p)
        self.get_state = fn("fmi2GetFMUstate", c_void_p, POINTER(c_void_p))
        self.set_state = fn("fmi2SetFMUstate", c_void_p, c_void_p)
        self.free_state = fn("fmi2FreeFMUstate", c_void_p, POINTER(c_void_p))
        self.size = fn("fmi2SerializedFMUstateSize", c_void_p, c_void_p, POINTER(c_size_t))
        self.serialize = fn("fmi2SerializeFMUstate", c_void_p, c_void_p, c_char_p, c_size_t)
        self.deserialize = fn("fmi2DeSerializeFMUstate", c_void_p, c_char_p, c_size_t,
                              POINTER(c_void_p))
        self.debug = fn("fmi2SetDebugLogging", c_void_p, c_int, c_size_t, POINTER(c_char_p))
        status_value = {"Status": POINTER(c_int), "RealStatus": POINTER(c_double),
                        "IntegerStatus": POINTER(c_int), "BooleanStatus": POINTER(c_int),
                        "StringStatus": POINTER(c_char_p)}
        self.status = {k: fn(f"fmi2Get{k}", c_void_p, c_int, t) for k, t in status_value.items()}
        self.directional = fn("fmi2GetDirectionalDerivative", c_void_p, POINTER(c_uint),
                              c_size_t, POINTER(c_uint), c_size_t, POINTER(c_double),
                              POINTER(c_double))
        self.input_derivatives = fn("fmi2SetRealInputDerivatives", c_void_p, POINTER(c_uint),
                                    c_size_t, POINTER(c_int), POINTER(c_double))
        self.output_derivatives = fn("fmi2GetRealOutputDerivatives", c_void_p,
                                     POINTER(c_uint), c_size_t, POINTER(c_int),
                                     POINTER(c_double))

    def _log(self, env, name, status, category, message):
        self.logged += 1

    def call(self, what, function, *args, logged=True):
        """``function(*args)``: its status, after the rules are checked."""
        before = self.logged
        status = function(*args)
        self.calls += 1
        if not 0 <= status <= 3:
            raise Failure(f"{what}: status {status}")
        self.counts[STATUS[status]] += 1
        if status >= 2 and logged and self.logged == before:
            raise Failure(f"{what}: {STATUS[status]} without a log message")
        return status

    # -- hostile arguments ----------------------------------------------------------
    def references(self, rng):
        """A list of value references: known ones of any type, out of range, mixed."""
        known = list(self.vr.values())
        pool = known + [self.n_vars, self.n_vars + 1, 2 ** 31, 2 ** 32 - 1]
        return [rng.choice(pool if rng.random() < 0.3 else known)
                for _ in range(rng.choice((1, 1, 2, 3, 4)))]

    def values_of(self, kind, n, rng):
        if kind == "Real":
            return (c_double * n)(*[rng.choice(REALS) for _ in range(n)])
        if kind in ("Integer", "Boolean"):
            return (c_int * n)(*[rng.choice(INTEGERS) for _ in range(n)])
        return (c_char_p * n)(*[rng.choice(STRINGS) for _ in range(n)])

    def hostile_values(self, rng):
        kind = rng.choice(("Real", "Integer", "Boolean", "String"))
        refs = self.references(rng)
        n = len(refs)
        vr = (c_uint * n)(*refs)
        out = self.values_of(kind, n, rng)
        # a count the arrays hold, or one beyond every limit (nothing may be read)
        nvr = rng.choice((n, n, n, 0, *HUGE))
        null = rng.random()
        args_vr = None if null < 0.05 else vr
        args_out = None if 0.05 <= null < 0.1 else out
        table = self.get if rng.random() < 0.5 else self.set
        self.call(f"{kind} nvr={nvr}", table[kind], self.c, args_vr, nvr, args_out)

    def hostile_states(self, rng):
        state = c_void_p()
        choice = rng.randrange(9)
        if choice == 0:
            self.call("GetFMUstate(NULL)", self.get_state, self.c, None)
        elif choice == 1:
            self.call("SetFMUstate(not a state)", self.set_state, self.c,
                      rng.choice((None, 0x1000, 0xdeadbeef, id(self))))
        elif choice == 2:
            state.value = rng.choice((0x1000, 0xdeadbeef, id(self)))
            self.call("FreeFMUstate(not a state)", self.free_state, self.c, byref(state))
        elif choice == 3:
            self.call("SerializedFMUstateSize(NULL)", self.size, self.c,
                      rng.choice((None, 0x1000)), None)
        elif choice == 4:
            size = c_size_t()
            self.call("SerializedFMUstateSize(not a state)", self.size, self.c, 0x1000,
                      byref(size))
        elif choice == 5:
            if self.call("GetFMUstate", self.get_state, self.c, byref(state)) == 0:
                size = c_size_t()
                self.call("SerializedFMUstateSize", self.size, self.c, state, byref(size))
                wrong = rng.choice((0, 1, size.value - 1, size.value + 1))
                buffer = ctypes.create_string_buffer(max(wrong, size.value) + 1)
                self.call("SerializeFMUstate(wrong size)", self.serialize, self.c, state,
                          buffer, wrong)
                self.call("SerializeFMUstate(NULL)", self.serialize, self.c, state, None,
                          size.value)
                freed = state.value
                self.call("FreeFMUstate", self.free_state, self.c, byref(state))
                self.call("SetFMUstate(freed)", self.set_state, self.c, freed)
                self.call("SerializedFMUstateSize(freed)", self.size, self.c, freed,
                          byref(size))
                state.value = freed
                self.call("FreeFMUstate(freed)", self.free_state, self.c, byref(state))
        elif choice == 6:
            data = ctypes.create_string_buffer(16)
            size = rng.choice((2 ** 63 + 5, SIZE_MAX, 2 ** 63))
            self.call(f"DeSerializeFMUstate(size {size})", self.deserialize, self.c, data,
                      size, byref(state))
        elif choice == 7:
            self.call("DeSerializeFMUstate(NULL data)", self.deserialize, self.c, None,
                      rng.choice((1, 100, SIZE_MAX)), byref(state))
        else:
            data = ctypes.create_string_buffer(8)
            self.call("DeSerializeFMUstate(NULL state)", self.deserialize, self.c, data, 8,
                      None)

    def hostile_life_cycle(self, rng):
        choice = rng.randrange(11)
        if choice == 0:
            self.call("SetupExperiment", self.setup, self.c, rng.choice((0, 1)),
                      rng.choice(REALS), rng.choice(REALS), rng.choice((0, 1)),
                      rng.choice(REALS))
        elif choice == 1:
            self.call("EnterInitializationMode", self.enter, self.c)
        elif choice == 2:
            self.call("ExitInitializationMode", self.exit, self.c)
        elif choice == 3:
            t = c_double()
            self.call("GetRealStatus", self.status["RealStatus"], self.c, 2, byref(t))
            # no step of hours: one doStep may take up to max_internal_steps
            # internal steps, which is bounded, not short
            h = rng.choice(STEPS)
            start = rng.choice((t.value, t.value, rng.choice(REALS)))
            self.call(f"DoStep({start}, {h})", self.do_step, self.c, start, h,
                      rng.choice((0, 1)))
        elif choice == 4:
            kind = rng.choice(tuple(self.status))
            value = {"Status": c_int, "RealStatus": c_double, "IntegerStatus": c_int,
                     "BooleanStatus": c_int, "StringStatus": c_char_p}[kind]()
            self.call(f"Get{kind}", self.status[kind], self.c,
                      rng.choice((0, 1, 2, 3, 4, 99, -1)),
                      None if rng.random() < 0.2 else byref(value))
        elif choice == 5:
            self.call("SetDebugLogging", self.debug, self.c, rng.choice((0, 1)),
                      rng.choice((0, 3, SIZE_MAX)), None)
        elif choice == 6:
            self.call("CancelStep", self.cancel, self.c)
        elif choice == 7:
            self.call("GetDirectionalDerivative", self.directional, self.c, None, SIZE_MAX,
                      None, SIZE_MAX, None, None)
            self.call("SetRealInputDerivatives", self.input_derivatives, self.c, None,
                      SIZE_MAX, None, None)
            self.call("GetRealOutputDerivatives", self.output_derivatives, self.c, None,
                      SIZE_MAX, None, None)
        elif choice == 8:
            self.call("Terminate", self.terminate, self.c)
        elif choice == 9:
            self.call("Reset", self.reset, self.c)
        else:
            self.initialized(rng)

    def initialized(self, rng=None):
        """Reset, set up and initialize with the defaults: a stepping instance."""
        for what, function, args in (("Reset", self.reset, ()),
                                     ("SetupExperiment", self.setup, (0, 0.0, 0.0, 0, 0.0)),
                                     ("EnterInitializationMode", self.enter, ()),
                                     ("ExitInitializationMode", self.exit, ())):
            if self.call(what, function, self.c, *args) != 0:
                raise Failure(f"{what} refused on a fresh instance")

    def hostile_arguments(self, rng, cases):
        for _ in range(cases):
            part = rng.random()
            if part < 0.5:
                self.hostile_values(rng)
            elif part < 0.75:
                self.hostile_states(rng)
            else:
                self.hostile_life_cycle(rng)

    # -- serialized states -------------------------------------------------------------
    def serialized_state(self):
        """The bytes of a valid state of an instance that took a step."""
        self.initialized()
        if self.call("DoStep", self.do_step, self.c, 0.0, 0.01, 1) != 0:
            raise Failure("doStep refused on a fresh instance")
        state, size = c_void_p(), c_size_t()
        self.call("GetFMUstate", self.get_state, self.c, byref(state))
        self.call("SerializedFMUstateSize", self.size, self.c, state, byref(size))
        buffer = ctypes.create_string_buffer(size.value)
        self.call("SerializeFMUstate", self.serialize, self.c, state, buffer, size.value)
        return state, buffer.raw[:size.value]

    @staticmethod
    def mutated(data, rng):
        data = bytearray(data)
        how = rng.randrange(6)
        if how == 0:                                        # cut short
            return bytes(data[:rng.randrange(len(data))])
        if how == 1:                                        # bits flipped
            for _ in range(rng.choice((1, 1, 2, 4, 16))):
                i = rng.randrange(len(data))
                data[i] ^= 1 << rng.randrange(8)
            return bytes(data)
        if how == 2:                                        # bytes overwritten
            i = rng.randrange(len(data))
            n = rng.randrange(1, 64)
            data[i:i + n] = bytes(rng.randrange(256) for _ in range(n))
            return bytes(data)
        if how == 3:                                        # bytes inserted or dropped
            i = rng.randrange(len(data))
            if rng.random() < 0.5:
                data[i:i] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 32)))
            else:
                del data[i:i + rng.randrange(1, 32)]
            return bytes(data)
        if how == 4:                                        # the header line, then noise
            line = bytes(data[:data.index(b"\n") + 1]) if b"\n" in data else b""
            return line + bytes(rng.randrange(256) for _ in range(rng.randrange(0, 2048)))
        return bytes(rng.randrange(256) for _ in range(rng.randrange(0, 512)))

    @staticmethod
    def _tweak(tree, rng):
        """``tree`` (a JSON value) with one entry replaced, removed or added."""
        tree = copy.deepcopy(tree)
        places = []

        def walk(node):
            if isinstance(node, dict):
                for key in node:
                    places.append((node, key))
                    walk(node[key])
            elif isinstance(node, list):
                for i in range(len(node)):
                    places.append((node, i))
                    walk(node[i])
        walk(tree)
        if not places:
            return tree
        node, key = rng.choice(places)
        what = rng.random()
        if what < 0.15 and isinstance(node, dict):
            del node[key]
        elif what < 0.25 and isinstance(node, dict):
            node[key + "_"] = 1
        else:
            node[key] = rng.choice((None, True, 0, -1, 2 ** 31, 10 ** 30, 1e308, -1e308,
                                    math.nan, math.inf, "x", "%s%n", "", [], {}, [1.0],
                                    {"a": 1}, 0.5, -0.0))
        return tree

    @staticmethod
    def _other_array(array, rng):
        how = rng.randrange(7)
        if how == 0:
            return array[:rng.randrange(array.size + 1)] if array.ndim else array
        if how == 1:
            return np.concatenate([array.ravel(), array.ravel()])
        if how == 2:
            out = np.array(array, dtype=np.float64).ravel()
            if out.size:
                out[rng.randrange(out.size)] = rng.choice((math.nan, math.inf, 1e308, -0.0))
            return out
        if how == 3:
            return array.astype(rng.choice((np.int32, np.float32, np.complex128, np.bool_)))
        if how == 4:
            return array.reshape(1, -1) if array.ndim else np.zeros((2, 2))
        if how == 5:
            return np.zeros(0)
        return np.frombuffer(bytes(rng.randrange(256) for _ in range(16)), dtype=np.uint8)

    def structured(self, data, rng):
        """``data`` with one field of the header or one array changed, packed again
        (so that the checks behind the container's are reached); the
        integrator's own bytes inside likewise."""
        magic, body = data.split(b"\n", 1)
        header, arrays = serial.unpack(body)
        inner = arrays.get("integrator")
        if inner is not None and rng.random() < 0.6:
            i_header, i_arrays = serial.unpack(inner.tobytes())
            if rng.random() < 0.5 or not i_arrays:
                i_header = self._tweak(i_header, rng)
            else:
                key = rng.choice(sorted(i_arrays))
                i_arrays[key] = self._other_array(i_arrays[key], rng)
            arrays["integrator"] = np.frombuffer(serial.pack(i_header, i_arrays),
                                                 dtype=np.uint8)
        elif rng.random() < 0.5:
            header = self._tweak(header, rng)
        else:
            key = rng.choice(sorted(arrays))
            arrays[key] = self._other_array(arrays[key], rng)
        try:
            return magic + b"\n" + serial.pack(header, arrays)
        except (TypeError, ValueError):
            return data

    def serialized_states(self, rng, cases):
        good, data = self.serialized_state()
        taken = 0
        for _ in range(cases):
            bytes_ = self.structured(data, rng) if rng.random() < 0.5 else \
                self.mutated(data, rng)
            state = c_void_p()
            status = self.call("DeSerializeFMUstate", self.deserialize, self.c, bytes_,
                               len(bytes_), byref(state))
            if status != 0:
                continue
            if self.call("SetFMUstate", self.set_state, self.c, state) == 0:
                taken += 1
                t = c_double()
                self.call("GetRealStatus", self.status["RealStatus"], self.c, 2, byref(t))
                self.call("DoStep", self.do_step, self.c, t.value, 0.01, 0)
                refs = (c_uint * 2)(self.vr["u[1]"], self.vr["W"])
                out = (c_double * 2)()
                self.call("GetReal", self.get["Real"], self.c, refs, 2, out)
            self.call("FreeFMUstate", self.free_state, self.c, byref(state))
            if self.call("SetFMUstate(good)", self.set_state, self.c, good) != 0:
                raise Failure("the valid state is refused after a fuzzed one")
        return taken


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("fmu", help="an extracted FMU")
    parser.add_argument("--cases", type=int, default=2000,
                        help="serialized states (and twice as many hostile calls)")
    parser.add_argument("--seed", type=int, default=26)
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    fuzz = Fuzz(args.fmu)
    try:
        fuzz.hostile_arguments(rng, 2 * args.cases)
        hostile = fuzz.calls
        taken = fuzz.serialized_states(rng, args.cases)
    except Failure as exc:
        print(f"fuzz: FAILED after {fuzz.calls} calls: {exc}")
        return 1
    counts = ", ".join(f"{name} {n}" for name, n in fuzz.counts.items() if n)
    print(f"fuzz: {hostile} hostile calls, {args.cases} serialized states "
          f"({taken} restored); statuses: {counts}; no fatal, every refusal logged")
    fuzz.slave.freeInstance()
    return 0


if __name__ == "__main__":
    sys.exit(main())
