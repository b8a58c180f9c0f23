"""The bottom layer: plain numpy records passed between stages (no gtsam).

Conventions (2-D):

- a pose is ``[x_m, y_m, theta_rad]``, body ``b`` in world ``w`` (``wTb``);
- a relative pose ``aTb`` is ``[dx_m, dy_m, dtheta_rad]`` of ``b`` expressed in
  frame ``a`` (what :class:`gtsam.Pose2.between` returns);
- a range-bearing measurement is ``[range_m, bearing_rad]`` in the body frame;
- a range-only measurement (a radio beacon's) is ``[range_m]``;
- covariances are in the same units and order as the vector they describe.

Every record validates itself at construction: non-finite values and
covariances that are not symmetric positive definite are refused with a
:class:`~slamcore.errors.MeasurementError`, so nothing bad reaches a back end.
"""

from __future__ import annotations

import enum
import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from slamcore.errors import MeasurementError, quote
from slamcore.planar.sighting_correlation import SightingCorrelation

#: Relative tolerance on covariance symmetry (file formats round to ~6 digits).
COV_SYMMETRY_RTOL = 1e-6


def _float_array(value, what: str) -> np.ndarray:
    """``value`` as a float64 array, or MeasurementError: text, a dict or ragged lists
    were numpy's bare ValueError or TypeError (twentieth hostile pass, the Python API)."""
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise MeasurementError(f"{what}: expected numbers, got {_shape_text(value)}") from None


def _shape_text(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def as_vector(value, size: int, what: str) -> np.ndarray:
    """Return ``value`` as a read-only float64 vector of ``size``; refuse NaN/inf."""
    v = _float_array(value, what).reshape(-1)
    if v.shape != (size,):
        raise MeasurementError(f"{what}: expected {size} values, got {v.size}")
    if not np.all(np.isfinite(v)):
        raise MeasurementError(f"{what}: non-finite value {v.tolist()}")
    v.setflags(write=False)
    return v


def as_covariance(value, size: int, what: str) -> np.ndarray:
    """Return ``value`` as a read-only (size, size) SPD covariance or raise."""
    c = _float_array(value, what)
    if c.shape != (size, size):
        raise MeasurementError(f"{what}: covariance must be {size}x{size}, got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise MeasurementError(f"{what}: covariance has non-finite entries")
    scale = max(float(np.max(np.abs(c))), 1e-300)
    if np.max(np.abs(c - c.T)) > COV_SYMMETRY_RTOL * scale:
        raise MeasurementError(f"{what}: covariance is not symmetric")
    try:
        # entries near the float limit overflow the factor instead of failing it
        positive = bool(np.all(np.isfinite(np.linalg.cholesky(c))))
    except np.linalg.LinAlgError:
        positive = False
    if not positive:
        raise MeasurementError(f"{what}: covariance is not positive definite")
    c.setflags(write=False)
    return c


class ObservationKind(enum.Enum):
    """What an observation's measurement vector ``z`` holds."""

    RANGE_BEARING = "range_bearing"  #: z = [range_m, bearing_rad], (2,)
    PIXEL = "pixel"  #: z = [u_px, v_px], (2,)
    RANGE = "range"  #: z = [range_m], (1,); covariance (1, 1) (range-only beacons)

    @property
    def size(self) -> int:
        """Length of ``z`` (and side of the covariance) for this kind."""
        return 1 if self is ObservationKind.RANGE else 2


#: Ids are int64 everywhere downstream (estimates, files): beyond it an id cannot be held.
ID_LIMIT = 2**63


def checked_id(value, what: str, name: str = "id") -> int:
    """``value`` as an int id: an integer (a whole float is taken as one) within int64;
    MeasurementError naming ``what`` and ``name`` otherwise. A fractional id silently
    became another landmark's, a string "7" landmark 7."""
    if type(value) is int and -ID_LIMIT <= value < ID_LIMIT:  # the common case, per sighting
        return value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer, float, np.floating)):
        raise MeasurementError(f"{what}: {name} must be an integer, got {quote(value)}")
    if not (math.isfinite(value) and value == int(value) and -ID_LIMIT <= int(value) < ID_LIMIT):
        raise MeasurementError(f"{what}: {name} must be an integer within int64, got {quote(value)}")
    return int(value)


