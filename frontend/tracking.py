"""The visual front end, one frame at a time: track ids that stay on one physical point.

Per frame (:meth:`Tracker.track`), given the image and the back end's
:class:`~slamcore.spatial.backend.PixelPredictions`:

1. **Detection**: corners by the configured detector, ``"harris"``
   (:class:`frontend.harris.HarrisDetector`), ``"orb"``
   (:class:`frontend.orb.OrbDetector`) or ``"fpga"`` (the simulated pixel-rate
   stream :class:`frontend.fpga_stream.FpgaHarrisStream`, fixed point).
2. **Active search** of the mapped landmarks (those the back end predicts),
   largest ellipse first, capped per frame (:mod:`frontend.active_search`);
   when the predictions carry the back end's ``max_corrections`` the search
   stops once that many are found, and the predicted landmarks left unsearched
   are reported (``PixelObservations.unsearched_ids``) so that the back end
   does not count them as misses.
   The matching depends on ``search`` (``"auto"`` picks by detector):
   ``"zncc"`` correlates the track's patch inside the ellipse (software
   RT-SLAM; default for Harris), ``"nearest"`` takes the Harris point nearest
   to the prediction inside the ellipse (the FPGA variant; default for
   ``fpga``), ``"descriptor"`` takes the ORB point inside the ellipse with the
   smallest Hamming distance to the track's descriptor (default for ORB).
3. **Following** of tracks not mapped yet (``follow_unmapped``): a back end
   that maps a point only once it has parallax (iSAM2 triangulates) needs the
   same id on the same point over several frames before it predicts it. Each
   such track is searched in a fixed window (``follow_window_px``) around its
   last position plus its last image velocity, by ZNCC of its patch (Harris,
   FPGA, and ORB with ``follow_by_patch``, on without odometry) or by
   descriptor among the ORB points in the window. A back end that
   initialises undelayed (the EKF) does not need this: unmapped tracks then
   live one frame, as candidates.
4. **New tracks**: detected corners at least ``min_distance_px`` from every
   tracked or predicted point, best response first, at most
   ``max_new_per_frame`` and only while fewer than ``max_tracks`` points are
   tracked (twice as many until the map starts, for a map started from two
   views without odometry), each with a fresh integer id.

Patches are cut where a track was born and kept (no drift along the track;
``patch_update = "last"`` re-cuts them at each match instead, which follows
appearance changes at the cost of slow drift).

**Appearance prediction** (``[active_search] predict_appearance``, zncc
matching): each patch is warped, before correlation, by the view change the
back end predicts between the camera it was cut in and the current one. The
predictions carry the current camera's predicted ``wTc``, ``K`` and the
landmarks' positions; where a patch is cut the tracker keeps a larger source
patch, its pixel and that frame's predicted ``wTc`` (data path and why that
pose: :mod:`frontend.appearance`). Followed unmapped tracks are not warped.
Nothing here knows 3-D but that warp: numpy and OpenCV only.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from frontend.active_search import ActiveSearch, ActiveSearchResult
from frontend.active_search_config import ActiveSearchConfig
from frontend.appearance import patch_affines, source_patch_size
from frontend.features import Features
from frontend.harris import HarrisConfig
from frontend.image import check_gray
from frontend.orb import OrbConfig
from frontend.search_matchers import extract_patches
from frontend.tracking_config import (
    CAMERA_ALONE_AIDS,
    TWO_VIEW_START_TRACKS_FACTOR,
    TrackerConfig,
    make_detector,
    search_matcher,
    search_mode_conflict,
)
from slamcore.errors import ConfigError, GraphSlamError
from slamcore.spatial.records import PixelObservations, PixelPredictions

__all__ = ["Tracker", "TrackingResult"]

#: Width the frames are reduced to before their image motion is measured, pixels
#: (PTAM's small blurry images are 80 px wide; twice that keeps a pixel's worth of
#: motion at VGA within 4 px).
IMAGE_MOTION_WIDTH_PX = 160
#: Phase-correlation peak below which the image motion is not trusted (OpenCV's
#: response is the peak's share of the correlation energy; a pure shift gives ~1,
#: a scene of independent motions a flat surface).
IMAGE_MOTION_MIN_RESPONSE = 0.1


@dataclass
class _Track:
    track_id: int
    uv: np.ndarray  # last measured pixel
    velocity: np.ndarray  # last image motion, px/frame
    born: int
    last_seen: int
    patch: np.ndarray  # (p, p) float32 (cut in every search mode)
    descriptor: np.ndarray | None  # (32,) uint8, search_mode "descriptor" only
    mapped: bool = False
    # appearance prediction only: (q, q) float32 patch around cut_uv, the pixel
    # the patch was cut around, and the predicted (4, 4) wTc of that frame
    source: np.ndarray | None = None
    cut_uv: np.ndarray | None = None
    cut_wTc: np.ndarray | None = None

    def orb_descriptor(self) -> np.ndarray:
        """The descriptor (search_mode "descriptor" keeps one for every track)."""
        if self.descriptor is None:
            raise GraphSlamError(f'track {self.track_id} has no descriptor (search_mode is not "descriptor")')
        return self.descriptor

    def cut(self) -> tuple[np.ndarray, np.ndarray]:
        """``(source, cut_uv)`` (appearance prediction keeps them for every track)."""
        if self.source is None or self.cut_uv is None:
            raise GraphSlamError(f"track {self.track_id} has no source patch (appearance prediction is off)")
        return self.source, self.cut_uv


@dataclass(frozen=True, eq=False)
class TrackingResult:
    """One frame of the front end: what goes to the back end and what Rerun draws.

    Attributes:
        observations: found landmarks, followed tracks and new tracks.
        corners: (F, 2) detected corners.
        cell_size_px: tessellation cell side of the detector (0 if none).
        pred_ids, pred_uv, pred_S: the predictions searched from (K,), (K, 2), (K, 2, 2)
            (sequential order: the re-predicted ellipse each was searched in).
        searched, found: (K,) bool per prediction; found_uv (K, 2), NaN if not found.
        gate: Mahalanobis-squared gate of the search ellipses.
        followed_ids, followed_from, followed_to: unmapped tracks followed (T,), (T, 2), (T, 2).
        new_ids, new_uv: tracks started this frame.
        image_fraction: union of the active-search ellipses' pixels / image area.
        follow_fraction: union of the follow windows / image area.
        timings_s: seconds spent in ``detect``, ``search``, ``follow``, ``new``.
    """

    observations: PixelObservations
    corners: np.ndarray
    cell_size_px: int
    pred_ids: np.ndarray
    pred_uv: np.ndarray
    pred_S: np.ndarray
    searched: np.ndarray
    found: np.ndarray
    found_uv: np.ndarray
    gate: float
    followed_ids: np.ndarray
    followed_from: np.ndarray
    followed_to: np.ndarray
    new_ids: np.ndarray
    new_uv: np.ndarray
    image_fraction: float
    follow_fraction: float
    timings_s: dict = field(default_factory=dict)

    @property
    def n_found(self) -> int:
        return int(self.found.sum())

    @property
    def n_searched(self) -> int:
        return int(self.searched.sum())


def _hamming(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamming distances between one (32,) descriptor ``a`` and (N, 32) ``b``."""
    return np.unpackbits(np.bitwise_xor(b, a[None, :]), axis=1).sum(axis=1)


