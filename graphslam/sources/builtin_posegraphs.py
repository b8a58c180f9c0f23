"""The built-in pose graphs (``w10000``, ``city10000``) as pose-graph files, so a built-in
name works wherever a path does: ``run --backend batch``, ``convert``; and the reader of
City10000's own layout.

``w10000`` is gtsam's ``w10000.graph`` (TORO). ``city10000`` is gtsam's
``T1_city10000_04.txt``, in its own ``EDGE2`` layout with several hypotheses
per edge and no noise numbers (not TORO's, whose reader would refuse it), read by
:func:`read_city10000_graph` (the first hypothesis, the right one, and the C++
example's noise) into a 2-D g2o graph; its ground truth (``ISAM2_GT_city10000.txt``)
goes with it. The frame streams of both are
:mod:`graphslam.sources.planar.posegraph`'s conversion of these graphs.
"""

from __future__ import annotations

import numpy as np

from graphslam.sources.posegraph_bulk import ids_in_bulk, numbers_in_bulk, rows_by_tag
from graphslam.sources.tokens import MAX_KEY_ID, iter_lines, parse_id, parse_numbers
from slamcore import posegraph as pg
from slamcore.errors import InputError, quote

__all__ = [
    "BUILTIN_POSE_GRAPHS",
    "CITY10000_SIGMAS",
    "builtin_pose_graph",
    "is_builtin_pose_graph",
    "read_city10000_graph",
]

#: Built-in dataset names that are pose graphs -> what they are.
BUILTIN_POSE_GRAPHS = {
    "w10000": "gtsam's w10000.graph (TORO, 10 000 poses, no truth)",
    "city10000": "gtsam's City10000 (10 000 poses, first hypotheses, with ground truth)",
}


def is_builtin_pose_graph(spec) -> bool:
    """Whether ``spec`` names a built-in pose graph: its name, and no file or folder of
    that name where it is looked for (a user's own ``w10000`` file wins)."""
    from pathlib import Path

    return str(spec) in BUILTIN_POSE_GRAPHS and not Path(spec).exists()


def builtin_pose_graph(name: str) -> tuple[pg.PoseGraph, tuple[np.ndarray, np.ndarray] | None]:
    """``(graph, truth)`` of a built-in pose graph; ``truth`` is ``(ids (M,), wTc (M, 4, 4))``
    or None."""
    import gtsam

    from graphslam.sources.posegraph_files import read_pose_graph_file

    if name == "w10000":
        return read_pose_graph_file(gtsam.findExampleDataFile("w10000.graph")), None
    if name != "city10000":
        raise KeyError(name)
    graph, truth = read_city10000_graph()
    return graph, (graph.ids, _truth_matrices(truth))


#: City10000 pose noise sigmas [x_m, y_m, theta_rad], from gtsam's C++ examples
#: (examples/City10000.h and Hybrid_City10000.cpp: ``kPoseNoiseModel`` =
#: Sigmas(1/30, 1/30, 1/100)), used there for odometry and loop closures alike.
CITY10000_SIGMAS = np.array([1.0 / 30.0, 1.0 / 30.0, 1.0 / 100.0])


def read_city10000_graph(path=None, ground_truth_path=None) -> tuple[pg.PoseGraph, np.ndarray]:
    """gtsam's City10000 (name "city10000") and its ground truth, ``(graph, truth)``
    with ``truth`` (N, 3) ``[x, y, theta]`` of each pose in id order.

    Line format: ``EDGE2 keyS <unused> keyT ambiguous n x1 y1 th1 [x2 y2 th2 ...]``
    (tokens as parsed by gtsam's ``HybridCity10000.py``); only the first
    hypothesis, the correct one, is kept. Every edge gets the covariance
    ``diag(CITY10000_SIGMAS**2)`` with sigmas (1/30, 1/30, 1/100) from gtsam's C++
    City10000 examples (``kPoseNoiseModel``; note: one version of the Python
    example ``HybridCity10000.py`` uses 1/20 for x, y instead). An edge from a
    pose to itself is left out and counted, as the pose-graph reader does.

    The ground-truth file has one ``x y theta`` line per pose; its line count must
    equal the number of poses.
    """
    import gtsam

    from graphslam.sources.posegraph_files import check_connected, with_chain_start

    if path is None:
        path = gtsam.findExampleDataFile("T1_city10000_04.txt")
    if ground_truth_path is None:
        ground_truth_path = gtsam.findExampleDataFile("ISAM2_GT_city10000.txt")
    edges, measurements, lines = _city10000_edges(path)
    truth = []
    for line_no, tok in iter_lines(ground_truth_path):
        if len(tok) != 3:
            raise InputError(
                f"ground-truth line needs 3 numbers (x y theta), got {len(tok)}", ground_truth_path, line_no
            )
        truth.append(parse_numbers(tok, ground_truth_path, line_no))
    ids = np.unique(edges)
    n_poses = int(ids[-1] - ids[0] + 1) if len(ids) else 0
    if len(truth) != n_poses:
        raise InputError(f"ground truth has {len(truth)} poses, the graph has {n_poses}", ground_truth_path)
    keep = edges[:, 0] != edges[:, 1]
    if not keep.any():
        raise InputError("no pose-graph edges in the file", path)
    information = np.linalg.inv(np.diag(CITY10000_SIGMAS**2))
    ids = np.unique(edges[keep])
    graph = pg.PoseGraph(
        name="city10000",
        format="g2o",
        dim=2,
        rotation="angle",
        ids=ids,
        vertices=np.zeros((len(ids), 3)),
        has_vertex=np.zeros(len(ids), dtype=bool),
        edges=edges[keep],
        measurements=measurements[keep],
        information=np.repeat(information[None], int(keep.sum()), axis=0),
        edge_lines=lines[keep],
        source_path=str(path),
        self_edge_lines=lines[~keep],
    )
    check_connected(graph, path)
    return with_chain_start(graph), np.array(truth, dtype=np.float64).reshape(-1, 3)


