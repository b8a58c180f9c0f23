"""3-D trajectory metrics against ground truth (numpy only, no gtsam).

Conventions: poses are (N, 4, 4) ``wTc`` (camera to world); trajectories are
matched by integer frame id, never by position in the array.

- :func:`align_umeyama` -- least-squares SE(3) or Sim(3) alignment of point
  sets (Umeyama 1991; Horn's closed form with the reflection fix);
- :func:`ate` -- absolute trajectory error of the camera centres after an
  ``"se3"`` (metric runs: odometry gives the scale), ``"sim3"`` (monocular
  runs without odometry: the scale is unobservable) or ``"none"`` alignment;
  the dict says which alignment was used and, for Sim(3), the scale;
- :func:`rpe` -- relative pose error over a fixed frame step: translation
  (metres) and rotation (degrees), on the estimate scaled by the Sim(3) scale
  when one is given;
- :func:`path_length` -- distance travelled along a trajectory;
- :func:`travel_direction_error` -- the direction of travel in the camera's axes
  against the truth's (no alignment: orientations that do not fit the path);
- :func:`pose_errors` / :func:`pose_nees` -- 6-DoF pose errors in the contract's
  right perturbation ``[rho, phi]`` and their NEES against the back end's
  (6, 6) pose covariances, with the 95 % chi-square bounds of the 2-D NEES;
  a camera-alone estimate is scored in its own gauge (:func:`gauge_sim3`).
"""

from __future__ import annotations

import math

import numpy as np

from graphslam.evaluation.alignment import collinear, rotation_about_line, umeyama
from graphslam.evaluation.matching import checked_delta, common_poses
from graphslam.evaluation.planar import NEES_CONFIDENCE, chi2_bounds, estimated_rows, nees
from slamcore.errors import GraphSlamError
from slamcore.spatial.geometry import invert_pose

ALIGNMENTS = ("se3", "sim3", "none")


def align_umeyama(
    src: np.ndarray, dst: np.ndarray, with_scale: bool = False
) -> tuple[float, np.ndarray, np.ndarray]:
    """``(s, R, t)`` minimising ``sum |s R src_i + t - dst_i|^2`` (:func:`.alignment.umeyama`).

    Args:
        src: (N, 3) points (the estimate), metres; at least 2.
        dst: (N, 3) corresponding points (the truth), metres.
        with_scale: fit the scale ``s`` too (Sim(3)); else ``s = 1`` (SE(3)).

    Returns:
        s: scale; R: (3, 3) rotation with ``det R = +1`` (never a reflection);
        t: (3,) translation, metres.
    """
    return umeyama(src, dst, 3, with_scale, "align_umeyama", min_points=2)


def _common(est_ids, est_wTc, gt_ids, gt_wTc):
    return common_poses(est_ids, est_wTc, gt_ids, gt_wTc, (4, 4))


def ate(est_ids, est_wTc, gt_ids, gt_wTc, alignment: str = "se3") -> dict:
    """Absolute trajectory error of the camera centres over the common frame ids.

    Returns ``{"rmse_m", "mean_m", "max_m", "n", "alignment", "scale"}``;
    ``scale`` is the fitted Sim(3) scale (1.0 otherwise).
    """
    if alignment not in ALIGNMENTS:
        raise GraphSlamError(f"ATE alignment must be one of {ALIGNMENTS}, got {alignment!r}")
    common, est, gt = _common(est_ids, est_wTc, gt_ids, gt_wTc)
    if common.size < 2:
        raise GraphSlamError(f"ATE needs at least 2 common frame ids, got {common.size}")
    if alignment == "sim3" and common.size < 3:  # 2 points: a Sim(3) fit is exact, the ATE 0
        raise GraphSlamError("a Sim(3)-aligned ATE needs at least 3 common frames (on 2 the fit is exact)")
    p, q = est[:, :3, 3], gt[:, :3, 3]
    s = 1.0
    if alignment != "none":
        s, R, t = align_umeyama(p, q, with_scale=alignment == "sim3")
        p = s * p @ R.T + t
    e = np.linalg.norm(p - q, axis=1)
    return {
        "rmse_m": float(np.sqrt(np.mean(e**2))),
        "mean_m": float(np.mean(e)),
        "max_m": float(np.max(e)),
        "n": int(common.size),
        "alignment": alignment,
        "scale": float(s),
    }


