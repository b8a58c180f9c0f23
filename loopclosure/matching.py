"""Descriptor matching for geometric verification: ratio test, cross-check, epipolar guidance.

All matching works on one (Na, Nb) Hamming distance matrix
(:func:`loopclosure.descriptor_distance.hamming_distances`): the plain match
(:func:`match_descriptors`) and the guided one (:func:`guided_match`) differ
only in which entries they allow. A match ``(a, b)`` is kept when

- its distance is at most ``max_hamming`` bits,
- it passes Lowe's ratio test among the allowed entries of row ``a``
  (``d1 < ratio * d2``, Lowe, IJCV 2004, 0.8 in his Fig. 11: it drops 90 % of
  the false matches and fewer than 5 % of the true ones), and
- with ``cross_check``, ``a`` is also the nearest allowed entry of column ``b``
  (mutual best match).

Deterministic: ties go to the lowest index (``argmin``).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = [
    "match_descriptors",
    "match_from_distances",
    "guided_match",
    "epipolar_distances",
    "epipolar_residuals",
]

#: Distance marking a forbidden entry: above any Hamming distance of 256-bit strings.
_FORBIDDEN = np.int32(1 << 20)


def match_from_distances(
    D: np.ndarray, ratio: float = 0.8, cross_check: bool = True, max_hamming: int = 64
) -> np.ndarray:
    """Matches of an (Na, Nb) int32 distance matrix -> (M, 2) int64 ``(a, b)`` sorted by a.

    Entries at or above :data:`_FORBIDDEN` are not candidates. A row with one
    allowed entry has no second neighbour; its ratio test compares to
    ``_FORBIDDEN`` (passes), as a nearest neighbour alone on its epipolar line.
    """
    na, nb = D.shape
    if na == 0 or nb == 0:
        return np.zeros((0, 2), np.int64)
    best = np.argmin(D, axis=1)  # lowest index on ties
    d_best = D[np.arange(na), best]
    # second smallest value of the row; equal to d_best on a tie (ambiguous: fails the test)
    d_second = np.partition(D, 1, axis=1)[:, 1] if nb >= 2 else np.full(na, _FORBIDDEN)
    ok = (d_best <= max_hamming) & (d_best < _FORBIDDEN) & (d_best < ratio * d_second)
    a = np.flatnonzero(ok)
    b = best[a]
    if cross_check:
        back = np.argmin(D, axis=0)
        keep = back[b] == a
        a, b = a[keep], b[keep]
    return np.stack([a, b], axis=1).astype(np.int64)


def match_descriptors(
    desc_a: np.ndarray,
    desc_b: np.ndarray,
    ratio: float = 0.8,
    cross_check: bool = True,
    max_hamming: int = 64,
) -> np.ndarray:
    """Match binary descriptors (N, 32) uint8 -> (M, 2) int64 index pairs ``(a, b)``.

    OpenCV's brute-force matcher (two nearest neighbours each way, about 3x
    faster than :func:`match_from_distances` on a numpy distance matrix);
    pairs sorted by index in a.
    """
    desc_a = np.ascontiguousarray(desc_a, dtype=np.uint8)
    desc_b = np.ascontiguousarray(desc_b, dtype=np.uint8)
    if desc_a.ndim != 2 or desc_b.ndim != 2 or desc_a.shape[1:] != desc_b.shape[1:]:
        raise ValueError(f"descriptors must be (N, D) with one D, got {desc_a.shape}, {desc_b.shape}")
    if len(desc_a) < 2 or len(desc_b) < 2:
        return np.zeros((0, 2), np.int64)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    good = [
        (m[0].queryIdx, m[0].trainIdx)
        for m in bf.knnMatch(desc_a, desc_b, k=2)
        if len(m) == 2 and m[0].distance <= max_hamming and m[0].distance < ratio * m[1].distance
    ]
    if not good:
        return np.zeros((0, 2), np.int64)
    pairs = np.asarray(good, np.int64)
    if cross_check:
        back = np.full(len(desc_b), -1, np.int64)
        for m in bf.match(desc_b, desc_a):
            back[m.queryIdx] = m.trainIdx
        pairs = pairs[back[pairs[:, 1]] == pairs[:, 0]]
    return pairs


def epipolar_distances(F: np.ndarray, xy_a: np.ndarray, xy_b: np.ndarray) -> np.ndarray:
    """(Na, Nb) symmetric epipolar distance, pixels, for ``x_b^T F x_a = 0``.

    The larger of the distance of ``x_b`` to the line ``F x_a`` and of ``x_a``
    to ``F^T x_b``: a pair is near its lines in both images.
    """
    ha = np.c_[xy_a, np.ones(len(xy_a))]
    hb = np.c_[xy_b, np.ones(len(xy_b))]
    la = ha @ F.T  # lines in image b, one per point of a
    lb = hb @ F  # lines in image a, one per point of b
    num = np.abs(la @ hb.T)  # |x_b^T F x_a|, (Na, Nb)
    na = np.hypot(la[:, 0], la[:, 1])[:, None]
    nb = np.hypot(lb[:, 0], lb[:, 1])[None, :]
    return num / np.maximum(np.minimum(na, nb), 1e-12)


def epipolar_residuals(F: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """(n,) symmetric epipolar distance, pixels, of matched rows ``pa[i] <-> pb[i]``."""
    ha = np.c_[pa, np.ones(len(pa))]
    hb = np.c_[pb, np.ones(len(pb))]
    la = ha @ F.T
    lb = hb @ F
    num = np.abs(np.sum(la * hb, axis=1))
    den = np.minimum(np.hypot(la[:, 0], la[:, 1]), np.hypot(lb[:, 0], lb[:, 1]))
    return num / np.maximum(den, 1e-12)


def guided_match(
    D: np.ndarray,
    F: np.ndarray,
    xy_a: np.ndarray,
    xy_b: np.ndarray,
    threshold_px: float,
    ratio: float = 0.8,
    cross_check: bool = True,
    max_hamming: int = 64,
) -> np.ndarray:
    """Matches allowed only within ``threshold_px`` of each other's epipolar lines.

    The ratio test then compares neighbours on the same line, so a repeated
    texture elsewhere in the image no longer vetoes a correct match (the point
    of guided matching, Hartley & Zisserman, 2nd ed., Sec. 11.6 step (v)).
    """
    allowed = epipolar_distances(F, xy_a, xy_b) <= threshold_px
    return match_from_distances(np.where(allowed, D, _FORBIDDEN), ratio, cross_check, max_hamming)
