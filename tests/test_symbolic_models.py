"""Models from a sympy potential energy: derivatives, parameters, quantities,
sparse mode, input checks and integration of the ready-made examples."""
import math
import pickle
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
import sympy

import hfdi
from hfdi.models.symbolic import EnergyModel, elastic_pendulum, spring_chain
from problems import dumbbell_states


def rel(a, b):
    """Normwise relative difference of two arrays (dense or sparse)."""
    a = a.toarray() if sp.issparse(a) else np.asarray(a)
    b = b.toarray() if sp.issparse(b) else np.asarray(b)
    return np.linalg.norm(a - b) / np.linalg.norm(b)


def pendulum_states(rng, n):
    """Positions of the pendulum mass at radius 0.5–2 in any direction."""
    r = rng.uniform(0.5, 2.0, n)
    angle = rng.uniform(-np.pi, np.pi, n)
    return np.column_stack([r * np.sin(angle), -r * np.cos(angle)])


def symbolic_dumbbell(**kwargs):
    """The paper's dumbbell (Eq. 44) written as a sympy energy."""
    x1, y1, x2, y2, A, sigma = sympy.symbols("x1 y1 x2 y2 A sigma")
    r = sympy.sqrt((x2 - x1) ** 2 + (y2 - y1) ** 2)
    energy = A * ((sigma / r) ** 5 - (sigma / r) ** 3)
    return EnergyModel([x1, y1, x2, y2], energy, mass=np.ones(4),
                       parameters={A: 1e6, sigma: math.sqrt(3.0 / 5.0)},
                       initial_displacement=[0, 0, 1, 0], initial_velocity=[0, 10, 0, 5],
                       **kwargs), (A, sigma)


# -- derivatives ----------------------------------------------------------------

def test_elastic_pendulum_derivatives_match_finite_differences():
    model = elastic_pendulum()
    check = hfdi.check_derivatives(model, pendulum_states(np.random.default_rng(3), 20))
    assert check.samples == 20
    assert check.force < 1e-8
    assert check.stiffness < 1e-8
    assert check.stiffness_derivative < 1e-8


@pytest.mark.parametrize("n_masses", [1, 2, 7])
def test_spring_chain_derivatives_match_finite_differences(n_masses):
    model = spring_chain(n_masses=n_masses, k=2.0, k3=5.0)
    states = np.random.default_rng(4).uniform(-1.5, 1.5, (15, n_masses))
    check = hfdi.check_derivatives(model, states)
    assert check.force < 1e-8
    assert check.stiffness < 1e-8
    assert check.stiffness_derivative < 1e-8


def test_a_wrong_energy_model_fails_the_check():
    """The check above can fail: shift K of the pendulum and it does."""
    model = elastic_pendulum()
    wrong = hfdi.System(mass=model.mass, internal_force=model.internal_force,
                        stiffness=lambda u: model.stiffness(u) * 1.001,
                        stiffness_derivative=model.stiffness_derivative,
                        potential_energy=model.potential_energy,
                        initial_displacement=model.initial_displacement)
    check = hfdi.check_derivatives(wrong, pendulum_states(np.random.default_rng(5), 5))
    assert check.stiffness > 1e-5


@pytest.mark.slow
def test_dumbbell_energy_equals_hand_written_dumbbell():
    model, _ = symbolic_dumbbell()
    reference = hfdi.models.dumbbell()
    rng = np.random.default_rng(6)
    for u in dumbbell_states(rng, 25):
        w = rng.standard_normal(4)
        assert rel(model.internal_force(u), reference.internal_force(u)) < 1e-10
        assert rel(model.stiffness(u), reference.stiffness(u)) < 1e-10
        assert rel(model.stiffness_derivative(u, w), reference.stiffness_derivative(u, w)) < 1e-10
        assert abs(model.potential_energy(u) - reference.potential_energy(u)) \
            <= 1e-10 * abs(reference.potential_energy(u))


@pytest.mark.slow
def test_matrices_are_symmetric_and_hessian_is_exposed():
    model, _ = symbolic_dumbbell()
    u = dumbbell_states(np.random.default_rng(7), 1)[0]
    K = model.stiffness(u)
    T = model.stiffness_derivative(u, np.array([0.3, -0.2, 0.1, 0.5]))
    np.testing.assert_array_equal(K, K.T)
    np.testing.assert_array_equal(T, T.T)
    x1, y1, x2, y2 = model.dofs
    assert model.hessian.shape == (4, 4)
    assert sympy.simplify(model.hessian[0, 2] - model.energy.diff(x1, x2)) == 0


