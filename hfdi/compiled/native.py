"""``advance`` as a C function, for hosts that call it without Python (an FMU's
native layer; docs/compiled.md, "The native path").

:class:`NativeAdvance` puts one compiled :class:`hfdi.Integrator` behind
``int64_t advance(int64_t *context, double t_stop)``, a numba ``cfunc`` that
runs the integrator's compiled loop in its own arrays without the GIL. A call
reaches ``t_stop`` (1) or changes nothing (0); the caller then takes that step
with :meth:`hfdi.Integrator.advance` after :meth:`NativeAdvance.sync`.
Protocol: :meth:`~NativeAdvance.arm`, any number of calls, then
:meth:`~NativeAdvance.sync` before Python uses the integrator again.
"""
from __future__ import annotations

import functools

import numpy as np
from llvmlite import ir
from numba import from_dtype, njit, types
from numba.core import cgutils
from numba.experimental import structref
from numba.extending import intrinsic

from ..core.arrays import copy
from ..core.codes import REACHED
from ..core.jit import JIT_OPTIONS, jitable, native
from ..core.numba_types import INT64_VECTOR, MATRIX, VECTOR, Struct, register
from ..core.records import Arrays
from ..core.state import CONFIG, DATA, FUNCTIONS, RUN, VECTORS
from ..stepping.attempt import refresh
from ..stepping.loop import advance_affine, advance_hfdi

__all__ = ["NativeAdvance", "TAKEN", "NOT_TAKEN"]

#: What the native ``advance`` returns: ``t_stop`` reached, or nothing changed
#: (0, the value a failed call of compiled code gives, means "take it in Python").
TAKEN, NOT_TAKEN = 1, 0

_BYTES = types.uint8[::1]
_EVERY = 2**63 - 1
#: The vectors a call may change, put back when it gives up (:func:`_state`, and
#: the global error estimate); as ``hfdi.compiled_steps._SNAPSHOT``, not
#: imported: this module's compiled code would be compiled again at every
#: change of that module.
_STATE = ("u", "v", "a", "f", "p", "u_previous", "v_previous", "a_previous", "f_previous",
          "p_previous")
# entries of ``limits``: the run's max_steps, the steps one call may take, the calls made
STEP_LIMIT, PER_CALL, CALLS = range(3)


#: The compiled loop's signature (:func:`hfdi.stepping.loop.advance_hfdi`).
ADVANCE = types.int64(FUNCTIONS.type, types.Array(from_dtype(CONFIG.dtype), 1, "C"), DATA.type,
                      types.Array(from_dtype(RUN.dtype), 1, "C"), VECTORS.type, types.float64,
                      types.int64)


@structref.register
class LoopType(Struct):
    pass


class CompiledLoop(structref.StructRefProxy):
    __slots__ = ()


#: The integrator's compiled loop as a first-class function: the C function
#: calls it through its address, so that its code (compiled and cached once)
#: is not compiled into the C function again.
LOOP = Arrays("Loop", [("advance", types.FunctionType(ADVANCE))])
register(LOOP, LoopType, CompiledLoop)
_LOOP_TYPE = LOOP.type


def _new_loop(advance):
    loop = structref.new(_LOOP_TYPE)
    loop.advance = advance
    return loop


# not cached on disk, for the reason of hfdi.core.numba_types.function_struct_of
_new_loop_compiled = njit(**JIT_OPTIONS)(_new_loop)
_NEW_LOOP = LOOP.type(types.FunctionType(ADVANCE))


def loop_struct(advance):
    """:data:`LOOP` of the compiled loop ``advance`` (a dispatcher)."""
    advance = getattr(advance, "dispatcher", advance)
    if ADVANCE.args not in advance.overloads:
        advance.compile(ADVANCE.args)
    if _NEW_LOOP.args not in _new_loop_compiled.overloads:
        _new_loop_compiled.compile(_NEW_LOOP)
    return _new_loop_compiled.overloads[_NEW_LOOP.args].entry_point(advance)


@structref.register
class NativeType(Struct):
    pass


class CompiledNative(structref.StructRefProxy):
    __slots__ = ()


NATIVE = Arrays("Native", [
    ("loop", LOOP.type),
    ("fn", FUNCTIONS.type), ("data", DATA.type), ("vec", VECTORS.type),
    ("cfg", types.Array(from_dtype(CONFIG.dtype), 1, "C")),     # the run's, max_steps per call
    ("run", types.Array(from_dtype(RUN.dtype), 1, "C")),
    ("run_bytes", _BYTES), ("saved_run", _BYTES),              # the run record as bytes
    ("saved", MATRIX),                                         # _STATE, then the held load
    ("saved_global", VECTOR),                                  # the global error estimate
    ("inputs", VECTOR),                                        # the host's held-load inputs
    ("limits", INT64_VECTOR),
])
register(NATIVE, NativeType, CompiledNative)


