"""Tolerance proportionality: does the achieved error follow ``rtol``? (``python -m benchmarks.proportionality``)

Error control per unit step (docs/algorithm.md, "Tolerance proportionality")
is meant to make the global error of a run about ``rtol`` times the size of
the solution, whatever ``rtol``: the error over ``rtol`` should stay O(1) and
the log–log slope of error against ``rtol`` should be 1. This module measures
it on problems with references independent of hfdi, against the per-step rule
and three other solvers at the same tolerances.

Problems (every model an :class:`hfdi.models.symbolic.EnergyModel`, so that
its steps run compiled; the definitions are those of ``tests/exact_problems.py``
and ``tests/problems.py``, restated here so as not to import the tests):

* ``duffing`` — ``u'' + u + 2u³ = 0``, ``u(0) = 1.2``, to ``t = 10``; exact
  (Jacobi's ``cn``);
* ``kepler`` — the two-body problem, eccentricity 0.5, one orbit ``2π``;
  exact (Kepler's equation by Newton's method);
* ``damped_chain`` — three masses, four springs, Rayleigh damping, to
  ``t = 5``; exact (eigen-decomposition of the first-order matrix);
* ``damped_chain_1e-4`` — the same with ``u`` and ``v`` scaled by 1e-4 (the
  model otherwise unchanged, ``u_scale = 1`` included); exact;
* ``pleiades`` — seven bodies (Hairer, Nørsett & Wanner I, II.10), to
  ``t = 3``; reference DOP853 at rtol = atol = 1e-13 on the first-order form;
* ``forced_duffing`` (not in the repository) — ``u'' + 0.3u' + u + u³ =
  0.5 cos 1.2t``, ``u(0) = 1``, ``u'(0) = 0``, to ``t = 20``; the load given
  as a sympy expression of time (compiled, exact rate for HFDI); reference
  DOP853 at rtol 1e-13, atol 1e-14.

The DOP853 references are checked against DOP853 at rtol 1e-11 (the
difference is reported as ``reference_check``: an upper estimate of the
looser run's error, so the reference's own is far below it).

Solvers, each at every ``rtol`` with the same ``atol``:

* ``newmark``, ``bathe``, ``hfdi``, ``generalized_alpha`` —
  ``hfdi.integrate(model, scheme, t_end, rtol=rtol, atol=atol)`` (the default
  rule: per unit step; per step for generalized-α);
* ``newmark/per-step``, ``bathe/per-step``, ``hfdi/per-step`` — the same with
  ``controller=hfdi.controller.ErrorControl(rtol, atol, per_step=True)``;
* ``Radau`` (analytic Jacobian) and ``DOP853`` — scipy's ``solve_ivp`` on the
  first-order form ``y = (u, v)``, ``y' = (v, M⁻¹(p(t) − C v − f(u)))``,
  ``dense_output=True``;
* ``IDA`` — SUNDIALS IDA through :func:`validation.reference.ida_solve`
  (the first-order implicit form with its analytic iteration matrix).

Absolute tolerance: ``atol = 1e-3·rtol·U`` for every component of ``u`` and
``1e-3·rtol·V`` for every component of ``v``, ``U = max |u_ref|`` and
``V = max |v_ref|`` over the run and the components (``hfdi`` takes it as a
``(2N,)`` array, ``u``'s then ``v``'s).

Measures, for every run: the end-point error and the run-maximum error (over
the solver's own step times) of ``u``, ``max_i |u_i − u_ref,i| / U``, and the
same for ``v`` with ``V`` (JSON only), each also over ``rtol``; the steps
(accepted steps for hfdi, ``len(t) − 1`` for the others); the CPU time of the
solve (:func:`time.process_time`), the best of two runs for hfdi and for a
competitor run under two seconds. hfdi's compiled loop and every model's
kernels are compiled by an untimed warm-up run per problem and scheme (a
tenth of the span, rtol 1e-3); the other solvers also get one warm-up run
per problem.

Limits: hfdi's ``max_steps`` (default 1,000,000) and a budget of
``MAX_NFEV`` right-hand-side (residual) evaluations for scipy and IDA; a run
that fails or reaches its limit is recorded with its message, and the tighter
``rtol`` values of that solver on that problem are skipped.

Outputs: ``proportionality.json`` in ``--out`` (default
``docs/performance-data``) and, on stdout, a Markdown table per problem ×
solver (``end/rtol (steps)`` per ``rtol``), a summary per solver (worst
``end/rtol`` and ``max/rtol`` over all problems and ``rtol`` values, and the
least-squares slope of ``log error`` against ``log rtol`` per problem, end and
max), and the checks that failed (an hfdi scheme under the default rule above
10× ``rtol``, or a slope outside [0.9, 1.1]).
"""
from __future__ import annotations

