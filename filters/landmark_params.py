"""Quaternions, point-landmark parametrisations and pinhole observation with Jacobians (numpy only).

Helpers of :mod:`filters.mono_ekf` (the FPGA paper, seed 003, section 2.1).

Quaternions are ``q = [w, x, y, z]`` (w first, Hamilton product, ``R(q)`` maps
body vectors to the world). ``R(q)`` is evaluated with the quadratic formula
``(w^2 - v.v) I + 2 v v^T + 2 w [v]_x`` so that its Jacobian with respect to a
non-unit ``q`` is exact; the filter renormalises ``q`` after each update.

Point landmarks, all in the world frame:

- Euclidean ``[X, Y, Z]`` (3), metres.
- IDP ``[x0, y0, z0, elevation, azimuth, rho]`` (6): anchor ``p0`` (the camera
  centre at initialisation, m), the ray direction
  ``m(el, az) = [cos el sin az, -sin el, cos el cos az]`` and the inverse
  distance ``rho`` (1/m) along it: ``p = p0 + m / rho``. The angles follow
  Civera et al. (2008) for a "camera-like" world (z forward, y down), which is
  the usual visual-SLAM world (the first camera's frame, KITTI's): the
  singular direction is the world's +-y axis (straight up or down), which a
  camera rarely initialises a point along.
- AHP ``[x0, y0, z0, u, v, w, rho]`` (7): anchor and homogeneous direction
  ``v`` (unit at initialisation, free afterwards): ``p = p0 + v / rho``.

All three share one form, which the batched observation uses: a landmark is an
anchor ``A``, a direction ``C`` and a weight ``W`` with
``p ~ W A + C`` in homogeneous coordinates (Euclidean: ``A = p, C = 0, W = 1``;
IDP: ``A = p0, C = m(el, az), W = rho``; AHP: ``A = p0, C = v, W = rho``). In
the camera ``h_c = R^T (W (A - p_cam) + C)``, which stays finite for points at
infinity (``rho = 0``) and is why inverse depth is linear enough to start with.

Batched landmark arrays use a padded layout of 7 columns per landmark
(:data:`PAD`): the parameters, then zeros; Jacobians w.r.t. the landmark are
``(k, 2, 7)`` with zero padding columns.
"""

from __future__ import annotations

import math

import numpy as np

from slamcore.spatial.geometry import skew

#: Landmark kinds (codes stored by the filter).
EUCLIDEAN, IDP, AHP = 0, 1, 2
KIND_NAMES = {EUCLIDEAN: "euclidean", IDP: "idp", AHP: "ahp"}
#: Parameters per kind.
SIZE = {EUCLIDEAN: 3, IDP: 6, AHP: 7}
#: Padded width of batched landmark parameters and Jacobians.
PAD = 7

__all__ = [
    "EUCLIDEAN",
    "IDP",
    "AHP",
    "KIND_NAMES",
    "SIZE",
    "PAD",
    "q_mul",
    "q_conj",
    "q_left",
    "q_right",
    "q2R",
    "R2q",
    "rot_jac_q",
    "rotT_jac_q",
    "v2q",
    "v2q_jac",
    "q2v",
    "right_jacobian_inv",
    "idp_direction",
    "idp_direction_jac",
    "direction_to_idp_angles",
    "to_euclidean",
    "init_landmarks",
    "observe_landmarks",
    "pose_jacobian_to_tangent",
    "tangent_to_pose_jacobian",
    "project_hypotheses",
]


# --------------------------------------------------------------- quaternions


