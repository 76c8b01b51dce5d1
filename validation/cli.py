"""``hfdi-validate``: the paper's tables, figures and report from the command line."""
from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import hfdi

from . import options as opt
from hfdi.files import write_output
from .experiments import OTHER_SCHEME_TARGETS, PAPER_SCHEMES, SCHEME_ORDER, experiment, names
from .options import UsageError, check_problem, check_runs, out_dir
from .reference import IDAError
from .runs import Progress, ProblemRuns, run_tables
from .tables import format_table, records_to_csv


_SCHEMES_HELP = (f"comma-separated, of {', '.join(SCHEME_ORDER)} (default: the paper's "
                 f"{', '.join(PAPER_SCHEMES)})")
_OTHER_TARGETS = (f"{', '.join(s for s in SCHEME_ORDER if s not in PAPER_SCHEMES)} "
                  f"{','.join(format(t, 'g') for t in OTHER_SCHEME_TARGETS)}")


_COMPILED_HELP = ("take the steps in compiled code where the model allows (the same steps "
                  "and N̄; t_T then measures compiled code; default: the Python path, as the "
                  "tables in docs/results.md)")


def _run_options(parser):
    """The options that choose the runs of ``figures`` and ``all``."""
    parser.add_argument("--schemes", type=opt.schemes, default=list(PAPER_SCHEMES),
                        help=_SCHEMES_HELP)
    parser.add_argument("--targets", type=opt.targets, default=None,
                        help="target iteration counts of the table runs, for every scheme "
                             "(default: the paper's per scheme; " + _OTHER_TARGETS + ")")
    parser.add_argument("--t-end", type=opt.positive, default=None,
                        help="end time of the runs and of the reference (default: T_o)")
    parser.add_argument("--long-t-end", type=opt.positive, default=None,
                        help="end time of the long energy runs of Figs. 7 and 18 (default: "
                             "--t-end when given, else the paper's 10 and 3)")
    parser.add_argument("--compiled", action="store_true", help=_COMPILED_HELP)


def build_parser():
    parser = opt.Parser(prog="hfdi-validate",
                     description="Reproduce the paper's tables and figures.")
    sub = parser.add_subparsers(dest="command", required=True)
    table = sub.add_parser("table", help="the paper's table for one problem, or several "
                                         "(comma-separated)")
    table.add_argument("problem", help=f"one of {', '.join(names())}, or "
                                       "several, comma-separated")
    table.add_argument("--schemes", type=opt.schemes, default=list(PAPER_SCHEMES),
                       help=_SCHEMES_HELP)
    table.add_argument("--targets", type=opt.targets, default=None,
                       help="target iteration counts (per sub-step for Bathe; default: the "
                            "paper's per scheme; " + _OTHER_TARGETS + ")")
    table.add_argument("--rtol", type=opt.rtols, default=None, metavar="R[,R...]",
                       help="error-controlled runs at these relative tolerances instead of "
                            "the paper's targets (with --targets: both rules combined)")
    table.add_argument("--t-end", type=opt.positive, default=None, help="observation time T_o")
    table.add_argument("--json", metavar="FILE", type=opt.output_file,
                       help="write the runs as JSON records")
    table.add_argument("--csv", metavar="FILE", type=opt.output_file,
                       help="write the runs as CSV")
    table.add_argument("--no-eps", action="store_true",
                       help="skip the IDA reference and the error norms")
    table.add_argument("--compiled", action="store_true", help=_COMPILED_HELP)
    opt.add_parallel_options(table)
    sub.add_parser("models", help="list the models, their parameters, T_o and the paper's targets")
    figures = sub.add_parser("figures", help="the paper's figures of one problem as PNG files")
    figures.add_argument("problem", help=f"one of {', '.join(names())}")
    figures.add_argument("--out", required=True, metavar="DIR", help="output directory")
    _run_options(figures)
    stability = sub.add_parser("stability", help="spectral radius, period elongation and "
                                                 "amplitude decay of the schemes (Figs. 1-2)")
    stability.add_argument("--out", required=True, metavar="DIR", help="output directory")
    stability.add_argument("--schemes", type=opt.schemes, default=list(PAPER_SCHEMES),
                           help=_SCHEMES_HELP)
    stability.add_argument("--ratios", type=opt.ratios, default=None,
                           help="Δt/T of the printed table, comma-separated "
                                "(default: 0.01,0.05,0.1,0.2,0.5,1,10)")
    every = sub.add_parser("all", help="every table, figure and the stability curves, with "
                                       "DIR/report.md; resumes an interrupted call")
    every.add_argument("--out", required=True, metavar="DIR", help="output directory")
    every.add_argument("--problems", type=opt.problems, default=None,
                       help="comma-separated problems (default: all four)")
    _run_options(every)
    every.add_argument("--ratios", type=opt.ratios, default=None,
                       help="Δt/T of the stability table")
    every.add_argument("--force", action="store_true",
                       help="redo outputs that already exist (default: skip them)")
    opt.add_parallel_options(every)
    return parser


