"""The FMI 2.0 co-simulation FMUs (``fmu``): validity, equivalence with
``hfdi.Integrator``, rollback, discards, communication step sizes, bad
parameters, the CLI and the example master.

The FMUs are built once per session (``fmus`` and ``dumbbell_fmu`` of
conftest.py). Their native layer runs the slaves inside this Python process,
so the slaves import the ``hfdi`` bundled in each FMU, not the one under test
here; both are the same sources.
"""
import itertools
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pythonfmu")
fmpy = pytest.importorskip("fmpy")

from fmpy import read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi2 import fmi2Error  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

import fmu  # noqa: E402
import hfdi  # noqa: E402
from fmu.cli import main  # noqa: E402
from fmu.master import Unit, coupled_dumbbells, cosimulate  # noqa: E402
from validation.experiments import EXPERIMENTS, experiment  # noqa: E402

#: the FMU tests run in one worker (--dist loadgroup): the FMUs are built, and
#: their copy of the compiled loops loaded, once per session rather than per worker
pytestmark = pytest.mark.xdist_group("fmu")

MODELS = hfdi.models.available()
SCHEMES = ("newmark", "bathe", "hfdi")
N = 4                                              # dumbbell DOFs
STATE = [f"{k}[{i}]" for k in "uva" for i in range(1, N + 1)]
OBSERVED = STATE + ["stretch", "W", "dE", "internal_steps", "newton_iterations"]
# a force no step can integrate: the Newton residuals overflow at every step size
HUGE = 1.7e308


def unit(dumbbell_fmu, parameters=None, name="unit"):
    path, unzip = dumbbell_fmu
    u = Unit(path, name, unzip_dir=unzip)
    u.initialize(parameters or {}, start_time=0.0)
    return u


def reference_row(itg):
    """The dumbbell FMU's observed outputs, from an in-process integrator."""
    s = itg.state
    stretch = itg.system.quantities(np.array([s.t]), s.u[None], s.v[None])["stretch"]
    st = itg.statistics
    return np.concatenate([s.u, s.v, s.a, np.ravel(stretch),
                           [itg.total_energy, itg.energy_error, st.steps,
                            st.newton_iterations]])


def assert_rows_close(fmu_rows, ref_rows, rtol=1e-12):
    fmu_rows, ref_rows = np.atleast_2d(fmu_rows), np.atleast_2d(ref_rows)
    scale = np.maximum(np.abs(ref_rows).max(axis=0), 1e-300)
    # dE is a sum of round-off-sized terms: measure it on the energy's scale
    scale[OBSERVED.index("dE")] = max(scale[OBSERVED.index("W")], 1.0)
    err = np.abs(fmu_rows - ref_rows) / scale
    assert err.max() <= rtol, (err.max(), np.unravel_index(err.argmax(), err.shape))


# -- the model descriptions -------------------------------------------------------------
@pytest.mark.parametrize("name", MODELS)
def test_fmu_validates_with_units_and_descriptions(fmus, name):
    path = fmus[name]
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    assert md.coSimulation.modelIdentifier == f"hfdi_{name}"
    n = hfdi.models.get(name).n_dof
    names = {v.name for v in md.modelVariables}
    for key in ("u", "v", "a", "F"):
        assert {f"{key}[{i}]" for i in range(1, n + 1)} <= names
    assert {"scheme", "target_iterations", "tolerance", "initial_step", "max_step", "W", "dE",
            "internal_steps", "newton_iterations"} <= names
    for v in md.modelVariables:
        assert v.description, v.name
        if v.type == "Real":
            assert v.unit, v.name
    defaults = hfdi.models.describe(name)
    for v in md.modelVariables:
        if v.causality == "parameter" and v.name in defaults:
            assert type(defaults[v.name])(v.start) == defaults[v.name], v.name


def test_dumbbell_variables(fmus):
    md = read_model_description(str(fmus["dumbbell"]))
    by_name = {v.name: v for v in md.modelVariables}
    assert by_name["u[3]"].unit == "m" and by_name["a[3]"].unit == "m/s2"
    assert by_name["F[3]"].unit == "N" and by_name["W"].unit == "J"
    assert by_name["F[3]"].causality == "input" and by_name["stretch"].causality == "output"
    assert by_name["internal_steps"].type == "Integer"
    assert by_name["internal_steps"].variability == "discrete"
    assert {"A", "sigma"} <= set(by_name) and by_name["scheme"].start == "hfdi"
    assert not any(name.startswith("z.") for name in by_name)   # quantity "u" not repeated
    assert all(u.dependencies == [] for u in md.outputs)          # no direct feedthrough


# -- equivalence with the library -----------------------------------------------------------
@pytest.mark.parametrize("scheme", SCHEMES)
def test_simulate_fmu_reproduces_integrator_advance(fmus, scheme):
    result = simulate_fmu(str(fmus["dumbbell"]), start_values={"scheme": scheme},
                          stop_time=2.0, output_interval=0.04, output=OBSERVED)
    itg = hfdi.Integrator(hfdi.models.get("dumbbell"), scheme, target_iterations=3.0)
    rows, refs, previous = [], [], 0.0
    for row in result:
        t = float(row["time"])
        if t > previous:
            # the FMU advanced to current + step, the master's two numbers
            assert itg.advance(previous + (t - previous))
            previous = t
        rows.append([row[name] for name in OBSERVED])
        refs.append(reference_row(itg))
    assert len(rows) == 51 and result["time"][-1] == 2.0
    assert_rows_close(rows, refs)
    assert result["internal_steps"][-1] == itg.statistics.steps > 50     # same internal steps


