"""The tetrahedra of the paper's Section 5.2: four masses joined by six Neo-Hooke
springs (Eqs. 45–46); the data, the paper's and the chosen ones, are in
docs/models.md, "Tetrahedra"."""
from __future__ import annotations

import numpy as np

from .. import checks
from .base import KernelModel
from .kernels import kernel
from .loads import hat_load_params
from .pair import pair_derivative_add, pair_force_add, pair_stiffness_add, relative

__all__ = ["Tetrahedra", "tetrahedra"]

#: The paper's initial positions (particle i in row i).
PAPER_POSITIONS = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
#: Pair order of the springs and of the force quantities: 12, 13, 14, 23, 24, 34.
PAIRS_I = (0, 0, 0, 1, 1, 2)
PAIRS_J = (1, 2, 3, 2, 3, 3)


#: The six particle pairs, in the order of the quantity ``f``.
_FMI_PAIRS = ("12", "13", "14", "23", "24", "34")

class Tetrahedra(KernelModel):
    """Four particles in space joined pairwise by Neo-Hooke springs (Eqs. 45–46).

    ``u`` holds the positions: particle ``i`` (0-based) at ``u[3i:3i+3]``.
    ``M = diag(masses)``, ``C = 0``, and the load acts on particle 1 in x:
    ``p_0(t) = hat(t; load_amplitude, load_time)``.

    Parameters
    ----------
    k_stiff : float
        Spring constant of the pair (1, 2), > 0 (paper: 10³).
    k_soft : float
        Spring constant of the other five pairs, > 0 (paper: 1).
    load_amplitude : float
        Peak ``P`` of the load on particle 1 in x, finite (chosen: 5).
    load_time : float
        Rise time ``t1`` of the load, > 0; the load vanishes after ``2 t1``
        (chosen: 1).
    masses : array_like (4,)
        Particle masses, > 0 (paper: 1).
    positions : array_like (4, 3), optional
        Initial positions, which also fix the rest lengths ``r0`` (the
        initial state is force-free). Default: the paper's
        (0,0,0), (1,0,0), (0,1,0), (0,0,1). No two particles may coincide.
    v0 : array_like (12,), optional
        Initial velocities (paper: at rest).

    Notes
    -----
    Pair potential ``φ(r) = k/6 (r² + 2 r0³/r − 3 r0²)`` and its derivatives
    ``φ' = k/3 (r − r0³/r²)``, ``φ'' = k/3 (1 + 2 r0³/r³)``,
    ``φ''' = −2 k r0³/r⁴``; ``φ(r0) = φ'(r0) = 0`` and ``φ''(r0) = k``.
    ``φ → ∞`` as ``r → 0``, so the springs resist collapse.

    Sign of the force quantities: with ``e^{ij} = (x_j − x_i)/r`` the unit
    vector from particle ``i`` to particle ``j``, ``f^{ij} = φ'(r) e^{ij}`` is the
    pair's contribution to the internal force ``f = ∂V/∂u`` at particle ``j``
    (and ``−f^{ij}`` at particle ``i``). A stretched spring (``r > r0``) has
    ``f^{ij}`` along ``e^{ij}``: it pulls ``j`` back towards ``i`` with the force
    ``−f^{ij}``.
    """

    name = "tetrahedra"
    FIXED_PARAMETERS = ("masses",)
    fmi_metadata = {
        "dofs": [["m", "x of particle {k}"], ["m", "y of particle {k}"],
                 ["m", "z of particle {k}"]],
        "parameters": {
            "k_stiff": ["N/m", "stiffness k of the spring between particles 1 and 2 (Eq. 45)"],
            "k_soft": ["N/m", "stiffness k of the five other springs (Eq. 45)"],
            "load_amplitude": ["N", "peak of the hat-shaped x force on particle 1"],
            "load_time": ["s", "time of the peak of the hat load (it ends at twice this)"],
        },
        "quantities": {
            "u": ["m", "positions", None],
            "f": ["N", "interaction forces f^ij of the six springs (Eq. 46)",
                  [f"pair {p} {c}" for p in _FMI_PAIRS for c in "xyz"]],
        },
        "stop_time": 50.0,
    }
    u_scale = 1.0

    def __init__(self, k_stiff=1e3, k_soft=1.0, load_amplitude=5.0, load_time=1.0,
                 masses=(1.0, 1.0, 1.0, 1.0), positions=None, v0=None):
        self.k_stiff = checks.positive("tetrahedra k_stiff", k_stiff)
        self.k_soft = checks.positive("tetrahedra k_soft", k_soft)
        self.load_amplitude = checks.real("tetrahedra load_amplitude", load_amplitude)
        self.load_time = checks.positive("tetrahedra load_time", load_time)
        self.masses = masses = checks.finite_array("tetrahedra masses", masses, (4,),
                                                   positive=True)
        x0 = checks.finite_array("tetrahedra positions",
                                 PAPER_POSITIONS if positions is None else positions, (4, 3))
        self.n_dof = 12
        self.mass = np.repeat(masses, 3)
        self.initial_displacement = x0.ravel().copy()
        self._built_positions = x0         # the rest lengths' geometry
        self.initial_velocity = (np.zeros(12) if v0 is None else
                                 checks.finite_array("tetrahedra v0", v0, (12,)))
        self.rest_length = self.distances(self.initial_displacement)
        if not np.all(self.rest_length > 0):
            k = int(np.flatnonzero(~(self.rest_length > 0))[0])
            raise ValueError(f"tetrahedra positions must be four distinct points (every rest "
                             f"length > 0), got particles {PAIRS_I[k] + 1} and {PAIRS_J[k] + 1} "
                             f"both at {tuple(x0[PAIRS_I[k]].tolist())}")

    @property
    def spring_constant(self):
        """``k`` of the six springs (6,), in the order of the pairs."""
        return np.array([self.k_stiff] + [self.k_soft] * 5)

    def parameters(self):
        return self._given({"k_stiff": self.k_stiff, "k_soft": self.k_soft,
                            "load_amplitude": self.load_amplitude, "load_time": self.load_time,
                            "masses": tuple(self.masses.tolist())}, (4, 3), PAPER_POSITIONS,
                           self._built_positions)

    def params(self):
        """The kernels' data: ``(r0³, k/3, −2k, k, r0)``, six entries each in the
        order of the pairs."""
        k, r0 = self.spring_constant, self.rest_length
        return np.concatenate([r0 ** 3, k / 3.0, -2.0 * k, k, r0])

    def load_params(self):
        """The load's data (:func:`~hfdi.models.loads.hat_load`): the pulse on particle 1 in x."""
        return hat_load_params(12, [(0, self.load_amplitude, self.load_time)])

    def distances(self, u):
        """Pair distances ``r`` (6,) in the order 12, 13, 14, 23, 24, 34."""
        x = np.asarray(u, dtype=float).reshape(4, 3)
        d = x[list(PAIRS_J)] - x[list(PAIRS_I)]
        return np.sqrt(np.einsum("pk,pk->p", d, d))

    def quantities(self, t, u, v):
        """Positions and the six interaction forces (Eq. 46), vectorised over times.

        Parameters
        ----------
        t : ndarray (n,)
        u, v : ndarray (n, 12)

        Returns
        -------
        dict
            ``"u"``: (n, 12) positions; ``"f"``: (n, 18), the force vectors
            ``f^{ij}`` (x, y, z each) of the pairs 12, 13, 14, 23, 24, 34, with
            the sign convention of the class notes.
        """
        u = np.atleast_2d(np.asarray(u, dtype=float))
        x = u.reshape(-1, 4, 3)
        d = x[:, PAIRS_J] - x[:, PAIRS_I]                      # (n, 6, 3)
        r = np.sqrt(np.einsum("npk,npk->np", d, d))
        k, r0 = self.spring_constant, self.rest_length
        f = ((k / 3.0 * (r - r0 ** 3 / r ** 2)) / r)[:, :, None] * d
        return {"u": u, "f": f.reshape(-1, 18)}


