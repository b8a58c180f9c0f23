"""The UTIAS MRCLAM reader, its odometry integration, the map error, and landmark SLAM on
the real Dataset 6 with Vicon truth (issue 31)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from graphslam import registry
from graphslam.cli.main import main
from graphslam.evaluation.planar import MAP_RECOVERY_RADIUS_M, map_errors
from graphslam.pipelines import planar as pipeline
from graphslam.sources.planar.mrclam import (MIN_MODEL_RANGE_M, MrclamConfig, frame_times,
                                             read_mrclam, sighting_covariances)
from graphslam.sources.planar.mrclam_motion import MotionModel, held_commands, integrate
from slamcore.errors import ConfigError, InputError
from slamcore.planar.records import Estimate

#: Exact arcs: what float64 leaves after a few hundred steps, metres and radians.
ARC_TOL = 1e-9
#: The issue's bound on iSAM2 with known ids, every robot of Dataset 6, metres.
ISAM2_ATE_BOUND_M = 0.12

#: Share of the sightings' ranges beyond 3 model sigma against the truth that the
#: reader's noise model may leave, all five robots (a Gaussian: 0.27 %; the fitted
#: model: 3.1 %, the ranges are quantised and skewed; the old constant sigma: 5.4 %).
RANGE_TAIL_BOUND = 0.04

#: Mean pose NEES of a filter that may be called consistent here (3 is the ideal; the
#: odometry's own check on 5 s windows gives 4.5, benchmarks/calibrate_mrclam.py).
CONSISTENT_NEES_BOUND = 6.0

UNIT = MotionModel(0.0, 1.0, 1.0, *([0.0] * 6))


def _arc(v, w, t):
    if abs(w) < 1e-12:
        return np.array([v * t, 0.0, 0.0])
    return np.array([v / w * math.sin(w * t), v / w * (1 - math.cos(w * t)), w * t])


@pytest.mark.parametrize("v, w", [(0.2, 0.0), (0.1, 0.5), (0.3, -1.2), (0.0, 0.7)])
def test_constant_commands_integrate_to_the_exact_arc(v, w):
    """Uneven command steps of the same (v, w) and frames between them: the unicycle's arc."""
    rng = np.random.default_rng(0)
    t_cmd = np.cumsum(rng.uniform(0.005, 0.03, 300))
    frames = np.array([t_cmd[0], t_cmd[0] + 1.234, t_cmd[0] + 3.0])
    deltas, covs = integrate(*held_commands(t_cmd, np.full(300, v), np.full(300, w), UNIT), frames,
                             UNIT.coefficients())
    for k in range(2):
        np.testing.assert_allclose(deltas[k, :2], _arc(v, w, frames[k + 1] - frames[k])[:2],
                                   atol=ARC_TOL)
        assert abs(math.remainder(deltas[k, 2] - w * (frames[k + 1] - frames[k]), 2 * math.pi)) \
            < ARC_TOL
    assert np.all(covs == 0.0)  # a model without noise adds none


def test_lag_and_scales_apply_as_documented():
    """A command takes effect ``lag_s`` after its stamp, at ``scale`` of its value."""
    t_cmd = np.array([0.0, 1.0, 2.0])
    v, w = np.array([0.0, 0.2, 0.2]), np.zeros(3)
    model = MotionModel(0.5, 0.9, 1.0, *([0.0] * 6))
    deltas, _ = integrate(*held_commands(t_cmd, v, w, model), np.array([0.0, 1.5, 2.5]),
                          model.coefficients())
    # before 1.5 s the 0.2 m/s command of t = 1 s has not yet acted
    np.testing.assert_allclose(deltas[:, 0], [0.0, 0.9 * 0.2 * 1.0], atol=ARC_TOL)


def _path_with_noise(ds, dth, dt, noise):
    """End pose of a path of arcs, each perturbed by ``noise (N, 3)`` = (along, lateral,
    heading) in the arc's mid-heading frame: the model ``integrate`` propagates."""
    x = y = th = 0.0
    for s, a, n in zip(ds, dth, noise):
        lx, ly = (s / a * math.sin(a), s / a * (1 - math.cos(a))) if abs(a) > 1e-12 else (s, 0.0)
        c, si = math.cos(th), math.sin(th)
        x, y = x + c * lx - si * ly, y + si * lx + c * ly
        phi = th + 0.5 * a
        x += math.cos(phi) * n[0] - math.sin(phi) * n[1]
        y += math.sin(phi) * n[0] + math.cos(phi) * n[1]
        th += a + n[2]
    return np.array([x, y, th])


def test_covariance_is_the_first_order_propagation_of_the_step_noise():
    """``integrate``'s covariance equals ``sum J_k Q_k J_k^T`` with the Jacobians of the
    end pose taken by central differences of the perturbed path."""
    rng = np.random.default_rng(1)
    n = 40
    v, w = rng.uniform(0.0, 0.3, n), rng.uniform(-1.0, 1.0, n)
    dt = np.full(n, 0.05)
    t_cmd = np.concatenate([[0.0], np.cumsum(dt)[:-1]])
    model = MotionModel(0.0, 1.0, 1.0, 3e-3, 2e-5, 5e-5, 8e-3, 3e-4, 1e-6)
    _, cov = integrate(*held_commands(t_cmd, v, w, model), np.array([0.0, dt.sum()]),
                       model.coefficients())
    a_s, b_s, a_y, a_t, c_t, b_t = model.coefficients()
    ds, dth = v * dt, w * dt
    q = np.column_stack([a_s * np.abs(ds) + b_s * dt, a_y * np.abs(ds),
                         a_t * np.abs(dth) + c_t * np.abs(ds) + b_t * dt])
    expected = np.zeros((3, 3))
    h = 1e-6
    for k in range(n):
        J = np.zeros((3, 3))
        for j in range(3):
            plus, minus = np.zeros((n, 3)), np.zeros((n, 3))
            plus[k, j], minus[k, j] = h, -h
            J[:, j] = (_path_with_noise(ds, dth, dt, plus) - _path_with_noise(ds, dth, dt, minus)) \
                / (2 * h)
        expected += J @ np.diag(q[k]) @ J.T
    np.testing.assert_allclose(cov[0], expected, rtol=1e-6, atol=1e-12)


def test_frame_times_cover_the_log_with_no_gap_longer_than_asked():
    odo = np.array([10.0, 20.0, 40.0])
    sightings = np.array([12.5, 12.5, 13.0, 39.0])
    t = frame_times(odo, sightings, 1.0)
    assert t[0] == 10.0 and t[-1] == 40.0
    assert set([12.5, 13.0, 39.0]) <= set(t.tolist())
    assert np.all(np.diff(t) > 0) and np.max(np.diff(t)) <= 1.0 + 1e-12


@pytest.fixture(scope="module")
def mrclam(shared_data) -> Path:
    return shared_data / "mrclam6"


