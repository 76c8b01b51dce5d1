"""The two speeds are one implementation: the same run, compiled and as plain
Python, gives the same numbers.

The stepping code (hfdi.stepping, hfdi.core, hfdi.linsolve) is written once;
``compiled=True`` runs it compiled by numba, ``compiled=False`` runs the same
functions in CPython. Both call the model's same kernels, the same LAPACK and
BLAS routines of one library, and their array primitives compute every entry
with the same operations in the same order, so the runs agree bit for bit:
every counter, every accepted state, every energy. A difference here is a
primitive whose two bodies round differently, not a tolerance to widen.

Every registered model runs under every registered scheme and mode; the quick
tier takes the two smallest models, the slow tier all of them.
"""
import dataclasses
import math

import numpy as np
import pytest

import hfdi
from problems import schemes_quick
from validation.experiments import EXPERIMENTS

pytest.importorskip("numba")

MODES = {"fixed": lambda T: dict(step=T / 2000), "iterations": lambda T: dict(target_iterations=3),
         "error": lambda T: dict(rtol=1e-6), "combined": lambda T: dict(target_iterations=3,
                                                                         rtol=1e-5)}
QUICK_MODELS = ("dumbbell", "articulated")
MODELS = [pytest.param(name, marks=() if name in QUICK_MODELS else pytest.mark.slow)
          for name in hfdi.models.available()]
SCHEMES = list(hfdi.SCHEMES)


def _observation_time(name):
    experiment = EXPERIMENTS.get(name)
    return experiment.observation_time if experiment is not None else 50.0


def assert_same_result(a, b):
    """Two results of the same run: equal status, counters, rows and energies."""
    assert (a.status, a.message) == (b.status, b.message)
    for field in dataclasses.fields(a.stats):
        if field.name != "cpu_time":
            assert getattr(a.stats, field.name) == getattr(b.stats, field.name), field.name
    for name in ("t", "u", "v", "a", "step_size", "iterations", "energy_increment",
                 "total_energy", "external_work", "energy_error", "global_error"):
        x, y = getattr(a, name, None), getattr(b, name, None)
        if x is not None or y is not None:
            np.testing.assert_array_equal(x, y, err_msg=name)


def assert_same_state(a, b):
    """Two integrators at the same point of the same run, bit for bit."""
    assert a.statistics.steps == b.statistics.steps
    sa, sb = a.get_state(), b.get_state()
    for name in ("proposed_step", "potential", "work", "energy_error", "energy_scale",
                 "last_step", "last_iterations", "last_energy_increment", "grid_origin",
                 "grid_steps", "status", "message", "first_step_pending", "newton_constant",
                 "newton_guard"):
        x, y = getattr(sa, name), getattr(sb, name)
        assert x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y)), name
    np.testing.assert_array_equal(sa.global_error, sb.global_error, err_msg="global_error")
    for which in ("current", "previous"):
        x, y = getattr(sa, which), getattr(sb, which)
        assert (x is None) == (y is None), which
        if x is not None:
            assert x.t == y.t
            for field in ("u", "v", "a", "f", "p"):
                np.testing.assert_array_equal(getattr(x, field), getattr(y, field),
                                              err_msg=f"{which}.{field}")


def _pair(make, *args, **options):
    compiled, python = make(*args, compiled=True, **options), make(*args, compiled=False,
                                                                   **options)
    return compiled, python


@pytest.mark.parametrize("mode", list(MODES))
@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("model", MODELS)
def test_a_run_is_the_same_at_both_speeds(model, scheme, mode):
    """integrate() to its step limit: the same rows, counters and status."""
    T = _observation_time(model)
    options = MODES[mode](T)
    if mode == "fixed":
        T = 60 * options["step"]
    else:
        options["max_steps"] = 60
    compiled, python = [hfdi.integrate(hfdi.models.get(model), scheme, T, compiled=c,
                                       **options) for c in (True, False)]
    # the step limit, or the end (a linear model's steps grow without bound
    # under the iteration-count rule)
    assert compiled.stats.steps >= 30 or compiled.t[-1] == T
    assert_same_result(compiled, python)


