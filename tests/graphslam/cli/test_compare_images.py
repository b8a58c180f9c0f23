"""``graphslam compare`` on image sequences and the visual pose NEES.

The comparisons run on a small QVGA synthetic room for a few frames (seconds);
the figures on the full sequence are in README.md, with their command.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphslam.evaluation.spatial import pose_nees
from graphslam.pipelines.compare_spatial import scale_baseline
from slamcore.errors import GraphSlamError
from slamcore.spatial.geometry import invert_pose, se3_exp, so3_exp
from tests.graphslam.cli.test_faults import graphslam, one_line, verify_rrd
from tests.graphslam.evaluation.test_metrics3d import _apply
from tests.graphslam.pipelines.test_localize import HALF

#: A small, fast room: QVGA images, 30 frames of which a few are run.
SMALL_ROOM = HALF + "n_frames = 30\n"
FIELDS = {"ate_rmse_m", "nees_mean", "nees_in_bounds_fraction", "frames_per_s", "peak_rss_mb",
          "input_digest", "rpe"}
#: Tolerance of a mean of N chi-square(6) draws: 5 standard deviations (sqrt(12 / N)).
N_DRAWS = 4000
MEAN_TOL = 5 * np.sqrt(12 / N_DRAWS)
#: The 2.5 % and 97.5 % quantiles of chi-square(6) (scipy.stats.chi2.ppf).
CHI2_6_LO, CHI2_6_HI = 1.2373442457, 14.4493753454
#: Tolerance of the share inside the 95 % bounds: 5 binomial standard deviations.
SHARE_TOL = 5 * np.sqrt(0.95 * 0.05 / N_DRAWS)


@pytest.fixture(scope="module")
def small_room(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "room.toml"
    path.write_text(SMALL_ROOM)
    return path


def _poses_with_errors(seed: int):
    """Truth along a 20 m path with random attitudes, estimates off by draws of
    known covariances: ``gt = est @ exp(xi)``, ``xi ~ N(0, C_k)``."""
    rng = np.random.default_rng(seed)
    gt = np.stack([se3_exp(np.r_[rng.uniform(-10, 10, 3), rng.normal(0, 1.0, 3)])
                   for _ in range(N_DRAWS)])
    A = rng.normal(0.0, 1.0, (N_DRAWS, 6, 6)) * np.r_[0.03, 0.03, 0.03, 0.005, 0.005, 0.005]
    C = A @ np.swapaxes(A, 1, 2) + np.diag([1e-4] * 3 + [1e-6] * 3)
    xi = np.einsum("nij,nj->ni", np.linalg.cholesky(C), rng.normal(size=(N_DRAWS, 6)))
    est = np.stack([g @ invert_pose(se3_exp(x)) for g, x in zip(gt, xi)])
    return gt, est, C


def test_pose_nees_of_consistent_draws_is_chi_square_6():
    gt, est, C = _poses_with_errors(seed=3)
    ids = np.arange(N_DRAWS)
    out = pose_nees(ids, est, C, ids, gt)
    assert abs(out["nees_mean"] - 6.0) < MEAN_TOL
    assert abs(out["nees_in_bounds_fraction"] - 0.95) < SHARE_TOL
    # twice the covariance halves the NEES: the error is scored against C itself
    assert abs(pose_nees(ids, est, 2 * C, ids, gt)["nees_mean"] - 3.0) < MEAN_TOL


def test_pose_nees_after_a_sim3_fit_undoes_scale_and_frame():
    """An estimate in another frame at another scale (a monocular run), its covariance
    in that scale: the Sim(3) NEES is the NEES in the truth's frame."""
    gt, est, C = _poses_with_errors(seed=4)
    ids = np.arange(N_DRAWS)
    s, R, t = 0.4, so3_exp([0.3, -1.0, 2.0]), np.array([5.0, -2.0, 1.0])
    moved = est.copy()
    moved[:, :3, :3] = R @ est[:, :3, :3]
    moved[:, :3, 3] = s * est[:, :3, 3] @ R.T + t
    D = np.diag([s] * 3 + [1.0] * 3)
    out = pose_nees(ids, moved, D @ C @ D, ids, gt, alignment="sim3")
    assert abs(out["scale"] - 1 / s) < 1e-3 / s  # the fit on noisy centres, 0.1 %
    assert abs(out["nees_mean"] - pose_nees(ids, est, C, ids, gt)["nees_mean"]) < MEAN_TOL
    # unaligned, the same estimate is nowhere near its truth
    assert pose_nees(ids, moved, D @ C @ D, ids, gt)["nees_mean"] > 1e3


