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


class OutputExistsError(SemmapError):
    """The output path exists and ``force`` was not given."""

    exit_code = 4


class SimulationError(SemmapError):
    """A simulated world or tour is inconsistent (collision, robot out of bounds)."""

    exit_code = 5
