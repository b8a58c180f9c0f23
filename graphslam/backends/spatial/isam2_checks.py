"""Input checks of the visual iSAM2 back end: covariances, intrinsics, transforms, pixels.

Each raises :class:`slamcore.errors.MeasurementError` naming the input before
anything is added to the graph, so a refused input leaves the back end as it
was.
"""

from __future__ import annotations

import numpy as np

from slamcore.errors import MeasurementError
from slamcore.spatial.records import PixelObservations


def checked_covariance(covariance, what: str, allow_singular: bool = False) -> np.ndarray:
    """(6, 6) finite symmetric covariance, positive definite (or semi-definite)."""
    if covariance is None:
        raise MeasurementError(f"isam2 (visual): {what} needs a (6, 6) covariance")
    cov = np.asarray(covariance, dtype=np.float64)
    if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
        raise MeasurementError(f"isam2 (visual): {what} covariance must be a finite (6, 6)")
    if not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-15):
        raise MeasurementError(f"isam2 (visual): {what} covariance is not symmetric")
    cov = 0.5 * (cov + cov.T)
    lowest = float(np.linalg.eigvalsh(cov)[0])
    if lowest < 0 and not (allow_singular and lowest > -1e-12 * max(1.0, float(np.trace(cov)))):
        raise MeasurementError(f"isam2 (visual): {what} covariance is not positive semi-definite")
    if lowest <= 0 and not allow_singular:
        raise MeasurementError(f"isam2 (visual): {what} covariance is not positive definite")
    return cov


def checked_intrinsics(K) -> np.ndarray:
    """Intrinsic matrix (3, 3) in pixels, finite with ``fx, fy > 0``, as float64."""
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise MeasurementError(f"isam2 (visual): bad intrinsic matrix K {K.tolist()}")
    return K


def checked_transform(T, what: str) -> np.ndarray:
    """A finite (4, 4) transform as float64; ``what`` names it in the error."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise MeasurementError(f"isam2 (visual): {what} is not a finite (4, 4)")
    return T


def checked_pixels(observations: PixelObservations) -> tuple[np.ndarray, np.ndarray, float]:
    """Track ids (k,) int64, pixels (k, 2) float64 and ``sigma_px`` (> 0) of one frame."""
    ids = np.asarray(observations.track_ids, dtype=np.int64).reshape(-1)
    uv = np.asarray(observations.uv_px, dtype=np.float64).reshape(-1, 2)
    sigma = float(observations.sigma_px)
    if len(ids) != len(uv):
        raise MeasurementError("isam2 (visual): track_ids and uv_px differ in length")
    if not (np.all(np.isfinite(uv)) and np.isfinite(sigma) and sigma > 0):
        raise MeasurementError("isam2 (visual): pixels must be finite and sigma_px > 0")
    return ids, uv, sigma