def test_sighting_noise_grows_with_range_as_configured():
    """The camera's model: range sigma a + k r in quadrature, bearing b + c / r."""
    cfg = MrclamConfig(sigma_range_m=0.01, sigma_range_per_m=0.04, sigma_bearing_rad=0.007,
                       sigma_bearing_m=0.016)
    R = sighting_covariances(cfg, np.array([[1.0, 0.2], [4.0, -0.1], [0.0, 0.0]]))
    np.testing.assert_allclose(np.sqrt(R[:, 0, 0]), [math.hypot(0.01, 0.04), math.hypot(0.01, 0.16),
                                                     math.hypot(0.01, 0.04 * MIN_MODEL_RANGE_M)])
    np.testing.assert_allclose(np.sqrt(R[:, 1, 1]), [math.hypot(0.007, 0.016),
                                                     math.hypot(0.007, 0.004),
                                                     math.hypot(0.007, 0.016 / MIN_MODEL_RANGE_M)])
    assert np.all(R[:, 0, 1] == 0.0) and np.all(np.isfinite(R))


@pytest.mark.parametrize("zeroed", [("sigma_range_m", "sigma_range_per_m"),
                                    ("sigma_bearing_rad", "sigma_bearing_m")])
def test_a_noiseless_sighting_model_is_refused(zeroed):
    with pytest.raises(ConfigError, match="both 0"):
        MrclamConfig(**{name: 0.0 for name in zeroed})


def test_the_readers_range_noise_fits_the_truth(mrclam):
    """Ranges of the five robots against the Vicon truth, divided by the reader's sigma:
    few beyond 3 (a constant sigma left 5.4 % there: the camera's range error grows
    with range). Pooled, as the calibration is: each robot's camera differs."""
    z, sigma = [], []
    for robot in range(1, 6):
        ds = read_mrclam(mrclam, MrclamConfig(robot=robot))
        for f in ds.frames:
            if f.wTb_true is None or not np.isfinite(f.wTb_true).all():
                continue
            for o in f.observations:
                true_range = np.linalg.norm(ds.landmarks_true[o.landmark_id] - f.wTb_true[:2])
                z.append(o.z[0] - true_range)
                sigma.append(math.sqrt(o.covariance[0, 0]))
    normalised = (np.array(z) - np.median(z)) / np.array(sigma)
    assert len(z) == 15383
    assert np.mean(np.abs(normalised) > 3.0) <= RANGE_TAIL_BOUND
    assert 0.8 <= 1.4826 * np.median(np.abs(normalised)) <= 1.25


def test_sightings_carry_their_time_and_their_cameras_correlation(mrclam):
    """Each sighting is stamped with its frame's time and carries its robot's error
    correlation (one sensor per robot); ``correlation_time_s = 0`` takes them as
    independent."""
    ds = read_mrclam(mrclam, MrclamConfig(robot=2))
    seen = [(f, o) for f in ds.frames for o in f.observations]
    assert seen and all(o.stamp_s == f.stamp_s for f, o in seen)
    model = seen[0][1].correlation
    assert model is not None and model.sensor == 2
    assert model.time_constant_s == MrclamConfig().correlation_time_s
    plain = read_mrclam(mrclam, MrclamConfig(robot=2, correlation_time_s=0.0))
    assert all(o.correlation is None for f in plain.frames for o in f.observations)


def _mean_pose_nees(ds, backend) -> float:
    result = pipeline.run(ds, backend, with_covariances=True)
    est = result.estimate
    ids, truth = ds.ground_truth()
    _, ia, ib = np.intersect1d(est.pose_ids, ids, return_indices=True)
    e = est.wTb[ia] - truth[ib]
    e[:, 2] = (e[:, 2] + math.pi) % (2 * math.pi) - math.pi
    return float(np.mean(np.einsum("ia,iab,ib->i", e, np.linalg.inv(est.pose_covariances[ia]), e)))


@pytest.mark.parametrize("robot", [1, 3])
def test_weighing_correlated_sightings_makes_the_ekf_consistent(mrclam, robot):
    """The EKF with known ids against the Vicon truth: its mean pose NEES (3 when
    consistent) is 10.8 and 10.6 on robots 1 and 3 with the sightings taken as
    independent, 4.4 and 2.7 when each is weighed by what it adds to the earlier ones
    of its landmark (the camera's errors correlate 0.97 within 0.3 s)."""
    with_model = _mean_pose_nees(read_mrclam(mrclam, MrclamConfig(robot=robot)),
                                 registry.make_backend("ekf"))
    independent = _mean_pose_nees(
        read_mrclam(mrclam, MrclamConfig(robot=robot, correlation_time_s=0.0)),
        registry.make_backend("ekf"))
    assert with_model <= CONSISTENT_NEES_BOUND < independent, (with_model, independent)


def test_robot_1_is_read_as_the_data_set_is(mrclam):
    """Counts checked against the files by hand (README of the data): barcode 43 is in no
    row of Barcodes.dat, robot 1's truth ends before its odometry, subjects 6-20 are
    the 15 landmarks."""
    ds = read_mrclam(mrclam, MrclamConfig(robot=1))
    assert ds.name == "mrclam6-robot1" and ds.has_timestamps
    notes = " / ".join(ds.notes)
    assert "1 sightings of barcodes Barcodes.dat does not list (43) in the whole log dropped" in notes
    assert "407 sightings of other robots in the whole log left out" in notes
    assert "truth on 1416 of the whole log's 1545 frames" in notes
    # the one line on its own truth, which a --ground-truth file replaces, is named as such
    (line,) = ds.truth_lines
    assert line in ds.notes and "truth on 1416 " in line
    assert sorted(ds.landmarks_true) == list(range(6, 21))
    seen = [o.landmark_id for f in ds.frames for o in f.observations]
    assert len(seen) == 1534 and set(seen) <= set(range(6, 21))
    stamps = np.array([f.stamp_s for f in ds.frames])
    assert np.all(np.diff(stamps) > 0) and np.max(np.diff(stamps)) <= 1.0 + 1e-9
    np.testing.assert_array_equal(ds.prior_wTb, ds.frames[0].wTb_true)
    ids, wTb = ds.ground_truth()
    assert len(ids) == 1416 and ids[-1] < len(ds.frames) - 1  # scored where truth is


def test_partial_truth_scores_only_where_it_exists(mrclam):
    ds = read_mrclam(mrclam, MrclamConfig(robot=1)).truncated(1500)
    result = pipeline.run(ds, registry.make_backend("ekf"))
    m = pipeline.compute_metrics(result, with_graph_error=False)
    assert m.ate_rmse_m is not None and m.map_rmse_m is not None
    # the ATE says how many poses it covers: those of the 1500 with truth
    assert m.ate_poses == sum(f.wTb_true is not None for f in ds.frames) == 1416
    assert m.dataset_notes[0] == "robot 1"


