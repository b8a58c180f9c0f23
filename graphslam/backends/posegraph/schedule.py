"""The order in which iSAM2 receives a pose graph: one update per pose, in id order.

Update ``k`` adds pose ``k`` (row ``k`` of the increasing ids) with every edge
between it and poses already added; its initial value composes one of those
edges onto the neighbour's current estimate. A pose with no edge to an earlier
one (ais2klinik's pose 7290, joined by a loop edge to a later pose) waits, with
its edges, until a later pose links it to the graph; it then enters in that
pose's update, initialised through the linking edges. Pure numpy: the plan is
made once, before any timing-relevant work.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Step:
    """One iSAM2 update.

    Attributes:
        inits: ``(row, edge, source_row)``: initialise ``row`` through ``edge``
            from ``source_row`` (added before, or earlier in this list);
            ``edge = -1`` for the first pose (its vertex value).
        edges: every edge whose two ends are added once this step is done.
    """

    inits: list[tuple[int, int, int]]
    edges: list[int] = field(default_factory=list)


def schedule(n_poses: int, edge_rows: np.ndarray) -> list[Step]:
    """Updates for poses ``0..n_poses-1`` joined by ``edge_rows`` (M, 2) (a
    connected graph: every pose is added by the last step)."""
    hi = edge_rows.max(axis=1)
    order = np.argsort(hi, kind="stable")
    bounds = np.searchsorted(hi[order], np.arange(n_poses + 1)).tolist()
    # the loop runs once per pose: plain lists, not numpy scalars (a fixed cost of the solve)
    other_of = (edge_rows.sum(axis=1) - hi)[order].tolist()
    order_list = order.tolist()
    added = [False] * n_poses  # a list: indexed once per edge, numpy scalars cost more
    added[0] = True
    steps = [Step([(0, -1, -1)])]
    waiting: dict[int, set[int]] = {}  # deferred row -> its edges seen so far
    for j in range(1, n_poses):
        lo, up = bounds[j], bounds[j + 1]
        group, others = order_list[lo:up], other_of[lo:up]
        if group and j not in waiting and all(added[o] for o in others):
            steps.append(Step([(j, group[0], others[0])], group))  # the usual case
            added[j] = True
            continue
        for e in group:
            for r in edge_rows[e].tolist():
                if not added[r]:
                    waiting.setdefault(r, set()).add(e)
        step = _join(j, edge_rows, added, waiting)
        if step is not None:
            steps.append(step)
    return steps


def _join(j: int, edge_rows: np.ndarray, added: list[bool], waiting: dict[int, set[int]]) -> Step | None:
    """Pose ``j`` with the waiting poses it reaches, if that set touches the graph."""
    rows, edges, frontier = {j}, set(), [j]
    while frontier:
        r = frontier.pop()
        for e in waiting.get(r, ()):
            edges.add(e)
            for other in edge_rows[e].tolist():
                if not added[other] and other not in rows:
                    rows.add(other)
                    frontier.append(other)
    if not any(added[r] for e in edges for r in edge_rows[e].tolist()):
        return None  # still floating: wait for a later pose
    inits: list[tuple[int, int, int]] = []
    known = {r for e in edges for r in edge_rows[e].tolist() if added[r]}
    pending = sorted(edges)
    while len(inits) < len(rows):
        for e in pending:
            a, b = edge_rows[e].tolist()
            if (a in known) != (b in known):
                src, dst = (a, b) if a in known else (b, a)
                inits.append((dst, e, src))
                known.add(dst)
    for r in rows:
        added[r] = True
        waiting.pop(r, None)
    return Step(inits, sorted(edges))
