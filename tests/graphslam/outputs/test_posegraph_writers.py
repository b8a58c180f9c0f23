"""Pose-graph writers: read, write, read is the identity in every format; the
optimised graph a run writes gives the run's cost back; ``graphslam convert``."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from graphslam.backends.posegraph import factors as fx
from graphslam.cli.main import main
from graphslam.outputs.posegraph import convert, write_pose_graph
from graphslam.sources.posegraph_files import read_pose_graph_file
from slamcore.posegraph import params_to_matrix
from tests.posegraphs import edges_with_closures, graph_lines, square_walk, write

#: The written estimate's cost equals the run's final cost to this, relative.
COST_REL = 1e-9
#: Rotations re-expressed (quaternion <-> roll pitch yaw) agree to this.
ROTATION_TOL = 1e-12

FIELDS = ("ids", "vertices", "has_vertex", "edges", "measurements", "information", "fixed",
          "equiv")


def assert_same_graph(a, b):
    assert (a.format, a.dim, a.rotation) == (b.format, b.dim, b.rotation)
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


def _lines(dim, fmt, vertices=True):
    rng = np.random.default_rng(3)
    side = 3 if dim == 2 else 6
    infos = [(lambda A: A @ A.T + side * np.eye(side))(rng.normal(size=(side, side)))
             for _ in range(12)]
    return graph_lines(square_walk(10, dim), edges_with_closures(10, [(0, 9), (2, 8), (1, 5)]),
                       fmt=fmt, sigma=0.03, vertices=vertices, info=lambda e: infos[e])


@pytest.mark.parametrize("vertices", [True, False])
@pytest.mark.parametrize("dim,fmt", [(2, "g2o"), (3, "g2o"), (2, "toro"), (3, "toro")])
def test_read_write_read_is_identity(tmp_path, dim, fmt, vertices):
    extra = ["FIX 0"] + (["EQUIV 0 9"] if fmt == "toro" else [])
    first = read_pose_graph_file(write(tmp_path / "a.txt", _lines(dim, fmt, vertices) + extra))
    write_pose_graph(tmp_path / "b.txt", first)
    assert_same_graph(first, read_pose_graph_file(tmp_path / "b.txt"))


@pytest.mark.parametrize("dim", [2, 3])
def test_convert_keeps_the_graph(tmp_path, dim):
    g = read_pose_graph_file(write(tmp_path / "a.g2o", _lines(dim, "g2o")))
    toro, _ = convert(g, "toro")
    write_pose_graph(tmp_path / "b.graph", toro)
    back, _ = convert(read_pose_graph_file(tmp_path / "b.graph"), "g2o")
    np.testing.assert_array_equal(back.information, g.information)
    np.testing.assert_allclose(params_to_matrix(back.measurements, back.rotation),
                               params_to_matrix(g.measurements, g.rotation), atol=ROTATION_TOL)
    assert fx.cost(back, fx.values_of(back, back.vertices)) == pytest.approx(
        fx.cost(g, fx.values_of(g, g.vertices)), rel=COST_REL)


def test_convert_drops_equiv_for_g2o_and_says_so(tmp_path):
    g = read_pose_graph_file(write(tmp_path / "a.graph", _lines(2, "toro") + ["EQUIV 0 9"]))
    out, notes = convert(g, "g2o")
    assert len(out.equiv) == 0 and "EQUIV" in notes[0]


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("backend", ["isam2", "batch"])
def test_run_writes_the_optimised_graph(tmp_path, capsys, dim, backend):
    src = write(tmp_path / "in.g2o", _lines(dim, "g2o"))
    out = tmp_path / "out"
    assert main(["run", "--dataset", str(src), "--backend", backend, "--rerun", "off",
                 "--out", str(out)]) == 0
    capsys.readouterr()
    metrics = json.loads((out / "metrics.json").read_text())
    written = read_pose_graph_file(out / "graph.g2o")
    original = read_pose_graph_file(src)
    np.testing.assert_array_equal(written.measurements, original.measurements)
    np.testing.assert_array_equal(written.information, original.information)
    cost = fx.cost(written, fx.values_of(written, written.vertices))
    assert cost == pytest.approx(metrics["final_cost"], rel=COST_REL)
    assert metrics["final_cost"] < metrics["initial_cost"]
    closures = (out / "closures.csv").read_text().splitlines()
    assert closures[0] == "from,to,line,kept,whitened_residual,tested" and len(closures) == 1 + 3
    assert {row.split(",")[-1] for row in closures[1:]} == {"1"}  # the polish tested them
    assert len((out / "trajectory.tum").read_text().splitlines()) == 1 + 10


def test_convert_command(tmp_path, capsys):
    src = write(tmp_path / "a.graph", _lines(3, "toro"))
    assert main(["convert", str(src), str(tmp_path / "b.g2o")]) == 0
    assert read_pose_graph_file(tmp_path / "b.g2o").format == "g2o"
    capsys.readouterr()
    assert main(["convert", str(src), str(tmp_path / "b.txt")]) == 2
    assert "--to" in capsys.readouterr().err


def test_convert_makes_the_output_folder_and_refuses_a_file_in_its_path(tmp_path, capsys):
    """A missing folder was refused only after the graph was read ("cannot write: No such
    file or directory"), where every other --out makes its folder."""
    src = write(tmp_path / "a.graph", _lines(3, "toro"))
    assert main(["convert", str(src), str(tmp_path / "new" / "deep" / "b.g2o")]) == 0
    assert read_pose_graph_file(tmp_path / "new" / "deep" / "b.g2o").format == "g2o"
    (tmp_path / "f").write_text("")
    capsys.readouterr()
    assert main(["convert", str(src), str(tmp_path / "f" / "b.g2o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "is an existing file, not a folder" in err


def test_rejected_closures_in_csv_and_recording(tmp_path, capsys):
    lines = graph_lines(square_walk(10, 2), edges_with_closures(10, [(0, 9), (2, 8), (1, 5)]),
                        sigma=0.01) + ["EDGE_SE2 2 7 5.0 -3.0 1.0 100 0 0 100 0 1000"]
    src = write(tmp_path / "in.g2o", lines)
    config = tmp_path / "c.toml"
    config.write_text('[posegraph]\nrobust_closures = "gnc"\n')
    out = tmp_path / "out"
    assert main(["run", "--dataset", str(src), "--backend", "batch", "--config", str(config),
                 "--out", str(out)]) == 0
    assert re.search(r"closures rejected\s+1 of 4 \(outlier test", capsys.readouterr().out)
    rows = (out / "closures.csv").read_text().splitlines()[1:]
    assert [r.split(",")[3] for r in rows] == ["1", "1", "1", "0"]
    assert (out / "run.rrd").stat().st_size > 0


#: Square-root information goes back through a Cholesky factor: equal to rounding.
SQRT_ROUND_TRIP_REL = 1e-13


@pytest.mark.parametrize("dim", [2, 3])
def test_square_root_information_round_trip(tmp_path, dim):
    first = read_pose_graph_file(write(tmp_path / "a.graph", _lines(dim, "toro")),
                                 toro_noise="sqrt_information")
    write_pose_graph(tmp_path / "b.graph", first)
    again = read_pose_graph_file(tmp_path / "b.graph", toro_noise="sqrt_information")
    np.testing.assert_array_equal(again.measurements, first.measurements)
    np.testing.assert_allclose(again.information, first.information, rtol=SQRT_ROUND_TRIP_REL)


def test_lm_stopped_by_its_cap_is_flagged(tmp_path, capsys):
    """A batch LM that uses every iteration it may says it did not converge (w20000
    from LAGO stops at the 200-iteration cap at 69x the cost the isam2 back end reaches)."""
    import gtsam

    w100 = gtsam.findExampleDataFile("w100.graph")
    capped = tmp_path / "capped.toml"
    capped.write_text("[posegraph]\nmax_iterations = 1\ninit = \"odometry\"\n")
    for name, config, converged in (("capped", capped, False), ("free", None, True)):
        out = tmp_path / name
        argv = ["run", "--dataset", w100, "--backend", "batch", "--rerun", "off", "--quiet",
                "--out", str(out)] + ([] if config is None else ["--config", str(config)])
        assert main(argv) == 0
        summary = capsys.readouterr().out
        assert json.loads((out / "metrics.json").read_text())["converged"] is converged
        assert ("NOT CONVERGED" in summary) is not converged


def test_convert_writes_toro_as_its_toro_noise_says(tmp_path, capsys):
    """g2o -> TORO with --toro-noise sqrt_information writes R (information = R^T R), so
    reading it back the same way gives the g2o file's information."""
    src = tmp_path / "a.g2o"
    truth = square_walk(6, 2)
    write(src, graph_lines(truth, edges_with_closures(len(truth), [(0, 5)]), fmt="g2o"))
    out = tmp_path / "b.graph"
    assert main(["convert", str(src), str(out), "--toro-noise", "sqrt_information"]) == 0
    a = read_pose_graph_file(src)
    b = read_pose_graph_file(out, toro_noise="sqrt_information")
    np.testing.assert_allclose(b.information, a.information, rtol=1e-9)
