"""Work–precision of our schemes against IDA and scipy's Radau and BDF (``python -m benchmarks precision``).

For each problem, every method integrates the model from its initial state to
``t_end`` (default ``T_o``), one run after another in one process, the
methods taken in turn (every method's loosest setting, then every method's
next one, ...) so that a drift of the machine's load is shared by all:

* ours — Newmark, Bathe, HFDI and generalized-α (every scheme of
  :data:`hfdi.SCHEMES`; :func:`hfdi.integrate`), one run per target
  iteration count ``N̄`` (per sub-step for Bathe), Newton tolerance 1e-8 and
  the energy guard of the paper's tables; and each error-controlled, one run
  per ``rtol`` of ``ours_rtols``;
* IDA (SUNDIALS, through scikit-sundae) on the first-order implicit form of
  :mod:`validation.reference` with its analytic iteration matrix, one run per
  ``rtol``; the linear solver is :mod:`validation.reference`'s ``"auto"``
  (dense up to 100 first-order unknowns, band or sparse beyond), so dense on
  the four paper problems (at most 42 unknowns);
* IDA at machine speed (``ida_c``): the same first-order form, rtol and
  atol, run by SUNDIALS' C library with a compiled residual and Jacobian over
  the model's own compiled kernels (:mod:`benchmarks.ida_compiled`; Debian's
  ``libsundials-dev``), the whole run in one compiled loop: the fair
  competitor of our compiled path (``--compiled``). Skipped, with the reason
  in its records, where the library or the model's kernels are missing;
* scipy's ``solve_ivp`` ``Radau`` and ``BDF`` on the explicit first-order form
  ``y = (u, v)``, ``y' = (v, M⁻¹(p − f(u) − C v))`` with the analytic Jacobian
  ``[[0, I], [−M⁻¹K(u), −M⁻¹C]]``, a CSR matrix when the model's ``K`` is
  sparse (the toss rule), dense otherwise; one run per ``rtol``.

Competitors' absolute tolerances, and those of our error-controlled runs
(methods ``<scheme>-rtol``: ``hfdi.integrate(..., rtol=rtol, atol=...)``,
whose error norm weighs ``(u, v)`` as IDA does), follow
:func:`validation.reference.default_atol` at the run's ``rtol``:
``atol_u,i = rtol · max(|u0_i|, u_scale)``, ``atol_v,i = rtol · max(|v0_i|, V)``
with ``V = max(‖v0‖∞, u_scale / t_end)`` — the rule of the reference itself.

Accuracy: the paper's error norm ``ε`` (Eq. 42,
:func:`validation.errors.error_norm`) of ``u`` (and of every quantity of
interest of the model) against a tight dense IDA reference
(:func:`validation.reference.cached_reference`, ``rtol`` 1e-12), evaluated for
every method alike at the method's own step times: every accepted step of
ours, every internal step of IDA (one-step output over ``[t0, t_end]``),
every step of ``solve_ivp`` (no ``t_eval``).

Cost: wall time (:func:`time.perf_counter`) around the solve only, and beside
it the process's CPU time (:func:`time.process_time`, same span), which other
processes' load disturbs less; the speed-ups are given for both. Model
construction, the first-order form's set-up (sparsity pattern, closures) and
the ε evaluation are outside the timer for every method; the solver's own
construction, the consistent initial state and the solve are inside. A fresh
model is built for every run so that no run profits from a cache another run
filled. Each method first makes one untimed warm-up run over a tenth of the
interval (imports, first-call costs). Runs shorter than ``repeat_below``
seconds are repeated ``repeats`` times in all and the shortest time is kept
(the results of the repeats are checked to be identical). Steps, Newton
iterations (ours), and residual/Jacobian evaluations and LU factorisations
(as each solver counts them) are reported beside.

Work budget: a competitor run is stopped after ``max_nfev`` evaluations of
its right-hand side or residual and recorded as failed; once a competitor run
needs more than ``skip_nfev`` evaluations, its tighter ``rtol`` values are
skipped (recorded as skipped). Both limits count evaluations, not seconds,
so that the set of runs is the same whatever the machine, load or ``--jobs``.
A run reported successful whose ``ε_u`` is more than 10 times that of every
looser setting of its method is marked INACCURATE and left out of the curves
(scipy's BDF at rtol 1e-10 steps over the tetrahedra's load pulse: the model
starts at rest without load, ``y'(0) = 0``, and its initial step is 21 s).

Speed-up at equal ε: each method's Pareto front of ``(ε_u, wall)``; ours is
the front of the union of our schemes' runs. For each point of our front,
every competitor's ``log wall`` is interpolated linearly in ``log ε`` on its
front (no extrapolation: "out of range"), the fastest competitor at that ε is
the best, and the speed-up is its wall divided by ours, both measured in the
same process. The goal figure compares IDA at ``rtol`` 1e-6 with the fastest
HFDI run (over the targets) whose ``ε_u`` is at most IDA's: measured wall
against measured wall, and beside it HFDI's front interpolated at IDA's ε.
"""
from __future__ import annotations

import argparse
import io
import json
import math
import os
import platform
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import scipy.sparse as sp

import hfdi

from hfdi.evaluation import normalise_matrix
from validation import options as opt
from hfdi.files import write_output
from validation.errors import error_norm
from validation.experiments import (ENERGY_LIMIT, SCHEME_COLOURS, SCHEME_ORDER, SchemeStyle,
                                   experiment, names)
from validation.reference import cached_reference, default_atol, ida_solve
from validation.runs import integrate, scheme_title

__all__ = ["bench_problem", "bench_task", "pareto_front", "interpolate_wall", "speedups",
           "goal", "format_problem", "plot_problem", "machine_info", "write_outputs",
           "add_parser", "run_command", "SCHEMES", "COMPETITORS", "DEFAULT_TARGETS", "DEFAULT_RTOLS"]

#: Our schemes: every scheme of :data:`hfdi.SCHEMES` (the paper's three and generalized-α).
SCHEMES = SCHEME_ORDER
#: Our schemes under error control (``hfdi.integrate(..., rtol=...)``), one run per rtol.
ERROR_CONTROLLED = tuple(f"{s}-rtol" for s in SCHEMES)
OURS = SCHEMES + ERROR_CONTROLLED
COMPETITORS = ("ida", "ida_c", "radau", "bdf")
#: Relative tolerances of our error-controlled runs, loosest first.
DEFAULT_OURS_RTOLS = tuple(10.0 ** -k for k in range(3, 10))

