"""What the course's filter demos show, in numpy: the EKF's correlation image and
FastSLAM's particle cloud, ESS and resampling events (issue 19 item 5).

No rerun here: :class:`graphslam.visualisation.planar.PlanarLog` logs what these
functions compute, so the arithmetic can be tested without a recording.

The EKF image is the covariance as correlation coefficients,
``rho_ij = P_ij / sqrt(P_ii P_jj)``, one row and column per *entity*: the pose
(its 3 state rows) then each landmark (2 rows) in state order, which is the
order landmarks entered the map, and, with several robots, the other robots'
poses last. Each cell is the largest ``|rho|`` between the
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
    rho = P * inv[:, None]
    rho *= inv[None, :]
    return np.clip(rho, -1.0, 1.0, out=rho)


def mean_off_diagonal(a: np.ndarray) -> float:
    """Mean of the off-diagonal entries of square ``a`` (0 for a 1 x 1 matrix):
    with ``a = |rho|``, the mean absolute correlation."""
    n = len(a)
    if n < 2:
        return 0.0
    return float((a.sum() - np.trace(a)) / (n * n - n))


def _block_max(a: np.ndarray, block: int) -> np.ndarray:
    """Maximum of square ``a`` >= 0 over ``block x block`` tiles (zero-padded at the end)."""
    n = len(a)
    k = -(-n // block)
    padded = np.zeros((k * block, k * block), dtype=a.dtype)
    padded[:n, :n] = a
    # one axis at a time: numpy's multi-axis max over a 4-D view is 10x slower
    rows = padded.reshape(k, block, k * block).max(axis=1)
    return rows.reshape(k, k, block).max(axis=2)


def entity_image(
    abs_rho: np.ndarray,
    pose_dim: int = 3,
    landmark_dim: int = 2,
    max_side: int = MAX_IMAGE_SIDE,
    parked_poses: int = 0,
) -> np.ndarray:
    """(k, k) float32 image of the largest ``|rho|`` between entities (module docstring).

    Args:
        abs_rho: (n, n) ``|correlation|`` of the state ``[pose, m1, m2, ...]``, or
            ``[pose, m1, ..., mM, parked_1, ..., parked_R]`` with ``parked_poses = R``
            other robots' poses after the landmarks (the EKF with several robots):
            they are the image's last entities.
        max_side: at most this many rows; above it, ``ceil(entities / max_side)``
            consecutive entities share a cell.
    """
    n = len(abs_rho)
    rest = n - pose_dim * (1 + parked_poses)
    if rest < 0 or rest % landmark_dim:
        what = f"{pose_dim} + {landmark_dim} x landmarks" + (
            f" + {parked_poses} x {pose_dim}" if parked_poses else ""
        )
        raise ValueError(f"state of size {n} is not {what}")
    m = rest // landmark_dim
    end = pose_dim + landmark_dim * m
    starts = np.r_[0, pose_dim + landmark_dim * np.arange(m), end + pose_dim * np.arange(parked_poses)]
    # the largest |rho| over each entity's rows, then over each entity's columns
    rows = np.maximum.reduceat(abs_rho, starts.astype(np.intp), axis=0)
    image = np.maximum.reduceat(rows, starts.astype(np.intp), axis=1).astype(np.float32)
    block = -(-len(image) // max_side)
    return _block_max(image, block) if block > 1 else image


@dataclass(frozen=True)
class CorrelationSnapshot:
    """One EKF step: its entity image and the mean ``|rho|`` of the full matrix."""

    image: np.ndarray  # (k, k) float32 in [0, 1]
    mean_abs: float
    landmarks: int


@dataclass(frozen=True)
class ParticleSeries:
    """FastSLAM's state over consecutive logged steps, sent to Rerun in one batch."""

    steps: np.ndarray  # (T,) int64
    stamps_s: np.ndarray | None  # (T,) seconds, when every step has a stamp
    positions: np.ndarray  # (T, N, 2) particle positions
    ess: np.ndarray  # (T,) ESS before each step's resampling
    events: list[tuple[int, str]]  # (step, text) of each resampling


def correlation_snapshot(ekf: EkfSlam, max_side: int = MAX_IMAGE_SIDE) -> CorrelationSnapshot:
    """The EKF's correlation image now. O(n^2): the cost of one observation update."""
    abs_rho = np.abs(correlation_matrix(ekf.state_covariance()))
    return CorrelationSnapshot(
        entity_image(abs_rho, max_side=max_side, parked_poses=ekf.num_parked_poses),
        mean_off_diagonal(abs_rho),
        ekf.num_landmarks,
    )


class FilterStateLogger:
    """Logs one back end's filter demos into a
    :class:`graphslam.visualisation.planar.PlanarLog`; nothing for back ends without
    any (iSAM2, the localisers).

    EKF: the correlation image and mean ``|rho|`` every ``every`` steps (O(n^2)
    each). FastSLAM: the cloud, ESS and resampling events of every step, kept
    here and sent every :data:`FLUSH_STEPS` steps and at :meth:`flush` as columns
    (one Rerun call per entity instead of three per step, which cost about as
    much as the filter's own step).
    """

    #: Steps of FastSLAM state held before they are sent (a live viewer lags this much).
    FLUSH_STEPS = 100

    def __init__(self, log, backend: str, every: int, color_index: int = 0):
        self.log, self.backend, self.every, self.color_index = log, backend, every, color_index
        self._rows: list[tuple[int, float | None, np.ndarray, float]] = []
        self._events: list[tuple[int, str]] = []
        self._sent = False  # the cloud's static style goes with the first batch

    def __call__(self, k: int, stamp_s: float | None, backend_obj) -> None:
        if isinstance(backend_obj, FastSlam):
            self._add_particles(k, stamp_s, backend_obj)
        elif isinstance(backend_obj, EkfSlam) and k % self.every == 0:
            self.log.log_correlation(self.backend, correlation_snapshot(backend_obj))

    def _add_particles(self, k: int, stamp_s: float | None, fs: FastSlam) -> None:
        ess = fs.step_ess()
        self._rows.append((k, stamp_s, fs.particle_poses[:, :2], ess))
        if fs.resampled_this_step():
            self._events.append((k, f"resampling {fs.resample_count}: ESS {ess:.1f} of {fs.n_particles}"))
        if len(self._rows) >= self.FLUSH_STEPS:
            self.flush()

    def final(self, backend_obj) -> None:
        """At the run's last step: the EKF's correlation image as the run ends (the
        last snapshot was up to ``every - 1`` steps before it, or only step 0)."""
        if isinstance(backend_obj, EkfSlam):
            self.log.log_correlation(self.backend, correlation_snapshot(backend_obj))

    def flush(self) -> None:
        """Send the FastSLAM steps held so far (none: nothing)."""
        if not self._rows:
            return
        steps, stamps, positions, ess = zip(*self._rows, strict=True)
        timed = all(t is not None for t in stamps)
        self.log.send_particles(
            self.backend,
            ParticleSeries(
                np.array(steps, dtype=np.int64),
                np.array(stamps, dtype=np.float64) if timed else None,
                np.stack(positions),
                np.array(ess),
                self._events,
            ),
            self.color_index,
            style=not self._sent,
        )
        self._rows, self._events, self._sent = [], [], True
