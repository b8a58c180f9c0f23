"""``graphslam localize``: a sequence placed frame by frame in a fixed map, scored, written.

:func:`run` feeds every frame to a :class:`~graphslam.pipelines.localize.Localizer`
(Ctrl-C honoured between frames, as in the visual run); :func:`compute_metrics`
scores it; :func:`write_outputs` writes ``localize.csv``, ``trajectory.tum``
(placed frames only), ``ground_truth.tum`` (the same frames, when there is
truth) and ``metrics.json``.

Metrics: ``frames``; ``localised_fraction`` (tracked or relocalised over
frames); ``tracked``; ``relocalisations`` (frames placed by place recognition,
the first one included); ``lost_frames``; and with ground truth, over the
placed frames, in the map's frame without any alignment (the map was built in
the truth's frame, so an error is an error): ``ate_rmse_m``,
``error_median_m``, ``error_max_m`` and ``frames_over_0_5m`` (placed frames
more than 0.5 m from the truth).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from graphslam.outputs.writers import OutputWrites
from graphslam.pipelines.common import FrameUnreadable, interrupt_between_frames, progress_bar, signal_hook
from graphslam.pipelines.localize import Localizer, Placement
from slamcore.errors import InputError

if TYPE_CHECKING:
    from graphslam.sources.spatial.sequence import ImageSequence

#: A placed frame farther than this from the truth is counted (issue 18's bound), metres.
FAR_M = 0.5
#: The truth is doubted to be in the map's frame when a rigid fit of the placements to it
#: divides their error by more than this (and takes off more than :data:`FAR_M`): placements
#: right in the map's frame gain only their noise's share from a fit of six numbers (KITTI 07
#: frames 40-159 with a truth restarted at the identity: 62 m unaligned, 0.19 m fitted).
FRAME_DOUBT_RATIO = 5.0

#: ``on_frame(i, image, placement)`` after each frame.
LocalizeHook = Callable[[int, np.ndarray, Placement], None]


@dataclass
class LocalizeResult:
    """Placements of every processed frame of ``sequence``."""

    sequence: ImageSequence
    placements: list[Placement] = field(default_factory=list)
    wall_s: float = 0.0
    load_s: float = 0.0
    interrupted: bool = False

    @property
    def frame_index(self) -> np.ndarray:
        """(N,) original frame index of each processed frame (``--frames`` aware)."""
        from graphslam.sources.spatial.frames import source_indices

        return source_indices(self.sequence)[: len(self.placements)]

    def placed(self) -> np.ndarray:
        return np.array([p.wTc is not None for p in self.placements], dtype=bool)


def run(
    sequence,
    localizer: Localizer,
    *,
    progress: bool = False,
    on_frame: LocalizeHook | None = None,
    max_frames: int | None = None,
) -> LocalizeResult:
    """Place every frame of ``sequence`` in ``localizer``'s map. A frame that cannot be
    read after others were placed raises :class:`FrameUnreadable` holding those."""
    n = len(sequence) if max_frames is None else min(max_frames, len(sequence))
    result = LocalizeResult(sequence)
    unreadable: InputError | None = None
    bar = progress_bar(n, sequence.name, "localize", progress)
    try:
        with interrupt_between_frames() as stop:
            for i in range(n):
                if stop.requested:  # SIGINT/SIGTERM: keep the frames placed so far
                    result.interrupted = True
                    break
                t = time.perf_counter()
                try:
                    image = sequence.load(i)
                except InputError as e:
                    if not result.placements:
                        raise
                    unreadable = e
                    result.interrupted = True
                    break
                t1 = time.perf_counter()
                placement = localizer.locate(image)
                result.wall_s += time.perf_counter() - t1
                result.load_s += t1 - t
                result.placements.append(placement)
                if on_frame is not None:
                    on_frame(i, image, placement)
                if bar is not None:
                    bar.update(1)
                signal_hook("step", i)
    except KeyboardInterrupt:
        if not result.placements:
            raise
        result.interrupted = True
    finally:
        if bar is not None:
            bar.close()
    if unreadable is not None:
        raise FrameUnreadable(unreadable, result)
    return result


def errors_m(result: LocalizeResult) -> np.ndarray | None:
    """(N,) distance of each frame's placed camera centre to the truth (NaN when lost)."""
    truth = getattr(result.sequence, "wTc_true", None)
    if truth is None:
        return None
    out = np.full(len(result.placements), np.nan)
    for i, p in enumerate(result.placements):
        if p.wTc is not None:
            out[i] = float(np.linalg.norm(p.wTc[:3, 3] - np.asarray(truth[i])[:3, 3]))
    return out


