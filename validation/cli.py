"""``hfdi-validate``: the paper's tables from the command line."""
from __future__ import annotations

import argparse
import json
import sys

import hfdi

from .tables import SCHEME_ORDER, format_table, problem_reference, records_to_csv, run_table


class _Exit(Exception):
    pass


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


def build_parser():
    parser = argparse.ArgumentParser(prog="hfdi-validate",
                                     description="Reproduce the paper's tables.")
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


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "table":
            _table(args)
        elif args.command == "models":
            _models(args)
    except _Exit as exc:
        print(f"hfdi-validate: error: {exc}", file=sys.stderr)
        return 2
    return 0
