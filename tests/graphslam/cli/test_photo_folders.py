"""A folder of photos, as a user brings one: its camera from ``--intrinsics``, the
camera alone by default (no odometry, no truth to derive one from), and the Lund
door set from the camera alone against its COLMAP reconstruction."""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphslam.cli.main import main
from graphslam.sources.spatial.calibration import INTRINSICS_FILE_NAMES
from slamcore.spatial.geometry import invert_pose, rotation_to_quaternion

#: Lund door from the camera alone against COLMAP, Sim(3)-aligned ATE as a share of the
#: path: 0.04 % measured (0.0053 units over 13.7; 0.08 % before stop 71); 1 % is a loose bound that still fails
#: a map that lost its scale or a frame (one frame misplaced by a step alone is ~3 %).
LUND_ATE_SHARE_OF_PATH = 0.01
#: Two conversions of one COLMAP pose agree to this (its units; the path is 13.7 of them).
SAME_POSE_UNITS = 1e-5


def _one_error_line(capsys, argv) -> str:
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("graphslam: error: "), err
    return err[0]


@pytest.fixture
def desk_photos(desk_copy):
    return desk_copy(3)


def test_a_folder_without_a_camera_names_the_option_and_the_files(capsys, desk_photos, tmp_path):
    line = _one_error_line(capsys, ["run", "--dataset", desk_photos, "--rerun", "off", "--out", tmp_path / "o"])
    assert "no intrinsics: pass --intrinsics FILE" in line and INTRINSICS_FILE_NAMES[0] in line
    assert line.endswith("or let graphslam run estimate them from the photos (--intrinsics estimate)")


@pytest.mark.parametrize("command", [
    ["run", "--rerun", "off", "--dataset", "{desk}"],
    # loops and vocab train said "no images in folder" alone (a pass after the eighteenth)
    ["loops", "{desk}", "--quiet", "--out", "{tmp}/l.csv"],
    ["vocab", "train", "{desk}", "--out", "{tmp}/v.npz"],
])
def test_a_data_set_whose_images_sit_one_level_down_is_pointed_there(capsys, shared_data, tmp_path, command):
    if not (shared_data / "slambook2_desk" / "images").is_dir():
        pytest.skip("desk photos missing")
    argv = [a.format(tmp=tmp_path, desk=shared_data / "slambook2_desk") for a in command]
    line = _one_error_line(capsys, argv)
    assert line.endswith("its folder images/ holds 10: pass that folder")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("dataset, words", [
    ("kitti07", "a KITTI sequence carries its own camera (calib.txt)"),
    ("synthetic-images", "the synthetic sequence has its own camera"),
    ("synthetic", "--intrinsics applies to image sequences only"),
])
def test_intrinsics_where_the_data_has_its_own_camera_is_refused(capsys, shared_data, tmp_path, dataset, words):
    spec = shared_data / dataset if dataset == "kitti07" else dataset
    if dataset == "kitti07" and not spec.is_dir():
        pytest.skip("KITTI 07 missing")
    (tmp_path / "K.txt").write_text("500 500 320 240\n")
    for command in (["run"], ["compare"]):
        line = _one_error_line(capsys, [*command, "--dataset", spec, "--intrinsics", tmp_path / "K.txt",
                                        "--rerun", "off", "--out", tmp_path / "o"])
        assert words in line
    assert not (tmp_path / "o").exists()