def _in_a_gauge(seed: int):
    """Draws as :func:`_poses_with_errors` in the gauge a camera-alone estimator holds:
    row 0 exactly on the truth (its prior) and the distance of rows 0 to 7 exactly
    the truth's (iSAM2's range factor of 1, here in metres)."""
    gt, est, C = _poses_with_errors(seed)
    est[0] = gt[0]
    d = est[7, :3, 3] - est[0, :3, 3]
    est[7, :3, 3] = est[0, :3, 3] + d * np.linalg.norm(gt[7, :3, 3] - gt[0, :3, 3]) / np.linalg.norm(d)
    return gt, est, C


def test_pose_nees_in_the_estimators_gauge_is_its_nees_in_the_truths_frame():
    """A camera-alone estimate in its own frame and unit (first pose at the origin,
    baseline 1): the gauge alignment undoes exactly that similarity, so every frame's
    NEES is the one the estimate has in the truth's frame; Umeyama's Sim(3) instead
    moves the held first pose, whose covariance is the prior's."""
    gt, est, C = _in_a_gauge(seed=6)
    ids = np.arange(N_DRAWS) + 100
    s = 1.0 / np.linalg.norm(gt[7, :3, 3] - gt[0, :3, 3])
    R = so3_exp([-0.7, 0.2, 1.1])
    moved = _apply(s, R, np.array([3.0, 1.0, -4.0]), est)
    D = np.diag([s] * 3 + [1.0] * 3)
    truth = pose_nees(ids, est, C, ids, gt)
    out = pose_nees(ids, moved, D @ C @ D, ids, gt, alignment="gauge", baseline_ids=(100, 107))
    assert out["alignment"] == "gauge" and abs(out["scale"] * s - 1.0) < 1e-9
    np.testing.assert_allclose(out["nees"], truth["nees"], rtol=1e-6, atol=1e-9)
    C0 = np.diag([1e-8] * 3 + [1e-10] * 3)  # the prior's covariance on the held pose
    covs = np.concatenate([C0[None], (D @ C @ D)[1:]])
    assert pose_nees(ids, moved, covs, ids, gt, alignment="gauge", baseline_ids=(100, 107))["nees"][0] < 1e-6
    hi = out["bounds"][1]
    assert pose_nees(ids, moved, covs, ids, gt, alignment="sim3")["nees"][0] > 5 * hi


def test_pose_nees_gauge_without_a_baseline_fits_the_scale_about_the_anchor():
    """A filter fixes no baseline (its scale comes from a depth prior): the gauge's
    scale is then the least-squares one about the held pose, 0.1 % on 4000 draws."""
    gt, est, C = _in_a_gauge(seed=7)
    ids = np.arange(N_DRAWS)
    s = 0.25
    moved = _apply(s, so3_exp([0.1, 0.9, -0.3]), np.array([-1.0, 0.0, 2.0]), est)
    D = np.diag([s] * 3 + [1.0] * 3)
    out = pose_nees(ids, moved, D @ C @ D, ids, gt, alignment="gauge")
    assert abs(out["scale"] * s - 1.0) < 1e-3
    assert abs(out["nees_mean"] - pose_nees(ids, est, C, ids, gt)["nees_mean"]) < MEAN_TOL
    assert out["errors"][0] == pytest.approx(np.zeros(6), abs=1e-9)


