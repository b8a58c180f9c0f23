"""``graphslam run`` on 2-D data: a landmark world, a landmark log or a pose graph."""

from __future__ import annotations

import argparse
from pathlib import Path

from graphslam.cli.common import fmt, report_outputs, summary_table
from slamcore.errors import GraphSlamError


def run(args: argparse.Namespace) -> int:
    """The 2-D ``graphslam run``; returns the exit status."""
    from graphslam import registry
    from graphslam.pipelines import planar as pipeline

    for flag in ("frontend", "odometry", "odometry_noise", "vocab"):
        if getattr(args, flag, None) is not None:
            raise GraphSlamError(f"--{flag.replace('_', '-')} applies to image sequences only")
    if args.loops:
        raise GraphSlamError("--loops applies to image sequences only (pose graphs bring "
                             "their own closures)")
    if args.max_steps is not None and args.max_steps < 1:
        raise GraphSlamError("--max-steps must be at least 1")
    dataset = registry.load_dataset(args.dataset, seed=args.seed, config_path=args.config)
    overrides = {"polish": False} if args.no_polish else {}
    backend = registry.make_backend(args.backend, config_path=args.config, overrides=overrides)
    out_dir = args.out or Path("runs") / f"{Path(dataset.name).stem}-{backend.name}"
    out_dir.mkdir(parents=True, exist_ok=True)

    n_steps = len(dataset.frames) if args.max_steps is None else min(args.max_steps,
                                                                     len(dataset.frames))
    log = None
    hook = None
    if args.rerun != "off":
        from graphslam.visualisation.planar import RunRecorder

        log = RunRecorder.open(args.rerun, out_dir / "run.rrd", args.rerun_url)
        log.start(dataset, n_steps)
        hook = log.hook(backend.name, every=args.rerun_every or max(1, n_steps // 50))

    result = pipeline.run(dataset, backend, max_steps=args.max_steps, progress=not args.quiet,
                          on_step=hook, with_covariances=log is not None)
    metrics = pipeline.compute_metrics(result, seed=dataset.seed)
    paths = pipeline.write_outputs(result, out_dir, metrics)
    if log is not None:
        log.finish(backend.name, result)
        log.close()
        if args.rerun == "save":
            paths["recording"] = out_dir / "run.rrd"
    return report_outputs(format_summary(metrics), out_dir, paths, result.interrupted)



def format_summary(metrics: dict) -> str:
    """A two-column table of the headline numbers."""
    rows = [
        ("dataset", metrics["dataset"]),
        ("backend", metrics["backend"]),
        ("steps", metrics["steps"]),
        ("landmarks", metrics["landmarks"]),
        ("final error", fmt(metrics["final_error"], ".6g")),
        ("ATE RMSE [m]", fmt(metrics["ate_rmse_m"], ".4f")),
        ("odometry ATE RMSE [m]", fmt(metrics["odometry_ate_rmse_m"], ".4f")),
        ("wall time [s]", fmt(metrics["wall_s"], ".2f")),
        ("steps/s", fmt(metrics["steps_per_s"], ".1f")),
    ]
    if metrics.get("loop_closures_skipped"):
        rows.append(("loop closures skipped", metrics["loop_closures_skipped"]))
    if metrics.get("interrupted"):
        rows.append(("interrupted", "yes"))
    return summary_table(rows)
