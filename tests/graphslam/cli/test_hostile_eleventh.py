"""Eleventh hostile pass (2026-11-30): what a hostile but plausible user found, one test a fix.

Run in process through :func:`graphslam.cli.main.main`, which turns errors into one
``graphslam: error:`` line and exit status 2.
"""

from __future__ import annotations

import json

from graphslam.cli.main import main


def test_the_first_monocular_map_names_the_files_frame_under_frames(tmp_path, capsys):
    """Under ``--frames 3:`` the summary said "monocular map started frame 2", the run's
    count: a user looks for file frame 5."""
    out = tmp_path / "o"
    argv = ["run", "--dataset", "synthetic-images", "--odometry", "none", "--frames", "3:16",
            "--quiet", "--rerun", "off", "--out", str(out)]
    assert main(argv) == 0
    said = capsys.readouterr().out
    first = json.loads((out / "metrics.json").read_text())["backend_stats"]["camera_alone"]["first_map"]
    assert first["file_frame"] == first["frame"] + 3
    assert f"frame {first['frame']} of the run (file frame {first['frame'] + 3})" in said


def _kitti_like(root, n: int):
    """A KITTI-style folder of ``n`` synthetic frames (image_0/, calib.txt, times.txt)."""
    import cv2

    from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig, make_synthetic_images

    seq = make_synthetic_images(SyntheticImagesConfig(width=160, height=120, fx=125, fy=125, cx=79.5,
                                                      cy=59.5, n_frames=n))
    (root / "image_0").mkdir(parents=True)
    for i in range(n):
        cv2.imwrite(str(root / "image_0" / f"{i:06d}.png"), seq.load(i))
    (root / "calib.txt").write_text("P0: 125 0 79.5 0 0 125 59.5 0 0 0 1 0\n")
    (root / "times.txt").write_text("".join(f"{0.1 * i:.6f}\n" for i in range(n)))
    return seq


def test_frames_count_the_files_frames_when_the_truth_starts_late(tmp_path, capsys):
    """A --ground-truth starting at frame 4 dropped frames 0-3 before --frames was
    applied, so --frames 0:8 ran file frames 4-11 and said nothing of it."""
    import numpy as np

    seq = _kitti_like(tmp_path / "k", 12)
    from scipy.spatial.transform import Rotation

    truth = tmp_path / "gt.tum"  # TUM, by time: the times of frames 4..11
    lines = []
    for i in range(4, 12):
        wTc = np.asarray(seq.wTc_true[i])
        q = Rotation.from_matrix(wTc[:3, :3]).as_quat()  # x y z w, TUM's order
        lines.append(" ".join(f"{v:.9f}" for v in (0.1 * i, *wTc[:3, 3], *q)) + "\n")
    truth.write_text("".join(lines))
    out = tmp_path / "o"
    argv = ["run", "--dataset", str(tmp_path / "k"), "--frames", "0:8", "--ground-truth", str(truth),
            "--odometry", "derived", "--quiet", "--rerun", "off", "--out", str(out)]
    assert main(argv) == 0
    stamps = np.loadtxt(out / "trajectory.tum", ndmin=2)[:, 0]
    np.testing.assert_allclose(stamps, 0.1 * np.arange(4, 8), atol=1e-6)  # frames 4-7, not 4-11
    warned = json.loads((out / "metrics.json").read_text())["warnings"]
    assert any("4 of 8 frames selected have no ground truth" in w for w in warned), warned


