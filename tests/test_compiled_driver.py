"""The compiled driver (hfdi.compiled.driver) against the Python driver.

Both drive the same compiled attempt, so every difference would be the
driver's: the runs must agree bit for bit (steps, Newton counts, evaluations,
states, energies) on every paper model, scheme and controller, through
integrate()'s rows and dense output, and where the driver hands a step back
(breakpoints, stops, max_steps, the energy limit). tests/test_compiled_step.py
holds the compiled path against the Python path.
"""
import math
import warnings

import numpy as np
import pytest

import hfdi
from hfdi.compiled import driver_reason
from hfdi.controller import Combined, ErrorControl, IterationCount
from hfdi.models import articulated, dumbbell, tetrahedra, toss_rule
from test_compiled_step import Chain, case

numba = pytest.importorskip("numba")

PROBLEMS = {"dumbbell": (dumbbell, 0.01, 0.2), "tetrahedra": (tetrahedra, 2.5, 5.0),
            "articulated": (articulated, 0.06, 0.2), "toss_rule": (toss_rule, 0.003, 0.012)}
MODES = {"fixed": dict(step=1 / 40), "iterations": dict(target_iterations=3),
         "error": dict(rtol=1e-6), "combined": dict(target_iterations=3, rtol=1e-5)}
COUNTERS = ("steps", "accepted", "rejected", "newton_iterations", "error_test_failures",
            "first_step_trials", "first_step_trial_iterations", "nfev", "njev", "ntev", "npev",
            "nlu", "t_reached")
STATE = ("proposed_step", "potential", "last_step", "last_iterations", "grid_origin",
         "grid_steps", "status", "message", "first_step_pending")
#: Sums of the energy balance: their dot products run in BLAS, numpy's on the
#: Python driver and scipy's on the compiled one, whose orders of summation
#: may differ; they agree to rounding (and bit for bit where a load has one entry).
ENERGY = ("work", "energy_error", "energy_scale", "last_energy_increment")


def _pair(make, scheme, **options):
    """Two integrators of the same run: the compiled driver's, and the Python
    driver's around the same compiled attempt."""
    driven = hfdi.Integrator(make(), scheme, compiled=True, **options)
    python = hfdi.Integrator(make(), scheme, compiled=True, **options)
    assert driven.driven, driver_reason(driven)
    python._driver = None                       # the Python driver, same attempt
    return driven, python


def _assert_same_state(a, b):
    for name in COUNTERS:
        assert getattr(a.statistics, name) == getattr(b.statistics, name), name
    sa, sb = a.get_state(), b.get_state()
    for name in STATE:
        x, y = getattr(sa, name), getattr(sb, name)
        assert x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y)), name
    scale = max(abs(sa.energy_scale), abs(sa.work), 1e-300)
    for name in ENERGY:
        assert abs(getattr(sa, name) - getattr(sb, name)) <= 1e-13 * scale, name
    for which in ("current", "previous"):
        x, y = getattr(sa, which), getattr(sb, which)
        assert (x is None) == (y is None), which
        if x is None:
            continue
        assert x.t == y.t
        for field in ("u", "v", "a", "f", "p"):
            fx, fy = getattr(x, field), getattr(y, field)
            assert (fx is None) == (fy is None), (which, field)
            if fx is not None:
                np.testing.assert_array_equal(fx, fy, err_msg=f"{which}.{field}")


@pytest.mark.parametrize("mode", list(MODES))
@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
@pytest.mark.parametrize("problem", list(PROBLEMS))
def test_the_driver_takes_the_python_drivers_steps_bit_for_bit(problem, scheme, mode):
    make, t_end, options = case(problem, mode, PROBLEMS, MODES)
    driven, python = _pair(make, scheme, t_bound=t_end, **options)
    # in two calls, the first ending between steps
    for t_stop in (0.37 * t_end, t_end):
        assert driven.advance(t_stop) == python.advance(t_stop)
        _assert_same_state(driven, python)
    assert driven.status == hfdi.Status.SUCCESS and driven.statistics.steps > 5


