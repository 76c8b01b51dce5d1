"""The articulated system of the paper's Section 5.3: two stiff links and a hinge
spring (Eqs. 47–49); the data, the paper's and the chosen ones, are in
docs/models.md, "Articulated system"."""
from __future__ import annotations

import math

import numpy as np

from .. import checks
from .base import KernelModel, length_scale
from .kernels import kernel
from .loads import hat_load_params
from .pair import pair_derivative_add, pair_force_add, pair_stiffness_add, relative, \
    scatter_block, scatter_vector

__all__ = ["Articulated", "articulated", "relative_angle"]

def relative_angle(u):
    """``Δα = α12 − α23`` wrapped to ``(−π, π]``, vectorised over leading axes.

    Computed as ``−atan2(d12 × d23, d12 · d23)`` (docs/models.md says why),
    smooth wherever the chain is not folded back on itself.

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


class Articulated(KernelModel):
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
    The axial links are pair potentials ``φ(r) = k_e/2 (r − h)²``, their
    terms those of :mod:`hfdi.models.pair`.

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
    FIXED_PARAMETERS = ("masses",)
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
        lengths = self.link_lengths(self.initial_displacement)
        if not np.all(lengths > 0):
            k = int(np.flatnonzero(~(lengths > 0))[0])
            raise ValueError(f"articulated positions: neighbouring masses must not coincide "
                             f"(link lengths > 0), got masses {k + 1} and {k + 2} both at "
                             f"{tuple(x0[k].tolist())}")

    @length_scale
    def u_scale(self) -> float:
        """The link length ``h``: the model's length scale (the default atol's)."""
        return self.h

    def parameters(self):
        return self._given({"k_e": self.k_e, "k_f": self.k_f, "h": self.h,
                            "load_amplitude": self.load_amplitude, "load_time": self.load_time,
                            "masses": tuple(self.masses.tolist())}, (3, 2),
                           [[0.0, 0.0], [self.h, 0.0], [2.0 * self.h, 0.0]])

    def params(self):
        """The kernels' data ``(k_e, k_f, h)``."""
        return np.array((self.k_e, self.k_f, self.h))

    def load_params(self):
        """The load's data (:func:`~hfdi.models.loads.hat_load`): the pulse on mass 1 in y."""
        return hat_load_params(6, [(1, self.load_amplitude, self.load_time)])

    # -- geometry --------------------------------------------------------------
    def link_lengths(self, u):
        """Lengths ``(r12, r23)``."""
        d = np.diff(np.asarray(u, dtype=float).reshape(3, 2), axis=0)
        return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])

    def delta_alpha(self, u):
        """``Δα = α12 − α23``, see :func:`relative_angle`."""
        return relative_angle(u)

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


# -- the kernels: params = (k_e, k_f, h) ---------------------------------------------
# Links 0 (mass 1 → 2) and 1 (mass 2 → 3) in the plane; the hinge's Δα and its
# derivatives through the complex link vectors z = d_x + i d_y (see the class
# notes): ∇α = (Im 1/z, Re 1/z), blocks s_k Im(c e_a e_b).

@kernel
def _hinge(u):
    """``Δα`` and the complex link vectors ``z_0``, ``z_1``."""
    ax, ay = u[2] - u[0], u[3] - u[1]
    bx, by = u[4] - u[2], u[5] - u[3]
    delta = -math.atan2(ax * by - ay * bx, ax * bx + ay * by)
    return delta, complex(ax, ay), complex(bx, by)


@kernel
def _hinge_gradient(za, zb):
    """``g = ∂Δα/∂u`` (6,)."""
    ga = 1.0 / za
    gb = 1.0 / zb
    g = np.zeros(6)
    scatter_vector(g, 0, 1, 2, (ga.imag, ga.real))
    scatter_vector(g, 1, 2, 2, (-gb.imag, -gb.real))
    return g


@kernel
def _link_blocks(ca, cb):
    """``scatter(s_k Im(c_k e_a e_b))`` (6, 6) for complex ``c_0 = ca``, ``c_1 = cb``."""
    out = np.zeros((6, 6))
    H = np.empty((2, 2))
    H[0, 0], H[0, 1], H[1, 0], H[1, 1] = ca.imag, ca.real, ca.real, -ca.imag
    scatter_block(out, 0, 1, 2, H)
    H[0, 0], H[0, 1], H[1, 0], H[1, 1] = -cb.imag, -cb.real, -cb.real, cb.imag
    scatter_block(out, 1, 2, 2, H)
    return out


@kernel
def articulated_force(u, params):
    k_e, k_f, h = params[0], params[1], params[2]
    f = np.zeros(6)
    for link in range(2):
        r, d = relative(u, link, link + 1, 2)
        pair_force_add(f, link, link + 1, 2, d, r, k_e * (r - h))
    delta, za, zb = _hinge(u)
    g = _hinge_gradient(za, zb)
    c = k_f * delta
    for i in range(6):
        f[i] += c * g[i]
    return f


@kernel
def articulated_stiffness(u, params):
    k_e, k_f, h = params[0], params[1], params[2]
    K = np.zeros((6, 6))
    for link in range(2):
        r, d = relative(u, link, link + 1, 2)
        pair_stiffness_add(K, link, link + 1, 2, d, r, k_e * (r - h), k_e)
    delta, za, zb = _hinge(u)
    g = _hinge_gradient(za, zb)
    G = _link_blocks(-1.0 / za ** 2, -1.0 / zb ** 2)
    for i in range(6):
        for j in range(6):
            K[i, j] += k_f * (g[i] * g[j] + delta * G[i, j])
    return K


@kernel
def articulated_stiffness_derivative(u, w, params):
    k_e, k_f, h = params[0], params[1], params[2]
    T = np.zeros((6, 6))
    for link in range(2):
        r, d = relative(u, link, link + 1, 2)
        wd = relative(w, link, link + 1, 2)[1]
        pair_derivative_add(T, link, link + 1, 2, d, r, wd, k_e * (r - h), k_e, 0.0)
    delta, za, zb = _hinge(u)
    g = _hinge_gradient(za, zb)
    G = _link_blocks(-1.0 / za ** 2, -1.0 / zb ** 2)
    oa = complex(w[2] - w[0], w[3] - w[1])
    ob = complex(w[4] - w[2], w[5] - w[3])
    D = _link_blocks(2.0 * oa / za ** 3, 2.0 * ob / zb ** 3)
    Gw = G @ w
    gw = 0.0
    for i in range(6):
        gw += g[i] * w[i]
    for i in range(6):
        for j in range(6):
            T[i, j] += k_f * (gw * G[i, j] + g[i] * Gw[j] + Gw[i] * g[j] + delta * D[i, j])
    return T


@kernel
def articulated_potential_energy(u, params):
    k_e, k_f, h = params[0], params[1], params[2]
    stretch = 0.0
    for link in range(2):
        r = relative(u, link, link + 1, 2)[0]
        stretch += (r - h) * (r - h)
    delta = _hinge(u)[0]
    return 0.5 * k_e * stretch + 0.5 * k_f * (delta * delta)


Articulated.KERNELS = (articulated_force, articulated_stiffness,
                       articulated_stiffness_derivative, articulated_potential_energy)


def articulated(**params) -> Articulated:
    """The paper's articulated system (Section 5.3); keyword arguments as :class:`Articulated`."""
    return Articulated(**params)
