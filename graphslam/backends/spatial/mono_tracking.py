"""Camera-only tracking for the visual iSAM2 back end: a constant-velocity prediction
of the next pose, and its refinement by PnP RANSAC on the landmarks the front end
re-found (numpy + OpenCV; the back end turns the result into factors).

Without odometry, a frame's pose is measured by the landmarks seen in it alone
(ORB-SLAM's tracking): the constant-velocity model only says where to look (the
active-search ellipses come from its covariance), PnP RANSAC on the re-found
landmarks gives the pose and rejects the wrong matches, and the frame enters
iSAM2 with its projection factors and no between-factor. A frame whose PnP
fails is *coasted*: the prediction enters with a constant-velocity factor under
the same noise, so the graph stays connected, and the back end counts it.

When PnP cannot measure a frame, its rotation still can be: the tracks seen in
it and in the frame before give the rotation between the two by RANSAC over
2-point samples of their rays (:func:`frame_rotation`, Wahba's problem solved
by SVD), allowing the parallax the predicted translation can make at the
median landmark depth. A camera that stops or starts turning between two
frames (the constant-velocity model's blind spot) then coasts on its measured
rotation, not on the old turn.

Units: a monocular map has no metric scale (its unit is the bootstrap baseline,
:mod:`.mono_init`), so the motion noise is scale-free: the translation sigma is
a fraction of the frame's own displacement, floored at what moves the median
landmark by one pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import cv2
import numpy as np

from frontend.two_view import MAX_SEED, TwoViewConfig
from loopclosure.pnp import pose_from_rodrigues
from slamcore.config import Validated, bounded
from slamcore.spatial.camera import project
from slamcore.spatial.geometry import invert_pose

__all__ = [
    "MonoTrackingConfig",
    "PnpPose",
    "constant_velocity",
    "motion_covariance",
    "pnp_pose",
    "reprojects",
    "frame_rotation",
    "rng_seed",
]


@dataclass(frozen=True)
class MonoTrackingConfig(Validated):
    """Camera-only tracking settings (``[isam2_visual.mono]``; used with ``--odometry none``).

    Attributes:
        cv_sigma_t_ratio: constant-velocity translation noise per axis and per
            frame, as a fraction of the frame's predicted displacement. Physics:
            a car braking or accelerating at 3 m/s^2 changes its 10 Hz frame
            displacement by 3 cm of 0.5-0.8 m (4-6 %); 0.1 covers that with a
            margin for a hand-held camera. Measured on KITTI 07's ground truth
            (frames 0-159): the constant-velocity error is 1.9 % rms per axis
            (3.5 % at the 95th percentile), inside it.
        cv_sigma_r_deg: constant-velocity rotation noise per axis and per frame,
            degrees. A car's yaw acceleration of about 1 rad/s^2 gives 0.57 deg
            a frame at 10 Hz; a hand-held camera's 4 rad/s^2 (the EKF's default)
            0.25 deg at 30 Hz. KITTI 07's ground truth: 0.13 deg rms, 0.35 max.
        min_pnp_inliers: fewest PnP inliers that measure a frame's pose; fewer
            and the frame is coasted. 10, as the run's relocaliser
            (``[relocalise] min_inliers``): 6 points fix a pose, and 10 agreeing
            within 3 sigma are not chance (ORB-SLAM asks more of its 2000
            features, a sparse tracker re-finds tens of landmarks).
        pnp_threshold_sigmas: PnP RANSAC reprojection threshold, in pixel
            sigmas of the observations (chi-square 2 dof at 99 %: 3.03).
        two_view: the bootstrap's two-view geometry (:class:`frontend.two_view.TwoViewConfig`).
        max_bootstrap_frames: frames the bootstrap may wait for parallax from
            its reference frame before it moves the reference to the latest
            frame (tracks from the old reference are mostly lost by then).
    """

    TABLE: ClassVar[str] = "isam2_visual.mono"  # a nested table only

    cv_sigma_t_ratio: float = bounded(0.1, gt=0.0)
    cv_sigma_r_deg: float = bounded(0.5, gt=0.0)
    min_pnp_inliers: int = bounded(10, min=6)
    pnp_threshold_sigmas: float = bounded(3.03, gt=0.0)
    two_view: TwoViewConfig = field(default_factory=TwoViewConfig)
    max_bootstrap_frames: int = bounded(30, min=1)


def rng_seed(base: int, k: int) -> int:
    """The seed of draw ``k`` (a frame, an attempt) of a run seeded ``base``: distinct draws,
    repeatable, and within OpenCV's C int (``cv2.setRNGSeed``, USAC's generator state)
    whatever the run's seed."""
    return (int(base) + int(k)) % (MAX_SEED + 1)