@intrinsic
def _address_of(typingctx, instance):
    """The address of a struct's meminfo (its one pointer)."""
    def codegen(context, builder, signature, args):
        proxy = cgutils.create_struct_proxy(signature.args[0])(context, builder, value=args[0])
        return builder.ptrtoint(proxy.meminfo, ir.IntType(64))
    return types.int64(instance), codegen


@intrinsic
def _native_at(typingctx, address):
    """The :data:`NATIVE` struct whose meminfo is at ``address`` (a new reference)."""
    struct_type = NATIVE.type

    def codegen(context, builder, signature, args):
        proxy = cgutils.create_struct_proxy(struct_type)(context, builder)
        proxy.meminfo = builder.inttoptr(args[0], proxy.meminfo.type)
        value = proxy._getvalue()
        context.nrt.incref(builder, struct_type, value)
        return value
    return struct_type(types.int64), codegen


@njit(**JIT_OPTIONS)
def _address(native):
    return _address_of(native)


@jitable(inline=True)
def _state(vec):
    """The vectors of :data:`_STATE`, in its order."""
    return (vec.u, vec.v, vec.a, vec.f, vec.p, vec.u_previous, vec.v_previous, vec.a_previous,
            vec.f_previous, vec.p_previous)


@jitable(inline=True)
def _save(native):
    copy(native.saved_run, native.run_bytes)
    k = 0
    for x in _state(native.vec):
        copy(native.saved[k], x)
        k += 1
    held = native.data.held
    for i in range(held.shape[0]):
        native.saved[10, i] = held[i]
    copy(native.saved_global, native.vec.global_error)


@jitable(inline=True)
def _restore(native):
    copy(native.run_bytes, native.saved_run)
    k = 0
    for x in _state(native.vec):
        copy(x, native.saved[k])
        k += 1
    held = native.data.held
    for i in range(held.shape[0]):
        held[i] = native.saved[10, i]
    copy(native.vec.global_error, native.saved_global)


@jitable(inline=True)
def _native_advance(context, t_stop):
    """The integrator's compiled loop (:func:`hfdi.stepping.loop.advance_hfdi`
    or ``advance_affine``) to ``t_stop`` in its records: ``TAKEN``, or
    ``NOT_TAKEN`` with them as before the call."""
    native = _native_at(context[0])
    run, cfg = native.run[0], native.cfg[0]
    if not (t_stop >= run.t and t_stop <= cfg.t_bound):       # NaN included
        return NOT_TAKEN
    _save(native)
    held, inputs = native.data.held, native.inputs
    changed = False
    for i in range(inputs.shape[0]):
        changed = changed or not inputs[i] == held[i]           # NaN counts as changed
    if changed:
        for i in range(inputs.shape[0]):
            held[i] = inputs[i]
        if not refresh(native.fn, cfg, native.data, run, native.vec, False):
            _restore(native)
            return NOT_TAKEN
    limits = native.limits
    cfg.max_steps = min(limits[STEP_LIMIT], run.steps + limits[PER_CALL])
    reason = native.loop.advance(native.fn, native.cfg, native.data, native.run, native.vec,
                                 t_stop, _EVERY)
    if reason == REACHED and run.status >= 0:
        limits[CALLS] += 1
        return TAKEN
    _restore(native)
    return NOT_TAKEN


_SIGNATURE = types.int64(types.CPointer(types.int64), types.float64)


@functools.lru_cache(maxsize=None)
def native_function():
    """The C function, compiled on first use (cached on disk)."""
    return native(_native_advance, _SIGNATURE)


