"""Short steps (hfdi.core.estimate.SHORT_STEP): steps far shorter than the step
proposed, forced by a landing point a few rounding units away.

Before they were taken apart, a step of 1e-15 after steps of 1e-2 changed
the acceleration by a factor up to 1e13 and the velocity by 3 % (the schemes
divide differences of u by h²), and a communication point 2e-17 past a load
breakpoint made every later attempt fail its error test (the extrapolations
divide by the history step). These tests fail on that version.
"""
import numpy as np
import pytest

import hfdi
from hfdi.controller import ErrorControl
from hfdi.models import articulated, dumbbell

SCHEMES = ["newmark", "bathe", "hfdi"]
MODES = {"iterations": dict(target_iterations=3),
         "error": dict(controller=ErrorControl(1e-6, per_step=True)),
         "fixed": dict(step=2e-3)}


def _short_step_cases():
    for scheme in SCHEMES:
        for mode in MODES:
            for compiled in (False, True):
                # error control on the Python path: 1.7-2.5 s each, the slow tier
                slow = mode == "error" and not compiled
                yield pytest.param(scheme, mode, compiled,
                                   id=f"{scheme}-{mode}-{'compiled' if compiled else 'python'}",
                                   marks=pytest.mark.slow if slow else ())


@pytest.mark.parametrize("scheme, mode, compiled", list(_short_step_cases()))
def test_a_short_step_changes_the_state_as_the_motion_does(scheme, mode, compiled):
    """v and a change by what the motion gives over the short step, not by
    rounding divided by h²; and the run after it is the run without it."""
    itg = hfdi.Integrator(dumbbell(), scheme, compiled=compiled, **MODES[mode])
    assert itg.advance(0.1)
    before = itg.get_state()
    u0, v0, a0 = itg.state.u, itg.state.v, itg.state.a
    # the scheme's a_n is the equation of motion's up to the corrector's tolerance
    gap = np.abs(a0 - itg.ev.acceleration(0.1, u0, v0)).max()
    for d in (1e-15, 1e-12, 1e-9):
        itg.set_state(before)
        assert itg.advance(0.1 + d)
        state = itg.state
        assert np.abs(state.v - v0 - d * a0).max() <= 1e-6 * d * np.abs(a0).max() + \
            4 * np.spacing(np.abs(v0).max())
        # |a'| of the dumbbell stays below 1e6 |a| per second
        assert np.abs(state.a - a0).max() <= 1e6 * d * np.abs(a0).max() + 2 * gap + \
            1e-12 * np.abs(a0).max()
        assert np.abs(state.u - u0).max() <= 2 * d * np.abs(v0).max() + \
            4 * np.spacing(np.abs(u0).max())
    itg.set_state(before)
    direct = hfdi.Integrator(dumbbell(), scheme, compiled=compiled, **MODES[mode])
    assert direct.advance(0.1)
    assert itg.advance(0.1 + 1e-13) and itg.advance(0.3) and direct.advance(0.3)
    # within a tenth of the tolerance (the short step's a is the equation of
    # motion's, the scheme's a_n differs from it by the corrector's tolerance)
    scale = np.abs(direct.state.u).max()
    assert np.abs(itg.state.u - direct.state.u).max() <= 1e-7 * scale
    assert itg.statistics.steps <= 1.01 * direct.statistics.steps + 3


@pytest.mark.slow
@pytest.mark.parametrize("scheme", SCHEMES)
def test_communication_points_rounding_units_past_a_breakpoint(scheme):
    """Communication points summed as a master sums them (t += h) fall 2e-17
    past the articulated system's load breakpoint at 0.025: the run goes on,
    as accurate and about as cheap as with the points at k h."""
    options = dict(rtol=1e-6, compiled=True)
    summed = hfdi.Integrator(articulated(), scheme, **options)
    exact = hfdi.Integrator(articulated(), scheme, **options)
    h, t = 0.05 / 200, 0.0
    for k in range(1, 201):
        t += h
        assert summed.advance(t), summed.message
        assert exact.advance(min(k * h, t))
    assert t != 0.05 and 0.025 in summed.breakpoints
    reference = hfdi.Integrator(articulated(), "hfdi", rtol=1e-11, compiled=True)
    assert reference.advance(t)
    scale = np.abs(reference.state.u).max()
    error = np.abs(summed.state.u - reference.state.u).max() / scale
    error_exact = np.abs(exact.state.u - reference.state.u).max() / scale
    assert error <= 3 * error_exact + 1e-9, (error, error_exact)
    assert summed.statistics.steps <= 1.2 * exact.statistics.steps


def test_a_short_step_does_not_become_the_history():
    itg = hfdi.Integrator(dumbbell(), "hfdi", rtol=1e-6)
    assert itg.advance(0.1)
    previous = itg.get_state().previous
    assert itg.advance(0.1 + 1e-12)
    assert itg.get_state().previous.t == previous.t
    assert itg.advance(0.2)
    assert itg.get_state().previous.t > 0.1


@pytest.mark.slow
@pytest.mark.parametrize("scheme", SCHEMES)
def test_a_short_advance_before_the_first_step(scheme):
    """advance(1e-15) right after construction: a short step, the controller's
    first step still to come, and the run as accurate as without it (Bathe
    under error control ended 3e-5 off instead of 5e-8 when the scheme took
    that step)."""
    reference = hfdi.Integrator(dumbbell(), "hfdi", rtol=1e-11)
    assert reference.advance(0.2)
    scale = np.abs(reference.state.u).max()
    itg = hfdi.Integrator(dumbbell(), scheme, rtol=1e-6)
    direct = hfdi.Integrator(dumbbell(), scheme, rtol=1e-6)
    assert itg.advance(1e-15)
    assert itg.get_state().first_step_pending
    assert itg.advance(0.2) and direct.advance(0.2)
    error = np.abs(itg.state.u - reference.state.u).max() / scale
    error_direct = np.abs(direct.state.u - reference.state.u).max() / scale
    assert error <= 1.1 * error_direct + 1e-9, (error, error_direct)


