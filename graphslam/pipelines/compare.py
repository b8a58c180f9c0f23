"""Several back ends on the same stream: one table, one JSON, plots, one recording.

Each back end runs in a forked child process on the same in-memory dataset
(same seed, same observations), so its wall time and peak memory are its own:
``peak_rss_mb`` is the child's peak resident set above its resident set when
it started. Rerun logging happens afterwards in the parent, off the clock.
"""

from __future__ import annotations

import multiprocessing as mp
import resource
import traceback
from dataclasses import dataclass

from graphslam import registry
from graphslam.evaluation import planar as metrics
from graphslam.evaluation.records import PlanarRunMetrics
from graphslam.pipelines import planar as pipeline
from slamcore.errors import GraphSlamError
from slamcore.planar.records import Dataset

@dataclass
class CompareEntry:
    backend: str
    result: pipeline.RunResult
    metrics: PlanarRunMetrics


def _run_one(dataset: Dataset, name: str, config, overrides, max_steps) -> tuple:
    backend = registry.make_backend(name, config=config, overrides=overrides)
    result = pipeline.run(dataset, backend, max_steps=max_steps, with_covariances=True)
    return result


def _child(conn, dataset, name, config, overrides, max_steps):
    try:
        start_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        result = _run_one(dataset, name, config, overrides, max_steps)
        peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        result.dataset = None  # the parent has it; don't send it back
        conn.send(("ok", result, (peak_kb - start_kb) / 1024.0))
    except GraphSlamError as e:
        conn.send(("error", str(e), None))
    except BaseException:  # report anything else with its traceback to the parent
        conn.send(("crash", traceback.format_exc(), None))
    finally:
        conn.close()


def run_isolated(dataset: Dataset, name: str, config=None, overrides=None,
                 max_steps=None) -> tuple[pipeline.RunResult, float]:
    """Run one back end in a forked child; returns its result and peak RSS (MB)."""
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(child, dataset, name, config, overrides,
                                            max_steps))
    proc.start()
    child.close()
    try:
        status, payload, peak_mb = parent.recv()
    except EOFError:
        proc.join()
        raise GraphSlamError(f"{name}: worker died (exit code {proc.exitcode})") from None
    except KeyboardInterrupt:
        proc.terminate()
        proc.join()
        raise
    proc.join()
    if status == "error":
        raise GraphSlamError(payload)
    if status == "crash":
        raise RuntimeError(f"{name} crashed in its worker:\n{payload}")
    payload.dataset = dataset
    return payload, peak_mb


def compare(dataset: Dataset, backends: list[str], *, config=None,
            overrides: dict[str, dict] | None = None, max_steps: int | None = None,
            isolate: bool = True, seed: int | None = None, progress=None) -> list[CompareEntry]:
    """Run each back end on ``dataset``; return results with their metrics.

    Args:
        overrides: per back-end config overrides, ``{name: {key: value}}``.
        isolate: run each back end in its own forked process (timing and memory
            are its own); False runs them in this process (no memory figure).
        progress: optional callable ``progress(name)`` called before each run.
    """
    entries = []
    for name in backends:
        if progress is not None:
            progress(name)
        ov = (overrides or {}).get(name, {})
        if isolate:
            result, peak_mb = run_isolated(dataset, name, config, ov, max_steps)
        else:
            result, peak_mb = _run_one(dataset, name, config, ov, max_steps), None
        m = pipeline.compute_metrics(result, seed=seed)
        m.peak_rss_mb = peak_mb
        if m.association is not None:
            m.association.oracle_accuracy = metrics.oracle_association_accuracy(
                dataset, result.steps)
        for key, value in metrics.pose_statistics(dataset, result.estimate).items():
            setattr(m, key, value)
        entries.append(CompareEntry(name, result, m))
    reference = next((e for e in entries if e.backend == "isam2"), None)
    if reference is not None:
        for e in entries:
            e.metrics.rms_to_isam2_m = metrics.rms_position_distance(e.result.estimate,
                                                                     reference.result.estimate)
    return entries
