"""ROS bags as ``--dataset`` (issue 35): bags written with ``rosbags`` itself from the
real KITTI 07 frames and the slambook2 desk photos, ROS 1 and ROS 2 (sqlite3 and
mcap). A run on a bag must equal the run on the same frames as a folder, bit for
bit; damaged input is one error line and exit 2; ``graphslam info`` lists topics.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from graphslam.cli.main import main
from tests.conftest import SHARED_DATA

from tests.bags import KITTI07, N, BagWriter, bag_path, kitti_frames, write_kitti_bag

pytest.importorskip("rosbags")

DESK = SHARED_DATA / "slambook2_desk" / "images"
KINDS = ("ros1", "sqlite3", "mcap")
# 20 frames of a car at its start: too little parallax for the camera alone, so the runs
# take odometry derived from the truth (the bag's truth topic, the folder's --ground-truth)
BASE = ["run", "--max-steps", str(N), "--rerun", "off", "--quiet"]
RUN = [*BASE, "--odometry", "derived"]

pytestmark = pytest.mark.skipif(not KITTI07.is_dir() or not DESK.is_dir(),
                                reason="shared data missing")


def kitti_folder(tmp: Path) -> tuple[Path, Path]:
    """The same N frames as a KITTI folder, and their truth as the TUM file of the
    bag's PoseStamped values (a KITTI 3x4 and a quaternion differ in the last bits)."""
    texts, _, images, _, poses = kitti_frames()
    folder = tmp / "kitti"
    (folder / "image_0").mkdir(parents=True)
    for img in images:
        shutil.copy(img, folder / "image_0" / img.name)
    shutil.copy(KITTI07 / "calib.txt", folder / "calib.txt")
    (folder / "times.txt").write_text("\n".join(texts) + "\n")
    truth = tmp / "truth.tum"
    truth.write_text("".join(f"{s} " + " ".join(repr(float(v)) for v in (*p, *q)) + "\n"
                             for s, (p, q) in zip(texts, poses)))
    return folder, truth


def run_files(argv, out: Path) -> dict[str, bytes]:
    assert main([str(a) for a in argv] + ["--out", str(out)]) == 0
    return {p.name: p.read_bytes() for p in out.iterdir() if p.suffix == ".tum"}


@pytest.fixture(scope="module")
def kitti_folder_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("kitti_folder")
    folder, truth = kitti_folder(tmp)
    return run_files([*RUN, "--dataset", folder, "--ground-truth", truth], tmp / "out")


@pytest.mark.parametrize("kind,compressed", [("ros1", False), ("sqlite3", True),
                                             ("mcap", False), ("ros1", True)])
def test_kitti_bag_run_equals_folder_run(tmp_path, kitti_folder_run, capsys, kind, compressed):
    bag = write_kitti_bag(bag_path(tmp_path, kind), kind, compressed)
    got = run_files([*RUN, "--dataset", bag], tmp_path / "out")
    assert set(got) == {"trajectory.tum", "ground_truth.tum"}
    assert got == kitti_folder_run
    out = capsys.readouterr().out
    topic = "/cam0/image_raw/compressed" if compressed else "/cam0/image_raw"
    assert f"image: {topic}" in out and "camera_info: /cam0/camera_info" in out
    assert "truth: /ground_truth/pose (geometry_msgs/msg/PoseStamped, 20 poses)" in out


def test_frames_and_topics_flags_on_a_bag(tmp_path, capsys):
    bag = write_kitti_bag(bag_path(tmp_path, "mcap"), "mcap")
    a = run_files([*RUN, "--dataset", bag, "--frames", "0:10", "--topics",
                   "image=/cam0/image_raw,truth=/ground_truth/pose"], tmp_path / "a")
    b = run_files([*RUN, "--dataset", bag, "--max-steps", "10"], tmp_path / "b")
    assert a == b


# --------------------------------------------------------------------------- the desk photos

DESK_INTRINSICS = "520.9 521.0 325.1 249.7\n"


