"""Simulated FPGA Harris stream: bit-identical to fixed-point Harris, ping-pong timing."""

from __future__ import annotations

import numpy as np
import pytest

from frontend.features import Detector, Features
from frontend.fpga_stream import FpgaHarrisStream, FpgaTiming
from frontend.harris import HarrisConfig, HarrisDetector
from frontend.image import load_gray
from slamcore.errors import ConfigError, InputError
from tests.frontend.test_harris import kitti_frames, noise_texture

#: Tolerance on times computed from the pixel clock, seconds.
TIME_TOL_S = 1e-12


def assert_same_points(a: Features, b: Features):
    np.testing.assert_array_equal(a.xy_px, b.xy_px)
    np.testing.assert_array_equal(a.response, b.response)
    np.testing.assert_array_equal(a.cell, b.cell)
    assert a.xy_px.dtype == b.xy_px.dtype and a.cell.dtype == b.cell.dtype


# ----------------------------------------------------------------------------- bit identity


def test_stream_bit_identical_on_kitti_frames(shared_data):
    cfg = HarrisConfig(arithmetic="fixed")
    stream, ref = FpgaHarrisStream(cfg), HarrisDetector(cfg)
    for f in kitti_frames(shared_data)[::53]:                 # frames 0, 53, 106, 159
        img = load_gray(f)
        got = stream.detect(img)
        assert len(got) > 50
        assert_same_points(got, ref.detect(img))


@pytest.mark.slow
@pytest.mark.heavy  # 17 s of CI; test_stream_bit_identical_on_kitti_frames checks every 53rd frame there
def test_stream_bit_identical_on_all_kitti07(shared_data):
    cfg = HarrisConfig(arithmetic="fixed")
    stream, ref = FpgaHarrisStream(cfg), HarrisDetector(cfg)
    for f in kitti_frames(shared_data):
        img = load_gray(f)
        assert_same_points(stream.detect(img), ref.detect(img))


@pytest.mark.parametrize("shape, kwargs, latency", [
    ((480, 640), dict(), 6),
    ((101, 77), dict(cell_size_px=16, border_px=5), 6),      # cells cut by both edges
    ((90, 130), dict(cell_size_px=7, border_px=9, threshold=0.0), 9),
    ((64, 64), dict(cell_size_px=3, border_px=5, k=0.05), 5),
])
def test_stream_bit_identical_on_noise(shape, kwargs, latency):
    img = noise_texture(shape, seed=sum(shape))
    cfg = HarrisConfig(arithmetic="fixed", **kwargs)
    stream = FpgaHarrisStream(cfg, FpgaTiming(latency_lines=latency))
    got = stream.detect(img)
    assert len(got) > 0
    assert_same_points(got, HarrisDetector(cfg).detect(img))


def test_stream_bit_identical_on_binary_noise_and_ties():
    """Extreme words (0/255 noise) and flat regions full of equal responses."""
    rng = np.random.default_rng(5)
    img = (rng.integers(0, 2, size=(70, 90)) * 255).astype(np.uint8)
    img[30:60, 40:80] = 100                                   # flat: ties everywhere
    img[40:45, 50:55] = 200                                   # a few equal corners
    for thr in (0.0, 1e4):
        cfg = HarrisConfig(arithmetic="fixed", cell_size_px=8, border_px=5, threshold=thr)
        assert_same_points(FpgaHarrisStream(cfg).detect(img), HarrisDetector(cfg).detect(img))
    flat = np.full((40, 40), 7, np.uint8)
    cfg = HarrisConfig(arithmetic="fixed", cell_size_px=8, border_px=5, threshold=0.0)
    assert len(FpgaHarrisStream(cfg).detect(flat)) == 0 == len(HarrisDetector(cfg).detect(flat))


def test_tiny_images_give_no_points():
    stream = FpgaHarrisStream()
    for shape in ((16, 16), (17, 200), (200, 5)):
        assert len(stream.detect(np.zeros(shape, np.uint8))) == 0


# ----------------------------------------------------------------------------- timing


def test_stamp_formula_vga():
    t = FpgaTiming()
    f = 25.175e6
    end = (479 * 800 + 640) / f
    assert abs(t.write_end_s((480, 640), 0.0) - end) < TIME_TOL_S
    assert abs(t.ready_s((480, 640), 1.0) - (1.0 + end + (6 * 800 + 13) / f)) < TIME_TOL_S
    assert abs(t.frame_period_s((480, 640)) - 525 * 800 / f) < TIME_TOL_S   # 59.94 Hz


@pytest.mark.parametrize("field, value", [
    # wrong type
    ("pipeline_cycles", 1.5), ("pixel_clock_hz", "25 MHz"), ("v_blank_lines", True),
    # out of range (no mode to choose here)
    ("latency_lines", 4), ("pixel_clock_hz", 0.0), ("pixel_clock_hz", float("inf")),
    ("h_blank_px", -1), ("v_blank_lines", -1), ("pipeline_cycles", -1),
])
def test_timing_refuses_a_bad_value_naming_it(field, value):
    # no config file sets the timing: its errors name the class
    with pytest.raises(ConfigError, match=rf"^fpgatiming\.{field}\b"):
        FpgaTiming(**{field: value})


def test_stream_overrides_are_checked_like_the_harris_config():
    assert FpgaHarrisStream(cell_size_px=16).config == HarrisConfig(arithmetic="fixed", cell_size_px=16)
    with pytest.raises(ConfigError, match=r"^harris\.cell_size_px\b"):
        FpgaHarrisStream(cell_size_px=0)


