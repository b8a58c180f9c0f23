"""Active search: gate, ordering, cap, ZNCC on synthetic images, hardware mode, KITTI 07 numbers."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from frontend.active_search import ActiveSearch
from frontend.active_search_config import ActiveSearchConfig, chi2_2dof
from frontend.search_matchers import ellipse_pixels, extract_patches
from frontend.features import Features
from slamcore.errors import ConfigError, InputError, MeasurementError


#: The parabolic sub-pixel refinement of an integer shift stays within this of the truth, px
#: (the correlation peak of a random texture is not exactly symmetric).
SUBPIXEL_TOL_PX = 0.1
#: KITTI 07 targets (see benchmarks/bench_active_search.py for the protocol).
MIN_FOUND = 0.90
MAX_WRONG = 0.02
MAX_IMAGE_FRACTION = 0.10
#: One warp cut from a source patch or from the whole image: the same match within, px.
SAME_WARP_TOL_PX = 1e-3


def _bench():
    # as every test loads a benchmark: with benchmarks/ on sys.path, so the script's
    # siblings (entry.py) import as when it runs
    from tests.benchmarks import load_benchmark

    return load_benchmark("bench_active_search")


def noise_image(seed=0, shape=(200, 300)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, size=shape).astype(np.uint8)
    return cv2.GaussianBlur(img, (3, 3), 0)


def test_chi2_gate_value():
    assert chi2_2dof(0.99) == pytest.approx(9.2103, abs=1e-4)
    assert ActiveSearchConfig().gate == pytest.approx(9.2103, abs=1e-4)
    assert chi2_2dof(1 - math.exp(-0.5)) == pytest.approx(1.0)  # 1-sigma ellipse of 2 dof


def test_ellipse_gate_just_inside_and_outside():
    # S = diag(4, 1): along u the gate boundary is at 2 * sqrt(gamma) px
    S = np.diag([4.0, 1.0])
    g = 9.0  # boundary at du = 6, dv = 3 exactly
    c = np.array([50.0, 40.0])
    u0, v0, mask = ellipse_pixels(c, S, g, (100, 100))
    inside = {(u0 + i, v0 + j) for j, i in zip(*np.nonzero(mask))}
    assert (56, 40) in inside and (57, 40) not in inside          # on the boundary counts as inside
    assert (50, 43) in inside and (50, 44) not in inside
    assert (44, 40) in inside and (43, 40) not in inside
    # a correlated covariance: brute-force check of every pixel of a generous box
    S = np.array([[9.0, 5.0], [5.0, 4.0]])
    c = np.array([30.3, 20.7])
    u0, v0, mask = ellipse_pixels(c, S, 9.21, (60, 60))
    Si = np.linalg.inv(S)
    for v in range(60):
        for u in range(60):
            d = np.array([u, v]) - c
            want = d @ Si @ d <= 9.21
            j, i = v - v0, u - u0
            got = 0 <= j < mask.shape[0] and 0 <= i < mask.shape[1] and mask[j, i]
            assert want == got
    # hardware mode: a point just inside is taken, one just outside is not
    sigma = 2.0
    r = math.sqrt(chi2_2dof(0.99)) * sigma
    img = np.zeros((100, 100), np.uint8)
    s = ActiveSearch(mode="nearest")
    for off, expect in ((r - 1e-6, True), (r + 1e-6, False)):
        f = Features(xy_px=np.array([[50.0 + off, 50.0]]), response=np.array([1.0]))
        res = s.search(img, np.array([[50.0, 50.0]]), np.array([np.eye(2) * sigma**2]), features=f)
        assert bool(res.found[0]) is expect


def _three_landmarks():
    z = np.array([[50.0, 50.0], [150.0, 100.0], [250.0, 150.0]])
    S = np.array([np.eye(2) * 4.0, np.eye(2) * 25.0, np.diag([9.0, 16.0])])
    return z, S


def test_order_largest_ellipse_first_and_cap():
    img = noise_image()
    z, S = _three_landmarks()
    s = ActiveSearch(max_corrections=2, min_score=-1.0)
    assert list(s.search_order(z, S, img.shape)) == [1, 2, 0]
    res = s.search(img, z, S, prev_image=img, prev_xy=z)
    assert list(res.order) == [1, 2] and res.searched.tolist() == [False, True, True]
    assert res.pixels[0] == 0 and res.pixels[1] > res.pixels[2] > 0
    for cap in (1, 3):
        r = ActiveSearch(max_corrections=cap).search(img, z, S, prev_image=img, prev_xy=z)
        assert len(r.order) == cap
    assert len(ActiveSearch(max_corrections=0).search(img, z, S, prev_image=img, prev_xy=z).order) == 3
    # predictions outside the image or with a huge ellipse are not searched and do not use the cap
    z2 = np.vstack([z, [[-50.0, 10.0]], [[100.0, 100.0]]])
    S2 = np.concatenate([S, [np.eye(2) * 900.0, np.eye(2) * 1e5]])
    r = ActiveSearch(max_corrections=3, max_half_extent_px=150).search(img, z2, S2, prev_image=img, prev_xy=z2)
    assert list(r.order) == [1, 2, 0]


def test_max_found_stops_the_search_and_marks_the_rest_skipped():
    img = noise_image()
    z, S = _three_landmarks()
    # the same image as the patches' source: every searched landmark is found
    full = ActiveSearch(max_corrections=0).search(img, z, S, prev_image=img, prev_xy=z)
    assert full.found.all() and not full.skipped.any()
    r = ActiveSearch(max_corrections=0).search(img, z, S, prev_image=img, prev_xy=z, max_found=2)
    assert list(r.order) == [1, 2] and r.found.tolist() == [False, True, True]
    assert r.skipped.tolist() == [True, False, False]
    np.testing.assert_array_equal(r.uv[1:], full.uv[1:])
    # a landmark searched but not found does not use the budget: the next one is searched
    patches = extract_patches(img, z, 11)
    patches[1] = patches[1][::-1, ::-1].T  # a patch that is nowhere in its ellipse
    r = ActiveSearch(max_corrections=0).search(img, z, S, patches=patches, max_found=2)
    assert list(r.order) == [1, 2, 0] and r.found.tolist() == [True, False, True]
    assert not r.skipped.any()


def test_image_fraction_union_and_sum():
    img = noise_image()
    z = np.array([[100.0, 100.0], [100.0, 100.0]])
    S = np.array([np.eye(2) * 4.0] * 2)
    r = ActiveSearch(max_corrections=0).search(img, z, S, prev_image=img, prev_xy=z)
    assert r.image_fraction_sum == pytest.approx(2 * r.image_fraction)
    assert r.image_fraction == pytest.approx(r.pixels[0] / img.size)


def test_zncc_finds_shifted_patch_exactly():
    prev = noise_image(1)
    shift = np.array([7, -4])  # current = previous moved by (+7, -4) px
    M = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
    cur = cv2.warpAffine(prev, M, (prev.shape[1], prev.shape[0]), borderMode=cv2.BORDER_REFLECT)
    rng = np.random.default_rng(2)
    xy_prev = np.column_stack([rng.integers(30, 260, 15), rng.integers(30, 160, 15)]).astype(float)
    truth = xy_prev + shift
    # predictions off the truth by a few px, inside a sigma = 4 px ellipse
    z = truth + rng.uniform(-5, 5, size=truth.shape)
    S = np.array([np.eye(2) * 16.0] * len(z))
    r = ActiveSearch(max_corrections=0, subpixel=False).search(cur, z, S, prev_image=prev, prev_xy=xy_prev)
    assert r.found.all()
    assert np.array_equal(r.uv, truth)  # integer peak: exact
    assert np.all(r.score > 0.999)
    rs = ActiveSearch(max_corrections=0).search(cur, z, S, prev_image=prev, prev_xy=xy_prev)
    assert np.abs(rs.uv - truth).max() <= SUBPIXEL_TOL_PX
    # stored patches give the same answer as cutting them from the previous image
    patches = extract_patches(prev, xy_prev, 11)
    r2 = ActiveSearch(max_corrections=0, subpixel=False).search(cur, z, S, patches=patches)
    assert np.array_equal(r.uv, r2.uv)
    # a landmark whose truth is outside its (small) ellipse is not found at the truth
    z_far = truth + 12.0
    r3 = ActiveSearch(max_corrections=0).search(cur, z_far, np.array([np.eye(2)] * len(z)),
                                                prev_image=prev, prev_xy=xy_prev)
    assert not np.any(r3.found & (np.linalg.norm(r3.uv - truth, axis=1) < 1.0))


def test_zncc_rejects_flat_and_low_score():
    flat = np.full((100, 100), 90, np.uint8)
    z = np.array([[50.0, 50.0]])
    S = np.array([np.eye(2) * 4.0])
    r = ActiveSearch().search(flat, z, S, prev_image=flat, prev_xy=z)
    assert r.searched[0] and not r.found[0]
    a, b = noise_image(3, (100, 100)), noise_image(4, (100, 100))
    r = ActiveSearch(min_score=0.95).search(b, z, S, prev_image=a, prev_xy=z)
    assert r.searched[0] and not r.found[0] and r.score[0] < 0.95


def test_appearance_prediction_by_warping():
    prev = noise_image(5, (200, 200))
    prev = cv2.GaussianBlur(prev, (5, 5), 0)
    A = np.array([[1.25, 0.0], [0.0, 1.25]])  # the current image is a 25 % zoom about (100, 100)
    c = np.array([100.0, 100.0])
    M = np.hstack([A, (c - A @ c)[:, None]])
    cur = cv2.warpAffine(prev, M, (200, 200), flags=cv2.INTER_LINEAR)
    xy_prev = np.array([[80.0, 84.0], [120.0, 112.0], [92.0, 120.0]])
    truth = xy_prev @ A.T + (c - A @ c)
    S = np.array([np.eye(2) * 9.0] * 3)
    aff = np.array([A] * 3)
    on = ActiveSearch(predict_appearance=True, min_score=0.0).search(
        cur, truth + 1.0, S, prev_image=prev, prev_xy=xy_prev, affine=aff)
    off = ActiveSearch(min_score=0.0).search(cur, truth + 1.0, S, prev_image=prev, prev_xy=xy_prev, affine=aff)
    assert on.found.all()
    assert np.abs(on.uv - truth).max() < 0.5
    assert np.all(on.score > off.score)
    with pytest.raises(InputError):
        ActiveSearch(predict_appearance=True).search(cur, truth, S, patches=extract_patches(prev, xy_prev, 11),
                                                     affine=aff)


def test_appearance_prediction_from_source_patches():
    """Warping from patches cut larger around the points (what the tracker keeps)
    gives what warping from the whole previous image gives."""
    prev = cv2.GaussianBlur(noise_image(6, (200, 200)), (5, 5), 0)
    th = math.radians(35.0)
    A = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])  # a 35 deg roll
    c = np.array([100.0, 100.0])
    cur = cv2.warpAffine(prev, np.hstack([A, (c - A @ c)[:, None]]), (200, 200), flags=cv2.INTER_LINEAR)
    xy_prev = np.array([[80.0, 84.0], [120.0, 112.0], [92.0, 120.0]])
    truth = xy_prev @ A.T + (c - A @ c)
    S = np.array([np.eye(2) * 9.0] * 3)
    aff = np.array([A] * 3)
    search = ActiveSearch(predict_appearance=True)
    from_image = search.search(cur, truth, S, prev_image=prev, prev_xy=xy_prev, affine=aff)
    sources = extract_patches(prev, xy_prev, 21)
    from_sources = search.search(cur, truth, S, source_patches=sources, affine=aff)
    assert from_sources.found.all() and from_image.found.all()
    # not bit-equal: cv2.warpAffine rounds sampling positions to 1/32 px from other origins
    assert np.abs(from_sources.uv - from_image.uv).max() < SAME_WARP_TOL_PX
    assert np.abs(from_sources.uv - truth).max() < 0.5
    # unwarped, a 35 deg roll is beyond ZNCC's reach
    assert not ActiveSearch().search(cur, truth, S, prev_image=prev, prev_xy=xy_prev).found.any()
    with pytest.raises(InputError):  # even sides have no centre pixel
        search.search(cur, truth, S, source_patches=sources[:, :20, :20], affine=aff)
    with pytest.raises(InputError):
        search.search(cur, truth, S, source_patches=sources, affine=np.zeros((3, 2, 2)))


def test_hardware_mode_picks_nearest_inside():
    img = np.zeros((100, 100), np.uint8)
    z = np.array([[50.0, 50.0]])
    S = np.array([np.diag([100.0, 1.0])])  # long along u, thin along v
    pts = np.array([[62.0, 50.0],   # 12 px along u: d2 = 1.44 (inside)
                    [50.0, 52.5],   # 2.5 px along v: d2 = 6.25 (inside, farther in Mahalanobis)
                    [50.0, 54.0],   # d2 = 16 (outside)
                    [45.0, 50.0]])  # d2 = 0.25: nearest
    f = Features(xy_px=pts, response=np.array([1.0, 2.0, 3.0, 4.0]))
    r = ActiveSearch(mode="nearest").search(img, z, S, features=f)
    assert r.found[0] and np.array_equal(r.uv[0], [45.0, 50.0]) and r.score[0] == 4.0
    assert r.d2[0] == pytest.approx(0.25)
    f2 = Features(xy_px=pts[:3], response=np.ones(3))
    r = ActiveSearch(mode="nearest").search(img, z, S, features=f2)
    assert np.array_equal(r.uv[0], [62.0, 50.0])  # nearest in Mahalanobis, not in pixels
    f3 = Features(xy_px=pts[2:3], response=np.ones(1))
    assert not ActiveSearch(mode="nearest").search(img, z, S, features=f3).found[0]
    with pytest.raises(InputError):
        ActiveSearch(mode="nearest").search(img, z, S)


@pytest.mark.parametrize("field, value", [
    # wrong type
    ("gate_probability", "0.99"), ("max_corrections", 2.5), ("patch_size_px", True),
    ("subpixel", 1), ("predict_appearance", "yes"), ("min_score", None),
    # out of range
    ("gate_probability", 0.0), ("gate_probability", 1.0), ("max_corrections", -1),
    ("max_corrections", 2**24 + 1), ("patch_size_px", 1), ("patch_size_px", 257),
    ("patch_size_px", 10),                              # even: no centre pixel
    ("min_score", 2.0), ("min_score", -1.5), ("min_patch_std", -0.1),
    ("max_half_extent_px", 0.0), ("max_half_extent_px", float("inf")),
    # unknown mode
    ("mode", "x"),
])
def test_config_refuses_a_bad_value_naming_it(field, value):
    with pytest.raises(ConfigError, match=rf"^active_search\.{field}\b"):
        ActiveSearchConfig(**{field: value})
    with pytest.raises(ConfigError, match=rf"^active_search\.{field}\b"):
        ActiveSearch(**{field: value})  # keyword overrides are checked the same way


def test_config_and_input_validation():
    assert ActiveSearchConfig.SECTION == "active_search"
    img = noise_image()
    z = np.array([[50.0, 50.0]])
    with pytest.raises(MeasurementError):
        ActiveSearch().search(img, z, np.array([[[1.0, 0.0], [0.0, -1.0]]]), prev_image=img, prev_xy=z)
    with pytest.raises(InputError):
        ActiveSearch().search(img, z, np.array([np.eye(2)]))  # no patches


# ---------------------------------------------------------------- KITTI 07


def _check_targets(res):
    assert res["found_rate"] >= MIN_FOUND, res
    assert res["wrong_rate"] <= MAX_WRONG, res
    assert res["image_fraction_mean"] < MAX_IMAGE_FRACTION, res


def test_kitti07_few_pairs(shared_data):
    b = _bench()
    res = b.evaluate([10, 50, 90, 130], data=b.Kitti(shared_data / "kitti07"))
    print("KITTI 07, 4 pairs:", res)
    assert res["visible"] >= 40
    _check_targets(res)


@pytest.mark.slow
def test_kitti07_all_pairs(shared_data):
    b = _bench()
    data = b.Kitti(shared_data / "kitti07")
    res = b.evaluate(b.all_pairs(data), data=data)
    print("KITTI 07, all pairs:", res)
    assert res["pairs"] == 159
    _check_targets(res)


def test_no_landmarks_and_nan_predictions():
    img = noise_image()
    r = ActiveSearch().search(img, np.zeros((0, 2)), np.zeros((0, 2, 2)), patches=np.zeros((0, 11, 11), np.float32))
    assert len(r.order) == 0 and r.found.shape == (0,) and r.image_fraction == 0.0
    z = np.array([[np.nan, 10.0], [50.0, 50.0]])
    r = ActiveSearch().search(img, z, np.array([np.eye(2)] * 2), prev_image=img, prev_xy=np.nan_to_num(z))
    assert r.searched.tolist() == [False, True] and r.found[1]


def _shifted_pair(n=9):
    """A textured frame, the next one shifted by (3, 2) px, ``n`` points on a grid in both."""
    prev = noise_image(11, (200, 300))
    cur = np.roll(prev, (2, 3), axis=(0, 1))
    xy = np.array([[60.0 + 30 * (k % 5), 60.0 + 40 * (k // 5)] for k in range(n)])
    return prev, cur, xy, xy + [3.0, 2.0], np.array([np.eye(2) * 16.0] * n)


def test_search_refuses_points_and_patches_it_cannot_use():
    prev, cur, xy, truth, S = _shifted_pair()
    with pytest.raises(InputError, match="prev_xy"):  # (2, N): was reshaped into scrambled points
        ActiveSearch().search(cur, truth, S, prev_image=prev, prev_xy=xy.T)
    with pytest.raises(InputError, match="prev_xy"):  # was an IndexError once searched
        ActiveSearch(predict_appearance=True).search(
            cur, truth, S, prev_image=prev, prev_xy=xy[:3], affine=np.array([np.eye(2)] * len(xy))
        )
    with pytest.raises(InputError, match="patches"):
        ActiveSearch().search(cur, truth, S, patches=[np.zeros((11, 11)), np.zeros((9, 9))])
    # a list of patches is the array it lists (was an AttributeError)
    listed = ActiveSearch().search(cur, truth, S, patches=list(extract_patches(prev, xy, 11)))
    assert listed.found.all()


def test_a_repredict_answer_of_another_length_is_refused():
    prev, cur, xy, truth, S = _shifted_pair()
    asked = []

    def one_row(found, uv, pending):
        asked.append(len(pending))
        return np.array([[150.0, 100.0]]), np.array([np.eye(2) * 16.0])

    with pytest.raises(InputError, match="repredict returned 1 predictions"):  # was broadcast
        ActiveSearch(order="sequential").search(cur, truth, S, prev_image=prev, prev_xy=xy, repredict=one_row)
    assert asked and asked[0] > 1
