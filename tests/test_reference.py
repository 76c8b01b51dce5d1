"""The IDA reference solutions and the error norm of Eq. 42 (validation package)."""
import math
import os
import signal
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.integrate import solve_ivp
from scipy.stats import linregress

import hfdi
from problems import coupled_duffing
from validation.errors import error_norm, error_norms
from hfdi.dense import hermite_quintic
from validation.reference import (IDAError, NonFiniteResidualError, cached_reference,
                                  ida_dense_reference, ida_reference)

pytest.importorskip("sksundae")


@pytest.fixture(scope="module")
def dumbbell():
    return hfdi.models.get("dumbbell")


@pytest.fixture(scope="module")
def dumbbell_reference(dumbbell):
    """The paper's dumbbell over its T_o = 2 at rtol 1e-12 (seconds, shared by the slow tests)."""
    return ida_dense_reference(dumbbell, 2.0, rtol=1e-12)


@pytest.fixture(scope="module")
def short_reference(dumbbell):
    """The dumbbell over [0, 0.3] at rtol 1e-12, for the quick tests."""
    return ida_dense_reference(dumbbell, 0.3, rtol=1e-12)


def dumbbell_rhs(A=1e6, sigma=math.sqrt(3.0 / 5.0)):
    """The dumbbell's equations written out anew (unit masses), for an explicit solver."""
    s3, s5 = sigma ** 3, sigma ** 5

    def rhs(t, y):
        x1, y1, x2, y2, vx1, vy1, vx2, vy2 = y
        dx, dy = x2 - x1, y2 - y1
        r = math.hypot(dx, dy)
        g = A * (-5.0 * s5 / r ** 6 + 3.0 * s3 / r ** 4) / r      # φ'(r)/r
        return np.array([vx1, vy1, vx2, vy2, g * dx, g * dy, -g * dx, -g * dy])
    return rhs


@pytest.mark.slow
def test_dumbbell_reference_matches_dop853(dumbbell, dumbbell_reference):
    t = np.linspace(0.0, 2.0, 201)
    y0 = np.concatenate([dumbbell.initial_displacement, dumbbell.initial_velocity])
    sol = solve_ivp(dumbbell_rhs(), (0.0, 2.0), y0, method="DOP853", rtol=1e-13, atol=1e-13,
                    t_eval=t)
    assert sol.success
    u, _ = dumbbell_reference.at(t)
    assert np.max(np.abs(u - sol.y[:4].T)) < 1e-8
    st = dumbbell_reference.stats
    assert dumbbell_reference.dense and st["steps"] > 1000 and st["linsolver"] == "dense"
    # the bond is quasi-rigid: its length stays 1 to the static centrifugal stretch
    stretch = dumbbell_reference.quantities(dumbbell)["stretch"]
    assert np.max(np.abs(stretch)) < 2e-5


def test_exact_outputs_and_dense_interpolation_agree(dumbbell, short_reference):
    result = hfdi.integrate(dumbbell, "hfdi", 0.3, target_iterations=3.3, compiled=False)
    exact = ida_reference(dumbbell, result.t, rtol=1e-12)
    assert np.array_equal(exact.t, result.t)
    u, v = short_reference.at(result.t)
    assert np.max(np.abs(u - exact.u)) < 1e-11
    assert np.max(np.abs(v - exact.v)) < 1e-7 * np.max(np.abs(exact.v))
    eps_dense = error_norms(dumbbell, result, short_reference)
    eps_exact = error_norms(dumbbell, result, exact)
    for name in eps_dense:
        assert eps_dense[name] == pytest.approx(eps_exact[name], rel=1e-4)


@pytest.mark.slow
def test_tighter_reference_changes_eps_by_less_than_a_percent(dumbbell, dumbbell_reference):
    result = hfdi.integrate(dumbbell, "hfdi", 0.5, target_iterations=3.3)
    assert result.success
    eps = error_norms(dumbbell, result, dumbbell_reference)                   # rtol 1e-12
    eps_tight = error_norms(dumbbell, result, ida_reference(dumbbell, result.t, rtol=1e-13))
    assert set(eps) == {"u", "stretch"}
    for name in eps:
        assert 0 < eps[name] < math.inf
        assert abs(eps_tight[name] - eps[name]) < 0.01 * eps[name], (name, eps, eps_tight)


