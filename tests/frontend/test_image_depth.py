"""16-bit images read as 8 bits (frontend.image): values in the low bits (a depth map,
a 12-bit camera's raw data) would be near black, and are refused by name."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from frontend.image import load_gray
from slamcore.errors import InputError


def _write16(path, values: np.ndarray) -> None:
    assert cv2.imwrite(str(path), values.astype(np.uint16))


def test_sixteen_bit_values_in_the_low_bits_are_refused(tmp_path):
    rng = np.random.default_rng(0)
    _write16(tmp_path / "raw12.png", rng.integers(0, 4096, (40, 60)))  # 12-bit raw: top byte 0..15
    with pytest.raises(InputError, match=r"raw12.png: 16-bit image .* 16 grey levels"):
        load_gray(tmp_path / "raw12.png")
    _write16(tmp_path / "depth.png", 5000 * (1 + 0.3 * rng.random((40, 60))))  # TUM depth, 1-1.3 m
    with pytest.raises(InputError, match="depth map"):
        load_gray(tmp_path / "depth.png")


def test_sixteen_bit_full_range_reads_as_its_top_byte(tmp_path):
    img8 = np.random.default_rng(1).integers(0, 256, (40, 60)).astype(np.uint8)
    _write16(tmp_path / "full.png", img8.astype(np.uint16) * 257)
    assert np.array_equal(load_gray(tmp_path / "full.png"), img8)


@pytest.mark.parametrize("suffix", [".pgm", ".tif"])
def test_other_sixteen_bit_formats_are_refused_too(tmp_path, suffix):
    raw = np.random.default_rng(2).integers(0, 4096, (40, 60))
    _write16(tmp_path / f"raw{suffix}", raw)
    with pytest.raises(InputError, match="16-bit image"):
        load_gray(tmp_path / f"raw{suffix}")


def test_a_flat_eight_bit_image_is_read(tmp_path):
    assert cv2.imwrite(str(tmp_path / "blank.png"), np.zeros((40, 60), np.uint8))  # a lens cap
    assert load_gray(tmp_path / "blank.png").max() == 0


def test_an_image_opencv_cannot_decode_gives_our_line_only(tmp_path, capfd):
    """Tenth hostile pass: a float TIFF printed OpenCV's own ``[ WARN ]`` line on stderr
    before the one-line error."""
    path = tmp_path / "frame.tiff"
    cv2.imwrite(str(path), np.random.default_rng(0).random((40, 50)).astype(np.float32))
    level = cv2.utils.logging.getLogLevel()
    with pytest.raises(InputError, match="cannot read image"):
        load_gray(path)
    assert capfd.readouterr().err == ""
    assert cv2.utils.logging.getLogLevel() == level  # OpenCV's own setting is left as it was