def test_a_rotation_off_so3_is_projected_before_it_enters_gtsam():
    """A camera coasting over 15 black frames composed products of products: its
    rotation drifted off SO(3) (gtsam's Rot3(matrix) keeps what it is given) until the
    matrix was zero and numpy warned "invalid value encountered in divide"."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from graphslam.backends import gtsam_convert as conv

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.1, -0.4, 0.2]).as_matrix()
    T[:3, 3] = [1.0, 2.0, 3.0]
    exact = conv.pose3(T).matrix()
    assert np.array_equal(exact, T)  # on SO(3): the very bits (runs stay repeatable)
    drifted = T.copy()
    drifted[:3, :3] *= 1.001  # 2e-3 off, as the coasting camera was
    R = conv.pose3(drifted).rotation().matrix()
    assert np.linalg.norm(R.T @ R - np.eye(3)) < 1e-12
    np.testing.assert_allclose(R, T[:3, :3], atol=1e-12)  # the nearest rotation: the original
    np.testing.assert_array_equal(conv.pose3(drifted).translation(), T[:3, 3])


def test_a_file_value_an_override_replaces_is_still_checked(tmp_path, capsys):
    """``[isam2_visual] robot_model = "banana"`` ran under ``--odometry none`` (which sets
    the robot model) and was refused only with odometry."""
    cfg = tmp_path / "c.toml"
    cfg.write_text('[isam2_visual]\nrobot_model = "banana"\n')
    argv = ["run", "--dataset", "synthetic-images", "--max-steps", "5", "--odometry", "none",
            "--config", str(cfg), "--quiet", "--rerun", "off", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.strip() == (f"graphslam: error: {cfg}:2: isam2_visual.robot_model must be one of "
                           "['odometry', 'constant_velocity'], got 'banana'")


def test_localize_says_which_config_sections_it_does_not_read(tmp_path, capsys):
    """A run's config given to localize: ``[tracker] detector = "harris"`` on an ORB map
    and ``[isam2_visual] min_parallax_deg = 200`` did nothing, unchecked, without a word."""
    m = tmp_path / "m"
    argv = ["run", "--dataset", "synthetic-images", "--max-steps", "12", "--quiet", "--rerun", "off",
            "--out", str(tmp_path / "o"), "--save-map", str(m)]
    assert main(argv) == 0
    cfg = tmp_path / "c.toml"
    cfg.write_text('[tracker]\ndetector = "harris"\n[isam2_visual]\nmin_parallax_deg = 200\n'
                   "[localize]\nmin_inliers = 15\n")
    capsys.readouterr()
    argv = ["localize", "--map", str(m), "--dataset", "synthetic-images", "--frames", "0:4",
            "--config", str(cfg), "--quiet", "--rerun", "off", "--out", str(tmp_path / "l")]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert (f"--config {cfg}: [tracker], [isam2_visual] not read by localize (the map fixes its "
            "tracker and back end); those settings did nothing and were not checked") in err


def test_loops_with_intrinsics_refuses_an_image_of_another_size(tmp_path, capsys):
    """One photo resized among the desk's with --intrinsics: its true closure was lost
    (matched under another camera's K) and the run said "0 closures" only."""
    import cv2
    import numpy as np

    folder = tmp_path / "imgs"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(folder / f"{i:02d}.png"), rng.integers(0, 255, (120, 160), dtype=np.uint8))
    big = cv2.resize(cv2.imread(str(folder / "02.png")), (320, 240))
    cv2.imwrite(str(folder / "02.png"), big)
    k = tmp_path / "k.txt"
    k.write_text("125 125 79.5 59.5\n")
    argv = ["loops", str(folder), "--intrinsics", str(k), "--out", str(tmp_path / "l.csv"), "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"graphslam: error: {folder / '02.png'}: image is 320x240 px, 00.png is 160x120: "
                   "--intrinsics describes one camera at one resolution (without it, images of any "
                   "size are matched)")


def _run_2d(tmp_path, capsys, *args, config: str | None = None) -> dict:
    argv = ["run", "--quiet", "--rerun", "off", "--out", str(tmp_path / "o"), *args]
    if config is not None:
        (tmp_path / "c.toml").write_text(config)
        argv += ["--config", str(tmp_path / "c.toml")]
    assert main(argv) == 0
    capsys.readouterr()
    return json.loads((tmp_path / "o" / "metrics.json").read_text())


def test_a_map_that_corrected_nothing_is_said(tmp_path, capsys):
    """Unknown ids where no candidate is ever confirmed: the dead reckoning to the last
    digit, as a quiet run."""
    m = _run_2d(tmp_path, capsys, "--backend", "ekf",
                config="[ekf]\nassociation = 'unknown'\nprovisional_sightings = 1000\n")
    assert m["landmarks"] == 0
    assert any(w.startswith("none of the 866 observations let in made a landmark") for w in m["warnings"])


def test_a_map_of_landmarks_seen_once_is_said(tmp_path, capsys):
    """Each sighting its own landmark: 864 landmarks from 866 sightings, the dead reckoning."""
    m = _run_2d(tmp_path, capsys, "--backend", "ekf",
                config="[ekf]\nassociation = 'unknown'\nnew_landmark_density_per_m2 = 1e9\n")
    said = [w for w in m["warnings"] if "under two sightings each" in w]
    assert said and said[0].startswith(f"{m['landmarks']} landmarks from 866 observations"), m["warnings"]


