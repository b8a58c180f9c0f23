"""The fifteenth hostile pass on the MRCLAM reader: genuine data cut in time, labels
or ranges of another data set, gaps in the logs, and what the notes count. Each folder
is a cut of Dataset 6 built here (the first 150 s unless said)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from graphslam.sources.planar.mrclam import MrclamConfig, read_mrclam

#: Dataset 6's first odometry time, s (Robot*_Odometry.dat).
T0 = 1248444187.0

Edit = Callable[[list[list[str]]], list[list[str]]]


@pytest.fixture(scope="module")
def mrclam(shared_data) -> Path:
    return shared_data / "mrclam6"


def _rows(path: Path) -> tuple[list[str], list[list[str]]]:
    header, rows = [], []
    for line in path.read_text().splitlines():
        (header.append(line) if line.startswith("#") or not line.strip() else rows.append(line.split()))
    return header, rows


def cut(mrclam: Path, folder: Path, robots=(1,), end_s: float = 150.0, edits: dict[str, Edit] | None = None) -> Path:
    """``folder`` holding ``robots``' logs up to ``T0 + end_s``, each file through its
    edit (rows of tokens -> rows) from ``edits``; an edit returning None drops the file."""
    folder.mkdir(parents=True)
    names = ["Barcodes.dat", "Landmark_Groundtruth.dat"] + [
        f"Robot{n}_{kind}.dat" for n in robots for kind in ("Odometry", "Measurement", "Groundtruth")
    ]
    for name in names:
        header, rows = _rows(mrclam / name)
        if name.startswith("Robot"):
            rows = [r for r in rows if float(r[0]) < T0 + end_s]
        edit = (edits or {}).get(name)
        if edit is not None:
            rows = edit(rows)
            if rows is None:
                continue
        (folder / name).write_text("\n".join(header + ["\t".join(r) for r in rows]) + "\n")
    return folder


def after(t_s: float) -> Edit:
    return lambda rows: [r for r in rows if float(r[0]) > T0 + t_s]


# -- 1. the truth-sightings doubt ------------------------------------------------------


def test_genuine_data_cut_in_time_is_not_doubted(mrclam, tmp_path):
    """Robot 1's log from 30 s on: its bearings sit 2-4 deg off the truth's for tens of
    seconds (a heading offset between Vicon and camera), 93 % beyond 3 sigma; the doubt
    said its files were "not of one robot" and the ATE (0.048 m) meaningless."""
    for name, edits in [
        ("odolate", {"Robot1_Odometry.dat": after(30)}),
        ("truthlate", {"Robot1_Groundtruth.dat": after(30)}),
    ]:
        folder = cut(mrclam, tmp_path / name, edits=edits)
        assert read_mrclam(folder, MrclamConfig(robot=1)).warnings == ()


def test_another_data_sets_barcodes_name_the_labels_and_keep_the_ate(mrclam, tmp_path):
    """Barcodes rotated by 3 among the landmarks: the trajectory is as right as with the
    true file; only the map's labels are wrong, and the doubt says so (it called the ATE
    meaningless)."""

    def rotate(rows):
        landmarks = [r for r in rows if int(r[0]) >= 6]
        codes = {r[0]: s[1] for r, s in zip(landmarks, landmarks[3:] + landmarks[:3])}
        return [[r[0], codes.get(r[0], r[1])] for r in rows]

    folder = cut(mrclam, tmp_path / "bc", edits={"Barcodes.dat": rotate})
    (doubt,) = read_mrclam(folder, MrclamConfig(robot=1)).warnings
    assert "labels are exchanged" in doubt and "11 at 14's" in doubt
    assert "ATE stand" in doubt and "meaningless" not in doubt


def test_ranges_in_centimetres_are_named(mrclam, tmp_path):
    def cm(rows):
        return [[t, code, f"{float(r) * 100:.3f}", b] for t, code, r, b in rows]

    folder = cut(mrclam, tmp_path / "cm", edits={"Robot1_Measurement.dat": cm})
    (doubt,) = read_mrclam(folder, MrclamConfig(robot=1)).warnings
    assert "divided by 10" in doubt and "(centimetres?)" in doubt and "not of one robot" not in doubt


def test_another_robots_truth_on_a_cut_is_still_doubted(mrclam, tmp_path):
    folder = cut(mrclam, tmp_path / "r2", robots=(1, 2))
    (folder / "Robot2_Groundtruth.dat").replace(folder / "Robot1_Groundtruth.dat")
    # the odometry does not follow that truth either: one line blames the truth file
    (doubt,) = read_mrclam(folder, MrclamConfig(robot=1)).warnings
    assert "Robot1_Odometry.dat's turns" in doubt and "do not follow it either" in doubt
    assert "not of one robot" in doubt and "no range unit and no exchange of landmark labels" in doubt
    assert "the truth is another robot's" in doubt


# -- 2. NEES and the unaligned final error need the run in the truth's frame -----------


def test_truth_starting_after_the_log_leaves_nees_out_and_says_why(mrclam, tmp_path, capsys):
    """Robot 3's Vicon cut to start 10 s in: the run starts at the origin, and its NEES
    (6746 against 1.61 on the whole cut) and unaligned final error (2.3 m) compared the
    origin's frame with the Vicon's."""
    import json

    from graphslam import registry
    from graphslam.cli.main import main
    from graphslam.evaluation.planar import pose_statistics
    from graphslam.pipelines import planar as pipeline

    whole = cut(mrclam, tmp_path / "whole", robots=(3,), end_s=60)
    late = cut(mrclam, tmp_path / "late", robots=(3,), end_s=60, edits={"Robot3_Groundtruth.dat": after(10)})
    for folder, frames_match in ((whole, True), (late, False)):
        ds = read_mrclam(folder, MrclamConfig(robot=3))
        stats = pose_statistics(ds, pipeline.run(ds, registry.make_backend("ekf"), with_covariances=True).estimate)
        assert (stats["nees_mean"] is not None) is frames_match
        assert (stats["final_pose_error_m"] is not None) is frames_match
        assert (stats["frame_doubt"] is None) is frames_match
    out = tmp_path / "out"
    argv = ["run", "--dataset", str(late), "--robot", "3", "--backend", "ekf", "--nees", "--rerun", "off"]
    assert main([*argv, "--quiet", "--out", str(out)]) == 0
    said = capsys.readouterr()
    assert "the run's first pose has no truth" in said.out + said.err
    m = json.loads((out / "metrics.json").read_text())
    assert m.get("nees_mean") is None and not (out / "nees.csv").exists()
    assert any("not in the truth's frame" in w for w in m["warnings"])


# -- 3. gaps in the odometry, and odometry that ends before the sightings --------------


def test_a_gap_in_the_odometry_is_warned_and_sightings_past_its_end_dropped(mrclam, tmp_path):
    """A 60-s hole in robot 1's odometry held the command before it across the hole, and
    robot 3's odometry ending at 100 s with sightings to 150 s held its last command for
    50 s (map RMSE 3.97 m), both without a word."""
    gap = cut(mrclam, tmp_path / "gap", edits={
        "Robot1_Odometry.dat": lambda rows: [r for r in rows if not T0 + 53.5 < float(r[0]) < T0 + 113.5]})
    (warning,) = read_mrclam(gap, MrclamConfig(robot=1)).warnings
    assert "Robot1_Odometry.dat has no line for 60.0 s from 53." in warning and "held" in warning
    short = cut(mrclam, tmp_path / "short", robots=(3,), edits={
        "Robot3_Odometry.dat": lambda rows: [r for r in rows if float(r[0]) < T0 + 100]})
    ds = read_mrclam(short, MrclamConfig(robot=3))
    # log seconds, not wall time: the frames end where the odometry does, plus the
    # longest interval its lines leave in the normal course (the reader's own rule)
    from graphslam.sources.planar.mrclam import odometry_gaps, read_table

    odometry_s = read_table(short / "Robot3_Odometry.dat", 3, "time, v, w")[0][:, 0]
    normal_gap_s, _ = odometry_gaps(3, odometry_s)
    assert odometry_s[-1] <= ds.frames[-1].stamp_s <= odometry_s[-1] + normal_gap_s
    assert any("sightings after its odometry ends dropped (odometry to 99." in n for n in ds.notes)
    assert read_mrclam(cut(mrclam, tmp_path / "whole", robots=(3,)), MrclamConfig(robot=3)).warnings == ()


# -- 5. what the notes count ------------------------------------------------------------


def test_notes_say_they_count_the_whole_log(mrclam, tmp_path, capsys):
    """``--max-steps 300`` printed the whole log's counts as if of the steps that ran."""
    from graphslam.cli.main import main

    folder = cut(mrclam, tmp_path / "r3", robots=(3,))
    assert main(["run", "--dataset", str(folder), "--robot", "3", "--max-steps", "30", "--rerun", "off",
                 "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "sightings of other robots in the whole log left out" in out


def test_all_robots_count_the_sightings_of_a_robot_without_a_log(mrclam, tmp_path):
    """Robot 4's files removed: the others' sightings of it went without a word."""
    from graphslam.sources.planar.mrclam_joint import read_mrclam_all

    folder = cut(mrclam, tmp_path / "no4", robots=(1, 2, 3, 5))
    notes = read_mrclam_all(folder, MrclamConfig(all_robots=True)).notes
    assert any(n.endswith("sightings of robot 4 left out: no Robot4_Odometry.dat here") for n in notes), notes


# -- 4. a repeated Vicon line ------------------------------------------------------------


def test_a_repeated_truth_line_is_dropped_and_a_contradicting_one_refused(mrclam, tmp_path):
    """One Vicon line written twice refused the data set: "time 1248444195.954 s comes
    after 1248444195.954 s: the log must be in time order"."""
    from slamcore.errors import InputError

    def twice(rows):
        return rows[:1000] + [rows[999]] + rows[1000:]

    def other_pose(rows):
        return rows[:1000] + [[rows[999][0], "0.5", *rows[999][2:]]] + rows[1000:]

    plain = read_mrclam(cut(mrclam, tmp_path / "plain"), MrclamConfig(robot=1))
    dup = read_mrclam(cut(mrclam, tmp_path / "dup", edits={"Robot1_Groundtruth.dat": twice}), MrclamConfig(robot=1))
    assert "robot 1: 1 repeated lines of Robot1_Groundtruth.dat dropped" in dup.notes
    assert [f.wTb_true is None for f in dup.frames] == [f.wTb_true is None for f in plain.frames]
    folder = cut(mrclam, tmp_path / "other", edits={"Robot1_Groundtruth.dat": other_pose})
    with pytest.raises(InputError, match=r"Robot1_Groundtruth\.dat:1005: time \d+\.\d+ s repeats line 1004's "
                                         r"with other values"):
        read_mrclam(folder, MrclamConfig(robot=1))


def test_another_data_sets_landmark_truth_is_named_when_the_robots_files_agree(mrclam, tmp_path):
    """Landmark_Groundtruth.dat with every landmark 1 m off (another data set's): the
    doubt said the robot's truth and sightings were not of one robot, and the ATE
    meaningless, though the robot's odometry follows its truth and its ATE stands."""

    def moved(rows):
        return [[r[0], f"{float(r[1]) + 1.0:.6f}", *r[2:]] for r in rows]

    folder = cut(mrclam, tmp_path / "lm", edits={"Landmark_Groundtruth.dat": moved})
    (doubt,) = read_mrclam(folder, MrclamConfig(robot=1)).warnings
    assert "while Robot1_Odometry.dat follows Robot1_Groundtruth.dat" in doubt
    assert "Landmark_Groundtruth.dat is not of this data set's landmarks" in doubt
    assert "the ATE stands" in doubt and "not of one robot" not in doubt
