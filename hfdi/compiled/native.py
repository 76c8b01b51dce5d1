"""``advance`` as a C function: the compiled driver for hosts that call it
without Python (an FMU's native layer, see docs/compiled.md).

:class:`NativeAdvance` puts one :class:`hfdi.Integrator`'s compiled driver
(:mod:`hfdi.compiled.driver`) behind a C function pointer,
``int64_t advance(int64_t *context, double t_stop)``, compiled once for all
models (a numba ``cfunc``, cached on disk). The context holds the addresses
of the arrays :func:`~hfdi.compiled.driver.drive` works on and of the
model's kernels; a call takes the ordinary steps to ``t_stop`` in those
arrays, without the interpreter and without the GIL.

A call either reaches ``t_stop`` (returns 1) or changes nothing (returns 0):
whenever the compiled driver would hand a step to the Python driver (a
breakpoint, a stop of the run, the step limit, the energy limit), the arrays
are put back as they were before the call, and the caller takes the step
with :meth:`hfdi.Integrator.advance` after :meth:`NativeAdvance.sync`, so
that statuses and messages keep their one source.

Protocol: :meth:`~NativeAdvance.arm` fills the arrays from the integrator's
state; then any number of calls; then :meth:`~NativeAdvance.sync` writes
the arrays back into the integrator before Python uses it again. While
armed, the integrator must not be stepped or changed from Python.
"""
from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import carray, cfunc, njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from .attempt import DAMPING_KIND as A_DAMPING_KIND
from .attempt import DENSE, DIAGONAL
from .attempt import MASS_KIND as A_MASS_KIND
from .attempt import NEWTON_CONSTANT as A_NEWTON_CONSTANT
from .attempt import NEWTON_GUARD as A_NEWTON_GUARD
from .driver import (ACCEPTED, C_NFEV, CALL_STEPS, CURRENT_HAS_F, FULL, MAX_STEPS, REACHED,
                     SAVE_ROWS, STEPS, STEPS_PER_CALL, T_CURRENT, T_STOP, A, F, P, U, V, drive)
from .lapack import all_finite
from .signatures import JIT_OPTIONS, KERNEL_SET

__all__ = ["NativeAdvance", "TAKEN", "NOT_TAKEN"]

#: What the native ``advance`` returns: ``t_stop`` reached, or nothing changed
#: (0, the value a failed call of compiled code gives, means "take it in Python").
TAKEN, NOT_TAKEN = 1, 0

# -- the context (int64): a header, then (address, shape...) of every array ------------
(KERNELS, STEP_LIMIT, STEPS_PER_CALL_LIMIT, CALLS) = range(4)
_HEADER = 8
_SLOT = 4                     # address and up to three extents per array
(PARAMS, LOAD_PARAMS, HELD, CONFIG, COEFFICIENTS, MD, MF, CD, CF, SETTINGS, SWITCHES, RTOL,
 ATOL, BREAKPOINTS, SCALARS, COUNTERS, CURRENT, PREVIOUS, ROW_SCALARS, ROW_STATES,
 BOUNDS, INPUTS) = range(22)
_ARRAYS = 22


@intrinsic
def _meminfo_address(typingctx, ref):
    """The address of a structref's meminfo (its one pointer)."""
    sig = types.int64(ref)

    def codegen(context, builder, signature, args):
        proxy = cgutils.create_struct_proxy(signature.args[0])(context, builder, value=args[0])
        return builder.ptrtoint(proxy.meminfo, ir.IntType(64))
    return sig, codegen


@intrinsic
def _kernel_set_at(typingctx, address):
    """The :data:`~hfdi.compiled.signatures.KERNEL_SET` whose meminfo is at
    ``address`` (a new reference: numba releases it when done)."""
    sig = KERNEL_SET(types.int64)

    def codegen(context, builder, signature, args):
        proxy = cgutils.create_struct_proxy(KERNEL_SET)(context, builder)
        proxy.meminfo = builder.inttoptr(args[0], proxy.meminfo.type)
        value = proxy._getvalue()
        context.nrt.incref(builder, KERNEL_SET, value)
        return value
    return sig, codegen


def _pointer_intrinsic(dtype):
    @intrinsic
    def pointer(typingctx, address):
        sig = types.CPointer(dtype)(types.int64)

        def codegen(context, builder, signature, args):
            return builder.inttoptr(args[0], context.get_value_type(signature.return_type))
        return sig, codegen
    return pointer


