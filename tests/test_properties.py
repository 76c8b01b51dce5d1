"""Property-based tests (hypothesis) of the schemes' energy behaviour and of
the stop-and-go driver.

What the properties say, and what was measured while writing them:

* Linear, undamped (``M u'' + K u = 0``): Newmark (average acceleration)
  conserves ``W = V + T`` to roundoff; HFDI and Bathe never increase it.
  Both follow from the amplification matrix ``A`` (:mod:`hfdi.spectral`):
  every scheme ends a step in equilibrium (``a = −ω² u``), so on the states an
  integration visits ``A`` acts on ``(u, h v)`` alone; in the energy
  coordinates ``(ω u, v)`` that 2×2 map ``E`` is normal (it commutes with
  its transpose, as a rational function of the skew generator of the exact
  rotation does), so its 2-norm, the square root of the largest one-step
  ratio ``W_{n+1}/W_n``, equals its spectral radius: ≤ 1 for the three
  schemes, = 1 for Newmark. Measured over τ = ωh in [1e-3, 1e3]: ‖E‖₂ ≤ 1 +
  2.6e-14 (HFDI), 1 + 7.8e-13 (Bathe), 1 + 2.1e-13 (Newmark), all roundoff.
  So Bathe never increases ``W`` from one step to the next on a linear
  undamped problem, at any τ. The bound needs ``a_n`` in equilibrium:
  Bathe's and Newmark's third column is not zero (an acceleration out of
  equilibrium feeds energy in), HFDI's is.
* Nonlinear springs (``V = ½ k d² + ¼ k₃ d⁴``): no scheme is
  energy-decreasing. With ``τ = h ω̂`` (``ω̂`` a bound of the highest
  linearised frequency at the run's energy), one step can raise ``W``; over
  2000 random chains at τ in [0.01, 1], by at most 0.0022 τ⁴ W₀ (HFDI),
  0.010 τ³ W₀ (Bathe), 0.020 τ³ W₀ (Newmark). Over a run of 40 steps ``W``
  never exceeded ``W₀`` by more than 0.0048 τ³ W₀ (HFDI) and 0.023 τ² W₀
  (Bathe), and Newmark stayed within 0.046 τ² W₀ of ``W₀``. The bounds
  asserted below are about four times these. At τ = 2 a step can raise ``W`` by
  several per cent (:func:`test_one_step_can_raise_the_energy_of_a_nonlinear_chain`).
* ``Integrator.advance`` called at arbitrary times, with the integrator
  replaced by a copy restored through ``get_state``/``set_state`` on the
  way, gives bit for bit the run without restores.
"""
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import hfdi
from hfdi.spectral import amplification_matrix

SCHEMES = ("newmark", "bathe", "hfdi")

# Bounded runs: the whole file takes well under a minute.
PROPERTY = settings(max_examples=50, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])

#: ``τ = ω h`` log-uniform over six decades.
taus = st.floats(min_value=-3.0, max_value=3.0).map(lambda x: 10.0 ** x)


def log_uniform(low, high):
    """Strategy of floats spread evenly in ``log10`` between ``low`` and ``high``.

    Parameters
    ----------
    low, high : float
        Positive bounds.

    Returns
    -------
    hypothesis.strategies.SearchStrategy
    """
    return st.floats(min_value=math.log10(low), max_value=math.log10(high)).map(
        lambda x: 10.0 ** x)


# -- the amplification matrix in the energy norm ---------------------------------

def energy_map(scheme, tau):
    """The one-step map of ``scheme`` on ``u'' + u = 0`` in energy coordinates.

    The integrator ends every step in equilibrium, ``a = −ω² u`` (checked in
    :func:`test_every_step_ends_in_equilibrium`), so the acceleration in the
    state ``r = (u, h v, h² a)`` of :func:`hfdi.spectral.amplification_matrix`
    is ``−τ² u``: on the states an integration visits, ``A`` acts as the 2×2
    matrix ``B`` on ``(u, h v)``, ``B[:, 0] = A[:2, 0] − τ² A[:2, 2]``,
    ``B[:, 1] = A[:2, 1]``. With ``ω = 1`` the energy ``W = ½ (ω² u² + v²)``
    is half the squared 2-norm of ``(ω u, v) = (τ u, h v) / h``, so ``B`` in
    the coordinates ``(τ u, h v)`` has, as its 2-norm, the square root of
    the largest one-step ratio ``W_{n+1} / W_n``.

    Parameters
    ----------
    scheme : str
    tau : float
        ``ω h``.

    Returns
    -------
    E : ndarray (2, 2)
        ``D B D⁻¹`` with ``D = diag(τ, 1)``.
    A : ndarray (3, 3)
        The amplification matrix.
    """
    A = amplification_matrix(scheme, tau)
    B = np.column_stack([A[:2, 0] - tau ** 2 * A[:2, 2], A[:2, 1]])
    D = np.diag([tau, 1.0])
    return D @ B @ np.linalg.inv(D), A


