"""IDA at machine speed: SUNDIALS' IDA in C with a compiled residual and Jacobian.

scikit-sundae's IDA (the ``ida`` competitor of :mod:`benchmarks.precision`)
calls a Python residual, so most of its time per step is the interpreter's.
This is the fair competitor of a compiled integrator: the IDA library itself
(``libsundials_ida``, SUNDIALS 6, Debian's ``libsundials-dev``) called
through ctypes, its residual and dense Jacobian numba ``cfunc`` s over the
model's own compiled kernels (:func:`hfdi.compiled.kernels_of`: the same
``f``, ``K`` and ``p`` the compiled HFDI loop calls), and the whole run,
every internal step recorded, in one compiled loop.

The problem is :mod:`validation.reference`'s first-order form, in block order
``y = (u, v)``::

    F(t, y, y') = ( u' − v ,  M v' + C v + f(u) − p(t) ) = 0,
    ∂F/∂y + c_j ∂F/∂y' = [[c_j I, −I], [K(u), c_j M + C]],

from the consistent ``y'(0) = (v0, M⁻¹(p(0) − f(u0) − C v0))``, with IDA's
defaults otherwise (variable order up to 5, its Newton iteration, a dense LU)
and ``IDASetStopTime(t_end)`` so that the last step lands on ``t_end``. A
non-finite residual stops the run (IDA would otherwise retry with ever
smaller steps).

:func:`available` says whether the library is there; :func:`solve` runs one
problem and returns what :func:`validation.reference.ida_solve` returns.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
import math

import numpy as np

__all__ = ["available", "solve", "LIBRARY"]

#: The library's name for :func:`ctypes.util.find_library`.
LIBRARY = "sundials_ida"
#: IDA's flags (ida.h).
_ONE_STEP = 2
_SUCCESS, _TSTOP_RETURN = 0, 1
#: The run's slots in the int64 array the callbacks get as user data.
(_N, _PARAMS, _PARAMS_SIZE, _LOAD_PARAMS, _LOAD_PARAMS_SIZE, _MASS, _DAMPING,
 _SLOTS) = range(8)
#: The compiled loop's own stops (IDA's failures are negative).
_FULL, _BUDGET = 100, 101
#: Kinds of M and C: none (C only), diagonal (a vector), dense.
_NONE, _DIAGONAL, _DENSE = 0, 1, 2

_P = ctypes.c_void_p
_I64 = ctypes.c_int64
_D = ctypes.c_double


@functools.lru_cache(maxsize=None)
def _library():
    """``(ctypes library, "")``, or ``(None, why)``."""
    path = ctypes.util.find_library(LIBRARY)
    if path is None:
        return None, ("SUNDIALS' IDA library (libsundials_ida) is not installed "
                      "(Debian: apt-get install libsundials-dev)")
    try:
        lib = ctypes.CDLL(path)
    except OSError as exc:
        return None, f"{path} does not load: {exc}"
    for name in ("SUNContext_Create", "N_VMake_Serial", "SUNLinSol_Dense", "IDASolve"):
        if not hasattr(lib, name):
            return None, f"{path} has no {name} (SUNDIALS 6 or later is needed)"
    return lib, ""


def available() -> tuple[bool, str]:
    """``(True, "")`` when IDA's library and numba are there, else ``(False, why)``."""
    lib, why = _library()
    if lib is None:
        return False, why
    from hfdi.compiled import numba_available
    return numba_available()


def _function(name, restype, *argtypes):
    """A prototype of its own for ``name`` (ctypes shares ``lib.name``'s)."""
    function = _library()[0][name]
    function.restype = restype
    function.argtypes = argtypes
    return function


