"""Marginal covariances of every pose and landmark of a visual iSAM2 run (for a saved map).

One batch factorisation of the whole graph at the final estimate
(``gtsam.Marginals``), then one marginal per key: the poses' in the contract
order ``[rho, phi]`` (right perturbation), the landmarks' in world metres^2.
Uses only the back end's public surface (its factor graph and its estimate),
so the polished estimate is the one linearised about when there was a polish.
"""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from graphslam.backends import gtsam_convert as conv
from slamcore.errors import GraphSlamError
from slamcore.spatial.records import VisualEstimate


def marginal_covariances(backend, estimate: VisualEstimate) -> tuple[np.ndarray, np.ndarray]:
    """``(pose covariances (N, 6, 6), landmark covariances (L, 3, 3))`` of ``estimate``'s
    frames and landmarks, in their order; ``backend`` is a ``VisualIsam2Backend``."""
    return _marginals(backend, estimate, with_landmarks=True)


def pose_marginals(backend, estimate: VisualEstimate) -> np.ndarray:
    """(N, 6, 6) marginal covariances of ``estimate``'s poses only (``graphslam compare``'s
    NEES; the landmarks' marginals are skipped, thousands of them on KITTI)."""
    return _marginals(backend, estimate, with_landmarks=False)[0]


def _marginals(backend, estimate: VisualEstimate, with_landmarks: bool):
    values = gtsam.Values()
    for f, T in zip(estimate.frame_ids.tolist(), estimate.wTc, strict=True):
        values.insert(X(f), conv.pose3(T))
    for t, p in zip(estimate.landmark_ids.tolist(), estimate.landmarks_w, strict=True):
        values.insert(L(t), np.asarray(p, dtype=np.float64))
    try:
        marginals = gtsam.Marginals(backend.factor_graph(), values)
        poses = np.array(
            [
                conv.pose3_covariance_from_gtsam(marginals.marginalCovariance(X(f)))
                for f in estimate.frame_ids.tolist()
            ]
        ).reshape(-1, 6, 6)
        points = np.array(
            [
                marginals.marginalCovariance(L(t))
                for t in (estimate.landmark_ids.tolist() if with_landmarks else [])
            ]
        ).reshape(-1, 3, 3)
    except RuntimeError as e:  # an indeterminate system: a variable the graph does not pin
        raise GraphSlamError(f"cannot compute the map's covariances: {e}") from None
    return poses, points
