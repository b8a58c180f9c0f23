"""Metric relative pose of a loop closure by PnP on the map (numpy + OpenCV).

Two views alone give the relative pose only up to scale (the verifier's
essential matrix). A monocular run with odometry has a metric map, so the
closure's pose can be metric: the landmarks mapped in the *match* frame ``a``
(3-D points expressed in camera ``a``, with ORB descriptors computed at their
pixels in image ``a``) are matched to the ORB features of the *query* image
``b``, and ``cv2.solvePnPRansac`` finds ``bTa``, refined on its inliers by
``cv2.solvePnPRefineLM``. Because the points are expressed in camera ``a``
(the map is locally accurate around ``a`` even when it has drifted globally),
the answer ``aTb`` does not depend on the drift the closure is meant to remove.

Covariance (contract order ``[rho, phi]``, right perturbation of ``aTb``): the
Gauss-Newton covariance ``sigma_px^2 (J^T J)^-1`` of the inlier reprojections,
``J`` = d pixel / d pose (:func:`slamcore.spatial.camera.project_jacobians`: a left
perturbation of ``bTa`` is minus a right perturbation of ``aTb``, so the
covariance is the same), times ``covariance_inflation`` because the map points
carry errors of their own that PnP treats as exact, plus a floor.

Determinism: ``cv2.setRNGSeed(seed)`` before each RANSAC.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import cv2
import numpy as np

from loopclosure.matching import match_descriptors
from loopclosure.verify import MAX_RANSAC_ITERS, MAX_SEED
from slamcore.config import Validated, bounded
from slamcore.spatial.camera import project_jacobians
from slamcore.spatial.geometry import invert_pose

__all__ = ["PnpConfig", "PnpResult", "relative_pose_pnp"]


@dataclass(frozen=True)
class PnpConfig(Validated):
    """Metric closure settings (config section ``[loop_pnp]``).

    Attributes:
        ratio, max_hamming: ORB matching of map points to query features
            (Lowe ratio, largest Hamming distance of 256 bits); mutual matches only.
        ransac_threshold_px: RANSAC reprojection threshold, pixels.
        confidence, max_iters: RANSAC confidence and iteration cap.
        min_inliers: fewest PnP inliers to accept the pose.
        min_inlier_ratio: smallest inliers / matches to accept.
        sigma_px: pixel standard deviation behind the covariance.
        covariance_inflation: variance multiplier for the map points' own error.
        min_sigma_t_m, min_sigma_r_deg: floors added to the covariance diagonal.
        seed: seed of OpenCV's RNG before each RANSAC.
    """

    SECTION: ClassVar[str] = "loop_pnp"

    ratio: float = bounded(0.8, gt=0.0, max=1.0)
    # a Hamming distance between 256-bit descriptors
    max_hamming: int = bounded(64, min=0, max=256)
    ransac_threshold_px: float = bounded(3.0, gt=0.0)
    confidence: float = bounded(0.999, gt=0.0, lt=1.0)
    max_iters: int = bounded(500, min=1, max=MAX_RANSAC_ITERS)
    # EPnP needs 4 points
    min_inliers: int = bounded(15, min=4)
    min_inlier_ratio: float = bounded(0.4, min=0.0, max=1.0)
    sigma_px: float = bounded(1.0, gt=0.0)
    covariance_inflation: float = bounded(4.0, gt=0.0)
    min_sigma_t_m: float = bounded(0.005, gt=0.0)
    min_sigma_r_deg: float = bounded(0.05, gt=0.0)
    seed: int = bounded(0, min=0, max=MAX_SEED)


@dataclass(frozen=True, eq=False)
class PnpResult:
    """Outcome of :func:`relative_pose_pnp`.

    Attributes:
        accepted: the pose passed the thresholds; ``reason`` says why not.
        n_points: map points offered; n_matches: ORB matches; n_inliers: PnP inliers.
        aTb: (4, 4) ``c_a T c_b`` (metres), or None.
        covariance: (6, 6) of ``aTb`` (``[rho, phi]``, right perturbation), or None.
        inlier_pairs: (K, 2) int64 ``(point index, query feature index)``.
        reprojection_rmse_px: RMS reprojection error of the inliers.
    """

    accepted: bool
    reason: str | None
    n_points: int
    n_matches: int
    n_inliers: int
    aTb: np.ndarray | None = None
    covariance: np.ndarray | None = None
    inlier_pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    reprojection_rmse_px: float | None = None


def pose_from_rodrigues(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """(4, 4) ``cTw`` of OpenCV's rotation vector and translation."""
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = np.asarray(tvec).reshape(3)
    return T


