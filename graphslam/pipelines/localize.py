"""Localisation against a fixed map (``graphslam localize``): place recognition, PnP, tracking.

The map (:class:`~graphslam.maps.spatial_map.SpatialMap`) is never changed.
Per frame (:meth:`Localizer.locate`):

1. **Tracking** (when the previous frame was placed): the pose is predicted
   with constant velocity (the last frame-to-frame motion repeated), the map
   landmarks seen by the ``local_keyframes`` keyframes nearest the prediction
   are projected, and each is searched for in a window of
   ``search_radius_px`` around its predicted pixel (active search): the
   frame's corners inside the window are compared by Hamming distance with
   the ORB descriptors the landmark had in those keyframes, the closest
   accepted under ``max_hamming``, one landmark per corner. The pose is then
   solved by PnP RANSAC on these matches (OpenCV, world points) and refined
   on its inliers; ``min_inliers`` inliers make the frame ``tracked``.
2. **Relocalisation** (first frame, or tracking failed): the frame's
   bag-of-words vector queries the map's keyframes (the loop detector's
   inverted-index database, :class:`loopclosure.database.BowDatabase`); the
   landmarks observed by the ``candidates`` best keyframes, with their
   descriptors there, are matched to the frame's corners and solved by
   :func:`loopclosure.pnp.relative_pose_pnp` with the world as "camera a", so
   its ``aTb`` is ``wTc``. Accepted: ``relocalised``; otherwise ``lost`` (and
   the next frame relocalises again).

Corners come from the detector the map was built with (``[tracker] detector``
of the map's configuration) and are described by ORB at their pixels, as the
map's observations were; the BoW vector uses the map's own ORB settings.

Covariance of a placed pose (``[rho, phi]``, right perturbation): the
Gauss-Newton ``sigma_px^2 (J^T J)^-1`` of the inlier reprojections, as for a
metric loop closure (:mod:`loopclosure.pnp`), inflated for the map points' own
error and floored (``[loop_pnp]`` settings), plus the map's own uncertainty
where the frame is: the covariance of the keyframe nearest the placed pose,
carried to the camera by the adjoint of ``cTk`` (the landmarks a keyframe
mapped move with its error, and a camera placed on them moves with them).
Without it, a map of KITTI 07's even frames placed the odd ones with a mean
NEES of 240 against the truth, 12.1 with it (6 if consistent; thirteenth hostile pass).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import cv2
import numpy as np

from frontend.orb import OrbDetector
from graphslam.maps.spatial_map import SpatialMap
from loopclosure.database import BowDatabase
from loopclosure.descriptor_distance import popcount_sum
from loopclosure.pnp import PnpConfig, pnp_covariance, pose_from_rodrigues, relative_pose_pnp
from slamcore.config import Validated, bounded
from slamcore.errors import GraphSlamError
from slamcore.spatial.camera import project, project_jacobians
from slamcore.spatial.geometry import invert_pose, se3_adjoint

Status = Literal["tracked", "relocalised", "lost"]


@dataclass(frozen=True)
class LocalizeConfig(Validated):
    """Localisation settings (config section ``[localize]``), module docstring.

    Attributes:
        candidates: keyframes place recognition hands to relocalisation.
        local_keyframes: keyframes nearest the predicted pose whose landmarks are tracked.
        search_radius_px: half side of the active-search window around a prediction.
        max_hamming: largest Hamming distance (bits of 256) of a tracking match.
        min_inliers: fewest PnP inliers to accept a tracked pose.
        ransac_threshold_px: tracking PnP RANSAC threshold, pixels.
    """

    SECTION: ClassVar[str] = "localize"

    candidates: int = bounded(3, min=1)
    local_keyframes: int = bounded(10, min=1)
    search_radius_px: float = bounded(20.0, gt=0.0)
    # a Hamming distance between 256-bit descriptors
    max_hamming: int = bounded(64, min=0, max=256)
    # EPnP needs 4 points
    min_inliers: int = bounded(15, min=4)
    ransac_threshold_px: float = bounded(3.0, gt=0.0)


@dataclass(frozen=True, eq=False)
class Placement:
    """One frame's outcome.

    Attributes:
        status: ``"tracked"``, ``"relocalised"`` or ``"lost"``.
        wTc: (4, 4) pose, or None when lost; covariance: (6, 6) ``[rho, phi]`` or None.
        inliers: PnP inliers; keyframe: map keyframe index retrieved (relocalisation).
        uv_px: (M, 2) pixels of the inlier landmarks (for the recording).
    """

    status: Status
    wTc: np.ndarray | None
    covariance: np.ndarray | None
    inliers: int = 0
    keyframe: int | None = None
    uv_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


class Localizer:
    """Places frames in a fixed :class:`SpatialMap` (module docstring).

    Args:
        smap: the map; K: (3, 3) intrinsics of the frames (checked against the
            map by the caller); detector: the corner detector the map was built with.
    """

    def __init__(
        self,
        smap: SpatialMap,
        K: np.ndarray,
        detector,
        config: LocalizeConfig | None = None,
        pnp: PnpConfig | None = None,
        bow_orb: OrbDetector | None = None,
    ):
        self.map = smap
        self.K = np.asarray(K, np.float64)
        self.detector = detector
        self.config = config or LocalizeConfig()
        self.pnp = pnp or PnpConfig()
        self.bow_orb = bow_orb or OrbDetector()
        self.describer = OrbDetector(self.bow_orb.config)
        self.db = BowDatabase(smap.vocabulary)
        for k in range(smap.n_keyframes):
            self.db.add(smap.bow(k))
        self._centres = smap.keyframe_wTc[:, :3, 3]
        self._last: list[np.ndarray] = []  # the last two placed poses, for the prediction
        self.timings_s: dict[str, float] = {"detect": 0.0, "track": 0.0, "relocalise": 0.0}

    def locate(self, image: np.ndarray) -> Placement:
        """Place the next frame (``image`` (H, W) uint8)."""
        t = time.perf_counter()
        corners = np.asarray(self.detector.detect(image).xy_px, np.float64).reshape(-1, 2)
        idx, desc = self.describer.describe(image, corners)
        xy = corners[idx]
        t1 = time.perf_counter()
        self.timings_s["detect"] += t1 - t
        placed = self._track(xy, desc) if self._last else None
        t2 = time.perf_counter()
        self.timings_s["track"] += t2 - t1
        if placed is None:
            placed = self._relocalise(image, xy, desc)
            self.timings_s["relocalise"] += time.perf_counter() - t2
        # the velocity comes from two consecutive placed frames; a lost frame forgets it
        self._last = [] if placed.wTc is None else [*self._last[-1:], placed.wTc]
        if placed.wTc is not None and placed.covariance is not None:
            placed = dataclasses.replace(
                placed, covariance=placed.covariance + self._map_covariance(placed.wTc)
            )
        return placed

    def _map_covariance(self, wTc: np.ndarray) -> np.ndarray:
        """(6, 6) the nearest keyframe's covariance carried to camera ``wTc`` (module doc)."""
        k = int(np.argmin(np.linalg.norm(self._centres - wTc[:3, 3], axis=1)))
        A = se3_adjoint(invert_pose(wTc) @ self.map.keyframe_wTc[k])
        C = A @ self.map.keyframe_cov[k] @ A.T
        return 0.5 * (C + C.T)

    # ------------------------------------------------------------------ tracking

    def _predicted(self) -> np.ndarray:
        if len(self._last) < 2:
            return self._last[-1]
        a, b = self._last
        return b @ (invert_pose(a) @ b)

    def _track(self, xy: np.ndarray, desc: np.ndarray) -> Placement | None:
        """Active search of the local map around the constant-velocity prediction."""
        wTc = self._predicted()
        obs = self._local_observations(wTc[:3, 3])
        lm = self.map.obs_landmark[obs]
        pts = self.map.landmark_w[lm]
        uv, depth = project(self.K, invert_pose(wTc), pts)
        W, H = self.map.image_size
        ok = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= H - 1)
        obs, lm, uv = obs[ok], lm[ok], uv[ok]
        pairs = self._search(uv, self.map.obs_desc[obs], lm, xy, desc)
        if len(pairs) < self.config.min_inliers:
            return None
        pts, img = self.map.landmark_w[pairs[:, 0]], xy[pairs[:, 1]]
        return self._solve(pts, img, "tracked", guess=wTc)

    def _local_observations(self, centre: np.ndarray) -> np.ndarray:
        n = min(self.config.local_keyframes, self.map.n_keyframes)
        near = np.argpartition(np.linalg.norm(self._centres - centre, axis=1), n - 1)[:n]
        return np.concatenate([self.map.keyframe_observations(int(k)) for k in near])

    def _search(self, uv, obs_desc, lm, xy, desc) -> np.ndarray:
        """(M, 2) ``(landmark index, corner index)``: per landmark the corner within the
        window closest in descriptor, then one landmark per corner (best first)."""
        if len(uv) == 0 or len(xy) == 0:
            return np.zeros((0, 2), np.int64)
        r = self.config.search_radius_px
        i, j = np.nonzero(np.max(np.abs(uv[:, None, :] - xy[None, :, :]), axis=2) <= r)
        if len(i) == 0:
            return np.zeros((0, 2), np.int64)
        ham = popcount_sum(np.bitwise_xor(obs_desc[i], desc[j]))
        keep = ham <= self.config.max_hamming
        cand = np.stack([lm[i[keep]], j[keep], ham[keep]], axis=1)
        cand = cand[np.lexsort((cand[:, 1], cand[:, 0], cand[:, 2]))]  # best distance first
        cand = cand[np.unique(cand[:, 0], return_index=True)[1]]  # best corner per landmark
        cand = cand[np.lexsort((cand[:, 0], cand[:, 2]))]
        cand = cand[np.unique(cand[:, 1], return_index=True)[1]]  # best landmark per corner
        return cand[:, :2].astype(np.int64)

    def _solve(self, pts: np.ndarray, img: np.ndarray, status: Status, guess: np.ndarray) -> Placement | None:
        """PnP RANSAC from the predicted pose, refined on the inliers, with its covariance."""
        cTw = invert_pose(guess)
        rvec = cv2.Rodrigues(cTw[:3, :3])[0]
        tvec = cTw[:3, 3].reshape(3, 1).copy()
        cv2.setRNGSeed(int(self.pnp.seed))
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            np.ascontiguousarray(pts),
            np.ascontiguousarray(img),
            self.K,
            None,
            rvec,
            tvec,
            useExtrinsicGuess=True,
            iterationsCount=int(self.pnp.max_iters),
            reprojectionError=float(self.config.ransac_threshold_px),
            confidence=float(self.pnp.confidence),
            flags=cv2.SOLVEPNP_ITERATIVE,
        )
        if not ok or inl is None or len(inl) < self.config.min_inliers:
            return None
        inl = inl.reshape(-1)
        rvec, tvec = cv2.solvePnPRefineLM(pts[inl], img[inl], self.K, None, rvec, tvec)
        cTw = pose_from_rodrigues(rvec, tvec)
        cov = self._covariance(cTw, pts[inl])
        if cov is None:
            return None
        return Placement(status, invert_pose(cTw), cov, int(len(inl)), uv_px=img[inl])

    def _covariance(self, cTw: np.ndarray, pts: np.ndarray) -> np.ndarray | None:
        _, depth, _, J = project_jacobians(self.K, cTw, pts)
        if np.any(depth <= 0):
            return None
        return pnp_covariance(J, self.pnp)

    # ------------------------------------------------------------------ relocalisation

    def _relocalise(self, image: np.ndarray, xy: np.ndarray, desc: np.ndarray) -> Placement:
        """Place recognition on the map's keyframes, then PnP against their landmarks."""
        descriptors = self.bow_orb.detect(image).descriptors
        if descriptors is None:  # ORB's features always have theirs
            raise GraphSlamError("localize: ORB features without descriptors")
        hits = self.db.query(self.db.bow(descriptors), max_results=self.config.candidates)
        if not hits:
            return Placement("lost", None, None)
        obs = np.concatenate([self.map.keyframe_observations(k) for k, _ in hits])
        # one observation per landmark, from the best-scoring keyframe (obs are in hit order)
        obs = obs[np.sort(np.unique(self.map.obs_landmark[obs], return_index=True)[1])]
        lm = self.map.obs_landmark[obs]
        res = relative_pose_pnp(self.map.landmark_w[lm], self.map.obs_desc[obs], xy, desc, self.K, self.pnp)
        if not res.accepted:
            return Placement("lost", None, None, res.n_inliers, hits[0][0])
        return Placement(
            "relocalised",
            res.aTb,
            res.covariance,
            res.n_inliers,
            hits[0][0],
            uv_px=xy[res.inlier_pairs[:, 1]],
        )


def make_localizer(smap: SpatialMap, K: np.ndarray, config=None) -> Localizer:
    """The :class:`Localizer` of ``smap`` with the map's own corner detector and BoW ORB,
    the other settings from ``config`` (a :class:`slamcore.config.ConfigFile`: sections
    ``[localize]``, ``[loop_pnp]``, ``[harris]``, ``[orb]``), defaults without."""
    from frontend.harris import HarrisConfig
    from frontend.orb import OrbConfig
    from frontend.tracking_config import TrackerConfig, make_detector, mark_unread_detector_sections
    from slamcore.config import ConfigFile, load_section

    tracker = TrackerConfig(detector=smap.meta.get("tracker", {}).get("detector", "harris"))
    if isinstance(config, ConfigFile):
        mark_unread_detector_sections(config, tracker.detector)
    detector = make_detector(tracker, load_section(HarrisConfig, config), load_section(OrbConfig, config))
    bow_orb = OrbDetector(OrbConfig(**smap.meta["bow_orb"])) if "bow_orb" in smap.meta else None
    return Localizer(
        smap,
        K,
        detector,
        load_section(LocalizeConfig, config),
        load_section(PnpConfig, config),
        bow_orb=bow_orb,
    )
