"""Robustness properties of the dumbbell FMU under whatever a master sends.

A Hypothesis state machine drives one FMU instance through fmpy's low-level
FMI 2.0 API with random sequences of: parameters (valid and invalid, before
and after initialization; ``compiled`` among them, which puts the doSteps,
the reads of states and the writes of inputs on the native path), inputs (NaN, infinities, huge and ordinary
values), the initialization calls, ``doStep`` with any step size and a
current time that need not be the FMU's, ``fmi2GetFMUstate`` /
``fmi2SetFMUstate``, (de)serialization, corrupt serialized states, String
values that are not UTF-8, wrong value references, ``fmi2Reset``,
``fmi2Terminate``, initialization calls out of place and output reads.
Properties:

* the process survives (the instances run in this process, and a subprocess
  checks the exit);
* no call returns ``fmi2Fatal``, and only these return ``fmi2Error`` (a
  refusal, as FMI 2.0 defines it): ``fmi2ExitInitializationMode`` with an
  invalid parameter (naming it) or a non-finite input, ``fmi2SetFMUstate``
  with a corrupt state, ``fmi2SetString`` with bytes that are not UTF-8, a get
  or set with a wrong value reference, an initialization call out of place;
  each with an ``fmi2Error`` log message, and each leaving the FMU as it was;
* every status other than ``fmi2OK`` comes with a log message;
* a discarded ``doStep`` leaves every variable bit-identical; an accepted one
  leaves finite outputs; a ``doStep`` that is invalid (before or after the
  simulation, wrong current time, step size not positive and finite,
  non-finite input) is discarded;
* restoring a saved state (also through serialization) gives bit-identical
  variables, and repeating the operations made after the save gives
  bit-identical statuses, log messages and variables;
* ``fmi2Reset`` gives back the freshly instantiated FMU, bit for bit.

The FMU is built once per session; its native layer runs the slave in this process
with the ``hfdi`` bundled in the FMU. The file also checks the answer to each
invalid call of the FMU table of ``docs/robustness.md`` and writes that table
(``python tests/test_fmu_properties.py --write``).
"""
import copy
import math
import os
import subprocess
import sys
import textwrap
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:               # run as a script (see the end of the file)
    sys.path.insert(0, str(ROOT))

pytest.importorskip("pythonfmu")
pytest.importorskip("fmpy")

from fmpy import extract  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi2 import fmi2String, fmi2ValueReference  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.stateful import (RuleBasedStateMachine, initialize, precondition,  # noqa: E402
                                 rule, run_state_machine_as_test)

import hfdi  # noqa: E402
from fmu.build import build  # noqa: E402
from fmu.master import Unit  # noqa: E402
from problems import write_doc_table  # noqa: E402

#: the FMU tests run in one worker (--dist loadgroup): the FMUs are built, and
#: their copy of the compiled loops loaded, once per session rather than per worker
pytestmark = pytest.mark.xdist_group("fmu")

STATUS = ("OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING")
FMI_STATUS = {"OK": "fmi2OK", "WARNING": "fmi2Warning", "DISCARD": "fmi2Discard",
              "ERROR": "fmi2Error", "FATAL": "fmi2Fatal", "PENDING": "fmi2Pending"}
N = 4                                               # dumbbell DOFs
OUTPUTS = [f"{k}[{i}]" for k in "uva" for i in range(1, N + 1)] + ["stretch", "W", "dE"]
COUNTERS = ["internal_steps", "newton_iterations"]
INPUTS = [f"F[{i}]" for i in range(1, N + 1)]
REAL_PARAMETERS = ["target_iterations", "tolerance", "initial_step", "max_step", "A", "sigma"]
READ = OUTPUTS + COUNTERS + INPUTS + REAL_PARAMETERS + ["max_internal_steps"]
#: Internal steps one doStep may take in the machine: a huge step costs this much.
WORK_LIMIT = 300
NAN, INF = math.nan, math.inf
SCHEMES = tuple(hfdi.SCHEMES)


# -- what a master may send ---------------------------------------------------------------
def _valid_scheme(value: str) -> bool:
    return value.strip().lower() in SCHEMES


_text = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\0"),
                max_size=12)
SCHEME_VALUES = st.one_of(
    st.sampled_from(["newmark", "bathe", "hfdi", "HFDI", " Bathe "]),
    st.sampled_from(["", "euler", "hfdi2", "h f d i", "\u0127fdi", "x" * 5000, "None", "nan"]),
    _text).map(lambda v: ("scheme", v, _valid_scheme(v)))