#: Targets ``N̄`` of every scheme (per sub-step for Bathe), loosest first. They
#: span the accuracy the iteration-count rule reaches: 5 gives a few steps per
#: period of the slow motion, 1.5 resolves part of the fast vibrations.
TARGETS = (5.0, 4.0, 3.5, 3.0, 2.5, 2.0, 1.5)
#: :data:`TARGETS` per scheme (the same for each).
DEFAULT_TARGETS = {s: TARGETS for s in SCHEMES}
#: Relative tolerances of the competitors, loosest first.
DEFAULT_RTOLS = tuple(10.0 ** -k for k in range(3, 11))
REFERENCE_RTOL = 1e-12
#: A competitor run is stopped after this many right-hand side (residual)
#: evaluations: about 30 s of scipy's Radau at 0.15 ms an evaluation.
MAX_NFEV = 200_000
#: A competitor run that needs more evaluations than this skips the tighter
#: rtols of its method: the next one would mostly take longer still, and the
#: curve has reached well below the accuracy of our schemes by then. (Not
#: always: scipy's BDF needs 50 000 evaluations on the toss rule at rtol 1e-3
#: and not many more at 1e-8, hence a limit well above that.)
SKIP_NFEV = 100_000
#: A run whose ε_u exceeds this factor times the largest ε_u of the looser
#: settings of its method is a false success (say scipy's BDF stepping over the
#: tetrahedra's load pulse in 3 steps at rtol 1e-10, from rest and no load at
#: t = 0): marked INACCURATE and left out of the curves and speed-ups.
INACCURATE_FACTOR = 10.0
REPEATS = 3
#: Runs shorter than this (seconds) are repeated: a short run's time is the
#: most exposed to the noise of the machine.
REPEAT_BELOW = 1.0
#: The goal's comparison point: IDA at this rtol.
GOAL_RTOL = 1e-6
GOAL_FACTOR = 10.0
#: The goals ``(competitor, its rtol, factor)``: HFDI at the competitor's ε_u
#: at least ``factor`` times faster — scikit-sundae's IDA (a Python residual)
#: at rtol 1e-6 by 10×; IDA in C at rtol 1e-6 by 3×, and at 1e-8 no slower.
GOALS = (("ida", GOAL_RTOL, GOAL_FACTOR), ("ida_c", 1e-6, 3.0), ("ida_c", 1e-8, 1.0))
#: The energy guard of the paper's tables (``validation.tables.ENERGY_LIMIT``).

ATOL_RULE = ("validation.reference.default_atol(model, rtol, t_end): atol_u,i = rtol * "
             "max(|u0_i|, u_scale), atol_v,i = rtol * max(|v0_i|, V), "
             "V = max(max|v0|, u_scale / t_end)")


class _Budget(Exception):
    """A competitor run reached its work budget (``max_nfev``)."""


# -- the runs -------------------------------------------------------------------------

def _run_ours(model, scheme, t_end, target=None, rtol=None, compiled=False):
    # error control with the competitors' absolute tolerances, (u, v) alike
    atol = None if rtol is None else default_atol(model, rtol, t_end)
    cpu = time.process_time()
    start = time.perf_counter()
    result = integrate(model, scheme, t_end, target, rtol, atol, compiled=compiled)
    wall = time.perf_counter() - start
    cpu = time.process_time() - cpu
    st = result.stats
    return {
        "wall": wall, "cpu": cpu, "t": result.t, "u": result.u, "v": result.v,
        "success": bool(result.success), "status": result.status.name,
        "message": result.message,
        "steps": int(st.steps), "accepted_steps": int(st.accepted),
        "newton_iterations": int(st.newton_iterations),
        "first_step_trial_iterations": int(st.first_step_trial_iterations),
        "nfev": int(st.nfev), "njev": int(st.njev), "nlu": int(st.nlu),
    }


def _run_ida(model, t_end, rtol, max_nfev):
    count = [0]

    def budget(t):
        # the budget stops a run that would take minutes; IDA passes the
        # exception through
        count[0] += 1
        if count[0] > max_nfev:
            raise _Budget(f"stopped at t = {t:.6g} after {max_nfev} residual evaluations "
                          f"(work budget)")

    cpu = time.process_time()
    start = time.perf_counter()
    try:
        sol = ida_solve(model, t_end, rtol=rtol, on_residual=budget)
    except _Budget as exc:
        return _failed(time.perf_counter() - start, time.process_time() - cpu, "BUDGET",
                       str(exc), count[0])
    wall = time.perf_counter() - start
    cpu = time.process_time() - cpu
    t = sol["t"]
    success = sol["success"] and t.size >= 2 and t[-1] == t_end
    return {
        "wall": wall, "cpu": cpu, "t": t, "u": sol["u"], "v": sol["v"],
        "success": success, "status": "SUCCESS" if success else f"IDA_{sol['status']}",
        "message": sol["message"], "steps": int(max(t.size - 1, 0)),
        "nfev": sol["nfev"], "njev": sol["njev"], "linsolver": sol["linsolver"],
        "atol": sol["atol"].tolist(),
    }


def _run_ida_c(model, t_end, rtol, max_nfev):
    from . import ida_compiled
    problem = ida_compiled.Problem(model)        # compiled once per process, untimed
    atol = default_atol(model, rtol, t_end)
    cpu = time.process_time()
    start = time.perf_counter()
    sol = ida_compiled.solve(problem, t_end, rtol=rtol, atol=atol, max_nfev=max_nfev)
    wall = time.perf_counter() - start
    cpu = time.process_time() - cpu
    if sol["status"] == "BUDGET":
        sol["u"] = sol["v"] = None           # stopped by us: no ε, as for the others
    return {**sol, "wall": wall, "cpu": cpu, "atol": sol["atol"].tolist()}


def _failed(wall, cpu, status, message, nfev):
    return {"wall": wall, "cpu": cpu, "t": np.zeros(0), "u": None, "v": None, "success": False,
            "status": status, "message": message, "steps": None, "nfev": int(nfev)}


