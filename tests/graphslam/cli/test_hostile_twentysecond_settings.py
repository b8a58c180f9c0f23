"""The twenty-second hostile pass's settings that did nothing unsaid (left from stop 92):
each test sets one, then checks that the command says so, on stderr and in its JSON."""

from __future__ import annotations

import json

from graphslam.cli.main import main
from slamcore.config import ConfigFile


def _chain_g2o(path, n: int = 12):
    lines = [f"VERTEX_SE2 {i} {i} 0 0" for i in range(n)]
    lines += [f"EDGE_SE2 {i} {i + 1} 1 0 0 100 0 0 100 0 1000" for i in range(n - 1)]
    lines.append(f"EDGE_SE2 0 {n - 1} {n - 1} 0 0 100 0 0 100 0 1000")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_synthetic_images_revisit_and_odometry_noise_are_said_unread(tmp_path, capsys):
    """The revisit rule (only benchmarks read it) and the sequence's odometry noise under
    --odometry derived ran the same bits, unsaid."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[synthetic_images]\nn_frames = 6\nodometry_sigma_t_m = 0.02\nrevisit_distance_m = 2.0\n")
    argv = ["run", "--dataset", "synthetic-images", "--config", str(cfg), "--out", str(tmp_path / "o")]
    assert main([*argv, "--odometry", "derived", "--rerun", "off", "--quiet"]) == 0
    err = capsys.readouterr().err
    said = json.loads((tmp_path / "o" / "metrics.json").read_text())["provenance"]["did_nothing"]
    for key, line in (("revisit_distance_m", 4), ("odometry_sigma_t_m", 3)):
        (hit,) = [w for w in said if f"] {key} did nothing" in w]
        assert f"line {line}:" in hit and hit in err
    # with the sequence's own odometry its noise acts: only the revisit rule is said
    assert main([*argv, "--odometry", "sequence", "--rerun", "off", "--quiet"]) == 0
    said = json.loads((tmp_path / "o" / "metrics.json").read_text())["provenance"]["did_nothing"]
    assert [w for w in said if "odometry_sigma" in w] == []
    assert [w for w in said if "revisit_distance_m" in w]


def test_lm_limits_under_isam2_without_its_polish_are_said_unread(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[posegraph]\npolish = false\nmax_iterations = 5\n")
    g = _chain_g2o(tmp_path / "g.g2o")
    argv = ["run", "--dataset", str(g), "--config", str(cfg), "--rerun", "off", "--quiet"]
    assert main([*argv, "--backend", "isam2", "--out", str(tmp_path / "i")]) == 0
    assert "[posegraph] max_iterations did nothing: it acts only with a batch LM" in capsys.readouterr().err
    # the batch solver reads them (and says [posegraph] polish unread instead)
    assert main([*argv, "--backend", "batch", "--out", str(tmp_path / "b")]) == 0
    err = capsys.readouterr().err
    assert "max_iterations did nothing" not in err and "polish did nothing" in err


def test_compare_says_what_run_says_did_nothing(tmp_path, capsys):
    """compare said only the gates of sections built in its own process: a landmark back
    end's loop-closure settings, or an image back end's tracker settings, went unsaid,
    and compare.json had no record of them."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[isam2]\nloop_closure_gate = 3.0\n")
    argv = ["compare", "--dataset", "synthetic", "--backends", "ekf", "isam2", "--max-steps", "10"]
    assert main([*argv, "--config", str(cfg), "--out", str(tmp_path / "o"), "--rerun", "off", "--in-process"]) == 0
    err = capsys.readouterr().err
    said = json.loads((tmp_path / "o" / "compare.json").read_text())["provenance"]["did_nothing"]
    (hit,) = [w for w in said if "loop_closure_gate did nothing" in w]
    assert "loop closures (this run had none)" in hit and hit in err


def _notes(read, inert=(), marked=()):
    return set(read), {k: "gate" for k in inert}, {k: "mark" for k in marked}


def test_merged_notes_keep_what_every_reader_left_unread():
    """A setting one entry used is not said to have done nothing for the comparison; one
    of a section only another entry read is."""
    config = ConfigFile()
    follow = ("tracker", "follow_window_px")
    ekf_only = ("mono_ekf", "x")
    config.merge_notes(
        [
            _notes({"tracker", "mono_ekf"}, marked=[follow, ekf_only]),  # the EKF: neither read
            _notes({"tracker", "isam2_visual"}),  # iSAM2 followed tracks; no [mono_ekf]
        ]
    )
    assert config.read_sections == {"tracker", "mono_ekf", "isam2_visual"}
    assert config.marked == {ekf_only: "mark"} and config.inert == {}
    config.merge_notes([_notes({"tracker"}, inert=[follow]), _notes({"tracker"}, marked=[follow])])
    assert config.inert == {follow: "gate"} and config.marked == {}


def test_compare_json_wall_s_is_the_entrys_whole_time_as_runs_is(tmp_path, capsys):
    """compare.json's wall_s was the back end's time, run's metrics.json's the whole run's:
    now the entry's whole time, the back end's kept as backend_s and shown in the table."""
    argv = ["compare", "--dataset", "synthetic", "--backends", "ekf", "--max-steps", "20", "--rerun", "off"]
    assert main([*argv, "--out", str(tmp_path / "o"), "--in-process"]) == 0
    assert "processing [s]" in capsys.readouterr().out
    (row,) = json.loads((tmp_path / "o" / "compare.json").read_text())["runs"]
    assert row["wall_s"] > row["backend_s"] > 0.0


def test_mean_nees_leaves_out_the_start_placed_at_the_truth(tmp_path, capsys):
    """The first pose starts at the truth, so its NEES is 0 whatever its covariance: it was
    counted in the mean (4.331 over 200 EKF steps, 4.353 over the estimated poses), and a
    one-step run was said to have a covariance far too large."""
    import csv

    argv = ["run", "--dataset", "synthetic", "--backend", "ekf", "--nees", "--rerun", "off", "--quiet"]
    assert main([*argv, "--max-steps", "30", "--out", str(tmp_path / "a")]) == 0
    rows = list(csv.DictReader((tmp_path / "a" / "nees.csv").open()))
    assert float(rows[0]["nees"]) == 0.0  # kept in the per-pose file, as it is
    mean = json.loads((tmp_path / "a" / "metrics.json").read_text())["nees_mean"]
    assert abs(mean - sum(float(r["nees"]) for r in rows[1:]) / (len(rows) - 1)) < 1e-6
    capsys.readouterr()
    assert main([*argv, "--max-steps", "1", "--out", str(tmp_path / "b")]) == 0
    assert "NEES" not in capsys.readouterr().err
    assert json.loads((tmp_path / "b" / "metrics.json").read_text()).get("nees_mean") is None