class NativeAdvance:
    """The compiled loop of one :class:`hfdi.Integrator` behind a C function
    (see the module's docstring for the protocol); made by
    :meth:`hfdi.Integrator.native_advance`.

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
        armed state (``f`` undefined for the schemes that keep none).
    n : int
        ``N``, the number of DOFs.
    """

    def __init__(self, integrator, fn, cfg, data, vec, held, run, state, hfdi):
        self._integrator = integrator
        self._twin_run = run                      # the integrator's RUN record
        self.n = state.shape[1]
        self._run = RUN.pack(run)
        self._cfg = cfg.copy()
        self._limits = np.zeros(3, np.int64)
        self._inputs = np.zeros(0)
        self._held = held
        self._parts = (loop_struct(advance_hfdi if hfdi else advance_affine), fn, data, vec)
        self._native = NATIVE.compiled(NATIVE.new(**self._fields()))
        self._context = np.array([_address(self._native)], np.int64)
        self.function_address = native_function().address
        self.context_address = int(self._context.ctypes.data)
        self.time_address = int(self._run.ctypes.data) + RUN.dtype.fields["t"][1]
        self.state_address = int(state.ctypes.data)
        self._armed = False

    @property
    def integrator(self):
        """The :class:`hfdi.Integrator` this object advances."""
        return self._integrator

    @property
    def armed(self) -> bool:
        """Whether the records stand for the integrator's state (since :meth:`arm`)."""
        return self._armed

    @property
    def held(self) -> np.ndarray:
        """The held load's value the armed state was computed with (a copy;
        empty without a :class:`~hfdi.HeldLoad`)."""
        return self._held.copy()

    @property
    def calls(self) -> int:
        """Successful native calls since the last :meth:`arm` or :meth:`sync`."""
        return int(self._limits[CALLS])

    def arm(self, max_steps_per_call: int | None = None, inputs=None) -> str:
        """Take the integrator's state, so that the native ``advance`` continues
        from it; ``""`` when armed, else why not (the run failed, the model
        changed, the held load is not a finite (N,) vector), and the native
        ``advance`` must not be called.

        ``max_steps_per_call``: the steps one call may take at most (attempts
        counted as :attr:`hfdi.Statistics.steps` counts them); a call that
        would need more changes nothing. Also bounded by ``max_steps``.

        ``inputs``: an (N,) float64 C-contiguous array that the host may write
        between calls, for an integrator with a :class:`~hfdi.HeldLoad`: when it
        differs from the held value (:attr:`held`), the next call holds it from
        its start, as ``load_changed()`` after a change of the held load would
        (when not finite, or when the model fails there, the call changes
        nothing). After :meth:`sync` the host must have the held load's source
        return :attr:`held`. The array must outlive the armed state; at
        :meth:`arm` it must equal the held value.
        """
        self.sync()
        self._armed = False
        itg = self._integrator
        if max_steps_per_call is not None and int(max_steps_per_call) < 1:
            raise ValueError(f"max_steps_per_call must be >= 1, got {max_steps_per_call!r}")
        why = itg._native_ready()
        if why:
            return why
        if inputs is None:
            inputs = np.zeros(0)
        elif not (isinstance(inputs, np.ndarray) and inputs.dtype == np.float64
                  and inputs.flags.c_contiguous and inputs.shape == (self.n,)):
            raise ValueError(f"inputs must be a C-contiguous float64 array of shape "
                             f"({self.n},), got {inputs!r}")
        elif self._held.shape[0] == 0:
            raise ValueError("inputs need an integrator with a hfdi.HeldLoad, it has none")
        elif inputs.tolist() != self._held.tolist():
            raise ValueError("inputs must equal the held load's value when armed")
        if inputs is not self._inputs:
            self._inputs = inputs
            self._native = NATIVE.compiled(NATIVE.new(
                **{**self._fields(), "inputs": inputs}))
            self._context[0] = _address(self._native)
        RUN.pack(self._twin_run, self._run)
        self._limits[STEP_LIMIT] = itg.max_steps
        self._limits[PER_CALL] = itg.max_steps if max_steps_per_call is None \
            else int(max_steps_per_call)
        self._limits[CALLS] = 0
        self._armed = True
        return ""

    def _fields(self):
        loop, fn, data, vec = self._parts
        return dict(loop=loop, fn=fn, data=data, vec=vec, cfg=self._cfg, run=self._run,
                    run_bytes=self._run.view(np.uint8),
                    saved_run=np.zeros(self._run.nbytes, np.uint8),
                    saved=np.zeros((len(_STATE) + 1, self.n)),
                    saved_global=np.zeros(2 * self.n), inputs=self._inputs,
                    limits=self._limits)

    def sync(self, cpu_time: float = 0.0) -> int:
        """Hand the native calls' steps back to the integrator (its state,
        statistics and status as :meth:`hfdi.Integrator.advance` leaves them);
        ``cpu_time``, the seconds the caller measured for the calls, is added
        to :attr:`hfdi.Statistics.cpu_time`. Returns the calls synced (0:
        nothing to do). The records stay armed."""
        calls = int(self._limits[CALLS])
        if calls == 0 or not self._armed:
            return 0
        self._limits[CALLS] = 0
        RUN.unpack(self._run, self._twin_run)
        self._integrator._native_synced(cpu_time)
        return calls