_float_pointer = _pointer_intrinsic(types.float64)
_int_pointer = _pointer_intrinsic(types.int64)


@njit(**JIT_OPTIONS)
def kernel_set_address(kernels):
    """The address :func:`native_advance` finds ``kernels`` at."""
    return _meminfo_address(kernels)


@njit(inline="always")
def _at(context, which):
    return _HEADER + _SLOT * which


@njit(inline="always")
def _vector(context, which):
    i = _at(context, which)
    return carray(_float_pointer(context[i]), (context[i + 1],))


@njit(inline="always")
def _index_vector(context, which):
    i = _at(context, which)
    return carray(_int_pointer(context[i]), (context[i + 1],))


@njit(inline="always")
def _matrix(context, which):
    i = _at(context, which)
    return carray(_float_pointer(context[i]), (context[i + 1], context[i + 2]))


@njit(inline="always")
def _block(context, which):
    i = _at(context, which)
    return carray(_float_pointer(context[i]), (context[i + 1], context[i + 2], context[i + 3]))


@njit(**JIT_OPTIONS)
def _apply_inputs(kernels, params, load_params, held, inputs, config, Md, Cd, scalars, counters,
                  current):
    """The held load becomes ``inputs`` at the current time, as
    :meth:`hfdi.Integrator.load_changed` makes it (``p_n`` and ``a_n`` anew,
    ``f_n`` evaluated when not kept), restated operation for operation
    (Evaluator.load, .force, .acceleration with a diagonal M). False where that
    is not done here (inputs not finite, a dense M or C, a load or force not
    finite): the caller then hands the step to Python, which reports it."""
    if not all_finite(inputs) or config[A_MASS_KIND] != DIAGONAL or \
            config[A_DAMPING_KIND] == DENSE:
        return False
    held[:] = inputs
    p = kernels.load(scalars[T_CURRENT], load_params)
    p = p + held
    if counters[CURRENT_HAS_F]:
        f = current[F].copy()
    else:
        f = kernels.force(np.ascontiguousarray(current[U]), params)
        counters[C_NFEV] += 1
    if not (all_finite(p) and all_finite(f)):
        return False
    b = p - f
    if config[A_DAMPING_KIND] == DIAGONAL:
        b = b - Cd * current[V]
    else:
        b = b - np.zeros_like(b)
    current[A] = b / Md
    current[P] = p
    current[F] = f
    counters[CURRENT_HAS_F] = 1
    return True


@cfunc(types.int64(types.CPointer(types.int64), types.float64), **JIT_OPTIONS)
def native_advance(context, t_stop):
    """:meth:`hfdi.Integrator.advance` to ``t_stop`` in the arrays of ``context``:
    :data:`TAKEN`, or :data:`NOT_TAKEN` with the arrays as before the call."""
    bounds = _vector(context, BOUNDS)
    scalars = _vector(context, SCALARS)
    if not (t_stop >= scalars[T_CURRENT] and t_stop <= bounds[0]):    # NaN included
        return NOT_TAKEN
    kernels = _kernel_set_at(context[KERNELS])
    params, load_params = _vector(context, PARAMS), _vector(context, LOAD_PARAMS)
    held, config = _vector(context, HELD), _index_vector(context, CONFIG)
    coefficients = _vector(context, COEFFICIENTS)
    Md, Mf = _vector(context, MD), _matrix(context, MF)
    Cd, Cf = _vector(context, CD), _matrix(context, CF)
    settings, switches = _vector(context, SETTINGS), _index_vector(context, SWITCHES)
    rtol, atol = _vector(context, RTOL), _vector(context, ATOL)
    breakpoints = _vector(context, BREAKPOINTS)
    counters = _index_vector(context, COUNTERS)
    current, previous = _matrix(context, CURRENT), _matrix(context, PREVIOUS)
    row_scalars, row_states = _matrix(context, ROW_SCALARS), _block(context, ROW_STATES)
    inputs = _vector(context, INPUTS)
    # all or nothing: what drive() writes, kept to be put back
    saved_scalars, saved_counters = scalars.copy(), counters.copy()
    saved_current, saved_previous = current.copy(), previous.copy()
    saved_held = held.copy()
    constant, guard = coefficients[A_NEWTON_CONSTANT], coefficients[A_NEWTON_GUARD]
    changed = False
    for i in range(inputs.shape[0]):
        changed = changed or inputs[i] != held[i]    # NaN counts as changed
    if changed and not _apply_inputs(kernels, params, load_params, held, inputs, config, Md,
                                     Cd, scalars, counters, current):
        held[:] = saved_held
        counters[:] = saved_counters
        current[:, :] = saved_current
        return NOT_TAKEN
    settings[T_STOP] = t_stop
    switches[SAVE_ROWS] = 0
    switches[CALL_STEPS] = STEPS_PER_CALL
    switches[MAX_STEPS] = min(context[STEP_LIMIT],
                              counters[STEPS] + context[STEPS_PER_CALL_LIMIT])
    reason = FULL
    while reason == FULL:
        reason, taken = drive(kernels, params, load_params, held, config, coefficients, Md, Mf,
                              Cd, Cf, settings, switches, rtol, atol, breakpoints, scalars,
                              counters, current, previous, row_scalars, row_states)
    if reason == REACHED:
        context[CALLS] += 1
        return TAKEN
    scalars[:] = saved_scalars
    counters[:] = saved_counters
    current[:, :] = saved_current
    previous[:, :] = saved_previous
    held[:] = saved_held
    coefficients[A_NEWTON_CONSTANT], coefficients[A_NEWTON_GUARD] = constant, guard
    return NOT_TAKEN


