"""Robot motion models of the monocular EKF (:class:`filters.mono_ekf.MonoEkf`).

The robot is the camera, ``x_r = [p (3) m, q (4)]`` or, with the
constant-velocity model, ``[p, q, v (3) m/s world, w (3) rad/s body]``. Each
model returns the new robot state and its Jacobians ``F`` (w.r.t. the state)
and ``G`` (w.r.t. the model's noise); :func:`propagate_covariance` applies
them to the robot rows and columns of the filter's covariance only (O(n)).
"""

from __future__ import annotations

import numpy as np

from filters import landmark_params as lp


def odometry_motion(x_r: np.ndarray, T: np.ndarray, dt_s: float):
    """Compose the robot ``x_r`` ([p q] (7,) or [p q v w] (13,)) with ``T = c_{k-1} T c_k`` (4, 4).

    ``p' = p + R(q) t``, ``q' = q (x) q_d``; for 13 states the velocities
    become the step's mean ``v' = R(q) t / dt_s``, ``w' = log(R_d) / dt_s``.
    The noise ``n = [rho, phi]`` (6,) is the contract's right perturbation,
    ``T <- T se3_exp(n)``.

    Returns ``x_r'``, ``F = d x_r' / d x_r`` (r, r), ``G = d x_r' / d n`` (r, 6).
    """
    r = len(x_r)
    p, q = x_r[0:3], x_r[3:7]
    t_d, R_d = T[:3, 3], T[:3, :3]
    q_d = lp.R2q(R_d)
    R = lp.q2R(q)
    q_new = lp.q_mul(q, q_d)
    F = np.eye(r)
    G = np.zeros((r, 6))
    dRt_dq = lp.rot_jac_q(q, t_d)
    F[0:3, 3:7] = dRt_dq
    F[3:7, 3:7] = lp.q_right(q_d)
    G[0:3, 0:3] = R @ R_d
    G[3:7, 3:6] = 0.5 * lp.q_left(q_new)[:, 1:]
    x_new = x_r.copy()
    x_new[0:3] = p + R @ t_d
    x_new[3:7] = q_new
    if r == 13:
        phi_d = lp.q2v(q_d)
        x_new[7:10] = R @ t_d / dt_s
        x_new[10:13] = phi_d / dt_s
        F[7:13, 7:13] = 0.0  # the old velocities are forgotten
        F[7:10, 3:7] = dRt_dq / dt_s
        G[7:10, 0:3] = R @ R_d / dt_s
        G[10:13, 3:6] = lp.right_jacobian_inv(phi_d) / dt_s
    return x_new, F, G


def constant_velocity_motion(x_r: np.ndarray, dt_s: float):
    """MonoSLAM constant velocity on ``x_r = [p q v w]`` (13,) over ``dt_s`` seconds.

    ``p' = p + (v + V) dt``, ``q' = q (x) v2q((w + O) dt)``, ``v' = v + V``,
    ``w' = w + O`` (``w`` in the body frame), with velocity impulses
    ``n = [V (m/s), O (rad/s)]`` (6,).

    Returns ``x_r'``, ``F`` (13, 13), ``G = d x_r' / d n`` (13, 6).
    """
    q, v, w = x_r[3:7], x_r[7:10], x_r[10:13]
    dq = lp.v2q(w * dt_s)
    F = np.eye(13)
    F[0:3, 7:10] = dt_s * np.eye(3)
    F[3:7, 3:7] = lp.q_right(dq)
    dq_dw = lp.q_left(q) @ lp.v2q_jac(w * dt_s) * dt_s
    F[3:7, 10:13] = dq_dw
    G = np.zeros((13, 6))
    G[0:3, 0:3] = dt_s * np.eye(3)
    G[7:10, 0:3] = np.eye(3)
    G[3:7, 3:6] = dq_dw
    G[10:13, 3:6] = np.eye(3)
    x_new = x_r.copy()
    x_new[0:3] = x_r[0:3] + v * dt_s
    x_new[3:7] = lp.q_mul(q, dq)
    return x_new, F, G


def propagate_covariance(P: np.ndarray, r: int, F: np.ndarray, G: np.ndarray, Q: np.ndarray) -> None:
    """``P <- A P A^T + G Q G^T`` in place, ``A`` = ``F`` on the robot's ``r`` states, identity elsewhere.

    ``P`` (n, n): the filter covariance; ``F`` (r, r), ``G`` (r, 6), ``Q``
    (6, 6) the motion noise. Only the robot block and the robot-map
    cross-covariances change, so this costs O(n), not an n x n product.
    """
    Prr = F @ P[:r, :r] @ F.T + G @ Q @ G.T
    P[:r, :r] = 0.5 * (Prr + Prr.T)
    if len(P) > r:
        P[:r, r:] = F @ P[:r, r:]
        P[r:, :r] = P[:r, r:].T
