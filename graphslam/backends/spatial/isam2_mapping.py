"""How the visual iSAM2 back end maps a track: triangulated once it has parallax, checked,
then added with a factor for each of its pixels.

A mixin of :class:`graphslam.backends.spatial.isam2.VisualIsam2Backend` (its own
module to keep the back end's size readable, as :mod:`.isam2_ordering`): it
reads the back end's waiting tracks, poses and pending graph and fills its
landmark slots; the geometry is :mod:`.landmark_init`'s.
"""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from graphslam.backends.spatial.landmark_init import Track, consistent, triangulate

__all__ = ["LandmarkMapping"]


class LandmarkMapping:
    """Delayed landmark initialisation of the visual iSAM2 back end."""

    def _triangulate_queued(self, fid: int, budget: int) -> list[int]:
        """Triangulate the tracks queued at the previous frame, at most ``budget`` of
        them mapped; returns those left waiting for a later frame's budget.

        They are triangulated now, from the pixels of frames before this one
        (``fid``): those poses have been corrected by their own pixels in this
        frame's update, while this frame's pose is still odometry alone (a few
        pixels off, which the consistency test would take for a bad track).
        This frame's pixel still gets its factor.
        """
        waiting = []
        for tid in self._queued:
            if tid not in self._tracks:
                continue
            if budget <= 0:
                waiting.append(tid)
                continue
            if self._triangulate(tid, self._tracks.pop(tid), fid):
                budget -= 1
        return waiting

    def _triangulate(self, tid: int, track: Track, current: int) -> bool:
        """Triangulate a track from its pixels of frames other than ``current``;
        map it with factors for all its pixels, or reject it for good."""
        used = [i for i, f in enumerate(track.frames) if f != current]
        poses = [self._pose(track.frames[i]) for i in used]
        uv = np.array([track.uv[i] for i in used])
        sigma = np.array([track.sigma[i] for i in used])
        point = triangulate(poses, self._cal, uv, sigma)
        if (point is None or not np.all(np.isfinite(point))
                or not consistent(poses, self._K, uv, sigma, point,
                                  min_depth_m=self.config.min_depth_m,
                                  max_sigmas=self.config.max_reprojection_sigmas)):
            self._rejected.add(tid)
            self._stats["rejected_triangulations"] += 1
            return False
        key = L(tid)
        self._values.insert(key, point)
        for f, u, s in zip(track.frames, track.uv, track.sigma):
            self._graph.add(gtsam.GenericProjectionFactorCal3_S2(
                u, self._pixel_noise(s), X(f), key, self._cal))
        self._add_landmark(tid, point, len(track.frames), track.sigma[-1])
        return True

    def _add_landmark(self, tid: int, point: np.ndarray, nobs: int, sigma: float) -> None:
        if self._n_lm == len(self._lm_pos):  # grow by doubling: amortised O(1)
            cap = max(64, 2 * self._n_lm)
            self._lm_pos = np.resize(self._lm_pos, (cap, 3))
            self._lm_nobs = np.resize(self._lm_nobs, cap)
            self._lm_sigma = np.resize(self._lm_sigma, cap)
            self._lm_last = np.resize(self._lm_last, cap)
            self._lm_read = np.resize(self._lm_read, cap)
        s = self._n_lm
        self._slot[tid] = s
        self._lm_ids.append(tid)
        self._lm_pos[s], self._lm_nobs[s], self._lm_sigma[s] = point, nobs, sigma
        self._lm_last[s] = len(self._frames) - 1
        self._lm_read[s] = -1  # its pending initial value: read again once iSAM2 has it
        self._n_lm += 1

    def _forget_stale_tracks(self, now: int) -> None:
        """Drop waiting tracks unseen for more than ``track_timeout_frames`` frames."""
        stale = [tid for tid, t in self._tracks.items()
                 if now - t.last_index > self.config.track_timeout_frames]
        for tid in stale:
            del self._tracks[tid]
        self._stats["dropped_tracks"] += len(stale)
