"""What makes a trajectory score doubtful: likely unit, convention and clock mix-ups
(numpy, scipy). Each check returns sentences; ``graphslam eval`` prints them as
warnings and keeps them in ``eval.json``. None fires on an honest estimate of the
reference, metric (``--align se3``) or monocular (``--align sim3``):

- :func:`size_doubt` -- under se3/first/none, an estimate whose positions spread
  :data:`SIZE_RATIO` times more or less than the reference's (millimetres against
  metres, a monocular estimate): the size error, not the estimate's, fills the ATE;
  under sim3, a fitted scale of about 1e-3, 1e-2 or 1e3: millimetres, centimetres
  or kilometres scored against metres, which the scale hides;
- :func:`absurd_doubts` -- an ATE RMSE over :data:`ABSURD_ATE_SHARE` of the
  reference's spread (the estimate hardly follows it), with what explains it when
  something does: the poses inverted (world-to-camera for camera-to-world);
- :func:`quaternion_doubt` -- a rotation error over :data:`ROTATION_DOUBT_DEG`
  that a quaternion read in the other order (``w x y z`` for ``x y z w``) removes;
- :func:`still_doubt` -- an estimate that does not move, scored without a fit;
- :func:`shared_doubt` -- pairs sharing a pose (a ``--max-diff`` wider than the
  gaps between stamps: a pose is scored against one at another time);
- :func:`clock_doubts` -- stamps on two clocks: the files' time spans differ by
  about 1e3, 1e6 or 1e9 (:func:`.trajectory.span_unit_doubt`: one file in
  milliseconds, microseconds or nanoseconds since its start), or a constant
  shift (start to start, or end to end) pairs :data:`CLOCK_GAIN_SHARE` more
  of the estimate's poses than ``--offset`` does.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from graphslam.evaluation.alignment import STILL_TOL, principal_spreads
from graphslam.evaluation.spatial import path_length
from graphslam.evaluation.trajectory import (
    EvalOptions,
    TrajectoryEval,
    align,
    associate,
    ate,
    span_unit_doubt,
)
from slamcore.errors import GraphSlamError
from slamcore.spatial.geometry import invert_pose

#: Under se3/first/none, an estimate whose RMS spread about its centre is this many
#: times the reference's, or its inverse, has another size (units, a monocular scale).
SIZE_RATIO = 1.25
#: Sim(3) scales read as a unit mix-up (within :data:`UNIT_SCALE_TOL`): the estimate in
#: millimetres (1e-3), centimetres (1e-2) or kilometres (1e3) against metres.
UNIT_SCALES = {1e-3: "millimetres", 1e-2: "centimetres", 1e3: "kilometres"}
UNIT_SCALE_TOL = 0.02
#: An ATE RMSE over this share of the reference's RMS spread about its centre: the
#: aligned estimate is about as far from the reference as the reference's own extent.
ABSURD_ATE_SHARE = 0.5
#: An explanation is said when it brings the ATE (or rotation error) under this share.
EXPLAINS = 0.25
#: A rotation RMSE (deg) above which the quaternion order is tried, and the one the
#: other order must bring it under to be said.
ROTATION_DOUBT_DEG = 20.0
EXPLAINED_ROTATION_DEG = 10.0
#: An inversion is said when the inverted poses' ATE is under this share of the spread.
EXPLAINED_ATE_SHARE = 0.1
#: A clock offset is said when shifting the estimate's stamps (start to start or end
#: to end) pairs this share of its poses more than ``--offset`` does. A reference that
#: covers part of the estimate gains nothing from a shift; an offset clock gains what it
#: lost.
CLOCK_GAIN_SHARE = 0.25


def _spread(points: np.ndarray) -> float:
    """RMS distance of ``points`` (k, 3) from their centre."""
    return float(np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1))))


def _moves(points: np.ndarray) -> bool:
    return bool(principal_spreads(points)[0] > STILL_TOL * max(1.0, float(np.max(np.abs(points)))))


def size_doubt(r: TrajectoryEval, options: EvalOptions) -> list[str]:
    """The estimate's size against the reference's (module doc)."""
    if len(r.ref) < 3:
        return []
    if options.align == "sim3":
        for unit_scale, unit in UNIT_SCALES.items():
            if abs(r.scale / unit_scale - 1.0) <= UNIT_SCALE_TOL:
                return [
                    f"the Sim(3) fit scales the estimate by {r.scale:.4g}: are its positions in "
                    f"{unit} against the reference's metres? (a metric estimate's scale is about 1)"
                ]
        return []
    ref_p, est_p = r.ref[:, :3, 3], r.est[:, :3, 3]
    if not (_moves(ref_p) and _moves(est_p)):
        return []
    ratio = _spread(est_p) / _spread(ref_p)
    if 1.0 / SIZE_RATIO <= ratio <= SIZE_RATIO:
        return []
    unit = next(
        (f" ({u} against metres?)" for s, u in UNIT_SCALES.items() if abs(ratio * s - 1.0) <= UNIT_SCALE_TOL),
        "",
    )
    return [
        f"the estimate spreads {ratio:.3g} times as far as the reference{unit}: --align "
        f"{options.align} keeps that size, so the ATE measures it; for an estimate of "
        "unknown scale (monocular) use --align sim3"
    ]


def _rescored(ref: np.ndarray, est: np.ndarray, options: EvalOptions) -> tuple[float, float] | None:
    """(ATE RMSE m, rotation RMSE deg) of ``est`` against ``ref`` under ``options``'
    alignment, or None when that alignment refuses them."""
    try:
        aligned, _ = align(ref, est, options.align, options.n_align)
    except GraphSlamError:
        return None
    t, rot = ate(ref, aligned)
    return float(np.sqrt(np.mean(t**2))), float(np.sqrt(np.mean(rot**2)))


def absurd_doubts(r: TrajectoryEval, options: EvalOptions) -> list[str]:
    """An ATE about the reference's own extent, and the inversion that explains it (module doc)."""
    ref_p = r.ref[:, :3, 3]
    if len(r.ref) < 3 or not _moves(ref_p):
        return []
    rmse = float(np.sqrt(np.mean(r.ate_trans_m**2)))
    spread = _spread(ref_p)
    if rmse <= ABSURD_ATE_SHARE * spread:
        return []
    head = (
        f"the ATE RMSE ({rmse:.4g} m) is {100 * rmse / spread:.0f} % of the reference's spread "
        f"about its centre ({spread:.4g} m)"
    )
    few = _few_aligned(r, options, rmse, spread)
    if few is not None:
        return [f"{head}: {few}"]
    out = (
        f"{head}: the estimate hardly follows the reference "
        "(another sequence, another clock, other units or pose convention?)"
    )
    if r.est_matched is not None:
        for what, ref, est in (
            ("the estimate's", r.ref, invert_pose(r.est_matched)),
            ("the reference's", invert_pose(r.ref), r.est_matched),
        ):
            again = _rescored(ref, est, options)
            if again is not None and again[0] < min(EXPLAINS * rmse, EXPLAINED_ATE_SHARE * spread):
                out += (
                    f"; with {what} poses inverted the ATE is {again[0]:.4g} m: is that file "
                    "world-to-camera rather than camera-to-world?"
                )
                break
    return [out]


