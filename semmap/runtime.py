"""Process-level helpers every stage may use: holding stop signals over a critical block, and a
process's own peak memory."""

from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Iterator

__all__ = ["STOP_SIGNALS", "peak_rss_mb", "signals_held"]

#: the signals that stop a build: Ctrl-C, ``kill``/systemd, a closed terminal
STOP_SIGNALS = tuple(s for s in (getattr(signal, n, None) for n in ("SIGINT", "SIGTERM", "SIGHUP")) if s)


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
