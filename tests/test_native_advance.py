"""advance as a C function (Integrator.native_advance(), hfdi.compiled.NativeAdvance) against advance itself.

A host calls the function through its address, as the FMU's native layer
does (here through ctypes): every call that takes its step must leave, after
sync(), the state, statistics and status advance() leaves, bit for bit; a
call that does not take it must change nothing, so that advance() then takes
the step and says why as always.
"""
import ctypes
import math

import numpy as np
import pytest

import hfdi
from hfdi.controller import ErrorControl
from hfdi.models import articulated, dumbbell, tetrahedra, toss_rule
from test_compiled_path import _assert_same_state

numba = pytest.importorskip("numba")
from hfdi.compiled.native import NOT_TAKEN, TAKEN  # noqa: E402

PROBLEMS = {"dumbbell": (dumbbell, 0.01, 0.2), "tetrahedra": (tetrahedra, 2.5, 5.0),
            "articulated": (articulated, 0.06, 0.2), "toss_rule": (toss_rule, 0.003, 0.012)}
MODES = {"fixed": dict(step=1 / 40), "iterations": dict(target_iterations=3),
         "error": dict(rtol=1e-6), "combined": dict(target_iterations=3, rtol=1e-5)}


def case(problem, mode):
    """``(make, t_end, options)`` of a run of ``problem`` in ``mode``: the long
    horizon for the iteration-count mode, else the short one; a fixed step is
    given as a fraction of the horizon."""
    make, short, long = PROBLEMS[problem]
    t_end = long if mode == "iterations" else short
    options = dict(MODES[mode])
    if mode == "fixed":
        options["step"] *= t_end
    return make, t_end, options


_FUNCTION = ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_void_p, ctypes.c_double)


class Host:
    """A host of the native function: it calls it for every communication point
    and hands the point to ``advance`` (after ``sync``) when the call does not
    take it, as the FMU's native layer does. With ``applied`` (the array its
    integrator's HeldLoad returns) it writes inputs into ``inputs`` between
    calls; where it takes a point itself it applies them as the FMU's slave
    does (``load_changed``)."""

    def __init__(self, itg, max_steps_per_call=None, applied=None):
        self.itg = itg
        self.native = itg.native_advance()
        self.function = _FUNCTION(self.native.function_address)
        self.max_steps_per_call = max_steps_per_call
        self.applied = applied
        self.inputs = None if applied is None else applied.copy()
        self.taken = self.handed = 0

    def call(self, t_stop):
        return self.function(self.native.context_address, t_stop)

    def sync(self):
        if self.native.sync() and self.applied is not None:
            self.applied[:] = self.native.held

    def advance(self, t_stop) -> bool:
        if self.native.armed and self.call(t_stop) == TAKEN:
            self.taken += 1
            return True
        self.sync()
        self.handed += 1
        if self.applied is not None and self.inputs.tolist() != self.applied.tolist():
            self.applied[:] = self.inputs
            self.itg.load_changed()
        ok = self.itg.advance(t_stop)
        self.native.arm(self.max_steps_per_call, inputs=self.inputs)
        return ok


def _cases():
    """Every model x scheme x mode; the quick tier on the two smallest models."""
    for problem in PROBLEMS:
        for scheme in hfdi.SCHEMES:
            for mode in MODES:
                slow = problem in ("tetrahedra", "toss_rule")
                yield pytest.param(problem, scheme, mode, id=f"{problem}-{scheme}-{mode}",
                                   marks=[pytest.mark.slow] if slow else [])


@pytest.mark.parametrize("problem, scheme, mode", list(_cases()))
def test_native_calls_leave_what_advance_leaves_bit_for_bit(problem, scheme, mode):
    make, t_end, options = case(problem, mode)
    host = Host(hfdi.Integrator(make(), scheme, compiled=True, t_bound=t_end, **options))
    plain = hfdi.Integrator(make(), scheme, compiled=True, t_bound=t_end, **options)
    assert host.itg.compiled
    # communication points between and across internal steps, the last t_bound
    for t_stop in np.linspace(0.0, t_end, 41)[1:]:
        assert host.advance(t_stop) == plain.advance(t_stop)
    host.native.sync()
    _assert_same_state(host.itg, plain)
    assert host.itg.status == plain.status == hfdi.Status.SUCCESS
    assert host.taken >= 30, (host.taken, host.handed)


