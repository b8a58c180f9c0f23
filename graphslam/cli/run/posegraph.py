"""``graphslam run`` on a pose-graph file (g2o or TORO, 2-D or 3-D) with the
``isam2`` or ``batch`` pose-graph solver."""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from graphslam.cli.common import (
    fmt,
    provenance,
    report_outputs,
    summary_table,
    warn,
    warn_run_doubts,
    warn_unread_sections,
)
from graphslam.cli.out_folder import OutputFolder
from slamcore.errors import ConfigError, GraphSlamError

#: Outputs of a pose-graph run (an earlier run's files of these names are removed).
OUTPUTS = {"trajectory.tum", "graph.g2o", "graph.graph", "closures.csv", "metrics.json", "ground_truth.tum"}


def refuse_ignored_flags(args: argparse.Namespace) -> None:
    """Flags a pose-graph solve cannot use are refused, one line each."""
    for flag in ("frontend", "odometry", "odometry_noise", "vocab", "rerun_every", "seed", "intrinsics"):
        if getattr(args, flag, None) is not None:
            raise ConfigError(
                f"--{flag.replace('_', '-')} does not apply to a pose-graph "
                "solve (nothing is random or streamed)"
            )
    for flag in ("save_map", "map"):
        if getattr(args, flag, None) is not None:
            raise ConfigError(
                f"--{flag.replace('_', '-')} applies to landmark runs and image "
                "sequences, not to a pose-graph solve"
            )
    if getattr(args, "frames", None) is not None:
        raise ConfigError(
            "--frames applies to image sequences only (--max-steps N keeps a pose graph's first N poses)"
        )
    if getattr(args, "nees", False):
        raise ConfigError(
            "--nees applies to streamed 2-D runs: a pose-graph solve computes no per-pose "
            "covariance to score (a filter, --backend ekf, streams a 2-D graph and scores it)"
        )
    if args.max_steps is not None and args.max_steps < 2:
        raise ConfigError("--max-steps must be at least 2 for a pose graph (one edge)")
    if args.loops:
        raise ConfigError("--loops applies to image sequences only (pose graphs bring their own closures)")
    if getattr(args, "relocalise", False):
        raise ConfigError("--relocalise applies to image sequences only")


def run(args: argparse.Namespace) -> int:
    """Solve the pose graph named by ``--dataset``; returns the exit status."""
    from graphslam import registry
    from graphslam.outputs.writers import OutputWrites, one_run_or_the_other
    from graphslam.pipelines import posegraph as pipeline

    t0 = time.perf_counter()
    refuse_ignored_flags(args)
    config = registry.read_config(args.config)
    overrides = {}
    if args.init is not None:
        overrides["init"] = args.init
    if args.no_polish:
        registry.check_no_polish(args.backend)
        overrides["polish"] = False
    solver_config = registry.pose_graph_config(config, overrides)
    polished = registry.backend_row(args.backend).polish  # iSAM2, then a batch polish
    if args.init is not None and polished and not solver_config.polish:
        raise ConfigError(
            "--init starts the batch polish after iSAM2, and the polish is off (--no-polish or "
            "[posegraph] polish = false): iSAM2's estimate is the answer"
        )
    graph, truth = load_graph(args.dataset, solver_config, args.max_steps, args.ground_truth)
    from graphslam.sources.builtin_posegraphs import is_builtin_pose_graph

    # a built-in graph is read by its own reader, a g2o file has no TORO convention
    toro_read = graph.format == "toro" and not is_builtin_pose_graph(args.dataset)
    mark_unread_settings(config, args.backend, solver_config, toro_read)
    for doubt in graph.warnings:  # the reader's; metrics.json keeps them too
        warn(doubt)
    out_dir = args.resolved_out = args.out or Path("runs") / f"{graph.name}-{args.backend}"
    folder = OutputFolder(out_dir, OUTPUTS | ({"run.rrd"} if args.rerun == "save" else set()))
    from graphslam.pipelines.progress import SolveProgress

    tracker = SolveProgress(enabled=not args.quiet)
    try:
        result = pipeline.run(graph, args.backend, solver_config, progress=tracker)
    finally:
        tracker.close()
    metrics = pipeline.metrics(
        graph, result, time.perf_counter() - t0, truth, solver_config.closure_test_alpha
    )
    if not result.lm_ran:  # iSAM2 without its polish, its factorisation never failing
        config.mark_inert(
            "posegraph",
            LM_KEYS,
            "a batch LM (polish = true, --backend batch or auto; iSAM2 alone reads them only "
            "where its factorisation fails)",
        )
    metrics.provenance = provenance(args, config)
    out_dir = args.resolved_out = folder.resolve()
    # a full disk part way: no earlier run's file left beside this run's
    writes = OutputWrites(out_dir)  # a file the disk refuses costs no other: each is tried
    with one_run_or_the_other(out_dir, tuple(sorted(OUTPUTS | {"run.rrd"}))):
        paths = pipeline.write_outputs(graph, result, out_dir, metrics, truth, writes)
        if args.rerun != "off":
            record(args, graph, result, folder, paths)
    folder.finish(paths)
    warn_unread_sections(config, args.config, "this pose-graph run")
    warn_run_doubts(metrics.warnings, said=graph.warnings)  # the reader's were said above
    status = report_outputs(format_summary(metrics), out_dir, paths, metrics.interrupted, writes=writes)
    writes.check(paths.values())
    return status


