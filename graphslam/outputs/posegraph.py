"""Writers of pose graphs: g2o and TORO, 2-D and 3-D (numpy + stdlib).

Numbers are written with Python's shortest round-trip form (``repr``), so
reading a written file gives back the same floats: read, write, read is the
identity. Vertices are whatever the record holds (the optimiser's estimate
when :meth:`PoseGraph.with_vertices` put it there); measurements, information,
``FIX`` and ``EQUIV`` lines are the file's. g2o has no ``EQUIV``: converting
TORO to g2o leaves those pairs out (:func:`convert` says how many).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from graphslam.sources.posegraph_files import TAG_NAMES, information_order
from slamcore import posegraph as pg
from slamcore.files import atomic_open

#: File name extension per format.
EXTENSIONS = {"g2o": ".g2o", "toro": ".graph"}


def _num(v: float) -> str:
    return repr(float(v))


def convert(graph: pg.PoseGraph, fmt: str) -> tuple[pg.PoseGraph, list[str]]:
    """``graph`` in format ``fmt`` (3-D rotations re-expressed); notes on what is lost."""
    if fmt not in EXTENSIONS:
        raise ValueError(f"format must be g2o or toro, got {fmt!r}")
    notes: list[str] = []
    if fmt == graph.format:
        return graph, notes
    rotation = "angle" if graph.dim == 2 else ("quat" if fmt == "g2o" else "rpy")
    out = replace(graph, format=fmt, rotation=rotation)
    if rotation != graph.rotation:
        out = replace(
            out,
            vertices=_re_express(graph.vertices, graph.rotation, rotation),
            measurements=_re_express(graph.measurements, graph.rotation, rotation),
        )
        if not out.has_vertex.all():  # what a reader of the converted file will compute
            out = replace(
                out, vertices=np.where(out.has_vertex[:, None], out.vertices, pg.chain_initialisation(out))
            )
    if fmt == "g2o":  # g2o numbers are information
        out = replace(out, noise="information")
    if fmt == "g2o" and len(graph.equiv):
        notes.append(f"{len(graph.equiv)} EQUIV line(s) left out: g2o has no EQUIV")
        out = replace(out, equiv=np.zeros((0, 2), dtype=np.int64))
    return out, notes


def _re_express(params: np.ndarray, src: str, dst: str) -> np.ndarray:
    return pg.matrix_to_params(pg.params_to_matrix(params, src), dst)


def graph_lines(graph: pg.PoseGraph) -> list[str]:
    """The lines of ``graph`` as a file of its format (no trailing newlines)."""
    vertex_tag, edge_tag = TAG_NAMES[(graph.format, graph.dim)]
    # poses without a vertex line stay without one, so an edge-only file stays edge-only
    lines = [
        f"{vertex_tag} {k} " + " ".join(map(_num, row))
        for k, row, has in zip(graph.ids.tolist(), graph.vertices, graph.has_vertex, strict=True)
        if has
    ]
    order = information_order(graph.format, graph.dim)
    sqrt = graph.format == "toro" and graph.noise == "sqrt_information"
    for (a, b), z, info in zip(graph.edges.tolist(), graph.measurements, graph.information, strict=True):
        if sqrt:  # upper Cholesky factor: read back as R^T R (to rounding, not bit for bit)
            info = np.linalg.cholesky(info).T
        numbers = [info[r, c] for r, c in order]
        lines.append(f"{edge_tag} {a} {b} " + " ".join(map(_num, [*z, *numbers])))
    lines += [f"EQUIV {a} {b}" for a, b in graph.equiv.tolist()]
    if len(graph.fixed):
        lines.append("FIX " + " ".join(str(k) for k in graph.fixed.tolist()))
    return lines


def write_pose_graph(path: Path, graph: pg.PoseGraph) -> None:
    """Write ``graph`` in its own format and dimension."""
    with atomic_open(path, "w", encoding="utf-8") as f:
        for line in graph_lines(graph):
            f.write(line + "\n")