def test_a_sound_map_says_nothing_of_its_landmarks(tmp_path, capsys):
    m = _run_2d(tmp_path, capsys, "--backend", "ekf", config="[ekf]\nassociation = 'unknown'\n")
    assert not any("sightings" in w or "made a landmark" in w for w in m.get("warnings") or [])


def test_fastslam_records_its_particles_seed(tmp_path, capsys):
    """``--seed 3`` on a real log changed the answer, and metrics.json said ``"seed": null``."""
    m = _run_2d(tmp_path, capsys, "--backend", "fastslam2", "--max-steps", "30",
                config="[fastslam]\nseed = 7\n")
    assert m["seed"] == 0 and m["backend_seed"] == 7  # the world's, the particles'


def test_loop_closure_settings_on_a_run_without_closures_are_said(tmp_path, capsys):
    """``[isam2] polish_method = "gnc"`` on a landmark world: bit-identical to the default,
    without a word."""
    from graphslam.backends.planar.isam2_config import Isam2Config

    assert set(Isam2Config.LOOP_CLOSURE_KEYS) <= set(Isam2Config.__dataclass_fields__)
    m = _run_2d(tmp_path, capsys, "--max-steps", "40",
                config="[isam2]\npolish_method = 'gnc'\nrelinearize_skip = 5\n")
    said = "[isam2] polish_method did nothing: it acts only with loop closures (this run had none)"
    assert any(said in w for w in m["provenance"]["did_nothing"])  # and on stderr


def test_a_back_end_failure_late_in_a_visual_run_keeps_the_frames_before_it(tmp_path, capsys, monkeypatch):
    """iSAM2 failing 100 frames into a run ("indeterminate linear system near x100") wrote
    nothing: every frame's work was lost to one numerical failure."""
    import numpy as np

    from graphslam.backends.spatial.isam2 import VisualIsam2Backend
    from slamcore.errors import GraphSlamError

    update = VisualIsam2Backend.update

    def failing(self, observations):
        if len(self._frames) == 4:
            raise GraphSlamError("isam2 (visual): indeterminate linear system near x3 at frame 3")
        return update(self, observations)

    monkeypatch.setattr(VisualIsam2Backend, "update", failing)
    out = tmp_path / "o"
    argv = ["run", "--dataset", "synthetic-images", "--max-steps", "8", "--quiet", "--rerun", "off",
            "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"graphslam: error: isam2 (visual): indeterminate linear system near x3 at frame 3; "
                   f"the run stopped at frame 3: {out}/ holds what it estimated from the frames before it"]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["interrupted"] is True and metrics["frames"] == 3
    assert len(np.loadtxt(out / "trajectory.tum", ndmin=2)) >= 3


