"""Monocular EKF-SLAM with undelayed inverse-depth landmarks (numpy only).

The filter of the FPGA paper (seed 003, sections 2 and 4.4; RT-SLAM), behind
:class:`slamcore.spatial.backend.VisualBackend`.

State ``X = [R, L1 ... Ln]`` with a full covariance ``P``. The robot is the
camera (``wTc``):

- ``robot_model = "odometry"``: ``R = [p (3) m, q (4)]``; :meth:`MonoEkf.predict`
  composes the given ``c_{k-1} T c_k`` (covariance in the contract's right
  perturbation ``[rho, phi]``).
- ``robot_model = "constant_velocity"``: ``R = [p, q, v (3) m/s world, w (3)
  rad/s body]`` (MonoSLAM): ``p += (v + V) dt``, ``q = q (x) v2q((w + O) dt)``,
  ``v += V``, ``w += O`` with impulses ``V = a dt``, ``O = alpha dt``
  (``cv_sigma_accel_mps2``, ``cv_sigma_alpha_radps2``). When odometry is given
  anyway, the pose is composed with it and ``v, w`` are reset to the step's
  mean velocities (``R(q) t / dt``, ``log(R_d) / dt``), so a later frame without
  odometry continues from them.

Landmarks (:mod:`filters.landmark_params`): initialised undelayed from one
pixel as IDP (6) or AHP (7) with the prior inverse distance
``rho0 = 1 / (2 d_min)``, ``sigma_rho = 1 / (4 d_min)``: the 2-sigma interval
``[0, 1 / d_min]`` covers every depth from ``min_depth_m`` to infinity (RT-SLAM).
Their cross-covariances come from the inverse observation model's Jacobians.
After each update, a non-Euclidean landmark whose linearity index
``L = 4 sigma_d / d |cos alpha|`` (Civera et al. 2008; ``sigma_d = sigma_rho
|C| / rho^2`` the depth std along the anchor ray, ``d`` its distance from the
current camera, ``alpha`` the angle between the anchor ray and the current
ray) is below ``linearity_threshold`` becomes Euclidean (3): ``P <- J P J^T``
with ``J`` the identity except the landmark's 3 x s block (the converted
landmark moves to the end of the state).

Per frame (:meth:`MonoEkf.update`):

1. Known track ids are corrections. The ones in front of the camera are
   ranked by the area of their innovation ellipse (``det S``), largest first
   (they carry the most information: paper section 4.4), and at most
   ``max_corrections`` are used.
2. One-point RANSAC (Civera et al., JFR 2010): each hypothesis is the state
   after a single-measurement EKF update (mean only); its support is the
   measurements it predicts within ``ransac_inlier_sigmas * sigma_px``. The
   best support ("low-innovation inliers") updates the filter in one batch;
   then each remaining measurement is re-predicted and "rescued" if its
   squared Mahalanobis distance passes the ``rescue_chi2_prob`` quantile
   (2 dof); the rescued update the filter in a second batch. The others are
   rejected (``stats["ransac_rejected"]``, which also counts the gate's
   rejections when ``ransac`` is off or fewer than 3 measurements). Up to ``ransac_max_hypotheses``
   hypotheses (all of them with 10 corrections and the default 20) are
   projected in one batch; with every hypothesis tried, no adaptive stopping
   rule is needed.
3. Unknown track ids inside the image are candidates: up to
   ``max_init_per_frame`` become landmarks while the map holds fewer than
   ``max_landmarks``, chosen greedily farthest (in pixels) from this frame's
   mapped measurements and each other, so new points spread over the image.
4. Map management: a landmark out of the image (or behind the camera) for
   ``forget_unseen_frames`` consecutive frames leaves the state (its last
   estimate stays in the map if it was Euclidean); one predicted in view but
   not found or rejected ``max_consecutive_misses`` frames in a row is deleted
   and its track id is never initialised again. The predictions carry
   ``max_corrections`` so the front end stops searching once it has found
   that many; landmarks it reports unsearched
   (``PixelObservations.unsearched_ids``) are not misses.

Costs, n = state size, k = corrections: :meth:`predict` touches the robot rows
and columns only, O(n). The update's ``H`` is non-zero on the 7 pose columns
and one landmark block per 2-row block, so ``P H^T`` is gathered from those
columns, ``P[:, :7] H_pose^T + P[:, L_i] H_Li^T`` (O(n k)), ``S = H P H^T + R``
from the same gathered rows, and ``P -= M M^T`` with ``M = P H^T L^-T``
(``S = L L^T``) is the one O(n^2 k) step. The RANSAC hypotheses cost one
batched projection of the k selected landmarks under every hypothesis.
Dropping or converting landmarks gathers the kept block of ``P`` once and
adds the converted rows ``J P[L_i, :]`` (O(n^2), no n x n product). At the
paper's sizes (20 landmarks, n ~ 110-130) the covariance algebra is a small
part of a frame; numpy call overhead dominates (benchmarks/bench_mono_ekf.py).

Pose covariances leave the filter in the contract's convention (right
perturbation ``[rho, phi]`` of ``wTc``) through the Jacobian of that
perturbation w.r.t. ``[p, q]`` (:func:`filters.landmark_params.pose_jacobian_to_tangent`),
and enter (``initialize``) through its right inverse.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from filters import landmark_params as lp
from slamcore.errors import ConfigError, GraphSlamError, MeasurementError, UnsupportedError
from slamcore.spatial.records import PixelObservations, PixelPredictions, VisualEstimate
from slamcore.spatial.backend import VisualBackend

__all__ = ["MonoEkfConfig", "MonoEkf", "odometry_motion", "constant_velocity_motion"]


def _chi2_2dof(prob: float) -> float:
    """Chi-square quantile with 2 dof: ``-2 ln(1 - p)`` (exact for 2 dof)."""
    return -2.0 * math.log(1.0 - prob)


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _is_num(v) -> bool:
    return isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool) \
        and math.isfinite(float(v))


@dataclass(frozen=True)
class MonoEkfConfig:
    """Monocular EKF-SLAM settings (config file section ``[mono_ekf]``).

    Attributes:
        robot_model: "odometry" ([p q]) or "constant_velocity" ([p q v w]).
        landmark_param: "idp" (6) or "ahp" (7) at initialisation.
        max_landmarks: landmarks in the state at most. Default 20, the paper's
            benchmark: with out-of-view landmarks forgotten, this is the
            number mapped at once (about a quarter of the ~75 points in view
            in the synthetic loop), and at 20 with 10 corrections the filter
            costs about 3.5 ms of CPU per frame here
            (benchmarks/bench_mono_ekf.py), leaving most of a 60 Hz frame
            (16.7 ms) to detection and search. 40 (all IDP) costs about
            1.7 times as much; 30 did not lower the ATE on the synthetic
            loop (seeds 0-3).
        max_init_per_frame: new landmarks per frame at most (paper: 5).
        max_corrections: measurements used per frame at most, largest
            innovation ellipse first.
        min_depth_m: nearest depth the inverse-depth prior covers at 2 sigma
            (``rho0 = 1/(2 d)``, ``sigma_rho = 1/(4 d)``), metres. Set it to
            the scene's nearest depth: the prior mean ``2 d`` biases the first
            corrections when the scene is much farther (measured on the
            synthetic loop, points 2.5-10 m away, odometry 1 cm and 5 mrad per
            frame: pose NEES ~100-350 with 1 m, 10-20 with 2 m).
        linearity_threshold: re-parametrise to Euclidean when the linearity
            index falls below this (Civera: 0.1); 0 disables it.
        ransac: use one-point RANSAC; else each measurement is gated alone.
        ransac_inlier_sigmas: hypothesis support radius, in pixel sigmas.
        ransac_max_hypotheses: hypotheses per frame at most (one per
            measurement when there are fewer).
        rescue_chi2_prob: gate of the rescue step (and of the gating without
            RANSAC), a probability (2 dof).
        forget_unseen_frames: consecutive frames out of view before a
            landmark leaves the state.
        max_consecutive_misses: consecutive frames in view but not found (or
            rejected) before a landmark is deleted for good.
        frame_dt_s: time between frames for the constant-velocity model, s.
        cv_sigma_accel_mps2, cv_sigma_alpha_radps2: constant-velocity
            acceleration noise (linear m/s^2, angular rad/s^2), held over a frame.
        cv_initial_sigma_v_mps, cv_initial_sigma_w_radps: prior std of the
            initial velocities (zero mean).
        default_sigma_px: pixel std used by :meth:`MonoEkf.predict_observations`
            before any observation is seen.
        seed: RANSAC sampling seed.
    """

    SECTION: ClassVar[str] = "mono_ekf"

    robot_model: str = "odometry"
    landmark_param: str = "idp"
    max_landmarks: int = 20
    max_init_per_frame: int = 5
    max_corrections: int = 10
    min_depth_m: float = 1.0
    linearity_threshold: float = 0.1
    ransac: bool = True
    ransac_inlier_sigmas: float = 3.0
    ransac_max_hypotheses: int = 20
    rescue_chi2_prob: float = 0.99
    forget_unseen_frames: int = 3
    max_consecutive_misses: int = 5
    frame_dt_s: float = 1.0 / 30.0
    cv_sigma_accel_mps2: float = 4.0
    cv_sigma_alpha_radps2: float = 4.0
    cv_initial_sigma_v_mps: float = 1.0
    cv_initial_sigma_w_radps: float = 1.0
    default_sigma_px: float = 1.0
    seed: int = 0

    def __post_init__(self):
        if self.robot_model not in ("odometry", "constant_velocity"):
            raise ConfigError("mono_ekf.robot_model must be 'odometry' or 'constant_velocity', "
                              f"got {self.robot_model!r}")
        if self.landmark_param not in ("idp", "ahp"):
            raise ConfigError(f"mono_ekf.landmark_param must be 'idp' or 'ahp', got {self.landmark_param!r}")
        if not isinstance(self.ransac, bool):
            raise ConfigError(f"mono_ekf.ransac must be true or false, got {self.ransac!r}")
        for name, lo in (("max_landmarks", 1), ("max_init_per_frame", 0), ("max_corrections", 1),
                         ("ransac_max_hypotheses", 1), ("forget_unseen_frames", 1),
                         ("max_consecutive_misses", 1), ("seed", 0)):
            v = getattr(self, name)
            if not _is_int(v) or v < lo:
                raise ConfigError(f"mono_ekf.{name} must be an integer >= {lo}, got {v!r}")
        for name in ("min_depth_m", "ransac_inlier_sigmas", "frame_dt_s", "cv_sigma_accel_mps2",
                     "cv_sigma_alpha_radps2", "cv_initial_sigma_v_mps", "cv_initial_sigma_w_radps",
                     "default_sigma_px"):
            v = getattr(self, name)
            if not _is_num(v) or v <= 0:
                raise ConfigError(f"mono_ekf.{name} must be a positive number, got {v!r}")
        v = self.linearity_threshold
        if not _is_num(v) or v < 0:
            raise ConfigError(f"mono_ekf.linearity_threshold must be a number >= 0, got {v!r}")
        for name in ("rescue_chi2_prob",):
            v = getattr(self, name)
            if not _is_num(v) or not 0.0 < v < 1.0:
                raise ConfigError(f"mono_ekf.{name} must be a probability in (0, 1), got {v!r}")

    @property
    def rho0(self) -> float:
        """Prior inverse distance of a new landmark, 1/m."""
        return 0.5 / self.min_depth_m

    @property
    def sigma_rho(self) -> float:
        """Prior std of the inverse distance, 1/m."""
        return 0.25 / self.min_depth_m


@dataclass
class _Landmark:
    """Bookkeeping of one landmark in the state (the parameters live in ``X``)."""

    track_id: int
    kind: int
    unseen: int = 0  # consecutive frames out of view
    misses: int = 0  # consecutive frames in view but not found or rejected


class MonoEkf(VisualBackend):
    """Monocular EKF-SLAM back end (see the module docstring)."""

    name = "mono_ekf"
    needs_track_history = False  # landmarks initialised undelayed, from one pixel

    def __init__(self, config: MonoEkfConfig | None = None):
        self.config = config if config is not None else MonoEkfConfig()
        if not isinstance(self.config, MonoEkfConfig):
            raise ConfigError(f"MonoEkf needs a MonoEkfConfig, got {type(self.config).__name__}")
        self.has_motion_model = self.config.robot_model == "constant_velocity"
        # the contract's cap, also sent with the predictions (the front end stops there)
        self.max_corrections = int(self.config.max_corrections)
        self._rdim = 13 if self.has_motion_model else 7
        self._kind0 = lp.IDP if self.config.landmark_param == "idp" else lp.AHP
        self._rescue_gate = _chi2_2dof(self.config.rescue_chi2_prob)
        self._x: np.ndarray | None = None
        self._P: np.ndarray | None = None
        #: Track ids of the last update: ``corrected`` (used), ``rejected``
        #: (RANSAC / gate), ``initialised`` (new landmarks); (k,) int64 each.
        self.last_update: dict[str, np.ndarray] = {}

    # ------------------------------------------------------------------ state

    @property
    def state_size(self) -> int:
        return 0 if self._x is None else len(self._x)

    @property
    def num_landmarks(self) -> int:
        return 0 if self._x is None else len(self._lms)

    def state_vector(self) -> np.ndarray:
        """Copy of ``X`` (n,)."""
        self._require_init()
        return self._x.copy()

    def state_covariance(self) -> np.ndarray:
        """Copy of ``P`` (n, n)."""
        self._require_init()
        return self._P.copy()

    def landmark_slots(self) -> list[tuple[int, str, int]]:
        """``(track_id, kind name, first state index)`` of each landmark, in state order."""
        self._require_init()
        return [(lm.track_id, lp.KIND_NAMES[lm.kind], int(o))
                for lm, o in zip(self._lms, self._off)]

    def reparametrise(self, track_ids) -> int:
        """Convert the given landmarks to Euclidean now, whatever their linearity
        (tests, or a caller that knows better); returns how many were converted.
        Unknown ids, Euclidean landmarks and ``rho <= 0`` are skipped."""
        self._require_init()
        changes = {}
        for t in track_ids:
            i = self._slot.get(int(t))
            if i is None or self._kinds[i] == lp.EUCLIDEAN:
                continue
            L = self._x[self._idx[i]][None]
            if L[0, 5 if self._kinds[i] == lp.IDP else 6] <= 0:
                continue
            p_w, J = lp.to_euclidean(self._kinds[i:i + 1], L)
            changes[i] = (p_w[0], J[0, :, :lp.SIZE[int(self._kinds[i])]])
        if changes:
            self._transform(changes)
            self._stats["reparametrised"] += len(changes)
        return len(changes)

    def _require_init(self) -> None:
        if self._x is None:
            raise GraphSlamError("mono_ekf: initialize() must be called first")

    def _reindex(self) -> None:
        """Offsets, kinds and padded index rows (k, 7) of the landmarks in state order."""
        sizes = np.array([lp.SIZE[lm.kind] for lm in self._lms], dtype=np.int64)
        self._off = self._rdim + np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64) \
            if len(sizes) else np.zeros(0, dtype=np.int64)
        self._kinds = np.array([lm.kind for lm in self._lms], dtype=np.int64)
        cols = np.arange(lp.PAD)
        # padding columns repeat the landmark's first index; their Jacobian columns are zero
        self._idx = np.where(cols[None, :] < sizes[:, None], self._off[:, None] + cols[None, :],
                             self._off[:, None]) if len(sizes) else np.zeros((0, lp.PAD), np.int64)
        self._slot = {lm.track_id: i for i, lm in enumerate(self._lms)}

    def _wTc(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = lp.q2R(self._x[3:7])
        T[:3, 3] = self._x[0:3]
        return T

    def _pose_covariance(self) -> np.ndarray:
        J = lp.pose_jacobian_to_tangent(self._x[3:7])
        C = J @ self._P[:7, :7] @ J.T
        return 0.5 * (C + C.T)

    # --------------------------------------------------------------- contract

    def initialize(self, frame_id: int, wTc: np.ndarray, covariance: np.ndarray,
                   K: np.ndarray, image_size: tuple[int, int]) -> None:
        wTc = np.asarray(wTc, dtype=np.float64)
        cov = np.asarray(covariance, dtype=np.float64)
        K = np.asarray(K, dtype=np.float64)
        if wTc.shape != (4, 4) or not np.all(np.isfinite(wTc)):
            raise MeasurementError(f"mono_ekf: initial wTc must be a finite (4, 4), got {wTc.shape}")
        if not _is_rotation(wTc[:3, :3]):
            raise MeasurementError("mono_ekf: initial wTc rotation is not orthonormal")
        _check_covariance(cov, "initial pose covariance")
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0 \
                or not np.allclose(K[2], [0, 0, 1]):
            raise MeasurementError("mono_ekf: K must be a finite (3, 3) with fx, fy > 0 and last row [0 0 1]")
        W, H = image_size
        if not (_is_int(W) and _is_int(H) and W > 0 and H > 0):
            raise MeasurementError(f"mono_ekf: image_size must be two positive ints, got {image_size!r}")
        self._K = K
        self._K_inv = np.linalg.inv(K)
        self._image_size = (int(W), int(H))
        q = lp.R2q(wTc[:3, :3])
        G = lp.tangent_to_pose_jacobian(q)
        n = self._rdim
        self._x = np.zeros(n)
        self._x[0:3] = wTc[:3, 3]
        self._x[3:7] = q
        self._P = np.zeros((n, n))
        self._P[:7, :7] = G @ cov @ G.T
        if self.has_motion_model:
            c = self.config
            self._P[7:10, 7:10] = np.eye(3) * c.cv_initial_sigma_v_mps ** 2
            self._P[10:13, 10:13] = np.eye(3) * c.cv_initial_sigma_w_radps ** 2
        self._lms: list[_Landmark] = []
        self._reindex()
        self._version = 0  # bumped by every change of X or P (prediction cache key)
        self._cache = None
        self._rng = np.random.default_rng(self.config.seed)
        self._sigma_px = float(self.config.default_sigma_px)
        self._banned: set[int] = set()
        self._retired: dict[int, np.ndarray] = {}  # track id -> last Euclidean estimate
        self._frame_ids: list[int] = [int(frame_id)]
        self._poses: list[np.ndarray] = [self._wTc()]
        self._stats = {"reparametrised": 0, "ransac_rejected": 0, "initialised": 0,
                       "forgotten": 0, "deleted": 0, "corrections": 0, "frames": 1}

    def predict(self, frame_id: int, odometry: np.ndarray | None,
                covariance: np.ndarray | None) -> None:
        self._require_init()
        if frame_id == self._frame_ids[-1]:
            raise GraphSlamError(f"mono_ekf: frame {frame_id} is already the current frame")
        if odometry is None:
            if not self.has_motion_model:
                raise UnsupportedError("mono_ekf: the odometry robot model needs odometry "
                                       "(robot_model = 'constant_velocity' has a motion model)")
            c = self.config
            self._x[:13], F, G = constant_velocity_motion(self._x[:13], c.frame_dt_s)
            Q = np.diag([(c.cv_sigma_accel_mps2 * c.frame_dt_s) ** 2] * 3
                        + [(c.cv_sigma_alpha_radps2 * c.frame_dt_s) ** 2] * 3)
        else:
            T = np.asarray(odometry, dtype=np.float64)
            if T.shape != (4, 4) or not np.all(np.isfinite(T)) or not _is_rotation(T[:3, :3]):
                raise MeasurementError("mono_ekf: odometry must be a finite rigid (4, 4) transform")
            if covariance is None:
                raise MeasurementError("mono_ekf: odometry needs its (6, 6) covariance")
            Q = np.asarray(covariance, dtype=np.float64)
            _check_covariance(Q, "odometry covariance")
            r = self._rdim
            self._x[:r], F, G = odometry_motion(self._x[:r], T, self.config.frame_dt_s)
        r = self._rdim
        P = self._P
        Prr = F @ P[:r, :r] @ F.T + G @ Q @ G.T
        P[:r, :r] = 0.5 * (Prr + Prr.T)
        if len(P) > r:
            P[:r, r:] = F @ P[:r, r:]
            P[r:, :r] = P[:r, r:].T
        self._version += 1
        self._frame_ids.append(int(frame_id))
        self._poses.append(self._wTc())
        self._stats["frames"] += 1

    def predict_observations(self) -> PixelPredictions:
        self._require_init()
        uv, hz, _, _, S = self._predicted(self._sigma_px ** 2)
        vis = np.flatnonzero(self._in_view(uv, hz))
        ids = np.array([self._lms[i].track_id for i in vis], dtype=np.int64)
        with np.errstate(invalid="ignore", divide="ignore"):  # rho = 0: at infinity, not finite
            p_w, _ = lp.to_euclidean(self._kinds[vis], self._x[self._idx[vis]])
        # pose, K and positions: for the front end's appearance prediction
        return PixelPredictions(ids, uv[vis], S[vis], max_corrections=self.max_corrections,
                                wTc=self._wTc(), K=self._K.copy(), landmarks_w=p_w)

    def _predicted(self, var: float):
        """Pixels, ``h_z``, Jacobians and ``S_i`` (pixel variance ``var``) of the whole map.

        Cached until the state changes, so :meth:`update` reuses what
        :meth:`predict_observations` computed for the same state.
        """
        key = (self._version, var)
        if self._cache is None or self._cache[0] != key:
            slots = np.arange(len(self._lms))
            uv, hz, Hp, Hl = self._observe(slots)
            with np.errstate(invalid="ignore", over="ignore"):
                S = self._innovation_blocks(slots, Hp, Hl, var)  # meaningless where h_z <= 0
            self._cache = (key, uv, hz, Hp, Hl, S)
        return self._cache[1:]

    def update(self, observations: PixelObservations) -> None:
        self._require_init()
        ids, uv_px, sigma_px = _check_observations(observations)
        self._sigma_px = sigma_px
        var = sigma_px ** 2
        c = self.config
        # the whole map at the predicted state: visibility for map management,
        # predictions and S_i of the known tracks
        uv_all, hz_all, Hp_all, Hl_all, S_all = self._predicted(var)
        visible = self._in_view(uv_all, hz_all)
        known = np.array([int(t) in self._slot for t in ids], dtype=bool)
        k_rows = np.flatnonzero(known)
        k_slots = np.array([self._slot[int(ids[r])] for r in k_rows], dtype=np.int64)
        accepted = np.zeros(len(self._lms), dtype=bool)
        rejected = np.zeros(len(self._lms), dtype=bool)
        if len(k_slots):
            front = hz_all[k_slots] > 0
            k_rows, k_slots = k_rows[front], k_slots[front]
        if len(k_slots):
            uv, Hp, Hl, S = uv_all[k_slots], Hp_all[k_slots], Hl_all[k_slots], S_all[k_slots]
            area = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
            # largest ellipses first (paper 4.4); stable sort for repeatability
            order = np.argsort(-area, kind="stable")[:c.max_corrections]
            sel, z = k_slots[order], uv_px[k_rows[order]]
            nu = z - uv[order]
            PHt, S_sel = self._gain_blocks(sel, Hp[order], Hl[order], var)
            if c.ransac and len(sel) >= 3:
                inl = self._one_point_ransac(sel, z, nu, PHt, S_sel, var)
            else:
                inl = np.zeros(len(sel), dtype=bool)
            if inl.any():
                # low-innovation inliers: P H^T and S are those already computed
                cols = np.stack([2 * np.flatnonzero(inl), 2 * np.flatnonzero(inl) + 1], 1).reshape(-1)
                self._apply_update(PHt[:, cols], S_sel[np.ix_(cols, cols)], nu[inl].reshape(-1))
            rest = np.flatnonzero(~inl)
            if len(rest):
                # rescue (or plain gating): re-predict at the updated state
                uv_r, hz_r, Hp_r, Hl_r = self._observe(sel[rest])
                S_r = self._innovation_blocks(sel[rest], Hp_r, Hl_r, var)
                nu_r = z[rest] - uv_r
                d2 = np.einsum("ki,ki->k", nu_r, np.linalg.solve(S_r, nu_r[:, :, None])[:, :, 0])
                ok = (hz_r > 0) & (d2 < self._rescue_gate)
                if ok.any():
                    PHt_r, S_rr = self._gain_blocks(sel[rest[ok]], Hp_r[ok], Hl_r[ok], var)
                    self._apply_update(PHt_r, S_rr, nu_r[ok].reshape(-1))
                inl[rest[ok]] = True
            accepted[sel[inl]] = True
            rejected[sel[~inl]] = True
            corrected_ids = np.array([self._lms[i].track_id for i in sel[inl]], dtype=np.int64)
            rejected_ids = np.array([self._lms[i].track_id for i in sel[~inl]], dtype=np.int64)
            self._stats["ransac_rejected"] += int((~inl).sum())
            self._stats["corrections"] += int(inl.sum())
        else:
            corrected_ids = rejected_ids = np.zeros(0, dtype=np.int64)
        observed = np.zeros(len(self._lms), dtype=bool)
        observed[k_slots] = True
        # not searched because the front end's budget was spent: not a miss
        for t in observations.unsearched_ids.tolist():
            slot = self._slot.get(int(t))
            if slot is not None:
                observed[slot] = True
        changes = self._manage_map(visible, observed, accepted, rejected)
        if c.linearity_threshold > 0:
            changes.update(self._reparametrise(exclude=changes))
        if changes:
            self._transform(changes)
        new_ids = self._initialise(ids, uv_px, known, var)
        self._poses[-1] = self._wTc()
        self.last_update = {"corrected": corrected_ids, "rejected": rejected_ids,
                            "initialised": new_ids}

    def estimate(self) -> VisualEstimate:
        self._require_init()
        ids, pts = self._euclidean_landmarks()
        lm_ids = list(self._retired.keys())
        lm_pts = list(self._retired.values())
        in_state = set(ids.tolist())
        keep = [i for i, t in enumerate(lm_ids) if t not in in_state]
        all_ids = np.array([lm_ids[i] for i in keep] + ids.tolist(), dtype=np.int64)
        all_pts = np.array([lm_pts[i] for i in keep] + list(pts), dtype=np.float64).reshape(-1, 3)
        stats = dict(self._stats)
        for kind, name in lp.KIND_NAMES.items():
            stats[f"landmarks_{name}"] = int(np.sum(self._kinds == kind))
        stats["landmarks_in_state"] = len(self._lms)
        stats["landmarks_retired"] = len(keep)
        return VisualEstimate(frame_ids=np.array(self._frame_ids, dtype=np.int64),
                              wTc=np.stack(self._poses), landmark_ids=all_ids,
                              landmarks_w=all_pts, current_covariance=self._pose_covariance(),
                              stats=stats)

    # ------------------------------------------------------------- internals

    def _observe(self, slots: np.ndarray, jacobians: bool = True, x: np.ndarray | None = None):
        """Predicted pixels of landmark ``slots`` at state ``x`` (default the current one)."""
        x = self._x if x is None else x
        idx = self._idx[slots]
        return lp.observe_landmarks(self._K, x[0:3], x[3:7], self._kinds[slots], x[idx],
                                    jacobians=jacobians)

    def _in_view(self, uv: np.ndarray, hz: np.ndarray) -> np.ndarray:
        W, H = self._image_size
        with np.errstate(invalid="ignore"):
            return (hz > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] < W - 0.5) \
                & (uv[:, 1] >= -0.5) & (uv[:, 1] < H - 0.5)

    def _innovation_blocks(self, slots, Hp, Hl, var) -> np.ndarray:
        """Per-landmark ``S_i = H_i P H_i^T + var I`` (k, 2, 2) from the pose and landmark blocks."""
        P = self._P
        idx = self._idx[slots]
        P_pl = P[:7][:, idx].transpose(1, 0, 2)  # (k, 7, 7)
        P_ll = P[idx[:, :, None], idx[:, None, :]]  # (k, 7, 7)
        HpT = Hp.transpose(0, 2, 1)
        S = Hp @ P[:7, :7] @ HpT + Hl @ P_ll @ Hl.transpose(0, 2, 1)
        X = Hp @ P_pl @ Hl.transpose(0, 2, 1)
        S += X + X.transpose(0, 2, 1) + var * np.eye(2)
        return S

    def _gain_blocks(self, slots, Hp, Hl, var) -> tuple[np.ndarray, np.ndarray]:
        """``P H^T`` (n, 2k) from the pose and landmark columns, and ``S`` (2k, 2k)."""
        P = self._P
        n, k = len(P), len(slots)
        idx = self._idx[slots]
        Hp2 = Hp.reshape(2 * k, 7)
        PHt = P[:, :7] @ Hp2.T + np.einsum("nkj,kaj->nka", P[:, idx], Hl).reshape(n, 2 * k)
        S = Hp2 @ PHt[:7] + np.einsum("kaj,kjm->kam", Hl, PHt[idx]).reshape(2 * k, 2 * k)
        S = 0.5 * (S + S.T) + var * np.eye(2 * k)
        return PHt, S

    def _apply_update(self, PHt: np.ndarray, S: np.ndarray, nu: np.ndarray) -> None:
        """EKF correction from ``P H^T`` (n, m), ``S`` (m, m) and the innovation ``nu`` (m,)."""
        L = np.linalg.cholesky(S)
        M = np.linalg.solve(L, PHt.T).T  # (n, m) = P H^T L^-T
        self._x += M @ np.linalg.solve(L, nu)
        self._P -= M @ M.T
        self._normalise_quaternion()
        self._version += 1

    def _normalise_quaternion(self) -> None:
        q = self._x[3:7]
        nq = float(np.linalg.norm(q))
        J = (np.eye(4) - np.outer(q, q) / nq ** 2) / nq
        self._x[3:7] = q / nq
        P = self._P
        P[3:7, :] = J @ P[3:7, :]
        P[:, 3:7] = P[:, 3:7] @ J.T

    def _one_point_ransac(self, slots: np.ndarray, z: np.ndarray, nu: np.ndarray,
                          PHt: np.ndarray, S: np.ndarray, var: float) -> np.ndarray:
        """Low-innovation inliers (k,) bool of the best single-measurement hypothesis.

        ``z``, ``nu`` (k, 2): measurements and innovations at the current state;
        ``PHt`` (n, 2k), ``S`` (2k, 2k) from :meth:`_gain_blocks`. All
        hypotheses (at most ``ransac_max_hypotheses``, drawn with the seeded
        generator when there are more measurements) are evaluated in one
        batched projection: cheaper in numpy than stopping early.
        """
        c = self.config
        k = len(slots)
        m = min(c.ransac_max_hypotheses, k)
        hyp = self._rng.permutation(k)[:m] if m < k else np.arange(k)
        # x_j = x + P H_j^T S_j^-1 nu_j for every hypothesis j at once
        Sj = np.stack([S[2 * j:2 * j + 2, 2 * j:2 * j + 2] for j in hyp])
        g = np.linalg.solve(Sj, nu[hyp][:, :, None])[:, :, 0]  # (m, 2)
        cols = PHt.reshape(len(PHt), k, 2)[:, hyp, :]  # (n, m, 2)
        X = self._x[:, None] + np.einsum("nmi,mi->nm", cols, g)  # (n, m)
        q = X[3:7].T
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        uv_h, hz_h = lp.project_hypotheses(self._K, X[0:3].T, q, self._kinds[slots],
                                           X[self._idx[slots]].transpose(2, 0, 1))
        e = z[None] - uv_h
        with np.errstate(invalid="ignore"):
            sup = (hz_h > 0) & (np.einsum("mki,mki->mk", e, e) < (c.ransac_inlier_sigmas ** 2) * var)
        return sup[int(np.argmax(sup.sum(axis=1)))]  # first of the best: repeatable

    def _manage_map(self, visible, observed, accepted, rejected) -> dict:
        """Update the landmarks' counters; returns ``{slot: None}`` of those to drop."""
        c = self.config
        drop = {}
        for i, lm in enumerate(self._lms):
            if not visible[i] and not observed[i]:
                lm.unseen += 1
            else:
                lm.unseen = 0
            if accepted[i]:
                lm.misses = 0
            elif rejected[i] or (visible[i] and not observed[i]):
                lm.misses += 1
            if lm.misses >= c.max_consecutive_misses:
                self._banned.add(lm.track_id)
                self._retired.pop(lm.track_id, None)
                self._stats["deleted"] += 1
                drop[i] = None
            elif lm.unseen >= c.forget_unseen_frames:
                self._stats["forgotten"] += 1
                drop[i] = None
                if lm.kind == lp.EUCLIDEAN:  # converged: keep it in the output map
                    o = self._off[i]
                    self._retired[lm.track_id] = self._x[o:o + 3].copy()
        return drop

    def _reparametrise(self, exclude=()) -> dict:
        """``{slot: (p_w (3,), J (3, s))}`` of the landmarks linear enough to become Euclidean."""
        slots = np.array([i for i in np.flatnonzero(self._kinds != lp.EUCLIDEAN) if i not in exclude],
                         dtype=np.int64)
        if not len(slots):
            return {}
        idx = self._idx[slots]
        kinds = self._kinds[slots]
        L = self._x[idx]
        rows = np.arange(len(slots))
        rho_col = np.where(kinds == lp.IDP, 5, 6)
        rho = L[rows, rho_col]
        var_rho = self._P[idx[rows, rho_col], idx[rows, rho_col]]
        ok = rho > 0
        if not ok.any():
            return {}
        slots, kinds, L, rho, var_rho = (a[ok] for a in (slots, kinds, L, rho, var_rho))
        p_w, J = lp.to_euclidean(kinds, L)
        ray0 = p_w - L[:, 0:3]  # anchor ray, length |C| / rho
        ray = p_w - self._x[0:3]
        d0 = np.linalg.norm(ray0, axis=1)
        d = np.linalg.norm(ray, axis=1)
        sigma_d = np.sqrt(np.maximum(var_rho, 0.0)) / rho * d0  # = |C| sigma_rho / rho^2
        cos_a = np.einsum("ki,ki->k", ray0, ray) / (d0 * d)
        lin = 4.0 * sigma_d / d * np.abs(cos_a)
        conv = np.flatnonzero(lin < self.config.linearity_threshold)
        self._stats["reparametrised"] += len(conv)
        return {int(slots[j]): (p_w[j], J[j, :, :lp.SIZE[int(kinds[j])]]) for j in conv}

    def _transform(self, changes: dict) -> None:
        """Drop (value None) or convert to Euclidean (value ``(p_w, J)``) the landmark slots in ``changes``.

        ``X <- f(X)``, ``P <- T P T^T`` with ``T`` the identity on the kept
        entries plus the converted 3 x s blocks ``J``. Kept entries keep their
        order; converted landmarks move to the end of the state, so the kept
        block is one fancy-index gather ``P[keep][:, keep]`` and the converted
        rows are ``J P[L_i, :]``: O(n^2), no n x n product.
        """
        n = len(self._x)
        keep = np.ones(n, dtype=bool)
        conv, lms, moved = [], [], []
        for i, ch in changes.items():
            o, s = int(self._off[i]), lp.SIZE[int(self._kinds[i])]
            keep[o:o + s] = False
            if ch is not None:
                conv.append((np.arange(o, o + s), ch[1], ch[0]))
                lm = self._lms[i]
                moved.append(_Landmark(lm.track_id, lp.EUCLIDEAN, lm.unseen, lm.misses))
        lms = [lm for i, lm in enumerate(self._lms) if i not in changes] + moved
        kidx = np.flatnonzero(keep)
        m, c3 = len(kidx), 3 * len(conv)
        P_new = np.empty((m + c3, m + c3))
        P_new[:m, :m] = self._P[np.ix_(kidx, kidx)]
        x_new = np.empty(m + c3)
        x_new[:m] = self._x[kidx]
        if conv:
            Y = np.concatenate([J @ self._P[src] for src, J, _ in conv])  # (3c, n)
            P_new[m:, :m] = Y[:, kidx]
            P_new[:m, m:] = P_new[m:, :m].T
            for b, (src, J, p_w) in enumerate(conv):
                x_new[m + 3 * b:m + 3 * b + 3] = p_w
                for b2, (src2, J2, _) in enumerate(conv):
                    P_new[m + 3 * b:m + 3 * b + 3, m + 3 * b2:m + 3 * b2 + 3] = \
                        Y[3 * b:3 * b + 3, src2] @ J2.T
            Pc = P_new[m:, m:]
            Pc[...] = 0.5 * (Pc + Pc.T)
        self._x = x_new
        self._P = P_new
        self._lms = lms
        self._reindex()
        self._version += 1

    def _initialise(self, ids: np.ndarray, uv_px: np.ndarray, known: np.ndarray,
                    var: float) -> np.ndarray:
        """New landmarks from unknown tracks (undelayed); returns their track ids."""
        c = self.config
        none = np.zeros(0, dtype=np.int64)
        room = min(c.max_init_per_frame, c.max_landmarks - len(self._lms))
        if room <= 0:
            return none
        W, H = self._image_size
        cand = [r for r in np.flatnonzero(~known) if int(ids[r]) not in self._banned
                and -0.5 <= uv_px[r, 0] < W - 0.5 and -0.5 <= uv_px[r, 1] < H - 0.5]
        if not cand:
            return none
        # greedy farthest-point choice: spread new points away from mapped ones
        taken = list(uv_px[known])
        chosen = []
        cand_uv = uv_px[cand]
        dmin = np.full(len(cand), np.inf)
        for t in taken:
            dmin = np.minimum(dmin, np.sum((cand_uv - t) ** 2, axis=1))
        for _ in range(min(room, len(cand))):
            j = int(np.argmax(dmin))  # first of ties: input order
            chosen.append(cand[j])
            dmin = np.minimum(dmin, np.sum((cand_uv - cand_uv[j]) ** 2, axis=1))
            dmin[j] = -1.0
        rows = np.array(chosen, dtype=np.int64)
        kind = self._kind0
        s = lp.SIZE[kind]
        L, G_pose, G_uv, G_rho = lp.init_landmarks(kind, self._K_inv, self._x[0:3], self._x[3:7],
                                                   uv_px[rows], c.rho0)
        k = len(rows)
        n = len(self._x)
        Gr = G_pose.reshape(k * s, 7)
        P = self._P
        P_LX = Gr @ P[:7, :]
        P_LL = Gr @ P_LX[:, :7].T
        own = var * G_uv @ G_uv.transpose(0, 2, 1) + c.sigma_rho ** 2 * np.outer(G_rho, G_rho)
        for j in range(k):
            P_LL[j * s:(j + 1) * s, j * s:(j + 1) * s] += own[j]
        P_new = np.empty((n + k * s, n + k * s))
        P_new[:n, :n] = P
        P_new[n:, :n] = P_LX
        P_new[:n, n:] = P_LX.T
        P_new[n:, n:] = 0.5 * (P_LL + P_LL.T)
        self._P = P_new
        self._x = np.concatenate([self._x, L.reshape(-1)])
        self._lms.extend(_Landmark(int(ids[r]), kind) for r in rows)
        self._reindex()
        self._version += 1
        self._stats["initialised"] += k
        return ids[rows].astype(np.int64)

    def _euclidean_landmarks(self) -> tuple[np.ndarray, np.ndarray]:
        """Track ids and Euclidean points (m) of the state's landmarks with ``rho > 0``."""
        if not self._lms:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        L = self._x[self._idx]
        with np.errstate(invalid="ignore", divide="ignore"):
            p_w, _ = lp.to_euclidean(self._kinds, L)
        rho = np.where(self._kinds == lp.IDP, L[:, 5], L[:, 6])
        ok = (self._kinds == lp.EUCLIDEAN) | (rho > 0)
        ids = np.array([lm.track_id for lm in self._lms], dtype=np.int64)
        return ids[ok], p_w[ok]


