"""Run the paper's experiments (its Tables 2–5) and format them beside its numbers."""
from __future__ import annotations

import json
import math
import threading
from collections import OrderedDict
from dataclasses import asdict, dataclass, field

import hfdi

from .errors import error_norms
from .paper import PAPER_TABLES
from .reference import cached_reference, default_cache_dir

__all__ = ["RunRecord", "run_experiment", "run_tables", "table_run",
           "make_record", "problem_reference", "shared_reference", "format_table",
           "records_to_csv", "ENERGY_LIMIT"]

SCHEME_ORDER = ("newmark", "bathe", "hfdi")
#: A run is reported "div" when a guard of the integrator stops it (step below
#: its minimum, halvings exhausted) or when its energy balance breaks down: the
#: spurious energy Σ ΔE (Eq. 40) exceeds this fraction of the run's energy
#: scale (see ``hfdi.Integrator``'s ``energy_limit``).
ENERGY_LIMIT = 0.5


@dataclass
class RunRecord:
    """One run of a table: a problem, a scheme and a target iteration count
    (the paper's mode), a relative tolerance (error control), or both."""

    problem: str
    scheme: str
    target: float | None
    steps: int
    mean_iterations: float
    mean_step: float
    cpu_time: float
    status: str
    message: str
    t_reached: float
    eps: dict = field(default_factory=dict)
    rtol: float | None = None

    @property
    def label(self) -> str:
        """``N̄`` (``2·N̄`` for Bathe), ``rtol`` or both, as the table heads its column."""
        parts = []
        if self.target is not None:
            parts.append(("2·" if self.scheme == "bathe" else "") + format(self.target, ".1f"))
        if self.rtol is not None:
            parts.append(format(self.rtol, ".0e"))
        return "/".join(parts)

    @property
    def diverged(self) -> bool:
        return self.status != "SUCCESS"

    def as_dict(self) -> dict:
        return asdict(self)


def run_experiment(problem: str, scheme: str, target: float | None,
                   t_end: float | None = None, params: dict | None = None, rtol=None,
                   progress=None):
    """Integrate ``problem`` to its ``T_o`` (or ``t_end``) at the target
    iteration count ``target`` (the paper's mode), under error control at
    ``rtol``, or both; returns (model, result). ``progress`` is passed to
    :func:`hfdi.integrate`."""
    model = hfdi.models.get(problem, **(params or {}))
    t_end = model.observation_time if t_end is None else t_end
    result = hfdi.integrate(model, scheme, t_end, target_iterations=target, rtol=rtol,
                            energy_limit=ENERGY_LIMIT, progress=progress)
    return model, result


def make_record(problem, scheme, target, model, result, reference=None, rtol=None) -> RunRecord:
    """The table record of one run, with ``ε`` against ``reference`` when given."""
    st = result.stats
    eps = error_norms(model, result, reference) if reference is not None else {}
    return RunRecord(problem, scheme, None if target is None else float(target), st.steps,
                     st.mean_iterations, st.mean_step, st.cpu_time, result.status.name,
                     result.message, float(result.t[-1]), eps,
                     None if rtol is None else float(rtol))


def problem_reference(problem: str, t_end=None, params=None, rtol=1e-12, progress=None):
    """The cached dense IDA reference of ``problem`` over ``[0, t_end]``
    (``T_o`` by default)."""
    if progress is not None:
        progress(f"IDA reference of {problem} (rtol {rtol:g}; computed once, then cached)")
    return cached_reference(problem, params, t_end=t_end, rtol=rtol)


#: References kept by :func:`shared_reference` in one process, most recently
#: used last. A table sweep asks for one problem's reference run after run
#: (the runs are in problem order), so a few are enough; each is read from the
#: disk cache at most once per process and problem while it is kept.
SHARED_REFERENCES = 4
_shared: OrderedDict = OrderedDict()
_shared_lock = threading.Lock()


def shared_reference(problem: str, t_end=None, params=None, rtol=1e-12):
    """:func:`problem_reference`, kept in memory in this process.

    The unit of a parallel table sweep is one run (:func:`table_run`); its
    worker gets the reference's settings, not the reference, and loads it from
    the disk cache (filled by the parent before the sweep) the first time,
    then finds it here. A worker whose cache lacks it (a Dask worker on
    another machine) computes it: IDA is deterministic, so it is the same
    reference. The key includes the cache directory. Thread-safe (a Dask
    worker may run tasks in threads).
    """
    key = (problem, json.dumps(params or {}, sort_keys=True, default=repr),
           None if t_end is None else float(t_end), float(rtol), str(default_cache_dir()))
    with _shared_lock:
        if key in _shared:
            _shared.move_to_end(key)
            return _shared[key]
        reference = problem_reference(problem, t_end, params, rtol=rtol)
        _shared[key] = reference
        while len(_shared) > SHARED_REFERENCES:
            _shared.popitem(last=False)
        return reference


def table_run(problem: str, scheme: str, target: float | None, t_end=None, params=None,
              eps_rtol=1e-12, rtol=None, progress=None) -> RunRecord:
    """One run of a table and its record, with ``ε`` against the rtol
    ``eps_rtol`` reference (:func:`shared_reference`; none when ``None``).

    The unit of work of :func:`run_tables`: a module-level function of plain
    arguments, so that it runs the same in a worker process.
    """
    model, result = run_experiment(problem, scheme, target, t_end, params, rtol, progress)
    reference = None if eps_rtol is None else shared_reference(problem, t_end, params, eps_rtol)
    return make_record(problem, scheme, target, model, result, reference, rtol)