import json
import math
import platform
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

import numpy as np
import sympy
from scipy.integrate import solve_ivp
from scipy.special import ellipj

import hfdi
from hfdi.controller import ErrorControl
from hfdi.files import write_output
from hfdi.models.symbolic import EnergyModel
from validation import options as opt

__all__ = ["PROBLEMS", "SOLVERS", "DEFAULT_RTOLS", "Problem", "first_order_form",
           "run_problem", "run_all", "slope", "format_tables", "main"]

DEFAULT_RTOLS = tuple(10.0 ** -k for k in range(3, 9))
SCHEMES = ("newmark", "bathe", "hfdi", "generalized_alpha")
PER_STEP_SCHEMES = ("newmark", "bathe", "hfdi")
SOLVERS = SCHEMES + tuple(f"{s}/per-step" for s in PER_STEP_SCHEMES) + ("Radau", "DOP853",
                                                                       "IDA")
#: Work budget of scipy's and IDA's runs, right-hand-side (residual) evaluations.
MAX_NFEV = 2_000_000
#: hfdi's step limit (Integrator's default).
MAX_STEPS = 1_000_000
#: A run shorter than this (CPU seconds) is repeated once, the shorter kept;
#: hfdi's runs are always timed twice.
REPEAT_BELOW = 2.0
ATOL_FACTOR = 1e-3
#: Checks: an hfdi scheme (default rule) whose error exceeds this factor times
#: rtol, or whose slope is outside this range, is flagged.
FLAG_FACTOR = 10.0
SLOPE_RANGE = (0.9, 1.1)
ATOL_RULE = ("atol = 1e-3*rtol*U for each u-component, 1e-3*rtol*V for each v-component; "
             "U = max|u_ref|, V = max|v_ref| over the run and the components")
ERROR_RULE = ("error = max_i |y_i - y_ref,i| / (max over the run and components of |y_ref|), "
              "y = u (or v); end: at t_end; max: over the solver's step times")


# -- problems ----------------------------------------------------------------------------

@dataclass
class Problem:
    """A model, its span and a reference ``ref(t) -> (u (n, N), v (n, N))``."""
    name: str
    model: object
    t_end: float
    reference: Callable
    reference_kind: str
    description: str
    #: times the reference has its own nodes at (DOP853's steps), for the scales
    nodes: np.ndarray = field(default_factory=lambda: np.zeros(0))
    reference_check: dict = field(default_factory=dict)


def _diag(a, n):
    a = np.asarray(a, dtype=float)
    return np.diag(a) if a.ndim == 1 else a.reshape(n, n)


def first_order_form(model):
    """``(rhs, jac, y0)`` of ``y = (u, v)``, ``y' = (v, M⁻¹(p(t) − C v − f(u)))``,
    from the model's public attributes; ``jac`` is the analytic
    ``[[0, I], [−M⁻¹K(u), −M⁻¹C]]``."""
    n = int(model.n_dof)
    mass = np.asarray(model.mass.toarray() if hasattr(model.mass, "toarray") else model.mass,
                      dtype=float)
    damping = model.damping
    if damping is not None:
        damping = np.asarray(damping.toarray() if hasattr(damping, "toarray") else damping,
                             dtype=float)
        damping = _diag(damping, n)
    if mass.ndim == 1:
        inv = 1.0 / mass

        def solve(b):
            return (inv * b.T).T
    else:
        Minv = np.linalg.inv(mass)

        def solve(b):
            return Minv @ b
    minus_Minv_C = None if damping is None else -solve(damping)

    def rhs(t, y):
        u, v = y[:n], y[n:]
        force = np.asarray(model.load(t), dtype=float) - np.asarray(model.internal_force(u))
        if damping is not None:
            force = force - damping @ v
        return np.concatenate([v, solve(force)])

    def jac(t, y):
        K = model.stiffness(y[:n])
        K = np.asarray(K.toarray() if hasattr(K, "toarray") else K, dtype=float)
        J = np.zeros((2 * n, 2 * n))
        J[:n, n:] = np.eye(n)
        J[n:, :n] = -solve(K)
        if minus_Minv_C is not None:
            J[n:, n:] = minus_Minv_C
        return J

    u0 = np.zeros(n) if model.initial_displacement is None else model.initial_displacement
    v0 = np.zeros(n) if model.initial_velocity is None else model.initial_velocity
    y0 = np.concatenate([np.asarray(u0, dtype=float), np.asarray(v0, dtype=float)])
    return rhs, jac, y0


def _dop853(model, t_end, rtol, atol):
    rhs, _, y0 = first_order_form(model)
    sol = solve_ivp(rhs, (0.0, t_end), y0, method="DOP853", rtol=rtol, atol=atol,
                    dense_output=True)
    if not sol.success:
        raise RuntimeError(f"the DOP853 reference of {model.name} failed: {sol.message}")
    return sol


