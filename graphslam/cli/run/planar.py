"""``graphslam run`` on 2-D data: a landmark world, a landmark log or a pose graph."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from graphslam.cli.common import (
    close_recorder, fmt, open_recorder, recoveries_text, report_outputs, summary_table,
)
from slamcore.errors import ConfigError, GraphSlamError


def refuse_ignored_flags(args: argparse.Namespace) -> None:
    """Flags that would have no effect on this 2-D run are refused, one line each."""
    from graphslam import registry

    for flag in ("frontend", "odometry", "odometry_noise", "vocab", "frames", "save_map", "map"):
        if getattr(args, flag, None) is not None:
            raise GraphSlamError(f"--{flag.replace('_', '-')} applies to image sequences only")
    if getattr(args, "relocalise", False):
        raise GraphSlamError("--relocalise applies to image sequences only")
    if args.loops:
        raise GraphSlamError("--loops applies to image sequences only (pose graphs bring "
                             "their own closures)")
    if args.max_steps is not None and args.max_steps < 1:
        raise GraphSlamError("--max-steps must be at least 1")
    if args.no_polish and args.backend != "isam2":
        raise ConfigError(f"--no-polish applies to the isam2 back end only (its final batch "
                          f"polish); {args.backend} has none")
    if (args.seed is not None and args.dataset != "synthetic"
            and args.backend not in registry.SEEDED_BACKENDS):
        raise ConfigError(f"--seed has no effect here: {args.dataset} is not simulated and "
                          f"{args.backend} draws no random numbers (it seeds the synthetic "
                          f"worlds and FastSLAM's particles)")


def run(args: argparse.Namespace) -> int:
    """The 2-D ``graphslam run``; returns the exit status."""
    from graphslam import registry
    from graphslam.outputs.writers import remove_stale_outputs
    from graphslam.pipelines import planar as pipeline

    t0 = time.perf_counter()
    refuse_ignored_flags(args)
    config = registry.read_config(args.config)
    dataset = registry.load_dataset(args.dataset, seed=args.seed, config=config)
    truth = None
    if args.ground_truth is not None:
        from graphslam.sources.ground_truth import planar_ground_truth, read_trajectory

        truth = planar_ground_truth(dataset, read_trajectory(args.ground_truth))
    if args.nees and truth is None and not dataset.has_ground_truth:
        raise GraphSlamError(f"--nees needs ground truth; {args.dataset} has none")
    overrides = {"polish": False} if args.no_polish else {}
    overrides.update(registry.seed_override(args.backend, args.seed))
    backend = registry.make_backend(args.backend, config=config, overrides=overrides)
    out_dir = args.out or Path("runs") / f"{Path(dataset.name).stem}-{backend.name}"
    out_dir.mkdir(parents=True, exist_ok=True)
    will_write = {"trajectory.tum", "landmarks.csv", "metrics.json", "ground_truth.tum",
                  "nees.csv"}
    remove_stale_outputs(out_dir, will_write | ({"run.rrd"} if args.rerun == "save" else set()))

    n_steps = len(dataset.frames) if args.max_steps is None else min(args.max_steps,
                                                                     len(dataset.frames))
    log = hook = None
    mode = args.rerun
    if mode != "off":
        from graphslam.visualisation.planar import RunRecorder

        log, mode = open_recorder(RunRecorder.open, mode, out_dir / "run.rrd", args.rerun_url)
        log.start(dataset, n_steps)
        hook = log.hook(backend.name, every=args.rerun_every or max(1, n_steps // 50))

    result = pipeline.run(dataset, backend, max_steps=args.max_steps, progress=not args.quiet,
                          on_step=hook, with_covariances=log is not None or args.nees)
    metrics = pipeline.compute_metrics(result, seed=dataset.seed, ground_truth=truth,
                                       wall_s=time.perf_counter() - t0)
    nees = pipeline.add_nees(result, metrics, truth) if args.nees else None
    paths = pipeline.write_outputs(result, out_dir, metrics, ground_truth=truth)
    if nees is not None:
        paths["nees"] = pipeline.write_nees(out_dir / "nees.csv", *nees)
    if log is not None:
        log.finish(backend.name, result)
        close_recorder(log)
        if mode == "save":
            paths["recording"] = out_dir / "run.rrd"
    remove_stale_outputs(out_dir, {p.name for p in paths.values()})
    return report_outputs(format_summary(metrics), out_dir, paths, result.interrupted)


def format_summary(metrics) -> str:
    """A two-column table of the headline numbers."""
    rows = [
        ("dataset", metrics.dataset),
        ("backend", metrics.backend),
        ("steps", metrics.steps),
        ("landmarks", metrics.landmarks),
        ("final error", fmt(metrics.final_error, ".6g")),
        ("ATE RMSE [m]", fmt(metrics.ate_rmse_m, ".4f")),
        ("odometry ATE RMSE [m]", fmt(metrics.odometry_ate_rmse_m, ".4f")),
        ("wall time [s]", fmt(metrics.wall_s, ".2f")),
        ("back end [s]", fmt(metrics.backend_s, ".2f")),
        ("back end steps/s", fmt(metrics.steps_per_s, ".1f")),
    ]
    if metrics.loop_closures_skipped:
        rows.append(("loop closures skipped", metrics.loop_closures_skipped))
    for note in metrics.numerical_recoveries or ():
        rows.append(("numerical recovery", note))
    if metrics.recoveries and any(metrics.recoveries.values()):
        rows.append(("numerical recoveries", recoveries_text(metrics.recoveries)))
    if metrics.interrupted:
        rows.append(("interrupted", "yes"))
    return summary_table(rows)
