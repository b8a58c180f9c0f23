"""``graphslam eval``: score trajectory files of any origin against a reference.

Reads the files (TUM, KITTI with an optional times file, EuRoC; told from the
content or given), scores each estimate with
:func:`graphslam.evaluation.trajectory.evaluate` and writes ``eval.json``:
``{"ground_truth", "options", "estimates": [{"estimate", <metrics>, "options"}]}``
with the metric keys of :meth:`TrajectoryEval.summary` (null where not
computable, e.g. the KITTI drift of a path under 100 m), among them
``matched_poses``, ``estimate_poses`` and ``matched_share``: the ATE covers the
matched poses only, and :func:`coverage_warnings` says so when they are few.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from graphslam.evaluation.records import LOW_MATCHED_SHARE
from graphslam.evaluation.trajectory import EvalOptions, TrajectoryEval, evaluate
from graphslam.sources.ground_truth import Trajectory, read_times, read_trajectory
from slamcore.errors import ConfigError


@dataclass
class EstimateResult:
    """One estimate file and its score."""

    path: str
    result: TrajectoryEval
    #: the shortest end of ``path`` that no other estimate of the same call shares
    #: (``a/trajectory.tum`` and ``b/trajectory.tum``, not two ``trajectory.tum``)
    label: str = ""

    def to_dict(self, options: EvalOptions) -> dict:
        return {
            "estimate": self.path,
            "label": self.label or Path(self.path).name,
            **self.result.summary(),
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
) -> list[EstimateResult]:
    """Score every estimate against ``ground_truth`` (same format and times options)."""
    ref = load(ground_truth, fmt, times)
    loaded = [
        (path, label, load(path, fmt, times))
        for path, label in zip(estimates, distinct_labels(estimates), strict=True)
    ]
    if times is not None and all(t.format != "kitti" for t in [ref] + [t for _, _, t in loaded]):
        # the files have their own stamps: a times file that changes nothing is refused
        raise ConfigError("--times gives KITTI files their stamps; none of these files is KITTI", times)
    return [
        EstimateResult(str(path), evaluate(ref.stamps_s, ref.wTc, est.stamps_s, est.wTc, options), label)
        for path, label, est in loaded
    ]


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
    return out


def write_eval_json(
    path: Path, ground_truth: Path, results: list[EstimateResult], options: EvalOptions
) -> Path:
    """``eval.json`` (module doc)."""
    from graphslam.outputs.writers import write_json

    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(
        path,
        {
            "ground_truth": str(ground_truth),
            "options": options.to_dict(),
            "estimates": [r.to_dict(options) for r in results],
        },
    )
    return path
