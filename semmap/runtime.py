"""Process-level helpers every stage may use: holding stop signals over a critical block, and a
process's own peak memory."""

from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Iterator

__all__ = ["STOP_SIGNALS", "forget_stops", "note_stop", "peak_rss_mb", "raise_if_stopped", "signals_held"]

#: the signals that stop a build: Ctrl-C, ``kill``/systemd, a closed terminal
STOP_SIGNALS = tuple(s for s in (getattr(signal, n, None) for n in ("SIGINT", "SIGTERM", "SIGHUP")) if s)


#: the stop signals whose handler has run in this process (see :func:`note_stop`)
_STOPS: list[int] = []


def note_stop(signum: int) -> None:
    """Record that a stop signal's handler ran. The handler raises its exception wherever the main thread
    is, and that may be inside a finalizer (an object the garbage collector frees mid-rendering), whose
    exceptions Python reports as unraisable and drops: the build would then run on and write its output
    as if nothing had come. :func:`raise_if_stopped` raises it again before an output is committed."""
    _STOPS.append(int(signum))


def forget_stops() -> None:
    """Forget the stop signals recorded (a command that starts, or one whose stop was handled)."""
    _STOPS.clear()


def raise_if_stopped() -> None:
    """Raise the stop signal :func:`note_stop` recorded, if one was (once: it is then forgotten)."""
    if not _STOPS:
        return
    signum = _STOPS[-1]
    forget_stops()
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    from .errors import Interrupted

    raise Interrupted(signum)


def peak_rss_mb() -> float:
    """This process's own peak resident memory, MB.

    Linux's ``VmHWM``: ``ru_maxrss`` of a spawned worker starts at its parent's size when it was
    forked, before the exec, and would report that instead of the worker's own peak."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / (1024.0 if sys.platform != "darwin" else 1024.0 ** 2)


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Hold SIGINT, SIGTERM and SIGHUP back while the block runs (clean-up, an atomic rename);
    one that arrives meanwhile is delivered when the block ends."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
