"""Run a dataset through a back end, collect metrics, write outputs.

The pipeline is where packages are wired together; it computes and returns,
and leaves printing to the CLI.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from graphslam.evaluation.records import PlanarRunMetrics
from graphslam.outputs.writers import OutputWrites
from graphslam.pipelines.common import interrupt_between_frames, progress_bar, signal_hook, stop_requested
from slamcore.errors import GraphSlamError
from slamcore.planar import geometry as se2
from slamcore.planar.backend import Backend
from slamcore.planar.records import Dataset, Estimate, Frame

#: ``on_step(step_index, frame, backend)`` hook, called after each frame.
StepHook = Callable[[int, Frame, Backend], None]


@dataclass
class RunResult:
    """What one run produced.

    Attributes:
        estimate: final estimate (polished if the back end does that).
        steps: frames processed (the first, anchoring frame included).
        wall_s: processing time of the frames plus finalisation (not the
            covariances fetched for reporting), seconds.
        interrupted: True if stopped by Ctrl-C; the estimate is what was
            estimated up to then.
        associations: per processed observation ``(true_id, assigned_id)``,
            where the data has ground-truth landmark ids.
        loop_closures_skipped: constraints a back end could not use.
        numerical_recoveries: switches the back end made (another factorisation).
        recoveries: the back end's per-update safeguards counted by kind (the
            filters' ``recoveries``; None for back ends that keep none).
        landmarks_pruned: landmarks the back end removed from its map as missed
            in the sensor's field (:meth:`~slamcore.planar.backend.Backend.pruned_landmark_ids`).
        observations: landmark observations streamed into the back end.
        observations_rejected: of those, identified ones its gate rejected
            (:meth:`~slamcore.planar.backend.Backend.rejected_observations`).
        records_restarted: landmark estimates started again from a sighting after the
            back end's gate held that landmark out too long
            (:meth:`~slamcore.planar.backend.Backend.restarted_landmark_records`).
        reassociation: ``(sightings moved, settled)`` of the back end's re-association at
            the end of the run (iSAM2 with unknown ids): ``settled`` False when its last
            pass still moved sightings; None where the back end has none.
        paired: ``(pose id, place in its update) -> landmark id or None`` (unused) of the
            observations the estimate pairs otherwise than their own ``landmark_id``
            (unknown association: every one), after the back end's revisions; empty with
            known association. The final error is taken over the graph so paired
            (:func:`paired_dataset`): the dataset's own ids name no landmark of the estimate.
    """

    dataset: Dataset
    backend: str
    estimate: Estimate
    steps: int
    wall_s: float
    interrupted: bool = False
    associations: list[tuple[int, int | None]] = field(default_factory=list)
    loop_closures_skipped: int = 0
    numerical_recoveries: list[str] = field(default_factory=list)
    recoveries: dict[str, int] | None = None
    landmarks_pruned: int = 0
    observations: int = 0
    observations_rejected: int = 0
    reassociation: tuple[int, bool] | None = None
    paired: dict[tuple[int, int], int | None] = field(default_factory=dict)
    records_restarted: int = 0


def run(
    dataset: Dataset,
    backend: Backend,
    *,
    max_steps: int | None = None,
    progress: bool = False,
    on_step: StepHook | None = None,
    with_covariances: bool = False,
    chained: bool = False,
) -> RunResult:
    """Stream ``dataset`` into ``backend`` and finalise. ``chained``: the back end is a
    filter (:attr:`graphslam.backend_table.Implementation.filtering`), which keeps only
    each robot's latest pose: an odometry step it would refuse part way is refused
    before the first frame (:func:`filters.planar_inputs.chain_break`).

    Ctrl-C or SIGTERM (:mod:`graphslam.pipelines.common`) stops the loop at the
    next frame; the estimate so far is still returned (without the final
    polish and the covariances) with ``interrupted=True``.
    """
    if max_steps is not None and (
        isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1
    ):
        # -1 ran all frames but the last and True one frame, as slices (twentieth hostile pass)
        raise GraphSlamError(f"max_steps must be a whole number >= 1 or None, got {max_steps!r}")
    frames = dataset.frames if max_steps is None else dataset.frames[:max_steps]
    if not frames:
        raise GraphSlamError(f"dataset {dataset.name!r} has no frames")
    if chained:
        from filters.planar_inputs import chain_break

        broken = chain_break(frames[0].pose_id, ((f.odometry, f.pose_id) for f in frames[1:]), backend.name)
        if broken is not None:
            raise GraphSlamError(broken)
    bar = progress_bar(len(frames), dataset.name, backend.name, progress)
    assoc: list[tuple[int, int | None]] = []
    slots: list[tuple[int, int]] = []  # (pose id, place in its update) of each of assoc
    paired: dict = {}  # where the back end's id is not the data's (_pair)
    counters = {"steps": 0, "skipped": 0, "observations": 0}
    interrupted = False
    t0 = time.perf_counter()
    try:
        with interrupt_between_frames() as stop:
            _feed(frames, dataset, backend, stop, (assoc, slots, paired), on_step, bar, counters)
            signal_hook("finalize")
        estimate = backend.finalize()
        # a stop asked for during finalisation: the estimate is whole, the
        # covariances (reporting only) are skipped
        interrupted = stop.requested
    except KeyboardInterrupt:
        interrupted = True
        if counters["steps"] == 0:
            raise
        estimate = backend.estimate(with_covariances=False)
    finally:
        if bar is not None:
            bar.close()
    wall_s = time.perf_counter() - t0
    if with_covariances and not interrupted:
        # fetched after the clock stops: reporting, not estimation
        estimate = backend.estimate(with_covariances=True)
    recoveries = getattr(backend, "recoveries", None)
    # an interrupt may have cut a revision short: then score the pairings as decided
    revised = None if interrupted else backend.final_associations()
    if revised is not None:  # scored as the estimate pairs them, not as first decided
        assoc = [(true_id, revised.get(slot)) for (true_id, _), slot in zip(assoc, slots, strict=True)]
        paired = _revised_pairing(frames[: counters["steps"]], revised)
    paired = finish_pairing(paired)
    reassociation = backend.reassociation()
    return RunResult(
        dataset,
        backend.name,
        estimate,
        counters["steps"],
        wall_s,
        interrupted,
        assoc,
        counters["skipped"],
        backend.numerical_recoveries(),
        None if recoveries is None else dict(recoveries),
        len(backend.pruned_landmark_ids()),
        counters["observations"],
        backend.rejected_observations(),
        reassociation,
        paired,
        records_restarted=backend.restarted_landmark_records(),
    )


def _pair(frame, given: list[int | None], paired: dict) -> None:
    """Record in ``paired`` the observations of ``frame`` the back end gave another id than
    their own (``given``), and under the key ``None`` those it left unused: with known
    ids a gated-out sighting stays in the final error's graph, with the back end's own
    ids (:func:`finish_pairing`) it leaves it."""
    unused = paired.setdefault(None, [])
    for i, (o, got) in enumerate(zip(frame.observations, given, strict=True)):
        if got is None:
            if o.landmark_id is not None:
                unused.append((o.pose_id, i))
        elif got != o.landmark_id:
            paired[(o.pose_id, i)] = got


def finish_pairing(paired: dict) -> dict[tuple[int, int], int | None]:
    """:attr:`RunResult.paired` from what :func:`_pair` recorded: the unused observations
    are None only where the back end gave its own ids to others (unknown association)."""
    unused = paired.pop(None, [])
    if paired:
        paired.update(dict.fromkeys(unused))
    return paired


def _revised_pairing(frames, revised: dict[tuple[int, int], int]) -> dict[tuple[int, int], int | None]:
    """:attr:`RunResult.paired` from the back end's final pairings ``revised`` (an
    observation absent from them was left unused)."""
    out: dict[tuple[int, int], int | None] = {}
    for frame in frames:
        for i, o in enumerate(frame.observations):
            got = revised.get((o.pose_id, i))
            if got is None or got != o.landmark_id:
                out[(o.pose_id, i)] = got
    return out


def paired_dataset(
    dataset: Dataset, paired: dict[tuple[int, int], int | None], landmark_ids: np.ndarray, prune: bool = False
) -> Dataset:
    """``dataset`` with each observation's ``landmark_id`` as the run paired it, for the
    final error of a run that associated: None (left out of the graph) where it was
    unused or its landmark is not among the estimate's ``landmark_ids`` (a filter pruned
    it, or FastSLAM's best particle of the time is not the final one). ``prune``: the
    latter also without pairings (a ``--map`` run, whose sightings of landmarks not in the
    map are unused: one of them made the final error n/a and skipped its test)."""
    if not paired and not prune:
        return dataset
    kept = set(np.asarray(landmark_ids).tolist())
    frames = []
    for frame in dataset.frames:
        obs = []
        for i, o in enumerate(frame.observations):
            got = paired.get((o.pose_id, i), o.landmark_id)
            obs.append(replace(o, landmark_id=got if got in kept else None))
        frames.append(replace(frame, observations=tuple(obs)))
    return replace(dataset, frames=tuple(frames))


def _feed(frames, dataset, backend, stop, scored, on_step, bar, counters) -> None:
    """Stream frames into the back end; a pending Ctrl-C is honoured between frames.
    ``scored``: the lists ``(true id, id given)`` and ``(pose id, place)`` of the
    observations with a true id, and the pairing of those given another id than their
    own (:attr:`RunResult.paired`), filled in step."""
    assoc, slots, paired = scored
    for k, frame in enumerate(frames):
        stop.check()
        if k == 0:
            backend.set_robot_count(max(1, len(dataset.agents)))
            backend.initialize(frame.pose_id, dataset.prior_wTb, dataset.prior_covariance)
            backend.set_sensor_field(dataset.sensor_field)
        else:
            if frame.odometry is None:
                raise GraphSlamError(f"frame {k} (pose {frame.pose_id}) has no odometry")
            backend.predict(frame.odometry, frame.pose_id)
        if frame.observations:
            backend.update(frame.observations)
            counters["observations"] += len(frame.observations)
            _pair(frame, backend.associations(), paired)
            if frame.true_landmark_ids is not None:
                assoc.extend(zip(frame.true_landmark_ids, backend.associations(), strict=True))
                slots.extend((o.pose_id, i) for i, o in enumerate(frame.observations))
        for lc in frame.loop_closures:
            if backend.supports_loop_closures:
                backend.add_loop_closure(lc)
            else:
                counters["skipped"] += 1
        for ps in frame.pose_sightings:
            backend.add_pose_sighting(ps)  # the EKF localiser refuses: one robot's pose
        counters["steps"] = k + 1
        if on_step is not None:
            on_step(k, frame, backend)
        if bar is not None:
            bar.update(1)
        signal_hook("step", k)


def dead_reckoning(dataset: Dataset, steps: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Odometry-only trajectory ``(pose_ids (N,), wTb (N, 3))`` from the prior pose."""
    frames = dataset.frames if steps is None else dataset.frames[:steps]
    poses = {frames[0].pose_id: np.asarray(dataset.prior_wTb, dtype=np.float64)}
    for frame in frames[1:]:
        odo = frame.odometry
        if odo is None:  # only the first frame has none
            raise GraphSlamError(f"pose {frame.pose_id}: a frame after the first without odometry")
        if odo.to_id == frame.pose_id:
            poses[frame.pose_id] = se2.compose(poses[odo.from_id], odo.delta)
        else:
            poses[frame.pose_id] = se2.compose(poses[odo.to_id], se2.inverse(odo.delta))
    ids = np.array([f.pose_id for f in frames], dtype=np.int64)
    return ids, np.array([poses[i] for i in ids])


