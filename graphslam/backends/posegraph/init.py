"""Starting points of the batch pose-graph solve (``--init``).

LAGO (2-D) and the chordal relaxation (3-D) first solve the rotations alone,
a problem with a unique minimum in practice, then the translations linearly:
Levenberg-Marquardt from there reaches the global optimum where it stalls from
the odometry chain (a graph that winds round a torus several times: 2.8x the
optimum from odometry in ``tests/graphslam/backends/test_posegraph_solver.py``). Shonan averaging
solves the rotations by a convex relaxation lifted to SO(p) and returns a
certificate: a minimum eigenvalue >= 0 (to numerical tolerance) of its
certificate matrix proves the **rotation averaging** problem (chordal cost,
isotropic rotation weights taken from the information) solved globally; it
does not certify the full pose-graph cost under the file's anisotropic
information, which LM then minimises locally from that start.

LAGO and the chordal relaxation are keyed by rank (row of the increasing ids),
as Shonan is: gtsam's LAGO walks the odometric path ``k-1 -> k`` of its keys and
fails (``IndexError: map::at``) where a key has no edge from its predecessor, so
it takes that path only when every consecutive rank pair is joined by an edge,
and gtsam's own spanning tree over all edges otherwise (an id gap in the file
costs nothing by rank; a pose joined only by closures, or a second session
restarted in its own frame, does). Where a relaxation still fails (gtsam
throws, e.g. an indeterminate system where closures carry information of 1e15
and more in 3-D, 1e18 in 2-D, or it gives non-finite poses), the start is the
``odometry`` one and :attr:`Start.note` says so in one sentence, which the
solver lists among its recoveries.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import gtsam
import numpy as np

from graphslam.backends import bounded, deep_stack
from graphslam.backends import factorization as fact
from graphslam.backends.posegraph import factors as fx
from slamcore.errors import GraphSlamError
from slamcore.posegraph import PoseGraph, chain_initialisation, fixed_information


@dataclass
class Start:
    """An initial estimate. ``certificate``: Shonan's minimum eigenvalue (else None);
    ``note``: one sentence when the start asked for failed and this one replaces it
    (``--init vertices`` of a file without vertex lines among them)."""

    method: str
    values: gtsam.Values
    certificate: float | None = None
    note: str | None = None


#: The relaxations as a sentence names them.
NAMES = {"lago": "LAGO", "chordal": "the chordal relaxation", "shonan": "Shonan averaging"}


def resolve(method: str, dim: int) -> str:
    if method == "auto":
        return "lago" if dim == 2 else "chordal"
    if method == "lago" and dim != 2:
        raise GraphSlamError("--init lago is for 2-D graphs; use chordal (or shonan) in 3-D")
    if method == "chordal" and dim != 3:
        raise GraphSlamError("--init chordal is for 3-D graphs; use lago (or shonan) in 2-D")
    return method


def initial(
    graph: PoseGraph, method: str, sigma: float, should_stop: Callable[[], bool] | None = None
) -> Start:
    """The start named by ``method`` (``auto`` resolved by dimension); the
    ``odometry`` start with a :attr:`Start.note` where a relaxation fails, or where
    ``should_stop`` (a signal) ended Shonan's averaging."""
    method = resolve(method, graph.dim)
    if method == "vertices":
        if not np.any(graph.has_vertex):  # the reader composed them: the odometry start, named so
            note = "--init vertices: the file has no VERTEX line; LM started from the odometry start instead"
            return Start("odometry", fx.values_of(graph, graph.vertices), note=note)
        return Start(method, fx.values_of(graph, graph.vertices))
    if method == "odometry":
        return Start(method, fx.values_of(graph, chain_initialisation(graph)))
    # asked for by name, Shonan takes SE-Sync's isotropic weights where gtsam refuses
    # the file's; auto's retry does not (see route.retry_from_certified_rotations)
    start, failure = relaxed(graph, method, sigma, should_stop, isotropic_weights=True)
    if start is not None:
        return start
    return Start(
        "odometry",
        fx.values_of(graph, chain_initialisation(graph)),
        note=f"--init {method}: {why_no_start(method, failure)}; LM started from the odometry "
        "start (edges composed along a spanning tree) instead",
    )


