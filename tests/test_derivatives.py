"""Finite-difference checks of f, K and T (and that the check can fail)."""
import numpy as np
import pytest

import hfdi
from problems import coupled_duffing, dumbbell_states


def test_dumbbell_derivatives_match_finite_differences():
    model = hfdi.models.dumbbell()
    check = hfdi.check_derivatives(model, dumbbell_states(np.random.default_rng(1), 20))
    assert check.samples == 20
    assert check.force < 1e-8
    assert check.stiffness < 1e-8
    assert check.stiffness_derivative < 1e-8


def test_dumbbell_tangent_is_symmetric_and_translation_invariant():
    model = hfdi.models.dumbbell()
    u = dumbbell_states(np.random.default_rng(2), 1)[0]
    K = model.stiffness(u)
    np.testing.assert_allclose(K, K.T, atol=1e-9 * abs(K).max())
    # a rigid translation changes nothing: K @ (1,0,1,0) = 0
    np.testing.assert_allclose(K @ [1, 0, 1, 0], 0, atol=1e-9 * abs(K).max())
    T = model.stiffness_derivative(u, np.array([0.3, -0.2, 0.1, 0.5]))
    np.testing.assert_allclose(T, T.T, atol=1e-9 * abs(T).max())


def test_dumbbell_rest_length_and_frequency():
    model = hfdi.models.dumbbell()
    np.testing.assert_allclose(model.rest_length, 1.0, rtol=1e-14)
    np.testing.assert_allclose(model.internal_force([0, 0, 1, 0]), 0, atol=1e-8)
    # ω² of the bond = 2 φ''(1) / m; the spec quotes ω ≈ 2362 rad/s
    K = model.stiffness(np.array([0, 0, 1.0, 0]))
    omega = np.sqrt(np.linalg.eigvalsh(K).max())
    assert abs(omega - 2362) < 1


def test_small_test_problem_derivatives():
    check = hfdi.check_derivatives(coupled_duffing(), samples=10, spread=1.0)
    assert check.ok(1e-8), check


def test_check_detects_a_wrong_directional_derivative():
    good = coupled_duffing()
    wrong = hfdi.System(mass=good.mass, internal_force=good.internal_force,
                        stiffness=good.stiffness,
                        stiffness_derivative=lambda u, w: 0.9 * good.stiffness_derivative(u, w),
                        potential_energy=good.potential_energy,
                        initial_displacement=good.initial_displacement)
    check = hfdi.check_derivatives(wrong, samples=5, spread=1.0)
    assert check.stiffness < 1e-8
    assert check.stiffness_derivative > 0.05
    assert not check.ok()


def test_check_detects_a_wrong_stiffness():
    good = coupled_duffing()
    wrong = hfdi.System(mass=good.mass, internal_force=good.internal_force,
                        stiffness=lambda u: good.stiffness(u) + 1e-3,
                        stiffness_derivative=good.stiffness_derivative,
                        potential_energy=good.potential_energy,
                        initial_displacement=good.initial_displacement)
    assert hfdi.check_derivatives(wrong, samples=3).stiffness > 1e-5


def test_reference_problems_derivatives():
    """The test problems with exact or published references have exact f, K, T
    too: the hand-written ones and the derived ones."""
    import exact_problems
    from problems import pleiades
    for model in (pleiades(), exact_problems.kepler()[0], exact_problems.duffing()[0],
                  pleiades(python=True), exact_problems.kepler(python=True)[0],
                  exact_problems.duffing(python=True)[0], exact_problems.damped_chain()[0]):
        check = hfdi.check_derivatives(model, samples=10, spread=0.1)
        assert check.ok(1e-7), (model.name, check)


def _with(**overrides):
    good = coupled_duffing()
    args = dict(mass=good.mass, internal_force=good.internal_force, stiffness=good.stiffness,
                stiffness_derivative=good.stiffness_derivative,
                potential_energy=good.potential_energy,
                initial_displacement=good.initial_displacement)
    args.update(overrides)
    return hfdi.System(**args)


def test_check_fails_a_model_whose_values_are_not_finite():
    """A NaN error must not pass as a perfect score (max(0, nan) is 0)."""
    n = coupled_duffing().n_dof
    nan_vector, nan_matrix = (lambda *a: np.full(n, np.nan)), (lambda *a: np.full((n, n), np.nan))
    for overrides, entry in (({"stiffness": nan_matrix}, "stiffness"),
                             ({"internal_force": nan_vector}, "stiffness"),
                             ({"stiffness_derivative": nan_matrix}, "stiffness_derivative"),
                             ({"potential_energy": lambda u: np.inf}, "force")):
        check = hfdi.check_derivatives(_with(**overrides), samples=3, spread=1.0)
        assert getattr(check, entry) == np.inf, (overrides, check)
        assert not check.ok(1.0), (overrides, check)


