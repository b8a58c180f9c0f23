"""Reader for the UTIAS MRCLAM data sets (Leung et al., IJRR 2011): one robot's log
as a 2-D landmark-SLAM :class:`~slamcore.planar.records.Dataset`.

A data set is a folder of text files (four ``#`` header lines each; tabs and
spaces): ``Barcodes.dat`` (subject, barcode), ``Landmark_Groundtruth.dat``
(subject, x, y, std x, std y), and per robot N ``RobotN_Odometry.dat`` (time,
commanded forward and angular velocity), ``RobotN_Measurement.dat`` (time,
*barcode*, range, bearing) and ``RobotN_Groundtruth.dat`` (Vicon: time, x, y,
heading). Subjects 1-5 are the robots, the others the landmarks.

What the reader makes of it:

- **Frames** at every distinct measurement time, and between them at least every
  ``frame_every_s`` so that the trajectory is sampled while no landmark is in
  view; the first frame at the first odometry time, the last at the log's end,
  but no later than the odometry's (sightings after it are dropped and counted:
  no motion is known there).
- **Odometry** integrated exactly between frames
  (:mod:`graphslam.sources.planar.mrclam_motion`) with the calibrated motion
  model and its propagated covariance; a gap in it beyond what the loggers leave
  (:data:`ODOMETRY_GAP_MEDIANS`) is warned of (the command before it is held). A log
  of one time is refused (nothing to integrate); lines repeating a time with another
  command are counted (the later is held).
- **Sightings**: barcodes mapped to subjects through ``Barcodes.dat``; a landmark
  subject is the landmark id (known association; back ends configured for
  unknown association ignore it and are scored against it). Sightings of
  the other robots are counted and left out (a single-robot run has no use for
  them), as are barcodes ``Barcodes.dat`` does not list and the robot's own barcode;
  a line written twice is dropped (counted). Subjects and barcodes are whole numbers
  below :data:`~graphslam.sources.planar.mrclam_checks.ID_LIMIT`. Most sightings
  outside the odometry's span (clocks that disagree) are a warning
  (:mod:`graphslam.sources.planar.mrclam_checks`).
- **Truth**: a Vicon line written twice is dropped (counted), two poses at one
  time refused; the Vicon pose interpolated at each frame inside the truth's span
  (and not across a gap in it longer than :data:`TRUTH_MAX_GAP_S`); the
  scoring covers those frames only. The landmarks' truth scores the map.
- **Start**: the truth at the first frame, where there is one (as the data
  set's authors and the SLAM courses that use it do), else the origin.

Every refusal names the file and line.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import ClassVar

import numpy as np

from filters.association import t2_quantile
from graphslam.sources.planar.mrclam_checks import (
    ID_LIMIT,
    check_one_time,
    drop_conflicting_sightings,
    drop_repeated_sightings,
    is_id,
    odometry_repeats_note,
    odometry_truth_doubt,
    outside_span,
    own_barcode_note,
)
from graphslam.sources.planar.mrclam_motion import COVARIANCE_FLOOR, MotionModel, held_commands, integrate
from graphslam.sources.planar.synthetic import MAX_STEPS
from graphslam.sources.tokens import NUMBER_TOKEN
from slamcore.config import Gate, Validated, bounded
from slamcore.errors import ConfigError, InputError, quote
from slamcore.files import folder_name
from slamcore.input_files import check_input_path, check_plain_text
from slamcore.planar import geometry as se2
from slamcore.planar.records import (
    MIN_ERROR_DOF,
    Dataset,
    Frame,
    SensorField,
    odometry_batch,
    range_bearing_batch,
)
from slamcore.planar.sighting_correlation import SightingCorrelation

#: Subjects 1-5 are robots in every MRCLAM data set; the rest are landmarks.
ROBOT_SUBJECTS = range(1, 6)
#: Truth is not interpolated across a gap in the Vicon log longer than this, s:
#: the robots turn at up to 1 rad/s, so half a second is already 0.5 rad of
#: unobserved motion; frames inside such a gap are not scored.
TRUTH_MAX_GAP_S = 0.5
#: Prior on the first pose (variance, m^2 and rad^2): the start is known.
PRIOR_VARIANCE = 1e-6
#: The note of a data set without ``Landmark_Groundtruth.dat`` (the file is optional).
NO_LANDMARK_TRUTH = "no Landmark_Groundtruth.dat: the map is not scored"


def landmark_truth_note(folder: Path) -> str:
    """Why a data set has no landmark truth: the file is absent, or it lists no landmark
    (a file cut to its header was said to be absent, hostile pass 17)."""
    path = Path(folder) / "Landmark_Groundtruth.dat"
    if path.is_file():
        return f"{path.name} lists no landmark: the map is not scored"
    return NO_LANDMARK_TRUTH


@dataclass(frozen=True)
class MrclamConfig(Validated):
    """``[mrclam]``: which robot, and its sensors' calibration.

    The defaults are fitted on MRCLAM Dataset 6 (all five robots) against its
    Vicon truth by ``python benchmarks/calibrate_mrclam.py``, which writes the
    fitted values and the consistency check to ``benchmarks/figures/calibrate_mrclam.json``:

    - ``odometry_lag_s``, ``forward_scale``, ``angular_scale``: least squares of
      the 1 s relative motions against the truth's (per robot the scales are
      0.91-0.96 forward and 0.91-0.94 angular: one value for all five);
    - the six noise coefficients (:mod:`~graphslam.sources.planar.mrclam_motion`):
      Student-t maximum likelihood of the relative motions over 5 s windows (the
      errors are correlated in time; the script's docstring says why 5 s);
    - the camera's field (percentiles of the sightings) and its detection
      probability there, matched to the runs of frames in which a landmark in the
      field by the truth is not reported;
    - the sightings' error correlation in time (``correlation_time_s`` and the two
      shares): least squares of ``share exp(-dt / tau)`` on the correlation of the
      normalised errors of two sightings of one landmark by one robot, by the time
      between them (range 0.97 within 0.3 s, 0.54 at 3-4 s, 0.21 at 8-12 s;
      bearing 0.52, 0.32, 0.14), pair counts as weights;
    - the sightings' noise (:func:`sighting_covariances`): its shape in range
      by Student-t maximum likelihood, its scale the robust (1.4826 MAD) scale
      of the residuals against the truth, normalised by that shape. A camera
      reads range from a barcode's apparent size, so the range error grows with
      the range (robust sigma 0.06 m at 1.5 m, 0.21 m at 4.5 m: about 4 % of it);
      the bearing has a constant part and one that falls with range (a
      centimetre-scale offset between the barcode's centre and its surveyed
      point). Both are functions of the measured range, which is what a run
      knows. A constant range sigma fitted to all of them (0.131 m) put 5.4 %
      of ranges beyond 3 sigma; this model puts 3.1 % there (the ranges are
      quantised and skewed), and 5.1 % of bearings (6.2 % with a constant).

    Attributes:
        robot: which robot's log is read (``RobotN_*.dat``, N in 1-5); ``--robot N``
            overrides it. Unused with ``all_robots``.
        all_robots: every robot of the folder in one graph
            (:mod:`graphslam.sources.planar.mrclam_joint`), all starts
            from the truth; ``--robot all`` sets it.
        frame_every_s: longest time between consecutive frames, s. Frames are put
            at every distinct landmark-sighting time; where two are further apart,
            evenly spaced frames are added between them so the trajectory is
            sampled while no landmark is in view.
        odometry_lag_s: each commanded velocity takes effect this long after its
            time stamp, s (the robot stands still before the first one does).
        forward_scale: the robot drives at this times the commanded forward
            velocity.
        angular_scale: the robot turns at this times the commanded angular
            velocity.
        a_s_m: along-track odometry variance per metre driven, m^2/m = m
            (``var_along = a_s |ds| + b_s dt`` per held command interval, in its
            mid-heading frame, propagated to first order between frames).
        b_s_m2_per_s: along-track variance per second, m^2/s, whether moving or
            not (the drift of a robot told to stand still).
        a_y_m: lateral (across-track) variance per metre driven, m^2/m = m.
        a_theta_rad: heading variance per radian turned, rad^2/rad = rad
            (``var_heading = a_theta |dtheta| + c_theta |ds| + b_theta dt``).
        c_theta_rad2_per_m: heading variance per metre driven, rad^2/m.
        b_theta_rad2_per_s: heading variance per second, rad^2/s.
        sigma_range_m: constant part of a sighting's range standard deviation,
            m: ``sigma_r(r)^2 = sigma_range_m^2 + (sigma_range_per_m r)^2``
            (with ``all_robots`` also for robot-to-robot sightings).
        sigma_range_per_m: part of the range standard deviation proportional to
            the measured range, m per m (a fraction of it).
        sigma_bearing_rad: constant part of a sighting's bearing standard
            deviation, rad: ``sigma_b(r)^2 = sigma_bearing_rad^2 +
            (sigma_bearing_m / r)^2``.
        sigma_bearing_m: part of the bearing error that is a fixed lateral
            offset, m (its angle falls as ``1 / r``).
        correlation_time_s: the sightings' errors are correlated in time: two
            sightings of one landmark ``dt`` apart by one robot correlate as
            ``share exp(-dt / correlation_time_s)``, and the back ends weigh each
            sighting by what it adds to the earlier ones
            (:mod:`slamcore.planar.sighting_correlation`). 0: independent.
        range_correlated_share: the correlated share of the range error's variance.
        bearing_correlated_share: the correlated share of the bearing error's variance.
        field_range_m, field_half_fov_deg: the camera's field, the 99th
            percentile of the sightings' ranges (m) and absolute bearings (deg).
        detection_prob: per-frame probability that a landmark inside that field is
            reported, as a model of independent frames sees it: a landmark in the
            field is reported in 30-36 % of the frames that report some landmark,
            but its misses come in runs, so the value stored is the one whose
            independent model matches the measured runs where the EKF's pruning
            acts (``benchmarks/calibrate_mrclam.py``, step 5). With the field,
            what the back ends that use missed sightings read
            (:class:`~slamcore.planar.records.SensorField`: the EKF's pruning of
            landmarks it should have seen).
        sighting_error_dof: the sightings' errors are heavier-tailed than a
            Gaussian: their squared Mahalanobis distance under the model above has
            its 0.999 quantile at 70.7 (a Gaussian's: 13.8), as a Student-t with
            these degrees of freedom has (``benchmarks/calibrate_mrclam.py``, step 6;
            at 0.99 measured 24.6, this t 25.9, the Gaussian 9.2). In the sensor's
            field record: what tells a landmark from another one in data association.
    """

    SECTION: ClassVar[str] = "mrclam"
    #: The settings of the sensor field's parts (:meth:`sensor_field`), by the name a back
    #: end's :meth:`~slamcore.planar.backend.Backend.sensor_field_use` gives the part,
    #: and those of the sightings' correlation in time: a back end that reads neither
    #: part (nor the correlation) leaves them doing nothing, which the CLI says.
    SENSOR_FIELD_PARTS: ClassVar[dict[str, tuple[str, ...]]] = {
        "error_dof": ("sighting_error_dof",),
        "field": ("field_range_m", "field_half_fov_deg", "detection_prob"),
    }
    CORRELATION_KEYS: ClassVar[tuple[str, ...]] = (
        "correlation_time_s",
        "range_correlated_share",
        "bearing_correlated_share",
    )
    #: settings read only in some modes of the others (hostile pass 22: each ran silent)
    GATES: ClassVar[tuple[Gate, ...]] = (
        Gate(("robot",), "all_robots = false (every robot runs under it)", lambda c: not c.all_robots),
        Gate(
            ("range_correlated_share", "bearing_correlated_share"),
            "correlation_time_s > 0 (0: the sightings' errors independent)",
            lambda c: c.correlation_time_s > 0.0,
        ),
    )
    #: ``robot``: which robot's log; ``all_robots``: every robot in one graph
    #: (:mod:`graphslam.sources.planar.mrclam_joint`), ``robot`` then unused.
    robot: int = bounded(1, min=1, max=5)
    all_robots: bool = False
    frame_every_s: float = bounded(1.0, gt=0.0, max=3600.0)
    odometry_lag_s: float = bounded(0.25, min=0.0, max=10.0)
    forward_scale: float = bounded(0.933, gt=0.0, max=10.0)
    angular_scale: float = bounded(0.929, gt=0.0, max=10.0)
    a_s_m: float = bounded(3.51e-3, min=0.0, max=1.0)
    b_s_m2_per_s: float = bounded(1.84e-5, min=0.0, max=1.0)
    a_y_m: float = bounded(5.18e-5, min=0.0, max=1.0)
    a_theta_rad: float = bounded(7.94e-3, min=0.0, max=10.0)
    c_theta_rad2_per_m: float = bounded(2.86e-4, min=0.0, max=10.0)
    b_theta_rad2_per_s: float = bounded(2.6e-8, min=0.0, max=10.0)
    sigma_range_m: float = bounded(0.0371, min=0.0, max=100.0)
    sigma_range_per_m: float = bounded(0.0372, min=0.0, max=10.0)
    sigma_bearing_rad: float = bounded(0.0067, min=0.0, max=math.pi)
    sigma_bearing_m: float = bounded(0.0156, min=0.0, max=100.0)
    correlation_time_s: float = bounded(7.32, min=0.0, max=3600.0)
    range_correlated_share: float = bounded(0.91, min=0.0, max=1.0)
    bearing_correlated_share: float = bounded(0.53, min=0.0, max=1.0)
    field_range_m: float = bounded(7.05, gt=0.0, max=1000.0)
    field_half_fov_deg: float = bounded(32.4, gt=0.0, max=180.0)
    detection_prob: float = bounded(0.0689, gt=0.0, max=1.0)
    sighting_error_dof: float = bounded(5.1, min=MIN_ERROR_DOF)

    def __post_init__(self):
        super().__post_init__()
        if self.sigma_range_m == 0.0 and self.sigma_range_per_m == 0.0:
            raise ConfigError(
                "mrclam.sigma_range_m and mrclam.sigma_range_per_m are both 0 "
                "(a range measured without error)"
            )
        if self.sigma_bearing_rad == 0.0 and self.sigma_bearing_m == 0.0:
            raise ConfigError(
                "mrclam.sigma_bearing_rad and mrclam.sigma_bearing_m are both 0 "
                "(a bearing measured without error)"
            )

    def sighting_correlation(self, robot: int) -> SightingCorrelation | None:
        """The time correlation of ``robot``'s camera errors, None when
        ``correlation_time_s`` is 0 (sightings independent)."""
        if self.correlation_time_s == 0.0:
            return None
        return SightingCorrelation(
            self.correlation_time_s, self.range_correlated_share, self.bearing_correlated_share, sensor=robot
        )

    def sensor_field(self) -> SensorField:
        """The camera's field, detection probability and error tail (``field_*``,
        ``detection_prob``, ``sighting_error_dof``)."""
        return SensorField(
            self.field_range_m,
            math.radians(self.field_half_fov_deg),
            self.detection_prob,
            self.sighting_error_dof,
        )

    def motion_model(self) -> MotionModel:
        return MotionModel(
            self.odometry_lag_s,
            self.forward_scale,
            self.angular_scale,
            self.a_s_m,
            self.b_s_m2_per_s,
            self.a_y_m,
            self.a_theta_rad,
            self.c_theta_rad2_per_m,
            self.b_theta_rad2_per_s,
        )


def is_mrclam_folder(path) -> bool:
    """Whether ``path`` is a folder holding an MRCLAM data set."""
    p = Path(path)
    # either file says MRCLAM: a folder missing the other is read as one, and refused
    # naming what it lacks (not as an image folder "without images")
    return p.is_dir() and ((p / "Barcodes.dat").is_file() or any(p.glob("Robot*_Odometry.dat")))


#: A file of an MRCLAM folder: ``RobotN_<part>.dat`` (N the robot) or a shared one.
_PART_FILE = re.compile(
    r"Robot([0-9]+)_(?:Odometry|Measurement|Groundtruth)\.dat|Barcodes\.dat|Landmark_Groundtruth\.dat"
)


def mrclam_part_of(path) -> tuple[Path, int | None] | None:
    """``(folder, robot or None)`` when ``path`` is one file of an MRCLAM folder (read as a
    file of its own it was a pose graph's "unknown tag" at its first line), else None."""
    p = Path(path)
    m = _PART_FILE.fullmatch(p.name)
    if m is None or not p.is_file() or not is_mrclam_folder(p.parent):
        return None
    return p.parent, (int(m.group(1)) if m.group(1) else None)


def read_table(path: Path, columns: int, what: str) -> tuple[np.ndarray, list[int]]:
    """``(N, columns)`` float64 of a ``.dat`` file and the file line of each row, or
    InputError naming file and line.

    Every token must be a decimal number as the pose-graph readers take them (no
    ``1_000``, no full-width digits) and finite.
    """
    if not path.exists():
        raise InputError(f"the MRCLAM folder has no {path.name} ({what})", path)
    check_input_path(path, path.name)  # a FIFO or a device is refused, not read forever
    check_plain_text(path)
    try:
        fh = open(path, encoding="utf-8-sig")
    except OSError as exc:
        raise InputError(f"cannot open file: {exc.strerror or exc}", path) from None
    lines, toks = [], []
    with fh:
        try:
            for line_no, line in enumerate(fh, start=1):
                tok = line.split()
                if not tok or tok[0].startswith("#"):
                    continue
                if len(tok) != columns:
                    raise InputError(f"needs {columns} numbers ({what}), got {len(tok)}", path, line_no)
                for t in tok:
                    if not NUMBER_TOKEN.fullmatch(t):
                        raise InputError(f"{quote(t)} is not a number", path, line_no)
                lines.append(line_no)
                toks.append(tok)
        except UnicodeDecodeError as exc:
            raise InputError(f"not a text file: {exc}", path) from None
    table = np.array(toks, dtype=np.float64).reshape(-1, columns)
    # 1e999: a decimal number that is not a finite double
    finite = np.isfinite(table).all(axis=1)
    refuse_first_row(~finite, lines, path, lambda k: "a value is not finite")
    return table, lines


def refuse_first_row(bad, lines: list[int], path: Path, message: Callable[[int], str]) -> None:
    """InputError at the file line of the first row ``k`` that ``bad`` (N,) marks,
    saying ``message(k)`` (the log readers' row checks: MRCLAM's, Plaza's)."""
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(message(k), path, lines[k])


def check_times(table, lines, path: Path, strictly: bool = False) -> None:
    """Times (column 0) non-decreasing (increasing with ``strictly``); InputError at the
    first that is not."""
    t = table[:, 0]
    step = np.diff(t)
    bad = (step <= 0) if strictly else (step < 0)
    if bad.any():
        k = int(np.argmax(bad)) + 1
        if t[k] == t[k - 1]:  # "comes after" itself read as a contradiction
            raise InputError(
                f"time {t[k]:.3f} s repeats line {lines[k - 1]}'s: the log's times must increase",
                path,
                lines[k],
            )
        raise InputError(
            f"time {t[k]:.3f} s comes after {t[k - 1]:.3f} s: the log must be in time order", path, lines[k]
        )


def check_repeats(table, lines, path: Path) -> None:
    """InputError at the first row of ``table`` (time-ordered) that repeats the time
    of the row before with other values: which of the two is the log's? A row that
    repeats the one before whole is a logger's duplicate (:func:`drop_repeats`)."""
    same_time = np.diff(table[:, 0]) == 0
    differs = same_time & np.any(table[1:] != table[:-1], axis=1)
    if differs.any():
        k = int(np.argmax(differs)) + 1
        raise InputError(
            f"time {table[k, 0]:.3f} s repeats line {lines[k - 1]}'s with other values: which is the log's?",
            path,
            lines[k],
        )


def drop_repeats(table: np.ndarray) -> tuple[np.ndarray, int]:
    """``table`` without the rows that repeat the row before whole, and how many."""
    repeat = np.concatenate([[False], np.all(table[1:] == table[:-1], axis=1)])
    return table[~repeat], int(repeat.sum())


def read_subjects(folder: Path) -> tuple[dict[int, int], dict[int, np.ndarray]]:
    """``{barcode: subject}`` and ``{landmark subject: (2,) true position}``."""
    path = folder / "Barcodes.dat"
    table, lines = read_table(path, 2, "subject, barcode")
    barcodes: dict[int, int] = {}
    worn: dict[int, int] = {}  # subject -> its barcode
    for row, (subject, code) in enumerate(table):
        if not (is_id(subject, 1) and is_id(code, 0)):  # a subject of 1e20 overflowed later
            raise InputError(
                f"subject and barcode must be whole numbers >= 1 and >= 0, below {ID_LIMIT} "
                f"(got {subject:.15g} and {code:.15g})",
                path,
                lines[row],
            )
        if int(code) in barcodes:
            raise InputError(f"barcode {int(code)} is given to two subjects", path, lines[row])
        # one subject under two barcodes merged two landmarks into one, quietly (ATE 0.08 ->
        # 0.65 m on robot 1): every subject wears one barcode
        if int(subject) in worn:
            raise InputError(
                f"subject {int(subject)} is given two barcodes ({worn[int(subject)]} and {int(code)})",
                path,
                lines[row],
            )
        barcodes[int(code)] = int(subject)
        worn[int(subject)] = int(code)
    path = folder / "Landmark_Groundtruth.dat"
    truth: dict[int, np.ndarray] = {}
    if path.exists():
        table, lines = read_table(path, 5, "subject, x, y, std x, std y")
        first_line: dict[int, int] = {}
        for row, values in enumerate(table):
            subject = values[0]
            if not is_id(subject, 1):
                raise InputError(
                    f"a landmark's subject must be a whole number >= 1, below {ID_LIMIT} "
                    f"(got {subject:.15g})",
                    path,
                    lines[row],
                )
            if int(subject) in ROBOT_SUBJECTS:  # scored as a 16th landmark no run could map
                raise InputError(
                    f"subject {int(subject)} is a robot (subjects 1-5 are, in every MRCLAM set), "
                    "not a landmark",
                    path,
                    lines[row],
                )
            first = first_line.get(int(subject))
            if first is not None:  # which is the truth? A map scored against either would be wrong
                raise InputError(
                    f"landmark {int(subject)} is given a second position (first on line {first})",
                    path,
                    lines[row],
                )
            first_line[int(subject)] = lines[row]
            truth[int(subject)] = values[1:3].copy()
    return barcodes, truth


def read_mrclam(folder, config: MrclamConfig | None = None) -> Dataset:
    """Robot ``config.robot`` of an MRCLAM data set as a Dataset (module docstring);
    every robot in one graph is :func:`graphslam.sources.planar.mrclam_joint.read_mrclam_all`.

    Raises:
        InputError: a missing or malformed file, naming file and line.
    """
    folder = Path(folder)
    config = config or MrclamConfig()
    barcodes, landmarks_true = read_subjects(folder)
    odo, meas, truth = read_robot(folder, config.robot)
    track = robot_track(config, config.robot, odo, meas, truth, barcodes)
    track.notes.insert(0, f"robot {config.robot}")
    if not landmarks_true:
        track.notes.append(landmark_truth_note(folder))
    if track.robot_sightings:
        track.notes.append(
            f"{len(track.robot_sightings)} sightings of other robots in the whole log left out "
            "(single-robot run)"
        )
    doubts = truth_doubts(config, config.robot, track, landmarks_true)
    dataset = _dataset(folder, config, track, landmarks_true)
    unscored = unscored_landmarks(dataset.frames, landmarks_true)
    return replace(dataset, notes=(*dataset.notes, *unscored), warnings=(*track.warnings, *doubts))


def unscored_landmarks(frames, landmarks_true: dict) -> list[str]:
    """A note naming the landmarks sighted that ``Landmark_Groundtruth.dat`` has no row
    for (none without that file: its own note says the map is not scored). A truth
    missing one landmark scored "14 of 14 recovered" with that one mapped and unsaid."""
    if not landmarks_true:
        return []
    sighted = {o.landmark_id for f in frames for o in f.observations if o.landmark_id is not None}
    missing = sorted(int(i) for i in sighted - set(landmarks_true))
    if not missing:
        return []
    return [
        f"landmark{'s' if len(missing) > 1 else ''} {', '.join(map(str, missing))} sighted but not in "
        "Landmark_Groundtruth.dat: mapped, not scored"
    ]


#: A sighting misses its landmark, seen from the truth's pose, when the sighting model
#: (its Student-t tail, ``sighting_error_dof``) gives an error that large a chance
#: below this (squared Mahalanobis distance 71 at the calibrated 5.1 dof); the truth
#: and the sightings are doubted when more than :data:`SIGHTING_MISS_SHARE` of them
#: miss. Measured on Dataset 6: each robot's own truth leaves 0-0.26 % beyond it (at
#: most 20 % of any 20 consecutive sightings), another robot's truth 96-100 %; beyond
#: half, the median sighting is no measurement from where the truth puts the robot.
#: Not 3 sigma: robot 1's genuine log holds its bearings 2-4 deg (5-6 sigma) off the
#: truth's for tens of seconds (a heading offset between the Vicon and the camera),
#: and its 30-150 s cut had 93 % of its sightings beyond 3 sigma.
SIGHTING_MISS_PROBABILITY, SIGHTING_MISS_SHARE = 1e-3, 0.5
#: Range units a misread log may hold, as the factor its ranges are of metres:
#: named when the ranges fit the truth once divided by a factor within
#: :data:`RANGE_UNIT_TOLERANCE` of one (the camera's own range scale is off by a few %).
RANGE_UNITS, RANGE_UNIT_TOLERANCE = {"centimetres": 100.0, "millimetres": 1000.0, "decimetres": 10.0}, 0.1


def _miss_share(config: MrclamConfig, pose: np.ndarray, z: np.ndarray, landmarks: np.ndarray) -> float:
    """Share of sightings ``z`` (N, 2) from ``pose`` (N, 3) of ``landmarks`` (N, 2) beyond
    the sighting model's :data:`SIGHTING_MISS_PROBABILITY` quantile."""
    nu = se2.innovation(z, se2.observe(pose, landmarks))
    var = np.diagonal(sighting_covariances(config, z), axis1=1, axis2=2)
    d2 = np.sum(nu**2 / var, axis=1)
    return float(np.mean(d2 > t2_quantile(1.0 - SIGHTING_MISS_PROBABILITY, config.sighting_error_dof)))


def _range_scale_fit(config, pose, z, landmarks) -> float | None:
    """The factor the ranges are of the truth's distances when dividing by it makes the
    sightings fit the truth, else None."""
    scale = float(np.median(z[:, 0] / np.maximum(np.linalg.norm(landmarks - pose[:, :2], axis=1), 1e-9)))
    rescaled = np.column_stack([z[:, 0] / scale, z[:, 1]])
    return scale if _miss_share(config, pose, rescaled, landmarks) <= SIGHTING_MISS_SHARE else None


def _relabelling_fit(config, pose, z, subjects: np.ndarray, landmarks_true: dict) -> dict[int, int] | None:
    """``{subject: landmark}`` for the subjects whose sightings (placed from the truth's
    pose, median per subject) sit at another landmark's truth, when that relabelling
    makes the sightings fit the truth; else None."""
    ids = np.array(sorted(landmarks_true))
    truth_xy = np.array([landmarks_true[s][:2] for s in ids], dtype=np.float64)
    heading = pose[:, 2] + z[:, 1]
    seen_w = pose[:, :2] + z[:, :1] * np.column_stack([np.cos(heading), np.sin(heading)])
    nearest = {}
    for s in np.unique(subjects).tolist():
        centre = np.median(seen_w[subjects == s], axis=0)
        nearest[s] = int(ids[np.argmin(np.linalg.norm(truth_xy - centre, axis=1))])
    moved = {s: m for s, m in nearest.items() if m != s}
    if not moved:
        return None
    relabelled = np.array([landmarks_true[nearest[s]][:2] for s in subjects.tolist()], dtype=np.float64)
    return moved if _miss_share(config, pose, z, relabelled) <= SIGHTING_MISS_SHARE else None


def truth_sightings_doubt(config: MrclamConfig, robot: int, track, landmarks_true: dict) -> str | None:
    """A doubt when most sightings of known landmarks at frames with truth miss the
    landmark, as seen from the true pose (:data:`SIGHTING_MISS_PROBABILITY`), naming the
    cause it can tell: ranges in another unit (they fit once scaled), the landmarks'
    labels exchanged (they fit once relabelled: the ATE stands), else the truth and the
    sightings not of one robot. ``robot``: the number the files carry. None otherwise
    (or too few to tell)."""
    rows = [
        (k, s, z)
        for k, s, z in track.landmark_sightings
        if s in landmarks_true and np.isfinite(track.wTb_true[k]).all()
    ]
    if len(rows) < 10:
        return None
    pose = track.wTb_true[[k for k, _, _ in rows]]
    z = np.array([z for _, _, z in rows], dtype=np.float64)
    subjects = np.array([s for _, s, _ in rows], dtype=np.int64)
    landmarks = np.array([landmarks_true[s][:2] for s in subjects.tolist()], dtype=np.float64)
    miss = _miss_share(config, pose, z, landmarks)
    if miss <= SIGHTING_MISS_SHARE:
        return None
    said = (
        f"{100 * miss:.0f} % of robot {robot}'s {len(rows)} sightings with truth miss their landmark, "
        f"seen from the truth's pose, by errors the sighting model gives odds below 1 in "
        f"{1 / SIGHTING_MISS_PROBABILITY:.0f}"
    )
    scale = _range_scale_fit(config, pose, z, landmarks)
    if scale is not None:
        unit = next(
            (
                f" ({name}?)"
                for name, f in RANGE_UNITS.items()
                if abs(scale / f - 1.0) <= RANGE_UNIT_TOLERANCE
            ),
            "",
        )
        return (
            f"{said}; divided by {scale:.3g}, their ranges fit: Robot{robot}_Measurement.dat's ranges "
            f"are in another unit{unit}, and the run took them for metres"
        )
    moved = _relabelling_fit(config, pose, z, subjects, landmarks_true)
    if moved is not None:
        pairs = ", ".join(f"{s} at {m}'s" for s, m in sorted(moved.items())[:5])
        more = f" and {len(moved) - 5} more" if len(moved) > 5 else ""
        return (
            f"{said}, and fit another landmark's truth ({pairs}{more}): the landmarks' labels are exchanged "
            "(Barcodes.dat or Landmark_Groundtruth.dat of another data set?); the trajectory and its ATE "
            "stand, the map's scores by label do not"
        )
    if track.odometry_fits_truth:  # the robot's own files agree: the landmarks' truth does not
        return (
            f"{said} (no range unit and no exchange of landmark labels makes them fit), while "
            f"Robot{robot}_Odometry.dat follows Robot{robot}_Groundtruth.dat: Landmark_Groundtruth.dat "
            "is not of this data set's landmarks (another data set's?); the ATE stands, the map's "
            "scores do not"
        )
    if track.odometry_unfollowed:  # two of the robot's three files agree: the truth does not
        return (
            f"{said} (no range unit and no exchange of landmark labels makes them fit), and "
            f"Robot{robot}_Odometry.dat's {' and '.join(track.odometry_unfollowed)} do not follow it "
            f"either: Robot{robot}_Groundtruth.dat and Robot{robot}_Measurement.dat are not of one "
            "robot, the truth is another robot's or data set's file; the ATE and map scores are "
            "meaningless"
        )
    return (
        f"{said} (no range unit and no exchange of landmark labels makes them fit): "
        f"Robot{robot}_Groundtruth.dat and Robot{robot}_Measurement.dat are not of one robot "
        "(another robot's or data set's file?); the ATE and map scores are meaningless"
    )


def truth_doubts(
    config: MrclamConfig, robot: int, track: RobotTrack, landmarks_true: dict[int, np.ndarray]
) -> list[str]:
    """Robot ``robot``'s doubts from its truth: on its odometry
    (:func:`~graphslam.sources.planar.mrclam_checks.odometry_truth_doubt`) and on its
    sightings (:func:`truth_sightings_doubt`), one line where both say the truth is not
    the robot's."""
    doubt = truth_sightings_doubt(config, robot, track, landmarks_true)
    if doubt is None:
        return list(track.odometry_doubts)
    if track.odometry_unfollowed and "do not follow it either" in doubt:
        # said in the sightings' line; a flipped sign or a unit on the other motion stays
        rest = [d for d in track.odometry_doubts if "do not follow its truth's" not in d]
        return [*rest, doubt]
    return [*track.odometry_doubts, doubt]


def robots_in(folder: Path) -> list[int]:
    """Robot numbers N in 1-5 (:data:`ROBOT_SUBJECTS`) with a ``RobotN_Odometry.dat`` in
    ``folder``, in order: a ``Robot6`` file is no MRCLAM robot (subject 6 is a landmark,
    whose barcode a robot 6 would drop as its own), and ``--robot 6`` is refused."""
    out = []
    for p in folder.glob("Robot*_Odometry.dat"):
        digits = p.name[len("Robot") : -len("_Odometry.dat")]
        if digits.isascii() and digits.isdigit() and int(digits) in ROBOT_SUBJECTS:
            out.append(int(digits))
    return sorted(out)


def read_robot(folder: Path, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Robot ``n``'s odometry (K, 3), sightings (M, 4) and truth (T, 4) or None, checked."""
    odo_path = folder / f"Robot{n}_Odometry.dat"
    if not odo_path.exists():
        robots = ", ".join(f"Robot{r}" for r in robots_in(folder))
        raise InputError(f"--robot {n}: no {odo_path.name} here (robots: {robots})", folder)
    odo, lines = read_table(odo_path, 3, "time, forward velocity, angular velocity")
    if len(odo) == 0:
        raise InputError("no odometry line", odo_path)
    check_times(odo, lines, odo_path)
    check_one_time(odo, lines, odo_path)
    _check_time_unit(odo, odo_path)
    _check_speeds(odo, lines, odo_path)
    meas_path = folder / f"Robot{n}_Measurement.dat"
    meas, lines = read_table(meas_path, 4, "time, barcode, range, bearing")
    check_times(meas, lines, meas_path)
    _check_sightings(meas, lines, meas_path)
    gt_path = folder / f"Robot{n}_Groundtruth.dat"
    truth = None
    if gt_path.exists():
        truth, lines = read_table(gt_path, 4, "time, x, y, heading")
        check_times(truth, lines, gt_path)  # a repeated line is dropped (robot_track), another refused
        check_repeats(truth, lines, gt_path)
        heading = truth[:, 3]
        refuse_first_row(  # Vicon headings are wrapped to +-pi; degrees reach 180
            ~(np.abs(heading) <= 2 * math.pi),
            lines,
            gt_path,
            lambda k: f"heading {heading[k]:g} rad is not within +-2 pi (degrees?)",
        )
        if len(truth) < 2:
            truth = None
    return odo, meas, truth


#: Fastest commanded speeds a log may hold: 10 m/s and 10 turns a second are far
#: beyond these 0.3 m/s robots; past them a number is a corrupt line.
SPEED_MAX_MPS, TURN_RATE_MAX_RADPS = 10.0, 20 * math.pi


#: Longest median interval between odometry lines, s: MRCLAM's robots log them a
#: median 0.01 s apart (Dataset 6, all five), so in milliseconds the median reads 10
#: "s" and every step is integrated 1000 times too long. 5 s lies between, and leaves
#: a log thinned to one line a second or two (an integration that coarse is the
#: user's choice, not a unit mix-up) readable.
ODOMETRY_STEP_MAX_S = 5.0


def _check_time_unit(odo, path: Path) -> None:
    if len(odo) < 2:
        return
    step = float(np.median(np.diff(odo[:, 0])))
    if step > ODOMETRY_STEP_MAX_S:
        raise InputError(
            f"odometry lines are a median {step:g} s apart (MRCLAM's robots: 0.01 s; "
            "the format's times are seconds): times in milliseconds?",
            path,
        )


def _check_speeds(odo, lines, path: Path) -> None:
    bad = (np.abs(odo[:, 1]) > SPEED_MAX_MPS) | (np.abs(odo[:, 2]) > TURN_RATE_MAX_RADPS)
    refuse_first_row(
        bad,
        lines,
        path,
        lambda k: (
            f"commanded velocity {odo[k, 1]:g} m/s, {odo[k, 2]:g} rad/s is beyond "
            f"{SPEED_MAX_MPS:g} m/s or {TURN_RATE_MAX_RADPS:.3g} rad/s"
        ),
    )


def _check_sightings(meas, lines, path: Path) -> None:
    for row in range(len(meas)):
        _, code, rng, bearing = meas[row]
        if not is_id(code, 0):
            raise InputError(
                f"barcode {code:.15g} is not a whole number >= 0 below {ID_LIMIT}", path, lines[row]
            )
        if not 0.0 < rng < 1e3:
            raise InputError(f"range {rng:g} m is not in (0, 1000)", path, lines[row])
        if not abs(bearing) <= 2 * math.pi:
            raise InputError(f"bearing {bearing:g} rad is not within +-2 pi (degrees?)", path, lines[row])


#: Most frames a robot's log may become: the synthetic world's step limit; at
#: ``frame_every_s = 1e-12`` a 40-minute log asked for 17.8 TiB of frame times.
MAX_FRAMES = MAX_STEPS


def frame_times(odometry_s: np.ndarray, sighting_s: np.ndarray, every_s: float) -> np.ndarray:
    """Frame times: each distinct sighting time in the odometry's span, and more
    where sightings are further apart than ``every_s``; (F,) increasing."""
    t0, t1 = (
        float(odometry_s[0]),
        float(max(odometry_s[-1], sighting_s[-1] if len(sighting_s) else odometry_s[-1])),
    )
    key = np.unique(np.concatenate([[t0, t1], sighting_s[(sighting_s >= t0) & (sighting_s <= t1)]]))
    frames = len(key) + float(np.maximum(np.ceil(np.diff(key) / every_s) - 1, 0).sum())
    if frames > MAX_FRAMES:  # counted before any array of them is made
        raise ConfigError(
            f"mrclam.frame_every_s = {every_s:g} would put {frames:.3g} frames on "
            f"{t1 - t0:.0f} s of data; at most {MAX_FRAMES:.0e}"
        )
    out = [key[:1]]
    for a, b in zip(key[:-1], key[1:], strict=True):
        extra = int(math.ceil((b - a) / every_s)) - 1
        if extra > 0:
            out.append(a + (b - a) * np.arange(1, extra + 1) / (extra + 1))
        out.append(np.array([b]))
    return np.concatenate(out)


def truth_at(truth: np.ndarray, times_s: np.ndarray) -> np.ndarray:
    """(F, 3) Vicon pose interpolated at ``times_s`` (heading unwrapped, then wrapped);
    NaN rows outside the truth's span or inside a gap longer than :data:`TRUTH_MAX_GAP_S`."""
    return unwrapped_truth_at(unwrapped(truth), times_s)


def unwrapped(truth: np.ndarray) -> np.ndarray:
    """The Vicon log (T, 4) with its heading unwrapped, for :func:`unwrapped_truth_at`
    (unwrapping the whole log is most of :func:`truth_at`'s cost, paid once here)."""
    return np.column_stack([truth[:, :3], np.unwrap(truth[:, 3])])


def unwrapped_truth_at(truth: np.ndarray, times_s: np.ndarray) -> np.ndarray:
    """:func:`truth_at` of a log :func:`unwrapped` once."""
    t, heading = truth[:, 0], truth[:, 3]
    out = np.column_stack(
        [
            np.interp(times_s, t, truth[:, 1]),
            np.interp(times_s, t, truth[:, 2]),
            np.interp(times_s, t, heading),
        ]
    )
    out[:, 2] = np.remainder(out[:, 2] + np.pi, 2 * np.pi) - np.pi
    k = np.searchsorted(t, times_s, side="right")
    inside = (k > 0) & (k < len(t))
    kk = np.clip(k, 1, len(t) - 1)
    gap_ok = (t[kk] - t[kk - 1]) <= TRUTH_MAX_GAP_S
    exact = (k > 0) & (t[np.maximum(k - 1, 0)] == times_s)  # at a line: side="right" puts it at k - 1
    out[~((inside & gap_ok) | exact)] = np.nan
    return out


@dataclass
class RobotTrack:
    """One robot's log made into frames (times), before pose ids are given.

    ``deltas (F-1, 3)``, ``covariances (F-1, 3, 3)``: odometry between consecutive
    frames; ``wTb_true (F, 3)`` with NaN rows where there is no truth;
    ``landmark_sightings``: ``(frame, subject, z (2,))``; ``robot_sightings``:
    ``(frame, subject, z (2,), time_s)`` of the other robots; ``notes`` and
    ``warnings`` (what the estimate rests on that the log does not give: a held
    command across a gap in the odometry), one line each.
    """

    times: np.ndarray
    deltas: np.ndarray
    covariances: np.ndarray
    wTb_true: np.ndarray
    landmark_sightings: list
    robot_sightings: list
    notes: list
    warnings: list = field(default_factory=list)
    #: the odometry's turns were fitted to the truth and follow it (its truth is this robot's)
    odometry_fits_truth: bool = False
    #: doubts on the odometry from its truth, kept apart from ``warnings``: with sightings
    #: that miss the truth too, :func:`truth_doubts` says both in one line
    odometry_doubts: list = field(default_factory=list)
    #: those of ``notes`` and ``warnings`` on the robot's own truth (``Dataset.truth_lines``)
    truth_lines: list = field(default_factory=list)
    #: motions that do not follow the truth at all (``"turns (cosine 0.14)"``)
    odometry_unfollowed: tuple = ()


def robot_track(
    config: MrclamConfig, n: int, odo, meas, truth, barcodes, extra_times: np.ndarray | None = None
) -> RobotTrack:
    """Frames at the landmark sightings, at least every ``frame_every_s``; odometry
    integrated between them. With ``extra_times`` (several robots in one graph), also
    at this robot's sightings of the others and at ``extra_times`` (when they see it)."""
    notes = odometry_repeats_note(n, odo)
    gap_s, warnings = odometry_gaps(n, odo[:, 0])
    if truth is not None:
        truth, repeated = drop_repeats(truth)
        if repeated:
            notes.append(f"robot {n}: {repeated} repeated lines of Robot{n}_Groundtruth.dat dropped")
        truth = truth if len(truth) >= 2 else None
    meas, repeated = drop_repeated_sightings(meas)  # one sighting, not two
    if repeated:
        notes.append(f"robot {n}: {repeated} repeated lines of Robot{n}_Measurement.dat dropped")
    meas, clashes = drop_conflicting_sightings(n, meas)
    warnings.extend(clashes)
    end_s = float(odo[-1, 0]) + gap_s  # the last command holds as long as between two lines
    if len(meas) == 0:  # a landmark-SLAM run on odometry alone: said, not only as 0 landmarks
        notes.append(f"robot {n}: Robot{n}_Measurement.dat holds no sighting (odometry only)")
    subject = np.array([barcodes.get(int(c), 0) for c in meas[:, 1]], dtype=np.int64)
    unknown = subject == 0
    if unknown.any():
        codes = sorted({int(c) for c in meas[unknown, 1]})
        notes.append(
            f"robot {n}: {int(unknown.sum())} sightings of barcodes Barcodes.dat does "
            f"not list ({', '.join(map(str, codes))}) in the whole log dropped"
        )
    own = subject == n
    notes.extend(own_barcode_note(n, meas, own))
    keep, said, late_warning = outside_span(
        n, meas[:, 0], ~unknown & ~own, float(odo[0, 0]), end_s, float(odo[-1, 0])
    )
    notes.extend(said)
    warnings.extend(late_warning)
    meas, subject = meas[keep], subject[keep]
    is_robot = np.isin(subject, list(ROBOT_SUBJECTS))
    if extra_times is None:
        wanted = meas[~is_robot, 0]
    else:  # the others see it while it has odometry only (beyond, it has no pose)
        wanted = np.concatenate(
            [meas[:, 0], extra_times[(extra_times >= odo[0, 0]) & (extra_times <= end_s)]]
        )
    times = frame_times(odo[:, 0], np.sort(wanted), config.frame_every_s)
    model = config.motion_model()
    held = held_commands(odo[:, 0], odo[:, 1], odo[:, 2], model)
    deltas, covs = integrate(*held, times, model.coefficients())
    wTb_true = truth_at(truth, times) if truth is not None else np.full((len(times), 3), np.nan)
    odometry_doubts, judged, unfollowed = odometry_truth_doubt(n, *held, times, wTb_true)
    has_truth = np.isfinite(wTb_true).all(axis=1)
    truth_lines = []
    if truth is None:
        truth_lines.append(f"robot {n}: no ground truth")
        notes.append(truth_lines[-1])
    elif not has_truth.any():  # a note only, and ATE n/a with exit 0 (hostile pass 21)
        truth_lines.append(
            f"Robot{n}_Groundtruth.dat covers none of robot {n}'s log ({truth[0, 0]:.3f}-"
            f"{truth[-1, 0]:.3f} s against {times[0]:.3f}-{times[-1]:.3f} s): nothing is scored "
            "(another log's truth, or its times shifted?)"
        )
        warnings.append(truth_lines[-1])
    elif not has_truth.all():
        truth_lines.append(
            f"robot {n}: truth on {int(has_truth.sum())} of the whole log's {len(times)} frames "
            "(scored there only)"
        )
        notes.append(truth_lines[-1])
    frame_of = np.searchsorted(times, meas[:, 0]).tolist()
    is_robot = is_robot.tolist()
    zs, stamps = meas[:, 2:4], meas[:, 0].tolist()
    landmarks = [
        (k, int(s), zs[i])
        for i, (k, s, r) in enumerate(zip(frame_of, subject, is_robot, strict=True))
        if not r
    ]
    robots = [
        (k, int(s), zs[i], stamps[i])
        for i, (k, s, r) in enumerate(zip(frame_of, subject, is_robot, strict=True))
        if r
    ]
    return RobotTrack(
        times,
        deltas,
        covs + COVARIANCE_FLOOR,
        wTb_true,
        landmarks,
        robots,
        notes,
        warnings,
        odometry_fits_truth=judged and not odometry_doubts,
        odometry_doubts=odometry_doubts,
        odometry_unfollowed=unfollowed,
        truth_lines=truth_lines,
    )


#: An interval between odometry lines longer than this many of the log's median
#: intervals is lines missing: the loggers write a line at least once a second while a
#: command holds (Dataset 6's five robots: longest interval 1.03 s, 103 times their
#: 0.01 s median), so twice that is beyond any the format leaves.
ODOMETRY_GAP_MEDIANS = 200.0
#: A log thinned to one line every few seconds (readable: :data:`ODOMETRY_STEP_MAX_S`)
#: has a median interval of seconds, and 200 of them let a 200-s hole pass unsaid; its
#: gaps are also those beyond this many of its median intervals (thinning leaves them
#: regular), but never below :data:`ODOMETRY_GAP_FLOOR_S`, twice the loggers' longest
#: interval: a genuine log's bound stays 200 medians (2 s).
ODOMETRY_THINNED_GAP_MEDIANS, ODOMETRY_GAP_FLOOR_S = 10.0, 2.06


def odometry_gaps(n: int, times_s: np.ndarray) -> tuple[float, list[str]]:
    """The longest interval ``times_s`` (K,) leaves between lines in the normal course
    (:data:`ODOMETRY_GAP_MEDIANS` of its median, fewer for a thinned log:
    :data:`ODOMETRY_THINNED_GAP_MEDIANS`), s (inf under two lines), and a
    warning naming the gaps beyond it, across which the last command is held."""
    step = np.diff(times_s)
    positive = step[step > 0]
    if not len(positive):
        return math.inf, []
    median = float(np.median(positive))
    gap_s = min(
        ODOMETRY_GAP_MEDIANS * median, max(ODOMETRY_GAP_FLOOR_S, ODOMETRY_THINNED_GAP_MEDIANS * median)
    )
    gaps = np.flatnonzero(step > gap_s)
    if not len(gaps):
        return gap_s, []
    worst = int(gaps[np.argmax(step[gaps])])
    more = f" and {len(gaps) - 1} more" if len(gaps) > 1 else ""
    return gap_s, [
        f"robot {n}: Robot{n}_Odometry.dat has no line for {step[worst]:.1f} s from "
        f"{times_s[worst] - times_s[0]:.1f} s into the log{more} (gaps over {gap_s:.3g} s, "
        f"{gap_s / median:.3g} times its median interval): the command before each is held "
        "across it, so the motion there is a guess"
    ]


#: Shortest range the noise model is evaluated at, m: the bearing's ``1 / r`` term
#: would diverge at a zero range (the log's shortest sighting is about 0.5 m).
MIN_MODEL_RANGE_M = 0.1


def sighting_covariances(config: MrclamConfig, z: np.ndarray) -> np.ndarray:
    """(N, 2, 2) ``[range, bearing]`` covariances of N sightings ``z`` (N, 2):
    the range-dependent model of :class:`MrclamConfig`."""
    r = np.maximum(np.asarray(z, dtype=np.float64).reshape(-1, 2)[:, 0], MIN_MODEL_RANGE_M)
    out = np.zeros((r.size, 2, 2))
    out[:, 0, 0] = config.sigma_range_m**2 + (config.sigma_range_per_m * r) ** 2
    out[:, 1, 1] = config.sigma_bearing_rad**2 + (config.sigma_bearing_m / r) ** 2
    return out


def landmark_observations(track: RobotTrack, config: MrclamConfig, pose_id_of, robot: int) -> dict:
    """``{frame: [Observation]}`` of the track's landmark sightings (by ``robot``'s
    camera), pose ids by ``pose_id_of(frame)``, time stamped, with the sensor's
    error correlation (:meth:`MrclamConfig.sighting_correlation`)."""
    rows = track.landmark_sightings
    observations = range_bearing_batch(
        [pose_id_of(k) for k, _, _ in rows],
        [s for _, s, _ in rows],
        [z for _, _, z in rows],
        sighting_covariances(config, np.array([z for _, _, z in rows]).reshape(-1, 2)),
        stamps_s=[track.times[k] for k, _, _ in rows],
        correlation=config.sighting_correlation(robot),
    )
    by_frame: dict[int, list] = {}
    for (k, _, _), obs in zip(rows, observations, strict=True):
        by_frame.setdefault(k, []).append(obs)
    return by_frame


def timed_frames(times: np.ndarray, odometry: list, by_frame: dict, wTb_true: np.ndarray) -> list[Frame]:
    """One :class:`Frame` a time of ``times`` (N,): pose k, the odometry ``odometry[k-1]``
    into it, its observations ``by_frame[k]`` (their ids the true ones: the data's
    barcodes or beacon ids) and the truth row ``wTb_true[k]`` (N, 3) where finite."""
    has_truth = np.isfinite(wTb_true).all(axis=1)
    frames = []
    for k, t in enumerate(times.tolist()):
        seen = tuple(by_frame.get(k, ()))
        frames.append(
            Frame(
                pose_id=k,
                stamp_s=t,
                odometry=odometry[k - 1] if k else None,
                observations=seen,
                true_landmark_ids=tuple(o.landmark_id for o in seen),
                wTb_true=wTb_true[k].copy() if has_truth[k] else None,
            )
        )
    return frames


def _dataset(folder: Path, config: MrclamConfig, track: RobotTrack, landmarks_true) -> Dataset:
    has_truth = np.isfinite(track.wTb_true).all(axis=1)
    prior = track.wTb_true[0] if has_truth[0] else np.zeros(3)
    track.notes.append(
        "start pose from the truth"
        if has_truth[0]
        else "start pose at the origin (no truth at the first frame)"
    )
    ids = list(range(len(track.times)))
    odometry = odometry_batch(ids[:-1], ids[1:], track.deltas, track.covariances)
    by_frame = landmark_observations(track, config, int, config.robot)
    frames = timed_frames(track.times, odometry, by_frame, track.wTb_true)
    return Dataset(
        name=f"{folder_name(folder)}-robot{config.robot}",
        frames=frames,
        prior_wTb=prior,
        prior_covariance=np.eye(3) * PRIOR_VARIANCE,
        landmarks_true=landmarks_true or None,
        has_timestamps=True,
        source_path=str(folder),
        notes=tuple(track.notes),
        sensor_field=config.sensor_field(),
        truth_lines=tuple(track.truth_lines),
    )
