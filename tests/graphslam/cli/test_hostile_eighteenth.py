"""The eighteenth hostile pass (2026-12-05): findings of the seventeenth left open.
Each test reproduces a finding, then checks what the code does now."""

from __future__ import annotations

import numpy as np
import pytest

from graphslam.sources.spatial.frames import parse_frames, select_frames
from graphslam.sources.spatial.sequence import ImageSequence


def _sequence(n: int) -> ImageSequence:
    K = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])
    truth = np.tile(np.eye(4), (n, 1, 1))
    return ImageSequence("fake", [f"/nowhere/{k:06d}.png" for k in range(n)], None, K, None, truth, (64, 48))


@pytest.mark.parametrize("frames", ["0:15", "5:11", "12::-1", "::"])
def test_frames_past_the_end_are_said(frames):
    """--frames 0:15 on a 10-frame folder ran 10 frames unsaid (a slice clips)."""
    picked = select_frames(_sequence(10), parse_frames(frames))
    said = [w for w in picked.warnings if "reaches past the sequence's 10 frames" in w]
    assert len(said) == (frames != "::")


@pytest.mark.parametrize("frames", ["0:10", "3:7", "9::-1", "-3:"])
def test_frames_inside_the_sequence_say_nothing(frames):
    assert not select_frames(_sequence(10), parse_frames(frames)).warnings


def test_a_principal_point_no_camera_has_names_its_yaml_line(tmp_path):
    """A calibration YAML whose principal point is 1e7 px was refused without a line
    number: the mapping parsed has none, so the line is found in the text."""
    from graphslam.sources.spatial.calibration import read_intrinsics_file
    from slamcore.errors import InputError

    path = tmp_path / "camera.yaml"
    path.write_text(
        "%YAML:1.0\nimage_width: 64\n\ncamera_matrix: !!opencv-matrix\n  rows: 3\n  cols: 3\n"
        "  dt: d\n  data: [100, 0, 1.0e7, 0, 100, 24, 0, 0, 1]\n"
    )
    with pytest.raises(InputError, match=r"camera\.yaml:4: principal point"):
        read_intrinsics_file(path)
    path.write_text("fx: 100\nfy: 100\ncx: 32\ncy: 24\nintrinsics: [1, 2, 3]\n")
    np.testing.assert_allclose(read_intrinsics_file(path)[0][0, 0], 100)
