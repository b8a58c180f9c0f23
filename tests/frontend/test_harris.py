"""Harris detector: float reference vs OpenCV, fixed point vs float, tessellation, bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from frontend.features import Detector, Features
from frontend.harris import (
    GAUSS5_FLOAT,
    GAUSS5_INT,
    RESPONSE_SHIFT,
    HarrisConfig,
    HarrisDetector,
    harris_response_fixed,
    harris_response_float,
    smooth_float,
    structure_response_float,
    tessellate,
)
from frontend.image import check_gray, load_gray
from slamcore.errors import ConfigError, InputError

#: Share of tessellated points that must be identical between fixed and float.
MIN_IDENTICAL_SHARE = 0.90
#: cornerHarris runs in float32: relative agreement allowed on R (of max |R|).
CV_FLOAT32_RTOL = 1e-4


def kitti_frames(shared_data, step=1):
    files = sorted((shared_data / "kitti07" / "image_0").glob("*.png"))
    if len(files) < 160:
        pytest.skip("KITTI 07 frames missing")
    return files[::step]


def identical_share(a: Features, b: Features) -> tuple[int, int]:
    """(points with the same cell and position in both, size of the union)."""
    sa = {(int(c), float(x), float(y)) for c, (x, y) in zip(a.cell, a.xy_px)}
    sb = {(int(c), float(x), float(y)) for c, (x, y) in zip(b.cell, b.xy_px)}
    return len(sa & sb), len(sa | sb)


def noise_texture(shape, seed):
    """Procedural multi-scale noise with blocky corners, uint8, seeded."""
    rng = np.random.default_rng(seed)
    h, w = shape
    img = np.zeros(shape)
    for scale in (3, 6, 12, 48):
        small = rng.standard_normal((h // scale + 2, w // scale + 2))
        interp = cv2.INTER_NEAREST if scale == 6 else cv2.INTER_CUBIC
        img += cv2.resize(small, (w, h), interpolation=interp)
    return np.round(np.clip(128 + 40 * img, 0, 255)).astype(np.uint8)


# ----------------------------------------------------------------------------- image checks


@pytest.mark.parametrize("bad, match", [
    (np.zeros((0, 5), np.uint8), "empty"),
    (np.zeros((10, 10), np.float64), "uint8"),
    (np.zeros((10, 10), np.uint16), "uint8"),
    (np.zeros((10, 10, 3), np.uint8), "greyscale"),
    (np.zeros(10, np.uint8), "greyscale"),
    ([[1, 2], [3, 4]], "numpy array"),
])
def test_check_gray_refuses_bad_images(bad, match):
    with pytest.raises(InputError, match=match):
        check_gray(bad)
    for det in (HarrisDetector(), HarrisDetector(arithmetic="fixed")):
        with pytest.raises(InputError):
            det.detect(bad)


def test_load_gray_names_missing_and_unreadable_files(tmp_path):
    missing = tmp_path / "nope.png"
    with pytest.raises(InputError, match="nope.png"):
        load_gray(missing)
    garbage = tmp_path / "garbage.png"
    garbage.write_bytes(b"not a png at all")
    with pytest.raises(InputError, match="garbage.png") as err:
        load_gray(garbage)
    assert err.value.path == str(garbage)


def test_load_gray_reads_kitti(shared_data):
    img = load_gray(kitti_frames(shared_data)[0])
    assert img.shape == (370, 1226) and img.dtype == np.uint8


# ----------------------------------------------------------------------------- config


@pytest.mark.parametrize("field, value", [
    # wrong type
    ("cell_size_px", 8.5), ("k", "0.04"), ("threshold", None), ("border_px", True),
    ("arithmetic", 0),
    # out of range
    ("border_px", 4), ("border_px", 4097), ("cell_size_px", 0), ("cell_size_px", 4097),
    ("k", 0.0), ("k", 0.3), ("k", 0.0004),            # 0.0004 * 1024 rounds to k_num = 0
    ("threshold", -1.0), ("threshold", float("nan")), ("threshold", 2.0**42),
    # unknown mode
    ("arithmetic", "double"),
])
def test_config_refuses_a_bad_value_naming_it(field, value):
    with pytest.raises(ConfigError, match=rf"^harris\.{field}\b"):
        HarrisConfig(**{field: value})
    with pytest.raises(ConfigError, match=rf"^harris\.{field}\b"):
        HarrisDetector(**{field: value})  # keyword overrides are checked the same way


def test_config_limits_are_the_fixed_point_ones():
    assert HarrisConfig(k=0.0005).k_num == 1                 # just above half a step
    assert HarrisConfig(threshold=2.0**42 - 1).threshold_fixed < 2**62


def test_config_section_and_fixed_constants():
    cfg = HarrisConfig()
    assert HarrisConfig.SECTION == "harris"
    assert cfg.k_num == 41                                    # 41/1024 ~ 0.04
    assert abs(cfg.k_num / 1024 - cfg.k) / cfg.k < 1e-3
    assert sum(GAUSS5_INT) == 256                             # normalised by >> 8
    assert np.max(np.abs(np.array(GAUSS5_INT) / 256 - GAUSS5_FLOAT)) < 0.004
    assert isinstance(HarrisDetector(), Detector)


# ----------------------------------------------------------------------------- float vs OpenCV


def test_float_response_matches_cornerharris(shared_data):
    """With a 3x3 box window, our response on the smoothed image is cornerHarris's / 16.

    cornerHarris(S, blockSize=3, ksize=1) uses the [-1, 0, 1] derivative scaled
    by 1/blockSize and an unnormalised 3x3 box sum: its Ix is 2/3 of ours
    (central difference / 2) and its A sums 9 pixels where ours averages them,
    so A_cv = 4 A_ours and R_cv = 16 R_ours.
    """
    img = load_gray(kitti_frames(shared_data)[0])
    k = 0.04
    s = smooth_float(img)
    ours = structure_response_float(s, k, window=np.ones(3) / 3)
    cv = cv2.cornerHarris(s.astype(np.float32), blockSize=3, ksize=1, k=k).astype(np.float64)
    inner = (slice(8, -8), slice(8, -8))
    scale = np.abs(cv[inner]).max()
    err = np.abs(cv[inner] - 16.0 * ours[inner]).max()
    assert err <= CV_FLOAT32_RTOL * scale, err / scale
    # Same strongest corners.
    top_cv = np.argsort(cv[inner], axis=None)[-50:]
    top_ours = np.argsort(ours[inner], axis=None)[-50:]
    assert len(set(top_cv) & set(top_ours)) >= 45


def test_float_detector_equals_tessellated_response(shared_data):
    img = load_gray(kitti_frames(shared_data)[0])
    cfg = HarrisConfig()
    feats = HarrisDetector(cfg).detect(img)
    r = harris_response_float(img, cfg.k)
    assert feats.xy_px.dtype == np.float64 and feats.xy_px.shape == (len(feats), 2)
    assert feats.response.dtype == np.float64 and feats.cell.dtype == np.int64
    u, v = feats.xy_px.T.astype(int)
    np.testing.assert_array_equal(feats.response, r[v, u])
    assert np.all(feats.response > cfg.threshold)
    assert np.all(np.diff(feats.cell) > 0)
    nc = -(-img.shape[1] // cfg.cell_size_px)
    np.testing.assert_array_equal(feats.cell, (v // 32) * nc + u // 32)
    assert np.all((u >= 8) & (u < img.shape[1] - 8) & (v >= 8) & (v < img.shape[0] - 8))
    # Every kept point is the maximum of its cell (inside the border).
    for c, uu, vv in zip(feats.cell[:40], u[:40], v[:40]):
        r0, c0 = (c // nc) * 32, (c % nc) * 32
        block = r[max(r0, 8):min(r0 + 32, img.shape[0] - 8), max(c0, 8):min(c0 + 32, img.shape[1] - 8)]
        assert r[vv, uu] == block.max()
    again = HarrisDetector(cfg).detect(img)
    np.testing.assert_array_equal(again.xy_px, feats.xy_px)


# ----------------------------------------------------------------------------- tessellation


def brute_force_tessellate(r, cs, border, thr):
    h, w = r.shape
    out = []
    nc = -(-w // cs)
    for cr in range(-(-h // cs)):
        for cc in range(nc):
            best = None
            for v in range(cr * cs, min((cr + 1) * cs, h)):
                for u in range(cc * cs, min((cc + 1) * cs, w)):
                    if border <= v < h - border and border <= u < w - border:
                        if best is None or r[v, u] > best[0]:
                            best = (r[v, u], u, v)
            if best is not None and best[0] > thr:
                out.append((cr * nc + cc, best[1], best[2], best[0]))
    return out


@pytest.mark.parametrize("shape, cs, border", [((37, 53), 8, 5), ((40, 40), 10, 6), ((23, 31), 32, 5)])
def test_tessellate_matches_brute_force_with_ties(shape, cs, border):
    rng = np.random.default_rng(7)
    r = rng.integers(-3, 4, size=shape).astype(np.int64)      # many ties
    xy, val, cell = tessellate(r, cs, border, 0)
    got = [(int(c), int(x), int(y), int(v)) for c, (x, y), v in zip(cell, xy, val)]
    assert got == brute_force_tessellate(r, cs, border, 0)
    xy, val, cell = tessellate(r.astype(np.float64), cs, border, 0.0)
    assert [(int(c), int(x), int(y)) for c, (x, y) in zip(cell, xy)] == \
        [g[:3] for g in brute_force_tessellate(r, cs, border, 0)]


def test_tessellate_threshold_is_strict():
    r = np.zeros((20, 20))
    r[10, 10] = 5.0
    assert len(tessellate(r, 20, 5, 5.0)[0]) == 0
    assert len(tessellate(r, 20, 5, 4.999)[0]) == 1


# ----------------------------------------------------------------------------- fixed point


def test_fixed_response_close_to_float(shared_data):
    """Fixed R / 2^20 vs float R where |R| > threshold: median and 99 % relative errors."""
    img = load_gray(kitti_frames(shared_data)[0])
    rf = harris_response_float(img)
    ri = harris_response_fixed(img)
    inner = (slice(5, -5), slice(5, -5))
    assert np.all(ri[:5] == np.iinfo(np.int64).min)
    fx = ri[inner] / 2.0**RESPONSE_SHIFT
    fl = rf[inner]
    strong = np.abs(fl) > HarrisConfig().threshold
    rel = np.abs(fx[strong] - fl[strong]) / np.abs(fl[strong])
    print(f"fixed vs float |R| > thr: median rel err {np.median(rel):.4f}, "
          f"p99 {np.percentile(rel, 99):.4f}")
    assert np.median(rel) < 0.02
    assert np.percentile(rel, 99) < 0.08


def test_fixed_extreme_contrast_no_overflow():
    """Binary 0/255 noise drives every word to its widest; fixed must track float."""
    rng = np.random.default_rng(3)
    img = (rng.integers(0, 2, size=(64, 80)) * 255).astype(np.uint8)
    rf = harris_response_float(img)[5:-5, 5:-5]
    ri = harris_response_fixed(img)[5:-5, 5:-5] / 2.0**RESPONSE_SHIFT
    scale = np.abs(rf).max()
    assert np.abs(ri - rf).max() < 0.03 * scale


def _share_over(frames, cfg):
    same = total = 0
    for f in frames:
        img = load_gray(f)
        a = HarrisDetector(cfg).detect(img)
        b = HarrisDetector(cfg, arithmetic="fixed").detect(img)
        s, t = identical_share(a, b)
        same += s
        total += t
    return same, total


def test_fixed_vs_float_identical_points_subset(shared_data):
    frames = kitti_frames(shared_data, step=20)          # 8 frames
    same, total = _share_over(frames, HarrisConfig())
    print(f"fixed vs float, {len(frames)} KITTI 07 frames: {same}/{total} = {same / total:.4f} identical")
    assert same / total >= MIN_IDENTICAL_SHARE


@pytest.mark.slow
def test_fixed_vs_float_identical_points_all_kitti07(shared_data):
    frames = kitti_frames(shared_data)
    same, total = _share_over(frames, HarrisConfig())
    print(f"fixed vs float, all {len(frames)} KITTI 07 frames: {same}/{total} = "
          f"{same / total:.4f} identical")
    assert same / total >= MIN_IDENTICAL_SHARE


def test_fixed_vs_float_on_noise_texture():
    img = noise_texture((240, 320), seed=11)
    cfg = HarrisConfig(cell_size_px=16)
    same, total = identical_share(HarrisDetector(cfg).detect(img),
                                  HarrisDetector(cfg, arithmetic="fixed").detect(img))
    assert total > 100
    assert same / total >= MIN_IDENTICAL_SHARE


def test_structure_response_float_checks_its_input_as_smooth_float_does():
    img = np.random.default_rng(2).uniform(0, 255, size=(40, 50))
    nan = img.copy()
    nan[20, 25] = np.nan  # spread over 45 pixels of the response before
    for bad in (np.dstack([img] * 3), nan, np.zeros((0, 10))):  # colour came back (H, W, 3)
        with pytest.raises(InputError, match="image"):
            structure_response_float(bad, 0.04)
    # an int64 or a nested list was OpenCV's error; they are numbers like any image
    as_int = structure_response_float(img.astype(np.int64), 0.04)
    np.testing.assert_array_equal(as_int, structure_response_float(img.astype(np.int64).astype(float), 0.04))
    assert structure_response_float(img.tolist(), 0.04).shape == img.shape
