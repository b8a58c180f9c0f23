"""The focal length refined in a bundle (``run --intrinsics estimate``): gtsam's own
projections of a seeded scene, solved from a focal length 20 % off."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from graphslam.backends.spatial.self_calibration import refine_focal

TRUE_F_PX, CX_PX, CY_PX = 500.0, 319.5, 239.5
#: Noise-free projections: the refined focal length is the true one to LM's tolerance.
NOISE_FREE_F_TOL_PX = 1e-3
#: 0.5 px pixel noise over 8 views of 60 points: the estimate within three of its own sigmas.
SIGMAS = 3.0


def _bundle(noise_px: float, seed: int = 0):
    """A run's bundle as the visual iSAM2 keeps it: Cal3_S2 projections at a focal length
    20 % off (the start), on poses and points at the truth."""
    rng = np.random.default_rng(seed)
    true_cal = gtsam.Cal3_S2(TRUE_F_PX, TRUE_F_PX, 0.0, CX_PX, CY_PX)
    guess = gtsam.Cal3_S2(1.2 * TRUE_F_PX, 1.2 * TRUE_F_PX, 0.0, CX_PX, CY_PX)
    points = rng.uniform([-2, -2, 4], [2, 2, 8], size=(60, 3))
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    pixel = gtsam.noiseModel.Isotropic.Sigma(2, max(noise_px, 1.0))
    for i in range(8):  # an arc round the points, each view turned towards their centre
        angle = np.radians(-20 + 40 * i / 7)
        eye = gtsam.Point3(6 * np.sin(angle), 0.3 * i, 6 - 6 * np.cos(angle))
        pose = gtsam.PinholeCameraCal3_S2.Lookat(eye, gtsam.Point3(0, 0, 6), gtsam.Point3(0, -1, 0), true_cal).pose()
        values.insert(X(i), pose)
        camera = gtsam.PinholeCameraCal3_S2(pose, true_cal)
        for j, p in enumerate(points):
            uv = camera.project(gtsam.Point3(p)) + rng.normal(0.0, noise_px, 2)
            graph.add(gtsam.GenericProjectionFactorCal3_S2(uv, pixel, X(i), L(j), guess))
    for j, p in enumerate(points):
        values.insert(L(j), gtsam.Point3(p))
    graph.add(gtsam.PriorFactorPose3(X(0), values.atPose3(X(0)), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    graph.add(gtsam.RangeFactorPose3(X(0), X(7), values.atPose3(X(0)).range(values.atPose3(X(7))),
                                     gtsam.noiseModel.Isotropic.Sigma(1, 1e-3)))
    return graph, values


def test_noise_free_projections_give_the_true_focal_length_from_20_percent_off():
    graph, values = _bundle(noise_px=0.0)
    fit = refine_focal(graph, values, 1.2 * TRUE_F_PX, CX_PX, CY_PX)
    assert fit.f_px == pytest.approx(TRUE_F_PX, abs=NOISE_FREE_F_TOL_PX)
    assert fit.projections == 8 * 60
    assert fit.error_after < 1e-9 < fit.error_before


@pytest.mark.parametrize("seed", range(3))
def test_noisy_projections_give_the_focal_length_within_its_own_sigma(seed):
    graph, values = _bundle(noise_px=0.5, seed=seed)
    fit = refine_focal(graph, values, 1.2 * TRUE_F_PX, CX_PX, CY_PX)
    assert fit.sigma_px is not None and 0.0 < fit.sigma_px < 0.05 * TRUE_F_PX
    assert abs(fit.f_px - TRUE_F_PX) <= SIGMAS * fit.sigma_px


def test_a_bundle_without_projections_is_refused():
    graph, values = _bundle(noise_px=0.0)
    only_prior = gtsam.NonlinearFactorGraph()
    only_prior.add(graph.at(graph.size() - 2))
    with pytest.raises(ValueError, match="no projection"):
        refine_focal(only_prior, values, TRUE_F_PX, CX_PX, CY_PX)