def odometry_motion(x_r: np.ndarray, T: np.ndarray, dt_s: float):
    """Compose the robot ``x_r`` ([p q] (7,) or [p q v w] (13,)) with ``T = c_{k-1} T c_k`` (4, 4).

    ``p' = p + R(q) t``, ``q' = q (x) q_d``; for 13 states the velocities
    become the step's mean ``v' = R(q) t / dt_s``, ``w' = log(R_d) / dt_s``.
    The noise ``n = [rho, phi]`` (6,) is the contract's right perturbation,
    ``T <- T se3_exp(n)``.

    Returns ``x_r'``, ``F = d x_r' / d x_r`` (r, r), ``G = d x_r' / d n`` (r, 6).
    """
    r = len(x_r)
    p, q = x_r[0:3], x_r[3:7]
    t_d, R_d = T[:3, 3], T[:3, :3]
    q_d = lp.R2q(R_d)
    R = lp.q2R(q)
    q_new = lp.q_mul(q, q_d)
    F = np.eye(r)
    G = np.zeros((r, 6))
    dRt_dq = lp.rot_jac_q(q, t_d)
    F[0:3, 3:7] = dRt_dq
    F[3:7, 3:7] = lp.q_right(q_d)
    G[0:3, 0:3] = R @ R_d
    G[3:7, 3:6] = 0.5 * lp.q_left(q_new)[:, 1:]
    x_new = x_r.copy()
    x_new[0:3] = p + R @ t_d
    x_new[3:7] = q_new
    if r == 13:
        phi_d = lp.q2v(q_d)
        x_new[7:10] = R @ t_d / dt_s
        x_new[10:13] = phi_d / dt_s
        F[7:13, 7:13] = 0.0  # the old velocities are forgotten
        F[7:10, 3:7] = dRt_dq / dt_s
        G[7:10, 0:3] = R @ R_d / dt_s
        G[10:13, 3:6] = lp.right_jacobian_inv(phi_d) / dt_s
    return x_new, F, G