def _rotation_angle(R: np.ndarray) -> np.ndarray:
    """(N,) rotation angles (rad) of (N, 3, 3) rotations, ``atan2(2 sin, 2 cos)`` from the
    skew part and the trace: ``arccos`` of the trace alone loses half the digits near 0,
    and a rotation 1e-7 off orthonormal (KITTI's poses.txt, printed to 6 digits) read as
    0.015 deg, the floor of every KITTI run's rotation RPE (thirteenth hostile pass)."""
    two_cos = np.trace(R, axis1=1, axis2=2) - 1.0
    skew = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    return np.arctan2(np.linalg.norm(skew, axis=1), two_cos)


def rpe(est_ids, est_wTc, gt_ids, gt_wTc, delta: int = 1, scale: float = 1.0) -> dict:
    """Relative pose error between common frames ``delta`` apart (sorted common ids).

    For each pair the error is ``inv(gt_rel) @ est_rel`` with the estimate's
    relative translation multiplied by ``scale`` (the Sim(3) scale of a
    monocular run; 1 for metric runs).

    Returns ``{"delta_frames", "trans_rmse_m", "trans_mean_m", "rot_rmse_deg",
    "rot_mean_deg", "n"}``.
    """
    delta = checked_delta(delta)
    if not (math.isfinite(scale) and scale > 0.0):
        raise GraphSlamError(f"RPE scale must be a finite number > 0, got {scale}")
    common, est, gt = _common(est_ids, est_wTc, gt_ids, gt_wTc)
    if common.size <= delta:
        raise GraphSlamError(f"RPE needs more than {delta} common frame ids, got {common.size}")
    rel_est = invert_pose(est[:-delta]) @ est[delta:]
    rel_est[:, :3, 3] *= float(scale)
    rel_gt = invert_pose(gt[:-delta]) @ gt[delta:]
    err = invert_pose(rel_gt) @ rel_est
    t = np.linalg.norm(err[:, :3, 3], axis=1)
    r = np.degrees(_rotation_angle(err[:, :3, :3]))
    return {
        "delta_frames": delta,
        "trans_rmse_m": float(np.sqrt(np.mean(t**2))),
        "trans_mean_m": float(np.mean(t)),
        "rot_rmse_deg": float(np.sqrt(np.mean(r**2))),
        "rot_mean_deg": float(np.mean(r)),
        "n": int(len(err)),
    }


#: A step counts for :func:`travel_direction_error` when the truth moved at least this
#: share of its median step: the direction of a step made while standing still is noise.
TRAVEL_STEP_SHARE = 0.5


def travel_direction_error(est_ids, est_wTc, gt_ids, gt_wTc, min_step_m: float = 0.0) -> dict | None:
    """Angle between the estimate's and the truth's direction of travel, each step's in
    the camera's own axes at its start (``R^T (t[k+1] - t[k])``), over the consecutive
    common frames where the truth moved (:data:`TRAVEL_STEP_SHARE`).

    It needs no alignment and no scale, so it sees what a Sim(3)-fitted ATE does not: a
    reconstruction whose orientations do not fit its path (the camera sliding sideways
    along a road it drove backwards, hostile pass 20: Sim(3) ATE 0.04 m on 20 frames).

    ``min_step_m``: steps the truth made shorter than this are left out too (the run's
    ATE: a step shorter than the position error has no direction to score, as in a
    camera turning in place).

    Returns ``{"median_deg", "n"}``, or None with fewer than 3 such steps.
    """
    common, est, gt = _common(est_ids, est_wTc, gt_ids, gt_wTc)
    if common.size < 4:
        return None
    step_est = np.einsum("nji,nj->ni", est[:-1, :3, :3], np.diff(est[:, :3, 3], axis=0))
    step_gt = np.einsum("nji,nj->ni", gt[:-1, :3, :3], np.diff(gt[:, :3, 3], axis=0))
    n_est, n_gt = np.linalg.norm(step_est, axis=1), np.linalg.norm(step_gt, axis=1)
    keep = (n_gt >= TRAVEL_STEP_SHARE * np.median(n_gt)) & (n_gt > max(min_step_m, 0.0)) & (n_est > 0)
    if keep.sum() < 3:
        return None
    cos = np.sum(step_est[keep] * step_gt[keep], axis=1) / (n_est[keep] * n_gt[keep])
    angles = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return {"median_deg": float(np.median(angles)), "n": int(keep.sum())}


