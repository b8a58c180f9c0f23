"""Bulk path of the 2-D pose-graph readers: a whole valid file in a few numpy calls.

:func:`~graphslam.sources.planar.posegraph.read_toro` and ``read_g2o`` check
every token of every line and name the line of the first bad one. On a valid
file that per-token work was most of the reading (w10000, 64 000 edges: 0.66 s
in all, 0.48 s with this path, of which ~0.2 s builds and groups the records;
``gtsam.load2D`` reads it in 0.13 s). :func:`read_se2_lines` reads the
same lines with the numbers of all edges parsed and checked at once; the
readers use it first and fall back to their line-by-line loop whenever it
declines (returns None: anything it would have to refuse, or a landmark line),
so every refusal and its ``file:line`` still come from the one loop, and a
file read either way gives the same records bit for bit
(``tests/test_reader_bulk.py``).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from graphslam.sources.tokens import ID_TOKEN, decimal_value
from slamcore.planar.geometry import wrap_angle

#: Ids separated by single spaces, each as ``posegraph_files.parse_id`` accepts one.
_ONE_ID = ID_TOKEN.pattern.removesuffix(r"\Z")
_IDS = re.compile(rf"(?:{_ONE_ID} )*{_ONE_ID}\Z")
#: Edge: tag, 2 ids, 3 measurement numbers, 6 noise numbers; vertex: tag, id, x, y, theta.
EDGE_TOKENS, VERTEX_TOKENS = 12, 5


def read_se2_lines(path, vertex_tag: str, edge_tag: str, ignored: tuple[str, ...],
                   noise_format: str, id_limit: int):
    """``(edges, pose_lines)`` of a valid 2-D pose-graph file, else None.

    ``edges``: list of ``(line_no, from_id, to_id, delta (3,), covariance (3, 3))``,
    as the line-by-line reader builds them; ``pose_lines``: ``{pose_id: line_no}``
    of the vertex lines. None whenever the line-by-line reader has to decide: a
    line it would refuse, a tag other than the three given, ids of ``id_limit``
    or more, a repeated vertex.
    """
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError):
        return None
    edge_rows: list[list[str]] = []
    edge_lines: list[int] = []
    vertex_rows: list[list[str]] = []
    vertex_lines: list[int] = []
    # read_text translates every newline to "\n", as iterating the file does: same line numbers
    for line_no, line in enumerate(text.split("\n"), start=1):
        s = line.strip()
        if not s or s[0] == "#":
            continue
        tok = s.split()
        if tok[0] == edge_tag and len(tok) == EDGE_TOKENS:
            edge_rows.append(tok)
            edge_lines.append(line_no)
        elif tok[0] == vertex_tag and len(tok) == VERTEX_TOKENS:
            vertex_rows.append(tok)
            vertex_lines.append(line_no)
        elif tok[0] not in ignored:
            return None
    ids = _ids([t[1] for t in edge_rows] + [t[2] for t in edge_rows]
               + [t[1] for t in vertex_rows], id_limit)
    numbers = _finite([t[3:] for t in edge_rows], 9)
    if ids is None or numbers is None or _finite([t[2:] for t in vertex_rows], 3) is None:
        return None
    n = len(edge_rows)
    pose_lines = dict(zip(ids[2 * n:], vertex_lines))
    if len(pose_lines) != len(vertex_rows):
        return None  # a pose declared twice
    covariances = noise_covariances(numbers[:, 3:], noise_format)
    if covariances is None:
        return None
    deltas = numbers[:, :3].copy()
    deltas[:, 2] = wrap_angle(deltas[:, 2])
    edges = list(zip(edge_lines, ids[:n], ids[n:2 * n], deltas, covariances))
    return edges, pose_lines


def _ids(tokens: list[str], id_limit: int) -> list[int] | None:
    """Python ints (never through a float) of decimal id tokens all below ``id_limit``."""
    if tokens and not _IDS.match(" ".join(tokens)):
        return None
    # int() refuses strings over 4300 digits: any token over 20 goes the long way
    ids = list(map(int if max(map(len, tokens), default=0) <= 20 else decimal_value, tokens))
    return ids if not ids or max(ids) < id_limit else None


def _finite(rows: list[list[str]], width: int) -> np.ndarray | None:
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


def noise_covariances(v: np.ndarray, noise_format: str) -> np.ndarray | None:
    """(N, 3, 3) covariances of the (N, 6) noise numbers read as ``noise_format`` (see
    :mod:`graphslam.sources.planar.posegraph`); None if a row is refused (no layout
    under ``auto``; an information matrix that is not positive definite). The line
    reader's ``noise_covariance`` is this on one row."""
    nz = v != 0
    if noise_format == "auto":
        graph = nz[:, 0] & ~nz[:, 1] & nz[:, 2] & nz[:, 3] & ~nz[:, 4] & ~nz[:, 5]
        cov = nz[:, 0] & ~nz[:, 1] & ~nz[:, 2] & nz[:, 3] & ~nz[:, 4] & nz[:, 5]
        if not (graph | cov).all():
            return None
        toro_layout, information = graph, np.zeros(len(v), dtype=bool)
    else:
        toro_layout = np.full(len(v), noise_format in ("graph", "toro"))
        information = np.full(len(v), noise_format in ("toro", "g2o"))
    v1, v2, v3, v4, v5, v6 = v.T
    m = np.where(toro_layout[:, None, None],
                 np.stack([v1, v2, v5, v2, v3, v6, v5, v6, v4], axis=1).reshape(-1, 3, 3),
                 np.stack([v1, v2, v3, v2, v4, v5, v3, v5, v6], axis=1).reshape(-1, 3, 3))
    if information.any():
        info = m[information]
        try:
            np.linalg.cholesky(info)
        except np.linalg.LinAlgError:
            return None
        inv = np.linalg.inv(info)
        m[information] = 0.5 * (inv + inv.transpose(0, 2, 1))
    return m