def compute_metrics(
    result: RunResult,
    *,
    seed: int | None = None,
    with_graph_error: bool = True,
    ground_truth: tuple[np.ndarray, np.ndarray] | None = None,
    wall_s: float | None = None,
    map_fixed: bool = False,
) -> PlanarRunMetrics:
    """The metrics of ``metrics.json`` for one run.

    Args:
        map_fixed: the run localised against a saved map: it made no landmark, so the
            line on landmarks made from too few sightings does not apply.
        ground_truth: ``(pose_ids (M,), wTb (M, 3))`` to score against instead
            of the dataset's own (``--ground-truth``); ATE is over the common ids.
        wall_s: the whole run's time (loading, running, scoring), seconds;
            without it ``wall_s`` is the back end's ``backend_s``. ``steps_per_s``
            is always the back end's rate.
    """
    from graphslam.evaluation import planar as metrics

    est = result.estimate
    final_error = ate = odo_ate = cost = None
    if with_graph_error:
        from graphslam import registry
        from graphslam.backends.gtsam_convert import graph_cost

        row = registry.descriptor(result.backend)
        # a filter's last estimate is not a least-squares optimum: its cost is reported,
        # not tested, and the test's bulk figure is not computed for it
        smoother = not (row is None or row.landmarks is None or row.landmarks.filtering)
        cost = graph_cost(
            paired_dataset(result.dataset, result.paired, est.landmark_ids, prune=map_fixed),
            est,
            bulk=smoother,
        )
        final_error = None if cost is None else cost[0]
        if not smoother:
            cost = None
    gt = result.dataset.ground_truth() if ground_truth is None else _checked_truth(ground_truth)
    # ATE needs two common poses: a run cut after its first step has none (null)
    ate_poses = spread = None
    common = 0 if gt is None else np.intersect1d(est.pose_ids, gt[0]).size
    n_est = len(est.pose_ids)
    unscored = (
        [f"ATE not scored: the ground truth given shares {common} pose ids with the estimate's {n_est}"]
        if ground_truth is not None and common < 2 <= n_est
        else []
    )
    if gt is not None and common >= 2:
        scored = metrics.ate(est.pose_ids, est.wTb, *gt)
        ate, ate_poses = scored["rmse_m"], scored["n"]
        spread = metrics.truth_spread_m(est.pose_ids, *gt)
        odo_ids, odo_wTb = dead_reckoning(result.dataset, result.steps)
        odo_ate = metrics.ate(odo_ids, odo_wTb, *gt)["rmse_m"]
    agents = None
    if result.dataset.agents and gt is not None and ate is not None:
        agents = agent_ates(result, gt)
    moved, settled = result.reassociation or (None, None)
    map_scores = {}
    if result.dataset.landmarks_true and gt is not None:
        map_scores = metrics.map_errors(est, gt, result.dataset.landmarks_true, result.associations)
    return PlanarRunMetrics(
        **map_scores,
        dataset_notes=list(result.dataset.notes) or None,
        agents=agents,
        ate_poses=ate_poses,
        dataset=result.dataset.name,
        backend=result.backend,
        seed=seed,
        steps=result.steps,
        landmarks=int(len(est.landmark_ids)),
        final_error=final_error,
        ate_rmse_m=ate,
        odometry_ate_rmse_m=odo_ate,
        wall_s=result.wall_s if wall_s is None else wall_s,
        backend_s=result.wall_s,
        steps_per_s=result.steps / result.wall_s if result.wall_s > 0 else None,
        interrupted=result.interrupted,
        loop_closures_skipped=result.loop_closures_skipped,
        association=_made_none(metrics.association_accuracy(result.associations), map_fixed),
        sightings_reassociated=moved,
        reassociation_settled=settled,
        numerical_recoveries=result.numerical_recoveries or None,
        recoveries=result.recoveries,
        landmarks_pruned=result.landmarks_pruned or None,
        observations_rejected=result.observations_rejected or None,
        records_restarted=result.records_restarted or None,
        # the reader's doubts about the input first, then the estimate's
        warnings=[
            *result.dataset.warnings,
            *metrics.estimate_warnings(est, ate, odo_ate, ate_poses, cost, spread),
            *metrics.rejected_warning(result.observations, result.observations_rejected),
            *(
                []
                if map_fixed
                else metrics.map_warning(
                    result.observations, result.observations_rejected, len(est.landmark_ids)
                )
            ),
            *metrics.truth_map_warning(
                len(est.landmark_ids), map_scores, metrics.landmark_spread_m(result.dataset.landmarks_true)
            ),
            *metrics.skipped_closures_warning(result.loop_closures_skipped, result.backend),
            *unscored,
        ]
        or None,
    )