def run_tables(problems, schemes=SCHEME_ORDER, targets=None, t_end=None, params=None,
               eps=True, runner=None, progress=None, say=None, rtols=None,
               run_progress=None) -> dict:
    """Every run of the paper's tables of several problems (their targets unless
    ``targets``), each record with ``ε`` (Eq. 42) of every quantity of interest
    of its model when ``eps``.

    Parameters
    ----------
    problems : sequence of str
    schemes, targets, t_end, params
        Schemes, target iteration counts (every scheme), end time (default
        ``T_o``) and model parameters (every problem).
    rtols : sequence of float, optional
        Relative tolerances: the runs are error-controlled, one per rtol
        (combined with each of ``targets`` when both are given).
    eps : bool
        Compute ``ε`` against the rtol 1e-12 reference.
    runner : validation.parallel.Runner, optional
        Where the runs go (default: one after the other in this process).
        Each run is a task; the references are computed or loaded here first,
        one after the other, so that the workers find them in the disk cache.
    progress : callable, optional
        ``progress(record)`` for each run, in the order of the runs.
    say : callable, optional
        ``say(text)`` for the references.
    run_progress : callable, optional
        ``run_progress(label)`` returns the ``progress(t, statistics)``
        callback of :func:`hfdi.integrate` for the run ``label``; used when the
        runs are made in this process (a worker's output is not shown).

    Returns
    -------
    dict
        Problem name → list of :class:`RunRecord` (scheme by scheme, target
        by target); identical whatever the runner, apart from the
        measured ``cpu_time``.
    """
    from .parallel import Runner, single_threaded_blas
    runner = runner or Runner()
    problems = list(problems)
    if eps:
        for problem in problems:
            if say is not None:
                say(f"IDA reference of {problem} (rtol 1e-12; computed once, then cached)")
            # BLAS on one thread, as where a worker without the cache computes it
            with single_threaded_blas():
                if runner.parallel:
                    # fills the disk cache for the workers; not kept here
                    problem_reference(problem, t_end, params)
                else:
                    shared_reference(problem, t_end, params)
    tasks = []
    for problem in problems:
        model = hfdi.models.get(problem, **(params or {}))
        for scheme in schemes:
            for target in (targets or ([None] if rtols else model.paper_targets[scheme])):
                for rtol in (rtols or [None]):
                    task = (problem, scheme, None if target is None else float(target),
                            t_end, params, 1e-12 if eps else None, rtol)
                    if run_progress is not None and not runner.parallel:
                        label = "/".join(f"{k}={v:g}" for k, v in (("N̄", target),
                                                                    ("rtol", rtol))
                                         if v is not None)
                        task += (run_progress(f"{problem} {scheme} {label}"),)
                    tasks.append(task)
    records = runner.map(table_run, tasks,
                         on_result=None if progress is None else lambda i, r: progress(r))
    tables = {problem: [] for problem in problems}
    for record in records:
        tables[record.problem].append(record)
    return tables


def _fmt(value, kind):
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if kind == "steps":
        return f"{value:d}"
    if kind == "mean_iterations":
        return f"{value:.3f}"
    if kind == "cpu_time":
        return f"{value:.3f}"
    return f"{value:.2g}" if value < 1e-3 else f"{value:.4f}"


def format_table(records: list) -> str:
    """A plain-text table in the paper's layout, with the paper's numbers beneath ours."""
    lines = []
    problem = records[0].problem if records else ""
    paper = PAPER_TABLES.get(problem, {})
    for scheme in SCHEME_ORDER:
        rows = [r for r in records if r.scheme == scheme]
        if not rows:
            continue
        width = 11
        lines.append(f"{scheme.upper() if scheme == 'hfdi' else scheme.capitalize()}")
        head = "/".join(name for name, used in (("N̄", rows[0].target is not None),
                                                 ("rtol", rows[0].rtol is not None)) if used)
        lines.append(f"  {head:<16}" + "".join(f"{r.label:>{width}}" for r in rows))
        for key, label in (("mean_step", "Δt_mv"), ("steps", "steps"),
                           ("mean_iterations", "N_mv"), ("cpu_time", "t_T [s]")):
            ours = []
            for r in rows:
                ours.append("div" if r.diverged else _fmt(getattr(r, key), key))
            lines.append(f"  {label:<16}" + "".join(f"{s:>{width}}" for s in ours))
            if all(r.rtol is not None for r in rows):
                continue                # error-controlled runs: the paper has none
            theirs = []
            for r in rows:
                row = "n/a" if r.rtol is not None else \
                    paper.get(scheme, {}).get(round(r.target, 3), "n/a")
                theirs.append("n/a" if row == "n/a" else
                              ("div" if row is None else _fmt(row[key], key)))
            lines.append(f"  {'  (paper)':<16}" + "".join(f"{s:>{width}}" for s in theirs))
        for name in rows[0].eps:
            cells = [("div " if r.diverged else "") + format(r.eps.get(name, math.nan), ".2e")
                     for r in rows]
            lines.append(f"  {'ε_' + name:<16}" + "".join(f"{c:>{width}}" for c in cells))
        for r in rows:
            if r.diverged:
                lines.append(f"  div at {head} = {r.label}: {r.status}, {r.message}"
                             + (" (ε over the interval reached)" if r.eps else ""))
        lines.append("")
    return "\n".join(lines)


def records_to_csv(records: list, path) -> None:
    """Write the runs as CSV, one row per run and one ``eps_<name>`` column per quantity."""
    import csv
    names = sorted({n for r in records for n in r.eps})
    fields = ["problem", "scheme", "target", "rtol", "steps", "mean_iterations", "mean_step",
              "cpu_time", "status", "t_reached"]
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(fields + [f"eps_{n}" for n in names] + ["message"])
        for r in records:
            writer.writerow([getattr(r, f) for f in fields]
                            + [r.eps.get(n, "") for n in names] + [r.message])