# (name, value, surely valid); a value not surely valid may still be accepted
# (1e300 for max_step, a denormal tolerance)
_IFFY_REALS = [0.0, -1.0, -0.0, NAN, INF, -INF, 1e300, -1e300, 5e-324]


def _real(name, valid, iffy):
    return st.one_of(valid.map(lambda v: (name, v, True)),
                     st.sampled_from(iffy + _IFFY_REALS).map(lambda v: (name, v, False)))


PARAMETER_VALUES = st.one_of(
    SCHEME_VALUES,
    _real("target_iterations", st.floats(1.0, 6.0), [0.5, 100.5, 101.0]),
    _real("tolerance", st.floats(1e-12, 1e-3), [1.0, 1.5]),
    _real("initial_step", st.sampled_from([0.0, 1e-4, 0.01]), []),
    _real("max_step", st.sampled_from([0.0, 0.05, 1.0]), [1e-13, 1e-300]),
    _real("A", st.floats(1e4, 1e6), [1e-300]),
    _real("sigma", st.floats(0.7, 0.85), [1e-300, 100.0]),
    st.sampled_from([1, 20, WORK_LIMIT]).map(lambda v: ("max_internal_steps", v, True)),
    # the compiled driver, and with it the native layer's doSteps and reads
    st.sampled_from([True, False]).map(lambda v: ("compiled", v, True)),
    st.sampled_from([0, -1, -2 ** 31]).map(lambda v: ("max_internal_steps", v, False)),
)
INPUT_VALUES = st.one_of(
    st.floats(-1e3, 1e3),
    st.sampled_from([0.0, -0.0, NAN, INF, -INF, 1e300, -1e300, 1.7e308, 5e-324]))
STEP_SIZES = st.one_of(
    st.floats(1e-4, 0.1),
    st.sampled_from([0.0, -0.0, -0.1, -1e-300, 5e-324, 1e-300, 1e-15, 1e-9, 1e6, 1e300,
                     NAN, INF, -INF]))
CURRENT_TIMES = st.sampled_from(["now", "now", "now", "near", "ahead", "behind", "nan", "inf"])
START_TIMES = st.sampled_from([0.0, 0.0, 1.25, -2.0, 1e6, NAN, INF])


# -- calls and their properties ---------------------------------------------------------------
@dataclass
class Track:
    """What the machine expects of the FMU (the model the properties are checked against).

    Attributes
    ----------
    phase : str
        ``instantiated``, ``initialization``, ``stepping`` or ``terminated``.
    t : float
        The FMU's time while stepping.
    start : float
        The start time ``fmi2SetupExperiment`` gave (0 by default).
    iffy : frozenset of str
        Parameters whose current value is not surely valid.
    inputs : tuple of float
    """

    phase: str = "instantiated"
    t: float = 0.0
    start: float = 0.0
    iffy: frozenset = frozenset()
    inputs: tuple = (0.0,) * N


@dataclass
class Saved:
    """An FMU state, what the FMU showed when it was taken, and what came after.

    Attributes
    ----------
    state : fmpy FMU state
    read : tuple
        :meth:`FmuMachine.read` when the state was taken.
    track : Track
    trace : list of tuple
        ``(operation, arguments, result)`` of every operation made since,
        until an operation jumped elsewhere (restore, reset, replay).
    end : Track or None
        The track at the end of the trace, once closed.
    """

    state: object
    read: tuple
    track: Track
    trace: list = field(default_factory=list)
    end: Track = None


