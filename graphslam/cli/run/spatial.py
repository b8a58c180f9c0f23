"""``graphslam run`` on an image sequence: parse the visual flags, run, write, print.

Called by :func:`graphslam.cli.run.command.cmd_run` when ``--dataset`` is ``synthetic-images``
or a folder. Configuration sections read from ``--config`` (flags win):
``[synthetic_images]``, ``[visual]``, ``[odometry_noise]``, ``[tracker]``,
``[active_search]``, ``[harris]``, ``[orb]``, ``[isam2_visual]``, ``[mono_ekf]``,
and with ``--loops`` ``[loops]`` (its ORB in ``[loops.orb]``), ``[loop_verify]``,
``[loop_pnp]``, ``[loop_closing]``.

Flags and what they set: ``--frontend`` -> ``tracker.detector``; ``--odometry``
-> ``visual.odometry``; ``--odometry-noise T R`` -> ``odometry_noise.sigma_t_per_m``
and ``sigma_r_deg``; ``--seed`` -> the synthetic scene, the derived-odometry
noise, the EKF's RANSAC and, without odometry, iSAM2's two-view and PnP
RANSACs (``isam2_visual.seed``); ``--max-steps`` -> frames; ``--no-polish`` ->
``isam2_visual.polish = false``. With ``--odometry none`` the EKF runs its
constant-velocity model (``mono_ekf.robot_model``) with its own
``frame_dt_s``, and iSAM2 tracks by the camera alone
(``isam2_visual.robot_model = "constant_velocity"``: a monocular start, then
PnP). ``--loops`` (or ``--vocab FILE``) runs
:class:`graphslam.pipelines.loop_closing.VisualLoopCloser` alongside the back end;
without ``--vocab`` a 1000-word vocabulary tree is first trained on the ORB
features of the frames the run will see (as ``graphslam loops`` does).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from graphslam.cli.common import (
    counts_row,
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
from slamcore.files import folder_name

#: Words of the vocabulary trained on the sequence itself (a 10-way tree of depth 3).
SELF_TRAINED_WORDS = 1000


def refuse_ignored_flags(args: argparse.Namespace, mode: str, config=None) -> None:
    """Flags that would have no effect on this visual run are refused, one line each;
    the same settings in ``config`` (the file) are said to do nothing.

    ``mode`` is the odometry the run uses (``auto`` resolved).
    """
    from graphslam import registry

    used = "the sequence's own odometry" if mode == "sequence" else "no odometry"
    if args.odometry_noise is not None and mode != "derived":
        raise ConfigError(
            f"--odometry-noise sets the noise of derived odometry; this run uses {used} (--odometry {mode})"
        )
    if config is not None and mode != "derived" and "odometry_noise" in config.data:
        warn(
            f"--config {args.config}: [odometry_noise] sets the noise of derived odometry; this run "
            f"uses {used} (--odometry {mode}): it did nothing"
        )
    if args.no_polish:
        registry.check_no_polish(args.backend)
    if args.nees:
        raise ConfigError("--nees applies to 2-D runs only")
    if getattr(args, "map", None) is not None and mode == "none":
        # the saved map would give the first pose only: the run's lengths would be its own
        raise ConfigError(
            "--map anchors the run's first pose in the saved map's metric frame; "
            "without odometry the run has a scale of its own (its first baseline), "
            "not the map's: give it odometry, or place frames with graphslam localize"
        )


def _load_sequence(args, config):
    """The image sequence of ``--dataset``, with ``--ground-truth`` if given."""
    from graphslam import registry

    sequence = registry.load_image_sequence(
        args.dataset, seed=args.seed, config=config, topics=args.topics, intrinsics=args.intrinsics
    )
    if getattr(args, "frames", None) is not None:  # first: --frames counts the files' frames
        from graphslam.sources.spatial.frames import parse_frames, select_frames

        sequence = select_frames(sequence, parse_frames(args.frames))
    if args.ground_truth is not None:  # frames without truth are dropped and said (warnings)
        from graphslam.sources.ground_truth import read_trajectory, with_ground_truth

        sequence = with_ground_truth(sequence, read_trajectory(args.ground_truth))
    for doubt in sequence.warnings:  # the reader's; metrics.json keeps them too
        warn(doubt)
    return sequence


def _estimate_camera(args, config, setup):
    """``--intrinsics estimate``: ``(setup, sequence, CameraEstimate)`` at the estimated
    camera, the rounds said on stderr unless ``--quiet``; ``(setup, its sequence, None)``
    otherwise."""
    import dataclasses

    from graphslam.sources.spatial.calibration import is_estimate

    sequence = setup.sequence
    if not is_estimate(args.intrinsics):
        return setup, sequence, None
    from graphslam.pipelines.self_calibration import estimate_camera, with_camera

    def said(start: float, k: int, f_in: float, f_out: float, k1: float, frames: int) -> None:
        if not args.quiet:
            print(
                f"estimating the camera from {start:.1f} px: round {k}: f {f_in:.1f} -> {f_out:.1f} px, "
                f"k1 {k1:.4f} ({frames} frames)",
                file=sys.stderr,
                flush=True,
            )

    camera = estimate_camera(
        sequence, config, max_frames=args.max_steps, detector=args.frontend, seed=args.seed, on_round=said
    )
    first = camera.settled[0]
    starts = " and ".join(f"{s.start_f_px:.1f}" for s in camera.settled)
    warn(
        f"camera estimated from the images: f = {first.f_px:.1f} +- {first.sigma_f_px:.1f} px, k1 = "
        f"{first.k1:.4f} +- {first.sigma_k1:.4f} (settled there from {starts} px; principal point at "
        "the centre); intrinsics.txt in the output folder holds it"
    )
    sequence = with_camera(sequence, camera.K, float(camera.distortion[0]))
    for doubt in sequence.camera_warnings:  # of the estimated camera (the start's were said)
        warn(doubt)
    return dataclasses.replace(setup, sequence=sequence), sequence, camera


def run(args: argparse.Namespace) -> int:
    """The visual ``graphslam run``; returns the exit status."""
    from graphslam import registry
    from graphslam.outputs.loops import write_loops  # stdlib only: cheap
    from graphslam.outputs.writers import OutputWrites, one_run_or_the_other, write_text
    from graphslam.pipelines import spatial as vp
    from graphslam.pipelines.session import VisualSetup

    t0 = time.perf_counter()
    if args.max_steps is not None and args.max_steps < 1:
        raise GraphSlamError("--max-steps must be at least 1")
    if args.backend not in registry.VISUAL_BACKENDS:
        raise GraphSlamError(
            f"back end {args.backend!r} does not run on image sequences "
            f"(use one of: {', '.join(registry.VISUAL_BACKENDS)})"
        )
    config = registry.read_config(args.config)
    sequence = _load_sequence(args, config)
    setup = VisualSetup.read(
        sequence,
        config,
        odometry=args.odometry,
        odometry_noise=args.odometry_noise,
        seed=args.seed,
        max_frames=args.max_steps,
        detector=args.frontend,
        no_polish=args.no_polish,
    )
    refuse_ignored_flags(args, setup.mode, config)
    loops = args.loops or args.vocab is not None
    if not (loops or getattr(args, "relocalise", False)):
        # closures come from --loops and --relocalise only (a relocalised pose joins as one)
        from graphslam.backend_table import load
        from slamcore.config import section_name

        cls = load(registry.visual_implementation(args.backend).config)
        config.mark_inert(
            section_name(cls),
            getattr(cls, "LOOP_CLOSURE_KEYS", ()),
            "--loops or --relocalise (the loop-closure factors)",
        )
    setup.check_seed([args.backend], simulated=args.dataset == "synthetic-images")
    setup, sequence, camera = _estimate_camera(args, config, setup)  # after every refusal: it takes a while
    session = setup.session(args.backend)
    backend, tracker = session.backend, session.tracker
    n_frames = len(sequence) if args.max_steps is None else min(args.max_steps, len(sequence))
    name = folder_name(sequence.source_path) if sequence.source_path else sequence.name
    out_dir = args.resolved_out = args.out or Path("runs") / f"{name}-{args.backend}"
    folder = OutputFolder(
        out_dir,
        {"trajectory.tum", "landmarks.csv", "metrics.json"}
        | ({"ground_truth.tum"} if sequence.has_ground_truth else set())
        | ({"run.rrd"} if args.rerun == "save" else set())
        | ({"loops.csv", "loops.jsonl"} if loops else set())
        | ({"intrinsics.txt"} if camera is not None else set()),
    )
    recorder = hook = None
    if args.rerun != "off":
        from graphslam.visualisation.spatial import VisualRecorder

        recorder = folder.open_recorder(VisualRecorder.open, args.rerun, "run.rrd", args.rerun_url)
        recorder.start(sequence, n_frames)
        hook = recorder.hook(args.backend)

    from graphslam.cli.run.maps import chain_hooks, save_run_map, session_extras

    prior_map, start_pose, mapper, relocaliser = session_extras(args, config, sequence, backend, tracker)
    hook = chain_hooks(hook, mapper, relocaliser)
    closer = None
    if loops:
        closer = _loop_closer(
            args,
            config,
            sequence,
            backend,
            n_frames,
            None if recorder is None else recorder.loop_hook(sequence),
        )
    from graphslam.pipelines.common import BackendFailed, FrameUnreadable

    cut = None
    try:
        result = session.run(
            progress=not args.quiet, on_frame=hook, loop_closer=closer, start_pose=start_pose
        )
    except (FrameUnreadable, BackendFailed) as e:  # the frames before it written, then the error
        result, cut = e.result, e
    metrics = _run_metrics(args, config, sequence, result, time.perf_counter() - t0, cut)
    if closer is not None:
        metrics.loops = {**closer.stats, "vocabulary": closer.vocabulary_source}
    if relocaliser is not None:
        metrics.tracking_loss = relocaliser.stats
    metrics.camera_estimate = None if camera is None else camera.to_dict()
    if prior_map is not None:  # what the run joined, and its error in the map's frame
        metrics.map = {
            "path": str(args.map),
            "start": "the first frame relocalised in the map",
            "ate_in_map_frame": vp.map_frame_ate(result),
        }
    out_dir = args.resolved_out = folder.resolve()
    # a file the disk refuses costs no other: each is tried, after the recording, if one
    # is being saved, has made room
    writes = OutputWrites(out_dir, make_room=folder.give_up_recording)
    with one_run_or_the_other(out_dir):  # a full disk: no earlier run's file left beside
        paths = vp.write_outputs(result, out_dir, metrics, writes)
        if camera is not None:
            writes(paths, "intrinsics", out_dir / "intrinsics.txt", write_text, camera.file_text())
        if closer is not None:
            from graphslam.sources.spatial.frames import source_indices

            paths.update(write_loops(closer, out_dir, writes, source_indices(sequence)))
        if (recorder := folder.recorder) is not None:  # None once given up for room
            recorder.finish(args.backend, result, every=args.rerun_every or 5)
            if closer is not None:
                recorder.log_loop_closures(args.backend, result.estimate, closer.closures)
            folder.close_recorder(paths)
    if mapper is not None:  # last: a map that cannot be built costs no other file
        writes.attempt(
            args.save_map, save_run_map, args, mapper, result, backend, closer, tracker, args.quiet, prior_map
        )
    folder.finish(paths)
    say_doubts(args, config, metrics, sequence, stopped=cut is not None or result.interrupted)
    status = report_outputs(format_summary(metrics), out_dir, paths, result.interrupted, cut, writes)
    writes.check(paths.values())
    return status


def _run_metrics(args, config, sequence, result, wall_s: float, cut):
    """The run's metrics record: scored, named, with its provenance and, when an error
    (``cut``) ended it early, that error."""
    from graphslam.pipelines import spatial as vp

    metrics = vp.compute_metrics(
        result, seed=getattr(getattr(sequence, "config", None), "seed", None), wall_s=wall_s
    )
    metrics.backend = args.backend
    metrics.backend_class = result.backend
    metrics.stopped_by = None if cut is None else str(cut)
    metrics.provenance = provenance(args, config)
    return metrics


def _loop_closer(args, config, sequence, backend, n_frames: int, on_candidate):
    """``--loops``/``--vocab``: the vocabulary (loaded, or trained on the run's frames)
    and the loop closer around it."""
    import sys

    from frontend.orb import OrbDetector
    from graphslam.pipelines import loop_closing as lc
    from graphslam.pipelines.place_recognition import (
        check_vocabulary,
        describe,
        train_vocabulary,
        vocabulary_doubt,
    )
    from loopclosure.detector import LoopDetectorConfig
    from loopclosure.pnp import PnpConfig
    from loopclosure.verify import VerifyConfig
    from loopclosure.vocabulary import load_vocabulary

    lc.require_loop_closures(backend, shown=args.backend)
    detector_config = config.section(LoopDetectorConfig)
    features = None
    if args.vocab is not None:
        vocab = load_vocabulary(args.vocab)
        check_vocabulary(vocab, args.vocab)
        source = str(args.vocab)
    else:
        features = lc.sequence_features(
            sequence, n_frames, OrbDetector(detector_config.orb), progress=not args.quiet
        )
        vocab = train_vocabulary([f.descriptors for f in features], SELF_TRAINED_WORDS)
        source = f"trained on the sequence ({n_frames} frames)"
        if not args.quiet:
            print(f"vocabulary: {describe(vocab)}", file=sys.stderr)
    if (doubt := vocabulary_doubt(vocab)) is not None:
        warn(doubt)
    return lc.make_loop_closer(
        sequence,
        backend,
        vocab,
        detector_config,
        config.section(VerifyConfig),
        config.section(PnpConfig),
        config.section(lc.LoopClosingConfig),
        features=features,
        on_candidate=on_candidate,
        vocabulary_source=source,
    )


def _frame_named(first: dict) -> str:
    """The first map's frame: the run's, and the file's where ``--frames`` moved it."""
    k, f = first["frame"], first.get("file_frame", first["frame"])
    return f"frame {k}" if k == f else f"frame {k} of the run (file frame {f})"


def format_summary(m) -> str:
    """A two-column table of the headline numbers of a visual run."""
    align = "Sim(3)" if m.alignment == "sim3" else "SE(3)"
    rpe = m.rpe or {}
    rows = [
        ("dataset", m.dataset),
        ("backend", m.backend),
        ("frontend", m.frontend),
        ("odometry", m.odometry),
        ("frames", m.frames),
        ("landmarks", m.landmarks),
        (f"ATE RMSE [m], {align}-aligned", fmt(m.ate_rmse_m, ".4f")),
        ("ATE [% of path]", fmt(m.ate_percent_of_path, ".2f")),
        ("odometry ATE RMSE [m]", fmt(m.odometry_ate_rmse_m, ".4f")),
        ("odometry ATE [% of path]", fmt(m.odometry_ate_percent_of_path, ".2f")),
        (
            "RPE per frame [m / deg]",
            "n/a" if not rpe else f"{rpe['trans_rmse_m']:.4f} / {rpe['rot_rmse_deg']:.3f}",
        ),
        ("path length [m]", fmt(m.path_length_m, ".2f")),
        ("wall time [s]", fmt(m.wall_s, ".2f")),
        ("tracking + back end [s]", fmt(m.processing_s, ".2f")),
        ("frames/s", fmt(m.frames_per_s, ".1f")),
    ]
    if m.map is not None:
        in_map = m.map.get("ate_in_map_frame")
        rows.append(("map (--map)", m.map["path"]))
        rows.append(("ATE in the map's frame [m]", "n/a" if in_map is None else f"{in_map['rmse_m']:.4f}"))
    stats = m.backend_stats or {}
    if stats.get("pose_covariance_from_isam2"):
        rows.append(
            ("numerical recovery", "polished marginals indeterminate; last pose covariance from iSAM2")
        )
    if "reparametrised" in stats:
        rows.append(("landmarks reparametrised", stats["reparametrised"]))
    if stats.get("landmarks_depth_undetermined"):  # points at a depth no parallax measured
        rows.append(
            (
                "landmarks of unmeasured depth",
                f"{stats['landmarks_depth_undetermined']} of {m.landmarks} (inverse depth within 2 sigma "
                "of 0, or known more from its prior than from the images; landmarks.csv gives "
                "their current guess)",
            )
        )
    if m.loops:
        lp = m.loops
        rows.append(
            counts_row(
                "loop closures added / verified / candidates", lp, "closures", "verified", "candidates"
            )
        )
        if lp.get("second_views"):
            rows.append(("closures from a second view of the candidate's place", lp["second_views"]))
        if lp.get("redundant"):
            rows.append(("closures skipped (map already re-observed)", lp["redundant"]))
    if m.tracking_loss:
        tl = m.tracking_loss
        rows.append(
            counts_row(
                "relocaliser's losses / relocalised / found again",
                tl,
                "losses",
                "relocalisations",
                "recovered_by_search",
            )
        )
        if tl.get("loss_rule"):  # not the camera-alone back end's losses, said apart
            rows.append(("search loss", tl["loss_rule"]))
    mono = stats.get("camera_alone")
    if mono is not None:
        first = mono.get("first_map")
        rows.append(("frames with a pose", f"{m.frames_with_pose} of {m.frames}"))
        rows.append(
            (
                "monocular map started",
                "never: " + mono.get("no_first_map_because", "")
                if first is None
                else f"{_frame_named(first)} ({first['model']}, {first['points']} points; "
                f"scale: {first['scale_gauge']})",
            )
        )
        rows.append(("frames by PnP / coasted", f"{mono['pnp_tracked_frames']} / {mono['coasted_frames']}"))
    for note in m.dataset_notes or ():
        rows.append(("data", note))
    if m.stopped_by is not None:  # not by the user: the error line below says what
        rows.append(("stopped early", "by the error below"))
    elif m.interrupted:
        rows.append(("interrupted", "yes"))
    return summary_table(rows)


def say_doubts(args, config, metrics, sequence, stopped: bool) -> None:
    """The file's unread sections, then the estimate's doubts on stderr, as every
    command's (they were in the summary on stdout, which may go to a file: hostile pass
    18); the reader's were said at the start, and a stopped run's one line is its stop."""
    warn_unread_sections(config, args.config, f"this run ({args.backend} on images)")
    if not stopped:
        warn_run_doubts(metrics.warnings, said=sequence.warnings)