@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
def test_integrate_gives_the_same_rows_and_dense_output(scheme):
    """integrate() takes the driver's rows in bulk: the same arrays as step by
    step, the t_eval outputs included, across the load's breakpoints."""
    t_end = 0.1
    t_eval = np.linspace(0.0, t_end, 41)
    runs = []
    for drive in (True, False):
        if not drive:
            import hfdi.integrator as module
            original = module.Integrator.driven
            module.Integrator.driven = property(lambda self: False)
        try:
            runs.append(hfdi.integrate(articulated(), scheme, t_end, rtol=1e-6, t_eval=t_eval,
                                       compiled=True))
            runs.append(hfdi.integrate(articulated(), scheme, t_end, rtol=1e-6, t_eval=t_eval,
                                       compiled=True, save_steps=False))
        finally:
            if not drive:
                module.Integrator.driven = original
    driven, driven_light, python, python_light = runs
    assert driven.success and driven.stats.steps > 50
    for key in ("t", "u", "v", "a", "step_size", "iterations", "energy_increment",
                "total_energy", "external_work", "u_eval", "v_eval"):
        np.testing.assert_array_equal(getattr(driven, key), getattr(python, key), err_msg=key)
        np.testing.assert_array_equal(getattr(driven_light, key), getattr(python_light, key),
                                      err_msg=key)
    assert driven_light.t.size == 2
    # the breakpoints (0.025, 0.05) were landed on, by the Python driver
    assert {0.025, 0.05} <= set(driven.t)


def test_progress_is_reported_from_the_driver(monkeypatch):
    monkeypatch.setattr(hfdi.integrator, "PROGRESS_INTERVAL", 0.0)
    seen = []
    result = hfdi.integrate(toss_rule(), "hfdi", 0.004, rtol=1e-7, compiled=True,
                            progress=lambda t, st: seen.append((t, st.accepted)))
    assert result.success
    assert len(seen) >= 2 and seen[-1][0] == 0.004
    assert [t for t, _ in seen] == sorted(t for t, _ in seen)


def log_spring():
    """``V = x²/2 + log(1 + x)/10`` thrown at its singularity ``x = -1``
    (reached at t ≈ 0.17): the steps shrink until below ``min_step``."""
    import sympy
    from hfdi.models.symbolic import EnergyModel
    x = sympy.Symbol("x")
    return EnergyModel([x], x**2 / 2 + sympy.log(1 + x) / 10, mass=[1.0],
                       initial_displacement=[0.0], initial_velocity=[-6.0])


def _stops():
    """Runs that the driver hands back to Python to stop: each must stop with
    the status, message and last good state of the Python driver."""
    yield "max_steps", articulated, dict(rtol=1e-6, max_steps=57), "MAX_STEPS"
    # a tiny first step, then growth until an error test fails
    yield "halvings", dumbbell, dict(rtol=1e-6, max_halvings=0, first_step=1e-6), \
        "HALVINGS_EXHAUSTED"
    yield "min_step", log_spring, dict(rtol=1e-6, min_step=1e-9), "STEP_BELOW_MINIMUM"
    yield "fixed", articulated, dict(step=0.004, max_iterations=2), "NEWTON_FAILED"
    yield "energy", tetrahedra, dict(target_iterations=6, energy_limit=1e-9), "ENERGY_GROWTH"


@pytest.mark.parametrize("name, make, options, status", list(_stops()),
                         ids=[s[0] for s in _stops()])
def test_stops_are_the_python_drivers(name, make, options, status):
    t_end = 0.2 if make is not tetrahedra else 5.0
    driven, python = _pair(make, "hfdi", t_bound=t_end, **options)
    ok = [itg.advance(t_end) for itg in (driven, python)]
    assert ok == [False, False]
    assert driven.status == hfdi.Status[status], driven.message
    assert driven.message == python.message
    assert driven.statistics.accepted > 0
    _assert_same_state(driven, python)