class NativeAdvance:
    """The compiled driver of one :class:`hfdi.Integrator` behind a C function
    (see the module's docstring for the protocol).

    Parameters
    ----------
    integrator : Integrator
        One whose ``advance`` runs in the compiled driver
        (:attr:`hfdi.Integrator.driven`).

    Attributes
    ----------
    function_address : int
        ``int64_t (*)(int64_t *context, double t_stop)``: 1 (:data:`TAKEN`) when
        ``t_stop`` was reached, 0 (:data:`NOT_TAKEN`) when nothing changed.
    context_address : int
        The ``context`` to pass; valid as long as this object lives.
    time_address : int
        A ``double``: the time of the armed state (the current time while armed).
    state_address : int
        ``double[5][N]``, C order: ``u``, ``v``, ``a``, ``f``, ``p`` of the
        armed state (``f`` zero for the schemes that keep none).
    n : int
        ``N``, the number of DOFs.

    Raises
    ------
    ValueError
        When ``integrator`` does not run in the compiled driver.
    """

    function_address = native_advance.address

    def __init__(self, integrator):
        driver = integrator._driver
        if driver is None:
            raise ValueError("integrator must run in the compiled driver "
                             "(Integrator.driven), it does not")
        self._integrator = integrator
        self._driver = driver
        self.n = driver.n
        self._scalars = np.zeros(11)
        self._counters = np.zeros(17, np.int64)
        self._held = np.zeros(0)
        self._bounds = np.array([math.inf])
        self._context = np.zeros(_HEADER + _SLOT * _ARRAYS, np.int64)
        self._keep = None           # the kernel set the context points into
        # the arrays whose addresses and shapes the context holds, kept alive
        # here: an array already there is not written again (ndarray.ctypes
        # costs 1.5 µs and makes garbage; arm() cost 75 µs with 22 of them)
        self._in_context = [None] * _ARRAYS
        self._accepted_at_arm = 0
        self._armed = False
        self.context_address = int(self._context.ctypes.data)
        self.time_address = int(self._scalars.ctypes.data) + 8 * T_CURRENT
        self.state_address = int(driver._current.ctypes.data)

    @property
    def integrator(self):
        """The :class:`hfdi.Integrator` this object advances."""
        return self._integrator

    @property
    def armed(self) -> bool:
        """Whether the arrays stand for the integrator's state (since :meth:`arm`)."""
        return self._armed

    def arm(self, max_steps_per_call: int | None = None, inputs=None) -> str:
        """Fill the arrays from the integrator's state, so that the native
        ``advance`` continues from it; ``""`` when armed, else why not (the
        first step is pending, the run failed, the model changed, the held
        load is not a finite (N,) vector), and the native ``advance`` must not
        be called.

        ``max_steps_per_call``: the steps one call may take at most (attempts
        counted as :attr:`hfdi.Statistics.steps` counts them); a call that
        would need more changes nothing. Also bounded by ``max_steps``.

        ``inputs``: an (N,) float64 C-contiguous array that the host may write
        between calls, for an integrator with a :class:`~hfdi.HeldLoad`: when it
        differs from the held value (:attr:`held`), the next call holds it from
        its start, as ``load_changed()`` after a change of the held load would
        (with a diagonal M and C; otherwise, or when not finite, the call
        changes nothing). After :meth:`sync` the host must have the held
        load's source return :attr:`held`. The array must outlive the armed
        state; at :meth:`arm` it must equal the held value.
        """
        self.sync()
        self._armed = False
        itg, driver = self._integrator, self._driver
        if itg.failed:
            return "the run has failed"
        if itg._s.first_step_pending:
            return "the first step is pending"
        if itg._model_version is not None and \
                itg.system.parameter_version != itg._model_version:
            return "the model changed since the last step"
        held = driver.held_load(itg)
        if held is None or (held.shape[0] and not np.all(np.isfinite(held))):
            return "the held load is not a finite vector of N values"
        if max_steps_per_call is not None and int(max_steps_per_call) < 1:
            raise ValueError(f"max_steps_per_call must be >= 1, got {max_steps_per_call!r}")
        if inputs is None:
            inputs = np.zeros(0)
        elif not (isinstance(inputs, np.ndarray) and inputs.dtype == np.float64
                  and inputs.flags.c_contiguous and inputs.shape == (self.n,)):
            raise ValueError(f"inputs must be a C-contiguous float64 array of shape "
                             f"({self.n},), got {inputs!r}")
        elif held.shape[0] == 0:
            raise ValueError("inputs need an integrator with a hfdi.HeldLoad, it has none")
        elif inputs.tolist() != held.tolist():
            raise ValueError("inputs must equal the held load's value when armed")
        scalars, counters = driver.load(itg)
        self._scalars[:] = scalars
        self._counters[:] = counters
        if self._held.shape == held.shape:
            self._held[:] = held                          # its own: calls write into it
        else:
            self._held = np.array(held, dtype=np.float64)
        self._bounds[0] = math.inf if itg.t_bound is None else float(itg.t_bound)
        step = driver.step
        params = np.ascontiguousarray(step.params(), dtype=np.float64)
        load_params = params if driver._load_reads_params else driver.load_params
        arrays = [params, load_params, self._held, driver.config, driver.coefficients,
                  step.Md, step.Mf, step.Cd, step.Cf, driver.settings, driver.switches,
                  driver.rtol, driver.atol, driver.breakpoints, self._scalars, self._counters,
                  driver._current, driver._previous, driver._no_rows[0], driver._no_rows[1],
                  self._bounds, inputs]
        context = self._context
        context[KERNELS] = kernel_set_address(step.kernel_set)
        context[STEP_LIMIT] = itg.max_steps
        context[STEPS_PER_CALL_LIMIT] = itg.max_steps if max_steps_per_call is None \
            else int(max_steps_per_call)
        context[CALLS] = 0
        in_context = self._in_context
        for which, array in enumerate(arrays):
            if array is in_context[which]:
                continue        # the same object: same address and shape
            if not (array.flags.c_contiguous and array.dtype in (np.float64, np.int64)):
                raise AssertionError(f"array {which} of the native context is not a "
                                     "C-contiguous float64 or int64 array")
            at = _HEADER + _SLOT * which
            context[at:at + _SLOT] = 0
            context[at] = array.ctypes.data
            context[at + 1:at + 1 + array.ndim] = array.shape
            in_context[which] = array
        # the kernel set stays alive with this object (the arrays in _in_context)
        self._keep = step.kernel_set
        self._accepted_at_arm = int(counters[ACCEPTED])
        self._armed = True
        return ""

    @property
    def held(self) -> np.ndarray:
        """The held load's value the armed state was computed with (a copy;
        empty without a :class:`~hfdi.HeldLoad`)."""
        return self._held.copy()

    @property
    def calls(self) -> int:
        """Successful native calls since the last :meth:`arm` or :meth:`sync`."""
        return int(self._context[CALLS])

    def sync(self, cpu_time: float = 0.0) -> int:
        """Write the arrays back into the integrator after native calls (its
        state, statistics and status as :meth:`hfdi.Integrator.advance` leaves
        them); ``cpu_time``, the seconds the caller measured for the calls, is
        added to :attr:`hfdi.Statistics.cpu_time`. Returns the calls synced
        (0: nothing to do). The arrays stay armed."""
        calls = int(self._context[CALLS])
        if calls == 0 or not self._armed:
            return 0
        self._context[CALLS] = 0
        itg = self._integrator
        taken = int(self._counters[ACCEPTED]) - self._accepted_at_arm
        self._driver.store(itg, self._scalars, self._counters, taken)
        self._accepted_at_arm = int(self._counters[ACCEPTED])
        itg._native_synced(taken, cpu_time)
        return calls