def test_a_call_not_taken_changes_nothing():
    """Past t_bound, NaN, before t, beyond the steps a call may take, and at a
    load breakpoint (handed to Python by the driver): the state stays, and
    advance() then takes the step as a plain run does."""
    options = dict(rtol=1e-6, t_bound=0.2)
    itg = hfdi.Integrator(articulated(), "hfdi", compiled=True, **options)
    plain = hfdi.Integrator(articulated(), "hfdi", compiled=True, **options)
    for i in (itg, plain):
        assert i.advance(0.01)
    host = Host(itg, max_steps_per_call=5)
    assert host.native.arm(5) == ""
    before = itg.get_state().to_bytes()
    t = itg.t
    breakpoint = float(next(b for b in itg.breakpoints if b > t))
    for t_stop in (0.3, math.nan, math.inf, t - 1e-3, t + 0.05, breakpoint + 1e-4):
        assert host.call(t_stop) == NOT_TAKEN, t_stop
        assert host.native.calls == 0
    assert host.native.sync() == 0
    assert itg.get_state().to_bytes() == before
    assert host.call(t) == TAKEN                 # t itself: nothing to do
    for t_stop in sorted((t + 0.05, breakpoint + 1e-4, 0.2)):
        assert host.advance(t_stop) and plain.advance(t_stop)
    host.native.sync()
    _assert_same_state(itg, plain)
    assert host.handed >= 2


def test_a_stop_is_advances_own_after_native_calls():
    options = dict(rtol=1e-6, max_steps=300, t_bound=0.2)
    host = Host(hfdi.Integrator(articulated(), "hfdi", compiled=True, **options))
    plain = hfdi.Integrator(articulated(), "hfdi", compiled=True, **options)
    results = []
    for t_stop in np.linspace(0.0, 0.2, 81)[1:]:
        results.append((host.advance(t_stop), plain.advance(t_stop)))
        if not results[-1][1]:
            break
    assert results[-1] == (False, False)
    assert host.itg.status == hfdi.Status.MAX_STEPS
    assert host.itg.message == plain.message
    _assert_same_state(host.itg, plain)
    assert host.taken >= 2


@pytest.mark.slow
def test_held_load_changed_between_arms():
    """A held load (a co-simulation input) changed between communication points:
    advance after load_changed, armed again, then native calls."""
    value = np.zeros(6)
    runs = []
    for native in (True, False):
        itg = hfdi.Integrator(articulated(), "bathe", rtol=1e-6, compiled=True,
                              extra_load=hfdi.HeldLoad(lambda: value))
        host = Host(itg) if native else None
        value[:] = 0.0
        for k, t in enumerate(np.linspace(0.005, 0.08, 32)):
            if k % 4 == 0:
                if host is not None:
                    host.native.sync()
                value[:] = 50.0 * np.sin(k + np.arange(6))
                itg.load_changed()
                if host is not None:
                    assert host.native.arm() == ""
            assert (host.advance(t) if host is not None else itg.advance(t))
        if host is not None:
            host.native.sync()
            assert host.taken >= 20
        runs.append(itg)
    _assert_same_state(*runs)


def test_sync_counts_what_the_calls_did():
    itg = hfdi.Integrator(dumbbell(), "hfdi", target_iterations=3, compiled=True)
    host = Host(itg)
    assert host.advance(0.01)
    steps, cpu = itg.statistics.steps, itg.statistics.cpu_time
    for k in range(1, 6):
        assert host.call(0.01 + 0.02 * k) == TAKEN
    assert itg.statistics.steps == steps         # not yet taken over
    assert host.native.sync(cpu_time=0.25) == 5
    assert itg.statistics.steps > steps and itg.t == 0.11
    assert itg.statistics.cpu_time == pytest.approx(cpu + 0.25)
    assert host.native.sync() == 0 and host.native.armed


def test_arm_says_why_not_and_bad_input_is_refused():
    itg = hfdi.Integrator(dumbbell(), "hfdi", target_iterations=3, compiled=True)
    native = itg.native_advance()
    assert native.arm() == "" and native.armed      # the first step too runs natively
    assert itg.advance(0.01)
    with pytest.raises(ValueError, match="max_steps_per_call must be >= 1"):
        native.arm(0)
    assert native.arm() == "" and native.armed
    failed = hfdi.Integrator(articulated(), "hfdi", compiled=True, step=0.004, max_iterations=2)
    assert not failed.advance(0.2)
    assert failed.native_advance().arm() == "the run has failed"
    python = hfdi.Integrator(dumbbell(), "hfdi", target_iterations=3, compiled=False)
    with pytest.raises(ValueError, match="must run compiled"):
        python.native_advance()


