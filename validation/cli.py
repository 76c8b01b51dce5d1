"""``hfdi-validate``: the paper's tables, figures and report from the command line."""
from __future__ import annotations

import argparse
import json
import os
import re
import sys
import tempfile
from pathlib import Path

import hfdi

from . import parallel
from .atomic import write_atomic
from .bench import add_bench_parser, run_bench_command
from .reference import IDAError
from .tables import SCHEME_ORDER, format_table, records_to_csv, run_tables


class _Exit(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    """Reports bad arguments in one line (no usage block), exit status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} -h)\n")


def _schemes(text):
    names = [s.strip().lower() for s in text.split(",") if s.strip()]
    bad = [s for s in names if s not in SCHEME_ORDER]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"unknown scheme(s) {', '.join(bad) or text!r}; choose from {', '.join(SCHEME_ORDER)}")
    return names


#: Largest target iteration count accepted. The corrector of a step may take
#: ``2 N̄`` corrections and the first step is bracketed with up to 40 trials, so
#: the cost grows with ``N̄``: 1e4 takes seconds on the dumbbell and 1e300 never
#: ends. The paper's targets are 3 to 5.
MAX_TARGET = 100.0


def _targets(text):
    try:
        values = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"targets must be numbers, got {text!r}") from None
    if not values or any(not (1.0 <= v <= MAX_TARGET) for v in values):
        raise argparse.ArgumentTypeError(f"targets must be numbers in [1, {MAX_TARGET:g}], "
                                         f"got {text!r}")
    return values


def _rtols(text):
    low, high = hfdi.controller.RTOL_RANGE
    try:
        values = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"rtol must be numbers, got {text!r}") from None
    if not values or any(not (low <= v < high) for v in values):
        raise argparse.ArgumentTypeError(f"rtol must be numbers in [{low:g}, {high:g}), "
                                         f"got {text!r}")
    return sorted(set(values), reverse=True)


def _output_file(text):
    """A file the command will write at the end: checked now, not after the runs."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must be a file name, got ''")
    path = Path(text).expanduser()
    parent = path.parent
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a directory")
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{str(parent)!r} " + ("is not a directory"
                                         if parent.exists() else "does not exist"))
    try:
        # a file made and removed: os.access says yes to root, and to read-only mounts
        with tempfile.TemporaryFile(dir=parent):
            pass
    except OSError:
        raise argparse.ArgumentTypeError(f"{text!r} is not writable") from None
    if path.exists() and not os.access(path, os.W_OK):
        raise argparse.ArgumentTypeError(f"{text!r} is not writable")
    return str(path)


def _positive(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not (value > 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text!r}")
    return value


def _ratios(text):
    try:
        values = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"ratios must be numbers, got {text!r}") from None
    if not values or any(not (0 < v < float("inf")) for v in values):
        raise argparse.ArgumentTypeError(f"ratios Δt/T must be positive finite numbers, "
                                         f"got {text!r}")
    return values


def _problems(text):
    names = [s.strip() for s in text.split(",") if s.strip()]
    available = hfdi.models.available()
    bad = [s for s in names if s not in available]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"unknown problem(s) {', '.join(map(repr, bad)) or repr(text)}; "
            f"available: {', '.join(available)}")
    return list(dict.fromkeys(names))


def _run_options(parser):
    """The options that choose the runs of ``figures`` and ``all``."""
    parser.add_argument("--schemes", type=_schemes, default=list(SCHEME_ORDER),
                        help="schemes of the table runs (default: all three)")
    parser.add_argument("--targets", type=_targets, default=None,
                        help="target iteration counts of the table runs, for every scheme "
                             "(default: the paper's per scheme)")
    parser.add_argument("--t-end", type=_positive, default=None,
                        help="end time of the runs and of the reference (default: T_o)")
    parser.add_argument("--long-t-end", type=_positive, default=None,
                        help="end time of the long energy runs of Figs. 7 and 18 (default: "
                             "--t-end when given, else the paper's 10 and 3)")


