"""2-D landmark maps around a run: ``run --save-map DIR`` and ``run --map DIR`` (localisation only).

A finished 2-D run's landmarks with their marginal covariances become a
:class:`~graphslam.maps.planar_map.PlanarMap` (:func:`build_run_map`, with a
``meta`` that says which data, how many steps, which back end and which
configuration built it). A saved map is given back to a run by
:func:`load_run_map`, which refuses a map of another dataset, or of another
synthetic world (the landmarks of the synthetic world depend on its seed and
geometry), and :func:`localiser` makes the localisation-only back end
(:mod:`graphslam.backends.planar.isam2_localise`, :mod:`filters.ekf_localise`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from graphslam import registry
from graphslam.maps.files import load_planar_map
from graphslam.maps.planar_map import PlanarMap, map_from_estimate
from graphslam.pipelines.planar import RunResult
from slamcore.config import load_section
from slamcore.errors import GraphSlamError, InputError
from slamcore.planar.backend import Backend

#: Fields of ``[synthetic]`` that decide where the landmarks are (and their ids).
WORLD_KEYS = (
    "seed",
    "n_landmarks",
    "route_length_m",
    "route_width_m",
    "corner_radius_m",
    "laps",
    "world_margin_m",
    "landmark_clearance_m",
    "speed_mps",
    "dt_s",
)


def dataset_world(dataset_name: str, seed: int | None, config) -> dict | None:
    """What fixes the landmarks of ``dataset_name``: the synthetic world's geometry and
    seed, None for recorded data (the name says it all)."""
    if dataset_name != "synthetic":
        return None
    from graphslam.sources.planar.synthetic import SyntheticConfig

    world = load_section(SyntheticConfig, config, {"seed": seed})
    return {k: getattr(world, k) for k in WORLD_KEYS}


#: Bytes of a source file read for its digest: past it the map's check falls back on the
#: dataset's name (Victoria Park's log is 0.6 MB, an MRCLAM set's landmark files 2 kB).
LANDMARK_SOURCE_MAX_BYTES = 64 * 1024 * 1024


def landmark_source(dataset) -> str | None:
    """What names and places ``dataset``'s landmarks, as a digest: an MRCLAM set's
    ``Barcodes.dat`` and ``Landmark_Groundtruth.dat`` (every robot of the set, alone or
    joint, shares them), or the log file's bytes; None for a synthetic world (its
    geometry and seed say it, :func:`dataset_world`) or a source not read."""
    from pathlib import Path

    from graphslam.sources.planar.mrclam import is_mrclam_folder

    source = getattr(dataset, "source_path", None)
    if source is None or dataset.name == "synthetic":
        return None
    path = Path(source)
    try:
        if is_mrclam_folder(path):
            return "mrclam:" + _digest([path / "Barcodes.dat", path / "Landmark_Groundtruth.dat"])
        if path.is_file() and path.stat().st_size <= LANDMARK_SOURCE_MAX_BYTES:
            return "file:" + _digest([path])
    except OSError:
        return None
    return None


def _digest(paths) -> str:
    """SHA-256 (16 hex digits) of the files' bytes in order, read in 1 MB blocks; a file
    that is not there counts as empty (an MRCLAM set may lack its landmark truth)."""
    import hashlib

    digest = hashlib.sha256()
    for path in paths:
        if path.is_file():
            with open(path, "rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    digest.update(block)
        digest.update(b"\0")
    return digest.hexdigest()[:16]


def build_run_map(result: RunResult, backend: Backend, config, max_steps: int | None) -> PlanarMap:
    """The map of a finished run (its estimate must hold landmark covariances)."""
    ds = result.dataset
    sections = {}
    for name, cls in registry.planar_sections(ds.name, backend.name).items():
        own = getattr(backend, "config", None)
        value = (
            own
            if isinstance(own, cls)
            else load_section(cls, config, {"seed": ds.seed} if name == "synthetic" else None)
        )
        if not dataclasses.is_dataclass(value) or isinstance(value, type):
            raise GraphSlamError(f"[{name}] settings are not a config record: {value!r}")
        sections[name] = dataclasses.asdict(value)
    meta = {
        "dataset": ds.name,
        "source": ds.source_path,
        "seed": ds.seed,
        "steps": result.steps,
        "max_steps": max_steps,
        "backend": result.backend,
        "world": dataset_world(ds.name, ds.seed, config),
        "landmarks": landmark_source(ds),
        "config": sections,
    }
    return map_from_estimate(result.estimate, meta)


def load_run_map(folder, dataset, config) -> PlanarMap:
    """The 2-D map in ``folder`` for a run on ``dataset``; InputError when it was built on
    other landmarks, or its landmark ids are a run's own labels.

    The landmarks are the same when :func:`landmark_source` agrees (another robot of the
    same MRCLAM set, the built-in Victoria Park and its file by path); an MRCLAM set whose
    landmark files differ is refused whatever its folder's name. A map without that record,
    or a log edited since (a file cut shorter), falls back on the dataset's name."""
    pmap = load_planar_map(folder)
    meta = pmap.meta
    unknown = [
        name
        for name, section in (meta.get("config") or {}).items()
        if isinstance(section, dict) and section.get("association") == "unknown"
    ]
    if unknown:  # its ids are the run's own labels 0, 1, ...: paired by id with the data's, wrongly
        raise InputError(
            f'map was built with [{unknown[0]}] association = "unknown": its landmark ids are that '
            "run's own labels, not the data's, and --map associates by id; save the map from a run "
            'with association = "known"',
            folder,
        )
    built_on, ours = meta.get("dataset"), landmark_source(dataset)
    saved = meta.get("landmarks") if isinstance(meta.get("landmarks"), str) else None  # damaged: unknown
    same = built_on == dataset.name
    if saved is not None and ours is not None and saved != ours:
        if saved.startswith("mrclam:") or ours.startswith("mrclam:") or not same:
            raise InputError(
                f"map was built on {built_on!r}, whose landmarks (ids and true positions) are not "
                f"this run's {dataset.name!r}: its landmark files differ (landmarks are associated by id)",
                folder,
            )
    elif not same and not (saved is not None and saved == ours):
        raise InputError(
            f"map was built on {built_on!r}, this run is on {dataset.name!r} "
            "(landmarks are associated by id)",
            folder,
        )
    world = dataset_world(dataset.name, dataset.seed, config)
    if world is not None and meta.get("world") != world:
        built = meta.get("world")
        built = built if isinstance(built, dict) else {}  # a damaged map.json: every key differs
        diff = sorted(k for k in world if built.get(k) != world[k])
        raise InputError(
            f"map was built on another synthetic world ([synthetic] {', '.join(diff) or 'world'} differ)",
            folder,
        )
    return pmap


