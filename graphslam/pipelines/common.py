"""What the pipelines share: the stop guard (SIGINT, SIGTERM, SIGHUP, SIGQUIT), its test hook,
and the progress bar.

A command runs inside one :func:`stop_guard` (``graphslam.cli.main`` opens it).
Until a run starts (:meth:`StopGuard.defer`), SIGINT, SIGTERM or SIGHUP raises
KeyboardInterrupt at once: nothing is estimated yet, nothing is lost. From then
on, to the end of the command (the loop, finalisation, metrics, writing), the
first signal is only recorded: loops stop at their next step boundary, optional
work (covariances) is skipped, and every output is still written. A second
signal raises KeyboardInterrupt at once while the loop still runs (a step that
does not end), but not once a stop has ended the loop: what follows is the save
the stop asked for, and further signals are only recorded. The writers replace
files atomically, so a cut write leaves each file the old complete one or the
new complete one.

Test hook: ``GRAPHSLAM_SIGNAL_AT=POINT[:N]`` makes the process send itself a
signal the first time the code reaches ``POINT`` (with ``N``: step ``N``,
0-based), so tests hit exact moments without sleeping. Points: ``start`` (the
command has parsed its arguments), ``step`` (a step is done), ``finalize``
(the loop is over; finalisation and covariances next), ``write`` (the first
output file is written, the others not yet), ``recorder`` (a command's Rerun recorder is
open, its run not yet started). ``GRAPHSLAM_SIGNAL`` names the
signal (``INT``, ``TERM``, ``KILL``; default ``INT``); ``GRAPHSLAM_SIGNAL_TO``
its target: ``main`` (the command's process, default; from a ``compare``
worker that is the parent), ``self`` or ``group`` (the process group, as a
terminal's Ctrl-C); ``GRAPHSLAM_SIGNAL_REPEAT=N`` sends it N times
(:data:`REPEAT_GAP_S` apart), as a user who presses Ctrl-C again.
"""

from __future__ import annotations

import errno
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from typing import Literal, get_args

from slamcore.errors import GraphSlamError, InputError

#: Where a visual run's odometry comes from (``[visual] odometry``, ``--odometry``):
#: here, not in :mod:`graphslam.pipelines.spatial`, so that the command line's parser
#: can offer them without importing the visual pipeline (OpenCV and the tracker,
#: 0.2 s of every command).
OdometryMode = Literal["auto", "sequence", "derived", "none"]
ODOMETRY_MODES: tuple[str, ...] = get_args(OdometryMode)

#: Exit status of a command stopped by each signal (128 + the signal number). SIGHUP
#: (the terminal closed) stops a command as SIGTERM does: what was estimated is written.
EXIT_STATUS_OF_SIGNAL: dict[int, int] = {signal.SIGINT: 130, signal.SIGTERM: 143}
if hasattr(signal, "SIGHUP"):  # not on Windows
    EXIT_STATUS_OF_SIGNAL[signal.SIGHUP] = 129
if hasattr(signal, "SIGQUIT"):  # Ctrl-\: killed a run with no line and lost its estimate (hostile pass 21)
    EXIT_STATUS_OF_SIGNAL[signal.SIGQUIT] = 131
STOP_SIGNALS = tuple(EXIT_STATUS_OF_SIGNAL)


def stop_signals() -> list[int]:
    """The stop signals this process catches: SIGINT and SIGTERM always, SIGHUP unless
    it was ignored at the start (``nohup``: a handler would undo the user's choice).
    A shell's background job also starts with SIGINT ignored; a command stops on
    ``kill -INT`` all the same, as it always did (scripts and test runners send it)."""
    hup = getattr(signal, "SIGHUP", None)
    return [s for s in STOP_SIGNALS if s != hup or signal.getsignal(s) is not signal.SIG_IGN]