class FmuMachine(RuleBasedStateMachine):
    """One FMU instance driven by random sequences of FMI calls (see the module docstring)."""

    fmu = None                     # (path, extraction), set by the test

    def __init__(self):
        super().__init__()
        path, unzip = self.fmu
        self.unit = Unit(path, "property", unzip_dir=unzip)
        self.track = Track()
        self.saves = []
        self.replaying = False
        self.fresh = self.read()

    def teardown(self):
        for saved in self.saves:
            self.unit.free_state(saved.state)
        self.unit.close(terminate=False)

    # -- helpers --------------------------------------------------------------------
    def call(self, function, *args, error=False):
        """Run one FMI call: its status, value and log messages, the common properties checked.

        Parameters
        ----------
        function : callable
            A method of fmpy's ``FMU2Slave`` or of :class:`fmu.master.Unit`.
        error : bool
            Whether ``fmi2Error`` (a refusal) is a documented answer here.

        Returns
        -------
        status : str
        value : object
        messages : list of (status, category, message)
        """
        start = len(self.unit.messages)
        try:
            value, status = function(*args), "OK"
        except FMICallException as exc:
            value, status = None, STATUS[exc.status]
        messages = self.unit.messages[start:]
        where = f"{getattr(function, '__name__', function)}{args!r:.200}"
        assert status != "FATAL", (where, messages)
        assert status != "ERROR" or error, (where, messages)
        if status != "OK":
            assert any(m[0] == status and m[2] for m in messages), (where, status, messages)
        return status, value, messages

    def read(self):
        """Every variable the machine looks at, as bytes (bit-identical comparisons)."""
        status, values, _ = self.call(self.unit.get, READ)
        assert status == "OK"
        status, scheme, _ = self.call(self.unit.get_string, "scheme")
        assert status == "OK"
        return np.asarray(values, dtype=float).tobytes(), scheme

    @staticmethod
    def outputs(read):
        return np.frombuffer(read[0])[:len(OUTPUTS)]

    def apply(self, operation, args):
        """Run a traced operation; its result must repeat bit for bit after a restore."""
        result = getattr(self, "_" + operation)(*args)
        if not self.replaying:
            for saved in self.saves:
                if saved.end is None:
                    saved.trace.append((operation, args, result))
        return result

    def close_traces(self):
        for saved in self.saves:
            if saved.end is None:
                saved.end = copy.copy(self.track)

    def limit_work(self):
        """Keep a huge communication step cheap: it is discarded after WORK_LIMIT steps."""
        self.apply("set_parameter", ("max_internal_steps", WORK_LIMIT, True))

    # -- traced operations ------------------------------------------------------------
    def _set_parameter(self, name, value, valid):
        before = self.read()
        early = self.track.phase in ("instantiated", "initialization")
        status, _, messages = self.call(self.unit.set, {name: value}, error=not early)
        if early:
            assert status == "OK"
            iffy = self.track.iffy - {name}
            self.track.iffy = iffy if valid else iffy | {name}
        else:
            # fixed after initialization (FMI): refused, nothing changes
            assert status == "ERROR"
            assert any(m[0] == "ERROR" and "fixed after initialization" in m[2]
                       for m in messages), messages
            assert self.read() == before
        return status, messages

    def _set_input(self, i, value):
        status, _, messages = self.call(self.unit.set, {f"F[{i}]": value})
        assert status == "OK"
        inputs = list(self.track.inputs)
        inputs[i - 1] = value
        self.track.inputs = tuple(inputs)
        return status, messages

    def _begin_initialization(self, start):
        fmu = self.unit.fmu
        status, _, messages = self.call(fmu.setupExperiment, None, start, None,
                                        error=not math.isfinite(start))
        if math.isfinite(start):
            assert status == "OK"
            self.track.start = start
        else:
            assert status == "ERROR"
            assert any("not finite" in m[2] for m in messages), messages
        status, _, more = self.call(fmu.enterInitializationMode)
        assert status == "OK"
        messages = messages + more
        self.track.phase = "initialization"
        return status, messages

    def _exit_initialization(self):
        bad_inputs = {f"F[{i + 1}]" for i, x in enumerate(self.track.inputs)
                      if not math.isfinite(x)}
        culprits = self.track.iffy | bad_inputs
        status, _, messages = self.call(self.unit.fmu.exitInitializationMode,
                                        error=bool(culprits))
        if status == "ERROR":
            errors = " ".join(m[2] for m in messages if m[0] == "ERROR")
            assert any(f"{name} = " in errors for name in culprits), (culprits, errors)
        else:
            assert status == "OK"
            self.track.phase, self.track.t = "stepping", self.track.start
            assert np.all(np.isfinite(self.outputs(self.read())))
        return status, messages

    def _do_step(self, where, h):
        t = self.track.t if self.track.phase in ("stepping", "terminated") else self.track.start
        current = {"now": t, "near": t + 1e-12 * h if math.isfinite(h) and h > 0 else t,
                   "ahead": t + 0.5, "behind": t - 0.25, "nan": NAN, "inf": INF}[where]
        before = self.read()
        status, _, messages = self.call(self.unit.fmu.doStep, current, h)
        after = self.read()
        assert status in ("OK", "DISCARD")
        elsewhere = not math.isfinite(current) or (
            abs(current - t) > max(64 * math.ulp(max(abs(current), abs(t))), 1e-10 * h))
        invalid = (self.track.phase != "stepping" or not (math.isfinite(h) and h > 0)
                   or elsewhere or not all(map(math.isfinite, self.track.inputs)))
        if invalid:
            assert status == "DISCARD", (self.track, current, h, messages)
        if status == "DISCARD":
            assert after == before, "a discarded step changed the FMU"
        else:
            self.track.t = current + h
            assert np.all(np.isfinite(self.outputs(after))), (current, h, after)
        return status, messages, after

    def _run_of_steps(self, n, h, value):
        """``n`` doSteps of ``h`` at the FMU's time with nothing but a read of the
        states between them (on the compiled path: the native layer's own), an
        input set before the middle one when ``value`` is given."""
        fmu = self.unit.fmu
        refs = [self.unit.vr(name) for name in OUTPUTS[:3 * N]]
        answers = []
        states = list(fmu.getReal(refs))
        for k in range(n):
            if value is not None and k == n // 2:
                self._set_input(1, value)
            before = states
            status, _, messages = self.call(fmu.doStep, self.track.t, h)
            assert status in ("OK", "DISCARD")
            states = list(fmu.getReal(refs))
            if status == "DISCARD":
                assert states == before, "a discarded step changed the FMU"
            else:
                self.track.t = self.track.t + h
                assert all(map(math.isfinite, states)), states
            answers.append((status, [m[2] for m in messages], states))
        after = self.read()
        # the states read by the native layer are those the slave reads
        assert np.asarray(states, dtype=float).tobytes() == \
            np.asarray(self.outputs(after)[:3 * N]).tobytes()
        return answers, after

    def _read_outputs(self):
        read = self.read()
        if self.track.phase in ("stepping", "terminated"):
            assert np.all(np.isfinite(self.outputs(read))), read
        return read

    def _terminate(self):
        status, _, messages = self.call(self.unit.fmu.terminate)
        assert status == "OK"
        self.track.phase = "terminated"
        return status, messages

    def _misplaced_initialization(self, which):
        before = self.read()
        function = {"enter": self.unit.fmu.enterInitializationMode,
                    "exit": self.unit.fmu.exitInitializationMode}[which]
        status, _, messages = self.call(function, error=True)
        assert status == "ERROR"
        assert any("the FMU is" in m[2] for m in messages), messages
        assert self.read() == before
        return status, messages

    # -- rules --------------------------------------------------------------------------
    @initialize(start=st.sampled_from([None, 0.0, 0.0, 1.25]), compiled=st.booleans())
    def start(self, start, compiled):
        """Most runs begin initialized, as a master would have it; half of them
        compiled (the native path)."""
        self.limit_work()
        if compiled:
            self.apply("set_parameter", ("compiled", True, True))
        if start is not None:
            self.apply("begin_initialization", (start,))
            self.apply("exit_initialization", ())

    @rule(case=PARAMETER_VALUES)
    def set_parameter(self, case):
        self.apply("set_parameter", case)

    @rule(i=st.integers(1, N), value=INPUT_VALUES)
    def set_input(self, i, value):
        self.apply("set_input", (i, value))

    @precondition(lambda self: self.track.phase == "instantiated")
    @rule(start=START_TIMES)
    def begin_initialization(self, start):
        self.apply("begin_initialization", (start,))

    @precondition(lambda self: self.track.phase == "initialization")
    @rule()
    def exit_initialization(self):
        self.apply("exit_initialization", ())

    @rule(where=CURRENT_TIMES, h=STEP_SIZES)
    def do_step(self, where, h):
        self.apply("do_step", (where, h))

    @precondition(lambda self: self.track.phase == "stepping")
    @rule(n=st.integers(2, 8), h=st.floats(1e-4, 0.02),
          value=st.one_of(st.none(), st.floats(-1e3, 1e3)))
    def run_of_steps(self, n, h, value):
        """A master's ordinary run of doSteps (see :meth:`_run_of_steps`)."""
        self.apply("run_of_steps", (n, h, value))

    @rule()
    def read_outputs(self):
        self.apply("read_outputs", ())

    @precondition(lambda self: self.track.phase == "stepping")
    @rule()
    def terminate(self):
        self.apply("terminate", ())

    @precondition(lambda self: self.track.phase in ("stepping", "terminated"))
    @rule(which=st.sampled_from(["enter", "exit"]))
    def misplaced_initialization(self, which):
        self.apply("misplaced_initialization", (which,))

    @precondition(lambda self: self.track.phase == "instantiated")
    @rule()
    def exit_before_enter(self):
        """fmi2ExitInitializationMode without fmi2EnterInitializationMode."""
        self.apply("misplaced_initialization", ("exit",))

    @precondition(lambda self: len(self.saves) < 8)
    @rule()
    def save_state(self):
        status, state, _ = self.call(self.unit.get_state)
        assert status == "OK"
        self.saves.append(Saved(state, self.read(), copy.copy(self.track)))

    @precondition(lambda self: self.saves)
    @rule(k=st.integers(0, 7))
    def restore_state(self, k):
        saved = self.saves[k % len(self.saves)]
        self.close_traces()
        status, _, _ = self.call(self.unit.set_state, saved.state)
        assert status == "OK"
        assert self.read() == saved.read, "the restored FMU differs from the saved one"
        self.track = copy.copy(saved.track)

    @precondition(lambda self: any(saved.trace for saved in self.saves))
    @rule(k=st.integers(0, 7))
    def replay(self, k):
        """Restore a state and repeat what followed it: the same answers, bit for bit."""
        self.close_traces()
        saved = [s for s in self.saves if s.trace][k % sum(1 for s in self.saves if s.trace)]
        status, _, _ = self.call(self.unit.set_state, saved.state)
        assert status == "OK"
        assert self.read() == saved.read
        self.track = copy.copy(saved.track)
        self.replaying = True
        try:
            for operation, args, result in saved.trace:
                again = getattr(self, "_" + operation)(*args)
                assert again == result, (operation, args, result, again)
        finally:
            self.replaying = False
        assert self.track == saved.end

    @precondition(lambda self: self.saves and len(self.saves) < 8)
    @rule(k=st.integers(0, 7))
    def serialize_and_deserialize(self, k):
        saved = self.saves[k % len(self.saves)]
        status, data, _ = self.call(self.unit.serialize, saved.state)
        assert status == "OK" and data
        status, state, _ = self.call(self.unit.deserialize, data)
        assert status == "OK"
        status, data_again, _ = self.call(self.unit.serialize, state)
        assert status == "OK" and data_again == data
        end = saved.end if saved.end is not None else copy.copy(self.track)
        self.saves.append(replace(saved, state=state, trace=list(saved.trace), end=end))

    @rule(k=st.integers(0, 7), how=st.sampled_from(["half", "empty", "foreign", "junk",
                                                    "shifted"]))
    def restore_corrupt_state(self, k, how):
        """A corrupt serialized state is refused and leaves the FMU as it was."""
        data = b"hfdi-fmu-state/2\n\x80\x04K"
        if self.saves:
            status, data, _ = self.call(self.unit.serialize, self.saves[k % len(self.saves)].state)
            assert status == "OK"
        bad = {"half": data[:len(data) // 2], "empty": b"", "foreign": b"not a state",
               "junk": data[:17] + b"\x80\x04junk", "shifted": data[1:]}[how]
        before = self.read()
        status, state, messages = self.call(self.unit.deserialize, bad, error=True)
        assert status == "ERROR"
        assert any("fmi2DeSerializeFMUstate" in m[2] for m in messages), messages
        assert self.read() == before

    @rule(data=st.sampled_from([b"sch\xe8me", b"\xff", b"hfdi\xc3"]))
    def set_undecodable_string(self, data):
        """A String value that is not UTF-8 is refused and changes nothing."""
        before = self.read()
        status, _, messages = self.call(_raw_set_string, self.unit, "scheme", data, error=True)
        assert status == "ERROR"
        assert any("not UTF-8" in m[2] for m in messages), messages
        assert self.read() == before

    @rule(call=st.sampled_from(["get unknown", "set unknown", "get as Integer",
                                "set as Real"]))
    def wrong_value_reference(self, call):
        """A value reference that does not exist or has another type is refused."""
        fmu, unknown, scheme = self.unit.fmu, 10 ** 6, self.unit.vr("scheme")
        function, args = {"get unknown": (fmu.getReal, ([unknown],)),
                          "set unknown": (fmu.setReal, ([unknown], [1.0])),
                          "get as Integer": (fmu.getInteger, ([scheme],)),
                          "set as Real": (fmu.setReal, ([scheme], [1.0]))}[call]
        before = self.read()
        status, _, messages = self.call(function, *args, error=True)
        assert status == "ERROR"
        assert self.read() == before

    @rule()
    def reset(self):
        self.close_traces()
        status, _, _ = self.call(self.unit.fmu.reset)
        assert status == "OK"
        assert self.read() == self.fresh, "fmi2Reset did not give back the fresh FMU"
        self.track = Track()
        self.limit_work()


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.slow
def test_fmu_answers_every_call_sequence(dumbbell_fmu):
    FmuMachine.fmu = dumbbell_fmu
    run_state_machine_as_test(FmuMachine, settings=settings(
        max_examples=60, stateful_step_count=30, deadline=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large]))


