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

import dataclasses
from dataclasses import dataclass
from typing import ClassVar, Literal

import cv2
import numpy as np

from frontend.features import Features
from frontend.image import MAX_PATCH_PX, MAX_POINTS_PER_FRAME, MAX_SIDE_PX, check_gray
from slamcore.config import bounded, validate


def _keypoint_arrays(kps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, 2) pixels, (N,) responses, (N,) octaves of OpenCV keypoints.

    ``cv2.KeyPoint_convert`` reads the positions in C; the two scalars go
    through ``np.fromiter`` (a KITTI frame has ~4 700 candidates: a list of
    Python floats per attribute cost more than describing the kept ones).
    """
    n = len(kps)
    xy = cv2.KeyPoint_convert(kps).astype(np.float64).reshape(n, 2)
    resp = np.fromiter((k.response for k in kps), np.float64, n)
    octv = np.fromiter((k.octave for k in kps), np.int64, n)
    return xy, resp, octv


@dataclass(frozen=True)
class OrbConfig:
    """ORB settings (config section ``[orb]``).

    Attributes:
        n_features: candidates ORB retains before the cell selection
            (``cv2.ORB_create(nfeatures=...)``).
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

    def __post_init__(self):
        validate(self)


class OrbDetector:
    """ORB + per-cell selection (:class:`frontend.features.Detector`).

    ``OrbDetector(config)`` or ``OrbDetector(cell_size_px=64, ...)`` (keyword
    overrides of :class:`OrbConfig`).
    """

    def __init__(self, config: OrbConfig | None = None, **overrides):
        config = config or OrbConfig()
        if overrides:
            config = dataclasses.replace(config, **overrides)
        self.config = config
        self._cv_orb = None

    def _orb(self):
        # One OpenCV ORB per detector: a new one reallocates its pyramid buffers on
        # first use (about 2 ms of a 9 ms KITTI frame). The config is frozen.
        if self._cv_orb is None:
            self._cv_orb = self._create()
        return self._cv_orb

    def _create(self):
        c = self.config
        return cv2.ORB_create(
            nfeatures=int(c.n_features), scaleFactor=float(c.scale_factor), nlevels=int(c.n_levels),
            edgeThreshold=int(c.edge_threshold), firstLevel=0, WTA_K=2,
            scoreType=cv2.ORB_HARRIS_SCORE if c.score == "harris" else cv2.ORB_FAST_SCORE,
            patchSize=int(c.patch_size), fastThreshold=int(c.fast_threshold))

    def _too_small(self, image: np.ndarray) -> bool:
        """No point of ``image`` is ``edge_threshold`` px inside every border, so ORB
        can describe none (and OpenCV fails on a 1-px side, whose pyramid levels
        have no pixel)."""
        c = self.config
        side = min(image.shape)
        return side <= 2 * c.edge_threshold or side / c.scale_factor ** (c.n_levels - 1) < 1.5

    def _cells(self, xy: np.ndarray, shape) -> np.ndarray:
        cs = self.config.cell_size_px
        n_cols = -(-shape[1] // cs)
        col = np.clip((xy[:, 0] // cs).astype(np.int64), 0, n_cols - 1)
        row = np.clip((xy[:, 1] // cs).astype(np.int64), 0, -(-shape[0] // cs) - 1)
        return row * n_cols + col

    @staticmethod
    def _order(xy, resp, octave, cell):
        """Sort by (cell, -response, row, column, octave): a total, deterministic order.

        Sorted on (cell, -response) first; only when two keypoints of one cell
        share a response (rare) is the full five-key sort needed, which costs
        about 3x more on a KITTI frame's ~4 800 candidates.
        """
        head = [-resp] if cell is None else [-resp, cell]
        o = np.lexsort(head)
        tie = resp[o][1:] == resp[o][:-1]
        if cell is not None:
            tie &= cell[o][1:] == cell[o][:-1]
        if not tie.any():
            return o
        return np.lexsort([octave, xy[:, 0], xy[:, 1]] + head)

    def describe(self, image: np.ndarray, xy_px: np.ndarray,
                 size_px: float = 31.0) -> tuple[np.ndarray, np.ndarray]:
        """ORB descriptors at given pixels (e.g. Harris corners of mapped tracks).

        Returns ``(index (M,) int64 into xy_px, descriptors (M, 32) uint8)``:
        OpenCV drops points too close to the border for the 31-px patch, so
        ``index`` says which points got a descriptor, in input order.
        """
        image = check_gray(image)
        xy = np.asarray(xy_px, dtype=np.float64).reshape(-1, 2)
        if len(xy) == 0 or self._too_small(image):
            return np.zeros(0, np.int64), np.zeros((0, 32), np.uint8)
        # class_id carries the input index through compute(), which may drop points
        kps = [cv2.KeyPoint(float(x), float(y), float(size_px), -1.0, 0.0, 0, int(i))
               for i, (x, y) in enumerate(xy)]
        kept, desc = self._orb().compute(image, kps)
        if desc is None or not kept:
            return np.zeros(0, np.int64), np.zeros((0, 32), np.uint8)
        index = np.array([k.class_id for k in kept], dtype=np.int64)
        o = np.argsort(index, kind="stable")
        return index[o], np.ascontiguousarray(desc[o])

    def select(self, kps, shape) -> np.ndarray:
        """Indices (sorted) of the OpenCV keypoints ``kps`` of an image of ``shape`` that
        :meth:`detect` keeps and describes: per-cell best, then the ``max_features`` cap."""
        c = self.config
        xy, resp, octv = _keypoint_arrays(kps)
        keep = np.arange(len(kps))
        if c.cell_size_px:
            cell = self._cells(xy, shape)
            order = self._order(xy, resp, octv, cell)
            sc = cell[order]
            # rank within the cell (order is sorted by cell, best first)
            start = np.r_[0, np.flatnonzero(np.diff(sc)) + 1]
            first = np.repeat(start, np.diff(np.r_[start, len(sc)]))
            rank = np.arange(len(sc)) - first
            keep = order[rank < c.per_cell]
        if c.max_features and len(keep) > c.max_features:
            o = np.lexsort([octv[keep], xy[keep, 0], xy[keep, 1], -resp[keep]])
            keep = keep[o[:c.max_features]]
        return np.sort(keep)

    def detect(self, image: np.ndarray) -> Features:
        """``image``: (H, W) uint8. Returns :class:`Features` with (N, 32) uint8 descriptors."""
        image = check_gray(image)
        c = self.config
        orb = self._orb()
        empty = Features(xy_px=np.zeros((0, 2)), response=np.zeros(0),
                         descriptors=np.zeros((0, 32), np.uint8),
                         cell=np.zeros(0, np.int64) if c.cell_size_px else None)
        if self._too_small(image):
            return empty
        kps = orb.detect(image, None)
        if not kps:
            return empty
        keep = self.select(kps, image.shape)
        kept_kps = [kps[i] for i in keep]  # only these are described
        kept_kps, desc = orb.compute(image, kept_kps)
        if desc is None or not kept_kps:
            return empty
        xy, resp, octv = _keypoint_arrays(kept_kps)
        cell = self._cells(xy, image.shape) if c.cell_size_px else None
        o = self._order(xy, resp, octv, cell)
        return Features(xy_px=xy[o], response=resp[o], descriptors=np.ascontiguousarray(desc[o]),
                        cell=None if cell is None else cell[o])
