"""Appearance prediction of tracked patches (RT-SLAM; the FPGA paper's patch warping).

A landmark's patch is cut once, where its track starts, and correlated in every
later frame. When the camera rolls about its optical axis, or moves towards or
away from the surface, the landmark no longer looks like that patch: ZNCC drops
below its threshold and the landmark is lost although its prediction is good.
Appearance prediction warps the patch by the view change the back end predicts
between the camera the patch was cut in (camera 0) and the current one
(camera 1), taking the patch on the fronto-parallel plane of camera 0 at the
landmark's depth there (:func:`slamcore.spatial.camera.plane_induced_affine`):
the local affine map of patch offsets image 0 -> image 1, ``A`` (2, 2).

The patch is warped about its centre, the pixel it was cut around, and the
affine is the homography's Jacobian there. Landmarks with no Euclidean
position (inverse depth ``rho <= 0``) or not in front of camera 0 are taken at
infinity (rotation only); where the cutting camera is unknown, or the map is
degenerate (not finite, or ``det A <= 0``: the plane seen edge-on or from
behind), the patch is used as it was cut (identity).

Data path (:class:`frontend.tracking.Tracker`): the back end's
:class:`~slamcore.spatial.records.PixelPredictions` carry the predicted pose of
the current camera ``wTc``, ``K`` and the predicted landmarks' positions
``landmarks_w``. When a track's patch is cut (at its birth, or at each match
with ``patch_update = "last"``) the tracker keeps with the track a larger
source patch around the same pixel (:func:`source_patch_size`), that pixel, and
the ``wTc`` of that frame's predictions. That pose is the back end's
prediction for the frame, before the frame's own update: its error is what one
update would correct, drift common to both cameras cancels in the relative
pose, and the warp of a patch of ten-odd pixels hardly feels it; it needs no
extra call to the back end (reading the updated pose would need one more
contract method and a call per frame). The next frame's predicted pose would
be one frame's motion off (4 degrees on a camera rolling 4 degrees a frame).
The first frame has no prediction: the pipeline hands its known pose the same
way (:meth:`PixelPredictions.empty`).
Predictions without these fields, or tracks cut without a pose, are
correlated unwarped, as with the option off.

Numpy only; camera maths from :mod:`slamcore.spatial.camera`.
"""

from __future__ import annotations

import numpy as np

from slamcore.spatial.camera import plane_induced_affine
from slamcore.spatial.geometry import invert_pose

__all__ = ["SOURCE_PATCH_FACTOR", "source_patch_size", "patch_affines"]

#: Side of the patch kept for warping, in units of the correlation patch's
#: half-side: the warped template's corners come from ``|A^-1| sqrt(2) h`` px
#: away, so a side of ``2 * 2h + 1`` covers any rotation and a shrink of the
#: view down to ``1 / sqrt(2)`` with rotation (beyond, edges are replicated).
SOURCE_PATCH_FACTOR = 2


def source_patch_size(patch_size_px: int) -> int:
    """Odd side (px) of the source patch kept for a ``patch_size_px`` template."""
    return SOURCE_PATCH_FACTOR * (patch_size_px // 2) * 2 + 1


def patch_affines(
    K: np.ndarray, wTc: np.ndarray, landmarks_w: np.ndarray, cut_wTc: np.ndarray, cut_uv: np.ndarray
) -> np.ndarray:
    """(N, 2, 2) maps of patch offsets, image the patch was cut in -> current image.

    Args:
        K: (3, 3) intrinsic matrix.
        wTc: (4, 4) predicted pose of the current camera.
        landmarks_w: (N, 3) estimated landmark positions, world frame, metres
            (non-finite rows: at infinity).
        cut_wTc: (N, 4, 4) pose of the camera each patch was cut in; NaN
            where unknown (identity map).
        cut_uv: (N, 2) pixels the patches were cut around (their centres).
    """
    K = np.asarray(K, dtype=np.float64)
    cut_wTc = np.asarray(cut_wTc, dtype=np.float64).reshape(-1, 4, 4)
    p_w = np.asarray(landmarks_w, dtype=np.float64).reshape(-1, 3)
    n = len(cut_wTc)
    out = np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
    if n == 0:
        return out
    c1Tc0 = invert_pose(wTc) @ cut_wTc
    # depth in camera 0: z of R^T (p_w - t)
    with np.errstate(invalid="ignore", over="ignore"):
        depth0 = np.einsum("ni,ni->n", p_w - cut_wTc[:, :3, 3], cut_wTc[:, :3, 2])
        depth0 = np.where(np.isfinite(depth0) & (depth0 > 0), depth0, np.inf)
        A = plane_induced_affine(K, c1Tc0, cut_uv, depth0)
        ok = np.all(np.isfinite(A.reshape(n, 4)), axis=1)
        ok[ok] = np.linalg.det(A[ok]) > 0
    out[ok] = A[ok]
    return out
