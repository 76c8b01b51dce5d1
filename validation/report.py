"""``hfdi-validate all``: every table, figure and the stability curves, and ``report.md``.

The outputs of :func:`run_all` in the directory ``out``:

* ``<problem>_table.json`` — the runs of the paper's table with their ``ε``
  (the records of ``hfdi-validate table --json``);
* ``<problem>_reference_convergence.json`` — ``ε`` of every table run against
  the rtol 1e-12 reference and a tighter one (rtol 1e-13);
* ``figures/*.png`` — the figures of :mod:`validation.figures` and
  :mod:`validation.stability`;
* ``stability.json`` — the table of ρ, PE and AD;
* ``report.md`` — all of it beside the paper's numbers, figures linked
  relatively;
* ``hfdi-validate-all.json`` — the settings the outputs were made with.

Every output is written atomically and an existing one is skipped unless
``force``, so an interrupted call resumes where it stopped; ``report.md`` is
redone when any output it draws on was written by the call (or the problems
differ from its own), and skipped only by a call that found everything done.
The settings file guards against mixing outputs of different settings in one
directory.

With a parallel :class:`validation.parallel.Runner` each problem (its table,
figures and reference convergence) and the stability outputs are one task;
a task returns its outputs as bytes and its progress lines, and this process
writes them (atomically, as they come in) and prints the lines. The outputs
are the same bytes as a serial call's, apart from measured times (``cpu_time``,
``t_T`` and the report's header); an interrupted parallel call keeps the
problems finished before the interruption, and a rerun resumes from there.
"""
from __future__ import annotations

import datetime
import json
import math
import time
from pathlib import Path

import numpy as np

import hfdi

from .errors import error_norms
from hfdi.files import write_output
from .experiments import EXPERIMENTS, PAPER_SCHEMES, SCHEME_ORDER, experiment, names
from .figures import figure_specs, write_figures
from .reference import IDAError
from .runs import Progress, ProblemRuns, RunRecord, scheme_title
from .stability import DEFAULT_RATIOS, FIGURE_NAMES, format_stability_table, write_stability

__all__ = ["run_all", "reference_convergence", "build_report", "stability_schemes",
           "SettingsMismatch", "TIGHT_RTOL", "SETTINGS_FILE"]

#: rtol of the default reference and of the tighter one of the convergence check.
DEFAULT_RTOL = 1e-12
TIGHT_RTOL = 1e-13
SETTINGS_FILE = "hfdi-validate-all.json"
FIGURE_DIR = "figures"


class SettingsMismatch(ValueError):
    """The output directory holds outputs made with other settings."""


# -- reference convergence ------------------------------------------------------------------

#: Factors on the default absolute tolerances of the tight reference, for the
#: displacements and the velocities, tried in turn. For a model starting at
#: rest the default velocity tolerance at rtol 1e-13 is tiny (1e-13 times one
#: length per observation time: 2e-15 for the tetrahedra), and IDA's error test
#: then fails repeatedly in its first step (the tetrahedra and the toss rule
#: do). Relaxing the velocities' by 10 gives them the tolerance of the rtol
#: 1e-12 reference while rtol and the displacements' stay 10× tighter.
TIGHT_ATOL_FACTORS = ((1.0, 1.0), (1.0, 3.0), (1.0, 10.0), (10.0, 10.0))


def _tight_reference(ctx, tight_rtol):
    """The tight reference with the first workable atol factor, and the failures before it."""
    failures = []
    for factors in TIGHT_ATOL_FACTORS:
        try:
            return ctx.reference(tight_rtol, factors), list(factors), failures
        except IDAError as exc:
            failures.append({"atol_factors": list(factors), "error": str(exc)})
            ctx.progress.say(f"reference {ctx.problem} rtol {tight_rtol:g}, atol ×{factors[0]:g} "
                             f"(u) ×{factors[1]:g} (v): IDA failed ({exc.message})")
    return None, None, failures


