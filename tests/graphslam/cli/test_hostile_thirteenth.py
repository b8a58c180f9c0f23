"""Thirteenth hostile pass (2026-12-01): settings on their way to a run, the figures of
compare and sweep, saved maps and localisation, large inputs. One test a fix.

Run in process through :func:`graphslam.cli.main.main`, which turns errors into one
``graphslam: error:`` line and exit status 2.
"""

from __future__ import annotations

import json

import pytest

from graphslam.cli.main import main

RUN = ["--rerun", "off", "--quiet"]
#: a few KITTI frames give the camera alone too little parallax: odometry from the truth
DERIVED = ["--odometry", "derived"]

def test_compare_records_the_seed_the_config_file_gave(tmp_path):
    """``[synthetic] seed = 2`` ran seed 2 and compare.json said ``"seed": null``."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[synthetic]\nseed = 2\n")
    out = tmp_path / "o"
    assert main(["compare", "--config", str(cfg), "--backends", "isam2", "--max-steps", "20",
                 "--rerun", "off", "--out", str(out)]) == 0
    runs = json.loads((out / "compare.json").read_text())["runs"]
    assert runs[0]["seed"] == 2

def test_robot_flag_wins_over_a_file_running_all_robots(tmp_path, capsys, shared_data):
    """``--robot 2`` under ``[mrclam] all_robots = true`` ran the five robots, silent."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[mrclam]\nall_robots = true\n")
    out = tmp_path / "o"
    assert main(["run", "--dataset", str(shared_data / "mrclam6"), "--robot", "2", "--config", str(cfg),
                 "--max-steps", "30", *RUN, "--out", str(out)]) == 0
    assert json.loads((out / "metrics.json").read_text())["dataset"] == "mrclam6-robot2"
    assert "[mrclam] all_robots did nothing: the command line's false" in capsys.readouterr().err

@pytest.fixture(scope="module")
def kitti_plain_map(tmp_path_factory, shared_data):
    """KITTI 07 frames 0-29 as a plain image folder with KITTI's intrinsics (no
    distortion), its derived odometry, and the map of a run on it."""
    root = tmp_path_factory.mktemp("plain")
    images = root / "images"
    images.mkdir()
    for i in range(30):
        (images / f"{i:06d}.png").symlink_to(shared_data / "kitti07" / "image_0" / f"{i:06d}.png")
    (root / "k.txt").write_text("707.0912 707.0912 601.8873 183.1104\n")
    assert main(["run", "--dataset", str(shared_data / "kitti07"), "--frames", "0:30", *RUN, *DERIVED,
                 "--save-map", str(root / "map"), "--out", str(root / "run")]) == 0
    return root

def test_the_same_camera_written_to_three_decimals_is_the_maps(kitti_plain_map, tmp_path, capsys):
    """707.091 for 707.0912 moved no pixel by 0.001 px and was refused as another camera."""
    k3 = tmp_path / "k3.txt"
    k3.write_text("707.091 707.091 601.887 183.110\n")
    assert main(["localize", "--map", str(kitti_plain_map / "map"), "--dataset", str(kitti_plain_map / "images"),
                 "--intrinsics", str(k3), *RUN, "--out", str(tmp_path / "l")]) == 0

def test_a_map_of_one_lens_model_is_refused_with_another(kitti_plain_map, tmp_path, capsys):
    """map.json held no distortion: a map read with k1 = -0.2 was used without it, silent."""
    kd = tmp_path / "kd.txt"
    kd.write_text("707.0912 707.0912 601.8873 183.1104\n-0.2 0 0 0\n")
    assert main(["localize", "--map", str(kitti_plain_map / "map"), "--dataset", str(kitti_plain_map / "images"),
                 "--intrinsics", str(kd), *RUN, "--out", str(tmp_path / "l")]) == 2
    assert "another camera" in capsys.readouterr().err

def test_save_map_refuses_a_folder_holding_someone_elses_map_json(tmp_path, capsys, shared_data):
    folder = tmp_path / "project"
    folder.mkdir()
    (folder / "map.json").write_text('{"type": "FeatureCollection", "features": []}')
    assert main(["run", "--dataset", str(shared_data / "kitti07"), "--frames", "0:5", *RUN, *DERIVED,
                 "--save-map", str(folder), "--out", str(tmp_path / "o")]) == 2
    assert "not a graphslam map" in capsys.readouterr().err
    assert "FeatureCollection" in (folder / "map.json").read_text()

