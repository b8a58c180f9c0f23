"""Two acceptance measures of a two-view geometry that scale with the images.

- :func:`log10_nfa`: the a-contrario number of false alarms of ORSA (Moisan
  & Stival, "A probabilistic criterion to detect rigid point matches between
  two images and estimate the fundamental matrix", IJCV 2004; Moisan,
  Moulon & Monasse, IPOL 2012). Under the background model "the matches are
  independent and uniform in the image", the expected number of models that
  explain ``k`` of ``n`` matches at least as well as the one found is::

      NFA(k) = N_sol (n - s) C(n, k) C(k, s) alpha_k^(k - s)

  with ``s`` the minimal sample size, ``N_sol`` the solutions per sample and
  ``alpha_k`` the chance that a random point falls within the k-th smallest
  residual ``e_k`` of its epipolar line (``2 D e_k / A``, D the image
  diagonal, A its area) or of its homography image (``pi e_k^2 / A``). A
  model is meaningful when ``min_k NFA(k) <= 1``: fewer than one such model is
  expected by chance. It is a relative criterion: 20 inliers among 60
  matches are meaningful, 20 among 2000 are not.
- :func:`hull_coverage`: the share of an image's textured area (convex hull
  of its features) that the inliers span, a measure of how much of the view
  the geometry explains.
- :func:`shared_view_coverage`: the same share, measured only on the part of
  one image that the other camera also sees (its features' hull carried over
  by the relative rotation, points at infinity, widened to the inliers): a
  view turned by 30 degrees is asked to explain only the part of the other
  view it still looks at.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["MINIMAL_SAMPLE", "hull_coverage", "image_extent", "log10_nfa", "shared_view_coverage"]

#: (sample size s, solutions per sample N_sol) of each model: 7-point F (up to
#: 3 real roots), 5-point E (up to 10, Nister 2004), 4-point H (one).
MINIMAL_SAMPLE = {"fundamental": (7, 3), "essential": (5, 10), "homography": (4, 1)}


def _log10_comb(n: np.ndarray | int, k: np.ndarray | int) -> np.ndarray:
    lg = np.vectorize(math.lgamma, otypes=[float])
    n = np.asarray(n, float)
    k = np.asarray(k, float)
    return (lg(n + 1) - lg(k + 1) - lg(n - k + 1)) / math.log(10)


def log10_nfa(residuals_px: np.ndarray, model: str, width: float, height: float) -> tuple[float, int]:
    """``(min_k log10 NFA(k), k at the minimum)`` for the residuals of all n matches.

    ``residuals_px``: (n,) symmetric epipolar distance (fundamental, essential)
    or transfer error (homography), pixels; ``width``/``height``: image size in
    pixels. Returns ``(inf, 0)`` when n is not above the minimal sample.
    """
    s, n_sol = MINIMAL_SAMPLE[model]
    e = np.sort(np.asarray(residuals_px, float).reshape(-1))
    n = len(e)
    if n <= s:
        return math.inf, 0
    k = np.arange(s + 1, n + 1)
    ek = np.maximum(e[s:], 1e-9)  # the k-th smallest residual (k = s+1 .. n)
    area = width * height
    if model == "homography":
        alpha = np.pi * ek**2 / area
    else:
        alpha = 2.0 * math.hypot(width, height) * ek / area
    alpha = np.minimum(alpha, 1.0)
    log_nfa = math.log10(n_sol * (n - s)) + _log10_comb(n, k) + _log10_comb(k, s) + (k - s) * np.log10(alpha)
    i = int(np.argmin(log_nfa))
    return float(log_nfa[i]), int(k[i])


def image_extent(xy_px: np.ndarray) -> tuple[float, float]:
    """(width, height) of the smallest image holding every point: a stand-in for the image size."""
    xy = np.asarray(xy_px, float).reshape(-1, 2)
    if len(xy) == 0:
        return 1.0, 1.0
    return float(np.floor(xy[:, 0].max()) + 1), float(np.floor(xy[:, 1].max()) + 1)


def hull_coverage(xy_all: np.ndarray, xy_inliers: np.ndarray) -> float:
    """Area of the inliers' convex hull over the area of all features' convex hull.

    A continuous measure of how much of the view the geometry explains
    (untextured parts of the image, which hold no feature, do not count); it
    needs no image size and has no cell boundaries to flip on a pixel.
    """
    xy_all = np.asarray(xy_all, np.float32).reshape(-1, 2)
    xy_in = np.asarray(xy_inliers, np.float32).reshape(-1, 2)
    if len(xy_all) < 3 or len(xy_in) < 3:
        return 0.0
    whole = cv2.contourArea(cv2.convexHull(xy_all))
    return float(cv2.contourArea(cv2.convexHull(xy_in)) / whole) if whole > 0 else 0.0


def _clip_in_front(rays: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """A closed polygon of (n, 3) rays clipped to ``z >= eps`` (Sutherland-Hodgman, one plane)."""
    out = []
    for cur, nxt in zip(rays, np.roll(rays, -1, axis=0), strict=True):
        if cur[2] >= eps:
            out.append(cur)
        if (cur[2] >= eps) != (nxt[2] >= eps):
            out.append(cur + (eps - cur[2]) / (nxt[2] - cur[2]) * (nxt - cur))
    return np.asarray(out, float).reshape(-1, 3)


def shared_view_coverage(
    xy_all: np.ndarray, xy_inliers: np.ndarray, xy_other: np.ndarray, K: np.ndarray, R: np.ndarray
) -> float:
    """Share of one image's features' hull, within the other camera's view, that the inliers span.

    ``xy_all``/``xy_inliers``: this image's features and inliers (pixels of
    ``K``); ``xy_other``: the other image's features; ``R``: rotation taking
    the other camera's axes to this one's (``p_this = R p_other + t``). The
    other image's features' hull is carried into this image by the infinite
    homography ``K R K^-1`` (rays clipped to the half-space in front of this
    camera), widened to the inliers' hull (both cameras see the inliers) and
    intersected with this image's hull: the part of this view the other
    camera sees. The result is ``area(inlier hull within it) / area(it)``,
    in [0, 1]; 0 when the other camera faces away or the views share no area.

    Points at infinity: the translation's parallax is not modelled (a caller
    bounds it separately); for a camera that moved forward, nearer points
    widen the true shared part, as far as the inliers show it.
    """
    xy_all = np.asarray(xy_all, np.float32).reshape(-1, 2)
    xy_in = np.asarray(xy_inliers, np.float32).reshape(-1, 2)
    xy_other = np.asarray(xy_other, np.float64).reshape(-1, 2)
    if len(xy_all) < 3 or len(xy_in) < 3 or len(xy_other) < 3:
        return 0.0
    K = np.asarray(K, np.float64)
    hull_other = cv2.convexHull(xy_other.astype(np.float32)).reshape(-1, 2).astype(np.float64)
    rays = np.c_[hull_other, np.ones(len(hull_other))] @ np.linalg.inv(K).T @ np.asarray(R, float).T
    rays = _clip_in_front(rays)
    if len(rays) < 3:
        return 0.0
    proj = rays @ K.T
    # a ray near the image plane projects far out: clip to a bound that keeps float32 exact enough
    seen = np.clip(proj[:, :2] / proj[:, 2:3], -1e6, 1e6).astype(np.float32)
    hull_in = cv2.convexHull(xy_in)
    # the inliers are seen by both cameras wherever they are: at finite depth the
    # shared part reaches beyond the part at infinity, at least as far as they do
    seen = cv2.convexHull(np.vstack([seen, hull_in.reshape(-1, 2)]))
    shared, region = cv2.intersectConvexConvex(cv2.convexHull(xy_all), seen)
    if region is None or shared <= 0:
        return 0.0
    covered, _ = cv2.intersectConvexConvex(hull_in, region)
    return float(min(covered / shared, 1.0))
