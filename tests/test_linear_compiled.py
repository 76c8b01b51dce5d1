"""``LinearSystem`` runs compiled where its parts allow, and a model that keeps
a run on the Python path says once why."""
import math
import warnings

import numpy as np
import pytest
from numba import njit

import hfdi
from hfdi.compiled import CompiledUnavailable

from problems import schemes_quick


def damped_chain(load=None, load_rate=None):
    """Three masses, dense M, K and C (a full mass matrix: HFDI's B is dense)."""
    rng = np.random.default_rng(0)
    A = rng.standard_normal((3, 3))
    K = A @ A.T + 3 * np.eye(3)
    return hfdi.LinearSystem(mass=np.eye(3) + 0.1 * np.ones((3, 3)), stiffness=K,
                             damping=0.05 * K, load=load, load_rate=load_rate,
                             initial_displacement=np.ones(3))


@njit
def _push(t):
    return np.array([math.sin(2.0 * t), 0.0, 0.0])


@njit
def _push_rate(t):
    return np.array([2.0 * math.cos(2.0 * t), 0.0, 0.0])


@pytest.mark.parametrize("forced", [False, True], ids=["free", "numba_load"])
@pytest.mark.parametrize("scheme", schemes_quick("hfdi"))
def test_a_linear_system_runs_compiled_and_as_on_the_python_path(scheme, forced):
    """Free, or forced by a load and exact load rate given as numba functions
    (called by the compiled loop's kernels): compiled, the Python path's run,
    and right against the closed form."""
    model = damped_chain(load=_push, load_rate=_push_rate) if forced else damped_chain()
    assert hfdi.Integrator(model, scheme, t_bound=1.0).compiled
    runs = [hfdi.integrate(model, scheme, 3.0, rtol=1e-5, compiled=c) for c in (False, True)]
    assert runs[0].stats.steps == runs[1].stats.steps
    # the kernels are the Python methods' own products (BLAS's dgemv both)
    np.testing.assert_allclose(runs[1].u, runs[0].u, rtol=0, atol=1e-12)
    # the first-order form's exponential, the load p = (sin 2t, 0, 0) as the
    # state of an oscillator beside it ((sin 2t)' = 2 cos 2t)
    from scipy.linalg import expm, solve
    M, K, C = model.mass, model.stiffness(None), model.damping
    big = np.zeros((8, 8))
    big[:3, 3:6] = np.eye(3)
    big[3:6, :3], big[3:6, 3:6] = -solve(M, K), -solve(M, C)
    if forced:
        big[3:6, 6] = solve(M, np.array([1.0, 0.0, 0.0]))
    big[6, 7], big[7, 6] = 2.0, -2.0
    exact = expm(3.0 * big) @ np.concatenate([np.ones(3), np.zeros(3), [0.0, 1.0]])
    assert np.abs(runs[1].u[-1] - exact[:3]).max() < 1e-3 * np.abs(exact[:3]).max()


def test_a_python_load_rate_beside_a_numba_load_is_named():
    model = damped_chain(load=_push, load_rate=lambda t: np.array([2.0 * np.cos(2.0 * t), 0, 0]))
    with pytest.raises(CompiledUnavailable, match="LinearSystem's load_rate is a Python function"):
        hfdi.Integrator(model, "hfdi", t_bound=1.0, compiled=True)


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