def _copy(mrclam: Path, tmp_path: Path, robots=(1,)) -> Path:
    folder = tmp_path / "mrclam"
    folder.mkdir()
    for name in ("Barcodes.dat", "Landmark_Groundtruth.dat"):
        shutil.copy(mrclam / name, folder / name)
    for r in robots:
        for kind in ("Odometry", "Measurement", "Groundtruth"):
            shutil.copy(mrclam / f"Robot{r}_{kind}.dat", folder / f"Robot{r}_{kind}.dat")
    return folder


def _corrupt(path: Path, line_no: int, text: str) -> None:
    lines = path.read_text().splitlines()
    lines[line_no - 1] = text
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("name, line, text, message", [
    ("Robot1_Odometry.dat", 10, "1248444187.240 0.1", "needs 3 numbers"),
    ("Robot1_Odometry.dat", 10, "1248444187.240 nan 0.1", "not finite"),
    ("Robot1_Odometry.dat", 10, "1248444187.240 0.1 1e999", "not finite"),
    ("Robot1_Odometry.dat", 10, "1248444100.0 0.1 0.1", "must be in time order"),
    ("Robot1_Odometry.dat", 10, "1248444187.240 250 0.1", "beyond 10 m/s"),
    ("Robot1_Measurement.dat", 8, "1248444190.0 14 -3.0 0.1", "range -3 m"),
    ("Robot1_Measurement.dat", 8, "1248444190.0 14.5 3.0 0.1", "barcode 14.5"),
    ("Robot1_Measurement.dat", 8, "1248444190.0 14 3.0 9.0", "bearing 9 rad"),
    ("Barcodes.dat", 6, "  2 \t   5", "barcode 5 is given to two subjects"),
    # tenth hostile pass: the later of two positions silently won (map RMSE 0.23 -> 2.4 m)
    ("Landmark_Groundtruth.dat", 6, "6 1.0 2.0 0.0001 0.0001",
     "landmark 6 is given a second position (first on line 5)"),
    ("Landmark_Groundtruth.dat", 6, "7.5 1.0 2.0 0.0001 0.0001", "subject must be a whole number"),
    # hostile pass 21: a robot's subject in the landmark truth read as a 16th landmark
    ("Landmark_Groundtruth.dat", 6, "3 1.0 1.0 0.0001 0.0001", "subject 3 is a robot"),
    ("Robot1_Groundtruth.dat", 7, "1248444175.103 1 2 3", "must be in time order"),
])
def test_bad_lines_are_refused_naming_file_and_line(mrclam, tmp_path, name, line, text, message):
    folder = _copy(mrclam, tmp_path)
    _corrupt(folder / name, line, text)
    with pytest.raises(InputError) as err:
        read_mrclam(folder, MrclamConfig(robot=1))
    assert message in str(err.value)
    assert f"{name}:{line}" in str(err.value)


def test_a_robot_the_folder_does_not_hold_is_named(mrclam, tmp_path):
    folder = _copy(mrclam, tmp_path)
    with pytest.raises(InputError, match=r"no Robot2_Odometry.dat here \(robots: Robot1\)"):
        read_mrclam(folder, MrclamConfig(robot=2))
    with pytest.raises(ConfigError):
        MrclamConfig(robot=6)


def test_a_log_without_sightings_or_landmark_truth_says_so(mrclam, tmp_path):
    """Third hostile pass: a Measurement file of its header only ran landmark SLAM on
    odometry alone, and a folder without Landmark_Groundtruth.dat left the map unscored,
    each without a word (0 landmarks, no map rows)."""
    folder = _copy(mrclam, tmp_path)
    meas = folder / "Robot1_Measurement.dat"
    meas.write_text("".join(meas.read_text().splitlines(True)[:4]))  # the 4 header lines
    (folder / "Landmark_Groundtruth.dat").unlink()
    notes = read_mrclam(folder, MrclamConfig(robot=1)).notes
    assert "robot 1: Robot1_Measurement.dat holds no sighting (odometry only)" in notes
    assert "no Landmark_Groundtruth.dat: the map is not scored" in notes


def test_a_folder_without_barcodes_is_refused_as_mrclam(mrclam, tmp_path, capsys):
    """Third hostile pass: without Barcodes.dat the folder was taken for an image folder
    and refused as one "without images"; the line now names the missing file."""
    folder = _copy(mrclam, tmp_path)
    (folder / "Barcodes.dat").unlink()
    line = _one_line_error(capsys, "run", "--dataset", str(folder), "--rerun", "off",
                           "--out", str(tmp_path / "o"))
    assert "Barcodes.dat" in line and "no images" not in line


def _one_line_error(capsys, *argv) -> str:
    rc = main(list(argv))
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("graphslam: error:"), err
    return err[0]


def test_run_writes_map_error_and_the_readers_notes(mrclam, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["run", "--dataset", str(mrclam), "--robot", "4",
               "--rerun", "off", "--quiet", "--out", str(out)])
    printed = capsys.readouterr().out
    assert rc == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["dataset"] == "mrclam6-robot4"
    assert metrics["landmarks_true"] == 15 and metrics["landmarks_matched"] == metrics["landmarks"]
    # SLAM at least halves dead reckoning's error, and the map is within the recovery radius
    assert metrics["ate_rmse_m"] < 0.5 * metrics["odometry_ate_rmse_m"]
    assert metrics["map_rmse_m"] < MAP_RECOVERY_RADIUS_M
    assert "3 sightings of barcodes Barcodes.dat does not list (50) in the whole log dropped" in \
        " / ".join(metrics["dataset_notes"])
    assert "landmarks recovered" in printed and "map RMSE" in printed
    assert (out / "ground_truth.tum").is_file()


def test_robot_flag_elsewhere_is_one_line(capsys, tmp_path):
    line = _one_line_error(capsys, "run", "--robot", "2", "--rerun", "off",
                           "--out", str(tmp_path / "o"))
    assert "--robot applies to MRCLAM folders only" in line


def test_map_errors_align_and_match_by_association():
    rng = np.random.default_rng(3)
    truth = {i: rng.uniform(-5, 5, 2) for i in range(10)}
    poses = np.column_stack([rng.uniform(-5, 5, (20, 2)), rng.uniform(-3, 3, 20)])
    c, s = math.cos(0.4), math.sin(0.4)
    R, t = np.array([[c, -s], [s, c]]), np.array([2.0, -1.0])
    moved = lambda xy: (np.asarray(xy) - t) @ R  # noqa: E731  (truth -> estimate frame)
    est_lm = np.array([moved(truth[i]) for i in range(10)])
    est_lm[0] += [0.5, 0.0]  # one landmark off by more than the recovery radius
    est = Estimate(pose_ids=np.arange(20), wTb=np.column_stack([moved(poses[:, :2]), poses[:, 2]]),
                   landmark_ids=np.arange(100, 110), landmarks_w=est_lm)
    pairs = [(i, 100 + i) for i in range(10)] * 2 + [(1, 100)]  # 100 mostly observes 0
    out = map_errors(est, (np.arange(20), poses), truth, pairs)
    assert out["landmarks_matched"] == 10 and out["landmarks_true"] == 10
    assert out["landmarks_recovered"] == 9
    assert out["map_rmse_m"] == pytest.approx(0.5 / math.sqrt(10), abs=1e-9)
    assert out["map_rmse_m_map_aligned"] < out["map_rmse_m"]
    assert MAP_RECOVERY_RADIUS_M == 0.3