def checked_stamp(value, what: str) -> float | None:
    """A time stamp, s: None, or a finite real number as a float; MeasurementError
    naming ``what`` otherwise (a NaN first stamp turned the sighting-correlation model
    off, a string failed later inside a filter)."""
    if value is None or (type(value) is float and math.isfinite(value)):  # the common case
        return value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise MeasurementError(
            f"{what}: stamp_s must be None or a finite number of seconds, got {quote(value)}"
        )
    return float(value)


def _check_ids(record, names: tuple[str, ...], what: str, optional: tuple[str, ...] = ()) -> None:
    """In a frozen record's ``__post_init__``: each id field through :func:`checked_id`,
    or None where ``optional``."""
    for name in names:
        value = getattr(record, name)
        if value is None and name in optional:
            continue
        object.__setattr__(record, name, checked_id(value, what, name))


def _check_distinct(record, what: str) -> None:
    """A relative constraint of a pose on itself constrains nothing (its factor is
    constant) and no filter can take it: refused (MeasurementError) where it is made."""
    if record.from_id == record.to_id:
        raise MeasurementError(f"{what}: links pose {record.from_id} to itself, which constrains nothing")


def _check_mean_and_covariance(record, field: str, n: int, what: str) -> None:
    """In a frozen record's ``__post_init__``: ``record.<field>`` as a finite (n,) vector
    and ``record.covariance`` as an SPD (n, n) matrix, both read-only float64
    (MeasurementError naming ``what`` otherwise)."""
    object.__setattr__(record, field, as_vector(getattr(record, field), n, what))
    object.__setattr__(record, "covariance", as_covariance(record.covariance, n, what))


@dataclass(frozen=True, eq=False)
class Odometry:
    """A relative-pose measurement ``fromTto`` between two poses.

    Attributes:
        from_id, to_id: pose ids as in the input (one of them is the new pose).
        delta: (3,) ``[dx_m, dy_m, dtheta_rad]`` of ``to`` in the ``from`` frame.
        covariance: (3, 3) covariance of ``delta``.
    """

    from_id: int
    to_id: int
    delta: np.ndarray
    covariance: np.ndarray

    def __post_init__(self):
        what = f"odometry {self.from_id}->{self.to_id}"
        _check_ids(self, ("from_id", "to_id"), what)
        _check_mean_and_covariance(self, "delta", 3, what)


@dataclass(frozen=True, eq=False)
class Observation:
    """One landmark measurement made at a pose.

    Attributes:
        pose_id: id of the pose the measurement was taken from.
        landmark_id: landmark id when association is known, ``None`` when not.
        z: measurement, shape and units given by ``kind`` ((1,) for RANGE, else (2,)).
        covariance: (2, 2) measurement covariance ((1, 1) for RANGE).
        kind: :class:`ObservationKind`.
        signature: optional appearance signature (course slides: landmarks
            carry one that data association may use).
        stamp_s: time of the measurement, s, or ``None``.
        correlation: how the sensor's errors correlate in time
            (:class:`~slamcore.planar.sighting_correlation.SightingCorrelation`),
            or ``None`` (independent); with ``stamp_s``, the back ends weigh a
            sighting by what it adds to the earlier ones of its landmark.
    """

    pose_id: int
    landmark_id: int | None
    z: np.ndarray
    covariance: np.ndarray
    kind: ObservationKind = ObservationKind.RANGE_BEARING
    signature: int | None = None
    stamp_s: float | None = None
    correlation: SightingCorrelation | None = None

    def __post_init__(self):
        what = f"observation of landmark {self.landmark_id} from pose {self.pose_id}"
        _check_ids(self, ("pose_id", "landmark_id"), what, optional=("landmark_id",))
        object.__setattr__(self, "stamp_s", checked_stamp(self.stamp_s, what))
        if not isinstance(self.kind, ObservationKind):
            # the enum's value ("range_bearing") is the plausible slip: taken; anything
            # else was AttributeError: 'str' object has no attribute 'size'
            try:
                object.__setattr__(self, "kind", ObservationKind(self.kind))
            except (TypeError, ValueError):
                kinds = ", ".join(k.value for k in ObservationKind)
                raise MeasurementError(f"{what}: kind must be one of {kinds}, got {self.kind!r}") from None
        size = self.kind.size
        _check_mean_and_covariance(self, "z", size, what)
        if self.kind in (ObservationKind.RANGE_BEARING, ObservationKind.RANGE) and self.z[0] <= 0.0:
            raise MeasurementError(f"{what}: range must be positive, got {self.z[0]}")