@functools.lru_cache(maxsize=None)
def _api():
    """The C functions, prototyped with pointers as ``void *`` for Python and
    as integers for compiled code (the same registers on x86-64 and arm64)."""
    f = _function
    return {
        "context": f("SUNContext_Create", ctypes.c_int, _P, ctypes.POINTER(_P)),
        "context_free": f("SUNContext_Free", ctypes.c_int, ctypes.POINTER(_P)),
        "vector": f("N_VMake_Serial", _P, _I64, _P, _P),
        "vector_free": f("N_VDestroy", None, _P),
        "matrix": f("SUNDenseMatrix", _P, _I64, _I64, _P),
        "matrix_free": f("SUNMatDestroy", None, _P),
        "dense_solver": f("SUNLinSol_Dense", _P, _P, _P, _P),
        "solver_free": f("SUNLinSolFree", ctypes.c_int, _P),
        "create": f("IDACreate", _P, _P),
        "init": f("IDAInit", ctypes.c_int, _P, _P, _D, _P, _P),
        "tolerances": f("IDASVtolerances", ctypes.c_int, _P, _D, _P),
        "linear_solver": f("IDASetLinearSolver", ctypes.c_int, _P, _P, _P),
        "jacobian": f("IDASetJacFn", ctypes.c_int, _P, _P),
        "user_data": f("IDASetUserData", ctypes.c_int, _P, _P),
        "max_steps": f("IDASetMaxNumSteps", ctypes.c_int, _P, ctypes.c_long),
        "stop_time": f("IDASetStopTime", ctypes.c_int, _P, _D),
        "free": f("IDAFree", None, ctypes.POINTER(_P)),
        "flag_name": f("IDAGetReturnFlagName", _P, ctypes.c_long),
        "c_free": _libc_free(),
        **{key: f(name, ctypes.c_int, _P, ctypes.POINTER(ctypes.c_long))
           for key, name in (("steps", "IDAGetNumSteps"), ("nfev", "IDAGetNumResEvals"),
                             ("njev", "IDAGetNumJacEvals"), ("nlu", "IDAGetNumLinSolvSetups"),
                             ("newton", "IDAGetNumNonlinSolvIters"),
                             ("error_test_fails", "IDAGetNumErrTestFails"),
                             ("newton_fails", "IDAGetNumNonlinSolvConvFails"))},
        # for compiled code: pointers as integers
        "solve_c": f("IDASolve", ctypes.c_int, _I64, _D, _I64, _I64, _I64, ctypes.c_int),
        "nfev_c": f("IDAGetNumResEvals", ctypes.c_int, _I64, _I64),
        "array_c": f("N_VGetArrayPointer", ctypes.POINTER(_D), _P),
        "matrix_data_c": f("SUNDenseMatrix_Data", ctypes.POINTER(_D), _P),
    }


def _libc_free():
    free = ctypes.CDLL(None).free
    free.restype, free.argtypes = None, [_P]
    return free


# -- compiled parts ----------------------------------------------------------------------

@functools.lru_cache(maxsize=None)
def _doubles_at():
    """A numba intrinsic: an int64 address as a ``double *``."""
    from numba import types
    from numba.extending import intrinsic

    @intrinsic
    def doubles_at(typingctx, address):
        if not isinstance(address, types.Integer):
            return None
        pointer = types.CPointer(types.float64)

        def codegen(context, builder, signature, args):
            return builder.inttoptr(args[0], context.get_value_type(pointer))
        return pointer(address), codegen
    return doubles_at


