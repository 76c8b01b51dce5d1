"""The tetrahedra (Section 5.2) and the articulated system (Section 5.3)."""
import math

import numpy as np
import pytest

import hfdi
from hfdi.models.articulated import Articulated, articulated, relative_angle
from hfdi.models.loads import hat
from hfdi.models.tetrahedra import PAIRS_I, PAIRS_J, Tetrahedra, tetrahedra
from validation.experiments import experiment


# -- helpers ------------------------------------------------------------------

def rotation_3d(rng):
    """A random proper rotation of space."""
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def rotation_2d(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


def blockdiag(R, n):
    return np.kron(np.eye(n), R)


def tetrahedra_states(rng, n):
    """The paper's tetrahedron distorted by up to ±0.3, rotated and moved anywhere."""
    base = tetrahedra().initial_displacement.reshape(4, 3)
    states = []
    for _ in range(n):
        x = base + rng.uniform(-0.3, 0.3, (4, 3))
        x = x @ rotation_3d(rng).T + rng.uniform(-10, 10, 3)
        states.append(x.ravel())
    return np.array(states)


def chain(x1, a1, a2, r1=0.5, r2=0.5):
    """Articulated state from mass 1's position, the link angles and lengths."""
    x1 = np.asarray(x1, float)
    x2 = x1 + r1 * np.array([math.cos(a1), math.sin(a1)])
    x3 = x2 + r2 * np.array([math.cos(a2), math.sin(a2)])
    return np.concatenate([x1, x2, x3])


def articulated_states(rng, n):
    """Random chains: links of 0.4–0.6 at any angle, hinge bent by up to ±2.5 rad."""
    states = []
    for _ in range(n):
        a1 = rng.uniform(-np.pi, np.pi)
        states.append(chain(rng.uniform(-3, 3, 2), a1, a1 + rng.uniform(-2.5, 2.5),
                            rng.uniform(0.4, 0.6), rng.uniform(0.4, 0.6)))
    return np.array(states)


def articulated_states_near_pi():
    """Chains where a link's own angle is at or near ±π."""
    eps = 1e-3
    return np.array([
        chain([0.3, -0.2], np.pi - eps, np.pi - 2 * eps),        # chain turned by ~π
        chain([0.3, -0.2], -np.pi + eps, -np.pi + 3 * eps),
        chain([0.0, 0.0], np.pi, np.pi, 0.52, 0.47),             # exactly along −x
        chain([1.0, 1.0], np.pi - eps, -np.pi + eps),            # link 2→3 past the axis
        chain([1.0, 1.0], -np.pi + eps, np.pi - eps),            # link 1→2 past the axis
        chain([-2.0, 0.5], np.pi - 0.2, -np.pi + 0.1, 0.55, 0.45),
        chain([0.0, 2.0], 0.5, np.pi - 1e-6),                    # bent, link 2 on −x
        chain([0.0, 2.0], -2.9, 3.0, 0.45, 0.52),
    ])


# -- load history ---------------------------------------------------------------

def test_hat_values_scalar_and_array():
    assert hat(0.5, 5.0, 1.0) == pytest.approx(2.5)
    assert hat(1.0, 5.0, 1.0) == pytest.approx(5.0)
    assert hat(1.5, 5.0, 1.0) == pytest.approx(2.5)
    assert hat(2.0, 5.0, 1.0) == pytest.approx(0.0, abs=1e-15)
    assert hat(-0.1, 5.0, 1.0) == 0.0
    assert hat(2.5, 5.0, 1.0) == 0.0
    assert isinstance(hat(0.3, 5.0, 1.0), float)
    t = np.array([[-1.0, 0.0, 0.0125], [0.025, 0.0375, 0.06]])
    expected = np.array([[0.0, 0.0, 100.0], [200.0, 100.0, 0.0]])
    np.testing.assert_allclose(hat(t, 200.0, 0.025), expected, atol=1e-12)
    assert hat(t, 200.0, 0.025).shape == t.shape


def test_hat_impulse_and_bad_rise_time():
    t = np.linspace(-1.0, 3.0, 40001)
    impulse = np.trapezoid(hat(t, 5.0, 1.0), t) if hasattr(np, "trapezoid") \
        else np.trapz(hat(t, 5.0, 1.0), t)
    assert impulse == pytest.approx(5.0, rel=1e-6)
    for bad in (0.0, -1.0, math.inf):
        with pytest.raises(ValueError, match="t1"):
            hat(0.5, 1.0, bad)


def test_model_loads():
    tet = tetrahedra()
    p = tet.load(0.5)
    assert p.shape == (12,)
    np.testing.assert_array_equal(p, [2.5] + [0.0] * 11)
    np.testing.assert_array_equal(tet.load(2.5), np.zeros(12))
    art = articulated()
    p = art.load(0.0375)
    assert p.shape == (6,)
    np.testing.assert_allclose(p, [0.0, 100.0, 0.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(art.load(0.06), np.zeros(6))
    assert tet.load_rate is None and art.load_rate is None


# -- tetrahedra -----------------------------------------------------------------

def test_tetrahedra_data():
    m = tetrahedra()
    assert m.n_dof == 12
    np.testing.assert_array_equal(m.mass, np.ones(12))
    assert m.damping is None
    np.testing.assert_array_equal(m.initial_displacement,
                                  [0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1])
    np.testing.assert_array_equal(m.initial_velocity, np.zeros(12))
    np.testing.assert_allclose(m.rest_length, [1, 1, 1, math.sqrt(2), math.sqrt(2),
                                               math.sqrt(2)])
    assert m.u_scale == 1.0
    table_3 = experiment("tetrahedra")
    assert table_3.observation_time == 50.0
    for scheme in ("newmark", "bathe", "hfdi"):
        assert tuple(table_3.targets[scheme]) == (3.0, 3.5, 4.0, 4.5)
    assert m.parameters()["k_stiff"] == 1e3 and m.parameters()["k_soft"] == 1.0


def test_tetrahedra_initial_state_is_force_free_and_stiff_frequency():
    m = tetrahedra()
    u0 = m.initial_displacement
    np.testing.assert_allclose(m.internal_force(u0), 0, atol=1e-13)
    assert m.potential_energy(u0) == pytest.approx(0.0, abs=1e-13)
    # the stiff spring 1–2 (k = 10³, reduced mass ½): ω = (2k)^{1/2} ≈ 44.7 rad/s
    omega = np.sqrt(np.linalg.eigvalsh(m.stiffness(u0)).max())
    assert omega == pytest.approx(math.sqrt(2e3), rel=2e-3)


def test_tetrahedra_derivatives_match_finite_differences():
    m = tetrahedra()
    check = hfdi.check_derivatives(m, tetrahedra_states(np.random.default_rng(11), 12))
    assert check.samples == 12
    assert check.worst < 1e-7, check


def test_tetrahedra_soft_springs_are_checked_too():
    # with k_stiff = 10³ the soft springs hardly show in ‖K w‖; equal constants expose them
    m = tetrahedra(k_stiff=1.0)
    check = hfdi.check_derivatives(m, tetrahedra_states(np.random.default_rng(12), 10))
    assert check.worst < 1e-7, check


def test_tetrahedra_spring_law():
    # stretch only the pair 1–2 to r = 1.5: V and φ' from Eqs. 45–46 by hand
    m = tetrahedra()
    u = m.initial_displacement.copy()
    u[3] = 1.5
    r = m.distances(u)
    assert r[0] == pytest.approx(1.5)
    k, r0 = 1e3, 1.0
    dphi = k / 3 * (1.5 - (r0 / 1.5) ** 2 * r0)
    q = m.quantities(np.zeros(1), u[None], np.zeros((1, 12)))
    np.testing.assert_allclose(q["f"][0, 0:3], [dphi, 0, 0], rtol=1e-14)
    # particle 2 is pulled back towards particle 1 by −f^{12}, particle 1 forward
    f = m.internal_force(u).reshape(4, 3)
    assert f[1, 0] > 0 and f[0, 0] < 0
    V = sum(kk / 6 * (rr ** 2 + (2 * r00 / rr - 3) * r00 ** 2)
            for kk, rr, r00 in zip(m.spring_constant, r, m.rest_length))
    assert m.potential_energy(u) == pytest.approx(V, rel=1e-13)


def test_tetrahedra_quantities_shapes_and_pair_forces():
    m = tetrahedra()
    rng = np.random.default_rng(3)
    u = tetrahedra_states(rng, 7)
    v = rng.standard_normal((7, 12))
    q = m.quantities(np.linspace(0, 1, 7), u, v)
    assert set(q) == {"u", "f"}
    assert q["u"].shape == (7, 12) and q["f"].shape == (7, 18)
    np.testing.assert_array_equal(q["u"], u)
    for n in range(7):
        x = u[n].reshape(4, 3)
        fq = q["f"][n].reshape(6, 3)
        f = np.zeros((4, 3))
        for p, (i, j) in enumerate(zip(PAIRS_I, PAIRS_J)):
            d = x[j] - x[i]
            r = np.linalg.norm(d)
            k, r0 = m.spring_constant[p], m.rest_length[p]
            expected = k / 3 * (r - (r0 / r) ** 2 * r0) * d / r
            np.testing.assert_allclose(fq[p], expected, rtol=1e-12, atol=1e-14)
            f[j] += fq[p]
            f[i] -= fq[p]
        # the pair forces add up to the internal force
        np.testing.assert_allclose(m.internal_force(u[n]), f.ravel(), rtol=1e-12,
                                   atol=1e-12 * np.abs(f).max())


def test_tetrahedra_translation_and_rotation_invariance():
    m = tetrahedra()
    rng = np.random.default_rng(4)
    u = tetrahedra_states(rng, 1)[0]
    w = rng.standard_normal(12)
    f, K, T = m.internal_force(u), m.stiffness(u), m.stiffness_derivative(u, w)
    scale = np.abs(K).max()
    # translation
    shift = np.tile(rng.standard_normal(3), 4)
    np.testing.assert_allclose(m.internal_force(u + shift), f, atol=1e-10 * scale)
    np.testing.assert_allclose(m.stiffness(u + shift), K, atol=1e-10 * scale)
    for axis in np.eye(3):
        np.testing.assert_allclose(K @ np.tile(axis, 4), 0, atol=1e-10 * scale)
    # rotation: f(Qu) = Q f(u), K(Qu) = Q K Qᵀ, T(Qu)[Qw] = Q T(u)[w] Qᵀ
    Q = blockdiag(rotation_3d(rng), 4)
    np.testing.assert_allclose(m.internal_force(Q @ u), Q @ f, atol=1e-10 * scale)
    np.testing.assert_allclose(m.stiffness(Q @ u), Q @ K @ Q.T, atol=1e-10 * scale)
    np.testing.assert_allclose(m.stiffness_derivative(Q @ u, Q @ w), Q @ T @ Q.T,
                               atol=1e-10 * np.abs(T).max())
    np.testing.assert_allclose(K, K.T, atol=1e-12 * scale)
    np.testing.assert_allclose(T, T.T, atol=1e-12 * np.abs(T).max())


def test_tetrahedra_short_hfdi_run():
    m = tetrahedra()
    res = hfdi.integrate(m, "hfdi", 3.0, target_iterations=4.0)
    assert res.success, res.message
    assert res.t[-1] == pytest.approx(3.0)
    assert np.all(np.isfinite(res.u))
    # internal forces conserve momentum: only the x load (impulse 5) changes it
    momentum = (res.v[-1] * m.mass).reshape(4, 3).sum(axis=0)
    np.testing.assert_allclose(momentum[1:], 0, atol=1e-9)
    assert momentum[0] == pytest.approx(5.0, rel=0.05)


@pytest.mark.parametrize("kwargs, name", [
    ({"k_stiff": 0.0}, "k_stiff"), ({"k_stiff": -1.0}, "k_stiff"),
    ({"k_soft": math.nan}, "k_soft"), ({"load_time": 0.0}, "load_time"),
    ({"load_amplitude": math.inf}, "load_amplitude"), ({"load_amplitude": "x"}, "load_amplitude"),
    ({"masses": (1, 1, 1)}, "masses"), ({"masses": (1, 1, 0, 1)}, "masses"),
    ({"positions": np.zeros((4, 3))}, "positions"), ({"v0": np.zeros(3)}, "v0"),
])
def test_tetrahedra_rejects_bad_parameters(kwargs, name):
    with pytest.raises(ValueError, match=name):
        Tetrahedra(**kwargs)


# -- articulated ----------------------------------------------------------------

def test_articulated_data():
    m = articulated()
    assert m.n_dof == 6
    np.testing.assert_array_equal(m.mass, np.ones(6))
    assert m.damping is None
    np.testing.assert_array_equal(m.initial_displacement, [0, 0, 0.5, 0, 1, 0])
    np.testing.assert_array_equal(m.initial_velocity, np.zeros(6))
    assert m.u_scale == 0.5
    table_4 = experiment("articulated")
    assert table_4.observation_time == 0.5 and table_4.long_observation_time == 3.0
    for scheme in ("newmark", "bathe", "hfdi"):
        assert tuple(table_4.targets[scheme]) == (3.0, 3.5, 4.0, 4.5, 5.0)
    assert m.parameters()["k_e"] == 1e7 and m.parameters()["k_f"] == 1e3


def test_articulated_initial_state_is_force_free():
    m = articulated()
    u0 = m.initial_displacement
    np.testing.assert_array_equal(m.internal_force(u0), np.zeros(6))
    assert m.potential_energy(u0) == 0.0
    # bending mode of the straight chain: ω² = 6 k_f / h²
    ev = np.linalg.eigvalsh(m.stiffness(u0))
    assert np.sort(ev)[3] == pytest.approx(6e3 / 0.25, rel=1e-9)


def test_relative_angle_sign_and_shape():
    # link 1→2 along +x, link 2→3 turned by +0.1: Δα = α12 − α23 = −0.1
    assert relative_angle(chain([0, 0], 0.0, 0.1)) == pytest.approx(-0.1)
    assert relative_angle(chain([0, 0], 0.3, 0.1)) == pytest.approx(0.2)
    u = articulated_states(np.random.default_rng(5), 6).reshape(2, 3, 6)
    assert relative_angle(u).shape == (2, 3)


def test_articulated_derivatives_match_finite_differences():
    m = articulated()
    states = np.vstack([articulated_states(np.random.default_rng(21), 12),
                        articulated_states_near_pi()])
    check = hfdi.check_derivatives(m, states)
    assert check.samples == 20
    assert check.worst < 1e-7, check


def test_articulated_hinge_derivatives_match_finite_differences():
    # with k_e = 10⁷ the hinge hardly shows in ‖K w‖; a soft link exposes it
    m = articulated(k_e=1.0)
    states = np.vstack([articulated_states(np.random.default_rng(22), 12),
                        articulated_states_near_pi()])
    check = hfdi.check_derivatives(m, states)
    assert check.worst < 1e-7, check


def test_articulated_continuous_across_minus_x_axis():
    m = articulated()
    for eps in (1e-6, 1e-9):
        for x1, other in (([0.2, 0.1], 2.9), ([-1.0, 0.4], -2.8)):
            # link 1→2 just above and just below the negative x axis
            above = chain(x1, np.pi - eps, other, 0.52, 0.47)
            below = chain(x1, -np.pi + eps, other, 0.52, 0.47)
            # the per-link atan2 difference jumps by 2π here...
            naive = [math.atan2(u[3] - u[1], u[2] - u[0]) - math.atan2(u[5] - u[3], u[4] - u[2])
                     for u in (above, below)]
            assert abs(abs(naive[0] - naive[1]) - 2 * np.pi) < 1e-3
            # ...the model's Δα, V, f and K do not
            assert abs(relative_angle(above) - relative_angle(below)) < 10 * eps
            assert abs(m.potential_energy(above) - m.potential_energy(below)) < 1e-3 * eps * 1e7
            np.testing.assert_allclose(m.internal_force(above), m.internal_force(below),
                                       atol=1e8 * eps)
            np.testing.assert_allclose(m.stiffness(above), m.stiffness(below), atol=1e8 * eps)
        # Δα is continuous on a path that turns the whole chain through ±π
        angles = np.linspace(np.pi - 0.01, np.pi + 0.01, 201)
        path = np.array([chain([0, 0], a, a + 0.3) for a in angles])
        da = relative_angle(path)
        np.testing.assert_allclose(da, -0.3, atol=1e-12)


def test_articulated_quantities_shapes():
    m = articulated()
    rng = np.random.default_rng(6)
    u = articulated_states(rng, 5)
    q = m.quantities(np.linspace(0, 1, 5), u, rng.standard_normal((5, 6)))
    assert set(q) == {"u", "delta_alpha"}
    assert q["u"].shape == (5, 6) and q["delta_alpha"].shape == (5, 1)
    np.testing.assert_allclose(q["delta_alpha"][:, 0], [m.delta_alpha(x) for x in u])
    r = m.link_lengths(u[0])
    V = 0.5e7 * np.sum((r - 0.5) ** 2) + 0.5e3 * q["delta_alpha"][0, 0] ** 2
    assert m.potential_energy(u[0]) == pytest.approx(V, rel=1e-13)


def test_articulated_translation_and_rotation_invariance():
    m = articulated()
    rng = np.random.default_rng(7)
    for u in (articulated_states(rng, 1)[0], articulated_states_near_pi()[3]):
        w = rng.standard_normal(6)
        f, K, T = m.internal_force(u), m.stiffness(u), m.stiffness_derivative(u, w)
        scale, tscale = np.abs(K).max(), np.abs(T).max()
        shift = np.tile(rng.standard_normal(2), 3)
        np.testing.assert_allclose(m.internal_force(u + shift), f, atol=1e-9 * scale)
        np.testing.assert_allclose(m.stiffness(u + shift), K, atol=1e-9 * scale)
        for axis in np.eye(2):
            np.testing.assert_allclose(K @ np.tile(axis, 3), 0, atol=1e-9 * scale)
        # rotations, including through ±π for the links
        for angle in (0.7, np.pi, -2.0, rng.uniform(-np.pi, np.pi)):
            Q = blockdiag(rotation_2d(angle), 3)
            assert relative_angle(Q @ u) == pytest.approx(relative_angle(u), abs=1e-12)
            np.testing.assert_allclose(m.internal_force(Q @ u), Q @ f, atol=1e-9 * scale)
            np.testing.assert_allclose(m.stiffness(Q @ u), Q @ K @ Q.T, atol=1e-9 * scale)
            np.testing.assert_allclose(m.stiffness_derivative(Q @ u, Q @ w), Q @ T @ Q.T,
                                       atol=1e-9 * tscale)
        np.testing.assert_allclose(K, K.T, atol=1e-12 * scale)
        np.testing.assert_allclose(T, T.T, atol=1e-12 * tscale)


def test_articulated_short_hfdi_run():
    m = articulated()
    res = hfdi.integrate(m, "hfdi", 0.1, target_iterations=4.0)
    assert res.success, res.message
    assert res.t[-1] == pytest.approx(0.1)
    assert np.all(np.isfinite(res.u))
    momentum = (res.v[-1] * m.mass).reshape(3, 2).sum(axis=0)
    assert abs(momentum[0]) < 1e-9
    assert momentum[1] > 0
    # the links stay close to their rest length h
    r = np.array([m.link_lengths(u) for u in res.u])
    assert np.abs(r - 0.5).max() < 1e-3


@pytest.mark.parametrize("kwargs, name", [
    ({"k_e": 0.0}, "k_e"), ({"k_e": -1e7}, "k_e"), ({"k_f": -1.0}, "k_f"),
    ({"k_f": math.nan}, "k_f"), ({"h": 0.0}, "h"), ({"load_time": -0.1}, "load_time"),
    ({"load_amplitude": math.nan}, "load_amplitude"), ({"masses": (1, -1, 1)}, "masses"),
    ({"positions": [[0, 0], [0, 0], [1, 0]]}, "positions"), ({"v0": [0, 1]}, "v0"),
])
def test_articulated_rejects_bad_parameters(kwargs, name):
    with pytest.raises(ValueError, match=name):
        Articulated(**kwargs)


def test_articulated_accepts_zero_hinge_stiffness():
    m = articulated(k_f=0.0)
    # a bent chain with unstretched links: only the two axial springs' stiffness, rank 2
    u = chain([0.3, 0.2], 0.4, 1.5)
    np.testing.assert_allclose(m.internal_force(u), 0, atol=1e-6)
    K = m.stiffness(u)
    assert np.linalg.matrix_rank(K, tol=1e-6 * np.abs(K).max()) == 2


@pytest.mark.parametrize("name", [name for name in hfdi.models.available()
                                  if hfdi.models.get(name).FIXED_PARAMETERS])
def test_a_parameter_the_model_was_built_from_is_fixed_by_name(name):
    """The masses (and the toss rule's section and material) are turned into
    the mass matrix and the kernels' data when the model is built: assigned
    afterwards they were kept by the model and used by nothing, a new
    integrate ran the old structure. Now refused, naming the parameter and
    how to get the model asked for; their arrays are read-only, in copies
    and unpickled models too."""
    import copy
    import pickle
    model = hfdi.models.get(name)
    fixed = type(model).FIXED_PARAMETERS
    assert set(fixed) <= set(hfdi.models.describe(name))
    for parameter in fixed:
        value = getattr(model, parameter)
        with pytest.raises(AttributeError, match=f"{name} {parameter} is fixed once the model "
                                                 f"is built.*models.get\\('{name}', "
                                                 f"{parameter}=...\\)"):
            setattr(model, parameter, value)
        for other in (model, copy.deepcopy(model), pickle.loads(pickle.dumps(model))):
            held = getattr(other, parameter)
            if isinstance(held, np.ndarray):
                with pytest.raises(ValueError, match="read-only"):
                    held[0] = 2.0 * held[0]


@pytest.mark.parametrize("name, derived", [
    ("toss_rule", ("area", "inertia", "G", "EA", "GA", "EJ")), ("dumbbell", ("rest_length",))])
def test_data_derived_from_the_parameters_cannot_be_assigned(name, derived):
    """The toss rule's section data were plain attributes: an assigned area,
    J or G changed nothing (EA, GA and EJ had been computed from them), an
    assigned EA changed the kernels but not the parameters the model
    reports. They follow the parameters now and refuse an assignment by
    name."""
    model = hfdi.models.get(name)
    rebuilt = hfdi.models.get(name, **model.parameters())
    for attribute in derived:
        assert getattr(model, attribute) == getattr(rebuilt, attribute)
        with pytest.raises(AttributeError, match=f"{name} {attribute} is derived from the "
                                                 f"model's parameters"):
            setattr(model, attribute, 2.0 * getattr(model, attribute))
    if name == "toss_rule":
        w, t, E, nu = model.width, model.thickness, model.E, model.nu
        assert (model.EA, model.EJ) == pytest.approx((E * w * t, E * w * t ** 3 / 12))
        assert model.GA == pytest.approx(5 / 6 * E / (2 * (1 + nu)) * w * t)
        np.testing.assert_array_equal(model.params()[1:4], (model.EA, model.GA, model.EJ))


@pytest.mark.parametrize("name, change", [
    ("articulated", {"h": 0.7}), ("articulated", {"k_f": 5.0}),
    ("tetrahedra", {"k_soft": 2.0}), ("dumbbell", {"sigma": 0.9}),
    ("impact_oscillator", {"gap": 0.2})])
def test_a_model_rebuilt_from_its_parameters_is_the_model(name, change):
    """``get(name, **model.parameters())`` after a live parameter changed, and
    with a start of the user's: the same start, M and forces. (The
    articulated system reported no positions after ``h`` changed, and the
    dumbbell no start at all: the rebuilt chain started relaxed at the new h
    where the model started stretched.)"""
    for start in (False, True):
        model = hfdi.models.get(name)
        if start:
            model = hfdi.models.get(name, **{**model.parameters(), **_a_start(model)})
        for key, value in change.items():
            setattr(model, key, value)
        rebuilt = hfdi.models.get(name, **model.parameters())
        u = model.initial_displacement + 0.01
        for attribute in ("initial_displacement", "initial_velocity", "mass"):
            np.testing.assert_array_equal(getattr(rebuilt, attribute), getattr(model, attribute))
        np.testing.assert_array_equal(rebuilt.internal_force(u), model.internal_force(u))
        np.testing.assert_array_equal(rebuilt.load(0.01), model.load(0.01))


def _a_start(model):
    """A start other than the default, in the constructor's terms."""
    u0, v0 = model.initial_displacement + 0.05, model.initial_velocity + 0.5
    if model.name == "dumbbell":
        return {"u0": u0, "v0": v0}
    if model.name == "impact_oscillator":
        return {"u0": float(u0[0]), "v0": float(v0[0])}
    return {"positions": u0.reshape(-1, 2 if model.name == "articulated" else 3), "v0": v0}


def test_the_impact_oscillators_mass_is_its_mass_matrix():
    """Its parameter ``mass`` is M's one entry: an assigned M is the model's
    mass in its parameters and its exact events too (they kept the mass it
    was built with, 0.584 s for a first impact the run met at 0.789 s)."""
    from hfdi.models.impact_oscillator import exact_events
    model = hfdi.models.impact_oscillator()
    model.mass = np.array([2.0])
    rebuilt = hfdi.models.impact_oscillator(**model.parameters())
    assert model.parameters()["mass"] == 2.0
    np.testing.assert_array_equal(exact_events(model, 2.0)[0], exact_events(rebuilt, 2.0)[0])


@pytest.mark.parametrize("name", ["dumbbell", "articulated", "impact_oscillator"])
def test_a_length_scale_from_live_parameters_may_be_assigned(name):
    """u_scale follows the parameter it is computed from, and may be assigned
    as on any model (it could not, for a while)."""
    model = hfdi.models.get(name)
    model.u_scale = 0.25
    assert model.u_scale == 0.25 and hfdi.system.declared_u_scale(model) == 0.25
    assert hfdi.system.declared_u_scale(hfdi.models.get(name)) > 0


def test_a_live_parameter_still_changes_the_model():
    """The dumbbell's σ is read by its kernels at every call: a change is
    followed, and the rest length (its stretch output) with it."""
    model = hfdi.models.dumbbell()
    before = hfdi.integrate(model, "hfdi", 0.05, rtol=1e-6)
    model.sigma = 0.8
    assert model.rest_length == pytest.approx(0.8 * math.sqrt(5.0 / 3.0))
    after = hfdi.integrate(model, "hfdi", 0.05, rtol=1e-6)
    again = hfdi.integrate(hfdi.models.dumbbell(sigma=0.8), "hfdi", 0.05, rtol=1e-6)
    assert np.abs(after.u[-1] - before.u[-1]).max() > 1e-3
    np.testing.assert_array_equal(after.u[-1], again.u[-1])


def test_the_toss_rules_geometry_is_read_only():
    """element_length was the kernels' own h_e: an edit changed h_e, not 1/h_e
    nor the mass, a structure of no parameters."""
    model = hfdi.models.toss_rule()
    before = model.params().copy()
    for array in (model.element_length, model.node_coordinates):
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 1.0
    np.testing.assert_array_equal(model.params(), before)
