"""``graphslam run``: the parser, and the dispatch to the 2-D or the visual run.

A ``--dataset`` that names an image sequence (``synthetic-images`` or a folder)
runs :mod:`graphslam.cli.run.spatial`; anything else (a 2-D world, a landmark
log, a pose-graph file) runs :mod:`graphslam.cli.run.planar`.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from graphslam.cli.common import (
    INTRINSICS_ESTIMATE_HELP,
    INTRINSICS_HELP,
    add_command,
    add_config_option,
    add_dataset_option,
    add_frames_option,
    add_intrinsics_option,
    add_max_steps_option,
    add_out_dir_option,
    add_quiet_option,
    add_rerun_options,
    add_robot_option,
    add_topics_option,
    check_out_keeps_the_camera,
    path_arg,
    seed_arg,
)
from graphslam.pipelines.common import ODOMETRY_MODES

RUN_EPILOG = """\
datasets:
  synthetic       2-D landmark world driven around a closed route (default);
                  noise from the course demo, settable in [synthetic] of --config
  victoria-park   Victoria Park (gtsam wheel), trees seen by laser, no ground truth
  city10000       city10000 pose graph with ground truth (gtsam wheel)
  w10000          w10000 Manhattan pose graph (gtsam wheel); both stream frame
                  by frame, or are solved whole with --backend batch (and
                  taken by convert) like a pose-graph file
  plaza1, plaza2  CMU Plaza range-only logs (gtsam wheel): dead reckoning and
                  ranges to 4 radio beacons, truth for the vehicle and the
                  beacons; range-only SLAM on isam2 (RangeFactor2D, beacons
                  placed from their first ranges); also PATH_DR.txt (with
                  PATH_TD.txt and PATH_.mat beside it) or a folder holding them
  PATH            a pose graph, g2o or TORO, 2-D or 3-D (VERTEX_SE2/EDGE_SE2,
                  VERTEX_SE3:QUAT/EDGE_SE3:QUAT, VERTEX2/EDGE2, VERTEX3/EDGE3);
                  --backend auto (default: batch, and iSAM2 too where batch's
                  result fails a chi-square check; the lower cost kept), isam2
                  (one update per pose, then LM) or batch (LM from --init);
                  loop closures tested for outliers ([posegraph]
                  robust_closures); writes graph.g2o or graph.graph (input format,
                  vertices at the estimate) and closures.csv
  PATH            landmark SLAM from a file (isam2, ekf, fastslam1, fastslam2):
                  a 2-D TORO file with BR lines (BR pose landmark bearing range
                  sigma_bearing sigma_range, as gtsam.load2D reads them), or a
                  log in Victoria Park's format (ODOMETRY, LANDMARK lines)
  FOLDER          a UTIAS MRCLAM data set (Barcodes.dat, RobotN_*.dat): one robot's
                  range-bearing log with Vicon truth, --robot N (landmark SLAM on
                  isam2, ekf, fastslam1, fastslam2; sensor calibration in
                  [mrclam] of --config); metrics.json adds the map error
  synthetic-images  rendered textured room, VGA, noisy odometry (visual SLAM;
                  [synthetic_images] of --config)
  FOLDER          an image sequence: KITTI, TUM RGB-D, EuRoC or a plain folder
                  with an intrinsics file (visual SLAM)
  BAG             a ROS 1 .bag or a ROS 2 bag folder (sqlite3 or mcap; needs
                  pip install ".[bags]"): sensor_msgs Image or CompressedImage,
                  CameraInfo (else an intrinsics file beside the bag), ground
                  truth from PoseStamped/TransformStamped; --topics picks the
                  topics when a kind has several; graphslam info BAG lists them

visual SLAM (image sequences): --backend isam2|ekf, --frontend harris|orb|fpga,
  --odometry sequence|derived|none (derived: ground truth times noise, default
  2 % of the distance and 0.1 deg per frame; none: the camera alone, iSAM2
  with a monocular start and PnP tracking or the EKF's constant velocity,
  Sim(3)-aligned ATE); landmarks.csv is id,x,y,z; --loops adds place
  recognition ([loops], [loop_verify], [loop_pnp] of --config) and writes
  loops.csv (query,match,score,inliers) and loops.jsonl (every candidate)