# ----------------------------------------------------------------- several robots, one graph

def test_all_robots_share_one_stream_with_truth_starts_and_sightings(mrclam):
    from graphslam.sources.planar.mrclam_joint import POSE_ID_STRIDE
    from slamcore.planar.geometry import between

    from graphslam.sources.planar.mrclam_joint import read_mrclam_all

    ds = read_mrclam_all(mrclam, MrclamConfig(all_robots=True))
    assert [name for name, _ in ds.agents] == [f"robot {n}" for n in range(1, 6)]
    stamps = [f.stamp_s for f in ds.frames]
    assert stamps == sorted(stamps)
    seen, first = set(), {}
    for f in ds.frames:
        robot = f.pose_id // POSE_ID_STRIDE
        if f.odometry is not None:
            assert f.odometry.to_id == f.pose_id and f.odometry.from_id in seen
        if robot not in first:
            first[robot] = f
        seen.add(f.pose_id)
        for ps in f.pose_sightings:  # both ends exist when the sighting arrives
            assert ps.from_id in seen and ps.to_id in seen and ps.from_id != ps.to_id
    anchor = ds.frames[0]
    for robot, f in first.items():  # every start from the truth
        if f is not anchor:
            np.testing.assert_allclose(f.odometry.delta, between(anchor.wTb_true, f.wTb_true),
                                       atol=1e-12)
    assert sum(len(f.pose_sightings) for f in ds.frames) == 3981
    assert "all starts from the truth" in ds.notes[0]
    # the cameras are the single-robot reader's: the back ends read their field and tail
    assert ds.sensor_field == MrclamConfig().sensor_field()


def test_all_robots_run_on_isam2_and_each_is_scored(mrclam, tmp_path, capsys):
    out = tmp_path / "all"
    rc = main(["run", "--dataset", str(mrclam), "--robot", "all", "--max-steps", "1200",
               "--rerun", "off", "--quiet", "--out", str(out)])
    assert rc == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert sorted(metrics["agents"]) == [f"robot {n}" for n in range(1, 6)]
    for name, a in metrics["agents"].items():
        assert a["ate_rmse_m"] < 0.2, name
        assert (out / f"trajectory_{name.replace(' ', '')}.tum").is_file()
        # the ATE's count is of the poses with truth (hostile pass 21: all of them were said)
        assert a["poses"] <= a["poses_estimated"]
    assert sum(a["poses"] for a in metrics["agents"].values()) == metrics["ate_poses"]
    assert not (out / "trajectory.tum").exists()  # five robots' stamps interleave


@pytest.mark.slow
@pytest.mark.heavy
def test_all_robots_in_every_fastslam2_particle_beat_each_robots_own_runs(mrclam):
    """Issue 31 item 4 on FastSLAM 2.0: every particle holds every robot's latest pose.
    Over seeds 0-2, each robot's median joint ATE is below the median of its own runs, and
    all 15 landmarks are recovered (about 45 s); over seeds 0-4 (benchmarks/bench_mrclam.py)
    0.132/0.145/0.147/0.155/0.196 m against 0.144/0.151/0.164/0.189/0.226 m."""
    from graphslam.sources.planar.mrclam_joint import read_mrclam_all

    seeds = (0, 1, 2)
    joint = read_mrclam_all(mrclam, MrclamConfig(all_robots=True))
    runs = [pipeline.compute_metrics(
        pipeline.run(joint, registry.make_backend("fastslam2", overrides={"seed": s})),
        with_graph_error=False) for s in seeds]
    assert all(m.landmarks_recovered == 15 for m in runs)
    for robot in range(1, 6):
        ds = read_mrclam(mrclam, MrclamConfig(robot=robot))
        alone = [pipeline.compute_metrics(
            pipeline.run(ds, registry.make_backend("fastslam2", overrides={"seed": s})),
            with_graph_error=False).ate_rmse_m for s in seeds]
        together = [m.agents[f"robot {robot}"]["ate_rmse_m"] for m in runs]
        assert np.median(together) < np.median(alone), (robot, together, alone)


#: Largest change of a robot's joint iSAM2 ATE that seeding another robot's new pose
#: from its linearisation point may make, metres (measured 3e-5 over 1200 frames).
SEED_ATE_TOL_M = 1e-4


def test_joint_isam2_seeds_another_robots_pose_from_its_linearisation_point(mrclam):
    """Starting another robot's new pose from iSAM2's linearisation point instead of its
    estimate (a back-substitution deep in the tree, half the joint run) leaves each
    robot's ATE within SEED_ATE_TOL_M."""
    from graphslam.backends.planar.isam2 import Isam2Backend
    from graphslam.sources.planar.mrclam_joint import read_mrclam_all

    class EstimateSeeded(Isam2Backend):
        def _seed(self, pose_id):
            return self._pose(pose_id)

    ds = read_mrclam_all(mrclam, MrclamConfig(all_robots=True))
    ours, base = (pipeline.compute_metrics(pipeline.run(ds, b, max_steps=1200), with_graph_error=False)
                  for b in (registry.make_backend("isam2"),
                            EstimateSeeded(registry.make_backend("isam2").config)))
    for name, a in ours.agents.items():
        assert a["ate_rmse_m"] == pytest.approx(base.agents[name]["ate_rmse_m"], abs=SEED_ATE_TOL_M)


@pytest.mark.heavy
def test_all_robots_in_one_ekf_beat_each_robots_own_ekf_run(mrclam):
    """Issue 31 item 4, the EKF as a centralised filter: with the shared landmarks and the
    3981 sightings of one robot by another, every robot's ATE is below its own run's
    (measured 0.088/0.084/0.077/0.093/0.084 m against 0.155/0.342/0.139/0.206/0.168 m),
    and all 15 landmarks are recovered (about 8 s alone, 20-30 s in the suite). `heavy`:
    ``benchmarks/bench_mrclam.py`` measures it (``joint_ekf``); the joint EKF's other
    tests (its map saved, its single-robot localiser refused) keep the path in CI."""
    from graphslam.sources.planar.mrclam_joint import read_mrclam_all

    joint = pipeline.compute_metrics(
        pipeline.run(read_mrclam_all(mrclam, MrclamConfig(all_robots=True)), registry.make_backend("ekf")),
        with_graph_error=False)
    assert joint.landmarks_recovered == 15
    for robot in range(1, 6):
        ds = read_mrclam(mrclam, MrclamConfig(robot=robot))
        alone = pipeline.compute_metrics(pipeline.run(ds, registry.make_backend("ekf")),
                                         with_graph_error=False)
        assert joint.agents[f"robot {robot}"]["ate_rmse_m"] < alone.ate_rmse_m, robot


