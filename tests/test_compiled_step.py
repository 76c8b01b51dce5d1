"""The compiled attempt (hfdi.compiled) against the Python attempt: the same steps,
Newton corrections and evaluations, and the same states to rounding, on every
paper model, scheme and mode; and when the compiled path is (not) taken."""
import math
import warnings

import numpy as np
import pytest
import scipy.sparse as sp

import hfdi
from hfdi import linalg
from hfdi.compiled import CompiledKernels, CompiledUnavailable
from hfdi.models import articulated, dumbbell, tetrahedra, toss_rule

numba = pytest.importorskip("numba")

#: Short horizons: a few hundred steps at most under error control; the
#: iteration count's long steps get a longer one.
PROBLEMS = {"dumbbell": (dumbbell, 0.01, 0.2), "tetrahedra": (tetrahedra, 1.5, 5.0),
            "articulated": (articulated, 0.03, 0.2), "toss_rule": (toss_rule, 0.003, 0.012)}
MODES = {"fixed": dict(step=1 / 40), "iterations": dict(target_iterations=3),
         "error": dict(rtol=1e-6)}
COUNTERS = ("steps", "accepted", "rejected", "newton_iterations", "error_test_failures",
            "first_step_trials", "first_step_trial_iterations", "nfev", "njev", "ntev", "nlu")


#: Models whose Python f, K, T sum their pair or element terms by BLAS products
#: in another order than the kernels: K and T agree to rounding, not bit for bit.
#: (The dumbbell's and the articulated system's agree bit for bit, and so do
#: their whole runs.)
NOT_BITWISE = ("tetrahedra", "toss_rule")


def case(problem, mode, problems=PROBLEMS, modes=MODES):
    """``(make, t_end, options)`` of a run of ``problem`` in ``mode``: the long
    horizon for the iteration-count mode, else the short one; a fixed step is
    given as a fraction of the horizon."""
    make, short, long = problems[problem]
    t_end = long if mode == "iterations" else short
    options = dict(modes[mode])
    if mode == "fixed":
        options["step"] *= t_end
    return make, t_end, options


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


def _cases():
    """Every model x scheme x mode; the beam under error control (thousands of
    steps, > 1 s) is marked slow."""
    for problem in PROBLEMS:
        for scheme in ("newmark", "bathe", "hfdi"):
            for mode in MODES:
                slow = problem == "toss_rule" and mode == "error"
                yield pytest.param(problem, scheme, mode, id=f"{problem}-{scheme}-{mode}",
                                   marks=[pytest.mark.slow] if slow else [])


@pytest.mark.parametrize("problem, scheme, mode", list(_cases()))
def test_compiled_attempt_takes_the_same_steps(problem, scheme, mode):
    make, t_end, options = case(problem, mode)
    python = hfdi.integrate(make(), scheme, t_end, compiled=False, **options)
    compiled = hfdi.integrate(make(), scheme, t_end, compiled=True, **options)
    assert python.success and python.stats.steps > 5
    if mode != "error" or problem not in NOT_BITWISE:
        _assert_same_run(python, compiled, problem not in NOT_BITWISE)
        return
    # Under error control the step sizes follow the error estimate, a
    # difference of nearly equal states, and the controller carries it from
    # step to step: rounding differences of K and T move the step sizes. The
    # weights of v also hold the corrector's estimated remaining error, which
    # after a single correction is the carried quadratic constant times
    # ‖Δu‖², the constant measured from second corrections at the level of
    # rounding: the step sizes differ by up to ~3e-5 relative here (~2e-8
    # with newton_test="correction"). The counts stay equal, and the end
    # states (both runs land on t_end) agree to ~3e-11.
    _assert_same_counts(python, compiled)
    np.testing.assert_allclose(compiled.t, python.t, rtol=2e-4, atol=0)
    assert _relative_error(compiled.u[-1], python.u[-1]) < 1e-10
    assert _relative_error(compiled.v[-1], python.v[-1]) < 1e-8


def test_the_paths_are_chosen_as_asked():
    model = dumbbell()
    assert hfdi.Integrator(model, "hfdi", step=1e-3).compiled           # default: auto
    assert hfdi.Integrator(model, "hfdi", step=1e-3, compiled=None).compiled   # auto
    assert hfdi.Integrator(model, "hfdi", step=1e-3, compiled=True).compiled
    assert not hfdi.Integrator(model, "hfdi", step=1e-3, compiled=False).compiled
    with pytest.raises(ValueError, match="compiled must be"):
        hfdi.Integrator(model, "hfdi", step=1e-3, compiled="yes")


