"""ROS bag input that was read wrongly or crashed (a hostile pass on bags): each case a
tiny bag written with ``rosbags`` in tmp_path, said in one line or read right."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from graphslam.cli.main import main
from tests.bags import BagWriter
from tests.graphslam.sources.test_rosbag import one_error_line

pytest.importorskip("rosbags")

RUN = ["run", "--rerun", "off", "--quiet"]
#: The tiny bags' camera: 64x48 px, 50 px focal length.
K_PX = np.array([[50.0, 0, 32], [0, 50, 24], [0, 0, 1]])
SIZE_PX = (64, 48)
FRAME_NS = 100_000_000


def tiny_bag(
    path: Path,
    kind: str = "ros1",
    *,
    image="/cam/image_raw",
    infos=("/cam/camera_info",),
    d=(),
    p=None,
    frames=3,
    stamp_ns=None,
    record_ns=None,
    extra=None,
) -> Path:
    """``frames`` textured mono8 images on ``image`` (PNG bytes when it ends in
    ``/compressed``), one CameraInfo (``K_PX``, ``d``, ``p``) on each of ``infos``;
    header stamps ``stamp_ns(k)`` (default k * 0.1 s), record times ``record_ns(k)``
    (default 1 s later); ``extra(w)`` writes more."""
    import cv2

    rng = np.random.default_rng(0)
    stamp_ns = stamp_ns or (lambda k: k * FRAME_NS)
    record_ns = record_ns or (lambda k: 10**9 + k * FRAME_NS)
    with BagWriter(path, kind) as w:
        for topic in infos:
            info = w.camera_info(0, K_PX, SIZE_PX, d)
            if p is not None:  # ROS 1 spells it P, ROS 2 p
                setattr(info, "P" if hasattr(info, "P") else "p", np.asarray(p, np.float64).reshape(12))
            w.write(topic, 0, info)
        for k in range(frames):
            img = rng.integers(0, 255, (SIZE_PX[1], SIZE_PX[0]), dtype=np.uint8)
            if image.endswith("/compressed"):
                msg = w.compressed(stamp_ns(k), cv2.imencode(".png", img)[1].tobytes())
            else:
                msg = w.image(stamp_ns(k), img)
            w.write(image, 0, msg, record_ns=record_ns(k))
        if extra is not None:
            extra(w)
    return path


# --------------------------------------------------------------------------- camera


@pytest.mark.parametrize("count", [3, 6])
def test_distortion_count_opencv_refuses_is_one_line(tmp_path, capsys, count):
    """A D of 3 or 6 coefficients was a cv2.error traceback at the first image."""
    bag = tiny_bag(tmp_path / "d.bag", d=[0.01] * count)
    line = one_error_line(capsys, [*RUN, "--dataset", bag, "--odometry", "none", "--out", tmp_path / "o"])
    assert "d.bag#/cam/camera_info: camera_info D: expected 4, 5, 8, 12 or 14" in line
    assert f"got {count}" in line


def test_distortion_count_of_an_intrinsics_file_is_one_line(tmp_path):
    from graphslam.sources.spatial.calibration import read_intrinsics_file
    from slamcore.errors import InputError

    text = tmp_path / "cam.txt"
    text.write_text("50 50 32 24\n0.1 0.01 0\n")
    with pytest.raises(InputError, match=r"cam.txt:2: expected 4, 5, 8, 12 or 14 .* got 3"):
        read_intrinsics_file(text)
    yaml = tmp_path / "cam.yaml"
    yaml.write_text("fx: 50\nfy: 50\ncx: 32\ncy: 24\ndistortion: [0.1, 0.01, 0, 0, 0, 0]\n")
    with pytest.raises(InputError, match=r"distortion: expected 4, 5, 8, 12 or 14 .* got 6"):
        read_intrinsics_file(yaml)


def test_compressed_images_take_their_namespaces_camera_info(tmp_path):
    """/cam0/image_raw/compressed is in /cam0: it takes /cam0/camera_info, as the raw
    topic does, not "2 camera_info topics" (image_transport's suffix was the namespace)."""
    from graphslam.sources.spatial.rosbag import read_bag

    for suffix in ("/compressed", ""):
        bag = tiny_bag(
            tmp_path / f"c{len(suffix)}.bag",
            image="/cam0/image_raw" + suffix,
            infos=("/cam0/camera_info", "/cam1/camera_info"),
        )
        assert read_bag(bag).topics["camera_info"] == "/cam0/camera_info"


def test_another_cameras_only_camera_info_is_a_warning(tmp_path):
    from graphslam.sources.spatial.rosbag import read_bag

    bag = tiny_bag(tmp_path / "b.bag", image="/cam1/image_raw", infos=("/cam0/camera_info",))
    (warning,) = read_bag(bag).warnings
    assert warning.startswith("images /cam1/image_raw take /cam0/camera_info, the bag's only camera_info")
    assert "--topics camera_info=TOPIC" in warning and "--intrinsics" in warning
    assert read_bag(bag, {"camera_info": "/cam0/camera_info"}).warnings == ()  # named: chosen
    # its own namespace, or one above it, is the convention's pairing
    for info in ("/cam1/camera_info", "/camera_info"):
        bag = tiny_bag(tmp_path / f"{len(info)}.bag", image="/cam1/image_raw", infos=(info,))
        assert read_bag(bag).warnings == ()


def test_rectified_images_take_p_and_no_distortion(tmp_path):
    """image_rect holds rectified images: undistorting them with the raw camera's K and D
    distorted them again; their camera is P's 3x3 (sensor_msgs/CameraInfo)."""
    from graphslam.sources.spatial.rosbag import read_bag

    P = np.hstack([K_PX + np.diag([5.0, 5.0, 0.0]), np.zeros((3, 1))])
    d = (-0.3, 0.1, 0.0, 0.0, 0.0)
    raw = read_bag(tiny_bag(tmp_path / "raw.bag", d=d, p=P))
    assert np.array_equal(raw.K, K_PX) and np.array_equal(raw.distortion, d)
    seq = read_bag(tiny_bag(tmp_path / "rect.bag", image="/cam/image_rect", d=d, p=P))
    assert np.array_equal(seq.K, P[:, :3]) and seq.distortion is None and seq.warnings == ()
    assert (
        "camera_info: /cam/camera_info (first message): P's 3x3, no distortion, for the "
        "rectified /cam/image_rect" in seq.notes
    )
    zero = read_bag(tiny_bag(tmp_path / "zero.bag", image="/cam/image_rect/compressed", d=d))
    assert np.array_equal(zero.K, K_PX) and zero.distortion is None
    (warning,) = zero.warnings
    assert warning.endswith(
        "zero.bag#/cam/camera_info: P is all zeros: the rectified images "
        "/cam/image_rect/compressed are taken with K and no distortion"
    )


# --------------------------------------------------------------------------- clocks


def truth_poses(w, stamp_ns, record_ns, frames=3, topic="/truth"):
    """PoseStamped k at x = k m, header ``stamp_ns(k)``, recorded at ``record_ns(k)``."""
    for k in range(frames):
        w.write(
            topic, 0, w.pose(stamp_ns(k), (float(k), 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)), record_ns=record_ns(k)
        )


def test_zero_image_stamps_put_truth_on_record_times_too(tmp_path):
    """Images of zero header stamps fall back to record times: truth matched by its
    header stamps (another clock) gave each image another frame's pose, silently.
    Image k and truth k are recorded together; their header clock is 1 frame off."""
    from graphslam.sources.spatial.rosbag import read_bag

    record = lambda k: 10**9 + k * FRAME_NS  # noqa: E731
    bag = tiny_bag(
        tmp_path / "z.bag",
        frames=4,
        stamp_ns=lambda k: 0,
        record_ns=record,
        extra=lambda w: truth_poses(w, lambda k: record(k + 1), record, frames=4),
    )
    seq = read_bag(bag)
    assert np.array_equal(seq.wTc_true[:, 0, 3], [0.0, 1.0, 2.0, 3.0])
    assert (
        "every header stamp of /cam/image_raw is 0: the bag's record times are used for "
        "/cam/image_raw, /truth" in seq.notes
    )


def test_zero_truth_stamps_fall_back_to_record_times_as_images_do(tmp_path):
    """All-zero truth stamps were "two poses have the header stamp 0.0 s"."""
    from graphslam.sources.spatial.rosbag import read_bag, read_bag_trajectory

    record = lambda k: 10**9 + k * FRAME_NS  # noqa: E731
    bag = tiny_bag(
        tmp_path / "z.bag", frames=3, record_ns=record, extra=lambda w: truth_poses(w, lambda k: 0, record)
    )
    seq = read_bag(bag)
    assert np.array_equal(seq.wTc_true[:, 0, 3], [0.0, 1.0, 2.0])
    assert np.array_equal(seq.stamps_s, [1.0, 1.1, 1.2])  # the images' record times too
    assert "every header stamp of /truth is 0" in " ".join(seq.notes)
    truth = read_bag_trajectory(bag, "/truth")
    assert np.array_equal(truth.stamps_s, [1.0, 1.1, 1.2])
    # eval says which clock it scored on (it switched unsaid, hostile pass 18)
    assert truth.notes == ("header stamps are all 0: its times are the bag's record times",)
    from graphslam.pipelines.trajectory_eval import stamp_doubts

    said = stamp_doubts(truth, truth)
    assert said[:2] == [f"the {who}'s {truth.notes[0]}" for who in ("reference", "estimate")]


# --------------------------------------------------------------------------- odometry


def odometry_messages(w, stamps_ns, cov):
    from tests.graphslam.sources.test_rosbag import write_odometry

    for k, ns in enumerate(stamps_ns):
        T = np.eye(4)
        T[0, 3] = 0.1 * k
        write_odometry(w, "/odom", ns, T, cov)


@pytest.mark.parametrize(
    "why,stamps,cov",
    [
        ("its pose covariance is not positive definite", range(0, 4 * FRAME_NS, FRAME_NS), np.zeros((6, 6))),
        ("2 of 4 images have no message within 0.02 s", range(0, 4 * FRAME_NS, 2 * FRAME_NS), np.eye(6)),
    ],
)
def test_odometry_sequence_names_the_topic_it_left_out(tmp_path, capsys, why, stamps, cov):
    """--odometry sequence said "has no odometry of its own" of a bag whose /odom was
    read and dropped (all-zero covariance, half the image rate)."""
    bag = tiny_bag(tmp_path / "o.bag", frames=4, extra=lambda w: odometry_messages(w, stamps, cov))
    for frames in ([], ["--frames", "0:3"]):
        line = one_error_line(
            capsys, [*RUN, "--dataset", bag, "--odometry", "sequence", *frames, "--out", tmp_path / "o"]
        )
        assert f"has no odometry of its own (odometry topic /odom not used: {why})" in line


def test_mono16_of_12_bit_values_is_refused_as_png_files_of_them_are(tmp_path, capsys):
    """12-bit values in mono16 read as near-black 8-bit frames ("no landmark entered the
    map"); a folder of 16-bit PNGs of them is refused by the same rule and message."""
    import cv2

    from frontend.image import load_gray
    from slamcore.errors import InputError

    twelve = np.random.default_rng(1).integers(0, 4096, (SIZE_PX[1], SIZE_PX[0]), dtype=np.uint16)
    bag = tmp_path / "m.bag"
    with BagWriter(bag, "ros1") as w:
        w.write("/cam/camera_info", 0, w.camera_info(0, K_PX, SIZE_PX))
        for k in range(3):
            w.write("/cam/image_raw", k * FRAME_NS, w.image(k * FRAME_NS, twelve, "mono16"))
    line = one_error_line(capsys, [*RUN, "--dataset", bag, "--odometry", "none", "--out", tmp_path / "o"])
    assert "m.bag#/cam/image_raw/000000: 16-bit image whose values sit in the low bits" in line
    png = tmp_path / "twelve.png"
    cv2.imwrite(str(png), twelve)
    with pytest.raises(InputError) as e:
        load_gray(png)
    assert e.value.reason == line.split(": ", 3)[-1]


# --------------------------------------------------------------------------- paths


def test_a_ros1_bag_is_known_by_its_content_not_its_name(tmp_path, capsys):
    """REC.BAG and x.bag.active were "not a text file: 'utf-8' codec can't decode"."""
    from graphslam.sources.spatial.rosbag import read_bag

    bag = tiny_bag(tmp_path / "rec.bag")
    upper = tmp_path / "REC.BAG"
    upper.write_bytes(bag.read_bytes())
    assert read_bag(upper).topics == read_bag(bag).topics
    assert main(["info", str(upper)]) == 0
    assert "read by --dataset: image /cam/image_raw" in capsys.readouterr().out
    active = tmp_path / "rec.bag.active"
    active.write_bytes(bag.read_bytes())
    line = one_error_line(capsys, [*RUN, "--dataset", active, "--out", tmp_path / "o"])
    assert "rec.bag.active: a ROS 1 bag that rosbag record did not close" in line
    assert "rosbag reindex" in line


@pytest.mark.parametrize("command", ["run", "compare"])
@pytest.mark.parametrize("flag", [["--odometry", "derived"], ["--topics", "image=/cam0/image_raw"]])
def test_a_missing_bag_is_said_before_the_flags_that_need_one(tmp_path, capsys, command, flag):
    line = one_error_line(
        capsys,
        [command, "--rerun", "off", "--dataset", tmp_path / "no_such.bag", *flag, "--out", tmp_path / "o"],
    )
    assert "no_such.bag: no such dataset or file" in line


# --------------------------------------------------------------------------- topics


def test_info_prints_the_messages_it_counted_and_warns_of_metadata_that_differ(tmp_path, capsys):
    """info printed metadata.yaml's count (and a rate from it) unchecked, though it reads
    every message."""
    import re

    bag = tiny_bag(tmp_path / "seq", "sqlite3")
    meta = bag / "metadata.yaml"
    text, n = re.subn(
        r"message_count: 3(\s+topic_metadata:\s+name: /cam/image_raw)",
        r"message_count: 99\1",
        meta.read_text(),
    )
    assert n == 1
    meta.write_text(text)
    assert main(["info", str(bag)]) == 0
    out, err = capsys.readouterr()
    (row,) = [ln.split() for ln in out.splitlines() if ln.startswith("/cam/image_raw")]
    assert row[2:] == ["3", "10.00"]
    assert err.strip() == f"graphslam: warning: {bag}: /cam/image_raw: the bag states 99 messages, it holds 3"


def test_a_topic_of_two_message_types_is_said_as_one(tmp_path, capsys):
    """It was "no image topic (...)" listing that very topic, and "None is not one of"."""

    def poses_on_the_image_topic(w):  # a second connection: BagWriter.write keeps one a topic
        msg = w.pose(0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
        conn = w.writer.add_connection("/cam/image_raw", msg.__msgtype__, typestore=w.ts)
        w.writer.write(conn, 2 * 10**9, w.ts.serialize_ros1(msg, msg.__msgtype__))

    bag = tiny_bag(tmp_path / "m.bag", extra=poses_on_the_image_topic)
    mixed = "/cam/image_raw holds mixed types (geometry_msgs/msg/PoseStamped, sensor_msgs/msg/Image)"
    line = one_error_line(capsys, [*RUN, "--dataset", bag, "--out", tmp_path / "o"])
    assert line.endswith(f"; {mixed}, not read")
    line = one_error_line(
        capsys, [*RUN, "--dataset", bag, "--topics", "image=/cam/image_raw", "--out", tmp_path / "o"]
    )
    assert "--topics image=/cam/image_raw: the topic holds mixed types (" in line and "None" not in line


def test_an_empty_topic_is_no_candidate(tmp_path, capsys):
    """A declared topic of no message made the choice "2 truth topics"."""
    from graphslam.sources.spatial.rosbag import read_bag

    def truth_and_an_empty_topic(w):
        truth_poses(w, lambda k: k * FRAME_NS, lambda k: 10**9 + k * FRAME_NS)
        w.conns["/empty/pose"] = w.writer.add_connection(
            "/empty/pose", "geometry_msgs/msg/PoseStamped", typestore=w.ts
        )

    bag = tiny_bag(tmp_path / "e.bag", extra=truth_and_an_empty_topic)
    assert read_bag(bag).topics["truth"] == "/truth"
    assert main(["info", str(bag)]) == 0
    assert "truth /truth" in capsys.readouterr().out