def test_a_back_end_failure_at_the_first_frame_is_the_plain_error(tmp_path, capsys, monkeypatch):
    from graphslam.backends.spatial.isam2 import VisualIsam2Backend
    from slamcore.errors import GraphSlamError

    def failing(self, observations):
        raise GraphSlamError("isam2 (visual): broken")

    monkeypatch.setattr(VisualIsam2Backend, "update", failing)
    argv = ["run", "--dataset", "synthetic-images", "--max-steps", "8", "--quiet", "--rerun", "off",
            "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    assert capsys.readouterr().err.strip() == "graphslam: error: isam2 (visual): broken"
    assert not (tmp_path / "o" / "trajectory.tum").exists()


def test_run_with_a_map_records_it_and_scores_in_its_frame(tmp_path, capsys):
    """``run --map``: nothing in the outputs said a map was used, and the SE(3)-aligned
    ATE hid the run's offset from the map (what --map is for)."""
    import numpy as np

    m = tmp_path / "m"
    base = ["run", "--dataset", "synthetic-images", "--quiet", "--rerun", "off"]
    assert main([*base, "--frames", "0:14", "--out", str(tmp_path / "a"), "--save-map", str(m)]) == 0
    assert main([*base, "--frames", "8:20", "--out", str(tmp_path / "b"), "--map", str(m)]) == 0
    said = capsys.readouterr().out
    rec = json.loads((tmp_path / "b" / "metrics.json").read_text())["map"]
    assert rec["path"] == str(m) and "relocalised" in rec["start"]
    est = np.loadtxt(tmp_path / "b" / "trajectory.tum", ndmin=2)
    gt = np.loadtxt(tmp_path / "b" / "ground_truth.tum", ndmin=2)
    rows = np.searchsorted(gt[:, 0], est[:, 0])  # the truth at the estimate's stamps
    assert np.allclose(gt[rows, 0], est[:, 0])
    e = np.linalg.norm(est[:, 1:4] - gt[rows, 1:4], axis=1)  # no alignment: the map's frame
    assert rec["ate_in_map_frame"]["alignment"] == "none"
    assert abs(rec["ate_in_map_frame"]["rmse_m"] - float(np.sqrt(np.mean(e**2)))) < 1e-6
    assert f"{rec['ate_in_map_frame']['rmse_m']:.4f}" in said


def test_a_back_end_broken_by_its_failure_is_one_line(tmp_path, capsys, monkeypatch):
    """After iSAM2's failure its estimate() raised gtsam's IndexError ("Requested the
    BayesTree clique for a key that is not in the BayesTree"): a traceback."""
    from graphslam.backends.spatial.isam2 import VisualIsam2Backend
    from slamcore.errors import GraphSlamError

    update = VisualIsam2Backend.update

    def failing(self, observations):
        if len(self._frames) == 4:
            raise GraphSlamError("isam2 (visual): indeterminate linear system near x3 at frame 3")
        return update(self, observations)

    def broken(self):
        raise IndexError("Requested the BayesTree clique for a key that is not in the BayesTree")

    monkeypatch.setattr(VisualIsam2Backend, "update", failing)
    monkeypatch.setattr(VisualIsam2Backend, "estimate", broken)
    argv = ["run", "--dataset", "synthetic-images", "--max-steps", "8", "--quiet", "--rerun", "off",
            "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    assert capsys.readouterr().err.strip() == (
        "graphslam: error: isam2 (visual): indeterminate linear system near x3 at frame 3")


def test_rpy_of_a_rotation_at_90_degrees_pitch_rebuilds_it():
    """g2o -> TORO at pitch 90 deg wrote a rotation 63 deg off (arcsin and two atan2 of
    rounding noise); 1e-12 below it, 9e-5 rad off."""
    import numpy as np

    from slamcore.posegraph import matrix_to_rpy, rpy_to_matrix

    rng = np.random.default_rng(3)
    rpy = np.column_stack([rng.uniform(-np.pi, np.pi, 60), rng.uniform(-1.5, 1.5, 60),
                           rng.uniform(-np.pi, np.pi, 60)])
    rpy[:6, 1] = np.pi / 2 - np.array([0.0, 1e-12, 1e-10, 1e-9, 1e-8, 1e-7])
    rpy[6:9, 1] = -np.pi / 2 + np.array([0.0, 1e-12, 1e-9])
    R = rpy_to_matrix(rpy)
    back = rpy_to_matrix(matrix_to_rpy(R))
    assert np.max(np.abs(back - R)) < 1e-14  # the same rotation, to rounding
    away = np.abs(np.abs(rpy[:, 1]) - np.pi / 2) > 1e-3  # away from the lock: the same angles
    np.testing.assert_allclose(matrix_to_rpy(R)[away], rpy[away], atol=1e-12)


def test_trajectory_tum_keeps_large_ids_and_coordinates_exact(tmp_path, capsys):
    """Pose ids past 2**53 (the readers take up to 2**62) became equal timestamps, and a
    UTM easting of 4500000.123456 m was written 4500000.12 (9 significant digits)."""
    b = 2**53
    g = tmp_path / "g.g2o"
    g.write_text(f"VERTEX_SE2 {b} 4500000.123456 5300000.654321 0.1\n"
                 f"VERTEX_SE2 {b + 1} 4500001.123456 5300000.754321 0.2\n"
                 f"VERTEX_SE2 {b + 2} 4500002.103456 5300000.954321 0.3\n"
                 f"EDGE_SE2 {b} {b + 1} 1.0 0.0 0.1 100 0 0 100 0 100\n"
                 f"EDGE_SE2 {b + 1} {b + 2} 1.0 0.1 0.1 100 0 0 100 0 100\n")
    out = tmp_path / "o"
    assert main(["run", "--dataset", str(g), "--backend", "batch", "--init", "vertices", "--quiet",
                 "--rerun", "off", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "repeat an earlier edge" not in err  # two different edges, ids apart by one
    rows = [ln.split() for ln in (out / "trajectory.tum").read_text().splitlines()[1:]]
    assert [r[0] for r in rows] == [str(b), str(b + 1), str(b + 2)]
    assert rows[0][1:3] == ["4500000.123456", "5300000.654321"]  # the fixed first pose, exact
    assert abs(float(rows[2][1]) - 4500002.07865981) < 1e-6


def test_ekf_default_sigmas_in_a_run_are_said_to_do_nothing(tmp_path, capsys):
    """``[ekf] default_sigma_range_m = 1e-12`` gave the default run to the last bit."""
    from filters.ekf_slam_config import EkfSlamConfig

    assert set(EkfSlamConfig.UNREAD_IN_RUNS) <= set(EkfSlamConfig.__dataclass_fields__)
    m = _run_2d(tmp_path, capsys, "--backend", "ekf", "--max-steps", "30",
                config="[ekf]\ndefault_sigma_range_m = 1e-12\n")
    said = "[ekf] default_sigma_range_m did nothing: it acts only with observations without a covariance"
    assert any(said in w for w in m["provenance"]["did_nothing"])  # and on stderr


def test_inverse_depth_landmarks_without_parallax_are_counted():
    """The monocular EKF's landmarks.csv held points at the initial depth guess (15-17 m
    for KITTI points 73-6500 m away) with nothing telling them apart."""
    import numpy as np

    from filters import landmark_params as lp
    from filters.mono_ekf_map import undetermined_depths

    kinds = np.array([lp.IDP, lp.IDP, lp.EUCLIDEAN])
    idx = np.array([[0, 1, 2, 3, 4, 5, 5], [6, 7, 8, 9, 10, 11, 11], [12, 13, 14, 14, 14, 14, 14]])
    x = np.zeros(15)
    x[5], x[11] = 0.06, 0.06  # both at 1/0.06 = 16.7 m
    P = np.eye(15) * 1e-4
    P[5, 5] = 0.04**2  # 0.06 within two sigma (0.08) of zero: depth unbounded
    P[11, 11] = 0.01**2  # six sigma from zero: measured
    assert undetermined_depths(x, P, idx, kinds).tolist() == [True, False, False]
    # A camera that only turned: the priors put rho0 at two sigmas, and the sightings
    # shrank the variance by 2 % (through the pose): a hair inside the bound, counted
    # as measured at the guessed depth. Against the prior it is the prior's depth.
    prior_var = np.array([0.03**2, 0.03**2, 0.0])
    x[11], P[11, 11] = 0.06, 0.98 * 0.03**2
    assert undetermined_depths(x, P, idx, kinds).tolist() == [True, False, False]
    assert undetermined_depths(x, P, idx, kinds, prior_var).tolist() == [True, True, False]
    P[11, 11] = 0.4 * 0.03**2  # the images gave more than the prior: measured
    assert undetermined_depths(x, P, idx, kinds, prior_var).tolist() == [True, False, False]


def test_a_filter_far_beyond_its_own_covariance_from_isam2_is_said():
    """Victoria Park's first 1896 steps: the EKF 56 m from iSAM2 (26.9 of its own sigmas),
    with unknown ids 202 m (36.1), printed in compare's table without a word."""
    import numpy as np

    from graphslam.evaluation.planar import reference_warning, sigmas_to_reference
    from slamcore.planar.records import Estimate

    rng = np.random.default_rng(0)
    n = 50
    ref_wTb = np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)])
    cov = np.tile(np.diag([0.1**2, 0.1**2, 0.01**2]), (n, 1, 1))

    def estimate(offset_sigmas: float) -> Estimate:
        err = rng.normal(size=(n, 3)) * [0.1, 0.1, 0.01] * offset_sigmas
        return Estimate(pose_ids=np.arange(n), wTb=ref_wTb + err, landmark_ids=np.zeros(0, np.int64),
                        landmarks_w=np.zeros((0, 2)), pose_covariances=cov)

    ref = Estimate(pose_ids=np.arange(n), wTb=ref_wTb, landmark_ids=np.zeros(0, np.int64),
                   landmarks_w=np.zeros((0, 2)))
    sound = sigmas_to_reference(estimate(1.0), ref)
    assert 0.7 < sound < 1.3  # its own sigmas: about one
    far = sigmas_to_reference(estimate(30.0), ref)
    assert 20 < far < 40
    assert reference_warning(sound, 0.1) == []
    assert reference_warning(far, 0.5) == []  # within a metre: the ATE rule's floor
    said = reference_warning(far, 56.0)
    assert len(said) == 1 and said[0].startswith(f"its poses are {far:.3g} of its own sigmas (56 m RMS)")


