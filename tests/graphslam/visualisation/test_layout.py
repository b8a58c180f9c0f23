"""The viewer layout sent with every recording: one view per kind of thing logged, and
no view of something the run did not log."""

from __future__ import annotations

import pytest

from graphslam.cli.main import main
from tests.recordings import blueprint_views, entity_paths


def _run(tmp_path, capsys, *args) -> tuple[list[dict], set[str]]:
    out = tmp_path / "run"
    rc = main(["run", *args, "--out", str(out), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    return blueprint_views(out / "run.rrd"), entity_paths(out / "run.rrd")


def _shows_only_what_was_logged(views, paths) -> None:
    for v in views:
        for query in v["contents"]:
            if query == "$origin/**":
                assert any(p == v["origin"] or p.startswith(v["origin"].rstrip("/") + "/")
                           for p in paths), v
            else:
                assert query in paths, v


def _by_kind(views) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for v in views:
        out.setdefault(v["kind"], []).append(v)
    return out


def test_ekf_run_layout(tmp_path, capsys):
    views, paths = _run(tmp_path, capsys, "--backend", "ekf", "--max-steps", "40")
    _shows_only_what_was_logged(views, paths)
    kinds = _by_kind(views)
    assert [(v["name"], v["origin"]) for v in kinds["2D"]] == [("map", "/world")]
    assert [v["origin"] for v in kinds["Tensor"]] == ["/filter/ekf/correlation"]
    series = {v["name"]: v["contents"] for v in kinds["TimeSeries"]}
    assert series == {"pose_sigma_m": ["/plots/ekf/pose_sigma_m"],
                      "mean_abs_correlation": ["/plots/ekf/mean_abs_correlation"]}
    assert "3D" not in kinds


def test_fastslam_run_layout(tmp_path, capsys):
    views, paths = _run(tmp_path, capsys, "--backend", "fastslam1", "--max-steps", "60")
    _shows_only_what_was_logged(views, paths)
    kinds = _by_kind(views)
    assert {v["name"] for v in kinds["TimeSeries"]} == {"pose_sigma_m", "ess"}
    assert "Tensor" not in kinds
    resampled = "/plots/fastslam1/resampling" in paths
    assert [v["origin"] for v in kinds.get("TextLog", [])] \
        == (["/plots/fastslam1/resampling"] if resampled else [])


@pytest.mark.slow
def test_visual_run_layout(tmp_path, capsys):
    views, paths = _run(tmp_path, capsys, "--dataset", "synthetic-images", "--max-steps", "8")
    _shows_only_what_was_logged(views, paths)
    kinds = _by_kind(views)
    assert [(v["name"], v["origin"]) for v in kinds["3D"]] == [("world", "/world")]
    assert [(v["name"], v["origin"]) for v in kinds["2D"]] \
        == [("isam2 camera", "/world/isam2/camera/image")]
    assert {v["name"] for v in kinds["TimeSeries"]} \
        == {"found", "searched", "observations", "image_fraction"}


def test_pose_graph_run_layout(tmp_path, capsys):
    import gtsam

    views, paths = _run(tmp_path, capsys, "--dataset", gtsam.findExampleDataFile("w100.graph"))
    _shows_only_what_was_logged(views, paths)
    assert [v["origin"] for v in views] == ["/world"]


def test_a_failing_layout_still_leaves_the_logged_data(tmp_path, monkeypatch):
    import rerun as rr

    import graphslam.visualisation.recording as recording

    def broken(_logged):
        raise RuntimeError("layout bug")

    monkeypatch.setattr(recording, "blueprint", broken)
    log = recording.RerunLog("save", tmp_path / "run.rrd")
    log.set_step(0)
    log.rec.log("world/points", rr.Points2D([[0.0, 1.0]]))
    with pytest.raises(RuntimeError, match="layout bug"):
        log.close()
    assert "/world/points" in entity_paths(tmp_path / "run.rrd")


def _counting_log(tmp_path, monkeypatch, **kw):
    """A RerunLog writing a file whose blueprint sends are counted in ``log.sends``."""
    import graphslam.visualisation.recording as recording

    log = recording.RerunLog("save", tmp_path / "run.rrd", **kw)
    log.sends = []
    real = log._stream.send_blueprint
    monkeypatch.setattr(log._stream, "send_blueprint",
                        lambda bp, **k: (log.sends.append(bp), real(bp, **k)))
    return log


def test_live_layout_is_sent_when_the_views_change(tmp_path, monkeypatch):
    """A live viewer gets the layout as the run's views appear, not once per new entity
    inside a view (each send resets what the user arranged), and again at the close."""
    import rerun as rr

    log = _counting_log(tmp_path, monkeypatch, live_layout=True)
    log.set_step(0)
    assert log.sends == []  # nothing logged yet: no layout
    log.rec.log("world/ekf/pose", rr.Arrows2D(origins=[[0, 0]], vectors=[[1, 0]]))
    log.rec.log("plots/ekf/pose_sigma_m", rr.Scalars(0.1))
    log.set_step(1)
    assert len(log.sends) == 1
    log.rec.log("world/ekf/trajectory", rr.LineStrips2D([[[0, 0], [1, 0]]]))  # same map view
    log.rec.log("plots/ekf/pose_sigma_m", rr.Scalars(0.2))
    log.set_step(2)
    assert len(log.sends) == 1
    log.rec.log("plots/fastslam1/pose_sigma_m", rr.Scalars(0.3))  # a new series in the view
    log.rec.set_time("frame", sequence=3)  # as the visual loggers start a frame
    assert len(log.sends) == 2
    log.close()
    assert len(log.sends) == 3


def test_a_file_gets_its_layout_once(tmp_path, monkeypatch):
    import rerun as rr

    log = _counting_log(tmp_path, monkeypatch)
    for step in range(3):
        log.set_step(step)
        log.rec.log(f"plots/ekf/q{step}", rr.Scalars(1.0))
    log.close()
    assert len(log.sends) == 1


def test_a_failing_live_layout_does_not_end_the_run(tmp_path, monkeypatch):
    import rerun as rr

    import graphslam.visualisation.recording as recording

    calls = []

    def broken(_logged):
        calls.append(1)
        raise RuntimeError("layout bug")

    monkeypatch.setattr(recording, "blueprint", broken)
    log = recording.RerunLog("save", tmp_path / "run.rrd", live_layout=True)
    for step in range(3):
        log.rec.log(f"plots/ekf/q{step}", rr.Scalars(1.0))
        log.set_step(step)  # does not raise, and stops trying after the first failure
    assert len(calls) == 1
    with pytest.raises(RuntimeError, match="layout bug"):  # the close says why
        log.close()
    assert "/plots/ekf/q2" in entity_paths(tmp_path / "run.rrd")


@pytest.mark.parametrize("args", [
    ["--dataset", "synthetic-images", "--backend", "ekf", "--max-steps", "6"],  # rec.set_time
    ["--dataset", "synthetic", "--max-steps", "30"],  # set_step
])
def test_runs_send_their_layout_live(tmp_path, capsys, monkeypatch, args):
    """The visual and the 2-D loggers both start their steps where the live check runs."""
    import graphslam.visualisation.recording as recording

    sends = []
    real_init = recording.RerunLog.__init__

    def init(self, mode, *a, **k):
        real_init(self, mode, *a, **{**k, "live_layout": True})
        real = self._stream.send_blueprint
        self._stream.send_blueprint = lambda bp, **kw: (sends.append(1), real(bp, **kw))

    monkeypatch.setattr(recording.RerunLog, "__init__", init)
    views, _ = _run(tmp_path, capsys, *args)
    assert views and len(sends) >= 2  # during the run, and at the close
