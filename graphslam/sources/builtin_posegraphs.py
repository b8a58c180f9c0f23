"""The built-in pose graphs (``w10000``, ``city10000``) as pose-graph files, so a built-in
name works wherever a path does: ``run --backend batch``, ``convert``.

``w10000`` is gtsam's ``w10000.graph`` (TORO). ``city10000`` is gtsam's
``T1_city10000_04.txt``, in its own ``EDGE2`` format with several hypotheses
per edge, read by :func:`graphslam.sources.planar.posegraph.read_city10000`
(the first hypothesis, the right one, and the C++ example's noise); its edges
become a 2-D g2o graph here, and its ground truth (``ISAM2_GT_city10000.txt``)
goes with it.
"""

from __future__ import annotations

import numpy as np

from slamcore import posegraph as pg

__all__ = ["BUILTIN_POSE_GRAPHS", "builtin_pose_graph", "is_builtin_pose_graph"]

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
    from graphslam.sources.planar.posegraph import read_city10000

    ds = read_city10000()
    return _graph_of_frames("city10000", ds.frames, ds.source_path), _truth_of_frames(ds.frames)


def _graph_of_frames(name: str, frames, source_path) -> pg.PoseGraph:
    """A 2-D g2o pose graph of planar frames' odometry and loop closures (information =
    inverse covariance); poses start from the odometry chain."""
    from graphslam.sources.posegraph_files import check_connected, with_chain_start

    rel = [f.odometry for f in frames if f.odometry is not None]
    rel += [c for f in frames for c in f.loop_closures]
    ids = np.array([f.pose_id for f in frames], dtype=np.int64)
    graph = pg.PoseGraph(
        name=name, format="g2o", dim=2, rotation="angle", ids=ids,
        vertices=np.zeros((len(ids), 3)), has_vertex=np.zeros(len(ids), dtype=bool),
        edges=np.array([(r.from_id, r.to_id) for r in rel], dtype=np.int64).reshape(-1, 2),
        measurements=np.array([r.delta for r in rel], dtype=np.float64).reshape(-1, 3),
        information=np.linalg.inv(np.array([r.covariance for r in rel])).reshape(-1, 3, 3),
        edge_lines=np.zeros(len(rel), dtype=np.int64),
        source_path=None if source_path is None else str(source_path))
    check_connected(graph, source_path)
    return with_chain_start(graph)


def _truth_of_frames(frames) -> tuple[np.ndarray, np.ndarray] | None:
    known = [f for f in frames if f.wTb_true is not None]
    if not known:
        return None
    wTc = np.tile(np.eye(4), (len(known), 1, 1))
    for T, f in zip(wTc, known):
        x, y, th = f.wTb_true
        T[:2, :2] = [[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]
        T[:2, 3] = x, y
    return np.array([f.pose_id for f in known], dtype=np.int64), wTc
