"""Trajectory-file evaluation as evo and the KITTI devkit compute it (numpy, scipy).

Poses are (N, 4, 4) ``wTc``; the reference comes first in every call.

- :func:`associate` -- evo's nearest-timestamp association: the shorter
  trajectory's stamps each take the nearest stamp of the longer one within
  ``max_diff`` (ties to the earlier one), the estimate's stamps shifted by
  ``offset``; defaults 0.01 s and 0 s, evo's;
- :func:`align` -- none, SE(3) or Sim(3) Umeyama over all or the first ``n``
  positions (evo ``-a``, ``-as``, ``--n_to_align``), or the first pose onto
  the reference's first pose (evo ``--align_origin``); unlike evo, an se3/sim3
  fit on positions that do not move is refused, and on positions along one
  line (2 poses, a straight drive) the rotation about the line, which
  positions leave free, is fitted on the orientations;
- :func:`ate` -- translation errors and rotation angles of ``inv(est) ref``;
- :func:`rpe_pairs`, :func:`rpe` -- evo's consecutive (non-overlapping)
  pairs a frame count or a path length (along the estimate, evo's default)
  apart, error ``inv(inv(Q_i) Q_j) inv(P_i) P_j``;
- :func:`kitti_drift` -- the KITTI odometry devkit's segment errors: path
  lengths 100..800 m measured on the reference, start frames every 10,
  translation error in % and rotation error in deg per 100 m.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from graphslam.evaluation.alignment import STILL_TOL, collinear, principal_spreads, rotation_about_line
from graphslam.evaluation.matching import checked_poses
from graphslam.evaluation.spatial import align_umeyama
from slamcore.errors import ConfigError, GraphSlamError
from slamcore.spatial.geometry import invert_pose

ALIGN_METHODS = ("none", "se3", "sim3", "first")
DELTA_UNITS = ("frames", "m")
#: evo's defaults for timestamp association.
DEFAULT_MAX_DIFF_S = 0.01
DEFAULT_OFFSET_S = 0.0
#: KITTI devkit (evaluate_odometry.cpp): segment lengths and start-frame step.
KITTI_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
KITTI_STEP_FRAMES = 10


@dataclass(frozen=True)
class EvalOptions:
    """How two trajectories are compared (every value checked here).

    Attributes:
        align: ``none``, ``se3``, ``sim3`` or ``first`` (first pose onto first pose).
        n_align: se3/sim3 fit on the first ``n_align`` matched poses (None: all).
        max_diff_s: largest time difference of an associated pair, seconds.
        offset_s: added to the estimate's stamps before association, seconds.
        delta, delta_unit: RPE step, in frames (an integer) or metres of path.
    """

    align: str = "se3"
    n_align: int | None = None
    max_diff_s: float = DEFAULT_MAX_DIFF_S
    offset_s: float = DEFAULT_OFFSET_S
    delta: float = 1
    delta_unit: str = "frames"

    def __post_init__(self):
        if self.align not in ALIGN_METHODS:
            raise ConfigError(f"--align must be one of {', '.join(ALIGN_METHODS)}, got {self.align!r}")
        n_align = self.n_align
        if n_align is not None and (isinstance(n_align, bool) or not isinstance(n_align, (int, np.integer))):
            raise ConfigError(f"--n-align must be a whole number of poses, got {n_align!r}")  # 3.5 was taken
        # 2 positions always lie on one line: the rotation about it is not determined
        if n_align is not None and (n_align < 3 or self.align not in ("se3", "sim3")):
            raise ConfigError("--n-align needs --align se3 or sim3 and at least 3 poses")
        for flag, value in (
            ("--max-diff", self.max_diff_s),
            ("--offset", self.offset_s),
            ("--delta", self.delta),
        ):
            # a string or None reached np.isfinite's TypeError (twentieth hostile pass)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise ConfigError(f"{flag} must be a number, got {value!r}")
        if not (np.isfinite(self.max_diff_s) and self.max_diff_s >= 0):
            raise ConfigError(f"--max-diff must be >= 0 seconds, got {self.max_diff_s}")
        if not np.isfinite(self.offset_s):
            raise ConfigError(f"--offset must be finite, got {self.offset_s}")
        if self.delta_unit not in DELTA_UNITS:
            raise ConfigError(f"--delta-unit must be frames or m, got {self.delta_unit!r}")
        if not (np.isfinite(self.delta) and self.delta > 0):
            raise ConfigError(f"--delta must be > 0, got {self.delta}")
        if self.delta_unit == "frames" and float(self.delta) != int(self.delta):
            raise ConfigError(f"--delta in frames must be a whole number, got {self.delta}")

    def to_dict(self) -> dict:
        return asdict(self)


def _nearest(short_t: np.ndarray, long_t: np.ndarray, max_diff: float) -> tuple[list, list]:
    """evo ``matching_time_indices``: per short stamp the nearest long one (ties earlier)."""
    i_short, i_long = [], []
    if np.all(np.diff(long_t) >= 0):
        for i, t in enumerate(short_t):
            if t < long_t[0] - max_diff or t > long_t[-1] + max_diff:
                continue
            j = min(int(np.searchsorted(long_t, t, side="right")), len(long_t) - 1)
            ub = long_t[j] - t
            lb = t - long_t[j - 1] if j > 0 else np.inf
            if ub <= max_diff and ub < lb:
                best = j
            elif lb <= max_diff and lb <= ub:
                best = j - 1
            else:
                continue
            i_short.append(i)
            i_long.append(best)
        return i_short, i_long
    for i, t in enumerate(short_t):  # unsorted: linear search, as evo does
        d = np.abs(long_t - t)
        j = int(np.argmin(d))
        if d[j] <= max_diff:
            i_short.append(i)
            i_long.append(j)
    return i_short, i_long


def associate(
    ref_t: np.ndarray,
    est_t: np.ndarray,
    max_diff: float = DEFAULT_MAX_DIFF_S,
    offset: float = DEFAULT_OFFSET_S,
) -> tuple[np.ndarray, np.ndarray]:
    """``(ref_rows, est_rows)`` of associated poses (module doc); GraphSlamError if none."""
    ref_t = np.asarray(ref_t, dtype=np.float64)
    est_t = np.asarray(est_t, dtype=np.float64)
    if len(est_t) > len(ref_t):
        i_ref, i_est = _nearest(ref_t, est_t + offset, max_diff)
    else:
        i_est, i_ref = _nearest(est_t, ref_t - offset, max_diff)
    if not i_ref:
        raise GraphSlamError(
            f"no timestamps match within {max_diff} s (offset {offset} s): the reference's stamps run "
            f"from {_span(ref_t)}, the estimate's from {_span(est_t)}{_unit_hint(ref_t, est_t)}"
        )
    return np.asarray(i_ref, dtype=np.int64), np.asarray(i_est, dtype=np.int64)


#: Stamps beyond this many seconds (3 000 years) are not seconds: milliseconds,
#: microseconds or nanoseconds since 1970 (1.7e12, 1.7e15, 1.7e18) read as seconds.
STAMP_MAX_S = 1e11


def _span(t: np.ndarray) -> str:
    return f"{float(np.min(t)):.12g} to {float(np.max(t)):.12g}" if t.size else "(none)"


#: Ratios of two files' time spans read as a unit mix-up (within :data:`SPAN_UNIT_TOL`):
#: seconds against milliseconds, microseconds or nanoseconds counted from a start.
SPAN_UNITS = {1e3: "milliseconds", 1e6: "microseconds", 1e9: "nanoseconds"}
SPAN_UNIT_TOL = 0.02


def span_unit_doubt(ref_t: np.ndarray, est_t: np.ndarray) -> str:
    """A sentence when one file's stamps span about 1e3, 1e6 or 1e9 times the other's
    (both cover the same run, one not in seconds), else ''."""
    spans = {"reference": float(np.ptp(ref_t)) if ref_t.size else 0.0}
    spans["estimate"] = float(np.ptp(est_t)) if est_t.size else 0.0
    if min(spans.values()) <= 0:
        return ""
    (who, big), (_, small) = sorted(spans.items(), key=lambda kv: -kv[1])
    for ratio, unit in SPAN_UNITS.items():
        if abs(big / small / ratio - 1.0) < SPAN_UNIT_TOL:
            return (
                f"the {who}'s stamps span {big:.4g}, {big / small:.4g} times the other file's "
                f"{small:.4g}: {unit}? Both are read as seconds"
            )
    return ""


def _unit_hint(*stamps: np.ndarray) -> str:
    """A clause naming stamps too large to be seconds, or spans in another unit, or ''."""
    big = [t for t in stamps if t.size and float(np.max(np.abs(t))) > STAMP_MAX_S]
    if not big:
        said = span_unit_doubt(*stamps) if len(stamps) == 2 else ""
        return f" ({said})" if said else ""
    return (
        f" (stamps over {STAMP_MAX_S:.0e} are not seconds: nanoseconds, as EuRoC writes them, "
        "belong in an EuRoC CSV or divided by 1e9 in a TUM file)"
    )


def on_one_line(points: np.ndarray, what: str, method: str) -> bool:
    """Whether an SE(3)/Sim(3) fit on ``points`` (k, 3) leaves a rotation free
    (:func:`.alignment.collinear`). GraphSlamError when the positions do not move at
    all: then there is no rotation to fit (and a Sim(3) scale of 0)."""
    spread = principal_spreads(points)
    scale = max(1.0, float(np.max(np.abs(points))))
    if spread[0] <= STILL_TOL * scale:
        raise GraphSlamError(
            f"the {what} does not move (its {len(points)} matched positions "
            f"are within {spread[0]:.1e} m of their mean): --align {method} "
            "has nothing to fit; use --align first (first pose onto first "
            "pose) or --align none"
        )
    return collinear(points, spread)


def align(ref: np.ndarray, est: np.ndarray, method: str, n: int | None = None) -> tuple[np.ndarray, float]:
    """``(aligned estimate (N, 4, 4), scale)``: ``T @ est`` with positions scaled first.
    Positions on one line leave the rotation about it free: that angle is then
    fitted on the orientations (:func:`.alignment.rotation_about_line`); positions that do not move
    are a GraphSlamError."""
    est = np.array(est, dtype=np.float64)
    if method == "none":
        return est, 1.0
    if method == "first":
        if np.array_equal(est, ref):  # the reference itself: no rounding residue, an ATE of 0
            return est, 1.0
        T = ref[0] @ invert_pose(est[0])
        return T @ est, 1.0
    k = len(est) if n is None else min(int(n), len(est))
    if method == "sim3" and k < 3:
        # two points and a Sim(3) (7 parameters) always fit exactly: the error would read 0
        raise GraphSlamError(
            f"--align sim3 on {k} matched poses fits them exactly (an ATE of 0 whatever the "
            "estimate); it needs at least 3: use --align se3 or first"
        )
    line = on_one_line(ref[:k, :3, 3], "reference", method)
    line = on_one_line(est[:k, :3, 3], "estimate", method) or line
    if np.array_equal(est[:k], ref[:k]):  # the fit is the identity: an ATE of 0, not 1e-15
        return est, 1.0
    s, R, t = align_umeyama(est[:k, :3, 3], ref[:k, :3, 3], with_scale=method == "sim3")
    est[:, :3, 3] *= s
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    aligned = T @ est
    if line:
        aligned = rotation_about_line(ref[:k], aligned[:k]) @ aligned
    return aligned, float(s)


def rotation_angles_deg(R: np.ndarray) -> np.ndarray:
    """(N,) angles of (N, 3, 3) rotations, degrees (through the quaternion, as evo)."""
    from scipy.spatial.transform import Rotation  # lazy: the parser imports this module

    return np.degrees(Rotation.from_matrix(np.asarray(R).reshape(-1, 3, 3)).magnitude())


# invert_pose is the rigid inverse [R^T, -R^T t] evo takes: file rotations, rounded to a
# few digits, are orthonormal only to ~1e-7, so np.linalg.inv would differ.
def _relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``inv(a) @ b`` row by row (rigid inverse, as evo)."""
    return invert_pose(a) @ b


