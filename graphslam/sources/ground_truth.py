"""Ground-truth trajectory files (``--ground-truth FILE``) and their association
with an image sequence's frames or a 2-D dataset's poses (numpy only).

Formats, told apart by the content (the ``.csv`` extension also says EuRoC):

* **TUM**: ``t x y z qx qy qz qw`` a line (spaces), the camera-to-world pose
  at time ``t`` (seconds; for pose graphs and sequences without timestamps,
  the pose id or frame index, as our own ``trajectory.tum`` writes it);
* **KITTI**: 12 numbers a line, the row-major 3x4 ``wTc`` of frame k on line
  k (no times: associated by frame index);
* **EuRoC** ``state_groundtruth_estimate0/data.csv``: ``timestamp [ns], px,
  py, pz, qw, qx, qy, qz, ...`` separated by commas (the body pose; the
  camera extrinsics of ``sensor.yaml`` are not applied here);
* **COLMAP** ``images.txt`` (a text model): two lines an image, ``IMAGE_ID QW QX QY
  QZ TX TY TZ CAMERA_ID NAME`` (the world-to-camera pose) then its 2-D points (read
  for nothing, possibly empty), or the same in ``images.bin`` (COLMAP's default
  output, :mod:`graphslam.sources.spatial.colmap_binary`); the truth of an image
  folder, associated by file name (``--ground-truth`` only: ``graphslam eval``
  pairs poses by time or line, and refuses it). Its unit of length is the
  reconstruction's: the run says so.

A line that does not have its format's form is refused, the format told or
given: a comma in a TUM or KITTI line; in an EuRoC line no comma, an empty
field, or a time that is not integer nanoseconds (a TUM file given as EuRoC
read its seconds as nanoseconds and its columns shifted, without a word).

Association: an image sequence takes, per frame, the truth with the nearest
timestamp within :data:`~graphslam.sources.spatial.sequence.ASSOCIATION_MAX_DT_S`
(TUM, EuRoC) or the line of its frame number (KITTI: the number in the image
file name when every name is one, else the position), or COLMAP's image of the
frame's file name (a NAME with folders matches the end of the path); frames without truth
are dropped, as the TUM and EuRoC readers do. A 2-D dataset takes the truth
of each pose by its pose id (TUM time column, KITTI line number), or by its
timestamp when the dataset has real ones, keeping x, y and the yaw; a truth that
leaves the plane (:func:`off_plane`) is said to, since that drops what the score
cannot see.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphslam.sources.posegraph_files import TAGS, TRANSLATION_MAX_M
from graphslam.sources.spatial.frames import FrameSelection, source_indices
from graphslam.sources.spatial.sequence import (
    ASSOCIATION_MAX_DT_S,
    ImageSequence,
    associate,
    check_increasing,
    check_rotation,
    parse_euroc_line,
    parse_floats,
    quat_to_rotation,
    read_lines,
    rotation_entries,
)
from slamcore.errors import InputError
from slamcore.input_files import check_input_path
from slamcore.planar.records import Dataset

TRAJECTORY_FORMATS = ("tum", "kitti", "euroc", "colmap")

#: A 2-D run is scored on its truth's x, y and yaw. A truth whose height varies by more
#: than this share of its horizontal extent (and by more than the floor below) is
#: taken off a plane it does not lie in: a 3-D trajectory, or one whose up axis is not
#: z (KITTI's camera frame, y down): its ATE in the plane is no ATE of the motion.
#: A building's ramps rise about 1 in 12, a road's grades stay under 1 in 10 over a
#: short stretch and far less over a route: 5 % keeps such truths quiet.
PLANAR_HEIGHT_SHARE = 0.05
#: Height variation no truth of a planar robot is said for, m (motion capture and
#: survey noise, a floor's unevenness).
PLANAR_HEIGHT_FLOOR_M = 0.1
#: Tilt of a truth pose's up axis beyond which it is said, deg: no floor slopes so.
PLANAR_TILT_DEG = 15.0


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Poses read from a ground-truth file.

    Attributes:
        format: ``"tum"``, ``"kitti"``, ``"euroc"`` or ``"colmap"``.
        stamps_s: (N,) time column in seconds (TUM as written, EuRoC ns / 1e9),
            strictly increasing (rows sorted by time, a repeated time refused);
            None for KITTI and COLMAP.
        wTc: (N, 4, 4) camera- (or body-) to-world poses, in time order (KITTI, COLMAP:
            file order).
        path: the file.
        names: COLMAP: (N,) the image file name of each pose, else None.
        notes: how the reader took the poses where that changes the score, one clause
            each ("header stamps all 0: ..."), said by ``graphslam eval``.
    """

    format: str
    stamps_s: np.ndarray | None
    wTc: np.ndarray
    path: str
    names: tuple[str, ...] | None = None
    notes: tuple[str, ...] = ()


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _position(t: np.ndarray, path: Path, line: int | None) -> np.ndarray:
    """``t`` when within :data:`TRANSLATION_MAX_M` (as the pose-graph readers), else
    InputError: beyond it the alignment's sums overflow (LAPACK hung on the inf)."""
    if not np.max(np.abs(t)) <= TRANSLATION_MAX_M:
        raise InputError(
            f"position beyond {TRANSLATION_MAX_M:.0e} m: no trajectory's poses lie so far", path, line
        )
    return t


