"""Events: zeros of g(t, u, v) located between step ends, terminal events, resets.

Against exact event times: a linear oscillator's zero crossings and extrema,
and a bouncing ball with restitution (impact times in closed form, which the
schemes integrate exactly between impacts, so only the event machinery can
err). Both speeds find the same events at the same times.
"""
import math

import numpy as np
import pytest

import hfdi
from hfdi.events import EventError

from problems import schemes_quick

W = 3.0          # the oscillator's angular frequency
G, H0, E = 9.81, 1.0, 0.8


def oscillator():
    return hfdi.LinearSystem(mass=[1.0], stiffness=[[W * W]], initial_displacement=[1.0],
                             initial_velocity=[0.0])


def ball():
    return hfdi.LinearSystem(mass=[1.0], stiffness=[[0.0]], load=lambda t: np.array([-G]),
                             initial_displacement=[H0], initial_velocity=[0.0])


def impact_times(count):
    """The ball's impacts: first at √(2 H0/G), then each flight 2 eᵏ v1 / G."""
    t1 = math.sqrt(2 * H0 / G)
    v1 = G * t1
    times = [t1]
    for k in range(1, count):
        times.append(times[-1] + 2 * E ** k * v1 / G)
    return np.array(times)


def floor_event():
    def floor(t, u, v):
        return u[0]
    floor.direction = -1
    return floor


def bounce(t, u, v, which):
    return u, -E * v


