"""``run --intrinsics estimate``: the focal length of a plain image folder from its images.

Photos from a phone or a camera nobody calibrated come without ``fx fy cx cy``. Structure
from motion starts such a camera at a guess and refines it with the scene (COLMAP does so
by default); this does the same on top of the visual iSAM2:

1. start at :data:`~graphslam.sources.spatial.calibration.START_FOCAL_PER_LONG_SIDE` times
   the image's longer side, the principal point at the centre, no distortion;
2. run the camera alone (no odometry) on the first :data:`CALIBRATION_MAX_FRAMES` frames
   at the current focal length, with the run's own configuration;
3. solve that run's bundle again with the focal length free
   (:func:`graphslam.backends.spatial.self_calibration.refine_focal`);
4. repeat from 2 at the refined focal length until it moves by less than
   :data:`CONVERGED_SHARE` of itself: the tracker's gates, the two-view start and the
   triangulations all depend on the focal length, so a start far off (KITTI's wide
   images: 2.1 times the truth) needs a few rounds, each tracking further.

A run cut partway (a frame the back end could not place at a poor guess) still gives the
bundle of the frames before the cut. The estimate is refused, one line, when the images
do not determine it (:data:`MAX_SIGMA_SHARE`) or the rounds do not settle
(:data:`MAX_ROUNDS`). Every round is a seeded run: the same images give the same bits.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from graphslam.backends.spatial.self_calibration import FocalFit, refine_focal
from graphslam.pipelines.common import BackendFailed, FrameUnreadable, stop_requested
from graphslam.pipelines.session import VisualSetup
from graphslam.sources.spatial.calibration import START_FOCAL_PER_LONG_SIDE, start_camera
from graphslam.sources.spatial.sequence import ImageSequence
from slamcore.config import ConfigFile
from slamcore.errors import GraphSlamError

__all__ = ["CameraEstimate", "estimate_camera"]

#: Frames each round runs on: KITTI 07's 160 frames determine the focal length to 0.35 %
#: (2.4 px of 690); more only cost time, round after round.
CALIBRATION_MAX_FRAMES = 200
#: Rounds stop once the focal length moves by less than this share of itself (0.1 %:
#: under a third of the smallest standard deviation measured, KITTI's 0.35 %).
CONVERGED_SHARE = 1e-3
#: Rounds before the estimate is refused as not settling (KITTI from 2.1 times its focal
#: length: 4 rounds; the Lund door from 0.95 times: 2).
MAX_ROUNDS = 10
#: Refused when the standard deviation exceeds this share of the focal length: 2 % of
#: the focal length is 2 % of every depth, and the images then do not tell the camera.
MAX_SIGMA_SHARE = 0.02
#: Fewest frames whose bundle is refined (two views and a third to check them).
MIN_FRAMES = 3
#: Shorter runs tried when a round's run fails partway (module docstring).
RETRIES = 3
#: The visual back end whose bundle is refined (the one that keeps a bundle).
CALIBRATION_BACKEND = "isam2"


@dataclass(frozen=True)
class CameraEstimate:
    """The outcome of :func:`estimate_camera`.

    Attributes:
        K: (3, 3) the estimated intrinsic matrix, pixels (``fx = fy``, principal point at
            the image centre).
        f_px, sigma_px: the focal length and its standard deviation, pixels.
        start_f_px: the first round's focal length, pixels.
        rounds: ``(f_px in, f_px out, frames placed)`` of every round.
        frames: frames of the last round's bundle; projections: its pixels.
    """

    K: np.ndarray
    f_px: float
    sigma_px: float
    start_f_px: float
    rounds: tuple[tuple[float, float, int], ...]
    frames: int
    projections: int

    def to_dict(self) -> dict:
        """``metrics.json``'s ``camera_estimate``."""
        return {
            "fx_px": self.f_px,
            "fy_px": self.f_px,
            "cx_px": float(self.K[0, 2]),
            "cy_px": float(self.K[1, 2]),
            "sigma_f_px": self.sigma_px,
            "start_f_px": self.start_f_px,
            "rounds": [{"f_in_px": a, "f_out_px": b, "frames": n} for a, b, n in self.rounds],
            "frames": self.frames,
            "projections": self.projections,
            "model": "pinhole, fx = fy, principal point at the image centre, no distortion",
        }

    def file_text(self) -> str:
        """The camera as an intrinsics file (``fx fy cx cy``), for ``--intrinsics FILE``."""
        return (
            f"# estimated by graphslam run --intrinsics estimate: f = {self.f_px:.2f} +- "
            f"{self.sigma_px:.2f} px over {self.frames} frames\n"
            f"{self.f_px!r} {self.f_px!r} {float(self.K[0, 2])!r} {float(self.K[1, 2])!r}\n"
        )