@pytest.mark.parametrize("how, in_process", [
    (dict(tolerance=1e-5), dict(rtol=1e-5, target_iterations=3.0)),        # combined
    (dict(parameters={"target_iterations": 0.0, "rtol": 1e-5}), dict(rtol=1e-5)),
    # not DEFAULT_RTOL (1e-4): a tolerance the FMU dropped would not be seen
    (dict(parameters={"target_iterations": 0.0}, tolerance=3e-5), dict(rtol=3e-5)),
])
@pytest.mark.slow
def test_tolerances_give_error_control_as_in_process(dumbbell_fmu, how, in_process):
    """The master's tolerance (fmi2SetupExperiment) or the rtol parameter put
    the FMU under error control, with the same steps as in-process."""
    path, unzip = dumbbell_fmu
    u = Unit(path, "tol", unzip_dir=unzip)
    u.initialize(**how)
    itg = hfdi.Integrator(hfdi.models.get("dumbbell"), "hfdi", **in_process)
    t = 0.0
    for _ in range(5):          # some 7,000 internal steps, on the FMU's Python path
        assert u.step(t, 0.05)
        t += 0.05
        assert itg.advance(t)
    n = itg.ev.n
    np.testing.assert_allclose(u.get([f"u[{i}]" for i in range(1, n + 1)]), itg.state.u,
                               rtol=0, atol=1e-12 * np.abs(itg.state.u).max())
    assert int(u.get(["internal_steps"])[0]) == itg.statistics.steps
    u.close()


def test_a_call_that_logs_a_warning_returns_fmi2warning(dumbbell_fmu):
    """FMI pairs a logged warning with the status fmi2Warning: a master
    tolerance below the range is clipped, said at logStatusWarning, and
    fmi2SetupExperiment returns fmi2Warning (it returned fmi2OK); one in
    range returns fmi2OK."""
    path, unzip = dumbbell_fmu
    for tolerance, expected in ((1e-20, 1), (1e-6, 0)):
        unit = Unit(path, f"warn{expected}", unzip_dir=unzip)
        status = unit.fmu.fmi2SetupExperiment(unit.fmu.component, 1, tolerance, 0.0, 0, 0.0)
        assert status == expected, (tolerance, unit.messages[-2:])
        warned = [m for m in unit.messages if "outside" in str(m)]
        assert bool(warned) == bool(expected), unit.messages
        unit.close()


@pytest.mark.parametrize("name", [m for m in MODELS if m != "dumbbell"])
def test_other_models_reproduce_integrator_advance(fmus, name):
    model = hfdi.models.get(name)
    stop = 0.1 * experiment(name).observation_time if name in EXPERIMENTS \
        else type(model).fmi_metadata["stop_time"]
    result = simulate_fmu(str(fmus[name]), stop_time=stop, output_interval=stop / 10,
                          output=[f"u[{i}]" for i in range(1, model.n_dof + 1)] + ["W"])
    # a model with events is error-controlled at the default rtol over the
    # experiment when no tolerance is given (fmu/README.md)
    events = bool(getattr(model, "events", None))
    itg = hfdi.Integrator(model, "hfdi", target_iterations=3.0,
                          rtol=hfdi.DEFAULT_RTOL if events else None,
                          error_span=stop if events else None)
    previous = 0.0
    for row in result[1:]:
        t = float(row["time"])
        assert itg.advance(previous + (t - previous))
        previous = t
        u = np.array([row[f"u[{i}]"] for i in range(1, model.n_dof + 1)])
        scale = max(np.abs(itg.state.u).max(), 1e-300)
        assert np.abs(u - itg.state.u).max() <= 1e-12 * scale
        assert abs(row["W"] - itg.total_energy) <= 1e-12 * max(abs(itg.total_energy), 1.0)


@pytest.mark.parametrize("step", [2.5e-4, 1.0])
def test_communication_steps_far_below_and_above_the_internal_step(dumbbell_fmu, step):
    # the internal steps of the dumbbell are about 0.016 with HFDI
    t_end = 0.05 if step < 0.01 else 2.0
    u = unit(dumbbell_fmu)
    itg = hfdi.Integrator(hfdi.models.get("dumbbell"), "hfdi", target_iterations=3.0)
    t, rows, refs = 0.0, [], []
    while t < t_end - 1e-12:
        assert u.step(t, step)
        t += step
        assert itg.advance(t)
        rows.append(u.get(OBSERVED))
        refs.append(reference_row(itg))
    u.close()
    assert_rows_close(rows, refs)
    steps = rows[-1][OBSERVED.index("internal_steps")]
    if step < 0.01:
        assert steps == len(rows)             # one internal step per communication step
    else:
        assert steps > 50 * len(rows)
    assert abs(rows[-1][OBSERVED.index("dE")]) < 1e-3 * abs(rows[-1][OBSERVED.index("W")])


@pytest.mark.parametrize("scheme", SCHEMES)
def test_input_step_moves_the_centre_of_mass_exactly(dumbbell_fmu, scheme):
    # M_tot x_cm'' = F_x: every scheme integrates the constant acceleration after
    # the jump exactly, provided the step after the jump starts from its right limit
    u = unit(dumbbell_fmu, {"scheme": scheme})
    x0 = u.get(["u[1]", "u[3]", "v[1]", "v[3]"])
    t, h, t_jump, force = 0.0, 0.03, 0.09, 600.0
    while t < 0.3 - 1e-12:
        if abs(t - t_jump) < 1e-12:
            u.set({"F[1]": force / 2, "F[3]": force / 2})
        assert u.step(t, h)
        t += h
    x = u.get(["u[1]", "u[3]"])
    u.close()
    exact = 0.5 * (x0[0] + x0[1]) + 0.5 * (x0[2] + x0[3]) * t \
        + 0.5 * (force / 2.0) * (t - t_jump) ** 2
    assert abs(x.mean() - exact) < 1e-9 * abs(exact)


@pytest.mark.parametrize("compiled", [pytest.param(False, marks=pytest.mark.slow), True])
def test_a_step_past_the_stop_time_is_refused_on_both_paths(dumbbell_fmu, compiled):
    """FMI: past the stop time of fmi2SetupExperiment the FMU returns fmi2Error,
    whether its slave or its native layer would take the doStep; a master's
    rounded sum of steps still ends on the stop time. Nothing changes."""
    path, unzip = dumbbell_fmu
    name = f"stop-{compiled}"
    u = Unit(path, name, unzip_dir=unzip)
    u.initialize({"compiled": compiled, "rtol": 1e-5, "target_iterations": 0.0},
                 stop_time=0.1)
    gate = _gate(name)
    t, h = 0.0, 0.01
    for _ in range(10):
        assert u.step(t, h), u.messages[-2:]
        t += h
    assert t != 0.1 and abs(t - 0.1) < 1e-15          # 0.09999999999999999
    assert gate("steps") == (9 if compiled else 0)     # all but the first natively
    before, steps = u.get(STATE), gate("steps")
    with pytest.raises(FMICallException) as refused:
        u.step(t, 1e-3)
    assert refused.value.status == fmi2Error
    assert "past the stop time 0.1 that the experiment defined" in u.messages[-1][2]
    assert gate("steps") == steps and u.last_successful_time() == t
    np.testing.assert_array_equal(u.get(STATE), before)
    u.close()


