"""The forward revisit and the decisive share of the geometric verifier (issue 33,
item 3): KITTI 07 frames a few metres apart are the same place, frames 40-50 m apart
are not.

Features as ``benchmarks/loop_real.py`` (the loop detector's ORB), the newer
frame as image a, the older as image b, K from calib.txt.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from frontend.image import load_gray
from frontend.orb import OrbDetector
from tests.kitti import kitti07
from loopclosure.acontrario import hull_coverage, shared_view_coverage
from loopclosure.detector import LoopDetectorConfig
from loopclosure.verify import GeometricVerifier
from slamcore.spatial.geometry import invert_pose

#: The verifier before the forward revisit: the plain coverage test alone.
PLAIN = {"max_forward_scale": 0.0}
#: Rotation error of the pose of a newly verified pair vs poses.txt, degrees
#: (measured <= 0.17 on the pairs below).
ROT_TOL_DEG = 1.0
#: Angle between the recovered and the true translation directions, degrees (measured <= 0.8).
DIR_TOL_DEG = 5.0


@pytest.fixture(scope="module")
def kitti(shared_data):
    root, K, wTc = kitti07(shared_data)
    orb = OrbDetector(LoopDetectorConfig().orb)
    cache = {}

    def features(i):
        if i not in cache:
            img = load_gray(root / "image_0" / f"{i:06d}.png")
            cache[i] = (orb.detect(img), (float(img.shape[1]), float(img.shape[0])))
        return cache[i]

    return K, wTc, features


def _verify(verifier, fa, fb, K):
    (a, sa), (b, sb) = fa, fb
    return verifier.verify(a.xy_px, a.descriptors, b.xy_px, b.descriptors, K, size_a=sa, size_b=sb)


def _angle_deg(R: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


# (older, newer): 3.3-4.7 m apart, in a 26-33 deg curve or straight on
@pytest.mark.parametrize("i,j", [(0, 20), (6, 24), (44, 52), (138, 145), (148, 155)])
def test_near_pair_refused_by_plain_coverage_is_a_forward_revisit(kitti, i, j):
    K, wTc, features = kitti
    old = _verify(GeometricVerifier(**PLAIN), features(j), features(i), K)
    assert not old.accepted and old.reason.startswith("view overlap too small")
    verifier = GeometricVerifier()
    v = _verify(verifier, features(j), features(i), K)
    assert v.accepted, v.reason
    assert v.coverage >= verifier.config.min_coverage and v.accepted_by == "forward revisit"
    aTb = invert_pose(wTc[j]) @ wTc[i]
    assert _angle_deg(v.R.T @ aTb[:3, :3]) < ROT_TOL_DEG
    t_true = aTb[:3, 3] / np.linalg.norm(aTb[:3, 3])
    assert math.degrees(math.acos(np.clip(t_true @ v.t_unit, -1.0, 1.0))) < DIR_TOL_DEG


# (older, newer): 1.2-2.8 m apart; both coverage tests refuse them (coverage
# 0.29-0.65), the turn or the approach took what their inliers' hull misses
@pytest.mark.parametrize("i,j", [(48, 50), (56, 58), (116, 118), (152, 156)])
def test_near_pair_below_both_coverages_is_the_same_place_by_its_share(kitti, i, j):
    K, wTc, features = kitti
    without = _verify(GeometricVerifier(decisive_share=0.0), features(j), features(i), K)
    assert not without.accepted and without.reason.startswith("view overlap too small")
    verifier = GeometricVerifier()
    v = _verify(verifier, features(j), features(i), K)
    assert v.accepted, v.reason
    assert v.coverage < verifier.config.min_coverage and v.accepted_by == "decisive share"
    assert v.n_inliers >= verifier.config.decisive_share * 1000  # the loop ORB's 1000 features
    aTb = invert_pose(wTc[j]) @ wTc[i]
    assert _angle_deg(v.R.T @ aTb[:3, :3]) < ROT_TOL_DEG
    t_true = aTb[:3, 3] / np.linalg.norm(aTb[:3, 3])
    assert math.degrees(math.acos(np.clip(t_true @ v.t_unit, -1.0, 1.0))) < DIR_TOL_DEG


@pytest.mark.parametrize("a,b,why", [
    (110, 52, "forward coverage"),        # 46 m apart, one far street end: explains little of it
    (117, 63, "forward coverage"),        # 43 m
    (117, 65, "median scale change"),     # 41.6 m: iterated guided matching grew its coverage to 0.68
    (103, 47, "median scale change"),     # 44 m: the shared scene is near for such a baseline
    (52, 110, "in front of both cameras"),  # the older frame as image a: the forward test too
    # 42.2 m, a pose 8 deg off the truth: coverage 0.666 and scale 1.2004, both a
    # hair beyond their bounds (the verifier's thinnest margin against a wrong pose)
    (58, 110, "median scale change"),
    # 42.1 m: the most inliers (57 of 1000 features) of any pair over 40 m apart
    (113, 61, "feature share 0.06 < 0.25"),
])
def test_far_pair_with_one_geometry_is_not_a_forward_revisit(kitti, a, b, why):
    K, _, features = kitti
    v = _verify(GeometricVerifier(), features(a), features(b), K)
    assert not v.accepted and v.accepted_by is None
    assert v.reason.startswith("view overlap too small") and why in v.reason


def test_shared_view_coverage_follows_the_rotation():
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    rng = np.random.default_rng(0)
    xy = rng.uniform([0, 0], [640, 480], (400, 2))
    left = xy[xy[:, 0] < 320]
    # same orientation: the shared part is the whole view, as hull_coverage
    assert shared_view_coverage(xy, left, xy, K, np.eye(3)) == pytest.approx(hull_coverage(xy, left))
    # the other camera turned 32.6 deg to the left (about the image's y axis): it
    # faces the left half of this view only, which the left inliers fill
    a = math.atan(320 / 500)
    Ry = np.array([[math.cos(a), 0, -math.sin(a)], [0, 1, 0], [math.sin(a), 0, math.cos(a)]])
    turned = shared_view_coverage(xy, left, xy, K, Ry)
    assert turned > 0.9 > hull_coverage(xy, left)
    # turned away completely (180 deg): no shared view
    assert shared_view_coverage(xy, left, xy, K, np.diag([-1.0, 1.0, -1.0])) == 0.0
    assert shared_view_coverage(xy, left[:2], xy, K, np.eye(3)) == 0.0


@pytest.mark.slow
@pytest.mark.heavy
def test_kitti_near_pairs_verified_far_pairs_refused(kitti, shared_data):
    """The figure of ``bench_loop_pr.py --real``: 456 of the 612 pairs 1-5 m apart
    (74.5 %; 289 before the forward revisit, 424 before the decisive share), asked
    here at 70 % (issue 33's bar) with room for the RANSAC of another OpenCV build;
    none of the 115 > 50 m apart."""
    K, wTc, features = kitti
    pos = wTc[:, :3, 3]
    dist = np.linalg.norm(pos[:, None] - pos[None], axis=2)
    n = len(pos)
    near = [(i, j) for i in range(0, n, 2) for j in range(i + 1, n) if 1.0 <= dist[i, j] <= 5.0]
    far = [(i, j) for i in range(0, n, 8) for j in range(i + 1, n, 4) if dist[i, j] > 50.0]
    assert (len(near), len(far)) == (612, 115)
    v = GeometricVerifier()
    ok = sum(_verify(v, features(j), features(i), K).accepted for i, j in near)
    assert ok >= 0.70 * len(near), f"{ok}/{len(near)}"
    assert not any(_verify(v, features(j), features(i), K).accepted for i, j in far)
