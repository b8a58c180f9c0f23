"""Reader for the CMU Plaza range-only logs (Djugash, Hamner and Roth, "Navigating
with ranging radios: five data sets with ground truth", J. Field Robotics 2009),
as shipped in gtsam's wheel: a 2-D range-only SLAM
:class:`~slamcore.planar.records.Dataset`.

Files (whitespace-separated numbers, one record a line):

- ``PlazaN_DR.txt``, dead reckoning: time (s), distance travelled (m), heading
  change (rad) since the previous line;
- ``PlazaN_TD.txt``, ranges: time (s), sender (antenna) id, receiver (beacon)
  id, range (m);
- ``PlazaN_.mat`` (MATLAB, optional): ``GT`` (time, x, y, heading) of the start
  and of every DR line, ``TL`` (beacon id, x, y), and copies of DR and TD.

What the reader makes of it:

- **Frames**: frame 0 is the start (the truth's first time when the ``.mat``
  has one before the first DR line, else one DR period before it), frame ``k``
  the pose at the time of DR line ``k``, reached by the odometry
  ``[distance, 0, heading change]`` from frame ``k - 1`` (as gtsam's
  ``RangeISAMExample_plaza2.cpp`` builds its between factors).
- **Ranges** (in the order of the file, which in Plaza1 is not everywhere the
  order of time): a :attr:`~slamcore.planar.records.ObservationKind.RANGE`
  observation of beacon ``receiver`` at the frame nearest in time (the DR
  period is 0.1-0.2 s; gtsam's example takes the next frame instead); ranges
  more than one DR period outside the frames' span are dropped and counted, as are
  those inside a gap of the DR file (:data:`DR_GAP_MEDIANS`), which a warning names.
  The beacon id is the landmark id (known association).
- **Truth**: ``GT`` interpolated at each frame time (exact at the DR times);
  the beacons' ``TL`` scores the map. Plaza2's ``GT`` heading points against
  the direction of travel (the median angle between them is pi, where Plaza1's
  is 0): when the median over the moving steps is beyond pi/2, the truth's
  heading is turned by pi, and a note says so.
- **Start**: the truth at frame 0 (as gtsam's example does), else the origin.

Measured against the truth (``GT`` interpolated at the range times, ``TL``), the
ranges run long by a median 2.8 m on both logs, with a robust (1.4826 MAD) scale
of 1.2 m (Plaza1) and 1.8 m (Plaza2) and no residual beyond 7 m. Nothing here
removes that bias: it is what keeps the beacons' map error near 3 m.

Every refusal names the file and, for a bad line, the line.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from graphslam.sources.planar.mrclam import check_times, read_table, refuse_first_row, timed_frames, truth_at
from slamcore.errors import InputError
from slamcore.input_files import check_input_path
from slamcore.planar.records import Dataset, odometry_batch, range_batch

#: Noise from gtsam's ``examples/RangeISAMExample_plaza2.cpp`` (borglab/gtsam,
#: current version): odometry sigmas (0.05 m along, 0.01 m across, 0.1 rad) per DR
#: line, and sigma_r = 100 m on each range under a Tukey kernel of width 15 (we
#: use iSAM2's own ``observation_kernel``). The 2013 version of that example had
#: 0.2 rad on the heading.
ODOMETRY_SIGMAS = (0.05, 0.01, 0.1)
RANGE_SIGMA_M = 100.0
#: Prior on the first pose (variance, m^2 and rad^2): the start is known from the truth.
PRIOR_VARIANCE = 1e-6
#: A DR line further than this (m), or turning more than pi, is a corrupt line.
STEP_MAX_M = 100.0
#: Ranges accepted, metres (the radios reach about 100 m).
RANGE_MAX_M = 1e3
#: Steps shorter than this (m) say nothing about the truth's heading convention.
MOVING_STEP_M = 0.05
#: A DR interval beyond this many of the log's median intervals is a gap: the logger
#: writes a line every 0.1 s (Plaza2) or 0.2 s (Plaza1), and their longest interval is
#: 3.5 and 1.2 medians (0.35 s, 0.23 s). A log with 60 s of lines removed ran with that
#: motion lost and every range inside it put on the two frames at its edges, unsaid.
DR_GAP_MEDIANS = 10.0


def is_plaza_dr_file(path) -> bool:
    """Whether ``path`` names a Plaza dead-reckoning file (``*_DR.txt``)."""
    return Path(path).name.endswith("_DR.txt")


def plaza_path(number: int) -> Path:
    """``PlazaN_DR.txt`` of gtsam's wheel (its ``_TD.txt`` and ``_.mat`` lie beside it)."""
    import gtsam

    return Path(gtsam.findExampleDataFile(f"Plaza{number}_DR.txt"))


