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
layout. A viewer watching live (``--rerun spawn`` or ``connect``) also gets it
during the run, each time a step begins after the layout changed
(:func:`layout_key`: a new view, not a new entity inside one), so panels do
not jump once the run's views all exist.
"""

from __future__ import annotations

from collections import defaultdict

#: Archetypes that make the world a 3-D view.
_3D = {
    "Points3D",
    "LineStrips3D",
    "Arrows3D",
    "Boxes3D",
    "Transform3D",
    "Pinhole",
    "ViewCoordinates",
    "Mesh3D",
}
_IMAGES = {"Image", "EncodedImage"}


class LoggedEntities:
    """Entity path -> archetype names logged there (``rerun.archetypes.`` stripped)."""

    def __init__(self):
        self.kinds: dict[str, set[str]] = defaultdict(set)
        self.version = 0  # counts (path, archetype) pairs first noted: cheap "anything new?"

    def note(self, path: str, kind: str) -> None:
        kinds, kind = self.kinds["/" + path.strip("/")], kind.rsplit(".", 1)[-1]
        if kind not in kinds:
            kinds.add(kind)
            self.version += 1

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


def layout_key(logged: LoggedEntities) -> tuple:
    """What :func:`blueprint` builds from: equal keys, equal layouts.

    ``(world: None, "2d" or "3d"; image paths; (leaf, series paths) per plotted
    quantity; text log paths; tensor paths)``.
    """
    world = [p for p in logged.kinds if p == "/world" or p.startswith("/world/")]
    kind = None if not world else "3d" if any(logged.kinds[p] & _3D for p in world) else "2d"
    by_leaf: dict[str, list[str]] = defaultdict(list)
    for p in logged.paths("Scalars"):
        by_leaf[p.rsplit("/", 1)[-1]].append(p)
    return (
        kind,
        tuple(logged.paths(*_IMAGES)),
        tuple((leaf, tuple(paths)) for leaf, paths in by_leaf.items()),
        tuple(logged.paths("TextLog")),
        tuple(logged.paths("Tensor")),
    )


def blueprint(logged: LoggedEntities):
    """The layout of the module docstring, or None when nothing was logged."""
    import rerun.blueprint as rrb  # only when a layout is sent

    world, image_paths, series, texts, tensors = layout_key(logged)
    main: list[rrb.View] = []
    if world:
        view = rrb.Spatial3DView if world == "3d" else rrb.Spatial2DView
        main.append(view(name="world" if world == "3d" else "map", origin="/world"))
    images = [rrb.Spatial2DView(name=_image_name(p), origin=p) for p in image_paths]
    # one TimeSeriesView per plotted quantity (leaf name), its series from every run
    tabs: list[rrb.View] = [
        rrb.TimeSeriesView(name=leaf, origin="/", contents=list(paths)) for leaf, paths in series
    ]
    tabs += [rrb.TextLogView(name=_tail(p), origin=p) for p in texts]
    tabs += [rrb.TensorView(name=_tail(p), origin=p) for p in tensors]
    side: list[rrb.Container | rrb.View] = [*images, *([rrb.Tabs(*tabs)] if tabs else [])]
    if not main and not side:
        return None
    if side:
        column: rrb.Container | rrb.View = side[0] if len(side) == 1 else rrb.Vertical(*side)
        root = rrb.Horizontal(*main, column, column_shares=[3, 2]) if main else column
    else:
        root = main[0]
    return rrb.Blueprint(root, collapse_panels=False)


def _tail(path: str) -> str:
    """The last two parts of a path: ``filter/ekf/correlation`` -> ``ekf/correlation``."""
    return "/".join(path.strip("/").split("/")[-2:])


def _image_name(path: str) -> str:
    """``/world/isam2/camera/image`` -> ``isam2 camera``; else the path's tail."""
    parts = path.strip("/").split("/")
    if len(parts) >= 3 and parts[-1] == "image" and parts[-2] == "camera":
        return f"{parts[-3]} camera"
    return _tail(path)
