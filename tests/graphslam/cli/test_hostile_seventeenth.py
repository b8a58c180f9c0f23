"""The seventeenth hostile pass (2026-12-04): findings of the sixteenth left open, and
the new pass's. Each test reproduces a finding, then checks what the code does now."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from graphslam.cli.main import main
from graphslam.pipelines.sweep_spec import parse_sweep

REPO = Path(__file__).resolve().parents[3]


def _sweep_file(tmp_path: Path, extra: str = "") -> Path:
    import gtsam

    graph = gtsam.findExampleDataFile("noisyToyGraph.txt")
    path = tmp_path / "sweep.toml"
    path.write_text(f'[sweep]\ndataset = ["synthetic", "{graph}"]\nbackend = ["isam2"]\n{extra}')
    return path


def test_a_mixed_sweep_says_its_synthetic_runs_score_no_nees(tmp_path):
    """dataset = ["synthetic", a pose graph]: NEES off by default for every run, the
    synthetic ones included, and nothing said (hostile pass 16)."""
    spec = parse_sweep(_sweep_file(tmp_path))
    assert spec.nees is False
    assert len(spec.notes) == 1 and "nees = true" in spec.notes[0]
    assert all(not r.nees for r in spec.runs())


def test_a_sweep_that_chose_its_nees_is_told_nothing(tmp_path):
    assert parse_sweep(_sweep_file(tmp_path, "nees = false\n")).notes == ()
    only = tmp_path / "only.toml"
    only.write_text('[sweep]\ndataset = ["synthetic"]\nbackend = ["isam2"]\n')
    spec = parse_sweep(only)
    assert spec.nees is True and spec.notes == ()


def test_a_stop_signal_during_the_last_of_the_exit_is_ignored_not_a_silent_death(tmp_path):
    """A SIGTERM as a sweep exited killed it by the default action (status -15, no line),
    everything written: Python resets its handlers to the default late in its exit, and a
    progress bar's thread took the signal. The console script's last exit handler now
    ignores the stop signals; a hook that runs after it (registered before ``entry``)
    sends one and the command keeps its own status."""
    script = (
        "import atexit, os, signal, sys, time\n"
        "def late():\n"
        "    assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN, signal.getsignal(signal.SIGTERM)\n"
        "    os.kill(os.getpid(), signal.SIGTERM); time.sleep(0.2)\n"
        "atexit.register(late)\n"
        "sys.argv = ['graphslam', '--version']\n"
        "from graphslam.cli.main import entry\n"
        "entry()\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert done.returncode == 0, (done.returncode, done.stderr)
    assert "graphslam" in done.stdout and done.stderr == ""


def _serve_once(reply: bytes | None) -> tuple[int, object]:
    """A one-connection TCP server on a free port that reads what it is sent and answers
    ``reply`` (None: says nothing until the client leaves). Returns (port, thread)."""
    import socket
    import threading

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(4)
    port = srv.getsockname()[1]

    def serve():
        with srv:
            for _ in range(4):  # the check's probes, then the run's own connection
                try:
                    srv.settimeout(20)
                    conn, _ = srv.accept()
                except OSError:
                    return
                with conn:
                    conn.settimeout(3)
                    try:
                        conn.recv(64)
                        if reply is not None:
                            conn.sendall(reply)
                        conn.recv(64)
                    except OSError:
                        pass

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return port, thread


def test_connect_to_a_port_where_no_grpc_server_answers_saves_instead(tmp_path):
    """``--rerun connect`` to a web server's port: exit 0, "the recording is incomplete",
    nothing recorded and no run.rrd (the check asked only whether the port was open)."""
    from graphslam.visualisation.recording import sink_problem

    port, _ = _serve_once(b"HTTP/1.0 400 Bad request\r\n\r\n<!DOCTYPE html>")
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    out = tmp_path / "o"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "graphslam",
            "run",
            "--max-steps",
            "10",
            "--rerun",
            "connect",
            "--rerun-url",
            url,
            "--out",
            str(out),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert done.returncode == 0, done.stderr
    assert "not as a gRPC server" in done.stderr and "saving run.rrd" in done.stderr
    assert (out / "run.rrd").is_file() and (out / "trajectory.tum").is_file()
    silent, _ = _serve_once(None)
    why = sink_problem("connect", f"rerun+http://127.0.0.1:{silent}/proxy")
    assert why is not None and "says nothing" in why


def test_a_grpc_server_passes_the_connect_check():
    """What a gRPC server (Rerun's viewer is one) answers first: a SETTINGS frame."""
    from graphslam.visualisation.recording import sink_problem

    port, _ = _serve_once(bytes([0, 0, 0, 4, 0, 0, 0, 0, 0]))
    assert sink_problem("connect", f"rerun+http://127.0.0.1:{port}/proxy") is None


def _scaled_cut(src: Path, dst: Path, last_pose: int, scale: float) -> Path:
    """Poses below ``last_pose`` of a 2-D g2o file and their edges, every information entry
    times ``scale``."""
    out = []
    for line in src.read_text().splitlines():
        p = line.split()
        if p and p[0] == "VERTEX_SE2" and int(p[1]) < last_pose:
            out.append(line)
        elif p and p[0] == "EDGE_SE2" and int(p[1]) < last_pose and int(p[2]) < last_pose:
            out.append(" ".join(p[:6] + [repr(float(x) * scale) for x in p[6:]]))
    dst.write_text("\n".join(out) + "\n")
    return dst


def test_information_near_1e300_is_no_traceback_in_run_or_compare(tmp_path, shared_data):
    """600 poses of Bovisa04 with every edge's information times 1e297: iSAM2's estimate
    (its back-substitution) met an indeterminate system after the updates had passed, a
    RuntimeError traceback in ``run`` and in ``compare``, nothing written."""
    graph = _scaled_cut(
        shared_data / "rrr_posegraphs" / "Bovisa04_odometry_bow_tr.g2o", tmp_path / "huge.g2o", 600, 1e297
    )
    out = tmp_path / "o"
    assert (
        main(["run", "--dataset", str(graph), "--backend", "isam2", "--rerun", "off", "--out", str(out)]) == 0
    )
    metrics = json.loads((out / "metrics.json").read_text())
    assert any("solved by batch LM" in r for r in metrics["numerical_recoveries"]), metrics[
        "numerical_recoveries"
    ]
    cmp_out = tmp_path / "c"
    code = main(
        [
            "compare",
            "--dataset",
            str(graph),
            "--backends",
            "isam2",
            "batch",
            "--rerun",
            "off",
            "--out",
            str(cmp_out),
        ]
    )
    assert code in (0, 1) and (cmp_out / "compare.json").is_file()


def test_eval_of_several_estimates_scores_the_valid_ones_when_one_is_refused(tmp_path, capsys):
    """``eval gt est still.tum``: the estimate that never moves was refused, exit 2, and
    the valid one was not scored or written either."""
    from tests import trajectories as tr

    gt, est = tr.write_pair(tmp_path, "tum")
    rows = [ln.split() for ln in est.read_text().splitlines() if ln and not ln.startswith("#")]
    still = tmp_path / "still.tum"
    still.write_text("".join(f"{r[0]} 0 0 0 0 0 0 1\n" for r in rows))
    code, out, err = tr.run_eval(tmp_path, capsys, gt, est, still)
    assert code == 1, err
    doc = json.loads((tmp_path / "o" / "eval.json").read_text())
    assert [Path(e["estimate"]).name for e in doc["estimates"]] == [est.name]
    assert [Path(r["estimate"]).name for r in doc["refused"]] == ["still.tum"]
    assert "not scored" in err and "still.tum" in err and "Traceback" not in err
    # alone, it is the one error line it was
    code, _, err = tr.run_eval(tmp_path, capsys, gt, still)
    assert code == 2
    tr.one_error(err, "still.tum")


def test_an_unreadable_estimate_is_not_called_the_ground_truth(tmp_path, capsys):
    from tests import trajectories as tr

    gt, _ = tr.write_pair(tmp_path, "tum")
    five = tmp_path / "five.txt"
    five.write_text("1 2 3 4 5\n")
    code, _, err = tr.run_eval(tmp_path, capsys, gt, five)
    assert code == 2
    tr.one_error(err, "five.txt", "cannot tell the trajectory format")


def test_a_camera_alone_landmark_budget_below_a_pose_is_refused_with_its_line(tmp_path, shared_data, capsys):
    """``[isam2_visual] max_landmarks_per_frame = 1`` without odometry: IndexError from
    gtsam's jointMarginalCovariance (a pose with no factor), nothing written."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[isam2_visual]\nmax_landmarks_per_frame = 1\n")
    argv = [
        "run",
        "--dataset",
        str(shared_data / "kitti07"),
        "--frames",
        "0:12",
        "--config",
        str(cfg),
        "--rerun",
        "off",
        "--quiet",
        "--out",
    ]
    assert main([*argv, str(tmp_path / "o"), "--odometry", "none"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{cfg}:2" in err and "at least 3" in err
    assert main([*argv, str(tmp_path / "d"), "--odometry", "derived"]) == 0  # odometry places the poses


def test_a_pixel_noise_at_round_off_stops_the_monocular_ekf_in_one_line(tmp_path, shared_data, capsys):
    """``[tracker] sigma_px = 1e-9`` under the camera-alone EKF: LinAlgError traceback."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[tracker]\nsigma_px = 1e-9\n")
    out = tmp_path / "o"
    code = main(
        [
            "run",
            "--dataset",
            str(shared_data / "kitti07"),
            "--frames",
            "0:12",
            "--odometry",
            "none",
            "--backend",
            "ekf",
            "--config",
            str(cfg),
            "--rerun",
            "off",
            "--quiet",
            "--out",
            str(out),
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and "not positive definite" in err and "Traceback" not in err
    assert (out / "trajectory.tum").is_file()


def test_a_full_disk_write_is_tried_again_once_room_is_made(tmp_path):
    """OutputWrites asks its ``make_room`` once, at the first write a full disk refuses,
    and tries that write again when room was made."""
    import errno

    from graphslam.outputs.writers import OutputWrites

    calls = {"room": 0, "write": 0}

    def room() -> bool:
        calls["room"] += 1
        return True

    def writer(path):
        calls["write"] += 1
        if calls["write"] == 1:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        path.write_text("ok")

    writes = OutputWrites(tmp_path, make_room=room)
    paths: dict = {}
    assert writes(paths, "a", tmp_path / "a.txt", writer) and (tmp_path / "a.txt").read_text() == "ok"
    assert calls == {"room": 1, "write": 2} and writes.refused == []

    def full(path):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    assert not writes(paths, "b", tmp_path / "b.txt", full)  # asked once only
    assert calls["room"] == 1 and [p.name for p, _ in writes.refused] == ["b.txt"]


def test_a_recording_that_fills_the_disk_gives_way_to_the_run_files(tmp_path, shared_data):
    """A 600 kB disk, 20 KITTI frames camera alone: the recording's partial file held the
    disk, every text output was refused (exit 2, an empty folder) and only then was the
    partial deleted. Needs a tmpfs mount (root); skipped where none can be made."""
    import shutil

    disk = tmp_path / "small"
    disk.mkdir()
    if (
        subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=600k", "tmpfs", str(disk)], capture_output=True
        ).returncode
        != 0
    ):
        pytest.skip("cannot mount a small tmpfs here")
    try:
        kitti = shared_data / "kitti07"
        seq = tmp_path / "seq"
        (seq / "image_0").mkdir(parents=True)
        shutil.copy(kitti / "calib.txt", seq)
        for name in ("times.txt", "poses.txt"):
            (seq / name).write_text("".join((kitti / name).read_text().splitlines(keepends=True)[:20]))
        for k in range(20):
            shutil.copy(kitti / "image_0" / f"{k:06d}.png", seq / "image_0")
        out = disk / "o"
        done = subprocess.run(
            [
                sys.executable,
                "-m",
                "graphslam",
                "run",
                "--dataset",
                str(seq),
                "--odometry",
                "none",
                "--out",
                str(out),
                "--quiet",
            ],
            capture_output=True,
            text=True,
            timeout=300,
            env={**os.environ, "PYTHONPATH": str(REPO)},
        )
        assert done.returncode == 0, done.stderr
        assert "recording (run.rrd) is given up" in done.stderr
        names = sorted(p.name for p in out.iterdir())
        assert names == ["ground_truth.tum", "landmarks.csv", "metrics.json", "trajectory.tum"], names
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)


