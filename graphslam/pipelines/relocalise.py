"""Relocalisation inside a visual SLAM run (``graphslam run --relocalise``): tracking losses
counted, and a lost camera placed back in the run's own map instead of drifting on odometry.

A frame hook of :func:`graphslam.pipelines.spatial.run` (called after the back
end's update). A frame is *lost* when active search found fewer than
``min_found`` landmarks or, camera alone, PnP could not place it (the back end
coasted it: :meth:`VisualBackend.coasting`); frames before a camera-alone map
starts have no pose and count neither way. ``lost_after`` lost frames in a row open a loss. While
a loss is open, every frame is relocalised: the landmarks the back end has
mapped among the tracks observed in the last good frames before the loss
(``candidates`` of them, each with the ORB descriptors of its pixels there) are
expressed in that frame's camera (:meth:`VisualBackend.landmarks_in_frame`)
and matched to the current frame's corners; PnP RANSAC
(:func:`loopclosure.pnp.relative_pose_pnp`) gives the metric pose of the
current camera in the old one, added to the back end as a relative-pose
closure (iSAM2: a robust ``BetweenFactorPose3``). The loss closes at the first
frame placed that way, or found by active search again (counted apart).
``stats`` holds ``loss_rule`` (the rule above, in words), ``losses``, ``lost_frames``, ``relocalisations``,
``recovered_by_search`` and ``loss_lengths`` (per loss: frames from the last
good frame before it to the frame placed again; a 10-frame blackout recovered
on the first frame after it has length 11).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from frontend.orb import OrbDetector
from graphslam.pipelines.loop_closing import pnp_closure
from loopclosure.pnp import PnpConfig, relative_pose_pnp
from slamcore.config import Validated, bounded
from slamcore.errors import GraphSlamError


@dataclass(frozen=True)
class RelocaliseConfig(Validated):
    """Relocalisation in a SLAM run (config section ``[relocalise]``), module docstring.

    Attributes:
        min_found: a frame whose active search found fewer landmarks is lost.
        lost_after: lost frames in a row that open a loss.
        candidates: good frames before the loss whose tracks' landmarks the lost frame
            is matched to (those mapped by then, in the latest good frame's camera).
        min_inliers, ratio: PnP inliers to accept, and the ORB ratio test; looser than
            a loop closure's (``[loop_pnp]``): the candidates are the frames just
            before the loss, not a place recognised among all, and a run's map is
            sparse (measured: 14 ORB matches 11 frames after a 10-frame blackout).
    """

    SECTION: ClassVar[str] = "relocalise"

    min_found: int = bounded(3, min=1)
    lost_after: int = bounded(2, min=1)
    candidates: int = bounded(10, min=1)
    # EPnP needs 4 points
    min_inliers: int = bounded(10, min=4)
    ratio: float = bounded(0.9, gt=0.0, max=1.0)


@dataclass
class RunRelocaliser:
    """The frame hook (module docstring). ``K``: (3, 3) intrinsics of the run."""

    K: np.ndarray
    config: RelocaliseConfig = field(default_factory=RelocaliseConfig)
    pnp: PnpConfig = field(default_factory=PnpConfig)
    describer: OrbDetector = field(default_factory=OrbDetector)

    def __post_init__(self):
        self.pnp = dataclasses.replace(self.pnp, min_inliers=self.config.min_inliers, ratio=self.config.ratio)
        self._good: list[tuple[int, np.ndarray, np.ndarray]] = []  # (frame, track ids, descriptors)
        self._streak = 0  # lost frames in a row
        self._open: int | None = None  # frame after which recovery is counted
        self.stats: dict[str, Any] = {
            # the rule a loss is counted by (not the back end's: a camera-alone run's PnP
            # failures are its own losses, said apart; the summary named both "tracking
            # losses", 0 against 2 on KITTI 07)
            "loss_rule": (
                f"active search found fewer than {self.config.min_found} landmarks, or the "
                f"camera alone could not place the frame (coasted), in {self.config.lost_after} "
                "frames in a row"
            ),
            "losses": 0,
            "lost_frames": 0,
            "relocalisations": 0,
            "recovered_by_search": 0,
            "loss_lengths": [],
        }

    def __call__(self, k, image, tracking, backend) -> None:
        k = int(k)
        if not backend.has_pose(k):  # before a camera-alone map starts: neither lost nor good
            return
        # a camera-alone frame PnP could not place is lost, however many landmarks active
        # search found around its prediction (pass 23: the two rules disagreed, and
        # --relocalise did nothing on KITTI's camera-alone loss at frames 32-40)
        lost = tracking.n_found < self.config.min_found or backend.coasting()
        self.stats["lost_frames"] += int(lost)
        self._streak = self._streak + 1 if lost else 0
        if self._open is None and self._streak >= self.config.lost_after and self._good:
            self.stats["losses"] += 1
            self._open = k - self._streak  # the last good frame
        if self._open is None:
            if not lost:
                self._remember(k, image, tracking)
            return
        if not lost:
            self._close(k, "recovered_by_search")
            self._remember(k, image, tracking)
        elif self._relocalise(k, image, tracking, backend):
            self._close(k, "relocalisations")

    def _remember(self, k: int, image, tracking) -> None:
        obs = tracking.observations
        idx, desc = self.describer.describe(image, obs.uv_px)
        self._good.append((k, np.asarray(obs.track_ids, np.int64)[idx], desc))
        del self._good[: -self.config.candidates]

    def _close(self, k: int, how: str) -> None:
        if self._open is None:  # on_frame closes only an open loss
            raise GraphSlamError(f"relocalise: frame {k} closes no open loss")
        self.stats[how] += 1
        self.stats["loss_lengths"].append(k - self._open)
        self._open = None

    def _relocalise(self, k: int, image, tracking, backend) -> bool:
        """PnP of frame ``k``'s corners against the landmarks now mapped among the tracks
        of the last good frames (each with its latest descriptor), in the latest one's camera."""
        a = self._good[-1][0]
        ids = np.concatenate([g[1] for g in reversed(self._good)])
        desc_a = np.concatenate([g[2] for g in reversed(self._good)])
        ids, first = np.unique(ids, return_index=True)
        p_a = backend.landmarks_in_frame(a, ids)
        ok = np.all(np.isfinite(p_a), axis=1) & (p_a[:, 2] > 0)
        corners = np.asarray(tracking.corners, np.float64).reshape(-1, 2)
        idx, desc = self.describer.describe(image, corners)
        res = relative_pose_pnp(p_a[ok], desc_a[first][ok], corners[idx], desc, self.K, self.pnp)
        if res.accepted:
            backend.add_loop_closure(pnp_closure(a, k, res))
        return res.accepted
