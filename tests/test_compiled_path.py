"""When the compiled path is taken, and what it does where it is: the paths
chosen as asked, refusals with their reasons, numba missing, users' kernels
(dense, sparse, with loads) held to their Python models, loads held between
calls, faulty kernels, the model followed when it changes.

That the two speeds run the same numerics bit for bit on every model, scheme
and mode is tests/test_one_implementation.py; here a user's kernels and
Python methods are two definitions, so runs agree to their rounding."""
import math
import sys
import warnings

import numpy as np
import pytest
import scipy.sparse as sp

import hfdi
from hfdi.linsolve import sparse as linsolve_sparse
from hfdi.compiled import CompiledKernels, CompiledUnavailable
from hfdi.controller import Combined, ErrorControl, IterationCount
from hfdi.models import articulated, dumbbell, tetrahedra, toss_rule
from problems import schemes_quick

#: the per-step rule where a test is about the path, not the accuracy: its runs
#: take the steps they took before the default spent shares of the tolerance
PER_STEP = ErrorControl(1e-6, per_step=True)

numba = pytest.importorskip("numba")

#: Short horizons: a few hundred steps at most under error control; the
#: iteration count's long steps get a longer one.
PROBLEMS = {"dumbbell": (dumbbell, 0.01, 0.2), "tetrahedra": (tetrahedra, 1.5, 5.0),
            "articulated": (articulated, 0.03, 0.2), "toss_rule": (toss_rule, 0.003, 0.012)}
MODES = {"fixed": dict(step=1 / 40), "iterations": dict(target_iterations=3),
         "error": dict(rtol=1e-6)}
COUNTERS = ("steps", "accepted", "rejected", "newton_iterations", "error_test_failures",
            "first_step_trials", "first_step_trial_iterations", "nfev", "njev", "ntev", "nlu")


def _assert_same_counts(python, compiled):
    for name in COUNTERS:
        assert getattr(compiled.stats, name) == getattr(python.stats, name), name
    assert compiled.status == python.status
    np.testing.assert_array_equal(compiled.iterations, python.iterations)


def _relative_error(got, ref):
    difference = float(np.abs(got - ref).max())
    return difference / float(np.abs(ref).max()) if difference else 0.0


def _assert_same_run(python, compiled, bitwise_kernels=True):
    """Same counters and step sizes; ``u`` within 1e-12 of its largest entry in
    the run at every step, ``v`` and ``a`` as close as their conditioning allows."""
    _assert_same_counts(python, compiled)
    np.testing.assert_array_equal(compiled.t, python.t)
    assert _relative_error(compiled.u, python.u) <= 1e-12
    # HFDI's v_D solves with B = 2h/3 M, whose lumped rotary masses on the beam
    # are ~1e-6 of its translational ones: rounding of K reaches v amplified.
    # a = c_a u + a_0 (c_a = 4/h² in the trapezoidal rule) cancels digits.
    assert _relative_error(compiled.v, python.v) <= (1e-12 if bitwise_kernels else 1e-11)
    assert _relative_error(compiled.a, python.a) <= (1e-10 if bitwise_kernels else 1e-9)


def test_the_paths_are_chosen_as_asked():
    model = dumbbell()
    assert hfdi.Integrator(model, "hfdi", step=1e-3).compiled           # default: auto
    assert hfdi.Integrator(model, "hfdi", step=1e-3, compiled=None).compiled   # auto
    assert hfdi.Integrator(model, "hfdi", step=1e-3, compiled=True).compiled
    assert not hfdi.Integrator(model, "hfdi", step=1e-3, compiled=False).compiled
    with pytest.raises(ValueError, match="compiled must be"):
        hfdi.Integrator(model, "hfdi", step=1e-3, compiled="yes")


def test_compiled_true_without_kernels_is_refused_with_the_reason():
    plain = hfdi.System([1.0], lambda u: 4.0 * u, lambda u: np.array([[4.0]]),
                        lambda u, w: np.zeros((1, 1)), initial_displacement=[1.0])
    assert not hfdi.Integrator(plain, "hfdi", step=0.1, compiled=None).compiled
    with pytest.raises(CompiledUnavailable, match="internal_force is a Python function"):
        hfdi.Integrator(plain, "hfdi", step=0.1, compiled=True)
    # a sparse system: the steps in Python, the model compiled if it can be
    beam = toss_rule(n_elements=50)                                     # 153 DOFs: sparse
    for compiled in (None, True):
        itg = hfdi.Integrator(beam, "hfdi", step=1e-4, compiled=compiled)
        assert not itg.compiled and itg.compiled_model
    itg = hfdi.Integrator(beam, "hfdi", step=1e-4, compiled=False)
    assert not itg.compiled and not itg.compiled_model
    chain = hfdi.LinearSystem(mass=np.ones(200), stiffness=sp.diags(
        [-np.ones(199), 2.0 * np.ones(200), -np.ones(199)], [-1, 0, 1], format="csr"))
    assert not hfdi.Integrator(chain, "hfdi", step=0.1, compiled=None).compiled_model
    with pytest.raises(CompiledUnavailable, match="200 degrees of freedom.*no compiled sparse"):
        hfdi.Integrator(chain, "hfdi", step=0.1, compiled=True)


def test_without_numba_the_python_path_runs_and_says_so_once(monkeypatch):
    import hfdi.compiled as hc
    monkeypatch.setattr(hc, "_NUMBA", (False, "numba cannot be imported (test)"))
    monkeypatch.setattr(hc, "_SAID", set())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        a = hfdi.Integrator(dumbbell(), "hfdi", step=1e-3, compiled=None)
        b = hfdi.Integrator(dumbbell(), "hfdi", step=1e-3, compiled=None)
    assert not a.compiled and not b.compiled
    said = [w for w in caught if "Python path" in str(w.message)]
    assert len(said) == 1 and "numba cannot be imported" in str(said[0].message)
    with pytest.raises(CompiledUnavailable, match="numba"):
        hfdi.Integrator(dumbbell(), "hfdi", step=1e-3, compiled=True)


@pytest.mark.parametrize("scheme", schemes_quick("hfdi", among=["newmark", "bathe", "hfdi"]))
def test_failed_attempts_fail_alike(scheme):
    """A corrector that cannot converge in N_max = 1 correction: the fixed
    step stops the run with the same status and message; with N_max = 2 the
    error control retries shorter steps in the same way."""
    fixed = [hfdi.integrate(articulated(), scheme, 0.05, step=0.01, max_iterations=1,
                            compiled=c) for c in (False, True)]
    assert fixed[0].status == hfdi.Status.NEWTON_FAILED
    assert fixed[1].message == fixed[0].message
    _assert_same_run(*fixed)
    retried = [hfdi.integrate(articulated(), scheme, 0.05, rtol=1e-4, max_iterations=2,
                              compiled=c) for c in (False, True)]
    assert retried[0].success and retried[0].stats.rejected > 0
    _assert_same_run(*retried)


# -- a user model with its own kernels, dense M and C -------------------------------
# A chain of three masses with cubic springs, M dense (consistent), C dense or
# diagonal: it exercises the dense branches the paper's models (diagonal M, no
# C) leave out, and shows the protocol of docs/compiled.md.

from numba import njit  # noqa: E402

from hfdi.compiled.signatures import (FORCE, JIT_OPTIONS, POTENTIAL_ENERGY,  # noqa: E402
                                      STIFFNESS, STIFFNESS_DERIVATIVE)


@njit(FORCE, **JIT_OPTIONS)
def chain_force(u, params):
    k, c3 = params[0], params[1]
    f = np.zeros(3)
    for i in range(3):
        s = u[i] - (u[i - 1] if i > 0 else 0.0)
        t = k * s + c3 * s * s * s
        f[i] += t
        if i > 0:
            f[i - 1] -= t
    return f


@njit(**JIT_OPTIONS)
def _spring_matrix(e):
    """The (3, 3) matrix of springs with the coefficients ``e`` (ground to 1, 1–2, 2–3)."""
    A = np.zeros((3, 3))
    for i in range(3):
        A[i, i] += e[i]
        if i > 0:
            A[i - 1, i - 1] += e[i]
            A[i, i - 1] -= e[i]
            A[i - 1, i] -= e[i]
    return A


