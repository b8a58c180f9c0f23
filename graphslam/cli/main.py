"""``graphslam`` command line: parses, calls the library, prints.

Any :class:`~slamcore.errors.GraphSlamError` becomes one line on stderr and
exit status 2; Ctrl-C writes what was estimated so far and exits with 130.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from slamcore.errors import GraphSlamError

EXIT_ERROR = 2
EXIT_INTERRUPTED = 130

RUN_EPILOG = """\
datasets:
  synthetic       2-D landmark world driven around a closed route (default);
                  noise from the course demo, settable in [synthetic] of --config
  victoria-park   Victoria Park (gtsam wheel), trees seen by laser, no ground truth
  city10000       city10000 pose graph with ground truth (gtsam wheel)
  w10000          w10000 Manhattan pose graph (gtsam wheel)
  PATH            a 2-D pose graph, TORO (.graph) or g2o (.g2o)
  synthetic-images  rendered textured room, VGA, noisy odometry (visual SLAM;
                  [synthetic_images] of --config)
  FOLDER          an image sequence: KITTI, TUM RGB-D, EuRoC or a plain folder
                  with an intrinsics file (visual SLAM)

visual SLAM (image sequences): --backend isam2|ekf, --frontend harris|orb|fpga,
  --odometry sequence|derived|none (derived: ground truth times noise, default
  2 % of the distance and 0.1 deg per frame; none: EKF constant velocity,
  Sim(3)-aligned ATE); landmarks.csv is id,x,y,z; --loops adds place
  recognition ([loops], [loop_verify], [loop_pnp] of --config) and writes
  loops.csv (query,match,score,inliers) and loops.jsonl (every candidate)

outputs (in --out):
  trajectory.tum  TUM format; time column = pose id where the data has no stamps
  landmarks.csv   id,x,y
  metrics.json    final_error (gtsam graph error), ate_rmse_m, wall_s, ...
  run.rrd         Rerun recording (open with: rerun run.rrd)

examples:
  graphslam run
  graphslam run --dataset victoria-park --out runs/vp
  graphslam run --dataset city10000 --rerun off
  graphslam run --seed 3 --config my.toml --rerun spawn
  graphslam run --dataset synthetic-images --backend ekf --frontend fpga
  graphslam run --dataset ../shared/data/kitti07 --max-steps 160 --odometry derived