def test_a_potential_energy_lost_mid_run_stops_as_the_python_driver():
    """V known at the start and NaN at the end of a step: both drivers stop
    with MODEL_ERROR at the same last good state (the compiled one hands the
    step back)."""
    import sympy
    from hfdi.models.symbolic import EnergyModel
    x, c = sympy.symbols("x c")

    def make():
        return EnergyModel([x], x**2 / 2 + sympy.log(c), mass=[1.0], parameters={c: 2.0},
                           initial_displacement=[1.0])

    driven, python = _pair(make, "hfdi", rtol=1e-6)
    for itg in (driven, python):
        assert itg.advance(1.0)
        itg.system.set_parameters(c=-1.0)            # log(-1): V is NaN, f is not
        with np.errstate(invalid="ignore"):
            assert not itg.advance(2.0)
    assert driven.status == hfdi.Status.MODEL_ERROR, driven.message
    assert "potential_energy is NaN (unknown)" in driven.message
    assert driven.message == python.message
    assert driven.t == 1.0
    _assert_same_state(driven, python)


def test_state_saved_mid_run_continues_bit_for_bit():
    whole, _ = _pair(tetrahedra, "hfdi", rtol=1e-6, t_bound=4.0)
    whole.advance(1.3)
    whole.advance(4.0)
    first, _ = _pair(tetrahedra, "hfdi", rtol=1e-6, t_bound=4.0)
    first.advance(1.3)
    saved = hfdi.IntegratorState.from_bytes(first.get_state().to_bytes())
    second, _ = _pair(tetrahedra, "hfdi", rtol=1e-6, t_bound=4.0)
    second.set_state(saved)
    second.advance(4.0)
    _assert_same_state(second, whole)


def test_a_callback_runs_the_python_driver_with_the_same_steps():
    seen = []
    driven, _ = _pair(dumbbell, "bathe", rtol=1e-6, t_bound=0.01)
    stepped, _ = _pair(dumbbell, "bathe", rtol=1e-6, t_bound=0.01)
    driven.advance(0.01)
    stepped.advance(0.01, callback=lambda itg: seen.append(itg.t))
    assert len(seen) == stepped.statistics.accepted
    _assert_same_state(driven, stepped)


# -- when the driver is (not) used ---------------------------------------------------

class _Subclass(type(articulated())):
    def load(self, t):
        return 2.0 * super().load(t)


class _Counting(ErrorControl):
    pass


@pytest.mark.parametrize("why, build", [
    ("extra_load", lambda: hfdi.Integrator(dumbbell(), "hfdi", rtol=1e-6, compiled=True,
                                           extra_load=lambda t: np.zeros(4))),
    ("no compiled load", lambda: hfdi.Integrator(_Subclass(), "hfdi", rtol=1e-6,
                                                 compiled=True)),
    ("built-in controllers", lambda: hfdi.Integrator(
        dumbbell(), "hfdi", controller=_Counting(1e-6), compiled=True)),
    ("not compiled", lambda: hfdi.Integrator(dumbbell(), "hfdi", rtol=1e-6, compiled=False)),
])
def test_the_driver_is_not_used_where_it_would_compute_another_run(why, build):
    itg = build()
    assert not itg.driven
    assert why in driver_reason(itg)


def test_an_injected_built_in_controller_is_driven():
    c = Combined(IterationCount(3), ErrorControl(1e-5))
    driven, python = _pair(dumbbell, "hfdi", controller=c, t_bound=0.01)
    driven.advance(0.01)
    python.advance(0.01)
    _assert_same_state(driven, python)


def test_a_redefined_load_runs_on_the_python_driver_with_its_own_load():
    """A subclass that changes the load keeps the compiled attempt (its loads come
    from Python) but not the driver, whose compiled load is the parent's."""
    doubled = hfdi.integrate(_Subclass(), "hfdi", 0.05, rtol=1e-6, compiled=True)
    python = hfdi.integrate(_Subclass(), "hfdi", 0.05, rtol=1e-6)
    assert doubled.stats.steps == python.stats.steps
    np.testing.assert_array_equal(doubled.u, python.u)


# -- a user model with a compiled load, dense M and C -------------------------------

from numba import njit  # noqa: E402

from hfdi.compiled.signatures import JIT_OPTIONS, LOAD  # noqa: E402


@njit(LOAD, **JIT_OPTIONS)
def chain_load(t, load_params):
    p = np.zeros(3)
    p[2] = load_params[0] * math.sin(load_params[1] * t)
    return p


