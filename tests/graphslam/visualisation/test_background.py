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


def test_opening_a_recording_leaves_the_runs_signals_alone_and_the_child_apart(monkeypatch):
    """A Ctrl-C that arrives while the recording process starts must reach the run:
    before, the run ignored SIGINT for that moment and such a Ctrl-C was lost (the run
    went on to its end). The child has a session of its own, so a Ctrl-C to the
    terminal's process group does not reach it."""
    import os
    import signal

    touched: list[str] = []
    real_signal, real_mask = signal.signal, signal.pthread_sigmask
    monkeypatch.setattr(signal, "signal", lambda *a: touched.append("signal") or real_signal(*a))
    monkeypatch.setattr(signal, "pthread_sigmask",
                        lambda *a: touched.append("pthread_sigmask") or real_mask(*a))
    log = BackgroundLog(_Log)
    monkeypatch.undo()
    try:
        assert touched == []
        assert os.getsid(log._proc.pid) != os.getsid(0)
    finally:
        log.close()
