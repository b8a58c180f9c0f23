"""FastSLAM 1.0 and 2.0 for 2-D range-bearing landmarks (numpy only).

Rao-Blackwellised particle filter (course slides "FastSLAM"; Montemerlo et al.
2002, 2003): each of N particles holds a pose and one small EKF per landmark.
Everything is vectorised over particles: poses are ``(N, 3)``, and the landmark
EKF steps of a whole scan are one elementwise pass over its (particle,
observation) pairs (:mod:`filters.fastslam_update`), so a step costs O(N K)
numpy work with no per-particle Python loop and a few dozen numpy calls per
scan; only 2.0's proposal takes one pass per observation.

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
    The proposal covariances are checked for definiteness once per scan; if
    that fails the scan's proposal is recomputed with a check (and Joseph-form
    repair) at every observation.

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
from filters.fastslam_math import logsumexp, low_variance_resample, rotated_xy, sample_gaussian, sym
from filters.fastslam_update import ParticleUpdates
from filters.numerics import Recoveries
from slamcore.planar.backend import Backend
from slamcore.errors import GraphSlamError, UnsupportedError
from slamcore.planar.records import (
    Estimate, Observation, ObservationKind, Odometry, Prediction, as_covariance, as_vector,
)
from slamcore.planar.geometry import wrap_angle

_LOG_2PI = math.log(2.0 * math.pi)

__all__ = ["MAX_PARTICLES", "FastSlam", "FastSlamConfig", "low_variance_resample"]


class FastSlam(ParticleUpdates, Backend):
    """FastSLAM 1.0 / 2.0 back end (``name`` "fastslam1" / "fastslam2")."""

    supports_loop_closures = False

    def __init__(self, config: FastSlamConfig | None = None):
        self.config = config if config is not None else FastSlamConfig()
        self.name = f"fastslam{self.config.version}"
        self.n_particles = self.config.n_particles
        self._rng = np.random.default_rng(self.config.seed)
        self._rows = np.arange(self.n_particles)
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
            self._pending = (models.compose(self._poses, u), rotated_xy(cov, self._poses[:, 2]))
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
                raise UnsupportedError(f"{self.name} handles range-bearing observations only, "
                                       f"got {o.kind.value}")
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
        w = self.weights
        self._close_step(force=True, w=w)
        self._maybe_resample(w)
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

    def _update_v1(self, obs: list[Observation]) -> list[np.ndarray]:
        # association ignores the landmarks earlier observations of the scan took
        # (mutual exclusion), so it may run before their updates
        out: list[np.ndarray] = []
        for o in obs:
            out.append(self._columns_for(o, self._poses, None, out))
        self._scan_steps(obs, out, self._poses, weigh=True)
        return out

    def _update_v2(self, obs: list[Observation]) -> list[np.ndarray]:
        logw, counts = self._logw.copy(), dict(self.recoveries)
        with np.errstate(invalid="ignore", divide="ignore"):  # a failed pass is redone
            mu, Sig, out, ok = self._proposal(obs)
        if not ok:  # a proposal covariance lost definiteness: again, checking every step
            self._logw = logw
            self.recoveries.update(counts)
            mu, Sig, _, _ = self._proposal(obs, out)
        self._poses = sample_gaussian(mu, Sig, self._rng, self.recoveries)
        self._scan_steps(obs, out, self._poses, weigh=False)
        return out

    def _cloud_stats(self, w: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean pose (3,) and covariance (3, 3) of the particle cloud (weights ``w``)."""
        w = self.weights if w is None else w
        x = self._poses
        th = x[:, 2]
        mean = np.array([w @ x[:, 0], w @ x[:, 1],
                         math.atan2(float(w @ np.sin(th)), float(w @ np.cos(th)))])
        d = x - mean
        d[:, 2] = wrap_angle(d[:, 2])
        cov = (d * w[:, None]).T @ d
        return mean, sym(cov)

    def _close_step(self, force: bool = False, w: np.ndarray | None = None) -> None:
        """Record (or refresh) the history entry of the current pose."""
        if not (self._dirty or force):
            return
        mean, cov = self._cloud_stats(w)
        k = len(self._pose_ids)
        if len(self._hist_mean) == k:
            self._hist_mean[-1], self._hist_cov[-1] = mean, cov
        else:
            self._hist_mean.append(mean)
            self._hist_cov.append(cov)
        self._dirty = False

    def _maybe_resample(self, w: np.ndarray) -> None:
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