class DrivenChain(Chain):
    """The chain of test_compiled_step with its load compiled too."""

    def load(self, t):
        return np.array([0.0, 0.0, 3.0 * math.sin(20.0 * t)])

    load_rate = None    # HFDI takes the difference quotient, as the driver does

    def compiled_kernels(self):
        return super().compiled_kernels()._replace(load=chain_load,
                                                   load_params=np.array([3.0, 20.0]))


@pytest.mark.parametrize("damping", [None, np.array([0.3, 0.1, 0.2]),
                                     np.array([[0.4, -0.1, 0.0], [-0.1, 0.3, -0.1],
                                               [0.0, -0.1, 0.2]])],
                         ids=["undamped", "diagonal C", "dense C"])
@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
def test_user_model_with_compiled_load_and_dense_matrices(scheme, damping):
    driven, python = _pair(lambda: DrivenChain(damping), scheme, rtol=1e-6, t_bound=0.5)
    for itg in (driven, python):
        assert itg.advance(0.5)
    assert driven.statistics.steps > 20
    _assert_same_state(driven, python)
    # and the Python path, to rounding (its loads and products are numpy's)
    reference = hfdi.Integrator(DrivenChain(damping), scheme, rtol=1e-6, t_bound=0.5)
    reference.advance(0.5)
    assert reference.statistics.steps == driven.statistics.steps
    np.testing.assert_allclose(driven.state.u, reference.state.u, rtol=0, atol=1e-12)


def test_hat_load_kernel_is_the_models_load():
    from hfdi.compiled import kernels_of
    for make in (dumbbell, tetrahedra, articulated, toss_rule):
        model = make()
        kernels, _ = kernels_of(model)
        for t in np.concatenate([np.linspace(-0.01, 0.06, 71), model.load_breakpoints()
                                 if hasattr(model, "load_breakpoints") else []]):
            np.testing.assert_array_equal(kernels.load(float(t), kernels.load_params),
                                          model.load(float(t)))


def test_a_held_load_is_driven_as_the_python_driver_adds_it():
    """A co-simulation input (hfdi.HeldLoad) held over each advance and changed
    between them (load_changed): bit for bit, on the driver and on Python."""
    value = np.zeros(6)
    runs = []
    for drive in (True, False):
        itg = hfdi.Integrator(articulated(), "bathe", rtol=1e-6, compiled=True,
                              extra_load=hfdi.HeldLoad(lambda: value))
        assert itg.driven
        if not drive:
            itg._driver = None
        value[:] = 0.0
        for k, t in enumerate(np.linspace(0.005, 0.08, 16)):
            value[:] = 50.0 * np.sin(k + np.arange(6))
            itg.load_changed()
            assert itg.advance(t)
        runs.append(itg)
    _assert_same_state(*runs)
    assert runs[0].statistics.steps > 50


@pytest.mark.parametrize("fault", [np.nan, -np.inf])
def test_a_faulty_held_load_fails_the_run_as_on_the_python_path(fault):
    outcomes = []
    for drive in (True, False):
        value = np.zeros(6)
        itg = hfdi.Integrator(articulated(), "hfdi", rtol=1e-6, compiled=True,
                              extra_load=hfdi.HeldLoad(lambda: value))
        if not drive:
            itg._driver = None
        assert itg.advance(0.01)
        value[1] = fault
        assert not itg.advance(0.02)
        assert itg.t == 0.01 and "not finite" in itg.message
        outcomes.append((itg.status, itg.message, itg.statistics.steps))
    assert outcomes[0] == outcomes[1]
    with pytest.raises(ValueError, match="source must be callable"):
        hfdi.HeldLoad(np.zeros(6))


