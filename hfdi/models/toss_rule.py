"""The toss rule of the paper's Section 5.4: a co-rotational Timoshenko beam.

A plane, free–free beam is discretised into ``N_el`` two-node elements with
linear shape functions for the displacements ``u``, ``v`` and the section
rotation ``α``. The strains are the total Lagrangian co-rotational
(geometrically exact) measures of Eqs. 51–53, evaluated at the element centre
(one-point rule) with ``α_o = (α_i + α_j)/2``, ``u_ξ = (u_j − u_i)/h_e``,
``v_ξ = (v_j − v_i)/h_e`` and ``χ = (α_j − α_i)/h_e``::

    ε = cos α_o − 1 + (C_e cos α_o − S_e sin α_o) u_ξ + (C_e sin α_o + S_e cos α_o) v_ξ
    γ = −sin α_o − (S_e cos α_o + C_e sin α_o) u_ξ + (C_e cos α_o − S_e sin α_o) v_ξ
    χ = α_ξ

where ``S_e``, ``C_e`` are the sine and cosine of the element's initial
orientation (the paper's Eq. 52 prints ``E_e`` for ``S_e``, a typo). The
element energy is Eq. 50 with the one-point rule,
``V_e = ½ h_e (EA ε² + GA γ² + EJ χ²)``, and the mass is the lumped diagonal
of the kinetic energy of Eq. 54.

Data from the paper: the formulation above, ``N_el = 6``, ``T_o = 0.1``, the
quantities ``α_mv``, ``m_c`` (Eq. 55), ``α_t,mv`` and ``N_c``, and the target
iteration counts of Table 5. The paper's geometry, material and loads are
drawn in its Fig. 19 and not stated in its text, so these data were *chosen*
(a steel rule tossed by a blow at one end): length 0.5 m,
section 30 mm × 2 mm, ``E = 210 GPa``, ``ν = 0.3``, ``G = E/(2(1+ν))``, shear
factor 5/6, ``ρ = 7850 kg/m³``; straight along x from (0, 0), at rest, free at
both ends, no gravity; at the left end node a force in +y
``F(t) = hat(t; 200 N, 0.005 s)`` and a moment ``M(t) = hat(t; 10 N·m, 0.005 s)``.

Derivatives
-----------
Write ``y = (u_ξ, v_ξ, α_o, χ)`` for the element's reduced coordinates. They
are linear in the six element DOFs, ``y = D_e B d_e`` with the constant
``B`` and ``D_e = diag(1/h_e, 1/h_e, 1, 1/h_e)``, so every derivative of
``V_e = h_e W(y)`` with respect to ``d_e`` is ``B^T`` (derivative of ``W``)
``B`` with the ``D_e`` scalings. ``ε`` and ``γ`` are linear in ``u_ξ, v_ξ`` and
trigonometric in ``α_o``; with ``β = α_o + α̂`` their derivatives close on
themselves (``∂ε/∂α_o = γ``, ``∂γ/∂α_o = −(1 + ε)``), which gives the exact
gradients, Hessians and third derivatives used for ``f``, ``K`` and ``T``.
"""
from __future__ import annotations

import copy

import numpy as np
import scipy.sparse as sp

from .. import checks
from ..system import SecondOrderSystem
from .loads import hat, hat_breakpoints

__all__ = ["TossRule", "toss_rule", "MAX_ELEMENTS"]

#: The most elements a toss rule may have: 3,000,003 DOFs, about 7 GB in a run
#: (2.4 kB per DOF measured, docs/performance.md). More is refused up front
#: rather than left to exhaust the memory of the machine.
MAX_ELEMENTS = 1_000_000


# The constant part B of the map from the element DOFs
# d_e = (u_i, v_i, α_i, u_j, v_j, α_j) to the reduced coordinates
# y = (u_ξ, v_ξ, α_o, χ), before the 1/h_e scaling of rows 0, 1 and 3.
_B = np.array([[-1.0, 0.0, 0.0, 1.0, 0.0, 0.0],
               [0.0, -1.0, 0.0, 0.0, 1.0, 0.0],
               [0.0, 0.0, 0.5, 0.0, 0.0, 0.5],
               [0.0, 0.0, -1.0, 0.0, 0.0, 1.0]])