def _models(args):
    for name in names():
        exp = experiment(name)
        print(f"{name}  (N = {exp.model().n_dof}, T_o = {exp.observation_time:g})")
        targets = "; ".join(f"{s} {', '.join(format(t, 'g') for t in ts)}"
                            for s, ts in exp.targets.items())
        print(f"  paper's targets: {targets}")
        others = "; ".join(f"{s} {', '.join(format(t, 'g') for t in exp.table_targets(s))}"
                           for s in SCHEME_ORDER if s not in exp.targets)
        if others:
            print(f"  default targets of the other schemes (not in the paper): {others}")
        for key, value in hfdi.models.describe(name).items():
            print(f"  {key} = {value!r}")


def _table(args):
    problems = list(dict.fromkeys(s.strip() for s in args.problem.split(",") if s.strip()))
    for name in problems or [args.problem]:
        check_problem(name)
    check_runs(problems, args.schemes, args.targets, args.t_end, args.rtol)
    several = len(problems) > 1

    def progress(record):
        opt.raise_if_interrupted()
        where = f"{record.problem:11s} " if several else ""
        setting = " ".join(([f"N̄={record.target:g}"] if record.target is not None else [])
                           + ([f"rtol={record.rtol:.0e}"] if record.rtol is not None else []))
        print(f"  {where}{record.scheme:8s} {setting:<7} steps={record.steps:<6d} "
              f"{record.status}", file=sys.stderr, flush=True)

    def say(text):
        opt.raise_if_interrupted()
        print(f"  {text}", file=sys.stderr, flush=True)

    with opt.runner_from_args(args) as runner:
        tables = run_tables(problems, args.schemes, args.targets, args.t_end,
                            eps=not args.no_eps, runner=runner, progress=progress, say=say,
                            rtols=args.rtol, run_progress=_run_progress,
                            compiled=args.compiled)
    records = []
    for problem in problems:
        print(f"{problem}: computational characteristics "
              f"(ours, with the paper's beneath)\n")
        print(format_table(tables[problem]))
        records += tables[problem]
    if args.json:
        # atomic: a full disk or a kill leaves the previous file, not half of one
        write_output(args.json, json.dumps([r.as_dict() for r in records], indent=1).encode())
    if args.csv:
        records_to_csv(records, args.csv)


#: Seconds between two progress lines of one long run.
PROGRESS_EVERY = 5.0


def _run_progress(label):
    """A ``progress(t, statistics)`` callback for :func:`hfdi.integrate` that
    prints a line to stderr every :data:`PROGRESS_EVERY` seconds of a long
    run, so that a slow or stalled run is visible."""
    import time
    start = time.monotonic()
    last = [start]

    def progress(t, stats):
        now = time.monotonic()
        if now - last[0] >= PROGRESS_EVERY:
            last[0] = now
            print(f"    {label}: t = {t:.6g}, {stats.steps} steps, {now - start:.0f} s",
                  file=sys.stderr, flush=True)
    return progress


#: The temporary files of ``write_output`` (``.<name>.<random>.tmp``).
_STALE_TEMP = re.compile(r"\..+\.[A-Za-z0-9_]{8}\.tmp")