#: the ``[posegraph]`` keys only a batch LM reads
LM_KEYS = ("max_iterations", "relative_error_tol", "absolute_error_tol")


def mark_unread_settings(config, solver: str, settings, toro_read: bool) -> None:
    """Mark the file's ``[posegraph]`` settings that this solve does not read (said with
    the gates', :meth:`slamcore.config.ConfigFile.inert_lines`): iSAM2's under the batch
    solver, the polish's start with iSAM2 unpolished, the TORO convention on a g2o file.
    ``auto`` may run either solver, so it marks none of theirs."""
    from graphslam import registry

    row = registry.backend_row(solver)
    config.mark_inert("posegraph", row.pose_graph_unread, "the isam2 or auto solver (--backend isam2)")
    if row.polish and not settings.polish:
        # the certificate's retry starts from the certified rotations, never from `init`
        config.mark_inert("posegraph", ("init",), "polish = true (the start of the batch polish)")
    if not toro_read:
        config.mark_inert("posegraph", ("toro_noise",), "TORO files (.graph)")


def load_graph(dataset: str, solver_config, max_steps: int | None = None, ground_truth: Path | None = None):
    """``(graph, truth or None)`` of ``--dataset`` (a file or a built-in pose graph, whose
    truth comes with it), cut to ``max_steps`` poses; ``ground_truth``: a trajectory file
    matched by pose id."""
    from graphslam import registry
    from graphslam.pipelines import posegraph as pipeline
    from graphslam.sources.builtin_posegraphs import builtin_pose_graph, is_builtin_pose_graph

    truth = None
    if is_builtin_pose_graph(dataset):
        graph, truth = builtin_pose_graph(dataset)  # city10000's truth comes with it
    else:
        graph = registry.load_pose_graph(dataset, solver_config.toro_noise, solver_config.information_fix)
    if max_steps is not None:
        from graphslam.sources.posegraph_files import truncated

        graph = truncated(graph, max_steps)
    if truth is not None:
        keep = np.isin(truth[0], graph.ids)
        truth = (truth[0][keep], truth[1][keep]) if keep.sum() >= 2 else None
    if ground_truth is not None:
        from graphslam.sources.ground_truth import off_plane, read_trajectory

        truth = pipeline.ground_truth_of(graph, read_trajectory(ground_truth))
        if graph.dim == 2:  # scored in the plane: said when that drops something, written as scored
            doubt = off_plane(truth[1])
            if doubt is not None:
                graph = dataclasses.replace(graph, warnings=(*graph.warnings, doubt))
            truth = (truth[0], pipeline.in_plane(truth[1]))
    return graph, truth


def record(args, graph, result, folder: OutputFolder, paths: dict[str, Path]) -> None:
    """Rerun recording of the optimised graph, rejected closures in their own colour
    (listed in ``paths`` when it was kept)."""
    from graphslam.pipelines.posegraph import solved_graph
    from graphslam.visualisation.recording import ViewerUnavailable
    from graphslam.visualisation.spatial import log_pose_graph

    try:  # opened after the run's files: a disk they filled costs the recording only
        log = folder.open_recorder(open_posegraph_recording, args.rerun, "run.rrd", args.rerun_url)
    except ViewerUnavailable as e:
        warn(str(e))
        return
    log_pose_graph(log, solved_graph(graph, result), result.params, result.rejected)
    folder.close_recorder(paths)


