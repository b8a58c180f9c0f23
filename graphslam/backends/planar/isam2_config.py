"""Settings of the 2-D iSAM2 back end (:mod:`graphslam.backends.planar.isam2`).

Its own module, as for the visual back end (:mod:`graphslam.backends.spatial.isam2_config`):
the settings are read without importing the back end.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

import gtsam
import numpy as np

from graphslam.backends import factorization as fact
from graphslam.backends import gtsam_convert as conv
from slamcore.config import Gate, Validated, bounded

__all__ = ["Isam2Config"]


@dataclass(frozen=True)
class Isam2Config(Validated):
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
        reassociation_passes: unknown association: passes of re-association at the
            end of the run (:mod:`graphslam.backends.planar.isam2_unknown`): each
            solves the graph in batch (the polish's iteration limits), tests every
            sighting again against every landmark and moves those that another
            landmark explains better, scan by scan; passes stop when nothing moves. 0: the
            pairings stay as decided. On MRCLAM Dataset 6 each robot's run settled in
            7-10 passes (the last moving nothing); 20 leaves room for other data, and
            the summary says when the last pass still moved sightings.
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
    GATES: ClassVar[tuple[Gate, ...]] = (
        Gate(
            (
                "polish_max_iterations",
                "polish_relative_error_tol",
                "polish_absolute_error_tol",
                "polish_method",
                "gate_polish_rounds",
            ),
            "polish = true",
            lambda c: c.polish,
        ),
        Gate(
            ("gate_window", "gate_min_support", "gate_scale_from_data", "gate_polish_rounds"),
            "loop_closure_gate > 0",
            lambda c: c.loop_closure_gate > 0,
        ),
        Gate(("gate_polish_rounds",), 'polish_method = "lm"', lambda c: c.polish_method == "lm"),
        Gate(
            ("loop_closure_kernel_k",),
            'loop_closure_kernel other than "none"',
            lambda c: c.loop_closure_kernel != "none",
        ),
        Gate(
            ("observation_kernel_k",),
            'observation_kernel other than "none"',
            lambda c: c.observation_kernel != "none",
        ),
        # known ids: an observation without one is skipped, never associated
        Gate(
            ("association_gate_prob", "confirm_sightings", "reassociation_passes"),
            'association = "unknown"',
            lambda c: c.association == "unknown",
        ),
    )
    relinearize_threshold: float = bounded(0.1, gt=0.0)
    relinearize_skip: int = bounded(10, min=1)
    polish: bool = True
    polish_max_iterations: int = bounded(100, min=1)
    polish_relative_error_tol: float = bounded(1e-5, gt=0.0)
    polish_absolute_error_tol: float = bounded(1e-5, gt=0.0)
    loop_closure_kernel: conv.RobustKernel = "none"
    loop_closure_kernel_k: float = bounded(1.0, gt=0.0)
    polish_method: Literal["lm", "gnc"] = "lm"
    #: 0 disables the gate
    loop_closure_gate: float = bounded(0.0, min=0.0)
    gate_window: int = bounded(5, min=1)
    gate_min_support: int = bounded(2, min=1)
    gate_scale_from_data: bool = True
    gate_polish_rounds: int = bounded(3, min=0)
    factorization: fact.Factorization = "auto"
    observation_kernel: conv.RobustKernel = "cauchy"
    observation_kernel_k: float = bounded(2.385, gt=0.0)
    association: Literal["known", "unknown"] = "known"
    association_gate_prob: float = bounded(0.999, gt=0.0, lt=1.0)
    confirm_sightings: int = bounded(3, min=1)
    reassociation_passes: int = bounded(20, min=0)

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