@pytest.mark.parametrize("scheme", schemes_quick("hfdi", "newmark"))
def test_controlling_u_alone_is_the_same_at_both_speeds(scheme):
    """An atol infinite for v (only u controlled, docs/accuracy.md): the same
    run at both speeds."""
    model = hfdi.models.get("dumbbell")
    n = model.n_dof
    atol = np.r_[np.full(n, 1e-9), np.full(n, np.inf)]
    compiled, python = [hfdi.integrate(model, scheme, 2.0, rtol=1e-6, atol=atol, max_steps=60,
                                       compiled=c) for c in (True, False)]
    assert compiled.stats.steps >= 30
    assert_same_result(compiled, python)


@pytest.mark.slow
@pytest.mark.parametrize("scheme", SCHEMES)
def test_communication_points_breakpoints_and_short_steps_alike(scheme):
    """advance() to points a master sums (short steps past the articulated
    system's load breakpoint among them), then a changed model: the two
    speeds stay equal at every point."""
    itg = [hfdi.Integrator(hfdi.models.articulated(), scheme, rtol=1e-4, compiled=c)
           for c in (True, False)]
    t = 0.0
    for k in range(60):
        t += 1e-3 if k % 7 else 2e-17
        for one in itg:
            assert one.advance(t), one.message
        assert_same_state(*itg)
    for one in itg:
        one.system.k_f = 2000.0
        one.model_changed()
        assert one.advance(0.08)
    assert_same_state(*itg)


@pytest.mark.parametrize("scheme", schemes_quick("hfdi"))
@pytest.mark.parametrize("tell", ["model_changed", "load_changed"])
def test_a_changed_load_is_followed_alike(scheme, tell):
    """The load's own data changed mid-run (the articulated system's pulse
    switched off while it acts), then model_changed() or load_changed(): the
    compiled loop takes the load the Python steps take. It kept the old pulse
    (load_params apart from the model's params were not taken again: 0.28
    apart at t = 0.1)."""
    # the pulse acts until 0.05: switched off at 0.01, the runs compared at 0.02
    itg = [hfdi.Integrator(hfdi.models.articulated(), scheme, rtol=1e-5, t_bound=0.02,
                           compiled=c) for c in (True, False)]
    for one in itg:
        assert one.advance(0.01), one.message
        one.system.load_amplitude = 0.0
        getattr(one, tell)()
        assert one.advance(0.02), one.message
    assert itg[0].compiled
    assert_same_state(*itg)


@pytest.mark.slow
@pytest.mark.parametrize("scheme", SCHEMES)
def test_a_saved_state_continues_alike_at_the_other_speed(scheme):
    """A state saved by one speed and restored into the other continues as the
    first would have."""
    first = hfdi.Integrator(hfdi.models.dumbbell(), scheme, rtol=1e-4, compiled=True)
    assert first.advance(0.05)
    saved = first.get_state()
    other = hfdi.Integrator(hfdi.models.dumbbell(), scheme, rtol=1e-4, compiled=False)
    other.set_state(saved)
    assert first.advance(0.1) and other.advance(0.1)
    assert_same_state(first, other)


def test_the_stop_guards_alike():
    """max_steps, the energy limit and a model failure stop both speeds at the
    same step with the same status and message."""
    model = hfdi.models.dumbbell
    runs = [hfdi.integrate(model(), "hfdi", 1.0, rtol=1e-6, max_steps=17, compiled=c)
            for c in (True, False)]
    assert runs[0].status == hfdi.Status.MAX_STEPS
    assert_same_result(*runs)
    runs = [hfdi.integrate(model(), "newmark", 1.0, step=0.05, energy_limit=1e-9, compiled=c)
            for c in (True, False)]
    assert not runs[0].success
    assert_same_result(*runs)
