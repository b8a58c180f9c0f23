"""EKF localisation against a fixed 2-D landmark map (numpy only): a Schmidt-Kalman filter.

``graphslam run --map DIR --backend ekf`` on a 2-D dataset. The state is the
EKF-SLAM one, ``X = [x, y, theta, m1x, m1y, ...]``, initialised with the map's
landmarks and their saved 2x2 covariances (``P_mm`` block diagonal: the map
keeps no cross-covariances between landmarks), but the landmarks are *consider*
states (Schmidt, 1966): every update's gain is zero on them, so their means and
their covariance block never change, while the robot-landmark cross-covariance
``P_rm`` is carried exactly. The robot is therefore not over-confident about a
landmark it has already used (its error is correlated with the robot's through
``P_rm``), which folding the map's covariance into the measurement noise at
every sighting would make it.

With gain ``K = [K_r; 0]``, ``A = P H^T`` and ``S = H P H^T + R``, the optimal
robot gain is ``K_r = A_r S^-1`` and the covariance of this (suboptimal for the
whole state) gain, ``(I - K H) P (I - K H)^T + K R K^T``, is::

    P_rr <- P_rr - K_r S K_r^T,   P_rm <- P_rm - K_r (H P)_m,   P_mm unchanged.

``H`` is non-zero on the robot and one landmark, so a correction is O(M) (the
``3 x 2M`` block ``P_rm``); the ``2M x 2M`` block is stored as its M diagonal
2x2 blocks. Prediction is EKF-SLAM's: ``P_rr <- F P_rr F^T + G Q G^T``,
``P_rm <- F P_rm``.

Association is by ``Observation.landmark_id`` (the synthetic world and
Victoria Park give ids). An observation of a landmark that is not in the map,
or one without an id, is not used: no landmark is ever added, the observation
is reported as ``None`` by :meth:`associations` and counted in
:attr:`EkfLocaliser.unmapped_count`. ``[ekf] known_gate_chi2_prob`` gates the
innovations as in EKF-SLAM (rejections in :attr:`EkfLocaliser.rejected_count`),
``odometry_covariance_scale`` scales the odometry; the other ``[ekf]`` keys
concern mapping and are not used. No OC Jacobians: against a fixed map the
global pose is observable.

A filter cannot revise past poses: where the run leaves the mapped area it
dead-reckons until it sees a map landmark again (Victoria Park localised on the
map of its first half: 961 steps without one, 94 m off at their end, where the
iSAM2 localiser smooths the gap afterwards). An iterated update
(Gauss-Newton on the pose at each sighting) was tried and changed nothing
there (15.51 m against 15.53 m ATE to iSAM2): the error is drift, not linearisation.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from filters.ekf_slam_config import EkfSlamConfig
from filters.numerics import symmetrise
from filters.planar_inputs import checked_scan, initial_pose, mapped_predictions, odometry_step
from slamcore.errors import ConfigError, GraphSlamError
from slamcore.planar import geometry as models
from slamcore.planar.backend import Backend
from slamcore.planar.records import Estimate, Observation, Odometry, Prediction


class EkfLocaliser(Backend):
    """Localisation-only EKF on a fixed landmark map (module docstring).

    Args:
        landmark_ids: (M,) map landmark ids; landmarks_w: (M, 2) metres;
            landmark_cov: (M, 2, 2) their covariances, m^2.
        config: the ``[ekf]`` section (``association`` must be "known").
    """

    name = "ekf"
    supports_loop_closures = False

    def __init__(self, landmark_ids, landmarks_w, landmark_cov, config: EkfSlamConfig | None = None):
        self.config = config if config is not None else EkfSlamConfig()
        if self.config.association != "known":
            raise ConfigError(
                "ekf: localisation against a map associates by landmark id; "
                '[ekf] association = "unknown" is not supported with --map'
            )
        self._map_ids = np.asarray(landmark_ids, dtype=np.int64).copy()
        self._m = np.asarray(landmarks_w, dtype=np.float64).reshape(-1, 2).copy()
        self._Pm = np.asarray(landmark_cov, dtype=np.float64).reshape(-1, 2, 2).copy()
        for a in (self._map_ids, self._m, self._Pm):
            a.setflags(write=False)
        self._slot = {int(i): k for k, i in enumerate(self._map_ids)}
        self._gate = self.config.known_gate()
        self._R_typical = self.config.default_noise()
        self._x: np.ndarray | None = None
        self._Prr = np.zeros((3, 3))
        self._Prm = np.zeros((3, 2 * len(self._map_ids)))
        self._pose_id: int | None = None
        self._hist_ids: list[int] = []
        self._hist_wTb: list[np.ndarray] = []
        self._hist_cov: list[np.ndarray] = []
        self._last_associations = []
        #: Observations of landmarks not in the map (or without an id): not used.
        self.unmapped_count = 0
        #: Identified observations rejected by ``known_gate_chi2_prob``.
        self.rejected_count = 0

    # --------------------------------------------------------------- contract

    def initialize(self, pose_id: int, wTb: np.ndarray, covariance: np.ndarray) -> None:
        pose_id, wTb, cov = initial_pose(pose_id, wTb, covariance, "ekf initial pose")
        self._x = wTb.copy()
        self._x[2] = models.wrap_angle(wTb[2])
        self._Prr = cov.copy()
        self._Prm[:] = 0.0  # the map's frame is the run's: pose and map start uncorrelated
        self._pose_id = int(pose_id)
        self._record(new=True)

    def predict(self, odometry: Odometry, pose_id: int) -> None:
        x, cur = self._current()
        u, Q = odometry_step(odometry, cur, pose_id, "ekf")
        F, G = models.compose_jacobians(x, u)
        self._x = models.compose(x, u)
        Q = Q * self.config.odometry_covariance_scale
        self._Prr = symmetrise(F @ self._Prr @ F.T + G @ Q @ G.T)
        self._Prm = F @ self._Prm
        self._pose_id = int(pose_id)
        self._record(new=True)

    def update(self, observations: Sequence[Observation]) -> None:
        self._require_init()
        # the isam2 localiser refuses ranges alone too: the step is to run without a map
        obs = checked_scan(observations, self._pose_id, "ekf", "it runs without a map")
        assoc: list[int | None] = []
        for o in obs:
            lid = o.landmark_id
            slot = None if lid is None else self._slot.get(int(lid))
            if lid is None or slot is None:
                self.unmapped_count += 1
                assoc.append(None)
                continue
            self._R_typical = o.covariance
            if self._correct(slot, o.z, o.covariance):
                assoc.append(int(lid))
            else:
                self.rejected_count += 1
                assoc.append(None)
        self._last_associations = assoc
        self._record(new=False)

    def rejected_observations(self) -> int:
        return self.rejected_count

    def predict_observations(self, landmark_ids: Iterable[int]) -> list[Prediction]:
        self._require_init()
        return mapped_predictions(landmark_ids, self._slot, self._predicted)

    def estimate(self, with_covariances: bool = False) -> Estimate:
        """The filtered poses; the landmarks are the map's, unchanged (with its covariances)."""
        self._require_init()
        return Estimate(
            pose_ids=np.array(self._hist_ids, dtype=np.int64),
            wTb=np.array(self._hist_wTb).reshape(-1, 3),
            landmark_ids=self._map_ids.copy(),
            landmarks_w=self._m.copy(),
            pose_covariances=np.array(self._hist_cov).reshape(-1, 3, 3) if with_covariances else None,
            landmark_covariances=self._Pm.copy() if with_covariances else None,
        )

    def current_pose(self) -> np.ndarray:
        return self._current()[0].copy()

    def current_pose_covariance(self) -> np.ndarray | None:
        self._require_init()
        return self._Prr.copy()

    # ------------------------------------------------------------- internals

    def _predicted(self, slot: int) -> tuple[np.ndarray, np.ndarray]:
        """``(z_pred, S)`` of landmark ``slot``, ``R`` the last observation's covariance (the
        config's default before any)."""
        z, _, _, _, S = self._innovation_terms(slot, self._R_typical)
        return z, S

    def _innovation_terms(self, slot: int, R: np.ndarray):
        """``(z_pred, H_x, H_m, A_r, S)`` of landmark ``slot`` at the current pose."""
        m = self._m[slot]
        c = slice(2 * slot, 2 * slot + 2)
        x, _ = self._current()
        H_x, H_m = models.observe_jacobians(x, m)
        A_r = self._Prr @ H_x.T + self._Prm[:, c] @ H_m.T  # robot rows of P H^T
        B = self._Prm[:, c].T @ H_x.T + self._Pm[slot] @ H_m.T  # landmark rows of P H^T
        S = symmetrise(H_x @ A_r + H_m @ B + R)
        return models.observe(x, m), H_x, H_m, A_r, S

    def _correct(self, slot: int, z: np.ndarray, R: np.ndarray) -> bool:
        """Schmidt update by one observation of landmark ``slot``; False if gated out or
        if ``S`` is not positive definite (the state is then untouched)."""
        z_pred, H_x, H_m, A_r, S = self._innovation_terms(slot, R)
        nu = models.innovation(z, z_pred)
        try:
            Lc = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            return False
        w = np.linalg.solve(Lc, nu)
        if not float(w @ w) <= self._gate:
            return False
        K_r = np.linalg.solve(S, A_r.T).T  # (3, 2): S is symmetric
        HPm = H_x @ self._Prm  # (2, 2M): the landmark columns of H P
        HPm[:, 2 * slot : 2 * slot + 2] += H_m @ self._Pm[slot]
        x = self._current()[0] + K_r @ nu
        x[2] = models.wrap_angle(x[2])
        self._x = x
        self._Prm = self._Prm - K_r @ HPm
        self._Prr = symmetrise(self._Prr - K_r @ S @ K_r.T)
        return True

    def _record(self, new: bool) -> None:
        x, pose_id = self._current()
        if new:
            self._hist_ids.append(pose_id)
            self._hist_wTb.append(x.copy())
            self._hist_cov.append(self._Prr.copy())
        else:
            self._hist_wTb[-1] = x.copy()
            self._hist_cov[-1] = self._Prr.copy()

    def _require_init(self) -> None:
        self._current()

    def _current(self) -> tuple[np.ndarray, int]:
        """The current pose ``x`` (3,) (the array itself) and its id, once
        :meth:`initialize` has run."""
        if self._x is None or self._pose_id is None:
            raise GraphSlamError("ekf: initialize() must be called first")
        return self._x, self._pose_id
