"""The eighteenth hostile pass (2026-12-05): findings of the seventeenth left open.
Each test reproduces a finding, then checks what the code does now."""

from __future__ import annotations

import numpy as np
import pytest

from graphslam.sources.spatial.frames import parse_frames, select_frames
from graphslam.sources.spatial.sequence import ImageSequence


def _sequence(n: int) -> ImageSequence:
    K = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])
    truth = np.tile(np.eye(4), (n, 1, 1))
    return ImageSequence("fake", [f"/nowhere/{k:06d}.png" for k in range(n)], None, K, None, truth, (64, 48))


@pytest.mark.parametrize("frames", ["0:15", "5:11", "12::-1", "::"])
def test_frames_past_the_end_are_said(frames):
    """--frames 0:15 on a 10-frame folder ran 10 frames unsaid (a slice clips)."""
    picked = select_frames(_sequence(10), parse_frames(frames))
    said = [w for w in picked.warnings if "reaches past the sequence's 10 frames" in w]
    assert len(said) == (frames != "::")


@pytest.mark.parametrize("frames", ["0:10", "3:7", "9::-1", "-3:"])
def test_frames_inside_the_sequence_say_nothing(frames):
    assert not select_frames(_sequence(10), parse_frames(frames)).warnings


def test_a_principal_point_no_camera_has_names_its_yaml_line(tmp_path):
    """A calibration YAML whose principal point is 1e7 px was refused without a line
    number: the mapping parsed has none, so the line is found in the text."""
    from graphslam.sources.spatial.calibration import read_intrinsics_file
    from slamcore.errors import InputError

    path = tmp_path / "camera.yaml"
    path.write_text(
        "%YAML:1.0\nimage_width: 64\n\ncamera_matrix: !!opencv-matrix\n  rows: 3\n  cols: 3\n"
        "  dt: d\n  data: [100, 0, 1.0e7, 0, 100, 24, 0, 0, 1]\n"
    )
    with pytest.raises(InputError, match=r"camera\.yaml:4: principal point"):
        read_intrinsics_file(path)
    path.write_text("fx: 100\nfy: 100\ncx: 32\ncy: 24\nintrinsics: [1, 2, 3]\n")
    np.testing.assert_allclose(read_intrinsics_file(path)[0][0, 0], 100)


class _OneRowThenStop:
    """An executor whose first run is reported and whose second finishes unreported
    (its metrics.json written) as the stop comes: the harvest's case."""

    def map_unordered(self, runs, root):
        first, second = runs[0], runs[1]
        folder = root / "runs" / second.run_id
        folder.mkdir(parents=True)
        (folder / "metrics.json").write_text('{"interrupted": false}')
        yield first, {"run_id": first.run_id, "status": "ok", "error": "", "wall_s": 1.0}

    def close(self):
        pass