def test_a_joint_ekf_map_is_saved_and_its_single_robot_localiser_refused(mrclam, tmp_path, capsys):
    """The EKF's map of every robot is a map like any other; localising on it keeps one
    robot's pose in the EKF localiser, so --robot all with --map says so (it ran into the
    odometry check of another robot's start, a line that named no cause)."""
    saved = tmp_path / "map"
    assert main(["run", "--dataset", str(mrclam), "--robot", "all", "--backend", "ekf",
                 "--max-steps", "300", "--rerun", "off", "--quiet", "--save-map", str(saved),
                 "--out", str(tmp_path / "run")]) == 0
    capsys.readouterr()
    line = _one_line_error(capsys, "run", "--dataset", str(mrclam), "--robot", "all",
                           "--backend", "ekf", "--map", str(saved), "--rerun", "off",
                           "--out", str(tmp_path / "loc"))
    assert "--map with --robot all: the ekf localiser keeps one robot's pose" in line


@pytest.mark.parametrize("backend", ["isam2", "ekf"])
def test_all_robots_recording_draws_one_colour_per_robot(mrclam, tmp_path, backend):
    """The EKF's recording also holds its correlation image, other robots' poses last."""
    from tests.recordings import entity_rows

    out = tmp_path / "rec"
    assert main(["run", "--dataset", str(mrclam), "--robot", "all", "--max-steps", "300",
                 "--backend", backend, "--quiet", "--out", str(out)]) == 0
    strips = entity_rows(out / "run.rrd", f"/world/{backend}/trajectory", "LineStrips2D:strips")
    colors = entity_rows(out / "run.rrd", f"/world/{backend}/trajectory", "LineStrips2D:colors")
    assert len(strips[-1][1]) == 5 and len(set(colors[-1][1])) == 5


# ----------------------------------------------------------------- unknown association (iSAM2)

def test_a_candidate_enters_the_map_after_three_compatible_sightings():
    from graphslam.backends.planar.landmark_association import LandmarkAssociator
    from slamcore.planar.geometry import observe
    from slamcore.planar.records import Observation

    assoc = LandmarkAssociator(0.999, 3)
    R = np.diag([0.01, 1e-4])
    landmark = np.array([4.0, 1.0])
    kinds = []
    for k in range(3):
        wTb = np.array([0.1 * k, 0.0, 0.0])
        obs = Observation(k, None, observe(wTb, landmark), R)
        d = assoc.associate([obs], wTb, np.zeros(0, dtype=np.int64), np.zeros((0, 2)),
                            np.eye(3) * 1e-6)
        kinds.append(d[0].kind)
    assert kinds == ["candidate", "candidate", "confirmed"]
    np.testing.assert_allclose(d[0].mean_w, landmark, atol=1e-9)  # noise-free sightings
    assert len(d[0].sightings) == 3


def _cluster_run(**overrides):
    """A robot sees landmarks A and C (far apart) three times, turns 0.3 rad on an
    odometry of heading sigma 0.02 rad, sees A's neighbour B (0.25 m from A, 0.05 rad
    apart in bearing) alone twice, then A, B and C together. B's lone sightings are
    compatible with A (squared distance 5.4 under the turn's uncertainty and the
    bearing's) and go to it; in the joint scans B starts a landmark of its own.
    Noise-free ranges and bearings; the robot does not move after the turn."""
    from slamcore.planar.geometry import observe
    from slamcore.planar.records import Observation, Odometry

    truth = {0: np.array([5.0, 0.0]), 1: np.array([4.99, 0.25]), 2: np.array([-1.0, 5.0])}
    R = np.diag([0.04**2, 0.008**2])
    backend = registry.make_backend("isam2", overrides={"association": "unknown", **overrides})
    backend.initialize(0, np.zeros(3), np.eye(3) * 1e-8)
    seen = [[0, 2]] * 3 + [[1]] * 2 + [[0, 1, 2]] * 4
    for k, which in enumerate(seen, start=1):
        turn = 0.3 if k == 4 else 0.0  # before B's lone sightings
        cov = np.diag([1e-8, 1e-8, 0.02**2 if turn else 1e-8])
        backend.predict(Odometry(k - 1, k, np.array([0.0, 0.0, turn]), cov), k)
        wTb = np.array([0.0, 0.0, 0.3 if k >= 4 else 0.0])
        backend.update([Observation(k, None, observe(wTb, truth[j]), R) for j in which])
    est = backend.finalize()
    return {int(i): p for i, p in zip(est.landmark_ids, est.landmarks_w, strict=True)}


#: How close each landmark of the cluster run ends to its truth, metres: the sightings
#: are noise-free, so what is left is the pull of a wrong pairing (two of B's sightings
#: left on A move A and B by 5 and 8 mm under the Cauchy kernel).
CLUSTER_TOL_M = 1e-3


def test_a_new_neighbour_takes_back_the_sightings_it_explains_better(monkeypatch):
    """Splitting (isam2_unknown): when B is confirmed, its lone sightings that A had
    taken move to it, and every landmark ends where it is; without the move (and
    without the re-association at the end, which would make it), A keeps them and both
    are pulled toward each other."""
    truth = [np.array([5.0, 0.0]), np.array([4.99, 0.25]), np.array([-1.0, 5.0])]
    lms = _cluster_run(reassociation_passes=0)
    assert len(lms) == 3
    for t in truth:
        assert min(np.linalg.norm(p - t) for p in lms.values()) < CLUSTER_TOL_M
    from graphslam.backends.planar import isam2_unknown

    monkeypatch.setattr(isam2_unknown.UnknownAssociation, "split", lambda *args: 0)
    lms = _cluster_run(reassociation_passes=0)
    assert max(min(np.linalg.norm(p - t) for p in lms.values()) for t in truth) > CLUSTER_TOL_M


def test_reassociation_at_the_end_gives_back_what_a_decision_got_wrong(monkeypatch):
    """Re-association (isam2_unknown): with the split at confirmation turned off, A
    keeps B's lone sightings until the end; the pass at the batch estimate moves them to
    B, and every landmark ends where it is."""
    truth = [np.array([5.0, 0.0]), np.array([4.99, 0.25]), np.array([-1.0, 5.0])]
    from graphslam.backends.planar import isam2_unknown

    monkeypatch.setattr(isam2_unknown.UnknownAssociation, "split", lambda *args: 0)
    lms = _cluster_run()
    assert len(lms) == 3
    for t in truth:
        assert min(np.linalg.norm(p - t) for p in lms.values()) < CLUSTER_TOL_M


