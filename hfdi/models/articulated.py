"""The articulated system of the paper's Section 5.3: two stiff links and a hinge spring.

Data from the paper (Eqs. 47–49): three unit masses in the plane,
``u = (u1, v1, u2, v2, u3, v3)``, joined by two axial links and a rotational
spring at the middle mass,

``V = k_e/2 [(r12 − h)² + (r23 − h)²] + k_f/2 (α12 − α23)²``        (Eqs. 47–48)

with ``h = 0.5``, ``k_e = 10⁷``, ``k_f = 10³``, ``r_ij`` the length and
``α_ij`` the angle (Eq. 49) of the link from mass ``i`` to mass ``j``; a force
on mass 1 in y; observation time ``T_o = 0.5`` (3 for the long energy run of
Fig. 18); quantities of interest ``u`` and ``Δα = α12 − α23``; the paper's
targets are ``N̄ = 3.0, 3.5, 4.0, 4.5, 5.0`` for every scheme.

Chosen for this project (the paper's figures with them are lost): the masses
start at rest at (0, 0), (0.5, 0), (1, 0) (a straight, force-free chain), and
the load is ``P(t) = hat(t; 200, 0.025)``, a triangular pulse over
``0 ≤ t ≤ 0.05`` of impulse 5. A single link between two unit masses has
``ω = (2 k_e)^{1/2} ≈ 4500`` rad/s; the straight chain's axial modes are
``k_e^{1/2} ≈ 3200`` and ``(3 k_e)^{1/2} ≈ 5500`` rad/s, its bending mode
``(6 k_f)^{1/2}/h ≈ 155`` rad/s.
"""
from __future__ import annotations

import math

import numpy as np

from .. import checks
from ..system import SecondOrderSystem
from .loads import hat, hat_breakpoints
from .pair import PairPotential

__all__ = ["Articulated", "articulated", "relative_angle"]

# d_k = B_k u: link k's vector (link 0 from mass 1 to mass 2, link 1 from 2 to 3)
_B = np.zeros((2, 2, 6))
_B[0, :, 0:2], _B[0, :, 2:4] = -np.eye(2), np.eye(2)
_B[1, :, 2:4], _B[1, :, 4:6] = -np.eye(2), np.eye(2)
# Δα = α(d_0) − α(d_1) up to a locally constant multiple of 2π
_SIGN = np.array([1.0, -1.0])
# e_x ↦ 1, e_y ↦ i: derivatives of Im F(x + iy) for a holomorphic F
_E = np.array([1.0, 1.0j])
_EE = _E[:, None] * _E[None, :]


def relative_angle(u):
    """``Δα = α12 − α23`` wrapped to ``(−π, π]``, vectorised over leading axes.

    Computed as ``−atan2(d12 × d23, d12 · d23)``, the angle that turns link
    2→3 into link 1→2. It is smooth wherever the chain is not folded back on
    itself (``d23`` antiparallel to ``d12``), in particular when a link's own
    angle passes ±π, where the difference of two ``atan2`` link angles would
    jump by 2π.

    Parameters
    ----------
    u : array_like (..., 6)

    Returns
    -------
    ndarray (...)
    """
    x = np.asarray(u, dtype=float).reshape(np.shape(u)[:-1] + (3, 2))
    d1, d2 = x[..., 1, :] - x[..., 0, :], x[..., 2, :] - x[..., 1, :]
    cross = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
    dot = d1[..., 0] * d2[..., 0] + d1[..., 1] * d2[..., 1]
    return -np.arctan2(cross, dot)


