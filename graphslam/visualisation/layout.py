"""The viewer layout (Rerun blueprint) of a recording, built from what it logged.

Without a blueprint the viewer guesses one view per entity subtree: every
plot in its own panel, the EKF's correlation image beside the camera images,
each run different. :class:`LoggedEntities` notes the archetype of every
entity a :class:`~graphslam.visualisation.recording.RerunLog` writes, and
:func:`blueprint` lays them out the same way for every run:

- left, the ``world`` (a 3-D view when anything 3-D was logged there, else 2-D);
- right, above: each image (a camera with its overlays, a loop-closure pair);
- right, below, in tabs: one time-series view per plotted quantity (the leaf
  of ``plots/...``: back ends compared in one view, e.g. ``pose_sigma_m``),
  each text log, each tensor (the EKF's correlation image), in the order
  first logged.

The blueprint is sent when the recording closes, as the default and active
layout (a viewer watching live switches to it at the end of the run).
"""

from __future__ import annotations

from collections import defaultdict

#: Archetypes that make the world a 3-D view.
_3D = {"Points3D", "LineStrips3D", "Arrows3D", "Boxes3D", "Transform3D", "Pinhole",
       "ViewCoordinates", "Mesh3D"}
_IMAGES = {"Image", "EncodedImage"}


class LoggedEntities:
    """Entity path -> archetype names logged there (``rerun.archetypes.`` stripped)."""

    def __init__(self):
        self.kinds: dict[str, set[str]] = defaultdict(set)

    def note(self, path: str, kind: str) -> None:
        self.kinds["/" + path.strip("/")].add(kind.rsplit(".", 1)[-1])

    def note_log(self, path: str, entities) -> None:
        """What ``RecordingStream.log(path, *entities)`` logged."""
        for e in entities:
            self.note(path, type(e).__name__)

    def note_columns(self, path: str, columns) -> None:
        """What ``RecordingStream.send_columns(path, indexes, columns)`` sent."""
        for column in columns:
            archetype = column.component_descriptor().archetype
            if archetype:
                self.note(path, archetype)

    def paths(self, *kinds: str) -> list[str]:
        """Paths where any of ``kinds`` was logged, in the order first logged."""
        return [p for p, k in self.kinds.items() if k & set(kinds)]


def blueprint(logged: LoggedEntities):
    """The layout of the module docstring, or None when nothing was logged."""
    import rerun.blueprint as rrb  # only when a recording closes

    world = [p for p in logged.kinds if p == "/world" or p.startswith("/world/")]
    main = []
    if world:
        three_d = any(logged.kinds[p] & _3D for p in world)
        view = rrb.Spatial3DView if three_d else rrb.Spatial2DView
        main.append(view(name="world" if three_d else "map", origin="/world"))
    images = [rrb.Spatial2DView(name=_image_name(p), origin=p) for p in logged.paths(*_IMAGES)]
    tabs = _series_views(rrb, logged)
    tabs += [rrb.TextLogView(name=_tail(p), origin=p) for p in logged.paths("TextLog")]
    tabs += [rrb.TensorView(name=_tail(p), origin=p) for p in logged.paths("Tensor")]
    side = images + ([rrb.Tabs(*tabs)] if tabs else [])
    if not main and not side:
        return None
    if side:
        column = side[0] if len(side) == 1 else rrb.Vertical(*side)
        root = rrb.Horizontal(*main, column, column_shares=[3, 2]) if main else column
    else:
        root = main[0]
    return rrb.Blueprint(root, collapse_panels=False)


def _series_views(rrb, logged: LoggedEntities) -> list:
    """One TimeSeriesView per plotted quantity (leaf name), its series from every run."""
    by_leaf: dict[str, list[str]] = defaultdict(list)
    for p in logged.paths("Scalars"):
        by_leaf[p.rsplit("/", 1)[-1]].append(p)
    return [rrb.TimeSeriesView(name=leaf, origin="/", contents=paths)
            for leaf, paths in by_leaf.items()]


def _tail(path: str) -> str:
    """The last two parts of a path: ``filter/ekf/correlation`` -> ``ekf/correlation``."""
    return "/".join(path.strip("/").split("/")[-2:])


def _image_name(path: str) -> str:
    """``/world/isam2/camera/image`` -> ``isam2 camera``; else the path's tail."""
    parts = path.strip("/").split("/")
    if len(parts) >= 3 and parts[-1] == "image" and parts[-2] == "camera":
        return f"{parts[-3]} camera"
    return _tail(path)