ground truth: built in for synthetic, synthetic-images, city10000, KITTI
  (poses.txt, or dataset/poses/NN.txt of the KITTI odometry layout), TUM and
  EuRoC folders; --ground-truth FILE gives (or replaces) it: TUM (t x y z qx
  qy qz qw), KITTI (12 numbers a line, one per frame), EuRoC CSV or COLMAP's
  images.txt/.bin, told from the content; images match by timestamp (TUM, EuRoC;
  frame index for sequences without times), frame number (KITTI) or file
  name (COLMAP), 2-D poses by pose id (TUM time column; x, y and yaw)

outputs (in --out):
  trajectory.tum    TUM format; time column = pose id where the data has no stamps
  ground_truth.tum  the truth of the run's frames, same time column (when there is
                    truth; a camera-alone run's frames before its first map too,
                    which have no pose): evo_ape tum ground_truth.tum trajectory.tum
  landmarks.csv     id,x,y
  nees.csv          with --nees: step,pose_id,nees (2-D runs with ground truth)
  metrics.json      final_error (gtsam graph error), ate_rmse_m, wall_s (the whole
                    run), backend_s / processing_s (the estimator alone), ...
  run.rrd           Rerun recording (open with: rerun run.rrd); with --rerun
                    spawn/connect, when no viewer can be started or reached, a
                    warning and run.rrd is saved instead, and when the viewer
                    goes during the run, a warning and the whole recording
                    kept as run.rrd
  A run first removes files of these names (and loops.csv, loops.jsonl) that
  it will not write itself, left in --out by an earlier run (one whose
  metrics.json, compare.json or eval.json is there: without such a record
  they may be yours, and the run refuses instead); other files are never
  touched.

examples:
  graphslam run
  graphslam run --dataset victoria-park --out runs/vp
  graphslam run --dataset city10000 --rerun off
  graphslam run --seed 3 --config my.toml --rerun spawn
  graphslam run --dataset synthetic-images --backend ekf --frontend fpga
  graphslam run --dataset ../shared/data/kitti07 --max-steps 160 --odometry derived
