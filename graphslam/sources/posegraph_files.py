"""Readers of g2o and TORO pose-graph files, 2-D and 3-D, into :class:`PoseGraph`.

Tags (the format and dimension are told from the tags, not the file name):

=================  =========================================================
g2o 2-D            ``VERTEX_SE2 id x y th``;
                   ``EDGE_SE2 i j dx dy dth`` + 6 information numbers, upper
                   triangle row by row (``i11 i12 i13 i22 i23 i33``)
g2o 3-D            ``VERTEX_SE3:QUAT id x y z qx qy qz qw``;
                   ``EDGE_SE3:QUAT i j x y z qx qy qz qw`` + 21 numbers, the
                   upper triangle of the 6x6 information, translation first
TORO 2-D           ``VERTEX2 id x y th``; ``EDGE2 i j dx dy dth`` +
                   ``ixx ixy iyy ith ixt iyt`` (TORO's own order); a line
                   whose six numbers read ``a 0 0 b 0 c`` is in g2o's order
                   (gtsam's ``w20000.txt``, ``w100_30.g2o`` are written so;
                   ``gtsam.load2D`` tells them apart by the same pattern)
TORO 3-D           ``VERTEX3 id x y z roll pitch yaw``; ``EDGE3 i j x y z roll
                   pitch yaw`` + 21 numbers as in g2o 3-D
both               ``FIX id ...`` (poses held at their vertex), ``EQUIV i j``
                   (kept and written back, not used by the solver, as in gtsam;
                   counted in the summary; one naming an unknown pose is refused)
=================  =========================================================

The numbers after an edge are an **information** matrix in every format (the
g2o and TORO specifications; note ``gtsam.load2D`` reads TORO's as a
covariance when its zero pattern says so: identical on w10000, whose are
identity). Files written by iSAM use the TORO tags with the upper triangle of
the *square-root* information instead: gtsam's ``sphere2500.txt`` is one (its
measurements' residuals against ``sphere2500_groundtruth.txt`` have standard
deviations 0.10 m and 0.010/0.010/0.040 rad, the inverses of its numbers 10
and 100/100/25). Nothing in such a file tells the two apart; read as
information, its optimum (364.49) is neither gtsam's (which takes the numbers
in its own rotation-first order) nor that of the true noise: pass
``toro_noise="sqrt_information"`` (``[posegraph] toro_noise``) for such files. Blank lines, ``#`` comments and a UTF-8 byte-order mark are skipped.

Information matrices are symmetric by construction: the formats write the upper
triangle, mirrored here. One that is not positive definite (SE-Sync's
``cubicle.g2o`` has such edges, which g2o and SE-Sync read) is replaced, as
``information_fix`` says (``[posegraph] information_fix``): ``nearest`` (the
nearest positive-definite matrix), ``isotropic`` (SE-Sync's isotropic
translation and rotation weights), both by :func:`slamcore.posegraph.fixed_information`,
on those edges only, counted in :attr:`PoseGraph.information_fixed`; or
``refuse`` (an error at the first such edge's line). A non-finite matrix (an
overflowing square root) or one with no positive eigenvalue (an edge that
carries no information) is refused whatever the setting.

Checks, each one line with file and line (information matrices are checked
after the whole file is read, the rest line by line): ids are decimal integers read as
Python ints (never through a float), from 0 to 2**62; numbers finite;
quaternions of norm >= 1e-6; translations within 1e9 m; information finite and
positive definite (or replaced, above); an edge from a pose to itself is left out and counted
(:attr:`PoseGraph.self_edge_lines`); no vertex twice; when the file has vertex
lines, every edge and ``FIX`` names a declared pose. Edge-only files are initialised by composing edges
along a spanning tree that prefers the odometry chain. The graph must be
connected: otherwise its components are named.
"""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from graphslam.sources.tokens import iter_lines, parse_id, parse_numbers
from slamcore.errors import InputError, quote
from slamcore import posegraph as pg


