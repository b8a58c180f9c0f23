"""``graphslam run`` on 2-D data: a landmark world, a landmark log or a pose graph."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import time
from pathlib import Path
from typing import TYPE_CHECKING, cast

from graphslam.cli.common import (
    fmt,
    invocation,
    provenance,
    recoveries_text,
    report_outputs,
    summary_table,
    warn,
    warn_run_doubts,
    warn_unread_sections,
)
from graphslam.cli.out_folder import OutputFolder, claimed_folder
from slamcore.errors import ConfigError, GraphSlamError

if TYPE_CHECKING:
    from filters.ekf_localise import EkfLocaliser
    from graphslam.backends.planar.isam2_localise import Isam2Localiser

    #: What ``planar_maps.localiser`` returns (``registry.make_localiser``'s back ends).
    Localiser = Isam2Localiser | EkfLocaliser


def refuse_ignored_flags(args: argparse.Namespace) -> None:
    """Flags that would have no effect on this 2-D run are refused, one line each."""
    from graphslam import registry

    for flag in ("frontend", "odometry", "odometry_noise", "vocab", "frames", "intrinsics"):
        if getattr(args, flag, None) is not None:
            raise GraphSlamError(f"--{flag.replace('_', '-')} applies to image sequences only")
    if getattr(args, "map", None) is not None:
        if args.backend not in registry.LOCALISING_BACKENDS:
            raise ConfigError(
                f"--map: {args.backend} cannot localise against a fixed map "
                f"(2-D: {' or '.join(registry.LOCALISING_BACKENDS)})"
            )
        if getattr(args, "save_map", None) is not None:
            raise ConfigError(
                "--save-map with --map: a 2-D localisation run keeps the map "
                "fixed and adds no landmark, so there is no new map to save"
            )
    if getattr(args, "relocalise", False):
        raise GraphSlamError("--relocalise applies to image sequences only")
    if args.loops:
        raise GraphSlamError("--loops applies to image sequences only (pose graphs bring their own closures)")
    if args.max_steps is not None and args.max_steps < 1:
        raise GraphSlamError("--max-steps must be at least 1")
    if args.no_polish:
        registry.check_no_polish(args.backend)
    if args.seed is not None and registry.seed_draws_nothing(args.dataset, args.backend):
        raise ConfigError(
            f"--seed has no effect here: {args.dataset} is not simulated and "
            f"{args.backend} draws no random numbers (it seeds the synthetic "
            f"worlds and FastSLAM's particles)"
        )


def _ground_truth(args: argparse.Namespace, dataset):
    """``(dataset, truth or None)``: ``--ground-truth`` of the dataset's poses, the dataset
    then carrying the warning of a truth that leaves the plane (scored on x, y and yaw)."""
    if args.ground_truth is None:
        return dataset, None
    if dataset.agents:
        raise ConfigError(
            "--ground-truth with --robot all: one file cannot be every robot's truth (it was "
            "applied to each); the folder's RobotN_Groundtruth.dat score them, or score one "
            "robot against the file with --robot N"
        )
    from graphslam.sources.ground_truth import off_plane, planar_ground_truth, read_trajectory

    trajectory = read_trajectory(args.ground_truth)
    truth = planar_ground_truth(dataset, trajectory)
    # the reader's lines on its own truth's coverage do not describe this one (MRCLAM's
    # "truth on 1416 of 1545 frames" stood beside an ATE over 165: hostile pass 21)
    own = set(dataset.truth_lines)
    notes = [n for n in dataset.notes if n not in own]
    notes.append(
        f"truth from {Path(args.ground_truth).name}: {len(truth[0])} of the log's "
        f"{len(dataset.frames)} frames (scored there only)"
    )
    warnings = tuple(w for w in dataset.warnings if w not in own)
    dataset = dataclasses.replace(dataset, notes=tuple(notes), warnings=warnings, truth_lines=())
    if (doubt := off_plane(trajectory.wTc)) is not None:
        dataset = dataclasses.replace(dataset, warnings=(*dataset.warnings, doubt))
    return dataset, truth


def run(args: argparse.Namespace) -> int:
    """The 2-D ``graphslam run``; returns the exit status."""
    from graphslam import registry
    from graphslam.outputs.writers import OutputWrites, one_run_or_the_other
    from graphslam.pipelines import planar as pipeline

    t0 = time.perf_counter()
    refuse_ignored_flags(args)
    config = registry.read_config(args.config)
    dataset = registry.load_dataset(
        args.dataset, seed=args.seed, config=config, robot=getattr(args, "robot", None)
    )
    dataset, truth = _ground_truth(args, dataset)
    if args.nees and truth is None and not dataset.has_ground_truth:
        raise GraphSlamError(f"--nees needs ground truth; {args.dataset} has none")
    overrides = {"polish": False} if args.no_polish else {}
    overrides.update(registry.seed_override(args.backend, args.seed))
    pmap = None
    if getattr(args, "map", None) is not None:
        from graphslam.pipelines import planar_maps

        pmap = planar_maps.load_run_map(args.map, dataset, config)
        backend = planar_maps.localiser(args.backend, pmap, config, overrides)
        if dataset.agents and not backend.supports_pose_sightings:
            raise GraphSlamError(
                f"--map with --robot all: the {args.backend} localiser keeps one robot's pose; "
                "localising every robot on a map needs the isam2 back end"
            )
    else:
        backend = registry.make_backend(args.backend, config=config, overrides=overrides)
    out_dir = args.resolved_out = args.out or Path("runs") / f"{dataset.name}-{backend.name}"
    will_write = {"trajectory.tum", "landmarks.csv", "metrics.json", "ground_truth.tum", "nees.csv"}
    folder = OutputFolder(out_dir, will_write | ({"run.rrd"} if args.rerun == "save" else set()))

    n_steps = len(dataset.frames) if args.max_steps is None else min(args.max_steps, len(dataset.frames))
    log = hook = None
    if args.rerun != "off":
        from graphslam.visualisation.planar import RunRecorder

        opener = functools.partial(RunRecorder.open, background=n_steps >= RunRecorder.BACKGROUND_MIN_STEPS)
        log = folder.open_recorder(opener, args.rerun, "run.rrd", args.rerun_url)
        log.start(dataset, n_steps)
        hook = log.hook(backend.name, every=args.rerun_every or max(1, n_steps // 50))

    save_map = getattr(args, "save_map", None)
    result = pipeline.run(
        dataset,
        backend,
        max_steps=args.max_steps,
        progress=not args.quiet,
        on_step=hook,  # the recorder asks for its own covariances (finish)
        with_covariances=args.nees or save_map is not None,
        chained=registry.landmark_implementation(args.backend).filtering,
    )
    metrics = pipeline.compute_metrics(
        result,
        seed=dataset.seed,
        ground_truth=truth,
        wall_s=time.perf_counter() - t0,
        map_fixed=pmap is not None,
    )
    if args.backend in registry.SEEDED_BACKENDS:  # the particles' seed: a run repeats from it
        metrics.backend_seed = getattr(getattr(backend, "config", None), "seed", None)
    mark_unused_settings(backend, config, result.dataset, result.steps)  # before provenance, which lists them
    _mark_unread_sensor_settings(backend, config, result.dataset)
    metrics.provenance = provenance(args, config)
    if pmap is not None:  # backend is planar_maps.localiser's (annotated Backend there)
        from graphslam.pipelines import planar_maps

        metrics.map, metrics.localisation_only = str(args.map), True
        metrics.unmapped_observations = cast("Localiser", backend).unmapped_count
        metrics.ate_in_map_frame_m, doubts = planar_maps.map_frame_ate(result, truth, metrics.ate_rmse_m)
        source = planar_maps.map_source_doubt(pmap, result.dataset)
        metrics.warnings = [*(metrics.warnings or []), *([source] if source else []), *doubts] or None
        if result.observations and metrics.unmapped_observations == result.observations:
            # a map of other landmark ids: every sighting unmapped, said only as a count
            metrics.warnings = [
                *(metrics.warnings or []),
                f"none of the {result.observations} sightings is of a landmark of the map "
                f"({args.map}: its landmark ids and this run's have none in common): the run "
                "localised on its odometry alone",
            ]
    nees = None
    if args.nees and result.interrupted and registry.landmark_implementation(args.backend).filtering:
        # a filter keeps each step's covariance as it goes: the steps run are scored
        # (an interrupted --nees wrote no nees.csv at all, stop 56)
        result.estimate = backend.estimate(with_covariances=True)
    if args.nees and result.estimate.pose_covariances is None:
        # a system without marginals refused --nees before any output was written
        warn(
            "run interrupted before its covariances (a smoother's come from its marginals at "
            "the end): no nees.csv"
            if result.interrupted
            else "the estimate has no covariances (numerical recovery above): no NEES, no nees.csv"
        )
    elif args.nees and (scored := pipeline.add_nees(result, metrics, truth)) is not None:
        pose_ids, nees_k, undefined = scored
        nees = (pose_ids, nees_k)
        if undefined:
            warn(
                f"NEES undefined at {undefined} of {len(nees_k)} poses: their covariance is singular "
                "(a particle cloud collapsed to one pose, or a start known exactly); "
                "nees.csv gives them nan, the mean is over the others"
            )
    out_dir = args.resolved_out = folder.resolve()
    # a file the disk refuses costs no other: each is tried, after a recording being saved
    # has made room
    writes = OutputWrites(out_dir, make_room=folder.give_up_recording)
    with one_run_or_the_other(out_dir):  # a full disk: no earlier run's file left beside
        paths = pipeline.write_outputs(result, out_dir, metrics, ground_truth=truth, writes=writes)
        if nees is not None:
            writes(paths, "nees", out_dir / "nees.csv", pipeline.write_nees, *nees)
        if log is not None and folder.recorder is not None:  # not given up for room
            log.finish(backend.name, result, backend)
            folder.close_recorder(paths)
    folder.finish(paths)
    if not result.interrupted:  # a stopped run's one line is its stop (metrics.json keeps them)
        warn_run_doubts(metrics.warnings)
    status = report_outputs(format_summary(metrics), out_dir, paths, result.interrupted, writes=writes)
    if save_map is not None:
        # the folder --save-map locked, wherever it was moved while the run went on
        save_map = claimed_folder(Path(save_map), flag="--save-map")
        writes.attempt(
            save_map, save_planar_run_map, save_map, result, backend, config, args.max_steps, invocation(args)
        )
    warn_unread_sections(config, args.config, f"this run ({backend.name} on {dataset.name})")
    writes.check(paths.values())
    return status


def mark_unused_settings(backend, config, dataset, steps: int | None) -> None:
    """Mark the file's settings of the back end that did nothing in this run over the
    first ``steps`` frames of ``dataset`` (None: all)
    (eleventh hostile pass: ``polish_method = "gnc"`` on a landmark world and the EKF's
    ``default_sigma_range_m`` were bit-identical to the defaults, silent): its config's
    ``LOOP_CLOSURE_KEYS`` when the run had no loop closure, ``UNREAD_IN_RUNS`` always,
    ``ANONYMOUS_SIGHTING_KEYS`` under known ids when every sighting had an id,
    ``SENSOR_FIELD_KEYS`` under unknown ids when the data states no sensor field,
    ``CORRELATION_KEYS`` when no sighting states a correlation in time, ``STAMPED_KEYS``
    when no sighting has a time stamp.
    They are said with the gates' (:meth:`slamcore.config.ConfigFile.inert_lines`), with
    their file line, and listed in metrics.json's provenance."""
    from slamcore.config import section_name

    settings = getattr(backend, "config", None)
    cls = type(settings)
    closure_keys = getattr(cls, "LOOP_CLOSURE_KEYS", ())
    field_keys = getattr(cls, "SENSOR_FIELD_KEYS", ())
    correlation_keys = getattr(cls, "CORRELATION_KEYS", ())
    stamped_keys = getattr(cls, "STAMPED_KEYS", ())
    if (
        not closure_keys
        and not getattr(cls, "UNREAD_IN_RUNS", ())
        and not field_keys
        and not correlation_keys
        and not stamped_keys
    ):
        return
    section = section_name(cls)
    if field_keys and dataset.sensor_field is None and getattr(settings, "association", None) == "unknown":
        # the pruning needs the field the sensor sees and its detection probability:
        # Victoria Park and the g2o/TORO logs state neither (nothing was pruned)
        config.mark_inert(
            section, field_keys, "data that states its sensor's field (MRCLAM logs, the synthetic world)"
        )
    frames = dataset.frames[:steps]
    if correlation_keys and not any(
        o.correlation is not None and o.stamp_s is not None for f in frames for o in f.observations
    ):
        config.mark_inert(
            section, correlation_keys, "sightings that state how their errors correlate in time (MRCLAM logs)"
        )
    if stamped_keys and not any(o.stamp_s is not None for f in frames for o in f.observations):
        config.mark_inert(section, stamped_keys, "sightings with a time stamp (MRCLAM logs)")
    anonymous = getattr(cls, "ANONYMOUS_SIGHTING_KEYS", ())
    if anonymous and getattr(settings, "association", None) == "known":
        if all(o.landmark_id is not None or o.signature is not None for f in frames for o in f.observations):
            config.mark_inert(
                section,
                anonymous,
                'association = "unknown" (under known ids, sightings without an id; this run had none)',
            )
    if closure_keys and not any(f.loop_closures for f in frames):
        config.mark_inert(section, closure_keys, "loop closures (this run had none)")
    config.mark_inert(
        section,
        getattr(cls, "UNREAD_IN_RUNS", ()),
        "observations without a covariance of their own (the Python API; every "
        "observation of a run brings one)",
    )


