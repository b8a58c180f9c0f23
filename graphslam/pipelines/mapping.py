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

Where the run mapped few landmarks (a turn, where the tracker loses its
tracks before they gain parallax), the map is densified for later
localisation: corners of two keyframes are matched and triangulated with the
final poses (:func:`densify`). Such landmarks have negative ids, two
observations, and NaN patches (no track ever followed them).
"""

from __future__ import annotations

import cv2
import numpy as np

from frontend.orb import OrbDetector
from frontend.search_matchers import extract_patches
from graphslam.maps.spatial_map import SpatialMap, bow_csr
from loopclosure.database import BowDatabase
from loopclosure.matching import match_descriptors
from slamcore.errors import GraphSlamError, UnsupportedError

#: Words of a vocabulary trained on the run's own frames (a 10-way tree of depth 3).
SELF_TRAINED_WORDS = 1000
#: Densification (:func:`densify`): keyframes with fewer landmark observations than
#: this get points triangulated with the keyframe DENSIFY_GAP later; the checks.
DENSIFY_BELOW = 40
DENSIFY_GAP = 4
DENSIFY_MAX_REPROJ_PX = 2.0
DENSIFY_MIN_PARALLAX_DEG = 2.0


def require_map_backend(backend) -> None:
    """Saving a map needs past keyframe poses and their covariances: iSAM2 only."""
    if not backend.supports_loop_closures:
        raise UnsupportedError(
            f"--save-map: back end {backend.name!r} keeps no past keyframe poses to save; use --backend isam2"
        )


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
        self.corners: dict[int, tuple[np.ndarray, np.ndarray]] = {}

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
        bow = self.bow_orb.detect(image).descriptors
        if bow is None:  # ORB's features always have theirs
            raise GraphSlamError("map: ORB features without descriptors")
        self.bow_descriptors[int(k)] = bow
        corners = np.asarray(tracking.corners, np.float64).reshape(-1, 2)
        cidx, cdesc = self.describer.describe(image, corners)
        self.corners[int(k)] = (corners[cidx], cdesc)

    def build(
        self, estimate, backend, vocabulary=None, meta: dict | None = None, K=None, image_size=None
    ) -> SpatialMap:
        """The map of ``estimate`` (a finalised iSAM2 estimate of this run)."""
        from graphslam.backends.spatial.marginals import marginal_covariances

        require_map_backend(backend)
        frames = np.asarray(estimate.frame_ids, np.int64)
        if vocabulary is None:
            from graphslam.pipelines.place_recognition import train_vocabulary

            vocabulary = train_vocabulary([self.bow_descriptors[int(f)] for f in frames], SELF_TRAINED_WORDS)
        db = BowDatabase(vocabulary)
        pose_cov, point_cov = marginal_covariances(backend, estimate)
        kf_obs, lm_obs, obs_uv, obs_desc = self._observations(frames, estimate.landmark_ids)
        seen = np.unique(lm_obs)  # landmarks with at least one described pixel
        remap = np.full(len(estimate.landmark_ids), -1, np.int64)
        remap[seen] = np.arange(len(seen))
        lm_ids = np.asarray(estimate.landmark_ids, np.int64)[seen]
        lm_w = np.asarray(estimate.landmarks_w, np.float64)[seen]
        first = np.unique(lm_obs, return_index=True)[1]  # obs are in frame order
        patches = (
            np.stack([self.patches[int(t)] for t in lm_ids]).astype(np.float32)
            if len(lm_ids)
            else np.zeros((0, self.patch_px, self.patch_px), np.float32)
        )
        lm_desc, lm_cov, lm_obs = obs_desc[first], point_cov[seen], remap[lm_obs]
        wTc = np.asarray(estimate.wTc, np.float64)
        d = densify(
            wTc,
            [self.corners[int(f)] for f in frames],
            np.bincount(kf_obs, minlength=len(frames)),
            np.asarray(K, np.float64),
        )
        if len(d["points"]):
            n0 = len(lm_ids)
            lm_ids = np.r_[lm_ids, -1 - np.arange(len(d["points"]), dtype=np.int64)]
            lm_w, lm_cov = np.r_[lm_w, d["points"]], np.r_[lm_cov, d["covariances"]]
            lm_desc = np.r_[lm_desc, d["obs_desc"][0::2]]
            patches = np.r_[patches, np.full((len(d["points"]),) + patches.shape[1:], np.nan, np.float32)]
            kf_obs, lm_obs = np.r_[kf_obs, d["obs_keyframe"]], np.r_[lm_obs, n0 + d["obs_landmark"]]
            obs_uv, obs_desc = np.r_[obs_uv, d["obs_uv"]], np.r_[obs_desc, d["obs_desc"]]
        indptr, words, weights = bow_csr([db.bow(self.bow_descriptors[int(f)]) for f in frames])
        index = frames if self.frame_index is None else self.frame_index[frames]
        return SpatialMap(
            K=np.asarray(K, np.float64),
            image_size=(int(image_size[0]), int(image_size[1])),
            keyframe_ids=index.astype(np.int64),
            keyframe_wTc=wTc,
            keyframe_cov=pose_cov,
            landmark_ids=lm_ids,
            landmark_w=lm_w,
            landmark_cov=lm_cov,
            landmark_desc=lm_desc,
            landmark_patch=patches,
            obs_keyframe=kf_obs,
            obs_landmark=lm_obs,
            obs_uv=obs_uv,
            obs_desc=obs_desc,
            bow_indptr=indptr,
            bow_words=words,
            bow_weights=weights,
            vocabulary=vocabulary,
            meta={**(meta or {}), "densified_landmarks": len(d["points"])},
        )

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
        return (
            np.concatenate(kf),
            np.concatenate(lm),
            np.concatenate(uv).reshape(-1, 2),
            np.concatenate(desc).reshape(-1, 32).astype(np.uint8),
        )


def densify(wTc: np.ndarray, corners: list, n_obs: np.ndarray, K: np.ndarray) -> dict:
    """Landmarks added where the run mapped few (module docstring).

    For each keyframe ``a`` with fewer than :data:`DENSIFY_BELOW` landmark
    observations, its corners are matched (ORB, ratio test, mutual) with those
    of keyframe ``a + DENSIFY_GAP`` (or ``a - DENSIFY_GAP`` at the end) and
    triangulated with the two estimated poses (OpenCV DLT); a point is kept
    when it lies in front of both cameras, reprojects within
    :data:`DENSIFY_MAX_REPROJ_PX` in both and the rays meet at
    :data:`DENSIFY_MIN_PARALLAX_DEG` or more. Its covariance is the two-view
    Gauss-Newton ``sigma^2 (J_a^T J_a + J_b^T J_b)^-1`` at 1 px (the poses taken
    as exact). Returns points (D, 3), covariances (D, 3, 3) and two
    observations per point (keyframe, local landmark index, uv, descriptor),
    ``a`` first.
    """
    from slamcore.spatial.camera import project_jacobians
    from slamcore.spatial.geometry import invert_pose

    out: dict[str, list] = {
        "points": [],
        "covariances": [],
        "obs_keyframe": [],
        "obs_landmark": [],
        "obs_uv": [],
        "obs_desc": [],
    }
    n = len(wTc)
    for a in range(n):
        b = a + DENSIFY_GAP if a + DENSIFY_GAP < n else a - DENSIFY_GAP
        if n_obs[a] >= DENSIFY_BELOW or b < 0:
            continue
        (xa, da), (xb, db) = corners[a], corners[b]
        pairs = match_descriptors(da, db, ratio=0.8, cross_check=True, max_hamming=64)
        if len(pairs) == 0:
            continue
        cTw = [invert_pose(wTc[a]), invert_pose(wTc[b])]
        ua, ub = xa[pairs[:, 0]], xb[pairs[:, 1]]
        X = cv2.triangulatePoints(K @ cTw[0][:3], K @ cTw[1][:3], ua.T, ub.T)
        with np.errstate(divide="ignore", invalid="ignore"):
            p = (X[:3] / X[3]).T
        ok = np.all(np.isfinite(p), axis=1)
        p, ua, ub, pairs = p[ok], ua[ok], ub[ok], pairs[ok]
        (uva, za, Ja, _), (uvb, zb, Jb, _) = (project_jacobians(K, c, p) for c in cTw)
        ra, rb = p - wTc[a][:3, 3], p - wTc[b][:3, 3]
        cos = np.einsum("ij,ij->i", ra, rb) / (np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1))
        keep = (
            (za > 0)
            & (zb > 0)
            & (np.linalg.norm(uva - ua, axis=1) <= DENSIFY_MAX_REPROJ_PX)
            & (np.linalg.norm(uvb - ub, axis=1) <= DENSIFY_MAX_REPROJ_PX)
            & (cos <= np.cos(np.radians(DENSIFY_MIN_PARALLAX_DEG)))
        )
        info = np.einsum("nji,njk->nik", Ja, Ja) + np.einsum("nji,njk->nik", Jb, Jb)
        keep &= np.linalg.cond(info) < 1e12
        k = np.flatnonzero(keep)
        base = sum(len(q) for q in out["points"])
        out["points"].append(p[k])
        out["covariances"].append(np.linalg.inv(info[k]))
        out["obs_keyframe"].append(np.repeat(np.array([[a, b]]), len(k), axis=0).reshape(-1))
        out["obs_landmark"].append(np.repeat(base + np.arange(len(k)), 2))
        out["obs_uv"].append(np.stack([ua[k], ub[k]], axis=1).reshape(-1, 2))
        out["obs_desc"].append(np.stack([da[pairs[k, 0]], db[pairs[k, 1]]], axis=1).reshape(-1, 32))
    if not out["points"]:
        return {"points": np.zeros((0, 3))}
    return {key: np.concatenate(v) for key, v in out.items()}
