"""Build a :class:`~graphslam.maps.spatial_map.SpatialMap` from a visual run (``--save-map``).

:class:`MapRecorder` is a frame hook of :func:`graphslam.pipelines.spatial.run`:
per frame it keeps the observed tracks' pixels with an ORB descriptor computed
there (:meth:`frontend.orb.OrbDetector.describe`, as the loop closer does),
the patch each track was first seen with, and the frame's own ORB features
for its bag-of-words vector. Every frame of the run is a keyframe. After the
run :meth:`MapRecorder.build` takes the final estimate: keyframe poses,
landmarks, their marginal covariances (one batch factorisation,
:mod:`graphslam.backends.spatial.marginals`), the observations of mapped
landmarks, and the BoW vectors under the given vocabulary or, without one, a
vocabulary trained on the run's own ORB features (no second pass over the
images).
"""

from __future__ import annotations

import numpy as np

from frontend.active_search import extract_patches
from frontend.orb import OrbDetector
from graphslam.maps.spatial_map import SpatialMap, bow_csr
from loopclosure.database import BowDatabase
from slamcore.errors import UnsupportedError

#: Words of a vocabulary trained on the run's own frames (a 10-way tree of depth 3).
SELF_TRAINED_WORDS = 1000


def require_map_backend(backend) -> None:
    """Saving a map needs past keyframe poses and their covariances: iSAM2 only."""
    if not backend.supports_loop_closures:
        raise UnsupportedError(f"--save-map: back end {backend.name!r} keeps no past keyframe "
                               "poses to save; use --backend isam2")


class MapRecorder:
    """Frame hook collecting what a saved map needs (module docstring).

    Args:
        bow_orb: the ORB detector whose features make the BoW vectors (the loop
            detector's, so a map and a later query describe images alike).
        patch_px: side of the patches kept per track (the tracker's).
        frame_index: (N,) frame index in the original sequence of each run frame
            (a ``--frames`` selection), or None for the identity.
    """

    def __init__(self, bow_orb: OrbDetector, patch_px: int, frame_index=None):
        self.bow_orb = bow_orb
        self.describer = OrbDetector(bow_orb.config)
        self.patch_px = int(patch_px)
        self.frame_index = None if frame_index is None else np.asarray(frame_index, np.int64)
        self.frames: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self.bow_descriptors: dict[int, np.ndarray] = {}
        self.patches: dict[int, np.ndarray] = {}

    def __call__(self, k, image, tracking, backend) -> None:
        obs = tracking.observations
        uv = np.asarray(obs.uv_px, np.float64).reshape(-1, 2)
        idx, desc = self.describer.describe(image, uv)
        ids = np.asarray(obs.track_ids, np.int64)
        self.frames[int(k)] = (ids[idx], uv[idx], desc)
        fresh = [i for i, t in enumerate(ids.tolist()) if t not in self.patches]
        if fresh:
            cut = extract_patches(image, uv[fresh], self.patch_px)
            for j, i in enumerate(fresh):
                self.patches[int(ids[i])] = cut[j]
        self.bow_descriptors[int(k)] = self.bow_orb.detect(image).descriptors

    def build(self, estimate, backend, vocabulary=None, meta: dict | None = None,
              K=None, image_size=None) -> SpatialMap:
        """The map of ``estimate`` (a finalised iSAM2 estimate of this run)."""
        from graphslam.backends.spatial.marginals import marginal_covariances

        require_map_backend(backend)
        frames = np.asarray(estimate.frame_ids, np.int64)
        if vocabulary is None:
            from graphslam.pipelines.place_recognition import train_vocabulary

            vocabulary = train_vocabulary([self.bow_descriptors[int(f)] for f in frames],
                                          SELF_TRAINED_WORDS)
        db = BowDatabase(vocabulary)
        pose_cov, point_cov = marginal_covariances(backend, estimate)
        kf_obs, lm_obs, obs_uv, obs_desc = self._observations(frames, estimate.landmark_ids)
        seen = np.unique(lm_obs)  # landmarks with at least one described pixel
        remap = np.full(len(estimate.landmark_ids), -1, np.int64)
        remap[seen] = np.arange(len(seen))
        lm_ids = np.asarray(estimate.landmark_ids, np.int64)[seen]
        first = np.unique(lm_obs, return_index=True)[1]  # obs are in frame order
        indptr, words, weights = bow_csr([db.bow(self.bow_descriptors[int(f)]) for f in frames])
        index = frames if self.frame_index is None else self.frame_index[frames]
        return SpatialMap(
            K=np.asarray(K, np.float64), image_size=tuple(int(v) for v in image_size),
            keyframe_ids=index.astype(np.int64), keyframe_wTc=np.asarray(estimate.wTc, np.float64),
            keyframe_cov=pose_cov, landmark_ids=lm_ids,
            landmark_w=np.asarray(estimate.landmarks_w, np.float64)[seen],
            landmark_cov=point_cov[seen], landmark_desc=obs_desc[first],
            landmark_patch=np.stack([self.patches[int(t)] for t in lm_ids]).astype(np.float32)
            if len(lm_ids) else np.zeros((0, self.patch_px, self.patch_px), np.float32),
            obs_keyframe=kf_obs, obs_landmark=remap[lm_obs], obs_uv=obs_uv, obs_desc=obs_desc,
            bow_indptr=indptr, bow_words=words, bow_weights=weights, vocabulary=vocabulary,
            meta=dict(meta or {}))

    def _observations(self, frames: np.ndarray, landmark_ids: np.ndarray):
        """``(keyframe index, landmark index, uv, descriptor)`` of every described pixel
        of a mapped landmark, in frame order."""
        slot = {int(t): i for i, t in enumerate(np.asarray(landmark_ids).tolist())}
        kf, lm, uv, desc = [], [], [], []
        for k, f in enumerate(frames.tolist()):
            ids, px, d = self.frames[f]
            keep = [i for i, t in enumerate(ids.tolist()) if t in slot]
            kf.append(np.full(len(keep), k, np.int64))
            lm.append(np.array([slot[int(ids[i])] for i in keep], np.int64))
            uv.append(px[keep])
            desc.append(d[keep])
        return (np.concatenate(kf), np.concatenate(lm), np.concatenate(uv).reshape(-1, 2),
                np.concatenate(desc).reshape(-1, 32).astype(np.uint8))