@pytest.fixture
def lund_colmap(shared_data, tmp_path):
    """(images folder, intrinsics file, truth TUM file) from the Lund door's COLMAP model."""
    root = shared_data / "lund_door"
    if not (root / "colmap_ground_truth" / "images.txt").is_file():
        pytest.skip("Lund door data missing")
    cam = [ln.split() for ln in (root / "colmap_ground_truth" / "cameras.txt").read_text().splitlines()
           if ln.strip() and not ln.startswith("#")][0]
    assert cam[1] == "SIMPLE_RADIAL"  # f cx cy k: OpenCV's k1 = k
    f, cx, cy, k = map(float, cam[4:8])
    (tmp_path / "K.txt").write_text(f"{f} {f} {cx} {cy}\n{k} 0 0 0\n")
    rows = []
    lines = [ln for ln in (root / "colmap_ground_truth" / "images.txt").read_text().splitlines()
             if not ln.startswith("#")]
    for ln in lines[0::2]:  # image lines alternate with their 2-D point lines
        p = ln.split()
        qw, qx, qy, qz, tx, ty, tz = map(float, p[1:8])
        cTw = np.eye(4)
        cTw[:3, :3] = _rotation(qw, qx, qy, qz)
        cTw[:3, 3] = tx, ty, tz
        wTc = invert_pose(cTw)
        q = rotation_to_quaternion(wTc[None, :3, :3])[0]  # (qx, qy, qz, qw), TUM's order
        frame = int(p[9][4:8]) - 1  # DSC_0001.JPG is the folder's frame 0
        rows.append((frame, *wTc[:3, 3], *q))
    truth = tmp_path / "colmap.tum"
    truth.write_text("".join(" ".join(f"{v:.12g}" for v in r) + "\n" for r in sorted(rows)))
    return root / "images", tmp_path / "K.txt", truth


def _rotation(qw, qx, qy, qz) -> np.ndarray:
    return np.array([
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]])


def _check_lund_ate(truth, trajectory, eval_out) -> None:
    """All 12 photos placed, within :data:`LUND_ATE_SHARE_OF_PATH` of COLMAP's path after a Sim(3) fit."""
    assert main(["eval", str(truth), str(trajectory), "--align", "sim3", "--no-plot", "--out", str(eval_out)]) == 0
    (row,) = json.loads((eval_out / "eval.json").read_text())["estimates"]
    xyz = np.loadtxt(truth)[:, 1:4]
    path = np.linalg.norm(np.diff(xyz, axis=0), axis=1).sum()
    assert row["matched_poses"] == 12 and row["ate_rmse_m"] <= LUND_ATE_SHARE_OF_PATH * path


