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


class VocabularyError(GraphSlamError, ValueError):
    """Descriptors a visual vocabulary cannot train on or quantise. A ValueError too, as
    scikit-learn's estimators raise for bad data (and as these errors were before)."""


class NotFittedError(VocabularyError, AttributeError):
    """A vocabulary used before ``fit``: a ValueError and an AttributeError too, as
    scikit-learn's NotFittedError (an unfitted estimator lacks its learned attributes)."""


class UnsupportedError(GraphSlamError):
    """A capability a component does not have (e.g. a filter offered a loop closure)."""


#: Characters of a token that an error message quotes: enough to recognise it,
#: few enough that a 1 GB token (a file of NUL bytes) cannot flood stderr.
QUOTE_CHARS = 40


def quote(value: object) -> str:
    """``repr(value)`` for an error message, shortened past :data:`QUOTE_CHARS`
    characters to its start, an ellipsis and its length.

    A string is cut before ``repr`` so that a huge token is never copied whole.
    """
    if isinstance(value, str):
        if len(value) <= QUOTE_CHARS:
            return repr(value)
        return f"{value[:QUOTE_CHARS]!r}... ({len(value)} characters)"
    if isinstance(value, int) and value.bit_length() > 4 * QUOTE_CHARS:
        # repr of an int over 4300 digits raises ValueError: describe it instead
        return f"an integer of {value.bit_length()} bits"
    text = repr(value)
    if len(text) <= QUOTE_CHARS:
        return text
    return f"{text[:QUOTE_CHARS]}... ({len(text)} characters)"
