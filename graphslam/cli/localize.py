"""``graphslam localize --map DIR --dataset NAME|FOLDER``: place a sequence in a saved map.

The map (from ``graphslam run --save-map``) stays fixed; each frame is placed
by place recognition and PnP, then tracked against the map's landmarks while
it can (:mod:`graphslam.pipelines.localize`). Configuration sections read from
``--config``: ``[localize]``, ``[loop_pnp]`` (relocalisation PnP and the
covariance), ``[harris]``/``[orb]`` (the corner detector, the map's kind),
``[synthetic_images]``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from graphslam.cli.common import (
    add_command,
    add_config_option,
    add_frames_option,
    add_intrinsics_option,
    add_out_dir_option,
    add_quiet_option,
    add_rerun_options,
    add_topics_option,
    check_out_keeps_the_camera,
    fmt,
    invocation,
    path_arg,
    refuse_intrinsics_estimate,
    report_outputs,
    summary_table,
    warn,
    warn_unread_sections,
)
from graphslam.cli.out_folder import OutputFolder
from graphslam.outputs.writers import OutputWrites
from slamcore.files import folder_name

EPILOG = """\
outputs (in --out, default runs/<dataset>-localize):
  localize.csv      frame,t,status,x,y,z,qx,qy,qz,qw,c00..c55: per frame the status
                    (tracked, relocalised, lost), the pose in the map's frame and
                    its covariance (21 upper-triangle entries, [rho, phi] order)
  trajectory.tum    the placed frames; ground_truth.tum the same frames' truth
  metrics.json      frames, localised_fraction, tracked, relocalisations,
                    lost_frames, ate_rmse_m (no alignment: the map's frame),
                    error_median_m, error_max_m, frames_over_0_5m
  localize.rrd      Rerun: the map in grey, the live camera over it

examples:
  graphslam run --dataset synthetic-images --frames 0:200 --save-map maps/room
  graphslam localize --map maps/room --dataset synthetic-images --frames 200:300
"""


def register(sub) -> None:
    p = add_command(
        sub,
        "localize",
        cmd_localize,
        help="localise an image sequence against a saved map (map fixed)",
        description="Place every frame of an image sequence in a map saved by "
        "'graphslam run --save-map': place recognition, PnP RANSAC, then "
        "tracking against the map's landmarks, relocalising when lost.",
        epilog=EPILOG,
    )
    p.add_argument(
        "--map",
        type=path_arg,
        required=True,
        metavar="DIR",
        help="map folder written by 'graphslam run --save-map'",
    )
    p.add_argument(
        "--dataset",
        required=True,
        metavar="NAME|FOLDER",
        help="synthetic-images or an image-sequence folder (same camera as the map)",
    )
    add_topics_option(p)
    add_intrinsics_option(p)
    add_frames_option(p, "localise these frames only (Python slice; 159::-2 plays backwards)")
    add_out_dir_option(p)
    add_config_option(p, "TOML or YAML file ([localize], [loop_pnp], [harris], [orb], ...)")
    add_rerun_options(p, "save localize.rrd in --out (default), spawn or connect a viewer, or off")
    add_quiet_option(p)


def cmd_localize(args: argparse.Namespace) -> int:
    from graphslam import registry
    from graphslam.cli.common import check_rerun_flags, rerun_sink, warn_shadowed_dataset
    from graphslam.maps.files import load_map
    from graphslam.pipelines import localize_run
    from graphslam.pipelines.session import LocaliseSession
    from graphslam.sources.spatial.frames import parse_frames, select_frames
    from slamcore.files import check_no_folder_at

    t0 = time.perf_counter()
    check_rerun_flags(args)
    args.rerun = rerun_sink(args.rerun, args.rerun_url, "localize.rrd")
    frames = None if args.frames is None else parse_frames(args.frames)
    registry.check_dataset_named(args.dataset)  # a typo is said as one, not as a misused --topics
    warn_shadowed_dataset(args.dataset)
    registry.check_topics_flag(args.dataset, args.topics)
    if not registry.is_visual_dataset(args.dataset):
        from slamcore.errors import InputError

        raise InputError("not an image sequence (synthetic-images or a folder)", args.dataset)
    if args.out is not None:  # refused now, not after loading the map
        from slamcore.files import check_output_dir

        check_output_dir(args.out)
        check_out_keeps_the_camera(args.dataset, args.out)
    refuse_intrinsics_estimate(args.intrinsics, "localize")
    smap = load_map(args.map)
    config = registry.read_config(args.config)
    sequence = select_frames(
        registry.load_image_sequence(
            args.dataset, config=config, topics=args.topics, intrinsics=args.intrinsics
        ),
        frames,
    )
    session = LocaliseSession.open(sequence, config, smap, args.dataset)
    # a run's config reused: its tracker and back end are the map's business
    warn_unread_sections(config, args.config, "localize (the map fixes its tracker and back end)")
    for doubt in sequence.warnings:  # the reader's; metrics.json keeps them too
        warn(doubt)
    name = folder_name(sequence.source_path) if sequence.source_path else sequence.name
    out_dir = args.out or Path("runs") / f"{name}-localize"
    folder = OutputFolder(out_dir)
    names = {"localize.csv", "trajectory.tum", "metrics.json", "ground_truth.tum", "localize.rrd"}
    # refused now, not after the frames are placed
    check_no_folder_at(out_dir, names - ({"localize.rrd"} if args.rerun == "off" else set()))
    recorder = hook = None
    if args.rerun != "off":
        from graphslam.visualisation.spatial import LocalizeRecorder

        recorder = folder.open_recorder(LocalizeRecorder.open, args.rerun, "localize.rrd", args.rerun_url)
        recorder.start_map(smap, sequence, len(sequence))
        hook = recorder.log_placement
    from graphslam.pipelines.common import FrameUnreadable

    cut = None
    try:
        result = session.run(progress=not args.quiet, on_frame=hook)
    except FrameUnreadable as e:  # the frames placed before it are written, then the error said
        result, cut = e.result, e
    map_info = {
        "path": str(args.map),
        **smap.counts(),
        "built_from": smap.meta.get("frames"),
        # a map built from the camera alone is in a scale of its own (its first baseline)
        "metric": smap.meta.get("odometry") != "none",
    }
    metrics = localize_run.compute_metrics(result, map_info, wall_s=time.perf_counter() - t0)
    metrics["provenance"] = invocation(args)
    for doubt in metrics.get("warnings", []):  # what the scores mean (metrics.json says it too)
        if doubt not in sequence.warnings:  # the reader's were said above
            warn(doubt)
    if metrics["frames"] and not metrics["localised_fraction"] and not result.interrupted:
        # 0.0 %, a trajectory.tum of its header and exit 0 said nothing (hostile pass 16)
        nothing = (
            f"no frame of {metrics['frames']} was placed in the map: these frames do not see "
            "the mapped place (another part of the sequence, another scene), or the map is too "
            "sparse to relocalise in"
        )
        metrics.setdefault("warnings", []).append(nothing)
        warn(nothing)
    out_dir = folder.resolve()
    # a file the disk refuses costs no other: each is tried, after a recording being saved
    # has made room
    writes = OutputWrites(out_dir, make_room=folder.give_up_recording)
    paths = localize_run.write_outputs(result, out_dir, metrics, writes)
    folder.close_recorder(paths)
    folder.finish(paths)
    status = report_outputs(format_summary(metrics), out_dir, paths, result.interrupted, cut, writes)
    writes.check(paths.values())
    return status


def format_summary(m: dict) -> str:
    rows = [
        ("dataset", m["dataset"]),
        ("map keyframes / landmarks", f"{m['map']['keyframes']} / {m['map']['landmarks']}"),
        ("frames", m["frames"]),
        ("localised", fmt(100 * m["localised_fraction"], ".1f") + " %"),
        ("tracked / relocalised / lost", f"{m['tracked']} / {m['relocalisations']} / {m['lost_frames']}"),
        (
            "ATE RMSE [m], map frame"
            if m.get("ate_alignment", "none").startswith("none")
            else "ATE RMSE [m], Sim(3)-aligned",
            fmt(m.get("ate_rmse_m"), ".4f"),
        ),
        (
            "median / max error [m]",
            f"{fmt(m.get('error_median_m'), '.4f')} / {fmt(m.get('error_max_m'), '.4f')}",
        ),
        ("wall time [s]", fmt(m["wall_s"], ".2f")),
        ("frames/s", fmt(m["frames_per_s"], ".1f")),
    ]
    if m["interrupted"]:
        rows.append(("interrupted", "yes"))
    return summary_table(rows)
