"""Problems with solutions known independently of any integrator, for the
accuracy tests: each gives a model and a function ``exact(t) -> (u, v)``.

- :func:`damped_chain`: a linear damped 3-DOF chain, exact by the matrix
  exponential of its first-order form;
- :func:`duffing`: the undamped Duffing oscillator ``u'' + α u + β u³ = 0``,
  exact by Jacobi's elliptic function ``cn``;
- :func:`kepler`: the two-body problem on an ellipse, exact by Kepler's
  equation solved by Newton's method to round-off;
- :func:`stiff_and_slow`: two undamped modes, a slow one of unit amplitude
  and a stiff one barely excited, coupled by a rotation; exact by its modes.

Duffing and Kepler are :class:`~hfdi.models.symbolic.EnergyModel`s (they run
compiled, as a user's energy does); ``python=True`` gives the same physics as
a :class:`hfdi.System` of Python functions, which takes the Python path.
"""
from __future__ import annotations

import numpy as np
import sympy
from scipy.special import ellipj

import hfdi


def damped_chain():
    """Three masses, four springs to the walls and between them, Rayleigh damping."""
    m = np.array([1.0, 2.0, 1.5])
    k = np.array([40.0, 25.0, 30.0, 50.0])
    K = np.array([[k[0] + k[1], -k[1], 0.0],
                  [-k[1], k[1] + k[2], -k[2]],
                  [0.0, -k[2], k[2] + k[3]]])
    C = 0.02 * K + 0.05 * np.diag(m)
    u0 = np.array([0.1, -0.05, 0.02])
    v0 = np.array([0.0, 0.3, -0.1])
    model = hfdi.LinearSystem(m, K, C, initial_displacement=u0, initial_velocity=v0)
    A = np.block([[np.zeros((3, 3)), np.eye(3)],
                  [-K / m[:, None], -C / m[:, None]]])
    y0 = np.concatenate([u0, v0])

    # y(t) = exp(A t) y0 through A's eigenvectors (distinct eigenvalues, V
    # well conditioned): every time at once, to rounding of expm's (checked
    # against scipy.linalg.expm in tests/test_order.py)
    eigenvalues, V = np.linalg.eig(A)
    coefficients = np.linalg.solve(V, y0)

    def exact(t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        y = (np.exp(np.outer(t, eigenvalues)) * coefficients) @ V.T
        return y.real[:, :3], y.real[:, 3:]

    exact.matrix, exact.start = A, y0

    return model, exact


def stiff_and_slow(omega=1e3, stiff_amplitude=1e-7):
    """``u'' + K u = 0`` with ``K = Q diag(1, ω²) Qᵀ``, ``Q`` a rotation: the
    slow mode starts at amplitude 1, the stiff one at ``stiff_amplitude``, both
    at rest. A scheme that does not resolve ``ω`` errs in ``v`` by up to the
    stiff mode's velocity amplitude ``ω·stiff_amplitude`` (HFDI damps the
    mode, Newmark shifts its phase), in ``u`` by its ``stiff_amplitude``."""
    c, s = np.cos(0.6), np.sin(0.6)
    Q = np.array([[c, -s], [s, c]])
    frequencies = np.array([1.0, omega])
    K = Q @ np.diag(frequencies ** 2) @ Q.T
    q0 = np.array([1.0, stiff_amplitude])
    model = hfdi.LinearSystem(np.ones(2), K, initial_displacement=Q @ q0,
                              initial_velocity=np.zeros(2))

    def exact(t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        phase = np.outer(t, frequencies)
        return (q0 * np.cos(phase)) @ Q.T, (-q0 * frequencies * np.sin(phase)) @ Q.T

    return model, exact


def _energy_model(V, coordinates, name, **options):
    from hfdi.models.symbolic import EnergyModel
    return EnergyModel(coordinates, V, mass=np.ones(len(coordinates)), name=name, **options)


def duffing(alpha=1.0, beta=2.0, amplitude=1.2, python=False):
    """``u'' + α u + β u³ = 0``, ``u(0) = A``, ``u'(0) = 0``:
    ``u = A cn(ω t, m)`` with ``ω² = α + β A²``, ``m = β A² / (2 ω²)``."""
    omega = np.sqrt(alpha + beta * amplitude ** 2)
    mpar = beta * amplitude ** 2 / (2.0 * omega ** 2)
    if not python:
        u, a, b = sympy.symbols("u alpha beta")
        model = _energy_model(a * u ** 2 / 2 + b * u ** 4 / 4, [u], "duffing",
                              parameters={a: alpha, b: beta}, initial_displacement=[amplitude])
    else:
        model = hfdi.System(
            np.array([1.0]),
            lambda u: alpha * u + beta * u ** 3,
            lambda u: np.array([[alpha + 3.0 * beta * u[0] ** 2]]),
            lambda u, w: np.array([[6.0 * beta * u[0] * w[0]]]),
            potential_energy=lambda u: 0.5 * alpha * u[0] ** 2 + 0.25 * beta * u[0] ** 4,
            initial_displacement=[amplitude])

    def exact(t):
        sn, cn, dn, _ = ellipj(omega * np.atleast_1d(t), mpar)
        return (amplitude * cn)[:, None], (-amplitude * omega * sn * dn)[:, None]

    return model, exact


def kepler(eccentricity=0.5, python=False):
    """A unit-mass planet around a unit attractor (``f = u/|u|³``), started at
    the pericentre of an ellipse with semi-major axis 1 (period 2π)."""
    e = eccentricity

    def force(u):
        return u / np.dot(u, u) ** 1.5

    def stiffness(u):
        r2 = np.dot(u, u)
        return np.eye(2) / r2 ** 1.5 - 3.0 * np.outer(u, u) / r2 ** 2.5

    def stiffness_derivative(u, w):
        r2 = np.dot(u, u)
        uw = np.dot(u, w)
        return (-3.0 * np.outer(w, u) / r2 ** 2.5
                - 3.0 * (uw * np.eye(2) + np.outer(u, w)) / r2 ** 2.5
                + 15.0 * uw * np.outer(u, u) / r2 ** 3.5)

    start = {"initial_displacement": [1.0 - e, 0.0],
             "initial_velocity": [0.0, np.sqrt((1.0 + e) / (1.0 - e))]}
    if python:
        model = hfdi.System(np.ones(2), force, stiffness, stiffness_derivative,
                            potential_energy=lambda u: -1.0 / np.sqrt(np.dot(u, u)), **start)
    else:
        x, y = sympy.symbols("x y")
        model = _energy_model(-1 / sympy.sqrt(x ** 2 + y ** 2), [x, y], "kepler", **start)

    def exact(t):
        M = np.atleast_1d(np.asarray(t, dtype=float))
        E = M.copy()
        for _ in range(50):                       # Newton on E − e sin E = M
            E -= (E - e * np.sin(E) - M) / (1.0 - e * np.cos(E))
        c, s = np.cos(E), np.sin(E)
        b = np.sqrt(1.0 - e * e)
        u = np.stack([c - e, b * s], axis=1)
        Edot = 1.0 / (1.0 - e * c)
        v = np.stack([-s * Edot, b * c * Edot], axis=1)
        return u, v

    return model, exact