@dataclass(frozen=True, eq=False)
class LoopClosure:
    """A relative-pose constraint between two non-consecutive poses.

    Attributes:
        from_id, to_id: pose ids; ``delta`` is ``fromTto``, (3,).
        covariance: (3, 3).
        score: detector's confidence, if any (bag-of-words score, inliers...).
        source: who proposed it ("dataset", "bow", "injected-false", ...).
    """

    from_id: int
    to_id: int
    delta: np.ndarray
    covariance: np.ndarray
    score: float | None = None
    source: str = "dataset"

    def __post_init__(self):
        what = f"loop closure {self.from_id}->{self.to_id}"
        _check_ids(self, ("from_id", "to_id"), what)
        _check_distinct(self, what)
        _check_mean_and_covariance(self, "delta", 3, what)


def _checked_batch(values, shape: tuple[int, ...], what: str) -> np.ndarray:
    """(N, *shape) float64, read-only, finite; MeasurementError naming the first bad row."""
    try:
        a = np.array(values, dtype=np.float64).reshape((-1,) + shape)
    except (TypeError, ValueError) as exc:  # "x", ragged rows: numpy's words, one line
        raise MeasurementError(f"{what}s: not an array of numbers of shape (N, {shape}): {exc}") from None
    bad = ~np.isfinite(a).reshape(len(a), -1).all(axis=1) if len(a) else np.zeros(0, bool)
    if bad.any():
        raise MeasurementError(f"{what} {int(np.argmax(bad))}: non-finite value")
    a.setflags(write=False)
    return a


def _checked_covariances(values, size: int, what: str) -> np.ndarray:
    """:func:`as_covariance` on (N, size, size) at once: the same tests, one numpy call each."""
    c = _checked_batch(values, (size, size), what)
    if not len(c):
        return c
    scale = np.maximum(np.abs(c).reshape(len(c), -1).max(axis=1, initial=0.0), 1e-300)
    asym = np.abs(c - c.transpose(0, 2, 1)).reshape(len(c), -1).max(axis=1, initial=0.0)
    bad = asym > COV_SYMMETRY_RTOL * scale
    if not bad.any():
        try:
            bad = ~np.isfinite(np.linalg.cholesky(c)).reshape(len(c), -1).all(axis=1)
        except np.linalg.LinAlgError:  # which one: row by row, only on this failure
            bad = np.array([not _positive(m) for m in c])
    if bad.any():
        raise MeasurementError(f"{what} {int(np.argmax(bad))}: covariance is not symmetric positive definite")
    return c


def _positive(m: np.ndarray) -> bool:
    try:
        return bool(np.all(np.isfinite(np.linalg.cholesky(m))))
    except np.linalg.LinAlgError:
        return False


def _batch_ids(values, n: int, what: str, name: str) -> list[int]:
    """The ids of ``n`` rows as ints, by :func:`checked_id`'s rule: at numpy speed when
    they are an integer array within int64, else row by row (MeasurementError naming the
    row, or the count when it is not ``n``)."""
    a = np.asarray(values)
    if a.ndim == 1 and a.dtype.kind in "iu" and (a.dtype.kind == "i" or not a.size or a.max() < ID_LIMIT):
        ids = a.tolist()
    else:
        ids = [checked_id(v, f"{what} {k}", name) for k, v in enumerate(values)]
    if len(ids) != n:
        raise MeasurementError(f"{what}s: {len(ids)} values of {name} for {n} rows")
    return ids


def _bare(cls, **fields):
    """A record whose fields were checked in bulk (no second check per record)."""
    obj = object.__new__(cls)
    obj.__dict__.update(fields)  # what object.__setattr__ does per field, in one call
    return obj


def odometry_batch(from_ids, to_ids, deltas, covariances) -> list[Odometry]:
    """:class:`Odometry` records of N edges, checked as their constructor checks them but
    in a few numpy calls (a reader's 7000 records: 0.5 s one by one). MeasurementError
    names the first bad row; the deltas and covariances are views of read-only arrays."""
    d = _checked_batch(deltas, (3,), "odometry row")
    c = _checked_covariances(covariances, 3, "odometry row")
    a = _batch_ids(from_ids, len(d), "odometry row", "from_id")
    b = _batch_ids(to_ids, len(d), "odometry row", "to_id")
    return [
        _bare(Odometry, from_id=i, to_id=j, delta=d[k], covariance=c[k])
        for k, (i, j) in enumerate(zip(a, b, strict=True))
    ]


