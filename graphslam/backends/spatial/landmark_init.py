"""Delayed landmark initialisation of the visual iSAM2 back end: tracks waiting
for parallax, their triangulation and its consistency test.

A track not yet mapped buffers its pixels (:class:`Track`) until the angle
between the world rays of its first and latest pixels reaches the parallax
threshold with enough pixels (:meth:`Track.add`); it is then triangulated
(:func:`triangulate`, ``gtsam.triangulatePoint3``: DLT then Gauss-Newton) and
kept only if :func:`consistent` with every pixel it was triangulated from.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np

from graphslam.backends import gtsam_convert as conv


@dataclass
class Track:
    """A track waiting for parallax: its pixels, and the world ray of the first."""

    first_ray_w: np.ndarray  # (3,) unit
    frames: list[int] = field(default_factory=list)
    uv: list[np.ndarray] = field(default_factory=list)
    sigma: list[float] = field(default_factory=list)
    last_index: int = -1  # position in the frame list of the latest pixel
    queued: bool = False  # qualified: triangulated at the next frame

    def add(self, fid: int, uv: np.ndarray, sigma: float, now: int, ray_w: np.ndarray, *,
            max_observations: int, min_observations: int, cos_parallax: float) -> bool:
        """Buffer the pixel ``uv`` (2,) px of frame ``fid`` (frame index ``now``), seen
        along the unit world ray ``ray_w`` (3,); True when the track has just
        qualified for triangulation (enough pixels and parallax, not queued before).

        Beyond ``max_observations`` pixels the oldest but the first (the
        parallax baseline) is dropped.
        """
        self.frames.append(fid)
        self.uv.append(uv)
        self.sigma.append(sigma)
        self.last_index = now
        if len(self.frames) > max_observations:
            del self.frames[1], self.uv[1], self.sigma[1]
        if (not self.queued and len(self.frames) >= min_observations
                and self.first_ray_w @ ray_w <= cos_parallax):
            self.queued = True
            return True
        return False


def triangulate(poses: list[gtsam.Pose3], cal: gtsam.Cal3_S2, uv: np.ndarray,
                sigma: np.ndarray) -> np.ndarray | None:
    """Point (3,) m in the world seen at pixels ``uv`` (m, 2) from ``poses`` (``wTc``),
    or None when gtsam finds it underconstrained or behind a camera.

    The Gauss-Newton refinement weighs every pixel by the smallest ``sigma``
    (m,) px: the pixels of one track come from one front end.
    """
    try:
        return np.asarray(gtsam.triangulatePoint3(
            poses, cal, [u.reshape(2, 1) for u in uv], 1e-9, True,
            gtsam.noiseModel.Isotropic.Sigma(2, float(sigma.min())))).reshape(3)
    except RuntimeError:  # gtsam's underconstrained / cheirality exceptions
        return None


def consistent(poses: list[gtsam.Pose3], K: np.ndarray, uv: np.ndarray, sigma: np.ndarray,
               point: np.ndarray, *, min_depth_m: float, max_sigmas: float) -> bool:
    """``point`` (3,) m is in front of every camera by ``min_depth_m`` and every pixel
    ``uv`` (m, 2) reprojects within ``max_sigmas`` times its ``sigma`` (m,) px."""
    T = np.array([conv.pose3_matrix(p) for p in poses])
    p_c = np.einsum("nji,nj->ni", T[:, :3, :3], point - T[:, :3, 3])  # R^T (p - t)
    if np.any(p_c[:, 2] < min_depth_m):
        return False
    h = p_c @ K.T
    err = np.linalg.norm(h[:, :2] / h[:, 2:3] - uv, axis=1)
    return bool(np.all(err <= max_sigmas * sigma))
