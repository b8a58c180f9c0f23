"""Typed run metrics: what ``metrics.json`` holds, as dataclasses.

Pipelines fill these; the CLI reads their attributes for the summary table;
:meth:`MetricsRecord.to_dict` gives the JSON layout (fields in declaration order;
fields declared :func:`optional` left out while they are None, so files keep their
familiar shape).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

#: Below this share of the estimate's poses matched, the ATE describes a minority of
#: the trajectory (``graphslam eval``, and a 2-D run's own score): said in a warning,
#: not refused, because an estimate at a higher rate than its reference (200 Hz against
#: 20 Hz) matches a tenth of its poses and is still scored correctly.
LOW_MATCHED_SHARE = 0.5

#: Field metadata key of :func:`optional`.
OMITTED_WHILE_NONE = "omitted_while_none"


def optional() -> Any:
    """A metrics field that defaults to None and is left out of :meth:`MetricsRecord.to_dict`
    while it is None (a field that defaults to None without it is written as null)."""
    return field(default=None, metadata={OMITTED_WHILE_NONE: True})


@dataclass
class MetricsRecord:
    """Base of the metrics records: :meth:`to_dict` gives their JSON layout."""

    def to_dict(self) -> dict:
        """The fields in declaration order, nested records as their own dicts;
        :func:`optional` fields left out while they are None."""
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is None and f.metadata.get(OMITTED_WHILE_NONE):
                continue
            out[f.name] = value.to_dict() if isinstance(value, MetricsRecord) else value
        return out


@dataclass
class AssociationScore(MetricsRecord):
    """Data association against ground truth (:func:`.planar.association_accuracy`).

    Attributes:
        accuracy: share of observations given the right landmark (unused count wrong),
            as the final estimate pairs them where the back end revises its pairings
            (iSAM2 with unknown ids: merges, splits, re-association), else (and in an
            interrupted run) as each was decided when it arrived.
        observations: observations scored; unused: observations the back end left unused.
        landmarks_created: back-end landmarks; duplicates: extra back-end landmarks
            mapped to an already-taken true landmark.
        oracle_accuracy: the ceiling of an oracle knowing poses and map (compare only).
    """

    accuracy: float
    observations: int
    unused: int
    landmarks_created: int
    duplicates: int
    oracle_accuracy: float | None = optional()


@dataclass
class PlanarRunMetrics(MetricsRecord):
    """Metrics of a 2-D run (``metrics.json``; one entry of ``compare.json``).

    Attributes:
        final_error: GTSAM graph error ``0.5 sum ||whitened residual||^2`` under the
            dataset's noise model, or None; with unknown ids, of the sightings as the
            run paired them (those left unused, or of a landmark no longer in the
            estimate, out).
        ate_rmse_m, odometry_ate_rmse_m: SE(2)-aligned ATE of the estimate and of
            dead reckoning, or None without ground truth.
        wall_s: the whole run's time; backend_s: the back end's; steps_per_s: its rate.
        peak_rss_mb .. rms_to_isam2_m: filled by ``compare`` only.
        numerical_recoveries: switches the back end made, one line each with
            the step (iSAM2's factorisation fallbacks); left out when none.
        recoveries: per-update safeguards counted by kind (filters only; see
            :class:`filters.numerics.Recoveries`), or None.
        sightings_reassociated: sightings the back end's re-association moved to
            another landmark at the end of the run; reassociation_settled: False when
            its last pass still moved some (iSAM2 with unknown ids; left out otherwise).
        landmarks_pruned: landmarks the back end removed from its map as missed
            in the sensor's field (``prune_missed_alpha`` of the EKF and FastSLAM; for
            FastSLAM, those gone from every particle); left out when none.
        observations_rejected: sightings of identified landmarks the back end's gate
            kept out (the EKF's known-id gate, FastSLAM 2.0's misread gate for at least
            half its particles); left out when none.
        records_restarted: landmark estimates started again from a sighting because the
            gate had held that landmark out for longer than the back end allows (FastSLAM
            2.0's ``misread_restart_s`` with known ids, one per particle and record); left
            out when none.
        map, localisation_only, unmapped_observations: with ``run --map``: the map
            folder, True, and the observations of landmarks not in the map (not used);
            ate_in_map_frame_m: the ATE there without the SE(2) fit (the map's frame is
            the truth's when the map's run started at the truth, as every reader's does).
        warnings: what makes the estimate absurd, one line each
            (:func:`graphslam.evaluation.planar.estimate_warnings`); left out when none.
        dataset_notes: what the reader made of the source (``Dataset.notes``).
        map_rmse_m .. landmarks_true: the map against true landmark positions
            (:func:`graphslam.evaluation.planar.map_errors`), where the data has them.
        agents: several robots in one run: per robot, its own ATE, its dead
            reckoning's and its pose count (:func:`graphslam.pipelines.planar.agent_ates`).
        ate_poses: the poses the ATE covers (those with truth; a real log's truth
            may cover part of the run).
    """

    dataset: str
    backend: str
    seed: int | None
    steps: int
    landmarks: int
    final_error: float | None
    ate_rmse_m: float | None
    odometry_ate_rmse_m: float | None
    wall_s: float
    backend_s: float
    steps_per_s: float | None
    interrupted: bool
    loop_closures_skipped: int
    association: AssociationScore | None = optional()
    peak_rss_mb: float | None = optional()
    final_pose_error_m: float | None = optional()
    nees_mean: float | None = optional()
    nees_in_bounds_fraction: float | None = optional()
    rms_to_isam2_m: float | None = optional()
    #: RMS distance to iSAM2's poses in the back end's own pose sigmas (compare)
    sigmas_to_isam2: float | None = optional()
    #: the back end's own seed (FastSLAM's particles), beside ``seed`` (the world's)
    backend_seed: int | None = optional()
    numerical_recoveries: list[str] | None = optional()
    recoveries: dict[str, int] | None = optional()
    landmarks_pruned: int | None = optional()
    observations_rejected: int | None = optional()
    records_restarted: int | None = optional()
    sightings_reassociated: int | None = optional()
    reassociation_settled: bool | None = optional()
    map: str | None = optional()
    localisation_only: bool | None = optional()
    unmapped_observations: int | None = optional()
    ate_in_map_frame_m: float | None = optional()
    warnings: list[str] | None = optional()
    dataset_notes: list[str] | None = optional()
    map_rmse_m: float | None = optional()
    map_rmse_m_map_aligned: float | None = optional()
    landmarks_matched: int | None = optional()
    #: the distinct true landmarks the matched ones are (duplicates share one)
    landmarks_matched_true: int | None = optional()
    landmarks_recovered: int | None = optional()
    landmarks_true: int | None = optional()
    agents: dict | None = optional()
    ate_poses: int | None = optional()
    #: what ran: the command line, the config file's path and SHA-256, every section's
    #: settings as built (defaults, file, flags) -- :func:`graphslam.cli.common.provenance`
    provenance: dict | None = optional()


@dataclass
class SpatialRunMetrics(MetricsRecord):
    """Metrics of a visual run (``metrics.json``).

    Attributes:
        alignment: ``"se3"`` with metric odometry, ``"sim3"`` without (monocular).
        path_length_m: the truth's path over the frames the estimate has a pose for,
            which ``ate_percent_of_path`` is a share of (the odometry's percentage is
            of the whole run's path: it covers every frame).
        ate: the ATE record of :func:`.spatial.ate` (rmse, mean, max, scale...);
            ate_error: why it could not be computed, if so.
        rpe, odometry_rpe: per-frame RPE records; tracking: front-end counters;
            backend_stats: the back end's counters; loops: loop-closing counts;
            tracking_loss: losses and recoveries (``run --relocalise``).
        wall_s: the whole run's time; processing_s: tracking and back end;
            image_load_s: reading images.
        peak_rss_mb, nees_mean, nees_in_bounds_fraction, nees_alignment,
            frames_with_pose: frames the estimate has a pose for (a monocular run
            has none before its first map); the scores are over those.
            warnings: what makes the estimate doubtful, one line each (frames
            without a pose, frames the camera was not measured in).
            input_digest: filled by ``compare`` only (6-DoF pose NEES, the
            alignment it was scored after, the digest of what was fed).
            dataset_notes: what the reader made of the source (a ROS bag's
            topics), one line each, or None.
            stopped_by: the error that ended the run before its last frame (a frame
            that could not be read, the back end failing), else None; ``interrupted``
            is then true, as after a stop (the estimate so far, not finalised).
    """

    dataset: str
    source: str | None
    backend: str
    frontend: str
    seed: int | None
    frames: int
    landmarks: int
    odometry: str
    odometry_noise: dict | None
    alignment: str
    ate_rmse_m: float | None
    ate_percent_of_path: float | None
    odometry_ate_rmse_m: float | None
    odometry_ate_percent_of_path: float | None
    rpe: dict | None
    path_length_m: float | None
    wall_s: float
    frames_per_s: float | None
    processing_s: float
    image_load_s: float
    interrupted: bool
    backend_stats: dict
    tracking: dict
    ate_error: str | None = optional()
    ate: dict | None = optional()
    odometry_rpe: dict | None = optional()
    backend_class: str | None = optional()
    loops: dict | None = optional()
    tracking_loss: dict | None = optional()
    #: ``run --map``: the map, how the run started in it, the ATE in its frame
    map: dict | None = optional()
    #: ``run --intrinsics estimate``: the camera estimated from the images and its rounds
    camera_estimate: dict | None = optional()
    peak_rss_mb: float | None = optional()
    nees_mean: float | None = optional()
    nees_in_bounds_fraction: float | None = optional()
    nees_alignment: str | None = optional()
    input_digest: str | None = optional()
    #: the back end's own seed (its RANSAC draws), beside ``seed`` (the synthetic world's)
    backend_seed: int | None = optional()
    frames_with_pose: int | None = None
    warnings: list | None = optional()
    dataset_notes: list | None = optional()
    stopped_by: str | None = optional()
    #: what ran (as :class:`PlanarRunMetrics`)
    provenance: dict | None = optional()