def loop_closure_batch(from_ids, to_ids, deltas, covariances, source: str = "dataset") -> list[LoopClosure]:
    """:class:`LoopClosure` records of N edges without a score, checked in bulk (see
    :func:`odometry_batch`)."""
    d = _checked_batch(deltas, (3,), "loop closure row")
    c = _checked_covariances(covariances, 3, "loop closure row")
    a = _batch_ids(from_ids, len(d), "loop closure row", "from_id")
    b = _batch_ids(to_ids, len(d), "loop closure row", "to_id")
    same = [k for k, (i, j) in enumerate(zip(a, b, strict=True)) if i == j]
    if same:  # as the constructor: a pose tied to itself constrains nothing
        raise MeasurementError(f"loop closure row {same[0]}: links pose {a[same[0]]} to itself")
    return [
        _bare(LoopClosure, from_id=i, to_id=j, delta=d[k], covariance=c[k], score=None, source=source)
        for k, (i, j) in enumerate(zip(a, b, strict=True))
    ]


def range_bearing_batch(
    pose_ids, landmark_ids, zs, covariances, stamps_s=None, correlation: SightingCorrelation | None = None
) -> list[Observation]:
    """Range-bearing :class:`Observation` records of N rows, checked in bulk (see
    :func:`odometry_batch`): finite, SPD covariances, positive ranges; ``stamps_s`` (N,)
    and ``correlation`` as the fields of that name (None: none)."""
    z = _checked_batch(zs, (2,), "observation row")
    c = _checked_covariances(covariances, 2, "observation row")
    kind = ObservationKind.RANGE_BEARING
    return _observations(pose_ids, landmark_ids, z, c, kind, stamps_s, correlation)


def _observations(pose_ids, landmark_ids, z, c, kind, stamps_s, correlation) -> list[Observation]:
    """The records of the checked rows ``z`` (N, k) and ``c`` (N, k, k), once every
    range (column 0) is positive."""
    bad = z[:, 0] <= 0.0
    if bad.any():
        raise MeasurementError(f"observation row {int(np.argmax(bad))}: range must be positive")
    stamps = [None] * len(z) if stamps_s is None else _checked_batch(stamps_s, (), "observation row").tolist()
    if len(stamps) != len(z):
        raise MeasurementError(f"observation rows: {len(stamps)} stamps for {len(z)} rows")
    pose_ids = _batch_ids(pose_ids, len(z), "observation row", "pose_id")
    landmark_ids = _batch_ids(landmark_ids, len(z), "observation row", "landmark_id")
    return [
        _bare(
            Observation,
            pose_id=p,
            landmark_id=j,
            z=z[k],
            covariance=c[k],
            kind=kind,
            signature=None,
            stamp_s=t,
            correlation=correlation,
        )
        for k, (p, j, t) in enumerate(zip(pose_ids, landmark_ids, stamps, strict=True))
    ]


def range_batch(pose_ids, landmark_ids, ranges, variances) -> list[Observation]:
    """Range-only (:attr:`ObservationKind.RANGE`) :class:`Observation` records of N rows,
    checked in bulk as :func:`range_bearing_batch` checks them: finite, positive ranges
    (m) and positive variances (m^2); z is (1,), the covariance (1, 1)."""
    z = _checked_batch(ranges, (1,), "observation row")
    c = _checked_covariances(np.reshape(variances, (-1, 1, 1)), 1, "observation row")
    return _observations(pose_ids, landmark_ids, z, c, ObservationKind.RANGE, None, None)


@dataclass(frozen=True, eq=False)
class PoseSighting:
    """Range and bearing from one pose to another (one robot seeing another).

    Attributes:
        from_id: the observing pose; to_id: the pose seen (both must exist when the
            sighting is added).
        z: (2,) ``[range_m, bearing_rad]`` of ``to_id``'s position in ``from_id``'s frame.
        covariance: (2, 2).
    """

    from_id: int
    to_id: int
    z: np.ndarray
    covariance: np.ndarray

    def __post_init__(self):
        what = f"sighting of pose {self.to_id} from pose {self.from_id}"
        _check_ids(self, ("from_id", "to_id"), what)
        _check_distinct(self, what)
        _check_mean_and_covariance(self, "z", 2, what)
        if self.z[0] <= 0.0:
            raise MeasurementError(f"{what}: range must be positive, got {self.z[0]}")