def test_reference_against_itself_is_zero(dumbbell, short_reference):
    ref = short_reference
    as_result = SimpleNamespace(t=ref.t[::97], u=ref.u[::97], v=ref.v[::97])
    assert error_norms(dumbbell, as_result, ref) == {"u": 0.0, "stretch": 0.0}
    z = ref.quantities(dumbbell)["u"]
    assert error_norm(ref.t, z, z) == 0.0


def test_error_norm_is_eq_42_by_the_trapezoidal_rule():
    t = np.array([0.0, 1.0, 3.0])
    z_ref = np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 2.0]])
    z = z_ref + np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    # ∫|e|² = (0+1)/2·1 + (1+1)/2·2 = 2.5 ; ∫|z*|² = (1+2)/2·1 + (2+4)/2·2 = 7.5
    assert error_norm(t, z, z_ref) == pytest.approx(math.sqrt(2.5 / 7.5), rel=1e-15)
    # first component alone: ∫e² = 0.5·1 + 0.5·2 = 1.5 ; ∫z*² = 1·1 + 0.5·2 = 2
    assert error_norm(t, z[:, 0], z_ref[:, 0]) == pytest.approx(math.sqrt(1.5 / 2.0))
    assert error_norm(t, np.zeros(3), np.zeros(3)) == 0.0
    assert error_norm(t, np.ones(3), np.zeros(3)) == math.inf
    with pytest.raises(ValueError):
        error_norm(t, z, z_ref[:2])


@pytest.mark.parametrize("scheme, order", [("newmark", 2),
                                           pytest.param("bathe", 2, marks=pytest.mark.slow),
                                           ("hfdi", 3), ("generalized_alpha", 2)])
def test_eps_converges_with_the_order_of_the_scheme(scheme, order):
    system = coupled_duffing(damping=0.05)
    reference = ida_dense_reference(system, 2.0)
    steps = 2.0 / 2.0 ** np.arange(4, 9)
    eps = []
    for h in steps:
        result = hfdi.integrate(system, scheme, 2.0, step=h, tol=1e-12)
        assert result.success, result.message
        eps.append(error_norms(system, result, reference)["u"])
    fit = linregress(np.log(steps), np.log(eps))
    assert abs(fit.slope - order) <= 0.3, (fit.slope, eps)
    assert fit.rvalue > 0.99


@pytest.mark.parametrize("t_eval", [[0.7], [0.0, 0.7], [0.3, 0.7], [0.0, 0.35, 0.7]])
def test_one_or_two_output_times(t_eval):
    system = coupled_duffing(damping=0.05)
    dense = ida_dense_reference(system, 0.7)
    ref = ida_reference(system, t_eval)
    assert np.array_equal(ref.t, t_eval) and ref.u.shape == (len(t_eval), 2)
    u, v = dense.at(t_eval)
    np.testing.assert_allclose(ref.u, u, rtol=0, atol=1e-11)
    np.testing.assert_allclose(ref.v, v, rtol=0, atol=1e-10)
    if t_eval[0] == 0.0:
        np.testing.assert_array_equal(ref.u[0], system.initial_displacement)


def test_output_reference_does_not_interpolate():
    system = coupled_duffing()
    ref = ida_reference(system, [0.0, 0.5, 1.0])
    with pytest.raises(ValueError, match="requested output times"):
        ref.at([0.25])
    with pytest.raises(ValueError, match="outside"):
        ida_dense_reference(system, 1.0).at([1.5])


def test_hermite_quintic_reproduces_quintics():
    rng = np.random.default_rng(1)
    c = rng.standard_normal(6)
    p = np.polynomial.Polynomial(c)
    nodes = np.array([0.0, 0.3, 1.1, 2.0])
    t = np.linspace(0.0, 2.0, 37)
    P, dP, ddP = hermite_quintic(nodes, p(nodes)[:, None], p.deriv()(nodes)[:, None],
                                 p.deriv(2)(nodes)[:, None], t)
    np.testing.assert_allclose(P[:, 0], p(t), atol=1e-13)
    np.testing.assert_allclose(dP[:, 0], p.deriv()(t), atol=1e-12)
    np.testing.assert_allclose(ddP[:, 0], p.deriv(2)(t), atol=1e-11)