def why_no_start(method: str, failure: str) -> str:
    """The clause that says why :func:`relaxed` gave no start, from its ``failure``."""
    if failure.startswith(f"{bounded.Stopped.__name__}:"):  # as :func:`_why` words it
        return f"a signal stopped {NAMES[method]}"
    return f"{NAMES[method]} failed ({failure})"


def relaxed(
    graph: PoseGraph,
    method: str,
    sigma: float,
    should_stop: Callable[[], bool] | None = None,
    isotropic_weights: bool = False,
) -> tuple[Start | None, str]:
    """The relaxation ``method`` (``lago``, ``chordal`` or ``shonan``) of ``graph``, or
    None and why it failed (no fallback: :func:`initial` chooses one). ``should_stop``
    ends Shonan's wait (a signal), which then counts as failed; ``isotropic_weights``:
    see :func:`_shonan`."""
    try:
        if method == "shonan":
            start = _shonan(graph, should_stop, isotropic_weights)
        else:
            start = _relaxation(graph, method, sigma)
    # gtsam's C++ exceptions: std::out_of_range (IndexError), std::invalid_argument
    # (ValueError: Shonan takes isotropic noise only), IndeterminateLinearSystem and the
    # rest (RuntimeError); anything else is a bug of ours and propagates
    except (RuntimeError, IndexError, ValueError) as exc:
        return None, _why(graph, exc)
    if not np.isfinite(fx.params_from(graph, start.values)).all():
        return None, "it gave non-finite poses"
    return at_anchor(graph, start), ""


def at_anchor(graph: PoseGraph, start: Start) -> Start:
    """``start`` moved rigidly so that the gauge's pose (the first ``FIX`` pose, else the
    first pose) stands at its vertex, as the vertices' and the odometry start leave it.
    The gauge prior holds that pose where the start puts it, and a relaxation may put it
    elsewhere: LAGO moved a graph in UTM coordinates 14.7 m off its first vertex, whole
    (hostile pass 14). A rigid motion changes no edge's error."""
    k = int(fx.anchors(graph)[0])
    vertex = fx.pose(graph.vertices[graph.index_of(np.array([k], dtype=np.int64))[0]], graph.rotation)
    at = start.values.atPose2 if graph.dim == 2 else start.values.atPose3
    T = vertex.compose(at(k).inverse())
    moved = gtsam.Values()
    for key in start.values.keys():
        moved.insert(key, T.compose(at(key)))
    return replace(start, values=moved)


def _why(graph: PoseGraph, exc: BaseException) -> str:
    """A short reason for a relaxation's failure, naming the pose (by id) gtsam names."""
    if fact.is_indeterminate(exc):
        where = fact.failed_variable(exc)
        if where.isdigit() and int(where) < graph.n_poses:  # a rank key: say the pose id
            where = f"pose {int(graph.ids[int(where)])}"
        return f"indeterminate linear system near {where or '?'}"
    first = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {first[0] if first else 'no message'}"


def has_odometric_path(graph: PoseGraph) -> bool:
    """Whether every pose but the first is joined by an edge to its predecessor in
    id order (LAGO's odometric path exists)."""
    rows = graph.index_of(graph.edges.ravel()).reshape(-1, 2)
    chained = np.unique(rows[graph.odometry_mask()].min(axis=1))
    return len(chained) == graph.n_poses - 1


def rank_keyed(graph: PoseGraph) -> PoseGraph:
    """``graph`` with each pose keyed by its rank (0..N-1) instead of its id."""
    rows = graph.index_of(graph.edges.ravel()).reshape(-1, 2)
    return replace(
        graph,
        ids=np.arange(graph.n_poses, dtype=np.int64),
        edges=rows,
        fixed=graph.index_of(graph.fixed).astype(np.int64),
    )


