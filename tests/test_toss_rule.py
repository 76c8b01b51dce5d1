"""The toss rule of Section 5.4: derivatives, invariances, data and a short run."""
import math
import sys

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp

import hfdi
from hfdi.models.toss_rule import TossRule, toss_rule
from validation.experiments import experiment


def bent_states(model, rng, n):
    """Random large-rotation configurations of the rule.

    Each is a bent polygon: a rigid placement anywhere near the origin, an
    overall rotation up to ±3 rad, a curvature up to ±6 /m (up to 3 rad of
    bend along the rule), small stretches, and noise on every DOF so that
    shear and axial strains are non-zero.
    """
    n_el, L = model.n_elements, model.length
    s = np.linspace(0.0, L, n_el + 1)
    h = L / n_el
    states = []
    for _ in range(n):
        alpha = rng.uniform(-3, 3) + rng.uniform(-6, 6) * s + rng.uniform(-0.2, 0.2, n_el + 1)
        mid = 0.5 * (alpha[1:] + alpha[:-1])
        stretch = 1.0 + rng.uniform(-0.02, 0.02, n_el)
        xy = np.zeros((n_el + 1, 2))
        xy[0] = rng.uniform(-1, 1, 2)
        xy[1:] = xy[0] + np.cumsum(h * stretch[:, None]
                                   * np.column_stack([np.cos(mid), np.sin(mid)]), axis=0)
        xy += rng.normal(0.0, 1e-3 * h, xy.shape)
        states.append(np.column_stack([xy[:, 0] - s, xy[:, 1], alpha]).ravel())
    return np.array(states)


def rigid_state(model, theta, centre=(0.1, -0.2), shift=(0.3, 0.7)):
    """Displacements of a rigid rotation by ``theta`` about ``centre`` plus a shift."""
    X = model.node_coordinates
    c = np.asarray(centre)
    R = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
    x = (X - c) @ R.T + c + np.asarray(shift)
    return np.column_stack([x - X, np.full(len(X), theta)]).ravel()


def arc_state(model, kappa, theta0=0.0):
    """Uniform curvature without stretch or shear: a polygon of chords ``h``.

    Node rotations ``α_i = θ0 + κ s_i``; element ``e`` has its chord of
    length ``h`` along ``α_o``, so ``ε = γ = 0`` and ``χ = κ`` exactly.
    """
    n_el, L = model.n_elements, model.length
    s = np.linspace(0.0, L, n_el + 1)
    alpha = theta0 + kappa * s
    mid = 0.5 * (alpha[1:] + alpha[:-1])
    xy = np.zeros((n_el + 1, 2))
    xy[1:] = np.cumsum((L / n_el) * np.column_stack([np.cos(mid), np.sin(mid)]), axis=0)
    return np.column_stack([xy[:, 0] - s, xy[:, 1], alpha]).ravel()


# -- derivatives ---------------------------------------------------------------

@pytest.mark.parametrize("n_elements", [1, 2, 6, 15])
def test_derivatives_match_finite_differences_at_large_rotations(n_elements):
    model = toss_rule(n_elements)
    states = bent_states(model, np.random.default_rng(n_elements), 8)
    assert np.abs(states[:, 2::3]).max() > 2.0          # really large rotations
    check = hfdi.check_derivatives(model, states, seed=n_elements)
    assert check.samples == 8
    assert check.worst < 1e-6, check


def test_derivative_check_detects_a_dropped_third_derivative_term(monkeypatch):
    # T without the k ∇³k[z] term (small strains times a large rigidity):
    # the check must see it at bent states.
    module = sys.modules[TossRule.__module__]
    model = toss_rule(4)
    states = bent_states(model, np.random.default_rng(7), 3)
    assert hfdi.check_derivatives(model, states).worst < 1e-6
    monkeypatch.setattr(module, "_strain_third", lambda t, zp, zq, za: (0.0 * za,) * 3)
    bad = hfdi.check_derivatives(model, states)
    assert bad.stiffness < 1e-6 < bad.stiffness_derivative