# -- single calls whose answers docs/robustness.md documents -----------------------------------
def _raw_set_string(unit, name, data: bytes):
    """fmi2SetString with raw bytes (fmpy's setString encodes str values as UTF-8)."""
    vr = (fmi2ValueReference * 1)(unit.vr(name))
    unit.fmu.fmi2SetString(unit.fmu.component, vr, 1, (fmi2String * 1)(data))


def _exit_with(parameters=None, inputs=None):
    def act(unit):
        unit.fmu.setupExperiment(startTime=0.0)
        unit.fmu.enterInitializationMode()
        unit.set(parameters or {})
        unit.set(inputs or {})
        return unit.fmu.exitInitializationMode
    return act


def _after_initialization(call, parameters=None, inputs=None, start_time=0.0, then=(),
                          stop_time=None):
    def act(unit):
        unit.initialize(parameters or {}, start_time=start_time, stop_time=stop_time)
        for step in then:
            step(unit)
        unit.set(inputs or {})
        return lambda: call(unit)
    return act


def _corrupt(data_of):
    def act(unit):
        unit.initialize({})
        data = data_of(unit)
        return lambda: unit.deserialize(data)
    return act


#: (case, mistake or fault, how to make the call: unit -> call, status, text logged)
DOCUMENTED = [
    ("start-nan", "fmi2SetupExperiment with start time NaN",
     lambda unit: lambda: unit.fmu.setupExperiment(startTime=NAN), "ERROR", "is not finite"),
    ("setup-late", "fmi2SetupExperiment after initialization",
     _after_initialization(lambda unit: unit.fmu.setupExperiment(startTime=1.0)), "ERROR",
     "before fmi2EnterInitializationMode"),
    ("scheme", "`scheme` = \"euler\", then fmi2ExitInitializationMode",
     _exit_with({"scheme": "euler"}), "ERROR", "scheme = 'euler'"),
    ("scheme-bytes", "`scheme` set to bytes that are not UTF-8 (fmi2SetString)",
     lambda unit: lambda: _raw_set_string(unit, "scheme", b"sch\xe8me"), "ERROR",
     "not UTF-8"),
    ("target-nan", "`target_iterations` = NaN", _exit_with({"target_iterations": NAN}),
     "ERROR", "target_iterations = nan"),
    ("target-huge", "`target_iterations` = 1e6 with `tolerance` = 1e-14 (a step's Newton "
     "solve would run 2e6 corrections)",
     _exit_with({"target_iterations": 1e6, "tolerance": 1e-14}), "ERROR", "in [1, 100]"),
    ("tolerance", "`tolerance` = 1.5", _exit_with({"tolerance": 1.5}), "ERROR",
     "tolerance = 1.5"),
    ("tolerance-tiny", "`tolerance` = 1e-300, below ten machine epsilons",
     _exit_with({"tolerance": 1e-300}), "ERROR", "tolerance = 1e-300"),
    ("initial-step", "`initial_step` = -1", _exit_with({"initial_step": -1.0}), "ERROR",
     "initial_step = -1.0"),
    ("max-step-inf", "`max_step` = inf", _exit_with({"max_step": INF}), "ERROR",
     "max_step = inf"),
    ("max-step-tiny", "`max_step` = 1e-13, below hfdi's smallest step",
     _exit_with({"max_step": 1e-13}), "ERROR", "min_step must be < max_step"),
    ("max-internal-steps", "`max_internal_steps` = 0", _exit_with({"max_internal_steps": 0}),
     "ERROR", "max_internal_steps = 0"),
    ("A", "`A` = -1", _exit_with({"A": -1.0}), "ERROR", "A = -1.0"),
    ("sigma-tiny", "`sigma` = 5e-324 (the stretch output overflows at t0)",
     _exit_with({"sigma": 5e-324}), "ERROR", "sigma = 5e-324"),
    ("sigma-huge", "`sigma` = 1e300 (the model's force overflows)",
     _exit_with({"sigma": 1e300}), "ERROR", "sigma = 1e+300"),
    ("input-nan-init", "input `F[1]` = NaN at fmi2ExitInitializationMode",
     _exit_with(inputs={"F[1]": NAN}), "ERROR", "F[1] = nan"),
    ("parameter-late", "parameter `scheme` set after initialization",
     _after_initialization(lambda unit: unit.set({"scheme": "bathe"})), "ERROR",
     "fixed after initialization"),
    ("output-set", "output `u[1]` set",
     _after_initialization(lambda unit: unit.set({"u[1]": 1.0})), "ERROR",
     "outputs cannot be set"),
    ("output-set-early", "output `u[1]` set before initialization",
     lambda unit: lambda: unit.set({"u[1]": 1.0}), "ERROR", "outputs cannot be set"),
    ("step-past-stop", "fmi2DoStep past the stop time of fmi2SetupExperiment",
     _after_initialization(lambda unit: unit.step(0.0, 0.2), stop_time=0.1), "ERROR",
     "past the stop time 0.1"),
    ("enter-again", "fmi2EnterInitializationMode after initialization",
     _after_initialization(lambda unit: unit.fmu.enterInitializationMode()), "ERROR",
     "enters initialization mode once"),
    ("exit-again", "fmi2ExitInitializationMode after initialization",
     _after_initialization(lambda unit: unit.fmu.exitInitializationMode()), "ERROR",
     "the FMU is"),
    ("step-early", "fmi2DoStep before initialization",
     lambda unit: lambda: unit.fmu.doStep(0.0, 0.01), "DISCARD",
     "before a successful exitInitializationMode"),
    ("step-zero", "fmi2DoStep(0, 0)",
     _after_initialization(lambda unit: unit.fmu.doStep(0.0, 0.0)), "DISCARD",
     "positive and finite"),
    ("step-negative", "fmi2DoStep(0, -0.1)",
     _after_initialization(lambda unit: unit.fmu.doStep(0.0, -0.1)), "DISCARD",
     "positive and finite"),
    ("step-nan", "fmi2DoStep(0, NaN)",
     _after_initialization(lambda unit: unit.fmu.doStep(0.0, NAN)), "DISCARD",
     "positive and finite"),
    ("step-inf", "fmi2DoStep(0, inf)",
     _after_initialization(lambda unit: unit.fmu.doStep(0.0, INF)), "DISCARD",
     "positive and finite"),
    ("time-nan", "fmi2DoStep(NaN, 0.01)",
     _after_initialization(lambda unit: unit.fmu.doStep(NAN, 0.01)), "DISCARD",
     "communication point must be finite"),
    ("time-elsewhere", "fmi2DoStep(0.5, 0.01) with the FMU at t = 0",
     _after_initialization(lambda unit: unit.fmu.doStep(0.5, 0.01)), "DISCARD",
     "but the FMU is at t = 0.0"),
    ("step-below-resolution", "fmi2DoStep(1, 1e-17): t + h == t",
     _after_initialization(lambda unit: unit.fmu.doStep(1.0, 1e-17), start_time=1.0),
     "DISCARD", "below the time resolution"),
    ("step-huge", "fmi2DoStep(0, 1e300) with `max_internal_steps` = 300",
     _after_initialization(lambda unit: unit.fmu.doStep(0.0, 1e300),
                           {"max_internal_steps": 300}),
     "DISCARD", "max_internal_steps = 300 internal steps reached"),
    ("input-nan", "fmi2DoStep with input `F[1]` = NaN",
     _after_initialization(lambda unit: unit.fmu.doStep(0.0, 0.01), inputs={"F[1]": NAN}),
     "DISCARD", "F[1] = nan is not finite"),
    ("input-huge", "fmi2DoStep with input `F[3]` = 1.7e308",
     _after_initialization(lambda unit: unit.fmu.doStep(0.0, 0.01), inputs={"F[3]": 1.7e308}),
     "DISCARD", "rejected"),
    ("step-terminated", "fmi2DoStep after fmi2Terminate",
     _after_initialization(lambda unit: unit.fmu.doStep(0.0, 0.01),
                           then=[lambda unit: unit.fmu.terminate()]),
     "DISCARD", "after fmi2Terminate"),
    ("state-foreign", "fmi2DeSerializeFMUstate with bytes the FMU did not make",
     _corrupt(lambda unit: b"not a state"), "ERROR", "not a serialized hfdi FMU state"),
    ("state-truncated", "fmi2DeSerializeFMUstate with a truncated serialized state",
     _corrupt(lambda unit: unit.serialize(unit.get_state())[:200]), "ERROR", "cannot be read"),
    ("reference-unknown", "fmi2GetReal with a value reference the FMU does not have",
     _after_initialization(lambda unit: unit.fmu.getReal([10 ** 6])), "ERROR", "#1000000"),
    ("reference-type", "fmi2SetReal on the String parameter `scheme`",
     _after_initialization(lambda unit: unit.fmu.setReal([unit.vr("scheme")], [1.0])),
     "ERROR", "is not of type Real"),
    ("cancel-step", "fmi2CancelStep (not supported)",
     _after_initialization(lambda unit: unit.fmu.cancelStep()), "ERROR", "doStep always returns"),
    ("get-status", "fmi2GetStatus (not supported)",
     _after_initialization(lambda unit: unit.fmu.getStatus(0)), "DISCARD", "not provided"),
]


