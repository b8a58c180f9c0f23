"""``graphslam compare`` on image sequences: visual iSAM2 and the monocular EKF
(IDP and AHP landmarks) on the same frames, detections and active-search budget.

Each entry (:data:`graphslam.backend_table.VISUAL_COMPARE_BACKENDS`) runs
:func:`graphslam.pipelines.spatial.run` in its own forked process
(:func:`graphslam.pipelines.compare.run_entries`: failures, Ctrl-C and SIGTERM
as in the 2-D compare) on the same sequence, with the same odometry (resolved
or derived from the same seed) and the same ``[tracker]``, ``[active_search]``
and detector sections, so the search budget is one. The detector does not
depend on the back end's predictions, so the frames and corners fed are the
same for every entry; ``input_digest`` (SHA-256 of every frame's image, its
detected corners and the odometry) shows it per entry.

Pose NEES has 6 degrees of freedom (``[rho, phi]``, the back ends' covariance
convention, :func:`graphslam.evaluation.spatial.pose_nees`). The EKF's is
filtered: the covariance of each frame while it was current, read after that
frame's update (off the clock). iSAM2's is smoothed: the marginals of every
pose at the final estimate (one ``gtsam.Marginals``; skipped when the run was
cut, as the 2-D compare skips its covariances). Metric runs (odometry) start at
the true first pose and are scored unaligned, in the truth's frame, as the 2-D
NEES is. Runs without odometry (monocular, no scale) are scored in the
estimator's own gauge (:func:`graphslam.evaluation.spatial.gauge_sim3`): the
first estimated pose, which the back end's prior holds, put on the truth's, and
the scale of iSAM2's first-map baseline (its range factor of 1), or for the EKF
the least-squares scale about that pose; the covariance is scaled with it. The
Sim(3) fit of the ATE would move the anchored pose, whose covariance is the
prior's, and make the NEES meaningless.
"""

from __future__ import annotations

import dataclasses
import hashlib
from typing import cast

import numpy as np

from graphslam import registry
from graphslam.evaluation.planar import nees_doubt
from graphslam.evaluation.records import SpatialRunMetrics
from graphslam.evaluation.spatial import POSE_DOF, pose_nees
from graphslam.pipelines import spatial as vp
from graphslam.pipelines.common import FrameUnreadable
from graphslam.pipelines.compare import CompareEntry, finished, run_entries
from graphslam.pipelines.session import VisualSetup
from graphslam.sources.spatial.sequence import ImageSequence
from slamcore.errors import GraphSlamError

#: NEES alignment by the run's ATE alignment (module docstring).
NEES_ALIGNMENT = {"se3": "none", "sim3": "gauge"}


class _Feed:
    """``on_frame`` hook: digests what the back end is fed and, for a filter, keeps
    each frame's pose covariance (the estimate is only read, never changed)."""

    def __init__(self, filtered: bool):
        self.sha = hashlib.sha256()
        self.filtered = filtered
        self.covariances: list[np.ndarray] = []

    def __call__(self, k, image, tracking, backend) -> None:
        self.sha.update(np.ascontiguousarray(image).tobytes())
        self.sha.update(np.ascontiguousarray(tracking.corners, dtype=np.float64).tobytes())
        if self.filtered:
            self.covariances.append(backend.estimate().current_covariance)


def compare(
    setup: VisualSetup, names: list[str], *, isolate: bool = True, progress=None
) -> list[CompareEntry]:
    """Run each entry of ``names`` on ``setup``'s sequence; one entry each, in order,
    with its metrics (ATE, RPE, frames/s, peak memory, pose NEES)."""

    def job(name):
        return lambda: run_one(setup, name)

    def score(name, result, peak_mb):
        result.sequence = setup.sequence  # the worker sent it back without (strip)
        return _score(setup, name, result, peak_mb)

    entries = run_entries(names, job, score, isolate=isolate, strip=_without_sequence, progress=progress)
    # what the runs read is read, and what none of those reading it used did nothing
    setup.config.merge_notes([e.result.config_notes for e in finished(entries)])
    for e in finished(entries):
        e.nees = entry_nees(e.result, e.metrics.alignment)
        if e.nees is not None:
            e.metrics.nees_mean = e.nees["nees_mean"]
            e.metrics.nees_in_bounds_fraction = e.nees["nees_in_bounds_fraction"]
            e.metrics.nees_alignment = e.nees["alignment"]
            if (doubt := nees_doubt(e.metrics.nees_mean, POSE_DOF)) is not None:
                e.metrics.warnings = [*(e.metrics.warnings or []), doubt]
    return entries


