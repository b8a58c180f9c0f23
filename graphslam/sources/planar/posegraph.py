"""Readers for 2-D pose-graph files: TORO ``.graph``, g2o ``.g2o``, City10000.

Every reader raises :class:`~slamcore.errors.InputError` naming the file and
the 1-based line of bad input. Blank lines and lines starting with ``#`` are
skipped. TORO and g2o files are first read in bulk
(:mod:`graphslam.sources.planar.bulk`: all numbers parsed and checked at once);
whatever the bulk path declines is read line by line, which names the line.

Grouping into frames: poses are numbered ``first..last`` without gaps; frame
``k`` holds pose ``k``. The edge between ``k-1`` and ``k`` (in either direction,
kept as written: w10000 has ``EDGE2 1 0 ...``) is the frame's ``odometry``; every
other edge whose larger id is ``k`` is one of its ``loop_closures`` (direction
kept as written, ``source="dataset"``). Inverting an edge would change the
error value, so nothing is inverted.

Noise interpretation reproduces gtsam's loader (``gtsam/slam/dataset.cpp``,
``readNoiseModel``), checked factor by factor against ``gtsam.load2D`` and
``gtsam.readG2o`` in ``tests/test_readers.py``. The six numbers ``v1..v6`` after
an edge's measurement are read according to ``noise_format``:

- ``"auto"`` (what ``gtsam.load2D`` does by default, decided per line from the
  zero pattern): ``v1 0 v3 v4 0 0`` -> ``"graph"``; ``v1 0 0 v4 0 v6`` -> ``"cov"``;
  anything else is refused (gtsam refuses it too).
- ``"graph"``: TORO layout ``[[v1 v2 v5], [v2 v3 v6], [v5 v6 v4]]`` taken as a
  **covariance** (gtsam's NoiseFormatGRAPH).
- ``"toro"``: the same TORO layout taken as an **information** matrix (the TORO
  specification; gtsam's NoiseFormatTORO).
- ``"cov"``: g2o layout ``[[v1 v2 v3], [v2 v4 v5], [v3 v5 v6]]`` as a covariance.
- ``"g2o"``: g2o layout as an information matrix (what ``gtsam.readG2o`` uses).

Relative-pose angles are wrapped to [-pi, pi) (w10000 has values such as
-3.15858; gtsam's Pose2 wraps them the same way, so errors are unchanged).

So ``w10000.graph`` (every edge ``1 0 1 1 0 0``) gets identity covariances under
``read_toro``'s default, exactly like ``gtsam.load2D``.

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

from dataclasses import replace
from pathlib import Path

import numpy as np

from graphslam.sources.planar.bulk import noise_covariances, read_se2_lines
from graphslam.sources.tokens import (MAX_KEY_ID, SYMBOL_INDEX_LIMIT, iter_lines, parse_id,
                                      parse_numbers)
from slamcore.errors import InputError, MeasurementError, quote
from slamcore.planar.records import Dataset
from slamcore.planar.records import (
    Frame, LoopClosure, Observation, ObservationKind, Odometry, loop_closure_batch,
    odometry_batch,
)
from slamcore.planar.geometry import wrap_angle

NOISE_FORMATS = ("auto", "graph", "toro", "cov", "g2o")

#: City10000 pose noise sigmas [x_m, y_m, theta_rad], from gtsam's C++ examples
#: (examples/City10000.h and Hybrid_City10000.cpp: ``kPoseNoiseModel`` =
#: Sigmas(1/30, 1/30, 1/100)), used there for odometry and loop closures alike.
CITY10000_SIGMAS = np.array([1.0 / 30.0, 1.0 / 30.0, 1.0 / 100.0])


# --------------------------------------------------------------------------- helpers
def check_count(tokens, expected, path, line_no, layout):
    if len(tokens) != expected:
        raise InputError(f"{tokens[0]} line needs {expected} tokens ({layout}), "
                         f"got {len(tokens)}", path, line_no)


def noise_covariance(v, noise_format, path, line_no):
    """(3, 3) covariance from the six noise numbers ``v``, the way gtsam reads them
    (:func:`graphslam.sources.planar.bulk.noise_covariances` on one row), or InputError."""
    if noise_format not in NOISE_FORMATS:
        raise ValueError(f"noise_format must be one of {NOISE_FORMATS}, got {noise_format!r}")
    m = noise_covariances(np.array([v], dtype=np.float64), noise_format)
    if m is not None:
        return m[0]
    if noise_format == "auto":
        raise InputError(
            "noise numbers match neither diagonal layout gtsam.load2D recognises "
            f"({' '.join(f'{x:g}' for x in v)}); pass noise_format= explicitly",
            path, line_no)
    raise InputError("information matrix is not positive definite", path, line_no)


def group_edges(edges, path, pose_lines=None, ground_truth=None):
    """Frames from relative-pose edges.

    Args:
        edges: list of ``(line_no, from_id, to_id, delta (3,), covariance (3,3))``.
        pose_lines: optional ``{pose_id: line_no}`` of vertex declarations.
        ground_truth: optional list of (3,) true poses indexed from the first id.

    Returns:
        list of Frame, first pose first.
    """
    first_mention: dict[int, int] = {}
    for line_no, a, b, _, _ in edges:
        for k in (a, b):
            if k not in first_mention or line_no < first_mention[k]:
                first_mention[k] = line_no
    ids = set(first_mention) | set(pose_lines or {})
    if not ids:
        raise InputError("no poses found", path)
    first, last = min(ids), max(ids)
    odometry, closures = _edge_records(edges, path)
    _check_no_gap(sorted(ids), first_mention, path)
    for k in range(first + 1, last + 1):  # no gap: as many ids as lines, at most
        if k not in odometry:
            mentions = [first_mention.get(k), (pose_lines or {}).get(k)]
            mentions = [m for m in mentions if m is not None]
            if mentions:
                raise InputError(f"pose {k} has no edge to pose {k - 1}", path, min(mentions))
            # pose k never mentioned: blame the first line mentioning a later pose
            later = min(first_mention.get(j, 1 << 62) for j in range(k + 1, last + 1)
                        if j in first_mention)
            raise InputError(f"pose {k} is missing (gap in pose ids)", path, later)
    frames = []
    for i, k in enumerate(range(first, last + 1)):
        frames.append(Frame(
            pose_id=k,
            odometry=odometry.get(k),
            loop_closures=tuple(closures.get(k, ())),
            wTb_true=None if ground_truth is None else ground_truth[i],
        ))
    return frames


def _edge_records(edges, path) -> tuple[dict[int, Odometry], dict[int, list[LoopClosure]]]:
    """``{pose: its odometry}`` and ``{pose: closures to earlier poses}`` of ``edges``.

    The records are checked in bulk (64 000 edges of w10000: 0.1 s, not 3 s one by
    one); when anything is off, :func:`_edge_records_one_by_one` names the line.
    """
    odo_rows: dict[int, int] = {}  # pose -> index of its odometry edge
    lc_rows: list[int] = []
    for n, (_, a, b, _, _) in enumerate(edges):
        if a == b:
            return _edge_records_one_by_one(edges, path)
        if abs(a - b) == 1 and max(a, b) not in odo_rows:
            odo_rows[max(a, b)] = n
        else:
            lc_rows.append(n)
    try:
        built = _batch(odometry_batch, [edges[n] for n in odo_rows.values()])
        loops = _batch(loop_closure_batch, [edges[n] for n in lc_rows])
    except MeasurementError:
        return _edge_records_one_by_one(edges, path)
    closures: dict[int, list[LoopClosure]] = {}
    for lc in loops:
        closures.setdefault(max(lc.from_id, lc.to_id), []).append(lc)
    return dict(zip(odo_rows, built)), closures


def _edge_records_one_by_one(edges, path):
    """:func:`_edge_records` record by record: InputError at the first bad edge's line."""
    odometry: dict[int, Odometry] = {}
    closures: dict[int, list[LoopClosure]] = {}
    for line_no, a, b, delta, cov in edges:
        if a == b:
            raise InputError(f"edge from pose {a} to itself", path, line_no)
        hi = max(a, b)
        try:
            if abs(a - b) == 1 and hi not in odometry:
                odometry[hi] = Odometry(a, b, delta, cov)
            else:
                closures.setdefault(hi, []).append(
                    LoopClosure(a, b, delta, cov, source="dataset"))
        except MeasurementError as exc:
            raise InputError(str(exc), path, line_no) from None
    return odometry, closures