class _ExplicitForm:
    """``y = (u, v)``, ``y' = (v, M⁻¹(p − f(u) − C v))`` and its Jacobian, for solve_ivp."""

    def __init__(self, model):
        n = int(model.n_dof)
        self.model, self.n = model, n
        M = normalise_matrix(model.mass, n, "model mass")
        C = normalise_matrix(model.damping, n, "model damping")
        if isinstance(M, np.ndarray) and M.ndim == 1:
            minv = 1.0 / M
            self._minv = lambda x: minv * x if x.ndim == 1 else \
                (sp.diags(minv) @ x if sp.issparse(x) else minv[:, None] * x)
        else:
            # a full mass matrix: M⁻¹ by one dense factorisation (sparse M is
            # rare in small models; its inverse is dense anyway)
            import scipy.linalg as sla
            lu = sla.lu_factor(M.toarray() if sp.issparse(M) else M)
            self._minv = lambda x: sla.lu_solve(
                lu, x.toarray() if sp.issparse(x) else x)
        self.C = C
        self.minv_c = None if C is None else self._minv(C.toarray() if sp.issparse(C) else
                                                        (np.diag(C) if C.ndim == 1 else C))
        u0 = model.initial_displacement
        v0 = model.initial_velocity
        u0 = np.zeros(n) if u0 is None else np.asarray(u0, dtype=float)
        v0 = np.zeros(n) if v0 is None else np.asarray(v0, dtype=float)
        self.y0 = np.concatenate([u0, v0])
        self.sparse = sp.issparse(model.stiffness(u0))
        self._eye = sp.identity(n, format="csr") if self.sparse else np.eye(n)
        self._minv_c_sparse = None if self.minv_c is None else sp.csr_matrix(self.minv_c)
        self.count = 0
        self.max_nfev = math.inf

    def fun(self, t, y):
        self.count += 1
        if self.count > self.max_nfev:
            raise _Budget(f"stopped at t = {t:.6g} after {self.max_nfev} right-hand side "
                          f"evaluations (work budget)")
        n, model = self.n, self.model
        u, v = y[:n], y[n:]
        rhs = model.load(t) - model.internal_force(u)
        if self.C is not None:
            rhs = rhs - (self.C * v if self.C.ndim == 1 else self.C @ v)
        return np.concatenate([v, self._minv(rhs)])

    def jac(self, t, y):
        n = self.n
        K = self.model.stiffness(y[:n])
        if self.sparse:
            lower = -sp.csr_matrix(self._minv(sp.csr_matrix(K)))
            right = None if self._minv_c_sparse is None else -self._minv_c_sparse
            return sp.bmat([[None, self._eye], [lower, right]], format="csr")
        J = np.zeros((2 * n, 2 * n))
        J[:n, n:] = self._eye
        J[n:, :n] = -self._minv(K.toarray() if sp.issparse(K) else K)
        if self.minv_c is not None:
            J[n:, n:] = -self.minv_c
        return J


def _run_scipy(model, method, t_end, rtol, max_nfev):
    from scipy.integrate import solve_ivp
    form = _ExplicitForm(model)
    form.max_nfev = max_nfev
    atol = default_atol(model, rtol, t_end)
    cpu = time.process_time()
    start = time.perf_counter()
    try:
        sol = solve_ivp(form.fun, (0.0, t_end), form.y0, method=method, rtol=rtol, atol=atol,
                        jac=form.jac)
    except _Budget as exc:
        return _failed(time.perf_counter() - start, time.process_time() - cpu, "BUDGET",
                       str(exc), form.count)
    wall = time.perf_counter() - start
    cpu = time.process_time() - cpu
    n = form.n
    t = np.asarray(sol.t, dtype=float)
    success = bool(sol.success) and t.size >= 2 and t[-1] == t_end
    return {
        "wall": wall, "cpu": cpu, "t": t, "u": sol.y[:n].T, "v": sol.y[n:].T, "success": success,
        "status": "SUCCESS" if success else f"SCIPY_{int(sol.status)}",
        "message": str(sol.message), "steps": int(max(t.size - 1, 0)),
        "nfev": int(sol.nfev), "njev": int(sol.njev), "nlu": int(sol.nlu),
        "jacobian": "sparse CSR" if form.sparse else "dense", "atol": atol.tolist(),
    }


def _solve(problem, method, setting, t_end, max_nfev, compiled=False):
    """One run of ``method`` at ``setting`` (target or rtol) on a fresh model;
    ours on the compiled path when ``compiled``."""
    model = hfdi.models.get(problem)
    if method in SCHEMES:
        return model, _run_ours(model, method, t_end, setting, compiled=compiled)
    if method in ERROR_CONTROLLED:
        return model, _run_ours(model, method.split("-")[0], t_end, rtol=setting,
                                compiled=compiled)
    if method == "ida":
        return model, _run_ida(model, t_end, setting, max_nfev)
    if method == "ida_c":
        return model, _run_ida_c(model, t_end, setting, max_nfev)
    return model, _run_scipy(model, {"radau": "Radau", "bdf": "BDF"}[method], t_end, setting,
                             max_nfev)


def _errors(model, raw, reference):
    """``ε`` (Eq. 42) of ``u`` and of every quantity, at the run's own step times."""
    t = raw["t"]
    if raw["u"] is None or t.size < 2:
        return math.nan, {}
    u_ref, v_ref = reference.at(t)
    eps_u = error_norm(t, raw["u"], u_ref)
    z = model.quantities(t, np.asarray(raw["u"]), np.asarray(raw["v"]))
    z_ref = model.quantities(t, u_ref, v_ref)
    return eps_u, {name: error_norm(t, z[name], z_ref[name]) for name in z}


def _same(a, b):
    if a["u"] is None or b["u"] is None:
        return a["u"] is None and b["u"] is None
    return (np.array_equal(a["t"], b["t"]) and np.array_equal(a["u"], b["u"])
            and np.array_equal(a["v"], b["v"]))


def _record(problem, method, setting, raws, model, reference):
    raw = raws[0]
    eps_u, eps = _errors(model, raw, reference)
    walls = [r["wall"] for r in raws]
    rec = {
        "problem": problem, "method": method,
        "kind": "ours" if method in OURS else "competitor",
        "target": float(setting) if method in SCHEMES else None,
        "rtol": None if method in SCHEMES else float(setting),
        "label": _label(method, setting),
        "success": raw["success"], "status": raw["status"], "message": raw["message"],
        "t_reached": float(raw["t"][-1]) if raw["t"].size else None,
        "wall": min(walls), "walls": walls, "cpu": min(r["cpu"] for r in raws),
        "repeats_identical": all(_same(raw, r) for r in raws[1:]),
        "eps_u": eps_u, "eps": eps,
    }
    for key in ("steps", "accepted_steps", "newton_iterations", "first_step_trial_iterations",
                "nfev", "njev", "nlu", "linsolver", "jacobian"):
        rec[key] = raw.get(key)
    return rec


def _mark_inaccurate(records, factor=INACCURATE_FACTOR):
    """Mark runs far less accurate than a looser setting of their method.

    ``records`` are by method, loosest setting first. A curve of
    work–precision assumes that a tighter setting is no less accurate; a run
    whose solver reports success with ``ε_u`` more than ``factor`` times that
    of every looser run did not honour its setting, and would make the
    interpolation of its method's curve meaningless.
    """
    worst = {}
    for r in records:
        eps = r["eps_u"]
        if not r["success"] or not (isinstance(eps, float) and math.isfinite(eps)):
            continue
        looser = worst.get(r["method"])
        if looser is not None and eps > factor * looser:
            r["success"] = False
            r["solver_status"] = r["status"]
            r["status"] = "INACCURATE"
            r["message"] = (f"the solver reported success ({r['message']}) in {r['steps']} "
                            f"steps, but ε_u {eps:.2e} is more than {factor:g}× the largest "
                            f"ε_u of the looser settings ({looser:.2e}); left out of the "
                            f"curves")
            continue
        worst[r["method"]] = eps if looser is None else max(looser, eps)


