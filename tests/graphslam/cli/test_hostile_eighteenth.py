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