#: Roundoff of ``‖E‖₂`` as computed: ``amplification_matrix`` drives the
#: unit state ``h² a = 1`` (``a = 1/τ²``) through the scheme, so the error
#: grows as τ falls. Measured over 10 000 τ in [1e-3, 1e3]: ≤ 2.6e-14 above 1
#: for HFDI (third column zero), 2.1e-13 for Newmark and 7.8e-13 for Bathe,
#: both at τ ≈ 1e-3.
NORM_ROUNDOFF = {"hfdi": 1e-12, "bathe": 5e-12, "newmark": 5e-12}


@PROPERTY
@given(tau=taus)
def test_every_step_ends_in_equilibrium(tau):
    # The restriction to a = −τ² u in energy_map is only valid if every
    # column of A lands there: each scheme solves the equation of motion at
    # the end of the step.
    for scheme in SCHEMES:
        A = amplification_matrix(scheme, tau)
        scale = np.abs(A[2]).max() + tau ** 2 * np.abs(A[0]).max() + 1e-300
        assert np.abs(A[2] + tau ** 2 * A[0]).max() <= 1e-8 * scale, scheme


@PROPERTY
@given(tau=taus)
def test_hfdi_energy_norm_is_its_spectral_radius(tau):
    E, A = energy_map("hfdi", tau)
    # HFDI's next state does not depend on a_n: the third column is zero.
    assert np.all(A[:, 2] == 0.0)
    norm = np.linalg.norm(E, 2)
    radius = np.abs(np.linalg.eigvals(E)).max()
    tol = NORM_ROUNDOFF["hfdi"]
    assert norm <= 1.0 + tol
    assert abs(norm - radius) <= tol
    # normal: the norm is the spectral radius because E commutes with Eᵀ
    assert np.abs(E @ E.T - E.T @ E).max() <= tol
    # the spectral radius is |R(iτ)|, R the (1,2) Padé approximant of exp
    z = 1j * tau
    assert radius == pytest.approx(abs((1 + z / 3) / (1 - 2 * z / 3 + z * z / 6)), rel=1e-9)


@PROPERTY
@given(tau=taus)
def test_bathe_never_increases_the_energy_of_an_equilibrium_state(tau):
    E, A = energy_map("bathe", tau)
    norm = np.linalg.norm(E, 2)
    radius = np.abs(np.linalg.eigvals(E)).max()
    tol = NORM_ROUNDOFF["bathe"]
    assert norm <= 1.0 + tol
    assert abs(norm - radius) <= tol
    assert np.abs(E @ E.T - E.T @ E).max() <= tol


@PROPERTY
@given(tau=taus)
def test_newmark_energy_map_is_orthogonal(tau):
    E, _ = energy_map("newmark", tau)
    assert np.abs(E.T @ E - np.eye(2)).max() <= NORM_ROUNDOFF["newmark"]


@pytest.mark.parametrize("tau", [0.1, 1.0, 10.0])
def test_an_acceleration_out_of_equilibrium_feeds_bathe_and_newmark(tau):
    """Bathe's and Newmark's next state depends on ``a_n`` (the third column
    of ``A``), so the energy bound above holds for equilibrium states only:
    from rest at the origin (``W = 0``) with ``a_n ≠ 0`` they start to move.
    The integrator keeps ``a_n`` in equilibrium (with a load that jumps, once
    told through ``Integrator.load_changed``); HFDI ignores ``a_n``."""
    for scheme in ("bathe", "newmark"):
        A = amplification_matrix(scheme, tau)
        assert np.hypot(tau * A[0, 2], A[1, 2]) > 0.01, scheme   # W_{n+1} > 0 = W_n
    assert np.all(amplification_matrix("hfdi", tau)[:, 2] == 0.0)