class StopGuard:
    """The stop signals of one command (module docstring).

    Attributes:
        signum: the first stop signal received, or None.
        deferring: True once a run started: a first signal is a request.
        escalate: a second signal raises KeyboardInterrupt (not in workers).
        owner_pid: the command's process (a forked worker keeps its parent's).
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        #: the latest stop signal: the one that ended the command when a second one did
        self.latest: int | None = None
        #: said on stderr when a first signal is held (a long step that cannot stop),
        #: so the user knows it was heard: None says nothing
        self.held_note: str | None = None
        self.deferring = False
        self.escalate = True
        self.owner_pid = os.getpid()
        self._previous: dict = {}

    @property
    def requested(self) -> bool:
        return self.signum is not None

    @property
    def signal_name(self) -> str:
        """The latest stop signal's name (a SIGTERM after a held Ctrl-C ended the command:
        "interrupted (SIGINT)" named the wrong one, thirteenth hostile pass)."""
        return signal.Signals(self.latest or self.signum or signal.SIGINT).name

    def exit_status(self) -> int:
        latest = self.latest or self.signum
        if latest is None:
            return 130
        return EXIT_STATUS_OF_SIGNAL.get(latest, 130)

    def check(self) -> None:
        """Raise KeyboardInterrupt when a stop was asked for (call between steps)."""
        if self.signum is not None:
            raise KeyboardInterrupt

    def defer(self) -> None:
        """From now on a first signal is a request honoured at step boundaries."""
        self.deferring = True

    def become_worker(self) -> None:
        """In a forked worker: no request yet (the parent's stays the parent's), and
        no escalation: the parent passes on every signal it gets and kills a
        worker that does not stop in time, so a repeated signal must not cut
        the worker mid-step."""
        self.signum = self.latest = None
        self.escalate = False

    def begin_save(self) -> None:
        """Once a stop has been asked for, the rest of the command is a save (the
        estimate so far fetched or received from a worker, the files written): a
        repeated signal is then recorded, not raised, so a second Ctrl-C cannot lose
        what the first one stopped the run to keep."""
        if self.requested:
            self.escalate = False

    @contextmanager
    def waiting(self) -> Iterator[None]:
        """No escalation while the command waits for a worker's estimate (the worker is
        stopped by the signal passed on, or killed after a grace); a stop asked for
        meanwhile makes the rest a save (:meth:`begin_save`)."""
        escalate, self.escalate = self.escalate, False
        try:
            yield
        finally:
            self.escalate = escalate
            self.begin_save()

    def _handle(self, signum, frame) -> None:
        note_stop_signal(signum)
        if signum == getattr(signal, "SIGHUP", None):
            silence_closed_terminal()
        first = self.signum is None
        if first:
            self.signum = signum
        self.latest = signum
        if first and not self.deferring or not first and self.escalate:
            raise KeyboardInterrupt
        if first and self.held_note:
            # os.write: a print here could re-enter a print the signal cut (a RuntimeError)
            try:
                os.write(2, f"graphslam: {signal.Signals(signum).name}: {self.held_note}\n".encode())
            except OSError:
                pass

    def install(self) -> bool:
        """Install the handlers (main thread only); False where signals cannot be caught."""
        if threading.current_thread() is not threading.main_thread():
            return False
        for s in stop_signals():
            self._previous[s] = signal.signal(s, self._handle)
        return True

    def restore(self) -> None:
        for s, previous in self._previous.items():
            signal.signal(s, previous)
        self._previous.clear()


def silence_closed_terminal() -> None:
    """After SIGHUP: a stdout or stderr on the terminal that closed fails every write
    (EIO), which would stop the command before its files are written; point it at
    /dev/null (a pipe or a file is left as it is)."""
    for fd in (1, 2):
        try:
            os.write(fd, b"")
        except OSError as e:
            if e.errno == errno.EIO:
                to_devnull(fd)


def to_devnull(*fds: int) -> None:
    """Point the file descriptors ``fds`` at /dev/null: nothing written to them can
    fail again (a reader gone, a terminal closed), Python's exit-time flush included."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in fds:
            os.dup2(devnull, fd)
    finally:
        os.close(devnull)


_active: list[StopGuard] = []  # the guard of the command running in this process
_received: list[int] = []  # every stop signal a guard of this process received, in order


def note_stop_signal(signum: int) -> None:
    """Record ``signum`` as received by this process (:func:`stop_signals_received`)."""
    _received.append(signum)


def stop_signals_received() -> list[int]:
    """The stop signals guards (or callers of :func:`note_stop_signal`) received in this
    process, in order: a loop's own guard is gone once the loop is cut, and a caller that
    catches the KeyboardInterrupt after it, or finds the run went on, still names them."""
    return list(_received)


@contextmanager
def stop_guard() -> Iterator[StopGuard]:
    """The guard of one command, installed for the duration of the block."""
    guard = StopGuard()
    installed = guard.install()
    _active.append(guard)
    try:
        yield guard
    finally:
        _active.remove(guard)
        if installed:
            guard.restore()


def active_guard() -> StopGuard | None:
    """The command's guard, or None when the library is used without one."""
    return _active[-1] if _active else None


def stop_requested() -> bool:
    """True when the command was asked to stop (always False without a guard)."""
    guard = active_guard()
    return guard is not None and guard.requested