# -- parameters ---------------------------------------------------------------------

def test_parameters_change_the_result_without_rederivation(monkeypatch):
    model = spring_chain(n_masses=4, k=1.0, k3=4.0)
    fresh = spring_chain(n_masses=4, k=3.0, k3=0.5)   # derived with the new values
    u = np.array([0.3, -0.2, 0.5, 1.1])
    w = np.array([1.0, 0.5, -0.4, 0.2])
    before = model.internal_force(u)
    fresh.internal_force(u)                            # its functions made (on first use)

    def forbidden(*args, **kwargs):
        raise AssertionError("sympy was called: the model was re-derived")
    monkeypatch.setattr(sympy, "lambdify", forbidden)
    monkeypatch.setattr(sympy, "diff", forbidden)
    monkeypatch.setattr(sympy.Expr, "diff", forbidden)

    copy = model.with_parameters(k=3.0, k3=0.5)
    assert model.parameters() == {"k": 1.0, "k3": 4.0}    # the original is unchanged
    np.testing.assert_array_equal(model.internal_force(u), before)

    k_symbol = model.parameter_symbols[0]
    model.set_parameters({k_symbol: 3.0}, k3=0.5)          # by symbol and by name
    assert model.parameters() == {"k": 3.0, "k3": 0.5}
    assert rel(model.internal_force(u), before) > 0.1
    for m in (model, copy):
        np.testing.assert_allclose(m.internal_force(u), fresh.internal_force(u), rtol=1e-14)
        np.testing.assert_allclose(m.stiffness(u).toarray(), fresh.stiffness(u).toarray(),
                                   rtol=1e-14)
        np.testing.assert_allclose(m.stiffness_derivative(u, w).toarray(),
                                   fresh.stiffness_derivative(u, w).toarray(), rtol=1e-14)
        assert m.potential_energy(u) == pytest.approx(fresh.potential_energy(u), rel=1e-14)


@pytest.mark.slow
def test_dumbbell_parameters_follow_the_hand_written_model():
    model, (A, sigma) = symbolic_dumbbell()
    model.set_parameters({A: 2.5e5, sigma: 0.7})
    reference = hfdi.models.dumbbell(A=2.5e5, sigma=0.7)
    rng = np.random.default_rng(8)
    for u in dumbbell_states(rng, 5):
        w = rng.standard_normal(4)
        assert rel(model.internal_force(u), reference.internal_force(u)) < 1e-10
        assert rel(model.stiffness_derivative(u, w), reference.stiffness_derivative(u, w)) < 1e-10