def test_jcbb_pairs_a_scan_with_two_close_landmarks_despite_a_heading_error():
    """Two landmarks 0.2 m apart across the line of sight at 4 m, the believed heading
    off by 0.06 rad (its sigma 0.05): alone, the sighting of the lower landmark is
    nearest the upper one's prediction; the joint test, which knows the heading error
    is shared by both sightings, pairs both right."""
    from graphslam.backends.planar.landmark_association import LandmarkAssociator
    from slamcore.planar.geometry import innovation, observe
    from slamcore.planar.records import Observation

    assoc = LandmarkAssociator(0.999, 3)
    lms = np.array([[4.0, 0.1], [4.0, -0.1]])
    true_pose, believed = np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.06])
    R = np.diag([0.13**2, 0.0083**2])
    obs = [Observation(0, None, observe(true_pose, lm), R) for lm in lms]
    predicted = observe(believed[None], lms)
    nearest = np.argmin(np.abs(innovation(obs[1].z[None], predicted)[:, 1]))
    assert nearest == 0  # nearest neighbour alone gets the second sighting wrong
    P = np.zeros((7, 7))
    P[:3, :3] = np.diag([1e-4, 1e-4, 0.05**2])
    P[3:, 3:] = np.eye(4) * 1e-6
    d = assoc.associate(obs, believed, np.array([10, 11]), lms, P)
    assert [x.landmark_id for x in d] == [10, 11]


#: Every robot is `heavy` (robot 3, the last in CI, took 15 s of it; 1, 2, 4 and 5 about
#: 2.5 min): benchmarks/bench_mrclam.py measures every robot's iSAM2 with and without ids
#: (docs/data/landmark-logs.md).
ISAM2_ROBOTS = [
    pytest.param(
        robot,
        marks=[pytest.mark.heavy]
        + (
            [
                pytest.mark.xfail(
                    strict=True,
                    reason="issue 31 open: without ids 1.58x the known-id ATE since iSAM2's "
                    "covariances are in the world frame (1.25x before, from the frame error)",
                )
            ]
            if robot == 1
            else []
        ),
    )
    for robot in (1, 2, 3, 4, 5)
]


@pytest.mark.slow
@pytest.mark.parametrize("robot", ISAM2_ROBOTS)
def test_isam2_within_the_issues_bounds_with_and_without_ids(mrclam, robot):
    """Issue 31: with known ids, iSAM2 at most 0.12 m ATE and all 15 landmarks
    recovered on every robot of Dataset 6. Without ids, all 15 landmarks recovered by an estimate of their own
    (within 0.3 m) and ATE within 1.3x of the known-id run (1.58x, 1.09x, 1.29x, 1.11x,
    1.04x since the association reads iSAM2's covariances in the world frame, 2026-12-07:
    robot 1 fails, marked so; docs/data/landmark-logs.md). Robot 3 (7.3x before) needs the ambiguous
    sightings held (landmark_association, step 3); robots 1, 2, 4 and 5 (1.40x on robot
    1, 14 landmarks on 1, 2, 4, 5 before) need the re-association at the end
    (isam2_unknown)."""
    ds = read_mrclam(mrclam, MrclamConfig(robot=robot))
    known = pipeline.compute_metrics(pipeline.run(ds, registry.make_backend("isam2")),
                                     with_graph_error=False)
    assert known.ate_rmse_m <= ISAM2_ATE_BOUND_M and known.landmarks_recovered == 15
    unknown = pipeline.compute_metrics(
        pipeline.run(ds, registry.make_backend("isam2", overrides={"association": "unknown"})),
        with_graph_error=False)
    assert unknown.landmarks_recovered == 15
    assert unknown.ate_rmse_m <= 1.3 * known.ate_rmse_m
    assert unknown.reassociation_settled is True
    assert unknown.sightings_reassociated > 0


def test_frames_finer_than_any_log_needs_are_refused_before_allocating(monkeypatch):
    """frame_every_s = 1e-12 asked numpy for 17.8 TiB of frame times (a MemoryError
    traceback); the count is now checked first, and it is the count the frames get."""
    from graphslam.sources.planar import mrclam
    from slamcore.errors import ConfigError

    odometry_s, sightings_s = np.array([0.0, 900.0]), np.array([10.0, 20.0])
    with pytest.raises(ConfigError, match=r"frame_every_s = 1e-12 would put 9e\+14 frames"):
        mrclam.frame_times(odometry_s, sightings_s, 1e-12)
    n = len(mrclam.frame_times(odometry_s, sightings_s, 7.0))
    monkeypatch.setattr(mrclam, "MAX_FRAMES", n)  # exactly the limit: accepted
    assert len(mrclam.frame_times(odometry_s, sightings_s, 7.0)) == n
    monkeypatch.setattr(mrclam, "MAX_FRAMES", n - 1)  # one over: refused
    with pytest.raises(ConfigError, match=f"would put {n} frames"):
        mrclam.frame_times(odometry_s, sightings_s, 7.0)


@pytest.mark.slow
@pytest.mark.parametrize("robot", [1, 2, 3, 4, 5])
def test_ekf_unknown_association_within_the_issues_bound(mrclam, robot):
    """Issue 31: without ids the EKF within 2x of its known-id ATE and no more than 20
    landmarks. Needs the hold of ambiguous pairings (robot 3: 2.95x before) and three
    sightings to confirm a landmark under the camera's error tail (robot 1 built 24 with
    one; filters/ekf_slam.py). Measured 1.66/0.79/0.94/1.09/1.14x and 17/16/17/15/18
    landmarks."""
    ds = read_mrclam(mrclam, MrclamConfig(robot=robot))
    known = pipeline.compute_metrics(pipeline.run(ds, registry.make_backend("ekf")),
                                     with_graph_error=False)
    run = pipeline.run(ds, registry.make_backend("ekf", overrides={"association": "unknown"}))
    unknown = pipeline.compute_metrics(run, with_graph_error=False)
    assert unknown.ate_rmse_m <= 2.0 * known.ate_rmse_m
    assert len(run.estimate.landmark_ids) <= 20


@pytest.mark.slow
@pytest.mark.heavy
def test_fastslam2_unknown_association_on_robot_3_within_the_issues_bound(mrclam):
    """Issue 31: FastSLAM 2.0 without ids within 1.3x of its known-id ATE, medians over
    seeds 0-4. On robot 3 it was 3.25x (0.590 m against 0.181 m, per-step means) with
    the Gaussian new-landmark gate; the camera's own 0.999 error quantile
    (filters/fastslam_config.py) brings it to 0.86x (0.158 m against 0.183 m, the best
    particle's path). These are seeds 0-4 only: over seeds 0-19 robot 3's unknown-id
    runs ended near 0.13-0.19 m or near 0.43-0.58 m, a ratio of medians of 2.31x, until
    the weights took the sightings' correlation in time: now 1.10x (0.169 m against
    0.153 m, Gaussian weights), and 1.04x over seeds 0-19 with the camera's t law
    weighing the particles (0.140 m against 0.134 m; docs/data/landmark-logs.md)."""
    ds = read_mrclam(mrclam, MrclamConfig(robot=3))

    def median_ate(association: str) -> float:
        ates = []
        for seed in range(5):
            backend = registry.make_backend("fastslam2", overrides={"association": association, "seed": seed})
            ates.append(pipeline.compute_metrics(pipeline.run(ds, backend), with_graph_error=False).ate_rmse_m)
        return float(np.median(ates))

    assert median_ate("unknown") <= 1.3 * median_ate("known")


