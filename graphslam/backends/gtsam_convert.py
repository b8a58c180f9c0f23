"""numpy records <-> gtsam types. The only module besides the iSAM2 back end that
builds gtsam objects.

Keys: poses ``X(id)``, landmarks ``L(id)`` (``gtsam.symbol_shorthand``), with
the ids as in the input data.
"""

from __future__ import annotations

import math
import typing
from collections.abc import Iterable
from functools import lru_cache
from typing import Literal

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from slamcore import chi2
from slamcore.errors import GraphSlamError, MeasurementError, UnsupportedError
from slamcore.planar.records import Dataset, Estimate, LoopClosure, Observation, ObservationKind, Odometry

#: Reorders ``[range, bearing]`` (ours) into ``[bearing, range]`` (gtsam's BearingRange).
_RB_TO_BR = np.array([[0.0, 1.0], [1.0, 0.0]])


#: gtsam's Symbol keeps its index in a key's low 56 bits (the top 8 hold the letter).
SYMBOL_INDEX_LIMIT = 2**56


def key_index(value: int, what: str) -> int:
    """``value``, an int id (the records' rule), if a Symbol ``X(value)`` / ``L(value)``
    can hold it: ``0 <= value < 2**56``. Else MeasurementError naming it: gtsam raised a
    bare TypeError for a negative id and ValueError beyond. The records take any int64
    (the filters and the pose-graph solver, which keys poses by row, take those)."""
    if not 0 <= value < SYMBOL_INDEX_LIMIT:
        raise MeasurementError(f"{what} {value}: this back end keys ids as gtsam symbols, 0 to 2**56 - 1")
    return value


def checked_known_sighting(obs: Observation, pose_ids, who: str) -> None:
    """Refuse, before anything is added, a sighting with an id that a 2-D factor cannot
    take: from a pose not in ``pose_ids``, of a kind other than range (bearing), or with
    an id no symbol holds. A pixel observation was refused after its landmark had been
    placed from it, and a scan's later sighting after the earlier ones' factors were in
    (twentieth hostile pass). Sightings without an id pass (the caller skips them)."""
    if obs.landmark_id is None:
        return
    if obs.pose_id not in pose_ids:
        raise GraphSlamError(f"{who}: observation from unknown pose {obs.pose_id}")
    if obs.kind not in (ObservationKind.RANGE, ObservationKind.RANGE_BEARING):
        raise UnsupportedError(f"2-D back end cannot use {obs.kind.value} observations")
    key_index(obs.landmark_id, f"{who}: landmark")


def pose2(wTb: np.ndarray) -> gtsam.Pose2:
    return gtsam.Pose2(float(wTb[0]), float(wTb[1]), float(wTb[2]))


def pose2_vector(p: gtsam.Pose2) -> np.ndarray:
    """(3,) ``[x, y, theta]``."""
    return np.array([p.x(), p.y(), p.theta()])


def noise_from_covariance(covariance: np.ndarray) -> gtsam.noiseModel.Base:
    """Diagonal model when the covariance is diagonal (as gtsam's loaders build), else full."""
    cov = np.ascontiguousarray(covariance, dtype=np.float64)
    return _noise_model(cov.tobytes(), cov.shape[0])


@lru_cache(maxsize=4096)
def _noise_model(cov_bytes: bytes, dim: int) -> gtsam.noiseModel.Base:
    # Pose graphs repeat a handful of covariances thousands of times; noise
    # models are immutable, so factors can share one (measured: building them
    # was a third of our per-step overhead on w10000).
    cov = np.frombuffer(cov_bytes, dtype=np.float64).reshape(dim, dim)
    if np.count_nonzero(cov - np.diag(np.diag(cov))) == 0:
        return gtsam.noiseModel.Diagonal.Sigmas(np.sqrt(np.diag(cov)))
    return gtsam.noiseModel.Gaussian.Covariance(cov.copy())


def _pose2_tangent_to_world(theta: float) -> np.ndarray:
    """(3, 3) first-order map from gtsam's Pose2 tangent at a pose of heading ``theta``
    (``[x, y]`` in the body frame, then the heading) to our ``[x, y, theta]`` in the world."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose2_covariance_from_gtsam(theta: float, covariance: np.ndarray) -> np.ndarray:
    """gtsam Pose2 covariance (its tangent: body-frame ``x, y``, heading) at a pose of
    heading ``theta`` -> ours, world ``[x, y, theta]``, as the filters and the NEES hold it.
    ``covariance`` is (3, 3), or (3 + n, 3 + n) for a joint marginal whose first block is
    that pose (points after it are world already; the cross terms turn with the pose).
    gtsam's marginals are in the body frame: taken as world ones, a covariance long along
    the track pointed wherever the heading was not 0."""
    P = np.asarray(covariance, dtype=np.float64)
    B = np.eye(P.shape[0])
    B[:3, :3] = _pose2_tangent_to_world(theta)
    return B @ P @ B.T


def pose2_covariance_to_gtsam(theta: float, covariance: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pose2_covariance_from_gtsam` (a prior stated in the world frame).
    A covariance round about its heading axis (the same variance in x and y, no cross
    terms) is the same in both frames and is returned as given, to the bit."""
    P = np.asarray(covariance, dtype=np.float64)
    if P[0, 0] == P[1, 1] and P[0, 1] == P[1, 0] == P[0, 2] == P[2, 0] == P[1, 2] == P[2, 1] == 0.0:
        return P
    B = _pose2_tangent_to_world(theta)
    return B.T @ P @ B