def constant_velocity_motion(x_r: np.ndarray, dt_s: float):
    """MonoSLAM constant velocity on ``x_r = [p q v w]`` (13,) over ``dt_s`` seconds.

    ``p' = p + (v + V) dt``, ``q' = q (x) v2q((w + O) dt)``, ``v' = v + V``,
    ``w' = w + O`` (``w`` in the body frame), with velocity impulses
    ``n = [V (m/s), O (rad/s)]`` (6,).

    Returns ``x_r'``, ``F`` (13, 13), ``G = d x_r' / d n`` (13, 6).
    """
    q, v, w = x_r[3:7], x_r[7:10], x_r[10:13]
    dq = lp.v2q(w * dt_s)
    F = np.eye(13)
    F[0:3, 7:10] = dt_s * np.eye(3)
    F[3:7, 3:7] = lp.q_right(dq)
    dq_dw = lp.q_left(q) @ lp.v2q_jac(w * dt_s) * dt_s
    F[3:7, 10:13] = dq_dw
    G = np.zeros((13, 6))
    G[0:3, 0:3] = dt_s * np.eye(3)
    G[7:10, 0:3] = np.eye(3)
    G[3:7, 3:6] = dq_dw
    G[10:13, 3:6] = np.eye(3)
    x_new = x_r.copy()
    x_new[0:3] = x_r[0:3] + v * dt_s
    x_new[3:7] = lp.q_mul(q, dq)
    return x_new, F, G


