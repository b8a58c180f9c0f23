"""Pose-graph files built in the tests: chains with closures, 2-D and 3-D, from a
known truth, written as g2o or TORO text (helpers, not tests)."""

from __future__ import annotations

import math
from pathlib import Path

import gtsam
import numpy as np

#: Information of a plain edge: 0.1 m and about 0.03 rad standard deviations.
INFO_2D = np.diag([100.0, 100.0, 1000.0])
INFO_3D = np.diag([100.0, 100.0, 100.0, 1000.0, 1000.0, 1000.0])


def square_walk(n: int, dim: int) -> list:
    """Truth: a walk turning a quarter every 5 poses (3-D: also climbing, rolling)."""
    poses = [gtsam.Pose2() if dim == 2 else gtsam.Pose3()]
    for k in range(1, n):
        turn = math.pi / 2 if k % 5 == 0 else 0.0
        step = (gtsam.Pose2(1.0, 0.0, turn) if dim == 2 else
                gtsam.Pose3(gtsam.Rot3.Ypr(turn, 0.02, 0.03), gtsam.Point3(1.0, 0.0, 0.1)))
        poses.append(poses[-1].compose(step))
    return poses


def torus(rings: int, per_ring: int, radius_big: float = 5.0, radius_small: float = 1.5) -> list:
    """Truth on a torus: ``rings`` small circles of ``per_ring`` poses, heading along them."""
    poses = []
    for i in range(rings):
        u = 2 * math.pi * i / rings
        for j in range(per_ring):
            v = 2 * math.pi * j / per_ring
            centre = np.array([(radius_big + radius_small * math.cos(v)) * math.cos(u),
                               (radius_big + radius_small * math.cos(v)) * math.sin(u),
                               radius_small * math.sin(v)])
            rot = gtsam.Rot3.Ypr(u, -v, 0.0)
            poses.append(gtsam.Pose3(rot, gtsam.Point3(*centre)))
    return poses


def edges_with_closures(n: int, closures: list[tuple[int, int]]) -> list[tuple[int, int]]:
    return [(k - 1, k) for k in range(1, n)] + list(closures)


def perturb(z, sigma: float, rng: np.random.Generator, dim: int):
    if sigma == 0:
        return z
    if dim == 2:
        return z.compose(gtsam.Pose2(*rng.normal(0, sigma, 3)))
    return z.compose(gtsam.Pose3.Expmap(rng.normal(0, sigma, 6)))


def pose_numbers(p, dim: int, fmt: str) -> list[float]:
    if dim == 2:
        return [p.x(), p.y(), p.theta()]
    t = list(np.asarray(p.translation()))
    if fmt == "toro":
        return t + list(np.asarray(p.rotation().rpy()))
    q = p.rotation().toQuaternion()
    return t + [q.x(), q.y(), q.z(), q.w()]


def info_numbers(info: np.ndarray, dim: int, fmt: str) -> list[float]:
    if (dim, fmt) == (2, "toro"):
        order = ((0, 0), (0, 1), (1, 1), (2, 2), (0, 2), (1, 2))
    else:
        side = info.shape[0]
        order = tuple((r, c) for r in range(side) for c in range(r, side))
    return [info[r, c] for r, c in order]


TAGS = {(2, "g2o"): ("VERTEX_SE2", "EDGE_SE2"), (3, "g2o"): ("VERTEX_SE3:QUAT", "EDGE_SE3:QUAT"),
        (2, "toro"): ("VERTEX2", "EDGE2"), (3, "toro"): ("VERTEX3", "EDGE3")}


def graph_lines(truth: list, edges: list[tuple[int, int]], *, fmt: str = "g2o",
                sigma: float = 0.0, seed: int = 0, info=None, vertices: bool = True,
                ids=None, backwards=()) -> list[str]:
    """Lines of a pose-graph file: vertices at the truth, edge measurements from
    the truth perturbed by ``sigma``; edges listed in ``backwards`` are written
    from ``j`` to ``i`` with the inverse measurement and its transformed
    information (same cost). ``ids`` renames pose ``k`` to ``ids[k]``."""
    dim = 2 if isinstance(truth[0], gtsam.Pose2) else 3
    rng = np.random.default_rng(seed)
    ids = list(range(len(truth))) if ids is None else list(ids)
    vtag, etag = TAGS[(dim, fmt)]
    lines = [f"{vtag} {ids[k]} " + " ".join(_num(v) for v in pose_numbers(p, dim, fmt))
             for k, p in enumerate(truth)] if vertices else []
    for e, (a, b) in enumerate(edges):
        I = (INFO_2D if dim == 2 else INFO_3D) if info is None else info(e)
        z = perturb(truth[a].between(truth[b]), sigma, rng, dim)
        if e in backwards:
            Ad = z.AdjointMap()  # error of the flipped factor is -Ad(z) e: same cost
            swap = np.eye(6) if dim == 2 else np.block([[np.zeros((3, 3)), np.eye(3)],
                                                       [np.eye(3), np.zeros((3, 3))]])
            Ad = Ad if dim == 2 else swap @ Ad @ swap  # gtsam [rot, trans] -> file order
            Ad_inv = np.linalg.inv(Ad)
            I = Ad_inv.T @ I @ Ad_inv
            I = 0.5 * (I + I.T)
            a, b, z = b, a, z.inverse()
        lines.append(f"{etag} {ids[a]} {ids[b]} " + " ".join(
            _num(v) for v in pose_numbers(z, dim, fmt) + info_numbers(I, dim, fmt)))
    return lines


def write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _num(v) -> str:
    return repr(float(v))


#: Odometry and closure noise of :func:`manhattan_walk`: 5 cm, and 0.2 rad of heading
#: (the large rotation noise under which LAGO's rotations mislead batch LM).
MANHATTAN_SIGMA = np.array([0.05, 0.05, 0.2])


def manhattan_walk(folder: Path, n: int = 300, sigma=MANHATTAN_SIGMA, seed: int = 0) -> Path:
    """A random walk on a unit grid (a quarter turn 2 steps in 5), a closure
    wherever a cell is revisited more than 5 poses later; measurements perturbed
    by ``sigma``, which the information states; written as g2o into ``folder``."""
    rng = np.random.default_rng(seed)
    poses, pose = [gtsam.Pose2()], gtsam.Pose2()
    for _ in range(1, n):
        pose = pose.compose(gtsam.Pose2(1.0, 0.0, rng.choice([0, 0, 0, math.pi / 2,
                                                              -math.pi / 2])))
        pose = gtsam.Pose2(round(pose.x()), round(pose.y()), pose.theta())
        poses.append(pose)
    cells, edges = {}, [(k - 1, k) for k in range(1, n)]
    for k, q in enumerate(poses):
        key = (round(q.x()), round(q.y()))
        edges += [(j, k) for j in cells.get(key, []) if k - j > 5]
        cells.setdefault(key, []).append(k)
    noise = np.random.default_rng(seed + 1)
    info = 1.0 / np.asarray(sigma) ** 2
    lines = []
    for a, b in edges:
        z = poses[a].between(poses[b]).compose(gtsam.Pose2(*(noise.normal(0, 1, 3) * sigma)))
        lines.append(f"EDGE_SE2 {a} {b} {z.x()} {z.y()} {z.theta()} "
                     f"{info[0]} 0 0 {info[1]} 0 {info[2]}")
    return write(folder / f"manhattan_{n}_{seed}.g2o", lines)
