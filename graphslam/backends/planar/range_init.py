"""Initial positions of range-only landmarks (radio beacons), from several ranges.

One range puts a landmark on a circle around the pose it was taken from; a
landmark needs ranges from at least three poses that do not lie on one line
before its position is determined (two circles meet in two mirror points, the
third picks one). :class:`RangeLandmarkInitialiser` buffers the ranges of each
landmark not yet in the graph, with the position of the pose each was taken
from (as the back end estimated it when the range arrived), and gives an initial
position once they are enough and spread enough:

- at least ``min_ranges`` ranges;
- from poses spread in both directions: the smaller principal standard
  deviation of their positions (the minor axis of their scatter) at least
  ``min_spread_m``, so the trilateration is well conditioned and the mirror
  ambiguity of nearly collinear poses is resolved by real geometry, not noise.

:func:`trilaterate` solves it in two steps: linear least squares on the
differences of the squared range equations (``|m - p_i|^2 = r_i^2`` minus their
mean, which cancels ``|m|^2``: a linear system in ``m``), then Gauss-Newton on
the range residuals ``|m - p_i| - r_i`` from that start (the linear step weighs
far ranges more; Gauss-Newton gives each range its own weight). Noise-free
ranges give the exact position.

Pure numpy; the back end (:mod:`graphslam.backends.planar.isam2`) owns one
instance and passes it everything it needs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Gauss-Newton stops when a step moves the landmark less than this, metres.
STEP_TOL_M = 1e-12
#: Gauss-Newton iteration cap (noise-free data converges in a handful).
MAX_ITERATIONS = 50


def principal_spread(positions: np.ndarray) -> float:
    """Smaller principal standard deviation of (N, 2) positions, metres (0 for N < 2)."""
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    if len(p) < 2:
        return 0.0
    s = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    return float(s[-1] / np.sqrt(len(p)))


def trilaterate(positions: np.ndarray, ranges: np.ndarray) -> np.ndarray | None:
    """(2,) point whose distances to ``positions`` (N, 2), metres, best fit ``ranges``
    (N,) in least squares; None when the positions do not determine it (N < 3 or
    all on one line)."""
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    r = np.asarray(ranges, dtype=np.float64).reshape(-1)
    if len(p) < 3 or len(r) != len(p):
        return None
    centre = p.mean(axis=0)
    q = p - centre
    # |m' - q_i|^2 = r_i^2 with m' = m - centre; minus the mean over i (mean q = 0):
    # -2 q_i . m' + |q_i|^2 - mean|q|^2 = r_i^2 - mean r^2
    qq = np.einsum("ij,ij->i", q, q)
    A = 2.0 * q
    b = qq - qq.mean() - (r * r - np.mean(r * r))
    if np.linalg.matrix_rank(A) < 2:
        return None
    m = np.linalg.lstsq(A, b, rcond=None)[0]
    for _ in range(MAX_ITERATIONS):
        d = m - q
        dist = np.linalg.norm(d, axis=1)
        if np.any(dist == 0.0):
            break
        J = d / dist[:, None]
        step = np.linalg.lstsq(J, r - dist, rcond=None)[0]
        m = m + step
        if np.linalg.norm(step) < STEP_TOL_M:
            break
    return m + centre


@dataclass
class PendingRange:
    """One buffered range: the pose it came from and that pose's position then."""

    pose_id: int
    position: np.ndarray  # (2,) metres, world frame
    range_m: float
    observation: object  # the Observation, handed back when the landmark is initialised


class RangeLandmarkInitialiser:
    """Buffers ranges of landmarks not yet initialised; initialises them (module
    docstring).

    Args:
        min_ranges: ranges needed before a trilateration is tried (>= 3).
        min_spread_m: smaller principal standard deviation the poses' positions
            must reach, metres (> 0).
    """

    def __init__(self, min_ranges: int = 5, min_spread_m: float = 2.0):
        if min_ranges < 3 or not min_spread_m > 0:
            raise ValueError("range initialisation needs min_ranges >= 3 and min_spread_m > 0")
        self.min_ranges = int(min_ranges)
        self.min_spread_m = float(min_spread_m)
        self._pending: dict[int, list[PendingRange]] = {}

    def add(self, landmark_id: int, pose_id: int, position_w: np.ndarray, observation) -> None:
        """Buffer a range observation (``observation.z[0]``, metres) of ``landmark_id``
        taken at ``pose_id``, whose position is ``position_w`` (2,), metres."""
        xy = np.asarray(position_w, dtype=np.float64).reshape(2).copy()
        self._pending.setdefault(landmark_id, []).append(
            PendingRange(int(pose_id), xy, float(observation.z[0]), observation)
        )

    def try_initialise(self, landmark_id: int) -> tuple[np.ndarray, list] | None:
        """``(position (2,), buffered observations)`` when ``landmark_id``'s ranges
        determine it (the buffer is then emptied), else None (they stay buffered)."""
        pending = self._pending.get(landmark_id, [])
        if len(pending) < self.min_ranges:
            return None
        positions = np.array([p.position for p in pending])
        if principal_spread(positions) < self.min_spread_m:
            return None
        m = trilaterate(positions, np.array([p.range_m for p in pending]))
        if m is None or not np.all(np.isfinite(m)):
            return None
        del self._pending[landmark_id]
        return m, [p.observation for p in pending]

    def pending_count(self, landmark_id: int | None = None) -> int:
        """Ranges buffered for ``landmark_id`` (all landmarks when None)."""
        if landmark_id is not None:
            return len(self._pending.get(landmark_id, ()))
        return sum(len(v) for v in self._pending.values())

    def pending_landmarks(self) -> list[int]:
        """Landmarks with ranges buffered and no position yet."""
        return sorted(self._pending)
