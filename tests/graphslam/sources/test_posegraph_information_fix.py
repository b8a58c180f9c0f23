"""Information matrices that are not positive definite (issue 32, item 3): replaced
by the nearest positive-definite matrix or SE-Sync's isotropic weights, on those
edges only, counted in the summary and ``metrics.json``; or refused naming file
and line. A matrix with no information, or not finite, is refused always."""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphslam.cli.main import main
from graphslam.sources.posegraph_files import read_pose_graph_file, truncated
from slamcore.errors import InputError
from slamcore.posegraph import INFORMATION_FLOOR, fixed_information
from tests.posegraphs import INFO_2D, INFO_3D, edges_with_closures, graph_lines, square_walk, write

#: Eigenvalues and matrices compared to this, relative to the largest eigenvalue.
REL_TOL = 1e-12

#: Positive diagonal, a cross term too large: indefinite (eigenvalues about -14, 100, 124).
INDEFINITE = {2: np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 0.0], [50.0, 0.0, 10.0]])}
#: x and y translation carry the same information only (eigenvalues 0, 200, 1000).
SEMIDEFINITE = {2: np.array([[100.0, 100.0, 0.0], [100.0, 100.0, 0.0], [0.0, 0.0, 1000.0]])}
INDEFINITE[3] = INFO_3D.copy()
INDEFINITE[3][0, 3] = INDEFINITE[3][3, 0] = 400.0  # x with roll: 100 * 1000 < 400**2
SEMIDEFINITE[3] = INFO_3D.copy()
SEMIDEFINITE[3][0, 1] = SEMIDEFINITE[3][1, 0] = 100.0
#: Edges 1 and 2 of every test file are the bad ones; the file's lines of them.
BAD_EDGES = (1, 2)
N = 8


def _info(dim: int):
    good = INFO_2D if dim == 2 else INFO_3D
    return lambda e: {1: INDEFINITE[dim], 2: SEMIDEFINITE[dim]}.get(e, good)


def _path(tmp_path, dim: int, name: str = "g.g2o"):
    lines = graph_lines(square_walk(N, dim), edges_with_closures(N, [(0, N - 1)]), sigma=0.02,
                        info=_info(dim))
    return write(tmp_path / name, lines)


def _config(tmp_path, fix: str):
    path = tmp_path / f"{fix}.toml"
    path.write_text(f'[posegraph]\ninformation_fix = "{fix}"\nrobust_closures = "none"\n')
    return path


@pytest.mark.parametrize("method", ["nearest", "isotropic"])
@pytest.mark.parametrize("dim", [2, 3])
def test_only_the_edges_not_positive_definite_are_replaced(tmp_path, dim, method):
    graph = read_pose_graph_file(_path(tmp_path, dim), information_fix=method)
    assert graph.information_fix == method and graph.n_information_fixed == 2
    assert np.flatnonzero(graph.information_fixed).tolist() == list(BAD_EDGES)
    info = _info(dim)
    for e in range(graph.n_edges):
        if e in BAD_EDGES:
            np.linalg.cholesky(graph.information[e])  # positive definite now
            np.testing.assert_array_equal(graph.information[e], graph.information[e].T)
        else:  # the file's numbers, bit for bit
            np.testing.assert_array_equal(graph.information[e], info(e))


@pytest.mark.parametrize("dim", [2, 3])
def test_a_clean_file_has_nothing_replaced(tmp_path, dim):
    lines = graph_lines(square_walk(N, dim), edges_with_closures(N, [(0, N - 1)]))
    graph = read_pose_graph_file(write(tmp_path / "clean.g2o", lines))
    assert graph.information_fixed is None and graph.information_fix is None
    assert graph.n_information_fixed == 0


def test_nearest_is_highams_with_a_floor():
    """The eigenvalues clipped at the floor, eigenvectors kept: the Frobenius distance
    to the input is exactly that of the clipped eigenvalues, Higham's minimum."""
    rng = np.random.default_rng(0)
    for side in (3, 6):
        for _ in range(50):
            A = rng.normal(size=(side, side))
            A = A + A.T
            w = np.linalg.eigvalsh(A)
            if w[-1] <= 0:
                continue
            out = fixed_information(A[None], "nearest", 2 if side == 3 else 3)[0]
            wo = np.linalg.eigvalsh(out)
            assert wo[0] >= INFORMATION_FLOOR * w[-1] * (1 - 1e-9)
            np.linalg.cholesky(out)
            clipped = np.maximum(w, INFORMATION_FLOOR * w[-1])
            assert np.linalg.norm(out - A) == pytest.approx(np.linalg.norm(clipped - w),
                                                            rel=1e-9, abs=REL_TOL * w[-1])


@pytest.mark.parametrize("info", [INFO_2D, INFO_3D, INDEFINITE[2] @ INDEFINITE[2]])
def test_nearest_leaves_a_positive_definite_matrix_as_it_is(info):
    dim = 2 if len(info) == 3 else 3
    out = fixed_information(info[None], "nearest", dim)[0]
    np.testing.assert_allclose(out, info, rtol=0, atol=REL_TOL * np.abs(info).max())