def test_lund_door_from_the_camera_alone_matches_colmap(lund_colmap, tmp_path, capsys):
    """No odometry and no truth to derive one: the default run is the camera alone, every
    frame placed, within 1 % of the path of COLMAP's cameras after a Sim(3) fit."""
    images, intrinsics, truth = lund_colmap
    out = tmp_path / "run"
    assert main(["run", "--dataset", str(images), "--intrinsics", str(intrinsics), "--rerun", "off",
                 "--quiet", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["odometry"] == "none" and metrics["frames"] == 12
    assert not metrics.get("warnings")
    assert "graphslam: warning" not in capsys.readouterr().err  # the estimate's doubts go there
    _check_lund_ate(truth, out / "trajectory.tum", tmp_path / "eval")


def test_intrinsics_give_a_tum_folder_and_a_plain_folder_their_camera(tmp_path):
    import cv2

    from graphslam.sources.spatial.images import read_image_sequence

    (tmp_path / "K.txt").write_text("400 410 4 3\n")
    tum, plain = tmp_path / "tum", tmp_path / "plain"
    (tum / "rgb").mkdir(parents=True)
    plain.mkdir()
    for k in range(3):
        cv2.imwrite(str(tum / "rgb" / f"{k}.png"), np.full((6, 8), 10 * k, np.uint8))
        cv2.imwrite(str(plain / f"{k}.png"), np.full((6, 8), 10 * k, np.uint8))
    (tum / "rgb.txt").write_text("".join(f"{100 + 0.1 * k:.1f} rgb/{k}.png\n" for k in range(3)))
    for folder in (tum, plain):
        seq = read_image_sequence(folder, intrinsics_file=tmp_path / "K.txt")
        np.testing.assert_array_equal(seq.K, [[400, 0, 4], [0, 410, 3], [0, 0, 1]])


@pytest.mark.parametrize("frames, first", [("6:12", 6), ("::-1", 11), ("::2", 0)])
def test_a_frame_selection_keeps_the_folders_numbering(lund_colmap, tmp_path, capsys, frames, first):
    """A folder has no times: the time column is the frame's index in the folder, also
    under --frames (as localize writes it), so the selection pairs with the whole
    folder's truth (numbered from 0, frame 6 took frame 0's truth: ATE 0.35 of 2.5 units)."""
    images, intrinsics, truth = lund_colmap
    out = tmp_path / "run"
    assert main(["run", "--dataset", str(images), "--intrinsics", str(intrinsics), f"--frames={frames}",
                 "--rerun", "off", "--quiet", "--out", str(out)]) == 0
    stamps = np.loadtxt(out / "trajectory.tum")[:, 0]
    assert stamps[0] == first and len(stamps) in (6, 12)
    assert main(["eval", str(truth), str(out / "trajectory.tum"), "--align", "sim3", "--no-plot",
                 "--out", str(tmp_path / "eval")]) == 0
    (row,) = json.loads((tmp_path / "eval" / "eval.json").read_text())["estimates"]
    xyz = np.loadtxt(truth)[np.sort(stamps).astype(int), 1:4]
    path = np.linalg.norm(np.diff(xyz, axis=0), axis=1).sum()
    assert row["matched_poses"] == len(stamps) and row["ate_rmse_m"] <= LUND_ATE_SHARE_OF_PATH * path


def test_colmap_cameras_txt_is_read_with_opencvs_pixel_centres(tmp_path):
    """COLMAP puts the top-left pixel's centre at (0.5, 0.5), OpenCV at (0, 0)."""
    from graphslam.sources.spatial.calibration import read_intrinsics_file, stated_image_size

    cams = tmp_path / "cameras.txt"
    cams.write_text("# Camera list with one line of data per camera:\n"
                    "1 SIMPLE_RADIAL 1296 1936 2435.38 648 968 -0.0123\n")
    K, dist = read_intrinsics_file(cams)
    np.testing.assert_array_equal(K, [[2435.38, 0, 647.5], [0, 2435.38, 967.5], [0, 0, 1]])
    np.testing.assert_array_equal(dist, [-0.0123, 0, 0, 0])
    assert stated_image_size(cams) == (1296, 1936)
    cams.write_text("3 OPENCV 640 480 500 510 320 240 0.1 -0.2 0.001 0.002\n")
    K, dist = read_intrinsics_file(cams)
    np.testing.assert_array_equal(K, [[500, 0, 319.5], [0, 510, 239.5], [0, 0, 1]])
    np.testing.assert_array_equal(dist, [0.1, -0.2, 0.001, 0.002])
    cams.write_text("1 PINHOLE 640 480 500 510 320 240\n1 PINHOLE 640 480 500 510 320 240\n")
    assert read_intrinsics_file(cams)[1] is None  # one camera listed twice is one camera


@pytest.mark.parametrize("text, words", [
    ("1 OPENCV_FISHEYE 640 480 500 500 320 240 0 0 0 0\n", "COLMAP camera model OPENCV_FISHEYE is not supported"),
    ("1 PINHOLE 640 480 500 500 320 240\n2 PINHOLE 640 480 600 600 320 240\n", "2 different COLMAP cameras"),
    ("1 PINHOLE 640 480 500 500 320\n", "expected 6 numbers (WIDTH HEIGHT, PINHOLE), got 5"),
])
def test_a_colmap_camera_the_run_cannot_use_is_one_line(capsys, desk_photos, tmp_path, text, words):
    (tmp_path / "cameras.txt").write_text(text)
    line = _one_error_line(capsys, ["run", "--dataset", desk_photos, "--intrinsics", tmp_path / "cameras.txt",
                                    "--rerun", "off", "--out", tmp_path / "o"])
    assert words in line and "cameras.txt" in line


def test_colmap_images_txt_is_the_truth_of_its_photo_folder(lund_colmap, shared_data, tmp_path, capsys):
    """The Lund door's COLMAP model as it is: cameras.txt the camera, images.txt the truth
    (matched by file name), equal to the fixture's own conversion of the same files."""
    from graphslam.sources.ground_truth import read_trajectory, with_ground_truth
    from graphslam.sources.spatial.images import read_image_sequence

    images, _, tum = lund_colmap
    model = shared_data / "lund_door" / "colmap_ground_truth"
    seq = with_ground_truth(read_image_sequence(images, intrinsics_file=model / "cameras.txt"),
                            read_trajectory(model / "images.txt"))
    by_hand = np.loadtxt(tum)
    assert len(seq.wTc_true) == 12 and np.array_equal(by_hand[:, 0], np.arange(12))
    # the fixture's rotation takes COLMAP's quaternion as unit, ours normalises it: written to 6
    # digits, the Lund quaternions are unit to 5e-7, which moves a centre 8 units out by 3e-6
    np.testing.assert_allclose(seq.wTc_true[:, :3, 3], by_hand[:, 1:4], atol=SAME_POSE_UNITS)
    out = tmp_path / "run"
    assert main(["run", "--dataset", str(images), "--intrinsics", str(model / "cameras.txt"),
                 "--ground-truth", str(model / "images.txt"), "--odometry", "none", "--rerun", "off",
                 "--quiet", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["ate_rmse_m"] <= LUND_ATE_SHARE_OF_PATH * metrics["path_length_m"]
    assert any("reconstruction's unit of length" in w for w in metrics["warnings"])
    capsys.readouterr()  # the run's own lines
    line = _one_error_line(capsys, ["eval", model / "images.txt", out / "trajectory.tum", "--out", tmp_path / "e"])
    assert "COLMAP's images.txt names image files" in line


#: Two runs of the same photos whose estimates differ only in the gauge (where the first
#: pose is put) agree on every pose relative to their first to this, in the map's units
#: (floating point through iSAM2 from another linearisation point; measured 5e-9).
SAME_ESTIMATE_UNITS = 1e-6


def test_truth_given_to_score_a_photo_folder_does_not_change_its_run(lund_colmap, shared_data, tmp_path):
    """--ground-truth scores the run; under the default --odometry auto a folder of photos
    stays on the camera alone with it (before: odometry derived from the truth, which
    made the ATE measure the truth's own noise), with the same estimate as without it."""
    from graphslam.sources.ground_truth import read_trajectory

    images, _, _ = lund_colmap
    model = shared_data / "lund_door" / "colmap_ground_truth"
    runs = {}
    for name, extra in (("scored", ["--ground-truth", str(model / "images.txt")]), ("plain", [])):
        out = tmp_path / name
        assert main(["run", "--dataset", str(images), "--intrinsics", str(model / "cameras.txt"), *extra,
                     "--rerun", "off", "--quiet", "--out", str(out)]) == 0
        assert json.loads((out / "metrics.json").read_text())["odometry"] == "none"
        wTc = read_trajectory(out / "trajectory.tum").wTc
        runs[name] = np.array([invert_pose(wTc[0]) @ T for T in wTc])
    assert runs["scored"].shape == runs["plain"].shape == (12, 4, 4)
    np.testing.assert_allclose(runs["scored"], runs["plain"], atol=SAME_ESTIMATE_UNITS)


def _colmap_binary_model(model_dir, out_dir) -> tuple:
    """The text model written as COLMAP's binary one (its "Output Format" page), with a
    2-D point per image to skip: ``(cameras.bin, images.bin)``."""
    import struct

    ids = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "RADIAL": 3, "OPENCV": 4}
    cams = [ln.split() for ln in (model_dir / "cameras.txt").read_text().splitlines()
            if ln.strip() and not ln.startswith("#")]
    blob = struct.pack("<Q", len(cams))
    for c in cams:
        blob += struct.pack("<iiQQ", int(c[0]), ids[c[1]], int(c[2]), int(c[3]))
        blob += struct.pack(f"<{len(c) - 4}d", *map(float, c[4:]))
    (out_dir / "cameras.bin").write_bytes(blob)
    lines = [ln for ln in (model_dir / "images.txt").read_text().splitlines() if not ln.startswith("#")]
    blob = struct.pack("<Q", len(lines[0::2]))
    for ln in lines[0::2]:
        p = ln.split()
        blob += struct.pack("<i7di", int(p[0]), *map(float, p[1:8]), int(p[8]))
        blob += p[9].encode() + b"\x00" + struct.pack("<Q", 1) + struct.pack("<ddq", 1.5, 2.5, -1)
    (out_dir / "images.bin").write_bytes(blob)
    return out_dir / "cameras.bin", out_dir / "images.bin"


def test_colmap_binary_model_reads_as_its_text_export(lund_colmap, shared_data, tmp_path, capsys):
    """cameras.bin and images.bin (COLMAP's default output) give what the .txt give; a
    cut file is one line."""
    from graphslam.sources.ground_truth import read_trajectory
    from graphslam.sources.spatial.calibration import read_intrinsics_file, stated_image_size

    model = shared_data / "lund_door" / "colmap_ground_truth"
    cams_bin, images_bin = _colmap_binary_model(model, tmp_path)
    for a, b in zip(read_intrinsics_file(cams_bin), read_intrinsics_file(model / "cameras.txt"), strict=True):
        np.testing.assert_array_equal(a, b)
    assert stated_image_size(cams_bin) == stated_image_size(model / "cameras.txt") == (1296, 1936)
    from_bin, from_txt = read_trajectory(images_bin), read_trajectory(model / "images.txt")
    assert from_bin.names == from_txt.names and len(from_bin.names) == 12
    np.testing.assert_array_equal(from_bin.wTc, from_txt.wTc)
    images_bin.write_bytes(images_bin.read_bytes()[:-30])
    line = _one_error_line(capsys, ["run", "--dataset", lund_colmap[0], "--intrinsics", cams_bin,
                                    "--ground-truth", images_bin, "--rerun", "off", "--out", tmp_path / "o"])
    assert "images.bin: COLMAP binary file ends inside" in line
    import struct  # a damaged count of 2-D points: 2**62 of them (struct's own traceback before)
    images_bin.write_bytes(struct.pack("<Q", 1) + struct.pack("<i7di", 1, 1, 0, 0, 0, 0, 0, 0, 1)
                           + b"DSC_0001.JPG\x00" + struct.pack("<Q", 2**62))
    line = _one_error_line(capsys, ["run", "--dataset", lund_colmap[0], "--intrinsics", cams_bin,
                                    "--ground-truth", images_bin, "--rerun", "off", "--out", tmp_path / "o"])
    assert "ends inside the 2-D points of image record 1" in line


def test_compare_scores_every_back_end_against_a_colmap_truth(lund_colmap, shared_data, tmp_path, capsys):
    """compare --ground-truth: iSAM2 scored as run scores it; the EKFs, whose estimates on
    these photos never move (too few landmarks found), have no Sim(3) fit and no NEES,
    which ended the whole comparison in an error."""
    model = shared_data / "lund_door" / "colmap_ground_truth"
    out = tmp_path / "cmp"
    assert main(["compare", "--dataset", str(lund_colmap[0]), "--intrinsics", str(model / "cameras.txt"),
                 "--ground-truth", str(model / "images.txt"), "--odometry", "none", "--in-process",
                 "--rerun", "off", "--out", str(out)]) == 0
    runs = {r["backend"]: r for r in json.loads((out / "compare.json").read_text())["runs"]}
    assert runs["isam2"]["ate_rmse_m"] <= LUND_ATE_SHARE_OF_PATH * runs["isam2"]["path_length_m"]
    assert runs["ekf-idp"]["ate_rmse_m"] is None and runs["ekf-idp"].get("nees_mean") is None
    assert "does not move" in runs["ekf-idp"]["ate_error"]


#: The Lund door's camera estimated from its photos against COLMAP's, in the estimate's
#: own standard deviations: both are SIMPLE_RADIAL (f, k1, the principal point at the
#: centre); measured 0.27 for f (2441.7 +- 23.2 px against 2435.4) and 0.04 for k1
#: (-0.0330 +- 0.0151 against -0.0336).
LUND_CAMERA_SIGMAS = 3.0


@pytest.mark.heavy  # 18 s of CI; bench_self_calibration.py --quick runs the same estimate in CI
def test_lund_door_camera_estimated_from_its_photos(lund_colmap, tmp_path, capsys):
    """``--intrinsics estimate``: the focal length by bundle adjustment from 1.2 times the
    longer side, near COLMAP's; the run from it within 1 % of the path, and the camera
    written where a later run (and ``compare``) can take it."""
    from graphslam.sources.spatial.calibration import read_intrinsics_file

    images, intrinsics, truth = lund_colmap
    colmap_f, colmap_k1 = (float(v) for v in intrinsics.read_text().split()[0::4][:2])
    out = tmp_path / "run"
    assert main(["run", "--dataset", str(images), "--intrinsics", "estimate", "--rerun", "off",
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "estimating the camera from 2323.2 px: round 1: f 2323.2 -> " in err
    assert "camera estimated from the images" in err
    camera = json.loads((out / "metrics.json").read_text())["camera_estimate"]
    starts = camera["starts"]  # COLMAP's start and a wide camera's, settled at one camera
    assert [s["start_f_px"] for s in starts] == pytest.approx([1.2 * 1936, 0.7 * 1936])
    assert abs(starts[1]["f_px"] - starts[0]["f_px"]) <= starts[0]["sigma_f_px"]
    assert abs(camera["fx_px"] - colmap_f) <= LUND_CAMERA_SIGMAS * camera["sigma_f_px"]
    assert abs(camera["k1"] - colmap_k1) <= LUND_CAMERA_SIGMAS * camera["sigma_k1"]
    assert (camera["cx_px"], camera["cy_px"]) == ((1296 - 1) / 2, (1936 - 1) / 2)
    K, dist = read_intrinsics_file(out / "intrinsics.txt")
    assert K[0, 0] == K[1, 1] == camera["fx_px"] and K[0, 2] == camera["cx_px"]
    assert list(dist) == [camera["k1"], 0.0, 0.0, 0.0]
    _check_lund_ate(truth, out / "trajectory.tum", tmp_path / "eval")
    # the file it wrote is a camera the next run takes, and the same bits come out
    again = tmp_path / "again"
    assert main(["run", "--dataset", str(images), "--intrinsics", str(out / "intrinsics.txt"),
                 "--rerun", "off", "--quiet", "--out", str(again)]) == 0
    assert (again / "trajectory.tum").read_bytes() == (out / "trajectory.tum").read_bytes()


@pytest.mark.parametrize("command, words", [
    (["compare", "--backends", "isam2"], "graphslam compare does not estimate a camera"),
    (["localize", "--map", "m"], "graphslam localize does not estimate a camera"),
])
def test_intrinsics_estimate_is_run_only(capsys, desk_photos, tmp_path, command, words):
    line = _one_error_line(capsys, [*command, "--dataset", desk_photos, "--intrinsics", "estimate",
                                    "--rerun", "off", "--out", tmp_path / "o"])
    assert words in line and "intrinsics.txt" in line


def test_photos_the_camera_alone_cannot_start_on_are_one_line(capsys, desk_photos, tmp_path):
    """Three desk photos far apart: no first map at the start's focal length, said once."""
    line = _one_error_line(capsys, ["run", "--dataset", desk_photos, "--intrinsics", "estimate",
                                    "--rerun", "off", "--quiet", "--out", tmp_path / "o"])
    assert line.startswith("graphslam: error: --intrinsics estimate: at f = 768.0 px")
    assert "monocular tracking never started" in line
    assert not (tmp_path / "o").exists()


def test_a_file_named_estimate_is_still_a_file(tmp_path, monkeypatch):
    from graphslam.cli.common import intrinsics_arg
    from graphslam.sources.spatial.calibration import is_estimate

    assert is_estimate(intrinsics_arg("estimate"))
    assert not is_estimate(intrinsics_arg("./estimate")) and intrinsics_arg("./estimate").name == "estimate"


def test_an_unreadable_photo_that_cuts_the_estimate_short_is_named(lund_colmap, tmp_path, capsys):
    """The rounds use the frames before an unreadable photo; three frames do not determine
    the camera, and the one line says which file cut them short."""
    import shutil

    images, _, _ = lund_colmap
    folder = tmp_path / "photos"
    folder.mkdir()
    for p in sorted(images.iterdir())[:6]:
        shutil.copy(p, folder / p.name)
    bad = sorted(folder.iterdir())[3]
    bad.write_text("not a photo\n")
    line = _one_error_line(capsys, ["run", "--dataset", folder, "--intrinsics", "estimate", "--rerun", "off",
                                    "--quiet", "--out", tmp_path / "o"])
    assert "these images do not determine the focal length" in line and "from 3 frames" in line
    assert line.endswith(f"the rounds' runs stopped early: {bad}: cannot read image "
                         "(not an image file, or an unsupported format)")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", [["run"], ["run", "--intrinsics", "estimate"], ["compare"],
                                     ["localize", "--map", "m"]])
def test_a_photo_folder_run_into_itself_keeps_its_camera_file(capsys, desk_photos, command):
    """--out the photo folder itself: every command clears the outputs it does not write
    there, intrinsics.txt among them (a run deleted the folder's calibration, a run with
    --intrinsics estimate replaced it): refused before any work, the file as it was."""
    calibration = "520.9 521.0 325.1 249.7\n"
    (desk_photos / "intrinsics.txt").write_text(calibration)
    line = _one_error_line(capsys, [*command, "--dataset", desk_photos, "--rerun", "off", "--out", desk_photos])
    assert "intrinsics.txt is the input --dataset's camera file" in line
    assert (desk_photos / "intrinsics.txt").read_text() == calibration


def test_an_estimate_is_not_written_into_its_photo_folder(capsys, desk_photos):
    """The estimate's intrinsics.txt in the photo folder would be the folder's calibration
    on the next run on it, unasked: refused, nothing written."""
    line = _one_error_line(capsys, ["run", "--dataset", desk_photos, "--intrinsics", "estimate",
                                    "--rerun", "off", "--out", desk_photos])
    assert "where the next run on the folder would read it" in line
    assert sorted(p.name for p in desk_photos.iterdir()) == ["01.png", "02.png", "03.png"]


def test_the_camera_file_a_data_set_finds_on_its_own(tmp_path):
    """registry.camera_file: a photo folder's, the one in a ROS 2 bag's folder (named by
    the folder or by its .db3), the one beside it; none for built-in data or a folder
    without one."""
    from graphslam import registry

    photos, bag, outer = tmp_path / "photos", tmp_path / "rec" / "bag", tmp_path / "rec"
    photos.mkdir()
    bag.mkdir(parents=True)
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (bag / "bag_0.db3").write_bytes(b"")
    assert registry.camera_file(str(photos)) is None
    assert registry.camera_file(str(bag)) is None
    (outer / "intrinsics.txt").write_text("500 500 320 240\n")
    for spec in (bag, bag / "bag_0.db3"):  # the reader opens the folder either way
        assert registry.camera_file(str(spec)) == outer / "intrinsics.txt"
    (bag / "intrinsics.txt").write_text("500 500 320 240\n")
    for spec in (bag, bag / "bag_0.db3"):
        assert registry.camera_file(str(spec)) == bag / "intrinsics.txt"
    (photos / "intrinsics.txt").write_text("500 500 320 240\n")
    assert registry.camera_file(str(photos)) == photos / "intrinsics.txt"
    assert registry.camera_file("synthetic-images") is None
