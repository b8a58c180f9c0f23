"""How every benchmark script ends: one line, never a traceback, on Ctrl-C, SIGTERM or
SIGHUP, on the toolkit's own errors, on an output the disk refuses (full, a name too
long, a folder in its place) and on an input file that is not there; and no lost
measurement when the reader of its printout leaves (``| head``).

A benchmark runs the library for minutes. Cut by a signal, it printed
``KeyboardInterrupt`` under a traceback from wherever the run was (``whole()``
raises it for a cut run, so that a cut run never passes for a whole one). Now
SIGTERM and SIGHUP stop it as Ctrl-C does, and :func:`run` turns the
KeyboardInterrupt into one line naming the signal and the signal's exit status
(130, 143, 129).

Not the command line's guard (:func:`graphslam.pipelines.common.stop_guard`): under
it the library treats a stop as a request and returns what was done (a pose graph's
solve cut short, a compare entry marked "cut"), which a command writes as such but
a benchmark would score as a whole result. Here a signal ends the script: inside a
run's loop the loop's own guard stops it at the next step and ``whole()`` raises;
anywhere else the KeyboardInterrupt is raised where the script is. Files a script
wrote before the signal stay. A script that scores a run without ``whole()`` (a loop
detection pass, whose guard keeps the closures found so far) goes on after the cut;
:func:`run` then says at the end that its outputs may count a cut run as whole, and
exits with the signal's status all the same.

Every ``--out`` is checked as argparse parses it (:func:`output_file`,
:func:`output_folder`): a folder given for a file, a parent that is a file, a folder
the user cannot write or a name too long is refused before the measurement, not
found at its end. A full disk (or a quota, or a file-size limit) still is found at
the end, by :func:`write_json`: the JSON is printed on stdout instead, an earlier file
at ``--out`` is left as it was (never a truncated one), and the one line says so.

The scripts import numpy, gtsam and the toolkit at their top, before this exists: a
signal in that first second is :mod:`quiet_start`'s, each script's first import, which
ends it with one line too.

Usage, the last lines of a script::

    if __name__ == "__main__":
        import entry  # a module, not its run(): some scripts have a run() of their own

        raise SystemExit(entry.run(main))
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import errno
import json
import math
import signal
import sys
from pathlib import Path
from typing import Callable

from graphslam.cli.common import seed_arg

#: The exit status of a toolkit error (``graphslam``'s too).
EXIT_ERROR = 2
#: Errors of a named file a user fixes by naming another one (``--out``, ``--data``): a
#: refused write, or an input that is not there.
NAMED_FILE_ERRORS = (errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOENT, errno.ENOTDIR)
#: A write refused for want of room (a full disk, a quota, a file-size limit): the
#: results are printed rather than lost.
DISK_FULL_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def run(main: Callable[[], int | None]) -> int:
    """``main()`` with the stop signals raising KeyboardInterrupt; its exit status (None
    is 0), or one line on stderr and the signal's status, or 2 for a toolkit error. The
    signal handlers are restored on return."""
    from graphslam.pipelines.common import (
        EXIT_STATUS_OF_SIGNAL,
        note_stop_signal,
        stop_signals,
        stop_signals_received,
    )
    from slamcore.errors import GraphSlamError
    from slamcore.files import write_error_line

    def stop(signum, frame) -> None:
        note_stop_signal(signum)
        raise KeyboardInterrupt

    def said(what: str) -> int:
        signum = received()[-1] if received() else signal.SIGINT
        print(f"{name}: interrupted ({signal.Signals(signum).name}) {what}", file=sys.stderr)
        return EXIT_STATUS_OF_SIGNAL.get(signum, 130)

    before = len(stop_signals_received())

    def received() -> list[int]:
        return stop_signals_received()[before:]

    name = Path(sys.argv[0]).name
    previous = {s: signal.signal(s, stop) for s in stop_signals()}
    stdout, sys.stdout = sys.stdout, ReaderGone(sys.stdout)
    try:
        try:
            status = main()
        except GraphSlamError as e:
            print(f"{name}: error: {' '.join(str(e).split())}", file=sys.stderr)
            return EXIT_ERROR
        except OSError as e:
            # a full disk, a name too long, a folder given as --out, an input not there:
            # the user's to fix, as in graphslam; any other OSError keeps its traceback
            line = write_error_line(e)
            if line is None and e.errno in NAMED_FILE_ERRORS and e.filename is not None:
                line = f"{e.filename}: {e.strerror}"
            if line is None:
                raise
            print(f"{name}: error: {line}", file=sys.stderr)
            return EXIT_ERROR
        except KeyboardInterrupt:
            # a second signal while this is said must not end in a traceback after all
            for s in previous:
                signal.signal(s, signal.SIG_IGN)
            return said("before it finished")
        if received():
            # a run's own guard took the signal and cut the run (or let it finish a step it
            # does not cut), and the script, not asking whole(), went on to score it
            return said("but a run took the signal and the script went on: its outputs may count a cut run as whole")
        return 0 if status is None else int(status)
    finally:
        sys.stdout = stdout
        for s, handler in previous.items():
            signal.signal(s, handler)


def write_json(path: str | Path, payload, *, trailing_newline: bool = False, **dumps_kwargs) -> None:
    """A script's JSON result, ``json.dumps(payload, **dumps_kwargs)`` (and a newline if
    asked), written whole to ``path`` or not at all (a temporary file moved into place).

    On a full disk the minutes of measurement are not lost: the JSON goes to stdout and a
    GraphSlamError is raised, which :func:`run` says in one line (status 2). Any other
    OSError is raised as it is."""
    from slamcore.errors import GraphSlamError
    from slamcore.files import atomic_open

    text = json.dumps(payload, **dumps_kwargs) + ("\n" if trailing_newline else "")
    try:
        with atomic_open(path, "w") as fh:
            fh.write(text)
    except OSError as e:
        if e.errno not in DISK_FULL_ERRORS:
            raise
        reason = e.strerror or str(e)
        try:
            sys.stdout.write(text if text.endswith("\n") else text + "\n")
            sys.stdout.flush()
        except OSError:  # stdout on the same full disk (``> log``), where Python says so
            raise GraphSlamError(f"{path}: {reason}; the results could not be printed on stdout either") from e
        raise GraphSlamError(f"{path}: {reason}; the results are printed on stdout above") from e


class ReaderGone:
    """``stdout`` that, once its reader has left (``bench_x.py | head``: EPIPE), writes to
    /dev/null: the script goes on to write its JSON and PNG. A BrokenPipeError from a
    print ended the measurement in a traceback with nothing written."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._gone()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._gone()

    def _gone(self) -> None:
        from graphslam.pipelines.common import to_devnull

        # the file descriptor, not only this object: Python's exit-time flush of the
        # stream would meet the closed pipe again
        to_devnull(self._stream.fileno())

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