@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
def test_a_parameter_changed_mid_run_continues_as_a_run_started_there(scheme):
    """set_parameters between two advances: the run goes on as a run of the
    changed model started from the state reached (force, acceleration and
    potential energy of the changed model, no history), and the energy balance
    counts nothing for the change itself."""
    h, t1, t2 = 0.01, 0.5, 1.0
    model = spring_chain(3)
    itg = hfdi.Integrator(model, scheme, step=h, compiled=False)
    assert itg.advance(t1)
    reached, error_before = itg.state, itg.energy_error
    model.set_parameters(k=30.0)
    assert itg.advance(t2)
    fresh = hfdi.Integrator(spring_chain(3, k=30.0), scheme, step=h, compiled=False,
                            t0=reached.t, u0=reached.u, v0=reached.v)
    assert fresh.advance(t2)
    assert itg.statistics.steps - 50 == fresh.statistics.steps == 50
    np.testing.assert_allclose(itg.state.u, fresh.state.u, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(itg.state.v, fresh.state.v, rtol=1e-12, atol=1e-14)
    assert itg.total_energy == pytest.approx(fresh.total_energy, rel=1e-12)
    # the change of the potential (about 22 J here) is not an energy error
    assert abs(itg.energy_error - error_before - fresh.energy_error) \
        < 1e-9 * itg.total_energy


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")   # the overflow asked for
def test_a_changed_model_that_cannot_be_evaluated_stops_the_run():
    x = sympy.Symbol("x")
    c = sympy.Symbol("c")
    model = EnergyModel((x,), x ** 2 / 2 + c * x ** 4, [1.0], parameters={c: 0.0},
                        initial_displacement=[2.0])
    itg = hfdi.Integrator(model, "newmark", step=0.01, compiled=False)
    assert itg.advance(0.1)
    state = itg.state
    model.set_parameters(c=1e308)       # the force overflows
    assert not itg.advance(0.2)
    assert itg.status == hfdi.Status.MODEL_ERROR and "changed model" in itg.message
    assert itg.t == state.t
    np.testing.assert_array_equal(itg.state.u, state.u)


def test_set_parameters_rejects_unknown_names_and_bad_values():
    model = elastic_pendulum()
    with pytest.raises(ValueError, match="not a parameter"):
        model.set_parameters(m=2.0)
    with pytest.raises(ValueError, match="finite"):
        model.set_parameters(k=float("nan"))
    with pytest.raises(ValueError, match="real number"):
        model.set_parameters(k="stiff")
    assert model.parameters() == {"k": 30.0, "L": 1.0, "g": 9.81}


def test_model_pickles_without_rederivation():
    model = spring_chain(n_masses=3)
    model.set_parameters(k3=7.0)
    clone = pickle.loads(pickle.dumps(model))
    u = np.array([0.2, 0.9, 1.5])
    np.testing.assert_array_equal(clone.internal_force(u), model.internal_force(u))
    assert clone.parameters() == {"k": 1.0, "k3": 7.0}


# -- quantities and vectorised evaluation ------------------------------------------

def test_quantities_are_vectorised_over_times():
    model = elastic_pendulum(mass=2.0)
    rng = np.random.default_rng(9)
    n = 7
    t = np.linspace(0.0, 1.0, n)
    u = pendulum_states(rng, n)
    v = rng.standard_normal((n, 2))
    q = model.quantities(t, u, v)
    assert set(q) == {"u", "length", "angle", "energy"}
    assert q["u"].shape == (n, 2)
    for name in ("length", "angle", "energy"):
        assert q[name].shape == (n, 1)
    np.testing.assert_allclose(q["length"][:, 0], np.hypot(u[:, 0], u[:, 1]), rtol=1e-14)
    np.testing.assert_allclose(q["angle"][:, 0], np.arctan2(u[:, 0], -u[:, 1]), rtol=1e-14)
    energy = [model.potential_energy(ui) + 0.5 * 2.0 * vi @ vi for ui, vi in zip(u, v)]
    np.testing.assert_allclose(q["energy"][:, 0], energy, rtol=1e-13)
    # the potential energy is vectorised too
    np.testing.assert_allclose(model.potential_energy(u),
                               [model.potential_energy(ui) for ui in u], rtol=1e-14)


def test_constant_and_time_dependent_quantities_broadcast():
    x, y, vx, vy, t, c = sympy.symbols("x y vx vy t c")
    model = EnergyModel([x, y], x ** 2 + x * y ** 2, mass=[1.0, 1.0], parameters={c: 3.0},
                        velocities=[vx, vy], time=t,
                        quantities={"mixed": [x, 0, c, t * vy], "one": sympy.Integer(1),
                                    "u": [y, x]})
    n = 5
    times = np.arange(n, dtype=float)
    u = np.arange(2 * n, dtype=float).reshape(n, 2)
    v = -u
    q = model.quantities(times, u, v)
    assert q["mixed"].shape == (n, 4)
    assert q["one"].shape == (n, 1)
    np.testing.assert_array_equal(q["mixed"], np.column_stack([u[:, 0], np.zeros(n),
                                                               np.full(n, 3.0),
                                                               times * v[:, 1]]))
    np.testing.assert_array_equal(q["one"], np.ones((n, 1)))
    np.testing.assert_array_equal(q["u"], u[:, ::-1])     # a user's "u" replaces the default
    single = model.quantities(2.0, u[0], v[0])             # one state: n = 1
    assert single["mixed"].shape == (1, 4)
    with pytest.raises(ValueError, match="velocities"):
        model.quantities(times, u)


def test_default_quantity_is_u_and_results_use_it():
    x = sympy.Symbol("x")
    model = EnergyModel(x, x ** 2 / 2 + x ** 4, mass=[1.0], initial_displacement=[0.5])
    res = hfdi.integrate(model, "newmark", 1.0, step=0.05)
    q = res.quantities(model)
    assert list(q) == ["u"]
    np.testing.assert_array_equal(q["u"], res.u)


# -- sparse mode ------------------------------------------------------------------------

def test_sparse_mode_returns_csr_with_the_symbolic_pattern():
    n = 6
    chain = spring_chain(n_masses=n, k=1.5, k3=2.0)
    dense = EnergyModel(chain.dofs, chain.energy, chain.mass,
                        parameters=dict(zip(chain.parameter_symbols,
                                            chain.parameters().values())))
    assert chain.sparse and not dense.sparse
    tridiagonal = {(i, j) for i in range(n) for j in range(n) if abs(i - j) <= 1}
    rng = np.random.default_rng(10)
    # the pattern is structural: the same at a state where T vanishes (u = 0)
    for u in [np.zeros(n), *rng.uniform(-1, 1, (4, n))]:
        w = rng.standard_normal(n)
        K = chain.stiffness(u)
        T = chain.stiffness_derivative(u, w)
        for matrix in (K, T):
            assert sp.issparse(matrix) and matrix.format == "csr"
            assert matrix.shape == (n, n)
            assert matrix.has_canonical_format
            # the stored entries, explicit zeros included
            rows = np.repeat(np.arange(n), np.diff(matrix.indptr))
            cols = matrix.indices
            assert set(zip(rows.tolist(), cols.tolist())) == tridiagonal
        np.testing.assert_allclose(K.toarray(), dense.stiffness(u), rtol=0, atol=1e-15)
        np.testing.assert_allclose(T.toarray(), dense.stiffness_derivative(u, w),
                                   rtol=0, atol=1e-15)
    rows, cols = chain.stiffness_pattern
    assert set(zip(rows.tolist(), cols.tolist())) == tridiagonal


def test_sparse_pattern_skips_structural_zeros_of_T():
    # V = ½ x² + ½ (x − y)² + y⁴: K[0, :] is constant, so T lives on (1, 1) only
    x, y = sympy.symbols("x y")
    model = EnergyModel([x, y], x ** 2 / 2 + (x - y) ** 2 / 2 + y ** 4, mass=[1.0, 1.0],
                        sparse=True)
    K = model.stiffness([0.0, 0.5])
    T = model.stiffness_derivative([0.0, 0.5], [0.0, 2.0])
    assert K.nnz == 4
    assert T.nnz == 1
    np.testing.assert_array_equal(T.toarray(), [[0.0, 0.0], [0.0, 24 * 0.5 * 2.0]])
    np.testing.assert_array_equal(K.toarray(), [[2.0, -1.0], [-1.0, 1.0 + 12 * 0.25]])


def test_quadratic_energy_has_empty_T():
    x, y = sympy.symbols("x y")
    for sparse in (False, True):
        model = EnergyModel([x, y], x ** 2 + x * y + 2 * y ** 2, mass=[1.0, 2.0],
                            sparse=sparse)
        T = model.stiffness_derivative([1.0, 2.0], [0.5, 0.5])
        assert (T.toarray() if sparse else T).tolist() == [[0.0, 0.0], [0.0, 0.0]]
        K = model.stiffness([1.0, 2.0])
        assert (K.toarray() if sparse else K).tolist() == [[2.0, 1.0], [1.0, 4.0]]


# -- input checks -----------------------------------------------------------------------

def test_bad_input_is_rejected_with_clear_errors():
    x, y, z, a = sympy.symbols("x y z a")
    energy = x ** 2 + y ** 4

    def build(dofs=(x, y), energy=energy, mass=(1.0, 1.0), **kw):
        return EnergyModel(dofs, energy, mass, **kw)

    build()  # the valid reference
    with pytest.raises(ValueError, match=r"mass must have shape \(2,\)"):
        build(mass=[1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="mass"):
        build(mass=np.eye(3))
    with pytest.raises(ValueError, match="mass"):
        build(mass=sp.identity(3, format="csr"))
    with pytest.raises(ValueError, match="positive"):
        build(mass=[1.0, 0.0])
    with pytest.raises(ValueError, match="unknown symbols a, z"):
        build(energy=energy + a * z)
    with pytest.raises(ValueError, match="more than once"):
        build(dofs=(x, x))
    with pytest.raises(ValueError, match="used for two different symbols"):
        build(dofs=(x, sympy.Symbol("x", positive=True)), energy=x ** 2)
    with pytest.raises(ValueError, match="as dof and as parameter"):
        build(parameters={x: 1.0})
    with pytest.raises(ValueError, match="Symbols"):
        build(dofs=(x, x + y))
    with pytest.raises(ValueError, match="Symbol"):
        build(dofs="x y")
    with pytest.raises(ValueError, match="not a string"):
        build(energy="x**2 + y**4")
    with pytest.raises(ValueError, match="scalar"):
        build(energy=sympy.Matrix([x, y]))
    with pytest.raises(ValueError, match="undefined functions"):
        build(energy=sympy.Function("g")(x) + y ** 2)
    with pytest.raises(ValueError, match="parameter a must be a real number"):
        build(energy=a * energy, parameters={a: "big"})
    with pytest.raises(ValueError, match="finite"):
        build(energy=a * energy, parameters={a: np.inf})
    with pytest.raises(ValueError, match="damping"):
        build(damping=np.ones((3, 3)))
    with pytest.raises(ValueError, match="initial_displacement"):
        build(initial_displacement=[1.0])
    with pytest.raises(ValueError, match=r"load must be a callable t -> \(N,\) or 2 sympy"):
        build(load=[0.0, 1.0, 2.0])
    with pytest.raises(ValueError, match="load must be a sympy expression, not a string"):
        build(load=["0", "1"])
    with pytest.raises(ValueError, match="one symbol per degree of freedom"):
        build(velocities=[z])
    with pytest.raises(ValueError, match="quantity 'q' depends on unknown symbols z"):
        build(quantities={"q": [x, z]})
    with pytest.raises(ValueError, match="u_scale"):
        build(u_scale=0.0)
    with pytest.raises(ValueError, match="elastic_pendulum k"):
        elastic_pendulum(k=-1.0)
    with pytest.raises(ValueError, match="n_masses"):
        spring_chain(n_masses=0)


@pytest.mark.parametrize("where", ["energy", "load", "quantity"])
def test_names_that_would_be_printed_as_code_are_refused(where, tmp_path):
    """Only free symbols are renamed before the expressions become code
    (lambdify's, and the compiled kernels'): a bound variable's name, or a
    code-generation node's, would be written out verbatim."""
    from sympy.codegen.ast import FunctionCall
    marker = tmp_path / "ran"
    payload = f"[0][__import__('os').system('touch {marker}')]"
    x, t = sympy.symbols("x t")
    i = sympy.Symbol(payload, integer=True)
    bound = {"energy": sympy.Sum(i * x ** 4, (i, 1, 2)),
             "load": sympy.Product(i * t, (i, 1, 2)),
             "quantity": sympy.Integral(x * i, (i, 0, 1))}[where]
    kw = {"energy": {}, "load": dict(time=t, load=[bound]),
          "quantity": dict(quantities={"q": bound})}[where]
    energy = x ** 2 / 2 + (bound if where == "energy" else 0)
    with pytest.raises(ValueError, match=f"{where}.*bound variable"):
        model = EnergyModel([x], energy, [1.0], initial_displacement=[0.5], **kw)
        # (before the check: evaluating ran the payload)
        model.internal_force([0.5]), model.load(1.0), model.quantities(1.0, [0.5])
    with pytest.raises(ValueError, match="energy.*Subs"):
        EnergyModel([x], x ** 2 + sympy.Subs(x * i, i, 2), [1.0])
    with pytest.raises(ValueError, match="energy contains the symbols.*other than as free"):
        EnergyModel([x], x ** 2 + sympy.Limit(x * i, i, 0), [1.0])
    with pytest.raises(ValueError, match="energy.*code-generation node FunctionCall"):
        EnergyModel([x], x ** 2 + FunctionCall(f"__import__('os').system('touch {marker}')",
                                               [x]), [1.0]).internal_force([0.5])
    assert not marker.exists()


def _contact_model(**kw):
    """Two masses, the first against a contact spring beyond a gap, the second
    on ``|y|³`` and a one-sided spring: Max, Abs and Min of real symbols."""
    x, y = sympy.symbols("x y", real=True)
    c, g, a, b = sympy.symbols("c g a b", positive=True)
    energy = (x ** 2 / 2 + (y - x) ** 2 / 2 + c * sympy.Max(0, x - g) ** 2 / 2
              + a * sympy.Abs(y) ** 3 / 3 + b * sympy.Min(0, y) ** 2 / 2)
    return EnergyModel([x, y], energy, [1.0, 1.0], parameters={c: 50.0, g: 0.2, a: 3.0, b: 7.0},
                       **kw)


def test_max_min_and_abs_of_real_symbols_evaluate_with_their_kinks():
    """The derivatives of Max, Min and Abs bring DiracDelta, which has no
    value in numpy: it counts as 0, so f, K, T and V evaluate everywhere,
    on the kinks too (initial state)."""
    model = _contact_model(initial_displacement=[0.2, 0.0], initial_velocity=[1.0, -0.5])
    c, g, a, b = 50.0, 0.2, 3.0, 7.0

    def expected(u, w):
        x, y = u
        f = [x - (y - x) + c * max(0.0, x - g), (y - x) + a * y * abs(y) + b * min(0.0, y)]
        K = [[2.0 + c * (x > g), -1.0], [-1.0, 1.0 + 2 * a * abs(y) + b * (y < 0)]]
        T = [[0.0, 0.0], [0.0, 2 * a * np.sign(y) * w[1]]]
        V = (x ** 2 / 2 + (y - x) ** 2 / 2 + c * max(0.0, x - g) ** 2 / 2 + a * abs(y) ** 3 / 3
             + b * min(0.0, y) ** 2 / 2)
        return f, K, T, V

    rng = np.random.default_rng(5)
    for u in [[0.5, 0.3], [-0.1, -0.4], [0.3, -0.2], [0.1, 0.6]]:
        w = rng.standard_normal(2)
        f, K, T, V = expected(np.array(u), w)
        np.testing.assert_allclose(model.internal_force(u), f, rtol=1e-13)
        np.testing.assert_allclose(model.stiffness(u), K, rtol=1e-13)
        np.testing.assert_allclose(model.stiffness_derivative(u, w), T, rtol=1e-13, atol=1e-13)
        assert model.potential_energy(u) == pytest.approx(V, rel=1e-13)
    # on the kinks: finite, with sympy's Heaviside(0) = 1/2
    kink = model.initial_displacement
    np.testing.assert_allclose(model.internal_force(kink), [0.4, -0.2])
    np.testing.assert_allclose(model.stiffness(kink), [[2.0 + c / 4, -1.0], [-1.0, 1.0 + b / 4]])
    assert np.all(np.isfinite(model.stiffness_derivative(kink, [1.0, 1.0])))
    # a run through the kinks (starting on one fails the start's check of K)
    moving = _contact_model(initial_displacement=[0.0, 0.1], initial_velocity=[1.0, -0.5])
    res = hfdi.integrate(moving, "hfdi", 2.0, rtol=1e-6, compiled=False)
    assert res.success, res.message
    assert res.u[:, 0].max() > 0.2 and res.u[:, 1].min() < 0.0
    assert np.ptp(res.total_energy) < 1e-3 * abs(res.total_energy[0])


def test_evaluation_rejects_a_wrong_state_shape():
    model = elastic_pendulum()
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        model.internal_force([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"w must have shape \(2,\)"):
        model.stiffness_derivative([1.0, -1.0], [1.0])


def test_symbol_names_that_are_not_python_identifiers_work():
    # names like these cannot appear as such in generated Python code
    lam, dot, cse_name = sympy.symbols("lambda u.1 x0")
    model = EnergyModel([lam, dot], lam ** 4 + cse_name * (lam - dot) ** 2, mass=[1.0, 1.0],
                        parameters={cse_name: 2.0})
    np.testing.assert_allclose(model.internal_force([1.0, 0.5]), [4.0 + 2.0, -2.0])
    assert hfdi.check_derivatives(model, [[1.0, 0.5], [-0.3, 0.2]]).ok(1e-8)


# -- integration --------------------------------------------------------------------------

def test_hfdi_adaptive_run_of_the_pendulum_succeeds():
    model = elastic_pendulum()
    res = hfdi.integrate(model, "hfdi", model.observation_time, target_iterations=4.0)
    assert res.success, res.message
    assert res.t[-1] == pytest.approx(model.observation_time)
    assert res.stats.ntev > 0                      # the exact T[w] was used
    assert np.all(np.isfinite(res.u))
    # HFDI dissipates energy, it never creates it
    assert res.total_energy[-1] <= res.total_energy[0] + 1e-9 * abs(res.total_energy[0])


def test_hfdi_runs_the_sparse_chain():
    model = spring_chain(n_masses=8)
    res = hfdi.integrate(model, "hfdi", model.observation_time, target_iterations=4.0)
    assert res.success, res.message
    assert res.quantities(model)["extension"].shape == (res.t.size, 8)


# -- the user guide ----------------------------------------------------------------------

@pytest.mark.slow
def test_the_user_guide_examples_run():
    guide = Path(__file__).resolve().parents[1] / "docs" / "user-models.md"
    blocks = re.findall(r"```python\n(.*?)```", guide.read_text(encoding="utf-8"), re.S)
    assert len(blocks) >= 3
    namespace = {}
    for block in blocks:
        exec(compile(block, str(guide), "exec"), namespace)


def test_a_load_whose_rate_sympy_cannot_derive_is_refused_by_name():
    """|sin 2t| with a time symbol not declared real: sympy leaves
    Derivative(im(t)) in the rate, and lambdify's PrintMethodNotImplementedError
    escaped the constructor; now a ValueError that says what to declare."""
    x = sympy.Symbol("x", real=True)
    t = sympy.Symbol("t")
    with pytest.raises(ValueError, match="load rate could not be derived.*real"):
        EnergyModel([x], x ** 2 / 2, [1.0], time=t, load=[sympy.Abs(sympy.sin(2 * t))])
    t = sympy.Symbol("t", real=True)
    model = EnergyModel([x], x ** 2 / 2, [1.0], time=t, load=[sympy.Abs(sympy.sin(2 * t))])
    assert model.load_rate(0.3)[0] == pytest.approx(2 * math.cos(0.6))


@pytest.mark.parametrize("where, make, named", [
    ("energy", lambda x, t: dict(energy=x ** 2 / 2 + sympy.I * x), "energy"),
    ("energy", lambda x, t: dict(energy=x ** 2 / 2 + sympy.sqrt(-2) * x), "energy"),
    ("energy", lambda x, t: dict(energy=x ** 2 / 2 + sympy.log(-2) * x), "energy"),
    ("load", lambda x, t: dict(energy=x ** 2 / 2, load=[sympy.I * t], time=t), "load"),
    ("quantity", lambda x, t: dict(energy=x ** 2 / 2, quantities={"z": sympy.I * x}),
     "quantity 'z'"),
])
def test_complex_expressions_are_refused(where, make, named):
    """An energy (a load, a quantity) with an imaginary part ran with the
    imaginary part dropped; it is refused like the other complex inputs,
    naming what is complex and where."""
    x, t = sympy.symbols("x t")
    kwargs = make(x, t)
    energy = kwargs.pop("energy")
    with pytest.raises(ValueError) as info:
        EnergyModel([x], energy, mass=[1.0], initial_displacement=[1.0], **kwargs)
    message = str(info.value)
    assert message.startswith(f"{named} must be real, got the complex number "), message


def test_real_expressions_with_complex_looking_parts_are_taken():
    """exp(I*pi) is -1, Abs(I*x) is |x|: real numbers, taken."""
    x = sympy.Symbol("x", real=True)
    model = EnergyModel([x], sympy.exp(sympy.I * sympy.pi) * -x ** 2 / 2
                        + sympy.Abs(sympy.I * x), mass=[1.0])
    assert model.potential_energy([2.0]) == pytest.approx(4.0)


# -- the two derivation engines ----------------------------------------------------------

def _every_elementary_function():
    """An energy of three DOFs using every function symengine derives, a float,
    a rational, π and e, with states inside every function's domain."""
    x, y, z, c = sympy.symbols("x y z c")
    energy = (sympy.sin(x) * sympy.cos(y) + sympy.tan(z / 3) + sympy.exp(x * y / 4)
              + sympy.log(2 + x ** 2) + sympy.asin(y / 3) + sympy.acos(z / 4)
              + sympy.atan(x * z) + sympy.sinh(y / 2) * sympy.cosh(z / 5)
              + sympy.tanh(x - y) + sympy.asinh(z) + sympy.acosh(3 + y ** 2)
              + sympy.atanh(x / 4) + sympy.Float(0.1) * c * sympy.sqrt(1 + x ** 2 + z ** 2)
              + sympy.Rational(3, 7) * sympy.pi * (x - z) ** 4 + sympy.E ** (z / 7))
    return [x, y, z], energy, {c: 1.7}


@pytest.mark.slow
def test_symengine_and_sympy_derive_the_same_model(monkeypatch):
    """An elementary energy is derived by symengine; sympy's derivation of it
    (the route of any other energy) gives the same f, K, T and V to rounding,
    on the Python path and in the compiled kernels."""
    from hfdi.models import derivation
    dofs, energy, parameters = _every_elementary_function()
    assert derivation.elementary(energy)
    fast = EnergyModel(dofs, energy, np.ones(3), parameters=parameters)
    assert fast._derivation.engine == "symengine"
    kernels = fast.compiled_kernels()
    fast.internal_force(np.zeros(3))            # its functions made before symengine goes
    monkeypatch.setattr(derivation, "_symengine", lambda: None)
    slow = EnergyModel(dofs, energy, np.ones(3), parameters=parameters)
    assert slow._derivation.engine == "sympy"
    assert fast.stiffness_pattern[0].tolist() == slow.stiffness_pattern[0].tolist()
    rng = np.random.default_rng(3)
    params = fast.compiled_params()
    for _ in range(5):
        u, w = rng.uniform(-0.5, 0.5, 3), rng.standard_normal(3)
        assert rel(fast.internal_force(u), slow.internal_force(u)) < 1e-14
        assert rel(fast.stiffness(u), slow.stiffness(u)) < 1e-14
        assert rel(fast.stiffness_derivative(u, w), slow.stiffness_derivative(u, w)) < 1e-14
        assert fast.potential_energy(u) == pytest.approx(slow.potential_energy(u), rel=1e-14)
        assert rel(kernels.force(u, params), slow.internal_force(u)) < 1e-14
        assert rel(kernels.stiffness(u, params), slow.stiffness(u)) < 1e-14
        assert rel(kernels.stiffness_derivative(u, w, params),
                   slow.stiffness_derivative(u, w)) < 1e-14
    assert hfdi.check_derivatives(fast, rng.uniform(-0.5, 0.5, (3, 3))).ok(1e-6)
    # the public expressions, in the user's symbols (acosh's derivative is
    # written differently by the two: compared by value)
    point = {**dict(zip(dofs, (0.2, -0.3, 0.4))), **parameters}
    assert fast.hessian.free_symbols <= set(dofs) | set(parameters)
    for a, b in [*zip(fast.gradient, slow.gradient), *zip(fast.hessian, slow.hessian)]:
        assert float(a.subs(point)) == pytest.approx(float(b.subs(point)), rel=1e-13, abs=1e-15)


@pytest.mark.parametrize("make", [lambda x, y: sympy.Abs(x) * y ** 2,
                                  lambda x, y: sympy.Max(0, x - 1) ** 2 + y ** 2,
                                  lambda x, y: sympy.Piecewise((x ** 2, x > 0), (0, True)) + y,
                                  lambda x, y: sympy.Float("0.1", 30) * x ** 2 + y,
                                  lambda x, y: sympy.besselj(0, x) + y ** 2])
def test_an_energy_beyond_the_elementary_functions_is_derived_by_sympy(make):
    from hfdi.models import derivation
    x, y = sympy.symbols("x y", real=True)
    energy = make(x, y)
    assert not derivation.elementary(energy)
    model = EnergyModel([x, y], energy, np.ones(2))
    assert model._derivation.engine == "sympy"
    assert model.gradient[1] == energy.diff(y)


def test_a_copy_and_a_pickle_compute_in_the_same_order():
    """symengine may order the terms of the same expressions otherwise after a
    round trip; the reduced text travels with the model, so copies agree bit
    for bit."""
    dofs, energy, parameters = _every_elementary_function()
    model = EnergyModel(dofs, energy, np.ones(3), parameters=parameters)
    u, w = np.array([0.1, -0.2, 0.3]), np.array([0.5, 0.1, -1.0])
    for clone in (pickle.loads(pickle.dumps(model)), model.with_parameters(c=1.7)):
        np.testing.assert_array_equal(clone.internal_force(u), model.internal_force(u))
        np.testing.assert_array_equal(clone.stiffness_derivative(u, w),
                                      model.stiffness_derivative(u, w))


def test_a_float_of_another_precision_is_its_decimal_value_on_both_routes():
    """Float("0.1", 3) is 0.1 as sympy prints it, whichever engine derives the
    rest of the energy (symengine would take its 12-bit binary value)."""
    from hfdi.models import derivation
    x, y = sympy.symbols("x y", real=True)
    low = sympy.Float("0.1", 3)
    assert not derivation.elementary(low * x ** 2)
    for energy in (low * x ** 2 + y ** 2, low * x ** 2 + sympy.Abs(y) ** 3):
        model = EnergyModel([x, y], energy, np.ones(2))
        assert model.stiffness(np.array([0.3, 0.5]))[0, 0] == 0.2


def test_a_quantity_without_a_numerical_form_is_refused_at_construction():
    x = sympy.Symbol("x")
    with pytest.raises(ValueError, match="quantities has no numerical form.*fresnels"):
        EnergyModel([x], x ** 2 / 2, [1.0], quantities={"fs": sympy.fresnels(x)})
