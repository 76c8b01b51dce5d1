"""The FMI 3.0 co-simulation FMUs: validity, the same outputs as the FMI 2.0
FMUs of the same sources, early return at the model's events, FMU states
bit for bit, every function of fmi3Functions.h present, and refusals.

Against exact values: the impact oscillator's impacts and highest points in
closed form (hfdi.models.impact_oscillator.exact_events).
"""
import ctypes
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pythonfmu")
fmpy = pytest.importorskip("fmpy")

from fmpy import extract, read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi3 import FMU3Slave  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

import hfdi  # noqa: E402
from fmu.build import build  # noqa: E402
from fmu.cli import main  # noqa: E402
from hfdi.models.impact_oscillator import exact_events  # noqa: E402
from problems import run_in_ecos  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("fmu")]

STOP = 3.0
IMPACT_OUTPUTS = ["u[1]", "v[1]", "a[1]", "W", "dE", "internal_steps", "newton_iterations",
                  "event_count[1]", "event_time[1]", "event_count[2]", "event_time[2]"]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """FMI 2.0 and 3.0 FMUs of the impact oscillator and the dumbbell:
    ``{(model, version): path}``."""
    out = tmp_path_factory.mktemp("fmu3")
    return {(name, version): build(name, out, fmi_version=version)
            for name in ("impact_oscillator", "dumbbell") for version in (2, 3)}


class Slave3:
    """An FMI 3.0 co-simulation instance through fmpy's low-level API."""

    def __init__(self, path, early_return=False, parameters=None, unzip=None):
        self.md = read_model_description(str(path))
        self.unzip = unzip or extract(str(path))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.types = {v.name: v.type for v in self.md.modelVariables}
        self.fmu = FMU3Slave(guid=self.md.guid, unzipDirectory=self.unzip,
                             modelIdentifier=self.md.coSimulation.modelIdentifier,
                             instanceName="unit")
        self.fmu.instantiate(earlyReturnAllowed=early_return)
        self.fmu.enterInitializationMode(startTime=0.0, stopTime=STOP)
        for name, value in (parameters or {}).items():
            if isinstance(value, bool):
                self.fmu.setBoolean([self.vr[name]], [value])
            else:
                self.fmu.setFloat64([self.vr[name]], [value])
        self.fmu.exitInitializationMode()

    def get(self, names):
        out = []
        for name in names:
            if self.types[name] == "Int32":
                out.append(float(self.fmu.getInt32([self.vr[name]])[0]))
            else:
                out.append(self.fmu.getFloat64([self.vr[name]])[0])
        return np.array(out)

    def close(self):
        self.fmu.terminate()
        self.fmu.freeInstance()


def test_the_fmi3_fmus_validate_and_describe_the_fmi2_variables(built):
    for name in ("impact_oscillator", "dumbbell"):
        path3, path2 = built[(name, 3)], built[(name, 2)]
        assert path3.name == f"hfdi_{name}_fmi3.fmu"
        assert validate_fmu(str(path3)) == []
        assert validate_fmu(str(path2)) == []
        md3, md2 = read_model_description(str(path3)), read_model_description(str(path2))
        assert md3.fmiVersion == "3.0" and md2.fmiVersion == "2.0"
        assert md3.guid and md3.guid != md2.guid            # one build, one token
        assert md3.coSimulation.mightReturnEarlyFromDoStep
        assert not md3.coSimulation.hasEventMode
        assert md3.coSimulation.canGetAndSetFMUstate and md3.coSimulation.canSerializeFMUstate
        types = {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean",
                 "String": "String"}
        three = {(v.name, v.valueReference, v.type, v.causality, v.variability, v.start,
                  v.unit) for v in md3.modelVariables}
        two = {(v.name, v.valueReference, types[v.type], v.causality, v.variability, v.start,
                v.unit) for v in md2.modelVariables}
        assert three == two
        assert [v.name for v in md3.modelVariables if v.causality == "independent"] == ["time"]
        outputs3 = sorted(u.variable.valueReference for u in md3.outputs)
        assert outputs3 == sorted(u.variable.valueReference for u in md2.outputs)
        with zipfile.ZipFile(path3) as z:
            assert f"binaries/x86_64-linux/hfdi_{name}.so" in z.namelist()
            text = z.read("modelDescription.xml").decode()
        assert "fmi2" not in text and "fmi3EnterInitializationMode" in text
        assert md3.coSimulation.needsExecutionTool == md2.coSimulation.needsExecutionTool