#: When the MRCLAM reader's settings of each sensor-field part act (``Backend.sensor_field_use``).
_FIELD_PART_USE = {
    "error_dof": 'association = "unknown" (the gates that start a landmark)',
    "field": "the ekf's or fastslam's pruning of landmarks missed in view "
    '(association = "unknown", prune_missed_alpha)',
}


def _mark_unread_sensor_settings(backend, config, dataset) -> None:
    """Mark the file's ``[mrclam]`` settings of the sensor field's parts and of the
    sightings' correlation in time that the run's back end, as configured, does not
    read (hostile pass 18: ``sighting_error_dof`` under known ids, the field under
    iSAM2, the correlation under FastSLAM without ``temper_correlated`` changed
    nothing, unsaid)."""
    mark_unread_sensor_settings([backend], config, dataset)


def mark_unread_sensor_settings(backends, config, dataset) -> None:
    """:func:`_mark_unread_sensor_settings` for several back ends run on one dataset
    (``compare``): a setting is marked when none of them reads it."""
    from graphslam.sources.planar.mrclam import MrclamConfig, is_mrclam_folder

    if dataset.source_path is None or not is_mrclam_folder(dataset.source_path):
        return
    used = {part for b in backends for part in getattr(b, "sensor_field_use", frozenset)()}
    if any(f.wTb_true is not None for f in dataset.frames):
        used.add("error_dof")  # the reader's check of the sightings against the truth reads it
    for part, keys in MrclamConfig.SENSOR_FIELD_PARTS.items():
        if part not in used:
            config.mark_inert(MrclamConfig.SECTION, keys, _FIELD_PART_USE[part])
    if not any(getattr(b, "reads_sighting_correlation", bool)() for b in backends):
        config.mark_inert(
            MrclamConfig.SECTION,
            MrclamConfig.CORRELATION_KEYS,
            "a back end that weighs sightings by their correlation in time (isam2, ekf; fastslam "
            "with temper_correlated)",
        )