def test_fastslam_of_every_robot_with_nees_writes_its_files(mrclam, tmp_path, capsys):
    """Tenth hostile pass: every robot starts at its truth; ``--nees`` inverted a cloud of
    zero spread (LinAlgError, a traceback, nothing written). The run is whole: a row a
    step, and the mean finite (under the camera's t law weighing the particles no cloud of
    these 300 steps collapses to one pose; under Gaussian weights 12 did)."""
    out = tmp_path / "o"
    assert main(["run", "--dataset", str(mrclam), "--robot", "all", "--backend", "fastslam1",
                 "--max-steps", "300", "--nees", "--rerun", "off", "--quiet", "--out", str(out)]) == 0
    rows = (out / "nees.csv").read_text().splitlines()[1:]
    undefined = sum(r.endswith(",nan") for r in rows)
    assert len(rows) == 300
    assert ("NEES undefined at" in capsys.readouterr().err) == (undefined > 0)
    metrics = json.loads((out / "metrics.json").read_text())
    assert math.isfinite(metrics["nees_mean"])


def test_fastslam_nees_of_a_collapsed_cloud_is_undefined_and_said(mrclam, tmp_path, capsys):
    """One particle (one robot: the count is per robot): every pose's cloud is one pose,
    its covariance zero. Each NEES is NaN, said in one line, and no mean is claimed."""
    out, cfg = tmp_path / "o", tmp_path / "one.toml"
    cfg.write_text("[fastslam]\nn_particles = 1\n")
    assert main(["run", "--dataset", str(mrclam), "--robot", "1", "--backend", "fastslam1",
                 "--max-steps", "60", "--nees", "--rerun", "off", "--quiet", "--out", str(out),
                 "--config", str(cfg)]) == 0
    assert "NEES undefined at 60 of 60 poses" in capsys.readouterr().err
    rows = (out / "nees.csv").read_text().splitlines()[1:]
    assert len(rows) == 60 and all(r.endswith(",nan") for r in rows)
    assert json.loads((out / "metrics.json").read_text()).get("nees_mean") is None


def test_run_says_a_mean_nees_no_consistent_filter_gives(mrclam, tmp_path, capsys):
    """Three particles on robot 1: the cloud is nearly one pose and its NEES runs to
    1e12 (measured 6.9e12 over 300 steps). ``run --nees`` gave it only in metrics.json;
    now the summary shows it and a warning says how far its covariances understate its
    errors, as ``compare`` does. A consistent run (the EKF on the synthetic world, mean
    4.3) shows its NEES and is not doubted."""
    out, cfg = tmp_path / "o", tmp_path / "three.toml"
    cfg.write_text("[fastslam]\nn_particles = 3\n")
    assert main(["run", "--dataset", str(mrclam), "--robot", "1", "--backend", "fastslam1",
                 "--max-steps", "300", "--nees", "--rerun", "off", "--out", str(out),
                 "--config", str(cfg)]) == 0
    said = capsys.readouterr()
    assert "mean NEES (3 dof)" in said.out
    assert "above the 95 % bound of one step" in said.err and "understate its errors" in said.err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["nees_mean"] > 1e6
    assert any("above the 95 % bound" in w for w in metrics["warnings"])
    assert main(["run", "--backend", "ekf", "--max-steps", "200", "--nees", "--rerun", "off",
                 "--out", str(tmp_path / "e")]) == 0
    said = capsys.readouterr()
    assert "mean NEES (3 dof)" in said.out and "NEES" not in said.err


def test_a_sighted_landmark_without_truth_is_named_as_not_scored(mrclam, tmp_path):
    """Landmark_Groundtruth.dat without landmark 8's row scored "14 of 14 recovered" with
    landmark 8 mapped and nothing said (twentieth hostile pass)."""
    from graphslam.sources.planar.mrclam import read_mrclam

    folder = _copy(mrclam, tmp_path)
    truth = folder / "Landmark_Groundtruth.dat"
    truth.write_text("".join(ln for ln in truth.read_text().splitlines(True) if ln.split()[:1] != ["8"]))
    ds = read_mrclam(folder, MrclamConfig(robot=1))
    assert "landmark 8 sighted but not in Landmark_Groundtruth.dat: mapped, not scored" in ds.notes
    assert not any("not scored" in n for n in read_mrclam(mrclam, MrclamConfig(robot=1)).notes)


def test_a_robot_file_beyond_five_is_left_out_of_the_joint_run_and_said(mrclam, tmp_path):
    """Hostile pass 21: ``--robot all`` ran ``Robot6_*.dat`` (which ``--robot 6`` refuses)
    and dropped landmark 6's barcode as that robot's own."""
    folder = _copy(mrclam, tmp_path, robots=(1, 2))
    for kind in ("Odometry", "Measurement", "Groundtruth"):
        shutil.copy(folder / f"Robot2_{kind}.dat", folder / f"Robot6_{kind}.dat")
    from graphslam.sources.planar.mrclam_joint import read_mrclam_all

    ds = read_mrclam_all(folder, MrclamConfig())
    assert "Robot6_Odometry.dat left out: MRCLAM's robots are subjects 1-5" in ds.notes
    assert not any("robot 6" in n for n in ds.notes)
    (folder / "Robot2_Groundtruth.dat").unlink()
    with pytest.raises(InputError, match=r"robot 2 has no truth at its first frame \(no Robot2_Groundtruth.dat\)"):
        read_mrclam_all(folder, MrclamConfig())


