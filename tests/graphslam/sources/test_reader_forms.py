"""Hostile pass on the image-sequence readers: stamps in messages as plain numbers
(they read ``np.float64(5.192878)``), an EuRoC folder's truth with times in
seconds refused, and a dangling ``.png`` symbolic link refused, not skipped."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from graphslam.sources.spatial.images import read_euroc, read_image_folder, read_tum_rgbd
from graphslam.sources.spatial.sequence import check_increasing, folder_images, list_images
from slamcore.errors import InputError
from tests.graphslam.sources.test_image_readers import _fake_euroc, _png


def test_check_increasing_names_plain_numbers(tmp_path):
    with pytest.raises(InputError) as e:
        check_increasing(np.array([5.088502, 5.297154, 5.192878]), [7, 8, 9], tmp_path / "t.txt")
    assert e.value.line == 9
    assert "5.192878 is not after 5.297154 of line 8" in str(e.value)
    assert "np." not in str(e.value)


def test_tum_rgb_list_with_a_repeated_stamp_names_plain_numbers(tmp_path):
    (tmp_path / "rgb.txt").write_text(
        "# color images\n1305031102.175304 rgb/a.png\n1305031102.211214 rgb/b.png\n"
        "1305031102.211214 rgb/c.png\n")
    with pytest.raises(InputError) as e:
        read_tum_rgbd(tmp_path, intrinsics=(500, 500, 320, 240))
    assert e.value.line == 4
    assert "1305031102.211214 is not after 1305031102.211214 of line 3" in str(e.value)
    assert "np." not in str(e.value)


def test_euroc_folder_truth_in_seconds_is_refused(tmp_path):
    folder = _fake_euroc(tmp_path)
    gt = folder / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    rows = gt.read_text().splitlines()
    stamp, rest = rows[3].split(",", 1)
    rows[3] = f"{int(stamp) / 1e9:.6f},{rest}"
    gt.write_text("\n".join(rows) + "\n")
    with pytest.raises(InputError, match="integer nanoseconds") as e:
        read_euroc(folder)
    assert e.value.line == 4


@pytest.fixture
def dangling(tmp_path):
    """Two real images and a ``.png`` symbolic link to a file that does not exist."""
    folder = tmp_path / "imgs"
    for k in (1, 2):
        _png(folder / f"{k:02d}.png", 50 * k)
    os.symlink(tmp_path / "gone.png", folder / "03.png")
    (folder / "notes.txt").symlink_to(tmp_path / "gone.txt")  # not an image's name: ignored
    return folder


def test_dangling_image_link_is_refused_naming_it(dangling):
    for read in (list_images, folder_images):
        with pytest.raises(InputError) as e:
            read(dangling)
        assert str(e.value.path).endswith("03.png") and "image file not found" in str(e.value)
    with pytest.raises(InputError, match="03.png: image file not found"):
        read_image_folder(dangling, intrinsics=(500, 500, 4, 3))
    (dangling / "03.png").unlink()
    assert [os.path.basename(p) for p in list_images(dangling)] == ["01.png", "02.png"]
    assert cv2.imread(list_images(dangling)[0]) is not None
