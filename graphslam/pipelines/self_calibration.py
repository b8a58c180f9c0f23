"""``run --intrinsics estimate``: the camera of a plain image folder from its images.

Photos from a phone or a camera nobody calibrated come without ``fx fy cx cy``. Structure
from motion starts such a camera at a guess and refines it with the scene (COLMAP does so
by default); this does the same on top of the visual iSAM2 (:func:`settle`):

1. start at a focal length of the image's longer side times a factor, the principal
   point at the centre, no distortion (COLMAP's ``SIMPLE_RADIAL`` camera, ``k1 = 0``);
2. run the camera alone (no odometry) on the first :data:`CALIBRATION_MAX_FRAMES` frames
   at the current focal length, with the run's own configuration;
3. solve that run's bundle again with the focal length and ``k1`` free
   (:func:`graphslam.backends.spatial.self_calibration.refine_camera`);
4. repeat from 2 on images undistorted at the refined camera until it settles
   (:data:`CONVERGED_SHARE`, :data:`CONVERGED_K1`, :data:`CONVERGED_SIGMAS`), first with
   ``k1`` held at 0, then with it free (far from its focal length a camera's ``k1``
   absorbs the error: KITTI from 2.1 times its focal length gave ``k1 = 1.04``). The
   tracker's gates, the two-view start and the triangulations all depend on the
   camera, so a start far off (KITTI's wide images: 2.1 times the truth) needs a few
   rounds, each tracking further.

:func:`estimate_camera` settles from two starts (:data:`STARTS_PER_LONG_SIDE`) and
takes the estimate only when both settle at one camera: a bundle's standard
deviation says how well it holds its own minimum, not whether the images hold only
that one.

A run cut partway (a frame the back end could not place at a poor guess) still gives the
bundle of the frames before the cut. The estimate is refused, one line, when the images
do not determine it (:data:`MAX_SIGMA_SHARE`, or the starts settle apart) or the rounds
do not settle (:data:`MAX_ROUNDS`). Every round is a seeded run: the same images give
the same bits.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from graphslam.backends.spatial.self_calibration import CameraFit, refine_camera
from graphslam.pipelines.common import BackendFailed, FrameUnreadable, stop_requested
from graphslam.pipelines.session import VisualSetup
from graphslam.sources.spatial.calibration import START_FOCAL_PER_LONG_SIDE, start_camera
from graphslam.sources.spatial.sequence import ImageSequence, camera_doubts
from slamcore.config import ConfigFile
from slamcore.errors import GraphSlamError

__all__ = ["CameraEstimate", "Settled", "estimate_camera", "settle", "with_camera"]

#: The starts, times the image's longer side: COLMAP's default (1.2, about 45 deg across
#: the longer side) and a phone's wide camera (0.7: 26 mm equivalent, 69 deg). Both must
#: settle at one camera: a bundle built at a focal length can hold it as a local minimum
#: when the motion does not determine it (the synthetic room's first 60 frames, driven
#: in a plane, settle at 444.0 +- 3.9 px from 0.7 and at 750.4 +- 10.5 from 1.2, its
#: camera 500), so one start alone can be confidently wrong. The Lund door settles at
#: 2454.3 px from both (2441.7 before stop 71's larger camera-alone start; the focal
#: length alone: 2464.7 px from 0.7, 0.9, 1.2 and 1.5); KITTI 07 at 695.2 and 695.9
#: before stop 71, refused since (docs/data/images.md).
STARTS_PER_LONG_SIDE = (START_FOCAL_PER_LONG_SIDE, 0.7)
#: Two starts agree when they settle within this many of their combined standard
#: deviations (and the rounds' own convergence, :data:`CONVERGED_SHARE` and
#: :data:`CONVERGED_K1`, twice).
AGREE_SIGMAS = 3.0
#: Frames each round runs on: KITTI 07's 160 frames determined the focal length to 1.1 %
#: (7.8 px of 695; 0.35 % with k1 held; before stop 71); more only cost time, round after round.
CALIBRATION_MAX_FRAMES = 200
#: Rounds stop once the focal length moves by less than this share of itself (0.1 %:
#: under a third of the smallest standard deviation measured, KITTI's 0.35 % with k1
#: held) ...
CONVERGED_SHARE = 1e-3
#: ... and ``k1`` by less than this: at a 45 deg half view (the normalised radius 1), a
#: pixel moves by ``f`` times it, 0.1 % of the focal length as above.
CONVERGED_K1 = 1e-3
#: ... or each by less than this many of its own standard deviations: a round's run on
#: images undistorted anew tracks other pixels, so the camera moves between rounds by a
#: share of its own uncertainty (the Lund door: 2-6 px against 21 px, k1 by 0.004
#: against 0.015) however many rounds follow.
CONVERGED_SIGMAS = 0.5
#: Largest ``|k1|`` taken: beyond it the distortion folds within 45 deg of the axis
#: (``1 + 3 k1 r^2`` reaches 0 at ``r = 1`` for ``k1 = -1/3``) and the images are not a
#: lens COLMAP's one coefficient describes (a fisheye: undistort them first).
MAX_ABS_K1 = 0.3
#: Rounds per stage (k1 held, then free) before the estimate is refused as not settling
#: (KITTI from 2.1 times its focal length: 5 and 2; the Lund door from 0.56 times: 6 and 2).
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
class Settled:
    """Where the rounds from one start settled.

    Attributes:
        start_f_px: the first round's focal length, pixels (``k1 = 0``).
        f_px, sigma_f_px: the settled focal length and its standard deviation, pixels.
        k1, sigma_k1: the settled radial coefficient and its standard deviation.
        rounds: ``(f_px in, f_px out, k1 out, frames placed)`` of every round.
        frames: frames of the last round's bundle; projections: its pixels.
    """

    start_f_px: float
    f_px: float
    sigma_f_px: float
    k1: float
    sigma_k1: float
    rounds: tuple[tuple[float, float, float, int], ...]
    frames: int
    projections: int

    def to_dict(self) -> dict:
        return {
            "start_f_px": self.start_f_px,
            "f_px": self.f_px,
            "sigma_f_px": self.sigma_f_px,
            "k1": self.k1,
            "sigma_k1": self.sigma_k1,
            "rounds": [{"f_in_px": a, "f_out_px": b, "k1_out": k, "frames": n} for a, b, k, n in self.rounds],
            "frames": self.frames,
            "projections": self.projections,
        }


@dataclass(frozen=True)
class CameraEstimate:
    """The outcome of :func:`estimate_camera`.

    Attributes:
        K: (3, 3) the estimated intrinsic matrix, pixels (``fx = fy``, principal point at
            the image centre).
        distortion: (4,) OpenCV's coefficients ``(k1, 0, 0, 0)``.
        settled: where the rounds from each start of :data:`STARTS_PER_LONG_SIDE`
            settled; the first is the estimate, the others agreed with it.
    """

    K: np.ndarray
    distortion: np.ndarray
    settled: tuple[Settled, ...]

    @property
    def f_px(self) -> float:
        return self.settled[0].f_px

    @property
    def sigma_px(self) -> float:
        return self.settled[0].sigma_f_px

    def to_dict(self) -> dict:
        """``metrics.json``'s ``camera_estimate``."""
        first = self.settled[0]
        return {
            "fx_px": self.f_px,
            "fy_px": self.f_px,
            "cx_px": float(self.K[0, 2]),
            "cy_px": float(self.K[1, 2]),
            "k1": first.k1,
            "sigma_f_px": first.sigma_f_px,
            "sigma_k1": first.sigma_k1,
            "model": "COLMAP's SIMPLE_RADIAL: fx = fy, principal point at the image centre, radial k1",
            "starts": [s.to_dict() for s in self.settled],
        }

    def file_text(self) -> str:
        """The camera as an intrinsics file (``fx fy cx cy``, then OpenCV's distortion
        ``k1 k2 p1 p2``), for ``--intrinsics FILE``."""
        first = self.settled[0]
        return (
            f"# estimated by graphslam run --intrinsics estimate over {first.frames} frames: f = "
            f"{first.f_px:.2f} +- {first.sigma_f_px:.2f} px, k1 = {first.k1:.4f} +- {first.sigma_k1:.4f}\n"
            f"{self.f_px!r} {self.f_px!r} {float(self.K[0, 2])!r} {float(self.K[1, 2])!r}\n"
            f"{first.k1!r} 0 0 0\n"
        )


