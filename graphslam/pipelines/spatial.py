"""Run a 3-D visual back end over an image sequence with the front-end tracker.

Per frame ``k``::

    k == 0:  backend.initialize(0, wTc0, P0, K, image_size)
    k >= 1:  backend.predict(k, odometry_k, covariance_k)   # c_{k-1} T c_k, or None
             predictions = backend.predict_observations()
    tracking = tracker.track(image_k, predictions)           # active search + new tracks
    backend.update(tracking.observations)

With ``[active_search] order = "sequential"`` the tracker also gets
``backend.correct_and_repredict``: each match corrects the back end during the
search (RT-SLAM), and ``update`` adds the rest (map management, new landmarks).
A back end without that ability (visual iSAM2) is refused with a ConfigError.

``wTc0`` is the first ground-truth pose when the sequence has one (so the
estimate is in the ground truth's frame), else the identity.

Odometry (``VisualRunConfig.odometry``):

* ``"sequence"``: the sequence's own noisy odometry (synthetic sequences);
* ``"derived"``: for sequences with ground truth but no odometry (KITTI 07):
  the true relative pose ``c_{k-1} T c_k`` times ``E = [[exp(phi), rho], [0, 1]]``
  with ``rho ~ N(0, sigma_t^2 I3)``, ``sigma_t = max(sigma_t_per_m * d_k,
  min_sigma_t_m)`` (``d_k`` the true distance travelled in the frame) and
  ``phi ~ N(0, sigma_r^2 I3)``, ``sigma_r = sigma_r_deg`` per frame, drawn
  from ``default_rng(seed)``; the covariance handed to the back end is that
  ``diag(sigma_t^2 I3, sigma_r^2 I3)``. Defaults: 2 % of the distance and
  0.1 deg per frame (:class:`OdometryNoiseConfig`); the metrics state them;
* ``"none"``: the back end's own motion model (constant velocity); only for
  back ends with ``has_motion_model``. Such a monocular run has no metric
  scale: its ATE is Sim(3)-aligned.
* ``"auto"``: ``"sequence"`` when the sequence has odometry (the synthetic one, a bag's
  odometry topic), else ``"none"``: the camera alone. Odometry is never derived from
  ground truth unless asked for: no user's camera has it, and a default that used
  the truth the run is scored against would report the truth's own noise as the
  run's accuracy.

Ctrl-C and SIGTERM are honoured between frames (as in :mod:`graphslam.pipelines.planar`); the
result then holds what was estimated so far with ``interrupted=True``. A frame that
cannot be read after the first raises :class:`~graphslam.pipelines.common.FrameUnreadable`
carrying such a result.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np

from frontend.tracking import Tracker, TrackingResult
from graphslam import registry
from graphslam.backend_table import load
from graphslam.evaluation.records import SpatialRunMetrics
from graphslam.outputs.writers import OutputWrites
from graphslam.pipelines.common import (
    ODOMETRY_MODES,
    BackendFailed,
    FrameUnreadable,
    OdometryMode,
    interrupt_between_frames,
    progress_bar,
    signal_hook,
    stop_requested,
)
from graphslam.sources.spatial.sequence import ImageSequence
from slamcore.config import Validated, bounded
from slamcore.errors import ConfigError, GraphSlamError, InputError, LocatedError, UnsupportedError
from slamcore.spatial.backend import VisualBackend
from slamcore.spatial.geometry import invert_pose, so3_exp
from slamcore.spatial.records import PixelPredictions, VisualEstimate

#: ``on_frame(k, image, tracking, backend)``, called after each frame's update.
FrameHook = Callable[[int, np.ndarray, TrackingResult, VisualBackend], None]


@dataclass(frozen=True)
class OdometryNoiseConfig(Validated):
    """Noise of derived odometry (config section ``[odometry_noise]``).

    Attributes:
        sigma_t_per_m: translation standard deviation per axis, per metre
            travelled in the frame (0.02 = 2 % of the distance).
        min_sigma_t_m: floor of the translation sigma (a still camera is not
            known to the micrometre), metres.
        sigma_r_deg: rotation standard deviation per axis and per frame, degrees.
        seed: seed of the noise draws.
    """

    SECTION: ClassVar[str] = "odometry_noise"

    # the floor and the rotation sigma must be > 0: a zero covariance cannot weigh a factor;
    # above: 100 times the distance, a kilometre, half a turn a frame are no odometry
    # (1e308 drew an infinite rotation, a traceback in the exponential map)
    sigma_t_per_m: float = bounded(0.02, min=0.0, max=100.0)
    min_sigma_t_m: float = bounded(0.001, gt=0.0, max=1000.0)
    sigma_r_deg: float = bounded(0.1, gt=0.0, max=180.0)
    seed: int = bounded(0, min=0)


@dataclass(frozen=True)
class VisualRunConfig(Validated):
    """Visual run settings (config section ``[visual]``).

    Attributes:
        odometry: ``"auto"``, ``"sequence"``, ``"derived"`` or ``"none"`` (module doc).
        prior_sigma_t_m, prior_sigma_r_deg: standard deviations of the first pose.
    """

    SECTION: ClassVar[str] = "visual"

    odometry: OdometryMode = "auto"
    # The first pose is the world frame (nothing a camera measures is absolute), so its
    # prior only fixes the gauge: a weak one buys nothing and leaves iSAM2's system
    # indeterminate (synthetic images: at 10 m from the camera alone, at 360 deg; a
    # traceback-free error naming x0 or x1). Bounds with margin below what failed.
    prior_sigma_t_m: float = bounded(0.001, gt=0.0, max=1.0)
    prior_sigma_r_deg: float = bounded(0.01, gt=0.0, max=90.0)


@dataclass
class VisualRunResult:
    """What one visual run produced.

    Attributes:
        estimate: final estimate (``finalize``'d unless interrupted).
        frames: frames processed.
        interrupted: a stop was asked for (or a frame was unreadable) during the run.
        finalised: every frame was processed and the back end finished
            (``finalize``): the estimate is whole even if ``interrupted`` (a stop
            asked for during the final polish).
        wall_s: seconds in the tracker, the back end and the loop closer
            (detection, search, update, finalisation); image loading and logging
            are not counted (``processing_s`` of the metrics).
        load_s: seconds spent reading (or rendering) the images.
        odometry: the odometry mode used (``"sequence"``, ``"derived"``, ``"none"``).
        odometry_noise: the stated noise of derived odometry, else None.
        odometry_wTc: (frames, 4, 4) odometry-only trajectory from the first
            pose, or None without odometry.
        tracking: per-frame front-end counters (lists).
        pose_covariances: (frames, 6, 6) ``[rho, phi]`` covariances of
            ``estimate.wTc`` (``graphslam compare`` fills it), else None.
        backend_seed: the back end's own seed (its RANSAC draws), None if it has none.
        input_digest: SHA-256 of what the back end was fed (images, detected
            corners, odometry), filled by ``graphslam compare``, else None.
        config_notes: the config's notes of the run, :meth:`slamcore.config.ConfigFile.notes`
            (``graphslam compare`` fills it, in a worker process too: the sections no run
            read, the settings none of those reading them used), else None.
        unreadable: the error line of the frame that could not be read and ended the run
            early (``graphslam compare`` keeps the estimate of the frames before it).
    """

    sequence: ImageSequence
    backend: str
    frontend: str
    estimate: VisualEstimate
    frames: int
    wall_s: float
    load_s: float
    interrupted: bool
    odometry: str
    odometry_noise: dict | None
    odometry_wTc: np.ndarray | None
    tracking: dict = field(default_factory=dict)
    pose_covariances: np.ndarray | None = None
    input_digest: str | None = None
    finalised: bool = False
    backend_seed: int | None = None
    config_notes: tuple | None = None
    unreadable: str | None = None


def backend_overrides(
    backend: str,
    mode: str,
    seed: int | None = None,
    no_polish: bool = False,
    nearest_depth_m: float | None = None,
) -> dict:
    """Config overrides a visual run hands back end ``backend`` for odometry ``mode``,
    the seed, ``--no-polish`` and the scene's nearest depth
    (:func:`scene_nearest_depth`): each back end's own ``run_overrides`` (the
    back-end table's), which knows what its settings make of them."""
    impl = registry.visual_implementation(backend)
    if impl.run_overrides is None:
        return {}
    return load(impl.run_overrides)(mode, seed, no_polish, nearest_depth_m)


def scene_nearest_depth(sequence: ImageSequence, config) -> float | None:
    """The sequence's nearest scene depth (metres) for the EKF's ``min_depth_m``, or None
    when the sequence does not know it or ``[mono_ekf] min_depth_m`` is in the config
    file (the file wins). A prior meant for a nearer scene biases every new
    landmark's first corrections the same way, and the filter becomes
    overconfident (measured in README.md, "compare on image sequences")."""
    # what the file holds, not where: a line scanner misses legal TOML forms
    if config is not None and "min_depth_m" in (config.data.get("mono_ekf") or {}):
        return None
    return sequence.nearest_depth_m


def make_tracker(config, backend: VisualBackend, detector: str | None = None):
    """``(tracker config, tracker)`` from the config file's ``[tracker]``,
    ``[active_search]``, ``[harris]`` and ``[orb]`` with ``detector`` on top;
    unmapped tracks are followed when the back end needs their history, and the
    tracker's camera-alone aids are on when it has no odometry (its own motion
    model: the predictions are a guess; unless the file sets them)."""
    from frontend.active_search_config import ActiveSearchConfig
    from frontend.harris import HarrisConfig
    from frontend.orb import OrbConfig
    from frontend.tracking_config import (
        TrackerConfig,
        mark_unread_detector_sections,
        mark_unread_search_settings,
        search_mode_conflict,
    )

    cfg = config.section(TrackerConfig, {"detector": detector})
    mark_unread_detector_sections(config, cfg.detector)
    search = config.section(ActiveSearchConfig)
    # the two settings the tracker and the back end decide, refused with their file line
    why = search_mode_conflict(cfg, search)
    if why:
        raise ConfigError(why, config.path, config.line_of("active_search", "mode"))
    if search.order == "sequential" and not backend.supports_sequential_search:
        raise ConfigError(_sequential_refusal(backend), config.path, config.line_of("active_search", "order"))
    follow = backend.needs_track_history if cfg.follow_unmapped is None else cfg.follow_unmapped
    if not follow:  # hostile pass 17: set under the EKF, they ran the same bits, unsaid
        config.mark_inert(
            "tracker",
            ("follow_window_px", "follow_min_score", "follow_min_margin", "max_unmapped_age"),
            "following unmapped tracks (follow_unmapped; by default on for iSAM2, off for the EKF)",
        )
    tracker = Tracker(
        cfg,
        active_search=search,
        harris=config.section(HarrisConfig),
        orb=config.section(OrbConfig),
        follow_unmapped=follow,
        camera_alone=backend.has_motion_model,
    )
    mark_unread_search_settings(config, cfg.search_mode, tracker.follow_by_patch)
    return cfg, tracker


def derive_odometry(
    wTc_true: np.ndarray, config: OdometryNoiseConfig | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Noisy odometry from ground truth: ``(odometry (N-1, 4, 4), covariances (N-1, 6, 6))``.

    ``odometry[k] = c_k T c_{k+1} @ E`` (module docstring), seeded by ``config.seed``.
    """
    cfg = config or OdometryNoiseConfig()
    wTc = np.asarray(wTc_true, dtype=np.float64).reshape(-1, 4, 4)
    rng = np.random.default_rng(cfg.seed)
    n = len(wTc) - 1
    odo = np.empty((max(n, 0), 4, 4))
    cov = np.empty((max(n, 0), 6, 6))
    sigma_r = math.radians(cfg.sigma_r_deg)
    for k in range(n):
        rel = invert_pose(wTc[k]) @ wTc[k + 1]
        sigma_t = max(cfg.sigma_t_per_m * float(np.linalg.norm(rel[:3, 3])), cfg.min_sigma_t_m)
        E = np.eye(4)
        E[:3, 3] = rng.normal(0.0, sigma_t, 3)
        E[:3, :3] = so3_exp(rng.normal(0.0, sigma_r, 3))
        odo[k] = rel @ E
        cov[k] = np.diag([sigma_t**2] * 3 + [sigma_r**2] * 3)
    return odo, cov


def chain(wTc0: np.ndarray, odometry: np.ndarray) -> np.ndarray:
    """(N+1, 4, 4) poses from ``wTc0`` composed with (N, 4, 4) relative poses."""
    out = np.empty((len(odometry) + 1, 4, 4))
    out[0] = wTc0
    for k, T in enumerate(odometry):
        out[k + 1] = out[k] @ T
    return out


def resolve_odometry(sequence: ImageSequence, mode: str, noise: OdometryNoiseConfig | None = None):
    """``(mode, odometry (N-1, 4, 4) or None, covariances (N-1, 6, 6) or None, stated noise)``."""
    # only some sequences (synthetic, a bag's, a frame selection of those) carry odometry
    own = getattr(sequence, "odometry", None)
    if mode == "auto":  # odometry from truth is a test of the back end, never a default
        mode = "sequence" if own is not None else "none"
    if mode == "sequence":
        if own is None:
            # a bag's odometry topic that was read and left out says why, not "none of its own"
            unused = getattr(sequence, "odometry_unused", None)
            raise GraphSlamError(
                f"sequence {sequence.name!r} has no odometry of its own"
                + ("" if unused is None else f" (odometry topic {unused})")
                + "; use --odometry derived (needs ground truth) or none"
            )
        odo = np.asarray(own, dtype=np.float64)
        own_cov = getattr(sequence, "odometry_covariance")  # noqa: B009 (not on ImageSequence)
        cov = np.broadcast_to(np.asarray(own_cov, dtype=np.float64), (len(odo), 6, 6))
        st, sr = getattr(sequence, "odometry_sigmas", (None, None))
        stated = (
            None
            if st is None or sr is None
            else {"kind": "sequence", "sigma_t_m_per_frame": st, "sigma_r_deg_per_frame": math.degrees(sr)}
        )
        return mode, odo, cov, stated
    if mode == "derived":
        if sequence.wTc_true is None:
            raise GraphSlamError(
                f"sequence {sequence.name!r} has no ground truth to derive odometry from; use --odometry none"
            )
        cfg = noise or OdometryNoiseConfig()
        odo, cov = derive_odometry(sequence.wTc_true, cfg)
        stated = {
            "kind": "derived from ground truth",
            "sigma_t_per_m": cfg.sigma_t_per_m,
            "min_sigma_t_m": cfg.min_sigma_t_m,
            "sigma_r_deg_per_frame": cfg.sigma_r_deg,
            "seed": cfg.seed,
        }
        return mode, odo, cov, stated
    if mode == "none":
        return mode, None, None, None
    raise ConfigError(f"odometry must be one of {', '.join(ODOMETRY_MODES)}, got {mode!r}")


def run(
    sequence: ImageSequence,
    backend: VisualBackend,
    tracker: Tracker,
    *,
    config: VisualRunConfig | None = None,
    odometry_noise: OdometryNoiseConfig | None = None,
    max_frames: int | None = None,
    progress: bool = False,
    on_frame: FrameHook | None = None,
    frontend: str | None = None,
    loop_closer=None,
    start_pose=None,
) -> VisualRunResult:
    """Run ``backend`` over ``sequence`` with ``tracker`` (module docstring).

    ``loop_closer``: a :class:`graphslam.pipelines.loop_closing.VisualLoopCloser`, fed every
    frame after the back end's update (its time counts in ``wall_s`` and in
    ``stats["loops_s"]``); None runs without place recognition.
    ``start_pose``: ``(wTc0, P0)`` of the first frame (``run --map``: relocalised), or None.
    """

    cfg = config or VisualRunConfig()
    n = len(sequence) if max_frames is None else min(int(max_frames), len(sequence))
    if n < 1:
        raise GraphSlamError(f"sequence {sequence.name!r} has no frames")
    mode, odo, odo_cov, stated = resolve_odometry(sequence, cfg.odometry, odometry_noise)
    if mode == "none" and not backend.has_motion_model:
        raise UnsupportedError(
            f"back end {backend.name!r} has no motion model of its own; use --odometry sequence or derived"
        )
    repredict = _sequential_link(tracker, backend)
    wTc0, P0 = _first_pose(sequence, cfg) if start_pose is None else start_pose
    K = np.asarray(sequence.K, dtype=np.float64)
    start = (wTc0, P0, K, (sequence.image_size[0], sequence.image_size[1]))
    odo_model = (odo, odo_cov, repredict)
    stats: dict[str, list] = {name: [] for name in TRACKING_STATS}
    bar = progress_bar(n, sequence.name, backend.name, progress)
    done = 0
    wall = 0.0
    load = 0.0
    interrupted = False
    finalised = False
    unreadable: InputError | None = None  # the frame that cut the run, read after others
    failed: GraphSlamError | None = None  # the back end's failure after some frames
    try:
        with interrupt_between_frames() as stop:
            for k in range(n):
                stop.check()
                t = time.perf_counter()
                try:
                    image = sequence.load(k)
                except InputError as e:
                    if done == 0:
                        raise
                    unreadable = e
                    break
                t1 = time.perf_counter()
                load += t1 - t
                try:
                    tracking, (t2, t3, t4) = _step(backend, tracker, loop_closer, k, image, start, odo_model)
                except GraphSlamError as e:
                    if done == 0:
                        raise
                    failed = e
                    break
                wall += t4 - t1
                done = k + 1
                _count(stats, tracking, t3 - t2)
                stats["loops_s"].append(t4 - t3)
                if on_frame is not None:
                    on_frame(k, image, tracking, backend)
                if bar is not None:
                    bar.update(1)
                signal_hook("step", k)
            signal_hook("finalize")
        if unreadable is None and failed is None:
            t = time.perf_counter()
            estimate = _finalize(backend, sequence)
            wall += time.perf_counter() - t
            interrupted = stop.requested  # asked during finalisation: the estimate is whole
            finalised = True
        else:  # cut as a stop cuts it: the estimate so far, not finalised
            interrupted = True
            estimate = _estimate_so_far(backend, failed)
    except KeyboardInterrupt:
        interrupted = True
        if done == 0:
            raise
        estimate = backend.estimate()
    finally:
        if bar is not None:
            bar.close()
    odo_wTc = None if odo is None else chain(wTc0, odo[: done - 1])
    result = VisualRunResult(
        sequence=sequence,
        backend=backend.name,
        frontend=frontend or tracker.config.detector,
        estimate=estimate,
        frames=done,
        wall_s=wall,
        load_s=load,
        interrupted=interrupted,
        odometry=mode,
        odometry_noise=stated,
        odometry_wTc=odo_wTc,
        tracking=stats,
        finalised=finalised,
        backend_seed=getattr(getattr(backend, "config", None), "seed", None),
    )
    if unreadable is not None:
        raise FrameUnreadable(unreadable, result)
    if failed is not None:
        raise BackendFailed(failed, result, done)
    return result


def _step(backend, tracker, loop_closer, k: int, image, start, odo_model):
    """Frame ``k`` through the back end: its prediction, the front end's search, the
    update, then the loop closer. ``start``: ``(wTc0, P0, K, (W, H))`` of the first
    frame; ``odo_model``: ``(odometry, its covariances, repredict)``. Returns
    ``(tracking, (time after the search, after the update, after the loop closer))``."""
    wTc0, P0, K, size = start
    odo, odo_cov, repredict = odo_model
    if k == 0:
        backend.initialize(0, wTc0, P0, K, size)
        pred = PixelPredictions.empty(wTc0, K)  # no landmark, a known camera
    else:
        backend.predict(k, None if odo is None else odo[k - 1], None if odo_cov is None else odo_cov[k - 1])
        pred = backend.predict_observations()
    tracking = _track(tracker, image, pred, repredict if k else None)
    t2 = time.perf_counter()
    backend.update(tracking.observations)
    t3 = time.perf_counter()
    if loop_closer is not None:
        loop_closer.process(k, image, tracking, backend)
    return tracking, (t2, t3, time.perf_counter())


def _estimate_so_far(backend, failed: GraphSlamError | None):
    """The back end's estimate of the frames done; after its own failure, that failure
    again if it cannot give one (nothing then to write)."""
    try:
        return backend.estimate()
    except Exception:  # a back end broken by its failure (gtsam's IndexError): none to write
        if failed is None:
            raise
        raise failed from None


#: Per-frame lists in ``VisualRunResult.tracking``.
TRACKING_STATS = (
    "corners",
    "observations",
    "found",
    "searched",
    "predicted",
    "followed",
    "new",
    "image_fraction",
    "detect_s",
    "search_s",
    "update_s",
    "loops_s",
)


def _sequential_link(tracker: Tracker, backend: VisualBackend):
    """``backend.correct_and_repredict`` for the sequential active search, else None;
    ConfigError if the order is sequential and the back end cannot correct one at a time."""
    if tracker.search_config.order != "sequential":
        return None
    if not backend.supports_sequential_search:
        raise ConfigError(_sequential_refusal(backend))
    return backend.correct_and_repredict


def _sequential_refusal(backend: VisualBackend) -> str:
    return (
        f"active_search.order = 'sequential' needs a back end that corrects one "
        f"landmark at a time (mono_ekf); {backend.name!r} does not"
    )


def _track(tracker: Tracker, image: np.ndarray, pred: PixelPredictions, repredict) -> TrackingResult:
    """``tracker.track``; the batch order calls it as it always has (wrappers keep working)."""
    return (
        tracker.track(image, pred) if repredict is None else tracker.track(image, pred, repredict=repredict)
    )


def _first_pose(sequence: ImageSequence, cfg: VisualRunConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(wTc0 (4, 4), P0 (6, 6))``: the true first pose (else identity) and the prior."""
    wTc0 = np.eye(4) if sequence.wTc_true is None else np.asarray(sequence.wTc_true[0], dtype=np.float64)
    P0 = np.diag([cfg.prior_sigma_t_m**2] * 3 + [math.radians(cfg.prior_sigma_r_deg) ** 2] * 3)
    return wTc0, P0


def _count(stats: dict, tr: TrackingResult, update_s: float) -> None:
    stats["corners"].append(len(tr.corners))
    stats["observations"].append(len(tr.observations))
    stats["found"].append(tr.n_found)
    stats["searched"].append(tr.n_searched)
    stats["predicted"].append(len(tr.pred_ids))
    stats["followed"].append(len(tr.followed_ids))
    stats["new"].append(len(tr.new_ids))
    stats["image_fraction"].append(tr.image_fraction)
    stats["detect_s"].append(tr.timings_s.get("detect", 0.0))
    stats["search_s"].append(tr.timings_s.get("search", 0.0) + tr.timings_s.get("follow", 0.0))
    stats["update_s"].append(update_s)


# --------------------------------------------------------------------------- metrics


def compute_metrics(
    result: VisualRunResult, *, seed: int | None = None, wall_s: float | None = None
) -> SpatialRunMetrics:
    """The metrics of ``metrics.json`` for one visual run.

    The ATE alignment is SE(3) when the run had odometry (metric scale), Sim(3)
    when it had none (monocular: scale unobservable); ``alignment`` says which.
    ``wall_s``: the whole run's time (loading the sequence and its images,
    tracking, the back end, scoring), seconds; ``frames_per_s`` is taken over
    it. Without it, the time of tracking and the back end (``processing_s``)
    plus image loading (``image_load_s``) stands in.
    """
    est = result.estimate
    seq = result.sequence
    n = result.frames
    whole_s = result.wall_s + result.load_s if wall_s is None else wall_s
    m = SpatialRunMetrics(
        dataset=seq.name,
        source=seq.source_path,
        backend=result.backend,
        frontend=result.frontend,
        seed=seed,
        backend_seed=result.backend_seed,
        frames=n,
        landmarks=int(len(est.landmark_ids)),
        odometry=result.odometry,
        odometry_noise=result.odometry_noise,
        alignment="sim3" if result.odometry == "none" else "se3",
        ate_rmse_m=None,
        ate_percent_of_path=None,
        odometry_ate_rmse_m=None,
        odometry_ate_percent_of_path=None,
        rpe=None,
        path_length_m=None,
        wall_s=whole_s,
        frames_per_s=n / whole_s if whole_s > 0 else None,
        processing_s=result.wall_s,
        image_load_s=result.load_s,
        interrupted=result.interrupted,
        backend_stats=_with_file_frames(est.stats, seq),
        tracking=_tracking_summary(result.tracking),
    )
    m.frames_with_pose = int(len(est.frame_ids))
    m.warnings = [*seq.warnings, *truth_speed_doubt(seq), *_doubts(result)] or None
    m.dataset_notes = list(getattr(seq, "notes", ())) or None
    if seq.wTc_true is not None and n >= 2 and len(est.frame_ids) >= 2:
        _score_against_truth(m, result)
        if m.ate_percent_of_path is not None and m.ate_percent_of_path > DIVERGED_ATE_PERCENT:
            m.warnings = (m.warnings or []) + [
                f"ATE {m.ate_percent_of_path:.1f} % of the path (> {DIVERGED_ATE_PERCENT:g} %): "
                + (_inverted_truth(result, m) or "the estimate has most likely diverged")
            ]
    return m


#: Mean speed of a ground truth over its frames' time span beyond which it is not a
#: vehicle's, m/s: road cars top out near 70 m/s (KITTI's car below 25, a drone of EuRoC
#: below 3), so a truth past 100 m/s is in another unit (millimetres read as metres made
#: KITTI's 10 m/s car 3.5 km/s, hostile pass 15), and the odometry derived from it and the
#: scores against it carry that unit.
TRUTH_SPEED_MAX_MPS = 100.0


def truth_speed_doubt(seq) -> list[str]:
    """One line when the sequence's truth moves faster on average than
    :data:`TRUTH_SPEED_MAX_MPS` between its first and last stamps, else none (no truth,
    no stamps, or no time between them)."""
    truth, stamps = seq.wTc_true, seq.stamps_s
    if truth is None or stamps is None or len(truth) < 2 or len(stamps) != len(truth):
        return []
    span = float(stamps[-1] - stamps[0])
    if not span > 0:
        return []
    p = np.asarray(truth, dtype=np.float64)[:, :3, 3]
    path = float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))
    speed = path / span
    if not speed > TRUTH_SPEED_MAX_MPS:  # NaN: the reader refuses non-finite truth
        return []
    return [
        f"the ground truth travels {path:.6g} m in {span:.3g} s ({speed:.3g} m/s), beyond any "
        f"vehicle's {TRUTH_SPEED_MAX_MPS:g} m/s: is it in millimetres or centimetres? (the odometry "
        "derived from it and the scores against it are in its unit)"
    ]