def test_a_map_without_landmarks_says_so(tmp_path, capsys, shared_data):
    assert main(["run", "--dataset", str(shared_data / "kitti07"), "--frames", "0:1", *RUN, *DERIVED,
                 "--save-map", str(tmp_path / "m"), "--out", str(tmp_path / "o")]) == 0
    assert "has no landmark" in capsys.readouterr().err

def test_a_map_with_nan_covariances_or_a_scaled_rotation_is_refused(kitti_plain_map, tmp_path):
    import shutil

    import numpy as np

    from graphslam.maps.files import load_map, save_map
    from slamcore.errors import InputError

    smap = load_map(kitti_plain_map / "map")
    for name, spoil in (("keyframe_cov", lambda a: a.__setitem__((0, 0, 0), np.nan)),
                        ("keyframe_wTc", lambda a: a.__setitem__((1, slice(0, 3), slice(0, 3)), 2 * a[1, :3, :3])),
                        ("landmark_w", lambda a: a.__imul__(1e160))):
        folder = tmp_path / name
        shutil.copytree(kitti_plain_map / "map", folder)
        bad = load_map(folder)
        arr = getattr(bad, name).copy()
        spoil(arr)
        setattr(bad, name, arr)
        with pytest.raises(InputError):
            save_map(bad, folder)  # the same checks guard loading
    assert smap.n_keyframes == 30

#: chi-square 99 % quantile of 6 degrees of freedom: the mean pose NEES of a placement
#: that knows its error stays below what one pose exceeds 1 % of the time.
NEES_6DOF_99 = 16.81

