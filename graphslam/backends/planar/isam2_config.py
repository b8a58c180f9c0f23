"""Settings of the 2-D iSAM2 back end (:mod:`graphslam.backends.planar.isam2`).

Its own module, as for the visual back end (:mod:`graphslam.backends.spatial.isam2_config`):
the settings are read without importing the back end.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import gtsam
import numpy as np

from graphslam.backends import factorization as fact
from graphslam.backends import gtsam_convert as conv
from slamcore.errors import ConfigError

__all__ = ["Isam2Config"]


@dataclass(frozen=True)
class Isam2Config:
    """iSAM2 settings.

    Attributes:
        relinearize_threshold: relinearise a variable when its delta exceeds this
            (gtsam units: metres / radians of the tangent vector).
        relinearize_skip: check for relinearisation every this many updates.
        polish: run batch Levenberg-Marquardt on the whole graph at the end,
            starting from the incremental solution.
        polish_max_iterations: LM iteration cap for the polish.
        polish_relative_error_tol, polish_absolute_error_tol: LM stops when
            the error decreases by less than this fraction / this amount
            (gtsam's defaults, 1e-5 both). Tighter matters on graphs whose stated
            noise is much looser than the real one (w10000): their error
            surface is so flat that a whole-map bend of 0.2 m changes the error
            by 1e-6, and the defaults stop decimetres from the optimum.
        loop_closure_kernel: robust kernel on loop-closure factors, "none",
            "huber" or "cauchy", so one wrong closure cannot wreck the map.
            Dataset edges that are loop closures get it too.
        loop_closure_kernel_k: kernel width, in sigmas of the whitened residual.
        polish_method: "lm" (Levenberg-Marquardt on the graph as built) or
            "gnc" (graduated non-convexity, gtsam's GncLMOptimizer, with every
            factor but the loop closures known to be an inlier).
        loop_closure_gate: chi-square threshold on a closure's squared
            Mahalanobis residual (3 dof; 16.27 is the 99.9 % quantile), see the
            module docstring; 0 disables the gate (every closure goes in).
        gate_window: poses either side searched for a consistent partner closure.
        gate_min_support: consistent partners needed to accept a closure that
            fails the residual test.
        gate_scale_from_data: scale the gate by the robust residual scale, see
            the module docstring.
        gate_polish_rounds: with the gate and an "lm" polish, how many times
            every closure may be re-tested against the polished solution
            (kept set = closures within the gate) and the polish redone.
        observation_kernel: robust kernel on landmark observations, "none",
            "huber" or "cauchy". Default Cauchy: real range-bearing sensors have
            tails no Gaussian fits (UTIAS MRCLAM: 5 % of ranges and 6 % of
            bearings beyond 3 robust sigma; with "none" iSAM2 ends about 2 m off
            on two of its five robots, with Cauchy within 0.09-0.12 m on all
            five: ``benchmarks/bench_mrclam.py``), and a redescending kernel
            gives a gross outlier no pull at all. On Gaussian data it costs
            little: on the default synthetic world, seeds 0-4, ATE 0.15-0.33 m
            with either setting.
        observation_kernel_k: its width in sigmas of the whitened residual;
            2.385 is Cauchy's 95 %-efficiency constant (Holland and Welsch
            1977; Huber's is 1.345): on Gaussian data the estimate keeps 95 %
            of the least-squares efficiency.
        association: "known" (the observations' landmark ids) or "unknown" (the ids
            are ignored; :mod:`graphslam.backends.planar.landmark_association`
            pairs observations with landmarks by maximum likelihood on iSAM2's
            marginals and keeps new landmarks provisional until confirmed).
        association_gate_prob: unknown association: the individual-compatibility
            gate, a chi-square (2 dof) probability; 0.999 as the EKF's gate.
        confirm_sightings: unknown association: sightings, each compatible with
            the candidate, before a new landmark enters the map (3: one outlier,
            or two that happen to agree, never make a landmark; with 3-5 % of
            MRCLAM's sightings beyond 3 robust sigma, three outliers among
            three sightings of a place is a 1e-4 event).
        factorization: "auto" (Cholesky; on an indeterminate system, QR from
            then on, reported by :meth:`Isam2Backend.numerical_recoveries`),
            "cholesky" (no fallback) or "qr"; see
            :mod:`graphslam.backends.factorization`.
    """

    SECTION: ClassVar[str] = "isam2"
    #: settings that act on loop closures only: a run without any says they did nothing
    LOOP_CLOSURE_KEYS: ClassVar[tuple[str, ...]] = (
        "loop_closure_kernel",
        "loop_closure_kernel_k",
        "polish_method",
        "loop_closure_gate",
        "gate_window",
        "gate_min_support",
        "gate_scale_from_data",
        "gate_polish_rounds",
    )
    relinearize_threshold: float = 0.1
    relinearize_skip: int = 10
    polish: bool = True
    polish_max_iterations: int = 100
    polish_relative_error_tol: float = 1e-5
    polish_absolute_error_tol: float = 1e-5
    loop_closure_kernel: str = "none"
    loop_closure_kernel_k: float = 1.0
    polish_method: str = "lm"
    loop_closure_gate: float = 0.0
    gate_window: int = 5
    gate_min_support: int = 2
    gate_scale_from_data: bool = True
    gate_polish_rounds: int = 3
    factorization: str = "auto"
    observation_kernel: str = "cauchy"
    observation_kernel_k: float = 2.385
    association: str = "known"
    association_gate_prob: float = 0.999
    confirm_sightings: int = 3

    def __post_init__(self):
        if self.loop_closure_kernel not in conv.ROBUST_KERNELS:
            raise ConfigError("isam2.loop_closure_kernel must be none, huber or cauchy")
        if self.loop_closure_kernel_k <= 0:
            raise ConfigError("isam2.loop_closure_kernel_k must be > 0")
        if self.polish_method not in ("lm", "gnc"):
            raise ConfigError("isam2.polish_method must be lm or gnc")
        if self.relinearize_threshold <= 0:
            raise ConfigError("isam2.relinearize_threshold must be > 0")
        if self.relinearize_skip < 1:
            raise ConfigError("isam2.relinearize_skip must be >= 1")
        if self.polish_max_iterations < 1:
            raise ConfigError("isam2.polish_max_iterations must be >= 1")
        if not (self.polish_relative_error_tol > 0 and self.polish_absolute_error_tol > 0):
            raise ConfigError("isam2.polish_relative_error_tol and _absolute_error_tol must be > 0")
        if not self.loop_closure_gate >= 0:
            raise ConfigError("isam2.loop_closure_gate must be >= 0 (0: no gate)")
        if self.gate_min_support < 1:
            raise ConfigError("isam2.gate_min_support must be >= 1")
        if self.gate_window < 1:
            raise ConfigError("isam2.gate_window must be >= 1")
        if self.gate_polish_rounds < 0:
            raise ConfigError("isam2.gate_polish_rounds must be >= 0")
        if self.association not in ("known", "unknown"):
            raise ConfigError("isam2.association must be known or unknown")
        if not 0.0 < self.association_gate_prob < 1.0:
            raise ConfigError("isam2.association_gate_prob must be > 0 and < 1")
        if self.confirm_sightings < 1:
            raise ConfigError("isam2.confirm_sightings must be >= 1")
        if self.observation_kernel not in conv.ROBUST_KERNELS:
            raise ConfigError("isam2.observation_kernel must be none, huber or cauchy")
        if not self.observation_kernel_k > 0:
            raise ConfigError("isam2.observation_kernel_k must be > 0")
        if self.factorization not in fact.FACTORIZATIONS:
            raise ConfigError("isam2.factorization must be auto, cholesky or qr")

    def loop_closure_noise(self, covariance: np.ndarray) -> gtsam.noiseModel.Base:
        """Gaussian noise of a closure, wrapped in the configured robust kernel."""
        return conv.robust(
            conv.noise_from_covariance(covariance), self.loop_closure_kernel, self.loop_closure_kernel_k
        )

    def isam2_params(self) -> gtsam.ISAM2Params:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self.relinearize_threshold)
        params.relinearizeSkip = self.relinearize_skip
        return fact.isam2_factorization(params, self.factorization)