#: ATE above this share of the path length, percent, is reported as a divergence: monocular
#: visual odometry on the KITTI benchmark drifts 1-3 % of the distance travelled, and an
#: ATE (an RMS over the whole path) stays below the end-point drift.
DIVERGED_ATE_PERCENT = 5.0


#: Landmarks that must be found in a frame for it to measure the camera: a pose has
#: six degrees of freedom and a pixel gives two, and three points leave up to four
#: poses (P3P); the fourth point picks one.
MIN_LANDMARKS_PER_FRAME = 4


def _finalize(backend, sequence):
    """``backend.finalize()``; an error that names no file (the camera-alone map never
    started) is said of the images it was given."""
    try:
        return backend.finalize()
    except LocatedError:
        raise
    except GraphSlamError as e:
        # a camera-alone map that never started on large images: the pixel settings
        # (pass 23: KITTI upscaled 2x was told "more frames, or odometry")
        hint = _large_image_hint(int(getattr(sequence, "image_size", (0, 0))[0]))
        if sequence.source_path is None:
            if hint:
                raise GraphSlamError(str(e) + hint) from None
            raise
        raise InputError(str(e) + hint, sequence.source_path) from None


def _with_file_frames(stats: dict | None, seq) -> dict:
    """The back end's stats, with the camera-alone first map's frame also as the file's
    frame number (``file_frame``): under ``--frames 100:`` the run's frame 5 is file
    frame 105, and a user reads the file's."""
    out = dict(stats or {})
    mono = out.get("camera_alone")
    first = None if mono is None else mono.get("first_map")
    if mono is not None and first is not None:
        from graphslam.sources.spatial.frames import source_indices

        file_frame = int(source_indices(seq)[int(first["frame"])])
        out["camera_alone"] = {**mono, "first_map": {**first, "file_frame": file_frame}}
    return out