def plaza_files(path) -> tuple[Path, Path, Path] | None:
    """``(DR, TD, .mat)`` paths of a ``*_DR.txt`` file, or of a folder holding exactly
    one ``*_DR.txt`` with its ``*_TD.txt``; None when ``path`` is neither."""
    p = Path(path)
    if p.is_dir():
        drs = sorted(q for q in p.glob("*_DR.txt") if q.is_file())
        if len(drs) != 1 or not _sibling(drs[0], "_TD.txt").is_file():
            return None
        p = drs[0]
    elif not is_plaza_dr_file(p):
        return None
    return p, _sibling(p, "_TD.txt"), _sibling(p, "_.mat")


def plaza_folder_problem(path) -> str | None:
    """Why the folder ``path``, which holds a ``*_DR.txt``, is no Plaza log
    :func:`plaza_files` takes (two logs, or a DR file without its TD file), else None:
    such a folder was taken for an image folder ("no images")."""
    p = Path(path)
    if not p.is_dir():
        return None
    drs = sorted(q.name for q in p.glob("*_DR.txt") if q.is_file())
    if not drs or plaza_files(p) is not None:
        return None
    if len(drs) > 1:
        return f"holds {len(drs)} Plaza logs ({', '.join(drs)}): give one *_DR.txt as --dataset"
    return f"{drs[0]} has no {drs[0][: -len('_DR.txt')]}_TD.txt beside it (the Plaza log's ranges)"


#: The other files of a Plaza log, beside its ``*_DR.txt``.
PART_SUFFIXES = ("_TD.txt", "_.mat")


def dr_of_part(path) -> Path | None:
    """The ``*_DR.txt`` of the Plaza log ``path`` is another file of (its ``_TD.txt`` or
    ``_.mat``, the ``_DR.txt`` beside it), else None."""
    p = Path(path)
    for suffix in PART_SUFFIXES:
        if p.name.endswith(suffix):
            dr = p.with_name(p.name[: -len(suffix)] + "_DR.txt")
            return dr if dr.is_file() else None
    return None


def _sibling(dr_path: Path, suffix: str) -> Path:
    return dr_path.with_name(dr_path.name[: -len("_DR.txt")] + suffix)


def read_plaza(dr_path, td_path=None, mat_path=None) -> Dataset:
    """A Plaza log as a Dataset (module docstring). ``td_path`` and ``mat_path``
    default to ``*_TD.txt`` and ``*_.mat`` beside ``dr_path``; a missing ``.mat``
    means no truth.

    Raises:
        InputError: a missing or malformed file, naming file and line.
    """
    dr_path = Path(dr_path)
    td_path = Path(td_path) if td_path is not None else _sibling(dr_path, "_TD.txt")
    dr, dr_lines = _read(dr_path, 3, "time, distance, heading change")
    if len(dr) == 0:
        raise InputError("no dead-reckoning line", dr_path)
    check_times(dr, dr_lines, dr_path, strictly=True)
    _check_steps(dr, dr_lines, dr_path)
    td, td_lines = _read(td_path, 4, "time, sender, receiver, range")
    _check_ranges(td, td_lines, td_path)
    if mat_path is None and _sibling(dr_path, "_.mat").exists():
        mat_path = _sibling(dr_path, "_.mat")
    truth, beacons = _read_mat(Path(mat_path)) if mat_path is not None else (None, None)
    dataset = _dataset(dr_path, dr, dr_lines, td, truth, beacons, mat_path)
    swapped = columns_swapped(td, beacons, td_path)
    return dataset if swapped is None else replace(dataset, warnings=(*dataset.warnings, swapped))


def columns_swapped(td: np.ndarray, beacons: dict | None, td_path: Path) -> str | None:
    """A warning when the TD file's sender and receiver columns look exchanged: the
    receivers (read as the beacons) are not the truth's beacons while the senders are,
    or, without truth, one receiver is ranged by several senders (Plaza's logs: one
    antenna, id 2, ranging four beacons). Read as they stand, every range went to one
    "beacon" at the antenna's id, and the run said nothing."""
    senders = set(td[:, 1].astype(np.int64).tolist())
    receivers = set(td[:, 2].astype(np.int64).tolist())
    if beacons:
        known = set(beacons)
        if receivers <= known or not senders <= known:
            return None
    elif not (len(receivers) == 1 and len(senders) > 1):
        return None
    return (
        f"{td_path.name}: its receivers ({', '.join(map(str, sorted(receivers)))}) are read as the beacons, "
        f"but its senders ({', '.join(map(str, sorted(senders)))}) look like them"
        + (" (the truth's beacons)" if beacons else "")
        + ": are the sender and receiver columns exchanged? (the format: time, sender, receiver, range)"
    )


def _read(path: Path, columns: int, what: str) -> tuple[np.ndarray, list[int]]:
    if not path.exists():  # read_table would speak of an MRCLAM folder
        raise InputError(f"Plaza log file not found ({what})", path)
    return read_table(path, columns, what)


