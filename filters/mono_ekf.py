"""Monocular EKF-SLAM with undelayed inverse-depth landmarks (numpy only).

The filter of the FPGA paper (seed 003, sections 2 and 4.4; RT-SLAM), behind
:class:`slamcore.spatial.backend.VisualBackend`. This module holds the filter's
bookkeeping and per-frame logic; the algebra lives beside it:
:mod:`filters.mono_ekf_config` (settings), :mod:`filters.mono_ekf_checks`
(input checks), :mod:`filters.mono_ekf_motion` (motion models),
:mod:`filters.mono_ekf_correction` (``P H^T``, ``S``, the correction, one-point
RANSAC), :mod:`filters.mono_ekf_map` (adding, converting and dropping
landmarks) and :mod:`filters.mono_ekf_slots` (the landmark-slot store: which
track sits in which slot of the state, its counters, and the add, convert and
drop rules).

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
With ``depth_prior = "map"`` only an empty map (or none in view) uses it; later
landmarks take the median inverse distance of the landmarks in view, so they
inherit the map's scale instead of pulling it toward ``2 d_min``
(:meth:`MonoEkf._depth_prior`, :class:`filters.mono_ekf_config.MonoEkfConfig`).
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

Sequential active search (``[active_search] order = "sequential"``, RT-SLAM):
between :meth:`predict_observations` and :meth:`update` the front end hands
over each match at once (:meth:`MonoEkf.correct_and_repredict`): one
measurement is gated alone and corrects the state, a first batch of 3 or more
(``ransac_every``) goes through the one-point RANSAC above; the landmarks
still to search are re-predicted from the corrected state. :meth:`update` then
skips those tracks and does steps 3 and 4. Each sequential correction costs a
re-prediction of the map (O(n) projections) and an O(n^2) downdate.

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

from typing import TypeAlias

import numpy as np

from filters import landmark_params as lp
from filters.mono_ekf_checks import check_camera, check_initial_pose, check_observations, check_odometry
from filters.mono_ekf_config import MonoEkfConfig, chi2_2dof
from filters.mono_ekf_correction import (
    apply_correction,
    gain_blocks,
    gated_correction,
    innovation_blocks,
    one_point_ransac,
)
from filters.mono_ekf_motion import constant_velocity_motion, odometry_motion, propagate_covariance
from filters.mono_ekf_slots import LandmarkSlots
from slamcore.errors import ConfigError, GraphSlamError, UnsupportedError
from slamcore.spatial.backend import VisualBackend
from slamcore.spatial.records import PixelObservations, PixelPredictions, VisualEstimate

__all__ = ["MonoEkf"]

#: :meth:`MonoEkf._predicted`: pixels, ``h_z``, ``H_pose``, ``H_lm`` and ``S_i`` of the map
_Predicted: TypeAlias = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


class MonoEkf(VisualBackend):
    """Monocular EKF-SLAM back end (see the module docstring)."""

    name = "mono_ekf"
    needs_track_history = False  # landmarks initialised undelayed, from one pixel
    supports_sequential_search = True

    def __init__(self, config: MonoEkfConfig | None = None):
        self.config = config if config is not None else MonoEkfConfig()
        if not isinstance(self.config, MonoEkfConfig):
            raise ConfigError(f"MonoEkf needs a MonoEkfConfig, got {type(self.config).__name__}")
        self.has_motion_model = self.config.robot_model == "constant_velocity"
        # the contract's cap, also sent with the predictions (the front end stops there)
        self.max_corrections = int(self.config.max_corrections)
        self._rdim = 13 if self.has_motion_model else 7
        self._kind0 = lp.IDP if self.config.landmark_param == "idp" else lp.AHP
        self._rescue_gate = chi2_2dof(self.config.rescue_chi2_prob)
        self._x: np.ndarray | None = None
        self._P: np.ndarray | None = None
        self._map = LandmarkSlots(self._rdim)  # the landmarks' slots (reset by initialize)
        #: Track ids of the last update: ``corrected`` (used), ``rejected``
        #: (RANSAC / gate), ``initialised`` (new landmarks); (k,) int64 each.
        self.last_update: dict[str, np.ndarray] = {}

    # ------------------------------------------------------------------ state

    @property
    def state_size(self) -> int:
        return 0 if self._x is None else len(self._x)

    @property
    def num_landmarks(self) -> int:
        return 0 if self._x is None else len(self._map)

    def state_vector(self) -> np.ndarray:
        """Copy of ``X`` (n,)."""
        return self._state()[0].copy()

    def state_covariance(self) -> np.ndarray:
        """Copy of ``P`` (n, n)."""
        return self._state()[1].copy()

    def landmark_slots(self) -> list[tuple[int, str, int]]:
        """``(track_id, kind name, first state index)`` of each landmark, in state order."""
        self._require_init()
        return [
            (lm.track_id, lp.KIND_NAMES[lm.kind], int(o))
            for lm, o in zip(self._map.records, self._map.off, strict=True)
        ]

    def reparametrise(self, track_ids) -> int:
        """Convert the given landmarks to Euclidean now, whatever their linearity
        (tests, or a caller that knows better); returns how many were converted.
        Unknown ids, Euclidean landmarks and ``rho <= 0`` are skipped."""
        x, _ = self._state()
        changes = self._map.conversions(x, track_ids)
        if changes:
            self._transform(changes)
            self._stats["reparametrised"] += len(changes)
        return len(changes)

    def _require_init(self) -> None:
        self._state()

    def _state(self) -> tuple[np.ndarray, np.ndarray]:
        """``(X, P)`` (the arrays themselves, not copies), once :meth:`initialize` has run."""
        if self._x is None or self._P is None:
            raise GraphSlamError("mono_ekf: initialize() must be called first")
        return self._x, self._P

    def _wTc(self) -> np.ndarray:
        x, _ = self._state()
        T = np.eye(4)
        T[:3, :3] = lp.q2R(x[3:7])
        T[:3, 3] = x[0:3]
        return T

    def _pose_covariance(self) -> np.ndarray:
        x, P = self._state()
        J = lp.pose_jacobian_to_tangent(x[3:7])
        C = J @ P[:7, :7] @ J.T
        return 0.5 * (C + C.T)

    # --------------------------------------------------------------- contract

    def initialize(self, frame_id, wTc, covariance, K, image_size) -> None:
        # types: VisualBackend.initialize (the contract; mypy checks this body too)
        wTc = np.asarray(wTc, dtype=np.float64)
        cov = np.asarray(covariance, dtype=np.float64)
        K = np.array(K, dtype=np.float64)  # a copy: the caller's K may change after
        check_initial_pose(wTc, cov)
        self._image_size = check_camera(K, image_size)
        self._K = K
        self._K_inv = np.linalg.inv(K)
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
            self._P[7:10, 7:10] = np.eye(3) * c.cv_initial_sigma_v_mps**2
            self._P[10:13, 10:13] = np.eye(3) * c.cv_initial_sigma_w_radps**2
        self._map = LandmarkSlots(self._rdim)
        self._version = 0  # bumped by every change of X or P (prediction cache key)
        self._cache: (
            tuple[tuple[int, float], np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None
        ) = None
        self._rng = np.random.default_rng(self.config.seed)
        # the pixel sigma comes with each frame's observations (update); until the first
        # there is no landmark to predict, so this value is never used (a setting for it,
        # default_sigma_px, changed no run and was removed)
        self._sigma_px = 1.0
        self._frame_ids: list[int] = [int(frame_id)]
        self._poses: list[np.ndarray] = [self._wTc()]
        self._stats = {
            "reparametrised": 0,
            "ransac_rejected": 0,
            "initialised": 0,
            "forgotten": 0,
            "deleted": 0,
            "corrections": 0,
            "frames": 1,
        }
        self._sequential: dict[int, bool] = {}  # this frame: track id -> accepted (sequential)

    def predict(self, frame_id: int, odometry: np.ndarray | None, covariance: np.ndarray | None) -> None:
        x, P = self._state()
        if frame_id == self._frame_ids[-1]:
            raise GraphSlamError(f"mono_ekf: frame {frame_id} is already the current frame")
        if odometry is None:
            if not self.has_motion_model:
                raise UnsupportedError(
                    "mono_ekf: the odometry robot model needs odometry "
                    "(robot_model = 'constant_velocity' has a motion model)"
                )
            c = self.config
            x[:13], F, G = constant_velocity_motion(x[:13], c.frame_dt_s)
            Q = np.diag(
                [(c.cv_sigma_accel_mps2 * c.frame_dt_s) ** 2] * 3
                + [(c.cv_sigma_alpha_radps2 * c.frame_dt_s) ** 2] * 3
            )
        else:
            T, Q = check_odometry(odometry, covariance)
            r = self._rdim
            x[:r], F, G = odometry_motion(x[:r], T, self.config.frame_dt_s)
        propagate_covariance(P, self._rdim, F, G, Q)
        self._version += 1
        self._sequential = {}
        self._frame_ids.append(int(frame_id))
        self._poses.append(self._wTc())
        self._stats["frames"] += 1

    def predict_observations(self) -> PixelPredictions:
        x, _ = self._state()
        uv, hz, _, _, S = self._predicted(self._sigma_px**2)
        vis = np.flatnonzero(self._in_view(uv, hz))
        ids = self._map.ids[vis]
        with np.errstate(invalid="ignore", divide="ignore"):  # rho = 0: at infinity, not finite
            p_w, _ = lp.to_euclidean(self._map.kinds[vis], x[self._map.idx[vis]])
        # pose, K and positions: for the front end's appearance prediction
        return PixelPredictions(
            ids,
            uv[vis],
            S[vis],
            max_corrections=self.max_corrections,
            wTc=self._wTc(),
            K=self._K.copy(),
            landmarks_w=p_w,
        )

    def _predicted(self, var: float) -> _Predicted:
        """Pixels, ``h_z``, Jacobians and ``S_i`` (pixel variance ``var``) of the whole map.

        Cached until the state changes, so :meth:`update` reuses what
        :meth:`predict_observations` computed for the same state.
        """
        key = (self._version, var)
        if self._cache is None or self._cache[0] != key:
            slots = np.arange(len(self._map))
            uv, hz, Hp, Hl = self._observe(slots)
            with np.errstate(invalid="ignore", over="ignore"):
                S = self._innovation_blocks(slots, Hp, Hl, var)  # meaningless where h_z <= 0
            self._cache = (key, uv, hz, Hp, Hl, S)
        return self._cache[1:]

    def update(self, observations: PixelObservations) -> None:
        self._require_init()
        ids, uv_px, sigma_px = check_observations(observations)
        self._sigma_px = sigma_px
        var = sigma_px**2
        # the whole map at the predicted state: visibility for map management,
        # predictions and S_i of the known tracks
        predicted = self._predicted(var)
        visible = self._in_view(predicted[0], predicted[1])
        known = np.array([int(t) in self._map.slot for t in ids], dtype=bool)
        # tracks used by correct_and_repredict this frame are not corrected again
        k_rows = np.array(
            [r for r in np.flatnonzero(known) if int(ids[r]) not in self._sequential], dtype=np.int64
        )
        k_slots = np.array([self._map.slot[int(ids[r])] for r in k_rows], dtype=np.int64)
        accepted = np.zeros(len(self._map), dtype=bool)
        rejected = np.zeros(len(self._map), dtype=bool)
        seq_ids: dict[bool, list[int]] = {True: [], False: []}
        for t, ok in self._sequential.items():
            (accepted if ok else rejected)[self._map.slot[t]] = True
            seq_ids[ok].append(t)
        if len(k_slots):
            front = predicted[1][k_slots] > 0
            k_rows, k_slots = k_rows[front], k_slots[front]
        if len(k_slots):
            sel, inl = self._correct(k_slots, uv_px[k_rows], predicted, var)
            accepted[sel[inl]] = True
            rejected[sel[~inl]] = True
            corrected_ids, rejected_ids = self._map.ids[sel[inl]], self._map.ids[sel[~inl]]
        else:
            corrected_ids = rejected_ids = np.zeros(0, dtype=np.int64)
        corrected_ids = np.concatenate([np.array(seq_ids[True], np.int64), corrected_ids])
        rejected_ids = np.concatenate([np.array(seq_ids[False], np.int64), rejected_ids])
        observed = accepted | rejected
        observed[k_slots] = True
        # not searched because the front end's budget was spent: not a miss
        for t in observations.unsearched_ids.tolist():
            slot = self._map.slot.get(int(t))
            if slot is not None:
                observed[slot] = True
        self._manage_map(visible, observed, accepted, rejected)
        new_ids = self._initialise(ids, uv_px, known, var)
        self._poses[-1] = self._wTc()
        self.last_update = {"corrected": corrected_ids, "rejected": rejected_ids, "initialised": new_ids}

    def correct_and_repredict(self, track_ids, uv_px, pending_ids) -> tuple[np.ndarray, np.ndarray]:
        """Sequential active search (:meth:`VisualBackend.correct_and_repredict`).

        The measurements are corrected as :meth:`update` corrects a batch
        (one-point RANSAC from 3 measurements, else each gated alone at the
        ``rescue_chi2_prob`` quantile), with the last pixel sigma seen; then
        the pending landmarks are re-predicted (NaN where not in the state or
        behind the camera).
        """
        self._require_init()
        ids = np.asarray(track_ids, dtype=np.int64).reshape(-1)
        z = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
        if len(ids) != len(z) or any(int(t) not in self._map.slot or int(t) in self._sequential for t in ids):
            raise GraphSlamError(
                "mono_ekf: correct_and_repredict needs mapped tracks not yet used this frame, one pixel each"
            )
        var = self._sigma_px**2
        predicted = self._predicted(var)
        slots = np.array([self._map.slot[int(t)] for t in ids], dtype=np.int64)
        front = predicted[1][slots] > 0  # behind the camera: dropped, as update() drops them
        sel, z = slots[front], z[front]
        if len(sel) >= 3 and self.config.ransac:
            sel, inl = self._correct(sel, z, predicted, var)
        elif len(sel):
            inl = self._gated(sel, z, predicted, var)
        for i, ok in zip(sel, inl if len(sel) else (), strict=True):
            self._sequential[int(self._map.ids[i])] = bool(ok)
        pend = np.asarray(pending_ids, dtype=np.int64).reshape(-1)
        uv, hz, _, _, S = self._predicted(var)
        p = np.array([self._map.slot.get(int(t), -1) for t in pend], dtype=np.int64)
        uv_p, S_p = uv[p].copy(), S[p].copy()
        bad = (p < 0) | ~(hz[p] > 0)
        uv_p[bad], S_p[bad] = np.nan, np.nan
        return uv_p, S_p

    def _correct(
        self, k_slots: np.ndarray, z_known: np.ndarray, predicted: _Predicted, var: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Correct with the known landmarks ``k_slots`` (in front of the camera) measured at
        ``z_known`` (k, 2) px; ``predicted``: :meth:`_predicted` at this state.

        Returns the slots used (largest innovation ellipse first, at most
        ``max_corrections``) and which of them were accepted (bool).
        """
        c = self.config
        uv_all, _, Hp_all, Hl_all, S_all = predicted
        uv, Hp, Hl, S = uv_all[k_slots], Hp_all[k_slots], Hl_all[k_slots], S_all[k_slots]
        area = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
        # largest ellipses first (paper 4.4); stable sort for repeatability
        order = np.argsort(-area, kind="stable")[: c.max_corrections]
        sel, z = k_slots[order], z_known[order]
        nu = z - uv[order]
        PHt, S_sel = self._gain_blocks(sel, Hp[order], Hl[order], var)
        if c.ransac and len(sel) >= 3:
            x, _ = self._state()
            inl = one_point_ransac(
                self._rng,
                self._K,
                x,
                self._map.kinds[sel],
                self._map.idx[sel],
                z,
                nu,
                PHt,
                S_sel,
                var,
                max_hypotheses=c.ransac_max_hypotheses,
                inlier_sigmas=c.ransac_inlier_sigmas,
            )
        else:
            inl = np.zeros(len(sel), dtype=bool)
        if inl.any():
            # low-innovation inliers: P H^T and S are those already computed
            cols = np.stack([2 * np.flatnonzero(inl), 2 * np.flatnonzero(inl) + 1], 1).reshape(-1)
            self._apply_update(PHt[:, cols], S_sel[np.ix_(cols, cols)], nu[inl].reshape(-1))
        rest = np.flatnonzero(~inl)
        if len(rest):
            inl[rest[self._rescue(sel[rest], z[rest], var)]] = True
        self._stats["ransac_rejected"] += int((~inl).sum())
        self._stats["corrections"] += int(inl.sum())
        return sel, inl

    def _gated(self, slots: np.ndarray, z: np.ndarray, predicted: _Predicted, var: float) -> np.ndarray:
        """:func:`filters.mono_ekf_correction.gated_correction` of ``slots`` measured at
        ``z`` from ``predicted`` (:meth:`_predicted` at this state); returns the kept mask."""
        uv, _, Hp, Hl, S = (a[slots] for a in predicted)
        x, P = self._state()
        ok = gated_correction(x, P, self._map.idx[slots], Hp, Hl, z - uv, S, var, self._rescue_gate)
        self._version += int(ok.any())
        self._stats["ransac_rejected"] += int((~ok).sum())
        self._stats["corrections"] += int(ok.sum())
        return ok

    def _rescue(self, slots: np.ndarray, z: np.ndarray, var: float) -> np.ndarray:
        """Rescue (or plain gating): re-predict ``slots`` at the updated state, keep those
        whose Mahalanobis distance to ``z`` (k, 2) px passes the gate, and correct
        with them in one batch; returns the kept mask (k,)."""
        uv_r, hz_r, Hp_r, Hl_r = self._observe(slots)
        S_r = self._innovation_blocks(slots, Hp_r, Hl_r, var)
        nu_r = z - uv_r
        d2 = np.einsum("ki,ki->k", nu_r, np.linalg.solve(S_r, nu_r[:, :, None])[:, :, 0])
        ok = (hz_r > 0) & (d2 < self._rescue_gate)
        if ok.any():
            PHt_r, S_rr = self._gain_blocks(slots[ok], Hp_r[ok], Hl_r[ok], var)
            self._apply_update(PHt_r, S_rr, nu_r[ok].reshape(-1))
        return ok

    def estimate(self) -> VisualEstimate:
        x, P = self._state()
        ids, pts = self._map.euclidean_landmarks(x)
        lm_ids = list(self._map.retired.keys())
        lm_pts = list(self._map.retired.values())
        in_state = set(ids.tolist())
        keep = [i for i, t in enumerate(lm_ids) if t not in in_state]
        all_ids = np.array([lm_ids[i] for i in keep] + ids.tolist(), dtype=np.int64)
        all_pts = np.array([lm_pts[i] for i in keep] + list(pts), dtype=np.float64).reshape(-1, 3)
        stats = dict(self._stats)
        for kind, name in lp.KIND_NAMES.items():
            stats[f"landmarks_{name}"] = int(np.sum(self._map.kinds == kind))
        stats["landmarks_in_state"] = len(self._map)
        stats["landmarks_depth_undetermined"] = self._map.undetermined_count(x, P)
        stats["landmarks_retired"] = len(keep)
        return VisualEstimate(
            frame_ids=np.array(self._frame_ids, dtype=np.int64),
            wTc=np.stack(self._poses),
            landmark_ids=all_ids,
            landmarks_w=all_pts,
            current_covariance=self._pose_covariance(),
            stats=stats,
        )

    # ------------------------------------------------------------ the map

    def _manage_map(self, visible, observed, accepted, rejected) -> None:
        """Step 4 (drop the landmarks lost or missed too long) and the conversion of the
        landmarks linear enough to Euclidean, in one change of the state."""
        c = self.config
        x, P = self._state()
        changes, deleted, forgotten = self._map.count_frame(
            x, visible, observed, accepted, rejected, c.max_consecutive_misses, c.forget_unseen_frames
        )
        self._stats["deleted"] += deleted
        self._stats["forgotten"] += forgotten
        if c.linearity_threshold > 0:
            conv = self._map.linear_enough(x, P, c.linearity_threshold, exclude=changes)
            self._stats["reparametrised"] += len(conv)
            changes.update(conv)
        if changes:
            self._transform(changes)

    def _transform(self, changes: dict) -> None:
        """Drop or convert the landmark slots in ``changes`` (:meth:`LandmarkSlots.transform`)."""
        x, P = self._state()
        self._x, self._P = self._map.transform(x, P, changes)
        self._version += 1

    def _initialise(self, ids: np.ndarray, uv_px: np.ndarray, known: np.ndarray, var: float) -> np.ndarray:
        """Step 3: new landmarks from unknown tracks (undelayed); returns their track ids."""
        c = self.config
        room = min(c.max_init_per_frame, c.max_landmarks - len(self._map))
        rows = (
            self._map.candidates(ids, uv_px, known, self._image_size, room)
            if room > 0
            else np.zeros(0, dtype=np.int64)
        )
        if not len(rows):  # no room, or no candidate
            return rows
        kind = self._kind0
        rho0, sigma_rho = self._depth_prior()
        x, P = self._state()
        init = lp.init_landmarks(kind, self._K_inv, x[0:3], x[3:7], uv_px[rows], rho0)
        self._x, self._P = self._map.append(x, P, ids[rows], kind, init, var, sigma_rho)
        self._version += 1
        self._stats["initialised"] += len(rows)
        return ids[rows].astype(np.int64)

    def _depth_prior(self) -> tuple[float, float]:
        """``(rho0, sigma_rho)`` (1/m) of this frame's new landmarks (``depth_prior``)."""
        c = self.config
        if c.depth_prior == "fixed" or not len(self._map):
            return c.rho0, c.sigma_rho
        uv, hz, _, _ = self._observe(np.arange(len(self._map)), jacobians=False)
        vis = self._in_view(uv, hz)
        inv = self._map.inverse_distances(self._state()[0], vis)
        rho0 = float(np.median(inv)) if len(inv) else 0.0
        if not rho0 > 0:  # nothing in view, or only points at infinity: no map unit here
            return c.rho0, c.sigma_rho
        return rho0, 0.5 * max(rho0, float(inv.max()) - rho0)

    # ------------------------------------------------------------- internals

    def _observe(self, slots: np.ndarray, jacobians: bool = True, x: np.ndarray | None = None):
        """Predicted pixels of landmark ``slots`` at state ``x`` (default the current one)."""
        x = self._state()[0] if x is None else x
        idx = self._map.idx[slots]
        return lp.observe_landmarks(
            self._K, x[0:3], x[3:7], self._map.kinds[slots], x[idx], jacobians=jacobians
        )

    def _in_view(self, uv: np.ndarray, hz: np.ndarray) -> np.ndarray:
        W, H = self._image_size
        with np.errstate(invalid="ignore"):
            return (
                (hz > 0)
                & (uv[:, 0] >= -0.5)
                & (uv[:, 0] < W - 0.5)
                & (uv[:, 1] >= -0.5)
                & (uv[:, 1] < H - 0.5)
            )

    def _innovation_blocks(self, slots, Hp, Hl, var) -> np.ndarray:
        """Per-landmark ``S_i`` (k, 2, 2) of landmark ``slots``
        (:func:`filters.mono_ekf_correction.innovation_blocks`)."""
        return innovation_blocks(self._state()[1], self._map.idx[slots], Hp, Hl, var)

    def _gain_blocks(self, slots, Hp, Hl, var) -> tuple[np.ndarray, np.ndarray]:
        """``P H^T`` (n, 2k) and ``S`` (2k, 2k) of landmark ``slots``
        (:func:`filters.mono_ekf_correction.gain_blocks`)."""
        return gain_blocks(self._state()[1], self._map.idx[slots], Hp, Hl, var)

    def _apply_update(self, PHt: np.ndarray, S: np.ndarray, nu: np.ndarray) -> None:
        """EKF correction from ``P H^T`` (n, m), ``S`` (m, m) and the innovation ``nu`` (m,)."""
        x, P = self._state()
        apply_correction(x, P, PHt, S, nu)
        self._version += 1