def reference_convergence(ctx: ProblemRuns, rtol=DEFAULT_RTOL, tight_rtol=TIGHT_RTOL) -> dict:
    """``ε`` of every table run against two references of different tolerance.

    Parameters
    ----------
    ctx : ProblemRuns
    rtol, tight_rtol : float
        The tolerances of the two IDA references.

    Returns
    -------
    dict
        ``problem``, ``t_end``, ``rtol``, ``tight_rtol``; ``runs``: per run
        ``scheme``, ``target``, ``status``, ``eps``, ``eps_tight`` and
        ``relative_change`` (``|ε_tight − ε| / ε_tight`` per quantity);
        ``max_relative_change`` over every run and quantity and ``worst`` (the
        run and quantity where it is reached); ``reference_change``: per
        quantity, the largest difference of the two references on a fine grid
        relative to the quantity's largest magnitude; ``atol_factors`` (u, v)
        of the tight reference (see :data:`TIGHT_ATOL_FACTORS`) and
        ``failures``, the IDA failures of the factors tried before them. When every factor fails,
        ``error`` holds the last failure and there are no runs.
    """
    ref = ctx.reference(rtol)
    tight, factor, failures = _tight_reference(ctx, tight_rtol)
    if tight is None:
        return {"problem": ctx.problem, "t_end": ctx.t_end, "rtol": rtol,
                "tight_rtol": tight_rtol, "runs": [], "max_relative_change": math.nan,
                "worst": None, "reference_change": {}, "atol_factors": None,
                "failures": failures, "error": failures[-1]["error"]}
    runs, worst, largest = [], None, 0.0
    for record in ctx.records():
        result = ctx.run(record.scheme, record.target)
        eps = error_norms(ctx.model, result, ref)
        eps_tight = error_norms(ctx.model, result, tight)
        change = {}
        for name in eps:
            a, b = eps[name], eps_tight[name]
            change[name] = abs(a - b) / abs(b) if math.isfinite(a) and math.isfinite(b) \
                and b != 0 else (0.0 if a == b else math.nan)
            if math.isfinite(change[name]) and change[name] >= largest:
                largest, worst = change[name], {"scheme": record.scheme,
                                                "target": record.target, "quantity": name}
        runs.append({"scheme": record.scheme, "target": record.target,
                     "status": result.status.name, "eps": eps, "eps_tight": eps_tight,
                     "relative_change": change})
    t = ctx.plot_times()
    z = ctx.model.quantities(t, *ref.at(t))
    z_tight = ctx.model.quantities(t, *tight.at(t))
    reference_change = {}
    for name in z:
        scale = float(np.max(np.abs(z_tight[name])))
        diff = float(np.max(np.abs(z[name] - z_tight[name])))
        reference_change[name] = diff / scale if scale > 0 else diff
    return {"problem": ctx.problem, "t_end": ctx.t_end, "rtol": rtol, "tight_rtol": tight_rtol,
            "runs": runs, "max_relative_change": largest, "worst": worst,
            "reference_change": reference_change, "atol_factors": factor, "failures": failures,
            "reference_nodes": {"rtol": int(ref.t.size), "tight_rtol": int(tight.t.size)}}


# -- the report -------------------------------------------------------------------------------

def _num(value, kind):
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if kind == "steps":
        return f"{int(value):d}"
    if kind in ("mean_iterations", "cpu_time"):
        return f"{value:.3f}"
    return f"{value:.2g}"


def _target_text(scheme, target):
    return ("2·" if scheme == "bathe" else "") + f"{target:.1f}"


def _paper(problem, scheme, target):
    """The paper's row: a dict, ``None`` for "div", ``"n/a"`` when it has no such run."""
    return EXPERIMENTS[problem].paper.get(scheme, {}).get(round(float(target), 3), "n/a")