def _relaxation(graph: PoseGraph, method: str, sigma: float) -> Start:
    """LAGO (2-D) or the chordal relaxation (3-D) on the rank-keyed graph."""
    by_rank = rank_keyed(graph)
    # LAGO and the chordal relaxation take diagonal noise only: the diagonal of
    # each information matrix (a start, not the cost being minimised)
    pose_graph = gtsam.NonlinearFactorGraph()
    for e in range(graph.n_edges):
        pose_graph.add(fx.between(by_rank, e, fx.diagonal_model(graph.information[e])))
    # gtsam's LAGO roots its orientation tree at the first key and failed (IndexError:
    # map::at) with the prior on another (a FIX line naming pose 1): the start's gauge is
    # the first pose, and at_anchor moves it onto the FIX pose's vertex after
    anchor = 0 if method == "lago" else int(fx.anchors(by_rank)[0])
    pose_graph.add(fx.prior(by_rank, anchor, fx.pose(graph.vertices[anchor], graph.rotation), sigma))
    if method == "lago":
        values = deep_stack.call(gtsam.lago.initialize, pose_graph, has_odometric_path(graph))
    else:
        values = deep_stack.call(gtsam.InitializePose3.initialize, pose_graph)
    return Start(method, _by_id(graph, values))


def _by_id(graph: PoseGraph, values: gtsam.Values) -> gtsam.Values:
    """Rank-keyed ``values`` keyed by pose id."""
    at = values.atPose2 if graph.dim == 2 else values.atPose3
    out = gtsam.Values()
    for row, k in enumerate(graph.ids.tolist()):
        out.insert(k, at(row))
    return out


def _shonan(
    graph: PoseGraph, should_stop: Callable[[], bool] | None = None, isotropic_weights: bool = False
) -> Start:
    """Shonan rotations (certified or not), translations by a linear solve.

    Shonan indexes poses 0..N-1, so its factors are keyed by rank, not id. gtsam's
    Shonan takes a rotation noise that is isotropic, and refuses the file's where it
    is not (3-D graphs with anisotropic rotation information, sphere2500 among
    them). ``isotropic_weights`` gives it SE-Sync's isotropic weights of each edge
    there instead (the weights the certificate's problem has); the translations
    still take the file's information.
    """
    rows = graph.index_of(graph.edges.ravel()).reshape(-1, 2)
    info = graph.information
    if isotropic_weights and graph.dim == 3:  # the same weights where the file's are isotropic
        info = fixed_information(info, "isotropic", graph.dim)
    ranked = [
        (int(a), int(b), fx.pose(graph.measurements[e], graph.rotation), fx.noise_model(info[e]))
        for e, (a, b) in enumerate(rows)
    ]
    lm = gtsam.LevenbergMarquardtParams.CeresDefaults()
    shonan: gtsam.ShonanAveraging2 | gtsam.ShonanAveraging3
    if graph.dim == 2:
        shonan = gtsam.ShonanAveraging2(
            [gtsam.BetweenFactorPose2(*f) for f in ranked], gtsam.ShonanAveragingParameters2(lm)
        )
    else:
        shonan = gtsam.ShonanAveraging3(
            [gtsam.BetweenFactorPose3(*f) for f in ranked], gtsam.ShonanAveragingParameters3(lm)
        )
    R, min_eigenvalue = bounded.call(
        _run_shonan, shonan_budget_s(graph), shonan, _random_rotations(graph), graph, should_stop=should_stop
    )
    return Start("shonan", _with_translations(graph, R, rows), min_eigenvalue)


def shonan_budget_s(graph: PoseGraph) -> float:
    """Seconds Shonan averaging may take on ``graph``: :data:`SHONAN_BUDGET_BASE_S`
    and :data:`SHONAN_BUDGET_PER_EDGE_S` per edge."""
    return SHONAN_BUDGET_BASE_S + SHONAN_BUDGET_PER_EDGE_S * graph.n_edges


