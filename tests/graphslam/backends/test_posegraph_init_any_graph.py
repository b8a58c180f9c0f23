"""Every connected pose graph starts (issue 32, item 2): id gaps, a pose joined
only by closures, a second session restarted at the origin with a ``FIX`` line,
2-D and 3-D, every ``--init`` and both back ends reach the optimum; a relaxation
that fails hands over to the odometry start and says so."""

from __future__ import annotations

import json
import math

import gtsam
import numpy as np
import pytest

from graphslam.backends.posegraph import factors as fx
from graphslam.backends.posegraph import init as initialisers
from graphslam.backends.posegraph.config import PoseGraphConfig
from graphslam.backends.posegraph.solver import solve
from graphslam.cli.main import main
from graphslam.sources.posegraph_files import read_pose_graph_file
from tests.posegraphs import INFO_2D, INFO_3D, edges_with_closures, graph_lines, square_walk, write

#: A solve reaches the optimum found from the truth to this, relative.
OPTIMUM_REL = 1e-6
#: Least squares over every edge: these graphs have no wrong closure, and the
#: starts, not the outlier handling, are under test.
PLAIN = {"robust_closures": "none"}
#: Poses of every test graph (two sessions of 10 where the graph has sessions).
N = 20
#: The ids of a graph with a gap: 0..9, then 100..109.
GAP_IDS = list(range(10)) + list(range(100, 110))
#: Scales the closures' information to this largest value: the chordal relaxation
#: meets an indeterminate system from about 1e15 (LAGO from 1e18), LM still reaches
#: the optimum up to about 1e18.
HUGE_INFORMATION = 1e16

INITS = {2: ("auto", "lago", "odometry", "vertices", "shonan"),
         3: ("auto", "chordal", "odometry", "vertices", "shonan")}
#: LM from the file's vertices is local: where a session (or one pose) restarted at
#: the origin sits half a turn from its truth, batch LM from there stops in a local
#: minimum (2-D sessions 2601 against 8.87; 3-D restart 2485 against 13.6; 3-D
#: sessions at its 200-iteration cap, 3143 against 7.05, flagged not converged). A
#: valid run, not the optimum: iSAM2 and every other start reach it.
LOCAL_MINIMA = {("sessions", 2, "batch", "vertices"), ("sessions", 3, "batch", "vertices"),
                ("restart", 3, "batch", "vertices")}


def _vertex_tag(dim: int) -> str:
    return "VERTEX_SE2" if dim == 2 else "VERTEX_SE3:QUAT"


def _at_origin(lines: list[str], dim: int, ids) -> list[str]:
    """``lines`` with the vertices of ``ids`` at the origin (the file's pose restarted)."""
    tag, zero = _vertex_tag(dim), ("0 0 0" if dim == 2 else "0 0 0 0 0 0 1")
    return [f"{tag} {ln.split()[1]} {zero}" if ln.startswith(tag + " ")
            and int(ln.split()[1]) in ids else ln for ln in lines]


def _sessions(truth, dim: int) -> list[str]:
    """Two sessions of 10 poses (ids 0..9, 100..109) joined by closures only; the
    second's vertices in its own frame (its first pose at the origin); FIX 0."""
    edges = ([(k - 1, k) for k in range(1, 10)] + [(k - 1, k) for k in range(11, N)]
             + [(2, 12), (7, 17), (0, 15)])
    lines = graph_lines(truth, edges, sigma=0.05, ids=GAP_IDS)
    tag, out = _vertex_tag(dim), []
    for line in lines:
        k = int(line.split()[1]) if line.startswith(tag + " ") else -1
        if k >= 100:  # the pose in the frame of the session's first pose (truth 10)
            p = truth[10].between(truth[k - 90])
            line = graph_lines([p], [], ids=[k])[0]
        out.append(line)
    return out + ["FIX 0"]


def _graph_lines(kind: str, dim: int) -> list[str]:
    truth = square_walk(N, dim)
    closures = [(0, 19), (3, 14)]
    if kind == "gap":  # ids with a gap; every pose has an edge from its predecessor
        return graph_lines(truth, edges_with_closures(N, closures), sigma=0.05, ids=GAP_IDS)
    if kind == "lonely":  # pose 5 joined by closures only (no edge to 4 or 6)
        edges = ([(k - 1, k) for k in range(1, N) if k not in (5, 6)]
                 + [(4, 6), (2, 5), (5, 9)] + closures)
        return graph_lines(truth, edges, sigma=0.05)
    if kind == "sessions":
        return _sessions(truth, dim)
    # restart: FIX, an id gap and one pose (the first after the gap) at the origin
    lines = graph_lines(truth, edges_with_closures(N, [(2, 12), (7, 17), (0, 15)]), sigma=0.05,
                        ids=GAP_IDS)
    return ["FIX 0"] + _at_origin(lines, dim, {100})


