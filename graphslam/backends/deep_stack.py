"""Run a gtsam call on a thread with a deep stack.

gtsam eliminates and back-substitutes recursively over its elimination tree,
whose depth grows with a chain's length: batch LM on a 100 000-pose chain
overflows the main thread's 8 MiB stack and kills the interpreter (SIGSEGV, no
line, no file). No setting of gtsam avoids the recursion, so the deep calls run
on a thread whose stack is :data:`DEEP_STACK_BYTES` of address space (pages
are committed only as the recursion touches them). Signals still reach the
main thread, whose stop guard defers them while it waits.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

#: Address space of the worker's stack: 100 000 chained poses need well under
#: this (measured with ``tests/graphslam/backends/test_posegraph_deep.py``), and an untouched stack
#: costs no memory.
DEEP_STACK_BYTES = 2 << 30


def call(fn: Callable[..., T], *args, **kwargs) -> T:
    """``fn(*args, **kwargs)`` on a deep-stack thread; its exception re-raised here.
    Where no such thread can be made (a hard address-space limit), in this thread."""
    box: dict = {}

    def target():
        try:
            box["value"] = fn(*args, **kwargs)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller as is
            box["error"] = exc

    old = threading.stack_size()
    try:
        threading.stack_size(DEEP_STACK_BYTES)
        worker = threading.Thread(target=target, name="gtsam-deep-stack", daemon=True)
        worker.start()
    except (RuntimeError, ValueError, MemoryError):
        return fn(*args, **kwargs)
    finally:
        threading.stack_size(old)
    while worker.is_alive():
        worker.join(0.05)
    if "error" in box:
        raise box["error"]
    return box["value"]
