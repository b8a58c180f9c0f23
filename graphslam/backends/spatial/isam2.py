"""The visual iSAM2 back end (3-D): Pose3 cameras, point landmarks, projection factors.

Implements :class:`slamcore.spatial.backend.VisualBackend` on ``gtsam.ISAM2``.
Beside it: :mod:`~graphslam.backends.spatial.isam2_config` (settings),
:mod:`~graphslam.backends.spatial.isam2_checks` (input checks),
:mod:`~graphslam.backends.spatial.landmark_init` (tracks waiting for parallax,
triangulation), and the parts it is made of, each owning its state:
:mod:`~graphslam.backends.spatial.isam2_mapping` (the tracks not yet mapped),
:mod:`~graphslam.backends.spatial.landmark_slots` (the mapped landmarks' slots),
:mod:`~graphslam.backends.spatial.isam2_ordering` (elimination ordering),
:mod:`~graphslam.backends.spatial.isam2_recovery` (an indeterminate system) and
:mod:`~graphslam.backends.spatial.polish` (GNC polish).

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
- ``"marginal"``: block-diagonal approximation, the pose marginal (once) and each landmark's
  own marginal (one ``marginalCovariance`` call each, which is slower than the joint call
  here), cross-covariance dropped. The current pose is localised *from* those landmarks, so
  their errors are positively correlated and dropping the cross term mostly over-states S
  (larger, safe search ellipses), more so as the map drifts away from the prior.

Both are exact reads of iSAM2's Bayes tree, no approximation of the Gaussian itself;
``max_predictions`` caps how many landmarks are predicted (those seen most often first, as
the course advises). What the read costs depends on where those keys sit in the tree: with
gtsam's ordering the landmarks in view share one dense clique of hundreds of variables,
which each query eliminated again (0.1-0.6 s a frame late in the 300-frame benchmark room,
more than the update itself). ``predicted_in_root`` (default) passes an ordering hint to
each update so that the previous pose, the landmarks about to be predicted and the newest
pose are eliminated last and make the root clique by themselves; the query then reads a
clique of about 50 dimensions (about 1 ms), the same numbers to rounding
(tests/graphslam/backends/test_isam2_visual.py compares them with a batch ``gtsam.Marginals``).
"""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from graphslam.backends import factorization as fact
from graphslam.backends import gtsam_convert as conv
from graphslam.backends.spatial import isam2_checks as chk
from graphslam.backends.spatial.isam2_config import VisualIsam2Config
from graphslam.backends.spatial.isam2_mapping import TrackMapper
from graphslam.backends.spatial.isam2_ordering import RootOrderingPolicy
from graphslam.backends.spatial.isam2_recovery import recover_dropping_landmarks
from graphslam.backends.spatial.landmark_init import Track, first_map_graph
from graphslam.backends.spatial.landmark_slots import LandmarkSlots
from graphslam.backends.spatial.mono_motion import MonoMotion
from graphslam.backends.spatial.polish import gnc_polish
from slamcore.errors import GraphSlamError, MeasurementError, UnsupportedError
from slamcore.spatial.backend import VisualBackend
from slamcore.spatial.records import PixelObservations, PixelPredictions, PoseClosure, VisualEstimate

#: The first pose's prior is floored at this standard deviation (m and rad):
#: a caller may anchor it with a zero covariance, and iSAM2's Cholesky needs a
#: proper Gaussian. 1e-4 is far below any pixel's information at VGA.
PRIOR_SIGMA_FLOOR = 1e-4
#: Camera alone: the standard deviation of the range factor that fixes the map's
#: scale (the bootstrap baseline = 1), in that unit: a gauge, not a measurement.
SCALE_GAUGE_SIGMA = 1e-3