#: tag -> (format, dim, rotation, kind, token count)
TAGS = {
    "VERTEX_SE2": ("g2o", 2, "angle", "vertex", 5),
    "EDGE_SE2": ("g2o", 2, "angle", "edge", 12),
    "VERTEX_SE3:QUAT": ("g2o", 3, "quat", "vertex", 9),
    "EDGE_SE3:QUAT": ("g2o", 3, "quat", "edge", 31),
    "VERTEX2": ("toro", 2, "angle", "vertex", 5),
    "EDGE2": ("toro", 2, "angle", "edge", 12),
    "VERTEX3": ("toro", 3, "rpy", "vertex", 8),
    "EDGE3": ("toro", 3, "rpy", "edge", 30),
}
#: Tag names per (format, dim), for the writers.
TAG_NAMES = {(fmt, dim): (tags[0], tags[1]) for fmt, dim, tags in (
    ("g2o", 2, ("VERTEX_SE2", "EDGE_SE2")), ("g2o", 3, ("VERTEX_SE3:QUAT", "EDGE_SE3:QUAT")),
    ("toro", 2, ("VERTEX2", "EDGE2")), ("toro", 3, ("VERTEX3", "EDGE3")))}
#: TORO 2-D information order ``ixx ixy iyy ith ixt iyt`` as (row, col) of the matrix.
TORO2_ORDER = ((0, 0), (0, 1), (1, 1), (2, 2), (0, 2), (1, 2))


#: Smallest quaternion norm read: files hold unit quaternions to 6 digits, and below
#: this the components' rounding decides the rotation (1e-300 underflowed to 0).
QUATERNION_NORM_MIN = 1e-6
#: Largest translation component read, metres (a million km): beyond it a number is
#: no robot's motion, and least squares on it overflows (a 1e300 m step: the solve
#: ended in an indeterminate system, or silently far away).
TRANSLATION_MAX_M = 1e9


def upper_order(side: int) -> tuple[tuple[int, int], ...]:
    """(row, col) of the upper triangle row by row (g2o's order)."""
    return tuple((r, c) for r in range(side) for c in range(r, side))


def information_order(fmt: str, dim: int, numbers=None) -> tuple[tuple[int, int], ...]:
    """(row, col) of each information number; ``numbers`` decides TORO 2-D's layout."""
    if (fmt, dim) == ("toro", 2) and not is_g2o_diagonal(numbers):
        return TORO2_ORDER
    return upper_order(pg.TANGENT_SIZE[dim])


def is_g2o_diagonal(v) -> bool:
    """Six numbers ``a 0 0 b 0 c`` (a, b, c non-zero): a diagonal in g2o's order."""
    return (v is not None and v[0] != 0 and v[1] == 0 and v[2] == 0 and v[3] != 0
            and v[4] == 0 and v[5] != 0)


#: How TORO edge numbers are read (g2o's are information always); ``auto``: as
#: :data:`KNOWN_TORO_NOISE` says for a file it knows, else information (the format).
TORO_NOISE = ("auto", "information", "sqrt_information")
#: Files whose TORO noise convention is known, by (size in bytes, SHA-256 of their bytes)
#: -> (name, convention, why); only a file of a known size is hashed (a second pass over
#: a large graph for nothing otherwise). sphere2500.txt: module docstring (its residuals
#: against the ground-truth file have the standard deviations its numbers invert).
KNOWN_TORO_NOISE = {
    (618297, "4b9418a300e6ec3ec0a4223e13b0febb068d18f9a008ebb59c1b9f262626e552"): (
        "gtsam's sphere2500.txt", "sqrt_information", "written by iSAM"),
}


def resolve_toro_noise(path, toro_noise: str) -> tuple[str, str | None]:
    """``(convention, note)``: ``toro_noise`` unless it is ``auto``; then the known
    file's convention with a note saying so, or ``information`` and no note."""
    if toro_noise != "auto":
        return toro_noise, None
    import hashlib

    try:
        size = Path(path).stat().st_size
        if size not in {s for s, _ in KNOWN_TORO_NOISE}:
            return "information", None
        digest = hashlib.sha256()
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
    except OSError:
        return "information", None  # the reader says what is wrong with the file
    known = KNOWN_TORO_NOISE.get((size, digest.hexdigest()))
    if known is None:
        return "information", None
    name, convention, why = known
    return convention, (f"{convention} (auto: {name}, {why}; [posegraph] toro_noise = "
                        f"\"information\" reads the numbers as the format defines them)")
#: What is done with an information matrix that is not positive definite.
INFORMATION_FIX = (*pg.INFORMATION_FIXES, "refuse")