def test_every_function_of_fmi3_functions_h_is_exported(built):
    header = Path(fmpy.__file__).parent / "c-code" / "fmi3Functions.h"
    names = re.findall(r"FMI3_Export\s+fmi3\w+TYPE\s+(fmi3\w+);", header.read_text())
    assert len(names) > 70
    unzip = extract(str(built[("dumbbell", 3)]))
    library = ctypes.CDLL(str(Path(unzip) / "binaries" / "x86_64-linux" / "hfdi_dumbbell.so"))
    missing = [name for name in names if not hasattr(library, name)]
    assert not missing


@pytest.mark.parametrize("name, outputs", [
    ("dumbbell", ["u[1]", "u[2]", "v[3]", "a[4]", "stretch", "W", "dE", "internal_steps"]),
    ("impact_oscillator", IMPACT_OUTPUTS)])
def test_fmi3_outputs_are_those_of_the_fmi2_fmu(built, name, outputs):
    stop = 0.2 if name == "dumbbell" else STOP
    runs = [simulate_fmu(str(built[(name, version)]), stop_time=stop,
                         output_interval=stop / 50, output=outputs,
                         start_values={"rtol": 1e-5}) for version in (2, 3)]
    assert len(runs[0]) == len(runs[1]) == 51
    for column in ["time"] + outputs:
        np.testing.assert_array_equal(runs[1][column], runs[0][column], err_msg=column)


def test_fmi3_event_outputs_against_the_closed_form_and_in_process(built):
    """The event outputs at every communication point: the counts and last
    times of the zeros up to there, as an in-process integrator advanced to
    the same points finds them (bit for bit) and as the closed form gives them."""
    model = hfdi.models.impact_oscillator()
    impacts, tops = exact_events(model, STOP)
    unit = Slave3(built[("impact_oscillator", 3)], parameters={"rtol": 1e-9})
    itg = hfdi.Integrator(model, "hfdi", rtol=1e-9, target_iterations=3.0, error_span=STOP,
                          max_steps=2 ** 62)
    t, h = 0.0, 0.06
    while t < STOP - 1e-12:
        unit.fmu.doStep(t, h)
        t += h
        assert itg.advance(t)
        row = unit.get(["u[1]", "v[1]", "event_count[1]", "event_time[1]", "event_count[2]",
                        "event_time[2]"])
        assert row[0] == itg.state.u[0] and row[1] == itg.state.v[0]
        for k, exact in enumerate((impacts, tops)):
            count = int(np.count_nonzero(exact <= t))
            assert row[2 + 2 * k] == count == len(itg.t_events[k])
            if count:
                assert row[3 + 2 * k] == itg.t_events[k][-1]
                assert abs(row[3 + 2 * k] - exact[count - 1]) < 2e-8
            else:
                assert row[3 + 2 * k] == 0.0
    unit.close()


