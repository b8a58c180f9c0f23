"""What active search (:mod:`frontend.active_search`) runs inside one ellipse.

The gate ellipse's pixels (:func:`ellipse_pixels`), patch extraction and
warping, and the two modes' matchers: :class:`ZnccMatcher` (software, RT-SLAM)
and :class:`NearestMatcher` (the FPGA's nearest Harris point). Each matcher is a
:data:`Matcher`: called with one landmark's inverse innovation covariance and
ellipse pixels, it returns the accepted measurement, its score and distance.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import cv2
import numpy as np

from frontend.active_search_config import ActiveSearchConfig
from frontend.features import Features
from frontend.image import check_gray
from slamcore.errors import InputError

__all__ = [
    "Matcher",
    "NearestMatcher",
    "ZnccMatcher",
    "checked_points",
    "ellipse_pixels",
    "extract_patches",
    "inv2",
]


def ellipse_pixels(center: np.ndarray, S: np.ndarray, gamma: float, shape: tuple[int, int], margin: int = 0):
    """Integer pixels inside the gate ellipse and at least ``margin`` px from every edge.

    Returns ``(u0, v0, mask)``: ``mask`` (h, w) bool over the bounding box whose
    top-left pixel is ``(u0, v0)``; ``mask[j, i]`` is pixel ``(u0 + i, v0 + j)``.
    An empty box gives a (0, 0) mask.
    """
    H, W = shape
    cu, cv = float(center[0]), float(center[1])
    au, av = math.sqrt(gamma * S[0, 0]), math.sqrt(gamma * S[1, 1])
    u0 = max(math.ceil(cu - au), margin)
    u1 = min(math.floor(cu + au), W - 1 - margin)
    v0 = max(math.ceil(cv - av), margin)
    v1 = min(math.floor(cv + av), H - 1 - margin)
    if u1 < u0 or v1 < v0:
        return u0, v0, np.zeros((0, 0), dtype=bool)
    Si = inv2(S)
    du = np.arange(u0, u1 + 1, dtype=np.float64) - cu
    dv = np.arange(v0, v1 + 1, dtype=np.float64) - cv
    d2 = (
        Si[0, 0] * du[None, :] ** 2 + 2.0 * Si[0, 1] * du[None, :] * dv[:, None] + Si[1, 1] * dv[:, None] ** 2
    )
    return u0, v0, d2 <= gamma


def checked_points(values, what: str, n: int | None = None) -> np.ndarray:
    """``values`` as a float64 (N, 2) copy, N = ``n`` when given; InputError otherwise.
    An array of another shape is refused, not reshaped: (2, N) read as (N, 2) scrambles
    the points."""
    try:
        a = np.array(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(
            f"{what} must be (N, 2) pixels, got {type(values).__name__} of other values"
        ) from None
    if a.ndim != 2 or a.shape[1] != 2 or (n is not None and len(a) != n):
        raise InputError(f"{what} must be ({'N' if n is None else n}, 2) pixels, got shape {a.shape}")
    return a


def extract_patches(image: np.ndarray, xy: np.ndarray, size: int) -> np.ndarray:
    """(N, size, size) float32 patches centred on ``xy`` (N, 2) (sub-pixel, edges replicated)."""
    image = check_gray(image)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    out = np.empty((len(xy), size, size), np.float32)
    for i, (u, v) in enumerate(xy):
        out[i] = cv2.getRectSubPix(image, (size, size), (float(u), float(v)), patchType=cv2.CV_32F)
    return out


def _warp_patch(image: np.ndarray, xy: np.ndarray, A_inv: np.ndarray, size: int) -> np.ndarray:
    """Patch of float32 ``image`` as seen after the offset map ``A`` (prev -> cur), given
    ``A_inv`` (2, 2): ``P(d) = I(xy + A^-1 d)`` for offsets ``d`` from the patch centre."""
    c = (size - 1) / 2.0
    M = np.empty((2, 3))
    M[:, :2] = A_inv
    M[:, 2] = xy - A_inv @ np.array([c, c])
    return cv2.warpAffine(
        image, M, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE
    )


#: Flat-window peaks tested one by one before testing every window of the ellipse.
_PEAK_TRIES = 4


def _parabola(rm: float, r0: float, rp: float) -> float:
    den = rm - 2.0 * r0 + rp
    if not den < 0.0:
        return 0.0
    # plain floats: np.clip on a scalar costs more than the whole fit
    return min(max(0.5 * (rm - rp) / den, -0.5), 0.5)


def inv2(S: np.ndarray) -> np.ndarray:
    """Inverse of a 2x2 matrix in closed form (np.linalg.inv's call overhead is ~30 us)."""
    a, b, c, d = float(S[0, 0]), float(S[0, 1]), float(S[1, 0]), float(S[1, 1])
    det = a * d - b * c
    return np.array([[d / det, -b / det], [-c / det, a / det]])


#: One mode's matching of one landmark inside its ellipse:
#: ``matcher(i, Si, u0, v0, mask) -> (uv, score, d2)`` with ``Si`` (2, 2) the
#: inverse innovation covariance and ``(u0, v0, mask)`` the ellipse's pixels
#: (:func:`ellipse_pixels`). ``uv`` (2,) is the accepted measurement or None;
#: ``score`` is recorded even when nothing is accepted (None: no score);
#: ``d2`` None lets the search compute ``e^T S^-1 e`` from ``uv``.
Matcher = Callable[
    [int, np.ndarray, int, int, np.ndarray], tuple[np.ndarray | None, float | None, float | None]
]


class ZnccMatcher:
    """``"zncc"`` mode: best ZNCC of the landmark's template inside its ellipse.

    Templates are the stored ``patches`` (N, p, p), or, with appearance
    prediction, warped through the offset map ``affine`` (N, 2, 2) when the
    landmark is searched, from ``prev_image`` at ``prev_xy`` (N, 2) or from the
    centre of ``source_patches`` (N, q, q), q odd >= p (a track's patch cut
    larger, so that the corners of a rotated or shrunk template are image).
    """

    def __init__(
        self,
        config: ActiveSearchConfig,
        image: np.ndarray,
        n: int,
        *,
        patches: np.ndarray | None,
        prev_image: np.ndarray | None,
        prev_xy: np.ndarray | None,
        affine: np.ndarray | None,
        source_patches: np.ndarray | None = None,
    ):
        p = config.patch_size_px
        self.config, self.image, self.p, self.margin = config, image, p, p // 2
        self.min_var = float(config.min_patch_std) ** 2
        self.warp = config.predict_appearance and affine is not None
        if self.warp:
            self._warp_sources(n, prev_image, prev_xy, affine, source_patches)
        elif patches is None:
            if prev_image is None or prev_xy is None:
                raise InputError("zncc mode needs patches, or prev_image and prev_xy")
            patches = extract_patches(prev_image, checked_points(prev_xy, "prev_xy", n), p)
        if patches is not None:  # always, unless warping
            try:  # a list of (p, p) arrays is one
                patches = np.asarray(patches)
            except ValueError:
                raise InputError(f"patches must be ({n}, {p}, {p}), got arrays of several shapes") from None
            if patches.ndim != 3 or patches.shape[1:] != (p, p) or len(patches) != n:
                raise InputError(f"patches must be ({n}, {p}, {p}), got {patches.shape}")
            if not self.warp:
                # one vectorised call instead of one np.std per landmark
                self.tpl_std = patches.reshape(n, p * p).astype(np.float64).std(axis=1)
        self.patches = patches

    def _warp_sources(self, n: int, prev_image, prev_xy, affine, source_patches) -> None:
        """Check and keep what appearance prediction warps: float32 sources, their
        points, and the inverse maps (one batched inverse, not one per landmark)."""
        affine = np.asarray(affine, dtype=np.float64).reshape(-1, 2, 2)
        if len(affine) != n or not np.all(np.isfinite(affine)) or np.any(np.linalg.det(affine) == 0):
            raise InputError(f"affine must be {n} finite invertible (2, 2) maps")
        self.affine_inv = np.linalg.inv(affine)
        self.sources = None
        if source_patches is not None:
            self.sources = np.asarray(source_patches, dtype=np.float32)
            q = self.sources.shape[-1]
            if self.sources.shape != (n, q, q) or q < self.p or q % 2 == 0:
                raise InputError(
                    f"source_patches must be ({n}, q, q) with q odd >= {self.p}, got {self.sources.shape}"
                )
            self.source_xy = np.array([(q - 1) / 2.0, (q - 1) / 2.0])
            return
        if prev_image is None or prev_xy is None:
            raise InputError("appearance prediction needs prev_image and prev_xy, or source_patches")
        # converted once here, not once per landmark searched
        self.prev_image = check_gray(prev_image, "prev_image").astype(np.float32)
        self.prev_xy = checked_points(prev_xy, "prev_xy", n)  # too few rows: IndexError when searched

    def template(self, i: int) -> np.ndarray | None:
        """(p, p) float32 template of landmark ``i``, None if flat (ZNCC undefined)."""
        if not self.warp:
            if self.tpl_std[i] < self.config.min_patch_std:
                return None
            if self.patches is None:  # __init__ has them whenever it does not warp
                raise InputError("zncc mode needs patches, or prev_image and prev_xy")
            return np.ascontiguousarray(self.patches[i], dtype=np.float32)
        if self.sources is not None:
            tpl = _warp_patch(self.sources[i], self.source_xy, self.affine_inv[i], self.p)
        else:
            tpl = _warp_patch(self.prev_image, self.prev_xy[i], self.affine_inv[i], self.p)
        _, sd = cv2.meanStdDev(tpl)  # a tenth of np.std's cost on a patch
        return None if float(sd[0, 0]) < self.config.min_patch_std else tpl

    def __call__(self, i, Si, u0, v0, mask):
        tpl = self.template(i)
        if tpl is None:
            return None, None, None
        h = self.margin
        bh, bw = mask.shape
        # only the ellipse's bounding box (plus the patch margin) is converted
        region = self.image[v0 - h : v0 + bh + h, u0 - h : u0 + bw + h].astype(np.float32)
        res = cv2.matchTemplate(region, tpl, cv2.TM_CCOEFF_NORMED)
        masked = np.where(mask & np.isfinite(res), res, -np.inf)
        jv, ju = self._peak(region, masked)
        if masked[jv, ju] == -np.inf:
            return None, None, None
        best = float(res[jv, ju])
        if best < self.config.min_score:
            return None, best, None
        du = dv = 0.0
        if self.config.subpixel:
            if 0 < ju < bw - 1:
                du = _parabola(float(res[jv, ju - 1]), best, float(res[jv, ju + 1]))
            if 0 < jv < bh - 1:
                dv = _parabola(float(res[jv - 1, ju]), best, float(res[jv + 1, ju]))
        return np.array([u0 + ju + du, v0 + jv + dv]), best, None

    def _peak(self, region: np.ndarray, masked: np.ndarray) -> tuple[int, int]:
        """Best ZNCC ``(row, col)`` in ``masked`` whose image window is not flat.

        ZNCC is undefined on a flat window. The window test is done at the peak
        only and the next peak tried if it fails (the same pixel as testing
        every window); after a few flat peaks (a flat area) every window is
        tested at once. Flat windows are set to -inf in ``masked``; a -inf
        answer means no acceptable pixel.
        """
        p, h = self.p, self.margin
        bh, bw = masked.shape
        for _ in range(_PEAK_TRIES):
            jv, ju = divmod(int(np.argmax(masked)), bw)
            if masked[jv, ju] == -np.inf:
                return jv, ju
            _, sd = cv2.meanStdDev(region[jv : jv + p, ju : ju + p])
            if float(sd[0, 0]) ** 2 >= self.min_var:
                return jv, ju
            masked[jv, ju] = -np.inf
        k = (p, p)
        m1 = cv2.boxFilter(region, cv2.CV_32F, k, normalize=True, borderType=cv2.BORDER_CONSTANT)
        m2 = cv2.boxFilter(region * region, cv2.CV_32F, k, normalize=True, borderType=cv2.BORDER_CONSTANT)
        var = (m2 - m1 * m1)[h : h + bh, h : h + bw]
        masked[var < self.min_var] = -np.inf
        return divmod(int(np.argmax(masked)), bw)


class NearestMatcher:
    """``"nearest"`` mode: the detected point nearest to the prediction (Mahalanobis)
    inside the ellipse; its detector response is the score."""

    margin = 0

    def __init__(self, config: ActiveSearchConfig, z: np.ndarray, features: Features | None):
        if features is None:
            raise InputError("nearest mode needs the current frame's features")
        self.z, self.gate = z, config.gate
        self.fxy = np.asarray(features.xy_px, dtype=np.float64).reshape(-1, 2)
        self.fresp = np.asarray(features.response, dtype=np.float64)

    def __call__(self, i, Si, u0, v0, mask):
        if len(self.fxy) == 0:
            return None, None, None
        d = self.fxy - self.z[i]
        dd = np.einsum("ni,ij,nj->n", d, Si, d)
        inside = np.flatnonzero(dd <= self.gate)
        if len(inside) == 0:
            return None, None, None
        j = inside[np.argmin(dd[inside])]
        return self.fxy[j].copy(), self.fresp[j], None
