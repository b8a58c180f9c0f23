"""2-D pose graphs (TORO ``.graph``, g2o ``.g2o``, City10000) as frame streams.

Nothing is parsed here: :func:`graphslam.sources.posegraph_files.read_pose_graph_records`
is the one reader of TORO and g2o text (and its refusals, each naming the file
and the 1-based line), City10000's own layout is read by
:func:`graphslam.sources.builtin_posegraphs.read_city10000_graph`; this module
turns their :class:`~slamcore.posegraph.PoseGraph` into a streaming
:class:`~slamcore.planar.records.Dataset` for the filters and 2-D iSAM2.

Grouping into frames: poses are numbered ``first..last`` without gaps; frame
``k`` holds pose ``k``. The edge between ``k-1`` and ``k`` (in either direction,
kept as written: w10000 has ``EDGE2 1 0 ...``) is the frame's ``odometry``; every
other edge whose larger id is ``k`` is one of its ``loop_closures`` (direction
kept as written, ``source="dataset"``). Inverting an edge would change the
error value, so nothing is inverted. A gap in the ids, or a pose without an
edge to the one before it, is refused at the first line naming that pose.

Noise: each edge's covariance is the inverse of the information matrix the
reader gives (the same matrices a batch run of the file solves with), so a
file gets one noise model whatever the back end. TORO's six numbers are
therefore read as the format defines them, an **information** matrix in the
order ``ixx ixy iyy ith ixt iyt`` (``[[v1 v2 v5], [v2 v3 v6], [v5 v6 v4]]``),
and no longer as ``gtsam.load2D`` reads a ``v1 0 v3 v4 0 0`` line by default:
as a covariance (gtsam's NoiseFormatGRAPH, documented in its own header as
"toro-style order, but covariance matrix !"). Decided so because TORO's
specification says information (its README: ``EDGE2 ... inf_ff inf_fs inf_ss
inf_rr inf_fr inf_sr``, "the information matrix entries of the constraint", and
gtsam's NoiseFormatTORO reads it so), because the batch solvers always read it
so, and because it changes nothing on gtsam's TORO files of that pattern (w100,
w10000, example.graph: identity, its own inverse; ``tests/graphslam/sources/test_readers.py``
still matches load2D on w10000). The one file that changes is gtsam's
``w20000.txt`` (``3.16228 0 0 3.16228 0 5``, g2o's diagonal order, which load2D
took as a covariance): now the information the batch solver reads. g2o files
were read as information before as after. ``toro_noise`` (``auto``,
``information``, ``sqrt_information``, with its list of known files) and
``information_fix`` (a matrix that is not positive definite) mean here what they
mean for the batch solvers; an edge from a pose to itself is left out and
counted, as there: the dataset's ``notes`` say so.

Relative-pose angles are wrapped to [-pi, pi) (w10000 has values such as
-3.15858; gtsam's Pose2 wraps them the same way, so errors are unchanged).

Landmarks: a TORO file may hold ``BR i j bearing range bearing_sigma range_sigma``
lines (gtsam's ``example.graph``): landmark ``j`` seen from pose ``i``, read as
``gtsam.load2D`` reads them (a BearingRangeFactor2D with diagonal sigmas
``[bearing_sigma, range_sigma]``, rad and m). Each becomes a range-bearing
:class:`~slamcore.planar.records.Observation` of pose ``i``'s frame, with
``z = [range, bearing]`` (bearing wrapped to [-pi, pi)) and covariance
``diag(range_sigma**2, bearing_sigma**2)``: the file is then landmark SLAM, run
by the landmark back ends, not a pose graph.
"""

from __future__ import annotations

import numpy as np

from graphslam.sources.posegraph_bulk import Sightings
from graphslam.sources.posegraph_files import read_pose_graph_records
from graphslam.sources.tokens import MAX_KEY_ID
from slamcore import posegraph as pg
from slamcore.errors import InputError, MeasurementError
from slamcore.planar.geometry import wrap_angle
from slamcore.planar.records import (
    Dataset,
    Frame,
    LoopClosure,
    Observation,
    ObservationKind,
    Odometry,
    loop_closure_batch,
    odometry_batch,
    range_bearing_batch,
)


# --------------------------------------------------------------------------- public
def read_pose_graph(
    path, toro_noise: str = "auto", information_fix: str = "nearest", fmt: str | None = None
) -> Dataset:
    """A 2-D TORO or g2o file (told from its tags) as frames; ``BR`` lines become
    observations. ``toro_noise``, ``information_fix``: as for
    :func:`~graphslam.sources.posegraph_files.read_pose_graph_file`. ``fmt``
    (``"toro"``, ``"g2o"``): refuse a file of the other format. Name: the file stem."""
    graph, sightings = read_pose_graph_records(
        path, toro_noise, information_fix, landmarks=True, id_limit=MAX_KEY_ID
    )
    if fmt is not None and graph.format != fmt:
        raise InputError(f"a {graph.format} file, read here as {fmt}", path, int(graph.edge_lines[0]))
    return dataset_of_pose_graph(graph, sightings)


