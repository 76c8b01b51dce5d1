"""The paper's Tables 2–5 as text and CSV: our runs beside the paper's numbers."""
from __future__ import annotations

import math

from .experiments import EXPERIMENTS, SCHEME_ORDER
from .runs import scheme_title

__all__ = ["format_table", "records_to_csv"]


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
    """A plain-text table in the paper's layout, with the paper's numbers beneath ours
    (none beneath a scheme the paper did not run, as generalized-α)."""
    lines = []
    problem = records[0].problem if records else ""
    paper = EXPERIMENTS[problem].paper if problem in EXPERIMENTS else {}
    for scheme in SCHEME_ORDER:
        rows = [r for r in records if r.scheme == scheme]
        if not rows:
            continue
        width = 11
        lines.append(scheme_title(scheme))
        head = "/".join(name for name, used in (("N̄", rows[0].target is not None),
                                                 ("rtol", rows[0].rtol is not None)) if used)
        lines.append(f"  {head:<16}" + "".join(f"{r.label:>{width}}" for r in rows))
        for key, label in (("mean_step", "Δt_mv"), ("steps", "steps"),
                           ("mean_iterations", "N_mv"), ("cpu_time", "t_T [s]")):
            ours = []
            for r in rows:
                ours.append("div" if r.diverged else _fmt(getattr(r, key), key))
            lines.append(f"  {label:<16}" + "".join(f"{s:>{width}}" for s in ours))
            if all(r.rtol is not None for r in rows) or scheme not in paper:
                continue                # error-controlled runs, or a scheme the paper did not run
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
            if name == "u":
                # beside the true ε_u, the run's own estimate of it (no reference)
                cells = [format(r.eps_u_estimated, ".2e") for r in rows]
                lines.append(f"  {'ε_u estimated':<16}" + "".join(f"{c:>{width}}"
                                                                   for c in cells))
        for r in rows:
            if r.diverged:
                lines.append(f"  div at {head} = {r.label}: {r.status}, {r.message}"
                             + (" (ε over the interval reached)" if r.eps else ""))
        lines.append("")
    return "\n".join(lines)


def records_to_csv(records: list, path) -> None:
    """Write the runs as CSV (UTF-8), one row per run and one ``eps_<name>``
    column per quantity; atomically (:func:`hfdi.files.write_output`), so a
    failing write leaves the previous file as it was."""
    import csv
    import io

    from hfdi.files import write_output
    names = sorted({n for r in records for n in r.eps})
    fields = ["problem", "scheme", "target", "rtol", "steps", "mean_iterations", "mean_step",
              "cpu_time", "status", "t_reached", "eps_u_estimated"]
    text = io.StringIO(newline="")
    writer = csv.writer(text)
    writer.writerow(fields + [f"eps_{n}" for n in names] + ["message"])
    for r in records:
        writer.writerow([getattr(r, f) for f in fields]
                        + [r.eps.get(n, "") for n in names] + [r.message])
    write_output(path, text.getvalue())