def _is_rotation(R: np.ndarray) -> bool:
    """Orthonormal with determinant +1, to 1e-6."""
    return bool(np.abs(R.T @ R - np.eye(3)).max() < 1e-6 and np.linalg.det(R) > 0)


def _check_covariance(C: np.ndarray, what: str) -> None:
    if C.shape != (6, 6) or not np.all(np.isfinite(C)):
        raise MeasurementError(f"mono_ekf: {what} must be a finite (6, 6), got shape {C.shape}")
    if np.abs(C - C.T).max() > 1e-12 + 1e-9 * np.abs(C).max() or np.any(np.diag(C) < 0):
        raise MeasurementError(f"mono_ekf: {what} must be symmetric with a non-negative diagonal")


def _check_observations(obs: PixelObservations) -> tuple[np.ndarray, np.ndarray, float]:
    ids = np.asarray(obs.track_ids)
    uv = np.asarray(obs.uv_px, dtype=np.float64)
    if ids.ndim != 1 or (len(ids) and not np.issubdtype(ids.dtype, np.integer)):
        raise MeasurementError("mono_ekf: track_ids must be a 1-D integer array, "
                               f"got {ids.dtype} {ids.shape}")
    if uv.shape != (len(ids), 2):
        raise MeasurementError(f"mono_ekf: uv_px must be ({len(ids)}, 2), got {uv.shape}")
    if not np.all(np.isfinite(uv)):
        raise MeasurementError("mono_ekf: non-finite pixel in the observations")
    if len(np.unique(ids)) != len(ids):
        raise MeasurementError("mono_ekf: duplicate track ids in one frame")
    s = obs.sigma_px
    if not _is_num(s) or s <= 0:
        raise MeasurementError(f"mono_ekf: sigma_px must be a positive finite number, got {s!r}")
    return ids.astype(np.int64), uv, float(s)
