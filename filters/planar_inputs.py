"""What the 2-D filters (EKF-SLAM, FastSLAM, EKF localisation) accept from a run.

A filter keeps only its latest pose: an odometry step must link that pose to the
new one (either way round), and a scan must be range-bearing and taken at the
latest pose. The checks are here once so that every filter refuses the same
input with the same message.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from slamcore.errors import GraphSlamError, MeasurementError, UnsupportedError
from slamcore.planar import geometry
from slamcore.planar.records import Observation, ObservationKind, Odometry

__all__ = ["odometry_step", "checked_scan"]


def odometry_step(odometry: Odometry, cur: int, pose_id: int, who: str) -> tuple[np.ndarray, np.ndarray]:
    """``(u (3,), Q (3, 3))``: ``odometry`` as the step from the current pose ``cur`` to
    the new pose ``pose_id``, inverted when it was recorded new -> current.

    Raises:
        GraphSlamError: the odometry links other poses, or ``pose_id`` is ``cur``
            (messages start with ``who``, the filter's name).
    """
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


def checked_scan(observations: Iterable[Observation], pose_id: int | None, who: str) -> list[Observation]:
    """The scan as a list, refused whole before any of it touches a filter's state: each
    item must be a range-bearing :class:`Observation` taken at the current pose ``pose_id``.

    Raises:
        MeasurementError: not an Observation, or taken at another pose.
        UnsupportedError: another kind of measurement (pixels, ranges only).
    """
    obs = list(observations)
    for o in obs:
        if not isinstance(o, Observation):
            raise MeasurementError(f"{who}: expected Observation, got {type(o).__name__}")
        if o.kind is not ObservationKind.RANGE_BEARING:
            raise UnsupportedError(f"{who} handles range-bearing observations only, got {o.kind.value}")
        if o.pose_id != pose_id:
            raise MeasurementError(
                f"{who}: observation from pose {o.pose_id} but the current pose is {pose_id}"
            )
    return obs
