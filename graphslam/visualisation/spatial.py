"""Rerun logging of visual runs (images, search ellipses, frusta, 3-D map); imports rerun.

Layout of a recording, on the ``frame`` timeline (and ``time`` in seconds
where the sequence has stamps):

- ``world/ground_truth/trajectory``: static, when known;
  ``world/ground_truth/camera``: the true pose's frustum (Transform3D + Pinhole);
- ``world/<backend>/camera``: the estimated current pose's frustum; under it
  ``image`` (the frame, JPEG), ``image/corners`` (detected corners),
  ``image/grid`` (the detector's tessellation), ``image/ellipses`` (active
  search ellipses at the gate: green where found, red where not),
  ``image/matches`` (predicted -> found), ``image/followed`` (unmapped tracks
  followed: previous -> current) and ``image/new`` (tracks started);
- ``world/<backend>/trajectory`` and ``world/<backend>/landmarks`` (3-D map)
  and the estimated frusta, logged at the end of the run onto the frames they
  belong to (the final, smoothed estimate: see :meth:`VisualRecorder.hook`);
  ``world/odometry/trajectory`` at the last frame;
- ``plots/tracking/{found,searched,observations,image_fraction}``;
- with loop closing: ``loops/candidates`` (a text line per candidate: scores,
  inliers, accepted or why not), ``loops/pair`` (query and match images side
  by side, the PnP inliers joined by lines, for candidates that passed the
  detector's geometry), ``plots/loops/{score,normalised_score}``, and
  ``world/<backend>/loop_closures`` (the closures as 3-D segments between the
  estimated cameras, at the end of the run).

Modes save / spawn / connect as :class:`graphslam.visualisation.recording.RerunLog`.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from graphslam.visualisation.recording import GT_COLOR, PALETTE, RerunLog, ellipse_points
from slamcore.errors import GraphSlamError

if TYPE_CHECKING:
    from graphslam.sources.spatial.sequence import ImageSequence

FOUND_COLOR = (40, 200, 60)
MISSED_COLOR = (220, 50, 40)
CORNER_COLOR = (255, 200, 0)
NEW_COLOR = (0, 170, 255)
FOLLOW_COLOR = (200, 80, 255)
GRID_COLOR = (90, 90, 90, 120)


def world_up(wTc0: np.ndarray | None) -> str:
    """The ``rr.ViewCoordinates`` name of the world of a sequence whose first camera pose
    is ``wTc0`` (None: the world is the first camera's frame, as a run from the camera
    alone makes it), on the premise that the first camera is held upright: its image's
    down (the camera's +y) points down in the world, and the world axis nearest to it
    is the viewer's "down". KITTI's world is its first camera's frame (y down, z
    forward): declared z-up, the viewer drew the car climbing (twelfth hostile pass).
    The synthetic room's world is z-up."""
    down = np.array([0.0, 1.0, 0.0]) if wTc0 is None else np.asarray(wTc0, float)[:3, :3] @ [0.0, 1.0, 0.0]
    axis = int(np.argmax(np.abs(down)))
    name = "XYZ"[axis]
    return f"RIGHT_HAND_{name}_{'DOWN' if down[axis] > 0 else 'UP'}"