@functools.lru_cache(maxsize=None)
def _callbacks(force, stiffness, load, mass_kind, damping_kind):
    """The residual and Jacobian ``cfunc`` s for one set of kernels; the
    matrices' kinds (1 diagonal as a vector, 2 dense; 0 no damping) are
    constants of the code, their values and sizes the run's user data."""
    import numba
    from numba import carray, cfunc, types

    api = _api()
    array_of, matrix_data = api["array_c"], api["matrix_data_c"]
    doubles_at = _doubles_at()

    @numba.njit(inline="always")
    def doubles(slots, slot, size):
        return carray(doubles_at(slots[slot]), (size,))

    @numba.njit(inline="always")
    def times(kind, A, x, n, out):
        """``out += A x`` for ``A`` of ``kind`` stored as (n·n) or (n,)."""
        if kind == _DIAGONAL:
            for i in range(n):
                out[i] += A[i] * x[i]
        elif kind == _DENSE:
            for i in range(n):
                s = 0.0
                for j in range(n):
                    s += A[i * n + j] * x[j]
                out[i] += s

    @numba.njit(inline="always")
    def matrix(slots, slot, kind, n):
        """M or C as stored: (n·n) by rows, (n,) its diagonal, or nothing."""
        size = n * n if kind == _DENSE else (n if kind == _DIAGONAL else 0)
        return doubles(slots, slot, size)

    signature = types.intc(types.float64, types.voidptr, types.voidptr, types.voidptr,
                           types.voidptr)

    @cfunc(signature, error_model="numpy")
    def residual(t, yy, yp, rr, user_data):
        slots = carray(user_data, (_SLOTS,), dtype=np.int64)
        n = slots[_N]
        y = carray(array_of(yy), (2 * n,))
        rate = carray(array_of(yp), (2 * n,))
        r = carray(array_of(rr), (2 * n,))
        params = doubles(slots, _PARAMS, slots[_PARAMS_SIZE])
        f = force(y[:n], params)
        p = load(t, doubles(slots, _LOAD_PARAMS, slots[_LOAD_PARAMS_SIZE]))
        for i in range(n):
            r[i] = rate[i] - y[n + i]
            r[n + i] = f[i] - p[i]
        rv = r[n:]
        times(mass_kind, matrix(slots, _MASS, mass_kind, n), rate[n:], n, rv)
        times(damping_kind, matrix(slots, _DAMPING, damping_kind, n), y[n:], n, rv)
        for i in range(2 * n):
            if not math.isfinite(r[i]):
                return -1          # unrecoverable: the run stops with IDA_RES_FAIL
        return 0

    jacobian_signature = types.intc(types.float64, types.float64, types.voidptr, types.voidptr,
                                    types.voidptr, types.voidptr, types.voidptr, types.voidptr,
                                    types.voidptr, types.voidptr)

    @cfunc(jacobian_signature, error_model="numpy")
    def jacobian(t, cj, yy, yp, rr, J, user_data, tmp1, tmp2, tmp3):
        slots = carray(user_data, (_SLOTS,), dtype=np.int64)
        n = slots[_N]
        m = 2 * n
        y = carray(array_of(yy), (m,))
        # column-major, (2n)²: entry (row, col) at col·2n + row
        a = carray(matrix_data(J), (m * m,))
        K = stiffness(y[:n], doubles(slots, _PARAMS, slots[_PARAMS_SIZE]))
        mass = matrix(slots, _MASS, mass_kind, n)
        damping = matrix(slots, _DAMPING, damping_kind, n)
        for k in range(m * m):
            a[k] = 0.0
        for i in range(n):
            a[i * m + i] = cj                       # ∂(u' − v)/∂u'
            a[(n + i) * m + i] = -1.0               # ∂(u' − v)/∂v
            for j in range(n):
                a[j * m + n + i] = K[i, j]          # ∂f/∂u
        for i in range(n):
            if mass_kind == _DIAGONAL:
                a[(n + i) * m + n + i] += cj * mass[i]
            else:
                for j in range(n):
                    a[(n + j) * m + n + i] += cj * mass[i * n + j]
            if damping_kind == _DIAGONAL:
                a[(n + i) * m + n + i] += damping[i]
            elif damping_kind == _DENSE:
                for j in range(n):
                    a[(n + j) * m + n + i] += damping[i * n + j]
        return 0

    return residual, jacobian


@functools.lru_cache(maxsize=None)
def _loop():
    """The run's loop, compiled: IDASolve one step at a time, each step's
    ``t`` and ``y`` recorded, until ``t_end``, a failure, the work budget, or
    full arrays (the caller then grows them and calls again)."""
    import numba
    api = _api()
    solve_step, count_residuals = api["solve_c"], api["nfev_c"]

    @numba.njit
    def steps(mem, t_end, now, y, y_vector, rate_vector, out_t, out_y, k, max_nfev, nfev):
        while k < out_t.size:
            flag = solve_step(mem, t_end, now.ctypes.data, y_vector, rate_vector, _ONE_STEP)
            if flag < 0:
                return k, flag
            out_t[k] = now[0]
            out_y[k, :] = y
            k += 1
            count_residuals(mem, nfev.ctypes.data)
            if flag == _TSTOP_RETURN or now[0] >= t_end:
                return k, _TSTOP_RETURN
            if nfev[0] > max_nfev:
                return k, _BUDGET
        return k, _FULL
    return steps