def detect_format(path: Path, first_line: str) -> str:
    """``"euroc"`` (commas or ``.csv``), ``"kitti"`` (12 numbers), ``"tum"`` (8) or
    ``"colmap"`` (9 numbers and a name)."""
    if _is_colmap_image_line(first_line):
        return "colmap"
    if path.suffix.lower() == ".csv" or "," in first_line:
        return "euroc"
    tokens = first_line.split()
    n = len(tokens)
    tag = tokens[0] if n else ""
    if tag in TAGS:  # "5 numbers a line" of a line that starts with a word misled
        kind = "TORO" if TAGS[tag][0] == "toro" else TAGS[tag][0]
        raise InputError(
            f"a {kind} pose graph ({tag} lines), not a trajectory file: its vertex ids are "
            "no times or frames to pair poses by (give TUM, KITTI, EuRoC or COLMAP's images.txt)",
            path,
        )
    if n == 12:
        return "kitti"
    if n == 8:
        return "tum"
    raise InputError(
        f"cannot tell the trajectory format: {n} numbers a line (TUM has 8: "
        "t x y z qx qy qz qw; KITTI 12; EuRoC is comma-separated; COLMAP's images.txt "
        "9 and an image name)",
        path,
    )


def read_trajectory(path: str | Path, fmt: str | None = None) -> Trajectory:
    """A trajectory file in any of :data:`TRAJECTORY_FORMATS` (module doc); ``fmt``
    None tells the format from the content."""
    path = Path(path)
    from graphslam.sources.spatial.colmap_binary import is_colmap_binary

    if is_colmap_binary(path) and fmt in (None, "colmap"):  # COLMAP's default model output
        check_input_path(path, "trajectory file")
        return _read_colmap_images(path)
    lines = read_lines(path, "trajectory file")
    if not lines:
        raise InputError("no poses in the trajectory file", path)
    if fmt is None:
        fmt = detect_format(path, lines[0][1])
    elif fmt not in TRAJECTORY_FORMATS:
        raise InputError(f"unknown trajectory format {fmt!r} (one of {TRAJECTORY_FORMATS})", path)
    if fmt == "colmap":
        return _read_colmap_images(path)
    if fmt == "tum":
        fast = _tum_at_once(lines)
        if fast is not None:
            order = _time_order(fast[0], [n for n, _ in lines], path)
            return Trajectory(fmt, fast[0][order], fast[1][order], str(path))
    stamps, poses = [], []
    for n, text in lines:
        if fmt != "euroc" and "," in text:
            raise InputError(
                f"a comma in a {fmt.upper()} line: {fmt.upper()} is space-separated "
                "(the comma-separated format is EuRoC)",
                path,
                n,
            )
        if fmt == "kitti":
            v = parse_floats(text, path, n, 12, "numbers (KITTI: row-major 3x4 pose)")
            R = check_rotation(v.reshape(3, 4)[:, :3], path, n)
            poses.append(_pose(R, _position(v.reshape(3, 4)[:, 3], path, n)))
        elif fmt == "tum":
            v = parse_floats(text, path, n, 8, "numbers (TUM: t x y z qx qy qz qw)")
            stamps.append(v[0])
            poses.append(_pose(quat_to_rotation(v[7], v[4], v[5], v[6], path, n), _position(v[1:4], path, n)))
        else:
            v = parse_euroc_line(text, path, n, "t_ns,px,py,pz,qw,qx,qy,qz,...")
            if v.size < 8:
                raise InputError(f"expected at least 8 numbers, got {v.size}", path, n)
            stamps.append(v[0] / 1e9)  # as evo: 1e9 is exact, 1e-9 is not
            poses.append(_pose(quat_to_rotation(v[4], v[5], v[6], v[7], path, n), _position(v[1:4], path, n)))
    if fmt == "kitti":
        return Trajectory(fmt, None, np.array(poses), str(path))
    order = _time_order(np.array(stamps), [n for n, _ in lines], path)
    return Trajectory(fmt, np.array(stamps)[order], np.array(poses)[order], str(path))


