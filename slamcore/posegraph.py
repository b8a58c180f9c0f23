"""Pose graphs as numpy records (2-D and 3-D), their pose maths and their structure.

A :class:`PoseGraph` holds what a g2o or TORO file says, numbers as written, so
that writing it back gives the same file content:

- 2-D poses are ``[x, y, theta]``;
- 3-D poses are ``[x, y, z, qx, qy, qz, qw]`` (g2o, ``rotation = "quat"``) or
  ``[x, y, z, roll, pitch, yaw]`` (TORO, ``rotation = "rpy"``, rotation
  ``Rz(yaw) Ry(pitch) Rx(roll)``);
- information matrices are full and symmetric, in the order
  ``[translation, rotation]`` of the file (2-D ``x, y, theta``).

Ids are Python-int checked on reading and stored as int64; they may have gaps
(nothing here loops over the gap). Edge ``(i, j)`` with measurement ``iTj``
says pose ``j`` seen from pose ``i``; a backwards edge (``i > j``) is kept as
written.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from slamcore.errors import GraphSlamError, InputError, MeasurementError

#: Pose parameter count per rotation kind.
PARAM_SIZE = {"angle": 3, "quat": 7, "rpy": 6}
#: Tangent dimension (information matrix side) per graph dimension.
TANGENT_SIZE = {2: 3, 3: 6}


@dataclass(frozen=True, eq=False)
class PoseGraph:
    """A pose graph as read from a file.

    Attributes:
        name: file stem. format: ``"g2o"`` or ``"toro"``. dim: 2 or 3.
        rotation: ``"angle"`` (2-D), ``"quat"`` or ``"rpy"`` (3-D).
        ids: (N,) int64 pose ids, increasing.
        vertices: (N, P) pose parameters (P from :data:`PARAM_SIZE`); for poses
            without a vertex line, the spanning-tree initialisation.
        has_vertex: (N,) bool, whether the file gave the pose a vertex line.
        edges: (M, 2) int64 ``(from_id, to_id)``.
        measurements: (M, P) relative poses ``from T to``.
        information: (M, D, D) full information matrices (D = 3 or 6).
        edge_lines: (M,) 1-based line of each edge in the file (0: not from a file).
        fixed: (F,) int64 ids of ``FIX`` lines. equiv: (E, 2) int64 ``EQUIV`` pairs.
        source_path: the file read, or None.
        noise: how the file's edge numbers were read, ``"information"`` or
            ``"sqrt_information"`` (TORO tags written by iSAM); :attr:`information`
            is the information matrix either way. noise_note: why, when a known
            file decided it.
        information_fix: how the reader replaced information matrices that were
            not positive definite (``"nearest"`` or ``"isotropic"``, see
            :func:`fixed_information`), None when it replaced none.
        self_edge_lines: 1-based lines of edges from a pose to itself, left out
            (such a factor is constant: it constrains nothing).
        information_fixed: (M,) bool, the edges whose :attr:`information` is such a
            replacement, not the file's numbers; None when none is.
        warnings: what the reader doubts in the file (angles in degrees, quaternions
            that are not unit, edges written twice), one line each; empty when none.
    """

    name: str
    format: str
    dim: int
    rotation: str
    ids: np.ndarray
    vertices: np.ndarray
    has_vertex: np.ndarray
    edges: np.ndarray
    measurements: np.ndarray
    information: np.ndarray
    edge_lines: np.ndarray
    fixed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    equiv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    source_path: str | None = None
    noise: str = "information"
    #: why :attr:`noise` was chosen when ``toro_noise = "auto"`` recognised the file, else None
    noise_note: str | None = None
    information_fix: str | None = None
    information_fixed: np.ndarray | None = None
    self_edge_lines: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    warnings: tuple[str, ...] = ()

    @property
    def n_poses(self) -> int:
        return len(self.ids)

    @property
    def n_edges(self) -> int:
        return len(self.edges)

    @property
    def n_information_fixed(self) -> int:
        """How many edges hold a replaced information matrix (:attr:`information_fixed`)."""
        return 0 if self.information_fixed is None else int(self.information_fixed.sum())

    def index_of(self, pose_ids: np.ndarray) -> np.ndarray:
        """Row of each id in :attr:`ids`; GraphSlamError for an id not in the graph
        (searchsorted alone gave it the row of another pose, or one past the end)."""
        wanted = np.asarray(pose_ids, dtype=np.int64)
        rows = np.searchsorted(self.ids, wanted)
        found = rows < self.ids.size
        found[found] = self.ids[rows[found]] == wanted[found]
        if not np.all(found):
            missing = wanted[~found].ravel()
            raise GraphSlamError(f"pose id {int(missing[0])} is not in the graph ({missing.size} such ids)")
        return rows

    def odometry_mask(self) -> np.ndarray:
        """(M,) bool: edges between neighbours in id order (the odometry chain);
        every other edge is a loop closure."""
        rank = self.index_of(self.edges.ravel()).reshape(-1, 2)
        return np.abs(rank[:, 0] - rank[:, 1]) == 1

    def subgraph(self, keep_rows: np.ndarray) -> PoseGraph:
        """The poses of ``keep_rows`` ((N,) bool) and the edges among them."""
        from dataclasses import replace

        keep_rows = np.asarray(keep_rows, dtype=bool)
        keep_ids = self.ids[keep_rows]
        keep = np.isin(self.edges, keep_ids).all(axis=1)
        return replace(
            self,
            ids=keep_ids,
            vertices=self.vertices[keep_rows],
            has_vertex=self.has_vertex[keep_rows],
            edges=self.edges[keep],
            measurements=self.measurements[keep],
            information=self.information[keep],
            edge_lines=self.edge_lines[keep],
            fixed=self.fixed[np.isin(self.fixed, keep_ids)],
            equiv=self.equiv[np.isin(self.equiv, keep_ids).all(axis=1)],
            information_fixed=(None if self.information_fixed is None else self.information_fixed[keep]),
        )

    def with_vertices(self, vertices: np.ndarray) -> PoseGraph:
        """The same graph with other vertex values (e.g. an optimised estimate): one
        finite row a pose, of the graph's width (a writer took any other as given)."""
        from dataclasses import replace

        values = np.array(vertices, dtype=np.float64)
        if values.shape != self.vertices.shape:
            raise GraphSlamError(f"vertices must have shape {self.vertices.shape}, got {values.shape}")
        if not np.all(np.isfinite(values)):
            raise GraphSlamError("vertices must be finite")
        return replace(self, vertices=values, has_vertex=np.ones(self.n_poses, dtype=bool))


