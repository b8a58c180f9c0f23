"""The iSAM2 back end (2-D): Pose2 poses, bearing-range landmarks, between factors.

Range-only observations (radio beacons) become ``RangeFactor2D``; a landmark seen
by ranges alone enters the graph once its buffered ranges determine its position
(:mod:`graphslam.backends.planar.range_init`), with all those ranges as factors.
A sighting whose errors are correlated in time enters weighed by what it adds to the
earlier ones of its landmark (:mod:`slamcore.planar.sighting_correlation`).

Incremental use, as iSAM2 wants it: the factors and initial values of one
frame are buffered and handed to ``ISAM2.update`` once, when the next frame
starts or an answer is asked for. Per step we only read the one pose needed to
initialise the next (``calculateEstimate(key)``), never the full estimate, so
the per-step cost does not grow with the run. Full estimates, marginals and the
optional final batch Levenberg-Marquardt polish are on request.

Optional loop-closure gate (``loop_closure_gate > 0``): a closure whose
residual at the current estimate is implausible is held back instead of
entering iSAM2. Besides protecting the estimate, this keeps the factorisation
sparse: false closures between random far-apart poses would otherwise densify
the Bayes tree (a few thousand of them on w10000 make every update cost
seconds). The test is a chi-square one on the squared Mahalanobis residual
``r2``, in two tiers:

1. ``r2 = 2 * error`` of the Gaussian between factor at the current estimate
   (the new pose initialised from odometry); below the gate -> accepted with the
   frame, no extra cost.
2. otherwise (a true closure that ends a long excursion carries the drift of
   the excursion), pairwise consistency: the closure is accepted together with
   any earlier closure (accepted or held back) whose two poses are each within
   ``gate_window`` poses of its own and which closes a consistent cycle with
   it: ``r2`` of the cycle ``closure_a, local chain, closure_b^-1, local chain``
   under both closures' covariances plus the two short odometry chains'
   (compounded with Pose2 adjoints) is within the gate, for at least
   ``gate_min_support`` such partners (so that two false closures agreeing by
   chance are not enough, which matters when the stated noise is as loose as
   w10000's 1 m / 1 rad). Real revisits give runs
   of mutually consistent closures; false ones from perceptual aliasing are
   scattered and disagree with each other. (A simplified, local form of
   pairwise consistency maximisation, Mangelson et al., ICRA 2018.)
   Rejected -> held back.

Noise scale: some data state a covariance far looser than the real noise
(w10000: 1 m / 1 rad, while its optimum's closure residuals are ~0.07 sigma),
and a chi-square gate under such a covariance lets almost anything through.
With ``gate_scale_from_data`` the gate is applied to ``r2 / s2`` where
``s2 = median(r2) / 2.366`` (2.366: median of chi-square with 3 dof) over
the tier-1 residuals of all closures seen so far (recomputed every 100, after
the first 50; at most 1: never looser than the stated covariance). This is the
usual robust (median-based) scale estimate of M-estimation; false closures
among those seen only raise the median, i.e. make the gate more permissive.

At ``finalize`` held-back closures are tested again (tier 1) against the
estimate, and those now consistent are added, until none is. The ``"lm"``
polish is then truncated least squares by removal, alternated to a fixed
point: solve with the closures kept, re-test every closure (in the graph or
held back) against that solution, keep exactly those within the gate, solve
again, until the kept set stops changing (at most ``gate_polish_rounds``
re-tests). A closure dropped in one round can come back in the next: a false
closure that got into the graph bends the first solution, so true closures
around it fail the gate there, and fit again once it is out.
:meth:`Isam2Backend.rejected_loop_closures` lists what the final estimate does
not use.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from filters.planar_inputs import initial_pose, require_odometry, scan_list
from graphslam.backends import factorization as fact
from graphslam.backends import gtsam_convert as conv
from graphslam.backends.planar.isam2_config import Isam2Config
from graphslam.backends.planar.isam2_unknown import UnknownAssociation
from graphslam.backends.planar.range_init import RangeLandmarkInitialiser
from slamcore.errors import GraphSlamError, UnsupportedError
from slamcore.planar.backend import Backend
from slamcore.planar.records import (
    Estimate,
    LoopClosure,
    Observation,
    ObservationKind,
    Odometry,
    PoseSighting,
    Prediction,
    SensorField,
    error_dof,
)
from slamcore.planar.sighting_correlation import LastSightings

#: Median of the chi-square distribution with 3 degrees of freedom.
CHI2_3DOF_MEDIAN = 2.3660


class Isam2Backend(Backend):
    """Smoothing back end on ``gtsam.ISAM2``: known data association, or unknown
    (``association = "unknown"``, :mod:`~graphslam.backends.planar.landmark_association`)."""

    name = "isam2"
    supports_loop_closures = True
    supports_pose_sightings = True

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
        # each sighting weighed by what it adds to its landmark's earlier ones
        self._last_sightings = LastSightings()
        self._ranges = RangeLandmarkInitialiser()  # range-only landmarks not yet placed
        self._polished: gtsam.Values | None = None
        self._n_factors = 0  # factors handed to iSAM2 or pending, in insertion order
        self._loop_closures: dict[int, LoopClosure] = {}  # factor index -> closure
        self._held_back: list[LoopClosure] = []  # failed the gate, not in iSAM2
        self._gate_r2: list[float] = []  # tier-1 residuals seen, for the noise scale
        self._gate_s2 = 1.0  # residual scale (squared); the gate is loop_closure_gate * this
        self._odometry: dict[int, Odometry] = {}  # pose id -> its odometry (gate only)
        # gate: [closure, inserted?] by the closure's larger pose id, for partner search
        self._closures_near: dict[int, list[list]] = {}
        self._dropped: set[int] = set()  # factor indices the gated polish left out
        self._gate_rounds = 0  # LM solves of the last gated polish (diagnostics)
        self._recoveries: list[str] = []  # numerical fallbacks taken, for the summary
        # unknown association: owns its state (isam2_unknown)
        self._unknown: UnknownAssociation | None = None
        if self.config.association == "unknown":
            self._unknown = UnknownAssociation(
                self.config.association_gate_prob, self.config.confirm_sightings
            )

    # --- the contract -------------------------------------------------------

    def initialize(self, pose_id, wTb, covariance):
        if self._pose_ids:
            raise GraphSlamError("isam2: initialize() called twice")
        # the filters' checks: a (4,) pose lost its 4th value, a 2x2 covariance was gtsam's RuntimeError
        pose_id, wTb, covariance = initial_pose(pose_id, wTb, covariance, "isam2 initial pose")
        conv.key_index(pose_id, "isam2: pose")
        self._graph.add(conv.prior_factor(pose_id, wTb, covariance))
        self._values.insert(X(pose_id), conv.pose2(wTb))
        self._add_pose_id(pose_id)

    def set_sensor_field(self, sensor_field: SensorField | None) -> None:
        """Unknown association reads the sightings' error tail from it (what tells two
        landmarks apart, :mod:`.landmark_association`); None: Gaussian errors."""
        if self._unknown is not None:
            self._unknown.associator.set_error_dof(error_dof(sensor_field))

    def sensor_field_use(self) -> frozenset[str]:
        return frozenset({"error_dof"}) if self._unknown is not None else frozenset()

    def reads_sighting_correlation(self) -> bool:
        return True

    def predict(self, odometry: Odometry, pose_id: int) -> None:
        self._require_init()
        self._flush()
        if pose_id in self._pose_set:
            raise GraphSlamError(f"isam2: pose {pose_id} added twice")
        require_odometry(odometry)
        if odometry.to_id == pose_id and odometry.from_id in self._pose_set:
            wTb = self._seed(odometry.from_id).compose(conv.pose2(odometry.delta))
        elif odometry.from_id == pose_id and odometry.to_id in self._pose_set:
            wTb = self._seed(odometry.to_id).compose(conv.pose2(odometry.delta).inverse())
        else:
            raise GraphSlamError(
                f"isam2: odometry {odometry.from_id}->{odometry.to_id} does not link new pose "
                f"{pose_id} to a known pose"
            )
        conv.key_index(pose_id, "isam2: pose")
        self._graph.add(conv.between_factor(odometry))
        self._values.insert(X(pose_id), wTb)
        if self.config.loop_closure_gate > 0:
            self._odometry[pose_id] = odometry
        self._add_pose_id(pose_id)

    def update(self, observations: Sequence[Observation]) -> None:
        self._require_init()
        observations = scan_list(observations, "isam2")
        if self._unknown is not None:
            self._last_associations = self._update_unknown(self._unknown, observations)
            return
        for obs in observations:  # refused whole before any of it touches the graph
            conv.checked_known_sighting(obs, self._pose_set, "isam2")
        assoc: list[int | None] = []
        for obs in observations:
            if obs.landmark_id is None:
                # iSAM2 here needs known association; unknown ones are skipped, and reported.
                assoc.append(None)
                continue
            lid = conv.key_index(obs.landmark_id, "isam2: landmark")
            if obs.kind is ObservationKind.RANGE:
                self._add_range(obs, lid)
                assoc.append(lid)
                continue
            if lid not in self._landmark_set:
                wTb = self._pose(obs.pose_id)
                r, b = obs.z
                self._values.insert(L(lid), wTb.transformFrom(np.array([r * np.cos(b), r * np.sin(b)])))
                self._landmark_ids.append(lid)
                self._landmark_set.add(lid)
            self._graph.add(
                conv.bearing_range_factor(
                    self._last_sightings.observation(obs, lid),
                    lid,
                    self.config.observation_kernel,
                    self.config.observation_kernel_k,
                )
            )
            self._measurement_cov[lid] = obs.covariance
            assoc.append(lid)
        self._last_associations = assoc

    def _update_unknown(
        self, unknown: UnknownAssociation, observations: Sequence[Observation]
    ) -> list[int | None]:
        """Unknown association: :mod:`.isam2_unknown` decides, this adds the factors."""
        if not observations:
            return []
        if any(o.kind is not ObservationKind.RANGE_BEARING for o in observations):
            raise UnsupportedError(
                "isam2: unknown association needs range-bearing sightings; "
                'range-only beacons carry their ids (association = "known")'
            )
        pose_id = observations[0].pose_id
        if any(o.pose_id != pose_id for o in observations) or pose_id not in self._pose_set:
            raise GraphSlamError("isam2: one update takes the observations of one known pose")
        self._flush()
        decisions = unknown.step(self._isam, pose_id, observations)
        kernel = (self.config.observation_kernel, self.config.observation_kernel_k)
        assoc: list[int | None] = []
        for obs, d in zip(observations, decisions, strict=True):
            if d.kind == "confirmed":
                lid = d.landmark()
                self._values.insert(L(lid), gtsam.Point2(*d.position()))
                self._landmark_ids.append(lid)
                self._landmark_set.add(lid)
                for seen in d.sightings:
                    self._add_sighting(unknown, seen, lid, kernel)
            elif d.kind == "landmark":
                self._add_sighting(unknown, obs, d.landmark(), kernel)
            if d.landmark_id is not None:
                self._measurement_cov[d.landmark_id] = obs.covariance
            assoc.append(d.landmark_id)
        confirmed = [d.landmark() for d in decisions if d.kind == "confirmed"]
        if confirmed:  # sightings a new landmark explains better move to it (isam2_unknown)
            self._flush()
            self._n_factors += unknown.split(self._isam, confirmed, self._n_factors, kernel)
        paired = [d.landmark() for d in decisions if d.kind == "landmark"]
        if paired:
            self._flush()
            for keep, drop, tie in unknown.merges(self._isam, paired):
                self._graph.add(tie)
                self._landmark_ids.remove(drop)
                self._last_sightings.merged(keep, drop)
        return assoc

    def _reassociate(self, unknown: UnknownAssociation) -> None:
        """Re-association at the end of the run (:mod:`.isam2_unknown`): pass after pass
        at the batch estimate until nothing moves or the passes are spent."""
        kernel = (self.config.observation_kernel, self.config.observation_kernel_k)
        unknown.ran = True
        params = self._polish_params()
        for _ in range(self.config.reassociation_passes):
            graph = self.factor_graph()  # flushes
            values = gtsam.LevenbergMarquardtOptimizer(graph, self._values_now(), params).optimize()
            added, ties = unknown.reassociate(self._isam, values, self._n_factors, kernel)
            self._n_factors += added
            for keep, drop, _ in ties:
                self._landmark_ids.remove(drop)
                self._last_sightings.merged(keep, drop)
            if not added:
                return
        unknown.settled = False

    def _polish_params(self) -> gtsam.LevenbergMarquardtParams:
        """Levenberg-Marquardt with the polish's limits (the polish, the re-association)."""
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(self.config.polish_max_iterations)
        params.setRelativeErrorTol(self.config.polish_relative_error_tol)
        params.setAbsoluteErrorTol(self.config.polish_absolute_error_tol)
        return params

    def reassociation(self) -> tuple[int, bool] | None:
        """``(sightings moved, settled)`` by the re-association at the end of the run
        (:mod:`.isam2_unknown`); None with known ids or before it ran."""
        if self._unknown is None or not self._unknown.ran:
            return None
        return self._unknown.moved, self._unknown.settled

    def final_associations(self) -> dict[tuple[int, int], int] | None:
        if self._unknown is None:
            return None
        return self._unknown.pairings()

    def _add_sighting(self, unknown: UnknownAssociation, obs: Observation, lid: int, kernel) -> None:
        added = self._last_sightings.observation(obs, lid)  # weighed (sighting_correlation)
        unknown.record(lid, self._n_factors + self._graph.size(), obs, added)
        self._graph.add(conv.bearing_range_factor(added, lid, *kernel))

    def add_loop_closure(self, loop_closure: LoopClosure) -> None:
        for pid in (loop_closure.from_id, loop_closure.to_id):
            if pid not in self._pose_set:
                raise GraphSlamError(f"isam2: loop closure refers to unknown pose {pid}")
        if self.config.loop_closure_gate > 0:
            self._gate(loop_closure)
            return
        self._insert_closure(loop_closure)

    def add_pose_sighting(self, sighting: PoseSighting) -> None:
        for pid in (sighting.from_id, sighting.to_id):
            if pid not in self._pose_set:
                raise GraphSlamError(f"isam2: sighting refers to unknown pose {pid}")
        self._graph.add(
            conv.pose_sighting_factor(
                sighting, self.config.observation_kernel, self.config.observation_kernel_k
            )
        )

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
        self._require_init()
        values = self._values_now()
        est = conv.values_to_estimate(values, self._pose_ids, self._landmark_ids)
        if not with_covariances:
            return est

        def covariances(marginals):
            pcov = np.array(
                [
                    conv.pose2_covariance_from_gtsam(theta, marginals.marginalCovariance(X(i)))
                    for i, theta in zip(self._pose_ids, est.wTb[:, 2], strict=True)
                ]
            ).reshape(-1, 3, 3)
            lcov = np.array([marginals.marginalCovariance(L(j)) for j in self._landmark_ids]).reshape(
                -1, 2, 2
            )
            return pcov, lcov

        found = fact.marginals_or_none(lambda: covariances(self._marginals(values)), self._recoveries)
        if found is None:
            return est
        return Estimate(est.pose_ids, est.wTb, est.landmark_ids, est.landmarks_w, *found)

    def finalize(self, with_covariances: bool = False) -> Estimate:
        self._require_init()
        self._flush()
        if self._held_back and self._polished is None:
            self._readmit_held_back()
        if self._unknown is not None and self._polished is None and self.config.reassociation_passes:
            self._reassociate(self._unknown)
        if self.config.polish and self._polished is None and self._pose_ids:
            params = self._polish_params()
            initial = self._values_now()
            if self.config.polish_method == "gnc" and self._loop_closures:
                self._polished = self._gnc(params, initial)
            elif self.config.loop_closure_gate > 0:
                self._polished = self._gated_lm(params, initial)
            else:
                self._polished = gtsam.LevenbergMarquardtOptimizer(
                    self.factor_graph(), initial, params
                ).optimize()
        return self.estimate(with_covariances=with_covariances)

    def current_pose_covariance(self) -> np.ndarray | None:
        self._require_init()
        self._flush()
        key = X(self._pose_ids[-1])
        theta = self._isam.calculateEstimatePose2(key).theta()
        return fact.marginals_or_none(
            lambda: conv.pose2_covariance_from_gtsam(theta, self._isam.marginalCovariance(key)),
            self._recoveries,
        )

    def landmark_covariances(self) -> np.ndarray | None:
        """The landmarks' marginals alone (what a recording draws): the pose marginals
        :meth:`estimate` adds are most of its cost on long runs."""

        def compute():
            marginals = self._marginals(self._values_now())
            return np.array([marginals.marginalCovariance(L(j)) for j in self._landmark_ids]).reshape(
                -1, 2, 2
            )

        return fact.marginals_or_none(compute, self._recoveries)

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
        self._require_init()
        self._flush()
        key = X(self._pose_ids[-1])
        if self._polished is not None:
            return conv.pose2_vector(self._polished.atPose2(key))
        return conv.pose2_vector(self._pose(self._pose_ids[-1]))

    def rejected_loop_closures(self) -> list[LoopClosure]:
        """Closures the current estimate does not use: held back by the gate,
        dropped by the gated polish, or given a GNC weight below 0.5."""
        self._flush()
        return list(self._held_back) + [self._loop_closures[i] for i in sorted(self._dropped)]

    def numerical_recoveries(self) -> list[str]:
        """Fallbacks taken because a factorisation failed, one sentence each."""
        return list(self._recoveries)

    # --- internals ----------------------------------------------------------

    def _insert_closure(self, loop_closure: LoopClosure) -> None:
        self._loop_closures[self._n_factors + self._graph.size()] = loop_closure
        self._graph.add(
            conv.between_factor(loop_closure, self.config.loop_closure_noise(loop_closure.covariance))
        )

    def _gate_passes(self, lc: LoopClosure) -> bool:
        """Tier 1: squared Mahalanobis residual (closure covariance only) within the gate."""
        values = gtsam.Values()
        for pid in (lc.from_id, lc.to_id):
            values.insert(X(pid), self._pose(pid))
        r2 = 2.0 * conv.between_factor(lc).error(values)
        if self.config.gate_scale_from_data:
            self._gate_r2.append(r2)
            n = len(self._gate_r2)
            if n >= 50 and n % 100 == 50:
                self._gate_s2 = float(min(1.0, np.median(self._gate_r2) / CHI2_3DOF_MEDIAN))
        return r2 <= self._gate_threshold()

    def _gate_threshold(self) -> float:
        """Threshold on ``r2`` under the stated covariances (gate times noise scale)."""
        return self.config.loop_closure_gate * self._gate_s2

    def _gate(self, lc: LoopClosure) -> None:
        """Tier 1, else tier 2 (pairwise consistency); insert or hold back."""
        hi, lo = max(lc.from_id, lc.to_id), min(lc.from_id, lc.to_id)
        entry = [lc, False]
        if self._gate_passes(lc):
            self._insert_closure(lc)
            entry[1] = True
        else:
            w = self.config.gate_window
            partners = [
                e
                for h in range(hi - w, hi + w + 1)
                for e in self._closures_near.get(h, ())
                if abs(min(e[0].from_id, e[0].to_id) - lo) <= w and self._consistent(e[0], lc)
            ]
            if len(partners) >= self.config.gate_min_support:
                self._insert_closure(lc)
                entry[1] = True
                for e in partners:
                    if not e[1]:
                        self._held_back.remove(e[0])
                        self._insert_closure(e[0])
                        e[1] = True
            else:
                self._held_back.append(lc)
        self._closures_near.setdefault(hi, []).append(entry)

    def _chain(self, a: int, b: int) -> tuple[gtsam.Pose2, np.ndarray] | None:
        """``aTb`` from the estimate and its covariance from compounding the odometry."""
        if a == b:
            return gtsam.Pose2(), np.zeros((3, 3))
        lo, hi = min(a, b), max(a, b)
        T, cov = gtsam.Pose2(), np.zeros((3, 3))
        prev = self._pose(lo)
        for k in range(lo + 1, hi + 1):
            odo = self._odometry.get(k)
            if odo is None or k - 1 not in self._pose_set:
                return None
            cur = self._pose(k)
            u = prev.between(cur)
            Ad = u.inverse().AdjointMap()
            cov = Ad @ cov @ Ad.T + np.asarray(odo.covariance)
            T, prev = T.compose(u), cur
        if a > b:  # wanted hiTlo = T^-1
            Ad = T.AdjointMap()
            T, cov = T.inverse(), Ad @ cov @ Ad.T
        return T, cov

    def _consistent(self, la: LoopClosure, lb: LoopClosure) -> bool:
        """Whether two nearby closures agree: cycle error of b predicted from a."""
        chain_from = self._chain(la.from_id, lb.from_id)
        chain_to = self._chain(la.to_id, lb.to_id)
        if chain_from is None or chain_to is None:
            return False
        A, cov_A = chain_from  # a.from T b.from
        B, cov_B = chain_to  # a.to T b.to
        Za, Zb = conv.pose2(la.delta), conv.pose2(lb.delta)
        ZaB = Za.compose(B)
        pred = A.inverse().compose(ZaB)  # b.from T b.to, predicted
        # covariance of pred in its own tangent space (right perturbations)
        Ad_inv_B = B.inverse().AdjointMap()
        cov_Ainv = A.AdjointMap() @ cov_A @ A.AdjointMap().T
        Ad_ZaB = ZaB.inverse().AdjointMap()
        cov = (
            cov_B
            + Ad_inv_B @ np.asarray(la.covariance) @ Ad_inv_B.T
            + Ad_ZaB @ cov_Ainv @ Ad_ZaB.T
            + np.asarray(lb.covariance)
        )
        e = gtsam.Pose2.Logmap(Zb.between(pred))
        return float(e @ np.linalg.solve(cov, e)) <= self._gate_threshold()

    def _readmit_held_back(self) -> None:
        """Add held-back closures consistent with the estimate (tier 1), until none is."""
        while self._held_back:
            with fact.indeterminate_as_error("isam2"):
                values = self._isam.calculateEstimate()
            keep = []
            for lc in self._held_back:
                r2 = 2.0 * conv.between_factor(lc).error(values)
                if r2 <= self._gate_threshold():
                    self._insert_closure(lc)
                else:
                    keep.append(lc)
            admitted = len(keep) < len(self._held_back)
            self._held_back = keep
            if not admitted:
                break
            self._flush()

    def _gated_lm(self, params: gtsam.LevenbergMarquardtParams, initial: gtsam.Values) -> gtsam.Values:
        """LM polish with truncated least squares by removal, closures re-tested every round.

        Every round solves with the closures currently kept, then re-tests
        **every** closure (those in iSAM2 and the held-back ones) against that
        solution: the kept set of the next round is exactly those within the
        gate. Dropping is therefore not final: a false closure that slipped into
        iSAM2 bends the first solution, so true closures near it exceed the
        gate there; once the false one is out they fit again and come back
        (w10000 with 30 % false closures: 56 true closures dropped for good by
        a drop-only loop moved the map 0.2 m from its clean optimum). Stops when
        the kept set no longer changes, or after ``gate_polish_rounds`` re-tests.
        Held-back closures kept at the end are inserted into iSAM2, so that the
        graph of :meth:`factor_graph` is the one the polish solved.

        Hand-written rather than ``gtsam.GncLMOptimizer``: GNC's TLS weights
        reach the same 0/1 decision, but it re-solves the whole graph at each
        of its ~10-20 continuation steps (minutes each on w10000 with the tight
        tolerances its flat error surface needs), where this converges in 2-3
        warm-started LM solves; ``polish_method = "gnc"`` remains available.
        """
        full = self.factor_graph()
        n_full = full.size()
        held = list(self._held_back)
        # candidates: graph index -> closure, then held-back closures after the graph
        candidates = dict(self._loop_closures)
        gaussian = {i: conv.between_factor(lc) for i, lc in candidates.items()}
        for k, lc in enumerate(held):
            candidates[n_full + k] = lc
            gaussian[n_full + k] = conv.between_factor(lc)
        kept = set(self._loop_closures)  # start from what the incremental run used
        result = initial
        threshold = self._gate_threshold()
        for round_ in range(self.config.gate_polish_rounds + 1):
            graph = gtsam.NonlinearFactorGraph()
            for i in range(n_full):
                if (i in kept or i not in candidates) and full.at(i) is not None:
                    graph.add(full.at(i))
            for k, lc in enumerate(held):
                if n_full + k in kept:
                    graph.add(conv.between_factor(lc, self.config.loop_closure_noise(lc.covariance)))
            result = gtsam.LevenbergMarquardtOptimizer(graph, result, params).optimize()
            self._gate_rounds = round_ + 1
            if round_ == self.config.gate_polish_rounds:
                break
            now = {i for i, f in gaussian.items() if 2.0 * f.error(result) <= threshold}
            if now == kept:
                break
            kept = now
        readmitted = [lc for k, lc in enumerate(held) if n_full + k in kept]
        if readmitted:
            self._held_back = [lc for k, lc in enumerate(held) if n_full + k not in kept]
            for lc in readmitted:
                self._insert_closure(lc)
            self._flush()  # iSAM2 gets them too (resets _polished / _dropped)
        self._dropped = {i for i in self._loop_closures if i < n_full and i not in kept}
        return result

    def _add_range(self, obs: Observation, lid: int) -> None:
        """A range to ``lid``: a factor if it has a position, else buffered until its
        ranges determine one, then it enters with a factor for each of them."""
        kernel, k = self.config.observation_kernel, self.config.observation_kernel_k
        if lid in self._landmark_set:
            self._graph.add(conv.range_factor(obs, lid, kernel, k))
            return
        xy = conv.pose2_vector(self._pose(obs.pose_id))[:2]
        self._ranges.add(lid, obs.pose_id, xy, obs)
        ready = self._ranges.try_initialise(lid)
        if ready is None:
            return
        position, buffered = ready
        self._values.insert(L(lid), position)
        self._landmark_ids.append(lid)
        self._landmark_set.add(lid)
        for o in buffered:
            self._graph.add(conv.range_factor(o, lid, kernel, k))

    def _require_init(self) -> None:
        """As the filters: an empty estimate's current pose was a bare IndexError."""
        if not self._pose_ids:
            raise GraphSlamError("isam2: initialize() must be called first")

    def _add_pose_id(self, pose_id: int) -> None:
        self._pose_ids.append(pose_id)
        self._pose_set.add(pose_id)

    def _seed(self, pose_id: int) -> gtsam.Pose2:
        """The value a new pose linked to known pose ``pose_id`` starts from (through the
        odometry): the latest pose's estimate, else ``pose_id``'s linearisation point.

        An earlier pose is another robot's latest (``--robot all``, the robots' frames
        interleaved). Its estimate costs a back-substitution down to its clique, deep in
        a tree that the robots' sightings of each other bind together: on MRCLAM
        Dataset 6's five robots that was half the run (6.7 of 13.3 s over the first
        4000 frames). Its linearisation point is iSAM2's own value of it, as of its last
        relinearisation; it only seeds the solve. Measured on the whole joint stream
        (``benchmarks/bench_isam2_joint.py``): 93 s against 211 s, the final cost the
        same to six digits, each robot's ATE within 2e-5 m. One robot always extends
        its latest pose, so its runs are unchanged (the digests are identical).
        """
        if pose_id == self._pose_ids[-1]:
            return self._pose(pose_id)
        return self._isam.getLinearizationPoint().atPose2(X(pose_id))  # no solve: nothing to fail

    def _pose(self, pose_id: int) -> gtsam.Pose2:
        """Best current value of a known pose: pending initial value, else iSAM2's."""
        key = X(pose_id)
        if self._values.exists(key):
            return self._values.atPose2(key)
        with fact.indeterminate_as_error("isam2"):
            return self._isam.calculateEstimatePose2(key)

    def _gnc(self, lm_params: gtsam.LevenbergMarquardtParams, initial: gtsam.Values) -> gtsam.Values:
        """GNC over the graph with Gaussian closures; all other factors are known inliers."""
        graph = self.factor_graph()
        for index, lc in self._loop_closures.items():  # GNC wants plain Gaussian factors
            graph.replace(index, conv.between_factor(lc))
        params = gtsam.GncLMParams(lm_params)
        params.setKnownInliers([i for i in range(graph.size()) if i not in self._loop_closures])
        optimizer = gtsam.GncLMOptimizer(graph, initial, params)
        result = optimizer.optimize()
        weights = np.asarray(optimizer.getWeights())
        self._dropped = {i for i in self._loop_closures if weights[i] < 0.5}
        return result

    def _values_now(self) -> gtsam.Values:
        """The estimate answers are given from: the polish if current, else iSAM2's."""
        self._flush()
        if self._polished is not None:
            return self._polished
        with fact.indeterminate_as_error("isam2"):
            return self._isam.calculateEstimate()

    def _flush(self) -> None:
        if self._graph.size() == 0 and self._values.size() == 0:
            return
        # swap first: a Ctrl-C raised as update() returns must not leave the
        # factors pending, or the next flush would add them twice
        graph, values = self._graph, self._values
        self._graph, self._values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self._n_factors += graph.size()
        self._polished = None  # new information invalidates a previous polish
        self._dropped = set()
        try:
            self._isam.update(graph, values)
        except RuntimeError as exc:
            self._recover(exc)

    def _recover(self, exc: RuntimeError) -> None:
        """Cholesky met an indeterminate system: QR from here on (``auto``), else one line."""
        where = fact.failed_variable(exc) or "?"
        if not fact.is_indeterminate(exc):
            raise exc
        if self.config.factorization != "auto" or self._recoveries:
            raise GraphSlamError(
                f"isam2: indeterminate linear system near {where} with "
                f"{self.config.factorization} factorization (isam2.factorization = "
                f'"auto" falls back to QR)'
            ) from None
        self._isam = fact.rebuild_with_qr(self._isam, self.config.isam2_params())
        self._recoveries.append(
            f"iSAM2 Cholesky found an indeterminate system near {where} at pose "
            f"{self._pose_ids[-1]}; refactored with QR from there on"
        )

    def _marginals(self, values: gtsam.Values) -> gtsam.Marginals:
        return gtsam.Marginals(self.factor_graph(), values)
