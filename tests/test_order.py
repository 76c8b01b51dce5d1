"""Orders of accuracy measured by regression of the error on the step size."""
import numpy as np
import pytest
from scipy.stats import linregress

import hfdi
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


SCHEMES = [hfdi.Newmark(), hfdi.Bathe(), hfdi.HFDI(), hfdi.Newmark(gamma=0.6, beta=0.3025),
           hfdi.Bathe(gamma=0.4)]


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


def test_paper_load_rate_quotient_makes_hfdi_second_order():
    """The paper's p_t ≈ (p_{n+1} − p_n)/h is off by O(h) at t_{n+1}; multiplied by
    h²/6 it is an O(h³) local error, so a time-varying load costs one order."""
    system = coupled_duffing(load=lambda t: np.array([np.sin(3 * t), 0.0]),
                             load_rate=lambda t: np.array([3 * np.cos(3 * t), 0.0]))
    slope, _, errors = observed_order(system, hfdi.HFDI(load_rate="difference"))
    assert abs(slope - 2) <= 0.3, (slope, errors)
