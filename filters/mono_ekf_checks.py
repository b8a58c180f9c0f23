"""Input checks of the monocular EKF: settings' scalars, poses, covariances, camera, pixels.

Every check raises before the filter's state is touched, so a bad frame
leaves the filter as it was. Errors are :class:`slamcore.errors.MeasurementError`
(the settings are checked apart, by :func:`slamcore.config.validate` in
:mod:`filters.mono_ekf_config`).
"""

from __future__ import annotations

import math

import numpy as np

from slamcore.errors import MeasurementError
from slamcore.spatial.records import PixelObservations


def is_int(v) -> bool:
    """A Python or numpy integer, not a bool."""
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def is_num(v) -> bool:
    """A finite Python or numpy number, not a bool."""
    return (
        isinstance(v, (int, float, np.floating, np.integer))
        and not isinstance(v, bool)
        and math.isfinite(float(v))
    )


def is_rotation(R: np.ndarray) -> bool:
    """Orthonormal with determinant +1, to 1e-6."""
    return bool(np.abs(R.T @ R - np.eye(3)).max() < 1e-6 and np.linalg.det(R) > 0)


#: Most negative eigenvalue of a covariance taken as zero, relative to its largest
#: entry: float64 rounding of a matrix built from products, far above 1e-16, far below
#: any real negative variance (one made by hand, or a correlation above 1).
PSD_RTOL = 1e-9


def check_covariance(C: np.ndarray, what: str) -> None:
    """``C`` must be a finite, symmetric, positive semi-definite (6, 6): an indefinite one
    (a correlation above 1) made the state covariance indefinite and a later update
    failed in numpy's Cholesky."""
    if C.shape != (6, 6) or not np.all(np.isfinite(C)):
        raise MeasurementError(f"mono_ekf: {what} must be a finite (6, 6), got shape {C.shape}")
    scale = float(np.abs(C).max())
    if np.abs(C - C.T).max() > 1e-12 + 1e-9 * scale or np.any(np.diag(C) < 0):
        raise MeasurementError(f"mono_ekf: {what} must be symmetric with a non-negative diagonal")
    lowest = float(np.linalg.eigvalsh(0.5 * (C + C.T))[0])
    if lowest < -PSD_RTOL * max(scale, 1e-300):
        raise MeasurementError(
            f"mono_ekf: {what} must be positive semi-definite, its smallest eigenvalue is {lowest:.3g}"
        )


def check_initial_pose(wTc: np.ndarray, covariance: np.ndarray) -> None:
    """A finite rigid (4, 4) ``wTc`` and its (6, 6) covariance (contract's convention)."""
    if wTc.shape != (4, 4) or not np.all(np.isfinite(wTc)):
        raise MeasurementError(f"mono_ekf: initial wTc must be a finite (4, 4), got {wTc.shape}")
    if not is_rotation(wTc[:3, :3]):
        raise MeasurementError("mono_ekf: initial wTc rotation is not orthonormal")
    check_covariance(covariance, "initial pose covariance")


def check_camera(K: np.ndarray, image_size) -> tuple[int, int]:
    """Intrinsics ``K`` (3, 3) in pixels and ``image_size`` ``(W, H)`` in pixels; returns ``(W, H)``."""
    if (
        K.shape != (3, 3)
        or not np.all(np.isfinite(K))
        or K[0, 0] <= 0
        or K[1, 1] <= 0
        or not np.allclose(K[2], [0, 0, 1])
    ):
        raise MeasurementError("mono_ekf: K must be a finite (3, 3) with fx, fy > 0 and last row [0 0 1]")
    W, H = image_size
    if not (is_int(W) and is_int(H) and W > 0 and H > 0):
        raise MeasurementError(f"mono_ekf: image_size must be two positive ints, got {image_size!r}")
    return int(W), int(H)


def check_odometry(odometry, covariance) -> tuple[np.ndarray, np.ndarray]:
    """``c_{k-1} T c_k`` (4, 4) and its (6, 6) covariance as float64 arrays."""
    T = np.asarray(odometry, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)) or not is_rotation(T[:3, :3]):
        raise MeasurementError("mono_ekf: odometry must be a finite rigid (4, 4) transform")
    if covariance is None:
        raise MeasurementError("mono_ekf: odometry needs its (6, 6) covariance")
    Q = np.asarray(covariance, dtype=np.float64)
    check_covariance(Q, "odometry covariance")
    return T, Q


def check_observations(obs: PixelObservations) -> tuple[np.ndarray, np.ndarray, float]:
    """Track ids (k,) int64, pixels (k, 2) float64 and ``sigma_px`` of one frame."""
    ids = np.asarray(obs.track_ids)
    uv = np.asarray(obs.uv_px, dtype=np.float64)
    if ids.ndim != 1 or (len(ids) and not np.issubdtype(ids.dtype, np.integer)):
        raise MeasurementError(
            f"mono_ekf: track_ids must be a 1-D integer array, got {ids.dtype} {ids.shape}"
        )
    if uv.shape != (len(ids), 2):
        raise MeasurementError(f"mono_ekf: uv_px must be ({len(ids)}, 2), got {uv.shape}")
    if not np.all(np.isfinite(uv)):
        raise MeasurementError("mono_ekf: non-finite pixel in the observations")
    if len(np.unique(ids)) != len(ids):
        raise MeasurementError("mono_ekf: duplicate track ids in one frame")
    s = obs.sigma_px
    if not is_num(s) or s <= 0:
        raise MeasurementError(f"mono_ekf: sigma_px must be a positive finite number, got {s!r}")
    return ids.astype(np.int64), uv, float(s)
