"""The records of a run, by name: what the core reads and writes.

- ``CONFIG`` (numbers, read only): the scheme's shape, the model's matrix
  kinds, the corrector's and the controller's settings, the guards.
- ``DATA`` (arrays, read only during a run): ``M``, ``C``, the kernels' data,
  the tolerances, the load breakpoints, the scheme's parameters.
- ``RUN`` (numbers, read and written): time, history flags, the proposed step,
  status, Newton's memory, the energy balance, the statistics, and what the
  last attempt and a stop left for the message.
- ``VECTORS`` (arrays, read and written): the current, previous and new
  states, the work arrays of an attempt, and the rows of accepted steps.
- ``FUNCTIONS``: the model's kernels and the scheme's stage function, of the
  signatures of :mod:`hfdi.core.numba_types` (``FORCE``, ..., ``STAGE_FUNCTION``).

A scheme describes each of its stages by a :class:`Stage` (its coefficients),
returned by its stage function ``stage(h, index, params) -> Stage``.
"""
from __future__ import annotations

import math
from typing import NamedTuple

from .records import Arrays, Scalars

__all__ = ["CONFIG", "RUN", "DATA", "VECTORS", "FUNCTIONS", "Stage", "AFFINE", "HFDI", "FIXED",
           "ITERATION", "ERROR", "COMBINED", "CUSTOM", "MAX_STAGES"]

# -- controllers ------------------------------------------------------------------------
#: Kinds of step-size controller (``CONFIG.controller``); ``CUSTOM`` is a Python
#: object, whose rules the core never calls.
FIXED, ITERATION, ERROR, COMBINED, CUSTOM = range(5)

# -- stages -------------------------------------------------------------------------------
#: Kinds of stage: affine in the unknown ``u`` (the Newmark family, Bathe's
#: sub-steps, generalized-α), or HFDI's (Eq. 21 in ``u`` alone).
AFFINE, HFDI = 0.0, 1.0
#: The most stages a scheme may have (Bathe's two).
MAX_STAGES = 2


class Stage(NamedTuple):
    """One stage of a step of size ``h``, as its scheme's stage function gives it.

    An affine stage has one unknown ``u`` at ``t_n + time·h`` with
    ``a(u) = ca u + a0`` and ``v(u) = cv u + v0``, where ``a0`` and ``v0``
    combine the step's start ``(u_n, v_n, a_n)`` and the first stage's end
    ``(u_1, v_1, a_1)`` with the coefficients ``a_*`` and ``v_*``; its
    equation is

        m_new M a(u) + m_old M a_n + f_new (C v(u) + f(u)) + f_old (C v_n + f_n)
            = p(t_n + load_time·h),

    (1, 0, 1, 0 for Newmark and Bathe; generalized-α weighs both ends). An
    HFDI stage (``kind = HFDI``) uses only ``time`` and ``load_time`` (1).
    All entries are floats (one tuple type for every scheme).

    A rigid shift of the displacements moves neither ``v`` nor ``a``: the
    coefficients of ``u_n``, ``u_1`` and ``u`` in each add up to zero
    (``a_u + a_u1 + ca = 0``, ``v_u + v_u1 + cv = 0``). The stepping code
    relies on it and never forms the ``u_n`` terms: it iterates on the
    increment ``u − u_n``, so that the rounding of ``v`` and ``a`` is that of
    the increment, not of ``u`` (docs/algorithm.md, "Increments").
    """

    kind: float
    time: float
    load_time: float
    ca: float
    cv: float
    m_new: float
    m_old: float
    f_new: float
    f_old: float
    a_u: float
    a_v: float
    a_a: float
    a_u1: float
    a_v1: float
    a_a1: float
    v_u: float
    v_v: float
    v_a: float
    v_u1: float
    v_v1: float
    v_a1: float


