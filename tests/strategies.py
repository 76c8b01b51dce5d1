"""Hypothesis strategies and the random problems they draw, shared by the
property tests (:mod:`test_energy`, :mod:`test_integrator`)."""
import math

import numpy as np
from hypothesis import HealthCheck, assume, settings
from hypothesis import strategies as st

import hfdi

#: Settings of the property tests: bounded runs, no per-example deadline
#: (a run's first example pays for imports and first calls).
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