def ate(ref: np.ndarray, est: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose ``(translation error m, rotation error deg)`` of aligned, matched poses."""
    trans = np.linalg.norm(est[:, :3, 3] - ref[:, :3, 3], axis=1)
    rot = rotation_angles_deg(_relative(est, ref)[:, :3, :3])
    return trans, rot


def rpe_pairs(poses: np.ndarray, delta: float, unit: str) -> list[tuple[int, int]]:
    """evo's consecutive pairs ``delta`` frames, or ``delta`` metres of path, apart."""
    if unit == "frames":
        ids = np.arange(0, len(poses), int(delta))
        return [(int(i), int(j)) for i, j in zip(ids, ids[1:], strict=False)]
    kept, travelled = [0], 0.0
    for i in range(1, len(poses)):
        travelled += float(np.linalg.norm(poses[i, :3, 3] - poses[i - 1, :3, 3]))
        if travelled >= delta:
            kept.append(i)
            travelled = 0.0
    return list(zip(kept, kept[1:], strict=False))


def rpe(ref: np.ndarray, est: np.ndarray, pairs: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """Per-pair ``(translation error m, rotation error deg)``."""
    if not pairs:
        return np.zeros(0), np.zeros(0)
    i, j = np.array(pairs).T
    err = _relative(_relative(ref[i], ref[j]), _relative(est[i], est[j]))
    return np.linalg.norm(err[:, :3, 3], axis=1), rotation_angles_deg(err[:, :3, :3])


def kitti_drift(ref: np.ndarray, est: np.ndarray) -> tuple[float | None, float | None]:
    """``(translation error %, rotation error deg/100 m)`` averaged over every segment.

    As ``calcSequenceErrors`` of the KITTI devkit: for each start frame
    (every :data:`KITTI_STEP_FRAMES`) and each length, the segment ends at the
    first frame whose reference path distance exceeds the start's by the
    length; error pose ``inv(inv(E_a) E_b) inv(G_a) G_b``; translation error
    and rotation angle (``acos`` of the trace form, the devkit's) divided by
    the length. (None, None) when the path is shorter than 100 m.
    """
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ref[:, :3, 3], axis=0), axis=1))])
    # every (start, length) segment in the devkit's order; the path distance never
    # decreases, so each end is a binary search (a scan of the rest of the path per
    # segment made a 250 000-pose file take 28 s here and a million poses, hours)
    lengths = np.asarray(KITTI_LENGTHS_M, dtype=np.float64)
    first = np.repeat(np.arange(0, len(ref), KITTI_STEP_FRAMES), len(lengths))
    length = np.tile(lengths, len(first) // len(lengths))
    last = np.searchsorted(dist, dist[first] + length, side="right")
    keep = last < len(ref)
    first, last, length = first[keep], last[keep], length[keep]
    if not len(first):
        return None, None
    # the devkit inverts with a general matrix inverse
    inv = np.linalg.inv
    e = inv(inv(est[first]) @ est[last]) @ (inv(ref[first]) @ ref[last])
    d = 0.5 * (e[:, 0, 0] + e[:, 1, 1] + e[:, 2, 2] - 1.0)
    r_err = np.arccos(np.clip(d, -1.0, 1.0)) / length
    t_err = np.linalg.norm(e[:, :3, 3], axis=1) / length
    return 100.0 * float(np.mean(t_err)), float(np.degrees(np.mean(r_err)) * 100.0)


def _rmse(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(x**2))) if x.size else None


