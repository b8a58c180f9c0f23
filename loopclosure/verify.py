"""Geometric verification of a loop-closure candidate (numpy + OpenCV).

Two images that look alike (bag-of-words) are accepted as the same place only
if enough of their ORB matches agree with one two-view geometry:

1. Matching (:func:`match_descriptors`): brute-force Hamming
   (``cv2.BFMatcher(cv2.NORM_HAMMING)``), two nearest neighbours each way;
   a match ``(a, b)`` is kept when it passes Lowe's ratio test
   (``d1 < ratio * d2``), is mutual (``b``'s best match in image a is ``a``:
   cross-check) and its distance is at most ``max_hamming`` bits.
2. RANSAC on the matched pixels, with ``model``:

   - ``"essential"`` (``cv2.findEssentialMat``), needs ``K``; then
     ``cv2.recoverPose`` gives the relative pose of the two views;
   - ``"fundamental"`` (``cv2.findFundamentalMat``), no intrinsics;
   - ``"homography"`` (``cv2.findHomography``), for planar scenes;
   - ``"auto"`` (default): essential when ``K`` is given, else fundamental.

   The RANSAC threshold is in pixels for all three (OpenCV's essential
   matrix takes pixel coordinates and ``K``; with ``distortion`` the points
   are undistorted first and stay in pixels of ``K``).
3. Acceptance: at least ``min_inliers`` inliers, an inlier ratio
   (inliers / matches) of at least ``min_inlier_ratio``, and a feature share
   (inliers / features of the image with fewer) of at least
   ``min_feature_share``: the course's "share of matched features". The share
   is what separates a revisit from a view of the same far wall from a few
   metres further on (same scene, little overlap): on the synthetic sequence
   true revisits share >= 0.36 of 1000 ORB features, such look-alikes
   <= 0.27. It depends on the overlap a closure needs, so it is a loop-closure
   setting: set it to 0 to verify wide-baseline pairs.

Pose convention: with ``a`` the first image and ``b`` the second,
``R``/``t_unit`` are ``aTb`` up to scale: ``p_a = R p_b + s t_unit`` maps
points of camera b into camera a (``c_a T c_b``); ``t_unit`` has norm 1 (the
scale is not observable from two views).

Determinism: ``cv2.setRNGSeed(seed)`` is called before every RANSAC, so the
same inputs give the same result; matching is exhaustive and deterministic.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass
from typing import ClassVar, Literal

import cv2
import numpy as np

from slamcore.config import bounded, validate
from slamcore.errors import ConfigError

__all__ = ["VerifyConfig", "Verification", "GeometricVerifier", "match_descriptors", "MODELS"]

#: RANSAC models the verifier knows.
Model = Literal["auto", "essential", "fundamental", "homography"]
MODELS = typing.get_args(Model)

#: Most RANSAC iterations a config may ask for. A hopeless pair runs all of
#: them; 10^6 already covers 5-point samples at 10 % inliers with 99.9 %
#: confidence (ln(0.001) / ln(1 - 0.1^5), about 690 000), and costs minutes per pair
#: (about 0.2 ms per essential-matrix iteration on 300 matches).
MAX_RANSAC_ITERS = 1_000_000

#: Largest seed of OpenCV's RNG (``cv2.setRNGSeed`` takes a C int).
MAX_SEED = 2**31 - 1

#: Fewest points each OpenCV estimator needs (5-point E, 7/8-point F, 4-point H),
#: with a margin: RANSAC on the bare minimum always "succeeds".
_MIN_POINTS = {"essential": 8, "fundamental": 8, "homography": 6}


@dataclass(frozen=True)
class VerifyConfig:
    """Geometric verification settings (config section ``[loop_verify]``).

    Attributes:
        model: ``"auto"`` (essential with K, else fundamental), ``"essential"``,
            ``"fundamental"`` or ``"homography"``.
        ratio: Lowe ratio (best / second-best Hamming distance must be below it).
        cross_check: keep only mutual best matches.
        max_hamming: largest Hamming distance of a kept match (bits of 256).
        ransac_threshold_px: RANSAC inlier threshold, pixels (epipolar distance,
            or reprojection error for the homography).
        confidence: RANSAC confidence.
        max_iters: RANSAC iteration cap.
        min_inliers: fewest inliers to accept.
        min_inlier_ratio: smallest inliers / matches to accept.
        min_feature_share: smallest inliers / features of the image with fewer
            features (0 turns the test off).
        seed: seed of OpenCV's RNG before each RANSAC.
    """

    SECTION: ClassVar[str] = "loop_verify"

    model: Model = "auto"
    ratio: float = bounded(0.8, gt=0.0, max=1.0)
    cross_check: bool = True
    # a Hamming distance between 256-bit descriptors
    max_hamming: int = bounded(64, min=0, max=256)
    ransac_threshold_px: float = bounded(1.0, gt=0.0)
    confidence: float = bounded(0.999, gt=0.0, lt=1.0)
    max_iters: int = bounded(5000, min=1, max=MAX_RANSAC_ITERS)
    min_inliers: int = bounded(40, min=1)
    min_inlier_ratio: float = bounded(0.35, min=0.0, max=1.0)
    min_feature_share: float = bounded(0.3, min=0.0, max=1.0)
    seed: int = bounded(0, min=0, max=MAX_SEED)

    def __post_init__(self):
        validate(self)


@dataclass(frozen=True, eq=False)
class Verification:
    """Outcome of verifying one image pair.

    Attributes:
        accepted: whether the pair passed.
        reason: why it was rejected (None when accepted).
        model: RANSAC model used (``"essential"``, ``"fundamental"``, ``"homography"``).
        n_matches: descriptor matches after ratio test and cross-check.
        n_inliers: RANSAC inliers among them.
        inlier_ratio: ``n_inliers / n_matches`` (0 without matches).
        R: (3, 3) rotation of ``aTb`` (essential model with K), else None.
        t_unit: (3,) unit translation of ``aTb``, else None.
        inlier_pairs: (n_inliers, 2) int64 feature indices ``(index in a, index in b)``.
    """

    accepted: bool
    reason: str | None
    model: str
    n_matches: int
    n_inliers: int
    inlier_ratio: float
    R: np.ndarray | None
    t_unit: np.ndarray | None
    inlier_pairs: np.ndarray


def match_descriptors(desc_a: np.ndarray, desc_b: np.ndarray, ratio: float = 0.8,
                      cross_check: bool = True, max_hamming: int = 64) -> np.ndarray:
    """Match binary descriptors (N, 32) uint8 -> (M, 2) int64 index pairs ``(a, b)``.

    Lowe ratio test on the two nearest neighbours, optional mutual check,
    distance cap; pairs sorted by index in a.
    """
    desc_a = np.ascontiguousarray(desc_a, dtype=np.uint8)
    desc_b = np.ascontiguousarray(desc_b, dtype=np.uint8)
    if desc_a.ndim != 2 or desc_b.ndim != 2 or desc_a.shape[1:] != desc_b.shape[1:]:
        raise ValueError(f"descriptors must be (N, D) with one D, got {desc_a.shape}, {desc_b.shape}")
    if len(desc_a) < 2 or len(desc_b) < 2:
        return np.zeros((0, 2), np.int64)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    ab = bf.knnMatch(desc_a, desc_b, k=2)
    pairs = []
    for m in ab:
        if len(m) < 2:
            continue
        best, second = m
        if best.distance <= max_hamming and best.distance < ratio * second.distance:
            pairs.append((best.queryIdx, best.trainIdx))
    if not pairs:
        return np.zeros((0, 2), np.int64)
    pairs = np.asarray(pairs, np.int64)
    if cross_check:
        ba = bf.match(desc_b, desc_a)
        back = np.full(len(desc_b), -1, np.int64)
        for m in ba:
            back[m.queryIdx] = m.trainIdx
        pairs = pairs[back[pairs[:, 1]] == pairs[:, 0]]
    return pairs


class GeometricVerifier:
    """ORB matching + RANSAC + acceptance thresholds (:class:`VerifyConfig`).

    ``GeometricVerifier(config)`` or ``GeometricVerifier(min_inliers=20, ...)``
    (keyword overrides of :class:`VerifyConfig`).
    """

    def __init__(self, config: VerifyConfig | None = None, **overrides):
        config = config or VerifyConfig()
        if overrides:
            config = dataclasses.replace(config, **overrides)
        self.config = config

    def verify(self, xy_a: np.ndarray, desc_a: np.ndarray, xy_b: np.ndarray, desc_b: np.ndarray,
               K: np.ndarray | None = None, distortion: np.ndarray | None = None) -> Verification:
        """Verify images a and b from their features.

        ``xy_*``: (N, 2) pixel coordinates (column, row); ``desc_*``: (N, 32)
        uint8 ORB descriptors; ``K`` (3, 3) intrinsics (both images), or None;
        ``distortion``: OpenCV coefficients ``(k1, k2, p1, p2[, k3])`` or None.
        """
        c = self.config
        model = c.model
        if model == "auto":
            model = "essential" if K is not None else "fundamental"
        if model == "essential" and K is None:
            raise ConfigError("loop_verify.model 'essential' needs the intrinsics K")
        xy_a = np.asarray(xy_a, np.float64).reshape(-1, 2)
        xy_b = np.asarray(xy_b, np.float64).reshape(-1, 2)
        pairs = match_descriptors(desc_a, desc_b, c.ratio, c.cross_check, c.max_hamming)
        n = len(pairs)
        if n < max(_MIN_POINTS[model], c.min_inliers):
            need = max(_MIN_POINTS[model], c.min_inliers)
            return self._reject(model, n, 0, pairs[:0], f"too few matches ({n} < {need})")
        pa, pb = xy_a[pairs[:, 0]], xy_b[pairs[:, 1]]
        if K is not None and distortion is not None:
            K = np.asarray(K, np.float64)
            dist = np.asarray(distortion, np.float64)
            pa = cv2.undistortPoints(pa.reshape(-1, 1, 2), K, dist, P=K).reshape(-1, 2)
            pb = cv2.undistortPoints(pb.reshape(-1, 1, 2), K, dist, P=K).reshape(-1, 2)
        cv2.setRNGSeed(int(c.seed))  # RANSAC sampling repeats run to run
        R = t = None
        if model == "essential":
            K = np.asarray(K, np.float64)
            E, mask = cv2.findEssentialMat(pa, pb, K, method=cv2.RANSAC, prob=c.confidence,
                                           threshold=c.ransac_threshold_px, maxIters=c.max_iters)
            # OpenCV may return several stacked 3x3 solutions; the first is its best.
            if E is not None and E.shape[0] > 3:
                E = E[:3]
        elif model == "fundamental":
            E, mask = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, c.ransac_threshold_px,
                                             c.confidence, c.max_iters)
            if E is not None and E.shape[0] > 3:
                E = E[:3]
        else:
            E, mask = cv2.findHomography(pa, pb, cv2.RANSAC, c.ransac_threshold_px,
                                         maxIters=c.max_iters, confidence=c.confidence)
        if E is None or mask is None or E.shape != (3, 3):
            return self._reject(model, n, 0, pairs[:0], "RANSAC found no model")
        inl = mask.reshape(-1).astype(bool)
        n_in = int(inl.sum())
        if model == "essential" and n_in >= 5:
            # recoverPose(E, p1, p2) returns 2T1; with p1 = b, p2 = a that is aTb.
            # findEssentialMat(pa, pb) gives pb^T E pa = 0, so E.T relates b -> a.
            _, R, t, _ = cv2.recoverPose(E.T, pb[inl], pa[inl], K)
            t = t.reshape(3) / max(np.linalg.norm(t), 1e-12)
        ratio = n_in / n
        if n_in < c.min_inliers:
            return self._reject(model, n, n_in, pairs[inl], f"too few inliers ({n_in} < {c.min_inliers})")
        if ratio < c.min_inlier_ratio:
            return self._reject(model, n, n_in, pairs[inl],
                                f"inlier ratio too low ({ratio:.2f} < {c.min_inlier_ratio:.2f})")
        share = n_in / max(min(len(xy_a), len(xy_b)), 1)
        if share < c.min_feature_share:
            return self._reject(model, n, n_in, pairs[inl],
                                f"feature share too low ({share:.2f} < {c.min_feature_share:.2f})")
        return Verification(True, None, model, n, n_in, ratio, R, t, pairs[inl])

    @staticmethod
    def _reject(model, n, n_in, inlier_pairs, reason) -> Verification:
        return Verification(False, reason, model, int(n), int(n_in), n_in / n if n else 0.0,
                            None, None, inlier_pairs)