#: Image width (pixels) past which the tracker's pixel-sized windows are small for the
#: motion: its defaults were measured on 640-1241 px images (the synthetic room, KITTI).
LARGE_IMAGE_WIDTH_PX = 2000


def _large_image_hint(width: int) -> str:
    """What to try when the images are large (thirteenth hostile pass: KITTI upscaled 3x,
    3678 px wide, mapped nothing with either front end; it maps at 1x and 2x). The
    settings in pixels were measured on smaller images; which of them fails depends on
    the camera (an upscaled image localises corners to ~3 px, a sharp one to ~1 px but
    moves 3x farther a frame), so the hint names them and the tested route. ``width``:
    the images', pixels."""
    if width <= LARGE_IMAGE_WIDTH_PX:
        return ""
    return (
        f"; the front end's settings in pixels ([tracker] sigma_px and follow_window_px, "
        f"[active_search] patch_size_px) were measured on images up to {LARGE_IMAGE_WIDTH_PX} "
        f"px wide, these are {width}: images resized under that width are the tested route"
    )


def _image_size(result: VisualRunResult) -> tuple[int, int]:
    """(width, height) of the run's images, (0, 0) when its sequence does not say."""
    width, height = getattr(getattr(result, "sequence", None), "image_size", (0, 0))
    return int(width), int(height)