def _label(method, setting):
    if method in SCHEMES:
        return f"N̄={setting:g}"
    # the shortest digits that give the number back (labels are keys):
    # 1e-08, 1.2e-08, 3.16e-06
    return f"rtol={np.format_float_scientific(setting, trim='-', exp_digits=2)}"


def _skipped(problem, method, setting, why):
    return {"problem": problem, "method": method,
            "kind": "ours" if method in OURS else "competitor",
            "target": None, "rtol": float(setting), "label": _label(method, setting),
            "success": False, "status": "SKIPPED", "message": why, "t_reached": None,
            "wall": None, "walls": [], "cpu": None, "repeats_identical": True, "eps_u": math.nan,
            "eps": {}, "steps": None, "accepted_steps": None, "newton_iterations": None,
            "first_step_trial_iterations": None, "nfev": None, "njev": None, "nlu": None,
            "linsolver": None, "jacobian": None}


def bench_problem(problem, *, schemes=SCHEMES, targets=None, rtols=DEFAULT_RTOLS,
                  ours_rtols=DEFAULT_OURS_RTOLS, competitors=COMPETITORS, t_end=None, repeats=REPEATS,
                  repeat_below=REPEAT_BELOW, reference_rtol=REFERENCE_RTOL,
                  max_nfev=MAX_NFEV, skip_nfev=SKIP_NFEV, progress=None,
                  compiled=False) -> dict:
    """Work–precision runs of every method on one problem, one after another.

    Parameters
    ----------
    problem : str
        A name of :func:`hfdi.models.available`.
    schemes : sequence of str
        Our schemes, of :data:`SCHEMES` (``"newmark"``, ``"bathe"``,
        ``"hfdi"``, ``"generalized_alpha"``).
    targets : dict or sequence of float, optional
        Target iteration counts ``N̄`` (per sub-step for Bathe): one list for
        every scheme, or scheme → list. Default :data:`TARGETS` for each.
    rtols : sequence of float
        Relative tolerances of the competitors (sorted loosest first here).
    ours_rtols : sequence of float
        Relative tolerances of our schemes' error-controlled runs (methods
        ``<scheme>-rtol``); empty for none.
    competitors : sequence of str
        Of ``"ida"``, ``"ida_c"``, ``"radau"``, ``"bdf"``.
    t_end : float, optional
        End of every run and of the reference; default the model's ``T_o``.
    repeats : int
        Runs shorter than ``repeat_below`` seconds are made ``repeats`` times
        and the shortest wall time is kept.
    repeat_below : float
    reference_rtol : float
        ``rtol`` of the dense IDA reference of ``ε`` (Eq. 42).
    max_nfev, skip_nfev : int
        Work budget of a competitor run, and the work beyond which the
        tighter ``rtol`` values of that competitor are skipped.
    progress : callable, optional
        Called with one line of text per run.
    compiled : bool
        Our runs on the compiled path (``compiled=True``, docs/compiled.md).

    Returns
    -------
    dict
        ``problem``, ``settings``, ``reference`` (its statistics),
        ``records`` (one dict per run: ``method``, ``target`` or ``rtol``,
        ``wall`` [s], ``steps``, ``newton_iterations``, ``nfev``, ``njev``,
        ``nlu``, ``status``, ``success``, ``message``, ``eps_u`` and ``eps``
        of every quantity, ...), ``speedup`` (:func:`speedups`), ``goal``
        (:func:`goal`), ``machine`` (:func:`machine_info`) and ``bench_time``.
    """
    say = progress or (lambda text: None)
    started = time.perf_counter()
    load_start = load_average()
    model = hfdi.models.get(problem)
    t_end = float(experiment(problem).observation_time if t_end is None else t_end)
    unknown = [s for s in schemes if s not in SCHEMES]
    if unknown:
        raise ValueError(f"schemes must be of {', '.join(SCHEMES)}, got "
                         f"{', '.join(map(repr, unknown))}")
    if isinstance(targets, dict):
        per_scheme = {s: tuple(targets.get(s) or DEFAULT_TARGETS.get(s, TARGETS))
                      for s in schemes}
    else:
        per_scheme = {s: tuple(targets) if targets else DEFAULT_TARGETS.get(s, TARGETS)
                      for s in schemes}
    # loosest first: the warm-up uses the cheapest setting, and the skip rule
    # of the competitors needs the order
    per_scheme = {s: tuple(sorted(map(float, ts), reverse=True)) for s, ts in per_scheme.items()}
    rtols = tuple(sorted(map(float, rtols), reverse=True))
    ours_rtols = tuple(sorted(map(float, ours_rtols or ()), reverse=True))

    say(f"{problem}: IDA reference (rtol {reference_rtol:g}; computed once, then cached)")
    reference = cached_reference(problem, t_end=t_end, rtol=reference_rtol)

    methods = [(m, per_scheme[m]) for m in schemes] + \
        [(f"{m}-rtol", ours_rtols) for m in schemes] + [(c, rtols) for c in competitors]
    methods = [(m, ts) for m, ts in methods if ts]
    for method, settings in methods:
        # warm-up, untimed: imports and first-call costs belong to no run
        try:
            _solve(problem, method, settings[0], 0.1 * t_end, max_nfev, compiled)
        except Exception:
            pass
    # Round robin over the methods, loosest settings first: the load of the
    # machine drifts, and taking every method's k-th setting in turn spreads
    # the drift over all methods instead of favouring those run first.
    runs = {}
    skip_reason = {m: None for m, _ in methods}
    if "ida_c" in skip_reason:
        skip_reason["ida_c"] = _ida_c_missing(model)
    for k in range(max(len(ts) for _, ts in methods) if methods else 0):
        for method, settings in methods:
            if k >= len(settings):
                continue
            setting = settings[k]
            if skip_reason[method]:
                runs[method, k] = _skipped(problem, method, setting, skip_reason[method])
                say(f"  {problem:11s} {method:8s} {_label(method, setting):12s} skipped")
                continue
            fresh, raw = _solve(problem, method, setting, t_end, max_nfev, compiled)
            raws = [raw]
            while len(raws) < repeats and raw["wall"] < repeat_below:
                raws.append(_solve(problem, method, setting, t_end, max_nfev, compiled)[1])
            rec = _record(problem, method, setting, raws, fresh, reference)
            runs[method, k] = rec
            say(f"  {problem:11s} {method:8s} {rec['label']:12s} {rec['wall'] * 1e3:9.1f} ms  "
                f"ε_u {rec['eps_u']:.2e}  {rec['status']}")
            if method in COMPETITORS and (rec["nfev"] or 0) > skip_nfev:
                skip_reason[method] = (f"skipped: the run at {rec['label']} needed "
                                       f"{rec['nfev']} evaluations (> {skip_nfev})")
    # records by method, then setting (loosest first), whatever the order run
    records = [runs[m, k] for m, ts in methods for k in range(len(ts))]
    _mark_inaccurate(records)
    out = {
        "problem": problem,
        "n_dof": int(model.n_dof),
        "t_end": t_end,
        "observation_time": float(experiment(problem).observation_time),
        "settings": {
            "schemes": list(schemes), "targets": {s: list(ts) for s, ts in per_scheme.items()},
            "ours_rtols": list(ours_rtols), "competitors": list(competitors), "rtols": list(rtols), "repeats": int(repeats),
            "repeat_below": float(repeat_below), "reference_rtol": float(reference_rtol),
            "max_nfev": int(max_nfev), "skip_nfev": int(skip_nfev),
            "compiled": bool(compiled), "inaccurate_factor": INACCURATE_FACTOR,
            "atol_rule": ATOL_RULE, "newton_tol_ours": "hfdi's default: 1e-8 (targets), "
            "min(1e-8, max(1e-12, rtol/1000)) (error control)", "energy_limit_ours": ENERGY_LIMIT,
            "timing": "wall: time.perf_counter, cpu: time.process_time, around the solve "
                      "only (fresh model per run, built outside the timer); each the best of "
                      "the repeats; methods run in turn, loosest settings first",
            "eps": "Eq. 42 at each run's own step times against the dense IDA reference",
        },
        "reference": {"rtol": float(reference.rtol), "steps": reference.stats.get("steps"),
                      "nfev": reference.stats.get("nfev"),
                      "linsolver": reference.stats.get("linsolver"),
                      "from_cache": bool(reference.from_cache)},
        "records": records,
    }
    out["speedup"] = speedups(records)
    out["speedup_cpu"] = speedups(records, cost="cpu")
    out["goals"] = [goal(records, rival=rival, rtol=rtol, factor=factor, cost=cost)
                    for rival, rtol, factor in GOALS for cost in ("wall", "cpu")]
    out["goal"], out["goal_cpu"] = out["goals"][:2]
    out["machine"] = machine_info()
    out["machine"]["loadavg_start"] = load_start
    out["machine"]["loadavg_end"] = load_average()
    out["bench_time"] = time.perf_counter() - started
    return _plain(out)


