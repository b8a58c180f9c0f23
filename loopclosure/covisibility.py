"""Which older frames may answer a loop query: those the query is not covisible with.

A frame resembles the frames just before it because the camera still sees
what they saw, not because it came back. ORB-SLAM (Mur-Artal et al., T-RO
2015, Sec. VII-A) therefore excludes from a keyframe's loop candidates the
keyframes *covisible* with it, those sharing tracked map points with it,
and no fixed window of frames or seconds: a slow robot, a small room or a
1 Hz camera comes back to a place after any number of frames, and a place
left and re-entered starts new tracks.

- :class:`CovisibilityGraph` keeps the track ids each frame observed and
  counts, for a new frame, how many of them every older frame shares.
  A visual run gives it its tracker's ids (landmarks re-found by active
  search keep theirs); a folder of images gets them from
  :class:`DescriptorTracker`.
- :class:`DescriptorTracker` is the tracker of a folder command that has
  none: each image's strongest ORB features are matched (ratio test, mutual
  best) against the latest descriptor of every track still in the local
  map, the tracks observed by the frames covisible with the previous image
  (ORB-SLAM's local map, in miniature; a track seen in one image only stays
  in it for the next image alone); an unmatched feature starts a track.
  Written by hand because no library tracks binary descriptors over a
  local map; OpenCV's matchers are per image pair.

A frame is covisible with the query when they share at least
``min_shared`` tracks; the previous frame always counts (it is the
query's own odometry neighbour, never a loop).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from loopclosure.matching import match_descriptors

__all__ = ["CovisibilityGraph", "DescriptorTracker", "TRACKED_FEATURES"]

#: Strongest features of an image the folder tracker follows (ORB output is
#: sorted by response): enough for shared counts in the tens, at a few ms an image.
TRACKED_FEATURES = 500


class CovisibilityGraph:
    """Track ids per frame and the frames sharing them (an inverted index)."""

    def __init__(self) -> None:
        self._frame_ids: list[np.ndarray] = []
        self._frames_of: dict[int, list[int]] = {}

    def __len__(self) -> int:
        return len(self._frame_ids)

    def add(self, track_ids: np.ndarray) -> int:
        """Add the next frame's observed track ids ((N,) int); returns its index."""
        i = len(self._frame_ids)
        ids = np.unique(np.asarray(track_ids, np.int64).reshape(-1))
        self._frame_ids.append(ids)
        for t in ids.tolist():
            self._frames_of.setdefault(t, []).append(i)
        return i

    def shared(self, i: int) -> np.ndarray:
        """(i,) int: tracks frame ``i`` shares with each older frame 0..i-1."""
        counts = np.zeros(len(self._frame_ids), np.int64)
        for t in self._frame_ids[i].tolist():
            counts[self._frames_of[t]] += 1
        return counts[:i]

    def shared_between(self, a: int, b: int) -> int:
        """Tracks frames ``a`` and ``b`` both observed."""
        return int(np.intersect1d(self._frame_ids[a], self._frame_ids[b], assume_unique=True).size)

    def covisible(self, i: int, min_shared: int, shared: np.ndarray | None = None) -> np.ndarray:
        """Sorted older frames covisible with ``i`` (module docstring), the previous always;
        ``shared``: :meth:`shared` of ``i`` when the caller has it already."""
        near = np.flatnonzero((self.shared(i) if shared is None else shared) >= min_shared)
        if i > 0 and (near.size == 0 or near[-1] != i - 1):
            near = np.append(near, i - 1)
        return near

    @staticmethod
    def local_map(near: np.ndarray, neighbours: Sequence[np.ndarray]) -> np.ndarray:
        """Sorted older frames linked to a frame within two covisibility links: ``near``,
        the frames covisible with it (:meth:`covisible`), and those covisible with one
        of them (``neighbours[k]``: the older frames covisible with frame k).

        ORB-SLAM's local map (T-RO 2015, Sec. V-D) has the same reach. One link
        under-counts: a feature the tracker missed once starts a new track, while
        the verifier's guided matching still finds it, so frames just past the
        direct neighbours would verify as "loops" on a straight drive.
        """
        return np.unique(np.concatenate([near] + [neighbours[k] for k in near.tolist()]))


class DescriptorTracker:
    """Track ids for a folder's images from their ORB descriptors (module docstring)."""

    def __init__(self, n_features: int = TRACKED_FEATURES):
        self.n_features = int(n_features)
        # Grown by doubling: one track per unmatched feature, hundreds an image.
        self._desc = np.zeros((1024, 32), np.uint8)  # latest descriptor of each track
        self._last = np.full(1024, -1, np.int64)  # last frame that observed each track
        self._seen = np.zeros(1024, np.int64)  # images that observed each track
        # the tracks each frame observed: the pool is looked for among the local frames'
        # own, not among every track of the sequence (a cost growing with its length)
        self._frame_tracks: list[np.ndarray] = []
        self._n_tracks = 0
        self._n_frames = 0

    @property
    def n_tracks(self) -> int:
        return self._n_tracks

    def track(self, descriptors: np.ndarray, local_frames: np.ndarray) -> np.ndarray:
        """Track ids ((M,) int64) of the strongest ``n_features`` rows of ``descriptors``
        ((N, 32) uint8, M = min(N, n_features)), matched against the tracks last observed
        in ``local_frames`` (frame indices of earlier calls)."""
        desc = np.ascontiguousarray(np.asarray(descriptors, np.uint8).reshape(-1, 32)[: self.n_features])
        frame = self._n_frames
        self._n_frames += 1
        n = self._n_tracks
        local_frames = np.asarray(local_frames, np.int64)
        if frame > 0:  # the previous image's tracks are always candidates
            local_frames = np.union1d(local_frames, [frame - 1])
        # tracks last observed in a local frame (one a later frame re-found is not)
        seen_in = [self._frame_tracks[f] for f in local_frames.tolist()]
        act = np.unique(np.concatenate(seen_in)) if seen_in else np.zeros(0, np.int64)
        last = self._last[act]
        keep = np.isin(last, local_frames)
        act, last = act[keep], last[keep]
        # A track seen once and not re-found in the next image is dropped from the local
        # map (ORB-SLAM culls its new map points likewise): most features are such, and
        # matching against them would triple the cost for nothing
        pool = act[(last == frame - 1) | (self._seen[act] >= 2)]
        ids = np.full(len(desc), -1, np.int64)
        if pool.size and len(desc):
            m = match_descriptors(desc, self._desc[pool])
            ids[m[:, 0]] = pool[m[:, 1]]
        matched = ids >= 0
        self._desc[ids[matched]] = desc[matched]  # a track looks as it did last
        self._last[ids[matched]] = frame
        self._seen[ids[matched]] += 1
        n_new = int((~matched).sum())
        if n + n_new > len(self._last):
            cap = max(2 * len(self._last), n + n_new)
            self._desc = np.concatenate([self._desc, np.zeros((cap - len(self._desc), 32), np.uint8)])
            self._last = np.concatenate([self._last, np.full(cap - len(self._last), -1, np.int64)])
            self._seen = np.concatenate([self._seen, np.zeros(cap - len(self._seen), np.int64)])
        ids[~matched] = n + np.arange(n_new)
        self._desc[n : n + n_new] = desc[~matched]
        self._last[n : n + n_new] = frame
        self._seen[n : n + n_new] = 1
        self._frame_tracks.append(ids)
        self._n_tracks = n + n_new
        return ids
