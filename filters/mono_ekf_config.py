"""Settings of the monocular EKF-SLAM (:class:`filters.mono_ekf.MonoEkf`), checked on creation.

Section ``[mono_ekf]`` of the config file; types, modes and ranges are declared
on the fields and checked by :func:`slamcore.config.validate`. The landmark prior
(:attr:`MonoEkfConfig.rho0`, :attr:`MonoEkfConfig.sigma_rho`) is derived from
``min_depth_m`` here so the filter and its tests read one definition.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Literal

from slamcore.config import Gate, Validated, bounded

#: Most landmarks the state may hold. The covariance is dense, up to
#: (13 + 7 L)^2 float64 (constant-velocity model, AHP landmarks), and every
#: correction rewrites all of it: 1000 landmarks are 0.4 GB and O(n^2) work per
#: measurement, where the filter is meant for tens (the default 20).
MAX_LANDMARKS = 1000


def chi2_2dof(prob: float) -> float:
    """Chi-square quantile with 2 dof: ``-2 ln(1 - p)`` (exact for 2 dof)."""
    return -2.0 * math.log(1.0 - prob)


@dataclass(frozen=True)
class MonoEkfConfig(Validated):
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
            loop (seeds 0-3). At most :data:`MAX_LANDMARKS` (memory).
        max_init_per_frame: new landmarks per frame at most (paper: 5).
        max_corrections: measurements used per frame at most, largest
            innovation ellipse first.
        min_depth_m: nearest depth the inverse-depth prior covers at 2 sigma
            (``rho0 = 1/(2 d)``, ``sigma_rho = 1/(4 d)``), metres. Set it to
            the scene's nearest depth: the prior mean ``2 d`` biases the first
            corrections when the scene is much farther (measured on the
            synthetic loop, points 2.5-10 m away, odometry 1 cm and 5 mrad per
            frame: pose NEES ~100-350 with 1 m, 10-20 with 2 m).
        depth_prior: where a new landmark's inverse-distance prior comes from.
            "fixed": :attr:`rho0`, :attr:`sigma_rho` from ``min_depth_m``, the
            same for every landmark (Civera et al. 2008, RT-SLAM). "map": the
            first frame's landmarks take the fixed prior; later ones the
            median inverse distance (from the camera) of the landmarks
            predicted in view, ``sigma_rho`` half the larger of that median
            and the distance from it to the nearest one in view, so the
            2-sigma interval still reaches infinity (``rho = 0``) and the
            nearest mapped point (the fixed prior's rule, in the map's unit).
            A monocular map's scale is set only by its length-valued priors
            ("Dimensionless monocular SLAM", 2007); a fixed metric prior on
            every new landmark is one more scale measurement per landmark,
            biased by how far the scene's depth is from ``2 min_depth_m``, so
            the map's scale follows the scene's depth. Taken from the map,
            the prior is in the map's own unit and centred where the map's
            points are: it leaves the scale where the map has it.
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
        seed: RANSAC sampling seed.
    """

    SECTION: ClassVar[str] = "mono_ekf"
    GATES: ClassVar[tuple[Gate, ...]] = (
        Gate(
            (
                "cv_sigma_accel_mps2",
                "cv_sigma_alpha_radps2",
                "cv_initial_sigma_v_mps",
                "cv_initial_sigma_w_radps",
            ),
            'robot_model = "constant_velocity" (a run without odometry)',
            lambda c: c.robot_model == "constant_velocity",
        ),
        Gate(("ransac_inlier_sigmas", "ransac_max_hypotheses", "seed"), "ransac = true", lambda c: c.ransac),
    )

    robot_model: Literal["odometry", "constant_velocity"] = "odometry"
    landmark_param: Literal["idp", "ahp"] = "idp"
    max_landmarks: int = bounded(20, min=1, max=MAX_LANDMARKS)
    max_init_per_frame: int = bounded(5, min=0)
    max_corrections: int = bounded(10, min=1)
    min_depth_m: float = bounded(1.0, gt=0.0)
    depth_prior: Literal["fixed", "map"] = "fixed"
    linearity_threshold: float = bounded(0.1, min=0.0)
    ransac: bool = True
    ransac_inlier_sigmas: float = bounded(3.0, gt=0.0)
    ransac_max_hypotheses: int = bounded(20, min=1)
    rescue_chi2_prob: float = bounded(0.99, gt=0.0, lt=1.0)
    forget_unseen_frames: int = bounded(3, min=1)
    max_consecutive_misses: int = bounded(5, min=1)
    frame_dt_s: float = bounded(1.0 / 30.0, gt=0.0)
    cv_sigma_accel_mps2: float = bounded(4.0, gt=0.0)
    cv_sigma_alpha_radps2: float = bounded(4.0, gt=0.0)
    cv_initial_sigma_v_mps: float = bounded(1.0, gt=0.0)
    cv_initial_sigma_w_radps: float = bounded(1.0, gt=0.0)
    seed: int = bounded(0, min=0)

    @property
    def rho0(self) -> float:
        """Prior inverse distance of a new landmark, 1/m."""
        return 0.5 / self.min_depth_m

    @property
    def sigma_rho(self) -> float:
        """Prior std of the inverse distance, 1/m."""
        return 0.25 / self.min_depth_m

    @property
    def why_no_draws(self) -> str:
        """Why the filter draws no random number with these settings ("" when it does):
        its one RANSAC samples hypotheses only among more measurements than it tries."""
        if not self.ransac:
            return "the monocular EKF draws no random numbers (ransac = false)"
        if self.max_corrections <= self.ransac_max_hypotheses:
            return (
                f"the monocular EKF's one-point RANSAC tries every measurement it uses "
                f"(max_corrections {self.max_corrections} <= ransac_max_hypotheses "
                f"{self.ransac_max_hypotheses}) and draws no random numbers"
            )
        return ""


def run_overrides(mode: str, seed: int | None, no_polish: bool, nearest_depth_m: float | None) -> dict:
    """``[mono_ekf]`` overrides a visual run implies (the back-end table's
    ``run_overrides``): the RANSAC seed, the inverse-depth prior from the scene's
    nearest depth (``nearest_depth_m``, None: the file's) and, without odometry
    (``mode`` ``"none"``), the constant-velocity model. It has no polish.

    ``frame_dt_s`` stays the config's, not the sequence's frame interval: the
    acceleration and initial-rate noises are set per frame at that dt. With the
    0.1 s of the synthetic stamps and the default noises (sized for 1/30 s) the
    first search ellipses exceed the search cap and it diverges;
    benchmarks/synthetic_mono.toml and kitti07_mono.toml set the interval and the
    noises together, measured."""
    out: dict[str, object] = {}
    if seed is not None:
        out["seed"] = seed
    if nearest_depth_m is not None:
        out["min_depth_m"] = nearest_depth_m
    if mode == "none":
        out["robot_model"] = "constant_velocity"
    return out
