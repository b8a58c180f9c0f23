"""Delayed landmark initialisation of the visual iSAM2 back end: tracks waiting
for parallax, their triangulation and its consistency test.

A track not yet mapped buffers its pixels (:class:`Track`) until the angle
between the world rays of its first and latest pixels reaches the parallax
threshold with enough pixels (:meth:`Track.add`); it is then triangulated
(:func:`triangulate`, ``gtsam.triangulatePoint3``: DLT then Gauss-Newton) and
kept only if :func:`consistent` with every pixel it was triangulated from.
Without odometry the first map comes from two views instead
(:mod:`.mono_init`), and :func:`first_map_graph` turns it into factors.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

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

    def add(
        self,
        fid: int,
        uv: np.ndarray,
        sigma: float,
        now: int,
        ray_w: np.ndarray,
        *,
        max_observations: int,
        min_observations: int,
        cos_parallax: float,
    ) -> bool:
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
        if (
            not self.queued
            and len(self.frames) >= min_observations
            and self.first_ray_w @ ray_w <= cos_parallax
        ):
            self.queued = True
            return True
        return False


def triangulate(
    poses: list[gtsam.Pose3], cal: gtsam.Cal3_S2, uv: np.ndarray, sigma: np.ndarray
) -> np.ndarray | None:
    """Point (3,) m in the world seen at pixels ``uv`` (m, 2) from ``poses`` (``wTc``),
    or None when gtsam finds it underconstrained or behind a camera.

    The Gauss-Newton refinement weighs every pixel by the smallest ``sigma``
    (m,) px: the pixels of one track come from one front end.
    """
    try:
        return np.asarray(
            gtsam.triangulatePoint3(
                poses,
                cal,
                [u.reshape(2, 1) for u in uv],
                1e-9,
                True,
                gtsam.noiseModel.Isotropic.Sigma(2, float(sigma.min())),
            )
        ).reshape(3)
    except RuntimeError:  # gtsam's underconstrained / cheirality exceptions
        return None


def consistent(
    poses: list[gtsam.Pose3],
    K: np.ndarray,
    uv: np.ndarray,
    sigma: np.ndarray,
    point: np.ndarray,
    *,
    min_depth_m: float,
    max_sigmas: float,
) -> bool:
    """``point`` (3,) m is in front of every camera by ``min_depth_m`` and every pixel
    ``uv`` (m, 2) reprojects within ``max_sigmas`` times its ``sigma`` (m,) px."""
    T = np.array([conv.pose3_matrix(p) for p in poses])
    p_c = np.einsum("nji,nj->ni", T[:, :3, :3], point - T[:, :3, 3])  # R^T (p - t)
    if np.any(p_c[:, 2] < min_depth_m):
        return False
    h = p_c @ K.T
    err = np.linalg.norm(h[:, :2] / h[:, 2:3] - uv, axis=1)
    return bool(np.all(err <= max_sigmas * sigma))


def first_map_graph(
    first,
    wTc0: np.ndarray,
    prior_noise: gtsam.noiseModel.Base,
    cal: gtsam.Cal3_S2,
    pixel_noise: gtsam.noiseModel.Base,
    scale_sigma: float,
):
    """Factors and values of a monocular first map (:class:`.mono_init.FirstMap`):
    its first frame at ``wTc0`` (4, 4) under ``prior_noise``, the scale fixed by a
    ``RangeFactorPose3`` of 1 (sigma ``scale_sigma``) from the reference frame to
    the frame that initialised, and a projection factor for every pixel of a
    landmark seen in two frames or more.

    Returns ``(graph, values, landmarks)``, ``landmarks`` a list of
    ``(track id, (3,) world position, number of its pixels)``.
    """
    frames = [int(f) for f in first.frame_ids]
    wTref = wTc0 @ np.linalg.inv(first.refTc[0])  # the first frame with a pose at wTc0
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PriorFactorPose3(X(frames[0]), conv.pose3(wTc0), prior_noise))
    for f, refTc in zip(frames, first.refTc, strict=True):
        values.insert(X(f), conv.pose3(wTref @ refTc))
    graph.add(
        gtsam.RangeFactorPose3(
            X(int(first.reference)), X(frames[-1]), 1.0, gtsam.noiseModel.Isotropic.Sigma(1, scale_sigma)
        )
    )
    nobs = np.zeros(len(first.track_ids), np.int64)
    for rows, _ in first.pixels:
        nobs[rows] += 1
    for f, (rows, uvs) in zip(frames, first.pixels, strict=True):
        for r, u in zip(rows.tolist(), uvs, strict=True):
            if nobs[r] >= 2:
                graph.add(
                    gtsam.GenericProjectionFactorCal3_S2(
                        u, pixel_noise, X(f), L(int(first.track_ids[r])), cal
                    )
                )
    landmarks = []
    for r, tid in enumerate(first.track_ids.tolist()):
        if nobs[r] >= 2:
            p_w = wTref[:3, :3] @ first.points_ref[r] + wTref[:3, 3]
            values.insert(L(tid), p_w)
            landmarks.append((tid, p_w, int(nobs[r])))
    return graph, values, landmarks