@pytest.mark.parametrize("n_elements", [1, 6, 15])
def test_tangent_and_its_derivative_are_sparse_banded_and_symmetric(n_elements):
    model = toss_rule(n_elements)
    rng = np.random.default_rng(3)
    u = bent_states(model, rng, 1)[0]
    w = rng.standard_normal(model.n_dof)
    K = model.stiffness(u)
    T = model.stiffness_derivative(u, w)
    for A in (K, T):
        assert sp.issparse(A) and A.format == "csr"
        assert A.shape == (model.n_dof, model.n_dof)
        coo = A.tocoo()
        assert np.abs(coo.row - coo.col).max() <= 5
        # two nodes of 3 DOFs coupled per element: 27 per node row block,
        # less the 2 × 9 missing beyond the ends
        assert A.nnz == 27 * (n_elements + 1) - 18
        np.testing.assert_array_equal(A.indices, K.indices)
        np.testing.assert_array_equal(A.indptr, K.indptr)
        D = A.toarray()
        np.testing.assert_allclose(D, D.T, rtol=0, atol=1e-12 * np.abs(D).max())
    # the bandwidth is attained: node i's u couples with node i+1's α
    assert np.abs(K.toarray()[0, 5]) > 0


def test_returned_matrices_do_not_share_index_arrays():
    model = toss_rule(3)
    u = bent_states(model, np.random.default_rng(4), 1)[0]
    K1 = model.stiffness(u)
    K1.indices[:] = 0                                   # a careless caller
    K2 = model.stiffness(u)
    np.testing.assert_allclose(K2.toarray(), K2.toarray().T, atol=1e-9 * abs(K2).max())
    assert np.abs(K2.tocoo().row - K2.tocoo().col).max() == 5


# -- invariance and mechanics -------------------------------------------------

@pytest.mark.parametrize("theta", [0.0, 0.7, -2.5, 3.0, 10.0])
def test_rigid_motion_gives_no_force_and_no_energy(theta):
    model = toss_rule(7)
    u = rigid_state(model, theta)
    f = model.internal_force(u)
    scale = model.EA                                     # force of a unit strain
    assert np.abs(f).max() < 1e-10 * scale
    assert abs(model.potential_energy(u)) < 1e-20 * scale * model.length
    eps, gam, chi = model.element_strains(u)
    np.testing.assert_allclose(np.concatenate([eps, gam, chi]), 0, atol=1e-13)
    # the infinitesimal rigid modes at this state are in the kernel of K
    X = model.node_coordinates + u.reshape(-1, 3)[:, :2]
    n = model.n_dof
    modes = np.zeros((3, n))
    modes[0, 0::3] = 1.0
    modes[1, 1::3] = 1.0
    modes[2, 0::3], modes[2, 1::3], modes[2, 2::3] = -X[:, 1], X[:, 0], 1.0
    K = model.stiffness(u)
    for mode in modes:
        assert np.abs(K @ mode).max() < 1e-8 * abs(K).max()


def test_rigid_state_of_a_bent_rule_has_the_same_energy():
    model = toss_rule(6)
    u = bent_states(model, np.random.default_rng(5), 1)[0]
    theta = 1.3
    R = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
    X = model.node_coordinates
    x = (X + u.reshape(-1, 3)[:, :2]) @ R.T + [0.2, -0.4]
    u_rot = np.column_stack([x - X, u.reshape(-1, 3)[:, 2] + theta]).ravel()
    np.testing.assert_allclose(model.potential_energy(u_rot), model.potential_energy(u),
                               rtol=1e-9)
    # the force rotates with the rule, the moments stay
    f, f_rot = model.internal_force(u).reshape(-1, 3), model.internal_force(u_rot).reshape(-1, 3)
    np.testing.assert_allclose(f_rot[:, :2], f[:, :2] @ R.T, atol=1e-9 * np.abs(f).max())
    np.testing.assert_allclose(f_rot[:, 2], f[:, 2], atol=1e-9 * np.abs(f).max())


