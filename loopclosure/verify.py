"""Geometric verification of a loop-closure candidate (numpy + OpenCV).

Two images that look alike (bag-of-words) are accepted as the same place only
if enough of their ORB matches agree with one two-view geometry, with
thresholds that scale with what the images offer:

1. Matching (:mod:`loopclosure.matching`): Hamming distances, Lowe's ratio
   test, mutual best match (cross-check), a distance cap.
2. Robust fit on the matched pixels, ``method`` ``"magsac"`` (OpenCV's USAC
   MAGSAC++, Barath et al., CVPR 2020: no hard inlier threshold inside the
   fit, the threshold only labels the inliers) or ``"ransac"``, of ``model``:

   - ``"essential"`` (``cv2.findEssentialMat``), needs ``K``; then
     ``cv2.recoverPose`` gives the relative pose of the two views;
   - ``"fundamental"`` (``cv2.findFundamentalMat``), no intrinsics;
   - ``"homography"`` (``cv2.findHomography``), for planar scenes;
   - ``"auto"`` (default): essential when ``K`` is given, else fundamental.

   The threshold is in pixels for all three (with ``distortion`` the points
   are undistorted first and stay in pixels of ``K``).
3. Acceptance of that first fit:

   - an absolute floor, ``min_inliers``: what one epipolar geometry needs to
     be trusted (see the field's comment);
   - a relative one, the a-contrario number of false alarms
     (:func:`loopclosure.acontrario.log10_nfa`, ORSA): the fit must be
     unlikely to arise from that many random matches, ``NFA <= 10^max_log10_nfa``.
4. Guided matching (``guided``): with the epipolar geometry found, every
   feature is matched again among the features near its epipolar line only
   (:func:`loopclosure.matching.guided_match`), and the model is refitted on
   those matches: repeated texture elsewhere no longer vetoes correct
   matches by the ratio test, which matters most on real images.
5. View overlap: the inliers' convex hull must span at least
   ``min_coverage`` of the area of all features' hull in one of the images
   (:func:`loopclosure.acontrario.hull_coverage`): a revisit explains
   most of at least one view; views of one wall from 20-30 degrees apart, or
   of one far facade from 40 m apart, explain a part of each.
6. Forward revisit (essential model, ``max_forward_scale``): a pair below
   ``min_coverage`` is still accepted when the recovered pose says camera a
   drove on into camera b's view, close to b for the scene both see, and
   the inliers explain most of the view the two cameras share:

   - one camera's centre lies in front of the other (the query further
     along the older view's line of sight, or the older view further along
     the query's: a route driven again);
   - the triangulated inliers in front of both cameras are far compared
     with the baseline: the median of ``1 + 1 / rho`` (rho: distance to the
     nearer camera in baselines, a bound on the point's scale change
     between the views) is at most ``max_forward_scale``;
   - in a or in b, the inliers' hull spans at least ``min_coverage`` of the
     part of the image the other camera also sees
     (:func:`loopclosure.acontrario.shared_view_coverage`: the other
     image's features' hull carried over by the relative rotation, widened
     to the inliers).

   A car driving on sees the same street turned by a curve and a few
   metres nearer: the plain coverage counts what the turn took out of
   view, and what came too near to match, as unexplained (KITTI 07 pairs
   1-5 m apart: median coverage 0.67); the forward test removes the turn
   and bounds the approach.

7. Decisive share (``decisive_share``): a pair below both coverage tests is
   still accepted when its inliers are at least a quarter of the features of
   each image (of the one with more). Another place seen from afar fits a geometry with a
   few per cent of the features (KITTI 07 pairs over 40 m apart: at most
   0.057); a street seen again after a turn or from nearer explains a large
   share of them while its inliers' hull misses what left the view. The
   share holds at other feature counts: another place reaches 0.064 at 250
   features and 0.045 at 2000 (``benchmarks/bench_decisive_share.py``).

   Optional older tests, off by default: ``min_inlier_ratio``
   (inliers / matches) and ``min_feature_share`` (inliers / features of the
   image with fewer), the course's "share of matched features".

Pose convention: with ``a`` the first image and ``b`` the second,
``R``/``t_unit`` are ``aTb`` up to scale: ``p_a = R p_b + s t_unit`` maps
points of camera b into camera a (``c_a T c_b``); ``t_unit`` has norm 1 (the
scale is not observable from two views).

Determinism: ``cv2.setRNGSeed(seed)`` is called before every robust fit, so
the same inputs give the same result; matching is exhaustive and deterministic.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import ClassVar, Literal, Protocol, runtime_checkable

import cv2
import numpy as np

from loopclosure.acontrario import hull_coverage, image_extent, log10_nfa, shared_view_coverage
from loopclosure.descriptor_distance import hamming_distances
from loopclosure.matching import epipolar_residuals, guided_match, match_descriptors
from slamcore.config import Gate, Validated, bounded, with_overrides
from slamcore.errors import ConfigError, InputError

__all__ = ["VerifyConfig", "Verification", "PairVerifier", "GeometricVerifier", "MODELS"]

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

_METHODS = {"magsac": cv2.USAC_MAGSAC, "ransac": cv2.RANSAC}


@dataclass(frozen=True)
class VerifyConfig(Validated):
    """Geometric verification settings (config section ``[loop_verify]``).

    Attributes:
        model: ``"auto"`` (essential with K, else fundamental), ``"essential"``,
            ``"fundamental"`` or ``"homography"``.
        method: robust estimator, ``"magsac"`` (MAGSAC++) or ``"ransac"``.
        ratio: Lowe ratio (best / second-best Hamming distance must be below it).
        cross_check: keep only mutual best matches.
        max_hamming: largest Hamming distance of a kept match (bits of 256).
        ransac_threshold_px: inlier threshold, pixels (epipolar distance, or
            reprojection error for the homography); also the width of the
            band round an epipolar line in guided matching.
        confidence: RANSAC confidence.
        max_iters: RANSAC iteration cap.
        min_inliers: fewest inliers of the first fit to accept.
        max_log10_nfa: largest log10 of the a-contrario number of false alarms.
        guided: re-match along the epipolar lines and refit.
        min_coverage: smallest share of the features' convex hull spanned by
            the inliers' hull, in the image where it is larger (0 turns the test off).
        max_forward_scale: forward revisit (step 6 of the module doc), the
            largest median scale change of the inliers between the views
            (0 turns the forward revisit off).
        decisive_share: a pair below both coverage tests (steps 5 and 6) is
            still accepted when its inliers are at least this share of the
            features of each image (step 7); 0 turns it off.
        min_inlier_ratio: smallest inliers / matches (0 turns the test off).
        min_feature_share: smallest inliers / features of the image with fewer
            features (0 turns the test off).
        seed: seed of OpenCV's RNG before each robust fit.
    """

    SECTION: ClassVar[str] = "loop_verify"
    GATES: ClassVar[tuple[Gate, ...]] = (
        # step 6 recovers a pose (essential only) for pairs below min_coverage
        Gate(
            ("max_forward_scale",),
            'min_coverage > 0 and model = "essential" or "auto" (with intrinsics)',
            lambda c: c.min_coverage > 0 and c.model in ("essential", "auto"),
        ),
        # step 7 waives the coverage tests: nothing to waive without them
        Gate(("decisive_share",), "min_coverage > 0", lambda c: c.min_coverage > 0),
    )

    model: Model = "auto"
    method: Literal["magsac", "ransac"] = "magsac"
    # Lowe (IJCV 2004, Fig. 11): 0.8 drops 90 % of false matches, < 5 % of true ones
    ratio: float = bounded(0.8, gt=0.0, max=1.0)
    cross_check: bool = True
    # 64 of 256 bits: ORB-SLAM's TH_HIGH (100) is for its guided search; 64 keeps
    # the distance of true ORB matches (Rublee et al. 2011, Fig. 3: mostly < 64)
    max_hamming: int = bounded(64, min=0, max=256)
    # ORB keypoints at pyramid level 0 are located to about 1 px (ORB-SLAM's
    # sigma = 1 px at level 0); chi2(1 dof, 95 %) = 3.84 gives 1.96 sigma, ~2 px
    ransac_threshold_px: float = bounded(2.0, gt=0.0)
    confidence: float = bounded(0.999, gt=0.0, lt=1.0)
    max_iters: int = bounded(5000, min=1, max=MAX_RANSAC_ITERS)
    # ORB-SLAM (Mur-Artal et al., T-RO 2015, Sec. VII-B; LoopClosing.cc) accepts a
    # loop candidate from 20 RANSAC inliers; it is also 2.5x the 8-point minimum
    min_inliers: int = bounded(20, min=1)
    # NFA <= 1: fewer than one such fit expected by chance (Moisan & Stival 2004)
    max_log10_nfa: float = 0.0
    guided: bool = True
    # A revisit explains most of a view: the inliers' convex hull spans at
    # least two thirds of the area of all features' hull in one of the two
    # images (the larger share: a camera further along the same line of sight
    # sees part of the other view, all of its own). Measured with the
    # 1000-feature loop ORB, larger share: the desk's true pair 0.77, the
    # desk's overlapping neighbours <= 0.38; the 66 Lund door pairs: median
    # 0.83; KITTI 07 pairs 1-5 m apart: median 0.67; synthetic views of one
    # wall 0.7-0.9 m and 20-30 deg from a revisit <= 0.60, true synthetic
    # revisits >= 0.76. KITTI 07 pairs more than 40 m apart (all 9694 ordered
    # pairs of frames 0-159, 2026-12-02): 247 fit one geometry, at up to 0.666
    # (frames 58 and 110, 42.2 m apart, a pose 8 deg off the truth): the
    # threshold has no margin there (an earlier note said <= 0.39). A looser
    # measure (the features' hull peeled once) verified 458 of the 612 near
    # pairs and accepted that pair: not kept.
    min_coverage: float = bounded(2 / 3, min=0.0, max=1.0)
    # Forward revisit (step 6): largest median scale change 1 + 1/rho of the
    # inliers. 1.2 = one pyramid level of the loop ORB (OrbConfig.scale_factor):
    # a feature seen at most one level apart is one the descriptor matches
    # reliably (the median inlier at least 5 baselines from the nearer camera).
    # The false candidates that pass every other forward test (one camera ahead,
    # shared-view coverage >= 2/3) change scale by >= 1.34 (views of the
    # synthetic room 1-8 m apart that the loop detector verifies). KITTI 07
    # pairs more than 40 m apart (2026-12-02, all ordered pairs): 8 pass every
    # other forward test, at 1.2004 (58 and 110, the wrong pose above), 1.25 and
    # 1.43-1.93 (an earlier note said >= 1.44); a ninth, 125 and 72 (40.1 m), is
    # accepted by the plain coverage with a right pose (1.2 deg, 3.5 deg of
    # direction off: the same houses). Not fitted to KITTI's near pairs: 1.25
    # would verify 437 of its 612 pairs 1-5 m apart, 1.2 verifies 424.
    max_forward_scale: float = bounded(1.2, min=0.0)
    # A view of another place never explains a large share of the features: of
    # the 9694 ordered KITTI 07 pairs of frames 0-159 over 40 m apart (the same
    # houses, facades and trees further down the road, 2026-12-02), the 247 that
    # fit one geometry have at most 57 inliers of 1000 features (0.057); no pair
    # of the 770 across image sets fits one; the desk's overlapping neighbours
    # reach 0.117 (frames 4 and 5). A quarter is 4x the worst other place and 2x
    # the desk's neighbours. The KITTI pairs 1-5 m apart that fail both coverage
    # tests keep 28-483 inliers: the car turned or came near, so the hull
    # misses what left the view, while the matches say it is the same street.
    decisive_share: float = bounded(0.25, min=0.0, max=1.0)
    min_inlier_ratio: float = bounded(0.0, min=0.0, max=1.0)
    min_feature_share: float = bounded(0.0, min=0.0, max=1.0)
    seed: int = bounded(0, min=0, max=MAX_SEED)


@dataclass(frozen=True, eq=False)
class Verification:
    """Outcome of verifying one image pair.

    Attributes:
        accepted: whether the pair passed.
        reason: why it was rejected (None when accepted).
        model: model used (``"essential"``, ``"fundamental"``, ``"homography"``).
        n_matches: descriptor matches of the first (unguided) matching.
        n_inliers: inliers of the final fit (after guided matching when guided).
        inlier_ratio: inliers / matches of the final fit (0 without matches).
        R: (3, 3) rotation of ``aTb`` (essential model with K), else None; from the
            inliers' homography when under half of them triangulate in front of both
            cameras and the essential matrix's pose turns more than 90 degrees from it
            (too little parallax: that pose was the twisted pair).
        t_unit: (3,) unit translation of ``aTb``, else None (also None in that case).
        inlier_pairs: (n_inliers, 2) int64 feature indices ``(index in a, index in b)``.
        log10_nfa: a-contrario log10 NFA of the first fit (None before a fit).
        coverage: larger hull coverage of the two images (None before it was
            measured); for a pair accepted as a forward revisit (step 6 of the
            module doc), the larger coverage of the view the two cameras share.
        accepted_by: which test accepted the view overlap of an accepted pair:
            ``"coverage"`` (step 5, also when that test is off), ``"forward revisit"``
            (step 6) or ``"decisive share"`` (step 7); None when rejected.
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
    log10_nfa: float | None = None
    coverage: float | None = None
    accepted_by: str | None = None


