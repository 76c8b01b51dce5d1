"""The compiled (numba) kernels of the paper's models: against the models' Python
f, K, T and V, against finite differences, and the rules of when they are used."""
import subprocess
import sys

import numpy as np
import pytest

import hfdi
from hfdi.compiled import CompiledKernels, SparseKernels, kernels_of, sparse_kernels_of
from hfdi.models import articulated, dumbbell, tetrahedra, toss_rule
from hfdi.models.dumbbell import Dumbbell

numba = pytest.importorskip("numba")

MODELS = {"dumbbell": dumbbell, "tetrahedra": tetrahedra, "articulated": articulated,
          "toss_rule": toss_rule}


def _dense(a):
    return a.toarray() if hasattr(a, "toarray") else np.asarray(a)


def _relative(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def _states(model, rng, n=6):
    """Random states around the initial one (5 % of the model's length), with
    random velocities for the directions of T."""
    u0 = model.initial_displacement
    return [(u0 + 0.05 * model.u_scale * rng.standard_normal(model.n_dof),
             rng.standard_normal(model.n_dof)) for _ in range(n)]


@pytest.mark.parametrize("name", hfdi.models.available())
def test_kernels_are_the_python_model_bit_for_bit(name):
    """The Python methods run the kernels' code as plain Python: the compiled
    kernels give the same bits, for f, K, T, V and the load."""
    model = hfdi.models.get(name)
    kernels, why = kernels_of(model)
    assert isinstance(kernels, CompiledKernels), why
    p = kernels.params
    for u, w in _states(model, np.random.default_rng(7)):
        f = kernels.force(u, p)
        assert f.shape == (model.n_dof,)
        np.testing.assert_array_equal(f, model.internal_force(u))
        np.testing.assert_array_equal(kernels.stiffness(u, p), _dense(model.stiffness(u)))
        np.testing.assert_array_equal(kernels.stiffness_derivative(u, w, p),
                                      _dense(model.stiffness_derivative(u, w)))
        assert kernels.potential_energy(u, p) == model.potential_energy(u)
    for t in np.linspace(-0.01, 0.06, 15):
        np.testing.assert_array_equal(kernels.load(float(t), kernels.load_params),
                                      model.load(float(t)))


def test_the_python_methods_follow_a_changed_attribute():
    """The kernels' data are built from the model at each call."""
    model = dumbbell()
    u = model.initial_displacement + 0.01
    before = model.internal_force(u)
    model.sigma = 0.8
    after = model.internal_force(u)
    assert not np.array_equal(before, after)
    kernels, _ = kernels_of(model)
    np.testing.assert_array_equal(kernels.force(u, kernels.params), after)


class _KernelModel(hfdi.SecondOrderSystem):
    """The compiled kernels alone as a model, for the finite-difference check."""

    def __init__(self, model, kernels):
        self.n_dof, self.mass, self.u_scale = model.n_dof, model.mass, model.u_scale
        self.initial_displacement = model.initial_displacement
        self.k = kernels

    def internal_force(self, u):
        return self.k.force(np.ascontiguousarray(u, dtype=float), self.k.params)

    def stiffness(self, u):
        return self.k.stiffness(np.ascontiguousarray(u, dtype=float), self.k.params)

    def stiffness_derivative(self, u, w):
        return self.k.stiffness_derivative(np.ascontiguousarray(u, dtype=float),
                                           np.ascontiguousarray(w, dtype=float), self.k.params)

    def potential_energy(self, u):
        return self.k.potential_energy(np.ascontiguousarray(u, dtype=float), self.k.params)


@pytest.mark.parametrize("name", list(MODELS))
def test_kernels_are_exact_derivatives(name):
    """f = ∂V/∂u, K = ∂f/∂u and T[w] = ∂(K w)/∂u by central differences
    (hfdi.check_derivatives), at states away from the initial one."""
    model = MODELS[name]()
    kernels, _ = kernels_of(model)
    check = hfdi.check_derivatives(_KernelModel(model, kernels), samples=6, spread=0.1)
    assert check.ok(1e-7), check


def test_a_wrong_kernel_fails_the_finite_difference_check():
    model = dumbbell()
    kernels, _ = kernels_of(model)
    wrong = kernels._replace(params=kernels.params * np.array([1.0, 1.0 + 1e-3]))
    mixed = _KernelModel(model, kernels)
    mixed.stiffness = lambda u: wrong.stiffness(np.ascontiguousarray(u), wrong.params)
    assert not hfdi.check_derivatives(mixed, samples=3, spread=0.1).ok(1e-6)


def test_a_subclass_that_changes_the_model_has_no_kernels():
    class Softer(Dumbbell):
        def internal_force(self, u):
            return 0.5 * super().internal_force(u)

    kernels, why = kernels_of(Softer())
    assert kernels is None and "internal_force" in why
    # a subclass that changes only data keeps them
    class Renamed(Dumbbell):
        name = "renamed"

    assert kernels_of(Renamed())[0] is not None


def test_a_model_without_kernels_says_why():
    model = hfdi.System([1.0], lambda u: u, lambda u: np.eye(1), lambda u, w: np.zeros((1, 1)))
    kernels, why = kernels_of(model)
    assert kernels is None and "System's internal_force is a Python function" in why
    # a LinearSystem has them, unless a part of it cannot be compiled
    assert kernels_of(hfdi.LinearSystem(mass=[1.0], stiffness=[[1.0]]))[0] is not None
    kernels, why = kernels_of(hfdi.LinearSystem(mass=[1.0], stiffness=[[1.0]],
                                                load=lambda t: np.ones(1)))
    assert kernels is None and "load is a Python function" in why


def test_importing_hfdi_does_not_import_numba():
    code = "import hfdi, hfdi.compiled, sys; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"


# -- large sparse beams: compiled f, K and T in the model's CSR pattern ----------------

@pytest.mark.parametrize("n_elements", [1, 7, 60])
def test_sparse_kernels_reproduce_the_python_model(n_elements):
    """The toss rule's SparseKernels against its Python methods: the same CSR
    pattern (indices and indptr) and the same values, bit for bit."""
    model = toss_rule(n_elements)
    kernels, why = sparse_kernels_of(model)
    assert isinstance(kernels, SparseKernels), why
    for u, w in _states(model, np.random.default_rng(11), n=4):
        np.testing.assert_array_equal(kernels.force(u), model.internal_force(u))
        for mine, python in ((kernels.stiffness(u), model.stiffness(u)),
                             (kernels.stiffness_derivative(u, w),
                              model.stiffness_derivative(u, w))):
            assert mine.format == "csr" and mine.has_canonical_format
            assert np.array_equal(mine.indptr, python.indptr)
            assert np.array_equal(mine.indices, python.indices)
            np.testing.assert_array_equal(mine.data, python.data)


class _SparseKernelModel(_KernelModel):
    def __init__(self, model, kernels):
        super().__init__(model, kernels)
        self.python = model

    def internal_force(self, u):
        return self.k.force(u)

    def stiffness(self, u):
        return self.k.stiffness(u)

    def stiffness_derivative(self, u, w):
        return self.k.stiffness_derivative(u, w)

    def potential_energy(self, u):
        return self.python.potential_energy(u)


def test_sparse_kernels_are_exact_derivatives():
    model = toss_rule(9)
    kernels, _ = sparse_kernels_of(model)
    check = hfdi.check_derivatives(_SparseKernelModel(model, kernels), samples=6, spread=0.1)
    assert check.ok(1e-7), check


def test_sparse_kernels_follow_the_rules_of_the_dense_ones():
    from hfdi.models.toss_rule import TossRule

    class Stiffer(TossRule):
        def stiffness(self, u):
            return 2.0 * super().stiffness(u)

    kernels, why = sparse_kernels_of(Stiffer(60))
    assert kernels is None and "stiffness" in why
    linear = hfdi.LinearSystem(mass=[1.0], stiffness=[[1.0]])
    assert "no compiled sparse kernels" in sparse_kernels_of(linear)[1]