def test_an_early_return_lands_on_each_event(built):
    """With earlyReturnAllowed, fmi3DoStep returns at every zero of the model's
    event functions (earlyReturn, lastSuccessfulTime the zero's time, after the
    rebound); the master goes on from there and meets every event once, in
    order, at the times a run without early returns finds."""
    model = hfdi.models.impact_oscillator()
    impacts, tops = exact_events(model, STOP)
    expected = np.sort(np.concatenate([impacts, tops]))
    path = built[("impact_oscillator", 3)]
    early = Slave3(path, early_return=True, parameters={"rtol": 1e-9})
    t, h, returns = 0.0, 0.25, []
    while t < STOP - 1e-12:
        step = min(h, STOP - t)
        handling, terminate, returned, last = early.fmu.doStep(t, step)
        assert not handling and not terminate
        if returned:
            assert t < last < t + step
            returns.append(last)
            count = early.get(["event_count[1]", "event_count[2]"])
            times = early.get(["event_time[1]", "event_time[2]"])
            # the event returned at is the last one counted
            assert last in times and count.sum() == len(returns)
            if last == times[0]:                     # an impact: on the stop, rebounding
                u, v = early.get(["u[1]", "v[1]"])
                assert u == pytest.approx(-model.gap, abs=1e-12) and v > 0
            t = last
        else:
            assert last == t + step
            t += step
    assert len(returns) == len(expected)
    np.testing.assert_allclose(returns, expected, rtol=0, atol=2e-8)
    early.close()
    # a master that saves and restores the state at every early return (as
    # one that may retry does): the same returns, each zero counted once (on
    # the compiled path, whose steps are the Python path's, bit for bit)
    again = Slave3(path, early_return=True, parameters={"rtol": 1e-9, "compiled": True})
    t, repeated = 0.0, []
    while t < STOP - 1e-12 and len(repeated) <= len(expected):
        step = min(h, STOP - t)
        returned, last = again.fmu.doStep(t, step)[2:]
        if returned:
            repeated.append(last)
            state = again.fmu.getFMUState()
            again.fmu.setFMUState(again.fmu.deserializeFMUState(
                again.fmu.serializeFMUState(state)))
            again.fmu.freeFMUState(state)
        t = last if returned else t + step
    assert repeated == returns
    assert list(again.get(["event_count[1]", "event_count[2]"])) == [len(impacts), len(tops)]
    again.close()
    # a zero at the start time (a highest point at t0) is counted, not returned at
    start = Slave3(path, early_return=True, parameters={"u0": 0.05, "v0": 0.0})
    returned, last = start.fmu.doStep(0.0, 0.25)[2:]
    assert not returned and last == 0.25
    assert list(start.get(["event_count[2]", "event_time[2]"])) == [1.0, 0.0]
    start.close()
    # without early returns: the same events, counted inside the steps
    plain = Slave3(path, early_return=False, parameters={"rtol": 1e-9, "compiled": True})
    t = 0.0
    while t < STOP - 1e-12:
        step = min(h, STOP - t)
        assert plain.fmu.doStep(t, step)[2] is False
        t += step
    counts = plain.get(["event_count[1]", "event_count[2]"])
    assert list(counts) == [len(impacts), len(tops)]
    np.testing.assert_allclose(plain.get(["event_time[1]", "event_time[2]"]),
                               [impacts[-1], tops[-1]], rtol=0, atol=2e-8)
    plain.close()


@pytest.mark.parametrize("early_return", [False, True])
def test_without_a_tolerance_a_model_with_events_is_error_controlled(built, early_return):
    """No rtol and no master tolerance: the impact oscillator's unit controls
    the error at hfdi's default rtol (the iteration count alone grew the steps
    past whole bounces: 1 impact of 4 to t = 3, differently with and without
    early return), and meets every impact and highest point of the closed
    form; the dumbbell, without events, keeps the paper's rule alone."""
    model = hfdi.models.impact_oscillator()
    impacts, tops = exact_events(model, STOP)
    unit = Slave3(built[("impact_oscillator", 3)], early_return=early_return)
    t, h = 0.0, 0.25
    while t < STOP - 1e-12:
        returned, last = unit.fmu.doStep(t, min(h, STOP - t))[2:]
        t = last if returned else t + min(h, STOP - t)
    assert list(unit.get(["event_count[1]", "event_count[2]"])) == [len(impacts), len(tops)]
    # to rtol over the span (measured 2.9e-5 s at t = 2.9)
    np.testing.assert_allclose(unit.get(["event_time[1]", "event_time[2]"]),
                               [impacts[-1], tops[-1]], rtol=0, atol=hfdi.DEFAULT_RTOL * STOP)
    unit.close()
    description = read_model_description(str(built[("impact_oscillator", 3)]))
    rtol = next(v for v in description.modelVariables if v.name == "rtol")
    assert f"{hfdi.DEFAULT_RTOL:g}" in rtol.description
    description = read_model_description(str(built[("dumbbell", 3)]))
    rtol = next(v for v in description.modelVariables if v.name == "rtol")
    assert rtol.description.endswith("else none")