def _dop853_reference(model, t_end, rtol, atol, check_rtol=1e-11):
    """DOP853's dense solution as ``ref(t)``, its step times, and its
    difference to a run at ``check_rtol`` (an upper estimate of the error of
    the looser run, far above the reference's own)."""
    n = int(model.n_dof)
    sol = _dop853(model, t_end, rtol, atol)
    loose = _dop853(model, t_end, check_rtol, atol * check_rtol / rtol)

    def reference(t):
        y = sol.sol(np.atleast_1d(np.asarray(t, dtype=float)))
        return y[:n].T, y[n:].T

    grid = np.union1d(np.linspace(0.0, t_end, 2001), loose.t)
    yr, yl = sol.sol(grid), loose.sol(grid)
    U = np.abs(yr[:n]).max()
    V = np.abs(yr[n:]).max()
    check = {"rtol": rtol, "atol": atol, "steps": int(sol.t.size - 1), "nfev": int(sol.nfev),
             "check_rtol": check_rtol,
             "check_difference_u": float(np.abs(yr[:n] - yl[:n]).max() / U),
             "check_difference_v": float(np.abs(yr[n:] - yl[n:]).max() / V)}
    return reference, np.asarray(sol.t), check


def duffing(alpha=1.0, beta=2.0, amplitude=1.2, t_end=10.0):
    """``u'' + α u + β u³ = 0``, ``u(0) = A``: ``u = A cn(ω t, m)``,
    ``ω² = α + β A²``, ``m = β A² / (2 ω²)`` (tests/exact_problems.py)."""
    x = sympy.Symbol("x")
    model = EnergyModel([x], alpha * x ** 2 / 2 + beta * x ** 4 / 4, [1.0],
                        initial_displacement=[amplitude], name="duffing")
    omega = np.sqrt(alpha + beta * amplitude ** 2)
    mpar = beta * amplitude ** 2 / (2.0 * omega ** 2)

    def exact(t):
        sn, cn, dn, _ = ellipj(omega * np.atleast_1d(np.asarray(t, dtype=float)), mpar)
        return (amplitude * cn)[:, None], (-amplitude * omega * sn * dn)[:, None]

    return Problem("duffing", model, t_end, exact, "exact (Jacobi cn)",
                   f"u'' + {alpha:g}u + {beta:g}u^3 = 0, u(0) = {amplitude:g}, t in [0, {t_end:g}]")


def kepler(eccentricity=0.5, t_end=2.0 * np.pi):
    """The two-body problem from the pericentre of an ellipse of semi-major
    axis 1 (period 2π) (tests/exact_problems.py)."""
    e = eccentricity
    x, y = sympy.symbols("x y")
    model = EnergyModel([x, y], -1 / sympy.sqrt(x ** 2 + y ** 2), [1.0, 1.0],
                        initial_displacement=[1.0 - e, 0.0],
                        initial_velocity=[0.0, np.sqrt((1.0 + e) / (1.0 - e))], name="kepler")

    def exact(t):
        M = np.atleast_1d(np.asarray(t, dtype=float))
        E = M.copy()
        for _ in range(50):                       # Newton on E − e sin E = M
            E -= (E - e * np.sin(E) - M) / (1.0 - e * np.cos(E))
        c, s = np.cos(E), np.sin(E)
        b = np.sqrt(1.0 - e * e)
        Edot = 1.0 / (1.0 - e * c)
        return (np.stack([c - e, b * s], axis=1),
                np.stack([-s * Edot, b * c * Edot], axis=1))

    return Problem("kepler", model, t_end, exact, "exact (Kepler's equation)",
                   f"two bodies, e = {e:g}, one orbit t in [0, 2pi]")


