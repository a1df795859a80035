"""The semmap exception hierarchy.

Every error a user can cause (bad input, missing topic, malformed file) is a
:class:`SemmapError`. The CLI prints its message as one line and exits non-zero;
anything else is a bug and shows a traceback.
"""

from __future__ import annotations


class SemmapError(Exception):
    """Base class for errors caused by input, configuration or environment."""

    exit_code = 1


class ConfigError(SemmapError):
    """A configuration, calibration or world file is malformed or inconsistent."""

    exit_code = 2


class BagError(SemmapError):
    """A bag cannot be opened or read, or lacks a topic or message it needs."""

    exit_code = 3


class OutputError(SemmapError):
    """The output path cannot or must not be written (unwritable, not a semmap folder, holds an input)."""

    exit_code = 4


class OutputExistsError(OutputError):
    """The output path exists and ``force`` was not given."""


class SimulationError(SemmapError):
    """A simulated world or tour is inconsistent (collision, robot out of bounds)."""

    exit_code = 5


class WorkerError(SemmapError):
    """A worker process stopped without its result: killed (the out-of-memory killer sends
    SIGKILL), crashed in native code (SIGSEGV), or ran out of memory."""

    exit_code = 6


class MapFolderError(SemmapError):
    """A map folder cannot be read back: a file is missing or damaged, or it was written with another
    map-folder layout (``map_folder_version``)."""

    exit_code = 7


class AlignmentError(SemmapError):
    """Two maps cannot be compared: they do not overlap enough to be aligned, or the alignment is
    ambiguous (a long featureless corridor, a symmetric room)."""

    exit_code = 8


class InternalError(Exception):
    """A bug in a worker process. The message is the worker's exception type and message; the
    worker's own traceback is this exception's ``__cause__`` (shown with ``--debug``)."""


class Interrupted(KeyboardInterrupt):
    """A termination signal (SIGTERM, SIGHUP) raised as an exception, as Ctrl-C raises
    :class:`KeyboardInterrupt`, so that workers, shared memory and partial output are cleaned up."""

    def __init__(self, signum: int) -> None:
        import signal

        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)
