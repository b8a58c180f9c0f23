"""The pose-graph back ends (iSAM2 and batch, 2-D and 3-D): one contract tied to
the registry, the GTSAM optimum, initialisers, and the factorisation fallback."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from graphslam import registry
from graphslam.backends.posegraph import factors as fx
from graphslam.backends.posegraph.config import PoseGraphConfig
from graphslam.backends.posegraph.solver import solve
from graphslam.sources.posegraph_files import read_pose_graph_file
from slamcore.errors import GraphSlamError, MeasurementError
from slamcore.posegraph import params_to_matrix
from tests.posegraphs import edges_with_closures, graph_lines, square_walk, torus, write

#: Noise-free graphs are solved to the truth within this, metres / radians.
EXACT_TOL = 1e-6
#: Two solves of the same graph reach the same cost to this, relative.
OPTIMUM_REL = 1e-6
#: The torus graph: odometry-started LM must stall at least this far above the optimum.
LOCAL_MINIMUM_RATIO = 2.0

#: every pose-graph back end of the registry, with what it must meet
CONTRACT = {"auto": EXACT_TOL, "isam2": EXACT_TOL, "batch": EXACT_TOL}


def test_every_pose_graph_backend_runs_the_contract():
    assert set(CONTRACT) == set(registry.POSEGRAPH_BACKENDS)


def _graph(tmp_path, dim, sigma=0.0, n=20, closures=((0, 19), (3, 14), (6, 17)), **kw):
    truth = square_walk(n, dim)
    lines = graph_lines(truth, edges_with_closures(n, list(closures)), sigma=sigma, **kw)
    return read_pose_graph_file(write(tmp_path / f"g{dim}.g2o", lines)), truth


def _gtsam_optimum(path, dim: int) -> float:
    """A bare gtsam solve of the file: readG2o, a prior on the first pose, LM."""
    graph, initial = gtsam.readG2o(str(path), dim == 3)
    full = gtsam.NonlinearFactorGraph(graph)
    k = initial.keys()[0]
    gauge = gtsam.noiseModel.Isotropic.Sigma(3 if dim == 2 else 6, 1e-3)
    if dim == 2:
        full.add(gtsam.PriorFactorPose2(k, initial.atPose2(k), gauge))
    else:
        full.add(gtsam.PriorFactorPose3(k, initial.atPose3(k), gauge))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-12)
    return float(graph.error(gtsam.LevenbergMarquardtOptimizer(full, initial, params).optimize()))


@pytest.mark.parametrize("solver", sorted(CONTRACT))
@pytest.mark.parametrize("dim", [2, 3])
def test_noise_free_graph_gives_the_truth(tmp_path, solver, dim):
    g, truth = _graph(tmp_path, dim, vertices=False)
    res = solve(g, PoseGraphConfig(), solver)
    T = params_to_matrix(res.params, g.rotation)
    for k, p in enumerate(truth):
        np.testing.assert_allclose(T[k], p.matrix(), atol=CONTRACT[solver])
    assert res.final_cost < EXACT_TOL


@pytest.mark.parametrize("solver", sorted(CONTRACT))
@pytest.mark.parametrize("dim", [2, 3])
def test_noisy_graph_reaches_the_gtsam_optimum_repeatably(tmp_path, solver, dim):
    g, _ = _graph(tmp_path, dim, sigma=0.05)
    a, b = solve(g, PoseGraphConfig(), solver), solve(g, PoseGraphConfig(), solver)
    np.testing.assert_array_equal(a.params, b.params)
    assert a.final_cost == pytest.approx(_gtsam_optimum(tmp_path / f"g{dim}.g2o", dim),
                                         rel=OPTIMUM_REL)
    assert a.residuals.shape == (g.n_edges,) and np.all(np.isfinite(a.residuals))


@pytest.mark.parametrize("solver", sorted(CONTRACT))
def test_backwards_edges_change_nothing(tmp_path, solver):
    fwd, _ = _graph(tmp_path, 2, sigma=0.05)
    back, _ = _graph(tmp_path, 2, sigma=0.05, backwards={1, 7, 20})
    assert tuple(back.edges[7]) == (8, 7)
    a, b = solve(fwd, PoseGraphConfig(), solver), solve(back, PoseGraphConfig(), solver)
    assert a.final_cost == pytest.approx(b.final_cost, rel=OPTIMUM_REL)


@pytest.mark.parametrize("solver", sorted(CONTRACT))
def test_pose_joined_by_a_loop_edge_only(tmp_path, solver):
    truth = square_walk(8, 3)
    edges = [(0, 1), (1, 2), (2, 4), (4, 5), (3, 5), (5, 6), (6, 7), (0, 7), (1, 6)]
    g = read_pose_graph_file(write(tmp_path / "n.g2o", graph_lines(truth, edges, sigma=0.05)))
    res = solve(g, PoseGraphConfig(), solver)
    assert res.final_cost == pytest.approx(_gtsam_optimum(tmp_path / "n.g2o", 3), rel=OPTIMUM_REL)


def test_fixed_poses_stay_put(tmp_path):
    g, truth = _graph(tmp_path, 2, sigma=0.05)
    lines = graph_lines(truth, edges_with_closures(20, [(0, 19)]), sigma=0.05) + ["FIX 0 10"]
    g = read_pose_graph_file(write(tmp_path / "f.g2o", lines))
    res = solve(g, PoseGraphConfig(), "batch")
    np.testing.assert_allclose(res.params[10], g.vertices[10], atol=0.01)  # prior sigma 1 mm


def test_chordal_start_escapes_the_local_minimum_of_odometry(tmp_path):
    T = torus(10, 10)
    n = len(T)
    closures = [(k - 10, k) for k in range(10, n)] + [(k, (k + 10) % n) for k in range(n - 10, n)]
    lines = graph_lines(T, edges_with_closures(n, closures), sigma=0.2, seed=1, vertices=False)
    g = read_pose_graph_file(write(tmp_path / "torus.g2o", lines))
    odometry = solve(g, PoseGraphConfig(init="odometry"), "batch")
    auto = solve(g, PoseGraphConfig(), "batch")
    isam2 = solve(g, PoseGraphConfig(), "isam2")
    assert auto.init_method == "chordal"
    assert odometry.final_cost > LOCAL_MINIMUM_RATIO * auto.final_cost
    assert isam2.final_cost == pytest.approx(auto.final_cost, rel=OPTIMUM_REL)


@pytest.mark.parametrize("dim", [2, 3])
def test_shonan_start_is_certified(tmp_path, dim):
    g, _ = _graph(tmp_path, dim, sigma=0.02)
    res = solve(g, PoseGraphConfig(init="shonan"), "batch")
    lm = solve(g, PoseGraphConfig(), "batch")
    assert res.init_method == "shonan" and res.certificate is not None
    assert res.certificate > -1e-4  # tight relaxation: rotations globally optimal
    assert res.final_cost == pytest.approx(lm.final_cost, rel=OPTIMUM_REL)


def test_lago_and_chordal_refuse_the_other_dimension(tmp_path):
    g, _ = _graph(tmp_path, 2)
    with pytest.raises(GraphSlamError, match="3-D graphs"):
        solve(g, PoseGraphConfig(init="chordal"), "batch")


def _ill_conditioned(tmp_path, condition=1e7):
    """Each edge's information has eigenvalues (condition, sqrt(condition), 1) along
    random directions: plain iSAM2 with Cholesky throws IndeterminateSystem."""
    rng = np.random.default_rng(0)
    infos = []
    for _ in range(70):
        Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        infos.append(Q @ np.diag([condition, np.sqrt(condition), 1.0]) @ Q.T)
    truth = square_walk(60, 2)
    closures = [tuple(sorted(rng.choice(60, 2, replace=False))) for _ in range(10)]
    lines = graph_lines(truth, edges_with_closures(60, closures), sigma=0.05,
                        info=lambda e: infos[e])
    return read_pose_graph_file(write(tmp_path / "ill.g2o", lines))


def test_ill_conditioned_graph_falls_back_to_qr(tmp_path):
    g = _ill_conditioned(tmp_path)
    auto = solve(g, PoseGraphConfig(), "isam2")
    qr = solve(g, PoseGraphConfig(factorization="qr"), "batch")
    assert any("QR" in r for r in auto.recoveries)
    assert auto.final_cost == pytest.approx(qr.final_cost, rel=OPTIMUM_REL)
    with pytest.raises(GraphSlamError, match="indeterminate"):
        solve(g, PoseGraphConfig(factorization="cholesky", polish=False), "isam2")


def test_cost_is_gtsams_graph_error(tmp_path):
    g, _ = _graph(tmp_path, 3, sigma=0.05)
    graph, initial = gtsam.readG2o(str(tmp_path / "g3.g2o"), True)
    assert fx.cost(g, fx.values_of(g, g.vertices)) == pytest.approx(graph.error(initial),
                                                                    rel=1e-12)


def test_gnc_rejects_a_false_closure(tmp_path):
    truth = square_walk(20, 2)
    lines = graph_lines(truth, edges_with_closures(20, [(0, 19), (3, 14), (6, 17)]), sigma=0.01)
    lines.append("EDGE_SE2 2 12 5.0 -3.0 1.0 100 0 0 100 0 1000")  # a false closure
    g = read_pose_graph_file(write(tmp_path / "false.g2o", lines))
    res = solve(g, PoseGraphConfig(robust_closures="gnc"), "batch")
    closures = np.flatnonzero(~g.odometry_mask())
    assert res.rejected[closures].tolist() == [False, False, False, True]
    T = params_to_matrix(res.params, "angle")
    assert np.abs(T[:, :2, 2] - np.array([p.translation() for p in truth])).max() < 0.1


def _edited(graph, field, row, value):
    """``graph`` with one row of ``field`` replaced, as a caller editing it in Python would."""
    a = getattr(graph, field).copy()
    a[row] = value
    return dataclasses.replace(graph, **{field: a})


@pytest.mark.parametrize("solver", ["isam2", "batch", "auto"])
def test_solve_refuses_a_graph_edited_into_numbers_no_file_reader_takes(tmp_path, solver):
    g, _ = _graph(tmp_path, 2)
    cases = {  # before: a NaN final cost, bare RuntimeError or ValueError, non-finite params
        "edge 5: information matrix is not finite": _edited(g, "information", 5, np.nan),
        "edge 5: information matrix has no positive eigenvalue": _edited(g, "information", 5, -g.information[5]),
        "edge 5: information matrix is not positive definite": _edited(g, "information", 5, np.diag([1.0, -1, 1])),
        "measurement 3 is not finite": _edited(g, "measurements", 3, np.inf),
        "vertex 2 is not finite": _edited(g, "vertices", 2, np.nan),
    }
    for message, bad in cases.items():
        with pytest.raises(MeasurementError, match=message):
            solve(bad, PoseGraphConfig(), solver)
