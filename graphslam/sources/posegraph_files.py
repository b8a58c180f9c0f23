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
BR (TORO 2-D)      ``BR i j bearing range bearing_sigma range_sigma``: landmark
                   ``j`` seen from pose ``i`` (gtsam's ``example.graph``), read
                   beside the graph by :func:`read_pose_graph_records` with
                   ``landmarks=True`` (the landmark back ends), refused otherwise
=================  =========================================================

This is the one reader of these files: the frame streams of
:mod:`graphslam.sources.planar.posegraph` (filters, 2-D iSAM2) convert its graph,
so a file gets the same information matrices whatever the back end. A valid
file is read in bulk (:mod:`graphslam.sources.posegraph_bulk`); whatever that
declines is read line by line, which names the line.

The numbers after an edge are an **information** matrix in every format (the
g2o and TORO specifications; note ``gtsam.load2D`` reads TORO's as a
covariance when its zero pattern says so: identical on w10000, whose are
identity; :mod:`graphslam.sources.planar.posegraph` says why the format wins).
Files written by iSAM use the TORO tags with the upper triangle of the
*square-root* information instead: gtsam's ``sphere2500.txt`` is one (its
measurements' residuals against ``sphere2500_groundtruth.txt`` have standard
deviations 0.10 m and 0.010/0.010/0.040 rad, the inverses of its numbers 10
and 100/100/25). Nothing in such a file tells the two apart; read as
information, its optimum (364.49) is neither gtsam's (which takes the numbers
in its own rotation-first order) nor that of the true noise: pass
``toro_noise="sqrt_information"`` (``[posegraph] toro_noise``) for such files.
Blank lines, ``#`` comments and a UTF-8 byte-order mark are skipped.

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
Python ints (never through a float), from 0 to 2**62 (or ``id_limit``); numbers finite;
quaternions of norm >= 1e-6; translations within 1e9 m; information finite and
positive definite (or replaced, above); an edge from a pose to itself is left out and counted
(:attr:`PoseGraph.self_edge_lines`); no vertex twice; ``BR`` sigmas and ranges
positive, bearings within one turn, in a 2-D TORO file, from a pose of the graph; when the file has vertex
lines, every edge and ``FIX`` names a declared pose. Edge-only files are initialised by composing edges
along a spanning tree that prefers the odometry chain. The graph must be
connected: otherwise its components are named.

