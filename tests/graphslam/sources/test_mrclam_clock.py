"""One robot's clock off the others' under ``--robot all`` (hostile pass 18 left it
open): its three files shifted together pass every one-robot check, and the joint
graph joined its poses to the others' at the wrong instants, unsaid. Cuts of
Dataset 6's first 400 s, robot 3's files shifted."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from graphslam.sources.planar.mrclam import MrclamConfig, read_robot, truth_at, unwrapped, unwrapped_truth_at
from graphslam.sources.planar.mrclam_joint import read_mrclam_all
from tests.graphslam.sources.test_mrclam_fifteenth import cut

#: The offset is named to this, s: the fine grid's step.
OFFSET_TOL_S = 0.1
FILES = ("Odometry", "Measurement", "Groundtruth")


@pytest.fixture(scope="module")
def mrclam(shared_data) -> Path:
    return shared_data / "mrclam6"


def _shifted(mrclam: Path, folder: Path, dt_s: float) -> Path:
    def shift(rows):
        return [[f"{float(r[0]) + dt_s:.3f}", *r[1:]] for r in rows]

    edits = {f"Robot3_{kind}.dat": shift for kind in FILES}
    return cut(mrclam, folder, robots=(1, 2, 3, 4, 5), end_s=400.0, edits=edits)


@pytest.mark.parametrize("dt_s", [5.0, -30.0])
def test_a_robot_whose_files_run_off_the_others_clock_is_named_with_the_offset(mrclam, tmp_path, dt_s):
    (doubt,) = read_mrclam_all(_shifted(mrclam, tmp_path / "s", dt_s), MrclamConfig(all_robots=True)).warnings
    assert doubt.startswith("robot 3: ") and "off the others' clock" in doubt
    named = float(doubt.split("files run ")[1].split(" s off")[0])
    assert abs(named - dt_s) <= OFFSET_TOL_S


def test_an_offset_within_the_sighting_noise_is_not_doubted(mrclam, tmp_path):
    """A second at the robots' speeds moves a pose less than the sightings' noise."""
    assert read_mrclam_all(_shifted(mrclam, tmp_path / "s", 1.0), MrclamConfig(all_robots=True)).warnings == ()


def test_the_truth_unwrapped_once_interpolates_as_np_interp_does(mrclam):
    """The search reads the truth hundreds of times, unwrapped once: the poses of
    np.interp on the unwrapped heading, NaN outside the log and across its gaps
    longer than TRUTH_MAX_GAP_S, and a time at one of its lines exact."""
    from graphslam.sources.planar.mrclam import TRUTH_MAX_GAP_S

    truth = read_robot(mrclam, 3)[2]
    t = truth[:, 0]
    rng = np.random.default_rng(0)
    times = np.concatenate([t[:50], t[-3:], rng.uniform(t[0] - 5.0, t[-1] + 5.0, 2000)])
    got = unwrapped_truth_at(unwrapped(truth), times)
    heading = np.interp(times, t, np.unwrap(truth[:, 3]))
    want = np.column_stack([np.interp(times, t, truth[:, 1]), np.interp(times, t, truth[:, 2]),
                            np.angle(np.exp(1j * heading))])
    k = np.searchsorted(t, times)  # the line at or after each time
    after, before = t[np.clip(k, 0, len(t) - 1)], t[np.clip(k - 1, 0, len(t) - 1)]
    at_line = np.isin(times, t)
    inside = (times >= t[0]) & (times <= t[-1]) & ((after - before <= TRUTH_MAX_GAP_S) | at_line)
    want[~inside] = np.nan
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got[inside], want[inside], atol=1e-12)
    np.testing.assert_array_equal(truth_at(truth, times), got)
    assert np.isnan(got).any() and at_line[:53].all() and np.isfinite(got[:53]).all()
