"""``graphslam eval GT EST...``: score trajectory files against a reference."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from graphslam.cli.common import add_command, add_out_dir_option, path_arg
from graphslam.cli.out_folder import claim_out_dir

EPILOG = """\
formats (told from the content unless --format is given; a line not of the
  format's form is refused, told or given):
  tum     t x y z qx qy qz qw a line (seconds), separated by spaces
  kitti   12 numbers a line (row-major 3x4 wTc), one per frame, separated by
          spaces; paired by line number, or by time with --times FILE (one
          time a line, KITTI times.txt)
  euroc   EuRoC ground-truth CSV: timestamp [ns], px, py, pz, qw, qx, qy, qz, ...
          separated by commas, the timestamp an integer (nanoseconds)
  BAG:TOPIC  a ROS bag's PoseStamped, TransformStamped or Odometry messages at
          their header stamps (a ROS 1 .bag or a ROS 2 bag folder; BAG alone
          when it has one such topic; pip install ".[bags]")

as evo: association by nearest timestamp within --max-diff (default 0.01 s)
  after adding --offset (default 0 s) to the estimate's stamps; Umeyama
  alignment (--align se3|sim3, over the first --n-align poses if given) or the
  first pose onto the first pose (--align first); RPE on consecutive pairs
  --delta frames or metres (of the estimate's path) apart. KITTI drift as the
  KITTI devkit: segments of 100..800 m of the reference path starting every
  10 matched poses; null in eval.json when the path is under 100 m.

the "matched" column is matched poses / the estimate's poses; under half
  matched, a warning says the ATE covers those alone. Duplicated stamps are
  refused, unsorted TUM/EuRoC rows sorted, a --times file must increase.
  Warnings (also in eval.json) say a likely mix-up: another size (units, a
  monocular estimate under se3), inverted poses, the quaternion order, stamps
  not in seconds or frame indices, KITTI files of different lengths, poses
  paired twice by a wide --max-diff.

outputs (in --out): eval.json (one entry per estimate), eval.png

examples:
  graphslam eval groundtruth.txt trajectory.tum
  graphslam eval recording.bag:/vicon/pose runs/recording.bag-isam2/trajectory.tum
  graphslam eval poses/07.txt run07.txt --format kitti --align sim3 --delta 100 --delta-unit m
"""


def register(sub) -> None:
    """Add the ``eval`` sub-command to the ``graphslam`` parser."""
    from graphslam.evaluation.trajectory import (
        ALIGN_METHODS,
        DEFAULT_MAX_DIFF_S,
        DEFAULT_OFFSET_S,
        DELTA_UNITS,
    )
    from graphslam.sources.ground_truth import TRAJECTORY_FORMATS

    p = add_command(
        sub,
        "eval",
        cmd_eval,
        help="score trajectory files (TUM, KITTI, EuRoC) against ground truth",
        description="ATE, RPE and KITTI drift of one or more estimates against a reference "
        "trajectory; a table, eval.json and eval.png.",
        epilog=EPILOG,
    )
    p.add_argument(
        "ground_truth",
        type=path_arg,
        metavar="GT",
        help="reference trajectory file, or BAG:TOPIC (see below)",
    )
    p.add_argument(
        "estimates", type=path_arg, nargs="+", metavar="EST", help="estimate file(s), or BAG:TOPIC"
    )
    p.add_argument(
        "--format",
        choices=TRAJECTORY_FORMATS,
        default=None,
        help="file format of every file (default: told from the content)",
    )
    p.add_argument(
        "--times",
        type=path_arg,
        default=None,
        metavar="FILE",
        help="KITTI times file giving the KITTI files' stamps",
    )
    p.add_argument(
        "--align",
        choices=ALIGN_METHODS,
        default="se3",
        help="alignment of each estimate to the reference (default: se3)",
    )
    p.add_argument(
        "--n-align",
        type=int,
        default=None,
        metavar="N",
        help="fit se3/sim3 on the first N matched poses only (default: all)",
    )
    # Each option of EvalOptions has its field's name as dest: cmd_eval passes them on by name.
    p.add_argument(
        "--max-diff",
        dest="max_diff_s",
        type=float,
        default=DEFAULT_MAX_DIFF_S,
        metavar="S",
        help=f"largest time difference of a matched pair (default: {DEFAULT_MAX_DIFF_S} s)",
    )
    p.add_argument(
        "--offset",
        dest="offset_s",
        type=float,
        default=DEFAULT_OFFSET_S,
        metavar="S",
        help=f"time added to the estimates' stamps (default: {DEFAULT_OFFSET_S} s)",
    )
    p.add_argument("--delta", type=float, default=1, metavar="N", help="RPE step (default: 1)")
    p.add_argument(
        "--delta-unit", choices=DELTA_UNITS, default="frames", help="RPE step unit (default: frames)"
    )
    add_out_dir_option(p, "output folder (default: runs/eval)", default=Path("runs") / "eval")
    p.add_argument("--no-plot", action="store_true", help="do not write eval.png")


def format_table(results) -> str:
    """One row per estimate: ATE, RPE and drift."""
    from graphslam.cli.common import fmt

    head = (
        "estimate",
        "matched",
        "ATE rmse",
        "mean",
        "median",
        "max [m]",
        "rot [deg]",
        "RPE [m]",
        "RPE [deg]",
        "drift [%]",
        "[deg/100m]",
    )
    rows: list[tuple[str, ...]] = [head]
    for r in results:
        s = r.result.summary()
        rows.append(
            (
                r.label or Path(r.path).name,
                f"{s['matched_poses']}/{s['estimate_poses']}",
                *(
                    fmt(s[k], ".4f")
                    for k in (
                        "ate_rmse_m",
                        "ate_mean_m",
                        "ate_median_m",
                        "ate_max_m",
                        "ate_rot_rmse_deg",
                        "rpe_trans_rmse_m",
                        "rpe_rot_rmse_deg",
                        "kitti_drift_pct",
                        "kitti_drift_deg_per_100m",
                    )
                ),
            )
        )
    widths = [max(len(row[c]) for row in rows) for c in range(len(head))]
    return "\n".join(
        "  ".join(v.rjust(w) if c else v.ljust(w) for c, (v, w) in enumerate(zip(row, widths, strict=True)))
        for row in rows
    )


def cmd_eval(args: argparse.Namespace) -> int:
    """Score, print, write; the exit status."""
    from graphslam.cli.common import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, invocation, warn
    from graphslam.cli.out_folder import clear_earlier_outputs
    from graphslam.evaluation.trajectory import EvalOptions
    from graphslam.outputs.writers import EVAL_OUTPUT_NAMES, OutputWrites, one_run_or_the_other
    from graphslam.pipelines.trajectory_eval import eval_warnings, evaluate_files, write_eval_json
    from slamcore.files import check_not_inputs, check_output_dir

    # refused now, not after scoring
    names = ("eval.json",) if args.no_plot else ("eval.json", "eval.png")
    check_output_dir(args.out, files=names)
    check_not_inputs(  # --out . beside a trajectory named eval.json
        [(f"the output (in --out) {name}", args.out / name) for name in names],
        {"GT": args.ground_truth, "--times": args.times, **{f"EST {e}": e for e in args.estimates}},
    )
    options = EvalOptions(**{f.name: getattr(args, f.name) for f in dataclasses.fields(EvalOptions)})
    from graphslam.pipelines.common import interrupt_between_frames

    with interrupt_between_frames() as guard:
        # a stop while one estimate is scored ends the scoring after it, and the estimates
        # scored are written (Ctrl-C on the third of three lost the first two, seconds each
        # on 600 000 poses)
        guard.held_note = "stopping after the estimate being scored; those scored by then are written"
        refused: list[tuple[Path, str]] = []
        try:
            results = evaluate_files(
                args.ground_truth,
                args.estimates,
                options,
                fmt=args.format,
                times=args.times,
                should_stop=lambda: guard.requested,
                refused=refused,
            )
        finally:
            guard.held_note = None
        if guard.requested and not results:  # nothing scored: nothing to keep, and said
            # (the held note had said "the ones scored are kept", and nothing was written)
            print(
                f"graphslam: interrupted ({guard.signal_name}) before any estimate was scored: "
                "nothing written",
                file=sys.stderr,
            )
            return EXIT_INTERRUPTED
    # a stop scores a prefix of the estimates that were not refused
    done = {Path(r.path) for r in results} | {path for path, _ in refused}
    unscored = [str(e) for e in args.estimates if Path(e) not in done] if guard.requested else []
    claim_out_dir(args.out)
    clear_earlier_outputs(args.out, set(names), EVAL_OUTPUT_NAMES)  # --no-plot: no earlier eval.png
    # a stop while plotting: the earlier eval.png goes, not left beside the new eval.json
    writes = OutputWrites(args.out)  # a file the disk refuses costs no other: each is tried
    paths: dict[str, Path] = {}
    with one_run_or_the_other(args.out, EVAL_OUTPUT_NAMES):
        writes(
            paths,
            "json",
            args.out / "eval.json",
            write_eval_json,
            args.ground_truth,
            results,
            options,
            invocation(args),
            unscored,
            refused,
        )
        if not args.no_plot:
            from graphslam.visualisation.plots import plot_trajectory_eval

            writes(
                paths, "png", args.out / "eval.png", lambda path: plot_trajectory_eval(results, path, options)
            )
    print(format_table(results))
    for message in eval_warnings(results, options):
        warn(message)
    for _, why in refused:
        warn(f"not scored: {why}")
    print(writes.outputs_line(paths.values()))
    writes.check(paths.values())
    if unscored:
        print(
            f"graphslam: interrupted ({guard.signal_name}); {len(results)} of {len(args.estimates)} "
            f"estimates scored and written, not {', '.join(unscored)}",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    if refused:  # the others are written, but a script must not take the eval for a whole one
        return EXIT_FAILED
    return EXIT_OK