def test_compiled_code_that_cannot_be_loaded_leaves_the_python_path(monkeypatch):
    """numba failing to compile or cache (a read-only installation without a
    user cache, say): the default runs on, on the Python path, and says so
    once; compiled=True names the reason."""
    import warnings

    import hfdi.compiled as hc

    def broken(self):
        raise RuntimeError("cannot cache function: no locator available")

    monkeypatch.setattr(type(articulated()), "compiled_kernels", broken)
    monkeypatch.setattr(hc, "_SAID", set())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        runs = [hfdi.integrate(articulated(), "hfdi", 0.02, rtol=1e-6) for _ in range(2)]
    assert all(r.success for r in runs)
    said = [w for w in caught if "no locator available" in str(w.message)]
    assert len(said) == 1 and "Python path runs" in str(said[0].message)
    with pytest.raises(hc.CompiledUnavailable, match="no locator available"):
        hfdi.Integrator(articulated(), "hfdi", rtol=1e-6, compiled=True)


def test_a_driver_that_cannot_be_loaded_keeps_the_compiled_attempt(monkeypatch):
    import warnings

    import hfdi.compiled as hc
    import hfdi.compiled.driver as hd

    def broken(integrator):
        raise RuntimeError("the driver did not compile")

    monkeypatch.setattr(hd, "CompiledDriver", broken)
    monkeypatch.setattr(hc, "_SAID", set())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        itg = hfdi.Integrator(dumbbell(), "hfdi", rtol=1e-6, t_bound=0.01)
    assert itg.compiled and not itg.driven
    assert itg.advance(0.01)
    assert any("attempts compiled" in str(w.message) for w in caught)


def test_a_long_run_returns_to_python_between_calls(monkeypatch):
    """Control comes back to Python every STEPS_PER_CALL steps (a Ctrl-C is seen
    there), with the same run as in one call."""
    import hfdi.compiled.driver as hd
    whole, _ = _pair(dumbbell, "newmark", rtol=1e-7, t_bound=0.05)
    whole.advance(0.05)
    monkeypatch.setattr(hd, "STEPS_PER_CALL", 7)
    calls = []
    original = hd.drive

    def counting(*args):
        calls.append(1)
        return original(*args)

    monkeypatch.setattr(hd, "drive", counting)
    chunked, _ = _pair(dumbbell, "newmark", rtol=1e-7, t_bound=0.05)
    chunked.advance(0.05)
    assert len(calls) >= chunked.statistics.accepted // 7
    _assert_same_state(chunked, whole)


class _WrongLoad(DrivenChain):
    """Its compiled load has another frequency than its Python load."""

    def compiled_kernels(self):
        return super().compiled_kernels()._replace(load_params=np.array([3.0, 21.0]))


class _WrongStiffness(DrivenChain):
    """Its compiled kernels read other spring constants than its Python methods."""

    def compiled_kernels(self):
        kernels = super().compiled_kernels()
        return kernels._replace(params=2.0 * kernels.params)


@pytest.mark.parametrize("model, what", [(_WrongLoad, "load at t ="), (_WrongStiffness, "force")])
def test_kernels_that_compute_another_model_are_refused(model, what):
    """Kernels are checked against the Python model when the integrator is built
    (each at the initial state, the load at several times): kernels of another
    model would give a silent wrong answer, so the Python path runs, saying
    why once, and compiled=True names the kernel."""
    import warnings

    import hfdi.compiled as hc
    hc._SAID.clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        itg = hfdi.Integrator(model(None), "newmark", rtol=1e-6)
    assert not itg.compiled
    assert any(what in str(w.message) and "another model" in str(w.message) for w in caught)
    with pytest.raises(hc.CompiledUnavailable, match=f"compiled {what}"):
        hfdi.Integrator(model(None), "newmark", rtol=1e-6, compiled=True)


# -- kernels that fail: a wrong shape, an exception ------------------------------------