@pytest.mark.slow
def test_localize_covariance_holds_the_maps_own_uncertainty(tmp_path):
    """The covariance was PnP's alone, the map taken as exact: the synthetic room mapped
    on frames 0-149 and placed on 150-299 had a mean NEES of 317 against the truth (4.9
    with the nearest keyframe's covariance carried to the camera)."""
    import csv

    import numpy as np

    from graphslam.evaluation.spatial import pose_errors

    assert main(["run", "--dataset", "synthetic-images", "--frames", "0:150", *RUN,
                 "--save-map", str(tmp_path / "m"), "--out", str(tmp_path / "r")]) == 0
    assert main(["localize", "--map", str(tmp_path / "m"), "--dataset", "synthetic-images",
                 "--frames", "150:300", *RUN, "--out", str(tmp_path / "l")]) == 0
    truth = {}
    for line in (tmp_path / "l" / "ground_truth.tum").read_text().splitlines():
        if line and not line.startswith("#"):
            v = [float(x) for x in line.split()]
            truth[round(v[0], 6)] = v[1:]

    def pose(v):
        from scipy.spatial.transform import Rotation

        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(v[3:7]).as_matrix()
        T[:3, 3] = v[:3]
        return T

    iu = np.triu_indices(6)
    nees = []
    with open(tmp_path / "l" / "localize.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["status"] == "lost":
                continue
            est = pose([float(row[k]) for k in ("x", "y", "z", "qx", "qy", "qz", "qw")])
            gt = pose(truth[round(float(row["t"]), 6)])
            C = np.zeros((6, 6))
            C[iu] = [float(row[f"c{i}{j}"]) for i, j in zip(*iu)]
            C = C + C.T - np.diag(np.diag(C))
            e = pose_errors(est[None], gt[None])[0]
            nees.append(float(e @ np.linalg.solve(C, e)))
    assert len(nees) > 100
    assert np.mean(nees) < NEES_6DOF_99, np.mean(nees)

def test_vocab_train_says_the_loop_settings_it_does_not_read(tmp_path, capsys, shared_data):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[loops]\nmin_score = 0.05\n[loops.orb]\nn_features = 300\n")
    assert main(["vocab", "train", str(shared_data / "slambook2_desk" / "images"), "--words", "20",
                 "--out", str(tmp_path / "v.npz"), "--config", str(cfg), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "[loops] min_score did nothing" in err and "n_features" not in err

def test_a_joined_map_names_all_its_frames_and_a_repeated_session(kitti_plain_map, tmp_path, capsys, shared_data):
    """A joined map said the last session's frames only, and the same session joined
    twice doubled its keyframes, silent."""
    import shutil

    folder = tmp_path / "m"
    shutil.copytree(kitti_plain_map / "map", folder)
    for _ in range(2):
        assert main(["run", "--dataset", str(shared_data / "kitti07"), "--frames", "10:30", *RUN, *DERIVED,
                     "--map", str(folder), "--save-map", str(folder), "--out", str(tmp_path / "o")]) == 0
    assert "ran the same frames (10:30)" in capsys.readouterr().err
    meta = json.loads((folder / "map.json").read_text())["meta"]
    assert (meta["frames"], meta["n_frames"]) == ("0:30 + 10:30 + 10:30", 70)

def test_a_held_stop_is_acknowledged_and_the_signal_that_ends_is_named(capfd):
    """A Ctrl-C during vocab training was held for minutes with nothing said, and the
    SIGTERM that then ended it was reported as "interrupted (SIGINT)", status 130."""
    import os
    import signal

    from graphslam.pipelines.common import stop_guard

    with stop_guard() as guard:
        guard.defer()
        guard.held_note = "stop asked: the training ends first"
        os.kill(os.getpid(), signal.SIGINT)
        assert guard.requested
        assert "graphslam: SIGINT: stop asked: the training ends first" in capfd.readouterr().err
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)
        assert (guard.signal_name, guard.exit_status()) == ("SIGTERM", 143)

def test_compare_names_unread_sections_and_each_columns_fit(tmp_path, capsys):
    """[posegraph] and [fastslam] under --backends isam2 ekf ran silent (run says so), and
    an SE(2)-fitted ATE stood beside the unaligned final error with nothing said."""
    cfg = tmp_path / "c.toml"
    cfg.write_text('[posegraph]\ninit = "lago"\n[fastslam]\nn_particles = 10\n')
    assert main(["compare", "--config", str(cfg), "--backends", "isam2", "ekf", "--max-steps", "30",
                 "--rerun", "off", "--out", str(tmp_path / "o")]) == 0
    out, err = capsys.readouterr()
    assert "[posegraph], [fastslam] not read by this comparison" in err
    assert "ATE [m] (SE(2) fit)" in out and "final err [m] (no fit)" in out

def test_a_runs_metrics_say_what_ran(tmp_path):
    """metrics.json held no command, config or settings: a run could not be made again
    from its outputs. Rerun from the recorded settings: the same trajectory bytes."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[isam2]\nrelinearize_threshold = 0.2\n")
    out = tmp_path / "a"
    assert main(["run", "--max-steps", "40", "--no-polish", "--config", str(cfg), *RUN, "--out", str(out)]) == 0
    prov = json.loads((out / "metrics.json").read_text())["provenance"]
    assert prov["command"][:2] == ["graphslam", "run"] and prov["config_file"] == str(cfg)
    assert prov["settings"]["isam2"]["polish"] is False
    assert prov["settings"]["isam2"]["relinearize_threshold"] == 0.2

    lines = []
    for section, values in prov["settings"].items():
        lines.append(f"[{section}]")
        lines += [f"{k} = {json.dumps(v)}" for k, v in values.items() if v is not None]
    (tmp_path / "again.toml").write_text("\n".join(lines) + "\n")
    again = tmp_path / "b"
    assert main(["run", "--max-steps", "40", "--config", str(tmp_path / "again.toml"), *RUN, "--out", str(again)]) == 0
    assert (out / "trajectory.tum").read_bytes() == (again / "trajectory.tum").read_bytes()


def test_a_sweep_says_once_what_its_runs_said_of_their_config(tmp_path, capsys):
    """Each run's "[fastslam] not read" was in its stderr.txt only: the sweep said "1 ok"."""
    (tmp_path / "base.toml").write_text('[fastslam]\nn_particles = 5\n')
    (tmp_path / "sweep.toml").write_text('[sweep]\ndataset = ["synthetic"]\nbackend = ["isam2"]\n'
                                         'seed = [0, 1]\nmax_steps = 20\nconfig = "base.toml"\n')
    assert main(["sweep", str(tmp_path / "sweep.toml"), "--out", str(tmp_path / "o"), "--workers", "1",
                 "--no-plots", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err.count("[fastslam] not read by this run") == 1 and "2 of 2 runs" in err


def test_a_sweep_of_seeds_over_runs_that_draw_nothing_is_refused_before_it_starts(tmp_path, capsys, shared_data):
    """Every isam2 run on MRCLAM failed on --seed one by one, then "6 of 12 runs failed"."""
    (tmp_path / "s.toml").write_text(f'[sweep]\ndataset = ["{shared_data / "mrclam6"}"]\n'
                                     'backend = ["isam2", "fastslam2"]\nseed = [0, 1]\nmax_steps = 20\n')
    assert main(["sweep", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert "isam2 on" in capsys.readouterr().err and not (tmp_path / "o" / "runs").exists()


@pytest.mark.parametrize("dataset,xyz", [("kitti07", [3, 2, 5]), ("synthetic-images", [3, 5, 1])])
def test_a_recordings_world_is_declared_the_way_its_first_camera_stands(tmp_path, shared_data, dataset, xyz):
    """KITTI's world is its first camera's frame (right, down, forward): declared z-up,
    the viewer drew the car climbing. The synthetic room is z-up. (ViewDir codes: Up 1,
    Down 2, Right 3, Forward 5.)"""
    from rerun.chunk import RrdReader

    source, own = (str(shared_data / dataset), DERIVED) if dataset == "kitti07" else (dataset, [])
    assert main(["run", "--dataset", source, "--max-steps", "3", *own, "--quiet", "--out", str(tmp_path / "o")]) == 0
    found = [c.to_record_batch().column("ViewCoordinates:xyz").to_pylist()
             for c in RrdReader(str(tmp_path / "o" / "run.rrd")).stream()
             if c.entity_path == "/world" and c.is_static]
    assert found == [[[xyz]]]


def test_a_run_of_large_images_that_maps_nothing_names_the_pixel_settings():
    from graphslam.pipelines.spatial import _large_image_hint

    assert "sigma_px" in _large_image_hint(3678) and "3678" in _large_image_hint(3678)
    assert _large_image_hint(1241) == ""


def test_a_tum_file_read_at_once_is_the_line_readers_to_the_bit(tmp_path, monkeypatch):
    """The whole-file parse (a million-pose eval took 51 s, now 20 s) gives the line
    reader's numbers, and leaves every malformed line to it (its error names the line)."""
    import numpy as np

    import graphslam.sources.ground_truth as gt
    from slamcore.errors import InputError

    rng = np.random.default_rng(4)
    q = rng.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    rows = [f"{1e9 + 0.1 * k:.6f} {rng.normal():.9g} {rng.normal() * 1e3:.4e} +.5 {q[k, 0]:.9f} "
            f"{q[k, 1]:.9f} {q[k, 2]:.9f} {q[k, 3] * 1.01:.9f}" for k in range(500)]
    path = tmp_path / "t.tum"
    path.write_text("# t x y z qx qy qz qw\n" + "\n".join(rows[::-1]) + "\n")
    fast = gt.read_trajectory(path)
    monkeypatch.setattr(gt, "_tum_at_once", lambda lines: None)
    slow = gt.read_trajectory(path)
    assert np.array_equal(fast.wTc, slow.wTc) and np.array_equal(fast.stamps_s, slow.stamps_s)
    monkeypatch.undo()
    for bad, line in (("1 2 3 inf 0 0 0 1", 3), ("1 2 3 4 0 0 0 5", 3), ("1 2 3 4 0 0 0", 3), ("1 2 1.2.3 4 0 0 0 1", 3)):
        path.write_text("0 0 0 0 0 0 0 1\n\n" + bad + "\n")
        with pytest.raises(InputError) as e:
            gt.read_trajectory(path)
        assert e.value.line == line


@pytest.mark.parametrize("backend,written,step", [("ekf", True, 40), ("isam2", False, 41)])
def test_an_interrupted_nees_run_of_a_filter_writes_the_steps_it_ran(tmp_path, monkeypatch, capsys, backend,
                                                                     written, step):
    """An interrupted --nees wrote no nees.csv, though a filter keeps each step's
    covariance as it goes; a smoother's come from its marginals at the end (none).
    (The hook fires once per process and spec: one step each.)"""
    monkeypatch.setenv("GRAPHSLAM_SIGNAL_AT", f"step:{step}")
    out = tmp_path / "o"
    assert main(["run", "--backend", backend, "--max-steps", "200", "--nees", *RUN, "--out", str(out)]) == 130
    assert (out / "nees.csv").is_file() == written
    if written:
        rows = (out / "nees.csv").read_text().splitlines()
        assert 30 < len(rows) - 1 < 60
        assert json.loads((out / "metrics.json").read_text())["nees_mean"] is not None
    else:
        assert "no nees.csv" in capsys.readouterr().err


def _plain_kitti(folder, shared_data, n=5):
    folder.mkdir()
    for i in range(n):
        (folder / f"{i:06d}.png").symlink_to(shared_data / "kitti07" / "image_0" / f"{i:06d}.png")
    return folder


@pytest.mark.parametrize("yaml,words", [
    ("distortion_model: equidistant\ndistortion: [0.003, 0.0007, -0.002, 0.0002]\n", "equidistant' is not supported"),
    ("camera_model: omni\n", "omni' is not supported"),
    ("distortion: [0.1, 0.01, 0.001]\n", "got 3"),
    ("distortion: [.nan, 0.01, 0.001, 0.0]\n", "non-finite"),
])
def test_calibration_yaml_that_opencv_cannot_take_is_refused_naming_the_file(tmp_path, capsys, shared_data,
                                                                               yaml, words):
    """A fisheye model was read as radial-tangential (a corner thousands of pixels off,
    silent), three coefficients were an OpenCV traceback, a NaN a failed start."""
    images = _plain_kitti(tmp_path / "imgs", shared_data)
    (images / "camera.yaml").write_text("fx: 707.0912\nfy: 707.0912\ncx: 601.8873\ncy: 183.1104\n" + yaml)
    assert main(["run", "--dataset", str(images), *RUN, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert words in err and "camera.yaml" in err and "Traceback" not in err


def test_tum_images_without_truth_in_the_middle_are_said(tmp_path, shared_data):
    """Ten images of a motion-capture dropout were left out silently; the run stepped
    over them as one frame."""
    from graphslam.sources.spatial.images import read_tum_rgbd

    folder = tmp_path / "tum"
    (folder / "rgb").mkdir(parents=True)
    rgb, gt = [], []
    for i in range(30):
        (folder / "rgb" / f"{i}.png").symlink_to(shared_data / "kitti07" / "image_0" / f"{i:06d}.png")
        rgb.append(f"{i * 0.1:.4f} rgb/{i}.png")
        if not 10 <= i < 15:
            gt.append(f"{i * 0.1:.4f} {i * 0.5} 0 0 0 0 0 1")
    (folder / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (folder / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    seq = read_tum_rgbd(folder, intrinsics=(500.0, 500.0, 600.0, 180.0))
    assert len(seq.image_paths) == 25
    assert any("5 of 30 images have no ground truth" in w and "5 of them between" in w for w in seq.warnings)


@pytest.mark.parametrize("content,words", [
    ("VERTEX_SE2 0 0 0 0\n".encode("utf-16"), "UTF-16"),
    ("VERTEX_SE2 0 0 0 0\n".encode("utf-16-le"), "UTF-16"),
    (__import__("gzip").compress(b"VERTEX_SE2 0 0 0 0\n", mtime=0), "gzip"),
], ids=["utf16-bom", "utf16le", "gzip"])  # ids: a parameter's bytes must name it alike on every worker
def test_utf16_and_gzip_files_are_named_as_such(tmp_path, capsys, content, words):
    """Refused before, but as "unknown tag 'V\\x00E\\x00...'" or a codec error."""
    path = tmp_path / "g.g2o"
    path.write_bytes(content)
    assert main(["run", "--dataset", str(path), *RUN, "--out", str(tmp_path / "o")]) == 2
    assert words in capsys.readouterr().err


def test_a_csv_header_without_a_hash_is_named_a_header(tmp_path, capsys):
    (tmp_path / "gt.csv").write_text("#t,x,y,z,qw,qx,qy,qz\n1000,0,0,0,1,0,0,0\n2000,1,0,0,1,0,0,0\n")
    (tmp_path / "est.csv").write_text("timestamp,x,y,z,qw,qx,qy,qz\n1000,0,0,0,1,0,0,0\n2000,1,0,0,1,0,0,0\n")
    assert main(["eval", str(tmp_path / "gt.csv"), str(tmp_path / "est.csv"), "--no-plot",
                 "--out", str(tmp_path / "o")]) == 2
    assert "a header line" in capsys.readouterr().err


def test_a_kitti_colour_download_reads_its_camera(tmp_path, capsys, shared_data):
    """image_2/ only (a colour download) was "image_0/ not found", though the reader
    takes any camera of calib.txt."""
    folder = tmp_path / "k"
    (folder / "image_2").mkdir(parents=True)
    for i in range(8):
        (folder / "image_2" / f"{i:06d}.png").symlink_to(shared_data / "kitti07" / "image_0" / f"{i:06d}.png")
    for name in ("calib.txt", "times.txt", "poses.txt"):
        (folder / name).symlink_to(shared_data / "kitti07" / name)
    assert main(["run", "--dataset", str(folder), *RUN, *DERIVED, "--out", str(tmp_path / "o")]) == 0
    assert "camera 2 (image_2/) is read" in capsys.readouterr().err


def test_a_tum_folder_without_rgb_txt_is_said_not_pointed_at_depth(tmp_path, capsys, shared_data):
    folder = tmp_path / "tum"
    for sub in ("depth", "rgb"):
        (folder / sub).mkdir(parents=True)
        for i in range(3):
            (folder / sub / f"{i}.png").symlink_to(shared_data / "kitti07" / "image_0" / f"{i:06d}.png")
    (folder / "associations.txt").write_text("0.0 rgb/0.png 0.0 depth/0.png\n")
    assert main(["run", "--dataset", str(folder), *RUN, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "without its rgb.txt" in err and "depth/" not in err


def test_camera_alone_losses_longer_than_a_frame_are_said():
    """A cut to another place was bridged as 0.65 m of motion and a blurred stretch came
    back at 1.8x the scale: "found again by PnP" in metrics.json only."""
    from graphslam.pipelines.spatial import _loss_doubts

    assert _loss_doubts([{"frame": 101, "frames": 1, "ended": "found again by PnP"}]) == []
    said = _loss_doubts([{"frame": 50, "frames": 6, "ended": "found again by PnP"},
                         {"frame": 101, "frames": 1, "ended": "found again by PnP"}])
    assert len(said) == 1 and "frames 50-55" in said[0] and "another scale" in said[0]


def test_a_start_on_frames_without_corners_says_so():
    """Dark frames read "0 tracks shared with an earlier frame < 50", not why."""
    import numpy as np

    from graphslam.backends.spatial.mono_init import MonoBootstrap
    from graphslam.backends.spatial.mono_tracking import MonoTrackingConfig

    boot = MonoBootstrap(MonoTrackingConfig(), np.diag([500.0, 500.0, 1.0]))
    none = np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    assert boot.add(0, *none) is None and boot.add(1, *none) is None
    assert "no frame kept had a tracked corner" in boot.reason
    ids = np.arange(5)
    assert boot.add(2, ids, np.zeros((5, 2))) is None
    assert "at most 5 tracked in one frame" in boot.reason


def test_a_non_rigid_euroc_t_bs_is_named_in_sensor_yaml(tmp_path, capsys, shared_data):
    """A transposed T_BS read "estimate poses must be rigid transforms", no file named."""
    cam = tmp_path / "mav0" / "cam0"
    (cam / "data").mkdir(parents=True)
    (cam / "data" / "1000.png").symlink_to(shared_data / "kitti07" / "image_0" / "000000.png")
    (cam / "data.csv").write_text("#timestamp [ns],filename\n1000,1000.png\n")
    (cam / "sensor.yaml").write_text(
        "intrinsics: [458.6, 457.3, 367.2, 248.4]\ndistortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n"
        "T_BS:\n  rows: 4\n  cols: 4\n  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0,"
        " -0.02, 0.06, 0.01, 1.0]\n")
    from graphslam.sources.spatial.images import read_euroc
    from slamcore.errors import InputError

    with pytest.raises(InputError) as e:
        read_euroc(tmp_path)
    assert "T_BS" in str(e.value) and "sensor.yaml" in str(e.value.path)


def test_a_flat_vocabulary_of_minutes_says_so_before_it_starts(tmp_path, capsys, monkeypatch, shared_data):
    import graphslam.cli.vocab as vocab

    monkeypatch.setattr(vocab, "FLAT_SLOW_PRODUCT", 1.0)  # the desk is small: say it at any size
    assert main(["vocab", "train", str(shared_data / "slambook2_desk" / "images"), "--flat", "--words", "8",
                 "--out", str(tmp_path / "v.npz"), "--quiet"]) == 0
    assert "a flat k-means of 8 words" in capsys.readouterr().err
