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
    # beside a config file the flag's value was blamed on the file ("c.toml: odometry_noise...")
    (tmp_path / "c.toml").write_text("[visual]\n")
    assert main(["run", "--dataset", "synthetic-images", "--odometry-noise", *values, "--max-steps", "3",
                 "--config", str(tmp_path / "c.toml"), "--out", str(tmp_path / "o"), "--rerun", "off",
                 "--quiet"]) == 2
    err = capsys.readouterr().err
    assert said in err and "c.toml" not in err


def _grid_graph(tmp_path, offset=(0.0, 0.0), wrong: bool = False):
    """A 2-D walk of 120 one-metre steps on a grid (a turn every 6th step), 25 true
    closures between poses within 1.1 m, sigmas 5 cm / 5 cm / 0.02 rad, vertices composed
    from the odometry, in g2o; its truth in TUM (stamps are pose ids). ``offset`` moves
    every vertex and the truth (a georeferenced file); ``wrong`` adds a closure 10^4 times
    too confident between poses 10 and 90, 28 m apart, said to be 2.5 m apart (the
    fourteenth hostile pass's graph, seeds 11 and 12)."""
    import numpy as np

    def wrap(a):
        return (a + np.pi) % (2 * np.pi) - np.pi

    def comp(a, b):
        c, s = np.cos(a[2]), np.sin(a[2])
        return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap(a[2] + b[2])])

    def rel(a, b):
        c, s = np.cos(a[2]), np.sin(a[2])
        d = b[:2] - a[:2]
        return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], wrap(b[2] - a[2])])

    rng = np.random.default_rng(11)
    P = [np.zeros(3)]
    for k in range(1, 120):
        step = np.array([1.0, 0.0, 0.0])
        if k % 6 == 0:
            step[2] = rng.choice([np.pi / 2, -np.pi / 2, 0])
        P.append(comp(P[-1], step))
    P = np.array(P)
    near = [(i, j) for j in range(len(P)) for i in range(j - 3) if np.linalg.norm(P[i, :2] - P[j, :2]) < 1.1]
    rng.shuffle(near)
    edges = [(k, k + 1) for k in range(119)] + near[:25]
    info = np.diag(1 / np.array([0.05, 0.05, 0.02]) ** 2)
    L = np.linalg.cholesky(np.linalg.inv(info))
    noise = np.random.default_rng(12)
    meas = []
    for a, b in edges:
        z = rel(P[a], P[b]) + L @ noise.standard_normal(3)
        z[2] = wrap(z[2])
        meas.append((a, b, z))
    V = np.zeros_like(P)
    odo = {(a, b): z for a, b, z in meas if b == a + 1}
    for k in range(1, len(P)):
        V[k] = comp(V[k - 1], odo[(k - 1, k)])
    lines = [f"VERTEX_SE2 {k} {V[k, 0] + offset[0]:.9f} {V[k, 1] + offset[1]:.9f} {V[k, 2]:.9f}" for k in range(len(P))]
    text = f"{info[0, 0]:.9g} 0 0 {info[1, 1]:.9g} 0 {info[2, 2]:.9g}"
    lines += [f"EDGE_SE2 {a} {b} {z[0]:.9f} {z[1]:.9f} {z[2]:.9f} {text}" for a, b, z in meas]
    if wrong:
        lines.append(f"EDGE_SE2 10 90 2.0 1.5 0.8 {1e4 * info[0, 0]:.9g} 0 0 {1e4 * info[1, 1]:.9g} 0 "
                     f"{1e4 * info[2, 2]:.9g}")
    (tmp_path / "g.g2o").write_text("\n".join(lines) + "\n")
    (tmp_path / "t.tum").write_text("".join(
        f"{k} {P[k, 0] + offset[0]:.9f} {P[k, 1] + offset[1]:.9f} 0 0 0 {np.sin(P[k, 2] / 2):.12f} "
        f"{np.cos(P[k, 2] / 2):.12f}\n" for k in range(len(P))))
    return tmp_path / "g.g2o", tmp_path / "t.tum"


def test_a_wrong_closure_too_confident_for_the_test_is_said(tmp_path, capsys):
    """A wrong closure 10^4 times too confident bent the odometry until its own residual was
    small: kept, ATE many times the dead reckoning's, and no warning."""
    graph, truth = _grid_graph(tmp_path, wrong=True)
    assert main(["run", "--dataset", str(graph), "--ground-truth", str(truth), "--out", str(tmp_path / "o"),
                 "--rerun", "off", "--quiet"]) == 0
    err = capsys.readouterr().err
    warnings = json.loads((tmp_path / "o" / "metrics.json").read_text())["warnings"]
    assert any("after the closure test" in w and "above the chi-square bound" in w for w in warnings), warnings
    assert "after the closure test" in err
    assert any("the estimate is absurd" in w for w in warnings), warnings  # 15.1 m against 1.3 m
    clean = tmp_path / "clean"
    clean.mkdir()
    graph, truth = _grid_graph(clean)
    assert main(["run", "--dataset", str(graph), "--ground-truth", str(truth), "--out", str(clean / "o"),
                 "--rerun", "off", "--quiet"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_a_relaxed_start_leaves_a_georeferenced_graph_at_its_first_vertex(tmp_path):
    """LAGO put a graph in UTM coordinates 14.7 m off its first vertex, the whole estimate
    with it, silently (the odometry start kept it in place)."""
    import numpy as np

    east, north = 512345.0, 5034567.0
    graph, _ = _grid_graph(tmp_path, offset=(east, north))
    first = [ln.split() for ln in graph.read_text().splitlines() if ln.startswith("VERTEX_SE2 0 ")][0]
    assert main(["run", "--dataset", str(graph), "--backend", "batch", "--init", "lago", "--out",
                 str(tmp_path / "o"), "--rerun", "off", "--quiet"]) == 0
    row = (tmp_path / "o" / "trajectory.tum").read_text().splitlines()[1].split()
    assert np.allclose([float(row[1]), float(row[2])], [float(first[2]), float(first[3])], atol=1e-6)