def _is_colmap_image_line(text: str) -> bool:
    """Whether a line is an image line of COLMAP's ``images.txt``: an id, seven numbers,
    a camera id and a name that is not a number."""
    tokens = text.split()
    if len(tokens) < 10 or not (tokens[0].isdigit() and tokens[8].isdigit()):
        return False
    try:
        float(tokens[9])
    except ValueError:
        return True
    return False


def _colmap_image_lines(path: Path) -> list[tuple[int, str]]:
    """The image lines of COLMAP's ``images.txt``. Its lines come in pairs and a point
    line may be empty, so the file is read whole rather than as non-empty lines."""
    text = path.read_text(encoding="utf-8-sig", errors="replace")
    numbered = [(n, line) for n, line in enumerate(text.splitlines(), start=1) if not line.startswith("#")]
    return [(n, line) for n, line in numbered[0::2] if line.strip()]  # a blank line at the end


def _read_colmap_images(path: Path) -> Trajectory:
    """COLMAP's ``images.txt`` or ``images.bin`` (module doc): camera-to-world poses in
    file order and their image names."""
    from graphslam.sources.spatial.colmap_binary import image_lines, is_colmap_binary

    binary = is_colmap_binary(path)
    poses, names = [], []
    for n, line in image_lines(path) if binary else _colmap_image_lines(path):
        at = None if binary else n  # a binary file's errors name its record instead
        record = f"image record {n}: " if binary else ""
        if not _is_colmap_image_line(line):
            raise InputError(
                f"{record}expected a COLMAP image line (IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME): "
                f"{line.strip()[:60]!r}",
                path,
                at,
            )
        tokens = line.split()
        v = parse_floats(" ".join(tokens[1:8]), path, at, 7, f"{record}numbers (QW QX QY QZ TX TY TZ)")
        R_cw = quat_to_rotation(v[0], v[1], v[2], v[3], path, at)
        t_cw = _position(v[4:7], path, at)
        poses.append(_pose(R_cw.T, -R_cw.T @ t_cw))  # COLMAP stores world-to-camera
        names.append(" ".join(tokens[9:]))
    if not poses:
        raise InputError("no images in the COLMAP model", path)
    repeated = sorted({m for m in names if names.count(m) > 1})
    if repeated:
        raise InputError(f"image {repeated[0]!r} is listed twice", path)
    return Trajectory("colmap", None, np.array(poses), str(path), tuple(names))


#: What a TUM file of plain numbers holds (no letter but the exponent's, no comma).
_PLAIN_NUMBERS = re.compile(r"[0-9eE+\-. \t]*")


