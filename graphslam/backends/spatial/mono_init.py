"""Monocular bootstrap of the visual iSAM2 back end: the first map from two views.

Without odometry nothing can be triangulated until two views of the same
tracks are far enough apart. :class:`MonoBootstrap` keeps the latest frames
(their track ids and pixels, ``max_bootstrap_frames`` at most) and, at each new
frame, fits the two-view geometry between it and a reference: the oldest kept
frame that still shares ``two_view.min_points`` tracks with it, the widest
baseline the tracks allow (:func:`frontend.two_view.two_view_geometry`:
homography or essential matrix chosen as ORB-SLAM does, triangulation with
parallax and reprojection checks). Once it holds, the first map is made:

- the scale gauge is fixed once: the baseline from the reference to the frame
  that initialised is 1 (the unit of every length the run writes; a
  Sim(3)-aligned ATE is blind to it, and ``metrics.json`` states it);
- every other kept frame, before the reference or between the two, is placed
  by PnP on the triangulated points (the front end followed the tracks); one
  whose PnP fails is left without a pose (counted);
- every landmark keeps the pixels of every frame it reprojects into within the
  PnP threshold.

Frames that fell out of the window before the map was made get no pose. The
last reason the geometry was refused is kept, so a run that never initialises
can say why in one line.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from frontend.two_view import two_view_geometry
from graphslam.backends.spatial.mono_tracking import MonoTrackingConfig, pnp_pose, reprojects, rng_seed
from slamcore.errors import MeasurementError
from slamcore.spatial.geometry import invert_pose

__all__ = ["MonoBootstrap", "FirstMap"]


@dataclass(frozen=True, eq=False)
class FirstMap:
    """The map a bootstrap made, in the reference camera's frame (unit: the baseline).

    Attributes:
        frame_ids: (F,) frames with a pose, in order, the frame that initialised last.
        reference: the reference frame (its ``refTc`` is the identity).
        refTc: (F, 4, 4) their poses in the reference camera's frame.
        track_ids: (P,) tracks triangulated.
        points_ref: (P, 3) their positions in the reference camera's frame.
        pixels: per frame of ``frame_ids``, ``(rows (M,) into track_ids, uv (M, 2))``
            of the landmarks it saw that reproject within the PnP threshold.
        model: ``"essential"`` or ``"homography"``.
        median_parallax_deg: of the triangulated points.
    """

    frame_ids: np.ndarray
    reference: int
    refTc: np.ndarray
    track_ids: np.ndarray
    points_ref: np.ndarray
    pixels: list
    model: str
    median_parallax_deg: float


class MonoBootstrap:
    """The latest frames, and the two-view test at each new one (module doc)."""

    def __init__(self, config: MonoTrackingConfig, K: np.ndarray, sigma_px: float = 1.0, seed: int = 0):
        self.config = config
        self._K = np.asarray(K, dtype=np.float64)
        self._seed = int(seed)
        self._sigma_px = float(sigma_px)
        self._frames: list[tuple[int, np.ndarray, np.ndarray]] = []  # (frame id, ids, uv)
        self.reason = "no frame seen yet"
        #: the latest frame shared too few tracks with every frame kept (the front
        #: end's tracks die before the baseline), not too little parallax
        self.short_tracks = False
        self.attempts = 0

    def add(self, frame_id: int, track_ids: np.ndarray, uv_px: np.ndarray) -> FirstMap | None:
        """Frame ``frame_id``'s (M,) track ids at (M, 2) pixels; the first map once
        the two-view geometry to a reference holds, else None.

        The reference is the oldest frame kept that shares ``two_view.min_points``
        tracks with this one (the widest baseline the tracks allow); the frames
        kept before it are placed by PnP too once the map exists.
        """
        ids = np.asarray(track_ids, dtype=np.int64).reshape(-1)
        uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
        self._frames.append((int(frame_id), ids, uv))
        if len(self._frames) > self.config.max_bootstrap_frames:
            del self._frames[0]
        need = self.config.two_view.min_points
        best = 0
        for j, (_, ref_ids, _) in enumerate(self._frames[:-1]):  # noqa: B007 (j: used below)
            shared = np.intersect1d(ref_ids, ids, assume_unique=True)
            best = max(best, len(shared))
            if len(shared) >= need:
                break
        else:
            most = max(len(f[1]) for f in self._frames)
            # a frame that tracks nothing is said as that (dark frames read "0 shared")
            why = (
                "; no frame kept had a tracked corner (images too dark, blurred or bare?)"
                if most == 0
                else f"; at most {most} tracked in one frame"
            )
            self.reason = (
                f"{best} tracks shared with an earlier frame < {need}{why}"
                if len(self._frames) > 1
                else "one frame: no second view yet"
            )
            self.short_tracks = len(self._frames) > 1
            return None
        self.short_tracks = False
        _, ref_ids, ref_uv = self._frames[j]
        common, ia, ib = np.intersect1d(ref_ids, ids, assume_unique=True, return_indices=True)
        self.attempts += 1
        try:
            geo = two_view_geometry(
                ref_uv[ia],
                uv[ib],
                self._K,
                self.config.two_view,
                seed=rng_seed(self._seed, self.attempts),
                sigma_px=self._sigma_px,
            )
        except MeasurementError as exc:  # degenerate pixels (on one line): wait for better
            self.reason = str(exc)
            return None
        if geo is None or not geo.ok:
            self.reason = "two-view geometry found no model" if geo is None else geo.reason
            return None
        kept = np.asarray(geo.mapped, dtype=bool)  # kept and seen under parallax
        first = self._build(
            j,
            common[kept],
            np.asarray(geo.points_a)[kept],
            np.asarray(geo.aTb, dtype=np.float64),
            geo.model,
            float(geo.median_parallax_deg),
        )
        self._frames = []
        return first

    def _build(
        self,
        ref: int,
        track_ids: np.ndarray,
        points_ref: np.ndarray,
        refTlast: np.ndarray,
        model: str,
        parallax: float,
    ) -> FirstMap:
        """Poses of the kept frames (the reference ``ref``: identity, the last: the
        two-view pose, the others: PnP) and each frame's pixels of the triangulated tracks."""
        c = self.config
        threshold = c.pnp_threshold_sigmas * self._sigma_px
        order = np.argsort(track_ids)
        track_ids, points_ref = track_ids[order], points_ref[order]
        frame_ids, poses, pixels = [], [], []
        n = len(self._frames)
        for j, (fid, ids, uv) in enumerate(self._frames):
            _, rows_in_map, rows_in_frame = np.intersect1d(
                track_ids, ids, assume_unique=True, return_indices=True
            )
            if j == ref:
                refTc = np.eye(4)
            elif j == n - 1:
                refTc = refTlast
            else:
                est = pnp_pose(
                    points_ref[rows_in_map],
                    uv[rows_in_frame],
                    self._K,
                    refTlast,
                    threshold_px=threshold,
                    min_inliers=c.min_pnp_inliers,
                    seed=rng_seed(self._seed, j),
                )
                if est.wTc is None:  # left without a pose (counted by the caller)
                    continue
                refTc = est.wTc
            ok = reprojects(
                invert_pose(refTc), points_ref[rows_in_map], uv[rows_in_frame], self._K, threshold
            )
            frame_ids.append(fid)
            poses.append(refTc)
            pixels.append((rows_in_map[ok], uv[rows_in_frame][ok]))
        return FirstMap(
            np.asarray(frame_ids, np.int64),
            self._frames[ref][0],
            np.asarray(poses),
            track_ids,
            points_ref,
            pixels,
            model,
            parallax,
        )