def test_oscillator_zeros_and_extrema_hfdi():
    """u = cos 3t: u's zeros at (k + ½)π/3, v's (the extrema) at kπ/3 — t0 too,
    where v starts at zero and leaves it (as solve_ivp counts it)."""
    r = hfdi.integrate(oscillator(), "hfdi", 2.0, rtol=1e-10,
                       events=[lambda t, u, v: u[0], lambda t, u, v: v[0]])
    assert r.success
    tu, tv = r.t_events
    np.testing.assert_allclose(tu, (np.arange(2) + 0.5) * math.pi / W, rtol=1e-10, atol=0)
    np.testing.assert_allclose(tv, np.arange(2) * math.pi / W, rtol=1e-10, atol=1e-15)
    # the state at the events: by the dense output
    np.testing.assert_allclose(r.u_events[0][:, 0], 0.0, atol=1e-10)
    np.testing.assert_allclose(np.abs(r.v_events[0][:, 0]), W, rtol=1e-9)
    np.testing.assert_allclose(np.abs(r.u_events[1][:, 0]), 1.0, rtol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("scheme", ["newmark", "bathe", "generalized_alpha"])
def test_oscillator_zeros_second_order_schemes(scheme):
    r = hfdi.integrate(oscillator(), scheme, 2.0, rtol=1e-7, events=lambda t, u, v: u[0])
    assert r.success
    # the times are as accurate as the solution: its error over the speed
    np.testing.assert_allclose(r.t_events[0], (np.arange(2) + 0.5) * math.pi / W, rtol=1e-7)


def test_direction_is_honoured():
    up = lambda t, u, v: u[0]        # noqa: E731
    up.direction = 1
    down = lambda t, u, v: u[0]      # noqa: E731
    down.direction = -1
    r = hfdi.integrate(oscillator(), "hfdi", 4.0, rtol=1e-8, events=[up, down])
    # cos 3t falls through zero at π/6, rises at π/2, falls at 5π/6, ...
    zeros = (np.arange(4) + 0.5) * math.pi / W
    np.testing.assert_allclose(r.t_events[0], zeros[1::2], rtol=1e-7)
    np.testing.assert_allclose(r.t_events[1], zeros[0::2], rtol=1e-7)


@pytest.mark.parametrize("compiled", [pytest.param(False, marks=pytest.mark.slow), None])
def test_a_terminal_event_ends_the_run_at_its_zero(compiled):
    g = lambda t, u, v: u[0]         # noqa: E731
    g.terminal = 2
    r = hfdi.integrate(oscillator(), "hfdi", 10.0, rtol=1e-9, events=g, compiled=compiled,
                       t_eval=np.linspace(0, 10, 11))
    assert r.status == hfdi.Status.TERMINATED and r.success
    assert "events[0]" in r.message
    expected = 1.5 * math.pi / W
    assert r.t[-1] == r.t_events[0][-1]
    assert r.t_events[0].size == 2
    assert abs(r.t[-1] - expected) <= 1e-9 * expected
    assert abs(r.u[-1, 0]) <= 1e-8
    # t_eval only up to the end, as solve_ivp
    assert r.t_eval[-1] <= r.t[-1] and r.u_eval.shape == (r.t_eval.size, 1)
    assert not np.isnan(r.u_eval).any()


def test_several_events_in_one_step_come_in_time_order():
    """Five levels crossed by one long step (the ball's free fall is exact in
    a few steps): each found, in time order."""
    levels = [0.9, 0.7, 0.5, 0.3, 0.1]
    events = [(lambda c: lambda t, u, v: u[0] - c)(c) for c in levels]
    r = hfdi.integrate(ball(), "newmark", 0.45, step=0.45, events=events)
    assert r.stats.steps == 1
    found = [te[0] for te in r.t_events]
    np.testing.assert_allclose(found, [math.sqrt(2 * (H0 - c) / G) for c in levels],
                               rtol=1e-12)
    order = []
    record = []

    def watch(t, u, v, which):
        record.append((t, which))
        return None
    hfdi.integrate(ball(), "newmark", 0.45, step=0.45, events=events[::-1], on_event=watch)
    order = [which for _, which in record]
    assert order == [4, 3, 2, 1, 0]          # the functions given in reverse
    assert [t for t, _ in record] == sorted(t for t, _ in record)


@pytest.mark.parametrize("scheme", schemes_quick("hfdi", "newmark"))
def test_bouncing_ball_with_restitution(scheme):
    """Impacts at the closed-form times (to rounding: the flight is a
    parabola every scheme integrates exactly), the energy that each impact
    takes recorded as work, so that the energy balance stays closed."""
    r = hfdi.integrate(ball(), scheme, 3.0, rtol=1e-6, events=floor_event(),
                       on_event=bounce)
    assert r.success
    exact = impact_times(20)
    exact = exact[exact < 3.0]
    np.testing.assert_allclose(r.t_events[0], exact, rtol=1e-12)
    assert r.u.min() > -1e-12
    # v jumps from −e^k v1 to +e^(k+1) v1 at each impact: the row after it
    after = np.flatnonzero((r.step_size == 0) & (r.v[:, 0] > 0))
    assert after.size == exact.size
    v1 = G * exact[0]
    np.testing.assert_allclose(r.v[after, 0], v1 * E ** np.arange(1, exact.size + 1),
                               rtol=1e-12)
    # the lost kinetic energy ½(1 − e²)v² per impact is the (negative) work
    balance = r.total_energy - r.external_work
    assert np.abs(balance - balance[0]).max() <= 1e-12 * G * H0
    lost = 0.5 * (1 - E ** 2) * (v1 * E ** np.arange(exact.size)) ** 2
    gravity_work = r.external_work[-1] - (-lost.sum())
    u_last = r.u[-1, 0]
    assert math.isclose(gravity_work, G * (H0 - u_last), rel_tol=1e-10)


@pytest.mark.parametrize("scheme", schemes_quick("hfdi", "bathe"))
def test_impacts_accumulating_to_rest_stop_the_run_at_their_zeno_point(scheme):
    """The ball bouncing to rest: its impacts accumulate at t∞ = t1 + 2 e v1 /
    (G (1 − e)) (closed form), past which no step resolves them (it fell
    through the floor with SUCCESS). The run stops there, a failure saying
    so, with every impact before it at its closed-form time and the ball
    never below the floor."""
    t1 = math.sqrt(2 * H0 / G)
    t_zeno = t1 + 2 * E * (G * t1) / (G * (1 - E))
    r = hfdi.integrate(ball(), scheme, 2 * t_zeno, rtol=1e-6, events=floor_event(),
                       on_event=bounce)
    assert r.status == hfdi.Status.MODEL_ERROR and "accumulate" in r.message, r.message
    assert t_zeno - 1e-3 < r.t[-1] <= t_zeno
    assert r.u.min() > -1e-12
    count = r.t_events[0].size
    assert count >= hfdi.event_steps.ZENO_ZEROS
    exact = impact_times(count)
    # to rounding of the times (their spacing shrinks to 1e-6 of the time)
    np.testing.assert_allclose(r.t_events[0], exact, rtol=0, atol=1e-9)


def test_a_zero_taken_again_from_a_restored_state_is_no_zeno_point():
    """A master that restores a state before a zero and takes the step again
    (a co-simulation's rollback) answers that zero again at the same time:
    the twelfth time is as the first (the tenth stopped as a Zeno point)."""
    itg = hfdi.Integrator(oscillator(), "hfdi", rtol=1e-6, t_bound=10.0,
                          events=lambda t, u, v: u[0], on_event=lambda t, u, v, which: None)
    before = itg.get_state()
    for _ in range(12):
        itg.set_state(before)
        assert itg.advance(1.0), itg.message
    assert itg.status == hfdi.Status.RUNNING and itg.t == 1.0


@pytest.mark.parametrize("floor_at", [100.0, pytest.param(1e4, marks=pytest.mark.slow),
                                      pytest.param(-1e6, marks=pytest.mark.slow)])
def test_a_floor_away_from_zero_is_not_fallen_through(floor_at):
    """The floor at u = 100: after a rebound's reset g = u − 100 read exactly
    0 at the probe just after it (the first ulps of motion are below the
    rounding of u), was taken as a zero held over a while, and the ball's
    fall below the floor was skipped: SUCCESS at −81 below it. It bounces as
    on a floor at 0, to its Zeno point. At 1e4 the flights stopped
    shortening at the rounding of u (0.7–1.1e-6 s, never ten in a row below
    the interval rule's threshold) and the ball bounced there, a step each,
    until max_steps (hours at the default); now within the rounding of u
    from its Zeno point (1e-3 of the time about it at 1e6)."""
    model = hfdi.LinearSystem(mass=[1.0], stiffness=[[0.0]], load=lambda t: np.array([-G]),
                              initial_displacement=[floor_at + H0], initial_velocity=[0.0])

    def floor(t, u, v):
        return u[0] - floor_at
    floor.direction = -1
    t1 = math.sqrt(2 * H0 / G)
    t_zeno = t1 + 2 * E * (G * t1) / (G * (1 - E))
    r = hfdi.integrate(model, "hfdi", 2 * t_zeno, rtol=1e-8, events=floor,
                       on_event=lambda t, u, v, which: (np.array([floor_at]), -E * v))
    assert r.status == hfdi.Status.MODEL_ERROR and "accumulate" in r.message, r.message
    assert t_zeno - 1e-3 < r.t[-1] <= t_zeno
    assert r.t_events[0].size < 100, r.t_events[0].size
    assert r.u.min() >= floor_at - max(1e-12, 8 * np.spacing(abs(floor_at)))


@pytest.mark.slow
def test_a_bounce_at_the_rounding_of_u_is_judged_by_the_components_it_moves():
    """The rule for bounces at the rounding of u looks at each component the
    reset changed, against its own u: a ball on a floor at 1e4 beside an
    oscillator of amplitude 1 (the largest speed of all kept the rule from
    firing: 2,252 zeros past the Zeno time until max_steps), with a bounce
    counter the reset adds 1 to (a rule over every changed component never
    fired), stops at its Zeno point; a rattle of 1e-9 beside a coordinate
    resting at 1e9 (the rounding of ‖u‖∞ took its bounces for rounding), a
    stepper that a clock's reset moves by 1e-3 while at rest (its speed 0),
    and a sampled controller that nudges a mass at 1e4 by 1e-13 each 1e-4 s
    (intervals regular from the first) run to the end."""
    floor_at = 1e4
    model = hfdi.LinearSystem(mass=np.ones(3), stiffness=np.diag([0.0, 1.0, 0.0]),
                              load=lambda t: np.array([-G, 0.0, 0.0]),
                              initial_displacement=[floor_at + H0, 1.0, 0.0])

    def floor(t, u, v):
        return u[0] - floor_at
    floor.direction = -1

    def bounce(t, u, v, which):
        u, v = u.copy(), v.copy()
        u[0], v[0] = floor_at, -E * v[0]
        u[2] += 1.0
        return u, v
    t1 = math.sqrt(2 * H0 / G)
    t_zeno = t1 + 2 * E * (G * t1) / (G * (1 - E))
    r = hfdi.integrate(model, "hfdi", 2 * t_zeno, rtol=1e-8, events=floor, on_event=bounce,
                       max_steps=3000)
    assert r.status == hfdi.Status.MODEL_ERROR and "accumulate" in r.message, r.message
    assert t_zeno - 1e-4 < r.t[-1] <= t_zeno and r.t_events[0].size < 100

    gap, speed = 1e-9, 1e-6
    rattle = hfdi.LinearSystem(mass=[1.0, 1.0], stiffness=np.zeros((2, 2)),
                               load=lambda t: np.zeros(2), initial_displacement=[1e9, 0.0])

    def walls(t, u, v, which):
        v = v.copy()
        v[1] = speed if which == 2 else -v[1]
        return u, v
    r = hfdi.integrate(rattle, "hfdi", 10.2, rtol=1e-6, on_event=walls, events=[
        lambda t, u, v: u[1] - gap, lambda t, u, v: -gap - u[1], lambda t, u, v: t - 10.0])
    assert r.success and [len(times) for times in r.t_events] == [50, 50, 1], r.message

    tick = 1e-4
    rest = hfdi.LinearSystem(mass=[1.0], stiffness=[[0.0]], load=lambda t: np.zeros(1))

    def clock(t, u, v):
        return math.sin(math.pi * (t - 0.1) / tick) if t > 0.1 else t - 0.1
    r = hfdi.integrate(rest, "hfdi", 0.102, rtol=1e-6, events=clock, max_step=tick / 4,
                       on_event=lambda t, u, v, which: (u + 1e-3, 0.0 * v))
    assert r.success and r.t_events[0].size == 20, r.message
    assert r.u[-1, 0] == pytest.approx(0.02)
    held = hfdi.LinearSystem(mass=[1.0], stiffness=[[0.0]], load=lambda t: np.zeros(1),
                             initial_displacement=[1e4])

    def sampled(t, u, v, which):
        return u, np.array([-10.0 * (u[0] - 1e4) + 1e-9 * math.sin(t)])
    r = hfdi.integrate(held, "hfdi", 0.101, rtol=1e-6, max_step=tick / 4, on_event=sampled,
                       events=lambda t, u, v: (math.sin(math.pi * (t - 0.1) / tick)
                                               if t > 0.1 else t - 0.1))
    assert r.success and r.t_events[0].size == 11, r.message


MODES = [pytest.param(dict(rtol=1e-6), id="error"), pytest.param(dict(step=1e-2), id="fixed"),
         pytest.param(dict(target_iterations=3.0), id="iterations")]


@pytest.mark.parametrize("mode", MODES)
def test_a_rebound_shorter_than_the_first_look_is_seen(mode):
    """Sent up from the floor at 1e-6 m/s, the ball flies 2e-7 s, less than
    the first look after the zero (1e-6 of a step of a good part of a
    second): the landing was missed and the ball fell through the floor with
    SUCCESS in every mode. The second landing now ends the run where the
    closed form puts it."""
    floor = lambda t, u, v: u[0]        # noqa: E731
    floor.direction, floor.terminal = -1, 2
    r = hfdi.integrate(ball(), "hfdi", 3.0, events=floor,
                       on_event=lambda t, u, v, which: (u, np.array([1e-6])), **mode)
    t1 = math.sqrt(2 * H0 / G)
    assert r.status == hfdi.Status.TERMINATED, r.message
    np.testing.assert_allclose(r.t_events[0], [t1, t1 + 2e-6 / G], rtol=0, atol=5e-9)


def test_a_zero_passed_through_after_on_event_counts_once():
    """on_event answering without a reset: the step lands on the zero, a
    little off it (its own error), and g goes on through. The nearer looks
    took that offset for a flight: every zero counted twice."""
    duffing = hfdi.System([1.0], lambda u: u + 5 * u ** 3,
                          lambda u: np.array([[1 + 15 * u[0] ** 2]]),
                          lambda u, w: np.array([[30 * u[0] * w[0]]]),
                          initial_displacement=[1.0])
    floor = lambda t, u, v: u[0]        # noqa: E731
    floor.direction = -1
    answered = hfdi.integrate(duffing, "hfdi", 15.0, rtol=1e-4, events=floor,
                              on_event=lambda t, u, v, which: None)
    plain = hfdi.integrate(duffing, "hfdi", 15.0, rtol=1e-4, events=floor)
    assert answered.t_events[0].size == plain.t_events[0].size == 5
    np.testing.assert_allclose(answered.t_events[0], plain.t_events[0], rtol=0, atol=1e-6)


@pytest.mark.parametrize("scheme", schemes_quick("hfdi", "generalized_alpha"))
@pytest.mark.parametrize("mode", [pytest.param(dict(rtol=1e-3), id="error"),
                                  pytest.param(dict(step=0.05), id="fixed")])
@pytest.mark.parametrize("answer", [lambda t, u, v, which: None,
                                    lambda t, u, v, which: (u, v)], ids=["None", "same"])
def test_a_zero_the_landed_state_falls_short_of_counts_once(scheme, mode, answer):
    """u = cos 3t through u = 0.9 downwards: where on_event is asked the step
    lands on the zero, a little before it (its own error), and g goes on to
    it. That passing was counted as a new zero, 2e-8 to 2e-3 s later: 6
    zeros instead of 3, and terminal=3 stopped at the second."""
    oscillator = hfdi.LinearSystem([1.0], [9.0], initial_displacement=[1.0])
    level = lambda t, u, v: u[0] - 0.9        # noqa: E731
    level.direction = -1
    exact = (np.arccos(0.9) + 2 * np.pi * np.arange(3)) / 3
    plain = hfdi.integrate(oscillator, scheme, 5.0, events=level, **mode)
    answered = hfdi.integrate(oscillator, scheme, 5.0, events=level, on_event=answer, **mode)
    assert plain.t_events[0].size == answered.t_events[0].size == 3
    late = 5e-3 if "rtol" in mode else 2e-2      # the schemes' phase error at that step
    np.testing.assert_allclose(answered.t_events[0], exact, rtol=0, atol=late)
    level.terminal = 3
    stopped = hfdi.integrate(oscillator, scheme, 5.0, events=level, on_event=answer, **mode)
    assert stopped.status == hfdi.Status.TERMINATED
    np.testing.assert_allclose(stopped.t[-1], exact[2], rtol=0, atol=late)


@pytest.mark.parametrize("mode", MODES[1:])
def test_a_bouncing_ball_stops_at_its_zeno_point_in_every_mode(mode):
    """Restitution 0.5: error control stopped at the Zeno point; with a fixed
    step or the paper's rule the flights shrank below the first look and the
    ball fell through the floor (u = −65 at t = 5) with SUCCESS."""
    floor = lambda t, u, v: u[0]        # noqa: E731
    floor.direction = -1
    r = hfdi.integrate(ball(), "hfdi", 5.0, events=floor,
                       on_event=lambda t, u, v, which: (u, -0.5 * v), **mode)
    t_zeno = math.sqrt(2 * H0 / G) * (1 + 2 * 0.5 / (1 - 0.5))
    assert r.status == hfdi.Status.MODEL_ERROR and "accumulate" in r.message, r.message
    assert abs(r.t[-1] - t_zeno) < 1e-6 and abs(r.u[-1, 0]) < 1e-12


def test_a_zero_landed_on_late_in_time_counts_once():
    """At t0 = 1e5 the look just after a zero that on_event answered (a
    millionth of the next step) rounded to the zero's own time, where the
    landed state lies a rounding of t before the crossing: the zero was found
    again at the same time, ten times, and the run stopped as at a Zeno
    point. Every zero of u = cos(100 t) now counts once, where it is."""
    w = 100.0
    wave = hfdi.LinearSystem(mass=[1.0], stiffness=[[w * w]], initial_displacement=[1.0])
    r = hfdi.integrate(wave, "hfdi", 1e5 + 1.0, t0=1e5, rtol=1e-6, atol=1e-9,
                       events=lambda t, u, v: u[0], on_event=lambda t, u, v, which: None)
    assert r.success, r.message
    exact = 1e5 + (np.pi / 2 + np.pi * np.arange(32)) / w
    np.testing.assert_allclose(r.t_events[0], exact, rtol=0, atol=1e-6)


def test_regular_or_nearly_simultaneous_zeros_are_no_zeno_point():
    """Zeros that do not accumulate: a regular oscillation's every 0.079 s
    late in a run (t0 = 1e5; a threshold on the run's time scale took ten of
    them for a Zeno point), and twelve balls landing within 1e-9 s of each
    other, one function each (one count over all functions took them for
    one)."""
    w = 40.0
    wave = hfdi.LinearSystem(mass=[1.0], stiffness=[[w * w]], initial_displacement=[1.0])
    crossing = lambda t, u, v: u[0]
    r = hfdi.integrate(wave, "hfdi", 1e5 + 2.0, t0=1e5, rtol=1e-6, events=crossing,
                       on_event=lambda t, u, v, which: None)
    assert r.success and r.t_events[0].size >= 20, r.message
    heights = H0 + 1e-9 * np.arange(12)
    balls = hfdi.LinearSystem(mass=np.ones(12), stiffness=np.zeros((12, 12)),
                              load=lambda t: np.full(12, -G), initial_displacement=heights)
    floors = []
    for k in range(12):
        def floor(t, u, v, k=k):
            return u[k]
        floor.direction = -1
        floors.append(floor)

    def bounce_one(t, u, v, which):
        v = v.copy()
        v[which] = -E * v[which]
        return u, v
    r = hfdi.integrate(balls, "hfdi", 1.0, rtol=1e-6, events=floors, on_event=bounce_one)
    assert r.success, r.message
    assert all(times.size == 1 for times in r.t_events)


@pytest.mark.slow
def test_both_speeds_find_the_same_events():
    """The dumbbell compiled and on the Python path: the same steps and the
    same event times, bit for bit."""
    def g(t, u, v):
        return u[2] - u[0]
    runs = [hfdi.integrate(hfdi.models.get("dumbbell"), "hfdi", 0.35, rtol=1e-4, events=g,
                           compiled=compiled) for compiled in (False, True)]
    assert runs[1].stats.steps == runs[0].stats.steps
    assert runs[0].t_events[0].size >= 1
    assert np.array_equal(runs[0].t_events[0], runs[1].t_events[0])
    assert np.array_equal(runs[0].u_events[0], runs[1].u_events[0])


def test_events_do_not_change_the_steps():
    g = lambda t, u, v: u[0]         # noqa: E731
    a = hfdi.integrate(oscillator(), "hfdi", 2.0, rtol=1e-6, events=g)
    b = hfdi.integrate(oscillator(), "hfdi", 2.0, rtol=1e-6)
    assert np.array_equal(a.t, b.t) and np.array_equal(a.u, b.u)


def test_an_event_at_t0():
    """g(t0) = 0: counted at t0 when g leaves zero in its direction (as
    solve_ivp), not when it leaves the other way."""
    g = lambda t, u, v: v[0]         # noqa: E731
    g.direction = -1                 # v = −3 sin 3t leaves zero downwards
    r = hfdi.integrate(oscillator(), "hfdi", 0.5, rtol=1e-8, events=g)
    assert r.t_events[0].tolist() == [0.0]
    g.direction = 1
    r = hfdi.integrate(oscillator(), "hfdi", 0.5, rtol=1e-8, events=g)
    assert r.t_events[0].size == 0


def test_the_integrator_reports_events_as_it_steps():
    g = lambda t, u, v: u[0]         # noqa: E731
    itg = hfdi.Integrator(oscillator(), "hfdi", rtol=1e-8, t_bound=2.0, events=[g])
    assert itg.t_events[0].size == 0
    while itg.step():
        pass
    assert itg.status == hfdi.Status.SUCCESS
    np.testing.assert_allclose(itg.t_events[0], (np.arange(2) + 0.5) * math.pi / W,
                               rtol=1e-7)
    assert hfdi.Integrator(oscillator(), "hfdi", t_bound=1.0).t_events is None


def test_bad_events_are_refused_by_name():
    with pytest.raises(ValueError, match="events"):
        hfdi.integrate(oscillator(), "hfdi", 1.0, events=3)
    with pytest.raises(ValueError, match=r"events\[1\]"):
        hfdi.integrate(oscillator(), "hfdi", 1.0, events=[lambda t, u, v: 0.0, 5])
    g = lambda t, u, v: u[0]         # noqa: E731
    g.terminal = 0
    with pytest.raises(ValueError, match=r"events\[0\]\.terminal"):
        hfdi.integrate(oscillator(), "hfdi", 1.0, events=g)
    g = lambda t, u, v: u[0]         # noqa: E731
    g.direction = "up"
    with pytest.raises(ValueError, match=r"events\[0\]\.direction"):
        hfdi.integrate(oscillator(), "hfdi", 1.0, events=g)
    with pytest.raises(ValueError, match="on_event"):
        hfdi.integrate(oscillator(), "hfdi", 1.0, on_event=bounce)
    with pytest.raises(ValueError, match="on_event"):
        hfdi.integrate(oscillator(), "hfdi", 1.0, events=g, on_event=4)
    # at the initial state: refused before the run
    with pytest.raises(EventError, match=r"events\[0\] returned nan"):
        hfdi.integrate(oscillator(), "hfdi", 1.0, events=lambda t, u, v: math.nan)


def zero_of_u_failing_after(t_fail):
    """``g = u`` that raises RuntimeError("out of range") past ``t_fail``."""
    def g(t, u, v):
        if t > t_fail:
            raise RuntimeError("out of range")
        return u[0]
    return g


def test_an_event_function_that_fails_during_the_run_stops_it_with_a_message():
    r = hfdi.integrate(oscillator(), "hfdi", 1.0, rtol=1e-6, events=zero_of_u_failing_after(0.3))
    assert r.status == hfdi.Status.MODEL_ERROR and not r.success
    assert "events[0] raised RuntimeError: out of range" in r.message
    assert 0.2 < r.t[-1] <= 0.3          # the steps before the failing one are kept
    assert r.t_events[0].size == 0

    def nan_after(t, u, v):
        return math.nan if t > 0.3 else u[0]
    r = hfdi.integrate(oscillator(), "hfdi", 1.0, rtol=1e-6, events=nan_after)
    assert r.status == hfdi.Status.MODEL_ERROR and "returned nan" in r.message

    def bad_reset(t, u, v, which):
        return "no"
    r = hfdi.integrate(ball(), "hfdi", 1.0, rtol=1e-6, events=floor_event(),
                       on_event=bad_reset)
    assert r.status == hfdi.Status.MODEL_ERROR and "on_event must return" in r.message
    # asked at the zero, once landed there: stopped at it, the zero recorded
    assert r.t[-1] == pytest.approx(impact_times(1)[0], abs=1e-6)
    assert r.t_events[0].size == 1 and r.t_events[0][0] == r.t[-1]


@pytest.mark.slow
def test_a_compiled_event_function_finds_the_same_events():
    """An event function compiled with numba is evaluated over the rows in one
    compiled loop: the same zeros, bit for bit, as the same function in Python."""
    numba = pytest.importorskip("numba")

    def level(t, u, v):
        return u[0] - 0.25

    compiled_level = numba.njit(level)
    runs = [hfdi.integrate(oscillator(), "hfdi", 3.0, rtol=1e-8, events=g)
            for g in (level, compiled_level)]
    assert runs[0].t_events[0].size == 3
    assert np.array_equal(runs[0].t_events[0], runs[1].t_events[0])
    assert np.array_equal(runs[0].u_events[0], runs[1].u_events[0])

    @numba.njit
    def fails(t, u, v):
        return math.nan if t > 0.2 else u[0]
    r = hfdi.integrate(oscillator(), "hfdi", 1.0, rtol=1e-6, events=fails)
    assert r.status == hfdi.Status.MODEL_ERROR and "returned nan" in r.message


# -- the cases a review found wrong once ---------------------------------------------

@pytest.mark.parametrize("compiled", [False, None])
def test_a_zero_at_a_load_breakpoint_counts_once(compiled):
    """The load steps at tb (a restart row, the time twice): a zero exactly
    there is one event, on_event asked once, a terminal count of 2 not met."""
    tb = 0.5
    model = hfdi.LinearSystem(mass=[1.0], stiffness=[[W * W]],
                              load=lambda t: np.array([1.0 if t >= tb else 0.0]),
                              initial_displacement=[1.0], initial_velocity=[0.0])
    asked = []
    g = lambda t, u, v: t - tb       # noqa: E731
    r = hfdi.integrate(model, "hfdi", 1.0, rtol=1e-6, breakpoints=[tb], events=g,
                       on_event=lambda t, u, v, which: asked.append(t), compiled=compiled)
    assert r.t_events[0].tolist() == [tb] and asked == [tb]
    g.terminal = 2
    r = hfdi.integrate(model, "hfdi", 1.0, rtol=1e-6, breakpoints=[tb], events=g,
                       compiled=compiled)
    assert r.status == hfdi.Status.SUCCESS and r.t_events[0].tolist() == [tb]


def test_set_state_takes_the_event_values_of_the_restored_state():
    g = lambda t, u, v: u[0]         # noqa: E731
    itg = hfdi.Integrator(oscillator(), "hfdi", rtol=1e-8, t_bound=2.0, events=g)
    itg.advance(0.3)
    saved = itg.get_state()
    itg.advance(1.0)
    itg.set_state(saved)
    itg.advance(1.0)
    # the zero at π/6 found again after going back, none at the restored 0.3
    np.testing.assert_allclose(itg.t_events[0], [math.pi / 6] * 2, rtol=1e-7)


def test_events_with_a_custom_controller_are_refused():
    from hfdi.controller import Controller, Decision

    class Fixed(Controller):
        def init(self, trial, h0):
            return trial(0.01), Decision(True, 0.01)

        def adapt(self, attempt, rejections):
            return Decision(attempt.converged, 0.01)
    with pytest.raises(ValueError, match="events need one of the built-in controllers"):
        hfdi.Integrator(oscillator(), "hfdi", controller=Fixed(), t_bound=1.0,
                        events=lambda t, u, v: u[0])


def test_a_model_that_fails_at_the_reset_state_stops_the_run_there():
    def force(u):
        if u[0] > 2.0:
            raise ValueError("f undefined above 2")
        return np.zeros(1)
    model = hfdi.System([1.0], force, lambda u: np.zeros((1, 1)),
                        lambda u, w: np.zeros((1, 1)), load=lambda t: np.array([-G]),
                        potential_energy=lambda u: G * u[0], initial_displacement=[H0],
                        initial_velocity=[0.0])
    asked = []

    def away(t, u, v, which):
        asked.append(t)
        return u + 5.0, v
    r = hfdi.integrate(model, "hfdi", 1.0, rtol=1e-6, events=floor_event(), on_event=away)
    assert r.status == hfdi.Status.MODEL_ERROR and "after on_event's reset" in r.message
    assert len(asked) == 1 and r.t_events[0].size == 1
    assert r.t[-1] == r.t_events[0][0]


def test_a_terminal_event_with_a_reset_ends_at_its_count():
    g = floor_event()
    g.terminal = 2
    r = hfdi.integrate(ball(), "hfdi", 3.0, rtol=1e-6, events=g, on_event=bounce)
    assert r.status == hfdi.Status.TERMINATED
    np.testing.assert_allclose(r.t_events[0], impact_times(2), rtol=1e-12)
    assert r.t[-1] == r.t_events[0][-1] and r.v[-1, 0] > 0      # after the reset


def test_a_terminal_zero_at_t_end_and_the_global_mode_keep_terminated():
    g = lambda t, u, v: t - 1.0      # noqa: E731
    g.terminal = True
    r = hfdi.integrate(oscillator(), "hfdi", 1.0, rtol=1e-6, events=g)
    assert r.status == hfdi.Status.TERMINATED and r.t_events[0].tolist() == [1.0]
    h = lambda t, u, v: u[0]         # noqa: E731
    h.terminal = 3
    r = hfdi.integrate(oscillator(), "hfdi", 10.0, rtol=1e-9, events=h, error="global")
    assert r.status == hfdi.Status.TERMINATED, r.message
    assert "events[0] ended the run" in r.message and "global error" in r.message
    assert abs(r.t[-1] - 2.5 * math.pi / W) < 1e-8


def test_max_steps_holds_through_resets():
    for limit in (5, 8):
        r = hfdi.integrate(ball(), "hfdi", 3.0, rtol=1e-6, events=floor_event(),
                           on_event=bounce, max_steps=limit)
        assert r.stats.accepted <= limit


def test_a_ball_thrown_up_from_the_floor_is_not_an_event_at_t0():
    """u(0) = 0 leaving upwards: not a zero of the falling direction at t0;
    the landing at 2 v0 / G is, even within one long step."""
    model = hfdi.LinearSystem(mass=[1.0], stiffness=[[0.0]], load=lambda t: np.array([-G]),
                              initial_displacement=[0.0], initial_velocity=[3.0])
    r = hfdi.integrate(model, "newmark", 0.7, step=0.7, events=floor_event())
    np.testing.assert_allclose(r.t_events[0], [2 * 3.0 / G], rtol=1e-12)


def test_the_steps_before_a_terminal_zero_are_those_of_a_run_without_events():
    """The rewind takes the same steps again (compiled, the zero past the first
    call of 1,023 steps): the rows up to the zero's step are a run's
    without events, bit for bit."""
    def g(t, u, v):
        return u[2] - u[0]
    g.terminal = True
    model = hfdi.models.get("dumbbell")
    free = hfdi.integrate(model, "hfdi", 0.4, rtol=1e-6, compiled=True)
    stopped = hfdi.integrate(hfdi.models.get("dumbbell"), "hfdi", 0.4, rtol=1e-6, events=g,
                             compiled=True)
    assert stopped.status == hfdi.Status.TERMINATED
    k = stopped.t.size - 1                   # the last row is the landing at the zero
    assert k > 1023
    assert np.array_equal(stopped.t[:k], free.t[:k])
    assert np.array_equal(stopped.u[:k], free.u[:k])
    assert free.t[k - 1] < stopped.t[-1] <= free.t[k]


def test_a_failing_event_function_keeps_the_steps_before_its_failure():
    r = hfdi.integrate(oscillator(), "hfdi", 2.0, rtol=1e-6, events=zero_of_u_failing_after(1.0))
    assert r.status == hfdi.Status.MODEL_ERROR and "events[0] raised RuntimeError" in r.message
    assert 0.9 < r.t[-1] <= 1.0
    np.testing.assert_allclose(r.t_events[0], [math.pi / 6], rtol=1e-6)


# -- events a model declares ------------------------------------------------------------
@pytest.mark.parametrize("scheme", ["hfdi", pytest.param("bathe", marks=pytest.mark.slow)])
def test_the_impact_oscillator_declares_its_events_and_reset(scheme):
    """A model's ``events`` and ``on_event`` are used unless told otherwise: its
    impacts and highest points against the closed form of the piecewise
    harmonic motion (both depend on the integrated motion, so the bound is the
    run's accuracy)."""
    from hfdi.models.impact_oscillator import exact_events
    model = hfdi.models.impact_oscillator()
    impacts, tops = exact_events(model, 3.0)
    assert len(impacts) == 4 and len(tops) == 4
    rtol = 1e-9 if scheme == "hfdi" else 1e-8
    result = hfdi.integrate(model, scheme, 3.0, rtol=rtol)
    assert result.status == hfdi.Status.SUCCESS
    found_impacts, found_tops = result.t_events
    np.testing.assert_allclose(found_impacts, impacts, rtol=0, atol=2e-8)
    np.testing.assert_allclose(found_tops, tops, rtol=0, atol=2e-8)
    # at an impact the mass is on the stop; the rebound is in the next rows
    np.testing.assert_allclose(result.u_events[0][:, 0], -model.gap, atol=1e-12)
    # the energy lost at each impact is counted as work done, not numerical dissipation
    balance = result.total_energy[-1] - result.total_energy[0] - result.external_work[-1]
    assert abs(balance) < 1e-6 * result.total_energy[0]
    assert result.external_work[-1] < -0.5 * result.total_energy[0]


def test_events_none_takes_the_models_and_an_empty_list_none():
    model = hfdi.models.impact_oscillator()
    assert hfdi.integrate(model, "hfdi", 1.0, rtol=1e-6, events=()).t_events is None
    own = hfdi.integrate(model, "hfdi", 1.0, rtol=1e-6, events=[model.impact])
    # the model's reset is not taken for events of the caller's: the mass goes through
    assert len(own.t_events) == 1 and len(own.t_events[0]) == 1
    assert own.u[:, 0].min() < -1.5 * model.gap


@pytest.mark.parametrize("compiled", [pytest.param(False, marks=pytest.mark.slow), True])
def test_advance_until_event_stops_at_each_zero(compiled):
    """advance(until_event=True) returns at every zero, on its time, and the
    run goes on from there to the same events as without stopping."""
    model = hfdi.models.impact_oscillator()
    whole = hfdi.Integrator(model, "hfdi", rtol=1e-7, compiled=compiled)
    assert whole.advance(1.5)
    itg = hfdi.Integrator(model, "hfdi", rtol=1e-7, compiled=compiled)
    stops = []
    while itg.t < 1.5:
        assert itg.advance(1.5, until_event=True)
        stops.append(itg.t)
    expected = np.sort(np.concatenate(whole.t_events))
    assert len(stops) == len(expected) + 1 and stops[-1] == 1.5
    np.testing.assert_allclose(stops[:-1], expected, rtol=0, atol=1e-8)
    for mine, theirs in zip(itg.t_events, whole.t_events):
        np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-8)
    with pytest.raises(ValueError, match="until_event"):
        itg.advance(2.0, until_event=1)


