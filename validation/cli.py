"""``hfdi-validate``: the paper's tables, figures and report from the command line."""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import hfdi

from .reference import IDAError
from .tables import SCHEME_ORDER, format_table, problem_reference, records_to_csv, run_table


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


def _targets(text):
    try:
        values = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"targets must be numbers, got {text!r}") from None
    if not values or any(not (v >= 1.0) or v != v or v == float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"targets must be finite numbers >= 1, got {text!r}")
    return values


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
    table = sub.add_parser("table", help="the paper's table for one problem")
    table.add_argument("problem", help=f"one of {', '.join(hfdi.models.available())}")
    table.add_argument("--schemes", type=_schemes, default=list(SCHEME_ORDER))
    table.add_argument("--targets", type=_targets, default=None,
                       help="target iteration counts (per sub-step for Bathe)")
    table.add_argument("--t-end", type=_positive, default=None, help="observation time T_o")
    table.add_argument("--json", metavar="FILE", help="write the runs as JSON records")
    table.add_argument("--csv", metavar="FILE", help="write the runs as CSV")
    table.add_argument("--no-eps", action="store_true",
                       help="skip the IDA reference and the error norms")
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
    if args.problem not in hfdi.models.available():
        raise _Exit(f"unknown problem {args.problem!r}; available: "
                    f"{', '.join(hfdi.models.available())}")

    def progress(record):
        print(f"  {record.scheme:8s} N̄={record.target:<4} steps={record.steps:<6d} "
              f"{record.status}", file=sys.stderr, flush=True)

    def say(text):
        print(f"  {text}", file=sys.stderr, flush=True)

    reference = None if args.no_eps else problem_reference(args.problem, args.t_end,
                                                               progress=say)
    records = run_table(args.problem, args.schemes, args.targets, args.t_end, progress=progress,
                        reference=reference)
    print(f"{args.problem}: computational characteristics "
          f"(ours, with the paper's beneath)\n")
    print(format_table(records))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump([r.as_dict() for r in records], fh, indent=1)
    if args.csv:
        records_to_csv(records, args.csv)


def _out_dir(text) -> Path:
    """The ``--out`` directory, created; a clear error when it cannot be."""
    path = Path(text).expanduser()
    if path.exists() and not path.is_dir():
        raise _Exit(f"--out {text!r} exists and is not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _Exit(f"cannot create --out {text!r}: {exc.strerror or exc}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise _Exit(f"--out {text!r} is not writable")
    return path


def _check_problem(name):
    if name not in hfdi.models.available():
        raise _Exit(f"unknown problem {name!r}; available: "
                    f"{', '.join(hfdi.models.available())}")


def _figures(args):
    from .figures import Progress, ProblemRuns, write_figures
    _check_problem(args.problem)
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
    from .report import SettingsMismatch, run_all
    from .stability import DEFAULT_RATIOS
    out = _out_dir(args.out)
    progress = Progress()
    try:
        report = run_all(out, args.problems, args.schemes, args.targets, args.t_end,
                         args.long_t_end, args.ratios or list(DEFAULT_RATIOS), args.force,
                         progress)
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
    except _Exit as exc:
        print(f"hfdi-validate: error: {exc}", file=sys.stderr)
        return 2
    except IDAError as exc:
        print(f"hfdi-validate: error: reference solution failed: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("hfdi-validate: interrupted; outputs written so far are kept (a rerun of "
              "'all' resumes)", file=sys.stderr)
        return 130
    return 0
