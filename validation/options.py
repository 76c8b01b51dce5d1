"""The command-line argument types and checks of ``hfdi-validate`` and ``benchmarks``.

Each type raises ``argparse.ArgumentTypeError`` with a message naming the
allowed values, which :class:`Parser` prints in one line (exit status 2);
the checks made after parsing raise :class:`UsageError`, reported the same way.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import signal
import tempfile
import threading
from pathlib import Path

import hfdi

from .experiments import SCHEME_ORDER, experiment, names

__all__ = ["Parser", "UsageError", "schemes", "targets", "rtols", "positive", "ratios",
           "problems", "positive_integer", "job_count", "numbers", "output_file", "out_dir",
           "check_problem", "check_runs", "add_parallel_options", "runner_from_args",
           "LONGEST_RUN", "caused_by_interrupt", "watching_interrupts", "interrupted",
           "raise_if_interrupted"]


class UsageError(Exception):
    """Settings refused after parsing; the command line prints it in one line (exit 2)."""


def caused_by_interrupt(exc: BaseException) -> bool:
    """Whether Ctrl-C is behind ``exc``, itself or anywhere in its chain.

    A ``KeyboardInterrupt`` that arrives while a C extension initialises (the
    first figure importing matplotlib's Agg backend, say) comes out as an
    ``ImportError`` whose cause is the interrupt; the command lines treat it
    as the interrupt it is (exit status 130), not as a failure.
    """
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


#: Set by the SIGINT handler of :func:`watching_interrupts`.
_interrupt_seen = False


def _on_sigint(signum, frame):
    global _interrupt_seen
    _interrupt_seen = True
    raise KeyboardInterrupt


@contextlib.contextmanager
def watching_interrupts():
    """Remember every Ctrl-C within, so that one a library swallows still ends the command.

    A ``KeyboardInterrupt`` raised while a C extension is imported comes out
    as an ``ImportError``, and an optional import guarded by ``except
    ImportError`` (matplotlib's, say) drops it: the command would go on and
    exit 0. Within this block SIGINT raises ``KeyboardInterrupt`` as Python's
    own handler does and is recorded; :func:`raise_if_interrupted` raises it
    again at the next output, and :func:`interrupted` tells ``main`` to exit
    130. A SIGINT that is ignored (a background job of a non-interactive
    shell) stays ignored; outside the main thread nothing is installed.
    """
    global _interrupt_seen
    _interrupt_seen = False
    install = (threading.current_thread() is threading.main_thread()
               and signal.getsignal(signal.SIGINT) is signal.default_int_handler)
    if install:
        signal.signal(signal.SIGINT, _on_sigint)
    try:
        yield
    finally:
        if install:
            signal.signal(signal.SIGINT, signal.default_int_handler)


def interrupted() -> bool:
    """Whether a Ctrl-C came within the last :func:`watching_interrupts` block."""
    return _interrupt_seen


def raise_if_interrupted() -> None:
    """Raise ``KeyboardInterrupt`` if a Ctrl-C came and was swallowed."""
    if _interrupt_seen:
        raise KeyboardInterrupt


class Parser(argparse.ArgumentParser):
    """Reports bad arguments in one line (no usage block), exit status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} -h)\n")


def numbers(text, what, low=-float("inf"), high=float("inf"), high_open=False) -> list:
    """Comma-separated numbers in ``[low, high]`` (``[low, high)`` with ``high_open``)."""
    try:
        values = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what} must be numbers, got {text!r}") from None
    inside = (lambda v: low <= v < high) if high_open else (lambda v: low <= v <= high)
    if not values or not all(inside(v) for v in values):
        raise argparse.ArgumentTypeError(
            f"{what} must be numbers in [{low:g}, {high:g}{')' if high_open else ']'}, "
            f"got {text!r}")
    return values


def names_from(text, allowed, what, lower=True, also="") -> list:
    """Comma-separated names, each one of ``allowed`` (in the order given,
    without repeats); ``what`` names them in the message (``"scheme(s)"``),
    ``also`` adds to the list of choices (``" (or none)"``)."""
    items = [s.strip().lower() if lower else s.strip() for s in text.split(",") if s.strip()]
    bad = [s for s in items if s not in allowed]
    if bad or not items:
        raise argparse.ArgumentTypeError(
            f"unknown {what} {', '.join(map(repr, bad)) or repr(text)}; "
            f"choose from {', '.join(allowed)}{also}")
    return list(dict.fromkeys(items))


