"""A recording made in a second process, so the run does not wait for Rerun.

``--rerun save`` costs the run the Rerun SDK's import (rerun, pyarrow and the
pandas pyarrow pulls in: 1-3 s, more than 5 % of a Victoria Park run) and the
encoding of every message. :class:`BackgroundLog` stands in for a log object
(:class:`graphslam.visualisation.planar.PlanarLog`): each method call is
pickled down a pipe to a child process that owns the real log, imports Rerun
there and writes the file, on the machine's other core. Calls return None and
are applied in order; :meth:`BackgroundLog.close` waits for the child to flush
and close the file, and raises what went wrong in it, if anything. Once the
file is closed and its status sent, the child leaves by ``os._exit``: the
interpreter's teardown (Rerun's exit hooks, its modules) took 0.5-1.5 s that
the run, waiting for the child to exit, would have paid. The child runs at the
run's priority: niced, it starved on a busy machine and the run waited up to
20 s at the end for what it had not yet written.

The child is started with ``subprocess`` in a session of its own, not with
``multiprocessing``: a Ctrl-C to the terminal's process group then never reaches
it (it would die in a KeyboardInterrupt traceback, its file lost) while the run,
whose stop guard gets the signal, closes the recording with what was logged, as
in one process. Nothing in the run ignores or blocks a signal meanwhile (the
earlier way, ignoring SIGINT in the run while the child started, lost a Ctrl-C
that arrived in that window: the run went on to its end). A parent that dies
without closing leaves the child an end of file: it deletes the recording (the
earlier run's, if any, stays whole beside that run's files) and exits. A parent
that exits without closing (a Ctrl-C before the run's first step ends the command
with nothing written) abandons the child at interpreter exit and waits for it to
have deleted its file.
"""

from __future__ import annotations

import atexit
import os
import pickle
import queue
import socket
import subprocess
import sys
import threading
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

from slamcore.errors import GraphSlamError

#: What the child runs: its end of the socket is descriptor ``argv[1]``; the first
#: message is the parent's ``sys.path`` (so the factory imports as it did there, a
#: test module's class included), the second the factory and its arguments. A run
#: abandoned before sending them leaves an end of file: nothing was recorded, no word.
_CHILD = (
    "import pickle, sys\n"
    "from multiprocessing.connection import Connection\n"
    "conn = Connection(int(sys.argv[1]))\n"
    "try:\n"
    "    sys.path[:] = pickle.loads(conn.recv_bytes())\n"
    "    start = pickle.loads(conn.recv_bytes())\n"
    "except EOFError:\n"
    "    sys.exit(0)\n"
    "from graphslam.visualisation.background import _serve\n"
    "_serve(conn, *start)\n"
)


def _serve(conn, factory: Callable[..., Any], args: tuple) -> None:
    """The child: build the log, apply the calls, close on request or end of file."""
    failure = None
    try:
        log = factory(*args)
    except Exception as exc:  # reported at close, where the parent can say it
        log, failure = None, f"{type(exc).__name__}: {exc}"
    abandoned = False
    while True:
        try:
            name, a, kw = pickle.loads(conn.recv_bytes())
        except EOFError:  # the run ended without its outputs: no recording of it either
            name, a, kw = "close", (), {}
            abandoned = hasattr(log, "discard")
        if name == "close":
            break
        if log is not None and failure is None:
            try:
                getattr(log, name)(*a, **kw)
            except Exception as exc:
                failure = f"{name}: {type(exc).__name__}: {exc}"
    if abandoned:
        try:
            log.discard()
        except Exception:  # nobody is left to tell; the file is a hidden temporary
            pass
    elif log is not None:
        try:
            log.close()
        except Exception as exc:
            failure = failure or f"close: {type(exc).__name__}: {exc}"
    try:
        conn.send(failure)
    except OSError:
        pass
    # The file is flushed and closed: nothing is left to do, and the interpreter's
    # teardown (Rerun's exit hooks, freeing its modules) took 0.5-1.5 s that the run,
    # waiting in close(), would pay.
    conn.close()
    os._exit(0)


class BackgroundLog:
    """``factory(*args)`` built and driven in a child process (module docstring)."""

    def __init__(self, factory: Callable[..., Any], *args: Any):
        # pickled first: a factory that cannot be sent fails here, before any child exists
        start = [
            pickle.dumps(list(sys.path), pickle.HIGHEST_PROTOCOL),
            pickle.dumps((factory, args), pickle.HIGHEST_PROTOCOL),
        ]
        ours, theirs = socket.socketpair()
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-c", _CHILD, str(theirs.fileno())],
                pass_fds=(theirs.fileno(),),
                stdin=subprocess.DEVNULL,
                start_new_session=True,
            )  # module docstring
        except BaseException:
            ours.close()
            raise
        finally:
            theirs.close()
        self._conn = Connection(ours.detach())
        self._closed = False
        # A socket holds some 200 kB: sent from the run's thread, calls would wait for the
        # child to finish importing Rerun. A sender thread takes them from an unbounded
        # queue, the start messages first.
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        for message in start:
            self._queue.put(message)
        self._sender = threading.Thread(target=self._send_all, name="graphslam-recording-sender", daemon=True)
        self._sender.start()
        atexit.register(self.abandon)

    def _send_all(self) -> None:
        while True:
            message = self._queue.get()
            if message is None:  # close
                return
            try:
                self._conn.send_bytes(message)
            except OSError:  # the child is gone: close() says why
                return

    def __getattr__(self, name: str) -> Callable[..., None]:
        if name.startswith("_"):
            raise AttributeError(name)

        def call(*args: Any, **kwargs: Any) -> None:
            # pickled now: the caller may change its lists after the call returns
            self._queue.put(pickle.dumps((name, args, kwargs), pickle.HIGHEST_PROTOCOL))

        return call

    def close(self) -> None:
        """Wait for the child to write and close the recording.

        Raises:
            GraphSlamError: the child failed (the message says where) or died.
        """
        if self._closed:
            return
        self._closed = True
        atexit.unregister(self.abandon)
        self._queue.put(None)
        self._sender.join()
        try:
            self._conn.send_bytes(pickle.dumps(("close", (), {})))
            failure = self._conn.recv()
        except (OSError, EOFError):
            failure = f"the recording process exited with status {self._proc.wait()}"
        self._proc.wait()
        self._conn.close()
        if failure is not None:
            raise GraphSlamError(f"recording failed: {failure}")

    #: Seconds an abandoned child has to delete its partial file and exit before it is
    #: killed (it reads the call being sent, then the end of file).
    ABANDON_WAIT_S = 30.0

    def abandon(self) -> None:
        """End the child without a recording: calls not yet sent are dropped, the pipe
        is closed, and the child, reading its end, deletes the partial file and exits
        (killed if it has not within :data:`ABANDON_WAIT_S`). Called at interpreter
        exit for a log never closed."""
        if self._closed:
            return
        self._closed = True
        atexit.unregister(self.abandon)
        try:
            while True:
                self._queue.get_nowait()
        except queue.Empty:
            pass
        self._queue.put(None)
        # the sender finishes the message it is writing (the child reads it) and stops;
        # only then is the pipe closed, so no write can reach a reused descriptor
        self._sender.join()
        self._conn.close()
        try:
            self._proc.wait(self.ABANDON_WAIT_S)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