def test_band_and_sparse_solvers_on_a_chain():
    n = 60
    K = 100.0 * sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1],
                         format="csr")
    u0 = np.sin(np.pi * np.arange(1, n + 1) / (n + 1))
    chain = hfdi.LinearSystem(np.ones(n), K, damping=sp.diags(0.1 * np.ones(n)),
                              initial_displacement=u0)
    t = np.linspace(0.0, 1.0, 11)
    # the chain moves in its first mode: u = q(t) u0 with a damped oscillator q
    w2, c = 100.0 * (2 - 2 * np.cos(np.pi / (n + 1))), 0.1
    wd = np.sqrt(w2 - c * c / 4)
    exact = (np.exp(-c * t / 2) * (np.cos(wd * t) + c / (2 * wd) * np.sin(wd * t)))[:, None] * u0
    auto = ida_reference(chain, t)
    assert auto.stats["linsolver"] == "band"
    # node-interleaved unknowns keep the band of a tridiagonal K narrow
    assert (auto.stats["lband"], auto.stats["uband"]) == (3, 1)
    for linsolver in ("dense", "band", "sparse"):
        ref = ida_reference(chain, t, linsolver=linsolver)
        assert ref.stats["linsolver"] == linsolver
        assert np.max(np.abs(ref.u - exact)) < 1e-9


def test_sparse_pattern_covers_entries_zero_at_the_start(dumbbell):
    ref = ida_reference(dumbbell, [0.0, 0.05, 0.1], linsolver="sparse")
    dense = ida_reference(dumbbell, [0.0, 0.05, 0.1], linsolver="dense")
    assert ref.stats["dropped_jacobian_entries"] == 0
    assert np.max(np.abs(ref.u - dense.u)) < 1e-10


def test_cache_is_reused_and_a_corrupt_entry_recomputed(tmp_path, monkeypatch):
    import validation.reference as reference_module
    kwargs = dict(t_end=0.5, rtol=1e-12, cache_dir=tmp_path)
    first = cached_reference("dumbbell", {"A": 1e3}, **kwargs)

    def no_ida(*args, **kw):
        raise AssertionError("the reference was computed again instead of read from the cache")

    with monkeypatch.context() as patch:
        patch.setattr(reference_module, "ida_dense_reference", no_ida)
        second = cached_reference("dumbbell", {"A": 1e3}, **kwargs)
    assert not first.from_cache and second.from_cache
    assert first.cache_path == second.cache_path and os.path.exists(second.cache_path)
    for name in ("t", "u", "v", "a", "atol"):
        np.testing.assert_array_equal(getattr(first, name), getattr(second, name))
    assert second.dense and second.stats == first.stats and second.rtol == first.rtol

    # another tolerance or parameter is another entry
    other = cached_reference("dumbbell", {"A": 1e3}, t_end=0.5, rtol=1e-10, cache_dir=tmp_path)
    assert other.cache_path != first.cache_path and not other.from_cache

    path = first.cache_path
    with open(path, "r+b") as fh:                    # a truncated file, as from a crash
        fh.truncate(os.path.getsize(path) // 2)
    again = cached_reference("dumbbell", {"A": 1e3}, **kwargs)
    assert not again.from_cache
    np.testing.assert_array_equal(again.u, first.u)
    with open(path, "wb") as fh:
        fh.write(b"not a cache file")
    assert not cached_reference("dumbbell", {"A": 1e3}, **kwargs).from_cache
    assert cached_reference("dumbbell", {"A": 1e3}, **kwargs).from_cache
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]


def test_cache_write_is_atomic(tmp_path, monkeypatch):
    kwargs = dict(t_end=0.2, cache_dir=tmp_path)
    good = cached_reference("dumbbell", {"A": 1e3}, **kwargs)
    before = open(good.cache_path, "rb").read()

    def killed(*args, **kw):
        raise KeyboardInterrupt
    monkeypatch.setattr(np, "savez", killed)
    with pytest.raises(KeyboardInterrupt):
        cached_reference("dumbbell", {"A": 1e3}, refresh=True, **kwargs)
    monkeypatch.undo()
    assert open(good.cache_path, "rb").read() == before
    assert os.listdir(tmp_path) == [os.path.basename(good.cache_path)]
    assert cached_reference("dumbbell", {"A": 1e3}, **kwargs).from_cache