Doubts, one line each in :attr:`PoseGraph.warnings` (the run says them and keeps
them in ``metrics.json``; ``convert`` says them), when every line reads but the
numbers are unlikely as written (:func:`file_doubts`): edge angles beyond one turn
(degrees?), quaternions that are not unit or that turn every odometry step by
over 150 degrees (written w first?), an edge repeated to the last digit.
"""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from graphslam.sources.posegraph_bulk import FileLines, Sightings, read_in_bulk
from graphslam.sources.tokens import MAX_ID, check_count, iter_lines, parse_id, parse_numbers
from slamcore import posegraph as pg
from slamcore.errors import ConfigError, InputError, quote

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
TAG_NAMES = {
    (fmt, dim): (tags[0], tags[1])
    for fmt, dim, tags in (
        ("g2o", 2, ("VERTEX_SE2", "EDGE_SE2")),
        ("g2o", 3, ("VERTEX_SE3:QUAT", "EDGE_SE3:QUAT")),
        ("toro", 2, ("VERTEX2", "EDGE2")),
        ("toro", 3, ("VERTEX3", "EDGE3")),
    )
}
#: TORO 2-D information order ``ixx ixy iyy ith ixt iyt`` as (row, col) of the matrix.
TORO2_ORDER = ((0, 0), (0, 1), (1, 1), (2, 2), (0, 2), (1, 2))


#: Smallest quaternion norm read: files hold unit quaternions to 6 digits, and below
#: this the components' rounding decides the rotation (1e-300 underflowed to 0).
QUATERNION_NORM_MIN = 1e-6
#: Largest translation component read, metres (a million km): beyond it a number is
#: no robot's motion, and least squares on it overflows (a 1e300 m step: the solve
#: ended in an indeterminate system, or silently far away).
TRANSLATION_MAX_M = 1e9


#: An edge turning by more than one full turn (rad) is no radian measurement: g2o and
#: TORO writers give relative angles wrapped to +-pi (the gtsam examples and the RRR
#: graphs stay within 3.3); a file in degrees turns past it at its first 7 degree edge.
ONE_TURN_RAD = 2 * math.pi
#: Largest distance of a quaternion's norm from 1 read without a word: unit
#: quaternions written to 6 digits are within 1e-5 of it (the gtsam examples: 1.2e-6);
#: beyond, the four numbers are not a unit quaternion as written (another column?).
QUATERNION_UNIT_TOL = 1e-3
#: Smallest turn of every odometry edge (between neighbouring ids), degrees, at which
#: the quaternions are doubted: ``w x y z`` read as ``qx qy qz qw`` makes a step that
#: turns by ``t`` a turn of at least ``180 - t``, so a chain of steps under 30 degrees
#: turns by over 150 at every step, which no robot's odometry does (the gtsam examples'
#: steps: at most 63 degrees in the least turning of them).
HALF_TURN_STEPS_DEG = 150.0


def upper_order(side: int) -> tuple[tuple[int, int], ...]:
    """(row, col) of the upper triangle row by row (g2o's order)."""
    return tuple((r, c) for r in range(side) for c in range(r, side))


def information_order(fmt: str, dim: int) -> tuple[tuple[int, int], ...]:
    """(row, col) of each information number as the format writes it (a TORO 2-D
    line may also be in g2o's order: :func:`g2o_diagonal_rows`)."""
    if (fmt, dim) == ("toro", 2):
        return TORO2_ORDER
    return upper_order(pg.TANGENT_SIZE[dim])


def g2o_diagonal_rows(v: np.ndarray) -> np.ndarray:
    """(M,) bool of (M, 6) TORO 2-D numbers: ``a 0 0 b 0 c`` (a, b, c non-zero) is a
    diagonal in g2o's order."""
    nz = v != 0
    return nz[:, 0] & ~nz[:, 1] & ~nz[:, 2] & nz[:, 3] & ~nz[:, 4] & nz[:, 5]


#: How TORO edge numbers are read (g2o's are information always); ``auto``: as
#: :data:`KNOWN_TORO_NOISE` says for a file it knows, else information (the format).
TORO_NOISE = ("auto", "information", "sqrt_information")
#: Files whose TORO noise convention is known, by (size in bytes, SHA-256 of their bytes)
#: -> (name, convention, why); only a file of a known size is hashed (a second pass over
#: a large graph for nothing otherwise). sphere2500.txt: module docstring (its residuals
#: against the ground-truth file have the standard deviations its numbers invert).
KNOWN_TORO_NOISE = {
    (618297, "4b9418a300e6ec3ec0a4223e13b0febb068d18f9a008ebb59c1b9f262626e552"): (
        "gtsam's sphere2500.txt",
        "sqrt_information",
        "written by iSAM",
    )
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
    return convention, (
        f"{convention} (auto: {name}, {why}; [posegraph] toro_noise = "
        f'"information" reads the numbers as the format defines them)'
    )


#: What is done with an information matrix that is not positive definite.
INFORMATION_FIX = (*pg.INFORMATION_FIXES, "refuse")


def information_matrices(fmt: str, dim: int, noise: np.ndarray, sqrt: bool = False) -> np.ndarray:
    """(M, D, D) information of the (M, K) numbers after the edges' measurements, in
    the file's order (:func:`information_order`; g2o's for the TORO 2-D lines
    :func:`g2o_diagonal_rows` picks); ``sqrt``: the numbers are the upper triangle
    ``R`` of the information ``R^T R``."""
    side = pg.TANGENT_SIZE[dim]
    order = np.array(upper_order(side)).T  # (2, K): row and column of each number
    rows = np.repeat(order[0][None], len(noise), axis=0)
    cols = np.repeat(order[1][None], len(noise), axis=0)
    if (fmt, dim) == ("toro", 2):
        toro = ~g2o_diagonal_rows(noise)
        rows[toro], cols[toro] = np.array(information_order(fmt, dim)).T
    info = np.zeros((len(noise), side, side))
    edge = np.arange(len(noise))[:, None]
    info[edge, rows, cols] = noise
    if sqrt:
        with np.errstate(over="ignore"):  # an overflow is refused as not finite
            return np.matmul(info.transpose(0, 2, 1), info)
    info[edge, cols, rows] = noise
    return info


class _LineReader:
    """Lines of one file, each checked as it comes: the reference the bulk path
    (:mod:`graphslam.sources.posegraph_bulk`) must match, and the one that names lines."""

    def __init__(self, path: Path, landmarks: bool, id_limit: int):
        self.path, self.landmarks, self.id_limit = path, landmarks, id_limit
        self.kind: tuple[str, int, str] | None = None  # (format, dim, rotation)
        self.kind_line = 0
        self.vertices: dict[int, list[float]] = {}
        self.vertex_lines: dict[int, int] = {}
        self.edges: list[tuple[int, int]] = []
        self.numbers: list[list[float]] = []
        self.edge_lines: list[int] = []
        self.fixed: list[tuple[int, int]] = []  # (id, line)
        self.equiv: list[tuple[int, int]] = []
        self.equiv_lines: list[int] = []
        self.sightings: list[tuple[int, int]] = []
        self.sighting_numbers: list[list[float]] = []
        self.sighting_lines: list[int] = []

    def _id(self, token: str, line_no: int, what: str = "pose id") -> int:
        return parse_id(token, self.path, line_no, what, limit=self.id_limit)

    def line(self, line_no: int, tok: list[str]) -> None:
        tag = tok[0]
        if tag == "FIX":
            if len(tok) < 2:
                raise InputError("FIX line needs at least one pose id", self.path, line_no)
            self.fixed += [(self._id(t, line_no), line_no) for t in tok[1:]]
            return
        if tag == "EQUIV":
            if len(tok) != 3:
                raise InputError(f"EQUIV line needs 2 pose ids, got {len(tok) - 1}", self.path, line_no)
            self.equiv.append((self._id(tok[1], line_no), self._id(tok[2], line_no)))
            self.equiv_lines.append(line_no)
            return
        if tag in LANDMARK_TAGS:
            self._sighting(line_no, tok)
            return
        if tag not in TAGS:
            raise InputError(f"unknown tag {quote(tag)}", self.path, line_no)
        fmt, dim, rotation, kind, count = TAGS[tag]
        if self.kind is None:
            self.kind, self.kind_line = (fmt, dim, rotation), line_no
        elif self.kind != (fmt, dim, rotation):
            raise InputError(
                f"{tag} in a {self.kind[1]}-D {self.kind[0]} file (see line {self.kind_line})",
                self.path,
                line_no,
            )
        check_count(tok, count, self.path, line_no)
        (self._vertex if kind == "vertex" else self._edge)(line_no, tok, dim, rotation)

    def _pose(self, numbers: list[float], line_no: int, dim: int, rotation: str) -> list[float]:
        # plain Python, not numpy: this runs on every line of the file
        if rotation == "quat":
            norm = math.hypot(*numbers[3:7])
            if not norm >= QUATERNION_NORM_MIN:
                raise InputError(
                    f"quaternion of norm {norm:.3g} cannot be normalised into a "
                    "rotation (a unit quaternion is expected)",
                    self.path,
                    line_no,
                )
        if not max(abs(v) for v in numbers[:dim]) <= TRANSLATION_MAX_M:
            raise InputError(
                f"translation beyond {TRANSLATION_MAX_M:.0e} m: no robot's pose "
                "graph spans that (a shifted column?)",
                self.path,
                line_no,
            )
        return numbers

    def _vertex(self, line_no: int, tok: list[str], dim: int, rotation: str) -> None:
        k = self._id(tok[1], line_no)
        if k in self.vertices:
            raise InputError(
                f"pose {k} declared twice (first on line {self.vertex_lines[k]})", self.path, line_no
            )
        self.vertices[k] = self._pose(parse_numbers(tok[2:], self.path, line_no), line_no, dim, rotation)
        self.vertex_lines[k] = line_no

    def _edge(self, line_no: int, tok: list[str], dim: int, rotation: str) -> None:
        ids = (self._id(tok[1], line_no), self._id(tok[2], line_no))
        numbers = parse_numbers(tok[3:], self.path, line_no)
        self._pose(numbers[: pg.PARAM_SIZE[rotation]], line_no, dim, rotation)
        self.edges.append(ids)  # positive definiteness: checked for all edges at once
        self.numbers.append(numbers)
        self.edge_lines.append(line_no)

    def _sighting(self, line_no: int, tok: list[str]) -> None:
        """A ``BR`` line (gtsam's load2D reading): only where landmarks are read."""
        if not self.landmarks:
            raise InputError(
                f"{tok[0]} is a landmark observation (landmark SLAM, not a pose "
                "graph): graphslam run takes a 2-D TORO file with BR lines with "
                "--backend isam2, ekf, fastslam1 or fastslam2",
                self.path,
                line_no,
            )
        check_count(tok, 7, self.path, line_no, "BR pose landmark bearing range bearing_sigma range_sigma")
        ids = (self._id(tok[1], line_no), self._id(tok[2], line_no, "landmark id"))
        numbers = parse_numbers(tok[3:], self.path, line_no)
        if numbers[2] <= 0.0 or numbers[3] <= 0.0:
            raise InputError("BR sigmas must be positive", self.path, line_no)
        if numbers[1] <= 0.0:
            raise InputError("BR range must be positive", self.path, line_no)
        if not abs(numbers[0]) <= ONE_TURN_RAD:
            raise InputError(
                f"BR bearing {numbers[0]:g} rad is beyond one turn (2 pi): degrees? TORO angles are radians",
                self.path,
                line_no,
            )
        self.sightings.append(ids)
        self.sighting_numbers.append(numbers)
        self.sighting_lines.append(line_no)

    def file_lines(self) -> FileLines:
        size = pg.PARAM_SIZE[self.kind[2]] if self.kind else 0
        ints = np.int64
        numbers = np.array(self.numbers, dtype=np.float64) if self.numbers else np.zeros((0, size))
        return FileLines(
            kind=self.kind,
            vertex_ids=np.array(list(self.vertices), dtype=ints),
            vertices=np.array(list(self.vertices.values()), dtype=np.float64).reshape(
                len(self.vertices), size
            ),
            vertex_lines=np.array(list(self.vertex_lines.values()), dtype=ints),
            edges=np.array(self.edges, dtype=ints).reshape(-1, 2),
            numbers=numbers,
            edge_lines=np.array(self.edge_lines, dtype=ints),
            fixed=np.array([k for k, _ in self.fixed], dtype=ints),
            fixed_lines=np.array([n for _, n in self.fixed], dtype=ints),
            equiv=np.array(self.equiv, dtype=ints).reshape(-1, 2),
            equiv_lines=np.array(self.equiv_lines, dtype=ints),
            sightings=Sightings.of_rows(self.sightings, self.sighting_numbers, self.sighting_lines),
        )


def _in_range(lines: FileLines) -> bool:
    """Whether every pose of lines read in bulk passes :meth:`_LineReader._pose` (no:
    the line loop reads the file again and names the line). Quaternion norms near the
    bound go to the loop too, whose own arithmetic decides them."""
    if lines.kind is None:
        return False
    _, dim, rotation = lines.kind
    poses = np.concatenate(
        [lines.vertices] + ([lines.numbers[:, : pg.PARAM_SIZE[rotation]]] if len(lines.edges) else [])
    )
    if not (np.abs(poses[:, :dim]) <= TRANSLATION_MAX_M).all():
        return False
    return rotation != "quat" or bool(
        (np.sqrt((poses[:, 3:7] ** 2).sum(axis=1)) >= 2 * QUATERNION_NORM_MIN).all()
    )


def _assembled(lines: FileLines, path: Path, toro_noise: str, information_fix: str) -> pg.PoseGraph:
    """The graph of a file's lines: the checks across lines (module docstring)."""
    self_edge = lines.edges[:, 0] == lines.edges[:, 1]
    if lines.kind is None or self_edge.all():
        if self_edge.any():  # a place recogniser matching a frame to itself, and nothing else
            raise InputError(
                "no pose-graph edges in the file but edges from a pose to itself, which constrain nothing",
                path,
                int(lines.edge_lines[0]),
            )
        raise InputError("no pose-graph edges in the file", path)
    fmt, dim, rotation = lines.kind
    size = pg.PARAM_SIZE[rotation]
    # an edge from a pose to itself (RRR's NewCollege has 9): constant whatever the
    # estimate, so it constrains nothing; left out and counted, never silently
    keep = ~self_edge
    edges, numbers, edge_lines = lines.edges[keep], lines.numbers[keep], lines.edge_lines[keep]
    sqrt = fmt == "toro" and toro_noise == "sqrt_information"
    information, fixed = pg.checked_information(
        information_matrices(fmt, dim, numbers[:, size:], sqrt), edge_lines, dim, information_fix, path
    )
    _check_declared(lines, edges, edge_lines, path)
    ids = np.union1d(lines.vertex_ids, edges.ravel())
    vertices = np.zeros((len(ids), size))
    vertices[np.searchsorted(ids, lines.vertex_ids)] = lines.vertices
    graph = pg.PoseGraph(
        name=path.stem,
        format=fmt,
        dim=dim,
        rotation=rotation,
        ids=ids,
        vertices=vertices,
        has_vertex=np.isin(ids, lines.vertex_ids),
        edges=edges,
        measurements=numbers[:, :size].copy(),
        information=information,
        edge_lines=edge_lines,
        fixed=np.unique(lines.fixed),
        equiv=lines.equiv,
        source_path=str(path),
        noise=toro_noise if fmt == "toro" else "information",
        information_fix=None if fixed is None else information_fix,
        information_fixed=fixed,
        self_edge_lines=lines.edge_lines[self_edge],
    )
    check_connected(graph, path)
    doubts = file_doubts(lines, keep, rotation)
    return with_chain_start(replace(graph, warnings=doubts) if doubts else graph)


def _first_lines(line_numbers: np.ndarray) -> str:
    shown = ", ".join(map(str, line_numbers[:3].tolist()))
    return f"line{'s' if len(line_numbers) > 1 else ''} {shown}{', ...' if len(line_numbers) > 3 else ''}"


def file_doubts(lines: FileLines, keep: np.ndarray, rotation: str) -> tuple[str, ...]:
    """What makes a file's numbers doubtful though each line reads, one line each:
    edge angles beyond one turn (:data:`ONE_TURN_RAD`: degrees?), quaternions that
    are not unit (:data:`QUATERNION_UNIT_TOL`: normalised, but not as written) or
    half turns at every odometry step (:data:`HALF_TURN_STEPS_DEG`: w first?),
    edges written twice to the last digit (each counts: the measurement weighs
    double). ``keep``: the edges kept (not self-edges)."""
    doubts = []
    numbers, edge_lines = lines.numbers[keep], lines.edge_lines[keep]
    if rotation in ("angle", "rpy"):
        angles = numbers[:, 2:3] if rotation == "angle" else numbers[:, 3:6]
        over = (np.abs(angles) > ONE_TURN_RAD).any(axis=1)
        if over.any():
            first = int(np.argmax(over))
            doubts.append(
                f"{int(over.sum())} of {len(over)} edges turn by more than 2 pi rad "
                f"({_first_lines(edge_lines[over])}: {np.abs(angles[first]).max():g}): "
                "angles in degrees? g2o and TORO angles are radians"
            )
    if rotation == "quat":
        for what, quats, at in (
            ("vertex", lines.vertices[:, 3:7], lines.vertex_lines),
            ("edge", numbers[:, 3:7], edge_lines),
        ):
            norms = np.sqrt((quats**2).sum(axis=1))
            off = np.abs(norms - 1.0) > QUATERNION_UNIT_TOL
            if off.any():
                doubts.append(
                    f"{int(off.sum())} {what} quaternions are not unit (norms "
                    f"{norms[off].min():.4g} to {norms[off].max():.4g}, {_first_lines(at[off])}): "
                    "normalised, but four numbers of another meaning (a shifted column?) "
                    "read as qx qy qz qw"
                )
        edges = lines.edges[keep]
        rank = np.searchsorted(np.union1d(lines.vertex_ids, edges.ravel()), edges)
        odometry = np.abs(rank[:, 0] - rank[:, 1]) == 1
        q = numbers[odometry, 3:7]
        turn = np.degrees(2 * np.arccos(np.clip(np.abs(q[:, 3]) / np.sqrt((q**2).sum(axis=1)), 0.0, 1.0)))
        if len(turn) >= 2 and (turn > HALF_TURN_STEPS_DEG).all():
            doubts.append(
                f"every odometry edge turns by more than {HALF_TURN_STEPS_DEG:g} degrees "
                f"({turn.min():.0f} to {turn.max():.0f}): quaternions written w x y z? "
                "g2o's order is qx qy qz qw"
            )
    if len(numbers) > 1:
        # ids as integers (beyond 2**53 a float merges neighbours), numbers by their bits
        bits = np.ascontiguousarray(numbers, dtype=np.float64).view(np.int64)
        rows = np.column_stack([np.asarray(lines.edges[keep], dtype=np.int64), bits])
        _, originals, counts = np.unique(rows, axis=0, return_index=True, return_counts=True)
        if (counts > 1).any():
            again = np.setdiff1d(np.arange(len(rows)), originals)
            doubts.append(
                f"{len(again)} edges repeat an earlier edge to the last digit "
                f"({_first_lines(np.sort(edge_lines[again]))}): each copy is a factor, so "
                "the measurement weighs double (a file concatenated twice?)"
            )
    return tuple(doubts)


def _first_unknown(pairs: np.ndarray, known: np.ndarray) -> tuple[int, int] | None:
    """``(row, id)`` of the first id of ``pairs`` (rows in file order) not in ``known``."""
    if not len(pairs):
        return None
    bad = ~np.isin(pairs, known).reshape(len(pairs), -1)
    if not bad.any():
        return None
    row = int(np.argmax(bad.any(axis=1)))
    return row, int(pairs.reshape(len(pairs), -1)[row][bad[row]][0])


def _check_declared(lines: FileLines, edges: np.ndarray, edge_lines: np.ndarray, path) -> None:
    """With vertex lines present, an edge or FIX naming an undeclared pose is refused;
    an EQUIV naming a pose that is in no edge and no vertex line, always (it was
    copied into the written graph as a pose of nothing)."""
    bad = _first_unknown(lines.equiv, np.union1d(lines.vertex_ids, edges.ravel()))
    if bad is not None:
        raise InputError(
            f"EQUIV names pose {bad[1]}, which no vertex or edge has", path, int(lines.equiv_lines[bad[0]])
        )
    if not len(lines.vertex_ids):
        bad = _first_unknown(lines.fixed, edges.ravel())
        if bad is not None:
            raise InputError(
                f"FIX names pose {bad[1]}, which no edge uses", path, int(lines.fixed_lines[bad[0]])
            )
        return
    bad = _first_unknown(edges, lines.vertex_ids)
    if bad is not None:
        raise InputError(f"edge names pose {bad[1]}, which has no vertex line", path, int(edge_lines[bad[0]]))
    bad = _first_unknown(lines.fixed, lines.vertex_ids)
    if bad is not None:
        raise InputError(
            f"FIX names pose {bad[1]}, which has no vertex line", path, int(lines.fixed_lines[bad[0]])
        )


def _checked_sightings(lines: FileLines, graph: pg.PoseGraph, path) -> Sightings:
    """The BR lines, in a 2-D TORO file only, each seen from a pose of the graph."""
    seen = lines.sightings
    if not len(seen):
        return seen
    if (graph.format, graph.dim) != ("toro", 2):
        raise InputError(
            f"BR in a {graph.dim}-D {graph.format} file: landmark lines are read in 2-D TORO files only",
            path,
            int(seen.lines[0]),
        )
    bad = _first_unknown(seen.pose_ids, graph.ids)
    if bad is not None:
        raise InputError(
            f"BR seen from pose {bad[1]}, which no edge or vertex names", path, int(seen.lines[bad[0]])
        )
    return seen


def check_connected(graph: pg.PoseGraph, path) -> None:
    """InputError naming the components when ``graph`` is not connected."""
    rows = graph.index_of(graph.edges.ravel()).reshape(-1, 2)
    chain = np.zeros(max(graph.n_poses - 1, 0), dtype=bool)
    chain[rows.min(axis=1)[np.abs(rows[:, 0] - rows[:, 1]) == 1]] = True
    if chain.all():  # the odometry chain alone joins every pose (most files: no union-find)
        return
    parts = pg.components(graph.n_poses, rows)
    if len(parts) > 1:
        raise InputError(
            f"the graph is not connected: {len(parts)} components: "
            f"{pg.describe_components(graph.ids, parts)}",
            path,
        )


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
        raise InputError(f"the first {n_poses} poses have no edge between them", graph.source_path)
    try:
        check_connected(cut, graph.source_path)
    except InputError as e:  # the file is connected: the cut is not (ids out of travel order)
        raise InputError(
            f"the first {n_poses} poses by id (--max-steps {n_poses}) do not form a connected graph: "
            + e.reason.removeprefix("the graph is not connected: "),
            graph.source_path,
        ) from None
    return with_chain_start(cut)


def read_pose_graph_file(path, toro_noise: str = "auto", information_fix: str = "nearest") -> pg.PoseGraph:
    """Read a g2o or TORO pose graph, 2-D or 3-D (told from its tags); a landmark
    line (``BR``) is refused: :func:`read_pose_graph_records` reads those.

    ``toro_noise = "sqrt_information"`` reads TORO edge numbers as the upper
    triangle ``R`` of the information ``R^T R`` (files written by iSAM);
    ``"auto"`` does so for a file :data:`KNOWN_TORO_NOISE` knows to be such,
    and says so in the graph's ``noise_note``.
    ``information_fix``: ``nearest``, ``isotropic`` or ``refuse`` for information
    that is not positive definite (module docstring).
    """
    return read_pose_graph_records(path, toro_noise, information_fix)[0]


def read_pose_graph_records(
    path,
    toro_noise: str = "auto",
    information_fix: str = "nearest",
    *,
    landmarks: bool = False,
    id_limit: int = MAX_ID,
) -> tuple[pg.PoseGraph, Sightings]:
    """:func:`read_pose_graph_file`, and with ``landmarks`` the ``BR`` lines of a 2-D
    TORO file beside the graph (else refused); ids above ``id_limit`` are refused
    (``tokens.MAX_KEY_ID`` where they become gtsam symbol keys)."""
    path = Path(path)
    # the exception family's ConfigError, as a config file's bad value is (a bare ValueError)
    if toro_noise not in TORO_NOISE:
        raise ConfigError(f"toro_noise must be one of {TORO_NOISE}, got {toro_noise!r}")
    if information_fix not in INFORMATION_FIX:
        raise ConfigError(f"information_fix must be one of {INFORMATION_FIX}, got {information_fix!r}")
    toro_noise, note = resolve_toro_noise(path, toro_noise)
    lines = read_in_bulk(path, TAGS, id_limit)
    if lines is None or not _in_range(lines):
        reader = _LineReader(path, landmarks, id_limit)
        for line_no, tok in iter_lines(path):
            reader.line(line_no, tok)
        lines = reader.file_lines()
    graph = _assembled(lines, path, toro_noise, information_fix)
    sightings = _checked_sightings(lines, graph, path)
    if note and graph.format == "toro":
        graph = replace(graph, noise_note=note)
    return graph, sightings


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
