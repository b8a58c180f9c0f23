"""Checks of an MRCLAM log beyond its lines' syntax, for :mod:`graphslam.sources.planar.mrclam`
(hostile pass on its ids, its odometry and what its sightings lose):

- subjects and barcodes are whole numbers below :data:`ID_LIMIT`, refused naming file and
  line otherwise;
- an odometry log with one time only is refused (nothing to integrate);
- odometry lines repeating a time with another command are counted (the later is held);
- a sighting line written twice is dropped and counted, as a repeated Vicon line is;
  two readings of one barcode at one time are both dropped, with a warning;
- sightings of the robot's own barcode are counted; sightings outside the odometry's span
  are a warning, not a note, when that is all of them or the odometry covers under half
  of their time span (clocks that disagree, a file cut short);
- where the robot has truth, its odometry's turns and forward motions are fitted to the
  truth's: a flipped sign, another robot's log, deg/s or cm/s are a warning.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from slamcore.errors import InputError

#: Subjects and barcodes must be below this (2**31). They become landmark ids: gtsam
#: Symbol indices (56 bits), int64 arrays, the id columns of the outputs and of other
#: tools reading them (int32 fields). A subject of 1e20 overflowed int64 (a traceback),
#: one of 2**56 or more gtsam's Symbol index; 2**31 fits every one of them, and MRCLAM's
#: own barcodes and subjects are two-digit numbers.
ID_LIMIT = 2**31


def is_id(value: float, least: int) -> bool:
    """Whether ``value`` (a finite float of a table) is a whole number from ``least`` to
    :data:`ID_LIMIT` - 1."""
    return least <= value < ID_LIMIT and value == int(value)


def check_one_time(odo: np.ndarray, lines: list[int], path: Path) -> None:
    """InputError naming ``path`` when its odometry ``odo`` (K >= 1, 3), time-ordered, holds
    a single time: its first command would be held over the whole log, unsaid."""
    if odo[-1, 0] != odo[0, 0]:
        return
    held = "one command" if len(odo) == 1 else f"{len(odo)} commands, all at one time"
    raise InputError(
        f"holds {held} (at {odo[0, 0]:.3f} s): the motion cannot be integrated from it "
        "(its command would be held over the whole log); at least two times are needed",
        path,
        lines[0],
    )


def odometry_repeats_note(n: int, odo: np.ndarray) -> list[str]:
    """A note counting robot ``n``'s odometry lines that repeat the time of the line before
    with another command: the later is held (the earlier lasts no time), as
    :func:`~graphslam.sources.planar.mrclam_motion.integrate` holds them."""
    other = (np.diff(odo[:, 0]) == 0) & np.any(odo[1:, 1:] != odo[:-1, 1:], axis=1)
    count = int(other.sum())
    if not count:
        return []
    return [
        f"robot {n}: {count} lines of Robot{n}_Odometry.dat repeat the time of the line before "
        "with another command: the later of each is held (the earlier lasts no time)"
    ]


def drop_repeated_sightings(meas: np.ndarray) -> tuple[np.ndarray, int]:
    """``meas`` (M, 4) without the rows equal to an earlier row (one sighting written
    twice: same time, barcode, range and bearing), in order, and how many."""
    if len(meas) < 2:
        return meas, 0
    _, first = np.unique(meas, axis=0, return_index=True)
    return meas[np.sort(first)], len(meas) - len(first)


def drop_conflicting_sightings(n: int, meas: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """``meas`` (M, 4) without the sightings that share a time and a barcode with another
    (after :func:`drop_repeated_sightings`, so with another range or bearing), and the
    warning counting them. A camera image shows a barcode once: two readings of one
    barcode at one time contradict each other, and neither can be told right (Dataset 6
    holds none; merged or corrupt logs do). Both kept, a back end took two sightings
    of one landmark for independent evidence."""
    if len(meas) < 2:
        return meas, []
    _, inverse, counts = np.unique(meas[:, :2], axis=0, return_inverse=True, return_counts=True)
    clash = counts[inverse.ravel()] > 1
    if not clash.any():
        return meas, []
    return meas[~clash], [
        f"robot {n}: {int(clash.sum())} sightings in Robot{n}_Measurement.dat share their time and "
        "barcode with another of other range or bearing (one image shows a barcode once): all "
        "of them dropped"
    ]


def own_barcode_note(n: int, meas: np.ndarray, own: np.ndarray) -> list[str]:
    """A note counting robot ``n``'s sightings (rows of ``meas`` marked by ``own``) of its
    own barcode, dropped (a camera cannot see its robot)."""
    if not own.any():
        return []
    codes = ", ".join(str(int(c)) for c in sorted(set(meas[own, 1].tolist())))
    return [f"robot {n}: {int(own.sum())} sightings of its own barcode ({codes}) in the whole log dropped"]


#: Share of the sightings' time span the odometry must cover, below which dropping those
#: outside it is a warning, not a note: the run then holds a small part of the log
#: (logs whose clocks disagree, a file cut short). A log cut at its start is not warned
#: of (Dataset 6's robot 1 from 30 s on: 56 % of its sightings dropped, 78 % of their
#: span covered); all sightings dropped always is (the run is odometry only).
OUTSIDE_SPAN_WARN_SHARE = 0.5


def outside_span(
    n: int, times_s: np.ndarray, usable: np.ndarray, start_s: float, end_s: float, odo_end_s: float
) -> tuple[np.ndarray, list[str], list[str]]:
    """Which sightings (times ``times_s`` (M,), those ``usable`` of a known subject other
    than robot ``n``) lie in ``[start_s, end_s]``, and the notes or the warning
    (:data:`OUTSIDE_SPAN_WARN_SHARE`) on those that do not (before the first odometry
    line, after ``end_s``; its last line at ``odo_end_s``)."""
    early = usable & (times_s < start_s)
    late = usable & (times_s > end_s)
    inside = usable & ~early & ~late
    out, total = int(early.sum() + late.sum()), int(usable.sum())
    if not out:
        return inside, [], []
    t0, t1 = float(times_s[usable].min()), float(times_s[usable].max())
    covered = max(0.0, min(end_s, t1) - max(start_s, t0)) / (t1 - t0) if t1 > t0 else 0.0
    if out == total or covered < OUTSIDE_SPAN_WARN_SHARE:
        dropped = (
            f"all {total} of its sightings fall outside its odometry's span and are dropped: robot {n} "
            "runs on odometry alone"
            if out == total
            else f"{out} of its {total} sightings fall outside its odometry's span and are dropped"
        )
        warning = (
            f"robot {n}: {dropped} (sightings {t0:.3f}-{t1:.3f} s, odometry {start_s:.3f}-{odo_end_s:.3f} s, "
            f"covering {100 * covered:.0f} % of theirs; {int(early.sum())} before it, {int(late.sum())} "
            "after): do the logs' clocks disagree, or is a file cut?"
        )
        return inside, [], [warning]
    notes = []
    if early.any():
        notes.append(f"robot {n}: {int(early.sum())} sightings before the first odometry dropped")
    if late.any():  # no motion is known there: holding the last command would invent it
        notes.append(
            f"robot {n}: {int(late.sum())} sightings after its odometry ends dropped (odometry to "
            f"{odo_end_s - start_s:.1f} s into the log, sightings to {times_s[-1] - start_s:.1f} s)"
        )
    return inside, notes, []


#: The odometry is doubted when its turns, or its forward motion, between frames have a
#: cosine with the truth's below this (:func:`_fit`). Measured on Dataset 6, the commands
#: as the reader executes them (lag and scale of its motion model): each robot's whole log
#: 0.96-0.97 for its turns and 0.98 forward, every 30-s window of the five logs at least
#: 0.75 (none doubted, 60-s windows at least 0.85); the next robot's log, its turns -0.04
#: to 0.15. Halfway leaves room for a noisier robot.
ODOMETRY_MIN_CORRELATION = 0.5
#: Beyond this relative error of the scale that best maps the odometry's turns (forward
#: motion) onto the truth's, the odometry is doubted (Dataset 6: 0.96-1.01 for turns,
#: 0.95-1.01 forward). The units a misread log may be in, as the factor the truth's
#: motion is of the log's, are named when the fitted scale is within 10 % of one.
ODOMETRY_SCALE_TOLERANCE = 0.5
TURN_UNITS = {"deg/s": math.pi / 180.0}
SPEED_UNITS = {"cm/s": 0.01, "mm/s": 0.001}
#: Fewest consecutive frame pairs with truth the fit needs, and the least turning (rad)
#: or travel (m) they must hold for the turns (forward motion) to be judged.
ODOMETRY_FIT_MIN_PAIRS, ODOMETRY_FIT_MIN_TURN_RAD, ODOMETRY_FIT_MIN_TRAVEL_M = 20, 1.0, 1.0


def _fit(odo: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """The scale ``s`` minimising ``|s odo - truth|`` and the cosine of the two vectors
    (their correlation about zero, not about their means: a robot driving at one speed
    has forward motions of little spread, and their centred correlation is then noise)."""
    norms = float(np.linalg.norm(odo) * np.linalg.norm(truth))
    if norms == 0.0:
        return math.nan, math.nan
    return float(odo @ truth / (odo @ odo)), float(odo @ truth / norms)


def _motion_doubt(n: int, what: str, scale: float, corr: float, units: dict[str, float]) -> str | None:
    name = f"Robot{n}_Odometry.dat"
    if not (math.isfinite(scale) and math.isfinite(corr)):
        return None
    if corr <= -ODOMETRY_MIN_CORRELATION and abs(scale + 1.0) <= ODOMETRY_SCALE_TOLERANCE:
        return (
            f"robot {n}: {name}'s {what} run opposite to its truth's (cosine {corr:.2f}): "
            "a flipped sign? The estimate rests on this odometry"
        )
    if corr < ODOMETRY_MIN_CORRELATION:
        return (
            f"robot {n}: {name}'s {what} do not follow its truth's (cosine {corr:.2f}, where a "
            "robot's own log gives above 0.9): another robot's odometry, or a truth file not of this "
            "robot? The estimate and its scores rest on them"
        )
    if abs(scale - 1.0) <= ODOMETRY_SCALE_TOLERANCE:
        return None
    unit = next((f" (in {u}?)" for u, f in units.items() if abs(scale / f - 1.0) <= 0.1), "")
    return (
        f"robot {n}: {name}'s {what} are {1.0 / scale:.3g} times its truth's{unit}: the run took them "
        "for the format's m/s and rad/s, and its estimate rests on them"
    )


def odometry_truth_doubt(
    n: int, start_s: np.ndarray, v: np.ndarray, w: np.ndarray, times_s: np.ndarray, wTb_true: np.ndarray
) -> tuple[list[str], bool, tuple[str, ...]]:
    """Doubts on robot ``n``'s odometry, its commands as executed (``start_s, v, w`` (K,):
    :func:`~graphslam.sources.planar.mrclam_motion.held_commands`), from its truth
    ``wTb_true`` (F, 3; NaN rows without) at frame times ``times_s`` (F,): its turns and
    forward motion between consecutive frames, each command held to the next, fitted to the truth's
    (:data:`ODOMETRY_MIN_CORRELATION`, :data:`ODOMETRY_SCALE_TOLERANCE`). A log of
    another robot, one in deg/s or cm/s, or one whose turns have a flipped sign runs
    without a word otherwise: the sightings still fit the truth, so
    :func:`~graphslam.sources.planar.mrclam.truth_sightings_doubt` says nothing.
    Returns the doubts, whether the turns were judged (enough truth and turning), and
    the motions that do not follow the truth at all (``"turns (cosine 0.14)"``: the
    truth or the odometry is another robot's; the sightings tell which)."""
    t = start_s
    # piecewise-linear cumulative integrals: each command holds until the next line
    turned = np.concatenate([[0.0], np.cumsum(w[:-1] * np.diff(t))])
    travelled = np.concatenate([[0.0], np.cumsum(v[:-1] * np.diff(t))])
    inside = (times_s >= t[0]) & (times_s <= t[-1]) & np.isfinite(wTb_true).all(axis=1)
    pair = inside[:-1] & inside[1:]
    if int(pair.sum()) < ODOMETRY_FIT_MIN_PAIRS:
        return [], False, ()
    a, b = wTb_true[:-1][pair], wTb_true[1:][pair]
    d_theta = np.angle(np.exp(1j * (b[:, 2] - a[:, 2])))
    d_xy = b[:, :2] - a[:, :2]
    d_forward = np.cos(a[:, 2]) * d_xy[:, 0] + np.sin(a[:, 2]) * d_xy[:, 1]
    odo_theta = np.diff(np.interp(times_s, t, turned))[pair]
    odo_forward = np.diff(np.interp(times_s, t, travelled))[pair]
    fits = []
    judged = bool(np.abs(d_theta).sum() >= ODOMETRY_FIT_MIN_TURN_RAD)
    if judged:
        fits.append(("turns", *_fit(odo_theta, d_theta), TURN_UNITS))
    if np.abs(d_forward).sum() >= ODOMETRY_FIT_MIN_TRAVEL_M:
        fits.append(("forward motions", *_fit(odo_forward, d_forward), SPEED_UNITS))
    out = [_motion_doubt(n, what, scale, corr, units) for what, scale, corr, units in fits]
    unfollowed = tuple(
        f"{what} (cosine {corr:.2f})"
        for what, scale, corr, _ in fits
        if corr < ODOMETRY_MIN_CORRELATION
        and not (corr <= -ODOMETRY_MIN_CORRELATION and abs(scale + 1.0) <= ODOMETRY_SCALE_TOLERANCE)
    )
    return [d for d in out if d], judged, unfollowed