def save_planar_run_map(
    folder: Path, result, backend, config, max_steps, provenance: dict | None = None
) -> None:
    """``--save-map``: the run's landmarks and covariances to ``folder``; say so on stdout.
    ``provenance``: where and with what the run ran (:func:`~graphslam.cli.common.invocation`),
    kept in map.json."""
    from graphslam.maps.files import save_planar_map
    from graphslam.pipelines.planar_maps import build_run_map

    if result.interrupted:  # no covariances, not finalised: no map from half an estimate
        warn(f"run stopped before its end: no map saved in {folder}")
        return
    pmap = build_run_map(result, backend, config, max_steps)
    if provenance is not None:
        pmap.meta["provenance"] = provenance
    save_planar_map(pmap, folder)
    print(
        f"map in {folder}/: {pmap.n_landmarks} landmarks with covariances "
        f"({result.steps} steps of {result.dataset.name}, {result.backend})"
    )
    if pmap.n_landmarks and not _has_bearings(result.dataset):
        # saved in silence, then refused by every localiser (hostile pass 19)
        warn(
            f"the map in {folder} is of range-only beacons: no back end localises against "
            "ranges alone (--map takes range-bearing sightings)"
        )
    if pmap.n_landmarks == 0:  # saved in silence; run --map then placed nothing (hostile pass 16)
        warn(
            f"the map in {folder} has no landmark: a run against it (--map) can place nothing "
            "(a run of more steps, with landmark sightings, makes one)"
        )