class VisualIsam2Backend(VisualBackend):
    """Smoothing visual back end on ``gtsam.ISAM2``; tracks give the association."""

    name = "isam2"
    supports_loop_closures = True

    def __init__(self, config: VisualIsam2Config | None = None):
        self.config = config or VisualIsam2Config()
        #: camera alone (``robot_model = "constant_velocity"``): bootstrap, then PnP tracking
        self.has_motion_model = self.config.robot_model == "constant_velocity"
        self._mono: MonoMotion | None = None
        self._isam = gtsam.ISAM2(self.config.isam2_params())
        self._graph = gtsam.NonlinearFactorGraph()  # pending factors of this frame
        self._values = gtsam.Values()  # pending initial values of this frame
        self._frames: list[int] = []
        self._frame_set: set[int] = set()
        self._K = np.eye(3)  # the camera: placeholders until initialize()
        self._K_inv = np.eye(3)
        self._cal = conv.cal3_s2(self._K)
        self._size = (0, 0)
        self._mapper = TrackMapper(self.config)  # tracks not yet mapped
        self._lms = LandmarkSlots()  # mapped landmarks; read epochs are _epoch's
        self._ordering = RootOrderingPolicy(
            self.config.predicted_in_root, self.config.newest_pose_last, self.config.max_predictions
        )
        self._closures: list[tuple[int, int, gtsam.Pose3, np.ndarray]] = []  # (a, b, aTb, cov)
        self._pose_cache: dict[int, gtsam.Pose3] = {}  # valid until the next isam.update
        self._noise_cache: dict[float, gtsam.noiseModel.Base] = {}
        self._polished: gtsam.Values | None = None
        #: the linearisation point of an iSAM2 whose update failed beyond recovery
        self._failed_values: gtsam.Values | None = None
        self._current_cov_polished: np.ndarray | None = None
        self._n_updates = 0
        self._epoch = 0  # changes whenever the estimate can: each isam update, a polish
        self._stats = {
            "unused_pixels": 0,
            "loop_closures": 0,
            "predicted_outside_root": 0,
            "landmarks_dropped_indeterminate": 0,
        }  # after the mapper's counts

    # --- the contract -------------------------------------------------------

    def initialize(self, frame_id, wTc, covariance, K, image_size):
        if self._frames:
            raise GraphSlamError("isam2 (visual): initialize() called twice")
        K = chk.checked_intrinsics(K)
        self._K, self._K_inv = K, np.linalg.inv(K)
        self._cal = conv.cal3_s2(K)
        self._size = (int(image_size[0]), int(image_size[1]))
        cov = chk.checked_covariance(covariance, "prior", allow_singular=True)
        cov = cov + PRIOR_SIGMA_FLOOR**2 * np.eye(6)
        fid = int(frame_id)
        if self.has_motion_model:  # camera alone: no pose until the first map is made
            self._mono = MonoMotion(
                self.config.mono, K, np.asarray(wTc, dtype=np.float64), cov, self.config.seed
            )
            self._mono.next_frame(fid)
            return
        self._graph.add(gtsam.PriorFactorPose3(X(fid), conv.pose3(wTc), conv.pose3_noise(cov)))
        self._values.insert(X(fid), conv.pose3(wTc))
        self._add_frame(fid)

    def predict(self, frame_id, odometry, covariance):
        if self._mono is not None:
            self._predict_camera_only(self._mono, int(frame_id), odometry)
            return
        if odometry is None:
            raise UnsupportedError(
                "isam2 (visual) with robot_model = 'odometry' has no motion "
                "model of its own: predict() needs odometry"
            )
        if not self._frames:
            raise GraphSlamError("isam2 (visual): predict() before initialize()")
        fid = int(frame_id)
        if fid in self._frame_set:
            raise GraphSlamError(f"isam2 (visual): frame {fid} added twice")
        odo = chk.checked_transform(odometry, f"odometry to frame {fid}")
        cov = chk.checked_covariance(covariance, f"odometry to frame {fid}")
        prev = self._frames[-1]
        delta = conv.pose3(odo)
        # initialised from the previous pose as estimated before its own
        # pixels enter (they go in with this update): iSAM2 relinearises
        self._values.insert(X(fid), self._pose(prev).compose(delta))
        self._graph.add(gtsam.BetweenFactorPose3(X(prev), X(fid), delta, conv.pose3_noise(cov)))
        self._add_frame(fid)
        self._flush()

    def update(self, observations: PixelObservations) -> None:
        if self._mono is not None and not self._mono.mapped:
            ids, uv, sigma = chk.checked_pixels(observations)
            first = self._mono.bootstrap(ids, uv, sigma)
            if first is not None:
                self._start_map(self._mono, first, sigma)
            return
        if not self._frames:
            raise GraphSlamError("isam2 (visual): update() before initialize()")
        ids, uv, sigma = chk.checked_pixels(observations)
        fid = self._frames[-1]
        skip_pixels: set[int] = set()
        if self._mono is not None:
            skip_pixels = self._measure_pose(self._mono, fid, ids, uv, sigma)
        if len(ids) == 0:
            return
        now = len(self._frames) - 1
        noise = self._pixel_noise(sigma)
        wTc = self._pose(fid)
        R_wc = wTc.rotation().matrix()
        rays = (np.c_[uv, np.ones(len(uv))] @ self._K_inv.T) @ R_wc.T  # world ray directions
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        budget = self.config.max_landmarks_per_frame or len(ids) + self._mapper.n_queued
        skip, used = self._over_budget(ids, budget, skip_pixels)
        budget -= used
        lms = self._lms
        for i, tid in enumerate(ids.tolist()):
            slot = lms.slot.get(tid)
            if i in skip:
                continue
            if slot is None:  # buffered until it has parallax
                self._mapper.observe(tid, fid, uv[i], sigma, now, rays[i])
                continue
            self._graph.add(gtsam.GenericProjectionFactorCal3_S2(uv[i], noise, X(fid), L(tid), self._cal))
            lms.nobs[slot] += 1
            lms.sigma[slot] = sigma
            lms.last[slot] = now
        for tid, point, track in self._mapper.map_queued(fid, now, budget, self._pose, self._cal, self._K):
            self._map_track(tid, point, track)

    def _map_track(self, tid: int, point: np.ndarray, track: Track) -> None:
        """A triangulated track into the map, with factors for all its pixels."""
        key = L(tid)
        self._values.insert(key, point)
        for f, u, s in zip(track.frames, track.uv, track.sigma, strict=True):
            self._graph.add(
                gtsam.GenericProjectionFactorCal3_S2(u, self._pixel_noise(s), X(f), key, self._cal)
            )
        self._lms.add(tid, point, len(track.frames), track.sigma[-1], len(self._frames) - 1)

    def predict_observations(self) -> PixelPredictions:
        if self._mono is None:
            self._flush()
        elif not self._mono.mapped:  # camera alone, no map yet: nothing to predict
            return PixelPredictions.empty(None, self._K.copy())
        if not self._frames:
            return PixelPredictions.empty()
        wTc = self._current_pose()
        # the camera even without landmarks: the front end's appearance prediction keeps it
        empty = PixelPredictions.empty(conv.pose3_matrix(wTc), self._K.copy())
        if self._lms.n == 0:
            return empty
        slots = np.sort(self._select_in_view(wTc, self.config.max_predictions, margin=0.0))
        self._stats["predicted_outside_root"] += self._ordering.outside_root(slots)
        n = len(slots)
        if n == 0:
            return empty
        camera = gtsam.PinholeCameraCal3_S2(wTc, self._cal)
        x_key, A, Q = self._prediction_source()
        joint = None
        if self._polished is None and self.config.prediction_covariance == "joint":
            # one call for the pose and all selected landmarks: the Bayes-tree
            # work is shared (one call per landmark costs nearly as much each)
            joint = self._isam.jointMarginalCovariance(
                [x_key] + [L(self._lms.ids[s]) for s in slots.tolist()]
            )
            cov_x = A @ joint.at(x_key, x_key) @ A.T + Q
        else:
            cov_x = A @ self._pose_marginal(x_key) @ A.T + Q
        ids = np.empty(n, np.int64)
        uvs = np.empty((n, 2))
        S = np.empty((n, 2, 2))
        for i, s in enumerate(slots.tolist()):
            tid = self._lms.ids[s]
            D_pose = np.zeros((2, 6), order="F")
            D_point = np.zeros((2, 3), order="F")
            uvs[i] = camera.project(self._lms.pos[s], D_pose, D_point)
            if joint is not None:
                l_key = L(tid)
                cross = D_pose @ A @ joint.at(x_key, l_key) @ D_point.T
                S_i = (
                    D_pose @ cov_x @ D_pose.T + cross + cross.T + D_point @ joint.at(l_key, l_key) @ D_point.T
                )
            else:
                S_i = D_pose @ cov_x @ D_pose.T + D_point @ self._point_marginal(L(tid)) @ D_point.T
            S[i] = 0.5 * (S_i + S_i.T) + self._lms.sigma[s] ** 2 * np.eye(2)
            ids[i] = tid
        return PixelPredictions(
            ids, uvs, S, wTc=empty.wTc, K=empty.K, landmarks_w=self._lms.pos[slots].copy()
        )

    def _prediction_source(self) -> tuple[int, np.ndarray, np.ndarray]:
        """``(key, A, Q)``: the current pose is ``A`` times the perturbation of pose
        ``key`` in iSAM2 plus noise ``Q`` (gtsam's ``[phi, rho]`` order): the pose
        itself with odometry; camera alone, the last measured pose moved by the
        constant-velocity step ``delta`` (not yet in iSAM2): ``A = Ad(delta^-1)``."""
        if self._mono is None or not self._mono.awaiting:
            return X(self._frames[-1]), np.eye(6), np.zeros((6, 6))
        A = conv.pose3(self._mono.delta).inverse().AdjointMap()
        return (X(self._frames[-2]), A, conv.pose3_covariance_to_gtsam(self._mono.covariance))

    def estimate(self) -> VisualEstimate:
        if self._failed_values is None:  # a failed iSAM2 takes no more updates
            self._flush()
        frame_ids = np.asarray(self._frames, dtype=np.int64)
        lm_ids = np.asarray(self._lms.ids, dtype=np.int64)
        if not self._frames:
            return VisualEstimate(
                frame_ids, np.zeros((0, 4, 4)), lm_ids, np.zeros((0, 3)), None, self.stats()
            )
        if self._failed_values is not None:  # an update failed for good: no solve, no covariance
            values = self._failed_values
            wTc = np.array([conv.pose3_matrix(values.atPose3(X(f))) for f in self._frames])
            pts = np.array([values.atPoint3(L(t)) for t in self._lms.ids]).reshape(-1, 3)
            return VisualEstimate(frame_ids, wTc, lm_ids, pts, None, self.stats())
        values = self._polished if self._polished is not None else self._isam.calculateEstimate()
        wTc = np.array([conv.pose3_matrix(values.atPose3(X(f))) for f in self._frames])
        pts = np.array([values.atPoint3(L(t)) for t in self._lms.ids]).reshape(-1, 3)
        self._lms.pos[: self._lms.n] = pts  # free refresh of the pre-selection cache
        self._lms.read[: self._lms.n] = self._epoch
        if self._polished is not None:
            cov = self._current_cov_polished
        else:
            cov = conv.pose3_covariance_from_gtsam(self._isam.marginalCovariance(X(self._frames[-1])))
        return VisualEstimate(frame_ids, wTc, lm_ids, pts.copy(), cov, self.stats())

    def finalize(self) -> VisualEstimate:
        if self._mono is not None and not self._mono.mapped:
            raise GraphSlamError(
                "isam2 (visual): monocular tracking never started: no two frames "
                f"gave a first map ({self._mono.bootstrap_reason}); {self._mono.bootstrap_remedy}"
            )
        self._flush()
        if self.config.polish and self._polished is None and self._frames:
            params = gtsam.LevenbergMarquardtParams()
            params.setMaxIterations(self.config.polish_max_iterations)
            graph = self.factor_graph()
            if self.config.polish_method == "gnc" and self._closures:
                graph, polished, dropped = gnc_polish(
                    graph, self._isam.calculateEstimate(), self._closures, params
                )
                self._stats["closures_dropped_by_gnc"] = dropped
            else:
                polished = gtsam.LevenbergMarquardtOptimizer(
                    graph, self._isam.calculateEstimate(), params
                ).optimize()
            self._polished = polished
            self._current_cov_polished = conv.pose3_covariance_from_gtsam(
                self._polished_pose_covariance(graph, polished, X(self._frames[-1]))
            )
            self._epoch += 1
        return self.estimate()

    def _polished_pose_covariance(
        self, graph: gtsam.NonlinearFactorGraph, polished: gtsam.Values, key: int
    ) -> np.ndarray:
        """The last pose's covariance from a batch factorisation at the polish; where
        that Cholesky meets an indeterminate system (a landmark the polish left barely
        constrained, e.g. seen from two close frames), iSAM2's own marginal, counted
        in ``stats()["pose_covariance_from_isam2"]``: the run keeps its estimate."""
        try:
            return gtsam.Marginals(graph, polished).marginalCovariance(key)
        except RuntimeError as exc:
            if not fact.is_indeterminate(exc):
                raise
        self._stats["pose_covariance_from_isam2"] = 1
        return self._isam.marginalCovariance(key)

    def add_loop_closure(self, closure: PoseClosure) -> None:
        """A ``BetweenFactorPose3(X(a), X(b), aTb)`` under ``loop_closure_kernel``."""
        a, b = int(closure.frame_a), int(closure.frame_b)
        for f in (a, b):
            if f not in self._frame_set:
                raise GraphSlamError(f"isam2 (visual): loop closure names unknown frame {f}")
        if a == b:
            raise MeasurementError(f"isam2 (visual): loop closure from frame {a} to itself")
        aTb = chk.checked_transform(closure.aTb, f"loop closure {a}-{b} pose")
        cov = chk.checked_covariance(closure.covariance, f"loop closure {a}-{b}")
        measured = conv.pose3(aTb)
        noise = conv.robust(
            conv.pose3_noise(cov), self.config.loop_closure_kernel, self.config.loop_closure_kernel_k
        )
        self._graph.add(gtsam.BetweenFactorPose3(X(a), X(b), measured, noise))
        self._closures.append((a, b, measured, cov))
        self._stats["loop_closures"] += 1

    def has_pose(self, frame_id: int) -> bool:
        return int(frame_id) in self._frame_set

    def coasting(self) -> bool:
        return self._mono is not None and self._mono.coasting

    def landmarks_in_frame(self, frame_id: int, track_ids: np.ndarray) -> np.ndarray:
        fid = int(frame_id)
        if fid not in self._frame_set:
            raise GraphSlamError(f"isam2 (visual): unknown frame {fid}")
        ids = np.asarray(track_ids, dtype=np.int64).reshape(-1)
        out = np.full((len(ids), 3), np.nan)
        # reads go through iSAM2's current solution (pending factors stay pending)
        T = conv.pose3_matrix(
            self._polished.atPose3(X(fid)) if self._polished is not None else self._pose(fid)
        )
        for i, tid in enumerate(ids.tolist()):
            if tid in self._lms.slot:
                out[i] = (self._point(tid) - T[:3, 3]) @ T[:3, :3]
        return out

    # --- extras -------------------------------------------------------------

    def stats(self) -> dict:
        """Counters: landmarks, tracks waiting, rejected triangulations, ..."""
        out: dict[str, object] = {
            "frames": len(self._frames),
            "landmarks": self._lms.n,
            "tracks_waiting": len(self._mapper.tracks),
            **self._mapper.counts,
            **self._stats,
            "isam2_updates": self._n_updates,
        }
        if self._mono is not None:
            out["camera_alone"] = self._mono.stats()
        return out

    def factor_graph(self) -> gtsam.NonlinearFactorGraph:
        """All factors added so far (after flushing pending ones)."""
        self._flush()
        return gtsam.NonlinearFactorGraph(self._isam.getFactorsUnsafe())

    def bundle(self) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """All factors added so far and the estimate (polished once polished) they are
        read at: the bundle adjustment a calibration refines
        (:mod:`~graphslam.backends.spatial.self_calibration`)."""
        graph = self.factor_graph()
        return graph, self._polished if self._polished is not None else self._isam.calculateEstimate()

    def error(self) -> float:
        """GTSAM graph error (robust) of the current or polished estimate."""
        self._flush()
        values = self._polished if self._polished is not None else self._isam.calculateEstimate()
        return float(self._isam.getFactorsUnsafe().error(values))

    def current_pose(self) -> np.ndarray:
        """(4, 4) latest ``wTc``, read cheaply (no full estimate)."""
        self._flush()
        return conv.pose3_matrix(self._current_pose())

    # --- camera alone (robot_model = "constant_velocity") ----------------------

    def _predict_camera_only(self, mono: MonoMotion, fid: int, odometry) -> None:
        """The frame's pose at constant velocity from the last two (pending, without
        factors until :meth:`update` measures it); nothing before the first map."""
        if odometry is not None:
            raise UnsupportedError(
                "isam2 (visual) with robot_model = 'constant_velocity' tracks "
                "by the camera alone: it takes no odometry"
            )
        if fid in self._frame_set or fid == mono.frame_id:
            raise GraphSlamError(f"isam2 (visual): frame {fid} added twice")
        mono.next_frame(fid)
        if not mono.mapped:
            return
        self._flush()
        before, last = self._frames[-2], self._frames[-1]
        wTc_pred = mono.predict(conv.pose3_matrix(self._pose(before)), conv.pose3_matrix(self._pose(last)))
        self._values.insert(X(fid), conv.pose3(wTc_pred))
        self._add_frame(fid)

    def _measure_pose(
        self, mono: MonoMotion, fid: int, ids: np.ndarray, uv: np.ndarray, sigma: float
    ) -> set[int]:
        """PnP on the mapped landmarks among the frame's pixels: the pose then
        replaces the prediction, and the rows of ``ids`` PnP rejects are returned
        (they get no factor). Too few inliers: the frame is coasted on a
        constant-velocity factor and keeps only the pixels the prediction explains."""
        rows = np.array([i for i, t in enumerate(ids.tolist()) if t in self._lms], dtype=np.int64)
        points = np.array([self._point(int(ids[i])) for i in rows.tolist()]).reshape(-1, 3)
        predicted = conv.pose3_matrix(self._values.atPose3(X(fid)))
        est = mono.measure(points, uv[rows], predicted, sigma, ids, uv)
        wTc = est.wTc if est.wTc is not None else est.wTc_coast
        if wTc is None:  # measure() gives a frame it coasts its wTc_coast
            raise GraphSlamError(f"isam2 (visual): frame {fid} has neither a PnP nor a coasted pose")
        self._values.update(X(fid), conv.pose3(wTc))
        if est.wTc is None:
            self._add_coasting_factor(mono, fid)
        return set(rows[~est.inliers].tolist())

    def _add_coasting_factor(self, mono: MonoMotion, fid: int) -> None:
        self._graph.add(
            gtsam.BetweenFactorPose3(
                X(self._frames[-2]), X(fid), conv.pose3(mono.delta), conv.pose3_noise(mono.covariance)
            )
        )

    def _start_map(self, mono: MonoMotion, first, sigma: float) -> None:
        """The bootstrap's map into the graph (:func:`.landmark_init.first_map_graph`)."""
        graph, values, landmarks = first_map_graph(
            first,
            mono.wTc0,
            conv.pose3_noise(mono.prior_covariance),
            self._cal,
            self._pixel_noise(sigma),
            SCALE_GAUGE_SIGMA,
        )
        self._graph.push_back(graph)
        self._values.insert(values)
        for f in first.frame_ids.tolist():
            self._add_frame(int(f))
        for tid, p_w, nobs in landmarks:
            self._lms.add(tid, p_w, nobs, sigma, len(self._frames) - 1)

    # --- internals ----------------------------------------------------------

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
            if self._current_cov_polished is None:
                raise GraphSlamError("isam2 (visual): polished estimate without its covariance")
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
        return front & (u >= -0.5 - mu) & (u < W - 0.5 + mu) & (v >= -0.5 - mv) & (v < H - 0.5 + mv)

    def _pixel_noise(self, sigma: float) -> gtsam.noiseModel.Base:
        model = self._noise_cache.get(sigma)
        if model is None:
            model = conv.robust(
                gtsam.noiseModel.Isotropic.Sigma(2, sigma),
                self.config.pixel_kernel,
                self.config.pixel_kernel_k,
            )
            self._noise_cache[sigma] = model
        return model

    def _over_budget(
        self, ids: np.ndarray, budget: int, rejected: set[int] | frozenset[int] = frozenset()
    ) -> tuple[set[int], int]:
        """Rows of ``ids`` whose landmark gets no factor this frame (``rejected`` ones,
        then those beyond ``budget``), and how many mapped landmarks do get one."""
        skip = set(rejected)
        mapped = [i for i, t in enumerate(ids.tolist()) if t in self._lms.slot and i not in skip]
        over: set[int] = set()
        if len(mapped) > budget:  # keep the longest-seen landmarks (best constrained)
            nobs = self._lms.nobs[[self._lms.slot[int(ids[i])] for i in mapped]]
            order = np.lexsort((ids[mapped], -nobs))
            over = {mapped[j] for j in order[budget:].tolist()}
            self._stats["unused_pixels"] += len(over)
            skip |= over
        return skip, len(mapped) - len(over)

    def _select_in_view(self, wTc: gtsam.Pose3, count: int, margin: float) -> np.ndarray:
        """Slots of the mapped landmarks in view of ``wTc`` (positions read fresh; the
        image grown by ``margin`` of its size each side), at most ``count`` of them (0:
        all), the most observed first, then the oldest, in that order."""
        # pre-select on cached positions, with a margin: they may be stale
        slots = np.flatnonzero(self._in_view(wTc, self._lms.pos[: self._lms.n], margin=0.25))
        if self.config.predict_window_frames:  # before the reads: it needs no position
            age = len(self._frames) - 1 - self._lms.last[slots]
            recent = age <= self.config.predict_window_frames
            slots = slots[recent]
        # fresh positions of the pre-selected only, and only those not yet read at this
        # estimate (the hint before an update and the predictions after it read the same
        # landmarks once each frame: same numbers, half the reads)
        stale = slots[self._lms.read[slots] != self._epoch]
        for s in stale.tolist():
            self._lms.pos[s] = self._point(self._lms.ids[s])
        self._lms.read[stale] = self._epoch
        slots = slots[self._in_view(wTc, self._lms.pos[slots], margin=margin)]
        order = np.lexsort((slots, -self._lms.nobs[slots]))  # most observed, then oldest
        return slots[order[:count] if count else order]

    def _flush(self) -> None:
        if self._mono is not None and self._mono.awaiting:
            # read before its pixels (a Ctrl-C between predict and update): the
            # frame keeps its constant-velocity prediction, so iSAM2 can take it
            self._mono.coast("interrupted before the frame was measured")
            self._add_coasting_factor(self._mono, self._frames[-1])
        if self._graph.size() == 0 and self._values.size() == 0:
            return
        # before the swap: it reads the pending values
        groups, reelim = self._ordering.hint(self._frames, self._graph, self._lms.ids, self._select_for_root)
        # swap first: a Ctrl-C raised as update() returns must not leave the
        # factors pending, or the next flush would add them twice
        graph, values = self._graph, self._values
        self._graph, self._values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self._pose_cache.clear()
        self._polished = None  # new information invalidates a previous polish
        self._epoch += 1
        self._current_cov_polished = None
        self._n_updates += 1
        try:
            if groups is not None:
                self._isam.update(graph, values, [], groups, None, reelim)
            else:
                self._isam.update(graph, values)
        except RuntimeError as exc:
            failed = self._isam
            try:
                self._isam = recover_dropping_landmarks(
                    exc, failed, self.config, self._lms, self._drop_landmark, self._frames[-1]
                )
            except GraphSlamError:
                # The run ends here (the pipeline's BackendFailed); what it estimated so
                # far is kept for its files: the values iSAM2 last linearised at (every
                # frame's pose, the new one at its prediction), since the failed iSAM2
                # can no longer solve.
                self._failed_values = gtsam.Values(failed.getLinearizationPoint())
                if values.exists(X(self._frames[-1])):  # the frame this update added is not done
                    self._frame_set.discard(self._frames.pop())
                raise

    def _select_for_root(self, count: int, margin: float) -> np.ndarray:
        """:meth:`_select_in_view` at the newest pose (the ordering hint's candidates)."""
        return self._select_in_view(self._pose(self._frames[-1]), count, margin=margin)

    def _drop_landmark(self, tid: int) -> None:
        """Forget landmark ``tid`` (gtsam found it indeterminate): its slot goes and its
        track is ignored from then on."""
        self._lms.drop(tid)
        self._ordering.forget_root()
        self._mapper.reject(tid)
        self._stats["landmarks_dropped_indeterminate"] += 1
