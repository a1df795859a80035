"""``semmap`` entry point: sub-commands, logging, and error → exit-code mapping.

Errors a user can cause (:class:`~semmap.errors.SemmapError`) print one line and
exit non-zero; ``--debug`` shows the traceback of any error.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path

from ..errors import InternalError, Interrupted, SemmapError
from ..io.atomic import COMMITTED
from ..runtime import forget_stops, note_stop
from ..version import __version__
from . import batch as batch_cmd
from . import build as build_cmd
from . import calibrate as calibrate_cmd
from . import diff as diff_cmd
from . import evalseg as evalseg_cmd
from . import evaltraj as evaltraj_cmd
from . import export as export_cmd
from . import importlog as import_cmd
from . import info as info_cmd
from . import paint as paint_cmd
from . import segment as segment_cmd
from . import simulate as simulate_cmd

EXIT_INTERNAL = 70

COMMANDS = (build_cmd, diff_cmd, batch_cmd, export_cmd, import_cmd, simulate_cmd, info_cmd, calibrate_cmd, segment_cmd,
            evalseg_cmd, evaltraj_cmd, paint_cmd)


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
    """``-v``: semmap's info lines; ``-vv``: semmap's debug lines; ``-vvv``: every library's too.
    Other libraries (matplotlib's font search, numba...) say only their warnings before that."""
    level = logging.WARNING if verbose == 0 else logging.INFO if verbose == 1 else logging.DEBUG
    root = logging.getLogger()
    for h in [h for h in root.handlers if getattr(h, "semmap_cli", False)]:  # main() run again in one process
        root.removeHandler(h)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    handler.semmap_cli = True  # type: ignore[attr-defined]
    root.addHandler(handler)
    root.setLevel(logging.DEBUG if verbose >= 3 else logging.WARNING)
    logging.getLogger("semmap").setLevel(level)


def _quiet_unraisable(unraisable: sys.UnraisableHookArgs) -> None:
    """After a stop signal: what a half-built object's ``__del__`` raises while the stack unwinds (a
    ``ZipFile`` cut short inside ``np.savez``) is logged at debug level, not printed as a traceback."""
    logging.getLogger("semmap").debug("while stopping, ignored in %r: %s", unraisable.object, unraisable.exc_value)


def _raise_interrupted(signum: int, frame: object) -> None:
    sys.unraisablehook = _quiet_unraisable
    note_stop(signum)
    raise Interrupted(signum)


def _raise_keyboard_interrupt(signum: int, frame: object) -> None:
    sys.unraisablehook = _quiet_unraisable
    note_stop(signum)
    raise KeyboardInterrupt


@contextlib.contextmanager
def _stop_signals_raise() -> Iterator[None]:
    """SIGTERM and SIGHUP (``kill``, ``timeout``, ``docker stop``, a closed terminal) raise
    :class:`~semmap.errors.Interrupted`, as Ctrl-C raises KeyboardInterrupt, so that workers,
    shared memory and partial output are cleaned up on the way out."""
    names = ("SIGTERM", "SIGHUP")
    old = {}
    if threading.current_thread() is threading.main_thread():
        for name in names:
            sig = getattr(signal, name, None)
            if sig is not None:
                old[sig] = signal.signal(sig, _raise_interrupted)
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # Ctrl-C: KeyboardInterrupt, as ever
            old[signal.SIGINT] = signal.signal(signal.SIGINT, _raise_keyboard_interrupt)
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def _stop_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The stop signal (KeyboardInterrupt, :class:`~semmap.errors.Interrupted`) an exception was raised
    while handling, if any: a ``ZipFile`` that Ctrl-C cut short inside ``np.savez`` refuses to close
    ("open writing handle"), and that error, not the signal, reaches the top."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return e
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


def _stopped(prog: str, args: argparse.Namespace, exc: KeyboardInterrupt, n_committed: int) -> int:
    """The exit of a command a stop signal ended: one line and 128 + the signal, or 0 when the signal
    came once the output was complete."""
    forget_stops()
    signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
    out = getattr(args, "out", None)
    if out is not None and Path(out).expanduser().resolve() in COMMITTED[n_committed:]:
        # the signal came once the output was complete: the command did its job
        print(f"{prog}: {signal.Signals(signum).name} arrived after {out} was complete", file=sys.stderr)
        return 0
    print(f"{prog}: {'interrupted' if signum == signal.SIGINT else 'terminated'} "
          f"({signal.Signals(signum).name})", file=sys.stderr)
    return 128 + int(signum)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)  # exits 2 with a usage line on bad arguments
    _setup_logging(args.verbose)
    prog = f"semmap {args.command}"
    n_committed = len(COMMITTED)
    forget_stops()
    try:
        with _stop_signals_raise():
            code = int(args.run(args) or 0)
        return code
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM / SIGHUP raised as Interrupted
        return _stopped(prog, args, exc, n_committed)
    except Exception as exc:
        stop = _stop_behind(exc)
        if stop is not None:  # an error of the unwinding a stop signal started: the signal is what happened
            return _stopped(prog, args, stop, n_committed)
        if args.debug:
            raise
        if isinstance(exc, SemmapError):
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return exc.exit_code
        if isinstance(exc, OSError):  # unwritable output, full disk...: the message names the path
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return 1
        if isinstance(exc, InternalError):  # a bug in a worker process; its traceback is the cause
            print(f"{prog}: internal error {exc} (run again with --debug for the traceback, and please report it)",
                  file=sys.stderr)
            return EXIT_INTERNAL
        print(f"{prog}: internal error: {type(exc).__name__}: {exc} "
              f"(run again with --debug for the traceback, and please report it)", file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
