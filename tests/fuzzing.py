"""A seeded mutation fuzzer for text input files (no dependency beyond the stdlib).

:class:`Mutator` turns a valid file into a damaged one with one to three
mutations drawn from: byte flips, inserted bytes, dropped, duplicated and
swapped lines, numbers replaced by hostile ones (huge, tiny, negative, NaN,
past 2**53, not numbers at all), truncation, and a byte-order mark.
:func:`fuzz` feeds many mutants to a reader and collects every outcome that is
neither a result accepted by ``check`` nor one of our one-line errors
(:class:`slamcore.errors.GraphSlamError`), with the seed that reproduces it.
:func:`fuzz_cases` does the same for inputs of several files (a folder), each
mutant written by a ``prepare`` function from its seeded :class:`Mutator`;
:meth:`Mutator.mutate_json` and :meth:`Mutator.mutate_arrays` damage a parsed
JSON document and a dict of numpy arrays (an ``.npz``) in their structure.
"""

from __future__ import annotations

import copy
import random
import re
import signal
import traceback
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slamcore.errors import GraphSlamError

#: Numbers a mutation puts in place of a number of the file.
HOSTILE_NUMBERS = (
    "0", "-0", "-1", "1", "2", "0.5", "-3.5", "1e308", "-1e308", "1e-320", "1e400", "nan", "inf",
    "-inf", str(2**31), str(2**32 - 1), str(2**53 + 1), str(2**56), str(2**63 - 1), str(2**64),
    "9" * 40, "1e9", "1e11", "1.0", "3e3", "0x10", "1_000", "", "abc", "true", "[]", "{}",
    "\"s\"", "-", ".", "e5",
)
#: Bytes a mutation inserts.
HOSTILE_BYTES = (b"\x00", b"\xff", b"\xef\xbb\xbf", b"\n", b"\r", b"\t", b" ", b"#", b"[",
                 b"]", b"=", b"\"", b"'", b"-", b".", b"e", b"\xc3", b"\\")
_NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
#: Values :meth:`Mutator.mutate_json` puts in place of a value of the document.
HOSTILE_JSON = (None, True, 0, -1, 0.5, 1e308, 2**64, "", "x", [], [1, 2], {}, {"a": 1})
#: Values :meth:`Mutator.mutate_arrays` writes into an array (those its dtype holds).
HOSTILE_ARRAY_VALUES = (float("nan"), float("inf"), -float("inf"), 1e308, -1e308, 1e-320, -1, 0,
                        7, 2**31, 2**62, 2**63 - 1, -2**63)
#: Dtypes :meth:`Mutator.mutate_arrays` converts an array to.
HOSTILE_DTYPES = ("float32", "float64", "int32", "int64", "uint8", "bool", "complex128", "<U3")


class Mutator:
    """Mutations of one file's bytes, repeatable from ``seed``."""

    def __init__(self, seed: int):
        self.rng = random.Random(seed)
        self.operators = (self.flip_byte, self.insert_bytes, self.drop_line,
                          self.duplicate_line, self.swap_lines, self.replace_number,
                          self.replace_number, self.replace_number, self.truncate, self.bom)

    def mutate(self, data: bytes) -> bytes:
        for _ in range(self.rng.randint(1, 3)):
            data = self.rng.choice(self.operators)(data)
        return data

    def flip_byte(self, data: bytes) -> bytes:
        if not data:
            return data
        i = self.rng.randrange(len(data))
        return data[:i] + bytes([data[i] ^ (1 << self.rng.randrange(8))]) + data[i + 1:]

    def insert_bytes(self, data: bytes) -> bytes:
        i = self.rng.randint(0, len(data))
        return data[:i] + self.rng.choice(HOSTILE_BYTES) + data[i:]

    def _lines(self, data: bytes) -> list[bytes]:
        return data.splitlines(keepends=True)

    def drop_line(self, data: bytes) -> bytes:
        lines = self._lines(data)
        if lines:
            del lines[self.rng.randrange(len(lines))]
        return b"".join(lines)

    def duplicate_line(self, data: bytes) -> bytes:
        lines = self._lines(data)
        if lines:
            i = self.rng.randrange(len(lines))
            lines.insert(self.rng.randint(0, len(lines)), lines[i])
        return b"".join(lines)

    def swap_lines(self, data: bytes) -> bytes:
        lines = self._lines(data)
        if len(lines) >= 2:
            i, j = self.rng.sample(range(len(lines)), 2)
            lines[i], lines[j] = lines[j], lines[i]
        return b"".join(lines)

    def replace_number(self, data: bytes) -> bytes:
        spans = [m.span() for m in _NUMBER.finditer(data)]
        if not spans:
            return self.insert_bytes(data)
        a, b = self.rng.choice(spans)
        return data[:a] + self.rng.choice(HOSTILE_NUMBERS).encode() + data[b:]

    def truncate(self, data: bytes) -> bytes:
        return data[:self.rng.randint(0, len(data))]

    def bom(self, data: bytes) -> bytes:
        return b"\xef\xbb\xbf" + data

    def mutate_json(self, doc):
        """A copy of the parsed JSON ``doc`` with one value (at any depth) replaced by
        one of :data:`HOSTILE_JSON`, or one key of a table removed."""
        doc = copy.deepcopy(doc)
        places = [p for p in _json_places(doc, ()) if p]
        if not places:
            return self.rng.choice(HOSTILE_JSON)
        where = self.rng.choice(places)
        parent = doc
        for key in where[:-1]:
            parent = parent[key]
        if isinstance(parent, dict) and self.rng.random() < 0.15:
            del parent[where[-1]]
        else:
            parent[where[-1]] = copy.deepcopy(self.rng.choice(HOSTILE_JSON))
        return doc

    def mutate_arrays(self, arrays: dict) -> dict:
        """A copy of ``arrays`` (name -> numpy array) with one array damaged: a hostile
        value written into it, another dtype, rows dropped, repeated or all gone,
        flattened, made a scalar, removed; or an unknown array added."""
        arrays = dict(arrays)
        name = self.rng.choice(sorted(arrays))
        a = np.array(arrays[name])
        op = self.rng.randrange(8)
        if op == 0 and a.size:
            flat = a.reshape(-1).copy()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    flat[self.rng.randrange(flat.size)] = self.rng.choice(HOSTILE_ARRAY_VALUES)
                except (ValueError, OverflowError):  # a value the dtype cannot hold
                    pass
            a = flat.reshape(a.shape)
        elif op == 1:
            try:
                a = a.astype(self.rng.choice(HOSTILE_DTYPES))
            except (ValueError, TypeError):  # text that is no number
                pass
        elif op == 2 and a.ndim:
            a = a[:self.rng.randint(0, len(a))]
        elif op == 3 and a.ndim and len(a):
            a = np.concatenate([a, a[:self.rng.randint(1, 2)]])
        elif op == 4:
            a = a.reshape(-1)
        elif op == 5:
            a = np.array(self.rng.choice(HOSTILE_ARRAY_VALUES[:3] + (5,)))
        elif op == 6:
            del arrays[name]
            return arrays
        else:
            arrays["unknown"] = np.zeros(3)
        arrays[name] = a
        return arrays