def q_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a (x) b`` of (4,) quaternions."""
    aw, av = a[0], a[1:]
    bw, bv = b[0], b[1:]
    return np.r_[aw * bw - av @ bv, aw * bv + bw * av + np.cross(av, bv)]


def q_conj(q: np.ndarray) -> np.ndarray:
    return np.r_[q[0], -q[1:]]


def q_left(q: np.ndarray) -> np.ndarray:
    """(4, 4) ``Q_L(q)`` with ``q (x) p = Q_L(q) p``."""
    w, v = q[0], q[1:]
    M = np.empty((4, 4))
    M[0, 0], M[0, 1:] = w, -v
    M[1:, 0] = v
    M[1:, 1:] = w * np.eye(3) + skew(v)
    return M


def q_right(p: np.ndarray) -> np.ndarray:
    """(4, 4) ``Q_R(p)`` with ``q (x) p = Q_R(p) q``."""
    w, v = p[0], p[1:]
    M = np.empty((4, 4))
    M[0, 0], M[0, 1:] = w, -v
    M[1:, 0] = v
    M[1:, 1:] = w * np.eye(3) - skew(v)
    return M


def q2R(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of ``q`` (4,) by the quadratic formula (exact for unit q)."""
    w, x, y, z = (float(c) for c in q)
    return np.array(
        [
            [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
        ]
    )


def R2q(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w >= 0) of a rotation matrix (3, 3) (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    diag = np.diag(R)
    k = int(np.argmax(np.r_[tr, diag]))
    if k == 0:
        s = 2.0 * math.sqrt(max(1.0 + tr, 0.0))
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    else:
        i = k - 1
        j, m = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + R[i, i] - R[j, j] - R[m, m], 0.0))
        q = np.empty(4)
        q[0] = (R[m, j] - R[j, m]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + m] = (R[m, i] + R[i, m]) / s
    if q[0] < 0:
        q = -q
    return q / np.linalg.norm(q)


