"""``graphslam eval``: score trajectory files of any origin against a reference.

Reads the files (TUM, KITTI with an optional times file, EuRoC; told from the
content or given), scores each estimate with
:func:`graphslam.evaluation.trajectory.evaluate` and writes ``eval.json``:
``{"ground_truth", "options", "estimates": [{"estimate", <metrics>, "options"}]}``
with the metric keys of :meth:`TrajectoryEval.summary` (null where not
computable, e.g. the KITTI drift of a path under 100 m), among them
``matched_poses``, ``estimate_poses`` and ``matched_share``: the ATE covers the
matched poses only, and :func:`coverage_warnings` says so when they are few.
:func:`eval_warnings` adds what makes a score doubtful (a unit, convention or clock
mix-up: :func:`stamp_doubts` and :mod:`graphslam.evaluation.trajectory_doubts`),
also kept in ``eval.json`` as the estimate's ``warnings``. With several
estimates, those that could not be read or scored are under ``"refused"``
(``[{"estimate", "error"}]``) and the others are scored.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from graphslam.evaluation.records import LOW_MATCHED_SHARE
from graphslam.evaluation.trajectory import (
    DEFAULT_MAX_DIFF_S,
    DEFAULT_OFFSET_S,
    STAMP_MAX_S,
    EvalOptions,
    TrajectoryEval,
    evaluate,
)
from graphslam.evaluation.trajectory_doubts import clock_doubts, doubts
from graphslam.pipelines.common import signal_hook
from graphslam.sources.ground_truth import Trajectory, check_not_colmap, read_times, read_trajectory
from slamcore.errors import ConfigError, GraphSlamError, InputError, LocatedError


@dataclass
class EstimateResult:
    """One estimate file and its score."""

    path: str
    result: TrajectoryEval
    #: the shortest end of ``path`` that no other estimate of the same call shares
    #: (``a/trajectory.tum`` and ``b/trajectory.tum``, not two ``trajectory.tum``)
    label: str = ""
    #: what makes the score doubtful, one sentence each (:func:`eval_warnings`)
    warnings: list[str] = field(default_factory=list)
    #: what the reference's stamps are (:func:`stamp_kind`), for the plot's time axis
    stamps: str = "s"

    def to_dict(self, options: EvalOptions) -> dict:
        return {
            "estimate": self.path,
            "label": self.label or Path(self.path).name,
            **self.result.summary(),
            **({"warnings": self.warnings} if self.warnings else {}),
            "options": options.to_dict(),
        }


def distinct_labels(paths: Sequence[str | Path]) -> list[str]:
    """Per path, its file name, with as many parent folders as it takes for no two
    labels to be equal (the whole path for a path given twice)."""
    parts = [Path(p).parts or (str(p),) for p in paths]
    depth = [1] * len(parts)
    while True:
        labels = [str(Path(*pp[-d:])) for pp, d in zip(parts, depth, strict=True)]
        clash = {lab for lab in labels if labels.count(lab) > 1}
        grow = [i for i, lab in enumerate(labels) if lab in clash and depth[i] < len(parts[i])]
        if not grow:
            return labels
        for i in grow:
            depth[i] += 1


def load(path: Path, fmt: str | None, times: Path | None) -> Trajectory:
    """A trajectory file; a KITTI one takes its stamps from ``times`` when given.
    ``BAG:TOPIC`` (or a bag with one pose topic): the poses of PoseStamped,
    TransformStamped or Odometry messages at their header stamps (``fmt`` and
    ``times`` are for files)."""
    from graphslam.sources.spatial.rosbag import read_bag_trajectory, split_bag_spec

    bag = split_bag_spec(path)
    if bag is not None:
        return read_bag_trajectory(*bag)
    trajectory = read_trajectory(path, fmt)
    check_not_colmap(trajectory, "eval pairs poses by time or line")
    if times is not None and trajectory.stamps_s is None:
        trajectory = read_times(times, trajectory)
    return trajectory


def evaluate_files(
    ground_truth: Path,
    estimates: list[Path],
    options: EvalOptions,
    *,
    fmt: str | None = None,
    times: Path | None = None,
    should_stop: Callable[[], bool] | None = None,
    refused: list[tuple[Path, str]] | None = None,
) -> list[EstimateResult]:
    """Score every estimate against ``ground_truth`` (same format and times options).

    ``should_stop()``, asked before each estimate: True ends the scoring
    there, and the estimates scored so far are returned (``eval`` stopped by a signal
    writes them; the rest are the caller's to name). ``refused``: with several
    estimates, one that cannot be read or scored is appended there as ``(path, why)``
    and the others are scored (hostile pass 17: an estimate that does not move lost the
    scores of the valid ones); without it, or when every estimate is refused, the
    first refusal is raised."""
    ref = load(ground_truth, fmt, times)
    signal_hook("eval")  # (test hook: a stop before any estimate is scored)
    keep_going = refused is not None and len(estimates) > 1
    failures: list[tuple[Path, GraphSlamError]] = []

    def attempt(path: Path, work: Callable):
        try:
            return work()
        except GraphSlamError as e:
            if not keep_going:
                raise
            failures.append((path, e))
            return None

    loaded = [
        (path, label, t)
        for path, label in zip(estimates, distinct_labels(estimates), strict=True)
        if (t := attempt(path, lambda p=path: load(p, fmt, times))) is not None
    ]
    if times is not None and all(t.format != "kitti" for t in [ref] + [t for _, _, t in loaded]):
        # the files have their own stamps: a times file that changes nothing is refused
        raise ConfigError("--times gives KITTI files their stamps; none of these files is KITTI", times)
    unstamped = ref.stamps_s is None and all(t.stamps_s is None for _, _, t in loaded)
    moved = [
        flag
        for flag, value, default in (
            ("--max-diff", options.max_diff_s, DEFAULT_MAX_DIFF_S),
            ("--offset", options.offset_s, DEFAULT_OFFSET_S),
        )
        if value != default
    ]
    if unstamped and moved:  # paired by line: the flags would be recorded as if applied
        raise ConfigError(
            f"{' and '.join(moved)} act{'' if len(moved) > 1 else 's'} on timestamps, and these files "
            "have none (KITTI: paired by "
            "line); give them times with --times"
        )
    results: list[EstimateResult] = []
    for path, label, est in loaded:
        if should_stop is not None and should_stop():
            break  # the caller writes the estimates scored so far
        r = attempt(
            path, lambda p=path, lab=label, e=est: _score(ground_truth, ref, p, lab, e, estimates, options)
        )
        if r is not None:
            results.append(r)
    if failures and not results and not (should_stop is not None and should_stop()):
        raise failures[0][1]
    if refused is not None:
        refused.extend((path, str(e)) for path, e in failures)
    return results


def _score(
    ground_truth: Path,
    ref: Trajectory,
    path: Path,
    label: str,
    est: Trajectory,
    estimates: list[Path],
    options: EvalOptions,
) -> EstimateResult:
    """One estimate's :class:`EstimateResult` against the loaded reference ``ref``."""
    try:
        result = evaluate(ref.stamps_s, ref.wTc, est.stamps_s, est.wTc, options)
    except LocatedError:
        raise
    except GraphSlamError as e:  # which estimate of several, scored against which file
        raise InputError(f"{e} (scored against {ground_truth})", path) from None
    said = stamp_doubts(ref, est) + clock_doubts(ref.stamps_s, est.stamps_s, options, len(result.ref))
    said += doubts(result, options) + same_file_doubts(ground_truth, path, estimates)
    return EstimateResult(str(path), result, label, said, stamp_kind(ref.stamps_s))


def _same_file(a: Path, b: Path) -> bool:
    """One file under two names (a bag's ``FILE:/topic`` is no file name: never)."""
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def same_file_doubts(ground_truth: Path, path: Path, estimates: list[Path]) -> list[str]:
    """The estimate is the ground-truth file itself (its errors are 0 by construction),
    or an earlier estimate of the call again: said, never scored silently."""
    out = []
    if _same_file(path, ground_truth):
        out.append("this is the ground-truth file itself: its errors are 0 by construction")
    earlier = next((e for e in estimates if e is path or _same_file(e, path)), path)
    if earlier is not path:
        out.append(f"this is {earlier} again: the same estimate scored twice")
    return out


def _frame_indices(t: np.ndarray | None) -> bool:
    """Stamps 0, 1, 2, ... (a graphslam trajectory of a sequence without times)."""
    return t is not None and t.size > 1 and bool(np.array_equal(t, np.arange(t.size, dtype=np.float64)))


def stamp_kind(t: np.ndarray | None) -> str:
    """What stamps ``t`` are: "line" (none, KITTI: poses paired by line), "index"
    (0, 1, 2, ...: frame indices as graphslam writes a sequence without times, or
    whole seconds; the file cannot tell) or "s" (seconds)."""
    if t is None:
        return "line"
    return "index" if _frame_indices(t) else "s"


def stamp_doubts(ref: Trajectory, est: Trajectory) -> list[str]:
    """Sentences on stamps that pair the wrong poses without failing: KITTI files of
    different lengths paired by line, stamps too large to be seconds, frame indices
    against times."""
    out = [f"the {who}'s {note}" for who, t in (("reference", ref), ("estimate", est)) for note in t.notes]
    if ref.stamps_s is None and est.stamps_s is None and len(ref.wTc) != len(est.wTc):
        n = min(len(ref.wTc), len(est.wTc))
        out.append(
            f"KITTI files pair by line: the estimate has {len(est.wTc)} poses, the reference "
            f"{len(ref.wTc)}, so the first {n} of each are taken as the same frames (an estimate "
            "of some frames only, keyframes, is scored against the wrong poses; give both "
            "files' times with TUM files, or --times)"
        )
    for who, t in (("reference", ref.stamps_s), ("estimate", est.stamps_s)):
        if t is not None and t.size and float(np.max(np.abs(t))) > STAMP_MAX_S:
            out.append(
                f"the {who}'s times reach {float(np.max(np.abs(t))):.4g}: not seconds "
                "(nanoseconds, milliseconds?); --max-diff and --offset are compared with "
                "them as seconds"
            )
    for who, t, other in (
        ("estimate", est.stamps_s, ref.stamps_s),
        ("reference", ref.stamps_s, est.stamps_s),
    ):
        if _frame_indices(t) and other is not None and not np.all(np.mod(other, 1.0) == 0):
            out.append(
                f"the {who}'s times are 0, 1, 2, ... (frame indices, as graphslam writes a "
                "sequence without times) and the other file's are not whole numbers: paired "
                "by time, frame k took the pose at k s"
            )
    return out


def coverage_warnings(results: list[EstimateResult], options: EvalOptions) -> list[str]:
    """One sentence per estimate of which fewer than :data:`LOW_MATCHED_SHARE` of
    the poses matched the reference."""
    out = []
    for r in results:
        e = r.result
        if e.matched_share < LOW_MATCHED_SHARE:
            out.append(
                f"{r.label or Path(r.path).name}: only {len(e.ref)} of {e.estimate_poses} poses "
                f"({100 * e.matched_share:.0f} %) matched the reference (max diff "
                f"{options.max_diff_s} s, offset {options.offset_s} s); the ATE covers "
                "those alone"
            )
        elif e.reference_share is not None and e.reference_share < LOW_MATCHED_SHARE:
            out.append(  # (the reverse of the case above)
                f"{r.label or Path(r.path).name}: the {len(e.ref)} matched poses span "
                f"{100 * e.reference_share:.0f} % of the reference's time: the ATE scores that "
                "part alone"
            )
        if options.align == "se3" and len(e.ref) < 3:
            # two positions and a rigid fit: only their distance apart is left to score
            # (hostile pass 17: an ATE of 0.0000, nothing said)
            out.append(
                f"{r.label or Path(r.path).name}: only {len(e.ref)} poses matched, and an SE(3) fit "
                "to 2 positions leaves only their distance apart to score: the ATE says almost "
                "nothing (--align first scores them without a fit)"
            )
        elif options.align in ("none", "first") and len(e.ref) < 3:
            out.append(
                f"{r.label or Path(r.path).name}: only {len(e.ref)} poses matched: the ATE is "
                "theirs alone"
                + (" (and the first's error is 0 by construction)" if options.align == "first" else "")
            )
    return out


def eval_warnings(results: list[EstimateResult], options: EvalOptions) -> list[str]:
    """:func:`coverage_warnings`, then each estimate's doubts, named by its label."""
    return coverage_warnings(results, options) + [
        f"{r.label or Path(r.path).name}: {w}" for r in results for w in r.warnings
    ]


def write_eval_json(
    path: Path,
    ground_truth: Path,
    results: list[EstimateResult],
    options: EvalOptions,
    provenance: dict | None = None,
    unscored: Sequence[str] = (),
    refused: Sequence[tuple[Path, str]] = (),
) -> Path:
    """``eval.json`` (module doc); ``provenance``: where and with what it was made
    (:func:`graphslam.cli.common.invocation`), when given; ``unscored``: the estimates a
    stop left unscored (``interrupted``); ``refused``: ``(path, why)`` of the estimates
    that could not be read or scored (``refused``)."""
    from graphslam.outputs.writers import write_json

    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(
        path,
        {
            "ground_truth": str(ground_truth),
            "options": options.to_dict(),
            "estimates": [r.to_dict(options) for r in results],
            **({} if provenance is None else {"provenance": provenance}),
            **({"interrupted": True, "unscored": list(unscored)} if unscored else {}),
            **({"refused": [{"estimate": str(p), "error": why} for p, why in refused]} if refused else {}),
        },
    )
    return path
