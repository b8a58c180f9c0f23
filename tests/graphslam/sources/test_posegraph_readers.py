"""g2o and TORO readers, 2-D and 3-D: every property a benchmark file can have,
and every bad line refused as one line naming file and line (exit 2 from the CLI)."""

from __future__ import annotations

import re
import time

import gtsam
import numpy as np
import pytest

from graphslam.cli.main import main
from graphslam.sources.posegraph_files import read_pose_graph_file, truncated
from slamcore.errors import InputError
from slamcore.posegraph import params_to_matrix, rpy_to_matrix
from tests.posegraphs import edges_with_closures, graph_lines, square_walk, write

#: Poses composed from noise-free edges match the truth to this, metres / radians.
COMPOSE_TOL = 1e-9
#: Hang guard on reading a file with an id gap of 2**40, s: a loop over the gap would
#: take hours; the read takes milliseconds. Not a timing check.
GAP_READ_S = 300.0

EDGE_2D = "EDGE_SE2 0 1 1 0 0 100 0 0 100 0 1000"


def _file(tmp_path, text, name="g.g2o"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


@pytest.mark.parametrize("dim,fmt", [(2, "g2o"), (3, "g2o"), (2, "toro"), (3, "toro")])
def test_each_format_reads_vertices_edges_and_full_information(tmp_path, dim, fmt):
    truth = square_walk(8, dim)
    side = 3 if dim == 2 else 6
    rng = np.random.default_rng(0)
    infos = []
    for _ in range(9):  # full, off-diagonal terms included
        A = rng.normal(size=(side, side))
        infos.append(A @ A.T + side * np.eye(side))
    lines = graph_lines(truth, edges_with_closures(8, [(0, 6), (2, 7)]), fmt=fmt,
                        info=lambda e: infos[e])
    g = read_pose_graph_file(write(tmp_path / "g.txt", lines))
    assert (g.dim, g.format, g.n_poses, g.n_edges) == (dim, fmt, 8, 9)
    np.testing.assert_array_equal(g.information, np.array(infos))
    assert g.has_vertex.all()
    T = params_to_matrix(g.vertices, g.rotation)
    for k, p in enumerate(truth):
        np.testing.assert_allclose(T[k], p.matrix(), atol=COMPOSE_TOL)


def test_toro_2d_information_order_and_g2o_pattern(tmp_path):
    # TORO order: ixx ixy iyy ith ixt iyt
    g = read_pose_graph_file(_file(tmp_path, "EDGE2 0 1 1 0 0 10 1 20 30 2 3\n", "t.graph"))
    np.testing.assert_array_equal(g.information[0], [[10, 1, 2], [1, 20, 3], [2, 3, 30]])
    # "a 0 0 b 0 c" (gtsam's w20000.txt) is a diagonal in g2o's order
    g = read_pose_graph_file(_file(tmp_path, "EDGE2 0 1 1 0 0 3 0 0 4 0 5\n", "t.graph"))
    np.testing.assert_array_equal(g.information[0], np.diag([3.0, 4.0, 5.0]))


def test_toro_3d_rotation_is_rz_ry_rx(tmp_path):
    g = read_pose_graph_file(_file(tmp_path, "EDGE3 0 1 1 2 3 0.1 0.2 0.3 " +
                                   " ".join(["1"] + ["0"] * 5 + ["1"] + ["0"] * 4 + ["1"] +
                                            ["0"] * 3 + ["1", "0", "0", "1", "0", "1"]) + "\n",
                                   "t.graph"))
    R = params_to_matrix(g.measurements, "rpy")[0, :3, :3]
    np.testing.assert_allclose(R, gtsam.Rot3.Ypr(0.3, 0.2, 0.1).matrix(), atol=1e-12)
    np.testing.assert_allclose(R, rpy_to_matrix(np.array([0.1, 0.2, 0.3])), atol=1e-15)


@pytest.mark.parametrize("dim", [2, 3])
def test_edge_only_file_is_initialised_along_the_chain(tmp_path, dim):
    truth = square_walk(12, dim)
    lines = graph_lines(truth, edges_with_closures(12, [(0, 11)]), vertices=False)
    g = read_pose_graph_file(write(tmp_path / "e.g2o", lines))
    assert not g.has_vertex.any()
    T = params_to_matrix(g.vertices, g.rotation)
    for k, p in enumerate(truth):
        np.testing.assert_allclose(T[k], p.matrix(), atol=COMPOSE_TOL)


def test_backwards_edges_compose_the_inverse(tmp_path):
    truth = square_walk(10, 2)
    lines = graph_lines(truth, edges_with_closures(10, []), vertices=False, backwards={2, 5})
    g = read_pose_graph_file(write(tmp_path / "b.g2o", lines))
    assert tuple(g.edges[2]) == (3, 2)
    np.testing.assert_allclose(params_to_matrix(g.vertices, "angle")[-1], truth[-1].matrix(),
                               atol=COMPOSE_TOL)


def test_comments_blank_lines_bom_denormals_fix_equiv(tmp_path):
    text = ("\ufeff# a comment\n\nVERTEX2 0 0 0 0\n   \nVERTEX2 1 1 5e-324 0\n"
            "EDGE2 0 1 1 0 0 1 0 1 1 0 0\n# EQUIV below\nEQUIV 0 1\nFIX 0\n")
    g = read_pose_graph_file(_file(tmp_path, text, "c.graph"))
    assert g.vertices[1, 1] == 5e-324
    assert g.fixed.tolist() == [0] and g.equiv.tolist() == [[0, 1]]


def test_connected_graph_that_is_not_a_chain(tmp_path):
    # pose 3 is first joined by a loop edge to pose 5 (ais2klinik's pose 7290)
    truth = square_walk(7, 2)
    edges = [(0, 1), (1, 2), (2, 4), (4, 5), (3, 5), (5, 6), (0, 6)]
    g = read_pose_graph_file(write(tmp_path / "n.g2o", graph_lines(truth, edges,
                                                                   vertices=False)))
    T = params_to_matrix(g.vertices, "angle")
    np.testing.assert_allclose(T[3], truth[3].matrix(), atol=COMPOSE_TOL)


def test_ids_with_huge_gaps_and_exact_big_ids(tmp_path):
    big = 2**53 + 1  # not representable as a float
    ids = [0, 5, 2**40, big]
    lines = graph_lines(square_walk(4, 2), edges_with_closures(4, []), ids=ids)
    t0 = time.perf_counter()
    g = read_pose_graph_file(write(tmp_path / "gap.g2o", lines))
    assert time.perf_counter() - t0 < GAP_READ_S
    assert g.ids.tolist() == ids


def test_disconnected_graph_names_its_components(tmp_path):
    text = "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 5 6 1 0 0 1 0 0 1 0 1\n"
    with pytest.raises(InputError, match=r"2 components: ids 0\.\.1 \(2 poses\); ids 5\.\.6"):
        read_pose_graph_file(_file(tmp_path, text))


def test_truncated_keeps_the_first_poses(tmp_path):
    lines = graph_lines(square_walk(10, 2), edges_with_closures(10, [(0, 9), (1, 4)]))
    g = truncated(read_pose_graph_file(write(tmp_path / "t.g2o", lines)), 5)
    assert g.ids.tolist() == [0, 1, 2, 3, 4] and g.n_edges == 5


BAD_LINES = [
    ("VERTEX_SE2 0 0 0 0\nBOGUS 1 2\n", 2, "unknown tag"),
    ("EDGE_SE2 0 1 1 0 0 100 0 0 100 0\n", 1, "needs 12 tokens"),
    ("EDGE_SE2 0 1 1 x 0 100 0 0 100 0 1000\n", 1, "not a number"),
    ("EDGE_SE2 0 1 1 nan 0 100 0 0 100 0 1000\n", 1, "not finite"),
    ("EDGE_SE2 0 1 1 inf 0 100 0 0 100 0 1000\n", 1, "not finite"),
    ("EDGE_SE2 -1 1 1 0 0 100 0 0 100 0 1000\n", 1, "negative"),
    (f"EDGE_SE2 0 {2**62 + 1} 1 0 0 100 0 0 100 0 1000\n", 1, "larger than 2**62"),
    ("EDGE_SE2 0 1e3 1 0 0 100 0 0 100 0 1000\n", 1, "not an integer (decimal digits only)"),
    ("EDGE_SE2 0 3.0 1 0 0 100 0 0 100 0 1000\n", 1, "not an integer (decimal digits only)"),
    # information that is not positive definite is replaced by default
    # (tests/graphslam/sources/test_posegraph_information_fix.py); one without information is
    # refused
    ("EDGE_SE2 0 1 1 0 0 0 0 0 0 0 0\n", 1, "no positive eigenvalue"),
    ("EDGE_SE2 0 " + "7" * 5000 + " 1 0 0 100 0 0 100 0 1000\n", 1, "larger than 2**62"),
    # information is checked for all edges at once: the bad one among good ones is named
    ("EDGE_SE2 0 1 1 0 0 100 0 0 100 0 1000\n# c\nEDGE_SE2 1 2 1 0 0 -100 0 0 -100 0 -1\n"
     "EDGE_SE2 2 3 1 0 0 -100 0 0 100 0 1000\n", 3, "no positive eigenvalue"),
    ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 0 1 0 0\n", 2, "declared twice"),
    ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 0 0\nEDGE_SE2 0 2 1 0 0 1 0 0 1 0 1\n", 3,
     "no vertex line"),
    ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 0 0\n" + EDGE_2D + "\nFIX 7\n", 4, "no vertex line"),
    (EDGE_2D + "\nVERTEX2 1 0 0 0\n", 2, "2-D g2o file"),
    ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 0\n", 1, "quaternion of norm 0 cannot be normalised"),
    # issue 34: a norm that underflows (1e-300 squared) ended in a ZeroDivisionError
    ("EDGE_SE3:QUAT 0 1 1 0 0 1e-300 0 0 0 100 0 0 0 0 0 100 0 0 0 0 100 0 0 0 1000 0 0 "
     "1000 0 1000\n", 1, "quaternion of norm 1e-300 cannot be normalised"),
    # issue 34: an EQUIV of a pose nothing else names was copied into graph.graph
    ("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 100 0 100 1000 0 0\nEQUIV 0 7\n", 4,
     "EQUIV names pose 7, which no vertex or edge has"),
    # issue 34: a 1e300 m step ended in an indeterminate system (iSAM2) or a silent 1e300
    ("EDGE_SE2 0 1 1e300 0 0 100 0 0 100 0 1000\n", 1, "translation beyond 1e+09 m"),
    ("VERTEX_SE2 0 0 -2e9 0\nEDGE_SE2 0 1 1 0 0 100 0 0 100 0 1000\n", 1,
     "translation beyond 1e+09 m"),
    (EDGE_2D + "\nEQUIV 0\n", 2, "EQUIV line needs 2"),
    (EDGE_2D + "\nFIX\n", 2, "FIX line needs"),
]


