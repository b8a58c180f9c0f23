"""Settings of the pose-graph solver (section ``[posegraph]``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

from graphslam.backends.factorization import Factorization
from slamcore.config import Validated, bounded

#: How the batch solve is started (``--init``).
INIT_METHODS = ("auto", "odometry", "vertices", "lago", "chordal", "shonan")


@dataclass(frozen=True)
class PoseGraphConfig(Validated):
    """Pose-graph solver settings.

    Attributes:
        init: start of the batch solve: ``odometry`` (edges composed along a
            spanning tree that prefers the odometry chain), ``vertices`` (the
            file's), ``lago`` (2-D, ``gtsam.lago``), ``chordal`` (3-D,
            ``gtsam.InitializePose3``), ``shonan`` (``gtsam.ShonanAveraging2/3``
            rotations, certified when its minimum eigenvalue is >= 0; in 3-D on
            SE-Sync's isotropic weights of each edge, which gtsam needs), or
            ``auto`` = lago in 2-D, chordal in 3-D. iSAM2's polish starts from
            whichever of the iSAM2 estimate and this start has the lower cost.
        factorization: ``auto`` (Cholesky; QR where it meets an indeterminate
            system; batch LM if QR fails too), ``cholesky`` or ``qr``.
        max_iterations, relative_error_tol, absolute_error_tol: Levenberg-Marquardt
            stopping rules; the tolerances are tight because the benchmark
            graphs' cost surfaces are flat near the optimum and gtsam's default
            1e-5 stops short of it by more than 1e-6 relative.
        relinearize_threshold, relinearize_skip: iSAM2's, as in ``[isam2]``.
        polish: batch LM after iSAM2.
        robust_closures: how loop closures (edges between poses that are not
            neighbours in id order) that may be wrong are handled (see
            :mod:`graphslam.backends.posegraph.robust`): ``auto`` (default)
            when the graph has closures, iSAM2 adds them under a Cauchy kernel
            and, if any closure fails the outlier test at the best start, the
            solve is gtsam's GNC (odometry known inliers), closures it weighs
            below 0.5 rejected (``closures.csv``) and left out of a final LM;
            ``gnc``: GNC always; ``none``: plain least squares over every edge
            (graphs known clean).
        closure_test_alpha: probability that a graph whose closures all follow
            their stated noise loses one of them to the outlier test (the test
            is at ``1 - alpha / M`` per closure, M closures: Bonferroni).
        prior_sigma: gauge prior on the first pose (or the ``FIX`` poses), in
            metres / radians; it costs nothing at the optimum.
        toro_noise: how TORO files' edge numbers are read: ``information`` (the
            TORO format) or ``sqrt_information`` (files written by iSAM, such as
            gtsam's ``sphere2500.txt``: the upper triangle ``R`` of ``R^T R``);
            ``auto`` (default): ``sqrt_information`` for the files known to hold it
            (``graphslam.sources.posegraph_files.KNOWN_TORO_NOISE``, by content),
            said in the summary, else ``information``.
        information_fix: an edge information that is not positive definite is
            replaced by the ``nearest`` positive-definite matrix (eigenvalues raised
            to 1e-6 of the largest), or by SE-Sync's ``isotropic`` translation and
            rotation weights, or is ``refuse``d (an error naming file and line).
        certify: after a whole-file solve (default on), check whether the estimate
            is the global optimum of SE-Sync's problem (isotropic weights, chordal
            rotation distance; :mod:`graphslam.backends.posegraph.certificate`) and
            say so in the summary and ``metrics.json``; it adds a local solve of that
            problem (at most as long as the solve) and one sparse factorisation
            (gtsam's sphere2500: 1.4 s beside a 0.9 s solve; w10000: 2.0 s beside 3.2 s).
    """

    SECTION: ClassVar[str] = "posegraph"
    init: Literal["auto", "odometry", "vertices", "lago", "chordal", "shonan"] = "auto"
    factorization: Factorization = "auto"
    max_iterations: int = bounded(200, min=1, max=100_000)
    relative_error_tol: float = bounded(1e-10, gt=0.0, lt=1.0)
    absolute_error_tol: float = bounded(1e-10, gt=0.0)
    relinearize_threshold: float = bounded(0.1, gt=0.0)
    relinearize_skip: int = bounded(10, min=1, max=1_000_000)
    polish: bool = True
    robust_closures: Literal["auto", "gnc", "none"] = "auto"
    closure_test_alpha: float = bounded(0.01, gt=0.0, lt=1.0)
    prior_sigma: float = bounded(1e-3, gt=0.0)
    toro_noise: Literal["auto", "information", "sqrt_information"] = "auto"
    information_fix: Literal["nearest", "isotropic", "refuse"] = "nearest"
    certify: bool = True