# -- the kernels: params = (r0³, k/3, −2k, k, r0), six entries each ------------------
# φ' = k/3 (r − q/r), φ'' = k/3 (1 + 2 q/r²), φ''' = −2k q/r³ with q = r0³/r.

@kernel
def tetrahedra_force(u, params):
    f = np.zeros(12)
    for p in range(6):
        i, j = PAIRS_I[p], PAIRS_J[p]
        r, d = relative(u, i, j, 3)
        q = params[p] / r
        pair_force_add(f, i, j, 3, d, r, params[6 + p] * (r - q / r))
    return f


@kernel
def tetrahedra_stiffness(u, params):
    K = np.zeros((12, 12))
    for p in range(6):
        i, j = PAIRS_I[p], PAIRS_J[p]
        r, d = relative(u, i, j, 3)
        q = params[p] / r
        k3 = params[6 + p]
        pair_stiffness_add(K, i, j, 3, d, r, k3 * (r - q / r), k3 * (1.0 + 2.0 * q / (r * r)))
    return K


@kernel
def tetrahedra_stiffness_derivative(u, w, params):
    T = np.zeros((12, 12))
    for p in range(6):
        i, j = PAIRS_I[p], PAIRS_J[p]
        r, d = relative(u, i, j, 3)
        wd = relative(w, i, j, 3)[1]
        q = params[p] / r
        k3 = params[6 + p]
        pair_derivative_add(T, i, j, 3, d, r, wd, k3 * (r - q / r),
                            k3 * (1.0 + 2.0 * q / (r * r)), params[12 + p] * q / (r * r * r))
    return T


@kernel
def tetrahedra_potential_energy(u, params):
    V = 0.0
    for p in range(6):
        r = relative(u, PAIRS_I[p], PAIRS_J[p], 3)[0]
        k, r0 = params[18 + p], params[24 + p]
        q = params[p] / r
        V += k / 6.0 * (r * r + 2.0 * q - 3.0 * (r0 * r0))
    return V


Tetrahedra.KERNELS = (tetrahedra_force, tetrahedra_stiffness, tetrahedra_stiffness_derivative,
                      tetrahedra_potential_energy)


def tetrahedra(**params) -> Tetrahedra:
    """The paper's tetrahedra (Section 5.2); keyword arguments as :class:`Tetrahedra`."""
    return Tetrahedra(**params)
