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

The paper's data and the chosen ones (geometry, material, loads) are in
docs/models.md, "Toss rule".

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
from .base import KernelModel
from .kernels import compiled, kernel
from .loads import hat_load_params

__all__ = ["TossRule", "toss_rule", "MAX_ELEMENTS"]

#: The most elements a toss rule may have: 3,000,003 DOFs, about 7 GB in a run
#: (2.4 kB per DOF measured, docs/performance.md). More is refused up front
#: rather than left to exhaust the memory of the machine.
MAX_ELEMENTS = 1_000_000


class TossRule(KernelModel):
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
    area, inertia, G, EA, GA, EJ : float
        The section's ``A`` and ``J``, the shear modulus and the axial, shear
        and flexural rigidities; read-only, derived from the parameters.
    node_coordinates : ndarray (N_el + 1, 2)
        Initial node positions.
    element_length : ndarray (N_el,)
        ``h_e``.
    """

    name = "toss_rule"
    FIXED_PARAMETERS = ("n_elements", "length", "width", "thickness", "E", "nu",
                        "shear_factor", "rho")
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
    # than the load's derivative does (KernelModel: none).

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
        self._h = h.copy()
        self._inv_h = 1.0 / h
        # the geometry shown is what the kernels' data were made from: read-only
        # (an edit of element_length changed h_e in the kernels, not 1/h_e nor M)
        self.node_coordinates.flags.writeable = False
        self.element_length.flags.writeable = False

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
    # The section's data follow from the fixed parameters: read-only, so that
    # an assignment cannot leave the kernels or the mass on other values.
    @property
    def area(self) -> float:
        """``A = width·thickness``."""
        return self.width * self.thickness

    @property
    def inertia(self) -> float:
        """``J = width·thickness³/12``."""
        return self.width * self.thickness ** 3 / 12.0

    @property
    def G(self) -> float:                               # noqa: N802 - the symbol's name
        """``G = E/(2(1+ν))``."""
        return self.E / (2.0 * (1.0 + self.nu))

    @property
    def EA(self) -> float:                              # noqa: N802
        """Axial rigidity ``E A``."""
        return self.E * self.area

    @property
    def GA(self) -> float:                              # noqa: N802
        """Shear rigidity ``shear_factor·G·A``."""
        return self.shear_factor * self.G * self.area

    @property
    def EJ(self) -> float:                              # noqa: N802
        """Flexural rigidity ``E J``."""
        return self.E * self.inertia

    def _build_pattern(self):
        """The fixed CSR pattern of the banded tangent: every coupling of each
        element's six DOFs, sorted; a template of the result, and where each
        element's couplings lie in its data (:meth:`element_positions`)."""
        n = self.n_dof
        rows = np.repeat(self._dofs, 6, axis=1).ravel().astype(np.int64)
        cols = np.tile(self._dofs, (1, 6)).ravel().astype(np.int64)
        keys = np.unique(rows * n + cols)
        idx_dtype = np.int32 if max(n, keys.size) < 2 ** 31 - 1 else np.int64
        self._csr_indices = (keys % n).astype(idx_dtype)
        self._csr_indptr = np.concatenate(
            [[0], np.cumsum(np.bincount(keys // n, minlength=n))]).astype(idx_dtype)
        self._nnz = keys.size
        # sorted, canonical CSR with the fixed pattern, copied by csr_from_data
        template = sp.csr_matrix((np.zeros(self._nnz), self._csr_indices.copy(),
                                  self._csr_indptr.copy()), shape=(n, n))
        assert template.has_sorted_indices and template.has_canonical_format
        self._csr_template = template
        self._slots = self.element_positions()

    def element_positions(self):
        """Where each element's couplings lie in the data of the tangent's CSR
        pattern: ``positions[e, 6 a + b]`` for the coupling of its DOFs ``a``
        and ``b`` (int64, (N_el, 36))."""
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
        # a shallow copy of the validated template, not the checking constructor;
        # fresh index arrays, since a caller may sort, prune or scale it in place
        out = copy.copy(self._csr_template)
        out.data = data
        out.indices = self._csr_indices.copy()
        out.indptr = self._csr_indptr.copy()
        return out

    def params(self):
        """The kernels' data ``(N_el, EA, GA, EJ, h_e …, 1/h_e …, cos α̂_e …, sin α̂_e …)``
        (4 + 4 N_el entries)."""
        return np.concatenate([[self.n_elements, self.EA, self.GA, self.EJ],
                               self._h, self._inv_h, self._C, self._S])

    def load_params(self):
        """The load's data (:func:`~hfdi.models.loads.hat_load`): force and moment at node 0."""
        return hat_load_params(self.n_dof, [(1, self.force_amplitude, self.load_time),
                                            (2, self.moment_amplitude, self.load_time)])

    # -- the elements, all at once (docs/models.md, "One physics per model") ------
    def _reduced(self, u):
        """Reduced coordinates ``u_ξ, v_ξ, α_o, χ`` of every element, each (…, N_el)."""
        U = np.asarray(u, dtype=float)
        U = U.reshape(U.shape[:-1] + (self.n_elements + 1, 3))
        i, j = U[..., :-1, :], U[..., 1:, :]
        return beam_reduced(i[..., 0], i[..., 1], i[..., 2], j[..., 0], j[..., 1], j[..., 2],
                            self._inv_h)

    def _elements(self):
        """``(EA, GA, EJ)`` and the per-element ``h, 1/h, cos α̂, sin α̂`` of :meth:`params`."""
        params, n = self.params(), self.n_elements
        return params[1:4], (params[4:4 + n], params[4 + n:4 + 2 * n],
                             params[4 + 2 * n:4 + 3 * n], params[4 + 3 * n:])

    def _assemble(self, values):
        """The CSR matrix of the element blocks of ``values`` (7, N_el) (:func:`beam_block`)."""
        block = np.array(_BLOCK_SIGN)[:, None] * np.asarray(values)[list(_BLOCK_VALUE)]
        return self.csr_from_data(np.bincount(self._slots.ravel(), block.T.ravel(),
                                              self._nnz))

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
        eps, gam, _, _ = beam_strains(p, q, a, self._C, self._S)
        return eps, gam, chi

    def compiled_kernels(self):
        """The kernels below compiled (dense ``K`` and ``T``), with the hat loads
        (imports numba); defined here, where the Python methods are."""
        return super().compiled_kernels()

    def compiled_sparse_kernels(self):
        """Compiled f and CSR K, T for large beams: element loops that add each
        element's 6 × 6 block straight into the data array of the tangent's CSR
        pattern. O(N_el) time, no temporary per element (imports numba)."""
        from ..compiled import SparseKernels
        params = np.ascontiguousarray(self.params(), dtype=np.float64)
        slots = np.ascontiguousarray(self._slots, dtype=np.int64)
        nnz, as_vector = int(self._nnz), np.ascontiguousarray
        force, stiffness_data, derivative_data = (compiled(toss_rule_force),
                                                  compiled(toss_rule_stiffness_data),
                                                  compiled(toss_rule_stiffness_derivative_data))

        def stiffness(u):
            return self.csr_from_data(stiffness_data(as_vector(u, dtype=np.float64), params,
                                                     slots, nnz))

        def stiffness_derivative(u, w):
            return self.csr_from_data(derivative_data(
                as_vector(u, dtype=np.float64), as_vector(w, dtype=np.float64), params, slots,
                nnz))

        return SparseKernels(lambda u: force(as_vector(u, dtype=np.float64), params),
                             stiffness, stiffness_derivative)

    def potential_energy(self, u):
        """Strain energy ``V = Σ_e ½ h_e (EA ε² + GA γ² + EJ χ²)`` (Eq. 50, one-point rule)."""
        (EA, GA, EJ), (h, _, c, s) = self._elements()
        p, q, a, chi = self._reduced(u)
        # the sum in element order, as the kernel's loop forms it
        return 0.5 * float(np.cumsum(beam_energy(EA, GA, EJ, h, p, q, a, chi, c, s))[-1])

    def internal_force(self, u):
        """``f = ∂V/∂u``, shape (N,)."""
        (EA, GA, EJ), (h, _, c, s) = self._elements()
        p, q, a, chi = self._reduced(u)
        g0, g1, half, bend = beam_force(EA, GA, EJ, h, p, q, a, chi, c, s)
        f = np.zeros((self.n_elements + 1, 3))
        f[:-1, 0] -= g0
        f[:-1, 1] -= g1
        f[:-1, 2] += half - bend
        f[1:, 0] += g0
        f[1:, 1] += g1
        f[1:, 2] += half + bend
        return f.ravel()

    def stiffness(self, u):
        """``K = ∂²V/∂u²``, scipy CSR (N, N), symmetric and banded."""
        (EA, GA, EJ), (h, inv_h, c, s) = self._elements()
        p, q, a, _ = self._reduced(u)
        return self._assemble(beam_stiffness(EA, GA, EJ, h, inv_h, p, q, a, c, s))

    def stiffness_derivative(self, u, w):
        """``T(u)[w] = ∂(K(u) w)/∂u``, scipy CSR (N, N), same pattern as ``K``."""
        (EA, GA, _), (h, inv_h, c, s) = self._elements()
        p, q, a, _ = self._reduced(u)
        zp, zq, za, _ = self._reduced(w)
        return self._assemble(beam_derivative(EA, GA, h, inv_h, p, q, a, zp, zq, za, c, s))

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
        eps, _, _, _ = beam_strains(p, q, a, self._C, self._S)
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


# -- the kernels: params = (N_el, EA, GA, EJ, h_e …, 1/h_e …, cos α̂_e …, sin α̂_e …) -------
# Element e joins nodes e and e + 1 (DOFs 3e … 3e + 5); f_e = h_e L_eᵀ ∇W,
# K_e = h_e L_eᵀ ∇²W L_e, T_e = h_e L_eᵀ ∇³W[L_e w_e] L_e with L_e = D_e B (the
# module's "Derivatives"). The element functions are elementwise: numbers in
# the compiled loops, (N_el,) arrays in the Python methods.

@kernel
def beam_reduced(ui, vi, ai, uj, vj, aj, inv_h):
    """``(u_ξ, v_ξ, α_o, χ)`` of an element from the values at its nodes i and j."""
    return (uj - ui) * inv_h, (vj - vi) * inv_h, 0.5 * (aj + ai), (aj - ai) * inv_h


@kernel
def beam_strains(p, q, a, cos_hat, sin_hat):
    """``ε``, ``γ`` and their gradients ``∇ε = (cb, sb, γ)``, ``∇γ = (−sb, cb, −(1 + ε))``
    in ``(u_ξ, v_ξ, α_o)``, ``cb``, ``sb`` the cosine and sine of ``β = α_o + α̂`` by
    the addition theorem: one sine and cosine per element, not two."""
    ca, sa = np.cos(a), np.sin(a)
    cb, sb = ca * cos_hat - sa * sin_hat, sa * cos_hat + ca * sin_hat
    eps = ca - 1.0 + cb * p + sb * q
    gam = -sa - sb * p + cb * q
    return eps, gam, (cb, sb, gam), (-sb, cb, -(1.0 + eps))


@kernel
def beam_energy(EA, GA, EJ, h, p, q, a, chi, cos_hat, sin_hat):
    """``h_e (EA ε² + GA γ² + EJ χ²)``, twice the element's energy."""
    eps, gam, _, _ = beam_strains(p, q, a, cos_hat, sin_hat)
    return h * (EA * (eps * eps) + GA * (gam * gam) + EJ * (chi * chi))


@kernel
def beam_force(EA, GA, EJ, h, p, q, a, chi, cos_hat, sin_hat):
    """``h L_eᵀ (∇W, EJ χ)`` as ``(g_u, g_v, half, bend)``: ``∓g_u``, ``∓g_v`` on the
    translations of nodes i and j, ``half ∓ bend`` on their rotations."""
    eps, gam, g_eps, g_gam = beam_strains(p, q, a, cos_hat, sin_hat)
    EA_eps, GA_gam = EA * eps, GA * gam
    return (EA_eps * g_eps[0] + GA_gam * g_gam[0], EA_eps * g_eps[1] + GA_gam * g_gam[1],
            0.5 * h * (EA_eps * g_eps[2] + GA_gam * g_gam[2]), EJ * chi)


@kernel
def _alpha_entry(r, i, j):
    """Entry ``(i, j)`` of a 3 × 3 matrix non-zero in its α_o row and column
    only, that row being ``r`` (``∇²k`` with ``r = ±∇`` of the other strain)."""
    if j == 2:
        return r[i]
    if i == 2:
        return r[j]
    return 0.0


@kernel
def _stiffness_entry(EA, GA, eps, gam, g_eps, g_gam, m_eps, i, j):
    """``(∇²W)_ij`` in ``(u_ξ, v_ξ, α_o)``: ``∇²ε`` has the α_o row ∇γ, ``∇²γ`` the row −∇ε."""
    return (EA * (g_eps[i] * g_eps[j] + eps * _alpha_entry(g_gam, i, j))
            + GA * (g_gam[i] * g_gam[j] + gam * _alpha_entry(m_eps, i, j)))


@kernel
def beam_block(h, inv_h, r00, r01, r11, r02, r12, r22, r33):
    """The seven numbers of ``h L_eᵀ red L_e`` for the symmetric reduced ``red``
    whose χ row and column are zero but for ``r33``; :data:`_BLOCK_VALUE` and
    :data:`_BLOCK_SIGN` place them in the 6 × 6 block."""
    q, r = 0.25 * h * r22, inv_h * r33
    return (inv_h * r00, inv_h * r01, inv_h * r11, 0.5 * r02, 0.5 * r12, q + r, q - r)


@kernel
def beam_stiffness(EA, GA, EJ, h, inv_h, p, q, a, cos_hat, sin_hat):
    """The element's tangent block (:func:`beam_block`) from ``∇²W``."""
    eps, gam, g_eps, g_gam = beam_strains(p, q, a, cos_hat, sin_hat)
    m_eps = (-g_eps[0], -g_eps[1], -g_eps[2])
    return beam_block(h, inv_h, _stiffness_entry(EA, GA, eps, gam, g_eps, g_gam, m_eps, 0, 0),
                      _stiffness_entry(EA, GA, eps, gam, g_eps, g_gam, m_eps, 0, 1),
                      _stiffness_entry(EA, GA, eps, gam, g_eps, g_gam, m_eps, 1, 1),
                      _stiffness_entry(EA, GA, eps, gam, g_eps, g_gam, m_eps, 0, 2),
                      _stiffness_entry(EA, GA, eps, gam, g_eps, g_gam, m_eps, 1, 2),
                      _stiffness_entry(EA, GA, eps, gam, g_eps, g_gam, m_eps, 2, 2), EJ)


@kernel
def _row_image(r, zp, zq, za):
    """``M z`` for the 3 × 3 ``M`` non-zero in its α_o row and column only, that row ``r``."""
    return r[0] * za, r[1] * za, r[0] * zp + r[1] * zq + r[2] * za


@kernel
def _strain_third(t, zp, zq, za):
    """``∇³k[z]``'s α_o row, ``t = −∇k`` its third derivatives."""
    return _row_image(t, zp, zq, za)


@kernel
def _derivative_entry(R, k, g, r, Hz, gz, third, i, j):
    """``R (∇²k z ∇kᵀ + ∇k (∇²k z)ᵀ + (∇k·z) ∇²k + k ∇³k[z])_ij``."""
    return R * (Hz[i] * g[j] + g[i] * Hz[j] + gz * _alpha_entry(r, i, j)
                + k * _alpha_entry(third, i, j))


@kernel
def beam_derivative(EA, GA, h, inv_h, p, q, a, zp, zq, za, cos_hat, sin_hat):
    """The element's block of ``T[w]`` (:func:`beam_block`) from ``∇³W[z]``, ``z`` the
    reduced image of ``w`` (the curvature term is quadratic: no third derivative)."""
    eps, gam, g_eps, g_gam = beam_strains(p, q, a, cos_hat, sin_hat)
    m_eps = (-g_eps[0], -g_eps[1], -g_eps[2])
    m_gam = (-g_gam[0], -g_gam[1], -g_gam[2])
    r00 = r01 = r11 = r02 = r12 = r22 = 0.0
    # per strain k (rigidity R): ∇²k's α_o row r (∇γ for ε, −∇ε for γ), ∇³k's t = −∇k
    for which in range(2):
        if which == 0:
            R, k, g, r, t = EA, eps, g_eps, g_gam, m_eps
        else:
            R, k, g, r, t = GA, gam, g_gam, m_eps, m_gam
        Hz = _row_image(r, zp, zq, za)
        gz = g[0] * zp + g[1] * zq + g[2] * za
        third = _strain_third(t, zp, zq, za)
        r00 += _derivative_entry(R, k, g, r, Hz, gz, third, 0, 0)
        r01 += _derivative_entry(R, k, g, r, Hz, gz, third, 0, 1)
        r11 += _derivative_entry(R, k, g, r, Hz, gz, third, 1, 1)
        r02 += _derivative_entry(R, k, g, r, Hz, gz, third, 0, 2)
        r12 += _derivative_entry(R, k, g, r, Hz, gz, third, 1, 2)
        r22 += _derivative_entry(R, k, g, r, Hz, gz, third, 2, 2)
    return beam_block(h, inv_h, r00, r01, r11, r02, r12, r22, 0.0)


def _block_layout():
    """``(value, sign)`` of each entry ``6 a + b`` of an element block: the values
    of :func:`beam_block` ``(x_00, x_01, x_11, y_0, y_1, d, o)`` at ``±`` in
    ``h L_eᵀ red L_e`` (L_e has ∓1/h_e (u_ξ, v_ξ) on the translations of nodes
    i and j, 1/2 (α_o) and ∓1/h_e (χ) on their rotations)."""
    value, sign = [0] * 36, [1.0] * 36

    def put(a, b, k, s):
        value[6 * a + b], sign[6 * a + b] = k, s
    for t in range(2):
        for s in range(2):
            k = t + s
            put(t, s, k, 1.0), put(3 + t, 3 + s, k, 1.0)
            put(t, 3 + s, k, -1.0), put(3 + t, s, k, -1.0)
        for a, b in ((t, 2), (t, 5), (2, t), (5, t)):
            put(a, b, 3 + t, -1.0)
        for a, b in ((3 + t, 2), (3 + t, 5), (2, 3 + t), (5, 3 + t)):
            put(a, b, 3 + t, 1.0)
    put(2, 2, 5, 1.0), put(5, 5, 5, 1.0), put(2, 5, 6, 1.0), put(5, 2, 6, 1.0)
    return tuple(value), tuple(sign)


_BLOCK_VALUE, _BLOCK_SIGN = _block_layout()


@kernel
def _element(params, u, e):
    """``(h, 1/h, cos α̂, sin α̂)`` and the reduced coordinates of element ``e`` at ``u``."""
    n_el = int(params[0])
    h, inv_h = params[4 + e], params[4 + n_el + e]
    i = 3 * e
    return ((h, inv_h, params[4 + 2 * n_el + e], params[4 + 3 * n_el + e]),
            beam_reduced(u[i], u[i + 1], u[i + 2], u[i + 3], u[i + 4], u[i + 5], inv_h))


@kernel
def toss_rule_force(u, params):
    n_el = int(params[0])
    f = np.zeros(3 * (n_el + 1))
    for e in range(n_el):
        (h, _, c, s), (p, q, a, chi) = _element(params, u, e)
        g0, g1, half, bend = beam_force(params[1], params[2], params[3], h, p, q, a, chi, c, s)
        base = 3 * e
        f[base] -= g0
        f[base + 1] -= g1
        f[base + 3] += g0
        f[base + 4] += g1
        f[base + 2] += half - bend
        f[base + 5] += half + bend
    return f


@kernel
def _element_block(u, w, params, e):
    """The numbers of element ``e``'s block of ``K`` (``w`` empty) or of ``T[w]``."""
    (h, inv_h, c, s), (p, q, a, _) = _element(params, u, e)
    if w.size == 0:
        return beam_stiffness(params[1], params[2], params[3], h, inv_h, p, q, a, c, s)
    _, (zp, zq, za, _) = _element(params, w, e)
    return beam_derivative(params[1], params[2], h, inv_h, p, q, a, zp, zq, za, c, s)


@kernel
def _dense(u, w, params):
    n_el = int(params[0])
    out = np.zeros((3 * (n_el + 1), 3 * (n_el + 1)))
    for e in range(n_el):
        values = _element_block(u, w, params, e)
        for m in range(36):
            out[3 * e + m // 6, 3 * e + m % 6] += _BLOCK_SIGN[m] * values[_BLOCK_VALUE[m]]
    return out


@kernel
def _data(u, w, params, slots, nnz):
    data = np.zeros(nnz)
    for e in range(int(params[0])):
        values = _element_block(u, w, params, e)
        for m in range(36):
            data[slots[e, m]] += _BLOCK_SIGN[m] * values[_BLOCK_VALUE[m]]
    return data


@kernel
def toss_rule_stiffness(u, params):
    return _dense(u, np.empty(0), params)


@kernel
def toss_rule_stiffness_derivative(u, w, params):
    return _dense(u, w, params)


@kernel
def toss_rule_stiffness_data(u, params, slots, nnz):
    """The data array (nnz,) of ``K`` in the CSR pattern whose positions ``slots``
    (N_el, 36) gives for each element's couplings."""
    return _data(u, np.empty(0), params, slots, nnz)


@kernel
def toss_rule_stiffness_derivative_data(u, w, params, slots, nnz):
    """The data array (nnz,) of ``T(u)[w]`` in the pattern of :func:`toss_rule_stiffness_data`."""
    return _data(u, w, params, slots, nnz)


@kernel
def toss_rule_potential_energy(u, params):
    V = 0.0
    for e in range(int(params[0])):
        (h, _, c, s), (p, q, a, chi) = _element(params, u, e)
        V += beam_energy(params[1], params[2], params[3], h, p, q, a, chi, c, s)
    return 0.5 * V


TossRule.KERNELS = (toss_rule_force, toss_rule_stiffness, toss_rule_stiffness_derivative,
                    toss_rule_potential_energy)


def toss_rule(n_elements=6, **params) -> TossRule:
    """The toss rule of Section 5.4; keyword arguments as :class:`TossRule`."""
    return TossRule(n_elements=n_elements, **params)