@njit(STIFFNESS, **JIT_OPTIONS)
def chain_stiffness(u, params):
    k, c3 = params[0], params[1]
    e = np.empty(3)
    for i in range(3):
        s = u[i] - (u[i - 1] if i > 0 else 0.0)
        e[i] = k + 3.0 * c3 * s * s
    return _spring_matrix(e)


@njit(STIFFNESS_DERIVATIVE, **JIT_OPTIONS)
def chain_stiffness_derivative(u, w, params):
    c3 = params[1]
    e = np.empty(3)
    for i in range(3):
        s = u[i] - (u[i - 1] if i > 0 else 0.0)
        z = w[i] - (w[i - 1] if i > 0 else 0.0)
        e[i] = 6.0 * c3 * s * z
    return _spring_matrix(e)


@njit(POTENTIAL_ENERGY, **JIT_OPTIONS)
def chain_potential_energy(u, params):
    k, c3 = params[0], params[1]
    V = 0.0
    for i in range(3):
        s = u[i] - (u[i - 1] if i > 0 else 0.0)
        V += 0.5 * k * s * s + 0.25 * c3 * s ** 4
    return V


class Chain(hfdi.SecondOrderSystem):
    """Three masses on cubic springs, the first tied to the ground, with compiled kernels."""

    name = "chain"
    n_dof = 3

    def __init__(self, damping):
        self.params = np.array([100.0, 5e4])
        self.mass = np.array([[2.0, 0.5, 0.0], [0.5, 2.0, 0.5], [0.0, 0.5, 2.0]])
        self.damping = damping
        self.initial_displacement = np.array([0.05, -0.1, 0.2])
        self.initial_velocity = np.array([1.0, 0.0, -1.0])

    def _u(self, u):
        return np.ascontiguousarray(u, dtype=float)

    def internal_force(self, u):
        return chain_force(self._u(u), self.params)

    def stiffness(self, u):
        return chain_stiffness(self._u(u), self.params)

    def stiffness_derivative(self, u, w):
        return chain_stiffness_derivative(self._u(u), self._u(w), self.params)

    def potential_energy(self, u):
        return chain_potential_energy(self._u(u), self.params)

    def load(self, t):
        return np.array([0.0, 0.0, 3.0 * math.sin(20.0 * t)])

    def load_rate(self, t):
        return np.array([0.0, 0.0, 60.0 * math.cos(20.0 * t)])

    def compiled_kernels(self):
        return CompiledKernels(chain_force, chain_stiffness, chain_stiffness_derivative,
                               chain_potential_energy, self.params)


@pytest.mark.parametrize("scheme", ["newmark", "hfdi"])
def test_a_python_load_without_its_compiled_form_takes_the_python_steps(scheme):
    damping = None
    """The chain's load is Python only: the steps cannot run compiled (they
    would need p(t) in the loop); the default says why and runs in Python."""
    with pytest.raises(CompiledUnavailable, match="model Chain has no compiled load"):
        hfdi.Integrator(Chain(damping), scheme, rtol=1e-6, compiled=True)
    itg = hfdi.Integrator(Chain(damping), scheme, rtol=1e-6)
    assert not itg.compiled and "no compiled load" in itg.not_compiled_reason


# -- sparse systems: Python steps, compiled model -------------------------------------

def _beam_run(model, scheme, compiled, t_end, u0=None):
    itg = hfdi.Integrator(model, scheme, target_iterations=3.0, compiled=compiled, u0=u0)
    itg.advance(t_end)
    return itg


@pytest.mark.parametrize("scheme", schemes_quick("hfdi", among=["newmark", "bathe", "hfdi"]))
@pytest.mark.parametrize("n_elements", [200, pytest.param(1500, marks=pytest.mark.slow)])
def test_a_sparse_beam_with_compiled_kernels_takes_the_python_paths_steps(scheme, n_elements):
    """Above DENSE_BELOW the steps stay in Python and the model runs compiled:
    the same steps, Newton iterations and evaluations as the Python model,
    end states equal to rounding. 1500 elements put HFDI's masses beyond
    BLOCK_SPREAD (the interleaved block tangent), 200 below it.

    "Rounding" is measured: the Python path's own change when u0 moves by
    1e-16 (with 1500 elements the rotations' tiny inertia carries such a
    change into the velocities at 5e-8)."""
    model = toss_rule(n_elements)
    t_end = 1e-3
    python = _beam_run(model, scheme, False, t_end)
    compiled = _beam_run(model, scheme, None, t_end)
    nudged = _beam_run(model, scheme, False, t_end, model.initial_displacement + 1e-16)
    assert compiled.compiled_model and not python.compiled_model
    a, b = python.statistics, compiled.statistics
    assert python.status == hfdi.Status.RUNNING == compiled.status and a.accepted > 3
    for name in ("steps", "accepted", "rejected", "newton_iterations"):
        assert getattr(a, name) == getattr(b, name), name
    for name in ("nfev", "njev", "ntev", "nlu"):
        assert getattr(a, name) == getattr(b, name), name
    assert python.t == compiled.t
    for x in ("u", "v"):
        rounding = _relative_error(getattr(nudged.state, x), getattr(python.state, x))
        assert _relative_error(getattr(compiled.state, x), getattr(python.state, x)) \
            <= max(10.0 * rounding, 1e-12), x


def test_sparse_kernels_of_another_model_are_refused(monkeypatch):
    """The library's own kernels, handed out with another model's data by a
    method that is not the library's, are checked as any others."""
    import hfdi.compiled as hc
    from hfdi.models.toss_rule import TossRule
    monkeypatch.setattr(hc, "_SAID", set())
    other = toss_rule(60, E=2.0e11)
    own = TossRule.compiled_sparse_kernels
    monkeypatch.setattr(TossRule, "compiled_sparse_kernels", lambda self: own(other))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        itg = hfdi.Integrator(toss_rule(60), "newmark", step=1e-5)
    assert not itg.compiled_model
    assert any("does not match" in str(w.message) for w in caught)
    with pytest.raises(CompiledUnavailable, match="stiffness|force"):
        hfdi.Integrator(toss_rule(60), "newmark", step=1e-5, compiled=True)


@pytest.mark.parametrize("damped", [False, True])
@pytest.mark.parametrize("n_elements", [45, 1500])
def test_compiled_bands_are_the_python_bands_bit_for_bit(n_elements, damped):
    """hfdi.compiled.band builds HFDI's interleaved block band and the shifted
    band of Newmark and Bathe with the Python builders' operations in their
    order: the same arrays, bit for bit, for K and T of different patterns too."""
    from hfdi.compiled import band
    model = toss_rule(n_elements)
    rng = np.random.default_rng(n_elements)
    u = 0.01 * rng.standard_normal(model.n_dof)
    K = model.stiffness(u)
    T = model.stiffness_derivative(u, rng.standard_normal(model.n_dof))
    T = sp.csr_matrix(T.multiply(rng.random(T.shape) > 0.3))     # fewer entries than K
    T.sort_indices()
    T.indices, T.indptr = T.indices.astype(np.int32), T.indptr.astype(np.int32)
    b = 0.5 * model.mass + 0.01
    C = 3.0 * np.abs(rng.standard_normal(model.n_dof)) if damped else None
    python = linsolve_sparse._InterleavedBlockTangent(b, model.mass, C, K, T, 2e-9, 4e-5)
    compiled = linsolve_sparse._InterleavedBlockTangent(b, model.mass, C, K, T, 2e-9, 4e-5, band)
    lower = max(linsolve_sparse.banded_from_sparse(a, bandwidths_only=True)[1] for a in (K, T))
    upper = max(linsolve_sparse.banded_from_sparse(a, bandwidths_only=True)[2] for a in (K, T))
    mine = band.interleaved_block_band(K, T, model.mass, C, b, 2e-9, 4e-5, lower, upper)
    assert np.array_equal(mine[0], python.band()[0]) and mine[1:] == python.band()[1:]
    rhs = rng.standard_normal(model.n_dof)
    assert np.array_equal(compiled.solve(rhs), python.solve(rhs))
    shift = 1e3 * model.mass
    assert np.array_equal(linsolve_sparse._ShiftedTangent(K, shift, band).solve(rhs),
                          linsolve_sparse._ShiftedTangent(K, shift).solve(rhs))


