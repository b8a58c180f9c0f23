"""Landmark SLAM from files: TORO ``BR`` lines (gtsam's example.graph) and logs in
Victoria Park's format given by path, checked against gtsam's own reader and optimiser."""

from __future__ import annotations

import json
import re

import gtsam
import numpy as np
import pytest

from graphslam import registry
from graphslam.cli.main import main
from graphslam.sources.planar.posegraph import read_pose_graph
from graphslam.sources.planar.victoria_park import read_victoria_park, victoria_park_path
from slamcore.errors import InputError

#: Range and bearing as read back from gtsam's factors (text -> double both ways).
MEASUREMENT_TOL = 1e-12
#: Graph error of our polished iSAM2 estimate against gtsam's Levenberg-Marquardt
#: optimum of the same file (chi-square units; both converge to ~1e-7 of each other).
OPTIMUM_TOL = 1e-4

EDGE = "EDGE2 {a} {b} 1 0 0 1 0 1 1 0 0\n"


def _example_graph() -> str:
    return gtsam.findExampleDataFile("example.graph")


def _gtsam_bearing_ranges(path):
    graph, _ = gtsam.load2D(path)
    out = []
    for i in range(graph.size()):
        f = graph.at(i)
        if isinstance(f, gtsam.BearingRangeFactor2D):
            pose, landmark = f.keys()
            out.append((gtsam.Symbol(pose).index(), gtsam.Symbol(landmark).index(), f))
    return out


def test_example_graph_observations_match_load2d():
    ds = read_pose_graph(_example_graph(), fmt="toro")
    ours = [o for f in ds.frames for o in f.observations]
    theirs = _gtsam_bearing_ranges(_example_graph())
    assert len(ds.frames) == 95 and len(ours) == len(theirs) == 422
    # same observations, file order within a frame, frames in pose order
    theirs.sort(key=lambda t: t[0])
    for obs, (pose, landmark, factor) in zip(ours, theirs):
        assert (obs.pose_id, obs.landmark_id) == (pose, landmark)
        measured = factor.measured()
        assert obs.z[0] == pytest.approx(measured.range(), abs=MEASUREMENT_TOL)
        assert obs.z[1] == pytest.approx(measured.bearing().theta(), abs=MEASUREMENT_TOL)
        sigmas = factor.noiseModel().sigmas()  # gtsam: [bearing, range]
        np.testing.assert_allclose(np.sqrt(np.diag(obs.covariance)), sigmas[::-1],
                                   rtol=0, atol=MEASUREMENT_TOL)


def test_example_graph_runs_as_landmark_slam_to_gtsams_optimum(tmp_path, capsys):
    """gtsam's least squares: the sightings without the default robust kernel."""
    path = _example_graph()
    assert not registry.is_pose_graph_run(path, "isam2")
    assert registry.is_pose_graph_run(path, "batch")
    gaussian = tmp_path / "gaussian.toml"
    gaussian.write_text('[isam2]\nobservation_kernel = "none"\n')
    rc = main(["run", "--dataset", path, "--out", str(tmp_path / "r"), "--rerun", "off",
               "--quiet", "--config", str(gaussian)])
    assert rc == 0, capsys.readouterr().err
    metrics = json.loads((tmp_path / "r" / "metrics.json").read_text())
    graph, initial = gtsam.load2D(path)
    optimum = graph.error(gtsam.LevenbergMarquardtOptimizer(graph, initial).optimize())
    assert metrics["final_error"] == pytest.approx(optimum, abs=OPTIMUM_TOL)
    landmarks = (tmp_path / "r" / "landmarks.csv").read_text().splitlines()
    assert len(landmarks) - 1 == 24  # every landmark of the file, one row each


@pytest.mark.parametrize("backend", ["ekf", "fastslam1"])
def test_example_graph_runs_on_the_filters(tmp_path, capsys, backend):
    rc = main(["run", "--dataset", _example_graph(), "--backend", backend, "--out",
               str(tmp_path / backend), "--rerun", "off", "--quiet"])
    assert rc == 0, capsys.readouterr().err
    assert json.loads((tmp_path / backend / "metrics.json").read_text())["steps"] == 95