def test_fmu_state_save_and_restore_is_bit_exact(built):
    unit = Slave3(built[("impact_oscillator", 3)], early_return=True,
                  parameters={"rtol": 1e-8})
    t = 0.0
    for _ in range(5):
        t = unit.fmu.doStep(t, 0.1)[3]
    state = unit.fmu.getFMUState()
    data = unit.fmu.serializeFMUState(state)

    def run(start):
        rows, t = [], start
        for _ in range(12):
            handling, terminate, returned, t = unit.fmu.doStep(t, 0.1)
            rows.append(np.concatenate([[t, float(returned)], unit.get(IMPACT_OUTPUTS)]))
        return np.array(rows)

    first = run(t)
    assert first[:, 1].any()                       # early returns among them
    unit.fmu.setFMUState(state)
    again = run(t)
    np.testing.assert_array_equal(again, first)
    restored = unit.fmu.deserializeFMUState(data)
    unit.fmu.setFMUState(restored)
    np.testing.assert_array_equal(run(t), first)
    unit.fmu.freeFMUState(state)
    unit.fmu.freeFMUState(restored)
    unit.close()


def test_functions_that_do_not_apply_refuse_with_a_log_line(built):
    messages = []

    def log(env, status, category, message):
        messages.append((status, message.decode()))

    path = built[("dumbbell", 3)]
    md = read_model_description(str(path))
    fmu = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="unit")
    fmu.instantiate(logMessage=fmpy.fmi3.fmi3LogMessageCallback(log))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu.enterInitializationMode(startTime=0.0)
    fmu.exitInitializationMode()
    for call in (lambda: fmu.enterEventMode(), lambda: fmu.enterStepMode(),
                 lambda: fmu.getFloat32([vr["u[1]"]]),
                 lambda: fmu.setFloat64([vr["time"]], [1.0]),
                 lambda: fmu.updateDiscreteStates()):
        count = len(messages)
        with pytest.raises(FMICallException):
            call()
        assert len(messages) == count + 1 and messages[-1][0] == 3      # fmi3Error
    assert "event mode" in messages[0][1] and "Float32" in messages[2][1]
    # nValues that is not nValueReferences: a scalar-only FMU refuses
    values = (ctypes.c_double * 2)()
    refs = (ctypes.c_uint32 * 1)(vr["u[1]"])
    raw = fmu.dll.fmi3GetFloat64
    assert raw(ctypes.c_void_p(fmu.component), refs, ctypes.c_size_t(1), values,
               ctypes.c_size_t(2)) == 3
    assert "nValues = 2" in messages[-1][1]
    # a doStep from a time the FMU is not at: discarded, lastSuccessfulTime where it is
    with pytest.raises(FMICallException):
        fmu.doStep(0.5, 0.1)
    assert "FMU is at t = 0.0" in messages[-1][1] and "fmi2" not in messages[-1][1]
    # the slave's refusals name the FMI 3.0 functions too
    with pytest.raises(FMICallException):
        fmu.enterInitializationMode(startTime=0.0)
    assert messages[-1][1].startswith("fmi3EnterInitializationMode: the FMU is initialized")
    assert "fmi2" not in messages[-1][1]
    fmu.terminate()
    fmu.freeInstance()


def test_the_cli_builds_an_fmi3_fmu(tmp_path, capsys):
    assert main(["build", "impact_oscillator", "--out", str(tmp_path), "--fmi-version",
                 "3"]) == 0
    path = Path(capsys.readouterr().out.strip())
    assert path.name == "hfdi_impact_oscillator_fmi3.fmu"
    assert read_model_description(str(path)).fmiVersion == "3.0"
    with pytest.raises(SystemExit):
        main(["build", "impact_oscillator", "--fmi-version", "4"])


