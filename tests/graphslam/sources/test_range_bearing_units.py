"""Range-bearing logs in another unit (the sixth hostile pass): MRCLAM times in
milliseconds, MRCLAM bearings and Victoria Park heading changes in degrees are
refused with file (and line) and the likely unit; the real logs still read."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import pytest

from graphslam.sources.planar.mrclam import ODOMETRY_STEP_MAX_S, MrclamConfig, read_mrclam, read_robot
from graphslam.sources.planar.victoria_park import read_victoria_park, victoria_park_path
from slamcore.errors import InputError


@pytest.fixture(scope="module")
def mrclam(shared_data) -> Path:
    return shared_data / "mrclam6"


def _robot1(mrclam: Path, tmp_path: Path, edit=None, name="Robot1_Odometry.dat") -> Path:
    folder = tmp_path / "mr"
    folder.mkdir()
    for f in (
        "Barcodes.dat",
        "Landmark_Groundtruth.dat",
        "Robot1_Odometry.dat",
        "Robot1_Measurement.dat",
        "Robot1_Groundtruth.dat",
    ):
        shutil.copy(mrclam / f, folder / f)
    if edit is not None:
        lines = (folder / name).read_text().splitlines()
        rows = [edit(ln.split()) for ln in lines[4:] if ln.strip()]
        (folder / name).write_text("\n".join(lines[:4] + ["\t".join(r) for r in rows]) + "\n")
    return folder


def test_mrclam_times_in_milliseconds_are_refused(mrclam, tmp_path):
    ms = _robot1(mrclam, tmp_path, lambda t: [f"{float(t[0]) * 1000:.0f}", *t[1:]])
    with pytest.raises(
        InputError, match=r"Robot1_Odometry\.dat: odometry lines are a median 10 s apart.*milliseconds\?"
    ):
        read_mrclam(ms, MrclamConfig(robot=1))


@pytest.mark.parametrize("robot", [1, 2, 3, 4, 5])
def test_mrclam_robots_log_well_under_the_step_bound(mrclam, robot):
    import numpy as np

    odo, _, _ = read_robot(mrclam, robot)
    assert np.median(np.diff(odo[:, 0])) < ODOMETRY_STEP_MAX_S / 100


def test_mrclam_bearings_in_degrees_name_the_unit(mrclam, tmp_path):
    deg = _robot1(
        mrclam, tmp_path, lambda t: [*t[:3], f"{math.degrees(float(t[3])):.4f}"], "Robot1_Measurement.dat"
    )
    with pytest.raises(
        InputError, match=r"Robot1_Measurement\.dat:5: bearing .* rad is not within \+-2 pi \(degrees\?\)"
    ):
        read_mrclam(deg, MrclamConfig(robot=1))


def test_victoria_park_heading_changes_in_degrees_are_refused_at_the_line(tmp_path):
    lines = open(victoria_park_path()).read().splitlines()[:2000]
    out = []
    for ln in lines:
        t = ln.split()
        if t and t[0] == "ODOMETRY":
            t[5] = f"{math.degrees(float(t[5])):.6g}"
        out.append(" ".join(t))
    path = tmp_path / "vp.txt"
    path.write_text("\n".join(out) + "\n")
    with pytest.raises(
        InputError, match=r"vp\.txt:\d+: heading change .* beyond one turn \(2 pi\): degrees\?"
    ):
        read_victoria_park(path)
    path.write_text("\n".join(lines) + "\n")  # the log as published reads
    assert len(read_victoria_park(path).frames) > 100


def test_another_robots_truth_is_doubted_and_the_run_warns(mrclam, tmp_path, capsys):
    import json

    from graphslam.cli.main import main

    folder = _robot1(mrclam, tmp_path)
    shutil.copy(mrclam / "Robot2_Groundtruth.dat", folder / "Robot1_Groundtruth.dat")
    doubts = list(read_mrclam(folder, MrclamConfig(robot=1)).warnings)
    assert len(doubts) == 1 and "are not of one robot" in doubts[0]
    out = tmp_path / "out"
    argv = [
        "run",
        "--dataset",
        str(folder),
        "--rerun",
        "off",
        "--quiet",
        "--out",
        str(out),
        "--max-steps",
        "200",
    ]
    assert main(argv) == 0
    said = capsys.readouterr().err
    assert any(ln.startswith("graphslam: warning:") and "not of one robot" in ln for ln in said.splitlines())
    m = json.loads((out / "metrics.json").read_text())
    assert "not of one robot" in m["warnings"][0]
    assert not any("not of one robot" in n for n in m["dataset_notes"])


@pytest.mark.parametrize("robot", [1, 2, 3, 4, 5])
def test_each_robots_own_truth_raises_no_doubt(mrclam, robot):

    assert read_mrclam(mrclam, MrclamConfig(robot=robot)).warnings == ()


def test_all_robots_in_one_graph_doubt_the_robot_whose_files_disagree(mrclam, tmp_path):
    from graphslam.sources.planar.mrclam_joint import read_mrclam_all

    config = MrclamConfig(all_robots=True)
    assert read_mrclam_all(mrclam, config).warnings == ()
    folder = tmp_path / "mr"
    shutil.copytree(mrclam, folder)
    shutil.copy(mrclam / "Robot2_Groundtruth.dat", folder / "Robot3_Groundtruth.dat")
    doubts = read_mrclam_all(folder, config).warnings
    assert len(doubts) == 1 and "robot 3's" in doubts[0] and "Robot3_Groundtruth.dat" in doubts[0]
