"""``graphslam compare`` on a pose graph: its whole-graph solvers on the same graph.

``isam2`` (incremental, then polished), ``batch`` (LM from the chosen start) and
``auto`` (the checked fast route) each solve the graph with the same
``[posegraph]`` settings; every run's metrics are those of ``graphslam run``
(:class:`graphslam.pipelines.posegraph.PoseGraphRunMetrics`), with the RMS of its
positions against the first solver's (same gauge: each fixes the first pose), so
a table says whether they reach one optimum and at what cost in time. A solver
that fails (one clear line) is marked and the others still run; a stop request
ends the comparison after the solver in progress, which keeps its estimate.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from graphslam.backends.posegraph.solver import SolveResult
from graphslam.pipelines.common import stop_requested
from graphslam.pipelines.posegraph import PoseGraphRunMetrics, metrics, run, solved_graph, trajectory_matrices
from slamcore import posegraph as pg
from slamcore.errors import GraphSlamError

__all__ = ["PoseGraphCompareRun", "compare"]


@dataclass
class PoseGraphCompareRun:
    """One solver's outcome: ``metrics`` and ``result``, or ``error`` (one line)."""

    backend: str
    metrics: PoseGraphRunMetrics | None = None
    result: SolveResult | None = None
    error: str | None = None
    #: RMS (m) of its positions against the first solver's, over the poses both solved
    rms_to_first_m: float | None = None
    #: a stop came before it started: "not run", as the 2-D compare says it
    not_run: bool = False

    @property
    def status(self) -> str:
        if self.not_run:
            return "not run"
        if self.error is not None:
            return "failed"
        if self.metrics is None:  # a run has its metrics or its error
            raise GraphSlamError(f"{self.backend}: a compared run with neither metrics nor error")
        return "cut" if self.metrics.interrupted else "ok"

    def to_dict(self) -> dict:
        if self.metrics is None:
            return {"backend": self.backend, "status": self.status, "error": self.error}
        return {**self.metrics.to_dict(), "status": self.status, "rms_to_first_m": self.rms_to_first_m}


def compare(
    graph: pg.PoseGraph,
    backends: list[str],
    config=None,
    truth: tuple[np.ndarray, np.ndarray] | None = None,
    progress=None,
) -> list[PoseGraphCompareRun]:
    """Solve ``graph`` with each of ``backends`` in turn (module docstring);
    ``progress(name)`` is called before each."""
    runs: list[PoseGraphCompareRun] = []
    _warm_up(graph, backends, config)
    for name in backends:
        if stop_requested():  # the rest are listed, not left out: a table short of a row reads as whole
            runs.append(PoseGraphCompareRun(name, not_run=True))
            continue
        if progress is not None:
            progress(name)
        t0 = time.perf_counter()
        try:
            result = run(graph, name, config)
        except GraphSlamError as e:
            runs.append(PoseGraphCompareRun(name, error=" ".join(str(e).splitlines())))
            continue
        runs.append(
            PoseGraphCompareRun(name, metrics(graph, result, time.perf_counter() - t0, truth), result)
        )
    first = next((r.result for r in runs if r.result is not None), None)
    for r in runs:
        if r.result is not None and first is not None:
            r.rms_to_first_m = _rms_between(graph, first, r.result)
    return runs


#: Poses of the graph's start each solver solves once, untimed, before the comparison.
WARM_UP_POSES = 4


def _warm_up(graph: pg.PoseGraph, backends: list[str], config) -> None:
    """Solve the first :data:`WARM_UP_POSES` poses with each solver, untimed: the first
    solver paid the process's one-time costs (lazy imports, first calls into gtsam), and
    the table ranked the solvers by the order they were named (0.20 s against 0.01 s on
    a small graph, either way round: hostile pass 22). A start that is not a graph of its
    own (disconnected) warms nothing; the comparison still runs."""
    from graphslam.sources.posegraph_files import truncated

    try:
        start = truncated(graph, WARM_UP_POSES)
    except GraphSlamError:
        return
    for name in dict.fromkeys(backends):  # four poses each: the stop is asked in the loop after
        try:
            run(start, name, config)
        except Exception:  # noqa: BLE001 - untimed and discarded: the real solve says its own errors
            pass


def _rms_between(graph: pg.PoseGraph, a: SolveResult, b: SolveResult) -> float | None:
    """RMS distance (m) between two solutions' positions over the poses both hold."""
    ga, gb = solved_graph(graph, a), solved_graph(graph, b)
    common, ia, ib = np.intersect1d(ga.ids, gb.ids, return_indices=True)
    if common.size == 0:
        return None
    pa = trajectory_matrices(ga, a.params)[ia, :3, 3]
    pb = trajectory_matrices(gb, b.params)[ib, :3, 3]
    return float(np.sqrt(np.mean(np.sum((pa - pb) ** 2, axis=1))))