def schemes(text) -> list:
    """Scheme names of :data:`hfdi.SCHEMES` (the paper's three and
    generalized-α), comma-separated."""
    return names_from(text, SCHEME_ORDER, "scheme(s)")


def targets(text) -> list:
    """Target iteration counts in :data:`hfdi.controller.TARGET_ITERATIONS_RANGE`.

    The corrector of a step may take ``2 N̄`` corrections and the first step
    is bracketed with up to 40 trials, so the cost grows with ``N̄``; the
    paper's targets are 3 to 5.
    """
    return numbers(text, "targets", *hfdi.controller.TARGET_ITERATIONS_RANGE)


def rtols(text) -> list:
    """Relative tolerances in :data:`hfdi.controller.RTOL_RANGE`, loosest first."""
    values = numbers(text, "rtol", *hfdi.controller.RTOL_RANGE, high_open=True)
    return sorted(set(values), reverse=True)


def single(parse, what):
    """The parser of one value of a list option's ``parse`` (a list given
    where one value is taken is refused, not cut to its first value)."""
    def one(text):
        values = parse(text)
        if len(values) != 1:
            raise argparse.ArgumentTypeError(f"one {what} is taken here, got {text!r}")
        return values[0]
    return one


def positive(text) -> float:
    """A positive finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not (value > 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text!r}")
    return value


def ratios(text) -> list:
    """Ratios Δt/T in ``hfdi.spectral.RATIO_RANGE``, comma-separated."""
    low, high = hfdi.spectral.RATIO_RANGE
    try:
        values = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"ratios must be numbers, got {text!r}") from None
    if not values or any(not (low <= v <= high) for v in values):
        raise argparse.ArgumentTypeError(f"ratios Δt/T must be numbers in [{low:g}, {high:g}] "
                                         f"(outside, rounding outweighs the measures), "
                                         f"got {text!r}")
    return values


def problems(text) -> list:
    """Benchmarks of :mod:`validation.experiments`, comma-separated."""
    return names_from(text, names(), "problem(s)", lower=False)


def positive_integer(text) -> int:
    """An integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}")
    return value


def integer_in(text, low: int, high: int, why: str = "") -> int:
    """An integer in ``[low, high]`` (``why``: the bound's reason, in the message)."""
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or not low <= value <= high:
        raise argparse.ArgumentTypeError(f"must be an integer in [{low}, {high}]"
                                         f"{f' ({why})' if why else ''}, got {text!r}")
    return value


#: The most repetitions of a measured run a command takes.
MAX_REPEATS = 1000


def repeats(text) -> int:
    """An integer in ``[1, MAX_REPEATS]``: repetitions of a measured run (the
    best kept); more only multiplies the time a command takes."""
    return integer_in(text, 1, MAX_REPEATS)


def job_count(text) -> int:
    """An integer in ``[1, validation.parallel.max_jobs()]``."""
    from .parallel import max_jobs
    return integer_in(text, 1, max_jobs(), "four worker processes per CPU")


def output_file(text) -> str:
    """A file the command will write at the end: checked now, not after the runs.

    A symbolic link is checked as the file it points to (the output is
    written there, hfdi.files.write_output); a FIFO or a character device
    (``/dev/null``) is written to as it is and must be writable; a socket or
    a block device is refused."""
    import stat
    if not text.strip():
        raise argparse.ArgumentTypeError("must be a file name, got ''")
    path = Path(text).expanduser()
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a directory")
    try:
        mode = path.stat().st_mode
    except (FileNotFoundError, NotADirectoryError):
        mode = None                         # a new file (the folder is checked below)
    except OSError as exc:                  # a loop of links, a folder without access
        raise argparse.ArgumentTypeError(f"{text!r} cannot be written: "
                                         f"{exc.strerror or exc}") from None
    if mode is not None and (stat.S_ISFIFO(mode) or stat.S_ISCHR(mode)):
        if not os.access(path, os.W_OK):
            raise argparse.ArgumentTypeError(f"{text!r} is not writable")
        return str(path)
    if mode is not None and not stat.S_ISREG(mode):
        kind = "a socket" if stat.S_ISSOCK(mode) else \
            "a block device" if stat.S_ISBLK(mode) else "not a regular file"
        raise argparse.ArgumentTypeError(f"{text!r} is {kind}, not a file to write to")
    parent = (Path(os.path.realpath(path)) if path.is_symlink() else path).parent
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


