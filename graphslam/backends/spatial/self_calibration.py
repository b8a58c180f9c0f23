"""The focal length and radial distortion of an uncalibrated camera, refined by bundle
adjustment.

A camera-alone run of the visual iSAM2 (:class:`~graphslam.backends.spatial.isam2.VisualIsam2`)
on images undistorted at a guessed camera leaves a bundle: every pixel as a
``GenericProjectionFactorCal3_S2`` on a pose and a point. :func:`refine_camera` solves
that bundle again with the camera as one more unknown, as structure from motion does
for a camera nobody calibrated: COLMAP's default model, ``SIMPLE_RADIAL`` (a focal
length ``f``, the principal point held, one radial coefficient ``k1``:
``u = f (1 + k1 r^2) x + cx``, ``r^2 = x^2 + y^2`` of the normalised point ``(x, y)``,
OpenCV's ``k1`` alike). Each pixel goes back to the image as recorded (the guessed
camera's distortion put back) and becomes gtsam's ``GeneralSFMFactor2Cal3Bundler`` on
the same pose and point and one shared ``Cal3Bundler`` (``f, k1, k2``; ``k2`` held at 0
by a prior). The standard deviations are gtsam's marginals under the run's own pixel
noise model.

Not estimated: the principal point (held where the caller puts it, the image centre: it
trades off against the rotation and is poorly determined from a few views, which is why
COLMAP holds it too), ``k2`` and tangential distortion.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import K as CAMERA

__all__ = ["CameraFit", "refine_camera"]

#: Standard deviation of the prior each point gets in the refinement, in the map's unit:
#: a point the robust kernel left without an inlier view (or seen along its own ray) is
#: otherwise indeterminate, and gtsam then refuses the solve or every marginal; a prior a
#: million units wide leaves the solution and the camera's marginals as they are to far
#: below a pixel (a projection holds its points to well under a unit).
POINT_PRIOR_SIGMA = 1e6
#: The camera prior's standard deviations (f px, k1, k2): none on ``f`` and ``k1`` (a
#: million pixels, a thousand), ``k2`` held at 0 (SIMPLE_RADIAL has none); ``HELD`` holds
#: ``k1`` where it is too (``refine_camera(free_k1=False)``).
CAMERA_PRIOR_SIGMAS, HELD = (1e6, 1e3, 1e-8), 1e-8


@dataclass(frozen=True)
class CameraFit:
    """One bundle adjustment with the camera free.

    Attributes:
        f_px, k1: the refined focal length (pixels) and radial coefficient.
        sigma_f_px, sigma_k1: their standard deviations (gtsam's marginals); None when
            the bundle does not determine them (an indeterminate system).
        projections: pixel measurements in the bundle.
        error_before, error_after: the bundle's (robust) error at the guessed camera
            and at the refined one.
    """

    f_px: float
    k1: float
    sigma_f_px: float | None
    sigma_k1: float | None
    projections: int
    error_before: float
    error_after: float


def recorded_pixels(uv: np.ndarray, f_px: float, k1: float, cx_px: float, cy_px: float) -> np.ndarray:
    """(n, 2) pixels of images undistorted at camera ``(f_px, k1, cx_px, cy_px)`` (the
    undistorted image keeps ``f_px`` and the principal point, as OpenCV's
    ``initUndistortRectifyMap`` with ``K`` as the new camera) where the recorded image has
    them: the distortion put back."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    xy = (uv - (cx_px, cy_px)) / f_px
    scale = 1.0 + k1 * np.sum(xy * xy, axis=1, keepdims=True)
    return f_px * xy * scale + (cx_px, cy_px)


def refine_camera(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    f_px: float,
    k1: float,
    cx_px: float,
    cy_px: float,
    free_k1: bool = True,
) -> CameraFit:
    """Solve ``graph`` (a visual run's factors, from :meth:`VisualIsam2.bundle
    <graphslam.backends.spatial.isam2.VisualIsam2.bundle>`, its pixels in images
    undistorted at ``(f_px, k1)``) from ``values`` with the focal length and ``k1`` free,
    from there; the principal point ``(cx_px, cy_px)`` is held, and ``k1`` too unless
    ``free_k1`` (its standard deviation is then None).

    Factors on a variable ``values`` lacks (a frame cut mid-update) are left out.
    Raises ValueError when the bundle holds no projection.
    """
    bundle = gtsam.NonlinearFactorGraph()
    projections = 0
    for i in range(graph.size()):
        factor = graph.at(i)
        if factor is None or not all(values.exists(k) for k in factor.keys()):
            continue
        if isinstance(factor, gtsam.GenericProjectionFactorCal3_S2):
            pose, point = factor.keys()
            uv = recorded_pixels(factor.measured(), f_px, k1, cx_px, cy_px)[0]
            bundle.add(gtsam.GeneralSFMFactor2Cal3Bundler(uv, factor.noiseModel(), pose, point, CAMERA(0)))
            projections += 1
        else:
            bundle.add(factor)
    if projections == 0:
        raise ValueError("the bundle holds no projection")
    start = gtsam.Values(values)
    used = set(bundle.keyVector())
    for key in list(start.keys()):
        if key not in used:  # LM orders every variable it is given: none may be unconstrained
            start.erase(key)
    camera = gtsam.Cal3Bundler(float(f_px), float(k1), 0.0, float(cx_px), float(cy_px))
    sigmas = CAMERA_PRIOR_SIGMAS if free_k1 else (CAMERA_PRIOR_SIGMAS[0], HELD, CAMERA_PRIOR_SIGMAS[2])
    start.insert(CAMERA(0), camera)
    bundle.add(
        gtsam.PriorFactorCal3Bundler(CAMERA(0), camera, gtsam.noiseModel.Diagonal.Sigmas(np.array(sigmas)))
    )
    before = bundle.error(start)
    solved = gtsam.LevenbergMarquardtOptimizer(
        _with_wide_point_priors(bundle, start), start, gtsam.LevenbergMarquardtParams()
    ).optimize()
    out = solved.atCal3Bundler(CAMERA(0))
    sigma_f, sigma_k1 = _camera_sigmas(bundle, solved)
    sigma_k1 = sigma_k1 if free_k1 else None
    return CameraFit(
        float(out.fx()),
        float(out.k1()),
        sigma_f,
        sigma_k1,
        projections,
        float(before),
        float(bundle.error(solved)),
    )


def _camera_sigmas(
    bundle: gtsam.NonlinearFactorGraph, solved: gtsam.Values
) -> tuple[float | None, float | None]:
    """Standard deviations of ``f`` (pixels) and ``k1`` at ``solved`` (gtsam's marginal);
    None when the bundle does not determine them."""
    try:
        cov = np.asarray(
            gtsam.Marginals(_with_wide_point_priors(bundle, solved), solved).marginalCovariance(CAMERA(0))
        )
    except RuntimeError:  # gtsam's indeterminate system: the camera is not determined
        return None, None
    var = np.diag(cov)[:2]
    if not (np.all(np.isfinite(var)) and np.all(var > 0.0)):
        return None, None
    return float(np.sqrt(var[0])), float(np.sqrt(var[1]))


def _with_wide_point_priors(
    bundle: gtsam.NonlinearFactorGraph, at: gtsam.Values
) -> gtsam.NonlinearFactorGraph:
    """``bundle`` and a :data:`POINT_PRIOR_SIGMA` prior on each point at ``at``: no point
    is indeterminate, and none is held by more than a millionth of a pixel's worth."""
    graph = gtsam.NonlinearFactorGraph(bundle)
    wide = gtsam.noiseModel.Isotropic.Sigma(3, POINT_PRIOR_SIGMA)
    for key in at.keys():
        if gtsam.Symbol(key).chr() == ord("l"):
            graph.add(gtsam.PriorFactorPoint3(key, at.atPoint3(key), wide))
    return graph