def _few_aligned(r: TrajectoryEval, options: EvalOptions, rmse: float, spread: float) -> str | None:
    """The cause of an absurd ATE when it is ``--n-align``: the fit on the first few
    poses carried far from them, where a fit on all of them explains the error away
    (an ATE then under :data:`EXPLAINS` of this one and :data:`EXPLAINED_ATE_SHARE` of
    the spread); None otherwise. Without it, ``--n-align 3`` on a good estimate with a
    little noise on its first poses was blamed on another sequence, clock or units."""
    n = options.n_align
    if n is None or r.est_matched is None or n >= len(r.ref):
        return None
    again = _rescored(r.ref, r.est_matched, replace(options, n_align=None))
    if again is None or again[0] >= min(EXPLAINS * rmse, EXPLAINED_ATE_SHARE * spread):
        return None
    return (
        f"aligned on its first {n} matched poses only (--n-align), and aligned on all {len(r.ref)} "
        f"the ATE is {again[0]:.4g} m: the fit on so few poses is carried far from them "
        "(a larger --n-align?)"
    )


def _reordered(wTc: np.ndarray, shift: int) -> np.ndarray:
    """``wTc`` with each quaternion's components rotated by ``shift`` places
    (x y z w read from a file written w x y z, or the reverse)."""
    from scipy.spatial.transform import Rotation  # lazy: the parser imports this module

    out = np.array(wTc, dtype=np.float64)
    q = np.roll(Rotation.from_matrix(out[:, :3, :3]).as_quat(), shift, axis=1)
    out[:, :3, :3] = Rotation.from_quat(q).as_matrix()
    return out


