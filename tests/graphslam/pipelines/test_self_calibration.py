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