@pytest.mark.parametrize("text,line,fragment", BAD_LINES)
def test_bad_line_is_one_line_with_file_and_line(tmp_path, capsys, text, line, fragment):
    path = _file(tmp_path, text)
    with pytest.raises(InputError, match=re.escape(fragment)) as err:
        read_pose_graph_file(path)
    assert err.value.line == line
    rc = main(["run", "--dataset", str(path), "--rerun", "off", "--quiet",
               "--out", str(tmp_path / "out")])
    lines = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(lines) == 1
    assert f"g.g2o:{line}:" in lines[0] and fragment in lines[0]


# the frame-by-frame 2-D reader (filters on pose-graph files) gets the same id checks
@pytest.mark.parametrize("text,line,fragment", [
    ("EDGE2 0 1 1 0 0 1 0 1 1 0 0\nEDGE2 1 -2 1 0 0 1 0 1 1 0 0\n", 2, "negative"),
    (f"EDGE2 0 {2**56} 1 0 0 1 0 1 1 0 0\n", 1, "symbol key"),
    ("\ufeffEDGE2 0 1 1 0 0 1 0 1 1 0 0\nEDGE2 1 3 1 0 0 1 0 1 1 0 0\n", 2, "pose 2 is missing"),
    ("VERTEX2 0 0 0 0\nVERTEX2 1 0 0 0\nEDGE2 0 1 1 0 0 1 0 1 1 0 0\n"
     "EDGE2 1 2 1 0 0 1 0 1 1 0 0\n", 4, "no vertex line"),
])
def test_frame_reader_id_checks(tmp_path, text, line, fragment):
    from graphslam.sources.planar.posegraph import read_pose_graph

    with pytest.raises(InputError, match=re.escape(fragment)) as err:
        read_pose_graph(_file(tmp_path, text, "f.graph"), fmt="toro")
    assert err.value.line == line


