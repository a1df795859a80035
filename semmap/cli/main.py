"""``semmap`` entry point: sub-commands, logging, and error → exit-code mapping.

Errors a user can cause (:class:`~semmap.errors.SemmapError`) print one line and
exit non-zero; ``--debug`` shows the traceback of any error.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence

from .. import __version__
from ..errors import SemmapError
from . import build as build_cmd
from . import calibrate as calibrate_cmd
from . import evalseg as evalseg_cmd
from . import info as info_cmd
from . import paint as paint_cmd
from . import segment as segment_cmd
from . import simulate as simulate_cmd

EXIT_INTERNAL = 70
EXIT_INTERRUPTED = 130

COMMANDS = (build_cmd, simulate_cmd, info_cmd, calibrate_cmd, segment_cmd, evalseg_cmd, paint_cmd)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="semmap",
        description="Semantic, cleaned 2D occupancy maps from recorded robot tours "
                    "(2D LiDAR + RGB camera + wheel odometry, ROS1/ROS2 bags).",
    )
    parser.add_argument("--version", action="version", version=f"semmap {__version__}")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    common.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    common.add_argument("-q", "--quiet", action="store_true", help="no progress bars or summaries")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for cmd in COMMANDS:
        cmd.add_parser(sub, common)
    return parser


def _setup_logging(verbose: int) -> None:
    level = logging.WARNING if verbose == 0 else logging.INFO if verbose == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)  # exits 2 with a usage line on bad arguments
    _setup_logging(args.verbose)
    try:
        return int(args.run(args) or 0)
    except SemmapError as exc:
        if args.debug:
            raise
        print(f"semmap {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except OSError as exc:  # unwritable output, full disk...: the message names the path
        if args.debug:
            raise
        print(f"semmap {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"semmap {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:  # noqa: BLE001 - a bug; keep the user's terminal clean unless --debug
        if args.debug:
            raise
        print(f"semmap {args.command}: internal error: {type(exc).__name__}: {exc} "
              f"(run again with --debug for the traceback, and please report it)", file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