def _read(tmp_path, kind: str, dim: int):
    path = write(tmp_path / f"{kind}{dim}.g2o", _graph_lines(kind, dim))
    return read_pose_graph_file(path), path


def _optimum(graph, dim: int) -> float:
    """LM (gtsam alone, tight tolerances) from the truth: the cost to reach."""
    truth = gtsam.Values()
    for k, p in zip(graph.ids.tolist(), square_walk(N, dim)):
        truth.insert(k, p)
    edges = fx.edge_graph(graph)
    full = gtsam.NonlinearFactorGraph(edges)
    k0 = int(graph.ids[0])
    gauge = gtsam.noiseModel.Isotropic.Sigma(3 if dim == 2 else 6, 1e-3)
    full.add(gtsam.PriorFactorPose2(k0, truth.atPose2(k0), gauge) if dim == 2
             else gtsam.PriorFactorPose3(k0, truth.atPose3(k0), gauge))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-12)
    return float(edges.error(gtsam.LevenbergMarquardtOptimizer(full, truth, params).optimize()))


@pytest.mark.parametrize("solver", ["isam2", "batch"])
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kind", ["gap", "lonely", "sessions", "restart"])
def test_every_start_of_every_connected_graph_reaches_the_optimum(tmp_path, kind, dim, solver):
    graph, _ = _read(tmp_path, kind, dim)
    best = _optimum(graph, dim)
    for init in INITS[dim]:
        res = solve(graph, PoseGraphConfig(init=init, **PLAIN), solver)
        assert np.isfinite(res.params).all() and np.isfinite(res.final_cost), init
        if (kind, dim, solver, init) in LOCAL_MINIMA:
            assert res.final_cost > best, init  # still a valid run, from a worse start
            continue
        assert not res.lm_capped, init
        assert res.final_cost == pytest.approx(best, rel=OPTIMUM_REL), init


def test_lago_takes_the_odometric_path_by_rank_only_where_it_exists(tmp_path):
    gap, _ = _read(tmp_path, "gap", 2)
    assert initialisers.has_odometric_path(gap)  # 9 -> 100: neighbours by rank
    for kind in ("lonely", "sessions"):
        graph, _ = _read(tmp_path, kind, 2)
        assert not initialisers.has_odometric_path(graph)
        start = initialisers.initial(graph, "lago", 1e-3)
        assert start.method == "lago" and start.note is None
        assert sorted(start.values.keys()) == graph.ids.tolist()


def test_rank_keyed_graph_keeps_edges_and_fix_by_rank(tmp_path):
    graph, _ = _read(tmp_path, "sessions", 2)
    ranked = initialisers.rank_keyed(graph)
    assert ranked.ids.tolist() == list(range(N)) and ranked.fixed.tolist() == [0]
    np.testing.assert_array_equal(graph.ids[ranked.edges], graph.edges)


THE_ISSUES_GAP = {"gap.g2o": "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 2 1 0 0\n"
                             "EDGE_SE2 0 2 1 0 0 500 0 0 500 0 5000\n",
                  "gap.graph": "VERTEX2 0 0 0 0\nVERTEX2 2 1 0 0\n"
                               "EDGE2 0 2 1 0 0 500 0 500 5000 0 0\n"}


