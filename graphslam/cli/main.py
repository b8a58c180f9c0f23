"""``graphslam`` command line: parses, calls the library, prints.

Any :class:`~slamcore.errors.GraphSlamError` becomes one line on stderr and
exit status 2; Ctrl-C (SIGINT), SIGTERM or SIGHUP (the terminal closed) writes what
was estimated so far and exits with 130, 143 or 129 (:mod:`graphslam.pipelines.common`).
"""

from __future__ import annotations

import argparse
import atexit
import errno
import os
import re
import signal
import sys
from typing import NoReturn

from graphslam.cli.common import EXIT_ERROR, EXIT_INTERRUPTED, EXIT_OK, check_path_arguments, one_line
from slamcore.errors import QUOTE_CHARS, GraphSlamError, quote
from slamcore.files import write_error_line


class OneLineParser(argparse.ArgumentParser):
    """argparse's parser whose errors are one line, as every other error of the
    command (argparse prints the usage block first); sub-commands inherit it."""

    def parse_args(self, args=None, namespace=None):  # type: ignore[override]
        # argparse's own version joins the unknown tokens whole into the message
        parsed, extra = self.parse_known_args(args, namespace)
        if extra:
            self.error(f"unrecognized arguments: {' '.join(quote(a) for a in extra)}")
        return parsed

    def error(self, message: str) -> NoReturn:
        command = self.prog.removeprefix("graphslam").strip()
        where = f"{command}: " if command else ""
        message = one_line(_ARGPARSE_VALUE.sub(_short_value, message))
        self.exit(2, f"graphslam: error: {where}{message} (see {self.prog} --help)\n")


#: A value argparse quotes whole in its own messages ("invalid choice: 'x...'",
#: "invalid int value: 'x...'", as ``repr``): longer than :data:`QUOTE_CHARS`.
_ARGPARSE_VALUE = re.compile(rf"'[^'\n]{{{QUOTE_CHARS + 1},}}'|\"[^\"\n]{{{QUOTE_CHARS + 1},}}\"")


def _short_value(match: re.Match) -> str:
    """A long quoted value shortened as every other message quotes it (:func:`quote`)."""
    return quote(match.group(0)[1:-1])


#: ``--frames -1:``: argparse takes a value that starts with "-" (and is no plain
#: negative number) for an option; a slice is glued to its flag before parsing.
_SLICE = re.compile(r"-?\d*(:-?\d*){0,2}")


