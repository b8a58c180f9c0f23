"""PoseGraph records <-> gtsam: keys, poses, between factors, gauge priors.

Keys are the pose ids themselves (ids are checked to be below 2**62 on
reading). Poses and noise are built exactly as ``gtsam.readG2o`` / ``load3D``
build them (``Rot3.Quaternion(w, x, y, z)`` of the normalised quaternion,
``Rot3.Ypr(yaw, pitch, roll)``,
``Gaussian.Information`` of the file's matrix with the translation and rotation
blocks swapped into gtsam's ``[rotation, translation]`` tangent order), so the
cost of an estimate is the one gtsam gives the same file.
"""

from __future__ import annotations

from functools import lru_cache

import gtsam
import numpy as np

from slamcore.posegraph import PoseGraph

#: Swaps ``[translation, rotation]`` (file) and ``[rotation, translation]`` (gtsam Pose3).
SWAP6 = np.block([[np.zeros((3, 3)), np.eye(3)], [np.eye(3), np.zeros((3, 3))]])


def pose(params: np.ndarray, rotation: str):
    """One row of pose parameters -> ``gtsam.Pose2`` / ``gtsam.Pose3``."""
    p = [float(v) for v in params]
    if rotation == "angle":
        return gtsam.Pose2(p[0], p[1], p[2])
    if rotation == "quat":  # normalised first, as gtsam.readG2o does (files round to 6 digits)
        n = float(np.linalg.norm(p[3:7]))
        rot = gtsam.Rot3.Quaternion(p[6] / n, p[3] / n, p[4] / n, p[5] / n)
    else:
        rot = gtsam.Rot3.Ypr(p[5], p[4], p[3])
    return gtsam.Pose3(rot, gtsam.Point3(p[0], p[1], p[2]))


def params_of(value, rotation: str) -> np.ndarray:
    """``gtsam.Pose2`` / ``Pose3`` -> one row of pose parameters."""
    if rotation == "angle":
        return np.array([value.x(), value.y(), value.theta()])
    t = np.asarray(value.translation(), dtype=np.float64)
    if rotation == "quat":
        q = value.rotation().toQuaternion()
        quat = np.array([q.x(), q.y(), q.z(), q.w()])
        return np.concatenate([t, -quat if quat[3] < 0 else quat])
    return np.concatenate([t, np.asarray(value.rotation().rpy(), dtype=np.float64)])


def values_of(graph: PoseGraph, params: np.ndarray) -> gtsam.Values:
    values = gtsam.Values()
    for k, row in zip(graph.ids.tolist(), params, strict=True):
        values.insert(k, pose(row, graph.rotation))
    return values


def params_from(graph: PoseGraph, values: gtsam.Values) -> np.ndarray:
    """(N, P) parameters of every pose of ``graph`` read from ``values``."""
    ids = graph.ids.tolist()
    if graph.dim == 2 and values.keys() == ids:  # the usual case: x, y, theta() in one call
        return gtsam.utilities.extractPose2(values)
    if graph.rotation == "quat" and len(ids) >= VECTOR_QUAT_MIN and values.keys() == ids:
        rt = gtsam.utilities.extractPose3(values)  # R row-major, then t
        quat = quaternions(rt[:, :9].reshape(-1, 3, 3))
        quat[quat[:, 3] < 0] *= -1.0
        return np.concatenate([rt[:, 9:], quat], axis=1)
    get = values.atPose2 if graph.dim == 2 else values.atPose3
    return np.array([params_of(get(k), graph.rotation) for k in ids])


#: Poses from which :func:`quaternions` (75 us of numpy fixed cost) beats reading each
#: pose's (4 us a pose).
VECTOR_QUAT_MIN = 16


