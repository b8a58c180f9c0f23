"""The pose-graph solve's fast paths give what the slow ones gave, bit for bit:
the trajectory read from gtsam in one call (``params_from``), and the iSAM2
schedule built on plain lists."""

from __future__ import annotations

import gtsam
import numpy as np

from graphslam.backends.posegraph import factors as fx
from graphslam.backends.posegraph.schedule import schedule
from slamcore.posegraph import PoseGraph


def _rotations(n: int, seed: int = 0) -> list:
    """Rotations of every kind: random, tiny, large angle (trace <= 0), near pi, identity."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        if k % 3 == 0:
            out.append(gtsam.Rot3.Quaternion(*rng.normal(size=4)))
        elif k % 3 == 1:
            out.append(gtsam.Rot3.Expmap(rng.normal(size=3) * (3.0 if k % 2 else 1e-3)))
        else:
            out.append(gtsam.Rot3.Ypr(*rng.uniform(-np.pi, np.pi, 3)))
    for axis in range(3):
        v = np.zeros(3)
        v[axis] = np.pi - 1e-9
        out += [gtsam.Rot3.Expmap(v), gtsam.Rot3()]
    return out


def test_quaternions_are_gtsams_bit_for_bit():
    rots = _rotations(3000)
    R = np.array([r.matrix() for r in rots])
    ours = fx.quaternions(R)
    theirs = np.array([[q.x(), q.y(), q.z(), q.w()] for q in (r.toQuaternion() for r in rots)])
    assert (R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2] <= 0).sum() > 500  # both of Eigen's branches
    assert np.array_equal(ours, theirs)


def _graph(dim: int, n: int) -> PoseGraph:
    ids = np.arange(n, dtype=np.int64) * 3 + 7
    P = 3 if dim == 2 else 7
    edges = np.column_stack([ids[:-1], ids[1:]])
    return PoseGraph(name="g", dim=dim, format="g2o", rotation="angle" if dim == 2 else "quat",
                     ids=ids, vertices=np.zeros((n, P)), has_vertex=np.ones(n, dtype=bool),
                     edges=edges, measurements=np.zeros((n - 1, P)),
                     information=np.repeat(np.eye(P - (dim == 3))[None], n - 1, axis=0),
                     edge_lines=np.arange(n - 1))


def test_trajectory_read_in_one_call_equals_pose_by_pose():
    rng = np.random.default_rng(1)
    for dim in (2, 3):
        graph = _graph(dim, 300)
        values = gtsam.Values()
        for k, rot in zip(graph.ids.tolist(), _rotations(300, seed=dim)):
            t = rng.normal(size=3) * 10
            values.insert(k, gtsam.Pose2(t[0], t[1], rng.uniform(-4, 4)) if dim == 2
                          else gtsam.Pose3(rot, t))
        get = values.atPose2 if dim == 2 else values.atPose3
        slow = np.array([fx.params_of(get(k), graph.rotation) for k in graph.ids.tolist()])
        assert np.array_equal(fx.params_from(graph, values), slow)
        values.insert(10**9, gtsam.Pose2() if dim == 2 else gtsam.Pose3())  # not the graph's
        assert np.array_equal(fx.params_from(graph, values), slow)


def test_schedule_adds_every_pose_and_edge_once_from_added_poses():
    """A pose joined only to a later one (ais2klinik's 7290) waits for it; the rest
    take the fast path. Every pose enters once, from a pose already in, and every
    edge once its two ends are in."""
    rng = np.random.default_rng(2)
    for _ in range(200):
        n = int(rng.integers(4, 40))
        perm = np.concatenate([[0], rng.permutation(np.arange(1, n))])
        tree = [(int(perm[rng.integers(0, k)]), int(perm[k])) for k in range(1, n)]
        extra = [tuple(map(int, rng.integers(0, n, 2))) for _ in range(int(rng.integers(0, n)))]
        rows = np.array([e for e in tree + extra if e[0] != e[1]])
        added, used = {0}, []
        steps = schedule(n, rows)
        assert steps[0].inits == [(0, -1, -1)]
        for step in steps[1:]:
            for row, e, src in step.inits:
                assert src in added and row not in added and row in rows[e] and src in rows[e]
                added.add(row)
            for e in step.edges:
                assert set(rows[e].tolist()) <= added
            used += step.edges
        assert added == set(range(n)) and sorted(used) == list(range(len(rows)))
