"""ROS bag input that was read wrongly or crashed (a hostile pass on bags): each case a
tiny bag written with ``rosbags`` in tmp_path, said in one line or read right."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

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
