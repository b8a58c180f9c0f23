"""The focal length of an uncalibrated camera, refined by bundle adjustment.

A camera-alone run of the visual iSAM2 (:class:`~graphslam.backends.spatial.isam2.VisualIsam2`)
at a guessed focal length leaves a bundle: every pixel as a
``GenericProjectionFactorCal3_S2`` on a pose and a point. :func:`refine_focal` solves
that bundle again with the focal length as one more unknown, as structure from motion
does for a camera nobody calibrated (COLMAP's default ``SIMPLE_PINHOLE`` refinement):
each projection becomes gtsam's ``GeneralSFMFactor2Cal3f`` on the same pose and point
and one shared ``Cal3f`` (a focal length ``f``, the principal point held). Its standard
deviation is gtsam's marginal of that variable under the run's own pixel noise model.

What it does not estimate: the principal point (held where the caller puts it, the image
centre; it trades off against the rotation and is poorly determined from a few views,
which is why COLMAP holds it too) and lens distortion (none is modelled).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import K as CAMERA

__all__ = ["FocalFit", "refine_focal"]


@dataclass(frozen=True)
class FocalFit:
    """One bundle adjustment with the focal length free.

    Attributes:
        f_px: the refined focal length, pixels.
        sigma_px: its standard deviation (gtsam's marginal), pixels; None when the
            bundle does not determine it (an indeterminate system).
        projections: pixel measurements in the bundle.
        error_before, error_after: the bundle's (robust) error at the guessed focal
            length and at the refined one.
    """

    f_px: float
    sigma_px: float | None
    projections: int
    error_before: float
    error_after: float


def refine_focal(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, f_px: float, cx_px: float, cy_px: float
) -> FocalFit:
    """Solve ``graph`` (a visual run's factors, from :meth:`VisualIsam2.bundle
    <graphslam.backends.spatial.isam2.VisualIsam2.bundle>`) from ``values`` with the focal
    length free, from ``f_px``; the principal point ``(cx_px, cy_px)`` is held.

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
            bundle.add(
                gtsam.GeneralSFMFactor2Cal3f(factor.measured(), factor.noiseModel(), pose, point, CAMERA(0))
            )
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
    start.insert(CAMERA(0), gtsam.Cal3f(float(f_px), float(cx_px), float(cy_px)))
    before = bundle.error(start)
    solved = gtsam.LevenbergMarquardtOptimizer(
        _with_wide_point_priors(bundle, start), start, gtsam.LevenbergMarquardtParams()
    ).optimize()
    f_new = float(solved.atCal3f(CAMERA(0)).fx())
    return FocalFit(
        f_new, _focal_sigma(bundle, solved), projections, float(before), float(bundle.error(solved))
    )


#: Standard deviation of the prior each point gets in the refinement, in the map's unit:
#: a point the robust kernel left without an inlier view (or seen along its own ray) is
#: otherwise indeterminate, and gtsam then refuses the solve or every marginal; a prior a
#: million units wide leaves the solution and the focal length's marginal as they are to
#: far below a pixel (a projection holds its points to well under a unit).
POINT_PRIOR_SIGMA = 1e6


def _focal_sigma(bundle: gtsam.NonlinearFactorGraph, solved: gtsam.Values) -> float | None:
    """Standard deviation of the focal length at ``solved`` (gtsam's marginal), pixels;
    None when the bundle does not determine it."""
    try:
        var = float(
            gtsam.Marginals(_with_wide_point_priors(bundle, solved), solved).marginalCovariance(CAMERA(0))[
                0, 0
            ]
        )
    except RuntimeError:  # gtsam's indeterminate system: the focal length is not determined
        return None
    return float(np.sqrt(var)) if np.isfinite(var) and var > 0.0 else None


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