# A symmetric reduced matrix H is stored by its independent entries in this
# order; only the (u_ξ, v_ξ, α_o) block couples, χ enters alone through EJ χ².
_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2), (3, 3))
# Bᵀ H B = Σ_pairs H_ij (B_iᵀ B_j + B_jᵀ B_i) (once on the diagonal): row c of
# _BB is the flattened 6×6 contribution of the c-th independent entry.
_BB = np.array([(np.outer(_B[i], _B[j]) + (np.outer(_B[j], _B[i]) if i != j else 0.0)).ravel()
                for i, j in _PAIRS])
# The kernels compute the entries in this order instead: the pairs of
# x = (u_ξ, v_ξ, α_o) with the α_o column last, so that the three entries fed
# by ∇²k (its α_o row r = (r_p, r_q, r_α)) are the contiguous rows 3:6 in the
# order of r, and the gradient products are ∇k[_I] ∇k[_J].
_KERNEL_PAIRS = ((0, 0), (1, 1), (0, 1), (0, 2), (1, 2), (2, 2), (3, 3))
_I = np.array([i for i, _ in _KERNEL_PAIRS[:6]])
_J = np.array([j for _, j in _KERNEL_PAIRS[:6]])
# _KERNEL_ROW[c]: row of the kernel layout holding the c-th entry of _PAIRS.
_KERNEL_ROW = np.array([_KERNEL_PAIRS.index(pair) for pair in _PAIRS])