# -- one run ----------------------------------------------------------------------------

def _stored(a):
    """``(kind, float64 array)`` of M or C as the first-order form holds it
    (``None``, a diagonal, dense or sparse): a diagonal as its vector, else
    dense by rows."""
    import scipy.sparse as sp
    if a is None:
        return _NONE, np.zeros(1)
    if sp.issparse(a):
        a = a.toarray()
    a = np.ascontiguousarray(a, dtype=float)
    if a.ndim == 1:
        return _DIAGONAL, a
    return _DENSE, a.reshape(-1).copy()


class Problem:
    """A model's compiled first-order form for IDA: the callbacks and the data
    they read. Built outside the timed solve (compiling the callbacks takes a
    second once per process and set of kernels)."""

    def __init__(self, model):
        from hfdi.compiled import kernels_of
        ok, why = available()
        if not ok:
            raise RuntimeError(why)
        kernels, why = kernels_of(model)
        if kernels is None:
            raise ValueError(f"the model has no compiled kernels: {why}")
        if kernels.load is None:
            raise ValueError("the model's compiled kernels have no load")
        from validation.reference import _FirstOrderForm
        n = int(model.n_dof)
        self.model, self.n = model, n
        # the first-order form of the references: its M, C and consistent start
        self.form = _FirstOrderForm(model, "dense")
        self.mass_kind, self.mass = _stored(self.form.M)
        self.damping_kind, self.damping = _stored(self.form.C)
        self.params = np.ascontiguousarray(kernels.params, dtype=float)
        self.load_params = np.ascontiguousarray(
            kernels.params if kernels.load_params is None else kernels.load_params, dtype=float)
        self.residual, self.jacobian = _callbacks(kernels.force, kernels.stiffness, kernels.load,
                                                  self.mass_kind, self.damping_kind)
        self.slots = np.zeros(_SLOTS, np.int64)
        self.slots[_N] = n
        self.slots[_PARAMS], self.slots[_PARAMS_SIZE] = self.params.ctypes.data, self.params.size
        self.slots[_LOAD_PARAMS] = self.load_params.ctypes.data
        self.slots[_LOAD_PARAMS_SIZE] = self.load_params.size
        self.slots[_MASS] = self.mass.ctypes.data
        self.slots[_DAMPING] = self.damping.ctypes.data
        _loop()

    def initial_state(self):
        """``y0`` and the consistent ``y'(0) = (v0, M⁻¹(p − f − C v0))``, in block
        order ``(u, v)`` (:mod:`validation.reference`'s dense form)."""
        _, _, y0, rate0 = self.form.initial_state(0.0)
        return y0, rate0

