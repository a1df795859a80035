import sys

try:
    from semmap.cli.main import main
except KeyboardInterrupt:  # Ctrl-C while Python loads semmap: one line, no traceback
    print("semmap: interrupted (SIGINT)", file=sys.stderr)
    raise SystemExit(130) from None

raise SystemExit(main())
