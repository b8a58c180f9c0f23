"""Settings of FastSLAM 1.0 / 2.0 (:class:`filters.fastslam.FastSlam`), checked on creation.

Section ``[fastslam]`` of the config file; types, modes and ranges are
declared on the fields and checked by :func:`slamcore.config.validate`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

from filters.numerics import MAX_ODOMETRY_COVARIANCE_SCALE
from slamcore.config import Gate, Validated, bounded

#: Most particles a filter may have. Every particle carries its own 2-D EKF per
#: landmark it knows (mean 2 + covariance 2x2 float64, 48 bytes, written anew
#: for each particle an update touches), an int32 pointer and a float64 missed-sighting
#: score per landmark column, so N particles x L landmarks take up to about 60 N L bytes:
#: 1e6 particles are 6 GB for a map of only 100 landmarks, and the per-observation (N, 2, 2)
#: temporaries grow alike. 1e11 would need terabytes for the poses alone.
MAX_PARTICLES = 1_000_000


@dataclass(frozen=True)
class FastSlamConfig(Validated):
    """FastSLAM settings (config file section ``[fastslam]``).

    Attributes:
        version: 1 (motion proposal) or 2 (proposal including the observation).
        n_particles: number of particles N for each robot, at most :data:`MAX_PARTICLES`
            in all (memory). A run of R robots in one filter (``--robot all``) keeps
            R x N: every particle samples every robot's pose, and N for all of them left
            each robot worse than its own run of N (MRCLAM Dataset 6, FastSLAM 2.0, known
            ids, medians over seeds 0-4: 0.137/0.148/0.150/0.185/0.224 m against
            0.132/0.141/0.133/0.199/0.210 m alone; with 5 N 0.108/0.110/0.124/0.162/0.192 m;
            ``benchmarks/bench_mrclam.py``).
        seed: seed of the one random generator; runs repeat to the bit.
        resample_ess_fraction: resample when ESS < fraction * N; in [0, 1]
            (0 never resamples, 1 always does).
        association: "known" (landmark_id or signature) or "unknown" (per
            particle maximum likelihood).
        new_landmark_mahalanobis_sq: unknown association: squared Mahalanobis
            gate (2 dof); an observation outside it for every landmark of a
            particle starts a new landmark in that particle. Unset (the default):
            the 0.999 quantile of the sensor's error, from the data's sensor field
            (:func:`filters.association.t2_quantile`): the chi-square's 13.8 for a
            Gaussian sensor, 71.5 for MRCLAM's camera (Student-t, 5.1 dof), whose
            sightings fall beyond 13.8 3.5 % of the time and then made landmarks
            that are not there (31-56 for 15 with seed 0; 19-30 with its own
            quantile, and FastSLAM 2.0's median unknown-id ATE over seeds 0-4 fell
            from 0.261/0.262/0.590/0.540/0.254 m to 0.174/0.251/0.169/0.389/0.207 m,
            each step's mean as the trajectory; ``benchmarks/bench_mrclam.py``).
        pair_scans_jointly: unknown association: a particle in which two sightings of one
            scan would pair with the same landmark on their own pairs that scan as a whole,
            by the assignment of the highest joint log-likelihood (each landmark at most once;
            starting a landmark scores as a pairing at the gate's edge), instead of in the
            scan's order (:meth:`ParticleSet._scan_assignment
            <filters.fastslam_particles.ParticleSet._scan_assignment>`), as the EKF's and
            iSAM2's joint compatibility tests pair a scan. On by default since 2026-12-07.
            MRCLAM Dataset 6 (landmarks 0.18-0.26 m apart), FastSLAM 2.0, seeds 0-19,
            robots 1-5: seeds recovering all 15 landmarks 9/2/14/1/17 against 3/1/7/1/11 in
            order, median ATE 0.134/0.175/0.135/0.185/0.152 m against
            0.155/0.172/0.152/0.209/0.163 m (``python benchmarks/bench_mrclam.py --no-joint
            --seeds 0 .. 19``, ``benchmarks/figures/mrclam_seeds.json``; in order
            ``--pair-scans-in-order``, ``mrclam_seeds_in_order.json``). The default
            synthetic world (spread landmarks, 10 deg bearings), seeds 0-199 (``python
            benchmarks/bench_scan_pairing.py``, ``benchmarks/figures/scan_pairing.json``):
            FastSLAM 1.0 lost the loop (ATE above 1.3 m) in 62 runs against 86 in order,
            FastSLAM 2.0 in 65 against 56 (median ATE 0.77 m against 0.70 m; a gap within the
            seeds' spread, about one standard error). Off (in order) was the default until
            then, on seeds 0-29 alone: 2.0 lost 13 against 8 there. Scoring the whole scan
            under 2.0's motion prior, applying it only where it starts no landmark, or
            pairing as many sightings as possible first did no better on that world
            (measured while building this, not kept).
        new_landmark_log_likelihood: unknown association: log-likelihood
            weight factor of starting a new landmark; None uses the Gaussian
            density of the measurement noise R at the gate.
        trajectory: what the estimate's poses are. "path" (the default): the path of
            the highest-weight particle, the one its map (the estimate's landmarks) is
            conditioned on, revised by every resampling that keeps it
            (:mod:`filters.fastslam_paths`; on the default synthetic world, FastSLAM
            2.0 with known ids, seeds 0-4, ATE 0.36-0.65 m against 0.93-1.46 m).
            "filtered": the weighted mean of each step's particles, as that step left
            them, never revised. The pose covariances are each step's particle spread
            in both.
        prune_missed_alpha: unknown association, on data that states its sensor's
            field (:class:`slamcore.planar.records.SensorField`): a landmark of a particle
            that lies in the field as that particle sees it (three sigmas of its predicted
            measurement to spare) in scans that report other things, none of them inside its
            gate, leaves that particle's map once those misses since its last sighting have
            probability at most this if it were there (:mod:`filters.landmark_existence`;
            Montemerlo et al., FastSLAM, AAAI 2002, Sec. 5: the duplicate a wrong
            association or a drifted pose leaves behind goes). Default 1e-3, the new-landmark
            gate's own error rate (1 - its 0.999 quantile), as the EKF's. 0: off (no run of
            misses is that unlikely).
        odometry_covariance_scale: the odometry covariance is multiplied by
            this before sampling (> 0, at most
            :data:`~filters.numerics.MAX_ODOMETRY_COVARIANCE_SCALE`). Particle filters need motion noise
            that covers the real odometry error; e.g. gtsam's Victoria Park
            file is too confident for them at 1 and runs well at 10.
        temper_correlated: on sightings that state how their errors correlate in time
            (``Observation.correlation`` and a stamp: the MRCLAM reader's calibrated
            model), a particle's weight takes each sighting's log-likelihood at the share
            of it that is new information, given the time since that landmark record's
            last sighting by the same sensor (:func:`filters.fastslam_update.weight_shares`);
            the landmark EKFs and the 2.0 proposal keep the stated noise. A burst of
            sightings whose errors repeat (MRCLAM's ranges correlate 0.97 within 0.3 s)
            is one piece of evidence for a path: counted in full, it collapsed the
            particles onto whichever path explained its shared error. On MRCLAM
            Dataset 6, FastSLAM 2.0's median ATE over seeds 0-19 on robots 1-5
            (``benchmarks/figures/mrclam_seeds.json``, its command inside), known
            ids: 0.170/0.305/0.195/0.185/0.270 m without, 0.133/0.147/0.153/0.197/0.226 m
            with; unknown ids: 0.160/0.480/0.450/0.380/0.210 m without,
            0.151/0.252/0.169/0.239/0.172 m with (Gaussian weights; with the camera's
            t law in the weights, :mod:`filters.fastslam`, and since 2026-12-06 in 2.0's
            landmark steps after the draw: 0.135/0.147/0.134/0.168/0.213 m known and
            0.155/0.172/0.152/0.209/0.163 m unknown; with 2.0's misread gate too,
            0.135/0.152/0.128/0.181/0.135 m known). False: every sighting weighs in
            full, as if independent.
        misread_restart_s: FastSLAM 2.0, known ids, stamped sightings: a particle's
            landmark record whose sightings the misread gate has held out for longer
            than this, s, with none taken in between, is taken as the wrong one (its
            particle's pose was off when it began, or it began from an outlier) and
            starts again from the sighting, where the same scan confirms that
            particle's pose (another landmark's sighting taken in); where every sighting
            of the scan is held out the pose may be the one that is off, and the record
            is kept. Without it such a record is never revised:
            every later sighting lies beyond the gate. Under the truth of MRCLAM Dataset
            6, 13 of its 15 383 sightings lie beyond the gate, in runs of at most 4
            sightings over 1.16 s (robot 5 reading landmark 8 as 18); 5 s is four times
            that. On robot 4, seed 1, landmark 6's record began from one sighting at frame
            906 (0.58 m short in range), the best particle's was 1.6 m off by frame 1000,
            and it took none of its next 81 sightings (2.2 m off at the end). Robot 4, seeds
            0-19: all 15 landmarks within 0.3 m on 7 seeds against 1, median ATE 0.170 m
            against 0.181 m; robots 1, 2, 3 and 5 unchanged
            (``benchmarks/figures/mrclam_seeds.json``). A very large value (1e9) keeps
            every record as it began.
    """

    SECTION: ClassVar[str] = "fastslam"
    # known ids: an observation without one is refused, never associated
    GATES: ClassVar[tuple[Gate, ...]] = (
        Gate(
            (
                "new_landmark_mahalanobis_sq",
                "new_landmark_log_likelihood",
                "prune_missed_alpha",
                "pair_scans_jointly",
            ),
            'association = "unknown"',
            lambda c: c.association == "unknown",
        ),
        Gate(
            ("misread_restart_s",),
            'association = "known" and version = 2 (the misread gate is 2.0\'s)',
            lambda c: c.association == "known" and c.version == 2,
        ),
    )

    #: settings that act only on data stating its sensor's field (``Dataset.sensor_field``):
    #: without one the pruning has no field to miss a landmark in and does nothing
    SENSOR_FIELD_KEYS: ClassVar[tuple[str, ...]] = ("prune_missed_alpha",)
    #: settings that act only on sightings that state a correlation in time and a stamp
    CORRELATION_KEYS: ClassVar[tuple[str, ...]] = ("temper_correlated",)
    #: settings that act only on sightings with a time stamp
    STAMPED_KEYS: ClassVar[tuple[str, ...]] = ("misread_restart_s",)

    version: int = bounded(2, min=1, max=2)
    n_particles: int = bounded(100, min=1, max=MAX_PARTICLES)
    seed: int = bounded(0, min=0)
    resample_ess_fraction: float = bounded(0.5, min=0.0, max=1.0)
    association: Literal["known", "unknown"] = "known"
    new_landmark_mahalanobis_sq: float | None = bounded(None, gt=0.0)
    new_landmark_log_likelihood: float | None = None
    pair_scans_jointly: bool = True
    prune_missed_alpha: float = bounded(1e-3, min=0.0, lt=1.0)
    odometry_covariance_scale: float = bounded(1.0, gt=0.0, max=MAX_ODOMETRY_COVARIANCE_SCALE)
    trajectory: Literal["path", "filtered"] = "path"
    temper_correlated: bool = True
    misread_restart_s: float = bounded(5.0, gt=0.0)