def answer(fmu, make):
    """Status and log messages of the call ``make(unit)`` returns, on a new unit."""
    path, unzip = fmu
    unit = Unit(path, "documented", unzip_dir=unzip)
    try:
        call = make(unit)
        start = len(unit.messages)
        try:
            call()
            status = "OK"
        except FMICallException as exc:
            status = STATUS[exc.status]
        return status, unit.messages[start:]
    finally:
        unit.close(terminate=False)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("case, what, make, status, text", DOCUMENTED,
                         ids=[case[0] for case in DOCUMENTED])
def test_documented_answers(dumbbell_fmu, case, what, make, status, text):
    got, messages = answer(dumbbell_fmu, make)
    assert got == status, (got, messages)
    assert any(text in m[2] for m in messages), messages


def test_docs_table_covers_every_case():
    docs = ROOT / "docs" / "robustness.md"
    text = docs.read_text(encoding="utf-8")
    for case in DOCUMENTED:
        assert f"| `{case[0]}` |" in text, f"{docs.name} has no row for {case[0]}"


def fmu_table(fmu) -> str:
    """The FMU table of docs/robustness.md, by running every case of :data:`DOCUMENTED`."""
    lines = ["| case | mistake or fault | answer |", "|---|---|---|"]
    for case, what, make, _, _ in DOCUMENTED:
        status, messages = answer(fmu, make)
        text = f"`{FMI_STATUS[status]}`"
        for logged, _, message in messages:
            if logged == "OK":
                continue
            text += f": {message}" if logged == status else \
                f"; logged as {FMI_STATUS[logged]}: {message}"
        lines.append(f"| `{case}` | {what} | {text.replace('|', '/')} |")
    return "\n".join(lines)