def _json_places(doc, where: tuple):
    """Every path (a tuple of keys and indices) into the JSON ``doc``."""
    yield where
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for key, value in items:
        yield from _json_places(value, where + (key,))


@dataclass
class Finding:
    """A mutant whose outcome was neither valid nor one of our one-line errors."""

    seed: int
    data: bytes
    problem: str

    def __str__(self) -> str:
        return f"seed {self.seed}: {self.problem}\ninput: {self.data[:400]!r}"


class TooSlow(BaseException):
    """A mutant took longer than the fuzzer's per-input limit (a hang, say)."""


def _too_slow(signum, frame):
    raise TooSlow


def fuzz(base: bytes, path: Path, read: Callable[[Path], object], n: int, seed: int = 0,
         check: Callable[[object], None] | None = None,
         timeout_s: float = 2.0) -> list[Finding]:
    """Write ``n`` mutants of ``base`` to ``path`` in turn and ``read`` each.

    A mutant passes when ``read`` returns (and ``check`` of the result does not
    raise) or when it raises a :class:`GraphSlamError` whose message is one
    line. Mutant ``k`` comes from ``Mutator(seed + k)``: a finding's seed
    reproduces it alone. One taking over ``timeout_s`` is a finding (SIGALRM:
    call from the main thread).
    """
    def prepare(mutator: Mutator) -> tuple[Path, bytes]:
        data = mutator.mutate(base)
        path.write_bytes(data)
        return path, data

    return fuzz_cases(prepare, read, n, seed, check, timeout_s)


def fuzz_cases(prepare: Callable[[Mutator], tuple[object, bytes | str]],
               read: Callable[[object], object], n: int, seed: int = 0,
               check: Callable[[object], None] | None = None,
               timeout_s: float = 2.0) -> list[Finding]:
    """:func:`fuzz` for inputs of several files: ``prepare(Mutator(seed + k))``
    writes mutant ``k`` and returns ``(what read takes, a description of the
    damage)``; the outcomes are judged as :func:`fuzz` judges them."""
    findings = []
    previous = signal.signal(signal.SIGALRM, _too_slow)
    try:
        for k in range(n):
            arg, data = prepare(Mutator(seed + k))
            problem = _outcome(read, check, arg, timeout_s)
            if problem is not None:
                data = data if isinstance(data, bytes) else data.encode("utf-8", "replace")
                findings.append(Finding(seed + k, data, problem))
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    return findings


def _outcome(read, check, arg, timeout_s: float) -> str | None:
    """None when reading ``arg`` is valid or one of our one-line errors, else what went wrong."""
    signal.setitimer(signal.ITIMER_REAL, timeout_s)
    try:
        result = read(arg)
        if check is not None:
            check(result)
    except GraphSlamError as e:
        if "\n" in str(e) or not str(e).strip():
            return f"error not one line: {str(e)!r}"
    except TooSlow:
        return f"took over {timeout_s} s"
    except Exception:  # anything else is what the fuzzer looks for
        return traceback.format_exc(limit=-3)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
    return None