@contextmanager
def interrupt_between_frames() -> Iterator[StopGuard]:
    """A guard whose ``requested`` the loop checks between steps.

    Inside a command: the command's guard, now deferring (and left so: what
    follows the loop is part of the run). Without one (library use): a guard
    of its own for the loop only, so a first Ctrl-C still cuts the loop cleanly.
    """
    guard = active_guard()
    with nullcontext(guard) if guard is not None else stop_guard() as guard:
        guard.defer()
        try:
            yield guard
        finally:
            guard.begin_save()


class FrameUnreadable(InputError):
    """A frame that cannot be read cut a run after ``result`` processed some frames.

    Raised in place of the reader's :class:`InputError` (same file, line and reason)
    with ``result``, what was estimated before that frame (``interrupted``), so the
    command writes it before it reports the error: one bad file near the end of a long
    sequence stopped the run with nothing written.
    """

    def __init__(self, cause: InputError, result):
        super().__init__(cause.reason, cause.path, cause.line)
        self.result = result


class BackendFailed(GraphSlamError):
    """The back end failed at frame ``frame`` after ``result`` held some frames'
    estimate (``interrupted``): the command writes it, then reports the failure.
    A numerical failure 100 frames into a run wrote nothing (eleventh hostile pass)."""

    def __init__(self, cause: GraphSlamError, result, frame: int):
        super().__init__(str(cause))
        self.result = result
        self.frame = frame


def whole(result):
    """``result`` of a run, or KeyboardInterrupt when Ctrl-C cut it: for callers
    that score runs (benchmarks), where a cut run must not pass for a whole one."""
    if result.interrupted:
        raise KeyboardInterrupt
    return result


#: ``GRAPHSLAM_SIGNAL_REPEAT=N``: the hook's signals come this far apart (a user's
#: second Ctrl-C, faster than any hand).
REPEAT_GAP_S = 0.05


def signal_hook(point: str, step: int | None = None) -> None:
    """Test hook (module docstring): send the configured signal at ``point``."""
    spec = os.environ.get("GRAPHSLAM_SIGNAL_AT")
    if not spec or (os.getpid(), spec) in _fired:
        return
    name, _, at = spec.partition(":")
    if name != point or (at and (step is None or int(at) != step)):
        return
    _fired.add((os.getpid(), spec))
    signum = getattr(signal, "SIG" + os.environ.get("GRAPHSLAM_SIGNAL", "INT").upper())
    target = os.environ.get("GRAPHSLAM_SIGNAL_TO", "main")
    guard = active_guard()
    pid = guard.owner_pid if target == "main" and guard is not None else os.getpid()
    for k in range(int(os.environ.get("GRAPHSLAM_SIGNAL_REPEAT", "1"))):
        if k:
            time.sleep(REPEAT_GAP_S)
        if target == "group":
            os.killpg(os.getpgrp(), signum)
        else:
            os.kill(pid, signum)
        if k == 0 and guard is not None and pid == os.getpid():
            _await_handler(guard)


#: How long the hook, called off the main thread, waits for the main thread's handler.
HANDLER_WAIT_S = 5.0


def _await_handler(guard: StopGuard) -> None:
    """Called off the main thread (a solve's deep-stack thread), wait until the main
    thread's handler has taken the hook's signal: Python runs it only when the main thread
    next runs bytecode, and on a loaded machine a solve's thread ran two more LM
    iterations first, so the moment a test aimed at moved."""
    if threading.current_thread() is threading.main_thread():
        return
    deadline = time.monotonic() + HANDLER_WAIT_S
    while guard.signum is None and time.monotonic() < deadline:
        time.sleep(0.001)


_fired: set[tuple[int, str]] = set()  # the hook fires once per process (a worker too)


def progress_bar(total: int, dataset: str, backend: str, enabled: bool):
    """Progress of a run's steps on stderr (:func:`graphslam.pipelines.progress.progress`:
    a bar on a terminal, a line every few seconds in a log), or None when not ``enabled``."""
    if not enabled:
        return None
    from graphslam.pipelines.progress import progress

    return progress(total=total, desc=f"{backend} on {dataset}", unit="step")


#: Environment variable by which a sweep tells the ``graphslam run`` it starts to end
#: with it (:func:`die_with_parent`, read by the command line's main).
PARENT_PID_ENV = "GRAPHSLAM_END_WITH_PID"

#: prctl(2) option: the signal sent to this process when its parent dies.
_PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int, sig: int) -> None:
    """Have the system send ``sig`` to this process when its parent dies: a SIGKILLed
    ``compare`` left its worker running for no one, a SIGKILLed ``sweep`` its runs (as
    orphans that a re-run sweep then found writing their folders). Linux only
    (``PR_SET_PDEATHSIG``); a parent gone before it was set is seen in ``getppid``.
    Elsewhere the process ends with its work, as before."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent_pid:
        os.kill(os.getpid(), sig)
