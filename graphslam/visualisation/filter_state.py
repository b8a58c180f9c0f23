"""What the course's filter demos show, in numpy: the EKF's correlation image and
FastSLAM's particle cloud, ESS and resampling events (issue 19 item 5).

No rerun here: :class:`graphslam.visualisation.planar.PlanarLog` logs what these
functions compute, so the arithmetic can be tested without a recording.

The EKF image is the covariance as correlation coefficients,
``rho_ij = P_ij / sqrt(P_ii P_jj)``, one row and column per *entity*: the pose
(its 3 state rows) then each landmark (2 rows) in state order, which is the
order landmarks entered the map. Each cell is the largest ``|rho|`` between the
two entities' coordinates, so the image is ``(1 + M) x (1 + M)`` in ``[0, 1]``
with ones on the diagonal. Beyond :data:`MAX_IMAGE_SIDE` entities, blocks of
consecutive entities are merged by the same maximum (the image stays small in
the recording and a strong correlation is never averaged away).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from filters.ekf_slam import EkfSlam
from filters.fastslam import FastSlam

#: Largest side of the logged correlation image, cells (4 bytes each).
MAX_IMAGE_SIDE = 256


def correlation_matrix(P: np.ndarray) -> np.ndarray:
    """(n, n) correlation coefficients of covariance ``P``, clipped to [-1, 1].

    Rows and columns of a zero variance (an exactly known coordinate) are 0.
    """
    sigma = np.sqrt(np.clip(np.diag(P), 0.0, None))
    inv = np.divide(1.0, sigma, out=np.zeros_like(sigma), where=sigma > 0)
    return np.clip(P * inv[:, None] * inv[None, :], -1.0, 1.0)


def mean_abs_correlation(rho: np.ndarray) -> float:
    """Mean ``|rho_ij|`` over the off-diagonal entries (0 for a 1 x 1 matrix)."""
    n = len(rho)
    if n < 2:
        return 0.0
    a = np.abs(rho)
    return float((a.sum() - np.trace(a)) / (n * n - n))


def _block_max(a: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Maximum of ``a`` over the blocks whose rows and columns begin at ``starts``."""
    return np.maximum.reduceat(np.maximum.reduceat(a, starts, axis=0), starts, axis=1)


def entity_image(rho: np.ndarray, pose_dim: int = 3, landmark_dim: int = 2,
                 max_side: int = MAX_IMAGE_SIDE) -> np.ndarray:
    """(k, k) float32 image of the largest ``|rho|`` between entities (module docstring).

    Args:
        rho: (n, n) correlation matrix of the state ``[pose, m1, m2, ...]``.
        max_side: at most this many rows; above it, ``ceil(entities / max_side)``
            consecutive entities share a cell.
    """
    n = len(rho)
    if n < pose_dim or (n - pose_dim) % landmark_dim:
        raise ValueError(f"state of size {n} is not {pose_dim} + {landmark_dim} x landmarks")
    starts = np.concatenate([[0], np.arange(pose_dim, n, landmark_dim)])
    image = _block_max(np.abs(rho), starts)
    block = -(-len(image) // max_side)
    if block > 1:
        image = _block_max(image, np.arange(0, len(image), block))
    return image.astype(np.float32)


@dataclass(frozen=True)
class CorrelationSnapshot:
    """One EKF step: its entity image and the mean ``|rho|`` of the full matrix."""

    image: np.ndarray  # (k, k) float32 in [0, 1]
    mean_abs: float
    landmarks: int


@dataclass(frozen=True)
class ParticleSnapshot:
    """One FastSLAM step: the cloud, its ESS before resampling and the event."""

    poses: np.ndarray  # (N, 3)
    weights: np.ndarray  # (N,)
    ess: float
    resampled: bool
    resample_count: int


def correlation_snapshot(ekf: EkfSlam, max_side: int = MAX_IMAGE_SIDE) -> CorrelationSnapshot:
    """The EKF's correlation image now. O(n^2): the cost of one observation update."""
    rho = correlation_matrix(ekf.state_covariance())
    return CorrelationSnapshot(entity_image(rho, max_side=max_side), mean_abs_correlation(rho),
                               ekf.num_landmarks)


def particle_snapshot(fs: FastSlam) -> ParticleSnapshot:
    """FastSLAM's particles now (O(N) copies)."""
    return ParticleSnapshot(fs.particle_poses, fs.weights, fs.step_ess(),
                            fs.resampled_this_step(), fs.resample_count)


def log_filter_state(log, backend: str, k: int, backend_obj, every: int,
                     color_index: int = 0) -> None:
    """Log step ``k``'s filter demos of ``backend_obj`` into ``log`` (a
    :class:`graphslam.visualisation.planar.PlanarLog`); nothing for back ends
    without any (iSAM2, the localisers).

    FastSLAM: the cloud, ESS and any resampling event every step (O(N)). EKF:
    the correlation image and mean ``|rho|`` every ``every`` steps (O(n^2)).
    """
    if isinstance(backend_obj, FastSlam):
        log.log_particles(backend, particle_snapshot(backend_obj), color_index)
    elif isinstance(backend_obj, EkfSlam) and k % every == 0:
        log.log_correlation(backend, correlation_snapshot(backend_obj))
