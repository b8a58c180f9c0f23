"""Settings of the monocular EKF-SLAM (:class:`filters.mono_ekf.MonoEkf`), checked on creation.

Section ``[mono_ekf]`` of the config file. The landmark prior
(:attr:`MonoEkfConfig.rho0`, :attr:`MonoEkfConfig.sigma_rho`) is derived from
``min_depth_m`` here so the filter and its tests read one definition.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from filters.mono_ekf_checks import is_int, is_num
from slamcore.errors import ConfigError


def chi2_2dof(prob: float) -> float:
    """Chi-square quantile with 2 dof: ``-2 ln(1 - p)`` (exact for 2 dof)."""
    return -2.0 * math.log(1.0 - prob)


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
        default_sigma_px: pixel std used by
            :meth:`~filters.mono_ekf.MonoEkf.predict_observations` before any
            observation is seen.
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
            if not is_int(v) or v < lo:
                raise ConfigError(f"mono_ekf.{name} must be an integer >= {lo}, got {v!r}")
        for name in ("min_depth_m", "ransac_inlier_sigmas", "frame_dt_s", "cv_sigma_accel_mps2",
                     "cv_sigma_alpha_radps2", "cv_initial_sigma_v_mps", "cv_initial_sigma_w_radps",
                     "default_sigma_px"):
            v = getattr(self, name)
            if not is_num(v) or v <= 0:
                raise ConfigError(f"mono_ekf.{name} must be a positive number, got {v!r}")
        v = self.linearity_threshold
        if not is_num(v) or v < 0:
            raise ConfigError(f"mono_ekf.linearity_threshold must be a number >= 0, got {v!r}")
        for name in ("rescue_chi2_prob",):
            v = getattr(self, name)
            if not is_num(v) or not 0.0 < v < 1.0:
                raise ConfigError(f"mono_ekf.{name} must be a probability in (0, 1), got {v!r}")

    @property
    def rho0(self) -> float:
        """Prior inverse distance of a new landmark, 1/m."""
        return 0.5 / self.min_depth_m

    @property
    def sigma_rho(self) -> float:
        """Prior std of the inverse distance, 1/m."""
        return 0.25 / self.min_depth_m
