"""Records the 3-D visual stages hand each other (numpy only).

Conventions as in :mod:`slamcore.spatial.backend`: ``wTc`` (4, 4) maps camera
points to world points; pose covariances are (6, 6) ``[rho, phi]`` of a
perturbation on the right; pixels are ``[u, v]`` with pixel centres at integer
coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, eq=False)
class PixelObservations:
    """Pixels measured in one frame.

    Attributes:
        track_ids: (M,) int64 front-end track ids (unique within the frame).
        uv_px: (M, 2) float64 measured pixels.
        sigma_px: standard deviation of each pixel coordinate.
        unsearched_ids: (U,) int64 ids of predicted landmarks the front end did not
            look for because its per-frame search budget was spent
            (:attr:`PixelPredictions.max_corrections`): no evidence either way, so
            not a miss. Empty by default.
    """

    track_ids: np.ndarray
    uv_px: np.ndarray
    sigma_px: float = 1.0
    unsearched_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __len__(self) -> int:
        return len(self.track_ids)


@dataclass(frozen=True, eq=False)
class PixelPredictions:
    """Where the back end expects its landmarks in the current frame.

    Attributes:
        track_ids: (N,) int64 ids of landmarks predicted in front of the camera
            and inside the image.
        uv_px: (N, 2) predicted pixels.
        S_px2: (N, 2, 2) innovation covariances (pose and landmark uncertainty
            projected, plus the pixel noise), px^2.
        max_corrections: the back end corrects at most this many landmarks per
            frame, largest ellipses first (:attr:`VisualBackend.max_corrections`);
            the front end may stop searching once it has found that many
            (paper 4.4). ``None``: every prediction is used.
        wTc: (4, 4) predicted pose of the current camera, the one ``uv_px`` was
            projected from, or None. A front end that predicts appearance
            (RT-SLAM) warps a landmark's patch by the view change between the
            camera it was cut in and this one; it also remembers this pose for
            the patches it cuts in this frame. Given even when ``track_ids`` is
            empty.
        K: (3, 3) intrinsic matrix the pixels were predicted with, or None.
        landmarks_w: (N, 3) estimated world positions of the predicted
            landmarks, metres, rows in ``track_ids`` order, or None; a row that
            is not finite has no Euclidean position (inverse depth ``rho <= 0``:
            at infinity).
    """

    track_ids: np.ndarray
    uv_px: np.ndarray
    S_px2: np.ndarray
    max_corrections: int | None = None
    wTc: np.ndarray | None = None
    K: np.ndarray | None = None
    landmarks_w: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.track_ids)

    @classmethod
    def empty(
        cls, wTc: np.ndarray | None = None, K: np.ndarray | None = None, max_corrections: int | None = None
    ) -> PixelPredictions:
        """No landmark predicted, from the camera ``wTc`` (4, 4) with ``K`` (3, 3) if known."""
        return cls(
            np.zeros(0, np.int64),
            np.zeros((0, 2)),
            np.zeros((0, 2, 2)),
            max_corrections,
            wTc=wTc,
            K=K,
            landmarks_w=None if wTc is None else np.zeros((0, 3)),
        )


@dataclass(frozen=True, eq=False)
class VisualEstimate:
    """Belief of a visual back end.

    Attributes:
        frame_ids: (N,) int64 frame ids in the order they were added.
        wTc: (N, 4, 4) camera poses (only the current one for a filter that
            keeps no past poses: then the back end returns the poses it had
            when each frame was current).
        landmark_ids: (L,) int64 track ids of mapped landmarks.
        landmarks_w: (L, 3) Euclidean positions in the world frame, metres.
        current_covariance: (6, 6) covariance of the latest pose, or None.
        stats: counters a report may show (e.g. ``{"reparametrised": 12}``).
    """

    frame_ids: np.ndarray
    wTc: np.ndarray
    landmark_ids: np.ndarray
    landmarks_w: np.ndarray
    current_covariance: np.ndarray | None = None
    stats: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class PoseClosure:
    """A verified loop closure between two frames, with a metric relative pose.

    Attributes:
        frame_a: the earlier frame (the match); frame_b: the later one (the query).
        aTb: (4, 4) ``c_a T c_b`` measured, metres.
        covariance: (6, 6) of ``aTb`` in the contract order ``[rho, phi]``
            (perturbation on the right, in camera ``b``).
    """

    frame_a: int
    frame_b: int
    aTb: np.ndarray
    covariance: np.ndarray