def _tum_at_once(lines: list[tuple[int, str]]) -> tuple[np.ndarray, np.ndarray] | None:
    """``(stamps (N,), wTc (N, 4, 4))`` of TUM lines parsed as one array, the same numbers
    as the line-by-line reader (the same formulas, element by element), or None when any
    line is not plain (that reader then names the line). The line-by-line read took
    17 s of a 20 s eval of two 250 000-pose files (thirteenth hostile pass)."""
    if not all(_PLAIN_NUMBERS.fullmatch(text) for _, text in lines):
        return None
    tokens = [text.split() for _, text in lines]
    if any(len(t) != 8 for t in tokens):
        return None
    try:
        v = np.array(tokens, dtype=np.float64)
    except ValueError:  # "1.2.3", "e5": the line reader names it
        return None
    if not np.all(np.isfinite(v)) or not np.max(np.abs(v[:, 1:4]), initial=0.0) <= TRANSLATION_MAX_M:
        return None
    qx, qy, qz, qw = v[:, 4], v[:, 5], v[:, 6], v[:, 7]
    norm = np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    if not np.all((norm > 0.9) & (norm < 1.1)):
        return None
    T = np.zeros((len(v), 4, 4))
    T[:, :3, :3] = np.moveaxis(np.array(rotation_entries(qw / norm, qx / norm, qy / norm, qz / norm)), -1, 0)
    T[:, :3, 3] = v[:, 1:4]
    T[:, 3, 3] = 1.0
    return v[:, 0].copy(), T


def _time_order(stamps: np.ndarray, line_numbers: list[int], path: Path) -> np.ndarray:
    """Rows of a TUM or EuRoC file in time order; InputError naming both lines of a
    repeated stamp. Unsorted rows are sorted, not refused: our own ``trajectory.tum``
    of a pose graph takes pose ids as times, in the graph's order. A repeated stamp
    is refused: association would silently take one of the two poses."""
    order = np.argsort(stamps, kind="stable")
    same = np.nonzero(np.diff(stamps[order]) == 0)[0]
    if same.size:
        a, b = sorted((int(order[same[0]]), int(order[same[0] + 1])))
        raise InputError(
            f"time {float(stamps[b])} is duplicated (also on line {line_numbers[a]})", path, line_numbers[b]
        )
    return order


def read_times(path: str | Path, trajectory: Trajectory) -> Trajectory:
    """``trajectory`` (KITTI, no times) with the stamps of a KITTI ``times.txt``:
    one time in seconds a line, one line per pose, strictly increasing (line k
    is pose k, so a file out of order cannot be sorted: it is refused)."""
    path = Path(path)
    lines = read_lines(path, "times file")
    stamps = np.array([parse_floats(text, path, n, 1, "number (a time in seconds)")[0] for n, text in lines])
    check_increasing(stamps, [n for n, _ in lines], path)
    if len(stamps) != len(trajectory.wTc):
        raise InputError(f"{len(stamps)} times for {len(trajectory.wTc)} poses of {trajectory.path}", path)
    return dataclasses.replace(trajectory, stamps_s=stamps)


#: How a truth file names pose ids: what a refusal of another time column says to give.
POSE_ID_TRUTH = "give TUM with t = pose id, or KITTI (line = pose id)"


def rows_by_pose_id(truth: Trajectory, ids: np.ndarray, what: str = "pose ids") -> np.ndarray:
    """(N,) row of ``truth`` holding each pose id of ``ids`` (N,), -1 where none: the
    KITTI line number, or the TUM time column read as pose ids (``what`` names them in
    the refusal of a time that is not a whole number). EuRoC's nanosecond times are
    never pose ids: InputError. Shared by the 2-D datasets and the pose-graph files."""
    if truth.format == "euroc":
        raise InputError(
            f"EuRoC ground truth has nanosecond times, not pose ids; {POSE_ID_TRUTH}", truth.path
        )
    check_not_colmap(truth, POSE_ID_TRUTH)
    ids = np.asarray(ids, dtype=np.int64)
    if truth.stamps_s is None:
        return np.where((ids >= 0) & (ids < len(truth.wTc)), ids, -1)
    check_whole_stamps(truth, what, POSE_ID_TRUTH)
    row_of = {int(t): r for r, t in enumerate(truth.stamps_s.tolist())}
    return np.array([row_of.get(int(i), -1) for i in ids.tolist()], dtype=np.int64)