def _no_corner_hint(result: VisualRunResult) -> str:
    """What to look at when the detector found no corner in any frame (hostile pass 14:
    ``[harris] border_px = 200`` on 370-row images, or a threshold above any response,
    was said as "0 corners matched")."""
    width, height = _image_size(result)
    return (
        f"; the detector found no corner in {width}x{height} images: look at [harris] threshold "
        "and border_px (Harris and FPGA; a border of half the image or more leaves no pixel) "
        "or [orb] (ORB)"
    )


#: Consecutive frames the camera-alone motion model may bridge without a doubt said: one
#: weak frame (a turn's end; the synthetic room's two coasted frames are single ones).
BRIDGED_FRAMES = 1


def _loss_doubts(losses: list[dict], files: np.ndarray | None = None) -> list[str]:
    """A doubt for the camera-alone tracking losses longer than :data:`BRIDGED_FRAMES`:
    their poses are the constant-velocity guess, and landmarks mapped from them may hold
    another scale (thirteenth hostile pass: a cut to another place 55 m away was bridged
    as 0.65 m of motion, and a blurred stretch came back at 1.8x the scale, with nothing
    said but "found again by PnP" in metrics.json). ``files``: (N,) each run frame's
    index in the files (:func:`~graphslam.sources.spatial.frames.source_indices`), said
    beside the run's where ``--frames`` moved them (pass 23: "frames 13-17" were the
    run's, the trajectory's times the files')."""
    long = [x for x in losses if int(x.get("frames", 0)) > BRIDGED_FRAMES]
    if not long:
        return []

    def span(x: dict) -> str:
        a, b = int(x["frame"]), int(x["frame"]) + int(x["frames"]) - 1
        if files is None or (files[a] == a and files[b] == b):
            return f"{a}-{b}"
        return f"{a}-{b} of the run, file frames {int(files[a])}-{int(files[b])}"

    spans = ", ".join(span(x) for x in long[:5])
    more = f" and {len(long) - 5} more" if len(long) > 5 else ""
    return [
        f"tracking was lost {len(long)} time(s) for more than {BRIDGED_FRAMES} frame (frames {spans}{more}): "
        "the poses there are the motion model's guess, and what was mapped after a loss may hold "
        "another scale than the map before it (a cut to another place is bridged as motion)"
    ]


