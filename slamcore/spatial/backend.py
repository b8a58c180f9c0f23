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

import numpy as np

from slamcore.errors import UnsupportedError
from slamcore.spatial.records import PixelObservations, PixelPredictions, PoseClosure, VisualEstimate


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
    #: Whether :meth:`correct_and_repredict` works: the sequential active search
    #: (``[active_search] order = "sequential"``, RT-SLAM) corrects one landmark at a time.
    supports_sequential_search: bool = False

    @abstractmethod
    def initialize(
        self,
        frame_id: int,
        wTc: np.ndarray,
        covariance: np.ndarray,
        K: np.ndarray,
        image_size: tuple[int, int],
    ) -> None:
        """Anchor the first camera pose; ``K`` (3, 3), ``image_size`` ``(W, H)``."""

    @abstractmethod
    def predict(self, frame_id: int, odometry: np.ndarray | None, covariance: np.ndarray | None) -> None:
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
        raise UnsupportedError(
            f"{self.name} cannot use relative-pose loop closures; it closes loops by re-observing landmarks"
        )

    def correct_and_repredict(
        self, track_ids: np.ndarray, uv_px: np.ndarray, pending_ids: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Sequential active search, between :meth:`predict_observations` and
        :meth:`update`: correct now with the landmarks ``track_ids`` (M,) measured
        at ``uv_px`` (M, 2), and return the predicted pixels (P, 2) and innovation
        covariances (P, 2, 2) of ``pending_ids`` (P,) at the corrected state.
        :meth:`update` then skips these tracks (already used or rejected).

        Raises:
            UnsupportedError: back ends that do not correct one landmark at a time.
        """
        raise UnsupportedError(
            f"{self.name} cannot correct one landmark at a time (sequential active search)"
        )

    def coasting(self) -> bool:
        """Whether the latest frame kept its motion model's prediction because the images
        could not place it (a camera-alone tracking loss); False for a back end whose
        frames are always measured or carried by odometry."""
        return False

    def has_pose(self, frame_id: int) -> bool:
        """Whether frame ``frame_id`` has a pose in the estimate (a camera-alone back end
        places none before its map starts). This reads the whole estimate; a back end
        that keeps its frames apart answers from them."""
        return int(frame_id) in set(np.asarray(self.estimate().frame_ids).tolist())

    def landmarks_in_frame(self, frame_id: int, track_ids: np.ndarray) -> np.ndarray:
        """(N, 3) current positions of the landmarks ``track_ids`` in camera
        ``frame_id``'s frame (metres), NaN rows for tracks not mapped. Needed
        for metric loop closures (PnP against the map around an old frame).

        Raises:
            UnsupportedError: back ends that keep no past poses.
        """
        raise UnsupportedError(f"{self.name} keeps no past poses to express its map in")
