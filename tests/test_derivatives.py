"""Finite-difference checks of f, K and T (and that the check can fail)."""
import numpy as np

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
    """The test problems with exact or published references have exact f, K, T too."""
    import exact_problems
    from problems import pleiades
    for model in (pleiades(), exact_problems.kepler()[0], exact_problems.duffing()[0],
                  exact_problems.damped_chain()[0]):
        check = hfdi.check_derivatives(model, samples=10, spread=0.1)
        assert check.ok(1e-7), (model.name, check)
