"""Rerun logging of 2-D runs and comparisons.

Layout of a recording (2-D views, z up is implicit):

- ``world/ground_truth/{trajectory,landmarks}``: static, when known;
- ``world/<backend>/{trajectory,pose,landmarks,landmark_ellipses,pose_ellipse}``
  on the ``step`` timeline (and ``time`` in seconds where the data has stamps);
- ``plots/<backend>/pose_sigma_m``: 1-sigma position uncertainty over time,
  where the loop closure shows as a drop.
- filters (:mod:`.filter_state`): ``filter/<backend>/correlation``, the EKF's
  covariance as an entity-by-entity ``|rho|`` image, with
  ``plots/<backend>/mean_abs_correlation``, every ``every`` steps;
  ``world/<backend>/particles``, FastSLAM's cloud, with ``plots/<backend>/ess``
  (before resampling) and ``plots/<backend>/resampling`` (a text entry per
  resampling), every step.

Ellipses are 95 % confidence regions (chi-square, 2 dof).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from graphslam.visualisation.recording import GT_COLOR, PALETTE, RerunLog, ellipse_points
from slamcore.planar.records import Dataset, Estimate

if TYPE_CHECKING:  # the recording process needs none of the filters filter_state imports
    from graphslam.visualisation.background import BackgroundLog
    from graphslam.visualisation.filter_state import CorrelationSnapshot, FilterStateLogger, ParticleSeries


class PlanarLog(RerunLog):
    """A :class:`RerunLog` with the 2-D entities: ground truth, poses, landmarks."""

    def log_ground_truth(self, wTb: np.ndarray | list | None, landmarks: dict | None) -> None:
        """Static truth: ``wTb`` (N, 3) one strip, or a list of them (one per robot)."""
        rr = self._rr
        strips = [s for s in ([wTb] if isinstance(wTb, np.ndarray) else wTb or []) if len(s)]
        if strips:
            rr_strip = rr.LineStrips2D([s[:, :2] for s in strips], colors=[GT_COLOR], radii=0.05)
            self.rec.log("world/ground_truth/trajectory", rr_strip, static=True)
        if landmarks:
            ids = sorted(landmarks)
            pts = np.array([landmarks[i] for i in ids])
            self.rec.log(
                "world/ground_truth/landmarks",
                rr.Points2D(
                    pts, colors=[GT_COLOR], radii=0.15, labels=[str(i) for i in ids], show_labels=False
                ),
                static=True,
            )

    def log_pose(
        self, backend: str, wTb: np.ndarray, covariance: np.ndarray | None, color_index: int = 0
    ) -> None:
        """Current pose (arrow), its 95 % position ellipse and sigma plot."""
        rr = self._rr
        color = PALETTE[color_index % len(PALETTE)]
        heading = 1.0 * np.array([np.cos(wTb[2]), np.sin(wTb[2])])
        self.rec.log(
            f"world/{backend}/pose", rr.Arrows2D(origins=[wTb[:2]], vectors=[heading], colors=[color])
        )
        self.log_pose_uncertainty(backend, wTb, covariance, color_index)

    def log_pose_uncertainty(
        self, backend: str, wTb: np.ndarray, covariance: np.ndarray | None, color_index: int = 0
    ) -> None:
        """The 95 % position ellipse of the current pose and its sigma plot (at the set step)."""
        if covariance is None:
            return
        rr = self._rr
        color = PALETTE[color_index % len(PALETTE)]
        ring = ellipse_points(wTb[None, :2], covariance[None, :2, :2])[0]
        self.rec.log(f"world/{backend}/pose_ellipse", rr.LineStrips2D([ring], colors=[color]))
        sigma_m = float(np.sqrt(max(np.trace(covariance[:2, :2]), 0.0)))
        self.rec.log(f"plots/{backend}/pose_sigma_m", rr.Scalars(sigma_m))

    def log_pose_columns(
        self, backend: str, steps, stamps_s, wTb: np.ndarray, color_index: int = 0, row_colors=None
    ) -> None:
        """The pose arrows of many steps in one message (Rerun's columnar API): the
        same rows as :meth:`log_pose`'s arrow step by step, at a fraction of the cost
        (a log call is ~0.3 ms, the run's iSAM2 step ~2 ms). ``row_colors``: a palette
        index per row (one colour per robot where a run holds several)."""
        if not len(steps):
            return
        rr = self._rr
        wTb = np.asarray(wTb, dtype=np.float64).reshape(-1, 3)
        palette = np.array(PALETTE, dtype=np.uint8)
        color = (
            np.tile(palette[color_index % len(PALETTE)], (len(wTb), 1))
            if row_colors is None
            else palette[np.asarray(row_colors, dtype=np.int64) % len(PALETTE)]
        )
        indexes = [rr.TimeColumn("step", sequence=np.asarray(steps, dtype=np.int64))]
        if stamps_s is not None:
            indexes.append(rr.TimeColumn("time", duration=np.asarray(stamps_s, dtype=np.float64)))
        heading = np.column_stack([np.cos(wTb[:, 2]), np.sin(wTb[:, 2])])
        self.rec.send_columns(
            f"world/{backend}/pose",
            indexes=indexes,
            columns=rr.Arrows2D.columns(origins=wTb[:, :2], vectors=heading, colors=color),
        )

    def log_estimate(self, backend: str, estimate: Estimate, color_index: int = 0, pose_groups=None) -> None:
        """Trajectory, landmarks and (if present) their 95 % ellipses. ``pose_groups``:
        several robots' poses (index arrays into ``estimate.wTb``), one strip and one
        colour each."""
        rr = self._rr
        color = PALETTE[color_index % len(PALETTE)]
        if pose_groups:
            strips = [estimate.wTb[np.asarray(g, dtype=np.int64), :2] for g in pose_groups]
            colors = [PALETTE[i % len(PALETTE)] for i in range(len(strips))]
        else:
            strips, colors = [estimate.wTb[:, :2]], [color]
        self.rec.log(f"world/{backend}/trajectory", rr.LineStrips2D(strips, colors=colors, radii=0.05))
        if len(estimate.landmark_ids):
            self.rec.log(
                f"world/{backend}/landmarks",
                rr.Points2D(
                    estimate.landmarks_w,
                    colors=[color],
                    radii=0.2,
                    labels=[str(int(i)) for i in estimate.landmark_ids],
                    show_labels=False,
                ),
            )
            if estimate.landmark_covariances is not None:
                rings = ellipse_points(estimate.landmarks_w, estimate.landmark_covariances)
                self.rec.log(
                    f"world/{backend}/landmark_ellipses",
                    rr.LineStrips2D(list(rings), colors=[color], radii=0.02),
                )

    def log_correlation(self, backend: str, snap: CorrelationSnapshot) -> None:
        """The EKF's entity correlation image (viridis in a tensor view) and mean |rho|."""
        rr = self._rr
        self.rec.log(
            f"filter/{backend}/correlation",
            rr.Tensor(snap.image, dim_names=("entity", "entity"), value_range=(0.0, 1.0)),
        )
        self.rec.log(f"plots/{backend}/mean_abs_correlation", rr.Scalars(snap.mean_abs))

    def send_particles(
        self, backend: str, series: ParticleSeries, color_index: int = 0, style: bool = True
    ) -> None:
        """FastSLAM's particle positions, ESS before resampling and resampling entries
        of several steps, as columns on the step (and time) timelines; with ``style``
        the cloud's colour and size, static (once is enough)."""
        rr = self._rr
        entity = f"world/{backend}/particles"
        if style:
            color = PALETTE[color_index % len(PALETTE)]
            self.rec.log(entity, rr.Points2D.from_fields(colors=[color], radii=0.05), static=True)

        def indexes(steps, stamps=None):
            out = [rr.TimeColumn("step", sequence=steps)]
            return out if stamps is None else out + [rr.TimeColumn("time", duration=stamps)]

        T, N = series.positions.shape[:2]
        self.rec.send_columns(
            entity,
            indexes(series.steps, series.stamps_s),
            rr.Points2D.columns(positions=series.positions.reshape(-1, 2)).partition(np.full(T, N)),
        )
        self.rec.send_columns(
            f"plots/{backend}/ess",
            indexes(series.steps, series.stamps_s),
            rr.Scalars.columns(scalars=series.ess),
        )
        if series.events:
            at = np.searchsorted(series.steps, [k for k, _ in series.events])
            stamps = None if series.stamps_s is None else series.stamps_s[at]
            self.rec.send_columns(
                f"plots/{backend}/resampling",
                indexes(series.steps[at], stamps),
                rr.TextLog.columns(text=[t for _, t in series.events], level=["INFO"] * len(series.events)),
            )


class RunRecorder:
    """Records one or more back ends' runs of one dataset into a :class:`PlanarLog`.

    Every step's current pose is logged (in columns, a batch per snapshot);
    every ``every`` steps, and at the end, the whole estimate with landmark
    ellipses.
    """

    def __init__(self, log: PlanarLog | BackgroundLog):  # BackgroundLog: one in a child process
        self.log = log
        self._colors: dict[str, int] = {}
        self._filters: dict[str, FilterStateLogger] = {}
        self._pending: dict[str, tuple[list, list, list, list]] = {}  # steps, stamps, poses, robots
        self._agent_of: dict[int, int] = {}  # pose id -> robot index, several robots in one run
        self._dataset: Any = None  # what start() logged the truth of, and for how many steps
        self._truth_steps = 0

    #: Runs of at least this many steps record in a second process with ``save``: it
    #: costs an interpreter and Rerun's import (1-3 s of the other core's time), which a
    #: long run hides and a short one would wait for at the end.
    BACKGROUND_MIN_STEPS = 1000

    @classmethod
    def open(cls, mode: str, path: Path, url: str | None = None, *, background: bool = False) -> RunRecorder:
        """A recorder; with ``background``, ``save`` records in a second process
        (:mod:`.background`): the run does not wait for Rerun's import and encoding.
        A viewer (``spawn``, ``connect``) is started or reached here, in this process,
        so that failing to is known now."""
        if mode == "save" and background:
            from graphslam.visualisation.background import BackgroundLog

            return cls(BackgroundLog(PlanarLog, mode, path, url))
        return cls(PlanarLog(mode, path=path, url=url))

    def start(self, dataset, n_steps: int) -> None:
        self._agent_of = {int(pid): i for i, (_, ids) in enumerate(dataset.agents) for pid in ids}
        self._dataset, self._truth_steps = dataset, n_steps
        self._log_truth(n_steps)

    def _log_truth(self, n_steps: int) -> None:
        """The true poses of the first ``n_steps`` frames (a real log's truth may cover
        only some), one strip per robot: five robots' truth in frame order was one
        zig-zag line across the room."""
        dataset = self._dataset
        gt = dataset.ground_truth()
        strips = None
        if gt is not None:
            run = np.isin(gt[0], [f.pose_id for f in dataset.frames[:n_steps]])
            ids, xy = gt[0][run], gt[1][run]
            strips = [xy[mine] for mine in dataset.agent_groups(ids) if len(mine)]
        self.log.log_ground_truth(strips, dataset.landmarks_true)

    def color_index(self, backend: str) -> int:
        return self._colors.setdefault(backend, len(self._colors))

    def hook(self, backend: str, every: int):
        """An ``on_step`` callback for :func:`graphslam.pipelines.planar.run`.

        Pose arrows are gathered and sent as columns at each snapshot (every
        ``every`` steps) and at :meth:`finish`, not logged one call a step.
        """
        from graphslam.visualisation.filter_state import FilterStateLogger

        color = self.color_index(backend)
        filter_state = self._filters[backend] = FilterStateLogger(self.log, backend, every, color)
        pending = self._pending.setdefault(backend, ([], [], [], []))

        def on_step(k, frame, backend_obj):
            wTb = backend_obj.current_pose()
            pending[0].append(k)
            pending[1].append(frame.stamp_s)
            pending[2].append(wTb)
            pending[3].append(self._agent_of.get(frame.pose_id, color))
            if k % every == 0:
                self._send_poses(backend)
                self.log.set_step(k, frame.stamp_s)
                self.log.log_pose_uncertainty(backend, wTb, backend_obj.current_pose_covariance(), color)
                est = backend_obj.estimate(with_covariances=False)
                self.log.log_estimate(backend, est, color, self._groups(est))
            filter_state(k, frame.stamp_s, backend_obj)

        return on_step

    def _groups(self, est) -> list | None:
        """Index arrays of each robot's poses in ``est`` (None for one robot)."""
        return self._dataset.agent_groups(est.pose_ids) if self._agent_of else None

    def _send_poses(self, backend: str) -> None:
        steps, stamps, poses, robots = self._pending.get(backend, ([], [], [], []))
        if steps:
            timed = stamps if all(s is not None for s in stamps) else None
            self.log.log_pose_columns(
                backend,
                steps,
                timed,
                np.array(poses),
                self.color_index(backend),
                list(robots) if self._agent_of else None,
            )
            for column in (steps, stamps, poses, robots):
                column.clear()

    def finish(self, backend: str, result, source=None) -> None:
        """Log the final estimate (with ellipses if it has covariances) at the last step.

        ``source``: the back end, asked here for what the recording shows when the run
        fetched no covariances: the last pose's, and the landmarks' if there are any
        (a pose graph's 10 000 pose marginals would cost more than the whole recording).
        """
        self._send_poses(backend)
        if backend in self._filters:
            self._filters[backend].flush()
        last = max(result.steps - 1, 0)
        frames = result.dataset.frames
        # the last frame's time: the time line ended at the last snapshot's before
        self.log.set_step(last, frames[last].stamp_s if last < len(frames) else None)
        if source is not None and backend in self._filters:
            self._filters[backend].final(source)
        if result.interrupted and result.steps < self._truth_steps:  # the truth of the steps run
            self._truth_steps = result.steps
            self._log_truth(result.steps)
        est = result.estimate
        cov = est.current_covariance
        if source is not None and est.pose_covariances is None and not result.interrupted:
            cov = source.current_pose_covariance()
            if len(est.landmark_ids):
                est = dataclasses.replace(est, landmark_covariances=source.landmark_covariances())
        self.log.log_pose(backend, est.current_pose, cov, self.color_index(backend))
        self.log.log_estimate(backend, est, self.color_index(backend), self._groups(est))

    def relocate(self, folder: Path) -> None:
        """The output folder moved during the run: the recording is finished there."""
        self.log.relocate(folder)

    def close(self) -> None:
        self.log.close()

    def drop_disk_copy(self) -> bool:
        """A viewer stream's copy on disk deleted, the viewer still fed
        (:meth:`~graphslam.visualisation.recording.RerunLog.drop_disk_copy`); False
        when there is none (a saved recording, a child process's log)."""
        drop = getattr(self.log, "drop_disk_copy", None)
        return bool(drop()) if drop is not None else False

    def discard(self) -> None:
        """Stop recording and delete what was recorded (a child process's log is
        abandoned: it deletes its partial file)."""
        if hasattr(self.log, "abandon"):
            self.log.abandon()
        else:
            self.log.discard()

    def record_comparison(self, entries, dataset: Dataset, should_stop=None) -> bool:
        """Finished runs (:class:`graphslam.pipelines.compare.CompareEntry`), one entity
        subtree per back end, on the step timeline; True when ``should_stop()`` (asked at
        every pose) cut it, what was logged before kept."""
        n = max(e.result.steps for e in entries)
        self.start(dataset, n)
        # each pose at its frame's step and time, as the run's own recording has it
        frame_of = {f.pose_id: (k, f.stamp_s) for k, f in enumerate(dataset.frames)}
        for e in entries:
            est = e.result.estimate
            for k in range(len(est.pose_ids)):
                if should_stop is not None and should_stop():
                    return True
                self.log.set_step(*frame_of.get(int(est.pose_ids[k]), (k, None)))
                cov = None if est.pose_covariances is None else est.pose_covariances[k]
                self.log.log_pose(e.backend, est.wTb[k], cov, self.color_index(e.backend))
            self.finish(e.backend, e.result)
        return False