@pytest.mark.parametrize("n_elements", [4, 5])
def test_uniform_curvature_state(n_elements):
    model = toss_rule(n_elements)
    kappa, theta0 = 4.0, -1.2
    u = arc_state(model, kappa, theta0)
    eps, gam, chi = model.element_strains(u)
    np.testing.assert_allclose(eps, 0, atol=1e-14)
    np.testing.assert_allclose(gam, 0, atol=1e-14)
    np.testing.assert_allclose(chi, kappa, rtol=1e-12)
    np.testing.assert_allclose(model.potential_energy(u),
                               0.5 * model.EJ * kappa ** 2 * model.length, rtol=1e-12)
    # a free rule held in uniform bending needs the end moments ∓EJκ only
    f = model.internal_force(u)
    expected = np.zeros(model.n_dof)
    expected[2], expected[-1] = -model.EJ * kappa, model.EJ * kappa
    np.testing.assert_allclose(f, expected, atol=1e-9 * model.EJ * kappa)
    q = model.quantities(np.zeros(1), u[None], np.zeros((1, model.n_dof)))
    np.testing.assert_allclose(q["m_c"], [[model.EJ * kappa]], rtol=1e-12)
    np.testing.assert_allclose(q["N_c"], [[0.0]], atol=1e-14 * model.EA)
    np.testing.assert_allclose(q["alpha_mv"], [[theta0 + kappa * model.length / 2]],
                               rtol=1e-12)


def test_arc_through_the_nodes_stretches_its_chords():
    # nodes on a circle of radius 1/κ: chords 2 sin(κh/2)/κ, so ε = chord/h − 1
    model = toss_rule(6)
    kappa = 5.0
    s = np.linspace(0, model.length, 7)
    u = np.column_stack([np.sin(kappa * s) / kappa - s, (1 - np.cos(kappa * s)) / kappa,
                         kappa * s]).ravel()
    h = model.length / 6
    eps_expected = 2 * math.sin(kappa * h / 2) / (kappa * h) - 1
    q = model.quantities(np.zeros(1), u[None], np.zeros((1, model.n_dof)))
    np.testing.assert_allclose(q["N_c"], [[model.EA * eps_expected]], rtol=1e-9)
    np.testing.assert_allclose(q["m_c"], [[model.EJ * kappa]], rtol=1e-12)


def test_uniform_stretch_and_shear():
    model = toss_rule(3)
    e, g = 1e-3, 2e-3
    X = model.node_coordinates[:, 0]
    u = np.column_stack([e * X, g * X, np.zeros_like(X)]).ravel()
    eps, gam, chi = model.element_strains(u)
    np.testing.assert_allclose(eps, e, rtol=1e-12)
    np.testing.assert_allclose(gam, g, rtol=1e-12)
    np.testing.assert_allclose(model.potential_energy(u),
                               0.5 * model.length * (model.EA * e ** 2 + model.GA * g ** 2),
                               rtol=1e-12)
    f = model.internal_force(u).reshape(-1, 3)
    # end forces N = EA ε along x, shear GA γ along y; the shear's moment
    # GA γ·h/2 per element at each node
    np.testing.assert_allclose(f[0, :2], [-model.EA * e, -model.GA * g], rtol=1e-12)
    np.testing.assert_allclose(f[-1, :2], [model.EA * e, model.GA * g], rtol=1e-12)
    np.testing.assert_allclose(f[1:-1, :2], 0, atol=1e-9 * model.EA * e)


# -- data ------------------------------------------------------------------------

def test_rigidities_and_defaults():
    model = toss_rule()
    assert model.n_elements == 6 and model.n_dof == 21
    A, J = 0.030 * 0.002, 0.030 * 0.002 ** 3 / 12
    G = 210e9 / (2 * 1.3)
    assert model.EA == pytest.approx(210e9 * A)
    assert model.GA == pytest.approx(5 / 6 * G * A)
    assert model.EJ == pytest.approx(210e9 * J)
    assert model.EJ == pytest.approx(4.2)
    assert model.u_scale == 0.5
    assert model.load_rate is None and model.damping is None
    table_5 = experiment("toss_rule")
    assert table_5.observation_time == 0.1
    for scheme in ("newmark", "bathe", "hfdi"):
        assert tuple(table_5.targets[scheme]) == (3.0, 3.5, 4.0, 4.5, 5.0)
    np.testing.assert_array_equal(model.initial_displacement, 0)
    np.testing.assert_array_equal(model.initial_velocity, 0)
    p = model.parameters()
    assert p["n_elements"] == 6 and p["length"] == 0.5 and p["nu"] == 0.3
    assert isinstance(TossRule(**p), TossRule)
    assert "TossRule(" in repr(model)