def _check_steps(dr, lines, path: Path) -> None:
    bad = (np.abs(dr[:, 1]) > STEP_MAX_M) | (np.abs(dr[:, 2]) > math.pi)
    refuse_first_row(
        bad,
        lines,
        path,
        lambda k: f"step of {dr[k, 1]:g} m turning {dr[k, 2]:g} rad is beyond {STEP_MAX_M:g} m or pi rad",
    )


def _check_ranges(td, lines, path: Path) -> None:
    ids = td[:, 1:3]
    bad_id = ((ids != np.round(ids)) | (ids < 0)).any(axis=1)
    refuse_first_row(
        bad_id,
        lines,
        path,
        lambda k: f"sender and receiver ids must be whole numbers >= 0, got {td[k, 1]:g} and {td[k, 2]:g}",
    )
    bad = ~((td[:, 3] > 0) & (td[:, 3] < RANGE_MAX_M))
    refuse_first_row(bad, lines, path, lambda k: f"range {td[k, 3]:g} m is not in (0, {RANGE_MAX_M:g})")


def _read_mat(path: Path) -> tuple[np.ndarray | None, dict[int, np.ndarray] | None]:
    """``GT`` (N, 4) and ``{beacon: (2,)}`` of ``TL`` from the ``.mat``, each None if absent."""
    from scipy.io import loadmat

    check_input_path(path, "Plaza truth file")
    try:
        mat = loadmat(str(path))
    except Exception as exc:  # scipy raises ValueError, TypeError, OSError... on a bad file
        raise InputError(f"not a readable MATLAB file: {exc}", path) from None
    gt = np.asarray(mat.get("GT", np.zeros((0, 4))), dtype=np.float64)
    if gt.ndim != 2 or gt.shape[1] != 4 or not np.isfinite(gt).all():
        raise InputError(f"GT must be finite rows of time, x, y, heading (got shape {gt.shape})", path)
    if len(gt) >= 2 and not (np.diff(gt[:, 0]) > 0).all():
        raise InputError("GT times must increase", path)
    tl = np.asarray(mat.get("TL", np.zeros((0, 3))), dtype=np.float64)
    if tl.ndim != 2 or tl.shape[1] != 3 or not np.isfinite(tl).all():
        raise InputError(f"TL must be finite rows of beacon id, x, y (got shape {tl.shape})", path)
    beacons: dict[int, np.ndarray] = {}
    for k, row in enumerate(tl, start=1):  # int() would read 1.6 as beacon 1, a dict keep the last of two
        if row[0] != round(row[0]):
            raise InputError(f"TL row {k}: beacon id {row[0]:g} is not a whole number", path)
        if int(row[0]) in beacons:
            raise InputError(f"TL row {k}: beacon {int(row[0])} is given a second position", path)
        beacons[int(row[0])] = row[1:3].copy()
    return (gt if len(gt) >= 2 else None), (beacons or None)


def heading_reversed(truth: np.ndarray) -> tuple[bool, float]:
    """Whether the truth's heading points against its direction of travel, and the
    median angle (rad) between them over the steps longer than :data:`MOVING_STEP_M`."""
    v = np.diff(truth[:, 1:3], axis=0)
    moving = np.hypot(v[:, 0], v[:, 1]) > MOVING_STEP_M
    if not moving.any():
        return False, 0.0
    travel = np.arctan2(v[moving, 1], v[moving, 0])
    diff = np.angle(np.exp(1j * (travel - truth[1:, 3][moving])))
    median = float(np.median(np.abs(diff)))
    return median > math.pi / 2, median


