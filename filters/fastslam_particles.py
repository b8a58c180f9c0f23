"""The particle set of FastSLAM (:class:`filters.fastslam.FastSlam`): poses, weights and
landmark maps of N particles, and every step that changes them.

:class:`ParticleSet` owns the filter's state: the poses, log-weights, per-particle
landmark EKFs (:class:`~filters.fastslam_map.ParticleMaps`), the random stream every draw
comes from, FastSLAM 2.0's motion prediction, the landmark ids and noises of the
association, and the numerical recovery counts. Its methods are the particle filter's
steps: the initial draw, the motion draw, the measurement update of a scan (association,
2.0 proposal, landmark EKF steps of :mod:`filters.fastslam_update`, weights) and
resampling. :class:`~filters.fastslam.FastSlam` keeps the back-end contract around it
(input checks, pose ids, the history of estimates, the resampling decision).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from filters.association import t2_quantile
from filters.fastslam_config import FastSlamConfig
from filters.fastslam_map import ParticleMaps
from filters.fastslam_math import (
    all_positive_definite3,
    log_likelihood,
    logsumexp,
    low_variance_resample,
    rotated_xy,
    sample_gaussian,
    sandwich,
    t2_log_normaliser,
)
from filters.fastslam_update import landmark_steps, refine_proposal, weight_shares
from filters.landmark_existence import cusum_steps
from filters.numerics import Recoveries
from filters.numerics import symmetrise as sym
from slamcore.errors import GraphSlamError
from slamcore.planar import geometry as models
from slamcore.planar.geometry import wrap_angle
from slamcore.planar.records import Observation, SensorField

_LOG_2PI = math.log(2.0 * math.pi)
#: Probability of the new-landmark gate when ``new_landmark_mahalanobis_sq`` is unset:
#: the association gate of the EKF and iSAM2 (``gate_chi2_prob``, ``association_gate_prob``).
NEW_LANDMARK_PROB = 0.999

__all__ = ["ParticleSet"]


class ParticleSet:
    """N weighted FastSLAM particles: poses, log-weights, landmark maps, and their steps.

    Owns what the particle filter's arithmetic changes, so that one object holds it and
    the steps take and change only their own state: :attr:`poses` (N, 3), :attr:`logw`
    (N,), :attr:`maps`, :attr:`rng` (all randomness, in the order the steps run),
    :attr:`recoveries`, :attr:`last_noise` (landmark id -> the last measurement noise
    it was seen with, for predictions), the 2.0 motion prediction of the current step and
    the next landmark id of unknown association. Separate from
    :class:`~filters.fastslam.FastSlam` so that this state has one owner: the back end
    checks the inputs, keeps pose ids and the estimate history and decides when to
    resample, and only reads the set's public attributes.
    """

    def __init__(self, config: FastSlamConfig):
        self.config = config
        self.n_particles = config.n_particles
        self.rng = np.random.default_rng(config.seed)
        self.maps = ParticleMaps(self.n_particles)
        #: (N, 3) particle poses: empty until :meth:`draw_initial`.
        self.poses = np.zeros((0, 3))
        self.logw = np.full(self.n_particles, -math.log(self.n_particles))
        self.recoveries = Recoveries()
        self.last_noise: dict[int, np.ndarray] = {}
        self._rows = np.arange(self.n_particles)
        self._prior: tuple[np.ndarray, np.ndarray] | None = None  # 2.0: (x_hat, Q)
        self._next_id = 0  # unknown association: ids handed out
        #: Unknown association: the squared Mahalanobis gate of a new landmark
        #: (``new_landmark_mahalanobis_sq``, or the sensor's error quantile: :meth:`set_error_dof`).
        self.new_gate_d2 = self._new_gate(math.inf)
        #: Known association, 2.0: the squared Mahalanobis gate beyond which a sighting is
        #: taken as a misread id and neither refines a particle's proposal nor updates its
        #: landmark record (the sensor's :data:`NEW_LANDMARK_PROB` quantile;
        #: :func:`~filters.fastslam_update.refine_proposal`).
        self.misread_gate_d2 = t2_quantile(NEW_LANDMARK_PROB, math.inf)
        #: (particle, sighting) pairs the misread gate kept out of 2.0's proposal, and the
        #: sightings it kept out for at least half the particles (rejected)
        self.misreads = 0
        self.rejected = 0
        #: (particle, record) pairs restarted after a run of misreads (:meth:`_restart_misread_records`)
        self.misread_restarts = 0
        #: the last scan's misread masks, per observation (N,); None when none held
        self.last_misread: list[np.ndarray] | None = None
        #: The sensor's error law the weights use: Student-t dof (inf: Gaussian), from
        #: the data's sensor field (:meth:`set_error_dof`).
        self.error_dof = math.inf
        #: Several robots: each other robot's latest pose id -> its (N, 3) particle poses
        #: (every particle holds every robot's latest pose; :attr:`poses` is the one moving).
        self.parked: dict[int, np.ndarray] = {}
        #: Unknown association: the sensor's field and the pruning's ``(miss, limit)``
        #: (:meth:`set_sensor_field`); None: no pruning.
        self.field: SensorField | None = None
        self._cusum: tuple[float, float] | None = None
        #: (particle, landmark) pairs the pruning removed
        self.pruned = 0
        #: ids of the landmarks the pruning removed from the last particle that held them
        #: (gone from the filter's map, as the EKF's pruned landmarks are from its one map)
        self.pruned_ids: list[int] = []

    # ------------------------------------------------------------- draws
    def draw_initial(self, wTb: np.ndarray, cov: np.ndarray) -> None:
        """Poses drawn around the first pose ``wTb`` (3,) with covariance ``cov`` (3, 3)."""
        N = self.n_particles
        mean = np.broadcast_to(wTb, (N, 3))
        self.poses = sample_gaussian(mean, np.broadcast_to(cov, (N, 3, 3)), self.rng)

    def move(self, u: np.ndarray, cov: np.ndarray) -> None:
        """Motion step by odometry ``u`` (3,) with noise ``cov`` (3, 3), scaled by the
        config's ``odometry_covariance_scale``; 2.0 keeps the prediction its proposal
        starts from."""
        cov = sym(cov) * self.config.odometry_covariance_scale
        chol = np.linalg.cholesky(cov)
        eps = self.rng.standard_normal((self.n_particles, 3)) @ chol.T
        if self.config.version == 2:
            self._prior = (models.compose(self.poses, u), rotated_xy(cov, self.poses[:, 2]))
        self.poses = models.compose(self.poses, u + eps)

    def park_and_start(self, active_id: int, mean: np.ndarray, cov: np.ndarray) -> None:
        """Several robots: park the moving robot's poses under ``active_id`` and draw the
        poses of a robot that starts at ``mean`` (3,) with covariance ``cov`` (3, 3)."""
        self.parked[int(active_id)] = self.poses
        N = self.n_particles
        self.poses = sample_gaussian(np.broadcast_to(mean, (N, 3)), np.broadcast_to(cov, (N, 3, 3)), self.rng)
        self._prior = None

    def activate(self, pose_id: int, active_id: int) -> None:
        """Several robots: the parked poses of ``pose_id`` move now; the moving robot's
        are parked under ``active_id``."""
        moving = self.parked.pop(int(pose_id))
        self.parked[int(active_id)] = self.poses
        self.poses = moving
        self._prior = None

    def weigh_sighting(
        self, from_poses: np.ndarray, to_poses: np.ndarray, z: np.ndarray, R: np.ndarray
    ) -> None:
        """Several robots: weigh each particle by the likelihood of the range and bearing
        ``z`` (2,) (covariance ``R``) of its ``to_poses`` (N, 3) seen from its
        ``from_poses`` (N, 3), under the sensor's error law as the landmarks' sightings
        (:attr:`error_dof`: one camera sees both); the log-weights are normalised after."""
        nu = models.innovation(z, models.observe(from_poses, to_poses[:, :2]))
        r = sym(R)
        det = float(r[0, 0] * r[1, 1] - r[0, 1] ** 2)
        if not det > 0.0:
            raise GraphSlamError("a robot sighting's covariance is not positive definite")
        inv = (r[1, 1] / det, -r[0, 1] / det, r[0, 0] / det)
        self.logw += log_likelihood(nu[:, 0], nu[:, 1], inv, det, self.error_dof)
        self.logw -= logsumexp(self.logw)

    def resample(self, w: np.ndarray) -> np.ndarray:
        """Low-variance resampling by the weights ``w``; uniform weights after. Returns
        the parent of each new particle (N,)."""
        parents = low_variance_resample(w, self.rng)
        self.poses = self.poses[parents]
        for pid, poses in self.parked.items():
            self.parked[pid] = poses[parents]
        self.maps.resample(parents)
        self.logw = np.full(self.n_particles, -math.log(self.n_particles))
        return parents

    # ------------------------------------------------------------ weights
    @property
    def weights(self) -> np.ndarray:
        """(N,) normalised particle weights."""
        w = np.exp(self.logw - self.logw.max())
        return w / w.sum()

    def cloud_stats(
        self, w: np.ndarray | None = None, poses: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean pose (3,) and covariance (3, 3) of the moving robot's poses, or
        of ``poses`` (N, 3) (a parked robot's) (weights ``w``)."""
        w = self.weights if w is None else w
        x = self.poses if poses is None else poses
        th = x[:, 2]
        mean = np.array([w @ x[:, 0], w @ x[:, 1], math.atan2(float(w @ np.sin(th)), float(w @ np.cos(th)))])
        d = x - mean
        d[:, 2] = wrap_angle(d[:, 2])
        cov = (d * w[:, None]).T @ d
        return mean, sym(cov)

    # ------------------------------------------------------------- update
    def update(self, obs: list[Observation]) -> list[np.ndarray]:
        """Measurement update by a scan's observations (checked by the caller): the
        landmark column of each observation per particle (N,), in order. Normalises the
        log-weights; the 2.0 motion prediction is used up."""
        self.last_misread = None
        if self.config.version == 2 and self._prior is not None:
            cols = self._update_v2(obs)
        else:
            cols = self._update_v1(obs)
        self._prior = None
        self.logw -= logsumexp(self.logw)
        if self._cusum is not None:
            self._prune_missed(obs, cols)
        return cols

    def _update_v1(self, obs: list[Observation]) -> list[np.ndarray]:
        # association ignores the landmarks earlier observations of the scan took
        # (mutual exclusion), so it may run before their updates
        out: list[np.ndarray] = []
        clashes = self._scan_assignment(obs, self.poses)
        for k, o in enumerate(obs):
            out.append(self._columns_for(o, self.poses, None, out, clashes, k))
        self._scan_steps(obs, out, self.poses, weigh=True)
        return out

    def _update_v2(self, obs: list[Observation]) -> list[np.ndarray]:
        logw, counts, misreads = self.logw.copy(), dict(self.recoveries), (self.misreads, self.rejected)
        with np.errstate(invalid="ignore", divide="ignore"):  # a failed pass is redone
            mu, Sig, out, ok, skip = self._proposal(obs)
        if not ok:  # a proposal covariance lost definiteness: again, checking every step
            self.logw = logw
            self.recoveries.update(counts)
            self.misreads, self.rejected = misreads
            mu, Sig, _, _, skip = self._proposal(obs, out)
        self.poses = sample_gaussian(mu, Sig, self.rng, self.recoveries)
        self.last_misread = skip if any(m.any() for m in skip) else None
        if self.last_misread is not None:  # the scan's sightings of records each particle had
            had = [self._pointers(c) >= 0 for c in out]
        # a misread is no sighting of the landmark: its record is left as it was
        self._scan_steps(obs, out, self.poses, weigh=False, skip=skip)
        if self.last_misread is not None:
            # a particle that took in another landmark's sighting in this scan has its
            # pose confirmed: the held-out sighting then speaks against the record
            confirmed = np.logical_or.reduce([h & ~m for h, m in zip(had, skip, strict=True)])
            self._restart_misread_records(obs, out, skip, confirmed)
        return out

    def _restart_misread_records(
        self, obs: list[Observation], cols: list[np.ndarray], skip, confirmed: np.ndarray
    ) -> None:
        """2.0, known ids: a landmark record whose sightings the misread gate has kept out
        for longer than the sensor's misreads last is the wrong one (its particle's pose
        was off when it began): it starts again from this sighting, in the particles whose
        pose the scan ``confirmed`` (N,) through another landmark's sighting it took in.
        Where every sighting of the scan was held out, the pose is as likely to be off as
        the record (MRCLAM's joint run: robot 1 off in every particle held out its
        sightings of landmarks 16-18, whose records the other robots had built), and the
        record is kept. Under known ids every particle still pointing at a record after the
        scan held that sighting out, so the run's start is kept on the shared record."""
        T = self.config.misread_restart_s
        for k, o in enumerate(obs):
            if not skip[k].any() or o.stamp_s is None:
                continue
            i = np.flatnonzero(skip[k])
            p = self._pointers(cols[k])[i]
            since = self.maps.pool_misread_since[p]
            fresh = np.isnan(since)
            self.maps.pool_misread_since[p[fresh]] = o.stamp_s
            stale = ~fresh & (o.stamp_s - since > T) & confirmed[i]
            if stale.any():
                self.maps.table[i[stale], int(cols[k][0])] = -1
                keep = np.ones(self.n_particles, dtype=bool)
                keep[i[stale]] = False
                self._landmark_steps([o], [cols[k]], self.poses, weigh=False, skip=[keep])
                self.misread_restarts += int(stale.sum())

    def _scan_steps(
        self,
        obs: list[Observation],
        cols: list[np.ndarray],
        poses: np.ndarray,
        weigh: bool,
        skip: list[np.ndarray] | None = None,
    ) -> None:
        """Landmark steps of a scan: in one pass, or one per observation when a known id
        repeats in the scan (its updates must then follow each other); ``skip``: per
        observation, (N,) True where a particle took it as a misread id."""
        if self.config.association == "known" and len({int(c[0]) for c in cols}) < len(cols):
            for k, (o, c) in enumerate(zip(obs, cols, strict=True)):
                self._landmark_steps([o], [c], poses, weigh, None if skip is None else [skip[k]])
        else:
            self._landmark_steps(obs, cols, poses, weigh, skip)

    def _landmark_steps(
        self,
        obs: list[Observation],
        cols: list[np.ndarray],
        poses: np.ndarray,
        weigh: bool,
        skip: list[np.ndarray] | None = None,
    ) -> None:
        """:func:`~filters.fastslam_update.landmark_steps` on this set (1.0: ``weigh``)."""
        unknown = self.config.association == "unknown"
        landmark_steps(
            self.maps,
            obs,
            cols,
            poses,
            self.recoveries,
            known=not unknown,
            logw=self.logw if weigh else None,
            log_p0=self._log_p0 if unknown else None,
            temper=self.config.temper_correlated,
            dof=self.error_dof,
            robust=not weigh,  # after 2.0's draw (filters.fastslam_math.t_noise_factor)
            skip=None if skip is None or not any(m.any() for m in skip) else np.stack(skip, axis=1),
        )

    def _proposal(self, obs: list[Observation], cols: list[np.ndarray] | None = None):
        """2.0: the pose proposal N(mu, Sig), from the motion prediction of :meth:`move`,
        refined by each observation of a known landmark, weights included:
        ``(mu, Sig, columns, ok, misread)``, ``misread`` per observation (N,), True
        where the misread gate kept it out of a particle's proposal.

        Without ``cols`` (the first pass) the columns are chosen here and the covariances
        are checked once, at the end: a downdate by a positive definite ``L`` keeps an
        indefinite matrix indefinite, so a final positive definite ``Sig`` with every
        ``L`` positive definite means no step lost definiteness (``ok``). With ``cols``
        (the second pass, after a failed check) every step is symmetrised and checked,
        and repaired in Joseph form where it lost definiteness.
        """
        if self._prior is None:
            raise GraphSlamError("FastSLAM 2.0's proposal needs a motion step first")
        careful = cols is not None
        mu, Sig = (a.copy() for a in self._prior)
        out: list[np.ndarray] = []
        skip: list[np.ndarray] = []
        ok = True
        # known ids may be misread: gated under the predicted cloud's spread
        gate = (
            (self.cloud_stats(poses=mu)[1], self.misread_gate_d2)
            if self.config.association == "known"
            else None
        )
        clashes = self._scan_assignment(obs, mu) if cols is None else None
        for k, o in enumerate(obs):
            c = cols[k] if cols is not None else self._columns_for(o, mu, Sig, out, clashes, k)
            ptr = self._pointers(c)
            old = ptr >= 0
            n_old = int(np.count_nonzero(old))
            misread = np.zeros(self.n_particles, dtype=bool)
            if n_old:
                i = slice(None) if n_old == self.n_particles else np.flatnonzero(old)
                mu, Sig, step_ok, misread[i] = self._refine(o, i, ptr[i], mu, Sig, careful, gate)
                ok = ok and step_ok
            skip.append(misread)
            if self.config.association == "unknown" and n_old < self.n_particles:
                self.logw[~old] += self._log_p0(o.covariance)
            out.append(c)
        return mu, Sig, out, careful or (ok and all_positive_definite3(Sig)), skip

    def _refine(
        self, o: Observation, i, p: np.ndarray, mu: np.ndarray, Sig: np.ndarray, careful: bool, gate=None
    ) -> tuple[np.ndarray, np.ndarray, bool, np.ndarray]:
        """2.0: particles ``i``'s proposal N(mu, Sig) refined by observation ``o`` of their
        landmark records ``p`` (returned; updated in place for a subset), and weighed by it;
        ``gate``: the misread gate (:func:`~filters.fastslam_update.refine_proposal`), whose
        mask over ``i`` is returned last."""
        share = weight_shares(self.maps, p, [o], 0) if self.config.temper_correlated else None
        if isinstance(i, slice):
            x_new, S_new, logl, ok, misread = refine_proposal(
                self.maps, o, p, mu, Sig, careful, self.recoveries, self.error_dof, gate
            )
            self.logw += logl if share is None else logl * share
            self._count_misreads(misread)
            return x_new, S_new, ok, misread
        x_new, S_new, logl, ok, misread = refine_proposal(
            self.maps, o, p, mu[i], Sig[i], careful, self.recoveries, self.error_dof, gate
        )
        self.logw[i] += logl if share is None else logl * share
        self._count_misreads(misread)
        mu[i], Sig[i] = x_new, S_new
        return mu, Sig, ok, misread

    def _count_misreads(self, misread: np.ndarray) -> None:
        n = int(np.count_nonzero(misread))
        self.misreads += n
        self.rejected += int(2 * n >= self.n_particles)

    def _pointers(self, cols: np.ndarray) -> np.ndarray:
        """(N,) pool index of each particle's landmark ``cols`` (-1: unknown to it)."""
        if self.config.association == "known":  # one column for all particles
            return self.maps.table[:, int(cols[0])]
        return self.maps.table[self._rows, cols]

    # -------------------------------------------------------- association
    def _new_gate(self, dof: float) -> float:
        gate = self.config.new_landmark_mahalanobis_sq
        return t2_quantile(NEW_LANDMARK_PROB, dof) if gate is None else gate

    def set_sensor_field(self, field: SensorField | None) -> None:
        """The sensor's field (None: unknown): its error tail sets the new-landmark gate
        (:meth:`set_error_dof`), and with unknown association and ``prune_missed_alpha``
        its field and detection probability prune the landmarks each particle misses
        (:meth:`_prune_missed`)."""
        self.set_error_dof(math.inf if field is None else field.error_dof)
        alpha = self.config.prune_missed_alpha
        self.field, self._cusum = None, None
        if field is not None and alpha > 0.0 and self.config.association == "unknown":
            self.field, self._cusum = field, cusum_steps(field.detection_prob, alpha)

    def _prune_missed(self, obs: list[Observation], cols: list[np.ndarray]) -> None:
        """Missed sightings, per particle (``[fastslam] prune_missed_alpha``): each
        particle's landmarks that lay surely in the sensor's field this scan as its pose
        sees them (three sigmas of the predicted measurement to spare), that it paired with
        no observation of the scan and that no observation of the scan gates (an
        unpaired one may be its sighting), add one miss to their scores; a paired one
        resets its score; a landmark whose score reaches the limit leaves that particle
        (:mod:`filters.landmark_existence`, as the EKF prunes its one map). Vectorised over
        (particle, landmark) pairs like :meth:`associate`."""
        field, cusum = self.field, self._cusum
        maps = self.maps
        if field is None or cusum is None or maps.n_cols == 0:
            return
        T = maps.table
        valid = T >= 0
        ptr = np.where(valid, T, 0)
        m = maps.pool_mean[ptr]
        poses = self.poses
        dx = m[..., 0] - poses[:, 0:1]
        dy = m[..., 1] - poses[:, 1:2]
        q = np.maximum(dx * dx + dy * dy, 1e-300)
        r = np.sqrt(q)
        bearing = wrap_angle(np.arctan2(dy, dx) - poses[:, 2:3])
        seen = np.zeros_like(valid)
        for col in cols:
            seen[self._rows, col] = True
        score = maps.score
        score[seen] = 0.0
        # the pairs that may be inside (the margins only shrink the field): the rest of the
        # arithmetic runs on them alone, a few of the map's landmarks per particle
        i, j = np.nonzero(valid & ~seen & (r <= field.max_range_m) & (np.abs(bearing) <= field.half_fov_rad))
        if i.size == 0:
            return
        P = maps.pool_cov[ptr[i, j]]
        dx, dy, q, r, bearing = dx[i, j], dy[i, j], q[i, j], r[i, j], bearing[i, j]
        a, b, c, d = dx / r, dy / r, -dy / q, dx / q
        # the cloud's pose spread widens the margin and the gates as the EKF's pose
        # covariance does (a particle a little off must not count its own landmark missed)
        X = self.cloud_stats()[1]
        # H_m P H_m^T + H_x X H_x^T: the xy block of X enters as P does (H_x = -[H_m | 0, 1])
        (h00, h01, h11), _ = sandwich(
            a, b, c, d, P[:, 0, 0] + X[0, 0], P[:, 0, 1] + X[0, 1], P[:, 1, 1] + X[1, 1]
        )
        h01 = h01 + a * X[0, 2] + b * X[1, 2]
        h11 = h11 + 2 * (c * X[0, 2] + d * X[1, 2]) + X[2, 2]
        R = obs[-1].covariance  # the scan's noise, as the EKF's pruning takes it
        sd_r = 3.0 * np.sqrt(np.maximum(h00 + R[0, 0], 0.0))
        sd_b = 3.0 * np.sqrt(np.maximum(h11 + R[1, 1], 0.0))
        missed = (r + sd_r <= field.max_range_m) & (np.abs(bearing) + sd_b <= field.half_fov_rad)
        for o in obs:  # an observation inside a landmark's gate may be its sighting
            s00, s01, s11 = h00 + o.covariance[0, 0], h01 + o.covariance[0, 1], h11 + o.covariance[1, 1]
            nu_r = o.z[0] - r
            nu_b = wrap_angle(o.z[1] - bearing)
            det = s00 * s11 - s01 * s01
            missed &= ~(
                (s11 * nu_r * nu_r - 2 * s01 * nu_r * nu_b + s00 * nu_b * nu_b) <= self.new_gate_d2 * det
            )
        i, j = i[missed], j[missed]
        score[i, j] += cusum[0]
        out = score[i, j] >= cusum[1]
        if out.any():
            gone = np.zeros_like(valid)
            gone[i[out], j[out]] = True
            self.pruned += int(np.count_nonzero(out))
            maps.forget(gone)
            cols_out = np.unique(j[out])
            emptied = cols_out[(maps.table[:, cols_out] < 0).all(axis=0)]
            self.pruned_ids.extend(int(lid) for lid in maps.ids[emptied])

    def set_error_dof(self, dof: float) -> None:
        """The sensor's errors are Student-t with ``dof`` degrees of freedom (``inf``:
        Gaussian): an unset ``new_landmark_mahalanobis_sq`` becomes their
        :data:`NEW_LANDMARK_PROB` quantile, and the particles are weighed by that law."""
        self.new_gate_d2 = self._new_gate(dof)
        self.misread_gate_d2 = t2_quantile(NEW_LANDMARK_PROB, dof)
        self.error_dof = dof

    def _log_p0(self, R: np.ndarray) -> float:
        """Log-likelihood of a new landmark seen with noise ``R`` (unknown association)."""
        if self.config.new_landmark_log_likelihood is not None:
            return self.config.new_landmark_log_likelihood
        # the density at the gate, under the law the other weights use
        d2, dof, log_det = self.new_gate_d2, self.error_dof, math.log(np.linalg.det(R))
        if math.isinf(dof):
            return -0.5 * d2 - _LOG_2PI - 0.5 * log_det
        return t2_log_normaliser(dof) - 0.5 * log_det - 0.5 * (dof + 2.0) * math.log1p(d2 / dof)

    def _known_column(self, o: Observation) -> int:
        key = o.landmark_id if o.landmark_id is not None else o.signature
        if key is None:
            raise GraphSlamError("known association needs a landmark_id or a signature")
        self.last_noise[int(key)] = o.covariance
        return self.maps.add_column(int(key))

    def _columns_for(
        self,
        o: Observation,
        poses: np.ndarray,
        pose_cov: np.ndarray | None,
        taken: list[np.ndarray],
        clashes: ScanAssignment | None = None,
        k: int = 0,
    ) -> np.ndarray:
        """(N,) column of observation ``o`` per particle (created if new).

        ``taken``: the columns earlier observations of the same scan got, per
        particle; they are excluded (mutual exclusion: one landmark gives at
        most one observation per scan). ``clashes``: the scan's joint assignment
        (:meth:`_scan_assignment`), which decides ``o`` (the scan's ``k``-th) in the
        particles where it is set.
        """
        if self.config.association == "known":
            return np.full(self.n_particles, self._known_column(o), dtype=np.intp)
        cols, new = self.associate(o.z, o.covariance, poses, pose_cov, taken)
        if clashes is not None:
            rows = clashes.particles
            cols[rows], new[rows] = clashes.cols[:, k], clashes.new[:, k]
        if new.any():
            c = self.maps.add_column(self._next_id)
            self._next_id += 1
            cols[new] = c
        ids = self.maps.ids
        for c in np.unique(cols):
            self.last_noise[int(ids[int(c)])] = o.covariance
        return cols

    def associate(
        self,
        z: np.ndarray,
        R: np.ndarray,
        poses: np.ndarray,
        pose_cov: np.ndarray | None,
        taken: list[np.ndarray] | tuple = (),
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per-particle maximum likelihood among gated landmarks of the observation ``z``
        with noise ``R`` from ``poses`` (N, 3) (covariances ``pose_cov`` (N, 3, 3) or
        None), landmarks ``taken`` by earlier observations excluded: (cols (N,), new (N,)).

        Evaluates every (particle, landmark) pair, O(N L), in elementwise
        arithmetic on (N, L) arrays (much faster than stacks of 2x2 matmuls).
        """
        N = self.n_particles
        if self.maps.n_cols == 0:
            return np.zeros(N, dtype=np.intp), np.ones(N, dtype=bool)
        ll = self._gated_log_likelihoods(z, R, poses, pose_cov)
        for prev in taken:  # two landmarks 0.3 m apart otherwise merge into one
            ll[self._rows, prev] = -np.inf
        cols = np.argmax(ll, axis=1)
        return cols, ~np.isfinite(ll[self._rows, cols])

    def _scan_assignment(self, obs: list[Observation], poses: np.ndarray) -> ScanAssignment | None:
        """Unknown ids with ``pair_scans_jointly``: the particles in which two observations
        of the scan would pair with the same landmark on their own, and for those the best
        assignment of the whole scan (None when no particle has such a clash, or the
        setting is off).

        Sequential pairing under mutual exclusion depends on the scan's order: the first
        observation takes its closest landmark, which may be the one a later observation
        fits far better, and the later one then goes to a neighbour or starts a
        duplicate. MRCLAM's landmarks come in clusters 0.18-0.26 m apart, seen together.
        Here each clashing particle pairs its scan as a whole: the assignment (each
        landmark at most once) of the highest joint log-likelihood, starting a landmark
        scoring as a pairing at the gate's edge would (the association's own Gaussian score
        there with ``S = R``; not :meth:`_log_p0`, which weighs under the sensor's t law
        where the data states one, on another scale than these scores), solved exactly
        (:func:`scan_assignments`). Given the particle's pose the innovations are
        independent, so this is JCBB's joint test. Particles without a clash pair as
        before. The figures, for and against, are on
        :class:`~filters.fastslam_config.FastSlamConfig` ``pair_scans_jointly``.

        ``poses`` (N, 3) without their covariance: under 2.0 with the motion prior's
        covariance in the test, the default synthetic world lost its loop more often still
        (seeds 6-17: median ATE 2.39 m, against 0.78 m paired in order and 0.77 m from the
        poses alone; measured while building this, not kept)."""
        K = len(obs)
        unknown = self.config.association == "unknown"
        if not (unknown and self.config.pair_scans_jointly) or K < 2 or self.maps.n_cols == 0:
            return None
        ll = np.stack([self._gated_log_likelihoods(o.z, o.covariance, poses, None) for o in obs], axis=1)
        best = np.argmax(ll, axis=2)  # (N, K)
        paired = np.isfinite(np.take_along_axis(ll, best[..., None], axis=2)[..., 0])
        clash = np.zeros(self.n_particles, dtype=bool)
        for a in range(K):
            for b in range(a + 1, K):
                clash |= paired[:, a] & paired[:, b] & (best[:, a] == best[:, b])
        particles = np.flatnonzero(clash)
        if particles.size == 0:
            return None
        # starting a landmark scores as a pairing at the gate's edge would, on the scale of
        # _gated_log_likelihoods (Gaussian, no 2 pi term)
        start = [-0.5 * self.new_gate_d2 - 0.5 * math.log(np.linalg.det(o.covariance)) for o in obs]
        cols, new = scan_assignments(ll[particles], np.array(start))
        return ScanAssignment(particles, cols, new)

    def _gated_log_likelihoods(
        self, z: np.ndarray, R: np.ndarray, poses: np.ndarray, pose_cov: np.ndarray | None
    ) -> np.ndarray:
        """(N, L) Gaussian log-likelihood (up to a constant) of ``z`` for every
        (particle, landmark) pair inside the new-landmark gate; -inf elsewhere and where
        a particle does not know the landmark."""
        T = self.maps.table
        valid = T >= 0
        ptr = np.where(valid, T, 0)
        m = self.maps.pool_mean[ptr]  # (N, C, 2)
        P = self.maps.pool_cov[ptr]  # (N, C, 2, 2)
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
            s11 = s11 + c * c * X00 + 2 * c * d * X01 + d * d * X11 + 2 * c * X02 + 2 * d * X12 + X22
        nu_r = z[0] - r
        nu_b = wrap_angle(z[1] - np.arctan2(dy, dx) + poses[:, 2:3])
        det = s00 * s11 - s01 * s01
        d2 = (s11 * nu_r * nu_r - 2 * s01 * nu_r * nu_b + s00 * nu_b * nu_b) / det
        # det > 0: a covariance that lost definiteness gates nothing (its log is NaN)
        ok = valid & (d2 <= self.new_gate_d2) & (det > 0)
        return np.where(ok, -0.5 * d2 - 0.5 * np.log(np.where(ok, det, 1.0)), -np.inf)


@dataclass(frozen=True)
class ScanAssignment:
    """The joint pairing of a scan in some particles (:meth:`ParticleSet._scan_assignment`).

    Attributes:
        particles: (M,) the particles it decides.
        cols: (M, K) landmark column of each observation (where not ``new``).
        new: (M, K) True where the observation starts a landmark.
    """

    particles: np.ndarray
    cols: np.ndarray
    new: np.ndarray


def scan_assignments(ll: np.ndarray, start: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per particle, the pairing of a scan's K observations with L landmarks of the
    highest joint log-likelihood, each landmark paired at most once: ``ll`` (M, K, L)
    (-inf: outside the gate), ``start`` (K,) the log-likelihood of observation k
    starting a landmark instead. Returns ``(cols (M, K), new (M, K))``."""
    from scipy.optimize import linear_sum_assignment

    M, K, L = ll.shape
    own = np.where(np.eye(K, dtype=bool), start[:, None], -np.inf)
    cols = np.zeros((M, K), dtype=np.intp)
    new = np.ones((M, K), dtype=bool)
    for i in range(M):
        rows, chosen = linear_sum_assignment(np.concatenate([ll[i], own], axis=1), maximize=True)
        pair = chosen < L
        cols[i, rows[pair]] = chosen[pair]
        new[i, rows[pair]] = False
    return cols, new