def _checked_truth(ground_truth) -> tuple[np.ndarray, np.ndarray]:
    """``(pose_ids (M,), wTb (M, 3))``, or GraphSlamError: a dict or a triple ended in
    numpy's ValueError or TypeError (twentieth hostile pass, the Python API)."""
    try:
        ids, wTb = ground_truth
        ids, wTb = np.asarray(ids), np.asarray(wTb, dtype=np.float64)
    except (TypeError, ValueError):
        raise GraphSlamError("ground_truth must be (pose_ids (M,), wTb (M, 3))") from None
    if ids.ndim != 1 or wTb.shape != (len(ids), 3):
        raise GraphSlamError(
            f"ground_truth must be (pose_ids (M,), wTb (M, 3)), got {ids.shape} and {wTb.shape}"
        )
    return ids, wTb


def _made_none(score, map_fixed: bool):
    """``score`` of a run that localised on a saved map: it made no landmark (its
    ``landmarks_created`` counted the map's landmarks it sighted, 15 of 15 on MRCLAM,
    hostile pass 21)."""
    if score is None or not map_fixed:
        return score
    return replace(score, landmarks_created=0)


def agent_ates(result: RunResult, ground_truth) -> dict[str, dict]:
    """Each robot's own ATE (its own SE(2) alignment, as a run of it alone is scored)
    and its dead reckoning's, over its poses with truth."""
    from graphslam.evaluation import planar as metrics

    est = result.estimate
    odo_ids, odo_wTb = dead_reckoning(result.dataset, result.steps)
    out = {}
    for name, agent_ids in result.dataset.agents:
        ids = np.asarray(agent_ids, dtype=np.int64)
        keep = np.isin(est.pose_ids, ids)
        scored = np.intersect1d(est.pose_ids[keep], ground_truth[0]).size
        if scored < 2:
            continue
        mine = np.isin(odo_ids, ids)
        out[name] = {
            "ate_rmse_m": metrics.ate(est.pose_ids[keep], est.wTb[keep], *ground_truth)["rmse_m"],
            "odometry_ate_rmse_m": metrics.ate(odo_ids[mine], odo_wTb[mine], *ground_truth)["rmse_m"],
            # the ATE's own count: a robot's poses without truth (Vicon starting late) are
            # not in it, and "2617 poses" read as scored over 2428 (hostile pass 21)
            "poses": scored,
            "poses_estimated": int(keep.sum()),
        }
    return out


