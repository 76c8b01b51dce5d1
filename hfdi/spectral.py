"""Spectral analysis of the schemes on ``u'' + ω² u = 0`` (paper Section 3, Eqs. 24–33).

The amplification matrix ``A`` with ``r_{n+1} = A r_n``, ``r = (u, h v, h² a)``,
is computed by driving each scheme's own one-step code with the unit states,
so the curves describe the implementation rather than a transcription of it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import checks
from .core.codes import OK
from .evaluation import State
from .schemes import get_scheme
from .stepping.attempt import attempt
from .system import LinearSystem

__all__ = ["amplification_matrix", "spectral_properties", "SpectralProperties", "RATIO_RANGE",
           "TAU_RANGE"]

#: The ``Δt/T`` where the measures mean what they say, closed interval.
#: ``A`` is formed in floating point, and its principal pair ``e^{±iφ}`` sits
#: within ``τ`` of the triple point 1: a rounding ``ε`` of its entries moves
#: ``φ`` by about ``ε/τ``, so ``PE`` is off by about ``100 ε/τ²`` percentage
#: points (6e-10 at 1e-3). Over the range Newmark's and Bathe's ``PE`` and
#: ``AD`` are right to 1e-5 of themselves; below it the error grows as
#: ``1/τ⁴`` relative (Newmark's closed form: 1.5 % off at 1e-4, 6e4 times at
#: 1e-7). The third-order HFDI elongates far
#: less, about ``τ³``: against its closed form ``R(iτ)`` its ``PE`` is off by
#: up to 15 % of itself (6e-10 percentage points) in [1e-3, 1.5e-3), 1.3 %
#: in [1.5e-3, 2e-3), 2e-4 in [3e-3, 5e-3) and 1e-5 above 5e-3; its radius
#: and amplitude decay are exact to rounding there. Above 1e6 the ``h²``
#: scaling of the stages breaks down (Newmark's radius 1 + 2e-8 at 1e8, its
#: complex pair lost).
RATIO_RANGE = (1e-3, 1e6)

#: The ``τ = ω h`` that :func:`amplification_matrix` takes.
TAU_RANGE = (1e-100, 1e100)


def amplification_matrix(scheme, tau: float) -> np.ndarray:
    """Amplification matrix of ``scheme`` for ``τ = ω h`` (Eq. 24).

    Parameters
    ----------
    scheme : str or Scheme
    tau : float
        ``ω h`` in :data:`TAU_RANGE`.

    Returns
    -------
    ndarray (3, 3)
        Columns are the images of the unit states ``r = e_j``.
    """
    scheme = get_scheme(scheme)
    # the unit states divide by h² and the columns multiply by it: both stay
    # finite for h in [1e-100, 1e100] (the matrix is accurate there; its
    # eigenvalues' phase is not, see RATIO_RANGE)
    low, high = TAU_RANGE
    if isinstance(tau, (bool, str, bytes)) or np.ndim(tau) != 0 or np.iscomplexobj(tau):
        raise ValueError(f"tau must be a number in [{low:g}, {high:g}], got {tau!r:.80}")
    tau = float(tau)
    if not (np.isfinite(tau) and low <= tau <= high):
        raise ValueError(f"tau = ω h must be a number in [{low:g}, {high:g}], got {tau!r}")
    # the scheme's own step (hfdi.stepping) on u'' + u = 0 (ω = 1), in Python
    from .integrator import Integrator
    itg = Integrator(LinearSystem(mass=[1.0], stiffness=[[1.0]]), scheme, step=1.0,
                     compiled=False, check_stiffness=False, tol=1e-13, max_iterations=4)
    h = tau
    A = np.empty((3, 3))
    for j in range(3):
        r = np.zeros(3)
        r[j] = 1.0
        state = State(0.0, r[:1].copy(), r[1:2] / h, r[2:3] / h ** 2, None, np.zeros(1))
        # a lagged a is the scheme's own, taken as it is in the middle of a run
        # of steps h, not moved as the equation's at a start
        # (hfdi.stepping.attempt.start_acceleration)
        itg._put_current(state, State(-h, state.u, state.v, state.a, None, state.p)
                         if scheme.lagged_acceleration else None)
        itg._run.newton_constant = itg._run.newton_guard = np.inf
        with np.errstate(all="ignore"):
            outcome = attempt(itg._functions(), itg._cfg, itg._data, itg._run, itg._vec, h,
                              False, itg._hfdi)
        if outcome != OK:
            raise ArithmeticError(f"the {scheme.name} step failed at tau = {tau!r}")
        vec = itg._vec
        A[:, j] = [vec.u_new[0], h * vec.v_new[0], h * h * vec.a_new[0]]
    return A


@dataclass
class SpectralProperties:
    """Stability and accuracy measures over a range of ``Δt/T`` (Eqs. 29–33).

    Attributes
    ----------
    ratio : ndarray
        ``Δt/T = τ/(2π)``.
    tau : ndarray
    spectral_radius : ndarray
        ``ρ(A) = max |λ_i|``.
    principal_radius : ndarray
        ``ρ_p = |λ|`` of the complex pair (NaN where A has none).
    phase : ndarray
        ``φ = atan2(λ_Im, λ_Re)`` of the root with positive imaginary part,
        in ``(0, π]``: where the principal root's angle passes ``π`` (HFDI at
        ``Δt/T = √18/2π ≈ 0.675``) it is this wrapped angle, and ``PE`` jumps
        (136 % at ``Δt/T = 1`` against 73 % with the angle followed past ``π``).
    period_elongation : ndarray
        ``PE = 100 (τ − φ)/φ``, percent.
    amplitude_decay : ndarray
        ``AD = 100 (1 − ρ_p^{2π/φ})``, percent.
    """

    ratio: np.ndarray
    tau: np.ndarray
    spectral_radius: np.ndarray
    principal_radius: np.ndarray
    phase: np.ndarray
    period_elongation: np.ndarray
    amplitude_decay: np.ndarray


def spectral_properties(scheme, ratios) -> SpectralProperties:
    """Spectral radius, period elongation and amplitude decay of ``scheme``
    at each ``Δt/T`` in ``ratios``.

    Parameters
    ----------
    scheme : str or Scheme
    ratios : float or array_like (n,)
        ``Δt/T``, each in :data:`RATIO_RANGE` (1e-3 … 1e6).

    Raises
    ------
    ValueError
        For ratios that are not real numbers in :data:`RATIO_RANGE`.
    """
    low, high = RATIO_RANGE
    allowed = f"real numbers in [{low:g}, {high:g}] (hfdi.spectral.RATIO_RANGE)"
    given, ratios = ratios, checks.real_array(ratios)
    if ratios is None:
        raise ValueError(f"ratios (Δt/T) must be {allowed}, got {given!r:.80}")
    ratios = np.atleast_1d(ratios)
    if ratios.ndim != 1:
        raise ValueError(f"ratios (Δt/T) must be a 1-D array, got shape {ratios.shape}")
    bad = ~(np.isfinite(ratios) & (ratios >= low) & (ratios <= high))
    if np.any(bad):
        raise ValueError(f"ratios (Δt/T) must be {allowed} (outside it, rounding in the "
                         f"amplification matrix outweighs the measures), got "
                         f"{float(ratios[bad][0])!r}")
    tau = 2.0 * np.pi * ratios
    n = ratios.size
    radius, rho_p, phi = np.empty(n), np.full(n, np.nan), np.full(n, np.nan)
    for k, t in enumerate(tau):
        lam = np.linalg.eigvals(amplification_matrix(scheme, t))
        radius[k] = np.abs(lam).max()
        pair = lam[np.argmax(lam.imag)]
        if pair.imag > 1e-14 * max(1.0, abs(pair)):
            rho_p[k] = abs(pair)
            phi[k] = np.arctan2(pair.imag, pair.real)
    with np.errstate(invalid="ignore", divide="ignore"):
        pe = 100.0 * (tau - phi) / phi
        ad = 100.0 * (1.0 - rho_p ** (2.0 * np.pi / phi))
    return SpectralProperties(ratios, tau, radius, rho_p, phi, pe, ad)