def _batch(make, rows):
    return make([r[1] for r in rows], [r[2] for r in rows], [r[3] for r in rows],
                [r[4] for r in rows])


def _check_no_gap(ids: list[int], first_mention: dict[int, int], path) -> None:
    """InputError at the first gap in the sorted ids, found without looping over it."""
    gaps = np.flatnonzero(np.diff(np.array(ids, dtype=object)) != 1)
    if len(gaps):
        after = ids[gaps[0] + 1]
        raise InputError(f"pose {ids[gaps[0]] + 1} is missing (gap in pose ids)", path,
                         first_mention.get(after))


def wrapped_delta(values):
    """(3,) relative pose with its angle wrapped to [-pi, pi) (gtsam's Pose2 wraps too)."""
    d = np.array(values, dtype=np.float64)
    d[2] = float(wrap_angle(d[2]))
    return d


def _dataset(name, frames, path):
    return Dataset(name=name, frames=frames, prior_wTb=np.zeros(3),
                   prior_covariance=np.eye(3) * 1e-6, landmarks_true=None,
                   has_timestamps=False, source_path=str(path))


def _read_se2_graph(path, vertex_tag, edge_tag, ignored, noise_format, name,
                    landmark_tag=None):
    if noise_format not in NOISE_FORMATS:
        raise ValueError(f"noise_format must be one of {NOISE_FORMATS}, got {noise_format!r}")
    bulk = read_se2_lines(path, vertex_tag, edge_tag, ignored, noise_format, SYMBOL_INDEX_LIMIT)
    if bulk is not None:  # a valid file without landmark lines, read in bulk
        return _dataset(name, _grouped(*bulk, path), path)
    edges = []
    sightings: list[tuple[int, Observation]] = []  # (line, observation)
    pose_lines: dict[int, int] = {}
    for line_no, tok in iter_lines(path):
        tag = tok[0]
        if tag == landmark_tag:
            sightings.append((line_no, _bearing_range(tok, path, line_no)))
        elif tag == edge_tag:
            check_count(tok, 12, path, line_no, f"{edge_tag} id1 id2 dx dy dth + 6 noise")
            a = parse_id(tok[1], path, line_no, "id", limit=MAX_KEY_ID)
            b = parse_id(tok[2], path, line_no, "id", limit=MAX_KEY_ID)
            nums = parse_numbers(tok[3:], path, line_no)
            cov = noise_covariance(nums[3:], noise_format, path, line_no)
            edges.append((line_no, a, b, wrapped_delta(nums[:3]), cov))
        elif tag == vertex_tag:
            check_count(tok, 5, path, line_no, f"{vertex_tag} id x y theta")
            k = parse_id(tok[1], path, line_no, "id", limit=MAX_KEY_ID)
            parse_numbers(tok[2:], path, line_no)
            if k in pose_lines:
                raise InputError(f"pose {k} declared twice", path, line_no)
            pose_lines[k] = line_no
        elif tag in ignored:
            continue
        else:
            raise InputError(f"unknown tag {quote(tag)}", path, line_no)
    frames = _grouped(edges, pose_lines, path)
    return _dataset(name, _with_sightings(frames, sightings, path) if sightings else frames, path)