# -- a user's sparse model with compiled kernels ---------------------------------------
# A chain of n masses on cubic springs (spring i joins masses i - 1 and i, mass -1 the
# ground): spring force s(d) = k d + c d³. K is tridiagonal; its CSR pattern is fixed
# (row i: columns i - 1, i, i + 1 within range), so the kernels fill its data array.

@numba.njit(cache=False)
def _long_chain_force(u, k, c):
    n = u.shape[0]
    f = np.zeros(n)
    for i in range(n):
        d = u[i] - (u[i - 1] if i > 0 else 0.0)
        s = k * d + c * d ** 3
        f[i] += s
        if i > 0:
            f[i - 1] -= s
    return f


@numba.njit(cache=False)
def _long_chain_tangent(u, w, k, c, derivative, indptr, data):
    """K(u) (``derivative`` false) or T(u)[w] into the data of the tridiagonal pattern."""
    n = u.shape[0]
    data[:] = 0.0
    for i in range(n):
        d = u[i] - (u[i - 1] if i > 0 else 0.0)
        if derivative:
            z = w[i] - (w[i - 1] if i > 0 else 0.0)
            g = 6.0 * c * d * z
        else:
            g = k + 3.0 * c * d * d
        # row i: (i, i - 1) first when i > 0, then (i, i); row i - 1: ..., (i - 1, i - 1), (i - 1, i)
        diag_i = indptr[i] + (1 if i > 0 else 0)
        data[diag_i] += g
        if i > 0:
            data[diag_i - 1] -= g
            data[indptr[i - 1] + (1 if i > 1 else 0)] += g       # (i - 1, i - 1)
            data[indptr[i - 1] + (2 if i > 1 else 1)] -= g       # (i - 1, i)


class LongChain(hfdi.SecondOrderSystem):
    """A user's sparse model: Python methods in numpy, compiled sparse kernels in numba."""

    name = "long_chain"

    def __init__(self, n=400):
        self.n_dof = n
        self.k, self.c = 1.0e4, 2.0e7
        self.mass = np.full(n, 0.1)
        self.initial_displacement = np.zeros(n)
        self.initial_velocity = np.zeros(n)
        self.initial_velocity[-1] = 2.0
        self.pattern = sp.diags([np.ones(n - 1), np.ones(n), np.ones(n - 1)], [-1, 0, 1],
                                format="csr")
        self.pattern.indices = self.pattern.indices.astype(np.int32)
        self.pattern.indptr = self.pattern.indptr.astype(np.int32)

    def _springs(self, u):
        return np.diff(np.concatenate([[0.0], np.asarray(u, dtype=float)]))

    def internal_force(self, u):
        s = self.k * (d := self._springs(u)) + self.c * d ** 3
        f = s.copy()
        f[:-1] -= s[1:]
        return f

    def _tridiagonal(self, g):
        main = g.copy()
        main[:-1] += g[1:]
        return sp.diags([-g[1:], main, -g[1:]], [-1, 0, 1], format="csr")

    def stiffness(self, u):
        d = self._springs(u)
        return self._tridiagonal(self.k + 3.0 * self.c * d * d)

    def stiffness_derivative(self, u, w):
        return self._tridiagonal(6.0 * self.c * self._springs(u) * self._springs(w))

    def potential_energy(self, u):
        d = self._springs(u)
        return float(np.sum(0.5 * self.k * d ** 2 + 0.25 * self.c * d ** 4))

    def compiled_sparse_kernels(self):
        from hfdi.compiled import SparseKernels
        pattern, k, c = self.pattern, self.k, self.c

        def csr(data):
            out = pattern.copy()
            out.data = data
            return out

        def tangent(u, w, derivative):
            data = np.empty(pattern.nnz)
            _long_chain_tangent(np.ascontiguousarray(u, dtype=float),
                                np.ascontiguousarray(w, dtype=float), k, c, derivative,
                                pattern.indptr, data)
            return csr(data)

        return SparseKernels(
            lambda u: _long_chain_force(np.ascontiguousarray(u, dtype=float), k, c),
            lambda u: tangent(u, u, False),
            lambda u, w: tangent(u, w, True))


@pytest.mark.slow                               # compiles the user's kernels
@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
def test_a_users_sparse_model_runs_its_compiled_kernels(scheme):
    """SparseKernels of a model of one's own (not the toss rule): exact
    derivatives, taken by the default path, the same run as its Python methods."""
    model = LongChain()
    kernels = model.compiled_sparse_kernels()

    class Kernels(LongChain):
        def internal_force(self, u):
            return kernels.force(u)

        def stiffness(self, u):
            return kernels.stiffness(u)

        def stiffness_derivative(self, u, w):
            return kernels.stiffness_derivative(u, w)

    assert hfdi.check_derivatives(Kernels(), samples=3, spread=0.02).ok(1e-7)
    rng = np.random.default_rng(5)
    u, w = 0.01 * rng.standard_normal(model.n_dof), rng.standard_normal(model.n_dof)
    assert _relative_error(kernels.force(u), model.internal_force(u)) < 1e-13
    for mine, python in ((kernels.stiffness(u), model.stiffness(u)),
                         (kernels.stiffness_derivative(u, w), model.stiffness_derivative(u, w))):
        assert abs(mine - python).max() <= 1e-13 * abs(python).max()
    runs = {}
    for compiled in (False, None):      # rtol 1e-4: 70-380 steps (1e-6: 3,500, 25 s)
        itg = hfdi.Integrator(model, scheme, rtol=1e-4, compiled=compiled)
        itg.advance(0.02)
        runs[compiled] = itg
    python, default = runs[False], runs[None]
    assert default.compiled_model and not python.compiled_model
    assert python.status == hfdi.Status.RUNNING and python.statistics.accepted > 10
    for name in ("steps", "accepted", "rejected", "newton_iterations"):
        assert getattr(python.statistics, name) == getattr(default.statistics, name), name
    assert _relative_error(default.state.u, python.state.u) < 1e-10
    assert _relative_error(default.state.v, python.state.v) < 1e-9


# -- the compiled run against the Python run of the same model -----------------------

STATE = ("proposed_step", "first_step_pending", "status", "message", "potential",
         "initial_potential", "last_step", "last_iterations", "grid_origin", "grid_steps",
         "newton_constant", "newton_guard", "controller", "model_version")
ENERGY = ("work", "energy_error", "energy_scale", "last_energy_increment")


def _pair(make, scheme, **options):
    """Two integrators of the same run, compiled and in Python."""
    compiled = hfdi.Integrator(make(), scheme, compiled=True, **options)
    python = hfdi.Integrator(make(), scheme, compiled=False, **options)
    assert compiled.compiled, compiled.not_compiled_reason
    return compiled, python


def _assert_same_state(a, b):
    """The same counters and saved state, bit for bit."""
    for name in COUNTERS:
        assert getattr(a.statistics, name) == getattr(b.statistics, name), name
    sa, sb = a.get_state(), b.get_state()
    for name in STATE + ENERGY:
        x, y = getattr(sa, name), getattr(sb, name)
        assert x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y)), name
    for which in ("current", "previous"):
        x, y = getattr(sa, which), getattr(sb, which)
        assert (x is None) == (y is None), which
        if x is None:
            continue
        assert x.t == y.t
        for field in ("u", "v", "a", "f", "p"):
            fx, fy = getattr(x, field), getattr(y, field)
            assert (fx is None) == (fy is None), (which, field)
            if fx is not None:
                np.testing.assert_array_equal(fx, fy, err_msg=f"{which}.{field}")


def test_progress_is_reported_from_the_driver(monkeypatch):
    monkeypatch.setattr(sys.modules["hfdi.integrate"], "PROGRESS_INTERVAL", 0.0)
    seen = []
    result = hfdi.integrate(toss_rule(), "hfdi", 0.004, rtol=1e-7, compiled=True,
                            progress=lambda t, st: seen.append((t, st.accepted)))
    assert result.success
    assert len(seen) >= 2 and seen[-1][0] == 0.004
    assert [t for t, _ in seen] == sorted(t for t, _ in seen)