def path_length(wTc: np.ndarray) -> float:
    """Sum of the distances between consecutive camera centres (``wTc`` (N, 4, 4)), metres."""
    try:
        poses = np.asarray(wTc, dtype=np.float64)
    except (TypeError, ValueError):
        raise GraphSlamError("path_length: need an (N, 4, 4) array of poses") from None
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        # a reshape would read an (N, 16) or (4, 4, N) array as other poses in silence
        raise GraphSlamError(f"path_length: need an (N, 4, 4) array of poses, got shape {poses.shape}")
    p = poses[:, :3, 3]
    if len(p) < 2:
        return 0.0
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))


def percent_of(value: float | None, length: float) -> float | None:
    """``100 value / length``, or None when either is missing or the length is 0."""
    if value is None or not length or not math.isfinite(length):
        return None
    return 100.0 * float(value) / float(length)


#: Degrees of freedom of the visual pose NEES (``[rho, phi]``).
POSE_DOF = 6


def pose_errors(est_wTc: np.ndarray, gt_wTc: np.ndarray) -> np.ndarray:
    """(N, 6) ``[rho, phi]`` with ``gt ~ est @ se3_exp([rho, phi])`` to first order:
    ``rho = R_est^T (t_gt - t_est)`` (metres, camera frame), ``phi = log(R_est^T R_gt)``
    (radians) -- the right perturbation the back ends' covariances are stated in."""
    est = np.asarray(est_wTc, dtype=np.float64).reshape(-1, 4, 4)
    gt = np.asarray(gt_wTc, dtype=np.float64).reshape(-1, 4, 4)
    Rt = np.swapaxes(est[:, :3, :3], 1, 2)
    rho = np.einsum("nij,nj->ni", Rt, gt[:, :3, 3] - est[:, :3, 3])
    from scipy.spatial.transform import Rotation  # lazy: scipy.spatial costs every run ~0.2 s

    phi = Rotation.from_matrix(Rt @ gt[:, :3, :3]).as_rotvec()
    return np.concatenate([rho, phi], axis=1)


#: NEES alignments: :data:`ALIGNMENTS` and ``"gauge"`` (:func:`gauge_sim3`).
NEES_ALIGNMENTS = (*ALIGNMENTS, "gauge")


def gauge_sim3(
    est: np.ndarray, gt: np.ndarray, anchor: int, baseline: tuple[int, int] | None = None
) -> tuple[float, np.ndarray, np.ndarray]:
    """``(s, R, t)`` taking an estimate into the truth's frame in the estimator's own gauge.

    A camera-alone estimator fixes its gauge itself: a prior holds one pose (the
    anchor) and, in iSAM2, a range factor of 1 between two frames fixes the scale.
    Its covariances are relative to that gauge, so its NEES is scored after the
    similarity that puts the anchor pose exactly on the truth's and, with
    ``baseline``, makes that baseline the truth's length. Without one (a filter whose
    scale comes from a depth prior) the scale is the least-squares fit of the camera
    centres about the anchor. Umeyama's fit (``"sim3"``) would instead spread the
    error over every frame, and move the anchor, whose covariance is the prior's.

    Args:
        est, gt: (N, 4, 4) ``wTc``, rows matched.
        anchor: row of the anchored pose.
        baseline: rows ``(i, j)`` whose distance the estimator fixed, or None.
    """
    R = gt[anchor, :3, :3] @ est[anchor, :3, :3].T
    if baseline is not None:
        i, j = baseline
        d_est = float(np.linalg.norm(est[j, :3, 3] - est[i, :3, 3]))
        if d_est <= 0.0:
            raise GraphSlamError("pose_nees: the gauge's baseline has zero length in the estimate")
        s = float(np.linalg.norm(gt[j, :3, 3] - gt[i, :3, 3])) / d_est
    else:
        e = (est[:, :3, 3] - est[anchor, :3, 3]) @ R.T
        g = gt[:, :3, 3] - gt[anchor, :3, 3]
        den = float(np.sum(e * e))
        if den <= 0.0:
            raise GraphSlamError("pose_nees: the estimate never moved from its anchor")
        s = float(np.sum(e * g)) / den
    t = gt[anchor, :3, 3] - s * R @ est[anchor, :3, 3]
    return s, R, t


