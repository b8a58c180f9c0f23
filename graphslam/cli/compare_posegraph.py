"""``graphslam compare`` on a pose-graph file or a built-in pose graph: its whole-graph
solvers side by side (:mod:`graphslam.pipelines.compare_posegraph`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from slamcore.errors import GraphSlamError

if TYPE_CHECKING:
    from graphslam.cli.out_folder import OutputFolder


def wants_pose_graph_compare(dataset: str, backends: list[str] | None) -> bool:
    """Whether ``compare`` compares pose-graph solvers: a pose graph, and ``batch`` or
    ``auto`` named, or a 3-D graph (which only those solvers take)."""
    from graphslam import registry
    from graphslam.sources.builtin_posegraphs import is_builtin_pose_graph

    named_whole = bool(set(backends or ()) & set(registry.WHOLE_GRAPH_BACKENDS))
    if is_builtin_pose_graph(dataset):
        return named_whole
    if not registry.is_pose_graph_run(dataset, "batch"):
        return False
    from graphslam.sources.posegraph_files import TAGS, first_tag

    tag = first_tag(dataset)
    return named_whole or (tag is not None and tag in TAGS and TAGS[tag][1] == 3)


def compare_pose_graph(args: argparse.Namespace, config, rerun_mode: str, out_dir_of) -> int:
    """Run, print, write (compare.json, compare.png, compare.rrd); the exit status.
    ``out_dir_of(name)`` claims the output folder (an :class:`OutputFolder`)."""
    from graphslam import registry
    from graphslam.cli.common import EXIT_FAILED, EXIT_INTERRUPTED, fmt, invocation, warn, warn_doubts
    from graphslam.cli.run.posegraph import load_graph
    from graphslam.outputs import writers
    from graphslam.pipelines.common import active_guard, stop_requested
    from graphslam.pipelines.compare_posegraph import compare

    names = list(args.backends or registry.POSEGRAPH_BACKENDS)
    others = [n for n in names if n not in registry.POSEGRAPH_BACKENDS]
    if others:
        raise GraphSlamError(
            f"--backends {' '.join(others)}: a whole pose graph is compared "
            f"across {', '.join(registry.POSEGRAPH_BACKENDS)}; the filters stream "
            "a 2-D graph frame by frame: compare them without batch or auto"
        )
    for flag, value in (("--robot", args.robot), ("--odometry", args.odometry)):
        if value is not None:
            raise GraphSlamError(f"{flag} does not apply to a pose graph")
    if args.seed is not None:
        raise GraphSlamError("--seed has no effect here: the pose-graph solvers draw no random numbers")
    solver_config = registry.pose_graph_config(config)
    graph, truth = load_graph(args.dataset, solver_config, args.max_steps, args.ground_truth)
    folder = out_dir_of(graph.name)
    runs = compare(
        graph,
        names,
        solver_config,
        truth,
        progress=lambda n: print(f"running {n} ...", file=sys.stderr, flush=True),
    )
    rows = [
        (
            "backend",
            "status",
            "final cost",
            "iterations",
            "rejected",
            "certified",
            "ATE [m]",
            "RMS to first [m]",
            "wall [s]",
        )
    ]
    for r in runs:
        m = r.metrics
        rows.append(
            (r.backend, r.status)
            + (
                ("n/a",) * 7
                if m is None
                else (
                    fmt(m.final_cost, ".10g"),
                    fmt(m.iterations, "d"),
                    str(m.closures_rejected),
                    _certified(m.certificate),
                    fmt(m.ate_rmse_m, ".4f"),
                    fmt(r.rms_to_first_m, ".3g"),
                    fmt(m.wall_s, ".2f"),
                )
            )
        )
    widths = [max(len(row[c]) for row in rows) for c in range(len(rows[0]))]
    print(
        "\n".join(
            "  ".join(
                v.rjust(w) if c else v.ljust(w) for c, (v, w) in enumerate(zip(row, widths, strict=True))
            )
            for row in rows
        )
    )
    out_dir = folder.resolve()
    paths = {"json": out_dir / "compare.json"}
    writers.write_json(
        paths["json"],
        {
            "dataset": graph.name,
            "kind": "pose graph",
            "graph": {
                "dim": graph.dim,
                "format": graph.format,
                "poses": graph.n_poses,
                "edges": graph.n_edges,
            },
            "runs": [r.to_dict() for r in runs],
            "provenance": invocation(args),
        },
    )
    done = [r for r in runs if r.result is not None]
    if done:
        _figures(args, graph, truth, done, folder, rerun_mode, paths)
    folder.finish(paths)
    outputs = [p.name for p in paths.values()]
    # what makes an estimate doubtful (compare.json keeps it too), said as run says it
    warn_doubts({r.backend: getattr(r.metrics, "warnings", None) for r in done})
    for r in runs:
        if r.error is not None:
            warn(f"{r.backend} failed: {r.error}")
    print(f"outputs in {out_dir}/: {', '.join(outputs)}")
    if stop_requested() or any(r.status == "cut" for r in runs):
        guard = active_guard()
        print(
            f"graphslam: interrupted ({guard.signal_name if guard else 'stop'}); wrote the solvers that ran",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    return EXIT_FAILED if any(r.error for r in runs) else 0


def _certified(certificate: dict | None) -> str:
    """SE-Sync's certificate in a word (``run``'s summary and ``compare.json`` say more)."""
    if certificate is None or certificate["certified"] is None:
        return "n/a"
    return "yes" if certificate["certified"] else "NO"


def _figures(args, graph, truth, done, folder: OutputFolder, rerun_mode: str, paths: dict[str, Path]) -> None:
    """compare.png, and compare.rrd (one subtree per solver) unless ``--rerun off``,
    added to ``paths``."""
    import numpy as np

    from graphslam.cli.run.posegraph import open_posegraph_recording
    from graphslam.pipelines.posegraph import solved_graph, trajectory_matrices
    from graphslam.visualisation.plots import plot_pose_graph_comparison
    from graphslam.visualisation.spatial import log_pose_graph

    tracks = {
        r.backend: trajectory_matrices(solved_graph(graph, r.result), r.result.params)[:, :3, 3] for r in done
    }
    truth_xyz = None if truth is None else np.asarray(truth[1])[:, :3, 3]
    plot_pose_graph_comparison(
        folder.path / "compare.png",
        f"{graph.name}: {graph.dim}-D, {graph.n_poses} poses, {graph.n_edges} edges",
        tracks,
        truth_xyz,
        {r.backend: r.metrics.wall_s for r in done},
        {r.backend: r.metrics.final_cost for r in done},
    )
    paths["png"] = folder.path / "compare.png"
    if rerun_mode != "off":
        log = folder.open_recorder(open_posegraph_recording, rerun_mode, "compare.rrd", args.rerun_url)
        for r in done:
            log_pose_graph(
                log,
                solved_graph(graph, r.result),
                r.result.params,
                r.result.rejected,
                root=f"world/{r.backend}",
            )
        folder.close_recorder(paths)  # not listed when not kept
