"""``--backend auto`` (issue 32 item 4): batch from the relaxation start, kept
when its residuals are what the stated noise predicts; iSAM2 too where they are
not, the lower cost kept and a local minimum named."""

from __future__ import annotations

import json
import re

import pytest

from graphslam.backends.posegraph.config import PoseGraphConfig
from graphslam.backends.posegraph.solver import solve
from graphslam.cli.main import main
from graphslam.sources.posegraph_files import read_pose_graph_file
from tests.posegraphs import manhattan_walk

#: Two routes at the same optimum agree to this, relative.
OPTIMUM_REL = 1e-6


def test_auto_keeps_isam2_where_batch_stops_in_a_local_minimum(tmp_path):
    g = read_pose_graph_file(manhattan_walk(tmp_path))
    batch = solve(g, PoseGraphConfig(), "batch")
    isam2 = solve(g, PoseGraphConfig(), "isam2")
    auto = solve(g, PoseGraphConfig(), "auto")
    assert batch.final_cost > 10 * isam2.final_cost  # LAGO's start misleads batch here
    assert auto.route["kept"] == "isam2"
    assert auto.final_cost == pytest.approx(isam2.final_cost, rel=OPTIMUM_REL)
    assert "batch stopped in a local minimum" in auto.route["local_minimum"]


def test_auto_keeps_batch_alone_where_its_residuals_are_consistent(tmp_path):
    g = read_pose_graph_file(manhattan_walk(tmp_path, seed=1))
    auto = solve(g, PoseGraphConfig(), "auto")
    isam2 = solve(g, PoseGraphConfig(), "isam2")
    assert auto.route["kept"] == "batch" and "isam2" not in auto.route  # iSAM2 not run
    assert "within the chi-square bound" in auto.route["reason"]
    assert auto.final_cost == pytest.approx(isam2.final_cost, rel=OPTIMUM_REL)


def test_auto_is_the_default_for_a_pose_graph_file_and_says_its_route(tmp_path, capsys):
    path = manhattan_walk(tmp_path)
    out = tmp_path / "out"
    assert main(["run", "--dataset", str(path), "--out", str(out), "--rerun", "off"]) == 0
    text = capsys.readouterr().out
    assert re.search(r"backend\s+auto", text)
    assert re.search(r"route\s+isam2 kept \(2 x cost over kept edges", text)
    assert re.search(r"local minimum\s+batch stopped in a local minimum", text)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["backend"] == "auto" and metrics["route"]["kept"] == "isam2"


def test_no_polish_alone_still_runs_isam2_on_a_file(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", "--dataset", str(manhattan_walk(tmp_path, seed=1)), "--no-polish",
                 "--out", str(out), "--rerun", "off"]) == 0
    assert re.search(r"backend\s+isam2", capsys.readouterr().out)


def test_auto_on_a_stream_dataset_is_refused_in_one_line(capsys):
    assert main(["run", "--dataset", "synthetic", "--backend", "auto"]) == 2
    assert "--backend auto solves pose-graph files only" in capsys.readouterr().err