def _doubts(result: VisualRunResult) -> list[str]:
    """One line per reason to doubt the estimate: frames left without a pose, a run with
    odometry whose images gave no landmark or never found one again (the odometry alone),
    and a camera-alone run lost for stretches or mostly not measured (the motion model's
    guess)."""
    out = []
    n, n_pose = result.frames, len(result.estimate.frame_ids)
    if 0 < n_pose < n:
        out.append(
            f"{n - n_pose} of {n} frames have no pose (before the monocular map "
            f"started, or not placed by it); the scores are over the other {n_pose}"
        )
    if n < 2:
        return out
    if result.odometry != "none":
        out += _rejected_triangulations(result)
        if len(result.estimate.landmark_ids) > 0:
            return out + _never_found_again(result)
        corners = int(np.sum(result.tracking.get("corners", [])))
        return out + [
            f"no landmark entered the map in {n} frames ({corners} corners detected, "
            f"{sum(result.tracking.get('observations', []))} matched in all): the trajectory is the "
            "odometry alone, the images corrected nothing"
            + (_no_corner_hint(result) if corners == 0 else _large_image_hint(_image_size(result)[0]))
        ]
    mono = (result.estimate.stats or {}).get("camera_alone")
    if mono is not None:
        from graphslam.sources.spatial.frames import source_indices

        files = None if result.sequence is None else source_indices(result.sequence)
        out += _loss_doubts(mono.get("losses") or [], files)
        unmeasured = int(mono.get("coasted_frames", 0))
        what = "PnP could not measure the pose"
    else:
        found = np.asarray(result.tracking.get("found", [])[1:])
        unmeasured = int(np.count_nonzero(found < MIN_LANDMARKS_PER_FRAME))
        what = f"fewer than {MIN_LANDMARKS_PER_FRAME} landmarks were found"
    if unmeasured > 0.5 * max(n_pose - 1, 1):
        out.append(
            f"in {unmeasured} of {n - 1} frames {what}: the trajectory is mostly the "
            "motion model's guess, not a measurement"
        )
    return out