# -- linear undamped systems, integrated -----------------------------------------

@st.composite
def linear_systems(draw, max_dof=4):
    """A random undamped linear system with its initial state and a fixed step.

    Positive diagonal masses in [0.1, 10], a stiffness ``Q diag(λ) Qᵀ`` with
    ``λ`` in [0.1, 100] and ``Q`` orthogonal, and a step ``h = τ / ω_max``
    with ``τ`` log-uniform in [1e-3, 1e3].

    Returns
    -------
    system : hfdi.LinearSystem
    u0, v0 : ndarray
    h : float
    omega : ndarray
        The natural frequencies.
    """
    n = draw(st.integers(1, max_dof))
    unit = st.floats(-1.0, 1.0)
    m = np.array(draw(st.lists(log_uniform(0.1, 10.0), min_size=n, max_size=n)))
    lam = np.array(draw(st.lists(log_uniform(0.1, 100.0), min_size=n, max_size=n)))
    G = np.array(draw(st.lists(unit, min_size=n * n, max_size=n * n))).reshape(n, n)
    Q, _ = np.linalg.qr(G)            # orthogonal even when G is singular
    K = Q @ np.diag(lam) @ Q.T
    K = 0.5 * (K + K.T)
    omega = np.sqrt(np.linalg.eigvalsh(K / np.sqrt(np.outer(m, m))))
    u0 = np.array(draw(st.lists(unit, min_size=n, max_size=n)))
    v0 = omega.max() * np.array(draw(st.lists(unit, min_size=n, max_size=n)))
    # a state of unit size: W relative to roundoff, never subnormal
    size = math.hypot(np.linalg.norm(u0), np.linalg.norm(v0) / omega.max())
    assume(size > 1e-3)
    u0, v0 = u0 / size, v0 / size
    tau = draw(taus)
    return hfdi.LinearSystem(m, K), u0, v0, tau / omega.max(), omega


def energy_steps(system, scheme, u0, v0, h, steps):
    """``W`` after every step of a fixed-step run.

    Parameters
    ----------
    system : hfdi.SecondOrderSystem
    scheme : str
    u0, v0 : ndarray
    h : float
    steps : int

    Returns
    -------
    ndarray (steps + 1,)
        ``Result.total_energy``.
    """
    result = hfdi.integrate(system, scheme, steps * h, step=h, u0=u0, v0=v0)
    assert result.success, result.message
    assert len(result.t) == steps + 1
    return result.total_energy


# Roundoff of one step's W, relative: measured ≤ 2.4e-12 (Newmark),
# 7.3e-12 (Bathe), 8.7e-13 (HFDI) over 2700 random systems, largest at
# τ ≈ 1e-3 where v comes from a difference of nearly equal displacements.
W_ROUNDOFF = 1e-10


@PROPERTY
@given(case=linear_systems())
def test_newmark_conserves_linear_energy(case):
    system, u0, v0, h, _ = case
    W = energy_steps(system, "newmark", u0, v0, h, 20)
    assert np.all(np.abs(np.diff(W)) <= W_ROUNDOFF * W[:-1])


@PROPERTY
@given(case=linear_systems(), scheme=st.sampled_from(["hfdi", "bathe"]))
def test_hfdi_and_bathe_never_increase_linear_energy(case, scheme):
    system, u0, v0, h, omega = case
    W = energy_steps(system, scheme, u0, v0, h, 20)
    assert np.all(np.diff(W) <= W_ROUNDOFF * W[:-1])
    if omega.min() * h >= 1.0:
        # and they do dissipate when no mode is resolved
        assert W[-1] < 0.9 * W[0]


# -- nonlinear spring chains ------------------------------------------------------