def _ida_c_missing(model):
    """Why ``ida_c`` cannot run this model (``None`` when it can)."""
    from . import ida_compiled
    ok, why = ida_compiled.available()
    if not ok:
        return f"skipped: {why}"
    from hfdi.compiled import kernels_of
    kernels, why = kernels_of(model)
    if kernels is None or kernels.load is None:
        return f"skipped: the model has no compiled kernels with a load ({why or 'no load'})"
    return None


def bench_task(problem, options):
    """:func:`bench_problem` with keyword ``options``: the picklable task of
    :class:`validation.parallel.Runner` (one task per problem, so that the
    methods of a problem share one process and their times compare)."""
    def progress(text):
        print(text, file=sys.stderr, flush=True)
    return bench_problem(problem, progress=progress, **options)


# -- analysis -------------------------------------------------------------------------

def pareto_front(eps, wall) -> np.ndarray:
    """Indices of the points no other point beats in both ``ε`` and wall time.

    Parameters
    ----------
    eps, wall : array_like (n,)
        Error (Eq. 42) and cost of each run; points with a non-finite or
        non-positive value are left out.

    Returns
    -------
    ndarray of int
        The front, by increasing wall time (so by decreasing ``ε``).
    """
    eps = np.asarray(eps, dtype=float)
    wall = np.asarray(wall, dtype=float)
    ok = np.flatnonzero(np.isfinite(eps) & np.isfinite(wall) & (eps > 0) & (wall > 0))
    order = ok[np.lexsort((eps[ok], wall[ok]))]
    front, best = [], math.inf
    for i in order:
        if eps[i] < best:
            front.append(int(i))
            best = eps[i]
    return np.array(front, dtype=int)


def interpolate_wall(front_eps, front_wall, eps):
    """Wall time on a front at error ``eps``, linear in ``log wall`` against ``log ε``.

    Parameters
    ----------
    front_eps, front_wall : array_like (k,)
        A Pareto front (:func:`pareto_front`), in any order.
    eps : float

    Returns
    -------
    (float or None, str)
        The interpolated wall time and ``"in range"``; or ``None`` and
        ``"below range"`` (``eps`` smaller than the front's smallest ε: the
        method did not get that accurate) or ``"above range"`` (larger than its
        largest: even its cheapest run was more accurate). No extrapolation.
    """
    e = np.asarray(front_eps, dtype=float)
    w = np.asarray(front_wall, dtype=float)
    if e.size == 0 or not (math.isfinite(eps) and eps > 0):
        return None, "no data"
    order = np.argsort(e)
    e, w = e[order], w[order]
    if eps < e[0]:
        return None, "below range"
    if eps > e[-1]:
        return None, "above range"
    value = np.interp(math.log(eps), np.log(e), np.log(w))
    return float(math.exp(value)), "in range"


def _front(records, methods, cost="wall"):
    pts = [r for r in records if r["method"] in methods and r["success"]]
    idx = pareto_front([r["eps_u"] for r in pts], [r[cost] for r in pts])
    return [pts[i] for i in idx]