#: Share of the tracks triangulated against the odometry's poses that may fail
#: (behind a camera, or reprojected beyond the limit) before the run says so: past half,
#: the images disagree with the poses more often than they agree, so the map and its
#: corrections rest on the few that pass. Measured on KITTI 07 with its own truth: 3 of
#: 157 (frames 0:60), 21 of 563 (0:160); with a truth in the body-frame convention, of
#: another stretch or in reverse: 353 of 358, 382 of 400, 267 of 306 (hostile pass 15).
REJECTED_TRIANGULATION_SHARE_MAX = 0.5


def _rejected_triangulations(result: VisualRunResult) -> list[str]:
    """One line when more than :data:`REJECTED_TRIANGULATION_SHARE_MAX` of the tracks
    the back end triangulated were rejected (back ends that count them), else none."""
    stats = result.estimate.stats or {}
    rejected = stats.get("rejected_triangulations")
    if rejected is None:
        return []
    tried = (
        int(rejected)
        + len(result.estimate.landmark_ids)
        + int(stats.get("landmarks_dropped_indeterminate", 0))
    )
    if rejected <= REJECTED_TRIANGULATION_SHARE_MAX * tried:
        return []
    source = (
        "is the ground truth the odometry comes from this sequence's, camera-to-world, in time order?"
        if result.odometry == "derived"
        else "is the odometry in the camera's frame and this sequence's?"
    )
    return [
        f"{rejected} of {tried} tracks ({100 * rejected / tried:.0f} %) failed triangulation against "
        "the odometry's poses (behind a camera or reprojected too far): the images disagree with "
        f"the poses, so the map rests on the few that passed and the trajectory on the odometry ({source})"
    ]