class Articulated(SecondOrderSystem):
    """Three particles in the plane: two axial links and a hinge spring (Eqs. 47–49).

    ``u = (u1, v1, u2, v2, u3, v3)`` holds the positions, ``M = diag(masses)``
    per coordinate, ``C = 0``, and the load acts on mass 1 in y:
    ``p_1(t) = hat(t; load_amplitude, load_time)``.

    Parameters
    ----------
    k_e : float
        Axial stiffness of the links, > 0 (paper: 10⁷).
    k_f : float
        Hinge (bending) stiffness, >= 0 (paper: 10³).
    h : float
        Rest length of the links, > 0 (paper: 0.5).
    load_amplitude : float
        Peak ``P`` of the load on mass 1 in y, finite (chosen: 200).
    load_time : float
        Rise time ``t1`` of the load, > 0; the load vanishes after ``2 t1``
        (chosen: 0.025).
    masses : array_like (3,)
        Masses, > 0 (paper: 1).
    positions : array_like (3, 2), optional
        Initial positions. Default: the straight chain (0, 0), (h, 0), (2h, 0)
        (chosen; with the paper's h: (0, 0), (0.5, 0), (1, 0)). Neighbouring
        masses must not coincide.
    v0 : array_like (6,), optional
        Initial velocities (chosen: at rest).

    Notes
    -----
    The axial links are pair potentials ``φ(r) = k_e/2 (r − h)²`` handled by
    :class:`~hfdi.models.pair.PairPotential`.

    Hinge term ``W = k_f/2 Δα²``. ``Δα`` is computed by :func:`relative_angle`,
    so it stays continuous when a link angle passes ±π; it differs from
    ``α(d12) − α(d23)`` by a multiple of 2π that is constant wherever both
    are continuous, so its derivatives are
    those of the per-link angles ``α(d) = atan2(d_y, d_x)``. Writing a link as
    ``z = d_x + i d_y``, ``α = Im log z``; because ``log`` is holomorphic,
    ``∂/∂d_y = i ∂/∂d_x`` on it, so an ``n``-th partial derivative of ``α``
    with ``m`` of its differentiations by ``d_y`` is ``Im(i^m L_n)``, where
    ``L_1 = 1/z``, ``L_2 = −1/z²``, ``L_3 = 2/z³`` are the derivatives of ``log``:

    - gradient ``∂α/∂d_a = Im(e_a / z)``, i.e. ``(−d_y, d_x)/r²``;
    - Hessian ``∂²α/∂d_a∂d_b = Im(−e_a e_b / z²)``, i.e.
      ``[[2 d_x d_y, d_y² − d_x²], [d_y² − d_x², −2 d_x d_y]]/r⁴``;
    - third derivative contracted with ``ω``:
      ``Σ_c ∂³α/∂d_a∂d_b∂d_c ω_c = Im(2 e_a e_b ω̃ / z³)`` with
      ``ω̃ = ω_x + i ω_y``;

    here ``e_x = 1`` and ``e_y = i``. With ``d_k = B_k u`` (link 0: mass 1→2,
    link 1: mass 2→3, ``B_k`` the differencing maps) and ``s = (+1, −1)``:

    - ``g = ∂Δα/∂u = Σ_k s_k B_kᵀ ∇α(d_k)``,
    - ``G = ∂²Δα/∂u² = Σ_k s_k B_kᵀ ∇²α(d_k) B_k``,
    - ``D[w] = Σ_k s_k B_kᵀ ∇³α(d_k)[B_k w] B_k``,

    and the hinge's contributions are ``f = k_f Δα g``,
    ``K = k_f (g gᵀ + Δα G)`` and
    ``T[w] = d(K w)/du = k_f [(g·w) G + g (G w)ᵀ + (G w) gᵀ + Δα D[w]]``.
    ``Δα`` is discontinuous only where the chain folds back on itself
    (``Δα = ±π``), a state the hinge spring keeps the motion far from.
    """

    name = "articulated"
    #: Units and labels of the variables of the model's FMU (see :mod:`fmu.metadata`);
    #: ``stop_time`` is the end of its default experiment.
    fmi_metadata = {
        "dofs": [["m", "x of mass {k}"], ["m", "y of mass {k}"]],
        "parameters": {
            "k_e": ["N/m", "axial stiffness of the two links (Eq. 47)"],
            "k_f": ["N.m/rad", "rotational stiffness of the hinge spring (Eq. 48)"],
            "h": ["m", "rest length of each link"],
            "load_amplitude": ["N", "peak of the hat-shaped y force on mass 1"],
            "load_time": ["s", "time of the peak of the hat load (it ends at twice this)"],
        },
        "quantities": {
            "u": ["m", "positions", None],
            "delta_alpha": ["rad", "hinge angle alpha12 - alpha23", None],
        },
        "stop_time": 0.5,
    }
    #: No exact load rate: HFDI uses the paper's difference quotient.
    load_rate = None
    damping = None

    def __init__(self, k_e=1e7, k_f=1e3, h=0.5, load_amplitude=200.0, load_time=0.025,
                 masses=(1.0, 1.0, 1.0), positions=None, v0=None):
        self.k_e = checks.positive("articulated k_e", k_e)
        self.k_f = checks.non_negative("articulated k_f", k_f)
        self.h = checks.positive("articulated h", h)
        self.load_amplitude = checks.real("articulated load_amplitude", load_amplitude)
        self.load_time = checks.positive("articulated load_time", load_time)
        self.masses = masses = checks.finite_array("articulated masses", masses, (3,),
                                                   positive=True)
        x0 = checks.finite_array(
            "articulated positions",
            [[0.0, 0.0], [self.h, 0.0], [2.0 * self.h, 0.0]] if positions is None else positions,
            (3, 2))
        self.n_dof = 6
        self.mass = np.repeat(masses, 2)
        self.initial_displacement = x0.ravel().copy()
        self.initial_velocity = (np.zeros(6) if v0 is None else
                                 checks.finite_array("articulated v0", v0, (6,)))
        self._pair = PairPotential(3, 2, [0, 1], [1, 2])
        lengths = self._pair.geometry(self.initial_displacement)[1]
        if not np.all(lengths > 0):
            k = int(np.flatnonzero(~(lengths > 0))[0])
            raise ValueError(f"articulated positions: neighbouring masses must not coincide "
                             f"(link lengths > 0), got masses {k + 1} and {k + 2} both at "
                             f"{tuple(x0[k].tolist())}")
        self.u_scale = self.h
        self._positions_given = positions is not None
        self._k_e_pairs = np.full(2, self.k_e)
        self._zero_pairs = np.zeros(2)

    def parameters(self):
        params = {"k_e": self.k_e, "k_f": self.k_f, "h": self.h,
                  "load_amplitude": self.load_amplitude, "load_time": self.load_time,
                  "masses": tuple(self.masses.tolist())}
        if self._positions_given:
            x0 = self.initial_displacement.reshape(3, 2).tolist()
            params["positions"] = tuple(map(tuple, x0))
        if np.any(self.initial_velocity):
            params["v0"] = tuple(self.initial_velocity.tolist())
        return params

    # -- geometry --------------------------------------------------------------
    def link_lengths(self, u):
        """Lengths ``(r12, r23)``."""
        return self._pair.geometry(np.asarray(u, dtype=float))[1]

    def delta_alpha(self, u):
        """``Δα = α12 − α23``, see :func:`relative_angle`."""
        return relative_angle(u)

    @staticmethod
    def _links(u):
        """The links as complex numbers ``z_k = d_x + i d_y`` (2,)."""
        x = u.reshape(3, 2)
        d = x[1:] - x[:-1]
        return d[:, 0] + 1j * d[:, 1]

    def _angle_gradient(self, z):
        """``g = ∂Δα/∂u`` (6,)."""
        grad = (_E[None, :] / z[:, None]).imag                       # (2 links, 2)
        return np.einsum("k,kai,ka->i", _SIGN, _B, grad)

    def _angle_hessian(self, z):
        """``G = ∂²Δα/∂u²`` (6, 6)."""
        hess = (-_EE[None] / z[:, None, None] ** 2).imag              # (2, 2, 2)
        return np.einsum("k,kai,kab,kbj->ij", _SIGN, _B, hess, _B)

    def _angle_third(self, z, w):
        """``D[w] = Σ_c ∂³Δα/∂u_a∂u_b∂u_c w_c`` (6, 6)."""
        om = _B @ w                                                   # (2, 2)
        om = om[:, 0] + 1j * om[:, 1]
        third = (2.0 * _EE[None] * (om / z ** 3)[:, None, None]).imag
        return np.einsum("k,kai,kab,kbj->ij", _SIGN, _B, third, _B)

    # -- mechanics ---------------------------------------------------------------
    # The hinge terms in scalar arithmetic on the two links (the einsum forms
    # above, _angle_*, state the same sums); the ±blocks of each link are
    # scattered by the pair potential's constant scatter matrix, with the
    # sign s_k of the link in Δα. The link geometry is computed once per call.
    def _hinge(self, d):
        """``Δα``, ``s_k ∇α(d_k)`` (2, 2) and the complex link vectors ``z_k``."""
        (ax, ay), (bx, by) = d.tolist()
        delta = -math.atan2(ax * by - ay * bx, ax * bx + ay * by)
        za, zb = complex(ax, ay), complex(bx, by)
        ga, gb = 1.0 / za, 1.0 / zb                                   # Im(e_a / z)
        grads = np.array(((ga.imag, ga.real), (-gb.imag, -gb.real)))
        return delta, grads, za, zb

    @staticmethod
    def _link_blocks(ca, cb):
        """``s_k Im(c_k e_a e_b)`` (2, 2, 2) for complex ``c_k`` (s = +1, −1)."""
        return np.array((((ca.imag, ca.real), (ca.real, -ca.imag)),
                         ((-cb.imag, -cb.real), (-cb.real, cb.imag))))

    def internal_force(self, u):
        u = np.asarray(u, dtype=float)
        geometry = self._pair.geometry(u)
        f = self._pair.force(u, self.k_e * (geometry[1] - self.h), geometry)
        delta, grads, _, _ = self._hinge(geometry[0])
        return f + self.k_f * delta * self._pair.scatter_vectors(grads)

    def stiffness(self, u):
        u = np.asarray(u, dtype=float)
        geometry = self._pair.geometry(u)
        K = self._pair.stiffness(u, self.k_e * (geometry[1] - self.h), self._k_e_pairs,
                                 geometry)
        delta, grads, za, zb = self._hinge(geometry[0])
        g = self._pair.scatter_vectors(grads)
        G = self._pair._scatter(self._link_blocks(-1.0 / za ** 2, -1.0 / zb ** 2))
        return K + self.k_f * (np.outer(g, g) + delta * G)

    def stiffness_derivative(self, u, w):
        u = np.asarray(u, dtype=float)
        w = np.asarray(w, dtype=float)
        geometry = self._pair.geometry(u)
        T = self._pair.stiffness_derivative(u, w, self.k_e * (geometry[1] - self.h),
                                            self._k_e_pairs, self._zero_pairs, geometry)
        delta, grads, za, zb = self._hinge(geometry[0])
        g = self._pair.scatter_vectors(grads)
        G = self._pair._scatter(self._link_blocks(-1.0 / za ** 2, -1.0 / zb ** 2))
        (oax, oay), (obx, oby) = self._pair.relative(w).tolist()
        D = self._pair._scatter(self._link_blocks(2.0 * complex(oax, oay) / za ** 3,
                                                  2.0 * complex(obx, oby) / zb ** 3))
        Gw = G @ w
        hinge = (g @ w) * G + np.outer(g, Gw) + np.outer(Gw, g) + delta * D
        return T + self.k_f * hinge

    def compiled_kernels(self):
        """Compiled kernels of f, K, T, V and the load (:func:`hfdi.compiled.models.articulated_kernels`;
        imports numba)."""
        from ..compiled.models import articulated_kernels
        return articulated_kernels(self)

    def potential_energy(self, u):
        u = np.asarray(u, dtype=float)
        r = self.link_lengths(u)
        return float(0.5 * self.k_e * np.sum((r - self.h) ** 2)
                     + 0.5 * self.k_f * relative_angle(u) ** 2)

    def load_breakpoints(self):
        """The kinks of the hat load: ``0``, ``load_time`` and twice it."""
        return hat_breakpoints(self.load_time)

    def load(self, t):
        p = np.zeros(6)
        p[1] = hat(t, self.load_amplitude, self.load_time)
        return p

    def quantities(self, t, u, v):
        """Positions and the hinge angle, vectorised over times.

        Parameters
        ----------
        t : ndarray (n,)
        u, v : ndarray (n, 6)

        Returns
        -------
        dict
            ``"u"``: (n, 6); ``"delta_alpha"``: (n, 1), ``Δα = α12 − α23``.
        """
        u = np.atleast_2d(np.asarray(u, dtype=float))
        return {"u": u, "delta_alpha": relative_angle(u)[:, None]}


def articulated(**params) -> Articulated:
    """The paper's articulated system (Section 5.3); keyword arguments as :class:`Articulated`."""
    return Articulated(**params)