def test_an_mrclam_landmark_truth_of_its_header_alone_is_not_called_absent(tmp_path, shared_data):
    from graphslam.sources.planar.mrclam import MrclamConfig, read_mrclam

    src = shared_data / "mrclam6"
    folder = tmp_path / "m"
    folder.mkdir()
    for f in src.iterdir():
        if f.name != "Landmark_Groundtruth.dat":
            (folder / f.name).symlink_to(f)
    head = src.joinpath("Landmark_Groundtruth.dat").read_text().splitlines(keepends=True)[:4]
    (folder / "Landmark_Groundtruth.dat").write_text("".join(head))
    notes = read_mrclam(folder, MrclamConfig(robot=1)).notes
    assert any("Landmark_Groundtruth.dat lists no landmark" in n for n in notes), notes
    assert not any(n.startswith("no Landmark_Groundtruth.dat") for n in notes)


@pytest.mark.parametrize("backend", ["batch", "auto"])
def test_a_whole_graph_solver_on_a_file_that_is_no_graph_says_what_the_file_is(tmp_path, capsys, backend):
    """``--backend batch`` on a gzipped graph, an empty file or a TUM file said only that
    it "solves pose-graph files only"; without --backend the same files got their cause."""
    import gzip

    files = {
        "g.g2o": gzip.compress(b"VERTEX_SE2 0 0 0 0\n"),
        "empty.g2o": b"",
        "poses.txt": b"0.0 1 2 3 0 0 0 1\n",
    }
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    for name, cause in (
        ("g.g2o", "gzip-compressed"),
        ("empty.g2o", "no pose-graph edges"),
        ("poses.txt", "poses.txt:1:"),
    ):
        code = main(
            [
                "run",
                "--dataset",
                str(tmp_path / name),
                "--backend",
                backend,
                "--rerun",
                "off",
                "--out",
                str(tmp_path / "o"),
            ]
        )
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1, err
        assert cause in err and "pose-graph files only" in err, err