class TossRule(SecondOrderSystem):
    """A free plane co-rotational Timoshenko beam tossed by an end load (Section 5.4).

    DOFs are ordered node by node, ``u = (u_0, v_0, α_0, u_1, v_1, α_1, …)``,
    displacements and rotations from the straight initial configuration along
    x starting at (0, 0). The internal force, tangent and tangent derivative
    are the exact first, second and third derivatives of the strain energy
    (Eqs. 50–53, one-point rule); ``K`` and ``T`` are scipy CSR matrices with
    the beam's band (five off-diagonals on each side). The mass is the lumped
    diagonal of Eq. 54, a 1-D array.

    Parameters
    ----------
    n_elements : int
        Number of elements ``N_el`` (paper: 6), 1 … :data:`MAX_ELEMENTS`.
    length : float
        Length of the rule in m (chosen: 0.5).
    width, thickness : float
        Rectangular section in m (chosen: 0.030 × 0.002); bending is about
        the axis along the width, ``J = width·thickness³/12``.
    E : float
        Young's modulus in Pa (chosen: 210e9).
    nu : float
        Poisson's ratio, ``−1 < ν < 0.5`` (chosen: 0.3); ``G = E/(2(1+ν))``.
    shear_factor : float
        Shear correction factor, ``GA = shear_factor·G·A`` (chosen: 5/6).
    rho : float
        Density in kg/m³ (chosen: 7850).
    force_amplitude : float
        Peak of the +y force at the left end node in N (chosen: 200).
    moment_amplitude : float
        Peak of the counter-clockwise moment at the left end node in N·m
        (chosen: 10).
    load_time : float
        ``t1`` of both hat pulses in s (chosen: 0.005); the loads act on
        ``[0, 2 t1]``.

    Attributes
    ----------
    EA, GA, EJ : float
        Axial, shear and flexural rigidities.
    node_coordinates : ndarray (N_el + 1, 2)
        Initial node positions.
    element_length : ndarray (N_el,)
        ``h_e``.
    """

    name = "toss_rule"
    #: Units and labels of the variables of the model's FMU (see :mod:`fmu.metadata`);
    #: ``stop_time`` is the end of its default experiment.
    fmi_metadata = {
        "dofs": [["m", "axial u of node {k0}"],
                 ["m", "transverse v of node {k0}"],
                 ["rad", "rotation alpha of node {k0}"]],
        "parameters": {
            "n_elements": ["1", "number of beam elements (fixes the number of DOFs)"],
            "length": ["m", "length of the rule"],
            "width": ["m", "width of the cross-section"],
            "thickness": ["m", "thickness of the cross-section"],
            "E": ["Pa", "Young's modulus"],
            "nu": ["1", "Poisson's ratio"],
            "shear_factor": ["1", "shear correction factor"],
            "rho": ["kg/m3", "density"],
            "force_amplitude": ["N", "peak of the +y hat force at the left end"],
            "moment_amplitude": ["N.m", "peak of the hat moment at the left end"],
            "load_time": ["s", "time of the peak of both hat loads"],
        },
        "quantities": {
            "u": ["m", "nodal displacements and rotations", None],
            "alpha_mv": ["rad", "mean of the elements' rotations alpha_o (Eq. 55)", None],
            "m_c": ["N.m", "bending moment EJ chi at the centre (Eq. 55)", None],
            "alpha_t_mv": ["rad/s", "mean rotation rate over the elements", None],
            "N_c": ["N", "axial force EA epsilon at the centre", None],
        },
        "stop_time": 0.1,
    }
    # The hat pulses have kinks, so an exact rate would not help HFDI more
    # than the paper's difference quotient does.
    load_rate = None
    damping = None

    def __init__(self, n_elements=6, length=0.5, width=0.030, thickness=0.002, E=210e9,
                 nu=0.3, shear_factor=5.0 / 6.0, rho=7850.0, force_amplitude=200.0,
                 moment_amplitude=10.0, load_time=0.005):
        self.n_elements = n_el = checks.integer("toss rule n_elements", n_elements, 1,
                                                MAX_ELEMENTS)
        self.length = checks.positive("toss rule length", length)
        self.width = checks.positive("toss rule width", width)
        self.thickness = checks.positive("toss rule thickness", thickness)
        self.E = checks.positive("toss rule E", E)
        self.nu = checks.real("toss rule nu", nu, low=-1.0, high=0.5)
        self.shear_factor = checks.positive("toss rule shear_factor", shear_factor)
        self.rho = checks.positive("toss rule rho", rho)
        self.force_amplitude = checks.real("toss rule force_amplitude", force_amplitude)
        self.moment_amplitude = checks.real("toss rule moment_amplitude", moment_amplitude)
        self.load_time = checks.positive("toss rule load_time", load_time)

        self.area = self.width * self.thickness
        self.inertia = self.width * self.thickness ** 3 / 12.0
        self.G = self.E / (2.0 * (1.0 + self.nu))
        self.EA = self.E * self.area
        self.GA = self.shear_factor * self.G * self.area
        self.EJ = self.E * self.inertia

        n_nodes = n_el + 1
        self.n_dof = 3 * n_nodes
        self.u_scale = self.length
        x = np.linspace(0.0, self.length, n_nodes)
        self.node_coordinates = np.column_stack([x, np.zeros(n_nodes)])
        dxy = np.diff(self.node_coordinates, axis=0)
        self.element_length = h = np.hypot(dxy[:, 0], dxy[:, 1])
        # Initial orientation of each element (S_e, C_e of Eqs. 51-52); kept
        # per element so the kernels hold for any initial polygon.
        self._S = dxy[:, 1] / h
        self._C = dxy[:, 0] / h
        self._alpha_hat = np.arctan2(self._S, self._C)
        self._h = h
        self._inv_h = 1.0 / h

        # Element DOFs: element e joins nodes e and e+1, DOFs 3e .. 3e+5.
        self._dofs = 3 * np.arange(n_el)[:, None] + np.arange(6)[None, :]

        # Lumped mass of Eq. 54, summed at shared nodes.
        m_el = np.empty((n_el, 6))
        m_el[:, [0, 1, 3, 4]] = (self.rho * self.area * h / 2.0)[:, None]
        m_el[:, [2, 5]] = (self.rho * self.area * h ** 3 / 24.0)[:, None]
        self.mass = np.bincount(self._dofs.ravel(), weights=m_el.ravel(),
                                minlength=self.n_dof)

        self.initial_displacement = np.zeros(self.n_dof)
        self.initial_velocity = np.zeros(self.n_dof)
        self._build_pattern()

    # -- set-up ------------------------------------------------------------
    def _build_pattern(self):
        """Fixed CSR pattern of the banded tangent and the linear maps into it.

        Everything that does not depend on ``u`` is done here once, so that
        each call of ``f``, ``K`` or ``T`` is elementwise work on (N_el,)
        arrays followed by one sparse matrix–vector product:

        * ``_force_map`` (N, 4 N_el) takes the reduced gradients
          ``∂W/∂y`` (stored as (4, N_el)) to ``f``; it holds ``h_e D_e`` and
          ``Bᵀ`` and sums at the shared nodes.
        * ``_tangent_map`` (nnz, 7 N_el) takes the independent entries of
          the reduced element matrices (stored as (7, N_el) in the order of
          ``_PAIRS``) to the data array of the CSR tangent; it holds
          ``h_e D_e … D_e``, ``Bᵀ … B`` and the sums at the shared nodes.
        """
        n, n_el = self.n_dof, self.n_elements
        dofs = self._dofs
        e = np.arange(n_el)
        # D_e = diag(1/h_e, 1/h_e, 1, 1/h_e) as a (N_el, 4) array
        d = np.ones((n_el, 4))
        d[:, [0, 1, 3]] = self._inv_h[:, None]
        h = self._h

        # f: f[dofs[e, a]] += h_e d_i B[i, a] g[i, e]
        i_idx, a_idx = np.nonzero(_B)
        self._force_map = sp.csr_matrix(
            ((h[:, None] * d[:, i_idx] * _B[i_idx, a_idx]).ravel(),
             (dofs[:, a_idx].ravel(), (i_idx[None, :] * n_el + e[:, None]).ravel())),
            shape=(n, 4 * n_el))

        # Tangent pattern: all 6×6 couplings of each element, sorted as CSR.
        rows = np.repeat(dofs, 6, axis=1).ravel().astype(np.int64)
        cols = np.tile(dofs, (1, 6)).ravel().astype(np.int64)
        keys = np.unique(rows * n + cols)
        idx_dtype = np.int32 if max(n, keys.size) < 2 ** 31 - 1 else np.int64
        self._csr_indices = (keys % n).astype(idx_dtype)
        self._csr_indptr = np.concatenate(
            [[0], np.cumsum(np.bincount(keys // n, minlength=n))]).astype(idx_dtype)
        self._nnz = keys.size
        slot = self.element_positions()

        # K data: data[slot[e, m]] += h_e d_i d_j _BB[c, m] sym[c, e], (i, j) = _PAIRS[c]
        pair_scale = np.stack([h * d[:, i] * d[:, j] for i, j in _PAIRS], axis=1)
        c_idx, m_idx = np.nonzero(_BB)
        tangent_map = sp.csr_matrix(
            ((pair_scale[:, c_idx] * _BB[c_idx, m_idx]).ravel(),
             (slot[:, m_idx].ravel(), (c_idx[None, :] * n_el + e[:, None]).ravel())),
            shape=(self._nnz, len(_PAIRS) * n_el))
        # The kernels lay the entries out in the order of _KERNEL_PAIRS: renumber
        # the columns in place, keeping the stored order of every row (and so
        # the order of the sums of the matrix-vector product).
        cols = tangent_map.indices
        tangent_map.indices = (_KERNEL_ROW[cols // n_el] * n_el + cols % n_el).astype(cols.dtype)
        tangent_map.has_sorted_indices = False
        self._tangent_map = tangent_map

        # Rigidities of (ε, γ), broadcast over (2, rows, N_el) kernel arrays.
        self._R2 = np.array([self.EA, self.GA])[:, None, None]

        # Template of the result: sorted, canonical CSR with the fixed pattern.
        # Each K or T is a shallow copy that gets its own data and index
        # arrays, which skips the checks of the csr_matrix constructor.
        template = sp.csr_matrix((np.zeros(self._nnz), self._csr_indices.copy(),
                                  self._csr_indptr.copy()), shape=(n, n))
        assert template.has_sorted_indices and template.has_canonical_format
        self._csr_template = template

    # -- kinematics and element kernels ------------------------------------
    def _reduced(self, u):
        """Reduced coordinates ``u_ξ, v_ξ, α_o, χ`` of every element, each (…, N_el).

        ``u`` has shape (…, N); with the node-by-node ordering a reshape to
        (…, N_el + 1, 3) gives the nodal values without any gather.
        """
        U = np.asarray(u, dtype=float)
        U = U.reshape(U.shape[:-1] + (self.n_elements + 1, 3))
        # (u_j − u_i, v_j − v_i, α_j − α_i) / h_e in one go: columns p, q, χ
        dh = (U[..., 1:, :] - U[..., :-1, :]) * self._inv_h[:, None]
        a = 0.5 * (U[..., 1:, 2] + U[..., :-1, 2])
        return dh[..., 0], dh[..., 1], a, dh[..., 2]

    def _strains(self, p, q, a):
        """``ε``, ``γ`` (Eqs. 51–52) and ``cos β``, ``sin β`` with ``β = α_o + α̂``."""
        # C_e cos α − S_e sin α = cos(α + α̂) and C_e sin α + S_e cos α = sin(α + α̂)
        beta = a + self._alpha_hat
        cb, sb = np.cos(beta), np.sin(beta)
        eps = np.cos(a) - 1.0 + cb * p + sb * q
        gam = -np.sin(a) - sb * p + cb * q
        return eps, gam, cb, sb

    def _strain_derivatives(self, u):
        """Strains and their derivatives w.r.t. ``x = (u_ξ, v_ξ, α_o)``.

        Returns, for ``k = ε`` and ``k = γ``, a tuple ``(R, k, g, r, t)``:
        the rigidity, the strain (N_el,), the gradient ``g = ∂k/∂x``, the
        α_o-row ``r = ∂²k/∂x∂α_o`` of the Hessian and the third derivatives
        ``t = ∂³k/∂x∂α_o²``, each a (3, N_el) array (rows ``p, q, α``). Every
        other second or third derivative is zero because ``k`` is linear in
        ``u_ξ, v_ξ``. Since ``∂ε/∂α_o = γ`` and ``∂γ/∂α_o = −(1 + ε)``:
        ``r_ε = g_γ``, ``r_γ = −g_ε``, ``t_ε = −g_ε``, ``t_γ = −g_γ``; all of
        them are views of one (4, 3, N_el) array ``(g_ε, g_γ, −g_ε, −g_γ)``.
        """
        p, q, a, chi = self._reduced(u)
        eps, gam, cb, sb = self._strains(p, q, a)
        y = np.empty((4, 3) + eps.shape)
        y[0, 0] = cb
        y[0, 1] = sb
        y[0, 2] = gam
        np.negative(sb, out=y[1, 0])
        y[1, 1] = cb
        np.negative(1.0 + eps, out=y[1, 2])
        np.negative(y[:2], out=y[2:])
        return chi, ((self.EA, eps, y[0], y[1], y[2]),
                     (self.GA, gam, y[1], y[2], y[3]))

    def _assemble(self, sym):
        """Global CSR matrix from reduced element matrices.

        ``sym`` (7, N_el) holds the entries of the reduced symmetric element
        matrices ``∂²W/∂y²`` in the order of ``_KERNEL_PAIRS``.
        """
        return self.csr_from_data(self._tangent_map @ sym.ravel())

    def element_positions(self):
        """Where each element's couplings lie in the data of the tangent's CSR
        pattern: ``positions[e, 6 a + b]`` for the coupling of its DOFs ``a``
        and ``b`` (int64, (N_el, 36); made on demand, for compiled kernels)."""
        dofs = self._dofs
        rows = np.repeat(dofs, 6, axis=1)
        cols = np.tile(dofs, (1, 6))
        indptr, indices = self._csr_indptr, self._csr_indices
        # each row's columns are one contiguous run (a chain of nodes): the
        # column's offset from the row's first column is its position in the row
        positions = indptr[rows].astype(np.int64) + cols - indices[indptr[rows]]
        if not np.array_equal(indices[positions], cols):
            raise AssertionError("toss rule: the tangent's rows are not contiguous")
        return positions

    def csr_from_data(self, data):
        """The (N, N) CSR matrix with the tangent's fixed pattern and ``data`` (nnz,)."""
        # A shallow copy of the validated template (same shape, pattern and
        # format flags) instead of the checking constructor; fresh data and
        # index arrays, since a caller may sort, prune or scale it in place.
        out = copy.copy(self._csr_template)
        out.data = data
        out.indices = self._csr_indices.copy()
        out.indptr = self._csr_indptr.copy()
        return out

    # -- mechanics ---------------------------------------------------------
    def element_strains(self, u):
        """Centre strains ``ε``, ``γ``, ``χ`` of every element (Eqs. 51–53).

        Parameters
        ----------
        u : ndarray (…, N)

        Returns
        -------
        eps, gam, chi : ndarray (…, N_el)
        """
        p, q, a, chi = self._reduced(u)
        eps, gam, _, _ = self._strains(p, q, a)
        return eps, gam, chi

    def compiled_kernels(self):
        """Compiled kernels of f, K, T, V and the load (:func:`hfdi.compiled.models.toss_rule_kernels`;
        imports numba)."""
        from ..compiled.models import toss_rule_kernels
        return toss_rule_kernels(self)

    def compiled_sparse_kernels(self):
        """Compiled f and CSR K, T for large beams
        (:func:`hfdi.compiled.models.toss_rule_sparse_kernels`; imports numba)."""
        from ..compiled.models import toss_rule_sparse_kernels
        return toss_rule_sparse_kernels(self)

    def potential_energy(self, u):
        """Strain energy ``V = Σ_e ½ h_e (EA ε² + GA γ² + EJ χ²)`` (Eq. 50, one-point rule)."""
        eps, gam, chi = self.element_strains(u)
        return float(0.5 * np.sum(self._h * (self.EA * eps ** 2 + self.GA * gam ** 2
                                             + self.EJ * chi ** 2)))

    def internal_force(self, u):
        """``f = ∂V/∂u``, shape (N,)."""
        p, q, a, chi = self._reduced(u)
        eps, gam, cb, sb = self._strains(p, q, a)
        EA_eps, GA_gam = self.EA * eps, self.GA * gam
        # ∂W/∂y with y = (u_ξ, v_ξ, α_o, χ); the map applies h_e D_e and Bᵀ
        g = np.empty((4, self.n_elements))
        g[0] = EA_eps * cb - GA_gam * sb
        g[1] = EA_eps * sb + GA_gam * cb
        g[2] = EA_eps * gam - GA_gam * (1.0 + eps)
        g[3] = self.EJ * chi
        return self._force_map @ g.ravel()

    def stiffness(self, u):
        """``K = ∂²V/∂u²``, scipy CSR (N, N), symmetric and banded.

        In reduced coordinates ``Σ_k R_k (∇k ∇kᵀ + k ∇²k) + EJ e_χ e_χᵀ``
        over ``k ∈ {ε, γ}``.
        """
        _, ((R_e, k_e, g_e, r_e, _), (R_g, k_g, g_g, r_g, _)) = self._strain_derivatives(u)
        # Both strains at once: leading axis (ε, γ); rows as in _KERNEL_PAIRS.
        R = np.array((R_e, R_g), dtype=float)[:, None]
        g, r = np.array((g_e, g_g)), np.array((r_e, r_g))
        Rk = R * np.array((k_e, k_g))
        P = R[:, None] * (g[:, _I] * g[:, _J])           # R ∇k ∇kᵀ
        Q = Rk[:, None] * r                              # R k ∇²k, its α_o row
        # ∇²k is non-zero only in its α_o row and column, rows 3:6; the sums
        # in the order ε then γ, each gradient term before its ∇²k term.
        return self._assemble(self._kernel_sum(P, Q, self.EJ))

    def _kernel_sum(self, P, Q, curvature):
        """Independent entries of the reduced matrices (rows as in ``_KERNEL_PAIRS``):
        ``P`` (gradient terms) and ``Q`` (its α_o row, ``∇²k`` terms) of ε then γ,
        summed in that order, and the curvature entry."""
        sym = np.empty((len(_KERNEL_PAIRS), self.n_elements))
        head, alpha = sym[:6], sym[3:6]
        head[...] = P[0]
        alpha += Q[0]
        head += P[1]
        alpha += Q[1]
        sym[6] = curvature
        return sym

    def stiffness_derivative(self, u, w):
        """``T(u)[w] = ∂(K(u) w)/∂u``, scipy CSR (N, N), same pattern as ``K``.

        In reduced coordinates, for each strain ``k ∈ {ε, γ}`` with rigidity
        ``R_k`` and ``z`` the reduced image of ``w``,
        ``R_k (∇²k z ∇kᵀ + ∇k (∇²k z)ᵀ + (∇k·z) ∇²k + k ∇³k[z])``; the
        curvature term is quadratic, so it contributes nothing.
        """
        _, ((R_e, k_e, g_e, r_e, t_e), (R_g, k_g, g_g, r_g, t_g)) = self._strain_derivatives(u)
        zp, zq, za, _ = self._reduced(w)
        # Both strains at once: leading axis (ε, γ); rows as in _KERNEL_PAIRS.
        R = np.array((R_e, R_g), dtype=float)[:, None]
        y = np.array((g_e, g_g, r_e, r_g, t_e, t_g))
        g, r, t = y[0:2], y[2:4], y[4:6]
        # ∇k·z, r·z and t·z in one go
        yz = y[:, 0] * zp + y[:, 1] * zq + y[:, 2] * za
        # ∇²k z, with ∇²k = e_α rᵀ + r e_αᵀ − r_α e_α e_αᵀ: (r_p z_α, r_q z_α, r·z)
        Hz = np.empty_like(g)
        np.multiply(r[:, :2], za, out=Hz[:, :2])
        Hz[:, 2] = yz[2:4]
        P = R[:, None] * (Hz[:, _I] * g[:, _J] + g[:, _I] * Hz[:, _J])
        # (∇k·z) ∇²k + k ∇³k[z]; ∇³k[z] has the same α_o-only structure
        # with row (t_p z_α, t_q z_α, t·z)
        Rgz, Rk = R * yz[0:2], R * np.array((k_e, k_g))
        Q = Rgz[:, None] * r
        S = np.empty_like(Q)
        np.multiply(Rk[:, None] * t[:, :2], za, out=S[:, :2])
        np.multiply(Rk, yz[4:6], out=S[:, 2])
        Q += S
        return self._assemble(self._kernel_sum(P, Q, 0.0))

    def load_breakpoints(self):
        """The kinks of the hat load: ``0``, ``load_time`` and twice it."""
        return hat_breakpoints(self.load_time)

    def load(self, t):
        """``p(t)``: force ``F(t)`` in +y and moment ``M(t)`` at the left end node (chosen)."""
        p = np.zeros(self.n_dof)
        p[1] = hat(t, self.force_amplitude, self.load_time)
        p[2] = hat(t, self.moment_amplitude, self.load_time)
        return p

    # -- output --------------------------------------------------------------
    def _centre(self, values):
        """Value at the bar's centre from per-element values (…, N_el).

        With an even ``N_el`` the centre is a node: the mean of its two
        elements; with an odd ``N_el`` the central element's value.
        """
        n_el = self.n_elements
        if n_el % 2 == 0:
            return 0.5 * (values[..., n_el // 2 - 1] + values[..., n_el // 2])
        return values[..., n_el // 2]

    def quantities(self, t, u, v):
        """Quantities of interest of Section 5.4, vectorised over times.

        Parameters
        ----------
        t : ndarray (n,)
        u, v : ndarray (n, N)

        Returns
        -------
        dict
            ``"u"`` (n, N); ``"alpha_mv"`` (n, 1), the mean of the elements'
            ``α_o`` (Eq. 55); ``"m_c"`` (n, 1), ``EJ χ`` at the centre
            (Eq. 55); ``"alpha_t_mv"`` (n, 1), the mean over elements of
            ``(α̇_i + α̇_j)/2``; ``"N_c"`` (n, 1), ``EA ε`` at the centre.
        """
        u = np.atleast_2d(np.asarray(u, dtype=float))
        v = np.atleast_2d(np.asarray(v, dtype=float))
        p, q, a, chi = self._reduced(u)
        eps, _, _, _ = self._strains(p, q, a)
        _, _, a_t, _ = self._reduced(v)
        return {"u": u,
                "alpha_mv": a.mean(axis=-1)[:, None],
                "m_c": (self.EJ * self._centre(chi))[:, None],
                "alpha_t_mv": a_t.mean(axis=-1)[:, None],
                "N_c": (self.EA * self._centre(eps))[:, None]}

    def parameters(self):
        return {"n_elements": self.n_elements, "length": self.length, "width": self.width,
                "thickness": self.thickness, "E": self.E, "nu": self.nu,
                "shear_factor": self.shear_factor, "rho": self.rho,
                "force_amplitude": self.force_amplitude,
                "moment_amplitude": self.moment_amplitude, "load_time": self.load_time}


def toss_rule(n_elements=6, **params) -> TossRule:
    """The toss rule of Section 5.4; keyword arguments as :class:`TossRule`."""
    return TossRule(n_elements=n_elements, **params)
