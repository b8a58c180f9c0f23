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
        "config": sections,
    }
    return map_from_estimate(result.estimate, meta)


def load_run_map(folder, dataset_name: str, seed: int | None, config) -> PlanarMap:
    """The 2-D map in ``folder``; InputError when it was built on other data."""
    pmap = load_planar_map(folder)
    built_on = pmap.meta.get("dataset")
    if built_on != dataset_name:
        raise InputError(
            f"map was built on {built_on!r}, this run is on {dataset_name!r} "
            "(landmarks are associated by id)",
            folder,
        )
    world = dataset_world(dataset_name, seed, config)
    if world is not None and pmap.meta.get("world") != world:
        saved = pmap.meta.get("world")
        saved = saved if isinstance(saved, dict) else {}  # a damaged map.json: every key differs
        diff = sorted(k for k in world if saved.get(k) != world[k])
        raise InputError(
            f"map was built on another synthetic world ([synthetic] {', '.join(diff) or 'world'} differ)",
            folder,
        )
    return pmap


def localiser(name: str, pmap: PlanarMap, config, overrides: dict | None) -> Backend:
    """The localisation-only back end ``name`` on ``pmap`` (ConfigError for fastslam)."""
    return registry.make_localiser(
        name, pmap.landmark_ids, pmap.landmark_xy, pmap.landmark_cov, config=config, overrides=overrides
    )