class VisualRecorder:
    """Records one visual run. ``open(mode, path, url)``, ``start``, ``hook``, ``finish``, ``close``.

    Args:
        log: the :class:`RerunLog` to write to.
        image_every: log the image every N frames (overlays every frame).
        jpeg_quality: JPEG quality of the logged images (0 logs raw pixels).
    """

    def __init__(self, log: RerunLog, image_every: int = 1, jpeg_quality: int = 85):
        self.log = log
        self.rec = log.rec
        self._rr = log._rr
        self.image_every = max(1, int(image_every))
        self.jpeg_quality = int(jpeg_quality)
        self._sequence: ImageSequence | None = None

    @classmethod
    def open(cls, mode: str, path: Path | None, url: str | None = None, **kw) -> VisualRecorder:
        return cls(RerunLog(mode, path=path, url=url, recording_id="graphslam-visual-run"), **kw)

    # ------------------------------------------------------------------ static

    def start(self, sequence, n_frames: int) -> None:
        """Static ground truth, if the sequence has it."""
        rr = self._rr
        self._sequence = sequence
        first = None if sequence.wTc_true is None or not len(sequence.wTc_true) else sequence.wTc_true[0]
        self.rec.log("world", getattr(rr.ViewCoordinates, world_up(first)), static=True)
        if sequence.wTc_true is not None:
            p = np.asarray(sequence.wTc_true[:n_frames])[:, :3, 3]
            self.rec.log(
                "world/ground_truth/trajectory",
                rr.LineStrips3D([p], colors=[GT_COLOR], radii=0.01),
                static=True,
            )

    def _started(self) -> ImageSequence:
        """The sequence :meth:`start` was given (it comes before any frame)."""
        if self._sequence is None:
            raise GraphSlamError("VisualRecorder: start() must come before the frames")
        return self._sequence

    def _file_frame(self, k: int) -> int:
        """Frame ``k`` of the run as the files number it (``--frames 10:40``: frame 10 is
        the run's first; localize.csv and the summaries say so too)."""
        indices = getattr(self._sequence, "indices", None)
        return int(indices[k]) if indices is not None and 0 <= k < len(indices) else int(k)

    def _set_time(self, k: int) -> None:
        self.rec.set_time("frame", sequence=self._file_frame(k))
        stamps = None if self._sequence is None else self._sequence.stamps_s
        if stamps is not None:
            self.rec.set_time("time", duration=float(stamps[k]))

    def _camera(self, entity: str, wTc: np.ndarray, K: np.ndarray, size, color) -> None:
        rr = self._rr
        self.rec.log(entity, rr.Transform3D(translation=wTc[:3, 3], mat3x3=wTc[:3, :3]))
        self.rec.log(
            entity,
            rr.Pinhole(
                image_from_camera=K,
                resolution=[int(size[0]), int(size[1])],
                image_plane_distance=0.3,
                color=color,
            ),
        )

    # ------------------------------------------------------------------ per frame

    def log_frame(
        self, backend: str, k: int, image: np.ndarray, tracking, wTc: np.ndarray | None, color_index: int = 0
    ) -> None:
        """One frame: frusta, image with its overlays, tracking plots."""
        rr = self._rr
        seq = self._started()
        self._set_time(k)
        K = np.asarray(seq.K, dtype=np.float64)
        size = seq.image_size
        color = PALETTE[color_index % len(PALETTE)]
        if seq.wTc_true is not None:
            self._camera("world/ground_truth/camera", np.asarray(seq.wTc_true[k]), K, size, GT_COLOR)
        cam = f"world/{backend}/camera"
        if wTc is not None:
            self._camera(cam, wTc, K, size, color)
        img = f"{cam}/image"
        if k % self.image_every == 0:
            im = rr.Image(image)
            self.rec.log(img, im.compress(jpeg_quality=self.jpeg_quality) if self.jpeg_quality else im)
        if k == 0 and tracking.cell_size_px:
            self.rec.log(
                f"{img}/grid",
                rr.LineStrips2D(grid_lines(size, tracking.cell_size_px), colors=[GRID_COLOR], radii=0.5),
                static=True,
            )
        self.rec.log(f"{img}/corners", rr.Points2D(tracking.corners, colors=[CORNER_COLOR], radii=2.0))
        s = tracking.searched
        if s.any():
            rings = ellipse_points(tracking.pred_uv[s], tracking.pred_S[s], chi2=tracking.gate)
            cols = np.where(tracking.found[s][:, None], FOUND_COLOR, MISSED_COLOR)
            labels = [str(int(i)) for i in tracking.pred_ids[s]]
            self.rec.log(
                f"{img}/ellipses",
                rr.LineStrips2D(list(rings), colors=cols, radii=0.7, labels=labels, show_labels=False),
            )
        else:
            self.rec.log(f"{img}/ellipses", rr.Clear(recursive=False))
        f = tracking.found
        if f.any():
            segs = np.stack([tracking.pred_uv[f], tracking.found_uv[f]], axis=1)
            self.rec.log(f"{img}/matches", rr.LineStrips2D(list(segs), colors=[FOUND_COLOR], radii=0.8))
        else:
            self.rec.log(f"{img}/matches", rr.Clear(recursive=False))
        if len(tracking.followed_ids):
            segs = np.stack([tracking.followed_from, tracking.followed_to], axis=1)
            self.rec.log(f"{img}/followed", rr.LineStrips2D(list(segs), colors=[FOLLOW_COLOR], radii=0.6))
        else:
            self.rec.log(f"{img}/followed", rr.Clear(recursive=False))
        self.rec.log(f"{img}/new", rr.Points2D(tracking.new_uv, colors=[NEW_COLOR], radii=3.0))
        self.rec.log("plots/tracking/found", rr.Scalars(float(tracking.n_found)))
        self.rec.log("plots/tracking/searched", rr.Scalars(float(tracking.n_searched)))
        self.rec.log("plots/tracking/observations", rr.Scalars(float(len(tracking.observations))))
        self.rec.log("plots/tracking/image_fraction", rr.Scalars(float(tracking.image_fraction)))

    def log_estimate(self, backend: str, estimate, color_index: int = 0) -> None:
        """Estimated trajectory and 3-D map points."""
        rr = self._rr
        color = PALETTE[color_index % len(PALETTE)]
        wTc = np.asarray(estimate.wTc).reshape(-1, 4, 4)
        if len(wTc) >= 2:
            self.rec.log(
                f"world/{backend}/trajectory", rr.LineStrips3D([wTc[:, :3, 3]], colors=[color], radii=0.01)
            )
        pts = np.asarray(estimate.landmarks_w).reshape(-1, 3)
        self.rec.log(
            f"world/{backend}/landmarks",
            rr.Points3D(
                pts,
                colors=[color],
                radii=0.03,
                labels=[str(int(i)) for i in estimate.landmark_ids],
                show_labels=False,
            ),
        )

    def hook(self, backend: str, color_index: int = 0):
        """An ``on_frame`` callback for :func:`graphslam.pipelines.spatial.run`.

        It logs the front end only and never asks the back end for its
        estimate: reading it may change the back end's work (iSAM2 flushes its
        pending factors), and a run must give the same numbers with or without
        a recording. The estimated frusta and map come in :meth:`finish`.
        """

        def on_frame(k, image, tracking, backend_obj):
            self.log_frame(backend, k, image, tracking, None, color_index)

        return on_frame

    def finish(self, backend: str, result, color_index: int = 0, every: int = 5) -> None:
        """The estimate, placed on the timeline: each frame's estimated frustum at
        its own frame, the trajectory so far every ``every`` frames, the final
        map and the odometry-only trajectory at the last frame."""
        rr = self._rr
        est = result.estimate
        seq = self._started()
        K = np.asarray(seq.K, dtype=np.float64)
        color = PALETTE[color_index % len(PALETTE)]
        wTc = np.asarray(est.wTc).reshape(-1, 4, 4)
        ids = np.asarray(est.frame_ids, dtype=np.int64)
        for j, (k, T) in enumerate(zip(ids, wTc, strict=True)):
            self._set_time(int(k))
            self._camera(f"world/{backend}/camera", T, K, seq.image_size, color)
            if j % max(1, int(every)) == 0 and j >= 1:
                self.rec.log(
                    f"world/{backend}/trajectory",
                    rr.LineStrips3D([wTc[: j + 1, :3, 3]], colors=[color], radii=0.01),
                )
        self._set_time(max(result.frames - 1, 0))
        self.log_estimate(backend, est, color_index)
        if result.odometry_wTc is not None and len(result.odometry_wTc) >= 2:
            self.rec.log(
                "world/odometry/trajectory",
                rr.LineStrips3D([result.odometry_wTc[:, :3, 3]], colors=[(255, 127, 14)], radii=0.01),
            )

    def record_comparison(self, entries, sequence, should_stop=None) -> bool:
        """Finished image-sequence runs (``CompareEntry``), one entity subtree per back
        end, on the frame timeline; True when ``should_stop()`` (asked before each back
        end) cut it, what was logged before kept."""
        self.start(sequence, max(e.result.frames for e in entries))
        for i, e in enumerate(entries):
            if should_stop is not None and should_stop():
                return True
            self.finish(e.backend, e.result, color_index=i)
        return False

    def loop_hook(self, sequence):
        """An ``on_candidate`` callback for :class:`graphslam.pipelines.loop_closing.VisualLoopCloser`."""

        def on_candidate(k, record, image, links):
            self.log_loop_candidate(k, record, image, links, sequence)

        return on_candidate

    def log_loop_candidate(self, k: int, record, image: np.ndarray, links, sequence) -> None:
        """One :class:`~graphslam.pipelines.loop_closing.LoopCandidate` on the timeline;
        both images side by side when it got a pose."""
        rr = self._rr
        self._set_time(k)
        det = record.detector
        fate = "ACCEPTED" if record.accepted else f"rejected: {record.reason}"
        match = record.match
        text = (
            f"query {k} match {match if match is not None else det.best_match} "
            f"score {det.score:.3f} eta {det.normalised_score or 0.0:.2f} "
            f"inliers {det.n_inliers} pnp {None if record.pnp is None else record.pnp.n_inliers}"
            f": {fate}"
        )
        level = "INFO" if record.accepted else "DEBUG"
        self.rec.log("loops/candidates", rr.TextLog(text, level=level))
        self.rec.log("plots/loops/score", rr.Scalars(float(det.score or 0.0)))
        if det.normalised_score is not None:
            self.rec.log("plots/loops/normalised_score", rr.Scalars(float(det.normalised_score)))
        if links is None or match is None:
            return
        other = sequence.load(int(match))
        W = image.shape[1]
        pair = np.hstack([image, other])
        im = rr.Image(pair)
        self.rec.log("loops/pair", im.compress(jpeg_quality=self.jpeg_quality) if self.jpeg_quality else im)
        segs = np.asarray(links, dtype=np.float64).reshape(-1, 2, 2).copy()
        segs[:, 1, 0] += W
        color = FOUND_COLOR if record.accepted else MISSED_COLOR
        self.rec.log("loops/pair/inliers", rr.LineStrips2D(list(segs), colors=[color], radii=0.8))

    def log_loop_closures(self, backend: str, estimate, closures, color=(255, 0, 255)) -> None:
        """Accepted closures as 3-D segments between the estimated camera centres."""
        rr = self._rr
        ids = {int(f): i for i, f in enumerate(np.asarray(estimate.frame_ids))}
        wTc = np.asarray(estimate.wTc).reshape(-1, 4, 4)
        segs = [
            np.stack([wTc[ids[c.frame_a], :3, 3], wTc[ids[c.frame_b], :3, 3]])
            for c in closures
            if c.frame_a in ids and c.frame_b in ids
        ]
        if segs:
            self.rec.log(f"world/{backend}/loop_closures", rr.LineStrips3D(segs, colors=[color], radii=0.01))

    def relocate(self, folder: Path) -> None:
        """The output folder moved during the run: the recording is finished there."""
        self.log.relocate(folder)

    def close(self) -> None:
        self.log.close()

    def discard(self) -> None:
        """Stop recording and delete what was recorded (:meth:`RerunLog.discard`)."""
        self.log.discard()

    def drop_disk_copy(self) -> bool:
        """A viewer stream's copy on disk deleted, the viewer still fed
        (:meth:`RerunLog.drop_disk_copy`)."""
        return self.log.drop_disk_copy()