def damped_chain(scale=1.0, t_end=5.0, name="damped_chain"):
    """Three masses, four springs, Rayleigh damping (tests/exact_problems.py);
    the initial state times ``scale`` (a linear model: the solution too)."""
    m = np.array([1.0, 2.0, 1.5])
    k = np.array([40.0, 25.0, 30.0, 50.0])
    K = np.array([[k[0] + k[1], -k[1], 0.0],
                  [-k[1], k[1] + k[2], -k[2]],
                  [0.0, -k[2], k[2] + k[3]]])
    C = 0.02 * K + 0.05 * np.diag(m)
    u0 = scale * np.array([0.1, -0.05, 0.02])
    v0 = scale * np.array([0.0, 0.3, -0.1])
    q = sympy.symbols("q1:4")
    energy = sum(sympy.Rational(1, 2) * sympy.nsimplify(K[i, j]) * q[i] * q[j]
                 for i in range(3) for j in range(3))
    model = EnergyModel(list(q), energy, m, damping=C, initial_displacement=u0,
                        initial_velocity=v0, name=name)
    A = np.block([[np.zeros((3, 3)), np.eye(3)],
                  [-K / m[:, None], -C / m[:, None]]])
    eigenvalues, Vec = np.linalg.eig(A)
    coefficients = np.linalg.solve(Vec, np.concatenate([u0, v0]))

    def exact(t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        y = (np.exp(np.outer(t, eigenvalues)) * coefficients) @ Vec.T
        return y.real[:, :3], y.real[:, 3:]

    return Problem(name, model, t_end, exact, "exact (eigen-decomposition)",
                   f"3-mass damped chain, initial state x {scale:g}, t in [0, {t_end:g}]")


def damped_chain_scaled():
    return damped_chain(scale=1e-4, name="damped_chain_1e-4")


def pleiades(t_end=3.0):
    """Seven bodies of masses 1 … 7 in the plane (Hairer, Nørsett & Wanner I,
    II.10; tests/problems.py); reference DOP853 at rtol = atol = 1e-13."""
    X = sympy.symbols("x1:8")
    Y = sympy.symbols("y1:8")
    dofs = [s for pair in zip(X, Y) for s in pair]
    energy = sympy.Integer(0)
    for i in range(7):
        for j in range(i + 1, 7):
            energy -= (i + 1) * (j + 1) / sympy.sqrt((X[j] - X[i]) ** 2 + (Y[j] - Y[i]) ** 2)
    x0 = np.column_stack([[3, 3, -1, -3, 2, -2, 2], [3, -3, 2, 0, 0, -4, 4]]).ravel()
    v0 = np.column_stack([[0, 0, 0, 0, 0, 1.75, -1.5], [0, 0, 0, -1.25, 1, 0, 0]]).ravel()
    model = EnergyModel(dofs, energy, np.repeat(np.arange(1.0, 8.0), 2),
                        initial_displacement=x0.astype(float),
                        initial_velocity=v0.astype(float), name="pleiades")
    ref, nodes, check = _dop853_reference(model, t_end, 1e-13, 1e-13)
    return Problem("pleiades", model, t_end, ref, "DOP853 rtol 1e-13 atol 1e-13",
                   f"Pleiades, seven bodies, t in [0, {t_end:g}]", nodes, check)


def forced_duffing(c=0.3, alpha=1.0, beta=1.0, force=0.5, omega=1.2, t_end=20.0):
    """``u'' + c u' + α u + β u³ = F cos ω t``, ``u(0) = 1``, ``u'(0) = 0``: a
    damped, forced hardening oscillator (not chaotic at these values: the
    transient decays onto the forced response); reference DOP853 at rtol
    1e-13, atol 1e-14."""
    x, t = sympy.symbols("x t")
    model = EnergyModel([x], alpha * x ** 2 / 2 + beta * x ** 4 / 4, [1.0], damping=[c],
                        load=[force * sympy.cos(omega * t)], time=t,
                        initial_displacement=[1.0], initial_velocity=[0.0],
                        name="forced_duffing")
    ref, nodes, check = _dop853_reference(model, t_end, 1e-13, 1e-14)
    return Problem("forced_duffing", model, t_end, ref, "DOP853 rtol 1e-13 atol 1e-14",
                   f"u'' + {c:g}u' + {alpha:g}u + {beta:g}u^3 = {force:g} cos {omega:g}t, "
                   f"u(0) = 1, u'(0) = 0, t in [0, {t_end:g}]", nodes, check)


PROBLEMS = {
    "duffing": duffing,
    "kepler": kepler,
    "damped_chain": damped_chain,
    "damped_chain_1e-4": damped_chain_scaled,
    "pleiades": pleiades,
    "forced_duffing": forced_duffing,
}


def scales(problem):
    """``(U, V)``: max |u_ref| and max |v_ref| over the run and the components,
    on a fine grid and the reference's own nodes."""
    t = np.union1d(np.linspace(0.0, problem.t_end, 20001), problem.nodes)
    u, v = problem.reference(t)
    return float(np.abs(u).max()), float(np.abs(v).max())


# -- the runs ----------------------------------------------------------------------------

class _Budget(Exception):
    """A scipy or IDA run reached its work budget."""


def _timed(run, repeats):
    """Best CPU time of ``repeats`` calls of ``run()``; returns (output, cpu, all cpus)."""
    times, out = [], None
    for k in range(repeats):
        start = time.process_time()
        out = run()
        times.append(time.process_time() - start)
        if k == 0 and repeats > 1 and not out.get("success", False):
            break
    return out, min(times), times


def _run_hfdi(model, scheme, t_end, rtol, atol, per_step, max_steps):
    if per_step:
        result = hfdi.integrate(model, scheme, t_end, max_steps=max_steps,
                                controller=ErrorControl(rtol, atol, per_step=True))
    else:
        result = hfdi.integrate(model, scheme, t_end, rtol=rtol, atol=atol,
                                max_steps=max_steps)
    st = result.stats
    return {"success": bool(result.success), "message": str(result.message),
            "t": np.asarray(result.t), "u": np.asarray(result.u), "v": np.asarray(result.v),
            "steps": int(st.steps), "accepted_steps": int(getattr(st, "accepted", st.steps)),
            "rejected_steps": int(getattr(st, "rejected", 0)),
            "newton_iterations": int(getattr(st, "newton_iterations", 0)),
            "nfev": int(getattr(st, "nfev", 0)), "g": np.asarray(result.global_error)}


def _run_scipy(model, method, t_end, rtol, atol, max_nfev):
    rhs, jac, y0 = first_order_form(model)
    n = int(model.n_dof)
    count = [0]

    def counted(t, y):
        count[0] += 1
        if count[0] > max_nfev:
            raise _Budget(f"stopped at t = {t:.6g} after {max_nfev} evaluations (work budget)")
        return rhs(t, y)

    kwargs = {"jac": jac} if method == "Radau" else {}
    try:
        sol = solve_ivp(counted, (0.0, t_end), y0, method=method, rtol=rtol, atol=atol,
                        dense_output=True, **kwargs)
    except _Budget as exc:
        return {"success": False, "message": str(exc), "budget": True, "steps": None,
                "nfev": count[0]}
    success = bool(sol.success) and sol.t[-1] == t_end
    return {"success": success, "message": str(sol.message), "t": sol.t, "u": sol.y[:n].T,
            "v": sol.y[n:].T, "steps": int(sol.t.size - 1), "nfev": int(sol.nfev),
            "njev": int(sol.njev), "nlu": int(sol.nlu)}


def _run_ida(model, t_end, rtol, atol, max_nfev):
    from validation.reference import ida_solve
    count = [0]

    def budget(t):
        count[0] += 1
        if count[0] > max_nfev:
            raise _Budget(f"stopped at t = {t:.6g} after {max_nfev} residual evaluations "
                          f"(work budget)")

    try:
        sol = ida_solve(model, t_end, rtol=rtol, atol=atol, on_residual=budget)
    except _Budget as exc:
        return {"success": False, "message": str(exc), "budget": True, "steps": None,
                "nfev": count[0]}
    t = sol["t"]
    success = bool(sol["success"]) and t.size >= 2 and t[-1] == t_end
    return {"success": success, "message": sol["message"], "t": t, "u": sol["u"],
            "v": sol["v"], "steps": int(max(t.size - 1, 0)), "nfev": int(sol["nfev"]),
            "njev": int(sol["njev"]), "linsolver": sol["linsolver"]}


def _solve(problem, solver, rtol, atol, max_steps, max_nfev):
    model, t_end = problem.model, problem.t_end
    if solver in SCHEMES:
        return _run_hfdi(model, solver, t_end, rtol, atol, False, max_steps)
    if solver.endswith("/per-step"):
        return _run_hfdi(model, solver.split("/")[0], t_end, rtol, atol, True, max_steps)
    if solver in ("Radau", "DOP853"):
        return _run_scipy(model, solver, t_end, rtol, atol, max_nfev)
    if solver == "IDA":
        return _run_ida(model, t_end, rtol, atol, max_nfev)
    raise ValueError(f"unknown solver {solver!r}")


def _errors(problem, out, U, V):
    t, u, v = out["t"], out["u"], out["v"]
    u_ref, v_ref = problem.reference(t)
    eu = np.abs(u - u_ref).max(axis=1) / U
    ev = np.abs(v - v_ref).max(axis=1) / V
    errors = {"err_u_end": float(eu[-1]), "err_u_max": float(eu.max()),
              "err_v_end": float(ev[-1]), "err_v_max": float(ev.max())}
    if "g" in out:
        # hfdi's own global error estimate against the true error of u, at the
        # end and at its worst over the run
        n = u.shape[1]
        gu = np.abs(out["g"][:, :n]).max(axis=1) / U
        errors.update(estimate_over_true_end=float(gu[-1] / eu[-1]),
                      estimate_over_true_max=float(gu.max() / eu.max()))
    return errors


def run_one(problem, solver, rtol, atol, U, V, max_steps=MAX_STEPS, max_nfev=MAX_NFEV):
    """One solver at one ``rtol``: a record (dict) without the arrays."""
    record = {"problem": problem.name, "solver": solver, "rtol": rtol}
    hfdi_run = solver in SCHEMES or solver.endswith("/per-step")
    try:
        if hfdi_run:
            out, cpu, cpus = _timed(lambda: _solve(problem, solver, rtol, atol, max_steps,
                                                   max_nfev), 2)
        else:
            out, cpu, cpus = _timed(lambda: _solve(problem, solver, rtol, atol, max_steps,
                                                   max_nfev), 1)
            if out["success"] and cpu < REPEAT_BELOW:
                again, cpu2, _ = _timed(lambda: _solve(problem, solver, rtol, atol, max_steps,
                                                       max_nfev), 1)
                cpus.append(cpu2)
                cpu = min(cpu, cpu2)
    except Exception as exc:           # a failing solver is a result, not the end
        record.update(success=False, message=f"{type(exc).__name__}: {exc}", cpu=None)
        return record
    record.update(success=out["success"], message=out["message"], cpu=cpu, cpu_runs=cpus,
                  **{k: out[k] for k in ("steps", "accepted_steps", "rejected_steps",
                                         "newton_iterations", "nfev", "njev", "nlu",
                                         "linsolver", "budget") if k in out})
    if out["success"]:
        record.update(_errors(problem, out, U, V))
        for key in ("err_u_end", "err_u_max", "err_v_end", "err_v_max"):
            record[key + "_over_rtol"] = record[key] / rtol
    return record


def _warm_up(problem, atol_of, solvers, say):
    """Untimed runs over a tenth of the span: compile hfdi's loop per scheme
    and the model's kernels; import and first-call costs of the others."""
    rtol = 1e-3
    atol = atol_of(rtol)
    short = Problem(problem.name, problem.model, problem.t_end / 10, problem.reference,
                    problem.reference_kind, problem.description)
    start = time.perf_counter()
    compiled = {}
    for solver in solvers:
        try:
            _solve(short, solver, rtol, atol, MAX_STEPS, MAX_NFEV)
        except Exception as exc:
            say(f"  warm-up of {solver} failed: {type(exc).__name__}: {exc}")
        if solver in SCHEMES:
            try:
                integrator = hfdi.Integrator(problem.model, solver, rtol=rtol, atol=atol,
                                             t_bound=problem.t_end)
                compiled[solver] = bool(integrator.compiled) or \
                    str(integrator.not_compiled_reason)
            except Exception as exc:
                compiled[solver] = f"{type(exc).__name__}: {exc}"
    say(f"  warm-up {time.perf_counter() - start:.1f} s; compiled: {compiled}")
    return compiled


def run_problem(name, rtols=DEFAULT_RTOLS, solvers=SOLVERS, say=print, max_steps=MAX_STEPS,
                max_nfev=MAX_NFEV):
    """Every solver at every ``rtol`` on problem ``name``: a dict with the
    problem's description and the run records."""
    start = time.perf_counter()
    problem = PROBLEMS[name]()
    U, V = scales(problem)
    n = int(problem.model.n_dof)

    def atol_of(rtol):
        return np.concatenate([np.full(n, ATOL_FACTOR * rtol * U),
                               np.full(n, ATOL_FACTOR * rtol * V)])

    say(f"{name}: N = {n}, t_end = {problem.t_end:.6g}, U = {U:.4g}, V = {V:.4g}, "
        f"reference {problem.reference_kind} (built in {time.perf_counter() - start:.1f} s)"
        + (f"; check {problem.reference_check}" if problem.reference_check else ""))
    compiled = _warm_up(problem, atol_of, solvers, say)
    runs, stopped = [], {}
    for rtol in sorted(rtols, reverse=True):
        atol = atol_of(rtol)
        for solver in solvers:
            if solver in stopped:
                runs.append({"problem": name, "solver": solver, "rtol": rtol, "success": False,
                             "skipped": True,
                             "message": f"skipped: failed at rtol {stopped[solver]:g}"})
                continue
            record = run_one(problem, solver, rtol, atol, U, V, max_steps, max_nfev)
            runs.append(record)
            if record["success"]:
                say(f"  {solver:20s} rtol {rtol:.0e}: end/rtol {record['err_u_end_over_rtol']:9.3g}"
                    f"  max/rtol {record['err_u_max_over_rtol']:9.3g}  steps {record['steps']:>8}"
                    f"  cpu {record['cpu']:.3g} s")
            else:
                stopped[solver] = rtol
                say(f"  {solver:20s} rtol {rtol:.0e}: FAILED {record['message'][:160]}")
    return {"name": name, "description": problem.description, "n_dof": n,
            "t_end": problem.t_end, "reference": problem.reference_kind,
            "reference_check": problem.reference_check, "U": U, "V": V,
            "u_scale": float(getattr(problem.model, "u_scale", 1.0)),
            "compiled": compiled, "runs": runs,
            "wall_time_s": time.perf_counter() - start}


# -- analysis ----------------------------------------------------------------------------

def slope(rtols, errors):
    """Least-squares slope of ``log10 error`` against ``log10 rtol`` over the
    pairs with a positive finite error; ``None`` below three of them."""
    pairs = [(r, e) for r, e in zip(rtols, errors)
             if e is not None and np.isfinite(e) and e > 0]
    if len(pairs) < 3:
        return None
    x, y = np.log10([p[0] for p in pairs]), np.log10([p[1] for p in pairs])
    return float(np.polyfit(x, y, 1)[0])


def analyse(problems, solvers):
    """Per solver: worst end/rtol and max/rtol (and where), slopes per problem."""
    summary = {}
    for solver in solvers:
        entry = {"worst_end_over_rtol": None, "worst_end_at": None,
                 "worst_max_over_rtol": None, "worst_max_at": None, "failures": 0,
                 "slopes": {}}
        for p in problems:
            runs = [r for r in p["runs"] if r["solver"] == solver]
            ok = [r for r in runs if r.get("success")]
            entry["failures"] += len(runs) - len(ok)
            for r in ok:
                for kind in ("end", "max"):
                    value = r[f"err_u_{kind}_over_rtol"]
                    if entry[f"worst_{kind}_over_rtol"] is None or \
                            value > entry[f"worst_{kind}_over_rtol"]:
                        entry[f"worst_{kind}_over_rtol"] = value
                        entry[f"worst_{kind}_at"] = [p["name"], r["rtol"]]
            entry["slopes"][p["name"]] = {
                kind: slope([r["rtol"] for r in ok], [r[f"err_u_{kind}"] for r in ok])
                for kind in ("end", "max")}
            entry["slopes"][p["name"]]["v_max"] = slope([r["rtol"] for r in ok],
                                                        [r["err_v_max"] for r in ok])
        summary[solver] = entry
    return summary


def checks(problems, summary):
    """Lines naming what looks wrong for hfdi's schemes under the default rule."""
    lines = []
    for p in problems:
        for solver in SCHEMES:
            runs = [r for r in p["runs"] if r["solver"] == solver]
            found = []
            for r in runs:
                if not r.get("success"):
                    found.append(f"rtol {r['rtol']:.0e}: FAILED ({r['message'][:120]})")
                    continue
                for kind in ("end", "max"):
                    value = r[f"err_u_{kind}_over_rtol"]
                    if value > FLAG_FACTOR:
                        found.append(f"rtol {r['rtol']:.0e}: {kind}/rtol = {value:.3g} > "
                                     f"{FLAG_FACTOR:g}")
            slopes = summary[solver]["slopes"].get(p["name"], {})
            for kind in ("end", "max"):
                value = slopes.get(kind)
                if value is not None and not SLOPE_RANGE[0] <= value <= SLOPE_RANGE[1]:
                    found.append(f"slope of the {kind} error = {value:.3f} outside "
                                 f"[{SLOPE_RANGE[0]:g}, {SLOPE_RANGE[1]:g}]")
            lines += [f"{p['name']}, {solver}, {item}" for item in found]
    return lines


def _cell(r):
    if r is None:
        return ""
    if r.get("skipped"):
        return "skipped"
    if not r.get("success"):
        return "FAILED (budget)" if r.get("budget") else "FAILED"
    return f"{r['err_u_end_over_rtol']:.2g} ({r['steps']})"


def _fmt(x, spec=".3g"):
    return "–" if x is None else format(x, spec)


def format_tables(data):
    problems, solvers, rtols = data["problems"], data["solvers"], data["rtols"]
    lines = ["### End-point error of u over rtol (steps)", "",
             "| problem | solver | " + " | ".join(f"{r:.0e}" for r in rtols) + " |",
             "|---|---|" + "---|" * len(rtols)]
    for p in problems:
        for solver in solvers:
            by_rtol = {r["rtol"]: r for r in p["runs"] if r["solver"] == solver}
            if not by_rtol:
                continue
            lines.append(f"| {p['name']} | {solver} | "
                         + " | ".join(_cell(by_rtol.get(r)) for r in rtols) + " |")
    names = [p["name"] for p in problems]
    lines += ["", "### Summary per solver (u; worst over every problem and rtol; "
                  "slope of log error against log rtol, end / max)", "",
              "| solver | worst end/rtol | at | worst max/rtol | at | failed | "
              + " | ".join(f"slope {n}" for n in names) + " |",
              "|---|---|---|---|---|---|" + "---|" * len(names)]
    for solver in solvers:
        s = data["summary"][solver]
        at = (lambda w: "" if w is None else f"{w[0]} {w[1]:.0e}")
        lines.append(
            f"| {solver} | {_fmt(s['worst_end_over_rtol'])} | {at(s['worst_end_at'])} | "
            f"{_fmt(s['worst_max_over_rtol'])} | {at(s['worst_max_at'])} | {s['failures']} | "
            + " | ".join(f"{_fmt(s['slopes'][n]['end'], '.2f')} / "
                         f"{_fmt(s['slopes'][n]['max'], '.2f')}" for n in names) + " |")
    lines += ["", "### hfdi's global error estimate of u over the true error (end / worst "
                  "over the run)", "",
              "| problem | solver | " + " | ".join(f"{r:.0e}" for r in rtols) + " |",
              "|---|---|" + "---|" * len(rtols)]
    for p in problems:
        for solver in solvers:
            by_rtol = {r["rtol"]: r for r in p["runs"] if r["solver"] == solver}
            if not any("estimate_over_true_end" in r for r in by_rtol.values()):
                continue
            cells = []
            for rtol in rtols:
                r = by_rtol.get(rtol) or {}
                cells.append(f"{r['estimate_over_true_end']:.2f} / "
                             f"{r['estimate_over_true_max']:.2f}"
                             if "estimate_over_true_end" in r else "")
            lines.append(f"| {p['name']} | {solver} | " + " | ".join(cells) + " |")
    lines += ["", "### Checks (hfdi's schemes, default rule: error above "
                  f"{FLAG_FACTOR:g}×rtol, slope outside [{SLOPE_RANGE[0]:g}, "
                  f"{SLOPE_RANGE[1]:g}])", ""]
    lines += [f"- {line}" for line in data["checks"]] or ["- none"]
    return "\n".join(lines)


def _clean(obj):
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    return obj


def _write(path, data):
    write_output(path, json.dumps(_clean(data), indent=1, ensure_ascii=False) + "\n")


def run_all(problem_names, rtols, solvers, out, say=print, argv=(), max_steps=MAX_STEPS):
    start = time.perf_counter()
    data = {"command": "python -m benchmarks proportionality " + " ".join(argv),
            "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "machine": {"python": sys.version.split()[0], "platform": platform.platform(),
                        "processor": platform.processor() or platform.machine(),
                        "numpy": np.__version__,
                        "scipy": __import__("scipy").__version__},
            "rtols": list(rtols), "solvers": list(solvers), "atol_rule": ATOL_RULE,
            "error_rule": ERROR_RULE, "cpu_rule": "time.process_time of the solve; best of 2 "
            f"for hfdi, and for other runs under {REPEAT_BELOW:g} s",
            "max_steps": max_steps, "max_nfev": MAX_NFEV, "problems": []}
    path = Path(out) / "proportionality.json"
    for name in problem_names:
        data["problems"].append(run_problem(name, rtols, solvers, say, max_steps=max_steps))
        data["summary"] = analyse(data["problems"], solvers)
        data["checks"] = checks(data["problems"], data["summary"])
        data["wall_time_s"] = time.perf_counter() - start
        _write(path, data)             # after every problem: a partial run keeps its results
    return data, path