def test_frame_reader_gap_of_2_40_is_refused_at_once(tmp_path):
    from graphslam.sources.planar.posegraph import read_pose_graph

    text = f"EDGE2 0 1 1 0 0 1 0 1 1 0 0\nEDGE2 1 {2**40} 1 0 0 1 0 1 1 0 0\n"
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="gap"):
        read_pose_graph(_file(tmp_path, text, "f.graph"), fmt="toro")
    assert time.perf_counter() - t0 < GAP_READ_S


def test_a_filter_on_a_3d_graph_is_refused_in_one_line(tmp_path, capsys):
    path = write(tmp_path / "g3.g2o", graph_lines(square_walk(5, 3), edges_with_closures(5, [])))
    assert main(["run", "--dataset", str(path), "--backend", "ekf", "--rerun", "off",
                 "--out", str(tmp_path / "o")]) == 2
    assert "3-D pose graph" in capsys.readouterr().err


def test_toro_square_root_information(tmp_path):
    # iSAM writes the upper triangle R of the information R^T R under TORO tags
    R = np.array([[10.0, 1, 2], [0, 20, 3], [0, 0, 30]])
    text = "EDGE2 0 1 1 0 0 10 1 20 30 2 3\n"  # TORO order: xx xy yy tt xt yt
    g = read_pose_graph_file(_file(tmp_path, text, "s.graph"), toro_noise="sqrt_information")
    np.testing.assert_array_equal(g.information[0], R.T @ R)
    assert g.noise == "sqrt_information"
