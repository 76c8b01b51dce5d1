import sys

try:
    from .cli import main
except KeyboardInterrupt:      # Ctrl-C while the libraries are still being imported
    print("hfdi-validate: interrupted", file=sys.stderr)
    raise SystemExit(130) from None

raise SystemExit(main())