@pytest.mark.parametrize("dim", [2, 3])
def test_isotropic_weights_are_se_syncs(dim):
    """SE-Sync's read_g2o_file: tau = d / tr(I_t^-1); kappa = 3 / (2 tr(I_R^-1)) in 3-D
    (rotation precision 2 kappa here, its chordal cost kappa ||.||_F^2 ~ 2 kappa theta^2),
    kappa = I_33 in 2-D (the angle's precision)."""
    info = INDEFINITE[dim]
    out = fixed_information(info[None], "isotropic", dim)[0]
    t, r = slice(0, dim), slice(dim, len(info))
    tau = dim / np.trace(np.linalg.inv(info[t, t]))
    rotation = info[2, 2] if dim == 2 else 2 * 3 / (2 * np.trace(np.linalg.inv(info[r, r])))
    expected = np.diag([tau] * dim + [rotation] * (len(info) - dim))
    np.testing.assert_allclose(out, expected, rtol=1e-12)


@pytest.mark.parametrize("method", ["nearest", "isotropic"])
@pytest.mark.parametrize("dim", [2, 3])
def test_the_run_says_how_many_edges_and_how(tmp_path, capsys, dim, method):
    out = tmp_path / "out"
    assert main(["run", "--dataset", str(_path(tmp_path, dim)), "--backend", "batch",
                 "--config", str(_config(tmp_path, method)), "--rerun", "off",
                 "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["information_fixed"] == {"method": method, "edges": 2}
    summary = capsys.readouterr().out
    assert "information fixed" in summary and "2 edges not positive definite" in summary


def test_a_clean_run_has_no_information_fixed_field(tmp_path, capsys):
    src = write(tmp_path / "clean.g2o", graph_lines(square_walk(N, 2), edges_with_closures(N, [])))
    assert main(["run", "--dataset", str(src), "--backend", "batch", "--rerun", "off",
                 "--quiet", "--out", str(tmp_path / "out")]) == 0
    assert "information_fixed" not in json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert "information fixed" not in capsys.readouterr().out


@pytest.mark.parametrize("dim", [2, 3])
def test_refuse_is_one_line_with_file_and_the_first_bad_line(tmp_path, capsys, dim):
    path = _path(tmp_path, dim)
    first_bad = N + 1 + BAD_EDGES[0]  # N vertex lines, then the edges
    with pytest.raises(InputError, match="not positive definite") as err:
        read_pose_graph_file(path, information_fix="refuse")
    assert err.value.line == first_bad
    rc = main(["run", "--dataset", str(path), "--config", str(_config(tmp_path, "refuse")),
               "--rerun", "off", "--quiet", "--out", str(tmp_path / "out")])
    lines = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(lines) == 1
    assert f"g.g2o:{first_bad}:" in lines[0] and "not positive definite" in lines[0]


@pytest.mark.parametrize("method", ["nearest", "isotropic", "refuse"])
@pytest.mark.parametrize("text, line, fragment", [
    ("EDGE_SE2 0 1 1 0 0 100 0 0 100 0 1000\nEDGE_SE2 1 2 1 0 0 0 0 0 0 0 0\n", 2,
     "no positive eigenvalue"),
    ("EDGE_SE2 0 1 1 0 0 -1 0 0 -2 0 -3\n", 1, "no positive eigenvalue"),
    # square-root information R^T R overflows: not finite, not "not positive definite"
    ("EDGE2 0 1 1 0 0 1e200 0 1 1 0 0\n", 1, "not finite"),
])
def test_no_information_or_non_finite_is_refused_whatever_the_fix(tmp_path, method, text, line,
                                                                  fragment):
    path = tmp_path / "g.graph"
    path.write_text(text)
    if method == "refuse" and "no positive" in fragment:
        fragment = "not positive definite"  # refused first as not positive definite
    with pytest.raises(InputError, match=fragment) as err:
        read_pose_graph_file(path, "sqrt_information", method)
    assert err.value.line == line


def test_a_truncated_graph_counts_its_own_replaced_edges(tmp_path):
    graph = read_pose_graph_file(_path(tmp_path, 2))
    assert truncated(graph, 2).n_information_fixed == 0  # edge 0 only
    assert truncated(graph, 3).n_information_fixed == 1  # edges 0, 1
    assert truncated(graph, N - 1).n_information_fixed == 2


def test_convert_writes_the_replacement_and_says_so(tmp_path, capsys):
    src = _path(tmp_path, 3)
    assert main(["convert", str(src), str(tmp_path / "b.graph")]) == 0
    assert "2 edges' information matrices were not positive definite" in capsys.readouterr().err
    again = read_pose_graph_file(tmp_path / "b.graph")
    assert again.n_information_fixed == 0  # written positive definite
    assert main(["convert", str(src), str(tmp_path / "c.graph"), "--information-fix",
                 "refuse"]) == 2
    assert "not positive definite" in capsys.readouterr().err