def _faulty_kernels():
    """A Duffing pair whose force kernel returns shape (1,) beyond |u_0| > params[0],
    and whose load kernel raises beyond t > load_params[0] (the model's Python
    methods are right everywhere but for the same raising load)."""
    from numba import njit

    from hfdi.compiled import CompiledKernels
    from hfdi.compiled.signatures import (FORCE, JIT_OPTIONS, LOAD, POTENTIAL_ENERGY,
                                          STIFFNESS, STIFFNESS_DERIVATIVE)

    @njit(FORCE, **JIT_OPTIONS)
    def force(u, params):
        if abs(u[0]) > params[0]:
            return np.zeros(1)
        return np.array([u[0] + u[0] ** 3, 2.0 * u[1]])

    @njit(STIFFNESS, **JIT_OPTIONS)
    def stiffness(u, params):
        return np.array([[1.0 + 3.0 * u[0] ** 2, 0.0], [0.0, 2.0]])

    @njit(STIFFNESS_DERIVATIVE, **JIT_OPTIONS)
    def derivative(u, w, params):
        return np.array([[6.0 * u[0] * w[0], 0.0], [0.0, 0.0]])

    @njit(POTENTIAL_ENERGY, **JIT_OPTIONS)
    def potential(u, params):
        return 0.5 * u[0] ** 2 + 0.25 * u[0] ** 4 + u[1] ** 2

    @njit(LOAD, **JIT_OPTIONS)
    def load(t, load_params):
        if t > load_params[0]:
            raise ValueError("the load fails late")
        return np.zeros(2)

    class Faulty(hfdi.SecondOrderSystem):
        mass, damping, n_dof, u_scale = np.ones(2), None, 2, 1.0
        initial_displacement, initial_velocity = np.array([0.0, 0.1]), np.array([0.3, 0.0])

        def __init__(self, limit=math.inf, fails_after=math.inf):
            self.limit, self.fails_after = limit, fails_after

        def internal_force(self, u):
            return np.array([u[0] + u[0] ** 3, 2.0 * u[1]])

        def stiffness(self, u):
            return np.array([[1.0 + 3.0 * u[0] ** 2, 0.0], [0.0, 2.0]])

        def stiffness_derivative(self, u, w):
            return np.array([[6.0 * u[0] * w[0], 0.0], [0.0, 0.0]])

        def potential_energy(self, u):
            return 0.5 * u[0] ** 2 + 0.25 * u[0] ** 4 + u[1] ** 2

        def load(self, t):
            if t > self.fails_after:
                raise ValueError("the load fails late")
            return np.zeros(2)

        def compiled_kernels(self):
            return CompiledKernels(force, stiffness, derivative, potential,
                                   np.array([self.limit]), load,
                                   np.array([min(self.fails_after, 1e300)]))

    return Faulty


@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
def test_a_kernel_value_of_a_wrong_shape_stops_the_run_with_model_error(scheme):
    """numba checks no bounds: a force kernel of shape (1,) was read past its
    end (a wrong run reported as a success); it is now MODEL_ERROR at the last
    good state, as a wrong shape of the model's method is on the Python path."""
    Faulty = _faulty_kernels()
    r = hfdi.integrate(Faulty(limit=0.27), scheme, 6.0, rtol=1e-6, compiled=True)
    assert r.status == hfdi.Status.MODEL_ERROR, (r.status, r.message)
    assert "internal_force returned shape (1,), expected (2,)" in r.message
    assert 0.5 < r.t[-1] < 6.0 and np.abs(r.u[:, 0]).max() <= 0.27
    # below the limit the same kernels run to the end, as the Python path does
    good = hfdi.integrate(Faulty(limit=0.5), scheme, 6.0, rtol=1e-6, compiled=True)
    plain = hfdi.integrate(Faulty(), scheme, 6.0, rtol=1e-6, compiled=False)
    assert good.success and good.stats.steps == plain.stats.steps


@pytest.mark.parametrize("scheme", ["newmark", "hfdi"])
def test_a_raising_kernel_is_a_failed_attempt_as_on_the_python_path(scheme):
    """An exception in a kernel escaped integrate() (no Result; advance() lost
    the driver's steps of that call); it is now a failed attempt, as a raising
    model is on the Python path: the same stop, at the same time, after the
    same accepted steps."""
    Faulty = _faulty_kernels()
    itg = hfdi.Integrator(Faulty(fails_after=1.5), scheme, rtol=1e-6, compiled=True)
    assert itg.driven
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)       # said once per process
        assert not itg.advance(3.0)
    assert not itg.driven           # the rest of the run is the Python driver's
    python = hfdi.Integrator(Faulty(fails_after=1.5), scheme, rtol=1e-6, compiled=False)
    assert not python.advance(3.0)
    assert itg.status == python.status == hfdi.Status.STEP_BELOW_MINIMUM
    assert itg.t == python.t and 1.5 - 1e-9 < itg.t <= 1.5
    assert itg.statistics.accepted == python.statistics.accepted
    np.testing.assert_allclose(itg.state.u, python.state.u, rtol=0, atol=1e-12)
    # integrate() keeps every row of such a run
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        r = hfdi.integrate(Faulty(fails_after=1.5), scheme, 3.0, rtol=1e-6, compiled=True)
    plain = hfdi.integrate(Faulty(fails_after=1.5), scheme, 3.0, rtol=1e-6, compiled=False)
    assert r.status == plain.status and r.message == plain.message
    assert r.t.size == plain.t.size == r.stats.accepted + 1 and r.t[-1] == plain.t[-1]