def read_w10000() -> Dataset:
    """gtsam's w10000 Manhattan pose graph (``w10000.graph``, TORO, in the gtsam wheel)."""
    import gtsam  # only to find the wheel's example data

    return read_pose_graph(gtsam.findExampleDataFile("w10000.graph"))


def read_city10000(path=None, ground_truth_path=None) -> Dataset:
    """gtsam's City10000 with its ground truth (name "city10000"), as
    :func:`~graphslam.sources.builtin_posegraphs.read_city10000_graph` reads it."""
    from graphslam.sources.builtin_posegraphs import read_city10000_graph

    graph, truth = read_city10000_graph(path, ground_truth_path)
    return dataset_of_pose_graph(graph, truth=truth)


# --------------------------------------------------------------------------- frames
def dataset_of_pose_graph(
    graph: pg.PoseGraph, sightings: Sightings | None = None, truth: np.ndarray | None = None
) -> Dataset:
    """The frames of a 2-D pose graph (module docstring), named as the graph.

    ``sightings``: ``BR`` lines, each an observation in its pose's frame;
    ``truth``: (N, 3) true poses in id order."""
    path = graph.source_path
    if graph.dim != 2:
        raise InputError(
            f"a {graph.dim}-D pose graph: frame by frame, only 2-D ones run "
            "(run it with --backend isam2 or batch)",
            path,
        )
    rows = graph.index_of(graph.edges.ravel()).reshape(-1, 2)
    first_line = np.full(graph.n_poses, np.iinfo(np.int64).max)
    for side in (0, 1):
        np.minimum.at(first_line, rows[:, side], graph.edge_lines)
    gaps = np.flatnonzero(np.diff(graph.ids) != 1)
    if len(gaps):
        g = int(gaps[0])
        raise InputError(
            f"pose {int(graph.ids[g]) + 1} is missing (gap in pose ids)", path, int(first_line[g + 1])
        )
    is_odometry = _odometry_edges(graph, rows, first_line)
    deltas = graph.measurements.copy()
    deltas[:, 2] = wrap_angle(deltas[:, 2])
    inverse = np.linalg.inv(graph.information)
    covariances = 0.5 * (inverse + inverse.transpose(0, 2, 1))
    odometry, closures = edge_records(graph, deltas, covariances, is_odometry)
    frame_of_edge = rows.max(axis=1)
    odometry_of = dict(zip(frame_of_edge[is_odometry].tolist(), odometry, strict=True))
    closures_of: list[list[LoopClosure]] = [[] for _ in range(graph.n_poses)]
    for r, lc in zip(frame_of_edge[~is_odometry].tolist(), closures, strict=True):
        closures_of[r].append(lc)
    seen_of: list[list[Observation]] = [[] for _ in range(graph.n_poses)]
    if sightings is not None and len(sightings):
        for r, obs in zip(
            graph.index_of(sightings.pose_ids).tolist(), _observations(sightings, path), strict=True
        ):
            seen_of[r].append(obs)
    frames = [
        Frame(
            pose_id=k,
            odometry=odometry_of.get(r),
            observations=tuple(seen_of[r]),
            loop_closures=tuple(closures_of[r]),
            wTb_true=None if truth is None else truth[r],
        )
        for r, k in enumerate(graph.ids.tolist())
    ]
    return Dataset(
        name=graph.name,
        frames=frames,
        prior_wTb=np.zeros(3),
        prior_covariance=np.eye(3) * 1e-6,
        landmarks_true=None,
        has_timestamps=False,
        source_path=path,
        notes=_notes(graph),
        warnings=(*graph.warnings, *_fix_warnings(graph)),
    )


def _odometry_edges(graph: pg.PoseGraph, rows: np.ndarray, first_line: np.ndarray) -> np.ndarray:
    """(M,) bool: each pose's odometry, the first edge in file order between it and the
    pose before it (a later one is a loop closure); InputError for a pose without."""
    chain = np.flatnonzero(np.abs(rows[:, 0] - rows[:, 1]) == 1)
    frame, first = np.unique(rows[chain].max(axis=1), return_index=True)
    missing = np.setdiff1d(np.arange(1, graph.n_poses), frame)
    if len(missing):
        r = int(missing[0])
        raise InputError(
            f"pose {int(graph.ids[r])} has no edge to pose {int(graph.ids[r - 1])}",
            graph.source_path,
            int(first_line[r]),
        )
    is_odometry = np.zeros(graph.n_edges, dtype=bool)
    is_odometry[chain[first]] = True
    return is_odometry