@dataclass(frozen=True, eq=False)
class Frame:
    """Everything that arrives with one new pose.

    Attributes:
        pose_id: id of the new pose (as in the input; may have gaps).
        stamp_s: timestamp in seconds, or ``None`` if the data has none.
        odometry: measurement linking the new pose to an earlier one; ``None``
            for the first frame.
        observations: landmark measurements taken at ``pose_id``.
        loop_closures: constraints between ``pose_id`` and earlier poses.
        wTb_true: (3,) ground-truth pose, when known.
        true_landmark_ids: ground-truth landmark id of each observation (same
            order), when known; used only for scoring data association.
        pose_sightings: other poses seen from this one or seeing it
            (:class:`PoseSighting`; several robots in one graph), added once both
            poses exist.
    """

    pose_id: int
    stamp_s: float | None = None
    odometry: Odometry | None = None
    observations: tuple[Observation, ...] = ()
    loop_closures: tuple[LoopClosure, ...] = ()
    wTb_true: np.ndarray | None = None
    true_landmark_ids: tuple[int, ...] | None = None
    pose_sightings: tuple[PoseSighting, ...] = ()


@dataclass(frozen=True, eq=False)
class Prediction:
    """A predicted observation of a known landmark, for active search / gating.

    Attributes:
        landmark_id: landmark id.
        z: (2,) predicted measurement (same kind as the observations).
        innovation_covariance: (2, 2) ``S = H P H^T + R``.
    """

    landmark_id: int
    z: np.ndarray
    innovation_covariance: np.ndarray


#: Fewest degrees of freedom a sensor's Student-t errors may have: below 1 the t has no
#: mean, and its quantiles at an association gate's probability overflow float64.
MIN_ERROR_DOF = 1.0


@dataclass(frozen=True)
class SensorField:
    """Where a range-bearing sensor reports landmarks, and how reliably: what a
    missed sighting means (negative information).

    Attributes:
        max_range_m: a landmark further than this is not reported, m.
        half_fov_rad: a landmark whose bearing is further than this from the
            heading is not reported, rad (pi: all round).
        detection_prob: probability that a landmark inside the field is reported
            in a frame that reports something (0 < p <= 1; 1 for a simulated
            sensor that sees everything in its field).
        error_dof: the sightings' errors about their stated covariance are
            Student-t with these degrees of freedom (``inf``, the default: Gaussian;
            at least :data:`MIN_ERROR_DOF`); what tells one landmark from another in
            data association.
    """

    max_range_m: float
    half_fov_rad: float
    detection_prob: float
    error_dof: float = float("inf")

    def __post_init__(self):
        # each test fails for NaN too, so the message names the value at fault
        if not (0.0 < self.max_range_m < np.inf):
            raise MeasurementError(f"sensor field: max_range_m must be finite and > 0 ({self.max_range_m})")
        if not 0.0 < self.half_fov_rad <= np.pi:
            raise MeasurementError(f"sensor field: half_fov_rad must be in (0, pi] ({self.half_fov_rad})")
        if not 0.0 < self.detection_prob <= 1.0:
            raise MeasurementError(f"sensor field: detection_prob must be in (0, 1] ({self.detection_prob})")
        if not self.error_dof >= MIN_ERROR_DOF:
            raise MeasurementError(f"sensor field: error_dof must be >= {MIN_ERROR_DOF:g} ({self.error_dof})")


def error_dof(sensor_field: SensorField | None) -> float:
    """Degrees of freedom of the sightings' Student-t errors: ``sensor_field``'s, or
    ``inf`` (Gaussian) when the data states no sensor field."""
    return math.inf if sensor_field is None else sensor_field.error_dof