# ----------------------------------------------------------------------------- ping-pong


@pytest.fixture(scope="module")
def three_frames():
    imgs = [noise_texture((120, 160), seed=s) for s in (1, 2, 3)]
    cfg = HarrisConfig(arithmetic="fixed", cell_size_px=16)
    ref = [HarrisDetector(cfg).detect(im) for im in imgs]
    assert all(len(r) > 10 for r in ref)
    assert not np.array_equal(ref[0].xy_px, ref[1].xy_px)
    return cfg, imgs, ref


def test_frame_readable_while_next_is_written(three_frames):
    cfg, imgs, ref = three_frames
    stream = FpgaHarrisStream(cfg)                            # v_blank 45 lines > latency
    s0 = stream.push_frame(imgs[0], 0.0)
    assert stream.read(0.0) is None                           # nothing before the stamp
    assert stream.read(np.nextafter(s0, 0.0)) is None
    got = stream.read(s0)
    assert_same_points(got, ref[0])
    assert got.ready_time_s == s0
    assert stream.readable(s0) == (0, "Harris_LMK_A")

    t1 = stream.next_start_s()
    assert t1 > s0
    s1 = stream.push_frame(imgs[1], t1)
    # Frame 1 is being written into B: the processor still reads frame 0 from A.
    for now in (t1, (t1 + s1) / 2, np.nextafter(s1, 0.0)):
        assert_same_points(stream.read(now), ref[0])
        assert stream.readable(now) == (0, "Harris_LMK_A")
    assert_same_points(stream.read(s1), ref[1])               # swap at the stamp
    assert stream.readable(s1) == (1, "Harris_LMK_B")

    s2 = stream.push_frame(imgs[2], stream.next_start_s())
    assert stream.readable(s2) == (2, "Harris_LMK_A")
    assert_same_points(stream.read(s2 - 1e-6), ref[1])
    assert_same_points(stream.read(s2 + 1.0), ref[2])


def test_no_overwrite_before_swap_with_short_blanking(three_frames):
    """v_blank = 0: frame k+1 starts before frame k's stamp; nothing moves before a swap."""
    cfg, imgs, ref = three_frames
    stream = FpgaHarrisStream(cfg, FpgaTiming(v_blank_lines=0))
    s0 = stream.push_frame(imgs[0], 0.0)
    t1 = stream.next_start_s()
    assert t1 < s0
    s1 = stream.push_frame(imgs[1], t1)
    assert stream.read(t1) is None                            # frame 0 not swapped in yet
    assert_same_points(stream.read(s0), ref[0])
    t2 = stream.next_start_s()
    assert t2 < s1
    s2 = stream.push_frame(imgs[2], t2)
    # Frame 2 targets memory A, which still holds frame 0 until frame 1's swap.
    assert stream.readable(t2) == (0, "Harris_LMK_A")
    assert_same_points(stream.read(t2), ref[0])
    assert_same_points(stream.read(s1), ref[1])
    assert_same_points(stream.read(s2), ref[2])


def test_push_and_read_order_is_checked(three_frames):
    cfg, imgs, _ = three_frames
    stream = FpgaHarrisStream(cfg)
    stream.push_frame(imgs[0], 0.0)
    with pytest.raises(InputError, match="overlaps"):
        stream.push_frame(imgs[1], stream.next_start_s() - 1e-6)
    stream.push_frame(imgs[1], 1.0)
    with pytest.raises(InputError, match="precedes"):
        stream.read(0.5)
    with pytest.raises(InputError):
        stream.push_frame(np.zeros((10, 10, 3), np.uint8), 2.0)
    with pytest.raises(InputError):
        stream.push_frame(imgs[2], float("nan"))


def test_detect_is_a_detector_stamped_at_ready_time(three_frames):
    cfg, imgs, ref = three_frames
    stream = FpgaHarrisStream(cfg)
    assert isinstance(stream, Detector)
    a = stream.detect(imgs[0])
    b = stream.detect(imgs[1])
    assert_same_points(a, ref[0])
    assert_same_points(b, ref[1])
    t = stream.timing
    assert a.ready_time_s == pytest.approx(t.ready_s((120, 160), 0.0), abs=TIME_TOL_S)
    assert b.ready_time_s - a.ready_time_s == pytest.approx(t.frame_period_s((120, 160)),
                                                            abs=TIME_TOL_S)
    assert stream.frames_pushed == 2
    for bad in (np.zeros((0, 4), np.uint8), np.zeros((30, 30), np.float32)):
        with pytest.raises(InputError):
            stream.detect(bad)


@pytest.mark.slow
def test_stream_bit_identical_on_a_synthetic_sequence():
    """Every frame of a rendered synthetic image sequence (VGA, 30 frames, one lap)."""
    from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig, make_synthetic_images

    seq = make_synthetic_images(SyntheticImagesConfig(n_frames=30, laps=1.0, pixel_noise_sigma=1.0))
    cfg = HarrisConfig(arithmetic="fixed")
    stream, ref = FpgaHarrisStream(cfg), HarrisDetector(cfg)
    for i in range(len(seq)):
        img = seq.load(i)
        got = stream.detect(img)
        assert len(got) > 50, f"frame {i}: too few points for the comparison to mean much"
        assert_same_points(got, ref.detect(img))