def pose_nees(
    est_ids,
    est_wTc,
    covariances,
    gt_ids,
    gt_wTc,
    alignment: str = "none",
    *,
    anchor_id: int | None = None,
    baseline_ids: tuple[int, int] | None = None,
) -> dict:
    """Per-frame 6-DoF pose NEES of an estimate against the truth, over common frame ids.

    ``alignment`` ``"none"``: the estimate is in the truth's frame (a run that starts
    at the true first pose, whose covariance grows from that prior). ``"se3"`` /
    ``"sim3"``: the estimate is first mapped by the Umeyama fit of :func:`ate`,
    ``wTc' = [R_a R, s R_a t + t_a]``. ``"gauge"``: by :func:`gauge_sim3` instead,
    anchored at frame ``anchor_id`` (default: the first estimated frame) with the
    scale of ``baseline_ids`` when given. In the right perturbation the fit's rotation
    cancels (``R'^T R_a = R^T``) and its scale multiplies ``rho``, so the covariance
    becomes ``D C D`` with ``D = diag(s, s, s, 1, 1, 1)``.

    Args:
        covariances: (N, 6, 6) pose covariances ``[rho, phi]``, rows as ``est_wTc``.
        anchor_id, baseline_ids: frame ids of the ``"gauge"`` alignment; both must
            have truth.

    Returns:
        ``{"frame_ids" (K,), "errors" (K, 6), "covariances" (K, 6, 6) (scaled),
        "nees" (K,), "nees_mean", "nees_in_bounds_fraction", "bounds" (lo, hi),
        "alignment", "scale"}``; the bounds are the two-sided 95 % chi-square(6)
        quantiles of one run. The mean and the share in bounds leave out the poses
        placed at the truth (the held first pose, the gauge's anchor:
        :data:`~graphslam.evaluation.planar.GIVEN_POSE_TOL`); None without others.
    """
    if alignment not in NEES_ALIGNMENTS:
        raise GraphSlamError(f"NEES alignment must be one of {NEES_ALIGNMENTS}, got {alignment!r}")
    cov = np.asarray(covariances, dtype=np.float64).reshape(-1, 6, 6)
    if len(cov) != len(np.asarray(est_ids).reshape(-1)):
        raise GraphSlamError("pose_nees: one covariance per estimated pose is needed")
    ids = np.asarray(est_ids).astype(np.int64).reshape(-1)
    common, est, gt = _common(ids, est_wTc, gt_ids, gt_wTc)
    if common.size < 1:
        raise GraphSlamError("pose_nees: no frame id in common with the truth")
    order = np.argsort(ids)
    cov = cov[order[np.searchsorted(ids[order], common)]]
    s = 1.0
    if alignment != "none":
        if alignment == "gauge":
            s, R, t = gauge_sim3(est, gt, *_gauge_rows(common, ids, anchor_id, baseline_ids))
        else:
            s, R, t = align_umeyama(est[:, :3, 3], gt[:, :3, 3], with_scale=alignment == "sim3")
        est = est.copy()
        est[:, :3, :3] = R @ est[:, :3, :3]
        est[:, :3, 3] = s * est[:, :3, 3] @ R.T + t
        if alignment != "gauge" and (collinear(gt[:, :3, 3]) or collinear(est[:, :3, 3])):
            # positions on a line leave the rotation about it free: fit it on orientations
            est = rotation_about_line(gt, est) @ est
        D = np.diag([s] * 3 + [1.0] * 3)
        cov = D @ cov @ D
    err = pose_errors(est, gt)
    nees_k = nees(err, cov)
    lo, hi = chi2_bounds(POSE_DOF, 1, NEES_CONFIDENCE)
    # the first pose held at the truth, or the gauge's anchor, tests nothing
    scored = nees_k[estimated_rows(err)]
    return {
        "frame_ids": common,
        "errors": err,
        "covariances": cov,
        "nees": nees_k,
        "nees_mean": float(np.mean(scored)) if scored.size else None,
        "nees_in_bounds_fraction": float(np.mean((scored >= lo) & (scored <= hi))) if scored.size else None,
        "bounds": (lo, hi),
        "alignment": alignment,
        "scale": float(s),
    }


def _gauge_rows(common: np.ndarray, ids: np.ndarray, anchor_id, baseline_ids) -> tuple[int, tuple | None]:
    """Rows in ``common`` of the gauge's anchor and baseline frames (:func:`pose_nees`)."""
    anchor = int(ids[0]) if anchor_id is None else int(anchor_id)
    wanted = [anchor] + ([] if baseline_ids is None else [int(f) for f in baseline_ids])
    rows = np.searchsorted(common, wanted)
    for f, r in zip(wanted, rows.tolist(), strict=True):
        if r >= len(common) or int(common[r]) != f:
            raise GraphSlamError(f"pose_nees: the gauge's frame {f} has no estimate or no truth")
    return int(rows[0]), (None if baseline_ids is None else (int(rows[1]), int(rows[2])))