def _table_markdown(problem, records) -> list:
    lines = ["| scheme | N̄ | steps | steps (paper) | N_mv | N_mv (paper) | Δt_mv | "
             "Δt_mv (paper) | t_T [s] | t_T paper [s] | status |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in records:
        row = _paper(problem, r.scheme, r.target)
        ours = [_num(getattr(r, k), k) for k in ("steps", "mean_iterations", "mean_step",
                                                 "cpu_time")]
        if row == "n/a":
            theirs = ["n/a"] * 4
        elif row is None:
            theirs = ["div"] * 4
        else:
            theirs = [_num(row[k], k) for k in ("steps", "mean_iterations", "mean_step",
                                                "cpu_time")]
        status = "ok" if not r.diverged else f"**div** ({r.status} at t = {r.t_reached:.4g})"
        lines.append(f"| {scheme_title(r.scheme)} | {_target_text(r.scheme, r.target)} | "
                     f"{ours[0]} | {theirs[0]} | {ours[1]} | {theirs[1]} | {ours[2]} | "
                     f"{theirs[2]} | {ours[3]} | {theirs[3]} | {status} |")
    return lines


def _eps_markdown(records) -> list:
    names = []
    for r in records:
        names += [n for n in r.eps if n not in names]
    if not names:
        return []
    lines = ["| scheme | N̄ | " + " | ".join(f"ε_{n}" for n in names) + " |",
             "|---|---|" + "---:|" * len(names)]
    for r in records:
        cells = [("–" if not math.isfinite(r.eps.get(n, math.nan)) else f"{r.eps[n]:.2e}")
                 + (" (div)" if r.diverged else "") for n in names]
        lines.append(f"| {scheme_title(r.scheme)} | {_target_text(r.scheme, r.target)} | "
                     + " | ".join(cells) + " |")
    return lines


def _comparison_summary(problem, records) -> list:
    """One sentence per scheme on how our steps compare with the paper's."""
    lines = []
    for scheme in SCHEME_ORDER:
        pairs = []
        for r in records:
            row = _paper(problem, r.scheme, r.target)
            if r.scheme == scheme and isinstance(row, dict) and not r.diverged:
                pairs.append(r.steps / row["steps"])
        div_ours = [_target_text(scheme, r.target) for r in records
                    if r.scheme == scheme and r.diverged]
        div_paper = [_target_text(scheme, r.target) for r in records
                     if r.scheme == scheme and _paper(problem, scheme, r.target) is None]
        text = f"- {scheme_title(scheme)}: "
        runs = [_target_text(scheme, r.target) for r in records if r.scheme == scheme]
        if runs and scheme not in EXPERIMENTS[problem].paper:
            lines.append(f"{text}not in the paper (its targets: {', '.join(runs)}); div here "
                         f"at N̄ = {', '.join(div_ours) or 'none'}.")
            continue
        if not pairs and not div_ours and not div_paper:
            continue
        if pairs:
            text += (f"steps ours/paper from {min(pairs):.2f} to {max(pairs):.2f} "
                     f"(median {float(np.median(pairs)):.2f}) over {len(pairs)} runs both finished")
        text += f"; div here at N̄ = {', '.join(div_ours) or 'none'}"
        text += f"; div in the paper at N̄ = {', '.join(div_paper) or 'none'}."
        lines.append(text)
    return lines


def _convergence_markdown(conv) -> list:
    lines = []
    for failure in conv.get("failures", []):
        fu, fv = failure["atol_factors"]
        lines += [f"IDA failed at rtol {conv['tight_rtol']:g} with the default absolute "
                  f"tolerances ×{fu:g} (displacements) and ×{fv:g} (velocities): "
                  f"{failure['error']}", ""]
    if conv.get("error"):
        return lines + ["No tighter reference could be computed, so this check is missing."]
    fu, fv = conv.get("atol_factors") or (1.0, 1.0)
    if (fu, fv) != (1.0, 1.0):
        ratio = conv["rtol"] / conv["tight_rtol"]
        lines += [f"The tighter reference therefore uses rtol {conv['tight_rtol']:g} with the "
                  f"default absolute tolerances of that rtol ×{fu:g} for the displacements "
                  f"and ×{fv:g} for the velocities: {ratio / fu:.3g}× and {ratio / fv:.3g}× "
                  f"those of the rtol {conv['rtol']:g} reference.", ""]
    ok = conv["max_relative_change"] < 0.01
    worst = conv.get("worst") or {}
    where = (f" ({scheme_title(worst['scheme'])} N̄ = "
             f"{_target_text(worst['scheme'], worst['target'])}, ε_{worst['quantity']})"
             if worst else "")
    lines.append(f"Largest relative change of ε over all {len(conv['runs'])} table runs and "
                 f"quantities between the rtol {conv['rtol']:g} and rtol {conv['tight_rtol']:g} "
                 f"references: **{100 * conv['max_relative_change']:.3g} %**{where} — "
                 + ("below 1 %, as expected." if ok else "**not below 1 %**; see the runs below."))
    ref_change = ", ".join(f"{n}: {v:.1e}" for n, v in conv["reference_change"].items())
    lines.append("")
    lines.append(f"The two references differ by at most (relative to the quantity's largest "
                 f"magnitude, on a fine uniform grid): {ref_change}.")
    lines.append("")
    names = list(conv["runs"][0]["eps"]) if conv["runs"] else []
    lines.append("| scheme | N̄ | " + " | ".join(
        f"ε_{n} (rtol {conv['rtol']:g}) | ε_{n} (rtol {conv['tight_rtol']:g}) | change"
        for n in names) + " |")
    lines.append("|---|---|" + "---:|---:|---:|" * len(names))
    for run in conv["runs"]:
        if run["scheme"] != "hfdi":
            continue
        cells = []
        for n in names:
            a, b, c = run["eps"][n], run["eps_tight"][n], run["relative_change"][n]
            cells += [f"{a:.4e}", f"{b:.4e}", "–" if not math.isfinite(c) else f"{100 * c:.2g} %"]
        lines.append(f"| HFDI | {run['target']:.1f} | " + " | ".join(cells) + " |")
    per_scheme = []
    for scheme in SCHEME_ORDER:
        values = [c for run in conv["runs"] if run["scheme"] == scheme
                  for c in run["relative_change"].values() if math.isfinite(c)]
        if values:
            per_scheme.append(f"{scheme_title(scheme)} {100 * max(values):.2g} %")
    lines.append("")
    lines.append("Largest change per scheme (all its table runs): " + ", ".join(per_scheme) + ".")
    return lines


def build_report(out, problems, settings, stability_rows, elapsed=None) -> str:
    """The Markdown of ``report.md``, from the outputs already in ``out``.

    Parameters
    ----------
    out : Path
    problems : sequence of str
    settings : dict
        The settings of :func:`run_all` (``schemes``, ``targets``, ``t_end``,
        ``long_t_end``).
    stability_rows : list of dict
    elapsed : float, optional
        Wall time of the call, for the header.
    """
    out = Path(out)
    now = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
    lines = ["# hfdi validation report", "",
             f"Made by `hfdi-validate all` with hfdi {hfdi.__version__} on {now}"
             + (f"; this call took {elapsed:.0f} s (outputs already present were skipped)"
                if elapsed is not None else "") + ".", "",
             "Settings: "
             + ", ".join(f"{k} = {v if v is not None else 'default'}"
                         for k, v in settings.items()) + ".", "",
             "Each table lists our runs beside the paper's numbers (Tables 2–5). CPU times t_T "
             "are process times measured on this machine; the paper's were measured on "
             "another machine and compare only as ratios between schemes. ε is the paper's "
             "error norm (Eq. 42) against an IDA reference (rtol 1e-12) evaluated at each "
             "run's own step times, not the paper's fine-step Newmark solution, so ε has no "
             "paper counterpart beyond the trends of Figs. 9, 10, 20 and 21. Bathe's "
             "targets are per sub-step (the paper's 2·N̄) and its Δt_mv spans both "
             "sub-steps. Some model data are chosen for this project (docs/models.md), so "
             "steps and Δt_mv need not match the paper's.", "",
             "## Contents", ""]
    for problem in problems:
        lines.append(f"- [{experiment(problem).title}](#{problem.replace('_', '-')})")
    lines += ["- [Stability and accuracy of the schemes](#stability)",
              "- [Reference convergence](#reference-convergence)", ""]

    for problem in problems:
        title = experiment(problem).title
        records = [RunRecord(**d) for d in json.loads((out / f"{problem}_table.json").read_text())]
        ctx = ProblemRuns(problem, schemes=settings.get("schemes") or PAPER_SCHEMES,
                          targets=settings.get("targets"), t_end=settings.get("t_end"),
                          long_t_end=settings.get("long_t_end"))
        number = experiment(problem).table
        lines += [f'<a id="{problem.replace("_", "-")}"></a>', "",
                  f"## {title}" + (f" (paper Table {number})" if number else ""), "",
                  f"Table runs to t = {ctx.t_end:g} s (the paper's T_o = "
                  f"{ctx.experiment.observation_time:g} s); JSON: "
                  f"[{problem}_table.json]({problem}_table.json).", ""]
        lines += _table_markdown(problem, records)
        if math.isclose(ctx.t_end, ctx.experiment.observation_time):
            lines += [""] + _comparison_summary(problem, records) + [""]
        else:
            lines += ["", f"These runs end at t = {ctx.t_end:g} s, not at the paper's T_o: "
                          "their steps, N_mv, Δt_mv and t_T do not compare with the paper's.", ""]
        notes = [f"- {scheme_title(r.scheme)} N̄ = {_target_text(r.scheme, r.target)}: "
                 f"{r.status}, {r.message}" for r in records if r.diverged]
        if notes:
            lines += ["Runs stopped early (ε is over the interval reached):", ""] + notes + [""]
        lines += [f"### Errors ε of {title.lower()}", ""] + _eps_markdown(records) + [""]
        lines += [f"### Figures of {title.lower()}", ""]
        for spec in figure_specs(ctx):
            path = out / FIGURE_DIR / spec.name
            if path.exists():
                lines += [f"![{spec.name}]({FIGURE_DIR}/{spec.name})", "",
                          f"*{spec.name}* — {spec.paper}. {spec.caption}", ""]
            else:
                lines += [f"*{spec.name}* — {spec.paper}: not written.", ""]

    lines += ['<a id="stability"></a>', "", "## Stability and accuracy of the schemes "
              "(paper Section 3, Figs. 1–2)", "",
              "Spectral radius ρ of the amplification matrix, period elongation PE and "
              "amplitude decay AD (Eqs. 29–33) on u'' + ω²u = 0 at Δt/T = ωΔt/(2π), from the "
              "schemes' own one-step code (`hfdi.spectral`). JSON: "
              "[stability.json](stability.json).", ""]
    lines += [format_stability_table(stability_rows, markdown=True), ""]
    for key, caption in (("radius", "Spectral radius against Δt/T (paper Fig. 1)."),
                         ("accuracy", "Period elongation and amplitude decay in percent "
                                      "against Δt/T (paper Fig. 2).")):
        name = FIGURE_NAMES[key]
        if (out / FIGURE_DIR / name).exists():
            lines += [f"![{caption}]({FIGURE_DIR}/{name})", "", f"*{name}.* {caption}", ""]

    lines += ['<a id="reference-convergence"></a>', "", "## Reference convergence", "",
              f"ε of the table runs against the default IDA reference (rtol {DEFAULT_RTOL:g}) "
              f"and against one with a 10× tighter tolerance (rtol {TIGHT_RTOL:g}); the "
              "tables above use the first. The HFDI runs are listed; every run enters the "
              "largest change.", ""]
    for problem in problems:
        path = out / f"{problem}_reference_convergence.json"
        lines += [f"### {experiment(problem).title}", ""]
        if path.exists():
            lines += _convergence_markdown(json.loads(path.read_text())) + [""]
        else:
            lines += ["*Not computed.*", ""]
    return "\n".join(lines) + "\n"


# -- the whole run ----------------------------------------------------------------------------

def _check_settings(out: Path, settings: dict, force: bool) -> dict:
    """Read the settings file of ``out``; raise if it disagrees with ``settings``."""
    path = out / SETTINGS_FILE
    saved = {}
    if path.exists():
        try:
            saved = json.loads(path.read_text())
        except (OSError, ValueError):
            saved = {}
    if saved and not force and saved.get("settings") != settings:
        there = saved.get("settings", {})
        diff = ", ".join(f"{k}: {there.get(k)!r} there, {settings.get(k)!r} now"
                         for k in [*settings, *(k for k in there if k not in settings)]
                         if there.get(k) != settings.get(k))
        raise SettingsMismatch(f"{out} holds outputs made with other settings ({diff}); "
                               "use --force to redo them or choose another --out")
    return saved


class _Lines(Progress):
    """The progress lines of a task in a worker, kept for the parent to print."""

    def __init__(self):
        super().__init__()
        self.lines = []

    def say(self, text: str) -> None:
        self.lines.append(text)


def _existing(out: Path, problem: str | None, skip: bool) -> dict:
    """What of a task's outputs is in ``out`` already (nothing unless ``skip``):
    read here, so that a worker elsewhere needs no access to ``out``."""
    figures = out / FIGURE_DIR
    names = sorted(p.name for p in figures.iterdir()) if skip and figures.is_dir() else []
    if problem is None:
        stability = out / "stability.json"
        rows = json.loads(stability.read_text())["rows"] \
            if skip and stability.exists() else None
        return {"figures": names, "stability": rows}
    table = out / f"{problem}_table.json"
    return {"figures": names,
            "table": json.loads(table.read_text()) if skip and table.exists() else None,
            "convergence": skip and (out / f"{problem}_reference_convergence.json").exists()}


def _problem_outputs(problem, schemes, targets, t_end, long_t_end, out, existing, compiled,
                     write, progress) -> bool:
    """The table, figures and reference convergence of one problem, the runs
    compiled or not (:class:`validation.runs.ProblemRuns`).

    ``write(name, data)`` writes one output (``name`` relative to ``out``);
    outputs listed in ``existing`` (:func:`_existing`) are skipped. Returns
    whether anything was written.
    """
    out = Path(out)
    ctx = ProblemRuns(problem, schemes, targets, t_end, long_t_end, progress=progress,
                      compiled=compiled)
    wrote = False
    table = out / f"{problem}_table.json"
    if existing["table"] is not None:
        ctx.set_records([RunRecord(**d) for d in existing["table"]])
        progress.say(f"table {table}: exists, skipped")
    else:
        records = ctx.records()
        write(table.name, json.dumps([r.as_dict() for r in records], indent=1))
        wrote = True
        progress.say(f"table {table}")
    figures = write_figures(ctx, out / FIGURE_DIR, skip_existing=True,
                            exists=lambda path: path.name in existing["figures"],
                            write=lambda path, data: write(f"{FIGURE_DIR}/{path.name}", data))
    wrote = wrote or any(status == "written" for _, _, status in figures)
    conv = out / f"{problem}_reference_convergence.json"
    if existing["convergence"]:
        progress.say(f"reference convergence {conv}: exists, skipped")
    else:
        result = reference_convergence(ctx)
        write(conv.name, json.dumps(result, indent=1))
        wrote = True
        progress.say(f"reference convergence {conv}: largest relative change of ε "
                     f"{100 * result['max_relative_change']:.3g} %"
                     + (f" (atol ×{result['atol_factors'][0]:g} (u) "
                        f"×{result['atol_factors'][1]:g} (v))"
                        if result.get("atol_factors") not in (None, [1.0, 1.0]) else ""))
    return wrote


def stability_schemes(schemes) -> list:
    """The schemes of the stability outputs of ``all``: the paper's three
    (its Figs. 1–2), then any other scheme of ``schemes``."""
    return list(PAPER_SCHEMES) + [s for s in SCHEME_ORDER
                                  if s in schemes and s not in PAPER_SCHEMES]


def _stability_outputs(ratios, out, existing, write, progress, schemes=PAPER_SCHEMES) -> tuple:
    """The stability figures and ``stability.json``
    (:func:`validation.stability.write_stability` of ``schemes``, told what
    ``existing`` found); returns the table's rows and whether anything was
    written."""
    out = Path(out)
    done = write_stability(out / FIGURE_DIR, ratios, skip_existing=True, progress=progress,
                           json_path=out / "stability.json",
                           exists=lambda path: path.name in existing["figures"],
                           write=lambda path, data: write(str(path.relative_to(out)), data),
                           rows=existing["stability"], schemes=schemes)
    return done["rows"], bool(done["written"])


def _all_task(kind, *args) -> dict:
    """One task of a parallel :func:`run_all`, run in a worker: ``("problem",
    name, schemes, targets, t_end, long_t_end, out, existing, compiled)`` or
    ``("stability", ratios, out, existing, schemes)``. Returns the outputs as bytes
    (``files``: name → data, in the order made), the progress lines and, for
    the stability, its rows."""
    files, lines = {}, _Lines()

    def keep(name, data):
        files[name] = data.encode("utf-8") if isinstance(data, str) else data

    if kind == "problem":
        wrote = _problem_outputs(*args, write=keep, progress=lines)
        rows = None
    else:
        ratios, out, existing, schemes = args
        rows, wrote = _stability_outputs(ratios, out, existing, keep, lines, schemes)
    return {"kind": kind, "name": args[0] if kind == "problem" else "stability",
            "files": files, "lines": lines.lines, "wrote": wrote, "rows": rows}


def run_all(out, problems=None, schemes=PAPER_SCHEMES, targets=None, t_end=None,
            long_t_end=None, ratios=DEFAULT_RATIOS, force=False, progress=None,
            runner=None, compiled=False) -> Path:
    """Every table, figure, the stability outputs and ``report.md`` into ``out``.

    Parameters
    ----------
    out : str or Path
        Output directory (created).
    problems : sequence of str, optional
        Default: every benchmark of :mod:`validation.experiments`.
    schemes, targets, t_end, long_t_end
        As :class:`validation.runs.ProblemRuns`. The stability outputs show
        the paper's three schemes and any other of ``schemes``
        (:func:`stability_schemes`).
    ratios : sequence of float
        ``Δt/T`` of the stability table.
    force : bool
        Redo outputs that exist. Without it they are skipped, which resumes
        an interrupted call.
    progress : Progress, optional
    runner : validation.parallel.Runner, optional
        Runs each problem and the stability outputs as tasks (see the module
        docstring); default: one after the other in this process, each output
        written as soon as it is made.
    compiled : bool
        Take the runs' steps in compiled code where the model allows (the same
        steps and ``N̄``; ``t_T`` then of compiled code). A setting: an ``out``
        made the other way is not resumed.

    Returns
    -------
    Path
        ``report.md``.

    Raises
    ------
    SettingsMismatch
        ``out`` holds outputs made with other settings (and not ``force``).
    """
    start = time.perf_counter()
    progress = progress or Progress(enabled=False)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    # The paper's order (Tables 2-5), then any other registered model.
    problems = list(problems or names())
    settings = {"schemes": list(schemes), "targets": None if targets is None else
                [float(t) for t in targets], "t_end": t_end, "long_t_end": long_t_end,
                "ratios": [float(r) for r in ratios]}
    if compiled:
        # only when set: outputs made before the setting existed resume as they were
        settings["compiled"] = True
    saved = _check_settings(out, settings, force)
    write_output(out / SETTINGS_FILE, json.dumps(
        {"settings": settings, "report_problems": saved.get("report_problems")}, indent=1))
    skip = not force
    (out / FIGURE_DIR).mkdir(exist_ok=True)

    def write(name, data):
        write_output(out / name, data)

    ratios = list(ratios)
    if runner is None or not runner.parallel:
        # report.md is redone whenever an output it draws on was (re)written.
        wrote = False
        for problem in problems:
            wrote |= _problem_outputs(problem, schemes, targets, t_end, long_t_end, out,
                                      _existing(out, problem, skip), bool(compiled), write,
                                      progress)
        rows, written = _stability_outputs(ratios, out, _existing(out, None, skip), write,
                                           progress, stability_schemes(schemes))
        wrote |= written
    else:
        tasks = [("problem", p, list(schemes), targets, t_end, long_t_end, str(out),
                  _existing(out, p, skip), bool(compiled))
                 # longest first (Experiment.cost), so that the workers finish together
                 for p in sorted(problems, key=lambda p: -experiment(p).cost)]
        tasks.append(("stability", ratios, str(out), _existing(out, None, skip),
                      stability_schemes(schemes)))
        progress.say(f"{len(problems)} problems and the stability outputs: "
                     f"{len(tasks)} tasks on {runner} (their lines come when each is done)")
        state = {"wrote": False, "rows": None}

        def collect(_, result):
            for name, data in result["files"].items():
                write(name, data)
            for line in result["lines"]:
                progress.say(line)
            state["wrote"] |= result["wrote"]
            if result["kind"] == "stability":
                state["rows"] = result["rows"]

        runner.map(_all_task, tasks, on_result=collect)
        wrote, rows = state["wrote"], state["rows"]

    report = out / "report.md"
    if skip and not wrote and report.exists() and saved.get("report_problems") == problems:
        progress.say(f"report {report}: exists, skipped")
    else:
        report_settings = {k: v for k, v in settings.items() if k != "ratios"}
        write_output(report, build_report(out, problems, report_settings, rows,
                                          elapsed=time.perf_counter() - start))
        write_output(out / SETTINGS_FILE, json.dumps(
            {"settings": settings, "report_problems": problems}, indent=1))
        progress.say(f"report {report}")
    return report
