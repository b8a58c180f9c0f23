"""SE(2) maths and the range-bearing sensor model, with analytic Jacobians (numpy only).

Shared by EKF-SLAM and FastSLAM. Written by hand because the filters must stay
free of gtsam (DESIGN.md layering); the same maths is checked against gtsam's
Pose2 and BearingRange in the tests. Functions accept a leading batch axis so
FastSLAM can evaluate all particles at once.

Conventions: pose ``[x_m, y_m, theta_rad]``; odometry ``[dx, dy, dtheta]`` in
the body frame (``x' = x (+) u``); measurement ``[range_m, bearing_rad]``.
"""

from __future__ import annotations

import numpy as np


def wrap_angle(theta_rad):
    """Wrap angle(s) to [-pi, pi)."""
    return (np.asarray(theta_rad) + np.pi) % (2.0 * np.pi) - np.pi


def compose(wTb: np.ndarray, bTc: np.ndarray) -> np.ndarray:
    """``wTc = wTb (+) bTc`` for poses of shape (..., 3)."""
    x, y, th = wTb[..., 0], wTb[..., 1], wTb[..., 2]
    dx, dy, dth = bTc[..., 0], bTc[..., 1], bTc[..., 2]
    c, s = np.cos(th), np.sin(th)
    return np.stack([x + c * dx - s * dy, y + s * dx + c * dy, wrap_angle(th + dth)], axis=-1)


def compose_jacobians(wTb: np.ndarray, bTc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of :func:`compose` w.r.t. ``wTb`` and ``bTc``; each (..., 3, 3)."""
    th = wTb[..., 2]
    dx, dy = bTc[..., 0], bTc[..., 1]
    c, s = np.cos(th), np.sin(th)
    shape = np.shape(th) + (3, 3)
    J_x = np.zeros(shape)
    J_x[..., 0, 0] = J_x[..., 1, 1] = J_x[..., 2, 2] = 1.0
    J_x[..., 0, 2] = -s * dx - c * dy
    J_x[..., 1, 2] = c * dx - s * dy
    J_u = np.zeros(shape)
    J_u[..., 0, 0] = c
    J_u[..., 0, 1] = -s
    J_u[..., 1, 0] = s
    J_u[..., 1, 1] = c
    J_u[..., 2, 2] = 1.0
    return J_x, J_u


def between(wTa: np.ndarray, wTb: np.ndarray) -> np.ndarray:
    """``aTb = wTa^-1 (+) wTb`` of poses (..., 3) (numpy ``Pose2.between``)."""
    c, s = np.cos(wTa[..., 2]), np.sin(wTa[..., 2])
    dx, dy = wTb[..., 0] - wTa[..., 0], wTb[..., 1] - wTa[..., 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(wTb[..., 2] - wTa[..., 2])], axis=-1)


def inverse(aTb: np.ndarray) -> np.ndarray:
    """``bTa`` of a pose (3,)."""
    dx, dy, dth = aTb
    c, s = np.cos(dth), np.sin(dth)
    return np.array([-c * dx - s * dy, s * dx - c * dy, wrap_angle(-dth)])


def invert(aTb: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``bTa`` (3,) and its (3, 3) covariance from ``aTb`` (3,) and its covariance.

    First order: the covariance goes through the Jacobian of the inverse, for
    odometry stored new->old (as pose-graph files do).
    """
    dx, dy, dth = aTb
    c, s = np.cos(dth), np.sin(dth)
    bTa = inverse(aTb)
    J = np.array([[-c, -s, s * dx - c * dy], [s, -c, c * dx + s * dy], [0.0, 0.0, -1.0]])
    out = J @ covariance @ J.T
    return bTa, 0.5 * (out + out.T)


def observe(wTb: np.ndarray, m_w: np.ndarray) -> np.ndarray:
    """Predicted ``[range_m, bearing_rad]`` of landmark ``m_w`` (..., 2) from ``wTb`` (..., 3)."""
    d = m_w - wTb[..., :2]
    r = np.hypot(d[..., 0], d[..., 1])
    b = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - wTb[..., 2])
    return np.stack([r, b], axis=-1)


def observe_jacobians(wTb: np.ndarray, m_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of :func:`observe` w.r.t. the pose (..., 2, 3) and landmark (..., 2, 2)."""
    d = m_w - wTb[..., :2]
    q = d[..., 0] ** 2 + d[..., 1] ** 2
    r = np.sqrt(q)
    shape = np.shape(q)
    H_m = np.empty(shape + (2, 2))
    H_m[..., 0, 0] = d[..., 0] / r
    H_m[..., 0, 1] = d[..., 1] / r
    H_m[..., 1, 0] = -d[..., 1] / q
    H_m[..., 1, 1] = d[..., 0] / q
    H_x = np.empty(shape + (2, 3))
    H_x[..., :, :2] = -H_m
    H_x[..., 0, 2] = 0.0
    H_x[..., 1, 2] = -1.0
    return H_x, H_m


def inverse_observe(wTb: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Landmark position (..., 2) from pose (..., 3) and ``[range, bearing]`` (..., 2)."""
    a = wTb[..., 2] + z[..., 1]
    return np.stack([wTb[..., 0] + z[..., 0] * np.cos(a), wTb[..., 1] + z[..., 0] * np.sin(a)], axis=-1)


def inverse_observe_jacobians(wTb: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of :func:`inverse_observe` w.r.t. the pose (..., 2, 3) and ``z`` (..., 2, 2)."""
    a = wTb[..., 2] + z[..., 1]
    c, s = np.cos(a), np.sin(a)
    r = z[..., 0]
    shape = np.shape(a)
    G_x = np.zeros(shape + (2, 3))
    G_x[..., 0, 0] = G_x[..., 1, 1] = 1.0
    G_x[..., 0, 2] = -r * s
    G_x[..., 1, 2] = r * c
    G_z = np.empty(shape + (2, 2))
    G_z[..., 0, 0] = c
    G_z[..., 0, 1] = -r * s
    G_z[..., 1, 0] = s
    G_z[..., 1, 1] = r * c
    return G_x, G_z


def innovation(z: np.ndarray, z_pred: np.ndarray) -> np.ndarray:
    """``z - z_pred`` with the bearing wrapped, shape (..., 2)."""
    nu = z - z_pred
    return np.concatenate([nu[..., :1], wrap_angle(nu[..., 1:2])], axis=-1)
