"""A built-in dataset name works wherever a path does (issue 35's interface list)."""

from __future__ import annotations

import json

import numpy as np

from graphslam import registry
from graphslam.cli.main import main


def test_convert_takes_a_built_in_pose_graph(tmp_path, capsys):
    out = tmp_path / "city.g2o"
    assert main(["convert", "city10000", str(out)]) == 0, capsys.readouterr().err
    graph = registry.load_pose_graph(out)
    assert (graph.n_poses, graph.n_edges) == (10000, 20687)
    # the edges keep the built-in reader's numbers: sigmas 1/30 m, 1/30 m, 1/100 rad
    assert np.allclose(graph.information[0], np.diag([900.0, 900.0, 10000.0]))


def test_batch_solves_a_built_in_pose_graph_with_its_truth(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "--dataset", "city10000", "--backend", "batch", "--max-steps", "1500",
                 "--rerun", "off", "--quiet", "--out", str(out)]) == 0, capsys.readouterr().err
    m = json.loads((out / "metrics.json").read_text())
    assert m["backend"] == "batch"
    # the truth comes with the built-in graph: the ATE of the first 1500 poses is scored
    # (0.49 m, as the streamed iSAM2 run of the same poses; odometry 6.5 m)
    assert m["ate_poses"] == 1500 and m["ate_rmse_m"] < 0.1 * m["odometry_ate_rmse_m"]
    assert (out / "ground_truth.tum").is_file()


def test_batch_on_w10000_and_a_file_of_that_name_wins(tmp_path, capsys, monkeypatch):
    out = tmp_path / "w"
    assert main(["run", "--dataset", "w10000", "--backend", "batch", "--max-steps", "500",
                 "--rerun", "off", "--quiet", "--out", str(out)]) == 0, capsys.readouterr().err
    assert json.loads((out / "metrics.json").read_text())["poses"] == 500
    # a file named like a built-in in the working folder is read as the file
    monkeypatch.chdir(tmp_path)
    (tmp_path / "w10000").write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n"
                                     "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    assert registry.load_pose_graph("w10000").n_poses == 2


def test_unknown_dataset_lists_every_built_in(tmp_path, capsys):
    assert main(["run", "--dataset", str(tmp_path / "nosuch"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "synthetic-images" in err and "city10000" in err and len(err.splitlines()) == 1