class _Collector:
    """Lines of one file, checked as they come."""

    def __init__(self, path: Path, toro_noise: str = "information",
                 information_fix: str = "nearest"):
        if toro_noise not in TORO_NOISE[1:]:
            raise ValueError(f"toro_noise must be one of {TORO_NOISE}, got {toro_noise!r}")
        if information_fix not in INFORMATION_FIX:
            raise ValueError(f"information_fix must be one of {INFORMATION_FIX}, "
                             f"got {information_fix!r}")
        self.path = path
        self.toro_noise = toro_noise
        self.information_fix = information_fix
        self.kind: tuple[str, int, str] | None = None  # (format, dim, rotation)
        self.kind_line = 0
        self.vertices: dict[int, list[float]] = {}
        self.vertex_lines: dict[int, int] = {}
        self.edges: list[tuple[int, int]] = []
        self.measurements: list[list[float]] = []
        self.information: list[np.ndarray] = []
        self.edge_lines: list[int] = []
        self.self_edge_lines: list[int] = []
        self.fixed: list[tuple[int, int]] = []
        self.equiv: list[tuple[int, int]] = []
        self.equiv_lines: list[int] = []

    def line(self, line_no: int, tok: list[str]) -> None:
        tag = tok[0]
        if tag == "FIX":
            if len(tok) < 2:
                raise InputError("FIX line needs at least one pose id", self.path, line_no)
            self.fixed += [(parse_id(t, self.path, line_no), line_no) for t in tok[1:]]
            return
        if tag == "EQUIV":
            if len(tok) != 3:
                raise InputError(f"EQUIV line needs 2 pose ids, got {len(tok) - 1}", self.path,
                                 line_no)
            self.equiv.append((parse_id(tok[1], self.path, line_no),
                               parse_id(tok[2], self.path, line_no)))
            self.equiv_lines.append(line_no)
            return
        if tag in LANDMARK_TAGS:
            raise InputError(f"{tag} is a landmark observation (landmark SLAM, not a pose "
                             "graph): graphslam run takes a 2-D TORO file with BR lines with "
                             "--backend isam2, ekf, fastslam1 or fastslam2", self.path, line_no)
        if tag not in TAGS:
            raise InputError(f"unknown tag {quote(tag)}", self.path, line_no)
        fmt, dim, rotation, kind, count = TAGS[tag]
        if self.kind is None:
            self.kind, self.kind_line = (fmt, dim, rotation), line_no
        elif self.kind != (fmt, dim, rotation):
            raise InputError(f"{tag} in a {self.kind[1]}-D {self.kind[0]} file (see line "
                             f"{self.kind_line})", self.path, line_no)
        if len(tok) != count:
            raise InputError(f"{tag} line needs {count} tokens, got {len(tok)}", self.path,
                             line_no)
        (self._vertex if kind == "vertex" else self._edge)(line_no, tok, (fmt, dim, rotation))

    def _pose(self, numbers: list[float], line_no: int, dim: int, rotation: str) -> list[float]:
        # plain Python, not numpy: this runs on every line of the file
        if rotation == "quat":
            norm = math.hypot(*numbers[3:7])
            if not norm >= QUATERNION_NORM_MIN:
                raise InputError(f"quaternion of norm {norm:.3g} cannot be normalised into a "
                                 "rotation (a unit quaternion is expected)", self.path, line_no)
        if not max(abs(v) for v in numbers[:dim]) <= TRANSLATION_MAX_M:
            raise InputError(f"translation beyond {TRANSLATION_MAX_M:.0e} m: no robot's pose "
                             "graph spans that (a shifted column?)", self.path, line_no)
        return numbers

    def _vertex(self, line_no: int, tok: list[str], kind: tuple[str, int, str]) -> None:
        k = parse_id(tok[1], self.path, line_no)
        if k in self.vertices:
            raise InputError(f"pose {k} declared twice (first on line {self.vertex_lines[k]})",
                             self.path, line_no)
        self.vertices[k] = self._pose(parse_numbers(tok[2:], self.path, line_no), line_no,
                                      kind[1], kind[2])
        self.vertex_lines[k] = line_no

    def _edge(self, line_no: int, tok: list[str], kind: tuple[str, int, str]) -> None:
        a = parse_id(tok[1], self.path, line_no)
        b = parse_id(tok[2], self.path, line_no)
        fmt, dim, rotation = kind
        size = pg.PARAM_SIZE[rotation]
        numbers = parse_numbers(tok[3:], self.path, line_no)
        if a == b:
            # a place recogniser matching a frame to itself (RRR's NewCollege has 9): the
            # factor is constant whatever the estimate, so it constrains nothing; left out
            # and counted, never silently
            self._pose(numbers[:size], line_no, dim, rotation)  # still a well-formed line
            self.self_edge_lines.append(line_no)
            return
        side = pg.TANGENT_SIZE[dim]
        info = np.zeros((side, side))
        sqrt = fmt == "toro" and self.toro_noise == "sqrt_information"
        for (r, c), v in zip(information_order(fmt, dim, numbers[size:]), numbers[size:]):
            info[r, c] = v
            if not sqrt:
                info[c, r] = v
        if sqrt:  # the numbers are the upper triangle R of information = R^T R
            with np.errstate(over="ignore"):  # an overflow is refused as not finite
                info = info.T @ info
        # positive definiteness: checked for all edges at once, in graph()
        self.edges.append((a, b))
        self.measurements.append(self._pose(numbers[:size], line_no, dim, rotation))
        self.information.append(info)
        self.edge_lines.append(line_no)

    def graph(self) -> pg.PoseGraph:
        if self.kind is None or not self.edges:
            raise InputError("no pose-graph edges in the file", self.path)
        fmt, dim, rotation = self.kind
        information, fixed = self._checked_information(dim)
        self._check_declared()
        ids = np.array(sorted(set(self.vertices) | {k for e in self.edges for k in e}),
                       dtype=np.int64)
        size = pg.PARAM_SIZE[rotation]
        has_vertex = np.array([int(k) in self.vertices for k in ids.tolist()], dtype=bool)
        vertices = np.array([self.vertices.get(k, [0.0] * size) for k in ids.tolist()],
                            dtype=np.float64).reshape(-1, size)
        graph = pg.PoseGraph(
            name=self.path.stem, format=fmt, dim=dim, rotation=rotation, ids=ids,
            vertices=vertices, has_vertex=has_vertex,
            edges=np.array(self.edges, dtype=np.int64).reshape(-1, 2),
            measurements=np.array(self.measurements, dtype=np.float64).reshape(-1, size),
            information=information,
            edge_lines=np.array(self.edge_lines, dtype=np.int64),
            fixed=np.array(sorted({k for k, _ in self.fixed}), dtype=np.int64),
            equiv=np.array(self.equiv, dtype=np.int64).reshape(-1, 2),
            source_path=str(self.path),
            noise=self.toro_noise if fmt == "toro" else "information",
            information_fix=None if fixed is None else self.information_fix,
            information_fixed=fixed,
            self_edge_lines=np.array(self.self_edge_lines, dtype=np.int64))
        check_connected(graph, self.path)
        return with_chain_start(graph)

    def _checked_information(self, dim: int) -> tuple[np.ndarray, np.ndarray | None]:
        """(M, D, D) information and the (M,) mask of the edges replaced (None if none).

        One Cholesky of the stack passes a clean file (one by one it was half of
        reading w10000); otherwise the edges are looked at one by one: a matrix
        not finite, or without a positive eigenvalue, is an InputError at its
        line, and so is any that is not positive definite under ``refuse``."""
        stack = np.array(self.information)
        try:
            np.linalg.cholesky(stack)
            if np.isfinite(stack).all():
                return stack, None
        except np.linalg.LinAlgError:
            pass
        bad = np.zeros(len(stack), dtype=bool)
        for e, (info, line_no) in enumerate(zip(stack, self.edge_lines)):
            if not np.isfinite(info).all():
                raise InputError("information matrix is not finite", self.path, line_no)
            if pg.is_positive_definite(info):
                continue
            if self.information_fix == "refuse":
                raise InputError("information matrix is not positive definite ([posegraph] "
                                 "information_fix = \"nearest\" or \"isotropic\" replaces "
                                 "it)", self.path, line_no)
            if np.linalg.eigvalsh(info)[-1] <= 0.0:
                raise InputError("information matrix has no positive eigenvalue (the edge "
                                 "carries no information)", self.path, line_no)
            bad[e] = True
        if not bad.any():
            return stack, None
        stack[bad] = pg.fixed_information(stack[bad], self.information_fix, dim)
        return stack, bad

    def _check_declared(self) -> None:
        """With vertex lines present, an edge or FIX naming an undeclared pose is refused;
        an EQUIV naming a pose that is in no edge and no vertex line, always (it was
        copied into the written graph as a pose of nothing)."""
        known = set(self.vertices) | {k for e in self.edges for k in e}
        for pair, line_no in zip(self.equiv, self.equiv_lines):
            for k in pair:
                if k not in known:
                    raise InputError(f"EQUIV names pose {k}, which no vertex or edge has",
                                     self.path, line_no)
        if not self.vertices:
            for k, line_no in self.fixed:
                if not any(k in e for e in self.edges):
                    raise InputError(f"FIX names pose {k}, which no edge uses", self.path, line_no)
            return
        for (a, b), line_no in zip(self.edges, self.edge_lines):
            for k in (a, b):
                if k not in self.vertices:
                    raise InputError(f"edge names pose {k}, which has no vertex line",
                                     self.path, line_no)
        for k, line_no in self.fixed:
            if k not in self.vertices:
                raise InputError(f"FIX names pose {k}, which has no vertex line", self.path,
                                 line_no)