@pytest.mark.parametrize("n_elements", [1, 6, 15])
def test_lumped_mass_totals(n_elements):
    model = toss_rule(n_elements)
    m = model.mass
    assert m.shape == (model.n_dof,) and np.all(m > 0)
    rho_A = 7850 * 0.030 * 0.002
    total = rho_A * 0.5
    np.testing.assert_allclose(m[0::3].sum(), total, rtol=1e-14)
    np.testing.assert_allclose(m[1::3].sum(), total, rtol=1e-14)
    h = 0.5 / n_elements
    np.testing.assert_allclose(m[2::3].sum(), n_elements * rho_A * h ** 3 / 12, rtol=1e-14)
    # Eq. 54: ends carry one element's half, inner nodes two
    np.testing.assert_allclose(m[0], rho_A * h / 2, rtol=1e-14)
    if n_elements > 1:
        np.testing.assert_allclose(m[3], rho_A * h, rtol=1e-14)
        np.testing.assert_allclose(m[5], rho_A * h ** 3 / 12, rtol=1e-14)


def test_load_is_the_hat_pulses_at_the_left_end():
    model = toss_rule()
    for t, F, M in [(0.0, 0, 0), (0.0025, 100, 5), (0.005, 200, 10), (0.0075, 100, 5),
                    (0.01, 0, 0), (0.02, 0, 0), (-0.001, 0, 0)]:
        p = model.load(t)
        assert p.shape == (model.n_dof,)
        np.testing.assert_allclose(p[1:3], [F, M], atol=1e-12)
        assert np.count_nonzero(p[[0] + list(range(3, model.n_dof))]) == 0
    custom = toss_rule(2, force_amplitude=-50.0, moment_amplitude=0.0, load_time=0.002)
    np.testing.assert_allclose(custom.load(0.003)[1:3], [-25.0, 0.0])


def test_free_vibration_spectrum():
    # three rigid modes; the first bending mode of a fine mesh near the
    # free-free Euler-Bernoulli value ω = 4.730² / L² · sqrt(EJ/ρA)
    model = toss_rule(60)
    K = model.stiffness(np.zeros(model.n_dof)).toarray()
    omega2 = sla.eigh(K, np.diag(model.mass), eigvals_only=True)
    assert np.all(np.abs(omega2[:3]) < 1e-6 * omega2[3])
    rho_A = 7850 * 0.030 * 0.002
    omega_eb = 4.7300408 ** 2 / 0.5 ** 2 * math.sqrt(model.EJ / rho_A)
    period = 2 * math.pi / math.sqrt(omega2[3])
    assert period == pytest.approx(2 * math.pi / omega_eb, rel=0.01)
    assert period == pytest.approx(0.0235, abs=0.001)


# -- quantities -----------------------------------------------------------------

def test_quantities_shapes_and_values():
    model = toss_rule(6)
    rng = np.random.default_rng(6)
    u = bent_states(model, rng, 4)
    v = rng.standard_normal(u.shape)
    v[2, 2::3] = 7.5                                      # spin at 7.5 rad/s
    q = model.quantities(np.linspace(0, 0.1, 4), u, v)
    assert set(q) == {"u", "alpha_mv", "m_c", "alpha_t_mv", "N_c"}
    assert q["u"].shape == (4, model.n_dof)
    for name in ("alpha_mv", "m_c", "alpha_t_mv", "N_c"):
        assert q[name].shape == (4, 1), name
    a = u[:, 2::3]
    np.testing.assert_allclose(q["alpha_mv"][:, 0], (0.5 * (a[:, 1:] + a[:, :-1])).mean(axis=1))
    np.testing.assert_allclose(q["alpha_t_mv"][2], [7.5])
    # one state at a time gives the same as the batch
    q1 = model.quantities(np.array([0.0]), u[1], v[1])
    for name in q1:
        np.testing.assert_allclose(q1[name], q[name][1:2])