def write_outputs(
    result: RunResult,
    out_dir: Path,
    run_metrics: PlanarRunMetrics,
    ground_truth: tuple[np.ndarray, np.ndarray] | None = None,
    writes: OutputWrites | None = None,
) -> dict[str, Path]:
    """Write ``trajectory.tum``, ``landmarks.csv``, ``metrics.json`` and, when the
    run has truth (``ground_truth`` or the dataset's), ``ground_truth.tum`` for the
    run's poses with the same time column; return the paths written. A run of several
    robots writes ``trajectory_robotN.tum`` and ``ground_truth_robotN.tum`` instead.

    ``writes``: the command's :class:`~graphslam.outputs.writers.OutputWrites`, which
    notes a file the file system refuses and goes on (its caller checks it once every
    output was tried); without it, GraphSlamError once all were tried."""
    from graphslam.outputs import writers

    writes, own = writers.writes_for(out_dir, writes)
    est = result.estimate
    run_frames = result.dataset.frames[: result.steps]
    if result.dataset.has_timestamps:
        stamp_of = {f.pose_id: f.stamp_s for f in run_frames}
        stamps = np.array([stamp_of[int(i)] for i in est.pose_ids], dtype=float)
    else:
        stamp_of = {f.pose_id: f.pose_id for f in run_frames}  # ids exact, up to 2**62
        stamps = np.asarray(est.pose_ids, dtype=np.int64)
    paths: dict[str, Path] = {}
    gt = result.dataset.ground_truth() if ground_truth is None else ground_truth
    # one trajectory per robot where a run holds several (their stamps interleave)
    agents = result.dataset.agents or (("", tuple(int(i) for i in est.pose_ids)),)
    for name, ids in agents:
        suffix = "_" + name.replace(" ", "") if name else ""
        mine = np.isin(est.pose_ids, np.asarray(ids, dtype=np.int64))
        path = out_dir / f"trajectory{suffix}.tum"
        writes(paths, "trajectory" + suffix, path, writers.write_tum_planar, stamps[mine], est.wTb[mine])
        if gt is None:
            continue
        in_run = np.array([int(i) in stamp_of for i in gt[0]], dtype=bool)
        in_run &= np.isin(gt[0], np.asarray(ids, dtype=np.int64))
        if np.any(in_run):
            writes(
                paths,
                "ground_truth" + suffix,
                out_dir / f"ground_truth{suffix}.tum",
                writers.write_tum_planar,
                np.array([stamp_of[int(i)] for i in gt[0][in_run]]),
                np.asarray(gt[1])[in_run],
            )
    signal_hook("write")
    if stop_requested():  # asked while the outputs are written: say so in them
        run_metrics.interrupted = True
    landmarks = (est.landmark_ids, est.landmarks_w)
    writes(paths, "landmarks", out_dir / "landmarks.csv", writers.write_landmarks_csv, *landmarks)
    writes(paths, "metrics", out_dir / "metrics.json", writers.write_json, run_metrics.to_dict())
    if own:
        writes.check(paths.values())
    return paths