def test_a_map_is_judged_by_its_landmarks_not_the_folders_name(mrclam, tmp_path, capsys):
    """Hostile pass 21: robot 2 on robot 1's map was refused ('built on mrclam-robot1'),
    and so was a byte-identical copy of the folder under another name, while a copy whose
    truth files were moved 5 m was taken (ATE 1.68 m against 0.09, no word). A map saved
    by a run without ids localised by its labels as if they were barcodes (ATE 3.1 m)."""
    folder = _copy(mrclam, tmp_path, robots=(1, 2))
    steps = ["--max-steps", "600", "--rerun", "off"]
    assert main(["run", "--dataset", str(folder), "--robot", "1", *steps, "--save-map", str(tmp_path / "m1"),
                 "--out", str(tmp_path / "r1")]) == 0
    renamed = tmp_path / "elsewhere" / "copy"
    shutil.copytree(folder, renamed)
    for dataset, robot in ((folder, "2"), (renamed, "1"), (folder, "all")):
        assert main(["run", "--dataset", str(dataset), "--robot", robot, *steps, "--map", str(tmp_path / "m1"),
                     "--out", str(tmp_path / "loc")]) == 0, capsys.readouterr().err
        association = json.loads((tmp_path / "loc" / "metrics.json").read_text())["association"]
        assert association["landmarks_created"] == 0  # the map's, sighted: it counted them
    capsys.readouterr()
    # a damaged record of the landmarks is no record: judged by the name (it was AttributeError)
    original = (tmp_path / "m1" / "map.json").read_text()
    record = json.loads(original)
    record["meta"]["landmarks"] = 5
    (tmp_path / "m1" / "map.json").write_text(json.dumps(record))
    assert main(["run", "--dataset", str(folder), "--robot", "1", *steps, "--map", str(tmp_path / "m1"),
                 "--out", str(tmp_path / "loc")]) == 0
    (tmp_path / "m1" / "map.json").write_text(original)
    moved = tmp_path / "moved"
    shutil.copytree(folder, moved)
    truth = moved / "Landmark_Groundtruth.dat"
    truth.write_text("".join(ln if ln.startswith("#") or not ln.strip() else
                             " ".join([ln.split()[0], str(float(ln.split()[1]) + 5.0), *ln.split()[2:]]) + "\n"
                             for ln in truth.read_text().splitlines(True)))
    assert main(["run", "--dataset", str(moved), "--robot", "1", *steps, "--map", str(tmp_path / "m1"),
                 "--out", str(tmp_path / "loc2")]) == 2
    assert "its landmark files differ" in capsys.readouterr().err
    (tmp_path / "u.toml").write_text('[ekf]\nassociation = "unknown"\n')
    assert main(["run", "--dataset", str(folder), "--robot", "1", *steps, "--backend", "ekf", "--config",
                 str(tmp_path / "u.toml"), "--save-map", str(tmp_path / "mu"), "--out", str(tmp_path / "ru")]) == 0
    capsys.readouterr()
    for backend in ("isam2", "ekf"):
        assert main(["run", "--dataset", str(folder), "--robot", "1", *steps, "--backend", backend,
                     "--map", str(tmp_path / "mu"), "--out", str(tmp_path / "lu")]) == 2
        assert 'association = "unknown": its landmark ids are that run\'s own labels' in capsys.readouterr().err
    (tmp_path / "iu.toml").write_text('[isam2]\nassociation = "unknown"\n')
    assert main(["run", "--dataset", str(folder), "--robot", "1", *steps, "--config", str(tmp_path / "iu.toml"),
                 "--map", str(tmp_path / "m1"), "--out", str(tmp_path / "liu")]) == 2
    assert "[isam2] association = \"unknown\" is not supported with --map" in capsys.readouterr().err


def test_a_truth_that_covers_none_of_the_log_is_a_warning(mrclam, tmp_path):
    """Hostile pass 21: truth times shifted by 1e5 s gave exit 0 and ATE n/a, only a note."""
    folder = _copy(mrclam, tmp_path)
    path = folder / "Robot1_Groundtruth.dat"
    path.write_text("".join(ln if ln.startswith("#") or not ln.strip() else
                            " ".join([f"{float(ln.split()[0]) + 1e5:.3f}", *ln.split()[1:]]) + "\n"
                            for ln in path.read_text().splitlines(True)))
    ds = read_mrclam(folder, MrclamConfig(robot=1))
    assert any(w.startswith("Robot1_Groundtruth.dat covers none of robot 1's log") for w in ds.warnings)


def test_a_given_truth_replaces_the_readers_lines_on_its_own(mrclam, tmp_path, capsys):
    """Hostile pass 21: --ground-truth kept the note 'truth on 1416 of the whole log's 1545
    frames' beside an ATE over 154 poses of the given file."""
    steps = ["--max-steps", "300", "--rerun", "off"]
    assert main(["run", "--dataset", str(mrclam), "--robot", "1", *steps, "--out", str(tmp_path / "a")]) == 0
    lines = (tmp_path / "a" / "ground_truth.tum").read_text().splitlines()
    (tmp_path / "gt.tum").write_text("\n".join(lines[:1] + lines[1::10]) + "\n")
    capsys.readouterr()
    assert main(["run", "--dataset", str(mrclam), "--robot", "1", *steps, "--ground-truth",
                 str(tmp_path / "gt.tum"), "--out", str(tmp_path / "b")]) == 0
    notes = json.loads((tmp_path / "b" / "metrics.json").read_text())["dataset_notes"]
    assert not any("truth on " in n for n in notes)
    assert any(n.startswith("truth from gt.tum: ") for n in notes)


def test_the_comparison_plot_draws_one_line_a_robot(mrclam, monkeypatch, tmp_path):
    """Hostile pass 22: compare.png of --robot all drew each back end's poses in frame order,
    one zig-zag line across the five robots, over the whole log's truth."""
    from types import SimpleNamespace

    from graphslam.sources.planar.mrclam_joint import read_mrclam_all
    from graphslam.visualisation import plots

    ds = read_mrclam_all(mrclam, MrclamConfig()).truncated(400)
    result = pipeline.run(ds, registry.make_backend("ekf"))
    seen = {}
    monkeypatch.setattr(plots, "_comparison_figure", lambda path, title, truth, marks, tracks, errors, *a: seen.update(
        truth=truth, tracks=tracks, errors=errors) or path)
    plots.plot_comparison([SimpleNamespace(backend="ekf", result=result)], ds, tmp_path / "c.png")
    (label, strips, _), = seen["tracks"]
    assert label == "ekf" and len(strips) == 5 and sum(len(s) for s in strips) == len(result.estimate.pose_ids)
    assert len(seen["truth"]) == 5 and sum(len(s) for s in seen["truth"]) <= 400
    assert len(seen["errors"]) == 5 and {e[0] for e in seen["errors"]} == {"ekf"}


@pytest.mark.parametrize("config, flags, said", [
    ("[mrclam]\nall_robots = true\nrobot = 3\n", [], "[mrclam] robot did nothing"),
    ("[mrclam]\ncorrelation_time_s = 0\nrange_correlated_share = 0.1\n", ["--robot", "1"],
     "[mrclam] range_correlated_share did nothing"),
])
def test_mrclam_settings_another_leaves_unread_are_said(mrclam, tmp_path, capsys, config, flags, said):
    """Hostile pass 22: robot under all_robots, and the correlated shares without a
    correlation time, ran byte-identical and silent."""
    (tmp_path / "c.toml").write_text(config)
    assert main(["run", "--dataset", str(mrclam), *flags, "--config", str(tmp_path / "c.toml"),
                 "--max-steps", "100", "--rerun", "off", "--out", str(tmp_path / "o")]) == 0
    assert said in capsys.readouterr().err
