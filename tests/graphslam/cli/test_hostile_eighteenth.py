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


def test_a_viewer_that_dies_during_the_run_leaves_the_whole_recording(tmp_path):
    """``--rerun connect`` to a viewer killed during the run: the end said "the recording
    is incomplete" and nothing of it was kept. The stream is now copied to a hidden file
    beside run.rrd, which becomes run.rrd when the viewer went, and goes when it did not."""
    import os
    import shutil
    import signal
    import subprocess
    import time

    from graphslam.visualisation.recording import RerunLog, SavedInstead, find_viewer, sink_problem

    exe = find_viewer()
    if exe is None:
        pytest.skip("no Rerun viewer executable")
    url_of = "rerun+http://127.0.0.1:{}/proxy".format

    def serve() -> tuple[subprocess.Popen, str]:
        port = _free_port()
        # its own session: the `rerun` script starts the server as a child, killed with it
        server = subprocess.Popen(
            [exe, "--serve-grpc", "--port", str(port)],
            start_new_session=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        deadline = time.monotonic() + 60
        while sink_problem("connect", url_of(port)) is not None:
            assert server.poll() is None and time.monotonic() < deadline
            time.sleep(0.2)
        return server, url_of(port)

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