@pytest.mark.slow
@pytest.mark.parametrize("scheme", SCHEMES)
def test_compiled_fmu_reproduces_the_compiled_integrator(dumbbell_fmu, scheme):
    """``compiled = true``: the FMU takes its internal steps in the compiled driver
    (its own bundled copy, compiled on first use), with inputs changing between
    communication steps, a discarded step and the step budget: the same outputs
    as the compiled in-process integrator fed the same inputs, and the same
    internal steps as the FMU on the Python path."""
    parameters = {"scheme": scheme, "target_iterations": 0.0, "rtol": 1e-4}
    fast = unit(dumbbell_fmu, dict(parameters, compiled=True), "fast")
    slow = unit(dumbbell_fmu, parameters, "slow")
    held = np.zeros(N)
    itg = hfdi.Integrator(hfdi.models.get("dumbbell"), scheme, rtol=1e-4, compiled=True,
                          extra_load=hfdi.HeldLoad(lambda: held), max_steps=2 ** 62)
    assert itg.compiled
    t, h, rows, refs = 0.0, 0.01, [], []
    for k in range(25):
        inputs = {"F[1]": 30.0 * math.sin(k), "F[4]": -20.0 * math.cos(k)}
        for v in (fast, slow):
            v.set(inputs)
        if k == 12:                              # a step no budget of 3 can take
            fast.set({"F[3]": HUGE})
            assert not fast.step(t, h)
            fast.set({"F[3]": 0.0})
        for v in (fast, slow):
            assert v.step(t, h)
        changed = np.zeros(N)
        changed[0], changed[3] = inputs["F[1]"], inputs["F[4]"]
        if not np.array_equal(changed, held):
            held[:] = changed
            itg.load_changed()
        t += h
        assert itg.advance(t)
        rows.append(fast.get(OBSERVED))
        refs.append(reference_row(itg))
        assert fast.get(["internal_steps"]) == slow.get(["internal_steps"])
    assert_rows_close(rows, refs, rtol=0.0)
    np.testing.assert_array_equal(fast.get(STATE), slow.get(STATE))
    assert rows[-1][OBSERVED.index("internal_steps")] > 100
    budget = unit(dumbbell_fmu, dict(parameters, compiled=True, max_internal_steps=3),
                  "budget")
    assert not budget.step(0.0, 0.5)
    assert "max_internal_steps = 3 internal steps reached" in budget.messages[-1][2]
    assert budget.last_successful_time() == 0.0
    for v in (fast, slow, budget):
        v.close()


def _gate(instance_name):
    """The native path's gate of this process's FMU instance ``instance_name``,
    by the names of ``fmu.entry.GATE_FIELDS`` (read live)."""
    import gc
    adapters = [o for o in gc.get_objects() if type(o).__name__ == "Adapter"
                and getattr(getattr(o, "slave", None), "instance_name", None) == instance_name]
    assert len(adapters) == 1
    fields = sys.modules[type(adapters[0]).__module__].GATE_FIELDS
    gate = adapters[0].gate
    return lambda name: gate[fields.index(name)]


def test_the_gate_fields_are_the_native_layers():
    """fmu.entry.GATE_FIELDS names the entries of the native layer's enum, in its order."""
    from fmu.entry import GATE_FIELDS, GATE_SIZE
    source = (Path(fmu.__file__).parent / "native" / "hfdi_fmu_core.h").read_text()
    enum = re.search(r"enum \{ (GATE_ARMED[^}]*)\}", source).group(1)
    names = [n.strip() for n in enum.split(",")]
    assert names[-1] == f"GATE_SIZE = {GATE_SIZE}"
    assert [n.removeprefix("GATE_").lower() for n in names[:-1]] == list(GATE_FIELDS)


@pytest.mark.slow
@pytest.mark.parametrize("scheme", SCHEMES)
def test_native_path_takes_doSteps_and_reads_states_bit_for_bit(dumbbell_fmu, scheme):
    """``compiled = true``: after its first doStep the FMU's native layer takes
    the doSteps, reads the states and writes the inputs itself (the compiled
    driver without Python, hfdi.compiled.NativeAdvance), and hands over to
    the slave for everything else: outputs that are not states, FMU states,
    a step past the budget, a wrong time. Every value is the
    compiled in-process integrator's, bit for bit."""
    parameters = {"scheme": scheme, "target_iterations": 3.0, "compiled": True,
                  "max_internal_steps": 200}
    fast = unit(dumbbell_fmu, parameters, f"native-{scheme}")
    gate = _gate(f"native-{scheme}")
    held = np.zeros(N)
    itg = hfdi.Integrator(hfdi.models.get("dumbbell"), scheme, target_iterations=3.0,
                          compiled=True, extra_load=hfdi.HeldLoad(lambda: held),
                          max_steps=2 ** 62)
    refs = [fast.vr(name) for name in STATE]
    t, h, rows = 0.0, 1e-3, []
    for k in range(400):
        if k == 150:
            saved, t_saved = fast.get_state(), t
        if k % 25 == 7:                          # an input changes, held from t on
            fast.set({"F[2]": 40.0 * k})
            held[1] = 40.0 * k
            itg.load_changed()
        hk = 0.05 if k == 250 else h              # more internal steps than one
        assert fast.step(t, hk), fast.messages[-3:]
        t += hk
        assert itg.advance(t)
        row = fast.fmu.getReal(refs)
        rows.append(row)
        assert row == np.concatenate([itg.state.u, itg.state.v, itg.state.a]).tolist(), k
        if k % 97 == 0:                          # outputs from the slave, after a sync
            assert_rows_close(fast.get(OBSERVED), reference_row(itg), rtol=0.0)
    assert gate("steps") >= 390 and gate("reads") >= 390 and gate("writes") >= 15, \
        (gate("steps"), gate("reads"), gate("writes"), fast.messages[-4:])
    # a wrong time and a step past the budget: the slave's refusals, nothing changed
    before = fast.get(STATE)
    assert not fast.step(t + 0.5, h)
    assert "but the FMU is at t =" in fast.messages[-1][2]
    steps = gate("steps")
    assert not fast.step(t, 5.0)
    assert gate("steps") == steps
    assert "max_internal_steps = 200 internal steps reached" in fast.messages[-1][2]
    assert fast.last_successful_time() == t
    np.testing.assert_array_equal(fast.get(STATE), before)
    assert fast.step(t, h) and gate("steps") == steps   # the slave's again, then armed
    assert fast.step(t + h, h) and gate("steps") == steps + 1
    # back to the state saved at step 150: the same steps again, natively
    fast.set_state(saved)
    fast.free_state(saved)
    t = t_saved
    for k in range(150, 400):
        if k % 25 == 7:
            fast.set({"F[2]": 40.0 * k})
        hk = 0.05 if k == 250 else h
        assert fast.step(t, hk)
        t += hk
        assert fast.fmu.getReal(refs) == rows[k], k
    fast.close()