def quaternion_doubt(r: TrajectoryEval, options: EvalOptions) -> list[str]:
    """A rotation error that the other quaternion order removes (module doc)."""
    rot = float(np.sqrt(np.mean(r.ate_rot_deg**2)))
    if rot <= ROTATION_DOUBT_DEG or r.est_matched is None:
        return []
    best: tuple[float, str] | None = None
    for who in ("estimate", "reference"):  # the estimate's order first: a tie names it
        # shift -1: a file of w x y z read as x y z w (TUM); +1: x y z w read as w x y z (EuRoC)
        for shift, order in ((-1, "w x y z"), (1, "x y z w")):
            ref = _reordered(r.ref, shift) if who == "reference" else r.ref
            est = _reordered(r.est_matched, shift) if who == "estimate" else r.est_matched
            again = _rescored(ref, est, options)
            if again is not None and (best is None or again[1] < 0.5 * best[0]):
                best = (again[1], f"the {who}'s quaternions read as {order}")
    if best is None or best[0] >= min(EXPLAINS * rot, EXPLAINED_ROTATION_DEG):
        return []
    return [
        f"the rotation error ({rot:.4g} deg RMS) drops to {best[0]:.3g} deg with {best[1]}: "
        "was one file written with the quaternion in the other order? (TUM is t x y z qx qy qz qw, "
        "EuRoC t,x,y,z,qw,qx,qy,qz)"
    ]


def still_doubt(r: TrajectoryEval, options: EvalOptions) -> list[str]:
    """An estimate that does not move, scored with --align none or first (se3 and
    sim3 refuse it)."""
    if options.align in ("se3", "sim3") or len(r.est) < 2 or _moves(r.est[:, :3, 3]):
        return []
    return [
        f"the estimate does not move (its {len(r.est)} matched positions are one point): "
        "its ATE is only the reference's distance from that point"
    ]


def shared_doubt(r: TrajectoryEval, options: EvalOptions) -> list[str]:
    """Pairs sharing a pose (module doc)."""
    if not r.shared_matches:
        return []
    return [
        f"{r.shared_matches} of {len(r.ref)} matched pairs reuse a pose already paired "
        f"(--max-diff {options.max_diff_s:g} s is wider than the gaps between stamps): "
        "those poses are scored against a pose of another time; lower --max-diff"
    ]


def _paired(ref_t: np.ndarray, est_t: np.ndarray, options: EvalOptions, offset_s: float) -> int:
    try:
        return len(associate(ref_t, est_t, options.max_diff_s, offset_s)[0])
    except GraphSlamError:  # nothing pairs at this shift
        return 0


def clock_doubts(
    ref_t: np.ndarray | None, est_t: np.ndarray | None, options: EvalOptions, paired: int
) -> list[str]:
    """Stamps of two clocks or two units (module doc); ``*_t`` (N,) seconds or None;
    ``paired``: the poses the evaluation paired at ``--offset`` (not associated again)."""
    if ref_t is None or est_t is None or len(ref_t) < 2 or len(est_t) < 2:
        return []
    ref_t, est_t = np.asarray(ref_t, np.float64), np.asarray(est_t, np.float64)
    said = span_unit_doubt(ref_t, est_t)
    if said:
        return [said]
    now = paired
    shifts = {float(ref_t.min() - est_t.min()), float(ref_t.max() - est_t.max())}
    tried = [
        (s, _paired(ref_t, est_t, options, s))
        for s in shifts
        if abs(s - options.offset_s) > options.max_diff_s
    ]
    if not tried:
        return []
    shift, best = max(tried, key=lambda sp: sp[1])
    if best - now < CLOCK_GAIN_SHARE * len(est_t):
        return []
    return [
        f"the clocks may differ: shifting the estimate's stamps by {shift:.6g} s pairs {best} of its "
        f"{len(est_t)} poses, against {now} at --offset {options.offset_s:g} s (give --offset if "
        "the shift is right)"
    ]


def rpe_doubt(r: TrajectoryEval, options: EvalOptions) -> list[str]:
    """An RPE of no pair: ``--delta`` longer than the matched trajectory (its columns
    read n/a, unexplained: sixteenth hostile pass)."""
    if len(r.rpe_trans_m) or len(r.est) < 2:
        return []
    if options.delta_unit == "frames":
        span = f"{len(r.est)} matched poses"
    else:  # the pairs follow the aligned estimate's path (rpe_pairs)
        span = f"the estimate's {path_length(r.est):.3g} m of path"
    return [
        f"--delta {options.delta:g} {options.delta_unit} is longer than {span}: no pair is "
        "that far apart, so the RPE is n/a; lower --delta"
    ]


def doubts(r: TrajectoryEval, options: EvalOptions) -> list[str]:
    """The sentences of the checks above; an estimate that does not move is said
    alone, and a size mismatch, which fills the ATE, stands for the absurd ATE."""
    said = still_doubt(r, options)
    if not said:
        said = size_doubt(r, options) or absurd_doubts(r, options)
        said += quaternion_doubt(r, options)
    return shared_doubt(r, options) + said + rpe_doubt(r, options)