# argparse types for the scripts' numeric options: a bad value is argparse's one error
# line (and the usage), not a ZeroDivisionError or an empty median minutes later


def _at_least(minimum: int, doc: str) -> Callable[[str], int]:
    """An argparse type: a whole number of at least ``minimum``."""

    def parse(text: str) -> int:
        value = _number(text, int)
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected a whole number of at least {minimum}, got {text!r}")
        return value

    parse.__doc__ = doc
    return parse


count = _at_least(1, "A whole number of at least 1: repeats, runs, frames, pairs, workers.")
count_or_zero = _at_least(
    0,
    "A whole number of at least 0, where 0 means something of its own (no cap, all "
    "frames, the library's default thread count, no tolerance).",
)
#: A random seed: the command line's own (0 to 2**62; numpy refuses negative ones).
seed = seed_arg


def positive(text: str) -> float:
    """A finite number above 0: a distance, a standard deviation."""
    value = _number(text, float)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number above 0, got {text!r}")
    return value


def output_file(text: str) -> Path:
    """An output file (``--out``): refused by argparse, before the measurement, where it
    cannot be written (a folder of that name, a parent that is a file, a folder
    without write permission, a name too long). Found at the end, it cost the whole
    measurement: the one line came after the work."""
    from slamcore.files import check_output_file

    if Path(text).suffix.lower() == ".png":  # the figure's own name: it overwrote the JSON
        raise argparse.ArgumentTypeError(
            f"{text!r} is a figure's name: --out names the JSON result, the figure goes beside it (.png)"
        )
    return _checked(check_output_file, text)


def int_list(text: str) -> list[int]:
    """Comma-separated whole numbers of at least 0 (``--seeds 0,1,2``): a bad one is
    argparse's one line, not a ValueError traceback when the list is first read."""
    values = [_number(part.strip(), int) for part in text.split(",")]
    if not values or any(v < 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected whole numbers of at least 0 separated by commas, got {text!r}")
    return values


def names_from(*allowed: str) -> Callable[[str], list[str]]:
    """An argparse type: comma-separated names, each one of ``allowed`` (``--backends
    isam2,ekf``): an unknown one was a KeyError after the first back end's work."""

    def parse(text: str) -> list[str]:
        names = [part.strip() for part in text.split(",")]
        bad = [n for n in names if n not in allowed]
        if bad:
            raise argparse.ArgumentTypeError(f"unknown {', '.join(map(repr, bad))}; choose from {', '.join(allowed)}")
        return names

    parse.__doc__ = f"Comma-separated names, each one of {', '.join(allowed)}."
    return parse


def output_folder(text: str) -> Path:
    """An output folder (``--out`` of a script that writes several files), refused as
    :func:`output_file` is."""
    from slamcore.files import check_output_dir

    return _checked(check_output_dir, text)


def _checked(check: Callable[[str, str], Path], text: str) -> Path:
    from slamcore.errors import ConfigError

    try:
        return check(text, "--out")
    except ConfigError as e:  # argparse names the option itself: said once, not twice
        line = str(e)
        for prefix in ("--out: ", "--out "):
            line = line.removeprefix(prefix)
        raise argparse.ArgumentTypeError(line) from None


def _number(text: str, kind: type):
    try:
        return kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {'a whole number' if kind is int else 'a number'}, got {text!r}") from None


def quick_sizes(ap: argparse.ArgumentParser, argv: list[str] | None, args: argparse.Namespace, **sizes) -> None:
    """``--quick``'s smoke sizes (``name=value``) set on ``args`` for the options the user
    did not give: ``--quick --particles 5`` ran with 10 and 100 particles, the 5 dropped
    without a word. The command line ``argv`` (None: ``sys.argv[1:]``) is parsed again
    into a namespace that already holds a marker for each name, which argparse leaves
    in place unless the option is given (abbreviated or not, ``--x=v`` or ``--x v``)."""
    unset = object()
    probe = argparse.Namespace(**dict.fromkeys(sizes, unset))
    ap.parse_args(sys.argv[1:] if argv is None else argv, namespace=probe)
    for name, value in sizes.items():
        if getattr(probe, name) is unset:
            setattr(args, name, value)
