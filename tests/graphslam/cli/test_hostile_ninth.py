"""Ninth hostile pass (2026-11-30): what a hostile but plausible user found, one test a fix.

Run in process through :func:`graphslam.cli.main.main`, which turns errors into one
``graphslam: error:`` line and exit status 2.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from graphslam.cli.main import main

# ---- ninth hostile pass


@pytest.fixture(scope="module")
def frames():
    from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig, make_synthetic_images

    seq = make_synthetic_images(
        SyntheticImagesConfig(width=160, height=120, fx=125, fy=125, cx=79.5, cy=59.5, n_frames=5)
    )
    return [seq.load(i) for i in range(len(seq))]


def image_folder(root: Path, frames) -> Path:
    root.mkdir()
    for i, im in enumerate(frames):
        cv2.imwrite(str(root / f"f{i}.png"), im)
    (root / "intrinsics.txt").write_text("125 125 79.5 59.5\n")
    return root


def error_lines(capsys) -> list[str]:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return [ln for ln in err.splitlines() if ln.startswith("graphslam: error:")]


def test_an_unreadable_frame_late_in_a_run_keeps_the_frames_before_it(tmp_path, capsys, frames):
    """A truncated image at frame 3 of 5 stopped the run with nothing written: every
    frame before it was lost (a long KITTI run, to one bad file near its end)."""
    folder = image_folder(tmp_path / "seq", frames)
    cut = folder / "f3.png"
    cut.write_bytes(cut.read_bytes()[: cut.stat().st_size // 2])
    out = tmp_path / "o"
    argv = ["run", "--dataset", folder, "--backend", "ekf", "--odometry", "none", "--quiet",
            "--rerun", "off", "--out", out]
    assert main([str(a) for a in argv]) == 2
    lines = error_lines(capsys)
    assert len(lines) == 1 and "f3.png: truncated PNG" in lines[0] and "stopped at this frame" in lines[0]
    poses = [ln for ln in (out / "trajectory.tum").read_text().splitlines() if not ln.startswith("#")]
    assert len(poses) == 3
    assert json.loads((out / "metrics.json").read_text())["interrupted"] is True


def test_a_map_asked_of_a_run_cut_by_an_unreadable_frame_says_why_none_is_saved(tmp_path, capsys, frames):
    # it said "run interrupted", as if a signal had stopped it
    folder = image_folder(tmp_path / "seq", frames)
    cut = folder / "f3.png"
    cut.write_bytes(cut.read_bytes()[: cut.stat().st_size // 2])
    argv = ["run", "--dataset", folder, "--backend", "isam2", "--odometry", "none", "--quiet",
            "--rerun", "off", "--out", tmp_path / "o", "--save-map", tmp_path / "m"]
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert "run stopped before its end: no map saved in" in err and "interrupted" not in err
    assert not (tmp_path / "m").exists()


def test_an_unreadable_first_frame_is_the_plain_error(tmp_path, capsys, frames):
    folder = image_folder(tmp_path / "seq", frames)
    (folder / "f0.png").write_bytes(b"not a png")
    out = tmp_path / "o"
    argv = ["run", "--dataset", folder, "--backend", "ekf", "--odometry", "none", "--quiet",
            "--rerun", "off", "--out", out]
    assert main([str(a) for a in argv]) == 2
    lines = error_lines(capsys)
    assert len(lines) == 1 and "f0.png: cannot read image" in lines[0] and "stopped" not in lines[0]
    assert not (out / "trajectory.tum").exists()


def test_localize_keeps_the_frames_placed_before_an_unreadable_one(tmp_path):
    from graphslam.pipelines import localize_run
    from graphslam.pipelines.common import FrameUnreadable
    from graphslam.pipelines.localize import Placement
    from slamcore.errors import InputError

    class Sequence:
        name = "seq"

        def __len__(self):
            return 4

        def load(self, i):
            if i == 2:
                raise InputError("truncated PNG (no IEND chunk)", "f2.png")
            return np.zeros((4, 4), np.uint8)

    class Lost:
        def locate(self, image):
            return Placement("lost", None, None)

    with pytest.raises(FrameUnreadable) as e:
        localize_run.run(Sequence(), Lost())
    assert len(e.value.result.placements) == 2 and e.value.result.interrupted
    assert str(e.value) == "f2.png: truncated PNG (no IEND chunk)"


@pytest.mark.parametrize("value, says", [
    ("5", "config must name a config file (.toml, .yaml or .yml), got 5"),  # read as a path '5'
    ('""', "config must name a config file (.toml, .yaml or .yml), got ''"),  # the sweep's folder
    ('"."', "config '.' is a folder"),
    ('"base.toml"', "config 'base.toml' does not exist; a path is read beside the sweep file"),
])
def test_sweep_config_that_names_no_file_is_refused_at_its_line(tmp_path, capsys, value, says):
    """``[sweep] config`` was taken as a path whatever it was, and a missing one was
    "sub/5: config file not found": neither the sweep file nor its line was named."""
    sweep = tmp_path / "s.toml"
    sweep.write_text(f'[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\nseed = [0]\nconfig = {value}\n')
    assert main(["sweep", str(sweep), "--out", str(tmp_path / "sw")]) == 2
    lines = error_lines(capsys)
    assert len(lines) == 1 and f"{sweep}:5: [sweep] {says}" in lines[0], lines