def _never_found_again(result: VisualRunResult) -> list[str]:
    """The doubt of a run with odometry whose landmarks were never found again in a later
    frame (a search gate or score no match passes): each landmark was seen once, so the
    images corrected nothing (hostile pass 14: ``gate_probability = 0.01`` gave the
    odometry to the last digit, silent)."""
    tr = result.tracking
    searched = int(np.sum(tr.get("searched", [])[1:]))
    again = int(np.sum(tr.get("found", [])[1:])) + int(np.sum(tr.get("followed", [])[1:]))
    if again > 0 or searched == 0:
        return []
    return [
        f"no landmark was found again in {result.frames - 1} frames ({searched} searches): the "
        "images corrected nothing, the trajectory is the odometry alone (the search's "
        "settings: [active_search] gate_probability, min_score, max_half_extent_px; "
        "[tracker] sigma_px)"
    ]


#: The truth read inverted explains a divergence when it scores the estimate within
#: :data:`DIVERGED_ATE_PERCENT` of its path (no divergence) and at most this share of
#: the ATE against the truth as given.
INVERTED_TRUTH_ATE_SHARE = 0.5


def _inverted_truth(result: VisualRunResult, m: SpatialRunMetrics) -> str:
    """The sentence for a truth of world-to-camera poses read as camera-to-world (a
    ``--ground-truth`` file of the other convention), when its inverse explains the
    divergence (:data:`INVERTED_TRUTH_ATE_SHARE`), else ''."""
    from graphslam.evaluation import spatial as metrics3d

    est, n, truth = result.estimate, result.frames, result.sequence.wTc_true
    if truth is None or m.ate_rmse_m is None:
        return ""
    gt = invert_pose(np.asarray(truth[:n], dtype=np.float64))
    try:
        a = metrics3d.ate(est.frame_ids, est.wTc, np.arange(n, dtype=np.int64), gt, alignment=m.alignment)
    except GraphSlamError:
        return ""
    pct = metrics3d.percent_of(a["rmse_m"], metrics3d.path_length(gt))
    if pct is None or not (
        pct <= DIVERGED_ATE_PERCENT and a["rmse_m"] <= INVERTED_TRUTH_ATE_SHARE * m.ate_rmse_m
    ):
        return ""
    return (
        f"against the truth's poses inverted it is {pct:.2f} %: the truth holds world-to-camera "
        "poses read as camera-to-world (invert the --ground-truth file)"
    )


#: Median angle between the estimate's and the truth's direction of travel in the camera's
#: axes (:func:`graphslam.evaluation.spatial.travel_direction_error`) beyond which the
#: reconstruction is wrong, degrees. Sound runs err by about a degree (KITTI 07 camera
#: alone, frames 0-159: median 0.5; 119 down to 99: 0.9); the road driven backwards in
#: hostile pass 20 gave 53 with a Sim(3) ATE of 0.04 m.
TRAVEL_DIRECTION_MAX_DEG = 20.0


