"""What every data source returns: a :class:`Dataset` of frames (numpy only)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from graphslam.types import Frame


@dataclass(frozen=True, eq=False)
class Dataset:
    """A recorded or simulated run, ready to stream into a back end.

    Attributes:
        name: short name for reports ("synthetic", "victoria-park", ...).
        frames: in time order; ``frames[0]`` has no odometry and anchors the
            run with ``prior_wTb`` / ``prior_covariance``.
        prior_wTb: (3,) pose of the first frame.
        prior_covariance: (3, 3) prior on the first pose (datasets without one
            use sigma 1e-3 on each axis, as gtsam's examples do).
        landmarks_true: ground-truth landmark positions ``{id: (2,)}`` or None.
        has_timestamps: whether ``Frame.stamp_s`` holds real times; when not,
            writers use the pose id in the time column.
        source_path: file the data came from, if any.
        seed: seed that generated a simulated dataset (None for recorded data).
    """

    name: str
    frames: Sequence[Frame]
    prior_wTb: np.ndarray = field(default_factory=lambda: np.zeros(3))
    prior_covariance: np.ndarray = field(default_factory=lambda: np.eye(3) * 1e-6)
    landmarks_true: dict[int, np.ndarray] | None = None
    has_timestamps: bool = False
    source_path: str | None = None
    seed: int | None = None

    @property
    def has_ground_truth(self) -> bool:
        return len(self.frames) > 0 and all(f.wTb_true is not None for f in self.frames)

    def ground_truth(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(pose_ids (N,), wTb (N, 3))`` of the true trajectory, or None."""
        if not self.has_ground_truth:
            return None
        ids = np.array([f.pose_id for f in self.frames], dtype=np.int64)
        return ids, np.array([f.wTb_true for f in self.frames], dtype=np.float64)

    def truncated(self, max_frames: int) -> "Dataset":
        """The first ``max_frames`` frames (loop closures to later poses cannot occur)."""
        return replace(self, frames=list(self.frames[:max_frames]))