def add_nees(
    result: RunResult,
    run_metrics: PlanarRunMetrics,
    ground_truth: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """Pose NEES of each step against the truth (``ground_truth`` or the dataset's):
    fills the NEES fields of ``run_metrics`` and returns ``(pose_ids, nees, undefined)``,
    ``nees`` NaN and counted in ``undefined`` where the pose's covariance is singular
    (:func:`graphslam.evaluation.planar.nees`; the mean is over the others). None, the
    reason added to the metrics' warnings, when the run's poses are not in the truth's
    frame (:func:`graphslam.evaluation.planar.truth_frame_doubt`).

    Filters give each step's filtered covariance, iSAM2 the smoothed marginals. A mean
    NEES outside one step's 95 % chi-square bounds adds its doubt to the warnings
    (:func:`graphslam.evaluation.planar.nees_doubt`).
    GraphSlamError when the run has no truth or no covariances (interrupted).
    """
    from graphslam.evaluation import planar as metrics

    gt = result.dataset.ground_truth() if ground_truth is None else ground_truth
    est = result.estimate
    if gt is None:
        raise GraphSlamError(f"--nees needs ground truth; {result.dataset.name!r} has none")
    if est.pose_covariances is None:
        raise GraphSlamError("--nees: the run stopped before its covariances were computed")
    stats = metrics.pose_statistics(result.dataset, est, gt)
    run_metrics.final_pose_error_m = stats["final_pose_error_m"]
    run_metrics.nees_mean = stats["nees_mean"]
    run_metrics.nees_in_bounds_fraction = stats["nees_in_bounds_fraction"]
    if stats["frame_doubt"] is not None:
        run_metrics.warnings = [*(run_metrics.warnings or []), stats["frame_doubt"]]
        return None
    # a covariance off by a clear factor (a depleted particle cloud's NEES runs to 1e12)
    # is said, as compare says it
    if (doubt := metrics.nees_doubt(run_metrics.nees_mean, metrics.POSE_DOF)) is not None:
        run_metrics.warnings = [*(run_metrics.warnings or []), doubt]
    return stats["pose_ids"], stats["nees"], stats["nees_undefined"]


def write_nees(path: Path, pose_ids: np.ndarray, nees: np.ndarray) -> Path:
    """``nees.csv`` (:func:`graphslam.outputs.writers.write_nees_csv`)."""
    from graphslam.outputs.writers import write_nees_csv

    return write_nees_csv(path, pose_ids, nees)
