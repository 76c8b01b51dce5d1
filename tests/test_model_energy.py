"""Energy after the load has finished (Eqs. 40–41), every model, every scheme.

Newmark keeps W = V + T up to its (second-order) error on a nonlinear problem;
Bathe and HFDI only take energy out, of the modes their steps do not resolve.
Runs at the paper's finest target, N̄ = 3 (Bathe 2·3).
"""
import numpy as np
import pytest

import hfdi

# time the load ends, and the relative energy loss allowed to the dissipative
# schemes: the tetrahedra's stiff spring (ω ≈ 45 rad/s) is far from resolved by
# steps of ≈ 0.2, its vibration is damped out; elsewhere the motion is resolved.
CASES = {"dumbbell": (0.0, 0.01), "tetrahedra": (2.0, 0.15), "articulated": (0.05, 0.01),
         "toss_rule": (0.01, 0.01)}
_runs = {}


def run(name, scheme):
    if (name, scheme) not in _runs:
        model = hfdi.models.get(name)
        result = hfdi.integrate(model, scheme, model.observation_time, target_iterations=3.0)
        assert result.success, result.message
        after = result.t >= CASES[name][0]
        # the energy of the motion: V has an arbitrary constant (the dumbbell's
        # W ≈ −1.9e5 is mostly V(r₀)), so compare changes with the kinetic energy
        kinetic = 0.5 * np.sum(np.asarray(model.mass) * result.v ** 2, axis=1)
        _runs[name, scheme] = (result.total_energy[after], kinetic.max())
    return _runs[name, scheme]


@pytest.mark.parametrize("name", list(CASES))
def test_newmark_keeps_the_energy(name):
    W, scale = run(name, "newmark")
    assert abs(W[-1] - W[0]) <= 0.01 * scale


@pytest.mark.parametrize("scheme", ["bathe", "hfdi"])
@pytest.mark.parametrize("name", list(CASES))
def test_dissipative_schemes_only_take_energy_out(name, scheme):
    W, scale = run(name, scheme)
    loss = (W[0] - W[-1]) / scale
    assert -1e-4 <= loss <= CASES[name][1]
    # nonlinear exchange between modes may lift W slightly within a step, never much
    assert np.max(np.diff(W)) <= 0.01 * scale