@pytest.mark.parametrize("backend", ["isam2", "batch"])
@pytest.mark.parametrize("name", sorted(THE_ISSUES_GAP))
def test_the_issues_id_gap_runs_from_the_command_line(tmp_path, capsys, name, backend):
    path = tmp_path / name
    path.write_text(THE_ISSUES_GAP[name], encoding="utf-8")
    out = tmp_path / "out"
    assert main(["run", "--dataset", str(path), "--backend", backend, "--rerun", "off",
                 "--quiet", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["final_cost"] == pytest.approx(0.0, abs=1e-12)
    assert "numerical_recoveries" not in metrics


def _huge_closures(tmp_path, dim: int):
    base = INFO_2D if dim == 2 else INFO_3D
    huge = base / base.max() * HUGE_INFORMATION
    lines = graph_lines(square_walk(N, dim), edges_with_closures(N, [(0, 19), (3, 14)]),
                        sigma=0.05, info=lambda e: huge if e >= N - 1 else base)
    return read_pose_graph_file(write(tmp_path / f"huge{dim}.g2o", lines))


def test_a_failing_relaxation_hands_over_to_odometry_and_says_so(tmp_path):
    graph = _huge_closures(tmp_path, 3)
    start = initialisers.initial(graph, "auto", 1e-3)
    assert start.method == "odometry"
    assert "the chordal relaxation failed (indeterminate linear system near pose" in start.note
    res = solve(graph, PoseGraphConfig(**PLAIN), "batch")
    assert res.init_method == "odometry"
    from_vertices = solve(graph, PoseGraphConfig(init="vertices", **PLAIN), "batch")
    assert res.final_cost == pytest.approx(from_vertices.final_cost, rel=OPTIMUM_REL)


@pytest.mark.parametrize("failure, reason", [
    (IndexError("map::at"), "IndexError: map::at"),
    (RuntimeError("\nIndeterminate linear system detected while working near variable\n"
                  "3 (Symbol: 3)."), "indeterminate linear system near pose 3"),
])
def test_lago_failures_become_a_note(tmp_path, monkeypatch, failure, reason):
    graph, _ = _read(tmp_path, "gap", 2)

    def fail(*args):
        raise failure

    monkeypatch.setattr(gtsam.lago, "initialize", fail)
    start = initialisers.initial(graph, "lago", 1e-3)
    assert start.method == "odometry" and f"LAGO failed ({reason})" in start.note
    chain = initialisers.initial(graph, "odometry", 1e-3)
    np.testing.assert_array_equal(fx.params_from(graph, start.values),
                                  fx.params_from(graph, chain.values))
    res = solve(graph, PoseGraphConfig(**PLAIN), "batch")
    assert res.final_cost == pytest.approx(_optimum(graph, 2), rel=OPTIMUM_REL)


def test_non_finite_relaxation_becomes_a_note(tmp_path, monkeypatch):
    graph, _ = _read(tmp_path, "lonely", 2)

    def nan_poses(pose_graph, *args):
        values = gtsam.Values()
        for r in range(graph.n_poses):
            values.insert(r, gtsam.Pose2(math.nan, 0.0, 0.0))
        return values

    monkeypatch.setattr(gtsam.lago, "initialize", nan_poses)
    start = initialisers.initial(graph, "auto", 1e-3)
    assert start.method == "odometry" and "non-finite poses" in start.note


def test_init_shonan_takes_se_syncs_weights_where_gtsam_refuses_the_files(tmp_path):
    """gtsam's Shonan refuses anisotropic rotation information (sphere2500's: "noise
    models must be isotropic"), and --init shonan fell back to the odometry start.
    Asked for by name it now runs on SE-Sync's isotropic weights and LM reaches the
    optimum; auto's retry keeps the file's weights and says why it did not run."""
    truth = square_walk(N, 3)
    info = np.diag([100.0, 100.0, 100.0, 400.0, 1000.0, 2500.0])  # rotation axes unequal
    lines = graph_lines(truth, edges_with_closures(N, [(0, N - 1), (3, 14)]), sigma=0.05, seed=3, info=lambda e: info)
    graph = read_pose_graph_file(write(tmp_path / "aniso.g2o", lines))
    refused, why = initialisers.relaxed(graph, "shonan", 1e-3)
    assert refused is None and "isotropic" in why
    start = initialisers.initial(graph, "shonan", 1e-3)
    assert start.method == "shonan" and start.note is None and start.certificate is not None
    config = PoseGraphConfig(init="shonan", **PLAIN)
    from_shonan = solve(graph, config, "batch")
    from_chordal = solve(graph, PoseGraphConfig(init="chordal", **PLAIN), "batch")
    assert from_shonan.init_method == "shonan"
    assert math.isclose(from_shonan.final_cost, from_chordal.final_cost, rel_tol=OPTIMUM_REL)
    from graphslam.backends.posegraph import route

    kept = route.retry_from_certified_rotations(graph, PoseGraphConfig(**PLAIN), solve, from_chordal)
    assert kept is from_chordal and kept.route["shonan_retry"] == (
        "not certified; no retry: the file's rotation information is not isotropic, which "
        "gtsam's Shonan averaging needs (--init shonan runs it on SE-Sync's isotropic weights)")
