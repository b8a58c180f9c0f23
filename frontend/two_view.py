"""Monocular two-view initialisation, as ORB-SLAM's initializer (numpy + OpenCV).

Mur-Artal, Montiel & Tardos, "ORB-SLAM", T-RO 2015, Sec. IV, with OpenCV's
solvers in place of the hand-written ones:

1. Two robust fits (USAC MAGSAC++) on all correspondences: a homography and an
   essential matrix. USAC ignores ``cv2.setRNGSeed`` and seeds its own
   generator from ``UsacParams.randomGeneratorState`` (0 for the ``USAC_*``
   flags), so the fits pass ``seed`` there: the same seed gives the same bits,
   another seed another sample sequence.
2. ORB-SLAM's scores over all correspondences, in units of the pixels' sigma
   (``sigma_px``, ORB-SLAM's 1 px by default): for H the
   symmetric transfer error, each direction's chi2 truncated at 5.991 (2 dof,
   95 %); for F = K^-T E K^-1 the distance to each epipolar line, truncated at
   3.841 (1 dof); every term within adds ``5.991 - chi2``. The model's inliers
   are ORB-SLAM's too (both terms within: 2.45 px each way for H, 1.96 px from
   each line for F), not the MAGSAC mask: at ``ransac_threshold_px`` = 1 px
   that drops ~40 % of the true points of a homography at 0.5 px noise.
3. ``R_H = S_H / (S_H + S_F) > homography_ratio`` (a plane, or low parallax):
   the pose is the decomposition of H (``cv2.decomposeHomographyMat``, up to
   four) that triangulates most inliers well, and it must clearly beat the
   second (second < 0.75 x best, ORB-SLAM's ReconstructH), else not ok; a
   plane seen from two views has two physical decompositions, and only
   chirality (points behind a camera) tells them apart. Otherwise the pose is
   ``cv2.recoverPose`` of E on its inliers.
4. The inliers are triangulated and kept when in front of both cameras,
   reprojected within ``max_reprojection_sigmas`` in both views and seen under a
   parallax > 0; ok needs ``min_points`` kept points, ``min_points`` of them
   (or half of them, whichever is fewer) seen under a parallax of at least
   ``min_parallax_deg``. ORB-SLAM's test is its 50th-largest parallax above
   1 deg, among the hundreds of points its 2000 features give: a median
   there would ask hundreds of points for it, which forward motion never
   gives the points near the direction of travel. A sparse tracker keeps fewer
   than 100 points, and the test then becomes the median's.
5. The map gets only the kept points seen under at least
   ``min_point_parallax_deg`` (ORB-SLAM's CheckRT: rays whose cosine is below
   0.99998, 0.36 deg): the others count towards ``min_points`` as ORB-SLAM's do,
   but their depth is a guess. On KITTI 07 the first map held points at 160-650
   baselines (0.1-0.35 deg), whose depth no pixel measures; iSAM2's Cholesky met
   them as an indeterminate system as soon as its ordering put them in the root
   (``max_predictions`` 20).

Frames: ``a`` is the first view, ``b`` the second. OpenCV's
``findEssentialMat(p_a, p_b)``, ``findHomography(p_a, p_b)``,
``decomposeHomographyMat`` and ``recoverPose(E, p_a, p_b)`` all describe
``bTa`` (``x_b = R x_a + t``); the result is its inverse ``aTb``, with a unit
translation: the scale is not observable from two views, and the points are
in units of the baseline. Pixel centres are at integer coordinates (OpenCV's).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import cv2
import numpy as np

from slamcore.config import Validated, bounded
from slamcore.errors import ConfigError, MeasurementError
from slamcore.spatial.geometry import invert_pose

__all__ = ["TwoViewConfig", "TwoViewResult", "two_view_geometry"]

#: Fewest correspondences (and model inliers): the linear F needs 8; below it
#: the answer is None rather than a fit that always "succeeds".
MIN_CORRESPONDENCES = 8
#: USAC iteration cap (OpenCV's default is 1000): 5-point samples at 30 % inliers
#: need ln(0.001) / ln(1 - 0.3^5) = 2840 for 99.9 %; MAGSAC++ stops early on a good model.
MAX_ITERS = 5000
#: Points of a view closer than this (RMS, pixels) to one line (or one pixel) span
#: no area: neither H nor F is determined, and a fit on them is noise that can
#: still pass every later check. About the localisation noise of a keypoint.
MIN_SPREAD_PX = 1.0
#: Largest seed of OpenCV's RNG (``cv2.setRNGSeed`` takes a C int).
MAX_SEED = 2**31 - 1
#: ORB-SLAM's keypoint sigma at pyramid level 0, pixels: the default of the
#: correspondences' sigma, in whose units the chi2 tests and reprojection limit are.
SIGMA_PX = 1.0
#: chi2 95 % quantiles, 1 and 2 degrees of freedom (ORB-SLAM's thresholds).
CHI2_1DOF = 3.841
CHI2_2DOF = 5.991
#: ORB-SLAM (ReconstructH): the second-best homography decomposition must
#: triangulate fewer than this share of the best's points.
AMBIGUITY_RATIO = 0.75


@dataclass(frozen=True)
class TwoViewConfig(Validated):
    """Two-view initialisation settings (a nested table: ``[isam2_visual.mono.two_view]``).

    Attributes:
        min_parallax_deg: ``min_points`` kept points (or half of them, if fewer)
            must be seen under at least this parallax (ORB-SLAM: 50 points, 1 deg).
        min_points: kept (triangulated, checked) points needed.
        ransac_threshold_px: USAC MAGSAC++ inlier threshold, pixels.
        confidence: USAC confidence.
        homography_ratio: ``R_H = S_H / (S_H + S_F)`` above this selects the homography.
        max_reprojection_sigmas: largest reprojection error of a kept point, each
            view, in pixel sigmas (ORB-SLAM's CheckRT: 2).
        min_point_parallax_deg: smallest parallax of a point the first map gets
            (``mapped``); kept points below it still count towards ``min_points``
            (ORB-SLAM's CheckRT: cos(parallax) < 0.99998, 0.36 deg).
    """

    TABLE: ClassVar[str] = "two_view"  # a nested table (e.g. [isam2_visual.mono.two_view])

    # ORB-SLAM asks 1 deg: below it depth is too uncertain to start a map
    min_parallax_deg: float = bounded(1.0, min=0.0, lt=180.0)
    # ORB-SLAM's minimum of triangulated points (Initializer, 50)
    min_points: int = bounded(50, min=1)
    ransac_threshold_px: float = bounded(1.0, gt=0.0)
    confidence: float = bounded(0.999, gt=0.0, lt=1.0)
    homography_ratio: float = bounded(0.45, min=0.0, max=1.0)
    max_reprojection_sigmas: float = bounded(2.0, gt=0.0)
    # ORB-SLAM's CheckRT maps a point only when cos(parallax) < 0.99998
    min_point_parallax_deg: float = bounded(0.36, min=0.0, lt=180.0)


@dataclass(frozen=True, eq=False)
class TwoViewResult:
    """Outcome of :func:`two_view_geometry` (``N`` correspondences).

    Attributes:
        model: ``"essential"`` or ``"homography"``.
        aTb: (4, 4) maps points of camera b into camera a; unit-norm translation.
        points_a: (N, 3) triangulated points in camera a, baseline units; NaN where not kept.
        kept: (N,) bool: model inlier, in front of both cameras, reprojection
            within ``max_reprojection_sigmas`` in both views, parallax > 0.
        parallax_deg: (N,) angle between the two rays of each kept point (NaN elsewhere).
        mapped: (N,) bool: the kept points seen under at least
            ``min_point_parallax_deg``, those a first map gets.
        median_parallax_deg: median over kept points (NaN with none).
        score_h, score_f: ORB-SLAM's truncated symmetric-transfer scores.
        ok: ``min_points`` kept points with enough parallax (and, for the
            homography, an unambiguous decomposition).
        reason: ``""`` when ok, else one line saying why not.
    """

    model: str
    aTb: np.ndarray
    points_a: np.ndarray
    kept: np.ndarray
    parallax_deg: np.ndarray
    mapped: np.ndarray
    median_parallax_deg: float
    score_h: float
    score_f: float
    ok: bool
    reason: str


def _checked_inputs(uv_a, uv_b, K, seed) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, 2), (N, 2), (3, 3) contiguous float64, or MeasurementError / ConfigError."""
    ua = np.ascontiguousarray(uv_a, np.float64)
    ub = np.ascontiguousarray(uv_b, np.float64)
    if ua.ndim != 2 or ua.shape[1:] != (2,) or ua.shape != ub.shape:
        raise MeasurementError(f"two-view: uv_a and uv_b must both be (N, 2), got {ua.shape} and {ub.shape}")
    bad = int(np.count_nonzero(~(np.isfinite(ua).all(1) & np.isfinite(ub).all(1))))
    if bad:
        raise MeasurementError(f"two-view: {bad} of {len(ua)} correspondences have NaN or inf pixels")
    # USAC reads K's memory as contiguous: a strided view (a slice of P) gives no model
    K = np.ascontiguousarray(K, np.float64)
    if (
        K.shape != (3, 3)
        or not np.isfinite(K).all()
        or K[0, 0] <= 0
        or K[1, 1] <= 0
        or K[1, 0] != 0
        or not np.array_equal(K[2], [0.0, 0.0, 1.0])
    ):
        raise MeasurementError(
            "two-view: K must be a finite pinhole matrix "
            "[[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0"
        )
    if not (isinstance(seed, (int, np.integer)) and 0 <= seed <= MAX_SEED):
        raise ConfigError(f"two-view: seed must be an integer in [0, {MAX_SEED}], got {seed!r}")
    return ua, ub, K


def _fit(
    kind: str, ua: np.ndarray, ub: np.ndarray, K: np.ndarray, c: TwoViewConfig, seed: int
) -> np.ndarray | None:
    """Robust fit of ``p_b ~ H p_a`` or ``p_b^T E p_a = 0``: the 3x3 model, or None."""
    params = cv2.UsacParams()  # MAGSAC++ as the USAC_MAGSAC flag sets it, with our seed
    params.sampler = cv2.SAMPLING_UNIFORM
    params.score = cv2.SCORE_METHOD_MAGSAC
    params.loMethod = cv2.LOCAL_OPTIM_SIGMA
    params.threshold = float(c.ransac_threshold_px)
    params.confidence = float(c.confidence)
    params.maxIterations = MAX_ITERS
    params.randomGeneratorState = int(seed)
    try:
        if kind == "homography":
            M, mask = cv2.findHomography(ua, ub, params)
        else:
            M, mask = cv2.findEssentialMat(ua, ub, K, K, np.zeros(5), np.zeros(5), params)
    except cv2.error:  # degenerate samples (e.g. all points collinear) make some solvers throw
        return None
    # OpenCV may stack several 3x3 solutions; the first is its best. Its inlier mask
    # is not used: the inliers are ORB-SLAM's, from the scores (module doc)
    if M is not None and M.shape[0] > 3:
        M = M[:3]
    if M is None or mask is None or M.shape != (3, 3) or not np.isfinite(M).all():
        return None
    return M


def _scored(chi_b: np.ndarray, chi_a: np.ndarray, threshold: float) -> tuple[float, np.ndarray]:
    """ORB-SLAM's score and inliers from the chi2 of both directions: each term with
    chi2 <= threshold adds 5.991 - chi2; an inlier passes both (NaN, inf: neither)."""
    with np.errstate(invalid="ignore"):
        in_b, in_a = chi_b <= threshold, chi_a <= threshold
        score = np.sum(np.where(in_b, CHI2_2DOF - chi_b, 0.0)) + np.sum(
            np.where(in_a, CHI2_2DOF - chi_a, 0.0)
        )
    return float(score), in_a & in_b


def _homography_score(
    H: np.ndarray, ua: np.ndarray, ub: np.ndarray, sigma_px: float
) -> tuple[float, np.ndarray]:
    """ORB-SLAM's S_H of ``p_b ~ H p_a`` (transfer a -> b and b -> a, truncated at
    5.991) and its (N,) bool inliers."""

    def transfer(M, uv):
        x = uv @ M[:, :2].T + M[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):  # w = 0: at infinity, no score
            return x[:, :2] / x[:, 2:]

    try:
        H_inv = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return 0.0, np.zeros(len(ua), bool)
    chi_b = np.sum((ub - transfer(H, ua)) ** 2, axis=1) / sigma_px**2
    chi_a = np.sum((ua - transfer(H_inv, ub)) ** 2, axis=1) / sigma_px**2
    return _scored(chi_b, chi_a, CHI2_2DOF)


def _fundamental_score(
    F: np.ndarray, ua: np.ndarray, ub: np.ndarray, sigma_px: float
) -> tuple[float, np.ndarray]:
    """ORB-SLAM's S_F of ``p_b^T F p_a = 0`` (squared point-line distances in b and in
    a, truncated at 3.841, scored as 5.991 - chi2) and its (N,) bool inliers."""
    line_b = ua @ F[:, :2].T + F[:, 2]  # F p_a, the epipolar line of p_a in image b
    line_a = ub @ F[:2] + F[2]  # F^T p_b, in image a
    num2 = (np.sum(ub * line_b[:, :2], axis=1) + line_b[:, 2]) ** 2  # (p_b^T F p_a)^2, both directions
    with np.errstate(divide="ignore", invalid="ignore"):
        chi_b = num2 / np.sum(line_b[:, :2] ** 2, axis=1) / sigma_px**2
        chi_a = num2 / np.sum(line_a[:, :2] ** 2, axis=1) / sigma_px**2
    return _scored(chi_b, chi_a, CHI2_1DOF)


def _triangulate(K, R, t, ua, ub, max_reproj_px):
    """Points of ``bTa = (R, t)`` -> ((n, 3) in camera a, (n,) bool good, (n,) parallax deg).

    Good: finite, positive depth in both cameras, reprojection error within
    ``max_reproj_px`` in both views, parallax > 0 (a point at infinity has none).
    """
    P_a = K @ np.eye(3, 4)
    P_b = K @ np.hstack([R, t.reshape(3, 1)])
    Xh = cv2.triangulatePoints(P_a, P_b, np.ascontiguousarray(ua.T), np.ascontiguousarray(ub.T))
    with np.errstate(divide="ignore", invalid="ignore"):
        X_a = (Xh[:3] / Xh[3]).T
        X_b = X_a @ R.T + t
        err_a = np.linalg.norm((X_a @ K.T)[:, :2] / X_a[:, 2:] - ua, axis=1)
        err_b = np.linalg.norm((X_b @ K.T)[:, :2] / X_b[:, 2:] - ub, axis=1)
        # rays from each camera centre to the point, in frame a; centre of b is -R^T t
        ray_b = X_a + R.T @ t
        cos = np.sum(X_a * ray_b, axis=1) / (np.linalg.norm(X_a, axis=1) * np.linalg.norm(ray_b, axis=1))
        parallax = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        good = (
            np.isfinite(X_a).all(1)
            & (X_a[:, 2] > 0)
            & (X_b[:, 2] > 0)
            & (err_a <= max_reproj_px)
            & (err_b <= max_reproj_px)
            & (parallax > 0)
        )
    return X_a, good, parallax


def _unit(t: np.ndarray) -> np.ndarray:
    t = np.asarray(t, np.float64).reshape(3)
    return t / max(np.linalg.norm(t), np.finfo(float).tiny)


def _pose_from_homography(H, K, ua, ub, max_reproj_px: float):
    """Best decomposition of ``p_b ~ H p_a`` -> (R, unit t) of bTa, and "" or why it is ambiguous."""
    # decomposeHomographyMat: (R, t/d) is the change of basis source (a) -> destination (b),
    # x_b = R x_a + t, as recoverPose; t is divided by the plane's distance, so normalised here
    _, Rs, ts, _ = cv2.decomposeHomographyMat(H, K)
    counts = [
        int(_triangulate(K, R, _unit(t), ua, ub, max_reproj_px)[1].sum()) for R, t in zip(Rs, ts, strict=True)
    ]
    best = int(np.argmax(counts))  # the first of equals
    second = max(counts[:best] + counts[best + 1 :], default=0)
    note = ""
    if counts[best] > 0 and second >= AMBIGUITY_RATIO * counts[best]:
        note = f"homography decomposition ambiguous ({second} vs {counts[best]} points triangulated)"
    return Rs[best], _unit(ts[best]), note


def _pose_from_essential(E, K, ua, ub):
    """(R, unit t) of bTa from ``p_b^T E p_a = 0`` and the model's inliers."""
    # recoverPose(E, p_a, p_b, K) with E from findEssentialMat(p_a, p_b) returns R, t with
    # x_b = R x_a + t (a change of basis from camera a to camera b: bTa), |t| = 1
    _, R, t, _ = cv2.recoverPose(E, ua, ub, K)
    return R, _unit(t)


def _result(
    model, R, t, inliers, K, ua, ub, s_h, s_f, note, c: TwoViewConfig, sigma_px: float
) -> TwoViewResult:
    """Triangulate the inliers with bTa = (R, t), check them, and judge the initialisation."""
    n = len(ua)
    points = np.full((n, 3), np.nan)
    parallax = np.full(n, np.nan)
    kept = np.zeros(n, bool)
    idx = np.flatnonzero(inliers)  # at least MIN_CORRESPONDENCES of them
    X, good, par = _triangulate(K, R, t, ua[idx], ub[idx], c.max_reprojection_sigmas * sigma_px)
    kept[idx[good]] = True
    points[idx[good]], parallax[idx[good]] = X[good], par[good]
    n_kept = int(kept.sum())
    median = float(np.median(parallax[kept])) if n_kept else float("nan")
    why = [note] if note else []
    if not n_kept:
        why.append(f"no kept points (need {c.min_points}), so no parallax")
    else:
        if n_kept < c.min_points:
            why.append(f"{n_kept} kept points < {c.min_points}")
        wide = int(np.count_nonzero(parallax[kept] >= c.min_parallax_deg))
        need = min(c.min_points, -(-n_kept // 2))  # ORB-SLAM's count, at most half the points
        if wide < need:
            why.append(
                f"{wide} points with parallax >= {c.min_parallax_deg:g} deg < "
                f"{need} (median {median:.2f} deg)"
            )
    bTa = np.eye(4)
    bTa[:3, :3], bTa[:3, 3] = R, t
    mapped = kept & (np.nan_to_num(parallax, nan=-1.0) >= c.min_point_parallax_deg)
    return TwoViewResult(
        model, invert_pose(bTa), points, kept, parallax, mapped, median, s_h, s_f, not why, "; ".join(why)
    )


def two_view_geometry(
    uv_a: np.ndarray,
    uv_b: np.ndarray,
    K: np.ndarray,
    config: TwoViewConfig | None = None,
    seed: int = 0,
    sigma_px: float = SIGMA_PX,
) -> TwoViewResult | None:
    """Relative pose and initial points of two views of a static scene (ORB-SLAM's initializer).

    ``uv_a``, ``uv_b``: (N, 2) float64 corresponding pixels ``[u, v]`` (pixel
    centres at integer coordinates) in views a and b, undistorted; ``K``
    (3, 3) intrinsics of both; ``seed`` of the robust fits' generator;
    ``sigma_px`` the pixels' standard deviation (the chi2 tests and the
    reprojection limit are in its units, as ORB-SLAM scales them by its
    keypoints' pyramid level).

    Returns None only when no model can be fitted (fewer than 8 correspondences,
    or OpenCV finds neither H nor E with 8 inliers by ORB-SLAM's chi2 test);
    otherwise a :class:`TwoViewResult` whose ``ok``/``reason`` say whether it can start a map.
    Raises :class:`MeasurementError` on malformed or non-finite input, or when
    the points of a view lie on one line (or at one pixel).
    """
    c = config or TwoViewConfig()
    ua, ub, K = _checked_inputs(uv_a, uv_b, K, seed)
    if not (np.isfinite(sigma_px) and sigma_px > 0):
        raise MeasurementError(f"two-view: sigma_px must be a positive number, got {sigma_px!r}")
    if len(ua) < MIN_CORRESPONDENCES:
        return None
    for name, uv in (("a", ua), ("b", ub)):
        # RMS distance of the points from their best-fit line (smallest principal axis)
        off_line = np.linalg.svd(uv - uv.mean(axis=0), compute_uv=False)[-1] / np.sqrt(len(uv))
        if off_line < MIN_SPREAD_PX:
            raise MeasurementError(
                f"two-view: the {len(uv)} points of view {name} lie on one line "
                f"(RMS {off_line:.2f} px off it < {MIN_SPREAD_PX:g}): degenerate"
            )
    H = _fit("homography", ua, ub, K, c, seed)
    E = _fit("essential", ua, ub, K, c, seed)
    K_inv = np.linalg.inv(K)
    none = (0.0, np.zeros(len(ua), bool))
    s_h, inl_h = _homography_score(H, ua, ub, sigma_px) if H is not None else none
    s_f, inl_e = _fundamental_score(K_inv.T @ E @ K_inv, ua, ub, sigma_px) if E is not None else none
    # a model fewer than 8 correspondences agree with is no model (and recoverPose needs 5)
    H = H if inl_h.sum() >= MIN_CORRESPONDENCES else None
    E = E if inl_e.sum() >= MIN_CORRESPONDENCES else None
    if H is None and E is None:
        return None
    total = s_h + s_f
    # ORB-SLAM: R_H > 0.45 means a plane or too little parallax for F to be reliable
    if E is None or (H is not None and total > 0 and s_h / total > c.homography_ratio):
        R, t, note = _pose_from_homography(H, K, ua[inl_h], ub[inl_h], c.max_reprojection_sigmas * sigma_px)
        homography = _result("homography", R, t, inl_h, K, ua, ub, s_h, s_f, note, c, sigma_px)
        if not note or E is None:
            return homography
        # a plane seen twice has two decompositions; the five-point essential matrix is
        # not degenerate on a plane (Nister 2004) and chirality picks its pose
        R, t = _pose_from_essential(E, K, ua[inl_e], ub[inl_e])
        essential = _result("essential", R, t, inl_e, K, ua, ub, s_h, s_f, "", c, sigma_px)
        if essential.ok:
            return essential
        return dataclasses.replace(
            homography, reason=f"{homography.reason}; essential matrix: {essential.reason}"
        )
    R, t = _pose_from_essential(E, K, ua[inl_e], ub[inl_e])
    return _result("essential", R, t, inl_e, K, ua, ub, s_h, s_f, "", c, sigma_px)