@dataclass(frozen=True, eq=False)
class Estimate:
    """A back end's current belief, all numpy.

    Attributes:
        pose_ids: (N,) int ids of the poses in ``wTb``, in insertion order.
        wTb: (N, 3) poses ``[x_m, y_m, theta_rad]``.
        landmark_ids: (M,) int landmark ids.
        landmarks_w: (M, 2) landmark positions in world, metres.
        pose_covariances: (N, 3, 3) of ``[x, y, theta]`` in the world frame (not a
            body-frame tangent), or ``None`` if not computed.
        landmark_covariances: (M, 2, 2) or ``None`` if not computed.
    """

    pose_ids: np.ndarray
    wTb: np.ndarray
    landmark_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    landmarks_w: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    pose_covariances: np.ndarray | None = None
    landmark_covariances: np.ndarray | None = None

    @property
    def current_pose(self) -> np.ndarray:
        """(3,) the most recent pose."""
        return self.wTb[-1]

    @property
    def current_covariance(self) -> np.ndarray | None:
        """(3, 3) covariance of the most recent pose, if computed."""
        return None if self.pose_covariances is None else self.pose_covariances[-1]


@dataclass(frozen=True, eq=False)
class Dataset:
    """A recorded or simulated run, ready to stream into a back end.

    Attributes:
        name: short name for reports ("synthetic", "victoria-park", ...).
        frames: in time order; ``frames[0]`` has no odometry and anchors the
            run with ``prior_wTb`` / ``prior_covariance``.
        prior_wTb: (3,) pose of the first frame.
        prior_covariance: (3, 3) prior on the first pose (datasets without one
            use sigma 1e-3 on each axis, as gtsam's examples do).
        landmarks_true: ground-truth landmark positions ``{id: (2,)}`` or None.
        has_timestamps: whether ``Frame.stamp_s`` holds real times; when not,
            writers use the pose id in the time column.
        source_path: file the data came from, if any.
        seed: seed that generated a simulated dataset (None for recorded data).
        notes: what the reader made of the source, one line each, for the run's
            summary and ``metrics.json`` (sightings dropped, truth coverage, ...).
        agents: several robots in one run: ``(name, pose_ids)`` of each robot's
            trajectory, scored one by one; empty for one robot.
        warnings: what the reader doubts in the input (angles in degrees, another
            robot's truth), one line each: the run says them as warnings and keeps
            them in ``metrics.json`` ``warnings``, before the estimate's own.
        sensor_field: where the sensor reports landmarks and how reliably
            (:class:`SensorField`), when the source knows it; back ends that use
            negative information read it (:meth:`~slamcore.planar.backend.Backend.set_sensor_field`).
        truth_lines: those of ``notes`` and ``warnings`` that describe the source's own
            ground truth (its coverage, its absence): a truth given apart (``run
            --ground-truth``) replaces them.
    """

    name: str
    frames: Sequence[Frame]
    prior_wTb: np.ndarray = field(default_factory=lambda: np.zeros(3))
    prior_covariance: np.ndarray = field(default_factory=lambda: np.eye(3) * 1e-6)
    landmarks_true: dict[int, np.ndarray] | None = None
    has_timestamps: bool = False
    source_path: str | None = None
    seed: int | None = None
    notes: tuple[str, ...] = ()
    agents: tuple[tuple[str, tuple[int, ...]], ...] = ()
    warnings: tuple[str, ...] = ()
    sensor_field: SensorField | None = None
    truth_lines: tuple[str, ...] = ()

    @property
    def has_ground_truth(self) -> bool:
        """Whether any frame has a true pose (real logs may cover part of the run)."""
        return any(f.wTb_true is not None for f in self.frames)

    def ground_truth(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(pose_ids (N,), wTb (N, 3))`` of the frames with a true pose, or None."""
        known = [f for f in self.frames if f.wTb_true is not None]
        if not known:
            return None
        ids = np.array([f.pose_id for f in known], dtype=np.int64)
        return ids, np.array([f.wTb_true for f in known], dtype=np.float64)

    def agent_groups(self, pose_ids) -> list[np.ndarray]:
        """Index arrays into ``pose_ids`` (N,) of each robot's poses, one per robot of
        :attr:`agents` in order (empty for a robot with none there); without agents, one
        array of them all. Plots and recordings draw a robot's poses as its own line."""
        ids = np.asarray(pose_ids, dtype=np.int64).reshape(-1)
        if not self.agents:
            return [np.arange(len(ids))]
        return [np.flatnonzero(np.isin(ids, np.asarray(mine, dtype=np.int64))) for _, mine in self.agents]

    def truncated(self, max_frames: int) -> Dataset:
        """The first ``max_frames`` frames (loop closures to later poses cannot occur)."""
        return replace(self, frames=list(self.frames[:max_frames]))