def run_one(setup: VisualSetup, name: str) -> vp.VisualRunResult:
    """Entry ``name``'s run, with its input digest and pose covariances."""
    kind, overrides = registry.visual_compare_backend(name)
    # this entry's notes of the config apart from the others' (merged in :func:`compare`)
    setup = dataclasses.replace(setup, config=setup.config.fork())
    session = setup.session(kind, overrides)
    feed = _Feed(filtered=registry.visual_implementation(kind).filtering)
    try:
        result = session.run(on_frame=feed)
    except FrameUnreadable as e:  # scored on the frames before it, as run keeps them
        result = e.result
        result.unreadable = str(e)
    if setup.odometry is not None:
        feed.sha.update(np.ascontiguousarray(setup.odometry[: max(result.frames - 1, 0)]).tobytes())
    result.input_digest = feed.sha.hexdigest()
    result.pose_covariances = _covariances(feed, session.backend, result)
    result.config_notes = setup.config.notes()
    return result


def _covariances(feed: _Feed, backend, result: vp.VisualRunResult) -> np.ndarray | None:
    """(frames, 6, 6) pose covariances of the estimate, or None (module docstring)."""
    est = result.estimate
    if feed.filtered:
        covs = np.array(feed.covariances).reshape(-1, 6, 6)
        return covs if len(covs) == len(est.frame_ids) else None
    if result.interrupted:
        return None
    from graphslam.backends.spatial.marginals import pose_marginals

    try:
        return pose_marginals(backend, est)
    except GraphSlamError:  # an indeterminate system: no NEES, the run still counts
        return None


def _without_sequence(result: vp.VisualRunResult) -> vp.VisualRunResult:
    # the parent has it; don't send it back (None in transit only: the parent puts it back)
    result.sequence = cast(ImageSequence, None)
    return result


def _score(
    setup: VisualSetup, name: str, result: vp.VisualRunResult, peak_mb: float | None
) -> SpatialRunMetrics:
    m = vp.compute_metrics(result, seed=getattr(getattr(setup.sequence, "config", None), "seed", None))
    m.backend = name
    m.backend_class = result.backend
    m.peak_rss_mb = peak_mb
    m.input_digest = result.input_digest
    return m


def entry_nees(result: vp.VisualRunResult, alignment: str) -> dict | None:
    """The per-frame pose NEES record of one run (``alignment``: its ATE's), or None
    without covariances or ground truth."""
    truth = result.sequence.wTc_true
    est = result.estimate
    if result.pose_covariances is None or truth is None or len(est.frame_ids) < 2:
        return None
    truth = np.asarray(truth)
    try:
        return pose_nees(
            est.frame_ids,
            est.wTc,
            result.pose_covariances,
            np.arange(len(truth)),
            truth,
            alignment=NEES_ALIGNMENT[alignment],
            baseline_ids=scale_baseline(est.stats),
        )
    except GraphSlamError:  # no fit (a camera-alone estimate that never moved): no NEES,
        return None  # as it has no ATE; the comparison keeps the other back ends'


def scale_baseline(stats: dict | None) -> tuple[int, int] | None:
    """The two frames whose distance a camera-alone iSAM2 run fixed as its unit of
    length (its first map's reference and initialising frames), or None (a filter:
    its scale comes from its depth prior, and the NEES fits it)."""
    first = ((stats or {}).get("camera_alone") or {}).get("first_map")
    if not first:
        return None
    return int(first["reference_frame"]), int(first["frame"])
