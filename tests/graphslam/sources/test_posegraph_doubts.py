"""Pose-graph files whose lines all read but whose numbers are unlikely as written
(the sixth hostile pass): angles in degrees, quaternions not unit or written w first,
edges repeated to the last digit are said (``PoseGraph.warnings``, a ``graphslam:
warning:`` line of ``run`` and ``convert``, ``metrics.json`` ``warnings``); a ``BR``
bearing beyond one turn is refused at its line. Honest files say nothing."""

from __future__ import annotations

import json
import math
from pathlib import Path

import gtsam
import pytest

from graphslam.cli.main import main
from graphslam.sources.posegraph_files import read_pose_graph_file, read_pose_graph_records
from slamcore.errors import InputError

INFO2 = "100 0 0 100 0 1000"
INFO3 = " ".join("100" if r == c else "0" for r in range(6) for c in range(r, 6))


def _square(tmp_path, turn: float, extra: str = "", name: str = "g.g2o") -> Path:
    lines = [f"VERTEX_SE2 {k} 0 0 0" for k in range(4)]
    lines += [f"EDGE_SE2 {i} {(i + 1) % 4} 1 0 {turn:g} {INFO2}" for i in range(4)]
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n" + extra)
    return path


def _chain3(tmp_path, quat: str, closure_quat: str | None = None) -> Path:
    lines = [f"VERTEX_SE3:QUAT {k} {k} 0 0 0 0 0 1" for k in range(3)]
    lines += [f"EDGE_SE3:QUAT {k} {k + 1} 1 0 0 {quat} {INFO3}" for k in range(2)]
    lines.append(f"EDGE_SE3:QUAT 0 2 2 0 0 {closure_quat or quat} {INFO3}")
    path = tmp_path / "g3.g2o"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_radians_say_nothing_degrees_are_doubted(tmp_path):
    assert read_pose_graph_file(_square(tmp_path, math.pi / 2)).warnings == ()
    (doubt,) = read_pose_graph_file(_square(tmp_path, 90)).warnings
    assert "4 of 4 edges turn by more than 2 pi" in doubt and "degrees?" in doubt and "line" in doubt


def test_toro_3d_roll_pitch_yaw_in_degrees_is_doubted(tmp_path):
    info = " ".join("10" if r == c else "0" for r in range(6) for c in range(r, 6))
    text = "".join(f"VERTEX3 {k} {k} 0 0 0 0 0\n" for k in range(3))
    text += "".join(f"EDGE3 {k} {k + 1} 1 0 0 0 0 30 {info}\n" for k in range(2))
    path = tmp_path / "g.graph"
    path.write_text(text)
    assert "degrees?" in read_pose_graph_file(path).warnings[0]


def test_non_unit_and_w_first_quaternions_are_doubted(tmp_path):
    assert read_pose_graph_file(_chain3(tmp_path, "0 0 0 1")).warnings == ()
    (doubt,) = read_pose_graph_file(_chain3(tmp_path, "0 0 0 2")).warnings
    assert "3 edge quaternions are not unit" in doubt
    # identity written w x y z: every step a half turn about x
    (doubt,) = read_pose_graph_file(_chain3(tmp_path, "1 0 0 0")).warnings
    assert "w x y z?" in doubt
    # one odometry step that really turns little: not every step a half turn
    path = _chain3(tmp_path, "1 0 0 0")
    path.write_text(path.read_text().replace("EDGE_SE3:QUAT 0 1 1 0 0 1 0 0 0", "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1"))
    assert read_pose_graph_file(path).warnings == ()


def test_an_edge_repeated_to_the_last_digit_is_doubted(tmp_path):
    path = _square(tmp_path, math.pi / 2)
    last = path.read_text().splitlines()[-1]
    (doubt,) = read_pose_graph_file(_square(tmp_path, math.pi / 2, last + "\n")).warnings
    assert doubt.startswith("1 edges repeat an earlier edge") and "line 9" in doubt
    # the same pair measured twice with other numbers is two measurements: nothing said
    other = last.replace(" 1 0 ", " 1.01 0 ", 1)
    assert read_pose_graph_file(_square(tmp_path, math.pi / 2, other + "\n")).warnings == ()


def test_br_bearing_beyond_one_turn_is_refused_at_its_line(tmp_path):
    path = tmp_path / "b.graph"
    path.write_text(f"VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 {INFO2}\nBR 1 7 12.5 3 0.03 0.1\n")
    with pytest.raises(InputError, match=r"b\.graph:4: BR bearing 12\.5 rad is beyond one turn"):
        read_pose_graph_records(path, landmarks=True)


HONEST = [
    "w100.graph", "w10000.graph", "w20000.txt", "w100_30.g2o", "sphere2500.txt", "pose3example.txt",
    "pose3example-grid.txt", "pose3Localizationexample.txt", "simpleGraph10gradIter.txt",
    "toyExample.g2o", "Klaus3.g2o", "noisyToyGraph.txt", "pose2example.txt",
]


@pytest.mark.parametrize("name", HONEST)
def test_gtsam_example_graphs_raise_no_doubt(name):
    assert read_pose_graph_file(gtsam.findExampleDataFile(name)).warnings == ()


@pytest.mark.parametrize("name", ["Bovisa04_odometry_bow_tr.g2o", "NewCollege_odometry_bow_tr.g2o"])
def test_rrr_graphs_raise_no_doubt(shared_data, name):
    path = shared_data / "rrr_posegraphs" / name
    assert read_pose_graph_file(path).warnings == ()


def test_run_and_convert_say_the_doubt_and_metrics_keep_it(tmp_path, capsys):
    path = _square(tmp_path, 90)
    out = tmp_path / "out"
    assert main(["run", "--dataset", str(path), "--rerun", "off", "--quiet", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert any(ln.startswith("graphslam: warning:") and "degrees?" in ln for ln in err.splitlines())
    assert "degrees?" in json.loads((out / "metrics.json").read_text())["warnings"][0]
    assert main(["convert", str(path), str(tmp_path / "g.graph")]) == 0
    assert "degrees?" in capsys.readouterr().err
    honest = _square(tmp_path, math.pi / 2, name="h.g2o")
    assert main(["run", "--dataset", str(honest), "--rerun", "off", "--quiet", "--out", str(out)]) == 0
    # the square is noise-free: its one doubt is that (the residuals far below the stated noise)
    err = capsys.readouterr().err
    assert "degrees?" not in err and "is below the chi-square lower bound" in err
    assert not any("degrees?" in w for w in json.loads((out / "metrics.json").read_text())["warnings"])


def test_the_frame_stream_of_a_2d_file_carries_the_doubt(tmp_path):
    from graphslam.sources.planar.posegraph import read_pose_graph

    assert any("degrees?" in w for w in read_pose_graph(_square(tmp_path, 90)).warnings)
    assert read_pose_graph(_square(tmp_path, math.pi / 2)).warnings == ()