# -- past a stiff component (hfdi.stepping.attempt.fastest_rate) --------------------------
K_STIFF = np.array([[1.0 + 1e10, -1e10], [-1e10, 1e10]])    # ω ≈ 1 and ≈ 1.4e5


def _two_masses(stiff_amplitude):
    """A soft spring to the ground and a very stiff one between two unit masses,
    the stiff mode excited with ``stiff_amplitude``."""
    return hfdi.LinearSystem(mass=[1.0, 1.0], stiffness=K_STIFF,
                             initial_displacement=[1.0, 1.0 + stiff_amplitude])


@pytest.mark.parametrize("scheme", SCHEMES)
def test_a_short_step_past_a_stiff_mode_leaves_it_alone(scheme):
    """Proposed steps of 0.1–1 s step over a mode of ω = 1.4e5 (unresolved; Newmark
    keeps its amplitude, Bathe and HFDI damp it). A short step of 5e-4 of the
    proposed one has ω h = 7–65: Taylor's expansion grew the mode 1,500 times
    and broke Newmark's energy balance (6e-2 of energy error, against 2e-14);
    the scheme takes such a step instead."""
    amplitude = 1e-10
    runs = [hfdi.Integrator(_two_masses(amplitude), scheme, target_iterations=3)
            for _ in range(2)]
    plain, interrupted = runs
    assert plain.advance(1.0) and interrupted.advance(1.0)
    h = 5e-4 * interrupted.proposed_step
    assert h * 1.4e5 > 1.0                     # beyond Taylor's reach
    assert interrupted.advance(1.0 + h)
    assert interrupted.get_state().previous.t < 1.0       # not the history
    assert plain.advance(3.0) and interrupted.advance(3.0)

    def stiff(itg):
        return abs(itg.state.u[1] - itg.state.u[0])
    assert stiff(interrupted) <= 1.1 * max(stiff(plain), 1e-12 * amplitude) + 1e-13
    # Newmark conserves the energy of a linear system, up to the solves'
    # rounding in the stiff mode (ω² = 2e10: 1e-15 of u is 1e-10 of energy);
    # Bathe's and HFDI's dissipation depends on the steps taken, which the
    # short step shifts: it stays dissipation (no energy gained) of the plain
    # run's order (measured 1.0-1.9 times it), where Taylor's step gained 6e-2
    scale = plain.total_energy
    if scheme == "newmark":
        assert abs(interrupted.energy_error - plain.energy_error) <= 1e-8 * scale
    else:
        assert interrupted.energy_error <= 1e-12 * scale
        assert abs(interrupted.energy_error) <= 4 * abs(plain.energy_error) + 1e-12 * scale
    assert np.abs(interrupted.state.u - plain.state.u).max() <= 1e-5


def test_the_fastest_rate_bounds_the_linearised_motion():
    """fastest_rate ≥ the largest |λ| of the first-order system's matrix, for dense,
    diagonal and sparse M and C; inf where M's bound is not positive."""
    import scipy.sparse as sp
    from hfdi.evaluation import Evaluator
    from hfdi.stepping.attempt import fastest_rate

    def rate_of(system):
        """fastest_rate at u = 0 from the records of an integrator of ``system``."""
        itg = hfdi.Integrator(system, "newmark", step=0.1, compiled=False)
        return fastest_rate(itg._functions(), itg._cfg, itg._data, itg._run, itg._vec)
    rng = np.random.default_rng(5)
    n = 6
    A = rng.standard_normal((n, n))
    M = A @ A.T + n * np.eye(n)
    B = rng.standard_normal((n, n))
    K = B @ B.T * 50.0
    C = 0.3 * (M + 0.01 * K)
    for mass in (M, np.diag(np.diag(M)), sp.csr_matrix(M)):
        for damping in (None, C, np.diag(C).copy()):
            system = hfdi.LinearSystem(mass=mass, stiffness=K, damping=damping)
            Md = np.diag(mass) if isinstance(mass, np.ndarray) and mass.ndim == 1 else (
                mass.toarray() if sp.issparse(mass) else mass)
            Cd = np.zeros((n, n)) if damping is None else (
                np.diag(damping) if damping.ndim == 1 else damping)
            first_order = np.block([[np.zeros((n, n)), np.eye(n)],
                                    [-np.linalg.solve(Md, K), -np.linalg.solve(Md, Cd)]])
            largest = np.abs(np.linalg.eigvals(first_order)).max()
            rate = rate_of(system)
            assert largest <= rate < 100 * largest or rate == np.inf
    # a large sparse M (kept sparse) is bounded by Gershgorin: here by 1 − 1.2 < 0,
    # no bound (its smallest eigenvalue is 1 − 0.6·√2 > 0)
    n = 130
    lumpy = sp.lil_matrix(sp.identity(n))
    lumpy[0, 1] = lumpy[1, 0] = lumpy[0, 2] = lumpy[2, 0] = 0.6
    system = hfdi.LinearSystem(mass=lumpy.tocsr(), stiffness=sp.identity(n, format="csr"))
    assert Evaluator(system).mass_floor() == 0.0 and rate_of(system) == np.inf
    lumpy[0, 1] = lumpy[1, 0] = lumpy[0, 2] = lumpy[2, 0] = 0.25
    system = hfdi.LinearSystem(mass=lumpy.tocsr(), stiffness=sp.identity(n, format="csr"))
    assert Evaluator(system).mass_floor() == 0.5 and rate_of(system) == np.sqrt(1.0 / 0.5)
