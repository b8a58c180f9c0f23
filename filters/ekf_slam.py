"""EKF-SLAM for 2-D range-bearing landmarks (numpy only).

Course slides "Algorithme EKF-SLAM (2D)": the state is
``X = [x, y, theta, m1x, m1y, m2x, m2y, ...]`` with a full covariance ``P``.

Storage: ``X`` and ``P`` live in preallocated buffers sized for
``capacity`` landmarks; when a landmark does not fit, the capacity doubles and
the used ``n x n`` block is copied once (amortised O(1) copies per landmark,
never an ``np.block`` of the whole ``P`` per landmark). The working ``P`` is the
view ``buffer[:n, :n]``.

Costs per step, n = 3 + 2 M:

- :meth:`EkfSlam.predict`: only ``P_rr`` (3x3) and the cross block ``P_rm``
  (3 x 2M, written to both ``P[:3, 3:]`` and ``P[3:, :3]``) change:
  ``P_rr <- F P_rr F^T + G Q G^T``, ``P_rm <- F P_rm``. O(n).
- :meth:`EkfSlam.update`, per observation: ``H`` is non-zero only on the
  robot and one landmark, so ``H P = H_x P[0:3, :] + H_m P[i:i+2, :]`` (2 x n,
  from contiguous rows: P is symmetric), ``S = (H P)[:, idx] H_s^T + R``
  (2x2), the state moves by ``(H P)^T S^-1 nu``, and the covariance update
  ``P -= K S K^T = (H P)^T S^-1 (H P)`` is written as
  ``P -= M M^T`` with ``M = (L^-1 H P)^T`` (n x 2, ``S = L L^T``). That rank-2
  downdate is applied in place, one block of 8-64 rows at a time
  (``P[r0:r1] -= M[r0:r1] @ M.T``, see :data:`ROW_BLOCK_ELEMENTS`), so the
  temporary stays small enough to sit in cache and no n x n temporary is built. Nothing is O(n^3) and the only
  O(n^2) work is that one pass over ``P``. Each entry (i, j) and (j, i) is the
  same two products summed in the same order, so ``P`` stays symmetric.
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
- unknown (``association = "unknown"``, which ignores the given ids, or an
  observation with neither id nor signature): individual compatibility
  (Mahalanobis gate at ``gate_chi2_prob``, 2 dof) against every landmark, then
  JCBB over the scan (:mod:`filters.association`, bounded by
  ``jcbb_max_candidates`` and ``jcbb_max_nodes``). Paired observations update
  the filter one by one; an unpaired observation whose squared Mahalanobis
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
by :meth:`EkfSlam.associations`.

:meth:`EkfSlam.predict_observations` uses as ``R`` the covariance of the last
observation the filter saw, or, before any, ``diag(default_sigma_range_m^2,
default_sigma_bearing_rad^2)`` from the config (course demo values by default).

Estimates are filtering estimates: the trajectory is the history of filtered
poses (each step's pose after that step's observations) with their 3x3
covariances; earlier poses are never revised.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from slamcore.planar import geometry as models
from filters.association import (chi2_quantile, individual_candidates, jcbb,
                                 mahalanobis_sq_2d)
from slamcore.planar.backend import Backend
from slamcore.errors import ConfigError, GraphSlamError, MeasurementError, UnsupportedError
from slamcore.planar.records import (
    Estimate, Observation, ObservationKind, Odometry, Prediction, as_covariance, as_vector,
)
from slamcore.planar.geometry import wrap_angle

#: Size of one block of the in-place rank-2 downdate, in doubles (1 MiB): the
#: block has ``clip(ROW_BLOCK_ELEMENTS // n, 8, 64)`` rows of P. Small blocks keep
#: the temporary in cache and keep OpenBLAS on one thread for each small gemm
#: (measured: 128-row blocks at n = 4003 went multithreaded and ran 15x slower
#: on a loaded machine).
ROW_BLOCK_ELEMENTS = 1 << 17


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


@dataclass(frozen=True)
class EkfSlamConfig:
    """EKF-SLAM settings (config file section ``[ekf]``).

    Attributes:
        association: "known" (landmark_id, else signature) or "unknown"
            (gating + JCBB; the given ids are ignored).
        gate_chi2_prob: individual and joint compatibility probability.
            0.999 by default: at 0.99, 1 % of the true pairings fall outside
            the gate by construction.
        new_landmark_chi2_prob: an unpaired observation starts a landmark only
            if its squared Mahalanobis distance to every landmark exceeds this
            chi-square (2 dof) quantile; must be >= ``gate_chi2_prob``.
            Default equal to the gate (0.999): no discard zone, since a
            discarded observation is a lost one, while a landmark started
            twice is counted (``duplicates`` in the association report).
            Measured on the default synthetic world (course noise, seeds
            0-4): 96.9/89.3/97.6/91.5/97.8 % accuracy, against
            96.9/86.4/97.1/90.4/97.7 % with 0.9999.
        provisional_sightings: sightings before a landmark enters the map
            (1 = at first sighting).
        initial_capacity: landmarks the buffers hold before the first doubling.
        jcbb_max_candidates: individually compatible landmarks kept per observation.
        jcbb_max_nodes: pairing tests JCBB may do per scan.
        jacobians: "oc" (observability-constrained, default) or "standard".
        default_sigma_range_m, default_sigma_bearing_rad: measurement noise used
            by :meth:`EkfSlam.predict_observations` before any observation is seen.
        odometry_covariance_scale: the odometry covariance is multiplied by
            this in :meth:`EkfSlam.predict` (> 0). The filter assumes white
            odometry noise; real odometry errors are correlated (a slowly
            varying heading bias on Victoria Park), so over the steps between
            two sightings they grow faster than the file's per-step covariance
            says, and an unscaled filter trusts its drifted pose too much.
        known_gate_chi2_prob: known association only: an observation whose
            innovation's squared Mahalanobis distance (2 dof) exceeds this
            chi-square quantile is rejected (not absorbed, counted in
            :attr:`EkfSlam.rejected_count`, reported as None by
            :meth:`EkfSlam.associations`). A given id does not make a
            measurement right: one spurious range-bearing pair absorbed
            with full trust corrupts the pose and the map. None (default)
            absorbs every identified observation.
    """

    SECTION: ClassVar[str] = "ekf"

    association: str = "known"
    gate_chi2_prob: float = 0.999
    new_landmark_chi2_prob: float = 0.999
    provisional_sightings: int = 1
    initial_capacity: int = 64
    jcbb_max_candidates: int = 3
    jcbb_max_nodes: int = 2000
    default_sigma_range_m: float = 0.2
    default_sigma_bearing_rad: float = math.radians(10.0)
    jacobians: str = "oc"
    odometry_covariance_scale: float = 1.0
    known_gate_chi2_prob: float | None = None

    def __post_init__(self):
        if self.jacobians not in ("standard", "oc"):
            raise ConfigError(f"ekf.jacobians must be 'standard' or 'oc', got {self.jacobians!r}")
        if self.association not in ("known", "unknown"):
            raise ConfigError(f"ekf.association must be 'known' or 'unknown', got {self.association!r}")
        for name in ("gate_chi2_prob", "new_landmark_chi2_prob"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 < float(v) < 1.0:
                raise ConfigError(f"ekf.{name} must be a probability in (0, 1), got {v!r}")
        if self.new_landmark_chi2_prob < self.gate_chi2_prob:
            raise ConfigError("ekf.new_landmark_chi2_prob must be >= ekf.gate_chi2_prob "
                              f"({self.new_landmark_chi2_prob} < {self.gate_chi2_prob})")
        for name, lo in (("provisional_sightings", 1), ("initial_capacity", 1),
                         ("jcbb_max_candidates", 1), ("jcbb_max_nodes", 0)):
            v = getattr(self, name)
            if not _is_int(v) or v < lo:
                raise ConfigError(f"ekf.{name} must be an integer >= {lo}, got {v!r}")
        for name in ("default_sigma_range_m", "default_sigma_bearing_rad"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
                raise ConfigError(f"ekf.{name} must be a positive number, got {v!r}")
        v = self.odometry_covariance_scale
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
            raise ConfigError(f"ekf.odometry_covariance_scale must be a positive number, got {v!r}")
        v = self.known_gate_chi2_prob
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                              or not 0.0 < float(v) < 1.0):
            raise ConfigError("ekf.known_gate_chi2_prob must be None or a probability in (0, 1), "
                              f"got {v!r}")




class EkfSlam(Backend):
    """EKF-SLAM back end (see the module docstring)."""

    name = "ekf"
    supports_loop_closures = False

    def __init__(self, config: EkfSlamConfig | None = None):
        self.config = config if config is not None else EkfSlamConfig()
        self._gate = chi2_quantile(self.config.gate_chi2_prob, 2)
        self._new_gate = chi2_quantile(self.config.new_landmark_chi2_prob, 2)
        self._known_gate = (math.inf if self.config.known_gate_chi2_prob is None
                            else chi2_quantile(self.config.known_gate_chi2_prob, 2))
        self._R_typical = np.diag([self.config.default_sigma_range_m ** 2,
                                   self.config.default_sigma_bearing_rad ** 2])
        self._reset(self.config.initial_capacity)

    # ------------------------------------------------------------------ state

    def _reset(self, capacity: int) -> None:
        self._cap = int(capacity)
        dim = 3 + 2 * self._cap
        self._xbuf = np.zeros(dim)
        self._Pbuf = np.zeros((dim, dim))
        self._n = 0  # used state size; 0 = not initialised
        self._ids: list[int] = []  # landmark id of each landmark slot
        self._slot: dict[int, int] = {}  # landmark id -> slot
        self._m_first: list[np.ndarray] = []  # first estimate of each slot (OC)
        self._x_pred = np.zeros(3)  # robot pose predicted for this step (OC)
        self._next_id = 0
        self._pose_id: int | None = None
        self._hist_ids: list[int] = []
        self._hist_wTb: list[np.ndarray] = []
        self._hist_cov: list[np.ndarray] = []
        self._prov_known: dict[int, int] = {}  # known-association provisional counts
        self._prov: list[dict] = []  # unknown-association provisional entries
        self._scan = 0
        self._last_associations = []
        self.last_jcbb = None
        #: Identified observations rejected by ``known_gate_chi2_prob`` since initialisation.
        self.rejected_count = 0

    @property
    def _x(self) -> np.ndarray:
        return self._xbuf[:self._n]

    @property
    def _P(self) -> np.ndarray:
        return self._Pbuf[:self._n, :self._n]

    @property
    def num_landmarks(self) -> int:
        return len(self._ids)

    @property
    def capacity(self) -> int:
        """Landmarks the buffers hold before the next doubling."""
        return self._cap

    def state_vector(self) -> np.ndarray:
        """Copy of the state ``[x, y, theta, m1x, m1y, ...]`` (n,)."""
        return self._x.copy()

    def state_covariance(self) -> np.ndarray:
        """Copy of the full covariance (n, n). O(n^2)."""
        return self._P.copy()

    def landmark_ids(self) -> list[int]:
        """Landmark ids in state order."""
        return list(self._ids)

    def load_state(self, pose_id: int, x: np.ndarray, P: np.ndarray,
                   landmark_ids: Sequence[int] | None = None) -> None:
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
        self._n = x.size
        self._xbuf[:self._n] = x
        self._xbuf[2] = wrap_angle(x[2])
        self._Pbuf[:self._n, :self._n] = P
        # a loaded state is taken as both predicted and first estimate (OC)
        self._x_pred = self._xbuf[:3].copy()
        self._m_first = [self._xbuf[3 + 2 * k:5 + 2 * k].copy() for k in range(M)]
        self._ids = ids
        self._slot = {lid: k for k, lid in enumerate(ids)}
        self._next_id = max(ids) + 1 if ids else 0
        self._pose_id = int(pose_id)
        self._record_pose(new=True)

    def _grow(self) -> None:
        new_cap = 2 * self._cap
        dim = 3 + 2 * new_cap
        n = self._n
        xbuf = np.zeros(dim)
        xbuf[:n] = self._xbuf[:n]
        Pbuf = np.zeros((dim, dim))
        Pbuf[:n, :n] = self._Pbuf[:n, :n]
        self._xbuf, self._Pbuf, self._cap = xbuf, Pbuf, new_cap

    def _record_pose(self, new: bool) -> None:
        pose = self._xbuf[:3].copy()
        cov = self._Pbuf[:3, :3].copy()
        if new:
            self._hist_ids.append(self._pose_id)
            self._hist_wTb.append(pose)
            self._hist_cov.append(cov)
        else:
            self._hist_wTb[-1] = pose
            self._hist_cov[-1] = cov

    def _require_init(self) -> None:
        if self._n == 0:
            raise GraphSlamError("ekf: initialize() must be called first")

    # --------------------------------------------------------------- contract

    def initialize(self, pose_id: int, wTb: np.ndarray, covariance: np.ndarray) -> None:
        wTb = as_vector(wTb, 3, "ekf initial pose")
        cov = as_covariance(covariance, 3, "ekf initial pose")
        self._reset(self.config.initial_capacity)
        self._n = 3
        self._xbuf[:3] = wTb
        self._xbuf[2] = wrap_angle(wTb[2])
        self._Pbuf[:3, :3] = cov
        self._x_pred = self._xbuf[:3].copy()  # robot pose predicted for this step (OC)
        self._pose_id = int(pose_id)
        self._record_pose(new=True)

    def predict(self, odometry: Odometry, pose_id: int) -> None:
        self._require_init()
        cur = self._pose_id
        if odometry.from_id == cur and odometry.to_id == pose_id:
            u, Q = odometry.delta, odometry.covariance
        elif odometry.from_id == pose_id and odometry.to_id == cur:
            u, Q = models.invert(odometry.delta, odometry.covariance)
        else:
            raise GraphSlamError(
                f"ekf: odometry {odometry.from_id}->{odometry.to_id} does not link the current "
                f"pose {cur} to the new pose {pose_id} (a filter only extends the latest pose)")
        if pose_id == cur:
            raise GraphSlamError(f"ekf: pose {pose_id} is already the current pose")
        Q = np.asarray(Q) * self.config.odometry_covariance_scale
        n = self._n
        x = self._xbuf
        P = self._Pbuf
        F, G = models.compose_jacobians(x[:3], np.asarray(u))
        x[:3] = models.compose(x[:3], np.asarray(u))
        if self.config.jacobians == "oc":
            # d p_new / d theta between predicted positions, so that the
            # rotation direction propagates exactly (see _observability_constrained)
            F[0, 2] = -(x[1] - self._x_pred[1])
            F[1, 2] = x[0] - self._x_pred[0]
        self._x_pred = x[:3].copy()
        Prr = F @ P[:3, :3] @ F.T + G @ Q @ G.T
        P[:3, :3] = 0.5 * (Prr + Prr.T)
        if n > 3:
            Prm = F @ P[:3, 3:n]
            P[:3, 3:n] = Prm
            P[3:n, :3] = Prm.T
        self._pose_id = int(pose_id)
        self._record_pose(new=True)

    def update(self, observations: Sequence[Observation]) -> None:
        self._require_init()
        obs = list(observations)
        for o in obs:  # refuse the whole scan before touching the state
            if not isinstance(o, Observation):
                raise MeasurementError(f"ekf: expected Observation, got {type(o).__name__}")
            if o.kind is not ObservationKind.RANGE_BEARING:
                raise UnsupportedError(f"ekf handles range-bearing observations only, got {o.kind.value}")
            if o.pose_id != self._pose_id:
                raise MeasurementError(f"ekf: observation from pose {o.pose_id} but the current "
                                       f"pose is {self._pose_id}")
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
            slot = self._slot.get(lid)
            if slot is not None:
                if self._kalman_update(slot, o.z, o.covariance, self._known_gate):
                    assoc[k] = lid
                else:
                    self.rejected_count += 1
                continue
            if lid not in seen_prov:
                self._prov_known[lid] = self._prov_known.get(lid, 0) + 1
                seen_prov.add(lid)
            if self._prov_known[lid] >= self.config.provisional_sightings:
                del self._prov_known[lid]
                self._add_landmark(lid, o.z, o.covariance)
                assoc[k] = lid
        if unknown:
            self._update_unknown([obs[k] for k in unknown], unknown, assoc)
        self._last_associations = assoc
        self._record_pose(new=False)

    def predict_observations(self, landmark_ids: Iterable[int]) -> list[Prediction]:
        self._require_init()
        out = []
        for lid in landmark_ids:
            slot = self._slot.get(int(lid))
            if slot is None:
                continue
            z, H_s, idx = self._predict_one(slot)
            Psub = self._P[np.ix_(idx, idx)]
            S = H_s @ Psub @ H_s.T + self._R_typical
            out.append(Prediction(int(lid), z, 0.5 * (S + S.T)))
        return out

    def estimate(self, with_covariances: bool = False) -> Estimate:
        self._require_init()
        M = len(self._ids)
        lms = self._xbuf[3:3 + 2 * M].reshape(M, 2).copy()
        est = dict(pose_ids=np.array(self._hist_ids, dtype=np.int64),
                   wTb=np.array(self._hist_wTb).reshape(-1, 3),
                   landmark_ids=np.array(self._ids, dtype=np.int64).reshape(M),
                   landmarks_w=lms)
        if with_covariances:
            est["pose_covariances"] = np.array(self._hist_cov).reshape(-1, 3, 3)
            est["landmark_covariances"] = self._landmark_marginals()
        return Estimate(**est)

    def current_pose(self) -> np.ndarray:
        self._require_init()
        return self._xbuf[:3].copy()

    def current_pose_covariance(self) -> np.ndarray | None:
        self._require_init()
        return self._Pbuf[:3, :3].copy()

    # ------------------------------------------------------------- internals

    def _landmark_marginals(self) -> np.ndarray:
        M = len(self._ids)
        i = 3 + 2 * np.arange(M)
        P = self._Pbuf
        out = np.empty((M, 2, 2))
        out[:, 0, 0] = P[i, i]
        out[:, 0, 1] = P[i, i + 1]
        out[:, 1, 0] = P[i + 1, i]
        out[:, 1, 1] = P[i + 1, i + 1]
        return out

    def _predict_one(self, slot: int) -> tuple[np.ndarray, np.ndarray, list[int]]:
        i = 3 + 2 * slot
        xr = self._xbuf[:3]
        m = self._xbuf[i:i + 2]
        z = models.observe(xr, m)
        H_x, H_m = models.observe_jacobians(xr, m)
        return z, np.hstack([H_x, H_m]), [0, 1, 2, i, i + 1]

    def _kalman_update(self, slot: int, z: np.ndarray, R: np.ndarray,
                       gate: float = math.inf) -> bool:
        """One sequential EKF update with the landmark in ``slot`` (see module docstring).

        Returns False, leaving the state untouched, when the innovation's squared
        Mahalanobis distance exceeds ``gate``.
        """
        n = self._n
        i = 3 + 2 * slot
        x = self._xbuf
        P = self._Pbuf[:n, :n]
        xr = x[:3]
        m = x[i:i + 2]
        zhat = models.observe(xr, m)
        H_x, H_m = models.observe_jacobians(xr, m)
        if self.config.jacobians == "oc":
            H_x, H_m = self._observability_constrained(slot, H_x, H_m)
        HP = H_x @ P[0:3] + H_m @ P[i:i + 2]  # (2, n): H P, from contiguous rows
        S = HP[:, 0:3] @ H_x.T + HP[:, i:i + 2] @ H_m.T + R  # (2, 2)
        S = 0.5 * (S + S.T)
        nu = models.innovation(z, zhat)
        # S = L L^T, L lower triangular 2x2, written out.
        a = math.sqrt(S[0, 0])
        b = S[1, 0] / a
        c = math.sqrt(S[1, 1] - b * b)
        # L^-1 = [[1/a, 0], [-b/(a c), 1/c]]
        Mt = np.empty((2, n))
        np.multiply(HP[0], 1.0 / a, out=Mt[0])
        np.multiply(HP[1], 1.0 / c, out=Mt[1])
        Mt[1] -= (b / (a * c)) * HP[0]
        # w = L^-1 nu; state += (H P)^T S^-1 nu = M (L^-1 nu)
        w0 = nu[0] / a
        w1 = (nu[1] - b * w0) / c
        if w0 * w0 + w1 * w1 > gate:  # |L^-1 nu|^2 = nu^T S^-1 nu
            return False
        x[:n] += Mt[0] * w0 + Mt[1] * w1
        x[2] = wrap_angle(x[2])
        # P -= M M^T, in place, one block of rows at a time.
        M = Mt.T  # (n, 2) view
        rows = min(64, max(8, ROW_BLOCK_ELEMENTS // n))
        if n <= 2 * rows:
            np.subtract(P, M @ Mt, out=P)
        else:
            for r0 in range(0, n, rows):
                blk = P[r0:r0 + rows]
                np.subtract(blk, M[r0:r0 + rows] @ Mt, out=blk)
        return True

    def _observability_constrained(self, slot, H_x, H_m):
        """The Jacobian nearest to ``[H_x H_m]`` that keeps global rotation unobservable.

        OC-EKF (Huang, Mourikis & Roumeliotis, IJRR 2010): the plain EKF
        linearises at estimates that move over time, which hands it information
        about the global heading that no measurement carries, and it becomes
        overconfident. The unobservable directions (translation, and rotation
        about the origin) are tracked at the robot's predicted positions and the
        landmark's first estimate; ``H`` is projected onto their complement.
        """
        px, py = self._x_pred[0], self._x_pred[1]
        mx, my = self._m_first[slot]
        N = np.array([[1.0, 0.0, -py], [0.0, 1.0, px], [0.0, 0.0, 1.0],
                      [1.0, 0.0, -my], [0.0, 1.0, mx]])
        H = np.hstack([H_x, H_m])
        H = H - (H @ N) @ np.linalg.solve(N.T @ N, N.T)
        return H[:, :3], H[:, 3:]

    def _add_landmark(self, lid: int, z: np.ndarray, R: np.ndarray) -> int:
        """Insert landmark ``lid`` from observation ``z`` (inverse observation model)."""
        if len(self._ids) >= self._cap:
            self._grow()
        n = self._n
        x = self._xbuf
        P = self._Pbuf
        xr = x[:3].copy()
        G_x, G_z = models.inverse_observe_jacobians(xr, z)
        x[n:n + 2] = models.inverse_observe(xr, z)
        self._m_first.append(x[n:n + 2].copy())
        Pmx = G_x @ P[0:3, :n]  # (2, n)
        Pmm = G_x @ P[:3, :3] @ G_x.T + G_z @ R @ G_z.T
        P[n:n + 2, :n] = Pmx
        P[:n, n:n + 2] = Pmx.T
        P[n:n + 2, n:n + 2] = 0.5 * (Pmm + Pmm.T)
        slot = len(self._ids)
        self._ids.append(lid)
        self._slot[lid] = slot
        self._next_id = max(self._next_id, lid + 1)
        self._n = n + 2
        return slot

    def _all_predictions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Predicted z (L, 2), H_x (L, 2, 3), H_m (L, 2, 2) and S - R (L, 2, 2) for every landmark. O(L)."""
        L = len(self._ids)
        x, P = self._xbuf, self._Pbuf
        xr = x[:3]
        m = x[3:3 + 2 * L].reshape(L, 2)
        zhat = models.observe(xr, m)
        H_x, H_m = models.observe_jacobians(xr, m)
        Prr = P[:3, :3]
        Prm = P[:3, 3:3 + 2 * L].reshape(3, L, 2).transpose(1, 0, 2)  # (L, 3, 2)
        Pmm = self._landmark_marginals()
        HxPrm = H_x @ Prm  # (L, 2, 2)
        cross = HxPrm @ H_m.transpose(0, 2, 1)
        S0 = (H_x @ Prr @ H_x.transpose(0, 2, 1) + cross + cross.transpose(0, 2, 1)
              + H_m @ Pmm @ H_m.transpose(0, 2, 1))
        return zhat, H_x, H_m, S0

    def _update_unknown(self, obs: list[Observation], where: list[int],
                        assoc: list[int | None]) -> None:
        m = len(obs)
        Z = np.array([o.z for o in obs]).reshape(m, 2)
        Rs = np.array([o.covariance for o in obs]).reshape(m, 2, 2)
        L = len(self._ids)
        pairs: list[tuple[int, int]] = []
        min_d2 = np.full(m, np.inf)
        if L:
            zhat, H_x, H_m, S0 = self._all_predictions()
            nu = models.innovation(Z[:, None, :], zhat[None, :, :])  # (m, L, 2)
            d2 = mahalanobis_sq_2d(nu, S0[None] + Rs[:, None])  # (m, L)
            min_d2 = d2.min(axis=1)
            cands = individual_candidates(d2, self._gate, self.config.jcbb_max_candidates)
            pairs = [(i, l) for i, cl in enumerate(cands) for l in cl]
        hyp: list[int | None] = [None] * m
        if pairs:
            pair_obs = np.array([p[0] for p in pairs])
            pair_lm = np.array([p[1] for p in pairs])
            U = sorted(set(pair_lm.tolist()))
            col = {u: 3 + 2 * k for k, u in enumerate(U)}
            idx = [0, 1, 2] + [j for u in U for j in (3 + 2 * u, 4 + 2 * u)]
            Psub = self._Pbuf[np.ix_(idx, idx)]
            A = np.zeros((2 * len(pairs), len(idx)))
            for p, (i, l) in enumerate(pairs):
                A[2 * p:2 * p + 2, :3] = H_x[l]
                A[2 * p:2 * p + 2, col[l]:col[l] + 2] = H_m[l]
            C = A @ Psub @ A.T
            for p, (i, _) in enumerate(pairs):
                C[2 * p:2 * p + 2, 2 * p:2 * p + 2] += Rs[i]
            res = jcbb(Z, zhat[pair_lm], C, pair_obs, pair_lm,
                       chi2_prob=self.config.gate_chi2_prob,
                       max_nodes=self.config.jcbb_max_nodes,
                       individual_d2=d2[pair_obs, pair_lm])
            self.last_jcbb = res
            hyp = res.hypothesis
        # Updates first (slots are stable: new landmarks only append).
        for i, slot in enumerate(hyp):
            if slot is not None:
                self._kalman_update(slot, Z[i], Rs[i])
                assoc[where[i]] = self._ids[slot]
        # Then new landmarks (or provisional sightings) from the updated pose.
        hit_prov: set[int] = set()
        if L:
            # Mutual exclusion: a landmark paired with another observation of
            # this scan cannot also be this one, so it does not block a new one.
            taken = [s for s in hyp if s is not None]
            if taken:
                d2x = d2.copy()
                d2x[:, taken] = np.inf
                min_d2 = d2x.min(axis=1)
        for i in range(m):
            if hyp[i] is not None or not min_d2[i] > self._new_gate:
                continue
            if self.config.provisional_sightings <= 1:
                lid = self._next_id
                self._add_landmark(lid, Z[i], Rs[i])
                assoc[where[i]] = lid
                continue
            lid = self._provisional_sighting(Z[i], Rs[i], hit_prov)
            if lid is not None:
                assoc[where[i]] = lid
        self._prov = [e for e in self._prov if e is not None]

    def _provisional_sighting(self, z: np.ndarray, R: np.ndarray, hit: set[int]) -> int | None:
        xr = self._xbuf[:3].copy()
        G_x, G_z = models.inverse_observe_jacobians(xr, z)
        pt = models.inverse_observe(xr, z)
        C = G_x @ self._Pbuf[:3, :3] @ G_x.T + G_z @ R @ G_z.T
        best, best_d2 = None, self._gate
        for k, e in enumerate(self._prov):
            if e is None or k in hit:
                continue
            d = pt - e["pt"]
            d2 = float(mahalanobis_sq_2d(d, C + e["cov"]))
            if d2 < best_d2:
                best, best_d2 = k, d2
        if best is None:
            self._prov.append({"pt": pt, "cov": C, "count": 1})
            hit.add(len(self._prov) - 1)
            return None
        e = self._prov[best]
        e["count"] += 1
        e["pt"], e["cov"] = pt, C
        hit.add(best)
        if e["count"] >= self.config.provisional_sightings:
            self._prov[best] = None  # placeholder keeps indices in ``hit`` valid this scan
            lid = self._next_id
            self._add_landmark(lid, z, R)
            return lid
        return None