def test_check_fails_a_potential_known_at_some_states_only():
    """V given at one state and NaN ("not provided") at another is a faulty
    model (a run stops on it with MODEL_ERROR), not a model without V: the
    force check must not be dropped. NaN everywhere is a model without V."""
    good = coupled_duffing()
    states = good.initial_displacement + np.array([[0.0, 0.0], [0.3, -0.2], [-0.1, 0.4]])
    u0 = good.initial_displacement
    picky = _with(potential_energy=lambda u: good.potential_energy(u) if u[0] < u0[0] + 0.2
                  else np.nan)
    check = hfdi.check_derivatives(picky, states=states)
    assert check.force == np.inf and not check.ok(1.0), check
    # the same states, V everywhere: passes; V nowhere: no force check, passes
    assert hfdi.check_derivatives(good, states=states).ok(1e-7)
    check = hfdi.check_derivatives(_with(potential_energy=lambda u: np.nan), states=states)
    assert np.isnan(check.force) and check.ok(1e-7), check


def test_a_load_rate_of_zero_at_an_extremum_of_the_load_is_judged_right():
    """p = cos t: p'(0) = 0 was measured against the differences' own O(δ³)
    error and refused ("differ by 1"), by check_derivatives and by HFDI's
    Integrator; a wrong rate there is still refused."""
    e0 = np.array([1.0, 0.0])
    right = _with(load=lambda t: np.cos(t) * e0, load_rate=lambda t: -np.sin(t) * e0)
    wrong = _with(load=lambda t: np.cos(t) * e0, load_rate=lambda t: (0.01 - np.sin(t)) * e0)
    assert hfdi.check_derivatives(right, samples=1, times=[0.0, 1.0]).load_rate < 1e-6
    assert hfdi.check_derivatives(wrong, samples=1, times=[0.0]).load_rate > 1e-2
    for t_end in (3.0, 1e-3, 100.0):
        itg = hfdi.Integrator(right, hfdi.HFDI(load_rate="exact"), rtol=1e-6, t_bound=t_end)
        assert itg.advance(min(t_end, 0.1))      # refused at construction if at all
    with pytest.raises(hfdi.ModelError, match="load_rate does not match"):
        hfdi.Integrator(wrong, hfdi.HFDI(load_rate="exact"), rtol=1e-6, t_bound=3.0)
    # the scale of a zero rate is the finest variation the load resolves, not
    # a mean over a long step, which made wrong rates of growing loads pass
    from hfdi.system import load_rate_error
    grow = lambda t: np.array([np.exp(t / 0.01)])                       # noqa: E731
    for time_scale in (1.0, 10.0):
        assert load_rate_error(grow, lambda t: 5 * grow(t) / 0.01, 0.0, time_scale) > 0.5
        assert load_rate_error(grow, lambda t: grow(t) / 0.01, 0.0, time_scale) < 1e-8
    cube = lambda t: np.array([t ** 3])                                   # noqa: E731
    assert load_rate_error(cube, lambda t: np.array([1.003 * 3 * t ** 2]), 1.0, 100.0) > 2e-3
    ramp = _with(load=lambda t: np.tanh(t - 0.5) * e0,
                 load_rate=lambda t: 2.0 / np.cosh(t - 0.5) ** 2 * e0)   # twice the rate
    for t_end in (1.0, 10.0):
        with pytest.raises(hfdi.ModelError, match="load_rate does not match"):
            hfdi.Integrator(ramp, hfdi.HFDI(load_rate="exact"), rtol=1e-6, t_bound=t_end)



def test_a_load_rate_wrong_only_away_from_the_start_is_refused():
    """p = t² with p' = t: both zero at t0 = 0, so the check at t0 passed and
    HFDI ran with the wrong rate in its step equation. The rate is now also
    checked inside the run's span (where its end is known), and the right
    rate still passes, also with a breakpoint declared near a checked time."""
    e0 = np.array([1.0, 0.0])
    right = _with(load=lambda t: t * t * e0, load_rate=lambda t: 2.0 * t * e0)
    wrong = _with(load=lambda t: t * t * e0, load_rate=lambda t: t * e0)
    from hfdi.system import load_rate_error
    assert load_rate_error(wrong.load, wrong.load_rate, 0.0, 3.0) < 1e-3   # unseen at t0
    with pytest.raises(hfdi.ModelError, match=r"load_rate does not match load at t = 1\.1"):
        hfdi.Integrator(wrong, hfdi.HFDI(load_rate="exact"), rtol=1e-6, t_bound=3.0)
    for t_end in (3.0, 1e-3, 100.0):
        assert hfdi.Integrator(right, hfdi.HFDI(load_rate="exact"), rtol=1e-6,
                               t_bound=t_end).advance(min(t_end, 0.01))
    # a kink just after a checked time, declared: the differences stop before it
    kinked = _with(load=lambda t: (t * t + 5.0 * max(t - 1.1037, 0.0)) * e0,
                   load_rate=lambda t: (2.0 * t + 5.0 * (t >= 1.1037)) * e0)
    kinked.load_breakpoints = lambda: (1.1037,)
    assert hfdi.Integrator(kinked, hfdi.HFDI(load_rate="exact"), rtol=1e-6, t_bound=3.0)
    # a pulse over before the span's middle, its end declared: checked inside
    # its own interval (at t0 and at the span's shares it is zero, rate and all)
    pulse = lambda t: (np.sin(np.pi * t / 0.2) ** 2 if t < 0.2 else 0.0) * e0   # noqa: E731
    pulse_rate = lambda t: (np.pi / 0.2 * np.sin(2 * np.pi * t / 0.2) if t < 0.2    # noqa: E731
                            else 0.0) * e0
    for factor, refused in ((1.3, True), (1.0, False)):
        model = _with(load=pulse, load_rate=lambda t, f=factor: f * pulse_rate(t))
        model.load_breakpoints = lambda: (0.2,)
        if refused:
            with pytest.raises(hfdi.ModelError, match=r"does not match load at t = 0\.07"):
                hfdi.Integrator(model, hfdi.HFDI(load_rate="exact"), rtol=1e-6, t_bound=2.0)
        else:
            assert hfdi.Integrator(model, hfdi.HFDI(load_rate="exact"), rtol=1e-6, t_bound=2.0)


