"""Rerun logging: the only module that imports rerun.

Layout of a recording (2-D views, z up is implicit):

- ``world/ground_truth/{trajectory,landmarks}``: static, when known;
- ``world/<backend>/{trajectory,pose,landmarks,landmark_ellipses,pose_ellipse}``
  on the ``step`` timeline (and ``time`` in seconds where the data has stamps);
- ``plots/<backend>/pose_sigma_m``: 1-sigma position uncertainty over time,
  where the loop closure shows as a drop.

Ellipses are 95 % confidence regions (chi-square, 2 dof).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slamcore.errors import ConfigError
from slamcore.planar.records import Estimate

#: chi-square 95 % quantile with 2 degrees of freedom.
CHI2_2DOF_95 = 5.991464547107979
_ELLIPSE_POINTS = 33
_CIRCLE = np.stack([np.cos(np.linspace(0, 2 * np.pi, _ELLIPSE_POINTS)),
                    np.sin(np.linspace(0, 2 * np.pi, _ELLIPSE_POINTS))])  # (2, P)

GT_COLOR = (160, 160, 160)
PALETTE = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14)]


def ellipse_points(centers: np.ndarray, covariances: np.ndarray,
                   chi2: float = CHI2_2DOF_95) -> np.ndarray:
    """(M, P, 2) outline points of the ``chi2`` ellipses of (M, 2) centres, (M, 2, 2) covs."""
    vals, vecs = np.linalg.eigh(covariances)
    axes = vecs * np.sqrt(np.clip(vals, 0.0, None) * chi2)[:, None, :]  # (M, 2, 2)
    return centers[:, None, :] + np.einsum("mij,jp->mpi", axes, _CIRCLE)


class RerunLog:
    """One recording stream, saved to a file, spawned into a viewer, or sent to one.

    Args:
        mode: "save" (write ``path``), "spawn" (start a local viewer) or
            "connect" (gRPC to ``url``, default the viewer's own default).
        recording_id: fixed id so the same run gives the same recording.
    """

    def __init__(self, mode: str, path: Path | None = None, url: str | None = None,
                 application_id: str = "graphslam", recording_id: str = "graphslam-run"):
        import rerun as rr  # imported here: no work at import time, and only this module

        self._rr = rr
        self.rec = rr.RecordingStream(application_id, recording_id=recording_id)
        if mode == "save":
            if path is None:
                raise ConfigError("rerun: mode 'save' needs a path")
            self.rec.save(str(path))
        elif mode == "spawn":
            self.rec.spawn()
        elif mode == "connect":
            self.rec.connect_grpc(url) if url else self.rec.connect_grpc()
        else:
            raise ConfigError(f"rerun: unknown mode {mode!r} (save, spawn, connect)")
        self.path = path

    def set_step(self, step: int, stamp_s: float | None = None) -> None:
        self.rec.set_time("step", sequence=int(step))
        if stamp_s is not None:
            self.rec.set_time("time", duration=float(stamp_s))

    def log_ground_truth(self, wTb: np.ndarray | None, landmarks: dict | None) -> None:
        rr = self._rr
        if wTb is not None and len(wTb):
            rr_strip = rr.LineStrips2D([wTb[:, :2]], colors=[GT_COLOR], radii=0.05)
            self.rec.log("world/ground_truth/trajectory", rr_strip, static=True)
        if landmarks:
            ids = sorted(landmarks)
            pts = np.array([landmarks[i] for i in ids])
            self.rec.log("world/ground_truth/landmarks",
                         rr.Points2D(pts, colors=[GT_COLOR], radii=0.15,
                                     labels=[str(i) for i in ids], show_labels=False), static=True)

    def log_pose(self, backend: str, wTb: np.ndarray, covariance: np.ndarray | None,
                 color_index: int = 0) -> None:
        """Current pose (arrow), its 95 % position ellipse and sigma plot."""
        rr = self._rr
        color = PALETTE[color_index % len(PALETTE)]
        heading = 1.0 * np.array([np.cos(wTb[2]), np.sin(wTb[2])])
        self.rec.log(f"world/{backend}/pose", rr.Arrows2D(origins=[wTb[:2]], vectors=[heading],
                                                          colors=[color]))
        if covariance is not None:
            ring = ellipse_points(wTb[None, :2], covariance[None, :2, :2])[0]
            self.rec.log(f"world/{backend}/pose_ellipse", rr.LineStrips2D([ring], colors=[color]))
            sigma_m = float(np.sqrt(max(np.trace(covariance[:2, :2]), 0.0)))
            self.rec.log(f"plots/{backend}/pose_sigma_m", rr.Scalars(sigma_m))

    def log_estimate(self, backend: str, estimate: Estimate, color_index: int = 0) -> None:
        """Trajectory, landmarks and (if present) their 95 % ellipses."""
        rr = self._rr
        color = PALETTE[color_index % len(PALETTE)]
        self.rec.log(f"world/{backend}/trajectory",
                     rr.LineStrips2D([estimate.wTb[:, :2]], colors=[color], radii=0.05))
        if len(estimate.landmark_ids):
            self.rec.log(f"world/{backend}/landmarks",
                         rr.Points2D(estimate.landmarks_w, colors=[color], radii=0.2,
                                     labels=[str(int(i)) for i in estimate.landmark_ids],
                                     show_labels=False))
            if estimate.landmark_covariances is not None:
                rings = ellipse_points(estimate.landmarks_w, estimate.landmark_covariances)
                self.rec.log(f"world/{backend}/landmark_ellipses",
                             rr.LineStrips2D(list(rings), colors=[color], radii=0.02))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()


class RunRecorder:
    """Records one or more back ends' runs of one dataset into a :class:`RerunLog`.

    Every step logs the current pose (cheap for all back ends); every
    ``every`` steps, and at the end, the whole estimate with landmark ellipses.
    """

    def __init__(self, log: RerunLog):
        self.log = log
        self._colors: dict[str, int] = {}

    @classmethod
    def open(cls, mode: str, path: Path, url: str | None = None) -> "RunRecorder":
        return cls(RerunLog(mode, path=path, url=url))

    def start(self, dataset, n_steps: int) -> None:
        gt = dataset.ground_truth()
        self.log.log_ground_truth(None if gt is None else gt[1][:n_steps], dataset.landmarks_true)

    def color_index(self, backend: str) -> int:
        return self._colors.setdefault(backend, len(self._colors))

    def hook(self, backend: str, every: int):
        """An ``on_step`` callback for :func:`graphslam.pipelines.planar.run`."""
        color = self.color_index(backend)

        def on_step(k, frame, backend_obj):
            self.log.set_step(k, frame.stamp_s)
            snapshot = k % every == 0
            cov = backend_obj.current_pose_covariance() if snapshot else None
            self.log.log_pose(backend, backend_obj.current_pose(), cov, color)
            if snapshot:
                self.log.log_estimate(backend, backend_obj.estimate(with_covariances=False), color)

        return on_step

    def finish(self, backend: str, result) -> None:
        """Log the final estimate (with ellipses if it has covariances) at the last step."""
        self.log.set_step(max(result.steps - 1, 0))
        est = result.estimate
        cov = est.current_covariance
        self.log.log_pose(backend, est.current_pose, cov, self.color_index(backend))
        self.log.log_estimate(backend, est, self.color_index(backend))

    def close(self) -> None:
        self.log.close()