def main(argv=None) -> int:
    """``python -m benchmarks.proportionality [--out DIR] [--rtols R,...]
    [--problems P,...] [--solvers S,...]``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = opt.Parser(prog="python -m benchmarks proportionality",
                        description="Achieved error against rtol: hfdi's schemes (per unit "
                                    "step and per step), scipy's Radau and DOP853, IDA.")
    parser.add_argument("--out", default="docs/performance-data", metavar="DIR",
                        help="output directory of proportionality.json "
                             "(default docs/performance-data)")
    parser.add_argument("--rtols", type=opt.rtols, default=list(DEFAULT_RTOLS),
                        help="comma-separated rtols (default 1e-3,...,1e-8)")
    parser.add_argument("--problems", default=list(PROBLEMS),
                        type=lambda text: opt.names_from(text, tuple(PROBLEMS), "problem(s)"),
                        help=f"comma-separated, of {', '.join(PROBLEMS)} (default all)")
    parser.add_argument("--solvers", default=list(SOLVERS),
                        type=lambda text: opt.names_from(text, SOLVERS, "solver(s)",
                                                         lower=False),
                        help=f"comma-separated, of {', '.join(SOLVERS)} (default all)")
    parser.add_argument("--max-steps", type=opt.positive_integer, default=MAX_STEPS,
                        help=f"hfdi's step limit per run (default {MAX_STEPS:,})")
    args = parser.parse_args(argv)
    try:
        out = opt.out_dir(args.out)
    except opt.UsageError as exc:
        parser.error(str(exc))
    say = (lambda text: print(text, file=sys.stderr, flush=True))
    data, path = run_all(args.problems, args.rtols, args.solvers, out, say, argv,
                         max_steps=args.max_steps)
    print(format_tables(data))
    print(f"\n{path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