@dataclass
class TrajectoryEval:
    """One estimate scored against the reference; arrays are kept for plots.

    Attributes:
        ref, est: (N, 4, 4) matched reference and aligned estimate poses.
        stamps_s: (N,) the reference's stamps (or frame indices) of the matches.
        ate_trans_m, ate_rot_deg: (N,) per-pose errors.
        rpe_trans_m, rpe_rot_deg: per-pair errors.
        reference_poses, estimate_poses: poses in each trajectory before association
            (the matched count is ``len(ref)``).
        est_matched: (N, 4, 4) the matched estimate poses before alignment (None when
            not kept), for :mod:`.trajectory_doubts`.
        shared_matches: matched pairs whose reference or estimate pose is also in
            another pair (evo's association allows it; a wide ``--max-diff`` does it).
        reference_share: the matches' time span over the reference's: how much of the
            reference the ATE covers (None when paired by index: its own doubt says so).
    """

    ref: np.ndarray
    est: np.ndarray
    stamps_s: np.ndarray
    scale: float
    ate_trans_m: np.ndarray
    ate_rot_deg: np.ndarray
    rpe_trans_m: np.ndarray
    rpe_rot_deg: np.ndarray
    kitti_pct: float | None
    kitti_deg_per_100m: float | None
    reference_poses: int
    estimate_poses: int
    est_matched: np.ndarray | None = None
    shared_matches: int = 0
    reference_share: float | None = None

    @property
    def matched_share(self) -> float:
        """Matched poses over the estimate's: how much of the estimate the ATE covers."""
        return len(self.ref) / self.estimate_poses

    def summary(self) -> dict:
        """The numbers of ``eval.json`` (None where not computable)."""
        e = self.ate_trans_m
        return {
            "ate_rmse_m": _rmse(e),
            "ate_mean_m": float(np.mean(e)),
            "ate_median_m": float(np.median(e)),
            "ate_max_m": float(np.max(e)),
            "ate_rot_rmse_deg": _rmse(self.ate_rot_deg),
            "rpe_trans_rmse_m": _rmse(self.rpe_trans_m),
            "rpe_rot_rmse_deg": _rmse(self.rpe_rot_deg),
            "rpe_pairs": int(self.rpe_trans_m.size),
            "kitti_drift_pct": self.kitti_pct,
            "kitti_drift_deg_per_100m": self.kitti_deg_per_100m,
            "matched_poses": int(len(self.ref)),
            "estimate_poses": self.estimate_poses,
            "reference_poses": self.reference_poses,
            "matched_share": self.matched_share,
            "reference_share": self.reference_share,
            "scale": self.scale,
        }