def test_a_second_signal_while_a_stopped_sweep_saves_loses_no_finished_run(tmp_path):
    """Ctrl-C, then a batch system's SIGTERM while the sweep gathered the runs that
    finished as the first came: the second signal cut the harvest and those runs were
    left out of sweep.csv (the rare race of hostile pass 17)."""
    import signal

    from graphslam.pipelines.common import stop_guard
    from graphslam.pipelines.sweep import run_sweep
    from graphslam.pipelines.sweep_spec import parse_sweep

    sweep = tmp_path / "s.toml"
    sweep.write_text('[sweep]\ndataset = ["synthetic"]\nbackend = ["isam2"]\nseed = [0, 1]\nmax_steps = 5\n')
    spec = parse_sweep(sweep)
    with stop_guard() as guard:

        def ctrl_c(run, row):
            guard._handle(signal.SIGINT, None)  # the user's Ctrl-C, through the guard

        def harvested(folder):
            guard._handle(signal.SIGTERM, None)  # the second signal, mid-harvest
            return {"wall_s": None, "status": "ok", "error": "", "ate_rmse_m": 0.5}

        outcome = run_sweep(
            spec, tmp_path / "o", _OneRowThenStop(), on_result=ctrl_c, score_finished=harvested
        )
    assert outcome.interrupted
    assert [r["status"] for r in outcome.rows] == ["ok", "ok"]
    assert (tmp_path / "o" / "sweep.csv").read_text().count("\n") == 3  # header and both runs


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serve(exe: str):
    """A Rerun gRPC server (a viewer without a window) on a free port: ``(process, url)``."""
    import subprocess
    import time

    from graphslam.visualisation.recording import sink_problem

    port = _free_port()
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    # its own session: the `rerun` script starts the server as a child, killed with it
    server = subprocess.Popen(
        [exe, "--serve-grpc", "--port", str(port)],
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 60
    while sink_problem("connect", url) is not None:
        assert server.poll() is None and time.monotonic() < deadline
        time.sleep(0.2)
    return server, url


def test_a_full_disk_gives_up_a_viewers_copy_on_disk_and_the_stream_goes_on(tmp_path, capsys):
    """A full disk refusing a run's own file gave up a saved recording only: under
    ``--rerun connect`` the stream's copy on disk kept growing and the run's files were
    lost. The copy now goes, with a warning, and the viewer keeps taking the stream."""
    import os
    import signal

    from graphslam.cli.out_folder import OutputFolder
    from graphslam.visualisation.planar import RunRecorder
    from graphslam.visualisation.recording import find_viewer

    exe = find_viewer()
    if exe is None:
        pytest.skip("no Rerun viewer executable")
    server, url = _serve(exe)
    try:
        folder = OutputFolder(tmp_path / "o")
        recorder = folder.open_recorder(RunRecorder.open, "connect", "run.rrd", url)
        log = recorder.log
        for k in range(20):
            log.set_step(k)
            log.rec.log("p", log._rr.Points2D([[k, k]]))
        log.rec.flush(timeout_sec=10)
        (copy,) = [p for p in (tmp_path / "o").iterdir() if p.name != "run.rrd"]
        assert copy.stat().st_size > 0
        assert folder.give_up_recording()
        assert not copy.exists() and "the recording's copy on disk is given up" in capsys.readouterr().err
        for k in range(20, 40):  # the stream goes on, to the viewer only
            log.set_step(k)
            log.rec.log("p", log._rr.Points2D([[k, k]]))
        paths: dict = {}
        folder.close_recorder(paths)  # the viewer took everything: nothing said, nothing kept
        assert paths == {} and list((tmp_path / "o").iterdir()) == []
        assert capsys.readouterr().err == ""
        assert not folder.give_up_recording()  # no copy left to give up
    finally:
        os.killpg(server.pid, signal.SIGKILL)


def test_a_viewer_that_dies_during_the_run_leaves_the_whole_recording(tmp_path):
    """``--rerun connect`` to a viewer killed during the run: the end said "the recording
    is incomplete" and nothing of it was kept. The stream is now copied to a hidden file
    beside run.rrd, which becomes run.rrd when the viewer went, and goes when it did not."""
    import os
    import shutil
    import signal
    import subprocess

    from graphslam.visualisation.recording import RerunLog, SavedInstead, find_viewer

    exe = find_viewer()
    if exe is None:
        pytest.skip("no Rerun viewer executable")

    def serve() -> tuple[subprocess.Popen, str]:
        return _serve(exe)

    def points(log, steps):
        for k in steps:
            log.set_step(k)
            log.rec.log("p", log._rr.Points2D([[k, k]]))

    server, url = serve()
    try:
        log = RerunLog("connect", tmp_path / "run.rrd", url)
        points(log, range(30))
        log.rec.flush(timeout_sec=10)
        os.killpg(server.pid, signal.SIGKILL)
        server.wait()
        points(log, range(30, 100))
        with pytest.raises(SavedInstead, match=r"run\.rrd holds the whole recording"):
            log.close()
        assert [p.name for p in tmp_path.iterdir()] == ["run.rrd"]
        rerun_cli = shutil.which("rerun", path=os.path.dirname(exe)) or exe
        stats = subprocess.run(
            [rerun_cli, "rrd", "stats", str(tmp_path / "run.rrd")], capture_output=True, text=True, timeout=60
        )
        rows = int(stats.stdout.split("num_rows = ")[1].split()[0])
        assert rows >= 100, stats.stdout  # the 70 points sent after the death too
    finally:
        if server.poll() is None:
            os.killpg(server.pid, signal.SIGKILL)

    # a viewer that stays: the copy goes, nothing is said
    server, url = serve()
    try:
        (tmp_path / "again").mkdir()
        log = RerunLog("connect", tmp_path / "again" / "run.rrd", url)
        points(log, range(10))
        log.close()
        assert list((tmp_path / "again").iterdir()) == []
    finally:
        os.killpg(server.pid, signal.SIGKILL)


def test_sphere2500_keeps_its_weights_through_the_toolkits_own_files(tmp_path, capsys):
    """gtsam's sphere2500.txt (square-root numbers, known by its hash) converted to TORO
    was written as read: the copy, no longer known, was read as information, and its
    weights changed unsaid (cost 364 against 7403). TORO is now written as information."""
    import gtsam

    from graphslam.cli.main import main
    from graphslam.sources.posegraph_files import read_pose_graph_file

    src = gtsam.findExampleDataFile("sphere2500.txt")
    assert main(["convert", src, str(tmp_path / "s.graph")]) == 0
    assert "written as information" in capsys.readouterr().err
    direct = read_pose_graph_file(src)
    again = read_pose_graph_file(tmp_path / "s.graph")
    assert direct.noise == "sqrt_information" and again.noise == "information"
    np.testing.assert_allclose(again.information, direct.information, rtol=1e-6)
    # and a flag that acts on TORO files only says so on a g2o one
    assert main(["convert", str(tmp_path / "s.graph"), str(tmp_path / "s.g2o")]) == 0
    assert (
        main(["convert", str(tmp_path / "s.g2o"), str(tmp_path / "t.g2o"), "--toro-noise", "information"])
        == 0
    )
    assert "--toro-noise information did nothing" in capsys.readouterr().err


def test_a_pose_graph_recording_that_cannot_start_costs_only_itself(tmp_path, capsys, monkeypatch):
    """A pose-graph run opens its recording after writing its files; on a disk they
    filled, Rerun's writer refused to start and the traceback lost the run's summary
    (hostile pass 18: "Failed to encode LogMsg ... No space left on device")."""
    gtsam = pytest.importorskip("gtsam")
    import rerun

    from graphslam.cli.main import main

    def full_disk(self, path, *args, **kwargs):
        raise RuntimeError("Failed to encode LogMsg: Failed to write: No space left on device (os error 28)")

    monkeypatch.setattr(rerun.RecordingStream, "save", full_disk)
    out = tmp_path / "o"
    argv = ["run", "--dataset", gtsam.findExampleDataFile("w100.graph"), "--backend", "batch"]
    assert main([*argv, "--rerun", "save", "--quiet", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "the recording could not be started" in captured.err and "Traceback" not in captured.err
    assert "no run.rrd is kept" in captured.err
    listed = [ln for ln in captured.out.splitlines() if ln.startswith("outputs in")]
    assert listed and "run.rrd" not in listed[-1] and "graph.graph" in listed[-1]
    assert not (out / "run.rrd").exists() and not list(out.glob(".*rrd*"))


def test_convert_into_a_pipe_is_refused_and_the_pipe_kept(tmp_path, capsys):
    """convert IN /dev/stdout (or a FIFO) replaced the pipe with a regular file, unsaid:
    the output is written beside and moved over it."""
    import os
    import stat

    gtsam = pytest.importorskip("gtsam")
    from graphslam.cli.main import main

    fifo = tmp_path / "pipe.g2o"
    os.mkfifo(fifo)
    assert main(["convert", gtsam.findExampleDataFile("w100.graph"), str(fifo)]) == 2
    err = capsys.readouterr().err
    assert "is not a regular file" in err and len(err.strip().splitlines()) == 1
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_an_output_folder_holding_a_pipe_under_an_output_name_is_refused(tmp_path):
    import os

    from slamcore.errors import ConfigError
    from slamcore.files import check_output_dir

    os.mkfifo(tmp_path / "sweep.csv")
    with pytest.raises(ConfigError, match="not a regular file"):
        check_output_dir(tmp_path, files=("sweep.csv",))
    check_output_dir(tmp_path, files=("other.csv",))


def test_a_bag_of_times_past_its_int32_seconds_is_one_line(tmp_path):
    """--write-bag on a pose graph whose ids (its times) pass 2^31 ended in struct.error."""
    pytest.importorskip("rosbags")
    from graphslam.outputs.trajectory_bag import write_trajectory_bag
    from slamcore.errors import InputError

    poses = np.tile(np.eye(4), (2, 1, 1))
    with pytest.raises(InputError, match="below 2\\^31 s"):
        write_trajectory_bag(tmp_path / "t.bag", np.array([0.0, 3e9]), poses)
    assert not list(tmp_path.iterdir())
    write_trajectory_bag(tmp_path / "t.bag", np.array([0.0, 2.0**31 - 1]), poses)  # the last second fits


def test_a_g2o_line_ending_in_a_comment_is_read(tmp_path):
    """``EDGE_SE2 ... # odometry`` was refused as "needs 12 tokens, got 14"."""
    from graphslam.sources.posegraph_files import read_pose_graph_file

    commented, plain = tmp_path / "c.g2o", tmp_path / "p.g2o"
    body = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0{}\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1{}\n"
    commented.write_text(body.format("  # the second pose", " # odometry"))
    plain.write_text(body.format("", ""))
    a, b = read_pose_graph_file(commented), read_pose_graph_file(plain)
    assert np.array_equal(a.edges, b.edges) and np.array_equal(a.measurements, b.measurements)
    assert np.array_equal(a.vertices, b.vertices)


def test_a_warning_quoting_a_name_with_a_newline_is_one_line(capsys):
    from graphslam.cli.common import warn

    warn("bad\nname.tum: 3 of 4 poses have no truth")
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("graphslam: warning: bad name.tum")


def test_a_filter_on_a_pose_graph_says_its_skipped_closures_on_stderr(tmp_path, capsys):
    """The EKF on a 2-D pose graph with closures printed "WARNING: ekf cannot use loop
    closures" in the summary on stdout: piped to a file, the doubt went with it."""
    gtsam = pytest.importorskip("gtsam")
    from graphslam.cli.main import main

    argv = ["run", "--dataset", gtsam.findExampleDataFile("w100.graph"), "--backend", "ekf"]
    assert main([*argv, "--rerun", "off", "--quiet", "--out", str(tmp_path / "o")]) == 0
    captured = capsys.readouterr()
    assert "graphslam: warning: ekf cannot use loop closures" in captured.err
    assert "cannot use loop closures" not in captured.out


def _tum_line_file(path, stamps, xs):
    path.write_text("".join(f"{t:.3f} {x:.3f} 0 0 0 0 0 1\n" for t, x in zip(stamps, xs)))
    return path


@pytest.mark.parametrize(
    "align, n_est, said",
    [
        ("se3", 10, "span 9 % of the reference's time"),  # 10 of 100 poses, none said
        ("first", 2, "only 2 poses matched: the ATE is theirs alone (and the first's"),
        ("none", 2, "only 2 poses matched: the ATE is theirs alone"),
    ],
)
def test_eval_says_how_little_of_the_reference_an_estimate_covers(tmp_path, capsys, align, n_est, said):
    """An estimate of the first 10 poses of a 100-pose truth, or --align first/none on 2
    matched poses, was scored unsaid (the reverse, an estimate mostly unmatched, warned)."""
    from graphslam.cli.main import main

    t = np.arange(100) * 0.1
    ref = _tum_line_file(tmp_path / "ref.tum", t, t)
    est = _tum_line_file(tmp_path / "est.tum", t[:n_est], t[:n_est] + 0.01)
    argv = ["eval", str(ref), str(est), "--align", align, "--no-plot", "--out", str(tmp_path / "o")]
    assert main(argv) == 0
    assert said in capsys.readouterr().err
    assert (
        main(["eval", str(ref), str(ref), "--align", align, "--no-plot", "--out", str(tmp_path / "p")]) == 0
    )
    assert "of the reference's time" not in capsys.readouterr().err  # all of it covered


def test_eval_stopped_before_any_score_says_nothing_was_written(tmp_path):
    """Ctrl-C while eval read its reference: the held note promised "the ones scored are
    kept", then "interrupted", and nothing was written, unsaid."""
    from tests.graphslam.cli.test_faults import graphslam

    t = np.arange(50) * 0.1
    ref = _tum_line_file(tmp_path / "ref.tum", t, t)
    est = _tum_line_file(tmp_path / "est.tum", t, t)
    done = graphslam(tmp_path, "eval", str(ref), str(est), "--no-plot", "--out", "o", at="eval")
    assert done.returncode == 130 and "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1] == (
        "graphslam: interrupted (SIGINT) before any estimate was scored: nothing written"
    )
    assert not (tmp_path / "o").exists()


def test_robot_all_writes_a_bag_a_robot_and_refuses_one_truth_for_all(tmp_path, shared_data, capsys):
    """--write-bag with --robot all wrote nothing, unsaid (no trajectory.tum); one
    --ground-truth file was applied to every robot."""
    pytest.importorskip("rosbags")
    from graphslam.cli.main import main

    mrclam = shared_data / "mrclam6"
    if not mrclam.is_dir():
        pytest.skip("no MRCLAM data")
    common = [
        "run",
        "--dataset",
        str(mrclam),
        "--robot",
        "all",
        "--max-steps",
        "30",
        "--rerun",
        "off",
        "--quiet",
    ]
    assert main([*common, "--write-bag", "--out", str(tmp_path / "o")]) == 0
    bags = sorted(p.name for p in (tmp_path / "o").glob("*.bag"))
    estimated = sorted(  # (a robot not seen in the first 30 steps has no pose)
        p.with_suffix(".bag").name
        for p in (tmp_path / "o").glob("trajectory_robot*.tum")
        if any(ln.strip() and not ln.startswith("#") for ln in p.read_text().splitlines())
    )
    assert len(bags) >= 2 and bags == estimated
    capsys.readouterr()
    truth = tmp_path / "o" / "ground_truth_robot1.tum"
    assert main([*common, "--ground-truth", str(truth), "--out", str(tmp_path / "p")]) == 2
    assert "--ground-truth with --robot all" in capsys.readouterr().err


def test_a_built_in_name_that_is_also_a_file_here_says_which_is_read(tmp_path, monkeypatch, capsys):
    """A file named w10000 (or synthetic) in the working folder: convert read the file,
    run the built-in, neither said so."""
    from graphslam.cli.main import main

    monkeypatch.chdir(tmp_path)
    chain = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"
    (tmp_path / "w10000").write_text(chain)
    assert main(["convert", "w10000", "out.g2o"]) == 0
    assert "IN w10000 is read from the file of that name here" in capsys.readouterr().err
    (tmp_path / "synthetic").write_text(chain)
    assert main(["run", "--dataset", "synthetic", "--max-steps", "3", "--rerun", "off", "--quiet"]) == 0
    assert "--dataset synthetic is the built-in data set" in capsys.readouterr().err
    (tmp_path / "w10000").unlink()
    assert (
        main(["run", "--dataset", "synthetic-images", "--max-steps", "3", "--rerun", "off", "--quiet"]) == 0
    )
    assert "built-in" not in capsys.readouterr().err  # no file of its name here
