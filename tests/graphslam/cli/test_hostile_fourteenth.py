"""The fourteenth hostile pass (helpers V-Y: ROS bags, the Python API, two processes and
the file system, the paper's front end): each test reproduces a finding that was silent
or unclear, then checks what the command says now."""

from __future__ import annotations

import json

import pytest

from graphslam.cli.main import main


def _visual(tmp_path, capsys, config: str, *args, name: str = "o") -> tuple[int, str, dict | None]:
    (tmp_path / f"{name}.toml").write_text(config)
    out = tmp_path / name
    rc = main(["run", "--dataset", "synthetic-images", "--max-steps", "8", "--rerun", "off", "--quiet",
               "--config", str(tmp_path / f"{name}.toml"), "--out", str(out), *args])
    captured = capsys.readouterr()
    metrics = json.loads((out / "metrics.json").read_text()) if (out / "metrics.json").exists() else None
    return rc, captured.out + captured.err, metrics


def test_landmarks_never_found_again_say_the_images_corrected_nothing(tmp_path, capsys):
    """``gate_probability = 1e-6`` (read as a significance level): every landmark seen once,
    the EKF's trajectory the odometry to the last digit, and no word of it."""
    rc, text, m = _visual(tmp_path, capsys, "[active_search]\ngate_probability = 1e-6\n", "--backend", "ekf")
    assert rc == 0 and m["backend_stats"]["corrections"] == 0
    assert "no landmark was found again in 7 frames" in text
    rc, text, m = _visual(tmp_path, capsys, "", "--backend", "ekf", name="default")
    assert rc == 0 and m["backend_stats"]["corrections"] > 0 and "found again" not in text


def test_a_detector_that_finds_no_corner_is_named(tmp_path, capsys):
    """``[harris] border_px = 300`` on 480-row images (200 on KITTI's 370): "0 corners matched", no cause."""
    rc, text, m = _visual(tmp_path, capsys, "[harris]\nborder_px = 300\n", "--backend", "ekf")
    assert rc == 0 and m["tracking"]["corners_per_frame"] == 0
    assert "(0 corners detected, 0 matched in all)" in text
    assert "the detector found no corner in 640x480 images: look at [harris] threshold and border_px" in text


@pytest.mark.parametrize("text,backend,line", [
    ('# a comment\n\n[active_search]\nmode = "nearest"\n', "ekf", 4),
    ('# a comment\n\n[active_search]\norder = "sequential"\n', "isam2", 4),
])
def test_search_settings_the_run_refuses_name_their_file_line(tmp_path, capsys, text, backend, line):
    rc, said, _ = _visual(tmp_path, capsys, text, "--backend", backend)
    assert rc == 2 and f"o.toml:{line}: active_search." in said


def test_a_config_edited_during_the_run_keeps_the_digest_of_what_was_read(tmp_path, capsys):
    """The SHA-256 was taken when metrics.json was written: a file edited during the run was
    recorded by the new file's digest beside the old file's settings."""
    import hashlib
    from types import SimpleNamespace

    from graphslam.cli.common import provenance
    from slamcore.config import ConfigFile

    path = tmp_path / "c.toml"
    path.write_text("[isam2]\nrelinearize_skip = 5\n")
    read = hashlib.sha256(path.read_bytes()).hexdigest()
    config = ConfigFile.read(path)
    path.write_text("[isam2]\nrelinearize_skip = 50\n")
    record = provenance(SimpleNamespace(command_line=["graphslam", "run"]), config)
    assert record["config_sha256"] == read
    assert "changed during the run" in capsys.readouterr().err


def test_the_default_out_folder_in_a_folder_that_cannot_be_written_is_one_line(tmp_path, capsys, monkeypatch):
    """``graphslam run`` from a read-only folder (its default ``runs/...``): a traceback."""
    blocker = tmp_path / "runs"
    blocker.write_text("a file where the folder would go\n")  # refused even to root
    monkeypatch.chdir(tmp_path)
    assert main(["run", "--max-steps", "5", "--quiet", "--rerun", "off"]) == 2
    err = capsys.readouterr().err
    assert "--out runs/synthetic-isam2: cannot create it in " in err and "Traceback" not in err


def test_compare_on_images_and_pose_graphs_names_the_sections_no_run_read(tmp_path, capsys):
    """Image and pose-graph comparisons named no unread section (their runs read theirs in
    worker processes): ``[ekf]`` in a file shared with 2-D runs did nothing, silent."""
    import gtsam

    (tmp_path / "c.toml").write_text("[ekf]\ngate_chi2_prob = 0.9\n[mono_ekf]\nseed = 3\n[posegraph]\nprior_sigma = 0.01\n")
    assert main(["compare", "--dataset", "synthetic-images", "--max-steps", "6", "--config", str(tmp_path / "c.toml"),
                 "--out", str(tmp_path / "i"), "--rerun", "off"]) == 0
    said = [ln for ln in capsys.readouterr().err.splitlines() if "not read by this comparison" in ln]
    assert len(said) == 1 and "[ekf], [posegraph] not read" in said[0]  # [mono_ekf]: a worker read it
    assert main(["compare", "--dataset", gtsam.findExampleDataFile("noisyToyGraph.txt"), "--backends", "isam2",
                 "batch", "--config", str(tmp_path / "c.toml"), "--out", str(tmp_path / "p"), "--rerun", "off"]) == 0
    said = [ln for ln in capsys.readouterr().err.splitlines() if "not read by this comparison" in ln]
    assert len(said) == 1 and "[ekf], [mono_ekf] not read" in said[0]


@pytest.mark.parametrize("values,said", [(["-1", "0.1"], "--odometry-noise SIGMA_T_PER_M must be >= 0"),
                                         (["0.1", "inf"], "--odometry-noise SIGMA_R_DEG: expected a finite")])
def test_a_refused_odometry_noise_flag_is_named_as_the_flag(tmp_path, capsys, values, said):
    """``--odometry-noise -1 0.1`` was refused as ``odometry_noise.sigma_t_per_m``, a key
    the user never wrote."""
    assert main(["run", "--dataset", "synthetic-images", "--odometry-noise", *values, "--max-steps", "3",
                 "--out", str(tmp_path / "o"), "--rerun", "off", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert said in err and "odometry_noise." not in err
