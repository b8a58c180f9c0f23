"""The camera-alone state of the visual iSAM2 back end (``robot_model = "constant_velocity"``).

:class:`MonoMotion` owns what tracking without odometry needs between frames:
the bootstrap until the first map (:class:`~.mono_init.MonoBootstrap`), the
constant-velocity step predicted for the current frame and its noise, whether
the frame has been measured yet, and the counts a run reports (frames tracked
by PnP, frames coasted on the motion model, tracking losses and how each
ended). It knows no gtsam: the back end hands it poses as (4, 4) arrays and
turns what it returns into factors.
"""

from __future__ import annotations

import numpy as np

from graphslam.backends.spatial.mono_init import FirstMap, MonoBootstrap
from graphslam.backends.spatial.mono_tracking import (
    MonoTrackingConfig,
    PnpPose,
    constant_velocity,
    frame_rotation,
    motion_covariance,
    pnp_pose,
    reprojects,
    rng_seed,
)
from slamcore.errors import GraphSlamError
from slamcore.spatial.geometry import invert_pose

__all__ = ["MonoMotion"]


class MonoMotion:
    """Bootstrap, then constant-velocity prediction and PnP measurement of each frame.

    Args:
        config: camera-alone settings.
        K: (3, 3) intrinsics.
        wTc0: (4, 4) pose given to the first frame; the first map's reference
            frame is put there.
        prior_covariance: (6, 6) ``[rho, phi]`` prior of that pose.
        seed: RANSAC seed (each call adds the frame id: repeatable, not repeated).
    """

    def __init__(
        self,
        config: MonoTrackingConfig,
        K: np.ndarray,
        wTc0: np.ndarray,
        prior_covariance: np.ndarray,
        seed: int = 0,
    ):
        self.config = config
        self.K = np.asarray(K, dtype=np.float64)
        self.wTc0 = np.asarray(wTc0, dtype=np.float64)
        self.prior_covariance = np.asarray(prior_covariance, dtype=np.float64)
        self.seed = int(seed)
        self._boot: MonoBootstrap | None = None
        self.mapped = False
        self.frame_id: int | None = None  # the current frame
        self.awaiting = False  # the current frame is predicted, not measured yet
        self.delta = np.eye(4)  # the constant-velocity step c_{k-1} T c_k of the current frame
        self.covariance = np.eye(6)  # its noise, [rho, phi]
        self.median_depth = 1.0  # of the landmarks last measured, map units
        self.sigma_px = 1.0  # the pixel sigma of the latest frame's observations
        self._coasting = 0
        self.losses: list[dict] = []
        self.counts = {
            "pnp_tracked_frames": 0,
            "coasted_frames": 0,
            "coasted_on_measured_rotation": 0,
            "pnp_outlier_pixels": 0,
        }
        self.first_map: dict | None = None
        self._frames_seen = 0
        self._before: tuple[np.ndarray, np.ndarray] | None = None  # last frame's (ids, uv)

    def next_frame(self, frame_id: int) -> None:
        self.frame_id = int(frame_id)
        self._frames_seen += 1

    def _current(self) -> int:
        """The current frame's id, set by :meth:`next_frame`."""
        if self.frame_id is None:
            raise GraphSlamError("isam2 (visual), camera alone: a frame before next_frame()")
        return self.frame_id

    def bootstrap(self, track_ids: np.ndarray, uv_px: np.ndarray, sigma_px: float) -> FirstMap | None:
        """The current frame's pixels to the bootstrap; the first map once made."""
        self.sigma_px = float(sigma_px)
        if self._boot is None:
            self._boot = MonoBootstrap(self.config, self.K, sigma_px, self.seed)
        first = self._boot.add(self._current(), track_ids, uv_px)
        if first is None:
            return None
        self.mapped = True
        last = first.refTc[-1]
        depth = (first.points_ref - last[:3, 3]) @ last[:3, :3]
        self.median_depth = float(np.median(depth[:, 2])) if len(depth) else 1.0
        self.first_map = {
            "reference_frame": int(first.reference),
            "frame": int(first.frame_ids[-1]),
            "model": first.model,
            "median_parallax_deg": first.median_parallax_deg,
            "points": int(len(first.track_ids)),
            "frames_without_pose": self._frames_seen - len(first.frame_ids),
            "scale_gauge": f"distance from frame {int(first.reference)} to frame "
            f"{int(first.frame_ids[-1])} = 1 (the map's unit of length)",
        }
        return first

    @property
    def bootstrap_reason(self) -> str:
        """Why no first map has been made yet (one line)."""
        return "no frame seen" if self._boot is None else self._boot.reason

    @property
    def bootstrap_remedy(self) -> str:
        """What would start the first map, for :attr:`bootstrap_reason` (one line)."""
        if self._boot is not None and self._boot.short_tracks:
            return (
                "the camera alone needs tracks that last from one place to another far enough "
                "away: tracks that last longer (followed by their patch: Harris's, or ORB's with "
                "[tracker] follow_by_patch), more of them ([tracker] max_tracks), or odometry"
            )
        return "the camera alone needs frames seen from places far enough apart: more frames, or odometry"

    def predict(self, wTc_before: np.ndarray, wTc_last: np.ndarray) -> np.ndarray:
        """(4, 4) predicted pose of the current frame; keeps the step and its noise.

        The translation noise is floored at what moves the median landmark by the
        last frame's pixel sigma (a camera at rest is not known to the micrometre either).
        """
        wTc_pred, self.delta = constant_velocity(wTc_before, wTc_last)
        floor = self.sigma_px * self.median_depth / float(self.K[0, 0])
        self.covariance = motion_covariance(self.delta, self.config, floor)
        self.awaiting = True
        return wTc_pred

    def measure(
        self,
        points_w: np.ndarray,
        uv_px: np.ndarray,
        wTc_pred: np.ndarray,
        sigma_px: float,
        frame_ids: np.ndarray,
        frame_uv: np.ndarray,
    ) -> PnpPose:
        """The current frame's pose by PnP on the re-found landmarks ``points_w`` (N, 3)
        at ``uv_px`` (N, 2); ``frame_ids`` (M,) and ``frame_uv`` (M, 2) are all the
        frame's pixels (kept for the next frame's rotation). Without a PnP pose the
        frame is coasted (:meth:`coast`): on the rotation its tracks measure from
        the last frame when they can (:attr:`delta` is then corrected), else on the
        prediction; ``inliers`` are then the landmark pixels that agree with the
        coasted pose within the PnP threshold."""
        c = self.config
        self.sigma_px = float(sigma_px)
        threshold = c.pnp_threshold_sigmas * sigma_px
        est = pnp_pose(
            points_w,
            uv_px,
            self.K,
            wTc_pred,
            threshold_px=threshold,
            min_inliers=c.min_pnp_inliers,
            seed=rng_seed(self.seed, self._current()),
        )
        before, self._before = self._before, (np.asarray(frame_ids), np.asarray(frame_uv))
        self.awaiting = False
        if est.wTc is not None:
            self.counts["pnp_tracked_frames"] += 1
            self.counts["pnp_outlier_pixels"] += int(np.count_nonzero(~est.inliers))
            cTw = invert_pose(est.wTc)
            z = (np.asarray(points_w)[est.inliers] @ cTw[:3, :3].T + cTw[:3, 3])[:, 2]
            self.median_depth = float(np.median(z))
            if self._coasting:
                self.losses[-1].update(frames=self._coasting, ended="found again by PnP")
            self._coasting = 0
            return est
        wTc_coast = wTc_pred
        wTc_last = wTc_pred @ invert_pose(self.delta)  # the step is replaced, not composed
        if before is not None and self._rotate(before, frame_ids, frame_uv, sigma_px):
            wTc_coast = wTc_last @ self.delta
            self.counts["coasted_on_measured_rotation"] += 1
        self.coast(est.reason)
        gated = reprojects(
            invert_pose(wTc_coast),
            np.asarray(points_w, dtype=np.float64).reshape(-1, 3),
            np.asarray(uv_px, dtype=np.float64).reshape(-1, 2),
            self.K,
            threshold,
        )
        return PnpPose(None, gated, est.reason, wTc_coast=wTc_coast)

    def _rotate(self, before, frame_ids, frame_uv, sigma_px: float) -> bool:
        """The step's rotation measured from the tracks seen in both frames, kept
        in :attr:`delta` with a rotation noise of the fit's pixel sigma; False when
        too few tracks agree."""
        ids_b, uv_b = before
        _, ib, iu = np.intersect1d(ids_b, np.asarray(frame_ids), assume_unique=True, return_indices=True)
        f = float(self.K[0, 0])
        step = float(np.linalg.norm(self.delta[:3, 3]))
        # the parallax the predicted step can make at the median depth, and the pixel noise
        threshold = step / max(self.median_depth, 1e-12) + self.config.pnp_threshold_sigmas * sigma_px / f
        R, _ = frame_rotation(
            uv_b[ib],
            np.asarray(frame_uv)[iu],
            self.K,
            threshold_rad=threshold,
            min_inliers=self.config.min_pnp_inliers,
            seed=rng_seed(self.seed, self._current()),
        )
        if R is None:
            return False
        self.delta = self.delta.copy()
        self.delta[:3, :3] = R
        self.covariance = self.covariance.copy()
        sigma_r = sigma_px / f  # one pixel sigma of rotation: many rays, averaged
        self.covariance[3:, 3:] = np.eye(3) * max(sigma_r, 1e-6) ** 2
        return True

    @property
    def coasting(self) -> bool:
        """The current frame is coasted (PnP could not place it)."""
        return self._coasting > 0

    def coast(self, reason: str) -> None:
        """The current frame keeps its constant-velocity prediction (counted)."""
        self.awaiting = False
        self.counts["coasted_frames"] += 1
        if self._coasting == 0:
            self.losses.append(
                {
                    "frame": self._current(),
                    "reason": reason,
                    "frames": 1,
                    "ended": "still lost at the end of the run",
                }
            )
        self._coasting += 1
        self.losses[-1]["frames"] = self._coasting

    def stats(self) -> dict:
        """What ``metrics.json`` states of the camera-alone run."""
        out = {
            "motion": "camera alone: constant-velocity prediction, PnP measurement",
            **self.counts,
            "tracking_losses": len(self.losses),
            "losses": list(self.losses),
        }
        if self.first_map is not None:
            out["first_map"] = dict(self.first_map)
        else:
            out["first_map"] = None
            out["no_first_map_because"] = self.bootstrap_reason
        return out
