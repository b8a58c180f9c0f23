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
            "tracker and back end); those settings do nothing and are not checked") in err


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