def rot_jac_q(q: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``d (R(q) a) / d q`` for ``a`` (3,) -> (3, 4), or batched ``a`` (k, 3) -> (k, 3, 4)."""
    D = _dR_dq(q).reshape(3, 4, 3)  # [i, m, j] = dR_ij / dq_m
    if np.ndim(a) == 1:
        return D @ a
    return np.einsum("imj,kj->kim", D, a)


def rotT_jac_q(q: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``d (R(q)^T a) / d q`` for ``a`` (3,) -> (3, 4), or batched ``a`` (k, 3) -> (k, 3, 4)."""
    w, v = q[0], q[1:]
    a2 = np.atleast_2d(a)
    J = np.empty((a2.shape[0], 3, 4))
    J[:, :, 0] = 2.0 * w * a2 - 2.0 * np.cross(v, a2)
    J[:, :, 1:] = (
        -2.0 * a2[:, :, None] * v[None, None, :]
        + 2.0 * (a2 @ v)[:, None, None] * np.eye(3)
        + 2.0 * v[None, :, None] * a2[:, None, :]
        + 2.0 * w * skew(a2)
    )
    return J[0] if np.ndim(a) == 1 else J


def v2q(phi: np.ndarray) -> np.ndarray:
    """Unit quaternion of the rotation vector ``phi`` (3,) rad."""
    th = float(np.linalg.norm(phi))
    if th < 1e-12:
        q = np.r_[1.0, 0.5 * phi]
        return q / np.linalg.norm(q)
    return np.r_[math.cos(th / 2), math.sin(th / 2) / th * phi]


def v2q_jac(phi: np.ndarray) -> np.ndarray:
    """``d v2q(phi) / d phi`` (4, 3)."""
    th = float(np.linalg.norm(phi))
    J = np.empty((4, 3))
    if th < 1e-8:
        J[0] = -0.25 * phi
        J[1:] = 0.5 * np.eye(3)
        return J
    u = phi / th
    s, c = math.sin(th / 2), math.cos(th / 2)
    J[0] = -0.5 * s * u
    J[1:] = 0.5 * c * np.outer(u, u) + s / th * (np.eye(3) - np.outer(u, u))
    return J


def q2v(q: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) rad of a unit quaternion (the short way round)."""
    q = q if q[0] >= 0 else -q
    n = float(np.linalg.norm(q[1:]))
    if n < 1e-12:
        return 2.0 * q[1:]
    return 2.0 * math.atan2(n, q[0]) / n * q[1:]


def right_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """(3, 3) ``J_r^{-1}(phi)``: ``log(exp(phi) exp(d)) = phi + J_r^{-1}(phi) d + O(d^2)``."""
    th = float(np.linalg.norm(phi))
    W = skew(phi)
    if th < 1e-6:
        return np.eye(3) + 0.5 * W + W @ W / 12.0
    return np.eye(3) + 0.5 * W + (1.0 / th**2 - (1.0 + math.cos(th)) / (2.0 * th * math.sin(th))) * W @ W


def pose_jacobian_to_tangent(q: np.ndarray) -> np.ndarray:
    """(6, 7) ``d [rho, phi] / d [p, q]`` of the contract's right perturbation at ``q``.

    ``wTc <- wTc @ se3_exp([rho, phi])`` gives to first order
    ``dp = R rho`` and ``dq = q (x) [0, phi / 2]``, so
    ``rho = R^T dp`` and ``phi = 2 vec(q* (x) dq)``.
    """
    w, v = q[0], q[1:]
    J = np.zeros((6, 7))
    J[:3, :3] = q2R(q).T
    J[3:, 3] = -2.0 * v
    J[3:, 4:] = 2.0 * (w * np.eye(3) - skew(v))
    return J


def tangent_to_pose_jacobian(q: np.ndarray) -> np.ndarray:
    """(7, 6) ``d [p, q] / d [rho, phi]``, the right inverse of :func:`pose_jacobian_to_tangent`."""
    G = np.zeros((7, 6))
    G[:3, :3] = q2R(q)
    G[3:, 3:] = 0.5 * q_left(q)[:, 1:]
    return G


# ------------------------------------------------------------ parametrisations


def idp_direction(el: np.ndarray, az: np.ndarray) -> np.ndarray:
    """Unit rays ``m(el, az)`` (k, 3) of elevation/azimuth arrays (k,) rad."""
    ce, se = np.cos(el), np.sin(el)
    return np.stack([ce * np.sin(az), -se, ce * np.cos(az)], axis=-1)


def idp_direction_jac(el: np.ndarray, az: np.ndarray) -> np.ndarray:
    """``d m / d [el, az]`` (k, 3, 2)."""
    ce, se = np.cos(el), np.sin(el)
    ca, sa = np.cos(az), np.sin(az)
    J = np.zeros(np.shape(el) + (3, 2))
    J[..., 0, 0], J[..., 1, 0], J[..., 2, 0] = -se * sa, -ce, -se * ca
    J[..., 0, 1], J[..., 2, 1] = ce * ca, -ce * sa
    return J


def direction_to_idp_angles(m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``el, az`` (k,) rad of rays ``m`` (k, 3) (any length) and ``d [el, az] / d m`` (k, 2, 3)."""
    mx, my, mz = m[:, 0], m[:, 1], m[:, 2]
    r2 = mx * mx + mz * mz
    r = np.sqrt(r2)
    n2 = r2 + my * my
    el = np.arctan2(-my, r)
    az = np.arctan2(mx, mz)
    J = np.zeros((len(m), 2, 3))
    J[:, 0, 0] = my * mx / (r * n2)
    J[:, 0, 1] = -r / n2
    J[:, 0, 2] = my * mz / (r * n2)
    J[:, 1, 0] = mz / r2
    J[:, 1, 2] = -mx / r2
    return el, az, J


def _anchor_form(kinds: np.ndarray, L: np.ndarray, direction_jac: bool = False):
    """Anchor ``A`` (k, 3), direction ``C`` (k, 3), weight ``W`` (k,) of padded landmarks ``L`` (k, 7).

    With ``direction_jac``, also ``d C / d [el, az]`` (k_idp, 3, 2) of the IDP rows.
    """
    A = L[:, 0:3]
    idp = kinds == IDP
    ahp = kinds == AHP
    W = np.where(idp, L[:, 5], np.where(ahp, L[:, 6], 1.0))
    C = np.zeros_like(A)
    Jm = None
    if idp.any():
        el, az = L[idp, 3], L[idp, 4]
        ce, se, ca, sa = np.cos(el), np.sin(el), np.cos(az), np.sin(az)
        C[idp] = np.stack([ce * sa, -se, ce * ca], axis=-1)
        if direction_jac:
            Jm = np.zeros((len(el), 3, 2))
            Jm[:, 0, 0], Jm[:, 1, 0], Jm[:, 2, 0] = -se * sa, -ce, -se * ca
            Jm[:, 0, 1], Jm[:, 2, 1] = ce * ca, -ce * sa
    if ahp.any():
        C[ahp] = L[ahp, 3:6]
    return A, C, W, Jm


def to_euclidean(kinds: np.ndarray, L: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Euclidean points (k, 3) m of padded landmarks ``L`` (k, 7) and ``d p / d L`` (k, 3, 7).

    ``p = A + C / W``; meaningless for ``rho <= 0`` (a point at or beyond infinity).
    """
    A, C, W, Jm = _anchor_form(kinds, L, direction_jac=True)
    k = len(L)
    J = np.zeros((k, 3, PAD))
    J[:, :, 0:3] = np.eye(3)
    eu = kinds == EUCLIDEAN
    Wd = np.where(eu, 1.0, W)
    p = A + np.where(eu[:, None], 0.0, C / Wd[:, None])
    idp = kinds == IDP
    if idp.any():
        J[idp, :, 3:5] = Jm / W[idp, None, None]
        J[idp, :, 5] = -C[idp] / W[idp, None] ** 2
    ahp = kinds == AHP
    if ahp.any():
        J[ahp, :, 3:6] = np.eye(3) / W[ahp, None, None]
        J[ahp, :, 6] = -C[ahp] / W[ahp, None] ** 2
    return p, J


def init_landmarks(
    kind: int, K_inv: np.ndarray, p: np.ndarray, q: np.ndarray, uv_px: np.ndarray, rho0: float
):
    """Inverse observation model: landmarks from pixels ``uv_px`` (k, 2) seen at pose ``(p, q)``.

    Returns ``L`` (k, s) parameters (s = 6 IDP, 7 AHP) and the Jacobians
    ``G_pose`` (k, s, 7) w.r.t. ``[p, q]``, ``G_uv`` (k, s, 2) w.r.t. the
    pixel, ``G_rho`` (s,) w.r.t. the prior inverse distance ``rho0`` (1/m).
    """
    k = len(uv_px)
    r_c = np.c_[uv_px, np.ones(k)] @ K_inv.T  # (k, 3) rays in the camera
    R = q2R(q)
    m = r_c @ R.T  # rays in the world
    dm_dq = rot_jac_q(q, r_c)  # (k, 3, 4)
    dm_duv = np.broadcast_to(R @ K_inv[:, :2], (k, 3, 2))
    s = SIZE[kind]
    L = np.zeros((k, s))
    L[:, :3] = p
    L[:, -1] = rho0
    G_pose = np.zeros((k, s, 7))
    G_pose[:, 0:3, 0:3] = np.eye(3)
    G_uv = np.zeros((k, s, 2))
    if kind == IDP:
        el, az, Jd = direction_to_idp_angles(m)
        L[:, 3], L[:, 4] = el, az
    elif kind == AHP:
        nm = np.linalg.norm(m, axis=1)
        n = m / nm[:, None]
        L[:, 3:6] = n
        Jd = (np.eye(3) - n[:, :, None] * n[:, None, :]) / nm[:, None, None]
    else:
        raise ValueError(f"init_landmarks: kind must be IDP or AHP, got {kind!r}")
    d = Jd.shape[1]
    G_pose[:, 3 : 3 + d, 3:7] = Jd @ dm_dq
    G_uv[:, 3 : 3 + d, :] = Jd @ dm_duv
    G_rho = np.zeros(s)
    G_rho[-1] = 1.0
    return L, G_pose, G_uv, G_rho


def _dR_dq(q: np.ndarray) -> np.ndarray:
    """(3, 12): ``[dR/dw, dR/dx, dR/dy, dR/dz]`` side by side, so that for
    row vectors ``a`` (k, 3), ``a @ D`` holds ``d (R^T a) / d q_i`` in block i."""
    w, x, y, z = q
    D = np.empty((3, 12))
    # dR/dw = 2 w I + 2 [v]x
    D[:, 0:3] = 2.0 * np.array([[w, -z, y], [z, w, -x], [-y, x, w]])
    # dR/dv_j = 2 (-v_j I + e_j v^T + v e_j^T + w [e_j]x)
    D[:, 3:6] = 2.0 * np.array([[x, y, z], [y, -x, -w], [z, w, -x]])
    D[:, 6:9] = 2.0 * np.array([[-y, x, w], [x, y, z], [-w, z, -y]])
    D[:, 9:12] = 2.0 * np.array([[-z, -w, x], [w, -z, y], [x, y, z]])
    return D


def observe_landmarks(
    K: np.ndarray, p: np.ndarray, q: np.ndarray, kinds: np.ndarray, L: np.ndarray, jacobians: bool = True
):
    """Pinhole observation of padded landmarks ``L`` (k, 7) from the camera pose ``(p, q)``.

    Returns ``uv`` (k, 2) px, ``h_z`` (k,) (the depth times ``W``: positive
    means in front of the camera for ``rho > 0``), ``H_pose`` (k, 2, 7) =
    ``d uv / d [p, q]`` and ``H_lm`` (k, 2, 7) = ``d uv / d L`` (zero padding
    columns). ``uv`` is meaningless where ``h_z <= 0``. With
    ``jacobians=False`` the two Jacobians are None (RANSAC hypotheses).
    """
    A, C, W, Jm = _anchor_form(kinds, L, direction_jac=jacobians)
    R = q2R(q)
    a = W[:, None] * (A - p) + C  # world direction to the point, scaled by W
    h = a @ R  # = (R^T a) row by row
    g = h @ K.T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = g[:, :2] / g[:, 2:3]
        if not jacobians:
            return uv, g[:, 2], None, None
        # d uv / d h = (K[:2] - uv K[2]) / g_z
        J_h = (K[None, :2, :] - uv[:, :, None] * K[None, 2:3, :]) / g[:, 2, None, None]
    J_hR = J_h @ R.T  # d uv / d a  (k, 2, 3)
    k = len(L)
    H_pose = np.empty((k, 2, 7))
    H_pose[:, :, 0:3] = -W[:, None, None] * J_hR
    dh_dq = (a @ _dR_dq(q)).reshape(k, 4, 3)  # [k, i, :] = d h / d q_i
    H_pose[:, :, 3:7] = J_h @ dh_dq.transpose(0, 2, 1)
    H_lm = np.zeros((k, 2, PAD))
    H_lm[:, :, 0:3] = W[:, None, None] * J_hR
    idp = kinds == IDP
    if Jm is not None:
        H_lm[idp, :, 3:5] = J_hR[idp] @ Jm
        H_lm[idp, :, 5] = (J_hR[idp] @ (A[idp] - p)[:, :, None])[:, :, 0]
    ahp = kinds == AHP
    if ahp.any():
        H_lm[ahp, :, 3:6] = J_hR[ahp]
        H_lm[ahp, :, 6] = (J_hR[ahp] @ (A[ahp] - p)[:, :, None])[:, :, 0]
    return uv, g[:, 2], H_pose, H_lm


def project_hypotheses(
    K: np.ndarray, p: np.ndarray, q: np.ndarray, kinds: np.ndarray, L: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of the same k landmarks under m state hypotheses at once (one-point RANSAC).

    ``p`` (m, 3), ``q`` (m, 4) unit quaternions, ``kinds`` (k,), ``L`` (m, k, 7)
    padded parameters. Returns ``uv`` (m, k, 2) px and ``h_z`` (m, k) as
    :func:`observe_landmarks` would, hypothesis by hypothesis.
    """
    m, k = L.shape[:2]
    A, C, W, _ = _anchor_form(np.tile(kinds, m), L.reshape(m * k, PAD))
    a = (W[:, None] * (A - np.repeat(p, k, axis=0)) + C).reshape(m, k, 3)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    R = np.empty((m, 3, 3))
    R[:, 0, 0] = w * w + x * x - y * y - z * z
    R[:, 0, 1], R[:, 0, 2] = 2 * (x * y - w * z), 2 * (x * z + w * y)
    R[:, 1, 0], R[:, 1, 2] = 2 * (x * y + w * z), 2 * (y * z - w * x)
    R[:, 1, 1] = w * w - x * x + y * y - z * z
    R[:, 2, 0], R[:, 2, 1] = 2 * (x * z - w * y), 2 * (y * z + w * x)
    R[:, 2, 2] = w * w - x * x - y * y + z * z
    g = a @ R @ K.T  # rows: (R^T a)^T K^T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = g[:, :, :2] / g[:, :, 2:3]
    return uv, g[:, :, 2]
