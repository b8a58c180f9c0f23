"""Reader for gtsam's ``victoria_park.txt`` (real landmark SLAM, Sydney).

Format (one record a line; blank and ``#`` lines skipped):

- ``ODOMETRY i j dx dy dtheta c11 c12 c13 c22 c23 c33``: pose ``j`` relative to
  pose ``i`` with the upper triangle of its covariance.
- ``LANDMARK i j lx ly v1 v2 v3``: Cartesian position of landmark ``j`` in the
  frame of pose ``i``, with covariance ``[[v1, v2], [v2, v3]]``.

Pose ids have gaps (``ODOMETRY 4 6`` because landmark 5 was named in between);
they are kept as in the file. In the file every ``LANDMARK i`` line comes after
the ``ODOMETRY`` line that creates pose ``i``; such an observation joins the
frame of pose ``i`` (even if ``i`` is no longer the latest pose).

Noise follows ``gtsam.load2D`` on purpose, so that graph errors compare with
published numbers (checked factor by factor in ``tests/graphslam/sources/test_readers.py``):

- odometry: the six numbers are the g2o-layout covariance
  ``[[c11 c12 c13], [c12 c22 c23], [c13 c23 c33]]`` (load2D's automatic format
  detection picks "COV" for the ``c 0 0 c 0 c`` pattern of this file), which
  here is ``diag(c11, c22, c33)``;
- landmarks: load2D converts to a bearing-range factor with
  ``bearing = atan2(ly, lx)``, ``range = hypot(lx, ly)``, bearing sigma
  ``sqrt(v1 / 10)``, range sigma ``sqrt(v1)``, and ignores ``v2``, ``v3``. Our
  :class:`~slamcore.planar.records.Observation` has ``z = [range_m, bearing_rad]``, so its
  covariance is ``diag(v1, v1 / 10)``. This is load2D's model, not a propagation
  of the Cartesian covariance.
"""

from __future__ import annotations

import math

import numpy as np

from graphslam.sources.tokens import MAX_KEY_ID, check_count, iter_lines, parse_id, parse_numbers
from slamcore.errors import InputError, MeasurementError, quote
from slamcore.planar.geometry import wrap_angle
from slamcore.planar.records import (
    Dataset,
    Frame,
    Observation,
    ObservationKind,
    Odometry,
    odometry_batch,
    range_bearing_batch,
)

#: Variances a measurement of this log may state: standard deviations from
#: 1 micrometre (microradian) to 1 km (a full turn). Outside, the number says
#: nothing physical, and its information (1 / variance) leaves the range in
#: which a solver can weigh it against the others in double precision.
VARIANCE_MIN = 1e-12
VARIANCE_MAX = {
    "x": 1e6,
    "y": 1e6,
    "range": 1e6,
    "heading": (2 * math.pi) ** 2,
    "bearing": (2 * math.pi) ** 2,
}


#: ``c11 c12 c13 c22 c23 c33`` (an ODOMETRY line's upper triangle, g2o's order) -> the
#: row-major 3x3 covariance.
G2O_UPPER = [0, 1, 2, 1, 3, 4, 2, 4, 5]

#: Longest odometry step or landmark offset, metres: 1000 km, far past any
#: vehicle step or laser range, and where float64 still resolves micrometres.
DISTANCE_MAX_M = 1e6


def check_distances(values, path, line_no: int) -> None:
    """InputError when an offset is longer than :data:`DISTANCE_MAX_M`."""
    for v in values:
        if abs(v) > DISTANCE_MAX_M:
            raise InputError(f"offset {v:g} m is beyond {DISTANCE_MAX_M:g} m", path, line_no)


#: Largest heading change of one ODOMETRY line, rad: one full turn. A relative pose
#: is written wrapped (victoria_park.txt: within 0.13 rad a step); past a turn the
#: number is no angle in radians (degrees: the wrap made 90 a turn of -1.1 rad).
TURN_MAX_RAD = 2 * math.pi


def check_turn(dtheta: float, path, line_no: int) -> None:
    """InputError when an odometry heading change is beyond :data:`TURN_MAX_RAD`."""
    if not abs(dtheta) <= TURN_MAX_RAD:
        raise InputError(
            f"heading change {dtheta:g} rad is beyond one turn (2 pi): degrees? "
            "the format's angles are radians",
            path,
            line_no,
        )


