"""A gtsam call with no bound on its time runs in a child with a budget
(graphslam.backends.bounded): its answer, its exception, the budget, and a
signal in the parent all end the wait, and no child outlives it."""

from __future__ import annotations

import multiprocessing
import os
import signal
import time

import numpy as np
import pytest

from graphslam.backends import bounded
from graphslam.backends.posegraph import init
from graphslam.sources.posegraph_files import read_pose_graph_file
from tests.posegraphs import MANHATTAN_SIGMA, manhattan_walk

#: The parent notices the end of the budget within this (it polls every 50 ms).
NOTICE_S = 2.0


def _raise_value_error(text):
    raise ValueError(text)


def _kill_self():
    os.kill(os.getpid(), signal.SIGKILL)


def test_the_answer_and_the_exception_come_back_from_the_child():
    assert bounded.call(np.linalg.norm, 10.0, np.array([3.0, 4.0])) == 5.0
    assert bounded.call(os.getpid, 10.0) != os.getpid()
    with pytest.raises(ValueError, match="isotropic"):
        bounded.call(_raise_value_error, 10.0, "isotropic")
    assert not multiprocessing.active_children()


def _unpicklable():
    return lambda: None


def test_an_answer_that_will_not_pickle_is_an_error_not_a_wait():
    with pytest.raises(RuntimeError, match="^function: "):
        bounded.call(_unpicklable, 10.0)
    assert not multiprocessing.active_children()


def test_the_budget_stops_a_call_that_runs_on():
    t0 = time.monotonic()
    with pytest.raises(bounded.BudgetExceeded, match="past its 0 s budget"):
        bounded.call(time.sleep, 0.2, 60)
    assert time.monotonic() - t0 < 0.2 + NOTICE_S
    assert not multiprocessing.active_children()


def test_a_child_that_dies_is_a_failure_not_a_wait():
    with pytest.raises(RuntimeError, match="ended with status -9"):
        bounded.call(_kill_self, 30.0)
    assert not multiprocessing.active_children()


class _Alarm(Exception):
    pass


def test_a_signal_reaches_the_parent_during_the_call():
    """The parent waits in Python, not inside gtsam with the GIL held: a signal's
    handler runs at once, and the child is killed on the way out."""

    def on_alarm(signum, frame):
        raise _Alarm

    old = signal.signal(signal.SIGALRM, on_alarm)
    t0 = time.monotonic()
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.3)
        with pytest.raises(_Alarm):
            bounded.call(time.sleep, 60.0, 60)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    assert time.monotonic() - t0 < 0.3 + NOTICE_S
    assert not multiprocessing.active_children()


def test_shonan_past_its_budget_hands_over_to_the_odometry_start(tmp_path, monkeypatch):
    monkeypatch.setattr(init, "SHONAN_BUDGET_BASE_S", 0.0)
    monkeypatch.setattr(init, "SHONAN_BUDGET_PER_EDGE_S", 0.0)
    graph = read_pose_graph_file(manhattan_walk(tmp_path, sigma=np.asarray(MANHATTAN_SIGMA), seed=2))
    start = init.initial(graph, "shonan", 1e-3)
    assert start.method == "odometry"
    assert "Shonan averaging failed (BudgetExceeded: it ran past its 0 s budget" in start.note


def test_a_signal_the_guard_took_ends_shonan_and_the_retry_says_so(tmp_path):
    """Under the command line's stop guard a signal only sets a flag: ``should_stop``
    ends Shonan's wait at once, and the retry is not run."""
    from graphslam.backends.posegraph import route
    from graphslam.backends.posegraph.config import PoseGraphConfig
    from graphslam.backends.posegraph.solver import solve

    graph = read_pose_graph_file(manhattan_walk(tmp_path, sigma=np.asarray(MANHATTAN_SIGMA) * 1.5, seed=2))
    start, failure = init.relaxed(graph, "shonan", 1e-3, should_stop=lambda: True)
    assert start is None and failure == "Stopped: a signal stopped it"
    first = solve(graph, PoseGraphConfig(), "auto")
    kept = route.retry_from_certified_rotations(graph, PoseGraphConfig(), solve, first, lambda: True)
    assert kept is first
    assert kept.route["shonan_retry"] == "not certified; no retry: a signal stopped Shonan averaging"
    assert not multiprocessing.active_children()