def _score_against_truth(m: SpatialRunMetrics, result: VisualRunResult) -> None:
    """ATE, RPE and path length of the estimate and of the odometry, into ``m``."""
    from graphslam.evaluation import spatial as metrics3d

    est, n = result.estimate, result.frames
    truth = result.sequence.wTc_true
    if truth is None:  # scored only where the sequence has ground truth
        raise GraphSlamError(f"sequence {result.sequence.name!r}: no ground truth to score against")
    gt_ids = np.arange(n, dtype=np.int64)
    gt = np.asarray(truth[:n])
    # the path the scored poses travelled: a monocular run that started its map at
    # frame 103 of 160 is scored over frames 103-159, and a percentage of the whole
    # route made its error look three times smaller
    scored = np.isin(gt_ids, est.frame_ids)
    length = metrics3d.path_length(gt[scored]) if scored.sum() >= 2 else metrics3d.path_length(gt)
    m.path_length_m = length
    try:
        a = metrics3d.ate(est.frame_ids, est.wTc, gt_ids, gt, alignment=m.alignment)
    except GraphSlamError as e:  # e.g. a Sim(3) fit to an estimate that never moved
        m.ate_error = str(e)
        # said where the "n/a" is read, not only in metrics.json (hostile pass 17)
        m.warnings = [*(m.warnings or []), f"ATE not scored: {e}"]
    else:
        m.ate = a
        m.ate_rmse_m = a["rmse_m"]
        m.ate_percent_of_path = metrics3d.percent_of(a["rmse_m"], length)
        m.rpe = metrics3d.rpe(est.frame_ids, est.wTc, gt_ids, gt, delta=1, scale=a["scale"])
    # steps longer than the position error only: a camera turning in place has no direction
    travel = (
        None
        if m.ate_rmse_m is None
        else metrics3d.travel_direction_error(est.frame_ids, est.wTc, gt_ids, gt, min_step_m=m.ate_rmse_m)
    )
    if travel is not None and travel["median_deg"] > TRAVEL_DIRECTION_MAX_DEG:
        angle, steps = travel["median_deg"], travel["n"]
        m.warnings = [
            *(m.warnings or []),
            f"the estimate's direction of travel, in the camera's own axes, is {angle:.0f} deg from "
            f"the truth's (median over {steps} steps; over {TRAVEL_DIRECTION_MAX_DEG:g} deg): its "
            "orientations do not fit its path, a wrong reconstruction that the fitted ATE does not show",
        ]
    if result.odometry_wTc is not None:
        o = metrics3d.ate(gt_ids, result.odometry_wTc, gt_ids, gt, alignment="se3")
        m.odometry_ate_rmse_m = o["rmse_m"]
        m.odometry_ate_percent_of_path = metrics3d.percent_of(o["rmse_m"], metrics3d.path_length(gt))
        m.odometry_rpe = metrics3d.rpe(gt_ids, result.odometry_wTc, gt_ids, gt, delta=1)


def map_frame_ate(result: VisualRunResult) -> dict | None:
    """ATE of a ``run --map`` estimate with no alignment (``ate``'s record), or None
    without truth: the run starts relocalised in the map, so its poses are in the map's
    frame, the truth's when the map's run started at its truth. An aligned ATE hides
    an offset from the map, which is what ``--map`` is for."""
    from graphslam.evaluation import spatial as metrics3d

    truth, n = result.sequence.wTc_true, result.frames
    if truth is None:
        return None
    est = result.estimate
    try:
        return metrics3d.ate(
            est.frame_ids, est.wTc, np.arange(n, dtype=np.int64), np.asarray(truth[:n]), alignment="none"
        )
    except GraphSlamError:  # fewer than two frames with a pose
        return None


def _tracking_summary(stats: dict) -> dict:
    if not stats or not stats.get("observations"):
        return {}
    mean = {k: float(np.mean(v)) for k, v in stats.items() if v}
    return {
        "corners_per_frame": mean.get("corners", 0.0),
        "observations_per_frame": mean["observations"],
        "predicted_per_frame": mean["predicted"],
        "searched_per_frame": mean["searched"],
        "found_per_frame": mean["found"],
        "followed_per_frame": mean["followed"],
        "new_tracks": int(np.sum(stats["new"])),
        "image_fraction_searched": mean["image_fraction"],
        "detect_ms": 1e3 * mean["detect_s"],
        "search_ms": 1e3 * mean["search_s"],
        "update_ms": 1e3 * mean["update_s"],
        "loops_ms": 1e3 * mean.get("loops_s", 0.0),
    }


# --------------------------------------------------------------------------- outputs


def _frame_times(seq: ImageSequence, frames: np.ndarray) -> np.ndarray:
    """Time column of ``frames`` (positions in ``seq``): their stamps, else their index in
    the sequence as read. A ``--frames`` selection keeps the folder's numbering (as
    ``graphslam localize`` writes it), so its trajectory pairs with a truth of the whole
    folder by time; numbered from 0 it paired frame 6 with the truth of frame 0."""
    if seq.stamps_s is not None:
        return np.asarray(seq.stamps_s, dtype=float)[frames]
    from graphslam.sources.spatial.frames import source_indices

    return source_indices(seq)[frames].astype(float)


def write_outputs(
    result: VisualRunResult, out_dir: Path, run_metrics: SpatialRunMetrics, writes: OutputWrites | None = None
) -> dict[str, Path]:
    """Write ``trajectory.tum``, ``landmarks.csv`` (``id,x,y,z``), ``metrics.json`` and,
    when the sequence has ground truth, ``ground_truth.tum`` of the run's frames
    (same time column as the trajectory); return the paths written.

    ``writes``: the command's :class:`~graphslam.outputs.writers.OutputWrites`, which
    notes a file the file system refuses and goes on (its caller checks it once every
    output was tried); without it, GraphSlamError once all were tried."""
    from graphslam.outputs import writers

    writes, own = writers.writes_for(out_dir, writes)
    est = result.estimate
    ids = np.asarray(est.frame_ids, dtype=np.int64)
    seq = result.sequence
    stamps = _frame_times(seq, ids)
    paths: dict[str, Path] = {}
    writes(paths, "trajectory", out_dir / "trajectory.tum", writers.write_tum_spatial, stamps, est.wTc)
    signal_hook("write")
    if stop_requested():  # asked while the outputs are written: say so in them
        run_metrics.interrupted = True
    if seq.wTc_true is not None and result.frames > 0:
        frames = np.arange(result.frames)
        writes(
            paths,
            "ground_truth",
            out_dir / "ground_truth.tum",
            writers.write_tum_spatial,
            _frame_times(seq, frames),
            np.asarray(seq.wTc_true)[frames],
        )
    landmarks_w = np.asarray(est.landmarks_w).reshape(-1, 3)
    landmarks = (est.landmark_ids, landmarks_w)
    writes(paths, "landmarks", out_dir / "landmarks.csv", writers.write_landmarks_csv, *landmarks)
    writes(paths, "metrics", out_dir / "metrics.json", writers.write_json, run_metrics.to_dict())
    if own:
        writes.check(paths.values())
    return paths