def check_variances(variances, names, path, line_no: int) -> None:
    """InputError when a positive variance is outside :data:`VARIANCE_MIN` ..
    :data:`VARIANCE_MAX` (one <= 0 is the records' "not positive definite")."""
    for v, name in zip(variances, names, strict=True):
        if v > 0 and not VARIANCE_MIN <= v <= VARIANCE_MAX[name]:
            raise InputError(
                f"{name} variance {v:g} is outside {VARIANCE_MIN:g} .. {VARIANCE_MAX[name]:.4g}",
                path,
                line_no,
            )


def victoria_park_path() -> str:
    """Path of ``victoria_park.txt`` shipped in the gtsam wheel."""
    import gtsam

    return gtsam.findExampleDataFile("victoria_park.txt")


def read_victoria_park(path=None, name: str = "victoria-park") -> Dataset:
    """Read a Victoria-Park-format file into a Dataset.

    Args:
        path: the file; ``None`` reads the copy in the gtsam wheel.
        name: the dataset's name (what summaries and outputs call it).

    Returns:
        Dataset whose frames are the poses in file order; ``frames[0]`` is the
        ``from`` pose of the first ODOMETRY line.

    Raises:
        InputError: missing file or malformed line (names file and line).
    """
    if path is None:
        path = victoria_park_path()
    fast = read_well_formed(path, name)
    if fast is not None:
        return fast
    # Something in the file is off: the line-by-line reader names the line and why.
    order: list[int] = []  # pose ids in creation order
    odometry: dict[int, Odometry] = {}
    observations: dict[int, list[Observation]] = {}
    for line_no, tok in iter_lines(path):
        tag = tok[0]  # iter_lines reads utf-8-sig: a byte-order mark is already gone
        try:
            if tag == "ODOMETRY":
                check_count(tok, 12, path, line_no, "ODOMETRY i j dx dy dtheta + 6 covariance")
                i = parse_id(tok[1], path, line_no, limit=MAX_KEY_ID)
                j = parse_id(tok[2], path, line_no, limit=MAX_KEY_ID)
                nums = parse_numbers(tok[3:], path, line_no)
                check_distances(nums[:2], path, line_no)
                if not order:
                    order.append(i)
                    observations[i] = []
                elif i not in observations:
                    raise InputError(f"ODOMETRY from pose {i}, which does not exist yet", path, line_no)
                if j in observations:
                    raise InputError(f"ODOMETRY creates pose {j}, which already exists", path, line_no)
                cov = np.array(nums[3:])[G2O_UPPER].reshape(3, 3)
                check_variances(np.diag(cov), ("x", "y", "heading"), path, line_no)
                check_turn(nums[2], path, line_no)
                delta = np.array(nums[:3])
                delta[2] = wrap_angle(delta[2])  # gtsam's Pose2 wraps too
                odometry[j] = Odometry(i, j, delta, cov)
                order.append(j)
                observations[j] = []
            elif tag == "LANDMARK":
                check_count(tok, 8, path, line_no, "LANDMARK i j lx ly v1 v2 v3")
                i = parse_id(tok[1], path, line_no, limit=MAX_KEY_ID)
                j = parse_id(tok[2], path, line_no, "landmark id", limit=MAX_KEY_ID)
                lx, ly, v1, _v2, _v3 = parse_numbers(tok[3:], path, line_no)
                check_distances((lx, ly), path, line_no)
                if i not in observations:
                    raise InputError(f"LANDMARK seen from pose {i}, which does not exist yet", path, line_no)
                z = np.array([math.hypot(lx, ly), math.atan2(ly, lx)])
                cov = np.diag([v1, v1 / 10.0])
                check_variances(np.diag(cov), ("range", "bearing"), path, line_no)
                observations[i].append(Observation(i, j, z, cov, ObservationKind.RANGE_BEARING))
            else:
                raise InputError(f"unknown tag {quote(tag)}", path, line_no)
        except MeasurementError as exc:
            raise InputError(str(exc), path, line_no) from None
    if not order:
        raise InputError("no ODOMETRY line", path)
    return _dataset(path, order, odometry, observations, name)


def _dataset(path, order, odometry, observations, name: str) -> Dataset:
    frames = [Frame(pose_id=k, odometry=odometry.get(k), observations=tuple(observations[k])) for k in order]
    return Dataset(
        name=name,
        frames=frames,
        prior_wTb=np.zeros(3),
        prior_covariance=np.eye(3) * 1e-6,
        landmarks_true=None,
        has_timestamps=False,
        source_path=str(path),
    )


def _plain_ids(tokens) -> bool:
    """Ids the fast path takes as they are: ASCII digits (signs, underscores: line by line)."""
    joined = "".join(tokens)  # one test for all: no token is empty
    return joined.isascii() and joined.isdigit()


