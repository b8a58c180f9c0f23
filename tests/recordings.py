"""Read logged values back from a Rerun ``.rrd`` file (tests only; rerun's chunk reader)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def entity_rows(path: Path, entity: str, component: str) -> list[tuple[int, object]]:
    """``(step, value)`` of every row of ``component`` (e.g. "Scalars:scalars") logged at
    ``entity`` (e.g. "/plots/ekf/ess"), in step order; values as pyarrow gives them."""
    from rerun.chunk import RrdReader

    rows = []
    for chunk in RrdReader(str(path)).stream():
        if chunk.entity_path != entity or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        if component not in batch.schema.names:
            continue
        steps = batch.column("step").to_pylist()
        rows += zip(steps, batch.column(component).to_pylist())
    return sorted(rows, key=lambda r: r[0])


def scalars(path: Path, entity: str) -> tuple[np.ndarray, np.ndarray]:
    """``(steps, values)`` of a ``Scalars`` time series."""
    rows = entity_rows(path, entity, "Scalars:scalars")
    return (np.array([s for s, _ in rows], dtype=np.int64),
            np.array([v[0] for _, v in rows], dtype=np.float64))


def tensors(path: Path, entity: str) -> list[tuple[int, np.ndarray]]:
    """``(step, array)`` of a ``Tensor`` entity, reshaped to its logged shape."""
    out = []
    for step, value in entity_rows(path, entity, "Tensor:data"):
        data = value[0]
        out.append((step, np.asarray(data["buffer"], dtype=np.float64).reshape(data["shape"])))
    return out


def points2d(path: Path, entity: str) -> list[tuple[int, np.ndarray]]:
    """``(step, (n, 2) positions)`` of a ``Points2D`` entity."""
    return [(s, np.asarray(v, dtype=np.float64).reshape(-1, 2))
            for s, v in entity_rows(path, entity, "Points2D:positions")]


def blueprint_views(path: Path) -> list[dict]:
    """The views of the recording's blueprint: ``{"kind", "name", "origin", "contents"}``
    (contents: the view's query expressions)."""
    from rerun.chunk import RrdReader

    reader = RrdReader(str(path))
    stores = reader.blueprints()
    if not stores:
        return []
    views: dict[str, dict] = {}
    for chunk in reader.stream(store=stores[0]):
        parts = chunk.entity_path.strip("/").split("/")
        if parts[0] != "view":
            continue
        batch = chunk.to_record_batch()

        def last(column: str):  # one column at a time: log_time needs pandas to convert
            if column not in batch.schema.names:
                return None
            return batch.column(column).to_pylist()[-1]

        view = views.setdefault(parts[1], {})
        if parts[-1] == "ViewContents":
            view["contents"] = last("ViewContents:query")
        else:
            view["kind"] = last("ViewBlueprint:class_identifier")[0]
            view["name"] = (last("ViewBlueprint:display_name") or [None])[0]
            view["origin"] = last("ViewBlueprint:space_origin")[0]
    return list(views.values())


def entity_paths(path: Path) -> set[str]:
    """Every entity path the recording holds data for."""
    from rerun.chunk import RrdReader

    return {chunk.entity_path for chunk in RrdReader(str(path)).stream()}