"""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="graphslam",
        description="Graph-SLAM toolkit on GTSAM: run SLAM on a sequence and get a trajectory, "
                    "a map, metrics and a Rerun recording.")
    from graphslam import __version__

    parser.add_argument("--version", action="version", version=f"graphslam {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    from graphslam.registry import BACKENDS

    run_p = sub.add_parser(
        "run", help="run SLAM on a dataset and write trajectory, map, metrics, recording",
        description="Run one back end over a dataset, print a summary table and write the "
                    "outputs to --out.",
        epilog=RUN_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    run_p.add_argument("--dataset", default="synthetic", metavar="NAME|PATH",
                       help="built-in dataset name, pose-graph file or image-sequence folder "
                            "(default: synthetic)")
    run_p.add_argument("--backend", default="isam2", choices=BACKENDS,
                       help="estimator (default: isam2)")
    run_p.add_argument("--seed", type=int, default=None,
                       help="seed of the synthetic world (default: config file, else 0)")
    run_p.add_argument("--out", type=Path, default=None,
                       help="output folder (default: runs/<dataset>-<backend>)")
    run_p.add_argument("--config", type=Path, default=None,
                       help="TOML or YAML file with [synthetic], [isam2] sections")
    run_p.add_argument("--max-steps", type=int, default=None, metavar="N",
                       help="stop after N frames")
    run_p.add_argument("--no-polish", action="store_true",
                       help="skip the final batch Levenberg-Marquardt polish (iSAM2)")
    run_p.add_argument("--rerun", choices=("save", "spawn", "connect", "off"), default="save",
                       help="save run.rrd in --out (default), spawn a viewer, connect to a "
                            "running one, or log nothing")
    run_p.add_argument("--rerun-url", default=None,
                       help="viewer gRPC URL for --rerun connect "
                            "(default: rerun+http://127.0.0.1:9876/proxy)")
    run_p.add_argument("--rerun-every", type=int, default=None, metavar="N",
                       help="log the full estimate every N steps (default: about 50 snapshots)")
    run_p.add_argument("--quiet", action="store_true", help="no progress bar")
    vis = run_p.add_argument_group("image sequences")
    vis.add_argument("--frontend", choices=("harris", "orb", "fpga"), default=None,
                     help="corner detector and matching (default: [tracker] of --config, else harris)")
    vis.add_argument("--odometry", choices=("auto", "sequence", "derived", "none"), default=None,
                     help="sequence's own odometry, noisy odometry derived from ground truth, or "
                          "none (constant-velocity model, EKF only); default auto: sequence if "
                          "it has odometry, else derived")
    vis.add_argument("--odometry-noise", type=float, nargs=2, default=None,
                     metavar=("SIGMA_T_PER_M", "SIGMA_R_DEG"),
                     help="derived odometry noise: translation sigma per metre travelled and "
                          "rotation sigma per frame in degrees (default 0.02 0.1)")
    vis.add_argument("--loops", action="store_true",
                     help="detect loop closures (bag of words, RANSAC, metric pose by PnP on the "
                          "map) and add them to the back end as robust factors (isam2 only); "
                          "writes loops.csv and loops.jsonl. Without --vocab a vocabulary is "
                          "first trained on the sequence's own images (an extra pass)")
    vis.add_argument("--vocab", type=Path, default=None, metavar="FILE",
                     help="vocabulary for --loops, from 'graphslam vocab train' (implies --loops)")
    run_p.set_defaults(func=cmd_run)

    cmp_p = sub.add_parser(
        "compare", help="run several back ends on the same stream and compare them",
        description="Run several back ends on the same data (same seed, same observations), "
                    "each in its own process, and write one table, compare.json, "
                    "compare.png and one Rerun recording with a subtree per back end.",
        epilog=RUN_EPILOG.split("outputs")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    cmp_p.add_argument("--dataset", default="synthetic", metavar="NAME|PATH",
                       help="built-in dataset name or pose-graph file (default: synthetic)")
    cmp_p.add_argument("--backends", nargs="+", default=list(BACKENDS), choices=BACKENDS,
                       metavar="NAME", help=f"back ends to run (default: all of {', '.join(BACKENDS)})")
    cmp_p.add_argument("--seed", type=int, default=None,
                       help="seed of the synthetic world and of particle filters")
    cmp_p.add_argument("--out", type=Path, default=None,
                       help="output folder (default: runs/<dataset>-compare)")
    cmp_p.add_argument("--config", type=Path, default=None, help="TOML or YAML config file")
    cmp_p.add_argument("--max-steps", type=int, default=None, metavar="N",
                       help="stop after N frames")
    cmp_p.add_argument("--rerun", choices=("save", "spawn", "connect", "off"), default="save",
                       help="save compare.rrd in --out (default), spawn, connect, or off")
    cmp_p.add_argument("--rerun-url", default=None, help="viewer gRPC URL for --rerun connect")
    cmp_p.add_argument("--in-process", action="store_true",
                       help="run back ends in this process (no per-back-end memory figure)")
    cmp_p.set_defaults(func=cmd_compare)

    from graphslam.cli import loops, vocab

    for command in (vocab, loops):
        command.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except GraphSlamError as e:
        print(f"graphslam: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("graphslam: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def cmd_run(args: argparse.Namespace) -> int:
    from graphslam import registry
    from graphslam.pipelines import planar as pipeline

    if registry.is_visual_dataset(args.dataset):
        from graphslam.cli.run_spatial import run_visual

        return run_visual(args)
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


def report_outputs(summary: str, out_dir: Path, paths: dict, interrupted: bool) -> int:
    """Print a run's summary table and where its outputs went; the exit status."""
    print(summary)
    print(f"outputs in {out_dir}/: " + ", ".join(p.name for p in paths.values()))
    if interrupted:
        print("graphslam: interrupted; wrote the estimate so far", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from graphslam import registry
    from graphslam.pipelines import compare
    from graphslam.outputs import writers

    if args.max_steps is not None and args.max_steps < 1:
        raise GraphSlamError("--max-steps must be at least 1")
    dataset = registry.load_dataset(args.dataset, seed=args.seed, config_path=args.config)
    out_dir = args.out or Path("runs") / f"{Path(dataset.name).stem}-compare"
    out_dir.mkdir(parents=True, exist_ok=True)
    overrides = {name: registry.seed_override(name, args.seed) for name in args.backends}
    entries = compare.compare(
        dataset, args.backends, config_path=args.config, overrides=overrides,
        max_steps=args.max_steps, isolate=not args.in_process, seed=args.seed,
        progress=lambda name: print(f"running {name} ...", file=sys.stderr, flush=True))
    print(compare.format_table(entries))
    writers.write_json(out_dir / "compare.json",
                       {"dataset": dataset.name, "runs": [e.metrics for e in entries]})
    outputs = ["compare.json", compare.plot(entries, dataset, out_dir / "compare.png").name]
    if args.rerun != "off":
        from graphslam.visualisation.planar import RunRecorder

        recorder = RunRecorder.open(args.rerun, out_dir / "compare.rrd", args.rerun_url)
        compare.record(entries, dataset, recorder)
        recorder.close()
        if args.rerun == "save":
            outputs.append("compare.rrd")
    skipped = {e.backend: e.metrics["loop_closures_skipped"] for e in entries
               if e.metrics.get("loop_closures_skipped")}
    for name, n in skipped.items():
        print(f"note: {name} cannot use relative-pose loop closures; skipped {n}")
    print(f"outputs in {out_dir}/: " + ", ".join(outputs))
    return 0


def summary_table(rows: list[tuple[str, object]]) -> str:
    """``(label, value)`` rows as an indented two-column table."""
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)


def fmt(value, spec: str) -> str:
    """``value`` formatted with ``spec``, or "n/a" when it is None."""
    return "n/a" if value is None else format(value, spec)


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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
