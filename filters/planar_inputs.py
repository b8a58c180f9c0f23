"""What the 2-D filters (EKF-SLAM, FastSLAM, EKF localisation) accept from a run.

The initial pose is a finite 3-vector with a positive-definite 3x3 covariance.
A filter keeps only its latest pose: an odometry step must link that pose to the
new one (either way round), and a scan must be range-bearing and taken at the
latest pose. The checks are here once so that every filter refuses the same
input with the same message. :func:`mapped_predictions` answers
``predict_observations`` for the EKFs, whose landmarks sit in slots.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

import numpy as np

from slamcore.errors import GraphSlamError, MeasurementError, UnsupportedError
from slamcore.planar import geometry
from slamcore.planar.records import (
    Observation,
    ObservationKind,
    Odometry,
    Prediction,
    as_covariance,
    as_vector,
    checked_id,
)

__all__ = [
    "initial_pose",
    "linked_pose",
    "odometry_step",
    "chain_break",
    "checked_scan",
    "require_odometry",
    "scan_list",
    "mapped_predictions",
]


def initial_pose(
    pose_id: int, wTb: np.ndarray, covariance: np.ndarray, what: str
) -> tuple[int, np.ndarray, np.ndarray]:
    """``(pose_id, wTb (3,), covariance (3, 3))`` given to
    :meth:`slamcore.planar.backend.Backend.initialize`: the id as an int (the records'
    id rule, :func:`~slamcore.planar.records.checked_id`), the pose and covariance as
    read-only float64 arrays.

    Raises:
        MeasurementError: an id that is not an integer (2.7 became pose 2, "5" pose 5),
            not 3 finite values, or not a symmetric positive-definite 3x3 (messages
            start with ``what``).
    """
    return checked_id(pose_id, what, "pose_id"), as_vector(wTb, 3, what), as_covariance(covariance, 3, what)


def require_odometry(odometry) -> None:
    """MeasurementError unless ``odometry`` is an :class:`Odometry` record: a tuple given
    to ``predict`` was AttributeError: 'tuple' ... 'to_id' on every back end."""
    if not isinstance(odometry, Odometry):
        raise MeasurementError(f"predict takes an Odometry record, got {type(odometry).__name__}")


def linked_pose(odometry: Odometry, pose_id: int) -> int | None:
    """The pose ``odometry`` links the new pose ``pose_id`` to (either way round), or
    None when it does not touch ``pose_id``. With several robots the filters keep each
    robot's latest pose and read from this which one a step extends."""
    require_odometry(odometry)
    if odometry.to_id == pose_id:
        return odometry.from_id
    if odometry.from_id == pose_id:
        return odometry.to_id
    return None


def odometry_step(odometry: Odometry, cur: int, pose_id: int, who: str) -> tuple[np.ndarray, np.ndarray]:
    """``(u (3,), Q (3, 3))``: ``odometry`` as the step from the current pose ``cur`` to
    the new pose ``pose_id``, inverted when it was recorded new -> current.

    Raises:
        GraphSlamError: the odometry links other poses, or ``pose_id`` is ``cur``
            (messages start with ``who``, the filter's name).
    """
    require_odometry(odometry)
    if odometry.from_id == cur and odometry.to_id == pose_id:
        u, Q = odometry.delta, odometry.covariance
    elif odometry.from_id == pose_id and odometry.to_id == cur:
        u, Q = geometry.invert(odometry.delta, odometry.covariance)
    else:
        raise GraphSlamError(
            f"{who}: odometry {odometry.from_id}->{odometry.to_id} does not link the current "
            f"pose {cur} to the new pose {pose_id} (a filter only extends the latest pose)"
        )
    if pose_id == cur:
        raise GraphSlamError(f"{who}: pose {pose_id} is already the current pose")
    return np.asarray(u), np.asarray(Q)


