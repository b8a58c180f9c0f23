"""Every robot of an MRCLAM data set in one graph (``--robot all``, issue 31 item 4).

Each robot's log becomes frames as for one robot (:func:`.mrclam.robot_track`), with
frames added where it sees another robot and where another robot sees it, so that
both ends of each robot-to-robot sighting are poses. The frames of all robots are
then merged in time order into one stream:

- pose ids are ``robot * POSE_ID_STRIDE + frame``;
- the first frame of the stream anchors the graph with the prior (from the truth);
  every other robot's first frame is linked to it by the truth's relative pose
  with the prior's covariance: **all starts come from the truth** (stated in the
  notes), as the data set's authors do for cooperative localisation;
- a sighting of one robot by another becomes a
  :class:`~slamcore.planar.records.PoseSighting` between the two poses at that
  instant, attached to whichever of the two frames the stream reaches later. The
  camera is the same for robots and landmarks: measured against the truth, the
  robot sightings' residuals (range 0.095 m, bearing 0.0066 rad robust sigma) are
  within the landmark calibration, which is used for both;
- ``Dataset.agents`` names each robot's poses so that each is scored on its own.

Every 2-D back end runs it: iSAM2 (every pose), the EKF as a centralised filter
(every robot's latest pose in its state, :mod:`filters.ekf_slam`) and FastSLAM
(every robot's latest pose in every particle, :mod:`filters.fastslam`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphslam.sources.planar.mrclam import (
    PRIOR_VARIANCE,
    MrclamConfig,
    landmark_observations,
    landmark_truth_note,
    read_robot,
    read_subjects,
    robot_track,
    robots_in,
    sighting_covariances,
    truth_doubts,
    unscored_landmarks,
)
from graphslam.sources.planar.mrclam_clock import clock_doubts
from slamcore.errors import InputError
from slamcore.files import folder_name
from slamcore.planar.geometry import between
from slamcore.planar.records import Dataset, Frame, Odometry, PoseSighting, odometry_batch

#: Pose ids of robot N are ``N * POSE_ID_STRIDE + frame``: far above any frame count
#: of a 15-minute log at a few frames a second, far below gtsam's 2**56 key index.
POSE_ID_STRIDE = 1_000_000


def read_mrclam_all(folder: Path, config: MrclamConfig) -> Dataset:
    """Every robot of the data set in one Dataset (module docstring)."""
    barcodes, landmarks_true = read_subjects(folder)
    robots = robots_in(folder)
    if not robots:
        raise InputError("no RobotN_Odometry.dat here", folder)
    logs = {n: read_robot(folder, n) for n in robots}
    seen_at: dict[int, list[float]] = {n: [] for n in robots}  # times each robot is seen by another
    for n, (odo, meas, _) in logs.items():
        for t, code in meas[:, :2].tolist():
            subject = barcodes.get(int(code), 0)
            if subject in seen_at and subject != n and t >= odo[0, 0]:
                seen_at[subject].append(t)
    tracks = {n: robot_track(config, n, *logs[n], barcodes, np.array(seen_at[n])) for n in robots}
    order = sorted(((t, n, k) for n, tr in tracks.items() for k, t in enumerate(tr.times.tolist())))
    _, anchor_n, _ = order[0]
    notes = [f"robots {', '.join(map(str, robots))} in one graph; all starts from the truth"]
    stray = sorted(
        {p.name for p in folder.glob("Robot*_Odometry.dat")} - {f"Robot{n}_Odometry.dat" for n in robots}
    )
    if stray:  # Robot6: subject 6 is a landmark, and its barcode would be dropped as the robot's own
        notes.append(f"{', '.join(stray)} left out: MRCLAM's robots are subjects 1-5")
    starts = {}
    for n, tr in tracks.items():
        if not np.isfinite(tr.wTb_true[0]).all():
            missing = not (folder / f"Robot{n}_Groundtruth.dat").is_file()
            raise InputError(
                f"robot {n} has no truth at its first frame"
                + (f" (no Robot{n}_Groundtruth.dat)" if missing else "")
                + ": --robot all takes every robot's start from the truth",
                folder,
            )
        starts[n] = tr.wTb_true[0]
        notes.extend(tr.notes)
    position = {(n, k): i for i, (_, n, k) in enumerate(order)}
    sightings, unmatched = _sightings(tracks, config, position)
    observations = {
        n: landmark_observations(tr, config, lambda k, n=n: n * POSE_ID_STRIDE + k, n)
        for n, tr in tracks.items()
    }
    steps = {
        n: odometry_batch(
            [n * POSE_ID_STRIDE + k for k in range(len(tr.times) - 1)],
            [n * POSE_ID_STRIDE + k for k in range(1, len(tr.times))],
            tr.deltas,
            tr.covariances,
        )
        for n, tr in tracks.items()
    }
    frames = []
    for _, n, k in order:
        tr = tracks[n]
        pid = n * POSE_ID_STRIDE + k
        if k > 0:
            odometry = steps[n][k - 1]
        elif n != anchor_n:
            odometry = Odometry(
                anchor_n * POSE_ID_STRIDE,
                pid,
                between(starts[anchor_n], starts[n]),
                np.eye(3) * PRIOR_VARIANCE,
            )
        else:
            odometry = None
        seen = tuple(observations[n].get(k, ()))
        has_truth = np.isfinite(tr.wTb_true[k]).all()
        frames.append(
            Frame(
                pose_id=pid,
                stamp_s=float(tr.times[k]),
                odometry=odometry,
                observations=seen,
                true_landmark_ids=tuple(o.landmark_id for o in seen),
                wTb_true=tr.wTb_true[k].copy() if has_truth else None,
                pose_sightings=tuple(sightings.get(position[(n, k)], ())),
            )
        )
    agents = tuple(
        (f"robot {n}", tuple(n * POSE_ID_STRIDE + k for k in range(len(tr.times))))
        for n, tr in tracks.items()
    )
    notes.append(f"{sum(len(v) for v in sightings.values())} sightings of one robot by another")
    notes.extend(unmatched)
    # one robot's files that are not of one robot spoil the joint graph as much
    doubts = {n: truth_doubts(config, n, tr, landmarks_true) for n, tr in tracks.items()}
    warnings = tuple(w for tr in tracks.values() for w in tr.warnings) + tuple(sum(doubts.values(), []))
    # one robot's clock off the others': judged on the robots whose own files agree with their truth
    warnings += tuple(clock_doubts(config, logs, barcodes, judged=[n for n, d in doubts.items() if not d]))
    if not landmarks_true:
        notes.append(landmark_truth_note(folder))
    notes.extend(unscored_landmarks(frames, landmarks_true))
    return Dataset(
        name=f"{folder_name(folder)}-all",
        frames=frames,
        prior_wTb=starts[anchor_n],
        prior_covariance=np.eye(3) * PRIOR_VARIANCE,
        landmarks_true=landmarks_true or None,
        has_timestamps=True,
        source_path=str(folder),
        notes=tuple(notes),
        agents=agents,
        sensor_field=config.sensor_field(),
        warnings=warnings,
    )


def _sightings(tracks: dict, config: MrclamConfig, position: dict) -> tuple[dict[int, list], list[str]]:
    """Robot-to-robot sightings by the stream position of the later of their two frames,
    and a note on those left out: of a robot without a log here, or outside the seen
    robot's odometry (no pose of it then)."""
    out: dict[int, list] = {}
    no_log: dict[int, int] = {}
    outside = 0
    for n, tr in tracks.items():
        for k, subject, z, t in tr.robot_sightings:
            if subject not in tracks:
                no_log[subject] = no_log.get(subject, 0) + 1
                continue
            other = tracks[subject].times
            j = int(np.searchsorted(other, t))
            if j >= len(other) or other[j] != t:
                outside += 1
                continue
            sighting = PoseSighting(
                n * POSE_ID_STRIDE + k, subject * POSE_ID_STRIDE + j, z, sighting_covariances(config, z)[0]
            )
            later = max(position[(n, k)], position[(subject, j)])
            out.setdefault(later, []).append(sighting)
    notes = [
        f"{count} sightings of robot {r} left out: no Robot{r}_Odometry.dat here"
        for r, count in sorted(no_log.items())
    ]
    if outside:
        notes.append(
            f"{outside} sightings of a robot outside its odometry's span left out (no pose of it then)"
        )
    return out, notes