def build_parser():
    parser = _Parser(prog="hfdi-validate",
                     description="Reproduce the paper's tables and figures.")
    sub = parser.add_subparsers(dest="command", required=True)
    table = sub.add_parser("table", help="the paper's table for one problem, or several "
                                         "(comma-separated)")
    table.add_argument("problem", help=f"one of {', '.join(hfdi.models.available())}, or "
                                       "several, comma-separated")
    table.add_argument("--schemes", type=_schemes, default=list(SCHEME_ORDER))
    table.add_argument("--targets", type=_targets, default=None,
                       help="target iteration counts (per sub-step for Bathe)")
    table.add_argument("--rtol", type=_rtols, default=None, metavar="R[,R...]",
                       help="error-controlled runs at these relative tolerances instead of "
                            "the paper's targets (with --targets: both rules combined)")
    table.add_argument("--t-end", type=_positive, default=None, help="observation time T_o")
    table.add_argument("--json", metavar="FILE", type=_output_file,
                       help="write the runs as JSON records")
    table.add_argument("--csv", metavar="FILE", type=_output_file,
                       help="write the runs as CSV")
    table.add_argument("--no-eps", action="store_true",
                       help="skip the IDA reference and the error norms")
    parallel.add_options(table)
    sub.add_parser("models", help="list the models, their parameters, T_o and the paper's targets")
    figures = sub.add_parser("figures", help="the paper's figures of one problem as PNG files")
    figures.add_argument("problem", help=f"one of {', '.join(hfdi.models.available())}")
    figures.add_argument("--out", required=True, metavar="DIR", help="output directory")
    _run_options(figures)
    stability = sub.add_parser("stability", help="spectral radius, period elongation and "
                                                 "amplitude decay of the schemes (Figs. 1-2)")
    stability.add_argument("--out", required=True, metavar="DIR", help="output directory")
    stability.add_argument("--ratios", type=_ratios, default=None,
                           help="Δt/T of the printed table, comma-separated "
                                "(default: 0.01,0.05,0.1,0.2,0.5,1,10)")
    every = sub.add_parser("all", help="every table, figure and the stability curves, with "
                                       "DIR/report.md; resumes an interrupted call")
    every.add_argument("--out", required=True, metavar="DIR", help="output directory")
    every.add_argument("--problems", type=_problems, default=None,
                       help="comma-separated problems (default: all four)")
    _run_options(every)
    every.add_argument("--ratios", type=_ratios, default=None,
                       help="Δt/T of the stability table")
    every.add_argument("--force", action="store_true",
                       help="redo outputs that already exist (default: skip them)")
    parallel.add_options(every)
    add_bench_parser(sub)
    return parser


def _models(args):
    for name in hfdi.models.available():
        model = hfdi.models.get(name)
        print(f"{name}  (N = {model.n_dof}, T_o = {model.observation_time:g})")
        targets = "; ".join(f"{s} {', '.join(format(t, 'g') for t in ts)}"
                            for s, ts in model.paper_targets.items())
        print(f"  paper's targets: {targets}")
        for key, value in hfdi.models.describe(name).items():
            print(f"  {key} = {value!r}")


def _table(args):
    problems = list(dict.fromkeys(s.strip() for s in args.problem.split(",") if s.strip()))
    for name in problems or [args.problem]:
        _check_problem(name)
    _check_runs(problems, args.schemes, args.targets, args.t_end, args.rtol)
    several = len(problems) > 1

    def progress(record):
        where = f"{record.problem:11s} " if several else ""
        setting = " ".join(([f"N̄={record.target:g}"] if record.target is not None else [])
                           + ([f"rtol={record.rtol:.0e}"] if record.rtol is not None else []))
        print(f"  {where}{record.scheme:8s} {setting:<7} steps={record.steps:<6d} "
              f"{record.status}", file=sys.stderr, flush=True)

    def say(text):
        print(f"  {text}", file=sys.stderr, flush=True)

    with parallel.runner_from_args(args) as runner:
        tables = run_tables(problems, args.schemes, args.targets, args.t_end,
                            eps=not args.no_eps, runner=runner, progress=progress, say=say,
                            rtols=args.rtol, run_progress=_run_progress)
    records = []
    for problem in problems:
        print(f"{problem}: computational characteristics "
              f"(ours, with the paper's beneath)\n")
        print(format_table(tables[problem]))
        records += tables[problem]
    if args.json:
        # atomic: a full disk or a kill leaves the previous file, not half of one
        write_atomic(args.json, json.dumps([r.as_dict() for r in records], indent=1).encode())
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


