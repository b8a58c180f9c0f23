"""Settings of the visual iSAM2 back end (:class:`graphslam.backends.spatial.isam2.VisualIsam2Backend`).

Section ``[isam2_visual]`` of the config file; types, modes and ranges are
declared on the fields and checked on creation by
:func:`slamcore.config.validate` (:class:`slamcore.errors.ConfigError`). The
measured trade-offs behind the defaults are in the attribute notes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Literal

import gtsam

from frontend.two_view import MAX_SEED
from graphslam.backends.gtsam_convert import RobustKernel
from graphslam.backends.spatial.mono_tracking import MonoTrackingConfig
from slamcore.config import Gate, Validated, bounded
from slamcore.errors import ConfigError

#: Fewest landmarks a frame may give factors when the camera alone measures it: a pose
#: has 6 unknowns and a pixel gives 2.
MIN_CAMERA_ALONE_LANDMARKS = 3


@dataclass(frozen=True)
class VisualIsam2Config(Validated):
    """Visual iSAM2 settings.

    Attributes:
        robot_model: ``"odometry"`` (each frame's pose from the odometry, a
            between-factor) or ``"constant_velocity"`` (camera alone,
            ``--odometry none``: a monocular bootstrap, then each frame's pose
            predicted at constant velocity and measured by PnP RANSAC on the
            re-found landmarks; :mod:`graphslam.backends.spatial.mono_tracking`).
        seed: seed of the camera-alone RANSACs (two-view geometry, PnP).
        mono: camera-alone settings (``[isam2_visual.mono]``,
            :class:`~graphslam.backends.spatial.mono_tracking.MonoTrackingConfig`).
        relinearize_threshold: relinearise a variable when its delta exceeds this
            (gtsam tangent units: radians / metres).
        relinearize_skip: check for relinearisation every this many updates.
        pixel_kernel: robust kernel on pixel factors, "huber", "cauchy" or "none".
            On real images wrong ZNCC matches (repeated texture) are off by many
            pixels and Huber still gives them a linear pull: on KITTI 07 frames
            0-159 (derived odometry, seeds 0-3) ATE / odometry ATE is 0.72 on
            average with Cauchy k=1 against 1.00 with Huber 1.345
            (benchmarks/kitti07_visual.toml). Huber stays the default: with
            Cauchy (not convex) the incremental estimate strays farther from
            the batch optimum between relinearisations (0.13 m against
            0.07 m in tests/graphslam/backends/test_isam2_visual.py::test_matches_batch_lm).
        pixel_kernel_k: kernel width in sigmas of the whitened pixel residual.
        min_parallax_deg: angle between the world rays of a track's first and
            latest observations before it is triangulated, degrees. It also
            guards against "parallax" made of pose error alone: a camera
            turning on the spot with drifting odometry passes 1 deg within
            30 frames in tests/graphslam/backends/test_isam2_visual.py. In forward motion with
            metric odometry (KITTI 07) 1 deg maps points near the direction of
            travel before they leave the tracker: seeds 0-3 with the Cauchy
            kernel, ATE / odometry 0.61 with 1 deg against 0.72 with 2 deg
            (benchmarks/kitti07_visual.toml).
        min_observations: pixels a track needs before it is triangulated.
        min_depth_m: a triangulated point must be at least this far in front of
            every camera that saw it.
        max_reprojection_sigmas: a triangulated point's every pixel must
            reproject within this many ``sigma_px`` (Euclidean, in the image).
        track_timeout_frames: a waiting track not seen for this many frames is
            forgotten (bounds the buffer).
        max_track_observations: buffered pixels per waiting track; beyond, the
            oldest but the first (the parallax baseline) is dropped.
        max_landmarks_per_frame: cost bound: at most this many landmarks get a
            factor per frame (those seen longest first; newly triangulated ones
            count, and wait for a later frame when the budget is spent); the
            other pixels are unused (``stats["unused_pixels"]``). 0: no bound.
        newest_pose_last: elimination ordering hint given to each update: only
            the newest pose is constrained to the root of the Bayes tree (False:
            gtsam's default, every variable of the new factors).
        predicted_in_root: elimination ordering hint given to each update: the
            new factors' other keys (where gtsam's default puts them), then the
            previous pose, the landmarks likely to be predicted next (re-eliminated
            even if untouched) and the newest pose are eliminated last, so that
            the last three alone make the Bayes tree's
            root clique and :meth:`~graphslam.backends.spatial.isam2.VisualIsam2Backend.predict_observations`
            reads their joint marginal from it (exact, about 1 ms). With
            gtsam's default ordering the landmarks in view sit in one dense
            clique of hundreds of variables below the root, which every
            marginal query eliminates again (0.1-0.6 s a frame on the 300-frame
            benchmark scene). Excludes ``newest_pose_last``.
        prediction_covariance: "joint" or "marginal", see
            :mod:`graphslam.backends.spatial.isam2`.
        max_predictions: at most this many landmarks predicted per frame, those
            with most observations first; 0: all in view. The joint marginal
            costs grow with it (measured on the 300-frame benchmark scene:
            ~5 ms for 20, ~30 ms for 100 landmarks at frame 120, CPU time).
        predict_window_frames: predict only landmarks observed within this many
            frames (0: every mapped landmark in view). A window turns the map
            into a local one (visual odometry): old places are then recognised
            only through loop closures, never by re-finding their landmarks.
        loop_closure_kernel: robust kernel on loop-closure factors, "none",
            "huber" or "cauchy", so that a wrong closure cannot wreck the map.
        loop_closure_kernel_k: kernel width, in sigmas of the whitened residual.
        polish: at :meth:`~graphslam.backends.spatial.isam2.VisualIsam2Backend.finalize`,
            run batch Levenberg-Marquardt on the whole graph from the
            incremental solution.
        polish_method: "lm", or "gnc" (gtsam's GncLMOptimizer with every factor
            but the loop closures known to be an inlier; closures it weighs
            below 0.5 are counted in ``stats["closures_dropped_by_gnc"]``).
            GNC solves with the Gaussian core of every factor (its own weights
            replace robust kernels), so the pixel factors lose their Huber
            kernel in that solve.
        polish_max_iterations: LM iteration cap for the polish.
    """

    SECTION: ClassVar[str] = "isam2_visual"
    #: settings of loop-closure factors (``--loops``, ``--relocalise``), unread without them
    LOOP_CLOSURE_KEYS: ClassVar[tuple[str, ...]] = ("loop_closure_kernel", "loop_closure_kernel_k")
    GATES: ClassVar[tuple[Gate, ...]] = (
        # the RANSACs seeded are the camera-alone ones (two-view start, PnP)
        Gate(
            ("seed", "mono"),
            'robot_model = "constant_velocity" (a run without odometry)',
            lambda c: c.robot_model == "constant_velocity",
        ),
        Gate(("pixel_kernel_k",), 'pixel_kernel other than "none"', lambda c: c.pixel_kernel != "none"),
        Gate(
            ("loop_closure_kernel_k",),
            'loop_closure_kernel other than "none"',
            lambda c: c.loop_closure_kernel != "none",
        ),
        Gate(("polish_method", "polish_max_iterations"), "polish = true", lambda c: c.polish),
    )
    robot_model: Literal["odometry", "constant_velocity"] = "odometry"
    seed: int = bounded(0, min=0, max=MAX_SEED)  # OpenCV's generators take a C int
    mono: MonoTrackingConfig = field(default_factory=MonoTrackingConfig)
    relinearize_threshold: float = bounded(0.1, gt=0.0)
    relinearize_skip: int = bounded(10, min=1)
    pixel_kernel: RobustKernel = "huber"
    pixel_kernel_k: float = bounded(1.345, gt=0.0)
    min_parallax_deg: float = bounded(2.0, min=0.0, lt=90.0)
    min_observations: int = bounded(3, min=2)  # two rays to triangulate
    min_depth_m: float = bounded(0.1, gt=0.0)
    max_reprojection_sigmas: float = bounded(4.0, gt=0.0)
    track_timeout_frames: int = bounded(10, min=1)
    max_track_observations: int = 30
    # 0 (no bound) by default: with a bound of 40 and max_predictions = 10 the back end runs at
    # 19 frames/s on the 300-frame room (2.3 with no bound and 20 predictions), but with 5 % gross
    # outlier pixels the bound loses 1 cm of ATE (fewer landmarks). Predictions: 10 keeps the
    # joint marginal cheap; active search needs only the most informative few.
    max_landmarks_per_frame: int = bounded(0, min=0)  # 0: no bound
    newest_pose_last: bool = False
    predicted_in_root: bool = True
    prediction_covariance: Literal["joint", "marginal"] = "joint"
    max_predictions: int = bounded(10, min=0)  # 0: no cap
    predict_window_frames: int = bounded(0, min=0)  # 0: no window
    loop_closure_kernel: RobustKernel = "cauchy"
    loop_closure_kernel_k: float = bounded(1.0, gt=0.0)
    polish: bool = True
    polish_method: Literal["lm", "gnc"] = "lm"
    polish_max_iterations: int = bounded(50, min=1)

    def __post_init__(self):
        super().__post_init__()
        if self.newest_pose_last and self.predicted_in_root:
            raise ConfigError(
                "isam2_visual.newest_pose_last and isam2_visual.predicted_in_root are "
                "two elimination orderings: set one of them to false"
            )
        if (
            self.robot_model == "constant_velocity"
            and 0 < self.max_landmarks_per_frame < MIN_CAMERA_ALONE_LANDMARKS
        ):
            # 1 gave a traceback (a pose with no factor), 2 an indeterminate system (hostile pass 17)
            raise ConfigError(
                f"isam2_visual.max_landmarks_per_frame = {self.max_landmarks_per_frame}: without odometry "
                f"each frame's pose comes from its landmarks alone, and a pose (6 unknowns, 2 per pixel) "
                f"needs at least {MIN_CAMERA_ALONE_LANDMARKS} (0: no bound)"
            )
        if self.max_track_observations < self.min_observations:
            raise ConfigError(
                "isam2_visual.max_track_observations must be >= min_observations "
                f"({self.max_track_observations} < {self.min_observations})"
            )

    def isam2_params(self) -> gtsam.ISAM2Params:
        """gtsam's ISAM2 parameters for these settings."""
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self.relinearize_threshold)
        params.relinearizeSkip = self.relinearize_skip
        return params


def run_overrides(mode: str, seed: int | None, no_polish: bool, nearest_depth_m: float | None) -> dict:
    """``[isam2_visual]`` overrides a visual run implies (the back-end table's
    ``run_overrides``): the polish off with ``--no-polish`` and, without odometry
    (``mode`` ``"none"``), the camera-alone tracking (a monocular bootstrap, then
    PnP) with the run's RANSAC seed. The scene's depth is the EKF's concern."""
    out: dict[str, object] = {"polish": False} if no_polish else {}
    if mode == "none":
        out["robot_model"] = "constant_velocity"
        if seed is not None:
            out["seed"] = seed
    return out