@pytest.mark.filterwarnings("ignore::RuntimeWarning")     # the HUGE input's overflow
def test_states_are_read_natively_on_the_python_path_too(dumbbell_fmu):
    """``compiled = false``: the doSteps are the slave's, but after each it
    copies the states where the native layer reads them; the values are the
    Python integrator's, bit for bit, also after a discard and a restore."""
    fmu = unit(dumbbell_fmu, {"scheme": "bathe"}, "python-reads")
    gate = _gate("python-reads")
    held = np.zeros(N)
    itg = hfdi.Integrator(hfdi.models.get("dumbbell"), "bathe", target_iterations=3.0,
                          compiled=False, extra_load=hfdi.HeldLoad(lambda: held),
                          max_steps=2 ** 62)
    refs = [fmu.vr(name) for name in STATE]
    t, h = 0.0, 0.01
    for k in range(30):
        if k == 10:
            saved = fmu.get_state()
        if k == 20:
            fmu.set({"F[1]": 25.0})
            held[0] = 25.0
            itg.load_changed()
        assert fmu.step(t, h)
        t += h
        assert itg.advance(t)
        assert fmu.fmu.getReal(refs) == np.concatenate(
            [itg.state.u, itg.state.v, itg.state.a]).tolist(), k
    assert gate("steps") == 0 and gate("reads") >= 29
    before = fmu.fmu.getReal(refs)
    fmu.set({"F[2]": HUGE})
    assert not fmu.step(t, h)
    assert fmu.fmu.getReal(refs) == before
    fmu.set_state(saved)
    fmu.free_state(saved)
    assert fmu.fmu.getReal(refs) == fmu.get(STATE).tolist()
    fmu.close()


@pytest.mark.slow
@pytest.mark.parametrize("name", ["articulated", "toss_rule"])
def test_native_path_on_other_models_under_error_control(fmus, name):
    """The articulated system's load breakpoints (handed to the slave under error
    control) and the 21-DOF beam: the compiled FMU with its native path and
    inputs changed now and then gives the compiled in-process integrator's
    states bit for bit."""
    model = hfdi.models.get(name)
    n = model.n_dof
    stop = 0.1 * experiment(name).observation_time
    h = stop / 200
    fast = Unit(fmus[name], f"native-{name}")
    fast.initialize({"compiled": True, "rtol": 1e-6, "target_iterations": 0.0}, start_time=0.0)
    gate = _gate(f"native-{name}")
    held = np.zeros(n)
    itg = hfdi.Integrator(model, "hfdi", rtol=1e-6, compiled=True, max_steps=2 ** 62,
                          extra_load=hfdi.HeldLoad(lambda: held))
    refs = [fast.vr(f"{k}[{i}]") for k in "uva" for i in range(1, n + 1)]
    t = 0.0
    for k in range(200):
        if k % 40 == 13:
            value = 0.5 * math.sin(k)
            fast.set({"F[1]": value})
            held[0] = value
            itg.load_changed()
        assert fast.step(t, h), fast.messages[-2:]
        t += h
        assert itg.advance(t)
        assert fast.fmu.getReal(refs) == np.concatenate(
            [itg.state.u, itg.state.v, itg.state.a]).tolist(), k
    assert int(fast.get(["internal_steps"])[0]) == itg.statistics.steps
    assert gate("steps") >= 150 and gate("writes") >= 4, (gate("steps"), gate("writes"),
                                                          fast.messages[-4:])
    fast.close()


# -- FMU state -------------------------------------------------------------------------------
@pytest.mark.parametrize("scheme", ["bathe", "hfdi"])
def test_rollback_and_serialization_are_bit_identical(dumbbell_fmu, scheme):
    u = unit(dumbbell_fmu, {"scheme": scheme})
    t, h = 0.0, 0.03
    for k in range(5):
        u.set({"F[1]": 100.0 * k})
        assert u.step(t, h)
        t += h
    saved = u.get_state()
    t_saved = t

    def ten_steps(v, t):
        rows = []
        for k in range(10):
            v.set({"F[2]": -50.0 * k})
            assert v.step(t, h)
            t += h
            rows.append(v.get(OBSERVED))
        return np.array(rows)

    first = ten_steps(u, t_saved)
    u.set_state(saved)
    assert u.get(["F[1]", "F[2]"]).tolist() == [400.0, 0.0]      # inputs are part of the state
    again = ten_steps(u, t_saved)
    data = u.serialize(saved)
    u.set_state(u.deserialize(data))
    restored = ten_steps(u, t_saved)
    u.free_state(saved)
    u.close()
    fresh = unit(dumbbell_fmu, {"scheme": scheme}, name="fresh")   # another instance, same FMU
    fresh.set_state(fresh.deserialize(data))
    elsewhere = ten_steps(fresh, t_saved)
    fresh.close()
    assert np.array_equal(first, again)
    assert np.array_equal(first, restored)
    assert np.array_equal(first, elsewhere)


