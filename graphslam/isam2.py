"""The iSAM2 back end (2-D): Pose2 poses, bearing-range landmarks, between factors.

Incremental use, as iSAM2 wants it: the factors and initial values of one
frame are buffered and handed to ``ISAM2.update`` once, when the next frame
starts or an answer is asked for. Per step we only read the one pose needed to
initialise the next (``calculateEstimate(key)``), never the full estimate, so
the per-step cost does not grow with the run. Full estimates, marginals and the
optional final batch Levenberg-Marquardt polish are on request.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import ClassVar

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from graphslam import gtsam_convert as conv
from graphslam.backend import Backend
from graphslam.errors import ConfigError, GraphSlamError
from graphslam.types import Estimate, LoopClosure, Observation, Odometry, Prediction


@dataclass(frozen=True)
class Isam2Config:
    """iSAM2 settings.

    Attributes:
        relinearize_threshold: relinearise a variable when its delta exceeds this
            (gtsam units: metres / radians of the tangent vector).
        relinearize_skip: check for relinearisation every this many updates.
        polish: run batch Levenberg-Marquardt on the whole graph at the end,
            starting from the incremental solution.
        polish_max_iterations: LM iteration cap for the polish.
        loop_closure_kernel: robust kernel on loop-closure factors, "none",
            "huber" or "cauchy", so one wrong closure cannot wreck the map.
            Dataset edges that are loop closures get it too.
        loop_closure_kernel_k: kernel width, in sigmas of the whitened residual.
        polish_method: "lm" (Levenberg-Marquardt on the graph as built) or
            "gnc" (graduated non-convexity, gtsam's GncLMOptimizer, with every
            factor but the loop closures known to be an inlier).
    """

    SECTION: ClassVar[str] = "isam2"
    relinearize_threshold: float = 0.1
    relinearize_skip: int = 10
    polish: bool = True
    polish_max_iterations: int = 100
    loop_closure_kernel: str = "none"
    loop_closure_kernel_k: float = 1.0
    polish_method: str = "lm"

    def __post_init__(self):
        if self.loop_closure_kernel not in ("none", "huber", "cauchy"):
            raise ConfigError("isam2.loop_closure_kernel must be none, huber or cauchy")
        if self.loop_closure_kernel_k <= 0:
            raise ConfigError("isam2.loop_closure_kernel_k must be > 0")
        if self.polish_method not in ("lm", "gnc"):
            raise ConfigError("isam2.polish_method must be lm or gnc")
        if self.relinearize_threshold <= 0:
            raise ConfigError("isam2.relinearize_threshold must be > 0")
        if self.relinearize_skip < 1:
            raise ConfigError("isam2.relinearize_skip must be >= 1")
        if self.polish_max_iterations < 1:
            raise ConfigError("isam2.polish_max_iterations must be >= 1")

    def loop_closure_noise(self, covariance: np.ndarray) -> gtsam.noiseModel.Base:
        """Gaussian noise of a closure, wrapped in the configured robust kernel."""
        gaussian = conv.noise_from_covariance(covariance)
        if self.loop_closure_kernel == "none":
            return gaussian
        kernel = {"huber": gtsam.noiseModel.mEstimator.Huber,
                  "cauchy": gtsam.noiseModel.mEstimator.Cauchy}[self.loop_closure_kernel]
        return gtsam.noiseModel.Robust.Create(kernel.Create(self.loop_closure_kernel_k), gaussian)

    def isam2_params(self) -> gtsam.ISAM2Params:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self.relinearize_threshold)
        params.relinearizeSkip = self.relinearize_skip
        return params


class Isam2Backend(Backend):
    """Smoothing back end on ``gtsam.ISAM2``; uses known data association."""

    name = "isam2"
    supports_loop_closures = True

    def __init__(self, config: Isam2Config | None = None):
        self.config = config or Isam2Config()
        self._isam = gtsam.ISAM2(self.config.isam2_params())
        self._graph = gtsam.NonlinearFactorGraph()  # pending factors of this frame
        self._values = gtsam.Values()  # pending initial values of this frame
        self._pose_ids: list[int] = []
        self._pose_set: set[int] = set()
        self._landmark_ids: list[int] = []
        self._landmark_set: set[int] = set()
        self._last_associations = []
        self._measurement_cov: dict[int, np.ndarray] = {}  # last R seen per landmark
        self._polished: gtsam.Values | None = None
        self._n_factors = 0  # factors handed to iSAM2 or pending, in insertion order
        self._loop_closures: dict[int, LoopClosure] = {}  # factor index -> closure

    # --- the contract -------------------------------------------------------

    def initialize(self, pose_id, wTb, covariance):
        if self._pose_ids:
            raise GraphSlamError("isam2: initialize() called twice")
        self._graph.add(conv.prior_factor(pose_id, wTb, covariance))
        self._values.insert(X(pose_id), conv.pose2(wTb))
        self._add_pose_id(pose_id)

    def predict(self, odometry: Odometry, pose_id: int) -> None:
        self._flush()
        if pose_id in self._pose_set:
            raise GraphSlamError(f"isam2: pose {pose_id} added twice")
        if odometry.to_id == pose_id and odometry.from_id in self._pose_set:
            wTb = self._pose(odometry.from_id).compose(conv.pose2(odometry.delta))
        elif odometry.from_id == pose_id and odometry.to_id in self._pose_set:
            wTb = self._pose(odometry.to_id).compose(conv.pose2(odometry.delta).inverse())
        else:
            raise GraphSlamError(
                f"isam2: odometry {odometry.from_id}->{odometry.to_id} does not link new pose "
                f"{pose_id} to a known pose")
        self._graph.add(conv.between_factor(odometry))
        self._values.insert(X(pose_id), wTb)
        self._add_pose_id(pose_id)

    def update(self, observations: Sequence[Observation]) -> None:
        assoc: list[int | None] = []
        for obs in observations:
            if obs.landmark_id is None:
                # iSAM2 here needs known association; unknown ones are skipped, and reported.
                assoc.append(None)
                continue
            if obs.pose_id not in self._pose_set:
                raise GraphSlamError(f"isam2: observation from unknown pose {obs.pose_id}")
            lid = obs.landmark_id
            if lid not in self._landmark_set:
                wTb = self._pose(obs.pose_id)
                r, b = obs.z
                self._values.insert(L(lid), wTb.transformFrom(np.array([r * np.cos(b), r * np.sin(b)])))
                self._landmark_ids.append(lid)
                self._landmark_set.add(lid)
            self._graph.add(conv.bearing_range_factor(obs, lid))
            self._measurement_cov[lid] = obs.covariance
            assoc.append(lid)
        self._last_associations = assoc

    def add_loop_closure(self, loop_closure: LoopClosure) -> None:
        for pid in (loop_closure.from_id, loop_closure.to_id):
            if pid not in self._pose_set:
                raise GraphSlamError(f"isam2: loop closure refers to unknown pose {pid}")
        self._loop_closures[self._n_factors + self._graph.size()] = loop_closure
        self._graph.add(conv.between_factor(loop_closure,
                                            self.config.loop_closure_noise(loop_closure.covariance)))

    def predict_observations(self, landmark_ids: Iterable[int]) -> list[Prediction]:
        """Predicted ``[range, bearing]`` and ``S = H P H^T + R`` for known landmarks.

        ``P`` is the exact joint marginal of (current pose, landmark), cross
        terms included. gtsam's Python ISAM2 exposes only single-key
        marginals, so this builds one batch ``Marginals`` per call: meant for
        gating and active search on small maps, not for every step of a long run.
        """
        self._flush()
        wanted = [lid for lid in landmark_ids if lid in self._landmark_set]
        if not self._pose_ids or not wanted:
            return []
        x_key = X(self._pose_ids[-1])
        values = self._values_now()
        marginals = gtsam.Marginals(self.factor_graph(), values)
        wTb = values.atPose2(x_key)
        out = []
        for lid in wanted:
            l_key = L(lid)
            m = values.atPoint2(l_key)
            P = marginals.jointMarginalCovariance(gtsam.KeyVector([x_key, l_key])).fullMatrix()
            H_b_x, H_b_m = np.zeros((1, 3), order="F"), np.zeros((1, 2), order="F")
            H_r_x, H_r_m = np.zeros((1, 3), order="F"), np.zeros((1, 2), order="F")
            bearing = wTb.bearing(m, H_b_x, H_b_m).theta()
            range_m = wTb.range(m, H_r_x, H_r_m)
            H = np.block([[H_r_x, H_r_m], [H_b_x, H_b_m]])  # rows [range, bearing]
            R = self._measurement_cov.get(lid, np.zeros((2, 2)))
            out.append(Prediction(lid, np.array([range_m, bearing]), H @ P @ H.T + R))
        return out

    def estimate(self, with_covariances: bool = False) -> Estimate:
        values = self._values_now()
        est = conv.values_to_estimate(values, self._pose_ids, self._landmark_ids)
        if not with_covariances:
            return est
        marginals = self._marginals(values)
        pcov = np.array([marginals.marginalCovariance(X(i)) for i in self._pose_ids]).reshape(-1, 3, 3)
        lcov = np.array([marginals.marginalCovariance(L(j)) for j in self._landmark_ids]).reshape(-1, 2, 2)
        return Estimate(est.pose_ids, est.wTb, est.landmark_ids, est.landmarks_w, pcov, lcov)

    def finalize(self, with_covariances: bool = False) -> Estimate:
        self._flush()
        if self.config.polish and self._polished is None and self._pose_ids:
            params = gtsam.LevenbergMarquardtParams()
            params.setMaxIterations(self.config.polish_max_iterations)
            initial = self._isam.calculateEstimate()
            if self.config.polish_method == "gnc" and self._loop_closures:
                self._polished = self._gnc(params, initial)
            else:
                self._polished = gtsam.LevenbergMarquardtOptimizer(
                    self.factor_graph(), initial, params).optimize()
        return self.estimate(with_covariances=with_covariances)

    def current_pose_covariance(self) -> np.ndarray | None:
        self._flush()
        if not self._pose_ids:
            return None
        return np.asarray(self._isam.marginalCovariance(X(self._pose_ids[-1])))

    # --- extras -------------------------------------------------------------

    def factor_graph(self) -> gtsam.NonlinearFactorGraph:
        """All factors added so far (after flushing pending ones)."""
        self._flush()
        return gtsam.NonlinearFactorGraph(self._isam.getFactorsUnsafe())

    def error(self) -> float:
        """GTSAM graph error of the current (or polished) estimate under the added factors."""
        values = self._values_now()
        return float(self.factor_graph().error(values))

    def current_pose(self) -> np.ndarray:
        """(3,) latest pose, read cheaply (no full estimate)."""
        self._flush()
        key = X(self._pose_ids[-1])
        if self._polished is not None:
            return conv.pose2_vector(self._polished.atPose2(key))
        return conv.pose2_vector(self._isam.calculateEstimatePose2(key))

    # --- internals ----------------------------------------------------------

    def _add_pose_id(self, pose_id: int) -> None:
        self._pose_ids.append(pose_id)
        self._pose_set.add(pose_id)

    def _pose(self, pose_id: int) -> gtsam.Pose2:
        """Best current value of a known pose: pending initial value, else iSAM2's."""
        key = X(pose_id)
        if self._values.exists(key):
            return self._values.atPose2(key)
        return self._isam.calculateEstimatePose2(key)

    def _gnc(self, lm_params: gtsam.LevenbergMarquardtParams, initial: gtsam.Values) -> gtsam.Values:
        """GNC over the graph with Gaussian closures; all other factors are known inliers."""
        graph = self.factor_graph()
        for index, lc in self._loop_closures.items():  # GNC wants plain Gaussian factors
            graph.replace(index, conv.between_factor(lc))
        params = gtsam.GncLMParams(lm_params)
        params.setKnownInliers([i for i in range(graph.size()) if i not in self._loop_closures])
        return gtsam.GncLMOptimizer(graph, initial, params).optimize()

    def _values_now(self) -> gtsam.Values:
        """The estimate answers are given from: the polish if current, else iSAM2's."""
        self._flush()
        return self._polished if self._polished is not None else self._isam.calculateEstimate()

    def _flush(self) -> None:
        if self._graph.size() == 0 and self._values.size() == 0:
            return
        # swap first: a Ctrl-C raised as update() returns must not leave the
        # factors pending, or the next flush would add them twice
        graph, values = self._graph, self._values
        self._graph, self._values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self._n_factors += graph.size()
        self._polished = None  # new information invalidates a previous polish
        self._isam.update(graph, values)

    def _marginals(self, values: gtsam.Values) -> gtsam.Marginals:
        return gtsam.Marginals(self.factor_graph(), values)