def speedups(records, cost="wall") -> dict:
    """Speed-up of our best scheme over the best competitor at equal ``ε_u``.

    Parameters
    ----------
    records : list of dict
        The runs of one problem (:func:`bench_problem`).
    cost : {"wall", "cpu"}
        The record key of the cost: wall time, or the process's CPU time
        (less exposed to other processes' load).

    Returns
    -------
    dict
        ``ours_front``: per point of the Pareto front of all our runs, the
        run (method, label, ``ε_u`` of Eq. 42, cost) and per competitor the
        cost interpolated at that ``ε_u`` on its front (or why not: for a
        competitor whose cheapest run is already more accurate, that run as
        ``loosest``), the best competitor and ``ratio`` = its cost / ours
        (``None`` when no competitor's front covers that ε), and
        ``ratio_upper_bound``: the smallest of the interpolated costs and the
        ``loosest`` runs' costs, over ours — the speed-up cannot be larger if
        a competitor's cost does not grow as its accuracy falls; ``fronts``:
        each method's front.
    """
    ours = sorted({r["method"] for r in records if r["kind"] == "ours"}, key=OURS.index)
    rivals = sorted({r["method"] for r in records if r["kind"] == "competitor"},
                    key=COMPETITORS.index)
    fronts = {m: _front(records, {m}, cost) for m in ours + rivals}
    points = []
    for r in _front(records, set(ours), cost):
        row = {"method": r["method"], "label": r["label"], "eps_u": r["eps_u"],
               cost: r[cost], "competitors": {}}
        best = None
        for c in rivals:
            f = fronts[c]
            wall_c, where = interpolate_wall([p["eps_u"] for p in f], [p[cost] for p in f],
                                             r["eps_u"])
            row["competitors"][c] = {cost: wall_c, "range": where}
            if where == "above range":
                # even its cheapest run is more accurate than ours: at our ε it
                # would cost at most that run's time (if cost falls with ε)
                loose = max(f, key=lambda p: p["eps_u"])
                row["competitors"][c]["loosest"] = {"label": loose["label"],
                                                    "eps_u": loose["eps_u"],
                                                    cost: loose[cost]}
            if wall_c is not None and (best is None or wall_c < row["competitors"][best][cost]):
                best = c
        row["best_competitor"] = best
        row["ratio"] = None if best is None else row["competitors"][best][cost] / r[cost]
        # the best competitor's cost at our ε is at most the smallest of the
        # interpolated walls and the above-range competitors' cheapest runs
        bounds = [v[cost] if v[cost] is not None else v["loosest"][cost]
                  for v in row["competitors"].values()
                  if v[cost] is not None or "loosest" in v]
        row["ratio_upper_bound"] = min(bounds) / r[cost] if bounds else None
        points.append(row)
    return {
        "cost": cost, "ours": ours, "competitors": rivals,
        "ours_front": points,
        "fronts": {m: [{"label": p["label"], "eps_u": p["eps_u"], cost: p[cost]}
                       for p in f] for m, f in fronts.items()},
    }


def goal(records, rtol=GOAL_RTOL, factor=GOAL_FACTOR, cost="wall", rival="ida") -> dict:
    """A goal figure: HFDI against ``rival`` (IDA) at ``rtol`` (default 1e-6), at its ``ε_u``.

    ``ε_u`` is Eq. 42 against the tight reference; ``cost`` is ``"wall"``
    or ``"cpu"`` (see :func:`speedups`); ``rival`` ``"ida"`` (scikit-sundae)
    or ``"ida_c"`` (IDA in C, :mod:`benchmarks.ida_compiled`).

    Returns
    -------
    dict
        ``rival``; ``ida``: the rival's run at ``rtol`` (``ε_u``, cost); ``hfdi``: the fastest
        successful HFDI run with ``ε_u`` at most IDA's, or ``None``;
        ``ratio``: IDA's cost / that run's cost (measured against measured);
        ``hfdi_interpolated`` and ``ratio_interpolated``: HFDI's front
        interpolated at IDA's ``ε_u`` (log–log, no extrapolation);
        ``met``: ``ratio >= factor``; ``note`` says why not when not.
    """
    out = {"rival": rival, "cost": cost, "rtol": rtol, "factor": factor, "ida": None,
           "hfdi": None,
           "ratio": None,
           "hfdi_interpolated": None, "interpolation": None,
           "ratio_interpolated": None, "met": False, "note": ""}
    ida = [r for r in records if r["method"] == rival and r["rtol"] is not None
           and math.isclose(r["rtol"], rtol, rel_tol=1e-9)]
    if not ida or not ida[0]["success"]:
        out["note"] = f"no successful {_method_name(rival)} run at rtol {rtol:g}"
        return out
    ida = ida[0]
    out["ida"] = {"eps_u": ida["eps_u"], cost: ida[cost], "steps": ida["steps"],
                  "nfev": ida["nfev"]}
    hfdi_methods = {"hfdi", "hfdi-rtol"}
    hfdi_runs = [r for r in records if r["method"] in hfdi_methods and r["success"]]
    if not hfdi_runs:
        out["note"] = "no successful HFDI run"
        return out
    reach = [r for r in hfdi_runs if r["eps_u"] <= ida["eps_u"]]
    front = _front(records, hfdi_methods, cost)
    wall_i, where = interpolate_wall([p["eps_u"] for p in front], [p[cost] for p in front],
                                     ida["eps_u"])
    out["interpolation"] = where
    if wall_i is not None:
        out["hfdi_interpolated"] = wall_i
        out["ratio_interpolated"] = ida[cost] / wall_i
    if not reach:
        best = min(r["eps_u"] for r in hfdi_runs)
        out["note"] = (f"no HFDI run reaches IDA's ε_u {ida['eps_u']:.2e} "
                       f"(HFDI's smallest: {best:.2e})")
        return out
    fast = min(reach, key=lambda r: r[cost])
    out["hfdi"] = {"target": fast["target"], "rtol": fast["rtol"], "label": fast["label"],
                   "method": fast["method"], "eps_u": fast["eps_u"], cost: fast[cost],
                   "steps": fast["steps"], "newton_iterations": fast["newton_iterations"]}
    out["ratio"] = ida[cost] / fast[cost]
    out["met"] = bool(out["ratio"] >= factor)
    if not out["met"]:
        out["note"] = f"ratio {out['ratio']:.2f} < {factor:g}"
    return out


# -- machine ----------------------------------------------------------------------------

def load_average():
    """The 1, 5 and 15-minute load averages, rounded; ``None`` where unknown."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:                                      # pragma: no cover - not on Linux
        return None


def _cpu_model():
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def machine_info() -> dict:
    """Platform, CPU, cores, library versions and thread settings of this process."""
    from importlib.metadata import PackageNotFoundError, version

    def ver(name):
        try:
            return version(name)
        except PackageNotFoundError:
            return None
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:                               # pragma: no cover - not on Linux
        usable = os.cpu_count()
    return {
        "platform": platform.platform(), "python": platform.python_version(),
        "cpu": _cpu_model(), "cpu_count": os.cpu_count(), "cpus_usable": usable,
        "numpy": np.__version__, "scipy": ver("scipy"), "scikit-sundae": ver("scikit-sundae"),
        "hfdi": getattr(hfdi, "__version__", None),
        "threads": {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                    "MKL_NUM_THREADS")},
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }


def _plain(obj):
    """JSON-ready: numpy scalars and arrays to Python, NaN and inf to None."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return _plain(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


# -- output -----------------------------------------------------------------------------

def _num(value, fmt):
    return "-" if value is None else format(value, fmt)


