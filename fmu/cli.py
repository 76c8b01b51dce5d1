"""``hfdi-fmu``: build the FMUs and run the example master from the command line.

``python -m fmu build PROBLEM [--out DIR] [--fmi-version 2|3]``, ``python -m fmu build all``,
``python -m fmu list``, ``python -m fmu demo [PROBLEM]`` and ``python -m fmu master [FMU]``.
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
import zipfile
from pathlib import Path

__all__ = ["main", "build_parser"]


class _Parser(argparse.ArgumentParser):
    """Reports bad arguments in one line (no usage block), exit status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} -h)\n")


class _Refused(Exception):
    """An argument that parsed but cannot be used (one line on stderr, status 2)."""


def _out_dir(text) -> str:
    """The ``--out`` directory, created and tried with a file."""
    if not text.strip():
        raise _Refused("--out must name a directory, got ''")
    path = Path(text).expanduser()
    if path.exists() and not path.is_dir():
        raise _Refused(f"--out {text!r} exists and is not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):   # os.access says yes to root
            pass
    except OSError as exc:
        raise _Refused(f"--out {text!r} is not a writable directory: "
                       f"{exc.strerror or exc}") from None
    return str(path)


def _dumbbell_fmu(text) -> str:
    """An existing FMU of the dumbbell: the example master couples two of them
    and reads their variables by the dumbbell's names, so another model's FMU
    would run and print nonsense."""
    import xml.etree.ElementTree as ElementTree
    path = Path(text).expanduser()
    if not path.is_file():
        raise _Refused(f"FMU {text!r} does not exist or is not a file")
    try:
        with zipfile.ZipFile(path) as archive:
            description = ElementTree.fromstring(archive.read("modelDescription.xml"))
    except KeyError:
        raise _Refused(f"{text!r} is not an FMU: no modelDescription.xml in the archive") \
            from None
    except (OSError, zipfile.BadZipFile, ElementTree.ParseError) as exc:
        raise _Refused(f"{text!r} is not an FMU: {exc}") from None
    name = description.get("modelName")
    if name != "hfdi_dumbbell":
        raise _Refused(f"master couples two dumbbell FMUs (hfdi_dumbbell); {text!r} is "
                       f"the FMU of {name!r}")
    return str(path)


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
    parser = _Parser(
        prog="hfdi-fmu", description="FMI 2.0 and 3.0 co-simulation FMUs of hfdi's models.")
    sub = parser.add_subparsers(dest="command", required=True)
    build = sub.add_parser("build", help="build the FMU of a problem, or of all of them")
    build.add_argument("problem", help="a registered model (see 'list') or 'all'")
    build.add_argument("--out", default=".", metavar="DIR",
                       help="directory for hfdi_<problem>.fmu (FMI 3.0: "
                            "hfdi_<problem>_fmi3.fmu; default: the current one)")
    build.add_argument("--fmi-version", type=int, choices=(2, 3), default=2,
                       help="FMI version of the FMU (default 2)")
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
    return parser


def main(argv=None) -> int:
    """Entry point of ``hfdi-fmu`` and ``python -m fmu``; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        # inside the try: Ctrl-C during these imports (hfdi, numba) is an interrupt
        from .build import BuildError, build, build_all, problems
    except KeyboardInterrupt:
        return _interrupted()
    except ImportError as exc:
        if isinstance(exc.__cause__, KeyboardInterrupt):
            return _interrupted()       # Ctrl-C while a C extension initialised
        raise

    def check_problem(name, also=""):
        # before --out is created and before anything is imported or built
        if name not in problems():
            raise BuildError(f"unknown problem {name!r}; available: {', '.join(problems())}"
                             + also)

    try:
        if args.command == "list":
            print("\n".join(problems()))
        elif args.command == "build" and args.problem == "all":
            failed = 0
            for name, result in build_all(_out_dir(args.out), args.fmi_version).items():
                if isinstance(result, BuildError):
                    failed += 1
                    print(f"hfdi-fmu: error: {result}", file=sys.stderr)
                else:
                    print(result)
            return 1 if failed else 0
        elif args.command == "build":
            check_problem(args.problem, " (or 'all')")
            print(build(args.problem, _out_dir(args.out), args.fmi_version))
        elif args.command == "demo":
            check_problem(args.problem)
            from .demo import run_demo
            return run_demo(args.problem, _out_dir(args.out), args.scheme)
        elif args.command == "master":
            fmu = None if args.fmu is None else _dumbbell_fmu(args.fmu)
            from .master import run_example
            return run_example(fmu, args.t_end, args.step, args.stiffness, args.damping,
                               args.scheme)
    except (BuildError, _Refused) as exc:
        print(f"hfdi-fmu: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"hfdi-fmu: error: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:
        if isinstance(exc, ImportError) and isinstance(exc.__cause__, KeyboardInterrupt):
            return _interrupted()       # Ctrl-C while a C extension initialised
        from .master import CoSimulationError
        if not isinstance(exc, CoSimulationError):
            raise
        print(f"hfdi-fmu: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return _interrupted()
    return 0


def _interrupted() -> int:
    print("hfdi-fmu: interrupted", file=sys.stderr)
    return 130