@pytest.mark.parametrize("serialized", [pytest.param(False, marks=pytest.mark.slow), True])
def test_a_state_restored_at_a_zero_does_not_count_it_again(serialized):
    """get_state at each stop of advance(until_event=True) and set_state at once
    (bytes too): the zero stopped at is not found again, even where its g
    rounds to the side before it (a highest point's v = +4.6e-16), and the
    run meets the events a run without restores meets."""
    model = hfdi.models.impact_oscillator()
    plain = hfdi.Integrator(model, "hfdi", rtol=1e-9)
    assert plain.advance(3.0)
    itg = hfdi.Integrator(model, "hfdi", rtol=1e-9)
    calls = 0
    while itg.t < 3.0 and calls < 30:
        calls += 1
        t = itg.t
        assert itg.advance(3.0, until_event=True)
        assert itg.t > t
        saved = itg.get_state()
        if serialized:
            saved = hfdi.IntegratorState.from_bytes(saved.to_bytes())
        itg.set_state(saved)
    assert list(itg.event_count) == list(plain.event_count) == [4, 4]
    for mine, theirs in zip(itg.t_events, plain.t_events):
        np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-8)


def _second_zero_ends():
    """``u'' + u = 0`` from ``u = 1`` and ``u``'s zeros (π/2, 3π/2, ...), the
    second of which ends the run (``terminal = 2``)."""
    def zero(t, u, v):
        return u[0]
    zero.terminal = 2
    return hfdi.LinearSystem([1.0], [[1.0]], initial_displacement=[1.0]), zero