def test_compiled_true_without_kernels_is_refused_with_the_reason():
    linear = hfdi.LinearSystem(mass=[1.0], stiffness=[[4.0]], initial_displacement=[1.0])
    assert not hfdi.Integrator(linear, "hfdi", step=0.1, compiled=None).compiled
    with pytest.raises(CompiledUnavailable, match="no compiled kernels"):
        hfdi.Integrator(linear, "hfdi", step=0.1, compiled=True)
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


@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
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


@pytest.mark.parametrize("damping", [None, np.array([0.3, 0.1, 0.2]),
                                     np.array([[0.4, -0.1, 0.0], [-0.1, 0.3, -0.1],
                                               [0.0, -0.1, 0.2]])],
                         ids=["undamped", "diagonal C", "dense C"])
@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
@pytest.mark.slow
def test_user_model_with_dense_mass_and_damping(scheme, damping):
    model = Chain(damping)
    assert hfdi.check_derivatives(model, samples=3, spread=0.1).ok(1e-7)
    runs = [hfdi.integrate(model, scheme, 0.5, rtol=1e-6, compiled=c) for c in (False, True)]
    assert runs[0].success and runs[0].stats.steps > 20
    _assert_same_run(*runs)


# -- sparse systems: Python steps, compiled model -------------------------------------

def _beam_run(model, scheme, compiled, t_end, u0=None):
    itg = hfdi.Integrator(model, scheme, target_iterations=3.0, compiled=compiled, u0=u0)
    itg.advance(t_end)
    return itg


@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
@pytest.mark.parametrize("n_elements", [200, 1500])
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
    assert (python.ev.nfev, python.ev.njev, python.ev.ntev, python.ev.nlu) == \
        (compiled.ev.nfev, compiled.ev.njev, compiled.ev.ntev, compiled.ev.nlu)
    assert python.t == compiled.t
    for x in ("u", "v"):
        rounding = _relative_error(getattr(nudged.state, x), getattr(python.state, x))
        assert _relative_error(getattr(compiled.state, x), getattr(python.state, x)) \
            <= max(10.0 * rounding, 1e-12), x


def test_sparse_kernels_of_another_model_are_refused(monkeypatch):
    """The library's own kernels, handed out with another model's data by a
    method that is not the library's, are checked as any others."""
    import hfdi.compiled as hc
    import hfdi.compiled.models  # noqa: F401  (hc.models below)
    from hfdi.models.toss_rule import TossRule
    monkeypatch.setattr(hc, "_SAID", set())
    other = toss_rule(60, E=2.0e11)
    monkeypatch.setattr(TossRule, "compiled_sparse_kernels",
                        lambda self: hc.models.toss_rule_sparse_kernels(other))
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
    from hfdi import schemes
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
    python = schemes._InterleavedBlockTangent(b, model.mass, C, K, T, 2e-9, 4e-5)
    compiled = schemes._InterleavedBlockTangent(b, model.mass, C, K, T, 2e-9, 4e-5, band)
    lower = max(linalg.banded_from_sparse(a, bandwidths_only=True)[1] for a in (K, T))
    upper = max(linalg.banded_from_sparse(a, bandwidths_only=True)[2] for a in (K, T))
    mine = band.interleaved_block_band(K, T, model.mass, C, b, 2e-9, 4e-5, lower, upper)
    assert np.array_equal(mine[0], python.band()[0]) and mine[1:] == python.band()[1:]
    rhs = rng.standard_normal(model.n_dof)
    assert np.array_equal(compiled.solve(rhs), python.solve(rhs))
    shift = 1e3 * model.mass
    assert np.array_equal(schemes._ShiftedTangent(K, shift, band).solve(rhs),
                          schemes._ShiftedTangent(K, shift).solve(rhs))


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
    for compiled in (False, None):
        itg = hfdi.Integrator(model, scheme, rtol=1e-6, compiled=compiled)
        itg.advance(0.02)
        runs[compiled] = itg
    python, default = runs[False], runs[None]
    assert default.compiled_model and not python.compiled_model
    assert python.status == hfdi.Status.RUNNING and python.statistics.accepted > 10
    for name in ("steps", "accepted", "rejected", "newton_iterations"):
        assert getattr(python.statistics, name) == getattr(default.statistics, name), name
    assert _relative_error(default.state.u, python.state.u) < 1e-10
    assert _relative_error(default.state.v, python.state.v) < 1e-9
