"""``LinearSystem`` runs compiled where its parts allow, and a model that keeps
a run on the Python path says once why."""
import warnings

import numpy as np
import pytest

import hfdi
from hfdi.compiled import CompiledUnavailable

from problems import schemes_quick


def damped_chain(load=None):
    """Three masses, dense M, K and C (a full mass matrix: HFDI's B is dense)."""
    rng = np.random.default_rng(0)
    A = rng.standard_normal((3, 3))
    K = A @ A.T + 3 * np.eye(3)
    return hfdi.LinearSystem(mass=np.eye(3) + 0.1 * np.ones((3, 3)), stiffness=K,
                             damping=0.05 * K, load=load, initial_displacement=np.ones(3))


@pytest.mark.parametrize("scheme", schemes_quick("hfdi"))
def test_a_linear_system_runs_compiled_and_as_on_the_python_path(scheme):
    model = damped_chain()
    assert hfdi.Integrator(model, scheme, t_bound=1.0).compiled
    runs = [hfdi.integrate(model, scheme, 3.0, rtol=1e-4, compiled=c) for c in (False, True)]
    assert runs[0].stats.steps == runs[1].stats.steps
    # the kernels are the Python methods' own products (BLAS's dgemv both)
    np.testing.assert_allclose(runs[1].u, runs[0].u, rtol=0, atol=1e-12)
    # and the answer is right: against the matrix exponential of the first-order form
    from scipy.linalg import expm, solve
    M, K, C = model.mass, model.stiffness(None), model.damping
    A = np.block([[np.zeros((3, 3)), np.eye(3)], [-solve(M, K), -solve(M, C)]])
    exact = expm(3.0 * A) @ np.concatenate([np.ones(3), np.zeros(3)])
    assert np.abs(runs[1].u[-1] - exact[:3]).max() < 1e-3 * np.abs(exact[:3]).max()


def test_a_python_load_keeps_it_on_the_python_path_and_says_why_once():
    model = damped_chain(load=lambda t: np.array([1.0, 0.0, 0.0]))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        first = hfdi.Integrator(model, "hfdi", t_bound=1.0)
        hfdi.Integrator(model, "hfdi", t_bound=1.0)
    assert not first.compiled
    said = [w for w in caught if "the steps run in Python" in str(w.message)]
    assert len(said) <= 1         # once per process (an earlier test may have said it)
    assert "load is a Python function" in first.not_compiled_reason
    with pytest.raises(CompiledUnavailable, match="Python function"):
        hfdi.Integrator(model, "hfdi", t_bound=1.0, compiled=True)
