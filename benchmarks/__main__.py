"""``python -m benchmarks COMMAND [...]``: see :mod:`benchmarks`."""
import sys

from validation.options import UsageError, caused_by_interrupt, interrupted, watching_interrupts

COMMANDS = ("precision", "scale", "profile", "cosim", "proportionality")
USAGE = f"usage: python -m benchmarks {{{','.join(COMMANDS)}}} [-h] [...]"


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:
        print(f"python -m benchmarks: error: a command is required, one of "
              f"{', '.join(COMMANDS)} (see python -m benchmarks -h)", file=sys.stderr)
        return 2
    if argv[0] in ("-h", "--help"):
        print(USAGE + "\n\n" + (__import__("benchmarks").__doc__ or ""))
        return 0
    command, rest = argv[0], argv[1:]
    if command not in COMMANDS:
        print(f"python -m benchmarks: error: unknown command {command!r}; choose from "
              f"{', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    try:
        with watching_interrupts():
            status = _run(command, argv, rest)
        # a Ctrl-C that a library swallowed: the command went on, but was
        # interrupted (130 already: the command said so itself)
        return _interrupted(command) if interrupted() and status != 130 else status
    except (UsageError, OSError, ValueError) as exc:
        if caused_by_interrupt(exc) or interrupted():
            return _interrupted(command)
        print(f"python -m benchmarks {command}: error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, UsageError) else 1
    except BaseException as exc:
        # Ctrl-C, also when it arrived inside an import and came out as an
        # ImportError, or inside an FMU, which turns it into an error status
        # (fmpy's FMICallException)
        if not (caused_by_interrupt(exc) or interrupted()):
            raise
        return _interrupted(command)


def _run(command, argv, rest) -> int:
    if command == "precision":
        from validation.options import Parser
        from .precision import add_parser, run_command
        parser = Parser(prog="python -m benchmarks")
        add_parser(parser.add_subparsers(dest="command", required=True))
        return run_command(parser.parse_args(argv))
    module = __import__(f"benchmarks.{command}", fromlist=["main"])
    return module.main(rest)


def _interrupted(command) -> int:
    print(f"python -m benchmarks {command}: interrupted", file=sys.stderr)
    return 130


if __name__ == "__main__":
    sys.exit(main())
