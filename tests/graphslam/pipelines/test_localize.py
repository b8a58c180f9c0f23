"""Localisation against a saved map: a small synthetic room mapped on its first lap by
``graphslam run --save-map``, then its last frames placed by ``graphslam localize``.

The room is the default synthetic sequence (VGA, 300 frames, 1.5 laps): the map
is built on frames 0-199 (about 25 s) and shared by the tests of this module.
Tolerances in metres.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from graphslam.cli.main import main

#: Frames localised that must be placed (issue 18: 95 %).
MIN_LOCALISED = 0.95
#: ATE bound of the placed frames, in the map's frame (no alignment), metres: the
#: full SLAM run of the 300 frames scores 2.56 cm (SE(3)-aligned); measured 2.54 cm.
ATE_TOL_M = 0.03
#: No placed frame may be farther than this from the truth (issue 18), metres.
FAR_M = 0.5
#: Frames after a blackout within which the camera must be placed again.
RECOVER_FRAMES = 3

#: The same room at half resolution: another camera than the map's.
HALF = """\
[synthetic_images]
width = 320
height = 240
fx = 250.0
fy = 250.0
cx = 159.5
cy = 119.5
"""
MAP_FRAMES, LOCALISE_FRAMES = "0:200", "200:300"


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> tuple[Path, Path]:
    """``(config file, map folder)`` of the small room mapped on frames 0-199."""
    tmp = tmp_path_factory.mktemp("room")
    config = tmp / "room.toml"
    config.write_text("")
    folder = tmp / "map"
    rc = main(["run", "--dataset", "synthetic-images", "--config", str(config), "--frames",
               MAP_FRAMES, "--save-map", str(folder), "--out", str(tmp / "run"),
               "--rerun", "off", "--quiet"])
    assert rc == 0
    return config, folder


def test_localises_the_last_half_lap(room, tmp_path, capsys):
    config, folder = room
    out = tmp_path / "loc"
    rc = main(["localize", "--map", str(folder), "--dataset", "synthetic-images", "--config",
               str(config), "--frames", LOCALISE_FRAMES, "--out", str(out), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    m = json.loads((out / "metrics.json").read_text())
    assert m["frames"] == 100
    assert m["localised_fraction"] >= MIN_LOCALISED, m
    assert m["ate_rmse_m"] <= ATE_TOL_M, m
    assert m["error_max_m"] <= FAR_M and m["frames_over_0_5m"] == 0, m
    assert m["relocalisations"] >= 1  # the start pose is unknown: found by place recognition
    rows = (out / "localize.csv").read_text().splitlines()
    assert rows[0].startswith("frame,t,status,x,y,z,qx,qy,qz,qw,c00")
    assert rows[1].startswith("200,") and len(rows) == 101
    assert {"trajectory.tum", "ground_truth.tum", "localize.rrd"} <= {p.name for p in out.iterdir()}


def test_recovers_after_a_blackout(room):
    from graphslam import registry
    from graphslam.maps.files import load_map
    from graphslam.pipelines import localize_run
    from graphslam.pipelines.session import LocaliseSession
    from graphslam.sources.spatial.frames import black_out, parse_frames, select_frames

    config_path, folder = room
    config = registry.read_config(config_path)
    sel = select_frames(registry.load_image_sequence("synthetic-images", config=config),
                        parse_frames("200:240"))
    black = range(15, 25)  # ten black frames in the middle
    seq = black_out(sel, black)
    smap = load_map(folder)
    result = LocaliseSession.open(seq, config, smap, "synthetic-images").run()
    status = [p.status for p in result.placements]
    assert all(status[i] == "lost" for i in black)  # nothing to see: not placed
    after = status[25:25 + RECOVER_FRAMES]
    assert any(s != "lost" for s in after), status
    first = 25 + next(i for i, s in enumerate(after) if s != "lost")
    assert status[first] == "relocalised"
    err = localize_run.errors_m(result)
    assert np.nanmax(err) <= FAR_M


def test_refusals_are_one_line(room, tmp_path, capsys):
    config, folder = room
    base = ["localize", "--dataset", "synthetic-images", "--out", str(tmp_path / "x"),
            "--rerun", "off", "--quiet"]
    half = tmp_path / "half.toml"
    half.write_text(HALF)
    assert main([*base, "--map", str(folder), "--config", str(half), "--frames", "0:2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "640x480" in err[0]
    assert main([*base, "--map", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "map folder not found" in err[0]
    assert main([*base, "--map", str(folder), "--config", str(config), "--frames", "3:3"]) == 2
    assert "selects no frame" in capsys.readouterr().err


@pytest.mark.parametrize("sig, status", [("INT", 130), ("TERM", 143)])
def test_signal_keeps_the_frames_placed_so_far(room, tmp_path, sig, status):
    """SIGINT/SIGTERM between frames (the test hook, in a subprocess): every file is
    written with the frames placed so far, interrupted in metrics.json, one line."""
    from tests.graphslam.cli.test_faults import graphslam, one_line

    config, folder = room
    done = graphslam(tmp_path, "localize", "--map", str(folder), "--dataset", "synthetic-images",
                     "--config", str(config), "--frames", LOCALISE_FRAMES, "--out", "loc",
                     "--quiet", at="step:5", sig=sig)
    assert done.returncode == status
    assert f"interrupted (SIG{sig})" in one_line(done.stderr)
    out = tmp_path / "loc"
    assert {p.name for p in out.iterdir()} == {"localize.csv", "trajectory.tum", "metrics.json",
                                               "ground_truth.tum", "localize.rrd"}
    m = json.loads((out / "metrics.json").read_text())
    assert m["interrupted"] is True and m["frames"] == 6  # frames 0-5, stopped before 6
    assert len((out / "localize.csv").read_text().splitlines()) == 1 + m["frames"]


def test_a_camera_alone_map_is_scored_in_its_own_scale_and_joined_by_no_metric_run(tmp_path, capsys):
    """Tenth hostile pass: a map built with ``--odometry none`` is in units of its first
    baseline; ``localize`` scored its placements against metric truth unaligned (KITTI:
    "ATE 7.69 m" for placements 0.016 units from the map's own trajectory), and ``run --map``
    with odometry joined it at another scale (a saved map at two scales), each in silence."""
    folder = tmp_path / "map"
    assert main(["run", "--dataset", "synthetic-images", "--odometry", "none", "--frames", "0:120",
                 "--save-map", str(folder), "--out", str(tmp_path / "run"), "--rerun", "off",
                 "--quiet"]) == 0
    capsys.readouterr()
    out = tmp_path / "loc"
    assert main(["localize", "--map", str(folder), "--dataset", "synthetic-images", "--frames",
                 "20:60", "--out", str(out), "--rerun", "off", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "its unit is its first baseline, not a metre" in err
    m = json.loads((out / "metrics.json").read_text())
    assert m["ate_alignment"].startswith("sim3") and m["map"]["metric"] is False
    assert m["localised_fraction"] >= MIN_LOCALISED and m["ate_rmse_m"] <= ATE_TOL_M, m
    assert main(["run", "--dataset", "synthetic-images", "--frames", "20:60", "--map", str(folder),
                 "--out", str(tmp_path / "joined"), "--rerun", "off", "--quiet"]) == 2
    assert "was built from the camera alone, in a scale of its own" in capsys.readouterr().err


def test_a_truth_in_another_frame_than_the_maps_is_doubted(room):
    """Hostile pass 21: KITTI 07 frames 40-159 localised right on a map of frames 0-159,
    scored against a truth restarted at the identity (a second recording's): ATE 62 m,
    median 57 m, no word, where a rigid fit gave 0.19 m."""
    import dataclasses

    from graphslam import registry
    from graphslam.maps.files import load_map
    from graphslam.pipelines import localize_run
    from graphslam.pipelines.session import LocaliseSession
    from graphslam.sources.spatial.frames import parse_frames, select_frames

    config_path, folder = room
    config = registry.read_config(config_path)
    seq = select_frames(registry.load_image_sequence("synthetic-images", config=config), parse_frames("200:240"))
    result = LocaliseSession.open(seq, config, load_map(folder), "synthetic-images").run()
    info = {"metric": True}
    sound = localize_run.compute_metrics(result, info)
    assert sound["ate_rmse_m"] <= ATE_TOL_M and "ate_rmse_se3_m" not in sound
    assert not any("map's frame" in w for w in sound.get("warnings", []))
    # the same truth, restarted at the identity
    restart = np.linalg.inv(np.asarray(seq.wTc_true[0]))
    result.sequence = dataclasses.replace(seq, wTc_true=np.array([restart @ T for T in seq.wTc_true]))
    moved = localize_run.compute_metrics(result, info)
    assert moved["ate_rmse_m"] > 1.0
    assert moved["ate_rmse_se3_m"] == pytest.approx(sound["ate_rmse_m"], abs=0.05)
    assert any("is the truth in the map's frame?" in w for w in moved["warnings"])