def prior_factor(pose_id: int, wTb: np.ndarray, covariance: np.ndarray) -> gtsam.PriorFactorPose2:
    """Prior on ``X(pose_id)``; ``covariance`` in world ``[x, y, theta]`` (the back-end
    contract's), rotated into gtsam's body-frame tangent."""
    cov = pose2_covariance_to_gtsam(float(wTb[2]), covariance)
    return gtsam.PriorFactorPose2(X(pose_id), pose2(wTb), noise_from_covariance(0.5 * (cov + cov.T)))


def between_factor(edge: Odometry | LoopClosure, noise=None) -> gtsam.BetweenFactorPose2:
    """Factor on ``X(from) ^-1 X(to) = delta``; ``noise`` overrides the edge's Gaussian."""
    model = noise if noise is not None else noise_from_covariance(edge.covariance)
    return gtsam.BetweenFactorPose2(X(edge.from_id), X(edge.to_id), pose2(edge.delta), model)


def bearing_range_factor(
    observation: Observation, landmark_id: int, kernel: str = "none", kernel_k: float = 1.0
) -> gtsam.BearingRangeFactor2D:
    """gtsam's factor of a range-bearing observation, its noise wrapped in the robust
    ``kernel`` of width ``kernel_k`` (:func:`robust`)."""
    if observation.kind is not ObservationKind.RANGE_BEARING:
        raise UnsupportedError(f"2-D back end cannot use {observation.kind.value} observations")
    range_m, bearing_rad = observation.z
    cov_br = _RB_TO_BR @ observation.covariance @ _RB_TO_BR.T
    return gtsam.BearingRangeFactor2D(
        X(observation.pose_id),
        L(landmark_id),
        gtsam.Rot2(float(bearing_rad)),
        float(range_m),
        robust(noise_from_covariance(cov_br), kernel, kernel_k),
    )


def range_factor(
    observation: Observation, landmark_id: int, kernel: str = "none", kernel_k: float = 1.0
) -> gtsam.RangeFactor2D:
    """gtsam's factor of a range-only observation (``z = [range_m]``, (1, 1) covariance)
    from ``X(pose_id)`` to ``L(landmark_id)``, its noise wrapped in the robust
    ``kernel`` of width ``kernel_k`` (:func:`robust`)."""
    if observation.kind is not ObservationKind.RANGE:
        raise UnsupportedError(f"range factor: expected a range observation, got {observation.kind.value}")
    return gtsam.RangeFactor2D(
        X(observation.pose_id),
        L(landmark_id),
        float(observation.z[0]),
        robust(noise_from_covariance(observation.covariance), kernel, kernel_k),
    )


def landmark_factor(
    observation: Observation, landmark_id: int, kernel: str = "none", kernel_k: float = 1.0
) -> gtsam.NonlinearFactor:
    """:func:`range_factor` or :func:`bearing_range_factor`, by the observation's kind."""
    if observation.kind is ObservationKind.RANGE:
        return range_factor(observation, landmark_id, kernel, kernel_k)
    return bearing_range_factor(observation, landmark_id, kernel, kernel_k)


def pose_sighting_factor(
    sighting, kernel: str = "none", kernel_k: float = 1.0
) -> gtsam.BearingRangeFactorPose2:
    """gtsam's factor of one pose's range and bearing to another's position."""
    range_m, bearing_rad = sighting.z
    cov_br = _RB_TO_BR @ sighting.covariance @ _RB_TO_BR.T
    return gtsam.BearingRangeFactorPose2(
        X(sighting.from_id),
        X(sighting.to_id),
        gtsam.Rot2(float(bearing_rad)),
        float(range_m),
        robust(noise_from_covariance(cov_br), kernel, kernel_k),
    )


