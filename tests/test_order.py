"""Orders of accuracy measured by regression of the error on the step size."""
import numpy as np
import pytest
from scipy.stats import linregress

import hfdi
from exact_problems import damped_chain, duffing
from problems import coupled_duffing, reference_solution

T_END = 2.0
STEPS = T_END / 2.0 ** np.arange(4, 9)      # h = 0.125 ... 0.0078


def observed_order(system, scheme, steps=STEPS):
    u_ref, v_ref = reference_solution(system, T_END)
    errors = []
    for h in steps:
        result = hfdi.integrate(system, scheme, T_END, step=h, tol=1e-13)
        assert result.success, result.message
        assert result.t[-1] == T_END
        errors.append(np.linalg.norm(np.concatenate([result.u[-1] - u_ref,
                                                     result.v[-1] - v_ref])))
    fit = linregress(np.log(steps), np.log(errors))
    return fit.slope, fit.rvalue, errors


#: every scheme of the registry with its defaults, and variants of their parameters
SCHEMES = [kind() for kind in hfdi.SCHEMES.values()] + [
    hfdi.Newmark(gamma=0.6, beta=0.3025), hfdi.Bathe(gamma=0.4), hfdi.GeneralizedAlpha(0.0),
    hfdi.GeneralizedAlpha(0.5), hfdi.GeneralizedAlpha(1.0)]


@pytest.mark.parametrize("scheme", SCHEMES, ids=repr)
def test_order_on_a_damped_nonlinear_problem(scheme):
    """Each scheme converges with the order it declares (``scheme.order``, which
    the error control's step rule uses too): Newmark with γ ≠ 1/2 is first
    order."""
    slope, r, errors = observed_order(coupled_duffing(damping=0.05), scheme)
    assert abs(slope - scheme.order) <= 0.3, (slope, errors)
    assert r > 0.99


def test_hfdi_is_third_order_with_an_exact_load_rate():
    system = coupled_duffing(load=lambda t: np.array([np.sin(3 * t), 0.0]),
                             load_rate=lambda t: np.array([3 * np.cos(3 * t), 0.0]))
    scheme = hfdi.HFDI(load_rate="exact")
    slope, _, errors = observed_order(system, scheme)
    assert abs(slope - scheme.order) <= 0.3, (slope, errors)


@pytest.mark.slow
def test_hfdi_is_third_order_with_its_derived_load_rate():
    """A load without its rate, differentiated within the step (the quadratic
    through p at t_{n+1}, t_{n+1} − h/10, t_{n+1} − h/5): an O(h²) rate that
    keeps the third order the paper's quotient loses; its error is within
    5 % of the exact rate's."""
    system = coupled_duffing(load=lambda t: np.array([np.sin(3 * t), 0.0]))
    slope, _, errors = observed_order(system, hfdi.HFDI(load_rate="derived"))
    assert abs(slope - 3) <= 0.3, (slope, errors)
    exact = coupled_duffing(load=lambda t: np.array([np.sin(3 * t), 0.0]),
                            load_rate=lambda t: np.array([3 * np.cos(3 * t), 0.0]))
    _, _, exact_errors = observed_order(exact, hfdi.HFDI(load_rate="exact"))
    np.testing.assert_allclose(errors, exact_errors, rtol=0.05)


@pytest.mark.slow
@pytest.mark.parametrize("mode, same_as", [
    (dict(target_iterations=3), "difference"), (dict(step=0.01), "difference"),
    (dict(rtol=1e-6), "derived"), (dict(target_iterations=3, rtol=1e-5), "derived")])