def map_frame_ate(result, truth, fitted: float | None) -> tuple[float | None, list[str]]:
    """``(ATE in the map's frame, without the SE(2) fit, doubts)`` of a ``run --map`` (2-D),
    ``fitted`` the run's SE(2)-fitted ATE (None: not scored): the fitted ATE hid a map
    moved 3 m (0.64 m fitted, 4.17 m where it was; hostile pass 24). A doubt by localize's
    rule (:data:`~graphslam.pipelines.localize_run.FRAME_DOUBT_RATIO`, ``FAR_M``)."""
    from graphslam.evaluation import planar as metrics
    from graphslam.pipelines.localize_run import FAR_M, FRAME_DOUBT_RATIO

    gt = result.dataset.ground_truth() if truth is None else truth
    est = result.estimate
    if fitted is None or gt is None or np.intersect1d(est.pose_ids, gt[0]).size < 2:
        return None, []
    gt_ids, gt_wTb = gt
    placed = metrics.ate(est.pose_ids, est.wTb, gt_ids, gt_wTb, align=False)["rmse_m"]
    if not (placed > FRAME_DOUBT_RATIO * fitted and placed - fitted > FAR_M):
        return placed, []
    return placed, [
        f"in the map's frame the ATE is {placed:.3g} m, {fitted:.3g} m after the SE(2) fit: the "
        "poses agree with the truth in shape, not in place (a map away from the truth, or a "
        "truth in another frame than the map's)"
    ]


def map_source_doubt(pmap: PlanarMap, dataset) -> str | None:
    """A warning when the map was saved from a log of this run's name whose landmark digest
    differs (another file of the same name is taken as this one: hostile pass 24, a log
    with its landmark ids rotated localised at 8.2 m, unsaid), else None."""
    saved = pmap.meta.get("landmarks")
    ours = landmark_source(dataset)
    if not isinstance(saved, str) or ours is None or saved == ours:
        return None
    return (
        f"the map was saved from a log named {dataset.name!r} whose contents differ from this "
        "one's (its digest): taken as an edit of it; if it is another log, its landmark ids "
        "may name other landmarks"
    )


def localiser(name: str, pmap: PlanarMap, config, overrides: dict | None) -> Backend:
    """The localisation-only back end ``name`` on ``pmap`` (ConfigError for fastslam)."""
    return registry.make_localiser(
        name, pmap.landmark_ids, pmap.landmark_xy, pmap.landmark_cov, config=config, overrides=overrides
    )