@pytest.mark.slow
@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("error", ["local", "global"])
def test_progress_may_stop_the_run(monkeypatch, compiled, error):
    """progress raising StopIteration ends the run where it stands, as a
    success with the rows so far (those of the whole run: the exception
    propagated out of integrate, and the steps were lost); another exception
    propagates."""
    monkeypatch.setattr(sys.modules["hfdi.integrate"], "PROGRESS_INTERVAL", 0.0)
    monkeypatch.setattr(sys.modules["hfdi.integrator"], "STEPS_PER_CALL", 7)

    def model():
        return hfdi.LinearSystem([1.0, 2.0], [[5.0, -1.0], [-1.0, 2.0]],
                                 initial_displacement=[1.0, 0.0])

    def progress(t, statistics):
        if t > 5.0:
            raise StopIteration

    options = dict(rtol=1e-6, compiled=compiled, error=error)
    stopped = hfdi.integrate(model(), "hfdi", 10.0, progress=progress, **options)
    assert stopped.status == hfdi.Status.TERMINATED and stopped.success, stopped.message
    assert "progress raised StopIteration" in stopped.message
    assert 5.0 < stopped.t[-1] < 10.0 and stopped.runs == 1
    whole = hfdi.integrate(model(), "hfdi", 10.0, rtol=1e-6, compiled=compiled)
    np.testing.assert_array_equal(stopped.u, whole.u[:stopped.t.size])
    np.testing.assert_array_equal(stopped.sol(stopped.t[-1])[0], stopped.u[-1])

    def failing(t, statistics):
        raise KeyError("from progress")

    with pytest.raises(KeyError, match="from progress"):
        hfdi.integrate(model(), "hfdi", 10.0, progress=failing, **options)
    # a run that failed in the call whose rows progress saw keeps its failure
    short = hfdi.integrate(model(), "hfdi", 10.0, progress=progress, max_steps=40, **options)
    assert short.status == hfdi.Status.MAX_STEPS and "max_steps = 40" in short.message


def test_a_progress_stop_keeps_what_it_stopped(monkeypatch):
    """error="global": a stop during the rerun keeps the complete first run
    (it returned the rerun's fragment as the answer), saying so; events: no
    zero past where the run stopped (the scan had recorded it)."""
    monkeypatch.setattr(sys.modules["hfdi.integrate"], "PROGRESS_INTERVAL", 0.0)
    monkeypatch.setattr(sys.modules["hfdi.integrator"], "STEPS_PER_CALL", 7)
    import exact_problems
    kepler, _ = exact_problems.kepler()      # its first run misses the global tolerance
    seen = []

    def second_run(t, statistics):
        if seen and t < seen[-1]:
            raise StopIteration              # the time went back: a rerun
        seen.append(t)

    result = hfdi.integrate(kepler, "hfdi", 4 * np.pi, rtol=1e-4, error="global",
                            progress=second_run)
    assert result.t[-1] == 4 * np.pi and result.runs == 2
    assert result.status == hfdi.Status.TOLERANCE_NOT_MET
    assert "progress stopped the rerun" in result.message
    model = hfdi.LinearSystem([1.0], [[1.0]], initial_displacement=[1.0])

    def zero(t, u, v):
        return u[0]
    zero.terminal = True
    for k in range(1, 4):
        calls = []

        def stop(t, statistics):
            calls.append(t)
            if len(calls) == k:
                raise StopIteration

        stopped = hfdi.integrate(model, "hfdi", 5.0, rtol=1e-8, events=zero, progress=stop)
        assert all(np.all(times <= stopped.t[-1]) for times in stopped.t_events), k


def log_spring():
    """``V = x²/2 + log(1 + x)/10`` thrown at its singularity ``x = -1``
    (reached at t ≈ 0.17): the steps shrink until below ``min_step``."""
    import sympy
    from hfdi.models.symbolic import EnergyModel
    x = sympy.Symbol("x")
    return EnergyModel([x], x**2 / 2 + sympy.log(1 + x) / 10, mass=[1.0],
                       initial_displacement=[0.0], initial_velocity=[-6.0])


def _stops():
    """Runs that the driver hands back to Python to stop: each must stop with
    the status, message and last good state of the Python driver."""
    yield "max_steps", articulated, dict(rtol=1e-6, max_steps=57), "MAX_STEPS"
    # a tiny first step, then growth until an error test fails
    yield "halvings", dumbbell, dict(rtol=1e-6, max_halvings=0, first_step=1e-6), \
        "HALVINGS_EXHAUSTED"
    yield "min_step", log_spring, dict(rtol=1e-6, min_step=1e-9), "STEP_BELOW_MINIMUM"
    yield "fixed", articulated, dict(step=0.004, max_iterations=2), "NEWTON_FAILED"
    yield "energy", articulated, dict(target_iterations=6, energy_limit=1e-9), "ENERGY_GROWTH"


@pytest.mark.parametrize("name, make, options, status", list(_stops()),
                         ids=[s[0] for s in _stops()])
def test_stops_are_the_python_steps(name, make, options, status):
    t_end = 0.2
    driven, python = _pair(make, "hfdi", t_bound=t_end, **options)
    ok = [itg.advance(t_end) for itg in (driven, python)]
    assert ok == [False, False]
    assert driven.status == hfdi.Status[status], driven.message
    assert driven.message == python.message
    assert driven.statistics.accepted > 0
    _assert_same_state(driven, python)


def test_a_potential_energy_lost_mid_run_stops_as_the_python_driver():
    """V known at the start and NaN at the end of a step: both drivers stop
    with MODEL_ERROR at the same last good state (the compiled one hands the
    step back)."""
    import sympy
    from hfdi.models.symbolic import EnergyModel
    x, c = sympy.symbols("x c")

    def make():
        return EnergyModel([x], x**2 / 2 + sympy.log(c), mass=[1.0], parameters={c: 2.0},
                           initial_displacement=[1.0])

    driven, python = _pair(make, "hfdi", rtol=1e-6)
    for itg in (driven, python):
        assert itg.advance(1.0)
        itg.system.set_parameters(c=-1.0)            # log(-1): V is NaN, f is not
        with np.errstate(invalid="ignore"):
            assert not itg.advance(2.0)
    assert driven.status == hfdi.Status.MODEL_ERROR, driven.message
    assert "potential_energy is NaN (unknown)" in driven.message
    assert driven.message == python.message
    assert driven.t == 1.0
    _assert_same_state(driven, python)


def test_state_saved_mid_run_continues_bit_for_bit():
    whole, _ = _pair(tetrahedra, "hfdi", rtol=1e-6, t_bound=4.0)
    whole.advance(1.3)
    whole.advance(4.0)
    first, _ = _pair(tetrahedra, "hfdi", rtol=1e-6, t_bound=4.0)
    first.advance(1.3)
    saved = hfdi.IntegratorState.from_bytes(first.get_state().to_bytes())
    second, _ = _pair(tetrahedra, "hfdi", rtol=1e-6, t_bound=4.0)
    second.set_state(saved)
    second.advance(4.0)
    _assert_same_state(second, whole)


def test_a_callback_runs_the_python_driver_with_the_same_steps():
    seen = []
    driven, _ = _pair(dumbbell, "bathe", rtol=1e-6, t_bound=0.01)
    stepped, _ = _pair(dumbbell, "bathe", rtol=1e-6, t_bound=0.01)
    driven.advance(0.01)
    stepped.advance(0.01, callback=lambda itg: seen.append(itg.t))
    assert len(seen) == stepped.statistics.accepted
    _assert_same_state(driven, stepped)


# -- when the driver is (not) used ---------------------------------------------------

class _Subclass(type(articulated())):
    def load(self, t):
        return 2.0 * super().load(t)


class _Counting(ErrorControl):
    pass


@pytest.mark.parametrize("why, build", [
    ("extra_load", lambda: hfdi.Integrator(dumbbell(), "hfdi", rtol=1e-6, compiled=None,
                                           extra_load=lambda t: np.zeros(4))),
    ("no compiled load", lambda: hfdi.Integrator(_Subclass(), "hfdi", rtol=1e-6,
                                                 compiled=None)),
    ("built-in controllers", lambda: hfdi.Integrator(
        dumbbell(), "hfdi", controller=_Counting(1e-6), compiled=None)),
    ("compiled=False", lambda: hfdi.Integrator(dumbbell(), "hfdi", rtol=1e-6, compiled=False)),
])
def test_the_python_steps_run_where_compiled_ones_would_compute_another_run(why, build):
    itg = build()
    assert not itg.compiled
    assert why in itg.not_compiled_reason