@pytest.mark.slow
def test_process_survives_to_a_clean_exit(dumbbell_fmu):
    # an instance left unfreed and one refused with fmi2Error are the usual
    # ways a host exits
    path, unzip = dumbbell_fmu
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(ROOT)!r})
        from fmpy.fmi1 import FMICallException
        from fmu.master import Unit
        kept = Unit({str(path)!r}, "kept", unzip_dir={str(unzip)!r})
        kept.initialize({{}})
        assert kept.step(0.0, 0.05)
        refused = Unit({str(path)!r}, "refused", unzip_dir={str(unzip)!r})
        try:
            refused.initialize({{"scheme": "euler"}})
        except FMICallException:
            pass
        refused.close(terminate=False)
        print(kept.get(["u[1]"])[0])
    """)
    for _ in range(3):
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                              timeout=120, env={**os.environ, "PYTHONWARNINGS": "ignore"})
        assert done.returncode == 0, (done.returncode, done.stderr[-2000:])
        assert float(done.stdout.split()[-1]) != 0.0


if __name__ == "__main__":
    # python tests/test_fmu_properties.py          prints the FMU table
    # python tests/test_fmu_properties.py --write  updates it in docs/robustness.md
    import tempfile
    import warnings
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        built = build("dumbbell", tmp)
        generated = fmu_table((built, extract(str(built), unzipdir=str(Path(tmp) / "x"))))
    if "--write" in sys.argv[1:]:
        print(write_doc_table('fmu', generated))
    else:
        print(generated)