def spring_chain(m, k, k3):
    """A wall–mass–…–mass chain of springs ``V = Σ ½ k d² + ¼ k₃ d⁴``.

    ``d = B u`` are the spring stretches (``d_0 = u_0``, ``d_i = u_i −
    u_{i−1}``); ``f = Bᵀ (k d + k₃ d³)``, ``K = Bᵀ diag(k + 3 k₃ d²) B`` and
    ``T(u)[w] = Bᵀ diag(6 k₃ d ∘ B w) B``, all exact.

    Parameters
    ----------
    m, k, k3 : ndarray (n,)
        Masses, linear and cubic spring constants (positive).

    Returns
    -------
    hfdi.System
    """
    n = len(m)
    B = np.eye(n) - np.eye(n, k=-1)

    def force(u):
        d = B @ u
        return B.T @ (k * d + k3 * d ** 3)

    def stiffness(u):
        d = B @ u
        return B.T @ np.diag(k + 3.0 * k3 * d ** 2) @ B

    def stiffness_derivative(u, w):
        d = B @ u
        return B.T @ np.diag(6.0 * k3 * d * (B @ w)) @ B

    def potential(u):
        d = B @ u
        return float(np.sum(0.5 * k * d ** 2 + 0.25 * k3 * d ** 4))

    return hfdi.System(np.asarray(m, float), force, stiffness, stiffness_derivative,
                       potential_energy=potential, name="spring chain")


def frequency_bound(m, k, k3, energy):
    """A bound of the highest linearised frequency at any state of energy ≤ ``energy``.

    Each spring's stretch obeys ``½ k d² ≤ W`` and ``¼ k₃ d⁴ ≤ W``, so its
    tangent stiffness is at most ``k + 3 k₃ d̂²``; Gershgorin on ``M⁻¹ K``
    of the chain (a mass touches two springs, each entering a row twice)
    gives ``ω̂² = 4 max(k + 3 k₃ d̂²) / min(m)``.

    Parameters
    ----------
    m, k, k3 : ndarray (n,)
    energy : float

    Returns
    -------
    float
    """
    d2 = np.minimum(2.0 * energy / k, 2.0 * np.sqrt(energy / k3))
    return math.sqrt(4.0 * np.max(k + 3.0 * k3 * d2) / np.min(m))


@st.composite
def spring_chains(draw, tau_range=(1e-2, 1.0)):
    """A random chain of 2–4 masses with hardening springs and its initial state.

    Masses and ``k`` in [0.3, 3], ``k₃`` in [0.1, 10], displacements and
    velocities of size up to 3 (the cubic term from negligible to dominant),
    and a step ``h = τ / ω̂`` (:func:`frequency_bound`).

    Returns
    -------
    system : hfdi.System
    u0, v0 : ndarray
    h, tau, omega : float
    """
    n = draw(st.integers(2, 4))

    def vector(strategy):
        return np.array(draw(st.lists(strategy, min_size=n, max_size=n)))

    m, k, k3 = vector(log_uniform(0.3, 3.0)), vector(log_uniform(0.3, 3.0)), \
        vector(log_uniform(0.1, 10.0))
    amplitude = draw(log_uniform(0.1, 3.0))
    u0 = amplitude * vector(st.floats(-1.0, 1.0))
    v0 = amplitude * vector(st.floats(-1.0, 1.0))
    system = spring_chain(m, k, k3)
    energy = system.potential_energy(u0) + 0.5 * float(v0 @ (m * v0))
    assume(energy > 1e-6)
    omega = frequency_bound(m, k, k3, energy)
    tau = draw(log_uniform(*tau_range))
    return system, u0, v0, tau / omega, tau, omega


@PROPERTY
@given(case=spring_chains())
@pytest.mark.slow
def test_nonlinear_energy_growth_is_bounded(case):
    system, u0, v0, h, tau, _ = case
    W = {s: energy_steps(system, s, u0, v0, h, 40) for s in SCHEMES}
    W0 = W["hfdi"][0]
    # HFDI: W rises over a run by O(τ³) at most (measured ≤ 0.0048 τ³ W0)
    assert np.max(W["hfdi"] - W0) <= 0.02 * tau ** 3 * W0
    # Bathe: by O(τ²) (measured ≤ 0.023 τ² W0), as Newmark's energy error
    assert np.max(W["bathe"] - W0) <= 0.1 * tau ** 2 * W0
    # Newmark: W stays within O(τ²) of W0 either way (measured ≤ 0.046 τ² W0)
    assert np.max(np.abs(W["newmark"] - W0)) <= 0.2 * tau ** 2 * W0