def dataset_graph(dataset: Dataset, frames: int | None = None) -> gtsam.NonlinearFactorGraph:
    """Batch factor graph of a dataset (prior, odometry, landmarks, loop closures);
    range-bearing and range-only observations alike (:func:`landmark_factor`).

    Landmark observations without an id are left out (they need association).
    """
    graph = gtsam.NonlinearFactorGraph()
    selected = dataset.frames if frames is None else dataset.frames[:frames]
    if not selected:
        return graph
    graph.add(prior_factor(selected[0].pose_id, dataset.prior_wTb, dataset.prior_covariance))
    for frame in selected:
        if frame.odometry is not None:
            graph.add(between_factor(frame.odometry))
        for obs in frame.observations:
            if obs.landmark_id is not None:
                graph.add(landmark_factor(obs, obs.landmark_id))
        for lc in frame.loop_closures:
            graph.add(between_factor(lc))
        for ps in frame.pose_sightings:
            graph.add(pose_sighting_factor(ps))
    return graph


def estimate_values(estimate: Estimate) -> gtsam.Values:
    values = gtsam.Values()
    for pid, p in zip(estimate.pose_ids, estimate.wTb, strict=True):
        values.insert(X(int(pid)), pose2(p))
    for lid, m in zip(estimate.landmark_ids, estimate.landmarks_w, strict=True):
        values.insert(L(int(lid)), np.asarray(m, dtype=float))
    return values


def values_to_estimate(
    values: gtsam.Values, pose_ids: Iterable[int], landmark_ids: Iterable[int]
) -> Estimate:
    """Pull the named poses and landmarks out of ``values`` (order kept)."""
    pose_ids = np.fromiter(pose_ids, dtype=np.int64)
    landmark_ids = np.fromiter(landmark_ids, dtype=np.int64)
    keys = np.array(values.keys(), dtype=np.uint64)
    wTb = _rows_of(keys, gtsam.utilities.extractPose2(values), "x", pose_ids)
    if wTb is None:
        wTb = np.array([pose2_vector(values.atPose2(X(int(i)))) for i in pose_ids]).reshape(-1, 3)
    lms = _rows_of(keys, gtsam.utilities.extractPoint2(values), "l", landmark_ids)
    if lms is None:
        lms = np.array([values.atPoint2(L(int(j))) for j in landmark_ids]).reshape(-1, 2)
    return Estimate(pose_ids=pose_ids, wTb=wTb, landmark_ids=landmark_ids, landmarks_w=lms)


def _rows_of(keys: np.ndarray, rows: np.ndarray, char: str, ids: np.ndarray) -> np.ndarray | None:
    """Rows of ``ids`` in gtsam's one-call extraction (``rows``: one per value of the
    type, in key order), or None when the values do not hold exactly those
    variables under ``char`` keys (then one lookup per id). 7000 poses: 1 ms, not 40."""
    width = 3 if char == "x" else 2
    if not len(ids):
        return np.zeros((0, width))
    mine = keys[(keys >> np.uint64(56)) == np.uint64(ord(char))]  # gtsam.Symbol: char in the top byte
    if len(mine) != len(rows) or len(ids) > len(mine):
        return None
    wanted = (np.uint64(ord(char)) << np.uint64(56)) | ids.astype(np.uint64)
    at = np.searchsorted(mine, wanted)
    if at.max() >= len(mine) or not np.array_equal(mine[at], wanted):
        return None
    return np.asarray(rows, dtype=np.float64).reshape(-1, width)[at]


def graph_cost(
    dataset: Dataset, estimate: Estimate, bulk: bool = False
) -> tuple[float, int] | tuple[float, int, float] | None:
    """``(error, dof)``: GTSAM's ``0.5 * sum ||whitened residual||^2`` of ``estimate``
    under the dataset's noise and the graph's degrees of freedom (the measurements'
    dimensions less the variables'), or None as there. With ``bulk``, a third figure:
    :func:`_bulk_ratio` (about 1 when most residuals are as the noise says, whatever a
    few outliers do; one Python call a factor, so only for the smoothers' cost test)."""
    graph = dataset_graph(dataset, frames=len(estimate.pose_ids))
    values = estimate_values(estimate)
    keys = graph.keyVector()
    if not all(values.exists(key) for key in keys):
        return None
    factors = [graph.at(i) for i in range(graph.size()) if graph.at(i) is not None]
    dof = int(sum(f.dim() for f in factors) - values.dim())
    if not bulk:
        return float(graph.error(values)), dof
    return float(graph.error(values)), dof, _bulk_ratio(factors, values)


#: Factors of one kind a median is taken over (fewer say nothing of their kind's bulk).
BULK_MIN_FACTORS = 10


