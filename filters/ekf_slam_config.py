"""Settings of the 2-D EKF-SLAM (:class:`filters.ekf_slam.EkfSlam`), checked on creation.

Section ``[ekf]`` of the config file; types, modes and ranges are declared on
the fields and checked by :func:`slamcore.config.validate`, so a bad value
raises :class:`slamcore.errors.ConfigError` naming the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np

from filters.association import chi2_quantile
from filters.numerics import CHI2_2DOF_999, MAX_ODOMETRY_COVARIANCE_SCALE
from slamcore.config import Gate, Validated, bounded
from slamcore.errors import ConfigError

#: Most landmark slots the buffers may hold before the first doubling: the
#: state's covariance is a dense (3 + 2 L)^2 float64 allocated up front, so
#: 10 000 slots are already 3.2 GB (and every update touches all of it).
MAX_INITIAL_CAPACITY = 10_000
#: Most pairing tests JCBB may do per scan: the budget exists to bound the
#: search's time (the tree has up to (candidates + 1)^m leaves for m
#: observations), and a test costs about 50 us here (12 observations, 3
#: candidates each), so a million tests are already about a minute per scan.
MAX_JCBB_NODES = 1_000_000
#: Default ``damped_update_nis``: the association gate's 0.999 quantile (an innovation
#: the gate would call an outlier is damped); the measurement is in the field's docstring.
DAMPED_UPDATE_NIS = CHI2_2DOF_999


@dataclass(frozen=True)
class EkfSlamConfig(Validated):
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
            (1 = at first sighting). Unset (the default): 1 with known ids; with
            unknown ids, as many as make a run of sightings outside a mapped
            landmark's gate as rare as the gate's own error, for the sensor's error
            tail (:func:`filters.association.confirming_sightings`: 1 for a
            Gaussian sensor, 3 for MRCLAM's camera, as iSAM2's
            ``confirm_sightings``).
        initial_capacity: landmarks the buffers hold before the first doubling.
        jcbb_max_candidates: individually compatible landmarks kept per observation.
        jcbb_max_nodes: pairing tests JCBB may do per scan.
        jacobians: "oc" (observability-constrained, default) or "standard".
        default_sigma_range_m, default_sigma_bearing_rad: measurement noise used
            by :meth:`~filters.ekf_slam.EkfSlam.predict_observations` before any
            observation is seen.
        odometry_covariance_scale: the odometry covariance is multiplied by
            this in :meth:`~filters.ekf_slam.EkfSlam.predict` (> 0). The filter assumes white
            odometry noise; real odometry errors are correlated (a slowly
            varying heading bias on Victoria Park), so over the steps between
            two sightings they grow faster than the file's per-step covariance
            says, and an unscaled filter trusts its drifted pose too much.
        known_gate_chi2_prob: known association only: an observation whose
            innovation's squared Mahalanobis distance (2 dof) exceeds this
            chi-square quantile is rejected (not absorbed, counted in
            :attr:`~filters.ekf_slam.EkfSlam.rejected_count`, reported as None by
            :meth:`~filters.ekf_slam.EkfSlam.associations`). A given id does not make a
            measurement right: one spurious range-bearing pair absorbed
            with full trust corrupts the pose and the map. Default 0.9999 (NIS
            18.4): on the real MRCLAM sightings (5-6 % beyond 3 robust sigma)
            the ungated filter ends 1.8-2.9 m off on two robots of five and the
            gated one within 0.14-0.33 m (``benchmarks/bench_mrclam.py``); on
            Gaussian data it drops 0.01 % of the sightings. It lies above
            ``damped_update_nis`` (13.8) so that innovations between the two are
            still taken with the damped step rather than dropped. None absorbs
            every identified observation.
        jcbb_objective: unknown association: "count" (JCBB's most jointly
            compatible pairings, ties to the lower joint NIS) or "likelihood"
            (the jointly compatible hypothesis of highest likelihood against
            new landmarks, :func:`filters.association.jcbb` with
            ``pair_gain``; an unpaired observation is new where a new landmark
            explains it better than every landmark left unpaired; a pairing
            inside a gate as likely to hold a new landmark as the mapped one
            needs the measurement alone to favour it, or a second such pairing:
            :func:`filters.ekf_slam_association.ambiguous_gates`). Default
            "likelihood": unknown association on the default synthetic world,
            seeds 0-49 (``benchmarks/bench_filter_seeds.py``), within 1.5
            points of the known-pose ceiling on 45 seeds and the loop unbroken
            (ATE <= 2x known association) on 49 (46 and 49 before
            ``prune_missed_alpha``; 44 and 47 without the support rule), against
            38 and 39 with "count"; on seeds 50-99, before the pruning, 42 and 46
            (44 and 44 without the rule).
        new_landmark_density_per_m2, detection_prob: the "likelihood"
            objective's density of not yet mapped landmarks (0.015: the
            default synthetic world's 200 landmarks over its ~13 000 m2) and
            probability that a mapped landmark in view is detected.
        prune_missed_alpha: unknown association, on data that states its sensor's
            field (:class:`slamcore.planar.records.SensorField`): a landmark that
            lies in the field (with three sigmas of its predicted measurement to
            spare) in frames that report other things, none of them inside its
            gate, is removed once those misses since its last sighting have
            probability at most this if it were there (:mod:`filters.landmark_existence`: a
            duplicate left by a wrong association, which nothing feeds any more,
            goes; its rows and columns are marginalised out). Default 1e-3, the
            association gate's own error rate (1 - ``gate_chi2_prob``). Measured on
            MRCLAM Dataset 6, robots 1-5 (``benchmarks/bench_mrclam.py``): landmarks
            built 25/32/35/17/29 without, 25/21/19/15/24 with, map error
            0.25/0.74/1.13/0.18/0.34 m without, 0.25/0.85/0.48/0.15/0.26 m with,
            ATE within 5 mm; on the default synthetic world (seeds 0-9) 0-12
            duplicates removed per seed, ATE within 7 mm and the association
            accuracy unchanged (seeds 0-49: within 1.5 points of the ceiling on
            45, loop unbroken on 49). Without the gate test (an unpaired
            observation in the landmark's gate) a landmark JCBB found ambiguous
            was pruned at once where the sensor sees all its field. None keeps
            every landmark.
            Known association never prunes (a given id is a landmark).
        damped_update_nis: an update whose innovation's squared Mahalanobis
            distance (2 dof) exceeds this takes the damped iterated step
            (:func:`filters.ekf_slam_update.damped_iterated_step`) instead of
            the plain EKF step, which the linearisation cannot be trusted with
            that far out (10x the course's bearing noise, or a 2 cm range
            after a long loop, sent the plain EKF tens of metres off and then
            to a non-positive covariance). None: always the plain step.
    """

    SECTION: ClassVar[str] = "ekf"
    # Only the certain ones: under known ids an observation without an id still goes
    # through the unknown association (gate, JCBB), so those keys may act there.
    GATES: ClassVar[tuple[Gate, ...]] = (
        Gate(
            ("new_landmark_density_per_m2", "detection_prob"),
            'jcbb_objective = "likelihood"',
            lambda c: c.jcbb_objective == "likelihood",
        ),
        Gate(("prune_missed_alpha",), 'association = "unknown"', lambda c: c.association == "unknown"),
    )
    #: settings of the unknown association (gate, JCBB, new landmarks) that under known
    #: ids act only on sightings without an id: a run whose every sighting had one never
    #: read them (fifteenth hostile pass: five of them changed nothing, silently)
    ANONYMOUS_SIGHTING_KEYS: ClassVar[tuple[str, ...]] = (
        "gate_chi2_prob",
        "new_landmark_chi2_prob",
        "jcbb_max_candidates",
        "jcbb_max_nodes",
        "jcbb_objective",
        "new_landmark_density_per_m2",
        "detection_prob",
    )
    #: settings no run reads: every streamed observation brings its own covariance, so
    #: the default is only ``predict_observations``' before the first one (library use)
    UNREAD_IN_RUNS: ClassVar[tuple[str, ...]] = ("default_sigma_range_m", "default_sigma_bearing_rad")
    #: settings that act only on data stating its sensor's field (``Dataset.sensor_field``):
    #: without one the pruning has no field to miss a landmark in and does nothing
    SENSOR_FIELD_KEYS: ClassVar[tuple[str, ...]] = ("prune_missed_alpha",)

    association: Literal["known", "unknown"] = "known"
    gate_chi2_prob: float = bounded(0.999, gt=0.0, lt=1.0)
    new_landmark_chi2_prob: float = bounded(0.999, gt=0.0, lt=1.0)
    provisional_sightings: int | None = bounded(None, min=1)
    initial_capacity: int = bounded(64, min=1, max=MAX_INITIAL_CAPACITY)
    jcbb_max_candidates: int = bounded(3, min=1)
    jcbb_max_nodes: int = bounded(2000, min=0, max=MAX_JCBB_NODES)
    default_sigma_range_m: float = bounded(0.2, gt=0.0)
    default_sigma_bearing_rad: float = bounded(math.radians(10.0), gt=0.0)
    jacobians: Literal["standard", "oc"] = "oc"
    odometry_covariance_scale: float = bounded(1.0, gt=0.0, max=MAX_ODOMETRY_COVARIANCE_SCALE)
    known_gate_chi2_prob: float | None = bounded(0.9999, gt=0.0, lt=1.0)
    damped_update_nis: float | None = bounded(DAMPED_UPDATE_NIS, gt=0.0)
    jcbb_objective: Literal["count", "likelihood"] = "likelihood"
    new_landmark_density_per_m2: float = bounded(0.015, gt=0.0)
    detection_prob: float = bounded(0.9, gt=0.0, lt=1.0)
    prune_missed_alpha: float | None = bounded(1e-3, gt=0.0, lt=1.0)

    def __post_init__(self):
        super().__post_init__()
        if self.new_landmark_chi2_prob < self.gate_chi2_prob:
            raise ConfigError(
                "ekf.new_landmark_chi2_prob must be >= ekf.gate_chi2_prob "
                f"({self.new_landmark_chi2_prob} < {self.gate_chi2_prob})"
            )

    def known_gate(self) -> float:
        """The squared Mahalanobis distance (2 dof) beyond which ``known_gate_chi2_prob``
        rejects an identified observation; inf when that key is None (no gate)."""
        if self.known_gate_chi2_prob is None:
            return math.inf
        return chi2_quantile(self.known_gate_chi2_prob, 2)

    def default_noise(self) -> np.ndarray:
        """``diag(default_sigma_range_m^2, default_sigma_bearing_rad^2)`` (2, 2): the
        measurement covariance ``predict_observations`` uses before any observation."""
        return np.diag([self.default_sigma_range_m**2, self.default_sigma_bearing_rad**2])
