"""Run a pose-graph file through the pose-graph solver; metrics and outputs.

2-D and 3-D alike. Outputs: ``trajectory.tum`` (time column = pose id),
``graph.g2o`` or ``graph.graph`` (the input's format and dimension, vertices at
the estimate), ``closures.csv`` and ``metrics.json``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from graphslam.backends.posegraph.config import PoseGraphConfig
from graphslam.backends.posegraph.solver import SolveResult, solve
from graphslam.evaluation.planar import ate_ratio_warning
from graphslam.evaluation.records import MetricsRecord, optional
from graphslam.outputs.writers import OutputWrites
from graphslam.pipelines.common import interrupt_between_frames, signal_hook, stop_requested
from slamcore import posegraph as pg
from slamcore.errors import GraphSlamError, InputError
from slamcore.files import atomic_open

#: What Shonan's certificate covers, written next to it in ``metrics.json``.
SHONAN_CERTIFIES = (
    "a minimum eigenvalue >= 0 (to numerical tolerance) proves the rotation "
    "averaging relaxation tight, i.e. the start's rotations globally optimal for "
    "the chordal rotation cost; it does not certify the final pose-graph cost "
    "under the file's full information, which LM minimises locally from there"
)


@dataclass
class PoseGraphRunMetrics(MetricsRecord):
    """``metrics.json`` of a pose-graph run; costs are ``0.5 sum ||whitened
    residual||^2`` over the file's edges (the gtsam graph error), and
    ``final_cost_kept`` the same over the edges kept when closures were rejected
    (the cost the solve minimised). ``closure_test``: the outlier test of the
    closures (``robust_closures``, the whitened residual norm beyond which a
    closure fails, the re-test rounds), absent when closures were not tested.
    ``certificate``: SE-Sync's certificate of the estimate
    (:meth:`graphslam.backends.posegraph.certificate.Certificate.to_dict`), or
    ``{"certified": null, "unchecked": why}``; absent when ``certify`` is off or a
    stop cut the solve. ``warnings``: the reader's doubts about the file
    (:attr:`slamcore.posegraph.PoseGraph.warnings`), absent when none."""

    dataset: str
    backend: str
    dim: int
    format: str
    poses: int
    edges: int
    closures: int
    closures_rejected: int
    init: str
    initial_cost: float
    final_cost: float
    iterations: int | None
    wall_s: float
    backend_s: float
    isam2_cost: float | None = optional()
    isam2_s: float | None = optional()
    shonan_min_eigenvalue: float | None = optional()
    shonan_certifies: str | None = optional()
    numerical_recoveries: list[str] | None = optional()
    information_fixed: dict | None = optional()
    noise: str | None = optional()
    closure_test: dict | None = optional()
    #: the file's poses when a stop cut the solve (``poses`` are those solved)
    poses_in_file: int | None = optional()
    route: dict | None = optional()
    self_edges_ignored: dict | None = optional()
    equiv_ignored: int | None = optional()
    final_cost_kept: float | None = optional()
    certificate: dict | None = optional()
    ate_rmse_m: float | None = None
    odometry_ate_rmse_m: float | None = None
    ate_poses: int | None = optional()
    interrupted: bool = False
    converged: bool = True
    warnings: list[str] | None = optional()
    #: what ran (as :class:`~graphslam.evaluation.records.PlanarRunMetrics`)
    provenance: dict | None = optional()


def run(
    graph: pg.PoseGraph,
    solver: str = "isam2",
    config: PoseGraphConfig | None = None,
    progress: Callable[[str, int], None] | None = None,
) -> SolveResult:
    """Optimise ``graph``; see :func:`graphslam.backends.posegraph.solver.solve`.

    SIGINT or SIGTERM between iSAM2 updates ends the solve with the poses added
    so far (``result.cut``); during the batch part (LM, GNC) it ends it after the
    iteration it came in, the estimate in hand then whole (``result.stopped``). A
    whole estimate is then certified when ``config.certify`` (``result.optimality``;
    not after a stop). ``progress(point, step)``: told at every stop check
    (:class:`~graphslam.pipelines.progress.SolveProgress`).
    """
    config = config or PoseGraphConfig()
    tell = progress if progress is not None else (lambda point, step: None)
    with interrupt_between_frames() as stop:

        def should_stop(point: str, step: int) -> bool:
            signal_hook(point, step)
            tell(point, step)
            return stop.requested

        def stop_in(point: str) -> Callable[[], bool]:  # (no signal hook: none was placed there)
            def check() -> bool:
                tell(point, 0)
                return stop.requested

            return check

        result = solve(graph, config, solver, should_stop)
        signal_hook("finalize")
        if config.certify and result.cut is None and not stop.requested:
            certify(graph, result, stop_in("certificate"))
            if (
                solver == "auto"
                and result.optimality is not None
                and not result.optimality.certified
                and not stop.requested
            ):
                result = _retried(graph, config, result, stop_in("init"))
    return result


def _retried(
    graph: pg.PoseGraph, config: PoseGraphConfig, result: SolveResult, should_stop: Callable[[], bool]
) -> SolveResult:
    """``auto``'s estimate that failed the certificate, or batch from Shonan's
    rotations where that costs less (:func:`.route.retry_from_certified_rotations`),
    certified in turn."""
    from graphslam.backends.posegraph import route

    try:
        retried = route.retry_from_certified_rotations(graph, config, solve, result, should_stop)
    except (GraphSlamError, RuntimeError, IndexError, MemoryError) as exc:
        # a second opinion that fails leaves the first estimate, whole and written
        result.route = {
            **(result.route or {}),
            "shonan_retry": (
                f"not certified; batch from Shonan's rotations failed ({type(exc).__name__}: "
                f"{' '.join(str(exc).split())})"
            ),
        }
        return result
    if retried is not result and not should_stop():
        certify(graph, retried, should_stop)
    return retried


#: The certificate's refinement may take this many times the solve's wall time, and at
#: least REFINE_BUDGET_MIN_S: from far off it can take many times the solve (a 3-D grid
#: of 8000 poses: 500 s). A wall-clock budget makes the certificate depend on the
#: machine's load, so it is set well above what the refinement takes on the graphs
#: measured (sphere2500: 12 iterations in 1.4-2.1 s after a 1-3.8 s solve; under three
#: busy loops a budget of one solve's time stopped it at 11 iterations, not certified):
#: only a refinement five times slower than usual meets it, and the summary says so.
REFINE_BUDGET_SOLVES, REFINE_BUDGET_MIN_S = 3.0, 10.0


def certify(graph: pg.PoseGraph, result: SolveResult, should_stop: Callable[[], bool] | None = None) -> None:
    """Fill ``result.optimality`` (or ``optimality_unchecked``) for ``result``'s kept
    edges; ``should_stop`` (a signal) ends the check between refinement iterations."""
    from graphslam.backends.posegraph import certificate

    keep = ~result.rejected
    result.optimality_unchecked = certificate.uncheckable(graph, keep)
    if result.optimality_unchecked is not None:
        return
    try:
        budget_s = max(REFINE_BUDGET_SOLVES * result.wall_s, REFINE_BUDGET_MIN_S)
        result.optimality = certificate.certify(
            graph, result.params, keep, budget_s=budget_s, should_stop=should_stop
        )
    except certificate.CheckInterrupted as exc:  # the outputs are written at once
        result.optimality_unchecked = str(exc)
    except (RuntimeError, MemoryError) as exc:  # gtsam's indeterminate system, a huge fill
        # the check is a report on a finished solve: it never costs the run its outputs
        result.optimality_unchecked = f"the check failed ({type(exc).__name__}: {exc})"


def solved_graph(graph: pg.PoseGraph, result: SolveResult) -> pg.PoseGraph:
    """The graph ``result`` covers: ``graph``, or the poses solved before a stop."""
    return graph if result.cut is None else result.cut


def ground_truth_of(graph: pg.PoseGraph, truth) -> tuple[np.ndarray, np.ndarray]:
    """``(ids (M,), wTc (M, 4, 4))``: the truth of the graph's poses by pose id
    (TUM time column, KITTI line number); InputError when none matches."""
    from graphslam.sources.ground_truth import rows_by_pose_id

    rows = rows_by_pose_id(truth, graph.ids)
    if not np.any(rows >= 0):
        raise InputError(f"no pose of {graph.name!r} has ground truth (matched by pose id)", truth.path)
    return graph.ids[rows >= 0], np.asarray(truth.wTc)[rows[rows >= 0]]


def ate_rmse(graph: pg.PoseGraph, params: np.ndarray, truth: tuple[np.ndarray, np.ndarray]) -> float:
    """Aligned ATE RMSE (SE(2) in 2-D, SE(3) in 3-D) of ``params`` against ``truth``."""
    from graphslam.evaluation import planar, spatial

    gt_ids, gt_wTc = truth
    T = trajectory_matrices(graph, params)
    if graph.dim == 3:
        return spatial.ate(graph.ids, T, gt_ids, gt_wTc)["rmse_m"]
    return planar.ate(graph.ids, _xy_yaw(T), gt_ids, _xy_yaw(gt_wTc))["rmse_m"]


def _xy_yaw(T: np.ndarray) -> np.ndarray:
    return np.column_stack([T[:, 0, 3], T[:, 1, 3], np.arctan2(T[:, 1, 0], T[:, 0, 0])])


def in_plane(T: np.ndarray) -> np.ndarray:
    """Poses (N, 4, 4) as a 2-D run scores them: x, y and the yaw, at height 0. What a 2-D
    graph's ``ground_truth.tum`` holds, so that scoring the files gives the run's ATE."""
    xy_yaw = _xy_yaw(np.asarray(T, dtype=np.float64).reshape(-1, 4, 4))
    out = np.tile(np.eye(4), (len(xy_yaw), 1, 1))
    c, s = np.cos(xy_yaw[:, 2]), np.sin(xy_yaw[:, 2])
    out[:, 0, 0], out[:, 0, 1], out[:, 1, 0], out[:, 1, 1] = c, -s, s, c
    out[:, 0, 3], out[:, 1, 3] = xy_yaw[:, 0], xy_yaw[:, 1]
    return out


def _untested(result) -> dict | None:
    """``closure_test`` of a solve whose closures were suspects but never tested (iSAM2
    without its polish, or cut by a signal before it: they went in under the Cauchy
    kernel), else None (none suspect)."""
    if result.robust_mode is None:
        return None
    # a cut iSAM2 run said 'robust_closures = "none": every closure kept' (hostile pass 20)
    return {
        "robust_closures": result.robust_mode,
        "tested": False,
        **({"stopped": "incremental"} if result.cut else {}),
    }


def closures_tested(result) -> bool:
    """Whether the outlier test decided the closures (``closures.csv``'s ``tested``)."""
    return result.closure_threshold is not None and result.cut is None and result.stopped not in ("lm", "gnc")


#: Stated sigmas this many times the residuals' (``noise_overstated``) mean edges that
#: agree to round-off: float64 residuals of poses a metre apart are ~1e-16 m, and no
#: sensor's noise is stated a million times its error.
EXACT_EDGES_FACTOR = 1e6


def stalled_warning(graph: pg.PoseGraph, result: SolveResult, alpha: float) -> list[str]:
    """One line when the final LM took no step (0 iterations, the cost unchanged) from a
    start whose cost the stated noise cannot explain: the estimate is that start, not an
    optimum (hostile pass 17: every edge's information times 1e12 left LAGO's and LM's
    systems indeterminate; the trajectory was the odometry, 19 m from the optimum, and the
    one line blamed the closures)."""
    from graphslam.backends.posegraph.route import consistent

    if result.iterations != 0 or result.cut is not None or result.stopped is not None:
        return []
    if result.stationary_start:  # the start was already an optimum: nothing to take a step to
        return []
    if result.rejected.any():  # the final LM solved the kept edges: another cost than the start's
        return []
    if not result.final_cost >= result.initial_cost or consistent(graph, result, alpha)[0]:
        return []
    return [
        f"the solver took no step from its start (0 LM iterations, the cost unchanged at "
        f"{result.final_cost:.6g}, beyond what the stated noise explains): the estimate is that "
        "start, not an optimum; information of an extreme scale can leave the solver's linear "
        "systems indeterminate (the numerical recoveries say where)"
    ]


def closures_warning(graph: pg.PoseGraph, result: SolveResult, alpha: float) -> list[str]:
    """One line when the solve's kept edges leave a cost the stated noise cannot explain
    at an optimum (the chi-square test the auto route applies), in a graph with closures:
    trusted untested (``robust_closures = "none"``: RRR's Bovisa04 ended 84 m from GPS,
    quietly) or kept by the closure test (a wrong closure 10^4 times too confident bends
    the odometry until its own residual is small: 15.1 m ATE against 1.3 m of dead
    reckoning, quietly, hostile pass 14). Also one line when that cost lies below the
    chi-square lower tail: the noise is stated larger than the data's and the closure
    test cannot reject a wrong closure within the excess (information x 1e-6: 0 of 57
    closures rejected against 45, quietly, hostile pass 15). Nothing without
    closures or after a stop."""
    from graphslam.backends.posegraph.route import consistent, noise_overstated

    if not (~graph.odometry_mask()).any() or result.cut is not None or result.stopped is not None:
        return []  # a solve a signal stopped is at no optimum: the test does not apply
    low = noise_overstated(graph, result)
    if low is not None:
        # sigmas stated f times the data's: a closure e data-sigmas off reads e / f
        factor, sentence = low
        if not factor < EXACT_EDGES_FACTOR:  # inf (cost 0) or round-off: no noise to measure
            return [
                f"{sentence}: the edges agree to round-off (a graph made without noise, its measurements "
                "the poses' own relative poses), so their residuals measure no noise and the "
                "closure test, in stated sigmas, says nothing of the data's"
            ]
        said = (
            f"{sentence}: the noise is stated about {factor:.3g}x larger in sigma than the "
            "residuals show (sqrt(degrees of freedom / (2 x cost)))"
        )
        if result.closure_threshold is None:
            return [f"{said}; a wrong closure would not stand out of it"]
        return [
            f"{said}, so the closure test, which measures in stated sigmas, passes a wrong "
            f"closure up to about {factor:.3g}x its threshold off in the data's own noise"
        ]
    ok, sentence = consistent(graph, result, alpha)
    if ok:
        return []
    if result.robust_mode is None:
        return [
            f"the closures were trusted untested and {sentence}: a wrong closure (or noise stated "
            'smaller than the data\'s) bends the graph; robust_closures = "auto" tests them'
        ]
    if result.closure_threshold is None:  # iSAM2 without its polish: Cauchy kernel, no test
        return [
            f"the closures went in under iSAM2's Cauchy kernel, untested (no polish), and {sentence}: "
            "a wrong closure (or noise stated smaller than the data's) bends the graph; the polish tests them"
        ]
    return [
        f"after the closure test, {sentence}: an edge it kept does not fit the stated noise "
        "(a wrong closure too confident to fail the test bends the graph, or the noise is stated "
        "smaller than the data's)"
    ]


def metrics(
    graph: pg.PoseGraph,
    result: SolveResult,
    wall_s: float,
    truth: tuple[np.ndarray, np.ndarray] | None = None,
    closure_test_alpha: float | None = None,
) -> PoseGraphRunMetrics:
    """The run's metrics; ATE of the estimate and of the odometry chain when ``truth``
    (of the poses solved, when a stop cut the solve); ``closure_test_alpha``: the
    run's (default: the config's), for :func:`closures_warning`."""
    alpha = PoseGraphConfig().closure_test_alpha if closure_test_alpha is None else closure_test_alpha
    in_file = graph.n_poses
    graph = solved_graph(graph, result)
    stalled = stalled_warning(graph, result, alpha)
    # ATE needs two poses with truth: a run cut after its first pose has none (null)
    scored = truth is not None and np.isin(truth[0], graph.ids).sum() >= 2
    closures = ~graph.odometry_mask()
    shonan = result.certificate
    ate_m = None if truth is None or not scored else ate_rmse(graph, result.params, truth)
    odometry_ate_m = (
        None if truth is None or not scored else ate_rmse(graph, pg.chain_initialisation(graph), truth)
    )
    return PoseGraphRunMetrics(
        dataset=graph.name,
        backend=result.solver,
        dim=graph.dim,
        format=graph.format,
        poses=graph.n_poses,
        poses_in_file=in_file if graph.n_poses != in_file else None,
        edges=graph.n_edges,
        closures=int(closures.sum()),
        closures_rejected=int(result.rejected.sum()),
        init=result.init_method,
        initial_cost=result.initial_cost,
        final_cost=result.final_cost,
        iterations=result.iterations,
        wall_s=wall_s,
        backend_s=result.wall_s,
        isam2_cost=result.isam2_cost,
        isam2_s=result.isam2_s,
        shonan_min_eigenvalue=shonan,
        shonan_certifies=None if shonan is None else SHONAN_CERTIFIES,
        numerical_recoveries=result.recoveries or None,
        information_fixed=(
            {"method": graph.information_fix, "edges": graph.n_information_fixed}
            if graph.n_information_fixed
            else None
        ),
        # how a TORO file's edge numbers were read, when a known file decided it
        noise=graph.noise_note,
        closure_test=_untested(result)
        if result.closure_threshold is None
        else {
            "robust_closures": result.robust_mode,
            "threshold_whitened": result.closure_threshold,
            "noise_scale_squared": result.noise_scale,
            "retest_rounds": result.closure_rounds,
            # only after a stop: which part of the solve it ended (the test may not have run)
            **({"stopped": result.stopped} if result.stopped is not None else {}),
        },
        equiv_ignored=len(graph.equiv) or None,
        self_edges_ignored=(
            {"edges": len(graph.self_edge_lines), "lines": graph.self_edge_lines[:10].tolist()}
            if len(graph.self_edge_lines)
            else None
        ),
        route=result.route,
        final_cost_kept=result.final_cost_kept if result.rejected.any() else None,
        certificate=_certificate_of(result),
        ate_rmse_m=ate_m,
        # how many poses the ATE covers: truth may cover a tenth of them (RRR's GPS)
        ate_poses=None if truth is None else int(np.isin(truth[0], graph.ids).sum()),
        odometry_ate_rmse_m=odometry_ate_m,
        interrupted=(stopped := result.cut is not None or stop_requested()),
        # a solve cut by a signal did not converge, whatever its last step did
        converged=not stopped and not result.lm_capped and not stalled,
        # the reader's doubts about the file (degrees, non-unit quaternions, repeats)
        warnings=[
            *graph.warnings,
            *stalled,
            *closures_warning(graph, result, alpha),
            *split_warning(graph, result),
            *lone_closure_warning(graph, result),
            *ate_ratio_warning(ate_m, odometry_ate_m),
        ]
        or None,
    )


def lone_closure_warning(graph: pg.PoseGraph, result: SolveResult) -> list[str]:
    """One line naming the kept closures that alone join two parts of the graph (its
    odometry chains): no other edge can contradict such a closure, so the outlier test
    keeps it whatever it says. Two sessions joined by three wrong closures, one kept,
    were reported certified with the second session 16 m off (twentieth hostile pass)."""
    if not closures_tested(result):
        return []
    rows = graph.index_of(graph.edges.ravel()).reshape(-1, 2)
    kept, odometry = ~result.rejected, graph.odometry_mask()
    pieces = pg.components(graph.n_poses, rows[kept & odometry])
    if len(pieces) < 2:
        return []
    piece_of = np.empty(graph.n_poses, dtype=np.int64)
    for i, p in enumerate(pieces):
        piece_of[p] = i
    links = [int(e) for e in np.flatnonzero(kept & ~odometry) if piece_of[rows[e, 0]] != piece_of[rows[e, 1]]]
    lone = [
        links[k] for k in bridges(len(pieces), [(piece_of[rows[e, 0]], piece_of[rows[e, 1]]) for e in links])
    ]
    if not lone:
        return []
    named = ", ".join(
        f"{a}-{b} (line {int(graph.edge_lines[e])})" for e in lone[:5] for a, b in [graph.edges[e]]
    )
    more = f" and {len(lone) - 5} more" if len(lone) > 5 else ""
    return [
        f"{len(lone)} kept closure{'s' if len(lone) > 1 else ''} alone join{'' if len(lone) > 1 else 's'} "
        f"parts of the graph ({named}{more}): no other edge can contradict "
        f"{'them' if len(lone) > 1 else 'it'}, so the outlier test cannot tell a wrong one"
    ]


def bridges(n: int, links: list[tuple[int, int]]) -> list[int]:
    """Indices into ``links`` ((a, b) node pairs of a multigraph on ``n`` nodes) of its
    bridges: links whose removal disconnects their ends. Tarjan's low-link DFS,
    iterative (written here: scipy's csgraph has no bridge search, and a graph of
    sessions is small, but a recursive DFS would not be bounded by it)."""
    adjacent: list[list[tuple[int, int]]] = [[] for _ in range(n)]
    for k, (a, b) in enumerate(links):
        adjacent[a].append((b, k))
        adjacent[b].append((a, k))
    order, low = [-1] * n, [0] * n
    out, counter = [], 0
    for root in range(n):
        if order[root] >= 0:
            continue
        order[root] = low[root] = counter
        counter += 1
        stack = [(root, -1, iter(adjacent[root]))]
        while stack:
            node, via, it = stack[-1]
            step = next(it, None)
            if step is None:
                stack.pop()
                if stack:
                    parent = stack[-1][0]
                    low[parent] = min(low[parent], low[node])
                    if low[node] > order[parent]:
                        out.append(via)
                continue
            other, k = step
            if k == via:
                continue
            if order[other] < 0:
                order[other] = low[other] = counter
                counter += 1
                stack.append((other, k, iter(adjacent[other])))
            else:
                low[node] = min(low[node], order[other])
    return sorted(out)


def split_warning(graph: pg.PoseGraph, result: SolveResult) -> list[str]:
    """One line when the rejected closures were every link between parts of the graph:
    the kept edges leave it in pieces, each placed against the others by the start alone.
    Two sessions joined by three wrong closures gave a second session 7 m off, with only
    the optimality row's "not checked" (twentieth hostile pass)."""
    if not result.rejected.any() or result.cut is not None:
        return []
    rows = graph.index_of(graph.edges[~result.rejected].ravel()).reshape(-1, 2)
    parts = pg.components(graph.n_poses, rows)
    if len(parts) < 2:
        return []
    return [
        f"the rejected closures were every link between parts of the graph: the kept edges "
        f"leave it in {len(parts)} parts ({pg.describe_components(graph.ids, parts)}), each placed "
        "against the others by the start alone, not by any edge (if those closures are right, "
        'run with [posegraph] robust_closures = "none")'
    ]


def _certificate_of(result: SolveResult) -> dict | None:
    """``metrics.json``'s ``certificate`` (see :class:`PoseGraphRunMetrics`)."""
    if result.optimality is not None:
        return result.optimality.to_dict()
    if result.optimality_unchecked is not None:
        return {"certified": None, "unchecked": result.optimality_unchecked}
    return None


def trajectory_matrices(graph: pg.PoseGraph, params: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses (2-D ones lifted to the plane z = 0)."""
    T = pg.params_to_matrix(params, graph.rotation)
    if graph.dim == 3:
        return T
    out = np.repeat(np.eye(4)[None], len(T), axis=0)
    out[:, :2, :2], out[:, :2, 3] = T[:, :2, :2], T[:, :2, 2]
    return out


def write_outputs(
    graph: pg.PoseGraph,
    result: SolveResult,
    out_dir: Path,
    run_metrics: PoseGraphRunMetrics,
    truth: tuple[np.ndarray, np.ndarray] | None = None,
    writes: OutputWrites | None = None,
) -> dict[str, Path]:
    """Write trajectory, graph, closures, metrics (and ``ground_truth.tum`` of the
    poses with truth, same time column); return the paths written.

    ``writes``: the command's :class:`~graphslam.outputs.writers.OutputWrites`, which
    notes a file the file system refuses and goes on (its caller checks it once every
    output was tried); without it, GraphSlamError once all were tried."""
    from graphslam.outputs import posegraph as graph_writer
    from graphslam.outputs import writers

    graph = solved_graph(graph, result)

    writes, own = writers.writes_for(out_dir, writes)
    paths: dict[str, Path] = {}
    writes(
        paths,
        "trajectory",
        out_dir / "trajectory.tum",
        writers.write_tum_spatial,
        np.asarray(graph.ids, dtype=np.int64),
        trajectory_matrices(graph, result.params),
    )
    signal_hook("write")
    if stop_requested():  # asked while the outputs are written: say so in them
        run_metrics.interrupted = True
    graph_path = out_dir / ("graph" + graph_writer.EXTENSIONS[graph.format])
    # numbers as information whatever the input held (sphere2500's square roots, written
    # as read, came back as information from graph.graph: other weights, unsaid)
    solved = replace(graph.with_vertices(result.params), noise="information")
    writes(paths, "graph", graph_path, graph_writer.write_pose_graph, solved)
    writes(paths, "closures", out_dir / "closures.csv", write_closures_csv, graph, result)
    writes(paths, "metrics", out_dir / "metrics.json", writers.write_json, run_metrics.to_dict())
    if truth is not None:
        ids = np.asarray(truth[0], dtype=np.int64)
        writes(paths, "ground_truth", out_dir / "ground_truth.tum", writers.write_tum_spatial, ids, truth[1])
    if own:
        writes.check(paths.values())
    return paths


def write_closures_csv(path: Path, graph: pg.PoseGraph, result: SolveResult) -> None:
    """Every non-odometry edge: ``from,to,line,kept,whitened_residual,tested`` (``tested``
    0: kept without the outlier test, by setting, without the polish or after a stop)."""
    closures = np.flatnonzero(~graph.odometry_mask())
    tested = int(closures_tested(result))
    with atomic_open(path, "w", encoding="utf-8") as f:
        f.write("from,to,line,kept,whitened_residual,tested\n")
        for e in closures.tolist():
            a, b = graph.edges[e].tolist()
            f.write(
                f"{a},{b},{int(graph.edge_lines[e])},{int(not result.rejected[e])},"
                f"{result.residuals[e]:.9g},{tested}\n"
            )