@pytest.mark.parametrize("serialized", [False, True])
def test_a_restored_state_ends_at_the_same_terminal_zero(serialized):
    """terminal=2 on the zeros of u (π/2, 3π/2, ...): a state saved after the
    first, restored into a new integrator (bytes too), ends at the second, as
    the run without a restore does. The count did not travel with the state:
    the restored run went on to the third (4.71 → 7.85)."""
    model, zero = _second_zero_ends()
    first = hfdi.Integrator(model, "hfdi", rtol=1e-8, events=zero)
    assert first.advance(2.0)
    saved = first.get_state()
    if serialized:
        saved = hfdi.IntegratorState.from_bytes(saved.to_bytes())
    restored = hfdi.Integrator(model, "hfdi", rtol=1e-8, events=zero)
    restored.set_state(saved)
    assert list(restored.event_count) == [1]
    restored.advance(10.0)
    first.advance(10.0)
    assert restored.terminated and first.terminated
    assert restored.t == pytest.approx(1.5 * np.pi, abs=1e-7) and restored.t == first.t


@pytest.mark.slow
def test_advance_until_event_counts_a_zero_at_its_start_and_goes_on():
    """A highest point at t0 (v0 = 0): counted by the first call, which goes
    on to the next zero instead of returning at t0 without moving."""
    model = hfdi.models.impact_oscillator(u0=0.05, v0=0.0)      # below the stop's reach
    itg = hfdi.Integrator(model, "hfdi", rtol=1e-8)
    assert itg.advance(2.5, until_event=True)
    assert list(itg.event_count) == [0, 2]
    assert itg.t_events[1][0] == 0.0 and itg.t == itg.t_events[1][1]
    assert itg.t == pytest.approx(1.0, abs=1e-7)                  # one period later


