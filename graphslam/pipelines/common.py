"""What the 2-D and visual pipelines share: the Ctrl-C guard and the progress bar."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def interrupt_between_frames() -> Iterator[dict]:
    """Turn the first Ctrl-C into a request honoured at the next frame boundary.

    A KeyboardInterrupt raised in the middle of a frame (say, inside an iSAM2
    update) would leave the back end half-updated and its estimate unusable;
    a second Ctrl-C still interrupts at once. Only the main thread can hold a
    signal handler; elsewhere Ctrl-C behaves as usual.
    """
    stop = {"requested": False}
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return

    def handler(signum, frame):
        if stop["requested"]:
            signal.default_int_handler(signum, frame)
        stop["requested"] = True

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield stop
    finally:
        signal.signal(signal.SIGINT, previous)


def progress_bar(total: int, dataset: str, backend: str, enabled: bool):
    """A tqdm bar on stderr, or None when ``enabled`` is False."""
    if not enabled:
        return None
    from tqdm import tqdm

    # disable=None: tqdm switches itself off when stderr is not a terminal (CI logs).
    return tqdm(total=total, desc=f"{backend} on {dataset}", unit="step", disable=None,
                dynamic_ncols=True)