"""


def register(sub) -> None:
    """Add the ``run`` sub-command to the ``graphslam`` parser."""
    from graphslam.registry import BACKEND_NAMES

    p = add_command(
        sub,
        "run",
        cmd_run,
        help="run SLAM on a dataset and write trajectory, map, metrics, recording",
        description="Run one back end over a dataset, print a summary table and write the outputs to --out.",
        epilog=RUN_EPILOG,
    )
    add_dataset_option(p)
    p.add_argument(
        "--backend",
        default=None,
        choices=BACKEND_NAMES,
        help="estimator (default: auto on a pose-graph file, isam2 otherwise; "
        "batch and auto: pose-graph files only)",
    )
    p.add_argument(
        "--seed",
        type=seed_arg,
        default=None,
        help="seed of the synthetic worlds, derived odometry, FastSLAM's "
        "particles, the visual EKF's RANSAC and, with --odometry none, "
        "visual iSAM2's two-view and PnP RANSACs (default: config file, "
        "else 0); refused where nothing is random",
    )
    add_out_dir_option(p, "output folder (default: runs/<dataset>-<backend>)")
    p.add_argument(
        "--write-bag",
        action="store_true",
        help="also write the estimate as trajectory.bag (ROS 1, geometry_msgs/"
        "PoseStamped on /graphslam/trajectory; rosbag and evo read it; needs "
        'pip install ".[bags]"); with --robot all, trajectory_robotN.bag a robot',
    )
    add_config_option(p, "TOML or YAML file with [synthetic], [isam2] sections")
    add_max_steps_option(p)
    p.add_argument(
        "--ground-truth",
        type=path_arg,
        default=None,
        metavar="FILE",
        help="trajectory to score against: TUM, KITTI, EuRoC or COLMAP images.txt (see below)",
    )
    p.add_argument(
        "--no-polish",
        action="store_true",
        help="skip the final batch Levenberg-Marquardt polish (isam2 only)",
    )
    add_rerun_options(
        p,
        "save run.rrd in --out (default), spawn a viewer, connect to a running one, or log nothing",
        url_help="viewer gRPC URL for --rerun connect (default: rerun+http://127.0.0.1:9876/proxy)",
    )
    p.add_argument(
        "--rerun-every",
        type=int,
        default=None,
        metavar="N",
        help="log the full estimate and the EKF's correlation image every N "
        "steps (default: about 50 snapshots; image sequences: every 5 "
        "frames)",
    )
    add_quiet_option(p)
    p.add_argument(
        "--nees",
        action="store_true",
        help="2-D runs with ground truth: write nees.csv (pose NEES per step) and "
        "NEES statistics in metrics.json (Monte Carlo consistency in sweeps)",
    )
    logs = p.add_argument_group("landmark logs")
    add_robot_option(
        logs,
        "MRCLAM folders: which robot's log to run, or all: every robot in one "
        "estimate, on any 2-D back end (default: [mrclam] robot of --config, else 1)",
    )
    _add_posegraph_options(p.add_argument_group("pose-graph files"))
    _add_image_options(p.add_argument_group("image sequences"))


def _add_posegraph_options(graphs) -> None:
    graphs.add_argument(
        "--init",
        default=None,
        choices=("auto", "odometry", "vertices", "lago", "chordal", "shonan"),
        help="start of the batch solve (and candidate start of isam2's polish): "
        "auto = lago in 2-D, chordal in 3-D (default: [posegraph] of "
        "--config, else auto)",
    )


def _add_image_options(vis) -> None:
    vis.add_argument(
        "--frontend",
        choices=("harris", "orb", "fpga"),
        default=None,
        help="corner detector and matching (default: [tracker] of --config, else harris)",
    )
    vis.add_argument(
        "--odometry",
        choices=ODOMETRY_MODES,
        default=None,
        help="sequence's own odometry, noisy odometry derived from ground truth, or "
        "none (the camera alone: iSAM2 starts a monocular map and tracks by "
        "PnP, the EKF runs its constant-velocity model); default auto: "
        "sequence if it has odometry (synthetic-images, a bag's odometry topic), "
        "else none; ground truth only scores a run unless --odometry derived",
    )
    vis.add_argument(
        "--odometry-noise",
        type=float,
        nargs=2,
        default=None,
        metavar=("SIGMA_T_PER_M", "SIGMA_R_DEG"),
        help="derived odometry noise: translation sigma per metre travelled and "
        "rotation sigma per frame in degrees (default 0.02 0.1); refused "
        "when the odometry is not derived",
    )
    vis.add_argument(
        "--loops",
        action="store_true",
        help="detect loop closures (bag of words, RANSAC, metric pose by PnP on the "
        "map) and add them to the back end as robust factors (isam2 only); "
        "writes loops.csv and loops.jsonl. Without --vocab a vocabulary is "
        "first trained on the sequence's own images (an extra pass)",
    )
    vis.add_argument(
        "--vocab",
        type=path_arg,
        default=None,
        metavar="FILE",
        help="vocabulary for --loops, from 'graphslam vocab train' (implies --loops)",
    )
    add_topics_option(vis)
    add_intrinsics_option(vis, INTRINSICS_HELP + INTRINSICS_ESTIMATE_HELP)
    add_frames_option(
        vis,
        "run on these frames only (Python slice: 0:200, 1:160:2, 159::-2 "
        "backwards); ground truth and odometry follow",
    )
    vis.add_argument(
        "--save-map",
        type=path_arg,
        default=None,
        metavar="DIR",
        help="save the map (keyframes, landmarks with covariances, descriptors and "
        "patches, bag of words, vocabulary) to DIR for 'graphslam localize' "
        "(isam2 only); 2-D runs: the landmarks with their 2x2 covariances",
    )
    vis.add_argument(
        "--map",
        type=path_arg,
        default=None,
        metavar="DIR",
        help="continue mapping from a saved map: the first frame is relocalised in "
        "it (its pose and covariance start the run); with --save-map the "
        "joint map of both sessions is saved. 2-D runs (isam2, ekf): "
        "localisation only, the map's landmarks held fixed, associated by id",
    )
    vis.add_argument(
        "--relocalise",
        action="store_true",
        help="when active search loses the track, relocalise against the run's own "
        "map (PnP, added as a closure; isam2 only); metrics.json counts the "
        "losses and recoveries ([relocalise] of --config)",
    )


def cmd_run(args: argparse.Namespace) -> int:
    """Run the 2-D or the visual pipeline, as ``--dataset`` says; the exit status."""
    from graphslam import registry
    from graphslam.cli.common import check_rerun_flags, rerun_sink, warn_shadowed_dataset
    from graphslam.cli.out_folder import claim_out_dir
    from slamcore.errors import ConfigError, GraphSlamError
    from slamcore.files import check_output_dir

    check_rerun_flags(args)
    # a mistyped path is said as one, not as a flag that does not apply to it
    registry.check_dataset_named(args.dataset)
    warn_shadowed_dataset(args.dataset)
    registry.check_topics_flag(args.dataset, args.topics)
    if args.write_bag:  # refused now, not after the run
        from graphslam.outputs.trajectory_bag import check_bag_writer

        check_bag_writer()
    if args.robot is not None and not registry.is_mrclam_dataset(args.dataset):
        raise ConfigError("--robot applies to MRCLAM folders only")
    if args.out is not None:  # refused now, not after the run
        check_output_dir(args.out, files=("trajectory.bag",) if args.write_bag else ())
        _check_outputs_are_not_inputs(args)
        check_out_keeps_the_camera(args.dataset, args.out, args.intrinsics)
    if getattr(args, "save_map", None) is not None:
        from graphslam.maps.files import MAP_JSON, MAP_NPZ, VOCAB_NPZ

        check_output_dir(args.save_map, "--save-map", files=(MAP_JSON, MAP_NPZ, VOCAB_NPZ))
        _check_not_a_foreign_map(Path(args.save_map) / MAP_JSON)
        # two runs saving one map: the second was refused nowhere and its map replaced the
        # first's, both saying "map in ..." (thirteenth hostile pass)
        made = None if Path(args.save_map).exists() else Path(args.save_map)
        claim_out_dir(Path(args.save_map), "--save-map")
    else:
        made = None
    # Decided before any work: a viewer that cannot be used costs one warning
    # line and a saved recording, not the run.
    args.rerun = rerun_sink(args.rerun, args.rerun_url, "run.rrd")
    if args.backend is None:  # a whole file takes the checked fast route; streams take iSAM2
        args.backend = registry.DEFAULT_BACKEND if args.no_polish else registry.default_backend(args.dataset)
    # file times lag the clock by up to a kernel tick (a few ms): 50 ms is far beyond it
    started_ns = time.time_ns() - 50_000_000
    before = _output_stats(args.out)
    try:
        status = _dispatch(args)
    except GraphSlamError as cut:  # a run cut by a bad frame or a failed back end keeps its estimate
        if args.write_bag and (tums := _trajectories_written_since(args, started_ns)):
            try:
                _write_bag(tums)
            except GraphSlamError as e:  # the cut is the error to report; say this one too
                raise GraphSlamError(f"{cut} (and the bag not written: {e})") from None
        earlier = _earlier_outputs(args, before)
        if earlier:
            raise GraphSlamError(f"{cut}; {earlier}") from None
        raise
    finally:
        _remove_if_empty(made)
    # an earlier run's bag went with its other files (remove_stale_outputs)
    if args.write_bag and status in (0, 130, 143) and (tums := _trajectories_written_since(args, started_ns)):
        _write_bag(tums)  # a finished or stopped run's estimate
    return status


def _output_stats(out: Path | None) -> dict[str, tuple[int, int]]:
    """``(inode, mtime)`` of each output file already in ``out`` as a run starts."""
    from graphslam.outputs.writers import FOLDER_OUTPUT_NAMES

    stats: dict[str, tuple[int, int]] = {}
    if out is None:
        return stats
    for name in FOLDER_OUTPUT_NAMES:
        try:
            st = (Path(out) / name).stat()
        except OSError:
            continue
        stats[name] = (st.st_ino, st.st_mtime_ns)
    return stats


def _earlier_outputs(args: argparse.Namespace, before: dict[str, tuple[int, int]]) -> str:
    """What a failed run that wrote nothing leaves in ``--out`` of an earlier command's
    (hostile pass 17: its trajectory and metrics of another data set stayed, unsaid,
    beside the error), as a clause; "" when it wrote or nothing is there."""
    out = getattr(args, "resolved_out", None) or args.out
    now = _output_stats(out)
    if not now or any(before.get(name) != st for name, st in now.items()):
        return ""  # nothing there, or this run wrote (its own message says what)
    from graphslam.cli.out_folder import holds_a_record

    whose = "an earlier command's " if holds_a_record(Path(out)) else ""  # else maybe the user's
    return f"{out}/ still holds {whose}{', '.join(now)}, not this run's"


def _trajectories_written_since(args: argparse.Namespace, started_ns: int) -> list[Path]:
    """The ``trajectory.tum`` this run wrote, or with ``--robot all`` its
    ``trajectory_robotN.tum`` (an earlier run's is never made a bag)."""
    out = getattr(args, "resolved_out", None)
    if out is None:
        return []
    out = Path(out)
    written = []
    for tum in [out / "trajectory.tum", *sorted(out.glob("trajectory_robot[0-9].tum"))]:
        try:
            if tum.stat().st_mtime_ns >= started_ns:
                written.append(tum)
        except OSError:
            continue
    return written


def _remove_if_empty(folder: Path | None) -> None:
    """Remove ``folder`` (one this run made to lock it) if no map went into it."""
    if folder is not None:
        try:
            folder.rmdir()
        except OSError:  # not empty (the map is in it), or gone
            pass


def _check_not_a_foreign_map(path: Path) -> None:
    """Refuse ``--save-map`` over a ``map.json`` that is no graphslam map (a GeoJSON of the
    user's was replaced without a word)."""
    import json

    from graphslam.maps.files import FORMAT
    from slamcore.errors import InputError

    if not path.is_file():
        return
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        doc = None
    if not (isinstance(doc, dict) and doc.get("format") == FORMAT):
        raise InputError(
            "--save-map: this map.json is not a graphslam map, and saving would replace it; "
            "choose another folder",
            path,
        )


def _check_outputs_are_not_inputs(args: argparse.Namespace) -> None:
    """Refuse an input file under the name of a file the run writes in ``--out``, or
    removes there as an earlier run's (a bag named trajectory.bag, a
    ``--ground-truth`` that is an earlier run's ground_truth.tum)."""
    from graphslam.outputs.writers import FOLDER_OUTPUT_NAMES
    from slamcore.files import check_not_inputs

    check_not_inputs(
        [("the output (in --out)", Path(args.out) / name) for name in FOLDER_OUTPUT_NAMES],
        {
            f"--{flag.replace('_', '-')}": getattr(args, flag, None)
            for flag in ("dataset", "ground_truth", "config", "intrinsics")
        },
    )


def _dispatch(args: argparse.Namespace) -> int:
    from graphslam import registry

    if registry.is_pose_graph_run(args.dataset, args.backend):
        from graphslam.cli.run import posegraph
        from slamcore.errors import GraphSlamError, InputError

        try:
            return posegraph.run(args)
        except InputError as e:
            # a file the pose-graph reader refuses at its first line, sent there by a
            # whole-graph solver: its reason, and the solver's scope
            if registry.has_pose_graph_tag(args.dataset):
                raise
            raise GraphSlamError(
                f"{e}; --backend {args.backend} solves pose-graph files only (g2o or TORO)"
            ) from None
    from graphslam.cli.run.posegraph import check_backend

    check_backend(args)
    if registry.is_visual_dataset(args.dataset):
        from graphslam.cli.run import spatial

        return spatial.run(args)
    from graphslam.cli.run import planar

    return planar.run(args)


def _write_bag(tums: list[Path]) -> None:
    """``--write-bag``: each trajectory file the run wrote (:func:`_trajectories_written_since`)
    as a bag beside it: ``trajectory.bag``, or with ``--robot all`` one
    ``trajectory_robotN.bag`` a robot (it wrote none)."""
    from graphslam.outputs.trajectory_bag import TOPIC, write_trajectory_bag
    from graphslam.sources.ground_truth import read_trajectory
    from slamcore.errors import GraphSlamError

    for tum in tums:
        if not any(
            line.strip() and not line.startswith("#") for line in tum.read_text(encoding="utf-8").splitlines()
        ):
            continue  # nothing estimated (a stop before the first pose)
        trajectory = read_trajectory(tum, "tum")
        if trajectory.stamps_s is None:  # TUM has a time column: read_trajectory broke its word
            raise GraphSlamError(f"{tum}: read without its time column")
        bag = write_trajectory_bag(tum.with_suffix(".bag"), trajectory.stamps_s, trajectory.wTc)
        print(f"wrote {bag} (geometry_msgs/PoseStamped on {TOPIC})")
