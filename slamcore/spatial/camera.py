"""Pinhole projection with Jacobians, and KITTI calibration / pose readers (numpy only).

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

KITTI odometry files
--------------------
* ``calib.txt``: lines ``P0: 12 numbers`` (row-major 3x4 projection); ``K`` of
  camera ``P0`` is its left 3x3 block.
* ``poses.txt``: one line per frame, 12 numbers, the row-major 3x4 ``wTc_k``
  mapping points of camera 0 at frame k into camera 0 at frame 0 (the world).
  :func:`read_kitti_poses` returns these as (N, 4, 4) ``wTc``; invert them
  (:func:`invert_pose`) for ``cTw``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from slamcore.errors import InputError

__all__ = [
    "skew", "so3_exp", "se3_exp", "invert_pose", "project", "project_jacobians",
    "innovation_covariance", "pose_covariance", "plane_induced_affine", "read_kitti_calib",
    "read_kitti_poses",
]


def skew(w: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices ``[w]_x`` (``[w]_x v = w x v``)."""
    w = np.asarray(w, dtype=np.float64)
    out = np.zeros(w.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -w[..., 2], w[..., 1]
    out[..., 1, 0], out[..., 1, 2] = w[..., 2], -w[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -w[..., 1], w[..., 0]
    return out


def so3_exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``phi`` (3,) (Rodrigues)."""
    phi = np.asarray(phi, dtype=np.float64)
    th = float(np.linalg.norm(phi))
    W = skew(phi)
    if th < 1e-8:
        return np.eye(3) + W + 0.5 * W @ W
    return np.eye(3) + math.sin(th) / th * W + (1 - math.cos(th)) / th**2 * W @ W


def se3_exp(delta: np.ndarray) -> np.ndarray:
    """(4, 4) SE(3) exponential of ``delta = [rho, phi]`` (translation first)."""
    delta = np.asarray(delta, dtype=np.float64).reshape(6)
    rho, phi = delta[:3], delta[3:]
    th = float(np.linalg.norm(phi))
    W = skew(phi)
    if th < 1e-8:
        V = np.eye(3) + 0.5 * W + W @ W / 6.0
    else:
        V = (np.eye(3) + (1 - math.cos(th)) / th**2 * W
             + (th - math.sin(th)) / th**3 * W @ W)
    T = np.eye(4)
    T[:3, :3] = so3_exp(phi)
    T[:3, 3] = V @ rho
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (4, 4) or a stack (N, 4, 4)."""
    T = np.asarray(T, dtype=np.float64)
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


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


def innovation_covariance(J_pose: np.ndarray, sigma_pose: np.ndarray, sigma_px: float,
                          J_point: np.ndarray | None = None,
                          sigma_point: np.ndarray | None = None) -> np.ndarray:
    """``S = J_pose Sigma_pose J_pose^T (+ J_point Sigma_point J_point^T) + sigma_px^2 I`` (N, 2, 2).

    ``sigma_point`` may be (3, 3) (shared) or (N, 3, 3). Cross-covariances
    between pose and point are taken as zero.
    """
    S = J_pose @ sigma_pose @ np.swapaxes(J_pose, 1, 2)
    if J_point is not None and sigma_point is not None:
        S = S + J_point @ sigma_point @ np.swapaxes(J_point, 1, 2)
    return S + (sigma_px**2) * np.eye(2)


def _numbers(path: Path, lineno: int, fields: list[str], count: int) -> np.ndarray:
    if len(fields) != count:
        raise InputError(f"expected {count} numbers, got {len(fields)}", path, lineno)
    try:
        vals = np.array([float(x) for x in fields], dtype=np.float64)
    except ValueError:
        raise InputError("non-numeric value", path, lineno) from None
    if not np.all(np.isfinite(vals)):
        raise InputError("non-finite value", path, lineno)
    return vals


def read_kitti_calib(path: str | Path, camera: str = "P0") -> np.ndarray:
    """``K`` (3, 3) of ``camera`` (``"P0"``..``"P3"``) from a KITTI odometry ``calib.txt``."""
    path = Path(path)
    if not path.is_file():
        raise InputError("calibration file not found", path)
    with path.open("r", encoding="utf-8") as f:
        for lineno, line in enumerate(f, start=1):
            if not line.strip():
                continue
            name, sep, rest = line.partition(":")
            if not sep:
                raise InputError("expected 'NAME: 12 numbers'", path, lineno)
            if name.strip() != camera:
                continue
            P = _numbers(path, lineno, rest.split(), 12).reshape(3, 4)
            K = P[:, :3].copy()
            if K[2, 2] == 0 or abs(K[0, 0]) == 0 or abs(K[1, 1]) == 0:
                raise InputError(f"degenerate {camera} projection matrix", path, lineno)
            return K / K[2, 2]
    raise InputError(f"no line for camera {camera!r}", path)


def read_kitti_poses(path: str | Path) -> np.ndarray:
    """(N, 4, 4) ``wTc_k`` from a KITTI ``poses.txt`` (12 numbers per line, row-major 3x4)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("pose file not found", path)
    poses = []
    with path.open("r", encoding="utf-8") as f:
        for lineno, line in enumerate(f, start=1):
            if not line.strip():
                continue
            T = np.eye(4)
            T[:3, :] = _numbers(path, lineno, line.split(), 12).reshape(3, 4)
            poses.append(T)
    if not poses:
        raise InputError("no poses", path)
    return np.stack(poses)


def plane_induced_affine(K: np.ndarray, c1Tc0: np.ndarray, uv0: np.ndarray, depth0: np.ndarray) -> np.ndarray:
    """(N, 2, 2) local affine maps of image-0 pixel offsets to image-1 offsets.

    Each point ``uv0`` (N, 2) of camera 0 at ``depth0`` (N,) is taken on the
    fronto-parallel plane ``z = depth`` of camera 0; ``c1Tc0`` moves camera-0
    points into camera 1. The plane (``n^T p0 = d``, n = [0, 0, 1]) induces the
    homography ``H = K (R + t n^T / d) K^-1``; the affine is its Jacobian at
    ``uv0``. Used to predict a patch's appearance (``frontend.active_search``).
    """
    K = np.asarray(K, dtype=np.float64)
    uv0 = np.asarray(uv0, dtype=np.float64).reshape(-1, 2)
    d = np.asarray(depth0, dtype=np.float64).reshape(-1)
    R, t = c1Tc0[:3, :3], c1Tc0[:3, 3]
    Kinv = np.linalg.inv(K)
    n = np.array([0.0, 0.0, 1.0])
    H = K @ (R[None] + t[None, :, None] * n[None, None, :] / d[:, None, None]) @ Kinv  # (N,3,3)
    x = np.concatenate([uv0, np.ones((len(uv0), 1))], axis=1)
    h = np.einsum("nij,nj->ni", H, x)
    uv1 = h[:, :2] / h[:, 2:3]
    return (H[:, :2, :2] - uv1[:, :, None] * H[:, 2:3, :2]) / h[:, 2, None, None]