def test_an_injected_built_in_controller_is_driven():
    c = Combined(IterationCount(3), ErrorControl(1e-5))
    driven, python = _pair(dumbbell, "hfdi", controller=c, t_bound=0.01)
    driven.advance(0.01)
    python.advance(0.01)
    _assert_same_state(driven, python)


@pytest.mark.slow
def test_a_redefined_load_runs_on_the_python_driver_with_its_own_load():
    """A subclass that changes the load takes the Python steps (its class's
    compiled load is the parent's), saying why."""
    with pytest.raises(CompiledUnavailable, match="no compiled load"):
        hfdi.Integrator(_Subclass(), "hfdi", rtol=1e-6, compiled=True)
    doubled = hfdi.integrate(_Subclass(), "hfdi", 0.05, rtol=1e-6, compiled=None)
    python = hfdi.integrate(_Subclass(), "hfdi", 0.05, rtol=1e-6)
    single = hfdi.integrate(articulated(), "hfdi", 0.05, rtol=1e-6)
    assert doubled.stats.steps == python.stats.steps
    np.testing.assert_array_equal(doubled.u, python.u)
    assert np.abs(doubled.u - single.u[-1]).max() > 0 or doubled.t.size != single.t.size


# -- a user model with a compiled load, dense M and C -------------------------------

from hfdi.compiled.signatures import LOAD  # noqa: E402


@njit(LOAD, **JIT_OPTIONS)
def chain_load(t, load_params):
    p = np.zeros(3)
    p[2] = load_params[0] * math.sin(load_params[1] * t)
    return p


class DrivenChain(Chain):
    """The chain above with its load compiled too."""

    def load(self, t):
        return np.array([0.0, 0.0, 3.0 * math.sin(20.0 * t)])

    load_rate = None    # HFDI takes the difference quotient, as the driver does

    def compiled_kernels(self):
        return super().compiled_kernels()._replace(load=chain_load,
                                                   load_params=np.array([3.0, 20.0]))


@pytest.mark.parametrize("damping", [None, np.array([0.3, 0.1, 0.2]),
                                     np.array([[0.4, -0.1, 0.0], [-0.1, 0.3, -0.1],
                                               [0.0, -0.1, 0.2]])],
                         ids=["undamped", "diagonal C", "dense C"])
@pytest.mark.parametrize("scheme", schemes_quick("hfdi", among=["newmark", "bathe", "hfdi"]))
def test_user_model_with_compiled_load_and_dense_matrices(scheme, damping):
    """The compiled run against the Python run of the same model: its kernels and
    its Python methods are two definitions (the load's sin rounds alike in
    both, products of M and C need not), so to rounding."""
    model = DrivenChain(damping)
    assert hfdi.check_derivatives(model, samples=3, spread=0.1).ok(1e-7)
    compiled, python = _pair(lambda: DrivenChain(damping), scheme, controller=PER_STEP,
                             t_bound=0.1)
    for itg in (compiled, python):
        assert itg.advance(0.1)
    assert compiled.statistics.steps > 20
    assert compiled.statistics.steps == python.statistics.steps
    np.testing.assert_allclose(compiled.state.u, python.state.u, rtol=0, atol=1e-12)


def test_hat_load_kernel_is_the_models_load():
    from hfdi.compiled import kernels_of
    for make in (dumbbell, tetrahedra, articulated, toss_rule):
        model = make()
        kernels, _ = kernels_of(model)
        for t in np.concatenate([np.linspace(-0.01, 0.06, 71), model.load_breakpoints()
                                 if hasattr(model, "load_breakpoints") else []]):
            np.testing.assert_array_equal(kernels.load(float(t), kernels.load_params),
                                          model.load(float(t)))


@pytest.mark.slow
def test_a_held_load_is_driven_as_the_python_driver_adds_it():
    """A co-simulation input (hfdi.HeldLoad) held over each advance and changed
    between them (load_changed): bit for bit, on the driver and on Python."""
    value = np.zeros(6)
    runs = []
    for drive in (True, False):
        itg = hfdi.Integrator(articulated(), "bathe", controller=PER_STEP, compiled=drive,
                              extra_load=hfdi.HeldLoad(lambda: value))
        assert itg.compiled == drive
        value[:] = 0.0
        for k, t in enumerate(np.linspace(0.005, 0.08, 16)):
            value[:] = 50.0 * np.sin(k + np.arange(6))
            itg.load_changed()
            assert itg.advance(t)
        runs.append(itg)
    _assert_same_state(*runs)
    assert runs[0].statistics.steps > 50


@pytest.mark.parametrize("fault", [np.nan, -np.inf])
def test_a_faulty_held_load_fails_the_run_as_on_the_python_path(fault):
    outcomes = []
    for drive in (True, False):
        value = np.zeros(6)
        itg = hfdi.Integrator(articulated(), "hfdi", controller=PER_STEP, compiled=drive,
                              extra_load=hfdi.HeldLoad(lambda: value))
        assert itg.advance(0.01)
        value[1] = fault
        assert not itg.advance(0.02)
        assert itg.t == 0.01 and "not finite" in itg.message
        outcomes.append((itg.status, itg.message, itg.statistics.steps))
    assert outcomes[0] == outcomes[1]
    with pytest.raises(ValueError, match="source must be callable"):
        hfdi.HeldLoad(np.zeros(6))


def test_compiled_code_that_cannot_be_loaded_leaves_the_python_path(monkeypatch):
    """numba failing to compile or cache (a read-only installation without a
    user cache, say): the default runs on, on the Python path, and says so
    once; compiled=True names the reason."""
    import warnings

    import hfdi.compiled as hc

    def broken(self):
        raise RuntimeError("cannot cache function: no locator available")

    monkeypatch.setattr(type(articulated()), "compiled_kernels", broken)
    monkeypatch.setattr(hc, "_SAID", set())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        runs = [hfdi.integrate(articulated(), "hfdi", 0.02, rtol=1e-6) for _ in range(2)]
    assert all(r.success for r in runs)
    said = [w for w in caught if "no locator available" in str(w.message)]
    assert len(said) == 1 and "Python path runs" in str(said[0].message)
    with pytest.raises(hc.CompiledUnavailable, match="no locator available"):
        hfdi.Integrator(articulated(), "hfdi", rtol=1e-6, compiled=True)


def test_a_long_run_returns_to_python_between_calls(monkeypatch):
    """Control comes back to Python every STEPS_PER_CALL accepted steps (a
    Ctrl-C is seen there), with the same run as in one call."""
    import hfdi.integrator as hi
    whole, _ = _pair(dumbbell, "newmark", rtol=1e-7, t_bound=0.01)
    whole.advance(0.01)
    monkeypatch.setattr(hi, "STEPS_PER_CALL", 7)
    calls = []
    chunked, _ = _pair(dumbbell, "newmark", rtol=1e-7, t_bound=0.01)
    original = chunked._advance_compiled

    def counting(*args):
        calls.append(1)
        return original(*args)

    chunked._advance_compiled = counting
    chunked.advance(0.01)
    assert len(calls) >= chunked.statistics.accepted // 7 > 3
    _assert_same_state(chunked, whole)


class _WrongLoad(DrivenChain):
    """Its compiled load has another frequency than its Python load."""

    def compiled_kernels(self):
        return super().compiled_kernels()._replace(load_params=np.array([3.0, 21.0]))


class _WrongStiffness(DrivenChain):
    """Its compiled kernels read other spring constants than its Python methods."""

    def compiled_kernels(self):
        kernels = super().compiled_kernels()
        return kernels._replace(params=2.0 * kernels.params)