@pytest.mark.parametrize("anchor, baseline", [(5000, None), (0, (0, 5000)), (3, (2, 2))])
def test_pose_nees_gauge_frames_must_be_estimated_distinct_and_true(anchor, baseline):
    gt, est, C = _poses_with_errors(seed=8)
    ids = np.arange(N_DRAWS)
    with pytest.raises(GraphSlamError, match="gauge"):
        pose_nees(ids, est, C, ids, gt, alignment="gauge", anchor_id=anchor, baseline_ids=baseline)


def test_a_mean_nees_outside_one_steps_bounds_is_said_with_its_factor_in_sigma():
    from graphslam.evaluation.planar import nees_doubt

    high = nees_doubt(149.0, 6)
    assert "understate" in high and "4.98x in sigma" in high and "(14.4)" in high
    low = nees_doubt(0.1, 3)
    assert "overstate" in low and "5.48x in sigma" in low and "(0.216)" in low
    assert nees_doubt(6.0, 6) is None and nees_doubt(CHI2_6_HI * 0.999, 6) is None
    assert nees_doubt(CHI2_6_LO * 1.001, 6) is None and nees_doubt(CHI2_6_HI * 1.001, 6) is not None
    assert nees_doubt(None, 6) is None and nees_doubt(float("nan"), 6) is None
    assert "infx" not in (nees_doubt(float("inf"), 3) or "understate")


def test_compare_scores_isam2_camera_alone_on_its_first_map_baseline():
    stats = {"camera_alone": {"first_map": {"reference_frame": 4, "frame": 17}}}
    assert scale_baseline(stats) == (4, 17)
    assert scale_baseline({"camera_alone": {"first_map": None}}) is None
    assert scale_baseline({}) is None and scale_baseline(None) is None


def test_pose_nees_on_a_straight_drive_fits_the_rotation_about_the_line():
    """Truth on one line (a straight drive, or two frames): the positions leave the
    rotation about that line free, so the aligned NEES must take it from the
    orientations; Umeyama's arbitrary angle read as a rotation error of up to 180 deg."""
    gt_any, est_any, C = _poses_with_errors(seed=5)
    rel = np.stack([invert_pose(g) @ e for g, e in zip(gt_any, est_any, strict=True)])
    gt = gt_any.copy()  # the same orientations, the centres on one line
    gt[:, :3, 3] = np.outer(np.linspace(0.0, 30.0, N_DRAWS), [1.0, 0.5, 0.0])
    est = gt @ rel  # the same errors, in each pose's frame
    R = so3_exp([0.2, 0.1, -0.4])
    moved = est.copy()
    moved[:, :3, :3] = R @ est[:, :3, :3]
    moved[:, :3, 3] = est[:, :3, 3] @ R.T + np.array([1.0, 2.0, 3.0])
    ids = np.arange(N_DRAWS)
    aligned = pose_nees(ids, moved, C, ids, gt, alignment="se3")["nees_mean"]
    assert abs(aligned - pose_nees(ids, est, C, ids, gt)["nees_mean"]) < MEAN_TOL