@pytest.mark.parametrize("scheme", schemes_quick("hfdi"))
@pytest.mark.parametrize("returns_state", [False, True])
def test_a_load_switched_by_on_event_acts_from_the_zero(scheme, returns_state):
    """``u'' + 9u = P H(t − π/6)``: on_event switches the load on at the first
    zero of ``u`` (returning None, or the state it was given). The steps taken
    past the zero with the old load were kept (None: 1.03 off, SUCCESS), or
    their replay no longer repeated them (a state: AssertionError). Exact:
    ``u = P/9 (1 − cos 3s) − sin 3s``, ``s = t − π/6``."""
    switched, P = [False], 5.0
    model = hfdi.LinearSystem([1.0], [[9.0]], initial_displacement=[1.0],
                              load=lambda t: np.array([P if switched[0] else 0.0]),
                              load_rate=lambda t: np.zeros(1))

    def on_event(t, u, v, which):
        switched[0] = True
        return (u, v) if returns_state else None

    def zero(t, u, v):
        return u[0]

    rtol = 1e-5
    result = hfdi.integrate(model, scheme, 1.5, rtol=rtol, events=zero, on_event=on_event)
    assert result.success, result.message
    ts = np.pi / 6
    s = result.t - ts
    exact = np.where(s < 0, np.cos(3 * result.t), P / 9 * (1 - np.cos(3 * s)) - np.sin(3 * s))
    assert np.abs(result.u[:, 0] - exact).max() < 50 * rtol
    assert result.t_events[0][0] == pytest.approx(ts, abs=10 * rtol)
    # the next zero is the switched motion's
    assert result.t_events[0][1] == pytest.approx(ts + 2 * math.atan(9 / P) / 3, abs=10 * rtol)