def chain_break(first_id: int, steps: Iterable[tuple[Odometry | None, int]], who: str) -> str | None:
    """The refusal :func:`odometry_step` would raise part way through a run, found before
    it: ``steps`` are ``(odometry, new pose id)`` after the first pose ``first_id``, in
    the order the filter gets them. A step extends a robot's latest pose, or starts a
    robot from the first pose (the filters' several-robot rule), else the run would
    stop there with the work so far lost (a Victoria Park file whose 174th step
    branched from pose 10: 173 steps run, no output, hostile pass 15). None when
    every step links."""
    latest = {int(first_id)}  # each robot's latest pose
    seen = {int(first_id)}
    for odometry, pose_id in steps:
        if odometry is None:
            return f"{who}: pose {pose_id} has no odometry"
        other = linked_pose(odometry, pose_id)
        if pose_id in seen:
            return f"{who}: pose {pose_id} is already in the trajectory; a new pose needs a new id"
        if other in latest:
            latest.discard(other)
        elif other != first_id:
            return (
                f"{who}: odometry {odometry.from_id}->{odometry.to_id} does not link a latest pose "
                f"({', '.join(map(str, sorted(latest)))}) to the new pose {pose_id} (a filter only "
                "extends the latest pose); refused before the run"
            )
        latest.add(int(pose_id))
        seen.add(int(pose_id))
    return None


def checked_scan(
    observations: Iterable[Observation],
    pose_id: int | None,
    who: str,
    range_only_hint: str = "the isam2 back end takes it",
) -> list[Observation]:
    """The scan as a list, refused whole before any of it touches a filter's state: each
    item must be a range-bearing :class:`Observation` taken at the current pose ``pose_id``.
    ``range_only_hint`` is the user's next step for ranges alone (a localiser's differs:
    no back end localises them).

    Raises:
        MeasurementError: not an Observation, or taken at another pose.
        UnsupportedError: another kind of measurement (pixels, ranges only).
    """
    obs = scan_list(observations, who)
    for o in obs:
        if o.kind is not ObservationKind.RANGE_BEARING:
            # the back end that takes ranges alone is named, as the user's next step
            also = f" (range-only data: {range_only_hint})" if o.kind is ObservationKind.RANGE else ""
            raise UnsupportedError(f"{who} handles range-bearing observations only, got {o.kind.value}{also}")
        if o.pose_id != pose_id:
            raise MeasurementError(
                f"{who}: observation from pose {o.pose_id} but the current pose is {pose_id}"
            )
    return obs


def scan_list(observations: Iterable[Observation], who: str) -> list[Observation]:
    """``observations`` as a list of :class:`Observation` (what every back end's
    ``update`` takes first).

    Raises:
        MeasurementError: one Observation instead of a list (Python's TypeError said
            less), not iterable, or an item that is not an Observation.
    """
    if isinstance(observations, Observation):
        raise MeasurementError(f"{who}: update takes a list of observations (a scan), got one Observation")
    try:
        obs = list(observations)
    except TypeError:
        raise MeasurementError(
            f"{who}: update takes a list of observations, got {type(observations).__name__}"
        ) from None
    for o in obs:
        if not isinstance(o, Observation):
            raise MeasurementError(f"{who}: expected Observation, got {type(o).__name__}")
    return obs


def mapped_predictions(
    landmark_ids: Iterable[int],
    slots: Mapping[int, int],
    predict: Callable[[int], tuple[np.ndarray, np.ndarray]],
) -> list[Prediction]:
    """``predict_observations`` of a filter whose landmarks sit in slots: for each of
    ``landmark_ids`` (in that order) that ``slots`` maps to a slot,
    ``Prediction(id, z, S)`` with ``(z, S) = predict(slot)``; ids not mapped are left out."""
    out = []
    for lid in landmark_ids:
        slot = slots.get(int(lid))
        if slot is not None:
            z, S = predict(slot)
            out.append(Prediction(int(lid), z, S))
    return out
