"""``python -m benchmarks COMMAND [...]``: see :mod:`benchmarks`."""
import sys

from validation.options import UsageError

COMMANDS = ("precision", "scale", "profile", "cosim")
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
        if command == "precision":
            from validation.options import Parser
            from .precision import add_parser, run_command
            parser = Parser(prog="python -m benchmarks")
            add_parser(parser.add_subparsers(dest="command", required=True))
            return run_command(parser.parse_args(argv))
        module = __import__(f"benchmarks.{command}", fromlist=["main"])
        return module.main(rest)
    except UsageError as exc:
        print(f"python -m benchmarks {command}: error: {exc}", file=sys.stderr)
        return 2
    except (OSError, ValueError) as exc:
        print(f"python -m benchmarks {command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"python -m benchmarks {command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
