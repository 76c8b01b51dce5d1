"""IDA in C with compiled callbacks (``benchmarks.ida_compiled``), the bench's machine-speed competitor.

It must be IDA on the same problem as scikit-sundae's IDA: the same
first-order form, tolerances and consistent start, so the same steps and
the same answer (the two builds of SUNDIALS differ in version, not in the
method); a residual or Jacobian written wrong would change IDA's Newton
iterations, steps or answer.
"""
import sys
from pathlib import Path

import numpy as np
import pytest

import hfdi
from hfdi.models import Dumbbell
from validation.reference import default_atol, ida_solve

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks import ida_compiled  # noqa: E402

OK, WHY = ida_compiled.available()
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not OK, reason=f"IDA in C not available: {WHY}")]


class DenseDamped(Dumbbell):
    """The dumbbell with a full mass matrix and a full damping matrix (the
    same kernels: f, K and p are the dumbbell's)."""

    def __init__(self):
        super().__init__()
        n = self.n_dof
        rng = np.random.default_rng(3)
        A = rng.uniform(-0.1, 0.1, (n, n))
        self.mass = np.diag(np.repeat(self.masses, 2)) + 0.5 * (A + A.T) * 0.2
        self.damping = 0.3 * np.eye(n) + 0.05 * np.ones((n, n))


def _both(model, t_end, rtol):
    atol = default_atol(model, rtol, t_end)
    ours = ida_compiled.solve(ida_compiled.Problem(model), t_end, rtol=rtol, atol=atol)
    theirs = ida_solve(model, t_end, rtol=rtol, atol=atol)
    return ours, theirs


@pytest.mark.parametrize("make, t_end, rtol", [
    (lambda: hfdi.models.get("dumbbell"), 0.3, 1e-6),
    (lambda: hfdi.models.get("articulated"), 0.1, 1e-5),
    (lambda: hfdi.models.get("tetrahedra"), 0.5, 1e-6),
    (DenseDamped, 0.1, 1e-6),
])
def test_the_same_run_as_scikit_sundae(make, t_end, rtol):
    ours, theirs = _both(make(), t_end, rtol)
    assert ours["success"] and theirs["success"]
    assert ours["t"][-1] == t_end
    # The same method on the same problem: the same steps, Newton iterations
    # and answer, to rounding. Rounding is not the same (the kernels sum in
    # another order than the Python methods, and the SUNDIALS builds differ),
    # and IDA's step choices amplify it over long runs (the articulated
    # system over 0.5 s: 5,306 steps against 4,964): short spans, and 5 %.
    steps = theirs["t"].size - 1
    assert abs(ours["steps"] - steps) <= 0.05 * steps
    assert abs(ours["nfev"] / ours["steps"] - theirs["nfev"] / steps) <= 0.05 * nfev_per_step(theirs)
    scale = np.abs(theirs["u"]).max()
    assert np.abs(ours["u"][-1] - theirs["u"][-1]).max() <= 10 * rtol * scale
    assert np.abs(ours["v"][-1] - theirs["v"][-1]).max() <= 10 * rtol * np.abs(theirs["v"]).max()


def nfev_per_step(run):
    return run["nfev"] / (run["t"].size - 1)


def test_accuracy_follows_rtol():
    """Against the exact motion of an undamped linear oscillator with diagonal
    mass (the dumbbell near its rest length is not linear: use a tight run as
    the reference instead, and check that the error falls with rtol)."""
    model = hfdi.models.get("dumbbell")
    problem = ida_compiled.Problem(model)
    t_end = 0.2
    ref = ida_compiled.solve(problem, t_end, rtol=1e-12, atol=default_atol(model, 1e-12, t_end))
    errors = []
    for rtol in (1e-4, 1e-6, 1e-8):
        run = ida_compiled.solve(problem, t_end, rtol=rtol, atol=default_atol(model, rtol, t_end))
        errors.append(np.abs(run["u"][-1] - ref["u"][-1]).max())
    assert errors[0] > 10 * errors[1] > 100 * errors[2]


def test_the_budget_stops_a_run_with_its_status():
    model = hfdi.models.get("dumbbell")
    run = ida_compiled.solve(ida_compiled.Problem(model), 1.0, rtol=1e-6,
                             atol=default_atol(model, 1e-6, 1.0), max_nfev=50)
    assert not run["success"] and run["status"] == "BUDGET"
    assert "work budget" in run["message"] and 50 < run["nfev"] < 60
    assert run["t"][-1] < 1.0 and run["t"].size == run["steps"] + 1


def test_bad_tolerances_are_refused_by_name():
    model = hfdi.models.get("dumbbell")
    problem = ida_compiled.Problem(model)
    with pytest.raises(ValueError, match="rtol"):
        ida_compiled.solve(problem, 1.0, rtol=0.0, atol=np.ones(8))
    with pytest.raises(ValueError, match="atol"):
        ida_compiled.solve(problem, 1.0, rtol=1e-6, atol=np.ones(3))
    with pytest.raises(ValueError, match="atol"):
        ida_compiled.solve(problem, 1.0, rtol=1e-6, atol=-np.ones(8))


def test_a_model_without_compiled_kernels_is_refused():
    system = hfdi.System(np.eye(2), lambda u: u, lambda u: np.eye(2),
                         lambda u, w: np.zeros((2, 2)), initial_displacement=[1.0, 0.0])
    with pytest.raises(ValueError, match="compiled kernels"):
        ida_compiled.Problem(system)
