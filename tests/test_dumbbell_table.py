"""The dumbbell at the paper's targets (Table 2)."""
import numpy as np
import pytest

import hfdi
from validation.experiments import experiment

MODEL = hfdi.models.dumbbell()
TABLE_2 = experiment("dumbbell")
T_O = TABLE_2.observation_time
RUNS = [(s, n) for s, targets in TABLE_2.targets.items() for n in targets]
_cache = {}


def run(scheme, target):
    if (scheme, target) not in _cache:
        _cache[scheme, target] = hfdi.integrate(MODEL, scheme, T_O,
                                                target_iterations=target)
    return _cache[scheme, target]


@pytest.mark.parametrize("scheme, target", RUNS)
def test_run_completes_or_reports_divergence(scheme, target):
    result = run(scheme, target)
    if result.success:
        assert result.t[-1] == T_O
    else:
        assert result.status < 0 and result.message
    st = result.stats
    assert st.steps == st.accepted + st.rejected
    assert st.newton_iterations >= st.steps
    assert np.isclose(st.mean_step, result.t[-1] / st.steps)


@pytest.mark.parametrize("scheme, target", [
    r if r != ("bathe", 5.0) else pytest.param(
        *r, marks=pytest.mark.xfail(strict=True, reason=(
            "31 steps only: the start-up ramp (first step sized with the linear "
            "predictor, growth ≤ (10/8)^½ per step) pulls N_mv to 9.58; the paper "
            "reports 9.586 for this run")))
    for r in RUNS])
def test_mean_iterations_track_the_target(scheme, target):
    result = run(scheme, target)
    step_target = target * (2 if scheme == "bathe" else 1)
    assert abs(result.stats.mean_iterations - step_target) <= 0.35


@pytest.mark.parametrize("target", [3.0, 3.5])
def test_hfdi_needs_fewer_steps_than_newmark(target):
    assert run("hfdi", target).stats.steps < run("newmark", target).stats.steps


@pytest.mark.parametrize("target", [3.0, 3.5])
def test_hfdi_needs_fewer_newton_iterations_than_bathe(target):
    """Bathe's step is two sub-steps; the paper's N_tot counts both."""
    assert run("hfdi", target).stats.newton_iterations < \
        run("bathe", target).stats.newton_iterations


def test_motion_is_a_rigid_rotation_with_the_bond_at_its_mean_stretch():
    """u'(0) is perpendicular to the bond: the dumbbell spins at 5 rad/s about its
    centre, which moves at (0, 7.5); the centrifugal stretch is mω²r/(2k)."""
    result = run("hfdi", 3.3)
    centre = 0.5 * (result.u[:, :2] + result.u[:, 2:])
    np.testing.assert_allclose(centre[-1], [0.5, 15.0], atol=1e-9)
    angle = np.unwrap(np.arctan2(result.u[:, 3] - result.u[:, 1], result.u[:, 2] - result.u[:, 0]))
    np.testing.assert_allclose(angle, -5.0 * result.t, atol=2e-3)
    k_bond = MODEL.stiffness(MODEL.initial_displacement)[0, 0]
    # after the first steps, which the L-stable scheme needs to damp the bond's start-up
    stretch = MODEL.quantities(result.t, result.u, result.v)["stretch"][result.t > 0.05, 0]
    np.testing.assert_allclose(stretch, 25.0 * 0.5 / k_bond, rtol=0.02)