def _grouped(edges, pose_lines, path):
    """Frames of the edges; with vertex lines, an edge to an undeclared pose is an error."""
    if pose_lines:
        for line_no, a, b, _, _ in edges:
            for k in (a, b):
                if k not in pose_lines:
                    raise InputError(f"edge names pose {k}, which has no vertex line", path,
                                     line_no)
    return group_edges(edges, path, pose_lines)


def _bearing_range(tok, path, line_no) -> Observation:
    """A ``BR i j bearing range bearing_sigma range_sigma`` line as an Observation."""
    check_count(tok, 7, path, line_no, "BR pose landmark bearing range bearing_sigma range_sigma")
    pose = parse_id(tok[1], path, line_no, "id", limit=MAX_KEY_ID)
    landmark = parse_id(tok[2], path, line_no, "landmark id", limit=MAX_KEY_ID)
    bearing, range_m, sigma_b, sigma_r = parse_numbers(tok[3:], path, line_no)
    if sigma_b <= 0.0 or sigma_r <= 0.0:
        raise InputError("BR sigmas must be positive", path, line_no)
    try:
        return Observation(pose, landmark, np.array([range_m, float(wrap_angle(bearing))]),
                           np.diag([sigma_r ** 2, sigma_b ** 2]), ObservationKind.RANGE_BEARING)
    except MeasurementError as exc:
        raise InputError(str(exc), path, line_no) from None


def _with_sightings(frames, sightings, path):
    """``frames`` with each observation in the frame of the pose it was taken from."""
    index = {f.pose_id: n for n, f in enumerate(frames)}
    seen: list[list[Observation]] = [[] for _ in frames]
    for line_no, obs in sightings:
        if obs.pose_id not in index:
            raise InputError(f"BR seen from pose {obs.pose_id}, which no edge or vertex names",
                             path, line_no)
        seen[index[obs.pose_id]].append(obs)
    return [replace(f, observations=tuple(f.observations) + tuple(o)) if o else f
            for f, o in zip(frames, seen)]


# --------------------------------------------------------------------------- public
def read_toro(path, noise_format: str = "auto") -> Dataset:
    """Read a TORO ``.graph`` file (``VERTEX2``, ``EDGE2``, ``BR``; ``EQUIV`` ignored).

    ``EDGE2 id1 id2 dx dy dth v1..v6``; the noise numbers are read as
    ``gtsam.load2D`` reads them (``noise_format="auto"``, see module docstring).
    ``BR`` lines are landmark observations (module docstring).
    Name of the dataset: the file stem.
    """
    return _read_se2_graph(path, "VERTEX2", "EDGE2", ("EQUIV",), noise_format, Path(path).stem,
                           landmark_tag="BR")


