"""Active search: look for each landmark only inside its innovation ellipse.

Seed 003, section 4.4. After the filter's prediction every landmark is
projected into the image with an innovation covariance ``S`` (2x2, px^2); the
observation must lie, with probability ``gate_probability``, in the ellipse

    (z - z_hat)^T S^-1 (z - z_hat) <= gamma,   gamma = chi2_2dof(p) = -2 ln(1 - p)

(9.21 for p = 0.99: for 2 degrees of freedom the chi-square quantile is exact
in closed form). Landmarks are searched largest ellipse first (``sqrt(det S)``,
proportional to the area: their observation brings the most information), and
at most ``max_corrections`` are searched per frame, a hard bound on the time;
``max_found`` stops the search once a back end's per-frame correction budget
is found (the others would not be used).

Two orders (``ActiveSearchConfig.order``):

* ``"batch"``: every ellipse comes from the one prediction of the frame and the
  back end corrects with all the matches at once, after the search.
* ``"sequential"`` (RT-SLAM): the largest ellipse is searched, the back end
  corrects with its match at once, and the landmarks still to search are
  re-predicted from the corrected state (their ellipses shrink) and re-sorted;
  the next is searched inside its new ellipse, up to the caps. With
  ``ransac_every = n`` (the paper's RT-SLAM variant, section 5.1: "one
  correction in two by one-point RANSAC" is n = 2, RT-SLAM's
  ``N_UPDATES_RANSAC``), the first ``ceil(cap / n)`` matches (``cap`` the
  back end's correction budget) are found in their predicted ellipses and
  handed over together, for the back end's one-point RANSAC; the rest
  follow one by one. The back end is reached through the ``repredict``
  callback of :meth:`ActiveSearch.search_with`.

Two modes (``ActiveSearchConfig.mode``):

* ``"zncc"`` (software, RT-SLAM): the stored patch (``patch_size_px`` square,
  from the previous image) is correlated (zero-mean normalised
  cross-correlation, ``cv2.matchTemplate(TM_CCOEFF_NORMED)`` on the ellipse's
  bounding box) and the best score among the integer pixels inside the
  ellipse is accepted if ``>= min_score``; image windows whose standard
  deviation is below ``min_patch_std`` grey levels are never accepted (ZNCC is
  undefined on flat windows). Optional sub-pixel refinement by a parabola
  through the 3 scores around the peak on each axis. Optional appearance
  prediction: the patch is warped, from the previous image or from a larger
  patch cut around the point, by a per-landmark affine map of pixel offsets
  (previous -> current, e.g.
  :func:`slamcore.spatial.camera.plane_induced_affine`; the tracker's are
  those of :mod:`frontend.appearance`) before correlation.
* ``"nearest"`` (hardware, the FPGA variant): among the current frame's Harris
  points (:class:`frontend.features.Features`), the one nearest to the
  prediction in Mahalanobis distance and inside the ellipse is taken. Points are
  not exclusive (two landmarks may take the same point), as in the paper.

Pixels "searched" by a landmark are the integer pixels inside its ellipse (and
inside the image, where a patch fits for ZNCC); the image fraction reported is
the union of these pixels over the frame, divided by ``H * W`` (the sum, which
counts overlaps twice, is reported as well).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, Literal

import cv2
import numpy as np

from frontend.features import Features
from frontend.image import MAX_PATCH_PX, MAX_POINTS_PER_FRAME, check_gray
from slamcore.config import bounded, validate
from slamcore.errors import ConfigError, InputError, MeasurementError

__all__ = ["ActiveSearchConfig", "ActiveSearchResult", "ActiveSearch", "Matcher", "ZnccMatcher",
           "NearestMatcher", "Repredict", "chi2_2dof", "ellipse_pixels", "extract_patches", "inv2"]


def chi2_2dof(probability: float) -> float:
    """Chi-square quantile with 2 degrees of freedom: ``-2 ln(1 - p)`` (9.2103 at 0.99)."""
    if not 0.0 < probability < 1.0:
        raise ConfigError(f"gate probability must be in (0, 1), got {probability!r}")
    return -2.0 * math.log1p(-probability)


@dataclass(frozen=True)
class ActiveSearchConfig:
    """Active search settings (config section ``[active_search]``).

    Attributes:
        mode: ``"zncc"`` (software patch correlation) or ``"nearest"`` (hardware:
            nearest Harris point inside the ellipse).
        gate_probability: probability mass of the search ellipse (chi-square, 2 dof).
        max_corrections: landmarks searched per frame at most (largest
            ellipses first); 0 = no cap.
        patch_size_px: odd side of the correlation patch, pixels.
        min_score: smallest ZNCC accepted, in [-1, 1].
        min_patch_std: patches / image windows with a grey-level standard
            deviation below this are not matched (flat, ZNCC undefined).
        subpixel: parabolic sub-pixel refinement of the ZNCC peak.
        predict_appearance: warp the patch by the given per-landmark affine
            before correlating (needs the previous image and points, or
            larger source patches; the tracker's patches are warped by the
            view change since they were cut, :mod:`frontend.appearance`).
        max_half_extent_px: landmarks whose ellipse's bounding box has a
            half-side above this are not searched (their prediction is
            meaningless; they would cost a large part of the frame).
        order: ``"batch"`` or ``"sequential"`` (module docstring); sequential
            needs a back end that corrects one landmark at a time (the
            monocular EKF).
        ransac_every: sequential only: one correction in ``n`` comes from the
            back end's one-point RANSAC over the first matches (module
            docstring); 0: none (every correction sequential, gated alone).
    """

    SECTION: ClassVar[str] = "active_search"

    mode: Literal["zncc", "nearest"] = "zncc"
    gate_probability: float = bounded(0.99, gt=0.0, lt=1.0)
    max_corrections: int = bounded(20, min=0, max=MAX_POINTS_PER_FRAME)
    patch_size_px: int = bounded(11, min=3, max=MAX_PATCH_PX)
    min_score: float = bounded(0.8, min=-1.0, max=1.0)
    min_patch_std: float = bounded(3.0, min=0.0)
    subpixel: bool = True
    predict_appearance: bool = False
    max_half_extent_px: float = bounded(150.0, gt=0.0)
    order: Literal["batch", "sequential"] = "batch"
    # 1 would hand every match to RANSAC at once: the batch order
    ransac_every: int = bounded(0, min=0, max=MAX_POINTS_PER_FRAME)

    def __post_init__(self):
        validate(self)
        if self.ransac_every == 1 or (self.ransac_every and self.order != "sequential"):
            raise ConfigError(f"active_search.ransac_every must be 0 or at least 2, with order "
                              f"'sequential' (got {self.ransac_every!r}, order {self.order!r})")
        if self.patch_size_px % 2 == 0:  # parity is not a range: checked here
            raise ConfigError(f"active_search.patch_size_px must be odd (a centre pixel), "
                              f"got {self.patch_size_px!r}")

    @property
    def gate(self) -> float:
        """Mahalanobis-squared threshold gamma of the ellipse."""
        return chi2_2dof(self.gate_probability)

    def first_batch(self, budget: int | None) -> int:
        """Matches handed to the back end together before the first re-prediction
        (sequential order): ``ceil(budget / ransac_every)``, else 1."""
        if not self.ransac_every or not budget:
            return 1
        return max(1, -(-int(budget) // self.ransac_every))


@dataclass(frozen=True, eq=False)
class ActiveSearchResult:
    """Outcome of one frame's active search, per landmark (N = number of predictions).

    Attributes:
        order: (M,) indices of the searched landmarks, in search order (largest ellipse first).
        searched: (N,) bool.
        found: (N,) bool, a match was accepted.
        uv: (N, 2) measured pixel position ``[u, v]``, NaN where not found.
        score: (N,) best ZNCC in the ellipse (zncc mode, even if rejected) or
            the Harris response of the chosen point (nearest mode); NaN if none.
        d2: (N,) Mahalanobis squared distance of ``uv`` to the prediction; NaN if not found.
        pixels: (N,) integer pixels evaluated inside the ellipse (0 if not searched).
        image_fraction: union of the searched pixels / (H W).
        image_fraction_sum: sum of ``pixels`` / (H W) (overlaps counted twice).
        skipped: (N,) bool, searchable but left unsearched because the search
            stopped (``max_corrections`` searched or ``max_found`` found); None
            for a result made without a search (no prediction).
    """

    order: np.ndarray
    searched: np.ndarray
    found: np.ndarray
    uv: np.ndarray
    score: np.ndarray
    d2: np.ndarray
    pixels: np.ndarray
    image_fraction: float
    image_fraction_sum: float
    skipped: np.ndarray | None = None

    @property
    def n_found(self) -> int:
        return int(self.found.sum())


def ellipse_pixels(center: np.ndarray, S: np.ndarray, gamma: float, shape: tuple[int, int],
                   margin: int = 0):
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
    d2 = (Si[0, 0] * du[None, :] ** 2 + 2.0 * Si[0, 1] * du[None, :] * dv[:, None]
          + Si[1, 1] * dv[:, None] ** 2)
    return u0, v0, d2 <= gamma


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
    return cv2.warpAffine(image, M, (size, size),
                          flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)


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
Matcher = Callable[[int, np.ndarray, int, int, np.ndarray],
                   tuple[np.ndarray | None, float | None, float | None]]

#: Sequential order's link to the back end: ``repredict(found, uv, pending) ->
#: (z (P, 2), S (P, 2, 2))``: correct with the landmarks ``found`` (M,) (indices
#: into the predictions) measured at ``uv`` (M, 2) px, and return the new
#: predictions and innovation covariances of the landmarks ``pending`` (P,).
Repredict = Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def _checked_predictions(predictions, S) -> tuple[np.ndarray, np.ndarray]:
    """``(z (N, 2), S (N, 2, 2))`` as float64; InputError / MeasurementError if malformed."""
    z = np.asarray(predictions, dtype=np.float64).reshape(-1, 2)
    S = np.asarray(S, dtype=np.float64).reshape(-1, 2, 2)
    n = len(z)
    if len(S) != n:
        raise InputError(f"{n} predictions but {len(S)} covariances")
    finite = np.all(np.isfinite(S.reshape(n, 4)), axis=1)
    Sf = S[finite]
    if np.any(np.abs(Sf[:, 0, 1] - Sf[:, 1, 0]) > 1e-9 * (1 + np.abs(Sf[:, 0, 1]))) or \
            np.any(Sf[:, 0, 0] <= 0) or np.any(np.linalg.det(Sf) <= 0):
        raise MeasurementError("innovation covariances must be symmetric positive definite")
    return z, S


class ZnccMatcher:
    """``"zncc"`` mode: best ZNCC of the landmark's template inside its ellipse.

    Templates are the stored ``patches`` (N, p, p), or, with appearance
    prediction, warped through the offset map ``affine`` (N, 2, 2) when the
    landmark is searched, from ``prev_image`` at ``prev_xy`` (N, 2) or from the
    centre of ``source_patches`` (N, q, q), q odd >= p (a track's patch cut
    larger, so that the corners of a rotated or shrunk template are image).
    """

    def __init__(self, config: ActiveSearchConfig, image: np.ndarray, n: int, *,
                 patches: np.ndarray | None, prev_image: np.ndarray | None,
                 prev_xy: np.ndarray | None, affine: np.ndarray | None,
                 source_patches: np.ndarray | None = None):
        p = config.patch_size_px
        self.config, self.image, self.p, self.margin = config, image, p, p // 2
        self.min_var = float(config.min_patch_std) ** 2
        self.warp = config.predict_appearance and affine is not None
        if self.warp:
            self._warp_sources(n, prev_image, prev_xy, affine, source_patches)
        elif patches is None:
            if prev_image is None or prev_xy is None:
                raise InputError("zncc mode needs patches, or prev_image and prev_xy")
            patches = extract_patches(prev_image, prev_xy, p)
        if patches is not None and (patches.ndim != 3 or patches.shape[1:] != (p, p) or len(patches) != n):
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
                raise InputError(f"source_patches must be ({n}, q, q) with q odd >= {self.p}, "
                                 f"got {self.sources.shape}")
            self.source_xy = np.array([(q - 1) / 2.0, (q - 1) / 2.0])
            return
        if prev_image is None or prev_xy is None:
            raise InputError("appearance prediction needs prev_image and prev_xy, or source_patches")
        # converted once here, not once per landmark searched
        self.prev_image = check_gray(prev_image, "prev_image").astype(np.float32)
        self.prev_xy = np.asarray(prev_xy, dtype=np.float64).reshape(-1, 2)

    def template(self, i: int) -> np.ndarray | None:
        """(p, p) float32 template of landmark ``i``, None if flat (ZNCC undefined)."""
        if not self.warp:
            if self.tpl_std[i] < self.config.min_patch_std:
                return None
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
        region = self.image[v0 - h:v0 + bh + h, u0 - h:u0 + bw + h].astype(np.float32)
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
            _, sd = cv2.meanStdDev(region[jv:jv + p, ju:ju + p])
            if float(sd[0, 0]) ** 2 >= self.min_var:
                return jv, ju
            masked[jv, ju] = -np.inf
        k = (p, p)
        m1 = cv2.boxFilter(region, cv2.CV_32F, k, normalize=True, borderType=cv2.BORDER_CONSTANT)
        m2 = cv2.boxFilter(region * region, cv2.CV_32F, k, normalize=True, borderType=cv2.BORDER_CONSTANT)
        var = (m2 - m1 * m1)[h:h + bh, h:h + bw]
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


class ActiveSearch:
    """Active search for one frame at a time (see the module docstring).

    ``ActiveSearch(config)`` or ``ActiveSearch(max_corrections=10, ...)``.
    """

    def __init__(self, config: ActiveSearchConfig | None = None, **overrides):
        config = config or ActiveSearchConfig()
        if overrides:
            config = dataclasses.replace(config, **overrides)
        self.config = config

    # ------------------------------------------------------------------ ordering

    def search_order(self, predictions: np.ndarray, S: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """Candidate landmark indices, largest ellipse (``sqrt(det S)``) first, ties by index.

        Drops predictions that are not finite, lie outside the image, or whose
        ellipse is larger than ``max_half_extent_px``. The cap is applied by
        :meth:`search` (a landmark whose ellipse has no usable pixel does not use it).
        """
        H, W = shape
        z = predictions
        ok = np.all(np.isfinite(z), axis=1) & np.all(np.isfinite(S.reshape(len(S), 4)), axis=1)
        ok &= (z[:, 0] >= -0.5) & (z[:, 0] <= W - 0.5) & (z[:, 1] >= -0.5) & (z[:, 1] <= H - 0.5)
        g = self.config.gate
        half = np.sqrt(g * np.maximum(np.maximum(S[:, 0, 0], S[:, 1, 1]), 0.0))
        ok &= half <= self.config.max_half_extent_px
        size = np.sqrt(np.maximum(np.linalg.det(S), 0.0))
        idx = np.flatnonzero(ok)
        return idx[np.argsort(-size[idx], kind="stable")]

    # ------------------------------------------------------------------ search

    def search(self, image: np.ndarray, predictions: np.ndarray, S: np.ndarray, *,
               patches: np.ndarray | None = None, prev_image: np.ndarray | None = None,
               prev_xy: np.ndarray | None = None, affine: np.ndarray | None = None,
               features: Features | None = None, max_found: int | None = None,
               source_patches: np.ndarray | None = None,
               repredict: Repredict | None = None) -> ActiveSearchResult:
        """Search the landmarks predicted at ``predictions`` (N, 2) with covariances ``S`` (N, 2, 2).

        ``image``: current (H, W) uint8 frame. zncc mode needs ``patches``
        (N, p, p) or ``prev_image`` + ``prev_xy`` (N, 2) (patches are cut there);
        appearance prediction needs ``affine`` (N, 2, 2) and either
        ``prev_image`` + ``prev_xy`` or ``source_patches`` (N, q, q), q odd >= p,
        centred on the points (:class:`ZnccMatcher`); without ``affine`` it is
        off. nearest mode needs ``features`` (the current frame's points).
        ``max_found``: stop once this many landmarks are found (a back end that
        corrects at most that many per frame, largest ellipses first, would not
        use the others: paper section 4.4); ``None`` or 0: no such stop. The
        config's ``max_corrections`` still caps the landmarks searched.
        ``repredict``: the sequential order's link to the back end
        (:meth:`search_with`).
        """
        image = check_gray(image)
        z, S = _checked_predictions(predictions, S)
        if self.config.mode == "zncc":
            matcher = ZnccMatcher(self.config, image, len(z), patches=patches, prev_image=prev_image,
                                  prev_xy=prev_xy, affine=affine, source_patches=source_patches)
        else:
            matcher = NearestMatcher(self.config, z, features)
        return self.search_with(image.shape, z, S, matcher, margin=matcher.margin, max_found=max_found,
                                repredict=repredict)

    def search_with(self, shape: tuple[int, int], z: np.ndarray, S: np.ndarray, matcher: Matcher, *,
                    margin: int = 0, max_found: int | None = None,
                    repredict: Repredict | None = None) -> ActiveSearchResult:
        """The search loop shared by every mode: ``matcher`` (see :data:`Matcher`) looks
        inside each ellipse, largest first, within the caps (:meth:`search`).

        ``shape``: ``(H, W)`` of the image; ``z`` (N, 2) and ``S`` (N, 2, 2)
        float64, already checked; ``margin``: pixels of every edge an ellipse
        pixel must keep (half the patch for ZNCC).

        ``repredict`` (:data:`Repredict`), with ``order = "sequential"``: each
        match (the first :meth:`ActiveSearchConfig.first_batch` together) goes
        to the back end at once, and the landmarks not searched yet are
        re-predicted and re-sorted. ``z`` and ``S`` are then updated in place:
        they end up holding the ellipse each landmark was searched in (the
        matcher reads them).
        """
        if repredict is not None and self.config.order != "sequential":
            raise ConfigError("active_search: a back-end link (repredict) needs order = 'sequential'")
        H, W = shape
        n = len(z)
        searched, found, skipped = np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool)
        uv, score, d2 = np.full((n, 2), np.nan), np.full(n, np.nan), np.full(n, np.nan)
        pixels = np.zeros(n, np.int64)
        union = np.zeros((H, W), bool)
        order, pending = [], []
        cap = self.config.max_corrections or n
        batch = self.config.first_batch(max_found or self.config.max_corrections)
        cand = list(self.search_order(z, S, (H, W)))
        while cand:
            if len(order) >= cap or (max_found and int(found.sum()) >= max_found):
                skipped[cand] = True
                break
            i = cand.pop(0)
            u0, v0, mask = ellipse_pixels(z[i], S[i], self.config.gate, (H, W), margin)
            cnt = int(mask.sum())
            if cnt == 0:
                continue
            order.append(i)
            searched[i] = True
            pixels[i] = cnt
            bh, bw = mask.shape
            union[v0:v0 + bh, u0:u0 + bw] |= mask
            if not self._match_one(i, z, S, matcher, (u0, v0, mask), uv, score, d2):
                continue
            found[i] = True
            if repredict is not None:
                pending.append(i)
                if len(pending) >= batch:
                    cand = self._corrected(repredict, pending, uv, cand, z, S, (H, W))
                    pending, batch = [], 1
        if pending:  # the last matches still correct the back end
            self._corrected(repredict, pending, uv, [], z, S, (H, W))
        npx = float(H * W)
        return ActiveSearchResult(order=np.asarray(order, dtype=np.int64), searched=searched, found=found,
                                  uv=uv, score=score, d2=d2, pixels=pixels,
                                  image_fraction=float(union.sum()) / npx,
                                  image_fraction_sum=float(pixels.sum()) / npx, skipped=skipped)

    @staticmethod
    def _match_one(i, z, S, matcher, box, uv, score, d2) -> bool:
        """Run ``matcher`` on landmark ``i`` in its ellipse ``box`` = ``(u0, v0, mask)``;
        fills ``uv``, ``score``, ``d2`` at ``i``; returns whether a match was accepted."""
        Si = inv2(S[i])
        m, sc, e2 = matcher(i, Si, *box)
        if sc is not None:
            score[i] = sc
        if m is None:
            return False
        if e2 is None:
            e = m - z[i]
            e2 = float(e @ Si @ e)
        d2[i] = e2
        uv[i] = m
        return True

    def _corrected(self, repredict, pending, uv, cand, z, S, shape) -> list:
        """Hand the matches ``pending`` to the back end, write the re-predictions of
        ``cand`` into ``z`` and ``S``, and return ``cand`` re-sorted (largest first;
        those now out of the image or too large dropped, as by :meth:`search_order`)."""
        p = np.asarray(pending, dtype=np.int64)
        c = np.asarray(cand, dtype=np.int64)
        z_new, S_new = repredict(p, uv[p].copy(), c)
        if not len(c):
            return []
        z[c] = np.asarray(z_new, dtype=np.float64).reshape(-1, 2)
        S_new = np.asarray(S_new, dtype=np.float64).reshape(-1, 2, 2)
        S[c] = 0.5 * (S_new + np.swapaxes(S_new, 1, 2))  # exactly symmetric, as the tracker's
        return c[self.search_order(z[c], S[c], shape)].tolist()