@pytest.mark.parametrize("case", ["defined to an event", "rounding noise", "offset",
                                  "periodic in round time"])
def test_the_rate_check_inside_the_span_refuses_no_right_rate(case):
    """Right rates the check inside the span must not refuse: a load from a
    table that ends before t_bound (the run stops at a terminal event), a
    component that is rounding noise, a large constant beside a small
    oscillation, a load periodic in a round time over a long span."""
    e0 = np.array([1.0, 0.0])
    t_bound = 10.0
    if case == "defined to an event":
        load = lambda t: (np.sin(t) if t <= 3.0 else np.nan) * e0          # noqa: E731
        rate = lambda t: (np.cos(t) if t <= 3.0 else np.nan) * e0          # noqa: E731
    elif case == "rounding noise":
        row = np.array([0.1 + 0.2 - 0.3, 1.0])      # the first sums to ~5.6e-17
        load = lambda t: row * np.cos(7 * t)                                   # noqa: E731
        rate = lambda t: -7 * row * np.sin(7 * t)                              # noqa: E731
    elif case == "offset":
        load = lambda t: (5e8 * (1 - np.exp(-50 * t)) + np.sin(10 * t)) * e0  # noqa: E731
        rate = lambda t: (2.5e10 * np.exp(-50 * t) + 10 * np.cos(10 * t)) * e0  # noqa: E731
        t_bound = 5.0
    else:
        load = lambda t: np.sin(2 * np.pi * t) * e0                            # noqa: E731
        rate = lambda t: 2 * np.pi * np.cos(2 * np.pi * t) * e0                # noqa: E731
        t_bound = 1e7
    model = _with(load=load, load_rate=rate)
    assert hfdi.Integrator(model, hfdi.HFDI(load_rate="exact"), rtol=1e-6, t_bound=t_bound)


def test_check_refuses_bad_arguments():
    model = coupled_duffing()
    n = model.n_dof
    for kwargs, name in (({"states": np.zeros((3, n + 1))}, "states"),
                         ({"states": np.zeros((0, n))}, "states"),
                         ({"states": [[np.nan] * n]}, "states"),
                         ({"states": "abc"}, "states"),
                         ({"samples": 0}, "samples"), ({"samples": 2.5}, "samples"),
                         ({"spread": -1.0}, "spread"), ({"spread": 1e200}, "spread"),
                         ({"eps": 0.0}, "eps"), ({"eps": np.nan}, "eps")):
        with pytest.raises(ValueError, match=name):
            hfdi.check_derivatives(model, **kwargs)
    with pytest.raises(TypeError, match="system"):
        hfdi.check_derivatives(object())


def test_check_measures_the_load_rate():
    """p' against differences of p: a correct rate passes whatever the load's
    time scale (a slow one, one with ω = 1e5, a ramp whose kink is at t = 0),
    a wrong one fails."""
    def model(load, rate):
        return _with(load=load, load_rate=rate)

    e0 = np.array([1.0, 0.0])
    for omega in (0.3, 5.0, 1e5):
        good = model(lambda t, w=omega: np.sin(w * t) * e0,
                     lambda t, w=omega: w * np.cos(w * t) * e0)
        assert hfdi.check_derivatives(good, samples=1).load_rate < 1e-6, omega
        wrong = model(lambda t, w=omega: np.sin(w * t) * e0,
                      lambda t, w=omega: 1.05 * w * np.cos(w * t) * e0)
        assert hfdi.check_derivatives(wrong, samples=1).load_rate > 0.04, omega
    ramp = model(lambda t: max(t, 0.0) * e0, lambda t: (1.0 if t >= 0 else 0.0) * e0)
    assert hfdi.check_derivatives(ramp, samples=1, times=[0.0, 2.0]).load_rate < 1e-6
    assert np.isnan(hfdi.check_derivatives(coupled_duffing(), samples=1).load_rate)
