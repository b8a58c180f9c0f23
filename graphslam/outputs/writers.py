"""Output files: TUM trajectories (2-D and 3-D), landmark CSV, metrics JSON (numpy + stdlib)."""

from __future__ import annotations

import contextlib
import errno
import json
import math
import stat
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from slamcore.errors import GraphSlamError
from slamcore.files import atomic_open, check_no_folder_at, write_error_line
from slamcore.spatial.geometry import rotation_to_quaternion


def metres(v: float) -> str:
    """A coordinate to the nanometre, shortest form: 9 significant digits (as before)
    rounded a UTM easting of 4 500 000.123456 m to 4 500 000.12 (the 11th pass)."""
    return np.format_float_positional(float(v), precision=9, unique=True, trim="-")


#: Stamps are written to the nanosecond: ROS and bag clocks count nanoseconds, and no
#: data read here is finer (6 decimals, as before, wrote 300 synthetic stamps 0.1 us
#: apart as 31 values, which ``graphslam eval`` refuses as duplicated times).
STAMP_DECIMALS = 9
#: ... and with at least 6 decimals, as before: KITTI's and MRCLAM's stamps (microseconds,
#: milliseconds) and whatever rounds to them are written as they were.
STAMP_MIN_DECIMALS = 6


def seconds(t: float, decimals: int | None = STAMP_DECIMALS) -> str:
    """A time in seconds to ``decimals`` places (None: the shortest form that reads back
    as the same float), trailing zeros trimmed down to :data:`STAMP_MIN_DECIMALS` places."""
    t = float(t)
    if not math.isfinite(t):
        return str(t)
    text = np.format_float_positional(t, precision=decimals, unique=True, trim="-")
    whole, _, fraction = text.partition(".")
    return f"{whole}.{fraction.ljust(STAMP_MIN_DECIMALS, '0')}"


def stamp_texts(stamps: Iterable[float], text: Callable[[float, int | None], str]) -> list[str]:
    """``text(t, STAMP_DECIMALS)`` of each stamp; where that writes two different stamps
    alike (less than a nanosecond apart), every stamp's shortest exact form: a file's
    distinct stamps are read back distinct."""
    values = [float(t) for t in stamps]
    texts = [text(t, STAMP_DECIMALS) for t in values]
    if len(set(texts)) < len(set(values)):
        texts = [text(t, None) for t in values]
    return texts


def write_tum(path: Path, stamps: np.ndarray, t_w: np.ndarray, q_xyzw: np.ndarray) -> None:
    """TUM format ``t x y z qx qy qz qw``, one pose a line: stamps to the nanosecond
    (:func:`stamp_texts`), positions to the nanometre (:func:`metres`), quaternions to 9
    significant digits.

    Args:
        stamps: (N,) seconds, or pose ids where the data has no timestamps
            (an integer array: written exactly, as ids up to 2**62 are read).
        t_w: (N, 3) positions in the world, metres.
        q_xyzw: (N, 4) unit quaternions of the body-to-world rotation.
    """
    stamps = np.asarray(stamps)
    if np.issubdtype(stamps.dtype, np.integer):
        texts = [str(t) for t in stamps.tolist()]
    else:
        texts = stamp_texts(stamps.tolist(), lambda t, d: f"{int(t)}" if t.is_integer() else seconds(t, d))
    t_w = np.asarray(t_w, dtype=np.float64).reshape(-1, 3)
    q_xyzw = np.asarray(q_xyzw, dtype=np.float64).reshape(-1, 4)
    with atomic_open(path, "w", encoding="utf-8") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        for stamp, p, q in zip(texts, t_w, q_xyzw, strict=True):
            f.write(f"{stamp} {' '.join(metres(v) for v in p)} {' '.join(f'{v:.9g}' for v in q)}\n")


def write_tum_planar(path: Path, stamps: np.ndarray, wTb: np.ndarray) -> None:
    """:func:`write_tum` of (N, 3) 2-D poses ``[x, y, theta]``: z = 0, yaw about z."""
    half = 0.5 * wTb[:, 2]
    zeros = np.zeros(len(wTb))
    write_tum(
        path,
        stamps,
        np.column_stack([wTb[:, 0], wTb[:, 1], zeros]),
        np.column_stack([zeros, zeros, np.sin(half), np.cos(half)]),
    )


def write_tum_spatial(path: Path, stamps: np.ndarray, wTc: np.ndarray) -> None:
    """:func:`write_tum` of (N, 4, 4) camera-to-world poses."""
    wTc = np.asarray(wTc, dtype=np.float64).reshape(-1, 4, 4)
    write_tum(path, stamps, wTc[:, :3, 3], rotation_to_quaternion(wTc[:, :3, :3]))