def test_the_default_load_rate_is_derived_where_steps_land_on_breakpoints(mode, same_as):
    """HFDI's default for a load without its rate: derived under error control
    (alone or combined), whose steps land on the load's breakpoints; the
    paper's quotient in the iteration-count mode (the paper's tables) and
    with fixed steps (which step over a kink off their grid: the derived
    rate's samples near the step's end would amplify it)."""
    system = coupled_duffing(load=lambda t: np.array([np.sin(3 * t), 0.0]))
    runs = {rate: hfdi.integrate(system, hfdi.HFDI(load_rate=rate), T_END, **mode)
            for rate in ("auto", "difference", "derived")}
    assert all(run.success for run in runs.values())
    other = "derived" if same_as == "difference" else "difference"
    np.testing.assert_array_equal(runs["auto"].u, runs[same_as].u)
    assert runs["auto"].u.shape != runs[other].u.shape or np.any(runs["auto"].u != runs[other].u)


def test_a_load_linear_between_its_breakpoints_keeps_the_exact_quotient():
    """The library's hat pulses are linear between their kinks: under error
    control HFDI's default takes the quotient, their exact rate (the same run
    as load_rate="difference", no loads spent on a derivative); a subclass
    that replaces the load gets the derived rate."""
    model = hfdi.models.articulated
    runs = [hfdi.integrate(model(), hfdi.HFDI(load_rate=rate), 0.03, rtol=1e-5)
            for rate in ("auto", "difference")]
    assert model().load_linear_between_breakpoints
    np.testing.assert_array_equal(runs[0].u, runs[1].u)
    assert runs[0].stats.npev == runs[1].stats.npev

    class Smooth(type(model())):
        def load(self, t):
            return super().load(t) * (1.0 + 0.1 * np.sin(100.0 * t))

    assert not Smooth().load_linear_between_breakpoints
    smooth = [hfdi.integrate(Smooth(), hfdi.HFDI(load_rate=rate), 0.03, rtol=1e-5)
              for rate in ("auto", "derived")]
    np.testing.assert_array_equal(smooth[0].u, smooth[1].u)


def test_paper_load_rate_quotient_makes_hfdi_second_order():
    """The paper's p_t ≈ (p_{n+1} − p_n)/h is off by O(h) at t_{n+1}; multiplied by
    h²/6 it is an O(h³) local error, so a time-varying load costs one order."""
    system = coupled_duffing(load=lambda t: np.array([np.sin(3 * t), 0.0]),
                             load_rate=lambda t: np.array([3 * np.cos(3 * t), 0.0]))
    slope, _, errors = observed_order(system, hfdi.HFDI(load_rate="difference"))
    assert abs(slope - 2) <= 0.3, (slope, errors)


@pytest.mark.parametrize("rho_inf", [0.0, 0.5, 0.8, 1.0])
@pytest.mark.parametrize("problem", [duffing, damped_chain], ids=lambda p: p.__name__)
def test_generalized_alpha_is_second_order_against_exact_solutions(problem, rho_inf):
    """Fixed steps of generalized-α converge as h² to the exact solution (an
    elliptic-function Duffing oscillator, a damped linear chain), whatever
    ρ∞ (the force-interpolated form keeps the order)."""
    system, exact = problem()
    steps = 1.0 / 2.0 ** np.arange(5, 10)
    errors = []
    for h in steps:
        result = hfdi.integrate(system, hfdi.GeneralizedAlpha(rho_inf), 1.0, step=h, tol=1e-13)
        assert result.success, result.message
        u, v = exact(1.0)
        errors.append(np.linalg.norm(np.concatenate([result.u[-1] - u, result.v[-1] - v])))
    fit = linregress(np.log(steps), np.log(errors))
    assert abs(fit.slope - 2.0) <= 0.15 and fit.rvalue > 0.999, (fit.slope, errors)


def test_the_damped_chains_exact_solution_is_the_matrix_exponential():
    """The reference of the damped chain (eigenvectors) against scipy's expm."""
    import scipy.linalg as sla
    _, exact = damped_chain()
    times = np.array([0.0, 0.37, 2.0, 11.5])
    u, v = exact(times)
    for k, t in enumerate(times):
        y = sla.expm(exact.matrix * t) @ exact.start
        np.testing.assert_allclose(np.concatenate([u[k], v[k]]), y, rtol=0,
                                   atol=1e-14 * max(1.0, np.abs(y).max()))