def compute_metrics(result: LocalizeResult, map_info: dict, wall_s: float | None = None) -> dict:
    """The ``metrics.json`` of a localisation run (module docstring)."""
    status = [p.status for p in result.placements]
    n = len(status)
    placed = result.placed()
    whole = result.wall_s + result.load_s if wall_s is None else wall_s
    m: dict[str, object] = {
        "dataset": result.sequence.name,
        "source": result.sequence.source_path,
        "map": map_info,
        "frames": n,
        "localised_fraction": float(placed.mean()) if n else 0.0,
        "tracked": status.count("tracked"),
        "relocalisations": status.count("relocalised"),
        "lost_frames": status.count("lost"),
        "ate_rmse_m": None,
        "wall_s": whole,
        "processing_s": result.wall_s,
        "image_load_s": result.load_s,
        "frames_per_s": n / whole if whole > 0 else None,
        "interrupted": result.interrupted,
    }
    if result.sequence.warnings:  # the reader's doubts about the images
        m["warnings"] = list(result.sequence.warnings)
    metric = map_info.get("metric", True)
    err = errors_m(result) if metric else sim3_errors_m(result)
    if err is not None and placed.any():
        e = err[placed]
        m.update(
            ate_rmse_m=float(np.sqrt(np.mean(e**2))),
            error_median_m=float(np.median(e)),
            error_max_m=float(np.max(e)),
            frames_over_0_5m=int(np.sum(e > FAR_M)),
            ate_alignment="none (map frame)" if metric else "sim3 (a camera-alone map has no metric scale)",
        )
    if metric and err is not None and m["ate_rmse_m"] is not None:
        doubt = _frame_doubt(result, float(cast(float, m["ate_rmse_m"])))
        if doubt is not None:
            m["ate_rmse_se3_m"] = doubt[0]
            m["warnings"] = [*cast("list[str]", m.get("warnings", [])), doubt[1]]
    if not metric:  # tenth hostile pass: map units were scored as metres, unaligned
        m["warnings"] = [
            *cast("list[str]", m.get("warnings", [])),
            "the map was built from the camera alone: its unit is its first baseline, not a metre; "
            + (
                "the placements are scored after a Sim(3) fit to the truth"
                if m["ate_rmse_m"] is not None
                else "the placements' positions are in that unit"
            ),
        ]
    return m


def _frame_doubt(result: LocalizeResult, ate_m: float) -> tuple[float, str] | None:
    """``(SE(3)-fitted RMSE, warning)`` when a rigid fit of the placed camera centres to the
    truth takes their error down by :data:`FRAME_DOUBT_RATIO` (the truth recorded in another
    frame than the map's: a second recording's poses starting at the identity), else None."""
    fitted_err = fitted_errors_m(result, with_scale=False)
    if fitted_err is None:
        return None
    fitted = float(np.sqrt(np.nanmean(fitted_err**2)))
    if not (ate_m > FRAME_DOUBT_RATIO * fitted and ate_m - fitted > FAR_M):
        return None
    return fitted, (
        f"is the truth in the map's frame? a rigid fit of the placements to it takes their error "
        f"from {ate_m:.3g} m to {fitted:.3g} m: the placements agree with it in shape, not in "
        "place (a truth recorded in another frame, e.g. a second recording's poses starting at "
        "the identity, scores the frames' offset, not the localisation)"
    )


def sim3_errors_m(result: LocalizeResult) -> np.ndarray | None:
    """:func:`errors_m` after the Sim(3) fit of the placed camera centres to the truth (a map
    without metric scale: :func:`graphslam.evaluation.spatial.align_umeyama`); None without
    truth or with fewer than 3 placed frames (a scale needs them)."""
    return fitted_errors_m(result, with_scale=True)


def fitted_errors_m(result: LocalizeResult, with_scale: bool) -> np.ndarray | None:
    """:func:`errors_m` after the Sim(3) (``with_scale``) or SE(3) fit of the placed camera
    centres to the truth; None without truth or with fewer than 3 placed frames."""
    from graphslam.evaluation.spatial import align_umeyama

    truth = getattr(result.sequence, "wTc_true", None)
    placed = result.placed()
    if truth is None or placed.sum() < 3:
        return None
    est = np.array([p.wTc[:3, 3] for p in result.placements if p.wTc is not None])
    ref = np.asarray(truth)[: len(result.placements)][placed][:, :3, 3]
    s, R, t = align_umeyama(est, ref, with_scale=with_scale)
    out = np.full(len(result.placements), np.nan)
    out[placed] = np.linalg.norm(est * s @ R.T + t - ref, axis=1)
    return out


def write_outputs(
    result: LocalizeResult, out_dir: Path, metrics: dict, writes: OutputWrites | None = None
) -> dict[str, Path]:
    """``localize.csv``, ``trajectory.tum``, ``ground_truth.tum`` (with truth),
    ``metrics.json``; the paths written. ``writes``: as
    :func:`graphslam.pipelines.spatial.write_outputs` takes it."""
    from graphslam.outputs import writers
    from graphslam.outputs.localize import write_localize_csv

    writes, own = writers.writes_for(out_dir, writes)
    seq = result.sequence
    n = len(result.placements)
    stamps = result.frame_index.astype(float) if seq.stamps_s is None else np.asarray(seq.stamps_s, float)[:n]
    placed = result.placed()
    paths: dict[str, Path] = {}
    writes(
        paths,
        "localize",
        out_dir / "localize.csv",
        write_localize_csv,
        result.frame_index,
        stamps,
        [p.status for p in result.placements],
        [p.wTc for p in result.placements],
        [p.covariance for p in result.placements],
    )
    wTc = np.array([p.wTc for p in result.placements if p.wTc is not None]).reshape(-1, 4, 4)
    writes(paths, "trajectory", out_dir / "trajectory.tum", writers.write_tum_spatial, stamps[placed], wTc)
    if seq.wTc_true is not None:
        truth = np.asarray(seq.wTc_true)[:n][placed]
        writes(
            paths,
            "ground_truth",
            out_dir / "ground_truth.tum",
            writers.write_tum_spatial,
            stamps[placed],
            truth,
        )
    writes(paths, "metrics", out_dir / "metrics.json", writers.write_json, metrics)
    if own:
        writes.check(paths.values())
    return paths