def _hidden_term_model():
    """Kernels that add ``c u₀³`` to the force (and its K and T) where the Python
    model has none: nothing at u0 = 0, v0 = 0, or while ``c = 0``."""
    from numba import njit

    from hfdi.compiled import CompiledKernels
    from hfdi.compiled.signatures import (FORCE, JIT_OPTIONS, LOAD, POTENTIAL_ENERGY,
                                          STIFFNESS, STIFFNESS_DERIVATIVE)

    @njit(FORCE, **JIT_OPTIONS)
    def force(u, params):
        return np.array([u[0] + params[0] * u[0] ** 3, 2.0 * u[1]])

    @njit(STIFFNESS, **JIT_OPTIONS)
    def stiffness(u, params):
        return np.array([[1.0 + 3.0 * params[0] * u[0] ** 2, 0.0], [0.0, 2.0]])

    @njit(STIFFNESS_DERIVATIVE, **JIT_OPTIONS)
    def derivative(u, w, params):
        return np.array([[6.0 * params[0] * u[0] * w[0], 0.0], [0.0, 0.0]])

    @njit(POTENTIAL_ENERGY, **JIT_OPTIONS)
    def potential(u, params):
        return 0.5 * u[0] ** 2 + 0.25 * params[0] * u[0] ** 4 + u[1] ** 2

    @njit(LOAD, **JIT_OPTIONS)
    def load(t, load_params):
        if t > 5.0:                       # defined up to t = 5 only
            return np.full(2, np.nan)
        return np.array([math.sin(t), 0.0])

    class Hidden(hfdi.SecondOrderSystem):
        mass, damping, n_dof, u_scale = np.ones(2), None, 2, 1.0
        initial_displacement, initial_velocity = np.zeros(2), np.zeros(2)

        def __init__(self, c):
            self.c, self.parameter_version = c, 0

        def set_c(self, c):
            self.c, self.parameter_version = c, self.parameter_version + 1

        def internal_force(self, u):
            return np.array([u[0], 2.0 * u[1]])

        def stiffness(self, u):
            return np.diag([1.0, 2.0])

        def stiffness_derivative(self, u, w):
            return np.zeros((2, 2))

        def potential_energy(self, u):
            return 0.5 * u[0] ** 2 + u[1] ** 2

        def load(self, t):
            return np.full(2, np.nan) if t > 5.0 else np.array([math.sin(t), 0.0])

        def compiled_params(self):
            return np.array([self.c])

        def compiled_kernels(self):
            return CompiledKernels(force, stiffness, derivative, potential,
                                   self.compiled_params(), load, np.zeros(0))

    return Hidden