def quaternions(R: np.ndarray) -> np.ndarray:
    """(N, 4) ``x, y, z, w`` of rotation matrices (N, 3, 3), bit for bit as
    ``Rot3.toQuaternion`` (Eigen's ``Quaternion(Matrix3)``: the same branches, the
    same order of operations, the trace summed as ``m00 + (m11 + m22)``)."""
    q = np.empty((len(R), 4))
    trace = R[:, 0, 0] + (R[:, 1, 1] + R[:, 2, 2])
    pos = trace > 0
    t = np.sqrt(trace[pos] + 1.0)
    q[pos, 3] = 0.5 * t
    t = 0.5 / t
    Rp = R[pos]
    q[pos, 0] = (Rp[:, 2, 1] - Rp[:, 1, 2]) * t
    q[pos, 1] = (Rp[:, 0, 2] - Rp[:, 2, 0]) * t
    q[pos, 2] = (Rp[:, 1, 0] - Rp[:, 0, 1]) * t
    d = np.diagonal(R, axis1=1, axis2=2)  # Eigen: i = 1 if m11 > m00; i = 2 if m22 > m_ii
    first = np.where(d[:, 1] > d[:, 0], 1, 0)
    first = np.where(d[:, 2] > d[np.arange(len(R)), first], 2, first)
    for i in range(3):
        rows = np.flatnonzero(~pos & (first == i))
        j, k = (i + 1) % 3, (i + 2) % 3
        m = R[rows]
        t = np.sqrt(m[:, i, i] - m[:, j, j] - m[:, k, k] + 1.0)
        q[rows, i] = 0.5 * t
        t = 0.5 / t
        q[rows, 3] = (m[:, k, j] - m[:, j, k]) * t
        q[rows, j] = (m[:, j, i] + m[:, i, j]) * t
        q[rows, k] = (m[:, k, i] + m[:, i, k]) * t
    return q


@lru_cache(maxsize=4096)
def _information_model(info_bytes: bytes, side: int) -> gtsam.noiseModel.Base:
    # benchmark graphs repeat a handful of matrices thousands of times
    info = np.frombuffer(info_bytes, dtype=np.float64).reshape(side, side)
    if side == 6:
        info = SWAP6 @ info @ SWAP6
    return gtsam.noiseModel.Gaussian.Information(np.ascontiguousarray(info))


def noise_model(information: np.ndarray) -> gtsam.noiseModel.Base:
    info = np.ascontiguousarray(information, dtype=np.float64)
    return _information_model(info.tobytes(), info.shape[0])


def diagonal_model(information: np.ndarray) -> gtsam.noiseModel.Base:
    """Diagonal model from the diagonal of an information matrix (gtsam order)."""
    d = np.diag(information).astype(np.float64)
    if len(d) == 6:
        d = np.concatenate([d[3:], d[:3]])
    return gtsam.noiseModel.Diagonal.Precisions(d)


def between(graph: PoseGraph, e: int, noise=None):
    """Factor of edge ``e``; ``noise`` replaces the file's Gaussian (robust kernels)."""
    a, b = (int(k) for k in graph.edges[e])
    model = noise if noise is not None else noise_model(graph.information[e])
    z = pose(graph.measurements[e], graph.rotation)
    if graph.dim == 2:
        return gtsam.BetweenFactorPose2(a, b, z, model)
    return gtsam.BetweenFactorPose3(a, b, z, model)


def edge_factors(graph: PoseGraph) -> list:
    return [between(graph, e) for e in range(graph.n_edges)]


def edge_graph(graph: PoseGraph) -> gtsam.NonlinearFactorGraph:
    """Every edge of the file, in file order (the cost the benchmarks quote)."""
    out = gtsam.NonlinearFactorGraph()
    for f in edge_factors(graph):
        out.add(f)
    return out


def anchors(graph: PoseGraph) -> np.ndarray:
    """Ids held by the gauge prior: the ``FIX`` poses, else the first pose."""
    return graph.fixed if len(graph.fixed) else graph.ids[:1]


def prior(graph: PoseGraph, pose_id: int, value, sigma: float):
    """Gauge prior holding ``pose_id`` at ``value``."""
    dim = 3 if graph.dim == 2 else 6
    model = gtsam.noiseModel.Isotropic.Sigma(dim, sigma)
    if graph.dim == 2:
        return gtsam.PriorFactorPose2(int(pose_id), value, model)
    return gtsam.PriorFactorPose3(int(pose_id), value, model)


def cost(graph: PoseGraph, values: gtsam.Values, factors: gtsam.NonlinearFactorGraph | None = None) -> float:
    """``0.5 * sum ||whitened residual||^2`` over the file's edges."""
    return float((factors or edge_graph(graph)).error(values))
