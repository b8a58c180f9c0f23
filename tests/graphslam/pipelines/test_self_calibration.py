"""``run --intrinsics estimate`` on the synthetic room, whose camera is known: driven in
a plane, turning about one axis, it is a motion that does not determine the focal
length, and the estimate must say so rather than return a confident wrong one."""

from __future__ import annotations

import re

import pytest

from graphslam import registry
from graphslam.pipelines.self_calibration import MAX_SIGMA_SHARE, estimate_camera
from slamcore.errors import GraphSlamError

#: Frames of the room each round runs on: a third of a lap is enough to show it.
ROOM_FRAMES = 60


@pytest.fixture(scope="module")
def room():
    config = registry.read_config(None)
    return registry.load_image_sequence("synthetic-images", seed=0, config=config), config


@pytest.mark.slow
def test_the_room_camera_is_refused_not_guessed(room):
    sequence, config = room
    """Each start alone settles with a standard deviation under 2 %, far from the other and
    from the room's camera (500 px): the two disagree, and the run is refused in one line."""
    with pytest.raises(GraphSlamError) as info:
        estimate_camera(sequence, config, max_frames=ROOM_FRAMES)
    words = str(info.value)
    assert words.startswith("--intrinsics estimate: these images do not determine the camera: from 768.0 px")
    (f1, s1), (f2, s2) = [tuple(map(float, m)) for m in re.findall(r"at ([0-9.]+) \+- ([0-9.]+) px", words)]
    # each passes the one-start test (a standard deviation under MAX_SIGMA_SHARE)
    assert s1 < MAX_SIGMA_SHARE * f1 and s2 < MAX_SIGMA_SHARE * f2 and abs(f1 - f2) > 10 * (s1 + s2)


def test_a_round_that_fails_after_others_placed_frames_says_so(room, monkeypatch):
    """A round failing at a camera near one a round before could run on (KITTI's first 40
    frames, whose first map starts or not by chance) says what the rounds before did, not
    only that this one failed."""
    from graphslam.backends.spatial.self_calibration import CameraFit
    from graphslam.pipelines import self_calibration

    sequence, config = room
    calls = []

    def fake_round(sequence, camera, *args, **kwargs):
        calls.append(camera)
        if len(calls) == 1:
            return CameraFit(600.0, 0.0, 5.0, None, 1000, 1.0, 0.5), 40, None
        raise GraphSlamError("--intrinsics estimate: at f = 600.0 px, room: tracking never started")

    monkeypatch.setattr(self_calibration, "_round", fake_round)
    with pytest.raises(GraphSlamError) as info:
        self_calibration.settle(sequence, config, 768.0, ROOM_FRAMES)
    assert str(info.value).startswith("--intrinsics estimate: at f = 600.0 px, room: tracking never started (")
    assert "the 1 round(s) before, from 768.0 px, placed up to 40 frames" in str(info.value)

    def failing_round(*args, **kwargs):
        raise GraphSlamError("first round failed")

    monkeypatch.setattr(self_calibration, "_round", failing_round)
    with pytest.raises(GraphSlamError, match=r"^first round failed$"):  # no round before: as it was
        self_calibration.settle(sequence, config, 768.0, ROOM_FRAMES)
