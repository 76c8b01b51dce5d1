"""The compiled driver: a run of ordinary steps in one call from Python.

:meth:`hfdi.Integrator.advance` hands its state to :func:`drive`, which takes
steps until ``t_stop`` (or until its row buffer is full) with everything a
step needs compiled: the model's kernels (f, K, T, V and the load p), the
attempt of :mod:`hfdi.compiled.attempt` (predictor, stages, Newton), the
error estimate (:func:`hfdi.corrector.local_error`), the built-in controllers'
rules (:mod:`hfdi.controller`: :class:`~hfdi.controller.FixedStep`,
:class:`~hfdi.controller.IterationCount`, :class:`~hfdi.controller.ErrorControl`,
:class:`~hfdi.controller.Combined`), landing, the statistics and the energy
balance (Eqs. 40–41).

It hands the step back to the Python driver, before the attempt that needs it
and with the rejections of the step so far, whenever a step is not ordinary:
an attempt that lands on a load breakpoint (one-sided loads and the load's
right limit after it), a short step (:data:`hfdi.corrector.SHORT_STEP`), a
decision that would stop the run (the controller's message), ``max_steps``,
a step below the resolution of time. The Python
driver then takes that one step as always, so that the statuses and messages
have one source. After a step that breaks the energy limit it returns at
once, and Python applies its own test.

Every formula restates, operation for operation and in the same order, the
Python code it stands for (named in each function), so that on models whose
kernels agree bit for bit with their Python methods the two drivers take the
same steps; numpy's pairwise sum is restated for the error norm's mean.
``tests/test_compiled_driver.py`` holds the two drivers against each other.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from ..evaluation import State
from .attempt import (BATHE, DERIVATIVE_SHAPE, END_A, END_F, END_U, END_V, FORCE_SHAPE,
                      HFDI_SCHEME, INFO_SIZE, MID_U, NFEV, NJEV, NLU, NTEV, OK, STAGES_COUNTED,
                      STIFFNESS_SHAPE, T_END, T_PREVIOUS, T_START, attempt, workspace)
from .lapack import all_finite
from .attempt import HAS_PREVIOUS as A_HAS_PREVIOUS
from .attempt import HAS_START_FORCE as A_HAS_START_FORCE
from .attempt import FLOOR as A_FLOOR
from .attempt import GAMMA as A_GAMMA
from .attempt import MASS_KIND as A_MASS_KIND
from .attempt import MAX_ITERATIONS as A_MAX_ITERATIONS
from .attempt import NEWTON_CONSTANT as A_NEWTON_CONSTANT
from .attempt import NEWTON_GUARD as A_NEWTON_GUARD
from .attempt import NEWTON_TEST as A_NEWTON_TEST
from .attempt import SCHEME as A_SCHEME
from .attempt import TOL as A_TOL
from .signatures import INDEX_VECTOR, JIT_OPTIONS, KERNEL_SET, MATRIX, VECTOR
from ..corrector import is_short as _is_short
from ..evaluation import energy_overflows as _energy_overflows
from ..evaluation import potential_lost as _potential_lost

__all__ = ["drive"]

_EPS = float(np.finfo(float).eps)

# the Python driver's rules, compiled as they are (hfdi.compiled.cache watches
# corrector.py and evaluation.py)
is_short = njit(**JIT_OPTIONS)(_is_short)
energy_overflows = njit(**JIT_OPTIONS)(_energy_overflows)
potential_lost = njit(**JIT_OPTIONS)(_potential_lost)

# -- why drive() returned ------------------------------------------------------------
REACHED = 0          # t_stop reached
FULL = 1             # the row buffer is full: call again
HAND_OVER = 2        # the Python driver takes the next attempt (rejections so far kept)
ENERGY_CHECK = 3     # the last accepted step broke the energy limit

# -- controllers -----------------------------------------------------------------------
FIXED, ITERATION, ERROR, COMBINED = range(4)

# -- entries of ``settings`` (float64, read only) --------------------------------------
(FIXED_STEP, IT_TARGET, IT_MIN_STEP, IT_MAX_STEP, ER_MIN_STEP, ER_MAX_STEP, SAFETY, GROW,
 SHRINK, ENERGY_LIMIT, T_STOP, VELOCITY_GAIN) = range(12)
# -- entries of ``switches`` (int64, read only) ----------------------------------------
(CONTROLLER, IT_MAX_REJECTIONS, ER_MAX_REJECTIONS, ORDER, MAX_STEPS, SAVE_ROWS,
 CALL_STEPS, EXACT_RATE) = range(8)
# -- entries of ``scalars`` (float64, read and written) --------------------------------
(T_CURRENT, T_PREV, PROPOSED, POTENTIAL, INITIAL_POTENTIAL, WORK, ENERGY_ERROR,
 ENERGY_SCALE, LAST_STEP, LAST_ENERGY_INCREMENT, GRID_ORIGIN) = range(11)
# -- entries of ``counters`` (int64, read and written) ---------------------------------
(HAS_PREV, CURRENT_HAS_F, PREVIOUS_HAS_F, GRID_STEPS, STEPS, ACCEPTED, REJECTED,
 NEWTON_ITERATIONS, ERROR_TEST_FAILURES, C_NFEV, C_NJEV, C_NTEV, C_NLU, C_NPEV,
 LAST_ITERATIONS, REJECTIONS, ROWS) = range(17)
# -- rows of ``current`` and ``previous`` (5, N) ---------------------------------------
U, V, A, F, P = range(5)
# -- columns of ``row_scalars`` (R, 5): t, h, iterations, ΔE, W, work -------------------
R_T, R_H, R_ITERATIONS, R_INCREMENT, R_ENERGY, R_WORK = range(6)


# -- numpy's arithmetic, restated -------------------------------------------------------

@njit(**JIT_OPTIONS)
def _block_sum(a, lo, n):
    """numpy's pairwise summation of ``a[lo:lo + n]`` for ``n <= 128`` (one block)."""
    if n < 8:
        total = -0.0
        for i in range(lo, lo + n):
            total += a[i]
        return total
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - (n % 8):
        j = lo + i
        r0 += a[j]
        r1 += a[j + 1]
        r2 += a[j + 2]
        r3 += a[j + 3]
        r4 += a[j + 4]
        r5 += a[j + 5]
        r6 += a[j + 6]
        r7 += a[j + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        total += a[lo + i]
        i += 1
    return total


@njit(**JIT_OPTIONS)
def _pairwise_sum(a):
    """``np.add.reduce(a)`` for a contiguous float64 vector: numpy's pairwise
    summation (``pairwise_sum`` of its loops), in its order. Above a block of
    128 numpy splits at half (rounded down to a multiple of 8) and adds the
    two halves' sums; the recursion runs here on an explicit stack (numba
    cannot cache recursive functions)."""
    n = a.shape[0]
    if n <= 128:
        return _block_sum(a, 0, n)
    depth = 64
    starts = np.empty(depth, np.int64)
    sizes = np.empty(depth, np.int64)
    phase = np.zeros(depth, np.int64)       # 0: new, 1: left half pending, 2: right half
    lefts = np.empty(depth)
    top = 0
    starts[0], sizes[0] = 0, n
    while True:
        m = sizes[top]
        if m > 128 and phase[top] == 0:
            half = m // 2
            half -= half % 8
            phase[top] = 1
            top += 1
            starts[top], sizes[top], phase[top] = starts[top - 1], half, 0
            continue
        value = _block_sum(a, starts[top], m)
        top -= 1
        while True:               # hand the value to the halves waiting for it
            if top < 0:
                return value
            if phase[top] == 1:
                lefts[top] = value
                phase[top] = 2
                half = sizes[top] // 2
                half -= half % 8
                top += 1
                starts[top] = starts[top - 1] + half
                sizes[top] = sizes[top - 1] - half
                phase[top] = 0
                break
            value = lefts[top] + value
            top -= 1


@njit(**JIT_OPTIONS)
def _mass_dot(Md, Mf, m_kind, v, work):
    """``v · (M v)`` (the kinetic energy's quadratic form); ``work`` (N,) holds ``M v``."""
    if m_kind == 2:
        np.dot(Mf, v, work)
    else:
        for i in range(v.shape[0]):
            work[i] = Md[i] * v[i]
    return float(np.dot(v, work))


@njit(inline="always", **JIT_OPTIONS)
def _difference_and_sum(a, b, c, d, difference, total):
    """``difference = a − b`` and ``total = c + d`` (the factors of a step's work)."""
    for i in range(a.shape[0]):
        difference[i] = a[i] - b[i]
        total[i] = c[i] + d[i]


# -- the error estimate (hfdi.corrector.local_error) -----------------------------------

@njit(**JIT_OPTIONS)
def _local_error(current, previous, t_current, t_previous, has_previous, new, h, order, e):
    """:func:`hfdi.corrector.local_error` (with :func:`~hfdi.corrector.predict_from_rates`
    and :func:`~hfdi.corrector.velocity_history_factor`) into ``e`` (2N,), ``u``'s
    then ``v``'s, which it returns."""
    n = current.shape[1]
    if not has_previous:
        for i in range(n):
            Q = current[U, i] + h * current[V, i] + (0.5 * h * h) * current[A, i]
            e[i] = new[END_U, i] - Q
            e[n + i] = new[END_V, i] - (current[V, i] + h * current[A, i])
        return e
    H = t_current - t_previous
    s = h
    s2 = s * s
    sigma = h / H
    factor = 1.0 + (3.0 + 2.0 * sigma) * math.pow(sigma, 1.0 - order)
    H3 = math.pow(H, 3.0)
    for i in range(n):
        r2 = previous[V, i] - current[V, i] + H * current[A, i]
        r3 = previous[A, i] - current[A, i]
        c3 = r2 / (H * H) + r3 / (3.0 * H)
        c4 = (2.0 * r2 + H * r3) / (4.0 * H3)
        Q = (current[U, i] + s * current[V, i] + (0.5 * s2) * current[A, i] + (s2 * s) * c3
             + (s2 * s2) * c4)
        dQ = current[V, i] + s * current[A, i] + (3.0 * s2) * c3 + (4.0 * s2 * s) * c4
        e[i] = new[END_U, i] - Q
        e[n + i] = (new[END_V, i] - dQ) / factor
    return e


@njit(**JIT_OPTIONS)
def _error_norm(error, current, new, rtol, atol, noise, ratio):
    """:meth:`hfdi.controller.ErrorControl.error_norm`: the weighted RMS norm
    (``ratio`` (2N,) a work array)."""
    n = current.shape[1]
    for i in range(2 * n):
        row = U if i < n else V
        j = i if i < n else i - n
        end_row = END_U if i < n else END_V
        scale = atol[i] + rtol[i] * max(abs(current[row, j]), abs(new[end_row, j]))
        if noise != 0.0 and i >= n:
            scale += noise
        if error[i] == 0.0:
            ratio[i] = 0.0
        else:
            r = error[i] / scale
            ratio[i] = r * r
    return math.sqrt(_pairwise_sum(ratio) / (2 * n))


# -- the controllers' rules (hfdi.controller) -----------------------------------------

@njit(**JIT_OPTIONS)
def _clamp(h, low, high):
    return min(max(h, low), high)


@njit(**JIT_OPTIONS)
def _retry(rejections, max_rejections, h_next, min_step):
    """:meth:`Controller._retry`: ``(accept=False, h_next, stops)``; it stops after
    ``max_rejections`` rejections or below ``min_step``."""
    return False, h_next, rejections + 1 > max_rejections or h_next < min_step


@njit(**JIT_OPTIONS)
def _iteration_adapt(settings, switches, h, proposed, clipped, converged, iterations,
                     rejections):
    """:meth:`IterationCount.adapt` (with ``next_step``)."""
    if converged:
        target = settings[IT_TARGET]
        if clipped and iterations <= target:
            new = proposed
        else:
            new = h * math.sqrt(target / max(iterations, 1))
        return True, _clamp(new, settings[IT_MIN_STEP], settings[IT_MAX_STEP]), False
    return _retry(rejections, switches[IT_MAX_REJECTIONS], 0.5 * h, settings[IT_MIN_STEP])


@njit(**JIT_OPTIONS)
def _error_adapt(settings, switches, h, proposed, clipped, converged, err, history,
                 rejections):
    """:meth:`ErrorControl.adapt` (with ``_factor`` and ``_exponent``)."""
    max_rejections, min_step = switches[ER_MAX_REJECTIONS], settings[ER_MIN_STEP]
    if not converged:
        return _retry(rejections, max_rejections, 0.5 * h, min_step)
    if not math.isfinite(err):
        return _retry(rejections, max_rejections, 0.5 * h, min_step)
    grow = settings[GROW]
    exponent = 1.0 / (switches[ORDER] + 1) if history else 1.0 / 3.0
    if err == 0.0:
        factor = grow
    else:
        factor = min(grow, max(settings[SHRINK], settings[SAFETY] * math.pow(err, -exponent)))
    if err <= 1.0:
        if rejections:
            factor = min(factor, 1.0)
        h_next = h * factor
        if clipped:
            h_next = max(h_next, min(proposed, h * grow))
        return True, _clamp(h_next, min_step, settings[ER_MAX_STEP]), False
    return _retry(rejections, max_rejections, h * factor, min_step)


@njit(**JIT_OPTIONS)
def _landing(kind, h, remaining):
    """The controller's ``landing`` (IterationCount's own; the base rule else)."""
    if kind == ITERATION:
        if h >= remaining or remaining - h <= 0.01 * h:
            return remaining
        return h
    if remaining <= 1.1 * h:
        return remaining
    if remaining < 2.0 * h:
        return 0.5 * remaining
    return h


@njit(**JIT_OPTIONS)
def _limit(breakpoints, t, t_limit, fixed, grid_origin, h):
    """:meth:`Integrator._limit`: ``t_limit`` or the next breakpoint before it
    (with ``fixed``, the next one on the grid ``grid_origin + k h``)."""
    if breakpoints.shape[0]:
        i = np.searchsorted(breakpoints, t, side="right")
        while i < breakpoints.shape[0] and breakpoints[i] < t_limit:
            point = breakpoints[i]
            if not fixed or abs(point - (grid_origin + round((point - grid_origin) / h) * h)) \
                    <= 1e-6 * h:
                return point
            i += 1
    return t_limit


@njit(**JIT_OPTIONS)
def _is_breakpoint(breakpoints, t):
    if breakpoints.shape[0] == 0:
        return False
    i = np.searchsorted(breakpoints, t)
    return i < breakpoints.shape[0] and breakpoints[i] == t


_SIGNATURE = types.Tuple((types.int64, types.int64))(
    KERNEL_SET,                                       # f, K, T, V, the load and its rate
    VECTOR, VECTOR, VECTOR,                           # params, load_params, held load
    INDEX_VECTOR, VECTOR,                             # the attempt's config and coefficients
    VECTOR, MATRIX, VECTOR, MATRIX,                   # M, C
    VECTOR, INDEX_VECTOR, VECTOR, VECTOR, VECTOR,     # settings, switches, rtol, atol, bps
    VECTOR, INDEX_VECTOR,                             # scalars, counters
    MATRIX, MATRIX,                                   # current, previous
    MATRIX, types.float64[:, :, ::1])                 # row scalars, row states


@njit(_SIGNATURE, **JIT_OPTIONS)
def drive(kernels, params, load_params, held, config, coefficients, Md, Mf, Cd, Cf, settings,
          switches, rtol, atol, breakpoints, scalars, counters, current, previous, row_scalars,
          row_states):
    """Take ordinary steps towards ``settings[T_STOP]``; see the module's docstring.

    Parameters
    ----------
    kernels : KernelSet (:func:`hfdi.compiled.attempt.kernel_set`)
        The compiled ``force``, ``stiffness``, ``stiffness_derivative``,
        ``potential_energy``, ``load`` and ``load_rate`` (the last called only
        with ``switches[EXACT_RATE]``).
    params, load_params : ndarray (P,), (Q,)
    held : ndarray (N,) or (0,)
        A :class:`~hfdi.HeldLoad`'s value, added to the load (none: empty).
    config, coefficients : the attempt's (see :func:`hfdi.compiled.attempt.attempt`),
        scheme, ``N_max``, kinds of ``M`` and ``C``, the Newton test, ``γ``, ``β``,
        ``η`` and floor set; Newton's carried constant and guard read and updated
        in place
    Md, Mf, Cd, Cf : ``M`` and ``C`` (see :func:`~hfdi.compiled.attempt.attempt`)
    settings : ndarray (12,)
        The controllers' sizes and factors, the energy limit (``inf``: none),
        ``t_stop`` and the scheme's ``velocity_gain``.
    switches : ndarray (8,) int64
        Controller kind, its ``max_rejections`` (iteration, error), the scheme's
        order, ``max_steps``, whether to write rows, how many steps to take
        at most in this call (at most ``R`` when writing rows), and whether
        HFDI takes the exact load rate.
    rtol, atol : ndarray (2N,)
        Tolerances over ``(u, v)`` (unused without error control).
    breakpoints : ndarray (B,)
        Sorted load breakpoints (empty in the iteration-count mode; the fixed
        step lands on those on its grid).
    scalars : ndarray (11,), counters : ndarray (17,) int64
        The integrator's state and statistics, updated in place.
    current, previous : ndarray (5, N)
        ``u, v, a, f, p`` of the current and the previous state, updated in place.
    row_scalars : ndarray (R, 6), row_states : ndarray (R, 3, N)
        Written with ``t, h, iterations, ΔE, W, work`` and ``u, v, a`` of each
        accepted step when ``switches[SAVE_ROWS]``.

    Returns
    -------
    reason : int
        :data:`REACHED`, :data:`FULL`, :data:`HAND_OVER` or :data:`ENERGY_CHECK`.
    rows : int
        Accepted steps taken (and rows written).
    """
    force, stiffness, derivative = (kernels.force, kernels.stiffness,
                                    kernels.stiffness_derivative)
    potential_energy, load, load_rate = kernels.potential_energy, kernels.load, kernels.load_rate
    n = current.shape[1]
    kind = switches[CONTROLLER]
    scheme = config[A_SCHEME]
    uses_error = kind == ERROR or kind == COMBINED
    m_kind = config[A_MASS_KIND]
    t_stop = settings[T_STOP]
    save = switches[SAVE_ROWS] != 0
    capacity = switches[CALL_STEPS]
    loads = np.zeros((3, n))
    history = np.empty((2, n))
    # the work arrays of every attempt and of the error estimate and the
    # energy balance, made once per call (an allocation costs about 50 ns)
    out, info = np.empty((7, n)), np.empty(INFO_SIZE, np.int64)  # attempt() zeroes them
    vectors, matrices, pivots, ints = workspace(n)
    error, ratio = np.empty(2 * n), np.empty(2 * n)
    difference, load_sum = np.empty(n), np.empty(n)
    taken = 0
    rejections = 0
    if held.shape[0] and not all_finite(held):
        # the Python driver evaluates the load and reports which entry
        counters[REJECTIONS] = 0
        return HAND_OVER, taken
    while scalars[T_CURRENT] < t_stop:
        if taken >= capacity:
            counters[REJECTIONS] = rejections
            return FULL, taken
        t = scalars[T_CURRENT]
        limit = _limit(breakpoints, t, t_stop, kind == FIXED, scalars[GRID_ORIGIN],
                       scalars[PROPOSED])
        if counters[STEPS] >= switches[MAX_STEPS]:
            counters[REJECTIONS] = rejections
            return HAND_OVER, taken
        # Integrator._clip
        proposed = scalars[PROPOSED]
        remaining = limit - t
        if kind == FIXED:
            t_next = scalars[GRID_ORIGIN] + (counters[GRID_STEPS] + 1) * proposed
            if t_next >= limit - 1e-6 * proposed:
                t_end, clipped = limit, True
            else:
                t_end, clipped = t_next, False
        else:
            take = _landing(kind, proposed, remaining)
            if take >= remaining:
                t_end, clipped = limit, True
            else:
                t_end, clipped = t + take, take != proposed
        h = t_end - t
        if not h > 0.0 or _is_breakpoint(breakpoints, t_end) or is_short(h, proposed):
            counters[REJECTIONS] = rejections
            return HAND_OVER, taken
        # the loads at the stage times (CompiledStep._loads)
        # (Evaluator.load: the model's load, then + the extra load)
        if scheme == BATHE:
            loads[0] = load(t + coefficients[A_GAMMA] * h, load_params)
            if held.shape[0]:
                for i in range(n):
                    loads[0, i] = loads[0, i] + held[i]
        loads[1] = load(t_end, load_params)
        if held.shape[0]:
            for i in range(n):
                loads[1, i] = loads[1, i] + held[i]
        if scheme == HFDI_SCHEME:
            if switches[EXACT_RATE]:
                loads[2] = load_rate(t_end, load_params)
            else:
                for i in range(n):
                    loads[2, i] = (loads[1, i] - current[P, i]) / h
        has_previous = counters[HAS_PREV] != 0
        config[A_HAS_PREVIOUS] = 1 if has_previous else 0
        config[A_HAS_START_FORCE] = counters[CURRENT_HAS_F]
        coefficients[T_START], coefficients[T_END] = t, t_end
        coefficients[T_PREVIOUS] = scalars[T_PREV] if has_previous else t
        if has_previous:
            history[0] = previous[U]
            history[1] = previous[V]
        constant, guard = coefficients[A_NEWTON_CONSTANT], coefficients[A_NEWTON_GUARD]
        status, out, info, newton_error = attempt(
            force, stiffness, derivative, params, config, coefficients, Md, Mf, Cd, Cf,
            current, history, loads, out, info, vectors, matrices, pivots, ints)
        if status == FORCE_SHAPE or status == STIFFNESS_SHAPE or status == DERIVATIVE_SHAPE:
            # a kernel's value of a wrong shape: the Python driver redoes the
            # attempt and stops the run with MODEL_ERROR
            coefficients[A_NEWTON_CONSTANT], coefficients[A_NEWTON_GUARD] = constant, guard
            counters[REJECTIONS] = rejections
            return HAND_OVER, taken
        converged = status == OK
        iterations = 0
        for i in range(info[STAGES_COUNTED]):
            iterations += info[i]
        # the controller's verdict
        err = math.inf
        if uses_error and converged:
            error = _local_error(current, previous, t, scalars[T_PREV], has_previous, out, h,
                                 switches[ORDER], error)
            largest = 0.0
            for i in range(n):
                largest = max(largest, abs(out[END_U, i]))
            noise = settings[VELOCITY_GAIN] * (newton_error + _EPS * largest) / h
            err = _error_norm(error, current, out, rtol, atol, noise, ratio)
        if kind == FIXED:
            accept, h_next, stops = converged, settings[FIXED_STEP], not converged
        elif kind == ITERATION:
            accept, h_next, stops = _iteration_adapt(settings, switches, h, proposed, clipped,
                                                     converged, iterations, rejections)
        elif kind == ERROR:
            accept, h_next, stops = _error_adapt(settings, switches, h, proposed, clipped,
                                                 converged, err, has_previous, rejections)
        else:
            a_accept, a_next, a_stops = _iteration_adapt(settings, switches, h, proposed,
                                                         clipped, converged, iterations,
                                                         rejections)
            b_accept, b_next, b_stops = _error_adapt(settings, switches, h, proposed, clipped,
                                                     converged, err, has_previous, rejections)
            accept, h_next = a_accept and b_accept, min(a_next, b_next)
            stops = a_stops or b_stops
        potential = kinetic_old = kinetic_new = work = 0.0
        if accept:
            # Integrator._accept: the energy balance (Eqs. 40-41)
            potential = potential_energy(np.ascontiguousarray(out[END_U]), params)
            # difference holds M v here, then u's increment below
            kinetic_old = 0.5 * _mass_dot(Md, Mf, m_kind, current[V], difference)
            kinetic_new = 0.5 * _mass_dot(Md, Mf, m_kind, out[END_V], difference)
            if scheme == BATHE:
                _difference_and_sum(out[MID_U], current[U], current[P], loads[0], difference,
                                    load_sum)
                work = 0.5 * float(np.dot(difference, load_sum))
                _difference_and_sum(out[END_U], out[MID_U], loads[0], loads[1], difference,
                                    load_sum)
                work += 0.5 * float(np.dot(difference, load_sum))
            else:
                _difference_and_sum(out[END_U], current[U], current[P], loads[1], difference,
                                    load_sum)
                work = 0.5 * float(np.dot(difference, load_sum))
            stops = energy_overflows(kinetic_new, work, potential) or potential_lost(
                potential, scalars[INITIAL_POTENTIAL])
        if stops:
            # the run stops here: the Python driver redoes this attempt and says why
            # (from the corrector's memory as it was before it)
            coefficients[A_NEWTON_CONSTANT], coefficients[A_NEWTON_GUARD] = constant, guard
            counters[REJECTIONS] = rejections
            return HAND_OVER, taken
        counters[STEPS] += 1
        counters[NEWTON_ITERATIONS] += iterations
        counters[C_NFEV] += info[NFEV]
        counters[C_NJEV] += info[NJEV]
        counters[C_NTEV] += info[NTEV]
        counters[C_NLU] += info[NLU]
        scalars[PROPOSED] = h_next
        if not accept:
            counters[REJECTED] += 1
            if converged:
                counters[ERROR_TEST_FAILURES] += 1
            rejections += 1
            continue
        # Integrator._accept: the new state
        rejections = 0
        counters[C_NPEV] += 1
        increment = potential - scalars[POTENTIAL] + kinetic_new - kinetic_old - work
        if not is_short(h, scalars[PROPOSED]):      # a short step is no history
            previous[:, :] = current
            counters[PREVIOUS_HAS_F] = counters[CURRENT_HAS_F]
            scalars[T_PREV] = t
            counters[HAS_PREV] = 1
        current[U] = out[END_U]
        current[V] = out[END_V]
        current[A] = out[END_A]
        if scheme == HFDI_SCHEME:
            current[F] = out[END_F]
            counters[CURRENT_HAS_F] = 1
        else:
            current[F] = 0.0
            counters[CURRENT_HAS_F] = 0
        current[P] = loads[1]
        scalars[T_CURRENT] = t_end
        if kind == FIXED:
            grid_next = scalars[GRID_ORIGIN] + (counters[GRID_STEPS] + 1) * h
            if clipped and t_end != grid_next and abs(
                    t_end - (scalars[GRID_ORIGIN] + (counters[GRID_STEPS] + 1) * proposed)) \
                    > 1e-6 * proposed:
                scalars[GRID_ORIGIN] = t_end
                counters[GRID_STEPS] = 0
            else:
                counters[GRID_STEPS] += 1
        scalars[WORK] += work
        scalars[ENERGY_ERROR] += increment
        scalars[ENERGY_SCALE] = max(scalars[ENERGY_SCALE], kinetic_new + abs(
            potential - scalars[INITIAL_POTENTIAL]) + abs(scalars[WORK]))
        scalars[POTENTIAL] = potential
        scalars[LAST_STEP] = h
        counters[LAST_ITERATIONS] = iterations
        scalars[LAST_ENERGY_INCREMENT] = increment
        counters[ACCEPTED] += 1
        if save:
            row = row_scalars[taken]
            row[R_T] = t_end
            row[R_H] = h
            row[R_ITERATIONS] = iterations
            row[R_INCREMENT] = increment
            row[R_ENERGY] = potential + kinetic_new
            row[R_WORK] = scalars[WORK]
            row_states[taken, 0] = current[U]
            row_states[taken, 1] = current[V]
            row_states[taken, 2] = current[A]
        taken += 1
        limit_value = settings[ENERGY_LIMIT]
        if math.isfinite(limit_value) and math.isfinite(increment) and \
                scalars[ENERGY_ERROR] > limit_value * max(scalars[ENERGY_SCALE], 1e-300):
            return ENERGY_CHECK, taken
    return REACHED, taken


# -- the Python side -------------------------------------------------------------------

#: Accepted steps of one call of :func:`drive`: the rows kept by integrate()
#: are handed over (and progress reported) every this many steps, and Python
#: gets control back as often, so that a long run stays interruptible
#: (Ctrl-C is seen between calls; compiled code does not check for it).
STEPS_PER_CALL = 2048


class CompiledDriver:
    """:func:`drive` for one :class:`hfdi.Integrator`: its fixed inputs, set up once.

    Parameters
    ----------
    integrator : Integrator
        With a compiled attempt (``integrator._compiled``), a compiled load and a
        built-in controller (see :func:`hfdi.compiled.driver_reason`).
    """

    #: why :meth:`run` returned (the integrator reads them here: importing
    #: them at every call of its loop cost as much as a row of the state)
    REACHED, FULL, HAND_OVER, ENERGY_CHECK = REACHED, FULL, HAND_OVER, ENERGY_CHECK

    def __init__(self, integrator):
        from ..controller import Combined, ErrorControl, FixedStep, IterationCount
        step = integrator._compiled
        kernels = step.kernels
        self.step = step
        # load data that are the model's data follow them (EnergyModel.set_parameters)
        self._load_reads_params = kernels.load_params is kernels.params
        self.load_params = np.ascontiguousarray(kernels.load_params, dtype=np.float64)
        n = integrator.ev.n
        c = integrator.controller
        settings = np.zeros(12)
        switches = np.zeros(8, np.int64)
        settings[VELOCITY_GAIN] = step.scheme.velocity_gain
        iteration = c.iteration if isinstance(c, Combined) else c
        error = c.error if isinstance(c, Combined) else c
        self.rtol = np.zeros(2 * n)
        self.atol = np.zeros(2 * n)
        if isinstance(c, FixedStep):
            switches[CONTROLLER] = FIXED
            settings[FIXED_STEP] = c.step
        elif isinstance(c, IterationCount):
            switches[CONTROLLER] = ITERATION
        elif isinstance(c, ErrorControl):
            switches[CONTROLLER] = ERROR
        else:
            switches[CONTROLLER] = COMBINED
        if isinstance(iteration, IterationCount):
            settings[IT_TARGET] = iteration.target
            settings[IT_MIN_STEP], settings[IT_MAX_STEP] = iteration.min_step, iteration.max_step
            switches[IT_MAX_REJECTIONS] = iteration.max_rejections
        if isinstance(error, ErrorControl):
            settings[ER_MIN_STEP], settings[ER_MAX_STEP] = error.min_step, error.max_step
            settings[SAFETY], settings[GROW], settings[SHRINK] = (error.safety, error.grow,
                                                                  error.shrink)
            switches[ER_MAX_REJECTIONS] = error.max_rejections
            switches[ORDER] = error.order
            self.rtol[:] = error.rtol
            self.atol[:] = error.atol
        settings[ENERGY_LIMIT] = math.inf if integrator.energy_limit is None else \
            integrator.energy_limit
        switches[MAX_STEPS] = integrator.max_steps
        switches[EXACT_RATE] = step.exact_rate
        self.settings, self.switches = settings, switches
        self.breakpoints = np.ascontiguousarray(integrator.breakpoints, dtype=np.float64)
        self.config = step.config.copy()
        self.config[A_MAX_ITERATIONS] = integrator.max_iterations
        self.config[A_NEWTON_TEST] = integrator.newton_test == "error"
        self.coefficients = step.coefficients.copy()
        self.coefficients[A_TOL], self.coefficients[A_FLOOR] = integrator.tol, integrator.floor
        self.n = n
        # u, v, a, f, p of the current and previous state as drive() left them,
        # and the integrator's state object and States they stand for: while
        # those are still the integrator's, the arrays need not be filled again
        self._current = np.zeros((5, n))
        self._previous = np.zeros((5, n))
        self._in_arrays = (None, None, None)
        self._no_rows = (np.empty((0, 6)), np.empty((0, 3, n)))

    def held_load(self, integrator):
        """The :class:`~hfdi.HeldLoad`'s value as :func:`drive` adds it (empty
        without one), or ``None`` when it is not an (N,) vector: the Python
        driver then takes the steps and reports the fault (as it does for a
        value that is not finite, which :func:`drive` hands over)."""
        extra = integrator.ev.extra_load
        if extra is None:
            return np.zeros(0)
        try:
            value = np.ascontiguousarray(extra.source(), dtype=np.float64)
        except Exception:
            return None
        if value.shape != (self.n,):
            return None
        return value

    def run(self, integrator, t_stop: float, save_rows: bool, held):
        """Steps of ``integrator`` towards ``t_stop`` (``<= t_bound``) with the held
        load ``held`` (:meth:`held_load`), its state updated:
        ``(reason, taken, rows, rejections)`` with ``rows`` a dict of arrays
        (``None`` unless ``save_rows``) and ``rejections`` those of the step
        handed over."""
        n = self.n
        scalars, counters = self.load(integrator)
        self.settings[T_STOP] = t_stop
        self.switches[SAVE_ROWS] = save_rows
        self.switches[MAX_STEPS] = integrator.max_steps
        self.switches[CALL_STEPS] = STEPS_PER_CALL
        if save_rows:
            row_scalars, row_states = np.empty((STEPS_PER_CALL, 6)), \
                np.empty((STEPS_PER_CALL, 3, n))
        else:
            row_scalars, row_states = self._no_rows
        step = self.step
        params = step.params()
        self._in_arrays = (None, None, None)     # until drive() has returned
        reason, taken = drive(
            step.kernel_set, params, params if self._load_reads_params else self.load_params,
            held, self.config, self.coefficients, step.Md, step.Mf,
            step.Cd, step.Cf, self.settings, self.switches, self.rtol, self.atol,
            self.breakpoints, scalars, counters, self._current, self._previous, row_scalars,
            row_states)
        rejections = self.store(integrator, scalars, counters, taken)
        rows = None
        if save_rows:
            # views of this call's own buffers (made above, for this call
            # only), which the caller keeps and joins once at the end of a
            # run; copies when the call took less than half of them, so that
            # what a run keeps is at most twice its rows (a call ends at
            # every breakpoint)
            if 2 * taken < STEPS_PER_CALL:
                row_scalars, row_states = row_scalars[:taken].copy(), row_states[:taken].copy()
            rows = {"t": row_scalars[:taken, R_T], "u": row_states[:taken, 0],
                    "v": row_states[:taken, 1], "a": row_states[:taken, 2],
                    "step_size": row_scalars[:taken, R_H],
                    "iterations": row_scalars[:taken, R_ITERATIONS].astype(int),
                    "energy_increment": row_scalars[:taken, R_INCREMENT],
                    "total_energy": row_scalars[:taken, R_ENERGY],
                    "external_work": row_scalars[:taken, R_WORK]}
        return int(reason), taken, rows, rejections

    def load(self, integrator):
        """The arrays :func:`drive` works on, filled from ``integrator``'s state:
        ``current`` and ``previous`` (kept, filled only when they no longer
        stand for the integrator's states), the Newton memory in
        ``coefficients``, and new ``(scalars, counters)``."""
        s = integrator._s
        ev = integrator.ev
        st = s.statistics
        cur, prev = s.current, s.previous
        current, previous = self._current, self._previous
        saved, before, last = self._in_arrays
        if not (s is saved and cur is before and prev is last):
            current[U], current[V], current[A], current[P] = cur.u, cur.v, cur.a, cur.p
            current[F] = cur.f if cur.f is not None else 0.0
            previous[:] = 0.0
            if prev is not None:
                previous[U], previous[V], previous[A] = prev.u, prev.v, prev.a
                previous[F] = prev.f if prev.f is not None else 0.0
                previous[P] = prev.p
        scalars = np.array([cur.t, prev.t if prev is not None else cur.t, s.proposed_step,
                            s.potential, s.initial_potential, s.work, s.energy_error,
                            s.energy_scale, s.last_step, s.last_energy_increment,
                            s.grid_origin])
        counters = np.array([prev is not None, cur.f is not None,
                             prev is not None and prev.f is not None, s.grid_steps, st.steps,
                             st.accepted, st.rejected, st.newton_iterations,
                             st.error_test_failures, ev.nfev, ev.njev, ev.ntev, ev.nlu, ev.npev,
                             s.last_iterations, 0, 0], dtype=np.int64)
        self.coefficients[A_NEWTON_CONSTANT] = s.newton_constant
        self.coefficients[A_NEWTON_GUARD] = s.newton_guard
        return scalars, counters

    def store(self, integrator, scalars, counters, taken):
        """``integrator``'s state and statistics from the arrays :func:`drive`
        left after ``taken`` accepted steps since :meth:`load`; the rejections
        of the step handed over."""
        s = integrator._s
        ev = integrator.ev
        st = s.statistics
        cur = s.current
        current, previous = self._current, self._previous
        # as Python numbers: one tolist() costs what two float(array[i]) cost
        sc, co = scalars.tolist(), counters.tolist()
        ev.nfev, ev.njev, ev.ntev, ev.nlu, ev.npev = co[C_NFEV:C_NPEV + 1]
        st.steps, st.accepted, st.rejected = co[STEPS], co[ACCEPTED], co[REJECTED]
        st.newton_iterations = co[NEWTON_ITERATIONS]
        st.error_test_failures = co[ERROR_TEST_FAILURES]
        s.proposed_step = sc[PROPOSED]
        s.newton_constant = float(self.coefficients[A_NEWTON_CONSTANT])
        s.newton_guard = float(self.coefficients[A_NEWTON_GUARD])
        if taken:
            # States own their arrays (one block each, never written again):
            # drive() writes into current and previous at the next call
            if not co[HAS_PREV]:
                s.previous = None       # short steps after a breakpoint (no history)
            elif taken == 1 and sc[T_PREV] == cur.t:
                s.previous = cur        # one step: the previous state is the one it started from
            else:
                s.previous = _state(sc[T_PREV], previous.copy(), co[PREVIOUS_HAS_F])
            s.current = _state(sc[T_CURRENT], current.copy(), co[CURRENT_HAS_F])
            s.potential, s.work = sc[POTENTIAL], sc[WORK]
            s.energy_error = sc[ENERGY_ERROR]
            s.energy_scale = sc[ENERGY_SCALE]
            s.last_step = sc[LAST_STEP]
            s.last_energy_increment = sc[LAST_ENERGY_INCREMENT]
            s.last_iterations = co[LAST_ITERATIONS]
            s.grid_origin, s.grid_steps = sc[GRID_ORIGIN], co[GRID_STEPS]
            st.t_reached = s.current.t
        self._in_arrays = (s, s.current, s.previous)
        return co[REJECTIONS]


def _state(t, block, has_f):
    """A :class:`~hfdi.evaluation.State` on the rows of ``block`` (5, N), its own copy."""
    return State(t, block[U], block[V], block[A], block[F] if has_f else None, block[P])