def _run_shonan(shonan, initial: gtsam.Values, graph: PoseGraph) -> tuple[np.ndarray, float]:
    """Shonan's rotations ((N, d, d), by rank) and its minimum eigenvalue; in the
    child process of :func:`.bounded.call`, so numpy out, not gtsam."""
    p_min = graph.dim
    rotations, min_eigenvalue = shonan.run(initial, p_min, p_min + 7)
    rot_of = rotations.atRot2 if graph.dim == 2 else rotations.atRot3
    R = np.array([np.asarray(rot_of(r).matrix()) for r in range(graph.n_poses)])
    return R, float(min_eigenvalue)


#: Seed of Shonan's random start. gtsam's own ``initializeRandomly`` draws from
#: one generator shared by the whole process, so the same graph got a different
#: start (and estimate, and run time) after any other Shonan call; in one CI
#: run a Shonan call, likely from a start drawn that way, ran past ten minutes.
SHONAN_START_SEED = 0
#: Shonan's budget is this plus :data:`SHONAN_BUDGET_PER_EDGE_S` per edge. Timed
#: on this project's two-core machine: a 300-pose Manhattan walk 1-4 s (about
#: 10 ms an edge), w10000 68 s (1 ms an edge), Bovisa04's 11 589 edges 102 s
#: (9 ms an edge, then it failed). Five times the slowest per edge, so that only
#: a run that has run away meets it.
SHONAN_BUDGET_BASE_S = 60.0
SHONAN_BUDGET_PER_EDGE_S = 0.05


def _random_rotations(graph: PoseGraph) -> gtsam.Values:
    """Uniformly random rotations, rank-keyed, from :data:`SHONAN_START_SEED`:
    the same graph always starts Shonan from the same rotations."""
    rng = np.random.default_rng(SHONAN_START_SEED)
    values = gtsam.Values()
    if graph.dim == 2:
        for row, angle in enumerate(rng.uniform(-np.pi, np.pi, graph.n_poses).tolist()):
            values.insert(row, gtsam.Rot2.fromAngle(angle))
    else:  # a normalised 4-D Gaussian is a uniform unit quaternion
        q = rng.standard_normal((graph.n_poses, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        for row, (w, x, y, z) in enumerate(q.tolist()):
            values.insert(row, gtsam.Rot3.Quaternion(w, x, y, z))
    return values


def _with_translations(graph: PoseGraph, R: np.ndarray, rows: np.ndarray) -> gtsam.Values:
    """Poses from fixed rotations ``R`` (N, d, d): translations by weighted least
    squares on ``t_b - t_a = R_a t_ab`` (the translation block of the information
    as weight), the first pose at the origin."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    d, n = graph.dim, graph.n_poses
    r_idx, c_idx, vals = [], [], []
    rhs = np.zeros(graph.n_edges * d + d)
    for e, (ia, ib) in enumerate(rows.tolist()):
        W = np.linalg.cholesky(graph.information[e][:d, :d]).T  # whitens the translation
        for i in range(d):
            for j in range(d):
                r_idx += [e * d + i, e * d + i]
                c_idx += [ib * d + j, ia * d + j]
                vals += [W[i, j], -W[i, j]]
        rhs[e * d : e * d + d] = W @ (R[ia] @ graph.measurements[e, :d])
    for i in range(d):  # gauge
        r_idx.append(graph.n_edges * d + i)
        c_idx.append(i)
        vals.append(1.0)
    A = coo_matrix((vals, (r_idx, c_idx)), shape=(len(rhs), n * d)).tocsr()
    t = spsolve((A.T @ A).tocsc(), A.T @ rhs).reshape(-1, d)
    values = gtsam.Values()
    for row, k in enumerate(graph.ids.tolist()):
        if d == 2:
            values.insert(k, gtsam.Pose2(gtsam.Rot2.fromCosSin(R[row][0, 0], R[row][1, 0]), t[row]))
        else:
            values.insert(k, gtsam.Pose3(gtsam.Rot3(R[row]), t[row]))
    return values
