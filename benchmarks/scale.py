"""Scale of the toss rule: cost of a Newton iteration and memory against the model size.

The toss rule (``hfdi.models.toss_rule``) is a chain of ``N_el`` beam
elements with ``3 (N_el + 1)`` DOFs and a banded tangent, so every part of a
step — ``f``, ``K``, ``T``, the iteration matrix, its factorisation and solve —
should cost ``O(N_el)``. This module measures it:

* :func:`measure_size` runs one size in a fresh Python process (so that the
  peak resident memory belongs to that size alone) and times the Newton
  iterations of a fixed number of steps after the first;
* :func:`fit_exponent` fits ``log y = p log N_el + c`` (``scipy.stats.linregress``);
* :func:`run_scale` measures every size, fits the exponents over all sizes and
  over the asymptotic sizes (``N_el ≥ 6000``, where the fixed Python overhead
  of a call no longer dominates) and writes ``scale.json`` and ``scale.png``;
* :func:`full_run_comparison` integrates the whole observation time
  ``T_o = 0.1`` at 6000 elements with the schemes and with IDA (band solver)
  on the same model, and compares them.

``python -m benchmarks scale --out DIR`` does all of it (see :func:`main`).

Measurement conventions
-----------------------
* Wall-clock time (``time.perf_counter``) of ``steps`` steps after the first,
  divided by the Newton iterations they took (diverged attempts included, as
  ``Statistics.newton_iterations`` counts them). Model construction, the
  integrator's set-up and the first step (whose size is chosen by up to 40
  trial solves) are reported apart.
* ``OPENBLAS_NUM_THREADS = OMP_NUM_THREADS = MKL_NUM_THREADS = 1`` in the
  measuring process: a per-core cost that does not depend on the machine's
  other load or core count. ``threads="default"`` leaves them unset.
* Peak memory: ``ru_maxrss`` at the end minus the resident set size after the
  imports and before the model is built, i.e. what the model, the integrator
  and the steps added. No ``tracemalloc`` (it slows every allocation and
  would distort the timing); the figures are the operating system's.
"""
from __future__ import annotations

import argparse
import io
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from hfdi.files import write_output
from validation.errors import relative_error
from validation.experiments import SCHEME_ORDER, experiment
from hfdi.models.toss_rule import MAX_ELEMENTS
from validation import options as opt
from validation.options import Parser, caused_by_interrupt

__all__ = ["DEFAULT_SIZES", "ASYMPTOTIC_MIN", "measure_size", "fit_exponent", "run_scale",
           "full_run_comparison", "machine_info", "plot_scale", "main"]

#: The sizes of the issue "Performance and scale" (100 000 elements: 300 003 DOF).
DEFAULT_SIZES = (6, 60, 600, 6000, 60_000, 100_000)
#: Smallest size of the asymptotic fit; below it a Newton iteration is mostly
#: the fixed cost of Python calls, not work proportional to the size.
ASYMPTOTIC_MIN = 6000
#: Exponent the issue asks for.
TARGET_EXPONENT = 1.1
_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


class ScaleError(RuntimeError):
    """A measuring process failed; the message is one line."""


# -- one size, in the measuring process --------------------------------------------