def estimate_camera(
    sequence: ImageSequence,
    config: ConfigFile,
    *,
    max_frames: int | None = None,
    detector: str | None = None,
    on_round: Callable[[int, float, float, int], None] | None = None,
) -> CameraEstimate:
    """The focal length of ``sequence``'s camera (module docstring); ``sequence.K``'s
    principal point is held. ``max_frames``: the run's own frame limit, if any;
    ``on_round(round, f_in, f_out, frames)`` after each round (progress).

    Raises GraphSlamError (one line) when no bundle can be built, the images do not
    determine the focal length or the rounds do not settle; KeyboardInterrupt when a
    stop signal came during a round (nothing is estimated yet to write).
    """
    size = sequence.image_size
    f = START_FOCAL_PER_LONG_SIDE * max(size)
    cx, cy = float(sequence.K[0, 2]), float(sequence.K[1, 2])
    n = min(len(sequence), CALIBRATION_MAX_FRAMES, max_frames or CALIBRATION_MAX_FRAMES)
    rounds: list[tuple[float, float, int]] = []
    for k in range(MAX_ROUNDS):
        fit, frames = _round(sequence, start_camera(size, f), config, n, detector)
        rounds.append((f, fit.f_px, frames))
        if on_round is not None:
            on_round(k + 1, f, fit.f_px, frames)
        if not (np.isfinite(fit.f_px) and fit.f_px > 0.0):
            raise GraphSlamError(
                f"--intrinsics estimate: the bundle adjustment gave no focal length ({fit.f_px} px "
                f"from {f:.1f} px): pass the camera's intrinsics"
            )
        moved = abs(fit.f_px - f)
        f = fit.f_px
        if moved < CONVERGED_SHARE * f:
            break
    else:
        raise GraphSlamError(
            f"--intrinsics estimate: the focal length did not settle in {MAX_ROUNDS} rounds "
            f"({', '.join(f'{r[1]:.1f}' for r in rounds[-3:])} px last): pass the camera's intrinsics"
        )
    if fit.sigma_px is None or fit.sigma_px > MAX_SIGMA_SHARE * f:
        spread = "undetermined" if fit.sigma_px is None else f"+- {fit.sigma_px:.1f} px"
        raise GraphSlamError(
            f"--intrinsics estimate: these images do not determine the focal length ({f:.1f} px, "
            f"{spread} from {frames} frames; at most {MAX_SIGMA_SHARE:.0%} is taken): "
            "pass the camera's intrinsics (a calibration, or photos that turn more)"
        )
    K = np.array(start_camera(size, f))
    K[0, 2], K[1, 2] = cx, cy
    return CameraEstimate(K, f, fit.sigma_px, rounds[0][0], tuple(rounds), frames, fit.projections)


def with_camera(sequence: ImageSequence, K: np.ndarray) -> ImageSequence:
    """``sequence`` read with the intrinsic matrix ``K`` (no distortion)."""
    return dataclasses.replace(sequence, K=np.asarray(K, dtype=np.float64), distortion=None)


def _round(
    sequence: ImageSequence,
    K: np.ndarray,
    config: ConfigFile,
    n: int,
    detector: str | None,
    retries: int = RETRIES,
) -> tuple[FocalFit, int]:
    """One camera-alone run of ``n`` frames at ``K`` and its bundle refined: ``(fit,
    frames placed)``. A run the back end cannot continue (a frame it cannot place at a
    poor guess) is run again, up to ``retries`` times, on the frames before."""
    done = [0]

    def count(k: int, *_) -> None:
        done[0] = k + 1

    setup = VisualSetup.read(
        with_camera(sequence, K), config, odometry="none", max_frames=n, detector=detector
    )
    session = setup.session(CALIBRATION_BACKEND)
    try:
        session.run(on_frame=count)
    except (FrameUnreadable, BackendFailed, GraphSlamError) as e:
        if stop_requested():
            raise KeyboardInterrupt from None
        # the frame that broke it may be the last one in: its factors go in with the next
        shorter = min(done[0], n - 1)
        if shorter < MIN_FRAMES or retries == 0:
            raise GraphSlamError(f"--intrinsics estimate: at f = {K[0, 0]:.1f} px, {e}") from None
        return _round(sequence, K, config, shorter, detector, retries - 1)
    if stop_requested():
        raise KeyboardInterrupt  # a stop during a round: no camera, nothing to write
    placed = len(session.backend.estimate().frame_ids)
    if placed < MIN_FRAMES:
        raise GraphSlamError(
            f"--intrinsics estimate: at f = {K[0, 0]:.1f} px the camera-alone run placed "
            f"{placed} frame(s); {MIN_FRAMES} are needed: pass the camera's intrinsics"
        )
    graph, values = session.backend.bundle()
    try:
        return refine_focal(graph, values, K[0, 0], K[0, 2], K[1, 2]), placed
    except (RuntimeError, ValueError) as e:  # gtsam's indeterminate system, no projection
        raise GraphSlamError(
            f"--intrinsics estimate: the bundle adjustment at f = {K[0, 0]:.1f} px failed ({e}): "
            "pass the camera's intrinsics"
        ) from None