def check_not_colmap(truth: Trajectory, hint: str) -> None:
    """InputError for COLMAP truth where poses are matched by id or time: it names image
    files, and its order is COLMAP's image ids, not the frames' (taken by line, the poses
    of other images were scored in silence)."""
    if truth.format == "colmap":
        raise InputError(
            "COLMAP's images.txt names image files, not times or pose ids: it is the truth of "
            f"an image folder (graphslam run --dataset FOLDER --ground-truth images.txt); {hint}",
            truth.path,
        )


def check_whole_stamps(truth: Trajectory, what: str, hint: str) -> None:
    """InputError when ``truth``'s time column, read as ``what`` (pose ids, frame
    indices), holds a number that is not whole: times in seconds were read as ids
    (truth at 10 Hz from 0 s gave pose k the truth of k s, row 10 k, without a word)."""
    t = truth.stamps_s
    if t is None:
        return
    bad = np.nonzero(np.mod(t, 1.0) != 0)[0]
    if bad.size:
        raise InputError(
            f"its time column is read as {what}, and {float(t[bad[0]])!r} is not a whole "
            f"number (times in seconds?); {hint}",
            truth.path,
        )


def _frame_numbers(sequence: ImageSequence) -> np.ndarray:
    """(N,) frame number per image: the file name's number (KITTI's 000042.png),
    else the position in the sequence as read (a ``--frames`` selection's picks)."""
    stems = [Path(p).stem for p in sequence.image_paths]
    if all(s.isascii() and s.isdigit() for s in stems):
        return np.array([int(s) for s in stems], dtype=np.int64)
    return source_indices(sequence)


def _indices_for_frames(truth: Trajectory, sequence: ImageSequence) -> np.ndarray:
    """(N,) row of ``truth`` per frame of ``sequence``, -1 where it has none."""
    if truth.names is not None:  # COLMAP: by the image's file name
        return _rows_by_name(truth, sequence)
    if truth.stamps_s is None:
        rows = _frame_numbers(sequence)
        return np.where(rows < len(truth.wTc), rows, -1)
    order = np.argsort(truth.stamps_s, kind="stable")
    if sequence.stamps_s is None:
        # no image times: the time column is the frame index (our trajectory.tum)
        check_whole_stamps(
            truth,
            f"frame indices ({sequence.name!r} has no image times)",
            "give the truth with t = frame index, or the sequence its times",
        )
        frame_t = source_indices(sequence).astype(np.float64)
        idx = associate(frame_t, truth.stamps_s[order], 0.5)
    else:
        idx = associate(
            np.asarray(sequence.stamps_s, dtype=np.float64), truth.stamps_s[order], ASSOCIATION_MAX_DT_S
        )
    return np.where(idx >= 0, order[np.maximum(idx, 0)], -1)


def _rows_by_name(truth: Trajectory, sequence: ImageSequence) -> np.ndarray:
    """(N,) row of COLMAP ``truth`` whose name is each frame's file (a name with folders,
    ``sub/a.jpg``, matches the end of the frame's path), -1 where none is."""
    names = truth.names or ()
    row_of = {name.replace("\\", "/"): r for r, name in enumerate(names)}
    rows = []
    for p in sequence.image_paths:
        parts = Path(p).as_posix().split("/")
        # the longest tail of the path that COLMAP names (its NAME is relative to its image root)
        row = next((row_of[t] for k in range(len(parts)) if (t := "/".join(parts[k:])) in row_of), -1)
        rows.append(row)
    return np.array(rows, dtype=np.int64)


