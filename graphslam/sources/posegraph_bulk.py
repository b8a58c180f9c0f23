"""The lines of a pose-graph file as arrays (:class:`FileLines`), and their bulk path.

:func:`graphslam.sources.posegraph_files.read_pose_graph_records` checks every
token of every line and names the line of the first bad one. On a valid file
that per-token work was most of the reading (w10000, 64 000 edges).
:func:`read_in_bulk` reads the same lines with the numbers of all of them
parsed and checked at once; the reader uses it first and falls back to its
line loop whenever it declines (returns None: a line the loop would refuse, a
landmark line, anything the loop has to decide), so every refusal and its
``file:line`` still come from the one loop, and a file read either way gives
the same arrays bit for bit (``tests/graphslam/sources/test_reader_bulk.py``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from graphslam.sources.tokens import ID_TOKEN, decimal_value, iter_lines
from slamcore.errors import InputError

#: Ids separated by single spaces, each as ``tokens.parse_id`` accepts one.
_ONE_ID = ID_TOKEN.pattern.removesuffix(r"\Z")
_IDS = re.compile(rf"(?:{_ONE_ID} )*{_ONE_ID}\Z")


def _ints(values) -> np.ndarray:
    return np.array(values, dtype=np.int64).reshape(-1)


@dataclass(frozen=True, eq=False)
class Sightings:
    """``BR pose landmark bearing range bearing_sigma range_sigma`` lines of a 2-D TORO
    file (gtsam's ``load2D`` reads them as bearing-range factors), numbers as written.

    Attributes:
        pose_ids, landmark_ids: (K,) int64. bearing: (K,) rad. range_m: (K,) m.
        sigmas: (K, 2) ``[bearing_sigma rad, range_sigma m]``.
        lines: (K,) 1-based line of each in the file.
    """

    pose_ids: np.ndarray
    landmark_ids: np.ndarray
    bearing: np.ndarray
    range_m: np.ndarray
    sigmas: np.ndarray
    lines: np.ndarray

    @classmethod
    def of_rows(cls, ids: list[tuple[int, int]], numbers: list[list[float]], lines: list[int]) -> Sightings:
        """From ``(pose, landmark)`` ids and ``[bearing, range, bearing_sigma, range_sigma]``."""
        i = np.array(ids, dtype=np.int64).reshape(-1, 2)
        v = np.array(numbers, dtype=np.float64).reshape(-1, 4)
        return cls(i[:, 0], i[:, 1], v[:, 0], v[:, 1], v[:, 2:], _ints(lines))

    def __len__(self) -> int:
        return len(self.lines)


@dataclass(frozen=True, eq=False)
class FileLines:
    """What the lines of a pose-graph file say, each kind in file order, before any
    check across lines (those are the reader's): numbers as written.

    Attributes:
        kind: ``(format, dim, rotation)`` of the vertex and edge tags, None if none.
        vertex_ids: (N,) int64. vertices: (N, P). vertex_lines: (N,).
        edges: (M, 2) int64 as written (edges from a pose to itself included).
        numbers: (M, C) the measurement's P numbers, then the noise numbers.
        edge_lines: (M,). fixed, fixed_lines: (F,) ids of ``FIX`` lines and their lines.
        equiv: (E, 2) ``EQUIV`` pairs. equiv_lines: (E,).
        sightings: the ``BR`` lines.
    """

    kind: tuple[str, int, str] | None
    vertex_ids: np.ndarray
    vertices: np.ndarray
    vertex_lines: np.ndarray
    edges: np.ndarray
    numbers: np.ndarray
    edge_lines: np.ndarray
    fixed: np.ndarray
    fixed_lines: np.ndarray
    equiv: np.ndarray
    equiv_lines: np.ndarray
    sightings: Sightings


def read_in_bulk(path, tags: dict[str, tuple], id_limit: int) -> FileLines | None:
    """The :class:`FileLines` of a file whose lines are all well formed, else None.

    ``tags``: tag -> ``(format, dim, rotation, "vertex" | "edge", token count)``
    (``posegraph_files.TAGS``); ``FIX`` and ``EQUIV`` are read too. None whenever
    the line loop has to decide: an unknown or landmark tag, tags of two kinds, a
    token count, an id not as ``parse_id`` reads one or above ``id_limit``, a
    number not decimal or not finite, a repeated vertex.
    """
    got = rows_by_tag(path)
    if got is None:
        return None
    rows, lines = got
    kinds = {tags[t][:3] for t in rows if t in tags}
    if len(kinds) != 1 or not set(rows) <= {*tags, "FIX", "EQUIV"}:
        return None
    kind = kinds.pop()
    by_role = {tags[t][3]: t for t in rows if t in tags}
    vertex, edge = rows.get(by_role.get("vertex", ""), []), rows.get(by_role.get("edge", ""), [])
    fixes, equivs = rows.get("FIX", []), rows.get("EQUIV", [])
    for role, role_rows in (("vertex", vertex), ("edge", edge)):
        if role_rows and set(map(len, role_rows)) != {tags[by_role[role]][4]}:
            return None
    if any(len(t) < 2 for t in fixes) or any(len(t) != 3 for t in equivs):
        return None
    fixed_tokens = [t for r in fixes for t in r[1:]]
    ids = ids_in_bulk(
        [t[1] for t in vertex]
        + [t for r in edge for t in r[1:3]]
        + fixed_tokens
        + [t for r in equivs for t in r[1:]],
        id_limit,
    )
    size = {"angle": 3, "quat": 7, "rpy": 6}[kind[2]]
    v_num = numbers_in_bulk([t[2:] for t in vertex], size)
    e_num = numbers_in_bulk([t[3:] for t in edge], (len(edge[0]) - 3) if edge else 0)
    if ids is None or v_num is None or e_num is None:
        return None
    n_v, n_e, n_f = len(vertex), len(edge), len(fixed_tokens)
    if len(set(ids[:n_v])) != n_v:
        return None  # a pose declared twice: the loop names both lines
    fixed_lines = [n for r, n in zip(fixes, lines.get("FIX", []), strict=True) for _ in r[1:]]
    return FileLines(
        kind=kind,
        vertex_ids=_ints(ids[:n_v]),
        vertices=v_num,
        vertex_lines=_ints(lines.get(by_role.get("vertex", ""), [])),
        edges=_ints(ids[n_v : n_v + 2 * n_e]).reshape(-1, 2),
        numbers=e_num,
        edge_lines=_ints(lines.get(by_role.get("edge", ""), [])),
        fixed=_ints(ids[n_v + 2 * n_e : n_v + 2 * n_e + n_f]),
        fixed_lines=_ints(fixed_lines),
        equiv=_ints(ids[n_v + 2 * n_e + n_f :]).reshape(-1, 2),
        equiv_lines=_ints(lines.get("EQUIV", [])),
        sightings=Sightings.of_rows([], [], []),
    )


def rows_by_tag(path) -> tuple[dict[str, list[list[str]]], dict[str, list[int]]] | None:
    """``({tag: token lists}, {tag: their 1-based lines})`` of the lines
    ``tokens.iter_lines`` yields, grouped by tag in file order; None if the file cannot
    be read as UTF-8 (the line reader says why)."""
    rows: dict[str, list[list[str]]] = {}
    lines: dict[str, list[int]] = {}
    try:
        for line_no, tok in iter_lines(path):
            rows.setdefault(tok[0], []).append(tok)
            lines.setdefault(tok[0], []).append(line_no)
    except InputError:  # unreadable or not UTF-8: the line reader says so
        return None
    return rows, lines


def ids_in_bulk(tokens: list[str], id_limit: int) -> list[int] | None:
    """Python ints (never through a float) of decimal id tokens all up to ``id_limit``."""
    if tokens and not _IDS.match(" ".join(tokens)):
        return None
    # int() refuses strings over 4300 digits: any token over 20 goes the long way
    ids = list(map(int if max(map(len, tokens), default=0) <= 20 else decimal_value, tokens))
    return ids if not ids or max(ids) <= id_limit else None


def numbers_in_bulk(rows: list[list[str]], width: int) -> np.ndarray | None:
    """(N, width) float64 of number tokens, None unless all are decimal (as g2o reads
    them) and finite."""
    flat = "".join("".join(r) for r in rows)
    # float() also takes 1_000 and full-width digits; on ASCII without "_" its
    # syntax is the decimal one: anything else goes to the line reader, which refuses
    if "_" in flat or not flat.isascii():
        return None
    try:
        out = np.array(rows, dtype=np.float64).reshape(len(rows), width)
    except ValueError:
        return None
    return out if np.isfinite(out).all() else None