def open_posegraph_recording(mode: str, path: Path, url: str | None):
    from graphslam.visualisation.recording import RerunLog

    return RerunLog(mode, path, url, application_id="graphslam-posegraph")


def format_summary(metrics) -> str:
    from graphslam import registry

    rows = [
        ("dataset", metrics.dataset),
        ("backend", metrics.backend),
        (
            "graph",
            f"{metrics.dim}-D {metrics.format}, {metrics.poses} poses"
            + (f" solved of the file's {metrics.poses_in_file}" if metrics.poses_in_file else "")
            + f", {metrics.edges} edges ({metrics.closures} closures)",
        ),
        *information_rows(metrics.information_fixed),
        *([("edge numbers read as", metrics.noise)] if metrics.noise else []),
        *(
            [
                (
                    "self-edges ignored",
                    f"{metrics.self_edges_ignored['edges']} edges from a pose "
                    f"to itself (lines {', '.join(map(str, metrics.self_edges_ignored['lines']))}"
                    f"{', ...' if metrics.self_edges_ignored['edges'] > 10 else ''}): they constrain "
                    "nothing",
                )
            ]
            if metrics.self_edges_ignored
            else []
        ),
        *(
            [
                (
                    "EQUIV pairs ignored",
                    f"{metrics.equiv_ignored} (same-place marks: the solver "
                    "does not merge them, as gtsam; kept in the written graph)",
                )
            ]
            if metrics.equiv_ignored
            else []
        ),
        ("initialisation", metrics.init),
        ("initial cost", fmt(metrics.initial_cost, ".10g")),
        ("final cost", fmt(metrics.final_cost, ".10g")),
        *(
            [("final cost, kept edges", fmt(metrics.final_cost_kept, ".10g"))]
            if metrics.final_cost_kept is not None
            else []
        ),
        ("LM iterations", fmt(metrics.iterations, "d")),
        ("closures rejected", closure_row(metrics)),
        (
            "ATE RMSE [m]",
            fmt(metrics.ate_rmse_m, ".4f")
            + (
                ""
                if metrics.ate_poses is None or metrics.ate_rmse_m is None
                else f" (over the {metrics.ate_poses} of {metrics.poses} poses with truth)"
            ),
        ),
        ("odometry ATE RMSE [m]", fmt(metrics.odometry_ate_rmse_m, ".4f")),
        ("wall time [s]", fmt(metrics.wall_s, ".2f")),
        ("back end [s]", fmt(metrics.backend_s, ".2f")),
    ]
    if metrics.interrupted:
        rows.append(("interrupted", f"yes: {metrics.poses} poses solved"))
    if not metrics.converged and not metrics.interrupted:  # (a cut solve says so above)
        tries = (
            "--backend isam2, another --init"
            if not registry.backend_row(metrics.backend).streams
            else "--no-polish"
        )
        rows.append(
            (
                "NOT CONVERGED",
                "LM took no step from its start (see the warning)"
                if metrics.iterations == 0
                else f"LM stopped at its cap of {metrics.iterations} "
                "iterations; the cost may be far from the optimum "
                f"(try {tries}, or [posegraph] max_iterations)",
            )
        )
    rows += route_rows(metrics.route)
    if metrics.certificate is not None:
        retried = "shonan_retry" in (metrics.route or {})
        rows.append(("optimality", optimality_row(metrics.certificate, retried)))
    if metrics.shonan_min_eigenvalue is not None:
        rows.append(("Shonan min eigenvalue", fmt(metrics.shonan_min_eigenvalue, ".3g")))
    for note in metrics.numerical_recoveries or ():
        rows.append(("numerical recovery", note))
    return summary_table(rows)


def route_rows(route: dict | None) -> list[tuple[str, str]]:
    """``--backend auto``: the route kept, why, and a local minimum if one was met."""
    if not route:
        return []
    rows = [("route", f"{route['kept']} kept ({route['reason']})")]
    for name, tried in route.items():  # the attempts are the route's entries with a cost
        if isinstance(tried, dict) and "cost" in tried and name != route["kept"]:
            rows.append((f"  {name}", f"cost {tried['cost']:.10g}, {tried['wall_s']:.2f} s"))
    if "shonan_retry" in route:
        rows.append(("retry", route["shonan_retry"]))
    if "local_minimum" in route:
        rows.append(("local minimum", route["local_minimum"]))
    return rows