FUNCTIONS = Arrays("Functions", [
    ("force", "function FORCE"),
    ("stiffness", "function STIFFNESS"),
    ("stiffness_derivative", "function STIFFNESS_DERIVATIVE"),
    ("potential_energy", "function POTENTIAL_ENERGY"),
    ("load", "function LOAD"),
    ("load_rate", "function LOAD"),
    ("stage", "function STAGE_FUNCTION"),
])


def __getattr__(name):
    # the kernels' numba signatures (FORCE, ...) live with numba's types, which
    # are imported only when compiled code is made
    if name in ("FORCE", "STIFFNESS", "STIFFNESS_DERIVATIVE", "POTENTIAL_ENERGY", "LOAD",
                "STAGE_FUNCTION", "STAGE"):
        from . import numba_types
        return getattr(numba_types, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# -- numbers ---------------------------------------------------------------------------
_INF, _NAN = math.inf, math.nan

CONFIG = Scalars("Config", [
    ("n", "i8", 0),                     # degrees of freedom
    ("stages", "i8", 1),                # stages of the scheme
    ("order", "i8", 2),                 # its order (the error rule's exponent)
    ("velocity_gain", "f8", 3.0),       # h Σ|coefficients of u in v| (docs/algorithm.md)
    ("velocity_defect", "f8", 0.0),     # 1/(24 λ), λ the scheme's v error constant (or 0)
    ("velocity_order", "i8", 2),        # the order of v's local error (the estimate's)
    ("keeps_force", "b1", False),       # the state keeps f(u) (HFDI, generalized-α)
    ("lagged_acceleration", "b1", False),   # the state's a is not M⁻¹(p − C v − f) (gen.-α)
    ("acceleration_lag", "f8", 0.0),    # it is the acceleration at t + lag·h
    ("m_kind", "i8", 1),                # kinds of M and C (hfdi.core.arrays)
    ("c_kind", "i8", 0),
    ("sparse", "b1", False),            # sparse tangents (Python only)
    ("exact_rate", "b1", False),        # HFDI takes the model's load rate
    ("derived_rate", "b1", False),      # else HFDI differentiates the load in the step
    ("has_held", "b1", False),          # DATA.held is added to the load
    ("tol", "f8", 1e-8),                # Newton: Eq. 38's η, its floor, N_max
    ("floor", "f8", 1.0),
    ("max_iterations", "i8", 10),
    ("estimated", "b1", False),         # Newton stops on its estimated error too
    ("controller", "i8", ERROR),
    ("fixed_step", "f8", 0.0),
    ("target", "f8", 0.0),              # N̄ of the whole step (iteration count)
    ("it_min_step", "f8", 0.0),
    ("it_max_step", "f8", _INF),
    ("it_max_rejections", "i8", 30),
    ("er_min_step", "f8", 0.0),
    ("er_max_step", "f8", _INF),
    ("er_max_rejections", "i8", 30),
    ("safety", "f8", 0.9),
    ("grow", "f8", 5.0),
    ("shrink", "f8", 0.2),
    ("per_step", "b1", False),          # the error rule bounds the error per step (IDA's)
    ("error_span", "f8", _NAN),         # else a share over this span (NaN: elapsed)
    ("first_step_trials", "i8", 40),
    ("global_error", "b1", True),       # carry the global error estimate (VECTORS.global_error)
    ("min_step", "f8", 0.0),
    ("max_step", "f8", _INF),
    ("energy_limit", "f8", _INF),       # inf: no limit
    ("max_steps", "i8", 1_000_000),
    ("t_bound", "f8", _INF),            # inf: none
    ("mass_floor", "f8", 0.0),          # a lower bound of λ_min(M) (0: none known)
    ("damping_rate", "f8", 0.0),        # ‖C‖_∞ / mass_floor
])

RUN = Scalars("Run", [
    ("t", "f8", 0.0),
    ("t_previous", "f8", 0.0),
    ("has_previous", "b1", False),      # the predictor's history (u, v, a at t_previous)
    ("has_force", "b1", False),         # VECTORS.f is f(u) at t
    ("proposed", "f8", 0.0),            # the size proposed for the next step
    ("first_step_pending", "b1", True),
    ("status", "i8", 1),                # hfdi.Status: 1 running, 0 success, < 0 failed
    ("newton_constant", "f8", _INF),    # the corrector's carried constant and its guard
    ("newton_guard", "f8", _INF),
    ("potential", "f8", 0.0),           # the energy balance (Eqs. 40-41)
    ("initial_potential", "f8", 0.0),
    ("work", "f8", 0.0),
    ("energy_error", "f8", 0.0),
    ("energy_scale", "f8", 0.0),
    ("last_step", "f8", _NAN),
    ("last_iterations", "i8", 0),
    ("last_energy_increment", "f8", 0.0),
    ("grid_origin", "f8", 0.0),         # the fixed step's grid origin + k h
    ("grid_steps", "i8", 0),
    ("steps", "i8", 0),                 # statistics (hfdi.Statistics)
    ("accepted", "i8", 0),
    ("rejected", "i8", 0),
    ("newton_iterations", "i8", 0),
    ("error_test_failures", "i8", 0),
    ("first_step_trials", "i8", 0),
    ("first_step_trial_iterations", "i8", 0),
    ("nfev", "i8", 0),
    ("njev", "i8", 0),
    ("ntev", "i8", 0),
    ("npev", "i8", 0),
    ("nlu", "i8", 0),
    ("t_start", "f8", 0.0),
    ("t_reached", "f8", 0.0),
    ("rejections", "i8", 0),            # rejected attempts of the step being taken
    ("rows", "i8", 0),                  # rows written into VECTORS.row_* by this call
    ("restarted", "b1", False),         # the last step ended on a breakpoint where a jumped
    ("a_h", "f8", 0.0),                 # the last attempt: its size, end, proposal
    ("a_t_end", "f8", 0.0),
    ("a_proposed", "f8", 0.0),
    ("a_clipped", "b1", False),
    ("a_taylor", "b1", False),          # it was a short step by Taylor's expansion
    ("a_outcome", "i8", 0),             # hfdi.core.codes: OK or why it failed
    ("a_stage", "i8", 0),               # the stage that failed
    ("a_iterations", "i8", 0),          # its Newton corrections, all stages
    ("a_newton_error", "f8", 0.0),      # the corrector's estimated remaining error
    ("a_err", "f8", _NAN),              # the error norm (error control)
    ("a_estimated", "b1", False),       # VECTORS.error is the last attempt's estimate
    ("bad_rows", "i8", 0),              # a kernel's value of a wrong shape
    ("bad_columns", "i8", 0),
    ("stop", "i8", 0),                  # hfdi.core.codes: which guard stopped the run
    ("stop_next", "f8", 0.0),           # the size proposed when it stopped
    ("stop_t", "f8", 0.0),              # a time the message names
    ("stop_kinetic", "f8", 0.0),        # the energies of an overflowing step
    ("stop_work", "f8", 0.0),
    ("stop_potential", "f8", 0.0),
    ("trials_smallest", "f8", _INF),    # the first step's smallest trial
    ("trials", "i8", 0),                # the first step's trials in this search
    ("trial_failure", "i8", 0),         # the outcome of its last failed trial
    ("trial_guard", "i8", 0),           # the guard of its last rejection (error rule)
    ("search_low", "f8", _NAN),         # the first step's bracket (NaN: none yet)
    ("search_high", "f8", _NAN),
    ("search_best", "f8", _INF),        # the best trial's |N − N̄| so far
    ("saved_h", "f8", 0.0),             # an attempt kept aside (the first step's best)
    ("saved_t_end", "f8", 0.0),
    ("saved_proposed", "f8", 0.0),
    ("saved_clipped", "b1", False),
    ("saved_iterations", "i8", 0),
    ("saved_newton_error", "f8", 0.0),
    ("saved_err", "f8", _NAN),
    ("tangent_kind", "i8", 0),          # VECTORS.lu: the last HFDI tangent's factors (0: none)
    ("tangent_h", "f8", _NAN),          # of the attempt of this size
])

# -- arrays ---------------------------------------------------------------------------

DATA = Arrays("Data", [
    ("Md", "vector"), ("Mf", "matrix"),         # M: diagonal or full (CONFIG.m_kind)
    ("Cd", "vector"), ("Cf", "matrix"),         # C likewise (CONFIG.c_kind)
    ("params", "vector"),                       # the model kernels' data
    ("load_params", "vector"),                  # the load's
    ("held", "vector"),                         # a held extra load (CONFIG.has_held)
    ("rtol", "vector"), ("atol", "vector"),     # over (u, v), 2N each
    ("first_atol", "vector"),                   # atol of the run's first step
    ("breakpoints", "vector"),                  # sorted
    ("scheme_params", "vector"),                # the scheme's stage function's data
])

_STATE = ("u", "v", "a", "f", "p")
VECTORS = Arrays("Vectors", [
    *[(name, "vector") for name in _STATE],                       # at t
    *[(f"{name}_previous", "vector") for name in _STATE],         # at t_previous
    *[(f"{name}_new", "vector") for name in _STATE],              # the attempt's end
    ("u_mid", "vector"), ("v_mid", "vector"), ("a_mid", "vector"),  # the first stage's end
    ("p_mid", "vector"),
    *[(f"{name}_saved", "vector") for name in (*_STATE, "u_mid", "v_mid", "a_mid", "p_mid",
                                               "a_start")],
    ("p_stage", "vector"),          # the load at the stage's load time
    ("a_start", "vector"),          # the state's a as the step's stages take it
    ("a_equation", "vector"),       # M⁻¹(p − C v − f) at t and t_previous, for the
    ("a_equation_previous", "vector"),  # estimate where CONFIG.lagged_acceleration
    ("p_rate", "vector"),           # HFDI's p' at the step's end
    ("trial", "vector"),            # the Newton iterate: the increment u − u_n
    ("u_iterate", "vector"),        # u_n + the increment, where the model is evaluated
    *[(name, "vector") for name in ("rhs", "residual", "du", "g", "vd", "kv", "tmp", "work",
                                    "q0", "f0", "a0", "v0", "b_diagonal", "shift")],
    ("error", "vector"), ("ratio", "vector"),                     # 2N: the error estimate
    ("global_error", "vector"), ("g_z", "vector"),                # 2N: the global estimate
    ("g_stages", "matrix"),         # (3, 2N): its propagator's stage derivatives
    *[(name, "matrix") for name in ("J", "lu", "S", "SB", "product", "B", "B_lu",
                                    "columns")],
    ("G", "matrix"), ("G_lu", "matrix"),                          # the propagator's matrix
    ("K_last", "matrix"), ("T_last", "matrix"),   # K, T[v_D] of the last HFDI iterate
    ("mass_lu", "matrix"), ("mass_pivots", "int32 vector"),      # M's factors (dense M)
    ("pivots", "int32 vector"), ("b_pivots", "int32 vector"), ("g_pivots", "int32 vector"),
    ("ints", "int32 vector"), ("b_ints", "int32 vector"),
    ("stage_iterations", "int64 vector"),                         # MAX_STAGES
    ("row_t", "vector"), ("row_h", "vector"), ("row_iterations", "int64 vector"),
    ("row_increment", "vector"), ("row_energy", "vector"), ("row_work", "vector"),
    ("row_u", "matrix"), ("row_v", "matrix"), ("row_a", "matrix"),
    ("row_global", "matrix"),       # (rows, 2N)
    ("sparse", "vector"),           # Python only: the sparse solvers' cache (empty here)
])