def _parabola(rm: float, r0: float, rp: float) -> float:
    den = rm - 2.0 * r0 + rp
    if not den < 0.0:
        return 0.0
    return float(np.clip(0.5 * (rm - rp) / den, -0.5, 0.5))


class Tracker:
    """Stateful per-sequence tracker (see the module docstring).

    Args:
        config: :class:`TrackerConfig`.
        active_search: :class:`ActiveSearchConfig` (its ``mode`` is set from
            the tracker's search mode; ``"descriptor"`` reuses its gate and cap).
        harris, orb: detector configurations.
        follow_unmapped: overrides ``config.follow_unmapped`` (the pipeline
            passes what the back end needs); ``None`` keeps the config, and an
            unset config means True.
        camera_alone: the back end has no odometry: the aids the config leaves
            unset (:data:`~frontend.tracking_config.CAMERA_ALONE_AIDS`) are on;
            else off. With ``follow_unmapped`` too (a back end that starts its
            map from two views), up to
            :data:`~frontend.tracking_config.TWO_VIEW_START_TRACKS_FACTOR` times
            ``max_tracks`` are kept until the back end predicts a landmark.
    """

    def __init__(
        self,
        config: TrackerConfig | None = None,
        *,
        active_search: ActiveSearchConfig | None = None,
        harris: HarrisConfig | None = None,
        orb: OrbConfig | None = None,
        follow_unmapped: bool | None = None,
        camera_alone: bool = False,
    ):
        self.config = config or TrackerConfig()
        self.detector = make_detector(self.config, harris, orb)
        mode = search_matcher(self.config)
        base = active_search or ActiveSearchConfig()
        why = search_mode_conflict(self.config, base)
        if why:
            raise ConfigError(why)
        self.search_config = dataclasses.replace(base, mode=mode)
        self._search = ActiveSearch(self.search_config)
        if follow_unmapped is None:
            follow_unmapped = self.config.follow_unmapped
        self.follow_unmapped = True if follow_unmapped is None else bool(follow_unmapped)
        aid = {
            name: bool(camera_alone) if getattr(self.config, name) is None else getattr(self.config, name)
            for name in CAMERA_ALONE_AIDS
        }
        self.follow_image_motion = aid["follow_image_motion"]
        self.follow_missed_landmarks = aid["follow_missed_landmarks"]
        self.fill_first_frame = aid["fill_first_frame"]
        self.follow_recuts_patch = aid["follow_recuts_patch"]
        # Harris and the FPGA stream have no descriptor to follow by: always their patch
        self.follow_by_patch = self.config.search_mode != "descriptor" or aid["follow_by_patch"]
        # a two-view start keeps more tracks until the map starts (predictions come)
        self._start_tracks_factor = (
            TWO_VIEW_START_TRACKS_FACTOR if camera_alone and self.follow_unmapped else 1
        )
        self._tracks: dict[int, _Track] = {}
        self._next_id = 0
        self._frame = -1
        self._flow = np.zeros(2)  # median image motion of the tracks followed last frame
        self._small: np.ndarray | None = None  # last frame, reduced, for its image motion
        self._shift = np.zeros(2)  # the last trusted image motion (at the start: none, 0)
        self._hann: np.ndarray | None = None  # phase correlation's window, per reduced size
        self._jerk = np.zeros(2)  # this frame's image motion minus last frame's
        self._appearance = self.search_config.predict_appearance and mode == "zncc"
        self._view = PixelPredictions.empty()  # this frame's predictions: camera wTc and K

    @property
    def patch_size(self) -> int:
        return self.search_config.patch_size_px

    @property
    def max_tracks(self) -> int:
        """Tracks kept at most this frame: ``max_tracks``, times the two-view start's
        factor until the back end predicts a landmark."""
        return int(self.config.max_tracks) * self._start_tracks_factor

    @property
    def n_tracks(self) -> int:
        return len(self._tracks)

    def cell_size_px(self) -> int:
        cfg = getattr(self.detector, "config", None)
        return int(getattr(cfg, "cell_size_px", 0) or 0)

    # ------------------------------------------------------------------ one frame

    def track(
        self, image: np.ndarray, predictions: PixelPredictions | None = None, repredict=None
    ) -> TrackingResult:
        """Process the next frame (``image`` (H, W) uint8) given the back end's predictions.

        ``repredict``: with ``[active_search] order = "sequential"``, the back end's
        ``(track_ids (M,), uv (M, 2), pending_ids (P,)) -> (uv (P, 2), S (P, 2, 2))``:
        it corrects with the matches at once and re-predicts the landmarks still
        to search (:meth:`slamcore.spatial.backend.VisualBackend.correct_and_repredict`).
        """
        image = check_gray(image)
        cfg = self.config
        self._frame += 1
        k = self._frame
        H, W = image.shape
        timings = {}

        self._view = predictions = predictions if predictions is not None else PixelPredictions.empty()
        if len(predictions.track_ids):
            self._start_tracks_factor = 1  # the map has started
        pids, puv, pS, lm_w = self._searchable(predictions)
        t = time.perf_counter()
        if self.config.search_mode == "descriptor":
            # one ORB detection: the selected points, and the keypoints of the ellipses searched
            searched = self._search.search_order(puv, pS, image.shape)
            half = np.sqrt(self.search_config.gate * np.abs(pS[searched][:, [0, 1], [0, 1]]))
            boxes = np.hstack([puv[searched] - half, puv[searched] + half])
            feats, candidates = self.detector.detect_with_candidates(image, boxes)
        else:
            feats = candidates = self.detector.detect(image)
        if feats is None:  # an FPGA stream before its first stamp: no points yet
            feats = candidates = Features(xy_px=np.zeros((0, 2)), response=np.zeros(0))
        timings["detect"] = time.perf_counter() - t

        # ---- active search of mapped landmarks
        t = time.perf_counter()
        # a back end that corrects at most m landmarks (largest ellipses first) would
        # not use more: stop searching once m are found (paper 4.4)
        link = None
        if repredict is not None and len(pids):

            def link(found, uv, pending):  # indices of the predictions -> track ids
                return repredict(pids[found], uv, pids[pending])

        res = self._active_search(image, candidates, pids, puv, pS, predictions.max_corrections, lm_w, link)
        obs_ids: list[int] = []
        obs_uv: list[np.ndarray] = []
        for j in np.flatnonzero(res.found):
            tr = self._tracks[int(pids[j])]
            self._matched(tr, res.uv[j], image, feats, k)
            obs_ids.append(tr.track_id)
            obs_uv.append(res.uv[j].copy())
        timings["search"] = time.perf_counter() - t

        # ---- follow unmapped tracks
        t = time.perf_counter()
        f_ids, f_from, f_to, follow_fraction = self._follow(image, feats, obs_uv, k)
        obs_ids.extend(f_ids)
        obs_uv.extend(f_to)
        self._forget(k)
        timings["follow"] = time.perf_counter() - t

        # ---- new tracks away from everything tracked or predicted
        t = time.perf_counter()
        occupied = list(obs_uv)
        unfound = ~res.found
        inside = (puv[:, 0] >= 0) & (puv[:, 0] <= W - 1) & (puv[:, 1] >= 0) & (puv[:, 1] <= H - 1)
        occupied.extend(puv[unfound & inside])
        # the per-frame cap spreads the cost of new tracks over frames; a frame with no
        # track at all (the first) has nothing to spread it against, and until a two-view
        # start has its map every frame is one it may start from (fill_first_frame)
        filling = self.fill_first_frame and (not self._tracks or self._start_tracks_factor > 1)
        per_frame = self.max_tracks if filling else cfg.max_new_per_frame
        n_room = min(per_frame, max(0, self.max_tracks - len(obs_ids)))
        new_ids, new_uv = self._start_tracks(image, feats, np.array(occupied).reshape(-1, 2), n_room, k)
        obs_ids.extend(new_ids)
        obs_uv.extend(new_uv)
        timings["new"] = time.perf_counter() - t

        skipped = res.skipped if res.skipped is not None else np.zeros(len(pids), bool)
        observations = PixelObservations(
            track_ids=np.asarray(obs_ids, dtype=np.int64),
            uv_px=np.asarray(obs_uv, dtype=np.float64).reshape(-1, 2),
            sigma_px=float(cfg.sigma_px),
            unsearched_ids=pids[skipped].astype(np.int64),
        )
        return TrackingResult(
            observations=observations,
            corners=np.asarray(feats.xy_px, dtype=np.float64).reshape(-1, 2),
            cell_size_px=self.cell_size_px(),
            pred_ids=pids,
            # the ellipses searched in (sequential order: re-predicted), as documented
            pred_uv=puv if res.z is None else res.z,
            pred_S=pS if res.S is None else res.S,
            searched=res.searched,
            found=res.found,
            found_uv=res.uv,
            gate=self.search_config.gate,
            followed_ids=np.asarray(f_ids, dtype=np.int64),
            followed_from=np.asarray(f_from, dtype=np.float64).reshape(-1, 2),
            followed_to=np.asarray(f_to, dtype=np.float64).reshape(-1, 2),
            new_ids=np.asarray(new_ids, dtype=np.int64),
            new_uv=np.asarray(new_uv, dtype=np.float64).reshape(-1, 2),
            image_fraction=res.image_fraction,
            follow_fraction=follow_fraction,
            timings_s=timings,
        )

    # ------------------------------------------------------------------ stages

    def _searchable(self, predictions: PixelPredictions):
        """Predictions of tracks this tracker knows, marked mapped: ids (K,), pixels
        (K, 2), S (K, 2, 2) exactly symmetric, landmarks_w (K, 3) or None."""
        pids = np.asarray(predictions.track_ids, dtype=np.int64).reshape(-1)
        known = np.array([int(i) in self._tracks for i in pids], dtype=bool)
        pids = pids[known]
        puv = np.asarray(predictions.uv_px, dtype=np.float64).reshape(-1, 2)[known]
        pS = np.asarray(predictions.S_px2, dtype=np.float64).reshape(-1, 2, 2)[known]
        # a back end's S is symmetric up to rounding; active search wants it exactly so
        pS = 0.5 * (pS + np.swapaxes(pS, 1, 2))
        lm_w = predictions.landmarks_w
        if lm_w is not None:
            lm_w = np.asarray(lm_w, dtype=np.float64).reshape(-1, 3)[known]
        for tid in pids:
            self._tracks[int(tid)].mapped = True
        return pids, puv, pS, lm_w

    def _active_search(
        self, image, feats, pids, puv, pS, max_found=None, lm_w=None, repredict=None
    ) -> ActiveSearchResult:
        n = len(pids)
        mode = self.config.search_mode
        if n == 0:
            z = np.zeros(0)
            return ActiveSearchResult(
                order=np.zeros(0, np.int64),
                searched=z.astype(bool),
                found=z.astype(bool),
                uv=np.zeros((0, 2)),
                score=z,
                d2=z,
                pixels=z.astype(np.int64),
                image_fraction=0.0,
                image_fraction_sum=0.0,
            )
        if mode == "zncc":
            return self._zncc_search(image, pids, puv, pS, max_found, lm_w, repredict)
        if mode == "nearest":
            return self._search.search(
                image, puv, pS, features=feats, max_found=max_found, repredict=repredict
            )
        return self._descriptor_search(image.shape, feats, pids, puv, pS, max_found, repredict)

    def _descriptor_search(
        self, shape, feats, pids, puv, pS, max_found=None, repredict=None
    ) -> ActiveSearchResult:
        """ORB: the point inside the ellipse whose descriptor is closest (Hamming)."""
        g = self.search_config.gate
        fxy = np.asarray(feats.xy_px, dtype=np.float64).reshape(-1, 2)
        desc = feats.descriptors

        def closest_descriptor(i, Si, u0, v0, mask):
            if len(fxy) == 0 or desc is None:
                return None, None, None
            d = fxy - puv[i]
            dd = np.einsum("ni,ij,nj->n", d, Si, d)
            inside = np.flatnonzero(dd <= g)
            if len(inside) == 0:
                return None, None, None
            ham = _hamming(self._tracks[int(pids[i])].orb_descriptor(), desc[inside])
            j = int(np.argmin(ham))
            if ham[j] > self.config.max_hamming:
                return None, float(ham[j]), None
            return fxy[inside[j]], float(ham[j]), float(dd[inside[j]])

        return self._search.search_with(
            shape, puv, pS, closest_descriptor, max_found=max_found, repredict=repredict
        )

    def _zncc_search(self, image, pids, puv, pS, max_found, lm_w, repredict=None) -> ActiveSearchResult:
        """Patch correlation; with appearance prediction, each patch warped by the
        predicted view change since it was cut (module docstring)."""
        tracks = [self._tracks[int(i)] for i in pids]
        patches = np.stack([tr.patch for tr in tracks])
        view = self._view
        if not self._appearance or lm_w is None or view.wTc is None or view.K is None:
            return self._search.search(
                image, puv, pS, patches=patches, max_found=max_found, repredict=repredict
            )
        unknown = np.full((4, 4), np.nan)  # a patch cut without a pose: not warped
        cut_wTc = np.stack([unknown if tr.cut_wTc is None else tr.cut_wTc for tr in tracks])
        cuts = [tr.cut() for tr in tracks]
        affine = patch_affines(view.K, view.wTc, lm_w, cut_wTc, np.stack([uv for _, uv in cuts]))
        return self._search.search(
            image,
            puv,
            pS,
            patches=patches,
            affine=affine,
            max_found=max_found,
            source_patches=np.stack([source for source, _ in cuts]),
            repredict=repredict,
        )

    def _matched(self, tr: _Track, uv: np.ndarray, image, feats, k: int) -> None:
        tr.velocity = uv - tr.uv if tr.last_seen == k - 1 else np.zeros(2)
        tr.uv = np.asarray(uv, dtype=np.float64).copy()
        tr.last_seen = k
        recut = self.config.patch_update == "last" or (self.follow_recuts_patch and not tr.mapped)
        if recut and tr.patch is not None:
            tr.patch = extract_patches(image, tr.uv[None], self.patch_size)[0]
            self._remember_cut(tr, image)

    def _remember_cut(self, tr: _Track, image: np.ndarray) -> None:
        """Appearance prediction: keep, as ``tr``'s patch is cut at ``tr.uv``, a larger
        source patch there, that pixel, and this frame's predicted camera pose."""
        if not self._appearance:
            return
        tr.source = extract_patches(image, tr.uv[None], source_patch_size(self.patch_size))[0]
        tr.cut_uv = tr.uv.copy()
        wTc = self._view.wTc
        tr.cut_wTc = None if wTc is None else np.array(wTc, dtype=np.float64)

    def _follow(self, image, feats, taken: list, k: int):
        """Search each unmapped track seen last frame in its window; returns ids, from, to, fraction."""
        ids: list[int] = []
        src: list[np.ndarray] = []
        dst: list[np.ndarray] = []
        H, W = image.shape
        if not self.follow_unmapped:
            return ids, src, dst, 0.0
        if self.follow_image_motion:
            self._measure_image_motion(image)
        cfg = self.config
        half = int(cfg.follow_window_px)
        p = self.patch_size
        h = p // 2
        imf = image.astype(np.float32)
        union = np.zeros((H, W), bool)
        fxy = np.asarray(feats.xy_px, dtype=np.float64).reshape(-1, 2)
        cands = []  # (score, track, uv); best first resolves two tracks landing on one point
        for tr in list(self._tracks.values()):
            if tr.last_seen != k - 1 or (tr.mapped and not self.follow_missed_landmarks):
                continue  # (a landmark active search found this frame has last_seen == k)
            # a track born last frame has no motion of its own yet: use the image's
            c = tr.uv + (tr.velocity if tr.last_seen > tr.born or tr.mapped else self._flow) + self._jerk
            cu, cv = int(round(c[0])), int(round(c[1]))
            u0, u1 = max(cu - half, h), min(cu + half, W - 1 - h)
            v0, v1 = max(cv - half, h), min(cv + half, H - 1 - h)
            if u1 < u0 or v1 < v0:
                continue
            union[v0 : v1 + 1, u0 : u1 + 1] = True
            if not self.follow_by_patch:
                if len(fxy) == 0 or feats.descriptors is None:
                    continue
                inw = np.flatnonzero(
                    (fxy[:, 0] >= u0) & (fxy[:, 0] <= u1) & (fxy[:, 1] >= v0) & (fxy[:, 1] <= v1)
                )
                if len(inw) == 0:
                    continue
                ham = _hamming(tr.orb_descriptor(), feats.descriptors[inw])
                j = int(np.argmin(ham))
                if ham[j] > cfg.max_hamming:
                    continue
                cands.append((-float(ham[j]), tr.track_id, fxy[inw[j]].copy()))
                continue
            region = imf[v0 - h : v1 + h + 1, u0 - h : u1 + h + 1]
            r = cv2.matchTemplate(region, tr.patch, cv2.TM_CCOEFF_NORMED)
            r = np.nan_to_num(r, nan=-1.0, posinf=-1.0, neginf=-1.0)
            jv, ju = np.unravel_index(int(np.argmax(r)), r.shape)
            best = float(r[jv, ju])
            if best < cfg.follow_min_score:
                continue
            # A second peak almost as good away from the best one means a repeated
            # texture: the match is a guess, and a wrong id is worse than none.
            rr = r.copy()
            rr[max(jv - 2, 0) : jv + 3, max(ju - 2, 0) : ju + 3] = -1.0
            if rr.size and float(rr.max()) > best - cfg.follow_min_margin:
                continue
            du = dv = 0.0
            if 0 < ju < r.shape[1] - 1:
                du = _parabola(float(r[jv, ju - 1]), best, float(r[jv, ju + 1]))
            if 0 < jv < r.shape[0] - 1:
                dv = _parabola(float(r[jv - 1, ju]), best, float(r[jv + 1, ju]))
            cands.append((best, tr.track_id, np.array([u0 + ju + du, v0 + jv + dv])))
        cands.sort(key=lambda c: (-c[0], c[1]))
        moved = []
        placed = [np.asarray(u) for u in taken]
        min_sep = 3.0  # px: two ids on one spot means one of them slipped to its neighbour
        for _, tid, uv in cands:
            if placed and np.min(np.linalg.norm(np.asarray(placed) - uv, axis=1)) < min_sep:
                continue
            tr = self._tracks[tid]
            ids.append(tid)
            src.append(tr.uv.copy())
            dst.append(uv)
            placed.append(uv)
            moved.append(uv - tr.uv)
            self._matched(tr, uv, image, feats, k)
        self._flow = np.median(np.asarray(moved), axis=0) if moved else np.zeros(2)
        return ids, src, dst, float(union.sum()) / float(H * W)

    def _measure_image_motion(self, image: np.ndarray) -> None:
        """How much the whole image moved since the last frame changed from the motion
        before (``self._jerk``, px): phase correlation of the two frames reduced to
        about 160 px wide (PTAM's small blurry images, Klein & Murray 2008). A camera
        that starts to turn shifts every point at once, beyond the follow windows
        placed by each track's last motion; the windows move by this change. A weak
        correlation peak (a scene that does not move as one) changes nothing."""
        H, W = image.shape
        f = max(1, min(W // IMAGE_MOTION_WIDTH_PX, H // 2))  # a strip keeps 2 rows
        if W // f < 2 or H // f < 2:  # a Hanning window needs 2 pixels a side
            self._small, self._jerk = None, np.zeros(2)
            return
        small = cv2.GaussianBlur(
            cv2.resize(image, (W // f, H // f), interpolation=cv2.INTER_AREA).astype(np.float32), (0, 0), 1.0
        )
        prev, self._small = self._small, small
        self._jerk = np.zeros(2)
        if prev is None or prev.shape != small.shape:
            return
        if self._hann is None or self._hann.shape != small.shape:
            self._hann = cv2.createHanningWindow((small.shape[1], small.shape[0]), cv2.CV_32F)
        (du, dv), response = cv2.phaseCorrelate(prev, small, self._hann)
        if response >= IMAGE_MOTION_MIN_RESPONSE:
            shift = np.array([du, dv]) * f
            self._jerk = shift - self._shift
            # an untrusted frame leaves the last trusted motion (resetting it to 0 would
            # add the whole next motion to the tracks' own: counted twice)
            self._shift = shift

    def _forget(self, k: int) -> None:
        """Drop unmapped tracks that were lost or stayed unmapped too long."""
        age = self.config.max_unmapped_age
        for tid in [
            t.track_id
            for t in self._tracks.values()
            if not t.mapped and (t.last_seen < k or k - t.born >= age)
        ]:
            del self._tracks[tid]

    def _start_tracks(self, image, feats, occupied: np.ndarray, n_room: int, k: int):
        ids: list[int] = []
        uvs: list[np.ndarray] = []
        if n_room <= 0 or len(feats) == 0:
            return ids, uvs
        H, W = image.shape
        p = self.patch_size
        h = p // 2
        xy = np.asarray(feats.xy_px, dtype=np.float64).reshape(-1, 2)
        resp = np.asarray(feats.response, dtype=np.float64)
        ok = (xy[:, 0] >= h) & (xy[:, 0] <= W - 1 - h) & (xy[:, 1] >= h) & (xy[:, 1] <= H - 1 - h)
        # best response first; ties by position for a deterministic order
        order = np.lexsort([xy[:, 0], xy[:, 1], -resp])
        order = order[ok[order]]
        dmin2 = float(self.config.min_distance_px) ** 2
        # Distances checked in one go (not one norm per candidate): a candidate is
        # blocked by the occupied points, then by every candidate accepted before it.
        cxy = xy[order]
        orb = self.config.search_mode == "descriptor"
        by_patch = self.follow_by_patch  # a patch ZNCC could never find again is not started
        min_std = self.search_config.min_patch_std
        flat = np.zeros(len(order), bool)
        if by_patch and len(order) and np.array_equal(cxy, np.round(cxy)):
            # Harris points sit on integer pixels: every candidate's patch (the very
            # pixels getRectSubPix cuts there) and its flatness test in one gather
            off = np.arange(p) - h
            vi, ui = cxy[:, 1].astype(np.intp), cxy[:, 0].astype(np.intp)
            cand_patches = image[
                vi[:, None, None] + off[None, :, None], ui[:, None, None] + off[None, None, :]
            ].astype(np.float32)
            flat = cand_patches.reshape(len(order), p * p).astype(np.float64).std(axis=1) < min_std
        else:
            cand_patches = None
        occupied = np.asarray(occupied, dtype=np.float64).reshape(-1, 2)
        blocked = np.zeros(len(order), bool)
        for o in occupied:  # tens of points; an (F, O, 2) array would be large with ORB
            d = cxy - o
            blocked |= np.einsum("ci,ci->c", d, d) < dmin2
        for c, i in enumerate(order):
            if len(ids) >= n_room:
                break
            if blocked[c] or flat[c]:
                continue
            uv = xy[i]
            if cand_patches is not None:
                patch = cand_patches[c].copy()  # a view would keep the whole batch alive
            else:
                patch = extract_patches(image, uv[None], p)[0]
                if by_patch and float(patch.std()) < min_std:
                    continue  # flat: ZNCC could never find it again
            tid = self._next_id
            self._next_id += 1
            self._tracks[tid] = _Track(
                track_id=tid,
                uv=uv.copy(),
                velocity=np.zeros(2),
                born=k,
                last_seen=k,
                patch=patch,
                descriptor=None if not orb else np.asarray(feats.descriptors[i]).copy(),
            )
            self._remember_cut(self._tracks[tid], image)
            ids.append(tid)
            uvs.append(uv.copy())
            d = cxy - uv
            blocked |= np.einsum("ci,ci->c", d, d) < dmin2
        return ids, uvs
