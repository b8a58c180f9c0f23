"""Two trajectories matched by pose id, after checking that each is one (numpy only).

The 2-D metrics (:mod:`graphslam.evaluation.planar`, poses ``[x, y, theta]``) and the
3-D ones (:mod:`graphslam.evaluation.spatial`, poses ``wTc``) both score only the ids
the trajectories share. A score of arrays that are not trajectories is a number
with no meaning, so what cannot be one is refused here instead of reshaped: a
transposed array, ids with a fraction or repeated, a pose that is not finite, a
3-D pose that is not rigid.
"""

from __future__ import annotations

import math

import numpy as np

from slamcore.errors import GraphSlamError
from slamcore.spatial.geometry import non_rigid_rows

__all__ = ["RIGID_TOL", "checked_delta", "checked_poses", "common_poses"]

#: Largest deviation of a 3-D pose from a rigid transform (``R^T R - I`` and the
#: bottom row, elementwise) accepted. Poses of files of 9 printed digits are rigid to
#: about 1e-7 (KITTI's poses.txt: 1.5e-7), and odometry chained from them drifts
#: off further (3.4e-6 after 30 KITTI frames; a random walk of ~1e-7 a step reaches
#: 1e-5 over 10^4 steps): 1e-3 (a 0.1 % scale) is far above that and far below a
#: matrix that is no pose (a scaled or sheared one).
RIGID_TOL = 1e-3


def _ids(ids, what: str) -> np.ndarray:
    a = np.asarray(ids)
    if a.ndim != 1:
        raise GraphSlamError(f"{what} ids must be one-dimensional, got shape {a.shape}")
    if a.dtype.kind in "iu":
        out = a.astype(np.int64)
    elif a.dtype.kind == "f" and np.all(np.isfinite(a)) and np.all(a == np.round(a)):
        if a.size and np.max(np.abs(a)) >= 2.0**63:
            raise GraphSlamError(f"{what} ids must fit a 64-bit integer")
        out = a.astype(np.int64)
    else:
        raise GraphSlamError(f"{what} ids must be integers, got {a.dtype} values like {a[:3].tolist()}")
    if np.unique(out).size != out.size:
        raise GraphSlamError(f"{what} ids must be distinct (an id names one pose)")
    return out


def checked_poses(poses, pose_shape: tuple[int, ...], n: int, what: str, per: str = "ids") -> np.ndarray:
    """``poses`` as float64 (n, *pose_shape), one per id (or stamp: ``per``); GraphSlamError
    when not numbers, of another shape, not finite, or (4 x 4) not rigid."""
    try:
        p = np.asarray(poses, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise GraphSlamError(f"{what} poses must be numbers: {e}") from None
    if p.shape != (n, *pose_shape):
        raise GraphSlamError(
            f"{what} poses must have shape ({n}, {', '.join(map(str, pose_shape))}) for {n} {per}, "
            f"got {p.shape}"
        )
    if not np.all(np.isfinite(p)):
        raise GraphSlamError(f"{what} poses must be finite")
    if pose_shape == (4, 4) and np.any(non_rigid_rows(p, RIGID_TOL)):
        raise GraphSlamError(f"{what} poses must be rigid transforms (rotation and translation)")
    return p


def common_poses(
    est_ids, est_poses, gt_ids, gt_poses, pose_shape: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sorted common ids (K,) and the matching rows (K, *pose_shape) of both trajectories.

    Raises:
        GraphSlamError: ids that are not distinct integers of one dimension, poses
            not of shape ``(len(ids), *pose_shape)``, not finite, or (4 x 4) not rigid.
    """
    e_ids, g_ids = _ids(est_ids, "estimate"), _ids(gt_ids, "truth")
    est = checked_poses(est_poses, pose_shape, e_ids.size, "estimate")
    gt = checked_poses(gt_poses, pose_shape, g_ids.size, "truth")
    common, i_est, i_gt = np.intersect1d(e_ids, g_ids, assume_unique=True, return_indices=True)
    return common, est[i_est], gt[i_gt]


def checked_delta(delta) -> int:
    """The RPE step ``delta`` as an int >= 1 (a whole number of poses), or GraphSlamError."""
    if isinstance(delta, (bool, np.bool_)) or not isinstance(delta, (int, np.integer, float, np.floating)):
        raise GraphSlamError(f"RPE delta must be a whole number >= 1, got {delta!r}")
    if not (math.isfinite(delta) and delta == int(delta) and delta >= 1):
        raise GraphSlamError(f"RPE delta must be a whole number >= 1, got {delta!r}")
    return int(delta)
