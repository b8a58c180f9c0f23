"""``graphslam run --save-map DIR`` on an image sequence: record the map while running, save it after.

Also ``--map`` (the start pose relocalised in a saved map) and ``--relocalise``
(a frame hook). Kept apart from :mod:`graphslam.cli.run.spatial` so that the
run itself only gains a few calls: :func:`session_extras`, :func:`chain_hooks`
and :func:`save_run_map`.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path


def session_extras(args, config, sequence, backend, tracker):
    """``(prior map, start pose, map recorder, relocaliser)`` of ``--map``, ``--save-map``
    and ``--relocalise`` (None for each flag not given)."""
    prior_map, start_pose = anchor_on_map(args, config, sequence)
    return (
        prior_map,
        start_pose,
        start_map(args, config, sequence, backend, tracker),
        start_relocaliser(args, config, sequence, backend),
    )


def start_map(args, config, sequence, backend, tracker):
    """The :class:`~graphslam.pipelines.mapping.MapRecorder` of ``--save-map``, or None."""
    if getattr(args, "save_map", None) is None:
        return None
    from frontend.orb import OrbDetector
    from graphslam.pipelines.mapping import MapRecorder, require_map_backend
    from loopclosure.detector import LoopDetectorConfig

    require_map_backend(backend)
    orb = config.section(LoopDetectorConfig).orb
    return MapRecorder(OrbDetector(orb), tracker.patch_size, getattr(sequence, "indices", None))


def anchor_on_map(args, config, sequence):
    """``--map``: ``(map, (wTc0, covariance))`` of the first frame relocalised in the saved
    map, or ``(None, None)`` without the flag. GraphSlamError when it cannot be placed."""
    if getattr(args, "map", None) is None:
        return None, None
    from graphslam.maps.files import load_map
    from graphslam.pipelines.session import LocaliseSession
    from slamcore.errors import GraphSlamError

    smap = load_map(args.map)
    if smap.meta.get("odometry") == "none":  # this run has odometry (run refuses it without)
        raise GraphSlamError(
            f"--map: {args.map} was built from the camera alone, in a scale of its own (its "
            "first baseline), not in metres: a run with odometry would join it at another "
            "scale; place frames with graphslam localize, or build the map with odometry"
        )
    placed = LocaliseSession.open(sequence, config, smap, args.dataset).localizer.locate(sequence.load(0))
    if placed.wTc is None:
        raise GraphSlamError(
            f"--map: the first frame cannot be relocalised in {args.map} "
            "(place recognition and PnP found no pose); start the run where "
            "the map was seen (--frames)"
        )
    return smap, (placed.wTc, placed.covariance)


def start_relocaliser(args, config, sequence, backend):
    """The :class:`~graphslam.pipelines.relocalise.RunRelocaliser` of ``--relocalise``, or None."""
    if not getattr(args, "relocalise", False):
        return None
    from frontend.orb import OrbDetector
    from graphslam.pipelines.loop_closing import require_loop_closures
    from graphslam.pipelines.relocalise import RelocaliseConfig, RunRelocaliser
    from loopclosure.detector import LoopDetectorConfig
    from loopclosure.pnp import PnpConfig

    require_loop_closures(backend, "--relocalise", args.backend)  # a relocalised pose joins as a closure
    return RunRelocaliser(
        sequence.K,
        config.section(RelocaliseConfig),
        config.section(PnpConfig),
        OrbDetector(config.section(LoopDetectorConfig).orb),
    )


def chain_hooks(*hooks):
    """One frame hook calling each of ``hooks`` that is not None, in order (None if none)."""
    live = [h for h in hooks if h is not None]
    if not live:
        return None
    if len(live) == 1:
        return live[0]

    def hook(*a):
        for h in live:
            h(*a)

    return hook


def save_run_map(args, recorder, result, backend, closer, tracker, quiet: bool, prior_map=None) -> None:
    """Build the map of the finished run (joined after ``prior_map``, the ``--map`` of
    this session, when given), write it to ``--save-map`` and say so on stdout."""
    from graphslam.cli.common import warn

    if result.interrupted and not result.finalised:  # no map from half an estimate
        warn(f"run stopped before its end: no map saved in {args.save_map}")
        return
    if result.interrupted:  # asked during the final polish: the estimate is whole
        warn(
            f"stop asked after the last frame: the estimate is whole, so its map is saved in "
            f"{args.save_map} (a second Ctrl-C skips the map)"
        )
        try:
            _save(args, recorder, result, backend, closer, tracker, quiet, prior_map)
        except KeyboardInterrupt:
            warn(f"map not saved in {args.save_map}: stopped again")
        return
    _save(args, recorder, result, backend, closer, tracker, quiet, prior_map)


def _save(args, recorder, result, backend, closer, tracker, quiet: bool, prior_map) -> None:
    import sys

    from graphslam.cli.common import warn
    from graphslam.maps.files import save_map

    seq = result.sequence
    if not quiet and closer is None and prior_map is None:
        print("map: training a vocabulary on the run's frames ...", file=sys.stderr, flush=True)
    from graphslam.cli.common import invocation
    from graphslam.maps.merge import frame_range
    from graphslam.sources.spatial.frames import FrameSelection, source_indices

    meta = {
        "dataset": seq.name,
        "source": seq.source_path,
        # resolved, and the frames as the indices run: what tells a session joined twice
        # (and says where the map came from, from any folder)
        "source_path": None if seq.source_path is None else os.path.realpath(seq.source_path),
        "frames": args.frames,
        "frame_range": frame_range(source_indices(seq)[: result.frames]),
        "n_frames": result.frames,
        "backend": result.backend,
        "frontend": result.frontend,
        "odometry": result.odometry,
        "tracker": dataclasses.asdict(tracker.config),
        "bow_orb": dataclasses.asdict(recorder.bow_orb.config),
        # the lens model the keyframes' pixels were read with (check_camera compares it)
        "distortion": [] if seq.distortion is None else [float(d) for d in seq.distortion],
        "provenance": invocation(args),
    }
    vocabulary = None if closer is None else closer.detector.database.vocabulary
    if prior_map is not None:
        vocabulary = prior_map.vocabulary  # one vocabulary for the joint map's BoW vectors
    smap = recorder.build(
        result.estimate, backend, vocabulary=vocabulary, meta=meta, K=seq.K, image_size=seq.image_size
    )
    if prior_map is not None:
        from graphslam.maps.merge import merge_maps, repeated_session

        whole = seq.base if isinstance(seq, FrameSelection) else seq
        again = repeated_session(prior_map, meta, len(whole))
        if again is not None:
            first, last, step = meta["frame_range"]
            every = "" if step == 1 else f" every {step}"
            warn(
                f"the map's session {again + 1} ran the same frames ({meta['frames'] or 'all'}) of "
                f"{seq.name} (its frames {first} to {last}{every}): their keyframes are in the "
                "joined map twice"
            )
        smap = merge_maps(prior_map, smap)
    from graphslam.cli.out_folder import claimed_folder

    # the folder --save-map locked, wherever it was moved while the run went on
    folder = claimed_folder(Path(args.save_map), flag="--save-map")
    save_map(smap, folder)
    c = smap.counts()
    print(
        f"map in {folder}/: {c['keyframes']} keyframes, {c['landmarks']} landmarks, "
        f"{c['observations']} observations"
    )
    if c["landmarks"] == 0:  # saved in silence, then localize placed nothing, also silent
        warn(
            f"the map in {folder} has no landmark: nothing can be placed against it "
            "(a run of more frames, with parallax, makes one)"
        )