@pytest.mark.parametrize("model, what", [(_WrongLoad, "load at t ="), (_WrongStiffness, "force")])
def test_kernels_that_compute_another_model_are_refused(model, what):
    """Kernels are checked against the Python model when the integrator is built
    (each at the initial state, the load at several times): kernels of another
    model would give a silent wrong answer, so the Python path runs, saying
    why once, and compiled=True names the kernel."""
    import warnings

    import hfdi.compiled as hc
    hc._SAID.clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        itg = hfdi.Integrator(model(None), "newmark", rtol=1e-6)
    assert not itg.compiled
    assert any(what in str(w.message) and "another model" in str(w.message) for w in caught)
    with pytest.raises(hc.CompiledUnavailable, match=f"compiled {what}"):
        hfdi.Integrator(model(None), "newmark", rtol=1e-6, compiled=True)


# -- kernels that fail: a wrong shape, an exception ------------------------------------

def _faulty_kernels():
    """A Duffing pair whose force kernel returns shape (1,) beyond |u_0| > params[0],
    and whose load kernel raises beyond t > load_params[0] (the model's Python
    methods are right everywhere but for the same raising load)."""
    from numba import njit

    from hfdi.compiled import CompiledKernels
    from hfdi.compiled.signatures import (FORCE, JIT_OPTIONS, LOAD, POTENTIAL_ENERGY,
                                          STIFFNESS, STIFFNESS_DERIVATIVE)

    @njit(FORCE, **JIT_OPTIONS)
    def force(u, params):
        if abs(u[0]) > params[0]:
            return np.zeros(1)
        return np.array([u[0] + u[0] ** 3, 2.0 * u[1]])

    @njit(STIFFNESS, **JIT_OPTIONS)
    def stiffness(u, params):
        return np.array([[1.0 + 3.0 * u[0] ** 2, 0.0], [0.0, 2.0]])

    @njit(STIFFNESS_DERIVATIVE, **JIT_OPTIONS)
    def derivative(u, w, params):
        return np.array([[6.0 * u[0] * w[0], 0.0], [0.0, 0.0]])

    @njit(POTENTIAL_ENERGY, **JIT_OPTIONS)
    def potential(u, params):
        return 0.5 * u[0] ** 2 + 0.25 * u[0] ** 4 + u[1] ** 2

    @njit(LOAD, **JIT_OPTIONS)
    def load(t, load_params):
        if t > load_params[0]:
            raise ValueError("the load fails late")
        return np.zeros(2)

    class Faulty(hfdi.SecondOrderSystem):
        mass, damping, n_dof, u_scale = np.ones(2), None, 2, 1.0
        initial_displacement, initial_velocity = np.array([0.0, 0.1]), np.array([0.3, 0.0])

        def __init__(self, limit=math.inf, fails_after=math.inf):
            self.limit, self.fails_after = limit, fails_after

        def internal_force(self, u):
            return np.array([u[0] + u[0] ** 3, 2.0 * u[1]])

        def stiffness(self, u):
            return np.array([[1.0 + 3.0 * u[0] ** 2, 0.0], [0.0, 2.0]])

        def stiffness_derivative(self, u, w):
            return np.array([[6.0 * u[0] * w[0], 0.0], [0.0, 0.0]])

        def potential_energy(self, u):
            return 0.5 * u[0] ** 2 + 0.25 * u[0] ** 4 + u[1] ** 2

        def load(self, t):
            if t > self.fails_after:
                raise ValueError("the load fails late")
            return np.zeros(2)

        def compiled_kernels(self):
            return CompiledKernels(force, stiffness, derivative, potential,
                                   np.array([self.limit]), load,
                                   np.array([min(self.fails_after, 1e300)]))

    return Faulty


@pytest.mark.parametrize("scheme", schemes_quick("hfdi", among=["newmark", "bathe", "hfdi"]))
def test_a_kernel_value_of_a_wrong_shape_stops_the_run_with_model_error(scheme):
    """numba checks no bounds: a force kernel of shape (1,) was read past its
    end (a wrong run reported as a success); it is now MODEL_ERROR at the last
    good state, as a wrong shape of the model's method is on the Python path."""
    Faulty = _faulty_kernels()
    r = hfdi.integrate(Faulty(limit=0.27), scheme, 6.0, rtol=1e-4, compiled=True)
    assert r.status == hfdi.Status.MODEL_ERROR, (r.status, r.message)
    assert "internal_force returned shape (1,), expected (2,)" in r.message
    assert 0.5 < r.t[-1] < 6.0 and np.abs(r.u[:, 0]).max() <= 0.27
    # below the limit the same kernels run to the end, as the Python path does
    good = hfdi.integrate(Faulty(limit=0.5), scheme, 6.0, rtol=1e-4, compiled=True)
    plain = hfdi.integrate(Faulty(), scheme, 6.0, rtol=1e-4, compiled=False)
    assert good.success and good.stats.steps == plain.stats.steps


@pytest.mark.parametrize("scheme", schemes_quick("hfdi", among=["newmark", "hfdi"]))
def test_a_raising_kernel_is_a_failed_attempt_as_on_the_python_path(scheme):
    """An exception in a kernel escaped integrate() (no Result; advance() lost
    the driver's steps of that call); it is now a failed attempt, as a raising
    model is on the Python path: the same stop, at the same time, after the
    same accepted steps."""
    Faulty = _faulty_kernels()
    itg = hfdi.Integrator(Faulty(fails_after=1.5), scheme, rtol=1e-6, compiled=True)
    assert itg.compiled
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)       # said once per process
        assert not itg.advance(3.0)
    assert not itg.compiled           # the rest of the run takes Python steps
    assert "a compiled kernel raised ValueError" in itg.not_compiled_reason
    python = hfdi.Integrator(Faulty(fails_after=1.5), scheme, rtol=1e-6, compiled=False)
    assert not python.advance(3.0)
    assert itg.status == python.status == hfdi.Status.STEP_BELOW_MINIMUM
    assert itg.t == python.t and 1.5 - 1e-9 < itg.t <= 1.5
    assert itg.statistics.accepted == python.statistics.accepted
    np.testing.assert_allclose(itg.state.u, python.state.u, rtol=0, atol=1e-12)
    # integrate() keeps every row of such a run
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        r = hfdi.integrate(Faulty(fails_after=1.5), scheme, 3.0, rtol=1e-6, compiled=True)
    plain = hfdi.integrate(Faulty(fails_after=1.5), scheme, 3.0, rtol=1e-6, compiled=False)
    assert r.status == plain.status and r.message == plain.message
    assert r.t.size == plain.t.size == r.stats.accepted + 1 and r.t[-1] == plain.t[-1]


def _hidden_term_model():
    """Kernels that add ``c u₀³`` to the force (and its K and T) where the Python
    model has none: nothing at u0 = 0, v0 = 0, or while ``c = 0``."""
    from numba import njit

    from hfdi.compiled import CompiledKernels
    from hfdi.compiled.signatures import (FORCE, JIT_OPTIONS, LOAD, POTENTIAL_ENERGY,
                                          STIFFNESS, STIFFNESS_DERIVATIVE)

    @njit(FORCE, **JIT_OPTIONS)
    def force(u, params):
        return np.array([u[0] + params[0] * u[0] ** 3, 2.0 * u[1]])

    @njit(STIFFNESS, **JIT_OPTIONS)
    def stiffness(u, params):
        return np.array([[1.0 + 3.0 * params[0] * u[0] ** 2, 0.0], [0.0, 2.0]])

    @njit(STIFFNESS_DERIVATIVE, **JIT_OPTIONS)
    def derivative(u, w, params):
        return np.array([[6.0 * params[0] * u[0] * w[0], 0.0], [0.0, 0.0]])

    @njit(POTENTIAL_ENERGY, **JIT_OPTIONS)
    def potential(u, params):
        return 0.5 * u[0] ** 2 + 0.25 * params[0] * u[0] ** 4 + u[1] ** 2

    @njit(LOAD, **JIT_OPTIONS)
    def load(t, load_params):
        if t > 5.0:                       # defined up to t = 5 only
            return np.full(2, np.nan)
        return np.array([math.sin(t), 0.0])

    class Hidden(hfdi.SecondOrderSystem):
        mass, damping, n_dof, u_scale = np.ones(2), None, 2, 1.0
        initial_displacement, initial_velocity = np.zeros(2), np.zeros(2)

        def __init__(self, c):
            self.c, self.parameter_version = c, 0

        def set_c(self, c):
            self.c, self.parameter_version = c, self.parameter_version + 1

        def internal_force(self, u):
            return np.array([u[0], 2.0 * u[1]])

        def stiffness(self, u):
            return np.diag([1.0, 2.0])

        def stiffness_derivative(self, u, w):
            return np.zeros((2, 2))

        def potential_energy(self, u):
            return 0.5 * u[0] ** 2 + u[1] ** 2

        def load(self, t):
            return np.full(2, np.nan) if t > 5.0 else np.array([math.sin(t), 0.0])

        def compiled_params(self):
            return np.array([self.c])

        def compiled_kernels(self):
            return CompiledKernels(force, stiffness, derivative, potential,
                                   self.compiled_params(), load, np.zeros(0))

    return Hidden


