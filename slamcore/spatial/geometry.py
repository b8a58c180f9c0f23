"""SE(3) and SO(3) maths in numpy: exponential maps, inverse, quaternions.

Conventions: ``aTb`` (4, 4) maps points of frame ``b`` into frame ``a``; a
6-vector ``delta = [rho (3, translation, m), phi (3, rotation vector, rad)]``
(translation first), as in :mod:`slamcore.spatial.camera`. Quaternions are
``[qx, qy, qz, qw]`` (the TUM file order), ``qw >= 0``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["skew", "so3_exp", "se3_exp", "invert_pose", "rotation_to_quaternion"]


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
        V = np.eye(3) + (1 - math.cos(th)) / th**2 * W + (th - math.sin(th)) / th**3 * W @ W
    T = np.eye(4)
    T[:3, :3] = so3_exp(phi)
    T[:3, 3] = V @ rho
    return T


def se3_adjoint(T: np.ndarray) -> np.ndarray:
    """(6, 6) adjoint of the rigid transform ``T`` for ``[rho, phi]`` (translation
    first): ``T exp(xi) = exp(Ad_T xi) T``; gtsam's ``Pose3.AdjointMap`` with its
    ``[phi, rho]`` blocks swapped."""
    T = np.asarray(T, dtype=np.float64).reshape(4, 4)
    R, t = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = A[3:, 3:] = R
    A[:3, 3:] = skew(t) @ R
    return A


def non_rigid_rows(T: np.ndarray, tol: float) -> np.ndarray:
    """(N,) True where the (N, 4, 4) ``T[k]`` is not a rigid transform to ``tol``: its
    ``R^T R`` off the identity or its bottom row off ``[0, 0, 0, 1]`` by more, or a
    reflection."""
    T = np.asarray(T, dtype=np.float64).reshape(-1, 4, 4)
    R = T[:, :3, :3]
    off = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2), initial=0.0)
    bottom = np.abs(T[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1, initial=0.0)
    return (off > tol) | (bottom > tol) | (np.linalg.det(R) < 0.0)


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


def rotation_to_quaternion(R: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations -> (N, 4) unit quaternions ``[qx, qy, qz, qw]``, ``qw >= 0``."""
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    q = np.empty((len(R), 4))
    for i, m in enumerate(R):
        # Shepperd: pivot on the largest of (trace, diagonal) for precision
        tr = np.trace(m)
        d = np.diag(m)
        j = int(np.argmax([tr, *d]))
        if j == 0:
            s = 2.0 * math.sqrt(max(1.0 + tr, 0.0))
            v = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
        elif j == 1:
            s = 2.0 * math.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 0.0))
            v = [s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
        elif j == 2:
            s = 2.0 * math.sqrt(max(1.0 + m[1, 1] - m[0, 0] - m[2, 2], 0.0))
            v = [(m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
        else:
            s = 2.0 * math.sqrt(max(1.0 + m[2, 2] - m[0, 0] - m[1, 1], 0.0))
            v = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s]
        qi = np.asarray(v)
        qi /= np.linalg.norm(qi)
        q[i] = -qi if qi[3] < 0 else qi
    return q