def solve(problem: Problem, t_end, *, rtol, atol, max_nfev=10 ** 12,
          first_capacity=4096) -> dict:
    """One IDA run of ``problem`` over ``[0, t_end]``, every internal step kept;
    a failure is reported, not raised.

    ``atol`` (2N,) in ``(u, v)`` order. Returns ``t`` (steps + 1,), ``u``, ``v``,
    ``success``, ``status`` (IDA's flag, or ``"BUDGET"`` after ``max_nfev``
    residual evaluations), ``message``, ``steps``, ``nfev``, ``njev``,
    ``nlu`` (LU factorisations), ``newton_iterations``, ``error_test_fails``,
    ``newton_failures``, ``linsolver`` (``"dense"``) and ``atol``.
    """
    api, n = _api(), problem.n
    if not (math.isfinite(rtol) and 0 < rtol < 1):
        raise ValueError(f"rtol must be in (0, 1), got {rtol!r}")
    atol = np.ascontiguousarray(atol, dtype=float)
    if atol.shape != (2 * n,) or not (np.isfinite(atol).all() and (atol > 0).all()):
        raise ValueError(f"atol must be 2N = {2 * n} positive finite values, got {atol!r}")
    y0, rate0 = problem.initial_state()
    y, rate = y0.copy(), rate0.copy()
    context = _P()
    if api["context"](None, ctypes.byref(context)) != 0:
        raise RuntimeError("SUNContext_Create failed")
    made = []
    mem = _P()
    try:
        y_vector = api["vector"](2 * n, y.ctypes.data, context)
        rate_vector = api["vector"](2 * n, rate.ctypes.data, context)
        atol_vector = api["vector"](2 * n, atol.ctypes.data, context)
        made += [(api["vector_free"], v) for v in (y_vector, rate_vector, atol_vector)]
        matrix = api["matrix"](2 * n, 2 * n, context)
        made.append((api["matrix_free"], matrix))
        linear = api["dense_solver"](y_vector, matrix, context)
        made.append((api["solver_free"], linear))
        mem.value = api["create"](context)
        for name, args in (("init", (problem.residual.address, 0.0, y_vector, rate_vector)),
                           ("tolerances", (rtol, atol_vector)),
                           ("linear_solver", (linear, matrix)),
                           ("jacobian", (problem.jacobian.address,)),
                           ("user_data", (problem.slots.ctypes.data,)),
                           ("max_steps", (-1,)),          # no limit: the budget is max_nfev
                           ("stop_time", (float(t_end),))):
            flag = api[name](mem, *args)
            if flag != 0:
                raise RuntimeError(f"IDA's {name} set-up failed with flag {flag}")
        steps = _loop()
        capacity = first_capacity
        out_t = np.empty(capacity)
        out_y = np.empty((capacity, 2 * n))
        out_t[0], out_y[0] = 0.0, y0
        now, nfev = np.zeros(1), np.zeros(1, np.int64)
        k = 1
        while True:
            k, flag = steps(mem.value, float(t_end), now, y, y_vector, rate_vector, out_t,
                            out_y, k, max_nfev, nfev)
            if flag != _FULL:
                break
            capacity *= 2
            out_t = np.concatenate([out_t, np.empty(capacity - out_t.size)])
            out_y = np.concatenate([out_y, np.empty((capacity - out_y.shape[0], 2 * n))])
        stats = {}
        for key in ("steps", "nfev", "njev", "nlu", "newton", "error_test_fails",
                    "newton_fails"):
            count = ctypes.c_long()
            api[key](mem, ctypes.byref(count))
            stats[key] = int(count.value)
    finally:
        if mem.value:
            api["free"](ctypes.byref(mem))
        for free, handle in reversed(made):
            free(handle)
        api["context_free"](ctypes.byref(context))
    t, yk = out_t[:k], out_y[:k]
    success = flag == _TSTOP_RETURN and t[-1] == t_end
    if success:
        status, message = "SUCCESS", "IDA reached t_end"
    elif flag == _BUDGET:
        status = "BUDGET"
        message = (f"stopped at t = {t[-1]:.6g} after {stats['nfev']} residual evaluations "
                   f"(work budget)")
    else:
        status, message = f"IDA_{flag}", f"IDA failed at t = {t[-1]:.6g}: {_flag_name(flag)}"
    return {"t": t, "u": yk[:, :n], "v": yk[:, n:], "success": bool(success), "status": status,
            "message": message, "steps": stats["steps"], "nfev": stats["nfev"],
            "njev": stats["njev"], "nlu": stats["nlu"], "newton_iterations": stats["newton"],
            "error_test_fails": stats["error_test_fails"],
            "newton_failures": stats["newton_fails"], "linsolver": "dense", "atol": atol}


def _flag_name(flag):
    api = _api()
    name = api["flag_name"](flag)
    if not name:
        return f"flag {flag}"
    try:
        return ctypes.string_at(name).decode()
    finally:
        api["c_free"](name)