def _current_rss():
    """Resident set size now, bytes (``/proc/self/statm``; peak so far elsewhere)."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return _peak_rss()


def _peak_rss():
    """Peak resident set size of this process, bytes (``ru_maxrss`` is KiB on Linux)."""
    import resource
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak) * (1 if sys.platform == "darwin" else 1024)


#: Sizes of the untimed warm-up runs before the baseline: one dense system
#: (its steps in the compiled loop) and one above ``DENSE_BELOW`` unknowns (the
#: Python loop with the compiled sparse model).
_WARM_UP_SIZES = (6, 60)


def _warm_up(scheme, target):
    """One step of the toss rule at each of :data:`_WARM_UP_SIZES` with the
    integrator's defaults: numba and the compiled code the runs use (about
    120 MB, the same at every size) are loaded, or compiled, before the
    baseline, so that the peak is the model's and the run's memory and no
    compilation falls into the timed steps."""
    import hfdi
    t_o = experiment("toss_rule").observation_time
    for size in _WARM_UP_SIZES:
        hfdi.Integrator(hfdi.models.toss_rule(size), scheme, target_iterations=float(target),
                        t_bound=t_o).step()


def _measure_here(n_elements, scheme="hfdi", target=3.0, steps=5, compiled="auto"):
    """The measurement of :func:`measure_size`, in the current process."""
    import hfdi                                          # import before the baseline
    import scipy.sparse                                  # noqa: F401  (part of the baseline)
    if compiled != "off":
        _warm_up(scheme, target)
    baseline = _current_rss()
    t0 = time.perf_counter()
    model = hfdi.models.toss_rule(int(n_elements))
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    t_o = experiment("toss_rule").observation_time
    integrator = hfdi.Integrator(model, scheme, target_iterations=float(target), t_bound=t_o,
                                 compiled=_COMPILED[compiled])
    setup = time.perf_counter() - t0
    st = integrator.statistics
    t0 = time.perf_counter()
    ok = integrator.step()
    first = time.perf_counter() - t0
    first_iterations = st.newton_iterations
    trials, trial_iterations = st.first_step_trials, st.first_step_trial_iterations
    it0, steps0, t_start = st.newton_iterations, st.steps, integrator.t
    c0 = time.process_time()
    t0 = time.perf_counter()
    taken = 0
    while ok and taken < steps and integrator.t < t_o:
        ok = integrator.step()
        taken += 1
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    st = integrator.statistics
    iterations = st.newton_iterations - it0
    peak = _peak_rss()
    return {
        "n_elements": int(n_elements), "n_dof": int(model.n_dof), "scheme": str(scheme),
        "target_iterations": float(target), "steps_timed": int(st.steps - steps0),
        "newton_iterations_timed": int(iterations),
        "time_per_iteration_s": wall / iterations if iterations else math.nan,
        "cpu_time_per_iteration_s": cpu / iterations if iterations else math.nan,
        "time_per_step_s": wall / (st.steps - steps0) if st.steps > steps0 else math.nan,
        "timed_wall_s": wall, "timed_cpu_s": cpu,
        "t_start_timed": t_start, "t_end_timed": integrator.t,
        "model_build_s": build, "integrator_setup_s": setup, "first_step_s": first,
        "first_step_trials": int(trials), "first_step_trial_iterations": int(trial_iterations),
        "first_step_iterations": int(first_iterations), "first_step_size": integrator.t
        if steps0 == 1 else math.nan,
        "rss_baseline_MB": baseline / 2 ** 20, "peak_rss_MB": peak / 2 ** 20,
        "peak_memory_MB": max(peak - baseline, 0) / 2 ** 20,
        "status": integrator.status.name, "ok": bool(ok),
        "threads": {v: os.environ.get(v) for v in _THREAD_VARS},
        "compiled": str(compiled), "compiled_attempt": bool(integrator.compiled),
        "compiled_model": bool(integrator.compiled_model),
    }


#: ``--compiled``: the ``compiled`` argument of the integrator (auto: compiled
#: where it can be; off: the Python path with the Python model).
_COMPILED = {"auto": None, "off": False}


def _child_env(threads):
    env = dict(os.environ)
    for var in _THREAD_VARS:
        if threads == "default":
            env.pop(var, None)
        else:
            env[var] = str(int(threads))
    # the measuring process imports benchmarks (not installed) and this
    # package from the same tree as the caller
    root = str(Path(__file__).resolve().parent.parent)
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def measure_size(n_elements, scheme="hfdi", target=3.0, steps=5, threads=1, timeout=3600.0,
                 compiled="auto"):
    """Time per Newton iteration and peak memory of the toss rule at one size.

    Runs in a fresh Python process (``sys.executable``), so that the peak
    resident set size is this size's alone and no cache of an earlier size
    helps.

    Parameters
    ----------
    n_elements : int
        ``N_el`` of the toss rule (``3 (N_el + 1)`` DOFs).
    scheme : str
        A scheme of :data:`hfdi.SCHEMES`.
    target : float
        Target Newton iterations per step ``N̄``.
    steps : int
        Steps timed after the first (fewer if the run reaches ``T_o``).
    threads : int or "default"
        BLAS/OpenMP threads of the measuring process (``OPENBLAS_NUM_THREADS``,
        ``OMP_NUM_THREADS``, ``MKL_NUM_THREADS``); ``"default"`` unsets them.
    timeout : float
        Seconds before the measuring process is killed.
    compiled : {"auto", "off"}
        ``auto``: the integrator's default, compiled where it can be (the
        dense compiled driver below ``DENSE_BELOW`` DOFs, the compiled sparse
        model above); ``off``: the Python path and the Python model.

    Returns
    -------
    dict
        ``time_per_iteration_s``, ``time_per_step_s``, ``peak_memory_MB``
        (peak RSS minus the RSS after the imports), ``peak_rss_MB``,
        ``model_build_s``, ``integrator_setup_s``, ``first_step_s``,
        ``first_step_trials``, counts, the thread settings, ``status``.

    Raises
    ------
    ScaleError
        The process failed, was killed (say, out of memory) or timed out.
    """
    n_elements = int(n_elements)
    if n_elements < 1 or int(steps) < 1:
        raise ValueError(f"n_elements and steps must be >= 1, got {n_elements} and {steps}")
    if compiled not in _COMPILED:
        raise ValueError(f"compiled must be one of {', '.join(_COMPILED)}, got {compiled!r}")
    code = ("import json, sys; from benchmarks.scale import _measure_here; "
            "print(json.dumps(_measure_here(*json.loads(sys.argv[1]))))")
    args = json.dumps([n_elements, str(scheme), float(target), int(steps), compiled])
    try:
        proc = subprocess.run([sys.executable, "-c", code, args], capture_output=True, text=True,
                              env=_child_env(threads), timeout=timeout)
    except subprocess.TimeoutExpired:
        raise ScaleError(f"{n_elements} elements: no result within {timeout:g} s") from None
    if proc.returncode != 0:
        if proc.returncode < 0:
            why = f"killed by signal {-proc.returncode}" + \
                (" (out of memory?)" if proc.returncode == -9 else "")
        else:
            lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
            why = lines[-1] if lines else f"exit status {proc.returncode}"
        raise ScaleError(f"{n_elements} elements: measuring process failed: {why}")
    try:
        return json.loads(proc.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        raise ScaleError(f"{n_elements} elements: no result from the measuring process") from None


# -- fits, machine, figure -----------------------------------------------------------

def fit_exponent(n, y):
    """Least-squares fit of ``log10 y = p log10 n + c``.

    Parameters
    ----------
    n, y : array_like
        Sizes and positive values; non-positive or non-finite ``y`` are left out.

    Returns
    -------
    dict
        ``exponent`` p, its ``stderr``, ``intercept`` c (log10), ``r`` and the
        ``sizes`` used; ``None`` values when fewer than two points remain.
    """
    from scipy.stats import linregress
    n = np.asarray(n, dtype=float)
    y = np.asarray(y, dtype=float)
    keep = np.isfinite(y) & (y > 0) & (n > 0)
    out = {"sizes": n[keep].astype(int).tolist(), "exponent": None, "stderr": None,
           "intercept": None, "r": None}
    if np.unique(n[keep]).size < 2:
        return out
    fit = linregress(np.log10(n[keep]), np.log10(y[keep]))
    # two points fit exactly; linregress then reports a stderr of 0
    out.update(exponent=float(fit.slope), stderr=float(fit.stderr),
               intercept=float(fit.intercept), r=float(fit.rvalue))
    return out


def machine_info(threads=1):
    """:func:`benchmarks.precision.machine_info` (platform, CPU, cores, versions,
    thread variables), with the memory, the BLAS threads of the measurement
    and the load average at its start."""
    from .precision import load_average, machine_info as common
    info = common()
    try:
        mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 ** 30
    except (ValueError, OSError):
        mem = None
    info.update(memory_GiB=mem,
                blas_threads="default (unset)" if threads == "default" else int(threads),
                load_average_at_start=load_average())
    return info


def plot_scale(records, fits, path):
    """Log–log figure of time per Newton iteration and peak memory against ``N_el``.

    Two panels; each shows the measured points, the fitted lines over all
    sizes and over ``N_el ≥ ASYMPTOTIC_MIN``, and the exponents in the
    legend.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in records if "error" not in r]
    n = np.array([r["n_elements"] for r in ok], dtype=float)
    series = (("time_per_iteration_s", 1e3, "time per Newton iteration [ms]", "C0", 0, "wall"),
              ("cpu_time_per_iteration_s", 1e3, "time per Newton iteration [ms]", "C2", 0,
               "CPU"),
              ("peak_memory_MB", 1.0, "peak memory (RSS above imports) [MB]", "C1", 1, ""))
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for key, scale, label, colour, panel, name in series:
        ax = axes[panel]
        y = np.array([r.get(key, math.nan) for r in ok], dtype=float) * scale
        good = np.isfinite(y) & (y > 0)
        if not good.any():
            continue
        ax.loglog(n[good], y[good], "o", color=colour, label=f"measured {name}".strip())
        for which, style in (("all", "-"), ("asymptotic", "--")):
            fit = fits[key][which]
            if fit["exponent"] is None:
                continue
            xs = np.array([min(fit["sizes"]), max(fit["sizes"])], dtype=float)
            ys = 10 ** (fit["intercept"] + fit["exponent"] * np.log10(xs)) * scale
            span = "all sizes" if which == "all" else f"N_el ≥ {ASYMPTOTIC_MIN}"
            ax.loglog(xs, ys, style, color=colour, alpha=0.7,
                      label=f"{name} fit {span}: exponent {fit['exponent']:.3f}".strip())
        ref = n[good]
        if ref.size and key != "cpu_time_per_iteration_s":
            # slope-1 guide through the largest size: what linear scaling looks like
            y1 = y[good][-1] * ref / ref[-1]
            ax.loglog(ref, y1, ":", color="0.6", label="slope 1")
        ax.set_xlabel("N_el (elements; DOF = 3 (N_el + 1))")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Toss rule: cost per Newton iteration and memory against size")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=120)
    plt.close(fig)
    return write_output(path, buffer.getvalue())


