"""EKF-SLAM for 2-D range-bearing landmarks (numpy only).

Course slides "Algorithme EKF-SLAM (2D)": the state is
``X = [x, y, theta, m1x, m1y, m2x, m2y, ...]`` with a full covariance ``P``.
Beside this module: :mod:`filters.ekf_slam_config` (settings),
:mod:`filters.ekf_slam_store` (the state, its covariance and the landmark
slots), :mod:`filters.ekf_slam_correction` (one observation's update, its
Jacobians and its numerical safeguards), :mod:`filters.ekf_slam_update` (the
in-place rank-2 correction and the damped iterated step) and
:mod:`filters.ekf_slam_association` (scan association with unknown ids and
the provisional list).

Storage (:class:`filters.ekf_slam_store.SlotStore`): ``X`` and ``P`` live in
preallocated buffers sized for ``capacity`` landmarks; when a landmark does not
fit, the capacity doubles and the used ``n x n`` block is copied once
(amortised O(1) copies per landmark, never an ``np.block`` of the whole ``P``
per landmark). The working ``P`` is the view ``buffer[:n, :n]``.

Costs per step, n = 3 + 2 M:

- :meth:`EkfSlam.predict`: only ``P_rr`` (3x3) and the cross block ``P_rm``
  (3 x 2M, written to both ``P[:3, 3:]`` and ``P[3:, :3]``) change:
  ``P_rr <- F P_rr F^T + G Q G^T``, ``P_rm <- F P_rm``. O(n).
- :meth:`EkfSlam.update`, per observation: ``H`` is non-zero only on the
  robot and one landmark (the 5 entries ``J``), so ``H P = H_J P[J, :]`` (2 x n,
  from 5 gathered rows: P is symmetric), ``S = H_J P[J, J] H_J^T + R`` (2x2),
  the state moves by ``(H P)^T S^-1 nu``, and the covariance update
  ``P -= K S K^T = (H P)^T S^-1 (H P)`` is written as ``P -= M M^T`` with
  ``M = (L^-1 H P)^T`` (n x 2, ``S = L L^T``). The 2x5 linearisation, the OC
  projection, the gate and the safeguards' checks run on Python floats; one
  3 x 5 by 5 x n product gives ``M^T`` and the state step together, and the
  downdate is one BLAS dgemm written in place into P's buffer
  (:mod:`filters.ekf_slam_update`): no n x n temporary, nothing O(n^3), and the
  only O(n^2) work is that one pass over ``P``, which stays symmetric to the bit.
  Measured against the same update written plainly in numpy with an in-place
  dgemm (``benchmarks/bench_ekf_update.py``): 0.9-1.1x from 50 to 2000 landmarks.
- New landmark (inverse observation model ``m = g(x_r, z)``):
  ``P_mX = G_x P[0:3, :]`` (all cross-covariances), ``P_mm = G_x P_rr G_x^T +
  G_z R G_z^T``. O(n).

Jacobians (``jacobians``): ``"oc"`` (default) is the observability-constrained
EKF of Huang, Mourikis & Roumeliotis (IJRR 2010); ``"standard"`` the textbook
one. Both use the same models and innovations. The textbook EKF linearises at
estimates that move over time, which gives it information about the global
heading that no measurement carries; with the course demo's 10 deg bearing noise
its average pose NEES on the default synthetic world is ~190 (20 runs; the 95 %
band is [2.0, 4.2]). OC keeps the unobservable directions (translation and
rotation about the origin) unobservable: the motion Jacobian's heading column is
taken between the robot's *predicted* positions, and each measurement Jacobian
is projected onto the complement of those directions, tracked at the predicted
robot pose and the landmark's first estimate (measured: average NEES 3.05,
inside the band on 96 % of the steps). It costs one 5x3 projection per update.
Evaluating H wholly at the first estimates (FEJ) diverged here, because a
landmark's first estimate is metres off with 10 deg bearings.

Data association:

- known: by ``Observation.landmark_id``; if that is None but ``signature`` is
  set, by signature (the landmark is then given the signature as its id);
- unknown (``association = "unknown"``, which ignores the given ids, or a run
  whose sightings carry neither id nor signature; a run mixing sightings with
  and without is refused): individual compatibility
  (Mahalanobis gate at ``gate_chi2_prob``, 2 dof) against every landmark, then
  JCBB over the scan (:mod:`filters.association`, bounded by
  ``jcbb_max_candidates`` and ``jcbb_max_nodes``), maximising the scan's
  likelihood against new landmarks (``jcbb_objective = "likelihood"``, the
  default) or the number of pairings ("count"). Paired observations update
  the filter one by one. With "likelihood" a pairing whose gate is as likely
  to hold a new landmark as the mapped one (a landmark mapped before a long
  drift) is kept only if the measurement alone favours it or a second such
  pairing of the scan supports it
  (:func:`filters.ekf_slam_association.ambiguous_gates`). A pairing that
  another jointly compatible hypothesis gives to a landmark the sensor tells
  apart (beyond the ``gate_chi2_prob`` quantile of its error, Student-t when
  the sensor field says so: :func:`filters.association.ambiguous_pairings`) was
  chosen by the pose prior alone and is held: no update, no new landmark (as
  iSAM2 does, :mod:`graphslam.backends.planar.landmark_association` step 3;
  MRCLAM robot 3's ATE 0.410 -> 0.130 m, 19 -> 17 landmarks). An unpaired
  observation is new where a new landmark explains it better than every
  landmark left unpaired (a refused pairing's observation is thus dropped);
  with "count", an unpaired observation whose squared Mahalanobis
  distance to every landmark exceeds the ``new_landmark_chi2_prob`` quantile
  becomes a new landmark (after the scan's updates, from the updated pose),
  otherwise it is discarded as ambiguous. That distance is taken over the
  landmarks *not* paired in the scan (mutual exclusion: a landmark gives at
  most one observation per scan), so a landmark 0.3-0.7 m from a mapped one
  that is seen in the same scan still enters the map; without it, such
  neighbours stayed out of the map for good and their observations were
  discarded or absorbed by the neighbour. Own ids are consecutive ints from 0
  (in "known" mode, the next int above every id used so far: a given id that
  later collides with an id the filter made up is taken as the same landmark,
  so do not mix anonymous and identified observations of different landmarks
  unless the given ids are known not to collide).

Provisional list (slides: "ou le mettre dans une liste provisoire"): with
``provisional_sightings = N > 1`` a landmark enters the map at its N-th
sighting (at most one sighting per scan), initialised from that sighting's
observation; earlier sightings are not used. With unknown association a new
sighting is matched to a provisional entry by a world-frame Mahalanobis gate on
the inverse-observed points (covariances ``G_x P_rr G_x^T + G_z R G_z^T``,
correlations ignored). Observations held on the list are reported as ``None``
by :meth:`EkfSlam.associations`. ``provisional_sightings`` unset (the default):
N = 1 with known ids; with unknown ids, the N that makes N sightings outside a
mapped landmark's gate as rare as the gate's own error under the sensor field's
error tail (:func:`filters.association.confirming_sightings`: 1 for a Gaussian
sensor, 3 for MRCLAM's camera; MRCLAM's robots then build 15-18 landmarks for 15
instead of 15-24).

Sightings whose errors are correlated in time (an observation's ``correlation``
and ``stamp_s``) update with their covariance inflated by what they add to the
earlier sightings of the landmark they were associated with
(:mod:`slamcore.planar.sighting_correlation`); association gates with the
sighting's own covariance.

:meth:`EkfSlam.predict_observations` uses as ``R`` the covariance of the last
observation the filter saw, or, before any, ``diag(default_sigma_range_m^2,
default_sigma_bearing_rad^2)`` from the config (course demo values by default).

Estimates are filtering estimates: the trajectory is the history of filtered
poses (each pose as it was when the filter replaced it by the next, or now for
the latest) with their 3x3 covariances; earlier poses are never revised.

Several robots (``graphslam run --robot all``, issue 31 item 4), as a
centralised filter: the state holds the latest pose of every robot beside the
shared landmarks (:class:`filters.ekf_slam_store.SlotStore` parks the robots
that are not moving). An odometry step may extend any robot's latest pose,
which becomes the active one, or start a robot from the first pose of the run
(the joint reader links every robot's start to it); a sighting of one robot by
another (:meth:`EkfSlam.add_pose_sighting`) updates both latest poses and,
through their correlations, the whole state, with the standard Jacobian. A
start from the first pose takes that pose's filtered estimate and covariance
without its correlations with the rest of the state (the filter keeps only
each robot's latest pose): exact when the first pose is known, as the joint
reader's starts from the truth (prior variance 1e-6), an approximation
otherwise.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from filters.association import (
    JcbbResult,
    chi2_quantile,
    confirming_sightings,
    mahalanobis_sq_2d,
    t2_quantile,
)
from filters.ekf_slam_association import (
    ProvisionalList,
    associate_scan,
    predict_landmarks,
    unpaired_distances,
)
from filters.ekf_slam_config import EkfSlamConfig
from filters.ekf_slam_correction import kalman_update, pose_sighting_update
from filters.ekf_slam_store import SlotStore
from filters.landmark_existence import MissedSightings
from filters.numerics import Recoveries
from filters.planar_inputs import checked_scan, initial_pose, linked_pose, mapped_predictions, odometry_step
from slamcore.errors import GraphSlamError, MeasurementError, UnsupportedError
from slamcore.planar import geometry as models
from slamcore.planar.backend import Backend
from slamcore.planar.records import (
    Estimate,
    Observation,
    Odometry,
    PoseSighting,
    Prediction,
    SensorField,
    error_dof,
)
from slamcore.planar.sighting_correlation import LastSightings


class EkfSlam(Backend):
    """EKF-SLAM back end (see the module docstring).

    The state, its covariance and the landmark slots are held in a
    :class:`filters.ekf_slam_store.SlotStore`; the filter keeps the pose
    history, the ids it hands out, the provisional lists and the counters.
    """

    name = "ekf"
    supports_loop_closures = False
    supports_pose_sightings = True

    def __init__(self, config: EkfSlamConfig | None = None):
        self.config = config if config is not None else EkfSlamConfig()
        self._gate = chi2_quantile(self.config.gate_chi2_prob, 2)
        self._new_gate = chi2_quantile(self.config.new_landmark_chi2_prob, 2)
        self._known_gate = self.config.known_gate()
        self._R_typical = self.config.default_noise()
        self._sensor_field: SensorField | None = None
        self._distinct_d2 = self._distinct_gate()
        self._reset(self.config.initial_capacity)

    # ------------------------------------------------------------------ state

    def _reset(self, capacity: int) -> None:
        self._store = SlotStore(capacity)  # st.n == 0: not initialised
        self._next_id = 0
        self._pose_id: int | None = None
        self._hist_ids: list[int] = []
        self._hist_wTb: list[np.ndarray] = []
        self._hist_cov: list[np.ndarray] = []
        self._hist_index: dict[int, int] = {}  # pose id -> its row of the history
        self._prov_known: dict[int, int] = {}  # known-association provisional counts
        self._id_kinds: set[str] = set()  # "given" / "own" landmark ids so far (known association)
        # unknown-association provisional entries
        self._prov = ProvisionalList(self._provisional_sightings(), self._gate)
        self._scan = 0
        # each sighting weighed by what it adds to its landmark's earlier ones
        self._last_sightings = LastSightings()
        self._last_associations = []
        self.last_jcbb: JcbbResult | None = None
        #: Identified observations rejected by ``known_gate_chi2_prob`` since initialisation.
        self.rejected_count = 0
        #: Sightings of one robot by another since initialisation: used, and rejected
        #: by the same gate as identified landmarks.
        self.pose_sightings_used = 0
        self.pose_sightings_rejected = 0
        #: Numerical recoveries since initialisation (:class:`filters.numerics.Recoveries`).
        self.recoveries = Recoveries()
        self._missed = self._missed_sightings()
        # landmark ids removed as missed in view since initialisation
        # (``prune_missed_alpha``, :mod:`filters.landmark_existence`)
        self._pruned_ids: list[int] = []

    @property
    def num_landmarks(self) -> int:
        return len(self._store.ids)

    @property
    def num_parked_poses(self) -> int:
        """Other robots' latest poses held after the landmarks (several robots)."""
        return len(self._store.parked_ids)

    @property
    def capacity(self) -> int:
        """Landmarks the buffers hold before the next doubling."""
        return self._store.cap

    def state_vector(self) -> np.ndarray:
        """Copy of the state ``[x, y, theta, m1x, m1y, ...]`` (n,)."""
        return self._store.x.copy()

    def state_covariance(self) -> np.ndarray:
        """Copy of the full covariance (n, n). O(n^2)."""
        return self._store.P.copy()

    def landmark_ids(self) -> list[int]:
        """Landmark ids in state order."""
        return list(self._store.ids)

    def load_state(
        self, pose_id: int, x: np.ndarray, P: np.ndarray, landmark_ids: Sequence[int] | None = None
    ) -> None:
        """Replace the whole filter state (tests, benchmarks, restoring a run).

        Args:
            pose_id: id of the current pose.
            x: (3 + 2M,) state; P: its (3 + 2M, 3 + 2M) covariance (not checked
                for definiteness: O(n^3)).
            landmark_ids: M ids in state order; default 0..M-1.
        """
        x = np.asarray(x, dtype=float).reshape(-1)
        P = np.asarray(P, dtype=float)
        if x.size < 3 or (x.size - 3) % 2 or P.shape != (x.size, x.size):
            raise GraphSlamError(f"load_state: bad shapes x {x.shape}, P {P.shape}")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
            raise MeasurementError("load_state: non-finite state or covariance")
        M = (x.size - 3) // 2
        ids = list(range(M)) if landmark_ids is None else [int(i) for i in landmark_ids]
        if len(ids) != M or len(set(ids)) != M:
            raise GraphSlamError("load_state: landmark_ids must be M distinct ids")
        self._reset(max(self.config.initial_capacity, M))
        self._store.load(x, P, ids)  # taken as both predicted pose and first estimates (OC)
        self._next_id = max(ids) + 1 if ids else 0
        self._pose_id = int(pose_id)
        self._record_pose(new=True)

    def _record_pose(self, new: bool) -> None:
        """Append the active pose to the history (``new``), or refresh its row."""
        self._record(self._current_pose_id(), 0, new)

    def _record(self, pose_id: int, i: int, new: bool) -> None:
        """The pose at state index ``i`` as history row of ``pose_id`` (appended if ``new``)."""
        pose = self._store.xbuf[i : i + 3].copy()
        cov = self._store.Pbuf[i : i + 3, i : i + 3].copy()
        if new:
            self._hist_index[pose_id] = len(self._hist_ids)
            self._hist_ids.append(pose_id)
            self._hist_wTb.append(pose)
            self._hist_cov.append(cov)
        else:
            row = self._hist_index[pose_id]
            self._hist_wTb[row] = pose
            self._hist_cov[row] = cov

    def _record_parked(self) -> None:
        """Refresh the history rows of the parked poses (corrections move them too)."""
        st = self._store
        for k, pid in enumerate(st.parked_ids):
            self._record(pid, st.parked_index(k), new=False)

    def _require_init(self) -> None:
        if self._store.n == 0:
            raise GraphSlamError("ekf: initialize() must be called first")

    def _current_pose_id(self) -> int:
        if self._pose_id is None:
            raise GraphSlamError("ekf: initialize() must be called first")
        return self._pose_id

    # --------------------------------------------------------------- contract

    def initialize(self, pose_id: int, wTb: np.ndarray, covariance: np.ndarray) -> None:
        pose_id, wTb, cov = initial_pose(pose_id, wTb, covariance, "ekf initial pose")
        self._reset(self.config.initial_capacity)
        self._store.start(wTb, cov)
        self._pose_id = int(pose_id)
        self._record_pose(new=True)

    def predict(self, odometry: Odometry, pose_id: int) -> None:
        self._require_init()
        if pose_id in self._hist_index:  # the trajectory would hold one id twice
            raise GraphSlamError(
                f"ekf: pose {pose_id} is already in the trajectory; a new pose needs a new id"
            )
        st = self._store
        other, cur = linked_pose(odometry, pose_id), self._current_pose_id()
        if other is not None and other != cur:  # another robot's step (module docstring)
            if other in st.parked_ids:  # it moves now: its latest pose becomes the active one
                self._record_pose(new=False)  # the active pose as it is when it is parked
                self._pose_id = st.activate(st.parked_ids.index(other), cur)
            elif other == self._hist_ids[0] and pose_id not in self._hist_index:
                self._start_robot(other, odometry, pose_id)
                return
        u, Q = odometry_step(odometry, self._current_pose_id(), pose_id, "ekf")
        Q = Q * self.config.odometry_covariance_scale
        self._record_pose(new=False)  # the pose as the filter leaves it
        n = st.n
        x = st.xbuf
        P = st.Pbuf
        F, G = models.compose_jacobians(x[:3], u)
        x[:3] = models.compose(x[:3], u)
        if self.config.jacobians == "oc":
            # d p_new / d theta between predicted positions, so that the rotation
            # direction propagates exactly (filters.ekf_slam_correction.observability_constrained)
            F[0, 2] = -(x[1] - st.x_pred[1])
            F[1, 2] = x[0] - st.x_pred[0]
        st.x_pred = x[:3].copy()
        Prr = F @ P[:3, :3] @ F.T + G @ Q @ G.T
        P[:3, :3] = 0.5 * (Prr + Prr.T)
        st.note_variances(float(P[:3, :3].diagonal().max()))
        if n > 3:
            Prm = F @ P[:3, 3:n]
            P[:3, 3:n] = Prm
            P[3:n, :3] = Prm.T
        self._pose_id = int(pose_id)
        self._record_pose(new=True)

    def _start_robot(self, first_id: int, odometry: Odometry, pose_id: int) -> None:
        """Start a robot at pose ``pose_id`` from the run's first pose (module docstring)."""
        u, Q = odometry_step(odometry, first_id, pose_id, "ekf")
        row = self._hist_index[first_id]
        x0, P0 = self._hist_wTb[row], self._hist_cov[row]
        F, G = models.compose_jacobians(x0, u)
        cov = F @ P0 @ F.T + G @ (Q * self.config.odometry_covariance_scale) @ G.T
        self._record_pose(new=False)
        self._store.park_and_start(self._current_pose_id(), models.compose(x0, u), 0.5 * (cov + cov.T))
        self._pose_id = int(pose_id)
        self._record_pose(new=True)

    def add_pose_sighting(self, sighting: PoseSighting) -> None:
        """Range and bearing from one robot's latest pose to another's (both in the
        state): one EKF correction of the whole state, gated as an identified landmark.

        Raises:
            UnsupportedError: a pose that is not a robot's latest (the filter keeps
                no other).
        """
        self._require_init()
        st = self._store
        live = {self._current_pose_id(): 0}
        live.update((pid, st.parked_index(k)) for k, pid in enumerate(st.parked_ids))
        missing = [p for p in (sighting.from_id, sighting.to_id) if p not in live]
        if missing or sighting.from_id == sighting.to_id:
            raise UnsupportedError(
                f"ekf keeps each robot's latest pose only: it cannot use a sighting of pose "
                f"{sighting.to_id} from pose {sighting.from_id}"
            )
        if pose_sighting_update(
            st,
            live[sighting.from_id],
            live[sighting.to_id],
            sighting.z,
            sighting.covariance,
            self._known_gate,
        ):
            self.pose_sightings_used += 1
        else:
            self.pose_sightings_rejected += 1
        self._record_pose(new=False)
        self._record_parked()

    def update(self, observations: Sequence[Observation]) -> None:
        self._require_init()
        obs = checked_scan(observations, self._pose_id, "ekf")
        if self.config.association == "known":
            self._check_one_id_space(obs)
        self._scan += 1
        assoc: list[int | None] = [None] * len(obs)
        unknown: list[int] = []
        seen_prov: set[int] = set()
        for k, o in enumerate(obs):
            self._R_typical = o.covariance
            lid = None
            if self.config.association == "known":
                lid = o.landmark_id if o.landmark_id is not None else o.signature
            if lid is None:
                unknown.append(k)
                continue
            lid = int(lid)
            slot = self._store.slot.get(lid)
            if slot is not None:
                # the clock is set by sightings used only: one the gate rejects is not
                # the previous sighting the next one is correlated with
                R = self._last_sightings.covariance(o, lid, record=False)
                if kalman_update(self._store, slot, o.z, R, self.config, self.recoveries, self._known_gate):
                    self._last_sightings.record(o, lid)
                    assoc[k] = lid
                else:
                    self.rejected_count += 1
                continue
            if lid not in seen_prov:
                self._prov_known[lid] = self._prov_known.get(lid, 0) + 1
                seen_prov.add(lid)
            if self._prov_known[lid] >= self._prov.sightings:
                del self._prov_known[lid]
                self._add_landmark(lid, o.z, o.covariance)  # a first sighting: its own
                self._last_sightings.record(o, lid)
                assoc[k] = lid
        if unknown:
            scan = [obs[k] for k in unknown]
            self._update_unknown(scan, unknown, assoc)
            self._prune_missed({a for a in assoc if a is not None}, scan)
        self._last_associations = assoc
        self._record_pose(new=False)

    def rejected_observations(self) -> int:
        return self.rejected_count

    def pruned_landmark_ids(self) -> list[int]:
        return list(self._pruned_ids)

    def set_sensor_field(self, sensor_field: SensorField | None) -> None:
        self._sensor_field = sensor_field
        self._missed = self._missed_sightings()
        self._prov.sightings = self._provisional_sightings()
        self._distinct_d2 = self._distinct_gate()

    def sensor_field_use(self) -> frozenset[str]:
        if self.config.association != "unknown":
            return frozenset()  # known ids: no gate of a new landmark, no pruning
        pruning = self.config.prune_missed_alpha is not None
        return frozenset({"error_dof", "field"} if pruning else {"error_dof"})

    def reads_sighting_correlation(self) -> bool:
        return True

    def _distinct_gate(self) -> float:
        """Squared distance beyond which the sensor tells two landmarks apart: the
        ``gate_chi2_prob`` quantile of its error (unknown association's hold)."""
        return t2_quantile(self.config.gate_chi2_prob, error_dof(self._sensor_field))

    def _provisional_sightings(self) -> int:
        """``provisional_sightings``, or when unset: 1 with known ids, else as many as the
        sensor's error tail needs (:func:`filters.association.confirming_sightings`)."""
        n = self.config.provisional_sightings
        if n is not None:
            return n
        if self.config.association == "known":
            return 1
        return confirming_sightings(self.config.gate_chi2_prob, error_dof(self._sensor_field))

    def predict_observations(self, landmark_ids: Iterable[int]) -> list[Prediction]:
        self._require_init()
        return mapped_predictions(landmark_ids, self._store.slot, self._predicted)

    def estimate(self, with_covariances: bool = False) -> Estimate:
        self._require_init()
        self._record_parked()
        st = self._store
        M = len(st.ids)
        lms = st.xbuf[3 : 3 + 2 * M].reshape(M, 2).copy()
        est = dict(
            pose_ids=np.array(self._hist_ids, dtype=np.int64),
            wTb=np.array(self._hist_wTb).reshape(-1, 3),
            landmark_ids=np.array(st.ids, dtype=np.int64).reshape(M),
            landmarks_w=lms,
        )
        if with_covariances:
            est["pose_covariances"] = np.array(self._hist_cov).reshape(-1, 3, 3)
            est["landmark_covariances"] = st.landmark_marginals()
        return Estimate(**est)

    def current_pose(self) -> np.ndarray:
        self._require_init()
        return self._store.xbuf[:3].copy()

    def current_pose_covariance(self) -> np.ndarray | None:
        self._require_init()
        return self._store.Pbuf[:3, :3].copy()

    # ------------------------------------------------------------- internals

    def _predicted(self, slot: int) -> tuple[np.ndarray, np.ndarray]:
        """``(z_pred, S)`` of landmark ``slot``, ``R`` the last observation's covariance (the
        config's default before any)."""
        i = 3 + 2 * slot
        xr = self._store.xbuf[:3]
        m = self._store.xbuf[i : i + 2]
        z = models.observe(xr, m)
        H_x, H_m = models.observe_jacobians(xr, m)
        H_s = np.hstack([H_x, H_m])
        idx = [0, 1, 2, i, i + 1]
        S = H_s @ self._store.P[np.ix_(idx, idx)] @ H_s.T + self._R_typical
        return z, 0.5 * (S + S.T)

    def _missed_sightings(self) -> MissedSightings | None:
        """The pruning's scores (module :mod:`filters.landmark_existence`), None when it is off."""
        alpha = self.config.prune_missed_alpha
        if self._sensor_field is None or alpha is None or self.config.association != "unknown":
            return None
        return MissedSightings(self._sensor_field.detection_prob, alpha)

    def _prune_missed(self, seen: set[int], obs: list[Observation]) -> None:
        """Remove the landmarks that lay surely in the sensor's field this scan, that
        no observation of the scan ``obs`` may be of, and that have been missed too
        often since their last sighting."""
        if self._missed is None or self._sensor_field is None:
            return
        field = self._sensor_field
        st = self._store
        if not st.ids:
            return
        # every landmark at once: predicted measurement and H P H^T (L, 2), (L, 2, 2)
        zhat, _, _, S0 = predict_landmarks(st.xbuf, st.Pbuf, st.landmark_marginals())
        # surely inside: three sigmas of the predicted measurement to spare
        sd = 3.0 * np.sqrt(np.maximum(np.diagonal(S0 + self._R_typical, axis1=1, axis2=2), 0.0))
        inside = (zhat[:, 0] + sd[:, 0] <= field.max_range_m) & (
            np.abs(zhat[:, 1]) + sd[:, 1] <= field.half_fov_rad
        )
        # an observation inside its gate that association left unpaired (an
        # ambiguous one) may be its sighting: not evidence that it is absent
        Z = np.array([o.z for o in obs]).reshape(-1, 2)
        Rs = np.array([o.covariance for o in obs]).reshape(-1, 2, 2)
        d2 = mahalanobis_sq_2d(models.innovation(Z[:, None, :], zhat[None]), S0[None] + Rs[:, None])
        gated = np.any(d2 <= self._gate, axis=0)
        in_field = [st.ids[k] for k in np.flatnonzero(inside & ~gated) if st.ids[k] not in seen]
        gone = self._missed.frame(seen, in_field)
        if gone:
            self._store.remove_slots([self._store.slot[lid] for lid in gone])
            self._pruned_ids.extend(gone)

    def _add_landmark(self, lid: int, z: np.ndarray, R: np.ndarray) -> int:
        """Insert landmark ``lid`` from observation ``z`` (inverse observation model)."""
        st = self._store
        xr = st.xbuf[:3].copy()
        G_x, G_z = models.inverse_observe_jacobians(xr, z)
        slot = st.open_slot(lid, models.inverse_observe(xr, z))  # may grow the buffers
        n = 3 + 2 * slot
        P = st.Pbuf
        Pmx = G_x @ P[0:3, :n]  # (2, n)
        Pmm = G_x @ P[:3, :3] @ G_x.T + G_z @ R @ G_z.T
        P[n : n + 2, :n] = Pmx
        P[:n, n : n + 2] = Pmx.T
        if st.n > n + 2:  # the parked poses of other robots, after the landmarks
            Pmp = G_x @ P[0:3, n + 2 : st.n]
            P[n : n + 2, n + 2 : st.n] = Pmp
            P[n + 2 : st.n, n : n + 2] = Pmp.T
        P[n : n + 2, n : n + 2] = 0.5 * (Pmm + Pmm.T)
        st.note_variances(float(P[n, n]), float(P[n + 1, n + 1]))
        self._next_id = max(self._next_id, lid + 1)
        return slot

    def _check_one_id_space(self, obs: list[Observation]) -> None:
        """Known association: every sighting of a run carries its landmark's id (or a
        signature), or none does. The filter names a landmark of an anonymous sighting
        with the next free id, which a given id arriving later can equal: that landmark
        was then gated as a re-sighting of the anonymous one and never entered the map.
        Refused rather than given ids of a separate space: a given id may be any int64,
        so no space is the filter's alone."""
        kinds = {"given" if o.landmark_id is not None or o.signature is not None else "own" for o in obs}
        if len(kinds | self._id_kinds) > 1:
            raise MeasurementError(
                'ekf: association = "known" with sightings both with and without landmark ids '
                '(the filter\'s ids for the latter could equal given ones); give every id, or use "unknown"'
            )
        self._id_kinds |= kinds

    def _update_unknown(self, obs: list[Observation], where: list[int], assoc: list[int | None]) -> None:
        """Associate the observations ``obs`` (rows ``where`` of the scan) by gating and
        JCBB, update with the pairs, then start landmarks (or provisional
        sightings) from the unpaired ones far from every unpaired landmark."""
        m = len(obs)
        Z = np.array([o.z for o in obs]).reshape(m, 2)
        Rs = np.array([o.covariance for o in obs]).reshape(m, 2, 2)
        c = self.config
        likelihood = None
        if c.jcbb_objective == "likelihood":
            likelihood = (c.new_landmark_density_per_m2, c.detection_prob)
        hyp, novelty, res, held = associate_scan(
            self._store.xbuf,
            self._store.Pbuf,
            self._store.landmark_marginals(),
            Z,
            Rs,
            gate=self._gate,
            chi2_prob=c.gate_chi2_prob,
            max_candidates=c.jcbb_max_candidates,
            max_nodes=c.jcbb_max_nodes,
            likelihood=likelihood,
            distinct_d2=self._distinct_d2,
        )
        if res is not None:
            self.last_jcbb = res
        # Updates first (slots are stable: new landmarks only append).
        for i, slot in enumerate(hyp):
            if slot is not None:
                R = self._last_sightings.covariance(obs[i], self._store.ids[slot])
                kalman_update(self._store, slot, Z[i], R, c, self.recoveries)
                assoc[where[i]] = self._store.ids[slot]
        # Then new landmarks (or provisional sightings) from the updated pose.
        hit_prov: set[int] = set()
        least = unpaired_distances(novelty, hyp)
        threshold = self._new_gate if likelihood is None else 0.0
        for i in range(m):
            if hyp[i] is not None or held[i] or not least[i] > threshold:
                continue
            if self._prov.sightings <= 1:
                lid = self._next_id
                self._add_landmark(lid, Z[i], Rs[i])
                assoc[where[i]] = lid
                self._last_sightings.record(obs[i], lid)  # its first sighting's time
                continue
            entered = self._provisional_sighting(Z[i], Rs[i], hit_prov)
            if entered is not None:
                assoc[where[i]] = entered
                self._last_sightings.record(obs[i], entered)
        self._prov.compact()

    def _provisional_sighting(self, z: np.ndarray, R: np.ndarray, hit: set[int]) -> int | None:
        """Sight ``z`` on the provisional list; the new landmark's id when it enters the map."""
        xr = self._store.xbuf[:3].copy()
        G_x, G_z = models.inverse_observe_jacobians(xr, z)
        pt = models.inverse_observe(xr, z)
        C = G_x @ self._store.Pbuf[:3, :3] @ G_x.T + G_z @ R @ G_z.T
        if not self._prov.sight(pt, C, hit):
            return None
        lid = self._next_id
        self._add_landmark(lid, z, R)
        return lid