def _matched(metrics) -> str:
    """``"38 landmarks"``, or ``"27 landmarks on 15 true ones"`` where some are copies
    (the summary counted copies as matched landmarks, silent: twelfth hostile pass)."""
    n, distinct = metrics.landmarks_matched, metrics.landmarks_matched_true
    if distinct is None or distinct == n:
        return f"{n} landmarks"
    return f"{n} landmarks on {distinct} true ones"


def format_summary(metrics) -> str:
    """A two-column table of the headline numbers."""
    rows = [
        ("dataset", metrics.dataset),
        ("backend", metrics.backend),
        ("steps", metrics.steps),
        ("landmarks", metrics.landmarks),
        ("final error", fmt(metrics.final_error, ".6g")),
        (
            "ATE RMSE [m]",
            fmt(metrics.ate_rmse_m, ".4f")
            + (
                f" (over the {metrics.ate_poses} of {metrics.steps} poses with truth)"
                if metrics.ate_poses is not None and metrics.ate_poses < metrics.steps
                else ""
            ),
        ),
        ("odometry ATE RMSE [m]", fmt(metrics.odometry_ate_rmse_m, ".4f")),
        ("wall time [s]", fmt(metrics.wall_s, ".2f")),
        ("back end [s]", fmt(metrics.backend_s, ".2f")),
        ("back end steps/s", fmt(metrics.steps_per_s, ".1f")),
    ]
    if metrics.map_rmse_m is not None:
        rows.append(("map RMSE [m]", f"{metrics.map_rmse_m:.4f} ({_matched(metrics)}, trajectory-aligned)"))
        rows.append(("map RMSE, map-aligned [m]", fmt(metrics.map_rmse_m_map_aligned, ".4f")))
        rows.append(
            ("landmarks recovered", f"{metrics.landmarks_recovered} of {metrics.landmarks_true} within 0.3 m")
        )
    if metrics.nees_mean is not None:
        rows.append(("mean NEES (3 dof)", fmt(metrics.nees_mean, ".4g")))
        rows.append(("NEES in 95 % bounds", fmt(metrics.nees_in_bounds_fraction, ".2f")))
    for name, a in (metrics.agents or {}).items():
        rows.append(
            (
                f"ATE RMSE {name} [m]",
                f"{a['ate_rmse_m']:.4f} (odometry {a['odometry_ate_rmse_m']:.4f}, over {a['poses']} of "
                f"{a['poses_estimated']} poses)",
            )
        )
    for note in metrics.dataset_notes or ():
        rows.append(("data", note))
    if metrics.landmarks_pruned:
        rows.append(("landmarks pruned", f"{metrics.landmarks_pruned} (missed in the sensor's field)"))
    if metrics.observations_rejected:
        rows.append(("sightings rejected", f"{metrics.observations_rejected} (beyond the back end's gate)"))
    if metrics.records_restarted:
        rows.append(
            (
                "records restarted",
                f"{metrics.records_restarted} (held out by the gate too long; per particle)",
            )
        )
    if metrics.sightings_reassociated:
        settled = (
            ""
            if metrics.reassociation_settled
            else "; its last pass still moved some (isam2.reassociation_passes)"
        )
        rows.append(
            ("sightings re-associated", f"{metrics.sightings_reassociated} at the end of the run{settled}")
        )
    if metrics.loop_closures_skipped:
        rows.append(("loop closures skipped", metrics.loop_closures_skipped))
    for note in metrics.numerical_recoveries or ():
        rows.append(("numerical recovery", note))
    if metrics.recoveries and any(metrics.recoveries.values()):
        rows.append(("numerical recoveries", recoveries_text(metrics.recoveries)))
    if metrics.localisation_only:
        rows.append(("localisation only", f"map {metrics.map}"))
        rows.append(("unmapped observations", metrics.unmapped_observations))
        if metrics.ate_in_map_frame_m is not None:
            rows.append(("ATE in the map's frame (no fit) [m]", fmt(metrics.ate_in_map_frame_m, ".4f")))
    if metrics.interrupted:
        rows.append(("interrupted", "yes"))
    return summary_table(rows)


def _has_bearings(dataset) -> bool:
    """Whether any frame of ``dataset`` holds a range-bearing sighting."""
    from slamcore.planar.records import ObservationKind

    return any(o.kind is ObservationKind.RANGE_BEARING for f in dataset.frames for o in f.observations)
