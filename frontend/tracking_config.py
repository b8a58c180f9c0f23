"""Settings of the front-end tracker (:mod:`frontend.tracking`) and the detector they name.

Its own module to keep the tracker readable: the settings, and the detector they
name, are imported from here.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass
from typing import ClassVar, Literal

from frontend.active_search_config import ActiveSearchConfig
from frontend.harris import HarrisConfig
from frontend.image import MAX_POINTS_PER_FRAME, MAX_SIDE_PX
from frontend.orb import OrbConfig
from slamcore.config import ConfigFile, Gate, Validated, bounded
from slamcore.errors import ConfigError

__all__ = ["TrackerConfig", "DETECTORS", "SEARCH_MODES", "AUTO_SEARCH", "make_detector"]

DetectorName = Literal["harris", "orb", "fpga"]
SearchMode = Literal["auto", "zncc", "nearest", "descriptor"]
DETECTORS = typing.get_args(DetectorName)
SEARCH_MODES = typing.get_args(SearchMode)
AUTO_SEARCH = {"harris": "zncc", "fpga": "nearest", "orb": "descriptor"}
#: The tracker's aids for a run without odometry, each on there unless the file sets it.
CAMERA_ALONE_AIDS = (
    "follow_image_motion",
    "follow_missed_landmarks",
    "fill_first_frame",
    "follow_recuts_patch",
    "follow_by_patch",
)


#: Until its map starts, a back end that starts it from two views without odometry
#: (iSAM2 camera alone) keeps up to this many times ``max_tracks``, as ORB-SLAM's
#: monocular initialiser extracts twice its features. The start needs
#: ``two_view.min_points`` (50) tracks shared across a 1-degree baseline, and a third
#: die before it (KITTI 07, frame 13: 55 of 80 Harris tracks left, 52 of 80 ORB ones):
#: 80 leave it at the threshold (ORB, followed by patch, started at frame 66 on 3 of
#: seeds 0-4 and from a wrong homography at frame 32 on the other 2; with 160, at 15 on
#: all 5).
TWO_VIEW_START_TRACKS_FACTOR = 2


@dataclass(frozen=True)
class TrackerConfig(Validated):
    """Front-end tracking settings (config section ``[tracker]``).

    Attributes:
        detector: ``"harris"``, ``"orb"`` or ``"fpga"``.
        search: active-search matching: ``"auto"`` (by detector, see module
            doc), ``"zncc"``, ``"nearest"`` (Harris/FPGA only) or
            ``"descriptor"`` (ORB only).
        max_tracks: new corners are started only while fewer points than this
            are tracked in the frame (until the map starts, a back end that starts
            it from two views without odometry, iSAM2 camera alone, keeps
            :data:`TWO_VIEW_START_TRACKS_FACTOR` times as many).
        max_new_per_frame: new tracks started per frame at most (see ``fill_first_frame``).
        min_distance_px: a new corner is at least this far from every tracked
            or predicted point (no two ids on one physical point).
        follow_unmapped: follow not-yet-mapped tracks from frame to frame;
            ``None`` lets the pipeline decide from the back end.
        follow_window_px: half side of the square window a followed track is
            searched in, around its last position plus its last image motion.
        follow_image_motion, follow_missed_landmarks, fill_first_frame, follow_recuts_patch: aids for a
            run whose back end has no odometry (its predictions are a motion
            model's guess, and a monocular start needs many tracks at once);
            each ``None`` lets the pipeline decide: on without odometry, off
            with it (where they are not needed and the figures measured
            without them stand).
            ``follow_image_motion``: move the follow windows by the change of
            the whole image's motion since the last frame (phase correlation of
            reduced frames): a camera that starts or stops turning moves every
            point at once, farther than a window placed by the track's last
            motion. ``follow_missed_landmarks``: a landmark seen last frame that
            active search did not find (its prediction was off, or beyond the
            back end's prediction cap) is followed like an unmapped track (with
            ``follow_unmapped``), instead of being lost until a prediction brings
            it back; the back end judges the pixel (PnP RANSAC, robust kernels).
            ``fill_first_frame``: a frame that starts with no track at all (the
            first) fills to ``max_tracks`` instead of ``max_new_per_frame``: the
            cap spreads the cost of new tracks over frames, and a monocular
            start measures parallax against one frame's tracks. Until a two-view
            start has its map, every frame fills so (each may be the start's
            reference): on KITTI 07 from frame 48 every second frame (1.2 m a
            frame) most new tracks die at their first follow, and with 20 new a
            frame at most 46 lived 2 frames, never the 50 a start needs; filled,
            87, and the map starts at frame 9.
            ``follow_recuts_patch``: an unmapped track re-cuts its patch at each
            frame it is followed in, whatever ``patch_update`` (as KLT follows
            a feature from one frame to the next: a followed track's only
            reference is the frame before); a mapped landmark keeps the patch
            ``patch_update`` gives it (it is re-found from a prediction, after
            any gap, and the anchor keeps it from drifting). A monocular start
            needs tracks that live through the appearance change of the
            baseline's parallax: KITTI 07 from the camera alone with the
            anchored patches started its map at frame 118 (103 of 160 frames
            without a pose); with this, at frame 13, every frame placed.
        follow_by_patch: an aid like those above (unset: on without odometry, off
            with it), for ORB only (Harris and the FPGA stream always follow by
            patch): an unmapped track, or a missed landmark, is
            followed by ZNCC of its patch, not by descriptor among the ORB
            points of its window (mapped landmarks are still searched by
            descriptor). A descriptor follow needs ORB to find the corner again
            in every frame, and as the car approaches it does not: on KITTI 07's
            first 60 frames (80 tracks, no map) a tenth of the descriptor-followed
            tracks lived past 4 frames and 36 past 10, of the patch-followed ones
            past 27 frames and 179 past 10 (Harris: 25, 175); the camera-alone
            map never started.
        follow_min_score: smallest ZNCC accepted when following.
        follow_min_margin: the best ZNCC must beat every other peak of the
            window (more than 2 px away) by this much (repeated texture).
        max_unmapped_age: frames a track may stay unmapped before it is dropped.
        max_hamming: largest Hamming distance (bits of 256) of an ORB match.
        patch_update: ``"anchor"`` (patch from the frame the track was born)
            or ``"last"`` (re-cut at every match).
        sigma_px: pixel standard deviation reported with the observations.
    """

    SECTION: ClassVar[str] = "tracker"
    GATES: ClassVar[tuple[Gate, ...]] = (
        Gate(
            ("max_hamming",),
            'the descriptor search (search = "descriptor", or "auto" with detector = "orb")',
            lambda c: c.search_mode == "descriptor",
        ),
        Gate(
            ("follow_min_score", "follow_min_margin"),
            "a ZNCC follow (a search other than the descriptor one, or follow_by_patch)",
            lambda c: c.search_mode != "descriptor" or c.follow_by_patch is not False,
        ),
        Gate(
            ("follow_by_patch",),
            'the descriptor search (search = "descriptor", or "auto" with detector = "orb")',
            lambda c: c.search_mode == "descriptor",
        ),
    )

    detector: DetectorName = "harris"
    search: SearchMode = "auto"
    max_tracks: int = bounded(80, min=1, max=MAX_POINTS_PER_FRAME)
    max_new_per_frame: int = bounded(20, min=0, max=MAX_POINTS_PER_FRAME)
    # beyond any image's diagonal it blocks every corner; 1e200 overflowed its square
    min_distance_px: float = bounded(16.0, min=0.0, max=2.0 * MAX_SIDE_PX)
    follow_unmapped: bool | None = None
    follow_window_px: int = bounded(24, min=1, max=MAX_SIDE_PX)
    follow_image_motion: bool | None = None
    follow_missed_landmarks: bool | None = None
    fill_first_frame: bool | None = None
    follow_recuts_patch: bool | None = None
    follow_by_patch: bool | None = None
    follow_min_score: float = bounded(0.85, min=-1.0, max=1.0)
    # ZNCC scores lie in [-1, 1]: two differ by 2 at most
    follow_min_margin: float = bounded(0.05, min=0.0, max=2.0)
    max_unmapped_age: int = bounded(60, min=1)
    # a Hamming distance between 256-bit descriptors
    max_hamming: int = bounded(64, min=0, max=256)
    patch_update: Literal["anchor", "last"] = "anchor"
    sigma_px: float = bounded(1.0, gt=0.0)

    def __post_init__(self):
        super().__post_init__()
        mode = self.search_mode
        if (mode == "descriptor") != (self.detector == "orb"):
            raise ConfigError(
                f"tracker.search {mode!r} does not fit detector {self.detector!r} "
                "(descriptor matching needs ORB, ORB needs descriptor matching)"
            )

    @property
    def search_mode(self) -> str:
        return AUTO_SEARCH[self.detector] if self.search == "auto" else self.search


def mark_unread_detector_sections(config: ConfigFile | None, detector: str) -> None:
    """Tell ``config`` which of its detector sections ``detector`` leaves unread, for the
    warning at the command's end (eleventh hostile pass: ``[orb]`` under Harris ran
    silently)."""
    if config is None:
        return
    if detector != "orb":
        config.mark_inert("orb", None, f'[tracker] detector = "orb" (this one is "{detector}")')
    if detector == "orb":
        config.mark_inert("harris", None, '[tracker] detector = "harris" or "fpga" (this one is "orb")')
    elif detector == "fpga":  # the stream is always fixed point: no float unit in the hardware
        config.mark_inert(
            "harris", ["arithmetic"], '[tracker] detector = "harris" (the FPGA stream is fixed point)'
        )


def search_matcher(config: TrackerConfig) -> Literal["zncc", "nearest"]:
    """The active search's matcher under the tracker's search mode (the descriptor search
    correlates the patches it follows: zncc)."""
    return "nearest" if config.search_mode == "nearest" else "zncc"


def search_mode_conflict(config: TrackerConfig, search: ActiveSearchConfig) -> str | None:
    """Why ``[active_search] mode`` contradicts the tracker's search, or None: the tracker
    decides the mode, so a different one set there would do nothing."""
    if search.mode is None or search.mode == search_matcher(config):
        return None
    return (
        f"active_search.mode = {search.mode!r}: the tracker's search ({config.search_mode!r}, "
        "[tracker] search) decides the mode here; set that instead"
    )


#: ``[active_search]`` keys only the ZNCC matcher reads (``frontend.search_matchers``)
ZNCC_SEARCH_KEYS = ("min_score", "subpixel", "predict_appearance")


def mark_unread_search_settings(config: ConfigFile | None, search_mode: str, follow_by_patch: bool) -> None:
    """Tell ``config`` which ``[active_search]`` keys the tracker's search mode leaves
    unread (hostile pass 14: ``min_score = 0.99`` under the FPGA's nearest-point search
    ran the same bits, silent), and, for ORB, the ZNCC follow's keys when its tracks are
    followed by descriptor (``follow_by_patch`` as the tracker resolved it: off with
    odometry). Only a patch follow tests a patch's flatness."""
    if config is None or search_mode == "zncc":
        return
    by_descriptor = search_mode == "descriptor" and not follow_by_patch
    keys = ZNCC_SEARCH_KEYS + (("min_patch_std",) if by_descriptor else ())
    config.mark_inert(
        "active_search",
        keys,
        f'the ZNCC search ([tracker] search = "zncc", the Harris default; this one is "{search_mode}")',
    )
    if by_descriptor:
        config.mark_inert(
            "tracker",
            ("follow_min_score", "follow_min_margin"),
            "a ZNCC follow (Harris, the FPGA stream, or ORB with follow_by_patch, on without odometry)",
        )


def make_detector(config: TrackerConfig, harris: HarrisConfig | None = None, orb: OrbConfig | None = None):
    """The detector named by ``config.detector`` (imports are lazy)."""
    if config.detector == "harris":
        from frontend.harris import HarrisDetector

        return HarrisDetector(harris or HarrisConfig())
    if config.detector == "orb":
        from frontend.orb import OrbDetector

        return OrbDetector(orb or OrbConfig())
    from frontend.fpga_stream import FpgaHarrisStream

    # the stream is always fixed point: the hardware has no float unit
    base = harris or HarrisConfig()
    return FpgaHarrisStream(dataclasses.replace(base, arithmetic="fixed"))