@pytest.mark.parametrize("scheme", list(hfdi.SCHEMES))
@pytest.mark.parametrize("make", [dumbbell, articulated], ids=["dumbbell", "articulated"])
def test_inputs_written_between_calls_are_held_as_load_changed_holds_them(make, scheme):
    """A host writes the held load's new value between calls (an FMU's
    fmi2SetReal of inputs): the call holds it from its start as
    load_changed() does, bit for bit, also where a point goes to Python."""
    n = make().n_dof
    applied, reference = np.zeros(n), np.zeros(n)
    # per step: Newmark keeps the stiff modes each input jump excites, and
    # at a share of the tolerance it resolves them (many steps per communication step)
    options = dict(controller=ErrorControl(1e-6, per_step=True), compiled=True, t_bound=0.1)
    itg = hfdi.Integrator(make(), scheme, extra_load=hfdi.HeldLoad(lambda: applied), **options)
    plain = hfdi.Integrator(make(), scheme, extra_load=hfdi.HeldLoad(lambda: reference),
                            **options)
    host = Host(itg, applied=applied)
    for k, t in enumerate(np.linspace(0.0, 0.1, 61)[1:]):
        if k % 3:
            value = 40.0 * np.sin(k + np.arange(n))
            host.inputs[:] = value
            if value.tolist() != reference.tolist():
                reference[:] = value
                plain.load_changed()
        assert host.advance(t) and plain.advance(t)
    host.sync()
    _assert_same_state(itg, plain)
    assert host.taken >= 40 and itg.statistics.accepted > 60


def test_inputs_not_applied_natively_are_handed_to_python():
    """Inputs that are not finite: the call changes nothing (Python then
    reports them); bad arrays are refused at arm()."""
    applied = np.zeros(4)
    itg = hfdi.Integrator(dumbbell(), "hfdi", target_iterations=3, compiled=True,
                          extra_load=hfdi.HeldLoad(lambda: applied))
    host = Host(itg, applied=applied)
    assert host.advance(0.01) and host.advance(0.02)
    host.inputs[1] = math.nan
    host.sync()
    before = itg.get_state().to_bytes()
    assert host.call(0.03) == NOT_TAKEN
    host.sync()
    assert itg.get_state().to_bytes() == before
    host.inputs[1] = 5.0
    assert host.call(0.03) == TAKEN
    host.sync()
    assert applied[1] == 5.0
    with pytest.raises(ValueError, match="inputs must be a C-contiguous float64 array"):
        host.native.arm(inputs=np.zeros(3))
    host.inputs[1] = 6.0
    with pytest.raises(ValueError, match="inputs must equal the held load"):
        host.native.arm(inputs=host.inputs)
    bare = hfdi.Integrator(dumbbell(), "hfdi", target_iterations=3, compiled=True)
    assert bare.advance(0.01)
    with pytest.raises(ValueError, match="HeldLoad"):
        bare.native_advance().arm(inputs=np.zeros(4))


def test_arm_points_the_context_at_the_arrays_of_this_arm():
    """arm() writes an array's address only when it is another object than at
    the last arm: a new ``inputs`` array is the one the calls read, the old one
    is not, and a held load changed between arms is the one held."""
    applied = np.zeros(4)
    itg = hfdi.Integrator(dumbbell(), "hfdi", target_iterations=3, compiled=True,
                          extra_load=hfdi.HeldLoad(lambda: applied))
    assert itg.advance(0.01)
    native = itg.native_advance()
    function = _FUNCTION(native.function_address)
    first, second = np.zeros(4), np.zeros(4)
    assert native.arm(inputs=first) == "" and native.arm(inputs=second) == ""
    first[1] = 5.0                                  # no longer the context's
    assert function(native.context_address, 0.011) == TAKEN
    native.sync()
    assert native.held.tolist() == [0.0] * 4
    second[1] = 5.0
    assert function(native.context_address, 0.012) == TAKEN
    native.sync()
    assert native.held.tolist() == [0.0, 5.0, 0.0, 0.0]
    # the host applies what the calls held, changes it from Python, and arms again
    applied[:] = [0.0, 5.0, 0.0, 0.0]
    applied[2] = -3.0
    itg.load_changed()
    assert itg.advance(0.013)
    inputs = applied.copy()
    assert native.arm(inputs=inputs) == ""
    assert native.held.tolist() == [0.0, 5.0, -3.0, 0.0]
    assert function(native.context_address, 0.014) == TAKEN
    native.sync()
    reference_load = np.zeros(4)
    reference = hfdi.Integrator(dumbbell(), "hfdi", target_iterations=3, compiled=True,
                                extra_load=hfdi.HeldLoad(lambda: reference_load))
    for t, load in ((0.01, None), (0.011, None), (0.012, [0.0, 5.0, 0.0, 0.0]),
                    (0.013, [0.0, 5.0, -3.0, 0.0]), (0.014, None)):
        if load is not None:
            reference_load[:] = load
            reference.load_changed()
        assert reference.advance(t)
    assert np.array_equal(itg.state.u, reference.state.u)
    assert np.array_equal(itg.state.v, reference.state.v)
