"""Contract for 3-D visual back ends (monocular EKF-SLAM, visual iSAM2); numpy only.

The 3-D counterpart of :mod:`slamcore.planar.backend`. A visual back end is driven
frame by frame by the visual pipeline::

    backend.initialize(frame_id0, wTc0, covariance0, K, image_size)
    backend.update(observations0)                      # first frame's new tracks
    for each later frame k:
        backend.predict(frame_id_k, odometry, covariance)  # c_{k-1} T c_k, or None
        pred = backend.predict_observations()          # -> active search ellipses
        backend.update(observations_k)                 # found + new tracks
    estimate = backend.finalize()

Observations are pixels of *tracks*: the front end gives every physical point
it follows one integer id and keeps it across frames. A back end decides
itself when a track becomes a landmark (the EKF undelayed, in inverse depth;
iSAM2 once triangulation has parallax) and may ignore tracks it does not want
(map full, too many initialisations this frame, RANSAC outlier).

Conventions: ``wTc`` (4, 4) maps camera points to world points; the camera
looks along its ``+z`` (x right, y down). Pose covariances are (6, 6) in the
order ``[rho (translation, m), phi (rotation vector, rad)]`` of a perturbation
applied on the right, ``wTc <- wTc @ se3_exp(delta)`` (in the camera frame).
Pixels are ``[u, v]`` (column, row) with pixel centres at integer coordinates.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from slamcore.errors import UnsupportedError


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
        track_ids: (K,) int64 ids of landmarks predicted in front of the camera
            and inside the image.
        uv_px: (K, 2) predicted pixels.
        S_px2: (K, 2, 2) innovation covariances (pose and landmark uncertainty
            projected, plus the pixel noise), px^2.
        max_corrections: the back end corrects at most this many landmarks per
            frame, largest ellipses first (:attr:`VisualBackend.max_corrections`);
            the front end may stop searching once it has found that many
            (paper 4.4). ``None``: every prediction is used.
    """

    track_ids: np.ndarray
    uv_px: np.ndarray
    S_px2: np.ndarray
    max_corrections: int | None = None

    def __len__(self) -> int:
        return len(self.track_ids)


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


class VisualBackend(ABC):
    """Abstract 3-D visual back end. Subclasses set :attr:`name`."""

    name: str = "visual"
    #: Whether :meth:`predict` accepts ``odometry=None`` (a motion model of its own).
    has_motion_model: bool = False
    #: Whether the front end must follow a track over frames before the back end can
    #: map it (iSAM2 triangulates once the track has parallax); False for back ends that
    #: initialise a landmark from one pixel (the monocular EKF, undelayed inverse depth).
    needs_track_history: bool = True
    #: Landmarks corrected per frame at most (largest innovation ellipses first), or
    #: None for no cap. A back end that caps puts it in its :class:`PixelPredictions`
    #: so the front end does not search for measurements that would not be used.
    max_corrections: int | None = None
    #: Whether :meth:`add_loop_closure` can use a relative-pose constraint; filters
    #: that keep no past poses close loops only by re-observing landmarks.
    supports_loop_closures: bool = False

    @abstractmethod
    def initialize(self, frame_id: int, wTc: np.ndarray, covariance: np.ndarray,
                   K: np.ndarray, image_size: tuple[int, int]) -> None:
        """Anchor the first camera pose; ``K`` (3, 3), ``image_size`` ``(W, H)``."""

    @abstractmethod
    def predict(self, frame_id: int, odometry: np.ndarray | None,
                covariance: np.ndarray | None) -> None:
        """Add frame ``frame_id``: ``odometry`` (4, 4) is ``c_{k-1} T c_k`` with
        ``covariance`` (6, 6), or ``None`` for the back end's own motion model
        (``UnsupportedError`` if it has none)."""

    @abstractmethod
    def predict_observations(self) -> PixelPredictions:
        """Predicted pixels and innovation covariances of mapped landmarks in the
        current frame (for active search)."""

    @abstractmethod
    def update(self, observations: PixelObservations) -> None:
        """Pixels measured in the current frame: known landmarks correct the
        estimate; unknown track ids are candidates for new landmarks."""

    @abstractmethod
    def estimate(self) -> VisualEstimate:
        """Current belief."""

    def finalize(self) -> VisualEstimate:
        """End of the run (e.g. a batch polish); returns the final estimate."""
        return self.estimate()

    def add_loop_closure(self, closure: PoseClosure) -> None:
        """Add a relative-pose constraint between two past frames.

        Raises:
            UnsupportedError: back ends that keep no past poses (they close
                loops by re-observing landmarks).
        """
        raise UnsupportedError(f"{self.name} cannot use relative-pose loop closures; "
                               "it closes loops by re-observing landmarks")

    def landmarks_in_frame(self, frame_id: int, track_ids: np.ndarray) -> np.ndarray:
        """(N, 3) current positions of the landmarks ``track_ids`` in camera
        ``frame_id``'s frame (metres), NaN rows for tracks not mapped. Needed
        for metric loop closures (PnP against the map around an old frame).

        Raises:
            UnsupportedError: back ends that keep no past poses.
        """
        raise UnsupportedError(f"{self.name} keeps no past poses to express its map in")
