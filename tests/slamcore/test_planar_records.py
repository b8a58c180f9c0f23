"""The 2-D records refuse at construction what no back end can use (slamcore.planar.records)."""

from __future__ import annotations

import numpy as np
import pytest

from slamcore.errors import MeasurementError
from slamcore.planar.records import (
    LoopClosure,
    Observation,
    PoseSighting,
    loop_closure_batch,
    odometry_batch,
    range_batch,
    range_bearing_batch,
)

R = np.eye(2) * 0.01
Q = np.eye(3) * 0.01


@pytest.mark.parametrize("stamp", [float("nan"), float("inf"), "abc", True])
def test_observation_refuses_a_stamp_that_is_no_time(stamp):
    with pytest.raises(MeasurementError, match="stamp_s"):
        Observation(0, 1, [5.0, 0.1], R, stamp_s=stamp)


def test_observation_takes_a_finite_stamp_as_float():
    assert Observation(0, 1, [5.0, 0.1], R, stamp_s=np.float32(2.5)).stamp_s == 2.5
    assert type(Observation(0, 1, [5.0, 0.1], R, stamp_s=3).stamp_s) is float
    assert Observation(0, 1, [5.0, 0.1], R).stamp_s is None


@pytest.mark.parametrize(
    "build",
    [
        lambda: range_bearing_batch([1.5], [7], [[5.0, 0.1]], [R]),
        lambda: range_bearing_batch([1], [7.9], [[5.0, 0.1]], [R]),
        lambda: range_bearing_batch([1], ["x"], [[5.0, 0.1]], [R]),
        lambda: range_batch([2.2], [1], [3.0], [0.01]),
        lambda: odometry_batch([0.6], [1], [[1.0, 0, 0]], [Q]),
        lambda: loop_closure_batch([0], [2**63], [[1.0, 0, 0]], [Q]),
    ],
)
def test_batches_refuse_ids_their_constructors_refuse(build):
    with pytest.raises(MeasurementError, match="row 0: .*must be an integer"):
        build()


@pytest.mark.parametrize("stamps", [[float("nan")], ["abc"], [1.0, 2.0]])
def test_range_bearing_batch_refuses_bad_stamps(stamps):
    with pytest.raises(MeasurementError):
        range_bearing_batch([1], [7], [[5.0, 0.1]], [R], stamps_s=stamps)


def test_batches_keep_whole_ids_and_stamps():
    obs = range_bearing_batch(np.array([1, 2]), [7.0, 8], [[5.0, 0.1]] * 2, [R] * 2, stamps_s=[0.5, 1])
    assert [(o.pose_id, o.landmark_id, o.stamp_s) for o in obs] == [(1, 7, 0.5), (2, 8, 1.0)]
    assert all(type(o.landmark_id) is int for o in obs)
    odo = odometry_batch(range(2), range(1, 3), [[1.0, 0, 0]] * 2, [Q] * 2)
    assert [(o.from_id, o.to_id) for o in odo] == [(0, 1), (1, 2)]


def test_a_pose_tied_to_itself_is_refused():
    with pytest.raises(MeasurementError, match="itself"):
        LoopClosure(1, 1, [0.0, 0, 0], Q)
    with pytest.raises(MeasurementError, match="itself"):
        PoseSighting(1, 1, [1.0, 0.0], R)
    with pytest.raises(MeasurementError, match="itself"):
        loop_closure_batch([0, 3], [2, 3], [[1.0, 0, 0]] * 2, [Q] * 2)