def test_compare_on_images_writes_table_json_png_and_recording(tmp_path, small_room):
    done = graphslam(tmp_path, "compare", "--dataset", "synthetic-images", "--config",
                     str(small_room), "--max-steps", "6", "--out", "c", "--rerun", "save")
    assert done.returncode == 0, done.stderr
    for head in ("ATE [m]", "mean NEES", "NEES in 95%", "RPE [m/frame]", "frames/s", "peak MB"):
        assert head in done.stdout
    data = json.loads((tmp_path / "c" / "compare.json").read_text())
    runs = data["runs"]
    assert [r["backend"] for r in runs] == ["isam2", "ekf-idp", "ekf-ahp"]
    for r in runs:
        assert FIELDS <= set(r) and r["frames"] == 6 and r["alignment"] == "se3"
        assert 0.0 <= r["nees_in_bounds_fraction"] <= 1.0 and r["nees_mean"] > 0
        # a mean NEES outside one step's chi-square(6) 95 % bounds is said, in the JSON and on stderr
        doubt = [w for w in r.get("warnings") or [] if w.startswith("mean NEES")]
        assert bool(doubt) == (not CHI2_6_LO <= r["nees_mean"] <= CHI2_6_HI), (r["nees_mean"], doubt)
        assert all(f"{r['backend']}: {w}" in done.stderr for w in doubt)
    # the same frames, corners and odometry fed to every back end
    assert len({r["input_digest"] for r in runs}) == 1
    assert data["nees"]["dof"] == 6 and data["odometry"] == "sequence"
    assert (tmp_path / "c" / "compare.png").stat().st_size > 0
    verify_rrd(tmp_path / "c" / "compare.rrd")


def test_input_digest_follows_the_input(small_room):
    """The digest is of what was fed: another seed renders other textures."""
    from graphslam import registry
    from graphslam.pipelines import compare_spatial as cs
    from graphslam.pipelines.session import VisualSetup

    config = registry.read_config(small_room)
    digests = []
    for seed in (0, 1):
        seq = registry.load_image_sequence("synthetic-images", seed=seed, config=config)
        setup = VisualSetup.read(seq, config, max_frames=3)
        digests.append(cs.run_one(setup, "ekf-ahp").input_digest)
    assert digests[0] != digests[1]


def test_compare_on_images_ctrl_c_keeps_the_cut_run(tmp_path, small_room):
    done = graphslam(tmp_path, "compare", "--dataset", "synthetic-images", "--config",
                     str(small_room), "--max-steps", "8", "--out", "c", "--rerun", "save",
                     at="step:3", sig="INT", to="group")
    assert done.returncode == 130
    one_line(done.stderr)
    runs = {r["backend"]: r for r in json.loads((tmp_path / "c" / "compare.json").read_text())["runs"]}
    assert runs["isam2"]["status"] == "cut" and runs["isam2"]["frames"] == 4
    assert runs["isam2"]["interrupted"] is True
    assert [runs[b]["status"] for b in ("ekf-idp", "ekf-ahp")] == ["not run"] * 2
    assert "cut" in done.stdout and "not run" in done.stdout
    assert (tmp_path / "c" / "compare.png").stat().st_size > 0
    verify_rrd(tmp_path / "c" / "compare.rrd")


def test_compare_refuses_a_2d_back_end_on_images(tmp_path, small_room):
    done = graphslam(tmp_path, "compare", "--dataset", "synthetic-images", "--backends", "ekf")
    assert done.returncode == 2
    assert "not on image sequences" in one_line(done.stderr)


def test_the_rooms_nearest_depth_sets_the_ekf_prior_unless_the_file_does(tmp_path, small_room):
    from graphslam import registry
    from graphslam.pipelines import spatial as vp

    seq = registry.load_image_sequence("synthetic-images", config=registry.read_config(small_room))
    uv_z = [seq.project(i) for i in range(len(seq))]
    nearest = min(z[(z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= 319) & (uv[:, 1] >= 0)
                    & (uv[:, 1] <= 239)].min() for uv, z in uv_z)
    # the 1st percentile: above the very nearest point, below 10 m (the room is 11 m wide)
    assert nearest <= seq.nearest_depth_m < 10.0
    assert vp.scene_nearest_depth(seq, registry.read_config(None)) == seq.nearest_depth_m
    own = tmp_path / "own.toml"
    own.write_text("[mono_ekf]\nmin_depth_m = 4.0\n")
    assert vp.scene_nearest_depth(seq, registry.read_config(own)) is None
    ekf = registry.make_visual_backend("ekf", overrides=vp.backend_overrides(
        "ekf", "sequence", nearest_depth_m=seq.nearest_depth_m))
    assert ekf.config.min_depth_m == seq.nearest_depth_m
