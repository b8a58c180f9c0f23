"""A Rerun recording stream (saved, spawned or connected) and the drawing helpers
the 2-D and visual recorders share. With :mod:`.planar` and :mod:`.spatial`, the
only modules that import rerun.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slamcore.errors import ConfigError

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

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()