@pytest.mark.parametrize("scheme", schemes_quick("hfdi", "newmark"))
def test_on_event_answers_every_zero_at_a_time_and_none_changes_nothing(scheme):
    """Two functions with the same zeros: on_event answers both, in turn. An
    on_event that returns None and changes nothing leaves no second row at
    the zero (the run lands there: one step more a zero, within tolerance)."""
    model = hfdi.LinearSystem([1.0], [[9.0]], initial_displacement=[1.0])

    def zero(t, u, v):
        return u[0]

    asked = []
    result = hfdi.integrate(model, scheme, 2.0, rtol=1e-5, events=[zero, zero],
                            on_event=lambda t, u, v, which: asked.append(which))
    assert result.success and asked == [0, 1] * 2, asked       # π/6, π/2
    plain = hfdi.integrate(model, scheme, 2.0, rtol=1e-5, events=zero)
    idle = hfdi.integrate(model, scheme, 2.0, rtol=1e-5, events=zero,
                          on_event=lambda t, u, v, which: None)
    assert np.all(np.diff(idle.t) > 0)
    assert idle.stats.accepted <= plain.stats.accepted + 2
    np.testing.assert_allclose(idle.u[-1], plain.u[-1], atol=1e-6)


def test_a_saved_event_count_out_of_range_is_refused():
    """event_count is data: a count that is negative, not whole, beyond 2**53
    (it wrapped to a negative int64: the terminal event never fired) or of
    another length than the integrator's events is refused, in bytes and in
    a state given directly; an integrator without events ignores it."""
    model, zero = _second_zero_ends()
    itg = hfdi.Integrator(model, "hfdi", rtol=1e-6, events=zero)
    assert itg.advance(2.0)
    saved = itg.get_state()
    for bad in ([-3.0], [1.5], [np.nan], [2.0 ** 63], [1.0, 0.0]):
        wrong = saved.copy()
        wrong.event_count = np.array(bad)
        with pytest.raises(ValueError, match="event_count"):
            itg.set_state(wrong)
        if len(bad) == 1:
            with pytest.raises(ValueError, match="event_count"):
                hfdi.IntegratorState.from_bytes(wrong.to_bytes())
    plain = hfdi.Integrator(model, "hfdi", rtol=1e-6)
    plain.set_state(saved)
    assert plain.advance(3.0)