def estimate_camera(
    sequence: ImageSequence,
    config: ConfigFile,
    *,
    max_frames: int | None = None,
    detector: str | None = None,
    seed: int | None = None,
    on_round: Callable[[float, int, float, float, float, int], None] | None = None,
) -> CameraEstimate:
    """The camera of ``sequence`` (module docstring); ``sequence.K``'s principal point is
    held. ``max_frames``, ``detector``, ``seed``: the run's own frame limit, corner
    detector and seed (its RANSACs' draws), if any; ``on_round(start_f, round, f_in,
    f_out, k1_out, frames)`` after each round (progress).

    Raises GraphSlamError (one line) when no bundle can be built, the images do not
    determine the camera (too wide, or the starts settle apart) or the rounds do not
    settle; KeyboardInterrupt when a stop signal came during a round (nothing is
    estimated yet to write).
    """
    size = sequence.image_size
    n = min(len(sequence), CALIBRATION_MAX_FRAMES, max_frames or CALIBRATION_MAX_FRAMES)
    settled = [
        settle(sequence, config, factor * max(size), n, detector, seed, on_round)
        for factor in STARTS_PER_LONG_SIDE
    ]
    first = settled[0]
    for other in settled[1:]:
        f_slack = AGREE_SIGMAS * float(np.hypot(first.sigma_f_px, other.sigma_f_px))
        k1_slack = AGREE_SIGMAS * float(np.hypot(first.sigma_k1, other.sigma_k1))
        if (
            abs(other.f_px - first.f_px) > f_slack + 2.0 * CONVERGED_SHARE * max(first.f_px, other.f_px)
            or abs(other.k1 - first.k1) > k1_slack + 2.0 * CONVERGED_K1
        ):
            raise GraphSlamError(
                f"--intrinsics estimate: these images do not determine the camera: from "
                f"{first.start_f_px:.1f} px it settles at {first.f_px:.1f} +- {first.sigma_f_px:.1f} px "
                f"(k1 {first.k1:.3f}), from {other.start_f_px:.1f} px at {other.f_px:.1f} +- "
                f"{other.sigma_f_px:.1f} px (k1 {other.k1:.3f}) (a motion that does not fix it, as "
                "driving in a plane can be): pass the camera's intrinsics"
            )
    K = np.array(start_camera(size, first.f_px))
    K[0, 2], K[1, 2] = float(sequence.K[0, 2]), float(sequence.K[1, 2])
    return CameraEstimate(K, np.array([first.k1, 0.0, 0.0, 0.0]), tuple(settled))


