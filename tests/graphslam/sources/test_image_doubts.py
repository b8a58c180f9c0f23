"""Image inputs a user brings (the fifth hostile pass): intrinsics that cannot be the
images' camera are refused, doubtful ones said; frames stored twice are said; file
names take one place each in a time order (decimal stamps by value)."""

from __future__ import annotations

import io
import math

import cv2
import numpy as np
import pytest
from PIL import Image

from graphslam.sources.spatial.calibration import read_camera_of
from graphslam.sources.spatial.frames import select_frames
from graphslam.sources.spatial.images import read_image_folder
from graphslam.sources.spatial.sequence import (
    MAX_HALF_VIEW_DEG,
    camera_doubts,
    list_images,
    natural_key,
    repeated_frames,
)
from slamcore.errors import InputError
from slamcore.spatial.camera import intrinsics_matrix

KITTI_K = intrinsics_matrix(707.0912, 707.0912, 601.8873, 183.1104)


def _texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w)).astype(np.uint8)


def _turned_jpeg(path, gray: np.ndarray, orientation: int = 6) -> None:
    im = Image.fromarray(gray)
    exif = im.getexif()
    exif[0x0112] = orientation  # 6: shown turned 90 degrees clockwise
    buf = io.BytesIO()
    im.save(buf, "JPEG", exif=exif.tobytes())
    path.write_bytes(buf.getvalue())


def test_decimal_stamp_names_sort_by_value():
    names = ["1.5.png", "1.25.png", "2.png", "1.0.png", "10.0.png", "2.125.png"]
    assert sorted(names, key=natural_key) == ["1.0.png", "1.25.png", "1.5.png", "2.png", "2.125.png", "10.0.png"]
    # digit runs still sort as numbers, and the two kinds of name compare
    assert sorted(["img10.png", "img2.png", "3.5.png"], key=natural_key) == ["3.5.png", "img2.png", "img10.png"]


def test_stamps_after_a_prefix_sort_by_value():
    """``f"cam_{t}.png"`` names (cam_0.30000000000000004.png) were read as two digit runs:
    0.3 after 0.9, and the run went on out of time order (twentieth hostile pass)."""
    names = [f"cam_{k * 0.1}.png" for k in range(20)]
    shuffled = sorted(names, key=lambda n: n[::-1])
    assert sorted(shuffled, key=natural_key) == names
    assert sorted(["cam_1.1.png", "cam_1.05.png", "cam_1.0.png"], key=natural_key) == [
        "cam_1.0.png", "cam_1.05.png", "cam_1.1.png"]
    # one dot between two runs only: a dotted version is still read run by run
    assert sorted(["v1.2.10.png", "v1.2.9.png"], key=natural_key) == ["v1.2.9.png", "v1.2.10.png"]


def test_two_spellings_of_one_frame_are_refused(tmp_path):
    for a, b in (("frame_1.png", "frame_01.png"), ("000003.png", "000003.jpg"), ("cam_1.5.png", "cam_1.50.png")):
        folder = tmp_path / a
        folder.mkdir()
        for name in (a, b, "000009.png"):
            cv2.imwrite(str(folder / name), _texture(4, 4))
        with pytest.raises(InputError, match="name the same frame"):
            list_images(folder)


def test_hidden_files_are_no_frames(tmp_path):
    # macOS leaves ._name AppleDouble companions on a copied drive: not images
    for name in ("000000.png", "000001.png"):
        cv2.imwrite(str(tmp_path / name), _texture(4, 4))
    (tmp_path / "._000000.png").write_bytes(b"\x00\x05\x16\x07" + bytes(80))
    assert [p.rsplit("/", 1)[1] for p in list_images(tmp_path)] == ["000000.png", "000001.png"]


def test_a_selection_keeps_the_readers_notes(tmp_path):
    # a ROS bag's notes (which topics were read) survive --frames
    from dataclasses import dataclass, fields

    from graphslam.sources.spatial.sequence import ImageSequence

    @dataclass(frozen=True, eq=False, kw_only=True)
    class Noted(ImageSequence):  # the notes as BagSequence holds them
        notes: tuple[str, ...] = ()

    folder = tmp_path / "imgs"
    folder.mkdir()
    for k in range(3):
        cv2.imwrite(str(folder / f"{k:02d}.png"), _texture(48, 64, k))
    (folder / "intrinsics.txt").write_text("60 60 31.5 23.5\n")
    seq = read_image_folder(folder)
    given = {f.name: getattr(seq, f.name) for f in fields(seq) if f.init}
    noted = Noted(**given, notes=("images: /cam0/image_raw (3 messages)",))
    assert select_frames(noted, slice(0, 2)).notes == noted.notes
    assert select_frames(seq, slice(0, 2)).notes == ()


def test_honest_kitti_camera_has_no_doubt():
    assert camera_doubts(KITTI_K, (1226, 370), "calib.txt") == []


def test_principal_point_outside_the_image_is_refused():
    with pytest.raises(InputError, match=r"outside the 1226x370 px images.*another resolution"):
        camera_doubts(intrinsics_matrix(707, 707, 2000, 900), (1226, 370), "K.txt")
    with pytest.raises(InputError, match="outside"):  # 'cx cy fx fy': cy = 707 > 370
        camera_doubts(intrinsics_matrix(601.9, 183.1, 707.1, 707.1), (1226, 370), "K.txt")


def test_normalised_intrinsics_are_refused():
    with pytest.raises(InputError, match="degrees off the axis"):
        camera_doubts(intrinsics_matrix(1.15, 1.91, 0.49, 0.49), (1226, 370), "K.txt")
    # the bound: an edge just inside MAX_HALF_VIEW_DEG passes
    f = 640 / math.tan(math.radians(MAX_HALF_VIEW_DEG - 1))
    assert camera_doubts(intrinsics_matrix(f, f, 639.5, 359.5), (1280, 720), "K.txt") == []