def test_corrupt_state_is_refused_not_a_crash(dumbbell_fmu):
    u = unit(dumbbell_fmu)
    with pytest.raises(FMICallException) as info:
        u.set_state(u.deserialize(b"not a state"))
    assert info.value.status == fmi2Error
    assert any("not a serialized hfdi FMU state" in m[2] for m in u.messages)
    u.close(terminate=False)


@pytest.mark.parametrize("field, value", [("params", ("rtol", 0.09)), ("mparams", ("A", 5.0)),
                                          ("start_time", 5.0), ("stop_time", 9.0)])
def test_a_state_whose_parameters_are_not_its_integrators_is_refused(dumbbell_fmu, field,
                                                                     value):
    """An FMU state's header edited (the rest intact): the FMU would report
    parameters it does not step with; refused, nothing changes."""
    from hfdi import serial
    u = unit(dumbbell_fmu, {"rtol": 1e-4})
    assert u.step(0.0, 0.01)
    state = u.get_state()
    data = u.serialize(state)
    magic, packed = data[:data.index(b"\n") + 1], data[data.index(b"\n") + 1:]
    header, arrays = serial.unpack(packed)
    if isinstance(value, tuple):
        header[field][value[0]] = value[1]
    else:
        header[field] = value
    tampered = u.deserialize(magic + serial.pack(header, arrays))
    before = u.get(OBSERVED)
    with pytest.raises(FMICallException) as refused:
        u.set_state(tampered)
    assert refused.value.status == fmi2Error
    assert "differ from those its integrator was built with" in u.messages[-1][2]
    assert np.array_equal(u.get(OBSERVED), before)
    u.set_state(u.deserialize(data))                  # the untouched bytes restore
    u.free_state(state)
    u.close()


# -- failures ----------------------------------------------------------------------------------
@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("scheme", SCHEMES)
def test_rejected_step_is_discarded_at_the_last_communication_point(dumbbell_fmu, scheme):
    u, clean = unit(dumbbell_fmu, {"scheme": scheme}), unit(dumbbell_fmu, {"scheme": scheme}, "clean")
    t, h = 0.0, 0.05
    for v in (u, clean):
        assert v.step(t, h)
    t += h
    before = u.get(OBSERVED)
    u.set({"F[3]": HUGE})
    assert not u.step(t, h)
    message = u.messages[-1]
    assert message[0] == "DISCARD" and "rejected" in message[2]
    assert "HALVINGS_EXHAUSTED" in message[2] or "STEP_BELOW_MINIMUM" in message[2]
    assert np.array_equal(u.get(OBSERVED), before)
    assert u.last_successful_time() == t
    u.set({"F[3]": 0.0})                      # no restore needed: the FMU is back at t
    for v in (u, clean):
        assert v.step(t, h / 2) and v.step(t + h / 2, h / 2)
    assert np.array_equal(u.get(OBSERVED), clean.get(OBSERVED))
    assert not u.step(0.0, h)                 # a step from elsewhere is refused
    assert "restore an FMU state" in u.messages[-1][2]
    u.set({"F[1]": math.nan})
    assert not u.step(t + h, h) and "not finite" in u.messages[-1][2]
    u.close()
    clean.close()


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("compiled", [False, True], ids=["python", "compiled"])
@pytest.mark.parametrize("h", [1e-15, 1e-3], ids=["short", "regular"])
def test_a_step_whose_energy_overflows_is_discarded(dumbbell_fmu, h, compiled):
    """F = 1e300 over a doStep of 1e-15 (a short step) or 1 ms: finite states
    whose energy (an output) is not. Accepted, they made W and dE inf and NaN
    (found by the robustness machine); the doStep is discarded instead."""
    u = unit(dumbbell_fmu, {"scheme": "newmark", "compiled": compiled})
    assert u.step(0.0, 0.01) and u.step(0.01, 0.01)      # the second one native if compiled
    before = u.get(OBSERVED)
    u.set({"F[1]": 1e300})
    assert not u.step(0.02, h)
    assert u.messages[-1][0] == "DISCARD" and "OVERFLOW" in u.messages[-1][2]
    assert np.array_equal(u.get(OBSERVED), before)
    u.set({"F[1]": 0.0})
    assert u.step(0.02, 0.01) and np.all(np.isfinite(u.get(OBSERVED)))
    u.close()


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_master_halves_and_repeats_a_discarded_step(dumbbell_fmu):
    path, unzip = dumbbell_fmu
    glitch_at, glitches = 0.1, []

    def run(exchange, times=None):
        units = [Unit(path, name, unzip_dir=unzip) for name in "AB"]
        try:
            for v in units:
                v.initialize({"scheme": "newmark"})
            return cosimulate(units, exchange, [STATE, STATE], 0.2, 0.02, times=times)
        finally:
            for v in units:
                v.close()

    def spring(t, h, values):
        a, b = values
        f = 1e3 * (b[0] + 2.0 - a[2] - 1.0)
        return [{"F[3]": f}, {"F[1]": -f}]

    def glitchy(t, h, values):
        inputs = spring(t, h, values)
        if abs(t - glitch_at) < 1e-12 and not glitches:
            glitches.append(h)                # once: as if a sensor spiked
            inputs[0]["F[3]"] = HUGE
        return inputs

    trace = run(glitchy)
    assert len(trace.discards) == 1
    t, h, who = trace.discards[0]
    assert t == pytest.approx(glitch_at, abs=1e-12) and h == pytest.approx(0.02) and who == [0]
    assert np.any(np.isclose(trace.times, glitch_at + 0.01))    # the halved step
    assert trace.times[-1] == 0.2 and trace.macro_steps == 11
    clean = run(spring, times=trace.times[1:])
    assert not clean.discards
    for mine, theirs in zip(trace.values, clean.values):
        assert np.array_equal(mine, theirs)