def test_on_event_changing_the_mass_stops_the_run_there():
    """The run reads M once: on_event changing it (alone: the event path only
    looked for changes of p, f and the parameter count) went on with the old
    mass, SUCCESS with the old mass's answer; with the load changed too,
    integrate raised and the steps were lost. Now a MODEL_ERROR at the zero,
    saying which matrix, with the steps up to it."""
    model = hfdi.LinearSystem([1.0], [[1.0]], initial_displacement=[1.0])

    def on_event(t, u, v, which):
        model.mass = np.array([4.0])

    result = hfdi.integrate(model, "hfdi", 5.0, rtol=1e-8, events=lambda t, u, v: u[0],
                            on_event=on_event)
    assert result.status == hfdi.Status.MODEL_ERROR
    assert "on_event changed the model's mass" in result.message
    assert result.t[-1] == pytest.approx(np.pi / 2, abs=1e-7)


@pytest.mark.parametrize("scheme", schemes_quick("hfdi"))
def test_a_zero_held_from_the_start_counts_where_g_leaves_it(scheme):
    """A function at zero over a while from the start, then leaving it (a
    clipped penetration depth): the zero counts where g leaves it. It was
    skipped whenever g was still zero at the probe just after a step's
    start, so the event was never found (a terminal one ran to t_end)."""
    def depth(t, u, v):                     # u = cos 3t falls below cos 0.2 at t = 0.2/3
        return max(math.cos(0.2) - u[0], 0.0)

    def clipped(t, u, v):
        return max(t - 2.345, 0.0)

    depth.direction, depth.terminal = 1, True
    rtol = 1e-8 if scheme == "hfdi" else 1e-6          # a second-order scheme's steps
    result = hfdi.integrate(oscillator(), scheme, 0.5, rtol=rtol, events=depth)
    assert result.status == hfdi.Status.TERMINATED
    assert result.t_events[0][0] == pytest.approx(0.2 / W, abs=100 * rtol)
    for direction in (1, 0):
        clipped.direction = direction
        found = hfdi.integrate(oscillator(), scheme, 3.0, rtol=1e-4, events=clipped).t_events
        assert len(found[0]) == 1 and found[0][0] == pytest.approx(2.345, abs=1e-12)
    clipped.direction = -1                  # leaving upwards is no falling zero
    assert len(hfdi.integrate(oscillator(), scheme, 3.0, rtol=1e-4,
                              events=clipped).t_events[0]) == 0
    itg = hfdi.Integrator(oscillator(), scheme, rtol=rtol, events=depth)
    itg.advance(0.5, until_event=True)
    assert itg.t == pytest.approx(0.2 / W, abs=100 * rtol)


