"""Run the paper's experiments (its Tables 2–5) and format them beside its numbers."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import hfdi

from .errors import error_norms
from .paper import PAPER_TABLES
from .reference import cached_reference

__all__ = ["RunRecord", "run_experiment", "run_table", "make_record", "problem_reference",
           "format_table",
           "records_to_csv", "ENERGY_LIMIT"]

SCHEME_ORDER = ("newmark", "bathe", "hfdi")

#: A run is reported "div" when a guard of the integrator stops it (step below
#: its minimum, halvings exhausted) or when its energy balance breaks down: the
#: spurious energy Σ ΔE (Eq. 40) exceeds this fraction of the run's energy
#: scale (see ``hfdi.Integrator``'s ``energy_limit``).
ENERGY_LIMIT = 0.5


@dataclass
class RunRecord:
    """One run of a table: a problem, a scheme and a target iteration count."""

    problem: str
    scheme: str
    target: float
    steps: int
    mean_iterations: float
    mean_step: float
    cpu_time: float
    status: str
    message: str
    t_reached: float
    eps: dict = field(default_factory=dict)

    @property
    def diverged(self) -> bool:
        return self.status != "SUCCESS"

    def as_dict(self) -> dict:
        return asdict(self)


def run_experiment(problem: str, scheme: str, target: float, t_end: float | None = None,
                   params: dict | None = None):
    """Integrate ``problem`` to its ``T_o`` (or ``t_end``); returns (model, result)."""
    model = hfdi.models.get(problem, **(params or {}))
    t_end = model.observation_time if t_end is None else t_end
    result = hfdi.integrate(model, scheme, t_end, target_iterations=target,
                            energy_limit=ENERGY_LIMIT)
    return model, result


def make_record(problem, scheme, target, model, result, reference=None) -> RunRecord:
    """The table record of one run, with ``ε`` against ``reference`` when given."""
    st = result.stats
    eps = error_norms(model, result, reference) if reference is not None else {}
    return RunRecord(problem, scheme, float(target), st.steps, st.mean_iterations,
                     st.mean_step, st.cpu_time, result.status.name, result.message,
                     float(result.t[-1]), eps)


def problem_reference(problem: str, t_end=None, params=None, rtol=1e-12, progress=None):
    """The cached dense IDA reference of ``problem`` over ``[0, t_end]``
    (``T_o`` by default)."""
    if progress is not None:
        progress(f"IDA reference of {problem} (rtol {rtol:g}; computed once, then cached)")
    return cached_reference(problem, params, t_end=t_end, rtol=rtol)


def run_table(problem: str, schemes=SCHEME_ORDER, targets=None, t_end=None, params=None,
              progress=None, reference=None) -> list:
    """Every run of the paper's table for ``problem`` (its targets unless ``targets``).

    With a ``reference`` (see :func:`problem_reference`) each record carries
    ``ε`` (Eq. 42) of every quantity of interest of the model.
    """
    records = []
    model = hfdi.models.get(problem, **(params or {}))
    for scheme in schemes:
        for target in (targets or model.paper_targets[scheme]):
            model, result = run_experiment(problem, scheme, target, t_end, params)
            records.append(make_record(problem, scheme, target, model, result, reference))
            if progress is not None:
                progress(records[-1])
    return records


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
        head = "2·" if scheme == "bathe" else ""
        lines.append(f"{scheme.upper() if scheme == 'hfdi' else scheme.capitalize()}")
        lines.append(f"  {'N̄':<16}" + "".join(f"{head + format(r.target, '.1f'):>{width}}"
                                              for r in rows))
        for key, label in (("mean_step", "Δt_mv"), ("steps", "steps"),
                           ("mean_iterations", "N_mv"), ("cpu_time", "t_T [s]")):
            ours = []
            for r in rows:
                ours.append("div" if r.diverged else _fmt(getattr(r, key), key))
            lines.append(f"  {label:<16}" + "".join(f"{s:>{width}}" for s in ours))
            theirs = []
            for r in rows:
                row = paper.get(scheme, {}).get(round(r.target, 3), "n/a")
                theirs.append("n/a" if row == "n/a" else
                              ("div" if row is None else _fmt(row[key], key)))
            lines.append(f"  {'  (paper)':<16}" + "".join(f"{s:>{width}}" for s in theirs))
        for name in rows[0].eps:
            cells = [("div " if r.diverged else "") + format(r.eps.get(name, math.nan), ".2e")
                     for r in rows]
            lines.append(f"  {'ε_' + name:<16}" + "".join(f"{c:>{width}}" for c in cells))
        for r in rows:
            if r.diverged:
                lines.append(f"  div at N̄ = {r.target}: {r.status}, {r.message}"
                             + (" (ε over the interval reached)" if r.eps else ""))
        lines.append("")
    return "\n".join(lines)


def records_to_csv(records: list, path) -> None:
    """Write the runs as CSV, one row per run and one ``eps_<name>`` column per quantity."""
    import csv
    names = sorted({n for r in records for n in r.eps})
    fields = ["problem", "scheme", "target", "steps", "mean_iterations", "mean_step",
              "cpu_time", "status", "t_reached"]
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(fields + [f"eps_{n}" for n in names] + ["message"])
        for r in records:
            writer.writerow([getattr(r, f) for f in fields]
                            + [r.eps.get(n, "") for n in names] + [r.message])