@pytest.mark.parametrize("kind", KINDS)
def test_desk_bag_run_equals_folder_run(tmp_path, capsys, kind):
    folder = tmp_path / "desk"
    folder.mkdir()
    photos = sorted(DESK.glob("*.png"))
    for p in photos:
        shutil.copy(p, folder / p.name)
    (folder / "intrinsics.txt").write_text(DESK_INTRINSICS)
    bags = tmp_path / "bags"
    bags.mkdir()
    bag = bag_path(bags, kind)
    with BagWriter(bag, kind) as w:  # 1 s apart: the folder's frame numbers as times
        for k, p in enumerate(photos):
            w.write("/camera/image/compressed", k * 10**9, w.compressed(k * 10**9, p.read_bytes()))
    (bags / "intrinsics.txt").write_text(DESK_INTRINSICS)  # no CameraInfo: the file beside
    flags = ["run", "--rerun", "off", "--quiet", "--backend", "ekf", "--odometry", "none"]
    want = run_files([*flags, "--dataset", folder], tmp_path / "a")
    assert run_files([*flags, "--dataset", bag], tmp_path / "b") == want
    assert "intrinsics: " in capsys.readouterr().out


def test_intrinsics_give_a_bag_without_camera_info_its_camera(tmp_path, capsys):
    """--intrinsics FILE from anywhere equals the file beside the bag; beside a
    camera_info topic (the images' own camera) it is refused in one line."""
    bags = tmp_path / "bags"
    bags.mkdir()
    bag = bag_path(bags, "ros1")
    photos = sorted(DESK.glob("*.png"))[:4]
    with BagWriter(bag, "ros1") as w:
        for k, p in enumerate(photos):
            w.write("/camera/image/compressed", k * 10**9, w.compressed(k * 10**9, p.read_bytes()))
    elsewhere = tmp_path / "cam.txt"
    elsewhere.write_text(DESK_INTRINSICS)
    flags = ["run", "--rerun", "off", "--quiet", "--backend", "ekf", "--odometry", "none", "--dataset", bag]
    given = run_files([*flags, "--intrinsics", elsewhere], tmp_path / "a")
    assert "(--intrinsics)" in capsys.readouterr().out
    (bags / "intrinsics.txt").write_text(DESK_INTRINSICS)
    assert run_files(flags, tmp_path / "b") == given
    with_info = small_bag(bag_path(tmp_path, "ros1"), "ros1")
    line = one_error_line(capsys, ["run", "--dataset", with_info, "--intrinsics", elsewhere, "--rerun", "off",
                                   "--out", tmp_path / "c"])
    assert "the bag has a camera_info topic (/cam/camera_info)" in line


# --------------------------------------------------------------------------- bad input

def one_error_line(capsys, argv) -> str:
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("graphslam: error:")]
    assert len(lines) == 1 and "Traceback" not in err, err[:2000]
    return lines[0]


def small_bag(path: Path, kind: str, frames: int = 3, size=(64, 48), encoding="mono8",
              stamps=None, extra=None) -> Path:
    """A tiny bag of textured frames with CameraInfo; ``extra(w)`` adds messages."""
    rng = np.random.default_rng(0)
    with BagWriter(path, kind) as w:
        w.write("/cam/camera_info", 0, w.camera_info(0, np.array(
            [[50.0, 0, 32], [0, 50, 24], [0, 0, 1]]), (64, 48)))
        for k in range(frames):
            ns = (stamps[k] if stamps else k) * 100_000_000
            wh = size[k] if isinstance(size, list) else size
            channels = 3 if encoding in ("bgr8", "rgb8") else 1
            img = rng.integers(0, 255, (wh[1], wh[0], channels)[:3 if channels > 1 else 2],
                               dtype=np.uint8)
            w.write("/cam/image_raw", ns, w.image(ns, img, encoding), record_ns=10**9 + k)
        if extra is not None:
            extra(w)
    return path


