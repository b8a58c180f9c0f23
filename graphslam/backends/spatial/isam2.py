"""The visual iSAM2 back end (3-D): Pose3 cameras, point landmarks, projection factors.

Implements :class:`slamcore.spatial.backend.VisualBackend` on ``gtsam.ISAM2``.

Graph: ``X(frame_id)`` Pose3 camera poses (``wTc``), a prior on the first,
``BetweenFactorPose3`` from odometry, ``L(track_id)`` Point3 landmarks with one
``GenericProjectionFactorCal3_S2`` per pixel under a robust noise model
(Huber by default) of the frame's ``sigma_px``.

Delayed initialisation: a track not yet in the map is buffered (its pixels and
frames) until the angle between the world rays of its first and latest
observations reaches ``min_parallax_deg`` and it has ``min_observations``
pixels. It is then triangulated (``gtsam.triangulatePoint3`` with the current
pose estimates, DLT then Gauss-Newton) and checked: in front of every
observing camera by ``min_depth_m``, every pixel reprojected within
``max_reprojection_sigmas * sigma_px``. A track that fails is dropped for good
(its pixels disagree: an outlier or a bad front-end track) and counted in
``stats["rejected_triangulations"]``. A track that passes enters as ``L(track)``
with factors for all its buffered pixels, and every later pixel adds a factor.

Incremental cost: the factors and values of a frame are buffered and handed to
``ISAM2.update`` once per frame, in :meth:`VisualIsam2Backend.predict` (the
previous frame's pixels and new landmarks, with the new pose and its
odometry factor), so that :meth:`predict_observations` reads the new pose's
marginal from iSAM2 directly. Per frame we read only what is needed: the
previous pose (to initialise the new one), the poses of the frames a
triangulated track was seen from, and the landmarks predicted in view; never
the full estimate. Landmark positions are cached in a numpy array used only to
pre-select those possibly in view (with a margin); the ones selected are read
fresh from iSAM2.

Innovation covariance (:meth:`predict_observations`): ``S = J Sigma J^T +
sigma_px^2 I`` with ``J = [d uv / d pose, d uv / d point]`` from
``PinholeCameraCal3_S2.project``. ``prediction_covariance`` chooses Sigma:

- ``"joint"``: iSAM2's exact joint marginal of the current pose and the
  predicted landmarks, one ``jointMarginalCovariance`` call per frame;
- ``"marginal"``: block-diagonal approximation, the pose marginal (once) and
  each landmark's own marginal (one ``marginalCovariance`` call each, which is
  slower than the joint call here), cross-covariance dropped. The current pose is
  localised *from* those landmarks, so their errors are positively
  correlated and dropping the cross term mostly over-states S (larger, safe
  search ellipses), more so as the map drifts away from the prior.

Both are exact reads of iSAM2's Bayes tree, no approximation of the Gaussian
itself; ``max_predictions`` caps how many landmarks are predicted (those seen
most often first, as the course advises), which bounds the per-frame cost.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from graphslam.backends import gtsam_convert as conv
from slamcore.errors import ConfigError, GraphSlamError, MeasurementError, UnsupportedError
from slamcore.spatial.records import (
    PixelObservations, PixelPredictions, PoseClosure, VisualEstimate,
)
from slamcore.spatial.backend import VisualBackend

#: The first pose's prior is floored at this standard deviation (m and rad):
#: a caller may anchor it with a zero covariance, and iSAM2's Cholesky needs a
#: proper Gaussian. 1e-4 is far below any pixel's information at VGA.
PRIOR_SIGMA_FLOOR = 1e-4


@dataclass(frozen=True)
class VisualIsam2Config:
    """Visual iSAM2 settings.

    Attributes:
        relinearize_threshold: relinearise a variable when its delta exceeds this
            (gtsam tangent units: radians / metres).
        relinearize_skip: check for relinearisation every this many updates.
        pixel_kernel: robust kernel on pixel factors, "huber", "cauchy" or "none".
            On real images wrong ZNCC matches (repeated texture) are off by many
            pixels and Huber still gives them a linear pull: on KITTI 07 frames
            0-159 (derived odometry, seeds 0-3) ATE / odometry ATE is 0.72 on
            average with Cauchy k=1 against 1.00 with Huber 1.345
            (benchmarks/kitti07_visual.toml). Huber stays the default: with
            Cauchy (not convex) the incremental estimate strays farther from
            the batch optimum between relinearisations (0.13 m against
            0.07 m in tests/test_isam2_visual.py::test_matches_batch_lm).
        pixel_kernel_k: kernel width in sigmas of the whitened pixel residual.
        min_parallax_deg: angle between the world rays of a track's first and
            latest observations before it is triangulated, degrees. It also
            guards against "parallax" made of pose error alone: a camera
            turning on the spot with drifting odometry passes 1 deg within
            30 frames in tests/test_isam2_visual.py. In forward motion with
            metric odometry (KITTI 07) 1 deg maps points near the direction of
            travel before they leave the tracker: seeds 0-3 with the Cauchy
            kernel, ATE / odometry 0.61 with 1 deg against 0.72 with 2 deg
            (benchmarks/kitti07_visual.toml).
        min_observations: pixels a track needs before it is triangulated.
        min_depth_m: a triangulated point must be at least this far in front of
            every camera that saw it.
        max_reprojection_sigmas: a triangulated point's every pixel must
            reproject within this many ``sigma_px`` (Euclidean, in the image).
        track_timeout_frames: a waiting track not seen for this many frames is
            forgotten (bounds the buffer).
        max_track_observations: buffered pixels per waiting track; beyond, the
            oldest but the first (the parallax baseline) is dropped.
        max_landmarks_per_frame: cost bound: at most this many landmarks get a
            factor per frame (those seen longest first; newly triangulated ones
            count, and wait for a later frame when the budget is spent); the
            other pixels are unused (``stats["unused_pixels"]``). 0: no bound.
        newest_pose_last: elimination ordering hint given to each update: only
            the newest pose is constrained to the root of the Bayes tree (False:
            gtsam's default, every variable of the new factors).
        prediction_covariance: "joint" or "marginal", see the module docstring.
        max_predictions: at most this many landmarks predicted per frame, those
            with most observations first; 0: all in view. The joint marginal
            costs grow with it (measured on the 300-frame benchmark scene:
            ~5 ms for 20, ~30 ms for 100 landmarks at frame 120, CPU time).
        predict_window_frames: predict only landmarks observed within this many
            frames (0: every mapped landmark in view). A window turns the map
            into a local one (visual odometry): old places are then recognised
            only through loop closures, never by re-finding their landmarks.
        loop_closure_kernel: robust kernel on loop-closure factors, "none",
            "huber" or "cauchy", so that a wrong closure cannot wreck the map.
        loop_closure_kernel_k: kernel width, in sigmas of the whitened residual.
        polish: at :meth:`VisualIsam2Backend.finalize`, run batch
            Levenberg-Marquardt on the whole graph from the incremental solution.
        polish_method: "lm", or "gnc" (gtsam's GncLMOptimizer with every factor
            but the loop closures known to be an inlier; closures it weighs
            below 0.5 are counted in ``stats["closures_dropped_by_gnc"]``).
            GNC solves with the Gaussian core of every factor (its own weights
            replace robust kernels), so the pixel factors lose their Huber
            kernel in that solve.
        polish_max_iterations: LM iteration cap for the polish.
    """

    SECTION: ClassVar[str] = "isam2_visual"
    relinearize_threshold: float = 0.1
    relinearize_skip: int = 10
    pixel_kernel: str = "huber"
    pixel_kernel_k: float = 1.345
    min_parallax_deg: float = 2.0
    min_observations: int = 3
    min_depth_m: float = 0.1
    max_reprojection_sigmas: float = 4.0
    track_timeout_frames: int = 10
    max_track_observations: int = 30
    # 0 (no bound) by default: with a bound of 40 and max_predictions = 10 the back end runs at
    # 19 frames/s on the 300-frame room (2.3 with no bound and 20 predictions), but with 5 % gross
    # outlier pixels the bound loses 1 cm of ATE (fewer landmarks). Predictions: 10 keeps the
    # joint marginal cheap; active search needs only the most informative few.
    max_landmarks_per_frame: int = 0
    newest_pose_last: bool = False
    prediction_covariance: str = "joint"
    max_predictions: int = 10
    predict_window_frames: int = 0
    loop_closure_kernel: str = "cauchy"
    loop_closure_kernel_k: float = 1.0
    polish: bool = True
    polish_method: str = "lm"
    polish_max_iterations: int = 50

    def __post_init__(self):
        if self.pixel_kernel not in conv.ROBUST_KERNELS:
            raise ConfigError("isam2_visual.pixel_kernel must be none, huber or cauchy")
        if not self.pixel_kernel_k > 0:
            raise ConfigError("isam2_visual.pixel_kernel_k must be > 0")
        if not self.relinearize_threshold > 0:
            raise ConfigError("isam2_visual.relinearize_threshold must be > 0")
        if self.relinearize_skip < 1:
            raise ConfigError("isam2_visual.relinearize_skip must be >= 1")
        if not 0 <= self.min_parallax_deg < 90:
            raise ConfigError("isam2_visual.min_parallax_deg must be in [0, 90)")
        if self.min_observations < 2:
            raise ConfigError("isam2_visual.min_observations must be >= 2 (triangulation)")
        if not self.min_depth_m > 0:
            raise ConfigError("isam2_visual.min_depth_m must be > 0")
        if not self.max_reprojection_sigmas > 0:
            raise ConfigError("isam2_visual.max_reprojection_sigmas must be > 0")
        if self.track_timeout_frames < 1:
            raise ConfigError("isam2_visual.track_timeout_frames must be >= 1")
        if self.max_track_observations < self.min_observations:
            raise ConfigError("isam2_visual.max_track_observations must be >= min_observations")
        if self.prediction_covariance not in ("joint", "marginal"):
            raise ConfigError("isam2_visual.prediction_covariance must be joint or marginal")
        if self.max_landmarks_per_frame < 0:
            raise ConfigError("isam2_visual.max_landmarks_per_frame must be >= 0 (0: no bound)")
        if self.max_predictions < 0:
            raise ConfigError("isam2_visual.max_predictions must be >= 0 (0: no cap)")
        if self.predict_window_frames < 0:
            raise ConfigError("isam2_visual.predict_window_frames must be >= 0 (0: no window)")
        if self.loop_closure_kernel not in conv.ROBUST_KERNELS:
            raise ConfigError("isam2_visual.loop_closure_kernel must be none, huber or cauchy")
        if not self.loop_closure_kernel_k > 0:
            raise ConfigError("isam2_visual.loop_closure_kernel_k must be > 0")
        if self.polish_method not in ("lm", "gnc"):
            raise ConfigError("isam2_visual.polish_method must be lm or gnc")
        if self.polish_max_iterations < 1:
            raise ConfigError("isam2_visual.polish_max_iterations must be >= 1")

    def isam2_params(self) -> gtsam.ISAM2Params:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self.relinearize_threshold)
        params.relinearizeSkip = self.relinearize_skip
        return params


@dataclass
class _Track:
    """A track waiting for parallax: its pixels, and the world ray of the first."""

    first_ray_w: np.ndarray  # (3,) unit
    frames: list[int] = field(default_factory=list)
    uv: list[np.ndarray] = field(default_factory=list)
    sigma: list[float] = field(default_factory=list)
    last_index: int = -1  # position in the frame list of the latest pixel
    queued: bool = False  # qualified: triangulated at the next frame


class VisualIsam2Backend(VisualBackend):
    """Smoothing visual back end on ``gtsam.ISAM2``; tracks give the association."""

    name = "isam2"
    has_motion_model = False
    supports_loop_closures = True

    def __init__(self, config: VisualIsam2Config | None = None):
        self.config = config or VisualIsam2Config()
        self._isam = gtsam.ISAM2(self.config.isam2_params())
        self._graph = gtsam.NonlinearFactorGraph()  # pending factors of this frame
        self._values = gtsam.Values()  # pending initial values of this frame
        self._frames: list[int] = []
        self._frame_set: set[int] = set()
        self._cal: gtsam.Cal3_S2 | None = None
        self._K = np.eye(3)
        self._K_inv = np.eye(3)
        self._size = (0, 0)
        self._tracks: dict[int, _Track] = {}  # waiting for parallax
        self._rejected: set[int] = set()  # failed triangulation: ignored from then on
        self._queued: list[int] = []  # qualified at the previous frame, see update()
        # mapped landmarks: slot per track id, numpy caches indexed by slot
        self._slot: dict[int, int] = {}
        self._lm_ids: list[int] = []
        self._lm_pos = np.zeros((0, 3))  # last read position (pre-selection only)
        self._lm_nobs = np.zeros(0, dtype=np.int64)
        self._lm_sigma = np.zeros(0)  # latest sigma_px seen
        self._lm_last = np.zeros(0, dtype=np.int64)  # index in _frames of the latest pixel
        self._closures: list[tuple[int, int, gtsam.Pose3, np.ndarray]] = []  # (a, b, aTb, cov)
        self._n_lm = 0
        self._pose_cache: dict[int, gtsam.Pose3] = {}  # valid until the next isam.update
        self._noise_cache: dict[float, gtsam.noiseModel.Base] = {}
        self._polished: gtsam.Values | None = None
        self._current_cov_polished: np.ndarray | None = None
        self._n_updates = 0
        self._stats = {"rejected_triangulations": 0, "dropped_tracks": 0, "ignored_pixels": 0,
                       "unused_pixels": 0, "loop_closures": 0}

    # --- the contract -------------------------------------------------------

    def initialize(self, frame_id, wTc, covariance, K, image_size):
        if self._frames:
            raise GraphSlamError("isam2 (visual): initialize() called twice")
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise MeasurementError(f"isam2 (visual): bad intrinsic matrix K {K.tolist()}")
        self._K, self._K_inv = K, np.linalg.inv(K)
        self._cal = conv.cal3_s2(K)
        self._size = (int(image_size[0]), int(image_size[1]))
        cov = _checked_covariance(covariance, "prior", allow_singular=True)
        cov = cov + PRIOR_SIGMA_FLOOR**2 * np.eye(6)
        fid = int(frame_id)
        self._graph.add(gtsam.PriorFactorPose3(X(fid), conv.pose3(wTc), conv.pose3_noise(cov)))
        self._values.insert(X(fid), conv.pose3(wTc))
        self._add_frame(fid)

    def predict(self, frame_id, odometry, covariance):
        if odometry is None:
            raise UnsupportedError("isam2 (visual) has no motion model of its own: "
                                   "predict() needs odometry")
        if not self._frames:
            raise GraphSlamError("isam2 (visual): predict() before initialize()")
        fid = int(frame_id)
        if fid in self._frame_set:
            raise GraphSlamError(f"isam2 (visual): frame {fid} added twice")
        odo = np.asarray(odometry, dtype=np.float64)
        if odo.shape != (4, 4) or not np.all(np.isfinite(odo)):
            raise MeasurementError(
                f"isam2 (visual): odometry to frame {fid} is not a finite (4, 4)")
        cov = _checked_covariance(covariance, f"odometry to frame {fid}")
        prev = self._frames[-1]
        delta = conv.pose3(odo)
        # initialised from the previous pose as estimated before its own
        # pixels enter (they go in with this update): iSAM2 relinearises
        self._values.insert(X(fid), self._pose(prev).compose(delta))
        self._graph.add(gtsam.BetweenFactorPose3(X(prev), X(fid), delta, conv.pose3_noise(cov)))
        self._add_frame(fid)
        self._flush()

    def update(self, observations: PixelObservations) -> None:
        if not self._frames:
            raise GraphSlamError("isam2 (visual): update() before initialize()")
        ids = np.asarray(observations.track_ids, dtype=np.int64).reshape(-1)
        uv = np.asarray(observations.uv_px, dtype=np.float64).reshape(-1, 2)
        sigma = float(observations.sigma_px)
        if len(ids) != len(uv):
            raise MeasurementError("isam2 (visual): track_ids and uv_px differ in length")
        if not (np.all(np.isfinite(uv)) and np.isfinite(sigma) and sigma > 0):
            raise MeasurementError("isam2 (visual): pixels must be finite and sigma_px > 0")
        if len(ids) == 0:
            return
        fid = self._frames[-1]
        now = len(self._frames) - 1
        noise = self._pixel_noise(sigma)
        wTc = self._pose(fid)
        R_wc = wTc.rotation().matrix()
        rays = (np.c_[uv, np.ones(len(uv))] @ self._K_inv.T) @ R_wc.T  # world ray directions
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        qualified: list[int] = []
        budget = self.config.max_landmarks_per_frame or len(ids) + len(self._queued)
        skip = set()
        mapped = [i for i, t in enumerate(ids.tolist()) if t in self._slot]
        if len(mapped) > budget:  # keep the longest-seen landmarks (best constrained)
            nobs = self._lm_nobs[[self._slot[int(ids[i])] for i in mapped]]
            order = np.lexsort((ids[mapped], -nobs))
            skip = {mapped[j] for j in order[budget:].tolist()}
            self._stats["unused_pixels"] += len(skip)
        budget -= len(mapped) - len(skip)
        for i, tid in enumerate(ids.tolist()):
            slot = self._slot.get(tid)
            if i in skip:
                continue
            if slot is not None:
                self._graph.add(gtsam.GenericProjectionFactorCal3_S2(
                    uv[i], noise, X(fid), L(tid), self._cal))
                self._lm_nobs[slot] += 1
                self._lm_sigma[slot] = sigma
                self._lm_last[slot] = now
                continue
            if tid in self._rejected:
                self._stats["ignored_pixels"] += 1
                continue
            track = self._tracks.get(tid)
            if track is None:
                track = self._tracks[tid] = _Track(first_ray_w=rays[i])
            elif track.last_index == now:  # same track twice in a frame: keep the first
                self._stats["ignored_pixels"] += 1
                continue
            track.frames.append(fid)
            track.uv.append(uv[i])
            track.sigma.append(sigma)
            track.last_index = now
            if len(track.frames) > self.config.max_track_observations:
                del track.frames[1], track.uv[1], track.sigma[1]
            if (not track.queued and len(track.frames) >= self.config.min_observations
                    and track.first_ray_w @ rays[i] <= self._cos_parallax):
                track.queued = True
                qualified.append(tid)
        # Tracks that qualified at the previous frame are triangulated now, from
        # the pixels of frames before this one: those poses have been corrected
        # by their own pixels in this frame's update, while this frame's pose is
        # still odometry alone (a few pixels off, which the consistency test
        # would take for a bad track). This frame's pixel still gets its factor.
        # New landmarks only within this frame's budget; the others wait.
        waiting = []
        for tid in self._queued:
            if tid not in self._tracks:
                continue
            if budget <= 0:
                waiting.append(tid)
                continue
            if self._triangulate(tid, self._tracks.pop(tid), fid):
                budget -= 1
        self._queued = waiting + qualified
        if now % self.config.track_timeout_frames == 0:  # amortised sweep
            self._forget_stale_tracks(now)

    def predict_observations(self) -> PixelPredictions:
        self._flush()
        if not self._frames:
            return PixelPredictions.empty()
        x_key = X(self._frames[-1])
        wTc = self._current_pose()
        # the camera even without landmarks: the front end's appearance prediction keeps it
        empty = PixelPredictions.empty(conv.pose3_matrix(wTc), self._K.copy())
        if self._n_lm == 0:
            return empty
        # pre-select on cached positions, with a margin: they may be stale
        slots = np.flatnonzero(self._in_view(wTc, self._lm_pos[:self._n_lm], margin=0.25))
        if self.config.predict_window_frames:  # before the reads: it needs no position
            recent = len(self._frames) - 1 - self._lm_last[slots] <= self.config.predict_window_frames
            slots = slots[recent]
        if len(slots) == 0:
            return empty
        for s in slots.tolist():  # fresh positions of the pre-selected only
            self._lm_pos[s] = self._point(self._lm_ids[s])
        slots = slots[self._in_view(wTc, self._lm_pos[slots], margin=0.0)]
        if self.config.max_predictions and len(slots) > self.config.max_predictions:
            order = np.lexsort((slots, -self._lm_nobs[slots]))  # most observed, then oldest
            slots = np.sort(slots[order[:self.config.max_predictions]])
        n = len(slots)
        if n == 0:
            return empty
        camera = gtsam.PinholeCameraCal3_S2(wTc, self._cal)
        joint = None
        if self._polished is None and self.config.prediction_covariance == "joint":
            # one call for the pose and all selected landmarks: the Bayes-tree
            # work is shared (one call per landmark costs nearly as much each)
            joint = self._isam.jointMarginalCovariance(
                [x_key] + [L(self._lm_ids[s]) for s in slots.tolist()])
            cov_x = joint.at(x_key, x_key)
        else:
            cov_x = self._pose_marginal(x_key)
        ids = np.empty(n, np.int64)
        uvs = np.empty((n, 2))
        S = np.empty((n, 2, 2))
        for i, s in enumerate(slots.tolist()):
            tid = self._lm_ids[s]
            D_pose = np.zeros((2, 6), order="F")
            D_point = np.zeros((2, 3), order="F")
            uvs[i] = camera.project(self._lm_pos[s], D_pose, D_point)
            if joint is not None:
                l_key = L(tid)
                cross = D_pose @ joint.at(x_key, l_key) @ D_point.T
                S_i = (D_pose @ cov_x @ D_pose.T + cross + cross.T
                       + D_point @ joint.at(l_key, l_key) @ D_point.T)
            else:
                S_i = (D_pose @ cov_x @ D_pose.T
                       + D_point @ self._point_marginal(L(tid)) @ D_point.T)
            S[i] = 0.5 * (S_i + S_i.T) + self._lm_sigma[s] ** 2 * np.eye(2)
            ids[i] = tid
        return PixelPredictions(ids, uvs, S, wTc=empty.wTc, K=empty.K, landmarks_w=self._lm_pos[slots].copy())

    def estimate(self) -> VisualEstimate:
        self._flush()
        frame_ids = np.asarray(self._frames, dtype=np.int64)
        lm_ids = np.asarray(self._lm_ids, dtype=np.int64)
        if not self._frames:
            return VisualEstimate(frame_ids, np.zeros((0, 4, 4)), lm_ids, np.zeros((0, 3)),
                                  None, self.stats())
        values = self._polished if self._polished is not None else self._isam.calculateEstimate()
        wTc = np.array([conv.pose3_matrix(values.atPose3(X(f))) for f in self._frames])
        pts = np.array([values.atPoint3(L(t)) for t in self._lm_ids]).reshape(-1, 3)
        self._lm_pos[:self._n_lm] = pts  # free refresh of the pre-selection cache
        if self._polished is not None:
            cov = self._current_cov_polished
        else:
            cov = conv.pose3_covariance_from_gtsam(
                self._isam.marginalCovariance(X(self._frames[-1])))
        return VisualEstimate(frame_ids, wTc, lm_ids, pts.copy(), cov, self.stats())

    def finalize(self) -> VisualEstimate:
        self._flush()
        if self.config.polish and self._polished is None and self._frames:
            params = gtsam.LevenbergMarquardtParams()
            params.setMaxIterations(self.config.polish_max_iterations)
            graph = self.factor_graph()
            if self.config.polish_method == "gnc" and self._closures:
                graph, self._polished = self._gnc(graph, params)
            else:
                self._polished = gtsam.LevenbergMarquardtOptimizer(
                    graph, self._isam.calculateEstimate(), params).optimize()
            # the polished pose's covariance, from a batch factorisation at the polish
            marginals = gtsam.Marginals(graph, self._polished)
            self._current_cov_polished = conv.pose3_covariance_from_gtsam(
                marginals.marginalCovariance(X(self._frames[-1])))
        return self.estimate()

    def add_loop_closure(self, closure: PoseClosure) -> None:
        """A ``BetweenFactorPose3(X(a), X(b), aTb)`` under ``loop_closure_kernel``."""
        a, b = int(closure.frame_a), int(closure.frame_b)
        for f in (a, b):
            if f not in self._frame_set:
                raise GraphSlamError(f"isam2 (visual): loop closure names unknown frame {f}")
        if a == b:
            raise MeasurementError(f"isam2 (visual): loop closure from frame {a} to itself")
        aTb = np.asarray(closure.aTb, dtype=np.float64)
        if aTb.shape != (4, 4) or not np.all(np.isfinite(aTb)):
            raise MeasurementError(f"isam2 (visual): loop closure {a}-{b} pose is not a finite (4, 4)")
        cov = _checked_covariance(closure.covariance, f"loop closure {a}-{b}")
        measured = conv.pose3(aTb)
        noise = conv.robust(conv.pose3_noise(cov), self.config.loop_closure_kernel,
                            self.config.loop_closure_kernel_k)
        self._graph.add(gtsam.BetweenFactorPose3(X(a), X(b), measured, noise))
        self._closures.append((a, b, measured, cov))
        self._stats["loop_closures"] += 1

    def landmarks_in_frame(self, frame_id: int, track_ids: np.ndarray) -> np.ndarray:
        fid = int(frame_id)
        if fid not in self._frame_set:
            raise GraphSlamError(f"isam2 (visual): unknown frame {fid}")
        ids = np.asarray(track_ids, dtype=np.int64).reshape(-1)
        out = np.full((len(ids), 3), np.nan)
        # reads go through iSAM2's current solution (pending factors stay pending)
        T = conv.pose3_matrix(self._polished.atPose3(X(fid)) if self._polished is not None
                              else self._pose(fid))
        for i, tid in enumerate(ids.tolist()):
            if tid in self._slot:
                out[i] = (self._point(tid) - T[:3, 3]) @ T[:3, :3]
        return out

    # --- extras -------------------------------------------------------------

    def stats(self) -> dict:
        """Counters: landmarks, tracks waiting, rejected triangulations, ..."""
        return {"frames": len(self._frames), "landmarks": self._n_lm,
                "tracks_waiting": len(self._tracks), **self._stats,
                "isam2_updates": self._n_updates}

    def factor_graph(self) -> gtsam.NonlinearFactorGraph:
        """All factors added so far (after flushing pending ones)."""
        self._flush()
        return gtsam.NonlinearFactorGraph(self._isam.getFactorsUnsafe())

    def error(self) -> float:
        """GTSAM graph error (robust) of the current or polished estimate."""
        self._flush()
        values = self._polished if self._polished is not None else self._isam.calculateEstimate()
        return float(self._isam.getFactorsUnsafe().error(values))

    def current_pose(self) -> np.ndarray:
        """(4, 4) latest ``wTc``, read cheaply (no full estimate)."""
        self._flush()
        return conv.pose3_matrix(self._current_pose())

    # --- internals ----------------------------------------------------------

    @property
    def _cos_parallax(self) -> float:
        return float(np.cos(np.deg2rad(self.config.min_parallax_deg)))

    def _add_frame(self, fid: int) -> None:
        self._frames.append(fid)
        self._frame_set.add(fid)

    def _pose(self, fid: int) -> gtsam.Pose3:
        """Best current value of a known pose: pending initial value, else iSAM2's."""
        key = X(fid)
        if self._values.exists(key):
            return self._values.atPose3(key)
        p = self._pose_cache.get(fid)
        if p is None:
            p = self._pose_cache[fid] = self._isam.calculateEstimatePose3(key)
        return p

    def _current_pose(self) -> gtsam.Pose3:
        key = X(self._frames[-1])
        if self._polished is not None:
            return self._polished.atPose3(key)
        return self._pose(self._frames[-1])

    def _point(self, tid: int) -> np.ndarray:
        key = L(tid)
        if self._polished is not None:
            return self._polished.atPoint3(key)
        if self._values.exists(key):
            return self._values.atPoint3(key)
        return self._isam.calculateEstimatePoint3(key)

    def _pose_marginal(self, key: int) -> np.ndarray:
        if self._polished is not None:  # gtsam order, as the Jacobians
            return conv.pose3_covariance_to_gtsam(self._current_cov_polished)
        return self._isam.marginalCovariance(key)

    def _point_marginal(self, key: int) -> np.ndarray:
        if self._polished is not None:
            return gtsam.Marginals(self.factor_graph(), self._polished).marginalCovariance(key)
        return self._isam.marginalCovariance(key)

    def _in_view(self, wTc: gtsam.Pose3, p_w: np.ndarray, margin: float) -> np.ndarray:
        """Mask of points in front (``min_depth_m``) and inside the image, grown by
        ``margin`` times its size each side (pixel centres at integers)."""
        T = conv.pose3_matrix(wTc)
        p_c = (p_w - T[:3, 3]) @ T[:3, :3]
        z = p_c[:, 2]
        front = z > self.config.min_depth_m
        with np.errstate(divide="ignore", invalid="ignore"):
            h = p_c @ self._K.T
            u, v = h[:, 0] / h[:, 2], h[:, 1] / h[:, 2]
        W, H = self._size
        mu, mv = margin * W, margin * H
        return (front & (u >= -0.5 - mu) & (u < W - 0.5 + mu)
                & (v >= -0.5 - mv) & (v < H - 0.5 + mv))

    def _pixel_noise(self, sigma: float) -> gtsam.noiseModel.Base:
        model = self._noise_cache.get(sigma)
        if model is None:
            model = conv.robust(gtsam.noiseModel.Isotropic.Sigma(2, sigma),
                                self.config.pixel_kernel, self.config.pixel_kernel_k)
            self._noise_cache[sigma] = model
        return model

    def _triangulate(self, tid: int, track: _Track, current: int) -> bool:
        """Triangulate a track from its pixels of frames other than ``current``;
        map it with factors for all its pixels, or reject it for good."""
        used = [i for i, f in enumerate(track.frames) if f != current]
        poses = [self._pose(track.frames[i]) for i in used]
        uv = np.array([track.uv[i] for i in used])
        sigma = np.array([track.sigma[i] for i in used])
        try:
            point = np.asarray(gtsam.triangulatePoint3(
                poses, self._cal, [u.reshape(2, 1) for u in uv], 1e-9, True,
                gtsam.noiseModel.Isotropic.Sigma(2, float(sigma.min())))).reshape(3)
        except RuntimeError:  # gtsam's underconstrained / cheirality exceptions
            point = None
        if (point is None or not np.all(np.isfinite(point))
                or not self._consistent(poses, uv, sigma, point)):
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

    def _consistent(self, poses, uv, sigma, point) -> bool:
        """In front of every camera by ``min_depth_m`` and every pixel reprojects
        within ``max_reprojection_sigmas``."""
        T = np.array([conv.pose3_matrix(p) for p in poses])
        p_c = np.einsum("nji,nj->ni", T[:, :3, :3], point - T[:, :3, 3])  # R^T (p - t)
        if np.any(p_c[:, 2] < self.config.min_depth_m):
            return False
        h = p_c @ self._K.T
        err = np.linalg.norm(h[:, :2] / h[:, 2:3] - uv, axis=1)
        return bool(np.all(err <= self.config.max_reprojection_sigmas * sigma))

    def _add_landmark(self, tid: int, point: np.ndarray, nobs: int, sigma: float) -> None:
        if self._n_lm == len(self._lm_pos):  # grow by doubling: amortised O(1)
            cap = max(64, 2 * self._n_lm)
            self._lm_pos = np.resize(self._lm_pos, (cap, 3))
            self._lm_nobs = np.resize(self._lm_nobs, cap)
            self._lm_sigma = np.resize(self._lm_sigma, cap)
            self._lm_last = np.resize(self._lm_last, cap)
        s = self._n_lm
        self._slot[tid] = s
        self._lm_ids.append(tid)
        self._lm_pos[s], self._lm_nobs[s], self._lm_sigma[s] = point, nobs, sigma
        self._lm_last[s] = len(self._frames) - 1
        self._n_lm += 1

    def _forget_stale_tracks(self, now: int) -> None:
        """Drop waiting tracks unseen for more than ``track_timeout_frames`` frames."""
        stale = [tid for tid, t in self._tracks.items()
                 if now - t.last_index > self.config.track_timeout_frames]
        for tid in stale:
            del self._tracks[tid]
        self._stats["dropped_tracks"] += len(stale)

    def _gnc(self, graph: gtsam.NonlinearFactorGraph, lm_params: gtsam.LevenbergMarquardtParams):
        """GNC over the whole graph, loop closures Gaussian and the only suspects."""
        keys = {(X(a), X(b)): (measured, cov) for a, b, measured, cov in self._closures}
        suspects = []
        for i in range(graph.size()):
            f = graph.at(i)
            if f is None or not isinstance(f, gtsam.BetweenFactorPose3):
                continue
            k = tuple(f.keys())
            if k in keys:  # GNC wants plain Gaussian factors: its own weights are the kernel
                measured, cov = keys[k]
                graph.replace(i, gtsam.BetweenFactorPose3(k[0], k[1], measured,
                                                          conv.pose3_noise(cov)))
                suspects.append(i)
        params = gtsam.GncLMParams(lm_params)
        suspect = set(suspects)
        params.setKnownInliers([i for i in range(graph.size()) if i not in suspect])
        optimizer = gtsam.GncLMOptimizer(graph, self._isam.calculateEstimate(), params)
        result = optimizer.optimize()
        weights = np.asarray(optimizer.getWeights())
        self._stats["closures_dropped_by_gnc"] = int(sum(weights[i] < 0.5 for i in suspects))
        return graph, result

    def _flush(self) -> None:
        if self._graph.size() == 0 and self._values.size() == 0:
            return
        # swap first: a Ctrl-C raised as update() returns must not leave the
        # factors pending, or the next flush would add them twice
        graph, values = self._graph, self._values
        self._graph, self._values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self._pose_cache.clear()
        self._polished = None  # new information invalidates a previous polish
        self._current_cov_polished = None
        self._n_updates += 1
        if self.config.newest_pose_last and self._frames:
            # Only the newest pose is forced to the root. gtsam's default forces
            # every key of the new factors there: ~all landmarks in view, which
            # makes a root clique of hundreds of dimensions, dense, re-factored
            # at every frame (and every marginal goes through it).
            groups = gtsam.KeyGroupMap()
            groups.insert2(X(self._frames[-1]), 1)
            self._isam.update(graph, values, [], groups)
        else:
            self._isam.update(graph, values)


def _checked_covariance(covariance, what: str, allow_singular: bool = False) -> np.ndarray:
    """(6, 6) finite symmetric covariance, positive definite (or semi-definite)."""
    if covariance is None:
        raise MeasurementError(f"isam2 (visual): {what} needs a (6, 6) covariance")
    cov = np.asarray(covariance, dtype=np.float64)
    if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
        raise MeasurementError(f"isam2 (visual): {what} covariance must be a finite (6, 6)")
    if not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-15):
        raise MeasurementError(f"isam2 (visual): {what} covariance is not symmetric")
    cov = 0.5 * (cov + cov.T)
    lowest = float(np.linalg.eigvalsh(cov)[0])
    if lowest < 0 and not (allow_singular and lowest > -1e-12 * max(1.0, float(np.trace(cov)))):
        raise MeasurementError(f"isam2 (visual): {what} covariance is not positive semi-definite")
    if lowest <= 0 and not allow_singular:
        raise MeasurementError(f"isam2 (visual): {what} covariance is not positive definite")
    return cov
