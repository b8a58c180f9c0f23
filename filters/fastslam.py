"""FastSLAM 1.0 and 2.0 for 2-D range-bearing landmarks (numpy only).

Rao-Blackwellised particle filter (course slides "FastSLAM"; Montemerlo et al.
2002, 2003): each of N particles holds a pose and one small EKF per landmark.
The particles (poses, log-weights, landmark maps, random stream) are one
object, :class:`filters.fastslam_particles.ParticleSet`, with the filter's steps
as its methods; :class:`FastSlam` wraps it in the back-end contract (input
checks, pose ids, the estimate history, the resampling decision).
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
  otherwise merged into one in every particle (default synthetic world, seed 0,
  100 particles, scans paired in order: accuracy 91.9 -> 96.2 % for 1.0, 90.9 ->
  95.4 % for 2.0). A particle in which two observations of a scan would take the same
  landmark pairs the scan as a whole (``pair_scans_jointly``, the default; the
  assignment of the highest joint likelihood). New landmarks come from the inverse
  observation model.

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

  Where the data states its sensor's error tail (``SensorField.error_dof``: MRCLAM's
  camera, Student-t with 5.1 dof), the weights' ``N(.; 0, S)`` and ``N(.; 0, L)`` are
  that law with the same scale matrix (:func:`filters.fastslam_math.log_likelihood`):
  under a Gaussian an outlier costs a particle ``d^2/2``, and the particles whose path
  explained it took the weight. After 2.0's draw the landmark EKFs take a sighting's
  ``R`` times the law's factor (:func:`filters.fastslam_math.t_noise_factor`, at least
  1: an outlier moves the landmark by its weight); the 2.0 proposal and 1.0's landmark
  EKFs stay Gaussian (the weights correct a draw; a 1.0 innovation is mostly its
  particle's pose error). Without a stated tail, or with a Gaussian one, all is as above.

  With known ids, FastSLAM 2.0 holds a sighting far beyond the sensor's gate out of
  the proposal and of its landmark record, as a misread id; a record whose sightings
  it has held out for longer than any run of misreads lasts (``[fastslam]
  misread_restart_s``) starts again from the sighting instead.

  Weights are kept in log space; low-variance (systematic) resampling runs when
  the effective sample size drops below ``resample_ess_fraction * N``.

  Sightings whose errors correlate in time (an observation's ``correlation`` and
  stamp, which the EKF and iSAM2 weigh in their updates) are weighed so in the
  particle weights only: each sighting's log-likelihood is taken at the share of it
  that is new since its landmark record's last sighting by the same sensor
  (``[fastslam] temper_correlated``, :func:`filters.fastslam_update.weight_shares`);
  the landmark EKFs and 2.0's proposal keep the stated noise, for the reason
  :mod:`slamcore.planar.sighting_correlation` gives (measured worse).

Cost per observation: known association is O(N) vectorised numpy (plus the
O(N L) int32 table copy when resampling). Unknown association evaluates every
(particle, landmark) pair, O(N L), in elementwise arithmetic on (N, L)
arrays; there is no spatial index. With unknown association ``landmark_id`` is
ignored; the back end's ids count up from 0 (one new id per observation that
starts a landmark in at least one particle; ids only dead particles knew are
dropped after resampling).

Estimates: the landmarks are those of the highest-weight particle, and the trajectory
is that particle's path (``trajectory = "path"``, :mod:`filters.fastslam_paths`: the
path its map is conditioned on, revised by every resampling) or, with ``"filtered"``,
the weighted-mean particle pose of each step (after that step's observations, before
resampling), never revised. Until an observation weighs the particles, both are the
odometry composed from the start (any particle is then as good as the "best", and their
mean varies by seed). The pose covariances are the
weighted particle covariance of each step in both; :meth:`FastSlam.current_pose` is the
trajectory's latest pose.

Several robots (``graphslam run --robot all``): ``n_particles`` is kept for each
robot (:meth:`FastSlam.set_robot_count`, R x N in all), and every particle holds every
robot's latest pose beside its landmark map (the robots that do not move are
parked in :attr:`filters.fastslam_particles.ParticleSet.parked`), so the map a
particle builds from all robots' sightings is conditioned on all their paths, as
in one robot's FastSLAM. An odometry step may extend any robot's latest pose, or
start a robot from the run's first pose: its poses are then drawn around that
pose's weighted mean, moved by the odometry, with that pose's cloud covariance
propagated (the joint reader starts every robot there, from the truth). A
sighting of one robot by another weighs each particle by its likelihood under the
particle's two poses (no gate, as known landmarks have none) and may resample.
A parked robot's history entry is refreshed when it moves again and at
:meth:`FastSlam.estimate`: its weighted mean changes with the weights.

All randomness comes from ``np.random.default_rng(seed)``: same seed and
inputs, same bits.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import replace

import numpy as np

from filters.fastslam_config import MAX_PARTICLES, FastSlamConfig
from filters.fastslam_map import ParticleMaps
from filters.fastslam_particles import ParticleSet
from filters.fastslam_paths import MAX_PATH_BYTES, ParticlePaths
from filters.numerics import Recoveries
from filters.numerics import symmetrise as sym
from filters.planar_inputs import checked_scan, initial_pose, linked_pose, odometry_step
from slamcore.errors import ConfigError, GraphSlamError, UnsupportedError
from slamcore.planar import geometry as models
from slamcore.planar.backend import Backend
from slamcore.planar.records import Estimate, Observation, Odometry, PoseSighting, Prediction, SensorField

__all__ = ["FastSlam"]


class FastSlam(Backend):
    """FastSLAM 1.0 / 2.0 back end (``name`` "fastslam1" / "fastslam2")."""

    supports_loop_closures = False
    supports_pose_sightings = True

    def __init__(self, config: FastSlamConfig | None = None):
        self.config = config if config is not None else FastSlamConfig()
        self.name = f"fastslam{self.config.version}"
        self._sensor_field: SensorField | None = None
        self._build(self.config.n_particles)
        self._pose_ids: list[int] = []
        self._pose_set: set[int] = set()
        self._hist_mean: list[np.ndarray] = []
        self._hist_cov: list[np.ndarray] = []
        self._hist_row: dict[int, int] = {}  # pose id -> its row of the history
        self._dirty = False
        self._best = 0
        # whether any observation has weighed the particles: until one does they are
        # draws alike, and the "best" one's path is one draw of the motion model; the
        # estimate is then the odometry composed from the start (the motion model's mode,
        # the EKF's and iSAM2's estimate): the particles' mean still varied by seed
        self._weighed = False
        self._nominal: dict[int, np.ndarray] = {}
        self._last_associations: list[int | None] = []
        #: How many times the particles were resampled.
        self.resample_count = 0
        # (poses so far, ESS, resample_count) at the last resampling decision: read
        # by step_ess() and resampled_this_step(), never by the filter itself
        self._decision: tuple[int, float, int] = (-1, float(self.n_particles), 0)

    def _build(self, n_particles: int) -> None:
        """The particle set and paths for ``n_particles`` (before :meth:`initialize`)."""
        #: Particles in all: ``n_particles`` of the settings for each robot of the run.
        self.n_particles = int(n_particles)
        self._particles = ParticleSet(replace(self.config, n_particles=self.n_particles))
        self._paths = ParticlePaths(self.n_particles) if self.config.trajectory == "path" else None
        # unknown ids: each particle's pairings, through the resamplings (final_associations)
        unknown = self.config.association == "unknown"
        self._pairings = ParticlePaths(self.n_particles) if unknown else None
        self._pairing_slots: list[int] = []  # pose id of each row of _pairings

    # ------------------------------------------------------------- contract
    def set_robot_count(self, n_robots: int) -> None:
        """Several robots in one filter: ``n_particles`` for each (module docstring)."""
        if self._pose_ids:
            raise GraphSlamError(f"{self.name}: set_robot_count() after initialize()")
        if isinstance(n_robots, bool) or not isinstance(n_robots, (int, np.integer)) or n_robots < 1:
            raise GraphSlamError(f"{self.name}: robot count must be a positive integer, got {n_robots!r}")
        n = self.config.n_particles * int(n_robots)
        if n > MAX_PARTICLES:
            raise ConfigError(
                f"[fastslam] n_particles = {self.config.n_particles} for each of {n_robots} robots is "
                f"{n} particles, over the {MAX_PARTICLES} a filter may have (memory)"
            )
        if n != self.n_particles:
            self._build(n)
            self._particles.set_sensor_field(self._sensor_field)

    def set_sensor_field(self, sensor_field: SensorField | None) -> None:
        """Unknown association reads the sensor's error tail from it (the gate of a new
        landmark, ``new_landmark_mahalanobis_sq`` unset; None: Gaussian errors) and its
        field, to prune the landmarks each particle misses (``prune_missed_alpha``)."""
        self._sensor_field = sensor_field
        self._particles.set_sensor_field(sensor_field)

    def initialize(self, pose_id: int, wTb: np.ndarray, covariance: np.ndarray) -> None:
        if self._pose_ids:
            raise GraphSlamError(f"{self.name}: initialize() called twice")
        pose_id, wTb, cov = initial_pose(pose_id, wTb, covariance, f"{self.name} initial pose")
        self._particles.draw_initial(wTb, cov)
        self._nominal[int(pose_id)] = np.asarray(wTb, dtype=np.float64).copy()
        self._pose_ids.append(int(pose_id))
        self._pose_set.add(int(pose_id))
        self._dirty = True

    def sensor_field_use(self) -> frozenset[str]:
        # the error's tail weighs the particles (and gates new landmarks under unknown ids)
        if self.config.association != "unknown" or self.config.prune_missed_alpha == 0.0:
            return frozenset({"error_dof"})
        return frozenset({"error_dof", "field"})

    def reads_sighting_correlation(self) -> bool:
        return self.config.temper_correlated

    def predict(self, odometry: Odometry, pose_id: int) -> None:
        self._require_init()
        cur = self._pose_ids[-1]
        if pose_id in self._pose_set:
            raise GraphSlamError(f"{self.name}: pose {pose_id} added twice")
        other = linked_pose(odometry, pose_id)
        particles = self._particles
        if other is not None and other != cur:  # another robot's step (module docstring)
            if other == self._pose_ids[0] and other not in particles.parked:
                self._start_robot(odometry, pose_id)
                return
            if other in particles.parked:  # it moves now: its poses become the moving ones
                self._close_step()
                self._refresh_parked()  # its latest pose as the filter leaves it
                particles.activate(other, cur)
                cur = other
        u, cov = odometry_step(odometry, cur, pose_id, self.name)
        self._close_step()
        particles.move(u, cov)
        if not self._weighed:  # needed only until then: not a dict a pose for the whole run
            self._nominal[int(pose_id)] = models.compose(self._nominal[cur], u)
        self._add_pose_id(pose_id)

    def _add_pose_id(self, pose_id: int) -> None:
        """``pose_id`` becomes the moving robot's latest pose (its history entry follows)."""
        self._pose_ids.append(int(pose_id))
        self._pose_set.add(int(pose_id))
        self._dirty = True

    def _start_robot(self, odometry: Odometry, pose_id: int) -> None:
        """Several robots: a robot starting at ``pose_id``, linked to the run's first pose."""
        first = self._pose_ids[0]
        u, Q = odometry_step(odometry, first, pose_id, self.name)
        self._close_step()  # the first pose's entry exists from here on
        mean0, cov0 = self._hist_mean[0], self._hist_cov[0]
        F, G = models.compose_jacobians(mean0, u)
        Q = Q * self.config.odometry_covariance_scale
        self._particles.park_and_start(
            self._pose_ids[-1], models.compose(mean0, u), sym(F @ cov0 @ F.T + G @ Q @ G.T)
        )
        if not self._weighed:
            self._nominal[int(pose_id)] = models.compose(self._nominal[first], u)
        self._add_pose_id(pose_id)

    def add_pose_sighting(self, sighting: PoseSighting) -> None:
        """Several robots: weigh the particles by a sighting of one robot's latest pose
        from another's (module docstring), then resample if the weights call for it.

        Raises:
            UnsupportedError: a pose that is not a robot's latest (no particle holds it).
        """
        self._require_init()
        particles = self._particles
        live = {self._pose_ids[-1]: particles.poses, **particles.parked}
        a, b = live.get(sighting.from_id), live.get(sighting.to_id)
        if a is None or b is None or sighting.from_id == sighting.to_id:
            raise UnsupportedError(
                f"{self.name} keeps each robot's latest pose only: it cannot use a sighting of "
                f"pose {sighting.to_id} from pose {sighting.from_id}"
            )
        particles.weigh_sighting(a, b, sighting.z, sighting.covariance)
        self._weighed = True
        self._best = int(np.argmax(particles.logw))
        w = particles.weights
        self._close_step(force=True, w=w)
        self._refresh_parked(w)
        self._maybe_resample(w)

    def update(self, observations: Sequence[Observation]) -> None:
        self._require_init()
        self._last_associations = []
        obs = checked_scan(observations, self._pose_ids[-1], self.name)
        if not obs:
            return
        for o in obs:
            if self.config.association == "known" and o.landmark_id is None and o.signature is None:
                raise GraphSlamError(
                    f"{self.name}: known association needs a landmark_id or "
                    f"a signature (observation from pose {o.pose_id})"
                )
        particles = self._particles
        cols = particles.update(obs)
        self._weighed = True
        self._best = int(np.argmax(particles.logw))
        ids = particles.maps.ids
        # a sighting the best particle took as a misread id went unused in the estimate
        misread = particles.last_misread
        self._last_associations = [
            None if misread is not None and misread[k][self._best] else int(ids[int(c[self._best])])
            for k, c in enumerate(cols)
        ]
        if self._pairings is not None:
            self._pairings.record(len(self._pairing_slots), ids[np.stack(cols, axis=1)])
            self._pairing_slots.append(self._pose_ids[-1])
        w = particles.weights
        self._close_step(force=True, w=w)
        self._maybe_resample(w)
        if self.config.association == "unknown":
            particles.maps.drop_empty_columns()

    def final_associations(self) -> dict[tuple[int, int], int] | None:
        """Unknown ids: the pairings of the estimate's particle, as its ancestors made them
        (the map is that particle's, built from its own lineage's pairings; the best
        particle of each step paired otherwise where the resamplings later dropped it)."""
        if self._pairings is None or self._pairings.given_up:
            return None
        rows = self._pairings.lineage(self._best, range(len(self._pairing_slots)))
        return {
            (pid, k): int(lid)
            for pid, row in zip(self._pairing_slots, rows, strict=True)
            for k, lid in enumerate(row)
        }

    def rejected_observations(self) -> int:
        """Sightings of known ids that 2.0's misread gate kept out of the pose proposal
        of at least half the particles (:func:`~filters.fastslam_update.refine_proposal`)."""
        return self._particles.rejected

    def restarted_landmark_records(self) -> int:
        """Particle landmark records started again by 2.0's misread restart
        (``misread_restart_s``), one per particle and record."""
        return self._particles.misread_restarts

    def pruned_landmark_ids(self) -> list[int]:
        """Ids of the landmarks the pruning (``prune_missed_alpha``) removed from every
        particle that held them: gone from the filter's map. A landmark pruned from some
        particles only is not listed (the others still hold it)."""
        return list(self._particles.pruned_ids)

    def predict_observations(self, landmark_ids: Iterable[int]) -> list[Prediction]:
        self._require_init()
        # the pose and landmarks estimate() reports: its latest pose with the
        # cloud covariance, and the best particle's landmark EKFs
        b = self._best
        x = self.current_pose()
        P_x = self.current_pose_covariance()
        maps = self._particles.maps
        out = []
        for lid in landmark_ids:
            col = maps.column(int(lid))
            if col is None:
                continue
            p = int(maps.pointers(np.array([b]), col)[0])
            if p < 0:
                continue
            m, P = maps.pool_mean[p], maps.pool_cov[p]
            H_x, H_m = models.observe_jacobians(x, m)
            S = H_x @ P_x @ H_x.T + H_m @ P @ H_m.T + self._particles.last_noise[int(lid)]
            out.append(Prediction(int(lid), models.observe(x, m), sym(S)))
        return out

    def estimate(self, with_covariances: bool = False) -> Estimate:
        self._require_init()
        self._close_step()
        self._refresh_parked()
        ids, means, covs = self._particles.maps.landmarks_of(self._best)
        paths = self._paths
        if not self._weighed:
            wTb = np.array([self._nominal[p] for p in self._pose_ids])
        elif self._tracks_paths() and paths is not None:
            wTb = paths.path(self._best, len(self._hist_mean))
        else:
            wTb = np.array(self._hist_mean)
        return Estimate(
            pose_ids=np.array(self._pose_ids, dtype=np.int64),
            wTb=wTb,
            landmark_ids=ids,
            landmarks_w=means,
            pose_covariances=np.array(self._hist_cov) if with_covariances else None,
            landmark_covariances=covs if with_covariances else None,
        )

    def numerical_recoveries(self) -> list[str]:
        out = []
        if self._paths is not None and self._paths.given_up:
            out.append(
                f"{self.name}: the particles' paths outgrew {MAX_PATH_BYTES >> 20} MiB without "
                "coalescing (no resampling): the trajectory is each step's weighted mean"
            )
        if self._pairings is not None and self._pairings.given_up:
            out.append(
                f"{self.name}: the particles' pairings outgrew {MAX_PATH_BYTES >> 20} MiB without "
                "coalescing (no resampling): each sighting is scored by the pairing of its step's "
                "best particle, not the estimate's own"
            )
        return out

    def current_pose(self) -> np.ndarray:
        """The estimate's latest pose: the highest-weight particle's (``trajectory =
        "path"``, the pose its landmarks are predicted from) or the weighted mean."""
        self._require_init()
        self._close_step()
        if not self._weighed:
            return self._nominal[self._pose_ids[-1]].copy()
        if self._tracks_paths():
            return self._particles.poses[self._best].copy()
        return self._hist_mean[-1].copy()

    def _tracks_paths(self) -> bool:
        """Whether the estimate is the best particle's path once an observation weighed
        them: ``trajectory = "path"`` and its paths kept (before, a log whose sightings
        were all dropped gave one random particle's path, a different ATE each seed,
        ranked above iSAM2's dead reckoning by ``compare``: twentieth hostile pass)."""
        return self._paths is not None and not self._paths.given_up

    def current_pose_covariance(self) -> np.ndarray | None:
        self._require_init()
        self._close_step()
        return self._hist_cov[-1].copy()

    # ------------------------------------------------------- introspection
    @property
    def particles(self) -> ParticleSet:
        """The particle set (read it, do not modify it)."""
        return self._particles

    @property
    def particle_poses(self) -> np.ndarray:
        """(N, 3) copy of the particle poses."""
        return self._particles.poses.copy()

    @property
    def weights(self) -> np.ndarray:
        """(N,) normalised particle weights."""
        return self._particles.weights

    @property
    def maps(self) -> ParticleMaps:
        """The shared landmark storage (read it, do not modify it)."""
        return self._particles.maps

    @property
    def recoveries(self) -> Recoveries:
        """Numerical recoveries (:class:`filters.numerics.Recoveries`)."""
        return self._particles.recoveries

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
        if not self._pose_ids:
            raise GraphSlamError(f"{self.name}: initialize() must come first")

    def _close_step(self, force: bool = False, w: np.ndarray | None = None) -> None:
        """Record (or refresh) the history entry of the current pose."""
        if not (self._dirty or force):
            return
        mean, cov = self._particles.cloud_stats(w)
        k = len(self._pose_ids)
        if len(self._hist_mean) == k:
            self._hist_mean[-1], self._hist_cov[-1] = mean, cov
        else:
            self._hist_row[self._pose_ids[-1]] = len(self._hist_mean)
            self._hist_mean.append(mean)
            self._hist_cov.append(cov)
        if self._paths is not None:
            self._paths.record(len(self._hist_mean) - 1, self._particles.poses)
        self._dirty = False

    def _refresh_parked(self, w: np.ndarray | None = None) -> None:
        """History entries of the parked robots' latest poses, at the current weights."""
        for pid, poses in self._particles.parked.items():
            row = self._hist_row[pid]
            self._hist_mean[row], self._hist_cov[row] = self._particles.cloud_stats(w, poses)
            if self._paths is not None:
                self._paths.record(row, poses)

    def _maybe_resample(self, w: np.ndarray) -> None:
        ess = 1.0 / float(np.sum(w * w))
        self._decision = (len(self._pose_ids), ess, self.resample_count)
        if ess >= self.config.resample_ess_fraction * self.n_particles:
            return
        parents = self._particles.resample(w)
        if self._paths is not None:
            self._paths.resampled(parents)
        if self._pairings is not None:
            self._pairings.resampled(parents)
        self._best = int(np.flatnonzero(parents == self._best)[0])
        self.resample_count += 1