def read_g2o(path, noise_format: str = "g2o") -> Dataset:
    """Read a 2-D g2o file (``VERTEX_SE2``, ``EDGE_SE2``; ``FIX`` lines ignored).

    ``EDGE_SE2 id1 id2 dx dy dth i11 i12 i13 i22 i23 i33`` is an information
    matrix in g2o order, as ``gtsam.readG2o`` reads it. (gtsam's parser stops
    silently at the first line it does not know, e.g. ``FIX``; we skip ``FIX``
    and read on.) Landmark tags
    (``VERTEX_XY``, ``EDGE_SE2_XY``) are refused as unknown.
    """
    return _read_se2_graph(path, "VERTEX_SE2", "EDGE_SE2", ("FIX",), noise_format,
                           Path(path).stem)


def read_pose_graph(path) -> Dataset:
    """Dispatch on extension (``.graph`` -> TORO, ``.g2o`` -> g2o), else on the first tag."""
    suffix = Path(path).suffix.lower()
    if suffix == ".graph":
        return read_toro(path)
    if suffix == ".g2o":
        return read_g2o(path)
    for line_no, tok in iter_lines(path):
        if tok[0] in ("VERTEX2", "EDGE2", "EQUIV", "BR"):
            return read_toro(path)
        if tok[0] in ("VERTEX_SE2", "EDGE_SE2", "FIX"):
            return read_g2o(path)
        raise InputError(f"cannot tell the pose-graph format from tag {quote(tok[0])}",
                         path, line_no)
    raise InputError("empty pose-graph file", path)


def read_w10000() -> Dataset:
    """gtsam's w10000 Manhattan pose graph (``w10000.graph``, TORO, in the gtsam wheel)."""
    import gtsam  # only to find the wheel's example data

    return read_pose_graph(gtsam.findExampleDataFile("w10000.graph"))


def read_city10000(path=None, ground_truth_path=None) -> Dataset:
    """Read gtsam's City10000 pose graph with its ground truth (name "city10000").

    Line format: ``EDGE2 keyS <unused> keyT ambiguous n x1 y1 th1 [x2 y2 th2 ...]``
    (tokens as parsed by gtsam's ``HybridCity10000.py``); only the first
    hypothesis, the correct one, is kept. Every edge gets the covariance
    ``diag(CITY10000_SIGMAS**2)`` with sigmas (1/30, 1/30, 1/100) from gtsam's C++
    City10000 examples (``kPoseNoiseModel``; note: one version of the Python
    example ``HybridCity10000.py`` uses 1/20 for x, y instead).

    The ground-truth file has one ``x y theta`` line per pose; its line count must
    equal the number of poses.
    """
    import gtsam

    if path is None:
        path = gtsam.findExampleDataFile("T1_city10000_04.txt")
    if ground_truth_path is None:
        ground_truth_path = gtsam.findExampleDataFile("ISAM2_GT_city10000.txt")
    cov = np.diag(CITY10000_SIGMAS ** 2)
    edges = []
    for line_no, tok in iter_lines(path):
        if tok[0] != "EDGE2":
            raise InputError(f"unknown tag {quote(tok[0])}", path, line_no)
        if len(tok) < 9:
            raise InputError(f"EDGE2 line needs at least 9 tokens, got {len(tok)}",
                             path, line_no)
        a = parse_id(tok[1], path, line_no, "id", limit=MAX_KEY_ID)
        b = parse_id(tok[3], path, line_no, "id", limit=MAX_KEY_ID)
        parse_id(tok[4], path, line_no, "ambiguity flag", limit=MAX_KEY_ID)
        n = parse_id(tok[5], path, line_no, "hypothesis count", limit=MAX_KEY_ID)
        if n < 1 or len(tok) != 6 + 3 * n:
            raise InputError(f"EDGE2 line with {n} hypotheses needs {6 + 3 * n} tokens, "
                             f"got {len(tok)}", path, line_no)
        nums = parse_numbers(tok[6:], path, line_no)
        edges.append((line_no, a, b, wrapped_delta(nums[:3]), cov))
    truth = []
    for line_no, tok in iter_lines(ground_truth_path):
        if len(tok) != 3:
            raise InputError(f"ground-truth line needs 3 numbers (x y theta), got {len(tok)}",
                             ground_truth_path, line_no)
        truth.append(np.array(parse_numbers(tok, ground_truth_path, line_no)))
    ids = {e[1] for e in edges} | {e[2] for e in edges}
    n_poses = (max(ids) - min(ids) + 1) if ids else 0
    if len(truth) != n_poses:
        raise InputError(f"ground truth has {len(truth)} poses, the graph has {n_poses}",
                         ground_truth_path)
    frames = group_edges(edges, path, ground_truth=truth)
    return _dataset("city10000", frames, path)