def edge_records(
    graph: pg.PoseGraph, deltas: np.ndarray, covariances: np.ndarray, is_odometry: np.ndarray
) -> tuple[list[Odometry], list[LoopClosure]]:
    """Odometry and loop-closure records of the edges (file order), checked in bulk
    (64 000 edges of w10000: 0.1 s, not 3 s one by one); when anything is off,
    :func:`edge_records_one_by_one` names the line."""
    a, b = graph.edges[:, 0], graph.edges[:, 1]
    odo, loop = is_odometry, ~is_odometry
    try:
        return (
            odometry_batch(a[odo], b[odo], deltas[odo], covariances[odo]),
            loop_closure_batch(a[loop], b[loop], deltas[loop], covariances[loop]),
        )
    except MeasurementError:
        return edge_records_one_by_one(graph, deltas, covariances, is_odometry)


def edge_records_one_by_one(
    graph: pg.PoseGraph, deltas: np.ndarray, covariances: np.ndarray, is_odometry: np.ndarray
) -> tuple[list[Odometry], list[LoopClosure]]:
    """:func:`edge_records` record by record: InputError at the first bad edge's line."""
    odometry: list[Odometry] = []
    closures: list[LoopClosure] = []
    for (a, b), delta, cov, odo, line_no in zip(
        graph.edges.tolist(), deltas, covariances, is_odometry, graph.edge_lines.tolist(), strict=True
    ):
        try:
            if odo:
                odometry.append(Odometry(a, b, delta, cov))
            else:
                closures.append(LoopClosure(a, b, delta, cov, source="dataset"))
        except MeasurementError as exc:
            raise InputError(str(exc), graph.source_path, line_no) from None
    return odometry, closures


def _observations(seen: Sightings, path) -> list[Observation]:
    """Range-bearing observations of ``BR`` lines (gtsam's load2D model, module docstring)."""
    z = np.stack([seen.range_m, wrap_angle(seen.bearing)], axis=1)
    cov = np.zeros((len(seen), 2, 2))
    cov[:, 0, 0], cov[:, 1, 1] = seen.sigmas[:, 1] ** 2, seen.sigmas[:, 0] ** 2
    try:
        return range_bearing_batch(seen.pose_ids, seen.landmark_ids, z, cov)
    except MeasurementError:
        pass
    out = []
    for k, line_no in enumerate(seen.lines.tolist()):
        try:
            out.append(
                Observation(
                    int(seen.pose_ids[k]),
                    int(seen.landmark_ids[k]),
                    z[k],
                    cov[k],
                    ObservationKind.RANGE_BEARING,
                )
            )
        except MeasurementError as exc:
            raise InputError(str(exc), path, line_no) from None
    return out


def _notes(graph: pg.PoseGraph) -> tuple[str, ...]:
    """What the reader did to the file's edges, said as a batch run's summary says it."""
    notes = []
    if graph.noise_note:
        notes.append(f"edge numbers read as {graph.noise_note}")
    if graph.n_information_fixed:
        notes.append(
            f"{graph.n_information_fixed} edges' information not positive definite, "
            f"replaced ({graph.information_fix}, as a batch run of the file does)"
        )
    self_edges = self_edges_note(graph)
    if self_edges:
        notes.append(self_edges)
    return tuple(notes)


def _fix_warnings(graph: pg.PoseGraph) -> tuple[str, ...]:
    """The sentence for ``FIX`` lines that hold more than one pose, which the frames leave
    out: a stream starts at the origin and follows the edges, so two held poses that the
    edges disagree with gave a different trajectory here than in a batch run of the file,
    with nothing said (one held pose fixes the gauge only)."""
    held = np.unique(graph.fixed)
    if len(held) < 2:
        return ()
    listed = ", ".join(map(str, held[:10].tolist())) + (", ..." if len(held) > 10 else "")
    return (
        f"FIX holds {len(held)} poses ({listed}): frame by frame they are not held, "
        "the run starts at the origin and follows the edges; --backend batch or isam2 on the "
        "whole file holds them",
    )


def self_edges_note(graph: pg.PoseGraph) -> str | None:
    """The sentence for the edges from a pose to itself the reader left out, or None."""
    lines = graph.self_edge_lines.tolist()
    if not lines:
        return None
    listed = ", ".join(map(str, lines[:10])) + (", ..." if len(lines) > 10 else "")
    return f"{len(lines)} edges from a pose to itself left out (lines {listed}): they constrain nothing"