def format_problem(result) -> str:
    """A plain-text table of one problem's runs, the speed-ups and the goal figure."""
    ref = result["reference"]
    # the method column as wide as its longest name ("generalized_alpha-rtol")
    width = max([8] + [len(r["method"]) for r in result["records"]])
    lines = [f"{result['problem']}  (N = {result['n_dof']}, t_end = {result['t_end']:g}; "
             f"ε_u against IDA rtol {ref['rtol']:g}, {ref['steps']} steps)",
             f"  {'method':{width}s} {'setting':11s} {'wall [ms]':>10s} {'CPU [ms]':>9s} "
             f"{'steps':>7s} "
             f"{'Newton it':>9s} {'nfev':>7s} {'njev':>6s} {'nlu':>6s} {'ε_u':>9s}  status"]
    for r in result["records"]:
        eps = "-" if r["eps_u"] is None else format(r["eps_u"], ".2e")
        lines.append(f"  {r['method']:{width}s} {r['label']:11s} "
                     f"{_num(None if r['wall'] is None else r['wall'] * 1e3, '10.1f'):>10s} "
                     f"{_num(None if r['cpu'] is None else r['cpu'] * 1e3, '9.1f'):>9s} "
                     f"{_num(r['steps'], 'd'):>7s} {_num(r['newton_iterations'], 'd'):>9s} "
                     f"{_num(r['nfev'], 'd'):>7s} {_num(r['njev'], 'd'):>6s} "
                     f"{_num(r['nlu'], 'd'):>6s} {eps:>9s}  {r['status']}"
                     + ("" if r["success"] else f" ({r['message'][:90]})"))
    sp_ = result["speedup"]
    lines.append("")
    lines.append(f"  Speed-up at equal ε_u (ours: Pareto front of {', '.join(sp_['ours'])}; each "
                 "competitor's wall interpolated log–log on its Pareto front):")
    for p in sp_["ours_front"]:
        cells = []
        for c, v in p["competitors"].items():
            if v["wall"] is not None:
                cells.append(f"{c} {v['wall'] * 1e3:.0f} ms")
            elif "loosest" in v:
                cells.append(f"{c} above range (its {v['loosest']['label']}: ε_u "
                             f"{v['loosest']['eps_u']:.1e} in {v['loosest']['wall'] * 1e3:.0f} ms)")
            else:
                cells.append(f"{c} {v['range']}")
        ratio = "no competitor in range" if p["ratio"] is None else \
            f"best {p['best_competitor']}: ×{p['ratio']:.2f}"
        if p["ratio_upper_bound"] is not None and (
                p["ratio"] is None or p["ratio_upper_bound"] < p["ratio"] * (1 - 1e-12)):
            ratio += f" (at most ×{p['ratio_upper_bound']:.2f})"
        cpu = [q for q in result["speedup_cpu"]["ours_front"]
               if q["method"] == p["method"] and q["label"] == p["label"]]
        if cpu and cpu[0]["ratio"] is not None:
            ratio += f"; CPU time: ×{cpu[0]['ratio']:.2f} ({cpu[0]['best_competitor']})"
        lines.append(f"    ε_u {p['eps_u']:.2e}  {p['method']} {p['label']} "
                     f"{p['wall'] * 1e3:.0f} ms | {', '.join(cells)} → {ratio}")
    lines.append("")
    goals = result.get("goals") or [result["goal"], result["goal_cpu"]]
    for g, gc in zip(goals[::2], goals[1::2]):
        lines.append(_format_goal(g, gc))
    m = result["machine"]
    lines.append(f"  ({m['cpu']}, {m['cpus_usable']} cores usable; load average "
                 f"{m['loadavg_start']} → {m['loadavg_end']}; this problem took "
                 f"{result['bench_time']:.0f} s)")
    ratio = [r["wall"] / r["cpu"] for r in result["records"] if r["wall"] and r["cpu"]]
    if ratio and float(np.median(ratio)) > 1.3:
        # wall > CPU for single-threaded solvers: the process waited for a core
        lines.append(f"  NOTE: the machine was loaded (median wall/CPU time of the runs "
                     f"{float(np.median(ratio)):.1f}): wall-time ratios are noisy; the "
                     f"CPU-time ratios beside them are steadier.")
    return "\n".join(lines)


def _format_goal(g, gc) -> str:
    """One goal figure (:func:`goal`) by wall time, with its CPU-time ratio ``gc``."""
    rival = _method_name(g.get("rival", "ida"))
    head = f"  Goal (HFDI ≥{g['factor']:g}× {rival} rtol {g['rtol']:g})"
    if g["ida"] is None:
        return f"{head}: {g['note']}"
    text = f"{head}: {rival} ε_u {g['ida']['eps_u']:.2e} in {g['ida']['wall'] * 1e3:.1f} ms; "
    if g["hfdi"] is not None:
        text += (f"fastest HFDI run with ε_u ≤ that: {g['hfdi']['method']} {g['hfdi']['label']}, "
                 f"ε_u {g['hfdi']['eps_u']:.2e}, {g['hfdi']['wall'] * 1e3:.1f} ms → "
                 f"×{g['ratio']:.2f} measured")
    else:
        text += g["note"]
    if g["ratio_interpolated"] is not None:
        text += f"; on HFDI's front interpolated: ×{g['ratio_interpolated']:.2f}"
    else:
        text += f"; HFDI's front at that ε_u: {g['interpolation']}"
    if gc["ratio"] is not None:
        text += f"; CPU time: ×{gc['ratio']:.2f} ({gc['hfdi']['method']} {gc['hfdi']['label']})"
    return text + f": {'met' if g['met'] else 'NOT met'}"


#: Colour, marker and line of each method: our schemes in the colours of every
#: figure (:data:`validation.experiments.SCHEME_COLOURS`) with a marker by their
#: place in :data:`hfdi.SCHEMES`, dotted when error-controlled.
_MARKERS = SchemeStyle(("o", "s", "D", "X", "*", "h"), "x")
_COMPETITOR_STYLE = {"ida": ("black", "^", "--"), "ida_c": ("dimgray", "<", "-."), "radau": ("tab:purple", "v", "--"),
                     "bdf": ("tab:brown", "P", "--")}


def _style(method):
    """``(colour, marker, line)`` of a method: a competitor, a scheme or
    ``<scheme>-rtol``; gray crosses for a name of neither."""
    if method in _COMPETITOR_STYLE:
        return _COMPETITOR_STYLE[method]
    scheme, _, mode = method.partition("-")
    if scheme in SCHEMES:
        return SCHEME_COLOURS[scheme], _MARKERS[scheme], ":" if mode else "-"
    return "gray", "x", ":"


def _method_name(method):
    """A method as the legends name it: ``HFDI``, ``GeneralizedAlpha (rtol)``, ``IDA``."""
    if method == "ida_c":
        return "IDA (C)"
    base, _, mode = method.partition("-")
    if base in SCHEMES:
        name = scheme_title(base)
    else:
        name = base.upper() if base in ("ida", "bdf") else base.capitalize()
    return name + (f" ({mode})" if mode else "")


