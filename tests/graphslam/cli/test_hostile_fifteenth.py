"""The fifteenth hostile pass (written outputs and help texts): each test reproduces a
finding that was silent or wrong, then checks what the output holds now."""

from __future__ import annotations

import pytest

from graphslam.cli.main import main
from slamcore.errors import ConfigError


def _pose_times(path, entity: str) -> list[tuple[int, float | None]]:
    """``(step, time in s or None)`` of every row logged at ``entity``."""
    from rerun.chunk import RrdReader

    rows = []
    for chunk in RrdReader(str(path)).stream():
        if chunk.entity_path != entity or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        steps = batch.column("step").to_pylist()
        times = (batch.column("time").to_pylist() if "time" in batch.schema.names
                 else [None] * batch.num_rows)
        rows += [(s, None if t is None else t.total_seconds()) for s, t in zip(steps, times)]
    return sorted(rows, key=lambda r: r[0])


def test_compare_recording_logs_each_back_ends_poses_at_their_own_time(tmp_path, capsys):
    """compare.rrd: the first back end's poses had no time (one row at its last step), every
    later one's had one time, the first back end's last stamp; run.rrd had the right ones."""
    out = tmp_path / "c"
    assert main(["compare", "--max-steps", "12", "--backends", "isam2", "ekf", "--out", str(out)]) == 0
    capsys.readouterr()
    for entity in ("/world/isam2/pose", "/world/ekf/pose", "/world/ekf/pose_ellipse", "/plots/ekf/pose_sigma_m"):
        rows = _pose_times(out / "compare.rrd", entity)
        assert {s for s, _ in rows} == set(range(12)), entity
        # the synthetic stream's dt is 1 s from 0: step k is at k seconds
        assert all(t is not None and abs(t - s) < 1e-6 for s, t in rows), (entity, rows)


def _eval_figure_texts(tmp_path, monkeypatch, files: tuple[str, str], *options: str) -> tuple[str, str]:
    """(first panel's title, middle panel's x label) of the eval.png ``graphslam eval`` draws."""
    import graphslam.visualisation.plots as plots

    seen = {}

    def save(fig, path):
        seen["title"] = fig.axes[0].get_title()
        seen["xlabel"] = fig.axes[1].get_xlabel()
        return path

    monkeypatch.setattr(plots, "_save", save)
    gt, est = tmp_path / files[0], tmp_path / files[1]
    assert main(["eval", str(gt), str(est), *options, "--out", str(tmp_path / "ev")]) == 0
    return seen["title"], seen["xlabel"]


def _write_tum(path, stamps) -> None:
    path.write_text("".join(f"{t} {0.3 * i} {0.1 * i * i} 0 0 0 0 1\n" for i, t in enumerate(stamps)))


def test_eval_plot_names_the_alignment_and_the_stamps_the_files_hold(tmp_path, capsys, monkeypatch):
    """eval.png titled its first panel "aligned trajectories" under --align none, and its time
    axis read "time since first match [s] (frames without stamps)" whatever the files held."""
    stamps = [100.0 + 0.1 * i for i in range(10)]
    _write_tum(tmp_path / "gt.tum", stamps)
    _write_tum(tmp_path / "est.tum", stamps)
    title, xlabel = _eval_figure_texts(tmp_path, monkeypatch, ("gt.tum", "est.tum"), "--align", "none")
    assert title == "trajectories (not aligned)" and xlabel == "time since first match [s]"
    title, _ = _eval_figure_texts(tmp_path, monkeypatch, ("gt.tum", "est.tum"), "--align", "sim3")
    assert "Sim(3)" in title
    title, _ = _eval_figure_texts(tmp_path, monkeypatch, ("gt.tum", "est.tum"), "--n-align", "5")
    assert "SE(3)" in title and "first 5 matched poses" in title
    # pose ids as stamps (graphslam's files of a sequence without times)
    _write_tum(tmp_path / "ids.tum", range(10))
    _, xlabel = _eval_figure_texts(tmp_path, monkeypatch, ("ids.tum", "ids.tum"))
    assert "frame indices" in xlabel
    # KITTI: no stamps at all, paired by line
    kitti = "".join(f"1 0 0 {0.3 * i} 0 1 0 {0.1 * i * i} 0 0 1 0\n" for i in range(10))
    (tmp_path / "gt.txt").write_text(kitti)
    (tmp_path / "est.txt").write_text(kitti)
    _, xlabel = _eval_figure_texts(tmp_path, monkeypatch, ("gt.txt", "est.txt"), "--format", "kitti")
    assert "paired by line" in xlabel
    capsys.readouterr()


def _help(capsys, command: str) -> str:
    with pytest.raises(SystemExit):
        main([command, "--help"])
    return " ".join(capsys.readouterr().out.split())  # argparse's wrapping undone


def test_help_texts_say_what_the_options_do(capsys):
    """``run --help``: ``--robot all`` ran "every robot in one graph (isam2)", though every 2-D
    back end runs it; ``loops --help`` offered exclude_recent first among [loops] keys, which
    the default mode ('covisibility') refuses."""
    text = _help(capsys, "run")
    assert "(isam2)" not in text and "every robot in one estimate, on any 2-D back end" in text
    text = _help(capsys, "loops")
    assert "[loops] mode (covisibility, the default; video, keyframes, auto)" in text
    assert 'exclude_recent(_s) with mode = "video" or "auto"' in text
    from loopclosure.detector import LoopDetectorConfig

    with pytest.raises(ConfigError, match="read only with mode"):
        LoopDetectorConfig(exclude_recent=10)  # why the key needs the mode named
    assert LoopDetectorConfig(mode="video", exclude_recent=10).exclude_recent == 10


def test_image_comparison_plot_shows_the_camera_path_not_the_farthest_landmark(monkeypatch):
    """compare.png on KITTI 07 (20 frames): landmarks 260 m away set the camera-centre
    panel to ~150 x 260 m, and the 2 m path was a dot; now the view is the paths' and the
    landmarks beyond it are counted in the title."""
    from types import SimpleNamespace

    import numpy as np

    import graphslam.visualisation.plots as plots

    seen = {}

    def save(fig, path):
        ax = fig.axes[0]
        seen.update(title=ax.get_title(), x=ax.get_xlim(), y=ax.get_ylim())
        return path

    monkeypatch.setattr(plots, "_save", save)
    n = 20
    wTc = np.tile(np.eye(4), (n, 1, 1))
    wTc[:, 2, 3] = np.linspace(0.0, 2.0, n)  # 2 m forward along z, KITTI's camera axis
    wTc[:, 0, 3] = 0.1 * np.sin(np.arange(n))
    landmarks = np.array([[1.0, 0.5, 2.5], [-0.5, 0.0, 1.0], [-30.0, 2.0, 260.0], [5.0, 1.0, 40.0]])
    est = SimpleNamespace(wTc=wTc, landmarks_w=landmarks, frame_ids=np.arange(n))
    entry = SimpleNamespace(backend="isam2", result=SimpleNamespace(estimate=est, frames=n),
                            metrics=SimpleNamespace(alignment="se3"), nees=None)
    plots.plot_visual_comparison([entry], SimpleNamespace(name="kitti07", wTc_true=wTc), None)
    assert seen["title"] == "kitti07: camera centres (2 of 4 landmarks of the runs beyond the view)"
    # the panel is about the path's size (its 2 m plus margins), not 260 m
    assert np.ptp(seen["x"]) < 10 and np.ptp(seen["y"]) < 10 and seen["y"][1] > 2.0
