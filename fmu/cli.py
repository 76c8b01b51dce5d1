"""``hfdi-fmu``: build the FMUs and run the example master from the command line.

``python -m fmu build PROBLEM [--out DIR]``, ``python -m fmu build all``,
``python -m fmu list``, ``python -m fmu demo [PROBLEM]`` and ``python -m fmu master [FMU]``.
"""
from __future__ import annotations

import argparse
import math
import sys

__all__ = ["main", "build_parser"]


def _positive(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text!r}")
    return value


def _non_negative(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not (value >= 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return value


def build_parser():
    parser = argparse.ArgumentParser(
        prog="hfdi-fmu", description="FMI 2.0 co-simulation FMUs of hfdi's models.")
    sub = parser.add_subparsers(dest="command", required=True)
    build = sub.add_parser("build", help="build the FMU of a problem, or of all of them")
    build.add_argument("problem", help="a registered model (see 'list') or 'all'")
    build.add_argument("--out", default=".", metavar="DIR",
                       help="directory for hfdi_<problem>.fmu (default: the current one)")
    sub.add_parser("list", help="the problems an FMU can be built for")
    master = sub.add_parser("master", help="co-simulate two dumbbell FMUs coupled by a "
                                           "spring-damper (fmpy's low-level API)")
    master.add_argument("fmu", nargs="?", default=None,
                        help="a dumbbell FMU (default: built into a temporary directory)")
    master.add_argument("--t-end", type=_positive, default=0.5)
    master.add_argument("--step", type=_positive, default=0.002, help="communication step")
    master.add_argument("--stiffness", type=_non_negative, default=1e3)
    master.add_argument("--damping", type=_non_negative, default=0.0)
    master.add_argument("--scheme", choices=("newmark", "bathe", "hfdi"), default="hfdi")
    demo = sub.add_parser("demo", help="build a problem's FMU, co-simulate it with fmpy and "
                                       "compare with the library in-process")
    demo.add_argument("problem", nargs="?", default="dumbbell")
    demo.add_argument("--out", default="out/fmu", metavar="DIR")
    demo.add_argument("--scheme", choices=("newmark", "bathe", "hfdi"), default="hfdi")
    bench = sub.add_parser("bench", help="time the FMU through fmpy against in-process "
                                         "advance, communication step ≈ 10 internal steps")
    bench.add_argument("problem", nargs="?", default="dumbbell")
    bench.add_argument("--scheme", choices=("newmark", "bathe", "hfdi"), default="hfdi")
    bench.add_argument("--repeats", type=int, default=5)
    bench.add_argument("--json", metavar="FILE")
    return parser


def main(argv=None) -> int:
    """Entry point of ``hfdi-fmu`` and ``python -m fmu``; returns the exit status."""
    args = build_parser().parse_args(argv)
    from .build import BuildError, build, build_all, problems

    try:
        if args.command == "list":
            print("\n".join(problems()))
        elif args.command == "build" and args.problem == "all":
            failed = 0
            for name, result in build_all(args.out).items():
                if isinstance(result, BuildError):
                    failed += 1
                    print(f"hfdi-fmu: error: {result}", file=sys.stderr)
                else:
                    print(result)
            return 1 if failed else 0
        elif args.command == "build":
            print(build(args.problem, args.out))
        elif args.command == "bench":
            if args.problem not in problems():
                raise BuildError(f"unknown problem {args.problem!r}; available: "
                                 f"{', '.join(problems())}")
            from .bench import main as bench_main
            return bench_main(args.problem, args.scheme, max(1, args.repeats), args.json)
        elif args.command == "demo":
            from .demo import run_demo
            return run_demo(args.problem, args.out, args.scheme)
        elif args.command == "master":
            from .master import run_example
            return run_example(args.fmu, args.t_end, args.step, args.stiffness, args.damping,
                               args.scheme)
    except BuildError as exc:
        print(f"hfdi-fmu: error: {exc}", file=sys.stderr)
        return 2
    return 0