def optimality_row(certificate: dict, retried: bool = False) -> str:
    """SE-Sync's certificate in one line (``metrics.json`` has the figures and what
    the certificate covers); ``retried``: ``auto`` already tried Shonan's start, so
    the line does not suggest it."""
    if certificate["certified"] is None:
        return f"not checked: {certificate['unchecked']}"
    near = (
        f"the estimate is {certificate['max_translation_change_m']:.3g} m / "
        f"{certificate['max_rotation_change_deg']:.3g} deg from it"
    )
    if certificate["certified"]:
        return (
            f"certified: SE-Sync's problem (isotropic weights, chordal rotations) refined "
            f"from the estimate is its global optimum within {certificate['relative_gap']:.1e} "
            f"relative; {near} (checked in {certificate['wall_s']:.2f} s)"
        )
    gap = (
        f"no dual bound: {certificate['negative_pivots']} negative eigenvalues"
        if certificate["relative_gap"] is None
        else f"gap {certificate['relative_gap']:.1e} relative"
    )
    budget = (
        "; its refinement stopped at its time budget (three times the solve's, at least 10 s: the "
        "machine was loaded, or the estimate far from the relaxation's optimum)"
        if certificate.get("refine_stopped")
        else ""
    )
    return (
        f"NOT certified ({gap}): SE-Sync's problem refined from the estimate may not be "
        f"at its global optimum, nor the estimate at the file's ({near}){budget}"
        + ("" if retried else "; --init shonan starts from certified rotations")
    )


def closure_row(metrics) -> str:
    """How many closures were rejected, and by which test."""
    test = metrics.closure_test
    if test is None:
        why = (
            '[posegraph] robust_closures = "none": every closure kept' if metrics.closures else "no closures"
        )
        return f"{metrics.closures_rejected} ({why})"
    if test.get("stopped") == "incremental":
        return (
            f"none tested of {metrics.closures} (a signal stopped iSAM2 before the outlier test; "
            "the closures of the poses solved went in under a Cauchy kernel)"
        )
    if test.get("tested") is False:
        return (
            f"none tested of {metrics.closures} (no polish: iSAM2 kept them under a Cauchy kernel; "
            f'the robust_closures = "{test["robust_closures"]}" test runs in the polish)'
        )
    if test.get("stopped") in ("lm", "gnc"):
        return f"none tested of {metrics.closures} (a signal stopped the solve before the outlier test)"
    return (
        f"{metrics.closures_rejected} of {metrics.closures} (outlier test: whitened "
        f"residual > {test['threshold_whitened']:.2f} at the kept-edge optimum; "
        f'robust_closures = "{test["robust_closures"]}")'
    )


#: What each ``[posegraph] information_fix`` put in place of the file's matrix.
INFORMATION_FIXES = {
    "nearest": "the nearest positive-definite matrix",
    "isotropic": "SE-Sync's isotropic translation and rotation weights",
}


def information_rows(fixed: dict | None) -> list[tuple[str, str]]:
    """The summary row saying how many edges' information the reader replaced, and how."""
    if not fixed:
        return []
    return [
        (
            "information fixed",
            f"{fixed['edges']} edges not positive definite, replaced by {INFORMATION_FIXES[fixed['method']]}",
        )
    ]


def check_backend(args: argparse.Namespace) -> None:
    """``--backend batch`` and ``--init`` exist for pose-graph files only."""
    from graphslam import registry

    if not registry.backend_row(args.backend).streams:
        raise GraphSlamError(f"--backend {args.backend} solves pose-graph files only (g2o or TORO)")
    if args.init is not None:
        from graphslam.sources.posegraph_files import has_landmark_lines

        why = (
            f" ({args.dataset} has landmark lines: it runs as landmark SLAM, whose poses "
            "start from the odometry)"
            if Path(args.dataset).is_file() and has_landmark_lines(args.dataset)
            else ""
        )
        raise GraphSlamError(f"--init applies to pose-graph files only (g2o or TORO){why}")