def test_active_search_mode_against_the_trackers_search_is_refused(tmp_path, capsys):
    """``[active_search] mode = "nearest"`` was overwritten by the tracker's search: no effect."""
    cfg = tmp_path / "c.toml"
    cfg.write_text('[active_search]\nmode = "nearest"\n')
    argv = ["run", "--dataset", "synthetic-images", "--max-steps", "5", "--config", str(cfg), "--quiet",
            "--rerun", "off", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    assert "[tracker] search) decides the mode here" in capsys.readouterr().err
    assert main([*argv[:-1], str(tmp_path / "o2"), "--frontend", "fpga"]) == 0  # the same mode: fine


def test_a_run_names_the_config_sections_it_never_read(tmp_path, capsys):
    """``[ekf] zzz = 1`` under the default back end ran silently (an unknown key, never checked)."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[ekf]\nzzz = 1\n[isam2]\npolish = true\n")
    argv = ["run", "--max-steps", "20", "--config", str(cfg), "--quiet", "--rerun", "off",
            "--out", str(tmp_path / "o")]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert (f"--config {cfg}: [ekf] not read by this run (isam2 on synthetic); those settings did "
            "nothing and were not checked") in err
    assert "[isam2]" not in err


def test_eval_refuses_time_flags_on_files_paired_by_line(tmp_path, capsys):
    """``--max-diff 5 --offset 3`` on KITTI files changed nothing and eval.json recorded them."""
    import numpy as np

    poses = np.tile(np.eye(4)[:3].reshape(1, 12), (5, 1))
    poses[:, 3] = np.arange(5)
    gt = tmp_path / "gt.txt"
    np.savetxt(gt, poses)
    assert main(["eval", str(gt), str(gt), "--max-diff", "5", "--offset", "3", "--no-plot",
                 "--out", str(tmp_path / "e")]) == 2
    assert capsys.readouterr().err.strip() == (
        "graphslam: error: --max-diff and --offset act on timestamps, and these files have none "
        "(KITTI: paired by line); give them times with --times")


def test_vocab_flat_refuses_a_branching(tmp_path, capsys):
    argv = ["vocab", "train", str(tmp_path), "--flat", "--branching", "3", "--out", str(tmp_path / "v.npz")]
    assert main(argv) == 2
    assert "--flat trains one flat k-means, no tree" in capsys.readouterr().err


def test_isam2_without_its_polish_does_not_call_its_closures_kept_by_setting(tmp_path, capsys):
    """``--backend isam2 --no-polish`` with ``robust_closures = "gnc"``: the summary said
    'robust_closures = "none": every closure kept'. The closures went in under iSAM2's
    Cauchy kernel and were never tested (the test runs in the polish)."""
    import gtsam

    cfg = tmp_path / "c.toml"
    cfg.write_text('[posegraph]\nrobust_closures = "gnc"\n')
    out = tmp_path / "o"
    argv = ["run", "--dataset", gtsam.findExampleDataFile("w100.graph"), "--backend", "isam2", "--no-polish",
            "--config", str(cfg), "--quiet", "--rerun", "off", "--out", str(out)]
    assert main(argv) == 0
    said = capsys.readouterr().out
    m = json.loads((out / "metrics.json").read_text())
    assert m["closures"] > 0 and m["closure_test"] == {"robust_closures": "gnc", "tested": False}
    assert f"none tested of {m['closures']} (no polish" in said and 'robust_closures = "none"' not in said


def test_odometry_noise_in_a_file_for_a_run_without_derived_odometry_is_said(tmp_path, capsys):
    """``--odometry-noise`` is refused where the sequence brings its odometry; the same
    numbers in ``[odometry_noise]`` gave a byte-identical run without a word."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[odometry_noise]\nsigma_t_per_m = 0.2\nsigma_r_deg = 1.0\n")
    argv = ["run", "--dataset", "synthetic-images", "--max-steps", "5", "--config", str(cfg), "--quiet",
            "--rerun", "off", "--out", str(tmp_path / "o")]
    assert main(argv) == 0
    assert (f"--config {cfg}: [odometry_noise] sets the noise of derived odometry; this run uses the "
            "sequence's own odometry (--odometry sequence): it did nothing") in capsys.readouterr().err
