"""The tokens of every line-based data file (pose graphs, landmark logs): one line
reader, one number parser, one id parser, one token count check, and so one wording
for their refusals.

Each refusal is an :class:`~slamcore.errors.InputError` naming the file and the
1-based line, quoting the token at most a few dozen characters long.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from slamcore.errors import InputError, quote
from slamcore.input_files import check_plain_text

#: Largest id a pose graph may use: ids are int64 and gtsam keys; 2**62 leaves room.
MAX_ID = 2**62
#: Ids that become gtsam symbol keys (``X(id)``, ``L(id)``) have a 56-bit index.
SYMBOL_INDEX_LIMIT = 2**56
#: Largest such id.
MAX_KEY_ID = SYMBOL_INDEX_LIMIT - 1
#: An id token as :func:`parse_id` accepts it (the bulk readers build theirs from it).
ID_TOKEN = re.compile(r"\+?[0-9]+\Z")
#: A decimal number as g2o's C++ stream reads it: optional sign, ASCII digits,
#: optional fraction and exponent, or inf/nan (refused later as not finite).
#: float() alone also takes ``1_000`` and full-width digits, which g2o does not.
NUMBER_TOKEN = re.compile(
    r"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:e[+-]?[0-9]+)?"
    r"|inf(?:inity)?|nan)\Z",
    re.ASCII | re.IGNORECASE,
)
#: Significant digits beyond any id's (2**62 has 19): such a token is out of range.
_MAX_ID_DIGITS = 20


def decimal_value(token: str) -> int:
    """``int(token)`` for an optional sign and decimal digits (checked by the caller),
    without ``int``'s refusal of strings over 4300 digits (a ValueError that would
    end a run in a traceback): a value of more than 20 significant digits comes back
    as +-10**20, outside every id range, for the caller's range check to refuse."""
    sign = -1 if token.startswith("-") else 1
    digits = token.lstrip("+-").lstrip("0")
    if len(digits) > _MAX_ID_DIGITS:
        return sign * 10**_MAX_ID_DIGITS
    return sign * int(digits or "0")


def parse_id(token: str, path, line_no: int, what: str = "pose id", *, limit: int = MAX_ID) -> int:
    """A decimal id as a Python int (never through a float, which rounds ids from
    2**53), from 0 to ``limit`` (:data:`MAX_ID`, or :data:`MAX_KEY_ID` for ids that
    become symbol keys), or one-line InputError."""
    if token.startswith("-") and ID_TOKEN.match(token[1:]):
        raise InputError(f"{what} {quote(token)} is out of range: negative", path, line_no)
    if not ID_TOKEN.match(token):
        raise InputError(f"{what} {quote(token)} is not an integer (decimal digits only)", path, line_no)
    value = decimal_value(token)
    if value > limit:
        bound = (
            "2**62"
            if limit == MAX_ID
            else "2**56 - 1 (the index a gtsam symbol key holds)"
            if limit == MAX_KEY_ID
            else str(limit)
        )
        raise InputError(f"{what} {quote(token)} is out of range: larger than {bound}", path, line_no)
    return value


def parse_numbers(tokens: list[str], path, line_no: int, what: str | None = None) -> list[float]:
    """Tokens as finite floats (:data:`NUMBER_TOKEN`), or one-line InputError."""
    label = f"{what} " if what else ""
    out = []
    for t in tokens:
        if not NUMBER_TOKEN.match(t):
            raise InputError(f"{label}{quote(t)} is not a number (decimal ASCII digits)", path, line_no)
        v = float(t)
        if not math.isfinite(v):
            raise InputError(f"{label}{quote(t)} is not finite", path, line_no)
        out.append(v)
    return out


def check_count(tokens: list[str], expected: int, path, line_no: int, layout: str | None = None) -> None:
    """One-line InputError unless the line has ``expected`` tokens (tag included);
    ``layout`` spells the line out in the message."""
    if len(tokens) != expected:
        spelled = f" ({layout})" if layout else ""
        raise InputError(
            f"{tokens[0]} line needs {expected} tokens{spelled}, got {len(tokens)}", path, line_no
        )


def iter_lines(path):
    """``(line_no, tokens)`` of the non-blank lines of ``path``, cut at a ``#`` (a comment
    line, or one ending a line: g2o's own reader ignores what follows its fields, and a
    trailing ``# odometry`` was refused with a token count); a byte-order mark is not a
    token. InputError when the file cannot be read or is not
    UTF-8 text."""
    path = Path(path)
    check_plain_text(path)
    try:
        fh = open(path, encoding="utf-8-sig")
    except OSError as exc:
        raise InputError(f"cannot open file: {exc.strerror or exc}", path) from None
    with fh:
        try:
            for line_no, line in enumerate(fh, start=1):
                tokens = line.split("#", 1)[0].split()
                if tokens:
                    yield line_no, tokens
        except UnicodeDecodeError as exc:
            raise InputError(f"not a text file: {exc}", path) from None
