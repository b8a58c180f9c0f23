"""``graphslam run`` options that used to be ignored or to end in a traceback:
Rerun sinks that cannot be used, ``--ground-truth`` and the KITTI odometry
layout, refused flags, stale outputs, and the wall time of the whole run."""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from graphslam.cli.main import main
from graphslam.outputs.writers import remove_stale_outputs
from graphslam.sources.ground_truth import (
    planar_ground_truth, read_trajectory, with_ground_truth,
)
from graphslam.sources.planar.posegraph import read_pose_graph
from graphslam.sources.spatial.images import read_image_sequence
from graphslam.visualisation import recording
from slamcore.errors import ConfigError, InputError
from tests.conftest import ROOT, SHARED_DATA

KITTI07 = SHARED_DATA / "kitti07"
needs_kitti = pytest.mark.skipif(not (KITTI07 / "poses.txt").is_file(), reason="no kitti07")


def run_cli(args, cwd, env_extra=None, drop=(), timeout=120):
    env = dict(os.environ, PYTHONPATH=str(ROOT), **(env_extra or {}))
    for k in drop:
        env.pop(k, None)
    return subprocess.run([sys.executable, "-m", "graphslam.cli.main", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout, env=env)


def one_line(stderr: str, prefix: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr  # one line, never a traceback
    assert lines[0].startswith(prefix), stderr
    return lines[0]


def _tum_line(t, T):
    from slamcore.spatial.geometry import rotation_to_quaternion

    q = rotation_to_quaternion(T[None, :3, :3])[0]
    return f"{t} " + " ".join(f"{v:.9f}" for v in (*T[:3, 3], *q)) + "\n"


def _euroc_line(t_s, T):
    x, y, z, qx, qy, qz, qw = _tum_line(0, T).split()[1:]
    return f"{int(round(t_s * 1e9))},{x},{y},{z},{qw},{qx},{qy},{qz}\n"


# --------------------------------------------------------------------------- Rerun sinks

def test_spawn_without_a_viewer_saves_instead(tmp_path):
    out = tmp_path / "out"
    proc = run_cli(["run", "--max-steps", "20", "--rerun", "spawn", "--out", str(out), "--quiet"],
                   tmp_path, env_extra={"PATH": ""}, drop=("DISPLAY", "WAYLAND_DISPLAY"))
    assert proc.returncode == 0, proc.stderr
    assert "saving run.rrd" in one_line(proc.stderr, "graphslam: warning:")
    for name in ("trajectory.tum", "landmarks.csv", "metrics.json", "run.rrd"):
        assert (out / name).is_file(), name


def test_viewer_lookup_needs_the_executable(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", "")
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python"))
    assert recording.find_viewer() is None
    assert "no Rerun viewer executable" in recording.sink_problem("spawn")


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_connect_to_a_closed_port_saves_instead(tmp_path):
    out = tmp_path / "out"
    url = f"rerun+http://127.0.0.1:{_closed_port()}/proxy"
    t0 = time.monotonic()
    proc = run_cli(["run", "--max-steps", "20", "--rerun", "connect", "--rerun-url", url,
                    "--out", str(out), "--quiet"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "no Rerun viewer answers" in one_line(proc.stderr, "graphslam: warning:")
    assert time.monotonic() - t0 < 30  # no wait for a viewer that is not there
    for name in ("trajectory.tum", "landmarks.csv", "metrics.json", "run.rrd"):
        assert (out / name).is_file(), name


def test_malformed_url_is_refused_before_any_work(tmp_path):
    out = tmp_path / "out"
    proc = run_cli(["run", "--rerun", "connect", "--rerun-url", "not a url", "--out", str(out)],
                   tmp_path)
    assert proc.returncode == 2
    assert "not a url" in one_line(proc.stderr, "graphslam: error:")
    assert not out.exists()
    with pytest.raises(ConfigError):
        recording.parse_viewer_url("http://127.0.0.1:9876/proxy")
    assert recording.parse_viewer_url(recording.DEFAULT_VIEWER_URL) == ("127.0.0.1", 9876)


@pytest.mark.parametrize("url", ["rerun+http://[::1/proxy", "rerun+http://[::1]:99999/proxy",
                                 "rerun+http://127.0.0.1:-1/proxy"])
def test_url_urllib_refuses_is_a_config_error(url):
    """Third hostile pass: an unclosed IPv6 bracket made urlsplit raise ValueError (a
    traceback); every URL urllib cannot split is the same one-line refusal."""
    with pytest.raises(ConfigError, match="is not like"):
        recording.parse_viewer_url(url)


# --------------------------------------------------------------------------- ground truth

def _kitti_layout(tmp_path: Path, with_poses: bool = True) -> Path:
    """``dataset/sequences/07`` and ``dataset/poses/07.txt`` linking the kitti07 files."""
    seq = tmp_path / "dataset" / "sequences" / "07"
    seq.mkdir(parents=True)
    for name in ("image_0", "calib.txt", "times.txt"):
        (seq / name).symlink_to(KITTI07 / name)
    if with_poses:
        (tmp_path / "dataset" / "poses").mkdir()
        (tmp_path / "dataset" / "poses" / "07.txt").symlink_to(KITTI07 / "poses.txt")
    return seq


@needs_kitti
def test_kitti_odometry_layout_finds_its_poses(tmp_path):
    seq = read_image_sequence(_kitti_layout(tmp_path))
    assert seq.has_ground_truth and seq.wTc_true.shape == (160, 4, 4)
    np.testing.assert_allclose(seq.wTc_true, read_image_sequence(KITTI07).wTc_true)


@needs_kitti
def test_kitti_frames_copied_out_take_their_own_rows(tmp_path):
    folder = tmp_path / "few"
    (folder / "image_0").mkdir(parents=True)
    for k in (3, 4, 5):
        (folder / "image_0" / f"{k:06d}.png").symlink_to(KITTI07 / "image_0" / f"{k:06d}.png")
    for name in ("calib.txt", "times.txt", "poses.txt"):
        (folder / name).symlink_to(KITTI07 / name)
    seq = read_image_sequence(folder)
    full = read_image_sequence(KITTI07)
    np.testing.assert_allclose(seq.wTc_true, full.wTc_true[3:6])
    np.testing.assert_allclose(seq.stamps_s, full.stamps_s[3:6])


@needs_kitti
def test_ground_truth_that_drops_frames_says_so(tmp_path, capsys):
    """Third hostile pass: a --ground-truth of 3 lines cut a 160-frame KITTI run to 3
    frames, the summary's frame count the only trace."""
    (tmp_path / "gt.txt").write_text("".join((KITTI07 / "poses.txt").read_text().splitlines(True)[:3]))
    assert main(["run", "--dataset", str(KITTI07), "--backend", "ekf", "--rerun", "off", "--quiet",
                 "--out", str(tmp_path / "o"), "--ground-truth", str(tmp_path / "gt.txt")]) == 0
    err = capsys.readouterr().err
    assert (f"graphslam: warning: {tmp_path / 'gt.txt'}: 157 of 160 frames have no "
            "ground truth (by frame index) and are left out of the run") in err
    assert main(["run", "--dataset", str(KITTI07), "--backend", "ekf", "--rerun", "off", "--quiet",
                 "--max-steps", "3", "--out", str(tmp_path / "p"), "--ground-truth",
                 str(KITTI07 / "poses.txt")]) == 0
    assert "ground truth" not in capsys.readouterr().err  # a whole truth drops nothing


@needs_kitti
def test_ground_truth_file_in_three_formats_gives_the_same_ate(tmp_path, capsys):
    """The KITTI layout's own truth, ``--ground-truth`` as KITTI, TUM and EuRoC:
    one ATE, and ``ground_truth.tum`` beside ``trajectory.tum`` (odometry derived from
    each: truth given only to score a run derives none by default)."""
    full = read_image_sequence(KITTI07)
    (tmp_path / "gt.tum").write_text("".join(_tum_line(f"{t:.6f}", T) for t, T in
                                             zip(full.stamps_s, full.wTc_true)))
    (tmp_path / "gt.csv").write_text("#timestamp [ns],px,py,pz,qw,qx,qy,qz\n" + "".join(
        _euroc_line(t, T) for t, T in zip(full.stamps_s, full.wTc_true)))
    bare = _kitti_layout(tmp_path / "bare", with_poses=False)
    common = ["run", "--backend", "ekf", "--max-steps", "5", "--rerun", "off", "--quiet"]
    ates = {}
    for name, extra in [("layout", ["--dataset", str(_kitti_layout(tmp_path / "own"))]),
                        ("kitti", ["--dataset", str(bare), "--ground-truth",
                                   str(KITTI07 / "poses.txt")]),
                        ("tum", ["--dataset", str(bare), "--ground-truth", str(tmp_path / "gt.tum")]),
                        ("euroc", ["--dataset", str(bare), "--ground-truth",
                                   str(tmp_path / "gt.csv")])]:
        out = tmp_path / f"out-{name}"
        assert main(common + extra + ["--odometry", "derived", "--out", str(out)]) == 0
        capsys.readouterr()
        ates[name] = json.loads((out / "metrics.json").read_text())["ate_rmse_m"]
        gt_rows = [ln.split() for ln in (out / "ground_truth.tum").read_text().splitlines()
                   if not ln.startswith("#")]
        traj_rows = [ln.split() for ln in (out / "trajectory.tum").read_text().splitlines()
                     if not ln.startswith("#")]
        assert [r[0] for r in gt_rows] == [r[0] for r in traj_rows] and len(gt_rows) == 5
    assert ates["layout"] is not None
    for name in ("kitti", "tum", "euroc"):
        assert ates[name] == pytest.approx(ates["layout"], rel=1e-6), ates
    # without truth there is no ATE and no ground_truth.tum
    out = tmp_path / "out-none"
    assert main(common + ["--dataset", str(bare), "--odometry", "none", "--out", str(out)]) == 0
    capsys.readouterr()
    assert json.loads((out / "metrics.json").read_text())["ate_rmse_m"] is None
    assert not (out / "ground_truth.tum").exists()


def test_tum_ground_truth_is_matched_by_timestamp(tmp_path):
    folder = tmp_path / "tum"
    (folder / "rgb").mkdir(parents=True)
    lines = []
    for k in range(4):
        cv2.imwrite(str(folder / "rgb" / f"{k}.png"), np.full((480, 640), 10 * k, np.uint8))  # fr3's size
        lines.append(f"{100 + 0.1 * k:.4f} rgb/{k}.png\n")
    (folder / "rgb.txt").write_text("".join(lines))
    seq = read_image_sequence(folder, intrinsics="fr3")
    assert not seq.has_ground_truth
    # truth from the second image on, 5 ms off the image times
    T = [np.eye(4) for _ in range(3)]
    for k, Tk in enumerate(T):
        Tk[0, 3] = k + 1.0
    gt = tmp_path / "groundtruth.txt"
    gt.write_text("".join(_tum_line(f"{100 + 0.1 * (k + 1) + 0.005:.4f}", Tk)
                          for k, Tk in enumerate(T)))
    truth = read_trajectory(gt)
    assert truth.format == "tum"
    got = with_ground_truth(seq, truth)
    assert len(got) == 3 and Path(got.image_paths[0]).name == "1.png"
    np.testing.assert_allclose(got.wTc_true[:, 0, 3], [1, 2, 3])


def _square_graph(tmp_path: Path, n: int = 12) -> tuple[Path, np.ndarray]:
    """A g2o pose graph walking a square with odometry noise, and its (n, 3) truth."""
    rng = np.random.default_rng(1)
    truth = np.zeros((n, 3))
    for k in range(1, n):
        turn = math.pi / 2 if k % 3 == 0 else 0.0
        th = truth[k - 1, 2]
        truth[k] = truth[k - 1] + [math.cos(th), math.sin(th), turn]
    lines = []
    for k in range(1, n):
        d = [1.0, 0.0, truth[k, 2] - truth[k - 1, 2]] + rng.normal(0, 0.05, 3)
        lines.append(f"EDGE_SE2 {k - 1} {k} {d[0]} {d[1]} {d[2]} 100 0 0 100 0 1000\n")
    path = tmp_path / "square.g2o"
    path.write_text("".join(lines))
    return path, truth


def test_pose_graph_ground_truth_by_pose_id(tmp_path, capsys):
    graph, truth = _square_graph(tmp_path)
    gt = tmp_path / "gt.tum"
    gt.write_text("# t x y z qx qy qz qw\n" + "".join(
        f"{k} {x} {y} 0 0 0 {math.sin(th / 2)} {math.cos(th / 2)}\n"
        for k, (x, y, th) in enumerate(truth)))
    ids, wTb = planar_ground_truth(read_pose_graph(graph), read_trajectory(gt))
    np.testing.assert_array_equal(ids, np.arange(len(truth)))
    np.testing.assert_allclose(wTb[:, :2], truth[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.cos(wTb[:, 2] - truth[:, 2]), 1.0, atol=1e-9)

    base = ["run", "--dataset", str(graph), "--rerun", "off", "--quiet"]
    assert main(base + ["--out", str(tmp_path / "no")]) == 0
    assert main(base + ["--ground-truth", str(gt), "--out", str(tmp_path / "gt")]) == 0
    capsys.readouterr()
    assert json.loads((tmp_path / "no" / "metrics.json").read_text())["ate_rmse_m"] is None
    m = json.loads((tmp_path / "gt" / "metrics.json").read_text())
    assert m["ate_rmse_m"] is not None and m["odometry_ate_rmse_m"] is not None
    written = read_trajectory(tmp_path / "gt" / "ground_truth.tum")
    np.testing.assert_array_equal(written.stamps_s, np.arange(len(truth)))
    np.testing.assert_allclose(written.wTc[:, :2, 3], truth[:, :2], atol=1e-6)
    assert not (tmp_path / "no" / "ground_truth.tum").exists()


def test_ground_truth_format_errors_name_the_file(tmp_path):
    bad = tmp_path / "gt.txt"
    bad.write_text("1 2 3 4 5\n")
    with pytest.raises(InputError, match="cannot tell the trajectory format"):
        read_trajectory(bad)
    bad.write_text("1 0 0 0 0 0 0 1\n1 0 0 0 0 0 x 1\n")
    with pytest.raises(InputError, match="gt.txt:2"):
        read_trajectory(bad)


# --------------------------------------------------------------------------- refused flags

@pytest.mark.parametrize("argv, fragment", [
    (["--dataset", "synthetic-images", "--odometry-noise", "0.05", "0.2"], "--odometry-noise"),
    (["--dataset", "synthetic-images", "--odometry", "sequence", "--odometry-noise", "0.05",
      "0.2"], "--odometry-noise"),
    (["--dataset", "synthetic-images", "--backend", "ekf", "--no-polish"], "isam2 back end only"),
    (["--backend", "ekf", "--no-polish"], "isam2 back end only"),
    (["--backend", "fastslam1", "--no-polish"], "isam2 back end only"),
    (["--dataset", "city10000", "--seed", "3"], "--seed has no effect"),
    (["--dataset", "victoria-park", "--backend", "ekf", "--seed", "3"], "--seed has no effect"),
    (["--rerun", "off", "--rerun-every", "3"], "--rerun-every"),
    (["--rerun-url", "rerun+http://127.0.0.1:9876/proxy"], "--rerun connect only"),
])
def test_ignored_flags_are_refused(tmp_path, capsys, argv, fragment):
    out = tmp_path / "out"
    assert main(["run", *argv, "--max-steps", "3", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert fragment in one_line(err, "graphslam: error:")
    assert not (out / "trajectory.tum").exists()


# --------------------------------------------------------------------------- stale outputs

def test_a_second_run_leaves_no_stale_outputs(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", "--max-steps", "20", "--out", str(out), "--quiet"]) == 0
    assert (out / "run.rrd").is_file() and (out / "ground_truth.tum").is_file()
    (out / "notes.txt").write_text("mine")
    (out / "loops.csv").write_text("query,match\n")
    graph, _ = _square_graph(tmp_path)
    assert main(["run", "--dataset", str(graph), "--rerun", "off", "--out", str(out),
                 "--quiet"]) == 0
    capsys.readouterr()
    left = sorted(p.name for p in out.iterdir())
    # a pose graph has no landmarks: the 2-D run's landmarks.csv goes
    assert left == ["closures.csv", "graph.g2o", "metrics.json", "notes.txt", "trajectory.tum"]


def test_remove_stale_outputs_touches_only_known_names(tmp_path):
    for name in ("run.rrd", "trajectory.tum", "other.rrd"):
        (tmp_path / name).write_text("x")
    (tmp_path / "loops.csv").mkdir()
    removed = remove_stale_outputs(tmp_path, {"trajectory.tum"})
    assert [p.name for p in removed] == ["run.rrd"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loops.csv", "other.rrd",
                                                          "trajectory.tum"]


# --------------------------------------------------------------------------- wall time

def test_visual_wall_time_includes_image_loading(tmp_path, capsys, monkeypatch):
    from graphslam.sources.spatial.synthetic_images import SyntheticImageSequence

    render = SyntheticImageSequence.load
    delay_s = 0.1

    def slow_load(self, i):
        time.sleep(delay_s)
        return render(self, i)

    monkeypatch.setattr(SyntheticImageSequence, "load", slow_load)
    out = tmp_path / "out"
    assert main(["run", "--dataset", "synthetic-images", "--backend", "ekf", "--max-steps", "6",
                 "--rerun", "off", "--out", str(out), "--quiet"]) == 0
    summary = capsys.readouterr().out
    m = json.loads((out / "metrics.json").read_text())
    assert m["image_load_s"] >= 6 * delay_s
    assert m["wall_s"] >= m["image_load_s"] + m["processing_s"]
    assert m["frames_per_s"] == pytest.approx(6 / m["wall_s"])
    assert f"{m['wall_s']:.2f}" in summary


def test_planar_wall_time_includes_loading(tmp_path, capsys, monkeypatch):
    from graphslam import registry

    load = registry.load_dataset
    delay_s = 0.3

    def slow(*a, **kw):
        time.sleep(delay_s)
        return load(*a, **kw)

    monkeypatch.setattr(registry, "load_dataset", slow)
    out = tmp_path / "out"
    assert main(["run", "--max-steps", "20", "--rerun", "off", "--out", str(out), "--quiet"]) == 0
    capsys.readouterr()
    m = json.loads((out / "metrics.json").read_text())
    assert m["wall_s"] >= delay_s + m["backend_s"]
