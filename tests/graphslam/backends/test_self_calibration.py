"""The camera refined in a bundle (``run --intrinsics estimate``): gtsam's own
projections of a seeded scene through a SIMPLE_RADIAL camera, solved from a focal length
20 % off and no distortion; the distortion put back as OpenCV takes it off."""

from __future__ import annotations

import cv2
import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from graphslam.backends.spatial.self_calibration import recorded_pixels, refine_camera

TRUE_F_PX, TRUE_K1, CX_PX, CY_PX = 500.0, -0.05, 319.5, 239.5
#: Noise-free projections: the refined camera is the true one to LM's tolerance.
NOISE_FREE_F_TOL_PX, NOISE_FREE_K1_TOL = 1e-3, 1e-6
#: The solved bundle's error then (squared whitened units: a few 1e-5 px of residual).
NOISE_FREE_ERROR = 1e-6
#: 0.5 px pixel noise over 8 views of 60 points: the estimate within three of its own sigmas.
SIGMAS = 3.0
#: OpenCV's undistortPoints iterates to about this (pixels); the inverse here is exact.
OPENCV_UNDISTORT_TOL_PX = 1e-3


def _bundle(noise_px: float, k1: float = TRUE_K1, seed: int = 0):
    """A run's bundle as the visual iSAM2 keeps it: Cal3_S2 projections at a focal length
    20 % off with no distortion (the start), of pixels a SIMPLE_RADIAL camera recorded,
    on poses and points at the truth."""
    rng = np.random.default_rng(seed)
    true_cal = gtsam.Cal3Bundler(TRUE_F_PX, k1, 0.0, CX_PX, CY_PX)
    guess = gtsam.Cal3_S2(1.2 * TRUE_F_PX, 1.2 * TRUE_F_PX, 0.0, CX_PX, CY_PX)
    points = rng.uniform([-2, -2, 4], [2, 2, 8], size=(60, 3))
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    pixel = gtsam.noiseModel.Isotropic.Sigma(2, max(noise_px, 1.0))
    for i in range(8):  # an arc round the points, each view turned towards their centre
        angle = np.radians(-20 + 40 * i / 7)
        eye = gtsam.Point3(6 * np.sin(angle), 0.3 * i, 6 - 6 * np.cos(angle))
        pose = gtsam.PinholeCameraCal3_S2.Lookat(eye, gtsam.Point3(0, 0, 6), gtsam.Point3(0, -1, 0),
                                                 gtsam.Cal3_S2()).pose()
        values.insert(X(i), pose)
        camera = gtsam.PinholeCameraCal3Bundler(pose, true_cal)
        for j, p in enumerate(points):
            uv = camera.project(gtsam.Point3(p)) + rng.normal(0.0, noise_px, 2)
            graph.add(gtsam.GenericProjectionFactorCal3_S2(uv, pixel, X(i), L(j), guess))
    for j, p in enumerate(points):
        values.insert(L(j), gtsam.Point3(p))
    graph.add(gtsam.PriorFactorPose3(X(0), values.atPose3(X(0)), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    graph.add(gtsam.RangeFactorPose3(X(0), X(7), values.atPose3(X(0)).range(values.atPose3(X(7))),
                                     gtsam.noiseModel.Isotropic.Sigma(1, 1e-3)))
    return graph, values


def test_noise_free_projections_give_the_true_camera_from_20_percent_off():
    graph, values = _bundle(noise_px=0.0)
    fit = refine_camera(graph, values, 1.2 * TRUE_F_PX, 0.0, CX_PX, CY_PX)
    assert fit.f_px == pytest.approx(TRUE_F_PX, abs=NOISE_FREE_F_TOL_PX)
    assert fit.k1 == pytest.approx(TRUE_K1, abs=NOISE_FREE_K1_TOL)
    assert fit.projections == 8 * 60
    assert fit.error_after < NOISE_FREE_ERROR < fit.error_before


def test_k1_held_stays_where_it_is_and_has_no_spread():
    graph, values = _bundle(noise_px=0.0, k1=0.0)
    fit = refine_camera(graph, values, 1.2 * TRUE_F_PX, 0.0, CX_PX, CY_PX, free_k1=False)
    assert fit.f_px == pytest.approx(TRUE_F_PX, abs=NOISE_FREE_F_TOL_PX)
    assert abs(fit.k1) < NOISE_FREE_K1_TOL and fit.sigma_k1 is None and fit.sigma_f_px is not None


@pytest.mark.parametrize("seed", range(3))
def test_noisy_projections_give_the_camera_within_its_own_sigmas(seed):
    graph, values = _bundle(noise_px=0.5, seed=seed)
    fit = refine_camera(graph, values, 1.2 * TRUE_F_PX, 0.0, CX_PX, CY_PX)
    assert fit.sigma_f_px is not None and 0.0 < fit.sigma_f_px < 0.05 * TRUE_F_PX
    assert abs(fit.f_px - TRUE_F_PX) <= SIGMAS * fit.sigma_f_px
    assert fit.sigma_k1 is not None and abs(fit.k1 - TRUE_K1) <= SIGMAS * fit.sigma_k1


def test_recorded_pixels_undo_what_opencv_undistorts():
    """OpenCV takes the distortion off (``undistortPoints`` with ``P = K``); recorded_pixels
    puts it back: the round trip is the identity."""
    rng = np.random.default_rng(3)
    raw = rng.uniform([0, 0], [640, 480], size=(50, 2))
    K = np.array([[TRUE_F_PX, 0, CX_PX], [0, TRUE_F_PX, CY_PX], [0, 0, 1.0]])
    dist = np.array([TRUE_K1, 0.0, 0.0, 0.0])
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    undistorted = cv2.undistortPoints(raw.reshape(-1, 1, 2), K, dist, R=None, P=K, criteria=criteria).reshape(-1, 2)
    back = recorded_pixels(undistorted, TRUE_F_PX, TRUE_K1, CX_PX, CY_PX)
    np.testing.assert_allclose(back, raw, atol=OPENCV_UNDISTORT_TOL_PX)


def test_a_bundle_without_projections_is_refused():
    graph, values = _bundle(noise_px=0.0)
    only_prior = gtsam.NonlinearFactorGraph()
    only_prior.add(graph.at(graph.size() - 2))
    with pytest.raises(ValueError, match="no projection"):
        refine_camera(only_prior, values, TRUE_F_PX, 0.0, CX_PX, CY_PX)