def test_one_step_can_raise_the_energy_of_a_nonlinear_chain():
    """Neither HFDI nor Bathe is energy-decreasing on nonlinear springs: a
    step of a large-amplitude chain of hardening springs at τ = 2 raises
    ``W`` by 3.8 % of W₀ (HFDI) and 7.8 % (Bathe); over the run W exceeds W₀
    by 1.4 % and 8.8 %."""
    m, k, k3 = np.array([1.0, 1.0]), np.array([1.0, 1.0]), np.array([10.0, 10.0])
    system = spring_chain(m, k, k3)
    u0, v0 = np.array([2.0, -1.0]), np.array([0.0, 0.0])
    energy = system.potential_energy(u0)
    h = 2.0 / frequency_bound(m, k, k3, energy)
    for scheme in ("hfdi", "bathe"):
        W = energy_steps(system, scheme, u0, v0, h, 40)
        assert np.max(np.diff(W)) > 0.03 * W[0], scheme
        assert np.max(W) > 1.01 * W[0], scheme


# -- advance at arbitrary times, with and without restores --------------------------

@st.composite
def stop_times(draw, t_end):
    """1–12 distinct increasing times in ``(0, t_end)`` and, for each, whether
    to continue on a copy restored from ``get_state``."""
    fractions = draw(st.lists(st.floats(1e-6, 1.0 - 1e-6), min_size=1, max_size=12,
                              unique=True))
    times = np.unique(np.asarray(fractions) * t_end)
    restore = draw(st.lists(st.booleans(), min_size=len(times), max_size=len(times)))
    return times, restore


@PROPERTY
@given(case=spring_chains(tau_range=(0.1, 1.0)), scheme=st.sampled_from(SCHEMES),
       target=st.floats(2.0, 5.0), periods=st.floats(0.5, 3.0), data=st.data())
@pytest.mark.slow
def test_advance_in_pieces_is_bit_identical_with_and_without_restores(case, scheme, target,
                                                                     periods, data):
    system, u0, v0, _, _, omega = case
    t_end = periods * 2.0 * math.pi / omega
    times, restore = data.draw(stop_times(t_end))

    # the same run, stopping at each time (the integrator does not know them
    # in advance), once straight through and once sometimes continued by a
    # fresh integrator from a saved state
    def fresh():
        return hfdi.Integrator(system, scheme, target_iterations=target, u0=u0, v0=v0,
                               t_bound=t_end)

    def run(restores):
        itg = fresh()
        rows = [(itg.t, itg.state.u, itg.state.v, itg.state.a)]

        def record(i):
            rows.append((i.t, i.state.u, i.state.v, i.state.a))

        ok = True
        for t, restart in zip([*times, t_end], [*restores, False]):
            ok = itg.advance(t, callback=record)
            if not ok:
                break
            assert itg.t == t
            assert itg.advance(t)                      # a second call is a no-op
            if restart:
                saved = itg.get_state()
                itg = fresh()
                itg.set_state(saved)
        return ok, [np.array(x) for x in zip(*rows)]

    ok, (t, u, v, a) = run(restore)
    ok_straight, (t2, u2, v2, a2) = run([False] * len(restore))
    assert ok == ok_straight
    # bit for bit: the same steps, the same arithmetic
    assert np.array_equal(t, t2)
    assert np.array_equal(u, u2) and np.array_equal(v, v2) and np.array_equal(a, a2)
    if ok:
        assert set(times) <= set(t)                   # advance lands on every stop
        # integrate with t_eval at those times: the steps of one uninterrupted
        # run, and the outputs from its dense output
        whole = hfdi.integrate(system, scheme, t_end, target_iterations=target, u0=u0, v0=v0,
                               t_eval=times)
        plain = hfdi.integrate(system, scheme, t_end, target_iterations=target, u0=u0, v0=v0)
        assert np.array_equal(whole.t, plain.t) and np.array_equal(whole.u, plain.u)
        if whole.success:
            np.testing.assert_allclose(whole.u_eval, plain.sol(times)[0], rtol=0,
                                       atol=1e-12 * (1.0 + np.abs(plain.u).max()))
