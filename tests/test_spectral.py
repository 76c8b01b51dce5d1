"""Amplification matrices from the code against closed forms (paper Section 3)."""
import numpy as np
import pytest
import sympy as sp

from hfdi.spectral import amplification_matrix, spectral_properties

TAUS = [0.01, 0.1, 0.5, 1.0, 2.0, 5.0, 10.0, 100.0, 1e4]


def hfdi_eq28(t):
    """Eq. 28 as restated in the algorithm notes, state r = (u, h v, h² a)."""
    t2 = t * t
    return np.array([[2 * (18 - 7 * t2), 2 * (18 - t2), 0],
                     [2 * t2 * (t2 - 18), 2 * (18 - 7 * t2), 0],
                     [t2 * (14 * t2 - 36), 2 * t2 * (t2 - 18), 0]]) / (t2 * t2 + 4 * t2 + 36)


def kinematic_amplification(scheme, tau):
    """A derived symbolically from the schemes' kinematic relations (not from the
    residual form the code uses): Newmark Eqs. 3–4, Bathe Eqs. 6–8, HFDI Eqs. 25–27."""
    h, w = sp.Rational(1), sp.nsimplify(tau)      # h = 1, ω = τ
    u0, hv0, h2a0 = sp.symbols("u0 hv0 h2a0")
    v0, a0 = hv0 / h, h2a0 / h ** 2
    if scheme == "newmark":
        u, v, a = sp.symbols("u v a")
        eqs = [u - (u0 + h * v0 + h ** 2 / 4 * (a0 + a)), v - (v0 + h / 2 * (a0 + a)),
               a + w ** 2 * u]
    elif scheme == "bathe":
        uh, vh, ah, u, v, a = sp.symbols("uh vh ah u v a")
        g = sp.Rational(1, 2)
        c1, c2, c3 = (1 - g) / (g * h), -1 / ((1 - g) * g * h), (2 - g) / ((1 - g) * h)
        eqs = [uh - (u0 + g * h / 2 * (v0 + vh)), vh - (v0 + g * h / 2 * (a0 + ah)),
               ah + w ** 2 * uh, v - (c1 * u0 + c2 * uh + c3 * u),
               a - (c1 * v0 + c2 * vh + c3 * v), a + w ** 2 * u]
    else:
        u, v, a = sp.symbols("u v a")
        eqs = [u - u0 - h / 3 * v0 - 2 * h / 3 * v + h ** 2 / 6 * a,
               v - v0 + w ** 2 * (h / 3 * u0 + 2 * h / 3 * u) - h ** 2 / 6 * w ** 2 * v,
               a + w ** 2 * u]
    sol = sp.solve(eqs, [u, v, a] + ([uh, vh, ah] if scheme == "bathe" else []), dict=True)[0]
    r1 = [sol[u], h * sol[v], h ** 2 * sol[a]]
    return np.array([[float(sp.diff(ri, x)) for x in (u0, hv0, h2a0)] for ri in r1])


@pytest.mark.parametrize("tau", TAUS)
def test_hfdi_amplification_matrix_is_eq28(tau):
    # to rounding: u_{n+1} = u_n + its increment carries ε|u_n| where the two
    # cancel (large ωh), and the stiffness multiplies that by (ωh)² = τ² in h²a
    expected = hfdi_eq28(tau)
    bound = 4.0 * np.finfo(float).eps * max(tau * tau, 1.0) * np.abs(expected).max()
    np.testing.assert_allclose(amplification_matrix("hfdi", tau), expected,
                               rtol=1e-12, atol=max(bound, 1e-12))


@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
@pytest.mark.parametrize("tau", [0.1, 1.0, 3.0, 30.0])
def test_amplification_matrix_matches_symbolic_derivation(scheme, tau):
    np.testing.assert_allclose(amplification_matrix(scheme, tau),
                               kinematic_amplification(scheme, tau), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("tau, rho, pe, ad", [(0.5, 0.999156, 0.0229, 1.055),
                                              (1.0, 0.987730, 0.352, 7.49)])
def test_hfdi_sample_values(tau, rho, pe, ad):
    props = spectral_properties("hfdi", [tau / (2 * np.pi)])
    assert abs(props.spectral_radius[0] - rho) < 5e-7
    assert abs(props.period_elongation[0] - pe) < 5e-4 * max(1, pe)
    assert abs(props.amplitude_decay[0] - ad) < 5e-3


def test_hfdi_radius_at_tau_10():
    assert abs(spectral_properties("hfdi", [10 / (2 * np.pi)]).spectral_radius[0] - 0.2044) < 5e-5


def test_hfdi_stability_function_is_the_pade_approximant():
    """On u'' = −ω²u the eigenvalues of A are R(±iτ) with R(z) = (1 + z/3)/(1 − 2z/3 + z²/6)."""
    for tau in [0.3, 2.0, 20.0]:
        lam = np.linalg.eigvals(amplification_matrix("hfdi", tau))
        z = 1j * tau
        R = (1 + z / 3) / (1 - 2 * z / 3 + z * z / 6)
        assert np.min(np.abs(lam - R)) < 1e-12
        assert np.min(np.abs(lam - np.conj(R))) < 1e-12


def test_newmark_is_energy_neutral_with_known_phase():
    ratios = np.logspace(-3, 3, 40)
    props = spectral_properties("newmark", ratios)
    np.testing.assert_allclose(props.spectral_radius, 1.0, atol=1e-12)
    tau = props.tau
    np.testing.assert_allclose(props.period_elongation,
                               100 * (tau / (2 * np.arctan(tau / 2)) - 1), rtol=1e-9, atol=1e-8)


@pytest.mark.parametrize("scheme", ["bathe", "hfdi"])
def test_l_stable_schemes_annihilate_high_frequencies(scheme):
    props = spectral_properties(scheme, np.logspace(-3, 4, 60))
    assert np.all(props.spectral_radius <= 1 + 1e-12)
    assert np.all(np.diff(props.spectral_radius) <= 1e-12)   # monotone decay
    assert props.spectral_radius[-1] < 1e-3


def test_period_elongation_ranking_at_small_steps():
    """At Δt/T = 0.05 HFDI (3rd order) elongates the period far less than the others."""
    pe = {s: spectral_properties(s, [0.05]).period_elongation[0] for s in ("newmark", "bathe", "hfdi")}
    assert pe["hfdi"] < 0.1 * pe["bathe"] < 0.1 * pe["newmark"]


def test_bad_input():
    with pytest.raises(ValueError, match="tau"):
        amplification_matrix("hfdi", -1.0)
    with pytest.raises(ValueError, match="ratios"):
        spectral_properties("hfdi", [0.0])
    with pytest.raises(ValueError, match="scheme"):
        amplification_matrix("euler", 1.0)