def _city10000_edges(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(edges (M, 2), first hypotheses (M, 3), lines (M,))`` of a City10000 file: in
    bulk when every line is well formed, else line by line, which names the line."""
    bulk = _city10000_in_bulk(path)
    if bulk is not None:
        return bulk
    edges, measurements, lines = [], [], []
    for line_no, tok in iter_lines(path):
        if tok[0] != "EDGE2":
            raise InputError(f"unknown tag {quote(tok[0])}", path, line_no)
        if len(tok) < 9:
            raise InputError(f"EDGE2 line needs at least 9 tokens, got {len(tok)}", path, line_no)
        a = parse_id(tok[1], path, line_no, "id", limit=MAX_KEY_ID)
        b = parse_id(tok[3], path, line_no, "id", limit=MAX_KEY_ID)
        parse_id(tok[4], path, line_no, "ambiguity flag", limit=MAX_KEY_ID)
        n = parse_id(tok[5], path, line_no, "hypothesis count", limit=MAX_KEY_ID)
        if n < 1 or len(tok) != 6 + 3 * n:
            raise InputError(
                f"EDGE2 line with {n} hypotheses needs {6 + 3 * n} tokens, got {len(tok)}", path, line_no
            )
        edges.append((a, b))
        measurements.append(parse_numbers(tok[6:], path, line_no)[:3])
        lines.append(line_no)
    return (
        np.array(edges, dtype=np.int64).reshape(-1, 2),
        np.array(measurements, dtype=np.float64).reshape(-1, 3),
        np.array(lines, dtype=np.int64),
    )


def _city10000_in_bulk(path) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """:func:`_city10000_edges` of a file whose lines are all well formed, else None
    (the same arrays: ``tests/graphslam/cli/test_command_costs.py``)."""
    got = rows_by_tag(path)
    if got is None or set(got[0]) != {"EDGE2"}:
        return None
    rows, lines = got[0]["EDGE2"], got[1]["EDGE2"]
    if min(map(len, rows)) < 9:
        return None
    ids = ids_in_bulk([t[k] for t in rows for k in (1, 3, 4, 5)], MAX_KEY_ID)
    if ids is None:
        return None
    n = np.array(ids[3::4])
    if (n < 1).any() or any(len(t) != 6 + 3 * k for t, k in zip(rows, n.tolist(), strict=True)):
        return None
    first = numbers_in_bulk([t[6:9] for t in rows], 3)
    others = [x for t in rows for x in t[9:]]  # later hypotheses: checked, not kept
    if first is None or numbers_in_bulk([others], len(others)) is None:
        return None
    edges = np.array(ids, dtype=np.int64).reshape(-1, 4)[:, :2]
    return edges, first, np.array(lines, dtype=np.int64)


def _truth_matrices(truth: np.ndarray) -> np.ndarray:
    """(N, 4, 4) ``wTc`` of (N, 3) planar poses ``[x, y, theta]``."""
    wTc = np.tile(np.eye(4), (len(truth), 1, 1))
    for T, (x, y, th) in zip(wTc, truth.tolist(), strict=True):
        T[:2, :2] = [[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]
        T[:2, 3] = x, y
    return wTc
