"""One robot's clock off the others' under ``--robot all``, told from the truth.

A robot whose three files share a clock offset from the other robots' (a log
written on a machine whose clock was set apart) passes every check of one robot:
its odometry follows its truth and its sightings of landmarks fit it, all in its
own clock. In one graph its sightings of the others, and theirs of it, join two
poses at different instants, unsaid. Against the truth those sightings miss where
the others' among themselves fit; shifting the robot's clock by the offset makes
them fit again, which names the offset.

Measured on Dataset 6 (``python -m graphslam.sources.planar.mrclam_clock``
prints it): each robot's 1186-1894 robot-to-robot sightings leave 0.0-0.3 % beyond the
sighting model's quantile (:data:`~.mrclam.SIGHTING_MISS_PROBABILITY`); robot 3's
files shifted by 5 s leave 40 % of its sightings beyond it (50 % in the first
400 s), the other robots'
among themselves 0.1 %, and a shift under about 2 s is within the sighting noise
at the robots' speeds (below 0.3 m/s): there the joint graph is not harmed either.
"""

from __future__ import annotations

import numpy as np

from filters.association import t2_quantile
from graphslam.sources.planar.mrclam import (
    SIGHTING_MISS_PROBABILITY,
    MrclamConfig,
    sighting_covariances,
    unwrapped,
    unwrapped_truth_at,
)
from slamcore.planar import geometry as se2

#: A robot's clock is doubted when more than this share of the robot-to-robot
#: sightings it takes part in miss the truth (Dataset 6: at most 0.3 % for every
#: robot; a 5-s offset: 40-50 %), while those among the other robots stay under
#: :data:`OTHERS_MISS_SHARE` (the others' files are then not the cause).
ROBOT_MISS_SHARE = 0.2
OTHERS_MISS_SHARE = 0.05
#: At least this many sightings with truth at both ends before a robot is judged.
MIN_SIGHTINGS = 20
#: Offsets searched, s: a coarse grid over this span either way, then a fine one
#: about its best (a 2-s offset is within the sightings' noise: the coarse grid
#: steps past no basin).
SEARCH_SPAN_S = 300.0
COARSE_STEP_S = 2.0
FINE_STEP_S = 0.1


def robot_sightings(logs: dict, barcodes: dict[int, int]) -> np.ndarray:
    """(S, 5) rows ``observer, subject, time_s (observer's clock), range_m, bearing_rad``
    of the robot-to-robot sightings between robots whose logs (``logs[n] = (odometry,
    sightings, truth or None)``) both hold truth."""
    rows = []
    for n, (_, meas, truth) in logs.items():
        if truth is None:
            continue
        for t, code, r, b in meas.tolist():
            s = barcodes.get(int(code), 0)
            if s != n and s in logs and logs[s][2] is not None:
                rows.append((n, s, t, r, b))
    return np.array(rows, dtype=np.float64).reshape(-1, 5)


def _d2(config: MrclamConfig, truths: dict, rows: np.ndarray, shift: dict[int, float]) -> tuple:
    """Per sighting: its squared Mahalanobis distance from the truth with robot ``n``'s
    clock ahead of the others' by ``shift[n]`` s, and whether both ends have truth
    then. ``truths[n]``: robot ``n``'s truth, :func:`~.mrclam.unwrapped`."""
    observer, subject = rows[:, 0].astype(int), rows[:, 1].astype(int)
    pose_o = np.full((len(rows), 3), np.nan)
    pose_s = np.full((len(rows), 3), np.nan)
    ahead = np.array([shift.get(o, 0.0) for o in observer.tolist()])
    for n in np.unique(np.concatenate([observer, subject])).tolist():
        i, j = observer == n, subject == n
        pose_o[i] = unwrapped_truth_at(truths[n], rows[i, 2])
        # the subject's clock at the instant the observer's reads t
        pose_s[j] = unwrapped_truth_at(truths[n], rows[j, 2] - ahead[j] + shift.get(n, 0.0))
    valid = np.isfinite(pose_o).all(axis=1) & np.isfinite(pose_s).all(axis=1)
    z = rows[:, 3:5]
    nu = se2.innovation(z, se2.observe(np.nan_to_num(pose_o), np.nan_to_num(pose_s[:, :2])))
    var = np.diagonal(sighting_covariances(config, z), axis1=1, axis2=2)
    return np.sum(nu**2 / var, axis=1), valid


def _miss_d2(config: MrclamConfig) -> float:
    return t2_quantile(1.0 - SIGHTING_MISS_PROBABILITY, config.sighting_error_dof)


