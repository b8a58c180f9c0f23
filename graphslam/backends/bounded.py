"""Run a gtsam call whose time has no bound in a child process with a budget.

gtsam's wrappers hold the GIL for the whole of a call, so a call that runs on
cannot be stopped from Python: no timer fires, and Ctrl-C or SIGTERM wait for
it. In one CI run, Shonan averaging on a 300-pose graph that it solves in 2 s
was still running after ten minutes, until CI's own limit ended the run
(likely an unlucky random start: see :data:`.posegraph.init.SHONAN_START_SEED`).
In a forked child the parent waits in Python, so it can give up at a budget
(and kill the child) and a signal reaches it at once. Where ``fork`` does not
exist (Windows), in a daemonic process (a ``multiprocessing.Pool`` worker, which
may have no children), or where no child can be made, the call runs here,
without a budget.
"""

from __future__ import annotations

import ctypes
import math
import multiprocessing
import os
import signal
import time
from collections.abc import Callable
from typing import TypeVar

from graphslam.backends import deep_stack

T = TypeVar("T")

#: How often the parent looks at the child's pipe.
POLL_S = 0.05
#: The child ends itself this long after the budget, should its parent be gone.
ALARM_SLACK_S = 5
#: ``prctl``'s option (``<linux/prctl.h>``): a signal to the caller when its parent dies.
PR_SET_PDEATHSIG = 1


class BudgetExceeded(RuntimeError):
    """The call ran past its budget; its child process was killed."""


class Stopped(RuntimeError):
    """``should_stop`` ended the wait (a signal the caller's guard took); the child
    process was killed."""


def call(fn: Callable[..., T], budget_s: float, *args, should_stop: Callable[[], bool] | None = None) -> T:
    """``fn(*args)`` (on a deep-stack thread) in a forked child, its result or its
    exception handed back by pickling; :class:`BudgetExceeded` after ``budget_s``
    seconds, :class:`Stopped` once ``should_stop()`` is true. ``fn``'s result must
    pickle (numpy arrays, floats)."""
    if "fork" not in multiprocessing.get_all_start_methods() or multiprocessing.current_process().daemon:
        return deep_stack.call(fn, *args)
    ctx = multiprocessing.get_context("fork")
    reader, writer = ctx.Pipe(duplex=False)
    child = ctx.Process(target=_child, args=(writer, fn, args, budget_s, os.getpid()), daemon=True)
    try:
        child.start()
    except OSError:  # no process left to make (a hard limit, no memory)
        reader.close()
        writer.close()
        return deep_stack.call(fn, *args)
    writer.close()
    try:
        return _wait(reader, child, budget_s, should_stop or (lambda: False))
    finally:  # the budget, a signal in the parent, or a result: no child outlives it
        if child.is_alive():
            child.kill()
        child.join()
        reader.close()


def _wait(reader, child, budget_s: float, should_stop: Callable[[], bool]):
    t0 = time.monotonic()
    while not reader.poll(POLL_S):
        if not child.is_alive() and not reader.poll(0):
            raise _no_answer(child)
        if time.monotonic() - t0 > budget_s:
            raise BudgetExceeded(f"it ran past its {budget_s:.0f} s budget and was stopped")
        if should_stop():
            raise Stopped("a signal stopped it")
    try:
        ok, value = reader.recv()
    except EOFError:
        raise _no_answer(child) from None
    if ok:
        return value
    raise value


def _die_with(parent_pid: int) -> None:
    """Linux's ``PR_SET_PDEATHSIG``: SIGKILL to this process when its parent dies (no
    dependency of ours wraps it; ctypes, and where it is missing the alarm still bounds
    the child)."""
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):  # not Linux
        return
    prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent_pid:  # the parent died before the line above
        os._exit(1)


def _no_answer(child) -> RuntimeError:
    child.join(1.0)  # its pipe may close before its status is known
    return RuntimeError(f"its process ended with status {child.exitcode} and no answer")


def _child(writer, fn, args, budget_s: float, parent_pid: int) -> None:
    # the parent owns signals: it kills this process when it gives up
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    # should the parent be killed outright (SIGKILL runs no finally), the kernel ends
    # this one: at once where Linux's prctl says so, else after the budget by SIGALRM,
    # whose default action needs no Python, nor the GIL
    _die_with(parent_pid)
    signal.signal(signal.SIGALRM, signal.SIG_DFL)
    signal.alarm(max(1, math.ceil(budget_s) + ALARM_SLACK_S))
    try:
        answer = (True, deep_stack.call(fn, *args))
    except BaseException as exc:  # noqa: BLE001 - handed to the parent as is
        answer = (False, exc)
    try:
        writer.send(answer)
    except OSError:  # the parent gave up and closed its end: nobody to tell
        pass
    except Exception as exc:  # noqa: BLE001 - an answer that will not pickle
        try:
            writer.send((False, RuntimeError(f"{type(answer[1]).__name__}: {exc}")))
        except OSError:
            pass
    writer.close()