@pytest.mark.parametrize("scheme", ["newmark", "hfdi"])
def test_kernels_that_differ_only_away_from_the_initial_state_are_refused(scheme):
    """Kernels were compared at u0 only (T at v0): a term vanishing at a model
    released from rest passed, and the run was silently another model's. A
    second state near u0 tells them apart."""
    Hidden = _hidden_term_model()
    with pytest.raises(hfdi.compiled.CompiledUnavailable, match="force at a second state"):
        hfdi.Integrator(Hidden(0.5), scheme, rtol=1e-6, compiled=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        itg = hfdi.Integrator(Hidden(0.5), scheme, rtol=1e-6)
    assert not itg.compiled
    same = hfdi.Integrator(Hidden(0.0), scheme, rtol=1e-6, compiled=True)   # no term: agree
    assert same.driven      # (and a load NaN past t = 5 in both is agreement, not a mismatch)


@pytest.mark.parametrize("scheme", ["newmark", "hfdi"])
def test_kernels_are_checked_again_when_the_model_changes(scheme):
    """Kernels that agree under one set of parameters may not under the next:
    after a change (parameter_version) they are compared again, and the rest
    of the run is the Python path where they differ."""
    Hidden = _hidden_term_model()
    model = Hidden(0.0)
    itg = hfdi.Integrator(model, scheme, rtol=1e-6, compiled=True)
    assert itg.driven and itg.advance(2.0)
    model.set_c(0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert itg.advance(4.0)
    assert not itg.compiled and not itg.driven
    plain = hfdi.Integrator(Hidden(0.0), scheme, rtol=1e-6, compiled=False)
    assert plain.advance(2.0)
    plain.system.set_c(0.5)
    assert plain.advance(4.0)
    np.testing.assert_allclose(itg.state.u, plain.state.u, rtol=0, atol=1e-9)


def test_the_library_kernels_skip_the_check_that_others_pass(monkeypatch):
    """The paper models' kernels are held to their Python methods by this
    suite; comparing them again at every construction cost up to 1.8 ms. A
    user's kernels are still compared."""
    def refuse(*args, **kwargs):
        raise AssertionError("kernel_mismatch called")

    monkeypatch.setattr(hfdi.compiled, "kernel_mismatch", refuse)
    monkeypatch.setattr(hfdi.compiled, "sparse_kernel_mismatch", refuse)
    for make in (dumbbell, articulated, tetrahedra, toss_rule):
        assert hfdi.Integrator(make(), "hfdi", rtol=1e-6, compiled=True).driven
    assert hfdi.Integrator(toss_rule(60), "hfdi", rtol=1e-6, compiled=True).compiled_model
    with pytest.raises(AssertionError, match="kernel_mismatch called"):
        hfdi.Integrator(_hidden_term_model()(0.0), "hfdi", rtol=1e-6, compiled=True)
    # the library's kernels with another model's data, handed out by a method
    # that is not the library's: checked, and refused
    monkeypatch.undo()
    from hfdi.models.dumbbell import Dumbbell
    other, library_method = dumbbell(A=2e6), Dumbbell.compiled_kernels
    monkeypatch.setattr(Dumbbell, "compiled_kernels", lambda self: library_method(other))
    with pytest.raises(hfdi.compiled.CompiledUnavailable, match="another model"):
        hfdi.Integrator(dumbbell(), "hfdi", rtol=1e-6, compiled=True)


def test_a_reason_is_said_again_in_another_situation(monkeypatch):
    """say_once kept the reason only: a fault said at construction was not
    said when the same reason came up after a model change."""
    import hfdi.compiled as hc
    monkeypatch.setattr(hc, "_SAID", set())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        hc.say_once("the reason")
        hc.say_once("the reason")
        hc.say_once("the reason", "after the model changed: {reason}")
    assert [str(w.message) for w in caught] == [
        "hfdi: the compiled step is not used (the reason); the Python path runs",
        "hfdi: after the model changed: the reason"]


def test_a_run_of_many_short_calls_keeps_only_its_rows():
    """A call of the driver ends at every breakpoint: the rows a run keeps
    are its rows (at most about twice them), not a full buffer per call."""
    import tracemalloc
    model = toss_rule()
    hfdi.integrate(model, "hfdi", 0.012, rtol=1e-6, compiled=True)      # compiled, loaded
    breakpoints = np.linspace(0.0, 0.1, 401)[1:-1]
    tracemalloc.start()
    try:
        result = hfdi.integrate(model, "hfdi", 0.1, rtol=1e-6, compiled=True,
                                breakpoints=breakpoints)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert result.success and result.stats.steps > 1000
    kept = sum(arr.nbytes for arr in (result.t, result.u, result.v, result.a))
    # a buffer per call (399 calls × 2048 rows) would be about 470 MB
    assert peak < 6 * kept + 20e6, (peak, kept)