def miss_shares(config: MrclamConfig, truths: dict, rows: np.ndarray) -> dict[int, tuple[int, float, float]]:
    """Per robot: ``(sightings it takes part in, their miss share, the others' miss
    share)`` with every clock as written."""
    d2, valid = _d2(config, truths, rows, {})
    miss = d2 > _miss_d2(config)
    out = {}
    for n in truths:
        part = (rows[:, 0] == n) | (rows[:, 1] == n)
        mine, others = part & valid, ~part & valid
        if mine.sum() >= MIN_SIGHTINGS:
            rest = float(miss[others].mean()) if others.sum() >= MIN_SIGHTINGS else 0.0
            out[n] = (int(mine.sum()), float(miss[mine].mean()), rest)
    return out


def _best_shift(config: MrclamConfig, truths: dict, rows: np.ndarray, n: int) -> tuple[float, float]:
    """The offset of robot ``n``'s clock that fits its sightings best, and their miss
    share there. Best by the mean distance clipped at the miss quantile: the miss share
    alone is flat (zero) over a second or more about the offset."""
    mine = rows[(rows[:, 0] == n) | (rows[:, 1] == n)]
    q = _miss_d2(config)

    def cost(dt: float) -> float:
        d2, valid = _d2(config, truths, mine, {n: dt})
        return float(np.minimum(d2[valid], q).mean()) if valid.sum() >= MIN_SIGHTINGS else q

    coarse = np.arange(-SEARCH_SPAN_S, SEARCH_SPAN_S + COARSE_STEP_S / 2, COARSE_STEP_S)
    best = min(coarse.tolist(), key=cost)
    fine = best + np.arange(-COARSE_STEP_S, COARSE_STEP_S + FINE_STEP_S / 2, FINE_STEP_S)
    best = min(fine.tolist(), key=cost)
    d2, valid = _d2(config, truths, mine, {n: best})
    return best, float((d2[valid] > q).mean())


def clock_doubts(
    config: MrclamConfig, logs: dict, barcodes: dict[int, int], judged: list[int] | None = None
) -> list[str]:
    """A warning per robot whose robot-to-robot sightings miss the truth while the
    others' fit (module docstring), naming the clock offset that makes them fit.
    ``judged``: the robots to judge (default all; one whose truth is not its own is
    already said, and its robot sightings miss for that reason)."""
    rows = robot_sightings(logs, barcodes)
    if len(rows) == 0:
        return []
    truths = {n: unwrapped(truth) for n, (_, _, truth) in logs.items() if truth is not None}
    out = []
    for n, (count, share, others) in miss_shares(config, truths, rows).items():
        if (
            share <= ROBOT_MISS_SHARE
            or others > OTHERS_MISS_SHARE
            or (judged is not None and n not in judged)
        ):
            continue
        said = (
            f"robot {n}: {100 * share:.0f} % of the {count} sightings between it and the other robots "
            f"miss the truth, where the others' among themselves {100 * others:.1f} %"
        )
        dt, fitted = _best_shift(config, truths, rows, n)
        if fitted <= OTHERS_MISS_SHARE:
            out.append(
                f"{said}; with {dt:+.1f} s taken off its times they fit ({100 * fitted:.1f} %): robot "
                f"{n}'s files run {dt:+.1f} s off the others' clock, and the joint graph joins its poses "
                "to the others' at the wrong instants (its own run, --robot N, is not affected)"
            )
        else:
            out.append(
                f"{said}, at any clock offset within {SEARCH_SPAN_S:.0f} s: robot {n}'s barcode in "
                "Barcodes.dat, or its files, are not of this data set's robot; the joint graph's "
                "robot-to-robot sightings of it are wrong"
            )
    return out


if __name__ == "__main__":  # the figures of the module docstring
    import sys
    from pathlib import Path

    from graphslam.sources.planar.mrclam import read_robot, read_subjects, robots_in

    folder = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("../shared/data/mrclam6")
    codes, _ = read_subjects(folder)
    logs = {n: read_robot(folder, n) for n in robots_in(folder)}
    conf = MrclamConfig(all_robots=True)
    truths = {n: unwrapped(truth) for n, (_, _, truth) in logs.items() if truth is not None}
    for n, (count, share, others) in miss_shares(conf, truths, robot_sightings(logs, codes)).items():
        print(f"robot {n}: {count} sightings, {100 * share:.2f} % miss; the others' {100 * others:.2f} %")
    print(*clock_doubts(conf, logs, codes), sep="\n")