def pnp_covariance(J: np.ndarray, c: PnpConfig) -> np.ndarray | None:
    """(6, 6) covariance of a PnP pose from its inliers' reprojection Jacobians
    ``J`` (N, 2, 6): ``(J^T J / sigma_px^2)^-1``, inflated and floored as ``c`` says;
    None when the information is singular."""
    try:
        cov = np.linalg.inv(np.einsum("nij,nik->jk", J, J) / c.sigma_px**2)
    except np.linalg.LinAlgError:
        return None
    floor = np.r_[[c.min_sigma_t_m**2] * 3, [math.radians(c.min_sigma_r_deg) ** 2] * 3]
    return c.covariance_inflation * 0.5 * (cov + cov.T) + np.diag(floor)


def relative_pose_pnp(
    points_a: np.ndarray,
    desc_a: np.ndarray,
    xy_b: np.ndarray,
    desc_b: np.ndarray,
    K: np.ndarray,
    config: PnpConfig | None = None,
) -> PnpResult:
    """Metric ``aTb`` from map points of frame ``a`` and ORB features of image ``b``.

    Args:
        points_a: (N, 3) map points in camera ``a``, metres (in front: z > 0).
        desc_a: (N, 32) uint8 ORB descriptors of those points in image ``a``.
        xy_b, desc_b: (M, 2) pixels and (M, 32) descriptors of image ``b``.
        K: (3, 3) intrinsics shared by both images.
    """
    c = config or PnpConfig()
    pts = np.asarray(points_a, np.float64).reshape(-1, 3)
    xy_b = np.asarray(xy_b, np.float64).reshape(-1, 2)
    K = np.asarray(K, np.float64)
    n = len(pts)
    if n < c.min_inliers:
        return PnpResult(False, f"{n} map points < {c.min_inliers}", n, 0, 0)
    pairs = match_descriptors(desc_a, desc_b, ratio=c.ratio, cross_check=True, max_hamming=c.max_hamming)
    m = len(pairs)
    if m < c.min_inliers:
        return PnpResult(False, f"{m} matches < {c.min_inliers}", n, m, 0)
    obj = np.ascontiguousarray(pts[pairs[:, 0]])
    img = np.ascontiguousarray(xy_b[pairs[:, 1]])
    cv2.setRNGSeed(int(c.seed))
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        obj,
        img,
        K,
        None,
        iterationsCount=int(c.max_iters),
        reprojectionError=float(c.ransac_threshold_px),
        confidence=float(c.confidence),
        flags=cv2.SOLVEPNP_EPNP,
    )
    if not ok or inl is None:
        return PnpResult(False, "PnP RANSAC found no pose", n, m, 0)
    inl = np.sort(inl.reshape(-1))
    if len(inl) < c.min_inliers:
        return PnpResult(False, f"{len(inl)} inliers < {c.min_inliers}", n, m, len(inl))
    if len(inl) < c.min_inlier_ratio * m:
        return PnpResult(False, f"inlier ratio {len(inl) / m:.2f} < {c.min_inlier_ratio}", n, m, len(inl))
    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], K, None, rvec, tvec)
    bTa = pose_from_rodrigues(rvec, tvec)
    uv, depth, _, J = project_jacobians(K, bTa, obj[inl])
    if np.any(depth <= 0):
        return PnpResult(False, "PnP pose puts inliers behind the camera", n, m, len(inl))
    err = uv - img[inl]
    rmse = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    cov = pnp_covariance(J, c)
    if cov is None:
        return PnpResult(False, "PnP pose is degenerate (singular information)", n, m, len(inl))
    return PnpResult(
        True,
        None,
        n,
        m,
        len(inl),
        aTb=invert_pose(bTa),
        covariance=cov,
        inlier_pairs=pairs[inl],
        reprojection_rmse_px=rmse,
    )