def _remove_stale_temporaries(out: Path, subdirs=()) -> None:
    """Delete what a killed call of ``all`` left half-written in ``out``.

    Outputs are written through a temporary file and ``os.replace``; SIGINT
    removes the temporary file, but SIGKILL (or a crash of the machine) can
    leave one behind.
    """
    for directory in (out, *(out / d for d in subdirs)):
        if directory.is_dir():
            for path in directory.iterdir():
                if _STALE_TEMP.fullmatch(path.name) and path.is_file():
                    try:
                        path.unlink()
                    except OSError:
                        pass


def _figures(args):
    from .figures import write_figures
    check_problem(args.problem)
    for option, t_end in (("--t-end", args.t_end), ("--long-t-end", args.long_t_end)):
        check_runs([args.problem], args.schemes, args.targets, t_end, option=option)
    out = out_dir(args.out)
    progress = Progress(checkpoint=opt.raise_if_interrupted)
    ctx = ProblemRuns(args.problem, args.schemes, args.targets, args.t_end, args.long_t_end,
                      progress=progress, compiled=args.compiled)
    written = write_figures(ctx, out)
    for _, path, _ in written:
        print(path)
    progress.say(f"{len(written)} figures of {args.problem} in {out}")


def _stability(args):
    from .stability import DEFAULT_RATIOS, write_stability
    out = out_dir(args.out)
    ratios = args.ratios or list(DEFAULT_RATIOS)
    done = write_stability(out, ratios, progress=Progress(checkpoint=opt.raise_if_interrupted),
                           schemes=args.schemes)
    print("Spectral radius ρ, period elongation PE and amplitude decay AD (Eqs. 29-33)\n")
    print(done["table"])
    print()
    for path in done["figures"].values():
        print(path)


def _all(args):
    for option, t_end in (("--t-end", args.t_end), ("--long-t-end", args.long_t_end)):
        check_runs(args.problems or names(), args.schemes, args.targets,
                    t_end, option=option)
    # after the checks: the figures import matplotlib (about a second)
    from .report import FIGURE_DIR, SettingsMismatch, run_all
    from .stability import DEFAULT_RATIOS
    # --dask: the extra and the scheduler are checked before --out is made
    with opt.runner_from_args(args) as runner:
        out = out_dir(args.out)
        _remove_stale_temporaries(out, [FIGURE_DIR])
        progress = Progress(checkpoint=opt.raise_if_interrupted)
        try:
            report = run_all(out, args.problems, args.schemes, args.targets, args.t_end,
                             args.long_t_end, args.ratios or list(DEFAULT_RATIOS), args.force,
                             progress, runner=runner, compiled=args.compiled)
        except SettingsMismatch as exc:
            raise UsageError(str(exc)) from None
    progress.say(f"done: {report}")
    print(report)


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with opt.watching_interrupts():
            status = _run(args)
    except BaseException as exc:
        if not opt.caused_by_interrupt(exc):
            raise
        status = None
    if status is None or opt.interrupted():
        # also when a library swallowed the KeyboardInterrupt and the command went on
        print("hfdi-validate: interrupted; outputs written so far are kept (a rerun of "
              "'all' resumes)", file=sys.stderr)
        return 130
    return status


def _run(args) -> int:
    try:
        if args.command == "table":
            _table(args)
        elif args.command == "models":
            _models(args)
        elif args.command == "figures":
            _figures(args)
        elif args.command == "stability":
            _stability(args)
        elif args.command == "all":
            _all(args)
    except (UsageError, IDAError, OSError, ValueError) as exc:
        if opt.caused_by_interrupt(exc):
            raise
        if isinstance(exc, UsageError):
            print(f"hfdi-validate: error: {exc}", file=sys.stderr)
            return 2
        if isinstance(exc, IDAError):
            print(f"hfdi-validate: error: reference solution failed: {exc}", file=sys.stderr)
            return 1
        # A file that cannot be written, or arguments the library refuses
        # (say --t-end below its smallest step): one line, no traceback.
        print(f"hfdi-validate: error: {exc}", file=sys.stderr)
        return 1
    return 0
