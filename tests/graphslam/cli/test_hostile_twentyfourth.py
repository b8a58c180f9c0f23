"""The twenty-fourth hostile pass (the visual front end; saved maps and localisation):
each test reproduces a finding, then checks what the toolkit does now."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from graphslam.cli.main import main
from slamcore.errors import ConfigError, InputError

QUIET = ["--quiet", "--rerun", "off"]


@pytest.fixture
def kitti_frame(shared_data):
    path = shared_data / "kitti07" / "image_0" / "000000.png"
    if not path.is_file():
        pytest.skip("KITTI 07 frames missing")
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)


def test_orb_runs_every_pyramid_opencv_runs(kitti_frame):
    """At scale 2.0 with 9 levels (KITTI's 370 rows: 1.45 px at the top) OpenCV finds
    3027 corners and the toolkit dropped them all; scale_factor = 1e300 overflowed."""
    from frontend.orb import OrbConfig, OrbDetector

    assert len(OrbDetector(OrbConfig(scale_factor=2.0, n_levels=9)).detect(kitti_frame).xy_px) > 100
    assert len(OrbDetector(OrbConfig(scale_factor=2.0, n_levels=10)).detect(kitti_frame).xy_px) > 100  # 0.72 px
    assert len(OrbDetector(OrbConfig(scale_factor=2.0, n_levels=11)).detect(kitti_frame).xy_px) == 0  # 0.36 px
    assert len(OrbDetector(OrbConfig(scale_factor=1e300, n_levels=2)).detect(kitti_frame).xy_px) == 0


def test_settings_beyond_what_an_image_holds_are_refused():
    """min_distance_px = 1e200 and min_patch_std = 1e200 overflowed their squares."""
    from frontend.active_search_config import ActiveSearchConfig
    from frontend.tracking_config import TrackerConfig

    with pytest.raises(ConfigError):
        TrackerConfig(min_distance_px=1e200)
    with pytest.raises(ConfigError):
        ActiveSearchConfig(min_patch_std=128.0)
    ActiveSearchConfig(min_patch_std=127.5)


def test_the_fpga_stream_takes_frames_a_period_apart_at_epoch_stamps():
    """15 of 30 frames one frame period apart at 1.4e9 s were refused as overlapping."""
    from frontend.fpga_stream import FpgaHarrisStream

    img = (np.random.default_rng(0).random((120, 160)) * 255).astype(np.uint8)
    stream = FpgaHarrisStream()
    period = stream.timing.frame_period_s(img.shape)
    for n in range(30):
        stream.push_frame(img, 1403636579.763555527 + n * period)
    with pytest.raises(InputError, match="overlaps the previous frame"):
        stream.push_frame(img, 1403636579.763555527 + 29.5 * period)


def test_sequential_search_records_the_ellipses_it_searched_in():
    """zncc and nearest searches re-predicted a copy: the result held the first ellipses."""
    from frontend.active_search import ActiveSearch
    from frontend.active_search_config import ActiveSearchConfig

    rng = np.random.default_rng(1)
    img = (rng.random((120, 160)) * 255).astype(np.uint8)
    z = np.array([[40.0, 40.0], [80.0, 60.0], [120.0, 80.0]])
    S = np.tile(np.eye(2) * 9.0, (3, 1, 1))

    def repredict(found, uv, pending):  # every pending ellipse moves 1 px and shrinks
        return z[pending] + 1.0, S[pending] * 0.5

    search = ActiveSearch(ActiveSearchConfig(order="sequential"))
    res = search.search(img, z, S, prev_image=img, prev_xy=z, repredict=repredict)
    assert res.found.sum() >= 2  # the same image: each patch is found where it was
    moved = ~np.all(res.z == z, axis=1)
    assert moved.any() and np.all(res.S[moved] == S[moved] * 0.5)
    assert np.all(z == [[40.0, 40.0], [80.0, 60.0], [120.0, 80.0]])  # the caller's, unchanged


def test_a_map_covariance_with_a_correlation_beyond_one_is_refused(tmp_path):
    from graphslam.maps.files import load_map, save_map
    from tests.graphslam.maps.test_maps import random_map

    smap = random_map()
    smap.keyframe_cov[:, 0, 1] = smap.keyframe_cov[:, 1, 0] = 10 * smap.keyframe_cov[:, 0, 0]
    with pytest.raises(InputError, match="not positive semi-definite"):
        save_map(smap, tmp_path / "m")
        load_map(tmp_path / "m")


@pytest.fixture
def synthetic_map(tmp_path):
    folder = tmp_path / "maps" / "syn"
    assert main(["run", "--max-steps", "400", "--save-map", str(folder), "--out", str(tmp_path / "r0"), *QUIET]) == 0
    return folder


def _edited(folder, to, edit):
    shutil.copytree(folder, to)
    doc = json.loads((to / "map.json").read_text())
    edit(doc)
    (to / "map.json").write_text(json.dumps(doc))
    return to


@pytest.mark.parametrize("edit, says", [
    (lambda d: d["meta"].update(config="isam2"), "'config' is not a table of sections"),
    (lambda d: d["meta"].update(n_frames="fifty"), "'n_frames' is not a whole number"),
    (lambda d: d["meta"].update(sessions=[{"frame_range": "0:100:2"}]), "'frame_range' is not a list"),
])
def test_map_json_fields_of_the_wrong_type_are_one_line(synthetic_map, tmp_path, capsys, edit, says):
    """meta.config "isam2" was an AttributeError; a session's frame range "0:100:2" or
    n_frames "fifty" a ValueError after the whole run."""
    bad = _edited(synthetic_map, tmp_path / "bad", edit)
    capsys.readouterr()
    assert main(["run", "--map", str(bad), "--out", str(tmp_path / "r"), *QUIET]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert says in line


def test_a_map_away_from_the_truth_is_said_in_the_maps_frame(synthetic_map, tmp_path, capsys):
    """A map moved 3 m scored 0.64 m after the SE(2) fit, unsaid; 4.17 m where it was."""
    from graphslam.maps.files import load_planar_map, save_planar_map

    pmap = load_planar_map(synthetic_map)
    pmap.landmark_xy[:] += 3.0
    save_planar_map(pmap, tmp_path / "moved")
    capsys.readouterr()
    assert main(["run", "--map", str(tmp_path / "moved"), "--out", str(tmp_path / "r"), *QUIET]) == 0
    err = capsys.readouterr().err
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert m["ate_in_map_frame_m"] > 5 * m["ate_rmse_m"] and "in the map's frame the ATE is" in err
    assert main(["run", "--map", str(synthetic_map), "--out", str(tmp_path / "r2"), *QUIET]) == 0
    assert "in the map's frame" not in capsys.readouterr().err


def test_a_map_of_another_log_of_the_same_name_is_said(tmp_path, capsys):
    """A log with other landmark ids under the same file name localised at 8.2 m, unsaid."""
    import gtsam

    src = gtsam.findExampleDataFile("victoria_park.txt")
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    lines = open(src).read().splitlines(True)[:3000]
    (tmp_path / "a" / "log.txt").write_text("".join(lines))
    (tmp_path / "b" / "log.txt").write_text("".join(lines[:-1]))  # another file: one line less
    assert main(["run", "--dataset", str(tmp_path / "a" / "log.txt"), "--save-map", str(tmp_path / "m"),
                 "--out", str(tmp_path / "r0"), *QUIET]) == 0
    capsys.readouterr()
    assert main(["run", "--dataset", str(tmp_path / "b" / "log.txt"), "--map", str(tmp_path / "m"),
                 "--out", str(tmp_path / "r1"), *QUIET]) == 0
    assert "whose contents differ from this one's" in capsys.readouterr().err


def test_a_map_folder_whose_files_would_pass_the_path_limit_is_refused_first(tmp_path):
    from slamcore.files import PATH_MAX_BYTES, check_output_dir, short_path

    deep = tmp_path / "/".join(["f" * 200] * 19)
    deep = deep / ("g" * (PATH_MAX_BYTES - 5 - len(str(deep)) - 1))
    with pytest.raises(ConfigError, match="its file vocabulary.npz would have a path of"):
        check_output_dir(deep, "--save-map", files=("map.json", "vocabulary.npz"))
    assert len(short_path(deep)) < 200 and short_path("a/b") == "a/b"


def test_a_localisation_past_the_map_keeps_its_final_error_and_test(tmp_path):
    """Sightings of landmarks not in the map (Victoria Park past the mapped 3000 steps)
    left their keys out of the estimate: final error n/a, its chi-square test skipped."""
    argv = ["run", "--dataset", "victoria-park", *QUIET]
    assert main([*argv, "--max-steps", "3000", "--save-map", str(tmp_path / "m"), "--out", str(tmp_path / "a")]) == 0
    assert main([*argv, "--max-steps", "5000", "--map", str(tmp_path / "m"), "--out", str(tmp_path / "b")]) == 0
    m = json.loads((tmp_path / "b" / "metrics.json").read_text())
    assert m["unmapped_observations"] > 0 and m["final_error"] is not None


def test_the_isam2_localiser_weighs_sightings_under_the_slam_kernel(shared_data, tmp_path):
    """Without the robust kernel, robot 3's misread sightings pulled its localisation on a
    map of all five robots to 0.90 m (2.7 m at step 700), no better than dead reckoning;
    [isam2] observation_kernel did nothing there."""
    folder = shared_data / "mrclam6"
    if not folder.is_dir():
        pytest.skip("MRCLAM Dataset 6 missing")
    argv = ["run", "--dataset", str(folder), *QUIET]
    assert main([*argv, "--robot", "all", "--max-steps", "800", "--save-map", str(tmp_path / "m"),
                 "--out", str(tmp_path / "a")]) == 0
    assert main([*argv, "--robot", "3", "--max-steps", "1500", "--map", str(tmp_path / "m"),
                 "--out", str(tmp_path / "b")]) == 0
    m = json.loads((tmp_path / "b" / "metrics.json").read_text())
    assert m["ate_rmse_m"] < 0.2 < m["odometry_ate_rmse_m"]