def test_batch_refuses_a_landmark_file_at_its_first_br_line(tmp_path, capsys):
    rc = main(["run", "--dataset", _example_graph(), "--backend", "batch", "--out",
               str(tmp_path / "b"), "--rerun", "off", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1
    assert "example.graph:190:" in err and "landmark SLAM" in err and "--backend isam2" in err


@pytest.mark.parametrize("line, fragment", [
    ("BR 1 5 0.1 2 0.01", "needs 7 tokens"),
    ("BR 3 5 0.1 2 0.01 0.1", "pose 3, which no edge or vertex names"),
    ("BR 1 5 0.1 0 0.01 0.1", "range must be positive"),
    ("BR 1 5 0.1 2 0 0.1", "sigmas must be positive"),
    ("BR 1 5 0.1 2 0.01 nan", "not finite"),
    ("BR 1 x 0.1 2 0.01 0.1", "landmark id"),
])
def test_bad_br_lines_are_named(tmp_path, capsys, line, fragment):
    path = tmp_path / "bad.graph"
    path.write_text("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\n" + EDGE.format(a=0, b=1) + line + "\n")
    with pytest.raises(InputError) as info:
        read_pose_graph(path, fmt="toro")
    assert info.value.line == 4 and fragment in str(info.value)
    rc = main(["run", "--dataset", str(path), "--out", str(tmp_path / "r"), "--rerun", "off",
               "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "bad.graph:4:" in err and err.count("\n") == 1


def test_bearing_is_wrapped_and_observations_join_their_pose(tmp_path):
    path = tmp_path / "w.graph"
    path.write_text(EDGE.format(a=0, b=1) + EDGE.format(a=1, b=2)
                    + "BR 2 7 4.0 3 0.01 0.1\nBR 0 7 -0.5 2 0.01 0.1\n")
    ds = read_pose_graph(path, fmt="toro")
    seen = {f.pose_id: f.observations for f in ds.frames}
    assert [len(seen[k]) for k in (0, 1, 2)] == [1, 0, 1]
    assert seen[2][0].z[1] == pytest.approx(4.0 - 2 * np.pi, abs=MEASUREMENT_TOL)


def test_victoria_park_format_by_path(tmp_path, capsys):
    lines = open(victoria_park_path()).read().splitlines(keepends=True)[:600]
    path = tmp_path / "log.txt"
    path.write_text("".join(lines))
    ds = registry.load_dataset(str(path))
    reference = read_victoria_park(path)
    assert ds.name == "log" and reference.name == "victoria-park"
    assert [f.pose_id for f in ds.frames] == [f.pose_id for f in reference.frames]
    assert sum(len(f.observations) for f in ds.frames) \
        == sum(len(f.observations) for f in reference.frames) > 0
    rc = main(["run", "--dataset", str(path), "--out", str(tmp_path / "r"), "--rerun", "off",
               "--quiet"])
    assert rc == 0, capsys.readouterr().err
    metrics = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert metrics["dataset"] == "log" and metrics["steps"] == len(ds.frames)


def test_pose_graph_only_options_say_why_on_a_landmark_file(tmp_path, capsys):
    rc = main(["run", "--dataset", _example_graph(), "--init", "lago", "--out",
               str(tmp_path / "r"), "--rerun", "off", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "has landmark lines" in err
    rc = main(["convert", _example_graph(), str(tmp_path / "g.g2o")])
    err = capsys.readouterr().err
    assert rc == 2 and "example.graph:190:" in err and "not a pose graph" in err


def test_a_3d_file_with_a_br_line_is_refused_at_that_line(tmp_path, capsys):
    path = tmp_path / "b.graph"
    path.write_text("VERTEX3 0 0 0 0 0 0 0\nVERTEX3 1 1 0 0 0 0 0\n"
                    "EDGE3 0 1 1 0 0 0 0 0" + " 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1"
                    + "\nBR 1 5 0.1 2 0.01 0.1\n")
    rc = main(["run", "--dataset", str(path), "--out", str(tmp_path / "r"), "--rerun", "off",
               "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "b.graph:4:" in err and "landmark" in err


def test_a_g2o_file_with_a_br_line_is_refused_at_that_line(tmp_path, capsys):
    path = tmp_path / "b.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n"
                    "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nBR 1 5 0.1 2 0.01 0.1\n")
    rc = main(["run", "--dataset", str(path), "--out", str(tmp_path / "r"), "--rerun", "off",
               "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "b.g2o:4:" in err and "2-D TORO" in err


@pytest.mark.parametrize("backend, section", [("ekf", "ekf"), ("fastslam2", "fastslam")])
def test_pruning_on_a_file_without_a_sensor_field_is_said_to_do_nothing(tmp_path, capsys, backend, section):
    """``prune_missed_alpha`` needs the field the sensor sees: a TORO file states none,
    and the setting changed nothing without a word."""
    config = tmp_path / "c.toml"
    config.write_text(f"[{section}]\nassociation = 'unknown'\nprune_missed_alpha = 0.01\n")
    rc = main(["run", "--dataset", _example_graph(), "--backend", backend, "--config", str(config),
               "--out", str(tmp_path / "r"), "--rerun", "off", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 0
    said = f"[{section}] prune_missed_alpha did nothing: it acts only with data that states its sensor's field"
    assert said in err
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert any(said in w for w in m["provenance"]["did_nothing"])
    assert "landmarks_pruned" not in m


def test_pruning_on_data_with_a_sensor_field_is_not_said_to_do_nothing(tmp_path, capsys):
    config = tmp_path / "c.toml"
    config.write_text("[ekf]\nassociation = 'unknown'\nprune_missed_alpha = 0.01\n")
    assert main(["run", "--backend", "ekf", "--max-steps", "60", "--config", str(config),
                 "--out", str(tmp_path / "r"), "--rerun", "off", "--quiet"]) == 0
    assert "prune_missed_alpha did nothing" not in capsys.readouterr().err


def test_a_misread_sighting_is_counted_in_the_summary_and_metrics(tmp_path, capsys):
    """FastSLAM 2.0 with the file's landmark ids: one sighting of landmark 7 reported
    90 deg off (a misread id) is kept out of every particle's proposal and landmark
    step, and the run says how many sightings its gate rejected (stdout and
    ``metrics.json``). One: had the misread moved the landmark (a Gaussian sensor's
    full Kalman step), the true sighting after it would have been rejected too."""
    firm = "EDGE2 {a} {b} 1 0 0 10000 0 10000 10000 0 0\n"  # 1 cm, 0.01 rad
    sightings = ["BR 0 7 0 5 0.01 0.05", "BR 1 7 0 4 0.01 0.05", "BR 2 7 1.5708 3 0.01 0.05",
                 "BR 3 7 0 2 0.01 0.05"]
    path = tmp_path / "misread.graph"
    path.write_text("".join(firm.format(a=k, b=k + 1) for k in range(3)) + "\n".join(sightings) + "\n")
    rc = main(["run", "--dataset", str(path), "--backend", "fastslam2", "--out", str(tmp_path / "r"),
               "--rerun", "off"])
    out = capsys.readouterr().out
    assert rc == 0
    assert re.search(r"sightings rejected +1 \(beyond the back end's gate\)", out)
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert m["observations_rejected"] == 1
