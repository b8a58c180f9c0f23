"""``graphslam compare`` on pose graphs: the whole-graph solvers side by side (issue 35:
'--backends isam2 batch' was refused and a 3-D graph's error suggested an option compare
does not have)."""

from __future__ import annotations

import json

import gtsam
import pytest

from graphslam.cli.main import main

#: Solvers that reach one optimum agree to this relative cost and these metres.
SAME_COST_REL = 1e-6
SAME_POSITIONS_M = 1e-3


def test_a_3d_graph_compares_its_three_solvers_by_default(tmp_path, capsys):
    out = tmp_path / "c"
    path = gtsam.findExampleDataFile("pose3example.txt")
    assert main(["compare", "--dataset", path, "--out", str(out)]) == 0, capsys.readouterr().err
    doc = json.loads((out / "compare.json").read_text())
    assert doc["kind"] == "pose graph" and doc["graph"]["dim"] == 3
    runs = doc["runs"]
    assert [r["backend"] for r in runs] == ["isam2", "batch", "auto"]
    best = min(r["final_cost"] for r in runs)
    for r in runs:
        assert r["status"] == "ok"
        assert r["final_cost"] <= best * (1 + SAME_COST_REL) + 1e-12
        assert r["rms_to_first_m"] < SAME_POSITIONS_M
    assert (out / "compare.png").stat().st_size > 5000 and (out / "compare.rrd").is_file()
    table = capsys.readouterr().out
    assert "RMS to first [m]" in table and "batch" in table
    # pose3example's optimum is certified by every solver, and the table says so
    assert all(r["certificate"]["certified"] is True for r in runs)
    assert "certified" in table.splitlines()[0]
    lines = [t.split() for t in table.splitlines() if t.split()[:1] in (["isam2"], ["batch"], ["auto"])]
    # backend, status, final cost, iterations, rejected, certified, ...
    assert [line[5] for line in lines] == ["yes", "yes", "yes"]


def test_named_solvers_on_a_2d_graph_and_a_built_in_with_truth(tmp_path, capsys):
    w100 = gtsam.findExampleDataFile("w100.graph")
    out = tmp_path / "w"
    assert main(["compare", "--dataset", w100, "--backends", "isam2", "batch", "--rerun", "off",
                 "--out", str(out)]) == 0
    assert [r["backend"] for r in json.loads((out / "compare.json").read_text())["runs"]] == \
        ["isam2", "batch"]
    assert not (out / "compare.rrd").exists()
    out = tmp_path / "city"
    assert main(["compare", "--dataset", "city10000", "--backends", "batch", "--max-steps", "400",
                 "--rerun", "off", "--out", str(out)]) == 0
    run = json.loads((out / "compare.json").read_text())["runs"][0]
    assert run["ate_poses"] == 400 and run["ate_rmse_m"] < run["odometry_ate_rmse_m"]
    capsys.readouterr()


@pytest.mark.parametrize("extra, words", [
    (["--backends", "isam2", "batch", "ekf"], "--backends ekf: a whole pose graph"),
    (["--backends", "batch", "--seed", "3"], "--seed has no effect"),
])
def test_what_a_pose_graph_comparison_cannot_do_is_one_line(tmp_path, capsys, extra, words):
    w100 = gtsam.findExampleDataFile("w100.graph")
    assert main(["compare", "--dataset", w100, "--rerun", "off", "--out", str(tmp_path / "o"),
                 *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0]


def test_a_graph_whose_file_name_is_not_utf8_is_drawn(tmp_path, capsys):
    # the plot's title names the graph: a Latin-1 file name (lone surrogates in Python)
    # made matplotlib's font code raise, a traceback after both solves
    import os

    path = tmp_path / os.fsdecode(b"g\xe9.g2o")
    path.write_text("".join(f"VERTEX_SE2 {k} {k} 0 0\n" for k in range(4))
                    + "".join(f"EDGE_SE2 {k} {k + 1} 1 0 0 100 0 0 100 0 1000\n" for k in range(3)))
    out = tmp_path / "c"
    assert main(["compare", "--dataset", str(path), "--out", str(out), "--rerun", "off",
                 "--backends", "batch", "isam2"]) == 0, capsys.readouterr().err
    assert (out / "compare.png").stat().st_size > 5000