def grid_lines(size, cell: int) -> list[np.ndarray]:
    """Tessellation cell borders of a ``(W, H)`` image as 2-point line strips."""
    W, H = int(size[0]), int(size[1])
    lines = [np.array([[x - 0.5, -0.5], [x - 0.5, H - 0.5]]) for x in range(cell, W, cell)]
    lines += [np.array([[-0.5, y - 0.5], [W - 0.5, y - 0.5]]) for y in range(cell, H, cell)]
    return lines


#: Pose-graph recordings: odometry chain, closures kept, closures rejected.
ODOMETRY_COLOR = PALETTE[0]
KEPT_CLOSURE_COLOR = (44, 160, 44, 110)
REJECTED_CLOSURE_COLOR = (214, 39, 40)


def log_pose_graph(
    log: RerunLog, graph, params: np.ndarray, rejected: np.ndarray, root: str = "world/posegraph"
) -> None:
    """The optimised pose graph (2-D views for 2-D graphs, 3-D otherwise):
    ``ROOT/{odometry,closures_kept,closures_rejected}``; rejected
    closures are drawn in red over the kept (translucent green) ones."""
    import rerun as rr

    from slamcore.posegraph import params_to_matrix

    T = params_to_matrix(params, graph.rotation)
    xyz = T[:, : graph.dim, -1]
    rows = graph.index_of(graph.edges.ravel()).reshape(-1, 2)
    odometry = graph.odometry_mask()
    strips = rr.LineStrips2D if graph.dim == 2 else rr.LineStrips3D
    parts = {
        "odometry": (odometry, ODOMETRY_COLOR, 0.02),
        "closures_kept": (~odometry & ~rejected, KEPT_CLOSURE_COLOR, 0.01),
        "closures_rejected": (~odometry & rejected, REJECTED_CLOSURE_COLOR, 0.03),
    }
    for name, (mask, color, radius) in parts.items():
        segments = np.stack([xyz[rows[mask, 0]], xyz[rows[mask, 1]]], axis=1)
        log.rec.log(f"{root}/{name}", strips(segments, colors=[color], radii=radius), static=True)


