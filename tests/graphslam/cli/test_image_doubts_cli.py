"""The CLI says the readers' doubts about images (the fifth hostile pass): one
``graphslam: warning:`` line each, kept in metrics.json; ``loops --intrinsics`` checks
the camera against the images."""

from __future__ import annotations

import json
import shutil

import pytest

from graphslam.cli.main import main


@pytest.fixture
def desk(desk_copy):
    return desk_copy(6)


def test_run_says_frames_stored_twice_and_keeps_it(desk, tmp_path, capsys):
    shutil.copy(desk / "03.png", desk / "03b.png")  # 03.png, 03b.png: one frame twice
    (desk / "intrinsics.txt").write_text("520 520 319.5 239.5\n")
    out = tmp_path / "out"
    assert main(["run", "--dataset", str(desk), "--backend", "ekf", "--rerun", "off", "--quiet",
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("graphslam: warning:")]
    # said once; the run's own doubts may follow (these five desk photos give the EKF few
    # landmarks: since colour turns grey by cvtColor, fewer than 4 in every frame, said)
    twice = [ln for ln in lines if "same image twice" in ln]
    assert len(twice) == 1 and "same image twice (first: 03.png, 03b.png)" in twice[0]
    assert any("same image twice" in w for w in json.loads((out / "metrics.json").read_text())["warnings"])


def test_loops_checks_intrinsics_against_the_images(desk, tmp_path, capsys):
    (tmp_path / "K.txt").write_text("1040 1040 640 480\n")  # a camera of twice the size
    argv = ["loops", str(desk), "--out", str(tmp_path / "l.csv"), "--quiet", "--intrinsics", str(tmp_path / "K.txt")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "outside the 640x480 px images" in err[0]
    (tmp_path / "K.txt").write_text("520 520 560 420\n")  # inside, at 75 % of the way to the edge
    assert main(argv) == 0
    warned = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("graphslam: warning:")]
    assert len(warned) == 1 and "principal point" in warned[0]