def _sleep_then_report(path, seconds):
    time.sleep(seconds)
    open(path, "w").close()


def _orphan_left(tmp_path, budget_s: float, slack_s: int, no_prctl: bool) -> str:
    """Kill (SIGKILL) a parent waiting on a child that sleeps 60 s; after
    ``budget_s + slack_s + NOTICE_S`` the processes still running it, by pgrep."""
    import subprocess
    import sys
    import textwrap

    marker = tmp_path / "done"
    script = textwrap.dedent(f"""
        import sys
        sys.path[:0] = {sys.path!r}
        from graphslam.backends import bounded
        from tests.graphslam.backends.test_bounded import _sleep_then_report
        bounded.ALARM_SLACK_S = {slack_s}
        if {no_prctl}:
            bounded._die_with = lambda parent_pid: None
        bounded.call(_sleep_then_report, {budget_s}, {str(marker)!r}, 60)
    """)
    parent = subprocess.Popen([sys.executable, "-c", script])
    running = ""
    for _ in range(100):  # the parent, then its child, once made
        time.sleep(0.1)
        running = subprocess.run(["pgrep", "-f", str(marker)], capture_output=True, text=True).stdout.split()
        if len(running) == 2:
            break
    assert len(running) == 2, running  # else the test would pass with no child at all
    parent.kill()
    parent.wait()
    time.sleep(budget_s + slack_s + NOTICE_S if no_prctl else NOTICE_S)
    assert not marker.exists()
    return subprocess.run(["pgrep", "-f", str(marker)], capture_output=True, text=True).stdout.strip()


def test_a_child_whose_parent_is_killed_dies_with_it(tmp_path):
    """Its parent killed outright (SIGKILL: no finally runs), the child is killed by
    the kernel at once (Linux's parent-death signal), not at its 60 s budget."""
    assert _orphan_left(tmp_path, budget_s=60.0, slack_s=5, no_prctl=False) == ""


def test_without_the_parent_death_signal_the_alarm_ends_the_orphan(tmp_path):
    """Where prctl is missing, the child's own alarm ends it just past its budget."""
    assert _orphan_left(tmp_path, budget_s=1.0, slack_s=0, no_prctl=True) == ""



def test_a_signal_during_init_shonan_ends_the_wait_and_the_solve_says_so(tmp_path):
    """``--init shonan`` under the stop guard: the stop reaches Shonan's wait (point
    ``"init"``), the start is the odometry's with a note, and LM stops at once."""
    from graphslam.backends.posegraph.config import PoseGraphConfig
    from graphslam.backends.posegraph.solver import solve

    graph = read_pose_graph_file(manhattan_walk(tmp_path, sigma=np.asarray(MANHATTAN_SIGMA), seed=2))
    asked = []

    def should_stop(point, step):
        asked.append(point)
        return point == "init" or len(asked) > 1

    t0 = time.monotonic()
    result = solve(graph, PoseGraphConfig(init="shonan"), "batch", should_stop)
    assert time.monotonic() - t0 < 1.0 + NOTICE_S  # Shonan alone takes 1-2 s here
    assert asked[0] == "init" and result.stopped and result.init_method == "odometry"
    assert "--init shonan: a signal stopped Shonan averaging; LM started from the odometry start" in result.recoveries[0]
    assert not multiprocessing.active_children()


def _norm_in_a_pool_worker(_):
    return bounded.call(np.linalg.norm, 10.0, np.array([3.0, 4.0]))


def test_a_daemonic_process_runs_the_call_itself():
    """A ``multiprocessing.Pool`` worker is daemonic and may have no children: the
    call ran into multiprocessing's AssertionError there; now it runs in process."""
    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.map(_norm_in_a_pool_worker, [0]) == [5.0]