def settle(
    sequence: ImageSequence,
    config: ConfigFile,
    f: float,
    n: int,
    detector: str | None = None,
    seed: int | None = None,
    on_round: Callable[[float, int, float, float, float, int], None] | None = None,
) -> Settled:
    """Rounds from the focal length ``f`` (pixels, ``k1 = 0``) on the first ``n`` frames
    until the camera stops moving (module docstring); GraphSlamError when they do not
    settle or the settled bundle does not determine it."""
    start, k1 = f, 0.0
    size = sequence.image_size
    rounds: list[tuple[float, float, float, int]] = []
    for free_k1 in (False, True):  # the focal length first: k1 far from it absorbs its error
        for _ in range(MAX_ROUNDS):
            try:
                fit, frames, cut = _round(
                    sequence, (start_camera(size, f), k1, free_k1), config, n, detector, seed
                )
            except GraphSlamError as e:
                if not rounds:
                    raise
                # a run that placed frames a round ago fails at a camera close by: say so
                # (KITTI's first 40 frames, median parallax 0.5 deg, start or not by chance)
                raise GraphSlamError(
                    f"{e} (the {len(rounds)} round(s) before, from {start:.1f} px, placed up to "
                    f"{max(r[3] for r in rounds)} frames: these frames hold a camera-alone run by a "
                    "thread; more frames or more motion, or the camera's intrinsics)"
                ) from None
            rounds.append((f, fit.f_px, fit.k1, frames))
            if on_round is not None:
                on_round(start, len(rounds), f, fit.f_px, fit.k1, frames)
            if not (np.isfinite(fit.f_px) and fit.f_px > 0.0 and abs(fit.k1) <= MAX_ABS_K1):
                raise GraphSlamError(
                    f"--intrinsics estimate: the bundle adjustment gave no camera a lens of one radial "
                    f"coefficient makes (f {fit.f_px:.1f} px, k1 {fit.k1:.3f} from {f:.1f} px; |k1| at most "
                    f"{MAX_ABS_K1}): pass the camera's intrinsics (a fisheye: undistort it first)"
                )
            moved_f, moved_k1 = abs(fit.f_px - f), abs(fit.k1 - k1)
            f, k1 = fit.f_px, fit.k1
            if moved_f < max(
                CONVERGED_SHARE * f, CONVERGED_SIGMAS * (fit.sigma_f_px or 0.0)
            ) and moved_k1 < max(CONVERGED_K1, CONVERGED_SIGMAS * (fit.sigma_k1 or 0.0)):
                break
        else:
            raise GraphSlamError(
                f"--intrinsics estimate: from {start:.1f} px the camera did not settle in {MAX_ROUNDS} "
                f"rounds ({', '.join(f'{r[1]:.1f}' for r in rounds[-3:])} px last): pass the camera's "
                "intrinsics"
            )
    if fit.sigma_f_px is None or fit.sigma_k1 is None or fit.sigma_f_px > MAX_SIGMA_SHARE * f:
        spread = "undetermined" if fit.sigma_f_px is None else f"+- {fit.sigma_f_px:.1f} px"
        raise GraphSlamError(
            f"--intrinsics estimate: these images do not determine the focal length ({f:.1f} px, "
            f"{spread} from {frames} frames; at most {MAX_SIGMA_SHARE:.0%} is taken): "
            "pass the camera's intrinsics (a calibration, or photos that turn more)"
            + ("" if cut is None else f"; the rounds' runs stopped early: {cut}")
        )
    return Settled(start, f, fit.sigma_f_px, k1, fit.sigma_k1, tuple(rounds), frames, fit.projections)