# --------------------------------------------------------------------------- pose maths
def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) ``[qx, qy, qz, qw]`` (normalised here) -> (..., 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def rpy_to_matrix(rpy: np.ndarray) -> np.ndarray:
    """(..., 3) ``[roll, pitch, yaw]`` -> ``Rz(yaw) Ry(pitch) Rx(roll)`` (..., 3, 3)."""
    r, p, y = np.moveaxis(np.asarray(rpy, dtype=np.float64), -1, 0)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1),
        ],
        -2,
    )


def matrix_to_rpy(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> (..., 3) ``[roll, pitch, yaw]`` (inverse of :func:`rpy_to_matrix`)."""
    R = np.asarray(R, dtype=np.float64)
    # Eigen's eulerAngles route: near 90 deg pitch roll and yaw each come from a column
    # that is only rounding noise, and arcsin loses half the digits of the pitch (a
    # rotation written 2 deg off at pitch 90 deg, the 11th pass). atan2 over the column's
    # norm keeps the pitch, and roll taken against the yaw found (from entries of order
    # one) makes the three angles rebuild R whatever yaw the noise gave.
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    pitch = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 0, 0], R[..., 1, 0]))
    s, c = np.sin(yaw), np.cos(yaw)
    roll = np.arctan2(s * R[..., 0, 2] - c * R[..., 1, 2], c * R[..., 1, 1] - s * R[..., 0, 1])
    return np.stack([roll, pitch, yaw], -1)


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> (..., 4) unit ``[qx, qy, qz, qw]`` with ``qw >= 0``."""
    from slamcore.spatial.geometry import rotation_to_quaternion

    R = np.asarray(R, dtype=np.float64)
    return rotation_to_quaternion(R.reshape(-1, 3, 3)).reshape(*R.shape[:-2], 4)


def params_to_matrix(params: np.ndarray, rotation: str) -> np.ndarray:
    """(N, P) pose parameters -> (N, 3, 3) SE(2) or (N, 4, 4) SE(3) matrices."""
    p = np.asarray(params, dtype=np.float64).reshape(-1, PARAM_SIZE[rotation])
    if rotation == "angle":
        T = np.zeros((len(p), 3, 3))
        c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
        T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -s, s, c
        T[:, :2, 2] = p[:, :2]
        T[:, 2, 2] = 1.0
        return T
    T = np.zeros((len(p), 4, 4))
    T[:, :3, :3] = quat_to_matrix(p[:, 3:7]) if rotation == "quat" else rpy_to_matrix(p[:, 3:6])
    T[:, :3, 3] = p[:, :3]
    T[:, 3, 3] = 1.0
    return T


def matrix_to_params(T: np.ndarray, rotation: str) -> np.ndarray:
    """Inverse of :func:`params_to_matrix`: (N, 3, 3) or (N, 4, 4) -> (N, P)."""
    T = np.asarray(T, dtype=np.float64)
    if rotation == "angle":
        return np.column_stack([T[:, 0, 2], T[:, 1, 2], np.arctan2(T[:, 1, 0], T[:, 0, 0])])
    rot = matrix_to_quat(T[:, :3, :3]) if rotation == "quat" else matrix_to_rpy(T[:, :3, :3])
    return np.column_stack([T[:, :3, 3], rot])


# --------------------------------------------------------------------------- structure
class _UnionFind:
    def __init__(self, n: int):
        self.parent = list(range(n))

    def find(self, a: int) -> int:
        root = a
        while self.parent[root] != root:
            root = self.parent[root]
        while self.parent[a] != root:  # path compression
            self.parent[a], a = root, self.parent[a]
        return root

    def union(self, a: int, b: int) -> bool:
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return False
        self.parent[max(ra, rb)] = min(ra, rb)
        return True


def components(n: int, edge_rows: np.ndarray) -> list[np.ndarray]:
    """Connected components of ``n`` nodes joined by ``edge_rows`` (M, 2) row
    indices, each an increasing array of rows, the component of row 0 first."""
    uf = _UnionFind(n)
    for a, b in edge_rows.tolist():
        uf.union(a, b)
    roots = np.array([uf.find(i) for i in range(n)], dtype=np.int64)
    return [np.flatnonzero(roots == r) for r in np.unique(roots)]


def spanning_tree(n: int, edge_rows: np.ndarray, odometry: np.ndarray) -> list[tuple[int, int]]:
    """Tree edges ``(edge index, row reached)`` in breadth-first order from row 0.

    Odometry edges are taken first (Kruskal with two weights), so the tree is
    the odometry chain wherever the chain exists and loop edges join the rest.
    """
    uf = _UnionFind(n)
    order = np.concatenate([np.flatnonzero(odometry), np.flatnonzero(~odometry)])
    adjacency: list[list[tuple[int, int]]] = [[] for _ in range(n)]
    for e in order.tolist():
        a, b = int(edge_rows[e, 0]), int(edge_rows[e, 1])
        if uf.union(a, b):
            adjacency[a].append((e, b))
            adjacency[b].append((e, a))
    seen = np.zeros(n, dtype=bool)
    seen[0] = True
    out, frontier = [], [0]
    while frontier:
        nxt = []
        for row in frontier:
            for e, other in adjacency[row]:
                if not seen[other]:
                    seen[other] = True
                    out.append((e, other))
                    nxt.append(other)
        frontier = nxt
    return out


def chain_initialisation(graph: PoseGraph) -> np.ndarray:
    """(N, P) poses composed along :func:`spanning_tree` from the first pose
    (at its vertex if the file has one, else at the origin)."""
    rows = graph.index_of(graph.edges.ravel()).reshape(-1, 2)
    meas = params_to_matrix(graph.measurements, graph.rotation)
    side = meas.shape[-1]
    poses = np.repeat(np.eye(side)[None], graph.n_poses, axis=0)
    if graph.has_vertex[0]:
        poses[0] = params_to_matrix(graph.vertices[:1], graph.rotation)[0]
    for e, reached in spanning_tree(graph.n_poses, rows, graph.odometry_mask()):
        a, b = rows[e]
        if reached == b:
            poses[b] = poses[a] @ meas[e]
        else:
            poses[a] = poses[b] @ np.linalg.inv(meas[e])
    return matrix_to_params(poses, graph.rotation)


def describe_components(ids: np.ndarray, parts: list[np.ndarray], limit: int = 5) -> str:
    """``"ids 0..99 (100 poses); ids 200..250 (51 poses)"`` for the first ``limit`` parts."""
    text = "; ".join(f"ids {ids[p[0]]}..{ids[p[-1]]} ({len(p)} poses)" for p in parts[:limit])
    if len(parts) > limit:
        text += f"; and {len(parts) - limit} more"
    return text


def is_positive_definite(m: np.ndarray) -> bool:
    try:
        np.linalg.cholesky(m)
    except np.linalg.LinAlgError:
        return False
    return bool(np.all(np.isfinite(m)))


# --------------------------------------------------------------------------- information
#: How information matrices that are not positive definite can be replaced.
INFORMATION_FIXES = ("nearest", "isotropic")
#: Smallest eigenvalue a replaced information matrix keeps, as a fraction of its
#: largest. Zero would be Higham's nearest semi-definite matrix, which gtsam cannot
#: whiten. 1e-6 puts along a direction the file gives no information about a
#: standard deviation 1000 times that of the edge's best-known direction (so the
#: other edges decide it) and bounds the matrix's condition number at 1e6, which
#: Cholesky factors in double precision with digits to spare. Measured on a 3-D
#: torus (144 poses) whose 30 % of edges lack information along one direction:
#: floors from 1e-4 to 1e-10 give the same ATE; from 1e-8 down, iSAM2's Cholesky
#: meets indeterminate systems (its QR fallback acts), at 1e-6 and above it does not.
INFORMATION_FLOOR = 1e-6


def fixed_information(
    info: np.ndarray, method: str, dim: int, floor: float = INFORMATION_FLOOR
) -> np.ndarray:
    """(K, D, D) positive-definite replacements of symmetric information matrices
    ``info`` (K, D, D) (finite, each with a positive eigenvalue), order
    ``[translation, rotation]``; eigenvalues below ``floor`` times each matrix's
    largest are raised to it.

    ``nearest``: the nearest symmetric matrix in the Frobenius norm whose
    eigenvalues are at least that floor: the eigenvalues clipped, eigenvectors
    kept (Higham 1988, "Computing a nearest symmetric positive semidefinite
    matrix", with a floor instead of zero).

    ``isotropic``: SE-Sync's weights (``read_g2o_file``): ``tau = d / tr(I_t^-1)`` on
    the translation block ``I_t`` and, from the rotation block ``I_R``, the
    precision ``r / tr(I_R^-1)`` (``r`` = 1 in 2-D, 3 in 3-D) on every rotation
    axis, cross terms dropped. In 3-D that is SE-Sync's ``2 kappa`` (its cost
    ``kappa ||R_j - R_i R_ij||_F^2`` is ``2 kappa theta^2`` for a small angle
    ``theta``); in 2-D it is ``I_R`` itself, the angle's precision SE-Sync takes
    as ``kappa``. Each block's eigenvalues are raised to the floor first
    (SE-Sync's formula needs positive blocks).
    """
    info = np.asarray(info, dtype=np.float64)
    w, V = np.linalg.eigh(info)
    low = floor * w[:, -1:]
    if method == "nearest":
        out = (V * np.maximum(w, low)[:, None, :]) @ V.transpose(0, 2, 1)
        return 0.5 * (out + out.transpose(0, 2, 1))
    if method != "isotropic":
        raise ValueError(f"method must be one of {INFORMATION_FIXES}, got {method!r}")
    out = np.zeros_like(info)
    for block in (slice(0, dim), slice(dim, info.shape[-1])):
        wb = np.maximum(np.linalg.eigvalsh(info[:, block, block]), low)
        weight = wb.shape[-1] / np.sum(1.0 / wb, axis=-1)  # size / trace of the inverse
        idx = np.arange(info.shape[-1])[block]
        out[:, idx, idx] = weight[:, None]
    return out


def checked_information(
    stack: np.ndarray, edge_lines: np.ndarray, dim: int, information_fix: str, path
) -> tuple[np.ndarray, np.ndarray | None]:
    """(M, D, D) information and the (M,) mask of the edges replaced (None if none).

    One Cholesky of the stack passes a clean file (one by one it was half of
    reading w10000); otherwise the edges are looked at one by one: a matrix
    not finite, or without a positive eigenvalue, is an InputError at its
    line (``edge k`` when ``edge_lines`` says 0, not from a file), and so is any that
    is not positive definite under ``refuse``."""
    try:
        np.linalg.cholesky(stack)
        if np.isfinite(stack).all():
            return stack, None
    except np.linalg.LinAlgError:
        pass
    bad = np.zeros(len(stack), dtype=bool)
    for e, (info, line_no) in enumerate(zip(stack, edge_lines.tolist(), strict=True)):
        where = "" if line_no else f"edge {e}: "  # built in Python, not read
        line_no = line_no or None
        if not np.isfinite(info).all():
            raise InputError(f"{where}information matrix is not finite", path, line_no)
        if is_positive_definite(info):
            continue
        if information_fix == "refuse":
            raise InputError(
                f"{where}information matrix is not positive definite ([posegraph] "
                'information_fix = "nearest" or "isotropic" replaces '
                "it)",
                path,
                line_no,
            )
        if np.linalg.eigvalsh(info)[-1] <= 0.0:
            raise InputError(
                f"{where}information matrix has no positive eigenvalue (the edge carries no information)",
                path,
                line_no,
            )
        bad[e] = True
    if not bad.any():
        return stack, None
    stack[bad] = fixed_information(stack[bad], information_fix, dim)
    return stack, bad


def check_numbers(graph: PoseGraph) -> None:
    """What the file readers refuse, for a graph built or edited in Python: vertices
    and measurements must be finite and every information matrix finite and positive
    definite (the readers' :func:`checked_information`; their replacements pass). gtsam
    met NaN with a NaN cost or a bare RuntimeError, a negated matrix with ValueError.

    Raises:
        MeasurementError: naming the vertex, measurement or edge (row of the graph).
    """
    for what, rows in (("vertex", graph.vertices), ("measurement", graph.measurements)):
        a = np.asarray(rows, dtype=np.float64)
        bad = ~np.isfinite(a.reshape(len(a), -1)).all(axis=1)
        if bad.any():
            raise MeasurementError(f"pose graph: {what} {int(np.argmax(bad))} is not finite")
    info = np.array(graph.information, dtype=np.float64)
    try:  # rows, not file lines: the graph may differ from its file
        _, replaced = checked_information(info, np.zeros(len(info), np.int64), graph.dim, "nearest", None)
    except InputError as exc:
        raise MeasurementError(f"pose graph: {exc.reason}") from None
    if replaced is not None:  # a reader replaces such a matrix and says so; solve does not
        raise MeasurementError(
            f"pose graph: edge {int(np.argmax(replaced))}: information matrix is not positive definite"
        )
