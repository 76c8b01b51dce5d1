"""Run the paper's experiments (its Tables 2–5) and format them beside its numbers."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import hfdi

from .paper import PAPER_TABLES

__all__ = ["RunRecord", "run_experiment", "run_table", "format_table", "ENERGY_LIMIT"]

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


def run_table(problem: str, schemes=SCHEME_ORDER, targets=None, t_end=None, params=None,
              progress=None) -> list:
    """Every run of the paper's table for ``problem`` (its targets unless ``targets``)."""
    records = []
    model = hfdi.models.get(problem, **(params or {}))
    for scheme in schemes:
        for target in (targets or model.paper_targets[scheme]):
            _, result = run_experiment(problem, scheme, target, t_end, params)
            st = result.stats
            records.append(RunRecord(problem, scheme, float(target), st.steps,
                                     st.mean_iterations, st.mean_step, st.cpu_time,
                                     result.status.name, result.message, float(result.t[-1])))
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
        for r in rows:
            if r.diverged:
                lines.append(f"  div at N̄ = {r.target}: {r.status}, {r.message}")
        lines.append("")
    return "\n".join(lines)