def _dataset(dr_path, dr, dr_lines, td, truth, beacons, mat_path) -> Dataset:
    notes = [f"{len(dr)} dead-reckoning steps from {dr_path.name}"]
    period = float(np.median(np.diff(dr[:, 0]))) if len(dr) > 1 else 0.1
    t0 = dr[0, 0] - period
    if truth is not None and truth[0, 0] < dr[0, 0]:
        t0 = truth[0, 0]
    times = np.concatenate([[t0], dr[:, 0]])
    wTb_true = np.full((len(times), 3), np.nan)
    if truth is not None:
        reversed_, median = heading_reversed(truth)
        if reversed_:
            truth = truth.copy()
            truth[:, 3] = truth[:, 3] + math.pi
            notes.append(
                f"truth heading turned by pi (it pointed against the travel: median angle {median:.2f} rad)"
            )
        wTb_true = truth_at(truth, times)
    has_truth = np.isfinite(wTb_true).all(axis=1)
    truth_doubt = []
    truth_lines = []  # Dataset.truth_lines: what a truth given apart replaces
    if truth is None:
        truth_lines.append("no truth (no .mat beside the log)")
        notes.append(truth_lines[-1])
    elif not has_truth.any():  # a note only, and ATE n/a with exit 0 (hostile pass 21)
        truth_lines.append(
            f"the .mat's GT covers none of the log ({truth[0, 0]:.1f}-{truth[-1, 0]:.1f} s against "
            f"{times[0]:.1f}-{times[-1]:.1f} s): nothing is scored (another log's .mat?)"
        )
        truth_doubt.append(truth_lines[-1])
    elif not has_truth.all():
        truth_lines.append(f"truth on {int(has_truth.sum())} of {len(times)} frames (scored there only)")
        notes.append(truth_lines[-1])
    prior = wTb_true[0] if has_truth[0] else np.zeros(3)
    notes.append("start pose from the truth" if has_truth[0] else "start pose at the origin")
    n = len(times)
    deltas = np.column_stack([dr[:, 1], np.zeros(len(dr)), dr[:, 2]])
    cov = np.diag(np.square(ODOMETRY_SIGMAS))
    odometry = odometry_batch(range(n - 1), range(1, n), deltas, np.broadcast_to(cov, (n - 1, 3, 3)))
    inside = (td[:, 0] >= times[0] - period) & (td[:, 0] <= times[-1] + period)
    if not inside.all():
        notes.append(f"{int((~inside).sum())} ranges outside the dead reckoning's time span dropped")
    td = td[inside]
    gap_warning, in_gap = _gaps(dr_path, dr_lines, times, period, td[:, 0])
    td = td[~in_gap]
    unordered = int((np.diff(td[:, 0]) < 0).sum())
    if unordered:  # Plaza1_TD.txt has two blocks a minute early; each goes by its own time
        notes.append(f"ranges out of time order at {unordered} places (each assigned by its time)")
    frame_of = _nearest(times, td[:, 0])
    beacon_ids = td[:, 2].astype(np.int64)
    ranges = range_batch(
        frame_of.tolist(), beacon_ids.tolist(), td[:, 3:4], np.full(len(td), RANGE_SIGMA_M**2)
    )
    ids = sorted(set(beacon_ids.tolist()))
    notes.append(f"{len(td)} ranges to {len(ids)} beacons ({', '.join(map(str, ids))})")
    unscored = [b for b in ids if beacons is not None and b not in beacons]
    if unscored:  # MRCLAM says it of its landmarks; here the map scored fewer in silence
        notes.append(
            f"beacon(s) {', '.join(map(str, unscored))} ranged but not in the .mat's TL: mapped, not scored"
        )
    by_frame: dict[int, list] = {}
    for obs in ranges:
        by_frame.setdefault(obs.pose_id, []).append(obs)
    frames = timed_frames(times, odometry, by_frame, wTb_true)
    name = dr_path.name[: -len("_DR.txt")].lower() if is_plaza_dr_file(dr_path) else dr_path.stem
    return Dataset(
        name=name,
        frames=frames,
        prior_wTb=prior,
        prior_covariance=np.eye(3) * PRIOR_VARIANCE,
        landmarks_true=beacons,
        has_timestamps=True,
        source_path=str(dr_path),
        notes=tuple(notes),
        warnings=(*truth_doubt, *gap_warning),
        truth_lines=tuple(truth_lines),
    )


def _gaps(
    dr_path: Path, dr_lines: list[int], times: np.ndarray, period: float, range_times: np.ndarray
) -> tuple[list[str], np.ndarray]:
    """A warning naming the DR file's gaps (:data:`DR_GAP_MEDIANS`), and which ranges
    fall inside one (more than a DR period from both its edges): they are dropped, for
    the nearest frame lies seconds from them, where the motion is not in the log."""
    step = np.diff(times)
    gaps = np.flatnonzero(step > DR_GAP_MEDIANS * period)
    in_gap = np.zeros(len(range_times), dtype=bool)
    for k in gaps:
        in_gap |= (range_times > times[k] + period) & (range_times < times[k + 1] - period)
    if not len(gaps):
        return [], in_gap
    worst = int(gaps[np.argmax(step[gaps])])
    more = f" (and {len(gaps) - 1} more gaps)" if len(gaps) > 1 else ""
    # times[k + 1] is the DR file's row k (times[0] is the start, before its first row)
    return [
        f"{dr_path.name} has no line for {step[worst]:.1f} s before its line {dr_lines[worst]} "
        f"(lines come every {period:.2g} s){more}: the motion there is not in the log, and "
        f"{int(in_gap.sum())} ranges timed inside {'them' if len(gaps) > 1 else 'it'} are dropped"
    ], in_gap


def _nearest(times: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index of the element of increasing ``times`` nearest to each of ``t``."""
    k = np.clip(np.searchsorted(times, t), 1, len(times) - 1)
    earlier = (t - times[k - 1]) <= (times[k] - t)
    return np.where(earlier, k - 1, k)