def write_landmarks_csv(path: Path, landmark_ids: np.ndarray, landmarks_w: np.ndarray) -> None:
    """``id,x,y`` (2-D) or ``id,x,y,z`` (3-D): ids as the back end gives them, metres."""
    landmarks_w = np.asarray(landmarks_w, dtype=np.float64)
    dim = landmarks_w.shape[1] if landmarks_w.ndim == 2 else 2
    with atomic_open(path, "w", encoding="utf-8") as f:
        f.write("id," + ",".join("xyz"[:dim]) + "\n")
        for lid, p in zip(landmark_ids, landmarks_w.reshape(-1, dim), strict=True):
            f.write(f"{int(lid)}," + ",".join(metres(v) for v in p) + "\n")


def write_text(path: Path, text: str) -> None:
    """``text`` as the file ``path`` (UTF-8, replaced atomically)."""
    with atomic_open(path, "w", encoding="utf-8") as f:
        f.write(text)


def _jsonable(value):
    if hasattr(value, "to_dict"):  # typed records (run metrics, scores)
        return _jsonable(value.to_dict())
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(path: Path, data: dict) -> None:
    with atomic_open(path, "w", encoding="utf-8") as f:
        json.dump(_jsonable(data), f, indent=2, sort_keys=False)
        f.write("\n")


#: Files ``graphslam run`` may write into ``--out``.
#: Several robots in one run (MRCLAM ``--robot all``) write one trajectory per robot.
AGENT_OUTPUT_NAMES = tuple(
    f"{kind}_robot{n}.tum" for n in range(1, 6) for kind in ("trajectory", "ground_truth")
) + tuple(f"trajectory_robot{n}.bag" for n in range(1, 6))  # (--write-bag)
RUN_OUTPUT_NAMES = (
    "trajectory.tum",
    "ground_truth.tum",
    "landmarks.csv",
    "metrics.json",
    "run.rrd",
    "loops.csv",
    "loops.jsonl",
    "nees.csv",
    "graph.g2o",  # a pose-graph run's graph at the estimate, in its input's format
    "graph.graph",
    "closures.csv",
    "trajectory.bag",  # --write-bag, written from trajectory.tum after the run
    "intrinsics.txt",  # --intrinsics estimate: the camera estimated from the images
) + AGENT_OUTPUT_NAMES
#: Files ``graphslam compare`` may write into ``--out``.
COMPARE_OUTPUT_NAMES = ("compare.json", "compare.png", "compare.rrd")
#: Files ``graphslam localize`` may write into ``--out``.
LOCALIZE_OUTPUT_NAMES = ("localize.csv", "trajectory.tum", "metrics.json", "ground_truth.tum", "localize.rrd")
#: Files ``graphslam eval`` may write into ``--out`` (often a run's folder).
EVAL_OUTPUT_NAMES = ("eval.json", "eval.png")
#: What a run, a comparison or a localisation clears from its ``--out``: every
#: command's outputs, as an earlier command's files beside this one's would read as
#: this one's (an eval.json of the trajectory before, a localize.csv beside a run's).
FOLDER_OUTPUT_NAMES = tuple(
    dict.fromkeys(RUN_OUTPUT_NAMES + COMPARE_OUTPUT_NAMES + LOCALIZE_OUTPUT_NAMES + EVAL_OUTPUT_NAMES)
)


def remove_stale_outputs(
    out_dir: Path, will_write: set[str] | frozenset[str], known: tuple[str, ...] = FOLDER_OUTPUT_NAMES
) -> list[Path]:
    """Delete the files of ``known`` names in ``out_dir`` that this run will not
    write, so a folder never mixes two runs' outputs; return what was removed.

    Only our own output names are touched, never other files, and only plain
    files (a folder of that name is left alone; a folder under a name this run
    writes is refused, ConfigError, before the run's work).

    Raises:
        GraphSlamError: a file that cannot be removed (another user's, in a shared
            folder), so it would stand beside this run's as if it were one of them.
    """
    check_no_folder_at(out_dir, will_write)
    removed = []
    for name in known:
        p = Path(out_dir) / name
        if name not in will_write and p.is_file():
            try:
                p.unlink()
            except OSError as e:
                raise GraphSlamError(
                    f"{p}: cannot remove this earlier output ({e.strerror}); it would stand beside "
                    "this run's as one of them: remove it, or choose another --out"
                ) from None
            removed.append(p)
    return removed


@contextmanager
def one_run_or_the_other(out_dir: Path, known: tuple[str, ...] = RUN_OUTPUT_NAMES) -> Iterator[None]:
    """Around the writing of a run's outputs: when it fails part way (a full disk, a
    second signal), delete the earlier run's files this run did not yet replace, so
    the folder holds the new run's files that were written and nothing of the old.

    An earlier run's file is one whose inode and modification time are those seen
    on entry (each writer replaces its file by a rename: a new inode)."""
    before = {name: _identity(Path(out_dir) / name) for name in known}
    try:
        yield
    except BaseException:
        for name, seen in before.items():
            p = Path(out_dir) / name
            if seen is not None and _identity(p) == seen:
                with contextlib.suppress(OSError):  # the failure in flight is the one to report
                    p.unlink(missing_ok=True)
        raise


#: errno of a write refused for want of space (a full disk, a user's quota)
_DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