def test_a_zero_reached_and_held_counts_once_where_it_is_reached():
    """g rises to zero at t = 3, stays there until 5, then goes on rising:
    one rising zero, at 3 (it was put at the end of the step that reached
    zero, and leaving it would have counted again)."""
    def ramp(t, u, v):
        return min(t - 3.0, 0.0) + max(t - 5.0, 0.0)

    for direction in (1, 0):
        ramp.direction = direction
        found = hfdi.integrate(oscillator(), "hfdi", 8.0, rtol=1e-6, events=ramp).t_events
        assert len(found[0]) == 1 and found[0][0] == pytest.approx(3.0, abs=1e-12)
    ramp.terminal = True
    result = hfdi.integrate(oscillator(), "hfdi", 8.0, rtol=1e-6, events=ramp)
    assert result.status == hfdi.Status.TERMINATED and result.t[-1] == pytest.approx(3.0)


@pytest.mark.parametrize("first_step", [None, 0.5, 1e-3])
def test_a_threshold_left_within_rounding_of_the_start_is_found(first_step):
    """g = u − 1 with u = 1 − t²/2: g stays exactly 0 for t below √(2ε),
    which the probe after the start fell in for a short first step: the
    zero was found or not depending on the step size. Found now, at t0 or
    where g first differs from zero."""
    model = hfdi.LinearSystem(mass=[1.0], stiffness=[[0.0]], load=lambda t: np.array([-1.0]),
                              initial_displacement=[1.0])

    def leave(t, u, v):
        return u[0] - 1.0

    leave.direction, leave.terminal = -1, True
    result = hfdi.integrate(model, "hfdi", 2.0, rtol=1e-6, first_step=first_step,
                            events=leave)
    assert result.status == hfdi.Status.TERMINATED
    assert len(result.t_events[0]) == 1 and result.t_events[0][0] <= 1e-7


def test_a_held_zero_left_again_after_a_reset_is_a_new_zero():
    """A clipped depth max(−u, 0) of a bouncing ball: zero through each
    flight, left at each impact. The zero counted where g left it (an
    impact), reset, and held through the flight was taken as one zero with
    the next impact, and the ball fell through the floor after the first."""
    def depth(t, u, v):
        return max(-u[0], 0.0)

    depth.direction = 1
    result = hfdi.integrate(ball(), "hfdi", 2.0, rtol=1e-8, events=depth,
                            on_event=lambda t, u, v, i: (u, -E * v))
    exact = impact_times(4)
    np.testing.assert_allclose(result.t_events[0], exact[exact < 2.0], atol=1e-7)
    assert result.u[:, 0].min() > -1e-6


def test_a_held_zero_inside_one_step_is_where_g_reaches_it():
    """g = min(t − 1.5, 0) + max(t − 3, 0) crosses inside one step: Brent's
    method stopped anywhere on the held zero (2.4 for 1.5); a dead zone of
    u = cos t (±0.02) met at 7.8586 for arccos 0.02 + 2π = 7.83398."""
    def ramp(t, u, v):
        return min(t - 1.5, 0.0) + max(t - 3.0, 0.0)

    found = hfdi.integrate(oscillator(), "hfdi", 4.0, step=4.0, events=ramp).t_events
    assert found[0] == pytest.approx([1.5], abs=1e-12)
    cosine = hfdi.LinearSystem(mass=[1.0], stiffness=[[1.0]], initial_displacement=[1.0])

    def dead_zone(t, u, v):
        return max(u[0] - 0.02, 0.0) + min(u[0] + 0.02, 0.0)

    dead_zone.direction = -1
    found = hfdi.integrate(cosine, "hfdi", 9.0, rtol=1e-4, events=dead_zone).t_events[0]
    exact = math.acos(0.02) + np.array([0.0, 2 * math.pi])
    np.testing.assert_allclose(found, exact, atol=1e-4)


@pytest.mark.parametrize("step", [2.5, 0.3])
def test_a_held_zero_left_against_the_direction_crosses_on_the_way_back(step):
    """g = 0 before t = 1, (t − 1)(t − 2) after, rising only: g leaves zero
    downwards at 1 and rises through it at 2. One step over both reported 1."""
    def late(t, u, v):
        return 0.0 if t < 1.0 else (t - 1.0) * (t - 2.0)

    late.direction = 1
    found = hfdi.integrate(oscillator(), "hfdi", 2.5, step=step, events=late).t_events
    assert found[0] == pytest.approx([2.0], abs=1e-12)


@pytest.mark.parametrize("stops", [False, True])
def test_zeros_ulps_apart_are_both_counted_when_the_first_stops_the_run(stops):
    """g = u and g = atan(5u) + u³ share their zeros, which the root finder
    puts ulps apart; with an on_event (even one that changes nothing) the
    run lands at the first and the landed state was already past the
    second: 9 and 10 zeros instead of 10 and 10. Held zeros alike:
    max(u, 0) leaves zero where min(u, 0) reaches it."""
    cosine = hfdi.LinearSystem(mass=[1.0], stiffness=[[1.0]], initial_displacement=[1.0])

    def plain(t, u, v):
        return u[0]

    def bent(t, u, v):
        return math.atan(5.0 * u[0]) + u[0] ** 3

    answer = (lambda t, u, v, i: None) if stops else None
    exact = np.pi / 2 + np.pi * np.arange(10)
    found = hfdi.integrate(cosine, "hfdi", 30.0, rtol=1e-7, events=[plain, bent],
                           on_event=answer).t_events
    for times in found:
        np.testing.assert_allclose(times, exact, atol=1e-6)

    def above(t, u, v):
        return max(u[0], 0.0)

    def below(t, u, v):
        return min(u[0], 0.0)

    above.direction = below.direction = 1
    found = hfdi.integrate(cosine, "hfdi", 12.0, rtol=1e-7, events=[above, below],
                           on_event=answer).t_events
    for times in found:
        np.testing.assert_allclose(times, [1.5 * np.pi, 3.5 * np.pi], atol=1e-6)