#: ``--offset -1e-3``: argparse reads a negative number as a value only in its plain
#: forms (``-1``, ``-0.001``), and ``-1e-3`` ended in "expected one argument".
_EXPONENT_NUMBER = re.compile(r"-(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


def glued_values(argv: list[str]) -> list[str]:
    """``argv`` with ``--frames VALUE`` written ``--frames=VALUE`` where VALUE is a
    slice starting with "-" (``-1:``, ``-10:-2``), and ``--flag -1e-3`` written
    ``--flag=-1e-3`` (a negative number in exponent form after any long option)."""
    out: list[str] = []
    for arg in argv:
        if out and out[-1] == "--frames" and arg.startswith("-") and _SLICE.fullmatch(arg):
            out[-1] = f"--frames={arg}"
        elif (
            out
            and out[-1].startswith("--")
            and out[-1] != "--"
            and "=" not in out[-1]
            and _EXPONENT_NUMBER.fullmatch(arg)
        ):
            out[-1] = f"{out[-1]}={arg}"
        else:
            out.append(arg)
    return out


def build_parser() -> argparse.ArgumentParser:
    """The ``graphslam`` parser with every sub-command."""
    parser = OneLineParser(
        prog="graphslam",
        description="Graph-SLAM toolkit on GTSAM: run SLAM on a sequence and get a trajectory, "
        "a map, metrics and a Rerun recording.",
    )
    from graphslam import __version__

    parser.add_argument("--version", action="version", version=f"graphslam {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    from graphslam.cli import compare, convert, info, localize, loops, vocab
    from graphslam.cli import eval as eval_command
    from graphslam.cli import sweep as sweep_command
    from graphslam.cli.run import command as run

    for command in (run, compare, vocab, loops, localize, convert, info):
        command.register(sub)
    eval_command.register(sub)
    sweep_command.register(sub)
    return parser


#: Exit status when stdout's reader closed the pipe (128 + SIGPIPE, as a shell reports it).
EXIT_BROKEN_PIPE = 141


class _NamedStdout:
    """``sys.stdout`` while a command runs. An error writing it names it (the system's
    names no file, and was reported as one of the outputs') and is kept: argparse
    swallows the error of writing ``--help``, and the stream drops what it held."""

    def __init__(self, stream):
        self.stream = stream
        self.error: OSError | None = None

    def write(self, text: str) -> int:
        try:
            return self.stream.write(text)
        except OSError as e:
            raise self._named(e) from None

    def flush(self) -> None:
        try:
            self.stream.flush()
        except OSError as e:
            raise self._named(e) from None

    def _named(self, e: OSError) -> OSError:
        if e.filename is None:
            e.filename = "standard output"
        self.error = self.error or e
        return e

    def __getattr__(self, name: str):
        return getattr(self.stream, name)


def _usable_std_streams() -> None:
    """A closed standard stream (``>&-``: Python's is None) discards what is written to
    it, as the user asked, instead of failing the run at its first print; a stream whose
    encoding cannot spell a path's character (``PYTHONIOENCODING=ascii``) escapes it."""
    for name in ("stdout", "stderr"):
        stream = getattr(sys, name)
        if stream is None:
            setattr(sys, name, open(os.devnull, "w", encoding="utf-8"))  # noqa: SIM115 (lives with the process)
        elif hasattr(stream, "reconfigure"):
            try:
                stream.reconfigure(errors="backslashreplace")
            except (ValueError, OSError):  # a detached or closed stream keeps its errors
                pass


def main(argv: list[str] | None = None) -> int:
    from graphslam.cli.out_folder import release_out_dirs

    _usable_std_streams()
    stdout = sys.stdout = _NamedStdout(sys.stdout)
    try:
        return _main(argv, stdout)
    finally:
        release_out_dirs()
        if sys.stdout is stdout:
            sys.stdout = stdout.stream


def _main(argv: list[str] | None, stdout: _NamedStdout) -> int:
    from graphslam.pipelines.common import (
        PARENT_PID_ENV,
        die_with_parent,
        signal_hook,
        stop_guard,
        to_devnull,
    )
    from graphslam.pipelines.provenance import invoked_as

    # The guard first: a signal while the parser and the libraries load is
    # one line and its exit status, never a traceback.
    with stop_guard() as guard:
        parent = os.environ.pop(PARENT_PID_ENV, "")
        if parent.isdigit():  # a sweep's run: stopped, outputs kept, when the sweep dies
            die_with_parent(int(parent), signal.SIGTERM)
        try:
            parser = build_parser()
            words = sys.argv[1:] if argv is None else list(argv)
            try:
                args = parser.parse_args(glued_values(words))
            except SystemExit as stop:
                if stop.code == 0:  # --help, --version: said, not lost with status 0
                    sys.stdout.flush()
                    if stdout.error is not None:
                        raise stdout.error from None
                raise
            check_path_arguments(args)
            # how it was started, honestly: "python3 -m graphslam" is not the console script
            # (a sweep's runs are "-m graphslam.cli.main"); main(argv) from Python stands
            # for the command
            args.command_line = [*(invoked_as() if argv is None else ["graphslam"]), *words]
            signal_hook("start")
            status = args.func(args)
            sys.stdout.flush()  # the summary's write error is this command's, not the exit's
        except GraphSlamError as e:
            print(f"graphslam: error: {one_line(str(e))}", file=sys.stderr)
            return EXIT_ERROR
        except BrokenPipeError:
            # the reader of our output left (``graphslam run ... | head``): the files are
            # written before the summary is printed; exit quietly, as a shell's SIGPIPE
            # does, and keep Python's exit-time flush of stdout from raising again
            to_devnull(sys.stdout.fileno())
            return EXIT_BROKEN_PIPE
        except OSError as e:
            if e.errno == errno.EIO and guard.requested and guard.signal_name == "SIGHUP":
                # the terminal closed (SIGHUP, then EIO on each write to it): the files
                # are written before the summary is printed; nothing can be said
                to_devnull(sys.stdout.fileno(), sys.stderr.fileno())
                return guard.exit_status()
            # a full disk or an over-long name met while writing: the user's to fix
            line = write_error_line(e)
            if line is None:
                raise
            print(f"graphslam: error: {one_line(line)}", file=sys.stderr)
            return EXIT_ERROR
        except KeyboardInterrupt:
            print(f"graphslam: interrupted ({guard.signal_name})", file=sys.stderr)
            return guard.exit_status()
        except Exception:
            # KeyboardInterrupt inside a C extension's import surfaces as
            # "ImportError: initialization failed": the signal's doing, not a bug.
            # Once a run defers signals, an exception is a bug, signal or not.
            if not guard.requested or guard.deferring:
                raise
            print(f"graphslam: interrupted ({guard.signal_name})", file=sys.stderr)
            return guard.exit_status()
        if guard.requested and status in (EXIT_OK, EXIT_INTERRUPTED):
            # the signal came while the outputs were being finished: all written
            if status == EXIT_OK:
                print(
                    f"graphslam: interrupted ({guard.signal_name}); the outputs are complete", file=sys.stderr
                )
            return guard.exit_status()
        return status


_returned: list[bool] = []  # set once main() has returned in the console script


def _late_stop(signum, frame) -> None:
    """A stop signal outside the command's guard: after the command returned, while the
    interpreter tears down (the sweep engine's exit handlers, thread joins: about
    0.1 s), everything is written; before the guard (microseconds) nothing ran. Either
    way exit at once with the signal's status instead of dying by it."""
    import os

    from graphslam.pipelines.common import EXIT_STATUS_OF_SIGNAL

    try:
        sys.stdout.flush()
        done = "; the outputs are complete" if _returned else ""
        sys.stderr.write(f"graphslam: interrupted{' while exiting' if _returned else ''}{done}\n")
        sys.stderr.flush()
    finally:
        os._exit(EXIT_STATUS_OF_SIGNAL.get(signum, 130))


def _ignore_stop_signals() -> None:
    """The last exit handler: the stop signals are ignored for what remains of the exit.
    Python then resets its signal handlers to the default action, and a SIGTERM in
    that window killed the process with status 143 and no line, everything written
    (hostile pass 16, a sweep stopped as it exited). Ignored, not blocked: a blocked
    signal still reaches a thread that has not blocked it (a progress bar's monitor),
    and kills the process by the default action. The command ends with its own status,
    which it had earned."""
    from graphslam.pipelines.common import stop_signals

    for s in stop_signals():
        signal.signal(s, signal.SIG_IGN)


def entry() -> None:
    """The ``graphslam`` console script: :func:`main` between handlers for a late
    signal (installed first, so the command's guard restores them when it ends and
    no moment of the exit is left to the default action)."""
    import signal

    from graphslam.pipelines.common import stop_signals

    for s in stop_signals():
        signal.signal(s, _late_stop)
    # registered first, so it runs after every library's exit handler
    atexit.register(_ignore_stop_signals)
    try:
        status = main()
    finally:  # a SystemExit of the parser (--help, an error) too
        _returned.append(True)
    recording = sys.modules.get("graphslam.visualisation.recording")
    if recording is not None and recording.wedged():
        # a recording's flush was given up on a full disk: Python's exit would wait
        # for Rerun's stopped writer forever (its exit hook, the stream's drop)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    sys.exit(status)


if __name__ == "__main__":  # pragma: no cover
    entry()