@pytest.mark.parametrize("scheme", ["newmark", "hfdi"])
def test_kernels_that_differ_only_away_from_the_initial_state_are_refused(scheme):
    """Kernels were compared at u0 only (T at v0): a term vanishing at a model
    released from rest passed, and the run was silently another model's. A
    second state near u0 tells them apart."""
    Hidden = _hidden_term_model()
    with pytest.raises(hfdi.compiled.CompiledUnavailable, match="force at a second state"):
        hfdi.Integrator(Hidden(0.5), scheme, rtol=1e-6, compiled=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        itg = hfdi.Integrator(Hidden(0.5), scheme, rtol=1e-6)
    assert not itg.compiled
    same = hfdi.Integrator(Hidden(0.0), scheme, rtol=1e-6, compiled=True)   # no term: agree
    assert same.compiled      # (and a load NaN past t = 5 in both is agreement, not a mismatch)


@pytest.mark.parametrize("scheme", schemes_quick("hfdi", among=["newmark", "hfdi"]))
def test_kernels_are_checked_again_when_the_model_changes(scheme):
    """Kernels that agree under one set of parameters may not under the next:
    after a change (parameter_version) they are compared again, and the rest
    of the run is the Python path where they differ."""
    Hidden = _hidden_term_model()
    model = Hidden(0.0)
    itg = hfdi.Integrator(model, scheme, rtol=1e-6, compiled=True)
    assert itg.compiled and itg.advance(2.0)
    model.set_c(0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert itg.advance(4.0)
    assert not itg.compiled and "after the model changed" in itg.not_compiled_reason
    plain = hfdi.Integrator(Hidden(0.0), scheme, rtol=1e-6, compiled=False)
    assert plain.advance(2.0)
    plain.system.set_c(0.5)
    assert plain.advance(4.0)
    np.testing.assert_allclose(itg.state.u, plain.state.u, rtol=0, atol=1e-9)


@pytest.mark.parametrize("scheme", schemes_quick("hfdi", among=["newmark", "hfdi"]))
def test_a_parameter_assigned_between_calls_is_followed_by_both_speeds(scheme):
    """``m.A = 4e6`` between two advances, without model_changed(): the
    compiled run kept the old A (bit for bit the run without the change),
    the Python path took the new one with the old f and a. Both now count
    the assignment (parameter_version) and restart from the model now."""
    ends = {}
    for compiled in (False, True):
        model = dumbbell()
        itg = hfdi.Integrator(model, scheme, rtol=1e-7, compiled=compiled)
        assert itg.advance(0.02)
        model.A = 4e6
        assert itg.advance(0.04)
        ends[compiled] = itg.state.u
    told = hfdi.Integrator(dumbbell(), scheme, rtol=1e-7, compiled=False)
    assert told.advance(0.02)
    told.system.A = 4e6
    told.model_changed()
    assert told.advance(0.04)
    unchanged = hfdi.Integrator(dumbbell(), scheme, rtol=1e-7)
    assert unchanged.advance(0.04)
    np.testing.assert_array_equal(ends[True], ends[False])
    np.testing.assert_array_equal(ends[False], told.state.u)
    assert np.abs(ends[True] - unchanged.state.u).max() > 1e-7


@njit
def _sine_load(t):
    return np.array([np.sin(t)])


@njit
def _sine_load_rate(t):
    return np.array([np.cos(t)])


@pytest.mark.parametrize("told", [True, False], ids=["model_changed", "assigned"])
def test_a_load_rate_removed_between_calls_is_refused_by_both_speeds(told):
    """``m.load_rate = None`` after HFDI chose the model's exact rate: the
    compiled run crashed in numba (AttributeError), the Python path failed
    after 30 halvings calling None. Both now refuse it with a ValueError that
    names the load_rate, as a changed mass is refused, and the run is left at
    the state it reached."""
    for compiled in (False, True):
        model = hfdi.LinearSystem(np.array([1.0]), np.array([[4.0]]), load=_sine_load,
                                  load_rate=_sine_load_rate)
        itg = hfdi.Integrator(model, "hfdi", rtol=1e-6, compiled=compiled)
        assert itg.advance(1.0)
        reached = itg.state.u.copy()
        model.load_rate = None
        with pytest.raises(ValueError, match="load_rate of model LinearSystem was removed"):
            itg.model_changed() if told else itg.advance(2.0)
        assert itg.t == 1.0
        np.testing.assert_array_equal(itg.state.u, reached)


def test_set_state_refused_by_the_changed_model_leaves_the_integrator_as_it_was():
    """A model that counts its changes, its mass changed since a state was
    saved: set_state's refresh refuses it (ValueError, the matrices are read
    once). The integrator was left at the saved state, its version taken as
    seen, so the next step went on with the old mass unasked."""
    class Counted(hfdi.LinearSystem):
        parameter_version = 0
    model = Counted(np.array([1.0]), np.array([[4.0]]), load=_sine_load,
                    load_rate=_sine_load_rate)
    itg = hfdi.Integrator(model, "hfdi", rtol=1e-6)
    assert itg.advance(0.5)
    saved = itg.get_state()
    assert itg.advance(1.0)
    reached = itg.state.u.copy()
    model.mass = np.array([2.0])
    model.parameter_version += 1
    with pytest.raises(ValueError, match="mass"):
        itg.set_state(saved)
    assert itg.t == 1.0
    np.testing.assert_array_equal(itg.state.u, reached)
    with pytest.raises(ValueError, match="mass"):
        itg.advance(2.0)


def test_the_same_load_rate_again_is_no_change():
    """Assigning a LinearSystem the load rate it has changes nothing (the run
    bit for bit, no restart), and a state of another model is still refused."""
    def fresh(k=4.0):
        return hfdi.LinearSystem(np.array([1.0]), np.array([[k]]), load=_sine_load,
                                 load_rate=_sine_load_rate)
    ends = []
    for reassign in (False, True):
        model = fresh()
        itg = hfdi.Integrator(model, "hfdi", rtol=1e-6)
        assert itg.advance(1.0)
        if reassign:
            model.load_rate = _sine_load_rate
        assert itg.advance(2.0)
        ends.append((itg.state.u, itg.statistics.steps))
    np.testing.assert_array_equal(ends[0][0], ends[1][0])
    assert ends[0][1] == ends[1][1]
    other = fresh(9.0)
    other.load_rate = _sine_load_rate
    with pytest.raises(ValueError, match="another model"):
        hfdi.Integrator(other, "hfdi", rtol=1e-6).set_state(itg.get_state())


def test_what_counts_as_a_change_of_a_built_in_model():
    """The constructors' names (a subclass's own __init__ included) and the
    attributes a model declares: counted once each change; the same value
    again, or an attribute of a subclass's own, is no change."""
    from hfdi.models.dumbbell import Dumbbell
    from hfdi.models.impact_oscillator import ImpactOscillator

    class Scaled(Dumbbell):
        def __init__(self, scale=1.0, **parameters):
            super().__init__(**parameters)
            self.scale = scale

    for model, name, value in ((Scaled(), "A", 4e6), (Scaled(), "scale", 2.0),
                               (ImpactOscillator(), "stiffness_value", 400.0)):
        before = model.parameter_version
        setattr(model, name, getattr(model, name))
        model.calls = 1
        assert model.parameter_version == before, name
        setattr(model, name, value)
        assert model.parameter_version == before + 1, name


def test_the_library_kernels_skip_the_check_that_others_pass(monkeypatch):
    """The paper models' kernels are held to their Python methods by this
    suite; comparing them again at every construction cost up to 1.8 ms. A
    user's kernels are still compared."""
    def refuse(*args, **kwargs):
        raise AssertionError("kernel_mismatch called")

    monkeypatch.setattr(hfdi.compiled, "kernel_mismatch", refuse)
    monkeypatch.setattr(hfdi.compiled, "sparse_kernel_mismatch", refuse)
    for make in (dumbbell, articulated, tetrahedra, toss_rule):
        assert hfdi.Integrator(make(), "hfdi", rtol=1e-6, compiled=True).compiled
    assert hfdi.Integrator(toss_rule(60), "hfdi", rtol=1e-6, compiled=True).compiled_model
    with pytest.raises(AssertionError, match="kernel_mismatch called"):
        hfdi.Integrator(_hidden_term_model()(0.0), "hfdi", rtol=1e-6, compiled=True)
    # the library's kernels with another model's data, handed out by a method
    # that is not the library's: checked, and refused
    monkeypatch.undo()
    from hfdi.models.dumbbell import Dumbbell
    other, library_method = dumbbell(A=2e6), Dumbbell.compiled_kernels
    monkeypatch.setattr(Dumbbell, "compiled_kernels", lambda self: library_method(other))
    with pytest.raises(hfdi.compiled.CompiledUnavailable, match="another model"):
        hfdi.Integrator(dumbbell(), "hfdi", rtol=1e-6, compiled=True)


def test_a_reason_is_said_again_in_another_situation(monkeypatch):
    """say_once kept the reason only: a fault said at construction was not
    said when the same reason came up after a model change."""
    import hfdi.compiled as hc
    monkeypatch.setattr(hc, "_SAID", set())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        hc.say_once("the reason")
        hc.say_once("the reason")
        hc.say_once("the reason", "after the model changed: {reason}")
    assert [str(w.message) for w in caught] == [
        "hfdi: the compiled step is not used (the reason); the Python path runs",
        "hfdi: after the model changed: the reason"]


@pytest.mark.slow
def test_a_run_of_many_short_calls_keeps_only_its_rows():
    """A call of the driver ends at every breakpoint: the rows a run keeps
    are its rows (at most about twice them), not a full buffer per call. At
    rtol 1e-3 the rows kept (29,000, 13 MB) are few beside a buffer per call;
    at 1e-6 (520,000 rows) the bound below could not see that."""
    import tracemalloc
    model = toss_rule()
    hfdi.integrate(model, "hfdi", 0.012, rtol=1e-6, compiled=True)      # compiled, loaded
    breakpoints = np.linspace(0.0, 0.1, 401)[1:-1]
    tracemalloc.start()
    try:
        result = hfdi.integrate(model, "hfdi", 0.1, rtol=1e-3, compiled=True,
                                breakpoints=breakpoints)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert result.success and result.stats.steps > 1000
    kept = sum(arr.nbytes for arr in (result.t, result.u, result.v, result.a))
    # a buffer per call (399 calls × 2048 rows) would be about 470 MB
    assert peak < 6 * kept + 20e6, (peak, kept)


# -- a System of numba functions ------------------------------------------------------

@njit
def _chain_force(u):
    """A chain of Duffing springs fixed at one end: f = Dᵀ s(D u), s(d) = d + d³/2."""
    d = np.diff(np.concatenate((np.zeros(1), u)))
    s = d + 0.5 * d ** 3
    out = s.copy()
    out[:-1] -= s[1:]
    return out


@njit
def _chain_matrix(u, weights):
    """Dᵀ diag(weights(D u)) D for the chain's springs."""
    n = u.shape[0]
    out = np.zeros((n, n))
    for i in range(n):
        out[i, i] += weights[i]
        if i + 1 < n:
            out[i, i] += weights[i + 1]
            out[i, i + 1] -= weights[i + 1]
            out[i + 1, i] -= weights[i + 1]
    return out


@njit
def _chain_stiffness(u):
    d = np.diff(np.concatenate((np.zeros(1), u)))
    return _chain_matrix(u, 1.0 + 1.5 * d ** 2)


@njit
def _chain_derivative(u, w):
    d = np.diff(np.concatenate((np.zeros(1), u)))
    return _chain_matrix(u, 3.0 * d * np.diff(np.concatenate((np.zeros(1), w))))


@njit
def _chain_energy(u):
    d = np.diff(np.concatenate((np.zeros(1), u)))
    return np.sum(0.5 * d ** 2 + 0.125 * d ** 4)


@njit
def _chain_load(t):
    p = np.zeros(4)
    p[-1] = math.sin(3.0 * t)
    return p


@njit
def _chain_load_rate(t):
    p = np.zeros(4)
    p[-1] = 3.0 * math.cos(3.0 * t)
    return p


_NJIT_CHAIN = dict(internal_force=_chain_force, stiffness=_chain_stiffness,
                   stiffness_derivative=_chain_derivative, potential_energy=_chain_energy,
                   load=_chain_load, load_rate=_chain_load_rate)


def _njit_chain(**replace):
    parts = dict(_NJIT_CHAIN, **replace)
    return hfdi.System(np.array([1.0, 2.0, 1.0, 0.5]), parts.pop("internal_force"),
                       parts.pop("stiffness"), parts.pop("stiffness_derivative"),
                       damping=np.full(4, 0.05), initial_displacement=[0.1, 0.3, 0.2, 0.6],
                       **parts)


@pytest.mark.slow              # compiles the functions and their kernels: 5-10 s
@pytest.mark.parametrize("scheme", list(hfdi.SCHEMES))
def test_a_system_of_numba_functions_runs_compiled(scheme):
    """Its callables are called by kernels of the compiled loop: the run is
    compiled and is the Python path's run (the same functions) bit for bit."""
    model = _njit_chain()
    assert hfdi.check_derivatives(model).ok(1e-6)
    # rtol 1e-4: 170-1,300 steps (1e-6 took 9-13 thousand with Newmark and
    # Bathe, 10-27 s on the Python path, for the same comparison)
    compiled = hfdi.Integrator(model, scheme, rtol=1e-4)
    assert compiled.compiled
    assert compiled.advance(5.0)
    python = hfdi.Integrator(model, scheme, rtol=1e-4, compiled=False)
    assert python.advance(5.0)
    assert compiled.statistics.steps == python.statistics.steps > 50
    np.testing.assert_array_equal(compiled.state.u, python.state.u)
    np.testing.assert_array_equal(compiled.state.v, python.state.v)
    assert compiled.energy_error == python.energy_error


@pytest.mark.parametrize("python_parts", [
    ("internal_force", "stiffness", "stiffness_derivative", "potential_energy", "load",
     "load_rate"),
    pytest.param(("load",), marks=pytest.mark.slow),
    pytest.param(("potential_energy",), marks=pytest.mark.slow)])
def test_a_system_with_a_python_function_says_which_and_runs_python(python_parts, monkeypatch):
    """The first Python function is named (the others, numba's, are compiled
    when the Python path calls them: the slow tier)."""
    import hfdi.compiled as hc
    monkeypatch.setattr(hc, "_SAID", set())     # said once per process: maybe before
    model = _njit_chain(**{name: _NJIT_CHAIN[name].py_func for name in python_parts})
    said = f"System's {python_parts[0]} is a Python function"
    with pytest.raises(CompiledUnavailable, match=said):
        hfdi.Integrator(model, "newmark", rtol=1e-6, compiled=True)
    with pytest.warns(RuntimeWarning, match=said):
        assert not hfdi.Integrator(model, "newmark", rtol=1e-6).compiled


@pytest.mark.slow
def test_a_system_of_numba_functions_without_energy_or_load_runs_compiled():
    model = hfdi.System(np.ones(4), _chain_force, _chain_stiffness, _chain_derivative,
                        initial_displacement=[0.1, 0.3, 0.2, 0.6])
    itg = hfdi.Integrator(model, "hfdi", rtol=1e-6)
    assert itg.compiled
    assert itg.advance(3.0)
    python = hfdi.Integrator(model, "hfdi", rtol=1e-6, compiled=False)
    assert python.advance(3.0)
    np.testing.assert_array_equal(itg.state.u, python.state.u)
    assert math.isnan(itg.total_energy) and math.isnan(python.total_energy)