def with_ground_truth(sequence: ImageSequence, truth: Trajectory) -> ImageSequence:
    """``sequence`` with ``wTc_true`` from ``truth`` (replacing any it had).

    Frames without truth are dropped (module doc); a sequence that brings its
    own per-frame odometry (the synthetic one) cannot lose frames, so there a
    missing frame raises InputError, as does no frame matching at all.
    """
    rows = _indices_for_frames(truth, sequence)
    keep = rows >= 0
    if truth.names is not None:
        how = "by file name"
    else:
        how = "by frame index" if truth.stamps_s is None else "by timestamp"
    if not np.any(keep):
        raise InputError(f"no frame of {sequence.name!r} has ground truth ({how})", truth.path)
    changes: dict = {"wTc_true": truth.wTc[rows[keep]]}
    warnings = list(sequence.frame_warnings)  # said with the frames' doubts; metrics.json keeps them
    if truth.format == "colmap":
        warnings.append(
            f"{truth.path}: COLMAP's poses are in its reconstruction's unit of length (metres only "
            "if the model was scaled to them): the ATE and RPE 'in m' are in that unit"
        )
    if not np.all(keep):
        if getattr(sequence, "odometry", None) is not None:
            raise InputError(
                f"{int(np.sum(~keep))} of {len(keep)} frames have no ground truth "
                f"({how}), and {sequence.name!r} cannot drop frames",
                truth.path,
            )
        changes["image_paths"] = [p for p, k in zip(sequence.image_paths, keep, strict=True) if k]
        if sequence.stamps_s is not None:
            changes["stamps_s"] = np.asarray(sequence.stamps_s)[keep]
        if isinstance(sequence, FrameSelection):  # it loads by its indices, not its paths
            changes["indices"] = np.asarray(sequence.indices)[keep]
        which = "frames selected" if isinstance(sequence, FrameSelection) else "frames"
        warnings.append(
            f"{truth.path}: {int(np.sum(~keep))} of {len(keep)} {which} have no ground truth "
            f"({how}) and are left out of the run"
        )
    if len(warnings) > len(sequence.frame_warnings):
        changes["frame_warnings"] = tuple(warnings)
    return dataclasses.replace(sequence, **changes)


def off_plane(wTc: np.ndarray) -> str | None:
    """The sentence for truth poses (N, 4, 4) that a 2-D run's score (x, y and yaw) would
    take off a plane they do not lie in (:data:`PLANAR_HEIGHT_SHARE`,
    :data:`PLANAR_TILT_DEG`), else None."""
    wTc = np.asarray(wTc, dtype=np.float64).reshape(-1, 4, 4)
    if not len(wTc):
        return None
    height = float(np.ptp(wTc[:, 2, 3]))
    extent = float(np.hypot(np.ptp(wTc[:, 0, 3]), np.ptp(wTc[:, 1, 3])))
    tilt = float(np.degrees(np.arccos(np.clip(wTc[:, 2, 2], -1.0, 1.0))).max())
    if height <= max(PLANAR_HEIGHT_FLOOR_M, PLANAR_HEIGHT_SHARE * extent) and tilt <= PLANAR_TILT_DEG:
        return None
    return (
        f"the ground truth is not planar (height spans {height:.3g} m against {extent:.3g} m "
        f"across x and y; up axis tilted up to {tilt:.3g} deg): this 2-D run is scored on its "
        "x, y and yaw only, which is no ATE of a 3-D motion or of a truth whose up axis is not z"
    )


def planar_ground_truth(dataset: Dataset, truth: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """``(pose_ids (M,), wTb (M, 3))``: the truth of ``dataset``'s poses, ``[x, y, yaw]``.

    By pose id (TUM time column, KITTI line number) or, when the dataset has
    real timestamps, by nearest time; poses without truth are left out (ATE
    is taken over the common ids). InputError when no pose matches.
    """
    ids = np.array([f.pose_id for f in dataset.frames], dtype=np.int64)
    if truth.format != "euroc" and truth.stamps_s is not None and dataset.has_timestamps:
        order = np.argsort(truth.stamps_s, kind="stable")
        t = np.array([f.stamp_s for f in dataset.frames], dtype=np.float64)
        idx = associate(t, truth.stamps_s[order], ASSOCIATION_MAX_DT_S)
        rows = np.where(idx >= 0, order[np.maximum(idx, 0)], -1)
    else:
        rows = rows_by_pose_id(truth, ids, f"pose ids ({dataset.name!r} has no timestamps)")
    keep = rows >= 0
    if not np.any(keep):
        by_time = dataset.has_timestamps and truth.stamps_s is not None
        raise InputError(
            f"no pose of {dataset.name!r} has ground truth (matched by {'time' if by_time else 'pose id'})",
            truth.path,
        )
    wTc = truth.wTc[rows[keep]]
    yaw = np.arctan2(wTc[:, 1, 0], wTc[:, 0, 0])
    return ids[keep], np.column_stack([wTc[:, 0, 3], wTc[:, 1, 3], yaw])
