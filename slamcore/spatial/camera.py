"""Pinhole camera maths in numpy: projection with Jacobians, innovation covariances,
plane-induced patch warps.

Conventions
-----------
* ``cTw`` (4, 4) maps world points into the camera frame: ``p_c = R p_w + t``.
  The camera looks along +z; ``depth`` is ``p_c[2]`` (metres).
* ``K`` (3, 3) is the intrinsic matrix; ``uv = (K p_c)[:2] / p_c[2]`` in pixels,
  ``u`` the column and ``v`` the row.
* Pose perturbation: a 6-vector ``delta = [rho (3, translation, metres),
  phi (3, rotation vector, radians)]`` applied on the LEFT, in the camera
  frame: ``cTw <- se3_exp(delta) @ cTw``. To first order
  ``p_c <- p_c + rho + phi x p_c``, so ``d p_c / d delta = [I, -[p_c]_x]``.
  A pose covariance ``Sigma (6, 6)`` uses the same order (translation first).
"""

from __future__ import annotations

import numpy as np

from slamcore.spatial.geometry import skew

__all__ = [
    "project",
    "project_jacobians",
    "innovation_covariance",
    "pose_covariance",
    "plane_induced_affine",
    "intrinsics_matrix",
]


def _check(K, cTw, p_w):
    K = np.asarray(K, dtype=np.float64)
    cTw = np.asarray(cTw, dtype=np.float64)
    p_w = np.asarray(p_w, dtype=np.float64)
    if K.shape != (3, 3) or cTw.shape != (4, 4) or p_w.ndim != 2 or p_w.shape[1] != 3:
        raise ValueError(f"expected K (3,3), cTw (4,4), p_w (N,3); got {K.shape}, {cTw.shape}, {p_w.shape}")
    return K, cTw, p_w


def project(K: np.ndarray, cTw: np.ndarray, p_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points ``p_w`` (N, 3) [m] -> ``(uv (N, 2) px, depth (N,) m)``.

    Points with depth <= 0 get ``uv`` computed anyway (meaningless): test ``depth > 0``.
    """
    K, cTw, p_w = _check(K, cTw, p_w)
    p_c = p_w @ cTw[:3, :3].T + cTw[:3, 3]
    h = p_c @ K.T
    z = p_c[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = h[:, :2] / h[:, 2:3]
    return uv, z


def project_jacobians(K: np.ndarray, cTw: np.ndarray, p_w: np.ndarray):
    """Projection and its Jacobians.

    Returns ``uv (N, 2), depth (N,), J_point (N, 2, 3) = d uv / d p_w,
    J_pose (N, 2, 6) = d uv / d delta`` with ``delta = [rho, phi]`` the left
    camera-frame perturbation ``cTw <- se3_exp(delta) @ cTw`` (module docstring).
    """
    K, cTw, p_w = _check(K, cTw, p_w)
    R = cTw[:3, :3]
    p_c = p_w @ R.T + cTw[:3, 3]
    h = p_c @ K.T
    z = p_c[:, 2]
    uv = h[:, :2] / h[:, 2:3]
    # d uv / d p_c = (K[:2] - uv K[2]) / h2 ; h2 = z when K[2] = [0, 0, 1]
    d_pc = (K[None, :2, :] - uv[:, :, None] * K[None, 2:3, :]) / h[:, 2, None, None]
    J_point = d_pc @ R
    d_delta = np.concatenate([np.broadcast_to(np.eye(3), (len(p_c), 3, 3)), -skew(p_c)], axis=2)
    J_pose = d_pc @ d_delta
    return uv, z, J_point, J_pose


def pose_covariance(sigma_t_m: float, sigma_r_rad: float) -> np.ndarray:
    """Diagonal (6, 6) pose covariance, translation first (per-axis sigmas)."""
    return np.diag([sigma_t_m**2] * 3 + [sigma_r_rad**2] * 3)


def innovation_covariance(
    J_pose: np.ndarray,
    sigma_pose: np.ndarray,
    sigma_px: float,
    J_point: np.ndarray | None = None,
    sigma_point: np.ndarray | None = None,
) -> np.ndarray:
    """``S = J_pose Sigma_pose J_pose^T (+ J_point Sigma_point J_point^T) + sigma_px^2 I`` (N, 2, 2).

    ``sigma_point`` may be (3, 3) (shared) or (N, 3, 3). Cross-covariances
    between pose and point are taken as zero.
    """
    S = J_pose @ sigma_pose @ np.swapaxes(J_pose, 1, 2)
    if J_point is not None and sigma_point is not None:
        S = S + J_point @ sigma_point @ np.swapaxes(J_point, 1, 2)
    return S + (sigma_px**2) * np.eye(2)


def plane_induced_affine(K: np.ndarray, c1Tc0: np.ndarray, uv0: np.ndarray, depth0: np.ndarray) -> np.ndarray:
    """(N, 2, 2) local affine maps of image-0 pixel offsets to image-1 offsets.

    Each point ``uv0`` (N, 2) of camera 0 at ``depth0`` (N,) is taken on the
    fronto-parallel plane ``z = depth`` of camera 0; ``c1Tc0`` (4, 4), or
    (N, 4, 4) one per point, moves camera-0 points into camera 1. The plane
    (``n^T p0 = d``, n = [0, 0, 1]) induces the homography
    ``H = K (R + t n^T / d) K^-1``; the affine is its Jacobian at ``uv0``. An
    infinite depth gives the rotation-only map. Used to predict a patch's
    appearance (``frontend.active_search``, ``frontend.appearance``).
    """
    K = np.asarray(K, dtype=np.float64)
    uv0 = np.asarray(uv0, dtype=np.float64).reshape(-1, 2)
    d = np.asarray(depth0, dtype=np.float64).reshape(-1)
    c1Tc0 = np.asarray(c1Tc0, dtype=np.float64)
    R, t = c1Tc0[..., :3, :3], c1Tc0[..., :3, 3]
    Kinv = np.linalg.inv(K)
    n = np.array([0.0, 0.0, 1.0])
    H = K @ (R + t[..., :, None] * n / d[:, None, None]) @ Kinv  # (N,3,3)
    x = np.concatenate([uv0, np.ones((len(uv0), 1))], axis=1)
    h = np.einsum("nij,nj->ni", H, x)
    uv1 = h[:, :2] / h[:, 2:3]
    return (H[:, :2, :2] - uv1[:, :, None] * H[:, 2:3, :2]) / h[:, 2, None, None]


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """(3, 3) ``K`` from focal lengths and principal point (pixels)."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