def test_a_failed_run_says_the_folder_still_holds_an_earlier_run(tmp_path, shared_data, capsys):
    """A run that fails before writing (camera alone, frames all black) left an earlier
    run's trajectory and metrics in --out, unsaid, beside its error."""
    import shutil

    out = tmp_path / "o"
    assert main(["run", "--max-steps", "5", "--rerun", "off", "--quiet", "--out", str(out)]) == 0
    kitti = shared_data / "kitti07"
    seq = tmp_path / "black"
    (seq / "image_0").mkdir(parents=True)
    shutil.copy(kitti / "calib.txt", seq)
    (seq / "times.txt").write_text("".join(f"{0.1 * k:.1f}\n" for k in range(8)))
    black = np.zeros((376, 1241), np.uint8)
    import cv2

    for k in range(8):
        cv2.imwrite(str(seq / "image_0" / f"{k:06d}.png"), black)
    capsys.readouterr()
    code = main(
        ["run", "--dataset", str(seq), "--odometry", "none", "--rerun", "off", "--quiet", "--out", str(out)]
    )
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and "still holds an earlier command's trajectory.tum" in err, err


def test_an_ate_that_cannot_be_scored_says_why_beside_its_n_a(tmp_path, shared_data, capsys):
    """``[mono_ekf] frame_dt_s = 1e-9``: the estimate never moves, the summary read "ATE
    n/a" and the reason was in metrics.json only."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[mono_ekf]\nframe_dt_s = 1e-9\n")
    out = tmp_path / "o"
    assert (
        main(
            [
                "run",
                "--dataset",
                str(shared_data / "kitti07"),
                "--frames",
                "0:12",
                "--odometry",
                "none",
                "--backend",
                "ekf",
                "--config",
                str(cfg),
                "--rerun",
                "off",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    captured = capsys.readouterr()
    said = captured.out + captured.err
    assert "ATE not scored" in said and "does not move" in said
    assert any("ATE not scored" in w for w in json.loads((out / "metrics.json").read_text())["warnings"])


def test_image_data_damaged_inside_a_whole_file_is_refused_by_name(shared_data, capfd):
    """A JPEG cut inside with its end marker kept decoded to grey below the cut and ran
    as a frame (exit 0; libjpeg's bare line named no file); a PNG whose data is damaged
    gave libpng's stray line and "not an image file"."""
    import cv2

    from frontend.image import decode_gray
    from slamcore.errors import InputError

    png = (shared_data / "kitti07" / "image_0" / "000010.png").read_bytes()
    ok, jpg = cv2.imencode(".jpg", cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE))
    jpg = jpg.tobytes()
    cut = jpg[: len(jpg) // 3] + jpg[-2:]
    bad = bytearray(png)
    for i in range(len(bad) // 2, len(bad) // 2 + 2000):
        bad[i] ^= 0x5A
    for data, name, what in ((cut, "cut.jpg", "Corrupt JPEG data"), (bytes(bad), "bad.png", "libpng error")):
        with pytest.raises(InputError, match=f"damaged image data \\({what}") as e:
            decode_gray(data, name)
        assert name in str(e.value)
    assert decode_gray(jpg, "whole.jpg").shape == (370, 1226)
    assert capfd.readouterr().err == ""  # the decoders' own lines are not left on stderr


def test_eval_of_two_matched_poses_under_a_rigid_fit_says_it_scores_little(tmp_path, capsys):
    from tests import trajectories as tr

    gt, _ = tr.write_pair(tmp_path, "tum")
    rows = [ln for ln in gt.read_text().splitlines() if ln and not ln.startswith("#")][:2]
    two = tmp_path / "two.tum"
    two.write_text(
        "".join(" ".join([r.split()[0], str(float(r.split()[1]) + 0.3)] + r.split()[2:]) + "\n" for r in rows)
    )
    code, out, err = tr.run_eval(tmp_path, capsys, gt, two)
    assert code == 0 and "only 2 poses matched" in err, err


def test_a_solve_that_took_no_step_from_its_start_says_so(tmp_path, shared_data, capsys):
    """600 poses of Bovisa04, every information entry times 1e12 (the same optimum): LAGO
    and LM met indeterminate systems, LM took 0 iterations, the trajectory was the
    odometry start 19 m from the optimum, and the one line blamed the closures. At the
    file's own scale the same cut converges (17 iterations) and nothing is said."""
    src = shared_data / "rrr_posegraphs" / "Bovisa04_odometry_bow_tr.g2o"
    for scale, stalled in ((1e12, True), (1.0, False)):
        graph = _scaled_cut(src, tmp_path / f"s{scale:g}.g2o", 600, scale)
        out = tmp_path / f"o{scale:g}"
        assert (
            main(["run", "--dataset", str(graph), "--backend", "batch", "--rerun", "off", "--out", str(out)])
            == 0
        )
        said = capsys.readouterr()
        metrics = json.loads((out / "metrics.json").read_text())
        assert ("took no step from its start" in said.err) == stalled, said.err
        assert metrics["converged"] is (not stalled)


def test_a_refused_write_that_names_no_file_is_given_its_name(tmp_path):
    """``--save-map`` under a file-size limit: "file larger than this system allows writing
    an output file" (numpy's zip writer names no file); the refused output is named."""
    import errno

    from graphslam.outputs.writers import OutputWrites

    def writer(path):
        raise OSError(errno.EFBIG, "File too large")

    writes = OutputWrites(tmp_path)
    assert not writes.attempt(tmp_path / "map", writer, tmp_path / "map")
    with pytest.raises(Exception, match="map") as e:
        writes.check([])
    assert "an output file" not in str(e.value)


def test_follow_settings_under_a_back_end_that_follows_nothing_are_said_to_do_nothing(
    tmp_path, shared_data, capsys
):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[tracker]\nfollow_window_px = 1\nmax_unmapped_age = 1\n")
    base = [
        "run",
        "--dataset",
        str(shared_data / "kitti07"),
        "--frames",
        "0:20",
        "--odometry",
        "none",
        "--config",
        str(cfg),
        "--rerun",
        "off",
        "--quiet",
        "--out",
    ]
    assert main([*base, str(tmp_path / "e"), "--backend", "ekf"]) == 0
    err = capsys.readouterr().err
    assert "follow_window_px, max_unmapped_age did nothing" in err, err
    assert main([*base, str(tmp_path / "i")]) == 0  # iSAM2 follows them: read
    assert "did nothing" not in capsys.readouterr().err


@pytest.mark.parametrize(
    ("name", "text", "kind"),
    [("gt.g2o", "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n", "g2o pose graph (VERTEX_SE2 lines)"),
     # eight tokens: it was read as TUM and refused at its first word as "not a number"
     ("gt.graph", "VERTEX3 0 0 0 0 0 0 0\n", "TORO pose graph (VERTEX3 lines)")],
)
def test_a_pose_graph_given_as_truth_is_named_as_one(tmp_path, capsys, name, text, kind):
    """RRR's ``Bovisa04_GT_GPS.g2o`` given to eval: "5 numbers a line" of a line that begins
    with a word. Its vertex ids are not the run's (1140 GPS vertices for 11393 poses), so it
    is refused, named as what it is, not paired by id."""
    from tests import trajectories as tr

    gt, _ = tr.write_pair(tmp_path, "tum")
    graph = tmp_path / name
    graph.write_text(text)
    code, _, err = tr.run_eval(tmp_path, capsys, gt, graph)
    assert code == 2
    tr.one_error(err, name, f"a {kind}, not a trajectory file")