def _bulk_ratio(factors: list, values: gtsam.Values) -> float:
    """The largest, over the kinds of factor (sightings, odometry, priors), of the
    median ``2 error`` of that kind over the median of a chi-square of its dimension
    (NaN when no kind has :data:`BULK_MIN_FACTORS`). By kind: the odometry's priors sit
    near 0 and would otherwise outvote the sightings."""
    median_of: dict[int, float] = {}  # one scipy call a dimension, not a factor
    kinds: dict[str, list[float]] = {}
    for f in factors:
        d = max(f.dim(), 1)
        if d not in median_of:
            median_of[d] = chi2.median(d)
        kinds.setdefault(type(f).__name__, []).append(2.0 * f.error(values) / median_of[d])
    medians = [float(np.median(v)) for v in kinds.values() if len(v) >= BULK_MIN_FACTORS]
    return max(medians) if medians else float("nan")


# --- 3-D (visual back ends) -------------------------------------------------
#
# Pose covariances: ours (slamcore.spatial.backend) are in the order
# [rho (translation), phi (rotation)] of a right perturbation; gtsam's Pose3
# tangent is [phi, rho], also on the right (Pose3.retract = compose(Expmap)).
# Same perturbation, swapped blocks: the permutation below is its own inverse.

_POSE3_SWAP = np.block([[np.zeros((3, 3)), np.eye(3)], [np.eye(3), np.zeros((3, 3))]])


#: Frobenius norm of ``R^T R - I`` beyond which a rotation matrix is projected on SO(3)
#: before it enters gtsam. Products of float64 rotations stay within 1e-14; gtsam's
#: ``Rot3(matrix)`` keeps whatever it is given, and a camera coasting on products of
#: products drifted from SO(3) until its rotation matrix was zero (an 11th-pass find).
ORTHONORMAL_TOL = 1e-9


def pose3(wTc: np.ndarray) -> gtsam.Pose3:
    """(4, 4) rigid transform -> ``gtsam.Pose3``; a rotation block off SO(3) by more
    than :data:`ORTHONORMAL_TOL` is replaced by the nearest rotation."""
    T = np.asarray(wTc, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"expected a (4, 4) pose, got {T.shape}")
    R = T[:3, :3]
    if not np.linalg.norm(R.T @ R - np.eye(3)) <= ORTHONORMAL_TOL:
        return gtsam.Pose3(gtsam.Rot3.ClosestTo(R), T[:3, 3].copy())
    return gtsam.Pose3(gtsam.Rot3(R), T[:3, 3].copy())


def pose3_matrix(p: gtsam.Pose3) -> np.ndarray:
    """``gtsam.Pose3`` -> (4, 4) float64."""
    return np.asarray(p.matrix(), dtype=np.float64)


def cal3_s2(K: np.ndarray) -> gtsam.Cal3_S2:
    """(3, 3) intrinsic matrix ``[[fx, s, u0], [0, fy, v0], [0, 0, 1]]`` -> ``gtsam.Cal3_S2``."""
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"expected K (3, 3), got {K.shape}")
    return gtsam.Cal3_S2(K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2])


def pose3_covariance_to_gtsam(covariance: np.ndarray) -> np.ndarray:
    """(6, 6) ``[rho, phi]`` covariance (ours) -> gtsam's Pose3 order ``[phi, rho]``."""
    cov = np.asarray(covariance, dtype=np.float64)
    return _POSE3_SWAP @ cov @ _POSE3_SWAP


def pose3_covariance_from_gtsam(covariance: np.ndarray) -> np.ndarray:
    """(6, 6) gtsam Pose3 covariance ``[phi, rho]`` -> ours ``[rho, phi]``."""
    cov = np.asarray(covariance, dtype=np.float64)
    return _POSE3_SWAP @ cov @ _POSE3_SWAP


#: Robust kernels by configuration name ("none" keeps the Gaussian): the type of the
#: config fields that choose one, and its values.
RobustKernel = Literal["none", "huber", "cauchy"]
ROBUST_KERNELS: tuple[str, ...] = typing.get_args(RobustKernel)


def robust(noise: gtsam.noiseModel.Base, kernel: str, k: float) -> gtsam.noiseModel.Base:
    """``noise`` wrapped in the M-estimator ``kernel`` ("huber" or "cauchy") of width
    ``k`` (in sigmas of the whitened residual); "none" returns ``noise`` itself."""
    if kernel == "none":
        return noise
    estimators: dict[
        str, type[gtsam.noiseModel.mEstimator.Huber] | type[gtsam.noiseModel.mEstimator.Cauchy]
    ] = {"huber": gtsam.noiseModel.mEstimator.Huber, "cauchy": gtsam.noiseModel.mEstimator.Cauchy}
    estimator = estimators[kernel]
    return gtsam.noiseModel.Robust.Create(estimator.Create(k), noise)


def pose3_noise(covariance: np.ndarray) -> gtsam.noiseModel.Base:
    """Gaussian noise model of a Pose3 factor from our ``[rho, phi]`` covariance."""
    return noise_from_covariance(pose3_covariance_to_gtsam(covariance))