def _stamps(stamps, what: str) -> np.ndarray | None:
    """``stamps`` as (N,) float64 seconds (None stays None), or GraphSlamError: a 2-D,
    boolean, text or scalar array ended in numpy's errors (twentieth hostile pass)."""
    if stamps is None:
        return None
    a = np.asarray(stamps)
    if a.ndim != 1 or a.dtype.kind not in "iuf":
        raise GraphSlamError(f"the {what}'s stamps must be (N,) numbers, got {a.dtype} of shape {a.shape}")
    return a.astype(np.float64)


def _count(stamps, poses) -> int:
    """How many poses ``stamps`` stand for (all of ``poses`` when there are none)."""
    return len(poses) if stamps is None else int(np.size(stamps))


def evaluate(ref_t, ref_wTc, est_t, est_wTc, options: EvalOptions) -> TrajectoryEval:
    """Associate, align and score (module doc). A stamp array of None pairs by index.

    Raises:
        GraphSlamError: poses not one per stamp, not finite (a NaN failed the SVD of the
            fit), or not rigid (a scaled rotation was scored); no stamps matched.
    """
    # the checks the planar and spatial ATE/RPE apply (common_poses), one pose per stamp
    ref_t, est_t = _stamps(ref_t, "reference"), _stamps(est_t, "estimate")
    ref_wTc = checked_poses(ref_wTc, (4, 4), _count(ref_t, ref_wTc), "reference", "stamps")
    est_wTc = checked_poses(est_wTc, (4, 4), _count(est_t, est_wTc), "estimate", "stamps")
    if ref_t is None and est_t is None:
        n = min(len(ref_wTc), len(est_wTc))
        i_ref = i_est = np.arange(n)
        stamps = np.arange(n, dtype=np.float64)
    elif ref_t is None or est_t is None:
        raise GraphSlamError(
            "one trajectory has timestamps and the other has none (KITTI): give its times file with --times"
        )
    else:
        i_ref, i_est = associate(ref_t, est_t, options.max_diff_s, options.offset_s)
        stamps = np.asarray(ref_t, dtype=np.float64)[i_ref]
    ref, est = ref_wTc[i_ref], est_wTc[i_est]
    if len(ref) < 2:
        hint = "" if ref_t is None or est_t is None else _unit_hint(np.asarray(ref_t), np.asarray(est_t))
        raise GraphSlamError(f"only {len(ref)} matched pose(s); at least 2 are needed{hint}")
    matched = est
    est, scale = align(ref, est, options.align, options.n_align)
    ate_t, ate_r = ate(ref, est)
    rpe_t, rpe_r = rpe(ref, est, rpe_pairs(est, options.delta, options.delta_unit))
    pct, deg = kitti_drift(ref, est)
    # a pose of either side paired twice (a --max-diff wider than the gaps between stamps)
    shared = len(i_ref) - min(np.unique(i_ref).size, np.unique(i_est).size)
    return TrajectoryEval(
        ref,
        est,
        stamps,
        scale,
        ate_t,
        ate_r,
        rpe_t,
        rpe_r,
        pct,
        deg,
        len(ref_wTc),
        len(est_wTc),
        est_matched=matched,
        shared_matches=int(shared),
        reference_share=_reference_share(ref_t, stamps),
    )


def _reference_share(ref_t, stamps: np.ndarray) -> float | None:
    """The matches' time span over the reference's (None when paired by index): a
    100-pose run scored against an hour of truth covers little of it."""
    if ref_t is None:
        return None
    whole = float(np.max(ref_t) - np.min(ref_t))
    return 1.0 if whole <= 0 else float(np.ptp(stamps)) / whole