def plot_problem(result, path) -> Path:
    """Log–log ``ε_u`` (Eq. 42) against wall time, one line per method, as a PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.5))
    try:
        methods = list(dict.fromkeys(r["method"] for r in result["records"]))
        for method in methods:
            runs = [r for r in result["records"] if r["method"] == method and r["success"]
                    and r["eps_u"] is not None and r["eps_u"] > 0]
            if not runs:
                continue
            # in the order of the settings (loosest first), as work-precision
            # diagrams are read: a zigzag shows where tightening cost no time
            color, marker, line = _style(method)
            x = [r["wall"] for r in runs]
            y = [r["eps_u"] for r in runs]
            name = _method_name(method)
            ax.plot(x, y, line, color=color, marker=marker, label=name, ms=5, lw=1.2)
            # label the ends of each curve (loosest and tightest setting)
            for r in {id(runs[0]): runs[0], id(runs[-1]): runs[-1]}.values():
                ax.annotate(r["label"].replace("N̄", "$\\bar N$"), (r["wall"], r["eps_u"]),
                            textcoords="offset points", xytext=(4, 3), fontsize=7,
                            color=color)
        g = result["goal"]
        if g.get("ida"):
            ax.plot([g["ida"]["wall"]], [g["ida"]["eps_u"]], "o", ms=12, mfc="none",
                    mec="black", label=f"IDA rtol {g['rtol']:g}")
        if g.get("hfdi"):
            ax.plot([g["hfdi"]["wall"]], [g["hfdi"]["eps_u"]], "o", ms=12, mfc="none",
                    mec="tab:red", label="fastest HFDI at IDA's ε")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time [s]")
        ax.set_ylabel("ε_u (Eq. 42)")
        path_name = "compiled path" if result.get("settings", {}).get("compiled") else \
            "Python path"
        ax.set_title(f"{result['problem']}: work–precision over [0, {result['t_end']:g}] "
                     f"(ours on the {path_name})")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=120)
    finally:
        plt.close(fig)
    return write_output(path, buffer.getvalue())


def write_outputs(results, out) -> dict:
    """``bench_<problem>.json`` and ``.png`` per problem and ``bench.md``; returns the paths."""
    out = Path(out)
    written = {}
    tables = []
    for res in results:
        name = res["problem"]
        written[f"{name}.json"] = write_output(out / f"bench_{name}.json",
                                               json.dumps(res, indent=1, allow_nan=False))
        written[f"{name}.png"] = plot_problem(res, out / f"bench_{name}.png")
        tables.append(format_problem(res))
    text = ["# Work–precision: our schemes against IDA, Radau and BDF", "",
            "Made by `python -m benchmarks precision`. ε_u is the paper's error norm (Eq. 42) against a "
            "dense IDA reference at each run's own step times; wall times are measured in one "
            "process per problem, one run after another (see `benchmarks/precision.py`).", ""]
    for table in tables:
        text += ["```", table, "```", ""]
    written["bench.md"] = write_output(out / "bench.md", "\n".join(text))
    return written


# -- command line -----------------------------------------------------------------------

def _rtols(text):
    try:
        values = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"rtols must be numbers, got {text!r}") from None
    if not values or any(not (0 < v < 1) for v in values):
        raise argparse.ArgumentTypeError(f"rtols must be numbers in (0, 1), got {text!r}")
    return sorted(set(values), reverse=True)


def _ours_rtols(text):
    return [] if text.strip().lower() == "none" else opt.rtols(text)


def _competitors(text):
    if text.strip().lower() == "none":
        return []
    return opt.names_from(text, COMPETITORS, "competitor(s)", also=" (or none)")


def add_parser(sub) -> None:
    """Register ``precision`` on the sub-parsers of ``python -m benchmarks``."""
    bench = sub.add_parser("precision", help="work–precision (ε_u against wall time) of our "
                                             "schemes, IDA, Radau and BDF, per problem")
    bench.add_argument("--problems", type=opt.problems, default=None,
                       help="comma-separated problems (default: all four)")
    bench.add_argument("--out", default="out/bench", metavar="DIR",
                       help="output directory (default out/bench)")
    bench.add_argument("--schemes", type=opt.schemes, default=list(SCHEMES),
                       help=f"our schemes, comma-separated (default: all, "
                            f"{','.join(SCHEMES)})")
    bench.add_argument("--targets", type=opt.targets, default=None,
                       help="target iteration counts for every scheme (per sub-step for "
                            "Bathe; default 1.5,2,2.5,3,3.5,4,5)")
    bench.add_argument("--competitors", type=_competitors, default=list(COMPETITORS),
                       help="comma-separated, of ida, radau, bdf, or none (default: all)")
    bench.add_argument("--rtols", type=_rtols, default=list(DEFAULT_RTOLS),
                       help="competitors' relative tolerances (default 1e-3,...,1e-10)")
    bench.add_argument("--rtol", dest="ours_rtols", type=_ours_rtols,
                       default=list(DEFAULT_OURS_RTOLS),
                       help="relative tolerances of our schemes' error-controlled runs "
                            "(default 1e-3,...,1e-9; none for none)")
    bench.add_argument("--t-end", type=opt.positive, default=None,
                       help="end time of the runs and of the reference (default: T_o)")
    bench.add_argument("--repeats", type=opt.repeats, default=REPEATS,
                       help=f"runs under {REPEAT_BELOW:g} s are made this many times, the "
                            f"shortest kept (default {REPEATS})")
    bench.add_argument("--max-nfev", type=opt.positive_integer, default=MAX_NFEV,
                       help=f"work budget of a competitor run, in evaluations (default "
                            f"{MAX_NFEV}); tighter rtols are skipped after a run above "
                            f"half of it")
    bench.add_argument("--compiled", action="store_true",
                       help="our runs on the compiled path (compiled=True; docs/compiled.md)")
    opt.add_parallel_options(bench)


def run_command(args) -> int:
    """``python -m benchmarks precision``: run, print the tables, write the outputs."""
    problems = args.problems or names()
    opt.check_runs(problems, args.schemes, args.targets, args.t_end)
    out = opt.out_dir(args.out)
    options = {"schemes": list(args.schemes), "targets": args.targets,
               "rtols": list(args.rtols), "ours_rtols": list(args.ours_rtols),
               "competitors": list(args.competitors),
               "t_end": args.t_end, "repeats": args.repeats, "max_nfev": args.max_nfev,
               "skip_nfev": max(1, args.max_nfev // 2), "compiled": args.compiled}
    started = time.perf_counter()
    results = opt.runner_from_args(args).map(bench_task, [(p, options) for p in problems])
    written = write_outputs(results, out)
    for res in results:
        print(format_problem(res))
        print()
    print(f"work–precision of {len(results)} problem(s) took "
          f"{time.perf_counter() - started:.0f} s; outputs in {out}")
    for path in written.values():
        print(path)
    return 0