def out_dir(text) -> Path:
    """The ``--out`` directory, created; :class:`UsageError` when it cannot be."""
    if not text.strip():
        # Path("") is the current directory: an empty --out (an unset shell
        # variable) would scatter the outputs there.
        raise UsageError("--out must name a directory, got ''")
    path = Path(text).expanduser()
    if path.exists() and not path.is_dir():
        raise UsageError(f"--out {text!r} exists and is not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"cannot create --out {text!r}: {exc.strerror or exc}") from None
    try:
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError:
        raise UsageError(f"--out {text!r} is not writable") from None
    return path


def check_problem(name) -> None:
    """:class:`UsageError` unless ``name`` is a benchmark."""
    if name not in names():
        raise UsageError(f"unknown problem {name!r}; available: {', '.join(names())}")


#: The longest --t-end accepted, in multiples of a benchmark's longest observation time.
LONGEST_RUN = 10.0


def longest_run(name) -> float:
    """The longest ``--t-end`` accepted for the benchmark ``name``."""
    return LONGEST_RUN * experiment(name).long_time


def check_runs(problem_names, scheme_names, target_values, t_end, rtol_values=None,
               option="--t-end") -> None:
    """Let the library refuse the run settings (say a ``--t-end`` below its
    smallest step) before the reference and the runs take their time;
    :class:`UsageError` naming the setting otherwise."""
    for name in problem_names:
        exp = experiment(name)
        model = exp.model()
        longest = longest_run(name)
        if t_end is not None and t_end > longest:
            # the IDA reference (rtol 1e-12, every step kept) grows with t_end:
            # 1e300 ran without end, memory growing
            raise UsageError(f"{option} = {t_end:g} is too long for {name}: at most "
                             f"{longest:g} ({LONGEST_RUN:g} times its longest observation "
                             "time)")
        for scheme in scheme_names:
            for target in target_values or ([None] if rtol_values else
                                            exp.table_targets(scheme)):
                for rtol in rtol_values or [None]:
                    try:
                        # the library's checks of the settings only: no compiled
                        # code is loaded (or compiled) for them
                        hfdi.Integrator(model, scheme, target_iterations=target, rtol=rtol,
                                        t_bound=t_end or exp.observation_time, compiled=False)
                    except ValueError as exc:
                        setting = ", ".join(f"{k} = {v:g}" for k, v in
                                            (("N̄", target), ("rtol", rtol)) if v is not None)
                        raise UsageError(f"cannot run {name} to t = "
                                         f"{t_end or exp.observation_time:g} ({scheme}, "
                                         f"{setting}): {exc}") from None


def _address(text):
    if not text.strip():
        raise argparse.ArgumentTypeError("must be a scheduler address "
                                         "(e.g. tcp://host:8786), got ''")
    return text.strip()


def add_parallel_options(parser) -> None:
    """Add ``--jobs N`` and ``--dask ADDRESS`` to a sub-command's parser."""
    parser.add_argument("--jobs", type=job_count, default=1, metavar="N",
                        help="worker processes on this machine (default 1: this process; "
                             "at most four per CPU)")
    parser.add_argument("--dask", metavar="ADDRESS", type=_address, default=None,
                        help="run the tasks on an existing Dask distributed cluster "
                             "(scheduler address, e.g. tcp://host:8786; extra 'dask'); "
                             "overrides --jobs")


def runner_from_args(args):
    """The :class:`validation.parallel.Runner` of parsed ``--jobs``/``--dask``."""
    from .parallel import Runner
    return Runner(getattr(args, "jobs", 1), getattr(args, "dask", None))
