"""Trajectories are matched by id only after checking each is one: arrays that are
not trajectories are refused, never reshaped into a score."""

from __future__ import annotations

import numpy as np
import pytest

from graphslam.evaluation import planar, spatial
from slamcore.errors import GraphSlamError

IDS = np.arange(5)
XY_YAW = np.c_[np.arange(5.0), np.zeros(5), np.zeros(5)]
WTC = np.tile(np.eye(4), (5, 1, 1))
WTC[:, 0, 3] = np.arange(5.0)


@pytest.mark.parametrize("call, words", [
    (lambda: planar.ate(IDS, XY_YAW.T.copy(), IDS, XY_YAW), "shape (5, 3)"),
    (lambda: planar.ate([0, 0.5, 1, 1.5, 2], XY_YAW, IDS, XY_YAW), "integers"),
    (lambda: planar.ate([0, 1, 0, 2, 3], XY_YAW, IDS, XY_YAW), "distinct"),
    (lambda: planar.ate(IDS.reshape(5, 1), XY_YAW, IDS, XY_YAW), "one-dimensional"),
    (lambda: planar.rpe(IDS, np.full((5, 3), np.nan), IDS, XY_YAW), "finite"),
    (lambda: planar.rpe(IDS, XY_YAW, IDS, XY_YAW, delta="x"), "whole number"),
    (lambda: planar.rpe(IDS, XY_YAW, IDS, XY_YAW, delta=1.5), "whole number"),
    (lambda: spatial.ate(IDS, np.moveaxis(WTC, 0, 2).copy(), IDS, WTC), "shape (5, 4, 4)"),
    (lambda: spatial.ate(IDS, WTC * 2.0, IDS, WTC), "rigid"),
    (lambda: spatial.ate(IDS, WTC, ["a", "b", "c", "d", "e"], WTC), "integers"),
    (lambda: spatial.rpe(IDS, WTC, IDS, WTC, scale=float("nan")), "scale"),
    (lambda: spatial.rpe(IDS, WTC, IDS, WTC, scale=-1.0), "scale"),
])
def test_what_is_no_trajectory_is_refused(call, words):
    with pytest.raises(GraphSlamError, match=words.replace("(", r"\(").replace(")", r"\)")):
        call()


def test_whole_float_ids_and_unsorted_ids_still_match_by_id():
    order = np.array([3, 0, 4, 1, 2])
    a = planar.ate(IDS.astype(float)[order], XY_YAW[order] + [0.0, 0.1, 0.0], IDS, XY_YAW, align=False)
    assert a["n"] == 5 and a["rmse_m"] == pytest.approx(0.1, abs=1e-12)
    b = spatial.ate(IDS[order], WTC[order], IDS, WTC, alignment="none")
    assert b["n"] == 5 and b["rmse_m"] == 0.0