def test_cache_directory_from_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("HFDI_CACHE_DIR", str(tmp_path / "env"))
    ref = cached_reference("dumbbell", {"A": 1e3}, t_eval=[0.0, 0.1, 0.2])
    assert ref.cache_path.startswith(str(tmp_path / "env"))
    assert not ref.dense and np.array_equal(ref.t, [0.0, 0.1, 0.2])


def test_ida_failure_raises_with_sundials_message(dumbbell):
    with pytest.raises(IDAError, match="max_num_steps") as info:
        ida_reference(dumbbell, np.linspace(0.0, 2.0, 5), max_num_steps=5)
    assert info.value.status < 0
    assert "mxstep" in info.value.sundials_message
    assert "mxstep" in str(info.value)


def _nan_model(where):
    def force(u):
        return np.array([np.nan]) if where == "force" and u[0] < 0.5 else u.copy()

    def load(t):
        return np.array([np.nan if where == "load" and t > 0.3 else 0.0])
    return hfdi.System(mass=[1.0], internal_force=force, stiffness=lambda u: np.eye(1),
                       stiffness_derivative=lambda u, w: np.zeros((1, 1)), load=load,
                       initial_displacement=[1.0])


@pytest.mark.parametrize("where", ["force", "load"])
def test_nan_from_the_model_raises_rather_than_hangs(where):
    def alarm(signum, frame):
        raise TimeoutError("IDA hung on a NaN residual")
    has_alarm = hasattr(signal, "SIGALRM")
    if has_alarm:
        previous = signal.signal(signal.SIGALRM, alarm)
        signal.alarm(30)
    try:
        with pytest.raises(NonFiniteResidualError, match="not finite"):
            ida_reference(_nan_model(where), np.linspace(0.0, 2.0, 5))
        with pytest.raises(NonFiniteResidualError):
            ida_dense_reference(_nan_model(where), 2.0)
    finally:
        if has_alarm:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, previous)


@pytest.mark.parametrize("damage", ["nan-u", "nan-v", "nan-a", "reversed-t"])
def test_cache_entry_with_damaged_data_is_recomputed(tmp_path, damage):
    """A cache file whose key matches but whose data are NaN, or whose times
    run backwards, is recomputed, not used (it printed NaN error norms with
    exit status 0)."""
    kwargs = dict(t_end=0.2, cache_dir=tmp_path)
    good = cached_reference("dumbbell", {"A": 1e3}, **kwargs)
    with np.load(good.cache_path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    field = damage.split("-")[1]
    values = data[field].copy()
    if damage == "reversed-t":
        values = values[::-1].copy()
    else:
        values.flat[values.size // 2] = np.nan
    data[field] = values
    np.savez(good.cache_path, **data)
    again = cached_reference("dumbbell", {"A": 1e3}, **kwargs)
    assert not again.from_cache
    for name in ("t", "u", "v", "a"):
        np.testing.assert_array_equal(getattr(again, name), getattr(good, name))


def test_cache_key_covers_the_helpers_a_model_uses():
    """Editing the loads or the pair potential the tetrahedra use must miss
    the cache: the key hashes every module of hfdi.models and the model
    protocol, not only the model's own module."""
    from validation.reference import _model_source_digest, model_sources
    model = hfdi.models.tetrahedra()
    sources = model_sources(model)
    names = {p.name for p in sources}
    assert {"tetrahedra.py", "pair.py", "loads.py", "system.py", "checks.py",
            "evaluation.py"} <= names
    # every file listed exists: one that does not would drop the sources from the key
    assert all(p.is_file() for p in sources)
    assert _model_source_digest(model) is not None


def test_cache_key_covers_the_hfdi_modules_a_model_module_uses(tmp_path, monkeypatch):
    """A model written outside hfdi.models: its module, and the modules of hfdi
    it takes names from (here hfdi.models.pair), are in the key."""
    import importlib
    import sys
    from validation.reference import model_sources
    (tmp_path / "my_model.py").write_text(
        "import hfdi\nfrom hfdi.models.pair import relative\n"
        "class Mine(hfdi.SecondOrderSystem):\n    n_dof = 1\n    mass = [1.0]\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("my_model")
    try:
        names = {p.name for p in model_sources(module.Mine())}
    finally:
        sys.modules.pop("my_model", None)
    assert {"my_model.py", "pair.py", "system.py", "evaluation.py"} <= names
