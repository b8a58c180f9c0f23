"""One exception family for the whole toolkit.

The CLI turns any :class:`GraphSlamError` into a one-line message and a
non-zero exit; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

from pathlib import Path


class GraphSlamError(Exception):
    """Base class of every error the toolkit raises on purpose."""


class LocatedError(GraphSlamError):
    """An error in a file: names the file and (when known) the 1-based line."""

    def __init__(self, message: str, path: str | Path | None = None, line: int | None = None):
        self.path = None if path is None else str(path)
        self.line = line
        self.reason = message
        where = ""
        if self.path is not None:
            where = self.path if line is None else f"{self.path}:{line}"
            where += ": "
        super().__init__(where + message)


class InputError(LocatedError):
    """Bad input data: names the file and (when known) the 1-based line."""


class ConfigError(LocatedError):
    """A configuration file or option that cannot be used (file and line when from a file)."""


class MeasurementError(GraphSlamError):
    """A measurement that must not enter an estimator (NaN, inf, bad covariance)."""


class UnsupportedError(GraphSlamError):
    """A capability a component does not have (e.g. a filter offered a loop closure)."""
