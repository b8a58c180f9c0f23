"""The twenty-third hostile pass (camera-alone runs; the documentation and benchmark
scripts as a user follows them) and taste leftovers of earlier passes: each test
reproduces a finding, then checks what the toolkit does now."""

from __future__ import annotations

import os

from graphslam.cli.main import main
from slamcore.errors import ConfigError

SWEEP = '[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\nseed = [0, 1, 2, 3]\nmax_steps = 5\nnees = false\n'


def test_more_workers_than_cores_is_said(tmp_path, monkeypatch, capsys):
    """--workers 1000 on two cores started them all, unsaid (a taste of pass 21)."""
    from graphslam.pipelines import sweep_exec

    asked = []

    class Fake:
        def __init__(self, workers):
            asked.append(workers)
            raise ConfigError("stop here")

    monkeypatch.setattr(sweep_exec, "PoolExecutor", Fake)
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    (tmp_path / "s.toml").write_text(SWEEP)
    assert main(["sweep", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--workers", "1000"]) == 2
    assert asked == [4]  # capped at the runs, as before
    assert "--workers 4 on 2 cores: the runs share them" in capsys.readouterr().err


# --------------------------------------------------------------------------- camera alone

import json  # noqa: E402
import shutil  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

QUIET = ["--quiet", "--rerun", "off"]


@pytest.fixture
def kitti(shared_data):
    folder = shared_data / "kitti07"
    if not (folder / "image_0").is_dir():
        pytest.skip("KITTI 07 frames missing")
    return folder


def _kitti_copy(kitti, tmp_path, n: int, jpg=(), truncated=None):
    """A KITTI-layout folder of the first ``n`` frames (calib.txt only), frames ``jpg``
    saved as JPEG, frame ``truncated`` cut short."""
    out = tmp_path / "k"
    (out / "image_0").mkdir(parents=True)
    shutil.copy(kitti / "calib.txt", out / "calib.txt")
    for k in range(n):
        src = kitti / "image_0" / f"{k:06d}.png"
        if k in jpg:
            cv2.imwrite(str(out / "image_0" / f"{k:06d}.jpg"), cv2.imread(str(src), cv2.IMREAD_GRAYSCALE))
        elif k == truncated:
            (out / "image_0" / f"{k:06d}.png").write_bytes(src.read_bytes()[:2000])
        else:
            shutil.copy(src, out / "image_0" / f"{k:06d}.png")
    return out


def test_loops_before_the_camera_alone_map_started_is_no_internal_error(desk_copy, tmp_path, capsys):
    """The last desk photo matched the first before any frame had a pose: 'isam2 (visual):
    unknown frame 0' and "interrupted yes". The candidate is now unplaced, and the run
    ends with the camera-alone map's own reason."""
    photos = desk_copy(10)
    (tmp_path / "cam.txt").write_text("520 520 319.5 239.5\n")
    argv = ["run", "--dataset", str(photos), "--intrinsics", str(tmp_path / "cam.txt"), "--loops"]
    assert main([*argv, "--out", str(tmp_path / "o"), *QUIET]) == 2
    err = capsys.readouterr().err
    assert "monocular tracking never started" in err and "unknown frame" not in err


def test_a_kitti_folder_takes_every_image_format(kitti, tmp_path):
    """Frames saved as .jpg in image_0/ were left out unsaid (the run jumped over them)."""
    from graphslam.sources.spatial.kitti import read_kitti

    seq = read_kitti(_kitti_copy(kitti, tmp_path, 6, jpg=(2, 3)))
    assert len(seq) == 6 and [p[-3:] for p in seq.image_paths] == ["png", "png", "jpg", "jpg", "png", "png"]


def test_a_camera_alone_setting_with_odometry_is_refused_before_the_run(kitti, tmp_path, capsys):
    """robot_model = "constant_velocity" with --odometry derived failed at the second frame,
    the summary saying "interrupted"."""
    cfg = tmp_path / "c.toml"
    cfg.write_text('[isam2_visual]\nrobot_model = "constant_velocity"\n')
    argv = ["run", "--dataset", str(kitti), "--frames", "0:5", "--odometry", "derived", "--config", str(cfg)]
    assert main([*argv, "--out", str(tmp_path / "o"), *QUIET]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"graphslam: error: {cfg}:2: [isam2_visual] robot_model")
    assert "--odometry derived" in line and not (tmp_path / "o").exists()


def test_a_run_cut_by_an_error_says_so_not_interrupted(kitti, tmp_path, capsys):
    folder = _kitti_copy(kitti, tmp_path, 6, truncated=5)
    assert main(["run", "--dataset", str(folder), "--out", str(tmp_path / "o"), *QUIET]) == 2
    out = capsys.readouterr().out
    assert "stopped early" in out and "interrupted" not in out
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["interrupted"] and "000005.png" in m["stopped_by"]


def test_a_camera_alone_map_that_never_starts_on_large_images_names_the_pixel_settings():
    """KITTI upscaled 2x never started a map and was told "more frames, or odometry"."""
    from types import SimpleNamespace

    from graphslam.pipelines.spatial import LARGE_IMAGE_WIDTH_PX, _finalize
    from slamcore.errors import GraphSlamError, InputError

    class Never:
        def finalize(self):
            raise GraphSlamError("isam2 (visual): monocular tracking never started: ...; or odometry")

    for width, hinted in ((LARGE_IMAGE_WIDTH_PX * 2, True), (640, False)):
        seq = SimpleNamespace(image_size=(width, 480), source_path="imgs")
        with pytest.raises(InputError) as e:
            _finalize(Never(), seq)
        assert ("[tracker] sigma_px" in str(e.value)) is hinted


def test_the_relocaliser_counts_camera_alone_losses_and_not_the_frames_before_the_map():
    """--relocalise counted frames before the camera-alone map as lost (15 'lost frames',
    0 losses) and missed the losses the camera-alone tracker coasted through."""
    from types import SimpleNamespace

    from graphslam.pipelines.relocalise import RunRelocaliser

    class Backend:
        placed: set = set()
        coasted = False

        def has_pose(self, k):
            return k in self.placed

        def coasting(self):
            return self.coasted

        def landmarks_in_frame(self, a, ids):
            return np.full((len(ids), 3), np.nan)

    backend = Backend()
    reloc = RunRelocaliser(np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]))
    tracking = SimpleNamespace(
        n_found=50,
        observations=SimpleNamespace(uv_px=np.zeros((0, 2)), track_ids=np.zeros(0, np.int64)),
        corners=np.zeros((0, 2)),
    )
    image = np.zeros((480, 640), np.uint8)
    for k in range(5):  # no map yet
        reloc(k, image, tracking, backend)
    assert reloc.stats["lost_frames"] == 0
    backend.placed = set(range(5, 20))
    for k in range(5, 20):
        backend.coasted = 9 <= k <= 12  # active search found 50, PnP placed none
        reloc(k, image, tracking, backend)
    assert reloc.stats["losses"] == 1 and reloc.stats["lost_frames"] == 4
    assert reloc.stats["recovered_by_search"] == 1


