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

The child ignores SIGINT and SIGTERM (they are blocked while it starts, and it
inherits the mask; then ignored, which holds for every thread): a Ctrl-C to the
process group stops the run, whose stop guard then closes the
recording with what was logged, as in one process. A parent that dies
without closing leaves the child an end of file: it deletes the recording (the
earlier run's, if any, stays whole beside that run's files) and exits.
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
import queue
import signal
import threading
from collections.abc import Callable
from typing import Any

from slamcore.errors import GraphSlamError

_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


def _serve(conn, factory: Callable[..., Any], args: tuple) -> None:
    """The child: build the log, apply the calls, close on request or end of file."""
    signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)  # kept whatever the start method
    # and ignored: a mask is per thread, and a thread the Rerun SDK starts may unblock them
    # (seen: one thread of the child with no signal blocked took a Ctrl-C sent to the
    # process group, and the child died in a KeyboardInterrupt traceback, its file lost)
    for stop in _STOP_SIGNALS:
        signal.signal(stop, signal.SIG_IGN)
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
        ctx = multiprocessing.get_context("spawn")  # no fork of a process holding gtsam's threads
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(child, factory, args), daemon=True,
                                 name="graphslam-recording")
        # The spawned child starts with no signal blocked (fork_exec resets the mask) but
        # keeps what is ignored, and Python leaves an ignored SIGINT ignored: so the stop
        # signals are ignored here while it starts, and the child never sees a Ctrl-C to
        # the process group, even while it imports (measured: 2 of 6 runs stopped 3 s in
        # died importing numpy, their recording lost). Blocked first, so that a signal for
        # this thread meanwhile is held, not ignored, and reaches the restored handler.
        old = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
        # handlers can be set from the main thread only (elsewhere: the child's own SIG_IGN)
        main = threading.current_thread() is threading.main_thread()
        handlers = {stop: signal.signal(stop, signal.SIG_IGN) for stop in _STOP_SIGNALS} \
            if main else {}
        try:
            self._proc.start()
        finally:
            for stop, handler in handlers.items():
                signal.signal(stop, handler)
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        child.close()
        self._closed = False
        # A pipe holds 64 kB: sent from the run's thread, calls would wait for the child
        # to finish importing Rerun. A sender thread takes them from an unbounded queue.
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._sender = threading.Thread(target=self._send_all, name="graphslam-recording-sender",
                                        daemon=True)
        self._sender.start()

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
        self._queue.put(None)
        self._sender.join()
        try:
            self._conn.send_bytes(pickle.dumps(("close", (), {})))
            failure = self._conn.recv()
        except (OSError, EOFError):
            failure = f"the recording process exited with status {self._proc.exitcode}"
        self._proc.join()
        self._conn.close()
        if failure is not None:
            raise GraphSlamError(f"recording failed: {failure}")