@pytest.mark.parametrize("parameters, named", [
    ({"scheme": "euler"}, "scheme"),
    ({"target_iterations": 0.5}, "target_iterations"),
    ({"rtol": 0.5}, "rtol"),
    ({"tolerance": 1.5}, "tolerance"),
    ({"max_step": -1.0}, "max_step"),
    ({"A": -1.0}, "A"),
])
def test_bad_parameter_is_an_error_status_not_a_crash(dumbbell_fmu, parameters, named):
    path, unzip = dumbbell_fmu
    u = Unit(path, "bad", unzip_dir=unzip)
    with pytest.raises(FMICallException) as info:
        u.initialize(parameters)
    assert info.value.status == fmi2Error
    errors = [m[2] for m in u.messages if m[0] == "ERROR"]
    assert errors and (f"parameter {named} = " in errors[0] or f"{named} = " in errors[0])
    u.close(terminate=False)
    again = unit(dumbbell_fmu, name="after")     # the process and the FMU are still usable
    assert again.step(0.0, 0.01)
    again.close()


@pytest.mark.skipif("toss_rule" not in MODELS, reason="toss_rule is not registered")
def test_structural_parameter_is_refused(fmus):
    u = Unit(fmus["toss_rule"], "structure")
    with pytest.raises(FMICallException):
        u.initialize({"n_elements": 3})
    assert any("n_elements = 3" in m[2] and "DOFs" in m[2] for m in u.messages)
    u.close(terminate=False)


