"""Least-squares alignment of corresponding point sets, in 2-D and 3-D (numpy only).

Umeyama (1991): the rotation from the SVD of the cross-covariance of the
centred sets, with the sign correction that keeps ``det R = +1`` (never a
reflection, even for degenerate or mirrored inputs), and optionally the scale.
The 2-D metrics (:func:`graphslam.evaluation.planar.align_se2`) and the 3-D ones
(:func:`graphslam.evaluation.spatial.align_umeyama`) both fit with it.
"""

from __future__ import annotations

import math

import numpy as np

from slamcore.errors import GraphSlamError

__all__ = ["LINE_TOL", "STILL_TOL", "collinear", "principal_spreads", "rotation_about_line", "umeyama"]

#: RMS spread from the mean (metres per metre of coordinate, at least 1 m) under
#: which a point set "does not move": far below any printed precision (TUM files
#: carry 4-9 decimals), far above the float64 residue of subtracting the mean
#: (~1e-16 per metre), so a still trajectory is caught whatever its coordinates.
STILL_TOL = 1e-9
#: Positions "lie on one line" when their second principal spread is below this
#: fraction of the first: a millionth is the precision of 6 printed digits
#: (KITTI's %e), so a rotation about the line would be fitted to print noise.
LINE_TOL = 1e-6


def umeyama(
    src, dst, dim: int, with_scale: bool, who: str, min_points: int = 1
) -> tuple[float, np.ndarray, np.ndarray]:
    """``(s, R, t)`` minimising ``sum |s R src_i + t - dst_i|^2``.

    Args:
        src: (N, dim) points (the estimate), metres.
        dst: (N, dim) corresponding points (the truth), metres.
        dim: 2 or 3.
        with_scale: fit the scale ``s`` too; else ``s = 1``.
        who: the caller's name, which starts every error message.
        min_points: fewest points accepted.

    Returns:
        s: scale; R: (dim, dim) rotation with ``det R = +1``; t: (dim,) translation.

    Raises:
        GraphSlamError: other shapes, fewer than ``min_points`` points, non-finite
            or overflowing coordinates, or (with the scale) a set that does not move.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != dim or src.shape != dst.shape:
        raise GraphSlamError(f"{who}: expected two (N, {dim}) arrays, got {src.shape} and {dst.shape}")
    if src.shape[0] < min_points:
        raise GraphSlamError(f"{who}: need at least {min_points} {'point' if min_points == 1 else 'points'}")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    if not np.all(np.isfinite(cov)):  # LAPACK's SVD can loop forever on inf or NaN
        raise GraphSlamError(f"{who}: non-finite or overflowing coordinates")
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(dim)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0.0:
        S[-1, -1] = -1.0
    R = U @ S @ Vt
    s = 1.0
    if with_scale:
        var_s = float(np.mean(np.sum(xs**2, axis=1)))
        var_d = float(np.mean(np.sum(xd**2, axis=1)))
        # a still target gives s = 0: every point collapses onto it and the error reads 0
        for var, pts, what in ((var_s, src, "estimate"), (var_d, dst, "reference")):
            if math.sqrt(var) <= STILL_TOL * max(1.0, float(np.max(np.abs(pts)))):
                raise GraphSlamError(f"{who}: the {what} does not move; no Sim({dim}) scale to fit")
        s = float(np.sum(D * np.diag(S)) / var_s)
    t = mu_d - s * R @ mu_s
    return s, R, t


def principal_spreads(points: np.ndarray) -> np.ndarray:
    """RMS spread (3,) of ``points`` (k, 3) from their mean along their principal axes, largest first."""
    points = _checked_points(points)
    centred = points - points.mean(axis=0)
    return np.linalg.svd(centred, compute_uv=False) / np.sqrt(len(points))


def _checked_points(points) -> np.ndarray:
    """``points`` as a finite (k, 3) float array, k >= 1; GraphSlamError otherwise (an SVD of
    NaN raises LinAlgError, and the mean of no point is NaN)."""
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise GraphSlamError("points: need a (k, 3) array of numbers") from None
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise GraphSlamError(f"points: need a (k, 3) array with k >= 1, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise GraphSlamError("points: not finite (NaN or inf)")
    return p


def collinear(points: np.ndarray, spreads: np.ndarray | None = None) -> bool:
    """Whether ``points`` (k, 3) lie on one line (:data:`LINE_TOL`; always so for two): a
    fit on their positions leaves the rotation about that line free. ``spreads``: their
    :func:`principal_spreads`, when the caller has them."""
    s = principal_spreads(points) if spreads is None else spreads
    return bool(s[1] <= LINE_TOL * s[0])


def rotation_about_line(ref: np.ndarray, est: np.ndarray) -> np.ndarray:
    """(4, 4) rotation about the reference's line (through its centroid) that best
    aligns the estimate's orientations with the reference's (both (k, 4, 4), the
    estimate already fitted on positions): positions on a line leave that angle
    free, and Umeyama's arbitrary choice reported up to 180 deg of rotation error
    for a 2-pose or straight trajectory. Closed form: with R(a) = I + sin a K +
    (1 - cos a) K^2 about the unit axis u (K = [u]x), sum_i tr(R(a) Q_i P_i^T) is
    largest at a = atan2(tr(K M), -tr(K^2 M)), M = sum_i Q_i P_i^T."""
    points = ref[:, :3, 3]
    centre = points.mean(axis=0)
    u = np.linalg.svd(points - centre)[2][0]
    K = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    M = np.einsum("kij,klj->il", est[:, :3, :3], ref[:, :3, :3])
    a = np.arctan2(np.trace(K @ M), -np.trace(K @ K @ M))
    R = np.eye(3) + np.sin(a) * K + (1.0 - np.cos(a)) * (K @ K)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, centre - R @ centre
    return T