MAP_COLOR = (150, 150, 150)
STATUS_COLORS = {"tracked": FOUND_COLOR, "relocalised": NEW_COLOR}


class LocalizeRecorder(VisualRecorder):
    """Records ``graphslam localize``: the prior map in grey (static: its landmarks and
    keyframe path), and per frame the live camera over it (green when tracked, blue when
    relocalised, nothing when lost), the image with the inlier pixels, the path so far,
    the status as a text line and ``plots/localize/inliers``."""

    def start_map(self, smap, sequence, n_frames: int) -> None:
        rr = self._rr
        self.start(sequence, n_frames)
        self.rec.log(
            "world/map/landmarks", rr.Points3D(smap.landmark_w, colors=[MAP_COLOR], radii=0.02), static=True
        )
        self.rec.log(
            "world/map/keyframes",
            rr.LineStrips3D([smap.keyframe_wTc[:, :3, 3]], colors=[MAP_COLOR], radii=0.005),
            static=True,
        )
        self._path: list[np.ndarray] = []

    def log_placement(self, i: int, image: np.ndarray, placement) -> None:
        rr = self._rr
        seq = self._started()
        self._set_time(i)
        K = np.asarray(seq.K, dtype=np.float64)
        if seq.wTc_true is not None:
            self._camera(
                "world/ground_truth/camera", np.asarray(seq.wTc_true[i]), K, seq.image_size, GT_COLOR
            )
        self.rec.log(
            "localize/status",
            rr.TextLog(
                f"frame {self._file_frame(i)}: {placement.status}, {placement.inliers} inliers",
                level="WARN" if placement.status == "lost" else "INFO",
            ),
        )
        self.rec.log("plots/localize/inliers", rr.Scalars(float(placement.inliers)))
        cam = "world/localize/camera"
        if placement.wTc is None:
            self.rec.log(cam, rr.Clear(recursive=True))
            return
        color = STATUS_COLORS[placement.status]
        self._camera(cam, placement.wTc, K, seq.image_size, color)
        if i % self.image_every == 0:
            im = rr.Image(image)
            self.rec.log(
                f"{cam}/image", im.compress(jpeg_quality=self.jpeg_quality) if self.jpeg_quality else im
            )
        self.rec.log(f"{cam}/image/inliers", rr.Points2D(placement.uv_px, colors=[color], radii=3.0))
        self._path.append(placement.wTc[:3, 3])
        # the whole path each frame would make the recording quadratic in its length
        if len(self._path) >= 2 and i % self.image_every == 0:
            self.rec.log(
                "world/localize/trajectory",
                rr.LineStrips3D([np.array(self._path)], colors=[PALETTE[0]], radii=0.01),
            )