@pytest.mark.parametrize("n_elements, chi_c", [(2, 0.25), (3, 7 / 36), (1, 0.25)])
def test_central_value_even_and_odd(n_elements, chi_c):
    # α = s³ on L = 0.5: χ_e = (s_j³ − s_i³)/h.
    # N_el = 2: the centre is a node, χ = (0.0625 + 0.4375)/2 = 0.25;
    # N_el = 3: the central element, ((1/3)³ − (1/6)³)·6 = 7/36;
    # N_el = 1: the only element, 0.5³/0.5 = 0.25.
    model = toss_rule(n_elements)
    s = model.node_coordinates[:, 0]
    u = np.column_stack([np.zeros_like(s), np.zeros_like(s), s ** 3]).ravel()
    q = model.quantities(np.zeros(1), u[None], np.zeros((1, model.n_dof)))
    np.testing.assert_allclose(q["m_c"], [[model.EJ * chi_c]], rtol=1e-12)
    # axial strain at the centre: ε = cos α_o − 1 with no translation
    a = 0.5 * (u[2::3][1:] + u[2::3][:-1])
    eps = np.cos(a) - 1
    eps_c = (eps[n_elements // 2 - 1] + eps[n_elements // 2]) / 2 if n_elements % 2 == 0 \
        else eps[n_elements // 2]
    np.testing.assert_allclose(q["N_c"], [[model.EA * eps_c]], rtol=1e-12)


# -- validation -----------------------------------------------------------------

@pytest.mark.parametrize("kwargs, name", [
    ({"n_elements": 0}, "n_elements"),
    ({"n_elements": 2.5}, "n_elements"),
    ({"n_elements": True}, "n_elements"),
    ({"n_elements": "6"}, "n_elements"),
    ({"length": 0.0}, "length"),
    ({"width": -0.03}, "width"),
    ({"thickness": float("nan")}, "thickness"),
    ({"E": float("inf")}, "E"),
    ({"nu": 0.5}, "nu"),
    ({"nu": -1.0}, "nu"),
    ({"shear_factor": 0.0}, "shear_factor"),
    ({"rho": "steel"}, "rho"),
    ({"force_amplitude": float("nan")}, "force_amplitude"),
    ({"moment_amplitude": None}, "moment_amplitude"),
    ({"load_time": 0.0}, "load_time"),
])
def test_invalid_parameters_are_rejected(kwargs, name):
    with pytest.raises(ValueError, match=name):
        TossRule(**kwargs)


def test_numpy_integer_element_count_is_accepted():
    assert toss_rule(np.int64(4)).n_elements == 4


# -- integration and size --------------------------------------------------------

def test_short_hfdi_run_conserves_the_blow():
    model = toss_rule()
    result = hfdi.integrate(model, "hfdi", 0.01, target_iterations=4.0)
    assert result.success, result.message
    assert result.t[-1] == pytest.approx(0.01)
    assert np.all(np.isfinite(result.u))
    # the pulses end at 2 t1 = 0.01: linear momentum = ∫F dt = 200 · 0.005 = 1 N·s,
    # nothing along x
    m, v = model.mass, result.v[-1]
    assert np.sum(m[1::3] * v[1::3]) == pytest.approx(1.0, rel=0.02)
    assert abs(np.sum(m[0::3] * v[0::3])) < 1e-6
    # the blow at the left end turns the rule clockwise
    q = model.quantities(result.t, result.u, result.v)
    assert q["alpha_t_mv"][-1, 0] < -20.0
    assert q["alpha_mv"][-1, 0] < 0.0


@pytest.mark.parametrize("n_elements", [60, 600])
def test_finer_meshes_build_and_evaluate(n_elements):
    model = toss_rule(n_elements)
    assert model.n_dof == 3 * (n_elements + 1)
    rng = np.random.default_rng(n_elements)
    u = bent_states(model, rng, 1)[0]
    w = rng.standard_normal(model.n_dof)
    f = model.internal_force(u)
    K = model.stiffness(u)
    T = model.stiffness_derivative(u, w)
    assert f.shape == (model.n_dof,) and np.all(np.isfinite(f))
    assert sp.issparse(K) and sp.issparse(T)
    assert K.nnz == T.nnz == 27 * (n_elements + 1) - 18
    assert np.all(np.isfinite(K.data)) and np.all(np.isfinite(T.data))
    assert np.isfinite(model.potential_energy(u))
    # a cheap derivative spot check along one direction
    d = rng.standard_normal(model.n_dof) * 1e-7
    df = model.internal_force(u + d) - model.internal_force(u - d)
    np.testing.assert_allclose(df, 2 * (K @ d), rtol=0, atol=1e-5 * np.abs(K @ d).max())