@pytest.mark.parametrize("threads", [1, 4])
def test_a_c_host_returns_early_from_threads(built, tmp_path, threads):
    """A C master (no Python of its own) whose first fmi3InstantiateCoSimulation
    comes from several threads at once, early returns allowed: every
    instance returns at every event, and all end with the values of the same
    run in this process (fmpy), bit for bit."""
    import os
    import shutil
    import subprocess
    compiler = os.environ.get("CC", "cc")
    if shutil.which(compiler) is None:
        pytest.skip(f"no C compiler ({compiler})")
    headers = Path(fmpy.__file__).parent / "c-code"
    program = tmp_path / "fmi3_threads"
    done = subprocess.run([compiler, "-O1", "-pthread", "-o", str(program),
                           str(Path(__file__).with_name("data") / "fmi3_threads.c"),
                           f"-I{headers}", "-ldl"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    path = built[("impact_oscillator", 3)]
    unzip = extract(str(path), unzipdir=str(tmp_path / "x"))
    names = ["u[1]", "v[1]", "event_time[1]", "event_time[2]"]
    here = Slave3(path, early_return=True, unzip=unzip)
    t, h, early = 0.0, 0.25, []
    while t < STOP - 1e-12:
        step = min(h, STOP - t)
        returned, last = here.fmu.doStep(t, step)[2:]
        if returned:
            early.append(last)
        t = last if returned else t + step
    expected = list(here.get(names))
    vrs = [here.vr[n] for n in names]
    here.close()
    md = read_model_description(str(path))
    env = {"PATH": "/usr/bin:/bin", "HFDI_CACHE_DIR": str(tmp_path / "cache"),
           **{k: v for k, v in os.environ.items() if k.startswith(("OPENBLAS_", "OMP_"))}}
    done = subprocess.run([str(program), str(Path(unzip) / "binaries" / "x86_64-linux" /
                                             "hfdi_impact_oscillator.so"),
                           str(Path(unzip) / "resources") + "/", md.guid, str(threads),
                           repr(STOP), repr(h), *map(str, vrs)],
                          capture_output=True, text=True, timeout=600, env=env)
    assert done.returncode == 0, (done.stdout[-2000:], done.stderr[-2000:])
    values, returns = {}, {}
    for line in done.stdout.splitlines():
        if line.startswith("value "):
            _, thread, _, x = line.split()
            values.setdefault(int(thread), []).append(float(x))
        elif line.startswith("early "):
            _, thread, x = line.split()
            returns.setdefault(int(thread), []).append(float(x))
    assert sorted(values) == list(range(threads)) and len(early) >= 4
    assert all(v == expected for v in values.values()), (values, expected)
    assert all(r == early for r in returns.values()), (returns, early)


def test_a_second_master_ecos_runs_the_fmi3_fmu(built, tmp_path):
    """Ecos (``ecospy``, a C++ co-simulation engine with its own FMI 3.0
    import) runs the FMI 3.0 FMU: the values fmpy's FMI 3.0 API gives at the
    same communication points, bit for bit, and the events counted. In a
    subprocess, so that a crash of the host would show as such."""
    path = built[("impact_oscillator", 3)]
    t, (u1, v1, impacts) = run_in_ecos(path, 1.0, [("real", "u[1]"), ("real", "v[1]"),
                                                   ("integer", "event_count[1]")], tmp_path)
    steps = round(t / 0.01)
    assert 95 <= steps <= 100
    unit = Slave3(path)
    t = 0.0
    for _ in range(steps):
        assert not unit.fmu.doStep(t, 0.01)[2]
        t += 0.01
    assert list(unit.get(["u[1]", "v[1]", "event_count[1]"])) == [u1, v1, impacts]
    assert impacts == 1.0                              # the first impact at t = 0.584
    unit.close()
