"""Several back ends on the same stream: one table, one JSON, plots, one recording.

:func:`run_entries` is what 2-D and image comparisons share (one process per
back end, failures and signals); :func:`compare` is the 2-D one and
:mod:`graphslam.pipelines.compare_spatial` the one on image sequences.

Each back end runs in a forked child process on the same in-memory dataset
(same seed, same observations), so its wall time and peak memory are its own:
``peak_rss_mb`` is the child's peak resident set above its resident set when
it started. Rerun logging happens afterwards in the parent, off the clock.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import resource
import signal
import time
import traceback
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass
from typing import Any, TypeVar, cast

import numpy as np

from graphslam import registry
from graphslam.evaluation import planar as metrics
from graphslam.evaluation.records import PlanarRunMetrics
from graphslam.pipelines import planar as pipeline
from graphslam.pipelines.common import active_guard, die_with_parent, interrupt_between_frames, stop_requested
from slamcore.errors import GraphSlamError
from slamcore.planar.records import Dataset

R = TypeVar("R")

#: How long a worker asked to stop may take to send what it has, seconds; then
#: it is killed (its row says so).
STOP_GRACE_S = 20.0
#: How often the parent checks for a stop request while a worker runs, seconds.
POLL_S = 0.1
#: Numerical breakdowns of a back end or of its scoring (a singular or
#: non-finite covariance from absurd settings or data): a one-line "failed"
#: entry like a GraphSlamError, not a traceback, and never the others' loss.
NUMERIC_FAILURES = (np.linalg.LinAlgError, FloatingPointError, OverflowError, ZeroDivisionError)


@dataclass
class CompareEntry:
    """One back end's row: ``status`` "ok", "cut" (stopped by a signal, or by a frame
    that cannot be read, which ``error`` then names; the estimate so far), "failed" or
    "not run" (the comparison was stopped first);
    ``result`` and ``metrics`` are None unless ok or cut; ``error`` says why not;
    ``nees``: the per-frame pose NEES record of an image comparison
    (:func:`graphslam.evaluation.spatial.pose_nees`), when there is one."""

    backend: str
    result: Any  # a 2-D RunResult or a VisualRunResult
    metrics: Any  # PlanarRunMetrics or SpatialRunMetrics
    status: str = "ok"
    error: str | None = None
    nees: dict | None = None


def finished(entries: list[CompareEntry]) -> list[CompareEntry]:
    """The entries with a result (ok or cut)."""
    return [e for e in entries if e.result is not None]


def _run_one(dataset: Dataset, name: str, config, overrides, max_steps) -> pipeline.RunResult:
    backend = registry.make_backend(name, config=config, overrides=overrides)
    chained = registry.landmark_implementation(name).filtering  # refused before, not part way
    return pipeline.run(dataset, backend, max_steps=max_steps, with_covariances=True, chained=chained)


def _child(conn, job, strip, parents_end=None, parent_pid: int | None = None):
    if parent_pid is not None:
        die_with_parent(parent_pid, signal.SIGKILL)  # its result goes to the parent only
    # the parent's end, inherited by the fork, closed: a parent that died (SIGKILL)
    # then makes the send below fail instead of blocking on a pipe nobody reads
    if parents_end is not None:
        parents_end.close()
    guard = active_guard()
    if guard is not None:
        guard.become_worker()
    message: tuple[str, Any, float | None]
    try:
        try:
            start_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            result = job()
            peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            message = ("ok", result if strip is None else strip(result), (peak_kb - start_kb) / 1024.0)
        except GraphSlamError as e:
            message = ("error", str(e), None)
        except NUMERIC_FAILURES as e:
            message = ("error", numeric_failure_line(e), None)
        except KeyboardInterrupt:  # stopped before its first step: nothing to send
            message = ("error", "stopped before its first step", None)
        except BaseException:  # report anything else with its traceback to the parent
            message = ("crash", traceback.format_exc(), None)
        try:
            conn.send(message)
        except OSError:  # the parent is gone (BrokenPipeError): no one to tell
            pass
        except BaseException:  # a result that cannot be sent: a bug, reported as one
            conn.send(("crash", traceback.format_exc(), None))
    finally:
        conn.close()


def run_isolated(job: Callable[[], R], name: str, strip: Callable[[R], R] | None = None) -> tuple[R, float]:
    """Run ``job()`` (one back end's run) in a forked child; returns its result and
    peak RSS (MB). ``strip`` lightens the result before it is sent back (drops
    what the parent already holds, e.g. the dataset).

    A stop request of this process (:mod:`graphslam.pipelines.common`) is passed
    on to the child, which sends the estimate it has; a child that does not
    answer within :data:`STOP_GRACE_S`, and any child still alive when this
    returns or raises, is killed: none is left behind.
    """
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(child, job, strip, parent, os.getpid()))
    proc.start()
    child.close()
    try:
        message = _wait_for(proc, parent, name)
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join()
        parent.close()
    if message is None:
        raise GraphSlamError(f"{name}: worker died (exit code {proc.exitcode})")
    status, payload, peak_mb = message
    if status == "error":
        raise GraphSlamError(payload)
    if status == "crash":
        raise BackendCrash(f"{name} crashed in its worker:\n{payload}")
    return payload, peak_mb


class BackendCrash(RuntimeError):
    """A back end raised something that is not a GraphSlamError (a bug): the text
    holds its traceback."""


def _wait_for(proc, conn, name: str):
    """The worker's message, or None if it died without one; forwards a stop
    request to it and kills it when it does not answer in time."""
    # a repeated signal must not drop the estimate the worker is sending
    guard = active_guard()
    with guard.waiting() if guard is not None else nullcontext():
        return _poll(proc, conn, name)


def _poll(proc, conn, name: str):
    deadline = None
    while not conn.poll(POLL_S):  # True on a message and on the pipe's end (child gone)
        if not proc.is_alive():
            break
        if deadline is None and stop_requested():
            os.kill(proc.pid, signal.SIGINT)
            deadline = time.monotonic() + STOP_GRACE_S
        elif deadline is not None and time.monotonic() > deadline:
            raise GraphSlamError(f"{name}: did not stop within {STOP_GRACE_S:.0f} s; killed")
    try:
        return conn.recv() if conn.poll() else None
    except EOFError:
        return None


def compare(
    dataset: Dataset,
    backends: list[str],
    *,
    config=None,
    overrides: dict[str, dict] | None = None,
    max_steps: int | None = None,
    isolate: bool = True,
    seed: int | None = None,
    progress=None,
) -> list[CompareEntry]:
    """Run each 2-D back end on ``dataset``; return one entry per back end, in order
    (:func:`run_entries`).

    Args:
        overrides: per back-end config overrides, ``{name: {key: value}}``.
        isolate: run each back end in its own forked process (timing and memory
            are its own); False runs them in this process (no memory figure).
        progress: optional callable ``progress(name)`` called before each run.
    """

    def job(name):
        return lambda: _run_one(dataset, name, config, (overrides or {}).get(name, {}), max_steps)

    def score(name, result, peak_mb):
        result.dataset = dataset  # the worker sent it back without (strip)
        return _score(dataset, result, peak_mb, seed)

    entries = run_entries(backends, job, score, isolate=isolate, strip=_without_dataset, progress=progress)
    reference = next(
        (e for e in entries if registry.backend_row(e.backend).reference and e.result is not None), None
    )
    if reference is not None:
        for e in finished(entries):
            e.metrics.rms_to_isam2_m = metrics.rms_position_distance(
                e.result.estimate, reference.result.estimate
            )
            if e is not reference:
                _against_reference(e, reference)
    return entries


def _against_reference(e: CompareEntry, reference: CompareEntry) -> None:
    """``sigmas_to_isam2`` of ``e``, and the line saying an estimate an order of
    magnitude beyond its own covariance (not for a particle filter's sample covariance,
    which no such test holds for: the table's ``sample_covariance``)."""
    m = e.metrics
    m.sigmas_to_isam2 = metrics.sigmas_to_reference(e.result.estimate, reference.result.estimate)
    row = registry.backend_row(e.backend).landmarks
    if row is not None and not row.sample_covariance:
        said = metrics.reference_warning(m.sigmas_to_isam2, m.rms_to_isam2_m)
        m.warnings = [*(m.warnings or []), *said] or None


def _without_dataset(result: pipeline.RunResult) -> pipeline.RunResult:
    # the parent has it; don't send it back (None in transit only: the parent puts it back)
    result.dataset = cast(Dataset, None)
    return result


def run_entries(
    names: list[str], job, score, *, isolate: bool = True, strip=None, progress=None
) -> list[CompareEntry]:
    """One entry per name, in order: ``job(name)()`` runs that back end (in a forked
    child when ``isolate``), ``score(name, result, peak_mb)`` gives its metrics.

    A back end that fails is a "failed" entry and the others still run; a stop
    request (SIGINT, SIGTERM) cuts the running back end (a "cut" entry with its
    estimate so far) and leaves the rest "not run". ``result.interrupted`` marks
    a cut result.
    """
    entries = []
    with interrupt_between_frames() as stop:
        for name in names:
            if stop.requested:
                entries.append(CompareEntry(name, None, None, "not run", "stopped before it"))
                continue
            if progress is not None:
                progress(name)
            entries.append(_compare_one(name, job(name), score, isolate, strip))
    return entries


def numeric_failure_line(e: BaseException) -> str:
    """One line for a numerical breakdown (:data:`NUMERIC_FAILURES`)."""
    return f"numerical failure ({type(e).__name__}: {e}); check the noise settings and the data"


def _compare_one(name, job, score, isolate, strip) -> CompareEntry:
    """One back end's entry; its failure is recorded, not raised. Scoring is
    inside the guard too: an estimate too absurd to score (a singular
    covariance) fails its own row, not the whole comparison. The metrics' ``wall_s`` is
    the entry's whole time (its process, the back end's set-up and run, the scoring), as
    ``run``'s is the whole run's; ``backend_s`` or ``processing_s`` keeps the back end's."""
    t0 = time.perf_counter()
    try:
        if isolate:
            result, peak_mb = run_isolated(job, name, strip)
        else:
            result, peak_mb = job(), None
        scored = score(name, result, peak_mb)
        if hasattr(scored, "wall_s"):  # (compare.json's wall_s was the back end's alone)
            scored.wall_s = time.perf_counter() - t0
    except KeyboardInterrupt:  # a second signal while it ran: this one is lost, the others kept
        return CompareEntry(
            name, None, None, "cut", "a second signal cut it before it could stop; no estimate"
        )
    except GraphSlamError as e:  # a worker asked to stop and killed for not stopping is cut
        return CompareEntry(name, None, None, "cut" if stop_requested() else "failed", str(e))
    except NUMERIC_FAILURES as e:
        return CompareEntry(name, None, None, "failed", f"{name}: {numeric_failure_line(e)}")
    except Exception:  # a bug in one back end must not lose the others' results
        return CompareEntry(name, None, None, "failed", traceback.format_exc())
    # a frame that could not be read ended it early: cut, and why (an image compare)
    return CompareEntry(
        name, result, scored, "cut" if result.interrupted else "ok", getattr(result, "unreadable", None)
    )


def _score(dataset, result, peak_mb, seed) -> PlanarRunMetrics:
    """The 2-D metrics of one finished run, with its peak memory and pose NEES."""
    m = pipeline.compute_metrics(result, seed=seed)
    m.peak_rss_mb = peak_mb
    if m.association is not None:
        m.association.oracle_accuracy = metrics.oracle_association_accuracy(dataset, result.steps)
    stats = metrics.pose_statistics(dataset, result.estimate)
    for key in ("final_pose_error_m", "nees_mean", "nees_in_bounds_fraction"):
        setattr(m, key, stats[key])
    if stats["frame_doubt"] is not None:  # every back end shares it: said once (warn_doubts)
        m.warnings = [*(m.warnings or []), stats["frame_doubt"]]
    if (doubt := metrics.nees_doubt(m.nees_mean, metrics.POSE_DOF)) is not None:
        m.warnings = [*(m.warnings or []), doubt]
    return m