def check_connected(graph: pg.PoseGraph, path) -> None:
    """InputError naming the components when ``graph`` is not connected."""
    rows = graph.index_of(graph.edges.ravel()).reshape(-1, 2)
    parts = pg.components(graph.n_poses, rows)
    if len(parts) > 1:
        raise InputError(f"the graph is not connected: {len(parts)} components: "
                         f"{pg.describe_components(graph.ids, parts)}", path)


def with_chain_start(graph: pg.PoseGraph) -> pg.PoseGraph:
    """Poses without a vertex line get the spanning-tree composition of the edges."""
    if graph.has_vertex.all():
        return graph
    init = pg.chain_initialisation(graph)
    return replace(graph, vertices=np.where(graph.has_vertex[:, None], graph.vertices, init))


def truncated(graph: pg.PoseGraph, n_poses: int) -> pg.PoseGraph:
    """The first ``n_poses`` poses in id order and the edges among them
    (``--max-steps``); InputError if they do not form a connected graph."""
    if n_poses >= graph.n_poses:
        return graph
    keep_rows = np.arange(graph.n_poses) < n_poses
    cut = graph.subgraph(keep_rows)
    if not cut.n_edges:
        raise InputError(f"the first {n_poses} poses have no edge between them",
                         graph.source_path)
    check_connected(cut, graph.source_path)
    return with_chain_start(cut)