def with_camera(sequence: ImageSequence, K: np.ndarray, k1: float = 0.0) -> ImageSequence:
    """``sequence`` read with the intrinsic matrix ``K`` and radial coefficient ``k1``
    (OpenCV's ``(k1, 0, 0, 0)``; its images are undistorted on loading), its camera
    doubts those of ``K`` (InputError when ``K`` cannot be a camera of its images)."""
    K = np.asarray(K, dtype=np.float64)
    doubts = camera_doubts(K, sequence.image_size, "--intrinsics estimate", sequence.image_paths[0])
    distortion = None if k1 == 0.0 else np.array([k1, 0.0, 0.0, 0.0])
    return dataclasses.replace(sequence, K=K, distortion=distortion, camera_warnings=tuple(doubts))


def _round(
    sequence: ImageSequence,
    camera: tuple[np.ndarray, float, bool],
    config: ConfigFile,
    n: int,
    detector: str | None,
    seed: int | None,
    retries: int = RETRIES,
) -> tuple[CameraFit, int, str | None]:
    """One camera-alone run of ``n`` frames at ``camera`` (``K``, ``k1``, whether ``k1`` is
    refined too) and its bundle refined: ``(fit, frames placed, why the run stopped
    early or None)``. A run the back end cannot continue (a frame it cannot place at a
    poor guess, a frame that cannot be read) is run again, up to ``retries`` times, on
    the frames before."""
    K, k1, free_k1 = camera
    done = [0]

    def count(k: int, *_) -> None:
        done[0] = k + 1

    setup = VisualSetup.read(
        with_camera(sequence, K, k1), config, odometry="none", seed=seed, max_frames=n, detector=detector
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
        fit, placed, _ = _round(sequence, camera, config, shorter, detector, seed, retries - 1)
        return fit, placed, " ".join(str(e).split())
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
        return refine_camera(graph, values, K[0, 0], k1, K[0, 2], K[1, 2], free_k1), placed, None
    except (RuntimeError, ValueError) as e:  # gtsam's indeterminate system, no projection
        raise GraphSlamError(
            f"--intrinsics estimate: the bundle adjustment at f = {K[0, 0]:.1f} px failed ({e}): "
            "pass the camera's intrinsics"
        ) from None