def _out_dir(text) -> Path:
    """The ``--out`` directory, created; a clear error when it cannot be."""
    if not text.strip():
        # Path("") is the current directory: an empty --out (an unset shell
        # variable) would scatter the outputs there.
        raise _Exit("--out must name a directory, got ''")
    path = Path(text).expanduser()
    if path.exists() and not path.is_dir():
        raise _Exit(f"--out {text!r} exists and is not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _Exit(f"cannot create --out {text!r}: {exc.strerror or exc}") from None
    # Try a file: os.access says yes to root, and to read-only mounts.
    try:
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError:
        raise _Exit(f"--out {text!r} is not writable") from None
    return path


#: The temporary files of ``write_atomic`` (``.<name>.<random>.tmp``).
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


def _check_problem(name):
    if name not in hfdi.models.available():
        raise _Exit(f"unknown problem {name!r}; available: "
                    f"{', '.join(hfdi.models.available())}")


#: The longest --t-end accepted, in multiples of a model's longest observation time.
LONGEST_RUN = 10.0


def _check_runs(problems, schemes, targets, t_end, rtols=None, option="--t-end"):
    """Let the library refuse the run settings (say a --t-end below its
    smallest step) before the reference and the runs take their time."""
    for name in problems:
        model = hfdi.models.get(name)
        longest = LONGEST_RUN * max(model.observation_time,
                                    getattr(model, "long_observation_time", None) or 0.0)
        if t_end is not None and t_end > longest:
            # the IDA reference (rtol 1e-12, every step kept) grows with t_end:
            # 1e300 ran without end, memory growing
            raise _Exit(f"{option} = {t_end:g} is too long for {name}: at most {longest:g} "
                        f"({LONGEST_RUN:g} times its longest observation time)")
        for scheme in schemes:
            for target in targets or ([None] if rtols else
                                      model.paper_targets.get(scheme) or [3.0]):
                for rtol in rtols or [None]:
                    try:
                        hfdi.Integrator(model, scheme, target_iterations=target, rtol=rtol,
                                        t_bound=t_end or model.observation_time)
                    except ValueError as exc:
                        setting = ", ".join(f"{k} = {v:g}" for k, v in
                                            (("N̄", target), ("rtol", rtol)) if v is not None)
                        raise _Exit(f"cannot run {name} to t = "
                                    f"{t_end or model.observation_time:g} ({scheme}, "
                                    f"{setting}): {exc}") from None


def _figures(args):
    from .figures import Progress, ProblemRuns, write_figures
    _check_problem(args.problem)
    for option, t_end in (("--t-end", args.t_end), ("--long-t-end", args.long_t_end)):
        _check_runs([args.problem], args.schemes, args.targets, t_end, option=option)
    out = _out_dir(args.out)
    progress = Progress()
    ctx = ProblemRuns(args.problem, args.schemes, args.targets, args.t_end, args.long_t_end,
                      progress=progress)
    written = write_figures(ctx, out)
    for _, path, _ in written:
        print(path)
    progress.say(f"{len(written)} figures of {args.problem} in {out}")


def _stability(args):
    from .figures import Progress
    from .stability import DEFAULT_RATIOS, write_stability
    out = _out_dir(args.out)
    ratios = args.ratios or list(DEFAULT_RATIOS)
    done = write_stability(out, ratios, progress=Progress())
    print("Spectral radius ρ, period elongation PE and amplitude decay AD (Eqs. 29-33)\n")
    print(done["table"])
    print()
    for path in done["figures"].values():
        print(path)


def _all(args):
    from .figures import Progress
    from .report import FIGURE_DIR, SettingsMismatch, run_all
    from .stability import DEFAULT_RATIOS
    for option, t_end in (("--t-end", args.t_end), ("--long-t-end", args.long_t_end)):
        _check_runs(args.problems or hfdi.models.available(), args.schemes, args.targets,
                    t_end, option=option)
    # --dask: the extra and the scheduler are checked before --out is made
    with parallel.runner_from_args(args) as runner:
        out = _out_dir(args.out)
        _remove_stale_temporaries(out, [FIGURE_DIR])
        progress = Progress()
        try:
            report = run_all(out, args.problems, args.schemes, args.targets, args.t_end,
                             args.long_t_end, args.ratios or list(DEFAULT_RATIOS), args.force,
                             progress, runner=runner)
        except SettingsMismatch as exc:
            raise _Exit(str(exc)) from None
    progress.say(f"done: {report}")
    print(report)


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
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
        elif args.command == "bench":
            run_bench_command(args)
    except _Exit as exc:
        print(f"hfdi-validate: error: {exc}", file=sys.stderr)
        return 2
    except IDAError as exc:
        print(f"hfdi-validate: error: reference solution failed: {exc}", file=sys.stderr)
        return 1
    except (OSError, ValueError) as exc:
        # A file that cannot be written, or arguments the library refuses
        # (say --t-end below its smallest step): one line, no traceback.
        print(f"hfdi-validate: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("hfdi-validate: interrupted; outputs written so far are kept (a rerun of "
              "'all' resumes)", file=sys.stderr)
        return 130
    return 0