class OutputWrites:
    """A command's output files written one by one: a file the file system refuses (a
    full disk, a file-size limit, a name too long, a folder in its place) is noted and
    the next is still tried, so every output that can be kept is written (fifteenth
    hostile pass: the first refused file cost every file after it, and nothing said
    which were written). :meth:`check` then raises one error for them all.

    ``writes(paths, key, path, writer, *args)`` calls ``writer(path, *args)`` and sets
    ``paths[key] = path`` once it is written; a file the file system refuses is noted
    instead (False) and an earlier command's file of its name removed, so the folder
    never holds it beside this command's outputs (as :func:`one_run_or_the_other`
    does); any other error is raised at once.
    """

    def __init__(self, out_dir: Path, make_room: Callable[[], bool] | None = None) -> None:
        self.out_dir = Path(out_dir)
        #: (path, error) of each refused file, in the order tried
        self.refused: list[tuple[Path, OSError]] = []
        #: called once, at the first write a full disk refuses: True when it freed space
        #: (a recording still being written, given up), and the write is tried again
        self.make_room = make_room

    def __call__(
        self, paths: dict[str, Path], key: str, path: Path, writer: Callable[..., object], *args, **kwargs
    ) -> bool:
        if not self.attempt(path, writer, path, *args, **kwargs):
            with contextlib.suppress(OSError):  # the refusal is the error to report
                if Path(path).is_file():
                    Path(path).unlink()
            return False
        paths[key] = Path(path)
        return True

    def attempt(self, what: Path, action: Callable[..., object], *args, **kwargs) -> bool:
        """``action(*args)``, which writes ``what`` (a file or a folder: ``--save-map``);
        False, noted, when the file system refused it."""
        try:
            action(*args, **kwargs)
        except OSError as e:
            if self._reason(e) is None:
                raise
            if e.filename is None:  # zipfile and numpy's writers name no file: say which
                e.filename = str(what)
            if e.errno in _DISK_FULL and self.make_room is not None:
                make_room, self.make_room = self.make_room, None
                if make_room():
                    return self.attempt(what, action, *args, **kwargs)
            self.refused.append((Path(what), e))
            return False
        return True

    def _reason(self, e: OSError) -> str | None:
        """The one line for a refused write (:func:`write_error_line`), or for the output
        folder gone while the files were written (moved or deleted after the command
        last found it: the files after that have nowhere to go); None for any other
        error (a bug: the traceback is wanted)."""
        line = write_error_line(e)
        if line is None and e.errno == errno.ENOENT and not self.out_dir.is_dir():
            line = f"{self.out_dir} was moved or deleted while this command wrote its outputs into it"
        return line

    def names(self) -> list[str]:
        """The refused files: a name in the output folder, a path elsewhere."""
        return [p.name if p.parent == self.out_dir else str(p) for p, _ in self.refused]

    def outputs_line(self, written: Iterable[str | Path]) -> str:
        """``outputs in DIR/: a, b (not written: c)``: what a command prints of its files."""
        names = ", ".join(Path(p).name for p in written)
        refused = f" (not written: {', '.join(self.names())})" if self.refused else ""
        return f"outputs in {self.out_dir}/: {names}{refused}"

    def check(self, written: Iterable[Path]) -> None:
        """Raise GraphSlamError when a file was refused: the first refusal's reason, the
        other refused files, and the files this command did write to its folder."""
        if not self.refused:
            return
        first = self.refused[0][1]
        gone = write_error_line(first) is None  # refused only because the folder went (_reason)
        line = self._reason(first) or str(first)
        others = self.names()[1:]
        if others:
            line += f"; not written either: {', '.join(others)}"
        kept = [Path(p).name for p in written]
        held = ", ".join(kept) if kept else "none of this command's outputs"
        where = "written before it went:" if gone else f"{self.out_dir}/ holds"
        raise GraphSlamError(f"{line}; {where} {held}")


def writes_for(out_dir: Path, writes: OutputWrites | None) -> tuple[OutputWrites, bool]:
    """``(writes, own)`` for a ``write_outputs`` that may be given its command's
    :class:`OutputWrites`: the one given, or one of its own (``own``: the caller then
    checks it once every output was tried, and raises for a refused file); makes
    ``out_dir``."""
    own = writes is None
    out_dir.mkdir(parents=True, exist_ok=True)
    return (OutputWrites(out_dir) if writes is None else writes), own


def _identity(path: Path) -> tuple[int, int, int] | None:
    """(device, inode, mtime in ns) of a plain file, None when there is none."""
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_dev, st.st_ino, st.st_mtime_ns) if stat.S_ISREG(st.st_mode) else None


def write_nees_csv(path: Path, pose_ids: np.ndarray, nees: np.ndarray) -> Path:
    """``step,pose_id,nees`` a line: the pose NEES of each step (``graphslam run --nees``)."""
    with atomic_open(path, "w", encoding="utf-8") as f:
        f.write("step,pose_id,nees\n")
        for k, (i, v) in enumerate(zip(pose_ids, nees, strict=True)):
            f.write(f"{k},{int(i)},{float(v):.9g}\n")
    return path