def test_damaged_bag(tmp_path, capsys):
    bag = small_bag(bag_path(tmp_path, "ros1"), "ros1", frames=20)
    data = bag.read_bytes()
    bag.write_bytes(data[:len(data) // 2])
    line = one_error_line(capsys, [*RUN, "--dataset", bag, "--out", tmp_path / "o"])
    assert "seq.bag: cannot read the bag" in line


def test_damaged_ros2_bag(tmp_path, capsys):
    bag = small_bag(bag_path(tmp_path, "sqlite3"), "sqlite3")
    next(bag.glob("*.db3")).write_bytes(b"not a database" * 100)
    line = one_error_line(capsys, [*RUN, "--dataset", bag, "--out", tmp_path / "o"])
    assert "cannot read the bag" in line


def test_ambiguous_and_missing_topics(tmp_path, capsys):
    def second_camera(w):
        w.write("/cam1/image_raw", 0, w.image(0, np.zeros((48, 64), np.uint8)))

    bag = small_bag(bag_path(tmp_path, "mcap"), "mcap", extra=second_camera)
    line = one_error_line(capsys, [*RUN, "--dataset", bag, "--out", tmp_path / "o"])
    assert "2 image topics (/cam/image_raw, /cam1/image_raw)" in line and "--topics image=" in line
    line = one_error_line(capsys, [*RUN, "--dataset", bag, "--topics", "image=/nope",
                                   "--out", tmp_path / "o"])
    assert "--topics image=/nope: no such topic" in line
    line = one_error_line(capsys, [*RUN, "--dataset", bag, "--topics", "camera=/cam/image_raw",
                                   "--out", tmp_path / "o"])
    assert "unknown role 'camera'" in line
    empty = tmp_path / "empty.bag"
    with BagWriter(empty, "ros1") as w:
        w.write("/cam/camera_info", 0, w.camera_info(0, np.eye(3) * 50 + np.diag([0, 0, -49]),
                                                    (64, 48)))
    line = one_error_line(capsys, [*RUN, "--dataset", empty, "--out", tmp_path / "o"])
    assert "no image topic" in line and "/cam/camera_info" in line


def test_topics_refused_for_a_folder(tmp_path, capsys):
    line = one_error_line(capsys, [*RUN, "--dataset", KITTI07, "--topics", "image=/x",
                                   "--out", tmp_path / "o"])
    assert "--topics applies to ROS bags only" in line


def test_changing_size_and_encoding(tmp_path, capsys):
    bag = small_bag(bag_path(tmp_path, "ros1", "sizes"), "ros1",
                    size=[(64, 48), (64, 48), (32, 48)])
    line = one_error_line(capsys, [*RUN, "--dataset", bag, "--out", tmp_path / "o"])
    assert "images of changing size" in line and "32x48" in line
    bag = small_bag(bag_path(tmp_path, "ros1", "bayer"), "ros1", encoding="bayer_rggb8")
    line = one_error_line(capsys, [*RUN, "--dataset", bag, "--out", tmp_path / "o"])
    assert "image encoding 'bayer_rggb8' is not supported" in line


def test_out_of_order_sorted_and_duplicates_refused(tmp_path, capsys):
    from graphslam.sources.spatial.rosbag import read_bag

    seq = read_bag(small_bag(bag_path(tmp_path, "ros1", "order"), "ros1", stamps=[0, 2, 1]))
    assert np.allclose(seq.stamps_s, [0.0, 0.1, 0.2])
    assert any("sorted by header stamp" in n for n in seq.notes)
    raw = [seq.load(i) for i in range(3)]
    assert not np.array_equal(raw[1], raw[2])
    bag = small_bag(bag_path(tmp_path, "ros1", "dup"), "ros1", stamps=[0, 1, 1])
    line = one_error_line(capsys, [*RUN, "--dataset", bag, "--out", tmp_path / "o"])
    assert "two images on /cam/image_raw have the header stamp 0.1 s" in line


def test_encodings_read_as_grey(tmp_path):
    import cv2

    from graphslam.sources.spatial.rosbag import read_bag

    rng = np.random.default_rng(1)
    bgr = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
    mono16 = rng.integers(0, 65535, (48, 64), dtype=np.uint16)
    path = bag_path(tmp_path, "sqlite3")
    with BagWriter(path, "sqlite3") as w:
        for k, (img, enc) in enumerate([(bgr, "bgr8"), (bgr[..., ::-1], "rgb8"),
                                        (mono16, "mono16")]):
            w.write(f"/cam{k}/image_raw", 0, w.image(0, img, enc))
    (tmp_path / "intrinsics.txt").write_text("50 50 32 24\n")
    shutil.copy(tmp_path / "intrinsics.txt", path / "intrinsics.txt")
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    for k in (0, 1):
        assert np.array_equal(read_bag(path, {"image": f"/cam{k}/image_raw"}).load(0), grey)
    # the top 8 bits, as the same frame in a 16-bit PNG reads (one rule for folders and bags)
    assert np.array_equal(read_bag(path, {"image": "/cam2/image_raw"}).load(0), (mono16 >> 8).astype(np.uint8))
    png = tmp_path / "frame16.png"
    cv2.imwrite(str(png), mono16)
    from frontend.image import load_gray

    assert np.array_equal(load_gray(png), read_bag(path, {"image": "/cam2/image_raw"}).load(0))
    cv2.imwrite(str(png), bgr)  # a colour PNG reads as the bgr8 message does (hostile pass 21)
    assert np.array_equal(load_gray(png), grey)


def test_missing_rosbags_is_one_line(tmp_path, capsys, monkeypatch):
    import sys

    bag = small_bag(bag_path(tmp_path, "ros1"), "ros1")
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)  # import fails
    line = one_error_line(capsys, [*RUN, "--dataset", bag, "--out", tmp_path / "o"])
    assert line.endswith('reading ROS bags needs the rosbags package: pip install ".[bags]"')


# --------------------------------------------------------------------------- graphslam info

@pytest.mark.parametrize("kind", KINDS)
def test_info_lists_topics(tmp_path, capsys, kind):
    bag = write_kitti_bag(bag_path(tmp_path, kind), kind)
    assert main(["info", str(bag)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split() == ["topic", "type", "messages", "rate", "[Hz]"]
    rows = {ln.split()[0]: ln.split()[1:] for ln in out[1:4]}
    assert rows["/cam0/image_raw"][:2] == ["sensor_msgs/msg/Image", "20"]
    assert abs(float(rows["/cam0/image_raw"][2]) - 9.6) < 0.1  # KITTI's ~10.4 fps... per record
    assert rows["/cam0/camera_info"] == ["sensor_msgs/msg/CameraInfo", "1", "n/a"]
    assert rows["/ground_truth/pose"][:2] == ["geometry_msgs/msg/PoseStamped", "20"]
    assert out[4] == ("read by --dataset: image /cam0/image_raw, camera_info /cam0/camera_info, "
                      "truth /ground_truth/pose")


def test_info_with_topics_that_pick_nothing_lists_then_fails(tmp_path, capsys):
    """Without --topics a listing is never refused; with it, the check it asks for fails
    with exit 2 and one error line after the table (a script checking a bag sees it)."""
    bag = write_kitti_bag(bag_path(tmp_path, "ros1"), "ros1")
    assert main(["info", str(bag), "--topics", "image=/nosuch"]) == 2
    out, err = capsys.readouterr()
    assert out.splitlines()[0].split()[0] == "topic"
    assert "no such topic" not in out  # the reason once, in the error line (hostile pass 21)
    (line,) = err.strip().splitlines()
    assert line.startswith("graphslam: error: --topics image=/nosuch: ") and "no such topic" in line
    assert line.count("--topics image=/nosuch") == 1  # said twice before (twentieth hostile pass)


def test_info_refuses_an_unknown_role_before_reading_the_bag(tmp_path, capsys, monkeypatch):
    """Hostile pass 21: --topics banana=/x read every message of the bag first."""
    from graphslam.sources.spatial import rosbag

    bag = write_kitti_bag(bag_path(tmp_path, "ros1"), "ros1")
    monkeypatch.setattr(rosbag, "bag_topics", lambda *a: pytest.fail("the bag was read"))
    line = one_error_line(capsys, ["info", bag, "--topics", "banana=/x"])
    assert "unknown role 'banana'" in line


def test_a_fifo_among_a_ros2_bags_files_is_refused(tmp_path, capsys):
    # SQLite's open of a FIFO waits for a writer for good, retrying through every
    # signal: the command hung and SIGTERM could not end it
    bag = small_bag(bag_path(tmp_path, "sqlite3"), "sqlite3")
    db = next(bag.glob("*.db3"))
    db.unlink()
    os.mkfifo(db)
    line = one_error_line(capsys, ["info", bag])
    assert f"{db.name}: file of the bag is a FIFO" in line


def test_info_refuses_what_is_not_a_bag(tmp_path, capsys):
    line = one_error_line(capsys, ["info", KITTI07])
    assert "not a ROS bag" in line


# --------------------------------------------------------------------------- odometry

def write_odometry(w, topic: str, ns: int, T: np.ndarray, cov: np.ndarray) -> None:
    from slamcore.spatial.geometry import rotation_to_quaternion

    q = rotation_to_quaternion(T[None, :3, :3])[0]
    pose = w.pose(ns, T[:3, 3], q).pose
    twist = w.make("geometry_msgs/msg/TwistWithCovariance", twist=w.make(
        "geometry_msgs/msg/Twist", linear=w.make("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0),
        angular=w.make("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0)), covariance=np.zeros(36))
    w.write(topic, ns, w.make("nav_msgs/msg/Odometry", header=w.header(ns), child_frame_id="cam0",
                              pose=w.make("geometry_msgs/msg/PoseWithCovariance", pose=pose,
                                          covariance=cov.reshape(36)),
                              twist=twist))


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_odometry_topic_is_the_sequence_odometry(tmp_path, capsys, kind):
    from graphslam.sources.spatial.kitti import read_kitti_poses
    from graphslam.sources.spatial.rosbag import read_bag

    wTc = read_kitti_poses(KITTI07 / "poses.txt")[:N]
    _, ns, _, _, _ = kitti_frames()
    sigmas = np.array([0.01, 0.01, 0.01, 0.002, 0.002, 0.002]) ** 2
    bag = bag_path(tmp_path, kind)
    path = write_kitti_bag(bag, kind, extra=lambda w: [
        write_odometry(w, "/odom", t, T, np.diag(sigmas)) for t, T in zip(ns, wTc)])
    seq = read_bag(path)
    assert seq.odometry.shape == (N - 1, 4, 4) and seq.odometry_covariance.shape == (N - 1, 6, 6)
    steps = np.linalg.inv(wTc[:-1]) @ wTc[1:]
    assert np.allclose(seq.odometry, steps, atol=1e-6)
    assert np.allclose(np.diagonal(seq.odometry_covariance, axis1=1, axis2=2), sigmas)
    assert main([*BASE, "--dataset", str(path), "--out", str(tmp_path / "o")]) == 0  # auto: the topic's
    out = capsys.readouterr().out
    assert re.search(r"^\s*odometry\s+sequence$", out, re.M), out
    assert "odometry: /odom (20 poses, taken as the camera's)" in out
    # without a usable covariance the odometry is left out, and the notes say so
    bag2 = bag_path(tmp_path, kind, "nocov")
    seq = read_bag(write_kitti_bag(bag2, kind, extra=lambda w: [
        write_odometry(w, "/odom", t, T, np.zeros((6, 6))) for t, T in zip(ns, wTc)]))
    assert seq.odometry is None
    assert "odometry: /odom not used: its pose covariance is not positive definite" in seq.notes
    assert read_bag(path, {"odometry": "none"}).odometry is None


# --------------------------------------------------------------------------- graphslam eval

def test_eval_reads_a_bag_topic_on_either_side(tmp_path, capsys):
    import json

    bag = write_kitti_bag(bag_path(tmp_path, "ros1"), "ros1")
    _, truth = kitti_folder(tmp_path)
    assert main(["eval", f"{bag}:/ground_truth/pose", str(truth), "--out", str(tmp_path / "e1"),
                 "--no-plot"]) == 0
    got = json.loads((tmp_path / "e1" / "eval.json").read_text())["estimates"][0]
    assert got["matched_poses"] == N and got["ate_rmse_m"] < 1e-9
    # the bag alone: its one pose topic; as the estimate
    assert main(["eval", str(truth), str(bag), "--out", str(tmp_path / "e2"), "--no-plot"]) == 0
    got = json.loads((tmp_path / "e2" / "eval.json").read_text())["estimates"][0]
    assert got["matched_poses"] == N and got["ate_rmse_m"] < 1e-9
    capsys.readouterr()
    line = one_error_line(capsys, ["eval", f"{bag}:/cam0/image_raw", str(truth),
                                   "--out", tmp_path / "e3"])
    assert "topic /cam0/image_raw is sensor_msgs/msg/Image, not one of" in line


# --------------------------------------------------------------------------- graphslam loops

def test_loops_on_a_bag_equals_loops_on_the_folder(tmp_path, capsys):
    import json

    folder = tmp_path / "desk"
    folder.mkdir()
    photos = sorted(DESK.glob("*.png"))
    for p in photos:
        shutil.copy(p, folder / p.name)
    intrinsics = tmp_path / "intrinsics.txt"  # beside the bag: its camera, as --intrinsics
    intrinsics.write_text(DESK_INTRINSICS)
    bag = bag_path(tmp_path, "ros1")
    with BagWriter(bag, "ros1") as w:
        for k, p in enumerate(photos):
            w.write("/camera/image/compressed", k * 10**9, w.compressed(k * 10**9, p.read_bytes()))
    logs = []
    for name, argv in (("folder", [folder, "--intrinsics", intrinsics]), ("bag", [bag])):
        assert main(["loops", *map(str, argv), "--words", "100", "--quiet", "--out",
                     str(tmp_path / f"{name}.csv"), "--log", str(tmp_path / f"{name}.jsonl")]) == 0
        rows = [json.loads(ln) for ln in (tmp_path / f"{name}.jsonl").read_text().splitlines()]
        logs.append([{k: v for k, v in r.items() if not k.endswith("_name")} for r in rows])
    assert logs[0] == logs[1] and len(logs[0]) > 0  # the same candidates, scores, verdicts
    # the same rows, the folder's file names being the bag's message numbers
    number = {p.name: f"{k:06d}" for k, p in enumerate(photos)}
    folder_rows = (tmp_path / "folder.csv").read_text().splitlines()
    renamed = [folder_rows[0]] + [",".join([number[a], number[b], *rest]) for a, b, *rest in
                                  (row.split(",") for row in folder_rows[1:])]
    assert renamed == (tmp_path / "bag.csv").read_text().splitlines()


def test_transform_and_odometry_messages_as_poses(tmp_path):
    from graphslam.sources.spatial.rosbag import read_bag, read_bag_trajectory

    _, ns, _, _, poses = kitti_frames()

    def transforms(w):
        for t, (p, q) in zip(ns, poses):
            tf = w.make("geometry_msgs/msg/Transform",
                        translation=w.make("geometry_msgs/msg/Vector3", x=p[0], y=p[1], z=p[2]),
                        rotation=w.pose(t, p, q).pose.orientation)
            w.write("/vicon", t, w.make("geometry_msgs/msg/TransformStamped", header=w.header(t),
                                        child_frame_id="cam0", transform=tf))

    bag = write_kitti_bag(bag_path(tmp_path, "sqlite3"), "sqlite3", extra=transforms)
    vicon = read_bag_trajectory(bag, "/vicon")
    pose = read_bag_trajectory(bag, "/ground_truth/pose")
    assert np.array_equal(vicon.wTc, pose.wTc) and np.array_equal(vicon.stamps_s, pose.stamps_s)
    assert len(vicon.wTc) == N
    # two truth topics: named, or refused with both listed
    with pytest.raises(Exception, match=r"2 truth topics \(/ground_truth/pose, /vicon\)"):
        read_bag(bag)
    assert np.array_equal(read_bag(bag, {"truth": "/vicon"}).wTc_true, pose.wTc)


def test_compressed_images_of_changing_size(tmp_path, capsys):
    import cv2

    bag = bag_path(tmp_path, "mcap")
    rng = np.random.default_rng(2)
    with BagWriter(bag, "mcap") as w:
        for k, wh in enumerate([(64, 48), (64, 48), (48, 64)]):
            img = rng.integers(0, 255, (wh[1], wh[0]), dtype=np.uint8)
            data = cv2.imencode(".png", img)[1].tobytes()
            w.write("/cam/image/compressed", k * 10**8, w.compressed(k * 10**8, data))
    (bag / "intrinsics.txt").write_text("50 50 32 24\n")
    line = one_error_line(capsys, [*RUN, "--dataset", bag, "--odometry", "none", "--backend",
                                   "ekf", "--out", tmp_path / "o"])
    assert "/cam/image/compressed/000002: image is 48x64 px, the sequence's are 64x48" in line


def test_vocab_train_names_a_bag_as_a_bag(tmp_path, capsys):
    """Hostile pass 21: a bag given to vocab train was 'cannot read image (not an image
    file...)', where loops takes the same bag."""
    bag = small_bag(bag_path(tmp_path, "ros1"), "ros1")
    line = one_error_line(capsys, ["vocab", "train", bag, "--out", tmp_path / "v.npz"])
    assert "is a ROS bag: vocab train reads image files and folders" in line
