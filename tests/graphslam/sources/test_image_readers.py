"""Image-sequence readers: real KITTI 07 and small fake TUM / EuRoC / folder layouts."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from slamcore.errors import InputError
from graphslam.sources.spatial.sequence import ImageSequence
from graphslam.sources.spatial.images import (
    read_euroc, read_image_folder, read_image_sequence, read_tum_rgbd,
)
from graphslam.sources.spatial.calibration import read_intrinsics_file
from graphslam.sources.spatial.kitti import read_kitti

KITTI_K = np.array([[707.0912, 0, 601.8873], [0, 707.0912, 183.1104], [0, 0, 1]])
#: KITTI poses are printed with 7 significant digits.
POSE_TOL = 1e-6


def _png(path: Path, value: int = 100, size=(8, 6)) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    img = np.full((size[1], size[0]), value, np.uint8)
    img[0, 0] = 255 - value
    assert cv2.imwrite(str(path), img)


# ----------------------------------------------------------------------------- KITTI

@pytest.fixture(scope="module")
def kitti(shared_data):
    folder = shared_data / "kitti07"
    if not folder.is_dir():
        pytest.skip("kitti07 not present")
    return read_kitti(folder)


def test_kitti07_real(kitti):
    assert isinstance(kitti, ImageSequence)
    assert len(kitti) == 160 and len(kitti.image_paths) == 160
    assert Path(kitti.image_paths[0]).name == "000000.png"
    assert Path(kitti.image_paths[-1]).name == "000159.png"
    np.testing.assert_allclose(kitti.K, KITTI_K, atol=1e-9)
    assert kitti.stamps_s.shape == (160,) and kitti.stamps_s[0] == 0.0
    assert np.all(np.diff(kitti.stamps_s) > 0)
    assert kitti.wTc_true.shape == (160, 4, 4)
    np.testing.assert_allclose(kitti.wTc_true[0], np.eye(4), atol=POSE_TOL)
    R = kitti.wTc_true[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-5)
    assert kitti.image_size == (1226, 370)
    img = kitti.load(5)
    assert img.dtype == np.uint8 and img.shape == (370, 1226)
    assert read_image_sequence(kitti.source_path).name == kitti.name


def _fake_kitti(tmp_path: Path, n_img=3, n_pose=3) -> Path:
    for k in range(n_img):
        _png(tmp_path / "image_0" / f"{k:06d}.png", 10 * k)
    P = "7 0 3 0 0 7 2 0 0 0 1 0"
    (tmp_path / "calib.txt").write_text(f"P0: {P}\nP1: 7 0 3 -3.5 0 7 2 0 0 0 1 0\n")
    (tmp_path / "times.txt").write_text("".join(f"{0.1 * k}\n" for k in range(n_img)))
    pose = "1 0 0 {x} 0 1 0 0 0 0 1 0\n"
    (tmp_path / "poses.txt").write_text("".join(pose.format(x=k) for k in range(n_pose)))
    return tmp_path


def test_kitti_fake_camera1_and_mismatch(tmp_path):
    folder = _fake_kitti(tmp_path)
    for k in range(3):
        _png(folder / "image_1" / f"{k:06d}.png")
    seq = read_kitti(folder, camera=1)
    # P1 = K [I | (-0.5, 0, 0)]: camera 1 sits 0.5 m to the right of camera 0.
    np.testing.assert_allclose(seq.wTc_true[2, :3, 3], [2.5, 0, 0])
    # a truth that ends before the images: the frames after it are left out and said
    # (it refused the folder, even under a --frames range inside the truth)
    (folder / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    short = read_kitti(folder)
    assert len(short) == 1 and short.wTc_true.shape == (1, 4, 4) and len(short.stamps_s) == 1
    assert any("2 of 3 images come after the last of the 1 poses" in w for w in short.warnings)
    # more poses than images whose names are not frame numbers cannot be matched: refused
    for k in range(3):
        (folder / "image_0" / f"{k:06d}.png").rename(folder / "image_0" / f"f{k}.png")
    (folder / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 5)
    with pytest.raises(InputError, match=r"5 poses but 3 images"):
        read_kitti(folder)


def test_kitti_without_calib_is_refused_as_kitti(tmp_path):
    """Third hostile pass: a KITTI folder without calib.txt was read as a plain folder
    and refused as one "without images"; the line names the missing calib.txt."""
    folder = _fake_kitti(tmp_path)
    (folder / "calib.txt").unlink()
    with pytest.raises(InputError, match=r"calib.txt: a KITTI sequence \(image_0/\) without calib.txt"):
        read_image_sequence(folder)


def test_kitti_malformed_line(tmp_path):
    folder = _fake_kitti(tmp_path)
    (folder / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 x 0 0 0 1 0\n")
    with pytest.raises(InputError) as e:
        read_kitti(folder)
    assert e.value.line == 2 and "poses.txt:2" in str(e.value)
    (folder / "calib.txt").write_text("P0: 1 2 3\n")
    with pytest.raises(InputError, match=r"calib.txt:1: P0: expected 12 numbers"):
        read_kitti(folder)


# ----------------------------------------------------------------------------- TUM

def _fake_tum(tmp_path: Path) -> Path:
    folder = tmp_path / "rgbd_dataset_freiburg1_fake"
    lines = ["# color images", "# timestamp filename"]
    for k in range(4):
        t = 100.0 + 0.1 * k
        _png(folder / "rgb" / f"{t:.6f}.png", 20 * k, size=(640, 480))  # the fr1 camera's
        lines.append(f"{t:.6f} rgb/{t:.6f}.png")
    (folder / "rgb.txt").write_text("\n".join(lines) + "\n")
    # Ground truth starts after the first image (as in TUM), every 0.01 s.
    gt = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
    for k in range(5, 40):
        t = 100.0 + 0.01 * k + 0.003
        gt.append(f"{t:.4f} {t - 100:.4f} 0 0 0 0 0 1")
    (folder / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    return folder


def test_tum_good(tmp_path):
    folder = _fake_tum(tmp_path)
    seq = read_tum_rgbd(folder, intrinsics=(500, 501, 320, 240))
    # image at t=100.0 has no ground truth within 0.02 s -> dropped.
    assert len(seq) == 3
    np.testing.assert_allclose(seq.stamps_s, [100.1, 100.2, 100.3])
    np.testing.assert_allclose(seq.wTc_true[:, 0, 3], [0.103, 0.203, 0.303], atol=1e-9)
    np.testing.assert_allclose(seq.K[0], [500, 0, 320])
    assert seq.image_size == (640, 480)
    assert seq.load(0).shape == (480, 640)
    # freiburg1 in the folder name selects the fr1 preset (with distortion).
    auto = read_image_sequence(folder)
    assert auto.name.startswith("tum") and auto.K[0, 0] == pytest.approx(517.3)
    assert auto.distortion is not None and auto.distortion.size == 5


def test_tum_bad(tmp_path):
    folder = _fake_tum(tmp_path)
    gt = folder / "groundtruth.txt"
    text = gt.read_text().splitlines()
    text[4] = "100.0700 0.07 0 0 0 0 1"  # 7 numbers instead of 8
    gt.write_text("\n".join(text) + "\n")
    with pytest.raises(InputError) as e:
        read_tum_rgbd(folder, intrinsics="fr3")
    assert e.value.line == 5 and "groundtruth.txt:5" in str(e.value)
    (folder / "rgb" / "100.200000.png").unlink()
    with pytest.raises(InputError, match=r"1 of 4 listed images are missing"):
        read_tum_rgbd(folder, intrinsics="fr3")
    (folder / "rgb.txt").write_text("100.0\n")
    with pytest.raises(InputError, match=r"rgb.txt:1: expected 'timestamp filename'"):
        read_tum_rgbd(folder, intrinsics="fr3")
    plain = tmp_path / "plain"
    _png(plain / "rgb" / "1.png")
    (plain / "rgb.txt").write_text("1.0 rgb/1.png\n")
    with pytest.raises(InputError, match="no intrinsics"):
        read_tum_rgbd(plain)


@pytest.mark.parametrize("where, line, text, message", [
    ("groundtruth.txt", 6, "100.0530 9 9 9 0 0 0 1", "groundtruth timestamps must increase"),
    ("rgb.txt", 3, "nan rgb/100.000000.png", "non-finite value"),
    ("rgb.txt", 3, "1_00.0 rgb/100.000000.png", "expected timestamp"),
])
def test_tum_repeated_truth_stamps_and_odd_image_stamps_are_refused(tmp_path, where, line,
                                                                      text, message):
    """Issue 34: a repeated groundtruth.txt stamp gave an image one of two truths without
    a word; rgb.txt took "nan" and "1_00.0" as times."""
    folder = _fake_tum(tmp_path)
    path = folder / where
    rows = path.read_text().splitlines()
    rows[line - 1] = text
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(InputError, match=message) as e:
        read_tum_rgbd(folder, intrinsics="fr3")
    assert f"{where}:{line}" in str(e.value)


# ----------------------------------------------------------------------------- EuRoC

SENSOR_YAML = """%YAML:1.0
sensor_type: camera
T_BS:
  cols: 4
  rows: 4
  data: [1.0, 0.0, 0.0, 0.1,
         0.0, 1.0, 0.0, 0.0,
         0.0, 0.0, 1.0, 0.0,
         0.0, 0.0, 0.0, 1.0]
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
"""


def _fake_euroc(tmp_path: Path) -> Path:
    cam = tmp_path / "MH_fake" / "mav0" / "cam0"
    lines = ["#timestamp [ns],filename"]
    for k in range(3):
        ns = 1_000_000_000 + 50_000_000 * k
        _png(cam / "data" / f"{ns}.png", 30 * k, size=(752, 480))  # the intrinsics' camera
        lines.append(f"{ns},{ns}.png")
    (cam / "data.csv").write_text("\n".join(lines) + "\n")
    (cam / "sensor.yaml").write_text(SENSOR_YAML)
    gt_dir = cam.parent / "state_groundtruth_estimate0"
    gt_dir.mkdir()
    gt = ["#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
          "q_RS_z [], v_x, v_y, v_z, bwx, bwy, bwz, bax, bay, baz"]
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)  # body yawed 90 deg
    for k in range(0, 30):
        ns = 1_000_000_000 + 5_000_000 * k + 1_000_000
        gt.append(f"{ns},{k},0,1,{c},0,0,{s}" + ",0" * 9)
    (gt_dir / "data.csv").write_text("\n".join(gt) + "\n")
    return tmp_path / "MH_fake"


def test_euroc_good(tmp_path):
    folder = _fake_euroc(tmp_path)
    seq = read_image_sequence(folder)
    assert seq.name.startswith("euroc") and len(seq) == 3
    np.testing.assert_allclose(seq.stamps_s, [1.0, 1.05, 1.1])
    np.testing.assert_allclose(np.diag(seq.K), [458.654, 457.296, 1.0])
    assert seq.distortion.shape == (4,)
    # wTc = wTb @ T_BS: body at (10k, 0, 1) for image k (nearest gt is 1 ms after),
    # yawed 90 deg, so the camera's +0.1 m x offset points along world +y.
    np.testing.assert_allclose(seq.wTc_true[1, :3, 3], [10, 0.1, 1], atol=1e-9)
    np.testing.assert_allclose(seq.wTc_true[1, :3, 0], [0, 1, 0], atol=1e-9)


def test_euroc_bad(tmp_path):
    folder = _fake_euroc(tmp_path)
    csv = folder / "mav0" / "cam0" / "data.csv"
    lines = csv.read_text().splitlines()
    lines[2] = "1050000000;1050000000.png"
    csv.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as e:
        read_euroc(folder)
    assert e.value.line == 3 and "data.csv:3" in str(e.value)
    (folder / "mav0" / "cam0" / "sensor.yaml").unlink()
    csv.write_text("#timestamp [ns],filename\n1000000000,1000000000.png\n")
    with pytest.raises(InputError, match="sensor.yaml not found"):
        read_euroc(folder)


# ----------------------------------------------------------------------------- folder

def test_image_folder_formats(tmp_path):
    for name in ("img10.png", "img2.jpg", "img1.PNG", "notes.txt"):
        if name.endswith("txt"):
            (tmp_path / name).write_text("hello")
        else:
            _png(tmp_path / name)
    (tmp_path / "intrinsics.txt").write_text("# fx fy cx cy\n500 500 3.5 2.5\n0.1 -0.01 0 0\n")
    seq = read_image_sequence(tmp_path)
    assert [Path(p).name for p in seq.image_paths] == ["img1.PNG", "img2.jpg", "img10.png"]
    assert seq.wTc_true is None and seq.stamps_s is None
    np.testing.assert_allclose(seq.K, [[500, 0, 3.5], [0, 500, 2.5], [0, 0, 1]])
    np.testing.assert_allclose(seq.distortion, [0.1, -0.01, 0, 0])

    kfile = tmp_path / "k3.txt"
    kfile.write_text("400 0 3\n0 410 2\n0 0 1\n")
    K, d = read_intrinsics_file(kfile)
    assert K[1, 1] == 410 and d is None
    yfile = tmp_path / "cam.yaml"
    yfile.write_text("%YAML:1.0\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
                     "  data: [300, 0, 4, 0, 301, 3, 0, 0, 1]\ndist_coeffs: [0.1, 0, 0, 0, 0]\n")
    seq = read_image_folder(tmp_path, intrinsics_file=yfile)
    assert seq.K[1, 1] == 301 and seq.distortion.size == 5
    (tmp_path / "f.yml").write_text("fx: 1\nfy: 2\ncx: 3\ncy: 4\n")
    assert read_intrinsics_file(tmp_path / "f.yml")[0][1, 2] == 4


def test_image_folder_bad(tmp_path):
    _png(tmp_path / "a.png")
    with pytest.raises(InputError, match="no intrinsics"):
        read_image_folder(tmp_path)
    bad = tmp_path / "intrinsics.txt"
    bad.write_text("# comment\n500 500 cx 2\n")
    with pytest.raises(InputError) as e:
        read_image_folder(tmp_path)
    assert e.value.line == 2 and "intrinsics.txt:2" in str(e.value)
    bad.write_text("500 500 3\n")
    with pytest.raises(InputError, match="three lines"):
        read_image_folder(tmp_path)
    bad.write_text("1 2 3 4\n")
    (tmp_path / "b.png").write_bytes(b"not a png")
    seq = read_image_folder(tmp_path)
    with pytest.raises(InputError, match=r"b.png: cannot read image"):
        seq.load(1)
    with pytest.raises(InputError, match="not found"):
        read_image_sequence(tmp_path / "nope")


def test_malformed_yaml_names_file(tmp_path):
    bad = tmp_path / "camera.yaml"
    bad.write_text("fx: 1\nK: [1, 2\nfy: 3\n")
    with pytest.raises(InputError, match=r"camera.yaml.*malformed YAML"):
        read_intrinsics_file(bad)


# ------------------------------------------------------------- files outside the folder

@pytest.mark.parametrize("name", ["../../outside.png", "ABSOLUTE"])
def test_tum_list_naming_a_file_outside_the_folder_is_refused(tmp_path, name):
    """Issue 34: ``rgb.txt`` naming ``../../x.png`` or an absolute path made the run
    read a file outside the sequence folder."""
    folder = _fake_tum(tmp_path / "a" / "b")
    outside = tmp_path / "outside.png"
    _png(outside, 99)
    name = str(outside) if name == "ABSOLUTE" else name
    rgb = folder / "rgb.txt"
    rgb.write_text(rgb.read_text() + f"100.4 {name}\n")
    with pytest.raises(InputError, match="outside the sequence folder") as err:
        read_tum_rgbd(folder, intrinsics=(500, 501, 320, 240))
    assert "rgb.txt" in str(err.value)


def test_euroc_list_naming_a_file_outside_the_folder_is_refused(tmp_path):
    folder = _fake_euroc(tmp_path)
    _png(tmp_path / "outside.png", 99)
    csv = folder / "mav0" / "cam0" / "data.csv"
    csv.write_text(csv.read_text() + "1150000000,../../../../outside.png\n")
    with pytest.raises(InputError, match="outside the sequence folder"):
        read_image_sequence(folder)


def test_a_frame_range_of_huge_numbers_is_a_short_error():
    # the bound was quoted whole: a 5000-character error line
    from graphslam.sources.spatial.frames import frame_indices, parse_frames
    from slamcore.errors import ConfigError

    with pytest.raises(ConfigError) as e:
        parse_frames("0:1" + "0" * 5000)
    assert len(str(e.value)) < 200 and "5003 characters" in str(e.value)
    with pytest.raises(ConfigError) as e:
        frame_indices(parse_frames("1" + "0" * 4000 + ":"), 10)
    assert len(str(e.value)) < 200 and "selects no frame" in str(e.value)


def test_intrinsics_with_a_byte_order_mark(tmp_path):
    (tmp_path / "K.txt").write_text("\ufeff520 520 320 240\n", encoding="utf-8")
    K = read_intrinsics_file(tmp_path / "K.txt")[0]
    assert K[0, 0] == 520 and K[1, 2] == 240