def constant_velocity(wTc_before: np.ndarray, wTc_last: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(wTc_predicted (4, 4), delta (4, 4))``: the last frame-to-frame motion
    ``delta = c_before T c_last`` applied once more to ``wTc_last``."""
    delta = invert_pose(wTc_before) @ wTc_last
    return wTc_last @ delta, delta


def motion_covariance(delta: np.ndarray, config: MonoTrackingConfig, floor_t: float) -> np.ndarray:
    """(6, 6) constant-velocity noise of one frame, contract order ``[rho, phi]``:
    translation sigma ``max(ratio * |delta_t|, floor_t)`` per axis, rotation
    ``cv_sigma_r_deg`` per axis."""
    sigma_t = max(config.cv_sigma_t_ratio * float(np.linalg.norm(delta[:3, 3])), floor_t)
    sigma_r = math.radians(config.cv_sigma_r_deg)
    return np.diag([sigma_t**2] * 3 + [sigma_r**2] * 3)


@dataclass(frozen=True, eq=False)
class PnpPose:
    """A frame's pose measured by PnP.

    Attributes:
        wTc: (4, 4) camera pose.
        inliers: (N,) bool over the correspondences given.
        reason: why no pose (``wTc`` is then None), else "".
        wTc_coast: (4, 4) the pose a frame without one coasts on, or None.
    """

    wTc: np.ndarray | None
    inliers: np.ndarray
    reason: str = ""
    wTc_coast: np.ndarray | None = None


def pnp_pose(
    points_w: np.ndarray,
    uv_px: np.ndarray,
    K: np.ndarray,
    wTc_guess: np.ndarray,
    *,
    threshold_px: float,
    min_inliers: int,
    seed: int,
) -> PnpPose:
    """Camera pose from (N, 3) world points seen at (N, 2) pixels, PnP RANSAC started
    at ``wTc_guess`` (4, 4) then refined by Levenberg-Marquardt on the inliers.

    The minimal solver (P3P inside RANSAC) ignores the guess; the guess's own
    reprojection decides when it is better than RANSAC's (a near-degenerate
    sample). ``cv2.setRNGSeed(seed)`` first: the same seed gives the same pose.
    """
    pts = np.ascontiguousarray(points_w, dtype=np.float64).reshape(-1, 3)
    uv = np.ascontiguousarray(uv_px, dtype=np.float64).reshape(-1, 2)
    n = len(pts)
    none = np.zeros(n, bool)
    if n < min_inliers:
        return PnpPose(None, none, f"{n} landmarks re-found < {min_inliers}")
    K = np.ascontiguousarray(K, dtype=np.float64)
    cTw = invert_pose(wTc_guess)
    rvec0 = cv2.Rodrigues(np.ascontiguousarray(cTw[:3, :3]))[0]
    tvec0 = cTw[:3, 3].reshape(3, 1).copy()
    cv2.setRNGSeed(int(seed))
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        pts,
        uv,
        K,
        None,
        rvec0.copy(),
        tvec0.copy(),
        useExtrinsicGuess=False,
        iterationsCount=200,
        reprojectionError=float(threshold_px),
        confidence=0.999,
        flags=cv2.SOLVEPNP_AP3P,
    )
    inliers = np.zeros(n, bool)
    if ok and inl is not None:
        inliers[inl.reshape(-1)] = True
    guess_in = reprojects(cTw, pts, uv, K, threshold_px)
    if guess_in.sum() > inliers.sum():  # the prediction explains more: start from it
        rvec, tvec, inliers = rvec0, tvec0, guess_in
    if inliers.sum() < min_inliers:
        return PnpPose(None, inliers, f"{int(inliers.sum())} PnP inliers < {min_inliers}")
    rvec, tvec = cv2.solvePnPRefineLM(pts[inliers], uv[inliers], K, None, rvec, tvec)
    cTw = pose_from_rodrigues(rvec, tvec)
    inliers = reprojects(cTw, pts, uv, K, threshold_px)  # re-judged at the refined pose
    if inliers.sum() < min_inliers:
        return PnpPose(None, inliers, f"{int(inliers.sum())} PnP inliers < {min_inliers}")
    return PnpPose(invert_pose(cTw), inliers)


def reprojects(
    cTw: np.ndarray, pts: np.ndarray, uv: np.ndarray, K: np.ndarray, threshold_px: float
) -> np.ndarray:
    """(N,) bool: world points ``pts`` (N, 3) in front of the camera ``cTw`` (4, 4) and
    reprojected within ``threshold_px`` of ``uv`` (N, 2)."""
    uv_hat, depth = project(K, cTw, pts)
    err = np.linalg.norm(uv_hat - uv, axis=1)
    return (depth > 0) & (err <= threshold_px)


def frame_rotation(
    uv_before: np.ndarray,
    uv_now: np.ndarray,
    K: np.ndarray,
    *,
    threshold_rad: float,
    min_inliers: int,
    seed: int,
    iterations: int = 100,
) -> tuple[np.ndarray | None, np.ndarray]:
    """Rotation ``R`` (3, 3) of camera ``before`` to camera ``now`` (``c_before R c_now``:
    rays of ``now`` rotated into ``before``) from (N, 2) pixels of the same points in
    both frames, translation neglected; and the (N,) bool inliers (ray angle within
    ``threshold_rad``). None when fewer than ``min_inliers`` agree.

    RANSAC over 2-point samples (the minimal set for a rotation; numpy's
    generator seeded by ``seed``), then a least-squares refit on the inliers
    (Kabsch's SVD solution of Wahba's problem)."""
    n = len(uv_before)
    inl = np.zeros(n, bool)
    if n < max(min_inliers, 2):
        return None, inl
    K_inv = np.linalg.inv(K)
    rays_b = _unit_rays(uv_before, K_inv)
    rays_n = _unit_rays(uv_now, K_inv)
    cos_min = math.cos(threshold_rad)
    rng = np.random.default_rng(seed)
    best = inl
    for _ in range(iterations):
        i, j = rng.choice(n, 2, replace=False)
        R = _kabsch(rays_b[[i, j]], rays_n[[i, j]])
        agree = np.einsum("ij,ij->i", rays_n @ R.T, rays_b) >= cos_min
        if agree.sum() > best.sum():
            best = agree
    if best.sum() < min_inliers:
        return None, best
    R = _kabsch(rays_b[best], rays_n[best])
    inl = np.einsum("ij,ij->i", rays_n @ R.T, rays_b) >= cos_min
    return (R, inl) if inl.sum() >= min_inliers else (None, inl)


def _unit_rays(uv: np.ndarray, K_inv: np.ndarray) -> np.ndarray:
    rays = np.c_[np.asarray(uv, dtype=np.float64).reshape(-1, 2), np.ones(len(uv))] @ K_inv.T
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation ``R`` minimising sum ||a_i - R b_i||^2 over (N, 3) unit vectors."""
    U, _, Vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(U @ Vt)) or 1.0
    return U @ np.diag([1.0, 1.0, d]) @ Vt
