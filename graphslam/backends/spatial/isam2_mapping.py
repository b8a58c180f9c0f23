"""How the visual iSAM2 back end maps a track: buffered until it has parallax,
triangulated, checked, then handed back to be added with a factor for each of its pixels.

:class:`TrackMapper` is a part of
:class:`graphslam.backends.spatial.isam2.VisualIsam2Backend` that owns the tracks not
yet in the map: those waiting for parallax, those that qualified and wait for a
frame's budget, those rejected for good, and the counters of what it dropped. It is
its own part because that bookkeeping is private to delayed initialisation: the back
end hands it the pixels of unmapped tracks and the current poses and camera, and gets
back the tracks to map; the geometry is :mod:`.landmark_init`'s.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gtsam
import numpy as np

from graphslam.backends.spatial.isam2_config import VisualIsam2Config
from graphslam.backends.spatial.landmark_init import Track, consistent, triangulate

__all__ = ["TrackMapper"]


class TrackMapper:
    """Delayed landmark initialisation of the visual iSAM2 back end.

    Attributes:
        tracks: track id -> :class:`Track` waiting for parallax (or for a budget).
        rejected: track ids whose triangulation failed or whose landmark was
            dropped: their pixels are ignored from then on.
        counts: ``rejected_triangulations``, ``dropped_tracks`` (timed out) and
            ``ignored_pixels`` (of a rejected track, or a track's second pixel in a
            frame), in the back end's ``stats()``.
    """

    def __init__(self, config: VisualIsam2Config) -> None:
        self.config = config
        self.tracks: dict[int, Track] = {}
        self.rejected: set[int] = set()
        self.counts = {"rejected_triangulations": 0, "dropped_tracks": 0, "ignored_pixels": 0}
        self._queued: list[int] = []  # qualified at the previous frame, see map_queued()
        self._qualified: list[int] = []  # qualified at this frame
        # the config's limits in the form Track.add and consistent() take, set once
        self._track_limits: dict[str, Any] = {
            "max_observations": config.max_track_observations,
            "min_observations": config.min_observations,
            "cos_parallax": float(np.cos(np.deg2rad(config.min_parallax_deg))),
        }
        self._point_limits = {"min_depth_m": config.min_depth_m, "max_sigmas": config.max_reprojection_sigmas}

    @property
    def n_queued(self) -> int:
        """Tracks qualified at the previous frame, waiting to be triangulated."""
        return len(self._queued)

    def observe(self, tid: int, fid: int, uv: np.ndarray, sigma: float, now: int, ray_w: np.ndarray) -> None:
        """A pixel of track ``tid`` (not mapped) in frame ``fid``, the ``now``-th frame,
        with its world ray direction ``ray_w``: buffered, the track queued for the
        next frame once it has the parallax and the pixels."""
        if tid in self.rejected:
            self.counts["ignored_pixels"] += 1
            return
        track = self.tracks.get(tid)
        if track is None:
            track = self.tracks[tid] = Track(first_ray_w=ray_w)
        elif track.last_index == now:  # same track twice in a frame: keep the first
            self.counts["ignored_pixels"] += 1
            return
        if track.add(fid, uv, sigma, now, ray_w, **self._track_limits):
            self._qualified.append(tid)

    def reject(self, tid: int) -> None:
        """Ignore track ``tid`` from now on (its landmark left the map)."""
        self.rejected.add(tid)

    def map_queued(
        self,
        fid: int,
        now: int,
        budget: int,
        pose: Callable[[int], gtsam.Pose3],
        cal: gtsam.Cal3_S2,
        K: np.ndarray,
    ) -> list[tuple[int, np.ndarray, Track]]:
        """End of frame ``fid`` (the ``now``-th): triangulate the tracks queued at the
        previous frame, at most ``budget`` of them mapped, with the poses ``pose(frame)``
        and camera ``cal`` (``K``); returns ``(track id, point, track)`` of each to map,
        in order. Those left waiting for a later frame's budget are queued again, before
        the tracks that qualified in this frame.

        They are triangulated now, from the pixels of frames before this one: those
        poses have been corrected by their own pixels in this frame's update, while
        this frame's pose is still odometry alone (a few pixels off, which the
        consistency test would take for a bad track). This frame's pixel still gets
        its factor.
        """
        mapped, waiting = [], []
        for tid in self._queued:
            if tid not in self.tracks:
                continue
            if budget <= 0:
                waiting.append(tid)
                continue
            track = self.tracks.pop(tid)
            point = self._triangulate(tid, track, fid, pose, cal, K)
            if point is not None:
                mapped.append((tid, point, track))
                budget -= 1
        self._queued, self._qualified = waiting + self._qualified, []
        if now % self.config.track_timeout_frames == 0:  # amortised sweep
            self._forget_stale_tracks(now)
        return mapped

    def _triangulate(
        self,
        tid: int,
        track: Track,
        current: int,
        pose: Callable[[int], gtsam.Pose3],
        cal: gtsam.Cal3_S2,
        K: np.ndarray,
    ) -> np.ndarray | None:
        """A track's point from its pixels of frames other than ``current``, or None:
        rejected for good."""
        used = [i for i, f in enumerate(track.frames) if f != current]
        poses = [pose(track.frames[i]) for i in used]
        uv = np.array([track.uv[i] for i in used])
        sigma = np.array([track.sigma[i] for i in used])
        point = triangulate(poses, cal, uv, sigma)
        if (
            point is None
            or not np.all(np.isfinite(point))
            or not consistent(poses, K, uv, sigma, point, **self._point_limits)
        ):
            self.rejected.add(tid)
            self.counts["rejected_triangulations"] += 1
            return None
        return point

    def _forget_stale_tracks(self, now: int) -> None:
        """Drop waiting tracks unseen for more than ``track_timeout_frames`` frames."""
        stale = [
            tid for tid, t in self.tracks.items() if now - t.last_index > self.config.track_timeout_frames
        ]
        for tid in stale:
            del self.tracks[tid]
        self.counts["dropped_tracks"] += len(stale)
