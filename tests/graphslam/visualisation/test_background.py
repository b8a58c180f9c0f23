"""The recording process (graphslam.visualisation.background) opened from any thread."""

from __future__ import annotations

import threading

from graphslam.visualisation.background import BackgroundLog


class _Log:
    """A log that records nothing: the child process builds it, the parent closes it."""

    def close(self) -> None:
        pass


def test_a_recording_opens_from_a_thread_other_than_the_main_one():
    """Signal handlers can be set from the main thread only: opening a recording from
    another (a caller's worker thread) raised ValueError before."""
    errors: list[str] = []

    def open_and_close():
        try:
            BackgroundLog(_Log).close()
        except Exception as exc:  # the assertion below reports it
            errors.append(repr(exc))

    worker = threading.Thread(target=open_and_close)
    worker.start()
    worker.join(timeout=300)
    assert not worker.is_alive() and errors == []
