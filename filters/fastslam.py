"""FastSLAM 1.0 and 2.0 for 2-D range-bearing landmarks (numpy only).

Rao-Blackwellised particle filter (course slides "FastSLAM"; Montemerlo et al.
2002, 2003): each of N particles holds a pose and one small EKF per landmark.
Everything is vectorised over particles: poses are ``(N, 3)``, and per
observation the work is a handful of numpy calls on ``(N, ...)`` arrays, so a
step costs O(N) numpy work with no per-particle Python loop.

Landmark EKFs live in :class:`filters.fastslam_map.ParticleMaps`: an
append-only pool of records plus an ``(N, L)`` int32 pointer table, so
resampling copies N x L pointers and no landmark record, and an update writes
new records for the particles it touches (copy-on-write). See that module for
the scheme and its costs.

Per frame:

- :meth:`FastSlam.predict` samples each particle's motion from the odometry
  noise (odometry stored new->old is inverted, covariance through the
  Jacobian);
- :meth:`FastSlam.update` takes the frame's range-bearing observations one by
  one, for all particles at once. Association is known (``landmark_id``, or
  ``signature`` when the id is None) or unknown: then each particle picks its
  own maximum-likelihood landmark among those inside a Mahalanobis gate, and
  starts a new one when none is (new landmarks of one observation share one
  new id across particles). A landmark a particle gave to an earlier
  observation of the same scan is out of the running for the later ones
  (mutual exclusion): two landmarks 0.3-0.7 m apart, always seen together,
  otherwise merged into one in every particle (default synthetic world,
  100 particles: accuracy 91.9 -> 96.2 % for 1.0, 90.9 -> 95.0 % for 2.0).
  New landmarks come from the inverse observation model.

  * FastSLAM 1.0: weight *= N(z; h(x, m), S), S = H_m P H_m^T + R, then the
    landmark EKF update.
  * FastSLAM 2.0: the pose is drawn from a proposal that includes the
    observations: starting from the motion prediction (x_hat, Q = J_u Sigma_u J_u^T),
    each observation of a known landmark refines the Gaussian
    ``Sigma_x = [H_x^T S^-1 H_x + Sigma_x^-1]^-1``,
    ``mu_x += Sigma_x H_x^T S^-1 (z - h(mu_x, m))`` (computed in the
    equivalent Kalman form) and multiplies the weight by
    N(z; h(mu_x, m), L), ``L = H_x Sigma_x H_x^T + H_m P H_m^T + R`` (with
    Sigma_x = Q for the first observation: the 2003 paper's formula; later
    observations use the sequentially refined proposal). The pose is then
    sampled once from N(mu_x, Sigma_x) and the landmark EKFs are updated from
    it. A second ``update`` for the same pose (no motion step in between)
    cannot resample the pose any more and falls back to the 1.0 update.

  Weights are kept in log space; low-variance (systematic) resampling runs when
  the effective sample size drops below ``resample_ess_fraction * N``.

Cost per observation: known association is O(N) vectorised numpy (plus the
O(N L) int32 table copy when resampling). Unknown association evaluates every
(particle, landmark) pair, O(N L), in elementwise arithmetic on (N, L)
arrays; there is no spatial index. With unknown association ``landmark_id`` is
ignored; the back end's ids count up from 0 (one new id per observation that
starts a landmark in at least one particle; ids only dead particles knew are
dropped after resampling).

Estimates are filtering estimates: the trajectory is the history of the
weighted-mean particle pose at each step (after that step's observations, before
resampling), with the weighted particle covariance of each step; earlier poses
are never revised. Landmarks are those of the highest-weight particle.

All randomness comes from ``np.random.default_rng(seed)``: same seed and
inputs, same bits.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
import numpy as np

from slamcore.planar import geometry as models
from filters.fastslam_config import MAX_PARTICLES, FastSlamConfig
from filters.fastslam_map import ParticleMaps
from filters.fastslam_math import (
    inv2, logsumexp, low_variance_resample, max_var, positive_definite, quad, sample_gaussian,
    sym, tr,
)
from filters.numerics import Recoveries, floored_noise
from slamcore.planar.backend import Backend
from slamcore.errors import GraphSlamError, UnsupportedError
from slamcore.planar.records import (
    Estimate, Observation, ObservationKind, Odometry, Prediction, as_covariance, as_vector,
)
from slamcore.planar.geometry import wrap_angle

_LOG_2PI = math.log(2.0 * math.pi)

__all__ = ["MAX_PARTICLES", "FastSlam", "FastSlamConfig", "low_variance_resample"]


class FastSlam(Backend):
    """FastSLAM 1.0 / 2.0 back end (``name`` "fastslam1" / "fastslam2")."""

    supports_loop_closures = False

    def __init__(self, config: FastSlamConfig | None = None):
        self.config = config if config is not None else FastSlamConfig()
        self.name = f"fastslam{self.config.version}"
        self.n_particles = self.config.n_particles
        self._rng = np.random.default_rng(self.config.seed)
        self._maps = ParticleMaps(self.n_particles)
        self._poses: np.ndarray | None = None  # (N, 3)
        self._logw = np.full(self.n_particles, -math.log(self.n_particles))
        self._pose_ids: list[int] = []
        self._pose_set: set[int] = set()
        self._hist_mean: list[np.ndarray] = []
        self._hist_cov: list[np.ndarray] = []
        self._dirty = False
        self._pending: tuple[np.ndarray, np.ndarray] | None = None  # 2.0: (x_hat, Q)
        self._last_R: dict[int, np.ndarray] = {}  # landmark id -> last R
        self._best = 0
        self._next_id = 0  # unknown association: ids handed out
        self._last_associations: list[int | None] = []
        #: How many times the particles were resampled.
        self.resample_count = 0
        # (poses so far, ESS, resample_count) at the last resampling decision: read
        # by step_ess() and resampled_this_step(), never by the filter itself
        self._decision: tuple[int, float, int] = (-1, float(self.n_particles), 0)
        #: Numerical recoveries (:class:`filters.numerics.Recoveries`).
        self.recoveries = Recoveries()

    # ------------------------------------------------------------- contract
    def initialize(self, pose_id: int, wTb: np.ndarray, covariance: np.ndarray) -> None:
        if self._poses is not None:
            raise GraphSlamError(f"{self.name}: initialize() called twice")
        wTb = as_vector(wTb, 3, "initial pose")
        cov = as_covariance(covariance, 3, "initial pose")
        mean = np.broadcast_to(wTb, (self.n_particles, 3))
        self._poses = sample_gaussian(mean, np.broadcast_to(cov, (self.n_particles, 3, 3)),
                                       self._rng)
        self._pose_ids.append(int(pose_id))
        self._pose_set.add(int(pose_id))
        self._dirty = True

    def predict(self, odometry: Odometry, pose_id: int) -> None:
        self._require_init()
        cur = self._pose_ids[-1]
        if pose_id in self._pose_set:
            raise GraphSlamError(f"{self.name}: pose {pose_id} added twice")
        if odometry.from_id == cur and odometry.to_id == pose_id:
            u, cov = np.asarray(odometry.delta), np.asarray(odometry.covariance)
        elif odometry.from_id == pose_id and odometry.to_id == cur:
            u, cov = models.invert(odometry.delta, odometry.covariance)
        else:
            raise GraphSlamError(
                f"{self.name}: odometry {odometry.from_id}->{odometry.to_id} must link new pose "
                f"{pose_id} with the current pose {cur} (a filter keeps only the latest pose)")
        self._close_step()
        cov = sym(cov) * self.config.odometry_covariance_scale
        chol = np.linalg.cholesky(cov)
        eps = self._rng.standard_normal((self.n_particles, 3)) @ chol.T
        if self.config.version == 2:
            x_hat = models.compose(self._poses, u)
            _, J_u = models.compose_jacobians(self._poses, np.broadcast_to(u, self._poses.shape))
            self._pending = (x_hat, J_u @ cov @ tr(J_u))
        self._poses = models.compose(self._poses, u + eps)
        self._pose_ids.append(int(pose_id))
        self._pose_set.add(int(pose_id))
        self._dirty = True

    def update(self, observations: Sequence[Observation]) -> None:
        self._require_init()
        obs = list(observations)
        self._last_associations = []
        if not obs:
            return
        cur = self._pose_ids[-1]
        for o in obs:
            if o.kind is not ObservationKind.RANGE_BEARING:
                raise UnsupportedError(f"{self.name}: only range-bearing observations ({o.kind})")
            if o.pose_id != cur:
                raise GraphSlamError(f"{self.name}: observation from pose {o.pose_id}, "
                                     f"but the current pose is {cur}")
            if self.config.association == "known" and o.landmark_id is None \
                    and o.signature is None:
                raise GraphSlamError(f"{self.name}: known association needs a landmark_id or "
                                     f"a signature (observation from pose {o.pose_id})")
        if self.config.version == 2 and self._pending is not None:
            cols = self._update_v2(obs)
        else:
            cols = self._update_v1(obs)
        self._pending = None
        self._logw -= logsumexp(self._logw)
        self._best = int(np.argmax(self._logw))
        ids = self._maps._ids
        self._last_associations = [ids[int(c[self._best])] for c in cols]
        self._close_step(force=True)
        self._maybe_resample()
        if self.config.association == "unknown":
            self._maps.drop_empty_columns()

    def predict_observations(self, landmark_ids: Iterable[int]) -> list[Prediction]:
        self._require_init()
        # the pose and landmarks estimate() reports: the weighted mean pose with
        # its cloud covariance, and the best particle's landmark EKFs
        b = self._best
        x = self.current_pose()
        P_x = self.current_pose_covariance()
        out = []
        for lid in landmark_ids:
            col = self._maps.column(int(lid))
            if col is None:
                continue
            p = int(self._maps.pointers(np.array([b]), col)[0])
            if p < 0:
                continue
            m, P = self._maps.pool_mean[p], self._maps.pool_cov[p]
            H_x, H_m = models.observe_jacobians(x, m)
            S = H_x @ P_x @ H_x.T + H_m @ P @ H_m.T + self._last_R[int(lid)]
            out.append(Prediction(int(lid), models.observe(x, m), sym(S)))
        return out

    def estimate(self, with_covariances: bool = False) -> Estimate:
        self._require_init()
        self._close_step()
        ids, means, covs = self._maps.landmarks_of(self._best)
        return Estimate(
            pose_ids=np.array(self._pose_ids, dtype=np.int64),
            wTb=np.array(self._hist_mean),
            landmark_ids=ids,
            landmarks_w=means,
            pose_covariances=np.array(self._hist_cov) if with_covariances else None,
            landmark_covariances=covs if with_covariances else None,
        )

    def current_pose(self) -> np.ndarray:
        self._require_init()
        self._close_step()
        return self._hist_mean[-1].copy()

    def current_pose_covariance(self) -> np.ndarray | None:
        self._require_init()
        self._close_step()
        return self._hist_cov[-1].copy()

    # ------------------------------------------------------- introspection
    @property
    def particle_poses(self) -> np.ndarray:
        """(N, 3) copy of the particle poses."""
        return self._poses.copy()

    @property
    def weights(self) -> np.ndarray:
        """(N,) normalised particle weights."""
        w = np.exp(self._logw - self._logw.max())
        return w / w.sum()

    @property
    def maps(self) -> ParticleMaps:
        """The shared landmark storage (read it, do not modify it)."""
        return self._maps

    def effective_sample_size(self) -> float:
        w = self.weights
        return float(1.0 / np.sum(w * w))

    def step_ess(self) -> float:
        """ESS of the current step's weights before this step's resampling, if any.

        After a resampling the weights are uniform (:meth:`effective_sample_size`
        is N); this is the ESS that triggered it, so a time series of it shows the
        depletion. Steps without a resampling decision (no observations) give the
        ESS of the current weights.
        """
        step, ess, _ = self._decision
        return ess if step == len(self._pose_ids) else self.effective_sample_size()

    def resampled_this_step(self) -> bool:
        """Whether the particles were resampled at the current step."""
        step, _, count_before = self._decision
        return step == len(self._pose_ids) and self.resample_count > count_before

    # ------------------------------------------------------------ internals
    def _require_init(self) -> None:
        if self._poses is None:
            raise GraphSlamError(f"{self.name}: initialize() must come first")

    def _known_column(self, o: Observation) -> int:
        key = o.landmark_id if o.landmark_id is not None else o.signature
        self._last_R[int(key)] = o.covariance
        return self._maps.add_column(int(key))

    def _log_p0(self, R: np.ndarray) -> float:
        if self.config.new_landmark_log_likelihood is not None:
            return self.config.new_landmark_log_likelihood
        return -0.5 * self.config.new_landmark_mahalanobis_sq - _LOG_2PI \
            - 0.5 * math.log(np.linalg.det(R))

    def _columns_for(self, o: Observation, poses: np.ndarray,
                     pose_cov: np.ndarray | None,
                     taken: Sequence[np.ndarray] = ()) -> np.ndarray:
        """(N,) column of observation ``o`` per particle (created if new).

        ``taken``: the columns earlier observations of the same scan got, per
        particle; they are excluded (mutual exclusion: one landmark gives at
        most one observation per scan).
        """
        if self.config.association == "known":
            return np.full(self.n_particles, self._known_column(o), dtype=np.intp)
        cols, new = self._associate(o.z, o.covariance, poses, pose_cov, taken)
        if new.any():
            c = self._maps.add_column(self._next_id)
            self._next_id += 1
            cols[new] = c
        for c in np.unique(cols):
            self._last_R[self._maps._ids[int(c)]] = o.covariance
        return cols

    def _associate(self, z, R, poses, pose_cov, taken=()) -> tuple[np.ndarray, np.ndarray]:
        """Per-particle maximum likelihood among gated landmarks: (cols (N,), new (N,)).

        Evaluates every (particle, landmark) pair, O(N L), in elementwise
        arithmetic on (N, L) arrays (much faster than stacks of 2x2 matmuls).
        """
        N = self.n_particles
        C = self._maps.n_cols
        if C == 0:
            return np.zeros(N, dtype=np.intp), np.ones(N, dtype=bool)
        T = self._maps.table
        valid = T >= 0
        ptr = np.where(valid, T, 0)
        m = self._maps.pool_mean[ptr]  # (N, C, 2)
        P = self._maps.pool_cov[ptr]  # (N, C, 2, 2)
        dx = m[..., 0] - poses[:, 0:1]
        dy = m[..., 1] - poses[:, 1:2]
        q = dx * dx + dy * dy
        r = np.sqrt(q)
        # H_m = [[a, b], [c, d]], H_x = [[-a, -b, 0], [-c, -d, -1]]
        a, b, c, d = dx / r, dy / r, -dy / q, dx / q
        p00, p01, p11 = P[..., 0, 0], P[..., 0, 1], P[..., 1, 1]
        t0, t1 = a * p00 + b * p01, a * p01 + b * p11
        u0, u1 = c * p00 + d * p01, c * p01 + d * p11
        s00 = t0 * a + t1 * b + R[0, 0]
        s01 = t0 * c + t1 * d + R[0, 1]
        s11 = u0 * c + u1 * d + R[1, 1]
        if pose_cov is not None:
            X00, X01, X02 = pose_cov[:, 0:1, 0], pose_cov[:, 0:1, 1], pose_cov[:, 0:1, 2]
            X11, X12, X22 = pose_cov[:, 1:2, 1], pose_cov[:, 1:2, 2], pose_cov[:, 2:3, 2]
            s00 = s00 + a * a * X00 + 2 * a * b * X01 + b * b * X11
            s01 = s01 + a * c * X00 + (a * d + b * c) * X01 + b * d * X11 + a * X02 + b * X12
            s11 = s11 + c * c * X00 + 2 * c * d * X01 + d * d * X11 + 2 * c * X02 \
                + 2 * d * X12 + X22
        nu_r = z[0] - r
        nu_b = wrap_angle(z[1] - np.arctan2(dy, dx) + poses[:, 2:3])
        det = s00 * s11 - s01 * s01
        d2 = (s11 * nu_r * nu_r - 2 * s01 * nu_r * nu_b + s00 * nu_b * nu_b) / det
        ok = valid & (d2 <= self.config.new_landmark_mahalanobis_sq)
        rows = np.arange(N)
        for prev in taken:  # two landmarks 0.3 m apart otherwise merge into one
            ok[rows, prev] = False
        ll = np.where(ok, -0.5 * d2 - 0.5 * np.log(det), -np.inf)
        cols = np.argmax(ll, axis=1)
        return cols, ~ok.any(axis=1)

    def _landmark_step(self, z, R, cols: np.ndarray, poses: np.ndarray, weigh: bool) -> None:
        """EKF update (or initialisation) of each particle's landmark ``cols``; 1.0 weights."""
        maps = self._maps
        ptr = maps._table[np.arange(self.n_particles), cols]
        old = ptr >= 0
        i = np.flatnonzero(old)
        j = np.flatnonzero(~old)
        if i.size:
            p = ptr[i]
            m, P = maps.pool_mean[p], maps.pool_cov[p]
            x = poses[i]
            H_x, H_m = models.observe_jacobians(x, m)
            nu = models.innovation(z, models.observe(x, m))
            Rf = self._floored(R, max_var(P)[:, None] * np.sum(H_m * H_m, axis=-1))
            PHt = P @ tr(H_m)
            S = H_m @ PHt + Rf
            Sinv, logdet = inv2(S)
            if weigh:
                self._logw[i] += -0.5 * quad(nu, Sinv) - 0.5 * logdet - _LOG_2PI
            K = PHt @ Sinv
            m_new = m + np.einsum("nij,nj->ni", K, nu)
            P_new = self._joseph_where_indefinite(sym(P - K @ tr(PHt)), P, K, H_m, lambda: Rf)
            maps.write(i, cols[i], m_new, P_new)
        if j.size:
            x = poses[j]
            zz = np.broadcast_to(z, (j.size, 2))
            m_new = models.inverse_observe(x, zz)
            _, G_z = models.inverse_observe_jacobians(x, zz)
            P0 = sym(G_z @ R @ tr(G_z))
            # a 1e-9 m range against a 10 deg bearing makes P0 rank one in
            # float64: floor R against P0's own spread ([1, 1/r^2]: |rows of H_m|^2)
            spread = max_var(P0)[:, None] * np.array([1.0, 1.0 / max(z[0], 1e-300) ** 2])
            Rf, hit = floored_noise(R, spread)
            if np.any(hit):
                self.recoveries.add("noise_floor", int(np.count_nonzero(hit)))
                P0 = sym(G_z @ Rf @ tr(G_z))
            maps.write(j, cols[j], m_new, P0)
            if weigh and self.config.association == "unknown":
                self._logw[j] += self._log_p0(R)

    def _floored(self, R: np.ndarray, prior_var: np.ndarray) -> np.ndarray:
        """(n, 2, 2) ``R`` raised to the float64 floor of :mod:`filters.numerics` (counted)."""
        Rf, hit = floored_noise(R, prior_var)
        self.recoveries.add("noise_floor", int(np.count_nonzero(hit)))
        return Rf

    def _joseph_where_indefinite(self, P_new, P, K, H, noise):
        """``P_new`` (n, k, k), recomputed in Joseph form ``(I - K H) P (I - K H)^T + K R K^T``
        (positive semi-definite by construction) where the short form lost definiteness.

        ``noise()`` gives ``R`` (2, 2) or (n, 2, 2), built only when needed.
        """
        bad = ~positive_definite(P_new)
        if np.any(bad):
            self.recoveries.add("joseph_fallback", int(np.count_nonzero(bad)))
            R = np.broadcast_to(noise(), (len(P),) + (2, 2))[bad]
            IKH = np.eye(P.shape[-1]) - K[bad] @ H[bad]
            P_new = P_new.copy()
            P_new[bad] = sym(IKH @ P[bad] @ tr(IKH) + K[bad] @ R @ tr(K[bad]))
        return P_new

    def _update_v1(self, obs: list[Observation]) -> list[np.ndarray]:
        out = []
        for o in obs:
            cols = self._columns_for(o, self._poses, None, out)
            self._landmark_step(o.z, o.covariance, cols, self._poses, weigh=True)
            out.append(cols)
        return out

    def _update_v2(self, obs: list[Observation]) -> list[np.ndarray]:
        mu, Sig = self._pending
        mu, Sig = mu.copy(), Sig.copy()
        maps = self._maps
        out = []
        for o in obs:
            z, R = o.z, o.covariance
            cols = self._columns_for(o, mu, Sig, out)
            ptr = maps._table[np.arange(self.n_particles), cols]
            old = ptr >= 0
            i = np.flatnonzero(old)
            if i.size:
                p = ptr[i]
                m, P = maps.pool_mean[p], maps.pool_cov[p]
                x, Sx = mu[i], Sig[i]
                H_x, H_m = models.observe_jacobians(x, m)
                nu = models.innovation(z, models.observe(x, m))
                prior_var = (max_var(P)[:, None] * np.sum(H_m * H_m, axis=-1)
                             + max_var(Sx)[:, None] * np.sum(H_x * H_x, axis=-1))
                Rf = self._floored(R, prior_var)
                HmPHmt = H_m @ P @ tr(H_m)
                SxHt = Sx @ tr(H_x)  # (n, 3, 2)
                L = H_x @ SxHt + HmPHmt + Rf
                Linv, logdet = inv2(L)
                self._logw[i] += -0.5 * quad(nu, Linv) - 0.5 * logdet - _LOG_2PI
                K = SxHt @ Linv  # (n, 3, 2)
                x_new = x + np.einsum("nij,nj->ni", K, nu)
                x_new[:, 2] = wrap_angle(x_new[:, 2])
                mu[i] = x_new
                # the noise besides the pose's (landmark and measurement) is HmPHmt + Rf
                Sig[i] = self._joseph_where_indefinite(sym(Sx - K @ tr(SxHt)), Sx, K, H_x,
                                                       lambda: HmPHmt + Rf)
            if self.config.association == "unknown" and i.size < self.n_particles:
                self._logw[~old] += self._log_p0(R)
            out.append(cols)
        self._poses = sample_gaussian(mu, Sig, self._rng, self.recoveries)
        for o, cols in zip(obs, out):
            self._landmark_step(o.z, o.covariance, cols, self._poses, weigh=False)
        return out

    def _cloud_stats(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean pose (3,) and covariance (3, 3) of the particle cloud."""
        w = self.weights
        x = self._poses
        th = x[:, 2]
        mean = np.array([w @ x[:, 0], w @ x[:, 1],
                         math.atan2(float(w @ np.sin(th)), float(w @ np.cos(th)))])
        d = x - mean
        d[:, 2] = wrap_angle(d[:, 2])
        cov = (d * w[:, None]).T @ d
        return mean, sym(cov)

    def _close_step(self, force: bool = False) -> None:
        """Record (or refresh) the history entry of the current pose."""
        if not (self._dirty or force):
            return
        mean, cov = self._cloud_stats()
        k = len(self._pose_ids)
        if len(self._hist_mean) == k:
            self._hist_mean[-1], self._hist_cov[-1] = mean, cov
        else:
            self._hist_mean.append(mean)
            self._hist_cov.append(cov)
        self._dirty = False

    def _maybe_resample(self) -> None:
        w = self.weights
        ess = 1.0 / float(np.sum(w * w))
        self._decision = (len(self._pose_ids), ess, self.resample_count)
        if ess >= self.config.resample_ess_fraction * self.n_particles:
            return
        parents = low_variance_resample(w, self._rng)
        self._poses = self._poses[parents]
        self._maps.resample(parents)
        self._best = int(np.flatnonzero(parents == self._best)[0])
        self._logw = np.full(self.n_particles, -math.log(self.n_particles))
        self.resample_count += 1