# -- command line and example master ---------------------------------------------------------------
def test_cli_unknown_problem_is_one_clear_line(capsys):
    assert main(["build", "pendulum"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "unknown problem 'pendulum'" in err and "dumbbell" in err


def test_cli_lists_the_problems(capsys):
    assert main(["list"]) == 0
    assert capsys.readouterr().out.split() == MODELS


def test_coupled_dumbbells_conserve_momentum(fmus):
    result = coupled_dumbbells(fmus["dumbbell"], t_end=0.1, step=0.002, stiffness=1e3)
    trace, momentum, energy = result["trace"], result["momentum"], result["total_energy"]
    assert trace.macro_steps == 50 and not trace.discards
    assert np.abs(momentum - momentum[0]).max() < 1e-9 * np.abs(momentum[0]).max()
    assert abs(energy[-1] - energy[0]) < 1e-4 * abs(energy[0])
    assert result["spring_energy"].max() > 0


@pytest.mark.slow
def test_demo_command_matches_in_process(tmp_path, capsys):
    from fmu.cli import main
    assert main(["demo", "dumbbell", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "largest relative difference 0.00e+00" in printed
    assert (tmp_path / "hfdi_dumbbell.fmu").is_file()


# -- the lasting copy of the bundled package ------------------------------------------
def _bundle(tmp_path):
    from fmu.entry import package_digest
    bundled = tmp_path / "resources" / "hfdi"
    (bundled / "sub").mkdir(parents=True)
    (bundled / "__init__.py").write_text("X = 1\n")
    (bundled / "sub" / "m.py").write_text("Y = 2\n")
    return bundled, f"_hfdi_fmu_{package_digest(bundled)}"


def test_the_bundle_has_a_lasting_copy_checked_before_every_use(tmp_path, monkeypatch):
    """Extractions of one FMU share a copy of its hfdi (so numba's cache beside
    it lasts); a copy whose files no longer give the digest in the bundle's
    name is made again, and without a copy the bundle itself is used."""
    from pathlib import Path

    from fmu.entry import lasting_copy
    monkeypatch.setenv("HFDI_CACHE_DIR", str(tmp_path / "cache"))
    bundled, alias = _bundle(tmp_path)
    copy = lasting_copy(alias, str(bundled))
    assert Path(copy) == tmp_path / "cache" / "fmu" / alias / "hfdi"
    assert (Path(copy) / "sub" / "m.py").read_text() == "Y = 2\n"
    (Path(copy) / "sub" / "__pycache__").mkdir()          # numba's cache: not part of it
    (Path(copy) / "sub" / "__pycache__" / "m.f-1.py311.nbi").write_bytes(b"\0")
    assert lasting_copy(alias, str(bundled)) == copy
    assert (Path(copy) / "sub" / "__pycache__" / "m.f-1.py311.nbi").exists()
    (Path(copy) / "sub" / "m.py").write_text("import os\n")  # changed: made again
    assert lasting_copy(alias, str(bundled)) == copy
    assert (Path(copy) / "sub" / "m.py").read_text() == "Y = 2\n"
    assert sorted(p.name for p in (tmp_path / "cache" / "fmu" / alias).iterdir()) == ["hfdi"]
    # a bundle that is not the one its name says (a damaged FMU): used as it
    # is, so that it fails as it would without a copy; never copied
    (bundled / "__init__.py").write_text("X = 3\n")
    assert lasting_copy(alias, str(bundled)) == str(bundled)
    assert (Path(copy) / "__init__.py").read_text() == "X = 1\n"
    monkeypatch.setenv("HFDI_CACHE_DIR", str(tmp_path / "other"))
    assert lasting_copy(alias, str(bundled)) == str(bundled)
    assert not (tmp_path / "other" / "fmu" / alias).exists()
    # no absolute folder for the cache (no home folder): the bundle itself
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HFDI_CACHE_DIR", "relative")
    (bundled / "__init__.py").write_text("X = 1\n")
    assert lasting_copy(alias, str(bundled)) == str(bundled)
    assert not (tmp_path / "relative").exists()
    # a cache that cannot be written: the bundle itself
    (tmp_path / "a-file").write_text("")
    monkeypatch.setenv("HFDI_CACHE_DIR", str(tmp_path / "a-file"))
    (bundled / "__init__.py").write_text("X = 1\n")
    assert lasting_copy(alias, str(bundled)) == str(bundled)


def test_copies_unused_for_a_month_are_removed_when_another_is_made(tmp_path, monkeypatch):
    import os
    import time

    from fmu.entry import UNUSED_COPY_DAYS, lasting_copy
    monkeypatch.setenv("HFDI_CACHE_DIR", str(tmp_path / "cache"))
    folder = tmp_path / "cache" / "fmu"
    old, recent = folder / "_hfdi_fmu_000000000000", folder / "_hfdi_fmu_111111111111"
    for path in (old, recent):
        (path / "hfdi").mkdir(parents=True)
    past = time.time() - (UNUSED_COPY_DAYS + 1) * 86400.0
    os.utime(old, (past, past))
    bundled, alias = _bundle(tmp_path)
    lasting_copy(alias, str(bundled))
    assert sorted(p.name for p in folder.iterdir()) == sorted([recent.name, alias])


@pytest.mark.slow
def test_a_new_extraction_loads_the_compiled_code_of_the_last(fmus):
    """The compiled FMU compiles its bundled kernels once per machine, not once
    per extraction: a process extracting the FMU anew loads the compiled loop
    from numba's cache, which the session's first extraction filled (the
    ``fmus`` fixture runs the compiled loops once in a process of its own)."""
    import os
    import subprocess
    import sys
    from pathlib import Path
    from hfdi.files import cache_dir
    root = Path(__file__).resolve().parents[1]
    code = (
        "import sys\n"
        "from fmpy import extract\n"
        "from fmu.master import Unit\n"
        "path = sys.argv[1]\n"
        "with Unit(path, 'x', unzip_dir=extract(path)) as unit:\n"
        "    unit.initialize({'compiled': True}, stop_time=1.0)\n"
        "    assert unit.step(0.0, 0.1)\n"
        "name = [m for m in sys.modules if m.startswith('_hfdi_fmu_')\n"
        "        and m.endswith('.stepping.loop')][0]\n"
        "stats = sys.modules[name].advance_hfdi.dispatcher.stats\n"
        "print(sys.modules[name].__file__)\n"
        "print(stats.cache_hits.total(), stats.cache_misses.total())\n")
    env = dict(os.environ,
               PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
    out = subprocess.run([sys.executable, "-c", code, str(fmus["dumbbell"])], env=env,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    where, counts = out.stdout.strip().splitlines()[-2:]
    assert Path(cache_dir()) / "fmu" in Path(where).parents, where
    assert [int(x) for x in counts.split()] == [1, 0]          # loaded, not compiled


def test_last_successful_time_is_the_time_the_fmu_is_at(dumbbell_fmu):
    """fmi2LastSuccessfulTime: the start time before any step, and after a
    doStep discarded because of the master's time the FMU's own time, not
    the master's communication point."""
    path, unzip = dumbbell_fmu
    u = Unit(path, "late", unzip_dir=unzip)
    u.initialize({}, start_time=2.0)
    assert u.last_successful_time() == 2.0
    assert u.step(2.0, 0.1)
    here = u.last_successful_time()
    assert here == 2.0 + 0.1
    for t in (7.0, math.nan):
        assert not u.step(t, 0.1)
        assert u.last_successful_time() == here
    u.close()


def test_a_refused_set_changes_nothing(dumbbell_fmu):
    """fmi2SetReal with one unknown reference among known ones: fmi2Error and
    no value set (the next doStep must not feel the input)."""
    u, clean = unit(dumbbell_fmu), unit(dumbbell_fmu, name="clean")
    with pytest.raises(FMICallException):
        u.fmu.setReal([u.variables["F[1]"].valueReference, 9999], [5.0, 1.0])
    assert u.get(["F[1]"])[0] == 0.0
    for v in (u, clean):
        assert v.step(0.0, 0.01)
    np.testing.assert_array_equal(u.get(STATE), clean.get(STATE))
    u.close()
    clean.close()


def test_a_state_that_says_initialized_without_its_integrator_is_refused(dumbbell_fmu):
    """A damaged state whose integrator part is missing (one bit in the zip
    directory hides it) must not leave the FMU stepping without one."""
    from fmu.slave import _MAGIC
    u = unit(dumbbell_fmu)
    assert u.step(0.0, 0.01)
    state = u.get_state()
    data = u.serialize(state)
    header, arrays = hfdi.serial.unpack(data[len(_MAGIC):])
    assert header["phase"] == "stepping"
    del arrays["integrator"]
    damaged = _MAGIC + hfdi.serial.pack(header, arrays)
    before = u.get(OBSERVED)
    try:
        restored = u.deserialize(damaged)
    except FMICallException:
        restored = None
    if restored is not None:
        with pytest.raises(FMICallException):
            u.set_state(restored)
    np.testing.assert_array_equal(u.get(OBSERVED), before)
    assert u.step(0.01, 0.01)                   # still stepping from where it was
    u.close()


_FREED_STATE_SCRIPT = r"""
import sys
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2FMUstate
from fmu.master import Unit
u = Unit(sys.argv[1], "freed", unzip_dir=sys.argv[2])
u.initialize({}, start_time=0.0)
assert u.step(0.0, 0.01)
state = u.get_state()
kept = fmi2FMUstate(state.value)           # the master's copy of the pointer
u.free_state(state)
calls = {"set": lambda: u.set_state(kept), "serialize": lambda: u.serialize(kept),
         "free again": lambda: u.free_state(fmi2FMUstate(kept.value))}
for name, call in calls.items():
    try:
        call()
        print(name, "accepted")
    except FMICallException as exc:
        print(name, "refused", exc.status)
assert u.step(0.01, 0.01)
print("still stepping")
"""


@pytest.mark.slow
def test_a_freed_state_is_refused_not_a_crash(dumbbell_fmu):
    """Using an FMU state after fmi2FreeFMUstate is the master's mistake; the
    FMU answers fmi2Error and keeps working instead of touching freed memory
    (a crash of the host before). Run in a subprocess: a crash there is a
    return code here."""
    import subprocess
    path, unzip = dumbbell_fmu
    done = subprocess.run([sys.executable, "-c", _FREED_STATE_SCRIPT, str(path), str(unzip)],
                          capture_output=True, text=True, timeout=300,
                          cwd=str(Path(__file__).parent.parent))
    assert done.returncode == 0, (done.returncode, done.stderr[-2000:])
    lines = done.stdout.split("\n")
    for name in ("set", "serialize", "free again"):
        assert f"{name} refused 3" in lines, done.stdout       # fmi2Error
    assert "still stepping" in lines


# -- any mix of native and Python calls --------------------------------------------------
def _random_sequence(rng, length):
    """Calls of a master, as ``(name, argument)``: input changes, doSteps of
    sizes that take one or many internal steps, reads, no-op save/restore
    pairs, a serialized round trip, and a restore of a state saved earlier."""
    calls = []
    for _ in range(length):
        kind = rng.choice(["input", "step", "step", "step", "read", "noop", "serial",
                           "save", "restore"], p=[.16, .2, .2, .14, .1, .06, .04, .05, .05])
        if kind == "input":
            calls.append(("input", (int(rng.integers(1, N + 1)), float(rng.normal(0, 60)))))
        elif kind == "step":
            calls.append(("step", float(rng.choice([2e-4, 1e-3, 4e-3, 0.02]))))
        else:
            calls.append((kind, None))
    return calls


def _play(u, calls):
    """The values a master reads along ``calls`` (the states after every call)."""
    t, saved, seen = 0.0, None, []
    start = u.get_state()
    u.set_state(start)                       # every sequence from the initial state
    for name, arg in calls:
        if name == "input":
            u.set({f"F[{arg[0]}]": arg[1]})
        elif name == "step":
            assert u.step(t, arg), u.messages[-3:]
            t += arg
        elif name == "read":
            seen.append(u.get_string("scheme"))
        elif name == "noop":
            state = u.get_state()
            u.set_state(state)
            u.free_state(state)
        elif name == "serial":
            state = u.get_state()
            u.set_state(u.deserialize(u.serialize(state)))
            u.free_state(state)
        elif name == "save":
            if saved is not None:
                u.free_state(saved[0])
            saved = (u.get_state(), t)
        elif name == "restore" and saved is not None:
            u.set_state(saved[0])
            t = saved[1]
        seen.append(u.get(OBSERVED).tolist())
    if saved is not None:
        u.free_state(saved[0])
    u.free_state(start)
    return seen


# every scheme under both controls, in turn: 16 sequences take each of the
# eight pairs twice, with other random calls
@pytest.mark.parametrize("sequences", [pytest.param(3, id="quick"),
                                       pytest.param(16, id="16", marks=pytest.mark.slow)])
def test_native_and_python_fmus_agree_on_any_call_sequence(dumbbell_fmu, sequences):
    """The compiled FMU (its native layer takes the doSteps and reads it can)
    and the Python-path FMU, driven by the same random calls of a master:
    the same values bit for bit after every call, save and restore included.
    (A restore after an input change handed back a stale step history: 223
    internal steps where 220 were taken.)"""
    rng = np.random.default_rng(2026)
    pairs = list(itertools.product(hfdi.SCHEMES, ({"rtol": 1e-4}, {"target_iterations": 3.0})))
    for k in range(sequences):
        scheme, control = pairs[k % len(pairs)]
        parameters = {"scheme": scheme, "max_internal_steps": 5000, **control}
        units = [unit(dumbbell_fmu, dict(parameters, compiled=c), f"mix-{k}-{c}")
                 for c in (True, False)]
        try:
            calls = _random_sequence(rng, 40)
            native, python = (_play(u, calls) for u in units)
            for i, (a, b) in enumerate(zip(native, python)):
                assert a == b, (k, scheme, i, calls[: i + 1])
        finally:
            for u in units:
                u.close()


# -- the global error estimate ------------------------------------------------------------
@pytest.mark.slow
def test_global_error_outputs_are_the_integrators(dumbbell_fmu):
    """global_error_u and global_error_v: the largest entries of u's and v's
    halves of hfdi.Integrator.global_error, as in-process."""
    u = unit(dumbbell_fmu, {"rtol": 1e-5, "target_iterations": 0.0})
    itg = hfdi.Integrator(hfdi.models.get("dumbbell"), "hfdi", rtol=1e-5)
    t = 0.0
    for _ in range(10):
        assert u.step(t, 0.02)
        t += 0.02
        assert itg.advance(t)
    g = np.abs(itg.global_error)
    got = u.get(["global_error_u", "global_error_v"])
    np.testing.assert_allclose(got, [g[:N].max(), g[N:].max()], rtol=1e-9)
    assert got[0] > 0 and got[1] > 0
    u.close()


def test_error_mode_global_discards_a_step_past_the_tolerance(dumbbell_fmu):
    """error_mode = global: a doStep whose end has an estimate above the
    tolerance is discarded, the FMU back at its start, the log naming the
    rtol to rerun with; it needs a tolerance. (HFDI at rtol 1e-2 steps over
    the dumbbell's stiff bar while it turns: its estimate grows past the
    tolerance, docs/algorithm.md, "Global error estimate".)"""
    u = unit(dumbbell_fmu, {"rtol": 1e-2, "target_iterations": 0.0, "error_mode": "global"})
    t, h, missed = 0.0, 0.1, None
    while t < 2.0:
        if not u.step(t, h):
            missed = u.messages[-1][2]
            break
        t += h
    assert missed is not None and "error_mode = global" in missed, missed
    assert re.search(r"rerun the experiment with rtol <= [0-9.e-]+", missed)
    assert u.last_successful_time() == t
    u.close()
    path, unzip = dumbbell_fmu
    bad = Unit(path, "no tolerance", unzip_dir=unzip)
    with pytest.raises(FMICallException):
        bad.initialize({"target_iterations": 3.0, "error_mode": "global"})
    assert any("error_mode = 'global' needs a tolerance" in m[2] for m in bad.messages)
    bad.close(terminate=False)


@pytest.mark.slow
def test_a_state_restores_under_another_stop_time(dumbbell_fmu):
    """The integrator's error control shares the tolerance over the
    experiment (start to stop time): a state saved under one stop time is
    restored, into an instance set up with another, with the integrator it
    was made with, and continues as the original does."""
    path, unzip = dumbbell_fmu
    a = Unit(path, "stop 1", unzip_dir=unzip)
    a.initialize({"rtol": 1e-5, "target_iterations": 0.0}, stop_time=1.0)
    b = Unit(path, "no stop", unzip_dir=unzip)
    b.initialize({"rtol": 1e-5, "target_iterations": 0.0})
    assert a.step(0.0, 0.02)
    state = a.fmu.getFMUstate()
    data = a.fmu.serializeFMUstate(state)
    b.fmu.setFMUstate(b.fmu.deSerializeFMUstate(data))
    for u in (a, b):
        assert u.step(0.02, 0.02)
    assert np.array_equal(a.get(OBSERVED), b.get(OBSERVED))
    a.fmu.freeFMUstate(state)
    a.close()
    b.close()