def read_pose_graph_file(path, toro_noise: str = "auto",
                         information_fix: str = "nearest") -> pg.PoseGraph:
    """Read a g2o or TORO pose graph, 2-D or 3-D (told from its tags).

    ``toro_noise = "sqrt_information"`` reads TORO edge numbers as the upper
    triangle ``R`` of the information ``R^T R`` (files written by iSAM);
    ``"auto"`` does so for a file :data:`KNOWN_TORO_NOISE` knows to be such,
    and says so in the graph's ``noise_note``.
    ``information_fix``: ``nearest``, ``isotropic`` or ``refuse`` for information
    that is not positive definite (module docstring).
    """
    path = Path(path)
    if toro_noise not in TORO_NOISE:
        raise ValueError(f"toro_noise must be one of {TORO_NOISE}, got {toro_noise!r}")
    toro_noise, note = resolve_toro_noise(path, toro_noise)
    collector = _Collector(path, toro_noise, information_fix)
    for line_no, tok in iter_lines(path):
        collector.line(line_no, tok)
    graph = collector.graph()
    return replace(graph, noise_note=note) if note and graph.format == "toro" else graph


#: Landmark-observation tags a 2-D pose-graph file may hold (gtsam's ``load2D`` reads
#: ``BR`` in TORO files): such a file is landmark SLAM (graphslam.sources.planar.posegraph).
LANDMARK_TAGS = ("BR",)
_LANDMARK_LINE = re.compile(rb"^[ \t]*(?:\xef\xbb\xbf)?BR[ \t]", re.MULTILINE)


def has_landmark_lines(path) -> bool:
    """Whether any line of a file starts with a landmark tag (one regex over the bytes)."""
    try:
        return _LANDMARK_LINE.search(Path(path).read_bytes()) is not None
    except OSError:
        return False


def is_pose_graph_tag(tag: str | None) -> bool:
    """Whether a file whose first tag is ``tag`` is a pose graph."""
    return tag in (*TAGS, "FIX", "EQUIV")


def first_tag(path) -> str | None:
    """The first tag of a text file, or None (unreadable or empty)."""
    try:
        for _, tok in iter_lines(path):
            return tok[0]
    except InputError:
        return None
    return None