def _fits(records):
    ok = [r for r in records if "error" not in r]
    n = np.array([r["n_elements"] for r in ok], dtype=float)
    out = {}
    for key in ("time_per_iteration_s", "cpu_time_per_iteration_s", "peak_memory_MB"):
        y = np.array([r.get(key, math.nan) for r in ok], dtype=float)
        big = n >= ASYMPTOTIC_MIN
        out[key] = {"all": fit_exponent(n, y), "asymptotic": fit_exponent(n[big], y[big])}
    return out


def _json_value(value):
    """``value`` with NaN and infinities as None (strict JSON, as the other
    commands write it: a measurement that failed or was not made)."""
    if isinstance(value, dict):
        return {k: _json_value(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_value(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.ndarray):
        return _json_value(value.tolist())
    return value


def _write_json(path, data):
    return write_output(path, json.dumps(_json_value(data), indent=1, default=float,
                                         allow_nan=False) + "\n")


def run_scale(out, sizes=DEFAULT_SIZES, scheme="hfdi", target=3.0, steps=5, threads=1,
              default_threads=False, timeout=3600.0, progress=None, compiled="auto",
              python_path=False):
    """Measure every size (one fresh process each), fit, write ``scale.json`` and ``scale.png``.

    Parameters
    ----------
    out : str or Path
        Output directory.
    sizes : sequence of int
    scheme, target, steps, threads, timeout
        As :func:`measure_size`.
    default_threads : bool
        Also time each size with the default BLAS threads (reported as
        ``time_per_iteration_default_threads_s``).
    compiled : {"auto", "off"}
        As :func:`measure_size`.
    python_path : bool
        With ``compiled="auto"``, also time each size on the Python path, in
        its own process right after (``time_per_iteration_python_s``,
        ``peak_memory_python_MB``, ``steps_python``, ``newton_iterations_python``).
    progress : callable ``progress(str)``, optional

    Returns
    -------
    dict
        ``records`` (one per size; a failed size holds ``error``), ``fits``
        (``time_per_iteration_s`` and ``peak_memory_MB``, each ``all`` and
        ``asymptotic``), ``machine``, settings, ``wall_time_s`` and the paths.
    """
    say = progress or (lambda text: None)
    out = Path(out)
    start = time.perf_counter()
    records = []
    for n in sizes:
        say(f"measuring {n} elements ({3 * (n + 1)} DOF) ...")
        t0 = time.perf_counter()
        try:
            rec = measure_size(n, scheme, target, steps, threads, timeout, compiled)
        except ScaleError as exc:
            rec = {"n_elements": int(n), "n_dof": 3 * (int(n) + 1), "error": str(exc)}
        if default_threads and "error" not in rec:
            try:
                other = measure_size(n, scheme, target, steps, "default", timeout, compiled)
                rec["time_per_iteration_default_threads_s"] = other["time_per_iteration_s"]
            except ScaleError as exc:
                rec["default_threads_error"] = str(exc)
        if python_path and compiled != "off" and "error" not in rec:
            try:
                other = measure_size(n, scheme, target, steps, threads, timeout, "off")
                rec.update(time_per_iteration_python_s=other["time_per_iteration_s"],
                           peak_memory_python_MB=other["peak_memory_MB"],
                           newton_iterations_python=other["newton_iterations_timed"],
                           steps_python=other["steps_timed"])
            except ScaleError as exc:
                rec["python_path_error"] = str(exc)
        rec["process_wall_s"] = time.perf_counter() - t0
        records.append(rec)
        say(f"  {_row(rec)}")
    fits = _fits(records)
    result = {"model": "toss_rule", "scheme": scheme, "target_iterations": float(target),
              "compiled": str(compiled),
              "steps_timed": int(steps), "sizes": [int(n) for n in sizes],
              "asymptotic_min": ASYMPTOTIC_MIN, "target_exponent": TARGET_EXPONENT,
              "records": records, "fits": fits, "machine": machine_info(threads),
              "wall_time_s": time.perf_counter() - start}
    result["json"] = str(_write_json(out / "scale.json", result))
    if any("error" not in r for r in records):
        result["png"] = str(plot_scale(records, fits, out / "scale.png"))
        _write_json(out / "scale.json", result)
    return result


# -- the full run at 6000 elements -----------------------------------------------

class _Error:
    """Collects ``|u − u*|²`` and ``|u*|²`` of Eq. 42 at one run's times as IDA
    marches past them (the reference is never held whole)."""

    def __init__(self, t, u):
        self.t = np.asarray(t, dtype=float)
        self.u = u                       # list of (N,) arrays, one per time
        self.err = np.full(self.t.size, np.nan)
        self.ref = np.full(self.t.size, np.nan)

    def add(self, t, u_ref):
        k = np.searchsorted(self.t, t)
        if k < self.t.size and self.t[k] == t:
            self.err[k] = float(np.sum((self.u[k] - u_ref) ** 2))
            self.ref[k] = float(np.sum(u_ref ** 2))

    def value(self):
        """``ε_u`` over the times reached (all of them, or up to where IDA stopped)."""
        done = np.isfinite(self.err)
        n = int(np.argmin(done)) if not done.all() else done.size
        if n < 2:
            return math.nan, None
        t = self.t[:n]
        return relative_error(t, self.err[:n], self.ref[:n]), float(t[-1])


def _scheme_run(model, scheme, target, keep, t_end):
    """One adaptive run to ``t_end`` (:meth:`hfdi.Integrator.advance`); keeps
    ``(t, u)`` of every accepted step only if asked, from the blocks of rows
    ``advance`` hands over (a time repeated at a load breakpoint kept once)."""
    import hfdi
    start = time.perf_counter()
    integrator = hfdi.Integrator(model, scheme, target_iterations=float(target), t_bound=t_end)
    ts, us = [integrator.t], [integrator.state.u.copy()] if keep else None

    def rows(block):
        for t, u in zip(block["t"], block["u"]):
            if t > ts[-1]:
                ts.append(float(t))
                us.append(u)

    ok = integrator.advance(t_end, rows=rows if keep else None)
    wall = time.perf_counter() - start
    st = integrator.statistics
    record = {"scheme": scheme, "target_iterations": float(target), "wall_time_s": wall,
              "steps": int(st.steps), "accepted": int(st.accepted), "rejected": int(st.rejected),
              "newton_iterations": int(st.newton_iterations),
              "mean_iterations": float(st.mean_iterations),
              "first_step_trials": int(st.first_step_trials), "t_reached": float(integrator.t),
              "status": "SUCCESS" if ok and integrator.t >= t_end else integrator.status.name,
              "success": bool(ok and integrator.t >= t_end),
              "message": integrator.message}
    return record, integrator.state.u.copy(), (ts, us)


def full_run_comparison(n_elements=6000, schemes=("hfdi", "newmark", "bathe"), target=3.0,
                        rtols=(1e-6, 1e-8), linsolver="band", band_jacobian="internal",
                        eps=True, ida_wall_limit=None, progress=None, checkpoint=None,
                        t_end=None, ida_atol_v=None):
    """Whole ``T_o = 0.1`` runs of the schemes and of IDA on the toss rule at one size.

    Each scheme runs adaptively to ``T_o`` (wall time, steps, Newton
    iterations, success); IDA (:func:`validation.reference.ida_march`, band
    solver with SUNDIALS' banded difference-quotient Jacobian, no dense
    matrix) runs the same model over the same interval at each ``rtol``.
    With ``eps`` the tightest IDA run lands on every step time of every
    scheme and gives ``ε_u`` of Eq. 42 (the schemes' displacements are kept
    per step for that, ``8 N`` bytes a step each).

    Parameters
    ----------
    n_elements : int
    schemes : sequence of str
    target : float
        ``N̄`` of the schemes.
    rtols : sequence of float
        IDA tolerances; the smallest is the reference of ``ε_u``.
    linsolver, band_jacobian : str
        IDA's linear solver (see :func:`validation.reference.ida_reference`).
    eps : bool
        Compute ``ε_u`` against the tightest IDA run.
    ida_wall_limit : float, optional
        Seconds after which an IDA run stops; it then reports the time it
        reached and ``ε_u`` covers ``[0, t_reached]``.
    progress : callable, optional
    t_end : float, optional
        End of the runs; default the model's ``T_o = 0.1``. A shorter interval
        gives a comparison where IDA, which resolves the beam's highest
        (undamped) frequencies, can finish.
    ida_atol_v : float, optional
        Absolute tolerance of IDA on the velocities (the displacements keep
        ``rtol · u_scale``); default :func:`validation.reference.default_atol`,
        ``rtol · u_scale / span`` for a model at rest, which makes IDA resolve
        the beam's fastest (undamped) modes.
    checkpoint : callable ``checkpoint(dict)``, optional
        Called with the partial result after every run (to save it), so that
        an interrupted comparison keeps what it finished. Without ``eps`` IDA
        runs first.

    Returns
    -------
    dict
        ``schemes`` and ``ida`` records, ``end_difference`` (relative 2-norm
        of ``u(T_o)`` of each scheme against each finished IDA run),
        ``wall_ratio`` (scheme / IDA), ``eps_u`` and settings.
    """
    import hfdi
    from validation.reference import ida_march

    say = progress or (lambda text: None)
    model = hfdi.models.toss_rule(int(n_elements))
    t_end = float(experiment("toss_rule").observation_time if t_end is None else t_end)
    rtols = sorted((float(r) for r in rtols), reverse=True)
    eps = eps and bool(rtols)           # no IDA run, nothing to measure against
    runs, ends, kept, ida, ida_ends = [], {}, {}, [], {}

    def summary():
        diffs, ratios = {}, {}
        for run in runs:
            s = run["scheme"]
            diffs[s] = {f"{r:g}": float(np.linalg.norm(ends[s] - u) / np.linalg.norm(u))
                        for r, u in ida_ends.items() if run["success"]}
            ratios[s] = {f"{rec['rtol']:g}": run["wall_time_s"] / rec["wall_time_s"]
                         for rec in ida if "error" not in rec and rec["success"]}
        if len(ida_ends) >= 2:
            tight = min(ida_ends)
            diffs["IDA"] = {f"{r:g} vs {tight:g}": float(np.linalg.norm(u - ida_ends[tight])
                                                       / np.linalg.norm(ida_ends[tight]))
                            for r, u in ida_ends.items() if r != tight}
        eps_u = {}
        for s, e in kept.items():
            value, until = e.value()
            eps_u[s] = {"eps_u": value, "over": [0.0, until], "reference_rtol": rtols[-1]}
        result = {
            "model": "toss_rule", "n_elements": int(n_elements), "n_dof": int(model.n_dof),
            "t_end": t_end, "target_iterations": float(target), "schemes": runs, "ida": ida,
            "ida_linsolver": linsolver, "ida_band_jacobian": band_jacobian,
            "ida_wall_limit_s": ida_wall_limit, "ida_atol_v": ida_atol_v,
            "end_difference_relative": diffs, "wall_ratio_scheme_over_ida": ratios,
            "eps_u": eps_u,
            "note": ("IDA: first-order form y = (u, v) interleaved by node; "
                     f"{linsolver} solver, {band_jacobian} Jacobian ('internal': SUNDIALS' own "
                     "banded difference quotients; scikit-sundae 1.2 hands a user Jacobian "
                     "of the band solver a full (2N, 2N) array)"),
            "machine": machine_info(_threads_here())}
        if checkpoint is not None:
            checkpoint(result)
        return result

    def run_schemes():
        for scheme in schemes:
            say(f"{scheme}: N̄ = {target:g}, {n_elements} elements to t = {t_end:g} ...")
            record, u_end, (ts, us) = _scheme_run(model, scheme, target, eps, t_end)
            runs.append(record)
            ends[scheme] = u_end
            if eps:
                kept[scheme] = _Error(ts, us)
            say(f"  {scheme}: {record['steps']} steps, {record['newton_iterations']} "
                f"iterations, {record['wall_time_s']:.1f} s, {record['status']}")
            summary()

    def run_ida():
        for rtol in rtols:
            t_eval = callback = None
            if eps and kept and rtol == rtols[-1]:
                t_eval = np.unique(np.concatenate([e.t for e in kept.values()]))

                def callback(t, u, v):
                    for e in kept.values():
                        e.add(t, u)
            say(f"IDA ({linsolver}, {band_jacobian} Jacobian) rtol {rtol:g}"
                f"{' landing on the schemes’ step times' if t_eval is not None else ''} ...")
            atol = None
            if ida_atol_v is not None:
                atol = np.concatenate([np.full(model.n_dof, rtol * model.u_scale),
                                       np.full(model.n_dof, float(ida_atol_v))])
            try:
                ref = ida_march(model, t_end, t_eval=t_eval, callback=callback, rtol=rtol,
                                atol=atol,
                                linsolver=linsolver, band_jacobian=band_jacobian,
                                wall_limit=ida_wall_limit)
            except Exception as exc:                    # recorded; the others go on
                ida.append({"rtol": rtol, "error": f"{type(exc).__name__}: {exc}"})
                say(f"  IDA rtol {rtol:g} failed: {exc}")
                summary()
                continue
            st = dict(ref.stats)
            rec = {"rtol": rtol, "wall_time_s": st.pop("wall_time"), "steps": st.pop("steps"),
                   "nfev": st.pop("nfev"), "njev": st.pop("njev"),
                   "t_reached": st.pop("t_reached"), "stopped": st.pop("stopped"),
                   "landed_on_scheme_times": t_eval is not None,
                   "success": bool(ref.t[-1] >= t_end), **st}
            ida.append(rec)
            if rec["success"]:
                ida_ends[rtol] = ref.u[-1]
            say(f"  IDA rtol {rtol:g}: {rec['steps']} steps, nfev {rec['nfev']}, "
                f"{rec['wall_time_s']:.1f} s, t reached {rec['t_reached']:.6g}")
            summary()

    if eps:
        run_schemes()
        run_ida()
    else:
        run_ida()
        run_schemes()
    return summary()


def _threads_here():
    """BLAS threads of this process as set by ``OPENBLAS_NUM_THREADS``, else ``"default"``."""
    value = os.environ.get("OPENBLAS_NUM_THREADS", "")
    return int(value) if value.isdigit() else "default"


# -- command line ----------------------------------------------------------------

def _row(rec, paths=False):
    if "error" in rec:
        return f"{rec['n_elements']:>8d} {rec['n_dof']:>8d}  failed: {rec['error']}"
    row = (f"{rec['n_elements']:>8d} {rec['n_dof']:>8d} "
           f"{1e3 * rec['time_per_iteration_s']:>12.3f} "
           f"{1e3 * rec.get('cpu_time_per_iteration_s', math.nan):>11.3f} "
           f"{rec['peak_memory_MB']:>10.1f} "
           f"{rec['newton_iterations_timed']:>6d} {rec['model_build_s']:>9.3f} "
           f"{rec['first_step_s']:>9.2f}")
    if paths:
        python = rec.get("time_per_iteration_python_s", math.nan)
        row += (f" {1e3 * python:>12.3f} {python / rec['time_per_iteration_s']:>8.2f}"
                f" {rec.get('peak_memory_python_MB', math.nan):>10.1f}")
    return row


def format_table(result):
    """The measurements and fits as text."""
    paths = any("time_per_iteration_python_s" in r for r in result["records"])
    lines = [f"{'N_el':>8s} {'DOF':>8s} {'ms/iteration':>12s} {'CPU ms/it':>11s} "
             f"{'peak MB':>10s} "
             f"{'iters':>6s} {'build s':>9s} {'first s':>9s}"
             + (f" {'Python ms/it':>12s} {'speed-up':>8s} {'Python MB':>10s}" if paths else "")]
    lines += [_row(r, paths) for r in result["records"]]
    lines.append("")
    for key, name in (("time_per_iteration_s", "time per iteration (wall)"),
                      ("cpu_time_per_iteration_s", "time per iteration (CPU)"),
                      ("peak_memory_MB", "peak memory")):
        parts = []
        for which, label in (("all", "all sizes"), ("asymptotic", f"N_el >= {ASYMPTOTIC_MIN}")):
            fit = result["fits"].get(key, {}).get(which, {"exponent": None})
            parts.append(f"{label}: " + ("n/a" if fit["exponent"] is None else
                                         f"{fit['exponent']:.3f} ± {fit['stderr']:.3f}"))
        lines.append(f"exponent of {name}: " + "; ".join(parts)
                     + f" (target <= {TARGET_EXPONENT})")
    m = result["machine"]
    lines.append(f"machine: {m['cpu']}, {m['cpu_count']} cores, BLAS threads {m['blas_threads']}; "
                 f"whole measurement {result['wall_time_s']:.0f} s")
    return "\n".join(lines)


def format_full_run(full):
    """The full-run comparison as text."""
    lines = [f"Full run: toss rule, {full['n_elements']} elements ({full['n_dof']} DOF), "
             f"t = 0 to {full['t_end']:g}, N̄ = {full['target_iterations']:g}"]
    for r in full["schemes"]:
        lines.append(f"  {r['scheme']:<8s} {r['wall_time_s']:9.1f} s  {r['steps']:7d} steps  "
                     f"{r['newton_iterations']:8d} iterations  {r['status']}")
    for r in full["ida"]:
        if "error" in r:
            lines.append(f"  IDA rtol {r['rtol']:g}: {r['error']}")
            continue
        lines.append(f"  IDA rtol {r['rtol']:<6g} {r['wall_time_s']:9.1f} s  "
                     f"{r['steps']:7d} steps  nfev {r['nfev']}  njev {r['njev']}  "
                     f"t reached {r['t_reached']:.6g}"
                     f"{'' if r['success'] else ' (stopped: ' + str(r['stopped']) + ')'}")
    for s, d in full["wall_ratio_scheme_over_ida"].items():
        for rtol, ratio in d.items():
            lines.append(f"  wall {s}/IDA(rtol {rtol}) = {ratio:.3g}")
    for s, d in full["end_difference_relative"].items():
        for rtol, diff in d.items():
            if s == "IDA":
                lines.append(f"  u(t_end) of IDA rtol {rtol}, relative difference: {diff:.3g}")
            else:
                lines.append(f"  |u(t_end) {s} - IDA(rtol {rtol})| / |IDA(rtol {rtol})| = "
                             f"{diff:.3g}")
    for s, e in full["eps_u"].items():
        lines.append(f"  eps_u {s} (against IDA rtol {e['reference_rtol']:g}, over "
                     f"[0, {e['over'][1]}]) = {e['eps_u']:.3g}")
    return "\n".join(lines)


def _sizes(text):
    if text.strip().lower() == "none":
        return []
    try:
        sizes = [int(s.replace("_", "")) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"sizes must be integers, got {text!r}") from None
    if not sizes or min(sizes) < 1 or max(sizes) > MAX_ELEMENTS:
        raise argparse.ArgumentTypeError(f"sizes must be integers in [1, {MAX_ELEMENTS}], got "
                                         f"{text!r}")
    return sizes


def _schemes_or_none(text):
    return [] if text.strip().lower() == "none" else opt.schemes(text)


def _full_t_end(text):
    value = opt.positive(text)
    longest = opt.longest_run("toss_rule")
    if value > longest:
        raise argparse.ArgumentTypeError(f"must be at most {longest:g} s ({opt.LONGEST_RUN:g} "
                                         f"times the toss rule's longest observation time), "
                                         f"got {text!r}")
    return value


def _floats(text):
    if text.strip().lower() == "none":
        return []
    try:
        values = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers, got {text!r}") from None
    if not values or any(not (0 < v < 1) for v in values):
        raise argparse.ArgumentTypeError(f"tolerances must be in (0, 1), got {text!r}")
    return values


def build_parser():
    p = Parser(prog="python -m benchmarks scale",
                description="Toss rule: time per Newton iteration and peak memory against "
                            "the number of elements, and a full run against IDA.")
    p.add_argument("--out", required=True, help="output directory (scale.json, scale.png, "
                                                "scale_full_run.json)")
    p.add_argument("--sizes", type=_sizes, default=list(DEFAULT_SIZES),
                   help="comma-separated N_el (default 6,60,600,6000,60000,100000); "
                        "'none' skips the size measurement")
    p.add_argument("--steps", type=lambda text: opt.integer_in(text, 1, 100_000), default=5,
                   help="steps timed after the first (5)")
    p.add_argument("--scheme", default="hfdi", choices=SCHEME_ORDER)
    p.add_argument("--target", type=opt.single(opt.targets, "target"), default=3.0,
                   help="target iterations N̄ (3)")
    p.add_argument("--default-threads", action="store_true",
                   help="also time with the default BLAS threads")
    p.add_argument("--compiled", default="auto", choices=tuple(_COMPILED),
                   help="auto: compiled where it can be (default); off: the Python path")
    p.add_argument("--paths", action="store_true",
                   help="with --compiled auto, also time each size on the Python path")
    p.add_argument("--timeout", type=opt.positive, default=3600.0,
                   help="seconds per size (3600)")
    p.add_argument("--full-run", action=argparse.BooleanOptionalAction, default=True,
                   help="the full T_o run against IDA (default on)")
    p.add_argument("--full-elements", type=opt.single(_sizes, "number of elements"),
                   default=6000)
    p.add_argument("--full-schemes", type=_schemes_or_none, default=["hfdi", "newmark", "bathe"],
                   help="schemes of the full run ('none' for IDA only)")
    p.add_argument("--full-t-end", type=_full_t_end, default=None,
                   help="end of the full run (default T_o = 0.1); the result then goes to "
                        "scale_run_t<T>.json")
    p.add_argument("--rtols", type=_floats, default=[1e-6, 1e-8],
                   help="IDA tolerances ('none': no IDA run)")
    p.add_argument("--ida-wall-limit", type=opt.positive, default=None,
                   help="seconds after which an IDA run stops and reports where it got")
    p.add_argument("--no-eps", action="store_true", help="skip eps_u of the full runs")
    p.add_argument("--ida-atol-v", type=opt.positive, default=None,
                   help="IDA's absolute tolerance on the velocities (default rtol·u_scale/span)")
    p.add_argument("--json", default=None, type=opt.output_file,
                   help="also write everything to this file")
    return p


def main(argv=None):
    """Command line; returns the exit status (0 ok, 1 failure, 2 bad arguments)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    say = (lambda text: print(text, file=sys.stderr, flush=True))
    try:
        out = opt.out_dir(args.out)
    except opt.UsageError as exc:
        parser.error(str(exc))
    try:
        everything = {}
        if args.sizes:
            result = run_scale(out, args.sizes, args.scheme, args.target, args.steps,
                               default_threads=args.default_threads, timeout=args.timeout,
                               progress=say, compiled=args.compiled, python_path=args.paths)
            print(format_table(result))
            for key in ("json", "png"):
                if key in result:
                    print(result[key])
            everything["scale"] = result
        if args.full_run:
            schemes = args.full_schemes
            start = time.perf_counter()
            path = out / ("scale_full_run.json" if args.full_t_end is None
                          else f"scale_run_t{args.full_t_end:g}.json")

            def save(partial):
                partial["wall_time_s"] = time.perf_counter() - start
                _write_json(path, partial)
            full = full_run_comparison(args.full_elements, schemes, args.target, args.rtols,
                                       eps=not args.no_eps, ida_wall_limit=args.ida_wall_limit,
                                       progress=say, checkpoint=save, t_end=args.full_t_end,
                                       ida_atol_v=args.ida_atol_v)
            print()
            print(format_full_run(full))
            print(path)
            everything["full_run"] = full
        if args.json:
            _write_json(Path(args.json).expanduser(), everything)
    except BaseException as exc:
        # Ctrl-C, also when it arrived inside an import and came out as an ImportError
        if caused_by_interrupt(exc):
            print("benchmarks scale: interrupted", file=sys.stderr)
            return 130
        if not isinstance(exc, (OSError, ValueError, ScaleError)):
            raise
        print(f"benchmarks scale: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