def test_loss_doubts_name_the_files_frames_under_a_frame_selection():
    from graphslam.pipelines.spatial import _loss_doubts

    losses = [{"frame": 13, "frames": 5}]
    (line,) = _loss_doubts(losses, np.arange(150, 300))
    assert "frames 13-17 of the run, file frames 163-167" in line
    (line,) = _loss_doubts(losses, np.arange(200))
    assert "(frames 13-17)" in line


def test_a_kitti_calib_txt_as_intrinsics_says_where_it_is_read(kitti):
    """It was 'malformed line, expected intrinsics numbers: P0: ...'."""
    from graphslam.sources.spatial.calibration import read_intrinsics_file
    from slamcore.errors import InputError

    with pytest.raises(InputError) as e:
        read_intrinsics_file(kitti / "calib.txt")
    assert e.value.line == 1 and "run the KITTI sequence folder itself" in str(e.value)


@pytest.mark.parametrize("fy, doubted", [(500.0, False), (510.0, False), (250.0, True), (600.0, True)])
def test_pixels_far_from_square_are_doubted(fy, doubted):
    """fy = fx / 2 ran without a word (pass 23)."""
    from graphslam.sources.spatial.sequence import camera_doubts

    K = np.array([[500.0, 0, 319.5], [0, fy, 239.5], [0, 0, 1]])
    said = camera_doubts(K, (640, 480), "cam.txt")
    assert any("square pixels" in w for w in said) is doubted