def _as_fundamental(model: str, M: np.ndarray, K: np.ndarray | None) -> np.ndarray:
    """F with ``x_b^T F x_a = 0`` in pixels (E of pixels of K becomes K^-T E K^-1)."""
    if model == "essential":
        if K is None:
            raise ConfigError("loop_verify.model 'essential' needs the intrinsics K")
        Ki = np.linalg.inv(K)
        return Ki.T @ M @ Ki
    return M


def _residuals(model: str, M: np.ndarray, K, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """(n,) pixel residuals of matched points: symmetric epipolar distance, or transfer error."""
    if model == "homography":
        proj = cv2.perspectiveTransform(pa.reshape(-1, 1, 2), M).reshape(-1, 2)
        return np.linalg.norm(proj - pb, axis=1)
    return epipolar_residuals(_as_fundamental(model, M, K), pa, pb)


@runtime_checkable
class PairVerifier(Protocol):
    """What the loop detector asks of a verifier: is this image pair one place?

    :class:`GeometricVerifier` is the toolkit's; another (a learned matcher, a
    stricter geometry, a scripted one in tests) is given to
    :class:`loopclosure.detector.LoopDetector` as ``verifier=``, as GTSFM injects
    its verifiers. ``xy_*``: (N, 2) pixels (column, row); ``desc_*``: (N, 32)
    uint8 ORB descriptors; ``K`` (3, 3) or None; ``distortion`` OpenCV
    coefficients or None; ``size_*`` (width, height) in pixels or None. The
    answer's ``R``/``t_unit`` (the relative pose of the views) may be None; the
    detector keeps them for the closure when given. ``tests/loopclosure/test_verifier_contract.py``
    holds the contract every implementation passes.
    """

    def verify(
        self,
        xy_a: np.ndarray,
        desc_a: np.ndarray,
        xy_b: np.ndarray,
        desc_b: np.ndarray,
        K: np.ndarray | None = None,
        distortion: np.ndarray | None = None,
        size_a: tuple[float, float] | None = None,
        size_b: tuple[float, float] | None = None,
    ) -> Verification: ...


def _checked_view(xy, desc, which: str) -> tuple[np.ndarray, np.ndarray]:
    """One view's ``(xy (N, 2) float64, desc (N, 32) uint8)``, contiguous; InputError
    for other shapes or types (float descriptors were cast to uint8 without a word, and
    a count that differs from the points' indexed past them)."""
    # np.ndarray, not NDArray[float64]: cv2's stubs type undistortPoints' result loosely
    xy_px: np.ndarray = np.asarray(xy, np.float64)
    d = np.asarray(desc)
    if d.dtype != np.uint8 or d.ndim != 2 or d.shape[1] != 32:
        raise InputError(f"view {which}: descriptors must be (N, 32) uint8 (ORB), got {d.dtype} {d.shape}")
    if xy_px.shape != (len(d), 2):
        raise InputError(f"view {which}: {len(d)} descriptors need ({len(d)}, 2) points, got {xy_px.shape}")
    return xy_px, np.ascontiguousarray(d)


def _checked_camera(K, distortion) -> np.ndarray:
    """``K`` as a contiguous finite (3, 3) float64 and a distortion OpenCV takes, or InputError."""
    K = np.ascontiguousarray(K, np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise InputError(f"K must be a finite (3, 3) matrix, got shape {K.shape}")
    n_dist = None if distortion is None else np.asarray(distortion).size
    if n_dist is not None and n_dist not in (4, 5, 8, 12, 14):
        raise InputError(f"distortion must hold 4, 5, 8, 12 or 14 coefficients (OpenCV's), got {n_dist}")
    return K


def _angle_deg(R: np.ndarray) -> float:
    """Rotation angle of ``R`` (3, 3), degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def _rotation_from_homography(pa: np.ndarray, pb: np.ndarray, K: np.ndarray) -> np.ndarray | None:
    """``R`` of ``aTb`` from the homography ``pa ~ K R K^-1 pb`` fitted to all the inliers
    (least squares: they are inliers already), projected on SO(3); None if it cannot be
    fitted or is no rotation (``K^-1 H K`` of a rotation has equal singular values; under
    half the largest, e.g. the rank-1 fit of collinear points, it is none)."""
    H, _ = cv2.findHomography(pb.astype(np.float64), pa.astype(np.float64), 0)
    if H is None or H.shape != (3, 3) or not np.all(np.isfinite(H)):
        return None
    U, S, Vt = np.linalg.svd(np.linalg.inv(K) @ H @ K)
    if not S[2] >= 0.5 * S[0]:
        return None
    R = U @ Vt
    return R if np.linalg.det(R) > 0 else -R


class GeometricVerifier:
    """ORB matching + robust fit + acceptance thresholds (:class:`VerifyConfig`).

    ``GeometricVerifier(config)`` or ``GeometricVerifier(min_inliers=20, ...)``
    (keyword overrides of :class:`VerifyConfig`).
    """

    def __init__(self, config: VerifyConfig | None = None, **overrides):
        self.config = with_overrides(config or VerifyConfig(), overrides, VerifyConfig)

    def _fit(self, model: str, pa: np.ndarray, pb: np.ndarray, K):
        """Robust fit -> (3x3 model or None, (n,) bool inlier mask or None)."""
        c = self.config
        method = _METHODS[c.method]
        cv2.setRNGSeed(int(c.seed))  # sampling repeats run to run
        try:
            if model == "essential":
                M, mask = cv2.findEssentialMat(
                    pa,
                    pb,
                    K,
                    method=method,
                    prob=c.confidence,
                    threshold=c.ransac_threshold_px,
                    maxIters=c.max_iters,
                )
            elif model == "fundamental":
                M, mask = cv2.findFundamentalMat(
                    pa, pb, method, c.ransac_threshold_px, c.confidence, c.max_iters
                )
            else:
                M, mask = cv2.findHomography(
                    pa, pb, method, c.ransac_threshold_px, maxIters=c.max_iters, confidence=c.confidence
                )
        except cv2.error:
            # USAC asserts (!model.empty()) when its local optimisation of a degenerate set
            # finds no model, where it should return none: desk photos 4 and 5 at 250 ORB
            # features, fundamental; no geometry fits, as OpenCV would otherwise say
            return None, None
        # OpenCV may return several stacked 3x3 solutions; the first is its best.
        if M is not None and M.shape[0] > 3:
            M = M[:3]
        if M is None or mask is None or M.shape != (3, 3):
            return None, None
        return M, mask.reshape(-1).astype(bool)

    def verify(
        self,
        xy_a: np.ndarray,
        desc_a: np.ndarray,
        xy_b: np.ndarray,
        desc_b: np.ndarray,
        K: np.ndarray | None = None,
        distortion: np.ndarray | None = None,
        size_a: tuple[float, float] | None = None,
        size_b: tuple[float, float] | None = None,
    ) -> Verification:
        """Verify images a and b from their features.

        ``xy_*``: (N, 2) pixel coordinates (column, row); ``desc_*``: (N, 32)
        uint8 ORB descriptors; ``K`` (3, 3) intrinsics (both images), or None;
        ``distortion``: OpenCV coefficients ``(k1, k2, p1, p2[, k3])`` or None;
        ``size_*``: (width, height) of each image in pixels (default: the
        extent of its features).
        """
        c = self.config
        model = c.model
        if model == "auto":
            model = "essential" if K is not None else "fundamental"
        if model == "essential" and K is None:
            raise ConfigError("loop_verify.model 'essential' needs the intrinsics K")
        # USAC reads K's memory as contiguous: a strided view (a slice of P) gives no model
        K = None if K is None else _checked_camera(K, distortion)
        ua, desc_a = _checked_view(xy_a, desc_a, "a")
        ub, desc_b = _checked_view(xy_b, desc_b, "b")
        size_a = size_a or image_extent(ua)
        size_b = size_b or image_extent(ub)
        pairs = match_descriptors(desc_a, desc_b, c.ratio, c.cross_check, c.max_hamming)
        n = len(pairs)
        need = max(_MIN_POINTS[model], c.min_inliers)
        if n < need:
            return self._reject(model, n, 0, pairs[:0], f"too few matches ({n} < {need})")
        if K is not None and distortion is not None:
            dist = np.asarray(distortion, np.float64)
            ua = cv2.undistortPoints(ua.reshape(-1, 1, 2), K, dist, P=K).reshape(-1, 2)
            ub = cv2.undistortPoints(ub.reshape(-1, 1, 2), K, dist, P=K).reshape(-1, 2)
        M, inl = self._fit(model, ua[pairs[:, 0]], ub[pairs[:, 1]], K)
        if M is None:
            return self._reject(model, n, 0, pairs[:0], "RANSAC found no model")
        n_in = int(inl.sum())
        if n_in < c.min_inliers:
            return self._reject(model, n, n_in, pairs[inl], f"too few inliers ({n_in} < {c.min_inliers})")
        res = _residuals(model, M, K, ua[pairs[:, 0]], ub[pairs[:, 1]])
        # the image where a random point lands near a line most easily (largest
        # diagonal / area): the more conservative of the two backgrounds
        size = max(size_a, size_b, key=lambda s: np.hypot(*s) / (s[0] * s[1]))
        lnfa, _ = log10_nfa(res, model, *size)
        if lnfa > c.max_log10_nfa:
            return self._reject(
                model,
                n,
                n_in,
                pairs[inl],
                f"not meaningful (log10 NFA {lnfa:.1f} > {c.max_log10_nfa:g})",
                lnfa,
            )
        n_first = n
        if c.guided and model != "homography":
            D = hamming_distances(desc_a, desc_b)
            gpairs = guided_match(
                D,
                _as_fundamental(model, M, K),
                ua,
                ub,
                c.ransac_threshold_px,
                c.ratio,
                c.cross_check,
                c.max_hamming,
            )
            if len(gpairs) >= need:
                M2, inl2 = self._fit(model, ua[gpairs[:, 0]], ub[gpairs[:, 1]], K)
                if M2 is not None and inl2.sum() >= n_in:
                    pairs, M, inl = gpairs, M2, inl2
        return self._accept_or_reject(model, M, K, ua, ub, pairs, inl, lnfa, n_first)

    def _accept_or_reject(self, model, M, K, ua, ub, pairs, inl, lnfa, n) -> Verification:
        c = self.config
        n_in = int(inl.sum())
        ipairs = pairs[inl]
        ratio = n_in / len(pairs)
        if ratio < c.min_inlier_ratio:
            return self._reject(
                model, n, n_in, ipairs, f"inlier ratio too low ({ratio:.2f} < {c.min_inlier_ratio:.2f})", lnfa
            )
        share = n_in / max(min(len(ua), len(ub)), 1)
        if share < c.min_feature_share:
            return self._reject(
                model,
                n,
                n_in,
                ipairs,
                f"feature share too low ({share:.2f} < {c.min_feature_share:.2f})",
                lnfa,
            )
        pa, pb = ua[ipairs[:, 0]], ub[ipairs[:, 1]]
        cov = max(hull_coverage(ua, pa), hull_coverage(ub, pb))
        R = t = None
        if model == "essential" and n_in >= 5:
            # recoverPose(E, p1, p2) returns 2T1; with p1 = b, p2 = a that is aTb.
            # findEssentialMat(pa, pb) gives pb^T E pa = 0, so E.T relates b -> a.
            n_front, R, t, _ = cv2.recoverPose(M.T, pb, pa, K)
            t = t.reshape(3) / max(np.linalg.norm(t), 1e-12)
            if n_front < n_in / 2:
                # Few inliers decided E's pose by cheirality. With too little parallax
                # (cameras a few cm apart, the scene metres away) it can be the twisted
                # pair, 180 deg off: the synthetic room's (220, 20) with 0 of 749 inliers
                # in front. The views then differ by a rotation, which the inliers'
                # homography K R K^-1 gives; the translation direction is not observable.
                # Rotations more than 90 deg apart can only be that flip (halfway to it).
                R_h = _rotation_from_homography(pa, pb, K)
                if R_h is not None and _angle_deg(R.T @ R_h) > 90.0:
                    R, t = R_h, None
        if cov < c.min_coverage:
            fwd, why = self._forward_revisit(K, R, t, ua, ub, pa, pb)
            if fwd is None or fwd < c.min_coverage:
                why = why or f"forward coverage {fwd:.2f} < {c.min_coverage:.2f}"
                if c.decisive_share > 0:
                    # of each image: a view with few features (low texture) does not make
                    # a far facade's inliers a large share
                    both = n_in / max(len(ua), len(ub), 1)
                    if both >= c.decisive_share:
                        return Verification(
                            True, None, model, n, n_in, ratio, R, t, ipairs, lnfa, cov, "decisive share"
                        )
                    why = f"{why}; feature share {both:.2f} < {c.decisive_share:.2f}"
                return self._reject(
                    model,
                    n,
                    n_in,
                    ipairs,
                    f"view overlap too small (coverage {cov:.2f} < {c.min_coverage:.2f}; {why})",
                    lnfa,
                    cov,
                )
            return Verification(True, None, model, n, n_in, ratio, R, t, ipairs, lnfa, fwd, "forward revisit")
        return Verification(True, None, model, n, n_in, ratio, R, t, ipairs, lnfa, cov, "coverage")

    def _forward_revisit(self, K, R, t, ua, ub, pa, pb) -> tuple[float | None, str | None]:
        """Step 6 of the module doc: ``(larger shared-view coverage, None)``, or
        ``(None, why not)`` when the pose is not a forward revisit."""
        c = self.config
        if c.max_forward_scale <= 0 or R is None or t is None:
            return None, "no forward test without a relative pose"
        centre_a = -R.T @ t  # a's centre in b's frame (p_a = R p_b + t), one baseline from b's
        # either order: the query drove on into the older view, or the older view lies
        # further along the query's line of sight (a route driven again, the older frame
        # a little ahead); t is b's centre in a's frame
        if centre_a[2] <= 0 and t[2] <= 0:
            return None, "neither camera is ahead of the other"
        X = cv2.triangulatePoints(
            K @ np.eye(3, 4), K @ np.c_[R, t], pb.T.astype(np.float64), pa.T.astype(np.float64)
        )
        X = (X[:3] / X[3]).T
        front = (X[:, 2] > 0) & ((X @ R.T + t)[:, 2] > 0)
        if front.sum() < c.min_inliers:
            return None, f"{int(front.sum())} inliers in front of both cameras"
        # distances in baselines (|t| = 1): a point rho baselines from the nearer
        # camera is at most (rho + 1) / rho times as far from the other one (its
        # scale change), and seen from directions at most asin(1 / rho) apart
        rho = np.minimum(np.linalg.norm(X[front], axis=1), np.linalg.norm(X[front] - centre_a, axis=1))
        scale = float(np.median(1.0 + 1.0 / np.maximum(rho, 1e-12)))
        if scale > c.max_forward_scale:
            return None, f"median scale change {scale:.2f} > {c.max_forward_scale:g}"
        # the larger share, as the plain coverage: in a, which drove on into b's
        # view, and in b (whose part seen by a shrinks at finite depth: pessimistic)
        return max(shared_view_coverage(ua, pa, ub, K, R), shared_view_coverage(ub, pb, ua, K, R.T)), None

    @staticmethod
    def _reject(model, n, n_in, inlier_pairs, reason, lnfa=None, cov=None) -> Verification:
        return Verification(
            False,
            reason,
            model,
            int(n),
            int(n_in),
            n_in / n if n else 0.0,
            None,
            None,
            inlier_pairs,
            lnfa,
            cov,
        )