def test_principal_point_far_from_the_centre_is_said():
    # intrinsics of twice the resolution: (cx, cy) near the far corner
    (line,) = camera_doubts(intrinsics_matrix(1414, 1414, 1203.8, 366.2), (1226, 370), "K.txt")
    assert "principal point" in line and "another resolution" in line and line.startswith("K.txt")


def test_exif_turned_photos_with_the_stored_pixels_camera(tmp_path):
    first = tmp_path / "IMG_0001.JPG"
    _turned_jpeg(first, _texture(480, 640))  # stored 640x480, read 480x640
    assert cv2.imread(str(first), cv2.IMREAD_GRAYSCALE).shape == (640, 480)
    landscape = intrinsics_matrix(520, 520, 320, 240)
    (line,) = camera_doubts(landscape, (480, 640), "K.txt", str(first))  # 42 % off: said
    assert "EXIF orientation" in line
    assert camera_doubts(intrinsics_matrix(520, 520, 240, 320), (480, 640), "K.txt", str(first)) == []
    # a wide photo whose landscape K falls outside the portrait image: refused, said why
    wide = tmp_path / "wide.jpg"
    _turned_jpeg(wide, _texture(370, 1226))
    with pytest.raises(InputError, match="EXIF orientation"):
        camera_doubts(KITTI_K, (370, 1226), "K.txt", str(wide))
    (tmp_path / "K.txt").write_text("520 520 320 240\n")  # graphslam loops --intrinsics
    K, dist, doubts = read_camera_of(tmp_path / "K.txt", first)
    assert dist is None and len(doubts) == 1 and "EXIF" in doubts[0]


def test_a_photo_turned_unlike_the_first_says_so(tmp_path):
    folder = tmp_path / "imgs"
    folder.mkdir()
    cv2.imwrite(str(folder / "01.jpg"), _texture(48, 64))
    _turned_jpeg(folder / "02.jpg", _texture(48, 64, 1))
    (folder / "intrinsics.txt").write_text("60 60 31.5 23.5\n")
    seq = read_image_folder(folder)
    with pytest.raises(InputError, match="EXIF orientation"):
        seq.load(1)


def test_frames_stored_twice_are_said_for_the_frames_run(tmp_path):
    folder = tmp_path / "imgs"
    folder.mkdir()
    for k, seed in enumerate([0, 0, 1, 2, 2, 3]):
        cv2.imwrite(str(folder / f"{k:02d}.png"), _texture(48, 64, seed))
    (folder / "intrinsics.txt").write_text("60 60 31.5 23.5\n")
    seq = read_image_folder(folder)
    assert len(seq.warnings) == 1 and seq.warnings[0].startswith("2 of 5 consecutive frames")
    # a selection is judged on its own frames: one pair left, or none
    assert select_frames(seq, slice(0, 4)).warnings[0].startswith("1 of 3 consecutive frames")
    assert select_frames(seq, slice(1, 4)).warnings == ()
    paths = seq.image_paths
    assert repeated_frames([paths[2], paths[3]]) == []
    assert repeated_frames([paths[2], paths[2]]) != []  # one file listed twice (a TUM rgb.txt)


def test_a_folder_with_a_camera_of_another_size_is_refused(tmp_path):
    folder = tmp_path / "imgs"
    folder.mkdir()
    cv2.imwrite(str(folder / "01.png"), _texture(48, 64))
    (folder / "intrinsics.txt").write_text("500 500 320 240\n")  # a VGA camera's
    with pytest.raises(InputError, match=r"intrinsics.txt: principal point .* outside the 64x48"):
        read_image_folder(folder)


def test_a_camera_file_stating_another_image_size_is_refused(tmp_path):
    folder = tmp_path / "imgs"
    folder.mkdir()
    for k in range(2):
        cv2.imwrite(str(folder / f"{k:02d}.png"), _texture(720, 1280, k))
    # a 1280x720 camera's file on 1920x1080 images would pass the principal-point check
    (folder / "camera.yaml").write_text(
        "image_width: 1920\nimage_height: 1080\n"
        "camera_matrix: {rows: 3, cols: 3, data: [1300, 0, 960, 0, 1300, 540, 0, 0, 1]}\n"
    )
    with pytest.raises(InputError, match=r"camera.yaml: the camera is calibrated for 1920x1080 px images"):
        read_image_folder(folder)
    with pytest.raises(InputError, match="calibrated for 1920x1080"):  # graphslam loops --intrinsics
        read_camera_of(folder / "camera.yaml", folder / "00.png")
    (folder / "camera.yaml").write_text("resolution: [1280, 720]\nintrinsics: [900, 900, 639.5, 359.5]\n")
    assert read_image_folder(folder).warnings == ()


def test_a_file_name_that_is_not_utf8_is_named(tmp_path):
    import os

    from graphslam.sources.spatial.sequence import check_utf8_names

    folder = tmp_path / "imgs"
    folder.mkdir()
    cv2.imwrite(str(folder / "01.png"), _texture(4, 4))
    latin1 = os.fsdecode(bytes(folder) + b"/caf\xe9.png")  # a Latin-1 name, not UTF-8
    cv2.imwrite(str(folder / "01.png"), _texture(4, 4))
    os.rename(folder / "01.png", latin1)
    paths = list_images(folder)
    with pytest.raises(InputError, match=r"b'caf\\xe9.png' is not UTF-8: the CSV"):
        check_utf8_names(paths, "the CSV")
    check_utf8_names([folder / "caf\u00e9.png"], "the CSV")  # the same name in UTF-8 passes
