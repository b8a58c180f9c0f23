"""Innovation covariances of the pixels visual iSAM2 predicts, for active search.

For a landmark ``l`` seen from the current pose ``x``, ``uv = project(x, l)``
and ``S = J Sigma J^T + sigma_px^2 I`` with ``J = [Jx, Jl]`` (gtsam's
``PinholeCameraCal3_S2.project`` derivatives) and ``Sigma`` the joint marginal
of ``(x, l)``. :class:`~graphslam.backends.spatial.isam2_config.VisualIsam2Config`'s
``prediction_covariance`` chooses how ``Sigma`` is obtained:

- ``"joint"``: the exact joint marginal (one ``jointMarginalCovariance`` call);
- ``"bound"``: ``S <= 2 (Jx Sxx Jx^T + Jl Sll Jl^T) + sigma_px^2 I``, from the
  pose's and each landmark's own marginal, no cross term. For any vectors
  ``a = Jx dx`` and ``b = Jl dl``, ``(a + b)(a + b)^T <= 2 (a a^T + b b^T)``
  (the difference is ``(a - b)(a - b)^T >= 0``); taking expectations gives the
  bound, so the 3-sigma ellipse of the bound contains the exact one. It is not
  within ``sqrt(2)`` of it: the current pose is localised from the landmarks
  in view, their errors are correlated and cancel in the projection, which the
  exact ``S`` sees and the blocks do not (tests/test_isam2_visual.py measures
  areas up to several times the exact one). A landmark's marginal only
  shrinks as factors are added (at a fixed linearisation point), so one read
  some frames ago still bounds today's: :class:`LandmarkCovariances` keeps them
  for ``landmark_covariance_max_age`` updates, and the bound holds up to
  relinearisation;
- ``"marginal"``: the same blocks without the factor 2 (not a bound: the cross
  term may add or remove).
"""

from __future__ import annotations

from typing import Callable

import gtsam
import numpy as np

#: Factor on the block-diagonal terms that makes the ``"bound"`` an upper bound.
BOUND_FACTOR = 2.0


def project_with_jacobians(camera: gtsam.PinholeCameraCal3_S2, points: np.ndarray):
    """``(uv (n, 2), Jx (n, 2, 6), Jl (n, 2, 3))``: gtsam's projections of ``points``
    and their derivatives in the pose (gtsam tangent order) and the point."""
    n = len(points)
    uv, Jx, Jl = np.empty((n, 2)), np.empty((n, 2, 6)), np.empty((n, 2, 3))
    for i in range(n):
        d_pose = np.zeros((2, 6), order="F")
        d_point = np.zeros((2, 3), order="F")
        uv[i] = camera.project(points[i], d_pose, d_point)
        Jx[i], Jl[i] = d_pose, d_point
    return uv, Jx, Jl


def joint_innovation(Jx: np.ndarray, Jl: np.ndarray, cov_x: np.ndarray, cov_xl: np.ndarray,
                     cov_l: np.ndarray) -> np.ndarray:
    """(n, 2, 2) ``J Sigma J^T`` with the exact blocks: ``cov_x`` (6, 6), ``cov_xl``
    (n, 6, 3) pose-landmark cross-covariances, ``cov_l`` (n, 3, 3)."""
    cross = Jx @ cov_xl @ Jl.transpose(0, 2, 1)
    S = Jx @ cov_x @ Jx.transpose(0, 2, 1) + cross + cross.transpose(0, 2, 1) \
        + Jl @ cov_l @ Jl.transpose(0, 2, 1)
    return 0.5 * (S + S.transpose(0, 2, 1))


def block_innovation(Jx: np.ndarray, Jl: np.ndarray, cov_x: np.ndarray, cov_l: np.ndarray,
                     factor: float) -> np.ndarray:
    """(n, 2, 2) ``factor (Jx Sxx Jx^T + Jl Sll Jl^T)``: the cross term dropped
    (``factor = BOUND_FACTOR``: an upper bound of ``J Sigma J^T``)."""
    S = Jx @ cov_x @ Jx.transpose(0, 2, 1) + Jl @ cov_l @ Jl.transpose(0, 2, 1)
    return factor * 0.5 * (S + S.transpose(0, 2, 1))


class LandmarkCovariances:
    """Each landmark's marginal covariance (3, 3), kept up to ``max_age`` updates
    after it was read (0: read again at every update)."""

    def __init__(self, max_age: int):
        self.max_age = max_age
        self._cov: dict[int, tuple[int, np.ndarray]] = {}  # key -> (update read at, cov)
        self.reads = 0

    def get(self, keys: list[int], now: int, read: Callable[[int], np.ndarray]) -> np.ndarray:
        """(n, 3, 3) covariances of ``keys`` at update count ``now``; stale ones
        are read again with ``read(key)``."""
        out = np.empty((len(keys), 3, 3))
        for i, key in enumerate(keys):
            kept = self._cov.get(key)
            if kept is None or now - kept[0] > self.max_age:
                kept = self._cov[key] = (now, np.asarray(read(key), dtype=np.float64))
                self.reads += 1
            out[i] = kept[1]
        return out

    def clear(self) -> None:
        self._cov.clear()
