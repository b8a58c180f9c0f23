"""ORB corners and descriptors (OpenCV) with per-cell selection, like the Harris tessellation.

OpenCV's ORB (oriented FAST + rotated BRIEF, an image pyramid) finds up to
``n_features`` candidates; the image is then tessellated into square cells of
``cell_size_px`` from the top-left corner (cell index = ``cell_row *
n_cell_cols + cell_col``, the same numbering as :mod:`frontend.harris`) and
only the ``per_cell`` best-response keypoints of each cell are kept, so
features spread over the image instead of piling up on one textured patch.
``cell_size_px = 0`` turns the tessellation off (``cell`` is then None).
Descriptors (32 bytes, uint8) are computed on the kept keypoints only; they
serve matching and the bag-of-words vocabulary.

Determinism: the same image gives the same output (OpenCV ORB is
deterministic; ties in response are broken by (row, column, octave) and the
output is sorted by cell, then decreasing response).
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass
from typing import ClassVar, Literal

import cv2
import numpy as np

from frontend.features import Features
from frontend.image import MAX_PATCH_PX, MAX_POINTS_PER_FRAME, MAX_SIDE_PX, check_gray
from slamcore.config import Validated, bounded, with_overrides
from slamcore.errors import GraphSlamError

#: Per-keypoint attribute readers: ``map`` over an ``attrgetter`` is the
#: fastest way OpenCV's Python binding offers (it has no array accessor for
#: response or octave; about 0.14 ms for a KITTI frame's ~4 800 candidates).
_RESPONSE = operator.attrgetter("response")
_OCTAVE = operator.attrgetter("octave")
_CLASS_ID = operator.attrgetter("class_id")


def _pixels(kps) -> np.ndarray:
    """(N, 2) float64 pixels of OpenCV keypoints (``cv2.KeyPoint_convert`` reads them in C)."""
    # cv2's stubs omit the KeyPoint_convert alias (and type KeyPoint.convert as a sequence)
    pts = cv2.KeyPoint_convert(kps)  # type: ignore[attr-defined]
    return pts.astype(np.float64).reshape(len(kps), 2)


def _responses(kps) -> np.ndarray:
    return np.fromiter(map(_RESPONSE, kps), np.float64, len(kps))


def _octaves(kps) -> np.ndarray:
    return np.fromiter(map(_OCTAVE, kps), np.int64, len(kps))


def _sort_key(resp: np.ndarray, cell: np.ndarray | None) -> np.ndarray:
    """One int64 key per keypoint that sorts like ``(cell, -response)``.

    One ``argsort`` of it costs about half of ``np.lexsort`` on the two keys.
    Exact: ``KeyPoint.response`` is a C float, so its float32 bits, made
    monotone (negative values have their magnitude bits flipped), order it
    as the float64 does; ``+ 0.0`` maps -0.0 to 0.0, which compare equal.
    """
    bits = (resp + 0.0).astype(np.float32).view(np.int32)
    mono = np.where(bits < 0, bits ^ np.int32(0x7FFFFFFF), bits).astype(np.int64)
    # -mono spans fewer than 2**32 values, so cells never overlap
    return -mono if cell is None else (cell << 32) - mono


@dataclass(frozen=True)
class OrbConfig(Validated):
    """ORB settings (config section ``[orb]``).

    Attributes:
        n_features: candidates ORB retains before the cell selection
            (``cv2.ORB.create(nfeatures=...)``).
        cell_size_px: side of the square cells; 0 disables the tessellation.
        per_cell: keypoints kept per cell (best responses).
        max_features: cap after the cell selection (best responses overall), 0 = none.
        fast_threshold: FAST intensity threshold (grey levels).
        scale_factor, n_levels: pyramid ratio and number of levels.
        edge_threshold, patch_size: ORB border and descriptor patch (pixels).
        score: ``"harris"`` or ``"fast"`` keypoint ranking.
    """

    SECTION: ClassVar[str] = "orb"

    n_features: int = bounded(5000, min=1, max=MAX_POINTS_PER_FRAME)
    cell_size_px: int = bounded(32, min=0, max=MAX_SIDE_PX)
    per_cell: int = bounded(1, min=1, max=MAX_POINTS_PER_FRAME)
    max_features: int = bounded(0, min=0, max=MAX_POINTS_PER_FRAME)
    # FAST compares grey levels of a uint8 image: above 255 nothing is a corner
    fast_threshold: int = bounded(20, min=0, max=255)
    scale_factor: float = bounded(1.2, gt=1.0)
    # OpenCV keeps one image per level, each scale_factor times smaller: at 1.2,
    # 32 levels take a 4096-px side down to 14 px (a level with no pixel fails)
    n_levels: int = bounded(8, min=1, max=32)
    # every pyramid level is padded by the border (and half the patch) on each side
    edge_threshold: int = bounded(31, min=0, max=MAX_PATCH_PX)
    patch_size: int = bounded(31, min=2, max=MAX_PATCH_PX)
    score: Literal["harris", "fast"] = "harris"


class OrbDetector:
    """ORB + per-cell selection (:class:`frontend.features.Detector`).

    ``OrbDetector(config)`` or ``OrbDetector(cell_size_px=64, ...)`` (keyword
    overrides of :class:`OrbConfig`).
    """

    def __init__(self, config: OrbConfig | None = None, **overrides):
        self.config = with_overrides(config or OrbConfig(), overrides, OrbConfig)
        self._cv_orb = None

    def __getstate__(self) -> dict:
        # OpenCV's ORB does not pickle (a sweep's workers, a saved detector): made anew
        return {**self.__dict__, "_cv_orb": None}

    def _orb(self):
        # One OpenCV ORB per detector: a new one reallocates its pyramid buffers on
        # first use (about 2 ms of a 9 ms KITTI frame). The config is frozen.
        if self._cv_orb is None:
            self._cv_orb = self._create()
        return self._cv_orb

    def _create(self):
        c = self.config
        return cv2.ORB.create(
            nfeatures=int(c.n_features),
            scaleFactor=float(c.scale_factor),
            nlevels=int(c.n_levels),
            edgeThreshold=int(c.edge_threshold),
            firstLevel=0,
            WTA_K=2,
            scoreType=cv2.ORB_HARRIS_SCORE if c.score == "harris" else cv2.ORB_FAST_SCORE,
            patchSize=int(c.patch_size),
            fastThreshold=int(c.fast_threshold),
        )

    def _too_small(self, image: np.ndarray) -> bool:
        """No point of ``image`` is ``edge_threshold`` px inside every border, so ORB
        can describe none, or OpenCV would fail: its coarsest level, the side divided by
        ``scale_factor ** (n_levels - 1)`` and rounded, has no pixel (measured: a 100-px
        side at 2.0 runs with 8 levels, 0.78 px, and fails with 9, 0.39 px). It took
        1.5 px for the limit and so dropped every corner of KITTI at scale 2, 9 levels,
        which OpenCV runs (hostile pass 24). Compared in logarithms: scale_factor = 1e300
        overflowed the power."""
        c = self.config
        side = min(image.shape)
        if side <= 2 * c.edge_threshold:
            return True
        return math.log(side / 0.5) <= (c.n_levels - 1) * math.log(c.scale_factor)

    def _cells(self, xy: np.ndarray, shape) -> np.ndarray:
        cs = self.config.cell_size_px
        n_cols = -(-shape[1] // cs)
        # Truncation, then clipping at 0, is the floor of x / cs; and the float64
        # quotient of a float32 pixel (KeyPoint.pt) never rounds up to the next
        # integer, so this is ``xy // cs`` at a third of the cost (as is
        # clipping each column by a scalar, not both by a pair).
        rc = (xy / cs).astype(np.int64)
        np.maximum(rc, 0, out=rc)
        col, row = rc[:, 0], rc[:, 1]
        np.minimum(col, n_cols - 1, out=col)
        np.minimum(row, -(-shape[0] // cs) - 1, out=row)
        return row * n_cols + col

    @staticmethod
    def _order(xy, resp, cell, octaves):
        """Sort by (cell, -response, row, column, octave): a total, deterministic order.

        Sorted on (cell, -response) first; only when two keypoints of one cell
        share a response (rare) is the full five-key sort needed, which costs
        about 3x more on a KITTI frame's ~4 800 candidates (and reads the
        octaves, ``octaves()``, which nothing else needs).
        """
        key = _sort_key(resp, cell)
        o = np.argsort(key)
        ko = key[o]
        if not (ko[1:] == ko[:-1]).any():
            return o
        head = [-resp] if cell is None else [-resp, cell]
        return np.lexsort([octaves(), xy[:, 0], xy[:, 1]] + head)

    def _cell_best(self, xy, resp, cell, kps, shape) -> np.ndarray:
        """Indices of the ``per_cell`` first keypoints of each cell in :meth:`_order`, in that order."""
        per_cell = self.config.per_cell
        if per_cell == 1:
            # The best response of each cell, found without a sort (a third of
            # its cost), unless two share it (or it is NaN) and the order decides.
            cs = self.config.cell_size_px
            best = np.full(-(-shape[0] // cs) * -(-shape[1] // cs), -np.inf)
            np.maximum.at(best, cell, resp)
            won = np.flatnonzero(resp == best[cell])
            if len(won) == np.count_nonzero(best != -np.inf):
                return won[np.argsort(cell[won])]  # one a cell
        order = self._order(xy, resp, cell, lambda: _octaves(kps))
        sc = cell[order]
        start = np.flatnonzero(np.r_[True, sc[1:] != sc[:-1]])  # order is sorted by cell
        first = np.repeat(start, np.diff(np.r_[start, len(sc)]))
        return order[np.arange(len(sc)) - first < per_cell]  # rank within the cell

    def describe(
        self, image: np.ndarray, xy_px: np.ndarray, size_px: float = 31.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """ORB descriptors at given pixels (e.g. Harris corners of mapped tracks).

        Returns ``(index (M,) int64 into xy_px, descriptors (M, 32) uint8)``:
        OpenCV drops points too close to the border for the 31-px patch, so
        ``index`` says which points got a descriptor, in input order.
        """
        image = check_gray(image)
        xy = _rows(xy_px, 2, "describe: points", "(N, 2) pixels")
        if len(xy) == 0 or self._too_small(image):
            return np.zeros(0, np.int64), np.zeros((0, 32), np.uint8)
        # class_id carries the input index through compute(), which may drop points
        kps = [
            cv2.KeyPoint(float(x), float(y), float(size_px), -1.0, 0.0, 0, int(i))
            for i, (x, y) in enumerate(xy)
        ]
        kept, desc = self._orb().compute(image, kps)
        if desc is None or not kept:
            return np.zeros(0, np.int64), np.zeros((0, 32), np.uint8)
        index = np.array([k.class_id for k in kept], dtype=np.int64)
        o = np.argsort(index, kind="stable")
        return index[o], np.ascontiguousarray(desc[o])

    def select(self, kps, shape) -> np.ndarray:
        """Indices (sorted) of the OpenCV keypoints ``kps`` of an image of ``shape`` that
        :meth:`detect` keeps and describes: per-cell best, then the ``max_features`` cap."""
        return np.sort(self._select(kps, shape)[0])

    def _select(self, kps, shape):
        """:meth:`select` in output order (:meth:`_order`), with the pixels, responses
        and cells (or None) of all ``kps``."""
        c = self.config
        xy, resp = _pixels(kps), _responses(kps)
        if not c.cell_size_px:
            # the cap's order (best response first, ties as _order) is the output order
            keep = self._order(xy, resp, None, lambda: _octaves(kps))[: c.max_features or None]
            return keep, xy, resp, None
        cell = self._cells(xy, shape)
        keep = self._cell_best(xy, resp, cell, kps, shape)
        if c.max_features and len(keep) > c.max_features:
            keep = np.sort(keep)
            sub = [kps[i] for i in keep]
            o = np.lexsort([_octaves(sub), xy[keep, 0], xy[keep, 1], -resp[keep]])[: c.max_features]
            keep = keep[
                o[
                    self._order(
                        xy[keep[o]], resp[keep[o]], cell[keep[o]], lambda: _octaves([sub[i] for i in o])
                    )
                ]
            ]
        return keep, xy, resp, cell

    def _empty(self) -> Features:
        return Features(
            xy_px=np.zeros((0, 2)),
            response=np.zeros(0),
            descriptors=np.zeros((0, 32), np.uint8),
            cell=np.zeros(0, np.int64) if self.config.cell_size_px else None,
        )

    def detect(self, image: np.ndarray) -> Features:
        """``image``: (H, W) uint8. Returns :class:`Features` with (N, 32) uint8 descriptors."""
        return self.detect_with_candidates(image)[0]

    def detect_with_candidates(
        self, image: np.ndarray, boxes_px: np.ndarray | None = None
    ) -> tuple[Features, Features]:
        """:meth:`detect`'s features, and every keypoint ORB found (up to ``n_features``,
        no cell selection, no ``max_features`` cap) inside one of ``boxes_px`` ((K, 4)
        ``u0, v0, u1, v1``, pixels), described, from one detection.

        The cell selection spreads the points new tracks start on; a landmark is
        searched for among all the keypoints, as ORB-SLAM's search by projection does:
        its corner need not be its cell's strongest in every frame. Only the keypoints
        inside the boxes (the search ellipses' bounding boxes) are described: all of a
        KITTI frame's 4 800 would double the detector's time. ``boxes_px`` None or
        empty: no candidate (the second record is then empty).
        """
        image = check_gray(image)
        if self._too_small(image):
            return self._empty(), self._empty_candidates()
        orb = self._orb()
        kps = orb.detect(image, None)
        if not kps:
            return self._empty(), self._empty_candidates()
        every = self._empty_candidates()
        boxes = np.zeros((0, 4)) if boxes_px is None else _rows(boxes_px, 4, "boxes", "(K, 4) u0 v0 u1 v1")
        if len(boxes):
            pts = _pixels(kps)
            inside = np.zeros(len(kps), bool)
            for u0, v0, u1, v1 in boxes:  # tens of boxes
                inside |= (pts[:, 0] >= u0) & (pts[:, 0] <= u1) & (pts[:, 1] >= v0) & (pts[:, 1] <= v1)
            # compute() takes keypoints by reference and may drop some: describe copies
            copies = [
                cv2.KeyPoint(k.pt[0], k.pt[1], k.size, k.angle, k.response, k.octave)
                for k in (kps[i] for i in np.flatnonzero(inside).tolist())
            ]
            if copies:
                described, desc = orb.compute(image, copies)
                if desc is not None and described:
                    every = Features(
                        xy_px=_pixels(described), response=_responses(described), descriptors=desc
                    )
        keep, xy, resp, cell = self._select(kps, image.shape)
        kept_kps = [kps[i] for i in keep.tolist()]  # only these are described
        # compute() drops keypoints it cannot describe and regroups the rest by
        # octave: class_id (the rank in the output order) puts them back, so
        # their pixels, responses and cells need not be read or sorted again
        for j, k in enumerate(kept_kps):
            k.class_id = j
        kept_kps, desc = orb.compute(image, kept_kps)
        if desc is None or not kept_kps:
            return self._empty(), every
        rank = np.fromiter(map(_CLASS_ID, kept_kps), np.int64, len(kept_kps))
        o = np.argsort(rank)
        got = keep[rank[o]]
        return Features(
            xy_px=xy[got], response=resp[got], descriptors=desc[o], cell=None if cell is None else cell[got]
        ), every

    @staticmethod
    def _empty_candidates() -> Features:
        return Features(xy_px=np.zeros((0, 2)), response=np.zeros(0), descriptors=np.zeros((0, 32), np.uint8))


def _rows(values, width: int, what: str, form: str) -> np.ndarray:
    """``values`` as (N, ``width``) float64 rows, or GraphSlamError: a (2, N) array was
    reshaped row-major into scrambled pixels and described there (twentieth hostile
    pass, the Python API). An empty input is no rows."""
    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise GraphSlamError(f"orb {what}: expected {form}, not numbers") from None
    if a.size == 0:
        return np.zeros((0, width))
    if a.ndim == 1 and a.shape == (width,):
        a = a[None]
    if a.ndim != 2 or a.shape[1] != width:
        raise GraphSlamError(f"orb {what}: expected {form}, got shape {a.shape}")
    return a