def read_well_formed(path, name: str = "victoria-park") -> Dataset | None:
    """The whole file at once, when every line is well formed: the same records as the
    line-by-line reader (same numbers: ``float`` on each token, ``math.hypot`` and
    ``math.atan2``), checked in bulk; None as soon as anything is off, for the
    line-by-line reader to name the line (a 10x cost paid only by bad files)."""
    odo, lms = [], []  # token lists, and (position in the file, pose id) of each landmark line
    where = []
    try:
        with open(path, encoding="utf-8-sig") as fh:
            for line in fh:
                tok = line.split()
                if not tok or tok[0].startswith("#"):
                    continue
                if tok[0] == "ODOMETRY" and len(tok) == 12:
                    odo.append(tok)
                elif tok[0] == "LANDMARK" and len(tok) == 8:
                    lms.append(tok)
                    where.append(len(odo))
                else:
                    return None
        if (
            not odo
            or not _plain_ids(t for r in odo for t in r[1:3])
            or not _plain_ids(t for r in lms for t in r[1:3])
        ):
            return None
        o_ids = [(int(r[1]), int(r[2])) for r in odo]
        l_ids = [(int(r[1]), int(r[2])) for r in lms]
        # numpy parses each token as float() does (correctly rounded): the same numbers
        o_num = np.array([r[3:] for r in odo], dtype=np.float64).reshape(-1, 9)
        l_num = np.array([r[3:] for r in lms], dtype=np.float64).reshape(-1, 5)
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    if max(max(pair) for pair in o_ids + l_ids) > MAX_KEY_ID:
        return None
    order, created = [o_ids[0][0]], {o_ids[0][0]: 1}  # pose -> the ODOMETRY line making it
    for n, (i, j) in enumerate(o_ids, start=1):
        if i not in created or j in created:
            return None
        created[j] = n
        order.append(j)
    # a LANDMARK line must come after the ODOMETRY line that creates its pose
    if any(created.get(i, len(o_ids) + 1) > n for (i, _), n in zip(l_ids, where, strict=True)):
        return None
    return _well_formed_records(path, order, o_ids, o_num, l_ids, l_num, name)


def _well_formed_records(path, order, o_ids, o_num, l_ids, l_num, name) -> Dataset | None:
    """Records of the parsed numbers, or None where a check of the reader fails."""
    if not (np.isfinite(o_num).all() and np.isfinite(l_num).all()):
        return None
    if (np.abs(o_num[:, :2]) > DISTANCE_MAX_M).any() or (np.abs(l_num[:, :2]) > DISTANCE_MAX_M).any():
        return None
    if not (np.abs(o_num[:, 2]) <= TURN_MAX_RAD).all():  # the line reader names the line
        return None
    o_cov = o_num[:, 3:][:, G2O_UPPER].reshape(-1, 3, 3)
    l_cov = np.zeros((len(l_num), 2, 2))
    l_cov[:, 0, 0], l_cov[:, 1, 1] = l_num[:, 2], l_num[:, 2] / 10.0
    upper = [VARIANCE_MAX[k] for k in ("x", "y", "heading", "range", "bearing")]
    if not (
        _variances_ok(o_cov[:, [0, 1, 2], [0, 1, 2]], upper[:3])
        and _variances_ok(l_cov[:, [0, 1], [0, 1]], upper[3:])
    ):
        return None
    deltas = o_num[:, :3].copy()
    deltas[:, 2] = wrap_angle(deltas[:, 2])  # as the line reader
    zs = [[math.hypot(lx, ly), math.atan2(ly, lx)] for lx, ly in l_num[:, :2].tolist()]
    try:
        odometry = odometry_batch([i for i, _ in o_ids], [j for _, j in o_ids], deltas, o_cov)
        seen = range_bearing_batch([i for i, _ in l_ids], [j for _, j in l_ids], zs, l_cov)
    except MeasurementError:
        return None
    observations: dict[int, list[Observation]] = {k: [] for k in order}
    for obs in seen:
        observations[obs.pose_id].append(obs)
    return _dataset(path, order, {o.to_id: o for o in odometry}, observations, name)


def _variances_ok(variances: np.ndarray, upper) -> bool:
    """:func:`check_variances` on (N, k) at once (a variance <= 0 is the records' test)."""
    pos = variances > 0
    return not (pos & ((variances < VARIANCE_MIN) | (variances > np.asarray(upper)))).any()
